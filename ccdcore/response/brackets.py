"""Exposure brackets as the response estimators read them: pixel traces per channel.

Tsin, Ramesh & Kanade (2001), sec. 3.2, step 1 ("preprocess the image"): a static scene is taken
at N exposure settings; at each pixel x the N codes ``z_1(x) .. z_N(x)`` form its *pixel trace*.
Known outliers are taken out before any estimation: the boundary pixels of the frame and the
pixels within a radius (default 3, as the paper's cameras) of a saturated pixel, where blooming
spills charge (sec. 2). Clipped codes (0 and ``levels - 1``) carry no value of the response either
and are marked unusable.

Public objects
--------------
BracketData
    One channel of one bracket: codes ``z`` (N × P), which observations are usable, the nominal
    exposure times, the number of code levels (``2**bits``) and the channel name.
load_bracket(session, stack=None, ...)
    The bracket frames of a session (role ``bracket``, one ``stack``) as one ``BracketData`` per
    channel (mono, RGB, or the CFA planes of a raw Bayer frame).
bracket_data(frames, t, bits, ...)
    The same from arrays already in memory.
preprocess(frame, levels, ...)
    The usable-observation mask of one frame: boundary, blooming and clipped codes removed.
bloom_mask(plane, levels, radius=3)
    The pixels within a radius of a saturated pixel.
BAYER_MAD_FACTOR
    The paper's correction of the MAD sigma for channels interpolated from a Bayer mosaic (eq. 12).
FIT_PIXELS
    Pixels per channel the estimators' traces hold by default (an even sample of the frame).
PAIR_LEVELS_MAX
    Largest number of code levels for which the comparagrams ``pair_counts`` are counted.

Memory at a camera's resolution: the masks and every check are made on the whole frame, one
frame at a time, but only an even sample of the pixels with a usable code (``max_pixels``,
default :data:`FIT_PIXELS` per channel) is kept as traces; the comparagrams of neighbouring
images (``pair_counts``) count every pixel.
"""
from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import channels as chan
from ..errors import CcdError
from ..session.records import MAX_EXPOSURE, MIN_EXPOSURE
from .names import DEFAULT_BLOOM_RADIUS, MAX_BLOOM_RADIUS

__all__ = ["BracketData", "load_bracket", "bracket_records", "bracket_data", "check_times",
           "preprocess", "bloom_mask", "kept_mask", "dilate_disk", "BAYER_MAD_FACTOR",
           "FIT_PIXELS", "PAIR_LEVELS_MAX",
           "DEFAULT_BLOOM_RADIUS", "MAX_BLOOM_RADIUS", "DEFAULT_BORDER"]

# DEFAULT_BLOOM_RADIUS (sec. 2: "usually 3 pixels") and MAX_BLOOM_RADIUS (the disk's cost grows
# with its area: 3000 asks 596 GiB, 300 takes 83 s on a 64x48 frame; a halo wider than 64 is lens
# flare, not blooming) live in ccdcore.response.names, which the command line's parser reads
# without loading this module
#: width (pixels) of the frame boundary dropped (sec. 3.2, step 1: "boundary pixels")
DEFAULT_BORDER = 1

#: eq. 12: the MAD sigma's second factor for colour channels interpolated from a Bayer mosaic
#: (correlated neighbours): 1.265 for green, 1.333 for red and blue; 1 otherwise
BAYER_MAD_FACTOR: dict[str, float] = {"R": 1.333, "G": 1.265, "B": 1.333}

#: default ``max_pixels`` of :func:`bracket_data`: pixels per channel kept as traces (an even,
#: deterministic sample of the pixels with a usable code). The estimators sample below it anyway:
#: Tsin's fit stores at most ``tsin.MAX_ENTRIES`` = 2**24 pair errors, 2**24 / (N (N - 1)) pixels
#: (233 k for a 9-image bracket, 2**18 = 262 k lies just above), the classic methods 20 000
#: pixels, the agreement 100 000; the rare codes near the clip levels are counted on every pixel
#: by ``pair_counts``. The traces then take N * 2**18 * 6 bytes (14 MB for N = 9) per channel,
#: whatever the camera's resolution.
FIT_PIXELS = 2 ** 18
#: ``pair_counts`` (N - 1 comparagrams of L x L int64) are counted up to this many code levels
#: (12 bits: 8 x 128 MiB for 9 images); ``None`` beyond
PAIR_LEVELS_MAX = 4096
#: a scattered write of the blooming disk costs about this many whole-frame ORs per pixel: below
#: that many saturated pixels the disks are marked one by one, else the frame is dilated
_SPARSE_COST = 16
#: threads scanning a bracket's channels at once (NumPy releases the GIL in its loops)
SCAN_THREADS = max(1, min(2, os.cpu_count() or 1))
#: pixels per chunk of the comparagram counts and of the sample (bounds temporaries)
_CHUNK = 1 << 20


@dataclass(frozen=True, eq=False)
class BracketData:
    """One channel of an exposure bracket, as pixel traces.

    Attributes
    ----------
    z
        ``(N, P)`` int32 codes: image ``k`` (in increasing exposure order) at kept pixel ``p``.
    valid
        ``(N, P)`` bool: the observation is usable (not clipped, not near a saturated pixel, not
        on the boundary).
    t
        ``(N,)`` nominal exposure times, increasing (seconds, or any unit: only ratios matter).
    levels
        Number of codes, ``2**bits`` (8-bit: 256); ``z`` lies in ``0 .. levels - 1``.
    channel
        Channel name (``"L"`` for mono, ``"R"``, ``"G"``, ``"B"``, or a CFA plane).
    shape
        ``(H, W)`` of the channel's frame; ``pixels`` the flat indices of the kept pixels.
    bayer_interpolated
        True when the channel was interpolated from a Bayer mosaic (eq. 12's extra factor).
    files
        The frames' paths (or names), in the order of ``z``'s rows.
    kept
        ``(N, P)`` bool: the observations not removed as outliers (see :attr:`observed`).
    pair_counts
        ``(N - 1, L, L)`` int64 comparagrams of neighbouring images over **every** pixel of the
        channel's frame (not only the kept sample, no mask): ``pair_counts[j, u, v]`` pixels
        read code ``u`` in image ``j`` and ``v`` in image ``j + 1``; ``None`` when not counted
        (more than :data:`PAIR_LEVELS_MAX` levels, negative codes, or built by hand).
    """

    z: NDArray[np.int32]
    valid: NDArray[np.bool_]
    t: NDArray[np.float64]
    levels: int
    channel: str = "L"
    shape: tuple[int, int] = (0, 0)
    pixels: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    bayer_interpolated: bool = False
    files: tuple[str, ...] = ()
    kept: NDArray[np.bool_] | None = None
    pair_counts: NDArray[np.int64] | None = None

    @property
    def observed(self) -> NDArray[np.bool_]:
        """``(N, P)``: observations not removed as outliers (boundary, blooming) -- the usable
        ones plus the clipped codes (0, ``levels - 1``), which say "at or beyond the clip level"."""
        if self.kept is not None:
            return self.kept
        return self.valid | (self.z <= 0) | (self.z >= self.levels - 1)

    @property
    def n_images(self) -> int:
        return int(self.z.shape[0])

    @property
    def n_pixels(self) -> int:
        return int(self.z.shape[1])

    @property
    def mad_factor(self) -> float:
        """Eq. 12's constant c: 1.483 (Gaussian MAD) times the Bayer factor when interpolated."""
        extra = BAYER_MAD_FACTOR.get(self.channel[:1], 1.0) if self.bayer_interpolated else 1.0
        return 1.483 * extra

    def row_bands(self, n: int) -> NDArray[np.int64]:
        """The band of every kept pixel when the frame's rows are cut into ``n`` bands (by
        flat index; by the pixel order when the flat indices are not known): blocks of pixels
        in which correlated neighbours stay together (jackknives, sandwich estimates)."""
        P = self.n_pixels
        h, w = self.shape
        if self.pixels.size == P and h * w > 0:
            return np.minimum(self.pixels.astype(np.int64) * n // (h * w), n - 1)
        return np.arange(P, dtype=np.int64) * n // max(P, 1)

    def take(self, columns: ArrayLike) -> "BracketData":
        """The same bracket restricted to the pixel columns ``columns`` (a subsample of pixels);
        ``pair_counts`` stay those of the whole frame."""
        idx = np.asarray(columns)
        return BracketData(self.z[:, idx], self.valid[:, idx], self.t, self.levels, self.channel,
                           self.shape, self.pixels[idx] if self.pixels.size else self.pixels,
                           self.bayer_interpolated, self.files,
                           None if self.kept is None else self.kept[:, idx], self.pair_counts)


def preprocess(frame: ArrayLike, levels: int, *, bloom_radius: int = DEFAULT_BLOOM_RADIUS,
               border: int = DEFAULT_BORDER, bloom: NDArray[np.bool_] | None = None
               ) -> NDArray[np.bool_]:
    """Usable pixels of one 2-D channel frame (sec. 3.2, step 1).

    A pixel is dropped when its code is clipped (0 or ``levels - 1``), when it lies within
    ``bloom_radius`` pixels (Euclidean disk) of a saturated pixel (blooming, sec. 2), or within
    ``border`` pixels of the frame's edge. ``bloom``: the frame's :func:`bloom_mask`, when
    already made.
    """
    z = np.asarray(frame)
    if z.ndim != 2:
        raise CcdError("bracket", f"expected a 2-D channel, got shape {z.shape}")
    if bloom is None:
        bloom = bloom_mask(z, levels, bloom_radius)
    usable = (z > 0) & (z < levels - 1) & ~bloom
    if border > 0:
        b = int(border)
        usable[:b, :] = usable[-b:, :] = False
        usable[:, :b] = usable[:, -b:] = False
    return usable


def kept_mask(frame: ArrayLike, levels: int, *, bloom_radius: int = DEFAULT_BLOOM_RADIUS,
              border: int = DEFAULT_BORDER, bloom: NDArray[np.bool_] | None = None
              ) -> NDArray[np.bool_]:
    """Observations of one 2-D channel frame that are not outliers: the boundary and the
    unsaturated pixels within ``bloom_radius`` of a saturated one are dropped; clipped codes stay
    (they are observations of "at or beyond the clip level")."""
    z = np.asarray(frame)
    if bloom is None:
        bloom = bloom_mask(z, levels, bloom_radius)
    kept = ~(bloom & (z < levels - 1))
    if border > 0:
        b = int(border)
        kept[:b, :] = kept[-b:, :] = False
        kept[:, :b] = kept[:, -b:] = False
    return kept


def bloom_mask(plane: ArrayLike, levels: int, radius: int = DEFAULT_BLOOM_RADIUS
               ) -> NDArray[np.bool_]:
    """Pixels within ``radius`` (a Euclidean disk) of a saturated pixel (code ``levels - 1``) of
    the 2-D ``plane``, the saturated ones included: where blooming may have spilled charge."""
    if not 0 <= radius <= MAX_BLOOM_RADIUS:
        raise CcdError("bloom_radius", f"must be from 0 to {MAX_BLOOM_RADIUS} pixels, got "
                                       f"{radius!r} (a wider halo is lens flare, not blooming)")
    z = np.asarray(plane)
    saturated = z >= levels - 1
    n_sat = int(np.count_nonzero(saturated)) if radius > 0 else 0
    if n_sat == 0:
        return np.zeros(z.shape, bool)
    r = int(radius)
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    disk = (yy * yy + xx * xx) <= r * r
    if n_sat * int(disk.sum()) * _SPARSE_COST > z.size:
        return dilate_disk(saturated, r)
    ys, xs = np.nonzero(saturated)
    # few saturated pixels (lights in a scene): mark the disk around each one directly
    out = np.zeros(z.shape, bool)
    h, w = z.shape
    for dy, dx in zip(yy[disk].tolist(), xx[disk].tolist()):
        y, x = ys + dy, xs + dx
        ok = (y >= 0) & (y < h) & (x >= 0) & (x < w)
        out[y[ok], x[ok]] = True
    return out


def dilate_disk(mask: ArrayLike, radius: int) -> NDArray[np.bool_]:
    """The binary dilation of the 2-D ``mask`` by a Euclidean disk of ``radius`` (the pixels
    ``dy**2 + dx**2 <= radius**2`` around each set pixel), as ``scipy.ndimage.binary_dilation``
    with that structure gives it, in a few whole-array ORs: the disk is a stack of horizontal
    segments of half-width ``isqrt(r**2 - dy**2)``, so the mask is dilated along the rows by
    each half-width once and the rows of the results are ORed at their offsets ``dy``."""
    m = np.asarray(mask, bool)
    r = int(radius)
    h, w = m.shape
    widths = [math.isqrt(r * r - dy * dy) for dy in range(r + 1)]   # half-width at |dy|
    rows: dict[int, NDArray[np.bool_]] = {}
    cur = m.copy()
    done = 0
    for hw in sorted(set(widths)):        # row dilations, each widening the last one
        for dx in range(done + 1, hw + 1):
            if dx < w:
                cur[:, dx:] |= m[:, :-dx]
                cur[:, :-dx] |= m[:, dx:]
        done = max(done, hw)
        rows[hw] = cur.copy() if hw != max(widths) else cur
    out = rows[widths[0]].copy()
    for dy in range(1, r + 1):
        if dy >= h:
            break
        src = rows[widths[dy]]
        out[dy:] |= src[:-dy]
        out[:-dy] |= src[dy:]
    return out


def check_times(t: Sequence[Any], files: Sequence[str]) -> NDArray[np.float64]:
    """A bracket's exposure times as an array, or one clear error naming the frame: at least
    two, each from :data:`MIN_EXPOSURE` to :data:`MAX_EXPOSURE` (seconds; beyond them a time is
    a typo or a unit slip, and the fits' logs and ratios overflow), no two the same."""
    where = files[0] if files else "bracket"
    if len(t) < 2:
        raise CcdError(where, f"a bracket needs at least two exposures, got {len(t)}")
    for f, v in zip(files or ["bracket"] * len(t), t):
        if v is None:
            raise CcdError(f, "missing exposure time: give 'exposure' in the manifest")
        if not (isinstance(v, (int, float, np.floating, np.integer)) and np.isfinite(v)
                and v > 0):
            raise CcdError(f, "exposure time is 0: a bracket frame needs a positive exposure"
                           if isinstance(v, (int, float, np.floating, np.integer)) and v == 0
                           else f"exposure time must be a positive number, got {v!r}")
        if not MIN_EXPOSURE <= v <= MAX_EXPOSURE:
            raise CcdError(f, f"exposure time {float(v):g} s is outside {MIN_EXPOSURE:g} to "
                              f"{MAX_EXPOSURE:g} s")
    arr = np.asarray(t, dtype=np.float64)
    if np.unique(arr).size != arr.size:
        dup = [f for f, v in zip(files, arr) if np.sum(arr == v) > 1]
        raise CcdError(dup[0] if dup else where,
                       "two frames of the bracket have the same exposure time "
                       f"({', '.join(dup) or 'several frames'}): a bracket needs distinct "
                       "exposures")
    return arr


def bracket_data(frames: Sequence[ArrayLike], t: Sequence[float], bits: int, *,
                 layout: str | None = None, bayer_interpolated: bool = False,
                 files: Sequence[str] = (), bloom_radius: int = DEFAULT_BLOOM_RADIUS,
                 border: int = DEFAULT_BORDER, max_pixels: int | None = FIT_PIXELS,
                 exclude: ArrayLike | None = None) -> dict[str, BracketData]:
    """One :class:`BracketData` per channel from frames in memory.

    ``frames`` are integer images of one static scene, all the same shape; ``t`` their nominal
    exposure times in seconds, 1 ns to 1e6 s (any order: the frames are sorted by it); ``bits``
    the ADC depth (codes ``0 .. 2**bits - 1``). Pixels with no usable observation in any frame
    are left out. A bracket whose usable codes do not change with exposure is refused (no code
    range to calibrate).

    ``max_pixels``: at most this many pixels per channel are kept as traces, an even and
    deterministic sample (a regular stride over the flat indices of the pixels with a usable
    code, so spread over the whole frame; ``pixels`` holds their flat indices); ``None`` keeps
    every one. The masks (boundary, blooming), every check (codes, usable pixels, a constant
    bracket) and the comparagrams ``pair_counts`` see every pixel, one frame at a time.

    ``exclude``: pixels (H, W) left out of the traces as the boundary is: where an aligned
    frame has no data (:mod:`ccdcore.response.align`) or something moved
    (:mod:`ccdcore.response.moving`).
    """
    files = tuple(str(f) for f in files) or tuple(f"frame {k}" for k in range(len(frames)))
    times = check_times(list(t), files)
    if len(frames) != times.size:
        raise CcdError(files[0], f"{len(frames)} frames but {times.size} exposure times")
    if bits is None or not 1 <= int(bits) <= 16:
        raise CcdError(files[0], f"bits must be 1..16 (the camera's ADC depth), got {bits!r}")
    if max_pixels is not None and int(max_pixels) < 1:
        raise CcdError(files[0], f"max_pixels must be at least 1 (or None), got {max_pixels!r}")
    levels = 2 ** int(bits)
    arrays = [np.asarray(f) for f in frames]
    negative = False
    for f, a in zip(files, arrays):
        if a.shape != arrays[0].shape:
            raise CcdError(f, f"shape {a.shape} differs from the bracket's first frame "
                              f"{arrays[0].shape}")
        if not np.issubdtype(a.dtype, np.integer):
            raise CcdError(f, f"expected integer codes, got {a.dtype}")
        if a.dtype != arrays[0].dtype:
            raise CcdError(f, f"{a.dtype} samples, the bracket's first frame has "
                              f"{arrays[0].dtype}: frames of one camera setting share a bit "
                              "depth (mixed cameras?)")
        if a.size and int(a.max()) >= levels:
            raise CcdError(f, f"code {int(a.max())} exceeds the camera's {bits} bits")
        if a.size and np.issubdtype(a.dtype, np.signedinteger):
            negative = negative or int(a.min()) < 0
    order = np.argsort(times, kind="stable")
    times = times[order]
    arrays = [arrays[i] for i in order]
    files = tuple(files[i] for i in order)
    lay = chan.check_layout(arrays[0].shape, layout, files[0])
    names = list(chan.split_channels(arrays[0], lay))
    count_pairs = levels <= PAIR_LEVELS_MAX and not negative
    drop = None if exclude is None else np.asarray(exclude, bool)
    if drop is not None and drop.shape != arrays[0].shape[:2]:
        raise CcdError(files[0], f"the excluded pixels' mask has shape {drop.shape}, the "
                                 f"frames {arrays[0].shape[:2]}")
    scans = {name: _PlaneScan(levels, bloom_radius, border, len(arrays), count_pairs, drop)
             for name in names}

    def scan(name: str) -> None:          # one frame at a time, every pixel
        prev = None
        for a in arrays:
            plane = chan.split_channels(a, lay)[name]
            scans[name].add(plane, prev)
            prev = plane

    if SCAN_THREADS > 1 and len(names) > 1:
        with ThreadPoolExecutor(min(SCAN_THREADS, len(names)), "bracket-scan") as pool:
            list(pool.map(scan, names))
    else:
        for name in names:
            scan(name)
    if all(not s.any_usable() for s in scans.values()):
        raise CcdError(files[0], "no usable pixel in the bracket: every code is clipped "
                                 "(all dark or all saturated) or near a saturated pixel")
    for name in names:
        scans[name].refuse_constant(name, files[0])
    out: dict[str, BracketData] = {}
    for name, s in scans.items():
        cols = s.sample(max_pixels)
        z, valid, kept = s.traces([chan.split_channels(a, lay)[name] for a in arrays], cols)
        out[name] = BracketData(z, valid, times, levels, name, s.shape, cols,
                                bayer_interpolated and lay == "rgb", files, kept,
                                s.pairs)
    return out


class _PlaneScan:
    """One channel's pass over a bracket's frames (in increasing exposure), one plane at a time:
    the pixels with a usable code in any frame, the blooming masks (bit-packed), whether any
    pixel's usable code changes (a constant bracket) and the comparagrams of neighbours."""

    def __init__(self, levels: int, bloom_radius: int, border: int, n: int, pairs: bool,
                 exclude: NDArray[np.bool_] | None = None):
        self.levels, self.bloom_radius, self.border, self.n = levels, bloom_radius, border, n
        self.exclude = exclude
        self.shape: tuple[int, int] = (0, 0)
        self.usable_any: NDArray[np.bool_] | None = None
        self.first: NDArray | None = None        # the first usable code of every pixel
        self.changed = False
        self.blooms: list[NDArray[np.uint8] | None] = []
        self.want_pairs = pairs
        self.pairs: NDArray[np.int64] | None = None

    def add(self, plane: NDArray, prev: NDArray | None) -> None:
        L = self.levels
        if self.usable_any is None:
            self.shape = (int(plane.shape[0]), int(plane.shape[1]))
            self.usable_any = np.zeros(self.shape, bool)
            self.first = np.zeros(self.shape, plane.dtype)
            if self.want_pairs and self.n > 1:
                self.pairs = np.zeros((self.n - 1, L, L), np.int64)
        bloom = bloom_mask(plane, L, self.bloom_radius)
        self.blooms.append(np.packbits(bloom, axis=None) if bloom.any() else None)
        usable = preprocess(plane, L, bloom_radius=self.bloom_radius, border=self.border,
                            bloom=bloom)
        if self.exclude is not None:
            usable &= ~self.exclude
        del bloom
        seen = self.usable_any
        if not self.changed:
            self.changed = bool(np.any((plane != self.first) & usable & seen))
            np.copyto(self.first, plane, where=usable & ~seen)
        np.logical_or(seen, usable, out=seen)
        if prev is not None and self.pairs is not None:
            _count_pairs(prev, plane, L, self.pairs[len(self.blooms) - 2])

    def any_usable(self) -> bool:
        return self.usable_any is not None and bool(self.usable_any.any())

    def refuse_constant(self, channel: str, where: str) -> None:
        """One clear error when no pixel of the channel changes its usable code with exposure.

        The response is found from how codes grow with exposure; frames that all hold the same
        codes (a lens cap, a frozen camera, one file copied N times) leave nothing to fit, and
        the estimators would return an arbitrary curve with exit 0.
        """
        if self.changed or not self.any_usable():
            return  # this channel is all clipped; another channel has usable codes
        assert self.first is not None and self.usable_any is not None
        codes = np.unique(self.first[self.usable_any])
        what = (f"every usable code is {int(codes[0])}" if codes.size == 1 else
                f"no usable code changes with exposure ({codes.size} distinct codes, each pixel "
                "constant)")
        raise CcdError(where, f"channel {channel}: {what} in every frame of the bracket: no code "
                              "range to calibrate (frames of a static scene at different "
                              "exposures are needed)")

    def sample(self, max_pixels: int | None) -> NDArray[np.int64]:
        """Flat indices of the kept pixels: every pixel with a usable code, or a regular stride
        of ``max_pixels`` of them (ranks ``i * count // max_pixels``: deterministic, spread over
        the whole frame, in increasing order)."""
        assert self.usable_any is not None
        flat = self.usable_any.reshape(-1)
        count = int(np.count_nonzero(flat))
        if max_pixels is None or count <= int(max_pixels):
            return np.flatnonzero(flat)
        m = int(max_pixels)
        ranks = np.arange(m, dtype=np.int64) * count // m
        out = np.empty(m, np.int64)
        done = seen = 0
        for c0 in range(0, flat.size, _CHUNK):      # the rank-th usable pixel, chunk by chunk
            idx = np.flatnonzero(flat[c0:c0 + _CHUNK])
            stop = int(np.searchsorted(ranks, seen + idx.size))
            out[done:stop] = idx[ranks[done:stop] - seen] + c0
            done, seen = stop, seen + idx.size
        return out

    def traces(self, planes: list[NDArray], cols: NDArray[np.int64]
               ) -> tuple[NDArray[np.int32], NDArray[np.bool_], NDArray[np.bool_]]:
        """``z``, ``valid`` and ``kept`` of the pixels ``cols`` (flat indices): the same values
        :func:`preprocess` and :func:`kept_mask` give on the whole frames."""
        L = self.levels
        h, w = self.shape
        ys, xs = np.divmod(cols, w)
        b = int(self.border)
        if b > 0:
            inside = (ys >= b) & (ys < h - b) & (xs >= b) & (xs < w - b)
        else:
            inside = np.ones(cols.size, bool)
        if self.exclude is not None:
            inside &= ~self.exclude[ys, xs]
        n = len(planes)
        z = np.empty((n, cols.size), np.int32)
        valid = np.empty((n, cols.size), bool)
        kept = np.empty((n, cols.size), bool)
        for k, (plane, packed) in enumerate(zip(planes, self.blooms)):
            z[k] = plane[ys, xs]
            if packed is None:
                bloom = np.zeros(cols.size, bool)
            else:
                bloom = ((packed[cols >> 3] >> (7 - (cols & 7)).astype(np.uint8)) & 1) > 0
            below = z[k] < L - 1
            valid[k] = (z[k] > 0) & below & ~bloom & inside
            kept[k] = ~(bloom & below) & inside
        return z, valid, kept


def _count_pairs(u: NDArray, v: NDArray, levels: int, out: NDArray[np.int64]) -> None:
    """Add to ``out`` (L x L, flattened as ``u * L + v``) the code pairs of two planes, over
    every pixel, in chunks of rows (bounded int64 temporaries)."""
    h, w = u.shape
    rows = max(1, max(_CHUNK, levels * levels) // max(1, w))
    flat = out.reshape(-1)
    for y in range(0, h, rows):
        key = u[y:y + rows].astype(np.intp)
        key *= levels
        key += v[y:y + rows]
        flat += np.bincount(key.reshape(-1), minlength=levels * levels)


def bracket_records(session: Any, stack: Any = None, *, role: str = "bracket") -> list[Any]:
    """The frame records of the bracket ``stack`` of ``session`` (the first when ``None``), in
    increasing exposure when every frame has one; a clear error when there is no such bracket."""
    stacks = session.bracket_stacks(role)
    if not stacks:
        raise CcdError(getattr(session, "root", "session"),
                       f"no '{role}' frames: capture an exposure bracket of a static scene "
                       f"(role = \"{role}\", one 'exposure' per frame)")
    if stack is None:
        stack = next(iter(stacks))
    if stack not in stacks:
        raise CcdError(getattr(session, "root", "session"),
                       f"no bracket stack {stack!r}; the session has "
                       f"{', '.join(str(s) for s in stacks)}")
    records = list(stacks[stack])
    if all(isinstance(r.exposure, (int, float)) for r in records):
        records.sort(key=lambda r: r.exposure)
    return records


def load_bracket(session: Any, stack: Any = None, *, role: str = "bracket",
                 bloom_radius: int = DEFAULT_BLOOM_RADIUS, border: int = DEFAULT_BORDER,
                 bayer_interpolated: bool = False, frames: Sequence[ArrayLike] | None = None,
                 max_pixels: int | None = FIT_PIXELS, exclude: ArrayLike | None = None,
                 records: Sequence[Any] | None = None) -> dict[str, BracketData]:
    """The bracket ``stack`` of ``session`` (the first when ``None``) per channel.

    Exposure times come from the manifest (``exposure`` of each frame); the bit depth from the
    camera (``[camera] bits``). Pass ``bayer_interpolated=True`` when the colour frames were
    interpolated from a Bayer mosaic (eq. 12's extra factor): the manifest does not record it.
    ``frames``: the frames already read, in :func:`bracket_records` order (not read again).
    ``max_pixels``: pixels per channel kept as traces (:func:`bracket_data`; ``None`` every one).
    ``exclude``: pixels left out of the traces (:func:`bracket_data`). ``records``: the frames'
    records when not all of the stack's (frames left out), in the order of ``frames``.
    """
    records = bracket_records(session, stack, role=role) if records is None else list(records)
    if hasattr(session, "raise_if_invalid"):
        # the session's own line first: an exposure of 0 or 1e300 is dropped there with its
        # reason, and reading the frames on would only say "missing exposure"
        session.raise_if_invalid(roles=(role,))
    cam = session.camera
    files = [r.relpath for r in records]
    if cam.bits is None:
        raise CcdError(files[0], "the camera's bit depth is unknown: give [camera] bits in the "
                                 "manifest (the response has 2**bits values)")
    if frames is None:
        frames = [session.read(r) for r in records]
    return bracket_data(frames, [r.exposure for r in records], cam.bits, layout=cam.layout,
                        bayer_interpolated=bayer_interpolated, files=files,
                        bloom_radius=bloom_radius, border=border, max_pixels=max_pixels,
                        exclude=exclude)
