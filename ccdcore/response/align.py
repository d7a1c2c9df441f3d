"""Registration of a hand-held exposure bracket: each frame's shift and small rotation onto a
reference frame, measured across exposures, and the resampling that applies it.

A bracket shot without a tripod is not registered: every frame is shifted (and slightly rotated)
relative to the others, and the response estimate and the HDR merge compare the codes of one
scene point across the frames. The frames differ in exposure -- each is an unknown monotone tone
curve of radiance × exposure time, clipped at 0 and at the top code -- so their codes cannot be
compared directly. The method:

1. **Exposure-invariant images.** Each frame's luminance (the sum of its channels) is replaced by
   its rank: the fraction of the frame's pixels below it (ties counted half), i.e. its histogram
   equalisation. Any monotone tone curve and any exposure leave the rank image unchanged except
   where codes are clipped (the idea of Ward's median threshold bitmap, kept at every grey level
   instead of one: Ward 2003, "Fast, robust image registration for compositing high dynamic
   range photographs from hand-held exposures", J. Graphics Tools 8(2)). Clipped pixels (a
   channel at the top code, or every channel at 0) carry no position. For each pair (reference,
   frame) both rank images are clamped to the ranks unclipped in both, ``[lo, hi]``: ``lo`` the
   larger of the two fractions clipped dark, ``hi`` one minus the larger fraction clipped
   bright, and clipped pixels set to the clamp. A pixel clipped in either frame is then flat in
   both images -- weight 0 for a phase correlation, which sees only structure -- without the
   step a zero-weight mask would cut at the clipping contour: such a mask, shared by both
   tiles, pulls the correlation peak towards the current estimate, and one per frame leaves too
   few clear peaks in a mostly clipped frame (docs/align.md). A tile where fewer than a third of
   the pixels are unclipped in both frames is not measured; this plays the part of Ward's
   exclusion bitmap.
2. **Coarse shift.** A copy block-averaged to at most :data:`COARSE_SIDE` pixels on its long side
   is phase-correlated as a whole (Hann window): the global translation to about one coarse
   pixel, whatever its size.
3. **Tiles and a rigid fit.** The image is cut into a grid of square tiles (4 × 4 to 8 × 8, of
   :data:`TILE_MIN` to :data:`TILE_MAX` pixels). For each tile the frame is resampled (cubic
   spline) through the current transform and phase-correlated with the reference tile (Kuglin &
   Hines 1975, "The phase correlation image alignment method"; Hann window, Gaussian low-pass of
   the normalised cross-power spectrum); the peak is located to 1/:data:`UPSAMPLE` pixel by a
   matrix-multiply DFT upsampled around it (Guizar-Sicairos, Thurman & Fienup 2008, "Efficient
   subpixel image registration algorithms", Opt. Lett. 33(2)) and a parabola through the
   upsampled maximum. Tiles whose peak stands less than :data:`PEAK_MIN` times the surface's RMS
   above it have no clear peak. A rigid transform (rotation + translation) is fitted to the tile
   centres and their measured positions in closed form (2-D Procrustes), with iterative trimming
   of tiles beyond 3.5 robust sigmas; the errors of the translation and the rotation are the
   residual scatter of the tiles carried through the least-squares covariance σ² (JᵀJ)⁻¹ (σ
   floored at 0.02 pixel per tile, the resolution of the peak fit). The loop (measure, fit)
   runs on the coarse copy until the fit moves the tiles less than 0.05 coarse pixel, then on
   full-resolution tiles cropped from the frame until it moves them less than 0.1 pixel (the
   tiles' last residual shifts are then a tenth of a pixel at most, where the peak fit is
   unbiased). A rotation within 4 sigma of zero (or moving no corner by 0.25 px) is reported and applied as 0 (the translation
   is refitted without it).
4. **Verdict.** A frame is left out (``registered=False``, with the reason) when fewer than
   :data:`MIN_TILES` tiles have a clear peak, when the clear tiles disagree (fewer than
   :data:`MIN_TILES` of them, or not half, fit one rigid transform, or their scatter exceeds a
   pixel), or when the shift exceeds ``max_shift`` of the smaller image side.

Convention (pixel centres at integers, x to the right along columns, y down along rows, centre
``c = ((W - 1) / 2, (H - 1) / 2)``): the scene point at ``p = (x, y)`` of the reference lies at

    p' = c + R(θ) (p - c) + (dx, dy),   R(θ) = [[cos θ, -sin θ], [sin θ, cos θ]]

of the frame, and :func:`apply_alignment` returns ``aligned(p) = frame(p')``. For a pure shift,
``aligned(x, y) = frame(x + dx, y + dy)``: a frame whose content moved by (+3, -2) pixels (right
and up) against the reference has ``dx = +3, dy = -2``. θ is in degrees; positive turns the
x axis towards the y axis, i.e. the frame's content is turned clockwise as displayed (y down)
against the reference.

Public objects
--------------
FrameShift
    One frame's shift and rotation onto the reference, their 1-sigma errors, whether it could
    be registered (and why not), whether :func:`apply_alignment` resamples it.
Alignment
    The reference and every frame's :class:`FrameShift`, with ``describe()`` and ``to_dict()``.
estimate_alignment(frames, names, reference=None, *, max_shift=0.1, levels=None)
    The registration of a bracket's frames (numpy arrays) onto its reference frame.
apply_alignment(frames, alignment)
    The aligned frames (bilinear resampling, same dtype) and the mask of the pixels valid in
    every one of them.
"""
from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from typing import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy import fft as sfft
from scipy import ndimage
from threadpoolctl import threadpool_limits

from ..errors import CcdError

__all__ = ["FrameShift", "Alignment", "estimate_alignment", "apply_alignment", "COARSE_SIDE",
           "TILE_MIN", "TILE_MAX", "PEAK_MIN", "MIN_TILES", "UPSAMPLE"]

#: longest side of the block-averaged copy the coarse shift is measured on
COARSE_SIDE = 1024
#: smallest and largest tile side (pixels) of the sub-pixel measurement
TILE_MIN, TILE_MAX = 32, 256
#: a tile's phase-correlation peak is clear when it stands this many RMS above the surface
PEAK_MIN = 8.0
#: fewest tiles with a clear, consistent peak a frame is registered with
MIN_TILES = 4
#: upsampling factor of the DFT around a correlation peak (Guizar-Sicairos et al. 2008)
UPSAMPLE = 20
#: fewest unclipped pixels (fraction, in both frames) a tile is measured with
_MIN_VALID = 1.0 / 3.0
#: per-tile measurement error floor (pixels): the resolution of the peak fit
_TILE_FLOOR = 0.02
#: Gaussian low-pass of the cross-power spectrum (cycles per pixel)
_LOWPASS = 0.1
#: the measure-and-fit loop of a level stops when the fit moves the tiles less than this (level
#: pixels): the coarse level only seeds the full-resolution tiles, whose phase correlation is
#: unbiased to well below 0.01 pixel at residual shifts of a tenth of a pixel
_CONVERGED = (0.05, 0.1)
#: a shift is applied when beyond this many pixels (and 4 sigma): registered brackets of the
#: camera simulator (tone curve, vignetting, Bayer, sharpening, JPEG) show shifts of up to
#: 0.17 px and rotations of 0.04 degree between exposures, 5-10 of their stated errors (the
#: rank images of a clipped, tone-mapped frame are not the reference's to the last tenth of a
#: pixel); resampling by that little only blurs, and the moving-object test takes a residual
#: of a few tenths of a pixel up (:mod:`ccdcore.response.moving`)
_APPLY_MIN = 0.25
#: frames registered at once
ALIGN_THREADS = max(1, min(2, os.cpu_count() or 1))
#: a shift or rotation counts beyond this many of its stated errors: the errors come out
#: about 1.3 times optimistic over noise draws, and a bracket of ten frames tested at 2 sigma
#: found a false rotation (0.16 ± 0.08 degree, 11 tiles) in a registered simulated bracket
_SIGNIFICANT = 4.0


@dataclass(frozen=True)
class FrameShift:
    """One frame's registration onto the reference.

    ``dx, dy`` (pixels) and ``rotation`` (degrees, about the frame centre) map the reference's
    pixel grid into the frame (module docstring): ``aligned(x, y) = frame(x + dx, y + dy)`` for a
    pure shift. ``dx_err, dy_err, rotation_err`` are 1-sigma errors from the scatter of the
    tiles' shifts; ``rotation`` is 0 unless beyond 4 ``rotation_err``. ``registered`` False: the
    frame could not be registered (``reason`` says why; its shift is 0) and the caller should
    leave it out of the merge. ``applied``: :func:`apply_alignment` resamples this frame (its
    shift or rotation is beyond 4 sigma and beyond 0.25 pixel); False for the reference, for a
    frame registered at zero within its error and for a frame left out.
    """

    name: str
    dx: float
    dy: float
    rotation: float
    dx_err: float
    dy_err: float
    rotation_err: float
    registered: bool
    reason: str
    applied: bool
    tiles: int = 0

    def to_dict(self) -> dict:
        """The fields as a JSON-ready dict (``tiles``: how many tiles the fit kept)."""
        return {k: (v if isinstance(v, (str, bool, int)) else float(v))
                for k, v in asdict(self).items()}

    def label(self) -> str:
        """``"IMG_0001.JPG by (+3.20, -1.40) px and 0.12°"``, or the reason it is left out."""
        if not self.registered:
            return self.reason
        text = f"{self.name} by ({self.dx:+.2f}, {self.dy:+.2f}) px"
        if self.rotation:
            text += f" and {self.rotation:+.3f}°"
        return text if self.applied else f"{self.name} unchanged (within its error or 0.25 px)"


@dataclass(frozen=True)
class Alignment:
    """The registration of a bracket: the reference's index and one :class:`FrameShift` per
    frame, in input order (the reference's all zeros, ``applied`` False)."""

    reference: int
    shifts: tuple[FrameShift, ...]

    @property
    def any_applied(self) -> bool:
        """Whether :func:`apply_alignment` resamples any frame."""
        return any(s.applied for s in self.shifts)

    @property
    def left_out(self) -> tuple[str, ...]:
        """The names of the frames that could not be registered (to leave out of the merge)."""
        return tuple(s.name for s in self.shifts if not s.registered)

    def to_dict(self) -> dict:
        """JSON-ready: reference (index and name), any_applied, left_out, the shifts, describe."""
        return {"reference": self.reference, "reference_name": self.shifts[self.reference].name,
                "any_applied": self.any_applied, "left_out": list(self.left_out),
                "shifts": [s.to_dict() for s in self.shifts], "describe": self.describe()}

    def describe(self) -> str:
        """One plain-English line: what was aligned to what, by how much, what was left out."""
        ref = self.shifts[self.reference].name
        out = [s for s in self.shifts if not s.registered]
        tail = f"; {len(out)} left out" + (
            " (" + "; ".join(s.reason for s in out) + ")" if out else "")
        if not self.any_applied:
            if not out:
                return ("frames registered (tripod): every shift within its error or 0.25 px, no "
                        "frame resampled")
            return (f"no frame resampled: every registered shift within its error or 0.25 px "
                    f"(reference {ref}){tail}")
        moved = [s.label() for s in self.shifts if s.applied]
        still = sum(1 for i, s in enumerate(self.shifts) if i != self.reference and s.registered
                    and not s.applied)
        rest = (f"; {still} other{'s' if still > 1 else ''} within {_APPLY_MIN:g} px or "
                "their error, not resampled" if still else "")
        return (f"{len(moved)} of {len(self.shifts)} frames aligned to {ref}: "
                + ", ".join(moved) + rest + tail)


# ---------------------------------------------------------------------------------- input


def _check(frames: Sequence[np.ndarray], names: Sequence[str], reference: int | None,
           max_shift: float, levels: int | None) -> tuple[list[np.ndarray], int, int]:
    """The frames as arrays, the reference index and the number of code levels; CcdError
    naming the frame for bad input."""
    names = [str(n) for n in names]
    arrays = [np.asarray(f) for f in frames]
    if len(names) != len(arrays):
        raise CcdError("names", f"{len(names)} names for {len(arrays)} frames")
    if len(arrays) < 2:
        raise CcdError(names[0] if names else "frames",
                       f"at least 2 frames are needed to align a bracket, got {len(arrays)}")
    shape = arrays[0].shape
    for name, a in zip(names, arrays):
        if a.dtype.kind not in "ui":
            raise CcdError(name, f"sample type {a.dtype} is not an integer type: alignment "
                                 f"reads the camera's codes (uint8 or uint16)")
        if a.ndim not in (2, 3) or min(a.shape[:2]) < 2 * TILE_MIN:
            raise CcdError(name, f"expected an (H, W) or (H, W, C) frame of at least "
                                 f"{2 * TILE_MIN} pixels a side, got shape {a.shape}")
        if a.shape != shape:
            raise CcdError(name, f"shape {a.shape} differs from {names[0]}'s {shape}")
        if a.dtype.kind == "i" and a.min() < 0:
            raise CcdError(name, "negative codes: alignment reads the camera's codes")
    if not 0.0 < max_shift < 0.5:
        raise CcdError("max_shift", f"must lie in (0, 0.5) of the smaller side, got {max_shift}")
    ref = len(arrays) // 2 if reference is None else int(reference)
    if not 0 <= ref < len(arrays):
        raise CcdError("reference", f"index {reference} outside the {len(arrays)} frames")
    tops = [int(a.max()) for a in arrays]
    if levels is None:
        levels = 256 if all(a.dtype == np.uint8 for a in arrays) else \
            max(2, 1 << max(tops).bit_length())
    levels = int(levels)
    if not 2 <= levels <= 2 ** 16:
        raise CcdError("levels", f"between 2 and 65536 code levels (up to 16 bits), got {levels}")
    for name, top in zip(names, tops):
        if top > levels - 1:
            raise CcdError(name, f"code {top} beyond the {levels} levels given")
    return arrays, ref, levels


# ------------------------------------------------------------------- exposure-invariant frame


def _luminance(block: np.ndarray) -> NDArray[np.float32]:
    """The sum of the channels (float32): the luminance the frames are registered on."""
    if block.ndim == 2:
        return block.astype(np.float32)
    acc = block[..., 0].astype(np.float32)
    for k in range(1, block.shape[2]):
        acc += block[..., k]
    return acc


def _clipped(block: np.ndarray, top: int) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Pixels clipped high (a channel at the top code) and low (every channel at code 0)."""
    if block.ndim == 2:
        return block >= top, block == 0
    high = block[..., 0].copy()
    for k in range(1, block.shape[2]):
        np.maximum(high, block[..., k], out=high)
    return high >= top, high == 0


class _Frame:
    """One frame as the registration sees it, at two levels: 0 the copy block-averaged by ``f``
    (the coarse shift), 1 the frame itself (crops for the tiles).

    The rank table is the histogram equalisation of the luminance (the sum of the channels),
    ties counted half, from an even sample of at most about 2**20 pixels; ``lo`` and ``hi`` are
    the ranks where clipping starts (the fractions clipped low and not clipped high)."""

    def __init__(self, frame: np.ndarray, levels: int):
        self.frame, self.top = frame, levels - 1
        H, W = frame.shape[:2]
        C = 1 if frame.ndim == 2 else frame.shape[2]
        self.f = max(1, math.ceil(max(H, W) / COARSE_SIDE))
        step = max(1, int(math.sqrt(H * W / 2 ** 20)))
        sub = frame[::step, ::step]
        codes = (sub if sub.ndim == 2 else sub.sum(axis=2, dtype=np.int64)).ravel()
        hist = np.bincount(codes.astype(np.int64), minlength=C * self.top + 1)
        cum = np.cumsum(hist, dtype=np.float64)
        self.cdf = (cum - 0.5 * hist) / max(1.0, cum[-1])
        self.dcdf = np.diff(self.cdf, append=self.cdf[-1])
        high, low = _clipped(sub, self.top)
        self.lo, self.hi = float(low.mean()), 1.0 - float(high.mean())
        self._coarse()
        self.tiles: dict = {}

    def _coarse(self) -> None:
        """The f × f block means of the luminance and of the clipped pixels (strip by strip)."""
        f, frame = self.f, self.frame
        h, w = frame.shape[0] // f, frame.shape[1] // f
        self.level0 = np.empty((3, h, w), np.float32)     # luminance, clipped high, low
        channels = 1 if frame.ndim == 2 else frame.shape[2]
        rows = max(1, 2 ** 22 // (frame.shape[1] * f * channels))
        for i in range(0, h, rows):
            blk = frame[i * f:min(h, i + rows) * f, :w * f]
            n = blk.shape[0] // f
            for k, plane in enumerate((_luminance(blk), *_clipped(blk, self.top))):
                self.level0[k, i:i + n] = plane.reshape(n, f, w, f).mean(axis=(1, 3))

    def shape(self, level: int) -> tuple[int, int]:
        return self.level0.shape[1:] if level == 0 else self.frame.shape[:2]

    def crop(self, level: int, y0: int, y1: int, x0: int, x1: int) -> NDArray[np.float32]:
        """Rows y0:y1, columns x0:x1 of a level as four planes: luminance, clipped high,
        clipped low (1 or the fraction of a coarse block) and outside the frame (1), the
        luminance edge-padded beyond the frame."""
        H, W = self.shape(level)
        cy0, cy1, cx0, cx1 = max(0, y0), min(H, y1), max(0, x0), min(W, x1)
        out = np.zeros((4, y1 - y0, x1 - x0), np.float32)
        if cy0 >= cy1 or cx0 >= cx1:
            out[3] = 1.0
            return out
        if level == 0:
            planes = self.level0[:, cy0:cy1, cx0:cx1]
        else:
            blk = self.frame[cy0:cy1, cx0:cx1]
            planes = np.stack([_luminance(blk), *_clipped(blk, self.top)]).astype(np.float32)
        pad = ((0, 0), (cy0 - y0, y1 - cy1), (cx0 - x0, x1 - cx1))
        out[:3] = np.pad(planes, pad, mode="edge")
        out[3] = 1.0
        out[3, cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0] = 0.0
        return out

    def rank(self, planes: np.ndarray, lo: float, hi: float
             ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """The rank image of crop planes, clamped to the ranks ``[lo, hi]`` unclipped in both
        frames of a pair (clipped pixels flat at the clamp), and the usable pixels (unclipped,
        inside the frame)."""
        lum = np.clip(planes[0], 0, self.cdf.size - 1)
        i = np.minimum(lum.astype(np.intp), self.cdf.size - 2)
        r = self.cdf[i] + (lum - i) * self.dcdf[i]       # linear in the table, spacing 1
        np.clip(r, lo, hi, out=r)
        r[planes[1] > 0.5] = hi
        r[planes[2] > 0.5] = lo
        return r, planes[1:].sum(axis=0) < 0.5


# ------------------------------------------------------------------------ phase correlation


def _prepared(rank: np.ndarray, window: np.ndarray) -> np.ndarray:
    """The windowed, zero-mean image a phase correlation transforms."""
    return (rank - (rank * window).sum() / window.sum()) * window


def _lowpass(shape: tuple[int, int]) -> np.ndarray:
    """The Gaussian low-pass on the half spectrum of ``rfft2``."""
    fy = sfft.fftfreq(shape[0])[:, None]
    fx = sfft.rfftfreq(shape[1])[None, :]
    return np.exp(-(fy ** 2 + fx ** 2) / (2 * _LOWPASS ** 2))


def _phase_correlation(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float]:
    """``(sy, sx, clarity)``: the shift s with ``b(u) ≈ a(u - s)`` (b's content moved by s
    against a), to sub-pixel precision, and the peak's height in RMS of the surface."""
    X = np.conj(sfft.rfft2(a)) * sfft.rfft2(b)
    mag = np.abs(X)
    top = float(mag.max())
    if not top > 0:                      # a flat image: no peak at all
        return 0.0, 0.0, 0.0
    X = X / np.maximum(mag, 1e-9 * top) * _lowpass(a.shape)
    c = sfft.irfft2(X, s=a.shape)
    iy, ix = np.unravel_index(int(np.argmax(c)), c.shape)
    ny, nx = c.shape
    ring = np.ones(c.shape, bool)
    ring[np.ix_((iy + np.arange(-3, 4)) % ny, (ix + np.arange(-3, 4)) % nx)] = False
    rms = float(np.sqrt(np.mean(c[ring] ** 2)))
    clarity = float(c[iy, ix]) / rms if rms > 0 else 0.0
    py = iy - ny if iy > ny // 2 else iy
    px = ix - nx if ix > nx // 2 else ix
    sy, sx = _refine(X, nx, float(py), float(px))
    return sy, sx, clarity


def _refine(X: np.ndarray, nx: int, py: float, px: float) -> tuple[float, float]:
    """The peak of ``irfft2(X)`` (``nx`` columns) near the integer ``(py, px)``: the inverse DFT
    evaluated on a grid 1/UPSAMPLE apart within ±1.2 pixel by two matrix products
    (Guizar-Sicairos et al. 2008; the half spectrum counted twice but for its real columns),
    then a parabola through the grid's maximum and its neighbours."""
    n = int(round(1.2 * UPSAMPLE))
    off = np.arange(-n, n + 1) / UPSAMPLE
    weight = np.full(X.shape[1], 2.0)
    weight[0] = 1.0
    if nx % 2 == 0:
        weight[-1] = 1.0
    ky = np.exp(2j * np.pi * np.outer(py + off, sfft.fftfreq(X.shape[0])))
    kx = np.exp(2j * np.pi * np.outer(sfft.rfftfreq(nx), px + off)) * weight[:, None]
    up = (ky @ X @ kx).real
    iy, ix = np.unravel_index(int(np.argmax(up)), up.shape)
    iy, ix = min(max(iy, 1), up.shape[0] - 2), min(max(ix, 1), up.shape[1] - 2)

    def vertex(m1: float, m0: float, p1: float) -> float:
        den = m1 - 2 * m0 + p1
        return 0.0 if den >= 0 else float(np.clip(0.5 * (m1 - p1) / den, -1, 1))

    dy = vertex(up[iy - 1, ix], up[iy, ix], up[iy + 1, ix])
    dx = vertex(up[iy, ix - 1], up[iy, ix], up[iy, ix + 1])
    return py + off[iy] + dy / UPSAMPLE, px + off[ix] + dx / UPSAMPLE


# ------------------------------------------------------------------------------- transforms


@dataclass(frozen=True)
class _Rigid:
    """``p' = c + R(theta) (p - c) + t`` in full-resolution pixels, (y, x) order."""

    theta: float = 0.0
    ty: float = 0.0
    tx: float = 0.0

    def at(self, f: int, shape: tuple[int, ...], pts: np.ndarray) -> np.ndarray:
        """The transform on points ``pts`` (..., 2) in (y, x) of a level block-averaged by f of
        a frame of ``shape`` (full resolution): the same map in that level's pixels, where the
        centre is :func:`_centre` and the translation ``t / f`` (a level pixel k covers the full
        pixels ``f k .. f k + f - 1``, centred on ``f k + (f - 1) / 2``)."""
        cy, cx = _centre(shape, f)
        y, x = pts[..., 0] - cy, pts[..., 1] - cx
        c, s = math.cos(self.theta), math.sin(self.theta)
        return np.stack([cy + s * x + c * y + self.ty / f, cx + c * x - s * y + self.tx / f],
                        axis=-1)


def _fit(p: np.ndarray, q: np.ndarray, centre: np.ndarray, rotate: bool
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares rigid fit ``q ≈ centre + R(θ)(p - centre) + t`` of points (n, 2) in (y, x):
    ``(params [θ, ty, tx], covariance 3 × 3, residuals (n, 2))``; θ = 0 when not ``rotate``.
    The covariance is σ² (JᵀJ)⁻¹, σ² the residual variance per coordinate (floored at the
    tile measurement's resolution)."""
    n = len(p)
    a, b = p - p.mean(axis=0), q - q.mean(axis=0)
    theta = 0.0
    if rotate:   # closed-form 2-D Procrustes: (y, x) coordinates, so x×y cross products
        cross = np.sum(a[:, 1] * b[:, 0] - a[:, 0] * b[:, 1])
        theta = math.atan2(cross, np.sum(a * b))
    c, s = math.cos(theta), math.sin(theta)
    d = p - centre
    rp = _apply_fit(np.array([theta, 0.0, 0.0]), p, centre)      # c + R(θ)(p - c)
    t = (q - rp).mean(axis=0)
    res = q - rp - t
    dof = max(1, 2 * n - (3 if rotate else 2))
    var = max(float(np.sum(res ** 2)) / dof, _TILE_FLOOR ** 2)
    J = np.zeros((2 * n, 3))
    J[0::2, 1] = 1.0
    J[1::2, 2] = 1.0
    J[0::2, 0] = c * d[:, 1] - s * d[:, 0]        # d/dθ of the y coordinate
    J[1::2, 0] = -s * d[:, 1] - c * d[:, 0]       # d/dθ of the x coordinate
    if not rotate:
        J = J[:, 1:]
    cov = var * np.linalg.inv(J.T @ J)
    if not rotate:
        cov = np.pad(cov, ((1, 0), (1, 0)))
    return np.array([theta, t[0], t[1]]), cov, res


def _robust_fit(p: np.ndarray, q: np.ndarray, centre: np.ndarray, rotate: bool):
    """:func:`_fit` with iterative trimming of tiles beyond 3.5 robust sigmas (at least 0.1
    pixel): ``(params, covariance, kept, sigma)`` or None when fewer than MIN_TILES agree."""
    d = q - p
    res = d - np.median(d, axis=0)         # the start: the median shift, no rotation
    kept = np.zeros(len(p), bool)
    params = cov = None
    for _ in range(12):
        r2 = np.sum(res ** 2, axis=1)
        sigma = math.sqrt(float(np.median(r2 if params is None else r2[kept]))
                          / (2 * math.log(2)))
        new = r2 <= max(3.5 * sigma, 0.1) ** 2
        if new.sum() < MIN_TILES:
            return None
        if np.array_equal(new, kept):
            break
        kept = new
        params, cov, _res = _fit(p[kept], q[kept], centre, rotate)
        res = q - _apply_fit(params, p, centre)
    sigma = float(np.sqrt(np.sum(res[kept] ** 2) / max(1, 2 * kept.sum() - 3)))
    return params, cov, kept, sigma


def _apply_fit(params: np.ndarray, p: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """``centre + R(θ)(p - centre) + t`` for params ``[θ, ty, tx]``, points (n, 2) in (y, x)."""
    c, s = math.cos(params[0]), math.sin(params[0])
    d = p - centre
    return centre + np.stack([s * d[:, 1] + c * d[:, 0], c * d[:, 1] - s * d[:, 0]],
                             axis=1) + params[1:]


# -------------------------------------------------------------------------------------- tiles


def _grid(shape: tuple[int, int]) -> tuple[int, list[tuple[int, int]]]:
    """Tile side and the top-left corners of the tile grid of a level of ``shape``."""
    h, w = shape
    side = 1 << int(math.log2(max(TILE_MIN, min(h, w) // 4)))
    side = min(TILE_MAX, max(TILE_MIN, side))
    corners = []
    ny, nx = (min(8, max(4, s // side)) for s in (h, w))
    ys = np.linspace(0, h - side, ny).round().astype(int)
    xs = np.linspace(0, w - side, nx).round().astype(int)
    for y in ys:
        corners += [(int(y), int(x)) for x in xs]
    return side, corners


def _hann(n: int) -> np.ndarray:
    w = np.hanning(n + 2)[1:-1]
    return np.outer(w, w)


def _reference_tile(ref: _Frame, level: int, corner: tuple[int, int], side: int):
    """The reference's crop planes of a tile (cached)."""
    key = (level, corner, side)
    if key not in ref.tiles:
        y, x = corner
        ref.tiles[key] = ref.crop(level, y, y + side, x, x + side)
    return ref.tiles[key]


def _frame_tile(src: _Frame, level: int, rigid: _Rigid, corner: tuple[int, int], side: int
                ) -> NDArray[np.float32]:
    """The frame's crop planes resampled through ``rigid`` onto a reference tile's pixels: the
    luminance by cubic spline, the clipped and outside planes bilinearly."""
    f = src.f if level == 0 else 1
    u = np.arange(side, dtype=np.float64)
    pts = np.stack(np.meshgrid(corner[0] + u, corner[1] + u, indexing="ij"), axis=-1)
    q = rigid.at(f, src.frame.shape[:2], pts)
    y0, x0 = (int(math.floor(q[..., i].min())) - 3 for i in (0, 1))
    y1, x1 = (int(math.ceil(q[..., i].max())) + 4 for i in (0, 1))
    planes = src.crop(level, y0, y1, x0, x1)
    coords = np.stack([q[..., 0] - y0, q[..., 1] - x0])
    out = np.zeros((4, side, side), np.float32)
    for k, plane in enumerate(planes):
        if k == 0 or plane.any():       # a plane of zeros (nothing clipped) stays zero
            out[k] = ndimage.map_coordinates(plane, coords, order=3 if k == 0 else 1,
                                             mode="nearest")
    return out


def _measure(ref: _Frame, src: _Frame, level: int, rigid: _Rigid):
    """Every tile's position in the frame at a level: ``(p, q, n_tiles)`` with p the centres of
    the tiles with a clear peak and q the points of the frame they map to (level pixels, (y,
    x)), and the number of tiles tried."""
    side, corners = _grid(ref.shape(level))
    f = src.f if level == 0 else 1
    lo, hi = max(ref.lo, src.lo), min(ref.hi, src.hi)
    win = _hann(side)
    half = (side - 1) / 2.0
    p, q = [], []
    for corner in corners:
        ra, va = ref.rank(_reference_tile(ref, level, corner, side), lo, hi)
        rb, vb = src.rank(_frame_tile(src, level, rigid, corner, side), lo, hi)
        both = va & vb
        if both.mean() < _MIN_VALID or np.ptp(ra[both]) <= 0 or np.ptp(rb[both]) <= 0:
            continue
        sy, sx, clarity = _phase_correlation(_prepared(ra, win), _prepared(rb, win))
        if clarity < PEAK_MIN or max(abs(sy), abs(sx)) > side / 4:
            continue
        centre = np.array([corner[0] + half, corner[1] + half])
        p.append(centre)
        q.append(rigid.at(f, src.frame.shape[:2], centre + np.array([sy, sx])))
    return np.array(p).reshape(-1, 2), np.array(q).reshape(-1, 2), len(corners)


def _centre(shape: tuple[int, ...], f: int) -> np.ndarray:
    """The frame centre ((H - 1) / 2, (W - 1) / 2) in pixels of a level block-averaged by f."""
    o = (f - 1) / 2.0
    return np.array([((shape[0] - 1) / 2.0 - o) / f, ((shape[1] - 1) / 2.0 - o) / f])


# ------------------------------------------------------------------------------ registration


def _coarse_shift(ref: _Frame, src: _Frame) -> _Rigid:
    """The global translation from the phase correlation of the whole coarse copies."""
    h, w = ref.shape(0)
    win = np.outer(np.hanning(h + 2)[1:-1], np.hanning(w + 2)[1:-1])
    lo, hi = max(ref.lo, src.lo), min(ref.hi, src.hi)
    planes = [np.concatenate([x.level0, np.zeros((1, h, w), np.float32)]) for x in (ref, src)]
    ra, rb = (x.rank(pl, lo, hi)[0] for x, pl in zip((ref, src), planes))
    sy, sx, _clarity = _phase_correlation(_prepared(ra, win), _prepared(rb, win))
    return _Rigid(0.0, sy * src.f, sx * src.f)


def _refine_levels(ref: _Frame, src: _Frame, rigid: _Rigid):
    """The measure-and-fit loop on the coarse copy, then on full-resolution tiles: ``(rigid,
    fit, None)`` with the last fit ``(params, cov, kept, sigma, n_tiles, p, q)`` in full
    pixels, or ``(None, None, reason)``."""
    shape = src.frame.shape[:2]
    fit = None
    for level in ((0, 1) if src.f > 1 else (1,)):
        f = src.f if level == 0 else 1
        centre = _centre(shape, f)
        for _ in range(5):
            p, q, n = _measure(ref, src, level, rigid)
            if len(p) < MIN_TILES:
                return None, None, (f"too little structure to register ({len(p)} of {n} tiles "
                                    f"with a clear peak{_clipped_note(ref, src)})")
            found = _robust_fit(p, q, centre, rotate=True)
            if found is None or found[2].sum() < 0.5 * len(p):
                agree = 0 if found is None else int(found[2].sum())
                return None, None, (f"the tiles disagree: no consistent shift ({agree} of "
                                    f"{len(p)} tiles with a clear peak fit one)")
            params, cov, kept, sigma = found
            if sigma > 1.0:
                return None, None, (f"the tiles disagree: residual scatter {sigma * f:.2g} px "
                                    f"of {int(kept.sum())} tiles")
            new = _Rigid(float(params[0]), float(params[1]) * f, float(params[2]) * f)
            moved = float(np.max(np.abs(new.at(f, shape, p) - rigid.at(f, shape, p))))
            rigid, fit = new, (params, cov, kept, sigma, n, p, q)
            if moved < _CONVERGED[level]:
                break
    return rigid, fit, None


def _clipped_note(ref: _Frame, src: _Frame) -> str:
    """``"; 92 % of its pixels clipped"`` (or the reference's) when most pixels are clipped."""
    note = ""
    for who, x in (("its", src), ("the reference's", ref)):
        clipped = 1.0 - (x.hi - x.lo)
        if clipped > 0.5:
            note += f"; {100 * clipped:.0f} % of {who} pixels clipped"
    return note


def _register(ref: _Frame, src: _Frame, name: str, max_shift: float) -> FrameShift:
    """One frame's :class:`FrameShift` onto the reference."""
    shape = src.frame.shape[:2]
    rigid, fit, reason = _refine_levels(ref, src, _coarse_shift(ref, src))
    if rigid is None:
        return _left_out(name, reason)
    params, cov, kept, _sigma, _n, p, q = fit
    centre = _centre(shape, 1)
    sd = np.sqrt(np.diag(cov))
    if abs(params[0]) <= _SIGNIFICANT * sd[0] or abs(params[0]) * math.hypot(*centre) <= _APPLY_MIN:
        # not significant, or moving no corner by _APPLY_MIN: no rotation, refit the shift
        params, cov, _res = _fit(p[kept], q[kept], centre, rotate=False)
        sd = np.concatenate([sd[:1], np.sqrt(np.diag(cov))[1:]])
    theta, dy, dx = (float(v) for v in params)
    limit = max_shift * min(shape)
    if max(abs(dx), abs(dy)) > limit:
        return _left_out(name, f"shift ({dx:+.1f}, {dy:+.1f}) px beyond max_shift ({max_shift:g} "
                               f"of the smaller side, {limit:.0f} px)")
    reach = abs(theta) * math.hypot(*centre)   # the rotation's largest displacement (corners)
    applied = (abs(dx) > max(_SIGNIFICANT * sd[2], _APPLY_MIN)
               or abs(dy) > max(_SIGNIFICANT * sd[1], _APPLY_MIN)
               or (theta != 0.0 and reach > _APPLY_MIN))
    return FrameShift(name, dx, dy, math.degrees(theta), float(sd[2]), float(sd[1]),
                      math.degrees(float(sd[0])), True, "", bool(applied), int(kept.sum()))


def _left_out(name: str, reason: str) -> FrameShift:
    return FrameShift(name, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, f"{name}: {reason}", False)


def estimate_alignment(frames: Sequence[np.ndarray], names: Sequence[str],
                       reference: int | None = None, *, max_shift: float = 0.1,
                       levels: int | None = None) -> Alignment:
    """The shift and rotation of every frame of a bracket onto its reference frame.

    Parameters
    ----------
    frames
        The bracket's frames, (H, W) or (H, W, C) integer codes (uint8, uint16), all one shape,
        in exposure order. Colour frames are registered on the sum of their channels.
    names
        One name per frame (its file name), used in the results and in every message.
    reference
        Index of the frame the others are aligned to; None: the middle one (``len // 2``).
    max_shift
        Largest shift accepted, as a fraction of the smaller image side; a frame measured
        beyond it is left out.
    levels
        Number of codes (clipped codes are 0 and ``levels - 1``); None: 256 for uint8, else the
        largest code of the frames plus one rounded up to a power of 2.

    Returns
    -------
    Alignment
        One :class:`FrameShift` per frame, in input order (module docstring for the method and
        the sign convention).

    Raises
    ------
    CcdError
        Fewer than 2 frames, frames of different shapes, a non-integer sample type, codes
        beyond ``levels``, a bad ``reference`` or ``max_shift``; the message names the frame.
    """
    arrays, ref, levels = _check(frames, names, reference, max_shift, levels)
    names = [str(n) for n in names]
    shifts = []
    # the small matrix products of the peak fits run far faster on one BLAS thread
    with threadpool_limits(1, user_api="blas"):
        ref_frame = _Frame(arrays[ref], levels)

        def one(i: int) -> FrameShift:
            if i == ref:
                return FrameShift(names[i], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, True, "", False)
            return _register(ref_frame, _Frame(arrays[i], levels), names[i], max_shift)

        # frames in threads (NumPy's FFTs and SciPy's splines release the GIL); the reference's
        # tile cache may compute a tile twice in a race, with the same values
        with ThreadPoolExecutor(ALIGN_THREADS, thread_name_prefix="align") as pool:
            shifts = list(pool.map(one, range(len(arrays))))
    return Alignment(ref, tuple(shifts))


# ---------------------------------------------------------------------------------- resampling


def _matrix(s: FrameShift, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The (row, column) matrix and offset of ``scipy.ndimage.affine_transform`` that samples
    the frame at ``p' = c + R(θ)(p - c) + (dx, dy)``."""
    th = math.radians(s.rotation)
    c, sn = math.cos(th), math.sin(th)
    M = np.array([[c, sn], [-sn, c]])
    centre = _centre(shape, 1)
    return M, centre + np.array([s.dy, s.dx]) - M @ centre


def _resample_strips(frame: np.ndarray, M: np.ndarray, offset: np.ndarray, starts: range,
                     rows: int, out: np.ndarray) -> None:
    """Strips of ``rows`` rows starting at ``starts`` of the bilinear resampling of ``frame`` at
    ``M (y, x) + offset`` into ``out`` (same shape and type): the four neighbours gathered for
    every channel at once, the sample point clamped to the frame (``mode="nearest"`` of
    ``scipy.ndimage``), rounded to the nearest code. The work arrays are made once and reused
    (at a camera's resolution, allocating them per strip costs more than the arithmetic)."""
    H, W = frame.shape[:2]
    flat, dest = frame.reshape(H * W, -1), out.reshape(H * W, -1)
    C = flat.shape[1]
    x = np.arange(W, dtype=np.float64)[None, :]
    info = np.iinfo(frame.dtype)
    code = np.empty((rows, W, C), frame.dtype)
    upper, lower, tmp = (np.empty((rows, W, C), np.float32) for _ in range(3))
    for y0 in starts:
        n = min(H, y0 + rows) - y0
        y = np.arange(y0, y0 + n, dtype=np.float64)[:, None]
        sy = np.clip(M[0, 0] * y + M[0, 1] * x + offset[0], 0, H - 1)
        sx = np.clip(M[1, 0] * y + M[1, 1] * x + offset[1], 0, W - 1)
        iy = np.minimum(sy.astype(np.intp), H - 2)
        ix = np.minimum(sx.astype(np.intp), W - 2)
        wy = (sy - iy).astype(np.float32)[..., None]
        wx = (sx - ix).astype(np.float32)[..., None]
        i00 = iy * W + ix
        u, lo, t = upper[:n], lower[:n], tmp[:n]
        for rows_at, acc in ((i00, u), (i00 + W, lo)):   # the upper and the lower neighbours
            np.take(flat, rows_at, axis=0, out=code[:n])
            np.multiply(code[:n], 1 - wx, out=acc)
            np.take(flat, rows_at + 1, axis=0, out=code[:n])
            np.multiply(code[:n], wx, out=t)
            acc += t
        lo -= u
        lo *= wy
        u += lo
        np.rint(u, out=u)
        np.clip(u, info.min, info.max, out=u)
        dest[y0 * W:(y0 + n) * W] = u.reshape(n * W, C)


def _resampled(frame: np.ndarray, s: FrameShift) -> np.ndarray:
    """The frame resampled (bilinear, every channel) onto the reference grid, in its own type:
    the same values as ``scipy.ndimage.affine_transform(order=1, mode="nearest")`` per channel,
    rounded, computed in strips of rows on two threads."""
    M, offset = _matrix(s, frame.shape)
    out = np.empty_like(frame)
    H, W = frame.shape[:2]
    rows = max(1, 2 ** 15 // W)
    starts = range(0, H, rows)
    with ThreadPoolExecutor(max_workers=2) as pool:
        list(pool.map(lambda k: _resample_strips(frame, M, offset, starts[k::2], rows, out),
                      range(2)))
    return out


def _inside(s: FrameShift, shape: tuple[int, ...]) -> NDArray[np.bool_]:
    """Pixels of the reference grid whose sample point ``p'`` lies within the frame (all four
    bilinear neighbours inside): per row, the interval of columns where both coordinates of p'
    (linear in the column) are in range."""
    H, W = shape[:2]
    M, offset = _matrix(s, shape)
    y = np.arange(H, dtype=np.float64)
    lo, hi = np.full(H, -np.inf), np.full(H, np.inf)
    for r, top in ((0, H - 1), (1, W - 1)):
        alpha, beta = M[r, 1], M[r, 0] * y + offset[r]       # coordinate = alpha x + beta
        if abs(alpha) < 1e-12:
            ok = (beta >= -1e-6) & (beta <= top + 1e-6)
            lo, hi = np.where(ok, lo, np.inf), np.where(ok, hi, -np.inf)
            continue
        a, b = (-1e-6 - beta) / alpha, (top + 1e-6 - beta) / alpha
        lo, hi = np.maximum(lo, np.minimum(a, b)), np.minimum(hi, np.maximum(a, b))
    x = np.arange(W, dtype=np.float64)
    return (x[None, :] >= lo[:, None]) & (x[None, :] <= hi[:, None])


def apply_alignment(frames: Sequence[np.ndarray], alignment: Alignment
                    ) -> tuple[list[np.ndarray], NDArray[np.bool_]]:
    """The frames resampled onto the reference's pixel grid, and the pixels valid in all.

    Parameters
    ----------
    frames
        The frames :func:`estimate_alignment` was given, in the same order.
    alignment
        Its result.

    Returns
    -------
    aligned : list of numpy.ndarray
        One per frame, same shape and dtype: ``aligned(p) = frame(c + R(θ)(p - c) + (dx, dy))``
        by bilinear interpolation (``scipy.ndimage.affine_transform``, order 1, or its
        separable equivalent for a pure shift), rounded to the nearest code. A frame with
        ``applied`` False (the reference, a frame registered at zero, a frame left out) is the
        very array given, bit for bit. Beyond the frame's edge a resampled frame repeats its
        edge values; the mask says where.
    valid : numpy.ndarray of bool, (H, W)
        True where every resampled frame's sample point lies within its source frame.

    Raises
    ------
    CcdError
        Not one frame per shift, or a frame of another shape than the reference.
    """
    if len(frames) != len(alignment.shifts):
        raise CcdError("frames", f"{len(frames)} frames for an alignment of "
                                 f"{len(alignment.shifts)}")
    ref = np.asarray(frames[alignment.reference])
    valid = np.ones(ref.shape[:2], bool)
    out = []
    for frame, s in zip(frames, alignment.shifts):
        if not (s.registered and s.applied):
            out.append(frame)
            continue
        a = np.asarray(frame)
        if a.shape != ref.shape:
            raise CcdError(s.name, f"shape {a.shape} differs from the reference's {ref.shape}")
        out.append(_resampled(a, s))
        valid &= _inside(s, a.shape)
    return out, valid
