"""The dark reference D̂_D(a, b) as a result and as a map (sec. V-A of Healey & Kondepudy 1994).

The type the dark estimate returns and the one conversion every user of D̂_D makes, below both
:mod:`ccdcore.dark.frame` (which estimates it from dark frames) and the modules that subtract it,
streamed (:mod:`ccdcore.fixedpattern`, :mod:`ccdcore.flatfield.fit`) or on a Dask cluster
(:mod:`ccdcore.distributed.client`).  Nothing here reads files or estimates anything; both names are
re-exported by :mod:`ccdcore.dark.frame`, their usual address.

Public objects
--------------
DarkReference
    Frozen result: mean map D̂_D, variance map, s, mean, spatial std, hot/dead masks and rules.
DarkSummary
    The record a calibration product stores of it (:meth:`DarkReference.summary`; no maps),
    with its displayable ``rows()``.
as_dark_map(dark, where="dark")
    D̂_D as a float64 array from a :class:`DarkReference`, an array or a scalar.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..common import json_safe
from .model import DarkModelSummary
from ..errors import CcdError
from ..records import OMIT_NONE, Record, Row

__all__ = ["DarkReference", "DarkSummary", "as_dark_map"]


@dataclass(frozen=True, eq=False)
class DarkReference:
    """The dark reference image D̂_D(a, b) of sec. V-A (Healey & Kondepudy 1994).

    Attributes
    ----------
    mean_map
        D̂_D(a, b): per-pixel mean of the ``s`` dark frames, float64 (H, W), DN.
    var_map
        Per-pixel temporal sample variance (ddof = 1), an estimate of σ²_N(a, b) (eq. 43).
    s
        Number of dark frames averaged.
    mean, spatial_std
        Mean and standard deviation (ddof = 0) of D̂_D over the array (paper, sec. VII-A: 10.74
        and 0.555).  The spatial std includes the noise of the average, σ²_N/s; see
        :attr:`spatial_std_signal` for the part that is dark-signal nonuniformity.
    hot_mask, dead_mask
        Boolean (H, W) flags; the rules in ``hot_rule`` / ``dead_rule`` (see
        :mod:`ccdcore.dark.frame`).
    exposure
        Exposure time of the dark frames (seconds) when known and common, else ``None``.
    notes
        Diagnostics (rules skipped, frames of several exposures ...).
    frames
        Relative paths of the dark frames it was made from (when known).
    err_var_map
        The error variance of D̂_D per pixel when it is not ``var_map/s`` (a dark from the
        dark model o + c·t, :mod:`ccdcore.dark.model`), else ``None``.
    model
        The dark model's summary when D̂_D came from it.
    """

    mean_map: np.ndarray
    var_map: np.ndarray
    s: int
    mean: float
    spatial_std: float
    hot_mask: np.ndarray
    dead_mask: np.ndarray
    hot_rule: str
    dead_rule: str
    exposure: float | None = None
    notes: tuple[str, ...] = ()
    frames: tuple[str, ...] = ()
    err_var_map: np.ndarray | None = None
    model: DarkModelSummary | None = None

    @property
    def shape(self) -> tuple[int, ...]:
        return self.mean_map.shape

    @property
    def sem_map(self) -> np.ndarray:
        """Standard error of D̂_D per pixel, ``sqrt(var_map / s)`` (σ_N/√s, sec. V-A), or the
        dark model's (``sqrt(err_var_map)``)."""
        if self.err_var_map is not None:
            return np.sqrt(self.err_var_map)
        return np.sqrt(self.var_map / self.s)

    @property
    def noise_var(self) -> float:
        """Mean temporal variance of a dark pixel, σ²_N at the dark level (DN²)."""
        return float(np.nanmean(self.var_map))

    @property
    def spatial_std_signal(self) -> float:
        """Spatial std of the dark signal with the noise of the average removed:
        ``sqrt(max(spatial_std² − mean(var_map)/s, 0))``."""
        if self.s < 2:
            return float("nan")
        return math.sqrt(max(self.spatial_std ** 2 - self.noise_var / self.s, 0.0))

    def summary(self) -> DarkSummary:
        """The summary statistics (no maps) as the record a product stores
        (``estimates["dark"]``): plain numbers, NaN as ``None``."""
        good = ~(self.hot_mask | self.dead_mask)
        several = self.s > 1
        return DarkSummary(
            s=int(self.s), shape=tuple(int(n) for n in self.mean_map.shape),
            mean=json_safe(float(self.mean)), spatial_std=json_safe(float(self.spatial_std)),
            spatial_std_signal=json_safe(self.spatial_std_signal),
            mean_sem=json_safe(float(np.sqrt(self.noise_var / self.s / self.mean_map.size)))
            if several else None,
            noise_var=json_safe(self.noise_var) if several else None,
            mean_good=json_safe(float(self.mean_map[good].mean())) if good.any() else None,
            spatial_std_good=json_safe(float(self.mean_map[good].std())) if good.any() else None,
            n_hot=int(self.hot_mask.sum()), n_dead=int(self.dead_mask.sum()),
            hot_rule=self.hot_rule, dead_rule=self.dead_rule,
            exposure=json_safe(self.exposure), notes=tuple(self.notes), model=self.model)

    def to_dict(self) -> dict[str, Any]:
        """Summary statistics only (no maps), JSON-friendly: :meth:`summary` as its JSON
        object."""
        return self.summary().to_dict()


@dataclass(frozen=True)
class DarkSummary(Record):
    """The dark reference D̂_D of sec. V-A as a product stores it (``estimates["dark"]``,
    :meth:`DarkReference.summary`): its statistics, hot and dead pixels and their rules; the
    maps are stored apart."""

    #: number of dark frames averaged, and the shape (H, W) of D̂_D
    s: int
    shape: tuple[int, int]
    #: mean and spatial standard deviation (ddof = 0) of D̂_D (paper, sec. VII-A: 10.74 and
    #: 0.555), DN
    mean: float
    spatial_std: float
    #: the spatial std without the noise of the average σ²_N/s, DN (``None`` when s < 2)
    spatial_std_signal: float | None
    #: standard error of the mean level, DN, and the mean temporal variance σ²_N of a dark
    #: pixel (eq. 43), DN² (``None`` for one frame)
    mean_sem: float | None
    noise_var: float | None
    #: mean and spatial std of D̂_D over the pixels neither hot nor dead, DN (``None``: none)
    mean_good: float | None
    spatial_std_good: float | None
    #: hot and dead pixels flagged, and their rules in words
    n_hot: int
    n_dead: int
    hot_rule: str
    dead_rule: str
    #: exposure time of the dark frames (s), when known and common
    exposure: float | None = None
    #: diagnostics (rules skipped, frames of several exposures ...)
    notes: tuple[str, ...] = ()
    #: the dark model o + c·t D̂_D came from (:mod:`ccdcore.dark.model`), when it did
    model: DarkModelSummary | None = field(default=None, metadata=OMIT_NONE)

    def rows(self) -> tuple[Row, ...]:
        """The headline figures: frames, exposure, mean level, spatial spread, temporal noise,
        hot and dead pixels."""
        return (
            Row("frames s", self.s, meaning="dark frames averaged into D̂_D (sec. V-A)"),
            Row("exposure", self.exposure, None, "s", "exposure time of the dark frames"),
            Row("mean level", self.mean, self.mean_sem, "DN",
                "mean of D̂_D ± its standard error"),
            Row("spatial std", self.spatial_std, None, "DN", "of D̂_D"),
            Row("spatial std of the signal", self.spatial_std_signal, None, "DN",
                "without the averaging noise σ²_N/s"),
            Row("temporal noise σ²_N", self.noise_var, None, "DN²",
                "mean per-pixel variance (eq. 43)"),
            Row("hot pixels", self.n_hot, meaning=self.hot_rule),
            Row("dead pixels", self.n_dead, meaning=self.dead_rule),
        ) + (() if self.model is None else self.model.rows())


def as_dark_map(dark: DarkReference | np.ndarray | float, where: str = "dark") -> np.ndarray:
    """D̂_D as a float64 array from a :class:`DarkReference`, an array, or a scalar."""
    if isinstance(dark, DarkReference):
        return dark.mean_map
    if dark is None:
        raise CcdError(where, "no dark reference D̂_D given (sec. V-A): compute one with "
                              "dark_reference() from dark frames")
    return np.asarray(dark, dtype=np.float64)
