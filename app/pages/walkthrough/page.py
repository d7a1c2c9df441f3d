"""The Walkthrough page's shell: the layout, the step list and its navigation, the gates.

Each step says in plain words what it does (symbols and equation numbers in a card below), shows
its plot, and ends in a gate (:mod:`ccdcore.guide`): what passed or failed, why, and what to
capture or change next. A step whose frames are missing says so and is skipped; it never blocks
the rest. Steps can be revisited and changed: a change (the photon-transfer levels left out, the
robust mode, the plan's inputs, a new session) drops the results of the steps after it
(:func:`.results.stale`), which recompute when shown.

The steps listed follow what the session holds (:func:`ccdcore.guide.session_plan`, kept as
:attr:`WalkthroughPage.coverage`): a bracket gets the response step, flats the flat field, a lab
session every step; Back and Next move among them.

The steps are :data:`ccdcore.guide.STEPS`, one module each (:data:`STEP_TYPES`); the page holds
one step object per step (:attr:`WalkthroughPage.steps`) and their typed results
(:attr:`WalkthroughPage.results`). The chosen step is in the URL (``?page=walkthrough&step=ptc``),
so a colleague can be sent to it.

Public objects
--------------
WalkthroughPage
    The page (a :class:`panel.viewable.Viewer`); its state is declared with ``param``: the step,
    the plan's inputs, the photon-transfer options, the export folder, the gates.
create_page(state)
    The registry entry point.
STATUS_ICONS
    The mark of each gate status in the step list.
STEP_TYPES
    The step class of each slug of :data:`ccdcore.guide.STEPS`, in their order.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import panel as pn
import param

from ccdcore.capture import CapturePlan
from ccdcore.guide import STEPS, Gate, GateStatus, SessionPlan, StepInfo, session_plan
from ccdcore.session import Session

from ...batch import batched, in_document
from ...state import AppState
from .._messages import PageMessages
from .._styles import MUTED, heading
from ._common import Step
from .dark import DarkStep
from .export import ExportStep
from .pattern import PatternStep
from .plan import PlanStep
from .ptc import PtcStep
from .response import ResponseStep
from .results import Results, stale
from .session import SessionStep
from .verify import VerifyStep

__all__ = ["WalkthroughPage", "create_page", "STATUS_ICONS", "STEP_TYPES", "gate_markdown"]

SLUGS = [s.slug for s in STEPS]
_CLASSES = {c.slug: c for c in (PlanStep, SessionStep, DarkStep, PtcStep, PatternStep,
                                ResponseStep, VerifyStep, ExportStep)}
#: the step class of each step of :data:`ccdcore.guide.STEPS`, in their order
STEP_TYPES: dict[str, type[Step]] = {slug: _CLASSES[slug] for slug in SLUGS}
#: the mark of each gate status in the step list (and the alert type of its gate)
STATUS_ICONS = {GateStatus.PASS: "\u2714", GateStatus.WARN: "\u26a0",
                GateStatus.FAIL: "\u2716", GateStatus.SKIP: "\u2013", None: "\u25cb"}
_ALERTS = {GateStatus.PASS: "success", GateStatus.WARN: "warning", GateStatus.FAIL: "danger",
           GateStatus.SKIP: "secondary", None: "light"}
_BUTTONS = {GateStatus.PASS: "success", GateStatus.WARN: "warning", GateStatus.FAIL: "danger",
            GateStatus.SKIP: "light", None: "light"}


def gate_markdown(gate: Gate | None) -> str:
    """A gate as Markdown: its summary, why, and what to do next."""
    if gate is None:
        return "Not run yet."
    lines = [f"**{gate.label}:** {gate.summary}"]
    if gate.reasons:
        lines += [""] + [f"- {r}" for r in gate.reasons]
    if gate.next:
        lines += ["", "**Next:**"] + [f"- {n}" for n in gate.next]
    return "\n".join(lines)


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
    coverage = param.ClassSelector(class_=SessionPlan, default=session_plan(None), doc=(
        "What the session's frames allow (ccdcore.guide.session_plan): the steps shown and "
        "whether the full lab plan is proposed."))

    def __init__(self, state: AppState | None = None, *, auto: bool = True, **params: Any):
        super().__init__(state=state if state is not None else AppState(), **params)
        self.auto = auto
        self.doc = pn.state.curdoc
        self._session: Session | None = None
        self.results = Results()
        self.error = ""
        self._running: set[str] = set()
        self._build()
        self.state.param.watch(self._on_session, "session")
        self._session_defaults()
        self._follow_session()
        self.steps["plan"].replan()
        if pn.state.curdoc is not None and pn.state.location is not None:
            pn.state.location.sync(self, {"step": "step"})
        self._show_step()

    @property
    def plan(self) -> CapturePlan | None:
        """The capture plan of step 1 (``None`` when its inputs are impossible)."""
        return self.results.plan.plan if self.results.plan is not None else None

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
        #: one step object per step, in the order of :data:`ccdcore.guide.STEPS`
        self.steps: dict[str, Step] = {slug: cls(self) for slug, cls in STEP_TYPES.items()}
        self.gate_panes: dict[str, pn.pane.Alert] = {}
        self.title_panes: dict[str, pn.pane.Markdown] = {}
        self.panels = {s.slug: self._build_panel(i, s) for i, s in enumerate(STEPS, start=1)}
        self._retitle()

    def _build_panel(self, i: int, s: StepInfo) -> pn.Column:
        """Step ``i``'s panel: title, plain words, the symbols card, its body, gate, back/next."""
        gate = pn.pane.Alert(gate_markdown(None), alert_type="light",
                             sizing_mode="stretch_width",
                             css_classes=[f"ccd-wt-gate-{s.slug}", "ccd-wt-gate"])
        body = pn.Column(*self.steps[s.slug].build(), sizing_mode="stretch_width", margin=0)
        back = pn.widgets.Button(label="\u2190 Back", color="default", width=110,
                                 disabled=i == 1, css_classes=["ccd-wt-back"])
        nxt = pn.widgets.Button(label="Next \u2192", color="primary", width=110,
                                disabled=i == len(STEPS), css_classes=["ccd-wt-next"])
        back.on_click(lambda e, slug=s.slug: self.go(slug, -1))
        nxt.on_click(lambda e, slug=s.slug: self.go(slug, +1))
        self.gate_panes[s.slug] = gate
        self.title_panes[s.slug] = pn.pane.Markdown(f"### {s.title}",
                                                    css_classes=["ccd-wt-title"])
        return pn.Column(
            self.title_panes[s.slug],
            pn.pane.Markdown(s.plain, sizing_mode="stretch_width"),
            pn.Card(pn.pane.Markdown(s.details, sizing_mode="stretch_width"),
                    title="Symbols and equations", collapsed=True, sizing_mode="stretch_width"),
            body, gate, pn.Row(back, nxt),
            visible=False, sizing_mode="stretch_width", css_classes=[f"ccd-wt-{s.slug}"])

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

    def go(self, slug: str, by: int) -> None:
        """Show the step ``by`` places from ``slug`` among the steps shown."""
        shown = [s for s in SLUGS if s in self.coverage.steps or s == slug]
        i = min(max(shown.index(slug) + by, 0), len(shown) - 1)
        self.step = shown[i]

    # ------------------------------------------------------------------ state -------------
    def _follow_session(self) -> None:
        """The steps the session's frames allow (:func:`ccdcore.guide.session_plan`)."""
        self.coverage = session_plan(self.state.session)

    def _retitle(self) -> None:
        """Each step's title counts the steps listed for this session ("Step 2 of 4"), not
        every step the Walkthrough knows."""
        shown = [slug for slug in SLUGS if slug in self.coverage.steps]
        for info in STEPS:
            pane = self.title_panes[info.slug]
            pane.object = (f"### Step {shown.index(info.slug) + 1} of {len(shown)}: "
                           f"{info.title}" if info.slug in shown else f"### {info.title}")

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
        self._follow_session()
        if self.auto:
            pn.state.execute(self.run_step)

    @param.depends("bits", "gain", "read_noise_e", "exposure_half_ms", "pixels", watch=True)
    def _on_plan_inputs(self) -> None:
        self.steps["plan"].replan()

    @param.depends("coverage", watch=True)
    def _on_coverage(self) -> None:
        self._retitle()
        self.steps["plan"].replan()

    @param.depends("exclude", "robust", watch=True)
    def refit_ptc(self) -> None:
        """The photon-transfer options changed (levels left out, robust mode, the step's fit
        range): drop step 4 on and, on that step, fit again."""
        self._invalidate("ptc", include=True)
        self.steps["ptc"].show_exclude()
        if self.auto and self.step == "ptc":
            pn.state.execute(self.run_step)

    def _invalidate(self, slug: str, include: bool = False) -> None:
        """Drop the results and gates a change in ``slug`` makes stale (:func:`.results.stale`)."""
        drop = stale(slug, include)
        self.results.drop(drop)
        for step in self.steps.values():
            step.dropped(drop)
        gates = {k: v for k, v in self.gates.items() if k not in drop}
        if gates != self.gates:
            self.gates = gates

    @param.depends("gates", "coverage", watch=True)
    def _render_progress(self) -> None:
        in_document(self.doc, self._draw_progress)

    @batched
    def _draw_progress(self) -> None:
        shown = self.coverage.steps
        done = sum(1 for s in shown if s in self.gates)
        self.progress.max = len(shown)
        self.progress.value = done
        self.progress_text.object = f"{done} of {len(shown)} steps checked"
        for i, s in enumerate(STEPS, start=1):
            self.step_buttons[s.slug].visible = s.slug in shown or s.slug == self.step
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

    def set_gate(self, slug: str, gate: Gate) -> None:
        self.gates = {**self.gates, slug: gate}

    # ------------------------------------------------------------------ steps -------------
    async def run_step(self, slug: str | None = None) -> None:
        """Compute the step ``slug`` (default: the one shown) if its result is missing, with
        the steps it needs, then draw it."""
        slug = slug or self.step
        step = self.steps[slug]
        if slug in self._running:
            return
        self._running.add(slug)
        try:
            await step.run()
        finally:
            self._running.discard(slug)

    async def save(self) -> None:
        """Save the product and its report into :attr:`export_folder` (step 8's save)."""
        await self.steps["export"].save()

    def release(self) -> None:
        """The browser session ended: drop the results and the arrays the views hold."""
        self.results.clear()
        for step in self.steps.values():
            step.release()


def create_page(state: AppState) -> WalkthroughPage:
    """Registry entry point: the Walkthrough page bound to ``state``."""
    return WalkthroughPage(state)
