"""The shared parts of :mod:`ccdcore.io.frames`: the file extensions, :class:`ImageHeader`, the
header values (numbers and exposure times as headers hold them) and error text on one line.

The lowest of the I/O modules (:mod:`ccdcore.io.limits`, :mod:`ccdcore.io.oiio`,
:mod:`ccdcore.io.oiio_write`, :mod:`ccdcore.io.fits`, :mod:`ccdcore.io.outputs` and
:mod:`ccdcore.io.frames` build on it); every public name a user needs is re-exported by
:mod:`ccdcore.io.frames`.
"""
from __future__ import annotations

import contextlib
import os
import stat
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ImageReadError

__all__ = [
    "FITS_EXTENSIONS", "RAW_EXTENSIONS", "OIIO_EXTENSIONS", "IMAGE_EXTENSIONS", "LAYOUTS",
    "ImageHeader", "is_image_path", "check_file", "float_or_none", "exposure_seconds", "int_or",
    "one_line", "os_problem", "sync_folder",
]


FITS_EXTENSIONS = frozenset({".fits", ".fit", ".fts"})
RAW_EXTENSIONS = frozenset({".dng", ".cr2", ".cr3", ".nef", ".arw", ".orf", ".rw2", ".raf",
                            ".pef", ".srw", ".raw"})
OIIO_EXTENSIONS = frozenset({".tif", ".tiff", ".exr", ".png", ".pgm", ".ppm", ".pnm", ".pfm",
                             ".bmp", ".jpg", ".jpeg", ".hdr", ".dpx", ".sgi", ".tga"})
#: every extension :func:`read_image` accepts
IMAGE_EXTENSIONS = OIIO_EXTENSIONS | FITS_EXTENSIONS | RAW_EXTENSIONS

#: the layout of an image of 1 to 4 channels
LAYOUTS = {1: "mono", 2: "mono+alpha", 3: "rgb", 4: "rgba"}
# Longest OpenImageIO/OS message quoted in an error line.
_MESSAGE_CHARS = 300


@dataclass(frozen=True)
class ImageHeader:
    """Pixel description and capture metadata of one image file."""

    path: Path
    width: int
    height: int
    channels: int
    dtype: np.dtype
    bits: int
    layout: str
    exposure: float | None = None
    gain: float | None = None
    temperature: float | None = None
    format: str = ""
    attributes: dict[str, Any] = field(default_factory=dict, compare=False)

    @property
    def shape(self) -> tuple[int, ...]:
        """Array shape :func:`read_image` returns: ``(H, W)`` or ``(H, W, C)``."""
        if self.channels == 1:
            return (self.height, self.width)
        return (self.height, self.width, self.channels)

    def to_dict(self) -> dict[str, Any]:
        return {"path": str(self.path), "width": self.width, "height": self.height,
                "channels": self.channels, "dtype": str(self.dtype), "bits": self.bits,
                "layout": self.layout, "exposure": self.exposure, "gain": self.gain,
                "temperature": self.temperature, "format": self.format}


def is_image_path(path: str | os.PathLike) -> bool:
    """True when the file extension is one :func:`read_image` reads."""
    return Path(path).suffix.lower() in IMAGE_EXTENSIONS


# --------------------------------------------------------------------------------------------
# header values
# --------------------------------------------------------------------------------------------
def check_file(path: Path) -> None:
    if not path.exists():
        raise ImageReadError(path, "file not found")
    if path.is_dir():
        raise ImageReadError(path, "is a folder, not an image file")
    if not path.is_file():
        mode = path.stat().st_mode
        what = ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a device"
                if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a socket"
                if stat.S_ISSOCK(mode) else "not a regular file")
        raise ImageReadError(path, f"is {what}, not an image file")
    if path.stat().st_size == 0:
        raise ImageReadError(path, "empty file (0 bytes)")
    if path.suffix.lower() not in IMAGE_EXTENSIONS:
        raise ImageReadError(path, f"unsupported file type '{path.suffix}' "
                                   f"(supported: {', '.join(sorted(IMAGE_EXTENSIONS))})")


def float_or_none(value: Any) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        return None
    return v if np.isfinite(v) else None


def _float32_value(value: Any) -> float | None:
    """A header number stored as float32 (TIFF/EXR EXIF), given back as its shortest decimal.

    EXIF ``ExposureTime`` goes through a 32-bit float, so 0.01 s reads as 0.009999999776...; the
    shortest decimal that maps to the same float32 (``0.01``) is what the camera wrote.
    """
    v = float_or_none(value)
    if v is None:
        return None
    with np.errstate(over="ignore"):
        v32 = np.float32(v)
    return float(np.format_float_positional(v32, unique=True)) if np.isfinite(v32) else None


#: largest denominator of the shutter speeds a float32 exposure time is recognised as (1/3 s,
#: 1/60 s, 10/13 s, 1/750 s ...; 1/8000 s and the like are short decimals anyway)
_SHUTTER_DENOMINATOR = 1000


def _shutter_speed(value: Any) -> float | None:
    """A float32 EXIF exposure time as the rational the camera wrote, else its shortest decimal.

    EXIF stores ExposureTime as a RATIONAL (1/60) and OpenImageIO hands it on as a float32
    (0.016666668).  When the shortest decimal of that float32 is not a short number someone
    would write (more than 6 significant digits) and a fraction with a denominator up to
    :data:`_SHUTTER_DENOMINATOR` rounds to the same float32, that fraction is the value
    (``1/60`` -> 0.016666666666666666), so exposure ratios come out exact.
    """
    v = _float32_value(value)
    if v is None or v <= 0 or len(f"{v:e}".split("e")[0].replace(".", "").rstrip("0")) <= 6:
        return v
    frac = Fraction(v).limit_denominator(_SHUTTER_DENOMINATOR)
    return float(frac) if frac and np.float32(float(frac)) == np.float32(v) else v


def exposure_seconds(value: Any) -> float | None:
    """An exposure time as a header gives it, in seconds, or None when it is not one.

    Accepts a number (EXIF RATIONALs come back from OpenImageIO as float32: given back as the
    camera's fraction or their shortest decimal, see :func:`_shutter_speed`), a rational
    ``(numerator, denominator)`` pair and text such as ``"1/250"``, ``"0.004"`` or
    ``"1/250 s"``.  Negative, zero-denominator and non-finite values give None.
    """
    if isinstance(value, bool):
        return None
    if isinstance(value, (tuple, list)) and len(value) == 2:
        num, den = (float_or_none(v) for v in value)
        v = None if num is None or not den else num / den
    elif isinstance(value, str):
        text = value.strip().lower().removesuffix("s").strip().removesuffix("sec").strip()
        num_text, slash, den_text = text.partition("/")
        num, den = float_or_none(num_text), float_or_none(den_text) if slash else 1.0
        v = None if num is None or not den else num / den
    else:
        v = _shutter_speed(value)
    return v if v is not None and np.isfinite(v) and v >= 0 else None


def int_or(value: Any, default: int) -> int:
    """``value`` as an int, or ``default`` when a header holds something else there."""
    try:
        return int(value)
    except (TypeError, ValueError, OverflowError):
        return default


# ---- messages -------------------------------------------------------------------------------
def one_line(*messages: str | None, tmp: Path | None = None, path: Path | None = None) -> str:
    """Messages as one line: distinct lines joined by ``; ``, whitespace collapsed, cut short.

    With ``tmp`` and ``path``, the hidden temporary file's name is replaced by the target's, so
    that an error about a failed write names the file the user asked for.
    """
    lines: list[str] = []
    for message in messages:
        for line in str(message or "").splitlines():
            line = " ".join(line.split())
            if tmp is not None and path is not None:
                line = line.replace(str(tmp), str(path)).replace(tmp.name, path.name)
            if line and line not in lines:
                lines.append(line)
    text = "; ".join(lines)
    return text if len(text) <= _MESSAGE_CHARS else text[:_MESSAGE_CHARS - 3] + "..."


def os_problem(exc: OSError, tmp: Path | None = None, path: Path | None = None) -> str:
    """An OS error in words (``No space left on device``), naming the target, not the temp file."""
    return one_line(exc.strerror or str(exc), tmp=tmp, path=path) or type(exc).__name__


def sync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable where the system allows it (best effort)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
