"""The prediction agreement of Tsin et al. sec. 4.2 (ccdcore.response.agreement)."""
from __future__ import annotations

import numpy as np
import pytest

from ccdcore.response.agreement import agreement, channel_agreement, code_range, inverse
from ccdcore.response.brackets import bracket_data
from ccdcore.simulate.tsin import expose, exposure_times, inverse_response


def _bracket(seed=3, a_err=None, sigma_c2=0.5):
    rng = np.random.default_rng(seed)
    E = rng.random((96, 128))
    t = exposure_times(8)
    a = t.copy() if a_err is None else t * a_err
    frames = [expose(E, a[k], 0.0, rng, sigma_s=0.0, sigma_c1=0.0, sigma_c2=sigma_c2).z
              for k in range(t.size)]
    return bracket_data(frames, t, 8, bloom_radius=0)["L"], a


def test_true_curve_predicts_within_the_output_noise():
    data, a = _bracket()
    g = inverse_response(np.arange(256), 1.2)
    c = channel_agreement(data, g, a)
    # each prediction error: the output noise of both images (0.5 DN each, plus rounding 1/12
    # DN² each) carried through the curve; about sqrt(2 (0.25 + 1/12)) = 0.82 DN at most
    assert 0.3 < c.rms < 0.9
    assert c.rms_fitted <= c.rms + 1e-12
    for p in c.pairs:
        assert p.ratio_fitted == pytest.approx(p.ratio, rel=0.01)


def test_a_wrong_shape_or_exposure_shows():
    data, a = _bracket()
    g = inverse_response(np.arange(256), 1.2)
    good = channel_agreement(data, g, a)
    wrong = channel_agreement(data, inverse_response(np.arange(256), 1.8), a)
    assert wrong.rms > 3 * good.rms
    # image 4's exposure 15 % long: its two pairs mispredict with the nominal ratio, and the
    # fitted ratio finds the true one (and the error of the shape alone stays small)
    err = np.ones(8)
    err[4] = 1.15
    data2, a2 = _bracket(a_err=err)
    c = channel_agreement(data2, g, data2.t)
    bad = [p for p in c.pairs if 4 in (p.j, p.k)]
    ok = [p for p in c.pairs if 4 not in (p.j, p.k)]
    assert min(p.rms for p in bad) > 3 * max(p.rms for p in ok)
    assert max(p.rms_fitted for p in bad) < 1.0
    assert bad[0].ratio_fitted == pytest.approx(a2[4] / a2[3], rel=0.01)
    assert bad[1].ratio_fitted == pytest.approx(a2[5] / a2[4], rel=0.01)
    # with its own (true) exposures the result agrees again
    assert channel_agreement(data2, g, a2).rms < 0.9


def test_pooled_over_channels_and_a_flat_curve():
    data, a = _bracket()
    g = inverse_response(np.arange(256), 1.2)
    ag = agreement({"R": data, "G": data}, {"R": {"g": g, "a": a, "b": np.zeros(8)},
                                           "G": {"g": g, "a": a, "b": np.zeros(8)}})
    assert ag.rms == pytest.approx(ag["R"].rms)
    assert ag.to_dict()["channels"][1]["channel"] == "G"
    # a collapsed curve (flat over codes 20..140) maps its value to the run's middle code
    flat = g.copy()
    flat[20:141] = flat[20]
    assert inverse(flat)(np.array([flat[20]]))[0] == pytest.approx(80.0)
    assert channel_agreement(data, flat, a).rms > 10.0


def test_code_range_scales_with_bits():
    assert code_range(256) == (10, 245)
    assert code_range(4096) == (161, 3934)
