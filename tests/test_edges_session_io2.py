"""Edge and boundary pins of plain-folder inference (ccdcore.session.folder), second part of
tests/test_edges_session_io.py.

What this file pins, each from the rules :func:`ccdcore.session.folder.open_folder` documents:
file-name roles, photon-transfer levels from names or pairs of exposure times, sub-folder
numbering, exposure keys to 6 significant digits, ``1/N s`` formatting, camera and capture
settings, the bracket decision (one camera, a majority of one size, >= 2 exposure times,
settings unchanged), repeated sequences and duplicate exposures; and the camera open_folder
infers. Also: ``assemble``'s per-frame and cross-frame checks at their limits, the output
safety rules (``ccdcore.io.outputs``), the product's maps, correction and camera
(``ccdcore.product.file``), and the app's result cache (``ccdcore_app.cache.store``: sizes,
eviction at the bound, keys, encoding, content hash by hand, index, folder modes).
"""
from __future__ import annotations

import gc
import hashlib
import json
import os
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from ccdcore.channels import Layout
from ccdcore.errors import CcdError, ImageWriteError
from ccdcore.io.base import ImageHeader
from ccdcore.io.frames import write_image
from ccdcore.io.oiio_write import oiio_samples
from ccdcore.io.outputs import check_not_inputs, ownership_problem
from ccdcore.product.file import CalibrationProduct, _camera_from, _check_maps, map_problem
from ccdcore.session import folder as fo
from ccdcore.session import open_session
from ccdcore.session.assemble import Candidate, assemble
from ccdcore.session.records import MAX_EXPOSURE, MIN_EXPOSURE, Camera
from ccdcore_app.cache import store
from ccdcore_app.cache.store import (ResultCache, SharedResults, Unserialisable, _canonical,
                                     content_hash, decode, encode, file_digest, unsafe_folder)


def _hdr(exposure: float | None = None, *, shape: tuple[int, int] = (4, 6), bits: int = 8,
         dtype: str = "uint8", gain: float | None = None, **attrs: Any) -> ImageHeader:
    """A header of a (H, W) = shape mono image with EXIF-like attributes."""
    return ImageHeader(Path("x.tif"), width=shape[1], height=shape[0], channels=1,
                       dtype=np.dtype(dtype), bits=bits, layout="mono", exposure=exposure,
                       gain=gain, attributes=attrs)


# ---- names and numbers -------------------------------------------------------------------------
@pytest.mark.parametrize("name,role", [
    ("dark_001.tif", "dark"), ("Bias-3.tif", "dark"), ("ptc.tif", "ptc"), ("flat 2.tif", "flat"),
    ("fpn7.tif", "fixed_pattern"), ("darkroom.tif", None), ("dark", None), ("white_1.tif", None),
    ("_dark_1.tif", None), ("1dark.tif", None), ("scene_1.tif", None), ("FLATS_1.fits", "flat")])
def test_file_name_role_reads_the_first_word(name: str, role: str | None) -> None:
    """The letters before the first digit, '_', '-', '.' or space name a calibration role;
    a word running on ('darkroom'), a bare word and subject words ('white') do not."""
    assert fo.file_name_role(name) == role


def test_in_role_subfolder_needs_two_levels_under_a_role_folder() -> None:
    """ptc/L03/a.tif is in a role sub-folder; ptc/a.tif and misc/L03/a.tif are not."""
    assert fo._in_role_subfolder("ptc/L03/a.tif") and fo._in_role_subfolder("PTC/x/y/a.tif")
    assert not fo._in_role_subfolder("ptc/a.tif") and not fo._in_role_subfolder("misc/L/a.tif")


def test_subfolder_ids_use_distinct_numbers_else_sorted_order() -> None:
    """Sub-folders are numbered by the last integer of their names when distinct, else 1..n
    in sorted name order."""
    assert fo._subfolder_ids(["L10", "L3"]) == {"L10": 10, "L3": 3}
    assert fo._subfolder_ids(["a1b7", "a2b9"]) == {"a1b7": 7, "a2b9": 9}    # the last number
    assert fo._subfolder_ids(["x1", "y1"]) == {"x1": 1, "y1": 2}            # not distinct
    assert fo._subfolder_ids(["b", "a2"]) == {"a2": 1, "b": 2}              # one has none
    assert fo._subfolder_ids(["L0", "L5"]) == {"L0": 0, "L5": 5}


def test_ptc_levels_from_names_when_they_make_pairs() -> None:
    """File-name numbers make the levels when there are >= 2 levels of >= 2 frames each."""
    rels = ["L1_a.tif", "L1_b.tif", "L2_a.tif", "L2_b.tif"]
    levels, how = fo._ptc_levels(rels, {})
    assert how == "name" and levels == {"L1_a.tif": 1, "L1_b.tif": 1, "L2_a.tif": 2,
                                        "L2_b.tif": 2}


def test_ptc_levels_from_exposure_pairs_ranked_from_the_shortest() -> None:
    """No pairs by name: frames sharing an exposure time (to 6 digits), all at one gain, form
    a level; levels rank exposures 1 = shortest."""
    rels = ["a1.tif", "a2.tif", "a3.tif", "a4.tif", "a5.tif", "a6.tif"]
    exps = [0.2, 0.01, 0.2, 0.01, 0.05, 0.05 * (1 + 1e-8)]
    headers = {r: _hdr(e, gain=2.0) for r, e in zip(rels, exps)}
    levels, how = fo._ptc_levels(rels, headers)
    assert how == "exposure"
    assert [levels[r] for r in rels] == [3, 1, 3, 1, 2, 2]


@pytest.mark.parametrize("case", ["one-frame-level", "two-gains", "missing-exposure",
                                  "one-level"])
def test_ptc_levels_fall_back_to_names(case: str) -> None:
    """Exposure pairing needs every frame's exposure, one gain, >= 2 levels, every level of
    >= 2 frames; otherwise the names' numbers are kept (level of one frame reported later)."""
    rels = ["a1.tif", "a2.tif", "a3.tif", "a4.tif"]
    exps: list[float | None] = [0.1, 0.1, 0.2, 0.2]
    gains: list[float | None] = [1.0] * 4
    if case == "one-frame-level":
        exps = [0.1, 0.1, 0.2, 0.3]
    elif case == "two-gains":
        gains = [1.0, 1.0, 1.0, 2.0]
    elif case == "missing-exposure":
        exps = [0.1, 0.1, 0.2, None]
    else:
        exps = [0.1] * 4
    headers = {r: _hdr(e, gain=g) for r, e, g in zip(rels, exps, gains)}
    levels, how = fo._ptc_levels(rels, headers)
    assert how == "name" and levels == {r: i for i, r in enumerate(rels, start=1)}


def test_ptc_levels_without_number_in_a_name_are_none() -> None:
    """A name without a number has level None (never pairs by name)."""
    levels, how = fo._ptc_levels(["a.tif", "b.tif"], {})
    assert how == "name" and levels == {"a.tif": None, "b.tif": None}


def test_exposure_key_is_six_significant_digits() -> None:
    """Exposures equal to 6 significant digits share a key; a 7th-digit difference does not
    count, a 6th-digit one does."""
    assert fo._exposure_key(1 / 60) == 0.0166667
    assert fo._exposure_key(0.0166667000001) == fo._exposure_key(1 / 60)
    assert fo._exposure_key(0.123456) != fo._exposure_key(0.123457)
    assert fo._exposure_key(1234567.0) == 1234570.0


@pytest.mark.parametrize("seconds,text", [(0.004, "1/250 s"), (1 / 60, "1/60 s"),
                                          (0.3, "0.3 s"), (0.5, "1/2 s"), (1.0, "1 s"),
                                          (2.5, "2.5 s"), (0.0, "0 s"), (1 / 3000.2, "1/3000 s"),
                                          (1 / 3001, "1/3001 s"), (0.0666, "0.0666 s")])
def test_format_exposure_as_one_over_n_below_a_second(seconds: float, text: str) -> None:
    """Fractions of a second within 1e-4 (relative) of 1/N show as '1/N s'; others and whole
    seconds with %g."""
    assert fo.format_exposure(seconds) == text


def test_names_and_numbers() -> None:
    """_names shows at most 6 names, then 'and N more'; _number keeps positive finite numbers
    rounded to `digits` significant digits, else None."""
    six = [f"{c}.jpg" for c in "abcdef"]
    assert fo._names(six) == "a.jpg, b.jpg, c.jpg, d.jpg, e.jpg, f.jpg"
    assert fo._names(six + ["g.jpg"]) == "a.jpg, b.jpg, c.jpg, d.jpg, e.jpg, f.jpg and 1 more"
    assert fo._names([]) == ""
    assert fo._number("100", 6) == 100.0
    assert fo._number(5.6789, 3) == 5.68
    for bad in (0, -100, "inf", "nan", None, "f/2"):
        assert fo._number(bad, 6) is None


# ---- camera and capture settings ---------------------------------------------------------------
def test_camera_of_joins_make_and_model_without_repeating() -> None:
    """'Make Model', the Model alone when it already starts with the Make (any case)."""
    assert fo.camera_of(_hdr(Make="Canon", Model="EOS 5D")) == "Canon EOS 5D"
    assert fo.camera_of(_hdr(Make="NIKON", Model="Nikon D750")) == "Nikon D750"
    assert fo.camera_of(_hdr(Make=" Sony\x00 ", Model=None)) == "Sony"
    assert fo.camera_of(_hdr(Model="X100")) == "X100"
    assert fo.camera_of(_hdr()) is None


def test_capture_settings_names_iso_aperture_gain() -> None:
    """ISO from Exif:ISOSpeedRatings else Exif:PhotographicSensitivity; f/N to 3 digits;
    gain with %g; absent or non-positive values left out."""
    got = fo.capture_settings(_hdr(gain=2.0, Make="A", Model="B",
                                   **{"Exif:PhotographicSensitivity": 400, "FNumber": 5.6001}))
    assert got == {"camera": "A B", "ISO": "400", "aperture": "f/5.6", "gain": "2"}
    got = fo.capture_settings(_hdr(**{"Exif:ISOSpeedRatings": 100,
                                      "Exif:PhotographicSensitivity": 400,
                                      "Exif:FNumber": 8}))
    assert got == {"ISO": "100", "aperture": "f/8"}
    assert fo.capture_settings(_hdr(FNumber=11.31)) == {"aperture": "f/11.3"}   # 3 digits
    assert fo.capture_settings(_hdr(**{"Exif:ISOSpeedRatings": 0, "FNumber": -1})) == {}
    assert fo.capture_settings(_hdr(gain=0.0)) == {"gain": "0"}


# ---- is it an exposure bracket? ----------------------------------------------------------------
def test_bracket_needs_two_exposures_in_the_majority_signature() -> None:
    """Two readable images at two exposure times, same size: a bracket; one exposure time or
    one image: scenes without a note."""
    rels = ["a.jpg", "b.jpg"]
    assert fo._looks_like_bracket(rels, {"a.jpg": _hdr(0.1), "b.jpg": _hdr(0.2)}) == (True, None)
    assert fo._looks_like_bracket(rels, {"a.jpg": _hdr(0.1), "b.jpg": _hdr(0.1)}) == (False, None)
    assert fo._looks_like_bracket(["a.jpg"], {"a.jpg": _hdr(0.1)}) == (False, None)
    assert fo._looks_like_bracket(rels, {"a.jpg": _hdr(0.1), "b.jpg": None}) == (False, None)
    assert fo._looks_like_bracket(["a.png"], {"a.png": _hdr()}) == (False, None)  # one image
    # one exposure time over two sizes: nothing like a bracket, so no size note either
    assert fo._looks_like_bracket(rels, {"a.jpg": _hdr(0.1), "b.jpg": _hdr(0.1, shape=(6, 4))}
                                  ) == (False, None)


def test_bracket_without_exposures_is_noted_only_for_one_signature() -> None:
    """Several same-size images with no exposure time: a note; of several sizes: none."""
    rels = ["a.png", "b.png"]
    take, why = fo._looks_like_bracket(rels, {"a.png": _hdr(), "b.png": _hdr()})
    assert not take and "none of them carries an exposure time" in why
    take, why = fo._looks_like_bracket(rels, {"a.png": _hdr(), "b.png": _hdr(shape=(6, 4))})
    assert (take, why) == (False, None)


def test_bracket_majority_signature_must_be_more_than_half() -> None:
    """A size shared by exactly half the images is no majority (they differ: a note naming
    W x H, dtype and bits); by more than half it is, and the odd one is left to the checks."""
    hdrs = {"a": _hdr(0.1), "b": _hdr(0.2), "c": _hdr(0.3, shape=(6, 4), bits=12,
                                                       dtype="uint16"),
            "d": _hdr(0.4, shape=(6, 4), bits=12, dtype="uint16")}
    take, why = fo._looks_like_bracket(list(hdrs), hdrs)
    assert not take and why.startswith("the images differ in size or bit depth (")
    assert "6x4 uint8 8-bit: a, b" in why and "4x6 uint16 12-bit: c, d" in why
    three = {k: hdrs[k] for k in "abc"}
    assert fo._looks_like_bracket(list(three), three) == (True, None)


def test_bracket_majority_needs_its_own_two_exposures() -> None:
    """The exposures counted are the majority's: two same-size frames at one time plus an
    odd-size frame at another are no bracket."""
    hdrs = {"a": _hdr(0.1), "b": _hdr(0.1), "c": _hdr(0.3, shape=(6, 4))}
    assert fo._looks_like_bracket(list(hdrs), hdrs) == (False, None)


def test_bracket_refused_when_settings_differ() -> None:
    """ISO (or camera, aperture, gain) changing across the frames: no bracket, the
    difference named with its files."""
    hdrs = {"a": _hdr(0.1, **{"Exif:ISOSpeedRatings": 100}),
            "b": _hdr(0.2, **{"Exif:ISOSpeedRatings": 200}), "c": _hdr(0.4)}
    take, why = fo._looks_like_bracket(list(hdrs), hdrs)
    assert not take and why == "ISO differs (100: a; 200: b)"


def test_sequences_split_repeated_exposure_sets() -> None:
    """a b c a b c (each set complete) is two brackets; a broken repeat, a single set, a
    missing exposure or a count not a multiple is one."""
    rels = list("123456")
    rep = {r: _hdr(e) for r, e in zip(rels, [0.1, 0.2, 0.4, 0.2, 0.1, 0.4])}
    assert fo._sequences(rels, rep) == [["1", "2", "3"], ["4", "5", "6"]]
    broken = {r: _hdr(e) for r, e in zip(rels, [0.1, 0.1, 0.4, 0.2, 0.2, 0.4])}
    assert fo._sequences(rels, broken) == [rels]
    half = {r: _hdr(e) for r, e in zip(rels, [0.1, 0.2, 0.4, 0.1, 0.1, 0.2])}
    assert fo._sequences(rels, half) == [rels]            # every set must be complete
    assert fo._sequences(rels[:3], {r: rep[r] for r in rels[:3]}) == [rels[:3]]
    five = {r: _hdr(e) for r, e in zip(rels, [0.1, 0.2, 0.1, 0.2, 0.1])}
    assert fo._sequences(rels[:5], five) == [rels[:5]]
    missing = dict(rep, **{"6": _hdr(None)})
    assert fo._sequences(rels, missing) == [rels]
    same = {r: _hdr(0.1) for r in rels[:4]}
    assert fo._sequences(rels[:4], same) == [rels[:4]]
    pairs = {r: _hdr(e) for r, e in zip(rels[:4], [0.1, 0.2, 0.2, 0.1])}
    assert fo._sequences(rels[:4], pairs) == [["1", "2"], ["3", "4"]]


def test_duplicate_exposures_are_one_error_per_time() -> None:
    """Frames of one bracket sharing an exposure time (to 6 digits): one error per time,
    at its first file, counting and naming the files."""
    hdrs = {"a": _hdr(0.004), "b": _hdr(0.004 * (1 + 1e-9)), "c": _hdr(0.1), "d": None,
            "e": _hdr(None), "f": _hdr(None)}
    problems = fo._duplicate_problems(list(hdrs), hdrs)
    assert [(p.where, p.code) for p in problems] == [("a", "duplicate-exposure")]
    assert problems[0].message.startswith("2 frames of one bracket have the same exposure time "
                                          "1/250 s (EXIF ExposureTime): a, b;")


# ---- assemble: per-frame and cross-frame checks (headers supplied by a stand-in reader) --------
def _assemble(tmp_path: Path, entries: list[tuple[str, str, dict, ImageHeader]],
              camera: Any = None) -> Any:
    """assemble() over tiny placeholder files whose headers are given (no image decoding)."""
    root = tmp_path.resolve()
    by_path: dict[Path, ImageHeader] = {}
    cands = []
    for rel, role, meta, hdr in entries:
        (root / rel).write_bytes(b"x")
        by_path[root / rel] = hdr
        cands.append(Candidate(f"frames ({rel})", rel, role, meta))
    return assemble(root, None, "manifest", camera or Camera(), cands, [],
                    read=lambda p: by_path[p])


def _codes(session: Any) -> list[tuple[str, str]]:
    return [(p.where, str(p.code)) for p in session.problems]


def test_bracket_exposure_range_both_ends_included(tmp_path: Path) -> None:
    """A bracket/reference/target exposure must lie in [1e-9, 1e6] s: both ends pass; 0 and
    just beyond either end are bad values."""
    h = _hdr(None)
    s = _assemble(tmp_path, [("a.tif", "bracket", {"exposure": MIN_EXPOSURE}, h),
                             ("b.tif", "bracket", {"exposure": MAX_EXPOSURE}, h),
                             ("c.tif", "reference", {"exposure": 0.0}, h),
                             ("d.tif", "target", {"exposure": MIN_EXPOSURE * 0.9}, h),
                             ("e.tif", "bracket", {"exposure": MAX_EXPOSURE * 1.01}, h),
                             ("f.tif", "dark", {"exposure": 0.0}, h)])
    assert _codes(s) == [("c.tif", "bad-value"), ("d.tif", "bad-value"), ("e.tif", "bad-value")]
    msgs = [p.message for p in s.problems]
    assert msgs[0] == "exposure is 0 s: a reference frame needs a positive exposure time"
    assert msgs[1] == "exposure 9e-10 s is outside 1e-09 to 1e+06 s"


def test_missing_exposure_only_for_exposure_roles_with_a_header(tmp_path: Path) -> None:
    """No exposure in the manifest or header: an error for bracket frames, none for darks;
    the header's exposure fills the gap (inferred), a manifest value is kept."""
    s = _assemble(tmp_path, [("a.tif", "bracket", {}, _hdr(None)),
                             ("b.tif", "dark", {}, _hdr(None)),
                             ("c.tif", "bracket", {}, _hdr(0.25, gain=2.0)),
                             ("d.tif", "bracket", {"exposure": 0.5}, _hdr(0.25))])
    assert _codes(s) == [("a.tif", "missing-exposure")]
    c, d = s.frames[2], s.frames[3]
    assert (c.exposure, c.gain, c.inferred) == (0.25, 2.0, ("exposure", "gain"))
    assert (d.exposure, d.inferred) == (0.5, ())


def test_roi_may_reach_the_frame_edge_but_not_beyond(tmp_path: Path) -> None:
    """roi [x, y, w, h] fits when x + w <= width and y + h <= height (8 x 5 frame here)."""
    h = _hdr(None, shape=(5, 8))
    s = _assemble(tmp_path, [("a.tif", "scene", {"roi": (0, 0, 8, 5)}, h),
                             ("b.tif", "scene", {"roi": (3, 2, 5, 3)}, h),
                             ("c.tif", "scene", {"roi": (0, 0, 5, 8)}, h),
                             ("d.tif", "scene", {"roi": (4, 0, 5, 1)}, h),
                             ("e.tif", "scene", {"roi": (0, 1, 1, 5)}, h)])
    assert _codes(s) == [("c.tif", "roi-outside"), ("d.tif", "roi-outside"),
                         ("e.tif", "roi-outside")]
    assert s.problems[0].message == "roi [0, 0, 5, 8] extends past the 8x5 frame"


def test_header_bits_compared_with_the_camera_only_when_explicit(tmp_path: Path) -> None:
    """A header depth above camera.bits is an error only when it is below the container width
    (16 bits in uint16 is just the container)."""
    s = _assemble(tmp_path, [("a.tif", "scene", {}, _hdr(None, bits=14, dtype="uint16")),
                             ("b.tif", "scene", {}, _hdr(None, bits=16, dtype="uint16")),
                             ("c.tif", "scene", {}, _hdr(None, bits=12, dtype="uint16")),
                             ("d.tif", "scene", {}, _hdr(None, bits=32, dtype="float32")),
                             ("e.tif", "scene", {}, _hdr(None, bits=13, dtype="int16"))],
                  camera=Camera(bits=12))
    assert _codes(s) == [("a.tif", "bit-depth"), ("e.tif", "bit-depth")]
    assert s.problems[0].message == "14-bit data but camera.bits = 12"


def test_mismatch_names_the_odd_frame_against_the_majority(tmp_path: Path) -> None:
    """Within a uniform role the most common (shape, dtype, bits) wins; each other frame gets
    one error listing each difference and the majority's count. Scenes are exempt."""
    big = _hdr(None, shape=(5, 8))
    s = _assemble(tmp_path, [("a.tif", "dark", {}, _hdr(None, shape=(8, 5), bits=12,
                                                         dtype="uint16")),
                             ("b.tif", "dark", {}, big), ("c.tif", "dark", {}, big),
                             ("d.tif", "scene", {}, _hdr(None, shape=(2, 2)))])
    assert _codes(s) == [("a.tif", "mismatch")]
    assert s.problems[0].message == ("size 5 × 8 differs from 8 × 5; dtype uint16 differs from "
                                     "uint8; bit depth 12 differs from 8 of the other dark "
                                     "frames (2 frames)")


def test_ptc_levels_need_two_frames_and_a_level(tmp_path: Path) -> None:
    """A ptc level of one frame is an error; two frames are a pair; a ptc frame without level
    and a fixed_pattern frame without config are reported once per entry."""
    h = _hdr(None)
    s = _assemble(tmp_path, [("a.tif", "ptc", {"level": 1}, h), ("b.tif", "ptc", {"level": 1}, h),
                             ("c.tif", "ptc", {"level": 2}, h), ("d.tif", "ptc", {}, h),
                             ("e.tif", "fixed_pattern", {}, h)])
    assert _codes(s) == [("frames (d.tif)", "missing-level"), ("frames (e.tif)", "missing-config"),
                         ("ptc level 2", "ptc-single-frame")]


def test_pixel_limit_at_assembly(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A frame of exactly the pixel limit is valid; one value more is an unreadable frame."""
    monkeypatch.setenv("CCDCORE_MAX_PIXELS", "40")
    s = _assemble(tmp_path, [("a.tif", "scene", {}, _hdr(None, shape=(5, 8))),
                             ("b.tif", "scene", {}, _hdr(None, shape=(41, 1)))])
    assert _codes(s) == [("b.tif", "unreadable")]


def test_a_group_without_level_is_reported_once(tmp_path: Path) -> None:
    """Frames of one [[groups]] entry missing 'level' give one problem for the entry, not one
    per frame."""
    root = tmp_path.resolve()
    for rel in ("a.tif", "b.tif"):
        (root / rel).write_bytes(b"x")
    cands = [Candidate("groups[0] (*.tif)", rel, "ptc", {}) for rel in ("a.tif", "b.tif")]
    s = assemble(root, None, "manifest", Camera(), cands, [], read=lambda p: _hdr(None))
    assert _codes(s) == [("groups[0] (*.tif)", "missing-level")]


# ---- output safety (ccdcore.io.outputs) --------------------------------------------------------
def test_check_not_inputs_equal_inside_and_holding(tmp_path: Path) -> None:
    """An output equal to or inside an input is refused; one holding an input only with
    contain=True; a sibling is fine."""
    data = tmp_path / "data"
    (data / "sub").mkdir(parents=True)
    with pytest.raises(CcdError, match="would overwrite an input"):
        check_not_inputs([tmp_path / "x" / ".." / "data"], [data])
    with pytest.raises(CcdError, match="is inside"):
        check_not_inputs([data / "sub" / "out.tif"], [data])
    with pytest.raises(CcdError, match="holds"):
        check_not_inputs([tmp_path], [data / "sub"])
    check_not_inputs([tmp_path], [data / "sub"], contain=False)
    check_not_inputs([tmp_path / "data2"], [data])      # a name prefix is not a parent


def test_ownership_of_files_and_folders(tmp_path: Path) -> None:
    """ownership_problem: absent -> None; not recorded -> refused; a file recorded as a file
    -> None; kinds swapped -> refused; a recorded folder holding extra files -> the first
    extra named and the rest counted."""
    (tmp_path / "f.tif").write_bytes(b"1")
    (tmp_path / "d" / "s").mkdir(parents=True)
    for name in ("a", "b", "s/c", "s/e"):
        (tmp_path / "d" / name).write_bytes(b"1")
    record = {"f.tif": None, "d": ["a", "b", "s/c", "s/e"], "g.tif": ["x"]}
    (tmp_path / "g.tif").write_bytes(b"1")
    assert ownership_problem(tmp_path, "none.tif", record) is None
    assert ownership_problem(tmp_path, "f.tif", record) is None
    assert ownership_problem(tmp_path, "d", record) is None
    assert ownership_problem(tmp_path, "f.tif", {}) == "exists and was not written by ccdcore"
    assert ownership_problem(tmp_path, "d", {"d": None}) == \
        "is a folder, where ccdcore wrote a file"
    assert ownership_problem(tmp_path, "g.tif", record) == \
        "is a file, where ccdcore wrote a folder"
    assert ownership_problem(tmp_path, "d", {"d": ["a", "b", "s/c"]}) == \
        "holds s/e, which ccdcore did not write"
    assert ownership_problem(tmp_path, "d", {"d": ["a"]}) == \
        "holds b (and 2 more), which ccdcore did not write"


# ---- the app's result cache (ccdcore_app.cache.store) ------------------------------------------
@pytest.mark.parametrize("text,expected", [
    ("1024", 1024), ("1k", 1024), ("2K", 2048), ("3m", 3 * 1024**2), ("1g", 1024**3),
    ("1t", 1024**4), ("1KiB", 1024), ("1kb", 1024), ("512b", 512), ("0", 0), ("-5", 0),
    ("0.5k", 512), ("  7  ", 7), ("1.9", 1)])
def test_cache_size_suffixes(monkeypatch: pytest.MonkeyPatch, text: str, expected: int) -> None:
    """CCDCORE_CACHE_MAX_BYTES: bytes with an optional K/M/G/T (1024-based, optional 'iB' or
    'B'), fractions truncated, never negative."""
    monkeypatch.setenv("CCDCORE_CACHE_MAX_BYTES", text)
    assert store.max_bytes() == expected


def test_cache_size_default_when_unset_or_not_a_size(monkeypatch: pytest.MonkeyPatch) -> None:
    """Unset, blank or not a number: DEFAULT_MAX_BYTES (2 GiB)."""
    assert store.DEFAULT_MAX_BYTES == 2 * 1024**3
    monkeypatch.delenv("CCDCORE_CACHE_MAX_BYTES", raising=False)
    assert store.max_bytes() == store.DEFAULT_MAX_BYTES
    for text in ("", "  ", "k", "lots", "1x"):
        monkeypatch.setenv("CCDCORE_CACHE_MAX_BYTES", text)
        assert store.max_bytes() == store.DEFAULT_MAX_BYTES


def test_cache_folder_from_the_environment(monkeypatch: pytest.MonkeyPatch,
                                           tmp_path: Path) -> None:
    """CCDCORE_CACHE names the folder; off/0/none/false/no/blank disable it; unset:
    $XDG_CACHE_HOME/ccdcore."""
    monkeypatch.setenv("CCDCORE_CACHE", str(tmp_path / "c"))
    assert store.cache_folder() == tmp_path / "c"
    for off in ("off", " OFF ", "0", "none", "False", "no", "", "  "):
        monkeypatch.setenv("CCDCORE_CACHE", off)
        assert store.cache_folder() is None and store.default_cache() is None
    monkeypatch.delenv("CCDCORE_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert store.cache_folder() == tmp_path / "xdg" / "ccdcore"


def test_eviction_keeps_a_total_exactly_at_the_bound(tmp_path: Path) -> None:
    """evict deletes least recently used entries only while the total exceeds max_bytes: a
    total equal to the bound stays whole; one byte less drops the oldest first."""
    keys = [f"{i:064x}" for i in range(3)]
    probe = ResultCache(tmp_path / "probe", max_bytes=10**9)
    for k in keys:
        probe.put(k, np.arange(50, dtype=np.int64) + int(k, 16))
    sizes = [probe._size(probe._path(k)) for k in keys]
    total = sum(sizes)
    for bound, left in ((total, keys), (total - 1, keys[1:]),
                        (total - sizes[0], keys[1:]), (total - sizes[0] - 1, keys[2:])):
        cache = ResultCache(tmp_path / f"c{bound}", max_bytes=10**9)
        for i, k in enumerate(keys):
            cache.put(k, np.arange(50, dtype=np.int64) + int(k, 16))
            os.utime(cache._path(k), ns=(10**18 + i, 10**18 + i))   # keys[0] the oldest
        cache.max_bytes = bound
        cache.evict()
        assert [p.name[:64] for p in cache.entries()] == left, bound


def test_evict_keeps_the_entry_just_written_last(tmp_path: Path) -> None:
    """evict(keep=key) removes that entry last even when it is the least recently used."""
    cache = ResultCache(tmp_path / "c", max_bytes=10**9)
    keys = [f"{i:064x}" for i in range(3)]
    for i, k in enumerate(keys):
        cache.put(k, np.zeros(40))
        os.utime(cache._path(k), ns=(10**18 + i, 10**18 + i))
    size = cache._size(cache._path(keys[0]))
    cache.max_bytes = 2 * size
    removed = cache.evict(keep=keys[0])
    assert [p.name[:64] for p in removed] == [keys[1]]
    assert sorted(p.name[:64] for p in cache.entries()) == [keys[0], keys[2]]


def test_shared_results_hold_exactly_max_entries() -> None:
    """SharedResults keeps max_entries finished values (least recently used dropped first);
    a weakly held value is found while someone holds it."""
    shared = SharedResults(max_entries=2)
    values = {k: [k] for k in "abc"}     # lists cannot be weakly referenced: held
    for k in "ab":
        _, entry, owner = shared.claim(k)
        assert owner and shared.finish(entry, values[k])
    assert shared.get("b") == ["b"] and shared.get("a") == ["a"]     # both kept, "a" used last
    _, entry, _ = shared.claim("c")
    shared.finish(entry, values["c"])
    assert "b" not in shared and shared.get("a") == ["a"] and shared.get("c") == ["c"]
    _, entry, owner = shared.claim("b")
    assert owner
    assert shared.running("b") is entry
    assert shared.finish(entry, None, None) and shared.running("b") is None
    assert not shared.finish(entry, ["late"])                        # only the first counts
    assert shared.claim("b")[2]                                      # may be claimed again


# ---- the calibration product (ccdcore.product.file) --------------------------------------------
def test_map_problem_k_strictly_positive_others_finite() -> None:
    """K must be finite and > 0 everywhere (it divides: 0 counts, the smallest positive float
    passes); dark etc. only finite (0 and negatives fine); 1-D/4-D or text maps refused."""
    k = np.ones((3, 4), np.float32)
    assert map_problem("K", k) is None
    k[0, 0], k[1, 1] = 0.0, np.inf
    assert map_problem("K", k) == "map 'K' has 2 pixel(s) that are not finite and > 0 (it divides)"
    assert map_problem("K", np.full((2, 2), np.finfo(np.float32).tiny)) is None
    dark = np.array([[0.0, -5.0], [np.nan, -np.inf]])
    assert map_problem("dark", dark) == "map 'dark' has 2 non-finite pixel(s)"
    assert map_problem("dark", dark[:1]) is None
    assert map_problem("hot", np.array([[np.nan]])) is None          # flags are not checked
    assert map_problem("hot", np.zeros((2, 2), bool)) is None
    assert map_problem("flat_G", np.zeros((2, 2, 3))) is None
    for bad in (np.zeros(4), np.zeros((1, 1, 1, 1)), np.array([["a"]])):
        assert "is not a numeric image" in map_problem("dark", bad)


def test_check_maps_shapes_per_family() -> None:
    """Frame maps share one shape and flat maps one shape, the two families independently."""
    ok = {"dark": np.zeros((2, 3)), "K": np.ones((2, 3)), "flat_G": np.ones((4, 5, 3)),
          "flat_O": np.zeros((4, 5, 3))}
    _check_maps(ok, Path("c.json"))
    with pytest.raises(CcdError, match="maps of different shapes"):
        _check_maps({"dark": np.zeros((2, 3)), "K": np.ones((3, 2))}, Path("c.json"))
    with pytest.raises(CcdError, match="maps of different shapes"):
        _check_maps({"flat_G": np.ones((2, 3)), "flat_O": np.zeros((2, 4))}, Path("c.json"))
    with pytest.raises(CcdError, match="unknown map 'gain'"):
        _check_maps({"gain": np.ones((2, 3))}, Path("c.json"))


def test_correct_subtracts_the_dark_then_divides_by_k() -> None:
    """(D - D_D) / K (Healey & Kondepudy eq. 51) with a non-trivial dark and K; D - D_D
    without K; a shape mismatch (transposed) is refused."""
    rng = np.random.default_rng(1)
    frame = rng.integers(100, 200, (3, 5)).astype(np.uint16)
    dark = rng.uniform(5, 10, (3, 5)).astype(np.float32)
    k = rng.uniform(0.5, 2.0, (3, 5)).astype(np.float32)
    p = CalibrationProduct(maps={"dark": dark, "K": k})
    expected = (frame.astype(np.float64) - dark.astype(np.float64)) / k.astype(np.float64)
    np.testing.assert_allclose(p.correct(frame), expected, rtol=1e-6)
    assert p.correct(frame).dtype == np.float32 and p.method == "fixed_pattern"
    d = CalibrationProduct(maps={"dark": dark})
    np.testing.assert_allclose(d.correct(frame), frame - dark.astype(np.float64), rtol=1e-6)
    assert d.method == "dark" and d.shape == (3, 5)
    with pytest.raises(CcdError, match="differs from the calibration maps"):
        p.correct(frame.T)
    with pytest.raises(CcdError, match="no dark reference or flat field"):
        CalibrationProduct(maps={"K": k}).correct(frame)
    flat = CalibrationProduct(maps={"dark": dark, "flat_G": np.ones((6, 7), np.float32)})
    assert flat.shape == (6, 7) and flat.method == "flat_field"
    assert CalibrationProduct(maps={}).shape is None


def test_linearise_codes_through_g_up_to_its_last_level(monkeypatch: pytest.MonkeyPatch) -> None:
    """linearise maps each code c to g[c]; the largest code g.size - 1 is valid, g.size and
    negative codes are refused, float frames too."""
    g = np.linspace(0.0, 1.0, 16) ** 2
    monkeypatch.setattr(CalibrationProduct, "response_models",
                        lambda self, where="x": {"L": SimpleNamespace(g=g)})
    p = CalibrationProduct(maps={})
    codes = np.array([[0, 15, 3], [7, 1, 2]], np.int16)
    np.testing.assert_array_equal(p.linearise(codes), g[codes].astype(np.float32))
    for bad in (np.array([[16]], np.uint8), np.array([[-1, 2]], np.int16)):
        with pytest.raises(CcdError, match="codes beyond the response's 16 levels"):
            p.linearise(bad)
    with pytest.raises(CcdError, match="integer codes"):
        p.linearise(codes.astype(np.float32))


@pytest.mark.parametrize("doc,ok", [({"bits": 1}, True), ({"bits": 32}, True),
                                    ({"bits": 0}, False), ({"bits": 33}, False),
                                    ({"bits": 12.0}, False), ({"black_level": 0}, True),
                                    ({"black_level": -3.5}, True),
                                    ({"black_level": float("inf")}, False),
                                    ({"black_level": "1"}, False), ([], False)])
def test_product_camera_bits_and_black_level(doc: Any, ok: bool) -> None:
    """A product's camera: bits an integer 1..32 (both ends), black_level any finite number."""
    if ok:
        cam = _camera_from(doc, Path("c.json"))
        assert cam.bits == doc.get("bits")
        assert cam.black_level == (None if "black_level" not in doc else float(doc["black_level"]))
    else:
        with pytest.raises(CcdError):
            _camera_from(doc, Path("c.json"))


# ---- open_folder: the camera inferred from the frames ------------------------------------------
def test_folder_camera_from_exif_and_rgba_as_rgb(tmp_path: Path) -> None:
    """Every frame naming one Make/Model names the camera; RGBA frames give layout rgb; the
    bit depth is the deepest integer frame's."""
    root = tmp_path / "shots"
    for i in range(2):
        write_image(root / f"s{i}.tif", np.full((4, 6, 4), 7 * i, np.uint8),
                    attributes={"Make": "Acme", "Model": "X1"})
    s = open_session(root)
    assert (s.camera.name, s.camera.layout, s.camera.bits) == ("Acme X1", "rgb", 8)
    write_image(root / "s2.tif", np.zeros((4, 6, 4), np.uint8),
                attributes={"Make": "Other", "Model": "Y"})
    assert open_session(root).camera.name == "shots"          # two cameras: the folder's name


def test_folder_bits_ignore_float_frames_and_take_the_deepest(tmp_path: Path) -> None:
    """camera bits = the largest header bit depth among integer frames (float maps ignored);
    mixed layouts fall back to mono."""
    root = tmp_path / "bench"
    write_image(root / "dark" / "d0.fits", np.zeros((4, 6), np.uint16), bits=12)
    write_image(root / "dark" / "d1.fits", np.zeros((4, 6), np.uint16), bits=14)
    write_image(root / "flat" / "f0.fits", np.ones((4, 6), np.float32))
    write_image(root / "scene" / "c.tif", np.zeros((4, 6, 3), np.uint8))
    s = open_session(root)
    assert (s.camera.bits, s.camera.layout, s.camera.name) == (14, "mono", "bench")


def test_folder_ptc_levels_from_exposure_pairs(tmp_path: Path) -> None:
    """ptc frames without level numbers in their names pair by exposure time (level 1 the
    shortest), and the folder's note says so."""
    root = tmp_path / "p"
    for name, t in (("pa", 0.02), ("pb", 0.01), ("pc", 0.02), ("pd", 0.01)):
        write_image(root / "ptc" / f"{name}.fits", np.zeros((4, 6), np.uint16), exposure=t)
    s = open_session(root)
    assert {lvl: [r.relpath for r in recs] for lvl, recs in s.ptc_levels().items()} == {
        1: ["ptc/pb.fits", "ptc/pd.fits"], 2: ["ptc/pa.fits", "ptc/pc.fits"]}
    assert "ptc levels 1-2 from the frames' exposure times" in s.problems[0].message


def test_folder_of_rgb_and_rgba_frames_is_mono(tmp_path: Path) -> None:
    """Frames of several layouts (rgb and rgba, either alone read as rgb) leave the camera's
    layout at mono."""
    root = tmp_path / "mixed"
    write_image(root / "a.tif", np.zeros((4, 6, 3), np.uint8))
    write_image(root / "b.tif", np.zeros((4, 6, 4), np.uint8))
    assert open_session(root).camera.layout == "mono"
    (root / "b.tif").unlink()
    assert open_session(root).camera.layout == "rgb"


def test_cache_key_parameters_as_plain_json() -> None:
    """Key parameters are canonical JSON: tuples equal lists, numpy scalars equal numbers,
    paths their text, None and bools kept (None differs from False and 0); other objects are
    refused."""
    assert _canonical({"a": (1, np.int64(2), np.float32(0.5)), 3: Path("x/y"), "n": None,
                       "b": True}) == {"a": [1, 2, 0.5], "3": "x/y", "n": None, "b": True}
    key = ResultCache.key
    assert key("h", "pt", {"roi": (0, 1)}) == key("h", "pt", {"roi": [0, 1]})
    assert len({key("h", "pt", {"v": v}) for v in (None, False, 0, "None")}) == 4
    assert key("h", "pt") == key("h", "pt", {}) != key("h2", "pt") != key("h", "other")
    with pytest.raises(TypeError, match="plain data, not object"):
        _canonical({"x": object()})


def test_cache_encoding_round_trip_keeps_types() -> None:
    """encode/decode give back equal values of the same types: a numpy scalar stays a scalar
    (not a 0-d array), tuples stay tuples, dict keys may be tuples, paths, ccdcore enums and
    dataclasses come back as themselves; other classes are refused."""
    value = {"arr": np.arange(3.0), "s": np.float32(1.5), "t": (1, [2, "x"]), (1, 2): None,
             "p": Path("a/b"), "e": Layout.BAYER_RGGB, "c": Camera(name="n", bits=12),
             "f": 0.25, "b": False}
    arrays: dict = {}
    got = decode(encode(value, arrays), arrays)
    assert set(got) == set(value) and list(arrays) == ["a0", "a1"]
    assert isinstance(got["s"], np.float32) and got["s"] == np.float32(1.5)
    assert isinstance(got["arr"], np.ndarray) and got["arr"].tolist() == [0.0, 1.0, 2.0]
    assert got["t"] == (1, [2, "x"]) and isinstance(got["t"], tuple)
    assert got[(1, 2)] is None and got["p"] == Path("a/b")
    assert got["e"] is Layout.BAYER_RGGB and got["c"] == Camera(name="n", bits=12)
    assert got["b"] is False and got["f"] == 0.25
    for bad in (object(), np.array([None], dtype=object), lambda: 1):
        with pytest.raises(Unserialisable):
            encode(bad, {})


def test_cache_folder_modes(tmp_path: Path) -> None:
    """unsafe_folder: a folder of this user writable only by the user (0700 or 0755) is fine;
    group- or other-writable (0770, 0702) is refused, naming the mode; a file is no folder;
    a missing sub-folder is fine."""
    root = tmp_path / "r"
    (root / "c").mkdir(parents=True)
    os.chmod(root, 0o700)
    for mode, ok in ((0o700, True), (0o755, True), (0o770, False), (0o702, False),
                     (0o720, False)):
        os.chmod(root / "c", mode)
        why = unsafe_folder(root / "c", root)
        assert (why is None) is ok, (oct(mode), why)
        if not ok:
            assert f"(mode {mode:04o}); make it 0700" in why
    os.chmod(root / "c", 0o700)
    assert unsafe_folder(root / "c" / "missing" / "deeper", root) is None
    (root / "c" / "f").write_text("x")
    assert unsafe_folder(root / "c" / "f", root) == f"{root / 'c' / 'f'} is not a folder"


def _demo_session(root: Path) -> Any:
    """A two-frame manifest session on disk."""
    write_image(root / "a.tif", np.arange(24, dtype=np.uint16).reshape(4, 6))
    write_image(root / "b.tif", np.arange(24, dtype=np.uint16).reshape(4, 6)[::-1].copy())
    (root / "session.toml").write_text(
        'schema = 1\n[[frames]]\npath = "b.tif"\nrole = "dark"\n'
        '[[frames]]\npath = "a.tif"\nrole = "dark"\n')
    return open_session(root)


def test_cache_content_hash_by_hand(tmp_path: Path) -> None:
    """content_hash: BLAKE2b-256 keyed stream of the manifest's digest, then per frame its
    relpath and its bytes' BLAKE2b-256 digest, each field length-prefixed (8 bytes little
    endian), as documented; file_digest is BLAKE2b-256 of the bytes."""
    session = _demo_session(tmp_path)

    def blake(data: bytes) -> str:
        return hashlib.blake2b(data, digest_size=32).hexdigest()

    def fld(text: str) -> bytes:
        data = text.encode()
        return len(data).to_bytes(8, "little") + data

    assert file_digest(tmp_path / "a.tif") == blake((tmp_path / "a.tif").read_bytes())
    stream = fld(blake((tmp_path / "session.toml").read_bytes()))
    for rel in ("b.tif", "a.tif"):
        stream += fld(rel) + fld(blake((tmp_path / rel).read_bytes()))
    expected = hashlib.blake2b(b"ccdcore_app cache content v2\0", digest_size=32)
    expected.update(stream)
    assert content_hash(session) == expected.hexdigest()


def test_cache_session_hash_is_indexed_by_stat(tmp_path: Path) -> None:
    """session_hash computes the content hash once and indexes it under the files' stats:
    known_hash then answers without reading; a changed frame is unknown until hashed again."""
    session = _demo_session(tmp_path / "s")
    cache = ResultCache(tmp_path / "c")
    assert cache.known_hash(session) is None
    h = cache.session_hash(session)
    assert h == content_hash(session) and cache.known_hash(session) == h
    assert ResultCache(tmp_path / "c").known_hash(session) == h      # from hashes.json
    a = tmp_path / "s" / "a.tif"
    data = bytearray(a.read_bytes())
    data[-1] ^= 1
    a.write_bytes(bytes(data))
    os.utime(a, ns=(10**18, 10**18))
    assert cache.known_hash(session) is None
    assert cache.session_hash(session) == content_hash(session) != h


def test_cache_index_keeps_the_most_recently_used(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """An index over INDEX_SIZE sessions keeps the INDEX_SIZE most recently used."""
    monkeypatch.setattr(store, "INDEX_SIZE", 3)
    cache = store.ResultCache(tmp_path / "c")
    used = [5, 1, 4, 2, 3]
    sessions = {f"s{i}": {"hash": f"h{i}", "used": float(u)} for i, u in enumerate(used)}
    cache._write_index(sessions)
    kept = json.loads(cache.index_path.read_text())["sessions"]
    assert sorted(kept) == ["s0", "s2", "s4"]
    assert cache._indexed("s2") == "h2" and cache._indexed("s1") is None
    cache.index_path.write_text(json.dumps({"format": store.FORMAT + 1, "sessions": kept}))
    assert cache._indexed("s2") is None                         # another format: ignored
    cache.index_path.write_text(json.dumps({"format": store.FORMAT, "sessions": ["s2"]}))
    assert cache._indexed("s2") is None
    cache.index_path.write_text("[" * 5000)
    assert cache._indexed("s2") is None


def test_cache_put_get_link_and_bad_entries(tmp_path: Path) -> None:
    """put/get round-trip; None is never stored; a link gives its target's value and never
    itself; a corrupt or foreign entry misses and is deleted; a bad key is refused."""
    cache = ResultCache(tmp_path / "c")
    k1, k2, k3 = (f"{i:064x}" for i in (1, 2, 3))
    assert cache.get(k1) is None and not cache.put(k1, None)
    assert cache.put(k1, {"x": np.arange(3), "y": (1, "a")})
    got = cache.get(k1)
    assert got["y"] == (1, "a") and got["x"].tolist() == [0, 1, 2]
    assert not cache.link(k1, k1) and cache.link(k2, k1)
    assert cache.get(k2)["y"] == (1, "a")
    assert cache.get("not-a-key") is None and cache.get(f"{10:064X}") is None
    for bad in ("short", "0" * 65, "g" * 64):
        with pytest.raises(ValueError, match="not a cache key"):
            cache.put(bad, 1)
    cache._path(k3).write_bytes(b"not an npz")
    assert cache.get(k3) is None and not cache._path(k3).exists()
    cache._path(k1).rename(cache._path(k3))                       # its key says k1: foreign
    assert cache.get(k3) is None and not cache._path(k3).exists()
    assert cache.get(k2) is None                                  # its target is gone
    assert not cache.put(f"{4:064x}", object())                   # not encodable: not cached
    (cache.results_dir / "old.pkl").write_bytes(b"x")
    assert ResultCache(tmp_path / "c").put(f"{5:064x}", 1)        # older pickles swept
    assert not (cache.results_dir / "old.pkl").exists()


def test_cache_refuses_an_unsafe_folder(tmp_path: Path) -> None:
    """A cache folder others may write is not used: get misses and put stores nothing."""
    folder = tmp_path / "c"
    cache = ResultCache(folder)
    key = f"{1:064x}"
    assert cache.put(key, 7) and cache.get(key) == 7
    os.chmod(folder, 0o777)
    try:
        assert not cache.usable() and cache.get(key) is None
        assert not cache.put(f"{2:064x}", 8)
    finally:
        os.chmod(folder, 0o700)
    assert cache.get(key) == 7


@pytest.mark.parametrize("data", [{"__dataclass__": "os:PathLike", "fields": {}},
                                  {"__dataclass__": "ccdcore.session.records:Camera",
                                   "fields": {"name": "x"}},
                                  {"__dataclass__": "ccdcore.session.records:Camera",
                                   "fields": []},
                                  {"__enum__": "ccdcore.channels:Layout.__class__", "value": 1},
                                  {"__enum__": "ccdcore.session.records:Camera", "value": 1},
                                  {"__namedtuple__": "ccdcore.channels:Layout", "items": []},
                                  {"__ndarray__": "b0"}, {"__ndarray__": 3}, {"other": 1}, {},
                                  {"__dict__": [[[1], 2]]}, {"__enum__": "a:b:c", "value": 1},
                                  {"__dataclass__": "json:JSONDecoder", "fields": {}},
                                  {"__dataclass__": "ccdcore_no_such_module:Foo", "fields": {}}])
def test_cache_decode_refuses_what_encode_never_writes(data: dict) -> None:
    """decode instantiates only ccdcore's dataclasses/enums/named tuples with their exact
    fields; other classes, names, array names and shapes are errors."""
    with pytest.raises((ValueError, KeyError, TypeError)):      # never an ImportError
        decode(data, {"a0": np.zeros(1), "b0": np.zeros(1)})


def test_cache_small_helpers(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Entry names and parameters; file digests remembered for at most FILE_MEMO_SIZE files;
    temporary files older than an hour swept by evict; weakly held shared values kept only
    while referenced elsewhere."""
    name, params = store.photon_transfer_entry((1, np.int64(2), 3, 4))
    assert (name, params) == ("photon_transfer", {"roi": [1, 2, 3, 4]})
    assert {type(v) for v in params["roi"]} == {int}                 # plain ints for the key
    assert store.photon_transfer_entry(None) == ("photon_transfer", {"roi": None})
    assert store.estimates_entry(None, a=1) == ("estimate_all", {"a": 1, "noise": None})
    monkeypatch.setattr(store, "FILE_MEMO_SIZE", 2)
    monkeypatch.setattr(store, "_FILE_DIGESTS", type(store._FILE_DIGESTS)())
    for i in range(3):
        (tmp_path / f"f{i}").write_bytes(bytes([i]))
        file_digest(tmp_path / f"f{i}")
    assert [Path(k[0]).name for k in store._FILE_DIGESTS] == ["f1", "f2"]
    cache = ResultCache(tmp_path / "c")
    assert cache.put(f"{1:064x}", 1)
    old, new = cache.results_dir / ".x.tmp", cache.results_dir / ".y.tmp"
    old.write_bytes(b"1"), new.write_bytes(b"1")
    os.utime(old, (1e9, 1e9))
    cache.evict()
    assert not old.exists() and new.exists()
    shared = SharedResults(max_entries=1)
    value = np.arange(3)                                    # weakly referable
    shared.finish(shared.claim("w")[1], value, hold=False)
    assert shared.get("w") is value
    del value
    gc.collect()
    assert shared.get("w") is None


@pytest.mark.parametrize("schema,hidden", [("1", False), ("true", False), ("1.0", False),
                                       ("2", False), ("1", True)])
def test_manifest_schema_and_glob_counts(tmp_path: Path, schema: str, hidden: bool) -> None:
    """schema must be the integer 1 (true and 1.0 equal 1 in Python, yet are refused); a glob
    skips hidden files and counts the non-image files it matched ('2 non-image files')."""
    root = tmp_path / "m"
    write_image(root / "d" / ".hidden.tif", np.zeros((2, 2), np.uint8))
    for name in ("a.txt", "b.csv"):
        (root / "d" / name).write_text("x")
    glob = 'd/*' if not hidden else 'd/.hidden.tif'
    (root / "session.toml").write_text(f'schema = {schema}\n[camera]\nbits = 8\n'
                                       f'[[groups]]\nglob = "{glob}"\nrole = "dark"\n')
    s = open_session(root)
    msgs = [(p.where, p.message) for p in s.errors]
    if schema != "1":
        assert msgs[0] == ("schema", f"unsupported schema {json.loads(schema)!r}; this "
                                     "version reads schema = 1")
    empty = "glob matches no image file" + ("" if hidden else " (2 non-image files)")
    assert msgs[-1] == (f"groups[0] ({glob})", empty)


def test_oiio_sample_types_per_format(tmp_path: Path) -> None:
    """EXR stores float16/float32 (other types become float32); PNG/PGM only uint8/uint16."""

    p = tmp_path / "x"
    assert oiio_samples(p, np.ones((2, 2, 1), np.float16), ".exr").dtype == np.float16
    for dt in (np.float64, np.uint16, np.int32):
        assert oiio_samples(p, np.ones((2, 2, 1), dt), ".exr").dtype == np.float32
    assert oiio_samples(p, np.ones((2, 2, 1), np.uint16), ".pgm").dtype == np.uint16
    for a, suffix in ((np.ones((2, 2, 1), np.int16), ".png"), (np.ones((2, 2, 1)), ".ppm"),
                      (np.ones((2, 2, 1), np.uint16), ".gif"), (np.ones((2, 2, 1), "u8"), ".tif")):
        with pytest.raises(ImageWriteError):
            oiio_samples(p, a, suffix)
