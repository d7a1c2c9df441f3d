"""Pins of the fourth fresh set of planted bugs (MUTANTS.md): each test's expectation is derived
independently (by hand, from the defining formula, or from a brute-force reference written
here), on data chosen so that the defaults do not hide the bug (scales far from 1, non-square
frames, asymmetric shifts)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ccdcore.change import detector as CH
from ccdcore.change.frames import srgb_inverse
from ccdcore.flatfield.check import held_out_figures


# ------------------------------------------------------------------------ change detection ----
def test_biweight_weights_are_tukeys_squared_form():
    """Tukey's biweight on d with cut-off c (c² = c2): w = (1 - (d/c)²)² inside, 0 beyond.
    At d² = c2/2 that is 1/4, at d² = c2/4 it is 9/16 (not 1/2 and 3/4, the unsquared form)."""
    c2 = 21.1
    d2 = np.array([0.0, c2 / 4, c2 / 2, 0.9 * c2, c2, 3 * c2])
    want = np.array([1.0, 9.0 / 16.0, 0.25, 0.01, 0.0, 0.0])
    np.testing.assert_allclose(CH.biweight_weights(d2, c2), want, rtol=1e-12, atol=1e-15)


def test_small_regions_keeps_a_region_of_exactly_min_region_pixels():
    """Three 8-connected regions of 8, 9 and 10 pixels (one joined only through a diagonal):
    with min_region = 9 only the 8-pixel one is small."""
    m = np.zeros((12, 30), bool)
    m[1, 1:9] = True                          # 8 pixels in a row
    m[5, 1:5] = True                          # 4 + 5 pixels joined at a corner: 9
    m[6, 5:10] = True
    m[9:11, 15:20] = True                     # a 2 x 5 block: 10
    small = CH.small_regions(m, 9)
    assert small.sum() == 8 and np.all(small[1, 1:9])
    assert not small[5:7].any() and not small[9:11].any()
    assert CH.small_regions(m, 10).sum() == 8 + 9
    assert CH.small_regions(m, 11).sum() == 8 + 9 + 10
    assert CH.small_regions(m, 1).sum() == 0


# ------------------------------------------------------------------------- frame sets (sRGB) --
def _srgb_forward(L):
    """IEC 61966-2-1's encoding, written here: V = 12.92 L below 0.0031308, else
    1.055 L^(1/2.4) - 0.055."""
    L = np.asarray(L, np.float64)
    return np.where(L <= 0.0031308, 12.92 * L, 1.055 * np.power(np.maximum(L, 0), 1 / 2.4)
                    - 0.055)


@pytest.mark.parametrize("levels", [256, 1024])
def test_srgb_inverse_inverts_the_standard_encoding_at_every_code(levels):
    """The decoding undoes the standard's encoding at every code, the dark codes of the linear
    segment included (code 5 of 255: 0.0196 / 12.92 = 1.518e-3)."""
    g = srgb_inverse(levels)
    u = np.arange(levels) / (levels - 1)
    np.testing.assert_allclose(_srgb_forward(g), u, rtol=0, atol=2e-6)
    if levels == 256:
        assert g[5] == pytest.approx((5 / 255) / 12.92, rel=1e-12)
        assert g[10] == pytest.approx((10 / 255) / 12.92, rel=1e-12)
        assert g[11] == pytest.approx(((11 / 255 + 0.055) / 1.055) ** 2.4, rel=1e-12)


def test_a_bracket_against_one_frame_goes_to_the_frame_set_path(tmp_path):
    """Reference a bracket of 7 exposures, target one frame at 0.5 s: a frame set on one side
    is enough for the frame-set path (its kinds, its 3 x 3 smallest region), and the target's
    radiance is eq. 9 for one frame, g(z) / a, with g the response fitted to the reference."""
    from ccdcore.change.frames import FRAME_MIN_REGION
    from ccdcore.change.session import session_change
    from ccdcore.io import read_image
    from ccdcore.session import open_session
    from ccdcore.simulate import change as sim

    root = tmp_path / "mixed"
    sim.simulate(root, seed=0, size=(96, 64))
    exps = (0.125, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0)
    rows = [f'    {{ path = "reference/k{i:02d}.tif", role = "reference", exposure = {t} }},'
            for i, t in enumerate(exps)]
    rows.append('    { path = "target/k02.tif", role = "target", exposure = 0.5 },')
    (root / "session.toml").write_text(
        "schema = 1\nframes = [\n" + "\n".join(rows) + "\n]\n\n[camera]\nname = \"sim\"\n"
        "bits = 8\nlayout = \"rgb\"\n")
    res, inp = session_change(open_session(root), method="debevec")
    assert inp.kinds == {"reference": "bracket", "target": "frames"}
    assert res.min_region == FRAME_MIN_REGION
    assert "target: 1 frame" in res.sources["noise"]
    z = np.asarray(read_image(root / "target" / "k02.tif")).astype(np.intp)
    models = inp.response.models()
    for i, c in enumerate(inp.channels):
        g = np.asarray(models[c].g, np.float64)
        ok = (z[..., i] > 0) & (z[..., i] < 255)
        assert ok.mean() > 0.5
        np.testing.assert_allclose(inp.E_tgt[..., i][ok], g[z[..., i][ok]] / 0.5, rtol=1e-12)


# ----------------------------------------------------------------------------- dark model ----
def test_only_currents_above_the_median_are_hot():
    """Darks at 0-8 s, σ = 1 DN: each pixel's current has the OLS error 1/√Σ(t - t̄)² =
    1/√40 = 0.16 DN/s, so 6 robust σ is about 1 DN/s. A pixel 48 DN/s above the median is hot;
    one 42 DN/s below it (a cold pixel) is not: hot means *above* the median."""
    from ccdcore.dark.model import fit_dark_model

    rng = np.random.default_rng(7)
    shape = (40, 50)
    current = np.full(shape, 2.0)
    current[10, 20] = 50.0                   # hot
    current[30, 5] = -40.0                   # cold (far below the median)
    frames = [(t, 100.0 + current * t + rng.standard_normal(shape))
              for t in (0.0, 1.0, 2.0, 4.0, 8.0)]
    model = fit_dark_model(frames)
    assert float(np.median(model.current)) == pytest.approx(2.0, abs=0.05)
    hot = model.hot_current
    assert hot[10, 20] and not hot[30, 5]
    assert int(hot.sum()) == 1
    assert model.summary().n_hot == 1


# ------------------------------------------------------------------------- held-out flat ----
def _gain_flat(G, var, n=2):
    """The parts of a flat field the held-out check reads, with the gain map ``G`` (the
    correction multiplies by it), no flagged pixel and the fitted flats' variance ``var``."""
    shape = G.shape
    return SimpleNamespace(G=G, flags=np.zeros(shape, bool), layout=None, shape=shape,
                           base=SimpleNamespace(var=np.full(shape, var), n=n),
                           correct=lambda raw, where=None: G * np.asarray(raw, np.float64))


@pytest.mark.parametrize("gain", [1.0, 2.5, 6.0])
def test_held_out_floor_carries_the_noise_through_g_squared(gain):
    """The correction multiplies the flat and its noise by G: the relative temporal noise is
    G σ / (G mean) = σ / mean whatever G's scale, and a corrected frame of pure noise has
    SNUP / floor = 1 / √(1 + 1/N) (0.816 for N = 2): it passes."""
    import math

    rng = np.random.default_rng(3)
    shape = (48, 80)
    frame = 1000.0 + 10.0 * rng.standard_normal(shape)
    check = held_out_figures(_gain_flat(np.full(shape, gain), 100.0), frame, n_fit=2,
                             held_out="h.fits")
    (ch,) = check.channels
    assert ch.temporal == pytest.approx(100.0 * 10.0 / float(frame.mean()), rel=1e-9)
    assert ch.floor == pytest.approx(ch.temporal * math.sqrt(1.5), rel=1e-12)
    # the sample SNUP of 3840 pixels: relative error 1/√(2 · 3840) = 1.1 %
    assert ch.ratio == pytest.approx(1.0 / math.sqrt(1.5), rel=0.05)
    assert check.verdict == "pass"
