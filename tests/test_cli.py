"""The command line: exit codes, one-line messages naming the file, JSON output."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ccdcore.cli.command import main
from ccdcore.simulate import load_truth
from ccdcore.io.frames import write_image

ROOT = Path(__file__).resolve().parents[1]


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_version(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert "ccdcore" in capsys.readouterr().out


def test_unknown_verb_and_bad_arguments_exit_2(capsys):
    for argv in (["frobnicate"], ["simulate", "nope", "x"], ["simulate", "healey94", "x", "--size", "12by3"],
                 ["ptc", "s", "--roi", "1,2,3"]):
        with pytest.raises(SystemExit) as info:
            main(argv)
        assert info.value.code == 2
        err = capsys.readouterr().err
        assert "error:" in err and "Traceback" not in err


def test_simulate_writes_session_and_truth(capsys, tmp_path):
    code, out, err = run(capsys, "simulate", "healey94", str(tmp_path / "h"), "--seed", "3",
                         "--size", "40x32", "--json")
    assert code == 0, err
    report = json.loads(out)
    truth = load_truth(tmp_path / "h")
    assert report["truth"] == truth.values
    for key in ("A", "sigma_c2", "read_noise_e", "bits"):
        assert key in truth
    assert (tmp_path / "h" / "session.toml").exists()


def test_ptc_json_has_the_contract_keys_and_recovers_truth(capsys):
    demo = ROOT / "assets" / "healey94"
    code, out, err = run(capsys, "ptc", str(demo), "--json")
    assert code == 0, err
    res = json.loads(out)
    for key in ("A", "sigma_c2", "cov", "chi2", "dof", "Q", "points", "conversion_gain_e_per_dn",
                "read_noise_e"):
        assert key in res
    assert {"level", "mu", "var", "var_err", "used"} <= set(res["points"][0])
    truth = load_truth(demo)
    a_err = res["cov"][0][0] ** 0.5
    assert abs(res["A"] - truth["A"]) < 3 * a_err  # three standard errors of the fit


def test_ptc_human_summary_and_bad_roi(capsys):
    demo = str(ROOT / "assets" / "healey94")
    code, out, err = run(capsys, "ptc", demo, "--roi", "10,10,50,40", "--exclude", "8")
    assert code == 0, err
    assert "excluded by user" in out and "Q =" in out
    code, out, err = run(capsys, "ptc", demo, "--roi", "200,100,500,500")
    assert code == 2 and "roi" in err.lower() and len(err.strip().splitlines()) == 1


def test_snup_json_contract_and_bad_file(capsys, tmp_path):
    flat = ROOT / "assets" / "delasarte07" / "nzdi" / "flat_L3_E04_0.tif"
    code, out, err = run(capsys, "snup", str(flat), "--roi", "8,8,40,30", "--json")
    assert code == 0, err
    res = json.loads(out)
    [img] = res["images"]
    assert img["path"] == str(flat)
    assert [c["name"] for c in img["channels"]] == ["R", "G", "B"]
    assert all({"name", "mean", "snup", "snup_err"} <= set(c) for c in img["channels"])
    (tmp_path / "bad.tif").write_bytes(b"nope")
    code, out, err = run(capsys, "snup", str(tmp_path / "bad.tif"))
    assert code == 2 and "bad.tif" in err and len(err.strip().splitlines()) == 1


def test_session_verb_on_demo_and_json(capsys):
    code, out, err = run(capsys, "session", str(ROOT / "assets" / "healey94"), "--json")
    assert code == 0, err
    info = json.loads(out)
    assert info["camera"]["bits"] == 8
    assert {f["role"] for f in info["frames"]} >= {"dark", "ptc", "fixed_pattern"}


def test_session_verb_reports_problems_with_exit_2(capsys, tmp_path):
    write_image(tmp_path / "a.tif", np.zeros((8, 8), np.uint8))
    (tmp_path / "session.toml").write_text(
        'schema = 1\n[camera]\nbits = 8\n[[frames]]\npath = "a.tif"\nrole = "drak"\n'
        '[[frames]]\npath = "missing.tif"\nrole = "dark"\n')
    code, out, err = run(capsys, "session", str(tmp_path))
    assert code == 2
    assert "drak" in out and "missing.tif" in out          # every problem in the summary
    assert len(err.strip().splitlines()) == 1 and "more problem" in err


def test_session_verb_on_missing_path(capsys, tmp_path):
    code, out, err = run(capsys, "session", str(tmp_path / "nowhere"))
    assert code == 2
    assert "nowhere" in err and "Traceback" not in err


def test_console_script_bad_input_has_no_traceback(tmp_path):
    broken = tmp_path / "s"
    broken.mkdir()
    (broken / "session.toml").write_text("schema = 1\n[camera\n")
    proc = subprocess.run([sys.executable, "-m", "ccdcore.cli", "session", str(broken)],
                          capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 2
    assert "session.toml" in proc.stderr and "Traceback" not in proc.stderr


def test_session_text_states_sizes_width_first(capsys):
    code, out, err = run(capsys, "session", str(ROOT / "assets" / "healey94"))
    assert code == 0, err
    assert "size 256x192" in out and "shape" not in out   # the demo is 256 px wide, 192 tall


def test_closed_pipe_stops_quietly():
    """``ccdcore session ... | head -1``: the reader goes away; no traceback, no error line."""
    proc = subprocess.Popen([sys.executable, "-m", "ccdcore.cli", "session",
                             str(ROOT / "assets" / "healey94")], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()                                    # nothing will ever be read
    err = proc.stderr.read().decode()
    assert proc.wait() == 141, err
    assert err == ""
