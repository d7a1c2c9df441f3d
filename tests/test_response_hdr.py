"""HDR radiance and its sigma (Tsin et al. 2001, eqs. 9, 18, 19): ccdcore.response.hdr."""
from __future__ import annotations

import numpy as np
import pytest

from ccdcore.errors import CcdError
from ccdcore.io.frames import read_image
from ccdcore.response.hdr import (FLAG_BLOOMED, FLAG_DARK, FLAG_OK, FLAG_SATURATED,
                                  HdrResult, ResponseModel, merge, noise_sigma)
from ccdcore.session import open_session
from ccdcore.simulate.tsin import simulate

#: the simulator's noise (sec. 4.1); rounding to integer codes adds 1/12 code² to σ_c2²
TRUE_NOISE = (0.015, 0.01, float(np.sqrt(1.0 + 1.0 / 12.0)))


def _bracket(folder, **options):
    truth = simulate(folder, seed=4, size=(192, 160), **options)
    session = open_session(folder)
    frames = [session.read(r) for r in session.bracket_stacks()[0]]
    E = read_image(folder / "truth" / "E.exr").astype(np.float64)
    a = np.array([f["a"] for f in truth["frames"]], dtype=np.float64)
    b = np.array([f["b"] for f in truth["frames"]], dtype=np.float64)
    return frames, E, a, b, np.array(truth["g"])


@pytest.mark.parametrize("white_balance", [False, True])
def test_radiance_errors_have_the_predicted_sigma(tmp_path, white_balance):
    """With the true calibration, (Ê - E) / σ_E over the 30,720 pixels has mean 0 and standard
    deviation 1: measured 0.008 / 1.007 and 0.018 / 1.014 here (seed 4; 0.012 / 0.999 and
    0.021 / 1.003 at 256²). The sampling error of the standard deviation is 1/√(2n) = 0.004;
    the tolerance 0.04 also covers the quantisation's departure from Gaussian noise. Without eq. 19's √N the spread would be off by
    up to √8, with eq. 18's weights replaced by 1/σ the radiance would keep its mean but the
    spread its formula predicts would be wrong."""
    frames, E, a, b, g = _bracket(tmp_path, white_balance=white_balance)
    model = ResponseModel(g, a, b, *TRUE_NOISE)
    hdr = merge(frames, model, bloom_radius=0)
    ok = hdr.flags == FLAG_OK
    assert ok.all() and hdr.radiance.shape == E.shape
    z = (hdr.radiance[ok] - E[ok]) / hdr.sigma[ok]
    assert abs(z.mean()) < 0.04
    assert abs(z.std() - 1.0) < 0.04
    assert hdr.used.max() == len(frames) and hdr.used.min() >= 1


def test_eq_18_weights_and_eq_19_sigma_on_one_pixel():
    g = (np.arange(256) / 255.0) ** 1.2
    model = ResponseModel(g, np.array([0.5, 1.0]), np.array([0.0, 0.02]), 0.015, 0.01, 1.0)
    z = [np.array([[60]], np.uint8), np.array([[120]], np.uint8)]
    hdr = merge(z, model, bloom_radius=0)
    s = np.array([noise_sigma(model, 60, 0), noise_sigma(model, 120, 1)])
    q = model.a / s
    pred = np.array([(g[60] - 0.0) / 0.5, (g[120] - 0.02) / 1.0])
    assert hdr.radiance[0, 0] == pytest.approx(float((q * pred).sum() / q.sum()), rel=1e-12)
    assert hdr.sigma[0, 0] == pytest.approx(float(np.sqrt(2) / q.sum()), rel=1e-12)
    dg = np.gradient(g)[120]
    assert s[1] == pytest.approx(np.sqrt(0.015 ** 2 * (g[120] - 0.02) + 0.01 ** 2 + dg ** 2))


def test_pixels_without_a_usable_code_get_a_bound_and_a_flag():
    g = (np.arange(256) / 255.0) ** 1.2
    model = ResponseModel(g, np.array([0.25, 1.0]), np.zeros(2), 0.015, 0.01, 1.0)
    short = np.full((9, 9), 100, np.uint8)
    long_ = np.full((9, 9), 200, np.uint8)
    short[0, 0] = long_[0, 0] = 255                  # saturated in every image
    short[8, 8] = long_[8, 8] = 0                    # dark in every image
    long_[4, 4] = 255                                # saturated in the long image only: its
    hdr = merge([short, long_], model, bloom_radius=2)   # neighbours lose that image's code
    assert hdr.flags[0, 0] == FLAG_SATURATED and np.isinf(hdr.sigma[0, 0])
    assert hdr.radiance[0, 0] == pytest.approx(g[255] / 0.25)      # lower bound
    assert hdr.flags[8, 8] == FLAG_DARK and np.isinf(hdr.sigma[8, 8])
    assert hdr.radiance[8, 8] == pytest.approx(g[1] / 1.0)         # upper bound
    assert hdr.flags[4, 5] == FLAG_OK and hdr.used[4, 5] == 1     # the short image only
    assert hdr.radiance[4, 4] == pytest.approx(g[100] / 0.25)      # the saturated pixel itself
    assert np.isfinite(hdr.radiance).all()
    # a code lost to the blooming mask in every image: merged from the masked codes, flagged
    both = [np.full((7, 7), 150, np.uint8), np.full((7, 7), 150, np.uint8)]
    both[0][3, 0] = both[1][3, 0] = 255
    hdr = merge(both, model, bloom_radius=1)
    assert hdr.flags[3, 1] == FLAG_BLOOMED and np.isfinite(hdr.sigma[3, 1])
    assert hdr.flag_image().shape == (7, 7)


def test_colour_channels_and_bad_input():
    g = (np.arange(256) / 255.0) ** 1.2
    models = {c: ResponseModel(g * s, np.array([0.5, 1.0]), np.zeros(2), 0.0, 0.0, 1.0)
              for c, s in (("R", 1.0), ("G", 2.0), ("B", 4.0))}
    rgb = [np.full((5, 6, 3), 80, np.uint8), np.full((5, 6, 3), 140, np.uint8)]
    hdr = merge(rgb, models, layout="rgb", bloom_radius=0)
    assert hdr.channels == ("R", "G", "B") and hdr.radiance.shape == (5, 6, 3)
    assert hdr.radiance[0, 0, 1] == pytest.approx(2 * hdr.radiance[0, 0, 0])
    with pytest.raises(CcdError, match="no calibration for channel"):
        merge(rgb, {"R": models["R"]}, layout="rgb")
    with pytest.raises(CcdError, match="shape"):
        merge([rgb[0], rgb[1][:4]], models, layout="rgb")
    with pytest.raises(CcdError, match="2 images, the bracket 3"):
        merge([rgb[0][..., 0]] * 3, models["R"])
    with pytest.raises(CcdError, match="integer codes"):
        merge([np.zeros((3, 3)), np.zeros((3, 3))], models["R"])


def test_flag_counts_and_the_description_that_hdr_prints():
    """flags.png's pixels by flag, counted over the channels' largest flag, and the lines
    ``hdr`` prints: the radiance's scale, its percentiles over merged pixels, the flags."""
    flags = np.zeros((4, 5, 3), np.uint8)
    flags[0, 0, 1] = FLAG_DARK
    flags[1, 1, :] = FLAG_SATURATED
    flags[2, 2, 2] = FLAG_BLOOMED
    flags[2, 2, 0] = FLAG_DARK                   # the largest flag of the pixel counts
    radiance = np.tile(np.arange(1.0, 21.0).reshape(4, 5)[..., None], (1, 1, 3))
    res = HdrResult(radiance, 0.05 * radiance, flags, np.ones(flags.shape, np.int16),
                    ("R", "G", "B"), "rgb")
    assert res.flag_counts() == {"merged": 17, "dark": 1, "saturated": 1, "bloomed": 1, "moving": 0}
    lines = res.describe()
    assert "no absolute unit" in lines[0]
    ok = radiance[flags == FLAG_OK]
    lo, med, hi = np.percentile(ok, [1, 50, 99])
    assert f"E {lo:.3g} … {hi:.3g}" in lines[1] and f"median {med:.3g}" in lines[1]
    assert "median 5 %" in lines[1]
    assert lines[2].startswith("flags.png: 17 merged (85 %), 1 dark") and "1 saturated" in lines[2]
