"""Edge and boundary pins of the session readers, the records, the image I/O and the channels
(the folder inference, assembly, output safety, product file and app cache are in
tests/test_edges_session_io2.py).

What this file pins (each expectation from the documented contract, derived by hand):

* manifest metadata values exactly at their documented limits (exposure 0, 1 ns and 1e6 s,
  photons 0, roi origin 0 and size 1, camera bits 1 and 32, black level 0) and just beyond;
* the nesting bound of a manifest's text (MAX_NESTING levels read, one more refused);
* ``Session.check_codes`` at the code ``2**bits - 1`` / ``2**bits`` boundary and for the
  containers it must not check;
* EMVA1288 descriptor fields at their range ends and the malformed lines still unexercised;
* the record selections (gain matching, several gains, settings, brackets sorted by exposure);
* FITS sample types of BZERO/BSCALE (FITS 4.0 sec. 4.4.2), header values (exposure forms,
  one-line messages), OpenImageIO header fields;
* a camera raw region (cropping ``[y:y+h, x:x+w]`` of the decoded mosaic), region bounds and
  the pixel limit of the whole strips / tiles a region read decodes;
* the session's content hash rebuilt from its documented byte stream, the groups table;
* channel layouts by shape, channel views, bilinear demosaicing at one site by hand.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from astropy.io import fits

from ccdcore.channels import Layout, check_layout, demosaic_bilinear, split_channels
from ccdcore.errors import CcdError, ImageReadError
from ccdcore.io.base import (ImageHeader, exposure_seconds, float_or_none, int_or, is_image_path,
                             one_line)
from ccdcore.io.fits import _fits_dtype, _scaled, fits_temperature
from ccdcore.io.frames import _raw_pattern, read_header, read_image, read_region, write_image
from ccdcore.io.oiio import header_from_spec
from ccdcore.io.outputs import RECORD, check_output, read_record
from ccdcore.session import _is_emva_descriptor, open_session
from ccdcore.session.emva import _count, _LineError, _number, open_emva_descriptor
from ccdcore.session.manifest import MAX_NESTING, _check_value, _parse_camera, bound_problem
from ccdcore.session.records import (MAX_EXPOSURE, MIN_EXPOSURE, Camera, FrameRecord, Problem,
                                     Session)

H, W = 6, 8


def _frame(seed: int, shape: tuple[int, ...] = (H, W), top: int = 256) -> np.ndarray:
    """A small deterministic uint16 frame with values below ``top``."""
    return np.random.default_rng(seed).integers(0, top, shape).astype(np.uint16)


def _session(bits: int | None, frames: tuple[FrameRecord, ...] = ()) -> Session:
    """A bare in-memory session of a camera of ``bits`` (no files needed)."""
    return Session(root=Path("."), manifest_path=None, source="manifest",
                   camera=Camera(bits=bits), frames=frames)


def _rec(relpath: str, role: str, **meta: object) -> FrameRecord:
    return FrameRecord(path=Path(relpath), relpath=relpath, role=role, **meta)  # type: ignore


# ---- manifest values at their limits -----------------------------------------------------------
@pytest.mark.parametrize("value", [0, 0.0, MIN_EXPOSURE, 1.0, MAX_EXPOSURE, 1])
def test_exposure_accepted_at_zero_and_at_both_ends(value: float) -> None:
    """exposure is 0 or within [1e-9, 1e6] s, both ends included (records.MIN/MAX_EXPOSURE)."""
    got, why = _check_value("exposure", value)
    assert why is None and got == float(value) and isinstance(got, float)


@pytest.mark.parametrize("value", [MIN_EXPOSURE * 0.5, MAX_EXPOSURE * (1 + 1e-12), -MIN_EXPOSURE,
                                   -1.0, math.inf, math.nan, True, "1"])
def test_exposure_refused_just_outside(value: object) -> None:
    """Half a nanosecond, just over 1e6 s, negatives, inf, nan, bool and text are refused."""
    got, why = _check_value("exposure", value)
    assert got is None and why is not None and "'exposure' must be 0 or from" in why


def test_photons_accept_zero_and_refuse_negative_and_infinite() -> None:
    """photons is a finite number >= 0: 0 is a dark point's count; -tiny, inf and nan are not."""
    assert _check_value("photons", 0) == (0.0, None)
    assert _check_value("photons", 12.5) == (12.5, None)
    for bad in (-1e-12, math.inf, -math.inf, math.nan, False):
        got, why = _check_value("photons", bad)
        assert got is None and "photons" in why


def test_roi_origin_zero_and_unit_size_are_valid() -> None:
    """roi = [x, y, w, h]: x, y >= 0 and w, h > 0 (docstring), so [0, 0, 1, 1] is the smallest."""
    assert _check_value("roi", [0, 0, 1, 1]) == ((0, 0, 1, 1), None)
    for bad in ([-1, 0, 1, 1], [0, -1, 1, 1], [0, 0, 0, 1], [0, 0, 1, 0], [0, 0, 1],
                [0, 0, 1, 1, 1], [0, 0, 1.0, 1], (0, 0, 1, 1), [True, 0, 1, 1]):
        got, why = _check_value("roi", bad)
        assert got is None and why.startswith("'roi' must be"), bad


def test_level_and_config_need_true_integers() -> None:
    """level/config are integers: bool and integral floats are refused, 0 and negatives kept."""
    assert _check_value("level", 0) == (0, None)
    assert _check_value("config", -3) == (-3, None)
    for key in ("level", "config"):
        for bad in (True, 1.0, "1"):
            assert _check_value(key, bad)[0] is None


def test_gain_and_temperature_are_finite_numbers() -> None:
    """gain/temperature: any finite number (negative temperatures are real), never inf/nan."""
    assert _check_value("temperature", -20) == (-20.0, None)
    assert _check_value("gain", 0) == (0.0, None)
    for bad in (math.inf, math.nan, -math.inf, True, "2"):
        assert _check_value("gain", bad)[0] is None
        assert _check_value("temperature", bad)[0] is None


def test_flags_are_deduplicated_in_order_and_unknown_refused() -> None:
    """flags: a list of known flags, repeats collapsed; an unknown flag refuses the list."""
    assert _check_value("flags", ["max-intensity", "max-intensity"]) == (("max-intensity",), None)
    assert _check_value("flags", []) == ((), None)
    assert _check_value("flags", ["max-intensity", "other"])[0] is None
    assert _check_value("flags", "max-intensity")[0] is None


def test_setting_stack_and_note_types() -> None:
    """setting/patch are names, stack an int or string, note a string."""
    assert _check_value("setting", "NZDI+1.a_b-c") == ("NZDI+1.a_b-c", None)
    assert _check_value("setting", "two words")[0] is None
    assert _check_value("patch", "")[0] is None
    assert _check_value("stack", 0) == (0, None)
    assert _check_value("stack", "s1") == ("s1", None)
    assert _check_value("stack", 1.5)[0] is None
    assert _check_value("note", 3) == (None, "'note' must be a string")


@pytest.mark.parametrize("bits,ok", [(1, True), (32, True), (0, False), (33, False),
                                     (12.0, False), (True, False)])
def test_camera_bits_range_is_one_to_thirty_two_inclusive(bits: object, ok: bool) -> None:
    """[camera] bits: an integer from 1 to 32 (both ends); else an error and bits unknown."""
    problems: list = []
    cam = _parse_camera({"camera": {"bits": bits}}, problems)
    if ok:
        assert cam.bits == bits and not problems
    else:
        assert cam.bits is None and [p.where for p in problems] == ["camera.bits"]
        assert problems[0].severity == "error"


@pytest.mark.parametrize("level,ok", [(0, True), (0.0, True), (64.5, True), (-0.5, False),
                                      (math.inf, False), ("0", False)])
def test_camera_black_level_is_a_number_at_least_zero(level: object, ok: bool) -> None:
    """[camera] black_level: a finite number >= 0 DN (0 is a valid offset)."""
    problems: list = []
    cam = _parse_camera({"camera": {"black_level": level}}, problems)
    if ok:
        assert cam.black_level == float(level) and not problems
    else:
        assert cam.black_level is None and [p.where for p in problems] == ["camera.black_level"]


def test_camera_table_defaults_and_errors() -> None:
    """No [camera]: a warning and a mono camera; a non-table: an error; a bad name or layout:
    an error each and the defaults kept; an unknown key: a warning."""
    problems: list = []
    assert _parse_camera({}, problems) == Camera() and problems[0].severity == "warning"
    problems = []
    assert _parse_camera({"camera": "mono"}, problems) == Camera()
    assert problems[0].severity == "error"
    problems = []
    cam = _parse_camera({"camera": {"name": 3, "layout": "bayer-xxxx", "lens": "50mm"}},
                        problems)
    assert (cam.name, cam.layout) == ("", "mono")
    assert sorted((p.where, p.severity) for p in problems) == [
        ("camera.layout", "error"), ("camera.lens", "warning"), ("camera.name", "error")]


def test_nesting_bound_reads_the_limit_and_refuses_one_more() -> None:
    """Arrays nested MAX_NESTING deep are read; MAX_NESTING + 1 levels are refused."""
    ok = "a = " + "[" * MAX_NESTING + "1" + "]" * MAX_NESTING + "\n"
    deep = "a = " + "[" * (MAX_NESTING + 1) + "1" + "]" * (MAX_NESTING + 1) + "\n"
    assert bound_problem(ok) is None
    assert "nested too deeply" in bound_problem(deep)
    # closing brackets bring the depth back: many shallow arrays in a row are fine
    assert bound_problem(("b = [[1]]\n" * (MAX_NESTING + 5))) is None
    # inline tables count as nesting too
    assert bound_problem("t = " + "{a = " * (MAX_NESTING + 1) + "1" + "}" * (MAX_NESTING + 1)) \
        is not None


# ---- Session.check_codes: values beyond [camera] bits ------------------------------------------
@pytest.mark.parametrize("bits,dtype", [(8, np.uint16), (12, np.uint16), (12, np.int16),
                                        (1, np.uint8), (31, np.uint32)])
def test_check_codes_boundary_is_two_to_the_bits(bits: int, dtype: type) -> None:
    """Codes 0 .. 2**bits - 1 pass; the value 2**bits is refused, naming the camera's bits."""
    session = _session(bits)
    rec = _rec("f.tif", "dark")
    top = (1 << bits) - 1
    ok = np.array([[0, top], [top // 2, 1]], dtype=dtype)
    assert session.check_codes(rec, ok) is ok
    bad = ok.copy()
    bad[1, 0] = top + 1
    with pytest.raises(CcdError, match=rf"holds value {top + 1}, beyond camera\.bits = {bits} "
                                       rf"\(codes 0\.\.{top}\)"):
        session.check_codes(rec, bad)


def test_check_codes_skips_what_it_cannot_judge() -> None:
    """Unknown bits, float data, containers no wider than bits and empty frames pass as is."""
    rec = _rec("f.tif", "dark")
    big16 = np.array([[65535]], dtype=np.uint16)
    assert _session(None).check_codes(rec, big16) is big16
    assert _session(16).check_codes(rec, big16) is big16          # 16-bit container, 16 bits
    assert _session(8).check_codes(rec, np.array([[255]], np.uint8)) is not None
    floats = np.array([[1e6]], dtype=np.float32)
    assert _session(8).check_codes(rec, floats) is floats
    empty = np.zeros((0, 3), dtype=np.uint16)
    assert _session(8).check_codes(rec, empty) is empty


def test_verify_pixels_lists_bit_depth_and_skips_unreadable_headers(tmp_path: Path) -> None:
    """verify_pixels adds one bit-depth problem per offending frame (not for in-range frames)."""
    root = tmp_path / "s"
    write_image(root / "a.tif", np.full((H, W), 255, np.uint16))
    write_image(root / "b.tif", np.full((H, W), 256, np.uint16))
    write_image(root / "c.tif", np.full((H, W), 100, np.uint16))
    (root / "session.toml").write_text(
        "schema = 1\n[camera]\nbits = 8\n"
        + "".join(f'[[frames]]\npath = "{n}.tif"\nrole = "dark"\n' for n in "abcd"))
    (root / "d.tif").write_bytes(b"II*\0 not a TIFF at all" * 4)   # its header cannot be read
    session = open_session(root)
    before = [(p.where, p.code) for p in session.errors]
    assert [where for where, _ in before] == ["d.tif"] and "d.tif" in [r.relpath for r in
                                                                     session.frames]
    checked = session.verify_pixels()        # d.tif is not reported a second time
    assert [(p.where, p.code) for p in checked.errors] == before + [("b.tif", "bit-depth")]


# ---- record selections -------------------------------------------------------------------------
def test_select_matches_gain_with_tolerance_and_frames_without_gain() -> None:
    """select(gain=g): frames of gain g (isclose) or without a gain; setting filters exactly."""
    frames = (_rec("a", "flat", gain=2.0, setting="ZDI"), _rec("b", "flat", gain=2.0 + 1e-12),
              _rec("c", "flat", gain=4.0), _rec("d", "flat"), _rec("e", "dark", gain=2.0))
    s = _session(12, frames)
    assert [r.relpath for r in s.select("flat", gain=2.0)] == ["a", "b", "d"]
    assert [r.relpath for r in s.select("flat", gain=4.0)] == ["c", "d"]
    assert [r.relpath for r in s.select("flat", setting="ZDI")] == ["a"]
    assert [r.relpath for r in s.select("flat")] == ["a", "b", "c", "d"]


def test_flat_groups_refuse_several_gains_unless_one_is_chosen() -> None:
    """flat_groups: two distinct gains without gain= raise; one gain (plus gainless) does not."""
    frames = (_rec("a", "flat", gain=1.0, level=1, exposure=0.1),
              _rec("b", "flat", gain=2.0, level=1, exposure=0.1),
              _rec("c", "flat", level=2, exposure=0.2))
    s = _session(12, frames)
    with pytest.raises(CcdError, match=r"several gains \[1\.0, 2\.0\]: pass gain="):
        s.flat_groups()
    groups = s.flat_groups(gain=2.0)
    assert {k: [r.relpath for r in v] for k, v in groups.items()} == {(1, 0.1): ["b"],
                                                                       (2, 0.2): ["c"]}
    single = _session(12, frames[:1] + frames[2:])
    assert list(single.flat_groups()) == [(1, 0.1), (2, 0.2)]
    # gains equal within isclose are one gain once chosen: no error
    near = _session(12, (_rec("a", "flat", gain=2.0), _rec("b", "flat", gain=2.0 + 1e-12)))
    assert [r.relpath for v in near.flat_groups(gain=2.0).values() for r in v] == ["a", "b"]


def test_resolve_setting_picks_the_first_and_names_the_others() -> None:
    """resolve_setting(None): the first setting, noted only when there are several."""
    one = _session(8, (_rec("a", "dark", setting="NZDI"), _rec("b", "dark", setting="NZDI")))
    assert one.resolve_setting(None) == ("NZDI", [])
    two = _session(8, (_rec("a", "dark", setting="ZDI"), _rec("b", "dark", setting="NZDI")))
    chosen, notes = two.resolve_setting(None)
    assert chosen == "ZDI" and len(notes) == 1 and "ZDI, NZDI" in notes[0]
    assert two.resolve_setting("NZDI") == ("NZDI", [])
    assert _session(8, (_rec("a", "dark"),)).resolve_setting(None) == (None, [])
    with pytest.raises(CcdError, match="names no settings"):
        _session(8, (_rec("a", "dark"),)).resolve_setting("ZDI")
    with pytest.raises(CcdError, match="the session has ZDI, NZDI"):
        two.resolve_setting("X")


def test_bracket_stacks_sorted_by_exposure_with_unknown_last() -> None:
    """bracket_stacks: frames of each stack sorted by exposure, an unknown exposure last."""
    frames = (_rec("a", "bracket", exposure=0.4, stack=1), _rec("b", "bracket", stack=1),
              _rec("c", "bracket", exposure=0.1, stack=1), _rec("d", "bracket", exposure=0.2))
    stacks = _session(8, frames).bracket_stacks()
    assert {k: [r.relpath for r in v] for k, v in stacks.items()} == {1: ["c", "a", "b"],
                                                                      None: ["d"]}
    with pytest.raises(CcdError):
        _session(8, frames).bracket_stacks("dark")


def test_scene_patches_by_patch_then_roi_without_max_intensity() -> None:
    """scene_patches: keyed by patch, else "roi=x,y,w,h"; max-intensity and plain scenes out."""
    frames = (_rec("a", "scene", roi=(0, 1, 2, 3)), _rec("b", "scene", patch="grey"),
              _rec("c", "scene", patch="grey", flags=("max-intensity",)),
              _rec("d", "scene"), _rec("e", "scene", roi=(0, 1, 2, 3), patch="white"))
    s = _session(8, frames)
    assert {k: [r.relpath for r in v] for k, v in s.scene_patches().items()} == {
        "roi=0,1,2,3": ["a"], "grey": ["b"], "white": ["e"]}
    assert s.max_intensity_frame().relpath == "c"
    later = _rec("f", "scene", flags=("max-intensity",))
    assert _session(8, frames + (later,)).max_intensity_frame().relpath == "c"   # the first
    assert _session(8, (_rec("g", "dark", flags=("max-intensity",)),)).max_intensity_frame() \
        is None                                                                  # scenes only
    assert _session(8, frames[:2]).max_intensity_frame() is None


# ---- EMVA1288 descriptors ----------------------------------------------------------------------
def test_emva_numbers_are_finite_and_at_least_zero() -> None:
    """Descriptor numbers: >= 0 and finite (0 ns is a valid exposure), decimal comma read."""
    assert _number("0", "x") == 0.0
    assert _number("1,5", "x") == 1.5
    for bad in ("-1e-9", "inf", "nan", "-0.5", "1.2.3", "abc"):
        with pytest.raises(_LineError):
            _number(bad, "x")


@pytest.mark.parametrize("text,low,high,ok", [("1", 1, 32, True), ("32", 1, 32, True),
                                              ("0", 1, 32, False), ("33", 1, 32, False),
                                              ("1048576", 1, 2**20, True),
                                              ("1048577", 1, 2**20, False),
                                              ("12.0", 1, 32, False), ("x", 1, 32, False)])
def test_emva_counts_are_integers_in_a_closed_range(text: str, low: int, high: int,
                                                    ok: bool) -> None:
    """n-line fields: integers from low to high, both ends included."""
    if ok:
        assert _count(text, "bits", low, high) == int(text)
    else:
        with pytest.raises(_LineError, match="bits"):
            _count(text, "bits", low, high)


def _emva_root(tmp_path: Path) -> Path:
    root = tmp_path / "e"
    for i in range(4):
        write_image(root / "img" / f"i{i}.tif", _frame(i))
    return root


def test_emva_malformed_lines_are_problems_with_their_line(tmp_path: Path) -> None:
    """Each malformed line is one problem naming its line; good points still import, the
    exposure converted from ns to s and the bit depth and size from the first n line."""
    root = _emva_root(tmp_path)
    desc = root / "d.txt"
    desc.write_text(f"v 4.0\nv\nn 10 {W} {H}\nn 12 {W} {H}\nn 12 {W}\n"
                    "b 0 0\ni img/i0.tif\ni img/i1.tif\n"
                    "d 250 1\nd 2500\ni img/i2.tif\ni img/i3.tif extra\ni img/i3.tif\n")
    s = open_session(desc)
    assert [(p.where, p.message) for p in s.problems] == [
        ("d.txt line 2", "should be 'v <version>'"),
        ("d.txt line 4", "a second 'n' line (only one is allowed)"),
        ("d.txt line 5", "should be 'n <bits> <width> <height>'"),
        ("d.txt line 9", "should be 'd <exposure_ns>'"),
        ("d.txt line 12", "should be 'i <relative path>'")]
    assert s.camera.bits == 10
    (level,) = s.ptc_levels().values()
    assert [(r.exposure, r.photons) for r in level] == [(0.0, 0.0), (0.0, 0.0)]
    assert [(r.relpath, r.exposure) for r in s.dark_frames()] == [("img/i2.tif", 2.5e-6),
                                                                   ("img/i3.tif", 2.5e-6)]


def test_emva_bad_n_fields_leave_bits_unknown_and_skip_the_size_check(tmp_path: Path) -> None:
    """An n line with bits 0 is a problem; without a valid n line the size is not compared."""
    root = _emva_root(tmp_path)
    desc = root / "d.txt"
    desc.write_text("v 4.0\nn 0 8 6\nb 1000 5\ni img/i0.tif\ni img/i1.tif\n")
    s = open_session(desc)
    assert s.camera.bits is None
    assert [p.message for p in s.problems] == [
        "bits must be an integer from 1 to 32, got 0", "no 'n <bits> <width> <height>' line"]


def test_emva_size_check_skips_unreadable_images(tmp_path: Path) -> None:
    """An image whose header cannot be read is reported once, not also as of the wrong size;
    an image of transposed size (W x H swapped) is a size problem."""
    root = _emva_root(tmp_path)
    write_image(root / "img" / "t.tif", _frame(9, (W, H)))
    (root / "img" / "bad.tif").write_bytes(b"II*\0 broken" * 8)
    desc = root / "d.txt"
    desc.write_text(f"v 4.0\nn 12 {W} {H}\nb 1000 5\ni img/i0.tif\ni img/bad.tif\n"
                    "d 1000\ni img/t.tif\ni img/i1.tif\n")
    s = open_session(desc)
    size = [p for p in s.problems if p.code == "descriptor-size"]
    assert [(p.where, p.message) for p in size] == [
        ("img/t.tif", f"image is {H}x{W} but the descriptor's n line says {W}x{H}")]
    assert [p.where for p in s.problems].count("img/bad.tif") == 1


def test_emva_descriptor_size_limit_and_sniffing_bound(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """A descriptor larger than MAX_DESCRIPTOR_BYTES is refused (one of exactly that size is
    read); sniffing reads at most that many bytes looking for the v line (the v line itself
    counted), and a file of comments only is no descriptor."""
    import ccdcore.session.emva as emva_mod
    root = _emva_root(tmp_path)
    desc = root / "d.txt"
    text = f"# c\nv 4.0\nn 12 {W} {H}\nb 1000 5\ni img/i0.tif\ni img/i1.tif\n"
    desc.write_text(text)
    size = len(text.encode())
    monkeypatch.setattr(emva_mod, "MAX_DESCRIPTOR_BYTES", size)
    assert open_emva_descriptor(desc).ok
    head = len("# c\nv 4.0\n")
    monkeypatch.setattr(emva_mod, "MAX_DESCRIPTOR_BYTES", head)
    assert _is_emva_descriptor(desc)
    monkeypatch.setattr(emva_mod, "MAX_DESCRIPTOR_BYTES", head - 1)
    assert not _is_emva_descriptor(desc)
    monkeypatch.setattr(emva_mod, "MAX_DESCRIPTOR_BYTES", size - 1)
    with pytest.raises(CcdError, match="larger than any EMVA1288 descriptor"):
        open_emva_descriptor(desc)
    monkeypatch.undo()
    only = root / "c.txt"
    only.write_text("# one\n\n# two\n")
    assert not _is_emva_descriptor(only)
    assert not _is_emva_descriptor(root / "absent.txt")
    (root / "n.txt").write_text("n 12 8 6\nv 4.0\n")
    assert not _is_emva_descriptor(root / "n.txt")
    with pytest.raises(CcdError, match="cannot read the EMVA1288 descriptor"):
        open_emva_descriptor(root / "absent.txt")


def test_emva_n_line_sizes_up_to_two_to_the_twenty(tmp_path: Path) -> None:
    """n-line width and height run from 1 to 2**20 (both ends read); 2**20 + 1 is a problem."""
    root = _emva_root(tmp_path)
    for n_line, problem in ((f"n 32 {2**20} 1", None),
                            (f"n 12 8 {2**20 + 1}",
                             f"height must be an integer from 1 to {2**20}, got {2**20 + 1}")):
        desc = root / "d.txt"
        desc.write_text(f"v 4.0\n{n_line}\nb 1000 5\ni img/i0.tif\ni img/i1.tif\n")
        s = open_session(desc)
        lines = [p.message for p in s.problems if p.code == "descriptor-line"]
        no_n = "no 'n <bits> <width> <height>' line"
        assert lines == ([] if problem is None else [problem, no_n])
        if problem is None:
            assert s.camera.bits == 32
            assert {p.message for p in s.problems if p.code == "descriptor-size"} == {
                f"image is {W}x{H} but the descriptor's n line says {2**20}x1"}


# ---- FITS sample types and regions -------------------------------------------------------------
@pytest.mark.parametrize("bitpix,bzero,bscale,dtype", [
    (16, 2.0**15, 1, "uint16"), (32, 2.0**31, 1, "uint32"), (8, -128.0, 1, "int8"),
    (8, 0, 1, "uint8"), (16, 0, 1, "int16"), (64, 0, 1, "int64"), (-32, 0, 1, "float32"),
    (-64, 0, 1, "float64"),
    (8, 128.0, 1, "float32"),          # an offset that is no unsigned convention: floats
    (16, 2.0**15, 2, "float32"),       # 32768 + 2 * 65536 fits float32
    (16, 0, 0.5, "float32"), (32, 0, 0.5, "float64"), (64, 0, 2, "float64"),
    (-32, 0, 0.5, "float32"),          # 0.5 * 3.4e38 = 1.7e38 <= 3e38
    (-32, 0, 2, "float64"),            # 2 * 3.4e38 > 3e38: beyond float32
    (-32, 2.9e38, 0.0001, "float32"),  # reach 2.9e38 + 3.4e34 < 3e38
    (-32, 3.1e38, 0.0001, "float64"),  # reach > 3e38
    (16, 1e39, 1, "float64"),
    (16, 0, 6.5e33, "float64"),        # 6.5e33 * 2**16 = 4.3e38 > 3e38 (2**15 would not be)
    (-32, -3.1e38, 0.0001, "float64")])  # |BZERO| counts: a negative offset reaches far too
def test_fits_sample_type_of_the_physical_values(bitpix: int, bzero: float, bscale: float,
                                                 dtype: str) -> None:
    """FITS 4.0 sec. 4.4.2 conventions: BZERO 2^15 / 2^31 on signed words and -128 on bytes are
    the unsigned (signed) integer types; any other scaling is float32 while
    |BZERO| + |BSCALE| * range <= 3e38 (float32's reach) for 8/16-bit and float32 data, else
    float64 (and always float64 for 32/64-bit words)."""
    header = {"BITPIX": bitpix, "BZERO": bzero, "BSCALE": bscale}
    assert _fits_dtype(header) == np.dtype(dtype)


@pytest.mark.parametrize("header", [{"BITPIX": 12}, {"BITPIX": 16, "BSCALE": 0},
                                    {"BITPIX": 16, "BZERO": math.inf},
                                    {"BITPIX": 16, "BSCALE": math.nan},
                                    {"BITPIX": 16, "BZERO": "x"}])
def test_fits_sample_type_refuses_no_scaling_and_unknown_bitpix(header: dict) -> None:
    """BITPIX outside the FITS table, BSCALE 0 and non-finite scalings are read errors."""
    with pytest.raises(ImageReadError):
        _fits_dtype(header, Path("f.fits"))


def test_fits_scaled_values_follow_the_formula() -> None:
    """_scaled: BZERO + BSCALE * stored exactly, integer offsets in integers (no float loss)."""
    raw = np.array([[-128, 127], [0, 1]], dtype=np.int8)
    got = _scaled(raw, {"BZERO": 2**40 + 1, "BSCALE": 1}, np.dtype("int64"))
    np.testing.assert_array_equal(got, raw.astype(np.int64) + 2**40 + 1)
    got = _scaled(raw.astype(np.int16), {"BZERO": 3.0, "BSCALE": 0.5}, np.dtype("float64"))
    np.testing.assert_array_equal(got, raw * 0.5 + 3.0)
    got = _scaled(raw, {"BZERO": -1.5, "BSCALE": 1}, np.dtype("float32"))
    np.testing.assert_array_equal(got, raw - 1.5)
    got = _scaled(raw, {"BZERO": 1e20, "BSCALE": 1}, np.dtype("float64"))  # beyond int64
    np.testing.assert_array_equal(got, raw.astype(np.float64) + 1e20)


def test_fits_region_of_a_cube_and_of_a_non_square_frame(tmp_path: Path) -> None:
    """read_region of FITS equals the numpy slice [y:y+h, x:x+w] of the whole frame, for a
    non-square unsigned 16-bit frame and a 3-channel (C, H, W) cube read as (H, W, C)."""
    rng = np.random.default_rng(4)
    mono = rng.integers(0, 65536, (5, 9)).astype(np.uint16)
    hdu = fits.PrimaryHDU((mono.astype(np.int32) - 32768).astype(np.int16))
    hdu.header["BZERO"], hdu.header["BSCALE"] = 32768, 1
    hdu.writeto(tmp_path / "m.fits")
    np.testing.assert_array_equal(read_image(tmp_path / "m.fits"), mono)
    np.testing.assert_array_equal(read_region(tmp_path / "m.fits", 2, 1, 6, 3), mono[1:4, 2:8])
    cube = rng.integers(0, 1000, (3, 4, 6)).astype(np.int16)     # C, H, W
    fits.PrimaryHDU(cube).writeto(tmp_path / "c.fits")
    hdr = read_header(tmp_path / "c.fits")
    assert (hdr.width, hdr.height, hdr.channels) == (6, 4, 3)
    hwc = np.moveaxis(cube, 0, -1)
    np.testing.assert_array_equal(read_image(tmp_path / "c.fits"), hwc)
    np.testing.assert_array_equal(read_region(tmp_path / "c.fits", 1, 2, 4, 2), hwc[2:4, 1:5])


def test_fits_temperature_prefers_the_set_point() -> None:
    """SET-TEMP first, then CCD-TEMP, then CCDTEMP; none: None (a non-number is skipped)."""
    assert fits_temperature({"SET-TEMP": -10.0, "CCD-TEMP": -9.5, "CCDTEMP": 1}) == -10.0
    assert fits_temperature({"CCD-TEMP": -9.5, "CCDTEMP": 1}) == -9.5
    assert fits_temperature({"CCDTEMP": 1}) == 1.0
    assert fits_temperature({"SET-TEMP": "cold", "CCDTEMP": 2}) == 2.0
    assert fits_temperature({}) is None


# ---- header values (ccdcore.io.base) -----------------------------------------------------------
@pytest.mark.parametrize("value,expected", [
    (np.float32(1 / 60), 1 / 60),     # EXIF RATIONAL through float32: the camera's fraction
    (np.float32(1 / 3), 1 / 3), (np.float32(0.01), 0.01), (np.float32(0.004), 0.004),
    (0, 0.0), (2, 2.0), ((1, 250), 0.004), ([3, 2], 1.5), ("1/250 s", 0.004), ("0.5 sec", 0.5),
    (" 2 ", 2.0), ("1/4s", 0.25), ("0", 0.0), ("2 secs", 2.0)])
def test_exposure_seconds_reads_header_forms(value: object, expected: float) -> None:
    """exposure_seconds: numbers (float32 EXIF as their rational), (num, den) pairs and text
    "1/250 s" give seconds; 0 is a valid (bias) exposure."""
    assert exposure_seconds(value) == expected


@pytest.mark.parametrize("value", [-0.001, (1, 0), (None, 2), (-1, 250), "1/0", "-1/250",
                                   "fast", True, math.inf, math.nan, 1e39, "inf", (1, 2, 3)])
def test_exposure_seconds_refuses_what_is_no_exposure(value: object) -> None:
    """Negative, zero-denominator, non-finite (also beyond float32), bool and text that is no
    number give None."""
    assert exposure_seconds(value) is None


def test_one_line_joins_distinct_lines_and_cuts_at_three_hundred() -> None:
    """one_line: lines deduplicated, whitespace collapsed, joined by '; '; at most 300
    characters (exactly 300 kept; longer cut to 297 + '...'); temp names replaced."""
    assert one_line("a  b\n\nc", "a b", None) == "a b; c"
    exact = "x" * 300
    assert one_line(exact) == exact
    cut = one_line("y" * 301)
    assert cut == "y" * 297 + "..." and len(cut) == 300
    tmp, path = Path("/d/.f.123.tmp.tif"), Path("/d/f.tif")
    assert one_line(f"cannot write {tmp}; {tmp.name}", tmp=tmp, path=path) == \
        "cannot write /d/f.tif; f.tif"


def test_int_or_and_float_or_none() -> None:
    """int_or: int(value) or the default; float_or_none: finite floats only."""
    assert int_or("12", 0) == 12 and int_or(12.7, 0) == 12 and int_or(None, 5) == 5
    assert int_or("x", -1) == -1 and int_or(math.inf, 3) == 3
    assert float_or_none("2.5") == 2.5 and float_or_none(0) == 0.0
    assert float_or_none("inf") is None and float_or_none(math.nan) is None
    assert float_or_none(None) is None and float_or_none(10**400) is None


def test_header_shape_and_is_image_path() -> None:
    """ImageHeader.shape is (H, W) for one channel, (H, W, C) otherwise; extensions any case."""
    hdr = ImageHeader(Path("a.tif"), width=5, height=3, channels=1, dtype=np.dtype("u2"),
                      bits=12, layout="mono")
    assert hdr.shape == (3, 5)
    assert ImageHeader(Path("a.tif"), 5, 3, 4, np.dtype("u1"), 8, "rgba").shape == (3, 5, 4)
    assert is_image_path("x.FITS") and is_image_path("x.Nef") and not is_image_path("x.txt")


# ---- camera raw files (rawpy replaced by a stand-in: no raw file needed) -----------------------
class _FakeRaw:
    """What ccdcore.io.frames uses of a rawpy RawPy object."""
    def __init__(self, data: np.ndarray, white: int, desc: bytes = b"RGBG",
                 pattern: tuple = ((0, 1), (3, 2))) -> None:
        self.raw_image_visible = data
        self.white_level = white
        self.color_desc = desc
        self.raw_pattern = np.array(pattern)

    def __enter__(self) -> "_FakeRaw":
        return self

    def __exit__(self, *exc: object) -> None:
        return None


@pytest.mark.parametrize("desc,pattern,layout", [
    (b"RGBG", ((0, 1), (3, 2)), "bayer-rggb"), (b"RGBG", ((1, 0), (2, 3)), "bayer-grbg"),
    (b"RGBG", ((2, 3), (1, 0)), "bayer-bggr"), (b"RGBG", ((3, 2), (0, 1)), "bayer-gbrg"),
    ("RGBG", ((0, 1), (3, 2)), "bayer-rggb"), (b"RGBE", ((0, 1), (3, 2)), "cfa"),
    (b"RGBG", ((0, 1, 0), (3, 2, 3), (0, 1, 0)), "cfa"), (b"RGBG", ((0, 0), (1, 2)), "cfa")])
def test_raw_pattern_reads_the_two_by_two_cell(desc: object, pattern: tuple,
                                               layout: str) -> None:
    """The raw_pattern indexes color_desc, read row by row; only R, G, G, B cells are Bayer."""
    assert _raw_pattern(_FakeRaw(np.zeros((2, 2)), 0, desc, pattern)) == layout


def _fake_raw_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, data: np.ndarray,
                   white: int) -> Path:
    import ccdcore.io.frames as frames_mod

    path = tmp_path / "shot.dng"
    path.write_bytes(b"not really a DNG")
    monkeypatch.setattr(frames_mod, "_raw_open", lambda p: _FakeRaw(data, white))
    return path


@pytest.mark.parametrize("white,bits", [(4095, 12), (16383, 14), (255, 8), (100, 8),
                                        (65535, 16), (0, 16), (4096, 13)])
def test_raw_header_bits_from_the_white_level(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              white: int, bits: int) -> None:
    """bits = bit length of the white level (at least 8); no white level: 16. The header's
    width/height are the visible mosaic's columns/rows (non-square to tell them apart)."""
    data = np.zeros((4, 6), np.uint16)
    hdr = read_header(_fake_raw_file(tmp_path, monkeypatch, data, white))
    assert (hdr.bits, hdr.width, hdr.height, hdr.channels) == (bits, 6, 4, 1)
    assert (hdr.layout, hdr.format, hdr.dtype) == ("bayer-rggb", "raw", np.dtype("uint16"))


def test_raw_region_is_the_crop_of_the_whole_mosaic(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """A raw region is decoded whole and cropped to [y:y+h, x:x+w]; the whole mosaic must fit
    the pixel limit (a raw file cannot be decoded in part)."""
    data = np.arange(6 * 10, dtype=np.uint16).reshape(6, 10)
    path = _fake_raw_file(tmp_path, monkeypatch, data, 4095)
    np.testing.assert_array_equal(read_image(path), data)
    np.testing.assert_array_equal(read_region(path, 3, 1, 5, 2), data[1:3, 3:8])
    np.testing.assert_array_equal(read_region(path, 9, 5, 1, 1), data[5:6, 9:10])
    assert read_region(path, 0, 0, 2, 2, max_pixels=60).shape == (2, 2)   # the limit itself
    with pytest.raises(ImageReadError, match="decoded whole"):
        read_region(path, 0, 0, 2, 2, max_pixels=59)


@pytest.mark.parametrize("box", [(-1, 0, 1, 1), (0, -1, 1, 1), (0, 0, 0, 1), (0, 0, 1, 0),
                                 (9, 0, 2, 1), (0, 5, 1, 2), (10, 0, 1, 1), (0, 6, 1, 1),
                                 (0.5, 0, 1, 1), (None, 0, 1, 1)])
def test_region_outside_the_image_is_refused(tmp_path: Path, box: tuple) -> None:
    """x, y >= 0, width, height >= 1 and x + width <= W, y + height <= H (W=10, H=6)."""
    path = write_image(tmp_path / "f.tif", np.arange(60, dtype=np.uint16).reshape(6, 10))
    with pytest.raises(ImageReadError, match="is not inside the 10x6 image"):
        read_region(path, *box)
    np.testing.assert_array_equal(read_region(path, 9, 5, 1, 1), [[59]])
    np.testing.assert_array_equal(read_region(path, 0, 0, 10, 6),
                                  np.arange(60).reshape(6, 10))
    np.testing.assert_array_equal(read_region(path, 2.0, "1", 3, 2),
                                  np.arange(60).reshape(6, 10)[1:3, 2:5])


# ---- what a region read decodes: whole strips / tiles, clipped at the image's edge -------------
def _oiio_tiff(path: Path, a: np.ndarray, *, rows: int = 0, tile: tuple[int, int] = (0, 0)
              ) -> Path:
    """A TIFF written directly through OpenImageIO with `rows` rows per strip or tiles of
    `tile` = (width, height)."""
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(a.shape[1], a.shape[0], 1, "uint16")
    if tile[0]:
        spec.tile_width, spec.tile_height = tile
    if rows:
        spec.attribute("tiff:RowsPerStrip", rows)
    out = oiio.ImageOutput.create(str(path))
    ok = out.open(str(path), spec) and out.write_image(a[:, :, None]) and out.close()
    assert ok, out.geterror()
    return path


@pytest.mark.parametrize("kind,box,decoded", [
    ("strips", (3, 13, 5, 6), 16 * 70),    # rows 13..18 -> strips 8..23
    ("strips", (0, 45, 2, 3), 8 * 70),     # rows 45..47 -> strip 40..47
    ("strips", (0, 49, 1, 1), 2 * 70),     # last strip 48..55 clipped at row 50
    ("strips", (0, 16, 1, 8), 8 * 70),     # exactly one strip
    ("strips", (0, 13, 1, 4), 16 * 70),    # rows 13..16: row 16 opens the next strip
    ("tiles", (17, 18, 3, 4), 32 * 16),    # inside one tile
    ("tiles", (66, 45, 4, 5), 6 * 18),     # the corner tile, clipped to 6 x 18
    ("tiles", (33, 17, 2, 2), 32 * 16),    # one tile, away from the origin in x and y
    ("tiles", (31, 15, 2, 2), 64 * 32)])   # four tiles
def test_region_limit_counts_the_strips_or_tiles_decoded(tmp_path: Path, kind: str, box: tuple,
                                                         decoded: int) -> None:
    """read_region decodes whole strips (rows y - y % R to the next multiple of R, at most
    the height) or whole tiles (likewise in x and y); the pixel limit applies to those: exactly
    that many values pass, one fewer is refused. (70 x 50 image, R = 8, tiles 32 wide and 16
    high, so that a mix-up of the tile's width and height shows.)"""
    a = np.arange(50 * 70, dtype=np.uint16).reshape(50, 70)
    path = (_oiio_tiff(tmp_path / "s.tif", a, rows=8) if kind == "strips"
            else _oiio_tiff(tmp_path / "t.tif", a, tile=(32, 16)))
    x, y, w, h = box
    np.testing.assert_array_equal(read_region(path, *box, max_pixels=decoded),
                                  a[y:y + h, x:x + w])
    with pytest.raises(ImageReadError, match="holding this region"):
        read_region(path, *box, max_pixels=decoded - 1)


class _FakeSpec:
    """What header_from_spec reads of an OpenImageIO ImageSpec."""
    def __init__(self, fmt: str, attrs: dict, width: int = 7, height: int = 3,
                 nchannels: int = 1) -> None:
        from types import SimpleNamespace

        self.format, self.width, self.height, self.nchannels = fmt, width, height, nchannels
        self._attrs = attrs
        self.extra_attribs = [SimpleNamespace(name=k, value=v) for k, v in attrs.items()]

    def get_int_attribute(self, name: str, default: int) -> int:
        return int(self._attrs.get(name, default))

    def getattribute(self, name: str) -> object:
        return self._attrs.get(name)


def test_header_from_spec_bits_gain_temperature_and_layout() -> None:
    """bits: oiio:BitsPerSample else the sample width; gain: Exif:Gain else Gain; temperature:
    Exif:Temperature else Exif:AmbientTemperature; exposure through exposure_seconds;
    layout by channel count (2: mono+alpha; 5: '5-channel')."""
    hdr = header_from_spec(Path("a.tif"), _FakeSpec("uint16", {
        "oiio:BitsPerSample": 12, "Exif:Gain": 2.5, "Gain": 9.0, "Exif:Temperature": -5.0,
        "Exif:AmbientTemperature": 20.0, "ExposureTime": "1/250"}), "tiff")
    assert (hdr.bits, hdr.gain, hdr.temperature, hdr.exposure) == (12, 2.5, -5.0, 0.004)
    assert (hdr.width, hdr.height, hdr.shape, hdr.layout) == (7, 3, (3, 7), "mono")
    hdr = header_from_spec(Path("a.tif"), _FakeSpec("uint16", {
        "Gain": 9.0, "Exif:AmbientTemperature": 20.0}, nchannels=2), "tiff")
    assert (hdr.bits, hdr.gain, hdr.temperature, hdr.exposure) == (16, 9.0, 20.0, None)
    assert hdr.layout == "mono+alpha"
    hdr = header_from_spec(Path("a.exr"), _FakeSpec("half", {}, nchannels=5), "openexr")
    assert (hdr.bits, str(hdr.dtype), hdr.layout) == (16, "float16", "5-channel")
    for td, dtype in (("uint", "uint32"), ("int", "int32"), ("float", "float32"),
                      ("double", "float64"), ("int8", "int8")):
        assert str(header_from_spec(Path("a.tif"), _FakeSpec(td, {}), "tiff").dtype) == dtype
    with pytest.raises(ImageReadError, match="unsupported sample type uint64"):
        header_from_spec(Path("a.tif"), _FakeSpec("uint64", {}), "tiff")


# ---- the session's content hash and tables -----------------------------------------------------
def _field(data: bytes) -> bytes:
    return len(data).to_bytes(8, "little") + data


def test_content_hash_follows_its_documented_stream(tmp_path: Path) -> None:
    """SHA-256 of: a prefix, the manifest (tag, size, bytes), then per frame its tag, relpath,
    size and bytes, each tag/path length-prefixed (Session.content_hash docstring); rebuilt
    here with hashlib."""
    root = tmp_path / "s"
    a = write_image(root / "a.tif", _frame(1))
    b = write_image(root / "sub" / "b.tif", _frame(2))
    manifest = root / "session.toml"
    manifest.write_text('schema = 1\n[[frames]]\npath = "sub/b.tif"\nrole = "dark"\n'
                        '[[frames]]\npath = "a.tif"\nrole = "dark"\n')
    s = open_session(root)
    stream = b"ccdcore session content v1\0" + _field(b"manifest")
    stream += len(manifest.read_bytes()).to_bytes(8, "little") + manifest.read_bytes()
    for rel, path in (("sub/b.tif", b), ("a.tif", a)):
        data = path.read_bytes()
        stream += _field(b"frame") + _field(rel.encode()) + len(data).to_bytes(8, "little") + data
    assert s.content_hash() == hashlib.sha256(stream).hexdigest()
    folder = open_session(root / "sub")                 # a plain folder: no manifest field
    data = b.read_bytes()
    stream = (b"ccdcore session content v1\0" + _field(b"frame") + _field(b"b.tif")
              + len(data).to_bytes(8, "little") + data)
    assert folder.content_hash() == hashlib.sha256(stream).hexdigest()


def test_problem_touches_roles() -> None:
    """A problem touches the roles it names; one naming none touches every role; None asks
    for any role."""
    p = Problem("x", "m", code="bad-value", roles=("dark", "flat"))
    assert p.touches(["flat"]) and p.touches(None) and not p.touches(["ptc"])
    assert not p.touches([])
    whole = Problem("camera", "m", code="bad-value")
    assert whole.touches(["ptc"]) and whole.touches([])
    s = _session(8)
    s = Session(root=s.root, manifest_path=None, source="manifest", camera=s.camera,
                frames=(), problems=(p, whole, Problem("w", "m", "warning", code="bad-value",
                                                       roles=("ptc",))))
    assert s.errors_for(["ptc"]) == (whole,) and s.errors_for(None) == (p, whole)
    assert not s.ok and len(s.warnings) == 1


def test_groups_table_keys_and_mixed_groups(tmp_path: Path) -> None:
    """groups_table: flats keyed by level, else by exposure; darks by exposure; ptc by level
    (None when missing), scenes by nothing; a group with two
    shapes has shape None and mixed ['shape']; exposures are distinct and sorted."""
    root = tmp_path / "g"
    write_image(root / "f1.tif", _frame(1))
    write_image(root / "f2.tif", _frame(2, (W, H)))
    write_image(root / "f3.tif", _frame(3))
    write_image(root / "d1.tif", _frame(4))
    write_image(root / "s1.tif", _frame(5))
    write_image(root / "p1.tif", _frame(6))
    (root / "session.toml").write_text(
        'schema = 1\n'
        '[[frames]]\npath = "f1.tif"\nrole = "flat"\nlevel = 2\nexposure = 0.2\n'
        '[[frames]]\npath = "f2.tif"\nrole = "flat"\nlevel = 2\nexposure = 0.1\n'
        '[[frames]]\npath = "f3.tif"\nrole = "flat"\nexposure = 0.3\n'
        '[[frames]]\npath = "d1.tif"\nrole = "dark"\nexposure = 0.3\n'
        '[[frames]]\npath = "s1.tif"\nrole = "scene"\nexposure = 0.5\n'
        '[[frames]]\npath = "p1.tif"\nrole = "ptc"\nexposure = 0.5\n')  # no level: an error
    rows = open_session(root).groups_table()
    got = [(r["role"], r["key_name"], r["key"], r["count"], r["shape"], r["mixed"],
            r["exposures"]) for r in rows]
    assert got == [("dark", "exposure", 0.3, 1, (H, W), [], [0.3]),     # in ROLES order
                   ("ptc", "level", None, 1, (H, W), [], [0.5]),         # only flats fall back
                   ("flat", "exposure", 0.3, 1, (H, W), [], [0.3]),     # keys sorted: 0.3 < 2
                   ("flat", "level", 2, 2, None, ["shape"], [0.1, 0.2]),
                   ("scene", None, None, 1, (H, W), [], [0.5])]


# ---- channel layouts (ccdcore.channels) --------------------------------------------------------
def test_check_layout_infers_and_refuses_by_shape() -> None:
    """None infers mono for 2-D and rgb for (H, W, 3); rgb needs (H, W, 3); mono and Bayer
    need 2-D; Bayer needs even height and width (checked separately: 4 x 5 and 5 x 4)."""
    assert check_layout((4, 6), None) is Layout.MONO
    assert check_layout((4, 6, 3), None) is Layout.RGB
    assert check_layout((2, 2), " Bayer-GBRG ") is Layout.BAYER_GBRG
    assert check_layout((5, 7), "mono") is Layout.MONO
    for shape, layout in (((4, 6, 4), None), ((4, 6, 1), None), ((4,), None), ((4, 6), "rgb"),
                          ((4, 6, 4), "rgb"), ((4, 6, 3), "mono"), ((4, 5), "bayer-rggb"),
                          ((5, 4), "bayer-rggb"), ((4, 6, 3), "rggb")):
        with pytest.raises(CcdError):
            check_layout(shape, layout)


def test_channel_slices_view_each_channel() -> None:
    """mono: the frame; rgb: [:, :, c] in R, G, B order; Bayer: [r::2, c::2] of each plane
    (G1 on the red row, G2 on the blue row)."""
    raw = np.arange(4 * 6).reshape(4, 6)
    got = split_channels(raw, "bayer-gbrg")      # G B / R G: red row is row 1
    np.testing.assert_array_equal(got["R"], raw[1::2, 0::2])
    np.testing.assert_array_equal(got["G1"], raw[1::2, 1::2])
    np.testing.assert_array_equal(got["G2"], raw[0::2, 0::2])
    np.testing.assert_array_equal(got["B"], raw[0::2, 1::2])
    rgb = np.arange(2 * 3 * 3).reshape(2, 3, 3)
    got = split_channels(rgb)
    assert list(got) == ["R", "G", "B"]
    np.testing.assert_array_equal(got["B"], rgb[:, :, 2])
    assert np.shares_memory(split_channels(raw)["L"], raw)


def test_demosaic_at_one_site_by_hand() -> None:
    """Bilinear (Tsin et al. sec. 2): at a red site of rggb, green is the mean of its 4 edge
    neighbours and blue the mean of its 4 diagonal ones; at a green site red is the mean of its
    2 red neighbours."""
    raw = np.random.default_rng(3).integers(0, 1000, (6, 8)).astype(np.float64)
    out = demosaic_bilinear(raw, "rggb")
    r, c = 2, 4                                   # a red site (even row, even column)
    assert out[r, c, 0] == raw[r, c]
    assert out[r, c, 1] == pytest.approx((raw[r - 1, c] + raw[r + 1, c] + raw[r, c - 1]
                                          + raw[r, c + 1]) / 4)
    assert out[r, c, 2] == pytest.approx((raw[r - 1, c - 1] + raw[r - 1, c + 1]
                                          + raw[r + 1, c - 1] + raw[r + 1, c + 1]) / 4)
    assert out[2, 3, 0] == pytest.approx((raw[2, 2] + raw[2, 4]) / 2)   # G1 site: red row
    assert out[3, 4, 0] == pytest.approx((raw[2, 4] + raw[4, 4]) / 2)   # G2 site: red column


# ---- output records and kinds (ccdcore.io.outputs) ----------------------------------------------
def test_read_record_keeps_only_plain_names(tmp_path: Path) -> None:
    """read_record: entries with a plain name and null or a list of strings; anything else
    dropped; a damaged record is empty."""
    entries = {"ok.tif": None, "dir": ["a", "b/c"], "": None, ".": None, "..": None,
               "a/b": None, "bad": [1], "worse": "x", "nul\0": None}
    (tmp_path / RECORD).write_text(json.dumps({"entries": entries}))
    assert read_record(tmp_path) == {"ok.tif": None, "dir": ["a", "b/c"]}
    (tmp_path / RECORD).write_text("{broken")
    assert read_record(tmp_path) == {}
    (tmp_path / RECORD).write_text(json.dumps({"entries": []}))
    assert read_record(tmp_path) == {}


def test_check_output_kinds(tmp_path: Path) -> None:
    """A file output may be absent, a file or a dangling symlink; a folder output a folder;
    a folder where a file is wanted (and the reverse), or a symlink to a FIFO, is refused."""
    (tmp_path / "f").write_bytes(b"1")
    (tmp_path / "d").mkdir()
    os.symlink(tmp_path / "nowhere", tmp_path / "dangling")
    check_output(tmp_path / "absent")
    check_output(tmp_path / "f")
    check_output(tmp_path / "dangling")
    check_output(tmp_path / "d", folder=True)
    with pytest.raises(CcdError, match="is a folder, not a file"):
        check_output(tmp_path / "d")
    with pytest.raises(CcdError, match="is a file, not a folder"):
        check_output(tmp_path / "f", folder=True)
    os.mkfifo(tmp_path / "fifo")
    os.symlink(tmp_path / "fifo", tmp_path / "link")
    with pytest.raises(CcdError, match=r"is a symlink to .*fifo, which is a FIFO \(named pipe\)"):
        check_output(tmp_path / "link")


def test_default_pixel_limit_is_the_documented_two_to_the_thirty(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """MAX_PIXELS is 2**30 values (ccdcore.io.limits docstring); without the variable it is
    the limit in force, and an image of exactly that many values is not refused."""
    from ccdcore.io.limits import MAX_PIXELS, check_pixel_limit, pixel_limit
    monkeypatch.delenv("CCDCORE_MAX_PIXELS", raising=False)
    assert MAX_PIXELS == 2**30 and pixel_limit() == 2**30
    check_pixel_limit("x", 2**15, 2**13, 4)                    # exactly 2**30 values
    with pytest.raises(ImageReadError, match="= 1,073,741,824 values, over the limit of "
                                             "1,073,741,823"):
        check_pixel_limit("x", 2**15, 2**13, 4, limit=2**30 - 1)
