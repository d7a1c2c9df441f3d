"""Edge pins of the dark reference (Healey & Kondepudy 1994 sec. V-A, eq. 43: ccdcore.dark.frame,
ccdcore.dark.map) and of the flat field's results and held-out check (de Lasarte et al. 2007,
eqs. 2-5: ccdcore.flatfield.results, ccdcore.flatfield.check).

What is pinned, each against an expectation derived by hand or from numpy/scipy on the same
data (never a snapshot): the hot and dead rules at a value exactly k·1.4826·MAD from the median
(strict), the MAD = 0 fallback, the noisy rule's scaled χ² threshold with noisy_factor != 1,
the stuck rule's expected false flags on both sides of 0.01, a pixel both hot and dead; the
exposure helpers (ratio distance, ties to the longer); the dark reference from the dark model;
sem, spatial_std_signal, the summary's standard error and "good" figures; G's relative error
with and without a dark term; the correction eq. 2 and its shape checks; the held-out check's
floor with masked pixels, its verdict exactly at the factor, and one flat (no floor).

And change detection end to end on a small synthetic RGB scene (ccdcore.change.detector.detect,
Tsin, Ramesh & Kanade 2001 sec. 5): a background of one transform, a shadow of another light,
a shade of the background's light, a new object; the clusters' search and its stopping rules
(max_condition, consistency, max_clusters), the shade test's loosest P, the scale note.
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import special, stats

from ccdcore.change import detector as CH
from ccdcore.change import kernels as CK
from ccdcore.dark import frame as DF
from ccdcore.dark import map as DMAP
from ccdcore.dark.model import DarkModel
from ccdcore.errors import CcdError
from ccdcore.flatfield import check as FC
from ccdcore.flatfield import results as FR
from ccdcore.stats import MomentsResult


# -- helpers ----------------------------------------------------------------------------------
def _levels(extra: list[float]) -> np.ndarray:
    """49 pixels at -1, one at 0, 49 at +1 and ``extra`` (two below, two above 0): median 0 and
    MAD 1 whatever the four extra values."""
    return np.array([-1.0] * 49 + [0.0] + [1.0] * 49 + list(extra))


def _ref(mean: np.ndarray, var: np.ndarray | float, s: int, **kw: float) -> DMAP.DarkReference:
    mean = np.asarray(mean, np.float64).reshape(1, -1)
    var = np.broadcast_to(np.asarray(var, np.float64), mean.shape).copy()
    return DF._reference(MomentsResult(mean=mean, var=var, n=s), None, [], **{
        "hot_sigma": 6.0, "noisy_factor": 1.0, **kw})


# -- the dark reference's rules ----------------------------------------------------------------
def test_hot_and_dead_are_strictly_beyond_k_robust_sigma() -> None:
    """Hot: D̂_D - median > k·1.4826·MAD; dead: median - D̂_D > k·1.4826·MAD. A pixel exactly
    at k·r (median 0, MAD 1, k = 6) is neither; a little beyond is."""
    k_r = 6.0 * (1.4826 * 1.0)
    ref = _ref(_levels([-k_r, -k_r - 0.01, k_r, k_r + 0.01]), 0.0, 1)
    hot = np.flatnonzero(ref.hot_mask[0])
    dead = np.flatnonzero(ref.dead_mask[0])
    assert hot.tolist() == [102] and dead.tolist() == [100]
    assert any("one dark frame" in n for n in ref.notes)
    assert "8.896 DN above 0 DN" in ref.hot_rule
    # hot_sigma 3: the threshold halves
    ref3 = _ref(_levels([-k_r, -k_r - 0.01, k_r, k_r + 0.01]), 0.0, 1, hot_sigma=3.0)
    assert ref3.hot_mask.sum() == 2 and ref3.dead_mask.sum() == 2


def test_zero_mad_falls_back_to_the_spatial_std() -> None:
    """A quantised quiet dark (MAD 0): the spatial scale is the std (ddof 0) with a note; a
    pixel 6 std above is hot, one below 6 std is not."""
    mean = np.zeros(200)
    mean[0], mean[1] = 100.0, 30.0
    std = float(mean.std())
    ref = _ref(mean, 0.0, 1)
    assert ref.hot_mask[0, 0] and not ref.hot_mask[0, 1]
    assert 30.0 < 6 * std < 100.0
    assert any("MAD of the dark mean map is 0" in n for n in ref.notes)


@pytest.mark.parametrize("s,factor", [(2, 1.0), (5, 2.0)])
def test_noisy_rule_is_the_scaled_chi2_quantile(s: int, factor: float) -> None:
    """Noisy: temporal variance above factor · σ² · χ²_{s-1}(1 - 1e-6)/(s - 1), σ² the median
    variance over χ²_{s-1}'s median/(s - 1). Pixels 0.1 % either side of it."""
    dof = s - 1
    var = np.full(103, 4.0)
    sigma2 = 4.0 / (stats.chi2.median(dof) / dof)
    thr = factor * sigma2 * stats.chi2.isf(1e-6, dof) / dof
    var[5], var[6] = thr * 1.001, thr * 0.999
    ref = _ref(_levels([-0.5, -0.5, 0.5, 0.5]), var, s, noisy_factor=factor)
    assert np.flatnonzero(ref.hot_mask[0]).tolist() == [5]
    assert "noisy" in ref.hot_rule
    assert ("× 2" in ref.hot_rule) == (factor != 1.0)
    # an infinite factor disables the rule
    off = _ref(_levels([-0.5, -0.5, 0.5, 0.5]), var, s, noisy_factor=math.inf)
    assert not off.hot_mask.any() and "noisy" not in off.hot_rule


def test_stuck_rule_applies_only_when_false_flags_are_rare() -> None:
    """Stuck (variance exactly 0) is dead when size · erf(0.5/(σ√2))^(s-1) < 0.01, σ² from the
    median variance; else skipped with a note. 103 pixels, 5 frames: σ = 10 gives 2.6e-4 and
    σ = 5 4.2e-3 (applied), σ = 3.3 0.021 and σ = 1 2.2 (skipped). A pixel both noisy and
    dead is dead only."""
    for sd, applied in ((10.0, True), (5.0, True), (3.3, False), (1.0, False)):
        var = np.full(103, sd ** 2 * stats.chi2.median(4) / 4)
        var[3] = 0.0
        var[7] = 1e9                                     # noisy ...
        mean = _levels([-50.0, -0.5, 0.5, 0.5])          # ... and index 7 is at -1: not dead
        ref = _ref(mean, var, 5)
        expect = 103 * special.erf(0.5 / (sd * math.sqrt(2))) ** 4
        assert (expect < 0.01) == applied
        assert bool(ref.dead_mask[0, 3]) == applied
        assert ref.hot_mask[0, 7] and ref.dead_mask[0, 99]
        assert any("stuck-pixel rule" in n for n in ref.notes) == (not applied)
    # noisy and far below the median: dead, not hot
    var = np.full(103, 100.0)
    var[99] = 1e9
    ref = _ref(_levels([-50.0, -0.5, 0.5, 0.5]), var, 5)
    assert ref.dead_mask[0, 99] and not ref.hot_mask[0, 99]


def test_exposure_helpers() -> None:
    """exposures_text: none, one, up to four listed, five or more as count and range;
    nearest_exposure in ratio (|log t/target|), ties to the longer, non-positive ones ignored,
    a non-positive target or no positive exposure refused."""
    assert DF.exposures_text([]) == "no known exposure"
    assert DF.exposures_text([0.1]) == "0.1 s"
    assert DF.exposures_text([0.4, 0.1, 0.2]) == "0.1, 0.2 and 0.4 s"
    assert DF.exposures_text([4, 3, 2, 1]) == "1, 2, 3 and 4 s"
    assert DF.exposures_text([5, 4, 3, 2, 1]) == "5 exposures, 1 to 5 s"
    assert DF.nearest_exposure([1.0, 2.9], 1.8) == 2.9        # the difference would give 1
    assert DF.nearest_exposure([1.0, 4.0], 2.0) == 4.0        # a tie in ratio: the longer
    assert DF.nearest_exposure([0.0, 1.0], 0.01) == 1.0
    for xs, t in (([1.0], 0.0), ([0.0, -1.0], 1.0), ([1.0], -1.0)):
        with pytest.raises(ValueError):
            DF.nearest_exposure(xs, t)


def test_dark_reference_refuses_single_and_colour_frames() -> None:
    """A single 2-D frame (not an iterable of frames), colour frames and 1-D frames: CcdError."""
    with pytest.raises(CcdError, match="single frame"):
        DF.dark_reference(np.zeros((4, 4)))
    with pytest.raises(CcdError, match="colour"):
        DF.dark_reference([np.zeros((4, 4, 3)), np.zeros((4, 4, 3))])
    with pytest.raises(CcdError, match="2-D"):
        DF.dark_reference([np.zeros(4), np.zeros(4)])
    ref = DF.dark_reference(np.stack([np.full((3, 4), 2.0), np.full((3, 4), 4.0)]))
    assert np.all(ref.mean_map == 3.0) and np.all(ref.var_map == 2.0) and ref.s == 2


def test_dark_reference_from_the_model_carries_its_errors() -> None:
    """dark_reference_from_model at t: D̂_D = o + c t, var_map the frame noise φ·σ²(t),
    err_var_map = var o + t² var c + 2 t cov, whose root is sem_map (not var_map/s)."""
    rng = np.random.default_rng(3)
    o = rng.uniform(90, 110, (6, 7))
    c = rng.uniform(1, 2, (6, 7))
    ov, cv, cov = np.full((6, 7), 0.5), np.full((6, 7), 0.02), np.full((6, 7), -0.05)
    phi = rng.uniform(0.8, 1.2, (6, 7))
    m = DarkModel(o, c, ov, cv, cov, phi, 2.0, 0.3, 9, (0.0, 1.0, 4.0), temperature=-5.0)
    ref = DF.dark_reference_from_model(m, 3.0)
    np.testing.assert_allclose(ref.mean_map, o + 3 * c, rtol=1e-12)
    np.testing.assert_allclose(ref.var_map, phi * (2.0 + 0.9), rtol=1e-12)
    np.testing.assert_allclose(ref.err_var_map, 0.5 + 9 * 0.02 - 0.3, rtol=1e-12)
    np.testing.assert_allclose(ref.sem_map, math.sqrt(0.38), rtol=1e-12)
    assert ref.s == 9 and ref.exposure == 3.0
    assert ref.notes[0].startswith("from the dark model o + c·t of 9 frames (0, 1 and 4 s, -5 °C)")


def _dark_session(exposures: list[float | None]) -> SimpleNamespace:
    """A session of dark frames (4 x 5, level 100 + 2 t + k) at these exposures, in memory."""
    recs = [SimpleNamespace(exposure=t, relpath=f"dark/{k}.fits", temperature=None, role="dark")
            for k, t in enumerate(exposures)]
    data = {r.relpath: np.full((4, 5), 100.0 + 2.0 * (r.exposure or 0.0) + k)
            for k, r in enumerate(recs)}
    return SimpleNamespace(root="/s", frames=[], dark_frames=lambda: list(recs),
                           select=lambda role, setting=None, gain=None: list(recs),
                           iter_frames=lambda rs, **kw: ((r, data[r.relpath]) for r in rs))


def test_reference_model_only_when_the_wanted_exposure_lacks_two_darks() -> None:
    """reference_model: None without a wanted exposure, with darks at one exposure, with a dark
    of unknown exposure, or with two or more darks at the wanted one (their average is D̂_D);
    one dark at it (or none) and two exposures: the dark model."""
    assert DF.reference_model(_dark_session([0.0, 1.0, 1.0]), None) is None
    assert DF.reference_model(_dark_session([1.0, 1.0, 1.0]), 1.0) is None
    assert DF.reference_model(_dark_session([0.0, 1.0, None]), 3.0) is None
    assert DF.reference_model(_dark_session([0.0, 0.0, 1.0, 1.0]), 1.0 * (1 + 1e-9)) is None
    m = DF.reference_model(_dark_session([0.0, 0.0, 1.0]), 1.0)
    assert isinstance(m, DarkModel) and m.n == 3
    assert isinstance(DF.reference_model(_dark_session([0.0, 1.0, 2.0]), 5.0), DarkModel)


def test_session_darks_at_several_exposures_need_one_chosen() -> None:
    """dark_reference on a session: darks at several exposures without ``exposure`` is an
    error listing them; an exposure within 1e-6 relative picks its frames; one with no frame
    is an error."""
    s = _dark_session([0.1, 0.1, 0.2])
    with pytest.raises(CcdError, match="0.1 and 0.2 s: choose one"):
        DF.dark_reference(s)
    ref = DF.dark_reference(s, exposure=0.1 * (1 + 5e-7))
    assert ref.s == 2 and ref.frames == ("dark/0.fits", "dark/1.fits")
    np.testing.assert_allclose(ref.mean_map, 100.2 + 0.5)
    with pytest.raises(CcdError, match="no dark frames at exposure 0.3 s"):
        DF.dark_reference(s, exposure=0.3)
    with pytest.raises(CcdError, match="no dark frames"):
        DF.dark_reference(_dark_session([]))


# -- the dark reference's figures --------------------------------------------------------------
def test_dark_figures_sem_signal_and_good_pixels() -> None:
    """sem = sqrt(var/s); noise_var = nanmean(var); spatial_std_signal = sqrt(max(std² -
    noise_var/s, 0)) (NaN for one frame); the summary's mean_sem = sqrt(noise_var/s/pixels),
    the mean and std (ddof 0) of the pixels neither hot nor dead."""
    mean = np.array([[10.0, 12.0, 11.0], [50.0, 9.0, 0.0]])
    var = np.array([[4.0, 2.0, np.nan], [1.0, 3.0, 6.0]])
    hot = np.zeros((2, 3), bool)
    dead = np.zeros((2, 3), bool)
    hot[1, 0], dead[1, 2] = True, True
    ref = DMAP.DarkReference(mean, var, 4, float(mean.mean()), float(mean.std()), hot, dead,
                             "h", "d")
    np.testing.assert_allclose(ref.sem_map, np.sqrt(var / 4))
    assert ref.noise_var == pytest.approx(16.0 / 5)
    assert ref.spatial_std_signal == pytest.approx(math.sqrt(mean.std() ** 2 - 3.2 / 4))
    s = ref.summary()
    assert s.mean_sem == pytest.approx(math.sqrt(3.2 / 4 / 6))
    good = np.array([10.0, 12.0, 11.0, 9.0])
    assert s.mean_good == pytest.approx(good.mean()) and s.spatial_std_good == pytest.approx(
        good.std())
    assert s.n_hot == 1 and s.n_dead == 1 and s.noise_var == pytest.approx(3.2)
    # noise larger than the spread: the signal's std is 0, not NaN
    flat = DMAP.DarkReference(np.full((2, 2), 5.0) + [[0, 0.01], [0, 0]], np.full((2, 2), 9.0),
                              2, 5.0, 0.0043, np.zeros((2, 2), bool), np.zeros((2, 2), bool),
                              "h", "d")
    assert flat.spatial_std_signal == 0.0
    one = DMAP.DarkReference(mean, var, 1, 0.0, 1.0, hot, dead, "h", "d")
    assert math.isnan(one.spatial_std_signal)
    assert one.summary().mean_sem is None and one.summary().noise_var is None
    everything = DMAP.DarkReference(mean, var, 4, 0.0, 1.0, np.ones((2, 3), bool), dead, "h", "d")
    assert everything.summary().mean_good is None


def test_dark_model_summary_medians_and_rows() -> None:
    """DarkModel.summary: medians of o, sqrt(var o), c, sqrt(var c) and φ, the mean current
    (hot pixels included), the hot count; its rows carry o and c with their median errors."""
    o = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    c = np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 60.0]])
    ov = np.array([[1.0, 4.0, 9.0], [16.0, 25.0, 36.0]])
    cv = ov / 100.0
    m = DarkModel(o, c, ov, cv, -ov / 10, np.full((2, 3), 1.5), 2.0, 0.25, 6, (0.0, 2.0),
                  temperature=-10.0, frames=("a", "b"))
    s = m.summary()
    assert s.offset_median == pytest.approx(3.5) and s.offset_err_median == pytest.approx(3.5)
    assert s.current_median == pytest.approx(0.35)
    assert s.current_err_median == pytest.approx(0.35)
    assert s.current_mean == pytest.approx(np.mean(c)) and s.scale_median == 1.5
    assert s.n_hot == 1 and s.noise_a == 2.0 and s.noise_b == 0.25
    rows = {r.label: r for r in s.rows()}
    assert rows["offset o (median)"].error == pytest.approx(3.5)
    assert rows["dark current c (median)"].value == pytest.approx(0.35)
    assert rows["temperature"].text == "-10 ± 1 °C"
    assert "b = 0.25 DN²/s" in rows["frame noise σ²(t)"].meaning
    ref = DMAP.DarkReference(o, ov, 4, 3.5, 1.7, np.zeros((2, 3), bool), np.zeros((2, 3), bool),
                             "h", "d", model=s)
    rrows = {r.label: r for r in ref.summary().rows()}
    assert rrows["mean level"].error == pytest.approx(math.sqrt(91 / 6 / 4 / 6))
    assert "offset o (median)" in rrows


def test_as_dark_map() -> None:
    """as_dark_map: a DarkReference's mean map, an array or a scalar as float64; None refused."""
    with pytest.raises(CcdError, match="no dark reference"):
        DMAP.as_dark_map(None)
    a = DMAP.as_dark_map(np.array([[1, 2]], np.uint16))
    assert a.dtype == np.float64 and a.tolist() == [[1.0, 2.0]]
    assert DMAP.as_dark_map(3).dtype == np.float64


# -- the flat field's results ------------------------------------------------------------------
def _ff(G: np.ndarray, O: np.ndarray, flags: np.ndarray, base_var: np.ndarray | float,
        n_base: int, layout: str = "mono", dark_n: int = 3, **kw: object) -> FR.FlatField:
    shape = G.shape
    dark = MomentsResult(mean=np.full(shape, 100.0), var=np.full(shape, 9.0), n=dark_n)
    base = MomentsResult(mean=np.full(shape, 1100.0),
                         var=np.broadcast_to(np.asarray(base_var, float), shape).copy(), n=n_base)
    return FR.FlatField(G.astype(np.float32), O.astype(np.float32), flags, dark, base, layout,
                        (FR.FlatChannel("L", 1000.0, 100.0, 1100.0, int(flags.sum()),
                                        flags.size),), **kw)


def test_g_relative_error_is_the_error_of_the_difference() -> None:
    """σ_G/G = sqrt(s²_B/n_B + s²_0/n_0) / (DL_B - DL_0), NaN where flagged; a dark of no
    frames (the zero-dark form) adds nothing."""
    shape = (3, 4)
    flags = np.zeros(shape, bool)
    flags[1, 2] = True
    ff = _ff(np.ones(shape), np.zeros(shape), flags, 25.0, 5, dark_n=3)
    err = ff.G_rel_err
    expect = math.sqrt(25.0 / 5 + 9.0 / 3) / 1000.0
    assert np.isnan(err[1, 2])
    np.testing.assert_allclose(err[~flags], expect, rtol=1e-12)
    zero = _ff(np.ones(shape), np.zeros(shape), flags, 25.0, 5, dark_n=0)
    np.testing.assert_allclose(zero.G_rel_err[~flags], math.sqrt(5.0) / 1000.0, rtol=1e-12)


def test_correction_is_o_plus_g_times_the_frame_with_shape_checks() -> None:
    """Eq. 2: DL_c = O + G·DL in float64, returned float32; a frame or an O of another shape
    is refused naming the frame; an unknown channel is a KeyError."""
    G = np.array([[1.5, 2.0], [0.5, 1.0]])
    O = np.array([[10.0, -5.0], [0.0, 3.0]])
    D = np.array([[100, 200], [300, 65535]], np.uint16)
    out = FR.correct(D, G, O, where="f.fits")
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, O + G * D.astype(float), rtol=1e-7)
    with pytest.raises(CcdError, match="f.fits"):
        FR.correct(D.T[:, :1], G, O, where="f.fits")
    with pytest.raises(CcdError):
        FR.correct(D, G, O[:1], where="f.fits")
    ff = _ff(G, O, np.zeros((2, 2), bool), 1.0, 2)
    np.testing.assert_allclose(ff.correct(D), out)
    assert ff.channel("L").k == 1000.0
    with pytest.raises(KeyError):
        ff.channel("R")


def test_summary_rows_base_and_zero_dark() -> None:
    """The summary: base key with a level None, 'n/a' without a base; the rows' 'dark pixels at
    0' line says 'clipped' only above ZERO_LIMIT (1 %), not at it; the dark row of the
    zero-dark and model forms; group_words."""
    shape = (2, 2)
    ff = _ff(np.ones(shape), np.zeros(shape), np.zeros(shape, bool), 1.0, 2,
             base_key=(None, 0.04))
    s = ff.summary()
    assert s.base == (None, 0.04) and s.base_text() == "level –, exposure 0.04 s"
    assert type(s.base[1]) is float
    s2 = _ff(np.ones(shape), np.zeros(shape), np.zeros(shape, bool), 1.0, 2,
             base_key=(np.int64(3), float("nan"))).summary()
    assert s2.base == (3, None) and type(s2.base[0]) is int
    assert FR.group_words((3, None)) == "level 3, exposure –"
    assert _ff(np.ones(shape), np.zeros(shape), np.zeros(shape, bool), 1.0, 2).summary(
    ).base_text() == "n/a"

    def zero_row(fraction: float) -> object:
        ch = FR.FlatChannelSummary("L", 1.0, 0.0, 1.0, 0, 4, dark_zero_fraction=fraction)
        rows = FR.FlatFieldSummary("mono", (2, 2), 3, 2, (ch,), 0, 5.0, 9, "r", None, None,
                                   None, ()).rows()
        return [r for r in rows if r.label == "dark pixels at 0"][0]
    assert zero_row(0.01).text is None and zero_row(0.01).value == pytest.approx(1.0)
    assert "clipped at zero" in zero_row(0.0101).text
    base = FR.FlatFieldSummary("mono", (2, 2), 0, 2, (), 0, 5.0, 9, "r", None, None, 2.0, (),
                               dark_source="zero")
    dark_row = [r for r in base.rows() if r.label == "dark image"][0]
    assert dark_row.text == "zero (DL_0 = 0)" and dark_row.value == 0


def test_dark_row_of_the_model_form_and_held_out_rows() -> None:
    """The dark row names the model's frames, temperature and exposure; the held-out rows give
    each channel's SNUP against its floor and the factor."""
    from ccdcore.dark.model import DarkModelSummary

    dm = DarkModelSummary(5, (0.0, 10.0), -10.0, 1.0, 1.0, 0.1, 0.2, 0.01, 0.2, 0, 1.0, 0.1, 1.0)
    s = FR.FlatFieldSummary("mono", (2, 2), 5, 2, (), 0, 5.0, 9, "r", None, None, 3.0, (),
                            dark_source="model", dark_model=dm)
    row = [r for r in s.rows() if r.label == "dark image"][0]
    assert row.value == 5 and row.text == "dark model (5 frames)"
    assert "at -10 °C, exposure 3 s" in row.meaning
    chk = FC.HeldOutCheck("h.fits", 4, "g", 1.15, "pass",
                          (FC.HeldOutChannel("L", 1.2, 1.5, 0.8, 1.3, 9.0),))
    rows = chk.rows()
    assert rows[0].text == "pass (h.fits, N = 4)"
    assert rows[1].value == 1.2 and rows[1].text == "1.2 % = 0.800 × floor"
    assert "floor 1.5 % (× 1.15 allowed); before correction 9 %" == rows[1].meaning


# -- the held-out check -----------------------------------------------------------------------
def test_held_out_floor_leaves_flagged_pixels_out() -> None:
    """held_out_figures: the corrected mean, ⟨G² s²⟩ and the SNUP over the unflagged pixels
    only; floor = 100 sqrt(1 + 1/N) sqrt(⟨G² s²⟩)/⟨DL_c⟩, ratio SNUP/floor, SNUP before
    correction on the raw frame (ddof 1, eq. 5). G not 1, a non-uniform variance."""
    rng = np.random.default_rng(5)
    shape = (20, 30)
    G = rng.uniform(0.8, 1.2, shape)
    O = np.full(shape, 5.0)
    flags = np.zeros(shape, bool)
    flags[3, 4] = flags[10, 11] = True
    var = rng.uniform(50, 150, shape)
    var[flags] = 1e6
    ff = _ff(G, O, flags, var, 4)
    frame = 1000 / G + rng.normal(0, 10, shape)
    frame[flags] = 1e5
    chk = FC.held_out_figures(ff, frame, n_fit=4, held_out="h.fits")
    (c,) = chk.channels
    corr = (O + G.astype(np.float32).astype(float) * frame)[~flags]
    noise = math.sqrt(float(np.mean((G.astype(np.float32).astype(float) ** 2 * var)[~flags])))
    temporal = 100 * noise / corr.mean()
    assert c.temporal == pytest.approx(temporal, rel=1e-6)
    assert c.floor == pytest.approx(temporal * math.sqrt(1.25), rel=1e-6)
    snup = 100 * corr.std(ddof=1) / corr.mean()
    assert c.snup == pytest.approx(snup, rel=1e-5)
    assert c.ratio == pytest.approx(snup / (temporal * math.sqrt(1.25)), rel=1e-5)
    raw = frame[~flags]
    assert c.snup_raw == pytest.approx(100 * raw.std(ddof=1) / raw.mean(), rel=1e-6)
    assert chk.n_fit == 4 and chk.worst_ratio == c.ratio


def test_held_out_verdict_at_the_factor_and_without_a_floor() -> None:
    """The check passes when SNUP/floor <= factor: exactly at the factor passes, just under
    it warns; a base of one flat has no temporal variance: no floor, ratio None, a warning,
    and the text says n/a."""
    rng = np.random.default_rng(6)
    shape = (16, 16)
    ff = _ff(np.ones(shape), np.zeros(shape), np.zeros(shape, bool), 100.0, 3)
    frame = 1000 + rng.normal(0, 10, shape)
    r = FC.held_out_figures(ff, frame, n_fit=3, held_out="h").channels[0].ratio
    at = FC.held_out_figures(ff, frame, n_fit=3, held_out="h", factor=r)
    assert at.verdict == "pass"
    below = FC.held_out_figures(ff, frame, n_fit=3, held_out="h", factor=r * (1 - 1e-12))
    assert below.verdict == "warn"
    one = _ff(np.ones(shape), np.zeros(shape), np.zeros(shape, bool), np.nan, 1)
    chk = FC.held_out_figures(one, frame, n_fit=1, held_out="h.fits", group="g")
    (c,) = chk.channels
    assert c.floor is None and c.ratio is None and c.temporal is None
    assert chk.verdict == "warn" and chk.worst_ratio is None
    assert "L: n/a" in chk.text() and chk.text().startswith("warn: h.fits held out")
    assert "(× " in at.text()


def test_held_out_worst_channel_and_an_infinite_floor() -> None:
    """RGB: worst_ratio is the largest channel ratio (B, with a pattern the correction left);
    a temporal variance that is infinite gives no ratio (None) and a warning, not 0."""
    rng = np.random.default_rng(7)
    shape = (16, 20, 3)
    ff = _ff(np.ones(shape), np.zeros(shape), np.zeros(shape, bool), 100.0, 3, layout="rgb")
    frame = 1000 + rng.normal(0, 10, shape)
    frame[..., 2] += 30 * np.sin(np.arange(20) / 2.0)[None, :]
    chk = FC.held_out_figures(ff, frame, n_fit=3, held_out="h")
    ratios = {c.name: c.ratio for c in chk.channels}
    assert chk.worst_ratio == ratios["B"] == max(ratios.values())
    assert ratios["B"] > 2 * ratios["R"]
    inf = FC.held_out_figures(ff, frame, n_fit=3, held_out="h",
                              temporal_var=np.full(shape, np.inf))
    assert all(c.ratio is None for c in inf.channels) and inf.verdict == "warn"


# -- change detection end to end ----------------------------------------------------------------
M0 = np.array([[0.8, 0.05, 0.0], [0.02, 0.7, 0.03], [0.0, 0.04, 0.9]])
M1 = 0.4 * np.array([[1.0, 0.1, 0.0], [0.0, 0.8, 0.1], [0.05, 0.0, 0.7]])
SIGMA = 0.004


def _scene(seed: int = 0) -> tuple[np.ndarray, ...]:
    """60 x 50 RGB: background E' = E M0; rows 0-19 x cols 0-24 a shadow of another light
    (E' = E M1, 500 px); rows 40-49 x cols 30-39 a new object (100 px); rows 50-59 x cols 0-9
    a soft shade of the background's light (E' = k E M0, k from 0.5 to 0.7 along the columns,
    100 px: no one M) and rows 50-59 x cols 40-49 a 'shade' outside the range (k from 2.4 to
    2.6). Noise σ = 0.004 on both, the sigma given."""
    rng = np.random.default_rng(seed)
    E = rng.uniform(0.1, 0.9, (60, 50, 3))
    Et = E @ M0
    Et[:20, :25] = E[:20, :25] @ M1
    Et[40:50, 30:40] = rng.uniform(0.1, 0.9, (10, 10, 3))
    ramp = np.linspace(0.0, 1.0, 10)[None, :, None]
    Et[50:, :10] = (0.5 + 0.2 * ramp) * (E[50:, :10] @ M0)
    Et[50:, 40:] = (2.4 + 0.2 * ramp) * (E[50:, 40:] @ M0)
    s = np.full(E.shape, SIGMA)
    return E + s * rng.standard_normal(E.shape), s, Et + s * rng.standard_normal(E.shape), s


@pytest.fixture(scope="module")
def scene() -> tuple[tuple[np.ndarray, ...], CH.ChangeResult]:
    maps = _scene()
    return maps, CH.detect(*maps, CH.ChangeOptions(pfa=0.01))


def test_detect_finds_background_shadow_shade_and_change(scene) -> None:
    """Two clusters: M0 and M1 each within 5 of its own standard errors (from M_cov); their
    members' median d² near χ²₃'s (2.37; 500 members: its sd about 0.15); the object is
    change, the 0.6 shade is a shade (label 253, k near 0.6), the 2.5 one change; the
    predicted target is E M0 everywhere; no scale note at s near 1."""
    (E, s, Et, st), r = scene
    assert len(r.clusters) == 2
    for c, M in zip(r.clusters, (M0, M1)):
        err = np.sqrt(np.diag(c.M_cov)).reshape(3, 3)
        assert np.all(np.abs(c.M - M) < 5 * err)
        assert c.d2_median == pytest.approx(stats.chi2.median(3), abs=0.6)
    assert np.mean(r.labels[:20, :25] == 1) > 0.97
    assert np.mean(r.labels[40:50, 30:40] == CH.LABEL_CHANGE) > 0.95
    assert np.mean(r.labels[50:, :10] == CH.LABEL_SHADE) > 0.9
    assert np.nanmedian(r.shade_k[50:, :10]) == pytest.approx(0.6, abs=0.01)
    assert np.mean(r.labels[50:, 40:] == CH.LABEL_CHANGE) > 0.9
    assert np.nanmedian(r.shade_k[50:, 40:]) == pytest.approx(2.5, abs=0.05)
    np.testing.assert_allclose(r.predicted, E @ r.clusters[0].M, rtol=1e-12)
    assert r.scale == pytest.approx(1.0, abs=0.1) and not any("times χ²" in n for n in r.notes)
    bg = np.ones((60, 50), bool)
    bg[:20, :25] = bg[40:, :] = False
    assert 0.002 <= np.mean(r.labels[bg] != 0) <= 0.03
    assert r.to_dict()["pfa_observed"] == pytest.approx(0.01, abs=0.005)


def test_shade_is_tested_where_the_loosest_p_leaves_pixels_unexplained(scene) -> None:
    """Step 5 tests the pixels above the threshold at max(P, SHADE_LOOSEST_P = 0.2): exactly
    those have a shade factor; the others NaN."""
    _, r = scene
    tested = np.isfinite(r.shade_k)
    np.testing.assert_array_equal(tested, r.valid & (r.d2_best > r.threshold_for(0.2)))
    assert 0 < np.count_nonzero(tested & (r.labels == 0))


def test_cluster_search_stops_at_an_ill_conditioned_or_inconsistent_cluster() -> None:
    """Step 4's rules: the shadow's M1 has condition number 1.5: max_condition 1.4 refuses
    it, 1.6 keeps it; its members' median d² over the background's is about 0.9: consistency
    0.5 refuses it; max_clusters 1 never searches. Refused, the shadow is change."""
    maps = _scene()
    cond = float(np.linalg.cond(M1))
    assert 1.4 < cond < 1.6
    for kw, n in ((dict(max_condition=1.4), 1), (dict(max_condition=1.6), 2),
                  (dict(consistency=0.5), 1), (dict(max_clusters=1), 1)):
        r = CH.detect(*maps, CH.ChangeOptions(pfa=0.01, shade=None, **kw))
        assert len(r.clusters) == n, kw
        if n == 1:
            assert np.mean(r.labels[:20, :25] == CH.LABEL_CHANGE) > 0.95
            assert r.shade is None and r.shade_k is None


def test_wrong_sigmas_are_noted_and_mono_has_no_shade() -> None:
    """Sigmas half the truth: s about 4 and the note 'times χ²'; a mono pair has no shade test
    (shade None) even with the option on."""
    E, s, Et, st = _scene(1)
    r = CH.detect(E, 0.5 * s, Et, 0.5 * st, CH.ChangeOptions(pfa=0.01, max_clusters=1))
    assert r.scale == pytest.approx(4.0, rel=0.2)
    assert any("times χ²" in n for n in r.notes)
    m = CH.detect(E[..., 0], s[..., 0], 0.8 * E[..., 0], st[..., 0],
                  CH.ChangeOptions(max_clusters=1))
    assert m.shade is None and m.shade_d2 is None and m.dof == 1


def test_consistency_compares_with_the_background_samples_median(scene) -> None:
    """A further cluster is kept when its members' (pixels the background leaves above the
    threshold, under the new M's threshold) median d² is at most consistency times the
    *median* of the background's sample: 1 % either side of the ratio flips the decision."""
    maps, r = scene
    thr = r.threshold
    valid = r.valid
    members = valid & (r.d2[..., 0] > thr) & (r.d2[..., 1] <= thr)
    rho = float(np.median(r.d2[..., 1][members])) / float(np.median(r.background))
    keep = CH.detect(*maps, CH.ChangeOptions(pfa=0.01, consistency=rho * 1.01))
    drop = CH.detect(*maps, CH.ChangeOptions(pfa=0.01, consistency=rho * 0.99))
    assert len(keep.clusters) == 2 and len(drop.clusters) == 1


def test_compiled_trial_costs_equal_the_trimmed_cost() -> None:
    """The LTS search scores RGB candidates with the compiled pass: each candidate's cost is
    the trimmed cost (the h smallest d² + ln det Σ_e - Σ ln σ²_E'), for h at both ends."""
    rng = np.random.default_rng(12)
    n = 60
    E = rng.uniform(0.1, 0.9, (n, 3))
    Et = E @ M0 + 0.01 * rng.standard_normal((n, 3))
    Et[:10] += 0.3
    var = rng.uniform(1e-4, 3e-4, (n, 3))
    var_t = rng.uniform(1e-4, 3e-4, (n, 3)) * [1.0, 2.0, 3.0]
    Ms = np.stack([M0, M1, np.eye(3), M0 + 0.01])
    for h in (10, 31, 59):
        out = np.empty(4)
        CK._trial_costs_rgb(E, Et, var, var_t, Ms, h, out)
        for M, cost in zip(Ms, out):
            d2, _, ld = CK.error_d2(E, Et, var, var_t, M, want_p=False, want_logdet=True)
            keep = np.argsort(d2)[:h]
            ref = np.sum(d2[keep] + ld[keep] - np.log(var_t[keep]).sum(axis=1))
            assert cost == pytest.approx(ref, rel=1e-9)


def test_transform_covariance_needs_more_members_than_entries() -> None:
    """_m_covariance: with C² = 9 members or fewer (weight > 0) the covariance is unknown
    (NaN); with 10 the sandwich B⁻¹ (Σ ψψᵀ) B⁻ᵀ exists (finite, symmetric, positive
    diagonal)."""
    rng = np.random.default_rng(13)
    n = 40
    E = rng.uniform(0.1, 0.9, (n, 3))
    var = np.full((n, 3), 1e-4)
    Et = E @ M0 + 0.01 * rng.standard_normal((n, 3))
    w = np.zeros(n)
    w[:9] = 1.0
    assert np.all(np.isnan(CH._m_covariance(E, Et, var, var, M0, w)))
    w[9] = 1.0
    cov = CH._m_covariance(E, Et, var, var, M0, w)
    assert np.all(np.isfinite(cov)) and np.allclose(cov, cov.T) and np.all(np.diag(cov) > 0)


def test_cluster_search_needs_twice_the_smallest_cluster_left(scene) -> None:
    """Step 4 searches the pixels the background leaves above the threshold only while they
    number at least 2 min_px: min_pixels (a count) of half of them searches and keeps the
    shadow; one more stops the search. (822 such pixels here, even: half of them is exactly
    at the limit.)"""
    maps, r = scene
    n_open = int(np.count_nonzero(r.d2[..., 0][r.valid] > r.threshold))
    assert n_open > 2 * 500 * 0.8
    half = n_open // 2
    found = CH.detect(*maps, CH.ChangeOptions(pfa=0.01, min_pixels=half))
    assert len(found.clusters) == 2
    stop = CH.detect(*maps, CH.ChangeOptions(pfa=0.01, min_pixels=half + 1))
    assert len(stop.clusters) == 1
