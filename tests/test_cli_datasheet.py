"""``ccdcore datasheet``: the EMVA 1288 figures as CSV, JSON and plots, from a session or a
calibration product; and ``ccdcore ptc --emva-range``, the EMVA 1288 fit range of photon
transfer (release 3.1 sec. 6.6: the levels up to 70 % of the saturation signal).

The data set is the reference generator's (emva1288 1.0.2 ``DatasetGenerator``, fixed seeds)
with a dark current high enough to be resolved and DSNU/PRNU patterns for the spatial plots.
"""
from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import json
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

# emva1288 1.0.2 calls np.asfarray, removed in NumPy 2 (see docs/notes.md)
np.asfarray = lambda a, dtype=np.float64: np.asarray(a, dtype=dtype)  # noqa: E731

from emva1288.camera.dataset_generator import DatasetGenerator  # noqa: E402

import ccdcore.emva.datasheet_files as datasheet_files  # noqa: E402
from ccdcore.cli.command import main  # noqa: E402
from ccdcore.common import format_pm  # noqa: E402
from ccdcore.io.frames import RECORD  # noqa: E402
from ccdcore.emva.datasheet import emva_figures  # noqa: E402
from ccdcore.emva.datasheet_files import CSV_COLUMNS, PLOT_FORMATS, PLOTS  # noqa: E402
from ccdcore.emva.sheet import DATASHEET, datasheet_rows  # noqa: E402
from ccdcore.noise import EMVA_FIT_FRACTION  # noqa: E402
from ccdcore.product.make import PRODUCT_FILE  # noqa: E402
from ccdcore.simulate import simulate  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
W, H = 64, 48
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
SVG_ROOT = "{http://www.w3.org/2000/svg}svg"


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def tree(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes) but the record of what ccdcore wrote
    there (RECORD, rewritten by every run)."""
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name != RECORD}


@pytest.fixture(scope="module")
def emva_set(tmp_path_factory):
    """16 exposure steps and a spatial set of 16 frames; a DSNU of 4 e-, a PRNU of 1 %, a dark
    current the exposure series resolves, and a full well above the 12-bit range (the series
    ends in ADC saturation)."""
    rng = np.random.default_rng(1)
    gen = DatasetGenerator(steps=16, L=16, image_format="tif",
                           outdir=str(tmp_path_factory.mktemp("emva") / "set"), width=W,
                           height=H, bit_depth=12, seed=5,
                           dsnu=rng.normal(0.0, 4.0, (H, W)),
                           prnu=1.0 + rng.normal(0.0, 0.01, (H, W)),
                           u_esat=60000.0, dark_signal_0=50.0, dark_current_ref=3000)
    return Path(gen.descriptor_path)


@pytest.fixture(scope="module")
def figures(emva_set):
    """The figures of the session as their record (``EmvaSummary``)."""
    return emva_figures(emva_set).summary()


@pytest.fixture(scope="module")
def sheet(emva_set, tmp_path_factory):
    """The datasheet of the session (text summary): its folder and stdout."""
    out = tmp_path_factory.mktemp("sheet") / "ds"
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(["datasheet", str(emva_set), "-o", str(out)])
    assert code == 0, stderr.getvalue()
    return out, stdout.getvalue(), stderr.getvalue()


@pytest.fixture(scope="module")
def healey(tmp_path_factory):
    """A session whose ptc frames have no photon counts."""
    root = tmp_path_factory.mktemp("h94") / "s"
    simulate("healey94", root, seed=2, size=(48, 32), n1=2, n2=1)
    return root


# --------------------------------------------------------------------------------------------
# the files of a session's datasheet
# --------------------------------------------------------------------------------------------
def test_every_file_is_written_and_every_plot_is_a_png_and_an_svg(sheet, figures):
    out, stdout, stderr = sheet
    assert datasheet_files.plot_plan(figures).skipped == ()     # the set has every plot's data
    assert sorted(p.name for p in out.iterdir()) == [RECORD, "datasheet.csv", "datasheet.json",
                                                     "plots"]
    expected = sorted(f"{name}.{fmt}" for name in PLOTS for fmt in PLOT_FORMATS)
    assert sorted(p.name for p in (out / "plots").iterdir()) == expected
    assert len(PLOTS) == 16 and "skipped plot" not in stderr
    for name in PLOTS:
        png = (out / "plots" / f"{name}.png").read_bytes()
        assert png[:8] == PNG_SIGNATURE, name
        width, height = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
        assert width >= 600 and height >= 400, name              # IHDR: a drawn figure
        svg = ET.parse(out / "plots" / f"{name}.svg").getroot()
        assert svg.tag == SVG_ROOT, name
        assert len(list(svg.iter())) > 50, name                 # axes, ticks, lines
    # no temporary folder left beside the set
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".ccdcore-tmp")]


def test_the_csv_round_trips_the_figures_exactly(sheet, figures):
    out, _, _ = sheet
    with open(out / "datasheet.csv", newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames) == CSV_COLUMNS
        rows = list(reader)
    assert [r["key"] for r in rows] == [d[1] for d in DATASHEET]        # the standard's order
    determined = undetermined = 0
    for r, (section, key, name, symbol, unit) in zip(rows, DATASHEET):
        assert (r["section"], r["name"], r["symbol"], r["unit"]) == (section, name, symbol, unit)
        want, want_err = getattr(figures, key), getattr(figures, f"{key}_err")
        if want is None:
            undetermined += 1
            assert r["value"] == r["error"] == "" and r["note"], key
            continue
        determined += 1
        assert float(r["value"]) == want, key                         # exact, not approximate
        assert r["note"] == "", key
        if want_err is None:
            assert r["error"] == "", key
        else:
            assert float(r["error"]) == want_err, key
    # both kinds are exercised: the dark current is resolved, some DSNU/PRNU parts are not
    assert figures.u_I_mean is not None and figures.u_I_var is not None
    assert determined >= 18 and undetermined >= 1


def test_the_json_holds_the_figures_and_the_rows(sheet, figures):
    out, _, _ = sheet
    doc = json.loads((out / "datasheet.json").read_text(encoding="utf-8"))
    assert doc["emva1288"] == figures.to_dict()
    assert doc["rows"] == [r.to_dict() for r in datasheet_rows(figures)]
    assert doc["plots"] == {"drawn": list(PLOTS), "skipped": []}
    # the plot data the figures carry are in it too
    assert doc["emva1288"]["spatial_plots"]["histograms"]["DSNU"]["count"] == \
        list(figures.spatial_plots.histograms.DSNU.count)


def test_the_summary_lists_every_figure_and_the_files(sheet, figures):
    out, stdout, _ = sheet
    lines = stdout.splitlines()
    at = 0
    for r in datasheet_rows(figures):           # in order: DR is both in dB and as a ratio
        at = next(i for i in range(at, len(lines))
                  if lines[i].split()[:len(r.name.split()) + 1] == r.name.split() + [r.symbol])
        if r.value is None:
            assert lines[at].rstrip().endswith("not determined")
            below = []                                                 # its reason below it
            for ln in lines[at + 1:]:
                if not ln.startswith("      "):
                    break
                below.append(ln)
            assert " ".join(" ".join(below).split()) == " ".join(r.note.split())
        else:
            assert lines[at].rstrip().endswith(format_pm(r.value, r.error, unit=r.unit))
        at += 1
    assert str(out / "datasheet.csv") in stdout and str(out / "datasheet.json") in stdout
    assert "16 plots, PNG and SVG each" in " ".join(stdout.split()) and "profiles_dark" in stdout


# --------------------------------------------------------------------------------------------
# a calibration product as the source
# --------------------------------------------------------------------------------------------
def test_a_product_gives_the_same_datasheet_and_may_hold_it(capsys, emva_set, sheet, tmp_path):
    out, _, _ = sheet
    product = tmp_path / "product"
    code, _, err = run(capsys, "calibrate", emva_set, "-o", product)
    assert code == 0, err
    before = tree(product)
    # written into the product folder itself: the product's files are not touched
    code, stdout, err = run(capsys, "datasheet", product, "-o", product, "--json")
    assert code == 0, err
    doc = json.loads(stdout)
    assert {k: v for k, v in tree(product).items() if k in before} == before   # untouched
    assert doc["source"] == str(product / PRODUCT_FILE)
    assert sorted(doc["files"]) == sorted(str(product / k) for k in tree(product)
                                          if k not in before)
    assert doc["plots"]["skipped"] == [] and len(doc["rows"]) == len(DATASHEET)
    # the product's figures are the session's: the same CSV, the same plots, byte for byte
    # (no date in the SVG, fixed element ids)
    assert (product / "datasheet.csv").read_bytes() == (out / "datasheet.csv").read_bytes()
    new = tree(product / "plots")
    assert new == tree(out / "plots")
    stored = json.loads((product / PRODUCT_FILE).read_text())["emva1288"]
    assert json.loads((product / "datasheet.json").read_text())["emva1288"] == stored


def test_a_product_without_emva_figures_is_one_line_saying_how_to_get_them(capsys, healey,
                                                                          tmp_path):
    product = tmp_path / "p"
    code, _, err = run(capsys, "calibrate", healey, "-o", product)
    assert code == 0, err
    code, out, err = run(capsys, "datasheet", product, "-o", tmp_path / "ds")
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    assert lines[0].startswith(f"ccdcore datasheet: error: {product / PRODUCT_FILE}: ")
    assert "holds no EMVA 1288 figures" in lines[0] and "photon counts" in lines[0]
    assert "EMVA1288 descriptor" in lines[0]                            # how to get them
    assert not (tmp_path / "ds").exists()


def test_a_session_without_photon_counts_is_one_line_naming_it(capsys, healey, tmp_path):
    code, out, err = run(capsys, "datasheet", healey, "-o", tmp_path / "ds")
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    assert str(healey) in lines[0] and "no photon counts" in lines[0]
    assert not (tmp_path / "ds").exists()


# --------------------------------------------------------------------------------------------
# skipped plots, replacement as one set, failures
# --------------------------------------------------------------------------------------------
def _product_with(emva_set, folder: Path, edit) -> Path:
    assert main(["calibrate", str(emva_set), "-o", str(folder), "--json"]) == 0
    doc = json.loads((folder / PRODUCT_FILE).read_text())
    edit(doc["emva1288"])
    (folder / PRODUCT_FILE).write_text(json.dumps(doc))
    return folder


def test_plots_without_data_are_skipped_and_said_and_the_old_set_goes(capsys, emva_set, sheet,
                                                                     tmp_path):
    def no_spatial_one_dark_exposure(e):
        e["spatial_plots"] = None
        t = e["dark_points"][0]["exposure"]
        for d in e["dark_points"]:
            d["exposure"] = t

    product = _product_with(emva_set, tmp_path / "p", no_spatial_one_dark_exposure)
    capsys.readouterr()
    out = tmp_path / "ds"
    # an earlier, complete datasheet in the folder (a run of ours), and a file of the user's
    shutil.copytree(sheet[0], out)
    (out / "mine.txt").write_text("keep")
    code, stdout, err = run(capsys, "datasheet", product, "-o", out)
    assert code == 0, err
    kept = ["photon_transfer", "snr", "linearity", "linearity_deviation"]
    assert sorted(p.name for p in (out / "plots").iterdir()) == sorted(
        f"{n}.{f}" for n in kept for f in PLOT_FORMATS)            # no plot of the old set
    assert (out / "mine.txt").read_text() == "keep"
    skipped = [ln.split(":")[0].split()[-1] for ln in err.splitlines()
               if ln.strip().startswith("skipped plot ")]
    assert skipped == [n for n in PLOTS if n not in kept]             # each once, in order
    flat = " ".join(err.split())
    assert "skipped plot spectrogram_dsnu_horizontal: no spatial sets" in flat
    assert "skipped plot dark_signal: the dark points are at 1 known exposure time" in flat
    doc = json.loads((out / "datasheet.json").read_text())
    assert doc["plots"]["drawn"] == kept
    assert {s["plot"] for s in doc["plots"]["skipped"]} == set(skipped)
    flat = " ".join(stdout.split())
    assert "plots/ (4 plots, PNG and SVG each): photon_transfer, snr, linearity, " \
           "linearity_deviation" in flat


def test_a_failure_while_writing_leaves_the_earlier_set_untouched(capsys, emva_set, sheet,
                                                                  tmp_path, monkeypatch):
    out = tmp_path / "ds"
    shutil.copytree(sheet[0], out)                 # an earlier datasheet of ours
    before = tree(out)
    real, calls = datasheet_files._render, []

    def disk_full(plot, emva, folder):
        calls.append(plot.name)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        return real(plot, emva, folder)

    monkeypatch.setattr(datasheet_files, "_render", disk_full)
    code, stdout, err = run(capsys, "datasheet", emva_set, "-o", out)
    assert code == 2 and len(calls) == 3
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(out) in lines[0] and "No space left on device" in lines[0]
    assert tree(out) == before                                       # nothing new, nothing lost
    assert not [p for p in out.iterdir() if p.name.startswith(".ccdcore-tmp")]


def test_damaged_plot_data_in_a_product_are_one_line_naming_the_file(capsys, emva_set,
                                                                     tmp_path):
    def damage(e):
        e["points"][2]["u_y"] = "lots"

    product = _product_with(emva_set, tmp_path / "p", damage)
    capsys.readouterr()
    code, _, err = run(capsys, "datasheet", product, "-o", tmp_path / "ds")
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    assert str(product / PRODUCT_FILE) in lines[0] and "points.u_y" in lines[0]
    assert not (tmp_path / "ds").exists()


def test_the_output_must_not_be_an_input(capsys, emva_set):
    images = next(p for p in emva_set.parent.rglob("*.tif"))
    code, _, err = run(capsys, "datasheet", emva_set, "-o", images)
    assert code == 2 and str(images) in err and len(err.strip().splitlines()) == 1


def test_without_matplotlib_the_verb_says_what_to_install(emva_set, tmp_path):
    """matplotlib made unimportable, as on a machine with the library alone."""
    argv = ["datasheet", str(emva_set), "-o", str(tmp_path / "ds")]
    code = ("import sys\nsys.modules['matplotlib'] = None\n"
            "from ccdcore.cli.command import main\n"
            f"sys.exit(main({argv!r}))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in out.stderr
    assert "needs matplotlib" in lines[0] and "pip install 'ccdcore[datasheet]'" in lines[0]
    assert not (tmp_path / "ds").exists()


def test_csv_and_json_need_no_plotting_package(figures, tmp_path):
    """``write_datasheet(..., plots=False)`` writes the CSV and the JSON only; importing the
    module does not import matplotlib."""
    code = ("import sys, json\nsys.modules['matplotlib'] = None\n"
            "from ccdcore.emva.datasheet_files import write_datasheet\n"
            "from ccdcore.emva.results import EmvaSummary\n"
            f"e = EmvaSummary.from_dict(json.loads(open({str(tmp_path / 'e.json')!r}).read()))\n"
            f"print('\\n'.join(map(str, write_datasheet(e, {str(tmp_path / 'ds')!r}, "
            "plots=False))))\n")
    (tmp_path / "e.json").write_text(json.dumps(figures.to_dict()))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [str(tmp_path / "ds" / "datasheet.csv"),
                                  str(tmp_path / "ds" / "datasheet.json")]
    assert sorted(os.listdir(tmp_path / "ds")) == [RECORD, "datasheet.csv", "datasheet.json"]
    assert "plots" not in json.loads((tmp_path / "ds" / "datasheet.json").read_text())


# --------------------------------------------------------------------------------------------
# ptc --emva-range
# --------------------------------------------------------------------------------------------
def test_ptc_emva_range_leaves_out_the_levels_above_70_percent_of_saturation(capsys, emva_set):
    code, out, err = run(capsys, "ptc", emva_set, "--json")
    assert code == 0, err
    plain = json.loads(out)
    code, out, err = run(capsys, "ptc", emva_set, "--emva-range", "--json")
    assert code == 0, err
    emva = json.loads(out)
    assert plain["fit_fraction"] is None and emva["fit_fraction"] == EMVA_FIT_FRACTION == 0.7
    assert "70 %" in emva["fit_range"] and "70 %" not in plain["fit_range"]
    assert not [p for p in plain["points"] if p["exclusion"] == "range"]
    # the saturation signal: the mean of the level of largest variance among the levels with
    # usable data (not clipped); above 70 % of it a level the plain fit uses is left out
    data = [p for p in plain["points"] if p["exclusion"] not in ("clipped", "zero-variance")]
    peak = max(data, key=lambda p: p["var"])
    above = {p["level"] for p in plain["points"]
             if p["used"] and p["mu"] > EMVA_FIT_FRACTION * peak["mu"]}
    ranged = {p["level"] for p in emva["points"] if p["exclusion"] == "range"}
    assert ranged == above and peak["level"] in ranged
    # this series: levels 11 to 15 of 16 (16 is clipped); the spatial set (17, mid range) stays
    assert ranged == {11, 12, 13, 14, 15}
    by_level = {p["level"]: p for p in emva["points"]}
    assert by_level[16]["exclusion"] == "clipped" and by_level[17]["used"]
    assert all(by_level[lv]["mu"] <= 0.7 * peak["mu"] for lv in by_level if by_level[lv]["used"])
    # every other level is treated alike, and the fit changes
    assert {p["level"]: p["used"] for p in plain["points"] if p["level"] not in ranged} == \
        {p["level"]: p["used"] for p in emva["points"] if p["level"] not in ranged}
    assert emva["dof"] == plain["dof"] - len(ranged) and emva["A"] != plain["A"]


def test_ptc_prints_its_fit_range(capsys, emva_set):
    code, out, err = run(capsys, "ptc", emva_set, "--emva-range")
    assert code == 0, err
    flat = " ".join(out.split())
    assert "fit range: the levels up to 70 % of the saturation signal (the EMVA 1288 range)" \
        in flat
    assert " 15 " in out and "no (range)" in out
    code, out, err = run(capsys, "ptc", emva_set)
    assert code == 0, err
    flat = " ".join(out.split())
    assert "fit range: every level below saturation (the paper's range)" in flat
    assert "no (range)" not in out


def test_the_plots_do_not_depend_on_a_matplotlibrc(figures, tmp_path):
    """A user's matplotlibrc (here: another dpi, font size and line width) changes no byte of
    the plots: they are drawn with matplotlib's own defaults."""
    emva = dataclasses.replace(figures, spatial_plots=None, dark_points=())   # four plots: quick
    (tmp_path / "e.json").write_text(json.dumps(emva.to_dict()))
    datasheet_files.write_datasheet(emva, tmp_path / "here")
    (tmp_path / "matplotlibrc").write_text("savefig.dpi: 30\nfont.size: 22\n"
                                           "lines.linewidth: 7\n")
    code = ("import json, sys\nfrom ccdcore.emva.datasheet_files import write_datasheet\n"
            "from ccdcore.emva.results import EmvaSummary\n"
            "write_datasheet(EmvaSummary.from_dict(json.loads(open("
            f"{str(tmp_path / 'e.json')!r}).read())), {str(tmp_path / 'there')!r})\n")
    env = dict(os.environ, MATPLOTLIBRC=str(tmp_path / "matplotlibrc"))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, env=env)
    assert out.returncode == 0, out.stderr
    here, there = tree(tmp_path / "here" / "plots"), tree(tmp_path / "there" / "plots")
    assert len(here) == 8 and here == there
