"""Channels of a frame: colour layouts, channel names and views, Bayer colour filter arrays.

The one home of everything that says which channels a frame has: the camera layouts of the
manifest (``mono``, ``rgb``, ``bayer-rggb`` ...), the channel names of each layout (``L``; ``R``,
``G``, ``B``; the four CFA planes ``R``, ``G1``, ``G2``, ``B``), views of each channel (no copies,
no interpolation), and the Bayer utilities (sampling, planes, bilinear demosaicing).  The session,
the estimators, the command line and the app all use it.

Bayer colour filter arrays
--------------------------

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
LAYOUTS
    The camera layouts of the manifest: ``mono``, ``rgb`` and the four ``bayer-<pattern>``.
is_bayer(layout)
    Whether a layout is a Bayer mosaic (the one test of it: never match the name's spelling).
CHANNEL_NAMES, channel_names(layout)
    Channel names per layout family.
check_layout(shape, layout, where), channel_slices(shape, layout), split_channels(image, layout)
    The layout of frames of a shape (checked), and each channel as a view.
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

from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import CcdError

__all__ = ["Layout", "LAYOUTS", "is_bayer", "CHANNEL_NAMES", "channel_names", "check_layout",
           "channel_slices", "split_channels", "PATTERNS", "PLANES", "check_pattern",
           "plane_offsets", "plane_masks", "channel_masks", "mosaic", "planes",
           "demosaic_bilinear"]

#: the four Bayer patterns, named by the top-left 2x2 cell read row by row
PATTERNS: tuple[str, ...] = ("rggb", "bggr", "grbg", "gbrg")

#: names of the four CFA planes; G1 is the green on the red row, G2 the green on the blue row
PLANES: tuple[str, ...] = ("R", "G1", "G2", "B")

class Layout(str, Enum):
    """The colour layouts of a camera (manifest key ``[camera] layout``): a string enum, so a
    layout compares equal to, and is written as, its name (``Layout.MONO == "mono"``)."""

    MONO = "mono"
    RGB = "rgb"
    BAYER_RGGB = "bayer-rggb"
    BAYER_BGGR = "bayer-bggr"
    BAYER_GRBG = "bayer-grbg"
    BAYER_GBRG = "bayer-gbrg"

    def __str__(self) -> str:
        return self.value


#: the Bayer mosaic layouts, one per pattern
_BAYER_LAYOUTS: tuple[str, ...] = tuple(f"bayer-{p}" for p in PATTERNS)

#: the names of :class:`Layout`, in order
LAYOUTS: tuple[str, ...] = tuple(m.value for m in Layout)

#: channel names per layout family
CHANNEL_NAMES: dict[str, tuple[str, ...]] = {"mono": ("L",), "rgb": ("R", "G", "B"),
                                             "bayer": PLANES}

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
    from scipy import ndimage

    arr = _check_raw(raw).astype(np.float64)
    red, green, blue = channel_masks(arr.shape, pattern)
    out = np.empty(arr.shape + (3,), dtype=np.float64)
    for i, (mask, kernel) in enumerate(((red, _KERNEL_RB), (green, _KERNEL_G),
                                        (blue, _KERNEL_RB))):
        sampled = np.where(mask, arr, 0.0)
        out[..., i] = ndimage.convolve(sampled, kernel, mode="mirror")
        out[..., i][mask] = arr[mask]
    return out


# --------------------------------------------------------------------------------------------
# layouts and channels
# --------------------------------------------------------------------------------------------
def _normal_layout(layout: str) -> str:
    if not isinstance(layout, str):
        raise CcdError("layout", f"expected a layout name, got {type(layout).__name__}")
    name = layout.strip().lower()
    if name in ("mono", "rgb"):
        return name
    return "bayer-" + check_pattern(name)


def is_bayer(layout: str) -> bool:
    """True when ``layout`` is a Bayer mosaic, False for ``mono`` and ``rgb``.

    Every Bayer layout of :data:`LAYOUTS` (``"bayer-rggb"``, ``"bayer-bggr"``, ``"bayer-grbg"``,
    ``"bayer-gbrg"``) is one, in any case, with surrounding spaces, or as the bare pattern
    (``"rggb"``), as :func:`channel_names` and :func:`check_layout` read them.  The one test of
    it: code never matches the spelling of a layout name.

    Raises
    ------
    CcdError
        ``layout`` is not a layout name (not a string, or none of :data:`LAYOUTS`).

    Examples
    --------
    >>> is_bayer("bayer-rggb"), is_bayer("mono"), is_bayer("rgb")
    (True, False, False)
    """
    return _normal_layout(layout) in _BAYER_LAYOUTS


def channel_names(layout: str) -> tuple[str, ...]:
    """``("L",)`` for mono, ``("R", "G", "B")`` for rgb, ``("R", "G1", "G2", "B")`` for Bayer."""
    name = _normal_layout(layout)
    return CHANNEL_NAMES["bayer" if is_bayer(name) else name]


def check_layout(shape: tuple[int, ...], layout: str | None, where: Any = "image") -> Layout:
    """Normalised layout (a :class:`Layout`) for frames of ``shape``; ``None`` infers mono
    (2-D) or rgb (H, W, 3).

    Raises
    ------
    CcdError
        The shape does not fit the layout (a colour frame for a mono or Bayer layout, a 2-D
        frame for rgb, odd Bayer dimensions ...).
    """
    shape = tuple(shape)
    if layout is None:
        if len(shape) == 2:
            return Layout.MONO
        if len(shape) == 3 and shape[2] == 3:
            return Layout.RGB
        raise CcdError(where, f"cannot tell the colour layout of frames of shape {shape}; "
                              "pass layout='mono', 'rgb' or 'bayer-rggb' ...")
    name = _normal_layout(layout)
    if name == Layout.RGB:
        if len(shape) != 3 or shape[2] != 3:
            raise CcdError(where, f"layout 'rgb' needs (H, W, 3) frames, got shape {shape}")
    elif len(shape) != 2:
        raise CcdError(where, f"layout '{name}' needs 2-D frames, got shape {shape}"
                              + (" (a colour image: use layout='rgb')" if len(shape) == 3 else ""))
    elif is_bayer(name) and (shape[0] % 2 or shape[1] % 2):
        raise CcdError(where, f"Bayer frames need even height and width, got {shape}")
    return Layout(name)


def channel_slices(shape: tuple[int, ...], layout: str | None) -> dict[str, tuple]:
    """Channel name -> index tuple giving that channel as a view: ``image[idx]``.

    mono: the whole frame; rgb: ``[:, :, c]``; Bayer: the plane ``[r::2, c::2]`` of each CFA site.
    """
    name = check_layout(shape, layout)
    full = slice(None)
    if name == Layout.MONO:
        return {"L": (full, full)}
    if name == Layout.RGB:
        return {c: (full, full, i) for i, c in enumerate(CHANNEL_NAMES["rgb"])}
    return {p: (slice(r, None, 2), slice(c, None, 2))
            for p, (r, c) in plane_offsets(name).items()}


def split_channels(image: ArrayLike, layout: str | None = None) -> dict[str, NDArray]:
    """Channel name -> view of ``image`` (see :func:`channel_slices`)."""
    arr = np.asarray(image)
    return {n: arr[idx] for n, idx in channel_slices(arr.shape, layout).items()}
