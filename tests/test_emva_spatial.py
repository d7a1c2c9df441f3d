"""Tests of ccdcore.emva.spatial: the release 4.0 split of the spatial variance into row, column
and pixel parts, DSNU and PRNU parts, and the arrays of the spatial section's plots.

Tolerances
----------
* The split over sensors drawn from the model: the generating variances within the bias of the
  definitions (1/M of a part, and σ²_pixel/(MN − M − N)) plus 4 standard errors of the mean.
* Stated errors against the scatter over noise draws: 300 draws give the spread of each part to
  about ±8 % (1/√(2·300) per standard deviation, twice that for a 4-sigma band): the ratio must
  lie in [0.8, 1.25].
* Against emva1288's Results1288 on the same files: 1e-7 relative (its leastsq fit of K stops at
  a relative step of 1.49e-8), as tests/test_datasheet.py.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from ccdcore.emva.spatial import (DETERMINABLE_Z, HIGH_PASS_SIZE, accumulated_histogram,
                                  defect_histogram, high_pass, nonuniformity_split, profiles,
                                  spectrogram, variance_split)

M, N = 24, 32


def _model_image(rng: np.random.Generator, M: int, N: int, s_row: float, s_col: float,
                 s_pix: float) -> np.ndarray:
    return (100.0 + rng.normal(0, math.sqrt(s_row), (M, 1)) + rng.normal(0, math.sqrt(s_col),
                                                                          (1, N))
            + rng.normal(0, math.sqrt(s_pix), (M, N)))


@pytest.mark.parametrize("parts", [(4.0, 9.0, 16.0), (0.0, 0.0, 16.0), (4.0, 0.0, 0.0),
                                   (0.0, 9.0, 1.0)])
def test_split_recovers_the_generating_variances_on_average(parts):
    """Over 40 sensors of 160 × 240 pixels drawn from the model (iid row, column and pixel
    parts) with the temporal noise of an average of L = 16 frames, the mean of each part is its
    generating variance. The definitions (emva1288's) measure a sensor's own rows and columns
    as a population (1/M, not 1/(M − 1)), so they are short by up to 1/M of the part, and the
    pixel parts leak about σ²_pixel/(MN − M − N) into the others: the tolerance is that bias
    plus 4 standard errors of the mean over the sensors. Dropping the 1/L of the noise terms
    moves the pixel part by 15/16 of σ²_stack = 2.3 DN², far beyond it."""
    s_row, s_col, s_pix = parts
    Mb, Nb, L, s2_stack = 160, 240, 16, 2.5
    rng = np.random.default_rng(11)
    est = np.array([[getattr(variance_split(
        _model_image(rng, Mb, Nb, s_row, s_col, s_pix)
        + rng.normal(0, math.sqrt(s2_stack / L), (Mb, Nb)), s2_stack, L), f"s2_{k}")
        for k in ("row", "col", "pixel")] for _ in range(40)])
    for j, want in enumerate(parts):
        sem = est[:, j].std(ddof=1) / math.sqrt(est.shape[0])
        bias = want / min(Mb, Nb) + s_pix / (Mb * Nb - Mb - Nb) + 1e-12
        assert abs(est[:, j].mean() - want) <= bias + 4 * sem, (j, est[:, j].mean(), want)


def _double_centred(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    p = rng.normal(size=shape)
    return p - p.mean(axis=0, keepdims=True) - p.mean(axis=1, keepdims=True) + p.mean()


def test_stated_errors_match_the_scatter_over_noise_draws():
    """One fixed pattern, 300 draws of the temporal noise left in the average: the standard
    deviation of each part over the draws is its stated error (module tolerances)."""
    rng = np.random.default_rng(7)
    pattern = (rng.normal(0, 1.0, (M, 1)) + rng.normal(0, 1.5, (1, N))
               + rng.normal(0, 2.0, (M, N)))
    s2_stack, L = 16.0, 4                                 # noise 4 DN² per pixel in the average
    draws = [variance_split(pattern + rng.normal(0, math.sqrt(s2_stack / L), (M, N)),
                            s2_stack, L) for _ in range(300)]
    for name in ("s2", "s2_row", "s2_col", "s2_pixel"):
        values = np.array([getattr(d, name) for d in draws])
        stated = float(np.median([getattr(d, f"{name}_err") for d in draws]))
        assert 0.8 <= values.std(ddof=1) / stated <= 1.25, (name, values.std(ddof=1), stated)


def test_a_part_below_its_noise_is_not_determinable_with_a_bound():
    """No row pattern in the dark image (its pixel part has no row means either): DSNU1288_row
    is None, its note says why and gives the bound √(max(s², 0) + 2σ)/K; the parts that are
    there have values √s²/K and errors."""
    rng = np.random.default_rng(3)
    K, K_err = 0.1, 0.001
    dark_img = 10.0 + rng.normal(0, 3.0, (1, N)) + 4.0 * _double_centred(rng, (M, N))
    bright_img = (dark_img + 500.0 * (1.0 + rng.normal(0, 0.004, (M, 1))
                                      + 0.01 * _double_centred(rng, (M, N))))
    dark = variance_split(dark_img + rng.normal(0, 0.5, (M, N)), 4.0, 16)
    bright = variance_split(bright_img + rng.normal(0, 0.5, (M, N)), 4.0, 16)
    s = nonuniformity_split(bright, dark, K, K_err)
    v, e = dark.part("row")
    assert not v > DETERMINABLE_Z * e
    assert s.DSNU1288_row is None and s.DSNU1288_row_err is None
    bound = dict(s.bounds)["DSNU1288_row"]
    assert bound == pytest.approx(math.sqrt(max(v, 0.0) + DETERMINABLE_Z * e) / K)
    assert any(n.startswith("DSNU1288_row is not determinable") and f"{bound:.3g}" in n
               for n in s.notes)
    assert s.DSNU1288_pixel == pytest.approx(math.sqrt(dark.s2_pixel) / K)
    assert s.DSNU1288_pixel_err > 0
    signal = bright.mean - dark.mean
    assert s.PRNU1288_pixel == pytest.approx(
        100.0 * math.sqrt(bright.s2_pixel - dark.s2_pixel) / signal)
    assert s.PRNU1288_col is None             # the bright image adds no column part
    assert set(s.figures()) == {f"{w}_{p}{e}" for w in ("DSNU1288", "PRNU1288")
                                for p in ("row", "col", "pixel") for e in ("", "_err")}


# ----------------------------------------------------------------------------- spectrogram --
def test_spectrogram_keeps_the_variance_and_finds_a_line_pattern():
    """Parseval: the one-sided power, weighted 1 at 0 and the Nyquist frequency and 2 between,
    sums to n times the mean power per pixel (exact for each line); a column pattern of period 8
    pixels peaks at 1/8 cycle per pixel horizontally and not vertically; white noise of variance
    σ² lies at σ."""
    rng = np.random.default_rng(5)
    img = rng.normal(0, 2.0, (64, 64))
    f, amp = spectrogram(img)
    assert f[0] == 0 and f[-1] == pytest.approx(0.5) and f.size == 33
    w = np.ones(f.size)
    w[1:-1] = 2.0
    centred = img - img.mean()
    assert float(np.sum(w * amp ** 2)) == pytest.approx(float(np.mean(centred ** 2)) * 64,
                                                        rel=1e-12)
    big = rng.normal(0, 2.0, (512, 64))
    assert float(np.mean(spectrogram(big)[1][1:-1] ** 2)) == pytest.approx(4.0, rel=0.03)
    cols = np.sin(2 * np.pi * np.arange(64) / 8.0)[None, :] * np.ones((64, 1))
    fh, ah = spectrogram(cols)
    fv, av = spectrogram(cols, vertical=True)
    assert fh[int(np.argmax(ah))] == pytest.approx(1 / 8)
    assert float(av[1:].max()) < 1e-9           # the columns' offsets are all at f = 0


def test_high_pass_and_histograms():
    """The high-pass image of a constant is zero and loses size//2 pixels at each edge; the
    histogram counts every value once and its normal model holds as many; the accumulated
    histogram starts at 100 % and falls."""
    assert np.all(high_pass(np.full((20, 30), 7.0)) == 0)
    assert high_pass(np.zeros((20, 30))).shape == (20 - 2 * (HIGH_PASS_SIZE // 2),
                                                   30 - 2 * (HIGH_PASS_SIZE // 2))
    rng = np.random.default_rng(2)
    v = rng.normal(3.0, 2.0, 20000)
    h = defect_histogram(v)
    assert int(h["count"].sum()) == v.size and h["x"][0] == pytest.approx(v.min())
    assert float(h["model"].sum()) == pytest.approx(v.size, rel=0.02)
    a = accumulated_histogram(v)
    assert a["percent"][0] == pytest.approx(100.0)
    assert np.all(np.diff(a["percent"]) <= 0)
    # about 4.55 % of normal values deviate by 2 σ or more
    i = int(np.searchsorted(a["x"], 4.0))
    assert a["percent"][i] == pytest.approx(4.55, abs=0.6)


def test_profiles_keep_extremes_when_reduced():
    rng = np.random.default_rng(4)
    img = rng.normal(0, 1.0, (40, 3000))
    p = profiles(img, points=1000)
    assert p["mean"].size == 1000
    assert float(p["min"].min()) == float(img.min()) and float(p["max"].max()) == float(img.max())
    assert float(p["mean"].mean()) == pytest.approx(float(img.mean()), rel=1e-9, abs=1e-12)
    q = profiles(img[:, :300], vertical=True)
    assert q["mean"].size == 40 and q["index"][-1] == 39


def test_histogram_of_quantised_values_fills_every_bin_alike():
    """Values on a grid of step q (an average of L integer frames): with ``quantum`` every bin
    spans a whole number of steps, so a flat distribution fills the bins evenly; 256 equal bins
    narrower than a step leave most empty."""
    q = 1.0 / 16
    v = np.repeat(np.arange(1000) * q, 7)                  # flat on the grid, 7 of each
    plain = defect_histogram(v)
    grid = defect_histogram(v, quantum=q)
    assert int(grid["count"].sum()) == v.size
    assert len(grid["count"]) <= 257
    widths = np.diff(np.r_[grid["x"], grid["x"][-1] + (grid["x"][1] - grid["x"][0])])
    steps = int(round(widths[0] / q))
    assert np.allclose(widths / q, steps)
    assert set(grid["count"][:-1].tolist()) == {7 * steps}   # the last bin may hold fewer
    assert len(set(plain["count"][:-1].tolist())) > 1          # 3.9 steps a bin: 3 or 4
    few = np.repeat(np.arange(60) * q, 5)                   # fewer steps than bins
    assert np.sum(defect_histogram(few)["count"] == 0) > 100
    assert np.all(defect_histogram(few, quantum=q)["count"] == 5)
