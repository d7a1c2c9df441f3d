"""The Change detection page: illumination-invariant change detection with shadows and a
calibrated false-alarm rate (Tsin, Ramesh & Kanade 2001, sec. 5).

The session's ``reference`` and ``target`` brackets become HDR radiance with per-pixel sigma;
:func:`ccdcore.change.session.session_change` fits the colour transform M of the background (E' = E
M, eq. 20) and of each shade of shadow, computes every pixel's d² under them and labels the pixels
at a chosen false-alarm probability. The page shows the reference, the target and the predicted
target (the reference under the background's new light) tone-mapped for display only, the d²
map and the labels, all with linked zoom and the values under the cursor; the background's d²
against the χ² density (Fig. 6) with the threshold; the clusters' M with their uncertainty.
The false-alarm slider re-thresholds at once (:meth:`ccdcore.change.detector.ChangeResult.at`: M is
not fitted again) by feeding the figures' sources in place.

Public objects
--------------
ChangePage
    The page (a :class:`panel.viewable.Viewer`); its state is declared with ``param``: the
    false-alarm probability ``pfa``, ``overlay`` (labels over the target) and the display
    exposure ``stops``.
create_page(state)
    The registry entry point.
compute_change(session, options, progress)
    :func:`ccdcore.change.session.session_change` with the app's progress tracker.
PFA_STEPS
    The slider's false-alarm probabilities (label -> value), log-spaced 1e-4 ... 0.2.
no_brackets_message(missing)
    What the page says when the session lacks the reference or target bracket.

Computing runs off the UI thread (:meth:`ccdcore_app.state.AppState.compute`); the result is cached
in ``state.results.change`` by the detector's options. The estimation lives in
:mod:`ccdcore.change.detector`; this page only shows it.
"""
from __future__ import annotations

import html
from typing import Any

import numpy as np
import pandas as pd
import panel as pn
import param

from ccdcore.change.detector import (LABEL_CHANGE, LABEL_SHADE, LABEL_UNDETERMINED, ChangeInputs,
                                     ChangeOptions, ChangeResult)
from ccdcore.change.session import session_change
from ccdcore.common import format_pm
from ccdcore.progress import Progress
from ccdcore.session import Session

from ..batch import batched, in_document
from ..plots.change import (D2Histogram, RgbView, label_colour, label_name, label_rgb,
                            log_colours, tone_map_rgb, white_point)
from ..image_view import ImageView, view_pane
from ..state import AppState
from ._messages import PageMessages
from ._styles import KEY_VALUE_CSS, TABLE_CSS, heading, progress_row

__all__ = ["ChangePage", "create_page", "compute_change", "PFA_STEPS", "no_brackets_message"]

_MUTED = {"font-size": "0.88em", "color": "#6c757d"}
IMAGE_WIDTH = 330
#: the slider's false-alarm probabilities: 1-2-5 steps, 1e-4 ... 0.2
PFA_STEPS = {f"{v:g}": v for v in (1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 0.01, 0.02, 0.05, 0.1,
                                   0.2)}
DEFAULT_PFA = 0.01

_LEGEND_CSS = """
table { border-collapse: collapse; font-size: 0.95em; }
td { padding: 3px 8px; border-bottom: 1px solid #eef0f2; white-space: nowrap; }
td.n { text-align: right; font-variant-numeric: tabular-nums; }
.sw { display: inline-block; width: 14px; height: 14px; border-radius: 3px;
      border: 1px solid rgba(0,0,0,0.25); vertical-align: middle; }
"""


def no_brackets_message(missing: list[str]) -> str:
    """What the page says when the session has no ``missing`` role(s): with neither, what to
    capture (an info, as the other pages say it); with one of the two, what is missing."""
    what = ("a reference and a target of one fixed camera under different light: one frame "
            "each, a few frames each (their spread gives the noise) or two exposure brackets, "
            "as folders `reference/` and `target/` or frames of those roles in `session.toml`. "
            "The bundled **change** demo has both.")
    if len(missing) > 1:
        return f"No reference or target frames in this session. Change detection compares {what}"
    return (f"This session has '{'target' if missing[0] == 'target' else 'reference'}' frames "
            f"missing, so there is nothing to compare. Change detection compares {what}")


def page_options(session: Session) -> ChangeOptions:
    """The page's settings: P = :data:`DEFAULT_PFA`, and for single frames or frame sets
    (:func:`ccdcore.change.frames.role_kind`) the smallest changed region of the CLI's default
    (:data:`ccdcore.change.frames.FRAME_MIN_REGION`); a role that is neither is left to
    :func:`compute_change` to report."""
    from ccdcore.change.frames import FRAME_MIN_REGION, role_kind
    from ccdcore.errors import CcdError

    try:
        kinds = [role_kind(session.by_role(r)) for r in ("reference", "target")
                 if hasattr(session, "by_role") and session.by_role(r)]
    except CcdError:
        kinds = []
    return ChangeOptions(pfa=DEFAULT_PFA, min_region=FRAME_MIN_REGION if "frames" in kinds
                         else 1)


def compute_change(session: Session, options: ChangeOptions | None = None,
                   progress: Progress | None = None) -> tuple[ChangeResult, dict[str, Any]]:
    """:func:`ccdcore.change.session.session_change` reporting to ``progress`` (the app's
    :class:`ccdcore.progress.Tracker`, which also stops it when cancelled); single frames or
    frame sets of either role go through :func:`ccdcore.change.frames.frames_change`."""
    return session_change(session, options or page_options(session), progress=progress)


def _table(css_class: str) -> pn.pane.DataFrame:
    return pn.pane.DataFrame(pd.DataFrame(), index=False, sizing_mode="stretch_width",
                             escape=True, css_classes=[css_class], stylesheets=[TABLE_CSS])


def _percent(p: float) -> str:
    if not np.isfinite(p):
        return "n/a"
    return f"{100 * p:.3g} %"


# ----------------------------------------------------------------------------- the page -------
class ChangePage(PageMessages, pn.viewable.Viewer):
    """Change and shadow labels between the loaded session's reference and target brackets."""

    state = param.ClassSelector(class_=AppState, doc="The app state shared by all pages.")
    pfa = param.Selector(default=DEFAULT_PFA, objects=PFA_STEPS, doc=(
        "Requested false-alarm probability per background pixel: the threshold on d² is the "
        "background's 1 - P quantile. Moving it re-thresholds without fitting M again."))
    overlay = param.Boolean(default=True, doc=(
        "Draw the labels over the target (grey); otherwise the labels alone."))
    stops = param.Number(default=0.0, bounds=(-4.0, 4.0), step=0.5, doc=(
        "Display exposure of the pictures, in stops (the radiance is not changed)."))

    def __init__(self, state: AppState | None = None, *, auto: bool = True, **params: Any):
        super().__init__(state=state if state is not None else AppState(), **params)
        self.auto = auto
        self._doc = pn.state.curdoc
        self._session: Session | None = None
        self._computing = False
        self.result: ChangeResult | None = None
        self.inputs: ChangeInputs | None = None
        self.labels: np.ndarray | None = None
        self.threshold: float = float("nan")
        self.counts: dict[int, int] = {}
        self._pictures: dict[str, np.ndarray] = {}
        self.error = ""
        self._build()
        self.state.param.watch(self._on_session, "session")
        self.state.param.watch(self._on_progress, ["progress", "status"])
        self._show_empty()
        if auto and self.state.session is not None:
            pn.state.execute(self.refresh)

    # ------------------------------------------------------------------------ building ----
    def _build(self) -> None:
        self._build_alerts("change")
        self.progress_bar, self.progress_text, self.progress_row = progress_row("ccd-change-progress")
        self.retry_button = pn.widgets.Button(label="Detect changes again", visible=False,
                                              width=200, css_classes=["ccd-change-retry"])
        self.retry_button.on_click(lambda event: pn.state.execute(self.refresh))
        # controls
        self.pfa_slider = pn.widgets.DiscreteSlider.from_param(
            self.param.pfa, name="False-alarm probability P (re-thresholds, M kept)",
            width=330, css_classes=["ccd-change-pfa"])
        self.overlay_box = pn.widgets.Checkbox.from_param(
            self.param.overlay, name="Labels over the target (grey)")
        self.stops_slider = pn.widgets.FloatSlider.from_param(
            self.param.stops, name="Display exposure of the pictures (stops)", width=330)
        # readouts
        number = dict(font_size="22pt", title_size="10pt", margin=(0, 18, 0, 0),
                      sizing_mode="fixed", width=170, height=70)
        self.count_number = pn.indicators.Number(label="Changed pixels", value=0,
                                                 format="{value:,}",
                                                 css_classes=["ccd-change-count"], **number)
        self.threshold_number = pn.indicators.Number(label="Threshold on d²", value=0.0,
                                                     format="{value:.2f}",
                                                     css_classes=["ccd-change-threshold"],
                                                     **number)
        self.observed_number = pn.indicators.Number(label="Observed false alarms", value=0.0,
                                                    format="{value:.2%}",
                                                    css_classes=["ccd-change-observed"],
                                                    **number)
        self.legend = pn.pane.HTML("", stylesheets=[_LEGEND_CSS], sizing_mode="stretch_width",
                                   css_classes=["ccd-change-legend"])
        self.details = pn.pane.Markdown("", sizing_mode="stretch_width",
                                        stylesheets=[KEY_VALUE_CSS],
                                        css_classes=["ccd-change-details"])
        # images: labels, reference, target, predicted target, d²; zoom linked
        common = dict(frame_width=IMAGE_WIDTH, max_frame_height=IMAGE_WIDTH)
        self.labels_view = RgbView(title="Labels", css_classes=["ccd-change-labels"], **common)
        self.ref_view = RgbView(title="Reference", link=self.labels_view,
                                css_classes=["ccd-change-reference"], **common)
        self.tgt_view = RgbView(title="Target", link=self.labels_view,
                                css_classes=["ccd-change-target"], **common)
        self.pred_view = RgbView(title="Predicted target: reference × M (background)",
                                 link=self.labels_view, css_classes=["ccd-change-predicted"],
                                 **common)
        self.d2_view = ImageView(title="d² under the best cluster", cmap="magma", label="d²",
                                 symbol="d²", link=self.labels_view,
                                 css_classes=["ccd-change-d2"], **common)
        log_colours(self.d2_view)
        self.views = (self.labels_view, self.ref_view, self.tgt_view, self.pred_view,
                      self.d2_view)
        for view in self.views:
            view.on_pointer = self._on_pointer
        self.labels_pane, self.ref_pane, self.tgt_pane, self.pred_pane, self.d2_pane = (
            view_pane(v) for v in self.views)
        self.readout = pn.pane.Markdown("Move the cursor over an image to read the radiance, "
                                        "d² and the label of a pixel.",
                                        sizing_mode="stretch_width", styles=_MUTED,
                                        css_classes=["ccd-change-readout"])
        self.pictures_note = pn.pane.Markdown("", sizing_mode="stretch_width", styles=_MUTED)
        # the threshold (Fig. 6) and the clusters
        self.hist = D2Histogram(css_classes=["ccd-change-hist"])
        self.hist_note = pn.pane.Markdown("", sizing_mode="stretch_width", styles=_MUTED)
        self.cluster_table = _table("ccd-change-clusters")
        self.cluster_note = pn.pane.Markdown("", sizing_mode="stretch_width", styles=_MUTED)
        self.notes_pane = pn.pane.Markdown("", sizing_mode="stretch_width", styles=_MUTED)

        controls = pn.Column(
            self.pfa_slider,
            pn.Row(self.count_number, self.threshold_number, self.observed_number,
                   margin=(6, 10)),
            self.legend, self.overlay_box, self.stops_slider,
            sizing_mode="stretch_width")
        self.content = pn.Column(
            pn.Card(pn.Row(self.labels_pane, controls, sizing_mode="stretch_width"),
                    self.readout,
                    pn.Row(self.ref_pane, self.tgt_pane),
                    pn.Row(self.pred_pane, self.d2_pane),
                    self.pictures_note,
                    title="Labels, reference, target and predicted target (linked zoom)",
                    sizing_mode="stretch_width", collapsible=False),
            pn.Card(pn.Row(pn.Column(pn.pane.Bokeh(self.hist.fig, sizing_mode="stretch_width"),
                                     self.hist_note, sizing_mode="stretch_width"),
                           pn.Column(self.details, width=430, margin=(0, 0, 0, 10)),
                           sizing_mode="stretch_width"),
                    title="The threshold: the background's d² against χ² (Fig. 6)",
                    sizing_mode="stretch_width", collapsible=False),
            pn.Card(self.cluster_table, self.cluster_note,
                    title="Colour transform M of each cluster (E′ = E M, eq. 20)",
                    sizing_mode="stretch_width", collapsible=False),
            pn.Card(self.notes_pane, title="Notes", sizing_mode="stretch_width",
                    collapsed=True),
            sizing_mode="stretch_width", visible=False)

    def __panel__(self) -> pn.viewable.Viewable:
        intro = ("Two exposure brackets of a static scene under different light: the reference "
                 "and the target. Every surface lit by one source obeys one colour transform "
                 "E′ = E M (Tsin, Ramesh & Kanade 2001, sec. 5): the background obeys one M, "
                 "each shade of shadow another, new objects none. A pixel whose prediction "
                 "error d² (χ² with one degree of freedom per channel) exceeds the threshold "
                 "under every cluster is a change; the threshold gives the chosen false-alarm "
                 "probability on the background.")
        return pn.Column(
            *heading("Change detection", intro),
            self.info_alert, self.error_alert, self.retry_button, self.progress_row,
            self.content,
            sizing_mode="stretch_width", name="Change detection")

    # ------------------------------------------------------------------------ events ------
    def on_show(self) -> None:
        """Called by the navigation each time it shows the page: compute when not yet done
        (a cancelled computation starts again)."""
        if self.auto and self.state.session is not None and self._session is None \
                and not self._computing:
            pn.state.execute(self.refresh)

    def _on_session(self, *events: Any) -> None:
        self._session = None
        self.result = None
        self.inputs = None
        self.labels = None
        if self.auto:
            pn.state.execute(self.refresh)

    def _on_progress(self, *events: Any) -> None:
        if self._computing and self.state.busy:
            p = self.state.progress
            self.progress_bar.param.update(value=p if p >= 0 else -1, active=p < 0)
            self.progress_text.object = html.escape(self.state.status)

    @param.depends("pfa", "overlay", watch=True)
    def _on_pfa(self) -> None:
        self._render_labels()

    @param.depends("stops", watch=True)
    def _on_stops(self) -> None:
        self._render_pictures()
        self._render_labels()

    def release(self) -> None:
        """The browser session ended: drop the arrays (nothing is redrawn)."""
        for view in self.views:
            view.release()
        self.result = self.inputs = self.labels = None
        self._pictures = {}

    # ------------------------------------------------------------------------ computing ---
    @property
    def _cache(self) -> dict:
        return self.state.results.change

    async def refresh(self) -> None:
        """Detect the changes between the session's reference and target brackets (cached),
        then show them."""
        session = self._new_session(busy=self._computing)
        if session is None:
            return
        self._info("")
        self.retry_button.visible = False
        missing = [role for role in ("reference", "target") if not session.bracket_stacks(role)]
        if missing:
            self.content.visible = False
            if len(missing) > 1:          # a session of another kind: what to capture
                self._info(no_brackets_message(missing))
            else:                         # half a change session: an error
                self._set_error(no_brackets_message(missing))
            return
        self.content.visible = True
        options = page_options(session)
        entry = self._cache.get(options)
        if entry is None:
            self._computing = True
            self.progress_text.object = "Computing the radiance of both brackets and the " \
                                        "colour transforms ..."
            self.progress_bar.param.update(value=-1, active=True)
            self.progress_row.visible = True
            self.content.loading = True
            try:
                entry = await self.state.compute(compute_change, session, options,
                                                 label="change detection", pass_progress=True)
            finally:
                self._computing = False
                self.content.loading = False
                self.progress_row.visible = False
            if self.state.session is not session:   # another session was opened meanwhile
                if self.auto:
                    await self.refresh()
                return
            if entry is None:
                self._session = None          # computed again on the next visit or on demand
                self.content.visible = False
                self._set_error(self.state.error or "change detection was cancelled.")
                self.retry_button.visible = True
                return
            self._cache[options] = entry
        self.result, self.inputs = entry
        in_document(self._doc, self._render_result)

    # ------------------------------------------------------------------------ rendering ---
    @batched
    def _render_result(self) -> None:
        res, inputs = self.result, self.inputs
        if res is None or inputs is None:
            return
        self._render_pictures(reset=True)
        d2 = res.d2_best
        finite = d2[np.isfinite(d2) & (d2 > 0)]
        thr_low = res.threshold_for(min(PFA_STEPS.values()))
        top = max(float(np.percentile(finite, 99.5)) if finite.size else 1.0, 10 * thr_low)
        low = max(float(np.percentile(finite, 0.5)) if finite.size else 0.01, 1e-3)
        self.d2_view.show(d2, clim=(low, top), how="max", reset=False)
        self.d2_pane.visible = True
        x_max = 1.05 * max(float(res.background[-1]) if res.background.size else 1.0,
                           thr_low, res.chi2_threshold(min(PFA_STEPS.values())))
        self.hist.show(res.background, res.dof, res.scale, x_max, res.threshold,
                       res.chi2_threshold())
        ch = list(inputs.channels)
        self.pictures_note.object = (
            "The pictures are tone-mapped for display only (gamma 2.2, one white point for all "
            "three). The predicted target is the reference under the background's new light "
            "(E M with the background's M): where it matches the target, nothing changed. d² is "
            "drawn on a logarithmic colour scale (the largest value of each block when zoomed "
            f"out). Channels: {', '.join(ch) or 'one'}.")
        self.hist_note.object = (
            f"The d² of the background's pixels ({res.background.size:,} in the calibration "
            f"sample) against the χ² density with {res.dof} degrees of freedom, which d² "
            "follows when the model and the noise terms are right; the dashed curve is χ² "
            "scaled by s, the background's median d² over χ²'s. The threshold (solid orange "
            "line) is the sample's 1 - P quantile; the bars beyond it are the background's "
            "false alarms. The dotted line is the plain χ² quantile.")
        kinds = ", ".join(f"{role} {'frames' if k == 'frames' else 'bracket'}"
                          for role, k in inputs.kinds.items())
        notes = [(f"- Response: {inputs.source} "
                  f"({len(inputs.files)} frames{'; ' + kinds if kinds else ''})"),
                 f"- Noise: {inputs.noise or 'not stated'}",
                 (f"- The clusters were fitted at P = {res.pfa:g}; the slider re-thresholds "
                  "the same clusters (`ChangeResult.at`), it does not fit M again.")]
        notes += [f"- {n}" for n in res.notes]
        self.notes_pane.object = "\n".join(notes)
        self._render_labels()

    @batched
    def _render_pictures(self, reset: bool = False) -> None:
        res, inputs = self.result, self.inputs
        if res is None or inputs is None:
            return
        white = white_point(inputs.E_ref, inputs.E_tgt)
        self._pictures = {
            "reference": tone_map_rgb(inputs.E_ref, white, self.stops),
            "target": tone_map_rgb(inputs.E_tgt, white, self.stops),
            "predicted": tone_map_rgb(res.predicted, white, self.stops)}
        for view, name in ((self.ref_view, "reference"), (self.tgt_view, "target"),
                           (self.pred_view, "predicted")):
            view.show_rgb(self._pictures[name], reset=reset)
        self.ref_pane.visible = self.tgt_pane.visible = self.pred_pane.visible = True

    @batched
    def _render_labels(self) -> None:
        """Labels, counts, legend, readouts, the histogram's threshold and the cluster table
        at the chosen false-alarm probability (the clusters' M kept)."""
        res = self.result
        if res is None:
            return
        pfa = float(self.pfa)
        labels, thr = res.at(pfa)
        self.labels, self.threshold = labels, thr
        self.counts = counts = res.counts(labels)
        base = self._pictures.get("target") if self.overlay else None
        self.labels_view.show_rgb(label_rgb(labels, base), reset=False,
                                  title=f"Labels at P = {pfa:g}")
        self.labels_pane.visible = True
        n_change = int(counts.get(LABEL_CHANGE, 0))
        observed = res.observed_pfa(thr)
        self.count_number.value = n_change
        self.threshold_number.value = float(thr)
        self.observed_number.value = float(observed) if np.isfinite(observed) else 0.0
        self.legend.object = self._legend_html(counts, labels.size)
        chi_thr = res.chi2_threshold(pfa)
        self.hist.set_threshold(thr, chi_thr)
        empirical = res.background.size >= 20.0 / pfa
        how = (f"the background sample's {100 * (1 - pfa):.4g} % quantile" if empirical else
               f"s · χ² quantile (the sample of {res.background.size:,} is too small for "
               f"P = {pfa:g}: it needs 20 / P)")
        rows = [
            ("Requested false-alarm probability P", f"{pfa:g}"),
            ("Threshold on d²", f"{thr:.4g}: {how}"),
            ("Observed false-alarm rate at the threshold",
             f"{_percent(observed)} of the background sample"),
            (f"χ² threshold ({res.dof} degrees of freedom)", f"{chi_thr:.4g}"),
            ("Observed false-alarm rate at the χ² threshold",
             _percent(res.observed_pfa(chi_thr))),
            ("Scale s of the background's d²", f"{res.scale:.4g}"),
            ("Changed pixels", (f"{n_change:,} of {labels.size:,} "
                                f"({_percent(n_change / max(labels.size, 1))})")),
            ("Shadow pixels (further clusters)",
             f"{sum(n for k, n in counts.items() if 0 < k < LABEL_SHADE):,}"),
            ("Shade pixels (the background's light times one factor)",
             "not tested (mono frames or --shade off)" if res.shade is None else
             f"{int(counts.get(LABEL_SHADE, 0)):,}, factor {res.shade[0]:g}-{res.shade[1]:g}"),
            ("Undetermined pixels", f"{int(counts.get(LABEL_UNDETERMINED, 0)):,}"),
        ]
        self.details.object = "| | |\n|---|---|\n" + "\n".join(
            f"| {k} | {v} |" for k, v in rows)
        self.cluster_table.object = self._cluster_frame(counts)
        self.cluster_note.object = (
            "Row vectors: the target's radiance E′ = E M; row *k* of M says how much of the "
            "reference's channel *k* goes into each channel of the target. ± one standard "
            "deviation, √diag of M's covariance (the M-estimator's sandwich). Pixels: members "
            f"at P = {pfa:g}; median d²: of the members at the fit's threshold.")

    def _legend_html(self, counts: dict[int, int], total: int) -> str:
        res = self.result
        shown = [c.label for c in res.clusters] + [LABEL_CHANGE]
        if counts.get(LABEL_SHADE, 0):
            shown.insert(-1, LABEL_SHADE)
        if counts.get(LABEL_UNDETERMINED, 0):
            shown.append(LABEL_UNDETERMINED)
        rows = []
        for lab in shown:
            n = int(counts.get(lab, 0))
            colour = label_colour(lab)
            if lab == 0 and self.overlay:
                name = "unchanged (background, the target in grey)"
            else:
                name = label_name(lab)
            rows.append(f"<tr class='ccd-label-{lab}'><td><span class='sw' "
                        f"style='background:{colour}'></span></td><td>{html.escape(name)}"
                        f"</td><td class='n'>{n:,}</td><td class='n'>"
                        f"{100 * n / max(total, 1):.2f} %</td></tr>")
        return ("<table><tr><td></td><td><b>label</b></td><td class='n'><b>pixels</b></td>"
                "<td class='n'><b>share</b></td></tr>" + "".join(rows) + "</table>")

    def _cluster_frame(self, counts: dict[int, int]) -> pd.DataFrame:
        res, inputs = self.result, self.inputs
        names = list(inputs.channels) if inputs is not None else []
        rows = []
        for c in res.clusters:
            C = c.M.shape[0]
            ch = names if len(names) == C else [str(k + 1) for k in range(C)]
            err = np.sqrt(np.clip(np.diag(c.M_cov), 0, None)).reshape(c.M.shape)
            for k in range(C):
                row = {"cluster": label_name(c.label) if k == 0 else "",
                       "pixels": f"{int(counts.get(c.label, 0)):,}" if k == 0 else "",
                       "median d²": f"{c.d2_median:.3g}" if k == 0 else "",
                       "from": ch[k]}
                for j in range(C):
                    row[f"→ {ch[j]}′"] = format_pm(float(c.M[k, j]), float(err[k, j]))
                rows.append(row)
        return pd.DataFrame(rows)

    def _on_pointer(self, x: float, y: float) -> None:
        res, inputs = self.result, self.inputs
        if res is None or inputs is None or self.labels is None:
            return
        if not (np.isfinite(x) and np.isfinite(y)):
            return
        col, row = int(round(x)), int(round(y))
        H, W = self.labels.shape
        if not (0 <= row < H and 0 <= col < W):
            return

        def vec(a: np.ndarray) -> str:
            v = np.atleast_1d(np.asarray(a, np.float64))
            return "(" + ", ".join(f"{e:.4g}" for e in v) + ")"

        lab = int(self.labels[row, col])
        d2 = res.d2[row, col]
        best = int(np.argmin(d2)) if np.all(np.isfinite(d2)) else None
        d2_text = ("undetermined" if best is None else
                   f"{float(res.d2[row, col, 0]):.4g} under the background"
                   + (f", best {float(d2[best]):.4g} ({label_name(res.clusters[best].label)})"
                      if best else ""))
        self.readout.object = (
            f"pixel (row {row}, col {col}): reference E = {vec(inputs.E_ref[row, col])}, "
            f"target E′ = {vec(inputs.E_tgt[row, col])}, predicted E M = "
            f"{vec(res.predicted[row, col])}; d² = {d2_text}; label: **{label_name(lab)}**")


def create_page(state: AppState) -> ChangePage:
    """Registry entry point: the Change detection page bound to ``state``."""
    return ChangePage(state)
