"""The Maps page: dark and fixed-pattern maps, acquisition planning and scene variation.

Healey & Kondepudy 1994: the dark reference D̂_D with hot/dead flags (sec. V-A), the
fixed-pattern map K̂ with n'_1 and the rejected slopes (eqs. 45–50), the acquisition plan n1, n2
(sec. V-B), the correction check (sec. VII-A) and the scene variation V_S with the variance budget
(sec. VI, VII-B/C, Figs. 3 and 4).

Public objects
--------------
MapsPage
    The page (a :class:`panel.viewable.Viewer`) with three tabs:

    * **Maps**: a grid of rasterised maps with linked zoom, the values of every map under the
      cursor, a histogram per shown map, row and column profiles (tap a map or use the sliders),
      colour range control and export of the selected map as EXR, FITS or 16-bit PNG; the
      summary statistics and the correction check next to them.
    * **Scene**: V_S ± error per patch and per light level, the eq. 57 fit (Fig. 3) and the
      variance budget (Fig. 4) of a chosen patch.
    * **Planning**: n1 and n2 from typed or estimated inputs, with their formulas.
    * **EMVA 1288 spatial** (an EMVA 1288 set with a spatial set only): the spatial
      nonuniformity of EMVA Standard 1288 (release 3.1 sec. 8, release 4.0's row, column and
      pixel parts): DSNU1288 and PRNU1288 with their parts, the spectrograms, the logarithmic and
      accumulated histograms and the profiles (:mod:`ccdcore_report.emva_figures`), computed
      once per session when the tab is first shown (off the UI thread, through the disk cache).

    Warnings that the session has fewer configurations or frames than the plan requires are shown
    at the top of the page; missing frames give an info alert saying what to capture.
create_page(state)
    The registry entry point.
dark_summary(dark), fixed_pattern_summary(fp), correction_summary(check)
    The summary tables (DataFrames: quantity, this session, paper).
scene_patch_frame(scene), scene_level_frame(variation)
    The scene tables (DataFrames).
export_bytes(layer, fmt, clim)
    A map as the bytes of an EXR, FITS or 16-bit PNG file.
missing_sentences(session)
    What the session lacks for this page's estimates, as Markdown sentences made of ccdcore's
    :class:`~ccdcore.product.make.Requirement` texts (:func:`ccdcore.product.make.missing_frames`).
MAPS_ESTIMATES
    The estimates of :func:`ccdcore.product.make.estimate_all` this page shows.
has_emva_spatial(session), emva_spatial_figures(session)
    Whether the session is an EMVA 1288 set with a spatial set; its EMVA 1288 figures (the
    JSON dict of :func:`ccdcore.emva.datasheet.emva_figures`) for the EMVA 1288 spatial tab.
emva_spatial_layout(emva), emva_spatial_text(emva)
    The spatial section's plots as one Bokeh layout; its figures as Markdown.

The tabs live in sibling modules, mixed into :class:`MapsPage`: the Maps tab in
:mod:`ccdcore_app.pages.maps.tab`, the Scene tab in :mod:`ccdcore_app.pages.maps.scene`, the
Planning tab in :mod:`ccdcore_app.pages.maps.planning`; the tables, the export and the EMVA 1288
spatial figures in :mod:`ccdcore_app.pages.maps.tables`.

Every number comes from ccdcore: :func:`ccdcore.product.make.estimate_all` (the same estimates, with
the same parameters, as ``calibrate()`` and the ``ccdcore calibrate`` verb: D̂_D, K̂, the plan and
its warnings, V_S and the correction check on the session's max-intensity frame),
:func:`ccdcore.planning.plan_acquisition`, :func:`ccdcore.product.make.budget_inputs` and
:func:`ccdcore.scene.variance_budget`. Results are shared with the other pages through
``state.results`` (``estimates``; ``ptc``, the noise model, is read and, when missing, filled).
The page's own state (maps shown and selected, the patch, the planning inputs) is declared with
``param``; watchers (``@param.depends(..., watch=True)``) redraw what depends on it, once per
change: the page sets choices together with their options and data through
:func:`ccdcore_app.pages._choices.set_choices`.
"""
from __future__ import annotations

import asyncio
import html
import logging
from typing import Any

import panel as pn
import param

from ccdcore.emva.results import EmvaSummary
from ccdcore.product.make import ESTIMATE_STEPS, estimate_all, missing_frames, requirement
from ccdcore.session import ROLES, Session

from ...plots import maps as map_plots
from ...cache.store import estimates_entry, photon_transfer_entry
from ...batch import batched
from ...image_view import HistogramView, ImageView
from ...state import AppState
from .planning import PAPER_PLAN_INPUTS, PLAN_INPUTS, PlanningTab
from .scene import SceneTab
from .tab import DEFAULT_SHOWN, MapsTab
from .tables import (EXPORT_FORMATS, MAPS_CSS, correction_summary, dark_summary,
                           emva_spatial_figures, emva_spatial_layout, emva_spatial_text,
                           export_bytes, fixed_pattern_summary, has_emva_spatial, maps_alert,
                           scene_level_frame, scene_patch_frame)

__all__ = ["MapsPage", "create_page", "dark_summary", "fixed_pattern_summary",
           "correction_summary", "scene_patch_frame", "scene_level_frame", "export_bytes",
           "missing_sentences", "MAPS_ESTIMATES", "PAPER_PLAN_INPUTS", "PLAN_INPUTS",
           "DEFAULT_SHOWN", "EXPORT_FORMATS", "EMVA_TAB", "has_emva_spatial",
           "emva_spatial_figures", "emva_spatial_layout", "emva_spatial_text"]

log = logging.getLogger(__name__)

#: the estimates of ccdcore.product.make.estimate_all shown on this page (in REQUIREMENTS order);
#: the flat field has its own page
MAPS_ESTIMATES = ("noise", "dark", "fixed_pattern", "plan", "correction_check", "scene")
#: the tab of the EMVA 1288 spatial nonuniformity (an EMVA 1288 set with a spatial set only)
EMVA_TAB = "EMVA 1288 spatial"


def _lacking(what: tuple[str, ...]) -> str:
    """What a session lacks, to follow "No": ``("scene", "ptc", "dark")`` -> "`scene`, `ptc`
    or `dark` frames"; a described frame (not a role) is added with "and no"."""
    roles = [f"`{r}`" for r in what if r in ROLES]
    parts = [r for r in what if r not in ROLES]
    if roles:
        head = roles[0] if len(roles) == 1 else ", ".join(roles[:-1]) + " or " + roles[-1]
        parts.insert(0, f"{head} frames")
    return " and no ".join(parts)


def missing_sentences(session: Session) -> list[str]:
    """What the session lacks for this page's estimates (:data:`MAPS_ESTIMATES`), one Markdown
    sentence per estimate: what is missing, what it is for and what to capture, all in the words
    of ccdcore's requirements (:func:`ccdcore.product.make.missing_frames`)."""
    return [f"**No {_lacking(lacking)}** for {req.purpose}: capture {req.capture}."
            for req, lacking in missing_frames(session, MAPS_ESTIMATES)]


def _purpose(estimate: str) -> str:
    """What an estimate of estimate_all is, for a person (its requirement's purpose)."""
    try:
        return requirement(estimate).purpose
    except KeyError:
        return estimate


# ================================================================================ the page ====
class MapsPage(MapsTab, SceneTab, PlanningTab, pn.viewable.Viewer):
    """Dark and fixed-pattern maps, planning and scene variation (see the module docstring).

    The state of the Maps, Scene and Planning tabs is declared by their mixins
    (:class:`~ccdcore_app.pages.maps.tab.MapsTab`: ``layers``, ``shown``, ``active``,
    ``overview``; :class:`~ccdcore_app.pages.maps.scene.SceneTab`: ``scene``, ``patch``;
    :class:`~ccdcore_app.pages.maps.planning.PlanningTab`: the planning inputs).
    """

    state = param.ClassSelector(class_=AppState, doc="The app state shared by all pages.")
    auto_compute = param.Boolean(default=True, doc=(
        "Compute the maps when the page is shown and the session has dark frames but no "
        "estimates yet."))
    computing = param.Boolean(default=False, precedence=-1, doc=(
        "True while the page computes the estimates (a request meanwhile is ignored)."))
    # ---- the EMVA 1288 spatial tab
    emva = param.ClassSelector(class_=EmvaSummary, default=None, allow_None=True,
                               precedence=-1, doc=(
        "The EMVA 1288 figures of the session (emva_spatial_figures), computed when the EMVA "
        "1288 spatial tab is first shown; None before and for another session."))
    emva_computing = param.Boolean(default=False, precedence=-1, doc=(
        "True while the page computes the EMVA 1288 figures."))

    def __init__(self, state: AppState | None = None, **params: Any):
        super().__init__(state=state if state is not None else AppState(), **params)
        #: the colour range of each map (the one slider shows the selected map's), and the
        #: slider's bounds, step, label and state per map
        self.clims: dict[str, tuple[float, float]] = {}
        self._clim_specs: dict[str, dict[str, Any]] = {}
        self._syncing_clim = False
        #: one view and one histogram per map key, built when the map is first shown, then
        #: fed in place; every map view shares the first one's zoom (linked)
        self.map_views: dict[str, ImageView] = {}
        self.hist_views: dict[str, HistogramView] = {}
        self._map_panes: dict[str, pn.pane.Bokeh] = {}
        self._hist_panes: dict[str, pn.pane.Bokeh] = {}
        self._shown_objects: tuple = (None, None)   # (dark, fp) the maps were built from
        self.plan_result: Any = None          # the planning panel's AcquisitionPlan
        self.budget: Any = None               # the chosen patch's variance budget
        self._build_header()
        self._build_maps_tab()
        self._build_scene_tab()
        self._build_planning_tab()
        self._build_emva_tab()
        self._layout: pn.viewable.Viewable | None = None
        self.state.param.watch(self._on_session, "session")
        self.state.results.param.watch(self._on_results, ["ptc", "estimates"])
        self.state.param.watch(self._on_state_message, ["error", "status", "busy"])
        self._update_plan()
        self._on_session()
        self._on_state_message()

    # ====================================================================== building ========
    def _build_header(self) -> None:
        self.compute_button = pn.widgets.Button(
            label="Compute maps", color="primary", width=170,
            description="D̂_D, K̂, the acquisition plan and V_S from this session's frames "
                        "(the same estimates as `ccdcore calibrate`)")
        self.compute_button.on_click(self._on_compute)
        self.status_pane = pn.pane.Markdown("", sizing_mode="stretch_width", margin=(8, 10))
        self.error_alert = maps_alert("", "danger", css_classes=["ccd-maps-error"])
        self.plan_alert = maps_alert("", "warning", css_classes=["ccd-plan-warning"])
        self.info_alert = maps_alert("", "info", css_classes=["ccd-maps-info"])
        # what the session cannot give, once maps are shown: one line above, the list folded
        # (five paragraphs pushed a real CCD's dark map below the first view)
        self.info_details = pn.pane.Markdown("", sizing_mode="stretch_width",
                                             css_classes=["ccd-maps-info-details"])
        self.info_card = pn.Card(self.info_details, title="", collapsed=True, visible=False,
                                 sizing_mode="stretch_width", css_classes=["ccd-maps-info-card"])

    def _build_emva_tab(self) -> None:
        self.emva_note = pn.pane.Markdown("", sizing_mode="stretch_width",
                                          css_classes=["ccd-emva-note"])
        # one Bokeh layout for the section's twelve plots (one pane: the cheapest to send)
        # (never hidden: Panel's Bokeh pane takes its visibility from the Bokeh model's)
        self.emva_pane = pn.pane.Bokeh(None, sizing_mode="stretch_width",
                                       css_classes=["ccd-emva-spatial"])
        #: the Bokeh layout of ``emva`` (built with it, off the UI thread)
        self._emva_layout: Any = None
        self._emva_status()

    # ======================================================================== layout =======
    def on_show(self) -> None:
        """Called by the navigation each time it shows the page: compute on first show."""
        if self.auto_compute and self._wants_auto_compute():
            pn.state.execute(self.compute)

    def __panel__(self) -> pn.viewable.Viewable:
        if self._layout is None:
            self._layout = self._build_layout()
        return self._layout

    def _build_layout(self) -> pn.viewable.Viewable:
        maps_tab = self._maps_tab_layout()
        scene_tab = self._scene_tab_layout()
        planning_tab = self._planning_tab_layout()
        # a button bar switching the content (Bokeh's Tabs lay a grid of fixed-size plots out
        # at zero size; swapping the content also renders each view only when it is shown)
        emva_tab = pn.Column(self.emva_note, self.emva_pane, sizing_mode="stretch_width",
                             name=EMVA_TAB)
        self._tab_views = {"Maps": maps_tab, "Scene": scene_tab, "Planning": planning_tab,
                           EMVA_TAB: emva_tab}
        self.tab_bar = pn.widgets.RadioButtonGroup(
            options=self._tab_names(), value="Maps", color="primary",
            variant="outline", css_classes=["ccd-maps-tabs"], margin=(10, 10, 0, 10))
        self.tab_content = pn.Column(maps_tab, sizing_mode="stretch_width")
        self.tab_bar.param.watch(self._on_tab, "value")
        return pn.Column(
            pn.pane.Markdown("## Maps", css_classes=["ccd-page-title"]),
            pn.Row(self.compute_button, self.status_pane, sizing_mode="stretch_width"),
            self.error_alert, self.plan_alert, self.info_alert, self.info_card, self.tab_bar,
            pn.layout.Divider(margin=(0, 10)), self.tab_content,
            sizing_mode="stretch_width", name="Maps", stylesheets=[MAPS_CSS])

    def _tab_names(self) -> list[str]:
        """The tabs the session has (the EMVA 1288 spatial one for an EMVA set with a spatial
        set only)."""
        return [name for name in self._tab_views
                if name != EMVA_TAB or has_emva_spatial(self.state.session)]

    def _update_tabs(self) -> None:
        if self._layout is None:
            return
        names = self._tab_names()
        shown = self.tab_bar.value if self.tab_bar.value in names else "Maps"
        self.tab_bar.param.update(options=names, value=shown)
        if shown == EMVA_TAB and self.emva is None:      # another EMVA set, its tab shown
            pn.state.execute(self.compute_emva)

    def _on_tab(self, event: Any = None) -> None:
        self.tab_content.objects = [self._tab_views[self.tab_bar.value]]
        if self.tab_bar.value == EMVA_TAB and self.emva is None:
            pn.state.execute(self.compute_emva)

    # ===================================================================== computing ========
    def _wants_auto_compute(self) -> bool:
        s = self.state.session
        return (s is not None and not self.computing and bool(s.roles().get("dark"))
                and self.state.results.estimates is None and not self.state.busy)

    async def _on_compute(self, event: Any = None) -> None:
        await self.compute()

    async def compute(self) -> None:
        """Compute D̂_D, K̂, the plan, V_S and the correction check (``estimate_all``, off the
        UI thread) and publish them as ``state.results.estimates`` (the noise model, when the
        Photon transfer page has not made it, as ``state.results.ptc``)."""
        session = self.state.session
        if session is None or self.computing:
            return
        self.computing = True
        try:
            results = self.state.results
            noise, options = results.ptc, {"emva1288": False}
            name, params = estimates_entry(noise, **options)
            est = await self.state.cached_compute(
                name, params, estimate_all, session, noise=noise, steps=ESTIMATE_STEPS,
                pass_progress=True,
                label="dark reference, K̂, plan, scene variation and correction check",
                **options)
            if est is not None and self.state.session is session:
                results.param.update(estimates=est,
                                     ptc=est.noise if est.noise is not None else results.ptc)
                if noise is None and est.noise is not None:
                    await self._link_cached(est, options)
        finally:
            self.computing = False

    async def _link_cached(self, est: Any, options: dict[str, Any]) -> None:
        """Estimates made with their own noise model are also those given that model (the
        Photon transfer page's full-frame fit when it ran first) and hold photon_transfer's
        full-frame result: the disk cache learns both (links, not copies)."""
        state, cache = self.state, self.state.cache
        key = await state.cache_key(*estimates_entry(None, **options))
        if cache is None or key is None:
            return
        ptc_key = await state.cache_key(*photon_transfer_entry(None))
        given_key = await state.cache_key(*estimates_entry(est.noise, **options))

        def store() -> None:
            if given_key is not None:
                cache.link(given_key, key)
            if ptc_key is not None and cache.get(ptc_key) is None:
                cache.put(ptc_key, est.noise)
        await asyncio.to_thread(store)

    async def compute_emva(self) -> None:
        """Compute the EMVA 1288 figures of the session (:func:`emva_spatial_figures`, off the
        UI thread, through the disk cache) for the EMVA 1288 spatial tab, once per session."""
        session = self.state.session
        if not has_emva_spatial(session) or self.emva_computing or self.emva is not None:
            return
        self.emva_computing = True
        try:
            found = await self.state.cached_compute(
                "emva_figures", {"with_ptc": False}, emva_spatial_figures, session,
                label="the EMVA 1288 spatial nonuniformity")
            if found is not None and self.state.session is session:
                # twelve figures (some 0.3 s): built off the UI thread too
                layout = await asyncio.to_thread(emva_spatial_layout, found)
                if self.state.session is session:
                    self._emva_layout = layout
                    self.emva = found
        finally:
            self.emva_computing = False
        if self.state.session is not session:          # opened meanwhile: its own figures
            self._update_tabs()

    @param.depends("emva", watch=True)
    @batched
    def _show_emva(self) -> None:
        if self.emva is None:
            self._emva_layout = None
        self.emva_pane.object = self._emva_layout
        self._emva_status()

    @param.depends("emva_computing", watch=True)
    def _emva_status(self) -> None:
        if self.emva is not None:
            text = emva_spatial_text(self.emva)
        elif self.emva_computing:
            text = "Computing the EMVA 1288 figures … (progress and **Cancel** in the header)"
        else:
            text = ("The EMVA 1288 figures are computed when this tab is shown"
                    + (" (the last try failed: see the error above; show the tab again to "
                       "retry)." if self.state.error else "."))
        self.emva_note.object = text

    @param.depends("computing", watch=True)
    def _on_computing(self) -> None:
        self.compute_button.loading = self.computing
        self._update_info(self.state.session)

    # ===================================================================== watchers =========
    def _on_session(self, event: Any = None) -> None:
        self.compute_button.disabled = self.state.session is None
        self.emva = None
        self._update_tabs()
        self._refresh()
        if event is not None and self._layout is not None and self.auto_compute \
                and self._wants_auto_compute():
            pn.state.execute(self.compute)

    def _on_results(self, *events: Any) -> None:
        self._refresh()

    def _on_state_message(self, *events: Any) -> None:
        # the step and frame counts are in the header (a text changing four times a second
        # here would make the browser lay this page out again each time)
        self.status_pane.object = "Computing… (progress and **Cancel** in the header)" \
            if self.state.busy else ""
        self._update_errors()
        self._update_info(self.state.session)

    # ====================================================================== refresh =========
    @batched
    def _refresh(self) -> None:
        """Bring every tab in line with ``state.session`` and ``state.results``."""
        session, results = self.state.session, self.state.results
        dark, fp = results.dark, results.fixed_pattern
        if dark is not self._shown_objects[0] or fp is not self._shown_objects[1]:
            self._shown_objects = (dark, fp)
            self._set_layers(map_plots.map_layers(dark, fp))
        self._update_stats(session, results)
        self._update_errors()
        self._update_info(session)
        self._update_plan_warnings(results.estimates)
        self._set_scene(results.scene)
        self._prefill_plan(results)

    def _update_errors(self) -> None:
        """The app's error and the estimates whose frames the method refused (``failed``)."""
        parts = [f"**Error:** {html.escape(self.state.error)}"] if self.state.error else []
        est = self.state.results.estimates
        if est is not None:
            parts += [f"**Not estimated — {html.escape(_purpose(s.estimate))}:** "
                      f"{html.escape(s.reason)}" for s in est.skipped if s.code == "failed"]
        text = "\n\n".join(parts)
        self.error_alert.object = text
        self.error_alert.visible = bool(text)

    def _update_info(self, session: Session | None) -> None:
        if session is None:
            text = "Open a session on the Session page; the Planning tab works without one."
        else:
            # estimates skipped for missing frames say so in missing_sentences; those skipped
            # because an estimate they build on is missing, and the remarks, are notes
            est = self.state.results.estimates
            lines = missing_sentences(session)
            if est is not None:
                lines += [f"Note: {_purpose(s.estimate)} not made: {s.reason}"
                          for s in est.skipped if s.code in ("needs", "not-applicable")]
            elif session.roles().get("dark") and not self.computing and not self.state.error:
                lines.insert(0, "Press **Compute maps** to estimate D̂_D, K̂, the plan and V_S.")
            text = "\n\n".join(lines)
            if est is not None and len(lines) > 1:
                # maps are shown: the list of what cannot be made folds away
                self.info_details.object = text
                self.info_card.param.update(
                    title=f"{len(lines)} estimates this session's frames cannot give (open "
                          "for what to capture)", visible=True)
                self.info_alert.param.update(object="", visible=False)
                return
        self.info_card.visible = False
        self.info_alert.object = text
        self.info_alert.visible = bool(text)

    def _update_plan_warnings(self, est: Any) -> None:
        warnings = est.plan_warnings if est is not None and est.plan is not None else ()
        if warnings:
            items = "\n".join(f"- {html.escape(w)}" for w in warnings)
            text = ("**This session has fewer frames than the acquisition plan requires "
                    f"(sec. V-B)** — K̂ is less accurate than the plan's target:\n\n{items}")
        else:
            text = ""
        self.plan_alert.object = text
        self.plan_alert.visible = bool(text)

    def release(self) -> None:
        """The browser session ended: drop the maps (no watcher runs, nothing is redrawn)."""
        for view in self.map_views.values():
            view.release()
        with param.parameterized.discard_events(self):
            self.layers = {}
            self.emva = None
        self._emva_layout = None


def create_page(state: AppState) -> MapsPage:
    """Registry entry point: the Maps page bound to ``state``."""
    return MapsPage(state)
