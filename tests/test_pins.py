"""Pins: estimators checked against expectations computed independently of the code under test.

Each test here guards against one small, plausible bug (a dropped factor, a wrong divisor, a
median for a mean ...) that the rest of the suite would not notice, because the other tests build
their expectations from the estimator's own outputs or check only loose bounds.  The expectation
is always computed from first principles in the test itself: the simulator's truth, a noise budget
derived in a comment next to the assertion, a closed-form value on frames constructed so that
their per-pixel statistics are known exactly, or a plain numpy computation on the same frames.
Never from a helper of the code under test.

Tolerances are a few standard errors of the compared statistic (derived next to each assertion)
or rounding error for exact identities; every random draw uses a fixed seed, so the tests are
deterministic.  Frames are small, so each test takes well under a second or two.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from ccdcore.dark.frame import dark_reference
from ccdcore.fixedpattern import fixed_pattern_map
from ccdcore.flatfield.fit import flat_field
from ccdcore.noise import PtcPoint, fit_points, pair_statistics, photon_transfer
from ccdcore.session import open_session
from ccdcore.simulate import load_truth, simulate
from ccdcore.flatfield.uniformity import snup_vs_averaging

#: q²/12 for integer data (q = 1 DN), the quantisation term of eq. 27 (Healey & Kondepudy 1994)
Q2_12 = 1.0 / 12.0


# --------------------------------------------------------------------------------------------
# 1. noise.py: the error of the read noise in electrons
# --------------------------------------------------------------------------------------------
def test_read_noise_e_err_is_the_delta_method_propagation(tmp_path):
    """Bug 1: ``read_noise_e_err`` dropping the factor 2 of ∂σ_R/∂σ²_C.

    Eq. 27: σ²_C = A²σ²_R + q²/12, so σ_R = √(σ²_C − q²/12)/A (electrons).  The black level b₀
    only shifts the fit's abscissa (it is given here by the manifest, without error) and adds no
    term to σ_R.  Delta method with the fit's covariance C of (A, σ²_C) (eq. 66):
        ∂σ_R/∂A = −σ_R/A,   ∂σ_R/∂σ²_C = 1/(2A·√(σ²_C − q²/12)),
        var(σ_R) = J·C·Jᵀ.
    An exact identity given (A, σ²_C, C), so the tolerance is rounding (1e-9 relative); without
    the 2 the error is 14 % larger on this session.
    """
    truth = simulate("healey94", tmp_path, seed=3, size=(96, 64), n_dark=4, levels=8, n1=1, n2=1,
                     patches=(("a", 0.01),), scene_levels=(0.5,), max_intensity=None)
    res = photon_transfer(tmp_path)
    assert res.black_level_source == "camera" and res.black_level_dn == truth["black_level_dn"]
    A, c, C = res.A, res.sigma_c2, np.asarray(res.cov, dtype=np.float64)
    assert c > Q2_12 and A > 0
    rn_dn = math.sqrt(c - Q2_12)
    sigma_r = rn_dn / A
    J = np.array([-sigma_r / A, 1.0 / (2.0 * A * rn_dn)])
    expected = math.sqrt(float(J @ C @ J))
    assert res.read_noise_e == pytest.approx(sigma_r, rel=1e-12)
    assert res.read_noise_e_err == pytest.approx(expected, rel=1e-9), (
        res.read_noise_e_err, expected)


def test_read_noise_e_err_matches_the_scatter_over_repeated_captures():
    """Bug 1: ``read_noise_e_err`` against the actual scatter of ``read_noise_e``.

    R = 800 independent photon-transfer experiments, each 7 pairs of Gaussian frames of M = 1024
    pixels with the exact noise model σ²_N = A·μ + σ²_C (A = 0.25 DN/e, A·σ_R = 1 DN, so
    σ_R = 4 e), measured with ``pair_statistics`` and fitted with ``fit_points``.  The levels
    (5 … 1600 DN) pin A well, so the σ²_C term dominates σ(σ_R): dropping the factor 2 makes the
    reported error 1.8 times too large.

    Tolerance: the sample std of R near-Gaussian values has relative standard error
    1/√(2(R − 1)) = 2.5 %; 4 of them = 10 %.  The delta method is first order: with a relative
    error of 6 % on σ_R the second-order terms are ~0.4 %, and the reported error uses the
    estimated weights (each σ̂²_N is off by √(2/M) = 4 %), which moves its mean by a few percent
    at most: 5 % more.  Total 15 %.
    """
    A, rn_dn, M, R = 0.25, 1.0, 1024, 800
    sigma_c2 = rn_dn ** 2 + Q2_12
    mus = np.array([5.0, 50.0, 100.0, 200.0, 400.0, 800.0, 1600.0])
    sds = np.sqrt(A * mus + sigma_c2)
    rng = np.random.default_rng(20240601)
    values, errors = [], []
    for _ in range(R):
        frames = mus[:, None, None] + sds[:, None, None] * rng.standard_normal((len(mus), 2, M))
        points = []
        for i, (d1, d2) in enumerate(frames):
            mu, var, var_var, m = pair_statistics(d1, d2)
            points.append(PtcPoint(level=i + 1, mu=mu, var=var, var_err=math.sqrt(var_var),
                                   n_pairs=1, n_pixels=m, used=True, reason=None, exposure=None,
                                   mu_raw=mu, clipped_fraction=0.0))
        res = fit_points(points, black_level_dn=0.0)
        assert all(p.used for p in res.points)
        values.append(res.read_noise_e)
        errors.append(res.read_noise_e_err)
    scatter = float(np.std(values, ddof=1))
    reported = float(np.mean(errors))
    # the experiments do measure σ_R (4 e) to within 4 standard errors scatter/√R, plus the
    # second-order bias of √(σ²_C − q²/12)/A, of order (relative error)²·σ_R ≈ 0.06²·4 e ≈ 0.015 e
    # (we allow 0.1 scatter = 0.025 e)
    assert abs(np.mean(values) - rn_dn / A) < 4 * scatter / math.sqrt(R) + 0.1 * scatter
    assert reported == pytest.approx(scatter, rel=0.15), (reported, scatter)


# --------------------------------------------------------------------------------------------
# 2. uniformity.py: the fixed/temporal split of SNUP (Table 1 of de Lasarte et al. 2007)
# --------------------------------------------------------------------------------------------
def test_snup_vs_averaging_splits_a_known_fixed_pattern_and_temporal_noise():
    """Bug 2: SNUP_fixed / SNUP_temporal / predicted SNUP_N of ``snup_vs_averaging``.

    Frames: a fixed pattern P = m·F (F a PRNU field of relative std 1 %, m = 1000 DN) plus
    independent Gaussian temporal noise of σ_t = 20 DN, n = 16 frames of M = 128² pixels.
    True values (in the test, from the construction): SNUP_fixed = 100·std(P)/mean(P) (the
    realised pattern, ≈ 1 %), SNUP_temporal = 100·σ_t/mean(P) (≈ 2 %).

    Errors (variance units DN², given P):
      * temporal: mean of M·(n − 1)-dof sample variances, relative SE √(2/(M(n − 1))) = 0.29 %
        in σ_t², 0.14 % in SNUP_temporal;
      * fixed: V̂ = s²(avg) − ⟨s²_t⟩/n with avg = P + ē, var(ē) = σ_t²/n = 25 DN²:
        SE of s²(ē) = 25·√(2/M) = 0.28, of the cross term 2·cov(P, ē) = 2·std(P)·5/√M = 0.78,
        of ⟨s²_t⟩/n = 25·0.0029 = 0.07; in quadrature 0.83 DN² on std(P)² = 100 DN², i.e.
        0.42 % in SNUP_fixed.
    Tolerance 5 of these.  (Forgetting the 1/n in SNUP_fixed² = SNUP_n² − SNUP_temporal²/n gives
    0 here; any other mix-up of the split is off by tens of percent.)
    """
    n, shape, m, f_std, sigma_t = 16, (128, 128), 1000.0, 0.01, 20.0
    rng = np.random.default_rng(7)
    P = m * (1.0 + f_std * rng.standard_normal(shape))
    frames = [P + sigma_t * rng.standard_normal(shape) for _ in range(n)]
    M = P.size
    res = snup_vs_averaging(frames, layout="mono")
    assert res.n_frames == n and [r.N for r in res.channel("L")] == [1, 2, 4, 8, 16]

    true_fixed = 100.0 * float(P.std(ddof=1)) / float(P.mean())
    true_temporal = 100.0 * sigma_t / float(P.mean())
    se_t_rel = 0.5 * math.sqrt(2.0 / (M * (n - 1)))
    var_e = sigma_t ** 2 / n
    se_v = math.sqrt((var_e * math.sqrt(2.0 / M)) ** 2
                     + (2.0 * float(P.std()) * math.sqrt(var_e / M)) ** 2
                     + (var_e * 2 * se_t_rel) ** 2)
    se_f_rel = se_v / (2.0 * float(P.var(ddof=1)))
    assert res.snup_temporal["L"] == pytest.approx(true_temporal, rel=5 * se_t_rel)
    assert res.snup_fixed["L"] == pytest.approx(true_fixed, rel=5 * se_f_rel)

    stack = np.stack(frames)
    for row in res.channel("L"):
        # the measured SNUP of the average of the first N frames: plain numpy, exact
        avg = stack[:row.N].mean(axis=0)
        assert row.snup == pytest.approx(100.0 * avg.std(ddof=1) / avg.mean(), rel=1e-9)
        # the prediction √(fixed² + temporal²/N) against the true one; its SE from the two
        # estimates' errors in SNUP² units, added linearly (they are correlated)
        true_pred = math.sqrt(true_fixed ** 2 + true_temporal ** 2 / row.N)
        se_pred2 = (2 * se_f_rel * true_fixed ** 2 + 2 * se_t_rel * true_temporal ** 2 / row.N)
        assert row.predicted == pytest.approx(true_pred, abs=5 * se_pred2 / (2 * true_pred)), (
            row.N, row.predicted, true_pred)


# --------------------------------------------------------------------------------------------
# 3, 4. flatfield.py: the reference level k and the flag rule
# --------------------------------------------------------------------------------------------
def test_flat_field_k_is_the_mean_of_a_skewed_delta():
    """Bug 3: k must be the *mean* of DL_B − DL_0 over the unflagged pixels (de Lasarte's
    "mean digital level"), not its median.

    Δ = 10 + Exp(50) DN per pixel: mean ≈ 60, median ≈ 10 + 50·ln 2 ≈ 44.7, so they differ by
    ~15 DN while the standard error of the mean over M = 64² pixels is 50/64 ≈ 0.8 DN.  Temporal
    noise σ = 1 DN on 4 base and 4 dark frames gives σ_Δ = √(1/4 + 1/4) = 0.71 DN, so c·σ_Δ =
    3.5 DN < 10 DN: no pixel is flagged, and k is the plain mean of the averaged Δ (to rounding).
    """
    rng = np.random.default_rng(11)
    shape = (64, 64)
    delta = 10.0 + rng.exponential(50.0, shape)
    dark = [100.0 + rng.standard_normal(shape) for _ in range(4)]
    base = [100.0 + delta + rng.standard_normal(shape) for _ in range(4)]
    d = np.mean(base, axis=0) - np.mean(dark, axis=0)
    assert np.mean(d) - np.median(d) > 10 * d.std() / math.sqrt(d.size)   # skewed, by far
    ff = flat_field(dark, base, layout="mono")
    ch = ff.channel("L")
    assert ch.n_flagged == 0
    assert ch.k == pytest.approx(float(np.mean(d)), rel=1e-12)
    # and G = k/Δ (eq. 3 with the default k) at every pixel
    np.testing.assert_allclose(ff.G, np.mean(d) / d, rtol=1e-6)


def _frames_with_known_variance(mean, amp, n):
    """n frames whose per-pixel sample mean is ``mean`` and whose per-pixel sample variance
    (ddof = 1) is exactly amp²·n/(n − 1) (n even: deviations ±amp alternating)."""
    signs = np.array([1.0 if j % 2 == 0 else -1.0 for j in range(n)])
    return [mean + s * amp for s in signs]


@pytest.mark.parametrize("c", [5.0, 3.0])
def test_flat_field_flags_pixels_just_below_and_above_the_threshold(c):
    """Bug 4: the flag rule Δ ≤ c·√(s²_B/n_B + s²_0/n_0) (its square root, and s²_B divided by
    n_B).

    Frames built so that the per-pixel statistics are exact: n_B = 4 base frames μ_B ± a
    (alternating) have s²_B = 4a²/3, n_0 = 2 dark frames μ_0 ± b have s²_0 = 2b², so
    σ_Δ² = s²_B/4 + s²_0/2 = a²/3 + b².  With a² = 3b², σ_Δ = √2·b.  Pixels are placed at
    Δ = c·σ_Δ·(1 ± 10⁻³) for σ_Δ = 0.5 DN and 4 DN (below and above 1 DN, so a rule without the
    square root, c·σ_Δ², moves the threshold down for one and up for the other; a rule with s²_B
    not divided by n_B has σ'_Δ = √5·b, up for both).  The relative margin 10⁻³ is far above the
    rounding of the streamed moments (~1e-14).  The rest of the frame is far above threshold.
    """
    shape = (8, 8)
    delta = np.full(shape, 1000.0)
    sig = np.full(shape, 0.5)
    expect = np.zeros(shape, bool)
    cases = [(0.5, 1 - 1e-3, True), (0.5, 1 + 1e-3, False),
             (4.0, 1 - 1e-3, True), (4.0, 1 + 1e-3, False)]
    for row, (s, factor, flagged) in enumerate(cases):
        sig[row, :] = s
        delta[row, :] = c * s * factor
        expect[row, :] = flagged
    b = sig / math.sqrt(2.0)
    a = math.sqrt(3.0) * b
    mu0 = 200.0
    dark = _frames_with_known_variance(np.full(shape, mu0), b, 2)
    base = _frames_with_known_variance(mu0 + delta, a, 4)
    # the construction's statistics, checked with numpy
    np.testing.assert_allclose(np.var(base, axis=0, ddof=1), 4 * a ** 2 / 3, rtol=1e-9)
    np.testing.assert_allclose(np.var(dark, axis=0, ddof=1), 2 * b ** 2, rtol=1e-9)
    np.testing.assert_allclose(np.mean(base, axis=0) - np.mean(dark, axis=0), delta, rtol=1e-9)
    ff = flat_field(dark, base, layout="mono", noise_limit=c)
    for row, (s, factor, flagged) in enumerate(cases):
        assert (ff.flags[row] == flagged).all(), (
            f"sigma_delta = {s} DN, delta = {factor:g} x threshold: expected flagged={flagged}, "
            f"got {ff.flags[row].tolist()}")
    np.testing.assert_array_equal(ff.flags, expect)
    assert ff.channel("L").n_flagged == int(expect.sum()) == 16


# --------------------------------------------------------------------------------------------
# 5, 6. darkframe.py: the standard error map and the dark-signal nonuniformity
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("s", [4, 5, 8])
def test_dark_sem_map_is_sqrt_var_over_s(s):
    """Bug 5: ``sem_map`` = √(var/s) (the standard error of the mean of s frames), not
    √(var/(s − 1)).

    Computed in the test with numpy (ddof = 1 variance over the s frames, divided by s).  The
    identity holds to rounding (1e-10 relative); the wrong divisor is off by √(s/(s − 1)) − 1 =
    6 % at s = 8, 15 % at s = 4.
    """
    rng = np.random.default_rng(100 + s)
    frames = [np.rint(50.0 + 2.0 * rng.standard_normal((32, 40))).astype(np.uint16)
              for _ in range(s)]
    dr = dark_reference(frames)
    stack = np.stack(frames).astype(np.float64)
    expected = np.sqrt(np.var(stack, axis=0, ddof=1) / s)
    np.testing.assert_allclose(dr.sem_map, expected, rtol=1e-10, atol=1e-12)


def _spatial_std_se(true_std: float, var_e: float, M: int, s: int) -> float:
    """Standard error of ``spatial_std_signal`` for a signal of spatial std ``true_std`` under
    averaging noise of variance ``var_e`` = σ²_N/s on M pixels: in variance units the cross term
    2·σ_D·σ_ē/√M, the sample variance of the noise σ²_ē·√(2/M) and that of mean(var_map)/s,
    σ²_ē·√(2/((s − 1)M)), in quadrature; then d(std) = d(var)/(2·std)."""
    se_var = math.sqrt((2 * true_std * math.sqrt(var_e / M)) ** 2
                       + (var_e * math.sqrt(2.0 / M)) ** 2
                       + (var_e * math.sqrt(2.0 / ((s - 1) * M))) ** 2)
    return se_var / (2 * true_std)


def test_dark_spatial_std_signal_recovers_a_known_nonuniformity():
    """Bug 6: ``spatial_std_signal`` = √(spatial_std² − mean(var_map)/s), not /(s − 1).

    Frames D + N: a true dark signal D of spatial std σ_D = 1 DN and temporal noise σ_n = 2 DN,
    s = 4 frames of M = 128² pixels.  The noise of the average adds σ_n²/s = 1 DN² to the spatial
    variance, which the estimator removes; with /(s − 1) it would remove 4/3 DN² and give
    ≈ √(2/3) = 0.82 DN instead of 1.

    Truth: std(D) of the realised D (ddof = 0, like ``spatial_std``).  Errors in variance units,
    given D (σ²_ē = σ_n²/s = 1): cross term 2·cov(D, ē), SE 2·σ_D·σ_ē/√M = 0.016; s²(ē),
    SE σ²_ē·√(2/M) = 0.011; mean(var_map)/s, SE (σ_n²/s)·√(2/((s − 1)M)) = 0.006.  In quadrature
    0.020 DN², i.e. 0.010 DN on σ_D = 1; 5 of them = 0.05 DN.
    """
    s, shape, sigma_d, sigma_n = 4, (128, 128), 1.0, 2.0
    rng = np.random.default_rng(606)
    D = 20.0 + sigma_d * rng.standard_normal(shape)
    frames = [D + sigma_n * rng.standard_normal(shape) for _ in range(s)]
    dr = dark_reference(frames)
    M = D.size
    true_std = float(D.std())
    var_e = sigma_n ** 2 / s
    se_std = _spatial_std_se(true_std, var_e, M, s)
    assert dr.spatial_std_signal == pytest.approx(true_std, abs=5 * se_std), (
        dr.spatial_std_signal, true_std, se_std)


def test_dark_spatial_std_signal_against_the_healey94_truth(tmp_path):
    """Bug 6 on the simulator: the true dark-signal nonuniformity is the std of the expected dark
    frame (``truth/dark.exr``, ``dark_std_dn`` ≈ 0.52 DN).

    s = 4 dark frames of 96×64 pixels, temporal variance σ²_N ≈ 1.14 DN² (``dark_sigma2_dn``):
    the noise of the average (σ²_N/s = 0.285 DN²) is as large as the signal variance 0.27 DN², so
    dividing by s − 1 instead of s leaves ≈ 0.42 DN (−20 %).  Errors in variance units (σ²_ē =
    0.285, M = 6144): cross term 2·σ_D·σ_ē/√M = 0.0069; s²(ē): σ²_ē·√(2/M) = 0.0051;
    mean(var_map)/s: σ²_ē·√(2/(3M)) = 0.0030; quadrature 0.0091 DN², i.e. 0.0088 DN on 0.52 DN.
    Tolerance 5 of them (8 %).  Rounding to integer DN is part of the temporal noise of both the
    frames and var_map, so it cancels.
    """
    s = 4
    truth = simulate("healey94", tmp_path, seed=21, size=(96, 64), n_dark=s, levels=3, n1=2, n2=1,
                     patches=(("a", 0.01),), scene_levels=(0.5,), max_intensity=None)
    dr = dark_reference(open_session(tmp_path))
    assert dr.s == s
    tmap = load_truth(tmp_path).map("dark_map").astype(np.float64)
    true_std = float(tmap.std())
    assert true_std == pytest.approx(truth["dark_std_dn"], rel=1e-5)
    M = tmap.size
    var_e = truth["dark_sigma2_dn"] / s
    se_std = _spatial_std_se(true_std, var_e, M, s)
    assert dr.spatial_std_signal == pytest.approx(true_std, abs=5 * se_std), (
        dr.spatial_std_signal, true_std, se_std)


# --------------------------------------------------------------------------------------------
# 7. fixedpattern.py: the accuracy of K̂ against the true K map
# --------------------------------------------------------------------------------------------
def test_fixed_pattern_K_error_matches_the_noise_budget(tmp_path):
    """Bug 7: K̂'s RMS error against the simulator's true K, pinned to its noise budget (a K̂
    made without subtracting the dark reference is 2.4 times the budget in mean square).

    healey94, 96×64, n1 = 12 configurations × n2 = 4 frames, s = 16 darks, no card spots
    (``outlier_fraction=0``) and p = 10⁹ (nothing rejected: K̂ is the plain mean of the n1
    slopes, eq. 49), so the budget follows from the model.  With e_i = μ_i − dark mean the
    configuration's level above dark (DN), the error of slope i at a pixel (eq. 47) is:
      * temporal noise of the average of n2 frames: σ²_N,i/(n2·e_i²), with
        σ²_N,i = A·(μ_i − black) + σ²_C (eqs. 28, 41);
      * the card texture, new for every configuration: σ²_card;
    both independent between configurations, so divided by n1 in K̂.  Common to all slopes:
      * the dark reference's error, variance σ²_dark/s, divided by e_i: (σ²_dark/s)·⟨1/e_i⟩²;
      * K's own share of the m×m window mean (eq. 47 divides by it): σ²_K/m².
    The illumination's curvature biases the window mean by ~5e-4/√n1 in K̂ (variance < 0.5 % of
    the budget) and the pixel's own 1/m² share of ē removes 1.2 % of the temporal term; both
    neglected.  The mean of M squared near-Gaussian errors has relative SE √(2/M) = 1.8 %; we
    allow 5 of them plus 5 % for the neglected terms (and the reflect border of the window).
    """
    n1, n2, s, m = 12, 4, 16, 9
    truth = simulate("healey94", tmp_path, seed=5, size=(96, 64), n_dark=s, levels=3, n1=n1,
                     n2=n2, outlier_fraction=0.0, patches=(("a", 0.01),), scene_levels=(0.5,),
                     max_intensity=None)
    session = open_session(tmp_path)
    fp = fixed_pattern_map(session, dark_reference(session), window=m, p=1e9)
    assert (fp.n1_used == n1).all()
    K = load_truth(tmp_path).map("K_map").astype(np.float64)
    rms2 = float(np.mean((fp.K - K) ** 2))

    A, sigma_c2, black = truth["A"], truth["sigma_c2"], truth["black_level_dn"]
    mu = np.asarray(truth["fixed_pattern"]["mean_dn"], dtype=np.float64)
    e = mu - truth["dark_mean_dn"]
    temporal = float(np.sum((A * (mu - black) + sigma_c2) / (n2 * e ** 2))) / n1 ** 2
    card = truth["fixed_pattern"]["card_reflectance_std"] ** 2 / n1
    dark_ref = truth["dark_sigma2_dn"] / s * float(np.mean(1.0 / e)) ** 2
    window = truth["sigma_K"] ** 2 / m ** 2
    budget = temporal + card + dark_ref + window
    tol = 5 * math.sqrt(2.0 / K.size) + 0.05
    assert rms2 == pytest.approx(budget, rel=tol), (rms2 / budget, tol)
