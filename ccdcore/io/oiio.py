"""Reading through OpenImageIO (TIFF, OpenEXR, PNG, PNM, ...) for :mod:`ccdcore.io.frames`: opening
a file with every call's error text looked at, its header, its pixels whole or the strips, rows or
tiles holding a region, and libpng's own lines kept off stderr.
"""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import threading
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import ImageReadError
from .base import LAYOUTS, ImageHeader, exposure_seconds, float_or_none, one_line
from .limits import check_pixel_limit

__all__ = ["oiio_module", "oiio_messages", "libpng_quiet", "oiio_open", "oiio_close",
           "header_from_spec", "read_oiio", "read_oiio_region"]


# ---- OpenImageIO ----------------------------------------------------------------------------
def oiio_module():
    import OpenImageIO as oiio  # imported lazily: it is heavy and only needed for I/O

    return oiio


def oiio_messages(oiio, obj=None, **names) -> str:
    """Retrieve -- and so clear -- the pending OpenImageIO errors of ``obj`` and of this thread.

    Retrieving them also keeps OpenImageIO from printing them on stderr at exit.
    """
    own = obj.geterror() if obj is not None else ""
    return one_line(own, oiio.geterror(), **names)


_STDERR_LOCK = threading.RLock()


def _stderr_to(sink) -> int | None:
    """Point file descriptor 2 at ``sink``; return a duplicate of the old one (None: left as is)."""
    with contextlib.suppress(AttributeError, ValueError, OSError):
        sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no stderr at all
        return None
    os.dup2(sink.fileno(), 2)
    return saved


def _stderr_back(saved: int | None, sink) -> None:
    """Restore file descriptor 2 and pass on what was written meanwhile, less libpng's lines."""
    if saved is None:
        return
    os.dup2(saved, 2)
    os.close(saved)
    sink.seek(0)
    rest = b"".join(line for line in sink if not line.startswith(b"libpng "))
    if rest:
        with contextlib.suppress(OSError):
            os.write(2, rest)


@contextlib.contextmanager
def libpng_quiet(path: Path) -> Iterator[None]:
    """Keep libpng's own ``libpng error: ...`` lines off stderr while OpenImageIO reads a PNG.

    libpng prints them straight to file descriptor 2, then OpenImageIO reports the same problem
    through ``geterror()``, which goes into the :class:`ImageReadError`. Whatever else reaches
    stderr meanwhile (another thread's output) is passed on afterwards; other formats are left
    alone.
    """
    sink = None
    if path.suffix.lower() == ".png":
        with contextlib.suppress(OSError):  # no room for it: libpng may speak then
            sink = tempfile.TemporaryFile()
    if sink is None:
        yield
        return
    with _STDERR_LOCK, sink:
        saved = _stderr_to(sink)
        try:
            yield
        finally:
            _stderr_back(saved, sink)


def oiio_open(oiio, path: Path):
    """Open ``path`` with OpenImageIO, or raise :class:`ImageReadError` naming it."""
    try:
        inp = oiio.ImageInput.open(str(path))
    except Exception as exc:  # the bindings raise for names they cannot pass on (bad UTF-8)
        raise ImageReadError(path, f"cannot read image: {one_line(str(exc))}") from None
    if inp is None:
        problem = oiio_messages(oiio) or "no reader for this file"
        raise ImageReadError(path, f"cannot read image: {problem}")
    oiio.geterror()  # drop what the readers tried before the right one left behind
    return inp


def oiio_close(oiio, inp) -> None:
    """Close a reader and drop its pending messages (the pixels were already checked)."""
    inp.close()
    oiio_messages(oiio, inp)


def _check_pixels(oiio, inp, data, path: Path) -> None:
    """Raise :class:`ImageReadError` unless a read gave pixels and no error."""
    problem = oiio_messages(oiio, inp)
    if data is None or problem:
        raise ImageReadError(path, "truncated or corrupt image data "
                                   f"({problem or 'OpenImageIO gave no pixels'})")


def header_from_spec(path: Path, spec, format_name: str) -> ImageHeader:
    dtype = np.dtype(_dtype_from_typedesc(spec.format, path))
    bits = spec.get_int_attribute("oiio:BitsPerSample", 0) or dtype.itemsize * 8
    attrs = {a.name: a.value for a in spec.extra_attribs
             if isinstance(a.value, (str, int, float))}
    # EXIF stores ExposureTime as a RATIONAL; a plugin may hand it on as (num, den) or "1/250"
    exposure = exposure_seconds(spec.getattribute("ExposureTime"))
    gain = float_or_none(attrs.get("Exif:Gain", attrs.get("Gain")))
    return ImageHeader(path=path, width=spec.width, height=spec.height,
                       channels=spec.nchannels, dtype=dtype, bits=int(bits),
                       layout=LAYOUTS.get(spec.nchannels, f"{spec.nchannels}-channel"),
                       exposure=exposure, gain=gain,
                       temperature=float_or_none(attrs.get("Exif:Temperature",
                                                           attrs.get("Exif:AmbientTemperature"))),
                       format=format_name, attributes=attrs)


def _dtype_from_typedesc(td, path: Path | None = None) -> str:
    name = str(td)
    table = {"uint8": "uint8", "int8": "int8", "uint16": "uint16", "int16": "int16",
             "uint": "uint32", "uint32": "uint32", "int": "int32", "int32": "int32",
             "half": "float16", "float": "float32", "double": "float64"}
    if name not in table:
        raise ImageReadError(path, f"unsupported sample type {name}")
    return table[name]


def read_oiio(path: Path, header: ImageHeader) -> np.ndarray:
    oiio = oiio_module()
    inp = oiio_open(oiio, path)
    try:
        data = inp.read_image(format=oiio.UNKNOWN)
        _check_pixels(oiio, inp, data, path)
    finally:
        oiio_close(oiio, inp)
    return np.ascontiguousarray(data).astype(header.dtype, copy=False)


def _round_up(n: int, step: int) -> int:
    return -(-n // step) * step


def _read_oiio_rows(oiio, inp, spec, box, path: Path, limit: int):
    """The full-width rows holding ``box`` in a scanline image, and where the box starts in them.

    In a TIFF file whole strips are read: they are decoded whole anyway, and OpenImageIO (3.2)
    reads a range ending inside a strip by decoding the file from its start.
    """
    x, y, w, h = box
    rows = spec.get_int_attribute("tiff:RowsPerStrip", 0) or 1
    y0, y1 = y - y % rows, min(_round_up(y + h, rows), spec.height)
    check_pixel_limit(path, spec.width, y1 - y0, spec.nchannels, limit,
                       what="the rows holding this region are")
    data = inp.read_scanlines(0, 0, spec.y + y0, spec.y + y1, spec.z, 0, spec.nchannels,
                              oiio.UNKNOWN)
    return data, (x, y - y0)


def _read_oiio_tiles(oiio, inp, spec, box, path: Path, limit: int):
    """The tiles covering ``box`` of a tiled image, and where the box starts in them."""
    x, y, w, h = box
    tw, th = spec.tile_width, spec.tile_height
    x0, y0 = x - x % tw, y - y % th
    x1, y1 = min(_round_up(x + w, tw), spec.width), min(_round_up(y + h, th), spec.height)
    check_pixel_limit(path, x1 - x0, y1 - y0, spec.nchannels, limit,
                       what="the tiles holding this region are")
    data = inp.read_tiles(0, 0, spec.x + x0, spec.x + x1, spec.y + y0, spec.y + y1,
                          spec.z, spec.z + max(spec.depth, 1), 0, spec.nchannels, oiio.UNKNOWN)
    return data, (x - x0, y - y0)


def read_oiio_region(path: Path, header: ImageHeader, box, limit: int) -> np.ndarray:
    oiio = oiio_module()
    inp = oiio_open(oiio, path)
    try:
        spec = inp.spec()
        read = _read_oiio_tiles if spec.tile_width else _read_oiio_rows
        data, (dx, dy) = read(oiio, inp, spec, box, path, limit)
        _check_pixels(oiio, inp, data, path)
    finally:
        oiio_close(oiio, inp)
    _, _, w, h = box
    data = np.asarray(data)
    if data.ndim == 4:  # (depth, rows, columns, channels) of a volume image: its first slice
        data = data[0]
    return np.ascontiguousarray(data[dy:dy + h, dx:dx + w]).astype(header.dtype, copy=False)
