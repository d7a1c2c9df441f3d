"""Flat-field correction G, O (de Lasarte et al. 2007, eqs. 1–4), base choice, zero dark image
and the comparison with Healey–Kondepudy's K̂, against the ``delasarte07`` simulator's truth.

Noise model used for the expected errors (eqs. 26–28 of Healey & Kondepudy 1994, the
simulator's model): var(DL) = A·(E[DL] − black) + σ²_C per pixel and frame.  Tolerances are
4 standard errors of the compared statistic, derived in each test.
"""
from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from ccdcore import channels
from ccdcore.errors import CcdError
from ccdcore.flatfield.fit import (base_image_study, compare_dark_settings, compare_with_k_map,
                               correct, flat_field, flat_field_from_session, recommend_base,
                               zero_dark)
from ccdcore.session import open_session
from ccdcore.simulate import load_truth, simulate
from ccdcore.flatfield.uniformity import snup

SIZE = (64, 48)


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    out = tmp_path_factory.mktemp("delasarte_ff")
    truth = simulate("delasarte07", out, seed=3, size=SIZE)
    F = load_truth(out).map("flatfield").astype(np.float64)
    return open_session(out), truth, F


def _truth_frame(truth, setting, key):
    return [e for e in truth["frames"] if e["role"] == "flat" and e["setting"] == setting
            and (e["level"], e["exposure"]) == tuple(key)][0]


def _noise_var(truth, mean_map, setting):
    black = np.array(truth["settings"][setting]["black_level_dn"])
    return np.array(truth["A"]) * (mean_map - black) + np.array(truth["sigma_c2"])


# ---- G and O ---------------------------------------------------------------------------------
def test_gain_recovers_true_flat_field(sim):
    session, truth, F = sim
    ff = flat_field_from_session(session, setting="NZDI")
    assert ff.base_key == (truth["base"]["level"], truth["base"]["exposure"])
    assert ff.dark_exposure == truth["base"]["exposure"] and ff.dark.n == 4 and ff.base.n == 8
    # expected relative error of G per pixel: var(G)/G² = (var_B/n_B + var_0/n_0)/Δ² with
    # Δ = S·F the true signal (the simulator's noise model)
    t = truth["base"]["exposure"]
    S = np.array(truth["signal_dn_per_s"]) * truth["radiance_levels"]["3"] * t
    dark = load_truth(session).map("dark_NZDI").astype(np.float64)
    var_b = _noise_var(truth, dark + S * F, "NZDI")
    var_0 = _noise_var(truth, dark, "NZDI")
    rel_sd = np.sqrt(var_b / ff.base.n + var_0 / ff.dark.n) / (S * F)
    GF = ff.G * F
    z = (GF / GF.mean(axis=(0, 1)) - 1) / rel_sd
    n = z[..., 0].size
    for c in range(3):
        # std(z) ~ 1 within 4/sqrt(2n); mean(z) ~ 0 within 4/sqrt(n)
        assert abs(z[..., c].std() - 1) < 4 / math.sqrt(2 * n)
        assert abs(z[..., c].mean()) < 4 / math.sqrt(n)
    # the measured per-pixel error agrees with the model on average (per-pixel variances of
    # 8 and 4 frames: each about 50 % uncertain, averaged over n pixels)
    assert np.nanmean(ff.G_rel_err) == pytest.approx(rel_sd.mean(), rel=0.05)
    # eq. 1 == eq. 2: O + G·DL = <DL_0> + k (DL - DL_0)/(DL_B - DL_0)
    frame = session.read(session.flat_groups(setting="NZDI")[(2, 0.08)][0]).astype(float)
    eq1 = np.stack([ff.channels[c].dark_level + ff.channels[c].k
                    * (frame[..., c] - ff.dark.mean[..., c])
                    / (ff.base.mean[..., c] - ff.dark.mean[..., c]) for c in range(3)], -1)
    assert np.allclose(ff.correct(frame), eq1, rtol=1e-5)
    assert ff.correct(frame).dtype == np.float32
    assert ff.flags.sum() == 0 and set(ff.maps()) >= {"flat_G", "flat_O", "flat_flags"}
    json.dumps(ff.to_dict())


def test_corrected_snup_reaches_shot_noise_limit(sim):
    session, truth, F = sim
    ff = flat_field_from_session(session, setting="NZDI")
    key = (2, 0.08)                  # held out: not the base
    t_img, t_b = 0.08, truth["base"]["exposure"]
    rate = np.array(truth["signal_dn_per_s"])
    x = rate * truth["radiance_levels"]["2"] * t_img * F     # image signal above dark
    y = rate * truth["radiance_levels"]["3"] * t_b * F       # base signal above dark
    dark = load_truth(session).map("dark_NZDI").astype(np.float64)
    var_d = _noise_var(truth, dark + x, "NZDI")
    var_b = _noise_var(truth, dark + y, "NZDI")
    var_0 = _noise_var(truth, dark, "NZDI")
    # C = <DL_0> + k (D - D_0)/(B - D_0): relative variance of k·x/y from the three noises
    rel = var_d / x ** 2 + var_b / ff.base.n / y ** 2 + var_0 / ff.dark.n * (1 / x - 1 / y) ** 2
    k = np.array([c.k for c in ff.channels])
    level = k * (x / y).mean(axis=(0, 1))
    d0 = np.array([c.dark_level for c in ff.channels])
    expected = 100 * np.sqrt((rel * level ** 2).mean(axis=(0, 1))) / (d0 + level)
    limit = 100 * np.sqrt(var_d.mean(axis=(0, 1))) / (dark + x).mean(axis=(0, 1))
    recs = session.flat_groups(setting="NZDI")[key]
    got = [snup(ff.correct(session.read(r))) for r in recs]
    for c, name in enumerate("RGB"):
        mean = np.mean([g[name].snup for g in got])
        err = np.mean([g[name].snup_err for g in got]) / math.sqrt(len(got))
        assert mean == pytest.approx(expected[c], abs=4 * err)
        # and that is the single-frame shot-noise limit plus the base's own noise: < 15 % above
        assert limit[c] < mean < 1.15 * limit[c]


def test_bayer_planes_are_independent(sim):
    session, truth, F = sim
    darks = [channels.mosaic(session.read(r), "rggb")
             for r in session.dark_groups(setting="NZDI")[truth["base"]["exposure"]]]
    base = [channels.mosaic(session.read(r), "rggb")
            for r in session.flat_groups(setting="NZDI")[(3, truth["base"]["exposure"])]]
    ff = flat_field(darks, base, layout="bayer-rggb")
    assert ff.G.shape == darks[0].shape and [c.name for c in ff.channels] == list(channels.PLANES)
    # each plane's G is exactly the mono G of that plane alone
    for name, (r, c) in channels.plane_offsets("rggb").items():
        mono = flat_field([d[r::2, c::2] for d in darks], [b[r::2, c::2] for b in base])
        np.testing.assert_allclose(ff.G[r::2, c::2], mono.G, rtol=1e-6)
    # G recovers the true flat field sampled on the mosaic (same error budget as rgb: < 1 %)
    Fm = channels.mosaic(F, "rggb")
    for name, plane in channels.planes(ff.G * Fm, "rggb").items():
        assert plane.std() / plane.mean() < 0.01
    # perturb the G1 sites of the base: only G1's G changes
    g1 = channels.plane_masks(darks[0].shape, "rggb")["G1"]
    bumped = [np.where(g1, np.clip(b * 1.1, 0, 255), b).astype(np.uint8) for b in base]
    ff2 = flat_field(darks, bumped, layout="bayer-rggb")
    assert not np.array_equal(ff2.G[g1], ff.G[g1])
    np.testing.assert_array_equal(ff2.G[~g1], ff.G[~g1])
    np.testing.assert_array_equal(ff2.O[~g1], ff.O[~g1])
    # correcting a raw frame touches each site with its own plane's maps only
    raw = base[0].copy()
    out1 = ff.correct(raw)
    raw[g1] = 0
    out2 = ff.correct(raw)
    np.testing.assert_array_equal(out1[~g1], out2[~g1])


def test_flags_for_non_positive_or_noisy_difference():
    rng = np.random.default_rng(2)
    shape = (32, 32)
    darks = [10 + rng.normal(0, 1, shape) for _ in range(4)]
    signal = np.full(shape, 90.0)
    signal[4:8, 4:8] = 0.0      # Δ ≈ 0
    signal[20, 20] = -5.0       # Δ < 0 (a pixel darker than dark)
    signal[25, 5] = 1.0         # Δ > 0 but noise dominated: σ_Δ ≈ sqrt(1/4 + 1/4) = 0.7, c = 5
    base = [10 + signal + rng.normal(0, 1, shape) for _ in range(4)]
    ff = flat_field(darks, base)
    expect = signal < 50
    np.testing.assert_array_equal(ff.flags, expect)
    assert np.isfinite(ff.G).all() and np.isfinite(ff.O).all()
    # flagged pixels get k over the local mean of unflagged Δ: about 1 here
    assert np.allclose(ff.G[expect], 1.0, atol=0.02)
    assert ff.channels[0].n_flagged == int(expect.sum())
    assert np.isfinite(ff.correct(base[0])).all()
    # one frame each: no variance, only Δ <= 0 flagged
    ff1 = flat_field(darks[:1], base[:1])
    np.testing.assert_array_equal(ff1.flags, base[0] - darks[0] <= 0)
    assert ff1.flags[20, 20] and any("no temporal" in n for n in ff1.notes)


def test_reference_level_k_and_correct_function():
    darks = [np.full((4, 6), 10.0)] * 2
    base = [np.full((4, 6), 110.0)] * 2
    ff = flat_field(darks, base, k=50.0)
    assert ff.channels[0].k == 50.0
    assert correct(np.full((4, 6), 110.0), ff.G, ff.O)[0, 0] == pytest.approx(60.0)
    rgb = flat_field([np.full((4, 6, 3), 10.0)] * 2, [np.full((4, 6, 3), 110.0)] * 2,
                     k={"R": 1.0, "G": 2.0, "B": 3.0})
    assert [c.k for c in rgb.channels] == [1.0, 2.0, 3.0]
    with pytest.raises(CcdError, match="per channel"):
        flat_field([np.ones((4, 6, 3))] * 2, [np.full((4, 6, 3), 9.0)] * 2, k=(1, 2))


# ---- base image, settings, K̂ --------------------------------------------------------------
def test_recommended_base_in_true_linear_range(sim):
    session, truth, F = sim
    for setting in ("NZDI", "ZDI"):
        rec = recommend_base(session, setting=setting)
        t = _truth_frame(truth, setting, rec.key)
        assert t["in_linear_range"], (setting, rec.key)
        lo_hi = truth["settings"][setting]["linear_range_dn"]
        for c in range(3):
            assert lo_hi[c][0] <= t["mean_dn"][c] <= lo_hi[c][1]
        assert "linear range" in rec.reason and rec.rule
        assert flat_field_from_session(session, setting=setting).base_key == rec.key
        # groups judged inside the range are never saturated ones
        for row in rec.candidates:
            if row["in_linear_range"]:
                assert max(_truth_frame(truth, setting, row["key"])["saturated_fraction"]) == 0
    json.dumps(rec.to_dict())


def test_base_image_study(sim):
    session, truth, F = sim
    study = base_image_study(session, setting="NZDI",
                             candidates=[(1, 0.005), (3, 0.04), (3, 0.16)],
                             images=[(2, 0.08), (1, 0.16)])
    tab = study.table("G")
    assert set(tab) == {None, (1, 0.005), (3, 0.04), (3, 0.16)}
    for img in ((2, 0.08), (1, 0.16)):
        # the recommended base corrects best; a dim or a saturated base hardly helps
        assert tab[(3, 0.04)][img] < 0.5 * tab[None][img]
        assert tab[(3, 0.04)][img] < tab[(1, 0.005)][img]
        assert tab[(3, 0.04)][img] < tab[(3, 0.16)][img]
    assert study.recommended == (3, 0.04)
    near = base_image_study(session, setting="NZDI", images=[(3, 0.04)], nearest=True)
    used = {r["base"] for r in near.rows} - {None}
    assert len(used) == 1 and (3, 0.04) not in used
    json.dumps(study.to_dict())


def test_zero_dark_image_detected_and_worse(sim):
    session, truth, F = sim
    zdi = zero_dark(session.iter_frames(session.dark_groups(setting="ZDI")[0.04]))
    nzdi = zero_dark(session.iter_frames(session.dark_groups(setting="NZDI")[0.04]))
    assert zdi.clipped and "clipped at zero" in zdi.warning and min(zdi.fractions.values()) > 0.5
    assert not nzdi.clipped and nzdi.warning is None and max(nzdi.fractions.values()) == 0
    ff = flat_field_from_session(session, setting="ZDI")
    assert zero_dark(ff).clipped and any("clipped at zero" in n for n in ff.notes)
    assert zero_dark(np.zeros((4, 4))).fractions == {"L": 1.0}
    table = compare_dark_settings(session)
    snups = {(r["setting"], r["channel"]): r["snup_mean"] for r in table.rows}
    n = {r["setting"]: r["n"] for r in table.rows}
    assert n["NZDI"] == n["ZDI"] > 10          # the same images for both settings
    for c in "RGB":                            # Table 2: the non-zero dark image corrects better
        assert snups[("NZDI", c)] < snups[("ZDI", c)]
    json.dumps(table.to_dict())


def test_compare_with_k_map(sim):
    session, truth, F = sim
    cmp = compare_with_k_map(session, setting="NZDI", truth_flatfield=F)
    assert cmp.evaluate != cmp.base and cmp.evaluate not in cmp.configurations
    for r in cmp.rows:
        # G/O removes vignetting and PRNU: near the single-frame limit (its own noise on top)
        assert r["snup_G"] < 1.25 * r["snup_limit"]
        # K̂ keeps the vignetting: SNUP and residual of the order of the true flat field's
        assert r["snup_K"] > 0.7 * r["snup_raw"] and r["residual_K_pct"] > 4
        assert r["residual_G_pct"] < 1
        # but K̂ captures the PRNU: its high-pass residual is small
        assert r["residual_hf_K_pct"] < r["residual_K_pct"] / 3
    assert "vignetting" in cmp.conclusion
    json.dumps(cmp.to_dict())


# ---- bad input -------------------------------------------------------------------------------
def test_bad_input(sim, tmp_path):
    session, truth, F = sim
    ok = [np.full((8, 8), 10.0)] * 2
    lit = [np.full((8, 8), 100.0)] * 2
    rec = SimpleNamespace(relpath="flat/odd_one.tif")
    with pytest.raises(CcdError, match="odd_one.tif"):
        flat_field(ok, [lit[0], (rec, np.full((8, 6), 100.0))])
    with pytest.raises(CcdError, match="base frames have shape"):
        flat_field(ok, [np.full((8, 6), 100.0)])
    with pytest.raises(CcdError, match="no dark"):
        flat_field([], lit)
    with pytest.raises(CcdError, match="no base"):
        flat_field(ok, [])
    with pytest.raises(CcdError, match="NaN"):
        flat_field(ok, [lit[0], (rec, np.where(np.eye(8, dtype=bool), np.nan, 100.0))])
    with pytest.raises(CcdError, match="rgb"):
        flat_field([np.ones((8, 8, 3))], [np.full((8, 8, 3), 9.0)], layout="mono")
    with pytest.raises(CcdError, match="even"):
        flat_field([np.ones((7, 8))], [np.full((7, 8), 9.0)], layout="bayer-rggb")
    with pytest.raises(CcdError, match="nowhere above"):
        flat_field(lit, ok)
    ff = flat_field(ok, lit)
    with pytest.raises(CcdError, match="x.tif"):
        ff.correct(np.ones((8, 8, 3)), where="x.tif")
    with pytest.raises(CcdError, match="no flat group"):
        flat_field_from_session(session, setting="NZDI", base=(9, 1.0))
    # darks at several exposures but none at the one named: the dark model serves, noted
    ff_m = flat_field_from_session(session, setting="NZDI", base=(3, 0.04), dark_exposure=0.5)
    assert ff_m.dark_source == "model"
    assert any("0.5 s is not used for the flat field" in n for n in ff_m.notes)
    with pytest.raises(CcdError, match="setting = 'XYZ'"):
        flat_field_from_session(session, setting="XYZ")
    # a session without darks, and one without flats
    from ccdcore.simulate._common import SessionWriter
    w = SessionWriter(tmp_path / "nodark", camera={"bits": 8, "layout": "mono"})
    for i in range(2):
        w.add_frame(f"flat/f{i}.tif", np.full((8, 8), 100, np.uint8), role="flat", level=1,
                    exposure=0.01)
        w.add_frame(f"flat/g{i}.tif", np.full((8, 8), 200, np.uint8), role="flat", level=1,
                    exposure=0.02)
    w.finish({})
    # no darks: de Lasarte's zero-dark form (DL_0 = 0), noted
    ff0 = flat_field_from_session(open_session(tmp_path / "nodark"), base=(1, 0.01))
    assert ff0.dark_source == "zero" and not ff0.dark.mean.any() and ff0.dark.n == 0
    assert any("zero-dark" in n for n in ff0.notes)
    assert ff0.summary().dark_source == "zero"
    w = SessionWriter(tmp_path / "noflat", camera={"bits": 8, "layout": "mono"})
    w.add_frame("dark/d.tif", np.full((8, 8), 10, np.uint8), role="dark", exposure=0.01)
    w.finish({})
    with pytest.raises(CcdError, match="no flat frames"):
        flat_field_from_session(open_session(tmp_path / "noflat"))
