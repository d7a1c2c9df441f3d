"""The results of the EMVA 1288 figures (:func:`ccdcore.datasheet.emva_figures`): the frozen
:class:`EmvaFigures` with its points, dark points and spatial sets, their JSON-safe ``to_dict()``
under the ``emva1288`` package's names, and the constants of the package's definitions.

Every name here is re-exported by :mod:`ccdcore.datasheet`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .common import json_safe
from .emva_dark import DarkCurrent
from .emva_spatial import NonuniformitySplit, SpatialPlots

__all__ = ["EmvaFigures", "EmvaPoint", "DarkPoint", "SpatialSet", "QUANTISATION_VARIANCE",
           "SIGMA2_Y_DARK_FLOOR", "SENSITIVITY_FRACTION", "LINEARITY_RANGE", "DISAGREEMENT_Z",
           "QUANTISATION_LIMIT_DN"]


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

    def to_dict(self) -> dict[str, Any]:
        return {k: json_safe(getattr(self, k)) for k in (
            "level", "exposure", "u_p", "u_y", "u_y_err", "u_y_dark", "s2_y", "s2_y_err",
            "s2_y_dark", "s2_y_dark_err", "n_pixels", "in_sensitivity_fit", "in_linearity_fit",
            "saturation")}


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

    def to_dict(self) -> dict[str, Any]:
        return {"exposure": json_safe(self.exposure), "u_y_dark": json_safe(self.u_y_dark),
                "u_y_dark_err": json_safe(self.u_y_dark_err),
                "s2_y_dark": json_safe(self.s2_y_dark),
                "s2_y_dark_err": json_safe(self.s2_y_dark_err), "relpaths": list(self.relpaths)}


@dataclass(frozen=True)
class SpatialSet:
    """The statistics of one spatial set of L frames at one point (sec. 8; ``Data1288``).

    ``u_y`` is the mean of the average image ⟨y⟩; ``s2_stack`` the mean over the pixels of the
    per-pixel temporal variance (σ²_y.stack, L − 1 in the denominator); ``s2_measured`` the spatial
    variance of ⟨y⟩ (N − 1 in the denominator); ``s2`` = s2_measured − s2_stack/L, the spatial
    variance with the temporal noise left in ⟨y⟩ removed, DN², with its standard error
    ``s2_err`` (see :func:`~ccdcore.datasheet.emva_figures`, Notes).
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

    def to_dict(self) -> dict[str, Any]:
        return {k: json_safe(getattr(self, k)) for k in (
            "level", "exposure", "L", "u_p", "u_y", "s2_stack", "s2_measured", "s2", "s2_err",
            "n_pixels")}


@dataclass(frozen=True)
class EmvaFigures:
    """The EMVA 1288 figures of one session (see :func:`~ccdcore.datasheet.emva_figures` for
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
    #: :func:`~ccdcore.datasheet.with_photon_transfer`)
    ptc_notes: tuple[str, ...] = ()

    # ---- curves for the report ----------------------------------------------------------
    def snr_curve(self) -> dict[str, list[float | None]]:
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
        out: dict[str, list[float | None]] = {
            "u_p": json_safe(u_p), "snr": json_safe(measured),
            "snr_model": json_safe(eta * u_p / np.sqrt(base))}
        if self.DSNU1288 is not None and self.PRNU1288 is not None \
                and math.isfinite(self.DSNU1288) and math.isfinite(self.PRNU1288):
            total = base + self.DSNU1288 ** 2 + (self.PRNU1288 / 100.0 * eta * u_p) ** 2
            out["snr_total"] = json_safe(eta * u_p / np.sqrt(total))
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe figures under the ``emva1288`` package's names (``K``, ``sigma_d``, ``QE``,
        ``u_e_sat``, ``u_p_sat``, ``u_p_min``, ``SNR_max``, ``DR``, ``DR_dB``, ``LE_min``,
        ``LE_max``, ``DSNU1288``, ``PRNU1288``, ``sigma_y_dark``, ...) with their ``*_err``, our
        ``sigma_d_ptc``, the ``snr_curve``, the ``points`` (for the PTC, SNR and linearity plots),
        the dark points, the spatial sets and the ``notes``."""
        names = ("K", "K_err", "R", "R_err", "QE", "QE_err", "sigma_y_dark", "sigma_y_dark_err",
                 "sigma_y_dark_measured", "u_y_dark", "u_y_dark_err", "sigma_d", "sigma_d_err",
                 "sigma_d_ptc", "sigma_d_ptc_err", "K_ptc", "K_ptc_err", "u_p_min",
                 "u_p_min_err", "u_p_sat", "u_p_sat_err", "u_e_sat", "u_e_sat_err", "SNR_max",
                 "SNR_max_err",
                 "DR", "DR_err", "DR_dB", "DR_dB_err", "LE_min", "LE_min_err", "LE_max",
                 "LE_max_err", "linearity_slope", "linearity_offset", "DSNU1288",
                 "DSNU1288_err", "PRNU1288", "PRNU1288_err", "index_u_ysat",
                 "index_sensitivity_max", "index_linearity_min", "index_linearity_max",
                 "sigma_d_consistent", "quantisation_limited")
        out: dict[str, Any] = {"standard": "EMVA 1288 release 3.1",
                               "definitions": "emva1288 1.0.2 (Results1288)"}
        out.update({k: json_safe(getattr(self, k)) for k in names})
        out["snr_curve"] = self.snr_curve()
        out["points"] = [p.to_dict() for p in self.points]
        out["dark_points"] = [d.to_dict() for d in self.dark_points]
        out["spatial"] = None if self.spatial is None else self.spatial.to_dict()
        out["spatial_dark"] = None if self.spatial_dark is None else self.spatial_dark.to_dict()
        out["notes"] = list(self.notes)
        out["source"] = self.source
        dc = self.dark_current
        out.update({k: json_safe(v) for k, v in (
            dc.figures() if dc is not None else dict.fromkeys(
                ("u_I_mean", "u_I_mean_err", "u_I_var", "u_I_var_err"))).items()})
        out["dark_current"] = None if dc is None else dc.to_dict()
        split = self.split
        out.update({k: json_safe(v) for k, v in (
            split.figures() if split is not None else dict.fromkeys(
                f"{w}_{p}{e}" for w in ("DSNU1288", "PRNU1288") for p in ("row", "col", "pixel")
                for e in ("", "_err"))).items()})
        out["nonuniformity_split"] = None if split is None else split.to_dict()
        out["spatial_plots"] = (None if self.spatial_plots is None
                                else self.spatial_plots.to_dict())
        return out
