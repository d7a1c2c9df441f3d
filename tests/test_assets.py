"""The bundled demos are valid sessions, small, and what assets/regenerate.py writes.

What "what it writes" means, per kind of file:

* integer images (frames, masks) and text (``session.toml``): byte for byte;
* float maps (``truth/*.exr``): value for value, within :data:`MAP_ULPS` float32 ulps;
* ``truth.json``: the same keys, lists, strings, integers and booleans; floats within a relative
  :data:`TRUTH_REL_TOL`.

A failure names the file, the place (a JSON path such as ``g[7]`` or ``settings.NZDI.dark_map``,
or a pixel) and both values -- never a byte dump.
"""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

from ccdcore.io.frames import is_image_path, read_image
from ccdcore.session import open_session
from ccdcore.simulate import load_truth
from ccdcore.simulate._common import TRUTH_DIGITS

ASSETS = Path(__file__).resolve().parents[1] / "assets"
_spec = importlib.util.spec_from_file_location("regenerate", ASSETS / "regenerate.py")
regen = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(regen)

#: Relative tolerance of truth.json floats: one unit in the last of the TRUTH_DIGITS = 12
#: significant digits they are rounded to (1e-11 relative for a leading digit 1, 1e-12 for 9).
#: NumPy's vector exp/log/pow differ by one ulp (1.1e-16 relative) between CPU feature sets
#: (AVX2, AVX-512, NEON); the simulators avoid them where it matters, but any ulp left upstream
#: either vanishes in the rounding or moves the rounded value by exactly one such unit when it lies
#: within an ulp of a rounding boundary.  Keys written at full precision (``g``) differ, if at all,
#: by ulps, far inside.  No estimator is within 1e-6 of the truth, and a real change of a simulator
#: (model, noise term, seed) moves values by far more than 1e-11.
TRUTH_REL_TOL = 10.0 ** (1 - TRUTH_DIGITS)
#: Float maps are float32 roundings of float64 computations: a one-ulp float64 difference upstream
#: can move the float32 value by at most one float32 ulp (6e-8 relative), when the float64 value
#: lies at a float32 rounding boundary.
MAP_ULPS = 1
#: files compared as text, byte for byte
TEXT_SUFFIXES = frozenset({".toml", ".txt", ".md", ".csv"})


def _files(root: Path) -> list[str]:
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())


# ---- truth.json ----------------------------------------------------------------------------
def _json_path(parent: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{parent}[{key}]"
    return f"{parent}.{key}" if parent else key


def _json_differences(a: Any, b: Any, path: str = "") -> Iterator[str]:
    """Differences between two parsed JSON values, each "<path>: <new> vs <committed>"."""
    where = path or "(top level)"
    if isinstance(a, bool) or isinstance(b, bool) or type(a) is not type(b):
        if type(a) is not type(b) or a != b:
            yield f"{where}: {a!r} vs {b!r}"
        return
    if isinstance(a, dict):
        for key in sorted(set(a) | set(b)):
            if key not in b:
                yield f"{_json_path(path, key)}: only in the regenerated truth ({a[key]!r:.60})"
            elif key not in a:
                yield f"{_json_path(path, key)}: only in the committed truth ({b[key]!r:.60})"
            else:
                yield from _json_differences(a[key], b[key], _json_path(path, key))
    elif isinstance(a, list):
        if len(a) != len(b):
            yield f"{where}: {len(a)} items vs {len(b)}"
        for i, (x, y) in enumerate(zip(a, b)):
            yield from _json_differences(x, y, _json_path(path, i))
    elif isinstance(a, float):
        same = (a == b or (math.isnan(a) and math.isnan(b))
                or math.isclose(a, b, rel_tol=TRUTH_REL_TOL, abs_tol=0.0))
        if not same:
            rel = abs(a - b) / max(abs(a), abs(b))
            yield f"{where}: {a!r} vs {b!r} (relative difference {rel:.2g})"
    elif a != b:
        yield f"{where}: {a!r} vs {b!r}"


# ---- images -----------------------------------------------------------------------------------
def _pixel(index: tuple[int, ...]) -> str:
    return "(" + ", ".join(map(str, index)) + ")"


def _image_difference(new: Path, old: Path) -> str | None:
    """None when the two image files match (see the module docstring), else one line."""
    a, b = read_image(new), read_image(old)
    if a.shape != b.shape or a.dtype != b.dtype:
        return f"shape/dtype {a.shape} {a.dtype} vs {b.shape} {b.dtype}"
    if a.dtype.kind == "f":
        a64, b64 = a.astype(np.float64), b.astype(np.float64)
        nan_a, nan_b = np.isnan(a64), np.isnan(b64)
        ulp = np.spacing(np.maximum(np.abs(a), np.abs(b)).astype(np.float32)).astype(np.float64)
        with np.errstate(invalid="ignore"):
            bad = (nan_a != nan_b) | (~nan_a & ~nan_b & ~(np.abs(a64 - b64) <= MAP_ULPS * ulp))
        if not bad.any():
            return None
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        return (f"{int(bad.sum())} of {bad.size} values differ by more than {MAP_ULPS} float32 "
                f"ulp; first at pixel {_pixel(first)}: {a[first]!r} vs {b[first]!r}")
    # integers: the files must be identical
    if new.read_bytes() == old.read_bytes():
        return None
    bad = a != b
    if not bad.any():
        return "same pixels, but the files differ (header or metadata)"
    first = tuple(int(i) for i in np.argwhere(bad)[0])
    return (f"{int(bad.sum())} of {bad.size} pixel values differ; first at {_pixel(first)}: "
            f"{a[first]} vs {b[first]}")


def _text_difference(new: Path, old: Path) -> str | None:
    if new.read_bytes() == old.read_bytes():
        return None
    a = new.read_text(encoding="utf-8", errors="replace").splitlines()
    b = old.read_text(encoding="utf-8", errors="replace").splitlines()
    for i, (x, y) in enumerate(zip(a, b), start=1):
        if x != y:
            return f"line {i}: {x!r} vs {y!r}"
    if len(a) != len(b):
        return f"{len(a)} lines vs {len(b)}"
    return "line endings or trailing bytes differ"


def compare_sessions(new: Path, old: Path) -> list[str]:
    """Every difference between a regenerated session ``new`` and the committed ``old``, one
    line each: ``<file>: <place>: <regenerated> vs <committed>``."""
    out: list[str] = []
    files_new, files_old = _files(new), _files(old)
    out += [f"{f}: only in the regenerated session" for f in files_new if f not in files_old]
    out += [f"{f}: only in the committed session" for f in files_old if f not in files_new]
    for rel in sorted(set(files_new) & set(files_old)):
        a, b = new / rel, old / rel
        if rel == "truth.json":
            out += [f"{rel}: {d}" for d in _json_differences(load_truth(new).values,
                                                              load_truth(old).values)]
        elif is_image_path(rel):
            why = _image_difference(a, b)
            if why:
                out.append(f"{rel}: {why}")
        elif a.suffix.lower() in TEXT_SUFFIXES:
            why = _text_difference(a, b)
            if why:
                out.append(f"{rel}: {why}")
        elif a.read_bytes() != b.read_bytes():
            out.append(f"{rel}: the files differ ({a.stat().st_size} vs {b.stat().st_size} bytes)")
    return out


# ---- the tests ------------------------------------------------------------------------------
def test_assets_stay_small():
    total = sum(p.stat().st_size for p in ASSETS.rglob("*") if p.is_file())
    assert total < 20e6


@pytest.mark.parametrize("preset", sorted(regen.DEMOS))
def test_demo_is_valid_and_regenerates(preset, tmp_path):
    session = open_session(ASSETS / preset)
    errors = [str(p) for p in session.problems if p.severity == "error"]
    assert errors == []
    deprecated = [str(p) for p in session.problems if p.code == "deprecated-note"]
    assert deprecated == []
    assert (ASSETS / preset / "truth.json").exists()
    regen.regenerate(preset, tmp_path)
    differences = compare_sessions(tmp_path / preset, ASSETS / preset)
    assert not differences, (f"assets/{preset} differs from what assets/regenerate.py writes "
                             f"({len(differences)} differences):\n  "
                             + "\n  ".join(differences[:20]))


def test_camera_demo_is_a_small_rgb_bracket_one_stop_apart():
    """assets/tsin01-camera: the ``camera="real"`` bracket (sRGB-like tone with toe and knee,
    structured scene, vignetting, exposure errors, Bayer, sharpening, JPEG quality 90).

    Its frames are JPEG-compressed yet compared byte for byte like the others: the JPEG is
    :func:`ccdcore.simulate.camera.jpeg_roundtrip`, plain IEEE arithmetic in a fixed order
    (no libjpeg, whose SIMD paths and versions round differently), so the bytes are the same on
    every CPU and no tolerance is needed.
    """
    import tomllib

    root = ASSETS / "tsin01-camera"
    assert sum(p.stat().st_size for p in root.rglob("*") if p.is_file()) < 1.5e6
    manifest = tomllib.loads((root / "session.toml").read_text())
    truth = load_truth(root).values
    assert manifest["camera"]["layout"] == "rgb" and manifest["camera"]["bits"] == 8
    exposures = np.array([f["exposure"] for f in manifest["frames"]])
    assert exposures.size == 10 and np.all(exposures[1:] / exposures[:-1] == 2.0)
    assert truth["size"] == [192, 128] and truth["camera_model"]["bundle"] == "real"
    assert truth["tone"]["name"] == "srgb-knee" and truth["jpeg"]["quality"] == 90
    assert len(truth["g"]) == 256 and truth["g"][0] == 0.0 and truth["g"][255] == 1.0
    assert np.array(truth["a"]).shape == (1, 10, 3)
    z = read_image(root / manifest["frames"][-1]["path"])
    assert z.shape == (128, 192, 3) and z.dtype == np.uint8


# ---- the comparison itself ------------------------------------------------------------------
def _copy(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


def test_comparison_tolerates_one_rounding_step_and_names_the_key(tmp_path):
    import json

    new = _copy(ASSETS / "tsin01", tmp_path / "new")
    truth = json.loads((new / "truth.json").read_text())
    assert compare_sessions(new, ASSETS / "tsin01") == []
    g7 = truth["g"][7]
    truth["g"][7] = float(np.nextafter(g7, 1.0))            # one ulp: tolerated
    assert truth["gamma"] == 1.2
    truth["gamma"] = 1.20000000001                          # one step of the 12th digit: tolerated
    (new / "truth.json").write_text(json.dumps(truth))
    assert compare_sessions(new, ASSETS / "tsin01") == []
    truth["g"][7] = g7 * (1 + 1e-9)
    truth["frames"][2]["a"] = 0.5
    truth["layout"] = "rgb"
    (new / "truth.json").write_text(json.dumps(truth))
    diffs = compare_sessions(new, ASSETS / "tsin01")
    assert len(diffs) == 3
    assert diffs[0].startswith("truth.json: frames[2].a: 0.5 vs ")
    assert diffs[1].startswith(f"truth.json: g[7]: {g7 * (1 + 1e-9)!r} vs {g7!r}")
    assert diffs[2] == "truth.json: layout: 'rgb' vs 'mono'"


def test_comparison_names_the_pixel_of_images_and_maps(tmp_path):
    from ccdcore.io.frames import read_header, write_image, write_map

    new = _copy(ASSETS / "tsin01", tmp_path / "new")
    frame = new / "bracket/s0_k03.tif"
    z = read_image(frame)
    z[5, 9] ^= 1
    write_image(frame, z, exposure=read_header(frame).exposure, bits=8)
    E = read_image(new / "truth/E.exr")
    E_one_ulp = E.copy()
    E_one_ulp[2, 3] = np.nextafter(E[2, 3], np.float32(2))
    write_map(new / "truth/E.exr", E_one_ulp)
    diffs = compare_sessions(new, ASSETS / "tsin01")
    assert diffs == [f"bracket/s0_k03.tif: 1 of {z.size} pixel values differ; first at (5, 9): "
                     f"{z[5, 9]} vs {z[5, 9] ^ 1}"]
    E_far = E.copy()
    E_far[2, 3] = E[2, 3] + np.float32(1e-3)
    write_map(new / "truth/E.exr", E_far)
    toml = (new / "session.toml").read_text()
    (new / "session.toml").write_text(toml.replace("bracket", "brackets", 1))
    diffs = compare_sessions(new, ASSETS / "tsin01")
    assert diffs[0] == f"bracket/s0_k03.tif: 1 of {z.size} pixel values differ; first at (5, 9): " \
                       f"{z[5, 9]} vs {z[5, 9] ^ 1}"
    assert diffs[1].startswith("session.toml: line 5: ") and '"brackets/s0_k00.tif"' in diffs[1]
    assert diffs[2] == (f"truth/E.exr: 1 of {E.size} values differ by more than 1 float32 ulp; "
                        f"first at pixel (2, 3): {E_far[2, 3]!r} vs {E[2, 3]!r}")
