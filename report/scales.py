"""Colour scales of maps and frames: a colour range from percentiles of a plane's values.

Pure NumPy, shared by the report's maps and the app's image views (:mod:`ccdcore_app.plots.base`
imports it from here).

Public objects
--------------
PERCENTILE_SAMPLES
    Most values a percentile is taken from (a regular subsample beyond).
subsample(values)
    A regular subsample of at most ``PERCENTILE_SAMPLES`` values (for percentiles and medians).
auto_clim(values, lower=0.5, upper=99.5)
    Colour range from percentiles of the finite values.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["PERCENTILE_SAMPLES", "subsample", "auto_clim"]

#: most pixels used for percentiles (a regular subsample keeps auto-range fast on big frames)
PERCENTILE_SAMPLES = 1_000_000


def subsample(values: NDArray) -> NDArray:
    """A regular subsample of at most ``PERCENTILE_SAMPLES`` values (all of them if fewer)."""
    flat = np.ravel(values)
    step = max(1, flat.size // PERCENTILE_SAMPLES)
    return flat[::step]


def auto_clim(values: NDArray, lower: float = 0.5, upper: float = 99.5) -> tuple[float, float]:
    """Colour range ``(lo, hi)`` from the ``lower`` and ``upper`` percentiles of the finite values.

    A flat (or empty) plane gives a range of width 1 around its value so the colour map stays
    defined.
    """
    if not 0 <= lower < upper <= 100:
        raise ValueError(f"lower, upper: need 0 <= lower < upper <= 100, got {lower}, {upper}")
    sample = subsample(values)
    if sample.dtype.kind == "f":
        sample = sample[np.isfinite(sample)]
    if sample.size == 0:
        return (0.0, 1.0)
    lo, hi = np.percentile(sample, [lower, upper])
    lo, hi = float(lo), float(hi)
    if not hi > lo:
        lo, hi = lo - 0.5, lo + 0.5
    return (lo, hi)
