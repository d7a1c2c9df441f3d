"""Step 1, plan: what the loaded session's frames allow (:func:`ccdcore.guide.session_plan`:
the steps shown, what is missing and why), and, with no session or a lab session, the capture
plan (:mod:`ccdcore.capture`) from the page's inputs with its checklist and ``session.toml`` to
download. A session of flats or of a bracket is not given a lab plan sized from default camera
figures: its gate is :meth:`ccdcore.guide.SessionPlan.gate`."""
from __future__ import annotations

import io
import math
from dataclasses import dataclass
from typing import Any

import pandas as pd
import panel as pn

from ccdcore.capture import CapturePlan, plan_captures
from ccdcore.errors import CcdError
from ccdcore.guide import Gate, GateStatus, SessionPlan

from ._common import Step, table


@dataclass(frozen=True, eq=False)
class PlanResult:
    """The capture plan and its table's rows (one per group of frames)."""

    plan: CapturePlan
    rows: pd.DataFrame


def plan_rows(plan: CapturePlan) -> pd.DataFrame:
    """The plan's groups as rows: frames, count, folder, exposures (ms), rule."""
    rows = []
    for g in plan.groups:
        exps = sorted({k["exposure"] for _, k in g.frames if "exposure" in k})
        rows.append({"frames": g.title, "count": g.count, "folder": g.frames[0][0].split("/")[0],
                     "exposures (ms)": ", ".join(f"{t * 1e3:.3g}" for t in exps[:8])
                     + (" …" if len(exps) > 8 else ""), "rule": g.rule})
    return pd.DataFrame(rows)


def coverage_markdown(cover: SessionPlan) -> str:
    """What the session's frames allow, as Markdown: the summary and what is missing."""
    lines = [f"**{cover.summary[0].upper() + cover.summary[1:]}.**"]
    if cover.missing:
        lines += ["", "Missing:"] + [f"- {m}" for m in cover.missing]
    return "\n".join(lines)


class PlanStep(Step):
    slug = "plan"

    def build(self) -> list[pn.viewable.Viewable]:
        w, p = pn.widgets, self.page.param
        inputs = pn.FlexBox(
            w.IntInput.from_param(p.bits, name="Bits", width=110),
            w.FloatInput.from_param(p.gain, name="Gain A (DN/e⁻)", width=150),
            w.FloatInput.from_param(p.read_noise_e, name="Read noise (e⁻)", width=140),
            w.FloatInput.from_param(p.exposure_half_ms, name="Half-scale exposure (ms)",
                                    width=190),
            w.IntInput.from_param(p.pixels, name="PTC pixels", width=140),
            sizing_mode="stretch_width")
        self.use_session = w.Button(label="Use the session's noise model", color="default",
                                    disabled=True, css_classes=["ccd-wt-use-session"])
        self.use_session.on_click(self.use_session_noise)
        self.plan_table = table("ccd-wt-plan-table")
        self.checklist = pn.pane.Markdown("", sizing_mode="stretch_width",
                                          css_classes=["ccd-wt-checklist"])
        self.checklist_download = w.FileDownload(
            callback=lambda: self._text(CapturePlan.checklist), filename="capture-checklist.md",
            label="Download the checklist (Markdown)", color="default",
            css_classes=["ccd-wt-checklist-download"])
        self.toml_download = w.FileDownload(
            callback=lambda: self._text(CapturePlan.to_toml), filename="session.toml",
            label="Download session.toml (file names to capture)", color="default",
            css_classes=["ccd-wt-toml-download"])
        self.coverage = pn.pane.Markdown("", sizing_mode="stretch_width",
                                         css_classes=["ccd-wt-coverage"])
        self.lab = pn.Column(inputs, self.use_session, self.plan_table,
                             pn.Row(self.checklist_download, self.toml_download),
                             pn.Card(self.checklist, title="Printable checklist",
                                     collapsed=True, sizing_mode="stretch_width"),
                             sizing_mode="stretch_width", margin=0,
                             css_classes=["ccd-wt-lab-plan"])
        return [self.coverage, self.lab]

    def _text(self, render: Any) -> io.BytesIO | None:
        plan = self.page.plan
        return io.BytesIO(render(plan).encode()) if plan else None

    async def run(self) -> None:
        self.replan()

    def replan(self) -> None:
        """What the session allows; with no session or a lab session the plan from the page's
        inputs (and the session's camera); then the gate."""
        page, session = self.page, self.page.state.session
        cover = page.coverage
        self.coverage.object = coverage_markdown(cover)
        self.lab.visible = cover.lab_plan
        if not cover.lab_plan:
            self.results.plan = None
            self.set_gate(cover.gate())
            return
        try:
            plan = plan_captures(
                int(page.bits), float(page.gain), read_noise_e=float(page.read_noise_e),
                pixels=int(page.pixels), exposure_half=float(page.exposure_half_ms) / 1e3,
                layout=session.camera.layout if session is not None else "mono",
                name=session.camera.name if session is not None else "")
        except CcdError as err:
            self.results.plan = None
            self.set_gate(Gate(GateStatus.FAIL, str(err), next=("correct the input named",)))
            return
        self.results.plan = PlanResult(plan, plan_rows(plan))
        self.redraw()
        self.set_gate(Gate(
            GateStatus.PASS, f"{plan.n_frames} frames to capture; predicted σ(A)/A = "
                             f"{plan.gain_rel_err:.2%}, K̂ from n1 = "
                             f"{plan.fixed_pattern.n1_required} × n2 = "
                             f"{plan.fixed_pattern.n2_required} frames",
            tuple(plan.notes) + tuple(f"missing: {m}" for m in cover.missing)))

    def draw(self, found: PlanResult) -> None:
        self.plan_table.object = found.rows
        self.checklist.object = found.plan.checklist()
        ptc = self.results.ptc
        self.use_session.disabled = ptc is None or ptc.noise is None

    def use_session_noise(self, event: Any = None) -> None:
        """The plan's gain and read noise from the photon-transfer step's result."""
        ptc = self.results.ptc
        if ptc is None or ptc.noise is None:
            return
        noise = ptc.noise
        rn = noise.read_noise_e if math.isfinite(noise.read_noise_e) else 0.0
        self.page.param.update(gain=float(noise.A), read_noise_e=float(rn))
