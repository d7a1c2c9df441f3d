"""Import of EMVA1288 descriptor files as capture sessions.

The EMVA1288 reference implementation (``emva1288.process.parser.ParseEmvaDescriptorFile``)
describes a measurement with a plain-text descriptor beside the images::

    v 4.0                     # format version
    n 12 640 480              # bits, width, height (once)
    b 500000.0 1234.567       # a bright point: exposure [ns], mean photons per pixel
    i images\\image0.tif       # its images (two for a temporal point, more for a spatial one)
    i images\\image1.tif
    d 500000.0                # a dark point at that exposure, followed by its images
    i images\\image2.tif
    i images\\image3.tif

Lines starting with ``#`` are comments; image paths are relative to the descriptor's folder and
may use ``\\`` as separator (the reference implementation writes them so).

Mapping onto a :class:`~ccdcore.session.Session`: the k-th bright point (1-based, in file order)
becomes photon-transfer level ``k`` (role ``ptc``) with its exposure in seconds and its photon count
in :attr:`FrameRecord.photons`; dark points become ``dark`` frames with their exposure (photons 0).
The camera has the ``n`` line's bit depth and a ``mono`` layout.  Besides the checks every session
gets, each image's size is compared with the ``n`` line.

Public objects
--------------
open_emva_descriptor(path)
    Read a descriptor and validate its images; return a :class:`~ccdcore.session.Session`.
"""
from __future__ import annotations

import dataclasses
import math
import posixpath
from pathlib import Path

from ..errors import CcdError, ImageReadError
from .assemble import Candidate, assemble
from .records import Camera, Problem, ProblemCode, Session

__all__ = ["open_emva_descriptor", "MAX_DESCRIPTOR_BYTES"]


#: the largest descriptor read (a series of 1000 points with its file names is under 1 MB)
MAX_DESCRIPTOR_BYTES = 64 * 2 ** 20


class _LineError(Exception):
    """A descriptor line of the wrong form (reported as a Problem, never raised to the user)."""


def _number(text: str, what: str) -> float:
    """A finite descriptor number >= 0; a decimal comma is accepted as the reference parser does.

    Raises
    ------
    _LineError
        Not a number, not finite, or negative (``what`` names the field).
    """
    try:
        value = float(text.replace(",", "."))
    except ValueError:
        raise _LineError(f"{what} {text!r} is not a number") from None
    if not math.isfinite(value) or value < 0:
        raise _LineError(f"{what} must be a finite number >= 0, got {text}")
    return value


def _count(text: str, what: str, low: int, high: int) -> int:
    """An integer field of the ``n`` line in [low, high]."""
    try:
        value = int(text)
    except ValueError:
        raise _LineError(f"{what} {text!r} is not an integer") from None
    if not low <= value <= high:
        raise _LineError(f"{what} must be an integer from {low} to {high}, got {value}")
    return value


def open_emva_descriptor(path: str | Path) -> Session:
    """Open an EMVA1288 descriptor file as a session (``source = "emva1288"``).

    Parameters
    ----------
    path
        The descriptor (e.g. ``EMVA1288descriptor.txt``).

    Returns
    -------
    Session
        Bright points as ``ptc`` levels 1, 2, ... (``exposure`` = ns / 1e9, ``photons`` set),
        dark points as ``dark`` frames.  Malformed lines, missing or unreadable images and images
        whose size differs from the ``n`` line are listed in :attr:`Session.problems`.

    Raises
    ------
    CcdError
        The descriptor cannot be read.
    """
    desc = Path(path)
    try:
        size = desc.stat().st_size
        if size > MAX_DESCRIPTOR_BYTES:
            raise CcdError(desc, f"{size / 2 ** 20:.0f} MB, larger than any EMVA1288 descriptor "
                                 f"(at most {MAX_DESCRIPTOR_BYTES // 2 ** 20} MB)")
        lines = desc.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise CcdError(desc, f"cannot read the EMVA1288 descriptor: {exc}") from None

    problems: list[Problem] = []
    candidates: list[Candidate] = []
    fmt: tuple[int, int, int] | None = None  # bits, width, height
    point: tuple[str, dict] | None = None    # (label, metadata) of the current b/d point
    n_images = 0  # images of the current point
    n_bright = 0

    def close_point() -> None:
        if point is not None and n_images < 1:
            problems.append(Problem(point[0], "point has no 'i' image lines",
                                    code=ProblemCode.DESCRIPTOR_LINE))

    for lineno, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        where = f"{desc.name} line {lineno}"
        fields = line.split()
        tag, args = fields[0], fields[1:]
        try:
            if tag == "v":
                if len(args) != 1:
                    raise _LineError("should be 'v <version>'")
            elif tag == "n":
                if len(args) != 3:
                    raise _LineError("should be 'n <bits> <width> <height>'")
                if fmt is not None:
                    raise _LineError("a second 'n' line (only one is allowed)")
                fmt = (_count(args[0], "bits", 1, 32), _count(args[1], "width", 1, 2 ** 20),
                       _count(args[2], "height", 1, 2 ** 20))
            elif tag in ("b", "d"):
                close_point()
                point, n_images = None, 0
                if tag == "b" and len(args) != 2:
                    raise _LineError("should be 'b <exposure_ns> <photons>'")
                if tag == "d" and len(args) != 1:
                    raise _LineError("should be 'd <exposure_ns>'")
                meta = {"exposure": _number(args[0], "exposure [ns]") / 1e9,  # ns -> s
                        "photons": _number(args[1], "photons per pixel") if tag == "b" else 0.0}
                if tag == "b":
                    n_bright += 1
                    point = (where, {"role": "ptc", "level": n_bright, **meta})
                else:
                    point = (where, {"role": "dark", **meta})
            elif tag == "i":
                if len(args) != 1:
                    raise _LineError("should be 'i <relative path>'")
                if point is None:
                    raise _LineError("image line before any 'b' or 'd' point")
                n_images += 1
                meta = dict(point[1])
                role = meta.pop("role")
                relpath = posixpath.normpath(args[0].replace("\\", "/"))
                candidates.append(Candidate(point[0], relpath, role, meta))
            else:
                raise _LineError(f"unknown line type '{tag}' (expected v, n, b, d or i)")
        except _LineError as exc:
            problems.append(Problem(where, str(exc), code=ProblemCode.DESCRIPTOR_LINE))
    close_point()

    if fmt is None:
        problems.append(Problem(desc.name, "no 'n <bits> <width> <height>' line",
                                code=ProblemCode.DESCRIPTOR_LINE))
    if not candidates and not any(p.severity == "error" for p in problems):
        # a session of 0 frames is nothing to calibrate: never "valid" (as an empty manifest)
        problems.append(Problem(desc.name, "the descriptor lists no images: add 'b' or 'd' "
                                           "points, each followed by its 'i' image lines",
                                code=ProblemCode.NO_FRAMES))
    camera = Camera(name=f"EMVA1288 {desc.stem}", bits=fmt[0] if fmt else None, layout="mono")
    session = assemble(desc.parent.resolve(), desc, "emva1288", camera, candidates, problems)
    if fmt is None:
        return session

    size_problems = []
    for rec in session.frames:
        try:
            hdr = session.header(rec)
        except ImageReadError:
            continue  # already reported
        if (hdr.width, hdr.height) != fmt[1:]:
            size_problems.append(Problem(rec.relpath, f"image is {hdr.width}x{hdr.height} but "
                                         f"the descriptor's n line says {fmt[1]}x{fmt[2]}",
                                         code=ProblemCode.DESCRIPTOR_SIZE, roles=(rec.role,)))
    return dataclasses.replace(session, problems=session.problems + tuple(size_problems))
