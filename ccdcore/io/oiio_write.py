"""Writing through OpenImageIO for :mod:`ccdcore.io.frames`: the sample type a format stores, the
image spec with deterministic bytes, every ImageOutput call checked, and the file read back.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import ImageWriteError
from .base import OIIO_EXTENSIONS, one_line
from .oiio import libpng_quiet, oiio_messages

__all__ = ["oiio_samples", "oiio_spec", "oiio_write"]


# OpenImageIO format names for numpy dtypes it writes natively
_OIIO_TYPES = {"uint8": "uint8", "int8": "int8", "uint16": "uint16", "int16": "int16",
               "uint32": "uint", "int32": "int", "float16": "half", "float32": "float",
               "float64": "double"}
# Fixed TIFF DateTime so that the same pixels give the same bytes.
_FIXED_DATETIME = "2000:01:01 00:00:00"
# What OpenImageIO (3.2) reports on closing every TIFF file that has no EXIF fields, although the
# file is complete; a real failure there is still caught by reading the file back and by the
# free-space check.
_OIIO_NOT_ERRORS = ("failed TIFFWriteCustomDirectory() of the Exif data",)
# The bytes every complete file of a format ends with, checked after writing: a PNG file missing
# only its closing IEND chunk still reads back.
_FILE_ENDS = {".png": b"\x00\x00\x00\x00IEND\xaeB`\x82", ".jpg": b"\xff\xd9",
              ".jpeg": b"\xff\xd9"}


def oiio_samples(path: Path, a: np.ndarray, suffix: str) -> np.ndarray:
    """``a`` in a sample type the format stores, or :class:`ImageWriteError`."""
    if suffix not in OIIO_EXTENSIONS:
        raise ImageWriteError(path, f"cannot write '{suffix}' files; use .tif, .png, .pgm, .exr "
                                    "or .fits")
    if suffix == ".exr" and a.dtype not in (np.float16, np.float32):
        with np.errstate(over="ignore"):  # beyond float32 becomes inf, which EXR keeps
            a = a.astype(np.float32)
    if suffix in (".png", ".pgm", ".ppm", ".pnm") and a.dtype not in (np.uint8, np.uint16):
        raise ImageWriteError(path, f"{suffix} stores only uint8 or uint16 samples, got {a.dtype}")
    if str(a.dtype) not in _OIIO_TYPES:
        raise ImageWriteError(path, f"unsupported sample type {a.dtype}")
    return a


def oiio_spec(oiio, path: Path, a: np.ndarray, suffix: str, exposure, attributes):
    spec = oiio.ImageSpec(a.shape[1], a.shape[0], a.shape[2], _OIIO_TYPES[str(a.dtype)])
    if suffix in (".tif", ".tiff", ".exr"):
        spec.attribute("DateTime", _FIXED_DATETIME)
        spec.attribute("compression", "zip")
    if exposure is not None and suffix not in (".pgm", ".ppm", ".pnm"):
        spec.attribute("ExposureTime", float(exposure))
    for key, value in (attributes or {}).items():
        try:
            spec.attribute(key, value)
        except (TypeError, ValueError) as exc:
            raise ImageWriteError(path, f"cannot store attribute {key!r} = {value!r}: "
                                        f"{one_line(str(exc))}") from None
    return spec


def _oiio_step(oiio, out, ok: bool, what: str, tmp: Path, path: Path) -> None:
    """Raise :class:`ImageWriteError` unless an ImageOutput call succeeded and left no error.

    Both are looked at because OpenImageIO reports some failures only through ``geterror()``: on a
    full disk a PNG write returns True, and a TIFF close returns True after failing to write its
    directory. Messages in ``_OIIO_NOT_ERRORS`` are not taken as failures.
    """
    lines = [line for line in out.geterror().splitlines() if line.strip() not in _OIIO_NOT_ERRORS]
    own = one_line(*lines, tmp=tmp, path=path)
    other = oiio_messages(oiio, tmp=tmp, path=path)
    if not ok or own:
        raise ImageWriteError(path, f"{what}: {own or other or 'OpenImageIO gave no reason'}")


def oiio_write(oiio, tmp: Path, path: Path, spec, a: np.ndarray) -> None:
    """Write ``a`` to ``tmp`` through OpenImageIO, checking open, write and close.

    ``write_image`` is never called after a failed ``open``: OpenImageIO 3.2 crashes on that.
    """
    out = oiio.ImageOutput.create(str(tmp))
    if out is None:
        problem = oiio_messages(oiio, tmp=tmp, path=path) or "unknown format"
        raise ImageWriteError(path, f"no writer for this format: {problem}")
    try:
        _oiio_step(oiio, out, out.open(str(tmp), spec), "cannot create the file", tmp, path)
        _oiio_step(oiio, out, out.write_image(a), "cannot write the pixels", tmp, path)
    except BaseException:
        out.close()
        oiio_messages(oiio, out)  # the first failure is the one reported
        raise
    _oiio_step(oiio, out, out.close(), "cannot finish the file", tmp, path)
    _verify_written(oiio, tmp, path, spec)


def _ends_whole(tmp: Path) -> bool:
    """False when ``tmp`` lacks the closing bytes its format always ends with (``_FILE_ENDS``)."""
    end = _FILE_ENDS.get(tmp.suffix.lower())
    if end is None:
        return True
    with open(tmp, "rb") as f:
        size = f.seek(0, os.SEEK_END)
        f.seek(max(size - len(end), 0))
        return f.read() == end


def _verify_written(oiio, tmp: Path, path: Path, spec) -> None:
    """Read back the header, the last row and the closing bytes of a file just written.

    OpenImageIO does not report every failed write: on a full disk an OpenEXR or PNG file, or a
    TIFF file cut short in its closing directory, comes back as a success. The writers write in
    order, so a file cut short lacks its end: its header or its last row does not read back, or
    its closing bytes are missing.
    """
    if not _ends_whole(tmp):
        raise ImageWriteError(path, "the written file is cut short (its closing bytes are "
                                    "missing); is the disk full?")
    with libpng_quiet(tmp):
        inp = oiio.ImageInput.open(str(tmp))
        if inp is None:
            problem = oiio_messages(oiio, tmp=tmp, path=path) or "unreadable"
            raise ImageWriteError(path, f"the written file does not read back ({problem}); "
                                        "is the disk full?")
        try:
            got = inp.spec()
            row = inp.read_scanlines(0, 0, got.y + got.height - 1, got.y + got.height, got.z,
                                     0, got.nchannels, oiio.UNKNOWN)
            problem = oiio_messages(oiio, inp, tmp=tmp, path=path)
        finally:
            inp.close()
            oiio_messages(oiio, inp)
    size = (got.width, got.height, got.nchannels)
    if row is None or problem or size != (spec.width, spec.height, spec.nchannels):
        raise ImageWriteError(path, "the written file does not read back "
                                    f"({problem or f'got {size[0]}x{size[1]}x{size[2]}'}); "
                                    "is the disk full?")
