"""Registration of hand-held brackets (ccdcore.response.align) on synthetic brackets.

Every bracket is drawn here: a textured radiance scene larger than the frame (smoothed noise on
two scales plus rectangles), seen at exposures a factor 4 apart through an sRGB tone curve,
clipped at 0 and the top code, with a little noise; each frame is sampled from the scene (cubic
spline) at a known shift and rotation, with the convention of the module: the scene point at
``p`` of the reference lies at ``c + R(θ)(p - c) + (dx, dy)`` of the frame.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import ndimage

from ccdcore.errors import CcdError
from ccdcore.response.align import Alignment, FrameShift, apply_alignment, estimate_alignment

SHAPE = (384, 512)          # (H, W) of the frames
ORIGIN = (60, 60)           # where the reference's top-left pixel lies in the scene


def make_scene(seed: int, shape=(520, 640)) -> np.ndarray:
    """A radiance map: log-normal texture (fine and coarse) plus rectangles (edges)."""
    rng = np.random.default_rng(seed)
    fine = ndimage.gaussian_filter(rng.standard_normal(shape), 2.0)
    coarse = ndimage.gaussian_filter(rng.standard_normal(shape), 20.0)
    loge = 0.35 * fine / fine.std() + 0.4 * coarse / coarse.std()
    for _ in range(12):
        y, x = rng.integers(0, shape[0] - 40), rng.integers(0, shape[1] - 40)
        h, w = rng.integers(15, 80, 2)
        loge[y:y + h, x:x + w] += rng.choice([-0.4, 0.4])
    return 10 ** ndimage.gaussian_filter(loge, 0.7)


def render(scene, dx=0.0, dy=0.0, rot=0.0, t=1.0, rng=None, *, noise=1.0, top=255,
           dtype=np.uint8, gains=None):
    """One frame: the scene moved by (dx, dy) and turned by ``rot`` degrees against the
    reference, exposed ``t`` (sRGB curve, clipped), ``noise`` codes of Gaussian noise unless
    ``rng`` is None; ``gains`` makes a colour frame (one factor per channel)."""
    H, W = SHAPE
    cy, cx = (H - 1) / 2, (W - 1) / 2
    c, s = np.cos(np.radians(rot)), np.sin(np.radians(rot))
    qy, qx = np.mgrid[0:H, 0:W].astype(float)
    X, Y = qx - cx - dx, qy - cy - dy                 # p = c + R⁻¹ (q - c - t)
    px, py = cx + c * X + s * Y, cy - s * X + c * Y
    E = ndimage.map_coordinates(scene, [py + ORIGIN[0], px + ORIGIN[1]], order=3,
                                mode="nearest")
    v = np.clip(E * t / 4.0, 0, None)
    z = top * np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(v, 1 / 2.4) - 0.055)
    if gains is not None:
        z = np.stack([z * g for g in gains], axis=-1)
    if rng is not None:
        z = z + rng.normal(0, noise, z.shape)
    return np.clip(np.rint(z), 0, top).astype(dtype)


def rank_image(frame: np.ndarray) -> np.ndarray:
    """Histogram equalisation of a frame's luminance (the exposure-invariant image)."""
    lum = frame.astype(float) if frame.ndim == 2 else frame.astype(float).sum(axis=2)
    order = np.argsort(lum, axis=None, kind="stable")
    r = np.empty(lum.size)
    r[order] = np.arange(lum.size) / lum.size
    return r.reshape(lum.shape)


def gradient_correlation(a, b, mask, top=255) -> float:
    """Correlation of the gradients of two frames' rank images over ``mask`` and the pixels
    unclipped in both."""
    use = ndimage.binary_erosion(mask & (a > 0) & (a < top) & (b > 0) & (b < top), iterations=2)
    ga, gb = np.gradient(rank_image(a)), np.gradient(rank_image(b))
    x = np.concatenate([ga[0][use], ga[1][use]])
    y = np.concatenate([gb[0][use], gb[1][use]])
    return float(np.corrcoef(x, y)[0, 1])


def check_shift(s: FrameShift, dx, dy, rot=None, slack=0.05):
    """The shift (and rotation) within 3 stated sigmas plus ``slack`` of the truth."""
    assert s.registered, s.reason
    assert abs(s.dx - dx) <= 3 * s.dx_err + slack, (s, dx)
    assert abs(s.dy - dy) <= 3 * s.dy_err + slack, (s, dy)
    if rot is not None:
        assert abs(s.rotation - rot) <= 3 * s.rotation_err + 0.01, (s, rot)


@pytest.fixture(scope="module")
def scene():
    return make_scene(7)


#: (dx, dy, rotation °) of each frame of the hand-held bracket; index 2 is the reference
HAND_HELD = [(2.3, -1.7, 0.0), (-0.6, 3.45, -0.4), (0.0, 0.0, 0.0), (-3.6, 4.2, 0.6)]
EXPOSURES = [1 / 16, 1 / 4, 1.0, 4.0]
NAMES = ["IMG_0001.JPG", "IMG_0002.JPG", "IMG_0003.JPG", "IMG_0004.JPG"]


@pytest.fixture(scope="module")
def hand_held(scene):
    rng = np.random.default_rng(11)
    frames = [render(scene, dx, dy, r, t, rng) for (dx, dy, r), t in zip(HAND_HELD, EXPOSURES)]
    return frames, estimate_alignment(frames, NAMES)


def test_shifts_and_rotations_are_recovered_within_their_errors(hand_held):
    frames, al = hand_held
    assert al.reference == 2                                  # the middle frame (len // 2)
    assert len(al.shifts) == 4 and [s.name for s in al.shifts] == NAMES
    ref = al.shifts[2]
    assert (ref.dx, ref.dy, ref.rotation, ref.applied, ref.registered) == (0, 0, 0, False, True)
    for s, (dx, dy, rot) in zip(al.shifts, HAND_HELD):
        check_shift(s, dx, dy, rot)
        if s is not ref:
            assert 0 < s.dx_err < 0.2 and 0 < s.dy_err < 0.2 and 0 < s.rotation_err < 0.05
            assert s.applied
    assert al.shifts[0].rotation == 0.0                       # no rotation: reported as 0
    assert abs(al.shifts[3].rotation - 0.6) < 0.02 and abs(al.shifts[1].rotation + 0.4) < 0.02
    assert al.any_applied and al.left_out == ()
    text = al.describe()
    assert text.startswith("3 of 4 frames aligned to IMG_0003.JPG: IMG_0001.JPG by (+2.30, "
                           "-1.70) px")
    assert text.endswith("; 0 left out")
    assert "IMG_0004.JPG by (-3.60, +4.20) px and +0.60" in text


def test_the_sign_convention_and_apply_moves_the_frame_back(scene):
    """A frame whose content moved by (+3, -2) (right and up) reports dx = +3, dy = -2, and
    apply_alignment brings it back onto the true scene crop: aligned(x, y) = frame(x + 3, y - 2)."""
    rng = np.random.default_rng(3)
    ref = render(scene, 0, 0, 0, 1.0, rng)
    moved = render(scene, 3.0, -2.0, 0, 0.25, rng)
    al = estimate_alignment([ref, moved], ["ref.png", "moved.png"], reference=0)
    s = al.shifts[1]
    check_shift(s, 3.0, -2.0)
    assert s.dx > 2.9 and s.dy < -1.9 and s.applied
    # the content is where the convention says: moved[y, x] == true[y + 2, x - 3]
    true = render(scene, 0, 0, 0, 0.25)                       # no noise: the scene itself
    assert np.abs(moved[:-2, 3:].astype(int) - true[2:, :-3]).mean() < 1.5
    aligned, valid = apply_alignment([ref, moved], al)
    assert aligned[0] is ref
    assert aligned[1].dtype == np.uint8 and aligned[1].shape == moved.shape
    err_after = np.abs(aligned[1].astype(int) - true)[valid].mean()
    err_before = np.abs(moved.astype(int) - true)[valid].mean()
    assert err_after < 1.5 < 5 < err_before
    # the frame's data ends 3 columns before the right edge and 2 rows below the top
    assert not valid[:, -3:].any() and valid[2:, :-3].all()
    assert not valid[:2, :].any()


def test_apply_aligns_the_rank_images_and_masks_the_border(hand_held):
    frames, al = hand_held
    aligned, valid = apply_alignment(frames, al)
    ref = frames[2]
    assert aligned[2] is ref
    for k in (0, 1, 3):
        assert aligned[k].dtype == frames[k].dtype and aligned[k].shape == frames[k].shape
        before = gradient_correlation(frames[k], ref, valid)
        after = gradient_correlation(aligned[k], ref, valid)
        assert after > 0.9 and before < 0.6, (k, before, after)
    # the valid border is about the largest shift (and the rotation's reach) wide
    H, W = SHAPE
    assert valid[40:-40, 40:-40].all()
    assert not valid[:, -3:].any()            # frame 0 (dx = +2.3) has no data there
    assert not valid[-4:, :].any()            # frame 3 (dy = +4.2) neither
    assert 0.85 < valid.mean() < 0.99


def test_the_mask_and_the_values_are_those_of_scipy_affine_transform(hand_held):
    """apply_alignment samples every channel bilinearly at c + R(θ)(p - c) + (dx, dy):
    the values of scipy.ndimage.affine_transform(order=1) (to the rounding of a code), and a
    pixel is valid exactly when that point lies inside the frame."""
    frames, al = hand_held
    s = al.shifts[3]
    aligned, valid = apply_alignment([frames[3], frames[2]], Alignment(1, (s, al.shifts[2])))
    th = np.radians(s.rotation)
    M = np.array([[np.cos(th), np.sin(th)], [-np.sin(th), np.cos(th)]])
    centre = np.array([(SHAPE[0] - 1) / 2, (SHAPE[1] - 1) / 2])
    offset = centre + np.array([s.dy, s.dx]) - M @ centre
    want = ndimage.affine_transform(frames[3].astype(float), M, offset=offset, order=1,
                                    mode="nearest")
    assert np.abs(aligned[0] - np.rint(want)).max() <= 1
    yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    sy = M[0, 0] * yy + M[0, 1] * xx + offset[0]
    sx = M[1, 0] * yy + M[1, 1] * xx + offset[1]
    inside = (sy >= -1e-6) & (sy <= SHAPE[0] - 1 + 1e-6) & (sx >= -1e-6) & (sx <= SHAPE[1] - 1
                                                                           + 1e-6)
    assert np.array_equal(valid, inside)


def test_a_tripod_bracket_comes_out_unchanged_to_the_bit(scene):
    rng = np.random.default_rng(5)
    frames = [render(scene, 0, 0, 0, t, rng) for t in (1 / 16, 1 / 4, 1, 4, 16)]
    names = [f"t{k}.tif" for k in range(5)]
    al = estimate_alignment(frames, names)
    assert not al.any_applied
    for s in al.shifts:
        assert not s.applied
        if s.registered:
            assert abs(s.dx) <= max(2 * s.dx_err, 0.05) and abs(s.dy) <= max(2 * s.dy_err, 0.05)
    copies = [f.copy() for f in frames]
    aligned, valid = apply_alignment(frames, al)
    for a, f, c in zip(aligned, frames, copies):
        assert a is f and a.dtype == c.dtype and np.array_equal(a, c)
    assert valid.all()
    if not al.left_out:
        assert al.describe() == ("frames registered (tripod): every shift within its error or "
                                 "0.25 px, no frame resampled")
    else:
        assert al.describe().startswith("no frame resampled")


def test_frames_without_structure_are_left_out_with_a_reason(scene):
    rng = np.random.default_rng(9)
    ref = render(scene, 0, 0, 0, 1.0, rng)
    good = render(scene, 1.25, -0.75, 0, 0.25, rng)
    noise = rng.integers(0, 256, SHAPE).astype(np.uint8)
    flat = np.full(SHAPE, 128, np.uint8)
    names = ["noise.png", "good.png", "ref.png", "flat.png"]
    al = estimate_alignment([noise, good, ref, flat], names)
    assert al.reference == 2
    assert al.left_out == ("noise.png", "flat.png")
    for k in (0, 3):
        s = al.shifts[k]
        assert not s.registered and not s.applied
        assert s.reason.startswith(f"{names[k]}: too little structure to register (")
        assert "tiles with a clear peak" in s.reason
    check_shift(al.shifts[1], 1.25, -0.75)
    text = al.describe()
    assert text.startswith("1 of 4 frames aligned to ref.png: good.png by (+1.25, -0.75) px")
    assert "2 left out (noise.png: too little structure" in text
    aligned, valid = apply_alignment([noise, good, ref, flat], al)
    assert aligned[0] is noise and aligned[3] is flat            # left out: returned as given
    assert valid[10:-10, 10:-10].all()


@pytest.mark.parametrize("t", [1 / 1024, 1 / 4096, 16.0, 64.0])
def test_a_heavily_clipped_frame_registers_or_is_left_out_never_wrong(scene, t):
    rng = np.random.default_rng(int(1 / t) if t < 1 else int(t))
    ref = render(scene, 0, 0, 0, 1.0, rng)
    frame = render(scene, 1.3, -0.7, 0.2, t, rng)
    clipped = np.mean((frame == 0) | (frame == 255))
    assert clipped > (0.25 if t == 1 / 1024 else 0.5)         # heavily clipped indeed
    al = estimate_alignment([ref, frame], ["ref.png", "dim.png"], reference=0)
    s = al.shifts[1]
    if s.registered:
        check_shift(s, 1.3, -0.7, slack=0.1)
    else:
        assert s.reason.startswith("dim.png: ") and "clipped" in s.reason
    if t == 1 / 1024:                  # a third dark, two thirds still usable: registered
        assert s.registered and s.dx_err < 0.1


def test_the_stated_errors_are_the_scatter_of_the_estimates(scene):
    """Over independent noise, the estimates of a noisy (dim) frame scatter about the truth by
    their stated error: the normalised errors have an RMS of order 1."""
    rng = np.random.default_rng(21)
    ref = render(scene, 0, 0, 0, 1.0, rng)
    z, errs = [], []
    for _ in range(8):
        frame = render(scene, -0.8, 1.6, 0, 1 / 1024, rng, noise=1.5)
        s = estimate_alignment([ref, frame], ["ref", "dim"], reference=0).shifts[1]
        assert s.registered, s.reason
        z += [(s.dx + 0.8) / s.dx_err, (s.dy - 1.6) / s.dy_err]
        errs.append(s.dx_err)
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.3 < rms < 3.0, (rms, z)
    assert 0.005 < np.mean(errs) < 0.2


def test_colour_frames(scene):
    rng = np.random.default_rng(13)
    gains = (1.0, 0.8, 0.55)
    truth = [(1.6, 2.2, 0.0), (0.0, 0.0, 0.0), (-2.4, -0.9, 0.3)]
    frames = [render(scene, dx, dy, r, t, rng, gains=gains)
              for (dx, dy, r), t in zip(truth, (1 / 4, 1, 4))]
    assert frames[0].shape == SHAPE + (3,)
    al = estimate_alignment(frames, ["a.jpg", "b.jpg", "c.jpg"])
    for s, (dx, dy, rot) in zip(al.shifts, truth):
        check_shift(s, dx, dy, rot)
    aligned, valid = apply_alignment(frames, al)
    assert aligned[1] is frames[1]
    for a in aligned:
        assert a.shape == SHAPE + (3,) and a.dtype == np.uint8
    for k in (0, 2):
        g = [gradient_correlation(aligned[k][..., c], frames[1][..., c], valid) for c in range(3)]
        assert min(g) > 0.85, g


def test_uint16_frames(scene):
    """12-bit codes in uint16: the levels are found from the data (4096) or given."""
    rng = np.random.default_rng(17)
    truth = [(0.0, 0.0, 0.0), (-1.15, 2.6, 0.0), (3.3, 0.4, -0.25)]
    frames = [render(scene, dx, dy, r, t, rng, noise=8.0, top=4095, dtype=np.uint16)
              for (dx, dy, r), t in zip(truth, (1 / 4, 1, 4))]
    assert frames[2].max() == 4095
    for levels in (None, 4096):
        al = estimate_alignment(frames, ["a.tif", "b.tif", "c.tif"], reference=0,
                                levels=levels)
        for s, (dx, dy, rot) in zip(al.shifts, truth):
            check_shift(s, dx - truth[0][0], dy - truth[0][1], rot)
    aligned, valid = apply_alignment(frames, al)
    assert aligned[0] is frames[0]
    assert all(a.dtype == np.uint16 for a in aligned) and aligned[2].max() <= 4095
    assert gradient_correlation(aligned[2], frames[0], valid, top=4095) > 0.9


def test_a_shift_beyond_max_shift_is_left_out(scene):
    rng = np.random.default_rng(19)
    frames = [render(scene, 0, 0, 0, 1, rng), render(scene, 12.4, -3.0, 0, 1, rng)]
    al = estimate_alignment(frames, ["ref", "far"], reference=0)
    check_shift(al.shifts[1], 12.4, -3.0)
    al = estimate_alignment(frames, ["ref", "far"], reference=0, max_shift=0.02)
    s = al.shifts[1]
    assert not s.registered and s.reason.startswith("far: shift (+12.4, -3.0) px beyond max_shift")
    assert al.left_out == ("far",)


def test_results_are_json_ready(hand_held):
    _frames, al = hand_held
    d = json.loads(json.dumps(al.to_dict()))
    assert d["reference"] == 2 and d["reference_name"] == "IMG_0003.JPG"
    assert d["any_applied"] is True and d["left_out"] == []
    assert [s["name"] for s in d["shifts"]] == NAMES
    first = d["shifts"][0]
    assert set(first) >= {"name", "dx", "dy", "rotation", "dx_err", "dy_err", "rotation_err",
                          "registered", "reason", "applied"}
    assert first["dx"] == pytest.approx(al.shifts[0].dx)
    assert d["describe"] == al.describe()


def test_bad_input_names_the_frame(scene):
    a = render(scene, 0, 0, 0, 1)
    with pytest.raises(CcdError, match="^b.png: shape"):
        estimate_alignment([a, a[:-1]], ["a.png", "b.png"])
    with pytest.raises(CcdError, match="^a.png: at least 2 frames"):
        estimate_alignment([a], ["a.png"])
    with pytest.raises(CcdError, match="^b.png: sample type float32 is not an integer type"):
        estimate_alignment([a, a.astype(np.float32)], ["a.png", "b.png"])
    with pytest.raises(CcdError, match="^b.png: code 255 beyond the 128 levels"):
        estimate_alignment([a // 2, a], ["a.png", "b.png"], levels=128)
    with pytest.raises(CcdError, match="^reference: "):
        estimate_alignment([a, a], ["a.png", "b.png"], reference=2)
    with pytest.raises(CcdError, match="^names: "):
        estimate_alignment([a, a], ["a.png"])
    al = estimate_alignment([a, a], ["a.png", "b.png"])
    with pytest.raises(CcdError, match="^frames: "):
        apply_alignment([a], al)
