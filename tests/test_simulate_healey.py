"""The healey94 simulator and the sensor model agree with the model of Healey & Kondepudy (1994).

Tolerances are 4 standard errors of the statistic being compared (derived in each test); with the
fixed seeds the tests are deterministic, and a wrong model (gain, noise term, map) moves the
statistic by many standard errors.
"""
from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from ccdcore.errors import CcdError
from ccdcore.io.frames import read_image
from ccdcore.session import open_session
from ccdcore.simulate import load_truth, simulate
from ccdcore.simulate.sensor import SensorModel, child_rng

SMALL = dict(size=(64, 48), n_dark=8, levels=5, n1=3, n2=2, scene_levels=(0.3, 0.7))


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("healey")
    truth = simulate("healey94", out, seed=11, saturate_level=True, **SMALL)
    return out, truth


def _manifest(root: Path) -> dict:
    return tomllib.loads((root / "session.toml").read_text())


def _frames(root: Path, **match) -> list[dict]:
    return [f for f in _manifest(root)["frames"] if all(f.get(k) == v for k, v in match.items())]


def test_registry_returns_required_truth(session):
    root, truth = session
    for key in ("A", "sigma_c2", "read_noise_e", "bits", "black_level_dn", "dark_mean_dn",
                "sigma_K", "ptc", "n1", "n2", "s", "scene", "K_map", "dark_map", "maps"):
        assert key in truth, key
    assert truth["bits"] == 8 and truth["A"] == pytest.approx(0.0034)
    assert truth["sigma_c2"] == pytest.approx(0.0034 ** 2 * 297.0 ** 2 + 1 / 12)  # eq. 27
    assert (root / truth["K_map"]).is_file() and (root / truth["dark_map"]).is_file()
    assert truth["maps"] == {"K": "truth/K.exr", "dark": "truth/dark.exr"}
    assert load_truth(root).values == truth
    man = _manifest(root)
    assert man["camera"] == {"name": "XC-77-like simulated CCD", "bits": 8, "layout": "mono",
                             "black_level": 0.0}
    roles = [f["role"] for f in man["frames"]]
    assert roles.count("dark") == 8
    assert roles.count("ptc") == 2 * 6          # 5 levels + the saturated one, pairs
    assert roles.count("fixed_pattern") == 3 * 2
    assert roles.count("scene") == 3 * 2 + 1    # 3 patches x 2 levels + max intensity
    assert all(f["exposure"] == pytest.approx(0.033) for f in man["frames"])
    assert all((root / f["path"]).is_file() for f in man["frames"])
    assert sorted({f["config"] for f in man["frames"] if f["role"] == "fixed_pattern"}) == [1, 2, 3]


def test_ptc_pairs_match_model(session):
    root, truth = session
    for lv in truth["ptc"]:
        if lv["saturated"]:
            continue
        d1, d2 = (read_image(root / p).astype(float) for p in lv["frames"][:2])
        M = d1.size
        mu, s2 = lv["mu"], lv["sigma2_N"]
        # eq. 37: the pixel mean of (D1+D2)/2 has variance sigma2_N / (2M) (K and I are fixed)
        assert abs(0.5 * (d1.mean() + d2.mean()) - mu) < 4 * np.sqrt(s2 / (2 * M))
        # eq. 38: var(D1-D2)/2 estimates sigma2_N with std sqrt(2/(M-1)) sigma2_N (eq. 39)
        s2_hat = np.var(d1 - d2, ddof=1) / 2
        assert abs(s2_hat - s2) < 4 * np.sqrt(2 / (M - 1)) * s2
        # eq. 41 holds exactly in the truth
        assert s2 == pytest.approx(truth["A"] * (mu - truth["black_level_dn"]) + truth["sigma_c2"])
    mus = [lv["mu"] for lv in truth["ptc"] if not lv["saturated"]]
    assert mus[0] < 0.08 * 255 and mus[-1] > 0.85 * 255      # covers ~5%..90% of the range


def test_saturated_level_clips(session):
    root, truth = session
    sat = [lv for lv in truth["ptc"] if lv["saturated"]]
    assert len(sat) == 1
    d = read_image(root / sat[0]["frames"][0])
    assert d.dtype == np.uint8 and d.max() == 255
    assert np.mean(d == 255) == pytest.approx(sat[0]["clipped_fraction"], abs=0.01)
    assert sat[0]["clipped_fraction"] > 0.99


def test_K_map_statistics(session):
    root, truth = session
    K = load_truth(root).map("K_map").astype(float)
    M, sK = K.size, truth["sigma_K"]
    assert K.shape == (48, 64)
    assert abs(K.mean() - 1.0) < 4 * sK / np.sqrt(M)               # SE of a mean
    assert abs(K.std(ddof=1) - sK) < 4 * sK / np.sqrt(2 * (M - 1))  # SE of a Gaussian std
    assert K.std(ddof=1) == pytest.approx(truth["K_std"], rel=1e-5)


def test_dark_frames_mean_and_temporal_variance(session):
    root, truth = session
    darks = np.stack([read_image(root / f["path"]).astype(float) for f in _frames(root, role="dark")])
    s, M = darks.shape[0], darks[0].size
    s2 = truth["dark_sigma2_dn"]   # A^2 E_DC + sigma_c2 (eqs. 26-28 with I = 0)
    assert abs(darks.mean() - truth["dark_mean_dn"]) < 4 * np.sqrt(s2 / (s * M))
    v = darks.var(axis=0, ddof=1).mean()   # per-pixel temporal variance, pixel averaged
    assert abs(v - s2) < 4 * np.sqrt(2 / ((s - 1) * M)) * s2
    # the dark reference (sec. V-A) differs from the true dark map by noise of variance s2/s only
    dark_map = load_truth(root).map("dark_map").astype(float)
    resid = darks.mean(axis=0) - dark_map
    assert abs(resid.var(ddof=1) - s2 / s) < 4 * np.sqrt(2 / (M - 1)) * s2 / s
    # the true dark map has the paper's spatial spread (sec. VII-A: 10.74 DN, std 0.555 DN)
    assert truth["dark_mean_dn"] == pytest.approx(10.7, abs=0.1)
    assert 0.4 < truth["dark_std_dn"] < 0.65


def test_fixed_pattern_configurations(session):
    root, truth = session
    fp = truth["fixed_pattern"]
    means = []
    for c in range(1, fp["n1"] + 1):
        fr = [read_image(root / f["path"]).astype(float) for f in _frames(root, config=c)]
        assert len(fr) == fp["n2"]
        avg = np.mean(fr, axis=0)
        # averaged frame mean: SE sqrt(sigma2_N / (n2 M)), sigma2_N = A(mu - black) + sigma_c2
        s2 = truth["A"] * fp["mean_dn"][c - 1] + truth["sigma_c2"]
        assert abs(avg.mean() - fp["mean_dn"][c - 1]) < 4 * np.sqrt(s2 / (fp["n2"] * avg.size))
        means.append(avg)
    # the card and lamp move: two configurations differ by far more than the noise
    # (pure noise would give var(C1 - C2) = 2 sigma2_N / n2 ~ 1.8 DN^2)
    assert np.var(means[0] - means[1]) > 10 * 2 * s2 / fp["n2"]


def test_scene_variation_recovered_with_true_maps(session):
    root, truth = session
    K = load_truth(root).map("K_map").astype(float)
    dark = load_truth(root).map("dark_map").astype(float)
    for patch in truth["scene"]["patches"]:
        x, y, w, h = patch["roi"]
        for fr in patch["frames"]:
            entry = _frames(root, path=fr["path"])[0]
            assert entry["roi"] == patch["roi"] and entry["patch"] == patch["name"]
            assert "note" not in entry
        top = patch["frames"][-1]
        D = read_image(root / top["path"]).astype(float)
        Dc = ((D - dark) / K)[y:y + h, x:x + w]                         # eq. 51
        mu_D, var_D = Dc.mean(), Dc.var(ddof=1)
        s2_kn = np.mean(1 / K[y:y + h, x:x + w] ** 2) * (top["sigma2_N"])  # eq. 56
        vs_hat = (var_D - s2_kn) / mu_D ** 2                             # eq. 57
        # SE of a sample variance ~ sqrt(2/(M-1)) var_D (Gaussian); propagate to V_S
        se = np.sqrt(2 / (Dc.size - 1)) * var_D / mu_D ** 2
        assert abs(vs_hat - patch["V_S"]) < 4 * se, patch["name"]
        assert abs(mu_D - top["mu_D"]) < 4 * np.sqrt(var_D / Dc.size)   # eq. 54


def test_session_reads_patches_and_max_intensity_without_warnings(session):
    """Scene patches and the max-intensity frame come from the manifest keys ``patch`` and
    ``flags``, not from a legacy note."""
    root, truth = session
    s = open_session(root)
    assert [p for p in s.problems if p.severity == "error"] == []
    assert [str(p) for p in s.problems if p.code == "deprecated-note"] == []
    patches = s.scene_patches()
    assert list(patches) == [p["name"] for p in truth["scene"]["patches"]]
    for p in truth["scene"]["patches"]:
        recs = patches[p["name"]]
        assert [r.path.name for r in recs] == [Path(f["path"]).name for f in p["frames"]]
        assert all(r.patch == p["name"] and r.roi == tuple(p["roi"]) and r.flags == ()
                   for r in recs)
    mx = s.max_intensity_frame()
    assert mx is not None and mx.path.name == Path(truth["max_intensity"]["path"]).name
    assert mx.flags == ("max-intensity",) and mx.patch is None and mx.roi is None
    entry = _frames(root, path=truth["max_intensity"]["path"])[0]
    assert entry["flags"] == ["max-intensity"] and "note" not in entry


def test_same_seed_same_bytes(tmp_path):
    opts = dict(size=(24, 16), n_dark=2, levels=2, n1=2, n2=1, scene_levels=(0.5,),
                scene_margin=2)
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    simulate("healey94", a, seed=5, **opts)
    simulate("healey94", b, seed=5, **opts)
    simulate("healey94", c, seed=6, **opts)
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    assert files_a == files_b and len(files_a) > 10
    for rel in files_a:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    assert (a / "dark/dark_000.tif").read_bytes() != (c / "dark/dark_000.tif").read_bytes()


def test_bad_options_raise(tmp_path):
    out = tmp_path / "never"
    with pytest.raises(CcdError, match="levels"):
        simulate("healey94", out, seed=0, levels=1)
    with pytest.raises(CcdError, match="too small"):
        simulate("healey94", out, seed=0, size=(4, 4))
    with pytest.raises(CcdError, match="unknown preset"):
        simulate("healey95", out, seed=0)
    assert not out.exists()   # options are checked before anything is written


# ---- the sensor model on its own (no files) --------------------------------------------------

def test_sensor_moments_match_eqs_22_to_28():
    m = SensorModel(A=0.01, read_noise_e=50.0, dark_current_e=500.0, sigma_K=0.0, bits=12)
    rng = child_rng(1, "test")
    n = 200_000
    I = np.full(n, 20_000.0)
    D = m.expose(I, 1.0, 500.0, rng).astype(float)
    assert D.dtype == np.float64 and m.dtype == np.uint16
    mu, var = m.expected_mean(20_000.0, 1.0, 500.0), m.expected_variance(20_000.0, 1.0, 500.0)
    assert mu == pytest.approx(205.0)                                     # eq. 22
    assert var == pytest.approx(0.01 ** 2 * 20_500 + 0.01 ** 2 * 50 ** 2 + 1 / 12)  # eqs. 26-28
    assert abs(D.mean() - mu) < 4 * np.sqrt(var / n)
    assert abs(D.var(ddof=1) - var) < 4 * np.sqrt(2 / (n - 1)) * var


def test_quantisation_and_clipping():
    rng = child_rng(2, "test")
    m8 = SensorModel(A=0.01, read_noise_e=10.0, dark_current_e=0.0, bits=8)
    D = m8.expose(np.full((50, 50), 1e6), 1.0, 0.0, rng)       # 10000 DN -> clipped
    assert D.dtype == np.uint8 and np.all(D == 255)
    m_neg = SensorModel(A=0.01, read_noise_e=10.0, dark_current_e=0.0, bits=8, black_level_dn=-3.0)
    assert np.all(m_neg.expose(np.zeros((50, 50)), 1.0, 0.0, rng) == 0)   # offset clips at 0
    # without noise the ADC rounds to the nearest integer (eq. 4)
    m0 = SensorModel(A=1.0, read_noise_e=0.0, dark_current_e=0.0, bits=10, black_level_dn=0.4)
    D0 = m0.expose(np.zeros(10), 1.0, 0.0, rng)
    assert D0.dtype == np.uint16 and np.all(D0 == 0)
    m1 = SensorModel(A=1.0, read_noise_e=0.0, dark_current_e=0.0, bits=10, black_level_dn=0.6)
    assert np.all(m1.expose(np.zeros(10), 1.0, 0.0, rng) == 1)
    assert SensorModel(bits=10).full_scale == 1023


# ------------------------------------------------------------------ a real sensor's nonlinearity
def test_nonlinearity_bends_the_response_and_is_off_by_default(tmp_path):
    """``nonlinearity`` = a: the signal above the black level times 1 + a(1 − 8x(1 − x)), x
    its fraction of the usable range; the same noise stream, so a level's mean moves by the
    bend; off, the same bytes as without the option and no truth key."""
    kw = dict(seed=4, size=(48, 32), n_dark=2, levels=[0.2, 0.5], n1=1, n2=1, patches=(),
              max_intensity=None, bits=12, full_well_e=None)
    lin = simulate("healey94", tmp_path / "lin", **kw)
    off = simulate("healey94", tmp_path / "off", nonlinearity=0.0, **kw)
    bent = simulate("healey94", tmp_path / "bent", nonlinearity=0.03, **kw)
    assert "nonlinearity" not in lin and "nonlinearity" not in off
    assert bent["nonlinearity"]["amplitude"] == 0.03
    assert bent["nonlinearity"]["span_dn"] == pytest.approx(4095.0)
    assert bent["ptc"] == lin["ptc"]                 # the linear model's truth
    for level, frac in ((1, 0.2), (2, 0.5)):
        name = f"ptc/L{level:02d}_a.tif"
        a = read_image(tmp_path / "lin" / name).astype(float)
        assert np.array_equal(a, read_image(tmp_path / "off" / name))
        b = read_image(tmp_path / "bent" / name).astype(float)
        x = a.mean() / 4095.0
        want = a.mean() * 0.03 * (1.0 - 8.0 * x * (1.0 - x))
        assert b.mean() - a.mean() == pytest.approx(want, rel=0.05, abs=0.05)
    with pytest.raises(CcdError, match="nonlinearity"):
        simulate("healey94", tmp_path / "x", nonlinearity=-0.2, **kw)
