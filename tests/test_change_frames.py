"""Change detection between single frames or a few frames (ccdcore.change.frames; Tsin, Ramesh &
Kanade 2001, sec. 5, eq. 20) on simulated video-camera pairs (ccdcore.simulate.change_frames):
an unknown sRGB-like response with toe and shoulder, 8-bit frames without exposure, a global
change of light with automatic gain, inserted objects with a truth mask."""
from __future__ import annotations

import json

import numpy as np
import pytest

from ccdcore.change.detector import ChangeOptions
from ccdcore.change.session import session_change
from ccdcore.change.frames import (ASSUMED_NOISE, fit_noise_terms, frames_change, role_kind,
                                   srgb_inverse)
from ccdcore.cli.command import main
from ccdcore.errors import CcdError
from ccdcore.io.frames import write_image
from ccdcore.session import open_session
from ccdcore.simulate.change_frames import frame_pair, write_frame_pair


def _run(tmp_path, seed=0, **opts):
    root = tmp_path / f"s{seed}"
    write_frame_pair(root, seed, **opts)
    res, inputs = session_change(open_session(root))
    truth = np.load(root / "truth" / "change_mask.npy")
    return res, inputs, truth


def _scores(res, truth):
    m = res.labels == 255
    tp = int(np.count_nonzero(m & truth))
    return tp / max(int(truth.sum()), 1), tp / max(int(m.sum()), 1)


@pytest.mark.parametrize("n_reference", [1, 5])
def test_objects_found_with_the_defaults(tmp_path, n_reference):
    # objects differ from the background by tens of DN at 1-2 DN of noise: every seed tried
    # (0-2) gave recall 1.00 and precision >= 0.97; the bounds leave room for a few edge pixels
    res, inputs, truth = _run(tmp_path, 0, n_reference=n_reference)
    recall, precision = _scores(res, truth)
    assert recall >= 0.95 and precision >= 0.9
    assert inputs.kinds == {"reference": "frames", "target": "frames"}
    assert inputs.source.startswith("assumed: the sRGB standard curve")
    assert res.to_dict()["response_source"] == inputs.source
    if n_reference == 1:
        assert inputs.noise.count("assumed") == 2
    else:
        assert "measured from the spread of its 5 frames" in inputs.noise
        assert "target: 1 frame, the noise measured on the reference frames" in inputs.noise


@pytest.mark.parametrize("seed", [0, 1])
def test_no_change_pair_false_alarms_near_pfa(tmp_path, seed):
    # with the noise measured from 5 frames, d² is χ²_3 on the background (scale near 1) and
    # the per-pixel rate above the threshold is P: 20 480 pixels give a binomial sd of 0.0007 at
    # P = 0.01; the calibration on the background's own quantile keeps it within 0.3 P
    res, _, truth = _run(tmp_path, seed, n_reference=5, n_objects=0)
    assert not truth.any()
    # the background cluster's d² (a further "shadow" cluster may take some of its tail)
    per_pixel = float(np.mean(res.d2[..., 0][res.valid] > res.threshold))
    assert abs(per_pixel - 0.01) < 0.003
    assert 0.85 < res.scale < 1.2          # sigma from the right frames: χ² holds
    assert res.dof == 3                    # RGB: three degrees of freedom
    assert np.mean(res.labels == 255) <= 0.01  # regions under 3 x 3 dropped


def test_dof_is_that_of_the_channels(tmp_path):
    res, _, _ = _run(tmp_path, 0, n_reference=5, n_objects=0)
    from scipy import stats
    assert res.chi2_threshold() == pytest.approx(stats.chi2.isf(0.01, 3))


def test_sigma_from_the_reference_frames_over_root_n(tmp_path):
    # the reference sigma is the spread of ITS frames over √5, the target's (one frame) the
    # model alone: a sigma from the wrong frames or without the √N fails these
    res, inputs, _ = _run(tmp_path, 0, n_reference=5, n_target=1)
    ok = np.isfinite(inputs.sigma_ref) & np.isfinite(inputs.sigma_tgt)
    ratio = np.median(inputs.sigma_tgt[ok] / inputs.sigma_ref[ok])
    # target one frame, 0.715 the reference's signal in radiance terms: about √5 times the
    # reference's sigma (shot noise scales as √signal, the target brighter in codes by autogain)
    assert 1.6 < ratio < 3.0


def test_noise_terms_fit_recovers_a_known_model():
    rng = np.random.default_rng(3)
    g = srgb_inverse(256)
    z = rng.uniform(20, 230, 20000)
    gb = np.interp(z, np.arange(256), g)
    sl = np.interp(z, np.arange(256), np.gradient(g))
    true = 0.01 ** 2 * gb + 0.002 ** 2 + (sl * 0.8) ** 2
    var = true * rng.chisquare(4, z.size) / 4
    s_s, s_c1, s_c2 = fit_noise_terms(gb, var, sl, 4)
    fit = s_s ** 2 * gb + s_c1 ** 2 + (sl * s_c2) ** 2
    assert np.median(np.abs(fit / true - 1)) < 0.1


def test_srgb_curve_ends():
    g = srgb_inverse(256)
    assert g[0] == 0 and g[-1] == pytest.approx(1.0) and np.all(np.diff(g) > 0)
    assert g[128] == pytest.approx(0.2158605, rel=1e-5)


def test_role_kind():
    class R:
        def __init__(self, e, p="a.png"):
            self.exposure, self.relpath, self.role = e, p, "reference"
    assert role_kind([R(None)]) == "frames"
    assert role_kind([R(0.01), R(0.01)]) == "frames"
    assert role_kind([R(0.01), R(0.02)]) == "bracket"
    with pytest.raises(CcdError, match="b.png"):
        role_kind([R(0.01), R(None, "b.png")])
    with pytest.raises(CcdError, match="c.png.*repeats|neither"):
        role_kind([R(0.01), R(0.02), R(0.02, "c.png")])


def test_srgb_response_option_named(tmp_path):
    root = tmp_path / "s"
    write_frame_pair(root, 0)
    res, inputs = frames_change(open_session(root), response="srgb")
    assert "as asked (--response srgb)" in inputs.source
    assert res.sources["noise"] == inputs.noise and "σ_s = 0.01" in inputs.noise
    assert str(ASSUMED_NOISE["sigma_c2"]) in inputs.noise or "σ_c2 = 1 " in inputs.noise


def _cli(argv, capsys):
    rc = main(argv)
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_cli_single_frames_json_and_summary(tmp_path, capsys):
    root = tmp_path / "s"
    write_frame_pair(root, 1)
    rc, out, _ = _cli(["change", str(root), "-o", str(tmp_path / "o"), "--json"], capsys)
    assert rc == 0
    data = json.loads(out)
    assert data["kinds"] == {"reference": "frames", "target": "frames"}
    assert data["response_source"].startswith("assumed: the sRGB")
    assert "assumed" in data["noise_source"] and data["min_region"] == 9
    rc, out, _ = _cli(["change", str(root), "-o", str(tmp_path / "o2")], capsys)
    assert rc == 0 and "response: assumed: the sRGB" in out and "noise: reference:" in out
    assert "reference: 1 frame, target: 1 frame" in out


def test_cli_target_of_another_size(tmp_path, capsys):
    root = tmp_path / "s"
    write_frame_pair(root, 0)
    write_image(root / "target" / "tgt_00.png", frame_pair(0, (100, 80))["target"][0])
    rc, _, err = _cli(["change", str(root), "-o", str(tmp_path / "o")], capsys)
    assert rc == 2
    line = err.strip().splitlines()[-1]
    assert "target/tgt_00.png" in line and "shape" in line and len(err.strip().splitlines()) == 1


def test_cli_reference_without_usable_pixels(tmp_path, capsys):
    root = tmp_path / "s"
    write_frame_pair(root, 0)
    write_image(root / "reference" / "ref_00.png", np.full((128, 160, 3), 255, np.uint8))
    rc, _, err = _cli(["change", str(root), "-o", str(tmp_path / "o")], capsys)
    assert rc == 2 and "reference/ref_00.png" in err and "no usable pixel" in err


def test_cli_mixed_exposures_not_a_bracket(tmp_path, capsys):
    root = tmp_path / "s"
    write_frame_pair(root, 0, n_reference=3)
    (root / "session.toml").write_text(
        '[camera]\nname = "c"\nbits = 8\nlayout = "rgb"\n'
        '[[frames]]\npath = "reference/ref_00.png"\nrole = "reference"\nexposure = 0.01\n'
        '[[frames]]\npath = "reference/ref_01.png"\nrole = "reference"\nexposure = 0.02\n'
        '[[frames]]\npath = "reference/ref_02.png"\nrole = "reference"\nexposure = 0.02\n'
        '[[frames]]\npath = "target/tgt_00.png"\nrole = "target"\nexposure = 0.01\n')
    rc, _, err = _cli(["change", str(root), "-o", str(tmp_path / "o")], capsys)
    assert rc == 2 and "reference/ref_02.png" in err and "neither a bracket" in err


def test_calibrated_noise_source_with_options(tmp_path):
    root = tmp_path / "s"
    write_frame_pair(root, 2, n_reference=3, n_target=3)
    res, inputs = session_change(open_session(root), ChangeOptions(min_region=1))
    assert res.min_region == 1
    assert "target: measured from the spread of its 3 frames" in inputs.noise


@pytest.mark.parametrize("seed", [0, 1])
def test_soft_shadows_are_shades_not_change(tmp_path, seed):
    # what the lobby taught: a person's soft shadow beside them (the light times 0.6-1, a
    # continuum no single M describes) was called change and halved the precision. Seeds 0-2
    # with two such shadows: without the shade test 48-71 % of the shadow is called change
    # (precision 0.19-0.27); with it none, recall 1.00 and precision >= 0.999
    root = tmp_path / f"s{seed}"
    write_frame_pair(root, seed, n_shadows=2)
    truth = np.load(root / "truth" / "change_mask.npy")
    shadow = np.load(root / "truth" / "shadow_mask.npy")
    assert shadow.sum() > 2000
    res, _ = session_change(open_session(root))
    recall, precision = _scores(res, truth)
    assert recall >= 0.95 and precision >= 0.9
    called = res.labels == 255
    assert np.count_nonzero(called & shadow) <= 0.05 * shadow.sum()
    assert np.count_nonzero((res.labels == 253) & shadow) >= 0.3 * shadow.sum()
    off, _ = session_change(open_session(root), ChangeOptions(min_region=9, shade=None))
    assert np.count_nonzero((off.labels == 255) & shadow) >= 0.3 * shadow.sum()
    assert not np.any(off.labels == 253)


def test_cli_shade_flag(tmp_path, capsys):
    root = tmp_path / "s"
    write_frame_pair(root, 0, n_shadows=2)
    rc, out, _ = _cli(["change", str(root), "-o", str(tmp_path / "o"), "--json"], capsys)
    on = json.loads(out)
    assert rc == 0 and on["shade"] == [0.5, 2.0] and on["shade_pixels"] > 1000
    rc, out, _ = _cli(["change", str(root), "-o", str(tmp_path / "o2"), "--json",
                       "--shade", "off"], capsys)
    off = json.loads(out)
    assert rc == 0 and off["shade"] is None and off["shade_pixels"] == 0
    assert off["changed_pixels"] > on["changed_pixels"] + 1000
    rc, out, _ = _cli(["change", str(root), "-o", str(tmp_path / "o3")], capsys)
    assert rc == 0 and "--shade off counts them as change" in out
    with pytest.raises(SystemExit) as exc:
        main(["change", str(root), "-o", str(tmp_path / "o4"), "--shade", "2,3"])
    assert exc.value.code == 2 and "--shade" in capsys.readouterr().err
