"""Pins for planted bugs in the response estimators that the other tests let through.

Each test compares the library with an expectation computed independently of its code: a
formula written out here (Tsin, Ramesh & Kanade 2001, eqs. 9 and 18; Tukey-McLaughlin's
standard error of a trimmed mean as scipy computes it; the cluster-robust variance of a mean),
an exact invariance of the reported result, or a Monte Carlo over simulated brackets. Seeds are
fixed; every tolerance says why it is what it is.

1. ``agreement.channel_agreement``'s ``rms_blend``: each image predicted from the blend of the
   *others* (eq. 9) with eq. 18's weights a_i / sigma(z_i), sigma taken as g'(z_i);
2. ``tsin._result``: the noise terms carried to the reported scale (sigma_s in sqrt(g) scales
   with sqrt(s), sigma_c1 in g with s);
3. ``tsin_kernels.group_sums``: the influence of a pixel on its pool's trimmed mean,
   winsorised deviation / ((1 - 2 alpha) n), and the band of g it makes;
4. ``tsin_gauge.sandwich``: the small-sample factor G / (G - 1) of the sandwich over blocks.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import mstats

from ccdcore.response import agreement as AG
from ccdcore.response.tsin import estimator as T
from ccdcore.response.tsin import gauge as TG
from ccdcore.response.tsin import kernels as TK
from ccdcore.response.brackets import BracketData, bracket_data
from ccdcore.response.scale import reference_codes
from ccdcore.simulate import tsin as sim


def sec41(seed: int, size=(64, 64), **noise):
    """One sequence of Tsin et al.'s sec. 4.1 protocol (8 exposures a factor sqrt 2 apart,
    g = (z/255)^1.2, E uniform on [0, 1]), without the blooming mask."""
    rng = np.random.default_rng(seed)
    E = sim.uniform_radiance(rng, size)
    t = np.asarray(sim.exposure_times(8, math.sqrt(2.0), math.sqrt(2.0)))
    frames = [sim.expose(E, t[k], 0.0, rng, **noise).z for k in range(t.size)]
    return bracket_data(frames, t, 8, bloom_radius=0, border=0)["L"]


# ------------------------------------------------- 1. the blend agreement (eqs. 9, 18) -----
def _small_bracket(seed: int = 11, P: int = 300):
    """4 images of g(z) = (z/255)^1.5 at exposures a factor 2 apart with small offsets b_k,
    300 pixels, 0.7 DN of output noise: codes from clipped-dark to clipped-bright."""
    rng = np.random.default_rng(seed)
    codes = np.arange(256, dtype=np.float64)
    g = (codes / 255.0) ** 1.5
    a = np.array([0.15, 0.3, 0.6, 1.2])
    b = np.array([0.0, 0.004, -0.003, 0.006])
    E = rng.uniform(0.02, 1.0, P)
    v = np.clip(a[:, None] * E[None, :] + b[:, None], 0.0, 1.0)
    z = np.rint(255.0 * v ** (1 / 1.5) + rng.normal(0.0, 0.7, v.shape))
    z = np.clip(z, 0, 255).astype(np.int32)
    data = BracketData(z=z, valid=(z > 0) & (z < 255), t=a.copy(), levels=256)
    return data, g, a, b


def _blend_rms_by_hand(z, g, a, b, lo, hi):
    """Eq. 9 with eq. 18's weights, pixel by pixel: image k predicted from the radiance
    E = sum_i w_i (g(z_i) - b_i) / a_i over the OTHER images i != k whose codes are readable
    (lo..hi), w_i = a_i / g'(z_i) normalised (eq. 18, sigma = g'); z_k's prediction is
    f(a_k E + b_k) with f = g^-1 (g increasing: linear interpolation of the inverse table).
    g' is the central difference (g(z+1) - g(z-1)) / 2: the readable codes are interior."""
    N, P = z.shape
    codes = np.arange(g.size, dtype=np.float64)
    sse, n = 0.0, 0
    for p in range(P):
        readable = [i for i in range(N) if lo <= z[i, p] <= hi]
        for k in readable:
            others = [i for i in readable if i != k]
            if not others:
                continue
            num = den = 0.0
            for i in others:
                zi = int(z[i, p])
                w = a[i] / ((g[zi + 1] - g[zi - 1]) / 2.0)
                num += w * (g[zi] - b[i]) / a[i]
                den += w
            pred = float(np.interp(a[k] * (num / den) + b[k], g, codes))
            sse += (pred - z[k, p]) ** 2
            n += 1
    return math.sqrt(sse / n), n


def test_rms_blend_is_eq9_with_eq18_weights_over_the_others():
    """``rms_blend`` against eq. 9 / eq. 18 written out pixel by pixel. Planted bugs it
    catches: the blend including the predicted image itself (the error then shrinks towards
    0), and the blend without its a_i weights (w_i = 1 / g'(z_i): the short exposures' noisy
    radiances weigh as much as the long ones'). Tolerance 1e-9 relative: the two sums differ
    only in the order of floating-point additions."""
    data, g, a, b = _small_bracket()
    lo, hi = AG.code_range(256)
    assert (lo, hi) == (10, 245)
    want, n_want = _blend_rms_by_hand(data.z, g, a, b, lo, hi)
    got = AG.channel_agreement(data, g, a, b)
    assert got.n_blend == n_want
    assert got.rms_blend == pytest.approx(want, rel=1e-9, abs=0.0)
    # about 1 DN (0.7 DN of noise in the predicted image and in the blend): measured 0.997;
    # the self-including blend gave 0.687 here, the blend without the a_i 1.176
    assert 0.8 < want < 1.2


def test_rms_blend_pools_over_channels():
    """``agreement`` pools the blend's squared errors over the channels: the RMS over every
    prediction, each channel's from eq. 9 / eq. 18 written out."""
    d1, g, a, b = _small_bracket(seed=11)
    d2, _, _, _ = _small_bracket(seed=12, P=200)
    lo, hi = AG.code_range(256)
    r1, n1 = _blend_rms_by_hand(d1.z, g, a, b, lo, hi)
    r2, n2 = _blend_rms_by_hand(d2.z, g, a, b, lo, hi)
    resp = {"g": g, "a": a, "b": b}
    got = AG.agreement({"R": d1, "G": d2}, {"R": resp, "G": resp})
    want = math.sqrt((r1 ** 2 * n1 + r2 ** 2 * n2) / (n1 + n2))
    assert got.rms_blend == pytest.approx(want, rel=1e-9, abs=0.0)


# ------------------------------------------ 2. the noise terms on the reported scale -----
def test_noise_terms_do_not_depend_on_the_fits_internal_scale(monkeypatch):
    """The fit holds g fixed at a knot of its own (:func:`tsin._anchors`, g(z) = z/255 there),
    then reports g scaled by s to g(z_hi) = z_hi/255 (z_hi = 230 for 8 bits). The noise terms must follow that scale:
    sigma_c1 is in units of g (sigma_c1² in g², times s²), sigma_s in sqrt(g) (sigma_s² a E is
    in g: times s). Fixing the fit at a different knot changes its internal scale, not the
    data: on g = (z/255)^1.2 the internal g is (z_a/255)^-0.2 times the truth, 1.45 at
    z_a = 40 and 1.02 at z_a = 230. The reported terms must agree; a conversion with the wrong
    power of s (sigma_c1 from sigma_c1² s, or sigma_s from sigma_s² s²) makes them differ by
    sqrt(1.45 / 1.02) = 1.19.

    Tolerance 5 %: measured 0.1-0.3 % at 128² (seeds 1, 2) and below 1.6 % at 96² (the two
    fits end at slightly different curves, 9e-4 apart at most).

    The band of g is reported with g(z_hi) fixed, whatever knot the fit held: it must not
    depend on the internal scale either (measured: the two bands within 0.5 % at every code;
    a band carried with the wrong power of s, or without s, differs by a factor 1.42)."""
    data = sec41(1, size=(128, 128))
    orig = T._anchors
    out = {}
    for z_a in (40, 230):
        def anchors(s, z_a=z_a):
            lo, _ = orig(s)
            return min(lo, z_a - 30), z_a
        monkeypatch.setattr(T, "_anchors", anchors)
        out[z_a] = T.estimate(data, T.TsinOptions(edge=0))
    monkeypatch.setattr(T, "_anchors", orig)
    r40, r230 = out[40], out[230]
    assert np.max(np.abs(r40.g - r230.g)) < 3e-3          # the same curve, reported
    assert r40.sigma_c1 == pytest.approx(r230.sigma_c1, rel=0.05)
    assert r40.sigma_s == pytest.approx(r230.sigma_s, rel=0.05)
    z_hi = reference_codes(256)[1]
    assert z_hi == 230
    codes = np.r_[12:z_hi, z_hi + 1:244]                  # g_err[z_hi] = 0 by definition
    np.testing.assert_allclose(r40.g_err[codes], r230.g_err[codes], rtol=0.05)
    # and near the simulator's terms on the reported scale: the truth g(230) = (230/255)^1.2 is
    # reported as 230/255, s = (230/255)^-0.2 = 1.021; sigma_c1 0.01 s, sigma_s 0.015 sqrt(s).
    # 20 %: a sanity bound (one 128² sequence; measured within 3 %), not the pin
    s = (z_hi / 255) ** -0.2
    for r in (r40, r230):
        assert r.sigma_c1 == pytest.approx(0.01 * s, rel=0.2)
        assert r.sigma_s == pytest.approx(0.015 * math.sqrt(s), rel=0.2)


# ------------------------------------------------------------ 3. group_sums and the band -----
def test_group_sums_is_the_trimmed_means_influence():
    """With every pixel its own block, the summed squares of a row's influences are the
    Tukey-McLaughlin variance of its trimmed mean (n - 1)/n times: sum_q ((w_q - w̄) /
    ((1 - 2 alpha) n))² = (n - 1) s_w² / ((1 - 2 alpha)² n²) with s_w² the winsorised variance
    (ddof 1), while scipy's trimmed_stde² = s_w² / ((1 - 2 alpha)² n). alpha = 0.17 (eq. 11
    keeps 66 %); the winsorising limits and the winsorised mean come from scipy's winsorize.
    Row sizes avoid exact multiples of 100 (where 0.17 n rounds differently in floating point:
    pinned in test_pins_planted). A factor 1/n instead of 1/((1 - 2 alpha) n) is 0.66² off.
    Tolerance 1e-10 relative: rounding only."""
    rng = np.random.default_rng(5)
    sizes = (13, 37, 58, 211, 333)
    rows = [np.sort(rng.standard_t(3, n) * 0.01 + 0.002) for n in sizes]
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    resid = np.concatenate(rows)
    lo, hi, wmean, want = [], [], [], []
    for x in rows:
        w = np.asarray(mstats.winsorize(x, limits=(0.17, 0.17)))
        lo.append(w.min())
        hi.append(w.max())
        wmean.append(w.mean())
        want.append(float(mstats.trimmed_stde(x, limits=(0.17, 0.17))) ** 2)
    # shuffle within each row: group_sums must not rely on an order
    perm = np.concatenate([offsets[i] + rng.permutation(n) for i, n in enumerate(sizes)])
    resid = resid[perm]
    G = resid.size
    egrp = np.arange(G, dtype=np.int64)                       # one pixel per block
    S = TK.group_sums(resid, egrp.astype(np.int32), offsets, np.array(lo), np.array(hi),
                      np.array(wmean), T.TRIM, G)
    assert S.shape == (len(sizes), G)
    n = np.asarray(sizes, np.float64)
    got = (S ** 2).sum(axis=1) * n / (n - 1)
    np.testing.assert_allclose(got, want, rtol=1e-10)
    # each row's influences sum to zero over its pixels (deviations from the winsorised mean)
    np.testing.assert_allclose(S.sum(axis=1), 0.0, atol=1e-15)


def test_band_matches_the_spread_of_g_over_sequences():
    """Monte Carlo over 12 sequences of the sec. 4.1 protocol at 64²: the spread of the reported
    g(z) across sequences (its SD per code, ddof 1, which no bias enters) against the reported
    band (RMS of g_err per code), pooled over codes 12..243 (z_hi = 230, fixed, left out).

    Measured on three disjoint sets of 12 seeds: 1.19, 1.27, 1.03 (the band a little narrow at
    this size; the SD of a 12-sample spread is some 20 % per code, pooled over codes whose errors
    are correlated about 10 %). Bounds 0.8 .. 1.45: a band 34 % too narrow (group_sums without
    its 1/(1 - 2 alpha)) gives 1.52 times those, 1.56 .. 1.93 (1.80 measured on these seeds);
    twice too wide would give 0.6."""
    z_hi = reference_codes(256)[1]
    codes = np.r_[12:z_hi, z_hi + 1:244]
    G, E = [], []
    for seed in range(3000, 3012):
        r = T.estimate(sec41(seed))
        G.append(r.g)
        E.append(r.g_err)
    G, E = np.array(G), np.array(E)
    assert np.allclose(G[:, z_hi], z_hi / 255, rtol=1e-12) and np.all(E[:, z_hi] == 0.0)
    sd2 = G[:, codes].var(axis=0, ddof=1)
    band2 = (E[:, codes] ** 2).mean(axis=0)
    ratio = math.sqrt(sd2.mean() / band2.mean())
    assert 0.8 < ratio < 1.45, ratio


# ------------------------------------------------ 4. the sandwich's small-sample factor -----
def test_sandwich_of_a_mean_is_the_unbiased_variance_of_the_mean():
    """A mean of G block values x_g: bread G (d/dmu of sum (x_g - mu)), scores x_g - x̄. The
    sandwich B^-1 (sum psi²) G/(G-1) B^-1 = sum (x_g - x̄)² / (G (G - 1)) = s²/G, the textbook
    unbiased variance of the mean (ddof 1). Without the small-sample factor G/(G-1) it is
    (G-1)/G of that: 0.75 at G = 4. Tolerance 1e-12 relative: rounding only."""
    x = np.array([0.3, -1.1, 2.4, 0.9])
    G = x.size
    cov = TG.sandwich(np.array([[float(G)]]), (x - x.mean())[None, :])
    assert cov.shape == (1, 1)
    assert cov[0, 0] == pytest.approx(np.var(x, ddof=1) / G, rel=1e-12)


def test_sandwich_of_a_regression_is_the_cr1_covariance_through_the_frame():
    """Least squares y = X beta over blocks of rows: bread X^T X, block scores X_g^T e_g; the
    cluster-robust covariance with the CR1 factor G/(G-1) (written out here as a sum over
    blocks), mapped by a frame F as F V F^T. 5 blocks: a missing factor is 0.8 off."""
    rng = np.random.default_rng(3)
    n, G = 40, 5
    X = np.column_stack([np.ones(n), rng.normal(size=n)])
    y = X @ np.array([1.0, -0.5]) + rng.normal(size=n)
    beta = np.linalg.lstsq(X, y, rcond=None)[0]
    e = y - X @ beta
    blk = np.arange(n) % G
    scores = np.column_stack([X[blk == g].T @ e[blk == g] for g in range(G)])
    Bi = np.linalg.inv(X.T @ X)
    meat = sum(np.outer(s, s) for s in scores.T)
    V = Bi @ meat @ Bi * G / (G - 1)
    F = np.array([[1.0, 2.0], [0.0, 1.0], [3.0, -1.0]])
    np.testing.assert_allclose(TG.sandwich(X.T @ X, scores), V, rtol=1e-12)
    np.testing.assert_allclose(TG.sandwich(X.T @ X, scores, F), F @ V @ F.T, rtol=1e-12)
