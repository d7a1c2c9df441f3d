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

The results and the constants are in :mod:`ccdcore.emva.results`, the computation of each figure
in :mod:`ccdcore.emva.fits`; both are re-exported here.
"""
from __future__ import annotations

import math
from contextlib import closing
from dataclasses import dataclass, replace
from os import PathLike
from typing import Any, Sequence

import numpy as np

from .dark import dark_current
from .fits import (Curves, DarkNoise, PtcReadNoise, Sensitivity, dark_at, dark_noise,
                        exposure_text, linearity, nonuniformity, ptc_read_noise, same_exposure,
                        sensitivity, spatial_section, threshold_and_range)
from .results import (DISAGREEMENT_Z, LINEARITY_RANGE, QUANTISATION_LIMIT_DN,
                           QUANTISATION_VARIANCE, SENSITIVITY_FRACTION, SIGMA2_Y_DARK_FLOOR,
                           DarkPoint, EmvaFigures, EmvaPoint, SpatialSet)
from ..errors import CcdError
from ..noise import PhotonTransfer
from ..reduce import READ_AHEAD
from ..progress import Progress, Steps
from ..session import FrameRecord, Session, open_session

__all__ = ["EmvaFigures", "EmvaPoint", "DarkPoint", "SpatialSet", "emva_figures",
           "with_photon_transfer", "EMVA_STEPS",
           "QUANTISATION_VARIANCE", "SIGMA2_Y_DARK_FLOOR", "SENSITIVITY_FRACTION",
           "LINEARITY_RANGE", "DISAGREEMENT_Z", "QUANTISATION_LIMIT_DN"]

#: the steps :func:`emva_figures` reports (name, overall fraction at which it starts)
EMVA_STEPS: tuple[tuple[str, float], ...] = (
    ("EMVA 1288 points", 0.0), ("photon transfer", 0.8), ("done", 1.0))

_MISSING_PHOTONS = ("no photon counts: the EMVA 1288 figures need the photons per pixel of each "
                    "bright frame (EMVA1288 descriptors carry them)")


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
def _dark_runs(session: Session) -> list[tuple[FrameRecord, ...]]:
    """Consecutive dark frames of one exposure, in session order: the dark points of a
    descriptor (each ``d`` line's images)."""
    runs: list[tuple[FrameRecord, ...]] = []
    cur: list[FrameRecord] = []
    for rec in session.frames:
        if rec.role == "dark" and cur and same_exposure(cur[-1].exposure, rec.exposure):
            cur.append(rec)
            continue
        if cur:
            runs.append(tuple(cur))
        cur = [rec] if rec.role == "dark" else []
    if cur:
        runs.append(tuple(cur))
    return runs


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
        pairs = [r for r in runs if len(r) == 2 and same_exposure(r[0].exposure, t)]
        longer = [r for r in runs if len(r) > 2 and same_exposure(r[0].exposure, t)]
        if pairs:
            darks.append((t, pairs[0]))
            if len(pairs) > 1:
                notes.append(f"{len(pairs)} dark points of two frames at {exposure_text(t)}; "
                             f"the first ({pairs[0][0].relpath}, …) is used")
        elif longer:
            darks.append((t, longer[0][:2]))
            notes.append(f"no dark point of two frames at {exposure_text(t)}: its first two "
                         f"dark frames ({longer[0][0].relpath}, {longer[0][1].relpath}) serve "
                         "(the reference implementation would refuse the set)")
        else:
            have = sorted({r[0].exposure for r in runs if r[0].exposure is not None})
            raise CcdError(label, f"no dark frames at {exposure_text(t)} (bright point of ptc "
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
        sp_dark = [r for r in runs if len(r) > 2 and same_exposure(r[0].exposure, spatial[1])]
        if sp_dark:
            spatial_dark = sp_dark[0]
        else:
            notes.append(f"the spatial set (ptc level {spatial[0]}, {len(spatial[3])} frames) "
                         f"has no dark set of more than two frames at its "
                         f"{exposure_text(spatial[1])}: DSNU1288 and PRNU1288 are not computed")
            spatial = None
    else:
        notes.append("no spatial sets (a ptc level of more than two frames and as many dark "
                     "frames at its exposure, sec. 8): DSNU1288 and PRNU1288 are not computed")
    return _Plan(temporal=tuple(temporal), darks=tuple(darks), spatial=spatial,
                 spatial_dark=spatial_dark, notes=tuple(notes))


_Moments = tuple[float, float, int]   # μ_y, σ²_y, N of a pair


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
        d = dark_at(dark_points, t)
        raw.append(EmvaPoint(level=lv, exposure=t, u_p=u_p, u_y=mu,
                             u_y_err=math.sqrt(max(s2, 0.0) / (2.0 * n)), s2_y=s2,
                             s2_y_err=math.sqrt(2.0 * s2 * s2 / (n - 1)), u_y_dark=d.u_y_dark,
                             s2_y_dark=d.s2_y_dark, s2_y_dark_err=d.s2_y_dark_err, n_pixels=n))
    return dark_points, raw


# --------------------------------------------------------------------------------------------
# the figures
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Temporal:
    """The temporal points and the figures made from them before the photon transfer, with the
    statistics of the spatial sets read in the same pass."""

    stacks: dict[str, SpatialSet]
    dark_points: list[DarkPoint]
    raw: list[EmvaPoint]
    curves: Curves
    sens: Sensitivity
    dark: DarkNoise


def _temporal_figures(session: Session, plan: _Plan, label: str, notes: list[str]) -> _Temporal:
    """The points (sec. 6.6, ``Data1288``) from one streamed pass over the frames, the
    saturation point, the fit range, R, K and QE (:func:`~ccdcore.emva.fits.sensitivity`), and
    σ_y.dark, μ_y.dark and σ_d from the darks (:func:`~ccdcore.emva.fits.dark_noise`)."""
    bright_stats, dark_stats, stacks = _read(session, plan)
    dark_points, raw = _points(plan, bright_stats, dark_stats)
    c = Curves.of(raw, dark_points)
    sens = sensitivity(c, raw, label, notes)
    dark = dark_noise(dark_points, sens, notes)
    return _Temporal(stacks, dark_points, raw, c, sens, dark)


def _later_figures(t: _Temporal, label: str, notes: list[str]) -> dict[str, Any]:
    """The figures after the photon transfer, as :class:`EmvaFigures` fields: the sensitivity
    threshold, saturation capacity, SNR_max and dynamic range; the linearity; the dark current;
    DSNU1288 and PRNU1288 with their release 4.0 split and plots; the points marked with the
    fits they are in."""
    c, sens, dark = t.curves, t.sens, t.dark
    thr = threshold_and_range(c.u_p, sens, dark)
    i_lin_min, i_lin_max, lin_a, lin_b, (le_min, le_min_err), (le_max, le_max_err) = \
        linearity(c.u_p, c.Y, c.var_Y, sens.i_sat, label)
    dark_points = t.dark_points
    current = dark_current([d.exposure for d in dark_points],
                           [d.u_y_dark for d in dark_points],
                           [d.u_y_dark_err for d in dark_points],
                           [d.s2_y_dark for d in dark_points],
                           [d.s2_y_dark_err for d in dark_points], sens.K, sens.K_err)
    notes.extend(current.notes)
    dsnu = dsnu_err = prnu = prnu_err = None
    split = plots = None
    sp, spd = t.stacks.get("spatial"), t.stacks.get("spatial_dark")
    if sp is not None and spd is not None:
        dsnu, dsnu_err, prnu, prnu_err = nonuniformity(sp, spd, sens.K, sens.K_err, notes)
        split, plots = spatial_section(sp, spd, sens.K, sens.K_err, dsnu, prnu, notes)

    points = tuple(replace(p, in_sensitivity_fit=i <= sens.i_fit,
                           in_linearity_fit=i_lin_min <= i <= i_lin_max,
                           saturation=i == sens.i_sat)
                   for i, p in enumerate(t.raw))
    return dict(
        u_p_min=thr.u_p_min, u_p_min_err=thr.u_p_min_err, u_p_sat=thr.u_p_sat,
        u_p_sat_err=thr.u_p_sat_err, u_e_sat=thr.u_e_sat, u_e_sat_err=thr.u_e_sat_err,
        SNR_max=thr.SNR_max, SNR_max_err=thr.SNR_max_err, DR=thr.DR, DR_err=thr.DR_err,
        DR_dB=thr.DR_dB, DR_dB_err=thr.DR_dB_err, LE_min=le_min, LE_min_err=le_min_err,
        LE_max=le_max, LE_max_err=le_max_err, linearity_slope=lin_a, linearity_offset=lin_b,
        DSNU1288=dsnu, DSNU1288_err=dsnu_err, PRNU1288=prnu, PRNU1288_err=prnu_err,
        index_linearity_min=i_lin_min, index_linearity_max=i_lin_max, points=points,
        spatial=sp, spatial_dark=spd, dark_current=current, split=split, spatial_plots=plots)


def _assemble(t: _Temporal, ptc: PtcReadNoise, later: dict[str, Any], label: str,
              notes: list[str], ptc_notes: list[str]) -> EmvaFigures:
    """The :class:`EmvaFigures` of the sensitivity, the dark noise, the photon transfer's σ_d
    and the ``later`` fields (:func:`_later_figures`)."""
    sens, dark = t.sens, t.dark
    return EmvaFigures(
        K=sens.K, K_err=sens.K_err, R=sens.R, R_err=sens.R_err, QE=sens.QE, QE_err=sens.QE_err,
        sigma_y_dark=dark.sigma_y_dark, sigma_y_dark_err=dark.sigma_y_dark_err,
        sigma_y_dark_measured=dark.sigma_y_dark_measured, u_y_dark=dark.u_dark,
        u_y_dark_err=dark.u_dark_err, sigma_d=dark.sigma_d, sigma_d_err=dark.sigma_d_err,
        sigma_d_ptc=ptc.sigma_d, sigma_d_ptc_err=ptc.sigma_d_err, K_ptc=ptc.K, K_ptc_err=ptc.K_err,
        index_u_ysat=sens.i_sat, index_sensitivity_max=sens.i_fit,
        dark_points=tuple(t.dark_points), sigma_d_consistent=ptc.consistent,
        quantisation_limited=dark.quantisation_limited, notes=tuple(notes), source=label,
        ptc_notes=tuple(ptc_notes), **later)


def emva_figures(session: Session | str | PathLike, *, noise: PhotonTransfer | None = None,
                 progress: Progress | None = None, with_ptc: bool = True) -> EmvaFigures:
    """The EMVA 1288 (release 3.1) figures of a session whose bright frames carry photon counts.

    Parameters
    ----------
    session : Session or str or PathLike
        An EMVA1288 descriptor opened as a session, or its path (or a manifest with
        ``photons``): temporal bright points (``ptc`` levels of two frames), the two dark frames
        at each of their exposure times and, optionally, a spatial set (module docstring).
    noise : PhotonTransfer or None, optional
        Our photon-transfer result for the same session (:func:`ccdcore.noise.photon_transfer`),
        for ``sigma_d_ptc``; computed here when not given.
    progress : Progress or None, optional
        A :class:`ccdcore.progress.Progress`: ``progress(start, name)`` as each of
        :data:`EMVA_STEPS` starts.
    with_ptc : bool, optional
        When ``noise`` is not given: compute it (``True``), or leave ``sigma_d_ptc`` out
        (``False``: a caller whose photon transfer already failed).

    Returns
    -------
    EmvaFigures
        The figures of the Notes with their standard errors, the points, the spatial sets and
        notes.

    Raises
    ------
    CcdError
        The ptc frames carry no photon counts (or one not above 0, or the frames of one level
        differ in it or in exposure time); a session error touching the ptc or dark frames;
        fewer than 3 temporal bright points; no dark frames, or none at a bright point's exposure;
        colour frames, frames of different shapes, NaN or infinite pixels; every point saturated
        (no point below 70 % of the saturation signal); fewer than 2 points in the sensitivity
        fit or in the linearity range; a fitted K or R not above 0; a path that
        :func:`~ccdcore.session.open_session` refuses.

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
    * μ_p.min = (σ_y.dark/K + 1/2)/η (absolute sensitivity threshold, sec. 2.4),
      μ_e.sat = η·μ_p.sat (saturation capacity), SNR_max = √μ_e.sat (eq. 33), DR = μ_p.sat/μ_p.min
      (eq. 18) and 20·log₁₀ DR; errors by first-order propagation.  μ_p.sat is the photon count of
      one of the points, so its error is the resolution of the series: the local spacing of μ_p
      over √12 (over seeds of the generator the saturation point moves between neighbours, and
      this error matches that spread); it enters μ_e.sat, SNR_max and DR.
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

    Examples
    --------
    >>> import tempfile
    >>> from ccdcore.simulate import simulate
    >>> tmp = tempfile.TemporaryDirectory()
    >>> truth = simulate("emva1288", tmp.name, seed=1, size=(64, 48))
    >>> figures = emva_figures(tmp.name)
    >>> abs(figures.K - truth["K"]) < 3 * figures.K_err       # the overall system gain
    True
    >>> tmp.cleanup()
    """
    report = Steps(progress, EMVA_STEPS)
    if not isinstance(session, Session):
        session = open_session(session)
    session.raise_if_invalid(roles=("ptc", "dark"))
    plan = _plan(session)
    label = session.label
    notes = list(plan.notes)
    report("EMVA 1288 points")
    t = _temporal_figures(session, plan, label, notes)
    report("photon transfer")
    ptc_notes: list[str] = []
    ptc = ptc_read_noise(session, noise, with_ptc, t.dark, ptc_notes)
    notes.extend(ptc_notes)
    later = _later_figures(t, label, notes)
    report("done")
    return _assemble(t, ptc, later, label, notes, ptc_notes)


def with_photon_transfer(figures: EmvaFigures, noise: PhotonTransfer | None) -> EmvaFigures:
    """``figures`` with σ_d from the intercept of ``noise`` (``sigma_d_ptc``, ``K_ptc``, their
    agreement with the darks and its note) instead of the photon transfer they were made with;
    ``None`` leaves them out. No frame is read: a page that refits the photon transfer (other
    levels, another fit range) keeps the figures of the frames and changes only these."""
    base = [n for n in figures.notes if n not in set(figures.ptc_notes)]
    dark = DarkNoise(figures.sigma_y_dark, figures.sigma_y_dark_err,
                     figures.sigma_y_dark_measured, figures.u_y_dark, figures.u_y_dark_err,
                     figures.sigma_d, figures.sigma_d_err, figures.quantisation_limited)
    ptc_notes: list[str] = []
    ptc = (ptc_read_noise(None, noise, False, dark, ptc_notes) if noise is not None
           else PtcReadNoise())
    return replace(figures, sigma_d_ptc=ptc.sigma_d, sigma_d_ptc_err=ptc.sigma_d_err,
                   K_ptc=ptc.K, K_ptc_err=ptc.K_err, sigma_d_consistent=ptc.consistent,
                   notes=tuple(base + ptc_notes), ptc_notes=tuple(ptc_notes))
