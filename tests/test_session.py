"""Tests of ccdcore.session: manifest parsing, validation, lazy frames, plain folders, drafts."""
from __future__ import annotations

import dataclasses
import inspect
import os
from pathlib import Path

import numpy as np
import pytest

import ccdcore.session.records as session_mod
from ccdcore.errors import CcdError, ImageReadError, SessionError
from ccdcore.io.frames import read_header, read_image, write_image
from ccdcore.session import (LAYOUTS, ROLES, FrameRecord, Problem, Session, draft_manifest,
                             open_session)
from ccdcore.common import format_size

H, W = 12, 16


def frame(seed: int, shape: tuple[int, ...] = (H, W), dtype=np.uint16) -> np.ndarray:
    """A small deterministic frame (values fit in 8 bits so any dtype holds them)."""
    return np.random.default_rng(seed).integers(0, 256, shape).astype(dtype)


def put(root: Path, rel: str, seed: int = 0, **kwargs) -> Path:
    """Write a 16x12 uint16 frame at ``root/rel`` (``kwargs`` go to write_image / frame)."""
    shape = kwargs.pop("shape", (H, W))
    dtype = kwargs.pop("dtype", np.uint16)
    return write_image(root / rel, frame(seed, shape, dtype), **kwargs)


def manifest(root: Path, body: str, camera: str = 'name = "bench"\nbits = 8\nlayout = "mono"'
             ) -> Session:
    """Write ``session.toml`` (schema 1, [camera], then ``body``) and open the folder."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "session.toml").write_text(f"schema = 1\n[camera]\n{camera}\n\n{body}\n")
    return open_session(root)


def problem_at(session: Session, where: str) -> list[Problem]:
    return [p for p in session.problems if p.where == where]


def errors(session: Session) -> list[tuple[str, str]]:
    return [(p.where, p.message) for p in session.problems if p.severity == "error"]


# --------------------------------------------------------------------------------------------
# a valid session with every role, groups with globs
# --------------------------------------------------------------------------------------------
@pytest.fixture
def full_session(tmp_path: Path) -> Path:
    root = tmp_path / "s"
    for i in range(3):
        put(root, f"dark/d{i}.tif", i)
    for level in (1, 2):
        for k in "ab":
            put(root, f"ptc/L{level}{k}.tif", 10 * level + ord(k))
    for config in (1, 2):
        for k in range(2):
            put(root, f"fp/c{config}_{k}.tif", 100 + 10 * config + k)
    for i, t in enumerate((0.01, 0.02)):
        put(root, f"flat/f{i}.tif", 200 + i)
    for i, t in enumerate((0.04, 0.01, 0.02)):
        put(root, f"hdr/b{i}.tif", 300 + i)
    put(root, "scene/s0.tif", 400)
    put(root, "ref/r0.tif", 500)
    put(root, "tgt/t0.tif", 600)
    (root / "dark" / "README.txt").write_text("not an image")  # ignored by the glob
    (root / "session.toml").write_text("""
schema = 1
[camera]
name = "bench"
bits = 8
layout = "mono"

[[frames]]
path = "ptc/L2a.tif"
role = "ptc"
level = 2
[[frames]]
path = "ptc/L2b.tif"
role = "ptc"
level = 2
[[frames]]
path = "ptc/L1a.tif"
role = "ptc"
level = 1
[[frames]]
path = "ptc/L1b.tif"
role = "ptc"
level = 1
[[frames]]
path = "flat/f0.tif"
role = "flat"
exposure = 0.01
[[frames]]
path = "flat/f1.tif"
role = "flat"
exposure = 0.02
[[frames]]
path = "hdr/b0.tif"
role = "bracket"
exposure = 0.04
stack = 1
[[frames]]
path = "hdr/b1.tif"
role = "bracket"
exposure = 0.01
stack = 1
[[frames]]
path = "hdr/b2.tif"
role = "bracket"
exposure = 0.02
stack = 1
[[frames]]
path = "scene/s0.tif"
role = "scene"
roi = [2, 3, 8, 6]
note = "grey card"
[[frames]]
path = "ref/r0.tif"
role = "reference"
exposure = 0.05
[[frames]]
path = "tgt/t0.tif"
role = "target"
exposure = 0.05
gain = 2.0
temperature = 25.5

[[groups]]
glob = "dark/*"
role = "dark"
exposure = 0.033
[[groups]]
glob = "fp/c1_*.tif"
role = "fixed_pattern"
config = 1
[[groups]]
glob = "fp/c2_*.tif"
role = "fixed_pattern"
config = 2
""")
    return root


def test_valid_session_with_every_role(full_session: Path) -> None:
    s = open_session(full_session)
    assert s.problems == ()
    assert s.ok and s.source == "manifest"
    s.raise_if_invalid()  # no error: must not raise
    assert s.manifest_path == full_session / "session.toml"
    assert s.root == full_session.resolve()
    assert s.camera.name == "bench" and s.camera.bits == 8 and s.camera.layout == "mono"
    assert s.roles() == {"dark": 3, "ptc": 4, "fixed_pattern": 4, "flat": 2, "bracket": 3,
                         "scene": 1, "reference": 1, "target": 1}
    assert set(s.roles()) == set(ROLES)
    # manifest order: [[frames]] entries first, then each group's matches sorted
    assert [r.relpath for r in s.frames[:2]] == ["ptc/L2a.tif", "ptc/L2b.tif"]
    assert [r.relpath for r in s.frames[12:]] == [
        "dark/d0.tif", "dark/d1.tif", "dark/d2.tif", "fp/c1_0.tif", "fp/c1_1.tif",
        "fp/c2_0.tif", "fp/c2_1.tif"]
    levels = s.ptc_levels()
    assert list(levels) == [1, 2]
    assert [r.relpath for r in levels[1]] == ["ptc/L1a.tif", "ptc/L1b.tif"]
    assert {r.exposure for r in s.dark_frames()} == {0.033}
    assert {k: [r.relpath for r in v] for k, v in s.fixed_pattern_configs().items()} == {
        1: ["fp/c1_0.tif", "fp/c1_1.tif"], 2: ["fp/c2_0.tif", "fp/c2_1.tif"]}
    assert list(s.flats()) == [0.01, 0.02]
    stacks = s.bracket_stacks()
    assert list(stacks) == [1]
    assert [r.exposure for r in stacks[1]] == [0.01, 0.02, 0.04]  # sorted by exposure
    assert [r.relpath for r in s.bracket_stacks("reference")[None]] == ["ref/r0.tif"]
    (scene,) = s.scenes()
    assert scene.roi == (2, 3, 8, 6) and scene.note == "grey card"
    (tgt,) = s.by_role("target")
    assert (tgt.gain, tgt.temperature, tgt.inferred) == (2.0, 25.5, ())
    for rec in s.frames:
        assert rec.path == (full_session / rec.relpath).resolve()
        assert s.header(rec).shape == (H, W)
    np.testing.assert_array_equal(s.read(levels[2][0]), read_image(full_session / "ptc/L2a.tif"))
    with pytest.raises(CcdError):
        s.by_role("darks")


def test_tables_and_dicts(full_session: Path) -> None:
    s = open_session(full_session)
    rows = s.groups_table()
    assert {(r["role"], r["key"]): r["count"] for r in rows} == {
        ("dark", 0.033): 3, ("ptc", 1): 2, ("ptc", 2): 2, ("fixed_pattern", 1): 2,
        ("fixed_pattern", 2): 2, ("flat", 0.01): 1, ("flat", 0.02): 1, ("bracket", 1): 3,
        ("scene", None): 1, ("reference", None): 1, ("target", None): 1}
    bracket = next(r for r in rows if r["role"] == "bracket")
    assert (bracket["shape"], bracket["dtype"], bracket["exposures"]) == (
        (12, 16), "uint16", [0.01, 0.02, 0.04])
    table = s.frames_table()
    assert len(table) == len(s.frames)
    assert table[9]["relpath"] == "scene/s0.tif" and table[9]["roi"] == [2, 3, 8, 6]
    assert (table[0]["shape"], table[0]["dtype"], table[0]["bits"]) == ((12, 16), "uint16", 16)
    d = s.to_dict()
    assert d["ok"] and d["source"] == "manifest" and len(d["frames"]) == 19
    assert s.frames[9].to_dict()["roi"] == [2, 3, 8, 6]
    assert "path" not in s.frames[0].to_dict()


def test_groups_with_recursive_glob_and_shared_metadata(tmp_path: Path) -> None:
    root = tmp_path / "s"
    for name in ("night/b/2.fits", "night/a/1.fits", "night/a/0.fits", "day/x.fits"):
        put(root, name)
    s = manifest(root, '[[groups]]\nglob = "night/**/*.fits"\nrole = "dark"\nexposure = 2.5\n'
                       'temperature = -10.0\nnote = "night run"')
    assert s.problems == ()
    assert [r.relpath for r in s.frames] == ["night/a/0.fits", "night/a/1.fits", "night/b/2.fits"]
    assert all((r.role, r.exposure, r.temperature, r.note) == ("dark", 2.5, -10.0, "night run")
               for r in s.frames)


# --------------------------------------------------------------------------------------------
# one case per validation problem
# --------------------------------------------------------------------------------------------
def test_unknown_role(tmp_path: Path) -> None:
    put(tmp_path / "s", "a.tif")
    s = manifest(tmp_path / "s", '[[frames]]\npath = "a.tif"\nrole = "darks"')
    (p,) = s.problems
    assert p.where == "frames[0] (a.tif)" and p.severity == "error"
    assert p.message.startswith("unknown role 'darks'")
    assert s.frames == () and not s.ok


def test_unknown_camera_layout(tmp_path: Path) -> None:
    put(tmp_path / "s", "a.tif")
    s = manifest(tmp_path / "s", '[[frames]]\npath = "a.tif"\nrole = "dark"',
                 camera='bits = 8\nlayout = "bayer-xyzw"')
    assert errors(s) == [("camera.layout", "unknown layout 'bayer-xyzw'; choose one of "
                                           + ", ".join(LAYOUTS))]


def test_camera_black_level(tmp_path: Path) -> None:
    """Optional ``[camera] black_level`` (DN): parsed as a float, validated, round-tripped."""
    put(tmp_path / "s", "a.tif")
    body = '[[frames]]\npath = "a.tif"\nrole = "dark"'
    s = manifest(tmp_path / "s", body, camera='bits = 8\nblack_level = 20')
    assert s.ok and s.camera.black_level == 20.0 and isinstance(s.camera.black_level, float)
    assert s.camera.to_dict()["black_level"] == 20.0
    assert "black_level = 20.0" in s.to_toml()
    (tmp_path / "s" / "session.toml").write_text(s.to_toml())
    assert open_session(tmp_path / "s").camera == s.camera
    assert manifest(tmp_path / "s", body).camera.black_level is None  # absent: None
    for bad in ("-1.5", '"high"', "true", "nan"):
        s = manifest(tmp_path / "s", body, camera=f"bits = 8\nblack_level = {bad}")
        assert s.camera.black_level is None
        ((where, message),) = errors(s)
        assert where == "camera.black_level" and message.startswith("must be a number >= 0 (DN)")


def test_missing_file(tmp_path: Path) -> None:
    put(tmp_path / "s", "a.tif")
    s = manifest(tmp_path / "s", '[[frames]]\npath = "a.tif"\nrole = "dark"\n'
                                 '[[frames]]\npath = "dark/missing.tif"\nrole = "dark"')
    assert errors(s) == [("dark/missing.tif", "file not found")]
    assert [r.relpath for r in s.frames] == ["a.tif"]


def test_glob_matching_nothing(tmp_path: Path) -> None:
    put(tmp_path / "s", "a.tif")
    (tmp_path / "s" / "flats").mkdir()
    (tmp_path / "s" / "flats" / "notes.txt").write_text("x")
    s = manifest(tmp_path / "s", '[[frames]]\npath = "a.tif"\nrole = "dark"\n'
                                 '[[groups]]\nglob = "flats/*"\nrole = "flat"\nexposure = 0.1')
    assert errors(s) == [("groups[0] (flats/*)", "glob matches no image file (1 non-image file)")]


@pytest.mark.parametrize("how", ["dotdot", "absolute", "symlink", "symlink-in-glob",
                                 "glob-dotdot"])
def test_path_escaping_the_session_folder(tmp_path: Path, how: str) -> None:
    root = tmp_path / "s"
    outside = put(tmp_path, "x.tif")  # exists, next to the session folder
    put(root, "a.tif")
    if how.startswith("symlink"):
        (root / "sub").mkdir()
        os.symlink(outside, root / "sub" / "link.tif")
    entry = {"dotdot": '[[frames]]\npath = "../x.tif"\nrole = "dark"',
             "absolute": f'[[frames]]\npath = "{outside}"\nrole = "dark"',
             "symlink": '[[frames]]\npath = "sub/link.tif"\nrole = "dark"',
             "symlink-in-glob": '[[groups]]\nglob = "sub/*.tif"\nrole = "dark"',
             "glob-dotdot": '[[groups]]\nglob = "../*.tif"\nrole = "dark"'}[how]
    s = manifest(root, '[[frames]]\npath = "a.tif"\nrole = "dark"\n' + entry)
    expected = {
        "dotdot": ("../x.tif", "path escapes the session folder ('..')"),
        "absolute": (str(outside), "absolute path; paths must be relative to the session folder"),
        "symlink": ("sub/link.tif", "resolves outside the session folder (symbolic link to "
                                    f"{outside.resolve()})"),
        "symlink-in-glob": ("sub/link.tif", "resolves outside the session folder (symbolic "
                                            f"link to {outside.resolve()}) (groups[0] (sub/*.tif))"),
        "glob-dotdot": ("groups[0] (../*.tif)", "glob escapes the session folder ('..')"),
    }[how]
    assert errors(s) == [expected]
    assert [r.relpath for r in s.frames] == ["a.tif"]  # nothing outside is ever listed


def test_shape_mismatch_within_a_role(tmp_path: Path) -> None:
    root = tmp_path / "s"
    for i in range(3):
        put(root, f"dark/d{i}.tif", i, shape=(H + 1, W) if i == 1 else (H, W))
    put(root, "scene/big.tif", shape=(2 * H, W))  # scenes are independent images: no problem
    put(root, "scene/small.tif")
    s = manifest(root, '[[groups]]\nglob = "dark/*.tif"\nrole = "dark"\n'
                       '[[groups]]\nglob = "scene/*.tif"\nrole = "scene"')
    assert errors(s) == [("dark/d1.tif", "size 16 × 13 differs from 16 × 12 of the other dark "
                                         "frames (2 frames)")]


def test_dtype_mismatch_within_a_role(tmp_path: Path) -> None:
    root = tmp_path / "s"
    put(root, "flat/f0.tif", exposure=0.1)
    put(root, "flat/f1.tif", exposure=0.1)
    put(root, "flat/f2.png", dtype=np.uint8, exposure=0.1)
    s = manifest(root, '[[groups]]\nglob = "flat/*"\nrole = "flat"')
    assert errors(s) == [("flat/f2.png", "dtype uint8 differs from uint16; bit depth 8 differs "
                                         "from 16 of the other flat frames (2 frames)")]


def test_ptc_shapes_are_compared_across_levels(tmp_path: Path) -> None:
    root = tmp_path / "s"
    for level, shape in ((1, (H, W)), (2, (H, W)), (3, (H, W + 2))):
        for k in "ab":
            put(root, f"ptc/L{level}{k}.tif", shape=shape)
    s = manifest(root, "".join(f'[[groups]]\nglob = "ptc/L{n}*.tif"\nrole = "ptc"\nlevel = {n}\n'
                               for n in (1, 2, 3)))
    assert errors(s) == [(f"ptc/L3{k}.tif", "size 18 × 12 differs from 16 × 12 of the other ptc "
                                            "frames (4 frames)") for k in "ab"]


def test_bits_above_camera_bits(tmp_path: Path) -> None:
    root = tmp_path / "s"
    put(root, "a.fits", bits=12)
    put(root, "b.fits", bits=14)  # FITS BITDEPTH: the significant bits, not the container
    put(root, "c.tif")            # a 16-bit TIFF container alone says nothing about the ADC
    s = manifest(root, '[[frames]]\npath = "a.fits"\nrole = "scene"\n'
                       '[[frames]]\npath = "b.fits"\nrole = "scene"\n'
                       '[[frames]]\npath = "c.tif"\nrole = "scene"', camera="bits = 12")
    assert errors(s) == [("b.fits", "14-bit data but camera.bits = 12")]


@pytest.mark.parametrize("role", ["bracket", "reference", "target"])
def test_missing_exposure(tmp_path: Path, role: str) -> None:
    root = tmp_path / "s"
    put(root, "with_exif.tif", exposure=0.25)
    put(root, "plain.tif")  # no EXIF ExposureTime, and the manifest gives none
    put(root, "given.tif")
    s = manifest(root, f'[[frames]]\npath = "with_exif.tif"\nrole = "{role}"\n'
                       f'[[frames]]\npath = "plain.tif"\nrole = "{role}"\n'
                       f'[[frames]]\npath = "given.tif"\nrole = "{role}"\nexposure = 0.5')
    assert errors(s) == [("plain.tif", f"missing exposure: a {role} frame needs one, and "
                                       "neither the manifest nor the file header (EXIF "
                                       "ExposureTime, FITS EXPTIME) gives it")]


def test_ptc_level_with_one_frame(tmp_path: Path) -> None:
    root = tmp_path / "s"
    for name in ("L1a.tif", "L1b.tif", "L2a.tif"):
        put(root, name)
    s = manifest(root, '[[frames]]\npath = "L1a.tif"\nrole = "ptc"\nlevel = 1\n'
                       '[[frames]]\npath = "L1b.tif"\nrole = "ptc"\nlevel = 1\n'
                       '[[frames]]\npath = "L2a.tif"\nrole = "ptc"\nlevel = 2')
    assert errors(s) == [("ptc level 2", "only one frame (L2a.tif); a photon-transfer level "
                                         "needs at least two")]


def test_ptc_without_level_and_fixed_pattern_without_config(tmp_path: Path) -> None:
    root = tmp_path / "s"
    for name in ("p0.tif", "p1.tif", "fp/0.tif", "fp/1.tif"):
        put(root, name)
    s = manifest(root, '[[frames]]\npath = "p0.tif"\nrole = "ptc"\n'
                       '[[frames]]\npath = "p1.tif"\nrole = "ptc"\nlevel = 1\n'
                       '[[frames]]\npath = "p0.tif"\nrole = "ptc"\nlevel = 1\n'
                       '[[groups]]\nglob = "fp/*.tif"\nrole = "fixed_pattern"')
    assert errors(s) == [
        ("frames[0] (p0.tif)", "ptc frame without 'level' (frames of one light level form pairs)"),
        ("p0.tif", "frame listed twice: frames[0] (p0.tif) and frames[2] (p0.tif)"),
        # a group reports its entry once, not once per file
        ("groups[0] (fp/*.tif)", "fixed_pattern frame without 'config' (configuration id)"),
        ("ptc level 1", "only one frame (p1.tif); a photon-transfer level needs at least two"),
    ]


def test_duplicate_frame_paths(tmp_path: Path) -> None:
    root = tmp_path / "s"
    for i in range(3):
        put(root, f"dark/d{i}.tif", i)
    s = manifest(root, '[[frames]]\npath = "dark/d1.tif"\nrole = "dark"\n'
                       '[[frames]]\npath = "./dark/d1.tif"\nrole = "dark"\n'
                       '[[groups]]\nglob = "dark/*.tif"\nrole = "dark"')
    assert errors(s) == [
        ("./dark/d1.tif", "frame listed twice: frames[0] (dark/d1.tif) and frames[1] "
                          "(./dark/d1.tif)"),
        ("dark/d1.tif", "frame listed twice: frames[0] (dark/d1.tif) and groups[0] "
                        "(dark/*.tif)"),
    ]
    assert [r.relpath for r in s.frames] == ["dark/d1.tif", "dark/d0.tif", "dark/d2.tif"]


def test_unreadable_and_truncated_images(tmp_path: Path) -> None:
    root = tmp_path / "s"
    put(root, "good.tif")
    data = put(root, "cut.tif").read_bytes()
    (root / "cut.tif").write_bytes(data[: len(data) // 2])  # header intact, pixels cut short
    (root / "stub.tif").write_bytes(data[:100])              # cut inside the header
    (root / "junk.tif").write_bytes(b"this is not a TIFF file at all" * 10)
    (root / "empty.fits").write_bytes(b"")
    names = ("good.tif", "cut.tif", "stub.tif", "junk.tif", "empty.fits")
    s = manifest(root, "".join(f'[[frames]]\npath = "{n}"\nrole = "scene"\n' for n in names))

    def message(read, name: str) -> str:  # the ImageReadError problem, as ccdcore.io.frames words it
        with pytest.raises(ImageReadError) as info:
            read(root / name)
        return info.value.problem

    header_errors = [(n, message(read_header, n)) for n in ("stub.tif", "junk.tif", "empty.fits")]
    assert errors(s) == header_errors  # opening reads headers only
    assert header_errors[2][1] == "empty file (0 bytes)"
    assert [r.relpath for r in s.frames] == list(names)  # unreadable frames stay listed
    checked = open_session(root, check_pixels=True)
    pixel_error = ("cut.tif", message(read_image, "cut.tif"))
    assert "truncated" in pixel_error[1]
    assert errors(checked) == header_errors + [pixel_error]
    assert errors(s.verify_pixels()) == errors(checked)


def test_unknown_keys_are_warnings(tmp_path: Path) -> None:
    root = tmp_path / "s"
    put(root, "a.tif")
    (root / "session.toml").write_text(
        'schema = 1\nowner = "me"\n[camera]\nbits = 8\nlens = "50mm"\n'
        '[[frames]]\npath = "a.tif"\nrole = "dark"\nexposre = 0.1\n')
    s = open_session(root)
    assert s.ok
    assert [(p.where, p.message, p.severity) for p in s.problems] == [
        ("owner", "unknown top-level key (ignored)", "warning"),
        ("camera.lens", "unknown key (ignored)", "warning"),
        ("frames[0] (a.tif)", "unknown key 'exposre' (ignored)", "warning"),
    ]


def test_every_problem_is_reported_at_once(tmp_path: Path) -> None:
    root = tmp_path / "s"
    put(root, "a.tif")
    put(root, "b.tif")
    s = manifest(root, '[[frames]]\npath = "a.tif"\nrole = "ptc"\nlevel = "one"\n'
                       '[[frames]]\npath = "b.tif"\nrole = "bracket"\nroi = [0, 0, 99, 5]\n'
                       '[[frames]]\npath = "c.tif"\nrole = "dark"\n'
                       '[[frames]]\npath = "/abs.tif"\nrole = "dark"\n'
                       '[[frames]]\nrole = "dark"\n'
                       '[[groups]]\nglob = "none/*.fits"\nrole = "dark"',
                 camera='bits = "twelve"\nlayout = "cmyk"')
    wheres = [w for w, _ in errors(s)]
    assert wheres == ["camera.bits", "camera.layout", "frames[0] (a.tif)", "frames[4]",
                      "groups[0] (none/*.fits)", "frames[0] (a.tif)", "b.tif", "b.tif", "c.tif",
                      "/abs.tif"]
    assert errors(s)[7] == ("b.tif", "roi [0, 0, 99, 5] extends past the 16x12 frame")
    with pytest.raises(SessionError) as info:
        s.raise_if_invalid()
    assert str(info.value) == ("camera.bits: must be an integer from 1 to 32, got 'twelve' "
                               "(and 9 more problems)")
    assert len(info.value.problems) == 10 and info.value.where == "camera.bits"


def test_toml_syntax_error_raises_naming_the_manifest(tmp_path: Path) -> None:
    root = tmp_path / "s"
    root.mkdir()
    (root / "session.toml").write_text('schema = 1\n[camera]\nbits = 8\nname = "unclosed\n')
    with pytest.raises(CcdError) as info:
        open_session(root)
    assert info.value.where == str(root / "session.toml")
    assert "TOML syntax error" in info.value.problem and "line 4" in info.value.problem


def test_unusable_paths_raise(tmp_path: Path) -> None:
    with pytest.raises(CcdError, match="does not exist"):
        open_session(tmp_path / "nowhere")
    (tmp_path / "notes.txt").write_text("# a comment\nhello\n")
    with pytest.raises(CcdError, match="not a session"):
        open_session(tmp_path / "notes.txt")


def test_manifest_file_path_is_accepted(full_session: Path) -> None:
    a = open_session(full_session / "session.toml")
    b = open_session(full_session)
    assert a.frames == b.frames and a.root == b.root


# --------------------------------------------------------------------------------------------
# headers: inference and lazy frames
# --------------------------------------------------------------------------------------------
def test_metadata_inferred_from_fits_and_tiff_headers(tmp_path: Path) -> None:
    root = tmp_path / "s"
    put(root, "b/0.fits", exposure=0.125, attributes={"GAIN": 1.5, "CCD-TEMP": -12.5})
    put(root, "b/1.tif", exposure=0.01)  # EXIF ExposureTime (a float32 in the file)
    put(root, "b/2.tif", exposure=0.3)   # the manifest's value wins over the header's
    s = manifest(root, '[[frames]]\npath = "b/0.fits"\nrole = "bracket"\n'
                       '[[frames]]\npath = "b/1.tif"\nrole = "bracket"\n'
                       '[[frames]]\npath = "b/2.tif"\nrole = "bracket"\nexposure = 0.5')
    assert s.problems == ()
    fits, tif, given = s.frames
    assert (fits.exposure, fits.gain, fits.temperature) == (0.125, 1.5, -12.5)
    assert fits.inferred == ("exposure", "gain", "temperature")
    assert (tif.exposure, tif.inferred) == (0.01, ("exposure",))
    assert (given.exposure, given.inferred) == (0.5, ())


def test_iter_frames_is_lazy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    root = tmp_path / "s"
    for i in range(4):
        put(root, f"dark/d{i}.tif", i)
    s = manifest(root, '[[groups]]\nglob = "dark/*.tif"\nrole = "dark"')
    assert s.ok
    calls: list[Path] = []

    def counting_read(path):
        calls.append(Path(path))
        return read_image(path)

    monkeypatch.setattr(session_mod, "read_image", counting_read)
    it = s.iter_frames()
    assert inspect.isgenerator(it) and calls == []
    rec, data = next(it)
    assert calls == [s.frames[0].path] and rec is s.frames[0]
    np.testing.assert_array_equal(data, frame(0))
    # a later frame is read only when reached: deleting it now fails only at that step
    s.frames[2].path.unlink()
    rec, data = next(it)
    np.testing.assert_array_equal(data, frame(1))
    with pytest.raises(ImageReadError, match="d2.tif"):
        next(it)
    assert len(calls) == 3
    # a subset, in the given order
    assert [r.relpath for r, _ in s.iter_frames([s.frames[3], s.frames[0]])] == [
        "dark/d3.tif", "dark/d0.tif"]


def test_headers_are_read_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    root = tmp_path / "s"
    put(root, "a.tif")
    put(root, "b.tif")
    s = manifest(root, '[[groups]]\nglob = "*.tif"\nrole = "dark"')
    calls: list[Path] = []
    monkeypatch.setattr(session_mod, "read_header", lambda p: calls.append(p))
    for _ in range(3):
        assert s.header(s.frames[0]).shape == (H, W)
        s.frames_table()
        s.groups_table()
    assert calls == []  # every header came from the cache filled while validating


# --------------------------------------------------------------------------------------------
# plain folders and drafts
# --------------------------------------------------------------------------------------------
@pytest.fixture
def plain_folder(tmp_path: Path) -> Path:
    root = tmp_path / "capture"
    for i in range(2):
        put(root, f"Darks/d{i}.fits", i, exposure=0.5)
        put(root, f"bias/b{i}.tif", 10 + i)
        put(root, f"flats/f{i}.tif", 20 + i, exposure=0.02)
        put(root, f"ptc/L03/{i}.tif", 30 + i, exposure=0.001)
        put(root, f"ptc/L10/{i}.tif", 40 + i, exposure=0.004)
        put(root, f"bracket/e{i}.tif", 50 + i, exposure=0.01 * (i + 1))
        for config in (1, 2):  # config from the first number of the file name
            put(root, f"FPN/C{config:02d}_F{i:02d}.tif", 70 + 10 * config + i)
    put(root, "misc/pic.tif", 60)
    put(root, "top.png", 61, dtype=np.uint8)
    (root / "notes.txt").write_text("not an image")
    (root / ".hidden").mkdir()
    put(root, ".hidden/skip.tif")
    return root


def test_plain_folder_infers_roles_and_exposures(plain_folder: Path) -> None:
    s = open_session(plain_folder)
    assert s.source == "folder" and s.manifest_path is None
    assert s.roles() == {"dark": 4, "ptc": 4, "fixed_pattern": 4, "flat": 2, "bracket": 2,
                         "scene": 2}
    assert [r.relpath for r in s.frames] == sorted(r.relpath for r in s.frames)
    by_path = {r.relpath: r for r in s.frames}
    assert (by_path["Darks/d0.fits"].role, by_path["Darks/d0.fits"].exposure) == ("dark", 0.5)
    assert by_path["Darks/d0.fits"].inferred == ("role", "exposure")
    assert (by_path["bias/b0.tif"].role, by_path["bias/b0.tif"].exposure) == ("dark", None)
    assert by_path["bias/b0.tif"].inferred == ("role",)
    assert (by_path["misc/pic.tif"].role, by_path["top.png"].role) == ("scene", "scene")
    # ptc levels from the sub-folder numbers
    assert {k: [r.relpath for r in v] for k, v in s.ptc_levels().items()} == {
        3: ["ptc/L03/0.tif", "ptc/L03/1.tif"], 10: ["ptc/L10/0.tif", "ptc/L10/1.tif"]}
    assert by_path["ptc/L10/1.tif"].inferred == ("role", "level", "exposure")
    assert {k: [r.relpath for r in v] for k, v in s.fixed_pattern_configs().items()} == {
        1: ["FPN/C01_F00.tif", "FPN/C01_F01.tif"], 2: ["FPN/C02_F00.tif", "FPN/C02_F01.tif"]}
    assert by_path["FPN/C02_F01.tif"].inferred == ("role", "config")
    assert s.camera.bits == 16 and s.camera.layout == "mono"
    # the only problem: a warning summarising the inference
    (warning,) = s.problems
    assert warning.severity == "warning" and warning.where == str(plain_folder.resolve())
    assert ("roles inferred from folder names (dark: 4, ptc: 4, fixed_pattern: 4, flat: 2, "
            "bracket: 2, scene: 2)") in warning.message
    assert "exposures from file headers for 10 of 18 frames" in warning.message
    assert s.ok


def test_draft_manifest_round_trip(plain_folder: Path) -> None:
    s = open_session(plain_folder)
    draft = draft_manifest(s)
    assert draft == plain_folder.resolve() / "session.toml.draft"
    assert "# inferred: role, level, exposure" in draft.read_text()
    draft.rename(plain_folder / "session.toml")
    again = open_session(plain_folder)
    assert again.source == "manifest" and again.problems == ()
    assert again.camera == s.camera

    def strip(rec: FrameRecord) -> FrameRecord:
        return dataclasses.replace(rec, inferred=())

    assert [strip(r) for r in again.frames] == [strip(r) for r in s.frames]
    # metadata written out by the draft is explicit now: nothing left to infer from folders
    assert all("role" not in r.inferred for r in again.frames)
    assert again.to_toml().count("[[frames]]") == len(s.frames)


def test_draft_never_overwrites_a_session_toml(full_session: Path) -> None:
    s = open_session(full_session)
    before = (full_session / "session.toml").read_bytes()
    with pytest.raises(CcdError, match="already exists"):
        draft_manifest(s, full_session / "session.toml")
    with pytest.raises(CcdError, match="session folder"):
        draft_manifest(s, full_session.parent / "elsewhere.toml")
    draft = draft_manifest(s)
    assert draft.name == "session.toml.draft"
    assert (full_session / "session.toml").read_bytes() == before
    assert [p.name for p in full_session.iterdir() if p.name.startswith(".")] == []  # atomic
    assert draft.read_text().count("[[frames]]") == len(s.frames)


def test_empty_folder_is_an_error_not_an_exception(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    s = open_session(tmp_path / "empty")
    assert not s.ok and s.frames == ()
    assert s.problems[0].message.startswith("no image files found")


def test_format_size():
    assert format_size((192, 256)) == "256 × 192"
    assert format_size((4, 6, 3), "x") == "6x4x3"
    assert format_size(None) == "?"


@pytest.mark.parametrize("read_ahead", [1, 3])
def test_iter_frames_reading_ahead_keeps_order_and_errors_in_place(tmp_path: Path,
                                                                   read_ahead: int) -> None:
    """Frames decoded ahead in threads come out in session order, equal to the plain reads; a
    frame that cannot be read raises when it is reached, after the frames before it."""
    root = tmp_path / "s"
    for i in range(6):
        put(root, f"dark/d{i}.tif", i)
    s = manifest(root, '[[groups]]\nglob = "dark/*.tif"\nrole = "dark"')
    plain = [(r.relpath, d.tobytes()) for r, d in s.iter_frames()]
    ahead = [(r.relpath, d.tobytes()) for r, d in s.iter_frames(read_ahead=read_ahead)]
    assert ahead == plain
    s.frames[4].path.write_bytes(b"not an image")
    seen = []
    with pytest.raises(ImageReadError, match="d4.tif"):
        for rec, _ in s.iter_frames(read_ahead=read_ahead):
            seen.append(rec.relpath)
    assert seen == [f"dark/d{i}.tif" for i in range(4)]
    it = s.iter_frames(s.frames[:3], read_ahead=read_ahead)   # stopped early: no error, no hang
    assert next(it)[0] is s.frames[0]
    it.close()
