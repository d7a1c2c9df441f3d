"""The Maps page's Planning tab: n1 and n2 for K̂ from typed or estimated inputs (sec. V-B).

Public objects
--------------
PlanningTab
    The part of :class:`ccdcore_app.pages.maps.page.MapsPage` (a ``param`` mixin: the inputs of
    :func:`ccdcore.planning.plan_acquisition` and their watcher) that shows n1 and n2 with their
    formulas and the n2 of every reading of the paper's rule.
PAPER_PLAN_INPUTS, PLAN_INPUTS, READINGS
    The paper's inputs; the inputs asked for; the readings of the n2 rule (label -> name).
"""
from __future__ import annotations

import html
import math
from typing import Any

import pandas as pd
import panel as pn
import param

from ccdcore.errors import CcdError
from ccdcore.planning import DEFAULT_WORST_RATIO, plan_acquisition

from .tables import MAPS_CSS, data_table, maps_alert, round_sig

__all__ = ["PlanningTab", "PAPER_PLAN_INPUTS", "PLAN_INPUTS", "READINGS"]

#: the paper's noise model and bit depth (sec. VII-A); σ̂ is not reported by the paper:
#: 2.7e-3 is inside the interval (2.604e-3, 2.731e-3] that gives its n̂_1 = 11 (ccdcore.planning)
PAPER_PLAN_INPUTS: dict[str, Any] = {"A": 0.003384, "sigma_c2": 1.1196, "bits": 8,
                                     "sigma_hat": 2.7e-3, "p": 1.5,
                                     "worst_ratio": DEFAULT_WORST_RATIO, "black_level": 0.0,
                                     "n2_reading": "paper"}
#: the inputs of :func:`ccdcore.planning.plan_acquisition` the Planning tab asks for
PLAN_INPUTS = ("A", "sigma_c2", "bits", "sigma_hat", "p", "worst_ratio", "black_level",
               "n2_reading")

#: the readings of the paper's n2 rule (label -> ``plan_acquisition``'s ``n2_reading``)
READINGS = {"paper (σ²_N/n2 ≤ 0.2 q², the literal text)": "paper",
            "with the dark reference's error": "with_dark",
            "difference-image variance 2σ²_N": "difference",
            "requantised average (+ q²/12)": "requantised"}
READING_TEXT = {v: k for k, v in READINGS.items()}


class PlanningTab(param.Parameterized):
    """Mixin of the Maps page: the Planning tab (see the module docstring)."""

    state: Any

    A = param.Number(default=PAPER_PLAN_INPUTS["A"], allow_None=True,
                     doc="A: the gain in DN per electron (photon transfer).")
    sigma_c2 = param.Number(default=PAPER_PLAN_INPUTS["sigma_c2"], allow_None=True,
                            doc="σ²_C: the noise intercept in DN² (photon transfer).")
    bits = param.Integer(default=PAPER_PLAN_INPUTS["bits"], allow_None=True,
                         doc="b: the ADC bit depth.")
    sigma_hat = param.Number(default=PAPER_PLAN_INPUTS["sigma_hat"], allow_None=True,
                             doc="σ̂: the standard deviation of the fixed-pattern slopes m_i.")
    p = param.Number(default=PAPER_PLAN_INPUTS["p"], allow_None=True,
                     doc="p: the width of the slope rejection (eq. 48).")
    worst_ratio = param.Number(default=PAPER_PLAN_INPUTS["worst_ratio"], allow_None=True,
                               doc="n1/n̂_1 at the worst pixel (slopes rejected there).")
    black_level = param.Number(default=PAPER_PLAN_INPUTS["black_level"], allow_None=True,
                               doc="b0: the black level in DN.")
    n2_reading = param.Selector(default=PAPER_PLAN_INPUTS["n2_reading"], objects=READINGS,
                                doc="Which reading of the paper's n2 rule to plan with.")

    def _build_planning_tab(self) -> None:
        self.plan_A = pn.widgets.FloatInput.from_param(self.param.A, label="A (DN per electron)",
                                                       step=1e-4, start=0.0, width=170)
        self.plan_sigma_c2 = pn.widgets.FloatInput.from_param(
            self.param.sigma_c2, label="σ²_C (DN²)", step=0.01, start=0.0, width=170)
        self.plan_bits = pn.widgets.IntInput.from_param(self.param.bits, label="bits b", start=1,
                                                        end=32, width=120)
        self.plan_sigma_hat = pn.widgets.FloatInput.from_param(
            self.param.sigma_hat, label="σ̂ (slope std)", step=1e-4, start=0.0, width=170)
        self.plan_p = pn.widgets.FloatInput.from_param(self.param.p, label="p (rejection width)",
                                                       step=0.1, start=0.1, width=150)
        self.plan_worst = pn.widgets.FloatInput.from_param(
            self.param.worst_ratio, label="worst ratio n1/n̂_1", step=0.05, start=1.0, width=170)
        self.plan_black = pn.widgets.FloatInput.from_param(
            self.param.black_level, label="black level b0 (DN)", step=1.0, width=150)
        self.plan_reading = pn.widgets.Select.from_param(self.param.n2_reading,
                                                         label="n2 reading", width=330)
        self._plan_inputs = (self.plan_A, self.plan_sigma_c2, self.plan_bits,
                             self.plan_sigma_hat, self.plan_p, self.plan_worst,
                             self.plan_black, self.plan_reading)
        self.paper_button = pn.widgets.Button(label="Paper's values", width=150)
        self.paper_button.on_click(self._on_paper_inputs)
        self.session_inputs_button = pn.widgets.Button(
            label="This session's estimates", width=200, disabled=True,
            description="A, σ²_C and b0 from photon transfer; σ̂ and the worst ratio from K̂")
        self.session_inputs_button.on_click(self._on_session_inputs)
        self.plan_source = pn.pane.Markdown("", sizing_mode="stretch_width",
                                            styles={"color": "#6c757d", "font-size": "0.9em"})
        self.plan_numbers = pn.pane.HTML("", sizing_mode="stretch_width", stylesheets=[MAPS_CSS],
                                         css_classes=["ccd-plan-numbers"])
        self.plan_formulas = pn.pane.Markdown("", sizing_mode="stretch_width",
                                              css_classes=["ccd-formula"], stylesheets=[MAPS_CSS])
        self.plan_alternatives = data_table()
        self.plan_error = maps_alert("", "danger")

    def _planning_tab_layout(self) -> pn.Column:
        """The Planning tab: what it plans, the inputs, n1 and n2, their formulas."""
        inputs = pn.FlexBox(*self._plan_inputs, sizing_mode="stretch_width")
        return pn.Column(
            pn.pane.Markdown(
                "How many fixed-pattern configurations **n1** and frames per configuration "
                "**n2** to capture for K̂ (sec. V-B): the error of K̂ at full scale below "
                "q²/10 (n1) and the variance of each configuration's average below 0.2 q² (n2)."
                " Type your camera's values before capture, or take them from this session's "
                "estimates.", sizing_mode="stretch_width"),
            pn.Row(self.paper_button, self.session_inputs_button), self.plan_source,
            inputs, self.plan_error, self.plan_numbers, self.plan_formulas,
            pn.Card(self.plan_alternatives, title="n2 under each reading of the paper",
                    sizing_mode="stretch_width", collapsed=False),
            sizing_mode="stretch_width", name="Planning")

    # ===================================================================== planning =========
    def plan_inputs(self) -> dict[str, Any]:
        """The Planning tab's inputs, as keyword arguments of ``plan_acquisition``."""
        return {k: getattr(self, k) for k in PLAN_INPUTS}

    @param.depends(*PLAN_INPUTS, watch=True)
    def _update_plan(self) -> None:
        kw = self.plan_inputs()
        try:
            if any(v is None for v in kw.values()):
                raise CcdError("planning", "fill in every input")
            plan = plan_acquisition(**kw)
        except CcdError as err:
            self.plan_result = None
            self.plan_error.object = f"**Cannot plan:** {html.escape(str(err))}"
            self.plan_error.visible = True
            self.plan_numbers.object = self.plan_formulas.object = ""
            self.plan_alternatives.value = pd.DataFrame()
            return
        self.plan_result = plan
        self.plan_error.visible = False
        self.plan_numbers.object = (
            "<div>Capture <span class='ccd-big'>n1 = "
            f"{plan.n1_required}</span> configurations &times; <span class='ccd-big'>n2 = "
            f"{plan.n2_required}</span> frames per configuration "
            f"({plan.n1_required * plan.n2_required} fixed-pattern frames); "
            f"n̂_1 = {plan.n1_hat} slopes kept at the worst pixel.</div>")
        notes = "\n".join(f"- {html.escape(n)}" for n in plan.notes)
        self.plan_formulas.object = (
            f"**n1** (text after eq. 50): `{plan.n1_formula}`\n\n"
            f"**n2** (end of sec. V-B, reading *{plan.n2_reading}*): `{plan.n2_formula}`"
            + (f"\n\n{notes}" if notes else ""))
        self.plan_alternatives.value = pd.DataFrame(
            [{"reading": READING_TEXT.get(k, k), "n2": v,
              "chosen": "✓" if k == plan.n2_reading else ""}
             for k, v in plan.n2_alternatives.items()],
            columns=["reading", "n2", "chosen"])

    def _set_plan_inputs(self, values: dict[str, Any], source: str) -> None:
        """Set the planning inputs (one plan update for all of them)."""
        self.param.update(**{k: v for k, v in values.items()
                             if k in PLAN_INPUTS and v is not None})
        self.plan_source.object = source

    def session_plan_inputs(self) -> dict[str, Any] | None:
        """Planning inputs from the session's results (``None`` without a noise model)."""
        results, session = self.state.results, self.state.session
        noise, fp = results.ptc, results.fixed_pattern
        if noise is None:
            return None
        b0 = noise.black_level_dn
        values: dict[str, Any] = {"A": round_sig(noise.A), "sigma_c2": round_sig(noise.sigma_c2),
                                  "black_level": float(b0) if b0 is not None else 0.0}
        bits = getattr(getattr(session, "camera", None), "bits", None)
        if bits:
            values["bits"] = int(bits)
        if fp is not None:
            values["sigma_hat"] = round_sig(fp.sigma_hat)
            if math.isfinite(fp.worst_ratio):
                values["worst_ratio"] = round_sig(fp.worst_ratio)
            values["p"] = float(fp.p)
        return values

    def _prefill_plan(self, results: Any) -> None:
        key = (id(results.ptc), id(results.fixed_pattern))
        if key == getattr(self, "_prefilled", None):
            return
        self._prefilled = key
        values = self.session_plan_inputs()
        self.session_inputs_button.disabled = values is None
        if values is None:
            self._set_plan_inputs(PAPER_PLAN_INPUTS, "Inputs: the paper's values (sec. VII-A; "
                                  "σ̂ = 2.7e-3 reproduces its n̂_1 = 11). Edit them for your "
                                  "camera.")
        else:
            self._on_session_inputs()

    def _on_paper_inputs(self, event: Any = None) -> None:
        self._set_plan_inputs(PAPER_PLAN_INPUTS, "Inputs: the paper's values (sec. VII-A; "
                              "σ̂ = 2.7e-3 reproduces its n̂_1 = 11).")

    def _on_session_inputs(self, event: Any = None) -> None:
        values = self.session_plan_inputs()
        if values is None:
            return
        has_fp = self.state.results.fixed_pattern is not None
        self._set_plan_inputs(values, "Inputs: this session's photon transfer (A, σ²_C, b0)"
                              + (" and fixed pattern (σ̂, worst ratio, p)." if has_fp else
                                 "; σ̂ and the worst ratio are the paper's / the default until "
                                 "K̂ is computed."))
