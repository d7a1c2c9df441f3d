"""Tests of ccdcore.capture: the capture plan's rules, its predicted error of A and its manifest."""
from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from ccdcore.capture import MIN_BRACKET, MIN_DARKS, plan_captures, predicted_gain_error
from ccdcore.errors import CcdError
from ccdcore.io.frames import write_image
from ccdcore.noise import weighted_line_fit
from ccdcore.planning import plan_acquisition
from ccdcore.session import open_session

# the paper's camera (Healey & Kondepudy 1994, sec. VII-A)
A, SC2, BITS = 0.003384, 1.1196, 8


def test_predicted_gain_error_matches_the_spread_of_the_fit() -> None:
    """Sample variances of M pixels drawn from their χ² law (eq. 38) and fitted by the appendix
    fit (eqs. 59–66) scatter A as predicted; 4000 draws give the spread to 1.1 % (1σ)."""
    rng = np.random.default_rng(11)
    M, draws = 1000, 4000
    mu = np.linspace(10.0, 220.0, 8)
    s2 = A * mu + SC2
    predicted = predicted_gain_error(mu, A, SC2, M)
    est = np.empty(draws)
    var_var = 2.0 * s2 ** 2 / (M - 1)
    for i in range(draws):
        var = s2 * rng.chisquare(M - 1, size=mu.size) / (M - 1)
        est[i] = weighted_line_fit(mu, var, var_var).A
    assert abs(est.mean() - A) < 4 * predicted / math.sqrt(draws)
    assert np.std(est, ddof=1) == pytest.approx(predicted, rel=0.04)


def test_the_plan_follows_each_rule() -> None:
    p = plan_captures(BITS, A, sigma_c2=SC2, pixels=256 * 192, exposure_half=0.01)
    darks = p.group("Dark frames")
    # s: σ²_C/s ≤ q²/10 → 12, raised to the minimum of 16
    assert darks.count == max(MIN_DARKS, math.ceil(SC2 / 0.1)) == 16
    # photon transfer: 8 levels × 2 frames spread over 5–85 % of full scale
    ptc = p.group("Photon transfer pairs")
    levels = [k["level"] for _, k in ptc.frames]
    assert levels == [k for k in range(1, 9) for _ in range(2)]
    exps = sorted({k["exposure"] for _, k in ptc.frames})
    assert exps[0] == pytest.approx(0.01 * 0.05 * 255 / 127.5, rel=1e-3)
    assert exps[-1] == pytest.approx(0.01 * 0.85 * 255 / 127.5, rel=1e-3)
    assert p.gain_rel_err == pytest.approx(
        predicted_gain_error(np.linspace(0.05, 0.85, 8) * 255, A, SC2, 256 * 192) / A)
    # fixed pattern: n2 from sec. V-B at full scale (the paper's numbers give 10), n1 from the
    # σ̂ predicted by the noise alone at the card level
    fp = p.group("Fixed-pattern configurations")
    n2 = plan_acquisition(A, SC2, BITS, sigma_hat=0.0).n2_required
    assert n2 == 10
    mu_k = 0.75 * 255
    sigma_hat = math.sqrt((A * mu_k + SC2) / n2 + SC2 / 16) / mu_k
    assert p.sigma_hat == pytest.approx(sigma_hat, rel=1e-12)
    n1 = plan_acquisition(A, SC2, BITS, sigma_hat=sigma_hat).n1_required
    configs = [k["config"] for _, k in fp.frames]
    assert sorted(set(configs)) == list(range(1, n1 + 1))
    assert all(configs.count(c) == n2 for c in set(configs))
    # flats: a factor 2 apart up to 95 % of full scale, the mid-range base with N frames
    flats = p.group("Flat fields")
    t = sorted({k["exposure"] for _, k in flats.frames})
    assert all(b / a == pytest.approx(2.0, rel=1e-3) for a, b in zip(t, t[1:]))
    assert t[-1] * 0.05 / t[0] <= 0.95 + 1e-6 < t[-1] * 2 * 0.05 / t[0]
    base = max(t, key=lambda e: sum(k["exposure"] == e for _, k in flats.frames))
    mu_b = 255 * 0.05 * base / t[0]
    assert abs(mu_b - 127.5) == min(abs(255 * 0.05 * e / t[0] - 127.5) for e in t)
    n_base = sum(k["exposure"] == base for _, k in flats.frames)
    assert n_base == math.ceil((100 * math.sqrt(A * mu_b + SC2) / mu_b / 0.3) ** 2)
    # bracket: ratio √2 between frames, spanning 0.25·100/0.9 in exposure
    br = [k["exposure"] for _, k in p.group("Exposure bracket").frames]
    assert len(br) == math.ceil(math.log(0.25 * 100 / 0.9) / math.log(math.sqrt(2))) + 1
    assert all(b / a == pytest.approx(math.sqrt(2), rel=1e-5) for a, b in zip(br, br[1:]))


def test_a_pilot_fixed_pattern_replaces_the_predicted_spread() -> None:
    class Pilot:                       # what plan_acquisition reads from a FixedPattern
        sigma_hat, worst_ratio, n1, n1_hat = 0.004, 1.5, 5, 4

    p = plan_captures(BITS, A, sigma_c2=SC2, fixed_pattern=Pilot())
    assert p.sigma_hat == 0.004
    want = plan_acquisition(A, SC2, BITS, fixed_pattern=Pilot()).n1_required
    assert p.fixed_pattern.n1_required == want
    assert {k["config"] for _, k in p.group("Fixed-pattern configurations").frames} == set(
        range(1, want + 1))


def test_read_noise_in_electrons_gives_sigma_c2_by_eq_27() -> None:
    p = plan_captures(12, 0.5, read_noise_e=3.0)
    assert p.inputs["sigma_c2"] == pytest.approx((0.5 * 3.0) ** 2 + 1 / 12)
    # here the q²/10 rule, not the minimum, sets the dark frames: ceil(2.333/0.1) = 24
    assert p.group("Dark frames").count == math.ceil(p.inputs["sigma_c2"] / 0.1) == 24
    assert len(p.group("Exposure bracket").frames) >= MIN_BRACKET


def test_the_template_opens_as_the_planned_session(tmp_path: Path) -> None:
    p = plan_captures(10, 0.05, read_noise_e=5.0, name='lab "cam" 1', black_level=32.0,
                      ptc_levels=5, scene_range=20.0)
    text = p.to_toml()
    doc = tomllib.loads(text)
    assert doc["camera"] == {"name": 'lab "cam" 1', "bits": 10, "layout": "mono",
                             "black_level": 32.0}
    rng = np.random.default_rng(3)
    for entry in doc["frames"]:
        write_image(tmp_path / entry["path"], rng.integers(40, 900, (6, 8)).astype(np.uint16))
    (tmp_path / "session.toml").write_text(text)
    s = open_session(tmp_path)
    assert s.ok, [str(e) for e in s.errors]
    planned = {}
    for g in p.groups:
        planned[g.role] = planned.get(g.role, 0) + g.count
    assert s.roles() == planned
    assert [len(v) for v in s.ptc_levels().values()] == [2] * 5
    fp = p.fixed_pattern
    assert {c: len(v) for c, v in s.fixed_pattern_configs().items()} == {
        c: fp.n2_required for c in range(1, fp.n1_required + 1)}
    assert len(s.bracket_stacks()) == 1
    assert p.checklist().count("- [ ] ") == len(p.groups)


@pytest.mark.parametrize("kwargs, where", [
    ({"bits": 0, "gain": A, "sigma_c2": SC2}, "bits"),
    ({"bits": 8, "gain": -1.0, "sigma_c2": SC2}, "gain"),
    ({"bits": 8, "gain": A}, "read noise"),
    ({"bits": 8, "gain": A, "sigma_c2": SC2, "ptc_levels": 2}, "ptc_levels"),
    ({"bits": 8, "gain": A, "sigma_c2": SC2, "black_level": 200.0}, "black_level"),
    ({"bits": 8, "gain": A, "sigma_c2": SC2, "layout": "cmyk"}, "layout"),
    ({"bits": 8, "gain": A, "sigma_c2": SC2, "bracket_ratio": 1.0}, "plan"),
])
def test_bad_inputs_name_the_input(kwargs: dict, where: str) -> None:
    with pytest.raises(CcdError) as err:
        plan_captures(**kwargs)
    assert str(err.value).startswith(where)
