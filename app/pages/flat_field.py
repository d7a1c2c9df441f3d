"""The Flat field page: gain and offset maps G, O and the spatial nonuniformity SNUP.

de Lasarte, Pujol, Arjona & Vilaseca 2007 (Applied Optics 46(2)): the corrected image
DL_c = O + G·DL (eqs. 1–4) from the dark image DL_0 and a base correction image DL_B, per channel,
and SNUP = 100·σ/mean (eq. 5) before and after correction; the effect of averaging (Table 1), the
linear response range (Fig. 2), the choice of the base image (Fig. 3, Tables 3–5), zero vs
non-zero dark images (Table 2) and, on the simulator's data, the comparison with Healey &
Kondepudy's K̂ against the true flat field.

Public objects
--------------
FlatFieldPage
    The page (a :class:`panel.viewable.Viewer`): offset setting and base image choice (the
    recommended base marked, with the reason), G and O maps per channel with the flagged pixels,
    a before/after view of any flat frame with linked zoom and a pixel readout, the SNUP table
    per channel before and after, SNUP against the number of averaged frames, the linearity plot,
    the base-image study, the zero-dark warning and Table 2, and the K̂ comparison.
create_page(state)
    The registry entry point.
FrameView, frame_view(session, record, flat)
    One flat frame, its correction and their SNUP (ccdcore's ``snup`` and ``FlatField.correct``).
default_frame(recommendation, groups)
    The flat frame shown first: one of the linear-range group ``compare_with_k_map`` evaluates.
kmap_comparison(session, setting)
    :func:`ccdcore.flatfield.fit.compare_with_k_map`, with the simulator's true flat field when the
    session has one (:func:`ccdcore.simulate.truth.find_truth`).
NO_FLAT_MESSAGE, ZERO_DARK_MESSAGE
    What the page says without flat frames, and above a zero-clipped dark image.

Every number comes from :mod:`ccdcore.flatfield.fit` and :mod:`ccdcore.flatfield.uniformity`; the
frames are grouped by the session (:meth:`ccdcore.session.Session.flat_groups`, ``dark_groups``,
``settings``) and the channels named by :mod:`ccdcore.channels`. Computing runs off the UI thread
through :meth:`ccdcore_app.state.AppState.compute`; results are cached in ``state.results.flat``
(:class:`ccdcore_app.state.FlatResults`, by offset setting and base group); the plots come from
:mod:`ccdcore_app.plots.flat` and :mod:`ccdcore_app.plots.base`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from functools import partial
from typing import Any, Sequence

import numpy as np
import pandas as pd
import panel as pn
import param

from ccdcore.channels import channel_names, split_channels
from ccdcore.errors import CcdError
from ccdcore.flatfield.fit import (BaseRecommendation, FlatField, KMapComparison,
                               base_image_study, compare_dark_settings, compare_with_k_map,
                               flat_field_from_session, recommend_base, zero_dark)
from ccdcore.session import FrameRecord, Session
from ccdcore.simulate.truth import find_truth
from ccdcore.flatfield.uniformity import SnupResult, snup, snup_vs_averaging

from ..plots import flat as flat_plots
from ..plots import base as plots
from ..image_view import ImageView
from ..latest import Latest
from ..state import AppState
from ..batch import batched, in_document as _in_document
from ._choices import set_choices
from ._messages import PageMessages
from ._styles import TABLE_CSS, heading

__all__ = ["FlatFieldPage", "create_page", "FrameView", "frame_view", "kmap_comparison",
           "default_frame", "NO_FLAT_MESSAGE", "ZERO_DARK_MESSAGE"]

log = logging.getLogger(__name__)

#: the name of the true flat field among a simulated session's truth maps
TRUE_FLATFIELD = "flatfield"

#: what the page says when the session has no flat frames
NO_FLAT_MESSAGE = (
    "**No flat-field frames in this session.** Capture a uniformly lit field (an integrating "
    "sphere or a diffuser in front of the lens) at **several exposure times** from just above "
    "the dark level to saturation, and list the frames in `session.toml` with `role = \"flat\"`, "
    "`level = N` (one N per radiance level) and `exposure` in seconds; take 8 or more frames at "
    "the exposure you mean to use as the base image. Add **dark frames** (`role = \"dark\"`) at "
    "the same exposure times. With several camera offset settings, tag every frame with "
    "`setting = \"NAME\"` (e.g. NZDI, ZDI).")

#: the headline of the zero-dark warning
ZERO_DARK_MESSAGE = ("The offset setting clips the dark image at zero; information is lost "
                     "\u2014 raise the offset.")


_MUTED = {"font-size": "0.88em", "color": "#6c757d"}


# ----------------------------------------------------------------------------- computing ------
@dataclass(frozen=True, eq=False)
class FrameView:
    """One flat frame before and after correction with the SNUP of each (eq. 5)."""

    relpath: str
    raw: np.ndarray
    corrected: np.ndarray
    before: SnupResult
    after: SnupResult
    base_key: tuple | None


def frame_view(session: Session, record: FrameRecord, flat: FlatField) -> FrameView:
    """Read ``record``, correct it with ``flat`` (DL_c = O + G·DL) and take both SNUPs."""
    raw = session.read(record)
    corrected = flat.correct(raw, where=record.relpath)
    before = snup(raw, layout=flat.layout, where=record.relpath)
    after = snup(corrected, layout=flat.layout, where=record.relpath)
    return FrameView(relpath=record.relpath, raw=raw, corrected=corrected, before=before,
                     after=after, base_key=flat.base_key)


def _averaging(session: Session, records: Sequence[FrameRecord], layout: str):
    return snup_vs_averaging(session.iter_frames(records), layout=layout)


def _zero_dark(session: Session, setting: str | None):
    recs = [r for group in session.dark_groups(setting=setting).values() for r in group]
    if not recs:
        raise CcdError(session.label, "no dark frames (role = 'dark')"
                       + (f" with setting = {setting!r}" if setting else ""))
    return zero_dark(session.iter_frames(recs), layout=session.camera.layout)


def _true_flatfield(session: Session) -> np.ndarray | None:
    """The simulator's true flat field of the session (``truth.json``'s ``flatfield`` map), or
    None for a real capture, a truth without one or one that cannot be read (logged)."""
    try:
        truth = find_truth(session)
        if truth is None or TRUE_FLATFIELD not in truth.maps():
            return None
        return truth.map(TRUE_FLATFIELD)
    except CcdError as err:
        log.warning("the true flat field is not used: %s", err)
        return None


def kmap_comparison(session: Session, setting: str | None) -> tuple[KMapComparison, bool]:
    """:func:`ccdcore.flatfield.fit.compare_with_k_map` on the session; the simulator's true flat
    field (:func:`ccdcore.simulate.truth.find_truth`) is passed as ``truth_flatfield`` when the
    session has one. Returns the comparison and whether the truth was used."""
    truth = _true_flatfield(session)
    return compare_with_k_map(session, setting=setting, truth_flatfield=truth), truth is not None


def default_frame(rec: BaseRecommendation | None, groups: dict) -> str | None:
    """The frame shown first: a frame of the linear-range group (not the base) with the most
    frames, then the highest level and exposure (the group compare_with_k_map evaluates)."""
    keys = list(groups)
    if not keys:
        return None
    pool = keys
    if rec is not None:
        inside = [k for k in keys if rec.linearity.in_range(k) and k != rec.key]
        pool = inside or [k for k in keys if k != rec.key] or keys
    key = max(pool, key=lambda k: (len(groups[k]), k[0] or 0, k[1] or 0))
    return groups[key][0].relpath


#: frame width of the side-by-side images (px); the height follows the image, pixels are square
IMAGE_WIDTH = 400


def _image_view(cmap: str, label: str, css_class: str, link: ImageView | None = None
                ) -> ImageView:
    """One zoomable image of the page (built once, fed in place), zoom linked with ``link``."""
    return ImageView(frame_width=IMAGE_WIDTH, max_frame_height=IMAGE_WIDTH, cmap=cmap,
                     label=label, symbol=label, link=link, css_classes=[css_class])


def _view_pane(view: ImageView) -> pn.Column:
    """The pane of a view (a Column around it: ``visible`` on a Bokeh pane fails)."""
    return pn.Column(pn.pane.Bokeh(view.figure), margin=0, visible=False)


def _table(df: pd.DataFrame, css_class: str, **kw: Any) -> pn.pane.DataFrame:
    return pn.pane.DataFrame(df, index=False, sizing_mode="stretch_width", escape=True,
                             css_classes=[css_class], stylesheets=[TABLE_CSS], **kw)


# ----------------------------------------------------------------------------- the page -------
class FlatFieldPage(PageMessages, pn.viewable.Viewer):
    """Flat-field correction of the loaded session (de Lasarte et al. 2007)."""

    state = param.ClassSelector(class_=AppState, doc="The app state shared by all pages.")
    channel = param.Selector(default="R", objects=["R", "G", "B"],
                             doc="Channel (or CFA plane) shown in the maps and plots.")
    offset = param.Selector(default=None, objects=[], allow_None=True, doc=(
        "The offset setting analysed (manifest key setting; None when the session names "
        "none)."))
    base = param.Selector(default=None, objects=[], allow_None=True, doc=(
        "(level, exposure) of the flat group used as the base image DL_B."))
    frame = param.Selector(default=None, objects=[], allow_None=True, doc=(
        "relpath of the flat frame shown before and after correction."))

    def __init__(self, state: AppState | None = None, *, auto: bool = True, **params: Any):
        """``auto``: compute when the page is built, the session changes or a widget changes
        (scheduled on the server's event loop); tests pass ``False`` and await the steps
        (:meth:`refresh`, :meth:`show_setting`, :meth:`show_base`, :meth:`show_frame`)."""
        super().__init__(state=state if state is not None else AppState(), **params)
        self.auto = auto
        #: the browser session's document (callbacks after a worker thread may not know it)
        self._doc = pn.state.curdoc
        self._session: Session | None = None
        self._settings = Latest()     # setting requests (newest wins)
        self._bases = Latest()        # base requests
        self._records: dict[str, FrameRecord] = {}
        #: what is shown (None until computed)
        self.setting: str | None = None
        self.recommendation: BaseRecommendation | None = None
        self.flat: FlatField | None = None
        self.view: FrameView | None = None
        self._study: Any = None
        self._zero: Any = None
        self.error = ""
        self._build_widgets()
        self.state.param.watch(self._on_session, "session")
        self._show_empty()
        if auto and self.state.session is not None:
            pn.state.execute(self.refresh)

    # ================================================================ building the widgets ====
    def _build_widgets(self) -> None:
        self._build_setup_widgets()
        self._build_pair_widgets()
        self._build_analysis_widgets()
        self._build_content()

    def _build_setup_widgets(self) -> None:
        """The alerts, the setting, base image and channel choices, the correction's tables."""
        self._build_alerts("flat")
        self.zero_alert = pn.pane.Alert("", alert_type="warning", visible=False,
                                        sizing_mode="stretch_width",
                                        css_classes=["ccd-flat-zero"])
        self.recommend_alert = pn.pane.Alert("", alert_type="info", visible=False,
                                             sizing_mode="stretch_width", margin=(5, 5, 0, 5))

        self.setting_select = pn.widgets.Select.from_param(self.param.offset,
                                                           label="Offset setting", width=180)
        self.base_select = pn.widgets.Select.from_param(
            self.param.base, label="Base image (level \u00b7 exposure)", width=460)
        self.channel_select = pn.widgets.RadioButtonGroup.from_param(
            self.param.channel, label="Channel", color="default", align="end", width=220)
        self.param.watch(self._on_channel, "channel")

        self.setup_pane = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.channel_table = _table(pd.DataFrame(), "ccd-flat-channels")
        self.held_pane = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.held_table = _table(pd.DataFrame(), "ccd-flat-held-out")
        self.flag_pane = pn.pane.Markdown("", sizing_mode="stretch_width", styles=_MUTED)
        self.notes_pane = pn.pane.Markdown("", sizing_mode="stretch_width", styles=_MUTED)

    def _build_pair_widgets(self) -> None:
        """Before and after: the frame choice, the SNUP table, the two linked views."""
        self.frame_select = pn.widgets.Select.from_param(
            self.param.frame, label="Frame (any flat of the setting)", sizing_mode="stretch_width")
        self.snup_title = pn.pane.Markdown("", sizing_mode="stretch_width", margin=(0, 10))
        self.rule_pane = pn.pane.Markdown("", sizing_mode="stretch_width", styles=_MUTED)
        self.snup_table = _table(pd.DataFrame(), "ccd-flat-snup")
        self.frame_alert = pn.pane.Alert("", alert_type="danger", visible=False,
                                         sizing_mode="stretch_width")
        # two views sharing their x and y ranges (linked zoom), the pointer read in both
        self.before_view = _image_view("gray", "DN", "ccd-flat-before")
        self.after_view = _image_view("gray", "DN", "ccd-flat-after", link=self.before_view)
        for view in (self.before_view, self.after_view):
            view.on_pointer = lambda x, y: self._on_pointer(x=x, y=y)
        self.before_pane = _view_pane(self.before_view)
        self.after_pane = _view_pane(self.after_view)
        # a FlexBox, not a Row: on a narrow window (1024 px) the second view wraps below the
        # first instead of overflowing the card
        self.pair_pane = pn.FlexBox(self.before_pane, self.after_pane,
                                    sizing_mode="stretch_width", css_classes=["ccd-flat-pair"])
        self.readout = pn.pane.Markdown("Move the cursor over either image to read the pixel "
                                        "before and after correction.",
                                        sizing_mode="stretch_width", css_classes=["ccd-readout"])

    def _build_analysis_widgets(self) -> None:
        """The analyses: the G and O maps, averaging, linearity, study, settings, K̂."""
        # maps
        self.g_view = _image_view("viridis", "G", "ccd-flat-gmap")
        self.o_view = _image_view("magma", "O (DN)", "ccd-flat-omap", link=self.g_view)
        self.g_pane = _view_pane(self.g_view)
        self.o_pane = _view_pane(self.o_view)
        self.maps_pane = pn.FlexBox(self.g_pane, self.o_pane, sizing_mode="stretch_width",
                                    css_classes=["ccd-flat-maps"])
        self.map_readout = pn.pane.Markdown("", sizing_mode="stretch_width")

        # averaging, linearity, study, settings, K
        self.avg_pane = pn.pane.HoloViews(None, sizing_mode="stretch_width", min_height=340,
                                          linked_axes=False, css_classes=["ccd-flat-avg"])
        self.avg_title = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.avg_table = _table(pd.DataFrame(), "ccd-flat-avg-table")
        self.lin_pane = pn.pane.HoloViews(None, sizing_mode="stretch_width", min_height=380,
                                          linked_axes=False, css_classes=["ccd-flat-lin"])
        self.lin_table = _table(pd.DataFrame(), "ccd-flat-lin-table")
        self.lin_notes = pn.pane.Markdown("", sizing_mode="stretch_width", styles=_MUTED)
        self.study_pane = pn.pane.HoloViews(None, sizing_mode="stretch_width", min_height=360,
                                            linked_axes=False, css_classes=["ccd-flat-study"])
        self.study_table = pn.widgets.Tabulator(
            pd.DataFrame(), disabled=True, show_index=False, sizing_mode="stretch_width",
            layout="fit_data_fill", selectable=False, height=360,
            frozen_columns=["corrected group"])
        self.study_alert = pn.pane.Alert("", alert_type="warning", visible=False,
                                         sizing_mode="stretch_width")
        self.zero_table = _table(pd.DataFrame(), "ccd-flat-zero-table")
        self.settings_table = _table(pd.DataFrame(), "ccd-flat-settings")
        self.settings_note = pn.pane.Markdown("", sizing_mode="stretch_width", styles=_MUTED)
        self.kmap_table = _table(pd.DataFrame(), "ccd-flat-kmap")
        self.kmap_note = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.kmap_alert = pn.pane.Alert("", alert_type="info", visible=False,
                                        sizing_mode="stretch_width")

    def _build_content(self) -> None:
        """The page's content: the correction, before and after, the analyses' tabs, notes."""
        # the choices first, then the figure (before and after), then the correction's
        # details: the first view at 1400 x 900 shows the corrected frame
        setup = pn.Card(
            pn.FlexBox(self.setting_select, self.base_select, self.channel_select,
                       sizing_mode="stretch_width"),
            self.recommend_alert,
            title="Correction: dark and base images", sizing_mode="stretch_width",
            collapsible=False)
        details = pn.Card(
            self.rule_pane, self.setup_pane, self.channel_table, self.flag_pane, self.held_pane,
            self.held_table, title="The correction's inputs and its held-out check",
            sizing_mode="stretch_width", collapsible=False)
        before_after = pn.Card(
            self.frame_select, self.frame_alert, self.pair_pane, self.readout, self.snup_title,
            self.snup_table,
            title="Before and after correction (linked zoom)", sizing_mode="stretch_width",
            collapsible=False)
        self.tabs = pn.Tabs(
            ("Gain and offset maps",
             pn.Column(pn.pane.Markdown(
                 "G (eq. 3) and O (eq. 4) of the chosen channel; zooming one map zooms the "
                 "other. Flagged pixels are marked with red crosses.", styles=_MUTED),
                 self.maps_pane, self.map_readout, sizing_mode="stretch_width")),
            ("Averaging (Table 1)",
             pn.Column(self.avg_title, self.avg_pane, self.avg_table,
                       sizing_mode="stretch_width")),
            ("Linear range (Fig. 2)",
             pn.Column(self.lin_pane, self.lin_table, self.lin_notes,
                       sizing_mode="stretch_width")),
            ("Base image study (Fig. 3, Tables 3\u20135)",
             pn.Column(pn.pane.Markdown(
                 "SNUP (%) after correction of every flat group (columns of the heat map) with "
                 "every candidate base image (rows), mean over the group's frames; the top row "
                 "is the uncorrected SNUP. A group corrected by itself looks better than it is: "
                 "its noise is in G.", styles=_MUTED),
                 self.study_alert, self.study_pane, self.study_table,
                 sizing_mode="stretch_width")),
            ("Dark image settings (Table 2)",
             pn.Column(self.zero_table, self.settings_note, self.settings_table,
                       sizing_mode="stretch_width")),
            ("K\u0302 against G",
             pn.Column(self.kmap_alert, self.kmap_note, self.kmap_table,
                       sizing_mode="stretch_width")),
            sizing_mode="stretch_width", dynamic=True)
        self.content = pn.Column(
            setup, self.zero_alert, before_after, details,
            pn.Card(self.tabs, title="Analyses", sizing_mode="stretch_width",
                    collapsible=False),
            pn.Card(self.notes_pane, title="Notes", sizing_mode="stretch_width",
                    collapsed=True),
            sizing_mode="stretch_width", visible=False)

    # ================================================================== layout =============
    def __panel__(self) -> pn.viewable.Viewable:
        intro = ("The corrected image DL_c = O + G\u00b7DL (de Lasarte et al. 2007, eqs. 1\u20134) "
                 "removes the pixel-to-pixel gain and the vignetting measured on a base "
                 "correction image DL_B above the dark image DL_0; the spatial nonuniformity "
                 "SNUP = 100\u00b7\u03c3/mean (eq. 5) says how well. Choose the base image "
                 "inside the camera's linear range.")
        return pn.Column(
            *heading("Flat field", intro),
            self.info_alert, self.error_alert, self.content,
            sizing_mode="stretch_width", name="Flat field")

    # ============================================================ widget events ============
    def _schedule(self, step: Any) -> None:
        if self.auto:
            pn.state.execute(step)

    def _choose(self, choice: str, objects: Any, value: Any) -> None:
        """Set a choice's options and value as the page's own: no event, so no step is
        scheduled (the caller shows it); the user's choices schedule theirs."""
        widget = {"offset": self.setting_select, "base": self.base_select,
                  "frame": self.frame_select, "channel": self.channel_select}[choice]
        set_choices(self, {choice: (widget, objects, value)}, trigger=False)

    def _on_session(self, *events: Any) -> None:
        self._session = None
        if self.auto:
            pn.state.execute(self.refresh)

    @param.depends("offset", watch=True)
    def _on_setting(self) -> None:
        self._schedule(self.show_setting)

    @param.depends("base", watch=True)
    def _on_base(self) -> None:
        self._schedule(self.show_base)

    @param.depends("frame", watch=True)
    def _on_frame(self) -> None:
        self._schedule(self.show_frame)

    def _on_channel(self, event: Any = None) -> None:
        self._render_maps()
        self._render_pair()
        self._render_linearity()
        self._render_study()

    def _in_document(self, render: Any) -> None:
        """Run ``render`` in a callback of the browser session's document (Panel's
        ``state.execute(..., schedule=True)``: holding the document lock, so replaced plots and
        linked ranges reach the browser), or at once outside a server."""
        _in_document(self._doc, render)

    # ============================================================ computing ================
    async def _get(self, cache: dict, key: Any, func: Any, *args: Any, label: str,
                   optional: bool = False, **kwargs: Any) -> tuple[Any, str]:
        """``cache[key]`` (a cache of ``state.results.flat``), computed off the UI thread and
        stored when missing; the result and the error message. ``optional`` failures do not
        stay in the app-wide ``state.error``."""
        cached = cache.get(key)
        if cached is not None:
            return cached, ""
        before = self.state.error
        result = await self.state.compute(func, *args, label=label, **kwargs)
        if result is None:
            error = self.state.error or "the computation did not finish (session changed?)"
            if optional:
                self.state.error = before
            return None, error
        cache[key] = result
        return result, ""

    @property
    def _cache(self) -> Any:
        """The flat-field results of the loaded session (:class:`ccdcore_app.state.FlatResults`)."""
        return self.state.results.flat

    def _current(self, session: Session, generation: int | None = None,
                 base_generation: int | None = None) -> bool:
        """True while ``session`` is shown and no newer setting (base) request was made."""
        return self.state.session is session and self._session is session and \
            self._settings.is_current(generation) and self._bases.is_current(base_generation)

    async def refresh(self) -> None:
        """Show the current session: its settings, then :meth:`show_setting`."""
        session = self._new_session()
        if session is None:
            return
        self.recommendation = self.flat = self.view = None
        if not session.by_role("flat"):
            self._info(NO_FLAT_MESSAGE)
            return
        self._info("")
        settings = list(session.settings())
        self._choose("offset", settings, settings[0] if settings else None)
        self.setting_select.visible = bool(settings)
        names = channel_names(session.camera.layout)
        # the options and the value together (an RGB session after a mono one: the widget
        # must never see a value outside its options)
        self._choose("channel", list(names), self.channel if self.channel in names else names[0])
        self.channel_select.visible = len(names) > 1
        self.content.visible = True
        await self.show_setting()

    async def show_setting(self) -> None:
        """The chosen offset setting: the base recommendation and base choices, linearity,
        the zero-dark check; then :meth:`show_base` and the setting-wide studies."""
        session = self._session
        if session is None or not self._current(session):
            return
        generation = self._settings.next()
        setting = self.offset or None
        self.setting = setting
        self._set_error("")
        self._study = None
        self._in_document(self._render_study)
        try:
            groups = session.flat_groups(setting=setting)
        except CcdError as err:
            self._set_error(str(err))
            return
        if not groups:
            self._info(f"No flat frames with setting = {setting!r}. " + NO_FLAT_MESSAGE)
            return
        self.content.loading = True
        try:
            rec, error = await self._get(self._cache.recommendations, setting, recommend_base,
                                         session, setting=setting,
                                         label="base image recommendation")
            if not self._current(session, generation):
                return
            self.recommendation = rec
            if rec is None:
                self._set_error(error)
            self._fill_bases(groups, rec)
            self._records = {r.relpath: r for recs in groups.values() for r in recs}
            frame = self.frame if self.frame in self._records else default_frame(rec, groups)
            self._choose("frame", list(self._records), frame)
            self._in_document(self._render_linearity)
            zero, zerr = await self._get(self._cache.zero_dark, setting, _zero_dark, session,
                                         setting, label="zero-dark check", optional=True)
            if not self._current(session, generation):
                return
            self._render_zero(zero, zerr)
        finally:
            if self._current(session, generation):
                self.content.loading = False
        await self.show_base()
        if self._current(session, generation):
            await self._show_studies(session, setting, generation)

    def _fill_bases(self, groups: dict, rec: BaseRecommendation | None) -> None:
        cands = {c["key"]: c for c in rec.candidates} if rec is not None else {}
        options: dict[str, tuple] = {}
        for key, recs in groups.items():
            label = f"{flat_plots.group_label(key)} \u2014 {len(recs)} frame" \
                    f"{'s' if len(recs) != 1 else ''}"
            c = cands.get(key)
            if c is not None and c["mean_dn"]:
                label += f", mean {np.mean(list(c['mean_dn'].values())):.0f} DN"
                if not c["in_linear_range"]:
                    label += ", outside the linear range"
            if rec is not None and key == rec.key:
                label += " (recommended)"
            options[label] = key
        keep = self.base if self.base in groups else None
        value = keep or (rec.key if rec is not None else next(iter(groups)))
        self._choose("base", options, value)
        if rec is not None:
            self.recommend_alert.object = (
                f"**Recommended base image: {flat_plots.group_label(rec.key)}** \u2014 "
                f"{rec.reason}.")
            self.rule_pane.object = f"*How the base image is recommended: {rec.rule}.*"
            self.recommend_alert.visible = True
        else:
            self.rule_pane.object = ""
            self.recommend_alert.visible = False

    async def show_base(self) -> None:
        """The chosen base image: G and O (darks at its exposure), the maps, the averaging
        table of its frames, then :meth:`show_frame`."""
        session = self._session
        key = self.base
        if session is None or key is None or not self._current(session):
            return
        generation = self._bases.next()
        setting = self.setting
        self.content.loading = True
        try:
            flat, error = await self._get(self._cache.fields, (setting, tuple(key)),
                                          flat_field_from_session, session, setting=setting,
                                          base=key, held_out=True,
                                          label="flat-field maps G, O")
            if not self._current(session, base_generation=generation):
                return
            self.flat = flat
            if flat is None:
                self._set_error(error)
                self.view = None
                self._in_document(self._render_flat)
                return
            self._set_error("")
            self._in_document(self._render_flat)
        finally:
            if self._current(session, base_generation=generation):
                self.content.loading = False
        await self.show_frame()
        if not self._current(session, base_generation=generation):
            return
        records = session.flat_groups(setting=setting).get(tuple(key), ())
        avg, aerr = await self._get(self._cache.averaging, (setting, tuple(key)), _averaging,
                                    session, records, session.camera.layout,
                                    label="SNUP against averaging", optional=True)
        if self._current(session, base_generation=generation):
            self._in_document(partial(self._render_averaging, avg, aerr, key))

    async def show_frame(self) -> None:
        """The chosen frame before and after correction with the current G, O."""
        session, flat = self._session, self.flat
        rec = self._records.get(self.frame)
        if session is None or flat is None or rec is None or not self._current(session):
            return
        generation = self._settings.ticket
        self.pair_pane.loading = True
        try:
            # the page's own (always recomputed: it is cheap)
            before = self.state.error
            view = await self.state.compute(frame_view, session, rec, flat,
                                            label="before/after correction")
            error = self.state.error
            if view is None:
                self.state.error = before
        finally:
            self.pair_pane.loading = False
        if not self._current(session, generation) or flat is not self.flat:
            return
        if view is None:
            self.view = None
            self.frame_alert.param.update(object=f"**Cannot correct the frame:** {error}",
                                          visible=True)
        else:
            self.frame_alert.visible = False
            self.view = view
        self._in_document(self._render_frame)

    async def _show_studies(self, session: Session, setting: str | None,
                            generation: int) -> None:
        """Setting-wide results: base-image study, Table 2, K̂ comparison (after the rest)."""
        study, serr = await self._get(self._cache.studies, setting, base_image_study,
                                      session, setting=setting, label="base-image study",
                                      optional=True)
        if not self._current(session):
            return
        self._study = study
        self.study_alert.param.update(object=f"**Base-image study not available:** {serr}",
                                      visible=study is None)
        self._in_document(self._render_study)
        if len(session.settings()) > 1:
            cache = self._cache
            comp, cerr = cache.settings, ""
            if comp is None:
                before = self.state.error
                comp = await self.state.compute(compare_dark_settings, session,
                                                label="dark settings comparison")
                if comp is None:
                    cerr = self.state.error or "the computation did not finish"
                    self.state.error = before
                elif self._current(session):
                    cache.settings = comp
            if not self._current(session):
                return
            self._render_settings(comp, cerr)
        else:
            self._render_settings(None, "the session has one offset setting: capture flats "
                                        "and darks at a second setting (e.g. a zero and a "
                                        "non-zero dark image) to compare them")
        kmap, kerr = await self._get(self._cache.kmaps, setting, kmap_comparison, session,
                                     setting, label="K\u0302 against G", optional=True)
        if self._current(session):
            self._render_kmap(kmap, kerr)

    # ============================================================ rendering ================
    @batched
    def _render_flat(self) -> None:
        flat = self.flat
        if flat is None:
            self.setup_pane.object = ""
            self.channel_table.object = pd.DataFrame()
            self.flag_pane.object = ""
            self.g_pane.object = self.o_pane.object = None
            self.notes_pane.object = ""
            self.held_pane.object = ""
            self.held_table.object = pd.DataFrame()
            return
        n_base = flat.base.n
        self.setup_pane.object = (
            f"**Base image DL_B:** {flat_plots.group_label(flat.base_key)} "
            f"({n_base} frame{'s' if n_base != 1 else ''} averaged) \u00b7 "
            + flat_plots.dark_text(flat)
            + (f" \u00b7 **setting** {flat.setting}" if flat.setting else ""))
        check = flat.held_out
        self.held_pane.object = (
            "**Held-out check:** not made (it needs three or more flats in the base group)"
            if check is None else
            f"**Held-out check: {check.verdict}** \u2014 {check.held_out} corrected with maps "
            f"from the other {check.n_fit} flats of the group; {check.rule} "
            f"(factor {check.factor:g}).")
        self.held_table.object = flat_plots.held_out_frame(check)
        self.channel_table.object = pd.DataFrame([
            {"channel": c.name, "k (DN)": f"{c.k:.2f}", "\u27e8DL_0\u27e9 (DN)":
             f"{c.dark_level:.2f}", "\u27e8DL_B\u27e9 (DN)": f"{c.base_level:.2f}",
             "flagged pixels": f"{c.n_flagged} of {c.n_pixels}"} for c in flat.channels])
        n_flag = int(flat.flags.sum())
        self.flag_pane.object = (
            f"**{n_flag} flagged pixel{'s' if n_flag != 1 else ''}** (c = {flat.noise_limit:g}, "
            f"window {flat.window}): {flat.flag_rule}.")
        notes = list(flat.notes)
        if self.recommendation is not None:
            notes += list(self.recommendation.linearity.notes)
        self.notes_pane.object = "\n".join(f"- {n}" for n in notes) or "No notes."
        self._render_maps()

    def _plane(self, array: np.ndarray, layout: str) -> np.ndarray:
        return split_channels(array, layout)[self.channel]

    @batched
    def _render_maps(self) -> None:
        flat = self.flat
        if flat is None or self.channel not in channel_names(flat.layout):
            for view in (self.g_view, self.o_view):
                view.show(None)
            self.g_pane.visible = self.o_pane.visible = False
            return
        G = self._plane(flat.G, flat.layout)
        O = self._plane(flat.O, flat.layout)
        flags = self._plane(flat.flags, flat.layout)
        self.g_view.show(G, clim=plots.auto_clim(G), title=f"G \u2014 channel {self.channel}")
        self.o_view.show(O, clim=plots.auto_clim(O),
                         title=f"O \u2014 channel {self.channel} (DN)")
        rows, cols = flat_plots.flagged_pixels(flags)
        self.g_view.set_points(rows, cols)
        self.g_pane.visible = self.o_pane.visible = True
        self.map_readout.object = (
            f"Channel {self.channel}: G from {float(G.min()):.4f} to {float(G.max()):.4f} "
            f"(mean {float(G.mean()):.4f}); O from {float(O.min()):.2f} to "
            f"{float(O.max()):.2f} DN; {int(flags.sum())} flagged.")

    def _render_frame(self) -> None:
        view = self.view
        if view is None:
            self.snup_title.object = ""
            self.snup_table.object = pd.DataFrame()
            self._hide_pair()
            return
        self.snup_title.object = (
            f"**SNUP of `{view.relpath}`** (100\u00b7\u03c3/mean \u00b1 standard error, eq. 5), "
            f"corrected with base {flat_plots.group_label(view.base_key)}:")
        self.snup_table.object = flat_plots.snup_frame(view.before, view.after)
        self._render_pair()

    @batched
    def _render_pair(self) -> None:
        view, flat = self.view, self.flat
        if view is None or flat is None or self.channel not in channel_names(flat.layout):
            self._hide_pair()
            return
        raw = self._plane(view.raw, flat.layout)
        cor = self._plane(view.corrected, flat.layout)
        clim = plots.auto_clim(np.concatenate([np.ravel(raw), np.ravel(cor)]))
        self.before_view.show(raw, clim=clim, title=f"Before \u2014 {self.channel}")
        self.after_view.show(cor, clim=clim, title=f"After \u2014 {self.channel}")
        self.before_pane.visible = self.after_pane.visible = True
        self.readout.object = ("Move the cursor over either image to read the pixel before and "
                               "after correction.")

    @batched
    def _hide_pair(self) -> None:
        for view in (self.before_view, self.after_view):
            view.show(None)
        self.before_pane.visible = self.after_pane.visible = False

    def release(self) -> None:
        """Let go of the frames and maps shown (the browser session ended; nothing is sent)."""
        for view in (self.before_view, self.after_view, self.g_view, self.o_view):
            view.release()
        self.flat = self.view = self.recommendation = None
        self._study = self._zero = None

    def _on_pointer(self, x: float | None = None, y: float | None = None) -> None:
        view, flat = self.view, self.flat
        if view is None or flat is None or x is None or y is None:
            return
        raw = self._plane(view.raw, flat.layout)
        col, row = int(round(x)), int(round(y))
        if not (0 <= row < raw.shape[0] and 0 <= col < raw.shape[1]):
            return
        cor = self._plane(view.corrected, flat.layout)
        G = self._plane(flat.G, flat.layout)
        O = self._plane(flat.O, flat.layout)
        flagged = " (flagged)" if self._plane(flat.flags, flat.layout)[row, col] else ""
        self.readout.object = (
            f"x = {col}, y = {row} ({self.channel}): **{raw[row, col]:g} DN \u2192 "
            f"{cor[row, col]:.2f} DN** (G = {G[row, col]:.4f}, O = {O[row, col]:.2f} DN)"
            f"{flagged}")

    def _render_linearity(self) -> None:
        rec = self.recommendation
        if rec is None:
            self.lin_pane.object = None
            self.lin_table.object = pd.DataFrame()
            self.lin_notes.object = ""
            return
        lin = rec.linearity
        if self.channel in lin.channels:
            self.lin_pane.object = flat_plots.linearity_plot(lin, self.channel)
        self.lin_table.object = flat_plots.linearity_frame(lin)
        self.lin_notes.object = (
            f"A point is linear while it stays within {100 * lin.tolerance:g} % (or "
            f"{lin.abs_tolerance:g} DN) of the line grown from the shortest exposures; the "
            "shaded band is [linear from, non-linear from); the dashed horizontal line is the "
            "saturation onset level and a dashed vertical line the first exposure of a level "
            "past it." + ("".join(f"\n- {n}" for n in lin.notes)))

    def _render_zero(self, zero: Any, error: str) -> None:
        if zero is None:
            self.zero_alert.param.update(
                object=f"**Zero-dark check not available:** {error}", alert_type="info",
                visible=bool(error))
            return
        self._zero = zero
        if zero.clipped:
            where = f" (setting {self.setting})" if self.setting else ""
            self.zero_alert.param.update(
                object=f"**Zero dark image{where}: {ZERO_DARK_MESSAGE}** {zero.warning}.",
                alert_type="warning", visible=True)
        else:
            self.zero_alert.visible = False
        if self._cache.settings is None:
            self.zero_table.object = flat_plots.zero_dark_frame({self.setting or "": zero})

    def _render_averaging(self, avg: Any, error: str, key: Sequence[Any]) -> None:
        if avg is None:
            self.avg_title.object = f"Not available: {error}"
            self.avg_pane.object = None
            self.avg_table.object = pd.DataFrame()
            return
        self.avg_title.object = (
            f"SNUP of the average of the first N of the {avg.n_frames} frames of the base group "
            f"{flat_plots.group_label(key)} (uncorrected). Dashed: ccdcore's prediction "
            "\u221a(SNUP_fixed\u00b2 + SNUP_temporal\u00b2/N): averaging lowers only the "
            "temporal part, the fixed pattern stays.")
        self.avg_pane.object = flat_plots.averaging_plot(avg)
        self.avg_table.object = flat_plots.averaging_frame(avg)

    def _render_study(self) -> None:
        study = self._study
        if study is None:
            self.study_pane.object = None
            self.study_table.value = pd.DataFrame()
            return
        self.study_pane.object = flat_plots.study_heatmap(study, self.channel)
        self.study_table.value = flat_plots.study_frame(study, self.channel)

    def _render_settings(self, comp: Any, error: str) -> None:
        if comp is None:
            self.settings_note.object = f"Table 2 not available: {error}."
            self.settings_table.object = pd.DataFrame()
            return
        self.settings_note.object = (
            "**Table 2** \u2014 mean SNUP (\u00b1 std over the images) after correction of the "
            "flat groups inside the linear range of every setting, each setting with its own "
            "recommended base and darks:")
        self.settings_table.object = flat_plots.settings_frame(comp)
        self.zero_table.object = flat_plots.zero_dark_frame(comp.zero_dark)

    def _render_kmap(self, kmap: Any, error: str) -> None:
        if kmap is None:
            self.kmap_alert.param.update(
                object=f"**The K\u0302 comparison needs more flat groups:** {error}",
                visible=True)
            self.kmap_note.object = ""
            self.kmap_table.object = pd.DataFrame()
            return
        comparison, with_truth = kmap
        self.kmap_alert.visible = False
        truth = ("Residuals: 100\u00b7std of the estimated flat field divided by the "
                 "simulator's true flat field (`truth.json`), overall and high-pass (PRNU only)."
                 if with_truth else "No true flat field in the session folder (`truth.json`): "
                 "no residuals.")
        self.kmap_note.object = (
            f"The held-out group {flat_plots.group_label(comparison.evaluate)} corrected by G "
            f"(base {flat_plots.group_label(comparison.base)}) and by Healey\u2013Kondepudy's "
            f"K\u0302 ({len(comparison.configurations)} flat groups as configurations, window "
            f"{comparison.window}). {comparison.conclusion}\n\n{truth}")
        self.kmap_table.object = flat_plots.kmap_frame(comparison)

    # ============================================================ helpers for tests ========
    @property
    def after_snup(self) -> dict[str, str]:
        """The after-correction SNUP shown per channel (display strings)."""
        df = self.snup_table.object
        if df is None or df.empty:
            return {}
        return dict(zip(df["channel"], df["SNUP after (%)"]))


def create_page(state: AppState) -> FlatFieldPage:
    """Registry entry point: the Flat field page bound to ``state``."""
    return FlatFieldPage(state)
