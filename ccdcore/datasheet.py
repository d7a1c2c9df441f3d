"""The EMVA 1288 figures of a camera: the data-sheet numbers of EMVA Standard 1288, release 3.1.

The definitions are those of EMVA Standard 1288 "Standard for Characterization of Image Sensors
and Cameras", release 3.1 (30 December 2016), *as the reference implementation computes them*:
the ``emva1288`` package 1.0.2 (``emva1288.process.data.Data1288`` and
``emva1288.process.results.Results1288``).  Where the package and the text of the standard differ,
we follow the package, so that our figures and its figures agree to rounding on the same files
(``docs/emva.md`` lists the choices and what differs: the errors, the notes, a few checks).
Sections cited are those of release 3.1: sec. 2 "Sensitivity, Linearity, and Noise" (2.1 Linear
Signal Model, 2.2 Noise Model, 2.3 Signal-to-Noise Ratio, 2.4 Signal Saturation and Absolute
Sensitivity Threshold), sec. 3 "Dark Current", sec. 4.1 "Spatial Variances, DSNU, and PRNU",
sec. 6 "Methods for Sensitivity, Linearity, and Noise" (6.6 evaluation according to the photon
transfer method, 6.7 evaluation of the linearity) and sec. 8 "Methods for Spatial
Nonuniformity"; equation numbers (10), (11), (18), (33) are those of release 3.1.

Frames (what a session must hold)
---------------------------------
* *temporal bright points*: ``ptc`` levels of exactly two frames whose records carry
  :attr:`~ccdcore.session.FrameRecord.photons` (the mean number of photons per pixel μ_p; an
  EMVA1288 descriptor's ``b`` lines give it);
* *temporal dark points*: two dark frames at the exposure time of each bright point (a run of two
  consecutive ``dark`` frames of that exposure, in session order, as a descriptor's ``d`` line
  lists them);
* optionally the *spatial sets* of sec. 8: one ``ptc`` level of more than two frames (L frames at
  one point, about 50 % of saturation) and a run of more than two dark frames at its exposure.
  The reference parser sorts points in the same way (two images: temporal; more: spatial).

Public objects
--------------
emva_figures(session, noise=None, progress=None)
    Every figure below, from one streamed pass over the frames.
with_photon_transfer(figures, noise)
    The same figures with σ_d from another photon transfer (no frame read).
EmvaFigures, EmvaPoint, DarkPoint, SpatialSet
    Frozen results (``to_dict()`` gives the JSON-safe dict under emva1288's names).
EMVA_STEPS
    The steps :func:`emva_figures` reports to its ``progress`` (a
    :class:`ccdcore.progress.Progress`).
QUANTISATION_VARIANCE, SIGMA2_Y_DARK_FLOOR, SENSITIVITY_FRACTION, LINEARITY_RANGE
    The constants of the package's definitions (1/12 DN², 0.24 DN², 70 %, 5–95 %).

References
----------
1. EMVA Standard 1288, release 3.1, European Machine Vision Association, 2016.
2. The ``emva1288`` package 1.0.2 (PyPI), the reference implementation.
3. G. E. Healey and R. Kondepudy, "Radiometric CCD Camera Calibration and Noise Estimation",
   IEEE TPAMI 16(3), 1994 (eq. 27: the read noise from the photon-transfer intercept).
"""
from __future__ import annotations

import math
from contextlib import closing
from dataclasses import dataclass, field, replace
from os import PathLike
from typing import Any, Sequence

import numpy as np

from .common import json_safe
from .emva_dark import DarkCurrent, dark_current
from .emva_spatial import (NonuniformitySplit, SpatialPlots, nonuniformity_split, spatial_plots,
                           variance_split)
from .errors import CcdError
from .noise import READ_AHEAD, PhotonTransfer
from .progress import Progress, Steps
from .session import FrameRecord, Session, open_session

__all__ = ["EmvaFigures", "EmvaPoint", "DarkPoint", "SpatialSet", "emva_figures",
           "with_photon_transfer", "EMVA_STEPS",
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
#: the steps :func:`emva_figures` reports (name, overall fraction at which it starts)
EMVA_STEPS: tuple[tuple[str, float], ...] = (
    ("EMVA 1288 points", 0.0), ("photon transfer", 0.8), ("done", 1.0))

_MISSING_PHOTONS = ("no photon counts: the EMVA 1288 figures need the photons per pixel of each "
                    "bright frame (EMVA1288 descriptors carry them)")


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
    ``s2_err`` (see :func:`emva_figures`, Notes).
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
    """The EMVA 1288 figures of one session (see :func:`emva_figures` for every definition).

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
    #: :func:`with_photon_transfer`)
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


# --------------------------------------------------------------------------------------------
# fits (closed forms of the package's least-squares fits)
# --------------------------------------------------------------------------------------------
def _birge(chi2: float, dof: int) -> float:
    """√(χ²/ν) when above 1 (the scatter exceeds the stated errors: the model misfits), else 1."""
    return math.sqrt(chi2 / dof) if dof > 0 and chi2 > dof else 1.0


def _line_b0(x: np.ndarray, y: np.ndarray, var_y: np.ndarray) -> tuple[float, float]:
    """The line y = m·x through the origin by unweighted least squares (``routines.LinearB0``):
    m = Σxy/Σx², with the standard error Σx²·var_y propagated, √(Σx²var_y)/Σx², scaled by
    :func:`_birge` with ν = n − 1 when the points scatter more than their errors about the
    weighted line (with errors spanning decades the unweighted line's χ² overstated the scatter:
    over 30 simulated cameras σ_y.dark's stated error was 1.23 times its spread, now 1.00)."""
    sxx = float(np.sum(x * x))
    if not sxx > 0:
        return float("nan"), float("nan")
    m = float(np.sum(x * y) / sxx)
    err = math.sqrt(float(np.sum(x * x * var_y))) / sxx
    if np.all(var_y > 0):
        # the scatter judged about the weighted line (the unweighted line's residuals at the
        # precise points carry the noisy points' pull: see ccdcore.emva_dark)
        w = 1.0 / var_y
        mw = float(np.sum(w * x * y) / np.sum(w * x * x))
        chi2 = float(np.sum(w * (y - mw * x) ** 2))
        err *= _birge(chi2, x.size - 1)
    return m, err


def _line_b_intercept(x: np.ndarray, y: np.ndarray, var_y: np.ndarray
                      ) -> tuple[float, float, float]:
    """Slope, intercept of the unweighted least-squares line (``routines.LinearB``) and the
    intercept's standard error: b = Σcᵢyᵢ with cᵢ = 1/n − x̄(xᵢ − x̄)/Sxx, var(b) = Σcᵢ²var_yᵢ,
    scaled by :func:`_birge` with ν = n − 2 (the χ² of the weighted line, as :func:`_line_b0`)."""
    n = x.size
    xm = float(x.mean())
    sxx = float(np.sum((x - xm) ** 2))
    slope = float(np.sum((x - xm) * (y - y.mean())) / sxx)
    intercept = float(y.mean() - slope * xm)
    c = 1.0 / n - xm * (x - xm) / sxx
    err = math.sqrt(float(np.sum(c * c * var_y)))
    if np.all(var_y > 0):
        w = 1.0 / var_y                     # the scatter about the weighted line (_line_b0)
        xw = float(np.sum(w * x) / np.sum(w))
        bw = float(np.sum(w * (x - xw) * y) / np.sum(w * (x - xw) ** 2))
        aw = float(np.sum(w * (y - bw * x)) / np.sum(w))
        chi2 = float(np.sum(w * (y - (bw * x + aw)) ** 2))
        err *= _birge(chi2, n - 2)
    return slope, intercept, err


def _linearity_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """The package's linearity fit (``Results1288.linearity``): the line a·x + b minimising
    Σ((y − a·x − b)/y)², in closed form."""
    xy = np.sum(x / y)
    xy2 = np.sum(x / y ** 2)
    x2y2 = np.sum((x / y) ** 2)
    _y = np.sum(1.0 / y)
    _y2 = np.sum(1.0 / y ** 2)
    b = ((xy * xy2) - (x2y2 * _y)) / ((xy2 ** 2) - (x2y2 * _y2))
    a = (xy - (b * xy2)) / x2y2
    return float(a), float(b)


def _saturation_index(s2_y: np.ndarray) -> int:
    """The package's saturation point (``Results1288.index_u_ysat``): walking back from the
    last point, the largest σ²_y before two consecutive points fall below it."""
    max_, max_i = 0.0, 0
    for i in range(len(s2_y) - 1, -1, -1):
        if s2_y[i] >= max_ or s2_y[abs(i - 1)] >= max_:
            max_, max_i = s2_y[i], i
        elif s2_y[i] < max_ and s2_y[abs(i - 1)] < max_:
            break
    return int(max_i)


# --------------------------------------------------------------------------------------------
# reading the frames
# --------------------------------------------------------------------------------------------
def _pixels(rec: FrameRecord, frame: np.ndarray) -> np.ndarray:
    """The frame as int64 (integer codes below 2¹⁶: exact sums, as the package keeps them; the
    sums of squares of a frame of up to 2³¹ pixels stay below 2⁶³) or float64 (other data)."""
    if frame.ndim != 2:
        raise CcdError(rec.relpath, f"colour frames ({'x'.join(map(str, frame.shape))}): the "
                                    "EMVA 1288 figures (release 3.1) are computed on mono frames")
    if frame.dtype.kind in "ui" and int(frame.max()) < 2 ** 16 and int(frame.min()) >= 0:
        return frame.astype(np.int64)
    out = frame.astype(np.float64)
    if not np.all(np.isfinite(out)):
        raise CcdError(rec.relpath, "NaN or infinite pixel values; the EMVA 1288 figures need "
                                    "finite pixel values")
    return out


def _pair(rec_a: FrameRecord, a: np.ndarray, rec_b: FrameRecord, b: np.ndarray
          ) -> tuple[float, float, int]:
    """μ_y and σ²_y of a pair exactly as ``Data1288._get_temporal_data``: the mean of the sum
    image over 2N; the pseudo-variance Σ2(y_A − y_B)² over 4N less (ȳ_B − ȳ_A)²/2."""
    if a.shape != b.shape:
        raise CcdError(rec_b.relpath, f"shape {b.shape} differs from {rec_a.relpath} {a.shape}")
    n = a.size
    total = a.sum() + b.sum()
    d = a - b
    sd2 = (d * d).sum()
    dmean = b.mean() - a.mean()
    return float(total / (2.0 * n)), float(sd2 / (2.0 * n) - dmean * dmean / 2.0), int(n)


class _Stack:
    """Sum and sum of squares of L frames, per pixel (``routines.get_int_imgs``)."""

    def __init__(self) -> None:
        self.sum: np.ndarray | None = None
        self.sq: np.ndarray | None = None
        self.L = 0

    def add(self, rec: FrameRecord, pix: np.ndarray) -> None:
        if self.sum is None:
            self.sum, self.sq = pix.copy(), pix * pix
        else:
            if pix.shape != self.sum.shape:
                raise CcdError(rec.relpath, f"shape {pix.shape} differs from the other frames "
                                            f"of its set {self.sum.shape}")
            self.sum += pix
            self.sq += pix * pix
        self.L += 1

    def statistics(self, level: int | None, exposure: float | None, u_p: float) -> SpatialSet:
        """``Data1288._get_spatial_data``: ⟨y⟩ = Σy/L; per-pixel variance
        L(LΣy² − (Σy)²)/(L²(L − 1)); its mean σ²_y.stack; the spatial variance of ⟨y⟩ with
        ddof = 1, less σ²_y.stack/L."""
        assert self.sum is not None and self.sq is not None
        L = self.L
        if self.sum.dtype.kind == "i":
            # exact in int64 while L³·max² < 2⁶³ (else float64, a relative rounding of 1e-16)
            big = float(L) ** 3 * float(np.abs(self.sum).max() / L) ** 2 >= 2.0 ** 62
            s = self.sum.astype(np.float64) if big else self.sum
            q = self.sq.astype(np.float64) if big else self.sq
        else:
            s, q = self.sum, self.sq
        pvar = L * (L * q - s * s)
        avg = s / float(L)
        var = pvar / (float(L) ** 2 * (L - 1))
        s2_stack = float(var.mean())
        u_y = float(avg.mean())
        s2_measured = float(np.var(avg, ddof=1))
        s2 = s2_measured - s2_stack / L
        n = int(avg.size)
        # the temporal noise left in <y> (variance s2_stack/L per pixel) is the only random part
        # once the pattern is fixed: var(s²) ≈ 4·s²·σ²_n/N + 2·σ⁴_n/N with σ²_n = s2_stack/L
        noise = s2_stack / L
        s2_err = math.sqrt(max(4.0 * max(s2, 0.0) * noise / n + 2.0 * noise * noise / n, 0.0))
        return SpatialSet(level=level, exposure=exposure, L=L, u_p=u_p, u_y=u_y,
                          s2_stack=s2_stack, s2_measured=s2_measured, s2=s2, s2_err=s2_err,
                          n_pixels=n, image=avg)


# --------------------------------------------------------------------------------------------
# the session's points
# --------------------------------------------------------------------------------------------
def _same_exposure(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return a is b
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-15)


def _dark_runs(session: Session) -> list[tuple[FrameRecord, ...]]:
    """Consecutive dark frames of one exposure, in session order: the dark points of a
    descriptor (each ``d`` line's images)."""
    runs: list[tuple[FrameRecord, ...]] = []
    cur: list[FrameRecord] = []
    for rec in session.frames:
        if rec.role == "dark" and cur and _same_exposure(cur[-1].exposure, rec.exposure):
            cur.append(rec)
            continue
        if cur:
            runs.append(tuple(cur))
        cur = [rec] if rec.role == "dark" else []
    if cur:
        runs.append(tuple(cur))
    return runs


def _exposure_text(t: float | None) -> str:
    return "unknown exposure" if t is None else f"exposure {t:g} s"


@dataclass(frozen=True)
class _Plan:
    """Which frames make which point (no pixels)."""

    temporal: tuple[tuple[int, float | None, float, tuple[FrameRecord, ...]], ...]
    darks: tuple[tuple[float | None, tuple[FrameRecord, ...]], ...]
    spatial: tuple[int, float | None, float, tuple[FrameRecord, ...]] | None
    spatial_dark: tuple[FrameRecord, ...] | None
    notes: tuple[str, ...]


def _plan(session: Session) -> _Plan:
    """Sort the session's frames into the points of sec. 6 and 8 (see the module docstring)."""
    label = session.label
    levels = session.ptc_levels()
    if not levels:
        raise CcdError(label, "no ptc frames: the EMVA 1288 figures need pairs of bright frames "
                              "at many light levels, each with its photon count")
    lacking = [lv for lv, recs in levels.items() if any(r.photons is None for r in recs)]
    if len(lacking) == len(levels):
        raise CcdError(label, "the ptc frames have " + _MISSING_PHOTONS)
    if lacking:
        shown = ", ".join(map(str, lacking[:8])) + (" …" if len(lacking) > 8 else "")
        raise CcdError(label, f"ptc level{'s' if len(lacking) > 1 else ''} {shown} ha"
                              f"{'ve' if len(lacking) > 1 else 's'} " + _MISSING_PHOTONS)
    notes: list[str] = []
    temporal, spatial_levels = [], []
    for lv, recs in levels.items():
        photons = {r.photons for r in recs}
        exposures = {r.exposure for r in recs}
        if len(photons) > 1 or len(exposures) > 1:
            raise CcdError(f"{label}: ptc level {lv}", "frames of one level differ in photon "
                                                       "count or exposure time")
        u_p = float(recs[0].photons)
        if not u_p > 0:
            raise CcdError(f"{label}: ptc level {lv}", f"photon count {u_p:g}: a bright point "
                                                       "needs a positive photon count")
        entry = (lv, recs[0].exposure, u_p, recs)
        (temporal if len(recs) == 2 else spatial_levels).append(entry)
    if len(temporal) < 3:
        raise CcdError(label, f"{len(temporal)} temporal bright point"
                              f"{'s' if len(temporal) != 1 else ''} (ptc levels of two frames); "
                              "the EMVA 1288 figures need at least 3, and the standard asks for "
                              "many more, from dark to saturation")
    # the package orders the temporal points by exposure time, then photon count
    temporal.sort(key=lambda e: (e[1] is None, e[1] or 0.0, e[2]))

    runs = _dark_runs(session)
    if not runs:
        raise CcdError(label, "no dark frames: the EMVA 1288 figures subtract from each bright "
                              "point the dark point (two dark frames) at its exposure time")
    darks: list[tuple[float | None, tuple[FrameRecord, ...]]] = []
    for t in dict.fromkeys(e[1] for e in temporal):
        pairs = [r for r in runs if len(r) == 2 and _same_exposure(r[0].exposure, t)]
        longer = [r for r in runs if len(r) > 2 and _same_exposure(r[0].exposure, t)]
        if pairs:
            darks.append((t, pairs[0]))
            if len(pairs) > 1:
                notes.append(f"{len(pairs)} dark points of two frames at {_exposure_text(t)}; "
                             f"the first ({pairs[0][0].relpath}, …) is used")
        elif longer:
            darks.append((t, longer[0][:2]))
            notes.append(f"no dark point of two frames at {_exposure_text(t)}: its first two "
                         f"dark frames ({longer[0][0].relpath}, {longer[0][1].relpath}) serve "
                         "(the reference implementation would refuse the set)")
        else:
            have = sorted({r[0].exposure for r in runs if r[0].exposure is not None})
            raise CcdError(label, f"no dark frames at {_exposure_text(t)} (bright point of ptc "
                                  f"level {next(e[0] for e in temporal if e[1] == t)}): EMVA "
                                  "1288 subtracts the dark point at each bright point's exposure "
                                  "time; the dark frames are at " + (
                                      ", ".join(f"{x:g}" for x in have[:6]) + " s"
                                      if have else "unknown exposures"))
    spatial = spatial_dark = None
    if spatial_levels:
        spatial = spatial_levels[0]
        if len(spatial_levels) > 1:
            notes.append(f"{len(spatial_levels)} spatial sets (ptc levels of more than two "
                         f"frames: {', '.join(str(e[0]) for e in spatial_levels)}); DSNU1288 "
                         f"and PRNU1288 come from the first, level {spatial[0]}")
        sp_dark = [r for r in runs if len(r) > 2 and _same_exposure(r[0].exposure, spatial[1])]
        if sp_dark:
            spatial_dark = sp_dark[0]
        else:
            notes.append(f"the spatial set (ptc level {spatial[0]}, {len(spatial[3])} frames) "
                         f"has no dark set of more than two frames at its "
                         f"{_exposure_text(spatial[1])}: DSNU1288 and PRNU1288 are not computed")
            spatial = None
    else:
        notes.append("no spatial sets (a ptc level of more than two frames and as many dark "
                     "frames at its exposure, sec. 8): DSNU1288 and PRNU1288 are not computed")
    return _Plan(temporal=tuple(temporal), darks=tuple(darks), spatial=spatial,
                 spatial_dark=spatial_dark, notes=tuple(notes))


_Moments = tuple[float, float, int]   # μ_y, σ²_y, N of a pair


def _dark_level(dark_points: Sequence[DarkPoint]
                ) -> tuple[tuple[float, float], tuple[float, float], str]:
    """(σ²_y.dark, error), (μ_y.dark, error) and how they were found (``Results1288.
    sigma_y_dark``): the dark point of the shortest exposure when there are at most two
    exposure times (or one is unknown), else the intercepts of the unweighted lines against the
    exposure time (``LinearB``)."""
    if len({d.exposure for d in dark_points}) <= 2 or any(d.exposure is None
                                                          for d in dark_points):
        first = dark_points[0]          # the shortest exposure (points are sorted)
        return ((first.s2_y_dark, first.s2_y_dark_err), (first.u_y_dark, first.u_y_dark_err),
                f"the dark point at {_exposure_text(first.exposure)}")
    x = np.array([d.exposure for d in dark_points], dtype=np.float64)
    _, s2, s2_err = _line_b_intercept(x, np.array([d.s2_y_dark for d in dark_points]),
                                      np.array([d.s2_y_dark_err ** 2 for d in dark_points]))
    _, u, u_err = _line_b_intercept(x, np.array([d.u_y_dark for d in dark_points]),
                                    np.array([d.u_y_dark_err ** 2 for d in dark_points]))
    return ((s2, s2_err), (u, u_err),
            f"extrapolated to zero exposure from {len(dark_points)} exposure times")


def _read(session: Session, plan: _Plan
          ) -> tuple[list[_Moments], list[_Moments], dict[str, SpatialSet]]:
    """One streamed pass over the frames of the plan: the moments of the temporal bright pairs
    and of the dark pairs (in plan order), and the statistics of the spatial sets (keys
    ``spatial``, ``spatial_dark``), two frames or one set's running sums in memory."""
    jobs: list[tuple[str, Any, Sequence[FrameRecord]]] = (
        [("bright", e, e[3]) for e in plan.temporal]
        + [("dark", d, d[1]) for d in plan.darks])
    if plan.spatial is not None and plan.spatial_dark is not None:
        jobs += [("spatial", plan.spatial, plan.spatial[3]),
                 ("spatial_dark", None, plan.spatial_dark)]
    pairs: dict[str, list[_Moments]] = {"bright": [], "dark": []}
    stacks: dict[str, SpatialSet] = {}
    with closing(session.iter_frames([r for _, _, recs in jobs for r in recs],
                                     read_ahead=READ_AHEAD)) as stream:
        for kind, what, recs in jobs:
            if kind in pairs:
                (ra, fa), (rb, fb) = next(stream), next(stream)
                pairs[kind].append(_pair(ra, _pixels(ra, fa), rb, _pixels(rb, fb)))
                continue
            stack = _Stack()
            for _ in recs:
                rec, frame = next(stream)
                stack.add(rec, _pixels(rec, frame))
            stacks[kind] = (stack.statistics(what[0], what[1], what[2]) if kind == "spatial"
                            else stack.statistics(None, recs[0].exposure, 0.0))
    sizes = {n for _, _, n in pairs["bright"] + pairs["dark"]}
    sizes |= {s.n_pixels for s in stacks.values()}
    if len(sizes) > 1:
        raise CcdError(session.label, f"frames of different sizes ({sorted(sizes)} pixels)")
    return pairs["bright"], pairs["dark"], stacks


def _linearity(u_p: np.ndarray, Y: np.ndarray, var_Y: np.ndarray, i_sat: int, label: str
               ) -> tuple[int, int, float, float, tuple[float, float], tuple[float, float]]:
    """The linearity of sec. 6.7 as ``Results1288.linearity``: the fit range (first, last
    index), the fit's slope and offset, (LE_min, its error), (LE_max, its error)."""
    lo = np.flatnonzero(Y >= LINEARITY_RANGE[0] * Y[i_sat])
    hi = np.flatnonzero(Y <= LINEARITY_RANGE[1] * Y[i_sat])
    first, last = int(lo.min()), int(hi.max())
    if last - first + 1 < 2:
        raise CcdError(label, f"{max(last - first + 1, 0)} bright point(s) between "
                              f"{100 * LINEARITY_RANGE[0]:g} and {100 * LINEARITY_RANGE[1]:g} % of "
                              "saturation: the linearity fit needs at least 2")
    lin = slice(first, last + 1)

    def deviations(y: np.ndarray) -> tuple[np.ndarray, float, float]:
        a, b = _linearity_fit(u_p[lin], y[lin])
        fitted = a * u_p[lin] + b
        return 100.0 * (y[lin] - fitted) / fitted, a, b

    dev, a, b = deviations(Y)
    k_min, k_max = int(np.argmin(dev)), int(np.argmax(dev))
    # first-order propagation of the Y errors: central differences of the closed-form fit
    jac = np.zeros((dev.size, Y.size))
    for j in range(first, last + 1):
        h = 1e-6 * max(abs(Y[j]), 1.0)
        up, down = Y.copy(), Y.copy()
        up[j] += h
        down[j] -= h
        jac[:, j] = (deviations(up)[0] - deviations(down)[0]) / (2.0 * h)
    dev_err = np.sqrt((jac * jac) @ var_Y)
    return (first, last, a, b, (float(dev[k_min]), float(dev_err[k_min])),
            (float(dev[k_max]), float(dev_err[k_max])))


def _nonuniformity(sp: SpatialSet, spd: SpatialSet, K: float, K_err: float, notes: list[str]
                   ) -> tuple[float, float, float, float]:
    """DSNU1288, its error, PRNU1288, its error (sec. 4.1, 8; NaN where a variance is negative,
    with a note)."""
    if spd.s2 >= 0:
        dsnu = math.sqrt(spd.s2) / K
        dsnu_err = (dsnu * math.hypot(spd.s2_err / (2.0 * spd.s2), K_err / K)
                    if spd.s2 > 0 else _nan())
    else:
        dsnu = dsnu_err = _nan()
        notes.append(f"the dark spatial variance s2_y.dark = {spd.s2:.4g} DN² is negative "
                     "(no measurable DSNU): DSNU1288 is not a number")
    diff = sp.s2 - spd.s2
    signal = sp.u_y - spd.u_y
    if diff >= 0 and signal > 0:
        prnu = 100.0 * math.sqrt(diff) / signal
        signal_err = math.sqrt(sp.s2_stack / (sp.L * sp.n_pixels)
                               + spd.s2_stack / (spd.L * spd.n_pixels))
        prnu_err = (prnu * math.hypot(math.hypot(sp.s2_err, spd.s2_err) / (2.0 * diff),
                                      signal_err / signal) if diff > 0 else _nan())
    else:
        prnu = prnu_err = _nan()
        notes.append(f"the bright spatial variance does not exceed the dark one "
                     f"({sp.s2:.4g} vs {spd.s2:.4g} DN²): PRNU1288 is not a number")
    return dsnu, dsnu_err, prnu, prnu_err


def _spatial_section(sp: SpatialSet, spd: SpatialSet, K: float, K_err: float,
                     dsnu: float | None, prnu: float | None, notes: list[str]
                     ) -> tuple[NonuniformitySplit | None, SpatialPlots | None]:
    """The release 4.0 split of DSNU and PRNU and the arrays of sec. 8's plots, from the
    average images of the spatial sets (:mod:`ccdcore.emva_spatial`)."""
    if sp.image is None or spd.image is None:
        return None, None
    if sp.image.shape != spd.image.shape or min(sp.image.shape) < 2 * 5:
        notes.append(f"the spatial sets' images ({sp.image.shape}, {spd.image.shape}) are too "
                     "small or differ: no row/column/pixel split and no spatial plots")
        return None, None
    split = nonuniformity_split(variance_split(sp.image, sp.s2_stack, sp.L),
                                variance_split(spd.image, spd.s2_stack, spd.L), K, K_err)
    notes.extend(split.notes)
    finite = (lambda v: v if v is not None and math.isfinite(v) else None)
    plots = spatial_plots(sp.image, spd.image, L=sp.L, L_dark=spd.L, s2_stack=sp.s2_stack,
                          s2_stack_dark=spd.s2_stack, K=K, DSNU1288=finite(dsnu),
                          PRNU1288=finite(prnu))
    return split, plots


# --------------------------------------------------------------------------------------------
# the figures
# --------------------------------------------------------------------------------------------
def _nan() -> float:
    return float("nan")


def _points(plan: Any, bright_stats: Sequence, dark_stats: Sequence
            ) -> tuple[list[DarkPoint], list[EmvaPoint]]:
    """The dark points (one per exposure time) and the bright points (sec. 6.6, ``Data1288``),
    each with the standard errors of its mean and variance (normal pixels)."""
    dark_points = []
    for i, (t, recs) in enumerate(plan.darks):
        mu, s2, n = dark_stats[i]
        dark_points.append(DarkPoint(
            exposure=t, u_y_dark=mu, u_y_dark_err=math.sqrt(max(s2, 0.0) / (2.0 * n)),
            s2_y_dark=s2, s2_y_dark_err=math.sqrt(2.0 * s2 * s2 / (n - 1)),
            relpaths=(recs[0].relpath, recs[1].relpath)))
    raw = []
    for (lv, t, u_p, _), (mu, s2, n) in zip(plan.temporal, bright_stats):
        d = _dark_at(dark_points, t)
        raw.append(EmvaPoint(level=lv, exposure=t, u_p=u_p, u_y=mu,
                             u_y_err=math.sqrt(max(s2, 0.0) / (2.0 * n)), s2_y=s2,
                             s2_y_err=math.sqrt(2.0 * s2 * s2 / (n - 1)), u_y_dark=d.u_y_dark,
                             s2_y_dark=d.s2_y_dark, s2_y_dark_err=d.s2_y_dark_err, n_pixels=n))
    return dark_points, raw


def _dark_at(dark_points: Sequence[DarkPoint], t: float | None) -> DarkPoint:
    return next(d for d in dark_points if _same_exposure(d.exposure, t))


@dataclass(frozen=True)
class _Curves:
    """The bright points as arrays: μ_p, Y = μ_y − μ_y.dark, S = σ²_y − σ²_y.dark, their
    variances, and σ²_y."""

    u_p: np.ndarray
    Y: np.ndarray
    var_Y: np.ndarray
    S: np.ndarray
    var_S: np.ndarray
    s2_y: np.ndarray

    @classmethod
    def of(cls, raw: Sequence[EmvaPoint], dark_points: Sequence[DarkPoint]) -> "_Curves":
        return cls(
            u_p=np.array([p.u_p for p in raw]),
            Y=np.array([p.u_y - p.u_y_dark for p in raw]),
            var_Y=np.array([p.u_y_err ** 2 + _dark_at(dark_points, p.exposure).u_y_dark_err ** 2
                            for p in raw]),
            S=np.array([p.s2_y - p.s2_y_dark for p in raw]),
            var_S=np.array([p.s2_y_err ** 2 + p.s2_y_dark_err ** 2 for p in raw]),
            s2_y=np.array([p.s2_y for p in raw]))


@dataclass(frozen=True)
class _Sensitivity:
    i_sat: int
    i_fit: int
    R: float
    R_err: float
    K: float
    K_err: float
    QE: float
    QE_err: float


def _sensitivity(c: _Curves, raw: Sequence[EmvaPoint], label: str, notes: list[str]
                 ) -> _Sensitivity:
    """The saturation point, the fit range and the fits of R and K (sec. 6.6), QE = R/K."""
    Y = c.Y
    i_sat = _saturation_index(c.s2_y)
    i_peak = int(np.argmax(c.s2_y))
    if c.s2_y[i_peak] > c.s2_y[i_sat]:
        notes.append(f"the saturation point is taken as the package does (its backward search "
                     f"stops at ptc level {raw[i_sat].level}, mu_y - mu_y.dark = "
                     f"{Y[i_sat]:.4g} DN), but the largest variance is at ptc level "
                     f"{raw[i_peak].level} ({Y[i_peak]:.4g} DN): the "
                     "search stopped on the plateau after saturation, and the figures that "
                     "use the saturation point (the fit range, mu_p.sat, mu_e.sat, SNR_max, "
                     "DR, linearity) are those of that point")
    below = np.flatnonzero(Y <= SENSITIVITY_FRACTION * Y[i_sat])
    if Y[i_sat] <= 0 or below.size == 0:
        raise CcdError(label, f"every bright point is saturated or dark: no point has a signal "
                              f"mu_y - mu_y.dark below {100 * SENSITIVITY_FRACTION:g} % of the "
                              f"saturation point's {Y[i_sat]:.4g} DN (ptc level "
                              f"{raw[i_sat].level}); capture points from dark to saturation")
    i_fit = int(below.max())
    fit = slice(0, i_fit + 1)
    if i_fit + 1 < 2:
        raise CcdError(label, f"only {i_fit + 1} bright point below "
                              f"{100 * SENSITIVITY_FRACTION:g} % of saturation (ptc level "
                              f"{raw[i_sat].level} at {Y[i_sat]:.4g} DN): the fits of R and K need "
                              "at least 2; capture more points below saturation")
    R, R_err = _line_b0(c.u_p[fit], Y[fit], c.var_Y[fit])
    K, K_err = _line_b0(Y[fit], c.S[fit], c.var_S[fit])
    if not (K > 0 and R > 0):
        raise CcdError(label, f"the fitted system gain K = {K:.4g} DN/e- or responsivity "
                              f"R = {R:.4g} DN/p is not positive: check the dark subtraction "
                              "and the photon counts")
    QE = 100.0 * R / K
    return _Sensitivity(i_sat, i_fit, R, R_err, K, K_err, QE,
                        QE * math.hypot(R_err / R, K_err / K))


@dataclass(frozen=True)
class _DarkNoise:
    sigma_y_dark: float
    sigma_y_dark_err: float
    sigma_y_dark_measured: float
    u_dark: float
    u_dark_err: float
    sigma_d: float
    sigma_d_err: float
    quantisation_limited: bool


def _dark_noise(dark_points: Sequence[DarkPoint], sens: _Sensitivity, notes: list[str]
                ) -> _DarkNoise:
    """σ_y.dark (floored as the package does), μ_y.dark and σ_d from the darks (sec. 2.2, 3)."""
    K, K_err = sens.K, sens.K_err
    (s2_dark, s2_dark_err), (u_dark, u_dark_err), dark_rule = _dark_level(dark_points)
    sigma_y_dark_measured = math.sqrt(s2_dark) if s2_dark > 0 else 0.0
    if s2_dark < SIGMA2_Y_DARK_FLOOR:
        notes.append(f"sigma2_y.dark = {s2_dark:.4g} DN² ({dark_rule}) is below "
                     f"{SIGMA2_Y_DARK_FLOOR:g} DN²: floored there as the package does, so "
                     "sigma_y.dark, sigma_d and mu_p.min are upper bounds without an error")
        s2_used, s2_used_err = SIGMA2_Y_DARK_FLOOR, _nan()
    else:
        s2_used, s2_used_err = s2_dark, s2_dark_err
    sigma_y_dark = math.sqrt(s2_used)
    excess = s2_used - QUANTISATION_VARIANCE
    sigma_d = math.sqrt(excess) / K if excess > 0 else _nan()
    if excess > 0:
        sigma_d_err = math.hypot(s2_used_err / (2.0 * K * math.sqrt(excess)), sigma_d * K_err / K)
    else:
        sigma_d_err = _nan()
    quantisation_limited = sigma_y_dark_measured < QUANTISATION_LIMIT_DN
    if quantisation_limited:
        notes.append(f"the temporal dark noise sigma_y.dark = {sigma_y_dark_measured:.3g} DN is "
                     f"below {QUANTISATION_LIMIT_DN:g} DN: at this level the rounding of the "
                     "ADC (quantisation noise, 1/12 DN²) dominates it, so the read noise sigma_d "
                     "is poorly determined, and the value from the darks and the one from the "
                     "photon-transfer intercept can differ by a factor of two; a higher gain "
                     "setting would measure it")
    return _DarkNoise(sigma_y_dark, s2_used_err / (2.0 * sigma_y_dark), sigma_y_dark_measured,
                      u_dark, u_dark_err, sigma_d, sigma_d_err, quantisation_limited)


@dataclass(frozen=True)
class _PtcReadNoise:
    sigma_d: float | None = None
    sigma_d_err: float | None = None
    K: float | None = None
    K_err: float | None = None
    consistent: bool | None = None


def _ptc_read_noise(session: Session | None, noise: PhotonTransfer | None, with_ptc: bool,
                    dark: _DarkNoise, notes: list[str]) -> _PtcReadNoise:
    """σ_d from the intercept of our photon-transfer line (Healey & Kondepudy eq. 27), and
    whether it agrees with σ_d from the darks within :data:`DISAGREEMENT_Z` standard errors."""
    if noise is None and with_ptc:
        from .noise import photon_transfer

        try:
            noise = photon_transfer(session)
        except CcdError as exc:
            notes.append(f"sigma_d from photon transfer is not available: {exc.problem}")
    if noise is None:
        return _PtcReadNoise()
    K_ptc, K_ptc_err = float(noise.A), float(noise.A_err)
    if not math.isfinite(noise.read_noise_e):
        notes.append("sigma_d from photon transfer is not resolved (its intercept "
                     "sigma_c2 is not above q²/12)")
        return _PtcReadNoise(K=K_ptc, K_err=K_ptc_err)
    s_ptc, s_ptc_err = float(noise.read_noise_e), float(noise.read_noise_e_err)
    consistent: bool | None = None
    both = math.hypot(dark.sigma_d_err, s_ptc_err)
    if math.isfinite(dark.sigma_d) and math.isfinite(both) and both > 0:
        z = abs(dark.sigma_d - s_ptc) / both
        consistent = z <= DISAGREEMENT_Z
        if not consistent:
            notes.append(
                f"sigma_d from the darks ({dark.sigma_d:.4g} ± {dark.sigma_d_err:.2g} e-) and "
                f"from the photon-transfer intercept ({s_ptc:.4g} ± {s_ptc_err:.2g} e-) "
                f"disagree by {z:.1f} standard errors"
                + (" (quantisation dominates the dark noise)"
                   if dark.quantisation_limited else ""))
    return _PtcReadNoise(s_ptc, s_ptc_err, K_ptc, K_ptc_err, consistent)


@dataclass(frozen=True)
class _Range:
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


def _threshold_and_range(u_p: np.ndarray, sens: _Sensitivity, dark: _DarkNoise) -> _Range:
    """The absolute sensitivity threshold, the saturation capacity, SNR_max and the dynamic
    range (sec. 2.4; eqs. 18, 33), with first-order errors."""
    R, R_err, K, K_err, QE = sens.R, sens.R_err, sens.K, sens.K_err, sens.QE
    eta = QE / 100.0
    u_p_min = (100.0 / QE) * (dark.sigma_y_dark / K + 0.5)          # = (σ_y.dark + K/2)/R
    u_p_min_err = math.sqrt((dark.sigma_y_dark_err / R) ** 2 + (K_err / (2.0 * R)) ** 2
                            + (u_p_min * R_err / R) ** 2)
    i_sat = sens.i_sat
    u_p_sat = float(u_p[i_sat])
    # the saturation point is one of the grid's points: the resolution of the series, the
    # local spacing over √12 (a uniform spread between the neighbours' midpoints)
    lo_i, hi_i = max(i_sat - 1, 0), min(i_sat + 1, len(u_p) - 1)
    u_p_sat_err = abs(float(u_p[hi_i] - u_p[lo_i])) / max(hi_i - lo_i, 1) / math.sqrt(12.0)
    u_e_sat = eta * u_p_sat
    u_e_sat_err = math.hypot(u_p_sat * sens.QE_err / 100.0, eta * u_p_sat_err)
    SNR_max = math.sqrt(u_e_sat)
    DR = u_p_sat / u_p_min
    DR_err = DR * math.hypot(u_p_min_err / u_p_min, u_p_sat_err / u_p_sat)
    return _Range(u_p_min, u_p_min_err, u_p_sat, u_p_sat_err, u_e_sat, u_e_sat_err, SNR_max,
                  u_e_sat_err / (2.0 * SNR_max), DR, DR_err, 20.0 * math.log10(DR),
                  20.0 / math.log(10.0) * DR_err / DR)


def emva_figures(session: Session | str | PathLike, *, noise: PhotonTransfer | None = None,
                 progress: Progress | None = None, with_ptc: bool = True) -> EmvaFigures:
    """The EMVA 1288 (release 3.1) figures of a session whose bright frames carry photon counts.

    Parameters
    ----------
    session
        An EMVA1288 descriptor opened as a session, or its path (or a manifest with
        ``photons``): temporal bright points (``ptc`` levels of two frames), the two dark frames
        at each of their exposure times and, optionally, a spatial set (module docstring).
    noise
        Our photon-transfer result for the same session (:func:`ccdcore.noise.photon_transfer`),
        for ``sigma_d_ptc``; computed here when not given.
    progress
        A :class:`ccdcore.progress.Progress`: ``progress(start, name)`` as each of
        :data:`EMVA_STEPS` starts.
    with_ptc
        When ``noise`` is not given: compute it (``True``), or leave ``sigma_d_ptc`` out
        (``False``: a caller whose photon transfer already failed).

    Returns
    -------
    EmvaFigures

    Raises
    ------
    CcdError
        The ptc frames carry no photon counts; a session error touching the ptc or dark frames;
        fewer than 3 temporal bright points; no dark frames, or none at a bright point's exposure;
        colour frames; every point saturated (no point below 70 % of the saturation signal);
        fewer than 2 points in the sensitivity fit.

    Notes
    -----
    Per point (sec. 6.6, ``Data1288``): μ_y = mean of both frames; σ²_y = the population variance
    of the difference image over 2 (the package's pseudo-variance less the squared difference of
    the frame means over 2); the same of the dark point at the point's exposure.  Points are
    ordered by exposure time, then by μ_p.  Standard errors of the points: √(σ²_y/(2N)) for μ_y
    and √(2σ⁴_y/(N − 1)) for σ²_y (normal pixels; the difference image has no fixed pattern).

    * Saturation point (sec. 6.6, ``index_u_ysat``): walking back from the last point, the point
      of largest σ²_y until two consecutive points fall below it (the package's search; it can
      stop on the plateau after saturation: a note then names the point of largest σ²_y).
      μ_p.sat is its μ_p.
    * Fit range (``index_sensitivity_max``): the points from the first to the last whose
      μ_y − μ_y.dark ≤ 70 % of that at saturation.
    * R (responsivity, DN/p, sec. 2.1): slope through the origin of μ_y − μ_y.dark against μ_p.
      K (system gain, DN/e⁻, sec. 2.2 and 6.6, the photon transfer method): slope through the
      origin of σ²_y − σ²_y.dark against μ_y − μ_y.dark.  Both are unweighted least squares
      (``LinearB0``); their standard errors propagate the points' errors through the fit,
      √(Σx²var_y)/Σx², scaled by √(χ²/ν) when the points scatter more than their errors (the
      photon counts are taken as exact: the error of R does not include the calibration of the
      light).
    * QE η = R/K in % (sec. 2.1), error from R and K (independent).
    * σ_y.dark (DN, sec. 2.2 and 3): σ²_y.dark of the shortest exposure when the session has at
      most two exposure times, else the intercept of the unweighted line σ²_y.dark against the
      exposure time (``LinearB``); floored at 0.24 DN² as the package does (quantisation
      dominates below; the error is then NaN and a note says so).  σ_y_dark_measured keeps the
      value before the floor.  μ_y.dark likewise (dark mean, or the intercept of its line).
    * σ_d = √(σ²_y.dark − 1/12)/K (e⁻, "from darks"; sec. 2.2), error propagated from σ²_y.dark
      and K.
    * sigma_d_ptc = √(σ²_C − q²/12)/A, the read noise from the intercept of our photon transfer
      line (eq. 27 of Healey & Kondepudy; :attr:`PhotonTransfer.read_noise_e`), with its error
      from the fit covariance.  A note flags a disagreement beyond :data:`DISAGREEMENT_Z`
      combined standard errors, and σ_y.dark below 0.5 DN (quantisation dominates).
    * μ_p.min = (σ_y.dark/K + 1/2)/η (absolute sensitivity threshold, sec. 2.4), μ_e.sat = η·μ_p.sat
      (saturation capacity), SNR_max = √μ_e.sat (eq. 33), DR = μ_p.sat/μ_p.min (eq. 18) and
      20·log₁₀ DR; errors by first-order propagation.  μ_p.sat is the photon count of one of
      the points, so its error is the resolution of the series: the local spacing of μ_p over
      √12 (over seeds of the generator the saturation point moves between neighbours, and this
      error matches that spread); it enters μ_e.sat, SNR_max and DR.
    * Linearity (sec. 6.7, ``Results1288.linearity``): the line a·μ_p + b through the points from
      5 % to 95 % of the saturation signal, minimising Σ((Y − a·μ_p − b)/Y)² (Y = μ_y − μ_y.dark);
      LE_min, LE_max = the extreme relative deviations 100·(Y − fit)/fit over those points (%).
      Errors: the temporal errors of the Y's propagated through the fit and the deviation at
      the point where the extreme is reached (an upper bound: the extreme of n deviations
      scatters less than one of them, about half as much over seeds of the generator).
    * DSNU1288 = s_y.dark/K (e⁻) and PRNU1288 = 100·√(s²_y − s²_y.dark)/(μ_y − μ_y.dark) (%)
      from the spatial sets (sec. 4.1 and 8): s² = the spatial variance of the average image of
      the L frames (N − 1 denominator) less the mean per-pixel temporal variance over L.  With
      the pattern fixed, the only random part of s² is the temporal noise left in the average
      image, σ²_n = σ²_stack/L per pixel: var(s²) ≈ 4s²σ²_n/N + 2σ⁴_n/N; with K's error.  NaN
      (``None``) when a variance is negative, as the package does.
    """
    report = Steps(progress, EMVA_STEPS)
    if not isinstance(session, Session):
        session = open_session(session)
    session.raise_if_invalid(roles=("ptc", "dark"))
    plan = _plan(session)
    label = session.label
    notes = list(plan.notes)

    report("EMVA 1288 points")
    bright_stats, dark_stats, stacks = _read(session, plan)
    dark_points, raw = _points(plan, bright_stats, dark_stats)
    c = _Curves.of(raw, dark_points)
    sens = _sensitivity(c, raw, label, notes)
    dark = _dark_noise(dark_points, sens, notes)
    report("photon transfer")
    ptc_notes: list[str] = []
    ptc = _ptc_read_noise(session, noise, with_ptc, dark, ptc_notes)
    notes.extend(ptc_notes)
    thr = _threshold_and_range(c.u_p, sens, dark)
    i_lin_min, i_lin_max, lin_a, lin_b, (le_min, le_min_err), (le_max, le_max_err) = \
        _linearity(c.u_p, c.Y, c.var_Y, sens.i_sat, label)
    current = dark_current([d.exposure for d in dark_points],
                           [d.u_y_dark for d in dark_points],
                           [d.u_y_dark_err for d in dark_points],
                           [d.s2_y_dark for d in dark_points],
                           [d.s2_y_dark_err for d in dark_points], sens.K, sens.K_err)
    notes.extend(current.notes)
    dsnu = dsnu_err = prnu = prnu_err = None
    split = plots = None
    sp, spd = stacks.get("spatial"), stacks.get("spatial_dark")
    if sp is not None and spd is not None:
        dsnu, dsnu_err, prnu, prnu_err = _nonuniformity(sp, spd, sens.K, sens.K_err, notes)
        split, plots = _spatial_section(sp, spd, sens.K, sens.K_err, dsnu, prnu, notes)

    points = tuple(replace(p, in_sensitivity_fit=i <= sens.i_fit,
                           in_linearity_fit=i_lin_min <= i <= i_lin_max,
                           saturation=i == sens.i_sat)
                   for i, p in enumerate(raw))
    report("done")
    return EmvaFigures(
        K=sens.K, K_err=sens.K_err, R=sens.R, R_err=sens.R_err, QE=sens.QE, QE_err=sens.QE_err,
        sigma_y_dark=dark.sigma_y_dark, sigma_y_dark_err=dark.sigma_y_dark_err,
        sigma_y_dark_measured=dark.sigma_y_dark_measured, u_y_dark=dark.u_dark,
        u_y_dark_err=dark.u_dark_err, sigma_d=dark.sigma_d, sigma_d_err=dark.sigma_d_err,
        sigma_d_ptc=ptc.sigma_d, sigma_d_ptc_err=ptc.sigma_d_err, K_ptc=ptc.K, K_ptc_err=ptc.K_err,
        u_p_min=thr.u_p_min, u_p_min_err=thr.u_p_min_err, u_p_sat=thr.u_p_sat,
        u_p_sat_err=thr.u_p_sat_err, u_e_sat=thr.u_e_sat, u_e_sat_err=thr.u_e_sat_err,
        SNR_max=thr.SNR_max, SNR_max_err=thr.SNR_max_err, DR=thr.DR, DR_err=thr.DR_err,
        DR_dB=thr.DR_dB, DR_dB_err=thr.DR_dB_err, LE_min=le_min, LE_min_err=le_min_err,
        LE_max=le_max, LE_max_err=le_max_err, linearity_slope=lin_a, linearity_offset=lin_b,
        DSNU1288=dsnu, DSNU1288_err=dsnu_err, PRNU1288=prnu, PRNU1288_err=prnu_err,
        index_u_ysat=sens.i_sat, index_sensitivity_max=sens.i_fit,
        index_linearity_min=i_lin_min, index_linearity_max=i_lin_max, points=points,
        dark_points=tuple(dark_points), spatial=sp, spatial_dark=spd,
        sigma_d_consistent=ptc.consistent, quantisation_limited=dark.quantisation_limited,
        notes=tuple(notes), source=label, dark_current=current, split=split,
        spatial_plots=plots, ptc_notes=tuple(ptc_notes))


def with_photon_transfer(figures: EmvaFigures, noise: PhotonTransfer | None) -> EmvaFigures:
    """``figures`` with σ_d from the intercept of ``noise`` (``sigma_d_ptc``, ``K_ptc``, their
    agreement with the darks and its note) instead of the photon transfer they were made with;
    ``None`` leaves them out. No frame is read: a page that refits the photon transfer (other
    levels, another fit range) keeps the figures of the frames and changes only these."""
    base = [n for n in figures.notes if n not in set(figures.ptc_notes)]
    dark = _DarkNoise(figures.sigma_y_dark, figures.sigma_y_dark_err,
                      figures.sigma_y_dark_measured, figures.u_y_dark, figures.u_y_dark_err,
                      figures.sigma_d, figures.sigma_d_err, figures.quantisation_limited)
    ptc_notes: list[str] = []
    ptc = (_ptc_read_noise(None, noise, False, dark, ptc_notes) if noise is not None
           else _PtcReadNoise())
    return replace(figures, sigma_d_ptc=ptc.sigma_d, sigma_d_ptc_err=ptc.sigma_d_err,
                   K_ptc=ptc.K, K_ptc_err=ptc.K_err, sigma_d_consistent=ptc.consistent,
                   notes=tuple(base + ptc_notes), ptc_notes=tuple(ptc_notes))
