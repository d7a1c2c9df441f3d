"""Tests of ccdcore.noise: photon transfer (Healey & Kondepudy 1994, sec. IV and appendix).

Tolerances.  The fit's covariance (eq. 66) is the statistical error of (A, σ²_C): with the
simulator's truth the estimates must lie within 3 of their standard errors (a wrong gain, a missing
noise term or a wrong black level moves them by many).  Per-level means: μ̂ averages 2M pixel
values of variance σ²_N, so its standard error is √(σ²_N / 2M); we allow 6 of them (the mean also
carries a rounding bias far below that).  Per-level variances: eq. 39 gives the standard error
√(2σ⁴/(M − 1)); we allow 4.  Algebraic identities (closed form vs. numpy) are checked to 1e-10.
Every random test uses a fixed seed, so the tests are deterministic.
"""
from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from ccdcore.errors import CcdError
from ccdcore.io.frames import read_image, write_image
from ccdcore.noise import (CLIP_LIMIT, LineFit, PhotonTransfer, fit_points, goodness_of_fit,
                           pair_statistics, photon_transfer, ptc_points, weighted_line_fit)
from ccdcore.session import open_session
from ccdcore.simulate import simulate

# small healey94 sessions: 96x64 frames, 8 PTC levels, few other frames (each takes ~0.3 s)
SMALL = dict(size=(96, 64), n_dark=4, levels=8, n1=1, n2=1, patches=(("a", 0.01),),
             scene_levels=(0.5,), max_intensity=None)
SEEDS = (3, 17, 2024)


def sim(root: Path, seed: int = 3, **options) -> tuple[Path, dict]:
    truth = simulate("healey94", root, seed=seed, **{**SMALL, **options})
    return root, truth


@pytest.fixture(scope="module", params=SEEDS)
def healey(request, tmp_path_factory) -> tuple[Path, dict]:
    return sim(tmp_path_factory.mktemp(f"healey{request.param}"), seed=request.param)


def within(value: float, truth: float, err: float, k: float = 3.0) -> bool:
    return abs(value - truth) <= k * err


def check_against_truth(pt: PhotonTransfer, truth: dict, sigma_c2: float | None = None) -> None:
    """A and σ²_C within 3 standard errors (eq. 66); read noise within 3 propagated errors."""
    c_true = truth["sigma_c2"] if sigma_c2 is None else sigma_c2
    assert within(pt.A, truth["A"], pt.A_err), (pt.A, truth["A"], pt.A_err)
    assert within(pt.sigma_c2, c_true, pt.sigma_c2_err), (pt.sigma_c2, c_true, pt.sigma_c2_err)
    if sigma_c2 is None:
        assert within(pt.read_noise_e, truth["read_noise_e"], pt.read_noise_e_err)
        rn_dn_true = math.sqrt(c_true - pt.quantisation_dn2)       # A·σ_R of eq. 27, in DN
        assert within(pt.read_noise_dn, rn_dn_true, pt.read_noise_dn_err)


def edit_manifest(root: Path, edit) -> None:
    path = root / "session.toml"
    doc = tomllib.loads(path.read_text())
    edit(doc)
    path.write_text(tomli_w.dumps(doc))


# --------------------------------------------------------------------------------------------
# the estimators (eqs. 37-40, 59-67)
# --------------------------------------------------------------------------------------------
def test_goodness_of_fit_reproduces_the_paper() -> None:
    # sec. VII-A: chi2 = 4.3496 with P = 6 pairs (4 degrees of freedom) gives Q = 0.3607; the
    # exact value is 0.360755..., which the paper reports truncated to 4 decimals
    q = goodness_of_fit(4.3496, 4)
    assert math.floor(q * 1e4) / 1e4 == 0.3607 and abs(q - 0.360755) < 1e-6
    assert goodness_of_fit(0.0, 3) == 1.0
    assert goodness_of_fit(1e4, 3) < 1e-100
    assert math.isnan(goodness_of_fit(1.0, 0))


def test_closed_form_fit_equals_generic_weighted_least_squares() -> None:
    rng = np.random.default_rng(5)
    for _ in range(5):
        p = int(rng.integers(3, 30))
        mu = rng.uniform(0, 4000, p)
        var_var = rng.uniform(0.01, 5.0, p)
        var = 0.02 * mu + 3.0 + rng.normal(0, np.sqrt(var_var))
        fit = weighted_line_fit(mu, var, var_var)
        # numpy.polyfit weights multiply the residuals: w = 1/sigma
        coef, cov = np.polyfit(mu, var, 1, w=1 / np.sqrt(var_var), cov="unscaled")
        np.testing.assert_allclose([fit.A, fit.sigma_c2], coef, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(fit.cov, cov, rtol=1e-10)
        # covariance (eq. 66) = inverse of the normal matrix of the weighted problem
        X = np.column_stack([mu, np.ones(p)])
        normal = X.T @ (X / var_var[:, None])
        np.testing.assert_allclose(fit.cov, np.linalg.inv(normal), rtol=1e-10)
        beta = np.linalg.solve(normal, X.T @ (var / var_var))
        np.testing.assert_allclose([fit.A, fit.sigma_c2], beta, rtol=1e-10, atol=1e-12)
        chi2 = float(np.sum((var - X @ beta) ** 2 / var_var))
        assert fit.chi2 == pytest.approx(chi2, rel=1e-10) and fit.dof == p - 2
        assert fit.Q == pytest.approx(goodness_of_fit(chi2, p - 2), rel=1e-12)


def test_line_predict_band_is_the_propagated_covariance() -> None:
    cov = np.array([[4e-8, -2e-6], [-2e-6, 3e-4]])
    fit = LineFit(A=0.01, sigma_c2=2.0, cov=cov, chi2=1.0, dof=3, Q=0.8)
    value, std = fit.predict(100.0)
    assert value == pytest.approx(3.0)
    assert std == pytest.approx(math.sqrt(np.array([100.0, 1.0]) @ cov @ np.array([100.0, 1.0])))
    values, stds = fit.predict([0.0, 100.0])
    assert stds[0] == pytest.approx(math.sqrt(3e-4)) and values[1] == pytest.approx(3.0)


def test_weighted_line_fit_rejects_bad_input() -> None:
    with pytest.raises(CcdError, match="at least 2 points"):
        weighted_line_fit([1.0], [1.0], [1.0])
    with pytest.raises(CcdError, match="var_var finite and > 0"):
        weighted_line_fit([1.0, 2.0], [1.0, 2.0], [1.0, 0.0])
    with pytest.raises(CcdError, match="same mean"):
        weighted_line_fit([1.0, 1.0, 1.0], [1.0, 2.0, 3.0], [1.0, 1.0, 1.0])


def test_pair_statistics_matches_the_definitions_and_eq_39() -> None:
    rng = np.random.default_rng(8)
    sigma2, shape = 4.0, (200, 150)
    field = 100 + 20 * rng.random(shape)  # a nonuniform mean cancels in the difference image
    d1 = field + rng.normal(0, math.sqrt(sigma2), shape)
    d2 = field + rng.normal(0, math.sqrt(sigma2), shape)
    mu, var, var_var, m = pair_statistics(d1, d2)
    assert m == d1.size
    assert mu == pytest.approx(np.concatenate([d1, d2]).mean(), rel=1e-12)       # eq. 37
    assert var == pytest.approx(np.var(d1 - d2, ddof=1) / 2, rel=1e-12)          # eq. 38
    assert var_var == pytest.approx(2 * var ** 2 / (m - 1), rel=1e-12)           # eq. 40
    assert abs(var - sigma2) < 4 * math.sqrt(2 * sigma2 ** 2 / (m - 1))          # eq. 39
    with pytest.raises(CcdError, match="shapes differ"):
        pair_statistics(d1, d2[:10])


# --------------------------------------------------------------------------------------------
# against the simulator's truth
# --------------------------------------------------------------------------------------------
def test_photon_transfer_recovers_the_truth(healey) -> None:
    root, truth = healey
    pt = photon_transfer(root)
    assert pt.black_level_source == "camera" and pt.black_level_dn == truth["black_level_dn"]
    check_against_truth(pt, truth)
    assert pt.conversion_gain_e_per_dn == pytest.approx(1 / pt.A)
    assert within(pt.conversion_gain_e_per_dn, 1 / truth["A"], pt.conversion_gain_e_per_dn_err)
    assert pt.quantisation_dn2 == pytest.approx(1 / 12)
    assert pt.read_noise_dn == pytest.approx(math.sqrt(pt.sigma_c2 - 1 / 12))
    # the propagated error is the numerical derivative of √(σ²_C − q²/12) times σ(σ²_C)
    h = 1e-6
    slope = (math.sqrt(pt.sigma_c2 + h - 1 / 12) - math.sqrt(pt.sigma_c2 - h - 1 / 12)) / (2 * h)
    assert pt.read_noise_dn_err == pytest.approx(slope * pt.sigma_c2_err, rel=1e-6)
    # chi2 ~ dof: Q not tiny
    assert pt.dof == 6 and pt.Q > 0.001 and pt.verdict in ("acceptable", "poor")
    m = 96 * 64
    for p, t in zip(pt.points, truth["ptc"]):
        assert p.used and p.reason is None and p.n_pairs == 1 and p.n_pixels == m
        assert abs(p.mu_raw - t["mu"]) < 6 * math.sqrt(t["sigma2_N"] / (2 * m))
        assert p.mu == p.mu_raw - truth["black_level_dn"]
        assert abs(p.var - t["sigma2_N"]) < 4 * math.sqrt(2 * t["sigma2_N"] ** 2 / (m - 1))
        assert p.var_err == pytest.approx(math.sqrt(2 * p.var ** 2 / (m - 1)))
    assert pt.sigma_n2(100.0) == pytest.approx(pt.A * 100 + pt.sigma_c2)


def test_to_dict_is_json_with_the_design_keys(healey) -> None:
    pt = photon_transfer(healey[0])
    d = json.loads(json.dumps(pt.to_dict(), allow_nan=False))
    for key in ("A", "sigma_c2", "cov", "chi2", "dof", "Q", "points", "conversion_gain_e_per_dn",
                "read_noise_e", "A_err", "sigma_c2_err", "read_noise_e_err", "black_level_dn",
                "black_level_source", "notes", "robust_dropped", "verdict"):
        assert key in d, key
    assert np.array(d["cov"]).shape == (2, 2)
    assert {"level", "mu", "var", "var_err", "used"} <= set(d["points"][0])


def test_roi(tmp_path) -> None:
    root, truth = sim(tmp_path / "s", seed=9)
    roi = (10, 8, 48, 32)
    full = photon_transfer(root)
    pt = photon_transfer(root, roi=roi)
    assert pt.roi == roi and all(p.n_pixels == 48 * 32 for p in pt.points)
    check_against_truth(pt, truth)
    # a quarter of the pixels: errors about twice as large (eq. 40 scales as 1/(M - 1))
    assert 1.5 < pt.A_err / full.A_err < 2.7
    session = open_session(root)
    (a, b) = session.ptc_levels()[3]
    d1, d2 = (read_image(r.path)[8:40, 10:58] for r in (a, b))
    mu, var, _, _ = pair_statistics(d1, d2)
    p3 = next(p for p in pt.points if p.level == 3)
    assert (p3.mu_raw, p3.var) == (pytest.approx(mu, rel=1e-12), pytest.approx(var, rel=1e-12))
    with pytest.raises(CcdError) as info:
        photon_transfer(root, roi=(60, 8, 48, 32))
    assert "ROI 60,8,48,32 (X,Y,W,H) lies outside the 96x64 frame" in str(info.value)
    with pytest.raises(CcdError, match="four integers"):
        photon_transfer(root, roi=(1, 2, 3))


def test_levels_with_more_frames_use_every_disjoint_pair(tmp_path) -> None:
    root, truth = sim(tmp_path / "s", seed=4, ptc_frames=5, levels=4)
    pt = photon_transfer(root)
    check_against_truth(pt, truth)
    session = open_session(root)
    recs = session.ptc_levels()[2]
    frames = [read_image(r.path) for r in recs]
    stats = [pair_statistics(frames[0], frames[1]), pair_statistics(frames[2], frames[3])]
    p = pt.points[1]
    m = 96 * 64
    assert (p.level, p.n_pairs) == (2, 2)
    assert p.mu_raw == pytest.approx(np.mean([s[0] for s in stats]), rel=1e-12)
    assert p.var == pytest.approx(np.mean([s[1] for s in stats]), rel=1e-12)
    assert p.var_err == pytest.approx(math.sqrt(2 * p.var ** 2 / (2 * (m - 1))), rel=1e-12)
    assert any("ptc level 2: 5 frames" in n and "L02_e.tif" in n for n in pt.notes)


def test_robust_mode_drops_an_outlier_level(tmp_path) -> None:
    root, truth = sim(tmp_path / "s", seed=21)
    # tamper level 4: extra noise of variance 2/3 in one frame raises sigma^2_N by 1/3 DN^2,
    # about 12 standard errors (sqrt(2 sigma^4 / (M - 1)) ~ 0.027 DN^2)
    path = root / "ptc" / "L04_b.tif"
    d = read_image(path).astype(int) + np.random.default_rng(1).integers(-1, 2, (64, 96))
    write_image(path, np.clip(d, 0, 255).astype(np.uint8), exposure=0.033, bits=8)
    plain = photon_transfer(root)
    assert all(p.used for p in plain.points) and plain.verdict == "model rejected"
    pt = photon_transfer(root, robust=True)
    assert pt.robust_dropped == (4,)
    p4 = next(p for p in pt.points if p.level == 4)
    assert not p4.used and p4.reason.startswith("robust mode: residual")
    assert sum(p.used for p in pt.points) == 7 and pt.dof == 5
    assert any(n.startswith("level 4 not used: robust mode") for n in pt.notes)
    check_against_truth(pt, truth)
    # the app's fast path: refit the same points without reading frames
    again = fit_points(ptc_points(root), robust=True, black_level_dn=0.0)
    assert again.robust_dropped == (4,) and again.A == pytest.approx(pt.A, rel=1e-12)
    assert pt.refit().robust_dropped == () and pt.refit().A == pytest.approx(plain.A, rel=1e-12)


def test_user_exclusions_and_refit(healey) -> None:
    root, truth = healey
    pt = photon_transfer(root, exclude_levels=[2, 5])
    assert [p.level for p in pt.points if not p.used] == [2, 5]
    assert {p.reason for p in pt.points if not p.used} == {"excluded by user"}
    assert pt.dof == 4
    check_against_truth(pt, truth)
    # fit_points recomputes every flag: no exclusions -> all levels used again
    refit = fit_points(pt.points)
    assert all(p.used for p in refit.points)
    assert refit.A == pytest.approx(photon_transfer(root).A, rel=1e-12)
    assert refit.black_level_dn == pytest.approx(0.0, abs=1e-9)
    assert pt.refit(exclude_levels=[2, 5]).A == pt.A
    with pytest.raises(CcdError, match="no ptc level 99"):
        fit_points(pt.points, exclude_levels=[99])


def test_saturated_level_is_excluded_with_its_reason(tmp_path) -> None:
    root, truth = sim(tmp_path / "s", seed=6, saturate_level=True)
    pt = photon_transfer(root)
    sat = pt.points[-1]
    assert truth["ptc"][-1]["saturated"] and sat.level == 9
    assert not sat.used and sat.clipped_fraction > 0.5
    assert sat.reason.startswith("clipped: ") and "at 0 or 255 (limit 0.01%)" in sat.reason
    assert all(p.used for p in pt.points[:-1]) and pt.dof == 6
    check_against_truth(pt, truth)
    # clipping below the limit does not exclude
    assert CLIP_LIMIT == 1e-4


def test_level_past_saturation_by_the_variance_turning_down(tmp_path) -> None:
    root, truth = sim(tmp_path / "s", seed=12)
    # the top level's variance collapses (as past a full well, where nothing reaches the ADC's
    # full scale): b := round((a + b) / 2) quarters it
    a_path, b_path = root / "ptc" / "L08_a.tif", root / "ptc" / "L08_b.tif"
    a, b = read_image(a_path).astype(float), read_image(b_path).astype(float)
    write_image(b_path, np.round((a + b) / 2).astype(np.uint8), exposure=0.033, bits=8)
    pt = photon_transfer(root)
    top = pt.points[-1]
    assert top.clipped_fraction == 0.0
    assert not top.used and top.reason.startswith("beyond the linear range (saturation)")
    assert "below the peak" in top.reason and "of level 7" in top.reason
    assert all(p.used for p in pt.points[:-1])
    check_against_truth(pt, truth)


def test_level_beyond_the_linear_range_without_exposure_information(tmp_path) -> None:
    root, truth = sim(tmp_path / "s", seed=13)
    # the top level's variance jumps (extra noise of variance 2 in each frame: +2 DN^2, about
    # 60 standard errors and +100 %); no exposure information, so the variance rule applies
    rng = np.random.default_rng(2)
    for name in ("L08_a.tif", "L08_b.tif"):
        path = root / "ptc" / name
        d = read_image(path).astype(int) + rng.integers(-2, 3, (64, 96))
        write_image(path, np.clip(d, 0, 255).astype(np.uint8), exposure=0.033, bits=8)
    pt = photon_transfer(root)
    top = pt.points[-1]
    assert not top.used and top.reason.startswith("beyond the linear range: variance")
    assert "top 10% of the range" in top.reason and "7 lower levels" in top.reason
    assert all(p.used for p in pt.points[:-1])
    check_against_truth(pt, truth)


# --------------------------------------------------------------------------------------------
# black level
# --------------------------------------------------------------------------------------------
def test_black_level_from_the_manifest_or_the_darks(tmp_path) -> None:
    root, truth = sim(tmp_path / "s", seed=31, black_level_dn=20.0)
    assert tomllib.loads((root / "session.toml").read_text())["camera"]["black_level"] == 20.0
    pt = photon_transfer(root)
    assert (pt.black_level_source, pt.black_level_dn) == ("camera", 20.0)
    check_against_truth(pt, truth)  # the offset carries no shot noise: sigma_c2 is the truth
    for p in pt.points:
        assert p.mu == pytest.approx(p.mu_raw - 20.0)

    given = photon_transfer(root, black_level=20.0)
    assert given.black_level_source == "argument" and given.A == pt.A

    edit_manifest(root, lambda doc: doc["camera"].pop("black_level"))
    dark = photon_transfer(root)
    assert dark.black_level_source == "dark_mean"
    # b0 = the dark mean over 4 frames of 6144 pixels; its error is tiny next to the ROI's spread
    assert dark.black_level_dn == pytest.approx(truth["dark_mean_dn"], abs=0.05)
    assert any("EMVA 1288 convention" in n and "dark shot noise" in n for n in dark.notes)
    # the intercept absorbs the dark shot noise A^2 E_DC = A (dark mean - black level)
    dark_shot = truth["A"] * (truth["dark_mean_dn"] - truth["black_level_dn"])
    check_against_truth(dark, truth, sigma_c2=truth["sigma_c2"] + dark_shot)
    assert within(dark.A, truth["A"], dark.A_err)


def synthetic_session(root: Path, mus: list[float], exposures: list[float], *,
                      darks: dict[float, float] | None = None, A: float = 0.5,
                      sigma_c2: float = 4.0, black: float = 5.0, shape=(32, 48), seed: int = 0,
                      variances: list[float] | None = None, dtype=np.uint16, bits: int = 12,
                      level_exposures: dict[int, tuple[float, float]] | None = None) -> Path:
    """PTC pairs of Gaussian frames with mean mu and variance A (mu - black) + sigma_c2 (12-bit
    TIFF), and dark frames {exposure: mean}; frames of level k at ``exposures[k - 1]``."""
    rng = np.random.default_rng(seed)
    frames = []

    def put(rel, mean, var, exposure, **meta):
        d = mean + rng.normal(0, math.sqrt(var), shape)
        if dtype == np.float32:
            d = d.astype(np.float32)
        else:
            d = np.clip(np.round(d), 0, 2 ** bits - 1).astype(dtype)
        write_image(root / rel, d, exposure=exposure)
        frames.append({"path": rel, "exposure": exposure, **meta})

    for k, (mu, t) in enumerate(zip(mus, exposures), start=1):
        var = A * (mu - black) + sigma_c2 if variances is None else variances[k - 1]
        ta, tb = (level_exposures or {}).get(k, (t, t))
        put(f"ptc/L{k}_a.tif", mu, var, ta, role="ptc", level=k)
        put(f"ptc/L{k}_b.tif", mu, var, tb, role="ptc", level=k)
    for i, (t, mean) in enumerate((darks or {}).items()):
        for j in range(2):
            put(f"dark/d{i}_{j}.tif", mean, sigma_c2 + A * (mean - black), t, role="dark")
    (root / "session.toml").write_text(tomli_w.dumps(
        {"schema": 1, "camera": {"name": "synthetic", "bits": bits, "layout": "mono"},
         "frames": frames}))
    return root


def test_black_level_extrapolated_from_darks_at_several_exposures(tmp_path) -> None:
    # dark mean 50 + 100 T DN at T = 0.01, 0.02, 0.04 s: zero-exposure black level 50 DN
    darks = {0.01: 51.0, 0.02: 52.0, 0.04: 54.0}
    root = synthetic_session(tmp_path / "s", [100.0, 400.0, 800.0, 1600.0],
                             [0.02, 0.02, 0.02, 0.02], darks=darks, black=50.0)
    pt = photon_transfer(root)
    assert pt.black_level_source == "dark_extrapolated"
    # each dark mean averages 2 x 1536 pixels of variance ~4.5: error ~0.04 DN; the extrapolated
    # intercept has about twice that error; allow 0.3 DN
    assert pt.black_level_dn == pytest.approx(50.0, abs=0.3)
    assert any("extrapolated to zero exposure" in n for n in pt.notes)
    assert within(pt.A, 0.5, pt.A_err) and within(pt.sigma_c2, 4.0, pt.sigma_c2_err)

    no_darks = synthetic_session(tmp_path / "n", [100.0, 400.0, 800.0], [0.02] * 3)
    pt = photon_transfer(no_darks)
    assert (pt.black_level_source, pt.black_level_dn) == ("none", 0.0)
    assert any("b0 = 0, the paper's model" in n for n in pt.notes)


def test_level_beyond_the_linear_range_from_exposure_times(tmp_path) -> None:
    # mean = 5 + 2000 T, linear up to the last level, which is 15 % low (a compressed response)
    exposures = [0.05, 0.1, 0.2, 0.4, 0.8, 1.2]
    mus = [5 + 2000 * t for t in exposures]
    mus[-1] = 5 + 0.85 * 2000 * exposures[-1]
    root = synthetic_session(tmp_path / "s", mus, exposures)
    pt = photon_transfer(root, black_level=5.0)
    assert [p.used for p in pt.points] == [True] * 5 + [False]
    assert pt.points[-1].reason.startswith("beyond the linear range: mean")
    assert "against exposure" in pt.points[-1].reason and "-15" in pt.points[-1].reason
    assert within(pt.A, 0.5, pt.A_err) and within(pt.sigma_c2, 4.0, pt.sigma_c2_err)
    # a looser tolerance keeps it (and the fit then sees the wrong variance of that level)
    assert all(p.used for p in photon_transfer(root, linearity_tolerance=0.2).points)


# --------------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------------
def test_fewer_than_three_levels(tmp_path) -> None:
    root, _ = sim(tmp_path / "s", seed=2, levels=2)
    with pytest.raises(CcdError) as info:
        photon_transfer(root)
    assert "2 usable ptc levels (1, 2) of 2; need at least 3" in str(info.value)
    root, _ = sim(tmp_path / "t", seed=2, levels=3, saturate_level=True)
    with pytest.raises(CcdError) as info:
        photon_transfer(root, exclude_levels=[1])
    msg = str(info.value)
    assert "2 usable ptc levels (2, 3) of 4; need at least 3" in msg
    assert "level 1: excluded by user" in msg and "level 4: clipped" in msg


def test_mismatched_exposure_in_a_pair(tmp_path) -> None:
    root, _ = sim(tmp_path / "s", seed=2, levels=4)

    def edit(doc):
        entry = next(f for f in doc["frames"] if f["path"] == "ptc/L03_b.tif")
        entry["exposure"] = 0.05

    edit_manifest(root, edit)
    with pytest.raises(CcdError) as info:
        photon_transfer(root)
    msg = str(info.value)
    assert msg.startswith(f"{root / 'session.toml'}: ptc level 3: mismatched exposure times")
    assert "ptc/L03_a.tif (0.033 s)" in msg and "ptc/L03_b.tif (0.05 s)" in msg


def test_no_ptc_frames(tmp_path) -> None:
    root = synthetic_session(tmp_path / "s", [], [], darks={0.01: 10.0})
    with pytest.raises(CcdError, match="no ptc frames"):
        photon_transfer(root)


def test_nan_pixels_in_float_frames(tmp_path) -> None:
    root = tmp_path / "s"
    synthetic_session(root, [100.0, 400.0, 800.0], [0.02] * 3, dtype=np.float32)
    path = root / "ptc" / "L2_b.tif"
    d = read_image(path)
    d[3, 4] = np.nan
    write_image(path, d, exposure=0.02)
    with pytest.raises(CcdError) as info:
        photon_transfer(root)
    assert str(info.value).startswith("ptc/L2_b.tif: 1 NaN or infinite pixel value in the frame")
    # outside the ROI it does not matter
    assert photon_transfer(root, roi=(10, 10, 20, 20)).dof == 1


def test_colour_frames_are_refused(tmp_path) -> None:
    root = tmp_path / "s"
    rng = np.random.default_rng(0)
    frames = []
    for k in (1, 2, 3):
        for s in "ab":
            write_image(root / f"L{k}{s}.tif", rng.integers(0, 255, (8, 8, 3)).astype(np.uint8))
            frames.append({"path": f"L{k}{s}.tif", "role": "ptc", "level": k})
    (root / "session.toml").write_text(tomli_w.dumps(
        {"schema": 1, "camera": {"bits": 8, "layout": "rgb"}, "frames": frames}))
    with pytest.raises(CcdError, match="colour frames .* per channel support comes with the "
                                       "flat-field work"):
        photon_transfer(root)


def test_emva_fit_range_leaves_out_levels_above_70_percent_of_saturation(tmp_path) -> None:
    """fit_fraction = 0.7 (EMVA 1288 release 3.1 sec. 6.6): levels whose signal is above 70 %
    of the saturation signal (the level of largest variance) are left out as "range", the rest
    as without it; the result and its dict say which range was used, and a refit keeps it."""
    from ccdcore.noise import EMVA_FIT_FRACTION, EXCLUSIONS

    root, truth = sim(tmp_path / "s", seed=14)
    full = photon_transfer(root)
    emva = photon_transfer(root, fit_fraction=EMVA_FIT_FRACTION)
    assert EMVA_FIT_FRACTION == 0.7 and "range" in EXCLUSIONS
    peak = max((p for p in full.points if p.used), key=lambda p: p.var)
    for a, b in zip(full.points, emva.points):
        above = a.used and a.mu > 0.7 * peak.mu
        assert b.used == (a.used and not above), a.level
        if above:
            assert b.exclusion == "range" and "70 % of the saturation signal" in b.reason
    assert sum(p.used for p in emva.points) < sum(p.used for p in full.points)
    assert emva.fit_fraction == 0.7 and "EMVA 1288 range" in emva.fit_range
    assert full.fit_fraction is None and "below saturation" in full.fit_range
    assert emva.to_dict()["fit_fraction"] == 0.7
    assert emva.refit().fit_fraction == 0.7 and emva.refit(fit_fraction=None).fit_fraction is None
    check_against_truth(emva, truth)
    with pytest.raises(CcdError, match="fit_fraction"):
        photon_transfer(root, fit_fraction=1.5)
