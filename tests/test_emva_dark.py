"""Tests of ccdcore.emva.dark (the dark current of EMVA 1288 sec. 3.1) and of the new figures of
ccdcore.emva.datasheet against the reference implementation (emva1288 1.0.2's Results1288: u_I_mean,
u_I_var, DSNU1288_row/col/pixel, PRNU1288_row/col/pixel) and the generator's dark current.

Tolerances
----------
* Exact lines: 1e-12 relative (rounding of a closed-form fit).
* Stated errors against the scatter over 400 simulated series: the ratio in [0.85, 1.18]
  (1/√(2·400) = 3.5 % per standard deviation, four of them).
* Against Results1288: 1e-7 relative (its leastsq fit of K stops at a relative step of 1.49e-8).
* Against the generator's dark current: 4 stated standard errors.
"""
from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
import pytest

# emva1288 1.0.2 calls np.asfarray, removed in NumPy 2 (see docs/notes.md)
np.asfarray = lambda a, dtype=np.float64: np.asarray(a, dtype=dtype)  # noqa: E731

from emva1288.camera.dataset_generator import DatasetGenerator  # noqa: E402
from emva1288.process import (Data1288, LoadImageData, ParseEmvaDescriptorFile,  # noqa: E402
                              Results1288)

from ccdcore.emva.datasheet import emva_figures  # noqa: E402
from ccdcore.emva.dark import RESOLVED_Z, dark_current  # noqa: E402
from ccdcore.emva.sheet import DATASHEET, datasheet_rows  # noqa: E402

T = np.array([0.001, 0.01, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5])
K = 0.1


def _points(current: float, t=T, offset=20.0, read2=10.0, noise=0.0, seed=0):
    """Dark points of a camera with dark current ``current`` e-/s: mean offset + K μ_I t (DN),
    variance K² (read² + μ_I t) + 1/12 (DN²), each with an error; ``noise`` > 0 scatters them
    by their errors."""
    rng = np.random.default_rng(seed)
    mu = offset + K * current * t
    s2 = K * K * (read2 + current * t) + 1.0 / 12.0
    mu_err = np.full(t.size, 0.002)
    s2_err = 0.01 * s2
    if noise:
        mu = mu + noise * mu_err * rng.normal(size=t.size)
        s2 = s2 + noise * s2_err * rng.normal(size=t.size)
    return list(t), mu, mu_err, s2, s2_err


def test_exact_lines_give_the_current_from_mean_and_variance():
    """μ_I = slope of the mean / K and slope of the variance / K² (sec. 3.1)."""
    d = dark_current(*_points(1500.0), K, 0.0)
    assert d.u_I_mean == pytest.approx(1500.0, rel=1e-12)
    assert d.u_I_var == pytest.approx(1500.0, rel=1e-12)
    assert d.mean_line.offset == pytest.approx(20.0, rel=1e-12)
    assert d.notes == () and d.u_I_mean_bound is None


def test_stated_errors_match_the_scatter_of_the_slopes():
    draws = [dark_current(*_points(1500.0, noise=1.0, seed=s), K, 0.0) for s in range(400)]
    for name in ("u_I_mean", "u_I_var"):
        values = np.array([getattr(d, name) for d in draws])
        stated = float(np.median([getattr(d, f"{name}_err") for d in draws]))
        assert 0.85 <= values.std(ddof=1) / stated <= 1.18, (name, values.std(ddof=1), stated)
        assert abs(values.mean() - 1500.0) < 4 * stated / math.sqrt(len(draws))


def test_K_error_enters_the_current():
    """K's relative error adds in quadrature to the slope's (twice it for the variance:
    μ_I = slope / K²)."""
    alone = dark_current(*_points(1500.0), K, 0.0)
    d = dark_current(*_points(1500.0), K, 0.01 * K)
    assert d.u_I_mean_err == pytest.approx(math.hypot(alone.u_I_mean_err, 0.01 * 1500.0),
                                           rel=1e-9)
    assert d.u_I_var_err == pytest.approx(math.hypot(alone.u_I_var_err, 0.02 * 1500.0),
                                          rel=1e-9)


def test_a_current_the_range_cannot_resolve_is_none_with_its_bound():
    """Mean falling with time (an offset drift): no negative current, a note saying why and the
    bound (the slope's error times RESOLVED_Z, at least zero); a tiny positive current within
    its noise: 'not resolved' with the bound slope + 2 σ."""
    t, mu, mu_err, s2, s2_err = _points(0.0)
    falling = mu - 0.01 * np.asarray(t)
    d = dark_current(t, falling, mu_err, s2, s2_err, K, 0.0)
    assert d.u_I_mean is None and d.u_I_mean_err is None
    assert d.u_I_mean_bound == pytest.approx(RESOLVED_Z * d.mean_line.slope_err / K)
    note = next(n for n in d.notes if n.startswith("u_I_mean "))
    assert "falls with the exposure time" in note and f"{d.u_I_mean_bound:.3g}" in note
    tiny = dark_current(*_points(0.01), K, 0.0)
    slope_e = tiny.mean_line.slope_err / K
    assert tiny.u_I_mean is None
    assert tiny.u_I_mean_bound == pytest.approx(0.01 * (tiny.mean_line.slope / K / 0.01)
                                                + RESOLVED_Z * slope_e, rel=1e-9)
    assert any(n.startswith("u_I_mean is not resolved") for n in tiny.notes)


def test_fewer_than_three_exposure_times_give_no_current(generated):
    t, mu, mu_err, s2, s2_err = _points(1500.0, t=np.array([0.01, 0.01, 0.2]))
    d = dark_current(t, mu, mu_err, s2, s2_err, K, 0.0)
    assert d.u_I_mean is None and d.u_I_var is None and d.mean_line is None
    assert d.notes and d.notes[0].startswith("no dark current") and "2 exposure times" in d.notes[0]
    # figures with this dark current's notes and without its figures
    figures = dataclasses.replace(generated[1].summary(), u_I_mean=None, u_I_mean_err=None,
                                  notes=d.notes)
    rows = {r.key: r for r in datasheet_rows(figures)}
    assert rows["u_I_mean"].note == d.notes[0]


# ---------------------------------------------------------------------- against emva1288 ----
W, H = 64, 48


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """The reference generator's series with a dark current of 1500 e-/s and DSNU/PRNU maps
    with row, column and pixel parts."""
    rng = np.random.default_rng(1)
    dsnu = rng.normal(0, 2.0, (H, 1)) + rng.normal(0, 3.0, (1, W)) + rng.normal(0, 4.0, (H, W))
    prnu = (1.0 + rng.normal(0, 0.004, (H, 1)) + rng.normal(0, 0.006, (1, W))
            + rng.normal(0, 0.01, (H, W)))
    gen = DatasetGenerator(steps=16, L=16, image_format="tif",
                           outdir=str(tmp_path_factory.mktemp("emva") / "dc"), width=W, height=H,
                           bit_depth=12, seed=5, dsnu=dsnu, prnu=prnu, u_esat=60000.0,
                           dark_signal_0=50.0, dark_current_ref=3000)
    logging.disable(logging.INFO)
    try:
        ref = Results1288(Data1288(LoadImageData(
            ParseEmvaDescriptorFile(gen.descriptor_path).images).data).data)
    finally:
        logging.disable(logging.NOTSET)
    return gen, emva_figures(gen.descriptor_path, with_ptc=False), ref


NEW = ("u_I_mean", "u_I_var", "DSNU1288_row", "DSNU1288_col", "DSNU1288_pixel", "PRNU1288_row",
       "PRNU1288_col", "PRNU1288_pixel")


def test_new_figures_agree_with_the_reference_implementation(generated):
    _, ours, ref = generated
    d = ours.to_dict()
    for name in NEW:
        assert d[name] == pytest.approx(float(getattr(ref, name)), rel=1e-7), name
        assert d[f"{name}_err"] > 0


def test_dark_current_against_the_generators_truth(generated):
    gen, ours, _ = generated
    truth = float(gen.cam._u_i())
    dc = ours.dark_current
    assert truth == pytest.approx(1500.0)
    assert abs(dc.u_I_mean - truth) <= 4 * dc.u_I_mean_err
    assert abs(dc.u_I_var - truth) <= 4 * dc.u_I_var_err


def test_datasheet_rows_follow_the_standard_and_carry_every_figure(generated):
    _, ours, _ = generated
    d = ours.to_dict()
    rows = datasheet_rows(ours.summary())
    assert [r.key for r in rows] == [k for _, k, _, _, _ in DATASHEET]
    for r in rows:
        if r.key == "sigma_d_ptc":                 # photon transfer was not run here
            assert r.value is None and r.note
            continue
        assert r.value == d[r.key] and r.error == d[f"{r.key}_err"] and r.note is None, r.key
    plots = d["spatial_plots"]
    assert set(plots["spectrograms"]) == {"DSNU_horizontal", "DSNU_vertical", "PRNU_horizontal",
                                          "PRNU_vertical"}
    assert len(plots["spectrograms"]["DSNU_horizontal"]["f"]) == W // 2 + 1
    assert len(plots["profiles"]["dark_vertical"]["mean"]) == H


# ------------------------------------------------------- darks at many exposure times ----
def test_exposures_in_a_few_words_and_the_nearest_one():
    from ccdcore.dark.frame import exposures_text, nearest_exposure

    assert exposures_text([0.4, 0.1, 0.2]) == "0.1, 0.2 and 0.4 s"
    many = list(np.linspace(4e-5, 0.05, 51))
    assert exposures_text(many) == "51 exposures, 4e-05 to 0.05 s"
    assert nearest_exposure([0.001, 0.01, 0.1], 0.03) == 0.01        # ratio 3 vs 3.33
    assert nearest_exposure([0.01, 0.04], 0.02) == 0.04               # a tie: the longer


def test_calibrate_makes_the_dark_reference_at_the_exposure_nearest_the_bright_frames(
        generated, tmp_path, capsys):
    """An EMVA set's darks span 16 exposure times: the dark reference and its hot/dead maps are
    made (not skipped) at the one nearest the ptc frames' median exposure, and a note says so
    in a few words (never every exposure); --dark-exposure names another."""
    from ccdcore.cli.command import main
    from ccdcore.common import format_pm
    from ccdcore.product.make import calibrate, dark_exposure_for
    from ccdcore.session import open_session

    gen, _, _ = generated
    session = open_session(gen.descriptor_path)
    have = sorted({r.exposure for r in session.dark_frames()})
    median = float(np.median([r.exposure for r in session.by_role("ptc")]))
    chosen, note = dark_exposure_for(session)
    assert len(have) == 16
    assert chosen == min(have, key=lambda t: abs(math.log(t / median)))
    assert "16 exposures" in note and "nearest" in note and str(have[3]) not in note
    product = calibrate(session)
    dark = product.estimates.dark
    assert dark.exposure == pytest.approx(chosen) and dark.notes[0] == note
    assert not any(s.estimate == "dark" for s in product.skipped)
    other = have[2]
    assert main(["calibrate", str(gen.descriptor_path), "-o", str(tmp_path / "p"),
                 "--dark-exposure", repr(other)]) == 0
    out = capsys.readouterr().out
    assert f"made at {other:g} s, as named" in " ".join(out.split())
    d = product.emva1288
    assert (f"    dark current   μ_I.mean = "
            f"{format_pm(d.u_I_mean, d.u_I_mean_err, unit='e⁻/s')}; μ_I.var = " in out)
    flat = " ".join(out.split())
    for part in ("row", "col", "pixel"):
        value, err = getattr(d, f"DSNU1288_{part}"), getattr(d, f"DSNU1288_{part}_err")
        assert f"DSNU1288.{part} = {format_pm(value, err, unit='e⁻')}" in flat
    assert "\u00a0" not in out
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", str(gen.descriptor_path), "-o", str(tmp_path / "q"),
              "--dark-exposure", "-1"])
    assert exc.value.code == 2
    assert "must be a positive number of seconds" in capsys.readouterr().err


def test_a_section_as_markdown_items(generated):
    from ccdcore.common import format_pm
    from ccdcore.emva.sheet import section_markdown

    _, ours, _ = generated
    d = ours.to_dict()
    lines = section_markdown(ours.summary(), "Dark current")
    assert lines == [f"- Dark current from the mean, μ_I.mean = **"
                     f"{format_pm(d['u_I_mean'], d['u_I_mean_err'], unit='e⁻/s')}**",
                     f"- Dark current from the variance, μ_I.var = **"
                     f"{format_pm(d['u_I_var'], d['u_I_var_err'], unit='e⁻/s')}**"]
    missing = section_markdown(
        dataclasses.replace(ours.summary(), u_I_mean=None, u_I_mean_err=None,
                            notes=("u_I_mean is not resolved: <x> below 3 e-/s",)),
        "Dark current")
    assert missing[0] == ("- Dark current from the mean, μ_I.mean: not determined — "
                          "u_I_mean is not resolved: &lt;x&gt; below 3 e-/s")


def test_a_line_the_points_do_not_follow_is_noted():
    """Points scattered 6 times their errors about the line (χ²/ν ≈ 36, Q ≪ 1e-3): the current
    is still given, with its error scaled by √(χ²/ν), and a note says the line may not describe
    the darks; points that follow their line get no note."""
    t, mu, mu_err, s2, s2_err = _points(1500.0)
    wobble = 6.0 * s2_err * np.where(np.arange(len(t)) % 2, 1.0, -1.0)
    d = dark_current(t, mu, mu_err, s2 + wobble, s2_err, K, 0.0)
    assert d.u_I_var is not None and d.var_line.chi2_dof > 20
    assert any(n.startswith("u_I_var: the dark variance scatters") for n in d.notes)
    assert not any(n.startswith("u_I_mean:") for n in d.notes)
    assert dark_current(*_points(1500.0, noise=1.0, seed=2), K, 0.0).notes == ()


def test_figures_take_another_photon_transfer_without_reading_frames(generated):
    """with_photon_transfer(figures without photon transfer, noise) is what emva_figures gives
    with that photon transfer (its notes in another order), for the paper's and the EMVA
    range; and None takes σ_d from the intercept out again."""
    from ccdcore.emva.datasheet import with_photon_transfer
    from ccdcore.noise import EMVA_FIT_FRACTION, photon_transfer
    from ccdcore.session import open_session

    gen, base, _ = generated
    session = open_session(gen.descriptor_path)
    for fraction in (None, EMVA_FIT_FRACTION):
        noise = photon_transfer(session, fit_fraction=fraction)
        want = emva_figures(session, noise=noise).to_dict()
        got = with_photon_transfer(base, noise).to_dict()
        assert got["sigma_d_ptc"] == want["sigma_d_ptc"] and got["K_ptc"] == want["K_ptc"]
        assert sorted(got.pop("notes")) == sorted(want.pop("notes"))
        assert got == want
    again = with_photon_transfer(with_photon_transfer(base, noise), None)
    assert again.sigma_d_ptc is None and again.notes == base.notes
