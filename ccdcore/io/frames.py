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

The parts live in sibling modules and are all importable from here: :mod:`ccdcore.io.base`
(extensions, :class:`ImageHeader`, header values), :mod:`ccdcore.io.limits` (the pixel limit),
:mod:`ccdcore.io.oiio` and :mod:`ccdcore.io.oiio_write` (OpenImageIO reading and writing),
:mod:`ccdcore.io.fits` (FITS) and :mod:`ccdcore.io.outputs` (output sets). The readers, camera
raw, the atomic writes and the writers stay here.
"""
from __future__ import annotations

import contextlib
import errno
import os
import tempfile
import warnings
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from . import base as io_base
from ..errors import ImageReadError, ImageWriteError, MethodNotAvailable
from .base import (FITS_EXTENSIONS, IMAGE_EXTENSIONS, RAW_EXTENSIONS, ImageHeader, check_file,
                      exposure_seconds, is_image_path, one_line, os_problem, sync_folder)
from .fits import fits_header, fits_to_write, read_fits, read_fits_region
from .limits import MAX_PIXELS, MAX_PIXELS_ENV, check_pixel_limit, pixel_limit, whole_number
from .oiio import (header_from_spec, libpng_quiet, oiio_close, oiio_module, oiio_open,
                      read_oiio, read_oiio_region)
from .oiio_write import oiio_samples, oiio_spec, oiio_write
from .outputs import (RECORD, TEMP_PREFIX, check_not_inputs, check_output, check_outputs,
                         output_set, ownership_problem, read_record, real_path,
                         remove_stale_temporaries, write_outputs)

__all__ = [
    "ImageHeader", "read_header", "read_image", "read_frame", "read_region", "write_image",
    "write_map", "atomic_path", "atomic_write_text", "atomic_write_bytes", "IMAGE_EXTENSIONS",
    "RAW_EXTENSIONS", "FITS_EXTENSIONS", "is_image_path", "MAX_PIXELS", "MAX_PIXELS_ENV",
           "check_pixel_limit",
    "pixel_limit", "TEMP_PREFIX", "RECORD", "read_record", "ownership_problem", "output_set",
    "write_outputs", "check_output", "check_outputs",
    "check_not_inputs", "real_path", "remove_stale_temporaries",
]

#: the extensions read through OpenImageIO (not in ``__all__``; defined in
#: :mod:`ccdcore.io.base`)
OIIO_EXTENSIONS = io_base.OIIO_EXTENSIONS
# the former private name, still importable from here
_exposure_seconds = exposure_seconds
# A write is not started with less free space than this in the target's folder.
_MIN_FREE_BYTES = 1 << 20


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
# _oiio_header, the camera raw readers, _read_pixels, _free_bytes and the atomic writes stay in
# this module: what replaces ccdcore.io.frames._oiio_header, ._raw_open, ._read_pixels,
# ._free_bytes or
# .open (tests do) reaches every caller, since the callers look those names up here.
def _oiio_header(path: Path) -> ImageHeader:
    oiio = oiio_module()
    inp = oiio_open(oiio, path)
    try:
        return header_from_spec(path, inp.spec(), inp.format_name())
    finally:
        oiio_close(oiio, inp)


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
        raise ImageReadError(path, f"cannot read camera raw file: {one_line(str(exc))}") from None


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
            raise ImageReadError(path, f"cannot decode camera raw data: {one_line(str(exc))}"
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
    check_file(path)
    suffix = path.suffix.lower()
    if suffix in FITS_EXTENSIONS:
        return fits_header(path)
    if suffix in RAW_EXTENSIONS:
        return _raw_header(path)
    with libpng_quiet(path):
        return _oiio_header(path)


def _read_pixels(path: Path, header: ImageHeader) -> np.ndarray:
    suffix = path.suffix.lower()
    if suffix in FITS_EXTENSIONS:
        return read_fits(path, header)
    if suffix in RAW_EXTENSIONS:
        return _read_raw(path)
    with libpng_quiet(path):
        return read_oiio(path, header)


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
    """Read one frame's pixels (see :func:`read_frame`, which takes the same arguments).

    Parameters
    ----------
    path : str or os.PathLike
        The image file.
    max_pixels : int or None, optional
        Refuse, before decoding, an image of more pixel values (width x height x channels) than
        this; ``None`` takes ``CCDCORE_MAX_PIXELS`` or :data:`MAX_PIXELS` (see
        :func:`pixel_limit`).

    Returns
    -------
    numpy.ndarray
        The pixels: ``(H, W)`` for one channel, ``(H, W, C)`` otherwise, in the stored dtype.

    Raises
    ------
    ImageReadError
        Missing, empty, truncated, unreadable, unsupported or too large file (the message names
        the file); a :class:`~ccdcore.errors.CcdError`.
    CcdError
        ``max_pixels`` or ``CCDCORE_MAX_PIXELS`` is not a positive whole number; a camera raw
        file without the ``raw`` extra installed (:class:`~ccdcore.errors.MethodNotAvailable`).

    Examples
    --------
    >>> import tempfile, numpy as np
    >>> from pathlib import Path
    >>> tmp = tempfile.TemporaryDirectory()
    >>> frame = np.arange(12, dtype=np.uint16).reshape(3, 4)
    >>> path = write_image(Path(tmp.name) / "frame.tif", frame)
    >>> back = read_image(path)
    >>> back.dtype, back.shape, bool((back == frame).all())
    (dtype('uint16'), (3, 4), True)
    >>> tmp.cleanup()
    """
    return read_frame(path, max_pixels=max_pixels)[0]


def _region_box(path: Path, header: ImageHeader, x, y, width, height) -> tuple[int, int, int, int]:
    """``(x, y, width, height)`` as ints, once they are known to lie inside the image."""
    box = tuple(whole_number(v) for v in (x, y, width, height))
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
        return _checked(path, read_fits_region(path, header, box), shape)
    if suffix in RAW_EXTENSIONS:
        check_pixel_limit(path, header.width, header.height, 1, limit,
                           what="a camera raw file is decoded whole; the image is")
        return _checked(path, _read_raw(path)[y:y + h, x:x + w], shape)
    with libpng_quiet(path):
        return _checked(path, read_oiio_region(path, header, box, limit), shape)


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------
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
                                    f"{os_problem(exc)}") from None
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
        raise ImageWriteError(path, f"cannot write the file: {os_problem(exc, tmp, path)}"
                              ) from None
    except BaseException:
        _discard(tmp)
        raise
    sync_folder(path.parent)


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


def write_image(path: str | os.PathLike, array: np.ndarray, *, exposure: float | None = None,
                bits: int | None = None, attributes: dict[str, Any] | None = None) -> Path:
    """Write a frame, keeping its sample type, atomically and with deterministic bytes.

    Parameters
    ----------
    path : str or os.PathLike
        Output file; the format follows the extension: ``.tif``/``.tiff`` (any integer or float
        type), ``.png`` and ``.pgm``/``.ppm``/``.pnm`` (uint8, uint16), ``.fits`` (any; unsigned
        integers with the standard ``BZERO`` convention), ``.exr`` (float16/float32; integers are
        stored as float32, which is exact up to 2**24).
    array : numpy.ndarray
        ``(H, W)`` or ``(H, W, C)``.
    exposure : float or None, optional
        Exposure time in seconds, written as EXIF ``ExposureTime`` (TIFF, PNG, EXR) or ``EXPTIME``
        (FITS).
    bits : int or None, optional
        Significant bits of the ADC (TIFF ``BitsPerSample`` stays the container width; FITS gets
        ``BITDEPTH``).
    attributes : dict of str to Any, or None, optional
        Extra header attributes (OpenImageIO names, or FITS keywords).

    Returns
    -------
    pathlib.Path
        ``path``, the file written.

    Raises
    ------
    ImageWriteError
        The array cannot be stored in this format, or writing failed (full disk, no permission,
        an OpenImageIO or astropy error): the message names ``path``, which keeps its previous
        content, and no temporary file is left behind; a :class:`~ccdcore.errors.CcdError`.

    Examples
    --------
    >>> import tempfile, numpy as np
    >>> from pathlib import Path
    >>> tmp = tempfile.TemporaryDirectory()
    >>> path = write_image(Path(tmp.name) / "dark.tif", np.full((2, 3), 7, np.uint8), exposure=0.5)
    >>> read_header(path).exposure, read_image(path).tolist()
    (0.5, [[7, 7, 7], [7, 7, 7]])
    >>> tmp.cleanup()
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
    a = oiio_samples(path, a, suffix)
    oiio = oiio_module()
    spec = oiio_spec(oiio, path, a, suffix, exposure, attributes)
    with atomic_path(path) as tmp:
        oiio_write(oiio, tmp, path, spec, a)
    return path


def _write_fits(path: Path, a: np.ndarray, *, exposure, bits, attributes) -> None:
    hdu = fits_to_write(path, a, exposure=exposure, bits=bits, attributes=attributes)
    with atomic_path(path) as tmp:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                hdu.writeto(tmp, overwrite=True, output_verify="exception")
        except OSError:
            raise  # atomic_path names the target and the system's reason
        except Exception as exc:  # astropy's VerifyError and the like
            raise ImageWriteError(path, "cannot write FITS file: "
                                        f"{one_line(str(exc), tmp=tmp, path=path)}") from None


def write_map(path: str | os.PathLike, array: np.ndarray) -> Path:
    """Write a float32 map as OpenEXR (``.exr``) or FITS (``.fits``), atomically.

    Reading it back with :func:`read_image` gives the same bits (EXR is written
    uncompressed-lossless ``zip``; NaNs and infinities are kept; values beyond float32 become
    infinities).

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
