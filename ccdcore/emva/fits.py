"""The computations of the EMVA 1288 figures (:func:`ccdcore.emva.datasheet.emva_figures`), one
function per step of its Notes: the closed forms of the ``emva1288`` package's least-squares
fits, the saturation point and the fits of R and K (:func:`sensitivity`), σ_y.dark and σ_d from
the darks (:func:`dark_noise`), σ_d from the photon-transfer intercept (:func:`ptc_read_noise`),
the sensitivity threshold and the dynamic range (:func:`threshold_and_range`), the linearity
(:func:`linearity`), DSNU1288 and PRNU1288 (:func:`nonuniformity`) and the release 4.0 split
(:func:`spatial_section`).

:mod:`ccdcore.emva.datasheet` sorts the frames into points, reads them and puts these together.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .results import (DISAGREEMENT_Z, LINEARITY_RANGE, QUANTISATION_LIMIT_DN,
                           QUANTISATION_VARIANCE, SENSITIVITY_FRACTION, SIGMA2_Y_DARK_FLOOR,
                           DarkPoint, EmvaPoint, SpatialSet)
from .spatial import (NonuniformitySplit, SpatialPlots, nonuniformity_split, spatial_plots,
                           variance_split)
from ..errors import CcdError
from ..noise import PhotonTransfer
from ..session import Session

__all__ = ["same_exposure", "exposure_text", "dark_at", "Curves", "Sensitivity", "sensitivity",
           "DarkNoise", "dark_noise", "PtcReadNoise", "ptc_read_noise", "Range",
           "threshold_and_range", "linearity", "nonuniformity", "spatial_section"]


# --------------------------------------------------------------------------------------------
# fits (closed forms of the package's least-squares fits)
# --------------------------------------------------------------------------------------------
def _birge(chi2: float, dof: int) -> float:
    """√(χ²/ν) when above 1 (the scatter exceeds the stated errors: the model misfits), else 1."""
    return math.sqrt(chi2 / dof) if dof > 0 and chi2 > dof else 1.0


def _line_b0(x: np.ndarray, y: np.ndarray, var_y: np.ndarray) -> tuple[float, float]:
    """The line y = m·x through the origin by unweighted least squares (``routines.LinearB0``):
    m = Σxy/Σx², with the standard error Σx²·var_y propagated, √(Σx²var_y)/Σx², scaled by
    :func:`_birge` with ν = n − 1 when the points scatter more than their errors about the
    weighted line (with errors spanning decades the unweighted line's χ² overstated the scatter:
    over 30 simulated cameras σ_y.dark's stated error was 1.23 times its spread, now 1.00)."""
    sxx = float(np.sum(x * x))
    if not sxx > 0:
        return float("nan"), float("nan")
    m = float(np.sum(x * y) / sxx)
    err = math.sqrt(float(np.sum(x * x * var_y))) / sxx
    if np.all(var_y > 0):
        # the scatter judged about the weighted line (the unweighted line's residuals at the
        # precise points carry the noisy points' pull: see ccdcore.emva.dark)
        w = 1.0 / var_y
        mw = float(np.sum(w * x * y) / np.sum(w * x * x))
        chi2 = float(np.sum(w * (y - mw * x) ** 2))
        err *= _birge(chi2, x.size - 1)
    return m, err


def _line_b_intercept(x: np.ndarray, y: np.ndarray, var_y: np.ndarray
                      ) -> tuple[float, float, float]:
    """Slope, intercept of the unweighted least-squares line (``routines.LinearB``) and the
    intercept's standard error: b = Σcᵢyᵢ with cᵢ = 1/n − x̄(xᵢ − x̄)/Sxx, var(b) = Σcᵢ²var_yᵢ,
    scaled by :func:`_birge` with ν = n − 2 (the χ² of the weighted line, as :func:`_line_b0`)."""
    n = x.size
    xm = float(x.mean())
    sxx = float(np.sum((x - xm) ** 2))
    slope = float(np.sum((x - xm) * (y - y.mean())) / sxx)
    intercept = float(y.mean() - slope * xm)
    c = 1.0 / n - xm * (x - xm) / sxx
    err = math.sqrt(float(np.sum(c * c * var_y)))
    if np.all(var_y > 0):
        w = 1.0 / var_y                     # the scatter about the weighted line (_line_b0)
        xw = float(np.sum(w * x) / np.sum(w))
        bw = float(np.sum(w * (x - xw) * y) / np.sum(w * (x - xw) ** 2))
        aw = float(np.sum(w * (y - bw * x)) / np.sum(w))
        chi2 = float(np.sum(w * (y - (bw * x + aw)) ** 2))
        err *= _birge(chi2, n - 2)
    return slope, intercept, err


def _linearity_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """The package's linearity fit (``Results1288.linearity``): the line a·x + b minimising
    Σ((y − a·x − b)/y)², in closed form."""
    xy = np.sum(x / y)
    xy2 = np.sum(x / y ** 2)
    x2y2 = np.sum((x / y) ** 2)
    _y = np.sum(1.0 / y)
    _y2 = np.sum(1.0 / y ** 2)
    b = ((xy * xy2) - (x2y2 * _y)) / ((xy2 ** 2) - (x2y2 * _y2))
    a = (xy - (b * xy2)) / x2y2
    return float(a), float(b)


def _saturation_index(s2_y: np.ndarray) -> int:
    """The package's saturation point (``Results1288.index_u_ysat``): walking back from the
    last point, the largest σ²_y before two consecutive points fall below it."""
    max_, max_i = 0.0, 0
    for i in range(len(s2_y) - 1, -1, -1):
        if s2_y[i] >= max_ or s2_y[abs(i - 1)] >= max_:
            max_, max_i = s2_y[i], i
        elif s2_y[i] < max_ and s2_y[abs(i - 1)] < max_:
            break
    return int(max_i)


# --------------------------------------------------------------------------------------------
# the session's points
# --------------------------------------------------------------------------------------------
def same_exposure(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return a is b
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-15)


def exposure_text(t: float | None) -> str:
    return "unknown exposure" if t is None else f"exposure {t:g} s"


def dark_at(dark_points: Sequence[DarkPoint], t: float | None) -> DarkPoint:
    return next(d for d in dark_points if same_exposure(d.exposure, t))


# --------------------------------------------------------------------------------------------
# the figures
# --------------------------------------------------------------------------------------------
def _nan() -> float:
    return float("nan")


@dataclass(frozen=True)
class Curves:
    """The bright points as arrays: μ_p, Y = μ_y − μ_y.dark, S = σ²_y − σ²_y.dark, their
    variances, and σ²_y."""

    u_p: np.ndarray
    Y: np.ndarray
    var_Y: np.ndarray
    S: np.ndarray
    var_S: np.ndarray
    s2_y: np.ndarray

    @classmethod
    def of(cls, raw: Sequence[EmvaPoint], dark_points: Sequence[DarkPoint]) -> "Curves":
        return cls(
            u_p=np.array([p.u_p for p in raw]),
            Y=np.array([p.u_y - p.u_y_dark for p in raw]),
            var_Y=np.array([p.u_y_err ** 2 + dark_at(dark_points, p.exposure).u_y_dark_err ** 2
                            for p in raw]),
            S=np.array([p.s2_y - p.s2_y_dark for p in raw]),
            var_S=np.array([p.s2_y_err ** 2 + p.s2_y_dark_err ** 2 for p in raw]),
            s2_y=np.array([p.s2_y for p in raw]))


@dataclass(frozen=True)
class Sensitivity:
    i_sat: int
    i_fit: int
    R: float
    R_err: float
    K: float
    K_err: float
    QE: float
    QE_err: float


def sensitivity(c: Curves, raw: Sequence[EmvaPoint], label: str, notes: list[str]
                ) -> Sensitivity:
    """The saturation point, the fit range and the fits of R and K (sec. 6.6), QE = R/K."""
    Y = c.Y
    i_sat = _saturation_index(c.s2_y)
    i_peak = int(np.argmax(c.s2_y))
    if c.s2_y[i_peak] > c.s2_y[i_sat]:
        notes.append(f"the saturation point is taken as the package does (its backward search "
                     f"stops at ptc level {raw[i_sat].level}, mu_y - mu_y.dark = "
                     f"{Y[i_sat]:.4g} DN), but the largest variance is at ptc level "
                     f"{raw[i_peak].level} ({Y[i_peak]:.4g} DN): the "
                     "search stopped on the plateau after saturation, and the figures that "
                     "use the saturation point (the fit range, mu_p.sat, mu_e.sat, SNR_max, "
                     "DR, linearity) are those of that point")
    below = np.flatnonzero(Y <= SENSITIVITY_FRACTION * Y[i_sat])
    if Y[i_sat] <= 0 or below.size == 0:
        raise CcdError(label, f"every bright point is saturated or dark: no point has a signal "
                              f"mu_y - mu_y.dark below {100 * SENSITIVITY_FRACTION:g} % of the "
                              f"saturation point's {Y[i_sat]:.4g} DN (ptc level "
                              f"{raw[i_sat].level}); capture points from dark to saturation")
    i_fit = int(below.max())
    fit = slice(0, i_fit + 1)
    if i_fit + 1 < 2:
        raise CcdError(label, f"only {i_fit + 1} bright point below "
                              f"{100 * SENSITIVITY_FRACTION:g} % of saturation (ptc level "
                              f"{raw[i_sat].level} at {Y[i_sat]:.4g} DN): the fits of R and K need "
                              "at least 2; capture more points below saturation")
    R, R_err = _line_b0(c.u_p[fit], Y[fit], c.var_Y[fit])
    K, K_err = _line_b0(Y[fit], c.S[fit], c.var_S[fit])
    if not (K > 0 and R > 0):
        raise CcdError(label, f"the fitted system gain K = {K:.4g} DN/e- or responsivity "
                              f"R = {R:.4g} DN/p is not positive: check the dark subtraction "
                              "and the photon counts")
    QE = 100.0 * R / K
    return Sensitivity(i_sat, i_fit, R, R_err, K, K_err, QE,
                       QE * math.hypot(R_err / R, K_err / K))


@dataclass(frozen=True)
class DarkNoise:
    sigma_y_dark: float
    sigma_y_dark_err: float
    sigma_y_dark_measured: float
    u_dark: float
    u_dark_err: float
    sigma_d: float
    sigma_d_err: float
    quantisation_limited: bool


def dark_noise(dark_points: Sequence[DarkPoint], sens: Sensitivity, notes: list[str]
               ) -> DarkNoise:
    """σ_y.dark (floored as the package does), μ_y.dark and σ_d from the darks (sec. 2.2, 3)."""
    K, K_err = sens.K, sens.K_err
    (s2_dark, s2_dark_err), (u_dark, u_dark_err), dark_rule = _dark_level(dark_points)
    sigma_y_dark_measured = math.sqrt(s2_dark) if s2_dark > 0 else 0.0
    if s2_dark < SIGMA2_Y_DARK_FLOOR:
        notes.append(f"sigma2_y.dark = {s2_dark:.4g} DN² ({dark_rule}) is below "
                     f"{SIGMA2_Y_DARK_FLOOR:g} DN²: floored there as the package does, so "
                     "sigma_y.dark, sigma_d and mu_p.min are upper bounds without an error")
        s2_used, s2_used_err = SIGMA2_Y_DARK_FLOOR, _nan()
    else:
        s2_used, s2_used_err = s2_dark, s2_dark_err
    sigma_y_dark = math.sqrt(s2_used)
    excess = s2_used - QUANTISATION_VARIANCE
    sigma_d = math.sqrt(excess) / K if excess > 0 else _nan()
    if excess > 0:
        sigma_d_err = math.hypot(s2_used_err / (2.0 * K * math.sqrt(excess)), sigma_d * K_err / K)
    else:
        sigma_d_err = _nan()
    quantisation_limited = sigma_y_dark_measured < QUANTISATION_LIMIT_DN
    if quantisation_limited:
        notes.append(f"the temporal dark noise sigma_y.dark = {sigma_y_dark_measured:.3g} DN is "
                     f"below {QUANTISATION_LIMIT_DN:g} DN: at this level the rounding of the "
                     "ADC (quantisation noise, 1/12 DN²) dominates it, so the read noise sigma_d "
                     "is poorly determined, and the value from the darks and the one from the "
                     "photon-transfer intercept can differ by a factor of two; a higher gain "
                     "setting would measure it")
    return DarkNoise(sigma_y_dark, s2_used_err / (2.0 * sigma_y_dark), sigma_y_dark_measured,
                     u_dark, u_dark_err, sigma_d, sigma_d_err, quantisation_limited)


@dataclass(frozen=True)
class PtcReadNoise:
    sigma_d: float | None = None
    sigma_d_err: float | None = None
    K: float | None = None
    K_err: float | None = None
    consistent: bool | None = None


def ptc_read_noise(session: Session | None, noise: PhotonTransfer | None, with_ptc: bool,
                   dark: DarkNoise, notes: list[str]) -> PtcReadNoise:
    """σ_d from the intercept of our photon-transfer line (Healey & Kondepudy eq. 27), and
    whether it agrees with σ_d from the darks within :data:`DISAGREEMENT_Z` standard errors."""
    if noise is None and with_ptc:
        from ..noise import photon_transfer

        try:
            noise = photon_transfer(session)
        except CcdError as exc:
            notes.append(f"sigma_d from photon transfer is not available: {exc.problem}")
    if noise is None:
        return PtcReadNoise()
    K_ptc, K_ptc_err = float(noise.A), float(noise.A_err)
    if not math.isfinite(noise.read_noise_e):
        notes.append("sigma_d from photon transfer is not resolved (its intercept "
                     "sigma_c2 is not above q²/12)")
        return PtcReadNoise(K=K_ptc, K_err=K_ptc_err)
    s_ptc, s_ptc_err = float(noise.read_noise_e), float(noise.read_noise_e_err)
    consistent: bool | None = None
    both = math.hypot(dark.sigma_d_err, s_ptc_err)
    if math.isfinite(dark.sigma_d) and math.isfinite(both) and both > 0:
        z = abs(dark.sigma_d - s_ptc) / both
        consistent = z <= DISAGREEMENT_Z
        if not consistent:
            notes.append(
                f"sigma_d from the darks ({dark.sigma_d:.4g} ± {dark.sigma_d_err:.2g} e-) and "
                f"from the photon-transfer intercept ({s_ptc:.4g} ± {s_ptc_err:.2g} e-) "
                f"disagree by {z:.1f} standard errors"
                + (" (quantisation dominates the dark noise)"
                   if dark.quantisation_limited else ""))
    return PtcReadNoise(s_ptc, s_ptc_err, K_ptc, K_ptc_err, consistent)


@dataclass(frozen=True)
class Range:
    u_p_min: float
    u_p_min_err: float
    u_p_sat: float
    u_p_sat_err: float
    u_e_sat: float
    u_e_sat_err: float
    SNR_max: float
    SNR_max_err: float
    DR: float
    DR_err: float
    DR_dB: float
    DR_dB_err: float


def threshold_and_range(u_p: np.ndarray, sens: Sensitivity, dark: DarkNoise) -> Range:
    """The absolute sensitivity threshold, the saturation capacity, SNR_max and the dynamic
    range (sec. 2.4; eqs. 18, 33), with first-order errors."""
    R, R_err, K, K_err, QE = sens.R, sens.R_err, sens.K, sens.K_err, sens.QE
    eta = QE / 100.0
    u_p_min = (100.0 / QE) * (dark.sigma_y_dark / K + 0.5)          # = (σ_y.dark + K/2)/R
    u_p_min_err = math.sqrt((dark.sigma_y_dark_err / R) ** 2 + (K_err / (2.0 * R)) ** 2
                            + (u_p_min * R_err / R) ** 2)
    i_sat = sens.i_sat
    u_p_sat = float(u_p[i_sat])
    # the saturation point is one of the grid's points: the resolution of the series, the
    # local spacing over √12 (a uniform spread between the neighbours' midpoints)
    lo_i, hi_i = max(i_sat - 1, 0), min(i_sat + 1, len(u_p) - 1)
    u_p_sat_err = abs(float(u_p[hi_i] - u_p[lo_i])) / max(hi_i - lo_i, 1) / math.sqrt(12.0)
    u_e_sat = eta * u_p_sat
    u_e_sat_err = math.hypot(u_p_sat * sens.QE_err / 100.0, eta * u_p_sat_err)
    SNR_max = math.sqrt(u_e_sat)
    DR = u_p_sat / u_p_min
    DR_err = DR * math.hypot(u_p_min_err / u_p_min, u_p_sat_err / u_p_sat)
    return Range(u_p_min, u_p_min_err, u_p_sat, u_p_sat_err, u_e_sat, u_e_sat_err, SNR_max,
                 u_e_sat_err / (2.0 * SNR_max), DR, DR_err, 20.0 * math.log10(DR),
                 20.0 / math.log(10.0) * DR_err / DR)


def _dark_level(dark_points: Sequence[DarkPoint]
                ) -> tuple[tuple[float, float], tuple[float, float], str]:
    """(σ²_y.dark, error), (μ_y.dark, error) and how they were found (``Results1288.
    sigma_y_dark``): the dark point of the shortest exposure when there are at most two
    exposure times (or one is unknown), else the intercepts of the unweighted lines against the
    exposure time (``LinearB``)."""
    if len({d.exposure for d in dark_points}) <= 2 or any(d.exposure is None
                                                          for d in dark_points):
        first = dark_points[0]          # the shortest exposure (points are sorted)
        return ((first.s2_y_dark, first.s2_y_dark_err), (first.u_y_dark, first.u_y_dark_err),
                f"the dark point at {exposure_text(first.exposure)}")
    x = np.array([d.exposure for d in dark_points], dtype=np.float64)
    _, s2, s2_err = _line_b_intercept(x, np.array([d.s2_y_dark for d in dark_points]),
                                      np.array([d.s2_y_dark_err ** 2 for d in dark_points]))
    _, u, u_err = _line_b_intercept(x, np.array([d.u_y_dark for d in dark_points]),
                                    np.array([d.u_y_dark_err ** 2 for d in dark_points]))
    return ((s2, s2_err), (u, u_err),
            f"extrapolated to zero exposure from {len(dark_points)} exposure times")


def linearity(u_p: np.ndarray, Y: np.ndarray, var_Y: np.ndarray, i_sat: int, label: str
              ) -> tuple[int, int, float, float, tuple[float, float], tuple[float, float]]:
    """The linearity of sec. 6.7 as ``Results1288.linearity``: the fit range (first, last
    index), the fit's slope and offset, (LE_min, its error), (LE_max, its error)."""
    lo = np.flatnonzero(Y >= LINEARITY_RANGE[0] * Y[i_sat])
    hi = np.flatnonzero(Y <= LINEARITY_RANGE[1] * Y[i_sat])
    first, last = int(lo.min()), int(hi.max())
    if last - first + 1 < 2:
        raise CcdError(label, f"{max(last - first + 1, 0)} bright point(s) between "
                              f"{100 * LINEARITY_RANGE[0]:g} and {100 * LINEARITY_RANGE[1]:g} % of "
                              "saturation: the linearity fit needs at least 2")
    lin = slice(first, last + 1)

    def deviations(y: np.ndarray) -> tuple[np.ndarray, float, float]:
        a, b = _linearity_fit(u_p[lin], y[lin])
        fitted = a * u_p[lin] + b
        return 100.0 * (y[lin] - fitted) / fitted, a, b

    dev, a, b = deviations(Y)
    k_min, k_max = int(np.argmin(dev)), int(np.argmax(dev))
    # first-order propagation of the Y errors: central differences of the closed-form fit
    jac = np.zeros((dev.size, Y.size))
    for j in range(first, last + 1):
        h = 1e-6 * max(abs(Y[j]), 1.0)
        up, down = Y.copy(), Y.copy()
        up[j] += h
        down[j] -= h
        jac[:, j] = (deviations(up)[0] - deviations(down)[0]) / (2.0 * h)
    dev_err = np.sqrt((jac * jac) @ var_Y)
    return (first, last, a, b, (float(dev[k_min]), float(dev_err[k_min])),
            (float(dev[k_max]), float(dev_err[k_max])))


def nonuniformity(sp: SpatialSet, spd: SpatialSet, K: float, K_err: float, notes: list[str]
                  ) -> tuple[float, float, float, float]:
    """DSNU1288, its error, PRNU1288, its error (sec. 4.1, 8; NaN where a variance is negative,
    with a note)."""
    if spd.s2 >= 0:
        dsnu = math.sqrt(spd.s2) / K
        dsnu_err = (dsnu * math.hypot(spd.s2_err / (2.0 * spd.s2), K_err / K)
                    if spd.s2 > 0 else _nan())
    else:
        dsnu = dsnu_err = _nan()
        notes.append(f"the dark spatial variance s2_y.dark = {spd.s2:.4g} DN² is negative "
                     "(no measurable DSNU): DSNU1288 is not a number")
    diff = sp.s2 - spd.s2
    signal = sp.u_y - spd.u_y
    if diff >= 0 and signal > 0:
        prnu = 100.0 * math.sqrt(diff) / signal
        signal_err = math.sqrt(sp.s2_stack / (sp.L * sp.n_pixels)
                               + spd.s2_stack / (spd.L * spd.n_pixels))
        prnu_err = (prnu * math.hypot(math.hypot(sp.s2_err, spd.s2_err) / (2.0 * diff),
                                      signal_err / signal) if diff > 0 else _nan())
    else:
        prnu = prnu_err = _nan()
        notes.append(f"the bright spatial variance does not exceed the dark one "
                     f"({sp.s2:.4g} vs {spd.s2:.4g} DN²): PRNU1288 is not a number")
    return dsnu, dsnu_err, prnu, prnu_err


def spatial_section(sp: SpatialSet, spd: SpatialSet, K: float, K_err: float,
                    dsnu: float | None, prnu: float | None, notes: list[str]
                    ) -> tuple[NonuniformitySplit | None, SpatialPlots | None]:
    """The release 4.0 split of DSNU and PRNU and the arrays of sec. 8's plots, from the
    average images of the spatial sets (:mod:`ccdcore.emva.spatial`)."""
    if sp.image is None or spd.image is None:
        return None, None
    if sp.image.shape != spd.image.shape or min(sp.image.shape) < 2 * 5:
        notes.append(f"the spatial sets' images ({sp.image.shape}, {spd.image.shape}) are too "
                     "small or differ: no row/column/pixel split and no spatial plots")
        return None, None
    split = nonuniformity_split(variance_split(sp.image, sp.s2_stack, sp.L),
                                variance_split(spd.image, spd.s2_stack, spd.L), K, K_err)
    notes.extend(split.notes)
    finite = (lambda v: v if v is not None and math.isfinite(v) else None)
    plots = spatial_plots(sp.image, spd.image, L=sp.L, L_dark=spd.L, s2_stack=sp.s2_stack,
                          s2_stack_dark=spd.s2_stack, K=K, DSNU1288=finite(dsnu),
                          PRNU1288=finite(prnu))
    return split, plots
