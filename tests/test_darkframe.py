"""Dark reference D̂_D (sec. V-A of Healey & Kondepudy 1994) against the healey94 simulator.

Tolerances are 4 standard errors of the compared statistic (derived next to each assertion); the
seeds are fixed, so the tests are deterministic, and a biased average or a wrong error model moves
the statistic by many standard errors.
"""
from __future__ import annotations

import numpy as np
import pytest

from ccdcore.dark.frame import DarkReference, dark_reference
from ccdcore.errors import CcdError
from ccdcore.io.frames import read_image
from ccdcore.session import open_session
from ccdcore.simulate import load_truth, simulate

S = 16
SMALL = dict(size=(64, 48), n_dark=S, levels=3, n1=2, n2=1, scene_levels=(0.5,),
             max_intensity=None)


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    root = tmp_path_factory.mktemp("dark")
    truth = simulate("healey94", root, seed=21, **SMALL)
    session = open_session(root)
    return root, truth, session, dark_reference(session)


def test_summary_and_shapes(sim):
    root, truth, session, dr = sim
    assert isinstance(dr, DarkReference)
    assert dr.s == S and dr.mean_map.shape == (48, 64) and dr.mean_map.dtype == np.float64
    assert dr.exposure == pytest.approx(truth["exposure"])
    d = dr.to_dict()
    assert d["s"] == S and d["n_hot"] == 0 and d["n_dead"] == 0
    assert "MAD" in d["hot_rule"] and "MAD" in d["dead_rule"]
    assert not any(isinstance(v, np.ndarray) for v in d.values())
    # the same frames as a plain iterable of arrays give the same map
    frames = [read_image(r.path) for r in session.dark_frames()]
    np.testing.assert_array_equal(dark_reference(iter(frames)).mean_map, dr.mean_map)
    np.testing.assert_allclose(dr.var_map, np.var(np.stack(frames).astype(float), axis=0, ddof=1),
                               rtol=1e-10, atol=1e-10)


def test_error_consistent_with_sigma_over_root_s(sim):
    """(D̂_D − truth)/sem has the spread sem predicts.

    The truth map is E_DC·A (+ black level), the mean of the *analogue* dark signal.  Rounding to
    integer DN biases the mean of a quantised value by a periodic term of amplitude
    ~exp(−2π²σ²)/π, about 1e-10 DN for σ ≈ 1.07 DN here, so the truth is the expected value of
    the quantised frames to far better than the noise; the rounding's q²/12 is in the variance.
    """
    root, truth, session, dr = sim
    tmap = load_truth(root).map("dark_map").astype(np.float64)
    err = dr.mean_map - tmap
    n = err.size
    # 1) with the estimated sem the standardised error is Student t with s−1 dof:
    #    var = (s−1)/(s−3); the SE of a sample variance of n values is var·sqrt((2 + κ)/n), κ the
    #    excess kurtosis 6/(s−5), so the SE of the std is half that relative.
    z = err / dr.sem_map
    sd_t = np.sqrt((S - 1) / (S - 3))
    se = 0.5 * sd_t * np.sqrt((2 + 6 / (S - 5)) / n)
    assert abs(z.std() - sd_t) < 4 * se
    assert abs(z.mean()) < 4 * sd_t / np.sqrt(n)
    # 2) with the true per-pixel variance σ²_N = A²·E_DC + σ²_C (eq. 43): std 1, SE 1/sqrt(2n)
    e_dc = (tmap - truth["black_level_dn"]) / truth["A"]
    z_true = err / np.sqrt((truth["A"] ** 2 * e_dc + truth["sigma_c2"]) / S)
    assert abs(z_true.std() - 1.0) < 4 / np.sqrt(2 * n)
    # 3) array mean within 4 SE of the truth (SE = sqrt(mean σ²_N / (s·n)))
    assert abs(dr.mean - truth["dark_mean_dn"]) < 4 * np.sqrt(truth["dark_sigma2_dn"] / (S * n))
    # 4) spatial std of the signal (noise of the average removed) vs the truth map's std:
    #    SE of a std of n values ≈ std/sqrt(2n) (dark map nearly Gaussian), doubled for the
    #    noise removal
    assert abs(dr.spatial_std_signal - truth["dark_std_dn"]) < 4 * 2 * truth["dark_std_dn"] \
        / np.sqrt(2 * n)


def test_hot_dead_noisy_pixels_are_flagged(sim):
    root, truth, session, dr = sim
    frames = [read_image(r.path).astype(np.int32) for r in session.dark_frames()]
    hot, noisy, dead, stuck = (5, 7), (10, 20), (30, 40), (44, 3)
    for k, f in enumerate(frames):
        f[hot] += 25                       # a hot pixel: 25 DN ≈ 45 robust sigma above
        f[noisy] += 8 * (k % 2)            # RTS: toggles by 8 DN, variance ≈ 17 DN²
        f[dead] = 0                        # dead: stuck at 0
        f[stuck] = 11                      # stuck at a normal-looking value: variance 0
    res = dark_reference(frames)
    exp_hot = np.zeros(res.shape, bool)
    exp_hot[hot] = exp_hot[noisy] = True
    exp_dead = np.zeros(res.shape, bool)
    exp_dead[dead] = exp_dead[stuck] = True
    # a normal pixel exceeds 6 robust sigma or the 1e-6 chi-square quantile with probability
    # ~1e-6 each: ~0.003 false flags expected over 3072 pixels
    np.testing.assert_array_equal(res.hot_mask, exp_hot)
    np.testing.assert_array_equal(res.dead_mask, exp_dead)
    assert "noisy" in res.hot_rule and "stuck" in res.dead_rule
    assert res.to_dict()["n_hot"] == 2 and res.to_dict()["n_dead"] == 2


def test_stuck_rule_skipped_for_quiet_sensor():
    rng = np.random.default_rng(3)
    frames = [np.rint(5 + 0.1 * rng.standard_normal((16, 16))) for _ in range(4)]
    res = dark_reference(frames)
    assert "stuck" not in res.dead_rule and any("skipped" in n for n in res.notes)
    assert not res.dead_mask.any()


def test_bad_inputs(tmp_path, sim):
    root, truth, session, dr = sim
    with pytest.raises(CcdError, match="no dark frames given"):
        dark_reference([])
    frames = [read_image(r.path) for r in session.dark_frames()[:3]]
    with pytest.raises(CcdError, match="frame 2.*differs"):
        dark_reference([frames[0], frames[1], frames[2][:, :10]])
    with pytest.raises(CcdError, match="colour frames"):
        dark_reference([np.zeros((8, 8, 3))] * 2)
    with pytest.raises(CcdError, match="not a single frame"):
        dark_reference(frames[0])
    with pytest.raises(CcdError, match="no dark frames at exposure"):
        dark_reference(session, exposure=1.0)
