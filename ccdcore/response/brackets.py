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
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from .. import channels as chan
from ..errors import CcdError
from ..session.records import MAX_EXPOSURE, MIN_EXPOSURE

__all__ = ["BracketData", "load_bracket", "bracket_records", "bracket_data", "check_times", "preprocess", "bloom_mask", "kept_mask",
           "BAYER_MAD_FACTOR",
           "DEFAULT_BLOOM_RADIUS", "MAX_BLOOM_RADIUS", "DEFAULT_BORDER"]

#: radius (pixels) around a saturated pixel whose codes are dropped (sec. 2: "usually 3 pixels")
DEFAULT_BLOOM_RADIUS = 3
#: largest blooming radius accepted: the disk's cost grows with its area (3000 asks 596 GiB, 300
#: takes 83 s on a 64x48 frame), and a halo wider than this is lens flare, not blooming
MAX_BLOOM_RADIUS = 64
#: width (pixels) of the frame boundary dropped (sec. 3.2, step 1: "boundary pixels")
DEFAULT_BORDER = 1

#: eq. 12: the MAD sigma's second factor for colour channels interpolated from a Bayer mosaic
#: (correlated neighbours): 1.265 for green, 1.333 for red and blue; 1 otherwise
BAYER_MAD_FACTOR: dict[str, float] = {"R": 1.333, "G": 1.265, "B": 1.333}


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

    def take(self, columns: ArrayLike) -> "BracketData":
        """The same bracket restricted to the pixel columns ``columns`` (a subsample of pixels)."""
        idx = np.asarray(columns)
        return BracketData(self.z[:, idx], self.valid[:, idx], self.t, self.levels, self.channel,
                           self.shape, self.pixels[idx] if self.pixels.size else self.pixels,
                           self.bayer_interpolated, self.files,
                           None if self.kept is None else self.kept[:, idx])


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
    if radius <= 0 or not saturated.any():
        return np.zeros(z.shape, bool)
    r = int(radius)
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    disk = (yy * yy + xx * xx) <= r * r
    ys, xs = np.nonzero(saturated)
    if ys.size * disk.sum() > z.size:
        return ndimage.binary_dilation(saturated, structure=disk)
    # few saturated pixels (lights in a scene): mark the disk around each one directly
    out = np.zeros(z.shape, bool)
    h, w = z.shape
    for dy, dx in zip(yy[disk].tolist(), xx[disk].tolist()):
        y, x = ys + dy, xs + dx
        ok = (y >= 0) & (y < h) & (x >= 0) & (x < w)
        out[y[ok], x[ok]] = True
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
                 border: int = DEFAULT_BORDER) -> dict[str, BracketData]:
    """One :class:`BracketData` per channel from frames in memory.

    ``frames`` are integer images of one static scene, all the same shape; ``t`` their nominal
    exposure times in seconds, 1 ns to 1e6 s (any order: the frames are sorted by it); ``bits``
    the ADC depth (codes ``0 .. 2**bits - 1``). Pixels with no usable observation in any frame
    are left out. A bracket whose usable codes do not change with exposure is refused (no code
    range to calibrate).
    """
    files = tuple(str(f) for f in files) or tuple(f"frame {k}" for k in range(len(frames)))
    times = check_times(list(t), files)
    if len(frames) != times.size:
        raise CcdError(files[0], f"{len(frames)} frames but {times.size} exposure times")
    if bits is None or not 1 <= int(bits) <= 16:
        raise CcdError(files[0], f"bits must be 1..16 (the camera's ADC depth), got {bits!r}")
    levels = 2 ** int(bits)
    arrays = [np.asarray(f) for f in frames]
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
    order = np.argsort(times, kind="stable")
    times = times[order]
    arrays = [arrays[i] for i in order]
    files = tuple(files[i] for i in order)
    lay = chan.check_layout(arrays[0].shape, layout, files[0])
    split = [chan.split_channels(a, lay) for a in arrays]
    out: dict[str, BracketData] = {}
    for name in split[0]:
        planes = [s[name] for s in split]
        h, w = planes[0].shape
        blooms = [bloom_mask(p, levels, bloom_radius) for p in planes]
        valid = np.stack([preprocess(p, levels, bloom_radius=bloom_radius, border=border,
                                     bloom=m) for p, m in zip(planes, blooms)]
                         ).reshape(len(planes), -1)
        kept = np.stack([kept_mask(p, levels, bloom_radius=bloom_radius, border=border,
                                   bloom=m) for p, m in zip(planes, blooms)]
                        ).reshape(len(planes), -1)
        z = np.stack([p.reshape(-1) for p in planes]).astype(np.int32)
        keep = np.flatnonzero(valid.any(axis=0))
        out[name] = BracketData(z[:, keep], valid[:, keep], times, levels, name, (h, w), keep,
                                bayer_interpolated and lay == "rgb", files, kept[:, keep])
    if all(not d.valid.any() for d in out.values()):
        raise CcdError(files[0], "no usable pixel in the bracket: every code is clipped "
                                 "(all dark or all saturated) or near a saturated pixel")
    for d in out.values():
        _refuse_constant(d, files[0])
    return out


def _refuse_constant(d: BracketData, where: str) -> None:
    """One clear error when no pixel of the channel changes its usable code with exposure.

    The response is found from how codes grow with exposure; frames that all hold the same codes
    (a lens cap, a frozen camera, one file copied N times) leave nothing to fit, and the
    estimators would return an arbitrary curve with exit 0.
    """
    if not d.valid.any():
        return  # this channel is all clipped; another channel has usable codes
    big = np.iinfo(np.int32).max
    low = np.where(d.valid, d.z, big).min(axis=0)
    high = np.where(d.valid, d.z, -1).max(axis=0)
    if np.any(high > low):
        return
    codes = np.unique(d.z[d.valid])
    what = (f"every usable code is {int(codes[0])}" if codes.size == 1 else
            f"no usable code changes with exposure ({codes.size} distinct codes, each pixel "
            "constant)")
    raise CcdError(where, f"channel {d.channel}: {what} in every frame of the bracket: no code "
                          "range to calibrate (frames of a static scene at different exposures "
                          "are needed)")


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
                 bayer_interpolated: bool = False, frames: Sequence[ArrayLike] | None = None
                 ) -> dict[str, BracketData]:
    """The bracket ``stack`` of ``session`` (the first when ``None``) per channel.

    Exposure times come from the manifest (``exposure`` of each frame); the bit depth from the
    camera (``[camera] bits``). Pass ``bayer_interpolated=True`` when the colour frames were
    interpolated from a Bayer mosaic (eq. 12's extra factor): the manifest does not record it.
    ``frames``: the frames already read, in :func:`bracket_records` order (not read again).
    """
    records = bracket_records(session, stack, role=role)
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
                        bloom_radius=bloom_radius, border=border)
