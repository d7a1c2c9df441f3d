"""The names of a calibration product's maps are one enum, ``MapName``: the products of the
bundled sessions hold only members, the folder keeps them, a stranger is refused on load, and
no code reads or writes a product map by a literal name."""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from ccdcore.errors import CcdError
from ccdcore.product.make import PRODUCT_FILE, CalibrationProduct, MapName, calibrate, load_product

ROOT = Path(__file__).resolve().parents[1]
SESSIONS = ("healey94", "delasarte07")


@pytest.fixture(scope="module", params=SESSIONS)
def saved(request, tmp_path_factory):
    """(product, its folder) of a bundled session, calibrated and saved into a tmp folder."""
    product = calibrate(ROOT / "assets" / request.param)
    return product, product.save(tmp_path_factory.mktemp(request.param) / "calib")


def test_the_members_are_the_names_on_disk():
    assert [m.value for m in MapName] == [
        "dark", "dark_var", "hot", "dead", "K", "K_var", "n1_used",
        "flat_G", "flat_O", "flat_flags", "flat_dark", "flat_base"]
    assert MapName.K == "K" and f"maps/{MapName.FLAT_G}.exr" == "maps/flat_G.exr"
    assert json.dumps({MapName.K: MapName.DARK}) == '{"K": "dark"}'
    assert {"K": 1}[MapName.K] == 1 and {MapName.K: 1}["K"] == 1


def test_every_map_of_a_bundled_session_is_a_member(saved):
    product, _ = saved
    assert product.maps
    for name in product.maps:
        assert isinstance(name, MapName), name
    assert set(product.maps) <= set(MapName)


def test_every_member_is_documented_in_the_product_docstring():
    doc = CalibrationProduct.__doc__ or ""
    missing = [m.value for m in MapName if f"``{m.value}``" not in doc]
    assert not missing, f"CalibrationProduct's docstring does not name {missing}"


def test_a_round_trip_keeps_names_and_arrays(saved):
    product, folder = saved
    doc = json.loads((folder / PRODUCT_FILE).read_text())
    assert doc["maps"] == {m.value: f"maps/{m.value}.exr" for m in sorted(product.maps)}
    back = load_product(folder)
    assert list(back.maps) == sorted(product.maps)
    for name, m in product.maps.items():
        assert isinstance(next(k for k in back.maps if k == name), MapName)
        assert back.maps[name].dtype == m.dtype
        assert back.maps[name].shape == m.shape
        assert back.maps[name].tobytes() == m.tobytes(), name
        assert back.maps[name.value].tobytes() == m.tobytes()   # a plain string reads it too


def test_loading_refuses_a_map_that_is_not_a_member(saved, tmp_path):
    _, folder = saved
    copy = shutil.copytree(folder, tmp_path / "calib")
    manifest = copy / PRODUCT_FILE
    doc = json.loads(manifest.read_text())
    first = next(iter(doc["maps"].values()))
    shutil.copy(copy / first, copy / "maps" / "gain.exr")
    doc["maps"]["gain"] = "maps/gain.exr"
    manifest.write_text(json.dumps(doc))
    with pytest.raises(CcdError) as err:
        load_product(copy)
    message = str(err.value)
    assert str(manifest) in message and "unknown map 'gain'" in message
    assert "flat_base" in message      # the names it would take


def test_saving_refuses_a_map_that_is_not_a_member(tmp_path):
    product = CalibrationProduct(maps={"gain": np.ones((4, 4), np.float32)})
    with pytest.raises(CcdError, match="unknown map 'gain'"):
        product.save(tmp_path / "calib")
    assert not (tmp_path / "calib" / PRODUCT_FILE).exists()


# a product map read or written by its literal name: maps["K"], maps.get('dark'),
# maps.pop("hot"), "flat_G" in product.maps
_NAMES = "|".join(re.escape(m.value) for m in MapName)
_LITERAL = re.compile(
    rf"""maps\s*(?:\[|\.get\(|\.pop\()\s*(["'])({_NAMES})\1"""
    rf"""|(["'])({_NAMES})\3\s+(?:not\s+)?in\s+[\w.]*maps\b""")
_SCANNED = [*sorted((ROOT / "ccdcore").rglob("*.py")),
            *sorted((ROOT / "report").rglob("*.py")),
            *sorted((ROOT / "app").rglob("*.py"))]


def test_the_scan_finds_a_literal_name():
    for line in ('x = product.maps["K"]', "maps.get('dark_var')", 'maps.pop("hot", None)',
                 'if "flat_G" in self.maps:', 'if "dark" not in product.maps:'):
        assert _LITERAL.search(line), line
    for line in ("maps[MapName.K]", 'maps["hot_dead"]', 'truth.maps.get("E")',
                 'roles.get("dark")'):
        assert not _LITERAL.search(line), line


def test_no_product_map_is_named_by_a_literal_string():
    found = []
    for path in _SCANNED:
        if path.name == "map_names.py" or "simulate" in path.parts:
            continue       # the enum itself; the simulators' truth maps are not product maps
        for no, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if _LITERAL.search(line):
                found.append(f"{path.relative_to(ROOT)}:{no}: {line.strip()}")
    assert not found, "use the MapName member:\n" + "\n".join(found)
