"""The registry of response methods, the CLI verbs ``response`` and ``hdr``, and the response in
the calibration product (calibrate, apply --linearise, hdr --calib)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from ccdcore.cli.command import build_parser, main
from ccdcore.errors import CcdError
from ccdcore.io.frames import read_image
from ccdcore.product.make import calibrate, load_product
from ccdcore.response.brackets import load_bracket
from ccdcore.response.bracket_fit import session_response
from ccdcore.response.methods import METHODS, response_of
from ccdcore.response.scale import reference_codes, rms_error
from ccdcore.session import open_session

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "assets" / "tsin01"
TRUTH_G = np.asarray(json.loads((DEMO / "truth.json").read_text())["g"])


def run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def results():
    brackets = load_bracket(open_session(DEMO))
    return {name: response_of(brackets, name) for name in METHODS}


def test_cli_choices_come_from_the_registry():
    sub = next(a for a in build_parser()._actions if a.dest == "verb")
    method = next(a for a in sub.choices["response"]._actions if a.dest == "method")
    assert list(method.choices) == ["auto"] + list(METHODS)
    assert list(METHODS) == ["tsin", "debevec", "robertson", "mitsunaga-nayar"]


@pytest.mark.parametrize("name", list(METHODS))
def test_every_method_gives_curve_band_and_noise(results, name):
    """On the demo bracket (128², 8 exposures): each curve on the reported scale, its band
    positive away from the fixed point and small next to the curve, the noise terms of eq. 17
    near the simulator's (σ_s 0.015, σ_c1 0.01) for the curve of sec. 3.2."""
    r = results[name]
    c = r["L"]
    _, z_hi = reference_codes(256)
    assert c.g.shape == c.g_err.shape == (256,)
    assert c.g[z_hi] == pytest.approx(z_hi / 255, abs=1e-15)
    assert np.all(np.diff(c.g) >= 0)
    mid = np.r_[20:220]
    assert np.all(c.g_err[mid] > 0) and np.all(c.g_err[mid] < 0.01)
    assert rms_error(c.g, TRUTH_G) < {"tsin": 6e-4, "debevec": 2.5e-3, "robertson": 6e-3,
                                      "mitsunaga-nayar": 6e-3}[name]
    if name == "tsin":
        assert 0.010 < c.sigma_s < 0.020 and 0.007 < c.sigma_c1 < 0.013
    else:   # eq. 17 on a classic curve: its error leaks into the residuals, terms shift
        assert all(v is not None and v >= 0 for v in (c.sigma_s, c.sigma_c1, c.sigma_c2))
    np.testing.assert_array_equal(c.a, r.t)
    np.testing.assert_array_equal(c.b, 0.0)


def test_methods_differ(results):
    """The four curves are four estimates, not one: pairwise differences above the bands."""
    names = list(METHODS)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert np.max(np.abs(results[a]["L"].g - results[b]["L"].g)) > 5e-4, (a, b)


def test_json_keys_and_shapes(results):
    d = results["tsin"].to_dict()
    for key in ("method", "channels", "g", "g_err", "a", "b", "sigma_s", "sigma_c1",
                "sigma_c2", "iterations", "converged"):
        assert key in d
    assert d["method"] == "tsin" and d["channels"] == ["L"]
    assert len(d["g"]) == 1 and len(d["g"][0]) == 256 and len(d["g_err"][0]) == 256
    assert len(d["a"][0]) == 8 and len(d["b"][0]) == 8
    assert isinstance(d["converged"][0], bool) and d["iterations"][0] >= 1
    json.dumps(d, allow_nan=False)                              # strict JSON


def test_cli_response_json(capsys):
    code, out, err = run(capsys, "response", DEMO, "--method", "debevec", "--json")
    assert code == 0, err
    d = json.loads(out)
    assert d["method"] == "debevec" and len(d["g"][0]) == 256
    code, out, err = run(capsys, "response", DEMO)
    assert code == 0 and "Tsin" in out and "σ_s" in out


def test_cli_response_without_bracket(capsys):
    code, out, err = run(capsys, "response", ROOT / "assets" / "healey94")
    assert code == 2 and out == ""
    assert "bracket" in err and len(err.strip().splitlines()) == 1


def test_cli_hdr_writes_radiance_sigma_flags(capsys, tmp_path):
    code, out, err = run(capsys, "hdr", DEMO, "-o", tmp_path / "h", "--json")
    assert code == 0, err
    rad = read_image(tmp_path / "h" / "radiance.exr")
    sig = read_image(tmp_path / "h" / "sigma.exr")
    flags = read_image(tmp_path / "h" / "flags.png")
    assert rad.shape == sig.shape == flags.shape == (128, 128)
    E = read_image(DEMO / "truth" / "E.exr").astype(np.float64)
    ok = flags == 0
    z = (rad[ok] - E[ok]) / sig[ok]
    # the response is estimated, not the truth: its scale is fixed at z_hi, E is not; with the
    # scale taken out, the errors are the size the sigma map says
    s = np.median(rad[ok] / E[ok])
    z = (rad[ok] / s - E[ok]) / (sig[ok] / s)
    assert abs(np.std(z) - 1.0) < 0.15


def test_cli_hdr_refuses_an_output_over_an_input(capsys, tmp_path):
    root = tmp_path / "s"
    shutil.copytree(DEMO, root)
    (root / "bracket" / "radiance.exr").write_bytes(b"")
    manifest = root / "session.toml"
    text = manifest.read_text().replace('path = "bracket/s0_k07.tif"',
                                        'path = "bracket/radiance.exr"')
    manifest.write_text(text)
    code, out, err = run(capsys, "hdr", root, "-o", root / "bracket")
    assert code == 2 and out == ""


def test_product_response_round_trip_and_linearise(capsys, tmp_path):
    product = calibrate(DEMO)
    assert "response" in product.estimates.made()
    folder = product.save(tmp_path / "c")
    back = load_product(folder)
    models = back.response_models()
    np.testing.assert_array_equal(models["L"].g, product.response_models()["L"].g)
    code, out, err = run(capsys, "apply", folder, DEMO / "bracket" / "s0_k03.tif",
                         "-o", tmp_path / "lin", "--linearise")
    assert code == 0, err
    lin = read_image(tmp_path / "lin" / "s0_k03.tif")
    raw = read_image(DEMO / "bracket" / "s0_k03.tif")
    np.testing.assert_array_equal(lin, models["L"].g[raw].astype(np.float32))
    code, out, err = run(capsys, "hdr", DEMO, "--calib", folder, "-o", tmp_path / "h")
    assert code == 0, err


def test_linearise_needs_a_response(capsys, tmp_path):
    folder = calibrate(ROOT / "assets" / "healey94").save(tmp_path / "c")
    code, out, err = run(capsys, "apply", folder, DEMO / "bracket" / "s0_k03.tif",
                         "-o", tmp_path / "lin", "--linearise")
    assert code == 2 and "no response curve" in err
    assert not (tmp_path / "lin").exists()


def test_damaged_response_in_product(tmp_path):
    folder = calibrate(DEMO).save(tmp_path / "c")
    doc = json.loads((folder / "calibration.json").read_text())
    doc["estimates"]["response"]["g"][0][100] = 5.0        # not monotone
    (folder / "calibration.json").write_text(json.dumps(doc))
    with pytest.raises(CcdError, match="damaged response"):
        load_product(folder).response_models()


def test_unknown_method():
    with pytest.raises(CcdError, match="unknown method"):
        session_response(DEMO, "gsolve")


def test_cli_white_balance_gains(capsys):
    code, out, err = run(capsys, "response", DEMO, "--white-balance", "--json")
    assert code == 0, err
    d = json.loads(out)
    assert d["white_balance"] == [True]
    # the gains start at the bracket's own exposures (estimated) and keep their gauge around
    # them: no trend of ln(a_k / t_k) in ln t_k (the mean follows the reported scale)
    a, t = np.asarray(d["a"][0]), np.asarray(d["exposures"]["estimated"])
    la, lt = np.log(a / t), np.log(t) - np.log(t).mean()
    assert abs(la @ lt) < 1e-6
    assert np.all(np.asarray(d["b_err"][0][1:]) > 0)
    assert np.all(np.asarray(d["a_err"][0]) > 0)
    code, out, err = run(capsys, "response", DEMO, "--white-balance", "--method", "robertson")
    assert code == 2 and "white balance is estimated by the tsin method" in err
