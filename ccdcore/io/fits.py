"""FITS through :mod:`astropy.io.fits` for :mod:`ccdcore.io.frames`: the header, the pixels whole
or a region's rows, and the HDU a write stores.

FITS goes through astropy rather than OpenImageIO because OpenImageIO's FITS plugin ignores
``BZERO``/``BSCALE``: the standard unsigned 16-bit FITS frame of astronomical cameras
(``BITPIX = 16``, ``BZERO = 32768``) would be read as signed and wrong.
"""
from __future__ import annotations

import contextlib
import math
import warnings
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..errors import CcdError, ImageReadError, ImageWriteError
from .base import LAYOUTS, ImageHeader, float_or_none, int_or, one_line

__all__ = ["fits_header", "fits_temperature", "read_fits", "read_fits_region", "fits_to_write"]


# ---- reading --------------------------------------------------------------------------------
def _fits_hdu(path: Path):
    """Open a FITS file and return ``(hdul, hdu)`` for the first HDU holding an image."""
    from astropy.io import fits

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            # the stored values: the scaling is applied here (_scaled), in the precision the
            # physical values need (astropy scales bytes and words in float32, where a BZERO of
            # 1e300 overflows to inf)
            hdul = fits.open(path, memmap=False, lazy_load_hdus=False,
                             do_not_scale_image_data=True)
    except Exception as exc:  # astropy raises OSError/ValueError/TypeError for bad files
        raise ImageReadError(path, f"cannot read FITS file: {one_line(str(exc))}") from None
    for hdu in hdul:
        if getattr(hdu, "is_image", False) and int_or(hdu.header.get("NAXIS"), 0) >= 2:
            return hdul, hdu
    hdul.close()
    raise ImageReadError(path, "FITS file holds no 2-D image")


def _fits_dtype(header, path: Path | None = None) -> np.dtype:
    """The sample type of the physical values ``BZERO + BSCALE · stored`` (FITS 4.0 sec. 4.4.2,
    the scaling astropy applies when it reads): the unsigned conventions (``BZERO`` 2^15, 2^31
    on signed words; -128 on bytes for signed) as integers, any other scaling as floats wide
    enough for its range (float64 beyond float32's, or for 32- and 64-bit words)."""
    bitpix = int_or(header.get("BITPIX"), 0)
    bzero = float_or_none(header.get("BZERO", 0))
    bscale = float_or_none(header.get("BSCALE", 1))
    if bzero is None or bscale is None or not (math.isfinite(bzero) and math.isfinite(bscale)) \
            or bscale == 0:
        raise ImageReadError(path, f"FITS BZERO = {header.get('BZERO')!r}, BSCALE = "
                                   f"{header.get('BSCALE')!r}: not a scaling of the stored "
                                   "values (finite, BSCALE non-zero)")
    table = {8: "uint8", 16: "int16", 32: "int32", 64: "int64", -32: "float32", -64: "float64"}
    if bitpix not in table:
        raise ImageReadError(path, f"FITS BITPIX = {header.get('BITPIX')!r} is not a FITS "
                                   "sample type")
    if bscale == 1:
        unsigned = {16: (2.0 ** 15, "uint16"), 32: (2.0 ** 31, "uint32"), 8: (-128.0, "int8")}
        if bitpix in unsigned and bzero == unsigned[bitpix][0]:
            return np.dtype(unsigned[bitpix][1])
        if bzero == 0:
            return np.dtype(table[bitpix])
    stored = 3.4e38 if bitpix < 0 else 2.0 ** bitpix
    reach = abs(bzero) + abs(bscale) * stored
    wide = reach > 3.0e38 or bitpix in (32, 64, -64)
    return np.dtype("float64" if wide else "float32")


def fits_temperature(h: Any) -> float | None:
    """The sensor temperature (°C) a FITS header states: the set point ``SET-TEMP`` when
    present (the temperature the camera regulates to, the same for every frame of a run), else
    the measured ``CCD-TEMP`` (or ``CCDTEMP``); the measured one stays in the header's
    attributes."""
    for key in ("SET-TEMP", "CCD-TEMP", "CCDTEMP"):
        t = float_or_none(h.get(key))
        if t is not None:
            return t
    return None


def fits_header(path: Path) -> ImageHeader:
    hdul, hdu = _fits_hdu(path)
    try:
        h = hdu.header
        naxis = int_or(h.get("NAXIS"), 0)
        width, height = int_or(h.get("NAXIS1"), 0), int_or(h.get("NAXIS2"), 0)
        channels = int_or(h.get("NAXIS3"), 0) if naxis >= 3 else 1
        dtype = _fits_dtype(h, path)
        exposure = float_or_none(h.get("EXPTIME", h.get("EXPOSURE")))
        bits = int_or(h.get("BITDEPTH", h.get("ADCBITS")), dtype.itemsize * 8)
        attrs = {k: v for k, v in h.items() if isinstance(v, (str, int, float)) and k}
        return ImageHeader(path=path, width=width, height=height, channels=channels, dtype=dtype,
                           bits=bits, layout=LAYOUTS.get(channels, f"{channels}-channel"),
                           exposure=exposure, gain=float_or_none(h.get("GAIN", h.get("EGAIN"))),
                           temperature=fits_temperature(h),
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
        raise ImageReadError(path, f"truncated or corrupt FITS data ({one_line(str(exc))})"
                             ) from None


def _scaled(raw: np.ndarray, fits_header: Any, dtype: np.dtype) -> np.ndarray:
    """The physical values ``BZERO + BSCALE · stored`` as ``dtype`` (:func:`_fits_dtype`):
    integer offsets in integers, anything else in float64 before the cast."""
    bzero = float(fits_header.get("BZERO", 0) or 0)
    bscale = float(fits_header.get("BSCALE", 1))
    if bscale == 1 and bzero == 0:
        return raw.astype(dtype, copy=False)
    if bscale == 1 and dtype.kind in "iu" and bzero == int(bzero):
        return (raw.astype(np.int64) + int(bzero)).astype(dtype)
    return (raw.astype(np.float64) * bscale + bzero).astype(dtype, copy=False)


def _fits_to_hwc(data, header: ImageHeader, fits_header: Any) -> np.ndarray:
    data = np.asarray(data)
    if data.ndim == 3:  # FITS cubes are (C, H, W)
        data = np.moveaxis(data, 0, -1)
    return np.ascontiguousarray(_scaled(data, fits_header, header.dtype))


def read_fits(path: Path, header: ImageHeader) -> np.ndarray:
    hdul, hdu = _fits_hdu(path)
    try:
        with _fits_data(path):
            return _fits_to_hwc(hdu.data, header, hdu.header)
    finally:
        hdul.close()


def read_fits_region(path: Path, header: ImageHeader, box) -> np.ndarray:
    """Read ``box`` through astropy's ``section``, which reads only the rows it needs."""
    x, y, w, h = box
    hdul, hdu = _fits_hdu(path)
    try:
        lead = (slice(None),) * (int_or(hdu.header.get("NAXIS"), 2) - 2)
        with _fits_data(path):
            return _fits_to_hwc(hdu.section[lead + (slice(y, y + h), slice(x, x + w))], header,
                                hdu.header)
    finally:
        hdul.close()


# ---- writing --------------------------------------------------------------------------------
def fits_to_write(path: Path, a: np.ndarray, *, exposure, bits, attributes):
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
        raise ImageWriteError(path, f"cannot make the FITS header: {one_line(str(exc))}"
                              ) from None
    return hdu
