"""Edge and error-formula pins of the photon-transfer fit and its exclusion rules
(:mod:`ccdcore.ptc_fit`), the pair and stack statistics (:mod:`ccdcore.stats`), the EMVA 1288
dark current (:mod:`ccdcore.emva.dark`), the spatial variance split, DSNU/PRNU parts and plot
arrays (:mod:`ccdcore.emva.spatial`), the fixed-pattern correction check
(:mod:`ccdcore.fixedpattern`), the datasheet's frame statistics (:mod:`ccdcore.emva.datasheet`),
the SNR curve (:mod:`ccdcore.emva.results`) and the plot needs of
:mod:`ccdcore.emva.datasheet_files`.

Every expectation is derived independently: numpy's generalised least squares on the same data,
the formulas of the docstrings written out by hand, a Monte-Carlo scatter with a fixed seed, or
hand arithmetic on small inputs.  The inputs avoid the values that hide bugs (K = 1, square
images, L = L_dark, equal errors, bin width 1) and reach the boundaries the rules name (exactly
at a limit, exactly the minimum size, +inf as well as NaN).
"""
from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats as sstats

from ccdcore.emva import dark as edark
from ccdcore.emva import datasheet as eds
from ccdcore.emva import spatial as esp
from ccdcore.errors import CcdError
from ccdcore import fixedpattern as fp
from ccdcore import ptc_fit as pf
from ccdcore import stats as cst


# --------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------
def _pt(level: int, mu: float, var: float, var_err: float = 1.0, *, exposure: float | None = None,
        photons: float | None = None, mu_raw: float | None = None,
        clipped: float = 0.0) -> pf.PtcPoint:
    """A photon-transfer level with the given numbers (mu_raw defaults to mu)."""
    return pf.PtcPoint(level=level, mu=mu, var=var, var_err=var_err, n_pairs=1, n_pixels=100,
                       used=True, reason=None, exposure=exposure,
                       mu_raw=mu if mu_raw is None else mu_raw, clipped_fraction=clipped,
                       photons=photons)


def _gls(x: np.ndarray, y: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Weighted least squares by the normal equations: (slope, intercept), covariance, χ²."""
    X = np.column_stack([x, np.ones_like(x)])
    W = np.diag(1.0 / v)
    cov = np.linalg.inv(X.T @ W @ X)
    beta = cov @ X.T @ W @ y
    r = y - X @ beta
    return beta, cov, float(r @ W @ r)


# --------------------------------------------------------------------------------------------
# ptc_fit: the weighted line (eqs. 59-67)
# --------------------------------------------------------------------------------------------
def test_weighted_line_matches_generalised_least_squares() -> None:
    """Â, σ̂²_C, their covariance (eq. 66), χ², ν = P − 2 and Q = χ²-survival (eq. 67) equal the
    normal-equation solution of the same weighted problem (numpy, unequal weights, scatter)."""
    x = np.array([10.0, 40.0, 90.0, 160.0, 250.0])
    y = np.array([7.1, 18.9, 41.0, 70.2, 108.5])
    v = np.array([0.04, 0.3, 1.1, 2.5, 9.0])
    fit = pf.weighted_line_fit(x, y, v)
    beta, cov, chi2 = _gls(x, y, v)
    assert fit.A == pytest.approx(beta[0], rel=1e-10)
    assert fit.sigma_c2 == pytest.approx(beta[1], rel=1e-10)
    np.testing.assert_allclose(fit.cov, cov, rtol=1e-9)
    assert fit.chi2 == pytest.approx(chi2, rel=1e-9)
    assert fit.dof == 3
    assert fit.Q == pytest.approx(sstats.chi2.sf(chi2, 3), rel=1e-9)
    value, std = fit.predict(120.0)
    g = np.array([120.0, 1.0])
    assert isinstance(value, float) and isinstance(std, float)
    assert value == pytest.approx(beta[0] * 120.0 + beta[1], rel=1e-10)
    assert std == pytest.approx(math.sqrt(g @ cov @ g), rel=1e-9)
    vals, stds = fit.predict([0.0, 300.0])
    assert stds[0] == pytest.approx(math.sqrt(cov[1, 1]), rel=1e-9)
    assert vals[1] == pytest.approx(300.0 * beta[0] + beta[1], rel=1e-10)


def test_weighted_line_two_points_and_refusals() -> None:
    """Exactly P = 2 is accepted (ν = 0, χ² = 0, Q NaN); one point, unequal lengths, a zero or
    infinite weight, a non-finite μ or σ² and all-equal μ are refused (the docstring's Raises)."""
    fit = pf.weighted_line_fit([1.0, 3.0], [2.0, 6.0], [0.5, 2.0])
    assert fit.dof == 0 and fit.chi2 == pytest.approx(0.0, abs=1e-20) and math.isnan(fit.Q)
    assert fit.A == pytest.approx(2.0) and fit.sigma_c2 == pytest.approx(0.0, abs=1e-12)
    bad = [([1.0], [1.0], [1.0]), ([1.0, 2.0], [1.0, 2.0], [1.0]),
           ([1.0, 2.0], [1.0, 2.0], [1.0, 0.0]), ([1.0, 2.0], [1.0, 2.0], [1.0, math.inf]),
           ([1.0, math.inf], [1.0, 2.0], [1.0, 1.0]), ([1.0, 2.0], [math.nan, 2.0], [1.0, 1.0]),
           ([1.0, 2.0], [1.0, -math.inf], [1.0, 1.0]), ([5.0, 5.0, 5.0], [1, 2, 3], [1, 1, 1])]
    for x, y, v in bad:
        with pytest.raises(CcdError):
            pf.weighted_line_fit(x, y, v)


def test_goodness_of_fit_paper_value_and_no_dof() -> None:
    """Q(4.3496 | 4) = 0.3607 (the paper's fit, eq. 67); ν = 0 gives NaN, ν = 1 a number."""
    assert pf.goodness_of_fit(4.3496, 4) == pytest.approx(0.3607, abs=1e-4)
    assert math.isnan(pf.goodness_of_fit(1.0, 0))
    assert pf.goodness_of_fit(1.0, 1) == pytest.approx(sstats.chi2.sf(1.0, 1))


# --------------------------------------------------------------------------------------------
# ptc_fit: the exclusion rules
# --------------------------------------------------------------------------------------------
def test_data_reason_boundaries() -> None:
    """A clipped fraction exactly at CLIP_LIMIT is kept, just above it is clipped (naming
    2^bits − 1); zero, NaN and +inf variance are zero-variance."""
    assert pf.data_reason(_pt(1, 10.0, 5.0, clipped=pf.CLIP_LIMIT), 12) is None
    code, text = pf.data_reason(_pt(1, 10.0, 5.0, clipped=pf.CLIP_LIMIT * 1.01), 12)
    assert code == "clipped" and "4095" in text
    assert pf.data_reason(_pt(1, 10.0, 5.0, clipped=1.5e-4), 12)[0] == "clipped"   # 10⁻⁴ (doc)
    code, text = pf.data_reason(_pt(1, 10.0, 5.0, clipped=0.5), None)
    assert code == "clipped" and "full scale" in text
    for var in (0.0, math.nan, math.inf, -1.0):
        assert pf.data_reason(_pt(1, 10.0, var), 12)[0] == "zero-variance"


def test_saturation_needs_both_sigma_and_tolerance() -> None:
    """A level above the peak's mean is beyond saturation only when its variance is below the
    peak by more than LINEARITY_Z combined errors (hypot of both) and more than tol (relative);
    a level at the peak's own mean is never tested; one level gives nothing."""
    assert pf.saturation_reasons([_pt(1, 10.0, 100.0)], 0.05) == {}
    peak = _pt(1, 100.0, 100.0, var_err=0.6)
    # drop 6: tol 5 % passes; z = 6/hypot(0.6, 0.8) = 6.0 > 5 -> excluded
    out = pf.saturation_reasons([peak, _pt(2, 120.0, 94.0, 0.8)], 0.05)
    assert set(out) == {2} and out[2][0] == "saturation"
    # z with the peak's error alone would be 10, with hypot(0.6, 1.0) it is 5.14; 1.1 -> 4.7
    assert pf.saturation_reasons([peak, _pt(2, 120.0, 94.0, 1.1)], 0.05) == {}
    # 6 sigma but a drop of 6 % under a tolerance of 6.5 %
    assert pf.saturation_reasons([peak, _pt(2, 120.0, 94.0, 0.8)], 0.065) == {}
    # the same mean as the peak: skipped; a lower mean: skipped
    assert pf.saturation_reasons([peak, _pt(2, 100.0, 50.0, 0.1)], 0.05) == {}
    assert pf.saturation_reasons([peak, _pt(2, 90.0, 50.0, 0.1)], 0.05) == {}


def test_range_reasons_limit_is_exclusive_and_uses_peak_variance() -> None:
    """Levels above fraction·μ(peak of σ²) are out of range; one exactly at the limit stays; the
    peak is the largest variance (not the largest mean); levels already excluded are skipped."""
    pts = [_pt(1, 20.0, 10.0), _pt(2, 50.0, 25.0), _pt(3, 60.0, 30.0), _pt(4, 100.0, 50.0),
           _pt(5, 130.0, 40.0)]
    out = pf.range_reasons(pts, {}, 0.5)
    assert set(out) == {3, 4, 5}
    assert pf.range_reasons(pts, {5: ("saturation", "x")}, 0.5).keys() == {3, 4}
    assert pf.range_reasons([], {}, 0.5) == {}


def test_linearity_needs_three_levels() -> None:
    """Fewer than three levels are never tested for linearity (two wildly off still kept)."""
    pts = [_pt(1, 10.0, 5.0, exposure=1.0), _pt(2, 500.0, 1.0, exposure=2.0)]
    assert pf.linearity_reasons(pts, 0.05) == {}


def test_linearity_by_exposure_fits_the_lower_half() -> None:
    """With an exposure per level the line of μ_raw against t is fitted on the lower
    max(2, ⌈P/2⌉) levels and a higher level is beyond the linear range when |μ − line| exceeds
    tol·(slope·t) (the signal without its offset): numpy's polyfit on the same points."""
    t = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    mu = np.array([510.0, 610.0, 730.0, 0.0, 0.0])   # level 3 off the line of 1-2 by 6.7 %
    a, c = np.polyfit(t[:3], mu[:3], 1)
    mu[3] = a * 4 + c + 0.05 * a * 4 * 1.03        # 3 % over the tolerance of the signal
    mu[4] = a * 5 + c - 0.05 * a * 5 * 0.97        # under it, and negative
    pts = [_pt(i + 1, m, 1.0, exposure=float(e), mu_raw=m) for i, (e, m) in enumerate(zip(t, mu))]
    out = pf.linearity_reasons(pts, 0.05)
    assert set(out) == {4} and out[4][0] == "nonlinear"
    mu[4] = a * 5 + c - 0.05 * a * 5 * 1.02
    pts[4] = _pt(5, mu[4], 1.0, exposure=5.0, mu_raw=mu[4])
    assert set(pf.linearity_reasons(pts, 0.05)) == {4, 5}
    # tolerance against the signal a·t, not against a·t + c (c = 0 would hide it)
    assert c > 300.0


def test_linearity_prefers_photons_over_exposure() -> None:
    """When every level has photons, μ_raw is tested against photons, not exposure."""
    ph = np.array([100.0, 200.0, 300.0, 400.0])
    ex = np.array([1.0, 2.0, 3.0, 8.0])              # exposure of level 4 is inconsistent
    pts = [_pt(i + 1, 2.0 * p, 1.0, exposure=float(e), photons=float(p))
           for i, (p, e) in enumerate(zip(ph, ex))]
    assert pf.linearity_reasons(pts, 0.05) == {}
    no_ph = [_pt(p.level, p.mu, 1.0, exposure=p.exposure) for p in pts]
    assert set(pf.linearity_reasons(no_ph, 0.05)) == {4}


def test_linearity_by_variance_top_tenth_boundary() -> None:
    """Without light counts the lower levels' weighted line predicts the variance of the top
    10 % of the μ range (μ ≥ lo + 0.9·(hi − lo), the boundary included); a level there is
    excluded when off by > LINEARITY_Z combined errors and > tol."""
    mus = [0.0, 20.0, 40.0, 60.0, 80.0, 90.0, 100.0]
    var = [10.0 + 0.5 * m for m in mus]
    var[5] = 0.7 * var[5]            # μ = 90, exactly at the boundary: tested
    var[6] = 0.98 * var[6]           # 2 % off, many sigma: under tol
    pts = [_pt(i + 1, m, v, var_err=0.05) for i, (m, v) in enumerate(zip(mus, var))]
    out = pf.linearity_reasons(pts, 0.05)
    assert set(out) == {6}
    pts[6] = _pt(7, 100.0, 60.0 * 0.9, var_err=0.05)
    assert set(pf.linearity_reasons(pts, 0.05)) == {6, 7}


# --------------------------------------------------------------------------------------------
# stats
# --------------------------------------------------------------------------------------------
def test_pair_statistics_against_numpy() -> None:
    """μ̂ = mean of both frames (eq. 37), σ̂²_N = var(D₁ − D₂, ddof 1)/2 (eq. 38) and
    var[σ̂²_N] = 2σ̂⁴/(M − 1) (eq. 40) on a non-square pair with an offset between frames."""
    rng = np.random.default_rng(7)
    a = rng.normal(100.0, 3.0, (3, 5))
    b = rng.normal(90.0, 3.0, (3, 5))
    mu, var, vv, m = cst.pair_statistics(a, b)
    ref = np.var(a - b, ddof=1) / 2.0
    assert m == 15
    assert mu == pytest.approx((a.mean() + b.mean()) / 2.0, rel=1e-12)
    assert var == pytest.approx(ref, rel=1e-12)
    assert vv == pytest.approx(2.0 * ref ** 2 / 14.0, rel=1e-12)
    mu2, var2, vv2, m2 = cst.pair_statistics([1.0, 4.0], [0.0, 1.0])   # exactly two pixels
    assert (mu2, var2, vv2, m2) == (1.5, 1.0, 2.0, 2)
    for a1, b1 in (([1.0], [2.0]), ([1.0, 2.0], [1.0, 2.0, 3.0])):
        with pytest.raises(CcdError):
            cst.pair_statistics(a1, b1)


def test_pixel_moments_mean_var_sem() -> None:
    """Streamed mean and ddof-1 variance equal numpy's; sem = √(var/n); one frame gives NaN
    variance and no mean variance; in-place result empties the accumulator; bad inputs raise."""
    rng = np.random.default_rng(3)
    frames = rng.integers(0, 4000, (4, 2, 3)).astype(np.uint16)
    r = cst.pixel_moments(iter(frames))
    np.testing.assert_allclose(r.mean, frames.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(r.var, frames.astype(float).var(axis=0, ddof=1), rtol=1e-9)
    np.testing.assert_allclose(r.sem, np.sqrt(frames.astype(float).var(axis=0, ddof=1) / 4))
    assert r.n == 4 and r.to_dict()["mean_of_var"] == pytest.approx(float(r.var.mean()))
    one = cst.pixel_moments([np.array([[1.0, 2.0]])])
    assert np.all(np.isnan(one.var)) and one.to_dict()["mean_of_var"] is None
    acc = cst.PixelMoments()
    acc.add(np.array([True, False]))
    acc.add(np.array([True, True]))
    res = acc.result(in_place=True)
    np.testing.assert_allclose(res.var, [0.0, 0.5])
    assert acc.n == 0
    with pytest.raises(CcdError):
        acc.result()
    acc.add(np.zeros((2, 2)))
    for bad in (np.zeros((2, 3)), np.zeros((2, 2), complex)):
        with pytest.raises(CcdError):
            acc.add(bad)
    with pytest.raises(CcdError):
        cst.PixelMoments().add(np.zeros((0, 3)))


def test_linearity_zero_photons_fall_back_to_exposure() -> None:
    """A level with zero photons is not a light count: the rule falls back to exposure times
    (the photons would show the levels linear, the exposures show level 4 off)."""
    ph = [0.0, 100.0, 200.0, 300.0]
    ex = [1.0, 2.0, 3.0, 8.0]
    pts = [_pt(i + 1, 2.0 * p + 5.0, 1.0, exposure=e, photons=p) for i, (p, e) in
           enumerate(zip(ph, ex))]
    assert set(pf.linearity_reasons(pts, 0.05)) == {4}


# --------------------------------------------------------------------------------------------
# emva.dark: the dark current
# --------------------------------------------------------------------------------------------
def _ols_err(t: np.ndarray, var_y: np.ndarray) -> float:
    """√(Σ cᵢ² var_yᵢ) with cᵢ = (tᵢ − t̄)/S_tt (module docstring)."""
    c = (t - t.mean()) / np.sum((t - t.mean()) ** 2)
    return float(np.sqrt(np.sum(c * c * var_y)))


def _wchi2_dof(t: np.ndarray, y: np.ndarray, var_y: np.ndarray) -> float:
    """χ²/ν of the weighted line (numpy generalised least squares)."""
    return _gls(t, y, var_y)[2] / (t.size - 2)


def test_dark_current_lines_errors_and_K_scaling() -> None:
    """μ_I.mean = slope(μ_y.dark)/K and μ_I.var = slope(σ²_y.dark)/K² (unweighted lines); the
    errors are the propagated point errors, scaled by √(χ²/ν) of the weighted line when it is
    above 1, and K's relative error enters once for the mean and twice for the variance."""
    t = np.array([0.01, 0.02, 0.04, 0.08, 0.16])
    K, K_err = 0.4, 0.02
    mu = np.array([100.0, 100.45, 101.0, 102.4, 104.5])   # scatters more than its errors
    mu_e = np.array([0.05, 0.05, 0.1, 0.1, 0.2])
    s2 = np.array([4.05, 4.09, 4.21, 4.39, 4.81])
    s2_e = np.array([0.05, 0.05, 0.08, 0.08, 0.1])            # scatters less than its errors
    r = edark.dark_current(list(t), mu, mu_e, s2, s2_e, K, K_err)
    for line, y, e in ((r.mean_line, mu, mu_e), (r.var_line, s2, s2_e)):
        slope, off = np.polyfit(t, y, 1)
        cd = _wchi2_dof(t, y, e ** 2)
        assert line.slope == pytest.approx(slope, rel=1e-9)
        assert line.offset == pytest.approx(off, rel=1e-9)
        assert line.dof == 3 and line.chi2_dof == pytest.approx(cd, rel=1e-9)
        assert line.slope_err == pytest.approx(_ols_err(t, e ** 2) * math.sqrt(max(cd, 1.0)),
                                               rel=1e-9)
    assert r.mean_line.chi2_dof > 1.0 > r.var_line.chi2_dof
    sm, sv = r.mean_line.slope, r.var_line.slope
    assert r.u_I_mean == pytest.approx(sm / K, rel=1e-12)
    assert r.u_I_mean_err == pytest.approx(
        math.hypot(r.mean_line.slope_err / K, sm / K * K_err / K), rel=1e-9)
    assert r.u_I_var == pytest.approx(sv / K ** 2, rel=1e-12)
    assert r.u_I_var_err == pytest.approx(
        math.hypot(r.var_line.slope_err / K ** 2, sv / K ** 2 * 2 * K_err / K), rel=1e-9)
    assert r.u_I_mean_bound is None and r.u_I_var_bound is None
    assert r.mean_line.summary().q() == pytest.approx(
        sstats.chi2.sf(r.mean_line.chi2_dof * 3, 3), rel=1e-9)


def test_dark_current_three_exposures_and_unresolved_bound() -> None:
    """Exactly three exposure times give a current; two (with repeats) give none; a slope within
    RESOLVED_Z errors is not resolved and bounded by max(value, 0) + 2·(statistical error)/K,
    K's error left out; a falling slope is bounded by 2·error alone."""
    t = [1.0, 2.0, 3.0]
    e = np.array([0.5, 0.5, 0.5])
    r = edark.dark_current(t, [10.0, 10.5, 11.0], e, [3.0, 3.0, 3.0], e, 2.0, 0.1)
    err_stat = _ols_err(np.array(t), e ** 2)          # chi2/dof < 1: no scaling
    assert r.u_I_mean is None and r.u_I_mean_err is None
    assert r.u_I_mean_bound == pytest.approx(0.5 / 2.0 + 2.0 * err_stat / 2.0, rel=1e-9)
    assert r.u_I_var is None
    assert r.u_I_var_bound == pytest.approx(2.0 * err_stat / 4.0, rel=1e-9)
    r = edark.dark_current(t, [11.0, 10.5, 10.0], e, [3.0, 3.0, 3.0], e, 2.0, 0.1)
    assert r.u_I_mean_bound == pytest.approx(2.0 * err_stat / 2.0, rel=1e-9)
    assert any("falls" in n for n in r.notes)
    two = edark.dark_current([1.0, 1.0, 2.0, 2.0], [1, 1, 2, 2], [1] * 4, [1] * 4, [1] * 4,
                             2.0, 0.1)
    assert two.mean_line is None and two.u_I_mean is None and two.u_I_mean_bound is None
    part = edark.dark_current([1.0, 2.0, 3.0, None], [1, 2, 3, 4], [1] * 4, [1] * 4, [1] * 4,
                              2.0, 0.1)
    assert part.mean_line is None and part.exposures == (1.0, 2.0, 3.0)


def test_dark_current_poor_fit_note_and_zero_error_point() -> None:
    """A line scattering with Q < POOR_FIT_Q gets a note; a point without an error leaves χ²/ν
    NaN (no note, no scaling) and the summary stores it as None."""
    t = [1.0, 2.0, 3.0, 4.0]
    e = np.full(4, 0.01)
    r = edark.dark_current(t, [10.0, 12.0, 11.0, 15.0], e, [3.0, 3.2, 3.4, 3.6], e, 2.0, 0.0)
    assert any(n.startswith("u_I_mean: the mean dark signal scatters") for n in r.notes)
    assert not any(n.startswith("u_I_var:") for n in r.notes)
    e0 = np.array([0.01, 0.0, 0.01, 0.01])
    r = edark.dark_current(t, [10.0, 12.0, 11.0, 15.0], e0, [3.0, 3.2, 3.4, 3.6], e0, 2.0, 0.0)
    assert math.isnan(r.mean_line.chi2_dof) and r.summary().mean_line.chi2_dof is None
    assert r.mean_line.slope_err == pytest.approx(_ols_err(np.array(t), e0 ** 2), rel=1e-9)
    assert not any("scatters" in n for n in r.notes)


# --------------------------------------------------------------------------------------------
# emva.spatial: the variance split and DSNU/PRNU parts
# --------------------------------------------------------------------------------------------
def _split_reference(a: np.ndarray, s2_stack: float, L: int) -> dict[str, float]:
    """The release 4.0 split as the module docstring writes it, with numpy."""
    M, N = a.shape
    MN = M * N
    n = s2_stack / L
    s2 = float(np.var(a, ddof=1)) - n
    cav = float(np.var(a.mean(axis=0))) - n / M
    rav = float(np.var(a.mean(axis=1))) - n / N
    d = MN - M - N
    return {"s2": s2, "cav": cav, "rav": rav,
            "col": ((MN - M) * cav - N * (s2 - rav)) / d,
            "row": ((MN - N) * rav - M * (s2 - cav)) / d,
            "pixel": MN * (s2 - cav - rav) / d}


def _pattern(M: int, N: int, seed: int) -> np.ndarray:
    """A fixed pattern with row, column and pixel parts of different sizes."""
    rng = np.random.default_rng(seed)
    return (50.0 + rng.normal(0, 2.0, (M, 1)) + rng.normal(0, 1.0, (1, N))
            + rng.normal(0, 1.5, (M, N)))


def _ss(a: np.ndarray) -> np.ndarray:
    """Two-way analysis-of-variance sums of squares (rows, columns, residual)."""
    M, N = a.shape
    mu = a.mean()
    ss_row = N * np.sum((a.mean(axis=1) - mu) ** 2)
    ss_col = M * np.sum((a.mean(axis=0) - mu) ** 2)
    return np.array([ss_row, ss_col, np.sum((a - mu) ** 2) - ss_row - ss_col])


def _part_coefficients(M: int, N: int) -> dict[str, np.ndarray]:
    """d(part)/d(SS_row, SS_col, SS_res) from the docstring: s²_y = ΣSS/(MN − 1) − σ²_n,
    s²_rav = SS_row/(MN) − σ²_n/N, s²_cav = SS_col/(MN) − σ²_n/M, and the parts' formulas."""
    MN, d = M * N, M * N - M - N
    s2 = np.ones(3) / (MN - 1)
    rav = np.array([1.0 / MN, 0, 0])
    cav = np.array([0, 1.0 / MN, 0])
    return {"s2": s2, "row": ((MN - N) * rav - M * (s2 - cav)) / d,
            "col": ((MN - M) * cav - N * (s2 - rav)) / d, "pixel": MN * (s2 - cav - rav) / d}


def test_variance_split_values_on_a_non_square_image() -> None:
    """s²_y, s²_cav, s²_rav and the row/column/pixel parts equal the docstring's formulas on a
    5 × 8 image with L = 3 (rows and columns not interchangeable, L ≠ 1)."""
    a = _pattern(5, 8, 11)
    vs = esp.variance_split(a, 6.0, 3)
    ref = _split_reference(a, 6.0, 3)
    assert (vs.M, vs.N, vs.L) == (5, 8, 3) and vs.mean == pytest.approx(a.mean())
    for k in ("s2", "cav", "rav", "row", "col", "pixel"):
        assert getattr(vs, f"s2_{k}" if k != "s2" else "s2") == pytest.approx(ref[k], rel=1e-9), k
    assert vs.part("total") == (vs.s2, vs.s2_err)
    assert vs.part("col") == (vs.s2_col, vs.s2_col_err)


def test_variance_split_errors_formula_with_and_without_pattern() -> None:
    """Each error is √(Σ c_k² var SS_k) with var SS_k = 4σ²_n·max(SS_k − ν_k σ²_n, 0) + 2σ⁴_n ν_k,
    ν = (M − 1, N − 1, (M − 1)(N − 1)) (module docstring): on a patterned 5 × 8 image and on a
    flat one (the pattern term clamped at zero, only the ν terms left)."""
    M, N, L, s2_stack = 5, 8, 3, 6.0
    n = s2_stack / L
    nu = np.array([M - 1.0, N - 1.0, (M - 1.0) * (N - 1.0)])
    coef = _part_coefficients(M, N)
    flat = 50.0 + 1e-3 * np.random.default_rng(1).normal(size=(M, N))
    for a in (_pattern(M, N, 11), flat):
        var_ss = 4 * n * np.maximum(_ss(a) - nu * n, 0.0) + 2 * n * n * nu
        vs = esp.variance_split(a, s2_stack, L)
        for k, attr in (("s2", "s2_err"), ("row", "s2_row_err"), ("col", "s2_col_err"),
                        ("pixel", "s2_pixel_err")):
            assert getattr(vs, attr) == pytest.approx(
                math.sqrt(float(np.sum(coef[k] ** 2 * var_ss))), rel=1e-9), k


def test_variance_split_errors_match_monte_carlo() -> None:
    """The errors describe the scatter of the parts over temporal-noise draws (white Gaussian,
    variance σ²_stack/L, on one fixed pattern): the root mean square of the reported errors
    (unbiased for the true variance, as SS − νσ²_n is) agrees with the standard deviation of
    3000 draws within 6 % (the Monte-Carlo standard deviation's own error is ≈ 1.5 %)."""
    M, N, L, s2_stack = 4, 7, 2, 2.0
    pat = _pattern(M, N, 5)
    rng = np.random.default_rng(2024)
    draws = pat + rng.normal(0.0, math.sqrt(s2_stack / L), (3000, M, N))
    splits = [esp.variance_split(d, s2_stack, L) for d in draws]
    for k in ("s2", "row", "col", "pixel"):
        values, errs = zip(*(s.part("total" if k == "s2" else k) for s in splits))
        sd = float(np.std(values, ddof=1))
        rms = math.sqrt(float(np.mean(np.square(errs))))
        assert rms == pytest.approx(sd, rel=0.06), k


def test_variance_split_minimum_shape() -> None:
    """2 × 3 is the smallest image with parts (MN − M − N > 0); one row or a 1-D array is
    refused."""
    a = np.array([[1.0, 2.0, 4.0], [3.0, 7.0, 5.0]])
    vs = esp.variance_split(a, 0.5, 4)
    ref = _split_reference(a, 0.5, 4)
    assert vs.s2_pixel == pytest.approx(ref["pixel"], rel=1e-9)
    vt = esp.variance_split(a.T, 0.5, 4)
    assert vt.s2_row == pytest.approx(vs.s2_col, rel=1e-9)
    assert vt.s2_row_err == pytest.approx(vs.s2_col_err, rel=1e-9)
    for bad in (np.ones((1, 5)), np.ones(6)):
        with pytest.raises(ValueError):
            esp.variance_split(bad, 0.5, 4)


def _vs(mean: float, parts: dict[str, tuple[float, float]], L: int = 4) -> esp.VarianceSplit:
    """A split with chosen parts (value, error)."""
    return esp.VarianceSplit(M=6, N=9, L=L, mean=mean, s2=1.0, s2_err=0.1, s2_cav=0.0,
                             s2_rav=0.0, s2_row=parts["row"][0], s2_row_err=parts["row"][1],
                             s2_col=parts["col"][0], s2_col_err=parts["col"][1],
                             s2_pixel=parts["pixel"][0], s2_pixel_err=parts["pixel"][1])


def test_nonuniformity_split_values_errors_and_bounds() -> None:
    """DSNU.part = √v/K with error value·hypot(e/(2v), K_err/K); PRNU.part = 100√(v_b − v_d)/
    (μ_b − μ_d) with error value·hypot(e_b, e_d)/(2(v_b − v_d)); a part exactly at 2 errors is
    not determinable, bounded by √(max(v, 0) + 2e)/K (DSNU) or 100√(...)/signal (PRNU)."""
    dark = _vs(100.0, {"row": (9.0, 1.0), "col": (2.0, 1.0), "pixel": (-1.0, 0.5)})
    bright = _vs(600.0, {"row": (25.0, 3.0), "col": (4.0, 1.0), "pixel": (16.0, 2.0)})
    K, K_err = 0.5, 0.05
    ns = esp.nonuniformity_split(bright, dark, K, K_err)
    assert ns.DSNU1288_row == pytest.approx(3.0 / K)
    assert ns.DSNU1288_row_err == pytest.approx(6.0 * math.hypot(1.0 / 18.0, 0.1))
    assert ns.DSNU1288_col is None and ns.DSNU1288_col_err is None      # 2.0 == 2·1.0
    bounds = dict(ns.bounds)
    assert bounds["DSNU1288_col"] == pytest.approx(math.sqrt(4.0) / K)
    assert bounds["DSNU1288_pixel"] == pytest.approx(math.sqrt(1.0) / K)
    v, e = 16.0, math.hypot(3.0, 1.0)
    assert ns.PRNU1288_row == pytest.approx(100.0 * 4.0 / 500.0)
    assert ns.PRNU1288_row_err == pytest.approx(0.8 * e / (2 * v))
    # col: 4 - 2 = 2 against hypot(1, 1)·2 = 2.83: not determinable
    assert ns.PRNU1288_col is None
    assert bounds["PRNU1288_col"] == pytest.approx(
        100.0 * math.sqrt(2.0 + 2.0 * math.sqrt(2.0)) / 500.0)
    assert ns.PRNU1288_pixel == pytest.approx(100.0 * math.sqrt(17.0) / 500.0)
    assert ns.summary().bounds == bounds and len(ns.notes) == 3


def test_prnu_without_signal_is_not_determinable() -> None:
    """A bright mean equal to the dark mean leaves every PRNU part None with a note and no
    bound (the signal must exceed zero)."""
    p = {"row": (25.0, 1.0), "col": (25.0, 1.0), "pixel": (25.0, 1.0)}
    ns = esp.nonuniformity_split(_vs(100.0, p), _vs(100.0, {k: (1.0, 0.1) for k in p}), 2.0, 0.0)
    assert ns.PRNU1288_row is None and ns.PRNU1288_pixel is None
    assert not any(k.startswith("PRNU") for k, _ in ns.bounds)
    assert sum("does not exceed" in n for n in ns.notes) == 3
    assert ns.DSNU1288_row == pytest.approx(0.5)


def test_prnu_part_exactly_two_errors_is_not_determinable() -> None:
    """v_b − v_d = 10 with hypot(3, 4) = 5: exactly DETERMINABLE_Z errors, not above: None,
    bounded by 100·√(10 + 2·5)/signal."""
    dark = _vs(10.0, {"row": (1.0, 0.1), "col": (1.0, 0.1), "pixel": (16.0, 4.0)})
    bright = _vs(210.0, {"row": (9.0, 0.1), "col": (9.0, 0.1), "pixel": (26.0, 3.0)})
    ns = esp.nonuniformity_split(bright, dark, 2.0, 0.0)
    assert ns.PRNU1288_pixel is None
    assert dict(ns.bounds)["PRNU1288_pixel"] == pytest.approx(100.0 * math.sqrt(20.0) / 200.0)
    assert ns.PRNU1288_row == pytest.approx(100.0 * math.sqrt(8.0) / 200.0)


# --------------------------------------------------------------------------------------------
# emva.spatial: spectrograms, filter, histograms, profiles, plots
# --------------------------------------------------------------------------------------------
def test_spectrogram_against_explicit_dft() -> None:
    """Amplitude² = mean over lines of |Σ_x (y − ȳ_image) e^{−2πikx/n}|²/n with the image mean
    (not the line mean) removed; vertical works along the columns of a non-square image."""
    rng = np.random.default_rng(9)
    img = rng.normal(10.0, 1.0, (3, 6)) + np.arange(3)[:, None]
    for vertical in (False, True):
        a = img.T if vertical else img
        n = a.shape[1]
        k = np.arange(n // 2 + 1)
        x = np.arange(n)
        basis = np.exp(-2j * np.pi * np.outer(k, x) / n)
        power = np.mean(np.abs((a - img.mean()) @ basis.T) ** 2, axis=0) / n
        f, amp = esp.spectrogram(img, vertical)
        np.testing.assert_allclose(f, k / n)
        np.testing.assert_allclose(amp, np.sqrt(power), rtol=1e-10, atol=1e-12)


def test_high_pass_valid_part_and_box_mean() -> None:
    """The image less its 5 × 5 box mean, with 2 pixels cut at each edge: (H − 4) × (W − 4)
    pixels equal to the explicit box mean difference; size 1 keeps the whole (zero) image."""
    rng = np.random.default_rng(4)
    img = rng.normal(0, 1, (7, 9))
    hp = esp.high_pass(img)
    assert hp.shape == (3, 5)
    ref = np.array([[img[i, j] - img[i - 2:i + 3, j - 2:j + 3].mean() for j in range(2, 7)]
                    for i in range(2, 5)])
    np.testing.assert_allclose(hp, ref, atol=1e-12)
    hp3 = esp.high_pass(img, 3)
    assert hp3.shape == (5, 7)
    assert hp3[0, 0] == pytest.approx(img[1, 1] - img[0:3, 0:3].mean())
    np.testing.assert_allclose(esp.high_pass(img, 1), 0.0, atol=1e-12)


def test_defect_histogram_edges_counts_and_normal_model() -> None:
    """Bins from min to max (lower edges), counts of every value, and a normal model
    N·width/(√(2π)σ)·exp(−½((centre − μ)/σ)²) with σ the population deviation (ddof 0)."""
    v = np.array([0.0, 1.0, 1.0, 2.0, 3.0, 3.0, 3.0, 7.0])
    h = esp.defect_histogram(v, bins=14)          # width 0.5 (1 would hide the factor)
    np.testing.assert_allclose(h["x"], np.arange(14) * 0.5)
    np.testing.assert_array_equal(h["count"], [1, 0, 2, 0, 1, 0, 3, 0, 0, 0, 0, 0, 0, 1])
    centre = np.arange(14) * 0.5 + 0.25
    sd = math.sqrt(np.mean((v - v.mean()) ** 2))
    model = 8 * 0.5 / (math.sqrt(2 * math.pi) * sd) * np.exp(-0.5 * ((centre - v.mean()) / sd) ** 2)
    np.testing.assert_allclose(h["model"], model, rtol=1e-12)
    flat = esp.defect_histogram(np.full(4, 2.0), bins=4)
    np.testing.assert_allclose(flat["x"], [2.0, 2.25, 2.5, 2.75])
    assert flat["count"].sum() == 4 and np.all(flat["model"] == 0.0)


def test_defect_histogram_quantised_bins() -> None:
    """With a quantum, bins are whole numbers of steps with edges half a step off the values:
    values 0, 0.25, ..., 2.5 (11 steps) in at most 4 bins take 3 steps each (4 bins)."""
    v = np.arange(11) * 0.25
    h = esp.defect_histogram(v, bins=4, quantum=0.25)
    np.testing.assert_allclose(h["x"], [-0.125, 0.625, 1.375, 2.125])
    np.testing.assert_array_equal(h["count"], [3, 3, 3, 2])
    one = esp.defect_histogram(v, bins=11, quantum=0.25)
    np.testing.assert_array_equal(one["count"], np.ones(11))


def test_accumulated_histogram_percent_at_or_above() -> None:
    """percent[k] = 100 × fraction of |v − mean| ≥ x_k; 100 % at x = 0."""
    v = np.array([1.0, 2.0, 3.0, 4.0, 10.0])      # deviations 3, 2, 1, 0, 6
    acc = esp.accumulated_histogram(v, bins=6)
    np.testing.assert_allclose(acc["x"], np.arange(6.0))
    dev = np.abs(v - v.mean())
    np.testing.assert_allclose(acc["percent"], [100 * np.mean(dev >= x) for x in range(6)])


def test_profiles_blocks_and_middle_line() -> None:
    """Per-column mean/min/max and the middle row (H // 2); with fewer points than columns the
    blocks give the mean of means, smallest minimum, largest maximum and first index; exactly
    as many points as columns keeps every column."""
    img = np.arange(15.0).reshape(3, 5) ** 1.5
    pr = esp.profiles(img, points=5)
    np.testing.assert_allclose(pr["mean"], img.mean(axis=0))
    np.testing.assert_allclose(pr["mid"], img[1])
    np.testing.assert_allclose(pr["index"], np.arange(5.0))
    pr2 = esp.profiles(img, points=2)          # blocks [0, 1] and [2, 3, 4]
    np.testing.assert_allclose(pr2["index"], [0.0, 2.0])
    np.testing.assert_allclose(pr2["mean"], [img[:, :2].mean(), img[:, 2:].mean()])
    np.testing.assert_allclose(pr2["min"], [img[:, :2].min(), img[:, 2:].min()])
    np.testing.assert_allclose(pr2["max"], [img[:, :2].max(), img[:, 2:].max()])
    np.testing.assert_allclose(pr2["mid"], [img[1, :2].mean(), img[1, 2:].mean()])
    pv = esp.profiles(img, vertical=True, points=10)
    np.testing.assert_allclose(pv["mean"], img.mean(axis=1))
    np.testing.assert_allclose(pv["mid"], img[:, 2])


def test_spatial_plots_levels_and_units() -> None:
    """Levels: DSNU1288·K in DN, σ_stack.dark and σ_stack.dark/√L_dark in DN, σ_stack and
    σ_stack/√L in % of the signal; PRNU spectrogram in % of the mean of bright − dark; DSNU
    histogram in e⁻ from the dark mean, with quantum 1/(L_dark·K) for an average of integers."""
    rng = np.random.default_rng(8)
    L, L_dark, K = 4, 5, 0.5
    dark = rng.integers(100, 140, (L_dark, 8, 10)).sum(axis=0) / L_dark
    bright = dark + 200.0 + rng.normal(0, 2.0, (8, 10))
    sp = esp.spatial_plots(bright, dark, L=L, L_dark=L_dark, s2_stack=9.0, s2_stack_dark=4.0,
                           K=K, DSNU1288=3.0, PRNU1288=0.7)
    lv = sp.levels
    signal = float((bright - dark).mean())
    assert lv["DSNU1288_DN"] == pytest.approx(1.5) and lv["PRNU1288"] == 0.7
    assert lv["sigma_y_stack_dark"] == pytest.approx(2.0)
    assert lv["sigma_y_stack_dark_avg"] == pytest.approx(2.0 / math.sqrt(L_dark))
    assert lv["sigma_y_stack_percent"] == pytest.approx(300.0 / signal)
    assert lv["sigma_y_stack_avg_percent"] == pytest.approx(300.0 / signal / math.sqrt(L))
    _, amp = esp.spectrogram(bright - dark)
    np.testing.assert_allclose(sp.spectrograms["PRNU_horizontal"]["amplitude"],
                               amp * 100.0 / signal)
    _, amp_d = esp.spectrogram(dark, True)
    np.testing.assert_allclose(sp.spectrograms["DSNU_vertical"]["amplitude"], amp_d)
    dsnu_e = (dark - dark.mean()) / K
    ref = esp.defect_histogram(dsnu_e, quantum=1.0 / (L_dark * K))
    np.testing.assert_allclose(sp.histograms["DSNU"]["x"], ref["x"])
    np.testing.assert_allclose(sp.accumulated["DSNU"]["percent"],
                               esp.accumulated_histogram(dsnu_e)["percent"])
    np.testing.assert_allclose(sp.profiles["bright_vertical"]["mean"], (bright - dark).mean(axis=1))
    assert len(sp.histograms["PRNU"]["x"]) == 256              # Results1288._histogram_Qmax
    assert sp.accumulated["PRNU"]["percent"].size == 256
    none = esp.spatial_plots(dark, dark, L=L, L_dark=L_dark, s2_stack=9.0, s2_stack_dark=-1.0,
                             K=K)
    assert none.levels["DSNU1288_DN"] is None and none.levels["sigma_y_stack_dark"] == 0.0
    assert math.isnan(none.levels["sigma_y_stack_percent"])


# --------------------------------------------------------------------------------------------
# fixedpattern: argument checks, correction and its check (eq. 51, sec. VII-A)
# --------------------------------------------------------------------------------------------
def test_fixed_pattern_map_argument_checks() -> None:
    """window must be odd and ≥ 3 (3 accepted: the call reaches the data check), p > 0 and
    center 'median' or 'mean'; each is refused before any frame is read."""
    frames = np.zeros((1, 2, 8, 8))
    for kw in ({"window": 1}, {"window": 4}, {"p": 0.0}, {"p": math.nan}, {"center": "mode"}):
        with pytest.raises(CcdError) as err:
            fp.fixed_pattern_map(frames, np.zeros((8, 8)), **kw)
        assert err.value.where == next(iter(kw))
    with pytest.raises(CcdError) as err:              # window 3 passes: the one config fails
        fp.fixed_pattern_map(frames, np.zeros((8, 8)), window=3)
    assert err.value.where not in ("window", "p", "center")


def test_correct_and_correction_check_boundaries() -> None:
    """D_C = (D − D̂_D)/K̂ in float32; the check counts |(D − D̂_D)(1/K̂ − 1)|/q strictly above 1
    and 2 (exactly 1q or 2q not counted), skips non-finite pixels (K̂ = 0) in every figure, and
    reads q ≠ 1 in DN."""
    D = np.array([[12.0, 14.0, 30.0, 10.0], [16.0, 20.0, 10.0, 50.0]])
    dark = np.full((2, 4), 10.0)
    K = np.array([[2.0, 2.0, 0.8, 1.0], [0.8, 0.0, 1.0, 2.0 / 3.0]])
    out = fp.correct(D, dark, K)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out[0], [1.0, 2.0, 25.0, 0.0])
    # levels 2, 4, 20, 0 | 6, 10, 0, 40; changes |L(1/K − 1)|: 1, 2, 5, 0 | 1.5, inf, 0, 20
    chk = fp.correction_check(D, dark, K, q=1.0)
    assert chk.n_pixels == 7
    assert chk.frac_gt_1q == pytest.approx(4 / 7)      # 5, 1.5, 20 and 2 (> 1); 1 is not
    assert chk.frac_gt_2q == pytest.approx(2 / 7)      # 5, 20; 2 is not
    assert chk.frac_gt_2q_of_gt_1q == pytest.approx(2 / 4)
    assert chk.max_change_q == pytest.approx(20.0)
    assert chk.mean_level == pytest.approx((2 + 4 + 20 + 0 + 6 + 0 + 40) / 7)
    chk2 = fp.correction_check(D, dark, K, q=2.5)
    assert chk2.frac_gt_1q == pytest.approx(2 / 7) and chk2.frac_gt_2q == pytest.approx(1 / 7)
    assert chk2.max_change_q == pytest.approx(8.0) and chk2.q == 2.5
    none = fp.correction_check(D, dark, np.ones((2, 4)))
    assert none.frac_gt_1q == 0.0 and none.frac_gt_2q_of_gt_1q == 0.0
    for q in (0.0, -1.0, math.nan):
        with pytest.raises(CcdError) as err:
            fp.correction_check(D, dark, K, q=q)
        assert err.value.where == "q"
    with pytest.raises(CcdError):
        fp.correction_check(D, dark, np.zeros((2, 4)))   # every change infinite or NaN
    with pytest.raises(CcdError):
        fp.correct(D, dark, np.ones((4, 2)))
    with pytest.raises(CcdError) as err:
        fp.correct(D[None], dark, K)
    assert err.value.where == "frame"


def test_linearity_degenerate_fit_sets_and_line_record() -> None:
    """The light-count rule needs two distinct counts among the lower levels, the variance rule
    two distinct means below the top tenth: otherwise nothing is excluded; LineFit.to_dict
    writes a NaN Q as None."""
    same = [_pt(i + 1, m, 1.0, photons=p) for i, (m, p) in
            enumerate(zip([100.0, 101.0, 102.0, 900.0], [50.0, 50.0, 50.0, 60.0]))]
    assert pf.linearity_reasons(same, 0.05) == {}
    flat = [_pt(1, 0.0, 10.0, 0.01), _pt(2, 0.0, 10.0, 0.01), _pt(3, 100.0, 1000.0, 0.01)]
    assert pf.linearity_reasons(flat, 0.05) == {}
    d = pf.weighted_line_fit([1.0, 3.0], [2.0, 5.0], [1.0, 4.0]).to_dict()
    assert d["Q"] is None and d["dof"] == 0 and d["A"] == pytest.approx(1.5)
    assert d["cov"][0][1] == pytest.approx(d["cov"][1][0])


def test_dark_line_q_needs_degrees_of_freedom() -> None:
    """Q of a dark line is None without χ²/ν or with ν = 0, else the χ² survival of χ²/ν·ν."""
    line = edark.DarkLineSummary(slope=1.0, slope_err=0.1, offset=0.0, chi2_dof=1.5, dof=0)
    assert line.q() is None
    assert edark.DarkLineSummary(1.0, 0.1, 0.0, None, 3).q() is None
    assert edark.DarkLineSummary(1.0, 0.1, 0.0, 1.5, 4).q() == pytest.approx(
        sstats.chi2.sf(6.0, 4))


def test_linearity_by_variance_looks_only_at_the_top_tenth() -> None:
    """A level 30 % off at μ = 85 (below lo + 0.9·(hi − lo) = 90) is not tested, only fitted
    (its large error keeps it from moving the line): nothing is excluded."""
    mus = [0.0, 20.0, 40.0, 60.0, 80.0, 85.0, 100.0]
    pts = [_pt(i + 1, m, 10.0 + 0.5 * m, var_err=0.05) for i, m in enumerate(mus)]
    pts[5] = _pt(6, 85.0, 0.7 * (10.0 + 0.5 * 85.0), var_err=2.0)
    assert pf.linearity_reasons(pts, 0.05) == {}


def test_pixel_moments_names_the_frame_of_a_pair() -> None:
    """(record, array) items are averaged like arrays, and a frame of another shape is refused
    naming its record's relpath."""
    a, b = np.array([[1.0, 5.0]]), np.array([[3.0, 9.0]])
    r = cst.pixel_moments([(SimpleNamespace(relpath="a.tif"), a),
                           (SimpleNamespace(relpath="b.tif"), b)])
    np.testing.assert_allclose(r.mean, [[2.0, 7.0]])
    np.testing.assert_allclose(r.var, [[2.0, 8.0]])
    with pytest.raises(CcdError) as err:
        cst.pixel_moments([(SimpleNamespace(relpath="a.tif"), a),
                           (SimpleNamespace(relpath="c.tif"), np.zeros((2, 2)))])
    assert err.value.where == "c.tif"


def test_ptc_point_summary_round_trip_keeps_nan() -> None:
    """PtcPoint.summary writes NaN as None and from_summary reads it back as NaN (the inverse
    the docstring states), photons and exposure kept."""
    p = replace(_pt(3, 12.5, math.nan, 0.25, exposure=0.02, photons=400.0),
                used=False, reason="zero variance", exclusion="zero-variance")
    s = p.summary()
    assert s.var is None and s.exposure == 0.02 and s.photons == 400.0
    q = pf.PtcPoint.from_summary(s)
    assert math.isnan(q.var) and q.summary() == s and q.mu == 12.5 and q.exclusion == \
        "zero-variance"


# --------------------------------------------------------------------------------------------
# emva.datasheet: pixel reading, pair statistics, stack statistics
# --------------------------------------------------------------------------------------------

_REC = SimpleNamespace(relpath="f.tif")


def test_pixels_integer_codes_and_refusals() -> None:
    """Integer codes in [0, 2¹⁶) become int64; 2¹⁶ or a negative code go to float64; NaN and
    +inf are refused, as are colour frames."""
    assert eds._pixels(_REC, np.array([[0, 65535]], np.uint16)).dtype == np.int64
    assert eds._pixels(_REC, np.array([[0, 65536]], np.uint32)).dtype == np.float64
    assert eds._pixels(_REC, np.array([[-1, 5]], np.int32)).dtype == np.float64
    for bad in (np.array([[1.0, math.nan]]), np.array([[1.0, math.inf]]), np.zeros((2, 2, 3))):
        with pytest.raises(CcdError):
            eds._pixels(_REC, bad)


def test_pair_mean_and_variance_against_numpy() -> None:
    """μ_y = (Σa + Σb)/(2N); σ²_y = Σ(a − b)²/(2N) − (ȳ_b − ȳ_a)²/2 = var(a − b, ddof 0)/2 on a
    non-square pair with an offset between frames; different shapes refused."""
    rng = np.random.default_rng(21)
    a = rng.integers(100, 200, (3, 7)).astype(np.int64)
    b = rng.integers(90, 210, (3, 7)).astype(np.int64)
    mu, var, n = eds._pair(_REC, a, _REC, b)
    assert n == 21 and mu == pytest.approx((a.mean() + b.mean()) / 2)
    assert var == pytest.approx(np.var((a - b).astype(float)) / 2, rel=1e-12)
    with pytest.raises(CcdError):
        eds._pair(_REC, a, _REC, b[:, :6])


def test_stack_statistics_against_numpy() -> None:
    """⟨y⟩ = Σy/L; σ²_stack = mean per-pixel variance (ddof 1); s²_measured = var(⟨y⟩, ddof 1);
    s² = s²_measured − σ²_stack/L; s²_err = √(4·max(s², 0)·σ²_n/N + 2σ⁴_n/N), σ²_n = σ²_stack/L;
    integer and float frames alike; a frame of another shape refused."""
    rng = np.random.default_rng(5)
    pattern = rng.normal(0, 4, (4, 6))
    frames = np.round(500 + pattern + rng.normal(0, 3, (3, 4, 6))).astype(np.int64)
    for data in (frames, frames.astype(np.float64) + 0.25):
        st = eds._Stack()
        for f in data:
            st.add(_REC, f.copy())
        ss = st.statistics(2, 0.01, 1000.0)
        avg = data.mean(axis=0)
        s2_stack = float(data.var(axis=0, ddof=1).mean())
        s2m = float(np.var(avg, ddof=1))
        s2 = s2m - s2_stack / 3
        noise = s2_stack / 3
        assert ss.L == 3 and ss.n_pixels == 24
        assert ss.u_y == pytest.approx(avg.mean(), rel=1e-12)
        assert ss.s2_stack == pytest.approx(s2_stack, rel=1e-10)
        assert ss.s2_measured == pytest.approx(s2m, rel=1e-10)
        assert ss.s2 == pytest.approx(s2, rel=1e-9)
        assert ss.s2_err == pytest.approx(
            math.sqrt(4 * max(s2, 0) * noise / 24 + 2 * noise ** 2 / 24), rel=1e-9)
        np.testing.assert_allclose(ss.image, avg)
    flat = eds._Stack()
    for f in (np.array([[1.0, 2.0], [3.0, 4.0]]), np.array([[3.0, 4.0], [1.0, 2.0]])):
        flat.add(_REC, f)
    fs = flat.statistics(None, None, 0.0)
    assert fs.s2 < 0 and fs.s2_err == pytest.approx(
        math.sqrt(2 * (fs.s2_stack / 2) ** 2 / 4), rel=1e-12)       # max(s², 0) = 0
    with pytest.raises(CcdError):
        flat.add(_REC, np.zeros((2, 3)))


def test_snr_curve_measured_model_and_total() -> None:
    """Measured SNR (μ_y − μ_y.dark)/σ_y, None where σ²_y = 0; model ημ_p/√(σ²_d + σ²_q/K² +
    ημ_p) (eq. 11) with σ²_q = 1/12 and K ≠ 1; with DSNU and PRNU also ημ_p/√(model variance +
    DSNU² + (PRNU/100·ημ_p)²); a NaN DSNU leaves the total out."""
    from ccdcore.emva.results import EmvaFigures

    pts = [SimpleNamespace(u_p=u, u_y=y, u_y_dark=10.0, s2_y=v)
           for u, y, v in ((100.0, 30.0, 9.0), (1000.0, 210.0, 64.0), (5000.0, 900.0, 0.0))]
    fig = SimpleNamespace(points=pts, QE=40.0, sigma_d=3.0, K=0.25, DSNU1288=2.0,
                          PRNU1288=1.5)
    s = EmvaFigures.snr_summary(fig)  # type: ignore[arg-type]
    assert s.snr[:2] == pytest.approx((20.0 / 3.0, 25.0)) and s.snr[2] is None
    u = np.array([100.0, 1000.0, 5000.0])
    base = 9.0 + (1 / 12) / 0.0625 + 0.4 * u
    assert s.snr_model == pytest.approx(tuple(0.4 * u / np.sqrt(base)))
    total = base + 4.0 + (0.015 * 0.4 * u) ** 2
    assert s.snr_total == pytest.approx(tuple(0.4 * u / np.sqrt(total)))
    fig.DSNU1288 = math.nan
    assert EmvaFigures.snr_summary(fig).snr_total is None  # type: ignore[arg-type]


def test_datasheet_files_plot_needs_and_cells() -> None:
    """A plot against the exposure time needs two known dark exposure times (None not counted);
    histogram edges close the last bin one bin width on (width 1 for one bin); a float cell is
    its repr (exact round trip), None empty."""
    from ccdcore.emva import datasheet_files as edf

    def darks(*t: float | None) -> SimpleNamespace:
        return SimpleNamespace(dark_points=[SimpleNamespace(exposure=x) for x in t])

    assert edf._needs_dark(darks(0.01, 0.02)) is None
    assert "1 known exposure time;" in edf._needs_dark(darks(0.01, None, 0.01))
    assert "0 known exposure times" in edf._needs_dark(darks(None))
    np.testing.assert_allclose(edf._edges(np.array([1.0, 1.5, 2.0])), [1.0, 1.5, 2.0, 2.5])
    np.testing.assert_allclose(edf._edges(np.array([3.0])), [3.0, 4.0])
    assert edf._cell(0.1 + 0.2) == "0.30000000000000004" and edf._cell(None) == ""
    assert edf._cell(7) == "7"
    assert np.isnan(edf._floats([1.0, None])[1])
