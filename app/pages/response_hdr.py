"""The Response & HDR page: inverse response curves, their verdict, noise terms and HDR radiance
with sigma.

Tsin, Ramesh & Kanade 2001 (sec. 3): the inverse response g per channel. On opening a session
the page computes the library's default result only, :func:`ccdcore.response.methods.response_of`
with ``method="auto"`` (sec. 3.2, :mod:`ccdcore.response.tsin.estimator`, unless Debevec & Malik's
curve predicts the bracket clearly better; on the bracket's own exposures when the images disagree
with the listed ones, :mod:`ccdcore.response.exposures`), and the HDR merged with it. It shows
the result's verdict in the library's own words (:mod:`ccdcore.response.verdict`: the page never
judges a result itself), which exposures were used and the frames whose listed exposures look
off, why this method was kept; the curve with its band; how well the curves predict the
bracket's own images (sec. 4.2, :mod:`ccdcore.response.agreement`: the result's and the curves
it was checked against, pooled, and the shown result's pairs of neighbouring images); the noise
terms σ_s, σ_c1, σ_c2 of eq. 17; the prediction errors of one pool before and after calibration
(Fig. 3c-d); the HDR radiance of the bracket (eqs. 9, 18) with its per-pixel sigma (eq. 19),
tone-mapped for display only, with linked zoom and the value ± sigma under the cursor.

The other methods of :data:`ccdcore.response.methods.METHODS` are computed only when asked:
choosing one in the method selector, or "Compare all methods" (each overlaid once computed).

Public objects
--------------
ResponsePage
    The page (a :class:`panel.viewable.Viewer`); its state is declared with ``param``: method
    ("auto" or a method), channel, compare (overlay every computed curve), tone curve and
    display exposure, blooming radius, white balance, exposures.
create_page(state)
    The registry entry point.
compute_response(session, method, bloom_radius, progress, white_balance, exposures)
    One result of :func:`~ccdcore.response.methods.response_of` on the session's first bracket.
compute_responses(session, bloom_radius, progress, white_balance, exposures, methods)
    Several of them (a dict method -> ResponseResult; by default every method).
compute_hdr(session, result, bloom_radius)
    The HDR merge of the bracket with one result's calibration.
AUTO_LABEL, NO_BRACKET_MESSAGE
    The default's label in the method selector; what the page says without a bracket.

Computing runs off the UI thread, once per server: :meth:`ccdcore_app.state.AppState.shared_compute`
keys each result (and each result's HDR) by the session's content hash and the options (method,
blooming radius, white balance, exposures), so a second browser tab on the same session waits
for the first one's computation instead of starting its own; the results are also kept in the
disk cache. Each browser session keeps what it computed in ``state.results.response``, keyed by
(blooming radius, white balance, exposures): ``{"responses": name -> ResponseResult, "hdr":
name -> HdrResult}`` with ``name`` "auto" or a method. Widget changes feed the figures' sources
in place (:mod:`ccdcore_app.plots.response`, :class:`ccdcore_app.image_view.ImageView`).
"""
from __future__ import annotations

import html
from typing import Any, Iterable

import numpy as np
import pandas as pd
import panel as pn
import param

from ccdcore.common import format_pm
from ccdcore.errors import CcdError
from ccdcore.progress import Progress, within
from ccdcore.response.bracket_fit import (BracketFit, finish_fit, fit_bracket, merge_fit,
                                         prepare_bracket, register_frames)
from ccdcore.response.brackets import DEFAULT_BLOOM_RADIUS, bracket_records
from ccdcore.response.moving import find_moving
from ccdcore.response.hdr import FLAG_OK, HdrResult
from ccdcore.response.hdr_merge import (FLAG_BLOOMED, FLAG_DARK, FLAG_MOVING,
                                        FLAG_SATURATED)
from ccdcore.response.methods import AUTO, EXPOSURE_MODES, METHODS, ResponseResult, response_of
from ccdcore.response.scale import normalize
from ccdcore.session import Session
from ccdcore.simulate.truth import find_truth

from ..batch import batched, in_document
from ..image_view import view_pane
from ..plots.response import (TONE_CURVES, VERDICT_ALERTS, PoolHistogram, ResponseFigure,
                              agreement_rows, details_markdown, dn, hdr_planes, hdr_views,
                              md_text, pair_rows)
from ..state import AppState
from ._choices import set_choices
from ._messages import PageMessages
from ._styles import TABLE_CSS, heading, progress_row

__all__ = ["ResponsePage", "create_page", "compute_response", "compute_responses",
           "compute_hdr", "NO_BRACKET_MESSAGE", "RESPONSES_ENTRY", "HDR_ENTRY", "AUTO_LABEL",
           "LABELS"]

NO_BRACKET_MESSAGE = (
    "**No exposure bracket in this session.** Photograph a static scene at several exposure "
    "times (e.g. 8 exposures a factor of 1.4 apart, from the shortest that keeps the "
    "highlights to the longest that shows the shadows; camera on a tripod, fixed aperture, "
    "focus and white balance) and list the frames in `session.toml` with `role = \"bracket\"` "
    "and `exposure` in seconds (a `stack = N` per bracket when there are several). The "
    "bundled **tsin01** demo has one.")

_MUTED = {"font-size": "0.88em", "color": "#6c757d"}
IMAGE_WIDTH = 330
#: the default result's label in the method selector
AUTO_LABEL = "auto (default)"
#: "auto" and every method -> its label
LABELS = {AUTO: AUTO_LABEL, **{name: m.label for name, m in METHODS.items()}}
#: the names the responses and the HDR are shared (and cached) under, with the options
RESPONSES_ENTRY = "response_curves"
HDR_ENTRY = "response_hdr"
#: flags.png's codes in words (the pointer's readout)
FLAG_WORDS = {FLAG_DARK: "dark in every image: an upper bound",
              FLAG_SATURATED: "saturated in every image: a lower bound",
              FLAG_BLOOMED: "merged from codes next to a saturated pixel",
              FLAG_MOVING: "merged from one exposure: something moved"}


# ----------------------------------------------------------------------------- computing ------
def compute_response(session: Session, method: str = AUTO,
                     bloom_radius: int = DEFAULT_BLOOM_RADIUS,
                     progress: Progress | None = None, white_balance: bool = False,
                     exposures: str = "auto") -> ResponseResult:
    """:func:`ccdcore.response.bracket_fit.fit_bracket` on the session's first bracket (its
    frames registered, its moving pixels left out, both in the verdict): ``method`` "auto"
    (the library's default) or a key of :data:`METHODS`; the white-balance gains only where the
    method estimates them."""
    return fit_bracket(session, method=method, progress=progress, bloom_radius=bloom_radius,
                       white_balance=_white_balance(method, white_balance),
                       exposures=exposures).result


def compute_responses(session: Session, bloom_radius: int = DEFAULT_BLOOM_RADIUS,
                      progress: Progress | None = None, white_balance: bool = False,
                      exposures: str = "auto",
                      methods: Iterable[str] | None = None) -> dict[str, ResponseResult]:
    """:func:`compute_response` for each of ``methods`` (default: every method of the
    registry), each taking an equal part of ``progress``; the bracket is read, registered and
    searched for moving pixels once (:func:`ccdcore.response.bracket_fit.prepare_bracket`)."""
    prepared = prepare_bracket(session, bloom_radius=bloom_radius)
    names = list(METHODS) if methods is None else list(methods)
    out: dict[str, ResponseResult] = {}
    for i, name in enumerate(names):
        sub = within(progress, i / len(names), (i + 1) / len(names),
                     prefix=f"{LABELS[name]}: ")
        res = response_of(prepared.brackets, name, progress=sub, bloom_radius=bloom_radius,
                          white_balance=_white_balance(name, white_balance),
                          exposures=exposures)
        out[name] = finish_fit(res, prepared).result
    return out


def _white_balance(method: str, asked: bool) -> bool:
    """Whether ``method`` ("auto" fits sec. 3.2 first) estimates the gains when ``asked``."""
    return bool(asked) and (method == AUTO or METHODS[method].white_balance)


def compute_hdr(session: Session, result: ResponseResult,
                bloom_radius: int = DEFAULT_BLOOM_RADIUS) -> HdrResult:
    """The bracket merged with ``result``'s calibration (eqs. 9, 18, 19): its frames registered
    as the fit's were, the pixels whose exposures disagree merged from one exposure
    (:mod:`ccdcore.response.moving`)."""
    records = bracket_records(session)
    frames, registration, no_data, keep = register_frames(
        [session.read(r) for r in records], [r.relpath for r in records])
    if len(keep) != len(result.files):
        raise CcdError(result.files[0], "the bracket's frames changed since the response")
    moving = find_moving(frames, result.models(), layout=session.camera.layout,
                         names=list(result.files), bloom_radius=bloom_radius)
    fit = BracketFit(result, frames, [records[k] for k in keep], registration, no_data, moving)
    return merge_fit(fit, session.camera.layout)


def _true_g(session: Session) -> np.ndarray | None:
    """The simulator's g (``truth.json``), when the session has one and it fits."""
    try:
        truth = find_truth(session)
    except CcdError:
        return None
    if truth is None or "g" not in truth:
        return None
    g = np.asarray(truth["g"], np.float64)
    if g.ndim != 1 or g.size < 2:
        return None
    # on the scale every curve is reported on (g(z_hi) = z_hi / (levels - 1)): a camera-like
    # simulation's own scale (a tone curve with headroom) would draw it far from every estimate
    try:
        return normalize(g, g.size)[0]
    except ValueError:
        return g


def _table(css_class: str) -> pn.pane.DataFrame:
    return pn.pane.DataFrame(pd.DataFrame(), index=False, sizing_mode="stretch_width",
                             escape=True, css_classes=[css_class], stylesheets=[TABLE_CSS])


def _label(name: str, result: ResponseResult | None = None) -> str:
    """The label of ``name``; the default's with the method it kept."""
    if name == AUTO and result is not None:
        return f"{AUTO_LABEL}: {METHODS[result.method].label}"
    return LABELS.get(name, name)


# ----------------------------------------------------------------------------- the page -------
class ResponsePage(PageMessages, pn.viewable.Viewer):
    """Response curves, their verdict, noise and HDR radiance of the loaded session's
    bracket."""

    state = param.ClassSelector(class_=AppState, doc="The app state shared by all pages.")
    method = param.Selector(default=AUTO, objects={v: k for k, v in LABELS.items()}, doc=(
        "The result whose curve, band, verdict, noise and HDR are shown: the library's default "
        "(auto: sec. 3.2 unless Debevec & Malik's curve predicts the bracket clearly better), "
        "or one method, computed when first chosen."))
    channel = param.Selector(default="L", objects=["L"], doc="Channel (or CFA plane) shown.")
    compare = param.Boolean(default=True, doc="Overlay every computed curve.")
    tone = param.Selector(default="gamma 2.2", objects=list(TONE_CURVES),
                          doc="Display curve of the HDR radiance (the data are not changed).")
    stops = param.Number(default=0.0, bounds=(-6.0, 6.0), step=0.5,
                         doc="Display exposure of the HDR radiance, in stops.")
    white_balance = param.Boolean(default=False, doc=(
        "Estimate each image's gain a_k and offset b_k (white balance, exposure errors) by "
        "sec. 3.2, up to a common factor and a trend in the exposure that no bracket fixes. "
        "The classic methods take the exposures as exact."))
    exposures = param.Selector(default="auto", objects=list(EXPOSURE_MODES), doc=(
        "Which exposures the curves are fitted with. auto: the bracket's own exposures "
        "(estimated from its images, before any curve) when the images clearly disagree with "
        "the listed ones, else the listed ones; listed: the exposures of session.toml or EXIF "
        "as they are (no estimate); estimated: always the bracket's own exposures."))
    bloom_radius = param.Integer(default=DEFAULT_BLOOM_RADIUS, bounds=(0, 10), doc=(
        "Pixels within this radius of a saturated pixel are dropped as blooming (sec. 2); 0 "
        "keeps them (for scenes without bright areas, e.g. simulated per-pixel radiance)."))

    def __init__(self, state: AppState | None = None, *, auto: bool = True, **params: Any):
        super().__init__(state=state if state is not None else AppState(), **params)
        self.auto = auto
        self._doc = pn.state.curdoc
        self._session: Session | None = None
        #: what this browser session computed with the current options: "auto" or a method
        #: -> its result (the default only, until other methods are asked for)
        self.responses: dict[str, ResponseResult] | None = None
        self.hdr: HdrResult | None = None
        self._hdr_of = ""
        self._truth: np.ndarray | None = None
        self._computing: set[str] = set()
        self.error = ""
        self._build()
        self.state.param.watch(self._on_session, "session")
        self.state.param.watch(self._on_progress, ["progress", "status"])
        self._show_empty()
        if auto and self.state.session is not None:
            pn.state.execute(self.refresh)

    # ------------------------------------------------------------------------ building ----
    def _build(self) -> None:
        self._build_alerts("response")
        self.verdict_alert = pn.pane.Alert("", alert_type="success", visible=False,
                                           sizing_mode="stretch_width",
                                           css_classes=["ccd-response-verdict"])
        # the verdict's registration and moving-pixel lines, below the curves (above them they
        # pushed the curves out of the first view)
        self.verdict_details = pn.pane.Markdown("", sizing_mode="stretch_width",
                                                css_classes=["ccd-response-verdict-details"])
        self.exposures_note = pn.pane.Markdown("", sizing_mode="stretch_width",
                                               css_classes=["ccd-response-exposures"])
        self.progress_bar, self.progress_text, self.progress_row = progress_row("ccd-response-progress")
        self.method_select = pn.widgets.RadioButtonGroup.from_param(
            self.param.method, color="default", css_classes=["ccd-response-method"],
            width=820)
        self.compare_button = pn.widgets.Button(
            label="Compare all methods", color="primary", variant="outline",
            width=190, css_classes=["ccd-response-compare"],
            description="Compute every other method on this bracket (with these options) and "
                        "overlay its curve")
        self.compare_button.on_click(lambda event: pn.state.execute(self.compare_all))
        self.channel_select = pn.widgets.RadioButtonGroup.from_param(
            self.param.channel, color="default", visible=False)
        self.compare_box = pn.widgets.Checkbox.from_param(self.param.compare,
                                                          name="Overlay the computed curves")
        self.bloom_input = pn.widgets.IntInput.from_param(self.param.bloom_radius,
                                                          name="Blooming radius (px)", width=150)
        self.wb_box = pn.widgets.Checkbox.from_param(
            self.param.white_balance, name="Estimate white balance a_k, b_k (sec. 3.2)")
        self.exposures_select = pn.widgets.RadioButtonGroup.from_param(
            self.param.exposures, color="default", css_classes=["ccd-response-exposure-mode"],
            description=self.param.exposures.doc, width=300, align="center")
        self.curves = ResponseFigure([AUTO, *METHODS], LABELS)
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
        self.content = pn.Column(*self._cards(), sizing_mode="stretch_width", visible=False)

    def _cards(self) -> list[pn.viewable.Viewable]:
        """The page's cards: curves with the controls, agreement, noise, pool, HDR, notes."""
        # the controls in two rows, so that the curves are in the first view at 1400 x 900
        controls = pn.FlexBox(self.method_select, self.compare_button, self.channel_select,
                              sizing_mode="stretch_width")
        options = pn.FlexBox(pn.pane.Markdown("Exposures:", margin=(12, 4, 0, 10)),
                             self.exposures_select, self.compare_box, self.wb_box,
                             self.bloom_input, sizing_mode="stretch_width",
                             align_items="center")
        return [
            pn.Card(controls, options, self.exposures_note,
                    pn.pane.Bokeh(self.curves.fig, sizing_mode="stretch_width"),
                    self.verdict_details, self.curve_note,
                    title="Inverse response g(z) with its 2σ band",
                    sizing_mode="stretch_width", collapsible=False),
            pn.Card(pn.pane.Markdown(
                        "Each image predicted from a neighbour through the curve and the "
                        "exposure ratio, in DN over the codes both read (Tsin et al. sec. 4.2): "
                        "with the result's own ratios, with each pair's ratio fitted (the "
                        "difference is what exposure errors cost), and from the blend of all "
                        "the other images. The default result is checked against Debevec & "
                        "Malik's curve on the same exposures (listed as the challenger).",
                        sizing_mode="stretch_width", styles=_MUTED),
                    self.agreement_table, self.pairs_note, self.pairs_table,
                    title="How well each curve predicts the bracket (sec. 4.2)",
                    sizing_mode="stretch_width", collapsible=False),
            pn.Card(pn.Row(pn.Column(pn.pane.Markdown("**Noise terms (eq. 7, fitted by eq. 17)**"),
                                     self.noise_table, sizing_mode="stretch_width"),
                           pn.Column(pn.pane.Markdown("**Scale a_k and offset b_k against the "
                                                      "exposures**"),
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
                    collapsed=True)]

    def __panel__(self) -> pn.viewable.Viewable:
        intro = ("The inverse response g maps a code z to a value proportional to the exposure "
                 "(Tsin, Ramesh & Kanade 2001, eqs. 5, 8). It is estimated from a bracket of a "
                 "static scene; its scale is fixed at the code 90 % up the range. The HDR "
                 "radiance merges the bracket with weights a_k/σ (eq. 18); its sigma (eq. 19) "
                 "says how far to trust each pixel.")
        return pn.Column(
            *heading("Response & HDR", intro),
            self.info_alert, self.error_alert, self.progress_row, self.verdict_alert,
            self.content, sizing_mode="stretch_width", name="Response & HDR")

    def _set_error(self, text: str) -> None:
        """The error as it is in ``error``; in the alert escaped (it names files)."""
        super()._set_error(text)
        if text:
            self.error_alert.object = f"**Error:** {md_text(text)}"

    # ------------------------------------------------------------------------ events ------
    def _on_session(self, *events: Any) -> None:
        self._session = None
        self.responses = None
        self.hdr = None
        self._show_verdict(None)
        if self.auto:
            pn.state.execute(self.refresh)

    def _on_progress(self, *events: Any) -> None:
        if self._computing and self.state.busy:
            p = self.state.progress
            self.progress_bar.param.update(value=p if p >= 0 else -1, active=p < 0)
            self.progress_text.object = html.escape(self.state.status)

    @param.depends("method", watch=True)
    def _on_method(self) -> None:
        self._render_response()
        self._render_agreement()
        if self.auto:
            pn.state.execute(self.show_method)

    @param.depends("channel", "compare", watch=True)
    def _on_view(self) -> None:
        self._render_response()
        self._render_hdr()

    @param.depends("tone", "stops", watch=True)
    def _on_tone(self) -> None:
        self._render_hdr()

    @param.depends("bloom_radius", "white_balance", "exposures", watch=True)
    def _on_options(self) -> None:
        self._session = None
        if self.auto:
            pn.state.execute(self.refresh)

    # ------------------------------------------------------------------------ computing ---
    @property
    def _cache(self) -> dict:
        return self.state.results.response

    def _key(self) -> tuple[int, bool, str]:
        return int(self.bloom_radius), bool(self.white_balance), str(self.exposures)

    def _options(self, method: str, **more: Any) -> dict[str, Any]:
        """What a shared result depends on besides the session's content."""
        return {"method": method, "bloom_radius": int(self.bloom_radius),
                "white_balance": _white_balance(method, self.white_balance),
                "exposures": str(self.exposures), **more}

    def _current(self, session: Session, key: tuple) -> bool:
        return self.state.session is session and self._session is session and \
            key == self._key()

    async def refresh(self) -> None:
        """Compute the default result on the session's bracket (cached), show it, then the
        HDR merged with it (or, when another method is chosen, that method's result and
        HDR)."""
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
        if entry is None or AUTO not in entry["responses"]:
            self._show_verdict(None)    # (the previous options' verdict is not this one's)
            self.content.loading = True
            try:
                found = await self._compute(session, AUTO, key)
            finally:
                self.content.loading = False
            entry = self._cache.get(key)
            if found is None or entry is None:
                return
        if not self._current(session, key):
            return                  # superseded while computing: the newer refresh shows
        self.responses = entry["responses"]
        self._truth = _true_g(session)
        names = list(next(iter(self.responses.values())).channels)
        in_document(self._doc, lambda: self._show_responses(names))
        await self.show_method()

    async def _compute(self, session: Session, name: str, key: tuple
                       ) -> ResponseResult | None:
        """The result ``name`` ("auto" or a method) with the options ``key``, computed (shared,
        with progress) unless this browser session has it; stored in its cache entry. None
        when it failed (the error is shown), was cancelled, or the session changed."""
        entry = self._cache.setdefault(key, {"responses": {}, "hdr": {}})
        if name in entry["responses"]:
            return entry["responses"][name]
        self._computing.add(name)
        self.progress_text.object = html.escape(f"Computing the response curve: "
                                                f"{LABELS[name]} ...")
        self.progress_bar.param.update(value=-1, active=True)
        self.progress_row.visible = True
        try:
            found = await self.state.shared_compute(
                RESPONSES_ENTRY, self._options(name), compute_response, session, name,
                key[0], white_balance=key[1], exposures=key[2],
                label=f"the response curve ({LABELS[name]})", pass_progress=True)
        finally:
            self._computing.discard(name)
            in_document(self._doc, self._sync_progress_row)
        if self.state.session is not session:
            return None
        if found is None:
            if self.state.error and self._current(session, key):
                self._set_error(self.state.error)
            elif name == AUTO and self._current(session, key):
                self._session = None        # cancelled: computed again on the next visit
                self._set_error(self.state.error or "the response was not computed")
            return None
        # (another page on this state may have stored the same shared result meanwhile)
        return entry["responses"].setdefault(name, found)

    def _sync_progress_row(self) -> None:
        self.progress_row.visible = bool(self._computing)

    async def show_method(self) -> None:
        """The chosen result, computed first when it is not yet, then its HDR."""
        session, key, name = self._session, self._key(), self.method
        if session is None or self.responses is None:
            return
        if name not in self.responses:
            if await self._compute(session, name, key) is None:
                return
            if not self._current(session, key):
                return
            in_document(self._doc, self._show_all)
        if name == self.method:
            await self.show_hdr()

    async def compare_all(self) -> None:
        """Every method not computed yet, one after the other, each overlaid once computed."""
        session, key = self._session, self._key()
        if session is None or self.responses is None:
            return
        self.compare_button.disabled = True
        try:
            for name in METHODS:
                if name in self.responses:
                    continue
                if await self._compute(session, name, key) is None or \
                        not self._current(session, key):
                    return
                in_document(self._doc, self._overlay)
        finally:
            in_document(self._doc, lambda: setattr(self.compare_button, "disabled", False))

    def _overlay(self) -> None:
        """Every computed curve overlaid, the tables with the new one."""
        if not self.compare:
            self.compare = True         # (its watcher draws the curves)
        self._show_all()

    @batched
    def _show_all(self) -> None:
        self._render_response()
        self._render_agreement()

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
        """The HDR merge with the shown result's calibration (cached per result)."""
        session = self._session
        method = self.method
        if session is None or self.responses is None or method not in self.responses:
            return
        entry = self._cache.get(self._key())
        hdr = entry["hdr"].get(method) if entry else None
        if hdr is None:
            hdr = await self.state.shared_compute(
                HDR_ENTRY, self._options(method), compute_hdr, session,
                self.responses[method], int(self.bloom_radius), label="HDR radiance",
                disk=False, hold=False)
            if hdr is None or self.state.session is not session:
                if self.state.error:
                    self._set_error(self.state.error)
                return
            if entry is not None:
                entry["hdr"][method] = hdr
        if method != self.method or self.responses is not (entry or {}).get("responses"):
            return
        self.hdr, self._hdr_of = hdr, _label(method, self.responses[method])
        in_document(self._doc, self._render_hdr)

    # ------------------------------------------------------------------------ rendering ---
    def _shown(self) -> ResponseResult | None:
        """The result of the chosen name, when computed."""
        return None if not self.responses else self.responses.get(self.method)

    def _tsin_result(self) -> ResponseResult | None:
        """A computed result whose curves are sec. 3.2's (the shown one first)."""
        shown = self._shown()
        results = ([shown] if shown is not None else []) + list((self.responses or {}).values())
        return next((r for r in results if r.method == "tsin"), None)

    @batched
    def _render_response(self) -> None:
        if not self.responses:
            return
        ch = self.channel
        curves = {m: (r[ch].g, r[ch].g_err) for m, r in self.responses.items()
                  if ch in r.channels}
        if not curves:
            return
        size = next(iter(curves.values()))[0].size
        truth = self._truth if (self._truth is not None and ch in ("L", "R", "G", "B") and
                                self._truth.size == size) else None
        self.curves.show(curves, self.method, self.compare, truth)
        res = self._shown()
        if res is None:                 # still computing: the other curves stay shown
            self.curve_note.object = f"{md_text(LABELS[self.method])}: computing ..."
            self.ab_table.object = pd.DataFrame()
            return
        c = res[ch]
        self.curve_note.object = (
            f"{_label(self.method, res)}: {c.iterations} iteration"
            f"{'s' if c.iterations != 1 else ''}{'' if c.converged else ' (not converged)'}; "
            "band: " + ("the spread of the pools' pixels (sandwich over blocks of rows)"
                        if res.method == "tsin" else "a jackknife over 8 blocks of rows")
            + (". Dashed: the simulator's true g." if truth is not None else "."))
        self.noise_table.object = pd.DataFrame([
            {"method": _label(m, r), "σ_s": _pm(r[ch].sigma_s, r[ch].sigma_s_err),
             "σ_c1": _pm(r[ch].sigma_c1, r[ch].sigma_c1_err),
             "σ_c2 (DN)": _pm(r[ch].sigma_c2, r[ch].sigma_c2_err)}
            for m, r in self.responses.items()])
        listed = np.asarray(res.t, np.float64)
        self.ab_table.object = pd.DataFrame({
            "image": [f"{k + 1}" for k in range(c.t.size)],
            "listed t (s)": [f"{t:.5g}" for t in listed] if listed.size == c.t.size
            else ["–"] * c.t.size,
            "t used (s)": [f"{t:.5g}" for t in c.t],
            "a_k": [f"{a:.5g}" for a in c.a],
            "a_k / t_k": [f"{a / t:.4f}" for a, t in zip(c.a, c.t)],
            "b_k": [f"{b:.4g}" for b in c.b]})
        self._render_pool(ch)
        notes = [f"- {md_text(_label(m, r))} ({ch}): {md_text(n)}"
                 for m, r in self.responses.items() for n in (*r[ch].notes, *r.notes)]
        self.notes_pane.object = "\n".join(notes) or "No remarks."

    def _render_pool(self, ch: str) -> None:
        tsin = self._tsin_result()
        pe = tsin[ch].pool_errors if tsin is not None and ch in tsin.channels else None
        if not pe:
            self.pool_hist.show(None, None)
            self.pool_note.object = ("Shown for a sec. 3.2 curve (the default when it keeps "
                                     "sec. 3.2, or Tsin, Ramesh & Kanade chosen above).")
            return
        self.pool_hist.show(pe.get("before"), pe.get("after"))
        self.pool_note.object = (
            f"Sec. 3.2's estimator: the pool of image {pe['pool_image'] + 1} at code "
            f"{pe['code']:.0f}, predicting image {pe['predicted_image'] + 1}: relative "
            "errors with the straight-line start (grey) and after calibration (orange); "
            "a calibrated camera centres them on zero.")

    @batched
    def _render_agreement(self) -> None:
        """The agreement of every computed curve and of the curves the results were checked
        against (pooled), the shown result's pairs, its verdict."""
        if not self.responses:
            return
        rows = [(_label(m, r), None if r.agreement is None else r.agreement.summary_record())
                for m, r in self.responses.items()]
        for m, r in self.responses.items():
            for other, a in r.compared.items():
                if other not in self.responses:
                    rows.append((f"{LABELS.get(other, other)} (challenger of "
                                 f"{_label(m, r)})", a.summary_record()))
        self.agreement_table.object = pd.DataFrame(agreement_rows(rows))
        res = self._shown()
        if res is None:                 # still computing: no stale verdict or pairs
            self.pairs_note.object = f"**{md_text(LABELS[self.method])}**: computing ..."
            self.pairs_table.object = pd.DataFrame()
            self._show_verdict(None)
            return
        a = res.agreement
        label = _label(self.method, res)
        if a is None:
            self.pairs_note.object = f"**{md_text(label)}**: no agreement computed."
            self.pairs_table.object = pd.DataFrame()
        else:
            self.pairs_table.object = pd.DataFrame(pair_rows(a.summary_record(), res.t))
            worst = [(w.rms, c.channel, w) for c in a.channels
                     if (w := c.worst_pair()) is not None]
            text = (f"**Pairs of neighbouring images, {md_text(label)}** (RMS in DN with "
                    "the result's ratio and with the pair's own; the fitted ratio over the "
                    f"listed t_k / t_j; codes {a.code_range[0]}..{a.code_range[1]})")
            if worst:
                _, ch, w = max(worst, key=lambda x: x[0])
                text += (f". Worst: images {w.j + 1}\u2192{w.k + 1} in {ch}, "
                         f"{dn(w.rms)} DN ({dn(w.rms_fitted)} DN with its ratio fitted).")
            self.pairs_note.object = text
        self._show_verdict(res)

    def _show_verdict(self, res: ResponseResult | None) -> None:
        """The result's verdict in the library's words (an alert styled by its status), which
        exposures it used, the frames whose listed exposures look off, why its method."""
        verdict = None if res is None else res.verdict
        if verdict is None:
            self.verdict_alert.visible = False
            self.verdict_alert.object = ""
            self.exposures_note.object = ""
            self.verdict_details.object = ""
            return
        self.verdict_details.object = details_markdown(verdict)
        self.verdict_alert.param.update(object=md_text(verdict.line()),
                                        alert_type=VERDICT_ALERTS.get(verdict.status, "info"),
                                        visible=True)
        parts = []
        if res.exposures is not None:
            summary = res.exposures.summary()
            parts.append(md_text(summary.line()))
            parts += [f"- {md_text(run)}" for run in summary.off_runs()]
        else:
            parts.append("exposures: listed (taken as they are, not estimated)")
        if res.selection:
            parts.append(f"**Why this curve:** {md_text(res.selection)}")
        self.exposures_note.object = "\n\n".join(parts)

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
        self.hdr_note.object = (
            f"With the calibration of {md_text(self._hdr_of)}: "
            + md_text(" ".join(hdr.describe()[1:])) + " The display curve and exposure change "
            "the picture only, not the radiance.")

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
        flag = "" if f == FLAG_OK else f" ({FLAG_WORDS.get(f, 'flagged')})"
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
