"""The results of the EMVA 1288 figures (:func:`ccdcore.emva.datasheet.emva_figures`): the frozen
:class:`EmvaFigures` with its points, dark points and spatial sets, their JSON-safe ``to_dict()``
under the ``emva1288`` package's names, and the constants of the package's definitions; and
the typed records a calibration product stores for them (the ``emva1288`` key of
``calibration.json``), each made by the result's ``summary()``.

Public objects
--------------
EmvaFigures, EmvaPoint, DarkPoint, SpatialSet
    The results (re-exported by :mod:`ccdcore.emva.datasheet`, with the constants).
EmvaSummary, EmvaPointSummary, DarkPointSummary, SpatialSetSummary, SnrCurveSummary
    Their records (``EmvaFigures.summary()``, ``EmvaPoint.summary()``, ...); ``EmvaSummary``
    nests the records of :mod:`ccdcore.emva.dark` and :mod:`ccdcore.emva.spatial`, and its
    ``rows()`` are the headline figures of the datasheet's rows
    (:data:`HEADLINE` of :func:`datasheet_rows`).
SheetRow, DATASHEET, HEADLINE, datasheet_rows(e)
    The datasheet as rows (rendered by :mod:`ccdcore.emva.sheet`, which re-exports them).
QUANTISATION_VARIANCE, SIGMA2_Y_DARK_FLOOR, SENSITIVITY_FRACTION, LINEARITY_RANGE,
DISAGREEMENT_Z, QUANTISATION_LIMIT_DN
    The constants of the definitions.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from ..common import json_safe
from .dark import DarkCurrent, DarkCurrentSummary
from .spatial import (NonuniformitySplit, NonuniformitySplitSummary, SpatialPlots,
                           SpatialPlotsSummary)
from ..records import OMIT_NONE, Record, Row, positive_problems

__all__ = ["EmvaFigures", "EmvaPoint", "DarkPoint", "SpatialSet", "EmvaSummary", "SheetRow",
           "DATASHEET", "HEADLINE", "datasheet_rows",
           "EmvaPointSummary", "DarkPointSummary", "SpatialSetSummary", "SnrCurveSummary",
           "QUANTISATION_VARIANCE", "SIGMA2_Y_DARK_FLOOR", "SENSITIVITY_FRACTION",
           "LINEARITY_RANGE", "DISAGREEMENT_Z", "QUANTISATION_LIMIT_DN"]


#: σ²_q, the quantisation noise variance of a 1-DN step (sec. 2.2), DN²
QUANTISATION_VARIANCE = 1.0 / 12.0
#: the floor the package puts under σ²_y.dark: below it the quantisation noise dominates, DN²
SIGMA2_Y_DARK_FLOOR = 0.24
#: the sensitivity fits (R, K) use the points up to this fraction of the saturation signal
SENSITIVITY_FRACTION = 0.70
#: the linearity fit uses the points from 5 % to 95 % of the saturation signal (sec. 6.7)
LINEARITY_RANGE = (0.05, 0.95)
#: σ_d from the darks and from photon transfer disagree beyond this many combined standard errors
DISAGREEMENT_Z = 3.0
#: below this temporal dark noise (DN) the quantisation of the ADC dominates it
QUANTISATION_LIMIT_DN = 0.5


# --------------------------------------------------------------------------------------------
# records (what calibration.json stores)
# --------------------------------------------------------------------------------------------
#: the standard and the definitions the figures follow (the first two keys of the record)
STANDARD = "EMVA 1288 release 3.1"
DEFINITIONS = "emva1288 1.0.2 (Results1288)"

_DN2 = "DN\u00b2"

#: a plotted curve: its values in order, ``None`` where not finite
_Curve = tuple[float | None, ...]


def _curve(values: Any) -> tuple[Any, ...]:
    """An array as plain numbers, NaN and infinities as ``None``."""
    return tuple(json_safe(np.asarray(values).tolist()))


@dataclass(frozen=True)
class EmvaPointSummary(Record):
    """An :class:`EmvaPoint` as ``calibration.json`` stores it (``emva1288.points``)."""

    #: the ``ptc`` level and its exposure time, s (``None``: unknown)
    level: int
    exposure: float | None
    #: μ_p, mean photons per pixel
    u_p: float
    #: μ_y, the mean of both frames, and its standard error, DN
    u_y: float
    u_y_err: float
    #: μ_y.dark of the dark point at this exposure, DN
    u_y_dark: float
    #: σ²_y = var(y_A − y_B)/2 and its standard error, DN²
    s2_y: float
    s2_y_err: float
    #: σ²_y.dark of the dark point at this exposure and its standard error, DN²
    s2_y_dark: float
    s2_y_dark_err: float
    #: N, pixels per frame
    n_pixels: int
    #: the point is in the R and K fits, in the linearity fit, is the saturation point
    in_sensitivity_fit: bool
    in_linearity_fit: bool
    saturation: bool

    def rows(self) -> tuple[Row, ...]:
        """The point's photons, signal and variance with their dark values, and its fits."""
        fits = [w for w, inside in (("sensitivity fit", self.in_sensitivity_fit),
                                    ("linearity fit", self.in_linearity_fit),
                                    ("saturation point", self.saturation)) if inside]
        return (Row("ptc level", self.level, None, "", "the operating point of the session"),
                Row("exposure time", self.exposure, None, "s", "exposure time of the frames"),
                Row("photons, \u03bc_p", self.u_p, None, "p", "mean photons per pixel"),
                Row("mean signal, \u03bc_y", self.u_y, self.u_y_err, "DN",
                    "mean of the two bright frames"),
                Row("mean dark signal, \u03bc_y.dark", self.u_y_dark, None, "DN",
                    "mean of the two dark frames at this exposure"),
                Row("temporal variance, \u03c3\u00b2_y", self.s2_y, self.s2_y_err, _DN2,
                    "temporal noise of the bright frames, from their difference"),
                Row("temporal dark variance, \u03c3\u00b2_y.dark", self.s2_y_dark,
                    self.s2_y_dark_err, _DN2, "temporal noise of the dark frames"),
                Row("used in", None, None, "", "the fits this point is in",
                    ", ".join(fits) or "no fit"))


@dataclass(frozen=True)
class DarkPointSummary(Record):
    """A :class:`DarkPoint` as ``calibration.json`` stores it (``emva1288.dark_points``)."""

    #: the exposure time, s (``None``: unknown)
    exposure: float | None
    #: μ_y.dark and its standard error, DN
    u_y_dark: float
    u_y_dark_err: float
    #: σ²_y.dark and its standard error, DN²
    s2_y_dark: float
    s2_y_dark_err: float
    #: the two dark frames, relative to the session
    relpaths: tuple[str, str]

    def rows(self) -> tuple[Row, ...]:
        """The exposure, the dark mean and variance, the frames."""
        return (Row("exposure time", self.exposure, None, "s", "exposure time of the frames"),
                Row("mean dark signal, \u03bc_y.dark", self.u_y_dark, self.u_y_dark_err, "DN",
                    "mean of the two dark frames"),
                Row("temporal dark variance, \u03c3\u00b2_y.dark", self.s2_y_dark,
                    self.s2_y_dark_err, _DN2, "temporal noise, from the frames' difference"),
                Row("frames", None, None, "", "the two dark frames", " and ".join(self.relpaths)))


@dataclass(frozen=True)
class SpatialSetSummary(Record):
    """A :class:`SpatialSet` as ``calibration.json`` stores it (``emva1288.spatial`` and
    ``emva1288.spatial_dark``)."""

    #: the ``ptc`` level (``None`` for the dark set) and the exposure time, s
    level: int | None
    exposure: float | None
    #: L, frames in the set
    L: int
    #: μ_p, mean photons per pixel (0 for the dark set)
    u_p: float
    #: μ_y, the mean of the average image ⟨y⟩, DN
    u_y: float
    #: σ²_y.stack, the mean per-pixel temporal variance (L − 1 in the denominator), DN²
    s2_stack: float
    #: the spatial variance of ⟨y⟩ (N − 1 in the denominator), DN²
    s2_measured: float
    #: s² = s2_measured − s2_stack/L (release 3.1 eq. 36) and its standard error, DN²
    s2: float
    s2_err: float
    #: N, pixels per frame
    n_pixels: int

    def rows(self) -> tuple[Row, ...]:
        """The frames, photons, mean, temporal and spatial variances of the set."""
        return (Row("frames, L", self.L, None, "", "frames averaged in the set"),
                Row("photons, \u03bc_p", self.u_p, None, "p", "mean photons per pixel"),
                Row("mean signal, \u03bc_y", self.u_y, None, "DN", "mean of the average image"),
                Row("temporal variance, \u03c3\u00b2_y.stack", self.s2_stack, None, _DN2,
                    "mean per-pixel temporal variance of the frames"),
                Row("spatial variance, s\u00b2_y", self.s2, self.s2_err, _DN2,
                    "spatial variance of the average image less its temporal noise"))


@dataclass(frozen=True)
class SnrCurveSummary(Record):
    """The SNR curve of the report (``emva1288.snr_curve``; :meth:`EmvaFigures.snr_curve`)."""

    #: μ_p of every point, photons
    u_p: _Curve
    #: the measured SNR (μ_y − μ_y.dark)/σ_y (eq. 10; ``None`` where σ²_y = 0)
    snr: _Curve
    #: the model ημ_p/√(σ²_d + σ²_q/K² + ημ_p) (eq. 11)
    snr_model: _Curve
    #: the model with DSNU1288 and PRNU1288 added (absent without them)
    snr_total: _Curve | None = field(default=None, metadata=OMIT_NONE)

    def rows(self) -> tuple[Row, ...]:
        """The points and the largest measured SNR."""
        snr = [v for v in self.snr if v is not None]
        return (Row("points", len(self.u_p), None, "", "points of the SNR curve"),
                Row("largest measured SNR", max(snr) if snr else None, None, "",
                    "the best signal-to-noise ratio measured"))


#: what each figure of the datasheet says, in plain words (keys of ``DATASHEET``)
_MEANINGS = {
    "QE": "share of the photons that free an electron",
    "R": "digital numbers per photon",
    "K": "digital numbers per electron",
    "sigma_d": "read noise from the dark frames, in electrons",
    "sigma_y_dark": "temporal noise of a dark frame, in digital numbers",
    "sigma_d_ptc": "read noise from the intercept of the photon-transfer line",
    "u_p_min": "photons per pixel giving a signal-to-noise ratio of 1",
    "u_p_sat": "photons per pixel at saturation",
    "u_e_sat": "electrons per pixel at saturation",
    "SNR_max": "signal-to-noise ratio at saturation",
    "DR_dB": "saturation over the sensitivity threshold, in decibels",
    "DR": "saturation over the sensitivity threshold",
    "LE_min": "largest deviation below the linear fit (5 to 95 % of saturation)",
    "LE_max": "largest deviation above the linear fit (5 to 95 % of saturation)",
    "u_I_mean": "thermal electrons per second, from the growth of the mean dark signal with "
                "the exposure time",
    "u_I_var": "thermal electrons per second, from the growth of the dark variance with the "
               "exposure time",
    "DSNU1288": "spread of the dark signal from pixel to pixel, in electrons",
    "PRNU1288": "spread of the response from pixel to pixel, % of the signal",
}
_MEANINGS.update({f"{what}_{part}": f"spread of the {signal} {where}"
                  for what, signal in (("DSNU1288", "dark signal"), ("PRNU1288", "response"))
                  for part, where in (("row", "common to each row"),
                                      ("col", "common to each column"),
                                      ("pixel", "of single pixels"))})


@dataclass(frozen=True)
class EmvaSummary(Record):
    """An :class:`EmvaFigures` as ``calibration.json`` stores it (the key ``emva1288``): the
    figures under the ``emva1288`` package's names with their standard errors (``None`` where
    none can be derived), the points, the spatial sets, the dark current and the release 4.0
    split with the plots' arrays. Units: K in DN/e⁻, R in DN/p, QE in %, σ_y.dark and μ_y.dark
    in DN, σ_d in e⁻, μ_p in photons, μ_e in e⁻, DR as a ratio and in dB, LE in %, DSNU1288 in
    e⁻, PRNU1288 in %, μ_I in e⁻/s."""

    #: the standard and the definitions followed
    standard: str
    definitions: str
    #: K, the overall system gain (sec. 6.6), DN/e⁻
    K: float
    K_err: float | None
    #: R, the responsivity (sec. 2.1), DN/p
    R: float
    R_err: float | None
    #: η, the quantum efficiency R/K, %
    QE: float
    QE_err: float | None
    #: σ_y.dark (sec. 2.2; floored at σ²_y.dark = 0.24 DN², then without an error) and its
    #: value before the floor, DN
    sigma_y_dark: float
    sigma_y_dark_err: float | None
    sigma_y_dark_measured: float
    #: μ_y.dark, DN
    u_y_dark: float
    u_y_dark_err: float | None
    #: σ_d = √(σ²_y.dark − σ²_q)/K from the darks, e⁻ (``None`` below the quantisation noise)
    sigma_d: float | None
    sigma_d_err: float | None
    #: σ_d and K from our photon-transfer line (Healey & Kondepudy eq. 27), e⁻ and DN/e⁻
    sigma_d_ptc: float | None
    sigma_d_ptc_err: float | None
    K_ptc: float | None
    K_ptc_err: float | None
    #: μ_p.min, the absolute sensitivity threshold (sec. 2.4), photons
    u_p_min: float
    u_p_min_err: float | None
    #: μ_p.sat and μ_e.sat, the saturation capacity, photons and e⁻
    u_p_sat: float
    u_p_sat_err: float | None
    u_e_sat: float
    u_e_sat_err: float | None
    #: SNR_max = √μ_e.sat (eq. 33)
    SNR_max: float
    SNR_max_err: float | None
    #: DR = μ_p.sat/μ_p.min (eq. 18) and 20 log₁₀ DR, dB
    DR: float
    DR_err: float | None
    DR_dB: float
    DR_dB_err: float | None
    #: LE_min and LE_max, the linearity error (sec. 6.7), %
    LE_min: float
    LE_min_err: float | None
    LE_max: float
    LE_max_err: float | None
    #: the linearity fit a·μ_p + b: a in DN/p, b in DN
    linearity_slope: float
    linearity_offset: float
    #: DSNU1288 (e⁻) and PRNU1288 (%) from the spatial sets (sec. 8); ``None`` without them or
    #: where a variance is negative
    DSNU1288: float | None
    DSNU1288_err: float | None
    PRNU1288: float | None
    PRNU1288_err: float | None
    #: the indices of the points: saturation, last in the R and K fits, the linearity range
    index_u_ysat: int
    index_sensitivity_max: int
    index_linearity_min: int
    index_linearity_max: int
    #: σ_d from the darks and from photon transfer agree within 3 standard errors (``None``:
    #: not compared); σ_y.dark is below 0.5 DN, where quantisation dominates
    sigma_d_consistent: bool | None
    quantisation_limited: bool
    #: the SNR curve of the report
    snr_curve: SnrCurveSummary
    #: the temporal bright points and the dark points
    points: tuple[EmvaPointSummary, ...]
    dark_points: tuple[DarkPointSummary, ...]
    #: the bright and the dark spatial set (``None`` without)
    spatial: SpatialSetSummary | None
    spatial_dark: SpatialSetSummary | None
    #: what the figures' reader should know
    notes: tuple[str, ...]
    #: the session the figures were made from
    source: str | None
    #: μ_I from the mean and from the variance with their standard errors, e⁻/s (sec. 3.1;
    #: ``None`` where not resolved). This key and the ones below are absent from the products
    #: made before the dark current and the release 4.0 split: they read as ``None``
    u_I_mean: float | None = None
    u_I_mean_err: float | None = None
    u_I_var: float | None = None
    u_I_var_err: float | None = None
    #: the dark current with its bounds and lines (``None``: not computed)
    dark_current: DarkCurrentSummary | None = None
    #: DSNU1288 by row, column and pixel (e⁻) with their standard errors (release 4.0)
    DSNU1288_row: float | None = None
    DSNU1288_row_err: float | None = None
    DSNU1288_col: float | None = None
    DSNU1288_col_err: float | None = None
    DSNU1288_pixel: float | None = None
    DSNU1288_pixel_err: float | None = None
    #: PRNU1288 by row, column and pixel (%) with their standard errors (release 4.0)
    PRNU1288_row: float | None = None
    PRNU1288_row_err: float | None = None
    PRNU1288_col: float | None = None
    PRNU1288_col_err: float | None = None
    PRNU1288_pixel: float | None = None
    PRNU1288_pixel_err: float | None = None
    #: the release 4.0 split (``None`` without spatial sets)
    nonuniformity_split: NonuniformitySplitSummary | None = None
    #: the arrays of the spatial section's plots (``None`` without spatial sets)
    spatial_plots: SpatialPlotsSummary | None = None

    def value_problems(self) -> list[tuple[str, str]]:
        """The system gain K must be positive (sec. 6.6), its error not negative."""
        return positive_problems(self, ("K",), ("K_err",))

    def rows(self) -> tuple[Row, ...]:
        """The headline figures (:data:`HEADLINE`: K, η, σ_d, μ_e.sat, DR in
        dB, μ_I.mean, DSNU1288, PRNU1288) that are determined, in the datasheet's order: the
        rows of :func:`datasheet_rows`, each labelled with its symbol."""
        return tuple(Row(r.symbol, r.value, r.error, r.unit, _MEANINGS[r.key])
                     for r in datasheet_rows(self) if r.key in HEADLINE and r.value is not None)


# ---------------------------------------------------------------------------------------------
# the datasheet's rows
# ---------------------------------------------------------------------------------------------
#: (section, key under emva1288's names, the standard's name, symbol, unit), in order
DATASHEET: tuple[tuple[str, str, str, str, str], ...] = (
    ("Sensitivity", "QE", "Quantum efficiency", "η", "%"),
    ("Sensitivity", "R", "Responsivity", "R", "DN/p"),
    ("Sensitivity", "K", "Overall system gain", "K", "DN/e⁻"),
    ("Noise", "sigma_d", "Temporal dark noise", "σ_d", "e⁻"),
    ("Noise", "sigma_y_dark", "Temporal dark noise", "σ_y.dark", "DN"),
    ("Noise", "sigma_d_ptc", "Temporal dark noise from the photon-transfer intercept", "σ_d",
     "e⁻"),
    ("Saturation", "u_p_min", "Absolute sensitivity threshold", "μ_p.min", "p"),
    ("Saturation", "u_p_sat", "Saturation capacity", "μ_p.sat", "p"),
    ("Saturation", "u_e_sat", "Saturation capacity", "μ_e.sat", "e⁻"),
    ("Saturation", "SNR_max", "Maximum signal-to-noise ratio", "SNR_max", ""),
    ("Dynamic range", "DR_dB", "Dynamic range", "DR", "dB"),
    ("Dynamic range", "DR", "Dynamic range", "DR", ""),
    ("Linearity", "LE_min", "Linearity error, minimum", "LE_min", "%"),
    ("Linearity", "LE_max", "Linearity error, maximum", "LE_max", "%"),
    ("Dark current", "u_I_mean", "Dark current from the mean", "μ_I.mean", "e⁻/s"),
    ("Dark current", "u_I_var", "Dark current from the variance", "μ_I.var", "e⁻/s"),
    ("Spatial nonuniformity", "DSNU1288", "Dark signal nonuniformity", "DSNU1288", "e⁻"),
    ("Spatial nonuniformity", "DSNU1288_row", "DSNU, row part", "DSNU1288.row", "e⁻"),
    ("Spatial nonuniformity", "DSNU1288_col", "DSNU, column part", "DSNU1288.col", "e⁻"),
    ("Spatial nonuniformity", "DSNU1288_pixel", "DSNU, pixel part", "DSNU1288.pixel", "e⁻"),
    ("Spatial nonuniformity", "PRNU1288", "Photo response nonuniformity", "PRNU1288", "%"),
    ("Spatial nonuniformity", "PRNU1288_row", "PRNU, row part", "PRNU1288.row", "%"),
    ("Spatial nonuniformity", "PRNU1288_col", "PRNU, column part", "PRNU1288.col", "%"),
    ("Spatial nonuniformity", "PRNU1288_pixel", "PRNU, pixel part", "PRNU1288.pixel", "%"),
)

#: the figures of a product's headline (keys of :data:`DATASHEET`; shown in its order, each
#: under its symbol, only when determined)
HEADLINE = ("K", "QE", "sigma_d", "u_e_sat", "DR_dB", "u_I_mean", "DSNU1288", "PRNU1288")


@dataclass(frozen=True)
class SheetRow:
    """One figure: where it belongs, what the standard calls it, its value and standard error
    (``None`` when not determined) and, then, why (``note``: the reason, and a bound when the
    data give one)."""

    section: str
    key: str
    name: str
    symbol: str
    unit: str
    value: float | None
    error: float | None
    note: str | None

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def _number(v: float | None) -> float | None:
    return None if v is None else float(v)


def _why(emva: EmvaSummary, key: str) -> str:
    """The note that names ``key`` (the estimators write ``"<key> is not ..."``), with the bound
    when one was found; else a plain reason."""
    for note in emva.notes:
        if note.startswith(f"{key} "):
            return note
    if key.startswith("u_I_"):
        for note in emva.notes:
            if note.startswith("no dark current"):
                return note
    if key.startswith(("DSNU1288", "PRNU1288")) and emva.spatial is None:
        return "no spatial sets (L bright and L dark frames at one point, sec. 8) in the session"
    if key == "sigma_d_ptc":
        return "photon transfer was not run with the figures"
    return "not determined from this session (see the notes)"




def datasheet_rows(e: EmvaSummary) -> list[SheetRow]:
    """Every figure of :data:`DATASHEET` of the figures ``e``, in order (the datasheet, as
    :mod:`ccdcore.emva.sheet` renders it)."""
    rows = []
    for section, key, name, symbol, unit in DATASHEET:
        value = _number(getattr(e, key))
        error = _number(getattr(e, f"{key}_err")) if value is not None else None
        rows.append(SheetRow(section, key, name, symbol, unit, value, error,
                             None if value is not None else _why(e, key)))
    return rows


_SUMMARY_FIELDS = [f.name for f in fields(EmvaSummary)]
#: the figures :class:`EmvaSummary` takes from the :class:`EmvaFigures` attributes of the
#: same names (``K`` to ``quantisation_limited``)
_FIGURES = tuple(_SUMMARY_FIELDS[_SUMMARY_FIELDS.index("K"):
                                _SUMMARY_FIELDS.index("quantisation_limited") + 1])


# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class EmvaPoint:
    """One temporal bright operating point with its dark point (sec. 6.6; ``Data1288``).

    Attributes
    ----------
    level, exposure
        The ``ptc`` level of the session and its exposure time (s; ``None`` when unknown).
    u_p
        μ_p, mean photons per pixel (the record's ``photons``).
    u_y, u_y_err
        μ_y, the mean of both frames (DN), and its temporal standard error √(σ²_y/(2N)).
    s2_y, s2_y_err
        σ²_y = var(y_A − y_B)/2 over the N pixels (population variance of the difference image,
        as ``Data1288`` computes it from its pseudo-variance), DN², and its standard error
        √(2σ⁴_y/(N − 1)) (normal pixels).
    u_y_dark, s2_y_dark, s2_y_dark_err
        The same of the dark point at this exposure.
    n_pixels
        N, pixels per frame.
    in_sensitivity_fit, in_linearity_fit, saturation
        The point is in the R and K fits (up to 70 % of saturation), in the linearity fit (5–95 %),
        is the saturation point.
    """

    level: int
    exposure: float | None
    u_p: float
    u_y: float
    u_y_err: float
    s2_y: float
    s2_y_err: float
    u_y_dark: float
    s2_y_dark: float
    s2_y_dark_err: float
    n_pixels: int
    in_sensitivity_fit: bool = False
    in_linearity_fit: bool = False
    saturation: bool = False

    def summary(self) -> EmvaPointSummary:
        """The record ``calibration.json`` stores."""
        return EmvaPointSummary(**{f.name: json_safe(getattr(self, f.name))
                                   for f in fields(EmvaPointSummary)})

    def to_dict(self) -> dict[str, Any]:
        return self.summary().to_dict()


@dataclass(frozen=True)
class DarkPoint:
    """The temporal dark point of one exposure time: μ_y.dark, σ²_y.dark (DN, DN²) with their
    standard errors, from two dark frames (``relpaths``)."""

    exposure: float | None
    u_y_dark: float
    u_y_dark_err: float
    s2_y_dark: float
    s2_y_dark_err: float
    relpaths: tuple[str, str]

    def summary(self) -> DarkPointSummary:
        """The record ``calibration.json`` stores."""
        return DarkPointSummary(
            exposure=json_safe(self.exposure), u_y_dark=json_safe(self.u_y_dark),
            u_y_dark_err=json_safe(self.u_y_dark_err), s2_y_dark=json_safe(self.s2_y_dark),
            s2_y_dark_err=json_safe(self.s2_y_dark_err),
            relpaths=(str(self.relpaths[0]), str(self.relpaths[1])))

    def to_dict(self) -> dict[str, Any]:
        return self.summary().to_dict()


@dataclass(frozen=True)
class SpatialSet:
    """The statistics of one spatial set of L frames at one point (sec. 8; ``Data1288``).

    ``u_y`` is the mean of the average image ⟨y⟩; ``s2_stack`` the mean over the pixels of the
    per-pixel temporal variance (σ²_y.stack, L − 1 in the denominator); ``s2_measured`` the spatial
    variance of ⟨y⟩ (N − 1 in the denominator); ``s2`` = s2_measured − s2_stack/L, the spatial
    variance with the temporal noise left in ⟨y⟩ removed, DN², with its standard error
    ``s2_err`` (see :func:`~ccdcore.emva.datasheet.emva_figures`, Notes).
    """

    level: int | None
    exposure: float | None
    L: int
    u_p: float
    u_y: float
    s2_stack: float
    s2_measured: float
    s2: float
    s2_err: float
    n_pixels: int
    #: the average image ⟨y⟩ (DN; not written by ``to_dict``): the release 4.0 split and the
    #: plots of sec. 8 are made from it
    image: np.ndarray | None = field(default=None, repr=False, compare=False)

    def summary(self) -> SpatialSetSummary:
        """The record ``calibration.json`` stores (without the average image)."""
        return SpatialSetSummary(**{f.name: json_safe(getattr(self, f.name))
                                    for f in fields(SpatialSetSummary)})

    def to_dict(self) -> dict[str, Any]:
        return self.summary().to_dict()


@dataclass(frozen=True)
class EmvaFigures:
    """The EMVA 1288 figures of one session (see :func:`~ccdcore.emva.datasheet.emva_figures` for
    every definition).

    Every ``*_err`` is a standard error (NaN when none can be derived, e.g. for a clamped
    σ_y.dark); ``to_dict()`` writes NaN as ``None``.  Units: K in DN/e⁻, R in DN/p, QE in %,
    σ_y.dark and μ_y.dark in DN, σ_d in e⁻, μ_p in photons, μ_e in e⁻, DR as a ratio and in dB,
    LE in %, DSNU1288 in e⁻, PRNU1288 in %.
    """

    K: float
    K_err: float
    R: float
    R_err: float
    QE: float
    QE_err: float
    sigma_y_dark: float
    sigma_y_dark_err: float
    sigma_y_dark_measured: float
    u_y_dark: float
    u_y_dark_err: float
    sigma_d: float
    sigma_d_err: float
    sigma_d_ptc: float | None
    sigma_d_ptc_err: float | None
    K_ptc: float | None
    K_ptc_err: float | None
    u_p_min: float
    u_p_min_err: float
    u_p_sat: float
    u_p_sat_err: float
    u_e_sat: float
    u_e_sat_err: float
    SNR_max: float
    SNR_max_err: float
    DR: float
    DR_err: float
    DR_dB: float
    DR_dB_err: float
    LE_min: float
    LE_min_err: float
    LE_max: float
    LE_max_err: float
    linearity_slope: float
    linearity_offset: float
    DSNU1288: float | None
    DSNU1288_err: float | None
    PRNU1288: float | None
    PRNU1288_err: float | None
    index_u_ysat: int
    index_sensitivity_max: int
    index_linearity_min: int
    index_linearity_max: int
    points: tuple[EmvaPoint, ...]
    dark_points: tuple[DarkPoint, ...]
    spatial: SpatialSet | None
    spatial_dark: SpatialSet | None
    sigma_d_consistent: bool | None
    quantisation_limited: bool
    notes: tuple[str, ...]
    source: str | None = None
    dark_current: DarkCurrent | None = None
    split: NonuniformitySplit | None = None
    spatial_plots: SpatialPlots | None = None
    #: the notes of ``notes`` that come from the photon transfer (replaced by
    #: :func:`~ccdcore.emva.datasheet.with_photon_transfer`)
    ptc_notes: tuple[str, ...] = ()

    # ---- curves for the report ----------------------------------------------------------
    def snr_summary(self) -> SnrCurveSummary:
        """μ_p of every point with the measured SNR (μ_y − μ_y.dark)/σ_y (eq. 10; ``None`` where
        σ²_y = 0, at saturation) and the model SNR ημ_p/√(σ²_d + σ²_q/K² + ημ_p) (eq. 11), as
        the package plots them; with the spatial sets also the model with DSNU1288 and PRNU1288
        added (``snr_total``)."""
        u_p = np.array([p.u_p for p in self.points])
        y = np.array([p.u_y - p.u_y_dark for p in self.points])
        s2 = np.array([p.s2_y for p in self.points])
        with np.errstate(divide="ignore", invalid="ignore"):
            measured = np.where(s2 > 0, y / np.sqrt(np.where(s2 > 0, s2, 1.0)), np.nan)
        eta = self.QE / 100.0
        base = self.sigma_d ** 2 + QUANTISATION_VARIANCE / self.K ** 2 + eta * u_p
        total = None
        if self.DSNU1288 is not None and self.PRNU1288 is not None \
                and math.isfinite(self.DSNU1288) and math.isfinite(self.PRNU1288):
            var = base + self.DSNU1288 ** 2 + (self.PRNU1288 / 100.0 * eta * u_p) ** 2
            total = _curve(eta * u_p / np.sqrt(var))
        return SnrCurveSummary(u_p=_curve(u_p), snr=_curve(measured),
                               snr_model=_curve(eta * u_p / np.sqrt(base)), snr_total=total)

    def snr_curve(self) -> dict[str, list[float | None]]:
        """The SNR curve (:meth:`snr_summary`) as JSON: ``u_p``, ``snr``, ``snr_model`` and,
        with the spatial sets, ``snr_total``."""
        return self.snr_summary().to_dict()

    # ---- the record ---------------------------------------------------------------------
    def summary(self) -> EmvaSummary:
        """The record ``calibration.json`` stores under ``emva1288``: the figures (NaN as
        ``None``), the SNR curve, the points, dark points and spatial sets, the notes, the
        dark current (its figures also at the top level, ``None`` without it), the release 4.0
        split (likewise) and the plots' arrays."""
        dc, split = self.dark_current, self.split
        current = dc.figures() if dc is not None else dict.fromkeys(
            ("u_I_mean", "u_I_mean_err", "u_I_var", "u_I_var_err"))
        parts = split.figures() if split is not None else dict.fromkeys(
            f"{w}_{p}{e}" for w in ("DSNU1288", "PRNU1288") for p in ("row", "col", "pixel")
            for e in ("", "_err"))
        return EmvaSummary(
            standard=STANDARD, definitions=DEFINITIONS,
            **{k: json_safe(getattr(self, k)) for k in _FIGURES},
            snr_curve=self.snr_summary(), points=tuple(p.summary() for p in self.points),
            dark_points=tuple(d.summary() for d in self.dark_points),
            spatial=None if self.spatial is None else self.spatial.summary(),
            spatial_dark=None if self.spatial_dark is None else self.spatial_dark.summary(),
            notes=tuple(self.notes), source=self.source,
            **{k: json_safe(v) for k, v in current.items()},
            dark_current=None if dc is None else dc.summary(),
            **{k: json_safe(v) for k, v in parts.items()},
            nonuniformity_split=None if split is None else split.summary(),
            spatial_plots=None if self.spatial_plots is None else self.spatial_plots.summary())

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe figures under the ``emva1288`` package's names (``K``, ``sigma_d``, ``QE``,
        ``u_e_sat``, ``u_p_sat``, ``u_p_min``, ``SNR_max``, ``DR``, ``DR_dB``, ``LE_min``,
        ``LE_max``, ``DSNU1288``, ``PRNU1288``, ``sigma_y_dark``, ...) with their ``*_err``, our
        ``sigma_d_ptc``, the ``snr_curve``, the ``points`` (for the PTC, SNR and linearity plots),
        the dark points, the spatial sets and the ``notes``: ``summary().to_dict()``."""
        return self.summary().to_dict()
