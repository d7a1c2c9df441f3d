"""The words a camera engineer reads: every number of the CLI's summaries with its unit and a
plain name beside the symbol, advice where a verdict is bad, notes where a choice is slow."""
from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

import ccdcore.cli.common as cli_common
import ccdcore.cli.response as cli_response
from ccdcore.cli.command import main
from ccdcore.io.frames import write_image

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT / "assets"


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def h94_product(tmp_path_factory):
    folder = tmp_path_factory.mktemp("p") / "h94"
    assert main(["calibrate", str(ASSETS / "healey94"), "-o", str(folder), "--json"]) == 0
    return folder


def test_calibrate_names_the_correction_and_flat_field_figures(capsys, tmp_path):
    code, out, err = run(capsys, "calibrate", ASSETS / "healey94", "-o", tmp_path / "h")
    assert code == 0, err
    doc = json.loads((tmp_path / "h" / "calibration.json").read_text())
    c = doc["estimates"]["correction_check"]
    assert re.search(rf"largest change +{c['max_change_q']:.5g} q", out)
    assert re.search(r"mean of K̂ +[0-9.]+ +each pixel's relative gain, no unit", out)
    # the plan's warning: a sentence first, the formula after
    flat = " ".join(out.split())
    assert re.search(r"the plan needs n1 = \d+ card/lamp positions, so that the error of the "
                     r"fixed-pattern map K̂", flat)
    assert "capture 93 more (formula: n̂_1" in flat
    code, out, err = run(capsys, "calibrate", ASSETS / "delasarte07", "-o", tmp_path / "d")
    assert code == 0, err
    ff = json.loads((tmp_path / "d" / "calibration.json").read_text())["estimates"]["flat_field"]
    level, t = ff["base"]
    flat = " ".join(out.split())
    assert f"level {level:g}, exposure {t:g} s ({ff['n_base']} frames)" in flat
    assert "corrected = O + G·raw" in flat and "[3, 0.04]" not in flat


def test_calibrate_ctrl_c_says_nothing_was_written(capsys, tmp_path, monkeypatch):
    import ccdcore.product.make as product

    def interrupted(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(product, "calibrate", interrupted)
    code, out, err = run(capsys, "calibrate", ASSETS / "healey94", "-o", tmp_path / "c")
    assert code == 130 and out == ""
    assert err.strip() == "ccdcore calibrate: interrupted: nothing was written"
    assert not (tmp_path / "c" / "calibration.json").exists()


def test_calibrate_ctrl_c_during_save_keeps_the_earlier_product(capsys, h94_product,
                                                                monkeypatch):
    import ccdcore.product.make as product

    before = (h94_product / "calibration.json").read_text()

    def interrupted(self, *a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(product.CalibrationProduct, "save", interrupted)
    code, out, err = run(capsys, "calibrate", ASSETS / "healey94", "-o", h94_product)
    assert code == 130
    assert f"nothing was written; the earlier product in {h94_product} is kept as it was" in err
    assert (h94_product / "calibration.json").read_text() == before


def test_response_names_channel_scale_and_noise_terms(capsys):
    code, out, err = run(capsys, "response", ASSETS / "tsin01")
    assert code == 0, err
    flat = " ".join(out.split())
    assert "g, L (mono)" in out
    assert ("g(z) is the inverse response: the relative exposure (light × time) that gives "
            "the code z") in flat
    assert "g(230) = 230/255 = 0.902" in flat
    assert re.search(r"shot noise σ_s = [\d.]+ ± [\d.]+ √g", flat)
    assert re.search(r"dark/input noise σ_c1 = [\d.]+ ± [\d.]+ g", flat)
    assert re.search(r"output/read noise σ_c2 = [\d.]+ ± [\d.]+ DN", flat)


def test_white_balance_prints_gains_and_offsets_with_errors(capsys):
    from types import SimpleNamespace

    from ccdcore.common import format_pm

    t = np.array([0.01, 0.02, 0.04])
    r = SimpleNamespace(g=np.linspace(0, 1.13, 256), g_err=np.full(256, 0.001), sigma_s=0.01,
                        sigma_s_err=0.001, sigma_c1=0.02, sigma_c1_err=0.002, sigma_c2=1.5,
                        sigma_c2_err=0.1, iterations=4, converged=True, white_balance=True,
                        a=t * np.array([0.95, 1.0, 1.05]), a_err=t * 0.01,
                        b=np.array([0.003, -0.001, -0.002]), b_err=np.array([1e-3, 2e-3, 3e-3]),
                        t=t, notes=())
    res = SimpleNamespace(levels=256, method="tsin", files=["a", "b", "c"], t=t,
                          channels=["R"], responses=[r], agreement=None, warnings=lambda: [],
                          requested="tsin", selection="", exposures=None, verdict=None)
    cli_response.print_response(res)
    out = capsys.readouterr().out
    assert "offset b_k (units of g" in " ".join(out.split())
    for a, a_err, b, b_err, tk in zip(r.a, r.a_err, r.b, r.b_err, r.t):
        assert re.search(rf"{tk:.4g}\s+{re.escape(format_pm(a / tk, a_err / tk))}\s+"
                         rf"{re.escape(format_pm(float(b), float(b_err)))}", out)
    assert re.search(r"0\.02\s+1\.000 ± 0\.010\s+-0\.0010 ± 0\.0020", out)


def test_change_labels_the_colour_transform(capsys, tmp_path, monkeypatch):
    import ccdcore.change.session as change

    got = []
    real = change.session_change
    monkeypatch.setattr(change, "session_change",
                        lambda *a, **k: got.append(real(*a, **k)) or got[-1])
    code, out, err = run(capsys, "change", ASSETS / "change", "-o", tmp_path / "c")
    assert code == 0, err
    flat = " ".join(out.split())
    assert "E_target = E_reference · M (row vectors): row k = reference channel k, column j = " \
           "target channel j" in flat
    assert re.search(r"M\s+target R\s+target G\s+target B", out)
    m = got[0][0].clusters[0].M
    assert re.search(rf"ref G\s+{m[1, 0]:.4f} ± [\d.]+\s+{m[1, 1]:.4f} ±", out)


def test_ptc_says_robust_mode_ran(capsys):
    code, out, err = run(capsys, "ptc", ASSETS / "healey94", "--robust")
    assert code == 0, err
    assert "robust mode  on: a level more than 3 σ off the line is dropped" in out
    assert "no level dropped" in out
    code, out, err = run(capsys, "ptc", ASSETS / "healey94")
    assert "robust mode" not in out and "advice" not in out     # acceptable: no advice


def test_ptc_poor_fit_gets_advice(capsys, monkeypatch):
    """A line its points stray from (a level 30 % off, resolved by its errors): the verdict in
    the Walkthrough's words and advice naming flags that exist."""
    import ccdcore.noise as noise

    real = noise.photon_transfer

    def off(*a, **k):
        res = real(*a, **k)
        used = [p for p in res.points if p.used]
        bad = used[len(used) // 2]
        points = tuple(dataclasses.replace(p, var=p.var * 1.3) if p is bad else p
                       for p in res.points)
        return dataclasses.replace(res, points=points, chi2=1e4, Q=1e-30)
    monkeypatch.setattr(noise, "photon_transfer", off)
    code, out, err = run(capsys, "ptc", ASSETS / "healey94")
    assert code == 0, err
    flat = " ".join(out.split())
    assert "verdict: Failed: " in flat and "Q = 1e-30" in flat
    assert "advice: failed: " in flat
    assert "leave out levels near saturation (--exclude LEVEL; the brightest used level has a " \
           "mean of 229.5 DN above b0)" in flat
    assert "--roi" in flat and "or try --robust" in flat
    code, out, err = run(capsys, "ptc", ASSETS / "healey94", "--robust")
    assert "advice: failed" in " ".join(out.split()) and "try --robust" not in out
    code, out, err = run(capsys, "ptc", ASSETS / "healey94", "--json")
    assert json.loads(out)["gate"]["label"] == "Failed"


def test_workers_note_on_a_small_session(capsys, monkeypatch):
    monkeypatch.setattr(cli_common, "cpu_cores", lambda: 2)
    cli_common.workers_note(2, 16, 786_432)
    err = " ".join(capsys.readouterr().err.split())
    assert err == ("note: --workers 2: this machine has 2 CPU cores and the session is small "
                   "(16 frames, 0.786 megapixels in all); starting a local cluster of 2 worker "
                   "processes takes seconds, so the streamed default (no --workers) is likely "
                   "faster here")
    monkeypatch.setattr(cli_common, "cpu_cores", lambda: 32)
    cli_common.workers_note(8, 4000, 4000 * 4_000_000)          # a big session on a big machine
    cli_common.workers_note(None, 16, 10)                       # streamed: nothing to say
    assert capsys.readouterr().err == ""


def test_ptc_workers_note_goes_to_stderr(capsys, monkeypatch):
    monkeypatch.setattr(cli_common, "cpu_cores", lambda: 2)
    code, out, err = run(capsys, "ptc", ASSETS / "healey94", "--workers", "1", "--json")
    assert code == 0
    json.loads(out)                                       # stdout stays one JSON object
    assert "--workers 1: this machine has 2 CPU cores and the session is small (16 frames" in \
        " ".join(err.split())


def test_hdr_workers_note_counts_the_bracket(capsys, monkeypatch, tmp_path):
    """hdr says it too, with the bracket's frames and pixels from their headers."""
    monkeypatch.setattr(cli_common, "cpu_cores", lambda: 2)
    code, out, err = run(capsys, "hdr", ASSETS / "tsin01", "-o", tmp_path / "h", "--workers", "1")
    assert code == 0, err
    from ccdcore.response.brackets import bracket_records
    from ccdcore.session import open_session
    s = open_session(ASSETS / "tsin01")
    recs = bracket_records(s)
    mp = sum(s.header(r).width * s.header(r).height for r in recs) / 1e6
    assert (f"the session is small ({len(recs)} frames, {mp:.3g} megapixels in all)"
            in " ".join(err.split()))


def test_apply_says_what_was_applied(capsys, h94_product, tmp_path):
    src = ASSETS / "healey94" / "ptc" / "L01_a.tif"
    code, out, err = run(capsys, "apply", h94_product, src, "-o", tmp_path / "o")
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0] == str(tmp_path / "o" / "L01_a.tif")          # the paths first
    flat = " ".join(" ".join(lines[1:]).split())
    assert flat == ("applied to 1 image (listed above, float32): dark reference subtracted and "
                    "the fixed pattern divided out with the maps dark, K: corrected = "
                    f"(raw − D̂_D)/K̂ (eq. 51); product {h94_product}")


def test_session_draft_advice_points_at_the_draft_it_wrote(capsys, tmp_path):
    """``session --draft`` told the user to run ``session --draft``: once the draft is written,
    the plain folder's advice points at it; without --draft it names the command."""
    rng = np.random.default_rng(4)
    for i in range(3):
        write_image(tmp_path / f"IMG_{i}.png", rng.integers(0, 255, (8, 8, 3)).astype(np.uint8))
    code, out, err = run(capsys, "session", tmp_path)
    flat = " ".join(out.split())
    assert "write a manifest draft with `ccdcore session FOLDER --draft`" in flat
    code, out, err = run(capsys, "session", tmp_path, "--draft")
    flat = " ".join(out.split())
    assert code == 0 and "--draft" not in flat.split("manifest draft written to")[0]
    assert "check the manifest draft written below and save it as session.toml" in flat
    assert (tmp_path / "session.toml.draft").is_file()


def test_a_photo_card_gets_one_line_for_what_it_never_meant_to_have(capsys, tmp_path):
    """A bracket alone: the estimates whose frames it holds none of are one line on stderr
    (their needs in --json), not eight blocks about darks and EMVA sets."""
    from ccdcore.simulate import simulate

    root = tmp_path / "b"
    simulate("tsin01", root, seed=1, size=(48, 32))
    code, out, err = run(capsys, "calibrate", root, "-o", tmp_path / "c")
    assert code == 0, err
    flat = " ".join(err.split())
    assert "not made: noise, emva1288, dark, fixed_pattern, plan, correction_check, scene, " \
           "flat_field: the session holds none of the frames they need" in flat
    assert "skipped dark" not in flat and "capture an EMVA1288 descriptor" not in flat
    code, out, err = run(capsys, "calibrate", root, "-o", tmp_path / "c2", "--json")
    skipped = {s["estimate"]: s for s in json.loads(out)["skipped"]}
    assert "lens-capped frames" in skipped["dark"]["reason"]


def test_calibrate_rows_keep_their_columns(capsys, tmp_path):
    """A value wider than its column (the photon-transfer verdict's line) takes the row's first
    line to itself: no line of the summary runs past the width, and every meaning starts in
    the meaning column."""
    from ccdcore.cli.common import WIDTH

    code, out, err = run(capsys, "calibrate", ASSETS / "healey94", "-o", tmp_path / "h")
    assert code == 0, err
    lines = out.splitlines()
    assert max(len(line) for line in lines) <= WIDTH
    verdict = next(i for i, line in enumerate(lines) if line.strip().startswith("verdict"))
    assert "Passed: the points agree with the line within their errors" in lines[verdict]
    column = next(line for line in lines if "chance of so large" in line).index("chance of so")
    assert lines[verdict + 1].index("the photon-transfer gate") == column


def test_a_noise_term_the_bracket_does_not_determine_is_said_so(capsys, monkeypatch):
    """σ_c2 = 0 ± 240000 DN printed as a figure: an error beyond its unit's whole range (the
    codes for σ_c2) is said to leave the term undetermined."""
    import ccdcore.response.bracket_fit as methods

    real = methods.session_response

    def vague(*a, **k):
        res = real(*a, **k)
        first = dataclasses.replace(res.responses[0], sigma_c2=0.0, sigma_c2_err=240000.0)
        return dataclasses.replace(res, responses=(first,) + tuple(res.responses[1:]))
    monkeypatch.setattr(methods, "session_response", vague)
    code, out, err = run(capsys, "response", ASSETS / "tsin01", "--method", "debevec")
    assert code == 0, err
    flat = " ".join(out.split())
    assert "output/read noise σ_c2 not determined by this bracket (0 ± 240000 DN)" in flat
    assert flat.count("output/read noise σ_c2 = ") == len(dataclasses.replace(
        real(ASSETS / "tsin01", "debevec")).channels) - 1
