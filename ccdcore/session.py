"""Capture sessions: the ``session.toml`` manifest, plain folders of images, lazy frame access.

A session is a folder of image files plus a manifest saying what each frame is for (its *role*:
dark frames, photon-transfer pairs, fixed-pattern configurations, flat fields, exposure brackets,
scenes, change-detection reference/target brackets) and its capture metadata (exposure, gain,
level, configuration, temperature ...).  See the "Capture sessions" section of DESIGN.md for the
manifest format.  Opening a session never reads pixels: it reads every file's header once (cached)
to validate the session and to fill in metadata the manifest leaves out (EXIF ``ExposureTime``,
FITS ``EXPTIME``/``GAIN``/``CCD-TEMP``).  Pixels are read one frame at a time by
:meth:`Session.read` and :meth:`Session.iter_frames`, so a thousand-frame session never sits in
memory.

Validation reports every problem at once in :attr:`Session.problems` (each naming the file or the
manifest entry) instead of stopping at the first; :meth:`Session.raise_if_invalid` turns the errors
into one :class:`~ccdcore.errors.SessionError`.

Public objects
--------------
ROLES, LAYOUTS
    The frame roles and camera colour layouts the manifest accepts.
ROLE_SYNONYMS
    Folder names recognised as roles when a plain folder is opened (``darks`` -> ``dark`` ...).
Camera, FrameRecord, Problem
    Frozen records of the camera, of one frame, and of one validation problem.
Session
    A validated session: frame lists by role, cached headers, lazy frame reading, tables, TOML.
open_session(path)
    Open a session folder, a ``session.toml``, a plain folder of images or an EMVA1288 descriptor.
draft_manifest(session, path=None)
    Write a manifest draft (``session.toml.draft``) for a session, e.g. one opened from a folder.
"""
from __future__ import annotations

import dataclasses
import posixpath
import re
import tomllib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any, Iterable, Iterator

import numpy as np
import tomli_w

from .errors import CcdError, ImageReadError, SessionError
from .io import IMAGE_EXTENSIONS, ImageHeader, atomic_write_text, read_header, read_image

__all__ = ["ROLES", "LAYOUTS", "ROLE_SYNONYMS", "Camera", "FrameRecord", "Problem", "Session",
           "open_session", "draft_manifest", "MANIFEST_NAME", "DRAFT_NAME"]

ROLES = ("dark", "ptc", "fixed_pattern", "flat", "bracket", "scene", "reference", "target")
LAYOUTS = ("mono", "rgb", "bayer-rggb", "bayer-bggr", "bayer-grbg", "bayer-gbrg")
MANIFEST_NAME = "session.toml"
DRAFT_NAME = "session.toml.draft"
SCHEMA = 1

#: folder name (lower case) -> role, for plain folders without a manifest
ROLE_SYNONYMS: dict[str, str] = {
    **{r: r for r in ROLES},
    "darks": "dark", "bias": "dark", "biases": "dark", "black": "dark", "offset": "dark",
    "ptcs": "ptc", "pairs": "ptc", "photon_transfer": "ptc", "photon-transfer": "ptc",
    "fixed-pattern": "fixed_pattern", "fixedpattern": "fixed_pattern", "fpn": "fixed_pattern",
    "prnu": "fixed_pattern",
    "flats": "flat", "flatfield": "flat", "flatfields": "flat", "flat_field": "flat",
    "flat-field": "flat", "flat_fields": "flat", "white": "flat",
    "brackets": "bracket", "hdr": "bracket", "exposures": "bracket",
    "scenes": "scene", "images": "scene",
    "references": "reference", "ref": "reference", "background": "reference",
    "targets": "target", "test": "target",
}

#: roles whose frames need an exposure time (manifest or file header)
EXPOSURE_ROLES = frozenset({"bracket", "reference", "target"})
#: roles whose frames must all share one shape, dtype and bit depth (scenes are independent images)
UNIFORM_ROLES = frozenset(ROLES) - {"scene"}

_CAMERA_KEYS = ("name", "bits", "layout", "black_level")
_META_KEYS = ("level", "exposure", "config", "gain", "temperature", "roi", "stack", "note",
              "photons")
_FRAME_KEYS = frozenset(("path", "role") + _META_KEYS)
_GROUP_KEYS = frozenset(("glob", "role") + _META_KEYS)
_HEADER_KEYS = ("exposure", "gain", "temperature")  # metadata a file header can supply


# --------------------------------------------------------------------------------------------
# records
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Camera:
    """The camera of a session: free-text name, ADC bit depth, colour layout (one of LAYOUTS)
    and, optionally, its black level (the electronic offset in DN that is not signal and carries
    no shot noise; manifest key ``[camera] black_level``, used by :mod:`ccdcore.noise`)."""

    name: str = ""
    bits: int | None = None
    layout: str = "mono"
    black_level: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "bits": self.bits, "layout": self.layout,
                "black_level": self.black_level}


@dataclass(frozen=True)
class FrameRecord:
    """One frame of a session and its metadata (no pixels).

    ``inferred`` names the metadata keys that were not in the manifest but read from the file
    header (``exposure``, ``gain``, ``temperature``) or, for a plain folder, guessed from the folder
    layout and file names (``role``, ``level``, ``config``).  ``photons`` is the mean number of photons per pixel
    of an EMVA1288 bright point (an extension of the manifest, optional).
    """

    path: Path
    relpath: str
    role: str
    level: int | None = None
    exposure: float | None = None
    config: int | None = None
    gain: float | None = None
    temperature: float | None = None
    roi: tuple[int, int, int, int] | None = None
    stack: int | str | None = None
    note: str | None = None
    inferred: tuple[str, ...] = ()
    photons: float | None = None

    def metadata(self) -> dict[str, Any]:
        """The manifest keys of this frame that are set (``role`` and the optional keys)."""
        out: dict[str, Any] = {"role": self.role}
        for key in _META_KEYS:
            value = getattr(self, key)
            if value is not None:
                out[key] = list(value) if key == "roi" else value
        return out

    def to_dict(self) -> dict[str, Any]:
        d = {"relpath": self.relpath, "role": self.role}
        for key in _META_KEYS:
            value = getattr(self, key)
            d[key] = list(value) if key == "roi" and value is not None else value
        d["inferred"] = list(self.inferred)
        return d


@dataclass(frozen=True)
class Problem:
    """One validation problem: ``where`` (file relpath or manifest entry), message, severity."""

    where: str
    message: str
    severity: str = "error"  # "error" | "warning"

    def __str__(self) -> str:
        return f"{self.where}: {self.message}"

    def to_dict(self) -> dict[str, str]:
        return {"where": self.where, "message": self.message, "severity": self.severity}


def _shape_text(shape: tuple[int, ...] | None) -> str | None:
    return None if shape is None else "x".join(str(n) for n in shape)


def size_text(shape: tuple[int, ...] | str | None, sep: str = "x") -> str | None:
    """A frame size as people state it, width first: ``(H, W)`` or ``(H, W, C)`` (NumPy order,
    or the ``"HxW"`` text of :meth:`Session.groups_table`) -> ``"WxH"`` or ``"WxHxC"``.
    Other text (``"mixed"``) is returned unchanged."""
    if shape is None:
        return None
    if isinstance(shape, str):
        parts = shape.split("x")
        if not (len(parts) in (2, 3) and all(p.isdigit() for p in parts)):
            return shape
        dims = [int(p) for p in parts]
    else:
        dims = [int(n) for n in shape]
    return sep.join(map(str, dims[1::-1] + dims[2:]))      # (H, W, ...) -> W, H, ...


def _sort_key(value: Any) -> tuple:
    """Sort None last and keep ints, floats and strings apart without comparing across types."""
    if value is None:
        return (2, 0, "")
    if isinstance(value, str):
        return (1, 0, value)
    return (0, value, "")


def _group_key(rec: FrameRecord) -> Any:
    """The key that groups frames of one role (see :meth:`Session.groups_table`)."""
    if rec.role == "ptc":
        return rec.level
    if rec.role == "fixed_pattern":
        return rec.config
    if rec.role == "flat":
        return rec.level if rec.level is not None else rec.exposure
    if rec.role == "dark":
        return rec.exposure
    if rec.role in ("bracket", "reference", "target"):
        return rec.stack
    return None


def _grouped(records: Iterable[FrameRecord], key) -> dict[Any, tuple[FrameRecord, ...]]:
    groups: dict[Any, list[FrameRecord]] = {}
    for rec in records:
        groups.setdefault(key(rec), []).append(rec)
    return {k: tuple(groups[k]) for k in sorted(groups, key=_sort_key)}


# --------------------------------------------------------------------------------------------
# the session
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Session:
    """A capture session: camera, frames (metadata only), validation problems.

    Build it with :func:`open_session`.  Frames are listed in manifest order (``[[frames]]``
    entries, then each ``[[groups]]`` entry's matches in sorted order); for a plain folder, in
    sorted path order.  Pixels are read on demand, one frame at a time.
    """

    root: Path
    manifest_path: Path | None
    source: str  # "manifest" | "folder" | "emva1288"
    camera: Camera
    frames: tuple[FrameRecord, ...]
    problems: tuple[Problem, ...] = ()
    _headers: dict[Path, ImageHeader] = field(default_factory=dict, repr=False)

    # ---- validity ---------------------------------------------------------------------------
    @property
    def ok(self) -> bool:
        """True when no problem has severity ``"error"``."""
        return not any(p.severity == "error" for p in self.problems)

    @property
    def errors(self) -> tuple[Problem, ...]:
        return tuple(p for p in self.problems if p.severity == "error")

    @property
    def warnings(self) -> tuple[Problem, ...]:
        return tuple(p for p in self.problems if p.severity != "error")

    def raise_if_invalid(self) -> None:
        """Raise :class:`SessionError` listing every error (``str``: the first plus a count)."""
        errors = self.errors
        if not errors:
            return
        first = errors[0]
        more = f" (and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''})" \
            if len(errors) > 1 else ""
        raise SessionError(first.where, first.message + more, problems=errors)

    # ---- frames by role ---------------------------------------------------------------------
    def by_role(self, role: str) -> tuple[FrameRecord, ...]:
        """Frames of one role, in session order."""
        if role not in ROLES:
            raise CcdError("role", f"unknown role '{role}'; choose one of {', '.join(ROLES)}")
        return tuple(r for r in self.frames if r.role == role)

    def roles(self) -> dict[str, int]:
        """Role -> number of frames, for the roles present (in :data:`ROLES` order)."""
        counts = Counter(r.role for r in self.frames)
        return {role: counts[role] for role in ROLES if counts[role]}

    def ptc_levels(self) -> dict[int, tuple[FrameRecord, ...]]:
        """Photon-transfer level -> its frames (two or more each in a valid session), by level."""
        return _grouped((r for r in self.by_role("ptc") if r.level is not None),
                        lambda r: r.level)

    def dark_frames(self) -> tuple[FrameRecord, ...]:
        return self.by_role("dark")

    def fixed_pattern_configs(self) -> dict[int, tuple[FrameRecord, ...]]:
        """Configuration id -> its frames (the n1 configurations x n2 frames of sec. V-B)."""
        return _grouped((r for r in self.by_role("fixed_pattern") if r.config is not None),
                        lambda r: r.config)

    def flats(self) -> dict[Any, tuple[FrameRecord, ...]]:
        """Flat-field frames keyed by level when set, else by exposure (sorted keys)."""
        return _grouped(self.by_role("flat"), _group_key)

    def bracket_stacks(self, role: str = "bracket") -> dict[Any, tuple[FrameRecord, ...]]:
        """Stack id (``None`` when unset) -> its frames sorted by exposure.

        ``role`` is ``"bracket"``, ``"reference"`` or ``"target"``.
        """
        if role not in ("bracket", "reference", "target"):
            raise CcdError("role", f"'{role}' frames do not form exposure brackets")
        stacks = _grouped(self.by_role(role), lambda r: r.stack)
        return {k: tuple(sorted(v, key=lambda r: _sort_key(r.exposure)))
                for k, v in stacks.items()}

    def scenes(self) -> tuple[FrameRecord, ...]:
        return self.by_role("scene")

    # ---- pixels -----------------------------------------------------------------------------
    def header(self, rec: FrameRecord) -> ImageHeader:
        """The file header of a frame (read once, then cached)."""
        hdr = self._headers.get(rec.path)
        if hdr is None:
            hdr = self._headers[rec.path] = read_header(rec.path)
        return hdr

    def _header_or_none(self, rec: FrameRecord) -> ImageHeader | None:
        try:
            return self.header(rec)
        except ImageReadError:
            return None

    def read(self, rec: FrameRecord) -> np.ndarray:
        """The pixels of one frame, in the stored dtype (``(H, W)`` or ``(H, W, C)``)."""
        return read_image(rec.path)

    def iter_frames(self, records: Iterable[FrameRecord] | None = None
                    ) -> Iterator[tuple[FrameRecord, np.ndarray]]:
        """Yield ``(record, pixels)`` one frame at a time, reading each file only when reached.

        ``records`` defaults to every frame of the session.
        """
        for rec in (self.frames if records is None else records):
            yield rec, self.read(rec)

    def verify_pixels(self) -> Session:
        """Decode every frame once, one at a time, and return a copy of the session whose
        problems also list the frames whose pixel data cannot be read (truncated or corrupt).

        Opening a session reads headers only, so a file cut short after its header is caught
        here (or when the frame is first read), not at open time.
        """
        extra = []
        for rec in self.frames:
            if rec.path not in self._headers:
                continue  # the header itself is unreadable: already reported
            try:
                self.read(rec)
            except ImageReadError as exc:
                extra.append(Problem(rec.relpath, exc.problem))
        return dataclasses.replace(self, problems=self.problems + tuple(extra))

    # ---- tables -----------------------------------------------------------------------------
    def groups_table(self) -> list[dict[str, Any]]:
        """One row per group of frames: ``role``, ``key`` (ptc level, fixed-pattern config, flat
        level or exposure, dark exposure, bracket stack; ``None`` for scenes), ``count``,
        ``shape`` and ``dtype`` (``"mixed"`` when they differ, ``None`` when unreadable), and the
        distinct ``exposures`` (sorted)."""
        rows = []
        for role in ROLES:
            for key, recs in _grouped(self.by_role(role), _group_key).items():
                headers = [self._header_or_none(r) for r in recs]
                shapes = {_shape_text(h.shape) if h else None for h in headers}
                dtypes = {str(h.dtype) if h else None for h in headers}
                exposures = sorted({r.exposure for r in recs if r.exposure is not None})
                rows.append({
                    "role": role, "key": key, "count": len(recs),
                    "shape": shapes.pop() if len(shapes) == 1 else "mixed",
                    "dtype": dtypes.pop() if len(dtypes) == 1 else "mixed",
                    "exposures": exposures,
                })
        return rows

    def frames_table(self) -> list[dict[str, Any]]:
        """One row per frame: its metadata plus ``shape``, ``dtype``, ``bits`` from the header
        (``None`` when unreadable) and ``inferred`` (comma-separated keys)."""
        rows = []
        for rec in self.frames:
            hdr = self._header_or_none(rec)
            row = rec.to_dict()
            row["roi"] = None if rec.roi is None else ",".join(map(str, rec.roi))
            row.update(shape=_shape_text(hdr.shape) if hdr else None,
                       dtype=str(hdr.dtype) if hdr else None, bits=hdr.bits if hdr else None,
                       inferred=", ".join(rec.inferred))
            rows.append(row)
        return rows

    # ---- serialisation ----------------------------------------------------------------------
    def to_toml(self) -> str:
        """A manifest for this session: camera plus one ``[[frames]]`` entry per frame.

        Metadata inferred from headers or the folder layout is written explicitly, so the user
        can review and edit it; opening the manifest gives the same frames (paths, roles,
        metadata) in the same order.
        """
        camera = {k: v for k, v in self.camera.to_dict().items() if v is not None}
        origin = {"folder": f"the folder {self.root} (no manifest)",
                  "emva1288": f"the EMVA1288 descriptor {self.manifest_path}"}.get(self.source)
        parts = [f"# Session manifest drafted by ccdcore from {origin}.\n"
                 "# Check every entry (comments say which keys were inferred), then save it as "
                 f"{MANIFEST_NAME}.\n" if origin else "",
                 tomli_w.dumps({"schema": SCHEMA}), "\n[camera]\n", tomli_w.dumps(camera)]
        for rec in self.frames:
            parts.append("\n[[frames]]\n")
            if rec.inferred:
                parts.append(f"# inferred: {', '.join(rec.inferred)}\n")
            parts.append(tomli_w.dumps({"path": rec.relpath, **rec.metadata()}))
        return "".join(parts)

    def to_dict(self) -> dict[str, Any]:
        return {
            "root": str(self.root),
            "manifest_path": None if self.manifest_path is None else str(self.manifest_path),
            "source": self.source, "ok": self.ok, "camera": self.camera.to_dict(),
            "roles": self.roles(), "frames": [r.to_dict() for r in self.frames],
            "problems": [p.to_dict() for p in self.problems],
        }


# --------------------------------------------------------------------------------------------
# building a session: candidates -> checked records
# --------------------------------------------------------------------------------------------
@dataclass
class _Candidate:
    """A frame before validation: where it was declared, its path and manifest metadata."""

    entry: str  # manifest entry ("frames[2] (a.tif)", "groups[0] (dark/*.tif)") or relpath
    relpath: str
    role: str
    meta: dict[str, Any]
    inferred: tuple[str, ...] = ()


def _path_problem(root: Path, relpath: str) -> str | None:
    """Why ``relpath`` is not a safe path inside ``root`` (resolved), or None when it is."""
    if not relpath:
        return "empty path"
    if PurePosixPath(relpath).is_absolute() or PureWindowsPath(relpath).is_absolute():
        return "absolute path; paths must be relative to the session folder"
    norm = posixpath.normpath(relpath)
    if norm == ".." or norm.startswith("../"):
        return "path escapes the session folder ('..')"
    target = (root / norm).resolve()
    if not target.is_relative_to(root):
        return f"resolves outside the session folder (symbolic link to {target})"
    return None


def _assemble(root: Path, manifest_path: Path | None, source: str, camera: Camera,
              candidates: list[_Candidate], problems: list[Problem]) -> Session:
    """Check paths, read headers, infer header metadata and validate a list of candidates."""
    headers: dict[Path, ImageHeader] = {}
    records: list[FrameRecord] = []
    seen: dict[Path, str] = {}
    reported: set[tuple[str, str]] = set()

    def once(where: str, message: str) -> None:  # a group reports its entry problem once
        if (where, message) not in reported:
            reported.add((where, message))
            problems.append(Problem(where, message))

    for cand in candidates:
        # a file matched by a group glob also names the group
        origin = f" ({cand.entry})" if cand.entry.startswith("groups") else ""
        why = _path_problem(root, cand.relpath)
        if why is not None:
            problems.append(Problem(cand.relpath, why + origin))
            continue
        path = (root / posixpath.normpath(cand.relpath)).resolve()
        if not path.exists():
            problems.append(Problem(cand.relpath, "file not found"))
            continue
        if path in seen:
            problems.append(Problem(cand.relpath, f"frame listed twice: {seen[path]} and "
                                                  f"{cand.entry}"))
            continue
        seen[path] = cand.entry
        if cand.role == "ptc" and cand.meta.get("level") is None:
            once(cand.entry, "ptc frame without 'level' (frames of one light level form pairs)")
        if cand.role == "fixed_pattern" and cand.meta.get("config") is None:
            once(cand.entry, "fixed_pattern frame without 'config' (configuration id)")

        meta, inferred = dict(cand.meta), list(cand.inferred)
        try:
            hdr = headers[path] = read_header(path)
        except ImageReadError as exc:
            problems.append(Problem(cand.relpath, exc.problem + origin))
            hdr = None
        if hdr is not None:
            for key in _HEADER_KEYS:
                value = getattr(hdr, key)
                if meta.get(key) is None and value is not None:
                    meta[key] = value
                    inferred.append(key)
        if cand.role in EXPOSURE_ROLES and meta.get("exposure") is None and hdr is not None:
            problems.append(Problem(cand.relpath, f"missing exposure: a {cand.role} frame needs "
                                    "one, and neither the manifest nor the file header "
                                    "(EXIF ExposureTime, FITS EXPTIME) gives it"))
        roi = meta.get("roi")
        if roi is not None and hdr is not None:
            x, y, w, h = roi
            if x + w > hdr.width or y + h > hdr.height:
                problems.append(Problem(cand.relpath, f"roi {list(roi)} extends past the "
                                        f"{hdr.width}x{hdr.height} frame"))
        records.append(FrameRecord(path=path, relpath=posixpath.normpath(cand.relpath),
                                   role=cand.role, inferred=tuple(dict.fromkeys(inferred)),
                                   **meta))

    problems.extend(_cross_frame_problems(records, headers, camera))
    return Session(root=root, manifest_path=manifest_path, source=source, camera=camera,
                   frames=tuple(records), problems=tuple(problems), _headers=headers)


def _cross_frame_problems(records: list[FrameRecord], headers: dict[Path, ImageHeader],
                          camera: Camera) -> list[Problem]:
    """Shape / dtype / bit-depth consistency within roles, bits vs camera, ptc level sizes."""
    out: list[Problem] = []
    for role in ROLES:
        recs = [r for r in records if r.role == role and r.path in headers]
        if role in UNIFORM_ROLES and recs:
            sigs = {r.path: (headers[r.path].shape, str(headers[r.path].dtype),
                             headers[r.path].bits) for r in recs}
            counts = Counter(sigs[r.path] for r in recs)
            common, n_common = counts.most_common(1)[0]  # ties: the first frame's signature
            for r in recs:
                sig = sigs[r.path]
                if sig == common:
                    continue
                diffs = [f"{name} {fmt(a)} differs from {fmt(b)}"
                         for name, a, b, fmt in (("size (WxH)", sig[0], common[0], size_text),
                                                 ("dtype", sig[1], common[1], str),
                                                 ("bit depth", sig[2], common[2], str))
                         if a != b]
                out.append(Problem(r.relpath, f"{'; '.join(diffs)} of the other {role} frames "
                                              f"({n_common} frame{'s' if n_common > 1 else ''})"))
    if camera.bits is not None:
        for r in records:
            hdr = headers.get(r.path)
            # A header whose bit depth is just the container width (a 12-bit camera stored in a
            # 16-bit TIFF) says nothing about the ADC; only an explicit smaller depth is compared.
            if (hdr is not None and hdr.dtype.kind in "ui" and hdr.bits > camera.bits
                    and hdr.bits < hdr.dtype.itemsize * 8):
                out.append(Problem(r.relpath, f"{hdr.bits}-bit data but camera.bits = "
                                              f"{camera.bits}"))
    for level, recs in _grouped((r for r in records if r.role == "ptc" and r.level is not None),
                                lambda r: r.level).items():
        if len(recs) < 2:
            out.append(Problem(f"ptc level {level}", f"only one frame ({recs[0].relpath}); a "
                                                     "photon-transfer level needs at least two"))
    return out


# --------------------------------------------------------------------------------------------
# the manifest
# --------------------------------------------------------------------------------------------
def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


def _check_value(key: str, value: Any) -> tuple[Any, str | None]:
    """Validate one metadata value; return (converted value, problem or None)."""
    if key in ("level", "config"):
        return (value, None) if _is_int(value) else (None, f"'{key}' must be an integer, "
                                                           f"got {value!r}")
    if key in ("exposure", "photons"):
        if _is_number(value) and value >= 0:
            return float(value), None
        unit = "seconds" if key == "exposure" else "photons per pixel"
        return None, f"'{key}' must be a number >= 0 ({unit}), got {value!r}"
    if key in ("gain", "temperature"):
        return (float(value), None) if _is_number(value) else (
            None, f"'{key}' must be a number, got {value!r}")
    if key == "roi":
        if (isinstance(value, list) and len(value) == 4 and all(_is_int(v) for v in value)
                and value[0] >= 0 and value[1] >= 0 and value[2] > 0 and value[3] > 0):
            return tuple(value), None
        return None, f"'roi' must be [x, y, w, h] (integers, w and h > 0), got {value!r}"
    if key == "stack":
        return (value, None) if _is_int(value) or isinstance(value, str) else (
            None, f"'stack' must be an integer or a string, got {value!r}")
    if key == "note":
        return (value, None) if isinstance(value, str) else (None, "'note' must be a string")
    raise AssertionError(key)


def _parse_entry(entry: Any, where: str, allowed: frozenset[str],
                 problems: list[Problem]) -> tuple[str | None, dict[str, Any]]:
    """Validate the role and metadata of a ``[[frames]]`` / ``[[groups]]`` entry."""
    role = entry.get("role")
    if role is None:
        problems.append(Problem(where, f"no 'role'; choose one of {', '.join(ROLES)}"))
    elif role not in ROLES:
        problems.append(Problem(where, f"unknown role {role!r}; choose one of "
                                       f"{', '.join(ROLES)}"))
        role = None
    for key in entry:
        if key not in allowed:
            problems.append(Problem(where, f"unknown key '{key}' (ignored)", "warning"))
    meta: dict[str, Any] = {}
    for key in _META_KEYS:
        if key in entry:
            value, why = _check_value(key, entry[key])
            if why:
                problems.append(Problem(where, why))
            else:
                meta[key] = value
    return role, meta


def _entry_label(kind: str, i: int, entry: dict, key: str) -> str:
    value = entry.get(key)
    return f"{kind}[{i}] ({value})" if isinstance(value, str) else f"{kind}[{i}]"


def _parse_camera(doc: dict, problems: list[Problem]) -> Camera:
    cam = doc.get("camera")
    if cam is None:
        problems.append(Problem("camera", "no [camera] table; assuming a mono camera of unknown "
                                          "bit depth", "warning"))
        return Camera()
    if not isinstance(cam, dict):
        problems.append(Problem("camera", "must be a table: [camera]"))
        return Camera()
    for key in cam:
        if key not in _CAMERA_KEYS:
            problems.append(Problem(f"camera.{key}", "unknown key (ignored)", "warning"))
    name, bits, layout = cam.get("name", ""), cam.get("bits"), cam.get("layout", "mono")
    if not isinstance(name, str):
        problems.append(Problem("camera.name", "must be a string"))
        name = ""
    if bits is not None and not (_is_int(bits) and 1 <= bits <= 32):
        problems.append(Problem("camera.bits", f"must be an integer from 1 to 32, got {bits!r}"))
        bits = None
    if layout not in LAYOUTS:
        problems.append(Problem("camera.layout", f"unknown layout {layout!r}; choose one of "
                                                 f"{', '.join(LAYOUTS)}"))
        layout = "mono"
    black_level = cam.get("black_level")
    if black_level is not None:
        if _is_number(black_level) and black_level >= 0:
            black_level = float(black_level)
        else:
            problems.append(Problem("camera.black_level", f"must be a number >= 0 (DN), got "
                                                          f"{black_level!r}"))
            black_level = None
    return Camera(name=name, bits=bits, layout=layout, black_level=black_level)


def _glob_problem(pattern: str) -> str | None:
    """Why a group's glob could reach outside the session folder, or None."""
    if PurePosixPath(pattern).is_absolute() or PureWindowsPath(pattern).is_absolute():
        return "absolute glob; globs must be relative to the session folder"
    if ".." in PurePosixPath(pattern).parts:
        return "glob escapes the session folder ('..')"
    return None


def _glob(root: Path, pattern: str) -> tuple[list[str], int]:
    """Relative posix paths of the image files ``pattern`` matches (sorted), and the number of
    non-image files it matched."""
    images, others = [], 0
    for p in root.glob(pattern):
        rel = p.relative_to(root).as_posix()
        if not p.is_file() or any(part.startswith(".") for part in PurePosixPath(rel).parts):
            continue
        if p.suffix.lower() in IMAGE_EXTENSIONS:
            images.append(rel)
        else:
            others += 1
    return sorted(images), others


def _open_manifest(manifest_path: Path) -> Session:
    root = manifest_path.parent.resolve()
    try:
        doc = tomllib.loads(manifest_path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise CcdError(manifest_path, f"TOML syntax error: {exc}") from None
    except (UnicodeDecodeError, OSError) as exc:
        raise CcdError(manifest_path, f"cannot read the manifest: {exc}") from None

    problems: list[Problem] = []
    schema = doc.get("schema")
    if schema is None:
        problems.append(Problem("schema", f"missing; assuming schema = {SCHEMA}", "warning"))
    elif schema != SCHEMA or not _is_int(schema):
        problems.append(Problem("schema", f"unsupported schema {schema!r}; this version reads "
                                          f"schema = {SCHEMA}"))
    for key in doc:
        if key not in ("schema", "camera", "frames", "groups"):
            problems.append(Problem(key, "unknown top-level key (ignored)", "warning"))
    camera = _parse_camera(doc, problems)

    candidates: list[_Candidate] = []
    for kind, allowed, path_key in (("frames", _FRAME_KEYS, "path"),
                                    ("groups", _GROUP_KEYS, "glob")):
        entries = doc.get(kind, [])
        if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
            problems.append(Problem(kind, f"must be an array of tables: [[{kind}]]"))
            continue
        for i, entry in enumerate(entries):
            where = _entry_label(kind, i, entry, path_key)
            role, meta = _parse_entry(entry, where, allowed, problems)
            target = entry.get(path_key)
            if not isinstance(target, str) or not target:
                problems.append(Problem(where, f"no '{path_key}' (a path relative to the "
                                               "session folder)"))
                continue
            if kind == "frames":
                relpaths = [target]
            else:
                why = _glob_problem(target)
                if why is not None:
                    problems.append(Problem(where, why))
                    continue
                relpaths, others = _glob(root, target)
                if not relpaths:
                    problems.append(Problem(where, "glob matches no image file" + (
                        f" ({others} non-image file{'s' if others > 1 else ''})" if others
                        else "")))
            if role is not None:
                candidates.extend(_Candidate(where, rel, role, meta) for rel in relpaths)
    if not candidates and not any(p.severity == "error" for p in problems):
        problems.append(Problem(manifest_path.name, "the manifest lists no frames"))
    return _assemble(root, manifest_path, "manifest", camera, candidates, problems)


# --------------------------------------------------------------------------------------------
# plain folders
# --------------------------------------------------------------------------------------------
#: the id key a plain folder's frames of a role get from their sub-folder or file name
_ID_KEYS = {"ptc": "level", "fixed_pattern": "config"}


def _subfolder_ids(names: list[str]) -> dict[str, int]:
    """Number sub-folders: by the integer in each name when those are distinct, else 1, 2, ..."""
    nums = {}
    for name in names:
        found = re.findall(r"\d+", name)
        nums[name] = int(found[-1]) if found else None
    if None not in nums.values() and len(set(nums.values())) == len(names):
        return nums  # type: ignore[return-value]
    return {name: i for i, name in enumerate(sorted(names), start=1)}


def _folder_images(root: Path) -> list[str]:
    out = []
    for p in root.rglob("*"):
        rel = p.relative_to(root)
        if (p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()
                and not any(part.startswith(".") for part in rel.parts)):
            out.append(rel.as_posix())
    return sorted(out)


def _open_folder(folder: Path) -> Session:
    root = folder.resolve()
    problems: list[Problem] = []
    candidates: list[_Candidate] = []
    relpaths = _folder_images(root)
    # role from the first path component; ptc level / fixed_pattern config from the sub-folder
    # (ptc/L03/a.tif) or else from the first number of the file name (ptc/L03_a.tif)
    sub: dict[str, list[str]] = {}
    roles: dict[str, str] = {}
    for rel in relpaths:
        parts = rel.split("/")
        roles[rel] = ROLE_SYNONYMS.get(parts[0].lower(), "scene") if len(parts) > 1 else "scene"
        if roles[rel] in _ID_KEYS and len(parts) > 2:
            sub.setdefault(roles[rel], []).append(parts[1])
    ids = {role: _subfolder_ids(sorted(set(names))) for role, names in sub.items()}
    for rel in relpaths:
        role, parts = roles[rel], rel.split("/")
        meta: dict[str, Any] = {}
        inferred = ["role"]
        if role in _ID_KEYS:
            number = re.search(r"\d+", PurePosixPath(rel).stem)
            value = ids[role][parts[1]] if len(parts) > 2 else (
                int(number.group()) if number else None)
            if value is not None:
                meta[_ID_KEYS[role]] = value
                inferred.append(_ID_KEYS[role])
        candidates.append(_Candidate(rel, rel, role, meta, tuple(inferred)))

    session = _assemble(root, None, "folder", Camera(name=root.name), candidates, problems)
    headers = [session._header_or_none(r) for r in session.frames]
    headers = [h for h in headers if h is not None]
    bits = max((h.bits for h in headers if h.dtype.kind in "ui"), default=None)
    layouts = {h.layout for h in headers}
    layout = layouts.pop() if len(layouts) == 1 else "mono"
    if layout not in LAYOUTS:
        layout = "rgb" if layout == "rgba" else "mono"
    camera = Camera(name=root.name, bits=bits, layout=layout)

    n_exp = sum("exposure" in r.inferred for r in session.frames)
    summary = ", ".join(f"{role}: {n}" for role, n in session.roles().items())
    if relpaths:
        note = (f"no {MANIFEST_NAME}: roles inferred from folder names ({summary}), exposures "
                f"from file headers for {n_exp} of {len(relpaths)} frames, camera bits = {bits}, "
                f"layout = {layout}; check them and save a manifest with draft_manifest()")
        extra = [Problem(str(root), note, "warning")]
    else:
        extra = [Problem(str(root), f"no image files found (looked for "
                                    f"{', '.join(sorted(IMAGE_EXTENSIONS))})")]
    return dataclasses.replace(session, camera=camera,
                               problems=tuple(extra) + session.problems)


# --------------------------------------------------------------------------------------------
# entry points
# --------------------------------------------------------------------------------------------
def _is_emva_descriptor(path: Path) -> bool:
    """True when the first non-comment, non-blank line of ``path`` starts with ``v``."""
    try:
        with path.open("r", encoding="utf-8", errors="replace") as f:
            head = f.read(65536)  # a descriptor starts with a few short lines
    except OSError:
        return False
    for line in head.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            return line.split()[0] == "v"
    return False


def open_session(path: str | Path, *, check_pixels: bool = False) -> Session:
    """Open a capture session.

    Parameters
    ----------
    path
        A session folder holding ``session.toml``; a manifest file (``*.toml``); a plain folder of
        images (no manifest: roles from folder names, metadata from headers); or an EMVA1288
        descriptor file (``v``/``n``/``b``/``d``/``i`` lines, see :mod:`ccdcore.emva`).
    check_pixels
        Also decode every frame once (streamed) to find truncated or corrupt pixel data, see
        :meth:`Session.verify_pixels`.  By default only headers are read.

    Returns
    -------
    Session
        Validation problems are in :attr:`Session.problems`; nothing is raised for them.

    Raises
    ------
    CcdError
        The path does not exist, is not a folder, manifest or descriptor, or the manifest is not
        valid TOML (the message gives the line).
    """
    p = Path(path)
    if not p.exists():
        raise CcdError(p, "does not exist")
    if p.is_dir():
        manifest = p / MANIFEST_NAME
        session = _open_manifest(manifest) if manifest.is_file() else _open_folder(p)
    elif p.suffix.lower() == ".toml":
        session = _open_manifest(p)
    elif _is_emva_descriptor(p):
        from .emva import open_emva_descriptor

        session = open_emva_descriptor(p)
    else:
        raise CcdError(p, "not a session: give a session folder, its session.toml, a folder "
                          "of images or an EMVA1288 descriptor file")
    return session.verify_pixels() if check_pixels else session


def draft_manifest(session: Session, path: str | Path | None = None) -> Path:
    """Write :meth:`Session.to_toml` as a manifest draft and return its path.

    Parameters
    ----------
    session
        The session (typically opened from a plain folder).
    path
        Where to write; default ``<session root>/session.toml.draft``.  It must be inside the
        session folder (manifest paths are relative to it).  An existing ``session.toml`` is never
        overwritten: rename the draft once you have checked it.

    Raises
    ------
    CcdError
        ``path`` is an existing ``session.toml`` or lies outside the session folder.
    """
    target = session.root / DRAFT_NAME if path is None else Path(path)
    if target.parent.resolve() != session.root:
        raise CcdError(target, "a manifest must be written in the session folder "
                               f"{session.root} (its paths are relative to it)")
    if target.name == MANIFEST_NAME and target.exists():
        raise CcdError(target, f"already exists; the draft never overwrites a {MANIFEST_NAME} "
                               f"(write {DRAFT_NAME} instead)")
    return atomic_write_text(target, session.to_toml())
