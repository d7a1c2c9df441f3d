"""Acquisition planning: how many fixed-pattern configurations n1 and frames per configuration n2
to capture (sec. V-B of Healey & Kondepudy 1994).

n1 (text after eq. 50)
    The error of K̂ scaled to the maximum intensity 2^b·q should have variance below q²/10:
    var[K̂] < q²/(10·(2^b q)²).  With the bound var[K̂] ≤ (p σ̂)²/n̂_1 (eq. 50) this needs
    ``n̂_1 = 10·2^(2b)·(p σ̂)²`` kept slopes at the worst pixel.  Because outlier rejection removes
    some slopes, ``n1 = ceil(n̂_1 · (n1/n̂_1)_worst)``, where the worst-case ratio of configurations
    captured to configurations kept (``n1 / min n'_1``) is measured from a previous
    :class:`~ccdcore.fixedpattern.FixedPattern` result (its ``worst_ratio``), else taken as
    :data:`DEFAULT_WORST_RATIO` (= 1.25: one slope in five lost at the worst pixel; an assumption,
    stated in the plan's notes).  n1 is at least 3 (rejection needs three slopes).

n2 (end of sec. V-B)
    "The variance of the estimates e_i is σ²_N/n2 ... allow an upper limit of 2/10": with σ²_N
    from eq. 41 at the maximum intensity (black level b0 removed: σ²_N = A·(μ_max − b0) + σ²_C,
    μ_max default 2^b − 1), ``n2 = ceil(σ²_N(μ_max) / (0.2 q²))``.  This literal reading is the
    default (``n2_reading="paper"``).

    With the paper's own numbers (A = 0.003384, σ²_C = 1.1196, b = 8) it gives σ²_N(255) = 1.983
    and n2 = 10, not the 18 the paper reports.  No natural reading gives 18 robustly; the plan
    lists the alternatives (``n2_alternatives``) so a user can see them:

    * ``"with_dark"``: e_i = average − D̂_D (eq. 46) also carries the dark reference's error:
      σ²_N(μ_max)/n2 + σ²_N(dark)/s ≤ 0.2 q² (needs ``s``; the paper's numbers give 14 with
      s = 20 dark frames, 16 if s = n2);
    * ``"difference"``: the difference-image variance 2σ²_N (eq. 31) used in place of σ²_N:
      2σ²_N/n2 ≤ 0.2 q² gives 20 at μ = 255, and 18 for a fixed-pattern level μ in (171.5, 201] DN
      (a card at 67–79 % of full scale, which is where such frames are usually taken);
    * ``"requantised"``: an average stored as integer DN adds q²/12: σ²_N/n2 + q²/12 ≤ 0.2 q²;
      this gives 17 at μ = 255 and 18 at μ = 2^b q = 256 (the paper's "maximum intensity
      representable is about 2^b q") — a knife edge, so not taken as the explanation.

    The paper's n̂_1 = 11 depends on its measured σ̂, which it does not report: 11 follows for
    σ̂ in (2.604e-3, 2.731e-3] with p = 1.5 and a worst ratio of 1.

Public objects
--------------
AcquisitionPlan
    Frozen result: required n1, n2, n̂_1, the formulas, inputs, alternatives and notes.
PlanSummary, PlanInputsSummary, PlanAlternatives
    The record a calibration product stores of a plan (:meth:`AcquisitionPlan.summary`, with
    the session's shortfalls), with its displayable ``rows()``; its inputs; n2 per reading.
plan_acquisition(A, sigma_c2, bits, ...)
    The plan from the noise model (or a PhotonTransfer-like object) and the bit depth.
check_session_plan(session, plan)
    Warnings when a session has fewer configurations or frames than the plan requires.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterable

from .common import json_safe
from .errors import CcdError
from .records import OMIT_NONE, Record, Row

__all__ = ["AcquisitionPlan", "PlanSummary", "PlanInputsSummary", "PlanAlternatives",
           "plan_acquisition", "check_session_plan", "DEFAULT_WORST_RATIO", "N2_READINGS"]

#: n1/n̂_1 assumed when no fixed-pattern result measured it
DEFAULT_WORST_RATIO = 1.25
#: the n2 readings plan_acquisition implements (see the module docstring)
N2_READINGS = ("paper", "with_dark", "difference", "requantised")


@dataclass(frozen=True)
class AcquisitionPlan:
    """How many configurations and frames to capture for K̂ (sec. V-B).

    Attributes
    ----------
    n1_required, n2_required
        Configurations and frames per configuration to capture.
    n1_hat
        n̂_1 = ceil(10·2^(2b)·(p σ̂)²), slopes needed at the worst pixel.
    n1_hat_exact
        The same before rounding up.
    worst_ratio
        n1/n̂_1 used (measured or :data:`DEFAULT_WORST_RATIO`).
    sigma2_n_max
        σ²_N at μ_max (eq. 41, black level removed), DN².
    n2_exact
        The real-valued n2 before rounding up (for the chosen reading).
    n1_formula, n2_formula
        The formulas, as text with the numbers substituted.
    n2_reading
        Which n2 reading was used (one of :data:`N2_READINGS`).
    n2_alternatives
        n2 under each reading that can be evaluated with the inputs.
    inputs
        The inputs (A, σ²_C, bits, σ̂, p, μ_max, limit, black level, q, s ...).
    notes
        Assumptions and warnings.
    """

    n1_required: int
    n2_required: int
    n1_hat: int
    n1_hat_exact: float
    worst_ratio: float
    sigma2_n_max: float
    n2_exact: float
    n1_formula: str
    n2_formula: str
    n2_reading: str
    n2_alternatives: dict[str, int] = field(default_factory=dict)
    inputs: dict[str, Any] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def summary(self, warnings: Iterable[str] = ()) -> PlanSummary:
        """The plan as the record a product stores (``estimates["plan"]``), with ``warnings``:
        what the session lacks against it (:func:`check_session_plan`)."""
        alt = {k: json_safe(v) for k, v in self.n2_alternatives.items()}
        inp = self.inputs
        s = inp.get("s")
        return PlanSummary(
            n1_required=json_safe(self.n1_required), n2_required=json_safe(self.n2_required),
            n1_hat=json_safe(self.n1_hat), n1_hat_exact=json_safe(self.n1_hat_exact),
            worst_ratio=json_safe(self.worst_ratio), sigma2_n_max=json_safe(self.sigma2_n_max),
            n2_exact=json_safe(self.n2_exact), n1_formula=self.n1_formula,
            n2_formula=self.n2_formula, n2_reading=self.n2_reading,
            n2_alternatives=PlanAlternatives(
                paper=alt["paper"], difference=alt["difference"],
                requantised=alt.get("requantised"), with_dark=alt.get("with_dark")),
            inputs=PlanInputsSummary(
                **{k: json_safe(inp[k]) for k in _INPUT_NUMBERS},
                s=None if s is None else int(s), sigma2_n_dark=json_safe(inp["sigma2_n_dark"])),
            notes=tuple(self.notes), warnings=tuple(str(w) for w in warnings))

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly values: :meth:`summary` as its JSON object, without ``warnings``."""
        out = self.summary().to_dict()
        del out["warnings"]
        return out


#: the inputs of a plan that are always numbers (:class:`PlanInputsSummary`), in order
_INPUT_NUMBERS = ("A", "sigma_c2", "bits", "sigma_hat", "p", "mu_max", "n2_var_limit",
                  "black_level", "q")


@dataclass(frozen=True)
class PlanAlternatives(Record):
    """n2 under each reading of the rule of sec. V-B (:data:`N2_READINGS`, the module
    docstring) that the plan's inputs allow; ``None`` (key absent) where they do not."""

    #: σ²_N(μ_max)/n2 ≤ limit, the literal reading; 2σ²_N (eq. 31) in place of σ²_N
    paper: int
    difference: int
    #: an average stored as integer DN adds q²/12 (``None`` when the limit is ≤ q²/12)
    requantised: int | None = field(default=None, metadata=OMIT_NONE)
    #: with the dark reference's error σ²_N(dark)/s (``None`` without s, or s too small)
    with_dark: int | None = field(default=None, metadata=OMIT_NONE)


@dataclass(frozen=True)
class PlanInputsSummary(Record):
    """The inputs of a plan (:attr:`AcquisitionPlan.inputs`)."""

    #: the noise model σ²_N = A·(μ − b0) + σ²_C (eq. 41): A (DN/e⁻), σ²_C (DN²)
    A: float
    sigma_c2: float
    #: the ADC bit depth b
    bits: int
    #: σ̂, the std of the slopes over configurations (sec. V-B), and the rejection width p
    sigma_hat: float
    p: float
    #: the intensity μ_max (raw DN) where σ²_N is evaluated for n2, and the variance limit of
    #: e_i (in q², the paper's 2/10)
    mu_max: float
    n2_var_limit: float
    #: the black level b0 (DN) and the quantisation step q (DN)
    black_level: float
    q: float
    #: dark frames s and σ²_N at the dark level (DN²) of the ``with_dark`` reading (``None``
    #: when s was not given)
    s: int | None = None
    sigma2_n_dark: float | None = None


@dataclass(frozen=True)
class PlanSummary(Record):
    """The acquisition plan of sec. V-B as a product stores it (``estimates["plan"]``,
    :meth:`AcquisitionPlan.summary`), with the session's shortfalls against it."""

    #: configurations n1 and frames per configuration n2 to capture
    n1_required: int
    n2_required: int
    #: n̂_1 = ceil(10·2^(2b)·(p σ̂)²), slopes needed at the worst pixel, and before rounding
    n1_hat: int
    n1_hat_exact: float
    #: n1/n̂_1 used (measured or :data:`DEFAULT_WORST_RATIO`)
    worst_ratio: float
    #: σ²_N at μ_max (eq. 41, black level removed), DN², and n2 before rounding up
    sigma2_n_max: float
    n2_exact: float
    #: the formulas, as text with the numbers substituted
    n1_formula: str
    n2_formula: str
    #: the n2 reading used (:data:`N2_READINGS`) and n2 under each reading
    n2_reading: str
    n2_alternatives: PlanAlternatives
    #: the inputs
    inputs: PlanInputsSummary
    #: assumptions and warnings of the plan
    notes: tuple[str, ...] = ()
    #: what the session lacks against the plan (:func:`check_session_plan`)
    warnings: tuple[str, ...] = ()

    def rows(self) -> tuple[Row, ...]:
        """The headline figures: n1 and n2 with their formulas, n̂_1, the worst-case ratio,
        σ²_N at μ_max, the reading of the n2 rule and the session's shortfalls."""
        alternatives = "; ".join(f"{k}: {v}" for k, v in self.n2_alternatives.to_dict().items())
        return (
            Row("n1 (configurations)", self.n1_required, meaning=self.n1_formula),
            Row("n2 (frames each)", self.n2_required, meaning=self.n2_formula),
            Row("n̂_1", self.n1_hat, meaning="slopes needed at the worst pixel (eq. 50)"),
            Row("worst-case ratio n1/n̂_1", self.worst_ratio,
                meaning="configurations captured per configuration kept"),
            Row("σ²_N at μ_max", self.sigma2_n_max, None, "DN²",
                f"noise variance at μ_max = {self.inputs.mu_max:g} DN (eq. 41)"),
            Row("reading of the n2 rule", meaning=alternatives, text=self.n2_reading),
            Row("shortfalls", len(self.warnings),
                meaning="what the session lacks against the plan"),
        )


def _ceil(x: float) -> int:
    """ceil with a tolerance for floating-point noise (10.000000000001 -> 10)."""
    return int(math.ceil(x - 1e-9))


def plan_acquisition(A: Any, sigma_c2: float | None = None, bits: int | None = None, *,
                     sigma_hat: float | None = None, p: float = 1.5,
                     mu_max: float | None = None, n2_var_limit: float = 0.2,
                     fixed_pattern: Any = None, worst_ratio: float | None = None,
                     black_level: float | None = None, q: float = 1.0, s: int | None = None,
                     dark_level: float | None = None,
                     n2_reading: str = "paper") -> AcquisitionPlan:
    """Required n1 and n2 for the fixed-pattern map (sec. V-B of Healey & Kondepudy 1994).

    Parameters
    ----------
    A, sigma_c2
        Noise model σ²_N = A·(μ − b0) + σ²_C (eq. 41; A in DN per electron, σ²_C in DN²).  ``A`` may
        instead be a PhotonTransfer-like object with ``.A``, ``.sigma_c2`` (and optionally
        ``.black_level_dn``); ``sigma_c2`` is then taken from it.
    bits
        ADC bit depth b.
    sigma_hat
        σ̂, the std of the slopes m_i over configurations (sec. V-B).  Taken from
        ``fixed_pattern.sigma_hat`` when omitted.
    p
        Rejection width (default 1.5).
    mu_max
        Maximum intensity (raw DN) at which σ²_N is evaluated for n2; default 2^b − 1.
    n2_var_limit
        Allowed variance of e_i in q² (the paper's 2/10).
    fixed_pattern
        A :class:`~ccdcore.fixedpattern.FixedPattern` from a pilot capture: gives σ̂ and the
        worst-case ratio n1/n̂_1.
    worst_ratio
        n1/n̂_1 to use (overrides the fixed-pattern result); default :data:`DEFAULT_WORST_RATIO`.
    black_level
        b0 in DN (default: from the PhotonTransfer-like object, else 0, the paper's model).
    q
        Quantisation step (DN).
    s, dark_level
        Number of dark frames and the dark level (raw DN, default b0) for the ``"with_dark"``
        reading.
    n2_reading
        ``"paper"`` (default), ``"with_dark"``, ``"difference"`` or ``"requantised"`` (see the
        module docstring).

    Returns
    -------
    AcquisitionPlan

    Raises
    ------
    CcdError
        Missing or non-physical inputs (A ≤ 0, σ²_C < 0, no σ̂, bits out of 1..32 ...).
    """
    notes: list[str] = []
    A, sigma_c2, b0 = _noise_model(A, sigma_c2, black_level)
    if bits is None or not (1 <= int(bits) <= 32):
        raise CcdError("bits", f"give the ADC bit depth (1..32), got {bits!r}")
    bits = int(bits)
    if not (q > 0) or not (p > 0) or not (n2_var_limit > 0):
        raise CcdError("q/p/n2_var_limit", "q, p and the variance limit must be positive")
    if n2_reading not in N2_READINGS:
        raise CcdError("n2_reading", f"unknown reading {n2_reading!r}; choose one of "
                                     f"{', '.join(N2_READINGS)}")
    n1 = _n1(bits, p, sigma_hat, worst_ratio, fixed_pattern, notes)
    n2 = _n2(A, sigma_c2, b0, bits, mu_max, n2_var_limit, q, s, dark_level, n2_reading, notes)
    inputs = {"A": A, "sigma_c2": sigma_c2, "bits": bits, "sigma_hat": n1.sigma_hat,
              "p": float(p), "mu_max": n2.mu, "n2_var_limit": float(n2_var_limit),
              "black_level": b0, "q": float(q), "s": s, "sigma2_n_dark": n2.sig2_dark}
    return AcquisitionPlan(n1_required=n1.required, n2_required=n2.required, n1_hat=n1.hat,
                           n1_hat_exact=n1.hat_exact, worst_ratio=n1.worst_ratio,
                           sigma2_n_max=n2.sig2, n2_exact=n2.exact, n1_formula=n1.formula,
                           n2_formula=n2.formula, n2_reading=n2_reading,
                           n2_alternatives={k: max(_ceil(v), 1) for k, v in n2.alts.items()},
                           inputs=inputs, notes=tuple(notes))


def _noise_model(A: Any, sigma_c2: float | None, black_level: float | None
                 ) -> tuple[float, float, float]:
    """(A, σ²_C, b0) of eq. 41, from numbers or from a PhotonTransfer-like object (``.A``,
    ``.sigma_c2``, optionally ``.black_level_dn``); b0 defaults to 0 (the paper's model)."""
    if hasattr(A, "A") and hasattr(A, "sigma_c2"):
        model = A
        A = float(model.A)
        if sigma_c2 is None:
            sigma_c2 = float(model.sigma_c2)
        if black_level is None:
            black_level = getattr(model, "black_level_dn", None)
    if sigma_c2 is None:
        raise CcdError("sigma_c2", "give σ²_C (DN²) or a PhotonTransfer result")
    A, sigma_c2 = float(A), float(sigma_c2)
    if not (A > 0) or not (sigma_c2 >= 0):
        raise CcdError("A/sigma_c2", f"need A > 0 and σ²_C ≥ 0, got A = {A}, σ²_C = {sigma_c2}")
    return A, sigma_c2, float(black_level) if black_level is not None else 0.0


@dataclass(frozen=True)
class _N1:
    required: int
    hat: int
    hat_exact: float
    worst_ratio: float
    sigma_hat: float
    formula: str


def _n1(bits: int, p: float, sigma_hat: float | None, worst_ratio: float | None,
        fixed_pattern: Any, notes: list[str]) -> _N1:
    """n1: n̂_1 = 10·2^(2b)·(p σ̂)², times the worst-case ratio n1/n̂_1 (measured by a pilot
    fixed-pattern result, else :data:`DEFAULT_WORST_RATIO`), at least 3."""
    if sigma_hat is None and fixed_pattern is not None:
        sigma_hat = float(fixed_pattern.sigma_hat)
    if sigma_hat is None or not (sigma_hat >= 0):
        raise CcdError("sigma_hat", "give σ̂ (std of the slopes m_i over configurations, sec. "
                                    "V-B), e.g. from a pilot fixed_pattern_map()")
    sigma_hat = float(sigma_hat)
    if worst_ratio is None and fixed_pattern is not None:
        worst_ratio = float(fixed_pattern.worst_ratio)
        notes.append(f"worst-case ratio n1/n̂_1 = {worst_ratio:.4g} measured from a fixed-pattern "
                     f"result ({fixed_pattern.n1} configurations, min n'_1 = "
                     f"{fixed_pattern.n1_hat})")
        if not math.isfinite(worst_ratio):
            raise CcdError("fixed_pattern", "the pilot fixed-pattern result kept no slope at some "
                                            "pixel (min n'_1 = 0): give worst_ratio=")
    elif worst_ratio is None:
        worst_ratio = DEFAULT_WORST_RATIO
        notes.append(f"worst-case ratio n1/n̂_1 not measured: assumed {DEFAULT_WORST_RATIO} "
                     "(run a pilot fixed_pattern_map and pass it as fixed_pattern=)")
    if worst_ratio < 1:
        raise CcdError("worst_ratio", f"n1/n̂_1 is at least 1, got {worst_ratio}")
    full = 2.0 ** bits
    n1_hat_exact = 10.0 * full ** 2 * (p * sigma_hat) ** 2
    n1_hat = max(_ceil(n1_hat_exact), 1)
    n1_req = _ceil(n1_hat_exact * worst_ratio)
    if n1_req < 3:
        notes.append(f"n1 = {max(n1_req, 1)} from the formula raised to 3: outlier rejection "
                     "needs at least three slopes")
        n1_req = 3
    formula = (f"n̂_1 = 10·2^(2·{bits})·({p:g}·{sigma_hat:.4g})² = {n1_hat_exact:.4g} -> "
               f"{n1_hat}; n1 = ceil(n̂_1·{worst_ratio:.4g}) = {n1_req}")
    return _N1(n1_req, n1_hat, n1_hat_exact, float(worst_ratio), sigma_hat, formula)


@dataclass(frozen=True)
class _N2:
    required: int
    exact: float
    mu: float
    sig2: float
    sig2_dark: float | None
    alts: dict[str, float]
    formula: str


def _n2(A: float, sigma_c2: float, b0: float, bits: int, mu_max: float | None,
        n2_var_limit: float, q: float, s: int | None, dark_level: float | None,
        n2_reading: str, notes: list[str]) -> _N2:
    """n2 from σ²_N(μ_max)/n2 ≤ the variance limit, in the reading asked (and every reading
    these inputs allow, as alternatives)."""
    full = 2.0 ** bits
    mu = float(full - 1.0) if mu_max is None else float(mu_max)
    if mu_max is None:
        notes.append(f"μ_max = 2^{bits} − 1 = {mu:g} DN (full scale)")
    sig2 = A * (mu - b0) + sigma_c2            # eq. 41 with the black level removed
    limit = n2_var_limit * q * q
    alts: dict[str, float] = {"paper": sig2 / limit, "difference": 2.0 * sig2 / limit}
    if limit > q * q / 12.0:
        alts["requantised"] = sig2 / (limit - q * q / 12.0)
    sig2_dark = None
    if s is not None:
        dl = b0 if dark_level is None else float(dark_level)
        sig2_dark = A * (dl - b0) + sigma_c2
        rest = limit - sig2_dark / int(s)
        if rest > 0:
            alts["with_dark"] = sig2 / rest
        else:
            notes.append(f"with s = {s} dark frames the dark reference alone exceeds the "
                         f"variance limit {limit:g}: capture more dark frames")
    if n2_reading not in alts:
        raise CcdError("n2_reading", f"reading {n2_reading!r} cannot be evaluated with these "
                                     "inputs (with_dark needs s= large enough; requantised needs "
                                     "a limit above q²/12)")
    n2_exact = alts[n2_reading]
    n2_req = max(_ceil(n2_exact), 1)
    formulas = {
        "paper": f"σ²_N(μ_max)/n2 ≤ {limit:g}",
        "with_dark": f"σ²_N(μ_max)/n2 + σ²_N(dark)/s ≤ {limit:g} (s = {s})",
        "difference": f"2·σ²_N(μ_max)/n2 ≤ {limit:g}",
        "requantised": f"σ²_N(μ_max)/n2 + q²/12 ≤ {limit:g}",
    }
    formula = (f"{formulas[n2_reading]}, σ²_N(μ_max) = {A:.4g}·({mu:g} − {b0:g}) + "
               f"{sigma_c2:.4g} = {sig2:.4g} -> n2 = ceil({n2_exact:.4g}) = {n2_req}")
    return _N2(n2_req, n2_exact, mu, sig2, sig2_dark, alts, formula)


def check_session_plan(session: Any, plan: AcquisitionPlan) -> list[str]:
    """Warnings when ``session`` has fewer fixed-pattern configurations (n1) or frames per
    configuration (n2) than ``plan`` requires, or too few dark frames for its ``s``.

    Returns an empty list when the session meets the plan.
    """
    out: list[str] = []
    configs = session.fixed_pattern_configs()
    n1 = len(configs)
    if n1 < plan.n1_required:
        out.append(f"fixed_pattern: {n1} configuration{'s' if n1 != 1 else ''}, the plan needs "
                   f"n1 = {plan.n1_required} card/lamp positions, so that the error of the "
                   "fixed-pattern map K̂ moves a full-scale pixel by less than a third of a "
                   f"quantisation step (sec. V-B): capture {plan.n1_required - n1} more "
                   f"(formula: {plan.n1_formula})")
    short = {cid: len(recs) for cid, recs in configs.items() if len(recs) < plan.n2_required}
    if short:
        listed = ", ".join(f"{cid}: {n}" for cid, n in list(short.items())[:5])
        more = f" and {len(short) - 5} more" if len(short) > 5 else ""
        out.append(f"fixed_pattern: {len(short)} configuration(s) have fewer than n2 = "
                   f"{plan.n2_required} frames, the number whose mean keeps the temporal "
                   "noise variance at full scale below "
                   f"{plan.inputs.get('n2_var_limit', 0.2):g} q² (sec. V-B): capture more frames "
                   f"at each of them (frames now, by configuration: {listed}{more}; formula: "
                   f"{plan.n2_formula})")
    s = plan.inputs.get("s")
    n_dark = len(session.dark_frames())
    if s is not None and n_dark < int(s):
        out.append(f"dark: {n_dark} dark frames, the plan assumed s = {s}")
    elif n_dark == 0:
        out.append("dark: no dark frames; K̂ needs the dark reference D̂_D (eq. 46)")
    return out
