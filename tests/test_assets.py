"""The bundled demos are valid sessions, small, and exactly what assets/regenerate.py writes."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from ccdcore.session import open_session

ASSETS = Path(__file__).resolve().parents[1] / "assets"
_spec = importlib.util.spec_from_file_location("regenerate", ASSETS / "regenerate.py")
regen = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(regen)


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_assets_stay_small():
    total = sum(p.stat().st_size for p in ASSETS.rglob("*") if p.is_file())
    assert total < 20e6


@pytest.mark.parametrize("preset", sorted(regen.DEMOS))
def test_demo_is_valid_and_regenerates_bit_exactly(preset, tmp_path):
    session = open_session(ASSETS / preset)
    errors = [str(p) for p in session.problems if p.severity == "error"]
    assert errors == []
    assert (ASSETS / preset / "truth.json").exists()
    regen.regenerate(preset, tmp_path)
    assert _files(tmp_path / preset) == _files(ASSETS / preset)
