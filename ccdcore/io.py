"""Reading and writing image frames and float32 maps, keeping digital numbers as captured.

Public objects
--------------
:class:`ImageHeader`
    What a file says about its pixels (size, channels, stored dtype, bit depth, layout) and its
    capture metadata (exposure time, gain, temperature) without reading the pixels.
:func:`read_header`, :func:`read_image`, :func:`read_frame`
    Read a frame through OpenImageIO (TIFF, OpenEXR, PNG, PNM, ...), FITS through astropy, camera
    raw (DNG, CR2, NEF, ...) through rawpy (optional ``raw`` extra) as undemosaiced CFA data.
:func:`read_region`
    Read a rectangle of a frame, decoding only the strips, tiles or rows it covers.
:data:`MAX_PIXELS`
    The largest image (width x height x channels) read without being asked; see
    :func:`pixel_limit`.
:func:`write_image`, :func:`write_map`
    Atomic writes (temporary file in the same folder, then rename) with deterministic bytes.
:func:`atomic_path`, :func:`atomic_write_text`, :func:`atomic_write_bytes`
    The atomic-write building blocks.
:func:`output_set`, :func:`write_outputs`, :func:`check_output`, :func:`check_not_inputs`
    Every verb's outputs written as one set (a temporary folder swapped in), never over an
    input of the run nor over a FIFO or a device.

Policy: integers stay integers of the stored width (no rescaling to [0, 1], no gamma); a single
channel comes back as a 2-D ``(H, W)`` array, several as ``(H, W, C)``.

The file boundary is checked: every OpenImageIO call's result and error text is looked at, a
failed write never replaces the previous file (the temporary file is removed and the error names
the target), an image whose header declares more than :data:`MAX_PIXELS` values is refused before
its pixels are decoded, and bad input gives one :class:`~ccdcore.errors.ImageReadError` line rather
than warnings on stderr.

FITS goes through :mod:`astropy.io.fits` rather than OpenImageIO because OpenImageIO's FITS plugin
ignores ``BZERO``/``BSCALE``: the standard unsigned 16-bit FITS frame of astronomical cameras
(``BITPIX = 16``, ``BZERO = 32768``) would be read as signed and wrong.
"""
from __future__ import annotations

import contextlib
import errno
import os
import shutil
import signal
import stat
import sys
import tempfile
import threading
import warnings
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

import numpy as np

from .errors import CcdError, ImageReadError, ImageWriteError, MethodNotAvailable

__all__ = [
    "ImageHeader", "read_header", "read_image", "read_frame", "read_region", "write_image",
    "write_map", "atomic_path", "atomic_write_text", "atomic_write_bytes", "IMAGE_EXTENSIONS",
    "RAW_EXTENSIONS", "FITS_EXTENSIONS", "is_image_path", "MAX_PIXELS", "MAX_PIXELS_ENV",
           "check_pixel_limit",
    "pixel_limit", "TEMP_PREFIX", "output_set", "write_outputs", "check_output", "check_outputs",
    "check_not_inputs", "real_path", "remove_stale_temporaries",
]

FITS_EXTENSIONS = frozenset({".fits", ".fit", ".fts"})
RAW_EXTENSIONS = frozenset({".dng", ".cr2", ".cr3", ".nef", ".arw", ".orf", ".rw2", ".raf",
                            ".pef", ".srw", ".raw"})
OIIO_EXTENSIONS = frozenset({".tif", ".tiff", ".exr", ".png", ".pgm", ".ppm", ".pnm", ".pfm",
                             ".bmp", ".jpg", ".jpeg", ".hdr", ".dpx", ".sgi", ".tga"})
#: every extension :func:`read_image` accepts
IMAGE_EXTENSIONS = OIIO_EXTENSIONS | FITS_EXTENSIONS | RAW_EXTENSIONS

_LAYOUTS = {1: "mono", 2: "mono+alpha", 3: "rgb", 4: "rgba"}
# OpenImageIO format names for numpy dtypes it writes natively
_OIIO_TYPES = {"uint8": "uint8", "int8": "int8", "uint16": "uint16", "int16": "int16",
               "uint32": "uint", "int32": "int", "float16": "half", "float32": "float",
               "float64": "double"}
# Fixed TIFF DateTime so that the same pixels give the same bytes.
_FIXED_DATETIME = "2000:01:01 00:00:00"

#: Largest image :func:`read_image`, :func:`read_frame` and :func:`read_region` decode unless told
#: otherwise, counted in pixel values: width x height x channels. 2**30 (1.07 G values) lets every
#: single-shot sensor through (a 151 MP medium-format or a 16k x 16k scientific frame as raw/mono,
#: RGB or RGBA; a 240 MP pixel-shift RGB composite) while a 40000 x 40000 "decompression bomb" is
#: refused; the largest image allowed takes 2 GiB as uint16 and 8 GiB once a caller makes it
#: float64, which still fits the 24 GiB machines this project targets.
MAX_PIXELS = 2**30
#: Environment variable that overrides :data:`MAX_PIXELS` (a positive whole number).
MAX_PIXELS_ENV = "CCDCORE_MAX_PIXELS"
# Longest OpenImageIO/OS message quoted in an error line.
_MESSAGE_CHARS = 300
# A write is not started with less free space than this in the target's folder.
_MIN_FREE_BYTES = 1 << 20
# What OpenImageIO (3.2) reports on closing every TIFF file that has no EXIF fields, although the
# file is complete; a real failure there is still caught by reading the file back and by the
# free-space check.
_OIIO_NOT_ERRORS = ("failed TIFFWriteCustomDirectory() of the Exif data",)
# The bytes every complete file of a format ends with, checked after writing: a PNG file missing
# only its closing IEND chunk still reads back.
_FILE_ENDS = {".png": b"\x00\x00\x00\x00IEND\xaeB`\x82", ".jpg": b"\xff\xd9",
              ".jpeg": b"\xff\xd9"}


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
# reading
# --------------------------------------------------------------------------------------------
def _check_file(path: Path) -> None:
    if not path.exists():
        raise ImageReadError(path, "file not found")
    if path.is_dir():
        raise ImageReadError(path, "is a folder, not an image file")
    if path.stat().st_size == 0:
        raise ImageReadError(path, "empty file (0 bytes)")
    if path.suffix.lower() not in IMAGE_EXTENSIONS:
        raise ImageReadError(path, f"unsupported file type '{path.suffix}' "
                                   f"(supported: {', '.join(sorted(IMAGE_EXTENSIONS))})")


def _float_or_none(value: Any) -> float | None:
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
    v = _float_or_none(value)
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


def _exposure_seconds(value: Any) -> float | None:
    """An exposure time as a header gives it, in seconds, or None when it is not one.

    Accepts a number (EXIF RATIONALs come back from OpenImageIO as float32: given back as the
    camera's fraction or their shortest decimal, see :func:`_shutter_speed`), a rational
    ``(numerator, denominator)`` pair and text such as ``"1/250"``, ``"0.004"`` or
    ``"1/250 s"``.  Negative, zero-denominator and non-finite values give None.
    """
    if isinstance(value, bool):
        return None
    if isinstance(value, (tuple, list)) and len(value) == 2:
        num, den = (_float_or_none(v) for v in value)
        v = None if num is None or not den else num / den
    elif isinstance(value, str):
        text = value.strip().lower().removesuffix("s").strip().removesuffix("sec").strip()
        num_text, slash, den_text = text.partition("/")
        num, den = _float_or_none(num_text), _float_or_none(den_text) if slash else 1.0
        v = None if num is None or not den else num / den
    else:
        v = _shutter_speed(value)
    return v if v is not None and np.isfinite(v) and v >= 0 else None


def _int_or(value: Any, default: int) -> int:
    """``value`` as an int, or ``default`` when a header holds something else there."""
    try:
        return int(value)
    except (TypeError, ValueError, OverflowError):
        return default


# ---- the pixel limit ------------------------------------------------------------------------
def _whole_number(value: Any) -> int | None:
    """``value`` (int, integral float, or such a number as text) as an int; None otherwise."""
    if isinstance(value, bool):
        return None
    with contextlib.suppress(TypeError, ValueError, OverflowError):
        number = float(value) if isinstance(value, (str, float)) else value
        if int(number) == number:
            return int(number)
    return None


def pixel_limit(max_pixels: int | None = None) -> int:
    """The largest image, in pixel values (width x height x channels), that a read decodes.

    Parameters
    ----------
    max_pixels
        Limit for this call; ``None`` takes the environment variable ``CCDCORE_MAX_PIXELS`` when
        set, else the module default :data:`MAX_PIXELS`.

    Returns
    -------
    int
        The limit in force.

    Raises
    ------
    CcdError
        ``max_pixels`` or the environment variable is not a positive whole number.
    """
    if max_pixels is not None:
        where, value = "max_pixels", max_pixels
    elif os.environ.get(MAX_PIXELS_ENV, "").strip():
        where, value = MAX_PIXELS_ENV, os.environ[MAX_PIXELS_ENV].strip()
    else:
        return int(MAX_PIXELS)
    limit = _whole_number(value)
    if limit is None or limit <= 0:
        raise CcdError(where, f"{value!r} is not a positive whole number "
                              "(the largest image to read, in pixel values)")
    return limit


def check_pixel_limit(path: str | Path, width: int, height: int, channels: int,
                      limit: int | None = None, what: str = "image is") -> None:
    """Raise :class:`ImageReadError` when ``width x height x channels`` exceeds ``limit``.

    Called with the header's numbers, before any pixel is decoded, so that a small file declaring
    a huge image (a decompression bomb, or a corrupt header) cannot exhaust memory. ``limit``:
    :func:`pixel_limit` when ``None``. Every reader of frames (the streamed reads here, a
    session's validation, the cluster paths, the app's previews) checks through this one rule.
    """
    limit = pixel_limit() if limit is None else int(limit)
    values = int(width) * int(height) * int(channels)
    if values > limit:
        raise ImageReadError(
            path, f"{what} {width}x{height} pixels x {channels} channel(s) = {values:,} values, "
                  f"over the limit of {limit:,} (a guard against decompression bombs); to read "
                  f"it anyway pass max_pixels={values} or set {MAX_PIXELS_ENV}={values}")


# ---- OpenImageIO ----------------------------------------------------------------------------
def _oiio():
    import OpenImageIO as oiio  # imported lazily: it is heavy and only needed for I/O

    return oiio


def _one_line(*messages: str | None, tmp: Path | None = None, path: Path | None = None) -> str:
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


def _oiio_messages(oiio, obj=None, **names) -> str:
    """Retrieve -- and so clear -- the pending OpenImageIO errors of ``obj`` and of this thread.

    Retrieving them also keeps OpenImageIO from printing them on stderr at exit.
    """
    own = obj.geterror() if obj is not None else ""
    return _one_line(own, oiio.geterror(), **names)


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
def _libpng_quiet(path: Path) -> Iterator[None]:
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


def _oiio_open(oiio, path: Path):
    """Open ``path`` with OpenImageIO, or raise :class:`ImageReadError` naming it."""
    try:
        inp = oiio.ImageInput.open(str(path))
    except Exception as exc:  # the bindings raise for names they cannot pass on (bad UTF-8)
        raise ImageReadError(path, f"cannot read image: {_one_line(str(exc))}") from None
    if inp is None:
        problem = _oiio_messages(oiio) or "no reader for this file"
        raise ImageReadError(path, f"cannot read image: {problem}")
    oiio.geterror()  # drop what the readers tried before the right one left behind
    return inp


def _oiio_close(oiio, inp) -> None:
    """Close a reader and drop its pending messages (the pixels were already checked)."""
    inp.close()
    _oiio_messages(oiio, inp)


def _check_pixels(oiio, inp, data, path: Path) -> None:
    """Raise :class:`ImageReadError` unless a read gave pixels and no error."""
    problem = _oiio_messages(oiio, inp)
    if data is None or problem:
        raise ImageReadError(path, "truncated or corrupt image data "
                                   f"({problem or 'OpenImageIO gave no pixels'})")


def _oiio_header(path: Path) -> ImageHeader:
    oiio = _oiio()
    inp = _oiio_open(oiio, path)
    try:
        return _header_from_spec(path, inp.spec(), inp.format_name())
    finally:
        _oiio_close(oiio, inp)


def _header_from_spec(path: Path, spec, format_name: str) -> ImageHeader:
    dtype = np.dtype(_dtype_from_typedesc(spec.format, path))
    bits = spec.get_int_attribute("oiio:BitsPerSample", 0) or dtype.itemsize * 8
    attrs = {a.name: a.value for a in spec.extra_attribs
             if isinstance(a.value, (str, int, float))}
    # EXIF stores ExposureTime as a RATIONAL; a plugin may hand it on as (num, den) or "1/250"
    exposure = _exposure_seconds(spec.getattribute("ExposureTime"))
    gain = _float_or_none(attrs.get("Exif:Gain", attrs.get("Gain")))
    return ImageHeader(path=path, width=spec.width, height=spec.height,
                       channels=spec.nchannels, dtype=dtype, bits=int(bits),
                       layout=_LAYOUTS.get(spec.nchannels, f"{spec.nchannels}-channel"),
                       exposure=exposure, gain=gain, temperature=None,
                       format=format_name, attributes=attrs)


def _dtype_from_typedesc(td, path: Path | None = None) -> str:
    name = str(td)
    table = {"uint8": "uint8", "int8": "int8", "uint16": "uint16", "int16": "int16",
             "uint": "uint32", "uint32": "uint32", "int": "int32", "int32": "int32",
             "half": "float16", "float": "float32", "double": "float64"}
    if name not in table:
        raise ImageReadError(path, f"unsupported sample type {name}")
    return table[name]


def _read_oiio(path: Path, header: ImageHeader) -> np.ndarray:
    oiio = _oiio()
    inp = _oiio_open(oiio, path)
    try:
        data = inp.read_image(format=oiio.UNKNOWN)
        _check_pixels(oiio, inp, data, path)
    finally:
        _oiio_close(oiio, inp)
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


def _read_oiio_region(path: Path, header: ImageHeader, box, limit: int) -> np.ndarray:
    oiio = _oiio()
    inp = _oiio_open(oiio, path)
    try:
        spec = inp.spec()
        read = _read_oiio_tiles if spec.tile_width else _read_oiio_rows
        data, (dx, dy) = read(oiio, inp, spec, box, path, limit)
        _check_pixels(oiio, inp, data, path)
    finally:
        _oiio_close(oiio, inp)
    _, _, w, h = box
    data = np.asarray(data)
    if data.ndim == 4:  # (depth, rows, columns, channels) of a volume image: its first slice
        data = data[0]
    return np.ascontiguousarray(data[dy:dy + h, dx:dx + w]).astype(header.dtype, copy=False)


# ---- FITS -----------------------------------------------------------------------------------
def _fits_hdu(path: Path):
    """Open a FITS file and return ``(hdul, hdu)`` for the first HDU holding an image."""
    from astropy.io import fits

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            hdul = fits.open(path, memmap=False, lazy_load_hdus=False)
    except Exception as exc:  # astropy raises OSError/ValueError/TypeError for bad files
        raise ImageReadError(path, f"cannot read FITS file: {_one_line(str(exc))}") from None
    for hdu in hdul:
        if getattr(hdu, "is_image", False) and _int_or(hdu.header.get("NAXIS"), 0) >= 2:
            return hdul, hdu
    hdul.close()
    raise ImageReadError(path, "FITS file holds no 2-D image")


def _fits_dtype(header, path: Path | None = None) -> np.dtype:
    bitpix = _int_or(header.get("BITPIX"), 0)
    bzero = header.get("BZERO", 0)
    bscale = header.get("BSCALE", 1)
    if bscale == 1 and bitpix == 16 and bzero == 32768:
        return np.dtype("uint16")
    if bscale == 1 and bitpix == 32 and bzero == 2**31:
        return np.dtype("uint32")
    if bscale == 1 and bitpix == 8:
        return np.dtype("uint8")
    table = {16: "int16", 32: "int32", 64: "int64", -32: "float32", -64: "float64"}
    if bitpix not in table and bitpix != 8:
        raise ImageReadError(path, f"FITS BITPIX = {header.get('BITPIX')!r} is not a FITS "
                                   "sample type")
    if bscale != 1 or bzero != 0:
        return np.dtype("float32")
    return np.dtype(table[bitpix])


def _fits_header(path: Path) -> ImageHeader:
    hdul, hdu = _fits_hdu(path)
    try:
        h = hdu.header
        naxis = _int_or(h.get("NAXIS"), 0)
        width, height = _int_or(h.get("NAXIS1"), 0), _int_or(h.get("NAXIS2"), 0)
        channels = _int_or(h.get("NAXIS3"), 0) if naxis >= 3 else 1
        dtype = _fits_dtype(h, path)
        exposure = _float_or_none(h.get("EXPTIME", h.get("EXPOSURE")))
        bits = _int_or(h.get("BITDEPTH", h.get("ADCBITS")), dtype.itemsize * 8)
        attrs = {k: v for k, v in h.items() if isinstance(v, (str, int, float)) and k}
        return ImageHeader(path=path, width=width, height=height, channels=channels, dtype=dtype,
                           bits=bits, layout=_LAYOUTS.get(channels, f"{channels}-channel"),
                           exposure=exposure, gain=_float_or_none(h.get("GAIN", h.get("EGAIN"))),
                           temperature=_float_or_none(h.get("CCD-TEMP", h.get("CCDTEMP"))),
                           format="fits", attributes=attrs)
    finally:
        hdul.close()


@contextlib.contextmanager
def _fits_data(path: Path) -> Iterator[None]:
    """Quietly read FITS pixels: any failure becomes one :class:`ImageReadError` naming ``path``."""
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            yield
    except CcdError:
        raise
    except Exception as exc:  # astropy/numpy raise many kinds for short or corrupt data
        raise ImageReadError(path, f"truncated or corrupt FITS data ({_one_line(str(exc))})"
                             ) from None


def _fits_to_hwc(data, header: ImageHeader) -> np.ndarray:
    data = np.asarray(data)
    if data.ndim == 3:  # FITS cubes are (C, H, W)
        data = np.moveaxis(data, 0, -1)
    return np.ascontiguousarray(data).astype(header.dtype, copy=False)


def _read_fits(path: Path, header: ImageHeader) -> np.ndarray:
    hdul, hdu = _fits_hdu(path)
    try:
        with _fits_data(path):
            return _fits_to_hwc(hdu.data, header)
    finally:
        hdul.close()


def _read_fits_region(path: Path, header: ImageHeader, box) -> np.ndarray:
    """Read ``box`` through astropy's ``section``, which reads only the rows it needs."""
    x, y, w, h = box
    hdul, hdu = _fits_hdu(path)
    try:
        lead = (slice(None),) * (_int_or(hdu.header.get("NAXIS"), 2) - 2)
        with _fits_data(path):
            return _fits_to_hwc(hdu.section[lead + (slice(y, y + h), slice(x, x + w))], header)
    finally:
        hdul.close()


# ---- camera raw -----------------------------------------------------------------------------
def _rawpy(path: Path):
    try:
        import rawpy
    except ImportError:
        raise MethodNotAvailable(path, "reading camera raw files needs the 'raw' extra: "
                                       "pip install 'ccdcore[raw]' (installs rawpy/LibRaw)") from None
    return rawpy


def _raw_open(path: Path):
    rawpy = _rawpy(path)
    try:
        return rawpy.imread(str(path))
    except Exception as exc:  # LibRawError subclasses
        raise ImageReadError(path, f"cannot read camera raw file: {_one_line(str(exc))}") from None


def _raw_pattern(raw) -> str:
    desc = raw.color_desc.decode() if isinstance(raw.color_desc, bytes) else str(raw.color_desc)
    pat = np.asarray(raw.raw_pattern)
    if pat.shape != (2, 2):
        return "cfa"
    letters = "".join(desc[int(i)] for i in pat.ravel()).lower()
    return f"bayer-{letters}" if sorted(letters) == ["b", "g", "g", "r"] else "cfa"


def _raw_header(path: Path) -> ImageHeader:
    with _raw_open(path) as raw:
        h, w = raw.raw_image_visible.shape
        white = int(getattr(raw, "white_level", 0) or 0)
        bits = max(int(white).bit_length(), 8) if white else 16
        layout = _raw_pattern(raw)
    exposure, attrs = None, {}
    with contextlib.suppress(Exception):  # EXIF of TIFF-based raws (DNG, NEF, CR2) via OIIO
        exif = _oiio_header(path)
        exposure = exif.exposure
        # the capture metadata (camera, ISO, aperture ...), not the container's (oiio:, tiff:)
        attrs = {k: v for k, v in exif.attributes.items()
                 if not k.startswith(("oiio:", "tiff:"))}
    return ImageHeader(path=path, width=w, height=h, channels=1, dtype=np.dtype("uint16"),
                       bits=bits, layout=layout, exposure=exposure, format="raw",
                       attributes=attrs)


def _read_raw(path: Path) -> np.ndarray:
    with _raw_open(path) as raw:
        try:
            return np.array(raw.raw_image_visible, dtype=np.uint16, copy=True)
        except Exception as exc:
            raise ImageReadError(path, f"cannot decode camera raw data: {_one_line(str(exc))}"
                                 ) from None


# ---- public readers -------------------------------------------------------------------------
def read_header(path: str | os.PathLike) -> ImageHeader:
    """Read what a file says about its pixels and capture, without reading the pixels.

    No pixel limit applies here: the header of a huge image can be listed; reading its pixels is
    what :data:`MAX_PIXELS` guards.

    Raises
    ------
    ImageReadError
        The file is missing, empty, of an unsupported type or not a readable image.
    """
    path = Path(path)
    _check_file(path)
    suffix = path.suffix.lower()
    if suffix in FITS_EXTENSIONS:
        return _fits_header(path)
    if suffix in RAW_EXTENSIONS:
        return _raw_header(path)
    with _libpng_quiet(path):
        return _oiio_header(path)


def _read_pixels(path: Path, header: ImageHeader) -> np.ndarray:
    suffix = path.suffix.lower()
    if suffix in FITS_EXTENSIONS:
        return _read_fits(path, header)
    if suffix in RAW_EXTENSIONS:
        return _read_raw(path)
    with _libpng_quiet(path):
        return _read_oiio(path, header)


def _checked(path: Path, data: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """``data`` with a single channel squeezed, once it has the ``shape`` the header promised."""
    if data.ndim == 3 and data.shape[2] == 1:
        data = data[:, :, 0]
    if data.shape != shape:
        raise ImageReadError(path, f"pixel data has shape {data.shape}, header says {shape}")
    if data.size == 0:
        raise ImageReadError(path, "image has no pixels")
    return data


def read_frame(path: str | os.PathLike, *,
               max_pixels: int | None = None) -> tuple[np.ndarray, ImageHeader]:
    """Read one frame and its header.

    Parameters
    ----------
    path
        The image file.
    max_pixels
        Refuse, before decoding, an image of more pixel values (width x height x channels) than
        this; ``None`` takes ``CCDCORE_MAX_PIXELS`` or :data:`MAX_PIXELS` (see
        :func:`pixel_limit`).

    Returns
    -------
    data
        ``(H, W)`` for one channel, ``(H, W, C)`` otherwise, in the stored dtype.
    header
        The :class:`ImageHeader` of the file.

    Raises
    ------
    ImageReadError
        Missing, empty, truncated, unreadable or too large file (the message names the file).
    """
    path = Path(path)
    limit = pixel_limit(max_pixels)
    header = read_header(path)
    check_pixel_limit(path, header.width, header.height, header.channels, limit)
    return _checked(path, _read_pixels(path, header), header.shape), header


def read_image(path: str | os.PathLike, *, max_pixels: int | None = None) -> np.ndarray:
    """Read one frame's pixels (see :func:`read_frame`, which takes the same arguments)."""
    return read_frame(path, max_pixels=max_pixels)[0]


def _region_box(path: Path, header: ImageHeader, x, y, width, height) -> tuple[int, int, int, int]:
    """``(x, y, width, height)`` as ints, once they are known to lie inside the image."""
    box = tuple(_whole_number(v) for v in (x, y, width, height))
    inside = (None not in box and box[0] >= 0 and box[1] >= 0 and box[2] >= 1 and box[3] >= 1
              and box[0] + box[2] <= header.width and box[1] + box[3] <= header.height)
    if not inside:
        raise ImageReadError(path, f"region x={x!r}, y={y!r}, width={width!r}, "
                                   f"height={height!r} is not inside the "
                                   f"{header.width}x{header.height} image")
    return box  # type: ignore[return-value]


def read_region(path: str | os.PathLike, x: int, y: int, width: int, height: int, *,
                max_pixels: int | None = None) -> np.ndarray:
    """Read the rectangle ``[y:y+height, x:x+width]`` of a frame without decoding all of it.

    Tiled TIFF/EXR files decode only the tiles the rectangle touches, scanline files only its rows
    (TIFF: the strips holding them), FITS only its rows (astropy ``section``). Camera raw files are
    decoded whole and cropped. The result equals ``read_image(path)[y:y+height, x:x+width]``.

    Parameters
    ----------
    path
        The image file.
    x, y
        Column and row of the rectangle's top-left pixel (0-based, from the image's top-left).
    width, height
        Size of the rectangle in pixels (at least 1; it must lie inside the image).
    max_pixels
        Refuse when what has to be decoded (the rectangle, or the rows/strips/tiles holding it)
        exceeds this many pixel values; ``None`` takes ``CCDCORE_MAX_PIXELS`` or
        :data:`MAX_PIXELS`.

    Returns
    -------
    numpy.ndarray
        ``(height, width)`` for one channel, ``(height, width, C)`` otherwise, in the stored dtype.

    Raises
    ------
    ImageReadError
        Unreadable, truncated or too large file, or a rectangle outside the image.
    """
    path = Path(path)
    limit = pixel_limit(max_pixels)
    header = read_header(path)
    box = _region_box(path, header, x, y, width, height)
    check_pixel_limit(path, box[2], box[3], header.channels, limit, what="the region is")
    x, y, w, h = box
    shape = (h, w) if header.channels == 1 else (h, w, header.channels)
    suffix = path.suffix.lower()
    if suffix in FITS_EXTENSIONS:
        return _checked(path, _read_fits_region(path, header, box), shape)
    if suffix in RAW_EXTENSIONS:
        check_pixel_limit(path, header.width, header.height, 1, limit,
                           what="a camera raw file is decoded whole; the image is")
        return _checked(path, _read_raw(path)[y:y + h, x:x + w], shape)
    with _libpng_quiet(path):
        return _checked(path, _read_oiio_region(path, header, box, limit), shape)


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------
def _os_problem(exc: OSError, tmp: Path | None = None, path: Path | None = None) -> str:
    """An OS error in words (``No space left on device``), naming the target, not the temp file."""
    return _one_line(exc.strerror or str(exc), tmp=tmp, path=path) or type(exc).__name__


def _free_bytes(folder: Path) -> int | None:
    """Bytes this process may still write in ``folder``'s file system (None: unknown): the
    blocks free to ordinary users, and for root also the blocks reserved for it."""
    try:
        st = os.statvfs(folder)
    except (OSError, AttributeError):  # no statvfs on Windows
        return None
    root = hasattr(os, "geteuid") and os.geteuid() == 0
    return (st.f_bfree if root else st.f_bavail) * st.f_frsize


def _new_temp(path: Path) -> Path:
    """Create an empty hidden temporary file beside ``path``, creating the folder if needed.

    A disk that is already full is refused here, before a writer is started on it.
    """
    try:
        if path.is_dir():
            raise ImageWriteError(path, "is a folder, not a file name")
        path.parent.mkdir(parents=True, exist_ok=True)
        free = _free_bytes(path.parent)
        if free is not None and free < _MIN_FREE_BYTES:
            raise ImageWriteError(path, f"the disk is full ({free:,} bytes free in "
                                        f"{path.parent}); nothing was written")
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}",
                                   dir=path.parent)
    except OSError as exc:
        raise ImageWriteError(path, f"cannot create a file in {path.parent}: "
                                    f"{_os_problem(exc)}") from None
    os.close(fd)
    return Path(tmp)


def _check_not_full(tmp: Path) -> None:
    """Raise ENOSPC when no space is left after a write: the writer may have lost data silently.

    OpenImageIO does not report every failed write (an OpenEXR or PNG file, or the metadata at the
    end of a TIFF file); a file system with no space left after the write is taken as one that
    refused some of it.
    """
    if _free_bytes(tmp.parent) == 0:
        raise OSError(errno.ENOSPC, "the disk became full while writing, the file may be "
                                    "incomplete")


def _sync_file(tmp: Path) -> None:
    """Flush ``tmp`` to the disk: a delayed write error (full disk, I/O error) is raised here."""
    fd = os.open(tmp, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _sync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable where the system allows it (best effort)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _discard(tmp: Path) -> None:
    with contextlib.suppress(OSError):
        tmp.unlink()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same extension); move it onto ``path`` on success.

    The parent folder is created; a disk that is already full is refused before the body runs. On
    success the temporary file is flushed to the disk (so that a full disk is noticed) and renamed
    onto ``path``; if no space is left by then, the file is taken as incomplete. If the body
    raises, or flushing or renaming fails, the temporary file is removed and ``path`` is left as
    it was.

    Raises
    ------
    ImageWriteError
        The file cannot be created, written, flushed or renamed (full disk, no permission, a
        folder in the way): the message names ``path`` and the system's reason. An
        :class:`OSError` raised by the body becomes this error too; other exceptions pass as they
        are.
    """
    path = Path(path)
    tmp = _new_temp(path)
    try:
        yield tmp
        os.chmod(tmp, 0o644)
        _sync_file(tmp)
        _check_not_full(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        _discard(tmp)
        raise ImageWriteError(path, f"cannot write the file: {_os_problem(exc, tmp, path)}"
                              ) from None
    except BaseException:
        _discard(tmp)
        raise
    _sync_folder(path.parent)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`).

    Raises
    ------
    ImageWriteError
        The bytes could not all be written and flushed; ``path`` keeps its previous content.
    """
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically (see :func:`atomic_write_bytes`)."""
    return atomic_write_bytes(path, text.encode("utf-8"))


# --------------------------------------------------------------------------------------------
# output sets: every write of a verb as one set, never over an input nor a special file
# --------------------------------------------------------------------------------------------
#: the prefix of the temporary folders an output set is written into (removed on failure, on
#: SIGTERM, and by the next write into the same folder once the process that made it is gone)
TEMP_PREFIX = ".ccdcore-tmp-"


def real_path(path: str | os.PathLike) -> Path:
    """``path`` absolute with every symlink resolved (what a write would really touch)."""
    return Path(os.path.abspath(path)).resolve()


def _not_regular(mode: int) -> str:
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISREG(mode):
        return "a file"
    return "a folder" if stat.S_ISDIR(mode) else "not a regular file"


def check_output(path: str | os.PathLike, *, folder: bool = False) -> None:
    """Refuse an output path that exists as something a write must not replace.

    A file output may be absent or a regular file (or a symlink to one: the link is replaced);
    a folder output may be absent or a folder. A FIFO, a device node or a socket -- or a
    symlink to one -- would otherwise be replaced by a regular file (or, for a FIFO, block).

    Raises
    ------
    CcdError
        Naming ``path`` and what it is.
    """
    path = Path(path)
    if not os.path.lexists(path):
        return
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return  # a dangling symlink: the link itself is replaced
    except OSError as exc:
        raise CcdError(path, f"cannot check the output: {exc.strerror}") from None
    wanted = stat.S_ISDIR(mode) if folder else stat.S_ISREG(mode)
    if not wanted:
        link = f"is a symlink to {os.path.realpath(path)}, which is" if path.is_symlink() \
            else "is"
        kind = "a folder" if folder else "a file"
        raise CcdError(path, f"{link} {_not_regular(mode)}, not {kind}; choose another -o")


def check_not_inputs(outputs: Iterable[str | os.PathLike],
                     inputs: Iterable[str | os.PathLike], *, contain: bool = True) -> None:
    """Refuse an output equal to, inside, or (``contain``) containing an input of the same run
    (resolved paths, so a symlink or ``..`` does not hide it): writing would destroy what is
    being read.

    Raises
    ------
    CcdError
        Naming the output and the input it would overwrite.
    """
    ins = [(Path(i), real_path(i)) for i in inputs]
    for out in outputs:
        o = real_path(out)
        for given, i in ins:
            if o == i:
                raise CcdError(out, "would overwrite an input of this run; choose another -o")
            if i in o.parents or (contain and o in i.parents):
                how = "is inside" if i in o.parents else "holds"
                raise CcdError(out, f"{how} {given}, an input of this run: writing there would "
                                    "overwrite an input; choose another -o")


def check_outputs(folder: str | os.PathLike, names: Iterable[str] | Mapping[str, bool],
                  inputs: Iterable[str | os.PathLike] = ()) -> None:
    """Check the outputs ``folder/name`` of a run before anything is computed or written:
    ``folder`` a folder (or absent) neither an input nor inside one, each output a regular
    file (a folder where ``names`` maps the name to ``True``) or absent, and none equal to,
    inside or containing an input (:func:`check_output`, :func:`check_not_inputs`).

    Raises
    ------
    CcdError
        Naming the output and the problem.
    """
    folder = Path(folder)
    inputs = list(inputs)
    check_output(folder, folder=True)
    check_not_inputs([folder], inputs, contain=False)
    kinds = names if isinstance(names, Mapping) else dict.fromkeys(names, False)
    for name, is_folder in kinds.items():
        check_output(folder / name, folder=is_folder)
    check_not_inputs([folder / n for n in kinds], inputs)


class _Terminated(BaseException):
    """SIGTERM while an output set is written: unwinds like KeyboardInterrupt so the temporary
    folder goes."""


def remove_stale_temporaries(folder: str | os.PathLike) -> None:
    """Remove the temporary folders killed writes left in ``folder`` (not those of live
    processes: their name ends with the writer's process id)."""
    for p in Path(folder).glob(f"{TEMP_PREFIX}*"):
        pid = p.name.rsplit("-", 1)[-1]
        if pid.isdigit() and int(pid) != os.getpid() and _alive(int(pid)):
            continue
        shutil.rmtree(p, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _renamed(err: CcdError, tmp: Path, folder: Path) -> CcdError:
    """``err`` naming ``folder`` where it named the internal temporary folder ``tmp``."""
    def fix(text: str | None) -> str | None:
        return None if text is None else text.replace(str(tmp), str(folder))

    cls = ImageWriteError if isinstance(err, ImageWriteError) else CcdError
    return cls(fix(err.where), fix(err.problem) or "")


def _swap_in(tmp: Path, folder: Path, last: str | None, replaces: Iterable[str]) -> None:
    """Move the entries of ``tmp`` into ``folder`` (or ``tmp`` onto ``folder`` when there is
    none yet); a folder entry replaces the earlier one whole; the entries ``replaces`` of the
    earlier set go even when not written again; ``last`` goes last, and its earlier version
    first (so ``folder`` is never a mix of two sets that ``last`` describes)."""
    if not folder.exists():
        os.chmod(tmp, 0o755)
        os.replace(tmp, folder)
        return
    names = sorted(n for n in os.listdir(tmp) if n != last)
    old = Path(tempfile.mkdtemp(prefix=f"{TEMP_PREFIX}old-", suffix=f"-{os.getpid()}",
                                dir=folder))
    if last is not None and os.path.lexists(folder / last):
        os.replace(folder / last, old / last)
    for name in replaces:
        if name != last and name not in names and os.path.lexists(folder / name):
            os.replace(folder / name, old / name)
    for name in names:
        dst = folder / name
        if (tmp / name).is_dir() and dst.is_dir() and not dst.is_symlink():
            os.replace(dst, old / name)
        os.replace(tmp / name, dst)
    if last is not None and os.path.lexists(tmp / last):
        os.replace(tmp / last, folder / last)
    shutil.rmtree(old, ignore_errors=True)
    shutil.rmtree(tmp, ignore_errors=True)
    _sync_folder(folder)


@contextlib.contextmanager
def output_set(folder: str | os.PathLike, *, inputs: Iterable[str | os.PathLike] = (),
               last: str | None = None, replaces: Iterable[str] = ()) -> Iterator[Path]:
    """Yield a temporary folder; what the body writes into it becomes part of ``folder`` as
    one set once the body is done.

    The one mechanism of every output (product saves, ``report``, ``apply``, ``hdr``,
    ``change``, ``simulate``): the body writes into a hidden ``.ccdcore-tmp-…-<pid>`` folder in
    ``folder`` (or beside it when ``folder`` does not exist yet, which then becomes it by one
    rename), so a full disk, an error, Ctrl+C or SIGTERM while writing leaves the earlier
    outputs untouched and removes the temporary folder; only then are the new entries renamed
    into ``folder`` (SIGTERM waits until the renames are done). Entries of ``folder`` the body
    did not write are left alone, except those named in ``replaces`` (the parts of an earlier
    set, removed); ``last`` is renamed in last (a description of the set). Leftovers of a killed process (SIGKILL) are removed by the
    next write into the same place.

    Before anything is written, each entry's target is checked (:func:`check_output`, and
    :func:`check_not_inputs` against ``inputs``); errors name ``folder``'s entries, never the
    temporary folder.

    Raises
    ------
    CcdError
        ``folder`` is not a folder, an output is a special file or an input, or writing failed
        (the message names the path the user gave and the system's reason).
    """
    folder = Path(os.path.abspath(folder))
    inputs = list(inputs)
    check_outputs(folder, (), inputs)
    home = folder if folder.is_dir() else folder.parent
    try:
        home.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(home)
        if home != folder.parent and folder.parent.is_dir():
            remove_stale_temporaries(folder.parent)
        tmp = Path(tempfile.mkdtemp(prefix=TEMP_PREFIX, suffix=f"-{os.getpid()}", dir=home))
    except OSError as exc:
        raise CcdError(folder, f"cannot write into the folder: {_os_problem(exc)}") from None
    state = {"defer": False, "pending": False}

    def on_term(signum: int, frame: Any) -> None:
        if state["defer"]:
            state["pending"] = True
        else:
            raise _Terminated()

    previous = None
    with contextlib.suppress(ValueError):  # not the main thread: signals cannot be handled here
        previous = signal.signal(signal.SIGTERM, on_term)
    try:
        try:
            yield tmp
            check_outputs(folder, {n: (tmp / n).is_dir() for n in os.listdir(tmp)}, inputs)
            state["defer"] = True
            _swap_in(tmp, folder, last, tuple(replaces))
        except _Terminated:
            raise SystemExit(128 + signal.SIGTERM) from None
        except CcdError as err:
            raise _renamed(err, tmp, folder) from None
        except OSError as exc:
            raise CcdError(folder, "cannot write the outputs: "
                                   f"{_os_problem(exc, tmp, folder)}") from None
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    if state["pending"]:
        raise SystemExit(128 + signal.SIGTERM)


def write_outputs(folder: str | os.PathLike, writers: Mapping[str, Callable[[Path], Any]], *,
                  inputs: Iterable[str | os.PathLike] = (), last: str | None = None
                  ) -> list[Path]:
    """Write the files ``name -> writer(path)`` into ``folder`` as one set (:func:`output_set`);
    the paths written, in ``folder``."""
    folder = Path(folder)
    with output_set(folder, inputs=inputs, last=last) as tmp:
        for name, writer in writers.items():
            writer(tmp / name)
    return [folder / name for name in writers]


def _as_hwc(array: np.ndarray, path: Path) -> np.ndarray:
    a = np.asarray(array)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[0] == 0 or a.shape[1] == 0 or not 1 <= a.shape[2] <= 4:
        raise ImageWriteError(path, f"cannot write an array of shape {np.shape(array)}; "
                                    "expected (H, W) or (H, W, C) with 1-4 channels")
    if a.dtype.kind not in "iuf":
        raise ImageWriteError(path, f"unsupported sample type {a.dtype}")
    return np.ascontiguousarray(a)


def _oiio_samples(path: Path, a: np.ndarray, suffix: str) -> np.ndarray:
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


def _oiio_spec(oiio, path: Path, a: np.ndarray, suffix: str, exposure, attributes):
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
                                        f"{_one_line(str(exc))}") from None
    return spec


def _oiio_step(oiio, out, ok: bool, what: str, tmp: Path, path: Path) -> None:
    """Raise :class:`ImageWriteError` unless an ImageOutput call succeeded and left no error.

    Both are looked at because OpenImageIO reports some failures only through ``geterror()``: on a
    full disk a PNG write returns True, and a TIFF close returns True after failing to write its
    directory. Messages in ``_OIIO_NOT_ERRORS`` are not taken as failures.
    """
    lines = [line for line in out.geterror().splitlines() if line.strip() not in _OIIO_NOT_ERRORS]
    own = _one_line(*lines, tmp=tmp, path=path)
    other = _oiio_messages(oiio, tmp=tmp, path=path)
    if not ok or own:
        raise ImageWriteError(path, f"{what}: {own or other or 'OpenImageIO gave no reason'}")


def _oiio_write(oiio, tmp: Path, path: Path, spec, a: np.ndarray) -> None:
    """Write ``a`` to ``tmp`` through OpenImageIO, checking open, write and close.

    ``write_image`` is never called after a failed ``open``: OpenImageIO 3.2 crashes on that.
    """
    out = oiio.ImageOutput.create(str(tmp))
    if out is None:
        problem = _oiio_messages(oiio, tmp=tmp, path=path) or "unknown format"
        raise ImageWriteError(path, f"no writer for this format: {problem}")
    try:
        _oiio_step(oiio, out, out.open(str(tmp), spec), "cannot create the file", tmp, path)
        _oiio_step(oiio, out, out.write_image(a), "cannot write the pixels", tmp, path)
    except BaseException:
        out.close()
        _oiio_messages(oiio, out)  # the first failure is the one reported
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
    with _libpng_quiet(tmp):
        inp = oiio.ImageInput.open(str(tmp))
        if inp is None:
            problem = _oiio_messages(oiio, tmp=tmp, path=path) or "unreadable"
            raise ImageWriteError(path, f"the written file does not read back ({problem}); "
                                        "is the disk full?")
        try:
            got = inp.spec()
            row = inp.read_scanlines(0, 0, got.y + got.height - 1, got.y + got.height, got.z,
                                     0, got.nchannels, oiio.UNKNOWN)
            problem = _oiio_messages(oiio, inp, tmp=tmp, path=path)
        finally:
            inp.close()
            _oiio_messages(oiio, inp)
    size = (got.width, got.height, got.nchannels)
    if row is None or problem or size != (spec.width, spec.height, spec.nchannels):
        raise ImageWriteError(path, "the written file does not read back "
                                    f"({problem or f'got {size[0]}x{size[1]}x{size[2]}'}); "
                                    "is the disk full?")


def write_image(path: str | os.PathLike, array: np.ndarray, *, exposure: float | None = None,
                bits: int | None = None, attributes: dict[str, Any] | None = None) -> Path:
    """Write a frame, keeping its sample type, atomically and with deterministic bytes.

    Parameters
    ----------
    path
        Output file; the format follows the extension: ``.tif``/``.tiff`` (any integer or float
        type), ``.png`` and ``.pgm``/``.ppm``/``.pnm`` (uint8, uint16), ``.fits`` (any; unsigned
        integers with the standard ``BZERO`` convention), ``.exr`` (float16/float32; integers are
        stored as float32, which is exact up to 2**24).
    array
        ``(H, W)`` or ``(H, W, C)``.
    exposure
        Exposure time in seconds, written as EXIF ``ExposureTime`` (TIFF, PNG, EXR) or ``EXPTIME``
        (FITS).
    bits
        Significant bits of the ADC (TIFF ``BitsPerSample`` stays the container width; FITS gets
        ``BITDEPTH``).
    attributes
        Extra header attributes (OpenImageIO names, or FITS keywords).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ImageWriteError
        The array cannot be stored in this format, or writing failed (full disk, no permission,
        an OpenImageIO or astropy error): the message names ``path``, which keeps its previous
        content, and no temporary file is left behind.
    """
    path = Path(path)
    a = _as_hwc(array, path)
    suffix = path.suffix.lower()
    if (a.dtype.kind == "f" and suffix not in (".exr", ".tif", ".tiff", ".fits")
            and not np.all(np.isfinite(a))):
        raise ImageWriteError(path, "non-finite values cannot be stored in this format")
    if suffix in FITS_EXTENSIONS:
        _write_fits(path, a, exposure=exposure, bits=bits, attributes=attributes)
        return path
    a = _oiio_samples(path, a, suffix)
    oiio = _oiio()
    spec = _oiio_spec(oiio, path, a, suffix, exposure, attributes)
    with atomic_path(path) as tmp:
        _oiio_write(oiio, tmp, path, spec, a)
    return path


def _fits_to_write(path: Path, a: np.ndarray, *, exposure, bits, attributes):
    """The FITS HDU for ``a`` and its keywords, or :class:`ImageWriteError`."""
    from astropy.io import fits

    data = a[:, :, 0] if a.shape[2] == 1 else np.moveaxis(a, -1, 0)
    if data.dtype == np.float16:
        data = data.astype(np.float32)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            hdu = fits.PrimaryHDU(np.ascontiguousarray(data))
            if exposure is not None:
                hdu.header["EXPTIME"] = (float(exposure), "exposure time [s]")
            if bits is not None:
                hdu.header["BITDEPTH"] = (int(bits), "significant ADC bits")
            for key, value in (attributes or {}).items():
                hdu.header[str(key)[:8].upper()] = value
    except Exception as exc:  # astropy raises ValueError/TypeError/KeyError for bad keywords
        raise ImageWriteError(path, f"cannot make the FITS header: {_one_line(str(exc))}"
                              ) from None
    return hdu


def _write_fits(path: Path, a: np.ndarray, *, exposure, bits, attributes) -> None:
    hdu = _fits_to_write(path, a, exposure=exposure, bits=bits, attributes=attributes)
    with atomic_path(path) as tmp:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                hdu.writeto(tmp, overwrite=True, output_verify="exception")
        except OSError:
            raise  # atomic_path names the target and the system's reason
        except Exception as exc:  # astropy's VerifyError and the like
            raise ImageWriteError(path, "cannot write FITS file: "
                                        f"{_one_line(str(exc), tmp=tmp, path=path)}") from None


def write_map(path: str | os.PathLike, array: np.ndarray) -> Path:
    """Write a float32 map as OpenEXR (``.exr``) or FITS (``.fits``), atomically.

    Reading it back with :func:`read_image` gives the same bits (EXR is written uncompressed-lossless
    ``zip``; NaNs and infinities are kept; values beyond float32 become infinities).

    Raises
    ------
    ImageWriteError
        Not ``.exr``/``.fits``, not a numeric array, or writing failed (see :func:`write_image`).
    """
    path = Path(path)
    if path.suffix.lower() not in {".exr"} | FITS_EXTENSIONS:
        raise ImageWriteError(path, "maps are written as .exr or .fits")
    a = np.asarray(array)
    if a.dtype.kind not in "fiub":
        raise ImageWriteError(path, f"cannot write a map of dtype {a.dtype}")
    with np.errstate(over="ignore"):
        a = a.astype(np.float32, copy=False)
    return write_image(path, a,
                       attributes={"compression": "zip"} if path.suffix.lower() == ".exr" else None)
