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
from ccdcore.io.frames import read_image
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


# ---------------------------------------------------------------------------------------------
# the camera model (ccdcore.simulate.camera): what makes a bracket behave like a real camera's

from ccdcore.simulate import camera  # noqa: E402
from ccdcore.simulate._common import round_sig  # noqa: E402

CODES = np.arange(256)


def test_srgb_knee_tone_is_monotone_with_toe_and_knee():
    tone = camera.SrgbKneeTone()                   # gamma 2.4, toe 0.01, knee 0.8, headroom 2
    g = np.array(tone.table())
    assert g[0] == 0.0 and g[255] == 1.0
    assert np.all(np.diff(g) > 0)
    # toe: g is linear in z up to the toe code (17): the slope of f is finite at black
    z_toe = int(tone.params()["toe_code"])
    assert z_toe == 17
    np.testing.assert_allclose(g[:z_toe + 1],
                               CODES[:z_toe + 1] / (255 * tone.slope * tone.headroom), rtol=1e-12)
    # above the toe the log-log slope d ln g / d ln z rises from 1 towards gamma = 2.4 (sRGB's
    # offset power law); over the mid-tones (51..204) g is roughly a gamma 2 curve
    slope = np.diff(np.log(g[18:205])) / np.diff(np.log(CODES[18:205]))
    assert np.all(np.diff(slope) > 0) and 1.0 < slope[0] < 1.1 and slope[-1] < 2.4
    assert 1.8 < math.log(g[204] / g[51]) / math.log(4) < 2.2
    # knee: above code 204 the codes cover far more exposure than the power law would give --
    # the shoulder folds `headroom` = 2 times the exposure into codes 204..255
    power = ((CODES / 255 + tone.alpha) / (1 + tone.alpha)) ** tone.gamma / tone.headroom
    np.testing.assert_allclose(g[18:205], power[18:205], rtol=1e-12)
    assert np.all(g[205:] > power[205:])
    assert power[255] == pytest.approx(0.5) and g[255] == 1.0
    dg = np.diff(g)
    assert dg[250] > 8 * dg[203]                    # highlights compressed: g steep at the top
    # sRGB's own constants come out of the construction (0.0030399 is where sRGB's 0.055 power
    # law and its 12.92 line meet with equal slopes; the standard rounds the break to 0.0031308)
    srgb = camera.SrgbKneeTone(2.4, 0.0030399, 0.8, 2.0)
    assert srgb.alpha == pytest.approx(0.055, abs=1e-5)
    assert srgb.slope == pytest.approx(12.92, abs=0.01)


@pytest.mark.parametrize("tone", [camera.SrgbKneeTone(), camera.SrgbKneeTone(2.2, 0.02, 0.85, 1.5),
                                  camera.GammaTone(1.2), camera.GammaTone(2.2)],
                         ids=["srgb-knee", "srgb-knee-2", "gamma-1.2", "gamma-2.2"])
def test_tone_inverts_exactly_on_the_codes(tone):
    g = np.array(tone.table())
    fz = tone.f(g)
    assert np.abs(fz - CODES).max() < 1e-9
    assert np.array_equal(np.rint(fz), CODES)
    half = CODES[:-1] + 0.5                          # and between the codes
    assert np.abs(tone.f(tone.g(half)) - half).max() < 1e-9
    # the noise-free pipeline reads every code back
    E = np.tile(g, (4, 1))
    shot = tsin.expose(E, 1.0, 0.0, np.random.default_rng(0), sigma_s=0.0, sigma_c1=0.0,
                       sigma_c2=0.0, tone=tone)
    assert np.array_equal(shot.z, np.tile(CODES, (4, 1)).astype(np.uint8))


def test_tone_f_is_the_formula_and_gamma_tone_is_the_protocol():
    v = np.linspace(0.0, 1.0, 10001)
    tone = camera.SrgbKneeTone()
    u = tone.headroom * v
    x = np.where(u < tone.toe, tone.slope * u,
                 (1 + tone.alpha) * np.power(u, 1 / tone.gamma) - tone.alpha)
    w = x - tone.knee
    ref = 255 * np.where(x <= tone.knee, x, tone.knee + w / (1 + w / tone.L))
    np.testing.assert_allclose(tone.f(v), ref, rtol=1e-13, atol=1e-12)
    assert tone.f(1.0) == pytest.approx(255.0, abs=1e-9) and tone.f(0.0) == 0.0
    gamma = camera.GammaTone(1.2)
    assert np.array_equal(gamma.f(v), tsin.response(v, 1.2))          # the same bits
    assert gamma.table() == tsin.response_table(1.2)


def _noise_free(**kw):
    return dict(sigma_s=0.0, sigma_c1=0.0, sigma_c2=0.0, **kw)


def test_exposure_errors_are_in_truth_and_in_the_frames(tmp_path):
    sigma = 0.05
    truth = simulate_preset("tsin01", tmp_path, seed=21, size=(16, 16), n_exposures=10, ratio=2.0,
                            t_max=1.0, n_stacks=5, exposure_error=sigma, **_noise_free())
    t = np.array(truth["t"])
    eps = np.array(truth["exposure_factor"])
    a = np.array(truth["a"])
    assert eps.shape == (5, 10) and a.shape == (5, 10)
    np.testing.assert_array_equal(a, [[round_sig(x) for x in row] for row in t * eps])
    assert [f["exposure_factor"] for f in truth["frames"]] == eps.ravel().tolist()
    assert truth["exposure_error"] == sigma
    # log factors ~ Normal(0, sigma): 50 draws, sample sd and mean within 99.9 % bounds
    ln = np.log(eps).ravel()
    lo, hi = (math.sqrt(stats.chi2.ppf(p, ln.size - 1) / (ln.size - 1)) for p in (0.0005, 0.9995))
    assert lo * sigma < ln.std(ddof=1) < hi * sigma
    assert abs(ln.mean()) < 3.3 * sigma / math.sqrt(ln.size)
    # the frames are imaged with the actual a_k, not the nominal t_k
    E = load_truth(tmp_path).map("E").astype(float)
    moved = 0
    for entry in truth["frames"]:
        z = read_image(tmp_path / entry["path"])
        actual = tsin.response(np.minimum(entry["a"] * E, 1.0))
        assert np.array_equal(z, np.rint(actual).astype(np.uint8))
        moved += int(np.count_nonzero(z != np.rint(tsin.response(np.minimum(entry["exposure"] * E,
                                                                               1.0)))))
    assert moved > 1000


def test_exposure_error_is_common_to_the_channels(tmp_path):
    truth = simulate_preset("tsin01", tmp_path, seed=8, size=(8, 8), layout="rgb",
                            white_balance=True, wb_sigma=0.03, offset_sigma=0.0,
                            exposure_error=0.03, black_level=0.002)
    t, eps = np.array(truth["t"]), np.array(truth["exposure_factor"][0])
    a, b = np.array(truth["a"][0]), np.array(truth["b"][0])
    w = a / (t * eps)[:, None]                      # the white-balance gains, per frame and channel
    assert a.shape == (8, 3) and 0.01 < w.std(ddof=1) < 0.06 and abs(w.mean() - 1) < 0.03
    np.testing.assert_array_equal(b, 0.002)         # the pedestal, in b_k


@pytest.mark.parametrize("options", [
    {"bayer": "rggb", "jpeg_quality": 90},
    {"jpeg_quality": 90},
    {"bayer": "rggb"},
], ids=["bayer+jpeg", "jpeg", "bayer"])
def test_camera_noise_is_spatially_correlated(tmp_path, options):
    """Residuals against the truth on a flat field: the protocol's are white, a demosaiced and/or
    JPEG-compressed camera's are correlated between neighbours (as in real brackets)."""
    E = np.full((64, 96, 3), 0.3, dtype=np.float32)

    def neighbour_correlation(root, truth):
        corr = []
        for entry in truth["frames"][2:7]:
            z = read_image(root / entry["path"]).astype(float)
            r = z - tsin.response(np.minimum(np.array(entry["a"]) * 0.3, 1.0))
            for c in range(3):
                x = r[1:-1, 1:-1, c]
                corr.append(np.corrcoef(x[:, :-1].ravel(), x[:, 1:].ravel())[0, 1])
                corr.append(np.corrcoef(x[:-1].ravel(), x[1:].ravel())[0, 1])
        return np.array(corr)

    plain = simulate_preset("tsin01", tmp_path / "plain", seed=5, size=(96, 64), layout="rgb",
                            radiance=E)
    cam = simulate_preset("tsin01", tmp_path / "cam", seed=5, size=(96, 64), layout="rgb",
                          radiance=E, **options)
    rho_plain = neighbour_correlation(tmp_path / "plain", plain)
    rho_cam = neighbour_correlation(tmp_path / "cam", cam)
    n = 62 * 93
    assert np.all(np.abs(rho_plain) < 4.5 / math.sqrt(n))        # white: |rho| < 0.06
    assert rho_cam.min() > 0.25 and rho_cam.mean() > 0.3


def test_real_camera_residuals_are_correlated_in_flat_regions(tmp_path):
    truth = simulate_preset("tsin01", tmp_path, seed=2, size=(128, 96), camera="real")
    Ee = load_truth(tmp_path).map(truth["radiance_map"]).astype(float)
    tone = camera.make_tone("srgb-knee")
    # inside the patches (vignetting varies the irradiance by < 5 % over 5 x 5 pixels)
    hi, lo = ndimage.maximum_filter(Ee, (5, 5, 1)), ndimage.minimum_filter(Ee, (5, 5, 1))
    flat = np.all(hi < 1.05 * lo, axis=2)
    rho, n = [], 0
    for entry in truth["frames"][5:]:
        z = read_image(tmp_path / entry["path"]).astype(float)
        mu = tone.f(np.array(entry["a"]) * Ee + np.array(entry["b"]))
        r = (z - mu)[..., 1]
        ok = flat & (mu[..., 1] > 20) & (mu[..., 1] < 230)
        pairs = ok[:, :-1] & ok[:, 1:]
        if pairs.sum() >= 300:
            rho.append(np.corrcoef(r[:, :-1][pairs], r[:, 1:][pairs])[0, 1])
            n += int(pairs.sum())
    assert len(rho) >= 4 and n > 3000
    assert min(rho) > 0.2 and np.mean(rho) > 0.3


def test_structured_scene_has_regions_edges_and_a_wide_dynamic_range():
    for seed in (0, 1, 2):
        E, desc = camera.structured_scene(np.random.default_rng([seed, 1]), (128, 192, 3))
        assert E.shape == (128, 192, 3) and np.all(E > 0)
        g = E[..., 1]
        p1, p50, p99 = np.percentile(g, [1, 50, 99])
        assert E.max() / p1 > 1e5                 # more than five decades
        assert p99 / p1 > 30                      # without the lights: more than 1.5 decades
        assert E.max() >= 1000                    # saturates a frame with a = 1/512 .. 1
        assert 0.01 < p50 < 0.2                   # most pixels dark: median a_max E < 0.2
        flat = np.mean(g[:, 1:] == g[:, :-1])     # piecewise-constant patches
        edges = np.mean(np.abs(np.log(g[:, 1:] / g[:, :-1])) > 1.0)
        assert flat > 0.15 and edges > 0.005
        assert len(desc["patches"]) >= 4 and len(desc["lights"]) >= 3
        assert desc["lights"][0]["radiance"] >= 1000
    E_mono, _ = camera.structured_scene(np.random.default_rng([0, 1]), (40, 48))
    assert E_mono.shape == (40, 48)


def test_vignetting_is_a_cos4_falloff_of_E(tmp_path):
    V = camera.vignetting_map((64, 96), 0.35)
    assert V.max() == pytest.approx(1.0, abs=1e-3) and V[0, 0] == pytest.approx(1 / 1.35 ** 2)
    assert V[0, 0] == V[-1, -1] == V[0, -1] == V[-1, 0]
    kw = dict(seed=4, size=(96, 64), layout="rgb", scene="structured")
    simulate_preset("tsin01", tmp_path / "off", **kw)
    t_on = simulate_preset("tsin01", tmp_path / "on", vignetting=0.35, **kw)
    E_off = load_truth(tmp_path / "off").map("E").astype(float)
    E_on = load_truth(tmp_path / "on").map("E").astype(float)
    Vmap = load_truth(tmp_path / "on").map("vignetting").astype(float)
    np.testing.assert_allclose(Vmap, V, rtol=1e-7)
    np.testing.assert_allclose(E_on, E_off * V[..., None], rtol=2e-7)
    assert t_on["vignetting"]["strength"] == 0.35
    assert t_on["vignetting"]["map"] == "truth/vignetting.exr"


def test_jpeg_model():
    C = camera.dct_matrix()
    np.testing.assert_allclose(C @ C.T, np.eye(8), atol=1e-15)
    assert camera._cos16() == pytest.approx([math.cos(k * math.pi / 16) for k in range(9)],
                                            abs=2e-16)
    from scipy import fft
    X = np.random.default_rng(0).standard_normal((8, 8))
    np.testing.assert_allclose(C @ X @ C.T, fft.dctn(X, norm="ortho"), atol=1e-14)
    assert np.array_equal(camera.quant_table(50), camera._LUMA_Q)
    assert np.all(camera.quant_table(100) == 1) and camera.quant_table(10).max() == 255
    flat = np.full((24, 40, 3), 77, np.uint8)
    assert np.array_equal(camera.jpeg_roundtrip(flat, 75), flat)
    rng = np.random.default_rng(1)
    smooth = ndimage.gaussian_filter(rng.random((37, 53, 3)) * 255, (4, 4, 0))
    noisy = np.clip(np.rint(smooth + rng.normal(0, 3, smooth.shape)), 0, 255).astype(np.uint8)
    err = {q: np.abs(camera.jpeg_roundtrip(noisy, q).astype(int) - noisy).mean()
           for q in (50, 90, 100)}
    assert err[100] < err[90] < err[50] < 6                  # lossy, more so at lower quality
    mono = noisy[..., 0]                                     # luminance only: no 4:2:0 loss
    err_mono = {q: np.abs(camera.jpeg_roundtrip(mono, q).astype(int) - mono).mean()
                for q in (90, 100)}
    assert err_mono[100] < 0.5 < err_mono[90] < 3
    assert camera.jpeg_roundtrip(mono, 90).shape == (37, 53)


def test_jpeg_model_is_close_to_libjpeg(tmp_path):
    """The model against a real JPEG (libjpeg through OpenImageIO, quality 90, 4:2:0): the
    differences are a fraction of the compression error itself."""
    from ccdcore.io.frames import write_image

    rng = np.random.default_rng(3)
    smooth = ndimage.gaussian_filter(rng.random((64, 96, 3)) * 255, (3, 3, 0))
    z = np.clip(np.rint(smooth + rng.normal(0, 3, smooth.shape)), 0, 255).astype(np.uint8)
    write_image(tmp_path / "x.jpg", z, attributes={"Compression": "jpeg:90"})   # OIIO wheels write JPEG
    real = read_image(tmp_path / "x.jpg").astype(int)
    ours = camera.jpeg_roundtrip(z, 90).astype(int)
    compression = np.abs(real - z).mean()
    assert compression > 1.5
    assert np.abs(ours - real).mean() < 0.4 * compression and np.abs(ours - real).max() <= 8


def test_real_camera_bundle_preset_and_determinism(tmp_path):
    size = (48, 32)
    t1 = simulate_preset("tsin01-camera", tmp_path / "a", seed=3, size=size)
    simulate_preset("tsin01", tmp_path / "b", seed=3, size=size, camera="real")
    simulate_preset("tsin01-camera", tmp_path / "c", seed=3, size=size)
    simulate_preset("tsin01-camera", tmp_path / "d", seed=4, size=size)
    a, b, c, d = (_all_bytes(tmp_path / x) for x in "abcd")
    assert a == b == c
    assert a.keys() == d.keys() and a["bracket/s0_k05.tif"] != d["bracket/s0_k05.tif"]
    assert len(a) == 2 + 3 + 10             # manifest, truth; E, E_effective, vignetting; frames
    manifest, on_disk = read_session(tmp_path / "a")
    assert on_disk == t1
    assert manifest["camera"]["layout"] == "rgb"
    exposures = np.array([f["exposure"] for f in manifest["frames"]])
    assert exposures.size == 10 and np.all(exposures[1:] / exposures[:-1] == 2.0)
    assert exposures[-1] == 1.0
    model = t1["camera_model"]
    assert model["bundle"] == "real"
    opts = model["options"]
    for key, value in camera.CAMERAS["real"].items():
        assert opts[key] == value, key
    assert t1["tone"]["name"] == "srgb-knee" and t1["gamma"] is None
    np.testing.assert_allclose(t1["g"], camera.SrgbKneeTone().table(), rtol=1e-15)
    assert t1["scene"]["kind"] == "structured" and t1["jpeg"]["quality"] == 90
    assert t1["sharpen"] == {"amount": 0.5, "sigma": camera.SHARPEN_SIGMA}
    assert np.array(t1["a"]).shape == (1, 10, 3) and t1["bayer"] == "rggb"
    # an explicit option beats the bundle's
    t2 = simulate_preset("tsin01", tmp_path / "e", seed=3, size=size, camera="real",
                         jpeg_quality=None)
    assert t2["jpeg"] is None and t2["camera_model"]["options"]["jpeg_quality"] is None


def test_real_camera_default_size_and_saturating_lights(tmp_path):
    truth = simulate_preset("tsin01", tmp_path, seed=1, camera="real")
    assert truth["size"] == list(camera.DEFAULT_SIZE)
    first = read_image(tmp_path / truth["frames"][0]["path"])
    last = read_image(tmp_path / truth["frames"][-1]["path"])
    assert np.any(first == 255)                    # the brightest light, even at 1/512
    assert np.median(first) < 10                   # a night scene: the short frames are dark
    assert 40 < np.median(last) < 200


def test_protocol_options_leave_the_protocol_unchanged(tmp_path):
    kw = dict(seed=12, size=(16, 12), bayer="grbg", white_balance=True)
    simulate_preset("tsin01", tmp_path / "a", **kw)
    t = simulate_preset("tsin01", tmp_path / "b", tone="gamma", scene="uniform", vignetting=0,
                        exposure_error=0.0, black_level=0.0, sharpen=0, jpeg_quality=None,
                        camera=None, **kw)
    assert _all_bytes(tmp_path / "a") == _all_bytes(tmp_path / "b")
    assert not {"camera_model", "tone", "scene", "exposure_factor", "jpeg"} & set(t)


@pytest.mark.parametrize("options", [
    {"tone": "film"}, {"scene": "city"}, {"jpeg_quality": 0}, {"jpeg_quality": 101},
    {"jpeg_quality": 90.5}, {"vignetting": -0.1}, {"exposure_error": -0.01},
    {"camera": "phone"}, {"tone": "srgb-knee", "knee": 0.05},
    {"tone": "srgb-knee", "headroom": 1.0},
    {"sharpen": -1.0}, {"black_level": -0.001},
])
def test_bad_camera_options_raise(tmp_path, options):
    with pytest.raises(CcdError):
        simulate_preset("tsin01", tmp_path, seed=0, size=(16, 16), **options)
