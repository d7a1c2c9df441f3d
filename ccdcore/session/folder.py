"""Plain folders of images without a manifest: roles from folder names, metadata from headers.

``dark/``, ``darks/``, ``bias/`` ... hold dark frames (or files named ``dark_001.tif``, see
:data:`FILE_ROLE_WORDS`), ``ptc/`` photon-transfer pairs (a level per
sub-folder ``ptc/L03/`` or per file name number ``ptc/L03_a.tif``), ``flats/`` flat fields and so on
(:data:`ROLE_SYNONYMS`).  Exposures, gains and temperatures come from EXIF/FITS headers.

Exposure brackets: the images of a ``bracket/`` (``hdr/``, ``exposures/`` ...) folder are one, and
so are the images of the top-level folder, or of a sub-folder not named for a role, when they
look like one: one camera, one size and bit depth, at least two exposure times (EXIF
``ExposureTime``) and no other setting changed (ISO, aperture).  A camera folder of bracketed
JPEG, PNG, TIFF or raw frames thus opens without a manifest (:func:`open_folder` documents the
rules; ``docs/session.md`` too).  Other images at the top level are scenes.

The session carries a warning saying what was inferred, and
:meth:`~ccdcore.session.Session.to_toml` writes it out as a manifest draft to review.
"""
from __future__ import annotations

import dataclasses
import posixpath
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

from ..channels import LAYOUTS
from ..errors import CcdError, ImageReadError
from ..io.frames import IMAGE_EXTENSIONS, RAW_EXTENSIONS, ImageHeader, read_header
from .assemble import Candidate, assemble, path_problem
from .records import MANIFEST_NAME, ROLES, Camera, Problem, ProblemCode, Session

__all__ = ["ROLE_SYNONYMS", "FILE_ROLE_WORDS", "file_name_role", "open_folder", "after_draft",
           "WRITE_DRAFT", "WRITE_MANIFEST"]

#: the advice of a plain folder's warnings, and what it becomes once the draft is written
#: (:func:`after_draft`)
WRITE_DRAFT = "write a manifest draft with `ccdcore session FOLDER --draft` and save it as " \
              f"{MANIFEST_NAME}"
WRITE_MANIFEST = "write a manifest (ccdcore session FOLDER --draft)"
_AFTER_DRAFT = {WRITE_DRAFT: f"check the manifest draft written below and save it as "
                             f"{MANIFEST_NAME}",
                WRITE_MANIFEST: "edit the manifest draft written below,"}


def after_draft(text: str) -> str:
    """A plain folder's warning once ``ccdcore session FOLDER --draft`` has written the draft:
    its advice points at the draft instead of the command just run."""
    for advice, done in _AFTER_DRAFT.items():
        text = text.replace(advice, done)
    return text


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

#: the id key a plain folder's frames of a role get from their sub-folder or file name
_ID_KEYS = {"ptc": "level", "fixed_pattern": "config"}

#: the first word of a file name (lower case) -> role, for images not in a folder named for a
#: role: ``dark_0.01s_001.tif``, ``bias-3.tif``, ``ptc_L03_a.tif``, ``flat_1.tif``. Only the
#: calibration roles, and only words that name them plainly (``white`` or ``black``, which name
#: subjects too, are not read from file names)
FILE_ROLE_WORDS: dict[str, str] = {
    "dark": "dark", "darks": "dark", "bias": "dark", "biases": "dark",
    "ptc": "ptc", "flat": "flat", "flats": "flat", "flatfield": "flat",
    "fpn": "fixed_pattern", "prnu": "fixed_pattern",
}


def file_name_role(name: str) -> str | None:
    """The role a file name states by its first word (:data:`FILE_ROLE_WORDS`): the letters
    before the first digit, ``_``, ``-``, ``.`` or space, or None."""
    word = re.match(r"[A-Za-z]+", name)
    if word is None or word.end() == len(name) or name[word.end()] not in "0123456789_-. ":
        return None
    return FILE_ROLE_WORDS.get(word.group().lower())


def _in_role_subfolder(rel: str) -> bool:
    """``ptc/L03/a.tif``: in a sub-folder of a folder named for a role (which numbers it)."""
    parts = rel.split("/")
    return len(parts) > 2 and ROLE_SYNONYMS.get(parts[0].lower()) is not None


def _ptc_levels(rels: list[str], headers: "_Headers") -> tuple[dict[str, int | None], str]:
    """Levels of photon-transfer frames that no sub-folder numbers: ``(relpath -> level, how)``.

    From the first number of each file name (``L03_a.tif``) when that makes pairs (two levels
    or more, every level two frames or more); else, when every frame's header gives an exposure time, all at one gain,
    and every exposure time is shared by two frames or more, the exposure times in increasing
    order (level 1 the shortest; ``how`` is ``"exposure"``); else the file-name numbers (the
    session then reports levels of one frame)."""
    by_name: dict[str, int | None] = {}
    for rel in rels:
        number = re.search(r"\d+", PurePosixPath(rel).stem)
        by_name[rel] = int(number.group()) if number else None

    def pairs(levels: dict[str, int | None]) -> bool:
        counts = Counter(levels.values())
        return None not in counts and len(counts) >= 2 and min(counts.values()) >= 2

    if pairs(by_name):
        return by_name, "name"
    hdrs = [headers.get(rel) for rel in rels]
    if all(h is not None and h.exposure is not None for h in hdrs) \
            and len({h.gain for h in hdrs}) == 1:            # type: ignore[union-attr]
        keys = [_exposure_key(h.exposure) for h in hdrs]     # type: ignore[union-attr]
        rank = {k: i for i, k in enumerate(sorted(set(keys)), start=1)}
        by_exposure: dict[str, int | None] = {rel: rank[k] for rel, k in zip(rels, keys)}
        if pairs(by_exposure):
            return by_exposure, "exposure"
    return by_name, "name"


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


# --------------------------------------------------------------------------------------------
# exposure brackets
# --------------------------------------------------------------------------------------------
#: the note a bracket frame without an exposure time gets (written into the manifest draft)
MISSING_EXPOSURE_NOTE = ("no exposure time in the file header (EXIF ExposureTime): fill in "
                         "'exposure' in seconds")
#: file names listed in one message at most
_MAX_NAMES = 6


class _Headers:
    """The headers of a folder's images, each read once (an unreadable one is remembered)."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self._cache: dict[Path, ImageHeader | ImageReadError] = {}

    def read(self, path: Path) -> ImageHeader:
        """:func:`~ccdcore.io.frames.read_header` through the cache (for :func:`assemble`)."""
        got = self._cache.get(path)
        if got is None:
            try:
                got = read_header(path)
            except ImageReadError as exc:
                got = exc
            self._cache[path] = got
        if isinstance(got, ImageReadError):
            raise got
        return got

    def get(self, rel: str) -> ImageHeader | None:
        """The header of ``rel`` (relative path), or None when unreadable or outside the folder
        (:func:`assemble` reports those)."""
        if path_problem(self.root, rel) is not None:
            return None
        try:
            return self.read((self.root / posixpath.normpath(rel)).resolve())
        except ImageReadError:
            return None


def _exposure_key(seconds: float) -> float:
    """Exposure times equal to 6 significant digits are one exposure (EXIF rationals read back
    through float32)."""
    return float(f"{seconds:.6g}")


def format_exposure(seconds: float) -> str:
    """``1/250 s`` for a fraction of a second that is one over a whole number, else ``0.3 s``."""
    if 0 < seconds < 1:
        inverse = 1 / seconds
        if abs(inverse - round(inverse)) <= 1e-4 * inverse:
            return f"1/{round(inverse)} s"
    return f"{seconds:g} s"


def _names(rels: list[str]) -> str:
    """``a.jpg, b.jpg and 3 more``."""
    shown = ", ".join(rels[:_MAX_NAMES])
    more = len(rels) - _MAX_NAMES
    return shown + (f" and {more} more" if more > 0 else "")


def _text(value: Any) -> str | None:
    text = str(value).strip().strip("\x00").strip() if value is not None else ""
    return text or None


def _number(value: Any, digits: int) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        return None
    return float(f"{v:.{digits}g}") if v == v and abs(v) != float("inf") and v > 0 else None


def camera_of(hdr: ImageHeader) -> str | None:
    """``Make Model`` from a header's EXIF (``Model`` alone when it starts with ``Make``)."""
    make, model = _text(hdr.attributes.get("Make")), _text(hdr.attributes.get("Model"))
    if make and model and model.lower().startswith(make.lower()):
        return model
    return " ".join(t for t in (make, model) if t) or None


def capture_settings(hdr: ImageHeader) -> dict[str, str]:
    """The settings an exposure bracket keeps fixed, as text, when the header gives them:
    ``camera`` (EXIF Make/Model), ``ISO`` (``Exif:ISOSpeedRatings``, or its EXIF 2.3 name
    ``Exif:PhotographicSensitivity``), ``aperture`` (``FNumber``) and ``gain`` (FITS ``GAIN``,
    EXIF ``Gain``)."""
    attrs = hdr.attributes
    out: dict[str, str] = {}
    camera = camera_of(hdr)
    if camera:
        out["camera"] = camera
    iso = next((v for v in (_number(attrs.get(k), 6) for k in (
        "Exif:ISOSpeedRatings", "Exif:PhotographicSensitivity", "ISOSpeedRatings"))
        if v is not None), None)
    if iso is not None:
        out["ISO"] = f"{iso:g}"
    fnumber = _number(attrs.get("FNumber", attrs.get("Exif:FNumber")), 3)
    if fnumber is not None:
        out["aperture"] = f"f/{fnumber:g}"
    if hdr.gain is not None:
        out["gain"] = f"{hdr.gain:g}"
    return out


def _setting_differences(rels: list[str], hdrs: dict[str, ImageHeader | None]) -> list[str]:
    """``ISO differs (100: a.jpg, b.jpg; 200: c.jpg)`` for each setting with several values
    among the frames that give it."""
    out = []
    settings = {rel: capture_settings(h) for rel, h in hdrs.items() if h is not None}
    for name in ("camera", "ISO", "aperture", "gain"):
        by_value: dict[str, list[str]] = {}
        for rel in rels:
            value = settings.get(rel, {}).get(name)
            if value is not None:
                by_value.setdefault(value, []).append(rel)
        if len(by_value) > 1:
            out.append(f"{name} differs (" + "; ".join(
                f"{value}: {_names(files)}" for value, files in by_value.items()) + ")")
    return out


def _signature(hdr: ImageHeader) -> tuple:
    return hdr.shape, str(hdr.dtype), hdr.bits


def _looks_like_bracket(rels: list[str], hdrs: dict[str, ImageHeader | None]
                        ) -> tuple[bool, str | None]:
    """Whether a folder's images not named for a role form an exposure bracket, and when they
    might be one but are not taken as one, why not."""
    readable = [r for r in rels if hdrs[r] is not None]
    exposures = {_exposure_key(hdrs[r].exposure) for r in readable
                 if hdrs[r].exposure is not None}
    if (len(readable) > 1 and not exposures
            and len({_signature(hdrs[r]) for r in readable}) == 1):
        return False, ("none of them carries an exposure time (EXIF ExposureTime; PNG files "
                       "seldom have EXIF)")
    if len(readable) < 2 or len(exposures) < 2:
        return False, None  # nothing like a bracket: scenes
    signatures = Counter(_signature(hdrs[r]) for r in readable)
    common, n_common = signatures.most_common(1)[0]
    if 2 * n_common <= len(readable):
        sizes = "; ".join(f"{'x'.join(map(str, sig[0][1::-1]))} {sig[1]} {sig[2]}-bit: "
                          f"{_names([r for r in readable if _signature(hdrs[r]) == sig])}"
                          for sig in signatures)
        return False, f"the images differ in size or bit depth ({sizes})"
    main = [r for r in readable if _signature(hdrs[r]) == common]
    if len({_exposure_key(hdrs[r].exposure) for r in main if hdrs[r].exposure is not None}) < 2:
        return False, None
    diffs = _setting_differences(readable, hdrs)
    if diffs:
        return False, "; ".join(diffs)
    return True, None


def _sequences(rels: list[str], hdrs: dict[str, ImageHeader | None]) -> list[list[str]]:
    """The brackets of one folder: several when, in file-name order, the same set of exposure
    times repeats (``a b c a b c``), each time with every exposure once; else one."""
    keys = [None if hdrs[r] is None or hdrs[r].exposure is None
            else _exposure_key(hdrs[r].exposure) for r in rels]
    distinct = set(keys)
    m, n = len(distinct), len(keys)
    if None in distinct or m < 2 or n % m or n // m < 2:
        return [rels]
    chunks = [list(range(i, i + m)) for i in range(0, n, m)]
    if all({keys[i] for i in chunk} == distinct for chunk in chunks):
        return [[rels[i] for i in chunk] for chunk in chunks]
    return [rels]


def _duplicate_problems(rels: list[str], hdrs: dict[str, ImageHeader | None]) -> list[Problem]:
    """One error per exposure time that several frames of one bracket share."""
    by_key: dict[float, list[str]] = {}
    for rel in rels:
        hdr = hdrs[rel]
        if hdr is not None and hdr.exposure is not None:
            by_key.setdefault(_exposure_key(hdr.exposure), []).append(rel)
    return [Problem(files[0], f"{len(files)} frames of one bracket have the same exposure time "
                              f"{format_exposure(key)} (EXIF ExposureTime): {_names(files)}; a "
                              "bracket has one frame per exposure time: remove the extra "
                              "frames, or put each bracket in its own sub-folder (bracket/1/, "
                              "bracket/2/ ...) or give them different 'stack' values in the "
                              "manifest", code=ProblemCode.DUPLICATE_EXPOSURE, roles=("bracket",))
            for key, files in by_key.items() if len(files) > 1]


def _folder_label(unit: str) -> str:
    return "the top-level folder" if unit == "" else f"{unit}/"


@dataclass
class _Brackets:
    """What :func:`_find_brackets` decided: relpath -> stack for the bracket frames, the
    problems found and one summary line per bracket folder."""

    stacks: dict[str, int] = field(default_factory=dict)
    problems: list[Problem] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    from_exif: bool = False  # some folder not named bracket was taken as a bracket


def _find_brackets(relpaths: list[str], named: dict[str, str | None], headers: _Headers
                   ) -> _Brackets:
    """The exposure brackets of a plain folder (see :func:`open_folder`)."""
    units: dict[tuple[str, bool], list[str]] = {}
    for rel in relpaths:
        if named[rel] in (None, "bracket"):
            raw = PurePosixPath(rel).suffix.lower() in RAW_EXTENSIONS
            units.setdefault((posixpath.dirname(rel), raw), []).append(rel)
    out = _Brackets()
    stack = 0
    for (unit, raw), rels in sorted(units.items()):
        hdrs = {rel: headers.get(rel) for rel in rels}
        label = _folder_label(unit) + (" (camera raw files)" if raw and any(
            u == unit and not r for u, r in units) else "")
        forced = named[rels[0]] == "bracket"
        if not forced:
            take, why = _looks_like_bracket(rels, hdrs)
            if why is not None:
                out.problems.append(Problem(
                    unit + "/" if unit else ".",
                    f"the {len(rels)} images in {label} are read as scenes, not as an "
                    f"exposure bracket: {why}. If they are a bracket, {WRITE_MANIFEST} giving "
                    "each frame role = \"bracket\" and its exposure (in a bracket only the "
                    "exposure time changes)",
                    severity="warning",
                    code=ProblemCode.NOT_A_BRACKET, roles=("bracket", "scene")))
            if not take:
                continue
            out.from_exif = True
        else:
            for diff in _setting_differences(rels, hdrs):
                out.problems.append(Problem(
                    unit + "/", f"the bracket's {diff}: in an exposure bracket only the exposure "
                                "time may change; remove the other frames, or give each frame "
                                "its effective exposure in a manifest",
                    code=ProblemCode.BRACKET_SETTINGS, roles=("bracket",)))
        sequences = _sequences(rels, hdrs)
        if len(sequences) == 1:
            out.problems.extend(_duplicate_problems(rels, hdrs))
        first = stack + 1
        for seq in sequences:
            stack += 1
            out.stacks.update((rel, stack) for rel in seq)
        times = sorted({h.exposure for h in hdrs.values()
                        if h is not None and h.exposure is not None})
        span = (f"{format_exposure(times[0])} to {format_exposure(times[-1])}" if len(times) > 1
                else format_exposure(times[0]) if times else "no exposure times")
        how = ("named for brackets" if forced else
               f"one size, camera and settings; {len(times)} exposure times from file headers")
        ids = (f"stack {first}" if len(sequences) == 1 else
               f"stacks {first}-{stack} ({len(sequences)} repeated sequences of "
               f"{len(sequences[0])})")
        out.notes.append(f"{ids} = {len(rels)} frames in {label}, {span} ({how})")
    return out


def _declared(role: str | None) -> str | None:
    """The role given on the command line (``--role``), checked."""
    if role is not None and role not in ROLES:
        raise CcdError("--role", f"unknown role {role!r}; choose one of {', '.join(ROLES)}")
    return role


def open_folder(folder: Path, role: str | None = None) -> Session:
    """Open a plain folder of images as a session (no manifest).

    ``role`` (one of ROLES, e.g. ``"flat"``; ``--role flat``) gives every image that role,
    whatever its names say; the rest of this docstring is what happens without it.

    Roles come from the first folder name under the root (:data:`ROLE_SYNONYMS`), else from the
    first word of the file name for the calibration roles (:data:`FILE_ROLE_WORDS`:
    ``dark_001.tif``, ``ptc_0.01s_a.tif``); other images at the top level and in folders not
    named for a role are scenes, unless they form an exposure bracket. Photon-transfer levels
    come from the sub-folder, else the file names' numbers, else (pairs of) exposure times
    (:func:`_ptc_levels`).  Exposure brackets, one per folder (the folder holding the images):

    * the images of a folder named for brackets (``bracket/``, ``hdr/``, ``exposures/`` ...);
    * the images of the top-level folder or of a folder not named for a role, when they come
      from one camera (EXIF Make/Model, when given), most of them share one size and bit depth
      and those have at least two exposure times (EXIF ``ExposureTime``, FITS ``EXPTIME``), and
      ISO, aperture and gain (when given) are the same on every frame.  When they might be a
      bracket but are not taken as one (settings differ, sizes differ, no exposure times), a
      warning (``not-a-bracket``) says why and they stay scenes; a frame of another size or
      bit depth in a bracket is a ``mismatch`` error naming it;
    * camera raw files and other images of one folder are looked at separately (a camera's
      RAW+JPEG pairs give two brackets).

    Each bracket gets its own ``stack`` (1, 2, ... in folder order).  A folder whose exposure
    times, in file-name order, repeat one set (``a b c a b c``, each exposure once a time)
    holds several brackets, one stack each; otherwise frames of one bracket sharing an exposure
    time are an error (``duplicate-exposure``) naming them.  In a folder named for brackets,
    frames from another camera or at another ISO, aperture or gain are an error
    (``bracket-settings``).  A bracket frame without an exposure time gets the
    ``missing-exposure`` error and a note in the draft saying to fill in ``exposure``.

    The camera is named from EXIF Make/Model when every frame giving them agrees (else the
    folder's name); its bit depth is the deepest integer frame's and its layout the frames'
    (``rgb`` for colour JPEG/PNG/TIFF, a Bayer pattern for raw files).
    """
    root, declared = folder.resolve(), _declared(role)
    problems: list[Problem] = []
    candidates: list[Candidate] = []
    relpaths = _folder_images(root)
    headers = _Headers(root)
    # role from the first path component (None: not named for a role, a scene unless a bracket);
    # ptc level / fixed_pattern config from the sub-folder (ptc/L03/a.tif) or else from the
    # first number of the file name (ptc/L03_a.tif)
    named: dict[str, str | None] = {}
    by_file_name = 0
    for rel in relpaths:
        parts = rel.split("/")
        named[rel] = declared or (ROLE_SYNONYMS.get(parts[0].lower()) if parts[1:] else None)
        if named[rel] is None:      # not in a folder named for a role: the file name may say
            named[rel] = file_name_role(parts[-1])
            by_file_name += named[rel] is not None
    brackets = _find_brackets(relpaths, named, headers)
    sub: dict[str, list[str]] = {}
    roles: dict[str, str] = {}
    for rel in relpaths:
        parts = rel.split("/")
        roles[rel] = "bracket" if rel in brackets.stacks else named[rel] or "scene"
        if roles[rel] in _ID_KEYS and _in_role_subfolder(rel):
            sub.setdefault(roles[rel], []).append(parts[1])
    ids = {role: _subfolder_ids(sorted(set(names))) for role, names in sub.items()}
    # ptc frames no sub-folder numbers: levels from file names, or pairs of exposure times
    loose = [rel for rel in relpaths if roles[rel] == "ptc" and not _in_role_subfolder(rel)]
    ptc_levels, ptc_how = _ptc_levels(loose, headers) if loose else ({}, "name")
    for rel in relpaths:
        role, parts = roles[rel], rel.split("/")
        meta: dict[str, Any] = {}
        inferred = ["role"]
        if role in _ID_KEYS:
            number = re.search(r"\d+", PurePosixPath(rel).stem)
            value = ids[role][parts[1]] if _in_role_subfolder(rel) else (
                ptc_levels[rel] if rel in ptc_levels else int(number.group()) if number else None)
            if value is not None:
                meta[_ID_KEYS[role]] = value
                inferred.append(_ID_KEYS[role])
        if role == "bracket":
            meta["stack"] = brackets.stacks[rel]
            inferred.append("stack")
            hdr = headers.get(rel)
            if hdr is not None and hdr.exposure is None:
                meta["note"] = MISSING_EXPOSURE_NOTE
        candidates.append(Candidate(rel, rel, role, meta, tuple(inferred)))

    session = assemble(root, None, "folder", Camera(name=root.name), candidates, problems,
                       read=headers.read)
    readable = [h for h in (session.header_or_none(r) for r in session.frames) if h is not None]
    bits = max((h.bits for h in readable if h.dtype.kind in "ui"), default=None)
    layouts = {h.layout for h in readable}
    layout = layouts.pop() if len(layouts) == 1 else "mono"
    if layout not in LAYOUTS:
        layout = "rgb" if layout == "rgba" else "mono"
    cameras = {c for c in (camera_of(h) for h in readable) if c}
    name = cameras.pop() if len(cameras) == 1 else root.name
    camera = Camera(name=name, bits=bits, layout=layout)

    n_exp = sum("exposure" in r.inferred for r in session.frames)
    summary = ", ".join(f"{role}: {n}" for role, n in session.roles().items())
    if relpaths:
        how = "folder names and EXIF exposure times" if brackets.from_exif else "folder names"
        if declared is not None:
            how = f"the role given (every image is a {declared} frame, as declared by --role)"
        elif by_file_name:
            how += f", and the file names of {by_file_name} frame{'s' if by_file_name != 1 else ''}"
        found = (f"; exposure brackets: {'; '.join(brackets.notes)}" if brackets.notes else "")
        if ptc_how == "exposure":
            n_levels = len(set(ptc_levels.values()))
            found += (f"; ptc levels 1-{n_levels} from the frames' exposure times (frames of "
                      f"one exposure time and gain form one level's pairs)")
        note = (f"no {MANIFEST_NAME}: roles inferred from {how} ({summary}){found}; exposures "
                f"from file headers for {n_exp} of {len(relpaths)} frames, camera "
                f"'{name}', bits = {bits}, layout = {layout}; check them, {WRITE_DRAFT}")
        extra = [Problem(str(root), note, "warning", code=ProblemCode.FOLDER_INFERRED)]
    else:
        extra = [Problem(str(root), f"no image files found (looked for "
                                    f"{', '.join(sorted(IMAGE_EXTENSIONS))})",
                         code=ProblemCode.NO_FRAMES)]
    return dataclasses.replace(session, camera=camera,
                               problems=tuple(extra) + tuple(brackets.problems)
                               + session.problems)
