"""A plain folder of bracketed camera frames (JPEG, PNG, TIFF, raw) read as an exposure bracket:
roles, stacks and exposures from EXIF, the draft manifest, and the problems that name files."""
from __future__ import annotations

import dataclasses
import json
import struct
from pathlib import Path

import numpy as np
import pytest

import ccdcore.io.frames as io_mod
import ccdcore.session.folder as folder_mod
from ccdcore.cli.command import main
from ccdcore.io.frames import ImageHeader, _exposure_seconds, read_header, write_image
from ccdcore.response.brackets import load_bracket
from ccdcore.session import FrameRecord, Session, draft_manifest, open_session
from ccdcore.session.folder import MISSING_EXPOSURE_NOTE, format_exposure
from ccdcore.session.manifest import open_manifest

H, W = 24, 32
#: a camera's shutter speeds, as the EXIF rationals it writes
SPEEDS = ((1, 1000), (1, 250), (1, 60), (1, 15))
CAMERA = {"Make": "Canon", "Model": "Canon EOS 80D", "Exif:ISOSpeedRatings": 100,
          "FNumber": 8.0}


def gradient(seconds: float, colour: bool = True, dtype=np.uint8, shape=(H, W)) -> np.ndarray:
    """A fixed scene (a gradient) exposed for ``seconds``, clipped like a camera does."""
    y, x = np.mgrid[0:shape[0], 0:shape[1]]
    radiance = 1.0 + x * 7.0 + y * 3.0
    top = np.iinfo(dtype).max
    scale = top / 300.0 * 15.0  # 1/15 s saturates the bright corner
    if colour:
        img = radiance[..., None] * np.array([1.0, 0.8, 0.6]) * seconds * scale
    else:
        img = radiance * seconds * scale
    return np.clip(np.round(img), 0, top).astype(dtype)


def set_exif_exposure(path: Path, num: int, den: int) -> None:
    """Rewrite a JPEG's EXIF ExposureTime (tag 0x829a, RATIONAL) to exactly ``num/den``, as a
    camera writes it (OpenImageIO's writer rounds 1/60 to 16666/1000000)."""
    data = bytearray(path.read_bytes())
    tiff = data.index(b"Exif\x00\x00") + 6
    order = "<" if data[tiff:tiff + 2] == b"II" else ">"

    def patch(ifd: int) -> bool:
        (count,) = struct.unpack_from(order + "H", data, tiff + ifd)
        for k in range(count):
            entry = tiff + ifd + 2 + 12 * k
            tag, kind, _, value = struct.unpack_from(order + "HHII", data, entry)
            if tag == 0x829A and kind == 5:
                struct.pack_into(order + "II", data, tiff + value, num, den)
                return True
            if tag == 0x8769 and patch(value):
                return True
        return False

    (first,) = struct.unpack_from(order + "I", data, tiff + 4)
    assert patch(first), f"{path}: no EXIF ExposureTime to rewrite"
    path.write_bytes(bytes(data))


def put_jpeg(root: Path, rel: str, speed: tuple[int, int] | None, **attributes) -> Path:
    seconds = 1.0 / 250 if speed is None else speed[0] / speed[1]
    path = write_image(root / rel, gradient(seconds), exposure=None if speed is None else seconds,
                       attributes={**CAMERA, **attributes})
    if speed is not None:
        set_exif_exposure(path, *speed)
    return path


@pytest.fixture
def jpeg_folder(tmp_path: Path) -> Path:
    """A camera's folder: four bracketed JPEGs at the top level, nothing else."""
    root = tmp_path / "DCIM"
    for i, speed in enumerate(SPEEDS):
        put_jpeg(root, f"IMG_{i:04d}.JPG", speed)
    return root


def problems(session: Session, code: str) -> list[tuple[str, str]]:
    return [(p.where, p.message) for p in session.problems if p.code == code]


def strip(rec: FrameRecord) -> FrameRecord:
    return dataclasses.replace(rec, inferred=())


# --------------------------------------------------------------------------------------------
# reading exposure times
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("value, seconds", [
    ((1, 250), 0.004), ("1/250", 0.004), ("1/250 s", 0.004), ("0.004", 0.004),
    (0.004000000189989805, 0.004), (30, 30.0), ("1/3", 1 / 3), ((1, 0), None), ("fast", None),
    # EXIF rationals handed on as float32: the camera's fraction, or the shortest decimal
    (float(np.float32(1 / 60)), 1 / 60), (float(np.float32(10 / 13)), 10 / 13),
    (float(np.float32(0.033)), 0.033), (float(np.float32(0.0166667)), 0.0166667),
    (-0.5, None), (None, None), (float("nan"), None), (True, None)])
def test_exposure_times_as_rationals_or_floats(value, seconds) -> None:
    got = _exposure_seconds(value)
    assert got == seconds  # exactly: 1/60 s is 0.016666666666666666, as 1 / 60


def test_exif_rational_exposure_reads_as_seconds(tmp_path: Path) -> None:
    path = put_jpeg(tmp_path, "a.jpg", (1, 60))
    hdr = read_header(path)
    assert hdr.exposure == pytest.approx(1 / 60, rel=1e-6)
    assert (hdr.attributes["Make"], hdr.attributes["Model"]) == ("Canon", "Canon EOS 80D")
    assert format_exposure(hdr.exposure) == "1/60 s" and format_exposure(0.3) == "0.3 s"


# --------------------------------------------------------------------------------------------
# a JPEG bracket at the top level
# --------------------------------------------------------------------------------------------
def test_top_level_jpegs_are_one_bracket(jpeg_folder: Path) -> None:
    s = open_session(jpeg_folder)
    assert s.source == "folder" and s.ok, s.problems
    assert s.roles() == {"bracket": 4}
    assert [r.stack for r in s.frames] == [1, 1, 1, 1]
    assert [r.exposure for r in s.frames] == pytest.approx([n / d for n, d in SPEEDS], rel=1e-6)
    assert all(r.inferred == ("role", "stack", "exposure") for r in s.frames)
    assert (s.camera.name, s.camera.bits, s.camera.layout) == ("Canon EOS 80D", 8, "rgb")
    (warning,) = s.problems
    assert warning.code == "folder-inferred" and warning.severity == "warning"
    assert "roles inferred from folder names and EXIF exposure times (bracket: 4)" in \
        warning.message
    assert ("stack 1 = 4 frames in the top-level folder, 1/1000 s to 1/15 s (one size, camera "
            "and settings; 4 exposure times from file headers)") in warning.message
    assert list(s.bracket_stacks()) == [1]


def test_jpeg_bracket_draft_round_trip_and_load_bracket(jpeg_folder: Path) -> None:
    s = open_session(jpeg_folder)
    draft = draft_manifest(s)
    text = draft.read_text()
    assert text.count('role = "bracket"') == 4 and text.count("stack = 1") == 4
    assert "exposure = 0.016666666666666666" in text  # 1/60 s, exactly as the camera wrote it
    assert "# inferred: role, stack, exposure" in text
    again = open_manifest(draft)  # the draft opened as a manifest
    assert again.source == "manifest" and again.problems == ()
    assert again.camera == s.camera
    assert [strip(r) for r in again.frames] == [strip(r) for r in s.frames]
    assert {k: [r.relpath for r in v] for k, v in again.bracket_stacks().items()} == \
        {k: [r.relpath for r in v] for k, v in s.bracket_stacks().items()}
    # the response code reads the inferred bracket as it reads the manifest's
    data, from_draft = load_bracket(s), load_bracket(again)
    assert list(data) == ["R", "G", "B"]
    np.testing.assert_allclose(data["G"].t, [n / d for n, d in SPEEDS], rtol=1e-6)
    assert list(data["G"].files) == [f"IMG_{i:04d}.JPG" for i in range(4)]
    for channel in data:
        np.testing.assert_array_equal(data[channel].z, from_draft[channel].z)


def test_cli_session_draft_on_a_camera_folder(jpeg_folder: Path, capsys) -> None:
    code = main(["session", str(jpeg_folder), "--draft", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["ok"] and out["roles"] == {"bracket": 4}
    assert out["camera"] == {"name": "Canon EOS 80D", "bits": 8, "layout": "rgb",
                             "black_level": None}
    assert Path(out["draft"]) == jpeg_folder.resolve() / "session.toml.draft"
    assert open_manifest(Path(out["draft"])).by_role("bracket")[0].stack == 1


# --------------------------------------------------------------------------------------------
# TIFF brackets in sub-folders, several brackets, scenes left alone
# --------------------------------------------------------------------------------------------
def test_tiff_bracket_in_a_subfolder_beside_role_folders(tmp_path: Path) -> None:
    root = tmp_path / "bench"
    times = [0.125, 1 / 3, 0.5, 2.0]  # floats; 1/3 goes through EXIF's float32
    for i, t in enumerate(times):
        write_image(root / f"house/f{i}.tif", gradient(t / 40, colour=False, dtype=np.uint16),
                    exposure=t)
    for i in range(2):
        write_image(root / f"darks/d{i}.tif", np.full((H, W), 64 + i, np.uint16), exposure=2.0)
    write_image(root / "overview.tif", gradient(0.01, colour=False, dtype=np.uint16),
                exposure=0.01)  # one image at the top level: a scene
    s = open_session(root)
    assert s.ok, s.problems
    assert s.roles() == {"dark": 2, "bracket": 4, "scene": 1}
    bracket = s.bracket_stacks()
    assert list(bracket) == [1]
    assert [r.relpath for r in bracket[1]] == [f"house/f{i}.tif" for i in range(4)]
    assert [r.exposure for r in bracket[1]] == pytest.approx(times, rel=1e-6)
    assert (s.camera.bits, s.camera.layout) == (16, "mono")
    assert s.camera.name == "bench"  # no EXIF Make/Model: the folder's name
    assert "stack 1 = 4 frames in house/, 1/8 s to 2 s" in s.problems[0].message
    (data,) = load_bracket(s).values()  # mono: one channel
    np.testing.assert_allclose(data.t, times, rtol=1e-12)  # 1/3 s: the float32 read back as 1/3
    again = open_manifest(draft_manifest(s))
    assert again.ok and [strip(r) for r in again.frames] == [strip(r) for r in s.frames]


def test_named_bracket_subfolders_and_repeated_sequences_are_stacks(tmp_path: Path) -> None:
    root = tmp_path / "c"
    for folder in ("hdr/kitchen", "hdr/yard"):
        for i, speed in enumerate(SPEEDS[:3]):
            put_jpeg(root, f"{folder}/{i}.jpg", speed)
    # three exposures repeated twice in file-name order: two brackets in one folder
    for i, speed in enumerate(SPEEDS[1:] * 2):
        put_jpeg(root, f"seq/{i:02d}.jpg", speed)
    s = open_session(root)
    assert s.ok, s.problems
    stacks = {k: [r.relpath for r in v] for k, v in s.bracket_stacks().items()}
    assert stacks == {1: ["hdr/kitchen/0.jpg", "hdr/kitchen/1.jpg", "hdr/kitchen/2.jpg"],
                      2: ["hdr/yard/0.jpg", "hdr/yard/1.jpg", "hdr/yard/2.jpg"],
                      3: ["seq/00.jpg", "seq/01.jpg", "seq/02.jpg"],
                      4: ["seq/03.jpg", "seq/04.jpg", "seq/05.jpg"]}
    assert "stacks 3-4 (2 repeated sequences of 3) = 6 frames in seq/" in s.problems[0].message


def test_images_at_one_exposure_stay_scenes(tmp_path: Path) -> None:
    root = tmp_path / "scenes_only"
    for i in range(3):
        put_jpeg(root, f"p{i}.jpg", (1, 125))
    s = open_session(root)
    assert s.ok and s.roles() == {"scene": 3}
    assert [p.code for p in s.problems] == ["folder-inferred"]
    assert "roles inferred from folder names (scene: 3)" in s.problems[0].message


# --------------------------------------------------------------------------------------------
# problems: each names the file(s), never a crash
# --------------------------------------------------------------------------------------------
def test_frame_without_exposure_is_a_problem_naming_it(jpeg_folder: Path) -> None:
    put_jpeg(jpeg_folder, "IMG_0004.JPG", None)  # same camera and size, no ExposureTime
    s = open_session(jpeg_folder)
    assert s.roles() == {"bracket": 5}
    ((where, message),) = problems(s, "missing-exposure")
    assert where == "IMG_0004.JPG"
    assert "missing exposure: a bracket frame needs one" in message
    assert "fill in its 'exposure' (seconds) in the manifest draft" in message
    assert not s.ok and s.errors_for(["dark"]) == ()
    rec = {r.relpath: r for r in s.frames}["IMG_0004.JPG"]
    assert (rec.exposure, rec.stack, rec.note) == (None, 1, MISSING_EXPOSURE_NOTE)
    text = draft_manifest(s).read_text()
    assert text.count("fill in 'exposure' in seconds") == 1
    # the draft opened as a manifest reports the same frame until the exposure is filled in
    again = open_manifest(jpeg_folder / "session.toml.draft")
    assert [w for w, _ in problems(again, "missing-exposure")] == ["IMG_0004.JPG"]
    fixed = text.replace('path = "IMG_0004.JPG"\nrole = "bracket"\n',
                         'path = "IMG_0004.JPG"\nrole = "bracket"\nexposure = 0.25\n')
    (jpeg_folder / "session.toml").write_text(fixed)
    assert open_session(jpeg_folder).ok


def test_png_bracket_folder_without_exif_names_every_file(tmp_path: Path) -> None:
    root = tmp_path / "pngs"
    for i, t in enumerate((0.01, 0.04, 0.16)):
        write_image(root / f"bracket/b{i}.png", gradient(t))  # PNG: no EXIF written
    s = open_session(root)
    assert s.roles() == {"bracket": 3} and (s.camera.bits, s.camera.layout) == (8, "rgb")
    missing = problems(s, "missing-exposure")
    assert [w for w, _ in missing] == ["bracket/b0.png", "bracket/b1.png", "bracket/b2.png"]
    assert all("PNG files seldom carry EXIF, so a folder of PNG frames needs that manifest" in m
               for _, m in missing)
    with pytest.raises(Exception, match="bracket/b0.png: missing exposure"):
        s.raise_if_invalid(["bracket"])
    assert draft_manifest(s).read_text().count(MISSING_EXPOSURE_NOTE) == 3


def test_png_images_without_exif_at_top_level_stay_scenes(tmp_path: Path) -> None:
    root = tmp_path / "pngs"
    for i, t in enumerate((0.01, 0.04)):
        write_image(root / f"b{i}.png", gradient(t))
    s = open_session(root)
    assert s.ok and s.roles() == {"scene": 2}
    ((where, message),) = problems(s, "not-a-bracket")  # a warning says how to make a bracket
    assert where == "."
    assert message.startswith("the 2 images in the top-level folder are read as scenes, not as "
                              "an exposure bracket: none of them carries an exposure time "
                              "(EXIF ExposureTime; PNG files seldom have EXIF). If they are a "
                              "bracket, write a manifest")


def test_frame_of_another_size_is_a_problem_naming_it(jpeg_folder: Path) -> None:
    path = write_image(jpeg_folder / "IMG_0009.JPG", gradient(1 / 30, shape=(H // 2, W)),
                       exposure=1 / 30, attributes=CAMERA)
    assert read_header(path).shape == (H // 2, W, 3)
    s = open_session(jpeg_folder)
    assert s.roles() == {"bracket": 5}
    ((where, message),) = problems(s, "mismatch")
    assert where == "IMG_0009.JPG"
    assert message == "size 32 × 12 × 3 differs from 32 × 24 × 3 of the other bracket frames " \
                      "(4 frames)"


def test_images_of_mixed_sizes_without_a_majority_stay_scenes(tmp_path: Path) -> None:
    root = tmp_path / "m"
    put_jpeg(root, "a.jpg", (1, 250))
    write_image(root / "b.jpg", gradient(1 / 60, shape=(H // 2, W)), exposure=1 / 60,
                attributes=CAMERA)
    s = open_session(root)
    assert s.ok and s.roles() == {"scene": 2}
    ((where, message),) = problems(s, "not-a-bracket")
    assert where == "."
    assert "the images differ in size or bit depth (32x24 uint8 8-bit: a.jpg; 32x12 uint8 " \
           "8-bit: b.jpg)" in message


def test_repeated_exposure_times_that_are_not_sequences_name_the_files(jpeg_folder: Path) -> None:
    put_jpeg(jpeg_folder, "IMG_0004.JPG", SPEEDS[1])  # a second 1/250 s frame
    s = open_session(jpeg_folder)
    assert s.roles() == {"bracket": 5} and [r.stack for r in s.frames] == [1] * 5
    ((where, message),) = problems(s, "duplicate-exposure")
    assert where == "IMG_0001.JPG"
    assert message.startswith("2 frames of one bracket have the same exposure time 1/250 s "
                              "(EXIF ExposureTime): IMG_0001.JPG, IMG_0004.JPG; a bracket has "
                              "one frame per exposure time")
    assert s.errors_for(["bracket"]) and not s.errors_for(["dark"])


def test_changed_iso_or_camera_is_said(tmp_path: Path) -> None:
    root = tmp_path / "iso"
    for i, speed in enumerate(SPEEDS[:3]):
        put_jpeg(root, f"top/{i}.jpg", speed, **{"Exif:ISOSpeedRatings": 100 * 2 ** i})
        put_jpeg(root, f"bracket/{i}.jpg", speed, **{"Exif:ISOSpeedRatings": 100 + 100 * (i == 2)})
        put_jpeg(root, f"two/{i}.jpg", speed, Model="Canon EOS R5" if i else "Canon EOS 80D")
    s = open_session(root)
    roles = {r.relpath: r.role for r in s.frames}
    assert [roles[f"top/{i}.jpg"] for i in range(3)] == ["scene"] * 3
    assert [roles[f"two/{i}.jpg"] for i in range(3)] == ["scene"] * 3
    assert [roles[f"bracket/{i}.jpg"] for i in range(3)] == ["bracket"] * 3
    warnings = dict(problems(s, "not-a-bracket"))
    assert "ISO differs (100: top/0.jpg; 200: top/1.jpg; 400: top/2.jpg)" in warnings["top/"]
    assert ("camera differs (Canon EOS 80D: two/0.jpg; Canon EOS R5: two/1.jpg, two/2.jpg)"
            in warnings["two/"])
    (error,) = [p for p in s.errors if p.code == "bracket-settings"]
    assert error.where == "bracket/" and error.roles == ("bracket",)
    assert error.message.startswith("the bracket's ISO differs (100: bracket/0.jpg, "
                                    "bracket/1.jpg; 200: bracket/2.jpg)")
    assert s.camera.name == "iso"  # frames from two cameras: the folder's name


def test_unreadable_file_in_a_bracket_is_named(jpeg_folder: Path) -> None:
    (jpeg_folder / "IMG_0007.JPG").write_bytes(b"\xff\xd8 not really a jpeg")
    s = open_session(jpeg_folder)
    assert s.roles() == {"bracket": 5}
    assert [p.where for p in s.errors] == ["IMG_0007.JPG"]
    assert s.errors[0].code == "unreadable"


# --------------------------------------------------------------------------------------------
# camera raw (headers faked: no raw file can be made here)
# --------------------------------------------------------------------------------------------
def test_raw_frames_and_their_jpegs_are_separate_brackets(tmp_path: Path, monkeypatch) -> None:
    root = tmp_path / "raw"
    root.mkdir()
    exposures = {f"IMG_{i}": n / d for i, (n, d) in enumerate(SPEEDS[:3])}
    for stem in exposures:
        (root / f"{stem}.CR2").write_bytes(b"raw")
        put_jpeg(root, f"{stem}.JPG", SPEEDS[int(stem[-1])])
    real = folder_mod.read_header

    def fake(path: Path) -> ImageHeader:
        if path.suffix != ".CR2":
            return real(path)
        return ImageHeader(path=path, width=64, height=48, channels=1,
                           dtype=np.dtype("uint16"), bits=14, layout="bayer-rggb",
                           exposure=exposures[path.stem], format="raw",
                           attributes={"Make": "Canon", "Model": "Canon EOS 80D"})

    monkeypatch.setattr(folder_mod, "read_header", fake)
    s = open_session(root)
    stacks = {k: [r.relpath for r in v] for k, v in s.bracket_stacks().items()}
    assert stacks == {1: ["IMG_0.JPG", "IMG_1.JPG", "IMG_2.JPG"],
                      2: ["IMG_0.CR2", "IMG_1.CR2", "IMG_2.CR2"]}
    assert "stack 2 = 3 frames in the top-level folder (camera raw files)" in \
        s.problems[0].message
    # the frames of the bracket role share one size: the JPEGs (the first frame's size is the
    # raw one) are named until the user keeps one kind
    assert {p.where for p in s.errors if p.code == "mismatch"} == {
        "IMG_0.JPG", "IMG_1.JPG", "IMG_2.JPG"}


def test_raw_header_carries_the_exif_camera_settings(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "x.dng"
    path.write_bytes(b"raw")

    class FakeRaw:
        raw_image_visible = np.zeros((4, 6), np.uint16)
        white_level = 16383
        color_desc = b"RGBG"
        raw_pattern = np.array([[0, 1], [3, 2]])

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

    exif = ImageHeader(path=path, width=1, height=1, channels=3, dtype=np.dtype("uint8"),
                       bits=8, layout="rgb", exposure=0.004,
                       attributes={"Make": "Nikon", "Model": "D850", "FNumber": 5.6,
                                   "oiio:BitsPerSample": 8, "tiff:Compression": 1})
    monkeypatch.setattr(io_mod, "_raw_open", lambda p: FakeRaw())
    monkeypatch.setattr(io_mod, "_oiio_header", lambda p: exif)
    hdr = read_header(path)
    assert (hdr.exposure, hdr.bits, hdr.layout, hdr.shape) == (0.004, 14, "bayer-rggb", (4, 6))
    assert hdr.attributes == {"Make": "Nikon", "Model": "D850", "FNumber": 5.6}
    assert folder_mod.capture_settings(hdr) == {"camera": "Nikon D850", "aperture": "f/5.6"}


# --------------------------------------------------------------------------------------------
# roles from file names, photon-transfer pairs from exposure times
# --------------------------------------------------------------------------------------------
def _tif(root: Path, rel: str, seconds: float | None, gain: float | None = None) -> None:
    attrs = {"GAIN": gain} if gain is not None else None     # a FITS header's gain
    write_image(root / rel, np.full((8, 8), int(100 * (seconds or 0.01)) + 10, np.uint16),
                exposure=seconds, attributes=attrs)


@pytest.mark.parametrize("name, role", [
    ("dark_0.01s_001.tif", "dark"), ("bias-3.tif", "dark"), ("DARK001.tif", "dark"),
    ("ptc_L03_a.tif", "ptc"), ("FLAT_10ms_a.tif", "flat"), ("fpn 2.tif", "fixed_pattern"),
    ("darkroom.tif", None), ("white_wall.tif", None), ("img_0001.tif", None), ("dark.tif", "dark"),
    ("bracket_1.tif", None), ("flat", None)])
def test_file_name_roles(name, role) -> None:
    assert folder_mod.file_name_role(name) == role


def test_top_level_tiffs_named_for_roles_and_ptc_pairs_by_exposure(tmp_path: Path) -> None:
    root = tmp_path / "ccd"
    for t in (0.01, 0.02, 0.04):
        for k in "ab":
            _tif(root, f"ptc_{t:.3f}s_{k}.tif", t)
    for i in range(3):
        _tif(root, f"dark_{i:03d}.tif", 0.01)
    _tif(root, "img_0001.tif", 0.01)
    s = open_session(root)
    assert s.ok, s.problems
    roles = {r.relpath: r.role for r in s.frames}
    assert roles["dark_000.tif"] == "dark" and roles["img_0001.tif"] == "scene"
    levels = {lv: sorted(r.relpath for r in recs) for lv, recs in s.ptc_levels().items()}
    assert levels == {1: ["ptc_0.010s_a.tif", "ptc_0.010s_b.tif"],
                      2: ["ptc_0.020s_a.tif", "ptc_0.020s_b.tif"],
                      3: ["ptc_0.040s_a.tif", "ptc_0.040s_b.tif"]}
    assert all("level" in r.inferred for r in s.by_role("ptc"))
    [note] = [p.message for p in s.problems if p.code == "folder-inferred"]
    assert "the file names of 9 frames" in note
    assert "ptc levels 1-3 from the frames' exposure times" in note


def test_ptc_levels_from_file_numbers_first_and_nothing_guessed_without_pairs(tmp_path) -> None:
    root = tmp_path / "a"
    for lv in (1, 2):                      # numbers make pairs: kept, whatever the exposures
        for k in "ab":
            _tif(root, f"ptc/L0{lv}_{k}.tif", 0.01 * (3 - lv))
    s = open_session(root)
    assert sorted(s.ptc_levels()) == [1, 2]
    root = tmp_path / "b"                  # one frame per exposure: no pairs, not guessed
    for i, t in enumerate((0.01, 0.02, 0.04)):
        _tif(root, f"ptc/img_{i}.tif", t)
    s = open_session(root)
    assert sorted(s.ptc_levels()) == [0, 1, 2]
    assert "one frame" in " ".join(p.message for p in s.errors)
    assert not any("exposure times (frames of one" in p.message for p in s.problems)
    root = tmp_path / "c"                  # pairs by exposure, but two gains: not guessed
    for t, g in ((0.01, 1.0), (0.01, 2.0), (0.02, 1.0), (0.02, 2.0)):
        _tif(root, f"ptc/img_{t}_{g}.fits", t, gain=g)
    s = open_session(root)
    assert {r.gain for r in s.frames} == {1.0, 2.0}
    assert not any("exposure times (frames of one" in p.message for p in s.problems)


def test_flat_pairs_stay_flats(tmp_path: Path) -> None:
    root = tmp_path / "f"
    for t in (0.01, 0.02):
        for k in "ab":
            _tif(root, f"flat_{k}_{t}.tif", t)
    s = open_session(root)
    assert {r.role for r in s.frames} == {"flat"} and not s.ptc_levels()
