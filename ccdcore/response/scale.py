"""The scale every response curve is reported in, and curve comparisons.

A response ``g`` maps a code ``z`` to a value proportional to the exposure ``a E`` (plus the
white-balance offset ``b``, eq. 5 of Tsin et al. 2001). Its scale is free: ``s g`` explains the
same images with ``E / s``; with free offsets (white balance on) so is a shift. ccdcore reports
every method's ``g`` on one documented scale (docs/response.md):

* the **scale** puts ``g(z_hi) = z_hi / (levels - 1)`` at the reference code
  ``z_hi = round(0.9 (levels - 1))`` (230 for 8 bits: 229.5 rounds half to even): g reads as
  "fraction of full scale" near the top, where every bracket has data;
* where the offsets are free too (white balance on), an offset of g and one of the radiance
  are free as well; estimators fit with ``g(z_lo)`` fixed too, at ``z_lo = round(0.2 (levels -
  1))`` (51 for 8 bits: the two fixed points of sec. 3.2), and report the offsets b_k of
  smallest norm (``ccdcore.response.tsin.estimator``).

Public objects
--------------
reference_codes(levels)
    ``(z_lo, z_hi)``.
normalize(g, levels, offset=False)
    ``g`` scaled (and shifted when ``offset``) onto the reported scale; returns the new curve and
    the factor (and shift) applied.
Knots(levels)
    The knots at which estimators solve for g (every code up to ``MAX_NODES`` levels, evenly
    spread beyond), with linear interpolation between them.
rms_error(g, truth, z_range=(5, 250), offset=False)
    RMS of ``g - truth`` over the codes in ``z_range`` after the free scale (and offset) of ``g``
    is fitted to ``truth`` by least squares: the figure of sec. 4.1.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["reference_codes", "normalize", "rms_error", "aligned", "Knots", "MAX_NODES"]

#: most knots at which a response is estimated (deeper codes are interpolated linearly)
MAX_NODES = 1024


def reference_codes(levels: int) -> tuple[int, int]:
    """The two reference codes ``(z_lo, z_hi)`` of a ``levels``-code response."""
    top = int(levels) - 1
    return int(round(0.2 * top)), int(round(0.9 * top))


def normalize(g: ArrayLike, levels: int, offset: bool = False
              ) -> tuple[NDArray[np.float64], float, float]:
    """``(s g + c, s, c)``: ``g`` on the reported scale (``c = 0`` unless ``offset``)."""
    g = np.asarray(g, dtype=np.float64)
    lo, hi = reference_codes(levels)
    top = float(levels - 1)
    if offset:
        span = g[hi] - g[lo]
        if not span > 0:
            raise ValueError("the response is not increasing between its reference codes")
        s = (hi - lo) / top / span
        c = lo / top - s * g[lo]
    else:
        if not g[hi] > 0:
            raise ValueError("the response is not positive at its reference code")
        s, c = hi / top / g[hi], 0.0
    return s * g + c, float(s), float(c)


def aligned(g: ArrayLike, truth: ArrayLike, z_range: tuple[int, int] = (5, 250),
            offset: bool = False) -> NDArray[np.float64]:
    """``g`` scaled (and shifted when ``offset``) to fit ``truth`` best over ``z_range``
    (least squares); the whole curve is returned."""
    g = np.asarray(g, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    z = np.arange(int(z_range[0]), int(z_range[1]) + 1)
    x, y = g[z], truth[z]
    if offset:
        A = np.stack([x, np.ones_like(x)], axis=1)
        (s, c), *_ = np.linalg.lstsq(A, y, rcond=None)
    else:
        s, c = float(x @ y) / float(x @ x), 0.0
    return s * g + c


def rms_error(g: ArrayLike, truth: ArrayLike, z_range: tuple[int, int] = (5, 250),
              offset: bool = False) -> float:
    """RMS of the aligned ``g`` against ``truth`` over ``z_range`` (inclusive)."""
    z = np.arange(int(z_range[0]), int(z_range[1]) + 1)
    d = aligned(g, truth, z_range, offset)[z] - np.asarray(truth, dtype=np.float64)[z]
    return float(np.sqrt(np.mean(d * d)))


class Knots:
    """g at ``n`` knots spread evenly over the codes (every code up to MAX_NODES levels)."""

    def __init__(self, levels: int):
        self.levels = int(levels)
        self.n = min(self.levels, MAX_NODES)
        self.identity = self.n == self.levels
        self.step = (self.levels - 1) / (self.n - 1)
        self.codes = np.linspace(0.0, self.levels - 1, self.n)

    def locate(self, z: NDArray) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Knot ``j0`` and fraction ``f``: g(z) = (1 - f) g[j0] + f g[j0 + 1]."""
        if self.identity:
            return np.asarray(z, dtype=np.int64), np.zeros(np.shape(z))
        u = np.asarray(z, dtype=np.float64) / self.step
        j0 = np.clip(np.floor(u).astype(np.int64), 0, self.n - 2)
        return j0, u - j0

    def terms(self, z: NDArray) -> list[tuple[NDArray[np.int64], NDArray[np.float64]]]:
        """The knots and coefficients each code contributes to (one or two terms)."""
        j0, f = self.locate(z)
        if self.identity:
            return [(j0, np.ones(np.shape(z)))]
        return [(j0, 1.0 - f), (j0 + 1, f)]
