"""Pure plot-building functions for the app (no widgets, no state).

Every function takes arrays and options and returns arrays or plain numbers, so the plotting
pipeline is tested without a browser and the page classes stay thin; the pages draw images with
:class:`ccdcore_app.image_view.ImageView`.

Public objects
--------------
LUMINANCE, LUMINANCE_WEIGHTS
    The name (``"L"``) and Rec. 709 weights of the luminance a colour frame also offers.
frame_layout(shape, layout=None)
    The colour layout a preview reads a frame with: the camera's when the frame fits it, else
    the one its shape shows (:func:`ccdcore.channels.check_layout`).
channel_planes(array, layout=None)
    The channel choices of a frame and their 2-D planes: none for mono, the CFA planes ``R``,
    ``G1``, ``G2``, ``B`` for Bayer, ``R``, ``G``, ``B`` and the luminance ``L`` for colour
    (:func:`ccdcore.channels.split_channels`).
channel_data(array, channel=None, layout=None)
    One 2-D plane of a frame: a channel, the luminance, or the frame itself when mono.
auto_clim(values, lower=0.5, upper=99.5)
    Colour range from percentiles of the finite values (:mod:`ccdcore_report.scales`, shared
    with the report).
subsample(values)
    A regular subsample of at most a million values (for percentiles and medians; from
    :mod:`ccdcore_report.scales`).
histogram_edges(values, bins=256)
    Bin edges for a frame's histogram (one bin per DN for small integer ranges).
histogram_counts(values, bins=256)
    Counts and edges of a plane's finite values.
OVERVIEWS, with_note(title, note), overview(plane, x_range, y_range, width, height, how=...,
centre=0.0)
    How a zoomed-out map reduces the pixels under a screen pixel (extreme, mean, max), and
    that reduction of the visible part of a map (one compiled pass, :func:`load_kernels`).
visible_span(rng, n), block_factor(cols, rows, width, height), block_reduce(plane, f, how=...)
    The pixels an axis range overlaps; the block size fitting pixels into screen pixels; the
    reduction of f × f blocks (shared by :func:`overview` and the tiled previews of
    :mod:`ccdcore_app.tiles`).
load_kernels(dtypes=None)
    Compile or load the reduction's kernels ahead of the first zoom.
frame_size(shape, frame_width, max_frame_height=560)
    The size of a plot frame giving square pixels.
"""
from __future__ import annotations

from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from ccdcore.channels import check_layout, split_channels
from ccdcore.errors import CcdError
from ccdcore_report.scales import auto_clim, subsample

__all__ = ["LUMINANCE", "LUMINANCE_WEIGHTS", "frame_layout", "channel_planes", "channel_data",
           "auto_clim", "histogram_edges", "histogram_counts", "OVERVIEWS", "overview",
           "visible_span", "block_factor", "block_reduce", "frame_size", "subsample"]

#: the name of the luminance plane a colour frame also offers
LUMINANCE = "L"

#: Rec. 709 luminance weights applied to linear R, G, B digital numbers
LUMINANCE_WEIGHTS: tuple[float, float, float] = (0.2126, 0.7152, 0.0722)


def frame_layout(shape: tuple[int, ...], layout: str | None = None) -> str:
    """The layout a preview reads a frame of ``shape`` with (one of ``ccdcore.channels.LAYOUTS``).

    The camera's ``layout`` when the frame fits it; otherwise (a colour scene in a mono session,
    odd sizes on a Bayer camera) the layout the shape shows: ``mono`` for ``(H, W)`` and
    ``(H, W, 1)``, ``rgb`` for ``(H, W, C >= 3)`` (channels past the third are ignored).

    Raises
    ------
    ValueError
        The shape is no image (not 2-D, nor ``(H, W, C)`` with C = 1 or C >= 3).
    """
    shape = tuple(int(n) for n in shape)
    if layout is not None:
        try:
            return check_layout(shape, layout)
        except CcdError:
            pass
    if len(shape) == 2 or (len(shape) == 3 and shape[2] == 1):
        return "mono"
    if len(shape) == 3 and shape[2] >= 3:
        return "rgb"
    raise ValueError(f"array: expected (H, W) or (H, W, C) frame, got shape {shape}")


def _luminance(rgb: NDArray) -> NDArray:
    w = np.asarray(LUMINANCE_WEIGHTS, dtype=np.float32)
    return rgb[:, :, :3].astype(np.float32) @ w


def channel_planes(array: NDArray, layout: str | None = None) -> dict[str, NDArray]:
    """The channel choices of a frame, name -> 2-D plane (views, as stored; ``L`` is float32).

    ``{}`` for a mono frame (the frame itself is shown); the four CFA planes ``R``, ``G1``,
    ``G2``, ``B`` (half size, :func:`ccdcore.channels.split_channels`) for a Bayer frame;
    ``R``, ``G``, ``B`` and the Rec. 709 luminance ``L`` of the linear digital numbers for a
    colour frame. ``layout`` is the camera's (see :func:`frame_layout`).
    """
    name = frame_layout(array.shape, layout)
    if name == "mono":
        return {}
    if name == "rgb":
        planes = split_channels(array[:, :, :3], "rgb")
        return {**planes, LUMINANCE: _luminance(array)}
    return split_channels(array, name)


def channel_data(array: NDArray, channel: str | None = None,
                 layout: str | None = None) -> NDArray:
    """Return one 2-D plane of a frame.

    Parameters
    ----------
    array
        A frame, ``(H, W)`` or ``(H, W, C)``, dtype as stored.
    channel
        One of :func:`channel_planes`' names; ``None`` means ``"L"`` for colour frames and the
        first CFA plane for Bayer frames. Ignored for mono frames.
    layout
        The camera's colour layout (see :func:`frame_layout`); ``None`` reads the shape.

    Returns
    -------
    numpy.ndarray
        ``(H, W)`` plane (``(H/2, W/2)`` for a CFA plane).
    """
    planes = channel_planes(array, layout)
    if not planes:
        return array if array.ndim == 2 else array[:, :, 0]
    if channel is None:
        channel = LUMINANCE if LUMINANCE in planes else next(iter(planes))
    if channel not in planes:
        raise ValueError(f"channel: expected one of {', '.join(planes)}, got {channel!r}")
    return planes[channel]


#: how a zoomed-out map view reduces the map pixels under one screen pixel (name -> what the
#: title says): a mean hides a single hot pixel or a pixel-scale pattern, the extreme keeps it
OVERVIEWS: dict[str, str] = {
    "extreme": "extreme pixel",   # the pixel of the block farthest from the map's centre
    "mean": "mean",
    "max": "largest",
}


def with_note(title: str, note: str) -> str:
    """``title · note``, or the note alone under an empty title (never a leading "·")."""
    return f"{title} \u00b7 {note}" if title else note


def overview(plane: NDArray, x_range: tuple[float, float] | None,
             y_range: tuple[float, float] | None, width: int | None, height: int | None, *,
             how: str = "extreme", centre: float = 0.0
             ) -> tuple[NDArray, tuple[float, float, float, float], int]:
    """The visible part of ``plane`` reduced to at most ``width`` × ``height`` screen pixels.

    Pixel ``(row, col)`` is centred on ``(x, y) = (col, row)`` (row 0 at the top). The
    columns and rows that ``x_range``, ``y_range`` (``None``: all) overlap are cut out (at
    least one); when they are more than the screen pixels, square blocks of ``f`` × ``f`` map
    pixels (``f`` the smallest integer that fits) become one value each:

    * ``"extreme"`` -- the pixel farthest from ``centre`` (its own value, sign kept), so one
      deviating pixel stays visible at any zoom and the colour scale keeps its meaning;
    * ``"mean"`` -- the mean of the block's finite pixels;
    * ``"max"`` -- the largest value (counts, flags).

    Non-finite pixels are ignored (a block of only NaN stays NaN); blocks at the edges may be
    partial. Returns the reduced array (rows as in the map), its bounds ``(left, bottom, right,
    top)`` in pixel coordinates (edges of the pixels it covers), and ``f`` (1: every pixel).
    """
    if how not in OVERVIEWS:
        raise ValueError(f"how: expected one of {', '.join(OVERVIEWS)}, got {how!r}")
    h, w = plane.shape
    c0, c1 = visible_span(x_range, w)
    r0, r1 = visible_span(y_range, h)
    crop = plane[r0:r1, c0:c1]
    f = block_factor(c1 - c0, r1 - r0, width, height)
    if f == 1:
        return crop, (c0 - 0.5, r0 - 0.5, c1 - 0.5, r1 - 0.5), 1
    nh, nw = -(-(r1 - r0) // f), -(-(c1 - c0) // f)
    out = block_reduce(crop, f, how=how, centre=centre)
    return out, (c0 - 0.5, r0 - 0.5, c0 - 0.5 + nw * f, r0 - 0.5 + nh * f), f


def block_reduce(plane: NDArray, f: int, *, how: str = "mean", centre: float = 0.0) -> NDArray:
    """Blocks of ``f`` × ``f`` pixels of ``plane`` (partial at the right and bottom edges) to
    one float64 value each, non-finite pixels skipped, as :func:`overview` reduces them."""
    if plane.dtype == np.bool_:
        plane = plane.view(np.uint8)
    elif plane.dtype not in _KERNEL_DTYPES:      # one compiled kernel per dtype: the common ones
        plane = plane.astype(np.float64)
    return _reduce_blocks(np.ascontiguousarray(plane), int(f), _MODES[how], float(centre))


def visible_span(rng: tuple[float, float] | None, n: int) -> tuple[int, int]:
    """The pixels ``first:last`` of ``n`` (centres at 0 .. n-1) that the axis range ``rng``
    overlaps (at least one; ``None`` or a non-finite range: all)."""
    if rng is None or not all(np.isfinite(rng)):
        return 0, n
    lo, hi = sorted(float(v) for v in rng)
    first = min(max(int(np.floor(lo - 0.5)) + 1, 0), n - 1)   # c + 1/2 > lo
    last = min(max(int(np.ceil(hi + 0.5)), first + 1), n)      # c - 1/2 < hi
    return first, last


def block_factor(cols: int, rows: int, width: int | None, height: int | None) -> int:
    """The smallest block size ``f`` that fits ``cols`` × ``rows`` pixels in ``width`` ×
    ``height`` screen pixels (``None``: no limit)."""
    return max(1, int(np.ceil(max(cols / max(width or cols, 1), rows / max(height or rows, 1)))))


#: the kernel's code for each reduction
_MODES = {"mean": 0, "max": 1, "extreme": 2}
#: the dtypes the kernel reads as they are (compiled once each, cached on disk); others are
#: converted to float64 first
_KERNEL_DTYPES = tuple(np.dtype(t) for t in (np.uint8, np.uint16, np.int32, np.int64,
                                             np.float32, np.float64))


@numba.njit(cache=True, nogil=True)
def _reduce_blocks(crop, f, mode, centre):  # pragma: no cover (compiled)
    """Blocks of ``f`` × ``f`` pixels of ``crop`` (partial at the right and bottom edges) to one
    value each, skipping non-finite pixels: their mean (``mode`` 0), largest value (1), or the
    pixel farthest from ``centre`` (2; the first in row-major order on a tie). A block without a
    finite pixel is NaN. One pass over the pixels, no copy of the crop."""
    h, w = crop.shape
    nh, nw = (h + f - 1) // f, (w + f - 1) // f
    out = np.empty((nh, nw), np.float64)
    for i in range(nh):
        for j in range(nw):
            total, count, best, pick = 0.0, 0, -np.inf, np.nan
            for r in range(i * f, min(i * f + f, h)):
                for c in range(j * f, min(j * f + f, w)):
                    v = float(crop[r, c])
                    if not np.isfinite(v):
                        continue
                    count += 1
                    if mode == 0:
                        total += v
                    elif mode == 1:
                        if v > best:
                            best = v
                    else:
                        d = abs(v - centre)
                        if d > best:
                            best, pick = d, v
            if count == 0:
                out[i, j] = np.nan
            elif mode == 0:
                out[i, j] = total / count
            elif mode == 1:
                out[i, j] = best
            else:
                out[i, j] = pick
    return out


def load_kernels(dtypes: tuple[Any, ...] | None = None) -> None:
    """Compile (first run on a machine) or load from the disk cache the block-reduction kernel
    for ``dtypes`` (default: every dtype it reads as is), so no zoom waits for it."""
    for dtype in dtypes or _KERNEL_DTYPES:
        overview(np.zeros((4, 4), dtype), None, None, 2, 2, how="mean")


def frame_size(shape: tuple[float, float], frame_width: int, max_frame_height: int = 560
               ) -> tuple[int, int]:
    """``(width, height)`` of a plot frame showing an ``(H, W)`` plane with square pixels:
    ``frame_width`` wide, narrower when it would be taller than ``max_frame_height``."""
    h, w = float(shape[0]), float(shape[1])
    ratio = h / max(w, 1e-9)
    width = min(float(frame_width), max_frame_height / max(ratio, 1e-9))
    return max(int(round(width)), 1), max(int(round(width * ratio)), 1)


def histogram_edges(values: NDArray, bins: int = 256) -> NDArray:
    """Bin edges for the histogram of ``values``.

    Integer data spanning at most ``bins`` DN get one bin per DN (edges at half-integers), so no
    bin mixes neighbouring codes; otherwise ``bins`` equal bins over the finite range.
    """
    sample = np.ravel(values)
    if sample.dtype.kind == "f":
        sample = sample[np.isfinite(sample)]
    if sample.size == 0:
        return np.linspace(0.0, 1.0, bins + 1)
    lo, hi = float(sample.min()), float(sample.max())
    if sample.dtype.kind in "iub" and hi - lo + 1 <= bins:
        return np.arange(lo - 0.5, hi + 1.5, 1.0)
    if not hi > lo:
        lo, hi = lo - 0.5, hi + 0.5
    return np.linspace(lo, hi, bins + 1)


def histogram_counts(values: NDArray, bins: int = 256) -> tuple[NDArray, NDArray]:
    """``(counts, edges)`` of the finite values of a plane, binned by :func:`histogram_edges`."""
    flat = np.ravel(values)
    if flat.dtype.kind == "f":
        flat = flat[np.isfinite(flat)]
    return np.histogram(flat, bins=histogram_edges(flat, bins))
