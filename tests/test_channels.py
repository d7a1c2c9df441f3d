"""Tests of ccdcore.channels: layouts, channel views, Bayer sampling, planes and bilinear demosaicing."""
from __future__ import annotations

import numpy as np
import pytest

from ccdcore import channels
from ccdcore.errors import CcdError


@pytest.fixture
def rgb() -> np.ndarray:
    return np.random.default_rng(7).random((8, 10, 3))


@pytest.mark.parametrize("pattern", channels.PATTERNS)
def test_plane_masks_partition_the_sensor(pattern):
    masks = channels.plane_masks((6, 8), pattern)
    assert set(masks) == set(channels.PLANES)
    stacked = np.stack([masks[p] for p in channels.PLANES])
    assert np.array_equal(stacked.sum(axis=0), np.ones((6, 8), int))
    for p in channels.PLANES:
        assert masks[p].sum() == 12
    # the top-left 2x2 cell spells the pattern
    letters = {"R": "r", "G1": "g", "G2": "g", "B": "b"}
    cell = ["?"] * 4
    for p, m in masks.items():
        (r, c), = np.argwhere(m[:2, :2])
        cell[2 * r + c] = letters[p]
    assert "".join(cell) == pattern


@pytest.mark.parametrize("pattern", channels.PATTERNS)
def test_green_planes_are_on_red_and_blue_rows(pattern):
    off = channels.plane_offsets(pattern)
    assert off["G1"][0] == off["R"][0]
    assert off["G2"][0] == off["B"][0]


@pytest.mark.parametrize("pattern", channels.PATTERNS)
def test_mosaic_picks_the_filtered_channel(rgb, pattern):
    raw = channels.mosaic(rgb, pattern)
    assert raw.shape == rgb.shape[:2] and raw.dtype == rgb.dtype
    r, g, b = channels.channel_masks(raw.shape, pattern)
    assert np.array_equal(raw[r], rgb[..., 0][r])
    assert np.array_equal(raw[g], rgb[..., 1][g])
    assert np.array_equal(raw[b], rgb[..., 2][b])


@pytest.mark.parametrize("pattern", channels.PATTERNS)
def test_demosaic_is_exact_at_sampled_sites(rgb, pattern):
    raw = channels.mosaic(rgb, pattern)
    out = channels.demosaic_bilinear(raw, pattern)
    assert out.shape == rgb.shape and out.dtype == np.float64
    for i, m in enumerate(channels.channel_masks(raw.shape, pattern)):
        assert np.array_equal(out[..., i][m], rgb[..., i][m])   # bit-exact, not approximately
    # and mosaic(demosaic(raw)) gives raw back exactly
    assert np.array_equal(channels.mosaic(out, pattern), raw)


@pytest.mark.parametrize("pattern", channels.PATTERNS)
def test_demosaic_constant_image_everywhere(pattern):
    rgb = np.empty((6, 8, 3))
    rgb[...] = (0.2, 0.5, 0.75)
    out = channels.demosaic_bilinear(channels.mosaic(rgb, pattern), pattern)
    assert np.array_equal(out, rgb)      # weights are exact binary fractions summing to 1


@pytest.mark.parametrize("pattern", channels.PATTERNS)
def test_demosaic_linear_ramp_in_the_interior(pattern):
    yy, xx = np.mgrid[0:10, 0:12].astype(float)
    rgb = np.stack([1.0 + 2.0 * xx - 0.5 * yy, 3.0 - xx + 1.5 * yy, 0.25 * xx + 0.75 * yy],
                   axis=-1)
    out = channels.demosaic_bilinear(channels.mosaic(rgb, pattern), pattern)
    inner = (slice(1, -1), slice(1, -1))
    # bilinear interpolation of a plane is exact; float rounding is below 1e-12 here
    np.testing.assert_allclose(out[inner], rgb[inner], rtol=0, atol=1e-12)
    # the border is not exact for a ramp (mirror extension), so the test can fail
    assert np.abs(out - rgb).max() > 0.1


@pytest.mark.parametrize("pattern", channels.PATTERNS)
def test_planes_round_trip(rgb, pattern):
    raw = channels.mosaic((rgb * 1000).astype(np.uint16), pattern)
    pl = channels.planes(raw, pattern)
    assert set(pl) == set(channels.PLANES)
    rebuilt = np.zeros_like(raw)
    masks = channels.plane_masks(raw.shape, pattern)
    for name, plane in pl.items():
        assert plane.shape == (4, 5) and plane.dtype == np.uint16
        rebuilt[masks[name]] = plane.ravel()
    assert np.array_equal(rebuilt, raw)
    # views share memory with the raw image
    assert np.shares_memory(pl["R"], raw)


def test_pattern_names_are_normalised():
    assert channels.check_pattern("Bayer-GRBG") == "grbg"
    assert channels.check_pattern(" rggb ") == "rggb"


@pytest.mark.parametrize("bad", ["rgbg", "xyz", "", "bayer-", 3])
def test_bad_pattern_raises(bad):
    with pytest.raises(CcdError):
        channels.plane_masks((4, 4), bad)


@pytest.mark.parametrize("shape", [(5, 4), (4, 7), (1, 2)])
def test_odd_shapes_raise(shape):
    with pytest.raises(CcdError):
        channels.plane_masks(shape, "rggb")
    with pytest.raises(CcdError):
        channels.mosaic(np.zeros(shape + (3,)), "rggb")
    with pytest.raises(CcdError):
        channels.planes(np.zeros(shape), "rggb")
    with pytest.raises(CcdError):
        channels.demosaic_bilinear(np.zeros(shape), "rggb")


def test_wrong_dimensions_raise():
    with pytest.raises(CcdError):
        channels.mosaic(np.zeros((4, 4)), "rggb")
    with pytest.raises(CcdError):
        channels.mosaic(np.zeros((4, 4, 4)), "rggb")
    with pytest.raises(CcdError):
        channels.demosaic_bilinear(np.zeros((4, 4, 3)), "rggb")
