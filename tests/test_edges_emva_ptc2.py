"""Edge and error-formula pins of the photon-transfer result (:func:`ccdcore.noise.fit_points`
and the measured levels: the conversion gain, the read noise and their errors, the robust mode,
the verdict), of the photon-transfer gate (:mod:`ccdcore.gates`), of the capture plan
(:mod:`ccdcore.capture`) and of the EMVA 1288 computations (:mod:`ccdcore.emva.fits`: the
closed-form lines and their Birge-scaled errors, the threshold and range, σ_d, the linearity
and its propagated errors, DSNU/PRNU).

Expectations come from the documented formulas (eq. 27 of Healey & Kondepudy, the gate's
stated tolerances, the EMVA 1288 definitions in the docstrings), numpy references on the same
data (weighted least squares, polyfit, finite differences for the delta method) or hand
arithmetic; the inputs reach the limits exactly (ROBUST_Z, Q_RESOLVED, σ(A)/A = 5 %, 70 % of
saturation, the 5 %/95 % linearity range, DISAGREEMENT_Z) and avoid A = 1, K = 1 and equal
errors.
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from ccdcore import gates as cg
from ccdcore import noise as cn
from ccdcore import ptc_fit as pf
from ccdcore.errors import CcdError


def _pt(level: int, mu: float, var: float, var_err: float = 1.0, *, exposure: float | None = None,
        photons: float | None = None, mu_raw: float | None = None) -> pf.PtcPoint:
    """A photon-transfer level with the given numbers (mu_raw defaults to mu)."""
    return pf.PtcPoint(level=level, mu=mu, var=var, var_err=var_err, n_pairs=1, n_pixels=100,
                       used=True, reason=None, exposure=exposure,
                       mu_raw=mu if mu_raw is None else mu_raw, clipped_fraction=0.0,
                       photons=photons)


def replace_point(p: pf.PtcPoint, **kw: object) -> pf.PtcPoint:
    """dataclasses.replace for a level."""
    return replace(p, **kw)  # type: ignore[arg-type]


# --------------------------------------------------------------------------------------------
# noise: fit_points and the figures of the result (eq. 27)
# --------------------------------------------------------------------------------------------


def _line_points(A: float, c: float, mus: list[float], rel_err: float = 0.02,
                 offsets: list[float] | None = None, b0: float = 7.0) -> list[pf.PtcPoint]:
    """Levels near σ² = A·μ + c with errors rel_err·σ² and small chosen offsets; μ linear in
    the exposure (so the linearity rule keeps every level)."""
    offsets = offsets or [0.0] * len(mus)
    return [_pt(i + 1, m, A * m + c + o, rel_err * (A * m + c), mu_raw=m + b0, exposure=m / 100)
            for i, (m, o) in enumerate(zip(mus, offsets))]


def _num_grad(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Central finite-difference gradient."""
    g = np.zeros_like(x)
    for i in range(x.size):
        d = np.zeros_like(x)
        d[i] = h * max(abs(x[i]), 1.0)
        g[i] = (f(x + d) - f(x - d)) / (2 * d[i])
    return g


def test_fit_points_figures_and_their_errors() -> None:
    """1/A with error A_err/A²; σ_R·A = √(σ²_C − q²/12) with error σ(σ²_C)/(2√(σ²_C − q²/12));
    σ_R = √(σ²_C − q²/12)/A with the delta-method error of (A, σ²_C) through the full covariance
    (finite differences here); b₀ the median of μ_raw − μ; A_err, σ²_C_err from cov."""
    pts = _line_points(0.37, 5.0, [20.0, 60.0, 150.0, 300.0, 500.0],
                       offsets=[0.05, -0.2, 0.4, -0.9, 1.5])
    r = cn.fit_points(pts)
    fit = pf.weighted_line_fit([p.mu for p in pts], [p.var for p in pts],
                               [p.var_err ** 2 for p in pts])
    q2 = 1.0 / 12.0
    assert r.quantisation_dn2 == pytest.approx(q2)
    assert r.A == pytest.approx(fit.A) and r.sigma_c2 == pytest.approx(fit.sigma_c2)
    assert r.A_err == pytest.approx(math.sqrt(fit.cov[0, 0]))
    assert r.sigma_c2_err == pytest.approx(math.sqrt(fit.cov[1, 1]))
    assert r.conversion_gain_e_per_dn == pytest.approx(1.0 / fit.A)
    assert r.conversion_gain_e_per_dn_err == pytest.approx(r.A_err / fit.A ** 2)
    rn_dn = math.sqrt(fit.sigma_c2 - q2)
    assert r.read_noise_dn == pytest.approx(rn_dn)
    assert r.read_noise_dn_err == pytest.approx(r.sigma_c2_err / (2 * rn_dn))
    assert r.read_noise_e == pytest.approx(rn_dn / fit.A)
    x0 = np.array([fit.A, fit.sigma_c2])
    g = _num_grad(lambda x: math.sqrt(x[1] - q2) / x[0], x0)
    assert r.read_noise_e_err == pytest.approx(math.sqrt(g @ fit.cov @ g), rel=1e-5)
    assert fit.cov[0, 1] != 0.0 and r.black_level_dn == pytest.approx(7.0)
    assert r.dof == 3 and r.Q == pytest.approx(fit.Q)


def test_fit_points_unresolved_read_noise_and_negative_slope() -> None:
    """σ²_C below q²/12 leaves the read noise NaN with a note; a negative slope leaves the
    conversion gain and the read noise in electrons NaN (the DN read noise stays)."""
    low = cn.fit_points(_line_points(0.5, 0.02, [10.0, 50.0, 100.0, 200.0]))
    assert math.isnan(low.read_noise_dn) and math.isnan(low.read_noise_e)
    assert math.isnan(low.read_noise_dn_err) and math.isnan(low.read_noise_e_err)
    assert any("not above q²/12" in n for n in low.notes)
    assert low.conversion_gain_e_per_dn == pytest.approx(1.0 / low.A)
    pts = [_pt(i + 1, m, 50.0 - 0.01 * m, 0.5) for i, m in enumerate([10.0, 50.0, 100.0])]
    neg = cn.fit_points(pts)
    assert neg.A < 0 and math.isnan(neg.conversion_gain_e_per_dn)
    assert math.isnan(neg.conversion_gain_e_per_dn_err) and math.isnan(neg.read_noise_e)
    assert neg.read_noise_dn == pytest.approx(math.sqrt(neg.sigma_c2 - 1 / 12))
    assert neg.summary().conversion_gain_e_per_dn is None


def test_verdict_thresholds() -> None:
    """Q < 0.001 rejected, Q < 0.05 poor, from 0.05 acceptable; NaN untested (docstring)."""
    assert cn._verdict(0.0009) == "model rejected"
    assert cn._verdict(0.001) == "poor"
    assert cn._verdict(0.0499) == "poor"
    assert cn._verdict(0.05) == "acceptable"
    assert cn._verdict(math.nan).startswith("untested")


def _robust_reference(pts: list[pf.PtcPoint]) -> list[int]:
    """The documented robust mode: refit and drop the level of largest |residual|/σ while it is
    above ROBUST_Z and more than three levels are left."""
    used, dropped = list(pts), []
    while len(used) > 3:
        fit = pf.weighted_line_fit([p.mu for p in used], [p.var for p in used],
                                   [p.var_err ** 2 for p in used])
        r = [abs(p.var - fit.A * p.mu - fit.sigma_c2) / p.var_err for p in used]
        k = int(np.argmax(r))
        if r[k] <= cn.ROBUST_Z:
            break
        dropped.append(used.pop(k).level)
    return dropped


def test_fit_points_robust_keeps_three_levels() -> None:
    """Robust mode drops the worst level (> 3σ) one at a time, refitting, and never below three
    levels; without robust nothing is dropped."""
    mus = [10.0, 40.0, 80.0, 120.0, 200.0, 260.0]
    pts = _line_points(0.5, 4.0, mus, rel_err=0.01, offsets=[0.0, 0.0, 5.0, 0.0, -12.0, 0.1])
    ref = _robust_reference(pts)
    assert len(ref) == 2
    r = cn.fit_points(pts, robust=True)
    assert list(r.robust_dropped) == ref
    assert sorted(p.level for p in r.points if not p.used) == sorted(ref)
    four = cn.fit_points(pts[:4], robust=True)        # 4 levels: at most one dropped
    assert list(four.robust_dropped) == _robust_reference(pts[:4])
    assert len(four.robust_dropped) == 1 and sum(p.used for p in four.points) == 3
    assert [p.exclusion for p in four.points if not p.used] == ["robust"]
    assert cn.fit_points(pts).robust_dropped == ()


def test_fit_points_argument_boundaries() -> None:
    """Exactly three usable levels fit; two do not; fit_fraction 1 is accepted and 0 or above 1
    refused; linearity_tolerance 0 refused; an unknown excluded level refused; a user-excluded
    level is marked 'user'."""
    pts = _line_points(0.5, 4.0, [10.0, 40.0, 80.0, 120.0])
    assert cn.fit_points(pts[:3]).dof == 1
    with pytest.raises(CcdError):
        cn.fit_points(pts[:2])
    with pytest.raises(CcdError):
        cn.fit_points(pts, exclude_levels=[1, 2])
    r = cn.fit_points(pts, exclude_levels=[2])
    assert [(p.level, p.exclusion, p.reason) for p in r.points if not p.used] == [
        (2, "user", cn.USER_EXCLUDED)]
    assert cn.fit_points(pts, fit_fraction=1.0).fit_fraction == 1.0
    for bad in ({"fit_fraction": 0.0}, {"fit_fraction": 1.01}, {"linearity_tolerance": 0.0},
                {"exclude_levels": [9]}):
        with pytest.raises(CcdError):
            cn.fit_points(pts, **bad)
    with pytest.raises(CcdError):
        cn.fit_points([])


def test_worst_levels_and_exclusion_notes_limit() -> None:
    """worst_levels: used levels by |residual|/σ, largest first, n of them; five excluded levels
    give five notes, six give one note per kind of exclusion."""
    pts = _line_points(0.5, 4.0, [10.0, 40.0, 80.0, 120.0, 160.0],
                       offsets=[0.0, 0.3, -0.1, 0.5, 0.0], rel_err=0.05)
    r = cn.fit_points(pts)
    z = [(p.level, (p.var - r.A * p.mu - r.sigma_c2) / p.var_err) for p in r.points]
    z.sort(key=lambda t: -abs(t[1]))
    worst = r.worst_levels(2)
    assert [lv for lv, _ in worst] == [lv for lv, _ in z[:2]]
    assert [v for _, v in worst] == pytest.approx([v for _, v in z[:2]])
    assert r.worst_levels(0) == []
    many = [replace_point(p, used=False, exclusion="user", reason="r") for p in pts]
    assert len(cn._exclusion_notes(many)) == 5
    extra = many + [replace_point(pts[0], level=99, used=False, exclusion="user", reason="r")]
    notes = cn._exclusion_notes(extra)
    assert len(notes) == 1 and notes[0].startswith("6 levels not used (user")




def test_robust_threshold_and_floor_of_three() -> None:
    """A level 4σ off (between ROBUST_Z = 3 and twice it) is dropped; with four levels two of
    which are off, only one goes (three must stay) although the second is still > 3σ off;
    b₀ is the median (not the mean) of μ_raw − μ."""
    pts = _line_points(0.5, 4.0, [10.0, 40.0, 80.0, 120.0, 200.0], rel_err=0.01)
    fit = pf.weighted_line_fit([p.mu for p in pts], [p.var for p in pts],
                               [p.var_err ** 2 for p in pts])
    assert fit.chi2 == pytest.approx(0.0, abs=1e-12)
    # push level 3 off so that its residual about the refit of all five is ≈ 4σ
    moved = replace_point(pts[2], var=pts[2].var + 5.2 * pts[2].var_err)
    pts5 = pts[:2] + [moved] + pts[3:]
    f5 = pf.weighted_line_fit([p.mu for p in pts5], [p.var for p in pts5],
                              [p.var_err ** 2 for p in pts5])
    z = abs(moved.var - f5.A * moved.mu - f5.sigma_c2) / moved.var_err
    assert 3.2 < z < 5.5
    assert cn.fit_points(pts5, robust=True).robust_dropped == (3,)
    two_off = [pts[0], replace_point(pts[1], var=pts[1].var - 30 * pts[1].var_err),
               replace_point(pts[2], var=pts[2].var + 30 * pts[2].var_err), pts[3]]
    ref = _robust_reference(two_off)
    assert len(ref) == 1
    used = [p for p in two_off if p.level not in ref]
    f3 = pf.weighted_line_fit([p.mu for p in used], [p.var for p in used],
                              [p.var_err ** 2 for p in used])
    assert max(abs(p.var - f3.A * p.mu - f3.sigma_c2) / p.var_err for p in used) > 3.0
    assert list(cn.fit_points(two_off, robust=True).robust_dropped) == ref
    skew = [replace_point(p, mu_raw=p.mu + b) for p, b in zip(pts, [7.0, 7.5, 8.0, 8.5, 30.0])]
    assert cn.fit_points(skew).black_level_dn == pytest.approx(8.0)
    assert cn.fit_points(skew, black_level_dn=3.0).black_level_dn == 3.0


# --------------------------------------------------------------------------------------------
# gates: the photon-transfer gate
# --------------------------------------------------------------------------------------------


def _noise(points: list[pf.PtcPoint], *, A: float = 0.5, c: float = 4.0, A_err: float = 0.001,
           chi2: float = 3.0, dof: int = 3, Q: float = 0.5,
           fit_fraction: float | None = None) -> SimpleNamespace:
    """A stand-in photon-transfer result with the attributes the gate reads."""
    return SimpleNamespace(points=points, A=A, A_err=A_err, sigma_c2=c, sigma_c2_err=0.1,
                           chi2=chi2, dof=dof, Q=Q, fit_range="r", fit_fraction=fit_fraction)


def test_ptc_deviation_only_used_points_with_positive_line() -> None:
    """(σ² − line)/line over the used levels whose line is positive: min, max and the level of
    the largest |deviation|; none left gives (nan, nan, None)."""
    pts = [_pt(1, 10.0, 9.0 * 1.02), _pt(2, 20.0, 14.0 * 0.95), _pt(3, 40.0, 24.0 * 1.04),
           replace_point(_pt(4, 50.0, 100.0), used=False), _pt(5, -20.0, 3.0), _pt(6, -8.0, 3.0)]
    lo, hi, worst = cg.ptc_deviation(_noise(pts))      # levels 5, 6: line −6 and 0, skipped
    assert lo == pytest.approx(-0.05) and hi == pytest.approx(0.04) and worst.level == 2
    lo, hi, worst = cg.ptc_deviation(_noise([replace_point(p, used=False) for p in pts]))
    assert math.isnan(lo) and math.isnan(hi) and worst is None


def test_ptc_linearity_relative_least_squares() -> None:
    """The line a·μ_p + b minimising Σ((μ − a·μ_p − b)/μ)² (numpy polyfit with weights 1/μ)
    through the used points at or above 5 % of the largest μ; LE = extremes of (μ − fit)/fit;
    fewer than three such points, or one without photons, gives None."""
    ph = np.array([40.0, 100.0, 400.0, 1000.0, 2000.0])
    mu = np.array([20.0, 51.0, 199.0, 505.0, 990.0])     # 20 = 0.05·400? no: top is 990
    mu[0] = 0.05 * 990.0                                   # exactly 5 % of the top: included
    pts = [_pt(i + 1, m, 1.0, photons=p) for i, (m, p) in enumerate(zip(mu, ph))]
    a, b = np.polyfit(ph, mu, 1, w=1.0 / mu)
    rel = (mu - (a * ph + b)) / (a * ph + b)
    lo, hi = cg.ptc_linearity(_noise(pts))
    assert lo == pytest.approx(rel.min(), rel=1e-9) and hi == pytest.approx(rel.max(), rel=1e-9)
    below = [replace_point(pts[0], mu=0.049 * 990.0)] + pts[1:]
    a2, b2 = np.polyfit(ph[1:], mu[1:], 1, w=1.0 / mu[1:])
    rel2 = (mu[1:] - (a2 * ph[1:] + b2)) / (a2 * ph[1:] + b2)
    assert cg.ptc_linearity(_noise(below)) == pytest.approx((rel2.min(), rel2.max()), rel=1e-9)
    assert cg.ptc_linearity(_noise(pts[2:])) is not None
    assert cg.ptc_linearity(_noise(pts[3:])) is None
    assert cg.ptc_linearity(_noise(pts[:4] + [replace_point(pts[4], photons=None)])) is None


def test_band_limits_belong_to_the_better_band() -> None:
    """|x| = pass limit passes, |x| = fail limit warns, beyond fails (either sign)."""
    assert cg._band(-0.03, 0.03, 0.10) == cg.GateStatus.PASS
    assert cg._band(0.030001, 0.03, 0.10) == cg.GateStatus.WARN
    assert cg._band(-0.10, 0.03, 0.10) == cg.GateStatus.WARN
    assert cg._band(0.1001, 0.03, 0.10) == cg.GateStatus.FAIL


def _on_line(devs: list[float], A: float = 0.5, c: float = 4.0) -> list[pf.PtcPoint]:
    mus = [10.0, 40.0, 80.0, 120.0, 200.0][:len(devs)]
    return [_pt(i + 1, m, (A * m + c) * (1 + d), 0.1) for i, (m, d) in enumerate(zip(mus, devs))]


def test_ptc_gate_resolution_gain_error_and_fail_cases() -> None:
    """A 6 % deviation warns only when Q < Q_RESOLVED (Q exactly 0.01 is not resolved); σ(A)/A
    exactly 5 % passes, above warns, and the Birge ratio √(χ²/ν) multiplies it when χ²/ν > 1;
    fewer than 3 used levels, ν = 0 or a non-finite figure fail."""
    pts = _on_line([0.0, 0.06, 0.0, -0.01, 0.0])
    assert cg.ptc_gate(_noise(pts, Q=0.01)).status == cg.GateStatus.PASS
    g = cg.ptc_gate(_noise(pts, Q=0.0099, chi2=3.0))
    assert g.status == cg.GateStatus.WARN and "+6.00 %" in g.summary
    flat = _on_line([0.0] * 5)
    assert cg.ptc_gate(_noise(flat, A=2.0, A_err=0.1)).status == cg.GateStatus.PASS
    assert cg.ptc_gate(_noise(flat, A=2.0, A_err=0.1001)).status == cg.GateStatus.WARN
    # χ²/ν = 1.21: Birge 1.1 takes 0.095/2 = 4.75 % to 5.2 %
    assert cg.ptc_gate(_noise(flat, A=2.0, A_err=0.095, chi2=3.63)).status == cg.GateStatus.WARN
    assert cg.ptc_gate(_noise(flat, A=2.0, A_err=0.095, chi2=2.9)).status == cg.GateStatus.PASS
    # 4.3 % × 1.1 = 4.73 % passes (× 1.21, without the root, would warn)
    assert cg.ptc_gate(_noise(flat, A=2.0, A_err=0.086, chi2=3.63)).status == cg.GateStatus.PASS
    falling = _on_line([0.0] * 5, A=-0.01, c=50.0)      # a slope not positive: σ(A)/A = inf
    assert cg.ptc_gate(_noise(falling, A=-0.01, c=50.0)).status == cg.GateStatus.WARN
    assert cg.ptc_gate(_noise(flat[:2])).status == cg.GateStatus.FAIL
    assert cg.ptc_gate(_noise(flat, dof=0)).status == cg.GateStatus.FAIL
    for bad in ({"A": math.inf}, {"A_err": math.nan}, {"chi2": None}):
        assert cg.ptc_gate(_noise(flat, **bad)).status == cg.GateStatus.FAIL


def test_ptc_gate_near_saturation_advice_and_emva_linearity() -> None:
    """The advice to fit the EMVA range comes when the worst level's μ is at or above 70 % of
    the largest used μ (and no fit range is set); the datasheet's LE (in %) overrides the
    photon-count linearity and its band can worsen the status."""
    pts = _on_line([0.0, 0.0, 0.0, 0.0, 0.0])
    pts[3] = _pt(4, 140.0, (0.5 * 140.0 + 4.0) * 1.06, 0.1)   # 140 = 0.7 · 200
    g = cg.ptc_gate(_noise(pts, Q=0.001))
    assert g.status == cg.GateStatus.WARN
    assert any("near saturation" in n for n in g.next)
    g2 = cg.ptc_gate(_noise(pts, Q=0.001, fit_fraction=0.7))
    assert not any("near saturation" in n for n in g2.next)
    flat = _on_line([0.0] * 5)
    emva = SimpleNamespace(LE_min=-0.5, LE_max=2.0)
    g3 = cg.ptc_gate(_noise(flat), emva=emva)
    assert g3.status == cg.GateStatus.WARN and "+2.00 %" in g3.summary
    g4 = cg.ptc_gate(_noise(flat), emva=SimpleNamespace(LE_min=-3.5, LE_max=1.0))
    assert g4.status == cg.GateStatus.FAIL
    g5 = cg.ptc_gate(_noise(flat), emva=SimpleNamespace(LE_min=-1.0, LE_max=1.0))
    assert g5.status == cg.GateStatus.PASS


# --------------------------------------------------------------------------------------------
# capture: the plan's rules
# --------------------------------------------------------------------------------------------
from ccdcore import capture as cc  # noqa: E402


def _gls_slope_err(m: np.ndarray, v: np.ndarray) -> float:
    """√C₀₀ of the weighted line's covariance (Xᵀ W X)⁻¹, W = 1/v (numpy)."""
    X = np.column_stack([m, np.ones_like(m)])
    return float(math.sqrt(np.linalg.inv(X.T @ np.diag(1.0 / v) @ X)[0, 0]))


def test_predicted_gain_error_is_the_fit_covariance() -> None:
    """σ(A) on a ladder = √C₀₀ of (XᵀWX)⁻¹ with var σ²_N = 2σ⁴_N/(M − 1) at σ²_N = A(μ − b₀) +
    σ²_C (eq. 66); b₀ ≠ 0 shifts the abscissa; two levels and two pixels are the minimum."""
    mu = np.array([300.0, 900.0, 1700.0, 2500.0])
    A, c, M, b0 = 0.3, 12.0, 500, 100.0
    s2 = A * (mu - b0) + c
    ref = _gls_slope_err(mu - b0, 2 * s2 ** 2 / (M - 1))
    assert cc.predicted_gain_error(mu, A, c, M, b0) == pytest.approx(ref, rel=1e-10)
    assert cc.predicted_gain_error(mu[:2], A, c, 2, b0) == pytest.approx(
        _gls_slope_err(mu[:2] - b0, 2 * s2[:2] ** 2), rel=1e-10)
    for args in ((mu[:1], A, c, M), (mu, A, c, 1)):
        with pytest.raises(CcdError):
            cc.predicted_gain_error(*args)


def test_plan_dark_ptc_and_bracket_rules() -> None:
    """Darks s = max(16, ⌈σ²_C/0.1⌉) with σ²_C = (Aσ_R)² + 1/12; the ladder at b₀ + f·(full −
    b₀), f evenly 5 … 85 %, two frames a level, exposure t½·(μ − b₀)/(full/2 − b₀); σ(A)/A from
    eq. 66; the bracket ⌈log(0.25·R/0.9)/log r⌉ + 1 frames (at least 5) from 1.8·t½ by r."""
    A, rn, b0, t_half = 0.25, 20.0, 64.0, 0.02
    plan = cc.plan_captures(12, A, read_noise_e=rn, black_level=b0, pixels=1000,
                            exposure_half=t_half, ptc_levels=5, scene_range=1000.0,
                            bracket_ratio=2.0)
    c = (A * rn) ** 2 + 1 / 12
    assert plan.inputs["sigma_c2"] == pytest.approx(c)
    assert plan.group("Dark frames").count == math.ceil(c / 0.1)      # 251 > 16
    full = 4095.0
    mus = b0 + np.linspace(0.05, 0.85, 5) * (full - b0)
    ptc = plan.group("Photon transfer pairs").frames
    assert len(ptc) == 10 and ptc[2][1]["level"] == 2
    for k in range(5):
        want = t_half * (mus[k] - b0) / (0.5 * full - b0)
        assert ptc[2 * k][1]["exposure"] == pytest.approx(want, rel=1e-3)
        assert ptc[2 * k + 1][1]["exposure"] == ptc[2 * k][1]["exposure"]
    s2 = A * (mus - b0) + c
    assert plan.gain_rel_err == pytest.approx(
        _gls_slope_err(mus - b0, 2 * s2 ** 2 / 999) / A, rel=1e-9)
    br = plan.group("Exposure bracket").frames
    n = math.ceil(math.log(0.25 * 1000 / 0.9) / math.log(2.0)) + 1            # 10
    assert len(br) == n == 10
    assert br[0][1]["exposure"] == pytest.approx(1.8 * t_half)
    assert br[-1][1]["exposure"] == pytest.approx(1.8 * t_half * 2 ** (n - 1), rel=1e-6)
    small = cc.plan_captures(12, A, sigma_c2=1.0, scene_range=2.0, bracket_ratio=2.0)
    assert small.group("Dark frames").count == 16 and small.group("Exposure bracket").count == 5
    assert cc.plan_captures(12, A, sigma_c2=1.7).group("Dark frames").count == 17
    # 0.1·24 = 2.4000000000000004: σ²_C/0.1 is 24 plus a rounding error, still 24 frames
    assert cc.plan_captures(12, A, sigma_c2=0.1 * 24).group("Dark frames").count == 24


def test_plan_flat_rule() -> None:
    """Flats at exposures doubling from the 5 % one while the level stays ≤ 95 % of the range;
    the base is the level nearest 50 % and takes max(2, ⌈(100σ_N(μ_B)/(μ_B − b₀)/SNUP)²⌉)
    frames, the others 2; four darks per exposure."""
    A, c, b0, snup = 0.5, 30.0, 100.0, 0.2
    plan = cc.plan_captures(10, A, sigma_c2=c, black_level=b0, flat_noise_snup=snup)
    full = 1023.0
    fracs = [0.05 * 2 ** k for k in range(12) if 0.05 * 2 ** k <= 0.95]   # 5 … 80 %: 5 levels
    levels = [b0 + f * (full - b0) for f in fracs]
    base = int(np.argmin([abs(m - (b0 + 0.5 * (full - b0))) for m in levels]))
    mu_b = levels[base]
    n_base = max(2, math.ceil((100 * math.sqrt(A * (mu_b - b0) + c) / (mu_b - b0) / snup) ** 2))
    flats = plan.group("Flat fields").frames
    per = {}
    for path, keys in flats:
        per[keys["exposure"]] = per.get(keys["exposure"], 0) + 1
    counts = [per[t] for t in sorted(per)]
    assert len(counts) == len(fracs) == 5
    assert counts == [n_base if i == base else 2 for i in range(5)]
    assert plan.group("Flat-field dark frames").count == 4 * 5
    t = sorted(per)
    assert t[1] / t[0] == pytest.approx(2.0, rel=1e-3)
    loose = cc.plan_captures(10, A, sigma_c2=c, black_level=b0, flat_noise_snup=100.0)
    assert min(len([f for f in loose.group("Flat fields").frames if f[1]["exposure"] == e])
               for e in t) == 2                       # the base takes at least 2 frames


def test_plan_argument_limits() -> None:
    """bits 1 … 32, gain > 0 and finite, read noise ≥ 0 (0 accepted) or σ²_C > 0, black level
    in [0, full/2), at least 3 ladder levels, scene range and bracket ratio above 1, pixels ≥ 2
    and a positive exposure: each refused with the name at fault."""
    # 32 bits is the largest depth (checked on the sensor alone: a 32-bit plan is huge)
    assert cc._Sensor.checked(32, 0.5, None, 2.0, 0.0, 0.01, "tif").full == 2.0 ** 32 - 1
    ok = cc.plan_captures(8, 0.5, read_noise_e=0.0, black_level=0.0, ptc_levels=3, pixels=2)
    assert ok.inputs["sigma_c2"] == pytest.approx(1 / 12)
    assert ok.group("Photon transfer pairs").count == 6
    assert cc.plan_captures(8, 0.5, sigma_c2=2.0, black_level=127.0).camera["black_level"] == 127
    bad = [({"bits": 0}, "bits"), ({"bits": 33}, "bits"), ({"bits": 12.0}, "bits"),
           ({"gain": 0.0}, "gain"), ({"gain": math.inf}, "gain"),
           ({"read_noise_e": -1.0, "sigma_c2": None}, "read noise"),
           ({"read_noise_e": None, "sigma_c2": None}, "read noise"),
           ({"sigma_c2": 0.0}, "sigma_c2"), ({"sigma_c2": math.inf}, "sigma_c2"),
           ({"black_level": 127.5}, "black_level"), ({"black_level": -1.0}, "black_level"),
           ({"ptc_levels": 2}, "ptc_levels"), ({"scene_range": 1.0}, "plan"),
           ({"bracket_ratio": 1.0}, "plan"), ({"flat_noise_snup": 0.0}, "plan"),
           ({"pixels": 1}, "plan"), ({"exposure_half": 0.0}, "plan"),
           ({"layout": "hexagonal"}, "layout")]
    for kw, where in bad:
        args = {"bits": 8, "gain": 0.5, "sigma_c2": 2.0, **kw}
        with pytest.raises(CcdError) as err:
            cc.plan_captures(args.pop("bits"), args.pop("gain"), **args)
        assert err.value.where == where, kw


def test_plan_predicted_sigma_hat() -> None:
    """Without a pilot, σ̂ = √(σ²_N(μ_K)/n2 + σ²_N(b₀)/s)/(μ_K − b₀) at the card level μ_K =
    b₀ + 0.75·(full − b₀) (module docstring); a pilot's σ̂ replaces it."""
    A, c, b0 = 0.4, 9.0, 50.0
    plan = cc.plan_captures(12, A, sigma_c2=c, black_level=b0)
    mu_k = b0 + 0.75 * (4095.0 - b0)
    n2 = plan.fixed_pattern.n2_required
    s = plan.group("Dark frames").count
    want = math.sqrt((A * (mu_k - b0) + c) / n2 + c / s) / (mu_k - b0)
    assert plan.sigma_hat == pytest.approx(want, rel=1e-12)
    fpg = plan.group("Fixed-pattern configurations")
    assert fpg.count == plan.fixed_pattern.n1_required * n2
    assert fpg.frames[0][1]["exposure"] == pytest.approx(0.01 * (mu_k - b0) / (2047.5 - b0),
                                                         rel=1e-3)


# --------------------------------------------------------------------------------------------
# emva.fits: the closed-form fits, the threshold and range, σ_d, the linearity, DSNU/PRNU
# --------------------------------------------------------------------------------------------
from ccdcore.emva import fits as ef  # noqa: E402
from ccdcore.emva.results import DarkPoint, SpatialSet  # noqa: E402


def _wls(X: np.ndarray, y: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, float]:
    """Weighted least squares (numpy normal equations): coefficients and χ²."""
    W = np.diag(1.0 / v)
    beta = np.linalg.solve(X.T @ W @ X, X.T @ W @ y)
    r = y - X @ beta
    return beta, float(r @ W @ r)


def test_line_through_origin_slope_error_and_birge() -> None:
    """m = Σxy/Σx²; error √(Σx²var)/Σx² times √(χ²/ν) of the weighted line through the origin
    with ν = n − 1 when above 1; a zero error leaves it unscaled; Σx² = 0 gives NaN."""
    x = np.array([1.0, 2.0, 4.0, 7.0])
    v = np.array([0.01, 0.04, 0.09, 0.25])
    for y in (np.array([2.1, 3.9, 8.3, 13.6]), np.array([2.01, 4.0, 7.99, 14.02])):
        m, err = ef._line_b0(x, y, v)
        assert m == pytest.approx(np.sum(x * y) / np.sum(x * x), rel=1e-12)
        _, chi2 = _wls(x[:, None], y, v)
        base = math.sqrt(np.sum(x * x * v)) / np.sum(x * x)
        assert err == pytest.approx(base * math.sqrt(max(chi2 / 3, 1.0)), rel=1e-9)
    v0 = np.array([0.01, 0.0, 0.09, 0.25])
    _, err0 = ef._line_b0(x, np.array([2.1, 3.9, 8.3, 13.6]), v0)
    assert err0 == pytest.approx(math.sqrt(np.sum(x * x * v0)) / np.sum(x * x), rel=1e-12)
    assert all(math.isnan(t) for t in ef._line_b0(np.zeros(3), np.ones(3), np.ones(3)))


def test_line_intercept_error_and_birge() -> None:
    """Intercept b = Σcᵢyᵢ, cᵢ = 1/n − x̄(xᵢ − x̄)/Sxx, error √Σcᵢ²varᵢ scaled by √(χ²/ν) of the
    weighted line with ν = n − 2 (numpy polyfit and normal equations)."""
    x = np.array([0.5, 1.0, 2.0, 4.0, 8.0])
    v = np.array([0.01, 0.02, 0.04, 0.1, 0.3])
    for y in (np.array([3.0, 3.6, 4.1, 6.4, 10.5]), np.array([3.0, 3.5, 4.0, 5.0, 7.0])):
        slope, icpt, err = ef._line_b_intercept(x, y, v)
        ps, pi = np.polyfit(x, y, 1)
        assert slope == pytest.approx(ps, rel=1e-10) and icpt == pytest.approx(pi, rel=1e-10)
        X = np.column_stack([x, np.ones_like(x)])
        _, chi2 = _wls(X, y, v)
        c = np.linalg.pinv(X)[1]                      # the intercept's row of the OLS map
        base = math.sqrt(np.sum(c * c * v))
        assert err == pytest.approx(base * math.sqrt(max(chi2 / 3, 1.0)), rel=1e-9)


def test_linearity_fit_is_relative_least_squares() -> None:
    """The closed form equals numpy's polyfit with weights 1/y (Σ((y − ax − b)/y)²)."""
    x = np.array([10.0, 30.0, 50.0, 80.0, 120.0])
    y = np.array([5.5, 14.0, 26.0, 39.0, 61.0])
    a, b = ef._linearity_fit(x, y)
    pa, pb = np.polyfit(x, y, 1, w=1.0 / y)
    assert a == pytest.approx(pa, rel=1e-9) and b == pytest.approx(pb, rel=1e-7)


def test_saturation_index_walks_back_to_the_peak() -> None:
    """Walking back, the largest σ² before two consecutive points fall below it: a plateau
    after the peak stops the search there; a monotone curve ends at its last point."""
    assert ef._saturation_index(np.array([1.0, 2.0, 3.0, 4.0])) == 3
    assert ef._saturation_index(np.array([1.0, 2.0, 5.0, 3.0, 2.0])) == 2
    # a local peak at 4 followed by a deeper dip, then the global peak earlier: stops at 4
    assert ef._saturation_index(np.array([1.0, 9.0, 2.0, 1.0, 6.0, 5.0])) == 4
    assert ef._saturation_index(np.array([3.0, 3.0])) == 0
    # a tie on the peak: the walk takes the earlier of the two equal points
    assert ef._saturation_index(np.array([1.0, 2.0, 5.0, 5.0, 1.0])) == 2


def _sens(R: float = 0.2, R_err: float = 0.004, K: float = 0.5, K_err: float = 0.01,
          i_sat: int = 3) -> ef.Sensitivity:
    QE = 100.0 * R / K
    return ef.Sensitivity(i_sat, i_sat - 1, R, R_err, K, K_err, QE,
                          QE * math.hypot(R_err / R, K_err / K))


def _dn(sigma: float = 1.5, sigma_err: float = 0.05) -> ef.DarkNoise:
    return ef.DarkNoise(sigma, sigma_err, sigma, 10.0, 0.1, 2.0, 0.1, False)


def test_threshold_and_range_values_and_errors() -> None:
    """μ_p.min = (σ_y.dark + K/2)/R with the first-order error of σ_y.dark, K and R; μ_p.sat
    the saturation point's μ_p with error (local spacing)/√12; μ_e.sat = η μ_p.sat, SNR_max =
    √μ_e.sat with error err/(2 SNR); DR = μ_p.sat/μ_p.min, in dB 20 log₁₀ DR with error
    (20/ln 10)·DR_err/DR."""
    u_p = np.array([100.0, 300.0, 600.0, 1000.0, 1600.0])
    s, d = _sens(), _dn()
    r = ef.threshold_and_range(u_p, s, d)
    u_min = (1.5 + 0.25) / 0.2
    assert r.u_p_min == pytest.approx(u_min)
    g = _num_grad_vec(lambda p: (p[0] + p[1] / 2) / p[2], np.array([1.5, 0.5, 0.2]))
    assert r.u_p_min_err == pytest.approx(
        math.sqrt(g[0] ** 2 * 0.05 ** 2 + g[1] ** 2 * 0.01 ** 2 + g[2] ** 2 * 0.004 ** 2),
        rel=1e-5)
    assert r.u_p_sat == 1000.0
    assert r.u_p_sat_err == pytest.approx((1600.0 - 600.0) / 2 / math.sqrt(12))
    eta = 0.4
    assert r.u_e_sat == pytest.approx(eta * 1000.0)
    assert r.u_e_sat_err == pytest.approx(
        math.hypot(1000.0 * s.QE_err / 100, eta * r.u_p_sat_err))
    assert r.SNR_max == pytest.approx(math.sqrt(400.0))
    assert r.SNR_max_err == pytest.approx(r.u_e_sat_err / (2 * 20.0))
    assert r.DR == pytest.approx(1000.0 / u_min)
    assert r.DR_err == pytest.approx(r.DR * math.hypot(r.u_p_min_err / u_min,
                                                       r.u_p_sat_err / 1000.0))
    assert r.DR_dB == pytest.approx(20 * math.log10(r.DR))
    assert r.DR_dB_err == pytest.approx(20 / math.log(10) * r.DR_err / r.DR)
    last = ef.threshold_and_range(u_p, _sens(i_sat=4), d)
    assert last.u_p_sat_err == pytest.approx(600.0 / math.sqrt(12))
    first = ef.threshold_and_range(u_p, _sens(i_sat=0), d)
    assert first.u_p_sat_err == pytest.approx(200.0 / math.sqrt(12))


def _num_grad_vec(f, x: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Central finite-difference gradient, steps relative to each coordinate."""
    g = np.zeros_like(x)
    for i in range(x.size):
        h = 1e-6 * abs(x[i])
        d = np.zeros_like(x)
        d[i] = h
        g[i] = (f(x + d) - f(x - d)) / (2 * h)
    return g


def _darks(s2: list[float], s2_err: list[float], t: list[float | None]) -> list[DarkPoint]:
    return [DarkPoint(exposure=ti, u_y_dark=10.0 + i, u_y_dark_err=0.01 * (i + 1), s2_y_dark=v,
                      s2_y_dark_err=e, relpaths=("a", "b"))
            for i, (v, e, ti) in enumerate(zip(s2, s2_err, t))]


def test_dark_noise_sigma_d_floor_and_quantisation() -> None:
    """σ_d = √(σ²_y.dark − 1/12)/K with error hypot(err/(2K√excess), σ_d·K_err/K); σ_y.dark's
    error err/(2σ_y.dark); below the floor 0.24 DN² σ²_y.dark is floored (error NaN); below
    0.5 DN (measured) the noise is quantisation limited; two exposure times use the shortest."""
    s = _sens(K=0.5, K_err=0.01)
    notes: list[str] = []
    dn = ef.dark_noise(_darks([2.0, 2.5], [0.1, 0.1], [0.01, 0.02]), s, notes)
    ex = 2.0 - 1 / 12
    assert dn.sigma_y_dark == pytest.approx(math.sqrt(2.0))
    assert dn.sigma_y_dark_err == pytest.approx(0.1 / (2 * math.sqrt(2.0)))
    assert dn.sigma_d == pytest.approx(math.sqrt(ex) / 0.5)
    assert dn.sigma_d_err == pytest.approx(math.hypot(0.1 / (2 * 0.5 * math.sqrt(ex)),
                                                      dn.sigma_d * 0.02))
    assert dn.u_dark == 10.0 and not dn.quantisation_limited and notes == []
    low = ef.dark_noise(_darks([0.2, 0.3], [0.01, 0.01], [0.01, 0.02]), s, notes)
    assert low.sigma_y_dark == pytest.approx(math.sqrt(0.24)) and math.isnan(low.sigma_d_err)
    assert low.sigma_y_dark_measured == pytest.approx(math.sqrt(0.2))
    assert low.quantisation_limited and len(notes) == 2
    at = ef.dark_noise(_darks([0.25, 0.3], [0.01, 0.01], [0.01, 0.02]), s, [])
    assert at.quantisation_limited is False         # √0.25 = 0.5 DN: not below the limit
    assert math.isfinite(at.sigma_y_dark_err)        # 0.25 ≥ 0.24: not floored
    edge = ef.dark_noise(_darks([0.24, 0.3], [0.01, 0.01], [0.01, 0.02]), s, [])
    assert edge.sigma_y_dark_err == pytest.approx(0.01 / (2 * math.sqrt(0.24)))   # at the floor


def test_dark_level_extrapolates_with_three_exposures() -> None:
    """Three or more exposure times: μ_y.dark and σ²_y.dark are the intercepts of the lines
    against t (numpy polyfit); exactly two take the shortest point."""
    t = [0.01, 0.02, 0.05]
    pts = _darks([2.0, 2.2, 2.9], [0.1, 0.1, 0.1], t)
    (s2, _), (u, u_err), rule = ef._dark_level(pts)
    assert s2 == pytest.approx(np.polyfit(t, [2.0, 2.2, 2.9], 1)[1], rel=1e-10)
    assert u == pytest.approx(np.polyfit(t, [10.0, 11.0, 12.0], 1)[1], rel=1e-10)
    assert "extrapolated" in rule
    (s2b, _), _, _ = ef._dark_level(pts[:2])
    assert s2b == 2.0
    (s2n, _), _, rule_n = ef._dark_level(_darks([2.0, 2.2, 2.9], [0.1] * 3, [0.01, None, 0.05]))
    assert s2n == 2.0 and "unknown" not in rule_n


def _spatial(u_y: float, s2: float, s2_err: float, L: int, s2_stack: float,
             n: int = 1000) -> SpatialSet:
    return SpatialSet(level=1, exposure=0.01, L=L, u_p=1000.0, u_y=u_y, s2_stack=s2_stack,
                      s2_measured=s2 + s2_stack / L, s2=s2, s2_err=s2_err, n_pixels=n)


def test_nonuniformity_dsnu_prnu_and_errors() -> None:
    """DSNU = √s²_dark/K with error DSNU·hypot(err/(2s²), K_err/K); PRNU = 100√(s²_b − s²_d)/(μ_b −
    μ_d) with error PRNU·hypot(hypot(err_b, err_d)/(2 diff), σ(signal)/signal), σ(signal)² =
    s²_stack/(L·N) of both sets; a negative dark variance or no excess gives NaN."""
    sp = _spatial(600.0, 40.0, 2.0, 8, 50.0, 900)
    spd = _spatial(100.0, 4.0, 0.3, 5, 9.0, 900)
    d, de, p, pe = ef.nonuniformity(sp, spd, 0.5, 0.02, [])
    assert d == pytest.approx(2.0 / 0.5)
    assert de == pytest.approx(4.0 * math.hypot(0.3 / 8.0, 0.04))
    assert p == pytest.approx(100 * 6.0 / 500.0)
    sig = math.sqrt(50.0 / (8 * 900) + 9.0 / (5 * 900))
    assert pe == pytest.approx(p * math.hypot(math.hypot(2.0, 0.3) / 72.0, sig / 500.0))
    notes: list[str] = []
    d2, de2, p2, pe2 = ef.nonuniformity(_spatial(600.0, 3.0, 1.0, 8, 50.0),
                                        _spatial(100.0, -1.0, 0.3, 5, 9.0), 0.5, 0.0, notes)
    assert math.isnan(d2) and math.isnan(de2) and p2 == pytest.approx(100 * 2.0 / 500.0)
    assert len(notes) == 1
    d3, de3, p3, _ = ef.nonuniformity(_spatial(600.0, 4.0, 1.0, 8, 50.0),
                                      _spatial(100.0, 0.0, 0.3, 5, 9.0), 0.5, 0.0, [])
    assert d3 == 0.0 and math.isnan(de3)
    _, _, p4, pe4 = ef.nonuniformity(_spatial(600.0, 4.0, 1.0, 8, 50.0),
                                     _spatial(100.0, 4.0, 0.3, 5, 9.0), 0.5, 0.0, [])
    assert p4 == 0.0 and math.isnan(pe4)


def test_linearity_range_and_error_propagation() -> None:
    """The fit uses the points with Y from 5 % to 95 % of Y_sat (both limits included); LE =
    100 (Y − fit)/fit at its extremes; their errors are the first-order propagation of var_Y
    through the relative least-squares fit (here numpy's polyfit, differentiated numerically)."""
    u_p = np.array([10.0, 50.0, 100.0, 200.0, 400.0, 700.0, 800.0])
    Y = np.array([0.5, 4.9, 10.2, 19.7, 40.3, 66.5, 70.0])
    Y[0] = 0.05 * 70.0                                 # exactly 5 %: inside
    Y[5] = 0.95 * 70.0                                 # exactly 95 %: inside
    var_Y = np.array([0.01, 0.02, 0.03, 0.05, 0.1, 0.2, 0.3])
    first, last, a, b, (lmin, lmin_e), (lmax, lmax_e) = ef.linearity(u_p, Y, var_Y, 6, "x")
    assert (first, last) == (0, 5)
    lin = slice(0, 6)

    def dev(y: np.ndarray) -> np.ndarray:
        pa, pb = np.polyfit(u_p[lin], y[lin], 1, w=1.0 / y[lin])
        return 100 * (y[lin] - (pa * u_p[lin] + pb)) / (pa * u_p[lin] + pb)

    d0 = dev(Y)
    assert lmin == pytest.approx(d0.min(), rel=1e-6) and lmax == pytest.approx(d0.max(), rel=1e-6)
    J = np.zeros((6, 7))
    for j in range(6):
        h = 1e-5 * Y[j]
        up, dn = Y.copy(), Y.copy()
        up[j] += h
        dn[j] -= h
        J[:, j] = (dev(up) - dev(dn)) / (2 * h)
    err = np.sqrt((J * J) @ var_Y)
    assert lmin_e == pytest.approx(err[np.argmin(d0)], rel=1e-4)
    assert lmax_e == pytest.approx(err[np.argmax(d0)], rel=1e-4)
    for y3 in ([0.1, 0.2, 70.0], [0.1, 30.0, 70.0]):    # no point, exactly one point in range
        with pytest.raises(CcdError):
            ef.linearity(u_p[:3], np.array(y3), var_Y[:3], 2, "x")


def test_sensitivity_fit_range_and_qe_error() -> None:
    """The fits of R (Y against μ_p) and K (S against Y) through the origin use the points up to
    the last with Y ≤ 70 % of Y_sat (exactly 70 % included); QE = 100 R/K with error
    QE·hypot(R_err/R, K_err/K); a single point below 70 % is refused."""
    u_p = np.array([100.0, 200.0, 400.0, 700.0, 900.0, 1000.0])
    Y = np.array([20.5, 39.0, 81.0, 140.0, 180.0, 200.0])
    Y[3] = 0.7 * 200.0
    S = np.array([10.0, 20.5, 39.0, 71.0, 88.0, 101.0])
    s2_y = S + 4.0
    c = ef.Curves(u_p, Y, np.array([0.5, 0.6, 1.0, 1.5, 2.0, 2.2]), S,
                  np.array([0.2, 0.4, 0.9, 1.6, 2.0, 2.5]), s2_y)
    raw = [SimpleNamespace(level=k + 1) for k in range(6)]
    s = ef.sensitivity(c, raw, "x", [])
    assert (s.i_sat, s.i_fit) == (5, 3)
    R, R_err = ef._line_b0(u_p[:4], Y[:4], c.var_Y[:4])
    K, K_err = ef._line_b0(Y[:4], S[:4], c.var_S[:4])
    assert s.R == pytest.approx(np.sum(u_p[:4] * Y[:4]) / np.sum(u_p[:4] ** 2))
    assert (s.R_err, s.K, s.K_err) == pytest.approx((R_err, K, K_err))
    assert s.QE == pytest.approx(100 * R / K)
    assert s.QE_err == pytest.approx(s.QE * math.hypot(R_err / R, K_err / K))
    one = ef.Curves(u_p[:3], np.array([20.0, 150.0, 200.0]), c.var_Y[:3], S[:3], c.var_S[:3],
                    s2_y[:3])
    with pytest.raises(CcdError):
        ef.sensitivity(one, raw[:3], "x", [])


def test_ptc_read_noise_agreement_boundary() -> None:
    """σ_d from the darks and from photon transfer agree when |Δ| ≤ DISAGREEMENT_Z·hypot of
    their errors (exactly 3 included, with no note); beyond, a note; an unresolved σ_R gives K
    alone."""
    dark = ef.DarkNoise(1.5, 0.05, 1.5, 10.0, 0.1, 2.0, 0.3, False)
    notes: list[str] = []
    ok = ef.ptc_read_noise(None, SimpleNamespace(A=0.5, A_err=0.01, read_noise_e=3.5,
                                                 read_noise_e_err=0.4), False, dark, notes)
    assert ok.consistent is True and ok.sigma_d == 3.5 and ok.K == 0.5 and notes == []
    bad = ef.ptc_read_noise(None, SimpleNamespace(A=0.5, A_err=0.01, read_noise_e=3.51,
                                                  read_noise_e_err=0.4), False, dark, notes)
    assert bad.consistent is False and len(notes) == 1
    un = ef.ptc_read_noise(None, SimpleNamespace(A=0.5, A_err=0.01, read_noise_e=math.nan,
                                                 read_noise_e_err=math.nan), False, dark, [])
    assert un.K == 0.5 and un.sigma_d is None and un.consistent is None
    assert ef.ptc_read_noise(None, None, False, dark, []) == ef.PtcReadNoise()


def test_spatial_section_needs_ten_pixels_a_side() -> None:
    """The split and plots need two equal images at least 2·5 pixels a side (10 accepted, 9
    refused with a note); without images nothing is computed."""
    rng = np.random.default_rng(12)

    def sset(img: np.ndarray | None, u: float) -> SpatialSet:
        return SpatialSet(level=1, exposure=0.01, L=4, u_p=1.0, u_y=u, s2_stack=4.0,
                          s2_measured=1.0, s2=1.0, s2_err=0.1, n_pixels=100, image=img)

    b, d = rng.normal(500, 3, (10, 12)), rng.normal(100, 1, (10, 12))
    split, plots = ef.spatial_section(sset(b, 500.0), sset(d, 100.0), 0.5, 0.01, 2.0, 1.0, [])
    assert split is not None and plots is not None
    assert split.bright.M == 10 and split.bright.N == 12
    notes: list[str] = []
    assert ef.spatial_section(sset(b[:9], 500.0), sset(d[:9], 100.0), 0.5, 0.01, None, None,
                              notes) == (None, None)
    assert len(notes) == 1
    assert ef.spatial_section(sset(b, 500.0), sset(d[:, :11], 100.0), 0.5, 0.01, None, None,
                              []) == (None, None)
    assert ef.spatial_section(sset(None, 500.0), sset(d, 100.0), 0.5, 0.01, None, None,
                              []) == (None, None)


def test_ptc_linearity_degenerate_inputs_and_negative_gain() -> None:
    """No used level, a non-positive mean among the fitted ones or all photon counts equal give
    no linearity; a fitted K not positive is refused by the sensitivity step."""
    pts = [_pt(i + 1, m, 1.0, photons=p) for i, (m, p) in
           enumerate(zip([50.0, 100.0, 200.0], [100.0, 200.0, 400.0]))]
    assert cg.ptc_linearity(_noise([replace_point(p, used=False) for p in pts])) is None
    assert cg.ptc_linearity(_noise([replace_point(p, photons=100.0) for p in pts])) is None
    zero = [replace_point(p, mu=0.0) for p in pts]     # all pass the 5 % rule, none > 0
    assert cg.ptc_linearity(_noise(zero)) is None
    u_p = np.array([100.0, 200.0, 400.0, 500.0])
    Y = np.array([20.0, 40.0, 80.0, 100.0])
    S = np.array([-10.0, -20.0, -40.0, -50.0])
    c = ef.Curves(u_p, Y, np.ones(4), S, np.ones(4), np.array([1.0, 2.0, 3.0, 4.0]))
    with pytest.raises(CcdError):
        ef.sensitivity(c, [SimpleNamespace(level=k) for k in range(4)], "x", [])


def test_measured_levels_average_pairs_and_their_error(tmp_path: Path) -> None:
    """A level's σ̂²_N is the mean of its disjoint pairs' estimates and its error
    √(2σ̂⁴/(n_pairs·(M − 1))) (eq. 40 for a mean of n_pairs estimates); μ − b₀ with the
    manifest's black level; an odd last frame is left out with a note (frames 0-1, 2-3)."""
    import tomli_w

    from ccdcore.io.frames import write_image
    from ccdcore import stats as cst

    rng = np.random.default_rng(31)
    frames, data = [], {}
    for level, n, mean, t in ((1, 4, 300.0, 0.01), (2, 3, 820.0, 0.03), (3, 2, 1860.0, 0.07)):
        for j in range(n):
            img = np.round(rng.normal(mean, math.sqrt(0.5 * mean), (4, 6))).astype(np.uint16)
            rel = f"ptc/L{level}_{j}.tif"
            write_image(tmp_path / rel, img, exposure=t)
            frames.append({"path": rel, "role": "ptc", "level": level, "exposure": t})
            data.setdefault(level, []).append(img)
    (tmp_path / "session.toml").write_text(tomli_w.dumps(
        {"schema": 1, "camera": {"name": "s", "bits": 12, "layout": "mono", "black_level": 40.0},
         "frames": frames}))
    pts = {p.level: p for p in cn.ptc_points(tmp_path)}
    for level, imgs in data.items():
        pairs = [cst.pair_statistics(imgs[i], imgs[i + 1]) for i in range(0, len(imgs) - 1, 2)]
        var = float(np.mean([v for _, v, _, _ in pairs]))
        mu = float(np.mean([m for m, _, _, _ in pairs]))
        p = pts[level]
        assert p.n_pairs == len(pairs) and p.n_pixels == 24
        assert p.var == pytest.approx(var, rel=1e-12)
        assert p.mu_raw == pytest.approx(mu, rel=1e-12) and p.mu == pytest.approx(mu - 40.0)
        assert p.var_err == pytest.approx(math.sqrt(2 * var ** 2 / (len(pairs) * 23)), rel=1e-12)
    pt = cn.photon_transfer(tmp_path)
    assert any("ptc level 2: 3 frames" in n for n in pt.notes)


def test_photon_transfer_refit_summary_and_model() -> None:
    """σ²_N(μ) = A·μ + σ²_C; refit keeps the fit range by default ("same") and takes a new one
    when given; the summary round-trips through from_summary; the fit property carries the
    covariance (its predict band at μ = 0 is σ(σ²_C))."""
    pts = _line_points(0.37, 5.0, [20.0, 60.0, 150.0, 300.0, 500.0],
                       offsets=[0.05, -0.2, 0.4, -0.9, 1.5])
    r = cn.fit_points(pts, fit_fraction=0.8)
    assert r.sigma_n2(100.0) == pytest.approx(r.A * 100.0 + r.sigma_c2)
    np.testing.assert_allclose(r.sigma_n2([0.0, 10.0]), [r.sigma_c2, r.A * 10 + r.sigma_c2])
    assert r.refit().fit_fraction == 0.8
    assert r.refit(fit_fraction=None).fit_fraction is None
    # the saturation signal is that of level 5 (largest σ²): 500 > 0.8 · 500, so it is out
    assert sorted(p.level for p in r.points if not p.used) == [5]
    s = r.summary()
    back = cn.PhotonTransfer.from_summary(s)
    assert back.summary() == s and back.A == r.A
    assert r.fit.predict(0.0)[1] == pytest.approx(r.sigma_c2_err)


def test_capture_text_helpers() -> None:
    """Times below 1 s in ms, from 1 s in s; TOML values: booleans before ints, floats to six
    significant digits, strings with quotes and backslashes escaped; the plan's TOML parses back
    with every frame of every group."""
    import tomllib

    assert cc._fmt_s(0.999) == "999 ms" and cc._fmt_s(1.0) == "1 s"
    assert cc._toml_value(True) == "true" and cc._toml_value(3) == "3"
    assert cc._toml_value(0.1234567891) == "0.123457"
    assert cc._toml_value('a"b\\c') == '"a\\"b\\\\c"'
    plan = cc.plan_captures(8, 0.5, sigma_c2=2.0, name='cam "x"')
    doc = tomllib.loads(plan.to_toml())
    assert doc["camera"]["name"] == 'cam "x"'
    assert len(doc["frames"]) == plan.n_frames == sum(g.count for g in plan.groups)


def test_gate_record_words() -> None:
    """A bare status string becomes its member (another string is refused); the line is
    "<label>: <summary>" with the documented labels; to_dict carries the value and lists."""
    g = cg.Gate("warn", "s", ("r",), ("n",))
    assert g.status is cg.GateStatus.WARN and g.line() == "Passed with warnings: s"
    assert g.to_dict() == {"status": "warn", "label": "Passed with warnings", "summary": "s",
                           "reasons": ["r"], "next": ["n"]}
    assert cg.Gate("skip", "x").label == "Skipped" and cg.Gate("fail", "x").label == "Failed"
    with pytest.raises(ValueError):
        cg.Gate("ok", "x")
    assert cg.pct(0.05) == "5 %" and cg.pct(0.012345) == "1.23 %"
    assert not cg._finite(None) and not cg._finite("a") and not cg._finite(math.inf)
    assert cg._finite("2.5")
