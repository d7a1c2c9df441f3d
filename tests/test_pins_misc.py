"""Pins for planted bugs that the other tests let through: dark current, DSNU plots,
photon-transfer exclusion rules, product maps, plain folders, datasheet dark plots, capture plan.

Each test checks the library against an expectation worked out independently of its code: a
textbook formula (scipy's ordinary least squares), the EMVA 1288 definitions, Healey &
Kondepudy 1994's rules as the docstrings state them, a Monte Carlo, or inputs built by hand
whose answer is worked out in the comments. Seeds are fixed, and each tolerance says why it is
what it is.

1. ``emva_dark._line``: a scattered line's slope error scaled by sqrt(chi2/nu), not chi2/nu;
2. ``emva_spatial.spatial_plots``: the DSNU spectrogram's white-noise floor sigma/sqrt(L_dark)
   (not sqrt(L)), and the DSNU histogram's bins in electrons (whole quanta of 1/(L_dark K));
3. ``ptc_fit``: the saturation, linearity and range rules on both sides of their thresholds
   (exactly at them too), and the "lower half" of an odd number of levels;
4. ``product_file``: flat-field maps of different shapes refused by save and on load;
5. ``session.folder``: repeated exposures split into brackets only when EVERY chunk holds each
   exposure once, and a small JPEG at another exposure not making a folder a bracket;
6. ``capture``: the plan's predicted sigma(A) with the black level removed (eq. 66, checked by
   a Monte Carlo);
7. ``datasheet_files``: the dark-signal and dark-variance plots each drawing its own points and
   line, and drawn with darks at two exposure times.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from ccdcore.emva import dark as emva_dark
from ccdcore.emva.spatial import spatial_plots
from ccdcore.ptc_fit import (PtcPoint, linearity_reasons, range_reasons,
                             saturation_reasons)


# ------------------------------------------------------------ 1. dark current error -----
def _ols_slope_se(t, y):
    """The textbook standard error of an unweighted least-squares slope, from the scatter of
    the points: sqrt(SSR / ((n - 2) S_tt)) -- scipy.stats.linregress's ``stderr``."""
    return stats.linregress(t, y).stderr


def test_dark_current_error_scaled_by_root_of_reduced_chi2():
    """Points of equal error sigma that scatter far more than sigma: the slope's error
    sqrt(sum c_i^2 sigma^2) = sigma / sqrt(S_tt) scaled by sqrt(chi2/nu), with
    chi2 = SSR / sigma^2, is the textbook OLS standard error sqrt(SSR / (nu S_tt)) (scipy),
    independent of sigma.  Here chi2/nu is about 20, so scaling by chi2/nu instead of its
    square root is 4.5 times too large.  mu_I = slope / K and slope / K^2 with K_err = 0.

    Tolerance 1e-9 relative: the same sums in another order (rounding only)."""
    t = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0])
    wiggle = np.array([0.5, -0.5, 0.4, -0.6, 0.5, -0.3, 0.2])
    mu = 10.0 + 2.0 * t + wiggle          # DN, slope 2 DN/s
    s2 = 4.0 + 3.0 * t - 0.8 * wiggle     # DN^2, slope 3 DN^2/s
    sigma_mu = np.full(t.size, 0.1)
    sigma_s2 = np.full(t.size, 0.08)
    K = 2.0
    dc = emva_dark.dark_current(list(t), mu, sigma_mu, s2, sigma_s2, K, 0.0)
    chi2_mu = float(np.sum((mu - np.polyval(np.polyfit(t, mu, 1), t)) ** 2) / 0.1 ** 2) / 5
    assert chi2_mu > 10.0                                  # the case under test
    assert dc.mean_line.chi2_dof == pytest.approx(chi2_mu, rel=1e-9)
    se_mu, se_s2 = _ols_slope_se(t, mu), _ols_slope_se(t, s2)
    assert dc.mean_line.slope_err == pytest.approx(se_mu, rel=1e-9)
    assert dc.var_line.slope_err == pytest.approx(se_s2, rel=1e-9)
    assert dc.u_I_mean == pytest.approx(stats.linregress(t, mu).slope / K, rel=1e-9)
    assert dc.u_I_mean_err == pytest.approx(se_mu / K, rel=1e-9)
    assert dc.u_I_var == pytest.approx(stats.linregress(t, s2).slope / K ** 2, rel=1e-9)
    assert dc.u_I_var_err == pytest.approx(se_s2 / K ** 2, rel=1e-9)


def test_dark_current_error_not_shrunk_when_points_scatter_less():
    """chi2/nu < 1: the error stays the propagated sigma / sqrt(S_tt) (no scaling down).
    Tolerance 1e-9 relative: rounding only."""
    t = np.array([1.0, 2.0, 4.0, 8.0])
    mu = 5.0 + 1.5 * t + np.array([0.01, -0.01, 0.01, -0.005])
    sig = np.full(4, 0.2)
    dc = emva_dark.dark_current(list(t), mu, sig, mu, sig, 1.0, 0.0)
    stt = float(np.sum((t - t.mean()) ** 2))
    assert dc.mean_line.chi2_dof < 1.0
    assert dc.mean_line.slope_err == pytest.approx(0.2 / math.sqrt(stt), rel=1e-9)


# ------------------------------------------------- 2. DSNU spectrogram and histogram -----
def _dark_stack(seed, L_dark, shape=(48, 64), sigma=None):
    """L_dark integer dark frames: an offset with a fixed pattern (0..3 DN) plus temporal
    noise (0..4 DN uniform integers, or Gaussian of ``sigma`` rounded)."""
    rng = np.random.default_rng(seed)
    pattern = rng.integers(0, 4, shape)
    if sigma is None:
        frames = 100 + pattern + rng.integers(0, 5, (L_dark,) + shape)
    else:
        frames = np.round(100 + rng.normal(0.0, sigma, (L_dark,) + shape))
    return frames.astype(np.int64)


def test_dsnu_spectrogram_floor_uses_the_dark_frame_count():
    """The floor drawn on the DSNU spectrogram is the temporal noise left in the average of the
    L_dark dark frames, sigma_y.stack.dark / sqrt(L_dark) (sec. 8.2), with L (the bright set's
    count) different from L_dark.  Monte Carlo: the dark average of L_dark = 4 frames of white
    noise (sigma 3 DN, no pattern) has its spectrogram's mean power at that floor (Parseval:
    the mean power over the frequencies is the variance).

    Tolerances: the level is sqrt(9 / 4) = 1.5 exactly (1e-12); the mean power of 48 x 256
    pixels has a relative standard error sqrt(2 / 12288) = 1.3 % (plus 1/12 DN^2 rounding, 1 %):
    5 % is about 3 standard errors."""
    L_dark, L = 4, 16
    frames = _dark_stack(7, L_dark, shape=(48, 256), sigma=3.0).astype(np.float64)
    dark = frames.mean(axis=0)
    bright = dark + 1000.0
    s2_dark = float(frames.var(axis=0, ddof=1).mean())
    p = spatial_plots(bright, dark, L=L, L_dark=L_dark, s2_stack=25.0, s2_stack_dark=9.0, K=2.0)
    assert p.levels["sigma_y_stack_dark"] == pytest.approx(3.0, rel=1e-12)
    assert p.levels["sigma_y_stack_dark_avg"] == pytest.approx(1.5, rel=1e-12)
    assert p.levels["sigma_y_stack_avg_percent"] == pytest.approx(100 * 5.0 / 4.0 / 1000.0,
                                                                  rel=1e-9)
    # the floor is where the spectrogram of the dark average lies
    p2 = spatial_plots(bright, dark, L=L, L_dark=L_dark, s2_stack=25.0, s2_stack_dark=s2_dark,
                       K=2.0)
    amp = np.asarray(p2.spectrograms["DSNU_horizontal"]["amplitude"])[1:]
    floor = p2.levels["sigma_y_stack_dark_avg"]
    assert math.sqrt(float(np.mean(amp ** 2))) == pytest.approx(floor, rel=0.05)


@pytest.mark.parametrize("L_dark, K", [(4, 2.5), (3, 0.4)])
def test_dsnu_histogram_bins_are_quanta_in_electrons(L_dark, K):
    """The DSNU histogram (sec. 8.3) is of (<y_dark> - mu_y.dark) / K in electrons; the
    average of L_dark integer frames takes values 1/L_dark DN = 1/(L_dark K) e- apart, so with
    fewer distinct values than 256 bins each bin is one quantum wide, its edges half a quantum
    off the values, and each holds exactly the pixels of one sum of the L_dark frames (counted
    here with bincount).  K != 1 tells electrons from DN.

    Tolerance: edges 1e-9 of a quantum (rounding of values of order 10 e-)."""
    frames = _dark_stack(3, L_dark)
    sums = frames.sum(axis=0)
    dark = sums / L_dark
    v = (dark - dark.mean()) / K                         # electrons
    q = 1.0 / (L_dark * K)
    p = spatial_plots(dark + 500.0, dark, L=8, L_dark=L_dark, s2_stack=4.0, s2_stack_dark=2.0,
                      K=K)
    h = p.histograms["DSNU"]
    x, count = np.asarray(h["x"]), np.asarray(h["count"])
    expected = np.bincount((sums - sums.min()).ravel())
    assert expected.size < 256
    assert count.size == expected.size
    np.testing.assert_array_equal(count, expected)
    np.testing.assert_allclose(np.diff(x), q, rtol=0, atol=1e-9 * q)
    assert x[0] == pytest.approx(v.min() - 0.5 * q, abs=1e-9 * q)
    # the normal model of the same mean (0) and deviation, in counts per bin of width q
    centre = x + 0.5 * q
    model = v.size * q / (math.sqrt(2 * math.pi) * v.std()) * np.exp(
        -0.5 * (centre / v.std()) ** 2)
    np.testing.assert_allclose(h["model"], model, rtol=1e-9)
    # the accumulated histogram: deviations in electrons, 100 % at zero
    acc = p.accumulated["DSNU"]
    assert acc["percent"][0] == pytest.approx(100.0)
    assert acc["x"][-1] < np.abs(v).max() <= acc["x"][-1] + np.abs(v).max() / 255.0 + 1e-12


# ---------------------------------------------------- 3. photon-transfer exclusions -----
def _pt(level, mu, var, var_err, exposure=None, mu_raw=None):
    return PtcPoint(level=level, mu=mu, var=var, var_err=var_err, n_pairs=1, n_pixels=10000,
                    used=True, reason=None, exposure=exposure,
                    mu_raw=mu if mu_raw is None else mu_raw, clipped_fraction=0.0)


def _saturation(drop, peak_err, err, tol):
    """Level 2 is the peak (var 100 DN^2 at mu 200); level 3, at a higher mean, is ``drop``
    below it; level 4 has the peak's mean exactly and a far lower variance."""
    pts = [_pt(1, 100.0, 50.0, 1.0), _pt(2, 200.0, 100.0, peak_err),
           _pt(3, 300.0, 100.0 - drop, err), _pt(4, 200.0, 10.0, 0.1)]
    return saturation_reasons(pts, tol)


@pytest.mark.parametrize("drop, excluded", [(24.5, False), (25.0, False), (25.5, True)])
def test_saturation_z_threshold_both_sides(drop, excluded):
    """Excluded when the drop exceeds LINEARITY_Z = 5 combined errors: hypot(3, 4) = 5 DN^2 so
    the threshold is a drop of 25 DN^2 (exactly representable: "more than" leaves it in); the
    relative tolerance (1 %) is passed at all three.  A level at the peak's mean is never
    beyond it ("a level of higher mu")."""
    out = _saturation(drop, 3.0, 4.0, 0.01)
    assert (3 in out) is excluded
    assert 4 not in out and 1 not in out
    if excluded:
        assert out[3][0] == "saturation"


@pytest.mark.parametrize("drop, excluded", [(24.5, False), (25.0, False), (25.5, True)])
def test_saturation_tolerance_both_sides(drop, excluded):
    """The relative rule: the drop must exceed tol x peak = 0.25 x 100 = 25 DN^2 (exact); the
    errors (hypot(0.3, 0.4) = 0.5) make z about 50, past 5 at all three."""
    assert ((3 in _saturation(drop, 0.3, 0.4, 0.25)) is excluded)


def test_linearity_lower_half_of_an_odd_number_of_levels():
    """Five levels at exposures 1..5 s: the line of mu against exposure is fitted on the lower
    half, (5 + 1) // 2 = 3 levels (the module docstring's rule; n_fit = max(2, ceil(n / 2))),
    and tested at the two above.  Means 100, 200, 330, 400, 500 DN.  By hand: the line through
    (1, 100), (2, 200), (3, 330) has slope 115 and intercept -20, so level 4 is predicted
    440 (signal 460: -8.7 %) and level 5 555 (signal 575: -9.6 %), both beyond 5 %; level 3
    is in the fit.  (Fitting the lower 2 only would flag level 3 at +10 % and keep 4 and 5.)"""
    mus = [100.0, 200.0, 330.0, 400.0, 500.0]
    pts = [_pt(i + 1, m, 2.0 * m, 1.0, exposure=float(i + 1)) for i, m in enumerate(mus)]
    out = linearity_reasons(pts, 0.05)
    assert set(out) == {4, 5}
    assert all(code == "nonlinear" for code, _ in out.values())
    # in the order given or not: the rule sorts by exposure
    assert set(linearity_reasons(pts[::-1], 0.05)) == {4, 5}


@pytest.mark.parametrize("factor, excluded", [(1 + 0.05 * (1 + 1e-6), True),
                                              (1 + 0.05 * (1 - 1e-6), False),
                                              (1 - 0.05 * (1 + 1e-6), True),
                                              (1 - 0.05 * (1 - 1e-6), False)])
def test_linearity_with_exposures_both_sides_of_tolerance(factor, excluded):
    """Four levels: the lower two (100 and 200 DN at 1 and 2 s) give the line 100 DN/s through
    zero; level 3 at 3 s is 300 x factor DN, 1e-6 of the tolerance inside or outside 5 %
    (far beyond the rounding of a two-point fit, ~1e-14); level 4 on the line."""
    mus = [100.0, 200.0, 300.0 * factor, 400.0]
    pts = [_pt(i + 1, m, 2.0 * m, 1.0, exposure=float(i + 1)) for i, m in enumerate(mus)]
    out = linearity_reasons(pts, 0.05)
    assert (3 in out) is excluded
    assert 4 not in out


def _variance_points(top_mu, top_var, top_err):
    """Nine levels at mu 0, 10, ..., 80 DN on sigma^2 = 2 mu + 10 (errors 1 DN^2) and one at
    ``top_mu``; no exposure, no photons: the variance rule of the top 10 % applies."""
    pts = [_pt(i, 10.0 * i, 2.0 * 10.0 * i + 10.0, 1.0) for i in range(9)]
    return pts + [_pt(99, top_mu, top_var, top_err)]


def _pred_std(mu):
    """The 1-sigma band of the weighted line through the nine lower levels at ``mu``:
    sqrt(x^T (X^T W X)^-1 x), written out with numpy's inverse."""
    X = np.column_stack([10.0 * np.arange(9), np.ones(9)])
    cov = np.linalg.inv(X.T @ X)                         # W = identity (errors 1)
    x = np.array([mu, 1.0])
    return math.sqrt(float(x @ cov @ x))


@pytest.mark.parametrize("z, excluded", [(5.02, True), (4.98, False), (-5.02, True),
                                         (-4.98, False)])
def test_variance_linearity_z_both_sides(z, excluded):
    """The top level at mu = 100 (the top 10 % of 0..100): its sigma^2 is z combined errors
    (hypot(its error 3, the line's band)) from the line's 210 DN^2, about 15 DN^2 or 7 %,
    past the 5 % tolerance.  0.4 % of the threshold either side: far beyond rounding."""
    s = math.hypot(3.0, _pred_std(100.0))
    out = linearity_reasons(_variance_points(100.0, 210.0 + z * s, 3.0), 0.05)
    assert abs(z * s / 210.0) > 0.06
    assert (99 in out) is excluded
    assert not set(out) - {99}


@pytest.mark.parametrize("rel, excluded", [(0.0502, True), (0.0498, False), (-0.0502, True),
                                           (-0.0498, False)])
def test_variance_linearity_tolerance_both_sides(rel, excluded):
    """The same with an error of 0.05 DN^2: z is about 200, so the 5 % tolerance decides."""
    out = linearity_reasons(_variance_points(100.0, 210.0 * (1 + rel), 0.05), 0.05)
    assert (99 in out) is excluded


def test_variance_linearity_top_ten_percent_includes_its_boundary():
    """Levels at 0..80 and 90 and 100 DN: the top 10 % of the range 0..100 starts at 90 DN
    (0.9 x 100 = 90.0 exactly), and "lies in the top 10 %" includes it.  The level at 90 is
    far off the line (+50 %) and excluded; at 100 it is on the line and kept."""
    pts = _variance_points(100.0, 210.0, 1.0)
    pts.append(_pt(90, 90.0, 1.5 * 190.0, 1.0))
    out = linearity_reasons(pts, 0.05)
    assert set(out) == {90}


@pytest.mark.parametrize("mu, out_of_range", [(70.0, False), (70.0001, True), (69.9999, False)])
def test_fit_range_boundary(mu, out_of_range):
    """EMVA 1288 fit range: above 70 % of the saturation signal (the mean of the level of
    largest variance, 100 DN: 0.7 x 100 = 70.0 exactly) is out; at 70 % it is in.  A level
    already excluded is not reported again."""
    pts = [_pt(1, 10.0, 20.0, 1.0), _pt(2, mu, 150.0, 1.0), _pt(3, 100.0, 200.0, 1.0),
           _pt(4, 90.0, 100.0, 1.0)]
    out = range_reasons(pts, {4: ("saturation", "x")}, 0.7)
    assert (2 in out) is out_of_range
    assert 3 in out and 4 not in out and 1 not in out


# ------------------------------------------------------- 4. product maps' shapes -----
def test_flat_maps_of_different_shapes_refused_on_save_and_on_load(tmp_path):
    """The flat-field maps (one family) must share a shape: save refuses a product where
    flat_G and flat_O differ, and a product folder whose flat_O was replaced by a map of
    another shape is refused on load with an error naming the shapes.  Maps of the two
    families may differ (a colour flat field beside a mono-shaped dark)."""
    from ccdcore.errors import CcdError
    from ccdcore.io.frames import write_map
    from ccdcore.map_names import MapName
    from ccdcore.product.file import CalibrationProduct, load_product

    g = np.full((4, 6), 1.25, np.float32)
    o = np.full((4, 6), -2.0, np.float32)
    bad = CalibrationProduct(maps={MapName.FLAT_G: g, MapName.FLAT_O: np.zeros((5, 7),
                                                                              np.float32)})
    with pytest.raises(CcdError, match="different shapes"):
        bad.save(tmp_path / "bad")
    assert not (tmp_path / "bad" / "calibration.json").exists()

    good = CalibrationProduct(maps={MapName.FLAT_G: g, MapName.FLAT_O: o,
                                    MapName.DARK: np.zeros((3, 5), np.float32)})
    folder = good.save(tmp_path / "p")
    back = load_product(folder)                      # the two families differ: accepted
    np.testing.assert_array_equal(back.maps[MapName.FLAT_O], o)

    write_map(folder / "maps" / "flat_O.exr", np.zeros((5, 7), np.float32))
    with pytest.raises(CcdError) as err:
        load_product(folder)
    text = str(err.value)
    assert "different shapes" in text and "(5, 7)" in text and "(4, 6)" in text
    assert "flat_O" in text and "flat_G" in text


# ------------------------------------------------------- 5. plain folders' brackets -----
_CAMERA = {"Make": "Canon", "Model": "Canon EOS 80D", "Exif:ISOSpeedRatings": 100,
           "FNumber": 8.0}


def _jpeg(root, rel, seconds, shape=(24, 32)):
    """A colour JPEG of a gradient exposed ``seconds``, with that EXIF ExposureTime."""
    from ccdcore.io.frames import write_image

    y, x = np.mgrid[0:shape[0], 0:shape[1]]
    img = np.clip((1.0 + 7 * x + 3 * y)[..., None] * np.array([1.0, 0.8, 0.6]) * seconds * 180,
                  0, 255)
    return write_image(root / rel, np.round(img).astype(np.uint8), exposure=seconds,
                       attributes=_CAMERA)


def test_repeated_exposures_split_only_when_every_chunk_holds_each_once(tmp_path):
    """Six frames whose exposures, in file-name order, are a b c | a a b: the first three
    hold every exposure once but the last three do not, so this is not two repeated brackets
    (the rule: "each time with every exposure once").  It is one bracket of six frames, with
    one duplicate-exposure error per shared exposure time (1/250 s three times, 1/60 s
    twice) naming the files."""
    from ccdcore.session import open_session

    root = tmp_path / "seq"
    a, b, c = 1 / 250, 1 / 60, 1 / 15
    for i, t in enumerate((a, b, c, a, a, b)):
        _jpeg(root, f"IMG_{i:02d}.JPG", t)
    s = open_session(root)
    assert s.roles() == {"bracket": 6}
    assert [r.stack for r in s.frames] == [1] * 6
    dup = sorted(p.message for p in s.problems if p.code == "duplicate-exposure")
    assert len(dup) == 2
    assert dup[0].startswith("2 frames of one bracket have the same exposure time 1/60 s")
    assert "IMG_01.JPG, IMG_05.JPG" in dup[0]
    assert dup[1].startswith("3 frames of one bracket have the same exposure time 1/250 s")
    assert "IMG_00.JPG, IMG_03.JPG, IMG_04.JPG" in dup[1]
    assert not s.ok


def test_repeated_complete_sequences_are_still_split(tmp_path):
    """The other side: a b c | c a b (each chunk holds every exposure once, in any order) is
    two brackets."""
    from ccdcore.session import open_session

    root = tmp_path / "seq2"
    a, b, c = 1 / 250, 1 / 60, 1 / 15
    for i, t in enumerate((a, b, c, c, a, b)):
        _jpeg(root, f"IMG_{i:02d}.JPG", t)
    s = open_session(root)
    assert s.ok, s.problems
    assert [r.stack for r in s.frames] == [1, 1, 1, 2, 2, 2]


def test_thumbnail_at_another_exposure_does_not_make_a_bracket(tmp_path):
    """Three photos at 1/125 s (24 x 32) and a small JPEG (12 x 16) at 1/500 s: the frames of
    the common size have one exposure time, so the folder is not a bracket (the rule counts the
    exposures of the frames sharing the common size); everything stays a scene, no error."""
    from ccdcore.session import open_session

    root = tmp_path / "photos"
    for i in range(3):
        _jpeg(root, f"IMG_{i:02d}.JPG", 1 / 125)
    _jpeg(root, "IMG_03.JPG", 1 / 500, shape=(12, 16))
    s = open_session(root)
    assert s.roles() == {"scene": 4}
    assert s.ok, s.problems
    assert not [p for p in s.problems if p.code in ("mismatch", "duplicate-exposure")]


# ----------------------------------------------- 6. the capture plan's sigma(A) -----
def test_capture_plan_gain_error_above_the_black_level():
    """The plan's predicted sigma(A)/A for a ladder with a large black level b0 = 1500 DN
    (12 bits, A = 0.5 DN/e-, sigma_C^2 = 20 DN^2, M = 4096 pixels, 5 levels spread over
    PTC_SPAN of the range above b0).  Expected from Healey & Kondepudy's appendix written out
    with its scalar sums: at each level sigma_N^2 = A (mu - b0) + sigma_C^2 (eq. 41 with the
    offset removed), var[sigma_N^2] = 2 sigma_N^4 / (M - 1) (eq. 40), w = 1 / var; S1 = sum w,
    S2 = sum w x, S4 = sum w x^2 with x = mu - b0 (eqs. 61, 62, 64), var(A) = S1 / (S1 S4 -
    S2^2) (eq. 66).  Tolerance 1e-9 relative: the same sums in another order.

    A Monte Carlo checks the formula itself: 4000 ladders whose sigma_N^2 estimates are
    sigma_N^2 chi^2_{M-1} / (M - 1), each fitted by the weighted line (eqs. 59-65); the spread
    of A_hat has a relative standard error 1/sqrt(2 x 4000) = 1.1 %: 5 % is over 4 of them."""
    from ccdcore.capture import PTC_SPAN, plan_captures, predicted_gain_error

    bits, A, c2, b0, M, P = 12, 0.5, 20.0, 1500.0, 4096, 5
    plan = plan_captures(bits, A, sigma_c2=c2, black_level=b0, pixels=M, ptc_levels=P)
    full = 2.0 ** bits - 1
    x = np.linspace(PTC_SPAN[0], PTC_SPAN[1], P) * (full - b0)       # mu - b0
    s2 = A * x + c2
    w = (M - 1) / (2 * s2 ** 2)
    S1, S2, S4 = w.sum(), (w * x).sum(), (w * x * x).sum()
    sigma_A = math.sqrt(S1 / (S1 * S4 - S2 ** 2))
    assert plan.gain_rel_err == pytest.approx(sigma_A / A, rel=1e-9)
    assert f"predicted σ(A)/A = {sigma_A / A:.2%}" in next(g for g in plan.groups if g.role == "ptc").rule
    assert predicted_gain_error(b0 + x, A, c2, M, b0) == pytest.approx(sigma_A, rel=1e-9)

    rng = np.random.default_rng(2024)
    R = 4000
    y = s2 * rng.chisquare(M - 1, (R, P)) / (M - 1)                  # sigma_N^2 estimates
    S3, S5 = (w * y).sum(axis=1), (w * x * y).sum(axis=1)
    A_hat = (S1 * S5 - S2 * S3) / (S1 * S4 - S2 ** 2)                # eq. 59
    assert float(A_hat.std(ddof=1)) == pytest.approx(sigma_A, rel=0.05)


# ----------------------------------------------- 7. the datasheet's dark plots -----
def _dark_figures(times, seed=5):
    """Dark points (two frames each) at exposure times ``times``: mean 100 + 2 t DN, variance
    9 + 30 t DN^2, with a little scatter, and the dark current of them, as the datasheet reads
    them from the figures (``dark_points``, ``dark_current``; the rest of the figures absent)."""
    from types import SimpleNamespace

    from ccdcore.emva.results import DarkPointSummary

    rng = np.random.default_rng(seed)
    t = np.asarray(times, np.float64)
    mu = 100.0 + 2.0 * t + rng.normal(0, 0.05, t.size)
    s2 = 9.0 + 30.0 * t + rng.normal(0, 0.3, t.size)
    mu_err, s2_err = np.full(t.size, 0.05), np.full(t.size, 0.3)
    pts = tuple(DarkPointSummary(exposure=float(t[i]), u_y_dark=float(mu[i]),
                                 u_y_dark_err=0.05, s2_y_dark=float(s2[i]), s2_y_dark_err=0.3,
                                 relpaths=(f"d{i}a.tif", f"d{i}b.tif")) for i in range(t.size))
    dc = emva_dark.dark_current(list(t), mu, mu_err, s2, s2_err, 1.5, 0.0).summary()
    emva = SimpleNamespace(dark_points=pts, dark_current=dc, points=(),
                           snr_curve=SimpleNamespace(u_p=()), spatial_plots=None)
    return emva, t, mu, s2


@pytest.mark.parametrize("times, drawn", [((0.01,), False), ((0.01, 0.01), False),
                                          ((0.01, 0.05), True), ((0.01, 0.05, 0.05), True)])
def test_dark_plots_need_two_exposure_times(times, drawn):
    """Sec. 7's plots of the dark signal and variance against the exposure time need two
    distinct known exposure times (a line needs two; the dark current three): drawn with two,
    skipped with one (whatever the number of points)."""
    from ccdcore.emva.datasheet_files import plot_plan

    plan = plot_plan(_dark_figures(times)[0])
    assert ("dark_signal" in plan.drawn) is drawn
    assert ("dark_variance" in plan.drawn) is drawn
    skipped = dict(plan.skipped)
    assert ("dark_signal" in skipped) is not drawn
    if not drawn:
        assert "1 known exposure time" in skipped["dark_variance"]


def _plotted(name, emva):
    """(points' x, points' y, line's x, line's y) of the datasheet plot ``name`` drawn on a
    matplotlib figure (the line: None without a dark current)."""
    # matplotlib is the datasheet extra, part of the test extra: never skipped
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ccdcore.emva.datasheet_files import draw_plot

    fig = Figure()
    FigureCanvasAgg(fig)
    draw_plot(name, fig, emva)
    (ax,) = fig.axes
    points = [ln for ln in ax.lines if ln.get_marker() == "o"]
    lines = [ln for ln in ax.lines if ln.get_marker() != "o" and ln.get_linestyle() == "-"]
    (p,) = points
    fit = lines[0].get_data() if lines else (None, None)
    assert len(lines) <= 1
    return (np.asarray(p.get_xdata(), float), np.asarray(p.get_ydata(), float),
            None if fit[0] is None else np.asarray(fit[0], float),
            None if fit[1] is None else np.asarray(fit[1], float))


def test_dark_signal_and_variance_plots_draw_their_own_data_and_lines():
    """The dark-signal plot shows mu_y.dark and the unweighted least-squares line of it against
    t (the line whose slope / K is mu_I.mean; numpy's polyfit here); the dark-variance plot
    sigma^2_y.dark and its own line.  The two lines differ (slopes 2 DN/s and 30 DN^2/s), so
    drawing one's line on the other's plot fails.  Tolerance 1e-9 relative: the same
    least-squares line computed two ways (rounding only)."""
    emva, t, mu, s2 = _dark_figures((0.01, 0.02, 0.05, 0.1, 0.2))
    for name, y in (("dark_signal", mu), ("dark_variance", s2)):
        px, py, lx, ly = _plotted(name, emva)
        np.testing.assert_allclose(px, t, rtol=1e-12)
        np.testing.assert_allclose(py, y, rtol=1e-12)
        slope, offset = np.polyfit(t, y, 1)
        np.testing.assert_allclose(lx, [t.min(), t.max()], rtol=1e-12)
        np.testing.assert_allclose(ly, offset + slope * lx, rtol=1e-9)
    # two exposure times: the points are drawn, without a line (no dark current below three)
    emva2, t2, mu2, s22 = _dark_figures((0.01, 0.05))
    for name, y in (("dark_signal", mu2), ("dark_variance", s22)):
        px, py, lx, _ = _plotted(name, emva2)
        np.testing.assert_allclose(py, y, rtol=1e-12)
        assert lx is None
