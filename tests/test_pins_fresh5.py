"""Pins for the survivors of the fifth fresh mutation round (see MUTANTS.md).

Each expectation is derived independently (by hand, from the documented contract or from a
first-principles reference computed in the test), never a snapshot of current output.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from ccdcore.emva.spatial import VarianceSplit, nonuniformity_split
from ccdcore.errors import CcdError
from ccdcore.io.frames import write_image
from ccdcore.io.outputs import MARK, TEMP_PREFIX, remove_stale_temporaries, write_outputs
from ccdcore.map_names import MapName
from ccdcore.product.file import CalibrationProduct, map_problem
from ccdcore.session import open_session
from ccdcore.session.records import ProblemCode


# --------------------------------------------------------------------------------------------
# io/outputs: stale temporaries of this very process are removed, live ones of others kept
# --------------------------------------------------------------------------------------------
def _marked_temp(folder: Path, tag: str, pid: int) -> Path:
    p = folder / f"{TEMP_PREFIX}{tag}-{pid}"
    p.mkdir()
    (p / MARK).write_text(str(pid))
    (p / "half.tif").write_bytes(b"partial")
    return p


def test_own_stale_temporary_is_removed_and_a_live_writers_is_kept(tmp_path: Path) -> None:
    """A temporary folder marked with this process's id is a leftover of an earlier write of
    this process (its own write of now has not made its folder yet): nobody else can be using
    it, so it goes. One marked with another live process's id is that writer's folder: kept."""
    folder = tmp_path / "out"
    folder.mkdir()
    own = _marked_temp(folder, "own", os.getpid())
    other = _marked_temp(folder, "other", os.getppid())     # the parent: alive while we run
    remove_stale_temporaries(folder)
    assert not own.exists()
    assert other.is_dir() and (other / MARK).read_text() == str(os.getppid())

    # the same through a real write: the next write into the folder cleans the leftover
    own = _marked_temp(folder, "again", os.getpid())
    written = write_outputs(folder, {"a.txt": lambda p: p.write_text("x")})
    assert written == [folder / "a.txt"] and (folder / "a.txt").read_text() == "x"
    assert not own.exists()
    assert other.is_dir()
    leftovers = sorted(p.name for p in folder.iterdir() if p.name.startswith(TEMP_PREFIX))
    assert leftovers == [other.name]


# --------------------------------------------------------------------------------------------
# session/manifest: ROI of zero size, schema that is not an integer
# --------------------------------------------------------------------------------------------
def _session(root: Path, body: str, schema: str = "1"):
    root.mkdir(parents=True, exist_ok=True)
    write_image(root / "a.tif", np.full((12, 16), 7, np.uint16))
    (root / "session.toml").write_text(
        f"schema = {schema}\n[camera]\nname = \"bench\"\nbits = 12\nlayout = \"mono\"\n\n"
        f"[[frames]]\npath = \"a.tif\"\nrole = \"dark\"\nexposure = 0.01\n{body}\n")
    return open_session(root)


def _codes(session, code) -> list:
    return [p for p in session.problems if p.code == code]


@pytest.mark.parametrize("roi", [[0, 0, 0, 5], [0, 0, 5, 0], [2, 3, 0, 0], [1, 1, -4, 2]])
def test_a_roi_of_zero_or_negative_size_is_refused(tmp_path: Path, roi: list[int]) -> None:
    """docs: roi is [x, y, w, h] with w and h > 0 -- an empty region has no pixel to measure."""
    s = _session(tmp_path / "s", f"roi = {roi}")
    bad = _codes(s, ProblemCode.BAD_VALUE)
    assert len(bad) == 1 and bad[0].severity == "error"
    assert "roi" in bad[0].message and bad[0].where.startswith("frames[0]")
    assert not s.ok


@pytest.mark.parametrize("roi", [[0, 0, 1, 1], [15, 11, 1, 1], [0, 0, 16, 12]])
def test_a_roi_of_one_pixel_or_the_whole_frame_is_accepted(tmp_path: Path,
                                                          roi: list[int]) -> None:
    s = _session(tmp_path / "s", f"roi = {roi}")
    assert _codes(s, ProblemCode.BAD_VALUE) == []
    assert [p for p in s.problems if p.severity == "error"] == []


@pytest.mark.parametrize("schema", ["1.0", "true", '"1"', "2", "0"])
def test_a_schema_that_is_not_the_integer_one_is_unsupported(tmp_path: Path,
                                                             schema: str) -> None:
    """The schema is an integer version: 1.0 and true compare equal to 1 in Python but are
    not the integer 1 the contract writes, so they are refused like 2 or "1"."""
    s = _session(tmp_path / "s", "", schema=schema)
    bad = _codes(s, ProblemCode.SCHEMA)
    assert len(bad) == 1 and bad[0].severity == "error" and bad[0].where == "schema"
    assert not s.ok


def test_the_integer_schema_one_is_supported(tmp_path: Path) -> None:
    s = _session(tmp_path / "s", "")
    assert _codes(s, ProblemCode.SCHEMA) == [] and _codes(s, ProblemCode.NO_SCHEMA) == []
    assert s.ok


# --------------------------------------------------------------------------------------------
# product/file: infinite values in the maps that must be finite
# --------------------------------------------------------------------------------------------
_FINITE = (MapName.DARK, MapName.DARK_VAR, MapName.K_VAR, MapName.FLAT_G, MapName.FLAT_O)


@pytest.mark.parametrize("name", _FINITE)
@pytest.mark.parametrize("bad", [np.inf, -np.inf, np.nan])
def test_maps_that_must_be_finite_refuse_infinities_as_well_as_nan(name: MapName,
                                                                   bad: float) -> None:
    m = np.full((6, 8), 3.0, np.float32)
    m[2, 5] = bad
    m[4, 1] = bad
    problem = map_problem(name, m)
    assert problem is not None and f"'{name}'" in problem and " 2 " in problem
    assert map_problem(name, np.full((6, 8), 3.0, np.float32)) is None


def test_a_product_with_an_infinite_dark_map_is_not_saved(tmp_path: Path) -> None:
    dark = np.full((6, 8), 100.0, np.float32)
    dark[0, 0] = -np.inf
    product = CalibrationProduct(maps={MapName.DARK: dark})
    with pytest.raises(CcdError, match="non-finite"):
        product.save(tmp_path / "calib")
    assert not (tmp_path / "calib").exists()
    dark[0, 0] = 100.0
    assert (CalibrationProduct(maps={MapName.DARK: dark}).save(tmp_path / "calib")
            / "calibration.json").is_file()


# --------------------------------------------------------------------------------------------
# emva/spatial: the standard error of a DSNU part (square root of a variance, over K)
# --------------------------------------------------------------------------------------------
def _split(v: dict[str, tuple[float, float]], mean: float) -> VarianceSplit:
    return VarianceSplit(M=40, N=60, L=16, mean=mean, s2=sum(x for x, _ in v.values()),
                         s2_err=1.0, s2_cav=0.0, s2_rav=0.0,
                         s2_row=v["row"][0], s2_row_err=v["row"][1],
                         s2_col=v["col"][0], s2_col_err=v["col"][1],
                         s2_pixel=v["pixel"][0], s2_pixel_err=v["pixel"][1])


def test_dsnu_part_error_is_the_propagated_error_of_a_root_over_k() -> None:
    """DSNU.part = √v / K. First order: σ(√v) = σ_v / (2√v), so σ(DSNU)/DSNU =
    hypot(σ_v/(2v), σ_K/K). Hand values: v = 400 ± 40 DN² -> √v = 20 ± 1 DN (5 %);
    K = 2 ± 0.15 (7.5 %) -> 10 e⁻ ± 10·hypot(0.05, 0.075) = 0.901388 e⁻."""
    dark = _split({"row": (400.0, 40.0), "col": (900.0, 18.0), "pixel": (100.0, 5.0)}, 50.0)
    bright = _split({"row": (800.0, 40.0), "col": (1800.0, 18.0), "pixel": (500.0, 5.0)},
                    1050.0)
    ns = nonuniformity_split(bright, dark, 2.0, 0.15)
    assert ns.DSNU1288_row == pytest.approx(10.0, rel=1e-12)
    assert ns.DSNU1288_row_err == pytest.approx(10.0 * math.hypot(0.05, 0.075), rel=1e-9)
    # col: √900 = 30 ± 18/(2·30) = 0.3 (1 %) -> 15 e⁻ ± 15·hypot(0.01, 0.075)
    assert ns.DSNU1288_col == pytest.approx(15.0, rel=1e-12)
    assert ns.DSNU1288_col_err == pytest.approx(15.0 * math.hypot(0.01, 0.075), rel=1e-9)
    # with an exact K only the variance's error is left: 10 ± 0.25 (σ_v/(2v) = 2.5 %)
    exact = nonuniformity_split(bright, dark, 1.0, 0.0)
    assert exact.DSNU1288_pixel == pytest.approx(10.0, rel=1e-12)
    assert exact.DSNU1288_pixel_err == pytest.approx(0.25, rel=1e-9)


def test_dsnu_part_error_matches_a_monte_carlo_of_its_inputs() -> None:
    """Brute force: draw v ~ N(400, 20²) and K ~ N(2, 0.1²) independently and take the spread
    of √v/K; the stated first-order error must match it within a few per cent (the
    second-order terms are ~ (5 %)², and 200 000 draws give a 0.2 % sampling error)."""
    rng = np.random.default_rng(20240611)
    v = rng.normal(400.0, 20.0, 200_000)
    k = rng.normal(2.0, 0.1, 200_000)
    spread = float(np.std(np.sqrt(v) / k))
    dark = _split({"row": (400.0, 20.0), "col": (400.0, 20.0), "pixel": (400.0, 20.0)}, 50.0)
    bright = _split({"row": (900.0, 20.0), "col": (900.0, 20.0), "pixel": (900.0, 20.0)}, 900.0)
    ns = nonuniformity_split(bright, dark, 2.0, 0.1)
    for part in ("row", "col", "pixel"):
        assert getattr(ns, f"DSNU1288_{part}_err") == pytest.approx(spread, rel=0.03)
