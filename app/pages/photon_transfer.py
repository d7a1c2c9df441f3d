"""The Photon transfer page: the camera's noise model σ²_N = A·μ + σ²_C from pairs of flat frames.

Healey & Kondepudy 1994, sec. IV and appendix: per light level the mean μ̂ (eq. 37), the noise
variance σ̂²_N of the difference image (eq. 38) and its standard error (eq. 40); the weighted line
(eq. 41, eqs. 59–65) with the covariance of (A, σ²_C) (eq. 66), χ² (eq. 42) and Q (eq. 67).

Public objects
--------------
PhotonTransferPage
    The page (a :class:`panel.viewable.Viewer`): the points with error bars, the fitted line with
    its 1-σ confidence band, residuals in sigma units, a log-log view in the EMVA 1288 style, Q with
    a plain-language verdict, the parameter table with uncertainties and units, level toggles and
    a robust mode that refit at once (no frame is read again), and an ROI drawn on a frame preview.
create_page(state)
    The registry entry point.
parameter_frame(result)
    The fitted parameters of a :class:`~ccdcore.noise.PhotonTransfer` as a display-ready
    DataFrame (quantity, symbol, value ± error (:func:`ccdcore.common.format_pm`), unit).
verdict_message(result)
    The alert type and plain-language text for the fit's Q.

Every number comes from :mod:`ccdcore.noise`: the page calls ``photon_transfer`` (one streamed
pass over the frames, off the UI thread), then ``PhotonTransfer.refit`` (i.e. ``fit_points`` with
the same black level, bit depth, ROI and notes) for every toggle; when too few levels are usable
for a fit it still shows the levels measured by ``ptc_points``. The fit and the points are shared
through ``state.results.ptc`` and ``state.results.ptc_points``; the measured levels at an ROI
are kept on disk (``AppState.cached_compute``, keyed by the session's content and the ROI), so a
session opened again shows them without reading its frames. The plots come from
:mod:`ccdcore_report.ptc` (shared with the report) and :mod:`ccdcore_app.plots.base`; the frame
preview under the ROI is :class:`ccdcore_app.frame_preview.FramePreview` (shared with the Session
page).
"""
from __future__ import annotations

import dataclasses
import logging
import math
from typing import Any, Sequence

import numpy as np
import pandas as pd
import panel as pn
import param

from ccdcore.common import format_pm, format_size
from ccdcore.errors import CcdError
from ccdcore.guide import GateStatus, ptc_gate
from ccdcore.noise import (EMVA_FIT_FRACTION, ROBUST_Z, USER_EXCLUDED, PhotonTransfer, PtcPoint,
                           photon_transfer, ptc_points)
from ccdcore.session import FrameRecord, Session

from ccdcore_report import ptc as ptc_plots

from ..plots import base as plots
from ..cache.store import photon_transfer_entry
from ..frame_preview import FramePreview
from ..tiles import TiledPlane
from ..state import AppState
from ..batch import batched
from ._choices import set_choices
from ._messages import PageMessages
from ._styles import TABLE_CSS, heading

__all__ = ["PhotonTransferPage", "create_page", "parameter_frame", "verdict_message",
           "NO_PTC_MESSAGE"]

log = logging.getLogger(__name__)

#: what the page says when the session has no photon-transfer frames
NO_PTC_MESSAGE = (
    "**No photon-transfer frames in this session.** Capture pairs of frames (two or more "
    "frames each) of a uniformly lit card at **three or more light levels**, from just above "
    "the dark level to just below saturation, and list them in `session.toml` with "
    "`role = \"ptc\"` and `level = N` (one N per light level). Dark frames at two or more "
    "exposure times give the black level; `[camera] black_level` states it directly.")

_BLACK_SOURCES = {
    "argument": "given",
    "camera": "from the manifest ([camera] black_level)",
    "dark_extrapolated": "dark frames extrapolated to zero exposure",
    "dark_mean": "mean of the dark frames (EMVA 1288 convention)",
    "none": "no dark frames: 0, the paper's model",
    "given": "given",
}

#: the alert of each gate status
_ALERTS = {GateStatus.PASS: "success", GateStatus.WARN: "warning", GateStatus.FAIL: "danger",
           GateStatus.SKIP: "info"}


#: the height of the levels' list before it scrolls (px)
LEVEL_LIST_HEIGHT = 260

_NAV_NOTE = ("Levels the estimator leaves out (clipped, beyond the linear range) stay out "
             "whatever their tick; the points table says why.")


def _roi_text(roi: Sequence[int] | None, shape: tuple[int, int] | None) -> str:
    if roi is None:
        return "full frame" + ("" if shape is None else f" ({format_size(shape)} px)")
    x, y, w, h = roi
    return f"x = {x}, y = {y}, {format_size((h, w))} px"


def parameter_frame(result: PhotonTransfer, shape: tuple[int, int] | None = None
                    ) -> pd.DataFrame:
    """The fitted noise model as rows of quantity, symbol, value (± standard error) and unit.

    ``shape`` (H, W) of the frames only labels the full-frame region.
    """
    used = [p for p in result.points if p.used]
    pixels = used[0].n_pixels if used else (result.points[0].n_pixels if result.points else 0)
    source = _BLACK_SOURCES.get(result.black_level_source, result.black_level_source)
    rows = [
        ("Gain (slope, eq. 41)", "A", format_pm(result.A, result.A_err), "DN/e\u207b"),
        ("Conversion gain", "1/A", format_pm(result.conversion_gain_e_per_dn,
                                                result.conversion_gain_e_per_dn_err),
         "e\u207b/DN"),
        ("Noise intercept (eq. 27)", "\u03c3\u00b2_C",
         format_pm(result.sigma_c2, result.sigma_c2_err), "DN\u00b2"),
        ("Read noise", "\u03c3_R", format_pm(result.read_noise_e, result.read_noise_e_err),
         "e\u207b"),
        ("Read noise in DN", "A\u00b7\u03c3_R", format_pm(result.read_noise_dn,
                                                               result.read_noise_dn_err), "DN"),
        ("Quantisation noise", "q\u00b2/12", format_pm(result.quantisation_dn2), "DN\u00b2"),
        ("Black level", "b\u2080", f"{format_pm(result.black_level_dn)} ({source})", "DN"),
        ("Chi-square (eq. 42)", "\u03c7\u00b2", format_pm(result.chi2), ""),
        ("Degrees of freedom", "\u03bd", str(result.dof), ""),
        ("Goodness of fit (eq. 67)", "Q", format_pm(result.Q), ""),
        ("Levels used", "P", f"{len(used)} of {len(result.points)}", ""),
        ("Region", "ROI", f"{_roi_text(result.roi, shape)}; M = {pixels} px per frame", ""),
    ]
    return pd.DataFrame(rows, columns=["quantity", "symbol", "value", "unit"])


def verdict_message(result: PhotonTransfer) -> tuple[str, str]:
    """``(alert_type, markdown)``: the photon-transfer gate of :func:`ccdcore.guide.ptc_gate`,
    the verdict the Walkthrough, ``ccdcore ptc`` and the report show in the same words (the
    line against stated tolerances of its deviation, with χ² and Q), with the levels furthest
    from the line when it does not pass."""
    gate = ptc_gate(result)
    text = f"**{gate.label}** \u2014 {gate.summary}"
    if gate.reasons:
        text += "\n\n" + "\n".join(f"- {r}" for r in gate.reasons)
    worst = result.worst_levels(2) if gate.status != GateStatus.PASS else []
    if worst:
        text += "\n- largest residuals: " + ", ".join(
            f"level {level} ({z:+.1f} \u03c3)" for level, z in worst)
    if gate.next:
        text += "\n\n**Next:** " + "; ".join(gate.next)
    return _ALERTS[gate.status], text


def _level_label(p: PtcPoint) -> str:
    return f"Level {p.level} (\u03bc {p.mu:.4g} DN)"


class PhotonTransferPage(PageMessages, pn.viewable.Viewer):
    """Photon transfer of the loaded session: points, fit, verdict, parameters, toggles, ROI."""

    state = param.ClassSelector(class_=AppState, doc="The app state shared by all pages.")
    robust = param.Boolean(default=False, doc=(
        f"Robust mode: drop, one at a time, the level whose residual exceeds {ROBUST_Z:g} sigma "
        "(at least three levels kept)."))
    emva_range = param.Boolean(default=False, doc=(
        "Fit the gain over the EMVA 1288 range only: the levels up to 70 % of the saturation "
        "signal (that of the level of largest variance; release 3.1 sec. 6.6)."))
    points = param.ClassSelector(class_=tuple, default=(), doc=(
        "The measured levels (ccdcore.noise.PtcPoint) at the applied ROI, with the estimator's "
        "flags when fitted."))
    levels = param.ListSelector(default=[], objects=[], doc=(
        "The light levels ticked for the fit (the others are excluded by the user)."))
    frame = param.Selector(default=None, objects=[], allow_None=True, doc=(
        "relpath of the photon-transfer frame previewed under the ROI box."))

    def __init__(self, state: AppState | None = None, *, auto: bool = True, **params: Any):
        """``auto``: compute as soon as the page is built and whenever the session changes
        (scheduled on the server's event loop); tests pass ``False`` and await :meth:`refresh`."""
        super().__init__(state=state if state is not None else AppState(), **params)
        self.auto = auto
        #: ``photon_transfer`` at the applied ROI with no user choices: carries the black level,
        #: bits, ROI and notes for every refit (None when the points cannot be fitted)
        self.base: PhotonTransfer | None = None
        #: the fit shown (None when there is none)
        self.result: PhotonTransfer | None = None
        #: the applied ROI (x, y, w, h), None for the full frame
        self.roi: tuple[int, int, int, int] | None = None
        #: (H, W) of the ptc frames, None before a session with ptc frames is shown
        self.shape: tuple[int, int] | None = None
        self.error = ""          # the page's current problem ('' when none)
        self._session: Session | None = None   # the session the page shows
        self._fit_error = ""     # why the measured points have no fit (shown by the next fit)
        self._records: dict[str, FrameRecord] = {}
        self._build_widgets()
        self.state.param.watch(self._on_session, "session")
        self.state.results.param.watch(self._on_results, "estimates")
        self.param.watch(self._on_frame, "frame")
        self._show_empty()
        if auto and self.state.session is not None:
            pn.state.execute(self.refresh)

    # ================================================================ building the widgets ====
    def _build_widgets(self) -> None:
        self._build_alerts("ptc")
        self.plan_alert = pn.pane.Alert("", alert_type="warning", visible=False,
                                        sizing_mode="stretch_width")
        self.verdict_alert = pn.pane.Alert("", alert_type="info", visible=False,
                                           sizing_mode="stretch_width", margin=(5, 5, 0, 5))
        self.parameter_table = pn.pane.DataFrame(
            pd.DataFrame(columns=["quantity", "symbol", "value", "unit"]), index=False,
            sizing_mode="stretch_width", name="parameters", css_classes=["ccd-ptc-parameters"],
            stylesheets=[TABLE_CSS])

        self.level_select = pn.widgets.CheckBoxGroup.from_param(
            self.param.levels, label="Levels in the fit", inline=False)
        self.robust_checkbox = pn.widgets.Checkbox.from_param(
            self.param.robust, label=f"Robust mode (drop levels beyond {ROBUST_Z:g}\u03c3, one at "
                                    "a time)")
        self.emva_checkbox = pn.widgets.Checkbox.from_param(
            self.param.emva_range, label="EMVA 1288 range (0–70 % of saturation)")
        self.all_levels_button = pn.widgets.Button(label="Use all levels", color="light")
        self.all_levels_button.on_click(self._on_all_levels)
        self.robust_pane = pn.pane.Markdown("", sizing_mode="stretch_width",
                                            styles={"font-size": "0.9em"})

        # the three plots are built once (plain Bokeh); every refit replaces their sources'
        # data (ptc_plots.PtcFigures.update), the browser only redraws
        self.figures = ptc_plots.PtcFigures()
        self.figures.transfer.css_classes = ["ccd-ptc-plot"]   # (a Bokeh pane shows the figure
        self.figures.loglog.css_classes = ["ccd-ptc-loglog"]   # itself: the class goes on it)
        self.transfer_pane = pn.pane.Bokeh(self.figures.transfer, sizing_mode="stretch_width",
                                           min_height=380)
        self.residual_pane = pn.pane.Bokeh(self.figures.residual, sizing_mode="stretch_width",
                                           min_height=220)
        # shown with a fit
        self.residual_box = pn.Column(self.residual_pane, sizing_mode="stretch_width",
                                      margin=0, visible=False)
        self.loglog_pane = pn.pane.Bokeh(self.figures.loglog, sizing_mode="stretch_width",
                                         min_height=600)
        #: what the plots draw now: (points, fit)
        self.drawn: tuple = ((), None)
        self.plot_tabs = pn.Tabs(
            ("Linear: \u03c3\u00b2_N against \u03bc",
             pn.Column(self.transfer_pane, self.residual_box, sizing_mode="stretch_width")),
            ("Log-log (EMVA 1288)", self.loglog_pane),
            sizing_mode="stretch_width", dynamic=False)

        self.points_table = pn.pane.DataFrame(pd.DataFrame(), index=False,
                                              sizing_mode="stretch_width", name="points",
                                              stylesheets=[TABLE_CSS])
        self.notes_pane = pn.pane.Markdown("", sizing_mode="stretch_width")

        # ---- ROI
        self.frame_select = pn.widgets.Select.from_param(self.param.frame, label="Preview frame",
                                                         sizing_mode="stretch_width")
        self.x_input = pn.widgets.IntInput(label="X (column)", value=0, start=0, width=110)
        self.y_input = pn.widgets.IntInput(label="Y (row)", value=0, start=0, width=110)
        self.w_input = pn.widgets.IntInput(label="W (px)", value=1, start=1, width=110)
        self.h_input = pn.widgets.IntInput(label="H (px)", value=1, start=1, width=110)
        self.apply_roi_button = pn.widgets.Button(label="Apply ROI", color="primary")
        self.apply_roi_button.on_click(self._on_apply_roi)
        self.full_frame_button = pn.widgets.Button(label="Full frame", color="light")
        self.full_frame_button.on_click(self._on_full_frame)
        self.roi_status = pn.pane.Markdown("", sizing_mode="stretch_width")
        # the frame preview (ccdcore_app.frame_preview), built once (plain Bokeh): another
        # frame replaces its data; a drawn box fills the inputs, the inputs move the outline
        self.preview = FramePreview(frame_width=560, max_frame_height=560,
                                    css_class="ccd-ptc-preview", select=True,
                                    on_box=self._on_bounds)
        self.preview_alert = self.preview.alert
        self.preview_view = self.preview.view
        self.preview_pane = self.preview.image_pane
        for widget in (self.x_input, self.y_input, self.w_input, self.h_input):
            widget.param.watch(self._on_roi_inputs, "value")

        # a measured EMVA 1288 set has a hundred levels: their list scrolls in a box of its
        # own, so the page's figure stays in the first view whatever the session's size
        self.level_box = pn.Column(self.level_select, height=LEVEL_LIST_HEIGHT, scroll=True,
                                   sizing_mode="stretch_width", css_classes=["ccd-ptc-levels"])
        levels_card = pn.Card(
            pn.pane.Markdown("Untick a level to leave it out; the fit follows at once.",
                             margin=(0, 10)),
            self.level_box, self.all_levels_button, pn.layout.Divider(),
            self.robust_checkbox, self.robust_pane, self.emva_checkbox,
            pn.pane.Markdown(_NAV_NOTE, styles={"font-size": "0.85em", "color": "#6c757d"}),
            title="Levels", width=320, collapsible=False)
        fit_card = pn.Card(self.parameter_table, title="Noise model",
                           sizing_mode="stretch_width", collapsible=False)
        roi_inputs = pn.Column(
            pn.pane.Markdown("Drag a box on the frame (box-select tool) or type the region; "
                             "**Apply ROI** measures the levels again over it.", margin=(0, 10)),
            pn.Row(self.x_input, self.y_input), pn.Row(self.w_input, self.h_input),
            pn.Row(self.apply_roi_button, self.full_frame_button), self.roi_status,
            width=280)
        self.roi_card = pn.Card(
            self.preview_alert,
            pn.Row(pn.Column(self.frame_select, self.preview_pane, sizing_mode="stretch_width"),
                   roi_inputs, sizing_mode="stretch_width"),
            title="Region of interest", sizing_mode="stretch_width", collapsible=False)
        # the verdict, then the figure beside the levels: the first view at 1400 x 900 shows
        # both whatever the number of levels (the parameters follow)
        self.content = pn.Column(
            self.verdict_alert,
            pn.Row(pn.Card(self.plot_tabs, title="Photon-transfer curve",
                           sizing_mode="stretch_width", collapsible=False,
                           css_classes=["ccd-ptc-curve-card"]),
                   levels_card, sizing_mode="stretch_width"),
            fit_card,
            pn.Card(self.points_table, title="Points (one per light level)",
                    sizing_mode="stretch_width"),
            self.roi_card,
            pn.Card(self.notes_pane, title="Notes", sizing_mode="stretch_width"),
            sizing_mode="stretch_width", visible=False)

    # ================================================================== layout =============
    def __panel__(self) -> pn.viewable.Viewable:
        intro = ("The noise variance of a pair of flat frames grows linearly with the mean "
                 "signal, \u03c3\u00b2_N = A\u00b7\u03bc + \u03c3\u00b2_C (Healey & Kondepudy "
                 "1994, eq. 41): the slope A is the gain in DN per electron, the intercept "
                 "\u03c3\u00b2_C holds the read noise and the quantisation noise (eq. 27).")
        return pn.Column(
            *heading("Photon transfer", intro),
            self.info_alert, self.error_alert, self.plan_alert, self.content,
            sizing_mode="stretch_width", name="Photon transfer")

    # ============================================================ session and computing =====
    def _on_session(self, *events: Any) -> None:
        """A new session: forget the old one's points, ROI and choices; compute again."""
        self._session = None
        self.base, self.result, self.roi, self.shape = None, None, None, None
        self._fit_error = ""
        set_choices(self, {"levels": (self.level_select, {}, []),    # one (empty) fit and render
                           "frame": (self.frame_select, [], None)}, points=())
        self._set_error("")
        if self.auto and self.state.session is not None:
            pn.state.execute(self.refresh)

    def _on_results(self, *events: Any) -> None:
        self._show_plan()

    async def refresh(self) -> None:
        """Show the current session: its ptc frames' geometry, then the points and the fit (from
        ``state.results.ptc`` when another page already computed them for the full frame)."""
        session = self._new_session()
        if session is None:
            return
        levels = session.ptc_levels()
        self.roi, self.base, self.result = None, None, None
        if not levels:
            self._info(NO_PTC_MESSAGE)
            self._show_plan()
            return
        self._info("")
        self.content.visible = True
        self._records = {r.relpath: r for recs in levels.values() for r in recs}
        try:
            header = session.header(next(iter(levels.values()))[0])
            self.shape = (int(header.shape[0]), int(header.shape[1]))
        except CcdError as err:
            self.shape = None
            self._set_error(str(err))
        self._reset_roi_inputs(None)
        order = sorted(levels)
        middle = levels[order[len(order) // 2]][0].relpath
        # previewed below, once the points are measured
        set_choices(self, {"frame": (self.frame_select, list(self._records), middle)},
                    trigger=False)
        self._show_plan()
        results = self.state.results
        cached = results.ptc
        if cached is not None and cached.roi is None:
            # another page's fit of the full frame: reuse its points, without its choices
            chosen = cached.robust_dropped or any(p.exclusion == "user" for p in cached.points)
            self._adopt(cached.refit() if chosen else cached, cached.points, None)
            if results.ptc_points is None:
                results.ptc_points = cached.points
        else:
            await self._measure(None)
        if self.state.session is session:
            await self._on_frame()

    async def _measure(self, roi: tuple[int, int, int, int] | None) -> bool:
        """Measure the levels over ``roi`` (frames read in a worker thread) and fit them.

        On a :class:`CcdError` the page keeps showing what it showed and says why; when only the
        fit fails (fewer than three usable levels) the measured levels are still shown.
        """
        session = self.state.session
        if session is None:
            return False
        self.content.loading = True
        try:
            name, params = photon_transfer_entry(roi)
            base = await self.state.cached_compute(name, params, photon_transfer, session,
                                                   roi=roi, label="photon transfer")
            if self.state.session is not session:
                return False
            if base is not None:
                self.state.results.param.update(ptc=base, ptc_points=base.points)
                self._adopt(base, base.points, base.roi)
                return True
            error = self.state.error
            points = await self.state.cached_compute("ptc_points", params, ptc_points,
                                                     session, roi=roi,
                                                     label="photon-transfer points")
            if self.state.session is not session:
                return False
            self.state.error = error
            if points is not None:
                self.state.results.ptc_points = points
            if points is None:  # nothing measurable (bad ROI, unreadable frames ...): keep view
                self._set_error(error)
                return False
            self._adopt(None, points, roi, error)
            return True
        finally:
            self.content.loading = False

    def _adopt(self, base: PhotonTransfer | None, points: Sequence[PtcPoint],
               roi: Sequence[int] | None, error: str = "") -> None:
        """Take new points measured over ``roi`` (and their default fit, ``base``) and refit
        with the user's choices."""
        self.base = base
        self.roi = None if roi is None else tuple(int(v) for v in roi)  # type: ignore[assignment]
        self._reset_roi_inputs(self.roi)
        excluded = self._excluded()
        self._fit_error = error
        options = {_level_label(p): p.level for p in points}
        set_choices(self, {"levels": (self.level_select, options,    # one fit for both
                                      [p.level for p in points if p.level not in excluded])},
                    points=tuple(points))

    def _excluded(self) -> set[int]:
        """Levels the user unticked (kept across ROI changes while the level exists)."""
        return set(self.param.levels.objects) - set(self.levels)

    @param.depends("points", "levels", "robust", "emva_range", watch=True)
    @batched
    def _refit(self) -> None:
        """Fit the measured points again with the ticked levels, the robust mode and the fit
        range (instant: ``PhotonTransfer.refit``, i.e. ``fit_points``; no frame is read)."""
        error, self._fit_error = self._fit_error, ""
        excluded = sorted(self._excluded() & {p.level for p in self.points})
        result: PhotonTransfer | None = None
        if self.base is not None:
            if not excluded and not self.robust and not self.emva_range:
                result = self.base
            else:
                try:
                    result = self.base.refit(
                        exclude_levels=excluded, robust=self.robust,
                        fit_fraction=EMVA_FIT_FRACTION if self.emva_range else None)
                except CcdError as err:
                    error = str(err)
        self.result = result
        self._set_error(error)
        if result is not None:
            self.state.results.ptc = result
        self._render()

    # ============================================================ showing the result =======
    def _display_points(self) -> tuple[PtcPoint, ...]:
        """The points to draw: the fit's, or (no fit) the measured ones with the user's
        exclusions marked as ``fit_points`` would mark them."""
        if self.result is not None:
            return self.result.points
        excluded = self._excluded()
        return tuple(dataclasses.replace(p, used=False, reason=USER_EXCLUDED, exclusion="user")
                     if p.used and p.level in excluded else p for p in self.points)

    def _render(self) -> None:
        result, points = self.result, self._display_points()
        self.figures.update(points, result)
        self.drawn = (points, result)
        self.residual_box.visible = result is not None
        table = ptc_plots.points_table(points, result)
        def fmt(column: str, spec: str) -> list[str]:
            return [format(v, spec) if math.isfinite(v) else "" for v in table[column]]

        shown = pd.DataFrame({
            "level": table["level"], "\u03bc \u2212 b\u2080 (DN)": fmt("mu", ".3f"),
            "\u03c3\u0302\u00b2_N (DN\u00b2)": fmt("var", ".5g"),
            "\u00b1 (DN\u00b2)": fmt("var_err", ".2g"),
            "residual (\u03c3)": fmt("residual", "+.2f"),
            "pairs": table["n_pairs"], "pixels M": table["n_pixels"],
            "status": table["status"], "reason": table["reason"]})
        self.points_table.object = shown
        if result is None:
            self.verdict_alert.visible = False
            self.parameter_table.object = pd.DataFrame(
                columns=["quantity", "symbol", "value", "unit"])
            self.robust_pane.object = ""
            self.notes_pane.object = "No fit."
        else:
            kind, text = verdict_message(result)
            self.verdict_alert.param.update(
                alert_type=kind, object=f"{text}\n\nFit range: {result.fit_range}.",
                visible=True)
            self.parameter_table.object = parameter_frame(result, self.shape)
            if self.robust:
                dropped = result.robust_dropped
                self.robust_pane.object = (
                    "Robust mode dropped " + ", ".join(f"level {lv}" for lv in dropped) + "."
                    if dropped else f"Robust mode dropped no level (every residual within "
                                    f"{ROBUST_Z:g}\u03c3).")
            else:
                self.robust_pane.object = ""
            self.notes_pane.object = "\n".join(f"- {n}" for n in result.notes) or "No notes."
        self.roi_status.object = f"Applied: **{_roi_text(self.roi, self.shape)}**"

    def _show_plan(self) -> None:
        """The acquisition plan's warnings for this session (``estimate_all``'s, computed on
        the Maps page)."""
        est = self.state.results.estimates
        warnings = list(est.plan_warnings) if est is not None and est.plan is not None \
            and self.state.session is not None else []
        self.plan_alert.object = ("**This session has fewer frames than the acquisition plan "
                                  "requires** (see the Maps page):\n\n"
                                  + "\n".join(f"- {w}" for w in warnings)) if warnings else ""
        self.plan_alert.visible = bool(warnings)

    # ============================================================ toggles ==================
    def _on_all_levels(self, event: Any = None) -> None:
        self.levels = [p.level for p in self.points]

    # ============================================================ ROI ======================
    def _pending_roi(self) -> tuple[int, int, int, int]:
        return (int(self.x_input.value), int(self.y_input.value), int(self.w_input.value),
                int(self.h_input.value))

    def _reset_roi_inputs(self, roi: Sequence[int] | None) -> None:
        if roi is None:
            roi = (0, 0, self.shape[1], self.shape[0]) if self.shape else (0, 0, 1, 1)
        x, y, w, h = (int(v) for v in roi)
        self.x_input.value, self.y_input.value = x, y
        self.w_input.value, self.h_input.value = w, h

    def roi_request(self) -> tuple[int, int, int, int] | None:
        """The typed region, or None when it is the full frame."""
        roi = self._pending_roi()
        if self.shape is not None and roi == (0, 0, self.shape[1], self.shape[0]):
            return None
        return roi

    async def apply_roi(self) -> bool:
        """Measure the levels again over the typed region (frames read off the UI thread)."""
        if self.state.session is None or self._session is None:
            return False
        return await self._measure(self.roi_request())

    async def _on_apply_roi(self, event: Any = None) -> None:
        await self.apply_roi()

    async def full_frame(self) -> bool:
        """Back to the whole frame."""
        self._reset_roi_inputs(None)
        if self.roi is None and (self.points or self._session is None):
            return True
        return await self._measure(None)

    async def _on_full_frame(self, event: Any = None) -> None:
        await self.full_frame()

    def _on_bounds(self, bounds: tuple[float, float, float, float] | None = None) -> None:
        """A box drawn on the preview -> the X, Y, W, H inputs: the pixels whose centres (at
        integer coordinates) lie in the box, clipped to the frame, at least one pixel."""
        if bounds is None or self.shape is None:
            return
        h_img, w_img = self.shape
        x0, y0, x1, y1 = bounds
        left = min(max(int(math.ceil(min(x0, x1))), 0), w_img - 1)
        top = min(max(int(math.ceil(min(y0, y1))), 0), h_img - 1)
        right = min(max(int(math.floor(max(x0, x1))) + 1, left + 1), w_img)
        bottom = min(max(int(math.floor(max(y0, y1))) + 1, top + 1), h_img)
        self._reset_roi_inputs((left, top, right - left, bottom - top))

    async def _on_frame(self, event: Any = None) -> None:
        """Show the chosen ptc frame with the ROI box (read in a worker thread): its own pixel
        grid (a raw mosaic as it is, the luminance of colour), read whole or, for a large
        frame, from its pyramid (:mod:`ccdcore_app.tiles`: read by the region)."""
        session, rec = self.state.session, self._records.get(self.frame)
        if session is None or rec is None:
            self.preview.clear()
            return
        read = await self.preview.fetch(session, rec, plane=True, spinner=self.preview_pane)
        if read is None or session is not self.state.session:
            return
        plane, error = read
        if plane is None:
            self.preview.clear()
            self.preview.fail(error)
            return
        self._show_preview(plane, rec.relpath)

    @batched
    def _show_preview(self, plane: np.ndarray | TiledPlane, title: str) -> None:
        """The frame's own pixel grid (luminance of colour), the ROI outlined on it."""
        self.preview.hide_error()
        clim = plots.auto_clim(plane.coarse() if isinstance(plane, TiledPlane) else plane)
        self.preview.show(plane, clim, title)
        self.preview.set_box(self._pending_roi())

    def release(self) -> None:
        """The browser session ended: drop the frame shown (no redraw)."""
        self.preview.release()

    def _on_roi_inputs(self, event: Any = None) -> None:
        self.preview.set_box(self._pending_roi())


def create_page(state: AppState) -> PhotonTransferPage:
    """Registry entry point: the Photon transfer page bound to ``state``."""
    return PhotonTransferPage(state)
