"""Reading a simulated session's ``truth.json``: one loader for tests, benchmarks and the app.

Every simulator preset writes ``truth.json`` next to ``session.toml``: the true camera parameters,
per-frame expectations and the file names of the true maps (``truth/K.exr``, ``truth/E.exr``,
masks ...), relative to the session folder.  :func:`load_truth` reads it into a :class:`Truth`,
which reads those maps on request (refusing a name that leads outside the folder).

Importing this module is light (no NumPy); :meth:`Truth.map` imports :mod:`ccdcore.io.frames` when
it reads a map.

Public objects
--------------
Truth
    The values of ``truth.json`` and the folder they belong to; ``truth["A"]``, ``truth.map("K")``.
load_truth(folder_or_session)
    Read ``truth.json``; :class:`~ccdcore.errors.CcdError` when there is none or it is not JSON.
find_truth(folder_or_session)
    The same, or ``None`` when the folder has no ``truth.json`` (not a simulated session).
TRUTH_NAME
    ``"truth.json"``.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator

from ..errors import CcdError

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

__all__ = ["Truth", "load_truth", "find_truth", "TRUTH_NAME"]

TRUTH_NAME = "truth.json"


def _lookup(values: Any, dotted: str) -> Any:
    """``values["a"]["b"]`` for ``"a.b"`` (``KeyError`` when a part is missing)."""
    node = values
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            raise KeyError(dotted)
        node = node[part]
    return node


def _is_image_name(value: Any) -> bool:
    from ..io.frames import is_image_path

    return isinstance(value, str) and bool(value) and is_image_path(value)


@dataclass(frozen=True)
class Truth:
    """The content of a simulated session's ``truth.json``.

    Attributes
    ----------
    folder
        The session folder; the file names in ``values`` are relative to it.
    values
        The parsed JSON object (plain ``dict``/``list``/``float``/``int``/``str``).

    ``truth[key]``, ``truth.get(key)``, ``key in truth``, ``truth.keys()``, ``len`` and iteration
    work as on ``values``.  :meth:`map` reads a true map (or mask) by key, :meth:`maps` lists the
    keys it accepts, :meth:`resolve` turns any relative file name of the truth (a frame's
    ``path``) into a path inside the folder.
    """

    folder: Path
    values: dict[str, Any]

    # ---- mapping interface ------------------------------------------------------------------
    def __getitem__(self, key: str) -> Any:
        return self.values[key]

    def get(self, key: str, default: Any = None) -> Any:
        return self.values.get(key, default)

    def __contains__(self, key: object) -> bool:
        return key in self.values

    def keys(self):
        return self.values.keys()

    def __iter__(self) -> Iterator[str]:
        return iter(self.values)

    def __len__(self) -> int:
        return len(self.values)

    @property
    def path(self) -> Path:
        """The ``truth.json`` file."""
        return self.folder / TRUTH_NAME

    # ---- files ------------------------------------------------------------------------------
    def resolve(self, name: str | os.PathLike) -> Path:
        """``folder / name`` for a relative file name of the truth; :class:`CcdError` when the
        name is absolute or leads outside the folder (``..``, a symbolic link pointing out)."""
        rel = Path(name)
        where = f"{self.path} ({Path(name).as_posix()})"
        if rel.is_absolute() or rel.drive or rel.anchor:
            raise CcdError(where, "a truth file name must be relative to the session folder")
        base = self.folder.resolve()
        target = (base / rel).resolve()
        if target != base and base not in target.parents:
            raise CcdError(where, "the file name leads outside the session folder; refused")
        return self.folder / rel

    def _map_name(self, key: str) -> str:
        value = self.values.get(key)
        if isinstance(value, str):
            return value
        maps = self.values.get("maps")
        if isinstance(maps, dict) and isinstance(maps.get(key), str):
            return maps[key]
        if "." in key:
            try:
                value = _lookup(self.values, key)
            except KeyError:
                value = None
            if isinstance(value, str):
                return value
        known = ", ".join(self.maps()) or "none"
        raise CcdError(self.path, f"no map {key!r} in the truth (maps: {known})")

    def map(self, key: str) -> "np.ndarray":
        """Read the map named by ``key``, with :func:`ccdcore.io.frames.read_image`.

        ``key`` is a top-level key whose value is a file name (``"K_map"``, ``"flatfield_map"``),
        a name of the ``maps`` table (``"K"``, ``"E"``, ``"flatfield"``) or a dotted path to a
        file name (``"masks.change"``, ``"settings.NZDI.dark_map"``).  The file name is relative
        to :attr:`folder`; one leading outside it is refused (:class:`CcdError`).
        """
        from ..io.frames import read_image

        return read_image(self.resolve(self._map_name(key)))

    def maps(self) -> tuple[str, ...]:
        """The keys :meth:`map` accepts without a dotted path: the top-level keys whose value is
        an image file name (``"K_map"``), then the names of the ``maps`` table (``"K"``)."""
        out = [k for k, v in self.values.items() if _is_image_name(v)]
        table = self.values.get("maps")
        if isinstance(table, dict):
            out += [k for k, v in table.items() if _is_image_name(v) and k not in out]
        return tuple(out)


def _locate(folder_or_session: Any) -> tuple[Path, Path, Path]:
    """(folder, truth file, what to name in an error) for a folder, a file or a session."""
    if not isinstance(folder_or_session, (str, os.PathLike)):
        root = getattr(folder_or_session, "root", None)
        if root is None:
            raise CcdError(repr(folder_or_session)[:80], "expected a session folder, a truth.json "
                                                         "path or a session (an object with .root)")
        folder = Path(root)
        return folder, folder / TRUTH_NAME, folder
    p = Path(folder_or_session)
    if p.suffix.lower() == ".json" and not p.is_dir():
        return p.parent, p, p
    if p.is_file():                       # session.toml, a descriptor: its folder's truth
        return p.parent, p.parent / TRUTH_NAME, p.parent
    return p, p / TRUTH_NAME, p


def _read(folder: Path, file: Path) -> Truth:
    try:
        text = file.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise CcdError(file, f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise CcdError(file, f"cannot read: {exc.strerror or exc}") from None
    try:
        values = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CcdError(file, f"not valid JSON: {exc.msg} (line {exc.lineno}, column "
                             f"{exc.colno})") from None
    if not isinstance(values, dict):
        raise CcdError(file, f"must hold a JSON object, got {type(values).__name__}")
    return Truth(folder=folder, values=values)


def find_truth(folder_or_session: Any) -> Truth | None:
    """The :class:`Truth` of a session folder, ``truth.json`` path or session (``.root``), or
    ``None`` when there is no ``truth.json`` (a real capture rather than a simulation).

    A ``truth.json`` that exists but cannot be read or parsed raises :class:`CcdError`.
    """
    folder, file, _ = _locate(folder_or_session)
    if not file.is_file():
        return None
    return _read(folder, file)


def load_truth(folder_or_session: Any) -> Truth:
    """The :class:`Truth` of a session folder, ``truth.json`` path or session (``.root``).

    Raises
    ------
    CcdError
        ``"<where>: no truth.json: not a simulated session"`` when the file is absent;
        ``"<truth.json>: not valid JSON: ..."`` (or another one-line reason) when it is unusable.
    """
    folder, file, where = _locate(folder_or_session)
    if not file.is_file():
        raise CcdError(where, f"no {TRUTH_NAME}: not a simulated session")
    return _read(folder, file)
