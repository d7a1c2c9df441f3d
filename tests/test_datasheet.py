"""Tests of ccdcore.emva.datasheet: the EMVA 1288 figures against the reference implementation
(emva1288 1.0.2's Results1288) and against its DatasetGenerator's truth; the product and the
command line carrying them; the session content hash of the provenance.

Tolerances
----------
* Against emva1288: both compute the same definitions from the same integer sums, so they differ
  only by the package's ``scipy.optimize.leastsq`` fits (R, K, the dark-noise line), which stop
  at a relative step of 1.49e-8 (its ``xtol``); we allow 1e-7 relative, and in addition one
  thousandth of our own stated standard error (the difference is statistically nothing).
* Against the generator's truth: 4 stated standard errors (fixed seeds).
"""
from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

# emva1288 1.0.2 calls np.asfarray, removed in NumPy 2 (see docs/notes.md)
np.asfarray = lambda a, dtype=np.float64: np.asarray(a, dtype=dtype)  # noqa: E731

from emva1288.camera.dataset_generator import DatasetGenerator  # noqa: E402
from emva1288.process import (Data1288, LoadImageData, ParseEmvaDescriptorFile,  # noqa: E402
                              Results1288)

from ccdcore.cli.command import main  # noqa: E402
from ccdcore.emva.datasheet import (DISAGREEMENT_Z, EMVA_STEPS, SIGMA2_Y_DARK_FLOOR,  # noqa: E402
                               EmvaFigures, emva_figures)
from ccdcore.errors import CcdError  # noqa: E402
from ccdcore.noise import photon_transfer  # noqa: E402
from ccdcore.product.make import PRODUCT_FILE, calibrate, load_product  # noqa: E402
from ccdcore.session import open_session  # noqa: E402
from ccdcore.simulate import simulate  # noqa: E402

W, H = 64, 48
REL = 1e-7            # leastsq's xtol is 1.49e-8 (module docstring)
ERR_FRACTION = 1e-3   # of our own standard error
Z = 4.0               # standard errors against truth

#: the figures Results1288 has as properties (DR_dB is a method)
FIGURES = ("K", "QE", "sigma_y_dark", "sigma_d", "u_p_min", "u_p_sat", "u_e_sat", "SNR_max",
           "DR", "LE_min", "LE_max", "DSNU1288", "PRNU1288")
INDICES = ("index_u_ysat", "index_sensitivity_max", "index_linearity_min", "index_linearity_max")


def generate(out: Path, **kwargs) -> DatasetGenerator:
    """The reference generator's exposure-time series (12-bit TIFF); kwargs go to its camera."""
    args = dict(steps=16, L=16, image_format="tif", outdir=str(out), width=W, height=H,
                bit_depth=12, seed=5)
    args.update(kwargs)
    return DatasetGenerator(**args)


def reference(descriptor: str | Path) -> Results1288:
    logging.disable(logging.INFO)   # the package logs every file it opens
    try:
        parsed = ParseEmvaDescriptorFile(str(descriptor))
        return Results1288(Data1288(LoadImageData(parsed.images).data).data)
    finally:
        logging.disable(logging.NOTSET)


def assert_agrees(ours: EmvaFigures, ref: Results1288, names=FIGURES) -> None:
    with np.errstate(invalid="ignore"):      # the package takes sqrt of negative variances
        for name in names:
            want, got = float(getattr(ref, name)), getattr(ours, name)
            if math.isnan(want):
                assert got is None or math.isnan(got), name
                continue
            err = getattr(ours, f"{name}_err", None)
            assert got == pytest.approx(want, rel=REL, abs=1e-12), name
            if err is not None and math.isfinite(err):
                assert abs(got - want) <= ERR_FRACTION * err, name
        assert ours.DR_dB == pytest.approx(float(ref.DR_dB()), rel=REL)
        for name in INDICES:
            assert getattr(ours, name) == int(getattr(ref, name)), name


# --------------------------------------------------------------------------------------------
# data sets
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """16 exposure steps and a spatial set of 16 frames; a dark signal far from 0 (no clipped
    dark electrons), a DSNU of 4 e- and a PRNU of 1 %, and a full well above the ADC's range so
    the series ends in clean ADC saturation."""
    rng = np.random.default_rng(1)
    dsnu = rng.normal(0.0, 4.0, (H, W))
    prnu = 1.0 + rng.normal(0.0, 0.01, (H, W))
    gen = generate(tmp_path_factory.mktemp("emva") / "clean", dsnu=dsnu, prnu=prnu,
                   u_esat=60000.0, dark_signal_0=50.0)
    cam = gen.cam
    truth = {"K": float(cam.K), "QE": 100.0 * float(cam.qe.qe.mean()),
             # the generator dithers by U(-1/2, 1/2) before rounding: 2 q²/12 in all, one of
             # which sigma_d keeps (as in benchmarks/bench_ptc_emva.py)
             "sigma_d": math.sqrt(cam._sigma2_dark_0 + 1.0 / (12.0 * cam.K ** 2)),
             "DSNU1288": float(np.std(dsnu, ddof=1)),
             "PRNU1288": 100.0 * float(np.std(prnu, ddof=1) / np.mean(prnu))}
    figures = emva_figures(gen.descriptor_path)
    return gen, truth, figures, reference(gen.descriptor_path)


@pytest.fixture(scope="module")
def plateau(tmp_path_factory):
    """The generator's own defaults: the full well (15000 e-) saturates at 1500 DN, far below
    the 12-bit range, and the package's saturation search stops on the plateau after it."""
    gen = generate(tmp_path_factory.mktemp("emva") / "plateau", steps=12, L=8)
    return gen, emva_figures(gen.descriptor_path), reference(gen.descriptor_path)


# --------------------------------------------------------------------------------------------
# agreement with the reference implementation and with truth
# --------------------------------------------------------------------------------------------
def test_figures_agree_with_the_reference_implementation(clean):
    _, _, ours, ref = clean
    assert_agrees(ours, ref)
    # the dark noise comes from the line over the 16 exposure times (> 2 exposures)
    assert len(ours.dark_points) == 16 and ours.u_y_dark != ours.dark_points[0].u_y_dark
    assert ours.R == pytest.approx(float(ref.R), rel=REL)


def test_figures_agree_with_the_generators_truth(clean):
    _, truth, f, _ = clean
    for name in ("K", "QE", "sigma_d", "DSNU1288", "PRNU1288"):
        err = getattr(f, f"{name}_err")
        assert 0 < err < 0.05 * truth[name], name               # errors are stated and small
        assert abs(getattr(f, name) - truth[name]) < Z * err, name
    # our photon transfer (A = K; sigma_d_ptc from its intercept, eq. 27) measures the same
    assert abs(f.K_ptc - truth["K"]) < Z * f.K_ptc_err
    assert abs(f.sigma_d_ptc - truth["sigma_d"]) < Z * f.sigma_d_ptc_err
    assert f.sigma_d_consistent is True and not f.quantisation_limited
    # the derived figures follow their definitions (sec. 2.4)
    eta = f.QE / 100
    assert f.u_e_sat == pytest.approx(eta * f.u_p_sat)
    assert f.SNR_max == pytest.approx(math.sqrt(f.u_e_sat))
    assert f.u_p_min == pytest.approx((f.sigma_y_dark / f.K + 0.5) / eta)
    assert f.DR_dB == pytest.approx(20 * math.log10(f.u_p_sat / f.u_p_min))


def test_plateau_saturation_is_taken_as_the_package_does_and_noted(plateau):
    gen, ours, ref = plateau
    assert_agrees(ours, ref)
    s2 = [p.s2_y for p in ours.points]
    assert ours.index_u_ysat != int(np.argmax(s2))          # the package's search stopped early
    assert any("plateau after saturation" in n for n in ours.notes)
    assert ours.PRNU1288 is not None and math.isnan(ours.PRNU1288)   # no PRNU simulated


def test_photon_series_at_one_exposure(tmp_path):
    """exposure_fixed: every bright point at one exposure time, one dark point for all of them
    (sigma_y.dark is that dark point's, not a line over exposures)."""
    gen = generate(tmp_path / "fixed", steps=10, L=4, exposure_fixed=2_000_000,
                   u_esat=60000.0, dark_signal_0=50.0)
    ours, ref = emva_figures(gen.descriptor_path), reference(gen.descriptor_path)
    assert_agrees(ours, ref)
    assert len(ours.dark_points) == 1
    assert ours.sigma_y_dark == pytest.approx(math.sqrt(ours.dark_points[0].s2_y_dark))


def test_quantisation_dominated_dark_noise_is_noted(tmp_path):
    """K = 0.1 DN/e- and 1 e- read noise: sigma_y.dark is below 0.5 DN; the package floors
    sigma2_y.dark at 0.24 DN² and so do we; the notes say both in plain words."""
    gen = generate(tmp_path / "q", steps=10, L=4, K=0.1, sigma2_dark_0=1.0,
                   dark_signal_0=50.0, u_esat=60000.0)
    ours = emva_figures(gen.descriptor_path)
    assert_agrees(ours, reference(gen.descriptor_path))
    assert ours.quantisation_limited and ours.sigma_y_dark_measured < 0.5
    assert ours.sigma_y_dark == pytest.approx(math.sqrt(SIGMA2_Y_DARK_FLOOR))
    assert math.isnan(ours.sigma_d_err)                     # a floor has no error
    text = " ".join(ours.notes)
    assert "quantisation" in text and "below 0.5 DN" in text and "floored" in text
    d = ours.to_dict()
    assert d["quantisation_limited"] is True and d["sigma_d_err"] is None


def test_disagreeing_read_noises_are_flagged(clean):
    gen, _, f, _ = clean
    session = open_session(gen.descriptor_path)
    pt = photon_transfer(session)
    err = f.sigma_d_err
    off = dataclasses.replace(pt, read_noise_e=f.sigma_d + 2 * (DISAGREEMENT_Z + 1) * err,
                              read_noise_e_err=err)
    flagged = emva_figures(session, noise=off)
    assert flagged.sigma_d_consistent is False
    assert any("disagree" in n for n in flagged.notes)
    near = dataclasses.replace(pt, read_noise_e=f.sigma_d + err, read_noise_e_err=err)
    assert emva_figures(session, noise=near).sigma_d_consistent is True


def test_stated_errors_match_the_scatter_over_seeds(tmp_path):
    """The standard errors (emva_figures, Notes) against the spread over 12 seeds of the same
    camera (one DSNU and PRNU pattern, new noise).

    Figures: the sample standard deviation of 12 values is within ±45 % of the truth at 2 sigma,
    so the mean stated error must lie within a factor 2 of it (over 60 seeds the ratios were
    0.9–1.2).  The points' sigma²_y errors √(2σ⁴/(N − 1)): 8 points × 12 seeds pooled give the
    standard deviation of the standardised deviations to ±15 % at 2 sigma."""
    rng = np.random.default_rng(1)
    pattern = dict(dsnu=rng.normal(0.0, 4.0, (24, 32)), prnu=1.0 + rng.normal(0.0, 0.01, (24, 32)))
    names = ("K", "QE", "sigma_d", "u_p_min", "DR_dB", "DSNU1288", "PRNU1288")
    values: dict[str, list[float]] = {k: [] for k in names}
    errors: dict[str, list[float]] = {k: [] for k in names}
    s2, s2_err = [], []
    for seed in range(12):
        gen = DatasetGenerator(steps=12, L=4, image_format="tif", outdir=str(tmp_path / str(seed)),
                               width=32, height=24, bit_depth=12, seed=100 + seed,
                               u_esat=60000.0, dark_signal_0=50.0, **pattern)
        f = emva_figures(gen.descriptor_path, with_ptc=False)
        for name in names:
            values[name].append(getattr(f, name))
            errors[name].append(getattr(f, f"{name}_err"))
        s2.append([p.s2_y for p in f.points[:8]])
        s2_err.append([p.s2_y_err for p in f.points[:8]])
    for name in names:
        ratio = np.mean(errors[name]) / np.std(values[name], ddof=1)
        assert 0.5 < ratio < 2.0, (name, ratio)
    s2, s2_err = np.array(s2), np.array(s2_err)
    z = (s2 - s2.mean(axis=0)) / s2_err * math.sqrt(12 / 11)
    assert 0.85 < z.std() < 1.15


def test_derived_errors_propagate_their_parts(clean):
    """First-order propagation, written out once more from the reported parts."""
    _, _, f, _ = clean
    rel = math.hypot
    assert f.QE_err == pytest.approx(f.QE * rel(f.R_err / f.R, f.K_err / f.K))
    s = f.sigma_y_dark ** 2
    assert f.sigma_d_err == pytest.approx(
        f.sigma_d * rel(f.sigma_y_dark * f.sigma_y_dark_err / (s - 1 / 12), f.K_err / f.K))
    assert f.u_e_sat_err == pytest.approx(
        f.u_e_sat * rel(f.QE_err / f.QE, f.u_p_sat_err / f.u_p_sat))
    assert f.SNR_max_err == pytest.approx(f.SNR_max * f.u_e_sat_err / f.u_e_sat / 2)
    assert f.DR_dB_err == pytest.approx(
        20 / math.log(10) * rel(f.u_p_min_err / f.u_p_min, f.u_p_sat_err / f.u_p_sat))
    assert f.DSNU1288_err == pytest.approx(
        f.DSNU1288 * rel(f.spatial_dark.s2_err / (2 * f.spatial_dark.s2), f.K_err / f.K))


def test_progress_reports_each_step(clean):
    gen, *_ = clean
    seen: list[tuple[float, str]] = []
    emva_figures(gen.descriptor_path, progress=lambda f, message: seen.append((f, message)),
                 with_ptc=False)
    assert seen == [(start, name) for name, start in EMVA_STEPS]


def test_to_dict_is_json_safe_under_the_packages_names(clean):
    _, _, f, _ = clean
    d = json.loads(json.dumps(f.to_dict(), allow_nan=False))
    for key in ("K", "K_err", "sigma_d", "sigma_d_err", "sigma_d_ptc", "sigma_d_ptc_err", "QE",
                "QE_err", "u_e_sat", "u_p_sat", "u_p_min", "SNR_max", "DR", "DR_dB", "LE_min",
                "LE_max", "DSNU1288", "PRNU1288", "u_y_dark", "sigma_y_dark", "snr_curve",
                "notes", "points"):
        assert key in d, key
    assert d["K"] == f.K and d["PRNU1288"] == f.PRNU1288
    curve = d["snr_curve"]
    assert len(curve["u_p"]) == len(curve["snr"]) == len(curve["snr_model"]) == len(f.points)
    # at mid range the measured SNR follows the model of eq. 11 (within a few %)
    mid = f.index_sensitivity_max
    assert curve["snr"][mid] == pytest.approx(curve["snr_model"][mid], rel=0.05)
    p = d["points"][0]
    assert {"u_p", "u_y", "u_y_dark", "s2_y", "s2_y_dark", "in_sensitivity_fit",
            "in_linearity_fit", "saturation"} <= set(p)
    assert sum(q["in_sensitivity_fit"] for q in d["points"]) == f.index_sensitivity_max + 1
    assert [q["saturation"] for q in d["points"]].index(True) == f.index_u_ysat


# --------------------------------------------------------------------------------------------
# refusals
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def healey(tmp_path_factory):
    root = tmp_path_factory.mktemp("h94") / "s"
    simulate("healey94", root, seed=2, size=(48, 32), n1=2, n2=1)
    return root


def test_a_session_without_photon_counts_is_refused_clearly(healey):
    with pytest.raises(CcdError, match=r"no photon counts: the EMVA 1288 figures need the "
                                       r"photons per pixel of each bright frame"):
        emva_figures(open_session(healey))


def _without(session, keep):
    return dataclasses.replace(session, frames=tuple(r for r in session.frames if keep(r)))


def test_too_few_points_no_darks_and_saturation_are_refused_clearly(clean):
    gen, _, f, _ = clean
    s = open_session(gen.descriptor_path)
    with pytest.raises(CcdError, match="no dark frames: "):
        emva_figures(_without(s, lambda r: r.role != "dark"), with_ptc=False)
    with pytest.raises(CcdError, match=r"2 temporal bright points .* at least 3"):
        emva_figures(_without(s, lambda r: r.role == "dark" or r.level in (1, 2)),
                     with_ptc=False)
    t = f.points[3].exposure
    with pytest.raises(CcdError, match=f"no dark frames at exposure {t:g} s"):
        emva_figures(_without(s, lambda r: r.role != "dark" or r.exposure != t), with_ptc=False)
    top = {p.level for p in f.points[f.index_u_ysat - 1:]}    # saturation and around it
    with pytest.raises(CcdError, match="every bright point is saturated"):
        emva_figures(_without(s, lambda r: r.role == "dark" or r.level in top), with_ptc=False)


# --------------------------------------------------------------------------------------------
# the product, the command line, the session hash
# --------------------------------------------------------------------------------------------
def test_product_keeps_the_figures_and_the_session_hash(clean, healey, tmp_path):
    gen, _, f, _ = clean
    session = open_session(gen.descriptor_path)
    product = calibrate(session)
    assert product.emva1288 is not None
    assert product.emva1288.K == f.K and product.emva1288.QE == f.QE
    # the photon transfer of the product is the sigma_d_ptc of the figures
    assert product.emva1288.sigma_d_ptc == product.estimates.noise.read_noise_e
    prov = product.provenance
    assert prov.session_hash == session.content_hash() and len(prov.session_hash) == 64
    assert prov.date.endswith("+00:00") and prov.steps.emva1288 is not None
    folder = product.save(tmp_path / "p")
    doc = json.loads((folder / PRODUCT_FILE).read_text())
    assert doc["emva1288"] == product.emva1288.to_dict()
    back = load_product(folder)
    assert back.emva1288 == product.emva1288 and back.provenance == product.provenance

    plain = calibrate(healey)
    assert plain.emva1288 is None and "emva1288" not in plain.to_dict()
    skip = {s.estimate: s for s in plain.skipped}["emva1288"]
    assert skip.code == "not-applicable" and "no photon counts" in skip.reason


def test_old_products_without_the_new_keys_still_load(clean, tmp_path):
    gen, *_ = clean
    folder = calibrate(gen.descriptor_path).save(tmp_path / "p")
    doc = json.loads((folder / PRODUCT_FILE).read_text())
    del doc["emva1288"], doc["provenance"]["session_hash"], doc["provenance"]["date"]
    (folder / PRODUCT_FILE).write_text(json.dumps(doc))
    back = load_product(folder)
    assert back.emva1288 is None and back.provenance.session_hash is None
    doc["emva1288"] = [1, 2]
    (folder / PRODUCT_FILE).write_text(json.dumps(doc))
    with pytest.raises(CcdError, match="'emva1288' must be a JSON object"):
        load_product(folder)


def test_cli_calibrate_prints_the_emva_block(clean, tmp_path, capsys):
    gen, _, f, _ = clean
    assert main(["calibrate", gen.descriptor_path, "-o", str(tmp_path / "c")]) == 0
    out = capsys.readouterr().out
    assert "EMVA 1288" in out and "DSNU1288" in out and "from photon transfer" in out
    assert f"{f.K:.4f}" in out
    assert main(["calibrate", gen.descriptor_path, "-o", str(tmp_path / "j"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["emva1288"]["K"] == f.K


def test_content_hash_changes_with_one_byte_and_only_then(clean, tmp_path):
    gen, *_ = clean
    root = tmp_path / "copy"
    shutil.copytree(Path(gen.descriptor_path).parent, root)
    desc = root / "EMVA1288descriptor.txt"
    first = open_session(desc).content_hash()
    # the same files elsewhere, and a fresh session of them: the same hash
    assert open_session(gen.descriptor_path).content_hash() == first
    assert open_session(desc).content_hash() == first
    # one byte of one frame, same size
    rec = open_session(desc).frames[5]
    data = bytearray(rec.path.read_bytes())
    data[-1] ^= 1
    st = rec.path.stat()
    rec.path.write_bytes(bytes(data))
    # the cache is keyed by size and st_mtime_ns; a file system with coarse timestamps could
    # give the rewrite the old time: set a later one, as any later write would have
    os.utime(rec.path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))
    changed = open_session(desc).content_hash()
    assert changed != first
    data[-1] ^= 1
    rec.path.write_bytes(bytes(data))
    os.utime(rec.path, ns=(st.st_atime_ns, st.st_mtime_ns + 2_000_000))
    assert open_session(desc).content_hash() == first       # content, not times
