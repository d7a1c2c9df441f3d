"""The verdict of a step, and the photon-transfer gate: judged on what matters to a user, the
line's deviation from its points and the gain's error, each against a stated tolerance, χ² and Q
still shown (a good camera measured with millions of pixels resolves any nonlinearity, and a χ²
test alone fails it).

The records and the gate live here, below :mod:`ccdcore.guide` (which re-exports them) and
:mod:`ccdcore.ptc_fit` (whose summary rows show the gate's line): one verdict, in the same words
on every surface.

Public objects
--------------
GateStatus, Gate, STATUS_LABELS
    A step's verdict: pass, warn, fail or skip, its summary, reasons and next steps; the words
    of each status.
ptc_gate(noise, emva=None), ptc_deviation(noise), ptc_linearity(noise)
    The photon-transfer gate and what it judges.
Q_RESOLVED, PTC_DEVIATION_PASS, PTC_DEVIATION_FAIL, LINEARITY_PASS, LINEARITY_FAIL,
GAIN_ERROR_LIMIT
    Its tolerances.
pct(x)
    A fraction as a percentage with three significant digits.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

__all__ = ["GateStatus", "Gate", "STATUS_LABELS", "ptc_gate", "ptc_deviation", "ptc_linearity",
           "Q_RESOLVED", "PTC_DEVIATION_PASS", "PTC_DEVIATION_FAIL", "LINEARITY_PASS",
           "LINEARITY_FAIL", "GAIN_ERROR_LIMIT", "pct"]

#: photon transfer: Q (eq. 67) below this means χ² resolves the points' deviation from the line
Q_RESOLVED = 0.01
#: photon transfer: a resolved relative deviation (σ̂²_N − line)/line of the points within
#: ±3 % passes, within ±10 % warns, beyond fails.  The variance is the derivative of the
#: response (σ²_y ∝ (dμ_y/dμ_e)²), so a smooth linearity error LE of the mean shows in the
#: photon transfer 2 to 5 times larger: the ±1 % of a good EMVA 1288 datasheet is ±2–5 %
#: here; ±10 % is a response 3–5 % off linear, or a clipped level
PTC_DEVIATION_PASS = 0.03
PTC_DEVIATION_FAIL = 0.10
#: photon transfer: the linearity error of the means (EMVA 1288 sec. 6.7) within ±1 % passes
#: (what good datasheets state: the reference CCD −0.62 … +0.48 %), within ±3 % warns
LINEARITY_PASS = 0.01
LINEARITY_FAIL = 0.03
#: photon transfer: σ(A)/A, the nonlinearity included (Birge ratio), above this warns
GAIN_ERROR_LIMIT = 0.05


class GateStatus(StrEnum):
    """A gate's verdict.  A ``str``: each member equals, hashes, formats and serialises (JSON)
    as its value, so code comparing a status to ``"pass"`` keeps working."""

    PASS = "pass"    # the step's checks hold
    WARN = "warn"    # done, with warnings (the reasons say which)
    FAIL = "fail"    # a check fails: fix what ``next`` says before relying on the step
    SKIP = "skip"    # not run: the session lacks the frames (``next`` says which to capture)


@dataclass(frozen=True)
class Gate:
    """A step's verdict: ``status`` a :class:`GateStatus` (``"pass"``, ``"warn"``, ``"fail"``
    or ``"skip"``; a bare string of these is taken as its member, any other is refused with
    ``ValueError``); ``summary`` one line; ``reasons`` why; ``next`` what to capture or
    change."""

    status: GateStatus
    summary: str
    reasons: tuple[str, ...] = ()
    next: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "status", GateStatus(self.status))

    @property
    def label(self) -> str:
        """The status in the words every surface shows it with (:data:`STATUS_LABELS`)."""
        return STATUS_LABELS[self.status]

    def line(self) -> str:
        """``"Passed with warnings: <summary>"``: the verdict in one line, the same on every
        surface (the Walkthrough, the Photon transfer page, ``ccdcore ptc``, the report)."""
        return f"{self.label}: {self.summary}"

    def to_dict(self) -> dict[str, Any]:
        return {"status": self.status.value, "label": self.label, "summary": self.summary,
                "reasons": list(self.reasons), "next": list(self.next)}


#: the words of each gate status, on every surface
STATUS_LABELS: dict[GateStatus, str] = {
    GateStatus.PASS: "Passed", GateStatus.WARN: "Passed with warnings",
    GateStatus.FAIL: "Failed", GateStatus.SKIP: "Skipped"}


def _finite(x: Any) -> bool:
    try:
        return x is not None and math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def pct(x: float) -> str:
    return f"{100 * x:.3g} %"


def ptc_deviation(noise: Any) -> tuple[float, float, Any]:
    """The relative deviation of the used points from the line, (σ̂²_N − line)/line with line
    = A·μ + σ²_C (eq. 41): its minimum and maximum over the used levels and the level of the
    largest |deviation| (``(nan, nan, None)`` without used levels)."""
    dev = [((p.var - (noise.A * p.mu + noise.sigma_c2)) / (noise.A * p.mu + noise.sigma_c2), p)
           for p in noise.points if p.used and noise.A * p.mu + noise.sigma_c2 > 0]
    if not dev:
        return math.nan, math.nan, None
    worst = max(dev, key=lambda d: abs(d[0]))[1]
    return min(d for d, _ in dev), max(d for d, _ in dev), worst


def ptc_linearity(noise: Any) -> tuple[float, float] | None:
    """The linearity error of the used levels' means against their photon counts, in the
    spirit of EMVA 1288 release 3.1 sec. 6.7: the line a·μ_p + b minimising
    Σ((μ − a·μ_p − b)/μ)² through the used points above 5 % of the largest μ (μ = μ̂ − b₀ of
    eq. 37), and (LE_min, LE_max) = the extreme relative deviations (μ − fit)/fit, fractions.
    ``None`` unless every such point has a photon count (an EMVA 1288 set) and there are three."""
    used = [p for p in noise.points if p.used]
    if not used:
        return None
    top = max(p.mu for p in used)
    pts = [p for p in used if p.mu >= 0.05 * top]
    if len(pts) < 3 or any(getattr(p, "photons", None) is None for p in pts):
        return None
    x = np.array([p.photons for p in pts], np.float64)
    y = np.array([p.mu for p in pts], np.float64)
    if np.any(y <= 0) or np.ptp(x) <= 0:
        return None
    a, b = np.linalg.lstsq(np.column_stack([x / y, 1.0 / y]), np.ones_like(y), rcond=None)[0]
    fit = a * x + b
    rel = (y - fit) / fit
    return float(rel.min()), float(rel.max())


def _worse(a: GateStatus, b: GateStatus) -> GateStatus:
    order = (GateStatus.PASS, GateStatus.WARN, GateStatus.FAIL)
    return a if order.index(a) >= order.index(b) else b


def _band(value: float, pass_limit: float, fail_limit: float) -> GateStatus:
    """PASS within ±``pass_limit``, WARN within ±``fail_limit``, FAIL beyond (limits included
    in the better band)."""
    if abs(value) <= pass_limit:
        return GateStatus.PASS
    return GateStatus.WARN if abs(value) <= fail_limit else GateStatus.FAIL


def ptc_gate(noise: Any, *, emva: Any = None) -> Gate:
    """The photon-transfer gate of a :class:`~ccdcore.noise.PhotonTransfer`: judged on what a
    user needs, the line's deviation from the points and the gain's error, each against a
    stated tolerance; χ² (eq. 42) and Q (eq. 67) are reported and say whether the deviation is
    resolved at all.

    * the points' deviation from the line, (σ̂²_N − A·μ − σ²_C)/(A·μ + σ²_C) (eqs. 38, 41):
      within ±:data:`PTC_DEVIATION_PASS` passes, within ±:data:`PTC_DEVIATION_FAIL` warns,
      beyond fails -- judged only when χ² resolves it (Q < :data:`Q_RESOLVED`); otherwise the
      points agree with the line within their errors and the gate passes;
    * the linearity error of the means (EMVA 1288 sec. 6.7; ``emva``'s ``LE_min``/``LE_max``
      in %, else :func:`ptc_linearity` when the levels carry photon counts): within
      ±:data:`LINEARITY_PASS` passes, within ±:data:`LINEARITY_FAIL` warns, beyond fails;
    * σ(A)/A with the nonlinearity included, the statistical error of eq. 66 times the Birge
      ratio √(χ²/ν) when χ²/ν > 1: above :data:`GAIN_ERROR_LIMIT` warns;
    * fewer than 3 levels used, or no degrees of freedom, fails.
    """
    used = int(np.sum([p.used for p in noise.points]))
    missing = [name for name in ("A", "A_err", "sigma_c2", "sigma_c2_err", "chi2")
               if not _finite(getattr(noise, name, None))]
    if missing or noise.dof is None:
        return Gate(GateStatus.FAIL, "the photon-transfer figures are incomplete ("
                                     f"{', '.join(missing or ['dof'])} missing): the line "
                                     "cannot be judged",
                    (f"fit range: {getattr(noise, 'fit_range', None)}",),
                    ("compute photon transfer again from the session",))
    q = float(noise.Q) if noise.dof > 0 else float("nan")
    chi2_dof = float(noise.chi2) / noise.dof if noise.dof > 0 else float("nan")
    birge = math.sqrt(chi2_dof) if chi2_dof > 1.0 else 1.0
    a_rel = birge * noise.A_err / noise.A if noise.A > 0 else float("inf")
    reasons = [f"A = {noise.A:.4g} ± {birge * noise.A_err:.2g} DN/e⁻ (σ(A)/A = {pct(a_rel)}"
               + (f", the statistical error × √(χ²/ν) = {birge:.3g} to include the "
                  "nonlinearity" if birge > 1.0 else "")
               + f"), σ²_C = {noise.sigma_c2:.4g} ± {birge * noise.sigma_c2_err:.2g} DN² from "
               f"{used} levels; χ² = {noise.chi2:.3g} with {noise.dof} degrees of freedom, "
               f"Q = {q:.3g}", f"fit range: {noise.fit_range}"]
    if used < 3 or noise.dof <= 0:
        return Gate(GateStatus.FAIL, "fewer than 3 levels in the fit: the line cannot be "
                                     "checked against its points", tuple(reasons),
                    ("capture pairs at more light levels (8 spread over the range; the capture "
                     "plan lists them)",))
    lo, hi, worst = ptc_deviation(noise)
    dev = lo if abs(lo) >= abs(hi) else hi
    resolved = not q >= Q_RESOLVED
    tol = (f"tolerance ±{pct(PTC_DEVIATION_PASS)} passes, ±{pct(PTC_DEVIATION_FAIL)} warns")
    reasons.append(f"the points deviate from the line by {100 * lo:+.2f} … {100 * hi:+.2f} % "
                   f"((σ̂²_N − line)/line; largest at level {worst.level}, "
                   f"{_resid(noise, worst):+.1f} σ); {tol}")
    status = GateStatus.PASS
    nxt: list[str] = []
    if not resolved:
        summary = "the points agree with the line within their errors"
    else:
        status = _band(dev, PTC_DEVIATION_PASS, PTC_DEVIATION_FAIL)
        reasons.append(f"χ²/ν = {chi2_dof:.3g} (Q = {q:.3g} < {Q_RESOLVED:g}): the points' "
                       "statistical errors are smaller than their deviation, so χ² resolves a "
                       "nonlinearity; whether it matters is its size against the tolerance")
        summary = {GateStatus.PASS: f"the line holds within ±{pct(PTC_DEVIATION_PASS)}: χ² "
                                    f"resolves a slight nonlinearity ({100 * dev:+.2f} %), "
                                    "within the tolerance",
                   GateStatus.WARN: f"the points deviate from the line by up to "
                                    f"{100 * dev:+.2f} %: beyond ±{pct(PTC_DEVIATION_PASS)}, "
                                    f"within ±{pct(PTC_DEVIATION_FAIL)}",
                   GateStatus.FAIL: f"the points deviate from the line by {100 * dev:+.2f} %, "
                                    f"beyond ±{pct(PTC_DEVIATION_FAIL)}: the camera is not "
                                    "linear over the fit range, or a level is clipped"}[status]
    if status != GateStatus.PASS:
        nxt.append(f"exclude level {worst.level} or switch on robust mode (drops levels beyond "
                   "3 σ one at a time); if levels near full scale misbehave, they are clipped")
        top = [p for p in noise.points if p.used]
        if noise.fit_fraction is None and worst.mu >= 0.7 * max(p.mu for p in top):
            nxt.append("the worst level is near saturation: fit over the EMVA 1288 range "
                       "(0–70 % of the saturation signal), where the standard fits the gain")
    clipped = [p.level for p in noise.points if p.used and getattr(p, "clipped_fraction", 0) > 0]
    if clipped:
        reasons.append(f"level(s) {', '.join(map(str, clipped))} have values at 0 or full "
                       "scale (fewer than the clipping limit): check them if they deviate")
    status, summary = _linearity_band(noise, emva, status, summary, reasons, nxt)
    if a_rel > GAIN_ERROR_LIMIT:
        status = _worse(status, GateStatus.WARN)
        reasons.append(f"σ(A)/A = {pct(a_rel)} is above {pct(GAIN_ERROR_LIMIT)}")
        nxt.append("use a larger ROI or more levels")
        if summary.startswith("the points agree") or summary.startswith("the line holds"):
            summary = f"the gain's error σ(A)/A = {pct(a_rel)} is above {pct(GAIN_ERROR_LIMIT)}"
    return Gate(status, summary, tuple(reasons), tuple(nxt))


def _linearity_band(noise: Any, emva: Any, status: GateStatus, summary: str,
                    reasons: list[str], nxt: list[str]) -> tuple[GateStatus, str]:
    """The linearity error of the means (EMVA 1288 sec. 6.7) joined to the gate."""
    le: tuple[float, float] | None = None
    source = "the used levels' means against their photon counts"
    if emva is not None and getattr(emva, "LE_min", None) is not None and \
            getattr(emva, "LE_max", None) is not None and math.isfinite(emva.LE_min):
        le, source = (emva.LE_min / 100.0, emva.LE_max / 100.0), \
            "the EMVA 1288 datasheet, 5–95 % of saturation"
    else:
        le = ptc_linearity(noise)
    if le is None:
        return status, summary
    worst = le[0] if abs(le[0]) >= abs(le[1]) else le[1]
    band = _band(worst, LINEARITY_PASS, LINEARITY_FAIL)
    reasons.append(f"linearity error LE = {100 * le[0]:+.2f} … {100 * le[1]:+.2f} % ({source}; "
                   f"EMVA 1288 sec. 6.7); tolerance ±{pct(LINEARITY_PASS)} passes, "
                   f"±{pct(LINEARITY_FAIL)} warns")
    if band == GateStatus.PASS or _worse(status, band) == status:
        return status, summary
    nxt.append("the camera's response is not linear: check the exposure times and the light "
               "source, and the levels near saturation")
    return band, (f"the linearity error {100 * worst:+.2f} % is beyond "
                  f"±{pct(LINEARITY_PASS if band == GateStatus.WARN else LINEARITY_FAIL)}")


def _resid(noise: Any, p: Any) -> float:
    pred = noise.A * p.mu + noise.sigma_c2
    return float((p.var - pred) / p.var_err) if p.var_err > 0 else 0.0
