"""Photon transfer: the camera noise model σ²_N = A·μ + σ²_C from pairs of flat frames.

Implements sec. IV and the appendix of G. E. Healey and R. Kondepudy, "Radiometric CCD Camera
Calibration and Noise Estimation", IEEE TPAMI 16(3), 1994.  For each light level a pair of frames
D₁, D₂ of a nearly uniform card gives the mean μ̂ (eq. 37), the noise variance σ̂²_N from the
difference image D₁ − D₂ (eq. 38) and the variance of that estimate (eq. 40).  The weighted line
σ²_N = A·μ + σ²_C (eq. 41) is fitted in closed form (eqs. 59–65, minimising χ² of eq. 42) with its
covariance (eq. 66) and goodness of fit Q (eq. 67).  A is the gain in DN per electron, 1/A the
conversion gain in electrons per DN, and σ²_C = A²σ²_R + q²/12 (eq. 27) gives the read noise σ_R in
electrons once the quantisation term q²/12 is removed (q = 1 DN for integer data).

Black level (an extension of the paper's model)
-----------------------------------------------
The paper's model (eq. 20) has no electronic offset: μ (eq. 36) is signal plus dark signal, all of
it with shot noise.  Real cameras add a black level b₀ (DN) that is not signal and has no shot
noise, so eq. 41 becomes σ²_N = A·(μ − b₀) + σ²_C and the fitted abscissa is μ̂ − b₀.  b₀ is, in
order (:attr:`PhotonTransfer.black_level_source`):

``"argument"``
    the ``black_level`` argument;
``"camera"``
    the session's ``[camera] black_level`` (manifest key, DN);
``"dark_extrapolated"``
    dark frames at two or more exposure times: the dark mean (over the ROI) extrapolated to zero
    exposure by a least-squares line in T (dark current ∝ T, sec. II-B), so the dark signal stays
    in μ with its shot noise, exactly as in the paper;
``"dark_mean"``
    dark frames at one exposure time: their mean (the EMVA 1288 convention).  Then μ̂ − b₀ is the
    light signal only and the intercept σ²_C also holds the dark shot noise A²·E_DC (noted);
``"none"``
    no dark frames: b₀ = 0, the paper's model (noted).

Exclusions (each excluded level keeps its reason in :attr:`PtcPoint.reason`; never silent)
------------------------------------------------------------------------------------------
* clipped: more than :data:`CLIP_LIMIT` (10⁻⁴) of the ROI pixel values of the level's frames are
  at 0 or at the full scale 2^bits − 1;
* zero variance (identical frames);
* user exclusions (``exclude_levels``): reason ``"excluded by user"`` (exclusion ``"user"``);
* beyond the linear range (saturation): the photon-transfer curve turns down past saturation;
  the level of largest σ̂²_N marks it (the EMVA 1288 convention), and a level of higher μ̂ whose
  σ̂²_N is below that peak by more than :data:`LINEARITY_Z` combined standard errors and by more
  than ``linearity_tolerance`` is excluded (this catches a full well that saturates below the
  ADC's full scale, where no value is clipped; a gross outlier *above* the curve at mid range
  would be taken for the peak, so check the points when many levels are excluded this way);
* beyond the linear range, when the light level is known (every level has an EMVA ``photons``
  count, or every level has its own exposure time): μ̂ is fitted by a least-squares line in that
  quantity over the lower half of the levels; a level above them whose μ̂ deviates from the line
  by more than ``linearity_tolerance`` (default 5 %) of its fitted signal is excluded.  Otherwise
  (light level unknown, e.g. neutral-density filters at one exposure) a level whose μ̂ lies in the
  top 10 % of the levels' μ̂ range is excluded when its σ̂²_N is more than :data:`LINEARITY_Z` (5)
  standard deviations *and* more than ``linearity_tolerance`` away from the line fitted to the
  levels below that top 10 % (the linearity rules see only the levels the earlier rules kept);
* outside the fit range (``fit_fraction``; the EMVA 1288 range is 0–70 % of the saturation
  signal, that of the level of largest σ̂²_N): a level above the fraction of it;
* robust mode: after the fit, the level with the largest |residual|/σ is dropped when that exceeds
  :data:`ROBUST_Z` (3), and the fit is repeated, as long as at least three levels remain.

Public objects
--------------
PtcPoint, LineFit, PhotonTransfer
    Frozen results: one light level; the weighted line; the photon-transfer result.
PtcPointSummary, PhotonTransferSummary
    The records a calibration product stores of a level and of the result
    (:meth:`PhotonTransfer.summary`; back with :meth:`PhotonTransfer.from_summary`), with their
    displayable ``rows()``.
photon_transfer(session_or_path, ...)
    Measure every PTC level of a session and fit the noise model.
ptc_points(session, ...)
    Only measure the levels (one pass over the frames).
fit_points(points, ...)
    Apply exclusions and fit already measured levels (no frame is read again).
pair_statistics(d1, d2)
    μ̂, σ̂²_N, var[σ̂²_N] and M for one pair (eqs. 37, 38, 40).
weighted_line_fit(mu, var, var_var)
    The closed-form weighted line, its covariance, χ², degrees of freedom and Q (eqs. 59–67).
goodness_of_fit(chi2, dof)
    Q (eq. 67).
CLIP_LIMIT, LINEARITY_Z, LINEARITY_TOLERANCE, ROBUST_Z, QUANTISATION_STEP
    The thresholds of the exclusion rules and q.

PtcPoint, LineFit, the two summaries, weighted_line_fit, goodness_of_fit, CLIP_LIMIT and
LINEARITY_Z are defined in :mod:`ccdcore.ptc_fit`, with the exclusion rules, and re-exported
here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from os import PathLike
from typing import Any, Callable, Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from .common import check_roi, crop, float_or_nan, json_safe
from .errors import CcdError
from .ptc_fit import (CLIP_LIMIT, LINEARITY_Z, LineFit, PhotonTransferSummary, PtcPoint,
                      PtcPointSummary, data_reason, goodness_of_fit, linearity_reasons,
                      range_reasons, saturation_reasons, weighted_line_fit)
from .reduce import STREAMED, Reducer, stand_in
from .session import FrameRecord, Session, open_session
from .stats import pair_statistics

__all__ = ["PtcPoint", "LineFit", "PhotonTransfer", "PtcPointSummary", "PhotonTransferSummary",
           "photon_transfer", "ptc_points", "fit_points", "pair_statistics", "weighted_line_fit",
           "goodness_of_fit", "CLIP_LIMIT", "LINEARITY_Z", "LINEARITY_TOLERANCE", "ROBUST_Z",
           "QUANTISATION_STEP", "EXCLUSIONS", "USER_EXCLUDED", "EMVA_FIT_FRACTION"]

#: default relative deviation from linearity tolerated (μ̂ vs light, or σ̂²_N vs the line)
LINEARITY_TOLERANCE = 0.05
#: robust mode drops a level whose |residual| / σ exceeds this
ROBUST_Z = 3.0
#: quantisation step q of integer data, DN (eq. 4)
QUANTISATION_STEP = 1.0


#: the kinds of photon-transfer exclusion (:attr:`PtcPoint.exclusion`), each with its rule in the
#: module docstring: clipped pixels, zero variance, excluded by the user, past saturation,
#: beyond the linear range, dropped by the robust mode
EXCLUSIONS: tuple[str, ...] = ("clipped", "zero-variance", "user", "saturation", "nonlinear",
                               "range", "robust")
#: the EMVA 1288 fit range of the gain: the points up to this fraction of the saturation signal
#: (release 3.1 sec. 6.6: "0 - 70 %"); ``fit_fraction=EMVA_FIT_FRACTION`` applies it
EMVA_FIT_FRACTION = 0.70
#: the reason text of a level the user excluded
USER_EXCLUDED = "excluded by user"


# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PhotonTransfer:
    """The photon-transfer result: noise model, its uncertainty, the points and diagnostics.

    Attributes
    ----------
    A, A_err
        Gain in DN per electron (slope of eq. 41) and its standard error.
    sigma_c2, sigma_c2_err
        σ²_C = A²σ²_R + q²/12 (eq. 27), DN², and its standard error.
    cov
        Covariance of (A, σ²_C) (eq. 66).
    chi2, dof, Q, verdict
        χ² (eq. 42), P − 2 degrees of freedom, goodness of fit Q (eq. 67) and its plain reading:
        ``"model rejected"`` (Q < 0.001), ``"poor"`` (Q < 0.05), ``"acceptable"``, or
        ``"untested (no degrees of freedom)"``.
    points
        Every level, used or not (with the reason).
    conversion_gain_e_per_dn, conversion_gain_e_per_dn_err
        1/A, electrons per DN.
    read_noise_e, read_noise_e_err
        σ_R = √(σ²_C − q²/12)/A (eq. 27), electrons (NaN when σ²_C < q²/12), with the error
        propagated from ``cov``.
    read_noise_dn, read_noise_dn_err
        A·σ_R = √(σ²_C − q²/12), DN, with the error σ(σ²_C)/(2·A·σ_R) from ``cov``.
    quantisation_dn2
        q²/12, DN².
    black_level_dn, black_level_source
        b₀ and the rule that gave it (see the module docstring).
    roi, bits
        The region (x, y, w, h) or ``None`` for the whole frame; the ADC bit depth.
    robust_dropped
        Levels dropped by the robust mode, in the order dropped.
    notes
        Plain-language remarks (black-level rule, exclusions, unpaired frames ...): those of the
        measurement (:attr:`measure_notes`) first, then those of the fit.
    source
        The session the points came from, when known.
    measure_notes
        The remarks of the measurement alone (kept by :meth:`refit`).
    """

    A: float
    A_err: float
    sigma_c2: float
    sigma_c2_err: float
    cov: np.ndarray
    chi2: float
    dof: int
    Q: float
    points: tuple[PtcPoint, ...]
    conversion_gain_e_per_dn: float
    conversion_gain_e_per_dn_err: float
    read_noise_e: float
    read_noise_e_err: float
    read_noise_dn: float
    read_noise_dn_err: float
    quantisation_dn2: float
    black_level_dn: float
    black_level_source: str
    roi: tuple[int, int, int, int] | None
    bits: int | None
    robust_dropped: tuple[int, ...]
    notes: tuple[str, ...]
    verdict: str
    linearity_tolerance: float = LINEARITY_TOLERANCE
    source: str | None = None
    measure_notes: tuple[str, ...] = ()
    fit_fraction: float | None = None

    @property
    def fit_range(self) -> str:
        """The fit range in words: every level below saturation, or the EMVA 1288 range."""
        if self.fit_fraction is None:
            return "every level below saturation (the paper's range)"
        return (f"the levels up to {100 * self.fit_fraction:g} % of the saturation signal "
                "(the EMVA 1288 range)")

    @property
    def fit(self) -> LineFit:
        """The fitted line as a :class:`LineFit` (for :meth:`LineFit.predict`)."""
        return LineFit(self.A, self.sigma_c2, self.cov, self.chi2, self.dof, self.Q)

    def sigma_n2(self, mu: ArrayLike) -> np.ndarray | float:
        """σ²_N = A·μ + σ²_C (eq. 41) at black-level-corrected means ``mu`` (DN)."""
        m = np.asarray(mu, dtype=np.float64)
        out = self.A * m + self.sigma_c2
        return float(out) if out.ndim == 0 else out

    def worst_levels(self, n: int = 2) -> list[tuple[int, float]]:
        """The ``n`` used levels farthest off the line, as ``(level, residual / σ)``, largest
        |residual| first: where to look when the fit is poor (Q small)."""
        z = [(p.level, (p.var - (self.A * p.mu + self.sigma_c2)) / p.var_err)
             for p in self.points if p.used and p.var_err > 0]
        return sorted(z, key=lambda lz: -abs(lz[1]))[:max(0, int(n))]

    def refit(self, *, exclude_levels: Iterable[int] = (), robust: bool = False,
              linearity_tolerance: float | None = None,
              fit_fraction: float | None | str = "same") -> PhotonTransfer:
        """Fit the same points again with other exclusions (no frame is read); ``fit_fraction``
        ``"same"`` keeps this fit's range."""
        return fit_points(self.points, exclude_levels=exclude_levels, robust=robust,
                          bits=self.bits, black_level_dn=self.black_level_dn,
                          black_level_source=self.black_level_source, roi=self.roi,
                          notes=self.measure_notes,
                          linearity_tolerance=(self.linearity_tolerance
                                               if linearity_tolerance is None
                                               else linearity_tolerance),
                          source=self.source,
                          fit_fraction=(self.fit_fraction if fit_fraction == "same"
                                        else fit_fraction))

    def summary(self) -> PhotonTransferSummary:
        """The result as the record a product stores (``estimates["noise"]``): plain numbers,
        NaN as ``None``, the points as :class:`PtcPointSummary`."""
        return PhotonTransferSummary(
            A=json_safe(self.A), A_err=json_safe(self.A_err), sigma_c2=json_safe(self.sigma_c2),
            sigma_c2_err=json_safe(self.sigma_c2_err),
            cov=tuple(tuple(json_safe(v) for v in row) for row in self.cov.tolist()),
            chi2=json_safe(self.chi2), dof=json_safe(self.dof), Q=json_safe(self.Q),
            verdict=self.verdict, points=tuple(p.summary() for p in self.points),
            conversion_gain_e_per_dn=json_safe(self.conversion_gain_e_per_dn),
            conversion_gain_e_per_dn_err=json_safe(self.conversion_gain_e_per_dn_err),
            read_noise_e=json_safe(self.read_noise_e),
            read_noise_e_err=json_safe(self.read_noise_e_err),
            read_noise_dn=json_safe(self.read_noise_dn),
            read_noise_dn_err=json_safe(self.read_noise_dn_err),
            quantisation_dn2=json_safe(self.quantisation_dn2),
            black_level_dn=json_safe(self.black_level_dn),
            black_level_source=self.black_level_source,
            roi=None if self.roi is None else tuple(json_safe(v) for v in self.roi),
            bits=json_safe(self.bits), robust_dropped=tuple(json_safe(self.robust_dropped)),
            notes=tuple(self.notes), linearity_tolerance=json_safe(self.linearity_tolerance),
            source=self.source, fit_fraction=json_safe(self.fit_fraction),
            fit_range=self.fit_range)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly values (NaN becomes ``None``): :meth:`summary` as its JSON object; the
        keys of the ``ptc`` verb in docs/cli.md (``A``, ``sigma_c2``, ``cov``, ``chi2``,
        ``dof``, ``Q``, ``points``, ``conversion_gain_e_per_dn``, ``read_noise_e``) plus errors
        and diagnostics."""
        return self.summary().to_dict()

    @classmethod
    def from_summary(cls, s: PhotonTransferSummary) -> PhotonTransfer:
        """The result a product stored (``estimates.noise``), e.g. to draw its plots: the
        inverse of :meth:`summary` (``None`` written for NaN is NaN again, the points are
        :meth:`PtcPoint.from_summary`), so ``PhotonTransfer.from_summary(s).summary() == s``.

        The product does not keep which notes the measurement made: :attr:`measure_notes` is
        empty, and :meth:`refit` of the result gives only the notes of the fit."""
        return cls(
            A=float_or_nan(s.A), A_err=float_or_nan(s.A_err), sigma_c2=float_or_nan(s.sigma_c2),
            sigma_c2_err=float_or_nan(s.sigma_c2_err),
            cov=np.array([[float_or_nan(v) for v in row] for row in s.cov], np.float64),
            chi2=float_or_nan(s.chi2), dof=int(s.dof), Q=float_or_nan(s.Q),
            points=tuple(PtcPoint.from_summary(p) for p in s.points),
            conversion_gain_e_per_dn=float_or_nan(s.conversion_gain_e_per_dn),
            conversion_gain_e_per_dn_err=float_or_nan(s.conversion_gain_e_per_dn_err),
            read_noise_e=float_or_nan(s.read_noise_e), read_noise_e_err=float_or_nan(s.read_noise_e_err),
            read_noise_dn=float_or_nan(s.read_noise_dn), read_noise_dn_err=float_or_nan(s.read_noise_dn_err),
            quantisation_dn2=float_or_nan(s.quantisation_dn2), black_level_dn=float_or_nan(s.black_level_dn),
            black_level_source=s.black_level_source,
            roi=None if s.roi is None else tuple(int(v) for v in s.roi), bits=s.bits,
            robust_dropped=tuple(s.robust_dropped), notes=tuple(s.notes), verdict=s.verdict,
            linearity_tolerance=float_or_nan(s.linearity_tolerance), source=s.source,
            fit_fraction=s.fit_fraction)


# --------------------------------------------------------------------------------------------
# reading a session
# --------------------------------------------------------------------------------------------
def _as_session(session_or_path: Session | str | PathLike) -> Session:
    if isinstance(session_or_path, Session):
        return session_or_path
    return open_session(session_or_path)


def _same(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return a is b
    return math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-12)


def _check_level_metadata(session: Session, level: int, recs: Sequence[FrameRecord]) -> None:
    """Frames of one level must share their exposure time and photon count."""
    where = f"{session.label}: ptc level {level}"
    for key, unit in (("exposure", " s"), ("photons", " photons")):
        first = recs[0]
        for rec in recs[1:]:
            a, b = getattr(first, key), getattr(rec, key)
            if (a is None) != (b is None) or not _same(a, b):
                raise CcdError(where, f"mismatched {'exposure times' if key == 'exposure' else key}"
                                      f": {first.relpath} ({a}{unit if a is not None else ''}) "
                                      f"and {rec.relpath} ({b}{unit if b is not None else ''}); "
                                      "frames of one level must be captured at the same light "
                                      "level and exposure")


def _bits(session: Session, rec: FrameRecord) -> int | None:
    if session.camera.bits is not None:
        return int(session.camera.bits)
    hdr = session.header(rec)
    return int(hdr.bits) if hdr.dtype.kind in "ui" else None


def _require_mono(rec: FrameRecord, shape: tuple[int, ...]) -> None:
    if len(shape) != 2:
        raise CcdError(rec.relpath, f"colour frames ({'x'.join(map(str, shape))}): photon "
                                    "transfer reads mono (or raw CFA) frames; per channel support "
                                    "comes with the flat-field work")


def _checked_pixels(rec: FrameRecord, frame: np.ndarray,
                    roi: tuple[int, int, int, int] | None) -> np.ndarray:
    _require_mono(rec, frame.shape)
    pix = crop(frame, roi)
    if pix.dtype.kind == "f":
        bad = int(np.count_nonzero(~np.isfinite(pix)))
        if bad:
            raise _nonfinite(roi)(rec.relpath, bad)
    return pix


def _dark_black_level(session: Session, roi: tuple[int, int, int, int] | None,
                      reducer: Reducer) -> tuple[float, str, tuple[str, ...]]:
    """b₀ from the dark frames (rules ``dark_extrapolated`` / ``dark_mean`` / ``none``)."""
    darks = session.dark_frames()
    if not darks:
        return 0.0, "none", ("no black level given and no dark frames: b0 = 0, the paper's model "
                             "(eq. 20); an electronic offset would then be counted as signal",)
    # one scalar sum per exposure (not a frame-sized accumulator: a set may have 100 exposures)
    sums: dict[float | None, float] = {}
    counts: dict[float | None, int] = {}
    frames: dict[float | None, int] = {}
    sums_of = reducer.frame_sums(session, darks, pixels=lambda r, f: _checked_pixels(r, f, roi),
                                 header_pixels=lambda r: _header_pixels(session, r, roi),
                                 roi=roi, nonfinite=_nonfinite(roi))
    for rec, (total, size) in sums_of:
        t = rec.exposure
        sums[t] = sums.get(t, 0.0) + total
        counts[t] = counts.get(t, 0) + size
        frames[t] = frames.get(t, 0) + 1
    means = {t: sums[t] / counts[t] for t in sums}
    timed = {t: m for t, m in means.items() if t is not None}
    if len(timed) >= 2:
        t = np.array(sorted(timed))
        m = np.array([timed[k] for k in sorted(timed)])
        slope, intercept = np.polyfit(t, m, 1)
        keys = sorted(timed)
        table = (", ".join(f"{k:g} s: {timed[k]:.4g} DN" for k in keys) if len(keys) <= 4 else
                 f"{len(keys)} exposures from {keys[0]:g} to {keys[-1]:g} s, dark means "
                 f"{min(m):.4g} to {max(m):.4g} DN")
        return float(intercept), "dark_extrapolated", (
            f"black level b0 = {intercept:.4g} DN: dark mean extrapolated to zero exposure "
            f"({table}; dark signal {slope:.4g} DN/s); the dark signal stays in mu with its "
            "shot noise as in eq. 36",)
    n = sum(frames.values())
    total = sum(sums.values()) / sum(counts.values())
    return total, "dark_mean", (
        f"black level b0 = {total:.4g} DN: mean of {n} dark frame{'s' if n > 1 else ''} at one "
        "exposure (EMVA 1288 convention); mu is then the light signal only and sigma_c2 also "
        "contains the dark shot noise A^2 E_DC; give [camera] black_level to separate them",)


def _measure(session: Session, roi: Sequence[int] | None, black_level: float | None,
             reducer: Reducer = STREAMED) -> tuple[tuple[PtcPoint, ...], dict[str, Any]]:
    """One pass over the PTC (and dark) frames by ``reducer``: the points and the fit
    context."""
    session.raise_if_invalid(roles=("ptc", "dark"))
    label = session.label
    levels = session.ptc_levels()
    if not levels:
        raise CcdError(label, "no ptc frames: photon transfer needs two or more frames "
                              "(role = \"ptc\", level = N) at each of three or more light levels")
    first = next(iter(levels.values()))[0]
    hdr = session.header(first)
    if hdr.channels != 1:
        raise CcdError(first.relpath, f"colour frames ({hdr.channels} channels): photon transfer "
                                      "reads mono (or raw CFA) frames; per channel support comes "
                                      "with the flat-field work")
    roi_t = check_roi(roi, hdr.shape, label, min_pixels=2)
    for level, recs in levels.items():
        _check_level_metadata(session, level, recs)
    bits = _bits(session, first)
    full = None if bits is None else float(2 ** bits - 1)

    notes: list[str] = []
    if black_level is not None:
        try:
            b0 = float(black_level)
        except (TypeError, ValueError):
            b0 = float("nan")
        if isinstance(black_level, bool) or not math.isfinite(b0):
            raise CcdError("black_level", f"must be a finite number (DN), got {black_level!r}")
        source = "argument"
        notes.append(f"black level b0 = {b0:g} DN given as an argument")
    elif session.camera.black_level is not None:
        b0, source = float(session.camera.black_level), "camera"
        notes.append(f"black level b0 = {b0:g} DN from the manifest ([camera] black_level)")
    else:
        b0, source, more = _dark_black_level(session, roi_t, reducer)
        notes.extend(more)

    points = []
    paired = {level: recs[:2 * (len(recs) // 2)] for level, recs in levels.items()}
    measured = reducer.pair_stats(session, paired,
                                  pixels=lambda r, f: _checked_pixels(r, f, roi_t),
                                  header_pixels=lambda r: _header_pixels(session, r, roi_t),
                                  roi=roi_t, full=full, nonfinite=_nonfinite(roi_t))
    for level, recs in levels.items():
        n_pairs = len(recs) // 2
        if len(recs) % 2:
            notes.append(f"ptc level {level}: {len(recs)} frames, the last one "
                         f"({recs[-1].relpath}) has no partner and is not used")
        mus, vars_, clipped, count, m = next(measured)
        mu_raw = float(np.mean(mus))
        var = float(np.mean(vars_))
        # eq. 40 for the mean of n_pairs independent estimates, evaluated at their average
        var_err = math.sqrt(2.0 * var * var / (n_pairs * (m - 1)))
        pt = PtcPoint(level=int(level), mu=mu_raw - b0, var=var, var_err=var_err,
                      n_pairs=n_pairs, n_pixels=m, used=True, reason=None,
                      exposure=recs[0].exposure, mu_raw=mu_raw,
                      clipped_fraction=clipped / count if count else 0.0,
                      photons=recs[0].photons)
        why = data_reason(pt, bits)
        points.append(replace(pt, used=why is None, exclusion=why and why[0],
                              reason=why and why[1]))
    context = {"bits": bits, "black_level_dn": b0, "black_level_source": source,
               "roi": roi_t, "notes": tuple(notes), "source": label}
    return tuple(points), context


def _header_pixels(session: Session, rec: FrameRecord,
                   roi: tuple[int, int, int, int] | None) -> np.ndarray:
    """A zero-memory stand-in for ``_checked_pixels(rec, frame, roi)`` built from the header:
    the same colour-frame error, and the ROI's shape and dtype."""
    hdr = session.header(rec)
    _require_mono(rec, hdr.shape)
    return crop(stand_in(hdr), roi)


def _nonfinite(roi: Sequence[int] | None) -> Callable[[str, int], CcdError]:
    """The error of a frame with ``bad`` NaN or infinite values (in the ROI when given)."""
    def error(name: str, bad: int) -> CcdError:
        return CcdError(name, f"{bad} NaN or infinite pixel value{'s' if bad > 1 else ''}"
                              f" in the {'ROI' if roi else 'frame'}; photon transfer "
                              "needs finite pixel values")
    return error


def ptc_points(session: Session | str | PathLike, *, roi: Sequence[int] | None = None,
               black_level: float | None = None) -> tuple[PtcPoint, ...]:
    """Measure every PTC level of a session (eqs. 37, 38, 40), without fitting.

    One streamed pass over the frames (two frames in memory at a time).  Levels with more than two
    frames use every disjoint pair (frames 0-1, 2-3, ...).  Clipped levels come back with
    ``used=False`` and their reason; :func:`fit_points` applies the other exclusions.  See
    :func:`photon_transfer` for the parameters and errors.
    """
    return _measure(_as_session(session), roi, black_level)[0]


# --------------------------------------------------------------------------------------------
# exclusions and the fit
# --------------------------------------------------------------------------------------------
def _verdict(q: float) -> str:
    if not math.isfinite(q):
        return "untested (no degrees of freedom)"
    if q < 0.001:
        return "model rejected"
    if q < 0.05:
        return "poor"
    return "acceptable"


def fit_points(points: Sequence[PtcPoint], *, exclude_levels: Iterable[int] = (),
               robust: bool = False, bits: int | None = None,
               black_level_dn: float | None = None, black_level_source: str = "given",
               roi: Sequence[int] | None = None, notes: Sequence[str] = (),
               linearity_tolerance: float = LINEARITY_TOLERANCE,
               source: str | None = None, fit_fraction: float | None = None) -> PhotonTransfer:
    """Apply the exclusion rules to measured levels and fit σ²_N = A·μ + σ²_C (eqs. 41, 59–67).

    Each point's ``used``/``reason`` is recomputed from scratch (clipping and zero variance from
    its data, then ``exclude_levels``, the linearity rule and the robust mode), so the app can
    toggle levels and refit at once without reading frames.

    The steps, each a function: the exclusions of the data and the user
    (:func:`_data_exclusions`), the linearity rules (:func:`_linearity_exclusions`), the
    weighted fit with the robust mode (:func:`_weighted_fit`) and the result
    (:func:`_result`).

    Parameters
    ----------
    points
        Levels from :func:`ptc_points` (or a previous result's ``points``).
    exclude_levels
        Level ids to leave out (exclusion ``"user"``, reason ``"excluded by user"``).
    robust
        Drop, one at a time, the level with the largest |residual|/σ while it exceeds 3, keeping
        at least three levels; :attr:`PhotonTransfer.robust_dropped` lists them in order.
    bits
        ADC bit depth (for the clipping message and the result).
    black_level_dn, black_level_source
        b₀ and its rule, for the result; b₀ defaults to ``mu_raw − mu`` of the points.
    roi, notes, source
        Carried into the result (``notes`` first, then the fit's own notes).
    linearity_tolerance
        Relative deviation tolerated by the linearity rule (module docstring).
    fit_fraction
        ``None`` (the paper's range: every level below saturation) or a fraction of the
        saturation signal above which levels are left out (exclusion ``"range"``): the EMVA 1288
        range is :data:`EMVA_FIT_FRACTION` = 0.7 (release 3.1 sec. 6.6). The saturation signal
        is that of the level of largest σ̂²_N. The result says which range it used
        (:attr:`PhotonTransfer.fit_range`).

    Raises
    ------
    CcdError
        Fewer than three usable levels (the message says why the others were excluded).
    """
    pts = list(points)
    if not pts:
        raise CcdError("photon transfer", "no ptc levels to fit")
    if not (linearity_tolerance > 0):
        raise CcdError("linearity_tolerance", f"must be > 0, got {linearity_tolerance!r}")
    reasons = _data_exclusions(pts, exclude_levels, bits)
    _linearity_exclusions(pts, reasons, bits, float(linearity_tolerance), fit_fraction)
    fit, dropped = _weighted_fit(pts, reasons, robust, source)
    return _result(pts, reasons, fit, dropped, bits=bits, black_level_dn=black_level_dn,
                   black_level_source=black_level_source, roi=roi, notes=notes,
                   linearity_tolerance=linearity_tolerance, source=source,
                   fit_fraction=fit_fraction)


def _data_exclusions(pts: list[PtcPoint], exclude_levels: Iterable[int],
                     bits: int | None) -> dict[int, tuple[str, str]]:
    """Level -> (exclusion code, reason) of the levels whose data cannot be used (clipping, zero
    variance) and of those the user excludes; an unknown level in ``exclude_levels`` is an
    error."""
    known = {p.level for p in pts}
    user = set()
    for lv in exclude_levels:
        if lv not in known:
            raise CcdError("exclude_levels", f"no ptc level {lv!r} (levels: "
                                             f"{', '.join(map(str, sorted(known)))})")
        user.add(lv)
    reasons: dict[int, tuple[str, str]] = {}   # level -> (exclusion code, reason)
    for p in pts:
        why = data_reason(p, bits)
        if why is not None:
            reasons[p.level] = why
        elif p.level in user:
            reasons[p.level] = "user", USER_EXCLUDED
    return reasons


def _linearity_exclusions(pts: list[PtcPoint], reasons: dict[int, tuple[str, str]],
                          bits: int | None, tol: float, fit_fraction: float | None) -> None:
    """Add to ``reasons`` the levels past saturation, beyond the linear range and (with
    ``fit_fraction``) outside the fit range, each rule seeing the levels the earlier ones
    kept (the range rule: every level with usable data)."""
    candidates = [p for p in pts if p.level not in reasons]
    reasons.update(saturation_reasons(candidates, tol))
    candidates = [p for p in pts if p.level not in reasons]
    reasons.update(linearity_reasons(candidates, tol))
    if fit_fraction is not None:
        if not 0.0 < fit_fraction <= 1.0:
            raise CcdError("fit_fraction", f"must be in (0, 1], got {fit_fraction!r}")
        reasons.update(range_reasons([p for p in pts if data_reason(p, bits) is None],
                                     reasons, float(fit_fraction)))


def _weighted_fit(pts: list[PtcPoint], reasons: dict[int, tuple[str, str]], robust: bool,
                  source: str | None) -> tuple[LineFit, list[int]]:
    """The weighted line (eqs. 59–67) through the levels not in ``reasons`` and, in robust mode,
    the levels dropped one at a time (added to ``reasons``); fewer than three usable levels is
    an error naming why the others were excluded."""
    def usable() -> list[PtcPoint]:
        return [p for p in pts if p.level not in reasons]

    def too_few(used: list[PtcPoint]) -> CcdError:
        why = "; ".join(f"level {lv}: {r}" for lv, (_, r) in reasons.items())
        return CcdError(source or "photon transfer",
                        f"{len(used)} usable ptc level{'s' if len(used) != 1 else ''} "
                        f"({', '.join(str(p.level) for p in used) or 'none'}) of {len(pts)}; "
                        f"need at least 3" + (f" ({why})" if why else ""))

    used = usable()
    if len(used) < 3:
        raise too_few(used)

    def fit_of(ps: list[PtcPoint]) -> LineFit:
        return weighted_line_fit([p.mu for p in ps], [p.var for p in ps],
                                 [p.var_err ** 2 for p in ps])

    fit = fit_of(used)
    dropped: list[int] = []
    if robust:
        while len(used) > 3:
            r = [abs(p.var - (fit.A * p.mu + fit.sigma_c2)) / p.var_err for p in used]
            worst = int(np.argmax(r))
            if r[worst] <= ROBUST_Z:
                break
            lv = used[worst].level
            reasons[lv] = "robust", f"robust mode: residual {r[worst]:.1f} sigma > {ROBUST_Z:g}"
            dropped.append(lv)
            used = usable()
            fit = fit_of(used)
    return fit, dropped


def _result(pts: list[PtcPoint], reasons: dict[int, tuple[str, str]], fit: LineFit,
            dropped: list[int], *, bits: int | None, black_level_dn: float | None,
            black_level_source: str, roi: Sequence[int] | None, notes: Sequence[str],
            linearity_tolerance: float, source: str | None,
            fit_fraction: float | None) -> PhotonTransfer:
    """The :class:`PhotonTransfer` of a fit: the points with their exclusions, the errors of A
    and σ²_C, the conversion gain and the read noise (eq. 27) with their errors, and the
    notes."""
    b0 = (float(np.median([p.mu_raw - p.mu for p in pts])) if black_level_dn is None
          else float(black_level_dn))
    out_points = tuple(replace(p, used=p.level not in reasons,
                               exclusion=reasons[p.level][0] if p.level in reasons else None,
                               reason=reasons[p.level][1] if p.level in reasons else None)
                       for p in pts)
    q2 = QUANTISATION_STEP ** 2 / 12.0
    a, c, cov = fit.A, fit.sigma_c2, fit.cov
    a_err, c_err = math.sqrt(max(cov[0, 0], 0.0)), math.sqrt(max(cov[1, 1], 0.0))
    all_notes = list(notes) + _exclusion_notes(out_points)
    if a > 0:
        gain, gain_err = 1.0 / a, a_err / (a * a)
    else:
        gain, gain_err = float("nan"), float("nan")
        all_notes.append(f"fit: slope A = {a:.4g} is not positive; no conversion "
                         "gain or read noise in electrons")
    rn_dn = math.sqrt(c - q2) if c > q2 else float("nan")
    rn_dn_err = c_err / (2.0 * rn_dn) if c > q2 else float("nan")   # d√(σ²_C − q²/12)/dσ²_C
    if a > 0 and c > q2:
        rn_e = rn_dn / a
        jac = np.array([-rn_e / a, 1.0 / (2.0 * a * rn_dn)])  # d sigma_R / d(A, sigma_c2), eq. 27
        rn_err = math.sqrt(max(float(jac @ cov @ jac), 0.0))
    else:
        rn_e = rn_err = float("nan")
        if c <= q2:
            all_notes.append(f"fit: sigma_c2 = {c:.4g} DN² is not above q²/12 = "
                             f"{q2:.4g} DN²: the read noise is not resolved")
    return PhotonTransfer(
        A=a, A_err=a_err, sigma_c2=c, sigma_c2_err=c_err, cov=cov, chi2=fit.chi2, dof=fit.dof,
        Q=fit.Q, points=out_points, conversion_gain_e_per_dn=gain,
        conversion_gain_e_per_dn_err=gain_err, read_noise_e=rn_e, read_noise_e_err=rn_err,
        read_noise_dn=rn_dn, read_noise_dn_err=rn_dn_err, quantisation_dn2=q2, black_level_dn=b0,
        black_level_source=black_level_source,
        roi=None if roi is None else tuple(int(v) for v in roi), bits=bits,
        robust_dropped=tuple(dropped), notes=tuple(all_notes), verdict=_verdict(fit.Q),
        linearity_tolerance=float(linearity_tolerance), source=source,
        measure_notes=tuple(notes), fit_fraction=None if fit_fraction is None
        else float(fit_fraction))


def _exclusion_notes(points: Sequence[PtcPoint], limit: int = 5) -> list[str]:
    """One note per level not used; beyond ``limit`` levels, one note per kind of exclusion
    (count, range of levels, the first reason), so a 100-level set stays readable."""
    out = [p for p in points if not p.used]
    if len(out) <= limit:
        return [f"level {p.level} not used: {p.reason}" for p in out]
    notes = []
    for code in dict.fromkeys(p.exclusion for p in out):
        same = [p for p in out if p.exclusion == code]
        levels = (", ".join(str(p.level) for p in same) if len(same) <= 4
                  else f"{same[0].level} … {same[-1].level}")
        notes.append(f"{len(same)} level{'s' if len(same) > 1 else ''} not used ({code}: "
                     f"{levels}); e.g. level {same[0].level}: {same[0].reason}")
    return notes


def photon_transfer(session_or_path: Session | str | PathLike, *,
                    roi: Sequence[int] | None = None, robust: bool = False,
                    exclude_levels: Iterable[int] = (), black_level: float | None = None,
                    linearity_tolerance: float = LINEARITY_TOLERANCE,
                    reducer: Reducer | None = None, fit_fraction: float | None = None
                    ) -> PhotonTransfer:
    """Estimate the noise model σ²_N = A·(μ − b₀) + σ²_C of a camera from its PTC frames.

    For each light level: μ̂ (eq. 37), σ̂²_N from the difference image (eq. 38) and
    var[σ̂²_N] (eq. 40), over the frame or ``roi``, averaged over the level's disjoint pairs; then
    the exclusions and the weighted fit of :func:`fit_points` (eqs. 59–67).

    Parameters
    ----------
    session_or_path : Session or str or PathLike
        A :class:`~ccdcore.session.Session` or anything :func:`~ccdcore.session.open_session`
        opens.
    roi : sequence of int or None, optional
        ``(x, y, w, h)`` in pixels; default the whole frame.
    robust : bool, optional
        Robust mode (drop levels beyond 3 sigma one at a time, reported).
    exclude_levels : iterable of int, optional
        Level ids to leave out.
    black_level : float or None, optional
        b₀ in DN; overrides the manifest and the dark frames (module docstring).
    linearity_tolerance : float, optional
        Relative deviation from linearity tolerated (module docstring).
    reducer : Reducer or None, optional
        Runs the reductions over frames (:mod:`ccdcore.reduce`; default streamed here). On a
        Dask cluster (:class:`ccdcore.distributed.client.DaskReducer`) the pairs and the dark sums
        of the black level are reduced in bands of rows, each worker reading its band of every
        frame: μ̂ (eq. 37) and the clipped fractions are identical for integer data; σ̂²_N
        (eq. 38), merged over the bands, agrees to a relative 1e-12
        (:data:`ccdcore.distributed.client.PTC_RTOL`), and so do A, σ²_C and their errors.
    fit_fraction : float or None, optional
        The fit range (:func:`fit_points`): ``None`` every level below saturation, 0.7 the
        EMVA 1288 range.

    Returns
    -------
    PhotonTransfer
        The noise model: A and σ²_C with their standard errors and covariance, χ² and Q with
        their verdict, every level's point (used or not, with the reason) and diagnostics.

    Raises
    ------
    CcdError
        No ptc frames; a session error concerning the PTC or dark frames; colour frames; an ROI
        outside the frame; frames of one level with different exposure times (or photon counts);
        NaN or infinite pixels; fewer than three usable levels; a ``black_level`` that is not a
        finite number, a ``linearity_tolerance`` not above 0, a ``fit_fraction`` outside (0, 1]
        or a level of ``exclude_levels`` the session does not have; a path that
        :func:`~ccdcore.session.open_session` refuses.

    Examples
    --------
    >>> import tempfile
    >>> from ccdcore.simulate import simulate
    >>> tmp = tempfile.TemporaryDirectory()
    >>> truth = simulate("healey94", tmp.name, seed=1, size=(64, 48))
    >>> ptc = photon_transfer(tmp.name)
    >>> abs(ptc.A - truth["A"]) < 3 * ptc.A_err      # eq. 37's A within its stated error
    True
    >>> tmp.cleanup()
    """
    session = _as_session(session_or_path)
    points, ctx = _measure(session, roi, black_level, reducer or STREAMED)
    return fit_points(points, exclude_levels=exclude_levels, robust=robust,
                      linearity_tolerance=linearity_tolerance, fit_fraction=fit_fraction, **ctx)
