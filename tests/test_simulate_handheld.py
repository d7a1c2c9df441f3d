"""The handheld bracket of ``tsin01`` (:mod:`ccdcore.simulate.handheld`): camera shake between
frames (a shift and a rotation per frame, the middle frame still) and objects moving through the
scene, with the truth an alignment step and a moving-object test of the HDR merge compare with.

Convention pinned here: the scene point at reference pixel p appears in frame k at
q = c + R(theta)(p - c) + (dx, dy), so aligned(x, y) = frame(x + dx, y + dy) for theta = 0.
"""
from __future__ import annotations

import hashlib
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from ccdcore.errors import CcdError
from ccdcore.io.frames import read_image
from ccdcore.simulate import handheld, load_truth, tsin
from ccdcore.simulate import simulate as simulate_preset

SIZE = (160, 120)                       # (width, height)
SHAPE = (SIZE[1], SIZE[0])              # (H, W)


def _hashes(root: Path) -> dict[str, str]:
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def _smooth_scene(shape, seed=0, sigma=6.0):
    """A smooth test radiance (bilinear interpolation error is small on it)."""
    rng = np.random.default_rng(seed)
    return 1.0 + ndimage.gaussian_filter(rng.standard_normal(shape), sigma, mode="reflect") * 5.0


# ---------------------------------------------------------------------------------------------
# pure functions


def test_frame_transforms_reference_exact_and_others_drawn():
    tr = handheld.frame_transforms(np.random.default_rng(1), 9, 3.0, 0.2)
    assert len(tr) == 9
    assert tr[4] == (0.0, 0.0, 0.0)
    others = np.array([t for k, t in enumerate(tr) if k != 4])
    assert np.all(others != 0.0)
    assert 0.5 < np.std(others[:, :2]) < 6.0 and 0.02 < np.std(others[:, 2]) < 0.5
    # another reference: the others' draws do not depend on which frame is the reference
    tr0 = handheld.frame_transforms(np.random.default_rng(1), 9, 3.0, 0.2, reference=0)
    assert tr0[0] == (0.0, 0.0, 0.0) and tr0[1:4] == tr[1:4] and tr0[5:] == tr[5:]
    # zero sigmas: every transform is the identity, with no -0.0
    zero = handheld.frame_transforms(np.random.default_rng(1), 4, 0.0, 0.0)
    assert all(math.copysign(1.0, v) == 1.0 for t in zero for v in t)
    with pytest.raises(CcdError):
        handheld.frame_transforms(np.random.default_rng(1), 4, 1.0, 0.0, reference=4)


def test_cos_sin_deg_is_the_library_cos_and_sin():
    for deg in (0.0, 0.2, -0.37, 1.0, 45.0, -90.0, 179.9, 200.0, -725.5):
        c, s = handheld.cos_sin_deg(deg)
        assert c == pytest.approx(math.cos(math.radians(deg)), abs=2e-15)
        assert s == pytest.approx(math.sin(math.radians(deg)), abs=2e-15)


def test_warp_scene_sign_convention_on_an_integer_shift():
    m = 6
    rng = np.random.default_rng(2)
    E = rng.random((SHAPE[0] + 2 * m, SHAPE[1] + 2 * m, 3))
    dx, dy = 3.0, -2.0
    F = handheld.warp_scene(E, (dx, dy, 0.0), SHAPE, m)
    # frame(q) = reference(q - d): the content moved by +d ...
    ref = E[m:m + SHAPE[0], m:m + SHAPE[1]]
    y0, x0 = m - int(dy), m - int(dx)
    np.testing.assert_array_equal(F, E[y0:y0 + SHAPE[0], x0:x0 + SHAPE[1]])
    # ... so aligned(x, y) = frame(x + dx, y + dy) is the reference
    np.testing.assert_array_equal(F[10 + int(dy):-10 + int(dy), 10 + int(dx):-10 + int(dx)],
                                  ref[10:-10, 10:-10])
    # the identity is an exact crop
    np.testing.assert_array_equal(handheld.warp_scene(E, (0.0, 0.0, 0.0), SHAPE, m), ref)
    # the matrix maps a reference pixel to where it appears in the frame
    M = np.array(handheld.transform_matrix((dx, dy, 0.0), SHAPE))
    assert M @ [40.0, 30.0, 1.0] == pytest.approx([43.0, 28.0])


def test_warp_scene_rotation_direction_and_matrix():
    """Positive theta turns +x towards +y: a point right of the centre moves down."""
    m = 12
    h, w = SHAPE
    E = np.zeros((h + 2 * m, w + 2 * m))
    c = ((w - 1) / 2, (h - 1) / 2)
    px, py = 139.5, 59.5                       # 60 px right of the centre, on its row
    E[int(py) + m:int(py) + m + 2, int(px) + m:int(px) + m + 2] = 1.0   # a 2x2 block
    theta = 3.0
    F = handheld.warp_scene(E, (0.0, 0.0, theta), SHAPE, m)
    yy, xx = np.mgrid[0:h, 0:w]
    cy, cx = (F * yy).sum() / F.sum(), (F * xx).sum() / F.sum()
    M = np.array(handheld.transform_matrix((0.0, 0.0, theta), SHAPE))
    qx, qy = M @ [px, py, 1.0]
    assert qy > py + 2.5                        # moved down by 60 sin(3 deg) = 3.1 px
    assert (cx, cy) == pytest.approx((qx, qy), abs=0.05)
    assert (qx, qy) == pytest.approx((c[0] + 60 * math.cos(math.radians(theta)),
                                      c[1] + 60 * math.sin(math.radians(theta))), abs=1e-9)


def test_bilinear_warp_is_map_coordinates_order_1():
    m = 10
    E = np.random.default_rng(3).random((SHAPE[0] + 2 * m, SHAPE[1] + 2 * m))
    tr = (2.37, -1.61, 0.43)
    F = handheld.warp_scene(E, tr, SHAPE, m)
    cos, sin = math.cos(math.radians(tr[2])), math.sin(math.radians(tr[2]))
    cx, cy = (SHAPE[1] - 1) / 2, (SHAPE[0] - 1) / 2
    yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]].astype(float)
    u, v = xx - tr[0] - cx, yy - tr[1] - cy
    X, Y = cx + cos * u + sin * v + m, cy - sin * u + cos * v + m
    expected = ndimage.map_coordinates(E, [Y, X], order=1, mode="reflect")
    np.testing.assert_allclose(F, expected, rtol=0, atol=1e-12)
    F3 = handheld.warp_scene(E, tr, SHAPE, m, order=3)
    np.testing.assert_allclose(F3, ndimage.map_coordinates(E, [Y, X], order=3, mode="reflect"))


def test_margin_is_never_exceeded():
    tr = handheld.frame_transforms(np.random.default_rng(4), 12, 8.0, 1.5)
    m = handheld.margin_for(tr, SHAPE)
    assert m > 8
    assert handheld.margin_for([(0.0, 0.0, 0.0)] * 3, SHAPE) == 0
    # on a ramp a reflected sample would break linearity: every frame's warp stays exact
    ramp_x = np.broadcast_to(np.arange(SHAPE[1] + 2 * m, dtype=float), (SHAPE[0] + 2 * m,
                                                                        SHAPE[1] + 2 * m))
    for t in tr:
        M = np.array(handheld.transform_matrix(t, SHAPE))
        F = handheld.warp_scene(ramp_x, t, SHAPE, m)
        # the frame's pixel q sees reference x = (A^-1 (q - t))_x
        A, b = M[:, :2], M[:, 2]
        yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]].astype(float)
        p = np.linalg.solve(A, np.stack([xx.ravel() - b[0], yy.ravel() - b[1]]))
        np.testing.assert_allclose(F.ravel(), p[0] + m, atol=1e-9)


@pytest.mark.parametrize("transform", [(2.7, -1.3, 0.0), (-3.4, 2.2, 0.35), (0.6, 4.1, -0.5)])
def test_a_frame_warped_back_with_the_documented_inverse_is_the_reference(transform):
    m = handheld.margin_for([transform], SHAPE)
    E = _smooth_scene((SHAPE[0] + 2 * m, SHAPE[1] + 2 * m, 3))
    ref = handheld.warp_scene(E, (0.0, 0.0, 0.0), SHAPE, m)
    frame = handheld.warp_scene(E, transform, SHAPE, m)
    aligned = handheld.align_frame(frame, transform)
    inner = (slice(m, -m), slice(m, -m))        # away from the border the frame never saw
    err = aligned[inner] - ref[inner]
    spread = float(ref.std())
    assert float(np.sqrt(np.mean(err ** 2))) < 0.02 * spread     # bilinear, twice
    assert float(np.max(np.abs(err))) < 0.06 * spread
    # the other sign does not align (the truth's sign is the aligner's)
    wrong = handheld.align_frame(frame, (-transform[0], -transform[1], -transform[2]))
    assert float(np.sqrt(np.mean((wrong[inner] - ref[inner]) ** 2))) > 0.3 * spread
    # with theta = 0 the inverse is the plain shift frame(x + dx, y + dy)
    if transform[2] == 0.0:
        dx, dy = transform[:2]
        yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]].astype(float)
        shifted = np.stack([ndimage.map_coordinates(frame[..., c], [yy + dy, xx + dx], order=1,
                                                    mode="reflect") for c in range(3)], axis=2)
        np.testing.assert_allclose(shifted, aligned, atol=1e-12)


def test_movers_move_by_speed_and_occlude():
    n, speed = 5, 12.0
    masks, rad, items = handheld.movers(np.random.default_rng(5), 1, n, SHAPE, 0.12, speed,
                                        level=0.3)
    assert masks.shape == (n,) + SHAPE and masks.dtype == bool
    assert rad.shape == (n,) + SHAPE + (3,)
    assert np.all(rad[~masks] == 0.0) and np.all(rad[masks] > 0.0)
    # its height is mover_size x H, its pixels the same in every frame (to discretisation)
    counts = masks.sum(axis=(1, 2))
    assert np.ptp(counts) <= 0.1 * counts.mean()
    rows = np.nonzero(masks[n // 2].any(axis=1))[0]
    assert rows.size == pytest.approx(0.12 * SHAPE[0], abs=2)
    yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    cent = np.array([[(xx * m).sum() / m.sum(), (yy * m).sum() / m.sum()] for m in masks])
    steps = np.hypot(*np.diff(cent, axis=0).T)
    np.testing.assert_allclose(steps, speed, atol=0.3)
    np.testing.assert_allclose(cent[n // 2], items[0].centre, atol=0.3)
    # uniform colour with a little texture
    patch = rad[0][masks[0]]
    rel = patch / np.median(patch, axis=0)
    assert 0.02 < float(rel.std()) < 0.15


# ---------------------------------------------------------------------------------------------
# the tsin01 sessions


def _session(tmp_path, name, **options):
    kw = {"seed": 11, "size": SIZE, "n_exposures": 5, "layout": "rgb"}
    kw.update(options)
    root = tmp_path / name
    return root, simulate_preset("tsin01", root, **kw)


def test_truth_holds_transforms_convention_and_mover_masks(tmp_path):
    root, truth = _session(tmp_path, "hh", handheld_shift=3.0, handheld_rotation=0.2, movers=1)
    manifest = tomllib.loads((root / "session.toml").read_text())
    files = [f["path"] for f in manifest["frames"]]
    tr = truth["transforms"]
    assert [t["file"] for t in tr] == files and [t["index"] for t in tr] == list(range(5))
    assert truth["handheld"]["convention"] == handheld.CONVENTION
    assert "aligned(x, y) = frame(x + dx, y + dy)" in truth["handheld"]["convention"]
    assert truth["handheld"]["reference"] == files[2] == "bracket/s0_k02.tif"
    assert (tr[2]["dx"], tr[2]["dy"], tr[2]["rotation_deg"]) == (0.0, 0.0, 0.0)
    assert all(abs(t["dx"]) > 0 and abs(t["rotation_deg"]) > 0 for k, t in enumerate(tr) if k != 2)
    # the transforms are the seed's own stream's
    drawn = handheld.frame_transforms(np.random.default_rng([11, 3]), 5, 3.0, 0.2)
    assert [(t["dx"], t["dy"], t["rotation_deg"]) for t in tr] == drawn
    for t in tr:
        assert np.allclose(t["matrix"], handheld.transform_matrix(drawn[t["index"]], SHAPE))
    own = np.load(root / "truth" / "movers.npy")
    aligned = np.load(root / "truth" / "movers_aligned.npy")
    moving = np.load(root / "truth" / "moving_mask.npy")
    assert own.shape == aligned.shape == (5,) + SHAPE and moving.shape == SHAPE
    assert own.dtype == aligned.dtype == moving.dtype == bool
    np.testing.assert_array_equal(moving, aligned.any(axis=0))
    np.testing.assert_array_equal(own[2], aligned[2])        # the reference's grid is its own
    mv = truth["movers"]
    assert mv["pixels"] == [int(m.sum()) for m in own] and mv["shape"] == [5, *SHAPE]
    assert mv["moving_pixels"] == int(moving.sum()) > 0
    t = load_truth(root)
    assert t.map("scene_margin").shape == (SHAPE[0] + 2 * t["handheld"]["margin"],
                                           SHAPE[1] + 2 * t["handheld"]["margin"], 3)
    assert not any(p.suffix == ".png" for p in (root / "truth").iterdir())


def test_frames_see_the_warped_scene(tmp_path):
    """Without noise each frame is exactly f(a_k warp(scene, T_k)): the frames follow the
    documented transform (sign included), and the reference frame is the plain crop."""
    quiet = {"sigma_s": 0.0, "sigma_c1": 0.0, "sigma_c2": 0.0}
    root, truth = _session(tmp_path, "q", handheld_shift=4.0, handheld_rotation=0.3, **quiet)
    t = load_truth(root)
    scene = np.asarray(t.map("scene_margin"), dtype=np.float64)
    m = truth["handheld"]["margin"]
    E = np.asarray(t.map("E"))
    np.testing.assert_array_equal(E, scene[m:m + SHAPE[0], m:m + SHAPE[1]].astype(np.float32))
    for tr, frame in zip(truth["transforms"], truth["frames"]):
        Ek = handheld.warp_scene(scene, (tr["dx"], tr["dy"], tr["rotation_deg"]), SHAPE, m)
        Ek = Ek.astype(np.float32).astype(np.float64)
        expected = np.rint(tsin.response(np.minimum(frame["a"] * Ek, 1.0), 1.2))
        expected[frame["a"] * Ek >= 1.0] = 255
        z = read_image(root / tr["file"])
        np.testing.assert_array_equal(z, expected.astype(np.uint8))
        if tr["index"] != 2:
            assert np.mean(z != read_image(root / truth["handheld"]["reference"])) > 0.3


def test_movers_alone_change_only_their_pixels(tmp_path):
    """Movers without camera shake: the frames are the static session's outside the movers'
    masks (the scene and the noise are the same), and moving_mask is the masks' union."""
    plain_root, _ = _session(tmp_path, "plain")
    root, truth = _session(tmp_path, "movers", movers=2, mover_speed=10.0)
    assert truth["handheld"]["margin"] == 0 and truth["handheld"]["scene_map"] is None
    assert all((t["dx"], t["dy"], t["rotation_deg"]) == (0.0, 0.0, 0.0)
               for t in truth["transforms"])
    own = np.load(root / "truth" / "movers.npy")
    np.testing.assert_array_equal(own, np.load(root / "truth" / "movers_aligned.npy"))
    np.testing.assert_array_equal(np.load(root / "truth" / "moving_mask.npy"), own.any(axis=0))
    np.testing.assert_array_equal(read_image(root / "truth" / "E.exr"),
                                  read_image(plain_root / "truth" / "E.exr"))
    for k, f in enumerate(truth["frames"]):
        z, z0 = read_image(root / f["path"]), read_image(plain_root / f["path"])
        np.testing.assert_array_equal(z[~own[k]], z0[~own[k]])
        assert own[k].sum() > 50
        assert np.any(z[own[k]] != z0[own[k]])
    # each mover's track moves by mover_speed per frame
    for track in truth["movers"]["tracks"]:
        steps = np.hypot(*np.diff(np.array(track["centre"]), axis=0).T)
        np.testing.assert_allclose(steps, 10.0, rtol=1e-9)


def test_real_camera_handheld_session(tmp_path):
    """The JPEG camera with shake and a mover: the options go through the bundle, are recorded
    when set, and the same seed gives the same bytes."""
    kw = {"seed": 3, "size": SIZE, "handheld_shift": 3.0, "handheld_rotation": 0.2,
          "movers": 1}
    a = simulate_preset("tsin01-camera", tmp_path / "a", **kw)
    simulate_preset("tsin01-camera", tmp_path / "b", **kw)
    assert _hashes(tmp_path / "a") == _hashes(tmp_path / "b")
    assert len(a["transforms"]) == 10 and a["handheld"]["reference"] == "bracket/s0_k05.tif"
    opts = a["camera_model"]["options"]
    assert opts["handheld_shift"] == 3.0 and opts["movers"] == 1 and "mover_speed" not in opts
    assert np.load(tmp_path / "a" / "truth" / "movers.npy").shape == (10,) + SHAPE
    # E.exr is the reference frame's crop of scene_margin.exr, vignetted (vignetting.exr is
    # the float64 map rounded to float32)
    t = load_truth(tmp_path / "a")
    m = a["handheld"]["margin"]
    crop = np.asarray(t.map("scene_margin"), dtype=np.float64)[m:m + SHAPE[0], m:m + SHAPE[1]]
    V = np.asarray(t.map("vignetting"), dtype=np.float64)
    np.testing.assert_allclose(t.map("E"), crop * V[..., None], rtol=3e-7, atol=0)


def test_default_options_leave_the_camera_preset_unchanged(tmp_path):
    kw = {"seed": 1994, "size": (96, 64)}
    plain = simulate_preset("tsin01-camera", tmp_path / "plain", **kw)
    with_defaults = simulate_preset("tsin01-camera", tmp_path / "defaults", handheld_shift=0,
                                    handheld_rotation=0.0, movers=0, mover_size=0.12,
                                    mover_speed=12, **kw)
    assert _hashes(tmp_path / "plain") == _hashes(tmp_path / "defaults")
    assert plain == with_defaults
    assert not {"transforms", "handheld", "movers"} & set(plain)
    assert not set(handheld.DEFAULTS) & set(plain["camera_model"]["options"])
    assert not (tmp_path / "plain" / "truth" / "movers.npy").exists()


@pytest.mark.parametrize("options", [{"handheld_shift": -1.0}, {"handheld_rotation": -0.1},
                                     {"movers": -1}, {"movers": 1.5}, {"movers": True},
                                     {"mover_size": 0.0}, {"mover_size": 1.5},
                                     {"mover_speed": -2.0}, {"handheld_shiftt": 1.0}])
def test_bad_options_raise(tmp_path, options):
    with pytest.raises(CcdError):
        simulate_preset("tsin01", tmp_path / "x", size=(32, 24), **options)
