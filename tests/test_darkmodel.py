"""The dark model o + c·t (ccdcore.dark.model), temperature matching, the held-out check of the
flat field (ccdcore.flatfield.check) and the product's darks and flats, on the simulated cooled CCD
(ccdcore.simulate.ccdlab).  Never reads /work/shared."""
from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from ccdcore.cli.command import main
from ccdcore.dark.frame import dark_reference
from ccdcore.dark.model import fit_dark_model, session_dark_model
from ccdcore.errors import CcdError
from ccdcore.flatfield.check import HELD_OUT_FACTOR, held_out_figures
from ccdcore.flatfield.fit import flat_field, flat_field_from_session, held_out_check, session_dark
from ccdcore.io.frames import read_image
from ccdcore.product.make import calibrate, load_product
from ccdcore.session import ProblemCode, open_session
from ccdcore.session.temperature import TEMPERATURE_TOLERANCE
from ccdcore.simulate.ccdlab import simulate

SIZE = (96, 64)


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    root = tmp_path_factory.mktemp("lab") / "s"
    truth = simulate(root, seed=3, size=SIZE)
    return root, truth


@pytest.fixture(scope="module")
def model(lab):
    return session_dark_model(open_session(lab[0]))


def _truth(root, name):
    return np.asarray(read_image(root / "truth" / f"{name}.exr"), np.float64)


def test_offset_and_current_recovered_within_their_stated_errors(lab, model):
    root, truth = lab
    o, c = _truth(root, "offset"), _truth(root, "current_-5")
    good = _truth(root, "hot") == 0
    n = int(good.sum())
    # the darks at -10 °C are left out; the 6 biases and 10 darks at -5 °C are fitted
    assert model.n == 16 and model.temperature == -5.0
    assert all("T-10" in f for f in model.excluded) and len(model.excluded) == 16
    assert all("T-5" in f for f in model.frames)
    for est, true, var in ((model.offset, o, model.offset_var),
                           (model.current, c, model.current_var)):
        err = est - true
        # the stated errors are the actual ones: mean squared error / mean stated variance is
        # 1 within ~4 statistical σ (sqrt(2/n) for n pixels, plus the scatter of the
        # per-pixel variances, n − 2 = 14 dof)
        ratio = float(np.mean(err[good] ** 2) / np.mean(var[good]))
        assert abs(ratio - 1.0) < 4 * math.sqrt(2.0 / n) + 0.08, ratio
        # unbiased: the mean error over the pixels within 5 of its standard errors
        z = err[good] / np.sqrt(var[good])
        assert abs(float(z.mean())) < 5 * math.sqrt(14 / 12 / n)
    # a hot pixel's large current is in the model: recovered to a few per cent
    hot = ~good
    assert hot.sum() >= 10
    rel = np.abs(model.current[hot] - c[hot]) / c[hot]
    assert float(np.median(rel)) < 0.05
    assert model.hot_current[hot].mean() > 0.9 and model.hot_current[good].mean() < 0.01
    # the frames' noise model: read noise² = 49 DN², shot b = 1/g · c = 0.25 DN²/s
    assert model.noise_a == pytest.approx(truth["read_noise_dn"] ** 2, rel=0.1)
    assert model.noise_b == pytest.approx(0.5 / truth["gain_e_per_dn"], rel=0.25)


def test_dark_at_any_exposure_comes_from_the_model(lab, model):
    root, _ = lab
    o, c = _truth(root, "offset"), _truth(root, "current_-5")
    for t in (0.0, 23.0, 100.0):
        err = model.dark_at(t) - (o + c * t)
        assert float(np.mean(err ** 2) / np.mean(model.error_var_at(t))) == pytest.approx(
            1.0, abs=0.2)
    m = model.moments_at(23.0)
    assert np.allclose(m.var / m.n, model.error_var_at(23.0))


def test_fit_from_arrays_and_errors():
    rng = np.random.default_rng(0)
    o, c = 100.0 + rng.normal(0, 2, (16, 16)), rng.uniform(0.5, 1.5, (16, 16))
    frames = [(t, o + c * t + rng.normal(0, 1.0, o.shape)) for t in (0, 0, 0, 5, 10, 20, 40)]
    m = fit_dark_model(frames)
    assert np.abs(m.offset - o).max() < 6 * np.sqrt(m.offset_var.max())
    assert np.abs(m.current - c).max() < 6 * np.sqrt(m.current_var.max())
    with pytest.raises(CcdError, match="two or more exposures"):
        fit_dark_model([(10.0, o), (10.0, o)])
    with pytest.raises(CcdError, match="shape"):
        fit_dark_model([(0.0, o), (1.0, o[:8])])


def test_darks_at_the_wrong_temperature_are_not_used_and_raise_the_problem(tmp_path):
    root = tmp_path / "cold"
    # darks only at -10 °C, flats at -5 °C: no dark within 1 °C of the flats
    simulate(root, seed=1, size=(32, 24), temperatures=(-10.0,), n_flats=3)
    session = open_session(root)
    (problem,) = [p for p in session.problems if p.code == ProblemCode.TEMPERATURE_MISMATCH]
    assert problem.severity == "warning"
    assert "-5 °C" in problem.message and "-10 °C" in problem.message
    with pytest.raises(CcdError, match=r"within 1 °C of the flats' -5 °C.*-10 °C"):
        flat_field_from_session(session)
    # calibrate makes neither the dark reference nor the flat field from the wrong darks,
    # and says why, naming the temperatures
    with pytest.raises(CcdError, match=r"nothing to calibrate.*flats' -5 °C.*-10 °C"):
        calibrate(session)
    assert TEMPERATURE_TOLERANCE == 1.0


def test_dark_reference_matches_the_temperature(lab):
    ref = dark_reference(open_session(lab[0]), exposure=60.0)
    assert ref.s == 2 and all("T-5" in f for f in ref.frames)
    assert any("-10 °C left out" in n for n in ref.notes)


def test_held_out_check_passes_on_a_good_set_and_fails_on_planted_bugs(lab):
    session = open_session(lab[0])
    groups = session.flat_groups()
    key = next(iter(groups))
    dark = session_dark(session, groups, key)
    assert dark.kind == "model"
    check = held_out_check(session, groups, key, dark)
    assert check.verdict == "pass" and check.n_fit == 9
    (ch,) = check.channels
    assert abs(ch.ratio - 1.0) < 0.05 and ch.ratio < HELD_OUT_FACTOR   # ±1 % statistical
    assert ch.snup_raw > 3 * ch.snup           # the vignetting and PRNU are corrected
    # planted bugs: maps rebuilt as a buggy correction would, the held-out flat corrected
    recs = list(groups[key])
    held = recs.pop()
    ff = flat_field(dark.source, session.iter_frames(recs))
    frame = session.read(held)
    ok = held_out_figures(ff, frame, n_fit=9, held_out=held.relpath)
    assert ok.verdict == "pass"
    # (1) O of eq. 4 from a dark scaled wrongly (the exposure taken in ms: the current
    #     × 1000), G from the right one; a current merely doubled stays under the flats' noise
    #     here (hot pixels are 0.3 % of the frame)
    wrong = dark.model.dark_at(23.0e3)
    g = ff.G.astype(np.float64)
    bad_o = replace(ff, O=(wrong.mean() - g * wrong).astype(np.float32))
    assert held_out_figures(bad_o, frame, n_fit=9, held_out=held.relpath).verdict == "warn"
    # (2) G shifted by one pixel (a gain map misaligned with the frames)
    bad_g = replace(ff, G=np.roll(ff.G, 1, axis=1), O=np.roll(ff.O, 1, axis=1))
    assert held_out_figures(bad_g, frame, n_fit=9, held_out=held.relpath).verdict == "warn"
    # (3) the zero-dark form on a CCD with a 1000 DN bias keeps the noise floor at the flats'
    #     own level (DL_0 errors cancel there, as the check's docstring says)
    zero = replace(dark, source=replace(dark.source, mean=np.zeros(frame.shape)))
    assert held_out_check(session, groups, key, zero).verdict == "pass"


def test_product_dark_model_frames_and_apply(lab, tmp_path, capsys):
    root, _ = lab
    out = tmp_path / "prod"
    assert main(["calibrate", str(root), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "dark current c (median)" in printed and "held-out SNUP, L" in printed
    assert "frames of flat_base: 10 frames" in printed
    doc = json.loads((out / "calibration.json").read_text())
    dark = doc["estimates"]["dark"]
    assert dark["exposure"] == 23.0 and dark["model"]["n"] == 16
    assert dark["model"]["temperature"] == -5.0
    ff = doc["estimates"]["flat_field"]
    assert ff["dark_source"] == "model" and ff["held_out"]["verdict"] == "pass"
    assert len(doc["frames"]["flat_base"]) == 10 and len(doc["frames"]["dark"]) == 16
    assert not any("T-10" in f for f in doc["frames"]["flat_G"])
    p = load_product(out)
    assert p.frames["flat_dark"] == tuple(doc["frames"]["flat_dark"])
    assert p.estimates.flat_field.held_out.verdict == "pass"
    # apply corrects a flat: its SNUP drops from the vignetting's to the noise floor's
    applied = tmp_path / "applied"
    assert main(["apply", str(out), str(root / "flat" / "flat_9.tif"), "-o", str(applied)]) == 0
    corrected = read_image(applied / "flat_9.tif")
    assert 100 * corrected.std() / corrected.mean() < 1.0


def test_dark_exposure_is_honoured_for_the_dark_reference(lab):
    product = calibrate(lab[0], dark_exposure=60.0)
    dark = product.estimates.dark
    assert dark.exposure == 60.0 and dark.s == 2 and dark.model is None  # 2 darks at 60 s
    product = calibrate(lab[0], dark_exposure=100.0)      # no darks at 100 s: the model's
    assert product.estimates.dark.exposure == 100.0
    assert product.estimates.dark.model is not None
    assert any("as named" in n for n in product.estimates.dark.notes)
    # the flat field's DL_0 stays the model's dark at the flats' own 23 s
    assert product.estimates.flat_field.dark_exposure == 23.0


def test_simulator_is_deterministic_and_writes_temperatures(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    simulate(a, seed=4, size=(16, 12), exposures=(10.0, 60.0), n_flats=2)
    simulate(b, seed=4, size=(16, 12), exposures=(10.0, 60.0), n_flats=2)
    for p in sorted(a.rglob("*.tif")):
        assert p.read_bytes() == (b / p.relative_to(a)).read_bytes()
    session = open_session(a)
    temps = {r.temperature for r in session.frames}
    assert temps == {-10.0, -5.0}
    assert {r.exposure for r in session.dark_frames()} == {0.0, 10.0, 60.0}
