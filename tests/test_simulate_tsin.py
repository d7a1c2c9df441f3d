"""Tests of the tsin01 simulator (Tsin, Ramesh & Kanade 2001, eq. 3 and sec. 4.1).

The statistical checks compare simulated digital numbers with the model's exact expectation:
for a pixel with noise-free signal v0 = aE + b, v ~ Normal(v0, sigma_s^2 aE + sigma_c1^2), and
E[z] = E[f(v)] (computed by Gauss-Hermite quadrature, so the curvature of f is accounted for),
Var[z] = Var[f(v)] + sigma_c2^2 + 1/12 (rounding).  Tolerances are a few standard errors.
"""
from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage, stats

from ccdcore import channels
from ccdcore.errors import CcdError
from ccdcore.io import read_image
from ccdcore.simulate import load_truth, tsin
from ccdcore.simulate import simulate as simulate_preset

NODES, WEIGHTS = np.polynomial.hermite_e.hermegauss(48)
WEIGHTS = WEIGHTS / math.sqrt(2.0 * math.pi)
ROUNDING_VAR = 1.0 / 12.0


def model_moments(v0, var_v, gamma=1.2, sigma_c2=1.0):
    """Exact mean and variance of z (before clipping) for v ~ Normal(v0, var_v)."""
    v0 = np.asarray(v0, float)[..., None]
    sd = np.sqrt(np.asarray(var_v, float))[..., None]
    fz = tsin.response(v0 + sd * NODES, gamma)
    mean = (fz * WEIGHTS).sum(-1)
    var = (fz ** 2 * WEIGHTS).sum(-1) - mean ** 2 + sigma_c2 ** 2 + ROUNDING_VAR
    return mean, var


def check_frame(z, v0, var_v, lo=20.0, hi=230.0, min_n=200):
    """z-score of the mean residual and normalised variance over pixels with E[z] in (lo, hi)."""
    mean, var = model_moments(v0, var_v)
    sel = (mean > lo) & (mean < hi)
    n = int(sel.sum())
    assert n >= min_n
    r = z[sel].astype(float) - mean[sel]
    zscore = r.sum() / math.sqrt(var[sel].sum())
    chi = float(np.mean(r ** 2 / var[sel]))
    return zscore, chi, n


def read_session(root: Path):
    manifest = tomllib.loads((root / "session.toml").read_text())
    return manifest, load_truth(root).values


# ---------------------------------------------------------------------------------------------
# the pipeline function


def test_expose_mean_and_variance_follow_eq3():
    rng = np.random.default_rng(11)
    levels = np.linspace(0.03, 0.95, 12)
    n = 3000
    E = np.repeat(levels[:, None], n, axis=1)
    a, b = 0.8, 0.02
    shot = tsin.expose(E, a, b, rng)
    v0 = a * levels + b
    mean, var = model_moments(v0, 0.015 ** 2 * a * levels + 0.01 ** 2)
    z = shot.z.astype(float)
    for i in range(levels.size):
        if not 20 < mean[i] < 230:
            continue
        # mean: 4.5 standard errors; variance: SE of a sample variance ~ var*sqrt(2/(n-1))
        assert abs(z[i].mean() - mean[i]) < 4.5 * math.sqrt(var[i] / n)
        assert abs(z[i].var(ddof=1) - var[i]) < 5 * var[i] * math.sqrt(2.0 / (n - 1))


def test_shot_noise_is_linear_in_the_signal():
    # Var(v) = sigma_s^2 aE + sigma_c1^2 (module notes): with sigma_c1 = 0 the variance of the
    # signal doubles when aE doubles (a^2 E^2 would quadruple it)
    rng = np.random.default_rng(5)
    n = 20000
    E = np.concatenate([np.full((1, n), 0.2), np.full((1, n), 0.4)])
    shot = tsin.expose(E, 1.0, 0.0, rng, sigma_s=0.05, sigma_c1=0.0)
    ratio = shot.v[1].var() / shot.v[0].var()
    # SE of a variance ratio ~ ratio*sqrt(4/n) = 0.028; allow 5 SE
    assert abs(ratio - 2.0) < 5 * 2.0 * math.sqrt(4.0 / n)
    assert abs(shot.v[0].var() - 0.05 ** 2 * 0.2) < 5 * 0.05 ** 2 * 0.2 * math.sqrt(2.0 / n)


def test_full_well_reads_255():
    rng = np.random.default_rng(2)
    E = np.full((20, 20), 0.9)
    shot = tsin.expose(E, 1.2, 0.0, rng)          # aE = 1.08, 4.5 sigma above full well
    assert np.all(shot.z[shot.v >= 1.0] == 255)
    assert np.mean(shot.z == 255) > 0.99
    dark = tsin.expose(np.zeros((20, 20)), 1.0, 0.0, rng, sigma_c1=0.0)
    assert dark.z.min() == 0 and dark.z.max() < 10  # clipped at 0, N_c2 = 1 DN above it


def test_exposure_times_and_response():
    t = tsin.exposure_times(8, math.sqrt(2.0), math.sqrt(2.0))
    np.testing.assert_allclose(t[1:] / t[:-1], math.sqrt(2.0), rtol=1e-11)
    assert t[0] == 0.125 and t[6] == 1.0
    z = np.arange(256)
    g = tsin.inverse_response(z)
    np.testing.assert_allclose(tsin.response(g), z, atol=1e-9)   # f = g^-1
    assert g[0] == 0.0 and g[255] == 1.0


# ---------------------------------------------------------------------------------------------
# the written session


@pytest.fixture(scope="module")
def mono_session(tmp_path_factory):
    root = tmp_path_factory.mktemp("tsin_mono")
    truth = simulate_preset("tsin01", root, seed=4, size=(64, 48))
    return root, truth


def test_manifest_and_truth_keys(mono_session):
    root, truth = mono_session
    manifest, on_disk = read_session(root)
    assert on_disk == truth
    assert manifest["schema"] == 1
    assert manifest["camera"] == {"name": "tsin01 simulated camera", "bits": 8, "layout": "mono"}
    frames = manifest["frames"]
    assert len(frames) == 8
    assert all(f["role"] == "bracket" and f["stack"] == 0 for f in frames)
    exposures = np.array([f["exposure"] for f in frames])
    np.testing.assert_allclose(exposures[1:] / exposures[:-1], math.sqrt(2.0), rtol=1e-11)
    for key in ("g", "f", "gamma", "a", "b", "t", "sigma_s", "sigma_c1", "sigma_c2",
                "shot_noise", "noise_model", "maps", "frames", "quantisation"):
        assert key in truth
    assert len(truth["g"]) == 256
    np.testing.assert_allclose(truth["g"], (np.arange(256) / 255.0) ** 1.2, rtol=1e-15)
    np.testing.assert_array_equal(truth["t"], exposures)
    np.testing.assert_array_equal(truth["a"][0], exposures)        # no white balance
    assert truth["b"] == [[0.0] * 8]
    assert (truth["sigma_s"], truth["sigma_c1"], truth["sigma_c2"]) == (0.015, 0.01, 1.0)
    assert "sigma_s^2 * a_k * E" in truth["shot_noise"]
    assert truth["maps"]["E"] == "truth/E.exr"


def test_radiance_is_uniform_on_unit_interval(mono_session):
    root, truth = mono_session
    E = load_truth(root).map("E")
    assert E.shape == (48, 64) and E.dtype == np.float32
    assert E.min() >= 0.0 and E.max() <= 1.0
    assert stats.kstest(E.ravel(), "uniform").pvalue > 0.001


def test_bracket_frames_follow_the_model(mono_session):
    root, truth = mono_session
    E = load_truth(root).map("E").astype(float)
    for k, entry in enumerate(truth["frames"]):
        z = read_image(root / entry["path"])
        assert z.dtype == np.uint8 and z.shape == (48, 64)
        a, b = entry["a"], entry["b"]
        zscore, chi, n = check_frame(z, a * E + b, 0.015 ** 2 * a * E + 0.01 ** 2)
        assert abs(zscore) < 4.5, (k, zscore)
        assert abs(chi - 1.0) < 5 * math.sqrt(2.0 / n), (k, chi)   # var of mean(chi2_1)/n


def test_bracket_spans_dark_to_saturated(mono_session):
    root, truth = mono_session
    E = load_truth(root).map("E").astype(float)
    first = read_image(root / truth["frames"][0]["path"])
    last = read_image(root / truth["frames"][-1]["path"])
    a_last = truth["a"][0][-1]
    assert first.max() < 80 and not np.any(first == 255)
    sure = a_last * E > 1.1                  # 5 sigma above full well
    assert sure.sum() > 100 and np.all(last[sure] == 255)
    assert not np.any(last[a_last * E < 0.85] == 255)   # 8 sigma below full scale
    assert abs(np.mean(last == 255) - (1 - 1 / a_last)) < 0.05


def test_colour_white_balance_session(tmp_path):
    truth = simulate_preset("tsin01", tmp_path, seed=9, size=(32, 32), layout="rgb",
                            white_balance=True)
    manifest, _ = read_session(tmp_path)
    assert manifest["camera"]["layout"] == "rgb"
    E = load_truth(tmp_path).map("E").astype(float)
    assert E.shape == (32, 32, 3)
    corr = np.corrcoef(E.reshape(-1, 3).T)
    assert np.all(np.abs(corr[np.triu_indices(3, 1)]) < 4 / math.sqrt(32 * 32))
    t = np.array(truth["t"])
    a, b = np.array(truth["a"][0]), np.array(truth["b"][0])
    assert a.shape == (8, 3) and b.shape == (8, 3)
    w = a / t[:, None]
    # 24 draws of Normal(1, 0.05): the sample sd lies in [0.56, 1.5] x 0.05 with prob > 0.999
    assert 0.028 < w.std(ddof=1) < 0.075 and abs(w.mean() - 1) < 4 * 0.05 / math.sqrt(24)
    assert np.all(b[0] == 0.0) and np.any(b[1:] != 0.0)
    for k, entry in enumerate(truth["frames"]):
        z = read_image(tmp_path / entry["path"])
        assert z.shape == (32, 32, 3)
        ak, bk = np.array(entry["a"]), np.array(entry["b"])
        zscore, chi, n = check_frame(z, ak * E + bk, 0.015 ** 2 * ak * E + 0.01 ** 2, min_n=100)
        assert abs(zscore) < 4.5 and abs(chi - 1.0) < 5 * math.sqrt(2.0 / n)


def _interpolated_variance(var_site, pattern):
    """Variance of each bilinearly interpolated value, from per-site variances."""
    out = np.empty(var_site.shape + (3,))
    kg = np.array([[0, 0.25, 0], [0.25, 1, 0.25], [0, 0.25, 0]]) ** 2
    krb = np.array([[0.25, 0.5, 0.25], [0.5, 1, 0.5], [0.25, 0.5, 0.25]]) ** 2
    for i, (m, k) in enumerate(zip(channels.channel_masks(var_site.shape, pattern), (krb, kg, krb))):
        out[..., i] = ndimage.convolve(np.where(m, var_site, 0.0), k, mode="mirror")
        out[..., i][m] = var_site[m]
    return out


def test_bayer_session_adds_noise_per_site_then_interpolates(tmp_path):
    truth = simulate_preset("tsin01", tmp_path, seed=3, size=(64, 64), bayer="rggb")
    assert truth["layout"] == "rgb" and truth["bayer"] == "rggb"
    assert truth["radiance_map"] == "E_effective"
    E = load_truth(tmp_path).map("E").astype(float)
    Ee = load_truth(tmp_path).map(truth["radiance_map"]).astype(float)      # E_effective
    np.testing.assert_allclose(Ee, channels.demosaic_bilinear(channels.mosaic(E, "rggb"), "rggb"),
                               rtol=1e-6)
    green = channels.channel_masks((64, 64), "rggb")[1]
    inner = np.zeros((64, 64), bool)
    inner[1:-1, 1:-1] = True                  # mirror borders double a weight: leave them out
    chis = {"sampled": [], "interpolated": []}
    for entry in truth["frames"][2:6]:
        z = read_image(tmp_path / entry["path"])
        assert entry["a"] == [entry["exposure"]] * 3      # no white balance: a = t per channel
        a = entry["exposure"]
        var_site = 0.015 ** 2 * a * channels.mosaic(E, "rggb") + 0.01 ** 2
        var_v = _interpolated_variance(var_site, "rggb")
        zscore, chi, n = check_frame(z[inner], a * Ee[inner], var_v[inner], min_n=100)
        assert abs(zscore) < 4.5 and abs(chi - 1.0) < 5 * math.sqrt(2.0 / n)
        # green noise at red/blue sites is the mean of 4 sites: about 1/4 of the variance
        mean, var = model_moments(a * Ee[..., 1], var_v[..., 1])
        for name, m in (("sampled", green & inner), ("interpolated", ~green & inner)):
            sel = m & (mean > 20) & (mean < 230)
            chis[name].append(np.mean((z[..., 1][sel] - mean[sel]) ** 2 / var[sel]))
    # the model with per-site noise fits both kinds of sites (mean chi^2 ~ 1, 4 frames x ~1000 px)
    assert abs(np.mean(chis["sampled"]) - 1) < 0.1
    assert abs(np.mean(chis["interpolated"]) - 1) < 0.1


def test_blooming_around_a_saturated_spot(tmp_path):
    E = np.full((32, 32), 0.3, dtype=np.float32)
    E[14:16, 20:22] = 1.0                      # saturates at a >= 1 only
    kw = dict(seed=6, size=(32, 32), radiance=E)
    t_on = simulate_preset("tsin01", tmp_path / "on", blooming=True, **kw)
    simulate_preset("tsin01", tmp_path / "off", blooming=False, **kw)
    masks = t_on["blooming"]["masks"][0]
    assert len(masks) == 8 and t_on["blooming"]["radius"] == 3
    spot = np.zeros((32, 32), bool)
    spot[14:16, 20:22] = True
    ring = ndimage.binary_dilation(spot, structure=tsin.bloom_kernel(3)) & ~spot
    for k, entry in enumerate(t_on["frames"]):
        labels = read_image(tmp_path / "on" / masks[k])
        z_on = read_image(tmp_path / "on" / entry["path"]).astype(int)
        z_off = read_image(tmp_path / "off" / entry["path"]).astype(int)
        assert labels.dtype == np.uint8
        assert np.all(z_on >= z_off)              # same noise, extra charge only
        assert not np.any((z_on != z_off) & (labels == 0))
        if t_on["a"][0][k] * 1.0 > 1.1:           # the spot is surely saturated
            assert np.all(labels[spot] == 2) and np.all(labels[ring] == 1)
            assert not np.any(labels[~(spot | ring)])
            assert np.all(z_on[spot] == 255)
            # spill: 4 sites x (a - 1) / 28 sites; the ring gains charge, visibly in DN
            diff = (z_on - z_off)[ring]
            assert diff.mean() > 3 * diff.std(ddof=1) / math.sqrt(diff.size)
        elif t_on["a"][0][k] < 0.9:
            assert not np.any(labels)
            assert np.array_equal(z_on, z_off)


def test_several_stacks(tmp_path):
    truth = simulate_preset("tsin01", tmp_path, seed=1, size=(16, 16), n_stacks=2)
    manifest, _ = read_session(tmp_path)
    stacks = [f["stack"] for f in manifest["frames"]]
    assert stacks == [0] * 8 + [1] * 8
    z0 = read_image(tmp_path / truth["frames"][4]["path"])
    z1 = read_image(tmp_path / truth["frames"][12]["path"])
    assert not np.array_equal(z0, z1)              # new noise, same scene
    assert abs(z0.astype(float).mean() - z1.astype(float).mean()) < 2.0


def _all_bytes(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_same_bytes(tmp_path):
    kw = dict(seed=12, size=(16, 12), bayer="grbg", blooming=True, white_balance=True)
    simulate_preset("tsin01", tmp_path / "a", **kw)
    simulate_preset("tsin01", tmp_path / "b", **kw)
    simulate_preset("tsin01", tmp_path / "c", **{**kw, "seed": 13})
    a, b, c = (_all_bytes(tmp_path / x) for x in "abc")
    assert len(a) == 1 + 1 + 2 + 8 + 8          # manifest, truth, 2 maps, 8 frames, 8 masks
    assert a == b
    assert a.keys() == c.keys() and a["bracket/s0_k03.tif"] != c["bracket/s0_k03.tif"]


@pytest.mark.parametrize("options", [
    {"layout": "cmyk"}, {"bayer": "rgbx"}, {"n_stacks": 0}, {"frobnicate": 1},
    {"sigma_s": -1.0}, {"ratio": 0.5}, {"radiance": np.zeros((3, 3))},
])
def test_bad_options_raise(tmp_path, options):
    with pytest.raises(CcdError):
        simulate_preset("tsin01", tmp_path, seed=0, size=(16, 16), **options)


def test_bayer_needs_even_size(tmp_path):
    with pytest.raises(CcdError):
        simulate_preset("tsin01", tmp_path, seed=0, size=(17, 16), bayer="rggb")
