"""SNUP with its standard error, SNUP of averages (Table 1) and the linear range (Fig. 2) of
de Lasarte et al. (2007), against closed-form cases and the ``delasarte07`` simulator's truth.

Tolerances are 4 standard errors of the compared statistic, derived in each test.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ccdcore.errors import CcdError
from ccdcore.session import open_session
from ccdcore.simulate import simulate
from ccdcore.channels import channel_names, split_channels
from ccdcore.flatfield.uniformity import linearity, snup, snup_vs_averaging

SIZE = (64, 48)


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    out = tmp_path_factory.mktemp("delasarte_u")
    truth = simulate("delasarte07", out, seed=5, size=SIZE)
    return open_session(out), truth


@pytest.fixture(scope="module")
def flat_sim(tmp_path_factory):
    """No vignetting, no PRNU: a uniform field whose SNUP is temporal noise only."""
    out = tmp_path_factory.mktemp("delasarte_flat")
    truth = simulate("delasarte07", out, seed=6, size=SIZE, vignetting_corner=1.0 - 1e-12,
                     prnu_std=0.0, settings=("NZDI",), levels=(1.0,), exposures=(0.02, 0.04),
                     n_average=16, n_dark=2, base=(1, 2))
    return open_session(out), truth


# ---- SNUP ----------------------------------------------------------------------------------
def test_snup_value_and_json_shape():
    img = np.array([[10.0, 11.0], [9.0, 10.0]])
    r = snup(img)
    assert r.names == ("L",)
    assert r["L"].snup == pytest.approx(100 * np.std(img, ddof=1) / 10.0)
    d = r.to_dict()["channels"][0]
    assert {"name", "mean", "snup", "snup_err"} <= set(d)
    json.dumps(r.to_dict())


def test_channel_names_per_layout():
    assert channel_names("mono") == ("L",)
    assert channel_names("rgb") == ("R", "G", "B")
    assert channel_names("bayer-grbg") == ("R", "G1", "G2", "B")
    raw = np.arange(16.0).reshape(4, 4) + 1
    planes = split_channels(raw, "bayer-rggb")
    assert planes["R"][0, 0] == raw[0, 0] and planes["B"][0, 0] == raw[1, 1]
    r = snup(raw, layout="bayer-rggb")
    assert r["G2"].mean == pytest.approx(raw[1::2, 0::2].mean())


@pytest.mark.parametrize("dist", ["normal", "gamma"])
def test_snup_standard_error_is_honest(dist):
    # z = (SNUP - true SNUP) / snup_err over 400 seeds: std(z) has standard error
    # 1/sqrt(2*400) = 0.035, mean(z) 0.05; bounds at 4 standard errors
    n, reps = 500, 400
    rng = np.random.default_rng(11)
    if dist == "normal":
        mu, sd = 100.0, 8.0
        draws = rng.normal(mu, sd, (reps, n))
    else:   # skewed pixels: the moment form of the error must still hold
        shape, scale = 4.0, 10.0
        mu, sd = shape * scale, math.sqrt(shape) * scale
        draws = rng.gamma(shape, scale, (reps, n))
    true = 100 * sd / mu
    z = np.array([(snup(d.reshape(20, 25))["L"].snup - true) / snup(d.reshape(20, 25))["L"].snup_err
                  for d in draws])
    assert abs(z.std() - 1) < 4 * 0.035
    # the bias of s/m is O(1/n) while the error is O(1/sqrt n): mean(z) stays near 0
    assert abs(z.mean()) < 4 * 0.05 + 0.1


def test_snup_roi_mask_and_rgb():
    rng = np.random.default_rng(0)
    img = rng.normal(50, 2, (40, 60, 3))
    img[:10, :10, 1] = 500.0
    full = snup(img)
    masked = snup(img, mask=np.pad(np.ones((10, 10), bool), ((0, 30), (0, 50))))
    roi = snup(img, roi=(10, 10, 50, 30))
    assert full["G"].snup > 50 and masked["G"].snup < 6 and roi["G"].snup < 6
    assert roi.to_dict()["roi"] == [10, 10, 50, 30] and roi["R"].n == 1500


def test_snup_bad_input():
    img = np.ones((8, 8))
    with pytest.raises(CcdError, match="NaN"):
        snup(np.where(np.eye(8, dtype=bool), np.nan, 1.0), where="a.tif")
    with pytest.raises(CcdError, match="mean"):
        snup(np.zeros((4, 4)))
    with pytest.raises(CcdError, match="rgb"):
        snup(img, layout="rgb")
    with pytest.raises(CcdError, match="layout"):
        snup(np.ones((4, 4, 3)), layout="mono")
    with pytest.raises(CcdError, match="even"):
        snup(img, layout="bayer-rggb", roi=(1, 0, 4, 4))
    with pytest.raises(CcdError, match="ROI"):
        snup(img, roi=(4, 4, 8, 8))


# ---- averaging (Table 1) -------------------------------------------------------------------
def test_snup_of_averages_falls_like_one_over_sqrt_n(flat_sim):
    session, truth = flat_sim
    frames = session.flat_groups(setting="NZDI")[(1, 0.04)]
    assert len(frames) == 16
    res = snup_vs_averaging(session.iter_frames(frames))
    assert [r.N for r in res.channel("G")] == [1, 2, 4, 8, 16]
    for c in ("R", "G", "B"):
        rows = res.channel(c)
        # temporal noise dominates: the fixed part is far below the temporal one
        assert res.snup_fixed[c] < 0.35 * res.snup_temporal[c]
        for r in rows:
            # the prediction follows within 4 standard errors of SNUP_N
            assert r.snup == pytest.approx(r.predicted, abs=4 * r.snup_err)
        s1, s16 = rows[0], rows[-1]
        ratio_err = (s1.snup / s16.snup) * math.hypot(s1.snup_err / s1.snup,
                                                      s16.snup_err / s16.snup)
        # 1/sqrt(N) up to the small fixed part: SNUP_1/SNUP_16 between 4 (pure 1/sqrt N) and
        # the prediction's ratio, within 4 errors
        pred_ratio = rows[0].predicted / rows[-1].predicted
        assert pred_ratio - 4 * ratio_err < s1.snup / s16.snup < 4 + 4 * ratio_err
        # truth: temporal SNUP of one frame from the noise model A(mu - black) + sigma_c2
        i = "RGB".index(c)
        f = [e for e in truth["frames"] if e["role"] == "flat" and e["exposure"] == 0.04][0]
        mean = f["mean_dn"][i]
        var = truth["A"][i] * (mean - truth["settings"]["NZDI"]["black_level_dn"][i]) \
            + truth["sigma_c2"][i]
        # snup_temporal from 16 frames x 3072 pixels: relative error ~ 1/sqrt(2*15*3072) ~ 0.3 %
        assert res.snup_temporal[c] == pytest.approx(100 * math.sqrt(var) / mean, rel=0.02)
    json.dumps(res.to_dict())


def test_averaging_bad_input():
    with pytest.raises(CcdError, match="only 2"):
        snup_vs_averaging([np.ones((4, 4)) + np.eye(4)] * 2, Ns=(1, 4))
    with pytest.raises(CcdError, match="no frames"):
        snup_vs_averaging([])


# ---- linear range (Fig. 2) -----------------------------------------------------------------
def test_linearity_against_truth(sim):
    session, truth = sim
    assert session.settings() == ("NZDI", "ZDI")
    lin = linearity(session, setting="NZDI")
    assert lin.channels == ("R", "G", "B") and lin.tolerance == 0.02
    for c, ch in enumerate(lin.channels):
        for fit in (f for f in lin.fits if f.channel == ch):
            level = truth["radiance_levels"][str(fit.level)]
            # the mean signal rate is signal_dn_per_s * level (mean of F is 1); the mean of
            # ~3000 pixels x 2 frames has relative error < 1e-3, plus dark current 0.1 %:
            # 1 % is far outside the noise and inside any real nonlinearity
            assert fit.slope == pytest.approx(truth["signal_dn_per_s"][c] * level, rel=0.01)
        lo, hi = lin.ranges[ch]
        assert hi < lin.upper[ch] <= 255
        # the highest-level, longest exposure saturates (truth: saturated_fraction 1)
        assert lin.saturation_dn[ch] == pytest.approx(255, abs=1)
    for p in lin.points:
        t = [e for e in truth["frames"] if e["role"] == "flat" and e["setting"] == "NZDI"
             and e["level"] == p.level and e["exposure"] == p.exposure][0]
        if t["in_linear_range"]:
            assert p.linear          # truly linear points are never rejected at 2 %
        if max(t["saturated_fraction"]) > 0.5:
            assert p.linear is False
    sat = [f for f in lin.fits if f.level == 3]
    assert all(f.saturation_exposure == 0.16 for f in sat)
    json.dumps(lin.to_dict())


def test_linearity_from_arrays_and_errors():
    t = (0.01, 0.02, 0.04, 0.08)
    rng = np.random.default_rng(1)
    groups = {(1, e): [np.clip(np.rint(5 + 2000 * e + rng.normal(0, 1, (16, 16))), 0, 255)
                       .astype(np.uint8) for _ in range(2)] for e in t}
    lin = linearity(groups, darks=[np.full((16, 16), 5, np.uint8)])
    # 2000 DN/s reaches 165 DN at 0.08 s: linear, unsaturated
    assert all(p.linear for p in lin.points) and lin.saturation_dn["L"] is None
    assert lin.fits[0].slope == pytest.approx(2000, rel=0.01)
    with pytest.raises(CcdError, match="no flat"):
        linearity({})
    with pytest.raises(CcdError, match="tolerance"):
        linearity(groups, tolerance=2)
