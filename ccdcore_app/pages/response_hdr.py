"""The Response & HDR page: inverse response curves, noise terms and HDR radiance with sigma.

Tsin, Ramesh & Kanade 2001 (sec. 3): the inverse response g per channel by the iterative
estimator of sec. 3.2 (:mod:`ccdcore.response.tsin`) and the classic methods beside it
(:mod:`ccdcore.response.classic`; one registry, :data:`ccdcore.response.methods.METHODS`), with
their bands; the noise terms σ_s, σ_c1, σ_c2 of eq. 17; the prediction errors of one pool before
and after calibration (Fig. 3c-d); how well each method's curves predict the bracket's own images
(sec. 4.2, :mod:`ccdcore.response.agreement`: pooled per method, per pair of neighbouring
images for the chosen one), with a warning when the chosen result is not to be trusted; the HDR
radiance of the bracket (eqs. 9, 18) with its per-pixel sigma (eq. 19), tone-mapped for display
only, with linked zoom and the value ± sigma under the cursor.

Public objects
--------------
ResponsePage
    The page (a :class:`panel.viewable.Viewer`); its state is declared with ``param``: method,
    channel, compare (overlay every method), tone curve and display exposure, blooming radius.
create_page(state)
    The registry entry point.
compute_responses(session, bloom_radius, progress)
    Every method on the session's first bracket (a dict method -> ResponseResult).
compute_hdr(session, result, bloom_radius)
    The HDR merge of the bracket with one method's calibration.
untrusted_reason(result, others)
    Why a method's result is not to be trusted (not converged, or predicting its bracket much
    worse than the best method), or None.
NO_BRACKET_MESSAGE
    What the page says when the session has no bracket.

Computing runs off the UI thread, once per server: :meth:`ccdcore_app.state.AppState.shared_compute`
keys the responses (and each method's HDR) by the session's content hash and the options, so a
second browser tab on the same session waits for the first one's computation instead of
starting its own; the responses are also kept in the disk cache. Each browser session keeps
what it shows in ``state.results.response`` by blooming radius and white balance. Widget
changes feed the figures' sources in place (:mod:`ccdcore_app.response_plots`,
:class:`ccdcore_app.image_view.ImageView`).
"""
from __future__ import annotations

from typing import Any, Iterable, Mapping

import numpy as np
import pandas as pd
import panel as pn
import param

from ccdcore.common import format_pm
from ccdcore.errors import CcdError
from ccdcore.progress import Progress, within
from ccdcore.response.brackets import DEFAULT_BLOOM_RADIUS, bracket_records, load_bracket
from ccdcore.response.hdr import FLAG_OK, HdrResult, merge
from ccdcore.response.methods import METHODS, ResponseResult, response_of
from ccdcore.session import Session
from ccdcore.simulate.truth import find_truth

from ..batch import batched, in_document
from ..image_view import view_pane
from ..response_plots import (TONE_CURVES, PoolHistogram, ResponseFigure, agreement_rows, dn,
                              hdr_planes, hdr_views, pair_rows)
from ..state import AppState
from ._choices import set_choices
from ._messages import PageMessages
from ._styles import TABLE_CSS, heading

__all__ = ["ResponsePage", "create_page", "compute_responses", "compute_hdr",
           "untrusted_reason", "NO_BRACKET_MESSAGE", "TRUST_FACTOR", "RESPONSES_ENTRY",
           "HDR_ENTRY"]

NO_BRACKET_MESSAGE = (
    "**No exposure bracket in this session.** Photograph a static scene at several exposure "
    "times (e.g. 8 exposures a factor of 1.4 apart, from the shortest that keeps the "
    "highlights to the longest that shows the shadows; camera on a tripod, fixed aperture, "
    "focus and white balance) and list the frames in `session.toml` with `role = \"bracket\"` "
    "and `exposure` in seconds (a `stack = N` per bracket when there are several). The "
    "bundled **tsin01** demo has one.")

_MUTED = {"font-size": "0.88em", "color": "#6c757d"}
IMAGE_WIDTH = 330
LABELS = {name: m.label for name, m in METHODS.items()}
#: a result whose agreement RMS exceeds the best method's by this factor is not trusted
TRUST_FACTOR = 1.5
#: the names the responses and the HDR are shared (and cached) under, with the options
RESPONSES_ENTRY = "response_curves"
HDR_ENTRY = "response_hdr"


def untrusted_reason(result: ResponseResult,
                     others: Iterable[ResponseResult] | Mapping[str, ResponseResult]
                     ) -> str | None:
    """Why ``result`` is not to be trusted, as one sentence, or None.

    For now: a channel whose estimate did not converge, or a prediction agreement
    (``result.agreement.rms``, sec. 4.2) more than :data:`TRUST_FACTOR` times the best of
    ``others`` (the other methods' results on the same bracket; ``result`` may be among them).
    """
    if isinstance(others, Mapping):
        others = others.values()
    reasons = []
    stuck = [c.channel for c in result.responses if not c.converged]
    if stuck:
        reasons.append(f"it did not converge (channel{'s' if len(stuck) > 1 else ''} "
                       f"{', '.join(stuck)})")

    def rms(r: ResponseResult) -> float | None:
        a = r.agreement
        return float(a.rms) if a is not None and np.isfinite(a.rms) else None

    own = rms(result)
    scored = [(v, r) for r in (*others, result) if (v := rms(r)) is not None]
    if own is not None and scored:
        best, best_result = min(scored, key=lambda vr: vr[0])
        if own > TRUST_FACTOR * best:
            times = f"{own / best:.1f}\u00d7" if best > 0 else "more than"
            reasons.append(f"it predicts the bracket's images within {own:.2f} DN RMS, {times} "
                           f"the best method's {best:.2f} DN "
                           f"({LABELS.get(best_result.method, best_result.method)})")
    # the library's own checks (collapsed curves, exposures the images disagree with)
    reasons += [w for w in result.warnings() if "without converging" not in w]
    if not reasons:
        return None
    return (f"{LABELS.get(result.method, result.method)}'s curves may not be trustworthy: "
            + "; ".join(reasons) + ".")


# ----------------------------------------------------------------------------- computing ------
def compute_responses(session: Session, bloom_radius: int = DEFAULT_BLOOM_RADIUS,
                      progress: Progress | None = None,
                      white_balance: bool = False) -> dict[str, ResponseResult]:
    """Every method of the registry on the session's first bracket (the methods that can,
    with the white-balance gains when ``white_balance``); each method takes an equal part of
    ``progress``."""
    brackets = load_bracket(session, bloom_radius=bloom_radius)
    out: dict[str, ResponseResult] = {}
    names = list(METHODS)
    for i, name in enumerate(names):
        sub = within(progress, i / len(names), (i + 1) / len(names),
                     prefix=f"{LABELS[name]}: ")
        out[name] = response_of(brackets, name, progress=sub, bloom_radius=bloom_radius,
                                white_balance=white_balance and METHODS[name].white_balance)
    return out


def compute_hdr(session: Session, result: ResponseResult,
                bloom_radius: int = DEFAULT_BLOOM_RADIUS) -> HdrResult:
    """The bracket merged with ``result``'s calibration (eqs. 9, 18, 19)."""
    frames = [session.read(r) for r in bracket_records(session)]
    return merge(frames, result.models(), layout=session.camera.layout,
                 bloom_radius=bloom_radius)


def _true_g(session: Session) -> np.ndarray | None:
    """The simulator's g (``truth.json``), when the session has one and it fits."""
    try:
        truth = find_truth(session)
    except CcdError:
        return None
    if truth is None or "g" not in truth:
        return None
    g = np.asarray(truth["g"], np.float64)
    return g if g.ndim == 1 else None


def _table(css_class: str) -> pn.pane.DataFrame:
    return pn.pane.DataFrame(pd.DataFrame(), index=False, sizing_mode="stretch_width",
                             escape=True, css_classes=[css_class], stylesheets=[TABLE_CSS])


# ----------------------------------------------------------------------------- the page -------
class ResponsePage(PageMessages, pn.viewable.Viewer):
    """Response curves, noise and HDR radiance of the loaded session's bracket."""

    state = param.ClassSelector(class_=AppState, doc="The app state shared by all pages.")
    method = param.Selector(default="tsin", objects={m.label: k for k, m in METHODS.items()},
                            doc="The method whose curve, band, noise and HDR are shown.")
    channel = param.Selector(default="L", objects=["L"], doc="Channel (or CFA plane) shown.")
    compare = param.Boolean(default=True, doc="Overlay every method's curve.")
    tone = param.Selector(default="gamma 2.2", objects=list(TONE_CURVES),
                          doc="Display curve of the HDR radiance (the data are not changed).")
    stops = param.Number(default=0.0, bounds=(-6.0, 6.0), step=0.5,
                         doc="Display exposure of the HDR radiance, in stops.")
    white_balance = param.Boolean(default=False, doc=(
        "Estimate each image's gain a_k and offset b_k (white balance, exposure errors) by "
        "sec. 3.2, up to a common factor and a trend in the exposure that no bracket fixes. "
        "The classic methods take the nominal times."))
    bloom_radius = param.Integer(default=DEFAULT_BLOOM_RADIUS, bounds=(0, 10), doc=(
        "Pixels within this radius of a saturated pixel are dropped as blooming (sec. 2); 0 "
        "keeps them (for scenes without bright areas, e.g. simulated per-pixel radiance)."))

    def __init__(self, state: AppState | None = None, *, auto: bool = True, **params: Any):
        super().__init__(state=state if state is not None else AppState(), **params)
        self.auto = auto
        self._doc = pn.state.curdoc
        self._session: Session | None = None
        self.responses: dict[str, ResponseResult] | None = None
        self.hdr: HdrResult | None = None
        self._truth: np.ndarray | None = None
        self.error = ""
        self._build()
        self.state.param.watch(self._on_session, "session")
        self._show_empty()
        if auto and self.state.session is not None:
            pn.state.execute(self.refresh)

    # ------------------------------------------------------------------------ building ----
    def _build(self) -> None:
        self._build_alerts("response")
        self.warning_alert = pn.pane.Alert("", alert_type="warning", visible=False,
                                           sizing_mode="stretch_width",
                                           css_classes=["ccd-response-warning"])
        self.method_select = pn.widgets.RadioButtonGroup.from_param(
            self.param.method, color="default", css_classes=["ccd-response-method"])
        self.channel_select = pn.widgets.RadioButtonGroup.from_param(
            self.param.channel, color="default", visible=False)
        self.compare_box = pn.widgets.Checkbox.from_param(self.param.compare,
                                                          name="Overlay all methods")
        self.bloom_input = pn.widgets.IntInput.from_param(self.param.bloom_radius,
                                                          name="Blooming radius (px)", width=150)
        self.wb_box = pn.widgets.Checkbox.from_param(
            self.param.white_balance, name="Estimate white balance a_k, b_k (sec. 3.2)")
        self.curves = ResponseFigure(list(METHODS), LABELS)
        self.pool_hist = PoolHistogram()
        self.curve_note = pn.pane.Markdown("", sizing_mode="stretch_width", styles=_MUTED)
        self.noise_table = _table("ccd-response-noise")
        self.ab_table = _table("ccd-response-ab")
        self.pool_note = pn.pane.Markdown("", sizing_mode="stretch_width", styles=_MUTED)
        self.notes_pane = pn.pane.Markdown("", sizing_mode="stretch_width", styles=_MUTED)
        self.agreement_table = _table("ccd-response-agreement")
        self.pairs_note = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.pairs_table = _table("ccd-response-pairs")
        # HDR: radiance (tone-mapped) and relative sigma, zoom linked, value ± sigma read out
        self.rad_view, self.sig_view = hdr_views(IMAGE_WIDTH,
                                                 ("ccd-hdr-radiance", "ccd-hdr-sigma"))
        for view in (self.rad_view, self.sig_view):
            view.on_pointer = self._on_pointer
        self.tone_select = pn.widgets.RadioButtonGroup.from_param(self.param.tone,
                                                                  color="default")
        self.stops_slider = pn.widgets.FloatSlider.from_param(self.param.stops,
                                                              name="Display exposure (stops)",
                                                              width=260)
        self.readout = pn.pane.Markdown("Move the cursor over either image to read the radiance "
                                        "and its sigma.", sizing_mode="stretch_width",
                                        css_classes=["ccd-hdr-readout"])
        self.hdr_note = pn.pane.Markdown("", sizing_mode="stretch_width", styles=_MUTED)
        # each view in a Column shown once it has data (``visible`` on a Bokeh pane fails)
        self.rad_pane = view_pane(self.rad_view)
        self.sig_pane = view_pane(self.sig_view)
        controls = pn.FlexBox(self.method_select, self.channel_select, self.compare_box,
                              self.wb_box, self.bloom_input, sizing_mode="stretch_width")
        self.content = pn.Column(
            pn.Card(controls, pn.pane.Bokeh(self.curves.fig, sizing_mode="stretch_width"),
                    self.curve_note, title="Inverse response g(z) with its 2σ band",
                    sizing_mode="stretch_width", collapsible=False),
            pn.Card(pn.pane.Markdown(
                        "Each image predicted from a neighbour through the curve and the "
                        "exposure ratio, in DN over the codes both read (Tsin et al. sec. 4.2): "
                        "with the result's own ratios, with each pair's ratio fitted (the "
                        "difference is what exposure errors cost), and from the blend of all "
                        "the other images.", sizing_mode="stretch_width", styles=_MUTED),
                    self.agreement_table, self.pairs_note, self.pairs_table,
                    title="How well each method predicts the bracket (sec. 4.2)",
                    sizing_mode="stretch_width", collapsible=False),
            pn.Card(pn.Row(pn.Column(pn.pane.Markdown("**Noise terms (eq. 7, fitted by eq. 17)**"),
                                     self.noise_table, sizing_mode="stretch_width"),
                           pn.Column(pn.pane.Markdown("**Scale a_k and offset b_k against the "
                                                      "nominal exposures**"),
                                     self.ab_table, sizing_mode="stretch_width"),
                           sizing_mode="stretch_width"),
                    title="Noise and white balance", sizing_mode="stretch_width",
                    collapsible=False),
            pn.Card(self.pool_note, pn.pane.Bokeh(self.pool_hist.fig,
                                                  sizing_mode="stretch_width"),
                    title="Prediction errors of one pool (Fig. 3c-d)",
                    sizing_mode="stretch_width", collapsible=False),
            pn.Card(pn.FlexBox(self.tone_select, self.stops_slider,
                               sizing_mode="stretch_width"),
                    pn.Row(self.rad_pane, self.sig_pane),
                    self.readout, self.hdr_note,
                    title="HDR radiance (eqs. 9, 18) and its sigma (eq. 19), linked zoom",
                    sizing_mode="stretch_width", collapsible=False),
            pn.Card(self.notes_pane, title="Notes", sizing_mode="stretch_width",
                    collapsed=True),
            sizing_mode="stretch_width", visible=False)

    def __panel__(self) -> pn.viewable.Viewable:
        intro = ("The inverse response g maps a code z to a value proportional to the exposure "
                 "(Tsin, Ramesh & Kanade 2001, eqs. 5, 8). It is estimated from a bracket of a "
                 "static scene; its scale is fixed at the code 90 % up the range. The HDR "
                 "radiance merges the bracket with weights a_k/σ (eq. 18); its sigma (eq. 19) "
                 "says how far to trust each pixel.")
        return pn.Column(
            *heading("Response & HDR", intro),
            self.info_alert, self.error_alert, self.warning_alert, self.content,
            sizing_mode="stretch_width", name="Response & HDR")

    # ------------------------------------------------------------------------ events ------
    def _on_session(self, *events: Any) -> None:
        self._session = None
        self.responses = None
        self.hdr = None
        self._warn(None)
        if self.auto:
            pn.state.execute(self.refresh)

    @param.depends("method", watch=True)
    def _on_method(self) -> None:
        self._render_response()
        self._render_agreement()
        if self.auto:
            pn.state.execute(self.show_hdr)

    @param.depends("channel", "compare", watch=True)
    def _on_view(self) -> None:
        self._render_response()
        self._render_hdr()

    @param.depends("tone", "stops", watch=True)
    def _on_tone(self) -> None:
        self._render_hdr()

    @param.depends("bloom_radius", "white_balance", watch=True)
    def _on_bloom(self) -> None:
        self._session = None
        if self.auto:
            pn.state.execute(self.refresh)

    # ------------------------------------------------------------------------ computing ---
    @property
    def _cache(self) -> dict:
        return self.state.results.response

    async def refresh(self) -> None:
        """Estimate every method on the session's bracket (cached), then show the HDR."""
        session = self._new_session()
        if session is None:
            return
        if not session.bracket_stacks("bracket"):
            self._info(NO_BRACKET_MESSAGE)
            return
        self._info("")
        self.content.visible = True
        key = self._key()
        entry = self._cache.get(key)
        if entry is None:
            self.content.loading = True
            try:
                found = await self.state.shared_compute(
                    RESPONSES_ENTRY, self._options(), compute_responses, session, key[0],
                    white_balance=key[1], label="response curves", pass_progress=True)
            finally:
                self.content.loading = False
            if self.state.session is not session:
                return
            if found is None:
                self._set_error(self.state.error or "the response was not computed")
                return
            # (another page on this state may have stored the same shared result meanwhile)
            entry = self._cache.setdefault(key, {"responses": found, "hdr": {}})
        if self._session is not session or key != self._key():
            return                  # superseded while computing: the newer refresh shows
        self.responses = entry["responses"]
        self._truth = _true_g(session)
        names = list(next(iter(self.responses.values())).channels)
        in_document(self._doc, lambda: self._show_responses(names))
        await self.show_hdr()

    def _key(self) -> tuple[int, bool]:
        return int(self.bloom_radius), bool(self.white_balance)

    def _options(self, **more: Any) -> dict[str, Any]:
        """What the shared results depend on besides the session's content."""
        return {"bloom_radius": int(self.bloom_radius),
                "white_balance": bool(self.white_balance), **more}

    @batched
    def _show_responses(self, names: list[str]) -> None:
        """The session's channels as the channel choice (its options and value in one
        update: a served radio group given options without the old value would clear it),
        then the curves and tables."""
        value = self.channel if self.channel in names else names[0]
        set_choices(self, {"channel": (self.channel_select, list(names), value)},
                    trigger=False)
        self.channel_select.visible = len(names) > 1
        self._render_response()
        self._render_agreement()

    async def show_hdr(self) -> None:
        """The HDR merge with the chosen method's calibration (cached per method)."""
        session = self._session
        if session is None or self.responses is None:
            return
        entry = self._cache.get(self._key())
        method = self.method
        hdr = entry["hdr"].get(method) if entry else None
        if hdr is None:
            hdr = await self.state.shared_compute(
                HDR_ENTRY, self._options(method=method), compute_hdr, session,
                self.responses[method], int(self.bloom_radius), label="HDR radiance",
                disk=False, hold=False)
            if hdr is None or self.state.session is not session:
                if self.state.error:
                    self._set_error(self.state.error)
                return
            if entry is not None:
                entry["hdr"][method] = hdr
        if method != self.method:
            return
        self.hdr = hdr
        in_document(self._doc, self._render_hdr)

    # ------------------------------------------------------------------------ rendering ---
    @batched
    def _render_response(self) -> None:
        if not self.responses:
            return
        ch = self.channel
        curves = {m: (r[ch].g, r[ch].g_err) for m, r in self.responses.items()
                  if ch in r.channels}
        truth = self._truth if (self._truth is not None and ch in ("L", "R", "G", "B") and
                                self._truth.size == next(iter(curves.values()))[0].size) \
            else None
        self.curves.show(curves, self.method, self.compare, truth)
        res = self.responses[self.method]
        c = res[ch]
        self.curve_note.object = (
            f"{LABELS[self.method]}: {c.iterations} iteration{'s' if c.iterations != 1 else ''}"
            f"{'' if c.converged else ' (not converged)'}; band: "
            + ("the spread of the pools' pixels (sandwich over blocks of rows)"
               if self.method == "tsin" else "a jackknife over 8 blocks of rows")
            + (". Dashed: the simulator's true g." if truth is not None else "."))
        rows = []
        for m, r in self.responses.items():
            cc = r[ch]
            rows.append({"method": LABELS[m],
                         "σ_s": _pm(cc.sigma_s, cc.sigma_s_err),
                         "σ_c1": _pm(cc.sigma_c1, cc.sigma_c1_err),
                         "σ_c2 (DN)": _pm(cc.sigma_c2, cc.sigma_c2_err)})
        self.noise_table.object = pd.DataFrame(rows)
        self.ab_table.object = pd.DataFrame({
            "image": [f"{k + 1}" for k in range(c.t.size)],
            "nominal t (s)": [f"{t:.5g}" for t in c.t],
            "a_k": [f"{a:.5g}" for a in c.a], "a_k / t_k": [f"{a / t:.4f}"
                                                            for a, t in zip(c.a, c.t)],
            "b_k": [f"{b:.4g}" for b in c.b]})
        pe = self.responses["tsin"][ch].pool_errors
        if pe:
            self.pool_hist.show(pe.get("before"), pe.get("after"))
            self.pool_note.object = (
                f"Sec. 3.2's estimator: the pool of image {pe['pool_image'] + 1} at code "
                f"{pe['code']:.0f}, predicting image {pe['predicted_image'] + 1}: relative "
                "errors with the straight-line start (grey) and after calibration (orange); "
                "a calibrated camera centres them on zero.")
        notes = [f"- {LABELS[m]} ({ch}): {n}" for m, r in self.responses.items()
                 for n in r[ch].notes]
        self.notes_pane.object = "\n".join(notes) or "No remarks."

    @batched
    def _render_agreement(self) -> None:
        """The agreement of every method (pooled), the chosen one's pairs, the warning."""
        if not self.responses:
            return
        res = self.responses[self.method]
        self.agreement_table.object = pd.DataFrame(agreement_rows(
            [(LABELS[m], None if r.agreement is None else r.agreement.summary_record())
             for m, r in self.responses.items()]))
        a = res.agreement
        if a is None:
            self.pairs_note.object = f"**{LABELS[self.method]}**: no agreement computed."
            self.pairs_table.object = pd.DataFrame()
        else:
            self.pairs_table.object = pd.DataFrame(pair_rows(a.summary_record(), res.t))
            worst = [(w.rms, c.channel, w) for c in a.channels
                     if (w := c.worst_pair()) is not None]
            text = (f"**Pairs of neighbouring images, {LABELS[self.method]}** (RMS in DN with "
                    "the result's ratio and with the pair's own; the fitted ratio over the "
                    f"nominal t_k / t_j; codes {a.code_range[0]}..{a.code_range[1]})")
            if worst:
                _, ch, w = max(worst, key=lambda x: x[0])
                text += (f". Worst: images {w.j + 1}\u2192{w.k + 1} in {ch}, "
                         f"{dn(w.rms)} DN ({dn(w.rms_fitted)} DN with its ratio fitted).")
            self.pairs_note.object = text
        self._warn(untrusted_reason(res, self.responses))

    def _warn(self, reason: str | None) -> None:
        self.warning_alert.object = f"**Warning:** {reason}" if reason else ""
        self.warning_alert.visible = bool(reason)

    @batched
    def _render_hdr(self) -> None:
        hdr = self.hdr
        if hdr is None:
            return
        ch = self.channel if self.channel in hdr.channels else hdr.channels[0]
        p = hdr_planes(hdr, hdr.channels.index(ch), self.stops, self.tone)
        E, F = p["E"], p["F"]
        self._E, self._S, self._F = E, p["S"], F
        self.rad_view.show(p["display"], clim=(0.0, 1.0))
        self.sig_view.show(p["rel"], clim=(0.0, p["top"]))
        self.rad_pane.visible = self.sig_pane.visible = True
        n_bad = int(np.count_nonzero(F != FLAG_OK))
        self.hdr_note.object = (
            f"{E.size - n_bad} pixels merged; {n_bad} flagged (saturated or dark in every "
            "image: a bound with σ = ∞; or merged from codes next to a saturated pixel). The "
            "display curve and exposure change the picture only, not the radiance.")

    def _on_pointer(self, x: float, y: float) -> None:
        E = getattr(self, "_E", None)
        if E is None:
            return
        if not (np.isfinite(x) and np.isfinite(y)):
            return
        col, row = int(round(x)), int(round(y))
        if not (0 <= row < E.shape[0] and 0 <= col < E.shape[1]):
            return
        e, s, f = float(self._E[row, col]), float(self._S[row, col]), int(self._F[row, col])
        flag = "" if f == FLAG_OK else " (flagged)"
        self.readout.object = (f"pixel (row {row}, col {col}): E = "
                               f"{format_pm(e, s) if np.isfinite(s) else f'{e:.5g} (bound)'}"
                               f"{flag}")


def _pm(v: Any, e: Any) -> str:
    if v is None:
        return "–"
    if e is None or not np.isfinite(e):
        return f"{v:.4g}"
    return format_pm(float(v), float(e))


def create_page(state: AppState) -> ResponsePage:
    """Registry entry point: the Response & HDR page bound to ``state``."""
    return ResponsePage(state)
