"""The spatial nonuniformity section of an EMVA 1288 datasheet: the row, column and pixel parts
of DSNU and PRNU, the spectrograms, the defect-pixel histograms and the profiles.

Definitions are those of EMVA Standard 1288 release 4.0 (the split of the spatial variance,
its eqs. for s²_y.cav, s²_y.rav, s²_y.col, s²_y.row, s²_y.pixel) and release 3.1 sec. 8 (the
spectrograms, histograms and profiles), *as the reference implementation computes them* (the
``emva1288`` package 1.0.2: ``Data1288._get_spatial_data``, ``Results1288.s_2_y_*``,
``DSNU1288_*``, ``PRNU1288_*``, ``routines.FFT1288``, ``routines.Histogram1288``,
``routines.high_pass_filter``, ``plotting.ProfileBase``), except where the package is unsound
(each departure is named where it is made and in ``docs/emva.md``).

The inputs are the *average images* ⟨y⟩ of the two spatial sets of sec. 8 (L bright frames at
one operating point, L_dark dark frames at its exposure) and their mean per-pixel temporal
variance σ²_y.stack (L − 1 in the denominator).

Variance split (release 4.0)
----------------------------
With M rows, N columns, μ_y the mean of ⟨y⟩, μ_y[n] the column means and μ_y[m] the row means:

* s²_y.cav = (1/N) Σ_n (μ_y[n] − μ_y)² − σ²_y.stack / (L M)  (variance of the column averages),
* s²_y.rav = (1/M) Σ_m (μ_y[m] − μ_y)² − σ²_y.stack / (L N)  (variance of the row averages),
* s²_y.col = [(MN − M) s²_y.cav − N (s²_y − s²_y.rav)] / (MN − M − N),
* s²_y.row = [(MN − N) s²_y.rav − M (s²_y − s²_y.cav)] / (MN − M − N),
* s²_y.pixel = MN (s²_y − s²_y.cav − s²_y.rav) / (MN − M − N),

with s²_y = var(⟨y⟩) (ddof 1) − σ²_y.stack / L (release 3.1 eq. 36, :class:`SpatialSet`).
DSNU1288.part = s_y.part.dark / K (e⁻) and PRNU1288.part = 100 √(s²_y.part − s²_y.part.dark) /
(μ_y − μ_y.dark) (%).

Errors. Once the pattern is fixed, the only random part of ⟨y⟩ is the temporal noise left in
it, white with variance σ²_n = σ²_y.stack / L per pixel. The sums of squares of the row means,
of the column means and of the residual (two-way analysis of variance) are projections of ⟨y⟩
on orthogonal subspaces of M − 1, N − 1 and (M − 1)(N − 1) dimensions, so their noise parts are
independent, each with variance 4 σ²_n SS_pattern + 2 σ⁴_n dof (Gaussian noise). Every part is a
linear combination of the three sums (its coefficients are computed, not written out), so its
error is exact to first order; K's error enters DSNU, and the bright and dark sets are
independent.

A part whose variance is not above zero by two of its standard errors is *not determinable*:
``None``, with its reason and the upper bound it gives (√ of the variance plus two errors).
The package returns NaN for a negative variance and a number for any positive one.

Public objects
--------------
VarianceSplit, variance_split(avg, s2_stack, L)
    The split of one average image.
NonuniformitySplit, nonuniformity_split(bright, dark, K, K_err)
    DSNU1288 and PRNU1288 as row, column and pixel parts with their errors and notes.
spectrogram(image, vertical=False)
    The EMVA spectrogram of an image: frequency (cycles per pixel) and amplitude (DN).
high_pass(image, size=5)
    The image less its size × size box mean (sec. 8.3's filter), valid part only.
defect_histogram(values, bins=256, quantum=None), accumulated_histogram(values, bins=256)
    The logarithmic and accumulated histograms of sec. 8.3.
profiles(image, vertical=False, points=1024)
    Mean, minimum, maximum and middle line of an image across one axis.
SpatialPlots, spatial_plots(bright_avg, dark_avg, ...)
    Every array of the section's plots, JSON-safe through ``to_dict()``.
VarianceSplitSummary, NonuniformitySplitSummary, SpatialPlotsSummary
    The records ``calibration.json`` stores (``summary()`` of the three results), with the
    records nested in the plots: SpectrogramsSummary, SpectrogramSummary, SpatialLevelsSummary,
    HistogramsSummary, HistogramSummary, AccumulatedSummary, AccumulatedHistogramSummary,
    ProfilesSummary, ProfileSummary.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Callable, Mapping, TypeVar

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import uniform_filter

from ..common import json_safe
from ..records import Record, Row

__all__ = ["VarianceSplit", "variance_split", "NonuniformitySplit", "nonuniformity_split",
           "spectrogram", "high_pass", "defect_histogram", "accumulated_histogram", "profiles",
           "SpatialPlots", "spatial_plots", "PARTS", "HIGH_PASS_SIZE", "HISTOGRAM_BINS",
           "DETERMINABLE_Z", "VarianceSplitSummary", "NonuniformitySplitSummary",
           "SpatialPlotsSummary", "SpectrogramsSummary", "SpectrogramSummary",
           "SpatialLevelsSummary", "HistogramsSummary", "HistogramSummary", "AccumulatedSummary",
           "AccumulatedHistogramSummary", "ProfilesSummary", "ProfileSummary"]

#: the parts of the split, in the standard's order
PARTS = ("row", "col", "pixel")
#: the box of sec. 8.3's high-pass filter (pixels)
HIGH_PASS_SIZE = 5
#: the most bins of a histogram (``Results1288._histogram_Qmax``)
HISTOGRAM_BINS = 256
#: a variance part is determinable when it exceeds zero by this many standard errors
DETERMINABLE_Z = 2.0


# --------------------------------------------------------------------------------------------
# the split of one average image
# --------------------------------------------------------------------------------------------
_DN2 = "DN\u00b2"


@dataclass(frozen=True)
class VarianceSplitSummary(Record):
    """A :class:`VarianceSplit` as ``calibration.json`` stores it
    (``emva1288.nonuniformity_split.dark`` and ``.bright``)."""

    #: rows and columns of the average image, and the frames L averaged in it
    M: int
    N: int
    L: int
    #: μ_y, the mean of the average image, DN
    mean: float
    #: s²_y = var(⟨y⟩) − σ²_y.stack/L (release 3.1 eq. 36) and its standard error, DN²
    s2: float
    s2_err: float
    #: s²_y.cav and s²_y.rav, the variances of the column and of the row averages, DN²
    s2_cav: float
    s2_rav: float
    #: the row, column and pixel parts s²_y.row, s²_y.col, s²_y.pixel (release 4.0) with their
    #: standard errors, DN²
    s2_row: float
    s2_row_err: float
    s2_col: float
    s2_col_err: float
    s2_pixel: float
    s2_pixel_err: float

    def rows(self) -> tuple[Row, ...]:
        """The image, its mean, the spatial variance and its three parts."""
        return (Row("average image", None, None, "",
                    "rows \u00d7 columns of the average image, and the frames averaged",
                    f"{self.M} \u00d7 {self.N}, L = {self.L}"),
                Row("mean, \u03bc_y", self.mean, None, "DN", "mean of the average image"),
                Row("spatial variance, s\u00b2_y", self.s2, self.s2_err, _DN2,
                    "spatial variance of the average image less its temporal noise"),
                Row("row part, s\u00b2_y.row", self.s2_row, self.s2_row_err, _DN2,
                    "variance of the pattern common to each row"),
                Row("column part, s\u00b2_y.col", self.s2_col, self.s2_col_err, _DN2,
                    "variance of the pattern common to each column"),
                Row("pixel part, s\u00b2_y.pixel", self.s2_pixel, self.s2_pixel_err, _DN2,
                    "variance of the pattern of single pixels"))


@dataclass(frozen=True)
class VarianceSplit:
    """The spatial variance of one average image and its row, column and pixel parts (DN²),
    each with its standard error (module docstring)."""

    M: int
    N: int
    L: int
    mean: float
    s2: float
    s2_err: float
    s2_cav: float
    s2_rav: float
    s2_row: float
    s2_row_err: float
    s2_col: float
    s2_col_err: float
    s2_pixel: float
    s2_pixel_err: float

    def part(self, name: str) -> tuple[float, float]:
        """(variance, its error) of ``name``: ``"row"``, ``"col"``, ``"pixel"`` or ``"total"``."""
        if name == "total":
            return self.s2, self.s2_err
        return getattr(self, f"s2_{name}"), getattr(self, f"s2_{name}_err")

    def summary(self) -> VarianceSplitSummary:
        """The record ``calibration.json`` stores."""
        return VarianceSplitSummary(**{f.name: json_safe(getattr(self, f.name))
                                       for f in fields(VarianceSplitSummary)})

    def to_dict(self) -> dict[str, Any]:
        return self.summary().to_dict()


def _combinations(M: int, N: int) -> dict[str, NDArray[np.float64]]:
    """The coefficients of s²_y, s²_cav, s²_rav and the parts on (SS_row, SS_col, SS_res) and on
    the constant σ²_n (the noise corrections), as rows [c_row, c_col, c_res, c_noise]."""
    MN = M * N
    # s²_y = (SS_row + SS_col + SS_res)/(MN − 1) − σ²_n ; s²_rav = SS_row/(MN) − σ²_n/N ;
    # s²_cav = SS_col/(MN) − σ²_n/M  (SS_row = N Σ_m (μ[m] − μ)², SS_col = M Σ_n (μ[n] − μ)²)
    s2 = np.array([1.0, 1.0, 1.0, 0.0]) / (MN - 1.0) - np.array([0.0, 0.0, 0.0, 1.0])
    rav = np.array([1.0 / MN, 0.0, 0.0, -1.0 / N])
    cav = np.array([0.0, 1.0 / MN, 0.0, -1.0 / M])
    d = MN - M - N
    col = ((MN - M) * cav - N * (s2 - rav)) / d
    row = ((MN - N) * rav - M * (s2 - cav)) / d
    pixel = MN * (s2 - cav - rav) / d
    return {"s2": s2, "cav": cav, "rav": rav, "row": row, "col": col, "pixel": pixel}


def variance_split(avg: NDArray, s2_stack: float, L: int) -> VarianceSplit:
    """The row, column and pixel parts of the spatial variance of the average image ``avg`` of
    ``L`` frames whose mean per-pixel temporal variance is ``s2_stack`` (module docstring;
    ``Results1288.s_2_y_row`` ... with ``Data1288._get_spatial_data``)."""
    a = np.asarray(avg, np.float64)
    if a.ndim != 2 or min(a.shape) < 2:
        raise ValueError(f"an average image of at least 2 × 2 pixels, got shape {a.shape}")
    M, N = a.shape
    mu = float(a.mean())
    row_means = a.mean(axis=1)                       # μ_y[m]
    col_means = a.mean(axis=0)                       # μ_y[n]
    ss_row = N * float(np.sum((row_means - mu) ** 2))
    ss_col = M * float(np.sum((col_means - mu) ** 2))
    ss_tot = float(np.sum((a - mu) ** 2))
    ss_res = max(ss_tot - ss_row - ss_col, 0.0)
    noise = float(s2_stack) / L                      # σ²_n
    c = _combinations(M, N)
    x = np.array([ss_row, ss_col, ss_res, noise])
    dof = np.array([M - 1.0, N - 1.0, (M - 1.0) * (N - 1.0)])
    ss = x[:3]
    var_ss = 4.0 * noise * np.maximum(ss - dof * noise, 0.0) + 2.0 * noise * noise * dof

    def value(name: str) -> tuple[float, float]:
        v = float(c[name] @ x)
        return v, math.sqrt(float(np.sum(c[name][:3] ** 2 * var_ss)))

    s2, s2_err = value("s2")
    row, row_err = value("row")
    col, col_err = value("col")
    pixel, pixel_err = value("pixel")
    return VarianceSplit(M=M, N=N, L=int(L), mean=mu, s2=s2, s2_err=s2_err,
                         s2_cav=value("cav")[0], s2_rav=value("rav")[0], s2_row=row,
                         s2_row_err=row_err, s2_col=col, s2_col_err=col_err, s2_pixel=pixel,
                         s2_pixel_err=pixel_err)


# --------------------------------------------------------------------------------------------
# DSNU and PRNU parts
# --------------------------------------------------------------------------------------------
_PART_WORDS = {"row": "row", "col": "column", "pixel": "pixel", "total": "total"}


#: the units of DSNU1288 and PRNU1288
_UNITS = {"DSNU1288": "e\u207b", "PRNU1288": "%"}


@dataclass(frozen=True)
class NonuniformitySplitSummary(Record):
    """A :class:`NonuniformitySplit` as ``calibration.json`` stores it
    (``emva1288.nonuniformity_split``)."""

    #: DSNU1288.row, .col, .pixel = s_y.part.dark / K with their standard errors, e⁻ (release
    #: 4.0); ``None`` where not determinable
    DSNU1288_row: float | None
    DSNU1288_row_err: float | None
    DSNU1288_col: float | None
    DSNU1288_col_err: float | None
    DSNU1288_pixel: float | None
    DSNU1288_pixel_err: float | None
    #: PRNU1288.row, .col, .pixel = 100 √(s²_y.part − s²_y.part.dark) / (μ_y − μ_y.dark) with
    #: their standard errors, %; ``None`` where not determinable
    PRNU1288_row: float | None
    PRNU1288_row_err: float | None
    PRNU1288_col: float | None
    PRNU1288_col_err: float | None
    PRNU1288_pixel: float | None
    PRNU1288_pixel_err: float | None
    #: the upper bound of each part not determinable, keyed like the figures (e⁻ or %)
    bounds: dict[str, float]
    #: the splits of the dark and of the bright average image
    dark: VarianceSplitSummary
    bright: VarianceSplitSummary
    #: why a part is not determinable
    notes: tuple[str, ...]

    def rows(self) -> tuple[Row, ...]:
        """The six parts (DSNU1288 and PRNU1288 by row, column and pixel) with the datasheet's
        labels (:data:`ccdcore.emva.sheet.DATASHEET`); a part not determinable gives its
        bound as text."""
        out = []
        for what, signal in (("DSNU1288", "dark signal"), ("PRNU1288", "photo response")):
            for part in PARTS:
                key = f"{what}_{part}"
                value, unit = getattr(self, key), _UNITS[what]
                bound = self.bounds.get(key)
                text = None if value is not None else (
                    "not determinable" if bound is None
                    else f"not determinable: below {bound:.3g} {unit}")
                where = ("of single pixels" if part == "pixel"
                         else f"common to each {_PART_WORDS[part]}")
                out.append(Row(f"{what[:4]}, {_PART_WORDS[part]} part, {what}.{part}", value,
                               getattr(self, f"{key}_err"), unit,
                               f"{signal} nonuniformity {where}", text))
        return tuple(out)


@dataclass(frozen=True)
class NonuniformitySplit:
    """DSNU1288 (e⁻) and PRNU1288 (%) as row, column and pixel parts (release 4.0) with their
    standard errors; ``None`` where a part is not determinable (its reason and bound in
    ``notes``; the bound in ``bounds``, keyed like the figures)."""

    dark: VarianceSplit
    bright: VarianceSplit
    DSNU1288_row: float | None
    DSNU1288_row_err: float | None
    DSNU1288_col: float | None
    DSNU1288_col_err: float | None
    DSNU1288_pixel: float | None
    DSNU1288_pixel_err: float | None
    PRNU1288_row: float | None
    PRNU1288_row_err: float | None
    PRNU1288_col: float | None
    PRNU1288_col_err: float | None
    PRNU1288_pixel: float | None
    PRNU1288_pixel_err: float | None
    bounds: tuple[tuple[str, float], ...]
    notes: tuple[str, ...]

    def figures(self) -> dict[str, float | None]:
        """The twelve figures under emva1288's names (``DSNU1288_row``, ``..._err``, ...)."""
        out: dict[str, float | None] = {}
        for what in ("DSNU1288", "PRNU1288"):
            for part in PARTS:
                key = f"{what}_{part}"
                out[key] = getattr(self, key)
                out[f"{key}_err"] = getattr(self, f"{key}_err")
        return out

    def summary(self) -> NonuniformitySplitSummary:
        """The record ``calibration.json`` stores (the bounds as an object keyed like the
        figures)."""
        return NonuniformitySplitSummary(
            **{k: json_safe(v) for k, v in self.figures().items()},
            bounds={k: json_safe(v) for k, v in self.bounds}, dark=self.dark.summary(),
            bright=self.bright.summary(), notes=tuple(self.notes))

    def to_dict(self) -> dict[str, Any]:
        return self.summary().to_dict()


def _dsnu_part(dark: VarianceSplit, part: str, K: float, K_err: float, notes: list[str],
               bounds: list[tuple[str, float]]) -> tuple[float | None, float | None]:
    v, e = dark.part(part)
    key = f"DSNU1288_{part}"
    if v > DETERMINABLE_Z * e and v > 0:
        value = math.sqrt(v) / K
        return value, value * math.hypot(e / (2.0 * v), K_err / K)
    bound = math.sqrt(max(v, 0.0) + DETERMINABLE_Z * e) / K
    bounds.append((key, bound))
    notes.append(f"{key} is not determinable: the {_PART_WORDS[part]} part of the dark spatial "
                 f"variance, {v:.3g} ± {e:.2g} DN², is not above zero by "
                 f"{DETERMINABLE_Z:g} standard errors (the temporal noise left in the average "
                 f"of {dark.L} dark frames hides it); it is below {bound:.3g} e-")
    return None, None


def _prnu_part(bright: VarianceSplit, dark: VarianceSplit, part: str, notes: list[str],
               bounds: list[tuple[str, float]]) -> tuple[float | None, float | None]:
    vb, eb = bright.part(part)
    vd, ed = dark.part(part)
    v, e = vb - vd, math.hypot(eb, ed)
    signal = bright.mean - dark.mean
    key = f"PRNU1288_{part}"
    if not signal > 0:
        notes.append(f"{key} is not determinable: the bright set's mean does not exceed the "
                     f"dark set's ({bright.mean:.4g} vs {dark.mean:.4g} DN)")
        return None, None
    if v > DETERMINABLE_Z * e and v > 0:
        value = 100.0 * math.sqrt(v) / signal
        return value, value * e / (2.0 * v)
    bound = 100.0 * math.sqrt(max(v, 0.0) + DETERMINABLE_Z * e) / signal
    bounds.append((key, bound))
    notes.append(f"{key} is not determinable: the {_PART_WORDS[part]} part of the bright "
                 f"spatial variance less the dark one, {v:.3g} ± {e:.2g} DN², is not above zero "
                 f"by {DETERMINABLE_Z:g} standard errors; it is below {bound:.3g} %")
    return None, None


def nonuniformity_split(bright: VarianceSplit, dark: VarianceSplit, K: float, K_err: float
                        ) -> NonuniformitySplit:
    """DSNU1288 and PRNU1288 as row, column and pixel parts (``Results1288.DSNU1288_row`` ...,
    ``PRNU1288_pixel``) from the splits of the bright and the dark average images and the
    system gain ``K`` (DN/e⁻) with its error."""
    notes: list[str] = []
    bounds: list[tuple[str, float]] = []
    vals: dict[str, Any] = {}
    for part in PARTS:
        v, e = _dsnu_part(dark, part, K, K_err, notes, bounds)
        vals[f"DSNU1288_{part}"], vals[f"DSNU1288_{part}_err"] = v, e
    for part in PARTS:
        v, e = _prnu_part(bright, dark, part, notes, bounds)
        vals[f"PRNU1288_{part}"], vals[f"PRNU1288_{part}_err"] = v, e
    return NonuniformitySplit(dark=dark, bright=bright, bounds=tuple(bounds),
                              notes=tuple(notes), **vals)


# --------------------------------------------------------------------------------------------
# spectrograms, histograms, profiles (sec. 8)
# --------------------------------------------------------------------------------------------
def spectrogram(image: NDArray, vertical: bool = False
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The spectrogram of sec. 8.2 (``routines.FFT1288``): the power spectrum of every line of
    the image less its mean, |FFT|² / (line length), averaged over the lines, and its square root
    (in the image's units: white noise of variance σ² lies at σ at every frequency); with
    ``vertical`` along the columns. Returns the frequencies (cycles per pixel, 0 … 0.5: numpy's
    ``rfftfreq``; the package's ``GetFrecs`` spaces them k/(2(n/2 + 1)), short of the true
    frequency by 1/(n/2 + 1): 0.4 % at 480 pixels) and the amplitudes."""
    a = np.asarray(image, np.float64)
    if vertical:
        a = a.T
    n = a.shape[1]
    f = np.fft.rfft(a - a.mean(), axis=1)
    power = (f.real ** 2 + f.imag ** 2).mean(axis=0) / n
    return np.fft.rfftfreq(n), np.sqrt(power)


def high_pass(image: NDArray, size: int = HIGH_PASS_SIZE) -> NDArray[np.float64]:
    """The image less its ``size`` × ``size`` box mean (sec. 8.3; ``routines.high_pass_filter``
    without its integer scaling), the valid part only (``size // 2`` pixels cut at each edge)."""
    a = np.asarray(image, np.float64)
    h = size // 2
    out = a - uniform_filter(a, size=size, mode="nearest")
    return out[h:a.shape[0] - h, h:a.shape[1] - h] if h else out


def _bins(lo: float, hi: float, bins: int) -> NDArray[np.float64]:
    if not hi > lo:
        hi = lo + 1.0
    return np.linspace(lo, hi, bins + 1)


def _quantised_bins(lo: float, hi: float, bins: int, quantum: float) -> NDArray[np.float64]:
    """At most ``bins`` + 1 bins whose width is a whole number of ``quantum`` steps, edges
    half a step off the grid of values ``lo + k·quantum``: every bin holds as many steps."""
    steps = max(int(round((hi - lo) / quantum)), 0) + 1
    width = quantum * max(1, math.ceil(steps / bins))
    n = max(1, math.ceil(steps * quantum / width))
    return lo - 0.5 * quantum + width * np.arange(n + 1)


def defect_histogram(values: NDArray, bins: int = HISTOGRAM_BINS,
                     quantum: float | None = None) -> dict[str, NDArray]:
    """The logarithmic histogram of sec. 8.3 (``routines.Histogram1288``): ``bins`` equal bins
    from the smallest to the largest value (lower edges ``x``, pixel counts ``count``) and the
    normal distribution of the same mean and standard deviation (``model``, counts per bin).

    ``quantum``: the step of quantised values (an average of L integer frames takes values
    1/L DN apart): the bins are then whole numbers of steps, as the package's integer bins are
    (equal bins narrower than a step leave most of them empty and the rest too full)."""
    v = np.asarray(values, np.float64).ravel()
    if quantum is not None and quantum > 0:
        edges = _quantised_bins(float(v.min()), float(v.max()), bins, float(quantum))
    else:
        edges = _bins(float(v.min()), float(v.max()), bins)
    count, _ = np.histogram(v, edges)
    mu, sd = float(v.mean()), float(v.std())
    width = edges[1] - edges[0]
    centre = 0.5 * (edges[:-1] + edges[1:])
    model = (v.size * width / (math.sqrt(2.0 * math.pi) * sd)
             * np.exp(-0.5 * ((centre - mu) / sd) ** 2)) if sd > 0 else np.zeros(centre.size)
    return {"x": edges[:-1], "count": count.astype(np.int64), "model": model}


def accumulated_histogram(values: NDArray, bins: int = HISTOGRAM_BINS) -> dict[str, NDArray]:
    """The accumulated logarithmic histogram of sec. 8.3: for each deviation x from the mean
    (``bins`` equal steps up to the largest), the percentage of pixels deviating by x or more
    (``percent``; 100 % at x = 0)."""
    v = np.abs(np.asarray(values, np.float64).ravel() - float(np.mean(values)))
    edges = _bins(0.0, float(v.max()), bins)
    count, _ = np.histogram(v, edges)
    above = np.cumsum(count[::-1])[::-1]
    return {"x": edges[:-1], "percent": 100.0 * above / max(v.size, 1)}


def _blocks(x: NDArray, points: int, how: str) -> NDArray[np.float64]:
    n = x.size
    if n <= points:
        return x.astype(np.float64)
    edges = np.linspace(0, n, points + 1).astype(np.int64)
    red = {"mean": np.add.reduceat, "min": np.minimum.reduceat, "max": np.maximum.reduceat}[how]
    out = red(x.astype(np.float64), edges[:-1])
    if how == "mean":
        out = out / np.diff(edges)
    return out


def profiles(image: NDArray, vertical: bool = False, points: int = 1024
             ) -> dict[str, NDArray]:
    """The horizontal (or ``vertical``) profiles of sec. 8.4 (``plotting.ProfileBase``): for
    each column (row) the mean, the minimum and the maximum over the rows (columns), and the
    middle line; reduced to at most ``points`` blocks of neighbouring columns (the mean of the
    means, the smallest minimum, the largest maximum, the middle line's mean) with ``index`` the
    first column of each block."""
    a = np.asarray(image, np.float64)
    if vertical:
        a = a.T
    n = a.shape[1]
    index = _blocks(np.arange(n, dtype=np.float64), points, "min")
    return {"index": index, "mean": _blocks(a.mean(axis=0), points, "mean"),
            "min": _blocks(a.min(axis=0), points, "min"),
            "max": _blocks(a.max(axis=0), points, "max"),
            "mid": _blocks(a[a.shape[0] // 2], points, "mean")}


#: a plotted curve: its values in order, ``None`` where not finite
_Curve = tuple[float | None, ...]


@dataclass(frozen=True)
class SpectrogramSummary(Record):
    """One spectrogram (sec. 8.2): frequency ``f`` (cycles per pixel) and ``amplitude`` (DN for
    DSNU, % of the mean signal for PRNU)."""

    f: _Curve
    amplitude: _Curve


@dataclass(frozen=True)
class SpectrogramsSummary(Record):
    """The four spectrograms of sec. 8.2: of the dark image (DSNU) and of the signal image
    (PRNU), along the rows (horizontal) and along the columns (vertical)."""

    DSNU_horizontal: SpectrogramSummary
    PRNU_horizontal: SpectrogramSummary
    DSNU_vertical: SpectrogramSummary
    PRNU_vertical: SpectrogramSummary


@dataclass(frozen=True)
class SpatialLevelsSummary(Record):
    """The levels drawn on the spectrograms."""

    #: DSNU1288 in DN (DSNU1288 · K) and PRNU1288 in %; ``None`` when not determined
    DSNU1288_DN: float | None
    PRNU1288: float | None
    #: σ_y.stack.dark, the temporal noise of one dark frame, and σ_y.stack.dark/√L, the
    #: white-noise floor of the average of the L dark frames, DN
    sigma_y_stack_dark: float
    sigma_y_stack_dark_avg: float
    #: σ_y.stack and σ_y.stack/√L of the bright set, % of the mean signal (``None`` without a
    #: signal)
    sigma_y_stack_percent: float | None
    sigma_y_stack_avg_percent: float | None


@dataclass(frozen=True)
class HistogramSummary(Record):
    """One logarithmic histogram of sec. 8.3: the bins' lower edges ``x``, the pixel
    ``count`` of each and the normal distribution of the same mean and deviation (``model``,
    counts per bin)."""

    x: _Curve
    count: tuple[int, ...]
    model: _Curve


@dataclass(frozen=True)
class HistogramsSummary(Record):
    """The histograms of sec. 8.3: DSNU in e⁻ from the mean dark level, PRNU in % of the mean
    signal of the high-pass filtered signal image."""

    DSNU: HistogramSummary
    PRNU: HistogramSummary


@dataclass(frozen=True)
class AccumulatedHistogramSummary(Record):
    """One accumulated histogram of sec. 8.3: the percentage of pixels (``percent``) deviating
    from the mean by ``x`` or more."""

    x: _Curve
    percent: _Curve


@dataclass(frozen=True)
class AccumulatedSummary(Record):
    """The accumulated histograms of sec. 8.3, of the same values as the histograms."""

    DSNU: AccumulatedHistogramSummary
    PRNU: AccumulatedHistogramSummary


@dataclass(frozen=True)
class ProfileSummary(Record):
    """One profile of sec. 8.4: the first column (row) ``index`` of each block and the mean,
    minimum, maximum and middle line across the other axis, DN."""

    index: _Curve
    mean: _Curve
    min: _Curve
    max: _Curve
    mid: _Curve


@dataclass(frozen=True)
class ProfilesSummary(Record):
    """The profiles of sec. 8.4 of the signal image (bright less dark) and of the dark image,
    across the columns (horizontal) and across the rows (vertical)."""

    bright_horizontal: ProfileSummary
    bright_vertical: ProfileSummary
    dark_horizontal: ProfileSummary
    dark_vertical: ProfileSummary


@dataclass(frozen=True)
class SpatialPlotsSummary(Record):
    """A :class:`SpatialPlots` as ``calibration.json`` stores it (``emva1288.spatial_plots``)."""

    spectrograms: SpectrogramsSummary
    levels: SpatialLevelsSummary
    histograms: HistogramsSummary
    accumulated: AccumulatedSummary
    profiles: ProfilesSummary

    def rows(self) -> tuple[Row, ...]:
        """The levels drawn on the spectrograms (sec. 8.2)."""
        lv = self.levels
        return (Row("DSNU1288 in DN", lv.DSNU1288_DN, None, "DN",
                    "dark signal nonuniformity in digital numbers"),
                Row("PRNU1288", lv.PRNU1288, None, "%",
                    "photo response nonuniformity, % of the mean signal"),
                Row("\u03c3_y.stack.dark", lv.sigma_y_stack_dark, None, "DN",
                    "temporal noise of one dark frame"),
                Row("\u03c3_y.stack.dark/\u221aL", lv.sigma_y_stack_dark_avg, None, "DN",
                    "white-noise floor of the average of the dark frames"),
                Row("\u03c3_y.stack", lv.sigma_y_stack_percent, None, "%",
                    "temporal noise of one bright frame, % of the mean signal"),
                Row("\u03c3_y.stack/\u221aL", lv.sigma_y_stack_avg_percent, None, "%",
                    "white-noise floor of the average of the bright frames"))


def _curve(values: Any) -> tuple[Any, ...]:
    """A plotted array as plain numbers, NaN and infinities as ``None``."""
    return tuple(json_safe(np.asarray(values).tolist()))


_R = TypeVar("_R", bound=Record)


def _record(cls: type[_R], values: Mapping[str, Any], convert: Callable[[Any], Any]) -> _R:
    """The record ``cls`` of the entries of ``values`` named like its fields, each converted."""
    return cls(**{f.name: convert(values[f.name]) for f in fields(cls)})   # type: ignore


@dataclass(frozen=True)
class SpatialPlots:
    """Every array of the spatial section's plots (sec. 8) of one camera.

    ``spectrograms``: ``{"DSNU_horizontal", "DSNU_vertical", "PRNU_horizontal",
    "PRNU_vertical"}`` each ``{"f", "amplitude"}`` (DSNU in DN, PRNU in % of the mean signal),
    with the levels drawn on them in ``levels``; ``histograms``: ``{"DSNU", "PRNU"}`` (DSNU in
    e⁻ from the mean dark level, PRNU in % of the mean signal, of the high-pass filtered image)
    and ``accumulated``: the same accumulated; ``profiles``: ``{"bright_horizontal",
    "bright_vertical", "dark_horizontal", "dark_vertical"}`` in DN (the bright image less the
    dark one)."""

    spectrograms: dict[str, dict[str, NDArray]]
    levels: dict[str, float]
    histograms: dict[str, dict[str, NDArray]]
    accumulated: dict[str, dict[str, NDArray]]
    profiles: dict[str, dict[str, NDArray]]

    def summary(self) -> SpatialPlotsSummary:
        """The record ``calibration.json`` stores: every array as a tuple of plain numbers."""
        def group(cls: type[_R], curves: type[Record], values: Mapping[str, Any]) -> _R:
            return _record(cls, values, lambda v: _record(curves, v, _curve))

        return SpatialPlotsSummary(
            spectrograms=group(SpectrogramsSummary, SpectrogramSummary, self.spectrograms),
            levels=_record(SpatialLevelsSummary, self.levels, json_safe),
            histograms=group(HistogramsSummary, HistogramSummary, self.histograms),
            accumulated=group(AccumulatedSummary, AccumulatedHistogramSummary, self.accumulated),
            profiles=group(ProfilesSummary, ProfileSummary, self.profiles))

    def to_dict(self) -> dict[str, Any]:
        return self.summary().to_dict()


def spatial_plots(bright_avg: NDArray, dark_avg: NDArray, *, L: int, L_dark: int,
                  s2_stack: float, s2_stack_dark: float, K: float,
                  DSNU1288: float | None = None, PRNU1288: float | None = None
                  ) -> SpatialPlots:
    """The arrays of every plot of the spatial section from the average images of the bright
    and the dark spatial sets (DN), their frame counts and mean temporal variances, and K
    (DN/e⁻).

    Departures from the package (each a defect there): the PRNU image is the bright average
    less the dark average, each over its own frame count (the package divides both sums by the
    bright L); the PRNU spectrogram is √(power) / mean · 100 (%), where the package plots
    √(power / mean), which has no unit; the DSNU spectrogram divides by the dark set's frame
    count, not the bright one's. The levels drawn are the release 3.1 totals (DSNU1288 in DN,
    PRNU1288 in %), the temporal noise of one frame σ_y.stack (the package's line) and what
    is left of it in the average image, σ_y.stack/√L: the white-noise floor of the
    spectrogram."""
    b = np.asarray(bright_avg, np.float64)
    d = np.asarray(dark_avg, np.float64)
    signal_img = b - d
    signal = float(signal_img.mean())
    scale = 100.0 / signal if signal > 0 else float("nan")
    spectra: dict[str, dict[str, NDArray]] = {}
    for vertical, name in ((False, "horizontal"), (True, "vertical")):
        f, amp = spectrogram(d, vertical)
        spectra[f"DSNU_{name}"] = {"f": f, "amplitude": amp}
        f, amp = spectrogram(signal_img, vertical)
        spectra[f"PRNU_{name}"] = {"f": f, "amplitude": amp * scale}
    levels = {"DSNU1288_DN": None if DSNU1288 is None else float(DSNU1288) * K,
              "PRNU1288": None if PRNU1288 is None else float(PRNU1288),
              "sigma_y_stack_dark": math.sqrt(max(s2_stack_dark, 0.0)),
              "sigma_y_stack_dark_avg": math.sqrt(max(s2_stack_dark, 0.0) / L_dark),
              "sigma_y_stack_percent": math.sqrt(max(s2_stack, 0.0)) * scale,
              "sigma_y_stack_avg_percent": math.sqrt(max(s2_stack, 0.0) / L) * scale}
    dsnu_e = (d - d.mean()) / K
    prnu_pc = high_pass(signal_img) * scale
    # the dark average of L_dark integer frames takes values 1/L_dark DN apart
    sums = d * L_dark
    quantum = 1.0 / (L_dark * K) if np.all(np.abs(sums - np.round(sums)) < 1e-6) else None
    hist = {"DSNU": defect_histogram(dsnu_e, quantum=quantum), "PRNU": defect_histogram(prnu_pc)}
    acc = {"DSNU": accumulated_histogram(dsnu_e), "PRNU": accumulated_histogram(prnu_pc)}
    prof = {"bright_horizontal": profiles(signal_img), "bright_vertical": profiles(signal_img,
                                                                                  True),
            "dark_horizontal": profiles(d), "dark_vertical": profiles(d, True)}
    return SpatialPlots(spectrograms=spectra, levels=levels, histograms=hist, accumulated=acc,
                        profiles=prof)
