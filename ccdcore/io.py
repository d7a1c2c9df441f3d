"""Reading and writing image frames and float32 maps, keeping digital numbers as captured.

Public objects
--------------
:class:`ImageHeader`
    What a file says about its pixels (size, channels, stored dtype, bit depth, layout) and its
    capture metadata (exposure time, gain, temperature) without reading the pixels.
:func:`read_header`, :func:`read_image`, :func:`read_frame`
    Read a frame through OpenImageIO (TIFF, OpenEXR, PNG, PNM, ...), FITS through astropy, camera
    raw (DNG, CR2, NEF, ...) through rawpy (optional ``raw`` extra) as undemosaiced CFA data.
:func:`write_image`, :func:`write_map`
    Atomic writes (temporary file in the same folder, then rename) with deterministic bytes.
:func:`atomic_path`, :func:`atomic_write_text`, :func:`atomic_write_bytes`
    The atomic-write building blocks.

Policy: integers stay integers of the stored width (no rescaling to [0, 1], no gamma); a single
channel comes back as a 2-D ``(H, W)`` array, several as ``(H, W, C)``.

FITS goes through :mod:`astropy.io.fits` rather than OpenImageIO because OpenImageIO's FITS plugin
ignores ``BZERO``/``BSCALE``: the standard unsigned 16-bit FITS frame of astronomical cameras
(``BITPIX = 16``, ``BZERO = 32768``) would be read as signed and wrong.
"""
from __future__ import annotations

import contextlib
import os
import tempfile
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from .errors import ImageReadError, ImageWriteError, MethodNotAvailable

__all__ = [
    "ImageHeader", "read_header", "read_image", "read_frame", "write_image", "write_map",
    "atomic_path", "atomic_write_text", "atomic_write_bytes", "IMAGE_EXTENSIONS",
    "RAW_EXTENSIONS", "FITS_EXTENSIONS", "is_image_path",
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
    except (TypeError, ValueError):
        return None
    return v if np.isfinite(v) else None


def _float32_value(value: Any) -> float | None:
    """A header number stored as float32 (TIFF/EXR EXIF), given back as its shortest decimal.

    EXIF ``ExposureTime`` goes through a 32-bit float, so 0.01 s reads as 0.009999999776...; the
    shortest decimal that maps to the same float32 (``0.01``) is what the camera wrote.
    """
    v = _float_or_none(value)
    return None if v is None else float(np.format_float_positional(np.float32(v), unique=True))


def _oiio():
    import OpenImageIO as oiio  # imported lazily: it is heavy and only needed for I/O

    return oiio


def _oiio_error(oiio, inp=None) -> str:
    msg = (inp.geterror() if inp is not None else "") or oiio.geterror() or "unreadable image"
    return " ".join(msg.split())


def _oiio_header(path: Path) -> ImageHeader:
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ImageReadError(path, f"cannot read image: {_oiio_error(oiio)}")
    try:
        spec = inp.spec()
        dtype = np.dtype(_dtype_from_typedesc(spec.format))
        bits = spec.get_int_attribute("oiio:BitsPerSample", 0) or dtype.itemsize * 8
        attrs = {a.name: a.value for a in spec.extra_attribs
                 if isinstance(a.value, (str, int, float))}
        exposure = _float32_value(attrs.get("ExposureTime"))
        gain = _float_or_none(attrs.get("Exif:Gain", attrs.get("Gain")))
        return ImageHeader(path=path, width=spec.width, height=spec.height,
                           channels=spec.nchannels, dtype=dtype, bits=int(bits),
                           layout=_LAYOUTS.get(spec.nchannels, f"{spec.nchannels}-channel"),
                           exposure=exposure, gain=gain, temperature=None,
                           format=inp.format_name(), attributes=attrs)
    finally:
        inp.close()


def _dtype_from_typedesc(td) -> str:
    name = str(td)
    table = {"uint8": "uint8", "int8": "int8", "uint16": "uint16", "int16": "int16",
             "uint": "uint32", "uint32": "uint32", "int": "int32", "int32": "int32",
             "half": "float16", "float": "float32", "double": "float64"}
    if name not in table:
        raise ImageReadError(None, f"unsupported sample type {name}")
    return table[name]


def _fits_hdu(path: Path):
    """Open a FITS file and return ``(hdul, hdu)`` for the first HDU holding an image."""
    from astropy.io import fits

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            hdul = fits.open(path, memmap=False, lazy_load_hdus=False)
    except Exception as exc:  # astropy raises OSError/ValueError/TypeError for bad files
        raise ImageReadError(path, f"cannot read FITS file: {exc}") from None
    for hdu in hdul:
        if getattr(hdu, "is_image", False) and hdu.header.get("NAXIS", 0) >= 2:
            return hdul, hdu
    hdul.close()
    raise ImageReadError(path, "FITS file holds no 2-D image")


def _fits_dtype(header) -> np.dtype:
    bitpix = int(header["BITPIX"])
    bzero = header.get("BZERO", 0)
    bscale = header.get("BSCALE", 1)
    if bscale == 1 and bitpix == 16 and bzero == 32768:
        return np.dtype("uint16")
    if bscale == 1 and bitpix == 32 and bzero == 2**31:
        return np.dtype("uint32")
    if bscale == 1 and bitpix == 8:
        return np.dtype("uint8")
    if bscale != 1 or bzero != 0:
        return np.dtype("float32")
    return np.dtype({16: "int16", 32: "int32", 64: "int64", -32: "float32", -64: "float64"}[bitpix])


def _fits_header(path: Path) -> ImageHeader:
    hdul, hdu = _fits_hdu(path)
    try:
        h = hdu.header
        naxis = int(h["NAXIS"])
        width, height = int(h["NAXIS1"]), int(h["NAXIS2"])
        channels = int(h["NAXIS3"]) if naxis >= 3 else 1
        dtype = _fits_dtype(h)
        exposure = _float_or_none(h.get("EXPTIME", h.get("EXPOSURE")))
        bits = int(h.get("BITDEPTH", h.get("ADCBITS", dtype.itemsize * 8)))
        attrs = {k: v for k, v in h.items() if isinstance(v, (str, int, float)) and k}
        return ImageHeader(path=path, width=width, height=height, channels=channels, dtype=dtype,
                           bits=bits, layout=_LAYOUTS.get(channels, f"{channels}-channel"),
                           exposure=exposure, gain=_float_or_none(h.get("GAIN", h.get("EGAIN"))),
                           temperature=_float_or_none(h.get("CCD-TEMP", h.get("CCDTEMP"))),
                           format="fits", attributes=attrs)
    finally:
        hdul.close()


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
        raise ImageReadError(path, f"cannot read camera raw file: {exc}") from None


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
    exposure = None
    with contextlib.suppress(Exception):  # EXIF of TIFF-based raws (DNG, NEF, CR2) via OIIO
        exposure = _oiio_header(path).exposure
    return ImageHeader(path=path, width=w, height=h, channels=1, dtype=np.dtype("uint16"),
                       bits=bits, layout=layout, exposure=exposure, format="raw")


def read_header(path: str | os.PathLike) -> ImageHeader:
    """Read what a file says about its pixels and capture, without reading the pixels.

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
    return _oiio_header(path)


def read_frame(path: str | os.PathLike) -> tuple[np.ndarray, ImageHeader]:
    """Read one frame and its header.

    Returns
    -------
    data
        ``(H, W)`` for one channel, ``(H, W, C)`` otherwise, in the stored dtype.
    header
        The :class:`ImageHeader` of the file.

    Raises
    ------
    ImageReadError
        Missing, empty, truncated or unreadable file (the message names the file).
    """
    path = Path(path)
    header = read_header(path)
    suffix = path.suffix.lower()
    if suffix in FITS_EXTENSIONS:
        data = _read_fits(path, header)
    elif suffix in RAW_EXTENSIONS:
        with _raw_open(path) as raw:
            try:
                data = np.array(raw.raw_image_visible, dtype=np.uint16, copy=True)
            except Exception as exc:
                raise ImageReadError(path, f"cannot decode camera raw data: {exc}") from None
    else:
        data = _read_oiio(path, header)
    if data.ndim == 3 and data.shape[2] == 1:
        data = data[:, :, 0]
    if data.shape != header.shape:
        raise ImageReadError(path, f"pixel data has shape {data.shape}, header says {header.shape}")
    if data.size == 0:
        raise ImageReadError(path, "image has no pixels")
    return data, header


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read one frame's pixels (see :func:`read_frame`)."""
    return read_frame(path)[0]


def _read_oiio(path: Path, header: ImageHeader) -> np.ndarray:
    oiio = _oiio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ImageReadError(path, f"cannot read image: {_oiio_error(oiio)}")
    try:
        data = inp.read_image(format=oiio.UNKNOWN)
        err = inp.geterror()
    finally:
        inp.close()
    if data is None or (err and "truncat" in err.lower()) or err:
        detail = " ".join((err or "no pixel data").split())
        raise ImageReadError(path, f"truncated or corrupt image data ({detail})")
    return np.ascontiguousarray(data).astype(header.dtype, copy=False)


def _read_fits(path: Path, header: ImageHeader) -> np.ndarray:
    hdul, hdu = _fits_hdu(path)
    try:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                data = np.asarray(hdu.data)
        except Exception as exc:
            raise ImageReadError(path, f"truncated or corrupt FITS data ({exc})") from None
        if data.ndim == 3:  # FITS cubes are (C, H, W)
            data = np.moveaxis(data, 0, -1)
        return np.ascontiguousarray(data).astype(header.dtype, copy=False)
    finally:
        hdul.close()


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------
@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same extension); rename it onto ``path`` on success.

    The parent folder is created. If the body raises, the temporary file is removed and ``path`` is
    left as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}",
                               dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o644)
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def _as_hwc(array: np.ndarray, path: Path) -> np.ndarray:
    a = np.asarray(array)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[0] == 0 or a.shape[1] == 0 or not 1 <= a.shape[2] <= 4:
        raise ImageWriteError(path, f"cannot write an array of shape {np.shape(array)}; "
                                    "expected (H, W) or (H, W, C) with 1-4 channels")
    return np.ascontiguousarray(a)


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
    """
    path = Path(path)
    a = _as_hwc(array, path)
    suffix = path.suffix.lower()
    if not np.all(np.isfinite(a)) and a.dtype.kind == "f" and suffix not in (".exr", ".tif", ".tiff", ".fits"):
        raise ImageWriteError(path, "non-finite values cannot be stored in this format")
    if suffix in FITS_EXTENSIONS:
        _write_fits(path, a, exposure=exposure, bits=bits, attributes=attributes)
        return path
    if suffix not in OIIO_EXTENSIONS:
        raise ImageWriteError(path, f"cannot write '{suffix}' files; use .tif, .png, .pgm, .exr or .fits")
    if suffix == ".exr" and a.dtype not in (np.float16, np.float32):
        a = a.astype(np.float32)
    if suffix in (".png", ".pgm", ".ppm", ".pnm") and a.dtype not in (np.uint8, np.uint16):
        raise ImageWriteError(path, f"{suffix} stores only uint8 or uint16 samples, got {a.dtype}")
    if str(a.dtype) not in _OIIO_TYPES:
        raise ImageWriteError(path, f"unsupported sample type {a.dtype}")
    oiio = _oiio()
    spec = oiio.ImageSpec(a.shape[1], a.shape[0], a.shape[2], _OIIO_TYPES[str(a.dtype)])
    if suffix in (".tif", ".tiff", ".exr"):
        spec.attribute("DateTime", _FIXED_DATETIME)
        spec.attribute("compression", "zip")
    if exposure is not None and suffix not in (".pgm", ".ppm", ".pnm"):
        spec.attribute("ExposureTime", float(exposure))
    for key, value in (attributes or {}).items():
        spec.attribute(key, value)
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise ImageWriteError(path, f"no writer: {_oiio_error(oiio)}")
        ok = out.open(str(tmp), spec) and out.write_image(a)
        err = out.geterror()
        out.close()
        if not ok:
            raise ImageWriteError(path, f"cannot write image: {' '.join(err.split())}")
    return path


def _write_fits(path: Path, a: np.ndarray, *, exposure, bits, attributes) -> None:
    from astropy.io import fits

    data = a[:, :, 0] if a.shape[2] == 1 else np.moveaxis(a, -1, 0)
    if data.dtype == np.float16:
        data = data.astype(np.float32)
    hdu = fits.PrimaryHDU(np.ascontiguousarray(data))
    if exposure is not None:
        hdu.header["EXPTIME"] = (float(exposure), "exposure time [s]")
    if bits is not None:
        hdu.header["BITDEPTH"] = (int(bits), "significant ADC bits")
    for key, value in (attributes or {}).items():
        hdu.header[str(key)[:8].upper()] = value
    with atomic_path(path) as tmp:
        hdu.writeto(tmp, overwrite=True, output_verify="exception")


def write_map(path: str | os.PathLike, array: np.ndarray) -> Path:
    """Write a float32 map as OpenEXR (``.exr``) or FITS (``.fits``), atomically.

    Reading it back with :func:`read_image` gives the same bits (EXR is written uncompressed-lossless
    ``zip``; NaNs and infinities are kept).
    """
    path = Path(path)
    if path.suffix.lower() not in {".exr"} | FITS_EXTENSIONS:
        raise ImageWriteError(path, "maps are written as .exr or .fits")
    a = np.asarray(array)
    if a.dtype.kind not in "fiub":
        raise ImageWriteError(path, f"cannot write a map of dtype {a.dtype}")
    return write_image(path, a.astype(np.float32, copy=False),
                       attributes={"compression": "zip"} if path.suffix.lower() == ".exr" else None)
