"""Step 4, ptc: photon transfer with its band and residuals, levels left out and the robust
mode; the EMVA 1288 figures when the session carries photon counts."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import pandas as pd
import panel as pn

from ccdcore import guide
from ccdcore.guide import Gate
from ccdcore.session import Session
from ccdcore_report.ptc import PtcFigures

from ._common import Step, skip_missing, table

if TYPE_CHECKING:
    from ccdcore.noise import PhotonTransfer


@dataclass(frozen=True, eq=False)
class PtcResult:
    """The photon transfer with the page's choices; ``noise`` is ``None`` when the session lacks
    the frames (the step is skipped)."""

    noise: PhotonTransfer | None


def compute_ptc(session: Session, exclude: list[int], robust: bool) -> Any:
    from ccdcore.noise import photon_transfer

    return photon_transfer(session, exclude_levels=exclude, robust=robust)


def compute_emva(session: Session, noise: Any) -> dict[str, Any]:
    """The EMVA 1288 figures (:func:`ccdcore.datasheet.emva_figures`) as their JSON dict."""
    from ccdcore.datasheet import emva_figures

    return emva_figures(session, noise=noise).to_dict()


#: the EMVA 1288 figures the photon-transfer step lists: key, unit, what it is
EMVA_ROWS = (("K", "DN/e⁻", "system gain"), ("QE", "%", "quantum efficiency η"),
             ("sigma_d", "e⁻", "temporal dark noise, from the dark frames"),
             ("sigma_d_ptc", "e⁻", "temporal dark noise, from the photon-transfer intercept"),
             ("u_e_sat", "e⁻", "saturation capacity μ_e.sat"), ("SNR_max", "", "maximum SNR"),
             ("DR_dB", "dB", "dynamic range"), ("LE_min", "%", "linearity error, min"),
             ("LE_max", "%", "linearity error, max"), ("DSNU1288", "e⁻", "DSNU"),
             ("PRNU1288", "%", "PRNU"))


def emva_table(figures: dict[str, Any]) -> pd.DataFrame:
    """The figures as rows (name, value ± error, unit, meaning); absent ones as '–'."""
    from ccdcore.common import format_pm

    rows = []
    for key, unit, what in EMVA_ROWS:
        v, e = figures.get(key), figures.get(f"{key}_err")
        text = "–" if v is None else (format_pm(float(v), float(e)) if e else f"{v:.4g}")
        rows.append({"figure": key, "value": text, "unit": unit, "meaning": what})
    return pd.DataFrame(rows)


class PtcStep(Step):
    slug = "ptc"

    def build(self) -> list[pn.viewable.Viewable]:
        self.figs = PtcFigures(height=320)
        self.exclude_select = pn.widgets.MultiChoice(label="Leave out levels", options=[],
                                                     width=300, css_classes=["ccd-wt-exclude"])
        self.exclude_select.param.watch(self._on_exclude, "value")
        self.robust_box = pn.widgets.Checkbox.from_param(
            self.page.param.robust, name="Robust mode (drop levels beyond 3σ)")
        self.emva_table = table("ccd-wt-emva")
        self.emva_holder = pn.Column(
            pn.pane.Markdown("**EMVA 1288 figures** (the session carries photon counts; "
                             "definitions of release 3.1, as the emva1288 package computes "
                             "them: docs/emva.md)"),
            self.emva_table, visible=False, sizing_mode="stretch_width")
        return [pn.Row(self.exclude_select, self.robust_box),
                pn.pane.Bokeh(self.figs.transfer, sizing_mode="stretch_width"),
                pn.pane.Bokeh(self.figs.residual, sizing_mode="stretch_width"),
                self.emva_holder]

    async def ensure(self) -> PhotonTransfer | None:
        """The photon-transfer result (``None`` when skipped or failed; the gate says why)."""
        found = await self.once(self._compute)
        return found.noise if found is not None else None

    async def _compute(self) -> PtcResult | None:
        """The photon transfer and its gate (a skip without the frames)."""
        page, session = self.page, self.page.state.session
        skip = skip_missing(session, "noise")
        if skip is not None:
            self.set_gate(skip)
            return PtcResult(None)
        noise = await self.compute(compute_ptc, session, list(page.exclude), bool(page.robust),
                                   label="photon transfer")
        if noise is None:
            return None
        self.results.ptc = found = PtcResult(noise)      # stored before the EMVA figures
        gate = guide.ptc_gate(noise)
        if any(r.photons for r in session.by_role("ptc")):
            gate = await self._with_emva(session, noise, gate)
        self.set_gate(gate)
        return found

    async def _with_emva(self, session: Session, noise: Any, gate: Gate) -> Gate:
        """The EMVA 1288 figures (``results.emva``), and ``gate`` with their notes."""
        state = self.page.state
        figures = await state.compute(compute_emva, session, noise,
                                      label="the EMVA 1288 figures")
        self.results.emva = figures
        if figures is None:
            notes: tuple[str, ...] = (
                f"the EMVA 1288 figures could not be made: {state.error}",)
        else:
            notes = tuple(f"EMVA 1288: {n}" for n in figures.get("notes", ()))
        return Gate(gate.status, gate.summary, gate.reasons + notes, gate.next)

    def draw(self, found: PtcResult) -> None:
        noise = found.noise
        if noise is None:
            return
        self.figs.update(noise.points, noise)
        figures = self.results.emva
        if figures:
            self.emva_table.object = emva_table(figures)
        self.emva_holder.visible = bool(figures)
        self.exclude_select.options = [int(p.level) for p in noise.points]
        self.page.steps["plan"].use_session.disabled = False

    def _on_exclude(self, event: Any) -> None:
        value = sorted(int(v) for v in event.new)
        if value != sorted(self.page.exclude):
            self.page.exclude = value

    def show_exclude(self) -> None:
        """The levels left out, as the page holds them (set from the address or a test)."""
        if self.exclude_select.value != list(self.page.exclude):
            self.exclude_select.value = list(self.page.exclude)
