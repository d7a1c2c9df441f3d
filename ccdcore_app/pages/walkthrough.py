"""The Walkthrough page: a guided calibration in eight steps, each with its own URL.

Each step says in plain words what it does (symbols and equation numbers in a card below), shows
its plot, and ends in a gate (:mod:`ccdcore.guide`): what passed or failed, why, and what to
capture or change next. A step whose frames are missing says so and is skipped; it never blocks
the rest. Steps can be revisited and changed: a change (the photon-transfer levels left out, the
robust mode, the plan's inputs, a new session) drops the results of the steps after it, which
recompute when shown.

The steps are :data:`ccdcore.guide.STEPS`: plan (:mod:`ccdcore.capture`), session, dark,
photon transfer, fixed pattern and flat field, response, verify and export (the calibration
product and the report). The chosen step is in the URL (``?page=walkthrough&step=ptc``), so a
colleague can be sent to it.

Public objects
--------------
WalkthroughPage
    The page (a :class:`panel.viewable.Viewer`); its state is declared with ``param``: the step,
    the plan's inputs, the photon-transfer options, the export folder, the gates.
create_page(state)
    The registry entry point.
STATUS_ICONS
    The mark of each gate status in the step list.
"""
from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pandas as pd
import panel as pn
import param

from ccdcore import guide
from ccdcore.capture import CapturePlan, plan_captures
from ccdcore.errors import CcdError
from ccdcore.guide import STEPS, Gate, GateStatus
from ccdcore.product import missing_frames, requirement
from ccdcore.progress import Progress, within
from ccdcore.session import Session

from ..batch import batched, in_document
from ..image_view import ImageView, view_pane
from ccdcore_report.ptc import PtcFigures
from ..response_plots import hdr_views
from ..state import AppState
from ._messages import PageMessages
from ._styles import MUTED, TABLE_CSS, heading

__all__ = ["WalkthroughPage", "create_page", "STATUS_ICONS", "DOWNSTREAM"]

SLUGS = [s.slug for s in STEPS]
#: the mark of each gate status in the step list (and the alert type of its gate)
STATUS_ICONS = {GateStatus.PASS: "\u2714", GateStatus.WARN: "\u26a0",
                GateStatus.FAIL: "\u2716", GateStatus.SKIP: "\u2013", None: "\u25cb"}
_ALERTS = {GateStatus.PASS: "success", GateStatus.WARN: "warning", GateStatus.FAIL: "danger",
           GateStatus.SKIP: "secondary", None: "light"}
_BUTTONS = {GateStatus.PASS: "success", GateStatus.WARN: "warning", GateStatus.FAIL: "danger",
            GateStatus.SKIP: "light", None: "light"}
#: the steps whose results a change in a step makes stale (they recompute when shown)
DOWNSTREAM: dict[str, tuple[str, ...]] = {
    "plan": (),
    "session": ("dark", "ptc", "emva", "pattern", "response", "verify", "report", "export"),
    "dark": ("pattern", "verify", "report", "export"),
    "ptc": ("emva", "pattern", "verify", "report", "export"),
    "pattern": ("verify", "report", "export"), "response": ("verify", "report", "export"),
    "verify": ("report", "export"), "export": ()}
IMAGE_WIDTH = 360


#: the dark step lists the dark level per exposure as a table up to this many exposures, and
#: plots it against the exposure beyond
DARK_TABLE_MAX = 8


def dark_level_columns(levels: list[dict[str, Any]]) -> dict[str, Any]:
    """The dark step's plot of dark level against exposure, as Bokeh source columns: the levels
    of :func:`ccdcore.guide.dark_step` with a known exposure, sorted by it: ``exposure`` (s),
    ``mean`` (DN), ``sem`` (its standard error, 0 when unknown), ``lo``/``hi`` (the error bar's
    ends) and ``n`` (frames)."""
    known = sorted((lv for lv in levels if lv["exposure"] is not None),
                   key=lambda lv: lv["exposure"])
    t = np.array([float(lv["exposure"]) for lv in known])
    mean = np.array([float(lv["mean"]) for lv in known])
    sem = np.array([float(lv["sem"]) if math.isfinite(lv["sem"]) else 0.0 for lv in known])
    return {"exposure": t, "mean": mean, "sem": sem, "lo": mean - sem, "hi": mean + sem,
            "n": [int(lv["n"]) for lv in known]}


def _dark_level_figure() -> tuple[Any, Any]:
    """The dark-level figure (built once, fed through its source): mean dark level (DN) with a
    ±1 standard-error bar against the exposure (s)."""
    from bokeh.models import ColumnDataSource, HoverTool
    from bokeh.plotting import figure

    src = ColumnDataSource(dark_level_columns([]))
    fig = figure(title="Dark level against exposure", height=300, sizing_mode="stretch_width",
                 tools="pan,wheel_zoom,box_zoom,reset,save", x_axis_label="exposure (s)",
                 y_axis_label="mean dark level (DN)", output_backend="canvas")
    fig.toolbar.logo = None
    fig.segment(x0="exposure", y0="lo", x1="exposure", y1="hi", source=src,
                line_color="#1f5f99", line_width=1.5)
    dots = fig.scatter("exposure", "mean", source=src, size=7, color="#1f5f99")
    fig.add_tools(HoverTool(renderers=[dots], tooltips=[
        ("exposure", "@exposure{0.0000} s"), ("mean", "@mean{0.0000} DN"),
        ("\u00b1", "@sem{0.0000} DN"), ("frames", "@n")]))
    return fig, src


def _table(css: str) -> pn.pane.DataFrame:
    return pn.pane.DataFrame(pd.DataFrame(), index=False, sizing_mode="stretch_width",
                             escape=True, css_classes=[css], stylesheets=[TABLE_CSS])


def gate_markdown(gate: Gate | None) -> str:
    """A gate as Markdown: its summary, why, and what to do next."""
    if gate is None:
        return "Not run yet."
    label = {GateStatus.PASS: "Passed", GateStatus.WARN: "Passed with warnings",
             GateStatus.FAIL: "Failed", GateStatus.SKIP: "Skipped"}[gate.status]
    lines = [f"**{label}:** {gate.summary}"]
    if gate.reasons:
        lines += [""] + [f"- {r}" for r in gate.reasons]
    if gate.next:
        lines += ["", "**Next:**"] + [f"- {n}" for n in gate.next]
    return "\n".join(lines)


def _skip_missing(session: Session, estimate: str) -> Gate | None:
    """A *skip* gate when the session lacks the frames of ``estimate`` (else ``None``)."""
    lacking = missing_frames(session, [estimate])
    if not lacking:
        return None
    req, roles = lacking[0]
    return Gate(GateStatus.SKIP, f"no {', '.join(roles)} frames: {req.purpose} is skipped",
                next=(f"capture {req.capture}",))


# --------------------------------------------------------------------------- computing -------
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


def compute_pattern(session: Session, dark: Any, noise: Any) -> Any:
    return guide.pattern_step(session, dark=dark, noise=noise)


def compute_product(session: Session, noise: Any, progress: Progress | None = None) -> Any:
    """The calibration product with the walkthrough's photon-transfer choices."""
    from ccdcore.product import calibrate

    return calibrate(session, noise=noise, progress=progress)


def compute_verify(session: Session, noise: Any, progress: Progress | None = None) -> tuple:
    product = compute_product(session, noise, progress)
    return product, guide.verify(session, product, noise=noise)


def compute_response(session: Session, progress: Progress | None = None) -> tuple[Any, Any]:
    """The response of the session's first bracket (Tsin et al. sec. 3.2) and the bracket's HDR
    radiance with its sigma (eqs. 9, 18, 19)."""
    from ccdcore.response.brackets import bracket_records
    from ccdcore.response.hdr import merge
    from ccdcore.response.methods import session_response

    res = session_response(session, progress=within(progress, 0.0, 0.9))
    if progress is not None:
        progress(0.9, "HDR radiance")
    frames = [session.read(r) for r in bracket_records(session)]
    hdr = merge(frames, res.models(), layout=session.camera.layout,
                bloom_radius=res.bloom_radius)
    return res, hdr


def compute_report(session: Session, product: Any) -> str:
    """The report of the walkthrough's product (:func:`ccdcore_report.build_report`; nothing is
    estimated again)."""
    from ccdcore_report import build_report

    return build_report(session, product=product)


def save_export(product: Any, html: str, folder: Path) -> tuple[Path, Path]:
    """Save the product into ``folder`` and its report beside its maps (``report.html``)."""
    from ccdcore.io import atomic_write_text

    out = product.save(folder)
    report = out / "report.html"
    atomic_write_text(report, html)
    return out, report


# --------------------------------------------------------------------------- the page --------
class WalkthroughPage(PageMessages, pn.viewable.Viewer):
    """A guided calibration of the loaded session (see the module docstring)."""

    state = param.ClassSelector(class_=AppState, doc="The app state shared by all pages.")
    step = param.Selector(default="plan", objects=SLUGS, doc="The step shown (in the URL).")
    # step 1: the plan's inputs
    # (defaults: the camera of Healey & Kondepudy sec. VII-A, A = 0.003384 DN/e⁻, σ²_C = 1.12)
    bits = param.Integer(default=8, bounds=(1, 32), doc="ADC bit depth b.")
    gain = param.Number(default=0.0034, bounds=(1e-6, None), doc=(
        "Rough gain A, DN per electron."))
    read_noise_e = param.Number(default=300.0, bounds=(0.0, None), doc="Rough read noise, e⁻.")
    exposure_half_ms = param.Number(default=10.0, bounds=(1e-3, None), doc=(
        "Exposure (ms) that gives about half of full scale under the lamp."))
    pixels = param.Integer(default=256 * 192, bounds=(2, None), doc=(
        "Pixels in the photon-transfer region (for the predicted error of A)."))
    # step 4: photon-transfer options
    exclude = param.List(default=[], item_type=int, doc="Photon-transfer levels left out.")
    robust = param.Boolean(default=False, doc="Robust mode: drop levels beyond 3σ one at a time.")
    # step 8
    export_folder = param.String(default="", doc="Folder for the calibration product.")
    gates = param.Dict(default={}, doc="Step slug -> its Gate (absent: not run yet).")

    def __init__(self, state: AppState | None = None, *, auto: bool = True, **params: Any):
        super().__init__(state=state if state is not None else AppState(), **params)
        self.auto = auto
        self._doc = pn.state.curdoc
        self._session: Session | None = None
        self.results: dict[str, Any] = {}
        self.plan: CapturePlan | None = None
        self.error = ""
        self._running: set[str] = set()
        self._build()
        self.state.param.watch(self._on_session, "session")
        self._session_defaults()
        self._plan()
        if pn.state.curdoc is not None and pn.state.location is not None:
            pn.state.location.sync(self, {"step": "step"})
        self._show_step()

    # ------------------------------------------------------------------ building ----------
    def _build(self) -> None:
        self._build_alerts("walkthrough")
        self.content = pn.Column(sizing_mode="stretch_width", margin=0)
        self.step_buttons: dict[str, pn.widgets.Button] = {}
        for i, s in enumerate(STEPS, start=1):
            b = pn.widgets.Button(label=f"{i}. {s.title}", color="light",
                                  sizing_mode="stretch_width", margin=(2, 0),
                                  stylesheets=[".bk-btn { text-align: left; }"],
                                  css_classes=[f"ccd-wt-nav-{s.slug}"])
            b.on_click(lambda event, slug=s.slug: setattr(self, "step", slug))
            self.step_buttons[s.slug] = b
        self.progress = pn.indicators.Progress(value=0, max=len(STEPS), height=14,
                                               sizing_mode="stretch_width",
                                               bar_color="success",
                                               css_classes=["ccd-wt-progress"])
        self.progress_text = pn.pane.Markdown("", styles={"color": MUTED},
                                              css_classes=["ccd-wt-progress-text"])
        self.panels: dict[str, pn.Column] = {}
        self.gate_panes: dict[str, pn.pane.Alert] = {}
        self.bodies: dict[str, pn.Column] = {}
        for i, s in enumerate(STEPS, start=1):
            gate = pn.pane.Alert(gate_markdown(None), alert_type="light",
                                 sizing_mode="stretch_width", css_classes=[f"ccd-wt-gate-{s.slug}",
                                                                           "ccd-wt-gate"])
            body = pn.Column(sizing_mode="stretch_width", margin=0)
            back = pn.widgets.Button(label="\u2190 Back", color="default", width=110,
                                     disabled=i == 1, css_classes=["ccd-wt-back"])
            nxt = pn.widgets.Button(label="Next \u2192", color="primary", width=110,
                                    disabled=i == len(STEPS), css_classes=["ccd-wt-next"])
            back.on_click(lambda e, k=i - 2: setattr(self, "step", SLUGS[max(k, 0)]))
            nxt.on_click(lambda e, k=i: setattr(self, "step", SLUGS[min(k, len(SLUGS) - 1)]))
            self.gate_panes[s.slug] = gate
            self.bodies[s.slug] = body
            self.panels[s.slug] = pn.Column(
                pn.pane.Markdown(f"### Step {i} of {len(STEPS)}: {s.title}",
                                 css_classes=["ccd-wt-title"]),
                pn.pane.Markdown(s.plain, sizing_mode="stretch_width"),
                pn.Card(pn.pane.Markdown(s.details, sizing_mode="stretch_width"),
                        title="Symbols and equations", collapsed=True,
                        sizing_mode="stretch_width"),
                body, gate, pn.Row(back, nxt),
                visible=False, sizing_mode="stretch_width", css_classes=[f"ccd-wt-{s.slug}"])
        self._build_plan()
        self._build_session()
        self._build_dark()
        self._build_ptc()
        self._build_pattern()
        self._build_response()
        self._build_verify()
        self._build_export()

    def _build_plan(self) -> None:
        w = pn.widgets
        inputs = pn.FlexBox(
            w.IntInput.from_param(self.param.bits, name="Bits", width=110),
            w.FloatInput.from_param(self.param.gain, name="Gain A (DN/e⁻)", width=150),
            w.FloatInput.from_param(self.param.read_noise_e, name="Read noise (e⁻)", width=140),
            w.FloatInput.from_param(self.param.exposure_half_ms, name="Half-scale exposure (ms)",
                                    width=190),
            w.IntInput.from_param(self.param.pixels, name="PTC pixels", width=140),
            sizing_mode="stretch_width")
        self.use_session = w.Button(label="Use the session's noise model", color="default",
                                    disabled=True, css_classes=["ccd-wt-use-session"])
        self.use_session.on_click(self._use_session_noise)
        self.plan_table = _table("ccd-wt-plan-table")
        self.checklist = pn.pane.Markdown("", sizing_mode="stretch_width",
                                          css_classes=["ccd-wt-checklist"])
        self.checklist_download = w.FileDownload(
            callback=lambda: io.BytesIO(self.plan.checklist().encode()) if self.plan else None,
            filename="capture-checklist.md", label="Download the checklist (Markdown)",
            color="default", css_classes=["ccd-wt-checklist-download"])
        self.toml_download = w.FileDownload(
            callback=lambda: io.BytesIO(self.plan.to_toml().encode()) if self.plan else None,
            filename="session.toml", label="Download session.toml (file names to capture)",
            color="default", css_classes=["ccd-wt-toml-download"])
        self.bodies["plan"].objects = [
            inputs, self.use_session, self.plan_table,
            pn.Row(self.checklist_download, self.toml_download),
            pn.Card(self.checklist, title="Printable checklist", collapsed=True,
                    sizing_mode="stretch_width")]

    def _build_session(self) -> None:
        self.problems_table = _table("ccd-wt-problems")
        self.bodies["session"].objects = [self.problems_table]

    def _build_dark(self) -> None:
        self.dark_view = ImageView(frame_width=IMAGE_WIDTH, max_frame_height=IMAGE_WIDTH,
                                   cmap="viridis", label="DN", symbol="D̂_D",
                                   title="Dark reference D̂_D (DN)",
                                   css_classes=["ccd-wt-dark-map"])
        self.dark_pane = view_pane(self.dark_view)
        self.dark_levels = _table("ccd-wt-dark-levels")
        # many exposures (a dark-current series): a plot of the level against the exposure
        self.dark_level_fig, self.dark_level_source = _dark_level_figure()
        self.dark_level_plot = pn.Column(pn.pane.Bokeh(self.dark_level_fig,
                                                       sizing_mode="stretch_width"),
                                         visible=False, sizing_mode="stretch_width",
                                         css_classes=["ccd-wt-dark-plot"])
        self.bodies["dark"].objects = [pn.Row(self.dark_pane, pn.Column(
            pn.pane.Markdown("**Dark level per exposure** (red crosses on the map: hot and dead "
                             "pixels)"), self.dark_levels, self.dark_level_plot,
            sizing_mode="stretch_width"), sizing_mode="stretch_width")]

    def _build_ptc(self) -> None:
        self.ptc_figs = PtcFigures(height=320)
        self.exclude_select = pn.widgets.MultiChoice(label="Leave out levels", options=[],
                                                     width=300, css_classes=["ccd-wt-exclude"])
        self.exclude_select.param.watch(self._on_exclude, "value")
        self.robust_box = pn.widgets.Checkbox.from_param(
            self.param.robust, name="Robust mode (drop levels beyond 3σ)")
        self.emva_table = _table("ccd-wt-emva")
        self.emva_holder = pn.Column(
            pn.pane.Markdown("**EMVA 1288 figures** (the session carries photon counts; "
                             "definitions of release 3.1, as the emva1288 package computes "
                             "them: docs/emva.md)"),
            self.emva_table, visible=False, sizing_mode="stretch_width")
        self.bodies["ptc"].objects = [
            pn.Row(self.exclude_select, self.robust_box),
            pn.pane.Bokeh(self.ptc_figs.transfer, sizing_mode="stretch_width"),
            pn.pane.Bokeh(self.ptc_figs.residual, sizing_mode="stretch_width"),
            self.emva_holder]

    def _build_pattern(self) -> None:
        self.k_view = ImageView(frame_width=IMAGE_WIDTH, max_frame_height=IMAGE_WIDTH,
                                cmap="RdBu_r", label="K̂", symbol="K̂",
                                css_classes=["ccd-wt-k-map"])
        self.k_pane = view_pane(self.k_view)
        self.snup_table = _table("ccd-wt-snup")
        self.bodies["pattern"].objects = [pn.Row(self.k_pane, pn.Column(
            pn.pane.Markdown("**SNUP on held-out flats** (%, before → after the flat-field "
                             "correction)"), self.snup_table, sizing_mode="stretch_width"),
            sizing_mode="stretch_width")]

    def _build_response(self) -> None:
        from ccdcore.response.methods import METHODS

        from ..response_plots import ResponseFigure

        self.response_fig = ResponseFigure(["tsin"], {"tsin": METHODS["tsin"].label},
                                           height=340)
        self.response_holder = pn.Column(pn.pane.Bokeh(self.response_fig.fig,
                                                       sizing_mode="stretch_width"),
                                         visible=False, sizing_mode="stretch_width")
        self.hdr_view, self.hdr_sigma = hdr_views(IMAGE_WIDTH,
                                                  ("ccd-wt-hdr", "ccd-wt-hdr-sigma"))
        self.hdr_pane, self.hdr_sigma_pane = view_pane(self.hdr_view), view_pane(self.hdr_sigma)
        self.bodies["response"].objects = [
            self.response_holder,
            pn.pane.Markdown("**HDR radiance** (gamma 2.2 for display) **and its relative sigma** "
                             "(eq. 19), zoom linked; the Response & HDR page has every control.",
                             sizing_mode="stretch_width"),
            pn.Row(self.hdr_pane, self.hdr_sigma_pane)]

    def _build_verify(self) -> None:
        self.verify_table = _table("ccd-wt-verify")
        self.bodies["verify"].objects = [self.verify_table]

    def _build_export(self) -> None:
        self.folder_input = pn.widgets.TextInput.from_param(
            self.param.export_folder, name="Product folder", sizing_mode="stretch_width",
            css_classes=["ccd-wt-folder"])
        self.save_button = pn.widgets.Button(label="Save the product and the report",
                                             color="primary",
                                             css_classes=["ccd-wt-save"])
        self.save_button.on_click(lambda e: pn.state.execute(self.save))
        self.report_download = pn.widgets.FileDownload(
            callback=self._report_bytes, filename="report.html",
            label="Download the report (HTML)", color="default", disabled=True,
            css_classes=["ccd-wt-report-download"])
        self.export_note = pn.pane.Markdown("", sizing_mode="stretch_width",
                                            css_classes=["ccd-wt-export-note"])
        self.bodies["export"].objects = [self.folder_input,
                                         pn.Row(self.save_button, self.report_download),
                                         self.export_note]

    def __panel__(self) -> pn.viewable.Viewable:
        intro = ("From the plan of the captures to a saved calibration product and its report. "
                 "Each step checks its result and says what to capture or change; a step that "
                 "lacks frames is skipped. The step is part of the address: copy it to send a "
                 "colleague to this step.")
        nav = pn.Column(self.progress, self.progress_text, *self.step_buttons.values(),
                        width=250, sizing_mode=None, css_classes=["ccd-wt-steps"])
        return pn.Column(*heading("Walkthrough", intro), self.info_alert, self.error_alert,
                         pn.Row(nav, pn.Column(*self.panels.values(),
                                               sizing_mode="stretch_width"),
                                sizing_mode="stretch_width"),
                         sizing_mode="stretch_width", name="Walkthrough")

    # ------------------------------------------------------------------ state -------------
    def _session_defaults(self) -> None:
        session = self.state.session
        if session is None:
            return
        if session.camera.bits:
            self.bits = int(session.camera.bits)
        self.export_folder = str(Path.home() / "ccdcore-products" /
                                 f"{session.root.name}-calibration")

    def _on_session(self, *events: Any) -> None:
        self._invalidate("session", include=True)
        self._session_defaults()
        if self.auto:
            pn.state.execute(self.run_step)

    def _invalidate(self, slug: str, include: bool = False) -> None:
        drop = DOWNSTREAM[slug] + ((slug,) if include else ())
        for s in drop:
            self.results.pop(s, None)
        if "report" in drop:         # its report is gone: nothing to download until rebuilt
            in_document(self._doc, lambda: setattr(self.report_download, "disabled", True))
        gates = {k: v for k, v in self.gates.items() if k not in drop}
        if gates != self.gates:
            self.gates = gates

    @param.depends("gates", watch=True)
    def _render_progress(self) -> None:
        in_document(self._doc, self._draw_progress)

    @batched
    def _draw_progress(self) -> None:
        done = sum(1 for s in SLUGS if s in self.gates)
        self.progress.value = done
        self.progress_text.object = f"{done} of {len(STEPS)} steps checked"
        for i, s in enumerate(STEPS, start=1):
            gate = self.gates.get(s.slug)
            status = gate.status if gate else None
            b = self.step_buttons[s.slug]
            b.label = f"{STATUS_ICONS[status]}  {i}. {s.title}"
            b.color = "primary" if s.slug == self.step else _BUTTONS[status]
            pane = self.gate_panes[s.slug]
            pane.object = gate_markdown(gate)
            pane.alert_type = _ALERTS[status]

    @param.depends("step", watch=True)
    def _show_step(self) -> None:
        for slug, panel in self.panels.items():
            panel.visible = slug == self.step
        self._draw_progress()
        if self.auto:
            pn.state.execute(self.run_step)

    def on_show(self) -> None:
        if self.auto and self.step not in self.gates:
            pn.state.execute(self.run_step)

    def _set_gate(self, slug: str, gate: Gate) -> None:
        self.gates = {**self.gates, slug: gate}

    # ------------------------------------------------------------------ steps -------------
    async def run_step(self, slug: str | None = None) -> None:
        """Compute the step ``slug`` (default: the one shown) if its result is missing, with
        the steps it needs, then draw it."""
        slug = slug or self.step
        runner = getattr(self, f"_run_{slug}")
        if slug in self._running:
            return
        self._running.add(slug)
        try:
            await runner()
        finally:
            self._running.discard(slug)

    def _needs_session(self, slug: str) -> Session | None:
        session = self.state.session
        if session is None:
            self._set_gate(slug, Gate(GateStatus.SKIP, "no session loaded",
                                      next=("open a session on the Session page",)))
        return session

    async def _compute(self, slug: str, func: Callable, *args: Any, label: str,
                       pass_progress: bool = False) -> Any:
        """``func(*args)`` off the UI thread; a failure becomes the step's *fail* gate."""
        session = self.state.session
        result = await self.state.compute(func, *args, label=label,
                                          pass_progress=pass_progress)
        if self.state.session is not session:
            return None
        if result is None:
            why = self.state.error or "the computation was cancelled"
            self._set_gate(slug, Gate(GateStatus.FAIL, why, next=(
                "correct the frames or the choices of this step, then revisit it",)))
        return result

    async def _run_plan(self) -> None:
        self._plan()

    def _plan(self) -> None:
        session = self.state.session
        try:
            self.plan = plan_captures(
                int(self.bits), float(self.gain), read_noise_e=float(self.read_noise_e),
                pixels=int(self.pixels), exposure_half=float(self.exposure_half_ms) / 1e3,
                layout=session.camera.layout if session is not None else "mono",
                name=session.camera.name if session is not None else "")
        except CcdError as err:
            self.plan = None
            self._set_gate("plan", Gate(GateStatus.FAIL, str(err),
                                        next=("correct the input named",)))
            return
        p = self.plan
        rows = []
        for g in p.groups:
            exps = sorted({k["exposure"] for _, k in g.frames if "exposure" in k})
            rows.append({"frames": g.title, "count": g.count, "folder": g.frames[0][0].split("/")[0],
                         "exposures (ms)": ", ".join(f"{t * 1e3:.3g}" for t in exps[:8])
                         + (" …" if len(exps) > 8 else ""), "rule": g.rule})
        self._plan_rows = pd.DataFrame(rows)
        in_document(self._doc, self._draw_plan)
        self._set_gate("plan", Gate(
            GateStatus.PASS, f"{p.n_frames} frames to capture; predicted σ(A)/A = "
                             f"{p.gain_rel_err:.2%}, K̂ from n1 = "
                             f"{p.fixed_pattern.n1_required} × n2 = "
                             f"{p.fixed_pattern.n2_required} frames", tuple(p.notes)))

    @batched
    def _draw_plan(self) -> None:
        if self.plan is None:
            return
        self.plan_table.object = self._plan_rows
        self.checklist.object = self.plan.checklist()
        noise = self.results.get("ptc")
        self.use_session.disabled = noise is None

    @param.depends("bits", "gain", "read_noise_e", "exposure_half_ms", "pixels", watch=True)
    def _on_plan_inputs(self) -> None:
        self._plan()

    def _use_session_noise(self, event: Any = None) -> None:
        noise = self.results.get("ptc")
        if noise is None:
            return
        rn = noise.read_noise_e if math.isfinite(noise.read_noise_e) else 0.0
        self.param.update(gain=float(noise.A), read_noise_e=float(rn))

    async def _run_session(self) -> None:
        session = self._needs_session("session")
        if session is None:
            return
        gate = guide.session_gate(session)
        rows = [{"severity": p.severity, "where": p.where, "problem": p.message,
                 "fix": p.code.fix}
                for p in session.problems]
        self._problems = pd.DataFrame(rows or [{"severity": "", "where": "",
                                                "problem": "no problems", "fix": ""}])
        in_document(self._doc, self._draw_session)
        self._set_gate("session", gate)

    @batched
    def _draw_session(self) -> None:
        self.problems_table.object = self._problems

    async def _ensure_dark(self) -> Any:
        if "dark" not in self.results:
            session = self.state.session
            step = await self._compute("dark", guide.dark_step, session,
                                       label="the dark reference")
            if step is None:
                return None
            self.results["dark"] = step
        return self.results["dark"]

    async def _run_dark(self) -> None:
        if self._needs_session("dark") is None:
            return
        step = await self._ensure_dark()
        if step is None:
            return
        in_document(self._doc, self._draw_dark)
        self._set_gate("dark", step.gate)

    @batched
    def _draw_dark(self) -> None:
        step = self.results.get("dark")
        if step is None:
            return
        if step.dark is not None:
            m = step.dark.mean_map
            lo, hi = np.percentile(m, [0.5, 99.5])
            self.dark_view.show(m, clim=(float(lo), float(max(hi, lo + 1e-6))))
            flagged = np.nonzero(step.dark.hot_mask | step.dark.dead_mask)
            self.dark_view.set_points(flagged[0][:2000], flagged[1][:2000])
            self.dark_pane.visible = True
        cols = dark_level_columns(step.levels)
        plot = len(cols["exposure"]) > DARK_TABLE_MAX    # a series: plot it, no long table
        self.dark_level_source.data = cols
        self.dark_level_plot.visible = plot
        self.dark_levels.visible = not plot
        self.dark_levels.object = pd.DataFrame([
            {"exposure (s)": "–" if lv["exposure"] is None else f"{lv['exposure']:.4g}",
             "frames": lv["n"], "mean (DN)": f"{lv['mean']:.4f}",
             "± (DN)": "–" if not math.isfinite(lv["sem"]) else f"{lv['sem']:.2g}"}
            for lv in step.levels]) if step.levels and not plot else pd.DataFrame()

    async def _ensure_ptc(self) -> Any:
        """The photon-transfer result (``None`` when skipped or failed; the gate says why)."""
        if "ptc" in self.results:
            return self.results["ptc"]
        session = self.state.session
        skip = _skip_missing(session, "noise")
        if skip is not None:
            self.results["ptc"] = None
            self._set_gate("ptc", skip)
            return None
        noise = await self._compute("ptc", compute_ptc, session, list(self.exclude),
                                    bool(self.robust), label="photon transfer")
        if noise is None:
            return None
        self.results["ptc"] = noise
        gate = guide.ptc_gate(noise)
        if any(r.photons for r in session.by_role("ptc")):
            figures = await self.state.compute(compute_emva, session, noise,
                                               label="the EMVA 1288 figures")
            self.results["emva"] = figures
            if figures is None:
                gate = Gate(gate.status, gate.summary, gate.reasons + (
                    f"the EMVA 1288 figures could not be made: {self.state.error}",), gate.next)
            else:
                gate = Gate(gate.status, gate.summary, gate.reasons + tuple(
                    f"EMVA 1288: {n}" for n in figures.get("notes", ())), gate.next)
        self._set_gate("ptc", gate)
        return noise

    async def _run_ptc(self) -> None:
        if self._needs_session("ptc") is None:
            return
        noise = await self._ensure_ptc()
        if noise is not None:
            in_document(self._doc, self._draw_ptc)

    @batched
    def _draw_ptc(self) -> None:
        noise = self.results.get("ptc")
        if noise is None:
            return
        self.ptc_figs.update(noise.points, noise)
        figures = self.results.get("emva")
        if figures:
            self.emva_table.object = emva_table(figures)
        self.emva_holder.visible = bool(figures)
        levels = [int(p.level) for p in noise.points]
        self.exclude_select.options = levels
        self.use_session.disabled = False

    def _on_exclude(self, event: Any) -> None:
        value = sorted(int(v) for v in event.new)
        if value != sorted(self.exclude):
            self.exclude = value

    @param.depends("exclude", "robust", watch=True)
    def _on_ptc_options(self) -> None:
        self._invalidate("ptc", include=True)
        if self.exclude_select.value != list(self.exclude):
            self.exclude_select.value = list(self.exclude)
        if self.auto and self.step == "ptc":
            pn.state.execute(self.run_step)

    async def _run_pattern(self) -> None:
        session = self._needs_session("pattern")
        if session is None:
            return
        if "pattern" not in self.results:
            if not (session.fixed_pattern_configs() or session.flat_groups()):
                step = guide.pattern_step(session)        # the skip gate, nothing to read
            else:
                dark = await self._ensure_dark()
                noise = await self._ensure_ptc()
                step = await self._compute(
                    "pattern", compute_pattern, session, dark.dark if dark is not None else None,
                    noise, label="the fixed pattern and flat field")
                if step is None:
                    return
            self.results["pattern"] = step
        step = self.results["pattern"]
        in_document(self._doc, self._draw_pattern)
        self._set_gate("pattern", step.gate)

    @batched
    def _draw_pattern(self) -> None:
        step = self.results.get("pattern")
        if step is None:
            return
        if step.fixed_pattern is not None:
            K = step.fixed_pattern.K
            half = float(max(np.percentile(np.abs(K - 1.0), 99.5), 1e-4))
            self.k_view.show(K, clim=(1.0 - half, 1.0 + half))
            self.k_pane.visible = True
        self.snup_table.object = pd.DataFrame([
            {"frame": r["frame"], "channel": r["channel"], "before (%)": f"{r['before']:.3g}",
             "after (%)": f"{r['after']:.3g}"} for r in step.snup_rows]) \
            if step.snup_rows else pd.DataFrame([{"": "no held-out flat frames"}])

    async def _run_response(self) -> None:
        session = self._needs_session("response")
        if session is None:
            return
        if "response" not in self.results:
            if not session.bracket_stacks("bracket"):
                self.results["response"] = None
                self._set_gate("response", Gate(
                    GateStatus.SKIP, "no exposure bracket: the response curve and HDR are skipped",
                    next=(f"capture {requirement('response').capture}",)))
                return
            res = await self._compute("response", compute_response, session,
                                      label="the response curve", pass_progress=True)
            if res is None:
                return
            self.results["response"] = res
        found = self.results["response"]
        if found is None:
            return
        in_document(self._doc, self._draw_response)
        self._set_gate("response", guide.response_gate(*found))

    @batched
    def _draw_response(self) -> None:
        found = self.results.get("response")
        if found is None:
            return
        from ..response_plots import hdr_planes

        res, hdr = found
        ch = res.channels[0]
        self.response_fig.show({"tsin": (res[ch].g, res[ch].g_err)}, "tsin", False)
        self.response_holder.visible = True
        p = hdr_planes(hdr, 0)
        self.hdr_view.show(p["display"], clim=(0.0, 1.0))
        self.hdr_sigma.show(p["rel"], clim=(0.0, p["top"]))
        self.hdr_pane.visible = self.hdr_sigma_pane.visible = True

    async def _ensure_verify(self) -> Any:
        if "verify" in self.results:
            return self.results["verify"]
        session = self.state.session
        noise = await self._ensure_ptc() if not _skip_missing(session, "noise") else None
        found = await self._compute("verify", compute_verify, session, noise,
                                    label="the calibration product", pass_progress=True)
        if found is None:
            return None
        self.results["verify"] = found
        return found

    async def _run_verify(self) -> None:
        if self._needs_session("verify") is None:
            return
        found = await self._ensure_verify()
        if found is None:
            return
        in_document(self._doc, self._draw_verify)
        self._set_gate("verify", found[1].gate)

    @batched
    def _draw_verify(self) -> None:
        found = self.results.get("verify")
        if found is None:
            return
        rows = found[1].rows
        self.verify_table.object = pd.DataFrame([
            {"frame": r.frame, "channel": r.channel, "SNUP before → after (%)":
             f"{r.before:.3g} → {r.after:.3g}", "pixel scale before → after (%)":
             f"{r.local_before:.3g} → {r.local_after:.3g}",
             "noise floor (%)": "–" if r.floor is None else f"{r.floor:.3g}",
             "pixels changed > 1 code": f"{r.changed:,} of {r.n_pixels:,}"} for r in rows]) \
            if rows else pd.DataFrame([{"": "no held-out frames"}])

    async def _ensure_report(self) -> tuple[Any, str] | None:
        """The product (step 7's) and its report, built once off the UI thread; the download
        and the save both use it."""
        found = await self._ensure_verify()
        if found is None:
            return None
        if "report" not in self.results:
            html = await self._compute("export", compute_report, self.state.session, found[0],
                                       label="the report")
            if html is None:
                return None
            self.results["report"] = html
        return found[0], self.results["report"]

    async def _run_export(self) -> None:
        if self._needs_session("export") is None:
            return
        ready = await self._ensure_report()
        if ready is None:
            return
        product = ready[0]
        name = self.state.session.root.name

        def enable() -> None:
            self.report_download.param.update(disabled=False, filename=f"{name}-report.html")

        in_document(self._doc, enable)
        if "export" not in self.results:
            self._set_gate("export", Gate(
                GateStatus.WARN if not product.maps else GateStatus.PASS,
                "the product is ready to save: choose a folder and save it",
                tuple(f"skipped {s.estimate}: {s.reason}" for s in product.skipped)))

    async def save(self) -> None:
        """Save the product and its report into :attr:`export_folder` (inside the allowed
        folders); the gate says where, or why not."""
        if self.state.session is None:
            return
        ready = await self._ensure_report()
        if ready is None:
            return
        try:
            folder = self.state.check_allowed(self.export_folder)
        except CcdError as err:
            self._set_gate("export", Gate(GateStatus.FAIL, str(err), next=(
                "choose a folder inside your home, the working folder or the session's",)))
            return
        saved = await self._compute("export", save_export, *ready, folder,
                                    label="the product and the report")
        if saved is None:
            return
        out, report = saved
        self.results["export"] = saved
        self._set_gate("export", Gate(GateStatus.PASS, f"saved the product to {out} and the "
                                                       f"report to {report}", (
            "apply it: ccdcore apply " + str(out) + " IMAGES -o OUT",)))
        in_document(self._doc, lambda: setattr(self.export_note, "object",
                                                f"Saved: `{out}` and `{report}`."))

    def _report_bytes(self) -> io.BytesIO | None:
        html = self.results.get("report")
        return io.BytesIO(html.encode()) if html else None

    def release(self) -> None:
        """The browser session ended: drop the results and the arrays the views hold."""
        self.results.clear()
        for view in (self.dark_view, self.k_view, self.hdr_view, self.hdr_sigma):
            view.release()


def create_page(state: AppState) -> WalkthroughPage:
    """Registry entry point: the Walkthrough page bound to ``state``."""
    return WalkthroughPage(state)
