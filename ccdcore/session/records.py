"""The records of a capture session and every query on its frames.

:class:`Camera`, :class:`FrameRecord` and :class:`Problem` are frozen records; :class:`Session`
holds them with the cached file headers and answers every question an estimator asks of a
session's frames: frames by role, photon-transfer levels, fixed-pattern configurations, flat and
dark groups by offset setting and gain, exposure brackets, scene patches, the max-intensity frame;
and the content hash of its files for a product's provenance (:meth:`Session.content_hash`).
Estimators never group frames themselves (``docs/session.md`` gives the manifest keys).

Validation problems carry a machine-readable ``code`` and the ``roles`` whose frames they touch,
so a verb refuses exactly the sessions whose errors concern the frames it uses
(:meth:`Session.raise_if_invalid` with ``roles=``) and no caller matches the text of a message.
The codes are the members of :class:`ProblemCode`, each with its fix in plain words; a
:class:`Problem` accepts no other code.
"""
from __future__ import annotations

import dataclasses
import hashlib
import itertools
import math
import os
import threading
from collections import Counter, OrderedDict, deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any, Iterable, Iterator, Sized

import numpy as np
import tomli_w

from ..channels import LAYOUTS
from ..common import group_by, sort_key
from ..errors import CcdError, ImageReadError, SessionError
from ..io.frames import ImageHeader, read_header, read_image
from ..progress import checkpoint

__all__ = ["ROLES", "LAYOUTS", "FLAGS", "MAX_INTENSITY", "META_KEYS", "EXPOSURE_ROLES",
           "MIN_EXPOSURE", "MAX_EXPOSURE",
           "UNIFORM_ROLES", "MANIFEST_NAME", "DRAFT_NAME", "SCHEMA", "Camera", "FrameRecord",
           "ProblemCode", "Problem", "Session"]

ROLES = ("dark", "ptc", "fixed_pattern", "flat", "bracket", "scene", "reference", "target")
MANIFEST_NAME = "session.toml"
DRAFT_NAME = "session.toml.draft"
SCHEMA = 1

#: the flag of the scene frame taken at maximum intensity (the correction check, sec. VII-A of
#: Healey & Kondepudy 1994)
MAX_INTENSITY = "max-intensity"
#: the frame flags the manifest accepts (key ``flags``, a list of these)
FLAGS: tuple[str, ...] = (MAX_INTENSITY,)

#: the exposure times (seconds) a frame may have besides 0: 1 ns to 1e6 s (11.6 days); beyond
#: them a value is a typo or a unit slip, and a response fit's logs and ratios overflow
MIN_EXPOSURE = 1e-9
MAX_EXPOSURE = 1e6

#: roles whose frames need an exposure time (manifest or file header)
EXPOSURE_ROLES = frozenset({"bracket", "reference", "target"})
#: roles whose frames must all share one shape, dtype and bit depth (scenes are independent images)
UNIFORM_ROLES = frozenset(ROLES) - {"scene"}

#: the per-frame metadata keys of the manifest, in the order a manifest draft writes them
META_KEYS = ("level", "exposure", "config", "gain", "temperature", "roi", "stack", "setting",
             "patch", "flags", "photons", "note")


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

    ``setting`` names the camera offset setting (de Lasarte et al.: ``"NZDI"``, ``"ZDI"``),
    ``patch`` the scene surface a frame shows (Healey & Kondepudy sec. VI), ``flags`` marks
    special frames (``"max-intensity"``).  ``note`` is free text, never parsed (a manifest of
    an earlier release with ``note = "setting=NZDI"`` is still read, with a warning).
    ``inferred`` names the metadata keys that were not in the manifest but read from the file
    header (``exposure``, ``gain``, ``temperature``), guessed from a plain folder's layout
    (``role``, ``level``, ``config``) or taken from a legacy note.  ``photons`` is the mean
    number of photons per pixel of an EMVA1288 bright point.
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
    setting: str | None = None
    patch: str | None = None
    flags: tuple[str, ...] = ()
    photons: float | None = None
    note: str | None = None
    inferred: tuple[str, ...] = ()

    def metadata(self) -> dict[str, Any]:
        """The manifest keys of this frame that are set (``role`` and the optional keys)."""
        out: dict[str, Any] = {"role": self.role}
        for key in META_KEYS:
            value = getattr(self, key)
            if value is not None and value != ():
                out[key] = list(value) if key in ("roi", "flags") else value
        return out

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"relpath": self.relpath, "role": self.role}
        for key in META_KEYS:
            value = getattr(self, key)
            d[key] = list(value) if key in ("roi", "flags") and value is not None else value
        d["inferred"] = list(self.inferred)
        return d


class ProblemCode(StrEnum):
    """The code of a validation problem, for programs, and its fix in plain words (``.fix``).

    A ``str``: each member equals, hashes, formats and serialises (JSON) as its value
    (``ProblemCode.FILE_NOT_FOUND == "file-not-found"``), so code comparing a problem's code
    to a string keeps working.  ``docs/session.md`` tables every code, its severity, meaning
    and fix; the two lists are the same (tests/test_vocabularies.py).
    """

    fix: str

    def __new__(cls, value: str, fix: str) -> ProblemCode:
        member = str.__new__(cls, value)
        member._value_ = value
        member.fix = fix
        return member

    SCHEMA = "schema", "write `schema = 1` at the top of session.toml"
    NO_SCHEMA = "no-schema", "add `schema = 1` at the top of session.toml"
    NO_CAMERA = "no-camera", "add a [camera] table with bits, layout and black_level"
    UNKNOWN_KEY = "unknown-key", "remove or rename the key (docs/session.md lists the keys)"
    BAD_VALUE = "bad-value", "correct the value's type or range as the message says"
    MISSING_ROLE = ("missing-role", "give the entry a role (dark, ptc, fixed_pattern, flat, "
                                    "bracket, scene, reference, target)")
    UNKNOWN_ROLE = ("unknown-role", "use one of the roles dark, ptc, fixed_pattern, flat, "
                                    "bracket, scene, reference, target")
    MISSING_PATH = "missing-path", "give the entry a path"
    EMPTY_GLOB = "empty-glob", "correct the pattern, or capture the frames it should match"
    PATH_OUTSIDE = ("path-outside", "move the frame inside the session folder and give a "
                                    "relative path")
    FILE_NOT_FOUND = "file-not-found", "capture or copy the frame, or remove its entry"
    NOT_A_FILE = "not-a-file", "point the entry at an image, not a folder"
    DUPLICATE = "duplicate", "list each frame once"
    UNREADABLE = ("unreadable", "re-export or re-capture the file (it is truncated or "
                                "corrupt)")
    MISSING_LEVEL = ("missing-level", "give each ptc frame its light level "
                                      "(`level = 1, 2, …`)")
    MISSING_CONFIG = ("missing-config", "give each fixed_pattern frame its configuration "
                                        "(`config = 1, 2, …`)")
    MISSING_EXPOSURE = "missing-exposure", "give each bracket frame its exposure time in seconds"
    ROI_OUTSIDE = "roi-outside", "shrink the roi to fit inside the frame"
    MISMATCH = ("mismatch", "capture every frame of a role with the same size, bit depth and "
                            "sample type")
    BIT_DEPTH = "bit-depth", "set [camera] bits to the depth the data use"
    LAYOUT = ("layout", "set [camera] layout to what the frames hold: mono for one channel, rgb "
                        "for three, bayer-rggb (or another mosaic) for a raw one-channel mosaic")
    PTC_SINGLE_FRAME = ("ptc-single-frame", "capture a second frame at that light level (pairs "
                                            "are differenced)")
    NO_FRAMES = ("no-frames", "list the frames in session.toml (the capture plan writes a "
                              "template)")
    DEPRECATED_NOTE = "deprecated-note", "write the key the warning names instead of `note`"
    FOLDER_INFERRED = ("folder-inferred", "review session.toml.draft (`ccdcore session "
                                          "--draft`) and save it as session.toml")
    NOT_A_BRACKET = ("not-a-bracket", "if the images are a bracket, write a manifest "
                                      "(`ccdcore session --draft`) giving each frame "
                                      "role = \"bracket\" and its exposure")
    DUPLICATE_EXPOSURE = ("duplicate-exposure", "remove the extra frames, put each bracket in "
                                                "its own sub-folder, or give each bracket its "
                                                "own `stack` in a manifest")
    BRACKET_SETTINGS = ("bracket-settings", "remove the frames taken at another camera, ISO, "
                                            "aperture or gain, or give each frame its effective "
                                            "exposure in a manifest")
    DESCRIPTOR_LINE = "descriptor-line", "correct the descriptor line the message names"
    DESCRIPTOR_SIZE = "descriptor-size", "re-export the image at the size of the `n` line"
    TEMPERATURE_MISMATCH = ("temperature-mismatch", "capture dark frames (and biases) at the "
                                                    "sensor temperature of the frames they "
                                                    "correct, within the tolerance the message "
                                                    "gives")


@dataclass(frozen=True)
class Problem:
    """One validation problem.

    Attributes
    ----------
    where
        The file (relative path) or manifest entry it concerns.
    message
        One line for a person.
    severity
        ``"error"`` or ``"warning"``.
    code
        What kind of problem, for programs: a :class:`ProblemCode` (a ``str``,
        ``"file-not-found"``, ``"unknown-key"`` ...; the list is in ``docs/session.md``), its
        fix ``code.fix``.  Keyword only and required.  The string of a member is taken as that
        member (a problem rebuilt from :meth:`to_dict`); any other string is refused
        (``ValueError``), as is any other type (``TypeError``).  ccdcore itself always passes a
        member.  Never match the message.
    roles
        The roles whose frames it touches; empty for a problem of the whole session (schema,
        camera), which touches every role.
    """

    where: str
    message: str
    severity: str = "error"  # "error" | "warning"
    code: ProblemCode = field(kw_only=True)
    roles: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if isinstance(self.code, ProblemCode):
            return
        if not isinstance(self.code, str):
            raise TypeError(f"a Problem's code must be a ProblemCode, got {self.code!r}")
        try:  # the string of a member (a problem read back from its dict or JSON) is that member
            code = ProblemCode(self.code)
        except ValueError:
            raise ValueError(f"unknown problem code {self.code!r}: a Problem's code must be a "
                             "ProblemCode (docs/session.md lists them)") from None
        object.__setattr__(self, "code", code)

    def __str__(self) -> str:
        return f"{self.where}: {self.message}"

    def touches(self, roles: Iterable[str] | None) -> bool:
        """True when the problem concerns frames of any of ``roles`` (``None``: any role)."""
        return roles is None or not self.roles or bool(set(self.roles) & set(roles))

    def to_dict(self) -> dict[str, Any]:
        return {"where": self.where, "message": self.message, "severity": self.severity,
                "code": self.code.value, "roles": list(self.roles)}


#: bytes read at a time by :meth:`Session.content_hash`
HASH_CHUNK = 1 << 20
#: session content hashes already computed, keyed by the (path, size, mtime_ns) of the manifest
#: and of every frame in order (a Session is frozen: the cache lives here, bounded)
_HASH_CACHE: OrderedDict[tuple, str] = OrderedDict()
_HASH_CACHE_SIZE = 64
_HASH_LOCK = threading.Lock()


def _stat_key(path: Path, where: str) -> tuple[str, int, int]:
    """(path, size, mtime_ns) of a file, or a :class:`CcdError` naming ``where``."""
    try:
        st = os.stat(path)
    except OSError as exc:
        raise CcdError(where, f"cannot read the file to hash it: {exc.strerror}") from None
    return str(path), int(st.st_size), int(st.st_mtime_ns)


#: the metadata key whose value groups the frames of a role (flat: level, else exposure)
_GROUP_FIELDS = {"ptc": "level", "fixed_pattern": "config", "flat": "level", "dark": "exposure",
                 "bracket": "stack", "reference": "stack", "target": "stack"}


def _group_field(rec: FrameRecord) -> str | None:
    """The metadata key that groups ``rec`` with the other frames of its role, or None."""
    field_ = _GROUP_FIELDS.get(rec.role)
    if rec.role == "flat" and rec.level is None:
        return "exposure"
    return field_


def _group_key(rec: FrameRecord) -> Any:
    """The key that groups frames of one role (see :meth:`Session.groups_table`)."""
    name = _group_field(rec)
    return None if name is None else getattr(rec, name)


# --------------------------------------------------------------------------------------------
# the session
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Session:
    """A capture session: camera, frames (metadata only), validation problems.

    Build it with :func:`ccdcore.session.open_session`.  Frames are listed in manifest order
    (``[[frames]]`` entries, then each ``[[groups]]`` entry's matches in sorted order); for a
    plain folder, in sorted path order.  Pixels are read on demand, one frame at a time.
    """

    root: Path
    manifest_path: Path | None
    source: str  # "manifest" | "folder" | "emva1288"
    camera: Camera
    frames: tuple[FrameRecord, ...]
    problems: tuple[Problem, ...] = ()
    headers: dict[Path, ImageHeader] = field(default_factory=dict, repr=False)

    # ---- validity ---------------------------------------------------------------------------
    @property
    def label(self) -> str:
        """How messages name the session: its manifest or descriptor, else its folder."""
        return str(self.manifest_path or self.root)

    @property
    def ok(self) -> bool:
        """True when no problem has severity ``"error"``."""
        return not self.errors

    @property
    def errors(self) -> tuple[Problem, ...]:
        return tuple(p for p in self.problems if p.severity == "error")

    @property
    def warnings(self) -> tuple[Problem, ...]:
        return tuple(p for p in self.problems if p.severity != "error")

    def errors_for(self, roles: Iterable[str] | None = None) -> tuple[Problem, ...]:
        """The errors that touch frames of ``roles`` (every error for ``None``)."""
        roles = None if roles is None else tuple(roles)
        return tuple(p for p in self.errors if p.touches(roles))

    def raise_if_invalid(self, roles: Iterable[str] | None = None) -> None:
        """Raise :class:`SessionError` listing every error that touches ``roles`` (all errors
        for ``None``); ``str`` of it is the first error plus a count of the others."""
        errors = self.errors_for(roles)
        if not errors:
            return
        first = errors[0]
        n = len(errors) - 1
        more = f" (and {n} more problem{'s' if n > 1 else ''})" if n else ""
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
        return group_by((r for r in self.by_role("ptc") if r.level is not None),
                        lambda r: r.level)

    def dark_frames(self) -> tuple[FrameRecord, ...]:
        return self.by_role("dark")

    def fixed_pattern_configs(self) -> dict[int, tuple[FrameRecord, ...]]:
        """Configuration id -> its frames (the n1 configurations x n2 frames of sec. V-B)."""
        return group_by((r for r in self.by_role("fixed_pattern") if r.config is not None),
                        lambda r: r.config)

    def flats(self) -> dict[Any, tuple[FrameRecord, ...]]:
        """Flat-field frames keyed by level when set, else by exposure (sorted keys)."""
        return group_by(self.by_role("flat"), _group_key)

    def bracket_stacks(self, role: str = "bracket") -> dict[Any, tuple[FrameRecord, ...]]:
        """Stack id (``None`` when unset) -> its frames sorted by exposure.

        ``role`` is ``"bracket"``, ``"reference"`` or ``"target"``.
        """
        if role not in ("bracket", "reference", "target"):
            raise CcdError("role", f"'{role}' frames do not form exposure brackets")
        stacks = group_by(self.by_role(role), lambda r: r.stack)
        return {k: tuple(sorted(v, key=lambda r: sort_key(r.exposure)))
                for k, v in stacks.items()}

    def scenes(self) -> tuple[FrameRecord, ...]:
        return self.by_role("scene")

    # ---- scene patches and flags ------------------------------------------------------------
    def flagged(self, flag: str, role: str | None = None) -> tuple[FrameRecord, ...]:
        """Frames carrying ``flag`` (one of :data:`FLAGS`), of ``role`` when given."""
        if flag not in FLAGS:
            raise CcdError("flag", f"unknown flag '{flag}'; choose one of {', '.join(FLAGS)}")
        return tuple(r for r in self.frames if flag in r.flags and (role is None or r.role == role))

    def max_intensity_frame(self) -> FrameRecord | None:
        """The first scene frame flagged ``max-intensity`` (sec. VII-A), or ``None``."""
        found = self.flagged(MAX_INTENSITY, "scene")
        return found[0] if found else None

    def scene_patches(self) -> dict[str, tuple[FrameRecord, ...]]:
        """Scene frames that measure one surface, by patch: the ``patch`` key, else the ROI
        (``"roi=x,y,w,h"``); in the order patches first appear.

        Frames with neither (general scene images) and max-intensity frames are left out.
        """
        groups: dict[str, list[FrameRecord]] = {}
        for rec in self.scenes():
            if MAX_INTENSITY in rec.flags:
                continue
            key = rec.patch if rec.patch is not None else (
                None if rec.roi is None else "roi=" + ",".join(map(str, rec.roi)))
            if key is not None:
                groups.setdefault(key, []).append(rec)
        return {k: tuple(v) for k, v in groups.items()}

    # ---- offset settings and gains ----------------------------------------------------------
    def settings(self) -> tuple[str, ...]:
        """The offset settings named by the frames (key ``setting``), in session order."""
        return tuple(dict.fromkeys(r.setting for r in self.frames if r.setting is not None))

    def resolve_setting(self, setting: str | None) -> tuple[str | None, list[str]]:
        """The setting to analyse and notes: ``None`` picks the first of several (noted).

        Raises
        ------
        CcdError
            ``setting`` is given but no frame has it.
        """
        have = self.settings()
        if setting is not None:
            if setting not in have:
                raise CcdError(self.label, f"no frames with setting = {setting!r}" + (
                    f"; the session has {', '.join(have)}" if have
                    else "; the session names no settings (leave the setting out)"))
            return setting, []
        if len(have) > 1:
            return have[0], [f"the session has offset settings {', '.join(have)}; used "
                              f"{have[0]} (choose another with setting=)"]
        return (have[0] if have else None), []

    def select(self, role: str, *, setting: str | None = None,
               gain: float | None = None) -> tuple[FrameRecord, ...]:
        """Frames of ``role`` with ``setting`` (any when ``None``) and ``gain`` (any when
        ``None``; frames without a gain match every gain)."""
        return tuple(r for r in self.by_role(role)
                     if (setting is None or r.setting == setting)
                     and (gain is None or r.gain is None or math.isclose(r.gain, gain)))

    def flat_groups(self, *, setting: str | None = None, gain: float | None = None
                    ) -> dict[tuple[Any, Any], tuple[FrameRecord, ...]]:
        """Flat frames of one setting (and gain) keyed by ``(level, exposure)``, sorted.

        Raises
        ------
        CcdError
            The selection mixes several gains and ``gain`` is not given.
        """
        recs = self.select("flat", setting=setting, gain=gain)
        gains = {r.gain for r in recs if r.gain is not None}
        if gain is None and len(gains) > 1:
            raise CcdError(self.label, f"flat frames at several gains {sorted(gains)}: pass gain=")
        return group_by(recs, lambda r: (r.level, r.exposure))

    def dark_groups(self, *, setting: str | None = None, gain: float | None = None
                    ) -> dict[Any, tuple[FrameRecord, ...]]:
        """Dark frames of one setting (and gain) keyed by exposure (``None`` when unknown)."""
        return group_by(self.select("dark", setting=setting, gain=gain), lambda r: r.exposure)

    # ---- content ----------------------------------------------------------------------------
    def content_hash(self) -> str:
        """The SHA-256 (hex) of what the session is made of, for a product's provenance.

        Hashed in order: the manifest or descriptor bytes (nothing for a plain folder), then for
        every frame in session order its path relative to the session root, its size in bytes
        and its bytes, read in 1 MiB chunks (each field length-prefixed, so no two sessions
        share a stream).  The same files give the same hash wherever the folder lies; one
        changed byte, a renamed, added, removed or reordered frame changes it.

        The hash is computed once per content: it is cached (for this and any other
        :class:`Session` of the same files) under the path, size and modification time
        (``st_mtime_ns``) of the manifest and of every frame, so a file rewritten in place with
        the same size and modification time would keep its old hash.

        Raises
        ------
        CcdError
            A file cannot be read.
        """
        files = ([] if self.manifest_path is None
                 else [(self.manifest_path, self.manifest_path.name, None)])
        files += [(rec.path, rec.relpath, rec.relpath) for rec in self.frames]
        key = tuple(_stat_key(path, where) for path, where, _ in files)
        with _HASH_LOCK:
            cached = _HASH_CACHE.get(key)
            if cached is not None:
                _HASH_CACHE.move_to_end(key)
                return cached
        digest = hashlib.sha256(b"ccdcore session content v1\0")

        def field_(data: bytes) -> None:
            digest.update(len(data).to_bytes(8, "little"))
            digest.update(data)

        for (path, where, relpath), (_, size, _) in zip(files, key):
            field_(b"manifest" if relpath is None else b"frame")
            if relpath is not None:
                field_(relpath.encode("utf-8"))
            digest.update(size.to_bytes(8, "little"))
            try:
                with open(path, "rb") as f:
                    read = 0
                    while chunk := f.read(HASH_CHUNK):
                        digest.update(chunk)
                        read += len(chunk)
            except OSError as exc:
                raise CcdError(where, f"cannot read the file to hash it: {exc.strerror}") from None
            if read != size:
                raise CcdError(where, f"changed while it was hashed ({size} bytes before, "
                                      f"{read} read)")
        out = digest.hexdigest()
        with _HASH_LOCK:
            _HASH_CACHE[key] = out
            while len(_HASH_CACHE) > _HASH_CACHE_SIZE:
                _HASH_CACHE.popitem(last=False)
        return out

    # ---- pixels -----------------------------------------------------------------------------
    def header(self, rec: FrameRecord) -> ImageHeader:
        """The file header of a frame (read once, then cached)."""
        hdr = self.headers.get(rec.path)
        if hdr is None:
            hdr = self.headers[rec.path] = read_header(rec.path)
        return hdr

    def header_or_none(self, rec: FrameRecord) -> ImageHeader | None:
        """:meth:`header`, or ``None`` when the file cannot be read (already a problem)."""
        try:
            return self.header(rec)
        except ImageReadError:
            return None

    def read(self, rec: FrameRecord) -> np.ndarray:
        """The pixels of one frame, in the stored dtype (``(H, W)`` or ``(H, W, C)``).

        Raises
        ------
        ImageReadError
            The file cannot be read.
        CcdError
            A value exceeds ``[camera] bits`` (see :meth:`check_codes`).
        """
        return self.check_codes(rec, read_image(rec.path))

    def check_codes(self, rec: FrameRecord, data: np.ndarray) -> np.ndarray:
        """``data`` once no value of it exceeds the camera's ``2**bits - 1``.

        Headers cannot tell: a 12-bit camera is stored in 16-bit files, so a camera declared
        8-bit whose frames hold values up to 65535 passes every header check and gives a dark
        mean of thousands of DN.  One maximum per frame read (a fraction of its decoding time)
        catches it.  Float data and containers no wider than ``bits`` are not checked.
        """
        bits = self.camera.bits
        if (bits is None or data.dtype.kind not in "ui" or data.dtype.itemsize * 8 <= bits
                or not data.size):
            return data
        top = int(data.max())
        if top >= 1 << bits:
            raise CcdError(rec.relpath, f"{data.dtype} sample type holds value {top}, beyond "
                                        f"camera.bits = {bits} (codes 0..{(1 << bits) - 1}): "
                                        "frames of another camera, or a wrong [camera] bits?")
        return data

    def iter_frames(self, records: Iterable[FrameRecord] | None = None, *,
                    read_ahead: int = 0) -> Iterator[tuple[FrameRecord, np.ndarray]]:
        """Yield ``(record, pixels)`` one frame at a time, in order.

        ``records`` defaults to every frame of the session.  With ``read_ahead = 0`` each file is
        read only when reached.  With ``read_ahead = n > 0`` the next n frames are decoded in
        worker threads while the caller works on the current one (image decoders release the
        GIL, so on several cores decoding and computing overlap); memory holds at most n + 1
        frames, and a frame that cannot be read raises when it is reached, as without read-ahead.

        Before each frame it calls :func:`ccdcore.progress.checkpoint` (frames done of the
        list's length): inside :func:`ccdcore.progress.tracking` that reports progress and
        stops a cancelled computation with :class:`ccdcore.progress.Cancelled`.
        """
        recs = self.frames if records is None else records
        total = len(recs) if isinstance(recs, Sized) else None
        if read_ahead <= 0:
            for i, rec in enumerate(recs):
                checkpoint(i, total)
                yield rec, self.read(rec)
            return
        todo = iter(recs)
        with ThreadPoolExecutor(max_workers=read_ahead) as pool:
            pending = deque((rec, pool.submit(self.read, rec))
                            for rec in itertools.islice(todo, read_ahead))
            try:
                i = 0
                while pending:
                    checkpoint(i, total)
                    rec, future = pending.popleft()
                    nxt = next(todo, None)
                    if nxt is not None:
                        pending.append((nxt, pool.submit(self.read, nxt)))
                    yield rec, future.result()
                    i += 1
            finally:  # the caller stopped early or a read failed: drop what was read ahead
                for _, future in pending:
                    future.cancel()

    def verify_pixels(self) -> Session:
        """Decode every frame once, one at a time, and return a copy of the session whose
        problems also list the frames whose pixel data cannot be read (truncated or corrupt)
        and those holding values beyond ``[camera] bits`` (code ``bit-depth``).

        Opening a session reads headers only, so a file cut short after its header is caught
        here (or when the frame is first read), not at open time.
        """
        extra = []
        for rec in self.frames:
            if rec.path not in self.headers:
                continue  # the header itself is unreadable: already reported
            try:
                self.read(rec)
            except ImageReadError as exc:
                extra.append(Problem(rec.relpath, exc.problem, code=ProblemCode.UNREADABLE,
                                     roles=(rec.role,)))
            except CcdError as exc:  # values beyond camera.bits (check_codes)
                extra.append(Problem(rec.relpath, exc.problem, code=ProblemCode.BIT_DEPTH,
                                     roles=(rec.role,)))
        return dataclasses.replace(self, problems=self.problems + tuple(extra))

    # ---- tables -----------------------------------------------------------------------------
    def groups_table(self) -> list[dict[str, Any]]:
        """One row per group of frames.

        Keys: ``role``; ``key`` (ptc level, fixed-pattern config, flat level or exposure, dark
        exposure, bracket stack; ``None`` for scenes) and ``key_name`` (which of those metadata
        keys it is); ``count``; ``shape`` (NumPy order
        ``(H, W)`` or ``(H, W, C)``) and ``dtype`` (``None`` when they differ within the group or
        no header is readable); ``mixed`` (which of ``"shape"``, ``"dtype"`` differ);
        ``unreadable`` (frames whose header cannot be read); the distinct ``exposures`` (sorted).
        Sizes are numbers: callers format them (:func:`ccdcore.common.format_size`).
        """
        rows = []
        for role in ROLES:
            for key, recs in group_by(self.by_role(role), _group_key).items():
                headers = [self.header_or_none(r) for r in recs]
                readable = [h for h in headers if h is not None]
                shapes = {h.shape for h in readable}
                dtypes = {str(h.dtype) for h in readable}
                rows.append({
                    "role": role, "key": key, "key_name": _group_field(recs[0]),
                    "count": len(recs),
                    "shape": shapes.pop() if len(shapes) == 1 else None,
                    "dtype": dtypes.pop() if len(dtypes) == 1 else None,
                    "mixed": [k for k, s in (("shape", shapes), ("dtype", dtypes)) if len(s) > 1],
                    "unreadable": len(headers) - len(readable),
                    "exposures": sorted({r.exposure for r in recs if r.exposure is not None}),
                })
        return rows

    def frames_table(self) -> list[dict[str, Any]]:
        """One row per frame: its metadata (:meth:`FrameRecord.to_dict`) plus ``shape``,
        ``dtype``, ``bits`` from the header (``None`` when unreadable)."""
        rows = []
        for rec in self.frames:
            hdr = self.header_or_none(rec)
            row = rec.to_dict()
            row.update(shape=hdr.shape if hdr else None, dtype=str(hdr.dtype) if hdr else None,
                       bits=hdr.bits if hdr else None)
            rows.append(row)
        return rows

    # ---- serialisation ----------------------------------------------------------------------
    def to_toml(self) -> str:
        """A manifest for this session: camera plus one ``[[frames]]`` entry per frame.

        Metadata inferred from headers, the folder layout or a legacy note is written
        explicitly, so the user can review and edit it; opening the manifest gives the same
        frames (paths, roles, metadata) in the same order.
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
