"""Edge pins of change detection (Tsin, Ramesh & Kanade 2001, sec. 5): ccdcore.change.detector,
ccdcore.change.kernels and ccdcore.change.frames.

What is pinned, each against an expectation derived by hand or from numpy/scipy on the same
data (never a snapshot): the option ranges at their exact ends; the calibrated threshold (the
sample's 1 - P quantile from exactly 20 / P values on, the scaled χ² one below) and the
false-alarm figures at a value exactly on the threshold; the labels at d² exactly on the
threshold, the cluster order, the shade's open factor range; the count of changed pixels the
min_region rule relabels; the background scale s and its gate; the smallest valid frame; d²,
ln det Σ_e and the normal equations against direct formulas for 1, 2 and 3 channels; the
trimmed cost; the frame-set radiance, its clipping, slope, and the shrunk sigma of eq. 7's
model with the frames' spread; the sRGB response when nothing else is there; the checks of
frame sets and of two brackets (ccdcore.change.session) before any merge.  The dark model
o + c·t (ccdcore.dark.model, Healey & Kondepudy 1994 eq. 43): the weighted fit and its
covariance against numpy's weighted least squares with unequal weights, the frames' noise
line and its clamps, two frames, the hot-current rule's fallback, the darks' temperature.
Small arrays only (the whole file runs in seconds).
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

from ccdcore.change import detector as CH
from ccdcore.change import frames as CF
from ccdcore.change import kernels as CK
from ccdcore.dark import model as DM
from ccdcore.errors import CcdError


# -- helpers ----------------------------------------------------------------------------------
def _result(d2: np.ndarray, valid: np.ndarray, background: np.ndarray, *, scale: float = 2.0,
            dof: int = 3, pfa: float = 0.01, min_region: int = 1,
            shade: tuple[float, float] | None = None, shade_k: np.ndarray | None = None,
            shade_d2: np.ndarray | None = None) -> CH.ChangeResult:
    """A ChangeResult built by hand: one cluster per plane of ``d2`` (labels 0, 1, ...)."""
    n = d2.shape[-1]
    C = dof
    clusters = [CH.Cluster(k, np.eye(C), np.zeros((C * C, C * C)), 0, 1.0) for k in range(n)]
    H, W = valid.shape
    return CH.ChangeResult(clusters, d2, valid, np.sort(background), scale, dof, pfa,
                           np.zeros((H, W, C)), min_region=min_region, shade=shade,
                           shade_k=shade_k, shade_d2=shade_d2)


# -- options ----------------------------------------------------------------------------------
@pytest.mark.parametrize("kw", [dict(pfa=0.4999), dict(pfa=1e-9), dict(coverage=0.1),
                                dict(coverage=0.9), dict(max_clusters=1),
                                dict(min_region=1), dict(min_pixels=1e-9),
                                dict(shade=(0.01, 1.01)), dict(shade=(0.99, 50.0))])
def test_options_accepted_at_the_ends_of_their_ranges(kw: dict) -> None:
    """The documented ranges are closed where the docstring says so: coverage [0.1, 0.9], at
    least one cluster, min_region >= 1; pfa and the shade's factors inside theirs."""
    CH.ChangeOptions(**kw).check()


@pytest.mark.parametrize("kw,field", [(dict(pfa=0.5), "pfa"), (dict(pfa=0.0), "pfa"),
                                      (dict(coverage=0.0999), "coverage"),
                                      (dict(coverage=0.9001), "coverage"),
                                      (dict(max_clusters=0), "max_clusters"),
                                      (dict(min_pixels=0.0), "min_pixels"),
                                      (dict(min_region=0), "min_region"),
                                      (dict(shade=(0.5, math.inf)), "shade"),
                                      (dict(shade=(1.0, 2.0)), "shade"),
                                      (dict(shade=(0.5, 1.0)), "shade")])
def test_options_refused_just_outside_their_ranges(kw: dict, field: str) -> None:
    """pfa in the open (0, 0.5), coverage outside [0.1, 0.9], no cluster, min_pixels 0,
    min_region 0, a shade range not 0 < k_min < 1 < k_max < inf: a CcdError naming it."""
    with pytest.raises(CcdError) as err:
        CH.ChangeOptions(**kw).check()
    assert field in str(err.value)


# -- the threshold ----------------------------------------------------------------------------
def test_threshold_is_the_sample_quantile_from_exactly_20_over_p_values() -> None:
    """Module docstring, step 3: the empirical 1 - P quantile when the sample holds at least
    20 / P values, the scaled χ² quantile when fewer. P = 0.1: 200 values use the quantile
    (numpy's, linear), 199 the scaled χ²."""
    bg = np.arange(1.0, 201.0)                       # 1..200
    assert CH._threshold(bg, 3.0, 2, 0.1) == pytest.approx(np.quantile(bg, 0.9), rel=1e-12)
    assert CH._threshold(bg[:199], 3.0, 2, 0.1) == pytest.approx(
        3.0 * stats.chi2.isf(0.1, 2), rel=1e-12)
    assert CH._threshold(bg[:199], 3.0, 4, 0.1) == pytest.approx(
        3.0 * stats.chi2.isf(0.1, 4), rel=1e-12)
    for bad in (0.0, 1.0, -0.1):
        with pytest.raises(CcdError, match="false-alarm"):
            CH._threshold(bg, 1.0, 3, bad)


def test_observed_pfa_does_not_count_a_value_exactly_on_the_threshold() -> None:
    """observed_pfa is the fraction of the sample *above* the threshold: a value equal to it
    is not a false alarm (labels take d² <= threshold as unchanged); an empty sample: NaN."""
    valid = np.ones((2, 2), bool)
    r = _result(np.zeros((2, 2, 1)), valid, np.array([4.0, 1.0, 3.0, 2.0]))
    assert r.observed_pfa(2.0) == pytest.approx(0.5)
    assert r.observed_pfa(0.5) == pytest.approx(1.0)
    assert r.observed_pfa(4.0) == 0.0
    assert r.observed_pfa(3.5) == pytest.approx(0.25)
    empty = _result(np.zeros((2, 2, 1)), valid, np.array([]))
    assert math.isnan(empty.observed_pfa(1.0))


def test_labels_at_the_threshold_cluster_order_and_undetermined() -> None:
    """Step 6: a pixel takes the first cluster whose d² is <= the threshold (equality is
    unchanged), else change (255); invalid pixels 254 whatever their d². The background
    sample is small (scaled χ²: threshold s·χ²₃(1 - P)); the chi2 threshold is unscaled."""
    thr = 2.0 * float(stats.chi2.isf(0.01, 3))
    d2 = np.array([[[thr, 0.0], [thr * 1.0000001, thr], [1e9, 1e9]],
                   [[thr * 2, thr * 2], [0.0, 0.0], [5.0, 1.0]]])
    valid = np.array([[True, True, True], [True, False, True]])
    r = _result(d2, valid, np.ones(10))
    assert r.threshold == thr
    assert r.chi2_threshold() == pytest.approx(stats.chi2.isf(0.01, 3), rel=1e-12)
    assert r.chi2_threshold(0.2) == pytest.approx(stats.chi2.isf(0.2, 3), rel=1e-12)
    expect = np.array([[0, 1, 255], [255, 254, 0]], np.uint8)
    np.testing.assert_array_equal(r.labels, expect)
    assert [c.pixels for c in r.clusters] == [2, 1]
    assert r.counts() == {0: 2, 1: 1, 254: 1, 255: 2}
    best = r.d2_best
    assert math.isnan(best[1, 1]) and best[1, 2] == 1.0 and best[0, 1] == thr
    d = r.to_dict()
    assert d["changed_pixels"] == 2 and d["undetermined_pixels"] == 1
    # background_d2_mean: cluster 0's d² over the pixels labelled 0 (thr and 5.0)
    assert d["background_d2_mean"] == pytest.approx((thr + 5.0) / 2)
    assert d["background_d2_mean_all"] == pytest.approx(1.0)
    assert d["threshold_chi2"] == pytest.approx(stats.chi2.isf(0.01, 3))
    assert d["shade"] is None and d["shade_threshold"] is None
    # another P re-thresholds: P = 0.2 lowers the threshold below 'thr'
    labels, thr2 = r.at(0.2)
    assert thr2 == pytest.approx(2.0 * stats.chi2.isf(0.2, 3))
    assert labels[0, 0] == 1 and labels[1, 2] == 0 and labels[0, 1] == 255


def test_the_shade_range_is_open_and_its_threshold_has_c_minus_1_dof() -> None:
    """Step 5's label 253: k strictly inside (k_min, k_max) and the shade d² <= s·χ²_{C-1}(1-P);
    k exactly at k_min or k_max, or d² just above, stays change. Pixels a cluster explains
    keep the cluster's label."""
    s = 1.7
    sthr = s * float(stats.chi2.isf(0.01, 2))
    H, W = 1, 6
    d2 = np.full((H, W, 1), 1e6)
    d2[0, 5] = 0.0                                      # explained by the background
    k = np.array([[0.5, 2.0, 0.51, 1.99, 1.0, 1.0]])
    sd2 = np.array([[0.0, 0.0, sthr, 0.0, sthr * 1.000001, 0.0]])
    r = _result(d2, np.ones((H, W), bool), np.ones(10), scale=s, shade=(0.5, 2.0),
                shade_k=k, shade_d2=sd2)
    assert r.shade_threshold() == pytest.approx(sthr, rel=1e-12)
    np.testing.assert_array_equal(r.labels[0], [255, 255, 253, 253, 255, 0])
    d = r.to_dict()
    assert d["shade_pixels"] == 2 and d["shade"] == [0.5, 2.0]
    assert d["shade_threshold"] == pytest.approx(sthr)
    # a mono result: the shade's dof is max(C - 1, 1) = 1
    mono = _result(np.zeros((1, 1, 1)), np.ones((1, 1), bool), np.ones(5), scale=1.3, dof=1)
    assert mono.shade_threshold(0.05) == pytest.approx(1.3 * stats.chi2.isf(0.05, 1))


def test_min_region_relabels_small_regions_and_counts_them_in_a_note() -> None:
    """min_region > 1: changed regions (8-connected) under min_region pixels are labelled 0,
    and the note counts exactly them (not the shades, not the undetermined pixels)."""
    H, W = 6, 8
    d2 = np.zeros((H, W, 1))
    d2[0, 0] = 1e6                                      # a lone changed pixel
    d2[3:5, 3:5] = 1e6                                  # a 2 x 2 region (kept at min 4)
    d2[5, 7] = 1e6                                      # a shade
    d2[0, 7] = 1e6                                      # invalid
    valid = np.ones((H, W), bool)
    valid[0, 7] = False
    k = np.full((H, W), np.nan)
    sd2 = np.full((H, W), np.nan)
    k[5, 7], sd2[5, 7] = 1.0, 0.0
    r = _result(d2, valid, np.ones(10), min_region=4, shade=(0.5, 2.0), shade_k=k,
                shade_d2=sd2)
    assert r.labels[0, 0] == 0 and r.labels[5, 7] == CH.LABEL_SHADE
    assert np.all(r.labels[3:5, 3:5] == CH.LABEL_CHANGE)
    assert r.labels[0, 7] == CH.LABEL_UNDETERMINED
    assert any(n.startswith("1 changed pixels in regions under 4") for n in r.notes)
    # min_region 5: the 2 x 2 region goes too (5 pixels relabelled)
    r5 = _result(d2, valid, np.ones(10), min_region=5, shade=(0.5, 2.0), shade_k=k,
                 shade_d2=sd2)
    assert any(n.startswith("5 changed pixels") for n in r5.notes)
    assert r5.to_dict()["min_region"] == 5
    # nothing small: no note
    d2b = np.zeros((H, W, 1))
    d2b[1:4, 1:4] = 1e6
    assert not _result(d2b, np.ones((H, W), bool), np.ones(10), min_region=9).notes


def test_cluster_dict_has_the_standard_errors_in_m_shape() -> None:
    """Cluster.to_dict: M_err = sqrt(diag(M_cov)) laid out as M (vec M row-major)."""
    c = CH.Cluster(2, np.array([[1.0, 2.0], [3.0, 4.0]]), np.diag([1.0, 4.0, 9.0, 16.0]), 7,
                   2.5)
    d = c.to_dict()
    assert d["M_err"] == [[1.0, 2.0], [3.0, 4.0]]
    assert d["label"] == 2 and d["pixels"] == 7 and d["d2_median"] == 2.5


# -- the background's scale s -----------------------------------------------------------------
def test_background_scale_matches_the_gated_median_and_drops_outliers() -> None:
    """s is the median of the gated sample over χ²'s median truncated at the gate
    (χ²_C(0.5 (1 - 1e-6))); values beyond s·χ²_C(1 - 1e-6) are not in the sample. Data: s₀
    times χ²₃'s quantiles (10 001 of them, median exactly s₀·χ²₃(0.5)) plus 100 outliers."""
    s0, dof = 2.5, 3
    q = s0 * stats.chi2.ppf((np.arange(10001) + 0.5) / 10001, dof)
    d2 = np.concatenate([q, np.full(100, 1e6)])
    rng = np.random.default_rng(0)
    rng.shuffle(d2)
    s, sample = CH._background_scale(d2, dof)
    expect = s0 * stats.chi2.ppf(0.5, dof) / stats.chi2.ppf(0.5 * (1 - 1e-6), dof)
    assert s == pytest.approx(expect, rel=1e-9)
    np.testing.assert_array_equal(sample, np.sort(q))
    # every value far above the gate at s = 1: s grows until the gate takes them
    s2, sample2 = CH._background_scale(np.full(50, 1e4), 1)
    assert s2 == pytest.approx(1e4 / stats.chi2.ppf(0.5 * (1 - 1e-6), 1), rel=1e-9)
    assert sample2.size == 50


# -- the valid pixels -------------------------------------------------------------------------
def _sig(H: int, W: int, C: int, n_valid: int) -> np.ndarray:
    s = np.full((H, W, C), 0.1)
    s.reshape(-1, C)[n_valid:] = np.inf
    return s


def test_smallest_frame_needs_twice_the_smallest_cluster() -> None:
    """min_px = ceil(min_pixels · n_valid) (a count when min_pixels >= 1), at least 10 C²;
    n_valid must reach max(10 C², 2 min_px). min_pixels = 0.5 puts the limit at n_valid even:
    21 valid pixels need 2·ceil(10.5) = 22; 22 pass. A count of 25 needs exactly 50."""
    o = CH.ChangeOptions(min_pixels=0.5)
    ones = np.full((10, 10, 1), 0.1)
    with pytest.raises(CcdError, match="only 21 of 100"):
        CH._valid_pixels(_sig(10, 10, 1, 21), ones, o, "ref")
    valid, min_px, _ = CH._valid_pixels(_sig(10, 10, 1, 22), ones, o, "ref")
    assert min_px == 11 and int(valid.sum()) == 22
    o25 = CH.ChangeOptions(min_pixels=25)
    with pytest.raises(CcdError):
        CH._valid_pixels(_sig(10, 10, 1, 49), ones, o25, "ref")
    assert CH._valid_pixels(_sig(10, 10, 1, 50), ones, o25, "ref")[1] == 25
    # RGB: at least 10·9 = 90 pixels per cluster, 180 valid
    o_rgb = CH.ChangeOptions(min_pixels=0.001)
    ones3 = np.full((20, 10, 3), 0.1)
    with pytest.raises(CcdError):
        CH._valid_pixels(_sig(20, 10, 3, 179), ones3, o_rgb, "ref")
    assert CH._valid_pixels(_sig(20, 10, 3, 180), ones3, o_rgb, "ref")[1] == 90


def test_undetermined_note_from_five_percent_of_the_frame() -> None:
    """The note on undetermined pixels appears when fewer than 95 % are valid: 95 of 100
    valid gives none, 94 gives one counting 6; a sigma of 0 or NaN in either map, or in one
    channel only, makes a pixel invalid."""
    ones = np.full((10, 10, 1), 0.1)
    o = CH.ChangeOptions()
    assert CH._valid_pixels(_sig(10, 10, 1, 95), ones, o, "ref")[2] == []
    notes = CH._valid_pixels(_sig(10, 10, 1, 94), ones, o, "ref")[2]
    assert len(notes) == 1 and notes[0].startswith("6 pixels")
    s = np.full((20, 10, 3), 0.1)
    st = np.full((20, 10, 3), 0.1)
    s[0, 0, 1] = 0.0
    st[0, 1, 2] = np.nan
    st[0, 2, 0] = -0.1
    valid = CH._valid_pixels(s, st, CH.ChangeOptions(min_pixels=1), "ref")[0]
    assert not valid[0, :3].any() and int(valid.sum()) == 197


def test_shapes_and_nan_are_refused_by_name() -> None:
    """_checked_maps: a sigma of another shape (either role), a map neither 2-D nor 3-D, NaN
    radiance in the target: CcdError naming the role."""
    E = np.ones((4, 5, 3))
    with pytest.raises(CcdError, match="ref"):
        CH._checked_maps(E, np.ones((4, 5, 2)), E, E, ("ref", "tgt"))
    with pytest.raises(CcdError, match="tgt"):
        CH._checked_maps(E, E, E, np.ones((4, 4, 3)), ("ref", "tgt"))
    with pytest.raises(CcdError, match="expected an"):
        CH._checked_maps(np.ones(5), np.ones(5), np.ones(5), np.ones(5), ("ref", "tgt"))
    bad = E.copy()
    bad[1, 1, 1] = np.nan
    with pytest.raises(CcdError, match="tgt"):
        CH._checked_maps(E, E, bad, E, ("ref", "tgt"))
    out = CH._checked_maps(np.ones((4, 5)), np.ones((4, 5)), np.ones((4, 5)),
                           np.ones((4, 5)), ("a", "b"))
    assert all(x.shape == (4, 5, 1) for x in out)


def test_prediction_d2_mono_is_the_propagated_error_and_nan_where_unknown() -> None:
    """Eq. 20 for one channel: d² = (E M - E')² / (M² σ_E² + σ_E'² + E² var M); NaN where a
    sigma or a radiance is not finite (2-D maps accepted)."""
    rng = np.random.default_rng(1)
    E = rng.uniform(1.0, 5.0, (4, 6))
    Et = 0.7 * E + rng.normal(0, 0.1, E.shape)
    s = rng.uniform(0.05, 0.2, E.shape)
    st = rng.uniform(0.05, 0.2, E.shape)
    s[0, 0] = np.inf
    st[1, 2] = np.nan
    E[2, 3] = np.inf
    out = CH.prediction_d2(E, s, Et, st, [[0.7]], [[4e-4]])
    with np.errstate(invalid="ignore"):
        expect = (0.7 * E - Et) ** 2 / (0.49 * s ** 2 + st ** 2 + E ** 2 * 4e-4)
    ok = np.ones(E.shape, bool)
    ok[0, 0] = ok[1, 2] = ok[2, 3] = False
    np.testing.assert_allclose(out[ok], expect[ok], rtol=1e-10)
    assert np.all(np.isnan(out[~ok]))
    no_cov = CH.prediction_d2(E, s, Et, st, 0.7)
    with np.errstate(invalid="ignore"):
        plain = (0.7 * E - Et) ** 2 / (0.49 * s ** 2 + st ** 2)
    np.testing.assert_allclose(no_cov[ok], plain[ok], rtol=1e-10)
    assert np.all(np.isnan(no_cov[~ok]))


# -- the kernels ------------------------------------------------------------------------------
def _rows(C: int, n: int, seed: int) -> tuple[np.ndarray, ...]:
    """Rows (n, C) of a non-symmetric M (E' = E M), unequal variances per channel, and a full
    covariance of vec M."""
    rng = np.random.default_rng(seed)
    E = rng.uniform(0.1, 0.9, (n, C))
    M = np.eye(C) * 0.8 + 0.1 * rng.standard_normal((C, C))
    Et = E @ M + 0.02 * rng.standard_normal((n, C))
    var = rng.uniform(1e-4, 4e-4, (n, C)) * np.arange(1, C + 1)
    var_t = rng.uniform(1e-4, 4e-4, (n, C)) * np.arange(C, 0, -1)
    A = 3e-3 * rng.standard_normal((C * C, C * C))
    return E, Et, var, var_t, M, A @ A.T


def _sigma_e(E: np.ndarray, var: np.ndarray, var_t: np.ndarray, M: np.ndarray,
             Mc: np.ndarray | None) -> np.ndarray:
    """Σ_e = Mᵀ diag(σ_E²) M + diag(σ_E'²) + J Σ_M Jᵀ for one row, J = ∂e/∂vec M."""
    C = E.size
    S = M.T @ np.diag(var) @ M + np.diag(var_t)
    if Mc is not None:
        J = np.kron(E[:, None], np.eye(C)).T
        S = S + J @ Mc @ J.T
    return S


@pytest.mark.parametrize("C", [1, 2, 3])
def test_d2_inverse_and_log_determinant_against_numpy(C: int) -> None:
    """error_d2 for 1, 2 and 3 channels: d² = eᵀ Σ_e⁻¹ e, P = Σ_e⁻¹ and ln det Σ_e (the LTS
    cost's term) against numpy's solve, inv and slogdet, with and without Σ_M."""
    E, Et, var, var_t, M, Mc = _rows(C, 40, 10 + C)
    for cov in (Mc, None):
        d2, P, logdet = CK.error_d2(E, Et, var, var_t, M, cov, want_logdet=True)
        for i in range(0, 40, 7):
            S = _sigma_e(E[i], var[i], var_t[i], M, cov)
            e = E[i] @ M - Et[i]
            assert d2[i] == pytest.approx(e @ np.linalg.solve(S, e), rel=1e-9)
            np.testing.assert_allclose(P[i], np.linalg.inv(S), rtol=1e-8)
            assert logdet[i] == pytest.approx(np.linalg.slogdet(S)[1], rel=1e-10, abs=1e-10)
    d2b, Pb = CK.error_d2(E, Et, var, var_t, M, Mc, want_p=False)
    assert Pb is None and np.allclose(d2b, CK.error_d2(E, Et, var, var_t, M, Mc)[0])


@pytest.mark.parametrize("C", [1, 3])
def test_normal_equations_are_the_weighted_corrected_moments(C: int) -> None:
    """design_normal: N[(k, j), (l, m)] = Σ_i w_i (E_ik E_il - δ_kl σ²_ik) P_ijm and
    r[k, j] = Σ_i w_i E_ik (P_i E'_i)_j (Fuller's correction with ``var``; none without)."""
    E, Et, var, var_t, M, _ = _rows(C, 30, 20 + C)
    rng = np.random.default_rng(2)
    w = rng.uniform(0.2, 1.0, 30)
    _, P = CK.error_d2(E, Et, var, var_t, M)
    EE = np.einsum("ik,il->ikl", E, E)
    for corr in (None, var):
        N, r = CK.design_normal(E, Et, P, w, corr)
        mom = EE - (0 if corr is None else np.einsum("ik,kl->ikl", var, np.eye(C)))
        N_ref = np.einsum("i,ikl,ijm->kjlm", w, mom, P).reshape(C * C, C * C)
        r_ref = np.einsum("i,ik,ijm,im->kj", w, E, P, Et).reshape(C * C)
        np.testing.assert_allclose(N, N_ref, rtol=1e-10)
        np.testing.assert_allclose(r, r_ref, rtol=1e-10)


def test_gls_recovers_an_exact_transform_and_returns_the_inverse_normal_matrix() -> None:
    """Noise-free rows E' = E M: GLS gives M (to rounding) from any start, and the matrix it
    returns is the inverse of the normal matrix at its last Σ_e."""
    E, _, var, var_t, M, _ = _rows(3, 50, 31)
    Et = E @ M
    w = np.linspace(0.5, 1.0, 50)
    Mg, Ninv = CK.gls(E, Et, var, var_t, w, np.eye(3), iters=3)
    np.testing.assert_allclose(Mg, M, rtol=1e-8, atol=1e-10)
    M_prev, _ = CK.gls(E, Et, var, var_t, w, np.eye(3), iters=2)
    _, P = CK.error_d2(E, Et, var, var_t, M_prev)
    N, _ = CK.design_normal(E, Et, P, w)
    np.testing.assert_allclose(Ninv @ N, np.eye(9), atol=1e-8)


def test_trimmed_cost_sums_the_h_smallest_log_likelihoods() -> None:
    """LTS's cost: over the h rows of smallest d², Σ (d² + ln det Σ_e - Σ_c ln σ²_E'c)."""
    for C in (1, 3):
        E, Et, var, var_t, M, _ = _rows(C, 25, 40 + C)
        Et[:5] += 0.5                                     # five rows far off
        d2 = np.empty(25)
        ld = np.empty(25)
        for i in range(25):
            S = _sigma_e(E[i], var[i], var_t[i], M, None)
            e = E[i] @ M - Et[i]
            d2[i] = e @ np.linalg.solve(S, e)
            ld[i] = np.linalg.slogdet(S)[1] - np.sum(np.log(var_t[i]))
        keep = np.argsort(d2)[:12]
        assert CK._trimmed_cost(E, Et, var, var_t, M, 12) == pytest.approx(
            float(np.sum(d2[keep] + ld[keep])), rel=1e-9)


def test_lts_finds_the_majority_transform_and_refuses_degenerate_colours() -> None:
    """FAST-LTS on 300 rows of which 40 % obey another transform: the 60 % majority's M (to
    its noise, here 1e-3 on rows of 0.1-0.9); rows of one colour span no basis: CcdError."""
    rng = np.random.default_rng(4)
    n = 300
    E = rng.uniform(0.1, 0.9, (n, 3))
    M = np.array([[0.8, 0.1, 0.0], [0.05, 0.7, 0.1], [0.0, 0.05, 0.9]])
    Et = E @ M
    Et[:120] = E[:120] @ (0.5 * M.T)
    var = np.full((n, 3), 1e-8)
    Mf, _ = CK.lts(E, Et, var, var, 0.5, 200, np.random.default_rng(0), 3)
    np.testing.assert_allclose(Mf, M, atol=1e-6)
    grey = np.tile([[0.3, 0.3, 0.3]], (n, 1))
    with pytest.raises(CcdError, match="degenerate"):
        CK.lts(grey, grey, var, var, 0.5, 50, np.random.default_rng(0), 2)


def test_shade_needs_rgb_and_gives_nan_for_a_black_prediction() -> None:
    """shade_d2: C != 3 refused; a row predicted 0 in every channel has no k (NaN, and NaN d²);
    an exact shade k·E M has d² 0 and its k."""
    E, Et, var, var_t, M, _ = _rows(2, 4, 50)
    with pytest.raises(CcdError, match="RGB"):
        CK.shade_d2(E, Et, var, var_t, M)
    E3 = np.array([[0.0, 0.0, 0.0], [0.2, 0.4, 0.6]])
    M3 = np.diag([0.9, 0.8, 0.7])
    Et3 = 1.5 * E3 @ M3
    v = np.full((2, 3), 1e-4)
    k, d2 = CK.shade_d2(E3, Et3, v, v, M3)
    assert math.isnan(k[0]) and math.isnan(d2[0])
    assert k[1] == pytest.approx(1.5, rel=1e-12) and d2[1] == pytest.approx(0.0, abs=1e-20)



def test_shade_factor_after_one_step_starts_from_k_1() -> None:
    """shade_d2 with iters = 1: k is one GLS step with Σ_e at the start k = 1,
    k = Pᵀ S⁻¹ E' / Pᵀ S⁻¹ P with S = Mᵀ Σ_E M + J Σ_M Jᵀ + Σ_E' and P = E M; d² is then
    taken with Σ_e(k) = k² (Mᵀ Σ_E M + J Σ_M Jᵀ) + Σ_E' (numpy on the same rows)."""
    E, _, var, var_t, M, Mc = _rows(3, 12, 60)
    var = var * 400.0                                 # a large Σ_E: the start matters
    Et = 0.3 * E @ M + 0.01
    k, d2 = CK.shade_d2(E, Et, var, var_t, M, Mc, iters=1)
    for i in range(12):
        A = _sigma_e(E[i], var[i], np.zeros(3), M, Mc)
        P = E[i] @ M
        S = A + np.diag(var_t[i])
        k1 = (P @ np.linalg.solve(S, Et[i])) / (P @ np.linalg.solve(S, P))
        e = Et[i] - k1 * P
        assert k[i] == pytest.approx(k1, rel=1e-9)
        assert d2[i] == pytest.approx(e @ np.linalg.solve(k1 ** 2 * A + np.diag(var_t[i]), e),
                                      rel=1e-8)


# -- frame sets ---------------------------------------------------------------------------------
def test_frame_set_mean_spread_clipping_and_slope() -> None:
    """_frame_set: E = mean of g(z) over the frames / a, their sample variance (N - 1), a pixel
    clipped when a code is 0 or levels - 1 in any frame, the slope g'(z̄) by interpolation of
    g's gradient at the mean code, and codes beyond the response refused."""
    L = 16
    g = np.linspace(0.0, 1.0, L) ** 2
    z = [np.array([[1, 15], [3, 7]]), np.array([[2, 14], [0, 8]]), np.array([[4, 13], [3, 9]])]
    out = CF._frame_set(z, g, 2.0)
    G = g[np.stack(z)]
    np.testing.assert_allclose(out["E"], G.mean(axis=0) / 2.0, rtol=1e-12)
    np.testing.assert_allclose(out["gbar"], G.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(out["var"], G.var(axis=0, ddof=1), rtol=1e-12)
    np.testing.assert_array_equal(out["clipped"], [[False, True], [True, False]])
    zbar = np.stack(z).mean(axis=0)
    grad = np.gradient(g)
    np.testing.assert_allclose(out["slope"], np.interp(zbar, np.arange(L), grad), rtol=1e-12)
    # at z̄ = 7/3 + ... the gradient of x² on the unit grid: 2 z̄ / (L-1)², away from the ends
    assert out["slope"][0, 0] == pytest.approx(2 * (7 / 3) / (L - 1) ** 2, rel=1e-12)
    assert CF._frame_set([z[0]], g, 1.0)["var"] is None
    with pytest.raises(CcdError, match="exceed"):
        CF._frame_set([np.array([[16]])], g, 1.0)
    top = CF._frame_set([np.array([[15]]), np.array([[14]])], g, 1.0)
    assert bool(top["clipped"][0, 0])


def test_model_variance_and_the_assumed_terms() -> None:
    """Eq. 7: σ² = σ_s² max(g, 0) + σ_c1² + (g' σ_c2)²; the assumed σ_c2 is levels / 256 codes
    (1 code at 8 bits, 4 at 10 bits) with σ_s = 0.01, σ_c1 = 0."""
    g = np.array([-0.5, 0.0, 0.25, 1.0])
    sl = np.array([0.1, 0.2, 0.3, 0.4])
    np.testing.assert_allclose(CF._model_var(g, sl, (0.3, 0.2, 2.0)),
                               0.09 * np.maximum(g, 0) + 0.04 + (2.0 * sl) ** 2, rtol=1e-12)
    assert CF._assumed_terms(256) == (0.01, 0.0, 1.0)
    assert CF._assumed_terms(1024) == (0.01, 0.0, 4.0)


def test_noise_terms_exact_on_a_noiseless_model_with_one_degree_of_freedom() -> None:
    """fit_noise_terms divides each bin's median variance by median(χ²_dof)/dof (0.455 at one
    degree of freedom): variances that are exactly the model times that factor give the terms
    back exactly (bins of 51 pixels, odd, over a model increasing in g with g'² = g², so a
    bin's median is the model at its median g). 49 pixels are too few; 50 pass that count
    (and meet the next rule: 2 bins of 25, fewer than the 3 rows the fit needs)."""
    dof = 1
    corr = stats.chi2.median(dof) / dof
    g = np.linspace(0.05, 0.95, 32 * 51)
    sl = g.copy()
    terms = (0.02, 0.003, 0.01)
    var = CF._model_var(g, sl, terms) * corr
    got = CF.fit_noise_terms(g, var, sl, dof)
    np.testing.assert_allclose(got, terms, rtol=1e-6)
    # the same at 3 degrees of freedom (factor 0.789)
    corr3 = stats.chi2.median(3) / 3
    np.testing.assert_allclose(CF.fit_noise_terms(g, var / corr * corr3, sl, 3), terms,
                               rtol=1e-6)
    # non-finite pixels are dropped before counting
    g50 = np.concatenate([np.linspace(0.1, 0.9, 50), [np.nan]])
    v50 = CF._model_var(g50, g50, terms)
    with pytest.raises(CcdError, match="spread is zero"):
        CF.fit_noise_terms(g50, v50, g50, 4)
    g75 = np.linspace(0.1, 0.9, 75)
    CF.fit_noise_terms(g75, CF._model_var(g75, g75, terms), g75, 4)
    with pytest.raises(CcdError, match="49 pixels"):
        CF.fit_noise_terms(g50[1:], v50[1:], g50[1:], 4)


def test_role_kind_of_no_records_is_an_error() -> None:
    """role_kind: no records is an error; all without exposure, or all at one: frames."""
    with pytest.raises(CcdError, match="no frames"):
        CF.role_kind([])
    r = SimpleNamespace
    assert CF.role_kind([r(exposure=None), r(exposure=None)]) == "frames"
    assert CF.role_kind([r(exposure=0.5), r(exposure=0.5)]) == "frames"
    assert CF.role_kind([r(exposure=0.5), r(exposure=1.0)]) == "bracket"


def _records(exposure: float | None, n: int, role: str) -> list[SimpleNamespace]:
    return [SimpleNamespace(exposure=exposure, relpath=f"{role}/{k}.png", role=role)
            for k in range(n)]


def test_frame_set_sigma_is_the_shrunk_spread_over_root_n_and_the_exposure() -> None:
    """Module docstring, noise source 1: a role of N = 3 frames at 2 s has
    σ = sqrt(((N-1) s² + 8 σ²_model) / (N - 1 + 8) / N) / 2 with eq. 7's model fitted to its
    frames' spread (fit_noise_terms on the unclipped pixels), E = mean g(z) / 2; the target
    of one frame without exposure takes that model alone, σ = sqrt(σ²_model); a clipped pixel
    has an infinite sigma."""
    rng = np.random.default_rng(8)
    H, W = 24, 20
    g = CF.srgb_inverse(256)
    base = rng.integers(30, 220, (H, W))
    ref = [np.clip(base + rng.integers(-3, 4, (H, W)), 0, 255).astype(np.uint8)
           for _ in range(3)]
    ref[1][0, 0] = 255                                    # clipped in one frame
    tgt = [np.clip(base // 2 + 40 + rng.integers(-3, 4, (H, W)), 0, 255).astype(np.uint8)]
    recs = {"reference": _records(2.0, 3, "reference"), "target": _records(None, 1, "target")}
    session = SimpleNamespace(camera=SimpleNamespace(layout=None))
    maps, words = CF._role_maps(session, {"reference": "frames", "target": "frames"}, recs,
                                {"reference": ref, "target": tgt},
                                {"L": (g, (9.0, 9.0, 9.0))}, None, 256, 0)
    z = np.stack(ref).astype(int)
    G = g[z]
    gbar, s2 = G.mean(axis=0), G.var(axis=0, ddof=1)
    slope = np.interp(z.mean(axis=0), np.arange(256), np.gradient(g))
    clip = np.any((z == 0) | (z == 255), axis=0)
    terms = CF.fit_noise_terms(gbar[~clip], s2[~clip], slope[~clip], 2)
    model = terms[0] ** 2 * gbar + terms[1] ** 2 + (slope * terms[2]) ** 2
    sig = np.sqrt((2 * s2 + 8 * model) / 10 / 3) / 2.0
    E, S = maps["reference"]
    np.testing.assert_allclose(E[..., 0], gbar / 2.0, rtol=1e-12)
    np.testing.assert_allclose(S[..., 0][~clip], sig[~clip], rtol=1e-10)
    assert np.isinf(S[0, 0, 0]) and int(np.isinf(S).sum()) == 1
    zt = tgt[0].astype(int)
    slope_t = np.interp(zt, np.arange(256), np.gradient(g))
    model_t = terms[0] ** 2 * g[zt] + terms[1] ** 2 + (slope_t * terms[2]) ** 2
    Et, St = maps["target"]
    np.testing.assert_allclose(Et[..., 0], g[zt], rtol=1e-12)
    np.testing.assert_allclose(St[..., 0], np.sqrt(model_t), rtol=1e-10)
    assert "spread of its 3 frames" in words and "measured on the reference" in words


def test_single_frames_without_a_noise_source_take_the_assumed_terms() -> None:
    """Noise source 3: two single 10-bit RGB frames, no response noise: eq. 7 with σ_s = 0.01,
    σ_c1 = 0, σ_c2 = 1024 / 256 = 4 codes, σ = sqrt(σ²) for one frame; a response's own terms
    (source 2) replace them, each channel its own."""
    rng = np.random.default_rng(9)
    g = CF.srgb_inverse(1024)
    z = [rng.integers(100, 900, (10, 12, 3)).astype(np.uint16) for _ in range(2)]
    recs = {"reference": _records(None, 1, "reference"), "target": _records(None, 1, "target")}
    session = SimpleNamespace(camera=SimpleNamespace(layout=None))
    kinds = {"reference": "frames", "target": "frames"}
    frames = {"reference": [z[0]], "target": [z[1]]}
    maps, words = CF._role_maps(session, kinds, recs, frames,
                                {c: (g, (0.5, 0.5, 0.5)) for c in "RGB"}, None, 1024, 0)
    for role, zz in zip(("reference", "target"), z):
        zi = zz.astype(int)
        slope = np.interp(zi, np.arange(1024), np.gradient(g))
        expect = np.sqrt(1e-4 * g[zi] + (4.0 * slope) ** 2)
        np.testing.assert_allclose(maps[role][1], expect, rtol=1e-10)
    assert "assumed" in words
    terms = {"R": (0.02, 0.001, 3.0), "G": (0.01, 0.002, 1.0), "B": (0.03, 0.0, 2.0)}
    maps2, words2 = CF._role_maps(session, kinds, recs, frames,
                                  {c: (g, terms[c]) for c in "RGB"}, "the noise terms of X",
                                  1024, 0)
    zi = z[0].astype(int)
    slope = np.interp(zi, np.arange(1024), np.gradient(g))
    for i, c in enumerate("RGB"):
        ss, c1, c2 = terms[c]
        np.testing.assert_allclose(maps2["reference"][1][..., i],
                                   np.sqrt(ss ** 2 * g[zi[..., i]] + c1 ** 2
                                           + (c2 * slope[..., i]) ** 2), rtol=1e-10)
    assert "the noise terms of X" in words2


# -- the dark model o + c·t -------------------------------------------------------------------
def _wls_reference(times: list[float], frames: list[np.ndarray], a: float, b: float
                   ) -> tuple[np.ndarray, ...]:
    """Per pixel weighted least squares of y = o + c t with w_i = 1/(a + b t_i), numpy's lstsq
    on the whitened design, and φ (XᵀWX)⁻¹ with φ = RSS_w / (n - 2)."""
    t = np.asarray(times)
    w = 1.0 / (a + b * t)
    X = np.stack([np.ones_like(t), t], axis=1)
    Y = np.stack([f.ravel() for f in frames])                  # (n, pixels)
    sw = np.sqrt(w)[:, None]
    beta, *_ = np.linalg.lstsq(X * sw, Y * sw, rcond=None)
    rss = np.sum(w[:, None] * (Y - X @ beta) ** 2, axis=0)
    phi = rss / (len(t) - 2)
    cov = np.linalg.inv(X.T @ (w[:, None] * X))
    return beta[0], beta[1], phi, cov


def test_dark_model_is_weighted_least_squares_with_its_covariance() -> None:
    """Module docstring, pass 3: o, c by weighted least squares with w_i = 1/σ²(t_i), σ²(t) the
    fitted noise line a + b t (b > 0 here: noise grows with t, so the weights differ), the
    scale φ = RSS_w/(n - 2) and cov(o, c) = φ (XᵀWX)⁻¹; error_var_at(t) is [1 t] cov [1 t]ᵀ,
    moments_at(t) the mean o + c t with var = n × that error."""
    rng = np.random.default_rng(21)
    shape = (12, 10)
    o = rng.uniform(90, 110, shape)
    c = rng.uniform(0.5, 3.0, shape)
    times = [0.0, 0.0, 2.0, 5.0, 5.0, 10.0, 10.0]
    frames = [o + c * t + rng.normal(0, math.sqrt(1.0 + 0.8 * t), shape) for t in times]
    m = DM.fit_dark_model(list(zip(times, frames)))
    assert m.noise_b > 0.1
    o_r, c_r, phi, cov = _wls_reference(times, frames, m.noise_a, m.noise_b)
    np.testing.assert_allclose(m.offset.ravel(), o_r, rtol=1e-9)
    np.testing.assert_allclose(m.current.ravel(), c_r, rtol=1e-8)
    np.testing.assert_allclose(m.scale.ravel(), phi, rtol=1e-7)
    np.testing.assert_allclose(m.offset_var.ravel(), phi * cov[0, 0], rtol=1e-7)
    np.testing.assert_allclose(m.current_var.ravel(), phi * cov[1, 1], rtol=1e-7)
    np.testing.assert_allclose(m.covariance.ravel(), phi * cov[0, 1], rtol=1e-7)
    t = 3.7
    x = np.array([1.0, t])
    np.testing.assert_allclose(m.error_var_at(t).ravel(), phi * (x @ cov @ x), rtol=1e-7)
    mom = m.moments_at(t)
    np.testing.assert_allclose(mom.mean.ravel(), o_r + c_r * t, rtol=1e-9)
    np.testing.assert_allclose(mom.var, m.error_var_at(t) * 7, rtol=1e-12)
    assert mom.n == 7 and m.exposures == (0.0, 2.0, 5.0, 10.0)
    np.testing.assert_allclose(m.noise_var_at(4.0), m.scale * (m.noise_a + 4.0 * m.noise_b))


def test_dark_noise_line_is_fitted_to_leverage_corrected_median_variances() -> None:
    """Pass 2: v_i = median over pixels of r²/0.4549/(1 - h_i), r the OLS residuals, h_i =
    1/n + (t_i - t̄)²/Sxx; σ²(t) = a + b t the least squares line through (t_i, v_i)."""
    rng = np.random.default_rng(22)
    shape = (30, 20)
    times = [0.0, 1.0, 1.0, 4.0, 9.0]
    frames = [50.0 + 2.0 * t + rng.normal(0, math.sqrt(2.0 + 0.5 * t), shape) for t in times]
    m = DM.fit_dark_model(list(zip(times, frames)))
    t = np.asarray(times)
    Y = np.stack(frames)
    X = np.stack([np.ones_like(t), t], axis=1)
    beta = np.linalg.lstsq(X, Y.reshape(5, -1), rcond=None)[0]
    r2 = (Y.reshape(5, -1) - X @ beta) ** 2
    h = 1 / 5 + (t - t.mean()) ** 2 / np.sum((t - t.mean()) ** 2)
    v = np.median(r2, axis=1) / stats.chi2.median(1) / (1 - h)
    b, a = np.polyfit(t, v, 1)
    assert m.noise_a == pytest.approx(a, rel=1e-7) and m.noise_b == pytest.approx(b, rel=1e-7)


def test_noise_line_clamps() -> None:
    """_noise_line: a falling line becomes flat at the mean (b = 0); one exposure: the mean;
    a negative intercept is raised to 1e-3 of the smallest variance; a rising line as is."""
    assert DM._noise_line(np.array([0.0, 1.0, 2.0]), np.array([3.0, 2.0, 1.0])) == (2.0, 0.0)
    assert DM._noise_line(np.array([1.0, 1.0]), np.array([3.0, 5.0])) == (4.0, 0.0)
    a, b = DM._noise_line(np.array([1.0, 2.0, 3.0]), np.array([1.0, 3.0, 5.0]))
    assert a == pytest.approx(1e-3) and b == pytest.approx(2.0)
    a, b = DM._noise_line(np.array([0.0, 1.0, 2.0]), np.array([1.0, 2.0, 3.0]))
    assert a == pytest.approx(1.0) and b == pytest.approx(1.0)


def test_two_frames_have_unknown_errors_and_moments_fall_back_to_the_noise() -> None:
    """Two frames: no residual scatter; the errors are NaN, φ is taken as 1 with a note, and
    moments_at's var is n × (σ²(t)/n) = σ²(t) = a + b t (the noise line of the two frames,
    flat here: the mean of their leverage-corrected variances)."""
    rng = np.random.default_rng(23)
    f0 = 100 + rng.normal(0, 1, (8, 9))
    f1 = 120 + rng.normal(0, 1, (8, 9))
    m = DM.fit_dark_model([(0.0, f0), (2.0, f1)])
    assert np.all(np.isnan(m.offset_var)) and np.all(np.isnan(m.covariance))
    assert np.all(m.scale == 1.0) and any("two frames" in n for n in m.notes)
    np.testing.assert_allclose(m.offset, f0, rtol=1e-12)
    np.testing.assert_allclose(m.current, (f1 - f0) / 2, rtol=1e-9)
    mom = m.moments_at(1.0)
    np.testing.assert_allclose(mom.var, m.noise_a + m.noise_b * 1.0, rtol=1e-12)
    assert mom.n == 2
    s = m.summary()
    assert s.offset_err_median is None and s.current_err_median is None
    assert s.scale_median == 1.0


@pytest.mark.parametrize("t", [None, -0.1, math.inf, math.nan])
def test_dark_model_needs_a_finite_non_negative_exposure(t: float | None) -> None:
    """Each frame needs an exposure >= 0 (biases 0 s): None, negative, inf or NaN is refused,
    naming the frame."""
    frames = [(0.0, np.zeros((3, 3))), (t, np.ones((3, 3))), (1.0, np.ones((3, 3)))]
    with pytest.raises(CcdError, match="dark frame 1"):
        DM.fit_dark_model(frames)


def test_dark_model_refuses_bad_frames_and_one_exposure() -> None:
    """A 1-D frame, frames of two shapes, and frames at one exposure only are refused; 0 s
    biases with one dark are enough (two exposures)."""
    with pytest.raises(CcdError, match="2-D"):
        DM.fit_dark_model([(0.0, np.zeros(4)), (1.0, np.zeros(4))])
    with pytest.raises(CcdError, match="differs"):
        DM.fit_dark_model([(0.0, np.zeros((3, 3))), (1.0, np.zeros((3, 4)))])
    with pytest.raises(CcdError, match="two or more"):
        DM.fit_dark_model([(1.0, np.zeros((3, 3))), (1.0, np.ones((3, 3)))])
    with pytest.raises(CcdError, match="two or more"):
        DM.fit_dark_model([(1.0, np.zeros((3, 3)))])
    m = DM.fit_dark_model([(0.0, np.zeros((3, 3))), (0.0, np.ones((3, 3))),
                           (1.0, np.full((3, 3), 2.0))])
    assert m.shape == (3, 3) and m.n == 3


def test_hot_current_falls_back_to_the_std_when_the_mad_is_zero() -> None:
    """hot_current: (c - median) > 6 r with r = 1.4826 MAD, or the spatial std when the MAD is
    0: 98 pixels at 0, one at 30, one at 100 DN/s: std 10.36, so 100 is hot and 30 is not.
    Also the frame noise of noise_var_at, clamped at 0."""
    cur = np.zeros((10, 10))
    cur[2, 3], cur[7, 7] = 30.0, 100.0
    z = np.zeros_like(cur)
    m = DM.DarkModel(z, cur, z, z, z, np.full_like(cur, 2.0), 1.0, 0.5, 3, (0.0, 1.0))
    hot = m.hot_current
    assert hot[7, 7] and not hot[2, 3] and int(hot.sum()) == 1
    # the frame noise φ·max(a + b t, 0): 2 × 3.5 at 5 s; a line below 0 is clamped to 0
    assert np.all(m.noise_var_at(5.0) == 7.0) and np.all(m.noise_var_at(-5.0) == 0.0)


def test_darks_default_to_the_temperature_most_of_them_share() -> None:
    """select_darks without a temperature to match: the one most darks share within the
    tolerance (ties: the lower), the others left out with a note; a matched dark without a
    temperature is noted."""
    R = SimpleNamespace
    darks = [R(temperature=20.0, relpath="a"), R(temperature=20.5, relpath="b"),
             R(temperature=30.0, relpath="c"), R(temperature=None, relpath="d")]
    session = R(frames=[])
    matched, excluded, target, notes = DM.select_darks(session, darks, None, 1.0)
    assert target == 20.0
    assert [r.relpath for r in matched] == ["a", "b", "d"]
    assert [r.relpath for r in excluded] == ["c"]
    assert any("most dark frames share" in n for n in notes)
    assert any(n.startswith("1 dark frame(s) without a temperature") for n in notes)
    # a frame 1.0 °C away is within the tolerance; a given temperature is "wanted"
    m2, e2, t2, n2 = DM.select_darks(session, darks, 21.0, 1.0)
    assert [r.relpath for r in m2] == ["a", "b", "d"] and t2 == 21.0
    assert any("wanted 21 °C" in n for n in n2)


def test_session_dark_model_errors_name_the_problem() -> None:
    """session_dark_model: no dark frames; none within the tolerance; a matched dark without
    an exposure: CcdError each."""
    R = SimpleNamespace

    def session(recs: list) -> SimpleNamespace:
        return R(select=lambda role, setting=None, gain=None: list(recs), frames=[],
                 root="/s", iter_frames=lambda rs: ((r, np.zeros((2, 2))) for r in rs))
    with pytest.raises(CcdError, match="no dark frames"):
        DM.session_dark_model(session([]))
    with pytest.raises(CcdError, match="within 1 °C of 5 °C"):
        DM.session_dark_model(session([R(temperature=20.0, relpath="a", exposure=0.0)]),
                              temperature=5.0)
    with pytest.raises(CcdError, match="exposure"):
        DM.session_dark_model(session([R(temperature=None, relpath="a", exposure=None),
                                       R(temperature=None, relpath="b", exposure=1.0)]))


# -- two brackets: the checks before the merge ----------------------------------------------------
def _bracket_session(ref: list[np.ndarray], tgt: list[np.ndarray]) -> SimpleNamespace:
    """A session of two brackets (exposures 1, 2, 4 ... s) held in memory."""
    recs = {role: [SimpleNamespace(exposure=float(2 ** k), relpath=f"{role}/k{k:02d}.tif",
                                   role=role) for k in range(len(fr))]
            for role, fr in (("reference", ref), ("target", tgt))}
    frames = {r.relpath: f for role, fr in (("reference", ref), ("target", tgt))
              for r, f in zip(recs[role], fr)}
    return SimpleNamespace(root="/s", bracket_stacks=lambda role: {None: recs[role]},
                           iter_frames=lambda rs, read_ahead=None: ((r, frames[r.relpath])
                                                                    for r in rs))


def test_bracket_change_refuses_another_sample_type_or_a_frame_of_another_shape() -> None:
    """bracket_change checks before any merge: the target's sample type against the
    reference's (naming the target's first frame), the shapes across brackets, and every frame
    against its own bracket's first (naming that frame)."""
    from ccdcore.change.session import bracket_change

    u8 = [np.zeros((6, 8), np.uint8) for _ in range(3)]
    u16 = [np.zeros((6, 8), np.uint16) for _ in range(3)]
    with pytest.raises(CcdError, match="target/k00.tif.*sample type uint16"):
        bracket_change(_bracket_session(u8, u16))
    with pytest.raises(CcdError, match="target/k00.tif.*shape"):
        bracket_change(_bracket_session(u8, [np.zeros((6, 7), np.uint8)] * 3))
    odd = [np.zeros((6, 8), np.uint8), np.zeros((6, 8), np.uint8), np.zeros((8, 6), np.uint8)]
    with pytest.raises(CcdError, match="reference/k02.tif"):
        bracket_change(_bracket_session(odd, u8))
    odd_t = [np.zeros((6, 8), np.uint8), np.zeros((6, 8), np.uint16), np.zeros((6, 8), np.uint8)]
    with pytest.raises(CcdError, match="target/k01.tif"):
        bracket_change(_bracket_session(u8, odd_t))


def test_frame_sets_must_share_shape_and_integer_sample_type() -> None:
    """_checked_frames: a frame of another sample type or shape than the reference's first is
    refused by name; float frames are not a camera's codes."""
    def session(ref: list, tgt: list) -> tuple[SimpleNamespace, dict]:
        recs = {"reference": _records(None, len(ref), "reference"),
                "target": _records(None, len(tgt), "target")}
        data = {r.relpath: f for role, fr in (("reference", ref), ("target", tgt))
                for r, f in zip(recs[role], fr)}
        return SimpleNamespace(read=lambda r: data[r.relpath]), recs
    a8 = np.zeros((4, 5), np.uint8)
    with pytest.raises(CcdError, match="target/1.png.*sample type uint16"):
        CF._checked_frames(*session([a8], [a8, a8.astype(np.uint16)]))
    with pytest.raises(CcdError, match="reference/1.png.*shape"):
        CF._checked_frames(*session([a8, a8.T], [a8]))
    with pytest.raises(CcdError, match="integer codes"):
        CF._checked_frames(*session([a8.astype(float)], [a8.astype(float)]))
    frames, dtype = CF._checked_frames(*session([a8, a8], [a8]))
    assert dtype == np.uint8 and len(frames["reference"]) == 2


def test_response_without_a_product_or_bracket_is_the_srgb_curve_named() -> None:
    """_response: an unknown choice is refused; 'auto' with no product and no bracket, or
    'srgb' even with a bracket in the session, give the sRGB curve with the assumed terms
    (σ_c2 = levels/256) and say why; no response estimate, no noise source."""
    kinds = {"reference": "frames", "target": "frames"}
    none = SimpleNamespace(by_role=lambda role: [])
    with pytest.raises(CcdError, match="unknown response 'x'"):
        CF._response(none, kinds, ("L",), 256, None, "x", "auto", {}, 0, None)
    resp, source, res, noise = CF._response(none, kinds, ("R", "G"), 512, None, "auto", "auto",
                                            {}, 0, None)
    assert set(resp) == {"R", "G"} and res is None and noise is None
    np.testing.assert_array_equal(resp["G"][0], CF.srgb_inverse(512))
    assert resp["R"][1] == (0.01, 0.0, 2.0)
    assert "sRGB" in source and "no calibration product" in source
    braket = SimpleNamespace(by_role=lambda role: [object()] if role == "bracket" else [])
    _, source2, res2, _ = CF._response(braket, kinds, ("L",), 256, None, "srgb", "auto", {}, 0,
                                       None)
    assert "as asked" in source2 and res2 is None
