"""Tests of the change-scene simulator (Tsin, Ramesh & Kanade 2001, sec. 5, eq. 20)."""
from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from ccdcore.errors import CcdError
from ccdcore.io.frames import read_header, read_image
from ccdcore.simulate import change, load_truth
from ccdcore.simulate import simulate as simulate_preset


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("change")
    truth = simulate_preset("change", root, seed=0)
    return root, truth


def test_manifest_and_truth_keys(scene):
    root, truth = scene
    manifest = tomllib.loads((root / "session.toml").read_text())
    assert load_truth(root).values == truth
    assert manifest["camera"]["layout"] == "rgb" and manifest["camera"]["bits"] == 8
    roles = [f["role"] for f in manifest["frames"]]
    assert roles == ["reference"] * 7 + ["target"] * 7
    for role in ("reference", "target"):
        exp = np.array([f["exposure"] for f in manifest["frames"] if f["role"] == role])
        np.testing.assert_allclose(exp[1:] / exp[:-1], 2.0, rtol=1e-12)
        np.testing.assert_array_equal(exp, truth["t"])
    for key in ("M", "M_shadows", "objects", "areas", "masks", "g", "gamma", "t", "reference",
                "target", "sigma_s", "sigma_c1", "sigma_c2", "maps", "shadow_labels"):
        assert key in truth
    assert np.array(truth["M"]).shape == (3, 3)
    assert np.array(truth["M_shadows"]).shape == (2, 3, 3)
    assert len(truth["g"]) == 256
    assert truth["maps"] == {"E": "truth/E.exr", "E_target": "truth/E_target.exr"}
    for entry in manifest["frames"]:
        z = read_image(root / entry["path"])
        assert z.dtype == np.uint8 and z.shape == (96, 128, 3)
        assert read_header(root / entry["path"]).exposure == pytest.approx(entry["exposure"])


def _masks(root, truth):
    t = load_truth(root)
    assert t.values == truth
    return t.map("masks.change"), t.map("masks.shadow")


def test_masks_have_the_expected_areas(scene):
    root, truth = scene
    cm, sm = _masks(root, truth)
    assert cm.dtype == np.uint8 and sm.dtype == np.uint8
    assert cm.shape == sm.shape == (96, 128)
    assert set(np.unique(cm)) == {0, 1} and set(np.unique(sm)) == {0, 1, 2}
    assert not np.any((cm > 0) & (sm > 0))                      # disjoint
    objects = truth["objects"]
    assert len(objects) == 3
    assert int(cm.sum()) == sum(o["area"] for o in objects) == truth["areas"]["change"]
    for o in objects:
        box = cm[o["y"]:o["y"] + o["h"], o["x"]:o["x"] + o["w"]]
        assert int(box.sum()) == o["area"]
        if o["shape"] == "rectangle":
            assert o["area"] == o["w"] * o["h"]
        else:   # digitised ellipse: area pi w h / 4 up to about a perimeter of pixels
            assert abs(o["area"] - math.pi * o["w"] * o["h"] / 4) < math.pi * (o["w"] + o["h"]) / 2
        # the cast shadow is the object shifted by (dx, dy), minus the object itself
        obj = np.zeros_like(cm, bool)
        obj[o["y"]:o["y"] + o["h"], o["x"]:o["x"] + o["w"]] = box > 0
        shifted = np.roll(obj, (o["shadow_dy"], o["shadow_dx"]), axis=(0, 1))
        assert np.all(sm[shifted & ~obj] == 1)
    for label in (1, 2):
        assert int(np.count_nonzero(sm == label)) == truth["areas"]["shadow"][str(label)]
    # shade 2 is a band of mean width 20 % of the frame (minus objects and cast shadows on it)
    assert 0.1 < np.count_nonzero(sm == 2) / sm.size < 0.2


def test_truth_radiance_obeys_the_transforms(scene):
    root, truth = scene
    cm, sm = _masks(root, truth)
    E = load_truth(root).map("E").astype(float)
    Et = load_truth(root).map("E_target").astype(float)
    assert E.shape == (96, 128, 3) and E.min() > 0
    transforms = [truth["M"], *truth["M_shadows"]]
    for label, M in enumerate(transforms):
        sel = (cm == 0) & (sm == label)
        M_hat = np.linalg.lstsq(E[sel], Et[sel], rcond=None)[0]
        # only the float32 rounding of the stored maps separates them (relative 6e-8)
        np.testing.assert_allclose(M_hat, M, atol=1e-5)
    # objects are new radiance, unrelated to E M
    pred = E @ np.array(truth["M"])
    for o in truth["objects"]:
        box = (slice(o["y"], o["y"] + o["h"]), slice(o["x"], o["x"] + o["w"]))
        inside = cm[box] > 0
        rel = np.linalg.norm(Et[box][inside] - pred[box][inside], axis=1) / np.linalg.norm(
            pred[box][inside], axis=1)
        assert np.median(rel) > 0.1


def _linearise(root, truth, role):
    """Inverse-variance weighted radiance from a bracket (eqs. 9, 18 with the true g, a, b)."""
    g = np.array(truth["g"])
    gprime = np.gradient(g)
    num = den = 0.0
    for k, path in enumerate(truth[role]["frames"]):
        z = read_image(root / path).astype(int)
        a, b = np.array(truth[role]["a"][k]), np.array(truth[role]["b"][k])
        v = g[z]
        var = (truth["sigma_s"] ** 2 * np.maximum(v - b, 0) + truth["sigma_c1"] ** 2
               + gprime[z] ** 2 * truth["sigma_c2"] ** 2) / a ** 2          # eq. 7, in E units
        w = np.where((z >= 5) & (z <= 250), 1.0 / var, 0.0)
        num = num + w * (v - b) / a
        den = den + w
    assert np.all(den > 0)
    return num / den, 1.0 / den


def test_frames_relate_by_the_colour_transforms(scene):
    root, truth = scene
    cm, sm = _masks(root, truth)
    R, var_r = _linearise(root, truth, "reference")
    T, _ = _linearise(root, truth, "target")
    for label, M in enumerate([truth["M"], *truth["M_shadows"]]):
        M = np.array(M)
        sel = (cm == 0) & (sm == label)
        X, Y = R[sel], T[sel]
        # eq. 20 by least squares, with the errors-in-variables correction: the noise of the
        # reference radiance adds sum(var) to X^T X (it would shrink M by ~1 % otherwise)
        A = X.T @ X - np.diag(var_r[sel].sum(axis=0))
        M_hat = np.linalg.solve(A, X.T @ Y)
        resid = Y - X @ M_hat
        s2 = (resid ** 2).sum(axis=0) / (len(X) - 3)
        se = np.sqrt(np.outer(np.diag(np.linalg.inv(A)), s2))    # SE of each element
        assert np.all(np.abs(M_hat - M) < 5 * se), (label, (M_hat - M) / se)
        assert se.max() < 0.01
        # and the background transform does not explain the shadows (or vice versa)
        if label:
            assert np.abs(M_hat - np.array(truth["M"])).max() > 0.2


def test_same_seed_same_bytes(tmp_path):
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        simulate_preset("change", tmp_path / name, seed=seed, size=(48, 32), n_objects=2)
    files = {}
    for name in "abc":
        root = tmp_path / name
        files[name] = {p.relative_to(root).as_posix(): p.read_bytes()
                       for p in sorted(root.rglob("*")) if p.is_file()}
    assert len(files["a"]) == 2 + 2 + 2 + 14      # manifest, truth, 2 maps, 2 masks, 14 frames
    assert files["a"] == files["b"]
    assert files["a"]["target/k03.tif"] != files["c"]["target/k03.tif"]


def test_options(tmp_path):
    M = np.diag([1.5, 1.0, 0.5])
    truth = simulate_preset("change", tmp_path, seed=1, size=(64, 48), n_objects=1,
                            band_fraction=0.0, M=M, white_balance=True, bayer="rggb")
    assert truth["M"] == M.tolist() and len(truth["objects"]) == 1
    assert truth["areas"]["shadow"]["2"] == 0 and truth["bayer"] == "rggb"
    assert set(truth["maps"]) == {"E", "E_target", "E_effective", "E_target_effective"}
    a = np.array(truth["target"]["a"])
    assert a.shape == (7, 3) and not np.allclose(a, np.array(truth["t"])[:, None])


@pytest.mark.parametrize("options", [
    {"M": np.eye(2)}, {"M_shadows": [np.eye(3)]}, {"n_colours": 2}, {"bayer": "xxxx"},
    {"unknown": 1}, {"n_objects": 40},
])
def test_bad_options_raise(tmp_path, options):
    with pytest.raises(CcdError):
        simulate_preset("change", tmp_path, seed=0, size=(32, 24), **options)


def test_apply_transform_uses_row_vectors():
    E = np.array([[1.0, 0.0, 0.0]])
    M = np.arange(9.0).reshape(3, 3)
    np.testing.assert_array_equal(change.apply_transform(E, M), [[0.0, 1.0, 2.0]])  # first row


def test_frame_pair_is_a_video_pair_with_truth(tmp_path):
    """The single-frame pairs (ccdcore.simulate.change_frames): 8-bit frames, reproducible for a
    seed, an illumination change with automatic gain, the truth mask of the inserted objects,
    a plain session folder without exposure; the change preset's bytes are not touched."""
    import json

    from ccdcore.session import open_session
    from ccdcore.simulate.change_frames import frame_pair, write_frame_pair

    a, b = frame_pair(4, n_reference=2), frame_pair(4, n_reference=2)
    assert all(np.array_equal(x, y) for x, y in zip(a["reference"], b["reference"]))
    assert len(a["reference"]) == 2 and len(a["target"]) == 1
    z = a["reference"][0]
    assert z.dtype == np.uint8 and z.shape == (128, 160, 3)
    assert not np.array_equal(a["reference"][0], a["reference"][1])      # own noise each
    bg = ~a["mask"]
    assert a["target"][0][bg].mean() < z[bg].mean() - 10                  # the light dimmed
    assert 0 < a["mask"].sum() < 0.3 * a["mask"].size
    assert not frame_pair(4, n_objects=0)["mask"].any()
    truth = write_frame_pair(tmp_path / "p", 4)
    assert json.loads((tmp_path / "p" / "truth.json").read_text()) == truth
    s = open_session(tmp_path / "p")
    assert s.roles() == {"reference": 1, "target": 1}
    assert np.load(tmp_path / "p" / "truth" / "change_mask.npy").sum() == truth["changed_pixels"]
    with pytest.raises(CcdError, match="unknown option"):
        frame_pair(0, colour=1)
