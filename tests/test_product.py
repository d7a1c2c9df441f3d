"""Calibration products: every estimate end to end, bit-exact round trip, correction of images."""
from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from ccdcore.cli.command import main
from ccdcore.errors import CcdError
from ccdcore.io.frames import read_image, write_image
from ccdcore.product.make import apply_product, calibrate, load_product
from ccdcore.simulate import simulate


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    root = tmp_path_factory.mktemp("h94")
    truth = simulate("healey94", root, seed=11, size=(96, 72))
    return root, truth


@pytest.fixture(scope="module")
def product(sim):
    return calibrate(sim[0])


def test_every_estimate_the_session_allows(product, sim):
    _, truth = sim
    assert set(product.estimates.made()) >= {"noise", "dark", "fixed_pattern", "plan", "scene",
                                             "correction_check"}
    # the paper's check on the max-intensity frame (27 %, 3 % for sigma_K = 3.72e-3 at ~244 DN)
    check = product.estimates.correction_check
    assert 0.1 < check.frac_gt_1q < 0.5 and check.frac_gt_2q < check.frac_gt_1q
    assert set(product.maps) >= {"dark", "dark_var", "hot", "dead", "K", "K_var", "n1_used"}
    noise = product.estimates.noise
    # three standard errors of the fitted covariance (eq. 66)
    assert abs(noise.A - truth["A"]) < 3 * noise.cov[0][0] ** 0.5
    assert abs(noise.sigma_c2 - truth["sigma_c2"]) < 3 * noise.cov[1][1] ** 0.5
    assert product.provenance.steps.fixed_pattern.window == 9


def test_scene_variation_end_to_end_within_its_error(product, sim):
    # estimated D̂_D, K̂ and noise model: the calibration maps' own errors (including the D̂_D
    # error that K̂ absorbs through eq. 46) are propagated, so V_S is within 3 of its errors
    _, truth = sim
    true_vs = {p["name"]: p["V_S"] for p in truth["scene"]["patches"]}
    scene = product.estimates.scene
    assert set(scene) == set(true_vs)
    for name, sv in scene.items():
        assert abs(sv.V_S - true_vs[name]) < 3 * sv.V_S_err, name


def test_save_load_round_trip_is_bit_exact(product, tmp_path):
    folder = product.save(tmp_path / "calib")
    back = load_product(folder)
    assert set(back.maps) == set(product.maps)
    for name, m in product.maps.items():
        assert back.maps[name].dtype == np.float32
        assert back.maps[name].tobytes() == m.tobytes(), name
    assert back.estimates == product.estimates
    assert json.dumps(back.estimates.to_dict()) == json.dumps(product.estimates.to_dict())
    # saving again over an existing product replaces it atomically
    product.save(folder)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["calib"]


def test_save_refuses_a_foreign_folder(product, tmp_path):
    (tmp_path / "mine.txt").write_text("keep me")
    with pytest.raises(CcdError, match="not a calibration product"):
        product.save(tmp_path)
    assert (tmp_path / "mine.txt").read_text() == "keep me"


def test_apply_is_eq_51_and_leaves_inputs_alone(product, sim, tmp_path):
    root, _ = sim
    src = root / "scene" / "max_intensity.tif"
    before = hashlib.sha256(src.read_bytes()).hexdigest()
    [out] = apply_product(product, [src], tmp_path / "out")
    assert out.name == "max_intensity.tif"
    got = read_image(out)
    expected = ((read_image(src).astype(np.float64) - product.maps["dark"]) /
                product.maps["K"]).astype(np.float32)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, expected)
    assert hashlib.sha256(src.read_bytes()).hexdigest() == before


def test_apply_compression_is_a_choice(product, sim, tmp_path, capsys):
    """Uncompressed by default (fast); zip on request: the same float32 values, a smaller file
    (the K̂-corrected frame is smooth enough to deflate); an unknown choice is refused."""
    src = sim[0] / "scene" / "max_intensity.tif"
    [plain] = apply_product(product, [src], tmp_path / "plain")
    [packed] = apply_product(product, [src], tmp_path / "zip", compression="zip")
    np.testing.assert_array_equal(read_image(plain), read_image(packed))
    assert packed.stat().st_size < plain.stat().st_size
    assert plain.stat().st_size >= read_image(plain).nbytes   # nothing deflated
    with pytest.raises(CcdError, match="unknown compression 'jpeg'"):
        apply_product(product, [src], tmp_path / "x", compression="jpeg")
    assert main(["apply", str(tmp_path / "nowhere"), str(src), "-o", str(tmp_path / "o"),
                 "--compression", "zip"]) == 2
    capsys.readouterr()


def test_apply_bad_inputs(product, sim, tmp_path):
    root, _ = sim
    small = write_image(tmp_path / "small.png", np.zeros((8, 8), np.uint8))
    with pytest.raises(CcdError, match="small.png"):
        apply_product(product, [small], tmp_path / "out")
    assert not (tmp_path / "out").exists()          # nothing written when an input is bad
    with pytest.raises(CcdError, match="overwrite"):
        apply_product(product, [root / "scene" / "max_intensity.tif"], root / "scene")


def test_calibrate_without_fixed_pattern_notes_what_is_missing(tmp_path):
    root = tmp_path / "s"
    simulate("healey94", root, seed=2, size=(48, 32), n1=2, n2=1)
    toml = (root / "session.toml").read_text()
    # drop the fixed-pattern and scene frames from the manifest
    blocks = toml.split("[[frames]]")
    keep = [b for b in blocks[1:] if 'role = "fixed_pattern"' not in b and 'role = "scene"' not in b]
    (root / "session.toml").write_text(blocks[0] + "".join("[[frames]]" + b for b in keep))
    prod = calibrate(root)
    assert prod.estimates.fixed_pattern is None and "K" not in prod.maps
    skipped = {s.estimate: s for s in prod.skipped}
    assert skipped["fixed_pattern"].code == "missing-frames"
    assert skipped["fixed_pattern"].roles == ("fixed_pattern",)
    d = read_image(root / "ptc" / "L01_a.tif")
    np.testing.assert_array_equal(prod.correct(d), (d - prod.maps["dark"]).astype(np.float32))


def test_cli_calibrate_and_apply(sim, tmp_path, capsys):
    root, _ = sim
    assert main(["calibrate", str(root), "-o", str(tmp_path / "c"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["maps"]["K"] == "maps/K.exr"
    assert main(["apply", str(tmp_path / "c"), str(root / "ptc" / "L02_a.tif"), "-o",
                 str(tmp_path / "o")]) == 0
    assert (tmp_path / "o" / "L02_a.tif").exists()
    capsys.readouterr()
    assert main(["apply", str(tmp_path / "nowhere"), str(root / "ptc" / "L02_a.tif"), "-o",
                 str(tmp_path / "o")]) == 2
    assert "no calibration.json" in capsys.readouterr().err


def test_flat_field_product_round_trip_and_apply(tmp_path):
    from ccdcore.flatfield.fit import flat_field_from_session
    from ccdcore.session import open_session

    root = tmp_path / "dl"
    simulate("delasarte07", root, seed=5, size=(48, 32))
    prod = calibrate(root)
    assert {"flat_G", "flat_O", "flat_flags"} <= set(prod.maps) and prod.method == "flat_field"
    assert "flat_field" in prod.estimates.made()
    back = load_product(prod.save(tmp_path / "c"))
    for name in ("flat_G", "flat_O"):
        assert back.maps[name].tobytes() == prod.maps[name].tobytes()
    ff = flat_field_from_session(open_session(root), base="auto")
    src = sorted((root / "nzdi").glob("flat_*.tif"))[0]
    [out] = apply_product(back, [src], tmp_path / "out")
    np.testing.assert_array_equal(read_image(out), ff.correct(read_image(src)))
