"""The pixel limit of :mod:`ccdcore.io.frames`: the largest image a read decodes unless told
otherwise (:data:`MAX_PIXELS`, the environment variable :data:`MAX_PIXELS_ENV`), checked with the
header's numbers before any pixel is decoded. Re-exported by :mod:`ccdcore.io.frames`."""
from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Any

from ..errors import CcdError, ImageReadError

__all__ = ["MAX_PIXELS", "MAX_PIXELS_ENV", "pixel_limit", "check_pixel_limit", "whole_number"]


#: Largest image :func:`read_image`, :func:`read_frame` and :func:`read_region` decode unless told
#: otherwise, counted in pixel values: width x height x channels. 2**30 (1.07 G values) lets every
#: single-shot sensor through (a 151 MP medium-format or a 16k x 16k scientific frame as raw/mono,
#: RGB or RGBA; a 240 MP pixel-shift RGB composite) while a 40000 x 40000 "decompression bomb" is
#: refused; the largest image allowed takes 2 GiB as uint16 and 8 GiB once a caller makes it
#: float64, which still fits the 24 GiB machines this project targets.
MAX_PIXELS = 2**30
#: Environment variable that overrides :data:`MAX_PIXELS` (a positive whole number).
MAX_PIXELS_ENV = "CCDCORE_MAX_PIXELS"


# ---- the pixel limit ------------------------------------------------------------------------
def whole_number(value: Any) -> int | None:
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
    limit = whole_number(value)
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
