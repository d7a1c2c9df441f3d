"""Step 8, export: the verify step's product and its report, saved into a folder inside the
allowed roots (``report.html`` beside the maps); the report to download. The product's estimates
are listed with their headline figures, the rows every result gives
(:func:`ccdcore_app.product.summary.estimates_frame`, as the product panel lists them)."""
from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable

import panel as pn

from ccdcore.errors import CcdError
from ccdcore.guide import Gate, GateStatus
from ccdcore.session import Session

from ...batch import in_document
from ...product.summary import estimates_frame
from ._common import Step, table

if TYPE_CHECKING:
    from ccdcore.product.make import CalibrationProduct


@dataclass(frozen=True)
class ExportResult:
    """Where the product (a folder) and its report were saved."""

    folder: Path
    report: Path


def compute_report(session: Session, product: Any) -> str:
    """The report of the walkthrough's product (:func:`ccdcore_report.build_report`; nothing is
    estimated again)."""
    from ccdcore_report import build_report

    return build_report(session, product=product)


def save_export(product: Any, html: str, folder: Path) -> ExportResult:
    """Save the product into ``folder`` and its report beside its maps (``report.html``)."""
    from ccdcore.io.frames import atomic_write_text

    out = product.save(folder)
    report = out / "report.html"
    atomic_write_text(report, html)
    return ExportResult(out, report)


class ExportStep(Step):
    slug = "export"
    result_name = "report"        # what is drawn: the report, ready to download

    def build(self) -> list[pn.viewable.Viewable]:
        self.folder_input = pn.widgets.TextInput.from_param(
            self.page.param.export_folder, name="Product folder", sizing_mode="stretch_width",
            css_classes=["ccd-wt-folder"])
        self.save_button = pn.widgets.Button(label="Save the product and the report",
                                             color="primary", css_classes=["ccd-wt-save"])
        self.save_button.on_click(lambda e: pn.state.execute(self.save))
        self.report_download = pn.widgets.FileDownload(
            callback=self.report_bytes, filename="report.html",
            label="Download the report (HTML)", color="default", disabled=True,
            css_classes=["ccd-wt-report-download"])
        self.export_note = pn.pane.Markdown("", sizing_mode="stretch_width",
                                            css_classes=["ccd-wt-export-note"])
        self.estimates_table = table("ccd-wt-estimates")
        return [pn.pane.Markdown("The product's estimates, with their headline figures:"),
                self.estimates_table, self.folder_input,
                pn.Row(self.save_button, self.report_download), self.export_note]

    async def ensure(self) -> tuple[CalibrationProduct, str] | None:
        """The product (step 7's) and its report, built once off the UI thread; the download
        and the save both use it."""
        found = await self.page.steps["verify"].ensure()
        if found is None:
            return None
        html = await self.once(lambda: self.compute(
            compute_report, self.page.state.session, found.product, label="the report"))
        return None if html is None else (found.product, html)

    def gate_of(self, found: tuple[CalibrationProduct, str]) -> Gate | None:
        """Ready to save (a saved product keeps its gate)."""
        if self.results.export is not None:
            return None
        product = found[0]
        return Gate(GateStatus.WARN if not product.maps else GateStatus.PASS,
                    "the product is ready to save: choose a folder and save it",
                    tuple(f"skipped {s.estimate}: {s.reason}" for s in product.skipped))

    def draw(self, found: str) -> None:
        """The report ``found`` (HTML) ready: its download is enabled, and the product's
        estimates are listed."""
        if self.results.verify is not None:
            self.estimates_table.object = estimates_frame(self.results.verify.product)
        session = self.page.state.session
        if session is not None:
            self.report_download.param.update(disabled=False,
                                              filename=f"{session.root.name}-report.html")

    async def save(self) -> None:
        """Save the product and its report into the page's ``export_folder`` (inside the
        allowed folders); the gate says where, or why not."""
        state = self.page.state
        if state.session is None:
            return
        ready = await self.ensure()
        if ready is None:
            return
        try:
            folder = state.check_allowed(self.page.export_folder)
        except CcdError as err:
            self.set_gate(Gate(GateStatus.FAIL, str(err), next=(
                "choose a folder inside your home, the working folder or the session's",)))
            return
        saved = await self.compute(save_export, *ready, folder,
                                   label="the product and the report")
        if saved is None:
            return
        self.results.export = saved
        self.set_gate(Gate(GateStatus.PASS, f"saved the product to {saved.folder} and the "
                                            f"report to {saved.report}", (
            "apply it: ccdcore apply " + str(saved.folder) + " IMAGES -o OUT",)))
        in_document(self.page.doc, lambda: setattr(
            self.export_note, "object", f"Saved: `{saved.folder}` and `{saved.report}`."))

    def report_bytes(self) -> io.BytesIO | None:
        html = self.results.report
        return io.BytesIO(html.encode()) if html else None

    def dropped(self, names: Iterable[str]) -> None:
        if "report" in names:        # its report is gone: nothing to download until rebuilt
            in_document(self.page.doc, lambda: setattr(self.report_download, "disabled", True))
