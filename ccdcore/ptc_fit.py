"""The photon-transfer levels and their fit for :mod:`ccdcore.noise`: the measured level
(:class:`PtcPoint`), the weighted line σ²_N = A·μ + σ²_C in the closed form of Healey & Kondepudy's
appendix (eqs. 59–67) and the exclusion rules a level is checked against before the fit (clipping,
zero variance, saturation, linearity, the EMVA 1288 fit range; their statement is in the
docstring of :mod:`ccdcore.noise`).

Every name in ``__all__`` but the rules is re-exported by :mod:`ccdcore.noise`.

Public objects
--------------
PtcPoint, LineFit
    Frozen results: one light level; the weighted line.
PtcPointSummary, PhotonTransferSummary
    The records a calibration product stores (:class:`ccdcore.records.Record`): one light level
    (:meth:`PtcPoint.summary`, back with :meth:`PtcPoint.from_summary`) and the photon-transfer
    result (:meth:`ccdcore.noise.PhotonTransfer.summary`, back with
    :meth:`ccdcore.noise.PhotonTransfer.from_summary`), each with its displayable ``rows()``.
weighted_line_fit(mu, var, var_var)
    The closed-form weighted line, its covariance, χ², degrees of freedom and Q (eqs. 59–67).
goodness_of_fit(chi2, dof)
    Q (eq. 67).
data_reason(p, bits)
    Why the data of a level cannot be used (clipping, zero variance), or None.
saturation_reasons(points, tol), linearity_reasons(points, tol), range_reasons(points, reasons,
fraction)
    The levels past saturation, beyond the linear range and outside the fit range, with reasons.
CLIP_LIMIT, LINEARITY_Z
    The thresholds of the clipping and linearity rules.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike

from .common import float_or_nan, json_safe
from .errors import CcdError
from .records import Record, Row, positive_problems

__all__ = ["PtcPoint", "PtcPointSummary", "PhotonTransferSummary", "LineFit",
           "weighted_line_fit", "goodness_of_fit", "data_reason", "saturation_reasons",
           "linearity_reasons", "range_reasons", "CLIP_LIMIT", "LINEARITY_Z"]

#: a level is clipped when more than this fraction of its ROI pixel values is at 0 or full scale
CLIP_LIMIT = 1e-4
#: standardized σ̂²_N residual beyond which a top-10 % level counts as beyond the linear range
LINEARITY_Z = 5.0
#: the fraction of the μ̂ range where the variance-based linearity rule looks
_TOP_FRACTION = 0.10


# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PtcPoint:
    """One photon-transfer light level.

    Attributes
    ----------
    level
        The ``level`` id of the session.
    mu
        μ̂ − b₀: the mean of eq. 37 minus the black level, DN (the fit's abscissa).
    var
        σ̂²_N (eq. 38), DN²; with several pairs, the average of the pairs' estimates.
    var_err
        Standard error of ``var``: √(eq. 40), i.e. √(2(σ̂²_N)²/(n_pairs·(M − 1))) for the average
        of ``n_pairs`` independent pair estimates.
    n_pairs, n_pixels
        Number of disjoint pairs (frames 0-1, 2-3, ...) and pixels M per frame (the ROI).
    used, reason, exclusion
        Whether the fit used the level, why not for a person (``None`` when used), and the kind
        of exclusion for programs (:data:`ccdcore.noise.EXCLUSIONS`; ``None`` when used).
    exposure
        The level's exposure time (s), when known.
    mu_raw
        μ̂ as measured (eq. 37), DN.
    clipped_fraction
        Fraction of the ROI pixel values of the level's frames at 0 or at 2^bits − 1.
    photons
        Mean photons per pixel (EMVA1288 descriptors), when known.
    """

    level: int
    mu: float
    var: float
    var_err: float
    n_pairs: int
    n_pixels: int
    used: bool
    reason: str | None
    exposure: float | None
    mu_raw: float
    clipped_fraction: float
    photons: float | None = None
    exclusion: str | None = None

    def summary(self) -> PtcPointSummary:
        """The level as the record a product stores (plain numbers, NaN as ``None``)."""
        return PtcPointSummary(
            level=json_safe(self.level), mu=json_safe(self.mu), var=json_safe(self.var),
            var_err=json_safe(self.var_err), used=bool(self.used), reason=self.reason,
            exclusion=self.exclusion, n_pairs=json_safe(self.n_pairs),
            n_pixels=json_safe(self.n_pixels), exposure=json_safe(self.exposure),
            mu_raw=json_safe(self.mu_raw), clipped_fraction=json_safe(self.clipped_fraction),
            photons=json_safe(self.photons))

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly values: :meth:`summary` as its JSON object."""
        return self.summary().to_dict()

    @classmethod
    def from_summary(cls, s: PtcPointSummary) -> PtcPoint:
        """The level a product stored (the inverse of :meth:`summary`: ``None`` written for NaN
        is NaN again, ``PtcPoint.from_summary(s).summary() == s``)."""
        return cls(level=int(s.level), mu=float_or_nan(s.mu), var=float_or_nan(s.var),
                   var_err=float_or_nan(s.var_err), n_pairs=int(s.n_pairs),
                   n_pixels=int(s.n_pixels), used=bool(s.used), reason=s.reason,
                   exposure=s.exposure, mu_raw=float_or_nan(s.mu_raw),
                   clipped_fraction=float_or_nan(s.clipped_fraction), photons=s.photons,
                   exclusion=s.exclusion)


@dataclass(frozen=True)
class LineFit:
    """The weighted line σ²_N = A·μ + σ²_C (eqs. 59–67).

    ``cov`` is the 2×2 covariance of (A, σ²_C) (eq. 66); ``Q`` the probability that χ² would exceed
    the value found if the model is right (eq. 67), NaN when ``dof`` = 0.
    """

    A: float
    sigma_c2: float
    cov: np.ndarray
    chi2: float
    dof: int
    Q: float

    def predict(self, mu: ArrayLike) -> tuple[np.ndarray | float, np.ndarray | float]:
        """The line at ``mu`` and its 1-σ band from the covariance:
        ``std² = μ²·C₀₀ + 2μ·C₀₁ + C₁₁``."""
        m = np.asarray(mu, dtype=np.float64)
        value = self.A * m + self.sigma_c2
        var = m * m * self.cov[0, 0] + 2.0 * m * self.cov[0, 1] + self.cov[1, 1]
        std = np.sqrt(np.maximum(var, 0.0))
        if m.ndim == 0:
            return float(value), float(std)
        return value, std

    def to_dict(self) -> dict[str, Any]:
        return {"A": json_safe(self.A), "sigma_c2": json_safe(self.sigma_c2),
                "cov": json_safe(self.cov.tolist()), "chi2": json_safe(self.chi2),
                "dof": self.dof, "Q": json_safe(self.Q)}


# --------------------------------------------------------------------------------------------
# the records a calibration product stores
# --------------------------------------------------------------------------------------------
#: the covariance of (A, σ²_C) (eq. 66) as stored: two rows of two numbers, ``None`` for NaN
CovRows = tuple[tuple[float | None, float | None], tuple[float | None, float | None]]



@dataclass(frozen=True)
class PtcPointSummary(Record):
    """One photon-transfer light level as a product stores it (:meth:`PtcPoint.summary`);
    the fields are those of :class:`PtcPoint`."""

    #: the ``level`` id of the session
    level: int
    #: μ̂ − b₀, the mean of eq. 37 minus the black level (DN); σ̂²_N (eq. 38, DN²) and its
    #: standard error √(eq. 40)
    mu: float
    var: float
    var_err: float
    #: whether the fit used the level; why not, for a person and as a kind of exclusion
    #: (:data:`ccdcore.noise.EXCLUSIONS`), ``None`` when used
    used: bool
    reason: str | None
    exclusion: str | None
    #: disjoint pairs and pixels M per frame (the ROI)
    n_pairs: int
    n_pixels: int
    #: exposure time (s), when known
    exposure: float | None
    #: μ̂ as measured (eq. 37), DN; the fraction of ROI values at 0 or 2^bits − 1
    mu_raw: float
    clipped_fraction: float
    #: mean photons per pixel (EMVA 1288 descriptors), when known
    photons: float | None = None

    def rows(self) -> tuple[Row, ...]:
        """The level as a person reads it: its mean, σ̂²_N with its error, and whether the fit
        used it."""
        return (
            Row("level", self.level, meaning="the light level of the session"),
            Row("mean μ − b₀", self.mu, None, "DN", "mean signal above the black level "
                                                    "(eq. 37)"),
            Row("noise variance σ̂²_N", self.var, self.var_err, "DN²",
                "from the difference of a frame pair (eq. 38), ± √eq. 40"),
            Row("pairs", self.n_pairs, meaning=f"frame pairs of {self.n_pixels} pixels"),
            Row("exposure", self.exposure, None, "s", "exposure time"),
            Row("fit", meaning="whether the line was fitted through the level",
                text="used" if self.used else f"excluded: {self.reason or self.exclusion}"),
        )


@dataclass(frozen=True)
class PhotonTransferSummary(Record):
    """The photon-transfer result as a product stores it (``estimates["noise"]``,
    :meth:`ccdcore.noise.PhotonTransfer.summary`): the noise model σ²_N = A·(μ − b₀) + σ²_C
    (eq. 41), its fit (eqs. 59–67), the levels and the figures derived from it (eq. 27)."""

    #: gain A in DN per electron (slope of eq. 41) and its standard error
    A: float
    A_err: float
    #: σ²_C = A²σ²_R + q²/12 (eq. 27), DN², and its standard error
    sigma_c2: float
    sigma_c2_err: float
    #: covariance of (A, σ²_C) (eq. 66)
    cov: CovRows
    #: χ² (eq. 42), P − 2 degrees of freedom, goodness of fit Q (eq. 67, ``None`` without
    #: degrees of freedom) and its plain reading
    chi2: float
    dof: int
    Q: float | None
    verdict: str
    #: every level, used or not (with the reason)
    points: tuple[PtcPointSummary, ...]
    #: 1/A, electrons per DN, and its error (``None`` when A ≤ 0)
    conversion_gain_e_per_dn: float | None
    conversion_gain_e_per_dn_err: float | None
    #: read noise σ_R = √(σ²_C − q²/12)/A (eq. 27), electrons, and in DN (A·σ_R), with errors
    #: (``None`` when σ²_C ≤ q²/12 or A ≤ 0)
    read_noise_e: float | None
    read_noise_e_err: float | None
    read_noise_dn: float | None
    read_noise_dn_err: float | None
    #: q²/12, DN²
    quantisation_dn2: float
    #: the black level b₀ (DN) and the rule that gave it (:mod:`ccdcore.noise`)
    black_level_dn: float
    black_level_source: str
    #: the region (x, y, w, h), ``None`` for the whole frame; the ADC bit depth
    roi: tuple[int, int, int, int] | None
    bits: int | None
    #: levels dropped by the robust mode, in the order dropped; plain-language remarks
    robust_dropped: tuple[int, ...]
    notes: tuple[str, ...]
    #: relative deviation from linearity tolerated by the exclusion rules
    linearity_tolerance: float = 0.05
    #: the session the points came from, when known
    source: str | None = None
    #: the fit range as a fraction of the saturation signal (``None``: every level below
    #: saturation, the paper's range) and in words
    fit_fraction: float | None = None
    fit_range: str = "every level below saturation (the paper's range)"

    def value_problems(self) -> list[tuple[str, str]]:
        """The gain A finite, and positive unless the summary states no gain (a fit whose slope
        came out negative is stored with a null conversion gain, and said so); the errors of A
        and σ²_C finite and not negative."""
        out = positive_problems(self, (), ("A_err", "sigma_c2_err"))
        if not math.isfinite(self.A):
            out.append(("A", f"is {self.A!r}: must be a finite number"))
        elif self.A <= 0 and self.conversion_gain_e_per_dn is not None:
            out.append(("A", f"is {self.A!r}, not positive, yet the conversion gain is "
                             f"stated ({self.conversion_gain_e_per_dn!r}): the gain of eq. 41 "
                             "is a positive slope"))
        return out

    def rows(self) -> tuple[Row, ...]:
        """The headline figures: A, the conversion gain, σ²_C, the read noise, b₀, the fit's
        χ², Q and the gate's verdict (the Walkthrough's words), and the levels used."""
        from .gates import ptc_gate

        used = sum(1 for p in self.points if p.used)
        return (
            Row("gain A", self.A, self.A_err, "DN/e⁻", "DN per electron (slope of eq. 41)"),
            Row("conversion gain", self.conversion_gain_e_per_dn,
                self.conversion_gain_e_per_dn_err, "e⁻/DN", "electrons per DN, 1/A"),
            Row("σ²_C", self.sigma_c2, self.sigma_c2_err, "DN²",
                "signal-independent noise, A²σ²_R + q²/12 (eq. 27)"),
            Row("read noise", self.read_noise_e, self.read_noise_e_err, "e⁻",
                "σ_R = √(σ²_C − q²/12)/A (eq. 27)"),
            Row("read noise in DN", self.read_noise_dn, self.read_noise_dn_err, "DN", "A·σ_R"),
            Row("black level b₀", self.black_level_dn, None, "DN",
                f"offset without shot noise, from: {self.black_level_source}"),
            Row("χ²", self.chi2, None, "", f"with {self.dof} degrees of freedom (eq. 42)"),
            Row("goodness of fit Q", self.Q, None, "",
                "chance of so large a χ² if the line fits (eq. 67)"),
            Row("verdict", meaning="the photon-transfer gate (ccdcore.gates.ptc_gate): the "
                                   "line's deviation from its points against stated "
                                   "tolerances", text=ptc_gate(self).line()),
            Row("levels used", used, None, "", f"of {len(self.points)} light levels; "
                                               f"{self.fit_range}"),
        )


# --------------------------------------------------------------------------------------------
# the weighted line (eqs. 59–67)
# --------------------------------------------------------------------------------------------
def goodness_of_fit(chi2: float, dof: int) -> float:
    """Q(χ²_M | ν) = ∫_{χ²_M}^∞ f_ν(x) dx, the chi-square survival function (eq. 67).

    Returns NaN when ``dof`` < 1.  The paper's fit (χ² = 4.3496, P = 6 pairs, ν = 4) gives 0.3607.
    """
    if dof < 1:
        return float("nan")
    from scipy import stats  # here: scipy.stats costs ~0.5 s to import (the app starts faster)

    return float(stats.chi2.sf(float(chi2), int(dof)))


def weighted_line_fit(mu: ArrayLike, var: ArrayLike, var_var: ArrayLike) -> LineFit:
    """Fit σ̂²_N = A·μ̂ + σ²_C minimising χ² (eq. 42) in the closed form of the appendix.

    Parameters
    ----------
    mu, var, var_var
        μ̂_i, σ̂²_N,i and var[σ̂²_N,i] (eqs. 37, 38, 40) of P ≥ 2 points; ``var_var`` > 0.

    Returns
    -------
    LineFit
        Â (eq. 59), σ̂²_C (eq. 60) from the sums S₁…S₅ (eqs. 61–65), the covariance of (A, σ²_C)
        (eq. 66), χ² at the minimum, ν = P − 2 and Q (eq. 67).

    Raises
    ------
    CcdError
        Fewer than two points, non-positive or non-finite weights, or all μ̂ equal.
    """
    x = np.asarray(mu, dtype=np.float64).ravel()
    y = np.asarray(var, dtype=np.float64).ravel()
    v = np.asarray(var_var, dtype=np.float64).ravel()
    if not (x.size == y.size == v.size):
        raise CcdError("weighted_line_fit", f"mu, var and var_var differ in length "
                                            f"({x.size}, {y.size}, {v.size})")
    if x.size < 2:
        raise CcdError("weighted_line_fit", f"need at least 2 points, got {x.size}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y)) and np.all(np.isfinite(v))
            and np.all(v > 0)):
        raise CcdError("weighted_line_fit", "mu, var must be finite and var_var finite and > 0")
    w = 1.0 / v
    s1 = w.sum()                 # eq. 61
    s2 = (w * x).sum()           # eq. 62
    s3 = (w * y).sum()           # eq. 63
    s4 = (w * x * x).sum()       # eq. 64
    s5 = (w * x * y).sum()       # eq. 65
    delta = s1 * s4 - s2 * s2
    if not delta > 0 or delta <= 1e-12 * s1 * s4:
        raise CcdError("weighted_line_fit", "all points have the same mean: the slope is "
                                            "undetermined")
    a = (s1 * s5 - s2 * s3) / delta          # eq. 59
    c = (s3 * s4 - s2 * s5) / delta          # eq. 60
    cov = np.array([[s1, -s2], [-s2, s4]]) / delta  # eq. 66, order (A, σ²_C)
    chi2 = float(np.sum((y - (a * x + c)) ** 2 * w))  # eq. 42
    dof = int(x.size - 2)
    return LineFit(A=float(a), sigma_c2=float(c), cov=cov, chi2=chi2, dof=dof,
                   Q=goodness_of_fit(chi2, dof))


# --------------------------------------------------------------------------------------------
# the exclusion rules
# --------------------------------------------------------------------------------------------
def data_reason(p: PtcPoint, bits: int | None) -> tuple[str, str] | None:
    """Why the data of a level cannot be used (clipping, zero variance): (code, text), or None."""
    if p.clipped_fraction > CLIP_LIMIT:
        top = f"{2 ** bits - 1}" if bits is not None else "full scale"
        return "clipped", (f"clipped: {100 * p.clipped_fraction:.3g}% of the ROI pixel values at "
                           f"0 or {top} (limit {100 * CLIP_LIMIT:g}%)")
    if not (p.var > 0 and math.isfinite(p.var)):
        return "zero-variance", "zero variance: the frames of the pair are identical"
    return None


def _light_quantity(points: Sequence[PtcPoint]) -> tuple[str, np.ndarray] | None:
    """The known light level per point: photons when all have them, else the exposure time when
    every level has its own, else None."""
    if all(p.photons is not None and p.photons > 0 for p in points):
        return "photons", np.array([p.photons for p in points], dtype=np.float64)
    exps = [p.exposure for p in points]
    if all(e is not None and e > 0 for e in exps) and len(
            {round(math.log(e), 9) for e in exps}) == len(exps):
        return "exposure", np.array(exps, dtype=np.float64)
    return None


def saturation_reasons(points: Sequence[PtcPoint], tol: float) -> dict[int, tuple[str, str]]:
    """Levels past saturation: the saturation point is the level of largest σ̂²_N (the EMVA 1288
    convention: the photon-transfer curve turns down there); a level of higher μ̂ whose σ̂²_N is
    below that peak by more than :data:`LINEARITY_Z` combined standard errors and by more than
    ``tol`` (relative) is beyond it."""
    out: dict[int, str] = {}
    if len(points) < 2:
        return out
    peak = max(points, key=lambda p: p.var)
    for p in points:
        if p.mu <= peak.mu:
            continue
        drop = peak.var - p.var
        z = drop / math.hypot(peak.var_err, p.var_err)
        if z > LINEARITY_Z and drop > tol * peak.var:
            out[p.level] = "saturation", (
                f"beyond the linear range (saturation): variance {p.var:.4g} DN² is "
                f"{100 * drop / peak.var:.3g}% ({z:.0f} sigma) below the peak "
                f"{peak.var:.4g} DN² of level {peak.level} at a lower mean")
    return out


def range_reasons(points: Sequence[PtcPoint], reasons: dict[int, tuple[str, str]],
                  fraction: float) -> dict[int, tuple[str, str]]:
    """Levels above ``fraction`` of the saturation signal (the EMVA 1288 fit range, release 3.1
    sec. 6.6): the saturation point is the level of largest σ̂²_N among the measured ones (the
    standard's rule, as :func:`saturation_reasons`), its signal μ̂ − b₀ the saturation signal;
    a level not excluded already whose signal is above ``fraction`` of it is out of range."""
    out: dict[int, tuple[str, str]] = {}
    if not points:
        return out
    peak = max(points, key=lambda p: p.var)
    limit = fraction * peak.mu
    for p in points:
        if p.level not in reasons and p.mu > limit:
            out[p.level] = "range", (
                f"outside the EMVA 1288 fit range: mean {p.mu:.4g} DN is above "
                f"{100 * fraction:g} % of the saturation signal {peak.mu:.4g} DN (level "
                f"{peak.level}, the largest variance)")
    return out


def linearity_reasons(points: Sequence[PtcPoint], tol: float) -> dict[int, tuple[str, str]]:
    """Levels beyond the linear range (see the docstring of :mod:`ccdcore.noise`),
    level -> (code, reason)."""
    out: dict[int, tuple[str, str]] = {}
    if len(points) < 3:
        return out
    light = _light_quantity(points)
    if light is not None:
        name, x = light
        order = np.argsort(x, kind="stable")
        n_fit = max(2, (len(points) + 1) // 2)
        fit_idx, test_idx = order[:n_fit], order[n_fit:]
        if len(np.unique(x[fit_idx])) < 2:
            return out
        mu = np.array([p.mu_raw for p in points])
        a, c = np.polyfit(x[fit_idx], mu[fit_idx], 1)
        unit = "photons" if name == "photons" else "exposure"
        for i in test_idx:
            signal = a * x[i]
            dev = mu[i] - (signal + c)
            if signal != 0 and abs(dev) > tol * abs(signal):
                out[points[i].level] = "nonlinear", (
                    f"beyond the linear range: mean {mu[i]:.4g} DN is {100 * dev / signal:+.3g}% "
                    f"off the line of mean against {unit} fitted on the lower "
                    f"{n_fit} levels (tolerance {100 * tol:g}%)")
        return out
    mus = np.array([p.mu for p in points])
    lo, hi = mus.min(), mus.max()
    top = mus >= lo + (1.0 - _TOP_FRACTION) * (hi - lo)
    lower = [p for p, t in zip(points, top) if not t]
    if len(lower) < 2 or len({p.mu for p in lower}) < 2:
        return out
    fit = weighted_line_fit([p.mu for p in lower], [p.var for p in lower],
                            [p.var_err ** 2 for p in lower])
    for p, t in zip(points, top):
        if not t:
            continue
        pred, pred_std = fit.predict(p.mu)
        z = (p.var - pred) / math.hypot(p.var_err, pred_std)
        rel = (p.var - pred) / pred if pred > 0 else float("inf")
        if abs(z) > LINEARITY_Z and abs(rel) > tol:
            out[p.level] = "nonlinear", (
                f"beyond the linear range: variance {p.var:.4g} DN² is {z:+.1f} sigma "
                f"({100 * rel:+.3g}%) from the line fitted on the {len(lower)} lower "
                f"levels, and its mean is in the top {100 * _TOP_FRACTION:g}% of the "
                "range (no exposure or photon counts to test linearity directly)")
    return out
