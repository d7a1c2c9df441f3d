"""Bayer colour filter arrays: sampling, plane extraction and bilinear demosaicing.

A colour CCD samples one colour per site through a Bayer mosaic: "two rows in a Bayer pattern
consist of a sequence of alternating red/green filter elements in one row followed by alternating
green/blue filter elements in the subsequent row" (Tsin, Ramesh & Kanade 2001, sec. 2).  The
pattern name spells the top-left 2x2 cell row by row, e.g. ``"rggb"`` is ``R G / G B``.

The full-resolution colour image is obtained "by some form of interpolation (e.g. bilinear
interpolation)" (ibid., sec. 2, ref. [1]); :func:`demosaic_bilinear` is that standard bilinear
interpolation.  It is what makes neighbouring pixels of a colour image correlated, the effect the
correction factors 1.265 (green) and 1.333 (red, blue) of Tsin et al. sec. 3.1 account for.

Public objects
--------------
PATTERNS
    The four Bayer patterns, ``("rggb", "bggr", "grbg", "gbrg")``.
PLANES
    Names of the four CFA planes, ``("R", "G1", "G2", "B")``.
check_pattern(pattern)
    Normalise a pattern name (also accepts ``"bayer-rggb"``); raise :class:`CcdError` if unknown.
plane_offsets(pattern)
    ``{plane: (row, col)}`` offset of each plane inside the 2x2 cell.
plane_masks(shape, pattern)
    Boolean site masks of the four planes.
channel_masks(shape, pattern)
    Boolean site masks of the three colours R, G, B (G = G1 | G2).
mosaic(rgb, pattern)
    Sample an ``(H, W, 3)`` image on the mosaic, giving the ``(H, W)`` raw image.
planes(raw, pattern)
    The four half-resolution planes of a raw image (views, no interpolation).
demosaic_bilinear(raw, pattern)
    Bilinear interpolation to an ``(H, W, 3)`` float64 image, exact at sampled sites.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from .errors import CcdError

__all__ = ["PATTERNS", "PLANES", "check_pattern", "plane_offsets", "plane_masks", "channel_masks",
           "mosaic", "planes", "demosaic_bilinear"]

#: the four Bayer patterns, named by the top-left 2x2 cell read row by row
PATTERNS: tuple[str, ...] = ("rggb", "bggr", "grbg", "gbrg")

#: names of the four CFA planes; G1 is the green on the red row, G2 the green on the blue row
PLANES: tuple[str, ...] = ("R", "G1", "G2", "B")

# bilinear kernels (exact binary fractions, so sampled sites are reproduced bit-exactly)
_KERNEL_G = np.array([[0.0, 0.25, 0.0], [0.25, 1.0, 0.25], [0.0, 0.25, 0.0]])
_KERNEL_RB = np.array([[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]])


def check_pattern(pattern: str) -> str:
    """Return the normalised pattern name (lower case, ``"bayer-"`` prefix removed).

    Raises
    ------
    CcdError
        If ``pattern`` is not one of :data:`PATTERNS`.
    """
    if not isinstance(pattern, str):
        raise CcdError("pattern", f"expected a Bayer pattern name, got {type(pattern).__name__}")
    name = pattern.strip().lower()
    if name.startswith("bayer-"):
        name = name[len("bayer-"):]
    if name not in PATTERNS:
        raise CcdError("pattern", f"unknown Bayer pattern {pattern!r}; choose one of "
                                  f"{', '.join(PATTERNS)}")
    return name


def plane_offsets(pattern: str) -> dict[str, tuple[int, int]]:
    """Offsets ``(row, col)`` of the planes R, G1, G2, B inside the 2x2 Bayer cell.

    G1 is the green site sharing its row with red, G2 the green site sharing its row with blue.
    """
    name = check_pattern(pattern)
    cell = {(0, 0): name[0], (0, 1): name[1], (1, 0): name[2], (1, 1): name[3]}
    out: dict[str, tuple[int, int]] = {}
    red_row = next(rc[0] for rc, c in cell.items() if c == "r")
    for rc, c in cell.items():
        if c == "r":
            out["R"] = rc
        elif c == "b":
            out["B"] = rc
        else:
            out["G1" if rc[0] == red_row else "G2"] = rc
    return {k: out[k] for k in PLANES}


def _check_shape(shape: tuple[int, ...], where: str) -> tuple[int, int]:
    if len(shape) < 2:
        raise CcdError(where, f"expected an image of at least 2 dimensions, got shape {shape}")
    h, w = int(shape[0]), int(shape[1])
    if h < 2 or w < 2 or h % 2 or w % 2:
        raise CcdError(where, f"Bayer images need even height and width >= 2, got {h}x{w} (HxW)")
    return h, w


def plane_masks(shape: tuple[int, ...], pattern: str) -> dict[str, NDArray[np.bool_]]:
    """Boolean ``(H, W)`` masks of the sites of each CFA plane R, G1, G2, B.

    Parameters
    ----------
    shape
        Image shape; only the first two entries (even height and width) are used.
    pattern
        One of :data:`PATTERNS`.
    """
    h, w = _check_shape(tuple(shape), "shape")
    masks: dict[str, NDArray[np.bool_]] = {}
    for name, (r, c) in plane_offsets(pattern).items():
        m = np.zeros((h, w), dtype=bool)
        m[r::2, c::2] = True
        masks[name] = m
    return masks


def channel_masks(shape: tuple[int, ...], pattern: str) -> tuple[NDArray[np.bool_], ...]:
    """Boolean ``(H, W)`` masks of the red, green and blue sites (green = G1 | G2)."""
    m = plane_masks(shape, pattern)
    return m["R"], m["G1"] | m["G2"], m["B"]


def mosaic(rgb: ArrayLike, pattern: str) -> NDArray:
    """Sample a colour image through the Bayer filter array.

    Parameters
    ----------
    rgb
        ``(H, W, 3)`` image, channels in R, G, B order, any dtype; H and W even.
    pattern
        One of :data:`PATTERNS`.

    Returns
    -------
    ndarray
        ``(H, W)`` raw image of the same dtype: each site keeps the channel its filter passes.
    """
    arr = np.asarray(rgb)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise CcdError("rgb", f"expected an (H, W, 3) colour image, got shape {arr.shape}")
    h, w = _check_shape(arr.shape, "rgb")
    raw = np.empty((h, w), dtype=arr.dtype)
    chan = {"R": 0, "G1": 1, "G2": 1, "B": 2}
    for name, (r, c) in plane_offsets(pattern).items():
        raw[r::2, c::2] = arr[r::2, c::2, chan[name]]
    return raw


def _check_raw(raw: ArrayLike) -> NDArray:
    arr = np.asarray(raw)
    if arr.ndim != 2:
        raise CcdError("raw", f"expected a 2-D Bayer raw image, got shape {arr.shape}")
    _check_shape(arr.shape, "raw")
    return arr


def planes(raw: ArrayLike, pattern: str) -> dict[str, NDArray]:
    """The four CFA planes of a raw image, without interpolation.

    Parameters
    ----------
    raw
        ``(H, W)`` Bayer raw image, H and W even.
    pattern
        One of :data:`PATTERNS`.

    Returns
    -------
    dict
        ``{"R", "G1", "G2", "B"}`` -> ``(H/2, W/2)`` strided views into ``raw`` (when ``raw`` is an
        ndarray; copy them before writing to them).
    """
    arr = _check_raw(raw)
    return {name: arr[r::2, c::2] for name, (r, c) in plane_offsets(pattern).items()}


def demosaic_bilinear(raw: ArrayLike, pattern: str) -> NDArray[np.float64]:
    """Bilinear demosaicing of a Bayer raw image (Tsin et al. 2001, sec. 2, ref. [1]).

    Green at a red or blue site is the mean of its four edge neighbours; red (blue) at a green
    site is the mean of its two red (blue) neighbours and at a blue (red) site the mean of its four
    diagonal neighbours.  Sampled sites keep their value exactly.  The borders use mirror
    extension, which keeps the Bayer phase, so a constant image is reproduced everywhere and a
    linear ramp everywhere except the outermost row and column.

    Parameters
    ----------
    raw
        ``(H, W)`` raw image, H and W even; any real dtype.
    pattern
        One of :data:`PATTERNS`.

    Returns
    -------
    ndarray
        ``(H, W, 3)`` float64 image, channels R, G, B.
    """
    arr = _check_raw(raw).astype(np.float64)
    red, green, blue = channel_masks(arr.shape, pattern)
    out = np.empty(arr.shape + (3,), dtype=np.float64)
    for i, (mask, kernel) in enumerate(((red, _KERNEL_RB), (green, _KERNEL_G),
                                        (blue, _KERNEL_RB))):
        sampled = np.where(mask, arr, 0.0)
        out[..., i] = ndimage.convolve(sampled, kernel, mode="mirror")
        out[..., i][mask] = arr[mask]
    return out
