"""Reading the ``session.toml`` manifest (the contract is in ``docs/session.md``).

The manifest is a public contract other tools write: it is extended, never broken.  Frame
metadata that earlier releases kept in the free-text ``note`` (``"setting=NZDI"``,
``"patch=grey"``, ``"max-intensity"``) is now the keys ``setting``, ``patch`` and
``flags = ["max-intensity"]``; the old note form is still read for one release, with a warning
(code ``deprecated-note``) that says which key to write instead.
"""
from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any

from ..channels import LAYOUTS
from ..errors import CcdError
from ..io.frames import IMAGE_EXTENSIONS
from .assemble import Candidate, assemble
from .records import (FLAGS, MAX_EXPOSURE, MAX_INTENSITY, META_KEYS, MIN_EXPOSURE, ROLES, SCHEMA,
                      Camera, Problem, ProblemCode, Session)

__all__ = ["open_manifest", "parse_legacy_note", "bound_problem", "MAX_MANIFEST_BYTES", "MAX_KEY_PARTS",
           "MAX_NESTING"]

_CAMERA_KEYS = ("name", "bits", "layout", "black_level")
_FRAME_KEYS = frozenset(("path", "role") + META_KEYS)
_GROUP_KEYS = frozenset(("glob", "role") + META_KEYS)
_NAME = re.compile(r"[\w.+-]+")
_LEGACY = re.compile(r"(?:^|[\s;,])(setting|patch)\s*=\s*([^\s;,]+)")


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check_value(key: str, value: Any) -> tuple[Any, str | None]:
    """Validate one metadata value; return (converted value, problem or None)."""
    if key in ("level", "config"):
        return (value, None) if _is_int(value) else (None, f"'{key}' must be an integer, "
                                                           f"got {value!r}")
    if key == "exposure":
        # 0 is a dark frame's (bias) exposure; outside 1 ns .. 1e6 s (11.6 days) a value is a typo
        # or a unit slip, and 1e-320 or 1e300 overflow the response fits' arithmetic
        if _is_number(value) and (value == 0 or MIN_EXPOSURE <= value <= MAX_EXPOSURE):
            return float(value), None
        return None, (f"'exposure' must be 0 or from {MIN_EXPOSURE:g} to {MAX_EXPOSURE:g} "
                      f"seconds, got {value!r}")
    if key == "photons":
        if _is_number(value) and value >= 0:
            return float(value), None
        return None, f"'{key}' must be a finite number >= 0 (photons per pixel), got {value!r}"
    if key in ("gain", "temperature"):
        return (float(value), None) if _is_number(value) else (
            None, f"'{key}' must be a finite number, got {value!r}")
    if key == "roi":
        if (isinstance(value, list) and len(value) == 4 and all(_is_int(v) for v in value)
                and value[0] >= 0 and value[1] >= 0 and value[2] > 0 and value[3] > 0):
            return tuple(value), None
        return None, f"'roi' must be [x, y, w, h] (integers, w and h > 0), got {value!r}"
    if key == "stack":
        return (value, None) if _is_int(value) or isinstance(value, str) else (
            None, f"'stack' must be an integer or a string, got {value!r}")
    if key in ("setting", "patch"):
        return (value, None) if isinstance(value, str) and _NAME.fullmatch(value) else (
            None, f"'{key}' must be a name (letters, digits, . _ + -), got {value!r}")
    if key == "flags":
        if isinstance(value, list) and all(v in FLAGS for v in value):
            return tuple(dict.fromkeys(value)), None
        return None, f"'flags' must be a list of {', '.join(map(repr, FLAGS))}, got {value!r}"
    if key == "note":
        return (value, None) if isinstance(value, str) else (None, "'note' must be a string")
    raise AssertionError(key)


def parse_legacy_note(note: str) -> dict[str, Any]:
    """The metadata an earlier release's free-text note carried: ``setting`` and ``patch`` from
    ``"setting=NAME"`` / ``"patch=NAME"``, ``flags`` from a note that is ``"max-intensity"``."""
    out: dict[str, Any] = {key: value for key, value in _LEGACY.findall(note)}
    if note.strip() == MAX_INTENSITY:
        out["flags"] = (MAX_INTENSITY,)
    return out


def _parse_entry(entry: dict, where: str, allowed: frozenset[str],
                 problems: list[Problem]) -> tuple[str | None, dict[str, Any], tuple[str, ...]]:
    """Validate the role and metadata of a ``[[frames]]`` / ``[[groups]]`` entry; return the
    role (None if bad), the metadata and the keys taken from a legacy note."""
    role = entry.get("role")
    if role is None:
        problems.append(Problem(where, f"no 'role'; choose one of {', '.join(ROLES)}",
                                code=ProblemCode.MISSING_ROLE))
    elif role not in ROLES:
        problems.append(Problem(where, f"unknown role {role!r}; choose one of "
                                       f"{', '.join(ROLES)}", code=ProblemCode.UNKNOWN_ROLE))
        role = None
    roles = (role,) if role else ()
    for key in entry:
        if key not in allowed:
            problems.append(Problem(where, f"unknown key '{key}' (ignored)", "warning",
                                    code=ProblemCode.UNKNOWN_KEY, roles=roles))
    meta: dict[str, Any] = {}
    for key in META_KEYS:
        if key in entry:
            value, why = _check_value(key, entry[key])
            if why:
                problems.append(Problem(where, why, code=ProblemCode.BAD_VALUE, roles=roles))
            else:
                meta[key] = value
    legacy = {k: v for k, v in parse_legacy_note(meta.get("note", "")).items() if k not in meta}
    if legacy:
        keys = ", ".join(f"{k} = {list(v) if k == 'flags' else repr(v)}"
                         for k, v in legacy.items())
        problems.append(Problem(where, f"metadata in 'note' is deprecated and will not be read "
                                       f"in the next release; write {keys}", "warning",
                                code=ProblemCode.DEPRECATED_NOTE, roles=roles))
        meta.update(legacy)
    return role, meta, tuple(legacy)


def _entry_label(kind: str, i: int, entry: dict, key: str) -> str:
    value = entry.get(key)
    if not isinstance(value, str):
        return f"{kind}[{i}]"
    shown = value.replace("\0", "\\0")  # a NUL character shown as \0, not printed
    return f"{kind}[{i}] ({shown})"


def _parse_camera(doc: dict, problems: list[Problem]) -> Camera:
    cam = doc.get("camera")
    if cam is None:
        problems.append(Problem("camera", "no [camera] table; assuming a mono camera of unknown "
                                          "bit depth", "warning", code=ProblemCode.NO_CAMERA))
        return Camera()
    if not isinstance(cam, dict):
        problems.append(Problem("camera", "must be a table: [camera]", code=ProblemCode.BAD_VALUE))
        return Camera()
    for key in cam:
        if key not in _CAMERA_KEYS:
            problems.append(Problem(f"camera.{key}", "unknown key (ignored)", "warning",
                                    code=ProblemCode.UNKNOWN_KEY))
    name, bits, layout = cam.get("name", ""), cam.get("bits"), cam.get("layout", "mono")
    if not isinstance(name, str):
        problems.append(Problem("camera.name", "must be a string", code=ProblemCode.BAD_VALUE))
        name = ""
    if bits is not None and not (_is_int(bits) and 1 <= bits <= 32):
        problems.append(Problem("camera.bits", f"must be an integer from 1 to 32, got {bits!r}",
                                code=ProblemCode.BAD_VALUE))
        bits = None
    if layout not in LAYOUTS:
        problems.append(Problem("camera.layout", f"unknown layout {layout!r}; choose one of "
                                                 f"{', '.join(LAYOUTS)}",
                                code=ProblemCode.BAD_VALUE))
        layout = "mono"
    black_level = cam.get("black_level")
    if black_level is not None:
        if _is_number(black_level) and black_level >= 0:
            black_level = float(black_level)
        else:
            problems.append(Problem("camera.black_level", f"must be a number >= 0 (DN), got "
                                                          f"{black_level!r}",
                                    code=ProblemCode.BAD_VALUE))
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


#: the largest manifest read (a session of 100 000 frames is about 10 MB of TOML)
MAX_MANIFEST_BYTES = 64 * 2 ** 20
#: the most parts of one dotted key or table name (``a.b.c``): a manifest's deepest is three;
#: Python's TOML reader takes time and memory quadratic in them (100 000 parts: 24 GB)
MAX_KEY_PARTS = 16
#: the deepest nesting of arrays and inline tables (a manifest's deepest is two)
MAX_NESTING = 32


#: the tokens of a manifest's structure: strings and comments (skipped whole) and the
#: characters that make keys, nesting and lines
_TOKENS = re.compile(r'"""[\s\S]*?"""|\'\'\'[\s\S]*?\'\'\'|"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*'
                     r"|[\[\]{}=.,\n]")


def bound_problem(text: str) -> str | None:
    """Why a manifest's text is beyond what any manifest holds (checked before parsing, in one
    linear scan: a dotted key or table name of many parts, arrays or tables nested deep), or
    None. Strings and comments are skipped, so a path or a note with dots or brackets never
    counts."""
    depth = parts = 0
    in_key = True                  # at a line's start, after "{" or ",": a key may follow
    for m in _TOKENS.finditer(text):
        c = m.group()
        if len(c) != 1:
            continue                           # a string or a comment
        if c == ".":
            if in_key:
                parts += 1
                if parts >= MAX_KEY_PARTS:
                    return f"a key or table name of more than {MAX_KEY_PARTS} dotted parts"
        elif c == "=":
            in_key, parts = False, 0
        elif c in "\n,{":
            in_key, parts = (c != "\n" or depth == 0) or in_key, 0
            if c == "{":
                depth += 1
        elif c == "[":
            depth += 1
        else:                                  # "]" or "}"
            depth = max(0, depth - 1)
        if depth > MAX_NESTING:
            return f"arrays or tables nested too deeply (more than {MAX_NESTING} levels)"
    return None


def _read_toml(manifest_path: Path) -> dict:
    """The manifest as a dict, or one :class:`CcdError` line naming it.

    A FIFO or device is refused before it is opened (reading one would block or never end); a
    manifest nested deeper than Python's recursion limit (``a = [[[[…]]]]``, only a corrupt or
    hostile file) is refused instead of letting ``tomllib``'s RecursionError out as a traceback.
    """
    if manifest_path.is_dir():
        raise CcdError(manifest_path, "is a folder, not a manifest file")
    if manifest_path.exists() and not manifest_path.is_file():
        raise CcdError(manifest_path, "is a FIFO/special file, not a manifest file")
    try:
        size = manifest_path.stat().st_size
        if size > MAX_MANIFEST_BYTES:
            raise CcdError(manifest_path, f"{size / 2 ** 20:.0f} MB, larger than any manifest "
                                          f"(at most {MAX_MANIFEST_BYTES // 2 ** 20} MB): not a "
                                          "session.toml?")
        text = manifest_path.read_bytes().decode("utf-8-sig")  # a byte-order mark is fine
    except UnicodeDecodeError as exc:
        raise CcdError(manifest_path, f"not UTF-8 text (byte {exc.start}): save the manifest "
                                      "as UTF-8") from None
    except OSError as exc:
        raise CcdError(manifest_path, f"cannot read the manifest: {exc.strerror or exc}") from None
    bound = bound_problem(text)
    if bound:
        raise CcdError(manifest_path, f"{bound}, beyond what any manifest holds (a corrupt or "
                                      "hostile file?)")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CcdError(manifest_path, f"TOML syntax error: {exc}") from None
    except RecursionError:
        raise CcdError(manifest_path, "tables or arrays nested too deeply to read (a corrupt "
                                      "manifest?)") from None


def open_manifest(manifest_path: Path) -> Session:
    """Open the session a ``session.toml`` describes (problems listed, not raised).

    Raises
    ------
    CcdError
        The manifest cannot be read or is not valid TOML (the message gives the line).
    """
    root = manifest_path.parent.resolve()
    doc = _read_toml(manifest_path)
    problems: list[Problem] = []
    schema = doc.get("schema")
    if schema is None:
        problems.append(Problem("schema", f"missing; assuming schema = {SCHEMA}", "warning",
                                code=ProblemCode.NO_SCHEMA))
    elif schema != SCHEMA or not _is_int(schema):
        problems.append(Problem("schema", f"unsupported schema {schema!r}; this version reads "
                                          f"schema = {SCHEMA}", code=ProblemCode.SCHEMA))
    for key in doc:
        if key not in ("schema", "camera", "frames", "groups"):
            problems.append(Problem(key, "unknown top-level key (ignored)", "warning",
                                    code=ProblemCode.UNKNOWN_KEY))
    camera = _parse_camera(doc, problems)

    candidates: list[Candidate] = []
    for kind, allowed, path_key in (("frames", _FRAME_KEYS, "path"),
                                    ("groups", _GROUP_KEYS, "glob")):
        entries = doc.get(kind, [])
        if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
            problems.append(Problem(kind, f"must be an array of tables: [[{kind}]]",
                                    code=ProblemCode.BAD_VALUE))
            continue
        for i, entry in enumerate(entries):
            where = _entry_label(kind, i, entry, path_key)
            role, meta, legacy = _parse_entry(entry, where, allowed, problems)
            roles = (role,) if role else ()
            target = entry.get(path_key)
            if not isinstance(target, str) or not target:
                problems.append(Problem(where, f"no '{path_key}' (a path relative to the "
                                               "session folder)", code=ProblemCode.MISSING_PATH,
                                        roles=roles))
                continue
            if kind == "frames":
                relpaths = [target]
            else:
                why = _glob_problem(target)
                if why is not None:
                    problems.append(Problem(where, why, code=ProblemCode.PATH_OUTSIDE, roles=roles))
                    continue
                relpaths, others = _glob(root, target)
                if not relpaths:
                    problems.append(Problem(where, "glob matches no image file" + (
                        f" ({others} non-image file{'s' if others > 1 else ''})" if others
                        else ""), code=ProblemCode.EMPTY_GLOB, roles=roles))
            if role is not None:
                candidates.extend(Candidate(where, rel, role, meta, legacy) for rel in relpaths)
    if not candidates and not any(p.severity == "error" for p in problems):
        problems.append(Problem(manifest_path.name, "the manifest lists no frames",
                                code=ProblemCode.NO_FRAMES))
    return assemble(root, manifest_path, "manifest", camera, candidates, problems)
