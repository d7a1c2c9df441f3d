"""Fixed-pattern map K̂ (eqs. 45–51 of Healey & Kondepudy 1994) and the correction check (sec.
VII-A), against the healey94 simulator's true K map.

Tolerances are 4 standard errors of the compared statistic, derived next to each assertion; seeds
are fixed, so the tests are deterministic.
"""
from __future__ import annotations

import tomllib

import numpy as np
import pytest
import tomli_w
from scipy.ndimage import uniform_filter
from scipy.special import ndtr

from ccdcore.dark.frame import dark_reference
from ccdcore.errors import CcdError
from ccdcore.fixedpattern import (CorrectionCheck, FixedPattern, correct, correction_check,
                                  fixed_pattern_map)
from ccdcore.io.frames import read_image
from ccdcore.session import open_session
from ccdcore.simulate import load_truth, simulate

N1, N2 = 12, 4
SMALL = dict(size=(64, 48), n_dark=16, levels=3, n1=N1, n2=N2, scene_levels=(0.5,))


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    root = tmp_path_factory.mktemp("fp")
    truth = simulate("healey94", root, seed=5, **SMALL)
    session = open_session(root)
    dark = dark_reference(session)
    fp = fixed_pattern_map(session, dark)
    K = load_truth(root).map("K_map").astype(np.float64)
    return root, truth, session, dark, fp, K


def test_result_fields(sim):
    root, truth, session, dark, fp, K = sim
    assert isinstance(fp, FixedPattern)
    assert fp.K.shape == (48, 64) and fp.n1 == N1 and fp.n2 == N2 and fp.window == 9
    assert fp.rejected.shape == (N1, 48, 64) and fp.rejected.dtype == bool
    np.testing.assert_array_equal(fp.n1_used, N1 - fp.rejected.sum(axis=0))
    assert fp.n1_hat == fp.n1_used.min() >= 1
    assert fp.var_bound == pytest.approx((fp.p * fp.sigma_hat) ** 2 / fp.n1_hat)   # eq. 50
    d = fp.to_dict()
    assert d["n1_hat"] == fp.n1_hat and d["config_ids"] == list(range(1, N1 + 1))
    assert not any(isinstance(v, np.ndarray) for v in d.values())
    # with a session the dark reference may be left out: computed from the session's darks
    np.testing.assert_array_equal(fixed_pattern_map(session).K, fp.K)


def test_K_error_within_eq50_bound(sim):
    """RMS of K̂ − K is within the bound of eq. 50; mean and spread match the truth."""
    root, truth, session, dark, fp, K = sim
    err = fp.K - K
    n = err.size
    rms2 = float(np.mean(err ** 2))
    assert rms2 <= fp.var_bound
    # the estimate is not trivially good: its error is a real fraction of σ_K, as the noise
    # budget predicts (per configuration sqrt(σ²_N/n2 + σ²_dark/s)/level ≈ 0.004, /sqrt(n1),
    # plus the dark reference's common error ≈ 0.27 DN / 170 DN ≈ 0.0016)
    assert 0.1 * truth["K_std"] < np.sqrt(rms2) < truth["K_std"]
    # mean: each slope is a ratio to its local mean (eq. 47), so K̂ is normalised to mean 1 (the
    # model's E[K], sec. II-B), not to the sample mean of this K draw (which is off 1 by
    # ~σ_K/sqrt(n) = 7e-5).  Two error terms: the random errors average out over n pixels
    # (SE ≈ rms/sqrt(n)); and a smooth illumination of relative std σ_ill over a scale of
    # L = min(H, W)/2 pixels has a relative curvature ≈ 2σ_ill/L², which biases a 9x9 window
    # mean by (m² − 1)/12 · 2σ_ill/L² per axis pair (≈ 4.6e-4 here), with a random sign per
    # configuration, so by that over sqrt(n1) in K̂
    ill = truth["fixed_pattern"]["illumination_std"]
    curv_bias = (81 - 1) / 12 * 2 * (2 * ill / (min(K.shape) / 2) ** 2) / np.sqrt(N1)
    assert abs(fp.mean - 1.0) < 4 * np.sqrt(rms2 / n) + curv_bias
    # spread: errors are independent of K, so std(K̂)² ≈ std(K)² + rms²; SE of a std of n values
    # ≈ std/sqrt(2n); plus 1/m² = 1.2 % for K's own share of the 9x9 window mean ē (eq. 47)
    expect = np.sqrt(float(K.std()) ** 2 + rms2)
    assert abs(fp.spatial_std - expect) < 4 * expect / np.sqrt(2 * n) + 0.012 * float(K.std())


def _config_slopes(session, dmap, K):
    """Per configuration: slope / true K − 1, from an independent numpy computation (eq. 47)."""
    out = []
    for cid, recs in session.fixed_pattern_configs().items():
        e = np.mean([read_image(r.path).astype(float) for r in recs], axis=0) - dmap
        out.append(e / uniform_filter(e, 9, mode="reflect") / K - 1.0)
    return np.stack(out)


def test_card_spots_are_rejected(tmp_path):
    """With 2 % of the card in spots of ±25 %, every spot slope is rejected (n'_1 < n1 there)."""
    simulate("healey94", tmp_path, seed=8, size=(64, 48), n_dark=16, levels=3, n1=10,
                     n2=4, outlier_fraction=0.02, outlier_contrast=0.25, scene_levels=(0.5,),
                     max_intensity=None)
    session = open_session(tmp_path)
    dark = dark_reference(session)
    fp = fixed_pattern_map(session, dark)
    K = load_truth(tmp_path).map("K_map").astype(np.float64)
    dev = _config_slopes(session, dark.mean_map, K)
    # a spot moves its slope by ±25 %; noise moves a slope by ~0.5 % (sd), so |dev| > 0.1 is a spot
    spots = np.abs(dev) > 0.1
    assert spots.sum() > 0.015 * spots.size
    assert fp.rejected[spots].all()
    assert (fp.n1_used[spots.any(axis=0)] < fp.n1).all()
    # and the spots do not leak into K̂: the error stays within the eq. 50 bound
    assert np.mean((fp.K - K) ** 2) <= fp.var_bound
    # the paper's centre m̄ (eq. 48) is pulled by a spot by 0.25/n1 = 0.025 > p·σ̂ and then rejects
    # every slope of such a pixel; the default median centre does not
    fp_mean = fixed_pattern_map(session, dark, center="mean")
    assert (fp_mean.n1_used == 0).any() and fp.n1_hat >= 1
    assert any("kept no slope" in n for n in fp_mean.notes)


def test_eq49_on_constructed_slopes():
    """Eqs. 47–49 literally, on configurations whose slopes are known."""
    rng = np.random.default_rng(0)
    n1, h, w = 7, 20, 24
    K = 1 + 0.01 * rng.standard_normal((h, w))
    base = 100.0 * (1 + 0.01 * rng.standard_normal((n1, h, w)))
    base[3, 5, 6] *= 1.5                               # an outlier
    configs = (K * base)[:, None]                      # (n1, n2 = 1, H, W), dark = 0
    for center in ("mean", "median"):
        fp = fixed_pattern_map(configs, np.zeros((h, w)), window=5, p=1.5, center=center)
        e = K * base
        m = e / uniform_filter(e, (1, 5, 5), mode="reflect")                # eq. 47
        m_bar = m.mean(axis=0)                                              # eq. 48
        sigma_hat = m.std(axis=0, ddof=1).mean()
        c = m_bar if center == "mean" else np.median(m, axis=0)
        keep = np.abs(m - c) <= 1.5 * sigma_hat
        np.testing.assert_allclose(fp.m_bar, m_bar, rtol=1e-6)
        assert fp.sigma_hat == pytest.approx(sigma_hat, rel=1e-6)
        np.testing.assert_array_equal(fp.rejected, ~keep)
        used = keep.sum(0)
        with np.errstate(invalid="ignore"):
            expect = np.where(used > 0, (m * keep).sum(0) / used, np.median(m, axis=0))  # eq. 49
        np.testing.assert_allclose(fp.K, expect, rtol=1e-6)
        assert fp.rejected[3, 5, 6]
        # the mean centre is pulled by the outlier (0.5/7 = 0.07 ≫ p·σ̂): nothing kept there,
        # K̂ falls back to the median; the median centre rejects the outlier only
        assert fp.n1_used[5, 6] == (0 if center == "mean" else n1 - 1)


def _kmap_by_array_formulas(e: np.ndarray, window: int, p: float, center: str) -> dict:
    """Eqs. 47–49 as whole-array numpy formulas over (n1, H, W) levels e_i (dark = 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        e_bar = uniform_filter(e, (1, window, window), mode="reflect")
        m = np.where(e_bar > 0, e / e_bar, np.nan).astype(np.float32)      # eq. 47
        ok = np.isfinite(m)
        cnt = ok.sum(0)
        m_bar = np.where(ok, m, 0).astype(np.float64).sum(0) / cnt         # eq. 48
        sd = np.sqrt(np.nansum((m - m_bar) ** 2, axis=0) / (cnt - 1))
        sigma_hat = float(np.nanmean(sd))
        med = np.nanmedian(m, axis=0).astype(np.float64)
        keep = np.abs(m - (m_bar if center == "mean" else med)) <= p * sigma_hat
        used = keep.sum(0)
        K = np.where(used > 0, np.where(keep, m, 0).astype(np.float64).sum(0) / used, med)
        ss = np.where(keep, m - K, 0.0) ** 2
        K_var = np.where(used >= 2, ss.sum(0) / ((used - 1.0) * used),
                         (p * sigma_hat) ** 2 / np.maximum(used, 1))
    return {"m_bar": m_bar, "sigma_hat": sigma_hat, "rejected": ~keep, "n1_used": used, "K": K,
            "K_var": K_var}


@pytest.mark.parametrize("n1,h,w,window", [(7, 40, 52, 9), (6, 33, 20, 5), (5, 7, 30, 9)])
def test_compiled_passes_match_array_formulas(n1, h, w, window):
    """The estimator's compiled passes (local mean, eq. 48, median, eq. 49) against the same
    equations as numpy array formulas, with NaN slopes (ē_i ≤ 0), outliers, even and odd
    counts of usable slopes, and a frame smaller than the window (scipy's border folding)."""
    rng = np.random.default_rng(n1 * h)
    K = 1 + 0.01 * rng.standard_normal((h, w))
    e = K * 100.0 * (1 + 0.01 * rng.standard_normal((n1, h, w)))
    e[1, :4, :4] = -300.0                                 # ē_1 ≤ 0 there: no slope
    e[2, 3, 5] *= 1.5                                     # an outlier
    e[rng.random((n1, h, w)) < 0.05] *= 1.03              # scattered milder ones
    for center in ("median", "mean"):
        fp = fixed_pattern_map(e[:, None], np.zeros((h, w)), window=window, p=1.0, center=center)
        ref = _kmap_by_array_formulas(e, window, 1.0, center)
        assert np.isnan(fp.m_bar).sum() == 0 and (fp.n1_used < n1).any()
        np.testing.assert_allclose(fp.m_bar, ref["m_bar"], rtol=1e-12)
        assert fp.sigma_hat == pytest.approx(ref["sigma_hat"], rel=1e-12)
        np.testing.assert_array_equal(fp.rejected, ref["rejected"])
        np.testing.assert_array_equal(fp.n1_used, ref["n1_used"])
        np.testing.assert_allclose(fp.K, ref["K"], rtol=1e-12)
        np.testing.assert_allclose(fp.K_var, ref["K_var"], rtol=1e-9)


def test_correct_is_eq51(sim):
    root, truth, session, dark, fp, K = sim
    frame = read_image(root / "scene/max_intensity.tif")
    out = correct(frame, dark, fp)
    assert out.dtype == np.float32
    expect = ((frame.astype(np.float64) - dark.mean_map) / fp.K).astype(np.float32)
    np.testing.assert_array_equal(out, expect)
    np.testing.assert_array_equal(correct(frame, dark.mean_map, fp.K), expect)
    with pytest.raises(CcdError, match="K: map shape"):
        correct(frame, dark, fp.K[:10])


def test_correction_check_matches_prediction(sim):
    """The fraction of max-intensity pixels the correction changes by > q and > 2q.

    The modification is c = L·(1/K̂ − 1), L = D − D̂_D, so |c| > q exactly when K̂ lies outside
    [L/(L+q), L/(L−q)].  With K̂ = K' + ε, K' the true K shrunk by its 1/m² share of the window
    mean, ε ~ N(0, rms²) independent of K (rms measured against the truth), the expected
    fraction is the mean over pixels of P(K' + ε outside that interval).  The observed fraction
    is a mean of n nearly independent indicators: SE = sqrt(f(1 − f)/n).
    """
    root, truth, session, dark, fp, K = sim
    frame = read_image(root / "scene/max_intensity.tif")
    chk = correction_check(frame, dark, fp, q=1.0)
    assert isinstance(chk, CorrectionCheck)
    L = frame.astype(np.float64) - dark.mean_map
    c = np.abs(L * (1 / fp.K - 1))
    assert chk.frac_gt_1q == pytest.approx(np.mean(c > 1))
    assert chk.frac_gt_2q == pytest.approx(np.mean(c > 2))
    assert chk.frac_gt_2q_of_gt_1q == pytest.approx(np.sum(c > 2) / np.sum(c > 1))
    assert chk.max_change_q == pytest.approx(c.max())
    assert chk.n_pixels == c.size
    # K̂'s centre: each slope divides by a window mean that contains the pixel's own K with
    # weight 1/m², so K̂ − 1 ≈ (K − 1)(1 − 1/81); the rest of K̂ − K is the random error ε
    k_centre = 1 + (K - 1) * (1 - 1 / 81)
    rms = np.sqrt(np.mean((fp.K - k_centre) ** 2))
    n = c.size
    for k, got in ((1, chk.frac_gt_1q), (2, chk.frac_gt_2q)):
        lo, hi = L / (L + k), L / (L - k)
        pred = float(np.mean(ndtr((lo - k_centre) / rms) + 1 - ndtr((hi - k_centre) / rms)))
        assert abs(got - pred) < 4 * np.sqrt(pred * (1 - pred) / n), (k, got, pred)
    # the simulator's own figure (true K, no estimation error) is lower: K̂ adds spread
    assert chk.frac_gt_1q > truth["max_intensity"]["fraction_changed_gt_1q"]
    # q in DN: with q = 2 the 1q fraction is the 2q fraction for q = 1
    assert correction_check(frame, dark, fp, q=2.0).frac_gt_1q == pytest.approx(chk.frac_gt_2q)


def test_bad_inputs(sim, tmp_path):
    root, truth, session, dark, fp, K = sim
    cfgs = session.fixed_pattern_configs()
    one = {1: session.iter_frames(cfgs[1])}
    with pytest.raises(CcdError, match="1 fixed-pattern configuration: K̂ needs at least 2"):
        fixed_pattern_map(one, dark)
    two = {c: session.iter_frames(cfgs[c]) for c in (1, 2)}
    assert any("n1 = 2" in n for n in fixed_pattern_map(two, dark).notes)
    # a frame of another shape: the error names the file
    frames = [read_image(r.path) for r in cfgs[2]]
    bad = {1: session.iter_frames(cfgs[1]),
           2: [(cfgs[2][0], frames[0]), (cfgs[2][1], frames[1][:, :32])]}
    with pytest.raises(CcdError, match=r"C02_F01\.tif: frame shape"):
        fixed_pattern_map(bad, dark)
    with pytest.raises(CcdError, match="differs from the dark reference"):
        fixed_pattern_map(session, dark.mean_map[:, :32])
    with pytest.raises(CcdError, match="no dark reference"):
        fixed_pattern_map({c: session.iter_frames(cfgs[c]) for c in (1, 2)}, None)
    # a session without dark frames
    man = tomllib.loads((root / "session.toml").read_text())
    man["frames"] = [f for f in man["frames"] if f["role"] != "dark"]
    (root / "nodark.toml").write_text(tomli_w.dumps(man))
    with pytest.raises(CcdError, match="no dark frames.*dark reference"):
        fixed_pattern_map(open_session(root / "nodark.toml"))
    with pytest.raises(CcdError, match="window"):
        fixed_pattern_map(session, dark, window=4)
    # a dark "configuration" (lens capped by mistake)
    dark_cfg = {1: session.iter_frames(cfgs[1]), 2: session.iter_frames(session.dark_frames())}
    with pytest.raises(CcdError, match="not above the dark level"):
        fixed_pattern_map(dark_cfg, dark)
