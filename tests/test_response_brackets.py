"""Exposure brackets as pixel traces (ccdcore.response.brackets) and the reported scale of
response curves (ccdcore.response.scale)."""
from __future__ import annotations

import numpy as np
import pytest

from ccdcore.errors import CcdError
from ccdcore.response import brackets as br
from ccdcore.response import scale
from ccdcore.session import open_session
from ccdcore.simulate.tsin import simulate


# ------------------------------------------------------------------------ preprocessing ------
def test_preprocess_drops_clipped_codes_blooming_disk_and_border():
    z = np.full((20, 20), 100, np.uint8)
    z[10, 10] = 255                                   # one saturated pixel
    z[2, 15] = 0                                      # one dark-clipped pixel
    usable = br.preprocess(z, 256, bloom_radius=3, border=1)
    yy, xx = np.mgrid[:20, :20]
    within = (yy - 10) ** 2 + (xx - 10) ** 2 <= 9     # Euclidean disk of radius 3
    assert not usable[within].any()
    assert usable[10, 14] and not usable[10, 13]      # 4 px away kept, 3 px away dropped
    assert not usable[12, 12] and usable[13, 13]      # 2.83 px away dropped, 4.24 px kept
    assert not usable[2, 15]
    assert not usable[0].any() and not usable[:, -1].any()
    assert usable[1:-1, 1:-1].sum() == 18 * 18 - within.sum() - 1
    # radius 0 and no border: only the clipped codes go
    assert br.preprocess(z, 256, bloom_radius=0, border=0).sum() == 400 - 2
    # the saturation level follows the bit depth: 255 is an ordinary 12-bit code
    assert br.preprocess(z.astype(np.uint16), 4096, bloom_radius=3, border=0).sum() == 399


def test_bracket_data_sorts_by_exposure_and_keeps_pixels_with_any_usable_code():
    rng = np.random.default_rng(0)
    frames = [rng.integers(1, 254, (8, 10)).astype(np.uint8) for _ in range(3)]
    frames[2][:, :] = 255                             # the longest: all saturated
    data = br.bracket_data([frames[2], frames[0], frames[1]], [0.4, 0.1, 0.2], 8,
                           files=["c.tif", "a.tif", "b.tif"], bloom_radius=0, border=0)
    d = data["L"]
    assert d.files == ("a.tif", "b.tif", "c.tif")
    np.testing.assert_array_equal(d.t, [0.1, 0.2, 0.4])
    np.testing.assert_array_equal(d.z[0], frames[0].reshape(-1))
    assert d.levels == 256 and d.shape == (8, 10) and d.n_images == 3
    assert not d.valid[2].any() and d.valid[:2].all()
    assert d.mad_factor == pytest.approx(1.483)


def test_rgb_channels_and_the_bayer_factor_of_eq_12():
    rgb = np.random.default_rng(1).integers(1, 250, (6, 7, 3)).astype(np.uint8)
    data = br.bracket_data([rgb, rgb // 2 + 1], [2.0, 1.0], 8, layout="rgb",
                           bayer_interpolated=True, bloom_radius=0, border=0)
    assert list(data) == ["R", "G", "B"]
    assert data["G"].mad_factor == pytest.approx(1.483 * 1.265)
    assert data["R"].mad_factor == pytest.approx(1.483 * 1.333)
    np.testing.assert_array_equal(data["B"].z[1], rgb[..., 2].reshape(-1))   # longest last


@pytest.mark.parametrize("frames, times, message", [
    (1, [0.1], "at least two exposures"),
    (2, [0.1, 0.1], "same exposure time"),
    (2, [0.1, None], "missing exposure time"),
    (2, [0.1, -1.0], "positive number"),
])
def test_bad_brackets_name_the_file_and_the_problem(frames, times, message):
    imgs = [np.full((4, 4), 100, np.uint8)] * frames
    files = [f"f{k}.tif" for k in range(frames)]
    with pytest.raises(CcdError, match=message):
        br.bracket_data(imgs, times, 8, files=files)


def test_mismatched_shapes_codes_beyond_the_bits_and_all_saturated():
    a = np.full((4, 4), 100, np.uint16)
    with pytest.raises(CcdError, match=r"f1\.tif: shape"):
        br.bracket_data([a, np.full((4, 5), 100, np.uint16)], [1, 2], 8,
                        files=["f0.tif", "f1.tif"])
    with pytest.raises(CcdError, match=r"f0\.tif: code 300 exceeds"):
        br.bracket_data([a + 200, a], [1, 2], 8, files=["f0.tif", "f1.tif"])
    with pytest.raises(CcdError, match=r"f1\.tif: uint8 samples, .* uint16.*mixed cameras"):
        br.bracket_data([a, a.astype(np.uint8)], [1, 2], 8, files=["f0.tif", "f1.tif"])
    with pytest.raises(CcdError, match="no usable pixel"):
        br.bracket_data([a * 0 + 255, a * 0 + 255], [1, 2], 8, files=["f0.tif", "f1.tif"])


def test_load_bracket_reads_the_session(tmp_path):
    simulate(tmp_path, seed=3, size=(40, 30), n_stacks=2)
    session = open_session(tmp_path)
    data = br.load_bracket(session, stack=1, bloom_radius=0)["L"]
    assert data.n_images == 8 and data.shape == (30, 40)
    assert data.files[0] == "bracket/s1_k00.tif"
    assert np.all(np.diff(data.t) > 0)
    with pytest.raises(CcdError, match="no bracket stack 7"):
        br.load_bracket(session, stack=7)


# ------------------------------------------------------------------------------ scale ------
def test_reported_scale_and_rms_after_the_free_scale():
    assert scale.reference_codes(256) == (51, 230)
    assert scale.reference_codes(4096) == (819, 3686)
    z = np.arange(256)
    truth = (z / 255.0) ** 1.2
    g, s, c = scale.normalize(3.0 * truth, 256)
    assert g[230] == pytest.approx(230 / 255) and c == 0.0
    assert s == pytest.approx((230 / 255) / (3.0 * truth[230]))
    g2, s2, c2 = scale.normalize(3.0 * truth + 0.2, 256, offset=True)
    assert (g2[51], g2[230]) == (pytest.approx(51 / 255), pytest.approx(230 / 255))
    # a scaled copy has no error; an offset counts unless the offset is free too
    assert scale.rms_error(7.0 * truth, truth) < 1e-15
    assert scale.rms_error(truth + 0.01, truth) > 1e-3
    assert scale.rms_error(2 * truth + 0.01, truth, offset=True) < 1e-15
    bumped = truth.copy()
    bumped[100] += 0.01                               # one code off by 0.01 over 246 codes
    assert scale.rms_error(bumped, truth) == pytest.approx(0.01 / np.sqrt(246), rel=0.02)


@pytest.mark.parametrize("fraction", [0.001, 0.02, 0.3])
def test_bloom_mask_is_the_disk_dilation_sparse_or_dense(fraction):
    """The direct marking used for few saturated pixels gives the binary dilation by the disk
    exactly, at the frame's edges too."""
    from scipy import ndimage

    from ccdcore.response.brackets import bloom_mask

    rng = np.random.default_rng(11)
    z = np.where(rng.random((61, 83)) < fraction, 255, 100).astype(np.uint8)
    z[0, 0] = z[-1, 40] = 255
    yy, xx = np.mgrid[-3:4, -3:4]
    ref = ndimage.binary_dilation(z == 255, structure=(yy * yy + xx * xx) <= 9)
    assert np.array_equal(bloom_mask(z, 256, 3), ref)
