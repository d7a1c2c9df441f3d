"""Streamed per-pixel statistics over frame stacks, in memory bounded by a few frames.

Public objects
--------------
:class:`PixelMoments`
    Accumulates per-pixel count, mean and variance one frame at a time.
:func:`pixel_moments`
    Runs :class:`PixelMoments` over any iterable of frames.
:class:`MomentsResult`
    Frozen result: per-pixel mean, unbiased variance, and the number of frames.
:func:`pair_statistics`
    μ̂, σ̂²_N and var[σ̂²_N] of one pair of frames (Healey & Kondepudy 1994, eqs. 37, 38, 40).

The accumulation is the shifted-data algorithm: sums of ``x - x_0`` and ``(x - x_0)**2`` in
float64, with ``x_0`` the first frame, fused into one compiled pass per frame (numba), about three
times faster than the equivalent four numpy passes (``benchmarks/bench_session_stream.py``). For integer data of up to 16 bits over any realistic number
of frames the sums stay far below 2**53, so the result equals the two-pass mean and variance to
rounding error (the test checks it against ``numpy.mean``/``numpy.var``), while memory holds three
float64 frames whatever the number of frames.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numba
import numpy as np
from numpy.typing import ArrayLike

from .errors import CcdError

__all__ = ["PixelMoments", "MomentsResult", "pixel_moments", "pair_statistics"]


@dataclass(frozen=True)
class MomentsResult:
    """Per-pixel mean and variance of ``n`` frames.

    Attributes
    ----------
    mean
        Per-pixel mean (float64).
    var
        Per-pixel unbiased variance (``ddof=1``; NaN where ``n < 2``).
    n
        Number of frames.
    """

    mean: np.ndarray
    var: np.ndarray
    n: int

    @property
    def sem(self) -> np.ndarray:
        """Standard error of the per-pixel mean, ``sqrt(var / n)``."""
        return np.sqrt(self.var / self.n)

    def to_dict(self) -> dict:
        return {"n": self.n, "shape": list(self.mean.shape),
                "mean_of_mean": float(np.mean(self.mean)),
                "mean_of_var": float(np.nanmean(self.var)) if self.n > 1 else None}


@numba.njit(cache=True, nogil=True)
def _accumulate(frame, shift, s1, s2):  # pragma: no cover - compiled
    """One fused pass: ``s1 += x - x0``, ``s2 += (x - x0)**2`` (all C-contiguous, same size)."""
    x = frame.ravel()
    x0 = shift.ravel()
    a = s1.ravel()
    b = s2.ravel()
    for i in range(x.size):
        d = np.float64(x[i]) - x0[i]
        a[i] += d
        b[i] += d * d


class PixelMoments:
    """Accumulate per-pixel mean and variance frame by frame.

    Examples
    --------
    >>> acc = PixelMoments()
    >>> for frame in (np.full((2, 2), 3), np.full((2, 2), 5)):
    ...     acc.add(frame)
    >>> acc.result().mean[0, 0], acc.result().var[0, 0]
    (4.0, 2.0)
    """

    def __init__(self) -> None:
        self._shift: np.ndarray | None = None
        self._s1: np.ndarray | None = None
        self._s2: np.ndarray | None = None
        self.n = 0

    def add(self, frame: np.ndarray, *, name: str | None = None) -> None:
        """Add one frame (any numeric dtype); ``name`` is used in the shape-mismatch error."""
        a = np.asarray(frame)
        if self._shift is None:
            if a.size == 0:
                raise CcdError(name, "empty frame")
            self._shift = a.astype(np.float64)
            self._s1 = np.zeros(a.shape, np.float64)
            self._s2 = np.zeros(a.shape, np.float64)
        elif a.shape != self._shift.shape:
            raise CcdError(name, f"frame shape {a.shape} differs from the first frame's "
                                 f"{self._shift.shape}")
        if a.dtype.kind not in "uifb":
            raise CcdError(name, f"cannot average frames of dtype {a.dtype}")
        _accumulate(np.ascontiguousarray(a), self._shift, self._s1, self._s2)
        self.n += 1

    def result(self, *, in_place: bool = False) -> MomentsResult:
        """The per-pixel mean and unbiased variance of the frames added so far.

        With ``in_place`` the mean and the variance are written over the accumulator's own
        buffers (no new memory: for a caller that is done with the accumulator); it is then
        empty again (``n = 0``) and ready for frames of any shape.
        """
        if self.n == 0:
            raise CcdError(None, "no frames to average")
        n = self.n
        shift, s1, s2 = self._shift, self._s1, self._s2
        if in_place:
            mean, var = shift, s2
            self._shift = self._s1 = self._s2 = None
            self.n = 0
        else:
            mean, var = np.empty_like(shift), np.empty_like(s2)
        _finish(shift, s1, s2, n, mean, var)
        return MomentsResult(mean=mean, var=var, n=n)


@numba.njit(cache=True, nogil=True)
def _finish(shift, s1, s2, n, mean, var):  # pragma: no cover - compiled
    """One pass: ``mean = x0 + s1/n`` and ``var = max((s2 − s1·s1/n)/(n − 1), 0)`` (NaN for
    n = 1), element by element with the operations of the formulas (``mean`` may be ``shift``
    and ``var`` may be ``s2``: each element is read before it is written)."""
    a = s1.ravel()
    b = s2.ravel()
    x0 = shift.ravel()
    m = mean.ravel()
    v = var.ravel()
    for i in range(a.size):
        ai = a[i]
        bi = b[i]
        m[i] = x0[i] + ai / n
        if n > 1:
            w = (bi - ai * ai / n) / (n - 1)
            v[i] = 0.0 if w < 0.0 else w
        else:
            v[i] = np.nan


def pixel_moments(frames: Iterable[np.ndarray]) -> MomentsResult:
    """Per-pixel mean and variance of a stream of frames (see :class:`PixelMoments`).

    ``frames`` may yield arrays or ``(record, array)`` pairs such as
    :meth:`ccdcore.session.Session.iter_frames` gives.
    """
    acc = PixelMoments()
    for item in frames:
        if isinstance(item, tuple):
            rec, arr = item
            acc.add(arr, name=getattr(rec, "relpath", None))
        else:
            acc.add(item)
    return acc.result()


def pair_statistics(d1: ArrayLike, d2: ArrayLike) -> tuple[float, float, float, int]:
    """μ̂, σ̂²_N, var[σ̂²_N] and M of one pair of frames (ROI already applied).

    μ̂ is the mean of both frames (eq. 37); σ̂²_N the sample variance of the difference image
    D_Δ = D₁ − D₂ divided by two, Σ(D_Δ − μ̂_Δ)²/(2(M − 1)) (eqs. 31, 38); and
    var[σ̂²_N] ≈ 2(σ̂²_N)²/(M − 1) (eq. 40, normal pixels).  Computed in float64.

    Raises
    ------
    CcdError
        Shapes differ or the frames have fewer than two pixels.
    """
    a = np.asarray(d1, dtype=np.float64)
    b = np.asarray(d2, dtype=np.float64)
    if a.shape != b.shape:
        raise CcdError("pair_statistics", f"frame shapes differ: {a.shape} and {b.shape}")
    m = int(a.size)
    if m < 2:
        raise CcdError("pair_statistics", "a pair needs at least two pixels per frame")
    mu = (a.sum() + b.sum()) / (2.0 * m)                         # eq. 37
    diff = a - b                                                 # eq. 31
    del a, b
    diff -= diff.mean()                                          # in place: (D_Δ − μ̂_Δ)²
    diff *= diff
    var = float(np.sum(diff) / (2.0 * (m - 1)))                  # eq. 38
    var_var = 2.0 * var * var / (m - 1)                          # eq. 40
    return float(mu), var, float(var_var), m
