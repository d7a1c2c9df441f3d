"""The delasarte07 simulator: linear range, saturation, ZDI/NZDI dark images, true flat field.

Tolerances are 4 standard errors of the compared statistic (derived in each test from the noise
model of eqs. 26–28 of Healey & Kondepudy 1994); the seeds are fixed.
"""
from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from ccdcore.io.frames import read_frame, read_image
from ccdcore.session import open_session
from ccdcore.simulate import load_truth, simulate

SIZE = (64, 48)


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("delasarte")
    truth = simulate("delasarte07", out, seed=21, size=SIZE)
    return out, truth


def _frames(truth: dict, **match) -> list[dict]:
    return [f for f in truth["frames"] if all(f.get(k) == v for k, v in match.items())]


def _load(root: Path, entries: list[dict]) -> np.ndarray:
    return np.stack([read_image(root / e["path"]).astype(float) for e in entries])


def _noise_var(truth: dict, mean_lin: np.ndarray | float, setting: str) -> np.ndarray:
    """Per-channel temporal variance A (mean - black) + sigma_c2 (eq. 41), linear range."""
    black = np.array(truth["settings"][setting]["black_level_dn"])
    return np.array(truth["A"]) * (np.asarray(mean_lin) - black) + np.array(truth["sigma_c2"])


def test_manifest_and_truth(session):
    root, truth = session
    man = tomllib.loads((root / "session.toml").read_text())
    assert man["camera"]["layout"] == "rgb" and man["camera"]["bits"] == 8
    assert len(man["frames"]) == len(truth["frames"])
    assert load_truth(root).values == truth
    settings = {f["setting"] for f in man["frames"]}        # the manifest key, not a note
    assert settings == {"NZDI", "ZDI"}
    assert not any("note" in f for f in man["frames"])
    assert all(f["setting"] == t["setting"] for f, t in zip(man["frames"], truth["frames"]))
    for f in man["frames"]:
        assert f["role"] in ("dark", "flat") and f["exposure"] > 0 and f["gain"] == 1.0
        assert ("level" in f) == (f["role"] == "flat")
    data, header = read_frame(root / man["frames"][0]["path"])
    assert data.shape == (48, 64, 3) and data.dtype == np.uint8
    assert header.exposure == pytest.approx(man["frames"][0]["exposure"])
    for key in ("flatfield", "vignetting", "dark_rate", "dark_NZDI", "dark_ZDI"):
        assert (root / truth["maps"][key]).is_file()
    assert truth["setting_key"] == "manifest key setting = '<NZDI|ZDI>'"
    base = _frames(truth, role="flat", setting="NZDI", level=truth["base"]["level"],
                   exposure=truth["base"]["exposure"])
    assert len(base) == 8                                   # N = 1, 2, 4, 8 can be averaged
    assert all(f["in_linear_range"] for f in base)
    assert set(truth["settings"]) == {"NZDI", "ZDI"}


def test_flat_means_match_truth_and_scale_with_exposure(session):
    root, truth = session
    M = SIZE[0] * SIZE[1]
    for setting in ("NZDI", "ZDI"):
        for level in (1, 2, 3):
            rate = []
            for t in truth["exposures"]:
                fr = _frames(truth, role="flat", setting=setting, level=level, exposure=t)
                if not fr[0]["in_linear_range"]:
                    continue
                data = _load(root, fr)
                mean = data.mean(axis=(0, 1, 2))
                lin = np.array(fr[0]["mean_dn_linear"])
                # mean over n frames and M pixels: SE sqrt(var / (n M))
                se = np.sqrt(_noise_var(truth, lin, setting) / (len(fr) * M))
                assert np.all(np.abs(mean - np.array(fr[0]["mean_dn"])) < 4 * se), (setting, level, t)
                darks = _load(root, _frames(truth, role="dark", setting=setting, exposure=t))
                if setting == "NZDI":
                    se_d = np.sqrt(_noise_var(truth, darks.mean(axis=(0, 1, 2)), setting)
                                   / (darks.shape[0] * M))
                    signal = mean - darks.mean(axis=(0, 1, 2))
                    rate.append((t, signal, np.sqrt(se ** 2 + se_d ** 2)))
            if setting == "NZDI":
                # in the linear range the dark-subtracted mean is proportional to exposure
                expected = np.array(truth["signal_dn_per_s"]) * truth["radiance_levels"][str(level)]
                assert len(rate) >= 3
                for t, signal, se in rate:
                    assert np.all(np.abs(signal / t - expected) < 4 * se / t), (level, t)


def test_saturation_and_knee(session):
    root, truth = session
    t_max = max(truth["exposures"])
    sat = _frames(truth, role="flat", setting="NZDI", level=3, exposure=t_max)
    data = _load(root, sat)
    assert np.mean(data == 255) > 0.99 and data.max() == 255
    assert min(sat[0]["saturated_fraction"]) > 0.99
    # just below saturation the response is compressed: mean below the linear prediction
    knee = [f for f in _frames(truth, role="flat", setting="NZDI")
            if not f["in_linear_range"] and max(f["saturated_fraction"]) < 0.5]
    assert knee
    for fr in knee[:2]:
        m = read_image(root / fr["path"]).astype(float).mean(axis=(0, 1))
        assert np.any(np.array(fr["mean_dn_linear"]) - m > 2.0)


def test_zdi_dark_is_zero_and_nzdi_dark_is_not(session):
    root, truth = session
    zdi = _load(root, _frames(truth, role="dark", setting="ZDI"))
    nzdi = _load(root, _frames(truth, role="dark", setting="NZDI"))
    assert np.mean(zdi == 0) > 0.95
    assert nzdi.min() > 0
    # NZDI dark mean = black level + dark current x exposure, per channel, within its SE
    M = SIZE[0] * SIZE[1]
    for t in truth["exposures"]:
        fr = _frames(truth, role="dark", setting="NZDI", exposure=t)
        d = _load(root, fr).mean(axis=(0, 1, 2))
        expected = (np.array(truth["settings"]["NZDI"]["black_level_dn"])
                    + np.array(truth["dark_current_dn_per_s"]) * t)
        se = np.sqrt(_noise_var(truth, expected, "NZDI") / (len(fr) * M))
        assert np.all(np.abs(d - expected) < 4 * se), t
    dark_zdi = load_truth(root).map("dark_ZDI")
    assert float(np.max(dark_zdi)) < 0.05


def test_true_flatfield_explains_the_flat_frames(session):
    """(DL_B - DL_0)/F is uniform up to noise, so G = 1/F is de Lasarte's correction."""
    root, truth = session
    F = load_truth(root).map("flatfield_map").astype(float)
    assert F.shape == (48, 64, 3)
    assert np.allclose(F.mean(axis=(0, 1)), 1.0, atol=1e-5)
    t_b, l_b = truth["base"]["exposure"], truth["base"]["level"]
    fr = _frames(truth, role="flat", setting="NZDI", level=l_b, exposure=t_b)
    dk = _frames(truth, role="dark", setting="NZDI", exposure=t_b)
    B, D = _load(root, fr), _load(root, dk)
    n_b, n_d, M = len(fr), len(dk), F[..., 0].size
    net = B.mean(axis=0) - D.mean(axis=0)
    corrected = net / F
    snup_raw = 100 * net.std(axis=(0, 1)) / net.mean(axis=(0, 1))
    snup_cor = 100 * corrected.std(axis=(0, 1)) / corrected.mean(axis=(0, 1))
    assert np.all(snup_raw > 3) and np.all(snup_cor < 0.3 * snup_raw)
    # residual variance of the corrected image = temporal noise only:
    # per pixel (var_B / n_b + var_D / n_d) / F^2, with var from eq. 41
    black = np.array(truth["settings"]["NZDI"]["black_level_dn"])
    S = np.array(truth["signal_dn_per_s"]) * truth["radiance_levels"][str(l_b)] * t_b
    dark = black + np.array(truth["dark_current_dn_per_s"]) * t_b
    var_b = _noise_var(truth, dark + S * F, "NZDI")
    var_d = _noise_var(truth, dark, "NZDI")
    pred = ((var_b / n_b + var_d / n_d) / F ** 2).mean(axis=(0, 1))
    got = corrected.var(axis=(0, 1), ddof=1)
    # sample variance of ~Gaussian residuals: SE sqrt(2/(M-1)) var
    assert np.all(np.abs(got - pred) < 4 * np.sqrt(2 / (M - 1)) * pred), (got, pred)
    assert np.all(np.abs(corrected.mean(axis=(0, 1)) - S) < 4 * np.sqrt(pred / M))


def test_same_seed_same_bytes(tmp_path):
    opts = dict(size=(16, 12), levels=(1.0,), exposures=(0.01, 0.04), n_frames=1, n_average=2,
                base=(1, 2), n_dark=1)
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    simulate("delasarte07", a, seed=3, **opts)
    simulate("delasarte07", b, seed=3, **opts)
    simulate("delasarte07", c, seed=4, **opts)
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    assert files_a == files_b and len(files_a) > 10
    for rel in files_a:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    assert (a / "truth/flatfield.exr").read_bytes() != (c / "truth/flatfield.exr").read_bytes()


def test_session_reads_settings_without_warnings(session):
    """The manifest's ``setting`` key selects the frames of each offset setting (no legacy note)."""
    root, truth = session
    s = open_session(root)
    assert [p for p in s.problems if p.severity == "error"] == []
    assert [str(p) for p in s.problems if p.code == "deprecated-note"] == []
    assert s.settings() == ("NZDI", "ZDI")
    for setting in ("NZDI", "ZDI"):
        flats = s.flat_groups(setting=setting)
        want = {(f["level"], f["exposure"]) for f in _frames(truth, role="flat", setting=setting)}
        assert set(flats) == want
        for (level, t), recs in flats.items():
            assert {r.path.name for r in recs} == {
                Path(f["path"]).name for f in _frames(truth, role="flat", setting=setting,
                                                      level=level, exposure=t)}
            assert all(r.setting == setting for r in recs)
        darks = s.dark_groups(setting=setting)
        assert sorted(darks) == sorted(truth["exposures"])
        assert all(len(v) == truth["n_dark"] for v in darks.values())
