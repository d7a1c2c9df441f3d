"""Writing simulated sessions: manifest, frames and ``truth.json``, all atomically."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from ..io import atomic_write_text, write_image, write_map

__all__ = ["SessionWriter", "to_jsonable"]


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays and tuples into plain JSON types (recursively)."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return obj.as_posix()
    return obj


class SessionWriter:
    """Collects frames of a simulated session and writes the manifest and truth at the end.

    Usage::

        w = SessionWriter(out_dir, camera={"name": "...", "bits": 8, "layout": "mono"})
        w.add_frame("dark/dark_000.tif", frame, role="dark", exposure=0.033)
        w.add_map("truth/K.exr", K)           # a true map, float32
        w.finish(truth={...})                # writes session.toml and truth.json

    Frames are written as they are added (so a large session never sits in memory); the manifest
    lists them in the order added.  ``metadata`` keys are written into the ``[[frames]]`` entry.
    """

    def __init__(self, out_dir: str | Path, camera: dict[str, Any]):
        self.root = Path(out_dir)
        self.root.mkdir(parents=True, exist_ok=True)
        self.camera = dict(camera)
        self.frames: list[dict[str, Any]] = []
        self.maps: dict[str, str] = {}

    def add_frame(self, relpath: str, data: np.ndarray, *, role: str, **metadata: Any) -> None:
        entry = {"path": relpath, "role": role}
        entry.update({k: to_jsonable(v) for k, v in metadata.items() if v is not None})
        write_image(self.root / relpath, data, exposure=metadata.get("exposure"),
                    bits=self.camera.get("bits"))
        self.frames.append(entry)

    def add_map(self, relpath: str, data: np.ndarray, name: str | None = None) -> str:
        write_map(self.root / relpath, np.asarray(data, dtype=np.float32))
        self.maps[name or Path(relpath).stem] = relpath
        return relpath

    def finish(self, truth: dict[str, Any], note: str | None = None) -> dict[str, Any]:
        manifest: dict[str, Any] = {"schema": 1, "camera": to_jsonable(self.camera),
                                    "frames": self.frames}
        text = tomli_w.dumps(manifest)
        if note:
            text = "".join(f"# {line}\n" for line in note.splitlines()) + text
        atomic_write_text(self.root / "session.toml", text)
        truth = dict(truth)
        if self.maps:
            truth.setdefault("maps", {}).update(self.maps)
        truth = to_jsonable(truth)
        atomic_write_text(self.root / "truth.json", json.dumps(truth, indent=2, sort_keys=True) + "\n")
        return truth
