"""The truth loader: ccdcore.simulate.load_truth / find_truth and Truth."""
from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ccdcore.errors import CcdError
from ccdcore.io.frames import read_image, write_map
from ccdcore.session import open_session
from ccdcore.simulate import Truth, find_truth, load_truth, simulate

HEALEY = dict(size=(24, 16), n_dark=2, levels=2, n1=2, n2=1, scene_levels=(0.5,), scene_margin=2)


@pytest.fixture(scope="module")
def healey(tmp_path_factory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("truth_healey")
    return root, simulate("healey94", root, seed=3, **HEALEY)


def test_round_trip_from_folder_file_and_session(healey):
    root, written = healey
    t = load_truth(root)
    assert isinstance(t, Truth) and t.folder == root and t.path == root / "truth.json"
    assert t.values == written
    for source in (str(root), root / "truth.json", root / "session.toml", open_session(root)):
        again = load_truth(source)
        assert again.values == written and again.folder == root
    assert find_truth(root).values == written


def test_mapping_interface(healey):
    root, written = healey
    t = load_truth(root)
    assert t["A"] == written["A"] and t.get("A") == written["A"]
    assert t.get("no such key") is None and t.get("no such key", 7) == 7
    assert "A" in t and "no such key" not in t
    assert sorted(t.keys()) == sorted(written) == sorted(t) and len(t) == len(written)
    with pytest.raises(KeyError):
        t["no such key"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.folder = Path("/")


def test_map_reads_the_file(healey):
    root, written = healey
    t = load_truth(root)
    assert t.maps() == ("K_map", "dark_map", "K", "dark")
    K = read_image(root / "truth/K.exr")
    for key in ("K", "K_map", "maps.K"):                 # the maps table, top level, dotted path
        m = t.map(key)
        assert m.dtype == np.float32 and np.array_equal(m, K)
    assert np.array_equal(t.map("dark"), read_image(root / written["dark_map"]))
    with pytest.raises(CcdError,
                       match=r"no map 'sigma_K' in the truth \(maps: K_map, dark_map, K, dark\)"):
        t.map("sigma_K")                                 # a number, not a file name
    with pytest.raises(CcdError, match="no map 'nothing'"):
        t.map("nothing")


def test_map_of_a_colour_session_and_a_mask(tmp_path):
    simulate("change", tmp_path, seed=2, size=(32, 24), n_objects=1)
    t = load_truth(tmp_path)
    assert set(t.maps()) == {"E", "E_target"}
    assert np.array_equal(t.map("E"), read_image(tmp_path / "truth/E.exr"))
    assert np.array_equal(t.map("masks.change"), read_image(tmp_path / "truth/change_mask.png"))


def _copy(root: Path, dst: Path) -> Path:
    shutil.copytree(root, dst)
    return dst


def test_a_map_outside_the_folder_is_refused(healey, tmp_path):
    root = _copy(healey[0], tmp_path / "session")
    write_map(tmp_path / "outside.exr", np.zeros((2, 2), np.float32))
    truth = json.loads((root / "truth.json").read_text())
    truth["escape_map"] = "../outside.exr"
    truth["absolute_map"] = str(tmp_path / "outside.exr")
    truth["maps"]["sneaky"] = "truth/../../outside.exr"
    (root / "truth" / "link.exr").symlink_to(tmp_path / "outside.exr")
    truth["link_map"] = "truth/link.exr"
    truth["inside_map"] = "truth/../truth/K.exr"
    (root / "truth.json").write_text(json.dumps(truth))
    t = load_truth(root)
    for key in ("escape_map", "sneaky", "link_map"):
        with pytest.raises(CcdError, match="leads outside the session folder"):
            t.map(key)
    with pytest.raises(CcdError, match="must be relative"):
        t.map("absolute_map")
    assert np.array_equal(t.map("inside_map"), read_image(root / "truth/K.exr"))
    with pytest.raises(CcdError, match="outside"):
        t.resolve("../outside.exr")
    assert t.resolve("dark/dark_000.tif") == root / "dark/dark_000.tif"


def test_missing_truth(tmp_path):
    with pytest.raises(CcdError) as err:
        load_truth(tmp_path)
    assert str(err.value) == f"{tmp_path}: no truth.json: not a simulated session"
    assert err.value.where == str(tmp_path)
    assert find_truth(tmp_path) is None
    with pytest.raises(CcdError, match="no truth.json: not a simulated session"):
        load_truth(tmp_path / "nowhere" / "truth.json")
    with pytest.raises(CcdError, match="no truth.json"):
        load_truth(tmp_path / "does-not-exist")


def test_a_real_capture_has_no_truth(healey, tmp_path):
    root = _copy(healey[0], tmp_path / "capture")
    (root / "truth.json").unlink()
    session = open_session(root)              # a valid session, just not a simulated one
    assert find_truth(session) is None
    with pytest.raises(CcdError, match="not a simulated session"):
        load_truth(session)


@pytest.mark.parametrize("text, message", [
    ('{"A": 1,', r"truth.json: not valid JSON: .* \(line 1, column 9\)"),
    ("[1, 2]", "truth.json: must hold a JSON object, got list"),
    (b"\xff\xfe{}", "truth.json: not UTF-8 text"),
])
def test_bad_truth_json(tmp_path, text, message):
    path = tmp_path / "truth.json"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(CcdError, match=message):
        load_truth(tmp_path)
    with pytest.raises(CcdError, match=message):
        find_truth(tmp_path)                  # present but unusable: an error, not None


def test_bad_argument():
    with pytest.raises(CcdError, match="expected a session folder"):
        load_truth(42)


def test_import_stays_light():
    code = ("import sys, ccdcore.simulate as s\n"
            "assert s.load_truth and s.find_truth and s.Truth\n"
            "print(','.join(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('numpy', 'scipy', 'tomli_w'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1], env={**os.environ})
    assert out.stdout.strip() == ""
