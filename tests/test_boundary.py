"""The file boundary and honest exits: partial products, verbs that refuse bad sessions, products
validated on load, manifests with a BOM or in a folder, descriptors with bad numbers, the texts a
person reads (help, valid/invalid, no doubled prefixes, no overlong lines)."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from ccdcore.cli.command import build_parser, main
from ccdcore.errors import CcdError, SessionError
from ccdcore.io.frames import TEMP_PREFIX, write_image, write_map
from ccdcore.noise import photon_transfer
from ccdcore.product.make import REQUIREMENTS, calibrate, load_product, missing_frames
from ccdcore.session import open_session
from ccdcore.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def h94(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("b") / "h94"
    simulate("healey94", root, seed=5, size=(48, 32), n1=3, n2=2)
    return root


def _keep_frames(root: Path, keep) -> None:
    """Rewrite the manifest keeping the [[frames]] blocks for which ``keep(block)`` is true."""
    toml = (root / "session.toml").read_text()
    blocks = toml.split("[[frames]]")
    kept = [b for b in blocks[1:] if keep(b)]
    (root / "session.toml").write_text(blocks[0] + "".join("[[frames]]" + b for b in kept))


def _copy(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


# ---------------------------------------------------------------------------------- products
def test_one_fixed_pattern_configuration_gives_a_partial_product(h94, tmp_path, capsys):
    """Darks and ptc pairs are fine, K̂ cannot be made from one configuration: every other
    estimate is written, K̂ is listed as skipped with the method's reason, exit 0."""
    root = _copy(h94, tmp_path / "s")
    _keep_frames(root, lambda b: 'role = "fixed_pattern"' not in b or "config = 1\n" in b)
    code, out, err = run(capsys, "calibrate", root, "-o", tmp_path / "c", "--json")
    assert code == 0
    doc = json.loads(out)
    assert {"noise", "dark"} <= set(doc["estimates"]) and "fixed_pattern" not in doc["estimates"]
    skipped = {s["estimate"]: s for s in doc["skipped"]}
    assert skipped["fixed_pattern"]["code"] == "failed" and skipped["fixed_pattern"]["reason"]
    assert skipped["plan"]["code"] == "needs" and "fixed_pattern" in skipped["plan"]["reason"]
    assert "skipped fixed_pattern:" in err
    on_disk = json.loads((tmp_path / "c" / "calibration.json").read_text())
    assert on_disk["skipped"] == doc["skipped"]
    assert load_product(tmp_path / "c").skipped == calibrate(root).skipped


def test_nothing_to_calibrate_exits_2_naming_the_roles(tmp_path, capsys):
    root = tmp_path / "t"
    simulate("change", root, seed=1, size=(32, 24))     # reference/target brackets only
    code, out, err = run(capsys, "calibrate", root, "-o", tmp_path / "c")
    assert code == 2 and out == ""
    assert "nothing to calibrate" in err and len(err.strip().splitlines()) == 1
    for req in REQUIREMENTS:
        assert "/".join(req.roles) in err
    assert not (tmp_path / "c").exists()


def test_missing_frames_names_what_each_estimate_lacks(h94, tmp_path):
    session = open_session(h94)
    assert [r.estimate for r, _ in missing_frames(session)] == ["flat_field", "response"]
    root = _copy(h94, tmp_path / "s")
    _keep_frames(root, lambda b: 'role = "scene"' not in b)
    lacking = dict((r.estimate, roles) for r, roles in missing_frames(open_session(root)))
    assert lacking["scene"] == ("scene",) and lacking["correction_check"] == ("scene",)


def test_calibrate_into_the_current_folder(h94, tmp_path, monkeypatch):
    out = tmp_path / "here"
    out.mkdir()
    monkeypatch.chdir(out)
    assert main(["calibrate", str(h94), "-o", "."]) == 0
    assert (out / "calibration.json").is_file()
    assert main(["calibrate", str(h94), "-o", "."]) == 0   # replaces its own product
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(TEMP_PREFIX)]


def test_sigterm_during_save_leaves_no_temporary_folder(h94, tmp_path):
    """A save killed by SIGTERM removes its temporary folder; one left by a SIGKILL is removed by
    the next save into the same folder."""
    script = textwrap.dedent(f"""
        import sys, time
        import ccdcore.io.frames as io
        from ccdcore.product.make import calibrate
        product = calibrate({str(h94)!r})
        real = io.write_map
        def slow(*a, **k):
            print("writing", flush=True)
            time.sleep(30)
        import ccdcore.product.file as prod
        prod.write_map = slow
        product.save({str(tmp_path / "out")!r})
    """)
    for sig in (signal.SIGTERM, signal.SIGKILL):
        proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE,
                                cwd=ROOT, text=True)
        assert proc.stdout.readline().strip() == "writing"
        proc.send_signal(sig)
        proc.wait(timeout=60)
        left = [p for p in tmp_path.iterdir() if p.name.startswith(TEMP_PREFIX)]
        if sig == signal.SIGTERM:
            assert proc.returncode == 128 + signal.SIGTERM and left == []
        else:
            assert len(left) == 1
    calibrate(h94).save(tmp_path / "out")
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


@pytest.fixture()
def saved(h94, tmp_path) -> Path:
    return calibrate(h94).save(tmp_path / "p")


@pytest.mark.parametrize("damage, message", [
    (lambda d: [], "must hold a JSON object, not a list"),
    (lambda d: {**d, "schema": 7}, "unsupported product schema 7"),
    (lambda d: {**d, "maps": ["maps/K.exr"]}, "'maps' must be a JSON object"),
    (lambda d: {**d, "estimates": {"noise": 3}}, "every entry of 'estimates' must be an object"),
    (lambda d: {**d, "maps": {**d["maps"], "K": "../K.exr"}}, "points outside the product"),
    (lambda d: {**d, "camera": {"bits": "eight"}}, "camera bits must be an integer"),
])
def test_load_product_validates_the_description(saved, damage, message):
    path = saved / "calibration.json"
    path.write_text(json.dumps(damage(json.loads(path.read_text()))))
    with pytest.raises(CcdError, match=message) as info:
        load_product(saved)
    assert str(path) in str(info.value)


def test_load_product_refuses_bad_maps(saved, capsys, h94, tmp_path):
    k = load_product(saved).maps["K"].copy()
    k[0, 0] = 0.0
    write_map(saved / "maps" / "K.exr", k)
    code, _, err = run(capsys, "apply", saved, h94 / "ptc" / "L01_a.tif", "-o", tmp_path / "o")
    assert code == 2 and "map 'K' has 1 pixel(s) that are not finite and > 0" in err
    assert not (tmp_path / "o").exists()
    write_map(saved / "maps" / "K.exr", k[:-2])
    with pytest.raises(CcdError, match="maps of different shapes"):
        load_product(saved)


# ---------------------------------------------------------------------------------- sessions
@pytest.mark.parametrize("damage, where", [
    (lambda root: (root / "ptc" / "L01_a.tif").unlink(), "ptc/L01_a.tif: file not found"),
    (lambda root: (root / "session.toml").write_text(
        (root / "session.toml").read_text().replace("schema = 1", "schema = 2")),
     "unsupported schema 2"),
    (lambda root: (root / "session.toml").write_text(
        (root / "session.toml").read_text().replace('role = "dark"', 'role = "darks"', 1)),
     "unknown role 'darks'"),
])
def test_ptc_refuses_sessions_with_errors_that_touch_its_frames(h94, tmp_path, capsys, damage,
                                                                 where):
    root = _copy(h94, tmp_path / "s")
    damage(root)
    code, out, err = run(capsys, "ptc", root)
    assert code == 2 and out == "" and where in err


def test_ptc_refuses_a_symlink_escaping_the_folder(h94, tmp_path, capsys):
    root = _copy(h94, tmp_path / "s")
    outside = tmp_path / "outside.tif"
    (root / "ptc" / "L02_b.tif").rename(outside)
    (root / "ptc" / "L02_b.tif").symlink_to(outside)
    code, _, err = run(capsys, "ptc", root)
    assert code == 2 and "resolves outside the session folder" in err


def test_ptc_ignores_errors_of_frames_it_does_not_use(h94, tmp_path):
    root = _copy(h94, tmp_path / "s")
    (root / "scene" / "max_intensity.tif").unlink()
    session = open_session(root)
    assert not session.ok and session.errors_for(["ptc", "dark"]) == ()
    assert photon_transfer(session).A > 0
    with pytest.raises(SessionError, match="file not found"):
        session.raise_if_invalid()


def test_manifest_with_a_byte_order_mark_is_read(h94, tmp_path):
    root = _copy(h94, tmp_path / "s")
    text = (root / "session.toml").read_bytes()
    (root / "session.toml").write_bytes(b"\xef\xbb\xbf" + text)
    got, want = open_session(root), open_session(h94)
    assert got.ok and [f.to_dict() for f in got.frames] == [f.to_dict() for f in want.frames]


def test_manifest_that_is_a_folder_or_not_utf8(tmp_path, capsys):
    (tmp_path / "a" / "session.toml").mkdir(parents=True)
    code, _, err = run(capsys, "session", tmp_path / "a")
    assert code == 2 and "session.toml: is a folder, not a manifest file" in err
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "session.toml").write_bytes(b"schema = 1\n# \xff\xfe\n")
    code, _, err = run(capsys, "session", tmp_path / "b")
    assert code == 2 and "not UTF-8 text" in err


def test_legacy_notes_are_read_with_a_warning(tmp_path):
    root = tmp_path / "s"
    (root / "scene").mkdir(parents=True)
    for name in ("a", "b", "m"):
        write_image(root / "scene" / f"{name}.tif", np.full((8, 10), 9, np.uint8))
    (root / "session.toml").write_text(textwrap.dedent("""
        schema = 1
        [camera]
        bits = 8
        [[frames]]
        path = "scene/a.tif"
        role = "scene"
        note = "patch=grey; taken at noon"
        [[frames]]
        path = "scene/b.tif"
        role = "scene"
        patch = "paper"
        note = "setting=NZDI"
        [[frames]]
        path = "scene/m.tif"
        role = "scene"
        note = "max-intensity"
    """))
    s = open_session(root)
    a, b, m = s.frames
    assert (a.patch, a.setting, b.patch, b.setting, m.flags) == (
        "grey", None, "paper", "NZDI", ("max-intensity",))
    assert [p.code for p in s.warnings] == ["deprecated-note"] * 3
    assert "write patch = 'grey'" in s.warnings[0].message
    assert s.max_intensity_frame() is m and list(s.scene_patches()) == ["grey", "paper"]
    assert 'patch = "grey"' in s.to_toml() and 'flags = [\n    "max-intensity",\n]' in s.to_toml()


@pytest.mark.parametrize("line, message", [
    ("b inf 100", "exposure [ns] must be a finite number >= 0, got inf"),
    ("b 1000 nan", "photons per pixel must be a finite number >= 0, got nan"),
    ("b -5 100", "exposure [ns] must be a finite number >= 0, got -5"),
    ("d x", "exposure [ns] 'x' is not a number"),
])
def test_descriptor_numbers_are_validated(tmp_path, capsys, line, message):
    write_image(tmp_path / "a.tif", np.zeros((4, 6), np.uint16))
    desc = tmp_path / "d.txt"
    desc.write_text(f"v 4.0\nn 12 6 4\n{line}\ni a.tif\ni a.tif\n")
    s = open_session(desc)
    assert any(message in p.message and p.code == "descriptor-line" for p in s.errors)
    code, out, err = run(capsys, "session", desc, "--json")
    assert code == 2 and json.loads(out)["ok"] is False   # strict JSON, no crash on inf


@pytest.mark.parametrize("n_line, message", [
    ("n 0 6 4", "bits must be an integer from 1 to 32, got 0"),
    ("n 12 -6 4", "width must be an integer from 1"),
])
def test_descriptor_format_line_is_validated(tmp_path, n_line, message):
    desc = tmp_path / "d.txt"
    desc.write_text(f"v 4.0\n{n_line}\n")
    assert any(message in p.message for p in open_session(desc).errors)


# ---------------------------------------------------------------------------------- texts
def test_session_says_valid_and_drafts_from_the_cli(tmp_path, capsys):
    root = tmp_path / "plain"
    (root / "darks").mkdir(parents=True)
    for i in range(2):
        write_image(root / "darks" / f"d{i}.tif", np.full((6, 8), i, np.uint8))
    code, out, _ = run(capsys, "session", root, "--draft")
    assert code == 0 and out.strip().splitlines()[-1].startswith("valid")
    assert "manifest draft written to" in out and (root / "session.toml.draft").is_file()
    (root / "session.toml.draft").rename(root / "session.toml")
    assert len(open_session(root).frames) == 2
    code, out, _ = run(capsys, "session", ROOT / "assets" / "healey94")
    assert code == 0 and out.strip().splitlines()[-1].startswith("valid")


def test_every_option_has_help_and_verbs_say_what_they_need():
    parser = build_parser()
    verbs = parser._subparsers._group_actions[0].choices   # argparse keeps them here
    for name, sub in verbs.items():
        for action in sub._actions:
            if action.dest != "help":
                assert action.help, f"{name} {action.option_strings or action.dest} has no help"
    for name in ("ptc", "calibrate", "snup", "apply", "response", "hdr", "change"):
        assert "Needs:" in verbs[name].description
    assert "X,Y,W,H" in verbs["ptc"].format_help()


def test_errors_have_one_prefix(capsys):
    code, _, err = run(capsys, "hdr", "S", "-o", "O")
    assert code == 2 and err.count("ccdcore hdr") == 1


def test_no_line_of_a_summary_is_overlong(h94, capsys):
    for argv in (["ptc", h94], ["session", h94]):
        code, out, _ = run(capsys, *argv)
        assert code == 0 and max(map(len, out.splitlines())) <= 200


def test_long_lists_of_excluded_levels_are_summarised(tmp_path):
    from ccdcore.noise import fit_points

    pt = photon_transfer(ROOT / "assets" / "healey94")
    many = tuple(p.__class__(**{**p.__dict__, "level": i + 1})
                 for i, p in enumerate(pt.points * 3))
    res = fit_points(many, exclude_levels=range(1, 13), bits=8)
    assert len([n for n in res.notes if "not used" in n]) == 1
    assert "12 levels not used (user: 1 … 12)" in res.notes[-1]
    assert max(map(len, res.notes)) <= 200


def test_snup_with_a_roi_reads_only_the_region(tmp_path, capsys, monkeypatch):
    """A frame over the pixel limit is refused whole, but its ROI is measured (read_region
    decodes only the FITS rows holding it: 30 x 80 = 2400 values under the limit of 3000)."""
    rng = np.random.default_rng(3)
    img = rng.normal(1000, 10, (64, 80)).astype(np.uint16)
    write_image(tmp_path / "big.fits", img)
    monkeypatch.setenv("CCDCORE_MAX_PIXELS", "3000")
    code, _, err = run(capsys, "snup", tmp_path / "big.fits")
    assert code == 2 and "over the limit" in err and "big.fits" in err
    code, out, _ = run(capsys, "snup", tmp_path / "big.fits", "--roi", "8,4,40,30", "--json")
    assert code == 0
    ch = json.loads(out)["images"][0]["channels"][0]
    part = img[4:34, 8:48].astype(float)
    assert ch["snup"] == pytest.approx(100 * part.std(ddof=1) / part.mean(), rel=1e-12)
