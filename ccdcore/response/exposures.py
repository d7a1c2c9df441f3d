"""The bracket's own exposures: the exposure ratios its images show, against the listed ones.

Tsin, Ramesh & Kanade (2001) write every image's exposure as a gain a_k (eq. 5, sec. 3.2): the
nominal time is only where a_k starts. Real brackets' listed exposures (manifest, EXIF) are often
wrong for part of the bracket -- a shutter that did not change for a few steps, a camera's
auto-exposure -- and every method given the listed times absorbs the error into its curve: on two
real 13- and 9-frame brackets, four neighbouring pairs fit about half the listed ratio of 2, and
every curve fitted at the listed times predicted the images within 16-60 DN instead of 4-5 DN.

:func:`estimate_exposures` estimates the ratios from the images, before any response method
runs, by alternation (the a_k of sec. 3.2, seeded by the images rather than by the listed
times):

1. a curve at the current exposures (Debevec & Malik's, :func:`ccdcore.response.classic.
   debevec`, on its usual sample of pixels: fast, and its hat weights keep it well behaved far
   from the truth), or the given curves;
2. each neighbour pair's ratio fitted with that curve (the prediction agreement's fitted ratio,
   :func:`ccdcore.response.agreement.fit_ratio`, sec. 4.2), in every channel;
3. the channels combined per pair: the inverse-variance mean of ln ratio (each channel's
   variance a delete-one-block jackknife over 16 bands of rows), its error inflated by the
   channels' disagreement (Birge ratio) where they disagree beyond it, and
   :data:`SYSTEMATIC` added for the quick curve's own bias;
4. the gauge. g^u with exposures a^u explains a bracket almost as well (sec. 3.2's
   u-ambiguity): the ratios are rescaled by the u that makes most pairs agree with the listed
   ratios (a trimmed least squares over the pairs, every pair's own u tried as a start, ties
   broken towards u = 1), and the exposures shifted so that the median frame keeps its listed
   time. "Most pairs as listed" is the one assumption: a bracket whose listed ratios are all
   wrong by the same power cannot be told from a different curve by any method;
5. repeated until no exposure moves by more than ``tol`` (relative), at most ``max_iter``.

The listed exposures are declared wrong (:attr:`ExposureEstimate.used` = ``"estimated"``) when
the curve's agreement with them is clearly worse than with the estimated ones: RMS more than
:data:`WORSE_FACTOR` times and :data:`WORSE_DN` DN above it. Otherwise the listed exposures
are kept, and the estimate is still reported.

Public objects
--------------
ExposureEstimate
    The listed and estimated exposures, the pairs' ratios with their errors, which are used and
    why; ``summary()`` gives its record.
ExposureSummary, PairRatioSummary
    The records (``calibration.json``'s ``response.exposures``; the CLI's JSON).
estimate_exposures(brackets, curves=None, ...)
    The estimate for a bracket's channels.
exposures_with_curves(brackets, curves, listed, mode)
    The exposures a calibration's curves merge a bracket at (``hdr --calib``, ``change``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Mapping

import numpy as np
from numpy.typing import NDArray

from ..records import Record, Row
from .agreement import PairMoments, code_range, fit_ratio, inverse, moments_by_block
from .brackets import BracketData

__all__ = ["ExposureEstimate", "ExposureSummary", "PairRatioSummary", "estimate_exposures",
           "exposures_with_curves",
           "WORSE_FACTOR", "WORSE_DN", "OFF_FACTOR", "JACKKNIFE_BLOCKS", "SYSTEMATIC"]

#: the listed exposures are wrong when the agreement with them is this many times ...
WORSE_FACTOR = 1.25
#: ... and this many DN worse than with the estimated ones
WORSE_DN = 0.5
#: a pair is named when its estimated ratio is off the listed one by more than this factor
#: (and by more than 3 of its standard errors)
OFF_FACTOR = 1.15
#: most pixels per channel the quick curve is fitted from (an even sample)
QUICK_PIXELS = 65536
#: bands of rows of the frame of the ratios' jackknife
JACKKNIFE_BLOCKS = 16
#: the quick curve's own bias in a pair's ln ratio, added in quadrature to the statistical
#: error: on the camera-like simulation (JPEG, Bayer, per-frame white balance) the pairs'
#: estimates fell 1-3 % from the truth beyond their jackknife errors
SYSTEMATIC = 0.02
#: in the gauge, a pair agrees with its listed ratio within this (in ln ratio) ...
GAUGE_BAND = 0.15
#: ... and the gauge leans towards u = 1 with this standard deviation of ln u
GAUGE_PRIOR = 1.0


@dataclass(frozen=True)
class PairRatioSummary(Record):
    """One pair of neighbouring frames (increasing exposure): listed and estimated ratio."""

    #: the frames (by file name) and their indices in increasing exposure
    first: str
    second: str
    j: int
    k: int
    #: the listed ratio t_k / t_j and the estimated one a_k / a_j with its 1-σ error
    listed: float
    estimated: float
    error: float | None

    @property
    def factor(self) -> float:
        """The estimated ratio as a fraction of the listed one."""
        return self.estimated / self.listed


@dataclass(frozen=True)
class ExposureSummary(Record):
    """An :class:`ExposureEstimate` as ``calibration.json`` stores it (``response.exposures``)."""

    #: the frames (by file name) in increasing listed exposure
    files: tuple[str, ...]
    #: the listed exposures (s), and the estimated ones on the same scale (the median frame
    #: keeps its listed time) with the 1-σ error of ln(estimated)
    listed: tuple[float, ...]
    estimated: tuple[float, ...]
    ln_error: tuple[float | None, ...]
    #: every neighbour pair's ratios
    pairs: tuple[PairRatioSummary, ...]
    #: "listed" or "estimated": which exposures the response used, and why
    used: str
    reason: str
    #: the quick curve's prediction agreement (sec. 4.2, DN RMS) with the listed and the
    #: estimated exposures
    rms_listed: float | None
    rms_estimated: float | None
    #: alternations made, and whether the exposures stopped moving
    iterations: int
    converged: bool

    def off_pairs(self) -> tuple[PairRatioSummary, ...]:
        """The pairs whose estimated ratio is off the listed one by more than
        :data:`OFF_FACTOR` and 3 standard errors."""
        out = []
        for p in self.pairs:
            d = abs(math.log(p.factor))
            e = p.error if p.error is not None else 0.0
            if d > math.log(OFF_FACTOR) and d > 3.0 * e:
                out.append(p)
        return tuple(out)

    def off_runs(self) -> tuple[str, ...]:
        """The off pairs in plain words, one phrase per run of neighbouring pairs:
        "DSC_0109 to DSC_0113 look 0.48× as far apart as listed" (the geometric mean factor
        of the run's pairs)."""
        off = self.off_pairs()
        runs: list[list[PairRatioSummary]] = []
        for p in off:
            if runs and runs[-1][-1].k == p.j and \
                    (runs[-1][-1].factor < 1) == (p.factor < 1):
                runs[-1].append(p)
            else:
                runs.append([p])
        out = []
        for run in runs:
            fac = math.exp(sum(math.log(p.factor) for p in run) / len(run))
            step = "each step " if len(run) > 1 else ""
            out.append(f"{_stem(run[0].first)} to {_stem(run[-1].second)} look {step}"
                       f"{fac:.2f}× as far apart as listed")
        return tuple(out)

    def line(self) -> str:
        """One line: which exposures were used and why."""
        return f"exposures: {self.used} ({self.reason})"

    def rows(self) -> tuple[Row, ...]:
        """Which exposures, the two agreements and the off pairs."""
        out = [Row("exposures used", None, None, "", self.reason, self.used),
               Row("agreement, listed exposures", self.rms_listed, None, "DN",
                   "the quick curve's prediction RMS with the listed exposures"),
               Row("agreement, estimated exposures", self.rms_estimated, None, "DN",
                   "the same with the bracket's own exposures")]
        for run in self.off_runs():
            out.append(Row("exposures off", None, None, "", run, "frames"))
        return tuple(out)


def _stem(name: str) -> str:
    base = str(name).replace("\\", "/").rsplit("/", 1)[-1]
    return base.rsplit(".", 1)[0] if "." in base else base


@dataclass(frozen=True, eq=False)
class ExposureEstimate:
    """The bracket's own exposures (see the module notes)."""

    files: tuple[str, ...]
    listed: NDArray[np.float64]
    estimated: NDArray[np.float64]
    ln_error: NDArray[np.float64]          # 1-σ of ln(estimated), from the pairs' errors
    pair_error: NDArray[np.float64]        # 1-σ of each pair's ln ratio
    used: str
    reason: str
    rms_listed: float
    rms_estimated: float
    iterations: int
    converged: bool

    @property
    def exposures(self) -> NDArray[np.float64]:
        """The exposures the response takes: the estimated ones when used, else the listed."""
        return self.estimated if self.used == "estimated" else self.listed

    def summary(self) -> ExposureSummary:
        """The record ``calibration.json`` stores."""
        pairs = tuple(PairRatioSummary(
            str(self.files[j]), str(self.files[j + 1]), j, j + 1,
            float(self.listed[j + 1] / self.listed[j]),
            float(self.estimated[j + 1] / self.estimated[j]),
            _num(self.estimated[j + 1] / self.estimated[j] * self.pair_error[j]))
            for j in range(self.listed.size - 1))
        return ExposureSummary(
            tuple(str(f) for f in self.files), tuple(float(v) for v in self.listed),
            tuple(float(v) for v in self.estimated), tuple(_num(v) for v in self.ln_error),
            pairs, self.used, self.reason, _num(self.rms_listed), _num(self.rms_estimated),
            int(self.iterations), bool(self.converged))


def _num(v: Any) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def _block_moments(data: BracketData, codes: tuple[int, int]
                   ) -> list[list[PairMoments]]:
    """Per pair, the code moments of every band of rows (their sum is the whole channel's)."""
    z = np.asarray(data.z)
    blk = data.row_bands(JACKKNIFE_BLOCKS)
    return [moments_by_block(z[j], z[j + 1], int(data.levels), codes, blk, JACKKNIFE_BLOCKS)
            for j in range(data.n_images - 1)]


def _pair_ln_ratios(moms: list[list[PairMoments]], g: NDArray, a: NDArray,
                    jackknife: bool = True) -> tuple[NDArray, NDArray, tuple[float, int]]:
    """Each pair's fitted ln ratio with the curve g, its jackknife variance (NaN without
    ``jackknife``), and the pooled squared error (DN²) and count at the ratios a gives (for the
    agreement)."""
    f = inverse(g)
    N1 = len(moms)
    lr = np.full(N1, np.nan)
    var = np.full(N1, np.nan)
    sse0 = 0.0
    n0 = 0
    for j, blocks in enumerate(moms):
        total = blocks[0]
        for m in blocks[1:]:
            total = total + m
        r0 = float(a[j + 1] / a[j])
        if total.n == 0:
            continue
        c0, _, r = fit_ratio(total, f, g, g, 0.0, 0.0, r0)
        sse0 += c0
        n0 += 2 * total.n
        lr[j] = math.log(r)
        if not jackknife:
            continue
        reps = []
        for m in blocks:
            if m.n == 0 or total.n - m.n == 0:
                continue
            reps.append(math.log(fit_ratio(total - m, f, g, g, 0.0, 0.0, r)[2]))
        if len(reps) >= 3:
            R = np.asarray(reps)
            var[j] = (R.size - 1) / R.size * float(np.sum((R - R.mean()) ** 2))
    return lr, var, (sse0, n0)


def _combine(lrs: NDArray, vars_: NDArray) -> tuple[NDArray, NDArray]:
    """Per pair, the channels' inverse-variance mean of ln ratio and its variance, inflated by
    the Birge ratio where the channels disagree beyond their errors."""
    C, N1 = lrs.shape
    out = np.full(N1, np.nan)
    var = np.full(N1, np.nan)
    for j in range(N1):
        x, v = lrs[:, j], vars_[:, j]
        ok = np.isfinite(x)
        if not ok.any():
            continue
        x = x[ok]
        v = v[ok]
        if not np.all(np.isfinite(v)) or np.any(v <= 0):
            out[j] = float(np.median(x))
            var[j] = float(np.var(x)) / max(1, x.size - 1) if x.size > 1 else np.nan
            continue
        w = 1.0 / v
        m = float(np.sum(w * x) / np.sum(w))
        vm = 1.0 / float(np.sum(w))
        if x.size > 1:
            birge = float(np.sum(w * (x - m) ** 2)) / (x.size - 1)
            vm *= max(1.0, birge)
        out[j], var[j] = m, vm
    return out, var


def _gauge(lr: NDArray, nominal: NDArray) -> float:
    """The u of sec. 3.2's ambiguity that makes most pairs agree with their listed ratios: the
    trimmed least squares Σ min((ln r / u − ln r_listed)², c²) + c² (ln u / GAUGE_PRIOR)²,
    every pair's own u and u = 1 tried as starts, each refined over its inliers."""
    ok = np.isfinite(lr) & (nominal > 0)
    x, y = lr[ok], nominal[ok]
    if x.size == 0:
        return 1.0
    c = GAUGE_BAND

    def cost(u: float) -> float:
        r = x / u - y
        return float(np.sum(np.minimum(r * r, c * c)) + c * c * (math.log(u) / GAUGE_PRIOR) ** 2)

    starts = [1.0] + [float(u) for u in (x / y) if u > 0.05]
    best_u, best = 1.0, cost(1.0)
    for u in starts:
        for _ in range(3):                         # refine over the inliers of u
            inl = np.abs(x / u - y) < c
            if not inl.any() or float(x[inl] @ y[inl]) <= 0:
                break
            u = float(x[inl] @ x[inl]) / float(x[inl] @ y[inl])
        cu = cost(u)
        if u > 0 and cu < best - 1e-12:
            best_u, best = u, cu
    return best_u


def _quick_curve(data: BracketData, a: NDArray) -> NDArray[np.float64]:
    from .classic import debevec

    return np.asarray(debevec(replace(data, t=np.asarray(a, np.float64))).g, np.float64)


def _quick_sample(data: BracketData) -> BracketData:
    """An even sample of at most :data:`QUICK_PIXELS` of the channel's pixels for the quick
    curve (Debevec's own sample of 20,000 is drawn from it; checking the whole bracket at
    every alternation cost more than the fit)."""
    P = data.n_pixels
    if P <= QUICK_PIXELS:
        return data
    keep = np.linspace(0, P - 1, QUICK_PIXELS).astype(np.int64)
    return data.take(keep[np.r_[True, keep[1:] != keep[:-1]]])


def estimate_exposures(brackets: Mapping[str, BracketData],
                       curves: Mapping[str, Any] | None = None, *, max_iter: int = 6,
                       tol: float = 5e-3) -> ExposureEstimate:
    """The bracket's own exposures (see the module notes): ``curves`` (channel -> g per code,
    or anything with ``g``) fixes the curve; otherwise a quick curve is fitted at each
    alternation. Channels share the exposures (a frame has one exposure)."""
    names = tuple(brackets)
    first = brackets[names[0]]
    t = np.asarray(first.t, np.float64)
    N = t.size
    codes = code_range(first.levels)
    nominal = np.diff(np.log(t))
    moms = {ch: _block_moments(brackets[ch], codes) for ch in names}

    quick = {ch: _quick_sample(brackets[ch]) for ch in names} if curves is None else {}

    def curve_of(ch: str, a: NDArray) -> NDArray:
        if curves is None:
            return _quick_curve(quick[ch], a)
        c = curves[ch]
        return np.asarray(getattr(c, "g", c), np.float64)

    a = t.copy()
    rms_listed = float("nan")
    it = 0
    converged = False
    while it < max_iter:
        it += 1
        lrs = []
        sse, n = 0.0, 0
        for ch in names:
            lr, _, (s0, n0) = _pair_ln_ratios(moms[ch], curve_of(ch, a), a, jackknife=False)
            lrs.append(lr)
            sse, n = sse + s0, n + n0
        if it == 1:
            rms_listed = math.sqrt(sse / n) if n else float("nan")
        lr, _ = _combine(np.asarray(lrs), np.full((len(names), N - 1), np.nan))
        lr = np.where(np.isfinite(lr), lr, np.log(a[1:] / a[:-1]))
        u = _gauge(lr, nominal)
        ln_a = np.r_[0.0, np.cumsum(lr / u)]
        ln_a += float(np.median(np.log(t) - ln_a))
        a_new = np.exp(ln_a)
        move = float(np.max(np.abs(np.log(a_new / a))))
        a = a_new
        if curves is not None or move < tol:
            converged = True
            break
    # the errors of the pairs' ratios (jackknife over bands of rows, channels combined) and the
    # agreement, at the final exposures
    lrs, vs = [], []
    sse, n = 0.0, 0
    for ch in names:
        lr, v, (s0, n0) = _pair_ln_ratios(moms[ch], curve_of(ch, a), a)
        lrs.append(lr)
        vs.append(v)
        sse, n = sse + s0, n + n0
    rms_est = math.sqrt(sse / n) if n else float("nan")
    _, pair_var = _combine(np.asarray(lrs), np.asarray(vs))
    pair_err = np.sqrt(np.where(np.isfinite(pair_var), pair_var, 0.0) + SYSTEMATIC ** 2)
    # ln a_k is the cumsum of the pairs from the median frame: its variance the sum of the
    # pairs' variances between frame k and the median frame
    mid = int(np.argmin(np.abs(np.log(t) - np.median(np.log(t)))))
    cum = np.r_[0.0, np.cumsum(pair_err ** 2)]
    ln_err = np.sqrt(np.abs(cum - cum[mid]))
    worse = (math.isfinite(rms_listed) and math.isfinite(rms_est)
             and rms_listed > WORSE_FACTOR * rms_est + WORSE_DN)
    used = "estimated" if worse else "listed"
    if worse:
        reason = (f"the images disagree with the listed exposures: {rms_listed:.1f} DN RMS "
                  f"with them, {rms_est:.1f} DN with the bracket's own")
    else:
        reason = (f"the images agree with the listed exposures ({rms_listed:.1f} DN RMS with "
                  f"them, {rms_est:.1f} DN with the bracket's own)")
    files = tuple(first.files) if first.files else tuple(f"frame {k}" for k in range(N))
    return ExposureEstimate(files, t, a, ln_err, pair_err, used, reason, rms_listed, rms_est,
                            it, converged)


def exposures_with_curves(brackets: Mapping[str, BracketData] | None,
                          curves: Mapping[str, Any], listed: Any, mode: str
                          ) -> tuple[NDArray[np.float64], ExposureEstimate | None]:
    """The exposures a calibration's ``curves`` (channel -> anything with ``g``) merge a bracket
    at: its own, estimated with those curves, when ``mode`` asks for them (``"estimated"``) or
    the images disagree with the listed ones (``"auto"``); else the ``listed`` ones. Also the
    estimate (``None`` when not made: ``"listed"``, or ``brackets`` not read here -- a cluster's
    workers read the frames)."""
    if brackets is None or mode == "listed":
        return np.asarray(listed, np.float64), None
    ex = estimate_exposures(brackets, {ch: getattr(c, "g", c) for ch, c in curves.items()})
    if mode == "estimated" and ex.used != "estimated":
        ex = replace(ex, used="estimated", reason=f"asked for (--exposures estimated); "
                                                  f"{ex.reason}")
    return np.asarray(ex.exposures, np.float64), ex
