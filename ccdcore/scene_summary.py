"""The records a calibration product stores of the checks of Healey & Kondepudy (1994) sec. VI
and VII: the scene variation V_S of a patch (:class:`SceneSummary`, with its measurements) and
the correction check of sec. VII-A (:class:`CorrectionCheckSummary`).

They are :class:`ccdcore.records.Record` s: ``to_dict()`` gives the JSON object of
``calibration.json`` and ``from_dict`` reads it back, checked; ``rows()`` gives the headline
figures as :class:`ccdcore.records.Row` s.  :mod:`ccdcore.scene` builds them
(:meth:`ccdcore.scene.SceneVariation.summary`) and re-exports them; this module imports
neither it nor the estimators.

Public objects
--------------
SceneMeasurementSummary
    One ROI in one corrected scene image (:meth:`ccdcore.scene.SceneMeasurement.summary`).
SceneSummary
    One patch across light levels: the eq. 57 fit, χ², dof, Q and the measurements.
CorrectionCheckSummary
    How much eq. 51 changes a maximum-intensity image (sec. VII-A), built from a
    :class:`ccdcore.fixedpattern.CorrectionCheck` by :meth:`CorrectionCheckSummary.of`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from .common import json_safe
from .records import Record, Row

__all__ = ["SceneMeasurementSummary", "SceneSummary", "CorrectionCheckSummary"]


@dataclass(frozen=True)
class SceneMeasurementSummary(Record):
    """One region of interest in one corrected scene image (sec. VI) as a product stores it;
    the fields are those of :class:`ccdcore.scene.SceneMeasurement` with ``y`` and ``used``."""

    #: the source frame and its light-level id (``None`` when unknown)
    path: str | None
    level: int | None
    #: ``(x, y, w, h)`` in pixels, and the pixels in it
    roi: tuple[int, int, int, int]
    n_pixels: int
    #: μ̂_D, the mean of D_C over the ROI (eq. 54), DN; σ̂²_D, its sample variance (eq. 55), DN²
    mu_D: float
    var_D: float
    #: E[1/K̂²] over the ROI (eq. 56)
    E_invK2: float
    #: D̄_D, the mean of the dark reference over the ROI (eq. 58), and the black level b0, DN
    dark_mean: float
    black_level: float
    #: σ̂²_N = Â(μ̂_D + D̄_D − b0) + σ̂²_C (eq. 58), σ̂²_KN = E[1/K̂²]·σ̂²_N (eq. 56) and the
    #: variance of the calibration maps' own errors σ̂²_cal, DN²
    sigma_N2: float
    sigma_KN2: float
    sigma_cal2: float
    #: y = σ̂²_D − σ̂²_KN − σ̂²_cal, the left side of eq. 57, DN²
    y: float
    #: V_S = y/μ̂²_D (eq. 57), its standard error for the imaged region, and with the sampling
    #: of the texture itself
    V_S: float | None
    V_S_err: float | None
    V_S_err_population: float | None
    #: ROI pixels at 0 or at full scale (such a frame is left out of the fit)
    n_clipped: int
    #: whether the eq. 57 fit used the measurement
    used: bool

    def rows(self) -> tuple[Row, ...]:
        """The measurement as a person reads it: level, mean, variance, noise, V_S and whether
        the fit used it."""
        return (
            Row("level", self.level, meaning=f"light level of {self.path or 'the frame'}"),
            Row("mean μ̂_D", self.mu_D, None, "DN", "mean of the corrected region (eq. 54)"),
            Row("variance σ̂²_D", self.var_D, None, "DN²", "spatial variance (eq. 55)"),
            Row("noise σ̂²_KN", self.sigma_KN2, None, "DN²",
                "the sensor noise in the corrected region (eq. 56)"),
            Row("scene variation V_S", self.V_S, self.V_S_err, "",
                "relative variance of the surface at this level (eq. 57)"),
            Row("clipped pixels", self.n_clipped, meaning="pixels at 0 or full scale in the ROI"),
            Row("fit", meaning="whether the eq. 57 fit used the level",
                text="used" if self.used else "excluded"),
        )


@dataclass(frozen=True)
class SceneSummary(Record):
    """One surface patch across light levels as a product stores it (``estimates["scene"]``
    holds one per patch name; :meth:`ccdcore.scene.SceneVariation.summary`): the fit of eq. 57
    (Fig. 3)."""

    #: the patch name (``note = "patch=NAME"``) or ``"roi=x,y,w,h"``
    name: str
    #: the fitted scene variation V_S = σ_E²/S² (eq. 57, no unit) and its standard error
    V_S: float
    V_S_err: float
    #: χ² across levels, L − 1 degrees of freedom and Q (eq. 67); ``None`` for one level
    chi2: float | None
    dof: int
    Q: float | None
    #: every measured frame, in input order, with whether the fit used it
    measurements: tuple[SceneMeasurementSummary, ...]
    #: the reasons of the measurements left out (``"path: reason"``), and remarks
    excluded: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    def rows(self) -> tuple[Row, ...]:
        """The headline figures: V_S with its error, the fit's χ² and Q, the levels used and
        excluded."""
        used = sum(1 for m in self.measurements if m.used)
        return (
            Row("scene variation V_S", self.V_S, self.V_S_err, "",
                "relative variance of the surface, σ_E²/S² (eq. 57)"),
            Row("χ²", self.chi2, None, "", f"with {self.dof} degrees of freedom"),
            Row("goodness of fit Q", self.Q, None, "",
                "chance of so large a χ² if V_S is the same at every level (eq. 67)"),
            Row("levels used", used, meaning=f"of {len(self.measurements)} frames"),
            Row("excluded", len(self.excluded), meaning="; ".join(self.excluded)),
        )


@dataclass(frozen=True)
class CorrectionCheckSummary(Record):
    """How much dividing by K̂ (eq. 51) changes a maximum-intensity image, in quantisation
    steps q (sec. VII-A), as a product stores it (``estimates["correction_check"]``); the
    fields are those of :class:`ccdcore.fixedpattern.CorrectionCheck`."""

    #: fractions of all pixels changed by more than q (paper: 27 %) and by more than 2q
    #: (paper: 3 %), and the fraction of the > 1q pixels that exceed 2q
    frac_gt_1q: float
    frac_gt_2q: float
    frac_gt_2q_of_gt_1q: float
    #: the largest change, in q (paper: five steps)
    max_change_q: float
    #: the mean of D − D̂_D over the image, DN, and the pixels considered (finite values)
    mean_level: float
    n_pixels: int
    #: the quantisation step q, DN
    q: float = 1.0

    @classmethod
    def of(cls, check: Any) -> CorrectionCheckSummary:
        """The record of a :class:`ccdcore.fixedpattern.CorrectionCheck` (or anything with its
        attributes): plain numbers, NaN as ``None``."""
        return cls(frac_gt_1q=json_safe(check.frac_gt_1q), frac_gt_2q=json_safe(check.frac_gt_2q),
                   frac_gt_2q_of_gt_1q=json_safe(check.frac_gt_2q_of_gt_1q),
                   max_change_q=json_safe(check.max_change_q),
                   mean_level=json_safe(check.mean_level), n_pixels=json_safe(check.n_pixels),
                   q=json_safe(check.q))

    def rows(self) -> tuple[Row, ...]:
        """The headline figures: the pixels changed by more than 1 q and 2 q, the largest
        change, the mean level and q."""
        return (
            Row("pixels changed by more than 1 q", 100.0 * self.frac_gt_1q, None, "%",
                "of all pixels (paper: 27 %)"),
            Row("pixels changed by more than 2 q", 100.0 * self.frac_gt_2q, None, "%",
                "of all pixels (paper: 3 %)"),
            Row("of those above 1 q, above 2 q", 100.0 * self.frac_gt_2q_of_gt_1q, None, "%",
                "the other reading of the paper's 3 %"),
            Row("largest change", self.max_change_q, None, "q", "paper: five steps"),
            Row("mean level of the image", self.mean_level, None, "DN",
                f"mean of D − D̂_D over {self.n_pixels} pixels"),
            Row("quantisation step q", self.q, None, "DN", "the unit of the changes"),
        )
