"""Writing simulated sessions: manifest, frames and ``truth.json``, all atomically.

Floats in ``truth.json`` carry :data:`TRUTH_DIGITS` significant digits (:func:`round_sig`):
values derived through ``exp``, ``log``, ``pow`` or sums over maps may differ in the last bit
(one ulp, ~1e-16 relative) from one CPU to another (NumPy picks its vector loops from the CPU's
features), and 12 digits are far more than any estimator recovers (its standard errors are
1e-6 relative at best), so the rounded text is the same everywhere except when a value lies
within an ulp of a rounding boundary -- then it differs by one unit in the 12th digit, which is
what ``tests/test_assets.py`` tolerates.  A preset may declare keys exact (``finish(exact=...)``):
they are written with all 17 digits (the response table ``g`` of ``tsin01``/``change``, an exact
function of ``gamma`` computed with the C library's scalar ``pow``, which does not depend on the
CPU's vector features).
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from ..common import json_safe
from ..io.frames import atomic_write_text, write_image, write_map

__all__ = ["SessionWriter", "round_sig", "round_floats", "TRUTH_DIGITS"]

#: significant digits of the floats written to ``truth.json`` (see the module docstring)
TRUTH_DIGITS = 12


def round_sig(x: float, digits: int = TRUTH_DIGITS) -> float:
    """``x`` rounded to ``digits`` significant digits (decimal), as a float; non-finite unchanged.

    ``round_sig(0.12499999999999994) == 0.125``; idempotent (rounding a rounded value again
    gives the same float).
    """
    x = float(x)
    if not math.isfinite(x) or x == 0.0:
        return x
    return float(f"{x:.{int(digits)}g}")


def round_floats(obj: Any, digits: int = TRUTH_DIGITS) -> Any:
    """Every float in a JSON-like structure rounded with :func:`round_sig` (ints, bools,
    strings and ``None`` unchanged)."""
    if isinstance(obj, dict):
        return {k: round_floats(v, digits) for k, v in obj.items()}
    if isinstance(obj, list):
        return [round_floats(v, digits) for v in obj]
    if isinstance(obj, float):
        return round_sig(obj, digits)
    return obj


class SessionWriter:
    """Collects frames of a simulated session and writes the manifest and truth at the end.

    Usage::

        w = SessionWriter(out_dir, camera={"name": "...", "bits": 8, "layout": "mono"})
        w.add_frame("dark/dark_000.tif", frame, role="dark", exposure=0.033)
        w.add_map("truth/K.exr", K)           # a true map, float32
        w.finish(truth={...})                # writes session.toml and truth.json

    Frames are written as they are added (so a large session never sits in memory); the manifest
    lists them in the order added.  ``metadata`` keys are written into the ``[[frames]]`` entry
    (the manifest keys: ``level``, ``exposure``, ``config``, ``gain``, ``roi``, ``stack``,
    ``setting``, ``patch``, ``flags`` ...; ``None`` values are left out).  Metadata goes into its
    own key, never into the free-text ``note`` (which ``ccdcore.session`` does not parse).
    """

    def __init__(self, out_dir: str | Path, camera: dict[str, Any]):
        self.root = Path(out_dir)
        self.root.mkdir(parents=True, exist_ok=True)
        self.camera = dict(camera)
        self.frames: list[dict[str, Any]] = []
        self.maps: dict[str, str] = {}

    def add_frame(self, relpath: str, data: np.ndarray, *, role: str, **metadata: Any) -> None:
        entry = {"path": relpath, "role": role}
        entry.update({k: json_safe(v) for k, v in metadata.items() if v is not None})
        write_image(self.root / relpath, data, exposure=metadata.get("exposure"),
                    bits=self.camera.get("bits"))
        self.frames.append(entry)

    def add_map(self, relpath: str, data: np.ndarray, name: str | None = None) -> str:
        write_map(self.root / relpath, np.asarray(data, dtype=np.float32))
        self.maps[name or Path(relpath).stem] = relpath
        return relpath

    def finish(self, truth: dict[str, Any], note: str | None = None,
               exact: tuple[str, ...] = ()) -> dict[str, Any]:
        """Write ``session.toml`` (``note``: comment lines at its top) and ``truth.json``.

        Floats of ``truth`` are rounded to :data:`TRUTH_DIGITS` significant digits except the
        top-level keys in ``exact``.  Returns the truth as written (plain JSON types).
        """
        manifest: dict[str, Any] = {"schema": 1, "camera": json_safe(self.camera),
                                    "frames": self.frames}
        text = tomli_w.dumps(manifest)
        if note:
            text = "".join(f"# {line}\n" for line in note.splitlines()) + text
        atomic_write_text(self.root / "session.toml", text)
        truth = dict(truth)
        if self.maps:
            truth.setdefault("maps", {}).update(self.maps)
        truth = {k: v if k in exact else round_floats(v) for k, v in json_safe(truth).items()}
        atomic_write_text(self.root / "truth.json", json.dumps(truth, indent=2, sort_keys=True) + "\n")
        return truth
