"""Outputs never lose anything: no special file, no input of the run, no half-written set, no
damaged product, no temporary folder left behind ("Honest at the edges: nothing lost")."""
from __future__ import annotations

import inspect
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from ccdcore.cli.command import main
from ccdcore.errors import CcdError
from ccdcore.io.frames import (RECORD, TEMP_PREFIX, check_not_inputs, read_image, write_image,
                        write_outputs)
from ccdcore.product.make import CalibrationProduct, calibrate, load_product
from ccdcore.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
BRACKET = ROOT / "assets" / "tsin01"


def run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def leftovers(*folders: Path) -> list[Path]:
    return [p for f in folders if f.is_dir() for p in f.iterdir()
            if p.name.startswith(TEMP_PREFIX)]


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("h94") / "s"
    simulate("healey94", root, seed=2, size=(48, 32), n1=2, n2=1)
    return root


@pytest.fixture(scope="module")
def calib(sim, tmp_path_factory) -> Path:
    return calibrate(sim).save(tmp_path_factory.mktemp("calib") / "c")


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


# 1. special files --------------------------------------------------------------------------
def test_report_refuses_a_fifo_and_a_symlink_to_a_device(capsys, calib, tmp_path):
    fifo = tmp_path / "pipe.html"
    os.mkfifo(fifo)
    code, _, err = run(capsys, "report", calib, "-o", fifo)
    assert code == 2 and "FIFO" in one_error_line(err) and str(fifo) in err
    assert fifo.is_fifo()
    link = tmp_path / "null.html"
    link.symlink_to(os.devnull)
    code, _, err = run(capsys, "report", calib, "-o", link)
    assert code == 2 and "symlink to /dev/null" in one_error_line(err)
    assert link.is_symlink() and os.readlink(link) == os.devnull
    fifo_link = tmp_path / "to_pipe.html"
    fifo_link.symlink_to(fifo)
    code, _, err = run(capsys, "report", calib, "-o", fifo_link)
    assert code == 2 and "FIFO" in one_error_line(err) and fifo_link.is_symlink()


def test_apply_refuses_special_outputs(capsys, calib, sim, tmp_path):
    src = sim / "scene" / "max_intensity.tif"
    out = tmp_path / "out"
    out.mkdir()
    os.mkfifo(out / "max_intensity.tif")
    code, _, err = run(capsys, "apply", calib, src, "-o", out)
    assert code == 2 and "FIFO" in one_error_line(err)
    assert (out / "max_intensity.tif").is_fifo()
    link = tmp_path / "devout"
    link.symlink_to(os.devnull)                     # a folder is expected: a device is refused
    code, _, err = run(capsys, "apply", calib, src, "-o", link)
    assert code == 2 and "device" in one_error_line(err)
    (out / "max_intensity.tif").unlink()
    (out / "max_intensity.tif").symlink_to(os.devnull)
    code, _, err = run(capsys, "apply", calib, src, "-o", out)
    assert code == 2 and "symlink to /dev/null" in one_error_line(err)
    assert (out / "max_intensity.tif").is_symlink()


# 2. simulate into a user's folder ----------------------------------------------------------
def test_simulate_refuses_a_users_session_unless_forced(capsys, tmp_path):
    user = tmp_path / "mine"
    user.mkdir()
    (user / "session.toml").write_text("# my real capture\n")
    write_image(user / "frame.tif", np.full((8, 8), 7, np.uint8))
    code, _, err = run(capsys, "simulate", "tsin01", user, "--size", "16x16")
    assert code == 2 and "--force" in one_error_line(err) and str(user) in err
    assert (user / "session.toml").read_text() == "# my real capture\n"
    assert sorted(p.name for p in user.iterdir()) == ["frame.tif", "session.toml"]
    # an earlier simulation of ours is replaced without asking
    sim = tmp_path / "sim"
    assert run(capsys, "simulate", "tsin01", sim, "--size", "16x16")[0] == 0
    code, _, err = run(capsys, "simulate", "tsin01", sim, "--size", "16x16", "--seed", "3")
    assert code == 0, err
    assert json.loads((sim / "truth.json").read_text())["seed"] == 3
    # --force writes into the user's folder (files of the same names replaced, others kept)
    code, _, err = run(capsys, "simulate", "tsin01", user, "--size", "16x16", "--force")
    assert code == 0, err
    assert (user / "frame.tif").is_file() and (user / "truth.json").is_file()
    assert leftovers(user, sim, tmp_path) == []


# 3. never over an input of the run ---------------------------------------------------------
def test_report_refuses_to_overwrite_the_sessions_truth(capsys, sim, tmp_path):
    root = _copy(sim, tmp_path / "s")
    truth = root / "truth.json"
    before = truth.read_bytes()
    code, _, err = run(capsys, "report", root, "-o", truth)
    assert code == 2 and "overwrite an input" in one_error_line(err)
    assert truth.read_bytes() == before
    true_map = root / json.loads(before)["maps"]["K"]   # the true maps the report reads too
    code, _, err = run(capsys, "report", root, "-o", true_map)
    assert code == 2 and "overwrite an input" in one_error_line(err)


def test_apply_refuses_to_write_inside_the_product(capsys, calib, sim, tmp_path):
    product = _copy(calib, tmp_path / "c")
    k = (product / "maps" / "K.exr").read_bytes()
    src = tmp_path / "K.exr"                        # an image whose output would be maps/K.exr
    write_image(src, read_image(sim / "scene" / "max_intensity.tif").astype(np.float32))
    code, _, err = run(capsys, "apply", product, src, "-o", product / "maps")
    assert code == 2 and "input of this run" in one_error_line(err)
    assert (product / "maps" / "K.exr").read_bytes() == k
    code, _, err = run(capsys, "report", product, "-o", product / "report.html")
    assert code == 2 and "input of this run" in one_error_line(err)
    assert not (product / "report.html").exists()
    load_product(product)


def test_check_not_inputs_compares_resolved_paths(tmp_path):
    inputs = [tmp_path / "calib", tmp_path / "s" / "a.tif"]
    (tmp_path / "s").mkdir()
    (tmp_path / "alias").symlink_to(tmp_path / "s")
    for out, what in ((tmp_path / "alias" / "a.tif", "would overwrite"),
                      (tmp_path / "calib" / "maps" / "x.tif", "is inside"),
                      (tmp_path / "s" / ".." / "s", "holds")):
        with pytest.raises(CcdError, match=what):
            check_not_inputs([out], inputs)
    check_not_inputs([tmp_path / "s" / "b.tif", tmp_path / "calib2"], inputs)


# 4. multi-file outputs as one set ----------------------------------------------------------
def test_hdr_failure_midway_leaves_the_earlier_set(capsys, tmp_path, monkeypatch):
    import ccdcore.io.frames as io

    out = tmp_path / "h"
    assert run(capsys, "hdr", BRACKET, "-o", out)[0] == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    real = io.write_image

    def full_disk(path, *a, **k):                  # flags.png, the last file, fails
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(io, "write_image", full_disk)
    code, out_text, err = run(capsys, "hdr", BRACKET, "-o", out)
    line = one_error_line(err)
    assert code == 2 and str(out) in line and TEMP_PREFIX not in line
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before   # nothing mixed
    assert leftovers(out, tmp_path) == []
    monkeypatch.setattr(io, "write_image", real)


def test_full_disk_names_the_users_folder(capsys, tmp_path, monkeypatch):
    import ccdcore.io.frames as io

    monkeypatch.setattr(io, "_free_bytes", lambda folder: 0)
    out = tmp_path / "h"
    code, _, err = run(capsys, "hdr", BRACKET, "-o", out)
    line = one_error_line(err)
    assert code == 2 and "disk is full" in line
    assert str(out / "radiance.exr") in line and TEMP_PREFIX not in line
    assert not out.exists() and leftovers(tmp_path) == []


def test_calibrate_over_an_earlier_product_removes_its_other_maps(calib, tmp_path):
    folder = _copy(calib, tmp_path / "c")
    (folder / "notes.txt").write_text("mine")
    dark = load_product(folder).maps["dark"]
    CalibrationProduct(maps={"dark": dark}).save(folder)
    assert sorted(p.name for p in (folder / "maps").iterdir()) == ["dark.exr"]
    assert (folder / "notes.txt").read_text() == "mine"
    assert set(load_product(folder).maps) == {"dark"} and leftovers(folder, tmp_path) == []
    CalibrationProduct(maps={}).save(folder)     # curves only: no maps/ left
    assert sorted(p.name for p in folder.iterdir()) == [RECORD, "calibration.json", "notes.txt"]
    assert load_product(folder).maps == {}


# 5. no damaged product from calibrate ------------------------------------------------------
def _keep_darks(root: Path, n: int, transform=None) -> None:
    """Keep the first ``n`` dark frames of the manifest (``transform`` rewrites their data)."""
    manifest = root / "session.toml"
    blocks = manifest.read_text().split("[[frames]]")
    kept, darks = [blocks[0]], 0
    for b in blocks[1:]:
        if 'role = "dark"' in b:
            darks += 1
            if darks > n:
                continue
            if transform is not None:
                rel = b.split('path = "', 1)[1].split('"', 1)[0]
                path = root / rel
                write_image(path, transform(read_image(path)))
        kept.append(b)
    manifest.write_text("[[frames]]".join(kept))


def test_one_dark_frame_is_a_skipped_estimate_not_a_damaged_product(capsys, sim, tmp_path):
    root = _copy(sim, tmp_path / "s")
    _keep_darks(root, 1)
    code, _, err = run(capsys, "calibrate", root, "-o", tmp_path / "c")
    assert code == 0, err
    assert "skipped dark" in err and "dark_var" in err
    product = load_product(tmp_path / "c")
    assert product.estimates.dark is None and "dark_var" not in product.maps
    assert any(s.estimate == "dark" and "dark_var" in s.reason for s in product.skipped)
    assert run(capsys, "apply", tmp_path / "c", root / "scene" / "max_intensity.tif",
               "-o", tmp_path / "o")[0] == 2     # no dark map: one clear line, not "damaged"


def test_an_infinite_dark_pixel_skips_the_maps_it_would_damage(capsys, sim, tmp_path):
    root = _copy(sim, tmp_path / "s")

    def one_inf(a):
        b = a.astype(np.float32)
        b[0, 0] = np.inf
        return b

    _keep_darks(root, 10 ** 6, one_inf)
    code, _, err = run(capsys, "calibrate", root, "-o", tmp_path / "c")
    assert code == 0, err
    product = load_product(tmp_path / "c")            # what was written loads
    assert "K" not in product.maps and "dark" not in product.maps
    assert {s.estimate for s in product.skipped} >= {"dark", "fixed_pattern"}


# 6. damaged estimates: one line, not a traceback -------------------------------------------
@pytest.fixture(scope="module")
def others(tmp_path_factory) -> dict:
    """A response and a flat field as calibration.json stores them (small simulated sessions),
    to damage one field of a whole estimate."""
    from ccdcore.flatfield.fit import flat_field_from_session
    from ccdcore.response.brackets import load_bracket
    from ccdcore.response.methods import response_of
    from ccdcore.session import open_session

    tmp = tmp_path_factory.mktemp("others")
    simulate("tsin01", tmp / "t", seed=5, size=(32, 24))
    simulate("delasarte07", tmp / "d", seed=5, size=(48, 32))
    response = response_of(load_bracket(open_session(tmp / "t")), "debevec")
    flat = flat_field_from_session(open_session(tmp / "d"), base="auto")
    return {"response": response.summary().to_dict(), "flat_field": flat.summary().to_dict()}


@pytest.mark.parametrize("damage, field", [
    (lambda d, o: d["estimates"].update(response={**o["response"], "g": "abc"}),
     "estimates.response.g"),
    (lambda d, o: d["estimates"].update(flat_field={**o["flat_field"], "channels": 3}),
     "estimates.flat_field.channels"),
    (lambda d, o: d.update(provenance="abc"), "provenance"),
    (lambda d, o: d["provenance"].update(steps="abc"), "provenance.steps"),
    (lambda d, o: d["estimates"]["noise"].update(A="big"), "estimates.noise.A"),
    (lambda d, o: d["estimates"]["dark"].update(notes=[3]), "estimates.dark.notes"),
])
def test_damaged_estimate_fields_are_one_line(capsys, calib, sim, others, tmp_path, damage,
                                              field):
    folder = _copy(calib, tmp_path / "c")
    manifest = folder / "calibration.json"
    doc = json.loads(manifest.read_text())
    damage(doc, others)
    manifest.write_text(json.dumps(doc))
    code, _, err = run(capsys, "report", folder, "-o", tmp_path / "r.html")
    line = one_error_line(err)
    assert code == 2 and str(manifest) in line and f"'{field}'" in line, line
    code, _, err = run(capsys, "apply", folder, sim / "scene" / "max_intensity.tif",
                       "-o", tmp_path / "o")
    assert code == 2 and f"'{field}'" in one_error_line(err)


# 7. SIGTERM: no temporary folder stays -----------------------------------------------------
def test_sigterm_while_writing_outputs_leaves_nothing(tmp_path):
    out = tmp_path / "out"
    write_outputs(out, {"a.txt": lambda p: Path(p).write_text("earlier")})
    script = textwrap.dedent(f"""
        import time
        from pathlib import Path
        from ccdcore.io.frames import write_outputs
        def slow(path):
            Path(path).write_text("new, half")
            print("writing", flush=True)
            time.sleep(30)
        write_outputs({str(out)!r}, {{"a.txt": slow, "b.txt": slow}})
    """)
    for sig in (signal.SIGTERM, signal.SIGKILL):
        proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE,
                                cwd=ROOT, text=True)
        assert proc.stdout.readline().strip() == "writing"
        proc.send_signal(sig)
        proc.wait(timeout=60)
        assert (out / "a.txt").read_text() == "earlier" and not (out / "b.txt").exists()
        if sig == signal.SIGTERM:
            assert proc.returncode == 128 + signal.SIGTERM and leftovers(out, tmp_path) == []
        else:
            assert len(leftovers(out)) == 1
    write_outputs(out, {"a.txt": lambda p: Path(p).write_text("new")})   # cleans the leftover
    assert sorted(p.name for p in out.iterdir()) == [RECORD, "a.txt"]
    assert (out / "a.txt").read_text() == "new"


def test_sigterm_during_report_leaves_no_temporary_file(calib, tmp_path):
    out = tmp_path / "r" / "report.html"
    write_outputs(out.parent, {out.name: lambda p: Path(p).write_text("an earlier report")})
    script = textwrap.dedent(f"""
        import time
        import ccdcore.io.frames as io
        from ccdcore.cli.command import main
        def slow(path, text):
            open(path, "w").write(text[:100])
            print("writing", flush=True)
            time.sleep(30)
        io.atomic_write_text = slow
        main(["report", {str(calib)!r}, "-o", {str(out)!r}])
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, cwd=ROOT, text=True)
    assert proc.stdout.readline().strip() == "writing"
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM
    assert sorted(os.listdir(out.parent)) == [RECORD, "report.html"]
    assert out.read_text() == "an earlier report"


# 8. SIGKILL at any moment of the swap: the earlier set or the new one, never a mix --------------
_KILL_AT = textwrap.dedent("""
    import os, signal, sys
    from pathlib import Path
    import ccdcore.io.outputs as outs
    real, calls = os.replace, [0]
    def replace(a, b):
        calls[0] += 1
        if calls[0] == int(sys.argv[2]):
            os.kill(os.getpid(), signal.SIGKILL)
        real(a, b)
    outs.os.replace = replace
    outs.write_outputs(sys.argv[1], {n: writer("new " + n) for n in
                                     ("a.txt", "b.txt", "plots", "c.txt")}, last="c.txt")
    print("done")
""")


def writer(text: str):
    """A writer of one entry of a set: a file holding ``text``, or (no suffix) a folder with a
    file holding it (the same code runs in the killed process: :data:`_KILL_AT`)."""
    def write(path):
        path = Path(path)
        if path.suffix:
            path.write_text(text)
        else:
            path.mkdir()
            (path / "p.png").write_text(text)
    return write


def _state(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): p.read_text() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != RECORD}


def test_a_run_killed_at_any_moment_of_the_swap_leaves_one_whole_set(tmp_path):
    """A run killed (SIGKILL) before, during or after each rename of the swap: once the next
    write has recovered, the folder holds exactly the earlier set or exactly the new one (and
    the user's file beside them), and no folder of ours is left."""
    from ccdcore.io.frames import write_outputs
    from ccdcore.io.outputs import recover_swaps, remove_stale_temporaries

    def earlier(folder: Path) -> None:
        write_outputs(folder, {n: writer("old " + n) for n in ("a.txt", "plots", "c.txt")},
                      last="c.txt")
        (folder / "mine.txt").write_text("the user's")

    outcomes = set()
    for k in range(1, 40):
        folder = tmp_path / f"k{k}"
        earlier(folder)
        old = _state(folder)
        script = _KILL_AT.replace(
            "outs.os.replace = replace", "outs.os.replace = replace\n"
            + textwrap.dedent(inspect.getsource(writer)))
        proc = subprocess.run([sys.executable, "-c", script, str(folder), str(k)], cwd=ROOT,
                              capture_output=True, text=True, timeout=120)
        finished = "done" in proc.stdout
        remove_stale_temporaries(folder)          # what the next write does first
        now = _state(folder)
        new = {"a.txt": "new a.txt", "b.txt": "new b.txt", "c.txt": "new c.txt",
               "mine.txt": "the user's", "plots/p.png": "new plots"}
        assert now in (old, new), (k, now)
        assert leftovers(folder) == [] and not list(folder.glob(".ccdcore-swap-*"))
        outcomes.add("new" if now == new else "old")
        if finished:
            break
    assert finished and outcomes == {"old", "new"}
    recover_swaps(folder)                         # nothing left to do: no change
    assert _state(folder) == new


def test_only_what_ccdcore_wrote_is_replaced_or_removed(capsys, tmp_path):
    """A folder of the user's named like our temporary folders is never removed; a file or a
    file inside a folder entry that ccdcore did not write is refused, naming it, and nothing
    is lost; the parts of an earlier set of ours are replaced as before."""
    from ccdcore.io.frames import output_set, write_outputs

    out = tmp_path / "out"
    out.mkdir()
    mine = out / f"{TEMP_PREFIX}mine-1"
    mine.mkdir()
    (mine / "data.txt").write_text("keep")
    (out / "report.html").write_text("the user's own page")
    with pytest.raises(CcdError, match="report.html.*not written by ccdcore"):
        write_outputs(out, {"report.html": lambda p: Path(p).write_text("ours")})
    assert (out / "report.html").read_text() == "the user's own page"
    write_outputs(out, {"plots": lambda p: (Path(p).mkdir(), (Path(p) / "a.png").write_text(
        "1"))})
    (out / "plots" / "user.png").write_text("the user's plot")
    with pytest.raises(CcdError, match="user.png, which ccdcore did not write"):
        with output_set(out, replaces=("plots",)) as tmp:
            (tmp / "x.txt").write_text("x")
    assert (out / "plots" / "user.png").read_text() == "the user's plot"
    (out / "plots" / "user.png").unlink()
    with output_set(out, replaces=("plots", "report.html")) as tmp:   # ours goes, theirs stays
        (tmp / "x.txt").write_text("x")
    assert not (out / "plots").exists() and (out / "report.html").exists()
    assert (mine / "data.txt").read_text() == "keep"


def test_report_over_a_users_file_is_refused_and_over_its_own_replaced(capsys, calib, tmp_path):
    """One rule for every verb (docs/cli.md): an output replaces what ccdcore wrote there and
    refuses anything else, in one line naming it (exit 2)."""
    page = tmp_path / "page.html"
    page.write_text("the user's own page")
    code, _, err = run(capsys, "report", calib, "-o", page)
    assert code == 2 and str(page) in one_error_line(err) and "not written by ccdcore" in err
    assert page.read_text() == "the user's own page"
    page.unlink()
    assert run(capsys, "report", calib, "-o", page)[0] == 0
    assert run(capsys, "report", calib, "-o", page)[0] == 0     # its own: replaced
