"""Tests of ccdcore.scene: scene variation V_S (sec. VI, eqs. 51, 54–58) and the variance budget
(Fig. 4) of Healey & Kondepudy (1994), against the healey94 simulator's truth.

The estimator is isolated from the other calibration steps: it gets the TRUE dark map and K map
(truth.json's files) and the true A and σ²_C.  The truth V_S of a patch is the realised
var(I)/mean(I)² of the ideal irradiance over the ROI, so the only randomness left is the sensor
noise of each frame — exactly what V_S_err describes (see the module notes of ccdcore.scene).
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import chi2 as chi2_dist

from ccdcore.errors import CcdError
from ccdcore.io.frames import read_image
from ccdcore.scene import (BUDGET_COMPONENTS, SceneVariation, fit_scene_variation,
                           scene_measurement, scene_variation, scene_variations, variance_budget)
from ccdcore.session import open_session
from ccdcore.simulate import load_truth, simulate

SIZE = (64, 48)  # ROI 48 x 32 = 1536 pixels with the default 8-pixel margin
FAST = dict(n_dark=1, levels=2, n1=1, n2=1)  # only the scene frames matter here


def _sim(root: Path, seed: int, **options):
    out = root / f"s{seed}"
    truth = simulate("healey94", out, seed=seed, size=SIZE, **{**FAST, **options})
    K = load_truth(out).map("K_map").astype(np.float64)
    dark = load_truth(out).map("dark_map").astype(np.float64)
    return out, truth, K, dark


def _noise(truth, cov=None):
    return SimpleNamespace(A=truth["A"], sigma_c2=truth["sigma_c2"], cov=cov,
                           black_level_dn=truth["black_level_dn"])


def _patch_frames(out: Path, patch):
    """(pixels, meta) items of one patch, as scene_variation accepts them."""
    for f in patch["frames"]:
        yield read_image(out / f["path"]), {"roi": patch["roi"], "level": f["level"],
                                            "path": f["path"]}


def _measure_all(out, truth, K, dark, cov=None):
    return {p["name"]: scene_variation(_patch_frames(out, p), dark, K, _noise(truth, cov),
                                       name=p["name"])
            for p in truth["scene"]["patches"]}


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    return _sim(tmp_path_factory.mktemp("scene"), seed=11)


# ---- accuracy -----------------------------------------------------------------------------------
def test_V_S_per_patch_within_error(sim):
    out, truth, K, dark = sim
    res = _measure_all(out, truth, K, dark)
    for p in truth["scene"]["patches"]:
        v = res[p["name"]]
        assert v.dof == len(p["frames"]) - 1 and all(v.used)
        # 3 standard errors: a 0.3 % two-sided chance per patch if V_S_err is honest
        assert abs(v.V_S - p["V_S"]) < 3 * v.V_S_err, (p["name"], v.V_S, p["V_S"], v.V_S_err)
        for m, f in zip(v.measurements, p["frames"]):
            assert abs(m.V_S - p["V_S"]) < 3.5 * m.V_S_err
            # μ̂_D vs A·mean(I): the noise averages over n pixels, σ = sqrt(σ²_KN/n); 4σ
            assert abs(m.mu_D - f["mu_D"]) < 4 * math.sqrt(m.sigma_KN2 / m.n_pixels)
            # eq. 58 vs the pixel mean of the exact eq. 28: they differ by A·(μ̂_D − μ_D)
            # (≈ 1e-4 DN²) and O(σ_K²) terms, far below 1e-3 relative
            assert m.sigma_N2 == pytest.approx(f["sigma2_N"], rel=1e-3)
            assert m.n_pixels == p["roi"][2] * p["roi"][3]


def test_level_independence_chi2(tmp_path):
    """χ² of the eq. 57 fit, pooled over patches and seeds, follows χ²(Σ dof)."""
    total, dof = 0.0, 0
    for seed in (21, 22, 23):
        out, truth, K, dark = _sim(tmp_path, seed)
        for v in _measure_all(out, truth, K, dark).values():
            total += v.chi2
            dof += v.dof
    # the pooled χ² (36 dof) is an honest test of level independence; reject only at Q < 1e-3
    assert 1e-3 < chi2_dist.sf(total, dof) < 1 - 1e-3, (total, dof)


def test_V_S_err_is_honest(tmp_path):
    """z = (V̂_S − V_S)/V_S_err over many independent frames has mean 0 and std 1."""
    z_level, z_fit = [], []
    for seed in range(8):
        out, truth, K, dark = _sim(tmp_path, 100 + seed)
        res = _measure_all(out, truth, K, dark)
        for p in truth["scene"]["patches"]:
            v = res[p["name"]]
            z_fit.append((v.V_S - p["V_S"]) / v.V_S_err)
            z_level += [(m.V_S - p["V_S"]) / m.V_S_err for m in v.measurements]
    for z in (np.array(z_level), np.array(z_fit)):
        n = z.size
        # sampling error of a std of n normal values ≈ 1/sqrt(2(n − 1)), of a mean 1/sqrt(n); 3σ
        assert abs(z.std(ddof=1) - 1.0) < 3 / math.sqrt(2 * (n - 1)), (n, z.std(ddof=1))
        assert abs(z.mean()) < 3 / math.sqrt(n), (n, z.mean())
    assert len(z_level) == 120 and len(z_fit) == 24


def test_noise_model_error_propagation(sim):
    """The noise-model term of V_S_err equals J C Jᵀ with J the finite-difference gradient of V̂_S
    with respect to (A, σ²_C), and a biased A moves V̂_S by J·ΔA."""
    out, truth, K, dark = sim
    p = truth["scene"]["patches"][0]
    frames = list(_patch_frames(out, p))
    A, c2 = truth["A"], truth["sigma_c2"]

    def fit(A_, c2_, cov=None):
        noise = {"A": A_, "sigma_c2": c2_, "cov": cov, "black_level_dn": 0.0}
        return scene_variation(frames, dark, K, noise)

    base = fit(A, c2)
    hA, hC = 1e-6, 1e-4
    J = np.array([(fit(A + hA, c2).V_S - base.V_S) / hA, (fit(A, c2 + hC).V_S - base.V_S) / hC])
    cov = np.array([[1e-8, -2e-7], [-2e-7, 1e-4]])  # typical scale of eq. 66 for such a PTC
    with_cov = fit(A, c2, cov)
    expect = math.sqrt(base.V_S_err ** 2 + J @ cov @ J)
    # GLS weights change slightly with the common term; 5 % agreement shows the propagation
    assert with_cov.V_S_err == pytest.approx(expect, rel=0.05)
    assert with_cov.V_S_err > base.V_S_err
    assert not any("covariance not given" in n for n in with_cov.notes)
    for m in with_cov.measurements:  # per level: same propagation through ∂y/∂(A, σ²_C)
        g = np.array(m.dy_dnoise) / m.mu_D ** 2
        assert m.V_S_err ** 2 == pytest.approx(m.var_y / m.mu_D ** 4 + g @ cov @ g, rel=1e-9)


def test_black_level(tmp_path):
    """With a black level b0 in the dark map, eq. 58 needs μ̂_D + D̄_D − b0 (no shot noise in b0)."""
    b0 = 20.0
    out, truth, K, dark = _sim(tmp_path, 5, black_level_dn=b0)
    assert truth["black_level_dn"] == b0
    p = truth["scene"]["patches"][2]
    right = scene_variation(_patch_frames(out, p), dark, K, _noise(truth))
    wrong = scene_variation(_patch_frames(out, p), dark, K, _noise(truth), black_level=0.0)
    for m, f in zip(right.measurements, p["frames"]):
        assert m.black_level == b0
        assert m.sigma_N2 == pytest.approx(f["sigma2_N"], rel=1e-3)
    for m, f in zip(wrong.measurements, p["frames"]):  # off by A·b0 = 0.068 DN², i.e. 4–5 %
        assert m.sigma_N2 - f["sigma2_N"] == pytest.approx(truth["A"] * b0, rel=0.05)
    assert abs(right.V_S - p["V_S"]) < 3 * right.V_S_err


# ---- the session entry -----------------------------------------------------------------------
def test_scene_variations_from_session(sim):
    out, truth, K, dark = sim
    session = open_session(out)
    dark_ref = SimpleNamespace(mean_map=dark)          # duck-typed DarkReference
    fixed = SimpleNamespace(K=K)                       # duck-typed FixedPattern
    res = scene_variations(session, dark_ref, fixed, _noise(truth))
    names = [p["name"] for p in truth["scene"]["patches"]]
    assert list(res) == names                          # the max-intensity frame is skipped
    direct = _measure_all(out, truth, K, dark)
    for name, v in res.items():
        assert isinstance(v, SceneVariation) and v.name == name
        assert [m.level for m in v.measurements] == [1, 2, 3, 4, 5]
        assert v.measurements[0].path.startswith(f"scene/{name}_L")
        assert v.V_S == pytest.approx(direct[name].V_S, rel=1e-12)
        d = json.loads(json.dumps(v.to_dict(), allow_nan=False))
        assert d["dof"] == 4 and len(d["measurements"]) == 5 and d["measurements"][0]["used"]


# ---- bad input -------------------------------------------------------------------------------
def test_bad_input(sim):
    out, truth, K, dark = sim
    p = truth["scene"]["patches"][0]
    frame = read_image(out / p["frames"][0]["path"])
    kw = dict(A=truth["A"], sigma_c2=truth["sigma_c2"])
    h, w = frame.shape
    with pytest.raises(CcdError, match="outside"):
        scene_measurement(frame, dark, K, roi=(w - 10, 0, 20, 10), **kw)
    with pytest.raises(CcdError, match="outside"):
        scene_measurement(frame, dark, K, roi=(-1, 0, 5, 5), **kw)
    with pytest.raises(CcdError, match="empty"):
        scene_measurement(frame, dark, K, roi=(0, 0, 0, 5), **kw)
    with pytest.raises(CcdError, match="shape"):
        scene_measurement(frame, dark[:-1], K, roi=p["roi"], **kw)
    with pytest.raises(CcdError, match="shape"):
        scene_measurement(frame, dark, K[:, :-1], roi=p["roi"], **kw)
    with pytest.raises(CcdError, match="colour"):
        scene_measurement(np.dstack([frame] * 3), dark, K, roi=p["roi"], **kw)
    bad_K = K.copy()
    bad_K[p["roi"][1] + 1, p["roi"][0] + 1] = 0.0
    with pytest.raises(CcdError, match="positive"):
        scene_measurement(frame, dark, bad_K, roi=p["roi"], **kw)
    with pytest.raises(CcdError, match="corrected mean"):  # a dark frame: no signal
        scene_measurement(np.rint(dark).astype(np.uint8), dark + 1.0, K, roi=p["roi"], **kw)
    with pytest.raises(CcdError, match="2x2"):
        scene_measurement(frame, dark, K, roi=p["roi"], noise_cov=np.eye(3), **kw)
    with pytest.raises(CcdError, match="sigma_c2"):
        scene_variation([frame], dark, K, {"A": 0.003})
    with pytest.raises(CcdError, match="no usable"):
        fit_scene_variation([])


def test_single_level_and_clipped(sim):
    out, truth, K, dark = sim
    p = truth["scene"]["patches"][1]
    one = scene_variation(list(_patch_frames(out, p))[:1], dark, K, _noise(truth))
    # one level: V_S is that level's, with its error; no goodness of fit
    assert one.dof == 0 and math.isnan(one.chi2) and math.isnan(one.Q)
    assert one.V_S == pytest.approx(one.measurements[0].V_S, rel=1e-12)
    assert one.V_S_err == pytest.approx(one.measurements[0].V_S_err, rel=1e-9)
    assert any("one level" in n for n in one.notes)
    assert json.loads(json.dumps(one.to_dict(), allow_nan=False))["Q"] is None
    # a frame with a saturated pixel in the ROI is measured but left out of the fit
    items = list(_patch_frames(out, p))
    hot = items[2][0].copy()
    hot[p["roi"][1] + 3, p["roi"][0] + 3] = 255
    items[2] = (hot, items[2][1])
    v = scene_variation(items, dark, K, _noise(truth), full_scale=255)
    assert v.used == (True, True, False, True, True) and v.dof == 3
    assert v.measurements[2].n_clipped == 1 and "clipped" in v.excluded[0]
    assert abs(v.V_S - p["V_S"]) < 3 * v.V_S_err


def test_calibration_error_terms(sim):
    """dark_var adds E[dark_var/K̂²] to the noise and K_var adds K_var·μ²_D (it would bias V_S)."""
    out, truth, K, dark = sim
    p = truth["scene"]["patches"][0]
    frame = read_image(out / p["frames"][-1]["path"])
    kw = dict(A=truth["A"], sigma_c2=truth["sigma_c2"], roi=p["roi"])
    m0 = scene_measurement(frame, dark, K, **kw)
    m1 = scene_measurement(frame, dark, K, dark_var=0.07, K_var=2e-6, **kw)
    assert m1.sigma_cal2 == pytest.approx(0.07 * m0.E_invK2 + 2e-6 * m0.mu_D ** 2, rel=1e-12)
    assert m1.V_S == pytest.approx(m0.V_S - m1.sigma_cal2 / m0.mu_D ** 2, rel=1e-9)
    assert m1.V_S_err > m0.V_S_err
    assert m0.V_S_err_population >= m0.V_S_err


# ---- variance budget (Fig. 4) ------------------------------------------------------------------
def test_variance_budget_shape_and_dominance(sim):
    out, truth, K, dark = sim
    fabric = _measure_all(out, truth, K, dark)["fabric"]
    mu = np.linspace(truth["dark_mean_dn"] + 1.0, 250.0, 60)
    b = variance_budget(mu, A=truth["A"], sigma_c2=truth["sigma_c2"],
                        dark_spatial_var=float(dark.var()), sigma_K2=truth["sigma_K"] ** 2,
                        V_S=fabric.V_S, dark_mean=truth["dark_mean_dn"])
    assert set(b.components) == set(BUDGET_COMPONENTS) == set(b.fractions)
    np.testing.assert_allclose(np.sum(list(b.fractions.values()), axis=0), 1.0, rtol=1e-12)
    assert np.all(np.diff(b.total) > 0)                # Fig. 4: total grows with μ
    dom = b.dominant()
    assert dom[0] == "sigma_C^2" and dom[-1] == "scene"  # as the paper's Fig. 4
    # functional forms: constant, constant, linear, quadratic, quadratic
    assert np.ptp(b.components["dark spatial"]) == 0 and np.ptp(b.components["sigma_C^2"]) == 0
    np.testing.assert_allclose(b.components["shot noise"], truth["A"] * mu, rtol=1e-12)
    sig = mu - truth["dark_mean_dn"]
    np.testing.assert_allclose(b.components["scene"], fabric.V_S * sig ** 2, rtol=1e-12)
    json.dumps(b.to_dict(), allow_nan=False)


def test_variance_budget_matches_a_simulated_frame(sim):
    """The budget's total equals the variance of a raw (uncorrected) ROI of the simulator."""
    out, truth, K, dark = sim
    p = truth["scene"]["patches"][2]
    x, y, w, h = p["roi"]
    sl = (slice(y, y + h), slice(x, x + w))
    for f in p["frames"]:
        raw = read_image(out / f["path"]).astype(np.float64)[sl]
        n = raw.size
        d, k = dark[sl], K[sl]
        b = variance_budget(raw.mean(), A=truth["A"], sigma_c2=truth["sigma_c2"],
                            dark_spatial_var=float(d.var(ddof=1)), sigma_K2=float(k.var(ddof=1)),
                            V_S=p["V_S"], dark_mean=float(d.mean()))
        total = float(b.total[0])
        # tolerance: the noise part of the sample variance (fixed maps + Gaussian noise:
        # (4·v_fixed·σ²_N + 2σ⁴_N)/(n − 1)) plus the realised cross-covariances of the three
        # fixed fields (dark, K·signal, scene; each pair ≈ 2·sqrt(v_a·v_b/n)); 4σ
        s2n = f["sigma2_N"]
        v_d = float(d.var())
        v_k = truth["sigma_K"] ** 2 * (f["mu_D"]) ** 2
        v_s = p["V_S"] * f["mu_D"] ** 2
        fixed = v_d + v_k + v_s
        sd = math.sqrt((4 * fixed * s2n + 2 * s2n ** 2) / (n - 1)
                       + 4 * (v_d * v_k + v_d * v_s + v_k * v_s) / n)
        assert abs(raw.var(ddof=1) - total) < 4 * sd, (f["level"], raw.var(ddof=1), total, sd)


def test_variance_budget_bad_input():
    kw = dict(A=0.0034, sigma_c2=1.1, dark_spatial_var=0.27, sigma_K2=1.4e-5, V_S=1e-3,
              dark_mean=10.7)
    with pytest.raises(CcdError, match="dark level"):
        variance_budget([5.0, 50.0], **kw)
    with pytest.raises(CcdError, match="V_S"):
        variance_budget([50.0], **{**kw, "V_S": -1e-5})
    with pytest.raises(CcdError, match="finite"):
        variance_budget([np.nan], **kw)
    b = variance_budget(100.0, **kw)                   # a scalar μ is accepted
    assert b.mu.shape == (1,) and b.total[0] > 0
