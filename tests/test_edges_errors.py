"""Hostile and odd input at the edges: one clear line on stderr and exit code 2, never a traceback.

Each test builds a tiny session in ``tmp_path`` (as tests/test_session.py and tests/test_cli.py
do) and runs the command line in-process: deeply nested manifests and product files, strange
frame paths (NUL, symbolic-link loops, FIFOs), decompression bombs, empty EMVA1288 descriptors,
values beyond the camera's bit depth, absurd exposure times, constant brackets, and options out
of range (blooming radius, frame size, seed, port).
"""
from __future__ import annotations

import os
import socket
from pathlib import Path

import numpy as np
import pytest

from ccdcore.cli.command import main
from ccdcore.errors import CcdError
from ccdcore.io.frames import read_image, write_image
from ccdcore.product.make import load_product
from ccdcore.response.brackets import MAX_BLOOM_RADIUS, bloom_mask, check_times
from ccdcore.session import open_session
from imagefiles import bomb_tiff

DEEP = 100_000  # far beyond Python's recursion limit (1000)


def run(capsys, *argv: str) -> tuple[int, str, str]:
    """Run the command line; argparse's exit is an exit code too."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def one_line(err: str) -> str:
    """The single error line of stderr (and nothing like a traceback)."""
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def manifest(root: Path, body: str, camera: str = "bits = 8") -> Path:
    root.mkdir(parents=True, exist_ok=True)
    (root / "session.toml").write_text(f"schema = 1\n[camera]\n{camera}\n\n{body}\n",
                                       encoding="utf-8")
    return root


def frames_body(role: str, names: list[str], exposures: list[str] | None = None) -> str:
    out = []
    for i, name in enumerate(names):
        out.append(f'[[frames]]\npath = "{name}"\nrole = "{role}"\n'
                   + (f"exposure = {exposures[i]}\n" if exposures else ""))
    return "\n".join(out)


def bracket(root: Path, exposures: list[str], role: str = "bracket", prefix: str = "b",
            constant: bool = False) -> list[str]:
    """8-bit frames of one static scene, brighter with each exposure (or all code 13)."""
    base = np.random.default_rng(1).uniform(10, 60, (24, 32))
    names = []
    for k in range(len(exposures)):
        codes = np.full((24, 32), 13) if constant else np.clip(base * (k + 1), 1, 250)
        names.append(f"{prefix}{k}.tif")
        write_image(root / names[-1], codes.astype(np.uint8))
    return names


# --------------------------------------------------------------------------------------------
# 1. deep nesting
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("value", ["[" * DEEP + "]" * DEEP, "{b = " * DEEP + "1" + "}" * DEEP])
def test_deeply_nested_manifest_is_one_line(capsys, tmp_path, value):
    root = manifest(tmp_path / "s", "a = " + value)
    with pytest.raises(CcdError, match="nested too deeply"):
        open_session(root)
    code, out, err = run(capsys, "session", root)
    assert code == 2
    line = one_line(err)
    assert "session.toml" in line and "nested too deeply" in line


def test_deeply_nested_product_json_is_one_line(capsys, tmp_path):
    product = tmp_path / "prod"
    product.mkdir()
    (product / "calibration.json").write_text("[" * DEEP + "]" * DEEP)
    image = write_image(tmp_path / "img.tif", np.zeros((8, 8), np.uint16))
    code, out, err = run(capsys, "apply", product, image, "-o", tmp_path / "out")
    assert code == 2
    line = one_line(err)
    assert "nested too deeply" in line and "calibration.json" in line
    with pytest.raises(CcdError, match="nested too deeply"):
        load_product(product)


# --------------------------------------------------------------------------------------------
# 2. frame paths, bombs, empty descriptors, bit depth
# --------------------------------------------------------------------------------------------
def test_nul_character_in_a_frame_path(capsys, tmp_path):
    root = manifest(tmp_path / "s", '[[frames]]\npath = "a\\u0000b.tif"\nrole = "dark"\n')
    session = open_session(root)
    assert [p.code for p in session.errors] == ["bad-value"]
    code, out, err = run(capsys, "session", root)
    assert code == 2
    line = one_line(err)
    assert "NUL" in line and "\0" not in line + out


def test_symlink_loop_as_a_frame(capsys, tmp_path):
    root = manifest(tmp_path / "s", frames_body("dark", ["a.tif"]))
    os.symlink(root / "a.tif", root / "b.tif")
    os.symlink(root / "b.tif", root / "a.tif")
    code, out, err = run(capsys, "session", root)
    assert code == 2
    line = one_line(err)
    assert "a.tif" in line and "symbolic link loop" in line


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_fifo_is_not_called_a_folder(capsys, tmp_path):
    root = manifest(tmp_path / "s", frames_body("dark", ["a.tif"]))
    os.mkfifo(root / "a.tif")
    code, out, err = run(capsys, "session", root)
    assert code == 2
    line = one_line(err)
    assert "FIFO/special file" in line and "folder" not in line
    fifo = tmp_path / "fifo"   # given as the session itself: refused, never opened (would block)
    os.mkfifo(fifo)
    code, out, err = run(capsys, "session", fifo)
    assert code == 2
    assert "FIFO/special file, not a folder" in one_line(err)
    (tmp_path / "t").mkdir()   # a session.toml that is a FIFO: refused, never read
    os.mkfifo(tmp_path / "t" / "session.toml")
    code, out, err = run(capsys, "session", tmp_path / "t")
    assert code == 2
    assert "FIFO/special file, not a manifest" in one_line(err)


def test_session_of_bomb_frames_is_not_valid(capsys, tmp_path):
    root = tmp_path / "s"
    root.mkdir()
    for i in range(2):
        bomb_tiff(root / f"d{i}.tif", 40000, 40000)   # ~1.5 MB each
    manifest(root, frames_body("dark", ["d0.tif", "d1.tif"]))
    code, out, err = run(capsys, "session", root)
    assert code == 2
    assert "valid" not in out.splitlines()[-1].replace("invalid", "")
    line = one_line(err)
    assert "d0.tif" in line and "40000x40000" in line and "over the limit" in line


def test_emva_descriptor_without_points_is_refused(capsys, tmp_path):
    desc = tmp_path / "EMVA1288descriptor.txt"
    desc.write_text("v 4.0\nn 8 16 12\n")
    code, out, err = run(capsys, "session", desc)
    assert code == 2
    assert "no images" in one_line(err) and "invalid" in out


def test_values_beyond_the_declared_bit_depth_are_refused(capsys, tmp_path):
    root = tmp_path / "s"
    root.mkdir()
    names = [f"d{i}.tif" for i in range(3)]
    for i, name in enumerate(names):   # a 16-bit camera's darks, declared 8-bit
        write_image(root / name, np.full((12, 16), 3217 + i % 2, np.uint16))
    manifest(root, frames_body("dark", names))
    session = open_session(root)
    with pytest.raises(CcdError, match=r"d0\.tif: uint16 sample type holds value 3217, "
                                       r"beyond camera\.bits = 8 \(codes 0\.\.255\)"):
        session.read(session.frames[0])
    assert {p.code for p in session.verify_pixels().errors} == {"bit-depth"}
    code, out, err = run(capsys, "calibrate", root, "-o", tmp_path / "out")
    assert code == 2
    assert "beyond camera.bits = 8" in one_line(err)


# --------------------------------------------------------------------------------------------
# 3. exposure times and constant brackets
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("exposure", ["1e-320", "1e300"])
def test_absurd_bracket_exposures_are_one_line(capsys, tmp_path, exposure):
    root = tmp_path / "s"
    root.mkdir()
    times = [exposure, "0.02", "0.04"]
    manifest(root, frames_body("bracket", bracket(root, times), times))
    code, out, err = run(capsys, "response", root)
    assert code == 2
    line = one_line(err)
    assert "b0.tif" in line and "'exposure' must be 0 or from 1e-09 to 1e+06 seconds" in line
    for bad in (float(exposure), -0.0 + 1e-12, 2e6):
        with pytest.raises(CcdError, match=r"f0\.tif: exposure time .* outside"):
            check_times([bad, 0.02], ["f0.tif", "f1.tif"])


def test_zero_exposure_in_a_bracket_names_the_frame(capsys, tmp_path):
    root = tmp_path / "s"
    root.mkdir()
    times = ["0", "0.02", "0.04"]
    manifest(root, frames_body("bracket", bracket(root, times), times))
    code, out, err = run(capsys, "response", root)
    assert code == 2
    assert one_line(err).endswith("b0.tif: exposure is 0 s: a bracket frame needs a positive "
                                  "exposure time")
    with pytest.raises(CcdError, match=r"f0\.tif: exposure time is 0"):
        check_times([0.0, 0.02], ["f0.tif", "f1.tif"])


def test_zero_exposure_in_a_change_bracket_is_not_a_nan_radiance(capsys, tmp_path):
    root = tmp_path / "s"
    root.mkdir()
    times = ["0", "0.02", "0.04"]
    body = (frames_body("reference", bracket(root, times, prefix="r"), times) + "\n"
            + frames_body("target", bracket(root, times, prefix="t"), times))
    manifest(root, body)
    code, out, err = run(capsys, "change", root, "-o", tmp_path / "out")
    assert code == 2
    line = one_line(err)
    assert "r0.tif: exposure is 0 s" in line and "NaN" not in line


def test_constant_bracket_is_refused(capsys, tmp_path):
    root = tmp_path / "s"
    root.mkdir()
    times = ["0.01", "0.02", "0.04"]
    manifest(root, frames_body("bracket", bracket(root, times, constant=True), times))
    code, out, err = run(capsys, "response", root)
    assert code == 2
    line = one_line(err)
    assert "every usable code is 13" in line and "no code range to calibrate" in line


# --------------------------------------------------------------------------------------------
# 4. options out of range
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, message", [
    (["response", "s", "--bloom-radius", "3000"], "must be in 0..64 pixels"),
    (["hdr", "s", "--bloom-radius", "-1", "-o", "x"], "must be in 0..64 pixels"),
    (["change", "s", "--bloom-radius", "65", "-o", "x"], "lens flare, not blooming"),
    (["simulate", "healey94", "x", "--size", "100000x100000"], "over the pixel limit"),
    (["simulate", "healey94", "x", "--seed", "-1"], "seed must be 0 or more"),
    (["app", "--port", "70000"], "--port: must be in 1..65535"),
    (["app", "--port", "-1"], "--port: must be in 1..65535"),
])
def test_options_out_of_range_are_one_line(capsys, argv, message):
    code, out, err = run(capsys, *argv)
    assert code == 2
    assert message in one_line(err)


def test_bloom_mask_refuses_a_huge_radius_quickly():
    plane = np.zeros((48, 64), np.uint8)
    plane[10, 10] = 255
    assert bloom_mask(plane, 256, MAX_BLOOM_RADIUS).sum() > 0
    with pytest.raises(CcdError, match="bloom_radius: must be from 0 to 64"):
        bloom_mask(plane, 256, 3000)


def test_busy_port_is_named_before_serving(capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        code, out, err = run(capsys, "app", "--port", port)
    assert code == 2
    assert "serving" not in out
    assert one_line(err).endswith(f"port {port} is in use: choose another with --port")


def test_out_of_memory_is_one_line_naming_the_input(capsys, tmp_path, monkeypatch):
    """MemoryError anywhere in a verb (NumPy could not allocate a frame's worth) is one line
    with exit 2 naming the session, not a traceback."""
    import ccdcore.session as session_mod

    def huge(*args, **kwargs):
        raise MemoryError("Unable to allocate 3.18 GiB for an array with shape (20000, 20000) "
                          "and data type float64")
    monkeypatch.setattr(session_mod, "open_session", huge)
    root = tmp_path / "big"
    root.mkdir()
    code, out, err = run(capsys, "session", root)
    assert code == 2
    line = one_line(err)
    assert "not enough memory" in line and "3.18 GiB" in line and str(root) in line


@pytest.mark.parametrize("preset, size", [("healey94", "16x16"), ("change", "8x8")])
def test_simulate_too_small_names_size(capsys, tmp_path, preset, size):
    """A frame too small for a preset's layout is refused naming --size and the smallest size
    that works, not an internal option the user never gave."""
    code, out, err = run(capsys, "simulate", preset, tmp_path / "s", "--size", size)
    assert code == 2
    line = one_line(err)
    assert line.startswith("ccdcore simulate: error: size: ") and "--size" in line
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("body, what", [
    ("a" + ".b" * 100_000 + " = 1", "dotted parts"),
    ("[" + "t." * 40 + "u]\nx = 1", "dotted parts"),
    ("a = " + "[" * 40 + "]" * 40, "nested too deeply"),
    ("a = " + "{b = " * 40 + "1" + "}" * 40, "nested too deeply")])
def test_a_manifest_beyond_any_is_refused_before_parsing(capsys, tmp_path, body, what):
    """A dotted key of 100 000 parts (the TOML reader is quadratic in them: it took all 24 GB)
    or nesting beyond any manifest's is one line naming session.toml, before the parser runs."""
    import tomllib

    root = manifest(tmp_path / "s", body)
    calls = []
    real = tomllib.loads
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tomllib, "loads", lambda text: calls.append(1) or real(text))
        code, out, err = run(capsys, "session", root)
    assert code == 2 and not calls
    line = one_line(err)
    assert "session.toml" in line and what in line


def test_an_ordinary_manifest_passes_the_bounds(tmp_path):
    """Dots and brackets inside strings and comments, float values, arrays and inline tables of
    an ordinary manifest are not counted."""
    from ccdcore.session.manifest import bound_problem

    text = ('schema = 1  # a.b.c.d.e.f.g.h.i.j.k.l.m.n.o.p.q.r.s\n[camera]\n'
            'name = "a.b.c.d.e.f.g.h.i.j.k.l.m.n.o.p.q.r.s [[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[["\n'
            '[[frames]]\npath = "x.y.z.tif"\nroi = [1, 2, 3, 4]\nexposure = 0.01\n'
            'note = \'c:\\\\a.b.c\'\nx = {a.b = 1.5, c = [1.5, [2.5, 3.5]]}\n')
    assert bound_problem(text) is None


def test_one_channel_frames_under_an_rgb_layout_are_an_error(capsys, tmp_path):
    """layout = "rgb" on one-channel frames was accepted and read them as colour (the
    photon-transfer figures changed): now an error naming each frame, its code the fix."""
    root = tmp_path / "s"
    root.mkdir()
    rng = np.random.default_rng(5)
    for i in range(2):
        write_image(root / f"d{i}.tif", rng.integers(90, 110, (8, 8)).astype(np.uint16), bits=12)
    (root / "session.toml").write_text(
        'schema = 1\n[camera]\nbits = 12\nlayout = "rgb"\n\n'
        + "".join(f'[[frames]]\npath = "d{i}.tif"\nrole = "dark"\nexposure = 0.01\n\n'
                  for i in range(2)))
    session = open_session(root)
    found = [p for p in session.problems if p.code == "layout"]
    assert [p.where for p in found] == ["d0.tif", "d1.tif"] and not session.ok
    assert "has 1 channel, where [camera] layout = 'rgb' needs 3" in found[0].message
    code, out, err = run(capsys, "calibrate", root, "-o", tmp_path / "c")
    assert code == 2 and "layout" in err


@pytest.fixture(scope="module")
def h94_product(tmp_path_factory):
    from ccdcore.product.make import calibrate
    from ccdcore.simulate import simulate

    root = tmp_path_factory.mktemp("p") / "s"
    simulate("healey94", root, seed=3, size=(48, 32), n1=2, n2=1)
    out = root.parent / "calib"
    calibrate(root).save(out)
    return root, out


@pytest.mark.parametrize("edit, what", [
    (lambda d: d["estimates"]["noise"].__setitem__("A", float("nan")), "NaN is not a number"),
    (lambda d: d["estimates"]["noise"].__setitem__("A", float("inf")), "Infinity is not a number"),
    (lambda d: d["estimates"]["noise"].__setitem__("A", -1.0),
     "'estimates.noise.A' is -1.0, not positive, yet the conversion gain is stated"),
    (lambda d: d["estimates"]["noise"].__setitem__("A_err", -0.5), "a standard error must be")])
def test_a_product_with_impossible_figures_is_refused(capsys, h94_product, tmp_path, edit, what):
    """A product never writes NaN or Infinity (a figure it cannot state is null) nor a gain
    that is not positive: such a calibration.json is damaged, and apply and report say so in
    one line (they exited 0 and printed K = nan)."""
    import json
    import shutil

    root, calib = h94_product
    bad = tmp_path / "bad"
    shutil.copytree(calib, bad)
    doc = json.loads((bad / "calibration.json").read_text())
    edit(doc)
    (bad / "calibration.json").write_text(json.dumps(doc))
    frame = next((root / "scene").iterdir())
    for argv in (("apply", bad, frame, "-o", tmp_path / "o"), ("report", bad, "-o",
                                                                tmp_path / "r.html")):
        code, out, err = run(capsys, *argv)
        assert code == 2 and what in one_line(err) and "calibration.json" in err


def test_an_emva_gain_that_is_not_positive_is_refused():
    """The EMVA 1288 system gain K of a stored datasheet must be positive."""
    from ccdcore.emva.datasheet import emva_figures
    from ccdcore.emva.results import EmvaSummary

    doc = emva_figures(open_session(Path(__file__).parents[1] / "assets" / "emva1288")).summary(
    ).to_dict()
    assert EmvaSummary.from_dict(doc, "calibration.json", "emva1288").K > 0
    for bad in (-1.0, 0.0):
        with pytest.raises(CcdError, match=f"'emva1288.K' is {bad}"):
            EmvaSummary.from_dict({**doc, "K": bad}, "calibration.json", "emva1288")


def test_a_frame_deeper_than_the_products_camera_is_refused(capsys, h94_product, tmp_path):
    """A 16-bit frame applied to an 8-bit camera's product (it was applied silently); an
    8-bit frame of the same size is corrected."""
    root, calib = h94_product
    shape = read_image(next((root / "dark").iterdir())).shape
    deep = write_image(tmp_path / "deep.tif", np.full(shape, 300, np.uint16), bits=16)
    code, out, err = run(capsys, "apply", calib, deep, "-o", tmp_path / "o")
    assert code == 2 and "16-bit uint16 data" in one_line(err) and "8-bit camera" in err
    ok = write_image(tmp_path / "ok.tif", np.full(shape, 30, np.uint8), bits=8)
    assert run(capsys, "apply", calib, ok, "-o", tmp_path / "o2")[0] == 0


def test_a_fifo_given_as_a_frame_is_named_as_one(capsys, h94_product, tmp_path):
    """A FIFO is refused as what it is (it was called an empty file), without blocking."""
    import os

    root, calib = h94_product
    fifo = tmp_path / "pipe.tif"
    os.mkfifo(fifo)
    code, out, err = run(capsys, "apply", calib, fifo, "-o", tmp_path / "o")
    assert code == 2 and "is a FIFO (named pipe), not an image file" in one_line(err)


def test_an_emva_descriptor_opening_with_64_kb_of_comments_is_one(tmp_path):
    """A descriptor may open with any amount of comments (it was refused as "not a session"
    when the first 64 KB were comments)."""
    import shutil

    src = Path(__file__).parents[1] / "assets" / "emva1288"
    root = Path(shutil.copytree(src, tmp_path / "e"))
    desc = root / "EMVA1288descriptor.txt"
    desc.write_text("# a comment line of a lab's own header\n" * 3000 + desc.read_text())
    assert desc.stat().st_size > 100_000
    session = open_session(desc)
    assert session.source == "emva1288" and session.roles()["ptc"] > 0
