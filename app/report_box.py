"""The sidebar's report download, on every page: the calibration report of the loaded session.

The report (:mod:`ccdcore_report`) runs every estimate the session allows, so it is prepared off the
UI thread with the header's progress bar (:meth:`ccdcore_app.state.AppState.compute`), then offered
as a download; a new session withdraws it.

Public objects
--------------
ReportBox
    The two buttons (prepare, download) bound to an :class:`~ccdcore_app.state.AppState`.
"""
from __future__ import annotations

import io
from typing import Any

import panel as pn
import param

from ccdcore.progress import Progress

from .state import AppState

__all__ = ["ReportBox", "make_report"]


def make_report(session: Any, progress: Progress | None = None) -> str:
    """The report of ``session`` as HTML text (:func:`ccdcore_report.build_report`)."""
    from ccdcore_report import build_report

    return build_report(session, progress=progress)


class ReportBox(param.Parameterized):
    """Prepare, then download, the loaded session's report (``<session>-report.html``)."""

    state = param.ClassSelector(class_=AppState)
    html = param.String(default="", doc="The prepared report ('' until prepared).")

    def __init__(self, state: AppState, **params: Any):
        super().__init__(state=state, **params)
        self.prepare = pn.widgets.Button(label="Prepare the report", color="default",
                                         sizing_mode="stretch_width", margin=(2, 10),
                                         css_classes=["ccd-report-prepare"],
                                         description="Every estimate of the session, its plots "
                                                     "and provenance in one HTML file")
        self.prepare.on_click(lambda event: pn.state.execute(self.build))
        self.download = pn.widgets.FileDownload(
            callback=self._bytes, filename="report.html", label="Download the report",
            color="primary", disabled=True, sizing_mode="stretch_width", margin=(2, 10),
            css_classes=["ccd-report-download"])
        self.note = pn.pane.Markdown("", margin=(0, 10), styles={"font-size": "0.85em",
                                                                  "color": "#6c757d"},
                                     css_classes=["ccd-report-note"])
        state.param.watch(self._on_session, "session")
        self._sync()

    def panel(self) -> pn.Column:
        return pn.Column(pn.pane.Markdown("#### Report", margin=(12, 10, 0, 10)), self.prepare,
                         self.download, self.note, sizing_mode="stretch_width")

    def _on_session(self, *events: Any) -> None:
        if self.html:
            self.html = ""          # (the watcher below redraws)
        else:
            self._sync()

    @param.depends("html", watch=True)
    def _sync(self) -> None:
        session = self.state.session
        self.prepare.disabled = session is None
        self.download.disabled = not self.html
        if session is not None:
            self.download.filename = f"{session.root.name}-report.html"
        self.note.object = (f"{len(self.html.encode()) / 1e6:.2f} MB, opens offline"
                            if self.html else "")

    async def build(self) -> None:
        session = self.state.session
        if session is None:
            return
        html = await self.state.compute(make_report, session, label="the report",
                                        pass_progress=True)
        if html is not None and self.state.session is session:
            self.html = html

    def _bytes(self) -> io.BytesIO | None:
        return io.BytesIO(self.html.encode()) if self.html else None
