"""Building a session: frame candidates from any source -> checked records and problems.

Every source (a manifest, a plain folder, an EMVA1288 descriptor) turns what it declares into
:class:`Candidate` frames and calls :func:`assemble`, which checks paths stay inside the session
folder, reads each header once, fills metadata the source leaves out from the header, and runs
the checks across frames (shapes, dtypes and bit depths within a role, ptc level sizes).
"""
from __future__ import annotations

import posixpath
from collections import Counter
from dataclasses import dataclass
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any, Callable

from ..common import format_size, group_by
from ..channels import Layout
from ..errors import ImageReadError
from ..io.frames import ImageHeader, check_pixel_limit, pixel_limit, read_header
from .records import (EXPOSURE_ROLES, MAX_EXPOSURE, MIN_EXPOSURE, ROLES, UNIFORM_ROLES, Camera,
                      FrameRecord, Problem, ProblemCode, Session)
from .temperature import temperature_problems

__all__ = ["Candidate", "path_problem", "assemble"]

_HEADER_KEYS = ("exposure", "gain", "temperature")  # metadata a file header can supply
#: :func:`path_problem`'s answers that are not about leaving the folder, with their codes
_NUL_PATH = "path holds a NUL character (\\0): no file can have that name"
_LINK_LOOP = "symbolic link loop (the link leads back to itself): no file to read"
_PATH_CODES = {_NUL_PATH: ProblemCode.BAD_VALUE, _LINK_LOOP: ProblemCode.NOT_A_FILE}


@dataclass
class Candidate:
    """A frame before validation: where it was declared, its path and metadata.

    ``entry`` is the manifest entry (``"frames[2] (a.tif)"``, ``"groups[0] (dark/*.tif)"``),
    descriptor line or relative path that declared it; ``meta`` holds metadata keys of
    :class:`~ccdcore.session.records.FrameRecord`; ``inferred`` names those not given explicitly.
    """

    entry: str
    relpath: str
    role: str
    meta: dict[str, Any]
    inferred: tuple[str, ...] = ()


def path_problem(root: Path, relpath: str) -> str | None:
    """Why ``relpath`` is not a safe path inside ``root`` (resolved), or None when it is."""
    if not relpath:
        return "empty path"
    if "\0" in relpath:  # the OS cannot name such a file; Path.resolve would raise ValueError
        return _NUL_PATH
    if PurePosixPath(relpath).is_absolute() or PureWindowsPath(relpath).is_absolute():
        return "absolute path; paths must be relative to the session folder"
    norm = posixpath.normpath(relpath)
    if norm == ".." or norm.startswith("../"):
        return "path escapes the session folder ('..')"
    try:
        target = (root / norm).resolve()
    except (RuntimeError, OSError):  # Python 3.11 raises RuntimeError for a loop, 3.13 OSError
        return _LINK_LOOP
    if not target.is_relative_to(root):
        return f"resolves outside the session folder (symbolic link to {target})"
    return None


def assemble(root: Path, manifest_path: Path | None, source: str, camera: Camera,
             candidates: list[Candidate], problems: list[Problem], *,
             read: Callable[[Path], ImageHeader] | None = None) -> Session:
    """Check paths, read headers, infer header metadata and validate a list of candidates.

    ``read`` reads a header (default :func:`~ccdcore.io.frames.read_header`): a source that looked
    at the headers already (a plain folder, to find brackets) passes its cache so no file is read
    twice.
    """
    read = read or read_header
    limit = pixel_limit()  # a frame over it could be listed but never read: an error now
    headers: dict[Path, ImageHeader] = {}
    records: list[FrameRecord] = []
    seen: dict[Path, str] = {}
    reported: set[tuple[str, str]] = set()

    def once(where: str, message: str, code: ProblemCode, role: str) -> None:
        if (where, message) not in reported:  # a group reports its entry problem once
            reported.add((where, message))
            problems.append(Problem(where, message, code=code, roles=(role,)))

    for cand in candidates:
        roles = (cand.role,)
        # a file matched by a group glob also names the group
        origin = f" ({cand.entry})" if cand.entry.startswith("groups") else ""
        why = path_problem(root, cand.relpath)
        if why is not None:
            problems.append(Problem(cand.relpath.replace("\0", "\\0"), why + origin,
                                    code=_PATH_CODES.get(why, ProblemCode.PATH_OUTSIDE),
                                    roles=roles))
            continue
        path = (root / posixpath.normpath(cand.relpath)).resolve()
        if not path.exists():
            problems.append(Problem(cand.relpath, "file not found", code=ProblemCode.FILE_NOT_FOUND,
                                    roles=roles))
            continue
        if not path.is_file():
            what = "a folder" if path.is_dir() else "a FIFO/special file"
            problems.append(Problem(cand.relpath, f"is {what}, not an image file",
                                    code=ProblemCode.NOT_A_FILE, roles=roles))
            continue
        if path in seen:
            problems.append(Problem(cand.relpath, f"frame listed twice: {seen[path]} and "
                                                  f"{cand.entry}", code=ProblemCode.DUPLICATE,
                                    roles=roles))
            continue
        seen[path] = cand.entry
        if cand.role == "ptc" and cand.meta.get("level") is None:
            once(cand.entry, "ptc frame without 'level' (frames of one light level form pairs)",
                 ProblemCode.MISSING_LEVEL, "ptc")
        if cand.role == "fixed_pattern" and cand.meta.get("config") is None:
            once(cand.entry, "fixed_pattern frame without 'config' (configuration id)",
                 ProblemCode.MISSING_CONFIG, "fixed_pattern")

        meta, inferred = dict(cand.meta), list(cand.inferred)
        try:
            hdr = headers[path] = read(path)
        except ImageReadError as exc:
            problems.append(Problem(cand.relpath, exc.problem + origin, code=ProblemCode.UNREADABLE,
                                    roles=roles))
            hdr = None
        if hdr is not None:
            try:  # a tiny file declaring a huge image (a decompression bomb) is not "valid"
                check_pixel_limit(path, hdr.width, hdr.height, hdr.channels, limit)
            except ImageReadError as exc:
                problems.append(Problem(cand.relpath, exc.problem + origin,
                                        code=ProblemCode.UNREADABLE, roles=roles))
            for key in _HEADER_KEYS:
                value = getattr(hdr, key)
                if meta.get(key) is None and value is not None:
                    meta[key] = value
                    inferred.append(key)
        if cand.role in EXPOSURE_ROLES and meta.get("exposure") is None and hdr is not None:
            problems.append(Problem(cand.relpath, _missing_exposure(cand, source),
                                    code=ProblemCode.MISSING_EXPOSURE, roles=roles))
        exposure = meta.get("exposure")
        if cand.role in EXPOSURE_ROLES and exposure is not None and not (
                MIN_EXPOSURE <= exposure <= MAX_EXPOSURE):
            # a bracket's exposures divide its codes: 0 would make the radiance NaN downstream
            problems.append(Problem(cand.relpath, (
                f"exposure is 0 s: a {cand.role} frame needs a positive exposure time"
                if exposure == 0 else
                f"exposure {exposure:g} s is outside {MIN_EXPOSURE:g} to {MAX_EXPOSURE:g} s"),
                code=ProblemCode.BAD_VALUE, roles=roles))
        roi = meta.get("roi")
        if roi is not None and hdr is not None:
            x, y, w, h = roi
            if x + w > hdr.width or y + h > hdr.height:
                problems.append(Problem(cand.relpath, f"roi {list(roi)} extends past the "
                                        f"{hdr.width}x{hdr.height} frame",
                                        code=ProblemCode.ROI_OUTSIDE, roles=roles))
        records.append(FrameRecord(path=path, relpath=posixpath.normpath(cand.relpath),
                                   role=cand.role, inferred=tuple(dict.fromkeys(inferred)),
                                   **meta))

    problems.extend(_cross_frame_problems(records, headers, camera))
    problems.extend(temperature_problems(records))
    return Session(root=root, manifest_path=manifest_path, source=source, camera=camera,
                   frames=tuple(records), problems=tuple(problems), headers=headers)


def _missing_exposure(cand: Candidate, source: str) -> str:
    """The message of a bracket/reference/target frame without an exposure time."""
    if source != "folder":
        return (f"missing exposure: a {cand.role} frame needs one, and neither the manifest nor "
                "the file header (EXIF ExposureTime, FITS EXPTIME) gives it")
    png = PurePosixPath(cand.relpath).suffix.lower() == ".png"
    return (f"missing exposure: a {cand.role} frame needs one, and the file header gives none "
            "(no EXIF ExposureTime / FITS EXPTIME); fill in its 'exposure' (seconds) in the "
            "manifest draft (ccdcore session FOLDER --draft) and save it as session.toml"
            + ("; PNG files seldom carry EXIF, so a folder of PNG frames needs that manifest"
               if png else ""))


def _layout_problems(records: list[FrameRecord], headers: dict[Path, ImageHeader],
                     camera: Camera) -> list[Problem]:
    """One-channel frames under ``[camera] layout = "rgb"``, which needs three (they were
    read as colour and changed every figure silently; a colour frame under a one-channel
    layout is refused where it is used, naming the layout)."""
    if camera.layout != Layout.RGB:
        return []
    want, out = 3, []
    for r in records:
        hdr = headers.get(r.path)
        if hdr is None or hdr.channels != 1:
            continue
        has = f"{hdr.channels} channel{'s' if hdr.channels != 1 else ''}"
        out.append(Problem(r.relpath, f"has {has}, where [camera] layout = "
                                      f"{camera.layout!r} needs {want}",
                           code=ProblemCode.LAYOUT, roles=(r.role,)))
    return out


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
                         for name, a, b, fmt in (("size", sig[0], common[0], format_size),
                                                 ("dtype", sig[1], common[1], str),
                                                 ("bit depth", sig[2], common[2], str))
                         if a != b]
                out.append(Problem(r.relpath, f"{'; '.join(diffs)} of the other {role} frames "
                                              f"({n_common} frame{'s' if n_common > 1 else ''})",
                                   code=ProblemCode.MISMATCH, roles=(role,)))
    if camera.bits is not None:
        for r in records:
            hdr = headers.get(r.path)
            # A header whose bit depth is just the container width (a 12-bit camera stored in a
            # 16-bit TIFF) says nothing about the ADC; only an explicit smaller depth is compared.
            if (hdr is not None and hdr.dtype.kind in "ui" and hdr.bits > camera.bits
                    and hdr.bits < hdr.dtype.itemsize * 8):
                out.append(Problem(r.relpath, f"{hdr.bits}-bit data but camera.bits = "
                                              f"{camera.bits}", code=ProblemCode.BIT_DEPTH,
                                   roles=(r.role,)))
    out += _layout_problems(records, headers, camera)
    for level, recs in group_by((r for r in records if r.role == "ptc" and r.level is not None),
                                lambda r: r.level).items():
        if len(recs) < 2:
            out.append(Problem(f"ptc level {level}", f"only one frame ({recs[0].relpath}); a "
                                                     "photon-transfer level needs at least two",
                               code=ProblemCode.PTC_SINGLE_FRAME, roles=("ptc",)))
    return out
