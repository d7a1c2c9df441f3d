"""Edges of the response modules: the prediction agreement (ccdcore.response.agreement), the gauge,
noise fit and notes of the sec. 3.2 fit (ccdcore.response.tsin.gauge, .noise, .notes), the verdict
thresholds (ccdcore.response.verdict) and the handheld simulation geometry
(ccdcore.simulate.handheld).

Every expectation is derived by hand from the docstrings / Tsin et al. (2001) equations or from
a brute-force numpy reference computed in the test on the same data; the data avoid the
degenerate cases that hide bugs (unequal exposure ratios, non-zero offsets, rectangular frames,
codes exactly at the limits of the readable range).
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from ccdcore.errors import CcdError
from ccdcore.response import agreement as agm
from ccdcore.response import verdict as vd
from ccdcore.response.brackets import BracketData
from ccdcore.response.tsin import estimator as est
from ccdcore.response.tsin import gauge, noise, notes
from ccdcore.simulate import handheld as hh
from ccdcore.simulate._common import round_sig

# ----------------------------------------------------------------------------------------------
# agreement (Tsin et al. sec. 4.2)

G_CURVE = (np.arange(256) / 255.0) ** 1.6 + 0.05 * np.arange(256) / 255.0   # strictly rising
A_EXP = np.array([1.0, 2.7, 6.1])
B_OFF = np.array([0.01, -0.015, 0.02])


def _f(signal: np.ndarray) -> np.ndarray:
    """The inverse of the strictly rising G_CURVE (code as a real number), clipped to 0..255."""
    return np.interp(signal, G_CURVE, np.arange(256.0))


def _bracket(P: int = 600, seed: int = 5) -> BracketData:
    """Three images of P pixels from the curve with gains A_EXP and offsets B_OFF, 0.7 DN noise;
    a few pixels read exactly the limits 10 and 245 of the readable range (and 9, 246)."""
    rng = np.random.default_rng(seed)
    E = rng.uniform(0.0, 0.2, P)
    z = np.stack([np.clip(np.rint(_f(A_EXP[k] * E + B_OFF[k]) + rng.normal(0, 0.7, P)), 0, 255)
                  for k in range(3)]).astype(np.int32)
    z[0, :4] = [10, 245, 9, 246]
    z[1, :4] = [10, 245, 9, 246]
    z[1, 4:8] = [10, 245, 9, 246]
    z[2, 4:8] = [12, 240, 20, 30]
    return BracketData(z, np.ones_like(z, bool), np.array([1.0, 2.5, 6.0]), 256)


def _pair_sse(z: np.ndarray, j: int, r: float, lo: int = 10, hi: int = 245) -> tuple[float, int]:
    """Brute force: both directions' squared prediction errors of pair (j, j+1) at ratio r."""
    k = j + 1
    m = (z[j] >= lo) & (z[j] <= hi) & (z[k] >= lo) & (z[k] <= hi)
    zj, zk = z[j, m], z[k, m]
    pk = _f(r * (G_CURVE[zj] - B_OFF[j]) + B_OFF[k])
    pj = _f((G_CURVE[zk] - B_OFF[k]) / r + B_OFF[j])
    return float(((pk - zk) ** 2).sum() + ((pj - zj) ** 2).sum()), 2 * int(m.sum())


def _blend_sse(z: np.ndarray, lo: int = 10, hi: int = 245) -> tuple[float, int]:
    """Brute force of eq. 9 with eq. 18's weights a_i / g'(z_i), per pixel and image."""
    slope = np.gradient(G_CURVE)
    sse, n = 0.0, 0
    for p in range(z.shape[1]):
        for k in range(3):
            if not lo <= z[k, p] <= hi:
                continue
            num = den = 0.0
            for i in range(3):
                if i != k and lo <= z[i, p] <= hi:
                    w = A_EXP[i] / slope[z[i, p]]
                    num += w * (G_CURVE[z[i, p]] - B_OFF[i]) / A_EXP[i]
                    den += w
            if den > 0:
                e = _f(A_EXP[k] * num / den + B_OFF[k]) - z[k, p]
                sse += e * e
                n += 1
    return sse, n


def test_agreement_matches_brute_force_with_offsets_and_unequal_ratios():
    """rms (own ratios a_k/a_j, offsets b), rms_blend (eq. 9 / 18) and the counts equal a
    per-pixel brute force; the fitted ratio minimises the pair's brute-force cost."""
    data = _bracket()
    c = agm.channel_agreement(data, G_CURVE, A_EXP, B_OFF)
    sse = n = 0
    for j, p in enumerate(c.pairs):
        s, m = _pair_sse(data.z, j, A_EXP[j + 1] / A_EXP[j])
        assert (p.j, p.k, p.n) == (j, j + 1, m)
        assert p.ratio == pytest.approx(A_EXP[j + 1] / A_EXP[j], rel=1e-12)
        assert p.rms == pytest.approx(math.sqrt(s / m), rel=1e-9)
        sf, _ = _pair_sse(data.z, j, p.ratio_fitted)
        assert p.rms_fitted == pytest.approx(math.sqrt(sf / m), rel=1e-6)
        assert sf <= s + 1e-9
        for step in (1.003, 1 / 1.003):
            assert _pair_sse(data.z, j, p.ratio_fitted * step)[0] >= sf - 1e-6
        sse, n = sse + s, n + m
    assert c.n == n and c.rms == pytest.approx(math.sqrt(sse / n), rel=1e-9)
    sb, nb = _blend_sse(data.z)
    assert c.n_blend == nb
    assert c.rms_blend == pytest.approx(math.sqrt(sb / nb), rel=1e-9)


def test_agreement_default_exposures_and_offsets_are_the_nominal_times_and_zero():
    """a defaults to the nominal times t (not the ratio 1) and b to 0 (docstring)."""
    data = _bracket()
    c = agm.channel_agreement(data, G_CURVE)
    assert [p.ratio for p in c.pairs] == pytest.approx([2.5, 2.4], rel=1e-12)
    explicit = agm.channel_agreement(data, G_CURVE, data.t, np.zeros(3))
    assert c.rms == explicit.rms and c.rms_blend == explicit.rms_blend


def test_agreement_pools_channels_of_different_sizes_by_their_sums():
    """The pooled RMS is sqrt(Σ sse / Σ n) over the channels, not the mean of their RMS."""
    d1, d2 = _bracket(600, 5), _bracket(250, 9)
    r = {"g": G_CURVE, "a": A_EXP, "b": B_OFF}
    ag = agm.agreement({"R": d1, "G": d2}, {"R": r, "G": SimpleNamespace(**r)})
    c1, c2 = ag["R"], ag["G"]
    assert ag.rms == pytest.approx(math.sqrt((c1.sse + c2.sse) / (c1.n + c2.n)), rel=1e-12)
    assert ag.rms_fitted == pytest.approx(
        math.sqrt((c1.sse_fitted + c2.sse_fitted) / (c1.n + c2.n)), rel=1e-12)
    assert ag.rms_blend == pytest.approx(
        math.sqrt((c1.sse_blend + c2.sse_blend) / (c1.n_blend + c2.n_blend)), rel=1e-12)
    assert c1.rms != pytest.approx(c2.rms, rel=1e-3)
    assert ag.code_range == (10, 245)
    with pytest.raises(KeyError):
        ag["B"]


def test_agreement_sample_of_columns_at_and_below_the_limit():
    """max_pixels == P keeps every pixel; below it the blend counts the even sample
    linspace(0, P-1, m) (the pair figures still count every pixel)."""
    data = _bracket(300)
    full = agm.channel_agreement(data, G_CURVE, A_EXP, B_OFF, max_pixels=300)
    ref = agm.channel_agreement(data, G_CURVE, A_EXP, B_OFF)
    assert full.n_blend == ref.n_blend and full.rms_blend == ref.rms_blend
    part = agm.channel_agreement(data, G_CURVE, A_EXP, B_OFF, max_pixels=50)
    cols = np.unique(np.linspace(0, 299, 50).astype(np.int64))
    sub = BracketData(data.z[:, cols], data.valid[:, cols], data.t, 256)
    sb, nb = _blend_sse(sub.z)
    assert part.n_blend == nb and part.rms_blend == pytest.approx(math.sqrt(sb / nb), rel=1e-9)
    assert part.n == ref.n


def test_moments_from_counts_blocks_and_codes_agree():
    """The comparagram's moments equal the pixels' (limits inclusive), and the blocks' moments
    sum to the whole and each equals its own pixels'."""
    data = _bracket(400)
    z = data.z
    rng = (10, 245)
    C = np.zeros((256, 256))
    np.add.at(C, (z[0], z[1]), 1.0)
    mc, mz = agm.moments_of_counts(C, rng), agm.moments_of_codes(z[0], z[1], 256, rng)
    m = (z[0] >= 10) & (z[0] <= 245) & (z[1] >= 10) & (z[1] <= 245)
    assert mc.n == mz.n == int(m.sum())
    for a, b in zip(mc.src_j + mc.src_k, mz.src_j + mz.src_k):
        np.testing.assert_allclose(a, b, atol=1e-9)
    # src_j: per code of image j, the sum and the sum of squares of image k's codes
    u = 10
    sel = m & (z[0] == u)
    assert mz.src_j[1][u] == pytest.approx(z[1][sel].sum())
    assert mz.src_k[2][245] == pytest.approx((z[0][m & (z[1] == 245)] ** 2).sum())
    block = np.arange(400) % 3
    parts = agm.moments_by_block(z[0], z[1], 256, rng, block, 3)
    total = parts[0] + parts[1] + parts[2]
    assert total.n == mz.n
    for a, b in zip(total.src_j + total.src_k, mz.src_j + mz.src_k):
        np.testing.assert_allclose(a, b, atol=1e-9)
    one = agm.moments_of_codes(z[0][block == 2], z[1][block == 2], 256, rng)
    diff = total - parts[0] - parts[1]
    assert parts[2].n == one.n == diff.n
    np.testing.assert_allclose(parts[2].src_k[1], one.src_k[1])
    np.testing.assert_allclose(diff.src_j[2], one.src_j[2])
    with_counts = BracketData(z[:2], data.valid[:2], data.t[:2], 256, pair_counts=C[None])
    assert agm.pair_moments(with_counts)[0].n == mz.n


def test_agreement_pair_without_shared_codes_and_code_range_of_10_bits():
    """A pair sharing no readable code has n = 0 and NaN figures (the others still count);
    code_range scales 10..245 by (levels - 1) / 255 with rounding."""
    data = _bracket(200)
    z = data.z.copy()
    z[2] = 255
    c = agm.channel_agreement(BracketData(z, data.valid, data.t, 256), G_CURVE, A_EXP, B_OFF)
    assert c.pairs[1].n == 0 and math.isnan(c.pairs[1].rms)
    assert c.pairs[1].ratio == pytest.approx(A_EXP[2] / A_EXP[1])
    assert c.n == c.pairs[0].n > 0
    assert c.worst_pair() is c.pairs[0]
    s = c.summary()
    assert s.pairs[1].rms is None and s.pairs[1].n == 0
    assert agm.code_range(1024) == (40, 983)
    assert agm.code_range(16) == (1, 14)


def test_inverse_end_codes_and_flat_runs():
    """f = g^-1 maps beyond g's range to the end codes, and a flat run to its middle code."""
    g = np.array([0.0, 0.1, 0.1, 0.1, 0.5, 0.9])
    f = agm.inverse(g)
    np.testing.assert_allclose(f(np.array([-1.0, 0.1, 0.3, 0.9, 5.0])), [0.0, 2.0, 3.0, 5.0, 5.0])


# ----------------------------------------------------------------------------------------------
# noise fit (eq. 17)

def _noise_rows(m: int, seed: int = 2) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(0.1, 1.0, m), rng.uniform(1.0, 3.0, m),
                         rng.uniform(0.01, 0.5, m)])
    n = rng.integers(20, 400, m).astype(float)
    return X, n


def test_noise_fit_recovers_exact_terms_and_weights_errors_by_the_mad_variance():
    """With σ² exactly X θ the fit returns θ; the errors are
    sqrt(diag((AᵀA)⁻¹) max(χ², 1))
    with rows weighted by 1/sd(σ²), sd = σ² sqrt(2 / (0.37 n)), and χ² over m - 3 dof."""
    X, n = _noise_rows(9)
    theta = np.array([0.02, 0.3, 1.5])
    sig = np.sqrt(X @ theta)
    th, err, chi2 = noise.noise_fit(X, sig, n)
    np.testing.assert_allclose(th, theta, rtol=1e-8)
    assert chi2 == pytest.approx(0.0, abs=1e-12)
    A = X / (sig ** 2 * np.sqrt(2.0 / (0.37 * n)))[:, None]
    np.testing.assert_allclose(err, np.sqrt(np.diag(np.linalg.inv(A.T @ A))), rtol=1e-8)
    # inconsistent data: the weighted least squares solution (all terms positive) and its chi²
    rng = np.random.default_rng(3)
    sig2 = sig * (1.0 + 0.1 * rng.standard_normal(9))
    th2, err2, chi2b = noise.noise_fit(X, sig2, n)
    y = sig2 ** 2
    w = 1.0 / (y * np.sqrt(2.0 / (0.37 * n)))
    sol = np.linalg.lstsq(X * w[:, None], y * w, rcond=None)[0]
    assert np.all(sol > 0)
    np.testing.assert_allclose(th2, sol, rtol=1e-6)
    ref_chi2 = float(np.sum(((X @ sol - y) * w) ** 2)) / 6
    assert chi2b == pytest.approx(ref_chi2, rel=1e-6) and chi2b > 1.0
    A2 = X * w[:, None]
    np.testing.assert_allclose(err2, np.sqrt(np.diag(np.linalg.inv(A2.T @ A2)) * ref_chi2),
                               rtol=1e-6)


def test_trim_is_the_papers_66_percent():
    """Eq. 11 keeps 66 % of a pool's errors (α = 0.17 cut each side)."""
    assert est.TRIM == 0.66


def test_noise_fit_dof_floor_at_three_pools():
    """With 3 pools (m - 3 = 0) the chi² is divided by 1, not 0."""
    X, n = _noise_rows(3)
    sig = np.sqrt(X @ np.array([0.02, 0.3, 1.5])) * np.array([1.0, 1.1, 0.95])
    _, _, chi2 = noise.noise_fit(X, sig, n)
    assert math.isfinite(chi2)


# ----------------------------------------------------------------------------------------------
# gauge of the white-balance fit (sec. 3.2)

T5 = np.array([0.5, 1.0, 2.2, 4.0, 9.0])
A5 = T5 * np.array([1.1, 0.95, 1.02, 0.9, 1.2])


def _C(t: np.ndarray) -> np.ndarray:
    lt = np.log(t) - np.log(t).mean()
    return np.stack([np.ones(t.size), lt])


def test_in_gauge_zero_mean_and_trend_and_keeps_the_rest():
    """ln(a/t) of the result has zero mean and zero trend in ln t; the change is a line in ln t."""
    out = gauge.in_gauge(A5, T5)
    la = np.log(out / T5)
    np.testing.assert_allclose(_C(T5) @ la, 0.0, atol=1e-12)
    d = np.log(out / A5)
    fit = np.polyfit(np.log(T5), d, 1)
    np.testing.assert_allclose(np.polyval(fit, np.log(T5)), d, atol=1e-12)


def test_gain_and_ab_gauge_steps_stay_in_the_gauge():
    """δa = T y + off moves ln(a/t) into the gauge (linearised) for every y; the columns of T/a
    are orthonormal and span the N - 2 directions; ab_gauge keeps b_0 fixed."""
    T, off = gauge.gain_gauge(A5, T5)
    C = _C(T5)
    assert T.shape == (5, 3)
    np.testing.assert_allclose(C @ (T / A5[:, None]), 0.0, atol=1e-12)
    np.testing.assert_allclose(C @ (np.log(A5 / T5) + off / A5), 0.0, atol=1e-12)
    Q = T / A5[:, None]
    np.testing.assert_allclose(Q.T @ Q, np.eye(3), atol=1e-12)
    Tab, offab = gauge.ab_gauge(A5, T5)
    assert Tab.shape == (10, 7)
    np.testing.assert_allclose(Tab[:5, :3], T)
    np.testing.assert_allclose(Tab[5], 0.0)
    np.testing.assert_allclose(Tab[6:, 3:], np.eye(4))
    np.testing.assert_allclose(offab, np.r_[off, np.zeros(5)])
    free = np.array([True, False, True, True])
    Tf, offf = gauge.joint_frame(free, A5, T5)
    assert Tf.shape == (14, 10)
    np.testing.assert_allclose(Tf[[0, 2, 3], :3], np.eye(3))
    np.testing.assert_allclose(Tf[1], 0.0)
    np.testing.assert_allclose(Tf[4:, 3:], Tab)
    np.testing.assert_allclose(offf, np.r_[np.zeros(4), offab])


def _reported(gk: np.ndarray, a: np.ndarray, b: np.ndarray, k_hi: int, scale: float
              ) -> np.ndarray:
    g_new, b_new, _ = gauge.least_offsets(gk, a, b, k_hi)
    return np.r_[g_new / g_new[k_hi] * scale, a, b_new]


def test_least_offsets_are_orthogonal_and_the_jacobian_matches_finite_differences():
    """The reported b is orthogonal to 1 and to a, g shifts by the same c as b
    (b_new = b + c - beta a); D's columns for g and b equal finite differences of the reported
    (g scaled at k_hi, a, b)."""
    gk = np.array([0.05, 0.2, 0.45, 0.7, 1.0, 1.3])
    a = np.array([1.0, 2.5, 5.0])
    b = np.array([0.03, -0.01, 0.07])
    g_new, b_new, D = gauge.least_offsets(gk, a, b, 4)
    assert abs(b_new.sum()) < 1e-12 and abs(b_new @ a) < 1e-12
    c = g_new - gk
    np.testing.assert_allclose(c, c[0], atol=1e-14)
    beta = (b + c[0] - b_new) / a
    np.testing.assert_allclose(beta, beta[0], atol=1e-12)
    x0 = np.r_[gk, a, b]
    K, N = 6, 3
    base = _reported(gk, a, b, 4, g_new[4])
    h = 1e-6
    for col in list(range(K)) + list(range(K + N, K + 2 * N)):
        x = x0.copy()
        x[col] += h
        fd = (_reported(x[:K], x[K:K + N], x[K + N:], 4, g_new[4]) - base) / h
        np.testing.assert_allclose(D[:, col], fd, atol=1e-5)


def test_sandwich_small_sample_factor_frame_and_singular_bread():
    """cov = B⁻¹ (Ψ Ψᵀ G/(G-1)) B⁻¹, mapped by the frame; NaN for a singular bread."""
    B = np.array([[2.0, 0.3], [-0.4, 1.0]])                 # not symmetric: B⁻¹ on both sides
    S = np.array([[1.0, -0.5, 0.2], [0.1, 0.4, -0.3]])
    Bi = np.linalg.inv(B)
    ref = Bi @ (S @ S.T * 1.5) @ Bi
    np.testing.assert_allclose(gauge.sandwich(B, S), ref, rtol=1e-12)
    F = np.array([[1.0, 2.0], [0.0, 1.0], [3.0, -1.0]])
    np.testing.assert_allclose(gauge.sandwich(B, S, F), F @ ref @ F.T, rtol=1e-12)
    out = gauge.sandwich(np.zeros((2, 2)), S, F)
    assert out.shape == (3, 3) and np.isnan(out).all()


def test_joint_step_trust_region_radius_and_prior():
    """No gain moves by more than MAX_GAIN_STEP × radius (before the gauge), the radius doubles
    up to MAX_RADIUS; a zero gradient with gains off their times is pulled back by the prior."""
    K, N = 3, 3
    t = np.array([1.0, 2.0, 4.0])
    a = t.copy()
    b = np.zeros(N)
    free = np.ones(K, bool)
    H = np.eye(K + 2 * N)
    grad = np.zeros(K + 2 * N)
    grad[K:K + N] = [5.0, -3.0, 40.0]
    grad[K + N:] = [0.3, -2.0, 1.5]
    eta, radius = 0.5, 2.0
    dg, a_new, b_new, r = gauge.joint_step(H, grad, free, a, b, t, 0.0, eta, radius, "x")
    assert r == 4.0
    Tf, off = gauge.joint_frame(free, a, t)
    y = np.linalg.lstsq(Tf.T @ H @ Tf, Tf.T @ (grad - H @ off), rcond=None)[0]
    d = Tf @ y + off
    rel = np.max(np.abs(eta * d[K:K + N] / a))
    assert rel > gauge.MAX_GAIN_STEP * radius
    d = d * gauge.MAX_GAIN_STEP * radius / rel
    np.testing.assert_allclose(a_new, gauge.in_gauge(a + eta * d[K:K + N], t), rtol=1e-12)
    np.testing.assert_allclose(b_new, eta * d[K + N:], atol=1e-12)
    assert b_new[0] == 0.0 and np.all(np.abs(b_new[1:]) > 1e-3)
    np.testing.assert_allclose(dg, d[:K], atol=1e-12)
    assert gauge.joint_step(H, 0 * grad, free, a, b, t, 0.0, 1.0, 5.0, "x")[3] == gauge.MAX_RADIUS
    # the prior ln(a/t) ~ N(0, σ²) (sec. 3.2): gains off their times along the gauge's free
    # direction (curvature in ln t) are pulled back by a tight prior, and left alone without it
    a2 = t * np.exp(0.05 * np.array([1.0, -2.0, 1.0]))
    _, a_0, _, _ = gauge.joint_step(H, 0 * grad, free, a2, b, t, 0.0, 1.0, 8.0, "x")
    np.testing.assert_allclose(a_0, a2, rtol=1e-12)
    _, a_p, _, _ = gauge.joint_step(H, 0 * grad, free, a2, b, t, 0.01, 1.0, 8.0, "x")
    assert np.max(np.abs(np.log(a_p / t))) < 0.2 * np.max(np.abs(np.log(a2 / t)))


# ----------------------------------------------------------------------------------------------
# notes of the fit

def _opts(**kw) -> SimpleNamespace:
    base = dict(max_iter=50, tol=1e-4, min_pool=100, white_balance=False)
    base.update(kw)
    return SimpleNamespace(**base)


def test_estimate_notes_boundaries():
    """A note each: sampled, not converged, pools below min_pool (not equal), white balance,
    chi² above 3 (not at 3, with sqrt(chi²) as the factor), a noise term θ_s or θ_c2 at 0 (not
    θ_c1)."""
    data = SimpleNamespace(n_pixels=500)
    s = SimpleNamespace(min_pool=100)
    kw = dict(sampled=0, converged=True, step=0.0, chi2=3.0, theta=np.array([1.0, 0.0, 1.0]))
    assert notes.estimate_notes(_opts(), data, s, **kw) == []
    out = notes.estimate_notes(_opts(), data, SimpleNamespace(min_pool=99),
                               **{**kw, "chi2": 12.25})
    assert len(out) == 2 and "3.5 times" in out[1] and "chi²/dof 12" in out[1]
    assert "shutter" in out[1]
    wb = notes.estimate_notes(_opts(white_balance=True), data, s, **{**kw, "chi2": 3.01})
    assert len(wb) == 2 and "gains and offsets do not explain" in wb[1]
    for theta in ([0.0, 1.0, 1.0], [1.0, 1.0, 0.0]):
        got = notes.estimate_notes(_opts(), data, s, **{**kw, "theta": np.array(theta)})
        assert len(got) == 1 and "forced to 0" in got[0]
    full = notes.estimate_notes(_opts(), data, s, **{**kw, "sampled": 9000, "converged": False})
    assert "500 of the bracket's 9000" in full[0] and "after 50 iterations" in full[1]


def test_pick_pool_nearest_to_78_percent_largest_on_ties():
    """The row whose pool code is nearest 0.78 (L-1) (ties: the most pixels); values divided by
    g_k at the pool's knot (1 where that is not positive)."""
    codes = np.array([10.0, 100.0, 198.0, 200.0, 220.0])
    rows = np.array([[0, 1, 1], [0, 2, 1], [1, 3, 2], [2, 3, 1], [1, 4, 2]])
    offsets = np.array([0, 3, 5, 9, 11, 12])
    s = SimpleNamespace(data=SimpleNamespace(levels=256), knots=SimpleNamespace(codes=codes),
                        rows=rows, offsets=offsets)
    resid = np.arange(12.0)
    gk = np.array([0.1, 0.2, 0.5, 0.0, 0.9])
    # 0.78 * 255 = 198.9: knot 2 (198) is nearest; rows 1 (2 pixels) only
    out = notes.pick_pool(s, resid, gk)
    assert out["row"] == 1 and out["code"] == 198.0 and out["pool_image"] == 0
    assert out["predicted_image"] == 1
    np.testing.assert_allclose(out["values"], resid[3:5] / 0.5)
    codes2 = codes.copy()
    codes2[3] = 198.0                      # rows 2 (4 pixels) and 3 (2) tie with row 1
    s.knots = SimpleNamespace(codes=codes2)
    out2 = notes.pick_pool(s, resid, gk)
    assert out2["row"] == 2
    np.testing.assert_allclose(out2["values"], resid[5:9])       # g_k 0 -> divided by 1
    assert notes.pick_pool(s, resid, gk, like={"row": 4})["row"] == 4


# ----------------------------------------------------------------------------------------------
# verdict thresholds

def _resp(g: np.ndarray | None = None, method: str = "tsin", converged: bool = True,
          wb: bool = False, iterations: int = 7) -> SimpleNamespace:
    g = (np.arange(256) / 255.0) ** 1.3 if g is None else g
    return SimpleNamespace(g=g, method=method, converged=converged, white_balance=wb,
                           iterations=iterations)


def _result(rms: float, rms_fitted: float, responses: list | None = None, method: str = "tsin",
            exposures: SimpleNamespace | None = None, pairs: list | None = None
            ) -> SimpleNamespace:
    responses = [_resp()] if responses is None else responses
    pairs = pairs or [SimpleNamespace(n=10, rms=rms, rms_fitted=rms_fitted, j=0, k=1)]
    ag = SimpleNamespace(rms=rms, rms_fitted=rms_fitted, channels=[SimpleNamespace(pairs=pairs)])
    return SimpleNamespace(levels=256, agreement=ag, method=method, exposures=exposures,
                           responses=responses, channels=tuple("RGB"[:len(responses)]),
                           files=("f0", "f1", "f2", "f3"))


def test_verdict_exposure_threshold_is_factor_times_fitted_plus_dn():
    """Doubtful exactly above 1.5 × rms_fitted + 1.0 DN (at it: trusted), at two fitted values so
    both the factor and the offset are pinned."""
    assert vd.response_verdict(_result(4.0, 2.0)).status == vd.TRUSTED
    v = vd.response_verdict(_result(4.0001, 2.0))
    assert v.status == vd.DOUBTFUL and v.next_step == "--exposures estimated"
    assert v.frames == ("f0", "f1")
    assert vd.response_verdict(_result(1.0, 0.0)).status == vd.TRUSTED
    assert vd.response_verdict(_result(1.0001, 0.0)).status == vd.DOUBTFUL
    # with the gains estimated (white balance) or the exposures already estimated: no step
    wb = vd.response_verdict(_result(5.0, 2.0, [_resp(wb=True)]))
    assert wb.status == vd.DOUBTFUL and wb.next_step == ""
    est = SimpleNamespace(used="estimated", converged=True, iterations=3)
    assert vd.response_verdict(_result(5.0, 2.0, exposures=est)).next_step == ""


def test_verdict_worst_pair_is_the_largest_gap_to_the_fitted_ratio():
    """The frames named are the pair with the largest rms - rms_fitted (not the largest rms);
    pairs with n = 0 or NaN are skipped."""
    pairs = [SimpleNamespace(n=10, rms=9.0, rms_fitted=8.5, j=0, k=1),
             SimpleNamespace(n=10, rms=6.0, rms_fitted=1.0, j=1, k=2),
             SimpleNamespace(n=0, rms=50.0, rms_fitted=0.0, j=2, k=3),
             SimpleNamespace(n=10, rms=float("nan"), rms_fitted=0.0, j=2, k=3)]
    v = vd.response_verdict(_result(6.0, 2.0, pairs=pairs))
    assert v.frames == ("f1", "f2")


def test_verdict_better_challenger_needs_both_factor_and_dn():
    """Another curve is clearly better when its RMS × 1.10 is below the result's and the gap
    exceeds 0.25 DN; the lowest such challenger is named; the result's own method, None and NaN
    challengers are skipped."""
    def status(rms: float, other: dict) -> vd.ResponseVerdict:
        ch = {k: (None if v is None else SimpleNamespace(rms=v)) for k, v in other.items()}
        return vd.response_verdict(_result(rms, rms), ch)
    assert status(3.31, {"dm": 3.0}).status == vd.DOUBTFUL
    assert status(3.29, {"dm": 3.0}).status == vd.TRUSTED          # factor 1.1 not met
    assert status(1.26, {"dm": 1.0}).status == vd.DOUBTFUL
    assert status(1.24, {"dm": 1.0}).status == vd.TRUSTED          # 0.25 DN not met
    v = status(5.0, {"tsin": 0.5, "dm": 2.0, "mr": 1.5, "x": None, "y": float("nan")})
    assert v.status == vd.DOUBTFUL and v.next_step == "--method mr" and "1.50 DN" in v.reason
    wb = vd.response_verdict(_result(5.0, 5.0, [_resp(wb=True)]),
                             {"dm": SimpleNamespace(rms=1.0)})
    assert wb.next_step == "--method dm without --white-balance"


def test_verdict_start_line_tolerance_and_readable_codes_only():
    """A tsin curve within 1e-6 of z/255 on codes 10..245 failed (whatever it does outside);
    2e-6 off it is not stuck; another method at the start line is not judged stuck."""
    line = np.arange(256) / 255.0
    near = line.copy()
    near[10:246] += 0.9e-6
    near[:10] += 0.1
    near[246:] += 0.1
    v = vd.response_verdict(_result(1.0, 1.0, [_resp(near)]))
    assert v.status == vd.FAILED and "starting line" in v.reason
    off = line.copy()
    off[245] += 2e-6
    assert vd.response_verdict(_result(1.0, 1.0, [_resp(off)])).status == vd.TRUSTED
    assert vd.response_verdict(_result(1.0, 1.0, [_resp(line, method="dm")])).status == vd.TRUSTED
    two = vd.response_verdict(_result(1.0, 1.0, [_resp(line), _resp(line)]))
    assert "channels R, G" in two.reason


def test_verdict_flat_run_of_a_tenth_of_the_readable_codes_at_either_end():
    """A run of 24 non-rising steps (>= 0.1 × 235) failed, 23 does not; runs touching code 10 or
    code 245 count (the readable range is inclusive), runs outside it do not."""
    def flat_at(start: int, steps: int) -> np.ndarray:
        g = (np.arange(256) / 255.0) ** 1.3
        g[start:start + steps + 1] = g[start]
        return g
    for start in (10, 245 - 24):
        assert vd.longest_flat_run(flat_at(start, 24), 256) == 24
        v = vd.response_verdict(_result(1.0, 1.0, [_resp(flat_at(start, 24))]))
        assert v.status == vd.FAILED and "flat over 24 codes of 10..245" in v.reason
    assert vd.response_verdict(_result(1.0, 1.0, [_resp(flat_at(100, 23))])).status == vd.TRUSTED
    assert vd.longest_flat_run(flat_at(246 - 1, 9), 256) == 0
    two = flat_at(40, 20)
    two[62:83] = two[62]                                      # runs of 20 and 20, apart
    assert vd.longest_flat_run(two, 256) == 20
    assert vd.response_verdict(_result(1.0, 1.0, [_resp(two)])).status == vd.TRUSTED
    # a rise far below 1e-9 of the range still counts as flat
    g = (np.arange(256) / 255.0) ** 1.3
    g[50:80] = g[50] + 1e-13 * np.arange(30)
    assert vd.longest_flat_run(g, 256) == 29


def test_verdict_unconverged_and_unsettled_exposures():
    """Not converged: doubtful with the iterations (largest over channels) and, for the tsin
    gains' fit only, the step without --white-balance; estimated exposures that did not settle:
    doubtful; no agreement at all: failed."""
    v = vd.response_verdict(_result(1.0, 1.0, [_resp(converged=False, iterations=40, wb=True),
                                                _resp(iterations=12)]))
    assert v.status == vd.DOUBTFUL and "channel R stopped after 40" in v.reason
    assert v.next_step == "--method tsin without --white-balance"
    v2 = vd.response_verdict(_result(1.0, 1.0, [_resp(converged=False, method="dm")],
                                     method="dm"))
    assert v2.next_step == ""
    v2b = vd.response_verdict(_result(1.0, 1.0, [_resp(converged=False)]))
    assert v2b.status == vd.DOUBTFUL and v2b.next_step == ""
    est = SimpleNamespace(used="estimated", converged=False, iterations=6)
    v3 = vd.response_verdict(_result(1.0, 1.0, exposures=est))
    assert v3.status == vd.DOUBTFUL and "6 alternations" in v3.reason
    ok = vd.response_verdict(_result(1.0, 1.0, exposures=SimpleNamespace(
        used="estimated", converged=True, iterations=6)))
    assert ok.status == vd.TRUSTED and "own exposures" in ok.reason
    none = vd.response_verdict(_result(float("nan"), float("nan")))
    assert none.status == vd.FAILED and "nothing checks" in none.reason


# ----------------------------------------------------------------------------------------------
# handheld simulation geometry

def test_cos_sin_deg_matches_math_over_every_turn():
    """cos/sin of degrees within 1e-14 of math's, wrapped into (-180, 180] at and beyond ±180."""
    for deg in (-725.5, -540.0, -190.0, -180.0, -179.9, -30.0, 0.0, 0.7, 90.0, 179.9, 180.0,
                181.0, 270.0, 359.0, 360.0, 725.5):
        c, s = hh.cos_sin_deg(deg)
        assert c == pytest.approx(math.cos(math.radians(deg)), abs=1e-14)
        assert s == pytest.approx(math.sin(math.radians(deg)), abs=1e-14)


def test_transform_matrix_maps_reference_to_frame_on_a_rectangle():
    """[R | c - R c + d] maps p to c + R (p - c) + d, c = ((W-1)/2, (H-1)/2) (rectangular)."""
    tr = (1.5, -2.25, 17.0)
    shape = (7, 12)
    M = np.array(hh.transform_matrix(tr, shape))
    th = math.radians(17.0)
    R = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    c = np.array([5.5, 3.0])
    for p in ([0.0, 0.0], [11.0, 2.0], [4.0, 6.0]):
        q = c + R @ (np.array(p) - c) + np.array(tr[:2])
        np.testing.assert_allclose(M @ np.r_[p, 1.0], q, atol=1e-12)


def test_margin_for_is_the_largest_corner_displacement_rounded_up_plus_two():
    """0 for identities; else ceil(largest corner displacement) + 2 (brute force over corners)."""
    assert hh.margin_for([(0.0, 0.0, 0.0)] * 3, (10, 20)) == 0
    assert hh.margin_for([(0.0, 0.0, 0.0), (3.0, -1.0, 0.0)], (10, 20)) == 5
    assert hh.margin_for([(0.0, 0.0, 0.0), (0.4, -2.5, 0.0)], (10, 20)) == 5
    shape = (30, 50)
    c = np.array([24.5, 14.5])
    for tr in ([(1.0, 0.5, 2.0), (-0.3, 0.2, -3.0)], [(0.0, 0.0, 0.0), (3.75, -1.0, 8.0)]):
        worst = 0.0
        for dx, dy, th in tr:
            r = math.radians(th)
            Rt = np.array([[math.cos(r), math.sin(r)], [-math.sin(r), math.cos(r)]])
            for q in ([0, 0], [49, 0], [0, 29], [49, 29]):
                p = c + Rt @ (np.array(q, float) - np.array([dx, dy]) - c)
                worst = max(worst, float(np.max(np.abs(p - q))))
        assert hh.margin_for(tr, shape) == math.ceil(worst) + 2


def test_reflect_folds_like_symmetric_padding():
    """Indices folded as d c b a | a b c d | d c b a."""
    n = 4
    ref = np.pad(np.arange(n), 12, mode="symmetric")
    i = np.arange(-12, n + 12)
    np.testing.assert_array_equal(hh._reflect(i, n), ref)


def test_warp_and_align_follow_the_convention_on_a_rectangle_with_channels():
    """warp: frame q sees the scene at p = c + Rᵀ (q - d - c); align: aligned(p) =
    frame(c + R (p - c) + d); bilinear weights at a quarter pixel; order 3 exact at integer
    points; the identity is an exact crop."""
    rng = np.random.default_rng(1)
    m, h, w = 3, 5, 8
    E = rng.random((h + 2 * m, w + 2 * m, 2))
    out = hh.warp_scene(E, (2.0, 1.0, 0.0), (h, w), m)
    np.testing.assert_allclose(out[1:, 2:], E[m:m + h - 1, m:m + w - 2])
    np.testing.assert_array_equal(hh.warp_scene(E, (0.0, 0.0, 0.0), (h, w), m),
                                  E[m:m + h, m:m + w])
    F = rng.random((h, w))
    al = hh.align_frame(F, (0.25, 0.0, 0.0))
    np.testing.assert_allclose(al[:, :-1], 0.75 * F[:, :-1] + 0.25 * F[:, 1:])
    al = hh.align_frame(F, (0.0, -0.5, 0.0))
    np.testing.assert_allclose(al[1:], 0.5 * F[1:] + 0.5 * F[:-1])
    # 90 degrees on an odd-sized rectangle: c = (3.5, 2); sample (c_x - (y - c_y), c_y + x - c_x)
    G = rng.random((5, 9))
    c = (4.0, 2.0)
    for order in (1, 3):
        al = hh.align_frame(G, (0.0, 0.0, 90.0), order=order)
        for x, y in ((4, 2), (5, 2), (4, 0), (3, 3)):
            sx, sy = c[0] - (y - c[1]), c[1] + (x - c[0])
            assert al[y, x] == pytest.approx(G[int(sy), int(sx)], abs=1e-9)
        wr = hh.warp_scene(np.pad(G, 4, mode="symmetric"), (0.0, 0.0, 90.0), (5, 9), 4,
                           order=order)
        for x, y in ((5, 2), (4, 1)):
            sx, sy = c[0] + (y - c[1]), c[1] - (x - c[0])
            assert wr[y, x] == pytest.approx(G[int(sy), int(sx)], abs=1e-9)
    with pytest.raises(CcdError):
        hh.align_frame(G, (0.5, 0.0, 0.0), order=2)
    hh.warp_scene(E, (1.0, 0.0, 0.0), (h, w), m)               # exactly the margin: fine
    with pytest.raises(CcdError):
        hh.warp_scene(E[:-1], (1.0, 0.0, 0.0), (h, w), m)
    with pytest.raises(CcdError):
        hh.warp_scene(E[:, :-1], (1.0, 0.0, 0.0), (h, w), m)


def _hopts(**kw) -> dict:
    base = dict(handheld_shift=0.0, handheld_rotation=0.0, mover_speed=12.0, movers=0,
                mover_size=0.12)
    base.update(kw)
    return base


def test_check_options_limits():
    """Sigmas and speed >= 0 (NaN refused), movers a non-negative integer (not bool), size in
    (0, 1]."""
    hh.check_options(_hopts(mover_size=1.0, movers=np.int64(2), handheld_shift=0.0))
    hh.check_options(_hopts(movers=0, mover_speed=0.0))
    for bad in (dict(handheld_shift=-0.1), dict(handheld_rotation=float("nan")),
                dict(mover_speed=-1.0), dict(movers=True), dict(movers=-1), dict(movers=2.0),
                dict(mover_size=0.0), dict(mover_size=1.0001)):
        with pytest.raises(CcdError):
            hh.check_options(_hopts(**bad))


def test_frame_transforms_scale_each_draw_and_fix_the_reference():
    """Frame k: (shift σ N_k0, shift σ N_k1, rotation σ N_k2) rounded, the reference (0, 0, 0);
    a reference outside 0..n-1 is refused."""
    out = hh.frame_transforms(np.random.default_rng(7), 4, 2.0, 0.3, reference=1)
    draws = np.random.default_rng(7).standard_normal((4, 3))
    assert out[1] == (0.0, 0.0, 0.0)
    for k in (0, 2, 3):
        assert out[k] == (round_sig(2.0 * draws[k, 0]), round_sig(2.0 * draws[k, 1]),
                          round_sig(0.3 * draws[k, 2]))
    assert hh.frame_transforms(np.random.default_rng(7), 5, 1.0, 1.0)[2] == (0.0, 0.0, 0.0)
    hh.frame_transforms(np.random.default_rng(7), 4, 1.0, 1.0, reference=3)
    for ref in (4, -1):
        with pytest.raises(CcdError):
            hh.frame_transforms(np.random.default_rng(7), 4, 1.0, 1.0, reference=ref)


def test_draw_movers_sizes_speeds_ranges_on_a_wide_frame(monkeypatch: pytest.MonkeyPatch):
    """ry = max(2, size H / 2), rx = max(1.5, 0.6 ry), |velocity| = speed with slope within
    ±0.25, centres in the middle half of the width and 40 % of the height, colours level ×
    [0.4, 2.5], texture (2 (ceil ry + 1) + 1)² within [0.6, 1.4]."""
    items = hh.draw_movers(np.random.default_rng(3), 40, 5, (60, 200), 0.3, 7.0,
                           n_channels=2, level=2.0)
    for mv in items:
        assert mv.radii == (pytest.approx(5.4), pytest.approx(9.0))
        assert math.hypot(*mv.velocity) == pytest.approx(7.0, rel=1e-9)
        assert abs(mv.velocity[1]) <= 0.25 * abs(mv.velocity[0]) + 1e-9
        assert 50.0 <= mv.centre[0] <= 150.0 and 18.0 <= mv.centre[1] <= 42.0
        assert len(mv.colour) == 2 and all(0.8 <= c <= 5.0 for c in mv.colour)
        assert mv.texture.shape == (21, 21)
        assert mv.texture.min() >= 0.6 and mv.texture.max() <= 1.4
        assert mv.reference == 2
        assert mv.centre_at(4) == pytest.approx((mv.centre[0] + 2 * mv.velocity[0],
                                                 mv.centre[1] + 2 * mv.velocity[1]))
    assert {mv.velocity[0] > 0 for mv in items} == {True, False}
    monkeypatch.setattr(hh, "_MOVER_TEXTURE", 1.0)          # wide texture: both clips reached
    tex = hh.draw_movers(np.random.default_rng(3), 1, 3, (60, 200), 0.3, 7.0)[0].texture
    assert tex.min() == 0.6 and tex.max() == 1.4
    small = hh.draw_movers(np.random.default_rng(3), 1, 3, (10, 10), 0.1, 1.0)[0]
    assert small.radii == (1.5, 2.0) and small.texture.shape == (7, 7)


def test_render_movers_ellipse_boundary_offset_and_occlusion():
    """A pixel is the mover's when its centre is in the ellipse (on its edge too); offset shifts
    the grid; a later mover occludes an earlier; radiance = texture at the nearest node ×
    colour."""
    tex = np.arange(81.0).reshape(9, 9) / 81 + 0.6
    m1 = hh.Mover((5.0, 4.0), (2.0, 1.0), (3.0, 2.0), (1.0, 2.0), tex, 0)
    mask, rad = hh.render_movers([m1], 0, (10, 12))
    Y, X = np.mgrid[0:10, 0:12]
    ref = ((X - 5.0) / 3.0) ** 2 + ((Y - 4.0) / 2.0) ** 2 <= 1.0
    np.testing.assert_array_equal(mask, ref)
    assert mask[4, 8] and mask[4, 2] and mask[6, 5] and mask[2, 5]
    assert rad[4, 8, 1] == pytest.approx(tex[4, 4 + 3] * 2.0)
    assert rad[6, 5, 0] == pytest.approx(tex[4 + 2, 4] * 1.0)
    assert np.all(rad[~mask] == 0.0)
    mask1, _ = hh.render_movers([m1], 1, (10, 12), offset=1)
    np.testing.assert_array_equal(mask1, ((X - 8.0) / 3.0) ** 2 + ((Y - 6.0) / 2.0) ** 2 <= 1.0)
    m2 = hh.Mover((6.0, 4.0), (0.0, 0.0), (1.5, 2.0), (7.0, 7.0), np.ones((7, 7)), 0)
    _, both = hh.render_movers([m1, m2], 0, (10, 12))
    assert both[4, 6, 0] == 7.0 and both[4, 3, 0] == pytest.approx(tex[4, 2])
    mask2, _ = hh.render_movers([m2], 0, (10, 12))
    np.testing.assert_array_equal(hh.render_movers([m1, m2], 0, (10, 12))[0], mask | mask2)
    gone = hh.Mover((-20.0, 4.0), (0.0, 0.0), (3.0, 2.0), (1.0,), tex, 0)
    assert not hh.render_movers([gone], 0, (10, 12))[0].any()


def test_plan_off_margin_reference_pad_and_crop():
    """No plan without shift, rotation or movers; else the reference n // 2, the margin of its
    transforms, a symmetric pad and an exact crop of a rectangle."""
    assert hh.plan(_hopts(), 1, 5, (20, 30)) is None
    p = hh.plan(_hopts(handheld_shift=1.5), 1, 5, (20, 30))
    assert p.reference == 2 and p.transforms[2] == (0.0, 0.0, 0.0)
    assert p.margin == hh.margin_for(p.transforms, (20, 30)) > 0
    assert p.shape == (20, 30) and p.grown((20, 30, 3)) == (20 + 2 * p.margin, 30 + 2 * p.margin, 3)
    E = np.random.default_rng(0).random((20, 30))
    padded = p.pad(E)
    np.testing.assert_array_equal(padded, np.pad(E, p.margin, mode="symmetric"))
    np.testing.assert_array_equal(p.crop(padded), E)
    assert hh.plan(_hopts(movers=1), 1, 5, (20, 30)).margin == 0


def test_band_without_gains_is_the_sandwich_carried_to_the_reported_scale():
    """Without gains: cov = sandwich(Hs[free, free], (JWᵀ S_g)[free]) over the blocks' summed
    influences S_g (trim n denominators), carried by S = I - (g/g_rep) e_repᵀ to the scale with
    g(z_rep) fixed: zero error at k_rep, the same a, b and zero errors for them."""
    from ccdcore.response.tsin.kernels import group_sums
    rng = np.random.default_rng(12)
    K, R = 5, 6
    offsets = np.array([0, 4, 9, 13, 18, 22, 27])
    resid = rng.normal(size=27)
    egrp = rng.integers(0, 4, 27).astype(np.int32)
    lo, hi = np.full(R, -1.0), np.full(R, 1.0)
    wmean = rng.normal(0, 0.1, R)
    JW = rng.normal(size=(R, K))
    Hs = JW.T @ JW + np.eye(K)
    p = SimpleNamespace(resid=resid, egrp=egrp, lo=lo, hi=hi, wmean=wmean, Hs=Hs, JW=JW)
    gk = np.array([0.0, 0.2, 0.45, 0.7, 1.0])
    free = np.array([True, True, False, True, True])
    a, b, t = np.array([1.0, 2.0]), np.array([0.0, 0.0]), np.array([1.0, 2.0])
    g2, b2, err, a_err, b_err = gauge.band(p, offsets, gk, a, b, t, free, 3, False, 4, 0.66)
    Sg = group_sums(resid, egrp, offsets, lo, hi, wmean, 0.66, 4)
    cov = np.zeros((K, K))
    cov[np.ix_(free, free)] = gauge.sandwich(Hs[np.ix_(free, free)], (JW.T @ Sg)[free])
    S = np.eye(K) - np.outer(gk / gk[3], np.eye(K)[3])
    np.testing.assert_allclose(err, np.sqrt(np.diag(S @ cov @ S.T)), rtol=1e-12)
    assert err[3] == 0.0 and err[2] > 0.0
    assert g2 is gk and b2 is b and not a_err.any() and not b_err.any()


def test_agreement_records_rows_and_line():
    """Records keep non-finite figures as None; the rows carry the three RMS figures in DN and the
    predictions counted (summed over the channels); the line prints each figure and the codes."""
    data = _bracket(300)
    r = {"g": G_CURVE, "a": A_EXP, "b": B_OFF}
    ag = agm.agreement({"R": data, "G": data}, {"R": r, "G": r}, codes=(12, 240))
    rec = ag.summary_record()
    assert rec.code_range == (12, 240) and rec["G"].n == ag["G"].n
    rows = {row.label: row for row in rec.rows()}
    assert rows["RMS, own ratios"].value == pytest.approx(ag.rms)
    assert rows["RMS from the blend of the others"].unit == "DN"
    assert rows["predictions"].value == 2 * ag["R"].n
    line = ag.summary()
    assert f"{ag.rms:.2f} DN RMS" in line and f"({ag.rms_fitted:.2f} DN" in line
    assert f"{ag.rms_blend:.2f} DN from the blend" in line and "codes 12..240" in line
    assert rec.line() == line
    with pytest.raises(KeyError):
        rec["B"]
    pr = ag["R"].pairs[0].summary()
    assert (pr.j, pr.k, pr.n) == (0, 1, ag["R"].pairs[0].n)
    assert [x.label for x in pr.rows()][-2:] == ["ratio", "fitted ratio"]
    empty = agm.Agreement((), (10, 245), float("nan"), float("inf"), 1.0).summary_record()
    assert empty.rms is None and empty.rms_fitted is None and empty.rms_blend == 1.0


def test_pair_moments_of_chosen_columns_ignore_the_comparagrams():
    """With ``columns`` the moments are those of those pixels even when the bracket carries
    whole-frame comparagrams."""
    rng = np.random.default_rng(11)
    z = rng.integers(0, 256, (3, 50)).astype(np.int32)
    counts = np.zeros((2, 256, 256), np.int64)
    counts[:, 100, 100] = 999
    d = BracketData(z, np.ones_like(z, bool), np.array([1.0, 2.0, 4.0]), 256, pair_counts=counts)
    cols = np.array([1, 5, 7, 30, 49])
    got = agm.pair_moments(d, columns=cols)
    for j in range(2):
        ref = agm.moments_of_codes(z[j, cols], z[j + 1, cols], 256, (10, 245))
        assert got[j].n == ref.n
        np.testing.assert_array_equal(got[j].src_j[1], ref.src_j[1])
    assert agm.pair_moments(d)[0].n == 999


def test_handheld_identity_align_is_a_float_copy_and_cubic_per_channel():
    """align_frame with the identity returns a float64 copy; order 3 on channels equals order 3
    on each channel alone."""
    F = np.arange(24, dtype=np.uint8).reshape(4, 6)
    out = hh.align_frame(F, (0.0, 0.0, 0.0))
    assert out.dtype == np.float64 and np.array_equal(out, F)
    out[0, 0] = 99
    assert F[0, 0] == 0
    rng = np.random.default_rng(2)
    C = rng.random((7, 9, 2))
    both = hh.align_frame(C, (0.3, -0.6, 5.0), order=3)
    for ch in range(2):
        np.testing.assert_allclose(both[..., ch], hh.align_frame(C[..., ch], (0.3, -0.6, 5.0),
                                                                 order=3), rtol=1e-12)


def test_check_converged_with_gains_phases():
    """With the gains fitted: phase 1 ends (k_lo then held) once a step is below max(tol, 1e-4)
    or the pools' χ² rose since the previous round; phase 2 converges when both the step of g
    and the largest relative step of a gain are below tol."""
    def st_of(phase: int, step: float, a_step: float = 0.0, hist: tuple = ()) -> SimpleNamespace:
        return SimpleNamespace(opts=SimpleNamespace(tol=1e-5), fit_a=True, phase=phase,
                               step=step, a_step=a_step, history=[{"chi2": c} for c in hist],
                               free=np.ones(5, bool), k_lo=1, converged=False, done=False)
    for step, hist, moved in ((0.99e-4, (), True), (1e-4, (), False),
                              (1e-3, (2.0, 2.5), True), (1e-3, (2.0, 1.5), False),
                              (1e-3, (2.0,), False)):
        st = st_of(1, step, hist=hist)
        est._check_converged(st, hist[-1] if hist else 1.0)
        assert (st.phase == 2) is moved and bool(st.free[1]) is (not moved) and not st.done
    for step, a_step, done in ((0.9e-5, 0.9e-5, True), (0.9e-5, 1e-5, False),
                               (1e-5, 0.0, False)):
        st = st_of(2, step, a_step)
        est._check_converged(st, 1.0)
        assert st.done is done and st.converged is done


def test_align_check_limits():
    """_check: at least 2 frames of integer codes, 2 × TILE_MIN a side (exactly that is fine),
    equal shapes, no negative codes, max_shift in (0, 0.5), the reference within the frames,
    2..65536 levels (uint16 codes: the next power of two above the largest) and no code beyond
    them."""
    from ccdcore.response import align as al
    ok = np.zeros((64, 70), np.uint8)
    arrays, ref, levels = al._check([ok, ok, ok], ["a", "b", "c"], None, 0.25, None)
    assert ref == 1 and levels == 256
    u16 = np.full((64, 64), 1000, np.uint16)
    assert al._check([u16, u16], ["a", "b"], 1, 0.49, None)[1:] == (1, 1024)
    u16b = u16.copy()
    u16b[0, 0] = 1024
    assert al._check([u16, u16b], ["a", "b"], 0, 0.1, None)[2] == 2048
    assert al._check([u16, u16], ["a", "b"], None, 0.1, 1001)[2] == 1001
    bad = [([ok], ["a"], None, 0.25, None), ([ok, ok], ["a"], None, 0.25, None),
           ([ok, ok.astype(float)], ["a", "b"], None, 0.25, None),
           ([ok[:63], ok[:63]], ["a", "b"], None, 0.25, None),
           ([ok[:, :63], ok[:, :63]], ["a", "b"], None, 0.25, None),
           ([ok, ok[:, :66]], ["a", "b"], None, 0.25, None),
           ([ok.astype(np.int16) - 1, ok.astype(np.int16)], ["a", "b"], None, 0.25, None),
           ([ok, ok], ["a", "b"], None, 0.5, None), ([ok, ok], ["a", "b"], None, 0.0, None),
           ([ok, ok], ["a", "b"], 2, 0.25, None), ([ok, ok], ["a", "b"], -1, 0.25, None),
           ([u16, u16], ["a", "b"], None, 0.25, 1000), ([ok, ok], ["a", "b"], None, 0.25, 1),
           ([ok, ok], ["a", "b"], None, 0.25, 2 ** 16 + 1)]
    for args in bad:
        with pytest.raises(CcdError):
            al._check(*args)
    al._check([u16, u16], ["a", "b"], None, 0.25, 2 ** 16)
