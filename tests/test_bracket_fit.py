"""A bracket from its files to a response on handheld and moving brackets
(ccdcore.response.bracket_fit): registration before the fit and the merge, the frames that
cannot be registered, one verdict that says both, and the command line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from ccdcore.cli.command import main
from ccdcore.io.frames import read_image
from ccdcore.response.bracket_fit import fit_bracket, register_frames
from ccdcore.response.brackets import bracket_records
from ccdcore.session import open_session
from ccdcore.simulate import simulate


@pytest.fixture(scope="module")
def tripod(tmp_path_factory):
    root = tmp_path_factory.mktemp("tripod") / "s"
    simulate("tsin01-camera", root, seed=5)
    return root


@pytest.fixture(scope="module")
def handheld(tmp_path_factory):
    root = tmp_path_factory.mktemp("handheld") / "s"
    simulate("tsin01-camera", root, seed=5, handheld_shift=3.0)
    return root


def _frames(root):
    s = open_session(root)
    recs = bracket_records(s)
    return s, recs, [s.read(r) for r in recs]


def test_a_tripod_bracket_is_left_as_it_is(tripod):
    _, recs, frames = _frames(tripod)
    out, reg, no_data, keep = register_frames(frames, [r.relpath for r in recs])
    assert keep == list(range(len(frames))) and no_data is None
    assert all(a is f for a, f in zip(out, frames))            # not resampled: the same arrays
    assert reg.describe().startswith("frames registered (tripod)")
    off = register_frames(frames, [r.relpath for r in recs], "off")
    assert off[1] is None and all(a is f for a, f in zip(off[0], frames))


def test_a_handheld_bracket_is_registered_to_its_truth(handheld):
    # the simulator's transforms (truth.json, the aligner's convention), within three stated
    # errors plus the camera pipeline's biases (tone curve, Bayer, sharpening, JPEG: up to
    # about 0.2 px)
    truth = json.loads((handheld / "truth.json").read_text())
    moved = {t["file"]: t for t in truth["transforms"]}
    _, recs, frames = _frames(handheld)
    out, reg, no_data, keep = register_frames(frames, [r.relpath for r in recs])
    assert reg.alignment.any_applied and no_data is not None and no_data.any()
    for s in reg.alignment.shifts:
        if not s.registered:
            continue
        t = moved[s.name]
        assert abs(s.dx - t["dx"]) <= 3 * s.dx_err + 0.2, (s, t)
        assert abs(s.dy - t["dy"]) <= 3 * s.dy_err + 0.2, (s, t)
        if s.applied:
            assert out[keep.index(recs.index(next(r for r in recs if r.relpath == s.name)))] \
                is not frames[[r.relpath for r in recs].index(s.name)]
    # the border without data is about the largest shift wide, never the frame's middle
    h, w = no_data.shape
    assert not no_data[h // 4:3 * h // 4, w // 4:3 * w // 4].any()


def test_registration_improves_the_fit_of_a_handheld_bracket(handheld):
    s = open_session(handheld)
    on = fit_bracket(s)
    off = fit_bracket(s, align="off")
    assert on.result.agreement.rms < off.result.agreement.rms
    v = on.result.verdict
    assert v.registration == on.alignment.describe() and "aligned to" in v.registration
    assert v.moving == on.moving.describe()
    assert off.result.verdict.registration == ""


def test_a_frame_too_plain_to_register(tripod, handheld):
    """Kept as it is when no other frame moved (a tripod's night scene: its shortest exposure
    holds the lights); left out with its reason when the others moved."""
    for root, kept in ((tripod, True), (handheld, False)):
        _, recs, frames = _frames(root)
        frames = list(frames)
        flat = np.full_like(frames[0], 128)
        frames[0] = flat
        names = [r.relpath for r in recs]
        out, reg, _, keep = register_frames(frames, names)
        text = reg.describe()
        assert f"{names[0]}: too little structure to register" in text
        if kept:
            assert 0 in keep and out[0] is flat and "kept as it is" in text
        else:
            assert 0 not in keep and len(out) == len(frames) - 1 and "1 left out" in text


def test_cli_hdr_says_the_registration_and_the_moving_pixels(handheld, tmp_path, capsys):
    assert main(["hdr", str(handheld), "-o", str(tmp_path / "a"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["registration"]["any_applied"] and d["registration"]["describe"] \
        == d["verdict"]["registration"]
    assert d["moving"]["pixels"] == d["flags"]["moving"] or d["moving"]["pixels"] >= 0
    flags = read_image(tmp_path / "a" / "flags.png")
    assert int(np.count_nonzero(flags == 4)) == d["flags"]["moving"]
    assert main(["hdr", str(handheld), "-o", str(tmp_path / "b"), "--json",
                 "--align", "off"]) == 0
    d2 = json.loads(capsys.readouterr().out)
    assert d2["registration"] is None and d2["verdict"]["registration"] == ""
    assert main(["response", str(handheld), "--align", "off"]) == 0
    assert main(["hdr", str(handheld), "-o", str(tmp_path / "c")]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "frames aligned to" in text and "moving objects:" in text
    assert "4 from one exposure where something moved" in text


def test_the_product_and_the_report_say_the_registration(handheld, tmp_path, capsys):
    """calibrate records the verdict with its registration and moving pixels; the report
    shows them in the same words (rows of the response section)."""
    from ccdcore.product.make import load_product

    assert main(["calibrate", str(handheld), "-o", str(tmp_path / "p")]) == 0
    v = load_product(tmp_path / "p").estimates.response.verdict
    assert "aligned to" in v.registration and v.moving.startswith("moving objects:")
    fit = fit_bracket(open_session(handheld))
    assert v.registration == fit.result.verdict.registration
    assert main(["report", str(tmp_path / "p"), "-o", str(tmp_path / "r.html")]) == 0
    html = (tmp_path / "r.html").read_text()
    for text in (v.registration, v.moving):
        assert text.replace("'", "&#x27;") in html or text in html
    capsys.readouterr()
