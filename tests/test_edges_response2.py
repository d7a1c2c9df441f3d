"""Edges of the sec. 3.2 estimator's compiled kernels and helpers (ccdcore.response.tsin.kernels,
ccdcore.response.tsin.estimator), the moving-pixel test (ccdcore.response.moving), the bracket's
registration step (ccdcore.response.bracket_fit) and the alignment helpers
(ccdcore.response.align).

The numba kernels are invisible to coverage: each is pinned here against a plain numpy reference
written from its docstring and Tsin, Ramesh & Kanade (2001) eqs. 9-13 and 17 on small hand-made
data (unequal gains, non-zero offsets, odd and even row sizes, sizes where the trim is exact).
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from ccdcore.errors import CcdError
from ccdcore.response import moving as mv
from ccdcore.response.brackets import BracketData
from ccdcore.response.hdr_merge import ResponseModel
from ccdcore.response.tsin import estimator as est
from ccdcore.response.tsin import kernels as kn

# ----------------------------------------------------------------------------------------------
# row statistics (eqs. 11-12, Tukey-McLaughlin standard error)


def _row_stats_ref(x: np.ndarray, trim: float, c: float) -> tuple[float, ...]:
    """Trimmed mean keeping `trim` (g = floor(α n) cut each side, α = (1 - trim)/2), MAD about
    it, winsorised variance / (n trim²)."""
    x = np.sort(x)
    n = x.size
    g = int(math.floor(0.5 * (1 - trim) * n + 1e-9))
    tm = x[g:n - g].mean()
    w = np.clip(x, x[g], x[n - g - 1])
    se = math.sqrt(w.var(ddof=1) / (n * trim * trim))
    return tm, c * float(np.median(np.abs(x - tm))), se, x[g], x[n - g - 1], w.mean()


def test_row_stats_match_a_reference_on_odd_even_and_exact_trim_sizes():
    """Per row: trimmed mean, MAD sigma (c × median |x - tm|, odd and even n), its standard
    error sqrt(winsorised var (n-1) / (n trim²)), the limits and the winsorised mean; at n = 300
    exactly 51 values are cut each side (α n = 51 in exact arithmetic)."""
    rng = np.random.default_rng(0)
    sizes = [7, 8, 300, 25, 2]
    rows = [rng.standard_t(3, n) * 0.1 + 0.3 for n in sizes]
    offsets = np.r_[0, np.cumsum(sizes)]
    resid = np.concatenate([np.sort(r) for r in rows])
    out = kn.row_stats(resid, offsets, 0.66, 1.483)
    for r, x in enumerate(rows):
        ref = _row_stats_ref(x, 0.66, 1.483)
        for got, want in zip(out, ref):
            assert got[r] == pytest.approx(want, rel=1e-12, abs=1e-15)
    # n = 300: the 51st smallest value is the lower limit
    assert out[3][2] == np.sort(rows[2])[51]


def test_sorted_mad_odd_even_and_centre_outside():
    """median |x - c| of a sorted array, c inside or beyond the data, odd and even sizes."""
    rng = np.random.default_rng(1)
    for n in (1, 2, 5, 6, 11):
        x = np.sort(rng.normal(size=n))
        for c in (float(np.median(x)), x[0] - 1.0, x[-1] + 0.5, 0.123):
            assert kn.sorted_mad(x, c) == pytest.approx(np.median(np.abs(x - c)), rel=1e-14)


def test_sort_rows_fresh_and_from_a_previous_order():
    """Each row sorted; from a previous order the result is still each row sorted, and the order
    now points at the sorted values."""
    rng = np.random.default_rng(2)
    offsets = np.array([0, 5, 5, 12, 13])
    resid = rng.normal(size=13)
    order = np.full(13, -1, np.int64)
    out = kn.sort_rows(resid, offsets, order)
    for r in range(4):
        lo, hi = offsets[r], offsets[r + 1]
        np.testing.assert_array_equal(out[lo:hi], np.sort(resid[lo:hi]))
    np.testing.assert_array_equal(resid[order], out)
    resid2 = resid + 0.3 * rng.normal(size=13)
    out2 = kn.sort_rows(resid2, offsets, order)
    for r in range(4):
        lo, hi = offsets[r], offsets[r + 1]
        np.testing.assert_array_equal(out2[lo:hi], np.sort(resid2[lo:hi]))
    np.testing.assert_array_equal(resid2[order], out2)


def test_group_sums_are_the_winsorised_influences_per_block():
    """S[r, b] = Σ over the row's pixels of block b of (clip(x, lo, hi) - wmean) / (trim n)."""
    rng = np.random.default_rng(3)
    offsets = np.array([0, 6, 15])
    resid = rng.normal(size=15)
    egrp = rng.integers(0, 4, 15).astype(np.int32)
    lo, hi = np.array([-0.5, -1.0]), np.array([0.4, 0.8])
    wmean = np.array([0.05, -0.1])
    S = kn.group_sums(resid, egrp, offsets, lo, hi, wmean, 0.66, 4)
    ref = np.zeros((2, 4))
    for r in range(2):
        for q in range(offsets[r], offsets[r + 1]):
            n = offsets[r + 1] - offsets[r]
            ref[r, egrp[q]] += (min(max(resid[q], lo[r]), hi[r]) - wmean[r]) / (0.66 * n)
    np.testing.assert_allclose(S, ref, rtol=1e-13, atol=1e-15)


def test_knot_of_a_code_identity_and_binned_up_to_the_top():
    """Identity: (code, 0); binned: u = code/step, j0 = min(floor u, K - 2), f = u - j0 (f = 1 at
    the top code)."""
    assert kn.knot(37, 1.0, True, 256) == (37, 0.0)
    step, K = 4095 / 1023, 1024
    for code in (0, 1, 4, 2000, 4094, 4095):
        j0, f = kn.knot(code, step, False, K)
        u = code / step
        assert j0 == min(int(u), K - 2) and f == pytest.approx(u - j0, abs=1e-12)
    assert kn.knot(4095, step, False, K)[1] == pytest.approx(1.0)


# ----------------------------------------------------------------------------------------------
# one pass over the pools (eqs. 9, 10, 13, 17)

def _tiny(P: int = 240, seed: int = 4, levels: int = 64) -> BracketData:
    """Four images of a 64-level camera, gains 1 : 2.3 : 5.5 : 9, with noise; clipped codes;
    image 1 unobserved at 30 pixels (their traces lack it); five pixels read code 3 in image 0
    and the top code in image 2 once (a clipped fraction of exactly 1/5)."""
    rng = np.random.default_rng(seed)
    E = rng.uniform(0.0, 1.0, P)
    t = np.array([1.0, 2.3, 5.5, 9.0])
    z = np.stack([np.clip(np.rint(6 + 50 * (t[k] * E / 9.0) ** 0.8 + rng.normal(0, 0.8, P)),
                          4, levels - 1) for k in range(4)]).astype(np.int32)
    z[3, :6] = levels - 1
    z[:, -5:] = [[3] * 5, [10] * 5, [levels - 1, 20, 20, 20, 20], [30] * 5]
    z[0, 50:53] = 2                                     # exactly the edge (clipped at edge 8)
    valid = np.ones_like(z, bool)
    valid[1, 10:40] = False
    kept = valid | (z <= 0) | (z >= levels - 1)
    return BracketData(z, valid, t, levels, shape=(12, P // 12), pixels=np.arange(P), kept=kept)


def _brute_pass(s, a: np.ndarray, b: np.ndarray, gk: np.ndarray, gpc: np.ndarray,
                wcode: np.ndarray, wimg: np.ndarray, paper: bool = False
                ) -> tuple[list, np.ndarray]:
    """Per row, the errors e = a_k Ê + b_k - g(z_k) with Ê = Σ_i w_i (g(z_i) - b_i)/a_i over
    the trace (w ∝ wimg_i wcode(z_i), Σ w = 1; the trace: observed, not the pool's image j, in
    the pool's included images), and eq. 17's regressors summed over the row's pixels with
    c_i = a_k w_i / a_i - [i = k]. ``paper``: the trace is every observed unclipped image and
    the pool predicts its own image j only."""
    R = s.rows.shape[0]
    errs = [[] for _ in range(R)]
    X = np.zeros((R, 3))
    N = s.mz.shape[1]
    K = s.knots.n
    for j in range(N):
        for m in range(K):
            for q in range(s.start[j * K + m], s.start[j * K + m + 1]):
                tr = [i for i in range(N) if s.mflag[q, i] & 1 and (
                    not s.mflag[q, i] & 2 if paper else i != j and s.inc[j, m, i])]
                if len(tr) < 2:
                    continue
                z = s.mz[q].astype(int)
                w = np.array([wimg[i] * wcode[z[i]] for i in tr])
                w = w / w.sum()
                g = gk[z]
                Ehat = sum(wi * (g[i] - b[i]) / a[i] for wi, i in zip(w, tr))
                for k in ([j] if paper else tr):
                    r = s.rowid[j, m, k]
                    if r < 0:
                        continue
                    errs[r].append(a[k] * Ehat + b[k] - g[k])
                    c = np.array([a[k] * wi / a[i] - (i == k) for wi, i in zip(w, tr)])
                    X[r] += [np.sum(c ** 2 * np.maximum(g[tr] - b[tr], 0.0)), np.sum(c ** 2),
                             np.sum(c ** 2 * gpc[z[tr]] ** 2)]
    return errs, X


def test_pool_rows_errors_regressors_and_linearisation_match_the_equations():
    """Every row's errors (eq. 10 from eq. 9's radiance with eq. 18-like weights per code and
    per image) and eq. 17's regressors equal a brute force over the memberships; J (eq. 13, the
    row's summed derivative in g) equals finite differences of the row's summed errors."""
    data = _tiny()
    s = est._setup(data, est.TsinOptions(min_pool=2))
    K, L = s.knots.n, data.levels
    a = np.array([1.1, 2.2, 5.9, 8.4])
    b = np.array([0.01, -0.02, 0.015, 0.03])
    gk = (np.arange(K) / (K - 1.0)) ** 1.2
    gpc = np.gradient(gk)
    wcode = 1.0 / (0.5 + np.arange(L) / L)
    J, X, resid, egrp = kn.pool_rows(s.start, s.mz, s.mflag, s.mgrp, s.inc, s.paper, s.rowid,
                                     s.offsets, a, b, gk, gpc, a, wcode, K,
                                     float(s.knots.step), True, True, False)
    errs, Xref = _brute_pass(s, a, b, gk, gpc, wcode, a)
    for r in range(s.rows.shape[0]):
        got = np.sort(resid[s.offsets[r]:s.offsets[r + 1]])
        np.testing.assert_allclose(got, np.sort(errs[r]), atol=1e-13)
    np.testing.assert_allclose(X, Xref, rtol=1e-10, atol=1e-13)
    blocks = data.row_bands(int(est.TsinOptions().groups))
    assert set(np.unique(egrp)) <= set(np.unique(blocks))

    def sums(g: np.ndarray) -> np.ndarray:
        _, _, res, _ = kn.pool_rows(s.start, s.mz, s.mflag, s.mgrp, s.inc, s.paper, s.rowid,
                                    s.offsets, a, b, g, gpc, a, wcode, K, float(s.knots.step),
                                    True, False, False)
        return np.add.reduceat(res, s.offsets[:-1])
    base = sums(gk)
    used = sorted(set(s.mz.ravel().tolist()))
    for t in used[::7]:
        g2 = gk.copy()
        g2[t] += 1e-6
        np.testing.assert_allclose(J[:, t], (sums(g2) - base) / 1e-6, atol=1e-5)


def test_pool_rows_paper_pools_predict_their_own_image():
    """pools="paper": a pool's one row is its own image j, predicted from every observed,
    unclipped code of the pixel (j included), counted when the trace has two images."""
    data = _tiny(seed=7)
    s = est._setup(data, est.TsinOptions(min_pool=2, pools="paper"))
    assert s.paper and np.all(s.rows[:, 0] == s.rows[:, 2])
    a, b = np.array([1.1, 2.2, 5.9, 8.4]), np.array([0.01, -0.02, 0.015, 0.03])
    gk = (np.arange(64) / 63.0) ** 1.2
    _, X, resid, _ = kn.pool_rows(s.start, s.mz, s.mflag, s.mgrp, s.inc, True, s.rowid,
                                  s.offsets, a, b, gk, np.gradient(gk), np.ones(4), np.ones(64),
                                  64, 1.0, True, True, False)
    errs, Xref = _brute_pass(s, a, b, gk, np.gradient(gk), np.ones(64), np.ones(4), paper=True)
    for r in range(s.rows.shape[0]):
        np.testing.assert_allclose(np.sort(resid[s.offsets[r]:s.offsets[r + 1]]),
                                   np.sort(errs[r]), atol=1e-13)
    np.testing.assert_allclose(X, Xref, rtol=1e-10, atol=1e-13)


def test_pool_rows_derivatives_in_the_gains_and_offsets():
    """With with_a, J's columns K + i (gain a_i) and K + N + i (offset b_i) equal finite
    differences of the rows' summed errors."""
    data = _tiny(seed=6)
    s = est._setup(data, est.TsinOptions(min_pool=2))
    K = s.knots.n
    a = np.array([1.1, 2.2, 5.9, 8.4])
    b = np.array([0.01, -0.02, 0.015, 0.03])
    gk = (np.arange(K) / (K - 1.0)) ** 1.2
    ones = np.ones(64)

    def run(a_: np.ndarray, b_: np.ndarray, with_a: bool) -> tuple:
        return kn.pool_rows(s.start, s.mz, s.mflag, s.mgrp, s.inc, s.paper, s.rowid, s.offsets,
                            a_, b_, gk, np.zeros(64), np.ones(4), ones, K,
                            float(s.knots.step), True, False, with_a)
    J = run(a, b, True)[0]
    base = np.add.reduceat(run(a, b, False)[2], s.offsets[:-1])
    for i in range(4):
        for col, (da, db) in ((K + i, (1e-7, 0.0)), (K + 4 + i, (0.0, 1e-7))):
            a2, b2 = a.copy(), b.copy()
            a2[i] += da
            b2[i] += db
            fd = (np.add.reduceat(run(a2, b2, False)[2], s.offsets[:-1]) - base) / 1e-7
            np.testing.assert_allclose(J[:, col], fd, atol=2e-5)


def test_setup_pools_traces_and_threshold():
    """Pools: a pixel's pool is its code in image j (observed and not clipped there; clipped:
    within round(edge × (L-1)/255) of 0 or the top); an image joins the trace when at most
    clip_fraction of the pool's pixels are clipped in it (exactly 1/5 joins at 0.2); rows need
    min_pool pixels, lowered for a small bracket to max(min(10, min_pool), min(min_pool,
    0.4 P/K))."""
    data = _tiny()
    opts = est.TsinOptions(min_pool=200, edge=8.0, clip_fraction=0.2)
    s = est._setup(data, opts)
    z, obs = data.z, data.observed
    e = round(8 * 63 / 255)
    assert e == 2
    clip = (z <= e) | (z >= 63 - e)
    assert s.min_pool == max(min(10, 200), min(200, 0.4 * 240 / 64))
    ref = np.zeros((4, 64, 4), bool)
    for j in range(4):
        for m in range(64):
            sel = (z[j] == m) & ~clip[j] & obs[j]
            for i in range(4):
                seen = int((sel & obs[i]).sum())
                ncl = int((sel & obs[i] & clip[i]).sum())
                ref[j, m, i] = seen > 0 and ncl <= 0.2 * seen and i != j
    np.testing.assert_array_equal(s.inc, ref)
    assert s.inc[0, 3, 2] and s.inc[0, 3, 1] and not s.inc[0, 2].any()
    counts = np.diff(s.offsets)
    assert counts.min() >= s.min_pool
    with pytest.raises(CcdError):
        est._setup(BracketData(z[:1], data.valid[:1], data.t[:1], 64), opts)


# ----------------------------------------------------------------------------------------------
# estimator helpers

def test_options_check_limits():
    """Each limit of TsinOptions.check: its boundary value accepted, the next refused."""
    ok = [dict(edge=0.0), dict(edge=63.9), dict(clip_fraction=0.0), dict(clip_fraction=0.49),
          dict(gain_prior=0.0), dict(smoothness=0.0), dict(max_iter=1), dict(min_pool=2),
          dict(groups=4), dict(pools="paper")]
    bad = [dict(edge=64.0), dict(edge=-0.1), dict(clip_fraction=0.5), dict(clip_fraction=-0.01),
           dict(eta=0.0), dict(tol=float("nan")), dict(gain_prior=-1e-9),
           dict(gain_prior=float("nan")),
           dict(smoothness=float("nan")), dict(max_iter=0), dict(min_pool=1), dict(groups=3),
           dict(pools="x")]
    for kw in ok:
        est.TsinOptions(**kw).check()
    for kw in bad:
        with pytest.raises(CcdError):
            est.TsinOptions(**kw).check()


def test_sample_cap_is_max_entries_over_n_times_n_minus_one(monkeypatch: pytest.MonkeyPatch):
    """P <= MAX_ENTRIES // (N (N-1)) keeps every pixel; one more takes an even sample of that
    many and reports the original count."""
    monkeypatch.setattr(est, "MAX_ENTRIES", 60)
    z = np.arange(33, dtype=np.int32).reshape(3, 11) % 64
    d11 = BracketData(z, np.ones_like(z, bool), np.array([1.0, 2.0, 4.0]), 64)
    d10 = d11.take(np.arange(10))
    same, n0 = est._sample(d10)
    assert same is d10 and n0 == 0
    sub, n1 = est._sample(d11)
    assert n1 == 11
    np.testing.assert_array_equal(sub.z, z[:, np.unique(np.linspace(0, 10, 10).astype(int))])


def test_sqrt_err_delta_method_and_zero():
    """sqrt with its error e / (2 sqrt v); at v <= 0: (0, sqrt(e))."""
    assert est._sqrt_err(4.0, 0.8) == (2.0, 0.2)
    assert est._sqrt_err(0.0, 0.09) == (0.0, pytest.approx(0.3))
    assert est._sqrt_err(-1.0, 0.09) == (0.0, pytest.approx(0.3))


def test_shorter_step_is_the_parabola_minimum_clipped():
    """η* = q / c of obj0 - 2 q η + c η² through the measured obj at η_t, within
    [0.1, 0.5] η_t; half the step when the parabola has no minimum or q <= 0."""
    q, c = 1.0, 4.0
    for eta in (1.0, 0.6):
        obj_t = 10.0 - 2 * q * eta + c * eta * eta
        assert est._shorter_step(10.0, obj_t, q, eta) == pytest.approx(min(max(q / c, 0.1 * eta),
                                                                          0.5 * eta))
    assert est._shorter_step(10.0, 10.0 - 2 + 40.0, 1.0, 1.0) == pytest.approx(0.1)
    assert est._shorter_step(10.0, 10.0 - 2 + 1.5, 1.0, 1.0) == pytest.approx(0.5)
    assert est._shorter_step(10.0, 11.0, 0.0, 0.8) == pytest.approx(0.4)
    assert est._shorter_step(10.0, 10.0 - 3.0, 1.0, 1.0) == pytest.approx(0.5)


def test_smoothness_relative_to_the_slope_with_its_floor():
    """gᵀ P g = Σ_i (gmed / max(g'_i, 0.1 gmed))² (D2 g)_i² over the interior knots, g' by
    central differences, gmed their positive median."""
    gk = np.array([0.0, 0.1, 0.3, 0.31, 0.31, 0.6, 1.0, 1.5])
    D2 = est._second_differences(8)
    assert D2.shape == (6, 8) and np.all(D2 @ np.arange(8.0) == 0)
    assert D2[2, 2:5].tolist() == [1, -2, 1]
    P = est._smoothness(gk, D2)
    gp = np.gradient(gk)[1:-1]
    gmed = np.median(gp[gp > 0])
    w = (gmed / np.maximum(gp, 0.1 * gmed)) ** 2
    x = np.random.default_rng(0).normal(size=8)
    assert x @ P @ x == pytest.approx(np.sum(w * (D2 @ x) ** 2), rel=1e-12)


def test_slopes_central_differences_and_two_knots():
    """g' per code from the knots' central differences (interpolated); with two knots the
    chord's slope."""
    kn3 = SimpleNamespace(n=4, codes=np.array([0.0, 5.0, 10.0, 15.0]))
    gk = np.array([0.0, 1.0, 4.0, 9.0])
    out = est._slopes(kn3, gk, 16)
    np.testing.assert_allclose(out[[0, 5, 10, 15]], [0.2, 0.4, 0.8, 1.0])
    np.testing.assert_allclose(out[7], 0.4 + 0.4 * 2 / 5)
    kn2 = SimpleNamespace(n=2, codes=np.array([0.0, 15.0]))
    np.testing.assert_allclose(est._slopes(kn2, np.array([0.2, 0.8]), 16), 0.04)


def test_anchors_are_the_weighted_quartiles_at_least_a_tenth_apart():
    """The 25th / 75th percentiles of the pools' codes weighted by their pixels; held inside
    1 .. K-2 and at least round(0.1 (K - 1)) knots apart."""
    K = 106                                  # 0.1 (K - 1) = 10.5 rounds to 10 (0.1 K to 11)

    def s_of(codes: list[int], sizes: list[int]) -> SimpleNamespace:
        rows = np.array([[0, c, 1] for c in codes])
        return SimpleNamespace(knots=SimpleNamespace(n=K), rows=rows,
                               offsets=np.r_[0, np.cumsum(sizes)])
    assert est._anchors(s_of([20, 40, 60, 80], [10, 10, 10, 10])) == (20, 60)
    assert est._anchors(s_of([20, 40, 60, 80], [10, 30, 10, 10])) == (40, 60)
    assert est._anchors(s_of([50, 52], [10, 10])) == (50, 60)
    assert est._anchors(s_of([0, 100], [10, 10])) == (1, 100)
    assert est._anchors(s_of([104, 105], [10, 10])) == (94, 104)


def test_advance_keeps_one_or_both_fixed_points():
    """Step 8-9: g + η δ made monotone, then scaled to keep g(k_hi) (k_lo free) or mapped
    affinely to keep g at both fixed points."""
    g = np.array([0.0, 0.2, 0.4, 0.6, 0.8, 1.0])
    delta = np.array([0.0, 0.1, 0.05, 0.0, -0.05, 0.1])
    p = SimpleNamespace(dg=np.ones(6), lam=0.0)
    st = SimpleNamespace(k_lo=1, k_hi=4, free=np.array([True] * 4 + [False, True]))
    new = g + 0.5 * delta
    out = est._advance(st, p, g, delta, 0.5)
    np.testing.assert_allclose(out, new * g[4] / new[4])
    st.free[1] = False
    out2 = est._advance(st, p, g, delta, 0.5)
    np.testing.assert_allclose(out2[[1, 4]], g[[1, 4]])
    np.testing.assert_allclose(np.diff(out2), np.diff(new) * (0.6 / (new[4] - new[1])))
    # a violation is pooled: the weighted mean of the two knots (weights dg + lam)
    p2 = SimpleNamespace(dg=np.array([1.0, 1.0, 3.0, 1.0, 1.0, 1.0]), lam=1.0)
    bump = np.array([0.0, 0.0, 0.3, -0.1, 0.0, 0.0])
    st.free[1] = True
    out3 = est._advance(st, p2, g, bump, 1.0)
    v = (4 * 0.7 + 2 * 0.5) / 6
    np.testing.assert_allclose(out3[2:4] * (g + bump)[4] / g[4], [v, v])


def test_prior_width_and_convergence_test():
    """The prior's width is gain_prior / sqrt(max(1, χ²)); without gains the fit converges once
    a step is below max(tol, resolution)."""
    st = SimpleNamespace(opts=SimpleNamespace(gain_prior=0.1, tol=1e-5))
    assert est._prior_width(st, 4.0) == pytest.approx(0.05)
    assert est._prior_width(st, 0.25) == pytest.approx(0.1)
    for step, res, done in ((0.9e-5, 0.0, True), (1e-5, 0.0, False), (5e-5, 1e-4, True),
                            (1e-4, 1e-4, False)):
        st = SimpleNamespace(opts=SimpleNamespace(tol=1e-5), fit_a=False, step=step,
                             resolution=res, converged=False, done=False)
        est._check_converged(st, 1.0)
        assert st.done is done and st.converged is done


# ----------------------------------------------------------------------------------------------
# moving pixels (eqs. 7, 9, 18, 19)

def _model() -> ResponseModel:
    g = (np.arange(32) / 31.0) ** 1.4
    return ResponseModel(g, np.array([1.0, 2.5, 7.0]), np.array([0.01, -0.02, 0.03]),
                         0.05, 0.01, 0.4)


def test_tables_weights_and_predictions_with_clipped_codes_out():
    """w = (a_k / σ_k(z))² with eq. 7's σ² = σ_s² (g - b_k)⁺ + σ_c1² + (g' σ_c2)², the
    prediction (g - b_k)/a_k; weight 0 at codes 0 and L - 1."""
    m = _model()
    w, pred = mv._tables(m)
    gp = np.gradient(m.g)
    for k in range(3):
        var = 0.05 ** 2 * np.maximum(m.g - m.b[k], 0) + 0.01 ** 2 + (gp * 0.4) ** 2
        np.testing.assert_allclose(w[k, 1:-1], (m.a[k] ** 2 / var)[1:-1], rtol=1e-12)
        np.testing.assert_allclose(pred[k], (m.g - m.b[k]) / m.a[k], rtol=1e-12)
    assert np.all(w[:, [0, 31]] == 0)


def test_sums_inverse_variance_mean_chi2_dof_blooms_and_extra():
    """Per pixel: Ē = Σ w p / Σ w, χ² = Σ w (p - Ē)², dof = (#w > 0) - 1 (at least 0); a
    bloomed code weighs 0; the registration term adds `extra` to each prediction's variance
    (w -> 1 / (1/w + extra))."""
    m = _model()
    w_tab, p_tab = mv._tables(m)
    rng = np.random.default_rng(5)
    zs = [rng.integers(0, 32, (4, 5)).astype(np.uint8) for _ in range(3)]
    zs[0][0, 0], zs[1][0, 0], zs[2][0, 0] = 0, 31, 12
    bloom = np.zeros((4, 5), bool)
    bloom[1, 2] = True
    zs[1][1, 2] = 15                                      # a usable code, bloomed
    extra = rng.uniform(0, 1e-3, (4, 5))
    for ex in (None, extra):
        mean, chi2, dof = mv._sums(zs, [None, bloom, None], w_tab, p_tab, ex)
        for y in range(4):
            for x in range(5):
                ws = np.array([0.0 if (k == 1 and bloom[y, x]) else w_tab[k, zs[k][y, x]]
                               for k in range(3)])
                if ex is not None:
                    ws = np.where(ws > 0, 1.0 / (1.0 / np.where(ws > 0, ws, 1) + ex[y, x]), 0)
                ps = np.array([p_tab[k, zs[k][y, x]] for k in range(3)])
                if ws.sum() == 0:
                    assert mean[y, x] == 0 and chi2[y, x] == 0 and dof[y, x] == 0
                    continue
                e = ws @ ps / ws.sum()
                assert mean[y, x] == pytest.approx(e, rel=1e-10)
                assert chi2[y, x] == pytest.approx(ws @ (ps - e) ** 2, rel=1e-6, abs=1e-12)
                assert dof[y, x] == max(int((ws > 0).sum()) - 1, 0)
    assert dof[0, 0] == 0


def test_off_mapping_quartiles_spread_floor_and_clipped_codes():
    """Off the mapping: |v - median_u| / max(IQR/1.349, 1) > z, with the comparagram's
    quartiles (smallest v whose cumulative count reaches the fraction), at least 5 pixels at
    that u, never at clipped codes of either image."""
    u = np.array([10] * 8 + [20] * 4 + [0, 10])
    v = np.array([30, 31, 31, 32, 32, 33, 34, 50] + [60, 61, 90, 62] + [5, 255])
    out = mv._off_mapping(u, v, 256, 6.0)
    # u = 10 (8 pixels): q25 = 31, median 32, q75 = 33 -> spread max(2/1.349, 1) = 1.48
    assert out.tolist()[:8] == [False] * 7 + [True]
    assert not out[8:12].any()                   # 4 pixels at u = 20: too few
    assert not out[12] and not out[13]           # clipped codes
    v2 = v.copy()
    for far, off in ((41, True), (40, False)):  # 9 / 1.4826 = 6.07 and 8 / 1.4826 = 5.40 spreads
        v2[7] = far
        assert bool(mv._off_mapping(u, v2, 256, 6.0)[7]) is off
    # a spread below one code is floored at 1: 7 codes off a tight mapping is beyond 6
    u3 = np.array([10] * 6)
    v3 = np.array([30, 30, 30, 30, 30, 37])
    assert mv._off_mapping(u3, v3, 256, 6.0).tolist() == [False] * 5 + [True]
    v3[5] = 36
    assert not mv._off_mapping(u3, v3, 256, 6.0).any()


def test_level_scale_small_and_binned():
    """Fewer than 20 × 32 values: the whole scale everywhere; else each value's bin median (32
    equal-count bins of the level), at least the whole scale."""
    u = np.linspace(0.5, 2.0, 639)
    np.testing.assert_array_equal(mv._level_scale(u, u, 0.9), np.full(639, 0.9))
    n = 640
    level = np.arange(n, dtype=float)
    uu = np.repeat(np.linspace(0.2, 3.0, 32), 20)
    out = mv._level_scale(uu, level, 1.0)
    np.testing.assert_allclose(out, np.maximum(uu, 1.0))


def test_regions_open_then_grow():
    """A line one pixel wide, a 2 × 2 block and single pixels go; a 3 × 3 block stays and grows
    by `grow`."""
    raw = np.zeros((20, 20), bool)
    raw[2, 2:18] = True
    raw[10:13, 10:13] = True
    raw[5, 5] = True
    raw[15:17, 3:5] = True                                # 2 x 2: smaller than the square
    out = mv._regions(raw, 2)
    ref = np.zeros((20, 20), bool)
    ref[8:15, 8:15] = True
    np.testing.assert_array_equal(out, ref)
    np.testing.assert_array_equal(mv._regions(raw, 0), raw & (np.arange(20)[:, None] >= 10)
                                  & (np.arange(20)[:, None] <= 12))


# ----------------------------------------------------------------------------------------------
# registration step of a session's bracket (bracket_fit.register_frames)

def _fake_alignment(shifts: list[tuple[bool, float, float, float]], applied: bool = False
                    ) -> SimpleNamespace:
    sh = [SimpleNamespace(registered=r, dx=dx, dy=dy, rotation=rot,
                          reason=f"frame {k} too plain") for k, (r, dx, dy, rot)
          in enumerate(shifts)]
    return SimpleNamespace(shifts=sh, any_applied=applied, describe=lambda: "aligned",
                           to_dict=lambda: {})


def _register(monkeypatch: pytest.MonkeyPatch, shifts: list, shape: tuple[int, int] = (64, 80),
              applied: bool = False, hole: bool = True) -> tuple:
    from ccdcore.response import align as al
    from ccdcore.response import bracket_fit as bf
    monkeypatch.setattr(al, "estimate_alignment", lambda frames, names: _fake_alignment(
        shifts, applied))
    valid = np.ones(shape, bool)                           # the pixels valid in all frames
    valid[0, 0] = not hole
    monkeypatch.setattr(al, "apply_alignment", lambda frames, alignment: (
        [f + 1 for f in frames], valid))
    frames = [np.full(shape, k, np.uint8) for k in range(len(shifts))]
    return bf.register_frames(frames, ["a", "b", "c"], "auto")


def test_register_frames_tripod_drift_limit_by_shift_and_rotation(monkeypatch: pytest.MonkeyPatch):
    """An unregistrable frame is kept when every registered frame moved by at most 1 px (shift
    plus |rotation| × half the diagonal hypot(H-1, W-1)), else left out."""
    _, reg, no_data, keep = _register(monkeypatch, [(False, 0, 0, 0), (True, 0, 0, 0),
                                                    (True, 0.6, 0.8, 0.0)])
    assert keep == [0, 1, 2] and no_data is None and "kept as it is" in reg.text
    assert "1.00 px" in reg.text
    _, _, _, keep = _register(monkeypatch, [(False, 0, 0, 0), (True, 0, 0, 0),
                                            (True, 0.6, 0.81, 0.0)])
    assert keep == [1, 2]
    half_diag = 0.5 * math.hypot(63, 79)
    for reach, kept in ((0.995, True), (1.005, False)):
        rot = -math.degrees(reach / half_diag)
        _, _, _, keep = _register(monkeypatch, [(False, 0, 0, 0), (True, 0, 0, 0),
                                                (True, 0.0, 0.0, rot)])
        assert (keep == [0, 1, 2]) is kept


def test_register_frames_resampled_no_data_and_limits(monkeypatch: pytest.MonkeyPatch):
    """Resampled frames come with the pixels an aligned frame lacks; fewer than two registered
    frames: taken as they are; frames under 2 × TILE_MIN a side are not registered (exactly
    2 × TILE_MIN is); 'off' and an unknown choice."""
    from ccdcore.response import bracket_fit as bf
    out, reg, no_data, keep = _register(monkeypatch, [(True, 0, 0, 0), (True, 2.0, 0, 0),
                                                      (True, 0, 0, 0)], applied=True)
    assert keep == [0, 1, 2] and out[0][0, 0] == 1 and reg.text == "aligned"
    assert no_data is not None and no_data.sum() == 1 and no_data[0, 0]
    assert _register(monkeypatch, [(True, 0, 0, 0), (True, 2.0, 0, 0), (True, 0, 0, 0)],
                     applied=True, hole=False)[2] is None
    out, reg, _, keep = _register(monkeypatch, [(True, 0, 0, 0), (False, 0, 0, 0),
                                                (False, 0, 0, 0)])
    assert keep == [0, 1, 2] and "taken as they are" in reg.text and "frame 2" in reg.text
    out, reg, _, _ = _register(monkeypatch, [(True, 0, 0, 0)] * 3, shape=(63, 90))
    assert reg.alignment is None and "90 x 63 pixels" in reg.text and "at least 64" in reg.text
    out, reg, _, _ = _register(monkeypatch, [(True, 0, 0, 0)] * 3, shape=(90, 63))
    assert reg.alignment is None
    frames = [np.zeros((70, 70), np.uint8)] * 2
    assert bf.register_frames(frames, ["a", "b"], "off")[1] is None
    assert bf.register_frames(frames[:1], ["a"])[1] is None
    with pytest.raises(CcdError):
        bf.register_frames(frames, ["a", "b"], "on")


# ----------------------------------------------------------------------------------------------
# alignment helpers (ccdcore.response.align)

def _shift(dx: float, dy: float, rot: float):
    from ccdcore.response.align import FrameShift
    return FrameShift("f", dx, dy, rot, 0.0, 0.0, 0.0, True, "", True)


def test_matrix_samples_at_the_simulation_convention_on_a_rectangle():
    """affine_transform's (row, col) matrix and offset sample p' = c + R(θ)(p - c) + (dx, dy):
    the same point as the handheld simulation's transform matrix (x, y order), c the centre of
    an H × W frame; the centre of a level block-averaged by f is ((H-1)/2 - (f-1)/2)/f."""
    from ccdcore.response import align as al
    from ccdcore.simulate.handheld import transform_matrix
    shape = (30, 52)
    s = _shift(1.25, -2.5, 3.0)
    M, off = al._matrix(s, shape)
    T = np.array(transform_matrix((1.25, -2.5, 3.0), shape))
    for x, y in ((0, 0), (51, 3), (10, 29)):
        row, col = M @ np.array([y, x], float) + off
        qx, qy = T @ np.array([x, y, 1.0])
        assert (row, col) == (pytest.approx(qy, abs=1e-12), pytest.approx(qx, abs=1e-12))
    np.testing.assert_allclose(al._centre((30, 52), 1), [14.5, 25.5])
    np.testing.assert_allclose(al._centre((30, 52), 4), [(14.5 - 1.5) / 4, (25.5 - 1.5) / 4])


def test_inside_is_where_the_sample_point_lies_in_the_frame():
    """A reference pixel is inside when both coordinates of its sample point lie in
    [0, H-1] × [0, W-1] (brute force over every pixel, shifted and rotated)."""
    from ccdcore.response import align as al
    shape = (21, 34)
    for s in (_shift(2.5, -1.0, 0.0), _shift(-0.5, 3.0, 4.0), _shift(0.0, 0.0, -7.0)):
        M, off = al._matrix(s, shape)
        Y, X = np.mgrid[0:21, 0:34]
        pts = np.einsum("ij,jhw->ihw", M, np.stack([Y, X]).astype(float)) + off[:, None, None]
        ref = ((pts[0] >= -1e-6) & (pts[0] <= 20 + 1e-6) & (pts[1] >= -1e-6)
               & (pts[1] <= 33 + 1e-6))
        np.testing.assert_array_equal(al._inside(s, shape), ref)


def test_rigid_fit_recovers_rotation_and_shift_with_its_covariance():
    """q = c + R(θ)(p - c) + t recovered exactly (residuals 0, covariance at the floor
    σ² = 0.02² times (JᵀJ)⁻¹); with noise, σ² = Σ res² / (2n - 3), J the derivatives of
    the model in (θ, ty, tx) (finite differences); without rotation θ = 0, dof 2n - 2."""
    from ccdcore.response import align as al
    rng = np.random.default_rng(8)
    p = rng.uniform(0, 100, (9, 2))
    c = np.array([40.0, 55.0])
    params = np.array([0.03, 1.5, -2.25])
    q = al._apply_fit(params, p, c)
    th = 0.03
    d = p - c
    np.testing.assert_allclose(q[:, 0], c[0] + math.sin(th) * d[:, 1] + math.cos(th) * d[:, 0]
                               + 1.5)
    got, cov, res = al._fit(p, q, c, True)
    np.testing.assert_allclose(got, params, atol=1e-10)
    np.testing.assert_allclose(res, 0.0, atol=1e-9)

    def jac(prm: np.ndarray) -> np.ndarray:
        J = np.zeros((18, 3))
        for i in range(3):
            e = np.zeros(3)
            e[i] = 1e-7
            J[:, i] = ((al._apply_fit(prm + e, p, c) - al._apply_fit(prm - e, p, c)) / 2e-7).ravel()
        return J
    J = jac(params)
    np.testing.assert_allclose(cov, 0.02 ** 2 * np.linalg.inv(J.T @ J), rtol=1e-5)
    qn = q + rng.normal(0, 0.3, q.shape)
    got, cov, res = al._fit(p, qn, c, True)
    var = np.sum(res ** 2) / (18 - 3)
    np.testing.assert_allclose(cov, var * np.linalg.inv(jac(got).T @ jac(got)), rtol=1e-5)
    got0, cov0, res0 = al._fit(p, qn, c, False)
    assert got0[0] == 0.0 and np.all(cov0[0] == 0)
    np.testing.assert_allclose(got0[1:], (qn - p).mean(axis=0))
    var0 = np.sum(res0 ** 2) / (18 - 2)
    np.testing.assert_allclose(cov0[1:, 1:], var0 * np.eye(2) / 9, rtol=1e-9)


def test_robust_fit_trims_an_outlier_and_needs_min_tiles():
    """A tile 2 px off among tiles scattered by 0.2 px is left out (3.5 robust sigmas) and the
    rest fit by their mean shift; fewer than MIN_TILES agreeing tiles: None."""
    from ccdcore.response import align as al
    rng = np.random.default_rng(9)
    p = rng.uniform(0, 100, (8, 2))
    c = np.array([50.0, 50.0])
    q = al._apply_fit(np.array([0.0, 0.7, -1.2]), p, c) + rng.normal(0, 0.2, (8, 2))
    q[3] += [1.5, -1.5]                       # 2.1 px: beyond 3.5 sigma (0.7 px), within 10
    params, cov, kept, sigma = al._robust_fit(p, q, c, False)
    assert kept.tolist() == [True] * 3 + [False] + [True] * 4
    np.testing.assert_allclose(params[1:], (q - p)[kept].mean(axis=0), atol=1e-12)
    assert 0.05 < sigma < 0.5
    exact = al._apply_fit(np.array([0.0, 0.7, -1.2]), p, c)
    assert al._robust_fit(p[:4], exact[:4], c, False)[2].all()
    assert al._robust_fit(p[:3], exact[:3], c, False) is None


def test_grid_tile_side_and_counts_on_a_wide_level():
    """Side: the power of two of min(H, W) / 4 within [TILE_MIN, TILE_MAX]; 4 to 8 tiles per
    axis, spread evenly from 0 to the far edge."""
    from ccdcore.response import align as al
    side, corners = al._grid((300, 1000))
    assert side == 64
    ys = sorted({y for y, _ in corners})
    xs = sorted({x for _, x in corners})
    assert ys == np.linspace(0, 236, 4).round().astype(int).tolist()
    assert xs == np.linspace(0, 936, 8).round().astype(int).tolist()
    assert al._grid((100, 100))[0] == al.TILE_MIN
    assert al._grid((4000, 5000))[0] == al.TILE_MAX
    assert al._grid((512, 600))[0] == 128


def test_merge_moving_takes_one_exposure_in_the_documented_order():
    """Moving pixels get one image's (g(z) - b)/a and σ/a (eq. 19, N = 1), flag FLAG_MOVING,
    used 1: the reference where well exposed (10-90 % of the range); else the nearest
    well-exposed image (ties: the earlier) that agrees with the reference's code within 3 σ;
    else the reference's usable code; else the nearest usable one. Others are untouched."""
    from ccdcore.response.hdr_merge import FLAG_MOVING, HdrResult, noise_sigma
    g = np.arange(256) / 255.0
    m = ResponseModel(g, np.array([1.0, 4.0, 16.0]), np.array([0.0, 0.01, -0.01]),
                      0.02, 0.002, 0.5)
    # pixels (0, 0..6): expected source image per pixel
    z = np.zeros((3, 2, 8), np.uint8)
    z[:, 0, 0] = [25, 100, 255]         # reference well exposed -> 1
    z[:, 0, 1] = [2, 10, 40]            # ref poor; image 2 agrees (40/16 vs 10/4) -> 2
    z[:, 0, 2] = [2, 10, 200]           # ref poor; image 2 disagrees -> ref's usable code: 1
    z[:, 0, 3] = [100, 255, 255]        # ref clipped; image 0 well exposed -> 0
    z[:, 0, 4] = [0, 255, 5]            # only image 2 usable (poorly) -> 2
    z[:, 0, 5] = [60, 255, 200]         # ref clipped; 0 and 2 equidistant -> the earlier, 0
    z[:, 0, 6] = [0, 255, 255]          # nothing usable -> unchanged
    z[:, 0, 7] = [2, 255, 100]          # ref clipped: well-exposed 2 before usable 0 -> 2
    frames = [z[k] for k in range(3)]
    mask = np.zeros((2, 8), bool)
    mask[0] = True
    moving = mv.MovingPixels(mask, 8, 1.0, 1e-4, 1, "f1", 16)
    res = HdrResult(np.full((2, 8), -1.0), np.full((2, 8), -2.0), np.zeros((2, 8), np.uint8),
                    np.full((2, 8), 3, np.int16), ("L",), "mono")
    out = mv.merge_moving(res, frames, {"L": m}, moving, bloom_radius=0)
    for x, k in [(0, 1), (1, 2), (2, 1), (3, 0), (4, 2), (5, 0), (7, 2)]:
        zz = int(z[k, 0, x])
        assert out.radiance[0, x] == pytest.approx((g[zz] - m.b[k]) / m.a[k], rel=1e-12)
        assert out.sigma[0, x] == pytest.approx(noise_sigma(m, np.array([zz]), k)[0] / m.a[k])
        assert out.flags[0, x] == FLAG_MOVING and out.used[0, x] == 1
    assert out.radiance[0, 6] == -1.0 and out.flags[0, 6] == 0 and out.used[0, 6] == 3
    assert np.all(out.radiance[1] == -1.0) and np.all(out.used[1] == 3)
    none = mv.MovingPixels(np.zeros((2, 8), bool), 0, 1.0, 1e-4, 1, "f1", 16)
    assert mv.merge_moving(res, frames, {"L": m}, none) is res


def test_find_moving_with_nothing_testable_and_the_descriptions():
    """Frames whose every code is clipped: nothing tested (scale NaN, count 0) and the line says
    so; the other lines give the count, its percentage of the frame and the pixels left out."""
    frames = [np.full((8, 10), v, np.uint8) for v in (0, 255, 255)]
    model = SimpleNamespace(g=np.arange(256) / 255.0, a=np.array([1.0, 2.0, 4.0]),
                            b=np.zeros(3), sigma_s=0.01, sigma_c1=0.001, sigma_c2=0.5)
    out = mv.find_moving(frames, {"L": model}, names=["a", "b", "c"])
    assert out.tested == 0 and out.count == 0 and math.isnan(out.scale)
    assert out.reference == 1 and out.reference_name == "b"
    assert "not tested" in out.describe() and out.to_dict()["scale"] is None
    m = np.zeros((10, 20), bool)
    m[:5, :5] = True
    hit = mv.MovingPixels(m, 25, 1.5, 1e-4, 2, "c.jpg", 150, excluded=1234, delta=0.25)
    line = hit.describe()
    assert "25 pixels (12 %)" in line and "c.jpg" in line and "1,234 pixels" in line
    assert "0.25 px" in line
    assert hit.to_dict()["fraction"] == pytest.approx(0.125)
    quiet = mv.MovingPixels(np.zeros((10, 20), bool), 0, 1.5, 1e-4, 2, "c", 150)
    assert quiet.describe().startswith("moving objects: none")
    assert "left out" not in quiet.describe()


def test_handheld_plan_layers_radiance_masks_and_truth(tmp_path):
    """The reference frame sees the scene's crop with its movers pasted, times the vignetting;
    another frame the warp of that; masks in the frame's own grid (any bilinear weight) and in
    the reference grid (the crop); truth lists their pixel counts and the union."""
    from ccdcore.simulate import handheld as hh
    opts = dict(handheld_shift=1.5, handheld_rotation=0.5, mover_speed=3.0, movers=2,
                mover_size=0.3)
    p = hh.plan(opts, 3, 5, (20, 30))
    m = p.margin
    rng = np.random.default_rng(0)
    scene = rng.uniform(0.0, 1.0, (20 + 2 * m, 30 + 2 * m)) ** 6   # median 1/64, mean 1/7
    V = np.linspace(0.8, 1.0, 30)[None, :] * np.ones((20, 1))
    p.attach(scene, V)
    assert len(p.movers) == 2 and all(mo.reference == 2 for mo in p.movers)
    level = float(np.median(scene))                       # the movers' level: the scene median
    assert all(0.4 * level <= mo.colour[0] <= 2.5 * level for mo in p.movers)
    assert all(mo.radii[1] == pytest.approx(0.5 * 0.3 * 20) for mo in p.movers)
    S2, mask2 = p._layers(2)
    ref_mask, ref_rad = hh.render_movers(p.movers, 2, scene.shape, offset=m)
    np.testing.assert_array_equal(mask2, ref_mask)
    np.testing.assert_allclose(S2, np.where(ref_mask, ref_rad[..., 0], scene))
    np.testing.assert_allclose(p.frame_radiance(2), (p.crop(S2) * V).astype(np.float32))
    S0, mask0 = p._layers(0)
    np.testing.assert_allclose(p.frame_radiance(0),
                               (hh.warp_scene(S0, p.transforms[0], (20, 30), m) * V)
                               .astype(np.float32), rtol=1e-6)
    own, ref = p.masks()
    assert own.shape == ref.shape == (5, 20, 30)
    np.testing.assert_array_equal(ref[0], p.crop(mask0))
    np.testing.assert_array_equal(own[0], hh.warp_scene(mask0.astype(float), p.transforms[0],
                                                        (20, 30), m) > 0)
    frames = [{"path": f"f{k}.tif", "stack": 0, "index": k} for k in range(5)]
    tr = p.truth(tmp_path, frames)
    assert tr["handheld"]["reference"] == "f2.tif" and tr["handheld"]["margin"] == m
    assert tr["movers"]["pixels"] == [int(o.sum()) for o in own]
    assert tr["movers"]["moving_pixels"] == int(ref.any(axis=0).sum())
    np.testing.assert_array_equal(np.load(tmp_path / "truth" / "moving_mask.npy"),
                                  ref.any(axis=0))
    assert tr["transforms"][4]["dx"] == p.transforms[4][0]
    assert "2 moving object(s)" in p.note()
    still = hh.plan(dict(opts, movers=0), 3, 5, (20, 30))
    still.attach(scene[:20 + 2 * still.margin, :30 + 2 * still.margin], None)
    S, mk = still._layers(1)
    assert not mk.any() and S is still.scene and "moving" not in still.note()


def _guard_state(last: tuple | None, eta: float = 1.0, fit_a: bool = False,
                 resolution: float = 0.0) -> SimpleNamespace:
    return SimpleNamespace(gk=np.array([0.0, 0.3, 0.6, 1.0]), last=last, it=3, phase=1, step=0.1,
                           a_step=0.0, history=[], eta=eta, resolution=resolution,
                           fit_a=fit_a, free=np.array([True, True, False, True]), k_lo=1, k_hi=2,
                           flat=0, restore=False, converged=False, done=False, reuse=None)


def test_guard_objective_rejection_shorter_step_and_flat():
    """Phase 1's objective Σ W tm² + λ gᵀ P g; a rise takes the last accepted curve again with
    the parabola's shorter step (or, below 1/8 of a step, ends the fit there); three rounds in a
    row gaining less than FLAT of the objective end it as flat."""
    p = SimpleNamespace(W=np.array([1.0, 4.0]), tm=np.array([0.5, 0.25]), lam=2.0,
                        P_s=np.eye(4), dg=np.ones(4))
    st = _guard_state(None)
    obj = 0.25 + 0.25 + 2.0 * (0.09 + 0.36 + 1.0)
    assert est._guard(st, p, 1.0) == (pytest.approx(obj), False) and st.flat == 0
    g_last = np.array([0.0, 0.25, 0.6, 1.0])
    delta = np.array([0.0, 0.05, 0.0, 0.0])
    last = (obj - 0.01, g_last, delta, 0.05, 2.0, "pass")
    st = _guard_state(last)
    _, ended = est._guard(st, p, 1.0)
    eta = est._shorter_step(obj - 0.01, obj, 2.0, 1.0)
    assert ended and st.eta == pytest.approx(eta) and st.history[-1]["rejected"]
    np.testing.assert_allclose(st.gk, est._advance(st, p, g_last, delta, eta))
    assert est._shorter_step(obj - 0.01, obj, 2.0, 0.2) == pytest.approx(2 / 20.25)
    st = _guard_state(last, eta=0.2)                      # the next step 0.099 < 1/8
    _, ended = est._guard(st, p, 1.0)
    assert ended and st.restore and st.converged and st.gk is g_last and st.reuse == "pass"
    st = _guard_state(last, eta=0.2, fit_a=True)
    _, ended = est._guard(st, p, 1.0)
    assert ended and st.phase == 2 and not st.free[1] and not st.converged
    st = _guard_state(last, resolution=0.05 * 0.5 + 1e-9)
    est._guard(st, p, 1.0)
    assert st.restore                                     # the step is below the resolution
    flat_last = (obj * (1 + 0.5e-5), g_last, delta, 0.05, 2.0, "pass")
    st = _guard_state(flat_last)
    for k in range(3):
        _, ended = est._guard(st, p, 1.0)
        assert st.flat == k + 1 and ended is (k == 2)
    assert st.converged and st.done
    st = _guard_state((obj * (1 + 2e-5), g_last, delta, 0.05, 2.0, "pass"))
    st.flat = 2
    est._guard(st, p, 1.0)
    assert st.flat == 0 and not st.done


def test_guard_gains_cost_with_the_prior_rejection_and_flat():
    """Phase 2's cost Σ W tm² + Σ (ln(a/t) / width)², width = gain_prior / sqrt(max(1, χ²)); a
    rise restores the kept state and quarters the trust radius (below 1e-3: converged); a gain
    below max(FLAT × cost, χ²) three times in a row is flat."""
    t = np.array([1.0, 2.0, 4.0])
    a = t * np.array([1.1, 1.0, 0.95])
    p = SimpleNamespace(W=np.array([1.0, 4.0]), tm=np.array([0.5, 0.25]))

    def st_of(kept: tuple | None, radius: float = 1.0) -> SimpleNamespace:
        return SimpleNamespace(opts=SimpleNamespace(gain_prior=0.1), a=a, t=t, b=np.zeros(3),
                               gk=np.zeros(4), kept=kept, radius=radius, history=[], it=2,
                               phase=2, step=0.0, a_step=0.0, flat=0, converged=False,
                               restore=False, done=False, reuse=None)
    chi2 = 4.0
    cost = 0.5 + float(np.sum((np.log(a / t) / (0.1 / 2.0)) ** 2))
    st = st_of(None)
    assert est._guard_gains(st, p, chi2) is False
    assert st.kept[0] == pytest.approx(cost) and st.kept[5] is p and st.flat == 0
    kept = (cost - 1e-3, chi2, "g", "a", "b", "pass")
    st = st_of(kept, radius=0.5)
    assert est._guard_gains(st, p, chi2) is True
    assert (st.gk, st.a, st.b, st.reuse) == ("g", "a", "b", "pass")
    assert st.radius == 0.125 and not st.converged and st.history[-1]["rejected"]
    st = st_of(kept, radius=0.0039)
    est._guard_gains(st, p, chi2)
    assert st.converged and st.restore
    st = st_of(kept, radius=0.0041)
    est._guard_gains(st, p, chi2)
    assert not st.converged
    st = st_of((cost + 3.9, chi2, "g", "a", "b", "pass"))     # gains 3.9 < χ² = 4: flat
    for k in range(3):
        assert est._guard_gains(st, p, chi2) is (k == 2)
        st.kept = (cost + 3.9,) + st.kept[1:]
    assert st.done and st.converged
    st = st_of((cost + 4.1, chi2, "g", "a", "b", "pass"))
    st.flat = 2
    assert est._guard_gains(st, p, chi2) is False and st.flat == 0
    st = st_of(None)
    st.opts.gain_prior = 0.0
    est._guard_gains(st, p, chi2)
    assert st.kept[0] == pytest.approx(0.5)
