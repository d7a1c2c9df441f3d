"""Statistical calibration of the imaging process: Tsin, Ramesh & Kanade (2001), sec. 3.

The camera (eq. 3) images radiance E through white balance and the response f::

    z = f(a E + N_s + N_c1 + b) + N_c2

and the inverse response g = f^-1 obeys g(z) = a E + b up to noise (eqs. 5, 8). From one channel
of an exposure bracket (a static scene at N exposure settings) :func:`estimate` recovers g at
every code with its confidence band, the three noise terms and, on request, the gains a_k and
offsets b_k of the images (white balance, exposure errors; see the last departure below), by the
iterative algorithm of sec. 3.2:

1. preprocessing (:mod:`ccdcore.response.brackets`): boundary and blooming pixels out, pixel
   traces; here the pools P(j, ẑ, ε) of the pixels of image j at code ẑ (ε = 1/2, one code;
   bins of codes beyond 10 bits) and each pool's trace: the images in which the pool is
   readable (at most ``clip_fraction`` of its pixels clipped there);
2. g initialised as the straight line through the fixed points, a_k at the nominal exposure
   times, b_k = 0;
3. every pixel's radiance from its trace, eq. 9, with eq. 18's weights a_i / σ(z_i), σ taken
   as g'(z) (constant weights, as printed for this step, let the shortest exposures' noise rule
   a bracket spanning a factor 512);
4. the prediction errors, eq. 10;
5. per pool, their 66 % trimmed mean (eq. 11) and MAD sigma (eq. 12, c = 1.483 times the Bayer
   factor 1.265 green / 1.333 red and blue for interpolated colour);
6. the linearised model of every pool's mean error in Δg (eq. 13), averaged from every pixel's
   own linearisation; the smoothness term; the fixed point of g;
7. the weighted least squares for the update (eq. 15);
8. the update with step η (eq. 16);
9. monotonicity by pool-adjacent-violators (PAV);
10. repeat from 3 until ‖η Δg‖₁ (per knot) is below the tolerance.

Then σ_s, σ_c1, σ_c2 by non-negative least squares from eq. 17, each with its error, and the
covariance of g (the confidence band) from the spread of the pools' pixels.

Departures from the paper, each for a measured reason (docs/response.md):

* **Instrumented pools** (``pools="instrument"``, the default). The paper's pool P(k, ẑ) predicts
  the code ẑ_k that selected it, from a radiance that includes that same code. A pool chosen by
  a noisy code holds pixels whose radiance regresses towards the bulk of the scene (Tweedie's
  formula), so its mean error is not zero even at the true g: on the sec. 4.1 simulation, near
  the darkest codes (E >= 0) and at every image's brightest code, and the printed pools give
  an RMS error of 1.15e-3 against 2.2e-4 here (``pools="paper"`` keeps them for comparison).
  Here the pool of image j at code ẑ predicts the *other* images k of its trace, from the
  radiance of the images other than j (eqs. 9-10 with image j left out). Given the pool, the
  noise of every image k != j is independent of the selection, so each mean error is zero at the
  truth whatever the scene's radiance distribution: image j acts as an instrument. Eq. 13 keeps
  its form (the sum runs over the pool's trace). Which images join a pool's trace depends only on
  the pool (its clipped fraction), never on one pixel's own noise, so the clipping biases no
  mean either.
* **Smoothness on g relative to its slope**, not on Δg: a penalty λ Σ (g''(z) / g'(z))² in
  eq. 15, the second differences of g weighted by (median slope / g'(z))² (from the last pass).
  The printed term on Δg only damps the steps and leaves the fixed point unregularised: codes
  seen by a few pools then wander. Relative to the slope because a real camera's curve spans
  decades: an absolute penalty on g'' is largest where g is steep, and on a real bracket it
  flattened the sparse highlights of the shoulder (the agreement of the longest exposures fell
  behind Debevec's hat-weighted smoothing); on a power law g''/g' = (γ-1)/z is small there.
  ``smoothness`` is the bandwidth in 8-bit code steps (λ = bandwidth^4 times the median data
  weight of a knot) where the slope is the median one.
* **One fixed point, where the pools are.** With a_k the nominal times and b_k = 0 only the
  scale of g is free: one fixed point (a second would contradict b = 0), at the 75th percentile
  of the pools' codes (:func:`_anchors`; the white-balance fit also holds the 25th); g is then
  reported with g(z_hi) fixed (:mod:`ccdcore.response.scale`).
* **A guarded step** (sec. 3.2 without white balance, and its first phase): a step that raises
  the objective is taken back and shortened (:func:`_shorter_step`); at 1/8 of a step, or once a
  step moves g by less than a tenth of its statistical error (:data:`RESOLUTION`), the fit has
  converged.
* **Pools** count from ``min_pool`` = 10 pixels and keep at most :data:`POOL_CAP` pixels.
* **Shot noise** is linear in the signal, σ² = σ_s² a E + σ_c1² + g'(z)² σ_c2² (eq. 7 reads
  a²E² as extracted; sec. 2 says the shot variance is proportional to E t). Eq. 17 carries the
  factor (a_k / a_i)² that eq. 13 implies (image i enters the error of image k scaled by
  a_k / a_i), and σ_c2 includes the quantisation (1/12 DN²).
* **Weights.** A pool's row in eq. 15 is weighted by the variance of its trimmed mean (Tukey and
  McLaughlin: winsorised variance / ((1 - 2α)² n)), the paper's σ̂² over the pool size.
* **White balance in a gauge.** With a joint step for g, a_k, b_k and the a-priori bound of
  sec. 3.2 the iteration wanders along the u-ambiguity on the sec. 4.1 simulation
  (docs/response.md). With ``white_balance`` g first comes near at the nominal times; then g,
  a_k and b_k take joint steps in which every direction no bracket fixes is fixed by a gauge
  instead of the prior: g keeps both fixed points, ln(a_k / t_k) has zero mean and zero trend in
  ln t_k, b of the shortest exposure is 0 (sec. 3.2's fixed b_k). g is then reported with the
  offsets of smallest norm and g(z_hi) fixed. A bracket that does not fit gets a note (the pools'
  chi²/dof above 3).

The compiled kernels are in :mod:`ccdcore.response.tsin.kernels`, the white-balance gauge and the
band in :mod:`ccdcore.response.tsin.gauge`, eq. 17's fit in :mod:`ccdcore.response.tsin.noise`.

Public objects
--------------
TsinOptions
    The estimator's settings.
ChannelResponse
    One channel's response with its band, a_k, b_k, the noise terms, iterations, the pools and
    the prediction errors of one pool before and after calibration (the paper's Fig. 3c-d).
estimate(data, options)
    The algorithm of sec. 3.2 on one channel.
noise_terms(data, g, a, b)
    σ_s, σ_c1, σ_c2 (eq. 17) for any response, e.g. a classic method's.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import isotonic_regression

from ...errors import CcdError
from ...progress import Progress
from ..brackets import BracketData
from ..scale import Knots, normalize, reference_codes
from .gauge import band, joint_step
from .kernels import (pool_counts, pool_members, pool_rows, row_counts, row_stats,
                           sort_rows)
from .noise import noise_fit
from .notes import estimate_notes, pick_pool

__all__ = ["TsinOptions", "ChannelResponse", "PoolTable", "estimate", "noise_terms", "TRIM",
           "MAX_ENTRIES"]

#: the fraction of a pool's prediction errors the trimmed mean keeps (eq. 11: "66 percent")
TRIM = 0.66
#: most prediction errors one pass stores (pixels × images × other images): larger brackets are
#: estimated on an even sample of their pixels (a 640×480 × 16 bracket keeps 70,000 pixels, some
#: 270 per code; the error of g is then set by the bias, not the sample)
MAX_ENTRIES = 2 ** 24
#: most pixels a pool keeps (evenly spread over the frame): beyond a few hundred pixels the
#: error of a pool's trimmed mean is far below the bias of g, and the pass costs in proportion
POOL_CAP = 256


@dataclass(frozen=True)
class TsinOptions:
    """Settings of :func:`estimate`.

    white_balance
        Estimate the gains a_k and offsets b_k as well (white balance and exposure errors,
        sec. 3.2), in the gauge of the u-ambiguity: ln(a_k / t_k) keeps zero mean and zero trend
        in ln t_k, b_0 = 0. False: a_k are the nominal exposure times, b_k = 0.
    pools
        ``"instrument"`` (default): the pool of image j predicts the other images of its trace
        from a radiance without image j; ``"paper"``: the pool of image k predicts image k
        itself from every usable code, as printed (biased; kept for comparison).
    smoothness
        Bandwidth of the smoothness term on g, in 8-bit code steps.
    eta
        Step of the update, eq. 16.
    tol
        Stop when the mean |η Δg| per knot is below this (g on a 0..1 scale).
    max_iter
        Most iterations.
    min_pool
        Fewest pixels a pool's prediction of one image needs to count (sec. 4.1 used 100 on
        its simulation; the default 10 lets the sparse codes of a real scene -- the
        highlights of a night street -- tie the curve together: with 100 they had no pool and
        g there was the smoothness term's extrapolation).
    edge
        Codes within ``edge`` (in 8-bit code steps) of 0 and of the top code count as clipped:
        a real camera's processing clips and compresses its toe and knee (black level, JPEG,
        the shoulder of its tone curve), where a code says little about the signal.
    clip_fraction
        An image joins a pool's trace when at most this fraction of the pool's pixels is
        clipped (0 or the top code) in it.
    mad_factor
        Eq. 12's c; ``None``: 1.483 times the Bayer factor of the data's channel.
    groups
        Blocks of pixels (bands of rows of the frame) over which the band of g is estimated.
    gain_prior
        With ``white_balance``: the a-priori bound on the gains (sec. 3.2), the standard
        deviation of ln(a_k / t_k) a priori (0: none). Within the gauge it only holds the
        directions the data leave loose, e.g. the gain of an image that is nearly all saturated.
        It is counted in the units of the pools' actual spread (divided by √(χ²/dof) when the
        model does not fit the camera, χ²/dof > 1).
    """

    white_balance: bool = False
    pools: str = "instrument"
    smoothness: float = 10.0
    eta: float = 1.0
    tol: float = 1e-5
    max_iter: int = 30
    min_pool: int = 10
    edge: float = 5.0
    clip_fraction: float = 0.02
    mad_factor: float | None = None
    groups: int = 64
    gain_prior: float = 0.1

    def check(self, where: str = "response") -> None:
        """Raise :class:`CcdError` (naming ``where``) for settings the estimator cannot use."""
        if self.pools not in ("instrument", "paper"):
            raise CcdError(where, f"pools must be 'instrument' or 'paper', got {self.pools!r}")
        for name in ("eta", "tol"):
            if not getattr(self, name) > 0:
                raise CcdError(where, f"{name} must be positive, got {getattr(self, name)}")
        if not self.gain_prior >= 0:
            raise CcdError(where, f"gain_prior must be >= 0, got {self.gain_prior}")
        if not self.smoothness >= 0:
            raise CcdError(where, f"smoothness must be >= 0, got {self.smoothness}")
        if not 0 <= self.edge < 64:
            raise CcdError(where, f"edge must be in [0, 64), got {self.edge}")
        if not 0 <= self.clip_fraction < 0.5:
            raise CcdError(where, f"clip_fraction must be in [0, 0.5), got {self.clip_fraction}")
        if self.max_iter < 1 or self.min_pool < 2 or self.groups < 4:
            raise CcdError(where, "max_iter >= 1, min_pool >= 2 and groups >= 4 are needed")


@dataclass(frozen=True, eq=False)
class PoolTable:
    """The counted pools of the last iteration, one row per (pool image j, code, predicted image
    k): size, trimmed-mean error (eq. 11), MAD sigma (eq. 12) and the standard error of the
    trimmed mean, in units of g."""

    j: NDArray[np.int64]
    code: NDArray[np.float64]
    k: NDArray[np.int64]
    n: NDArray[np.int64]
    error: NDArray[np.float64]
    sigma: NDArray[np.float64]
    se: NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class ChannelResponse:
    """One channel's response and noise, on the reported scale of :mod:`ccdcore.response.scale`
    (g(z_hi) = z_hi / (levels - 1)).

    ``g``, ``g_err``: per code (``g_err`` is zero at the fixed point, which carries no error by
    definition, and is the statistical 1-sigma band elsewhere); ``a``, ``b`` per image in
    increasing exposure order with ``a_err``, ``b_err`` (the nominal times and 0, errors 0, in
    this release); ``t`` the nominal times; noise terms
    (σ_s, σ_c1 in units of g, σ_c2 in codes) with errors, ``None`` where not estimated.
    """

    channel: str
    method: str
    g: NDArray[np.float64]
    g_err: NDArray[np.float64]
    a: NDArray[np.float64]
    a_err: NDArray[np.float64]
    b: NDArray[np.float64]
    b_err: NDArray[np.float64]
    t: NDArray[np.float64]
    sigma_s: float | None = None
    sigma_c1: float | None = None
    sigma_c2: float | None = None
    sigma_s_err: float | None = None
    sigma_c1_err: float | None = None
    sigma_c2_err: float | None = None
    iterations: int = 0
    converged: bool = True
    white_balance: bool = False
    pools: PoolTable | None = None
    history: tuple[dict[str, float], ...] = ()
    pool_errors: dict[str, Any] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    @property
    def levels(self) -> int:
        return int(self.g.size)


# ------------------------------------------------------------------------------ helpers ------
@dataclass
class _Setup:
    data: BracketData
    knots: Knots
    start: NDArray[np.int64]         # pools' CSR into the memberships
    mz: NDArray[np.uint16]           # (M, N) codes of each membership's pixel
    mflag: NDArray[np.uint8]         # (M, N) bit 0 observed, bit 1 clipped
    mgrp: NDArray[np.int32]          # (M,) block of the membership's pixel
    inc: NDArray[np.bool_]           # (N, K, N) image i in the trace of pool (j, m)
    rowid: NDArray[np.int64]         # (N, K, N) row of (pool j, m; image k), -1 if not counted
    offsets: NDArray[np.int64]       # rows' CSR into the residuals
    rows: NDArray[np.int64]          # (R, 3): j, m, k
    paper: bool
    min_pool: int
    #: the last pass's order of the errors within each row (:func:`sort_rows`), -1 before one
    order: NDArray[np.int64] | None = None


#: the shortest step of g (as a fraction of eq. 16's step) tried before the fit is taken as
#: converged: no step along the update lowers its objective
MIN_ETA = 1.0 / 8
#: the smoothness relative to the slope counts slopes from this fraction of the median one
SLOPE_FLOOR = 0.1
#: the iteration has converged once a step moves g by less than this fraction of g's
#: statistical error (the mean over the free knots of eq. 15's 1-sigma, per knot): further
#: steps only trade one noisy trimmed mean for another (on real brackets the guarded step was
#: then rejected again and again while the objective wobbled by 1e-4 of itself)
RESOLUTION = 0.1
#: the white-balance fit stops when three steps in a row lower its objective by less than
#: this fraction each
FLAT = 1e-5
#: a reported curve within this of the straight starting line (fraction of full scale, at every
#: code) never moved: not converged
START_TOLERANCE = 1e-6


def _sample(data: BracketData) -> tuple[BracketData, int]:
    """The bracket, or an even sample of its pixels when one pass would store more than
    :data:`MAX_ENTRIES` errors; and the original pixel count (0 when not sampled)."""
    N, P = data.z.shape
    cap = MAX_ENTRIES // max(1, N * (N - 1))
    if P <= cap:
        return data, 0
    keep = np.linspace(0, P - 1, cap).astype(np.int64)      # sorted: drop repeats
    keep = keep[np.r_[True, keep[1:] != keep[:-1]]]
    return data.take(keep), P


def _setup(data: BracketData, opts: TsinOptions) -> _Setup:
    N, P = data.z.shape
    L = int(data.levels)
    where = data.files[0] if data.files else "bracket"
    if N < 2:
        raise CcdError(where, f"a bracket needs at least two exposures, got {N}")
    knots = Knots(L)
    K = knots.n
    z = np.asarray(data.z)
    j0, fr = knots.locate(z)
    pb = np.ascontiguousarray(np.asarray(j0) + (np.asarray(fr) > 0.5), np.int64)
    obs = np.ascontiguousarray(data.observed, np.bool_)
    e = int(round(opts.edge * (L - 1) / 255.0))
    clip = (z <= e) | (z >= L - 1 - e)
    grp = data.row_bands(int(opts.groups)).astype(np.int32)
    paper = opts.pools == "paper"
    seen, nclip = pool_counts(pb, obs, clip, K)
    inc = (seen > 0) & (nclip <= opts.clip_fraction * seen)
    for j in range(N):
        inc[j, :, j] = False
    start, members = pool_members(pb, obs, clip, K, int(POOL_CAP))
    mz = np.ascontiguousarray(z.T.astype(np.uint16)[members])
    mflag = np.ascontiguousarray((obs.astype(np.uint8) | (clip.astype(np.uint8) << 1)).T[members])
    mgrp = grp[members]
    counts = row_counts(start, mflag, inc, paper, K)
    # small brackets: lower the pool threshold to what their size allows (at least 10)
    per_code = P / max(1, K)
    min_pool = int(max(min(10, opts.min_pool), min(opts.min_pool, 0.4 * per_code)))
    ok = counts >= min_pool
    rows = np.argwhere(ok)
    if rows.shape[0] < 3:
        raise CcdError(where, f"too few pixel pools with at least {min_pool} pixels "
                              f"({rows.shape[0]}): the bracket needs more pixels, or exposures "
                              "that overlap (each code seen in at least two images)")
    rowid = np.full(counts.shape, -1, np.int64)
    rowid[ok] = np.arange(rows.shape[0])
    offsets = np.zeros(rows.shape[0] + 1, np.int64)
    np.cumsum(counts[ok], out=offsets[1:])
    return _Setup(data, knots, start, mz, mflag, mgrp, inc, rowid, offsets, rows, paper,
                  min_pool)


def _slopes(knots: Knots, gk: NDArray, levels: int) -> NDArray[np.float64]:
    """g'(z) at every code, in units of g per code (central differences on the knots)."""
    codes = knots.codes
    d = np.gradient(gk, codes) if knots.n > 2 else np.full(knots.n, (gk[-1] - gk[0]) /
                                                           max(codes[-1] - codes[0], 1))
    return np.interp(np.arange(levels, dtype=np.float64), codes, d)


def _pass(s: _Setup, a, b, gk, want_noise=False, with_a=False, wcode=None):
    """One pass of :func:`ccdcore.response.tsin.kernels.pool_rows` at ``(a, b, g)``; the eq. 17
    regressors with ``want_noise``.
    ``wcode``: 1/σ per code for eq. 18's weights (``None``: constant weights)."""
    L = int(s.data.levels)
    gpc = _slopes(s.knots, gk, L) if want_noise else np.zeros(L)
    if wcode is None:
        wimg, wcode = np.ones(len(a)), np.ones(L)
    else:
        wimg = np.asarray(a, np.float64)
    J, X, resid, egrp = pool_rows(s.start, s.mz, s.mflag, s.mgrp, s.inc, s.paper, s.rowid,
                                  s.offsets, np.asarray(a, np.float64), np.asarray(b, np.float64),
                                  np.asarray(gk, np.float64), gpc, wimg,
                                  np.asarray(wcode, np.float64), s.knots.n,
                                  float(s.knots.step), bool(s.knots.identity), want_noise,
                                  with_a)
    return J, X, resid, egrp


def _eq18_codes(s: _Setup, gk: NDArray) -> NDArray[np.float64]:
    """1/σ(z) per code for eq. 18's weights in eq. 9, with σ taken as g'(z): the output noise,
    the same in codes for every image (the noise terms are not known before the fit; on a
    bracket of a real camera the full eq. 7 with the last pass's terms gave the same curve).
    Floored at 1 % of the curve's mean slope."""
    L = int(s.data.levels)
    gp = _slopes(s.knots, gk, L)
    floor = 0.01 * max(float(gk[-1] - gk[0]), 1e-12) / (L - 1)
    return 1.0 / np.maximum(gp, floor)


def _anchors(s: _Setup) -> tuple[int, int]:
    """The fit's two fixed points (knots): the 25th and 75th percentiles of the pools' codes,
    weighted by their pixels, at least a tenth of the code range apart.

    The paper fixes g at chosen codes; a fixed point where the bracket has few pools (the
    highlights of a night scene) leaves the rest of the curve loosely tied to it, and the
    smoothness term -- smaller for a smaller g -- then shrinks the loosely tied part towards
    zero (measured on a real bracket: g = 0.000 from code 20 to 140). Fixed where the pools
    are, the curve is held by its data; it is reported on the usual scale afterwards."""
    K = s.knots.n
    w = np.bincount(s.rows[:, 1], weights=np.diff(s.offsets).astype(np.float64), minlength=K)
    c = np.cumsum(w) / max(float(w.sum()), 1e-300)
    lo = int(np.searchsorted(c, 0.25))
    hi = int(np.searchsorted(c, 0.75))
    gap = max(1, int(round(0.1 * (K - 1))))
    lo = int(np.clip(lo, 1, K - 2 - gap))
    hi = int(np.clip(max(hi, lo + gap), lo + gap, K - 2))
    return lo, hi


def _sorted_rows(s: _Setup, resid: NDArray) -> NDArray[np.float64]:
    """The residuals sorted within each row (a compiled sort per row: sorting the whole pass at
    once, each row shifted into an interval of its own, cost 2-4 times as much on a 13-image
    bracket and was exact only to the shift's rounding), starting from the last pass's order
    (:func:`ccdcore.response.tsin.kernels.sort_rows`)."""
    resid = np.ascontiguousarray(resid, np.float64)
    if s.order is None or s.order.size != resid.size:
        s.order = np.full(resid.size, -1, np.int64)
    return sort_rows(resid, s.offsets, s.order)


def _second_differences(n: int) -> NDArray[np.float64]:
    D = np.zeros((max(n - 2, 0), n))
    r = np.arange(n - 2)
    D[r, r] = 1.0
    D[r, r + 1] = -2.0
    D[r, r + 2] = 1.0
    return D


def _pav(g: NDArray, weights: NDArray) -> NDArray[np.float64]:
    """Pool-adjacent-violators (sec. 3.2, step 9): the non-decreasing least-squares fit."""
    return np.asarray(isotonic_regression(g, weights=np.maximum(weights, 1e-12)).x, np.float64)


def _sqrt_err(v: float, e: float) -> tuple[float, float]:
    s = math.sqrt(max(v, 0.0))
    if s > 0:
        return s, e / (2 * s)
    return 0.0, math.sqrt(max(e, 0.0))

# ------------------------------------------------------------------------------ estimate ------
def estimate(data: BracketData, options: TsinOptions | None = None, *,
             progress: Progress | None = None) -> ChannelResponse:
    """The iterative calibration of sec. 3.2 on one channel of a bracket.

    Returns the response and noise on the reported scale, with the 1-sigma band of g (a
    sandwich estimate over blocks of pixels: one pixel's noise enters many pools' rows, and
    neighbours of an interpolated colour frame are correlated) and the noise terms' errors.
    ``progress(fraction, message)`` (a :class:`ccdcore.progress.Progress`) is called after
    every iteration. Raises :class:`CcdError` naming the bracket's first file when it cannot
    calibrate.
    """
    opts = options or TsinOptions()
    opts.check(data.files[0] if data.files else "bracket")
    data, sampled = _sample(data)
    st = _start(_setup(data, opts), opts)                      # steps 1-2
    # max_iter bounds the passes over the pools; a round that takes a kept pass again makes none
    while not st.done and (st.passes < opts.max_iter or st.reuse is not None):
        here = _next_pass(st)                                  # steps 3-5
        chi2 = float(np.sum(here.W * here.tm ** 2)) / max(1, here.tm.size - int(st.free.sum()))
        st.chi2 = chi2
        if st.restore:
            break                                 # the pass at the last accepted curve
        obj = 0.0
        if st.phase == 1:
            obj, ended = _guard(st, here, chi2)
            if ended:
                continue
        if st.phase == 2 and _guard_gains(st, here, chi2):
            continue
        if st.phase == 1:
            delta, rhs = _phase1_step(st, here)                # steps 6-7
            st.last = (obj, st.gk, delta, float(np.mean(np.abs(delta))),
                       float(delta[st.free] @ rhs[st.free]), here)
            gk_new = _advance(st, here, st.gk, delta, st.eta)  # steps 8-9
            st.eta = min(float(opts.eta), 2.0 * st.eta)
        else:
            delta = _phase2_step(st, here)                     # steps 6-7, gains and offsets
            gk_new = _advance(st, here, st.gk, delta, opts.eta)
        st.step = float(np.mean(np.abs(gk_new - st.gk)))
        st.gk = gk_new
        st.history.append({"iteration": st.it, "phase": st.phase, "step": st.step,
                           "a_step": st.a_step, "chi2": chi2, "pools": int(here.tm.size)})
        if progress is not None:
            progress(min(0.95, st.it / (4.0 if not st.fit_a else 12.0)),
                     f"iteration {st.it}: mean |Δg| {st.step:.1e}")
        _check_converged(st, chi2)                             # step 10
    return _result(st, sampled)


@dataclass(eq=False)
class _Fit:
    """The state of :func:`estimate`'s iteration, with what it holds fixed.

    With the gains a_k free: g first at the nominal times (phase 1), then g, the gains and the
    offsets together (phase 2); with offsets free g(z) and s g(z) + c fit alike, so g keeps both
    fixed points throughout (eq. 15's two fixed points)."""

    s: _Setup
    opts: TsinOptions
    t: NDArray                   # the nominal exposure times
    mad_c: float                 # eq. 12's c
    bw: float                    # the smoothness bandwidth, in knots
    D2: NDArray                  # second differences on the knots
    k_lo: int                    # the fit's fixed points (knots; see _anchors)
    k_hi: int
    k_rep: int                   # the reported scale's code (knot)
    free: NDArray                # the knots the fit moves
    gk: NDArray                  # g on the knots
    a: NDArray                   # the gains
    b: NDArray                   # the offsets
    fit_a: bool                  # white balance: the gains and offsets are fitted
    history: list[dict[str, float]] = field(default_factory=list)
    before: dict[str, Any] = field(default_factory=dict)   # the pool's errors at the start
    here: _PassState | None = None                          # the round's pass
    it: int = 0
    passes: int = 0
    phase: int = 1
    converged: bool = False
    done: bool = False                  # the iteration ends (converged, or flat)
    restore: bool = False               # one more round: the pass at the last accepted curve
    step: float = float("inf")          # mean |η Δg| of the last step
    a_step: float = 0.0                 # largest relative change of a gain in the last step
    kept: tuple | None = None           # the last accepted state of phase 2
    radius: float = 1.0                 # of the trust region, in MAX_GAIN_STEP
    flat: int = 0                       # accepted steps in a row that gained < FLAT
    last: tuple | None = None           # phase 1: (objective, g, Δg, ...) last accepted
    eta: float = 1.0                    # phase 1: the step, shortened on a worse fit
    reuse: _PassState | None = None     # a pass to take again instead of making it
    resolution: float = 0.0             # a tenth of g's statistical error (per knot)
    chi2: float = 1.0                   # the round's pools' χ²/dof

    @property
    def where(self) -> str:
        return self.s.data.files[0] if self.s.data.files else "bracket"


def _start(s: _Setup, opts: TsinOptions) -> _Fit:
    """Step 2: g the straight line through the fixed points, a_k the nominal exposures, b = 0."""
    data = s.data
    N = data.n_images
    L = int(data.levels)
    K = s.knots.n
    mad_c = float(opts.mad_factor) if opts.mad_factor else data.mad_factor
    t = np.asarray(data.t, np.float64)
    a = t.copy()                                  # step 2: the nominal exposures, b = 0
    b = np.zeros(N)
    z_lo, z_hi = reference_codes(L)
    k_rep = int(round(z_hi / s.knots.step))          # the reported scale's code
    # the fixed points of the fit, where the pools are (a departure: see _anchors)
    k_lo, k_hi = _anchors(s)
    gk = s.knots.codes / (L - 1.0)          # step 2: the straight line through the fixed points
    D2 = _second_differences(K)
    bw = opts.smoothness * (K - 1) / 255.0
    free = np.ones(K, bool)
    free[k_hi] = False
    free[k_lo] = True
    return _Fit(s, opts, t, mad_c, bw, D2, k_lo, k_hi, k_rep, free, gk, a, b,
                bool(opts.white_balance), eta=float(opts.eta))


def _next_pass(st: _Fit) -> _PassState:
    """Steps 3-5 of a round: radiance (eq. 9), errors (eq. 10), trimmed means and MAD sigmas
    (11-12); the pass also collects eq. 17's regressors: the last pass serves the noise fit and
    the band (it lies within one step below the tolerance of the result). A kept pass (at the
    last accepted curve) is taken again instead of making it."""
    st.it += 1
    if st.reuse is None:
        st.passes += 1
        here = _measure(st.s, st.a, st.b, st.gk, st.fit_a, st.mad_c, st.bw, st.D2)
        if st.it == 1:
            st.before = pick_pool(st.s, here.resid, st.gk)
    else:
        here, st.reuse = st.reuse, None    # the pass at the last accepted curve, kept
    st.here = here
    return here


def _advance(st: _Fit, p: _PassState, g_from: NDArray, delta: NDArray, eta: float) -> NDArray:
    """Steps 8-9: the update (eq. 16, g - η Δg with Δg = -delta), PAV (weighted by the pass
    ``p``'s normal matrix), the fixed points."""
    g_new = _pav(g_from + eta * delta, p.dg + p.lam)
    k_lo, k_hi = st.k_lo, st.k_hi
    if st.free[k_lo]:
        return g_new * g_from[k_hi] / g_new[k_hi]
    span = (g_from[k_hi] - g_from[k_lo]) / (g_new[k_hi] - g_new[k_lo])
    return g_from[k_lo] + (g_new - g_new[k_lo]) * span


def _guard(st: _Fit, p: _PassState, chi2: float) -> tuple[float, bool]:
    """Phase 1's guarded step (a departure, for real cameras: far from the solution the
    linearised step of eq. 15 can overshoot into a curve that fits worse): the step is accepted
    when the objective (the pools' χ² and the smoothness term) falls, else the last accepted
    curve is taken again with a shorter step. Returns the objective and whether the round ends
    here (a step taken back, or the fit at its minimum or flat)."""
    obj = float(np.sum(p.W * p.tm ** 2)) + p.lam * float(st.gk @ p.P_s @ st.gk)
    last = st.last
    if last is not None and obj > last[0]:
        st.history.append({"iteration": st.it, "phase": st.phase, "step": st.step,
                           "a_step": st.a_step, "chi2": chi2, "pools": int(p.tm.size),
                           "rejected": True})
        st.eta = _shorter_step(last[0], obj, last[4], st.eta)
        if st.eta < MIN_ETA or st.eta * last[3] < st.resolution:
            # no step along Δg improves the fit: it is at a minimum of the objective;
            # its pass is the one kept at the last accepted curve
            st.gk, st.reuse = last[1], last[5]
            if st.fit_a:
                st.phase, st.free[st.k_lo] = 2, False
                return obj, True
            st.restore, st.converged = True, True
            return obj, True
        gk_new = _advance(st, p, last[1], last[2], st.eta)
        st.step = float(np.mean(np.abs(gk_new - last[1])))
        st.gk = gk_new
        return obj, True
    st.flat = st.flat + 1 if last is not None and last[0] - obj < FLAT * last[0] else 0
    if st.flat >= 3 and not st.fit_a:
        st.converged = st.done = True            # the fit no longer improves: flat
        return obj, True
    return obj, False


def _guard_gains(st: _Fit, p: _PassState, chi2: float) -> bool:
    """Phase 2's guard: a step of the gains that made the fit worse (the pools' χ² and the
    a-priori bound) is taken back and the next one shortened (near a nearly saturated image the
    linearised step can mislead). True when the round ends here (taken back, or flat)."""
    opts = st.opts
    cost = float(np.sum(p.W * p.tm ** 2))
    if opts.gain_prior:
        cost += float(np.sum((np.log(st.a / st.t) / _prior_width(st, chi2)) ** 2))
    kept = st.kept
    if kept is not None and cost > kept[0]:
        _, _, st.gk, st.a, st.b, st.reuse = kept
        st.radius *= 0.25
        st.history.append({"iteration": st.it, "phase": st.phase, "step": st.step,
                           "a_step": st.a_step, "chi2": chi2, "pools": int(p.tm.size),
                           "rejected": True})
        if st.radius < 1e-3:
            st.converged = st.restore = True     # no step of any length improves the fit
        return True                              # from the kept state and its pass
    # a step whose gain is below the noise of the χ² itself (its value per degree of freedom:
    # one more unit of misfit in one row) is no improvement
    st.flat = st.flat + 1 if kept is not None and kept[0] - cost < max(FLAT * kept[0], chi2) \
        else 0
    if st.flat >= 3:
        st.converged = st.done = True            # the fit no longer improves: flat
        return True
    st.kept = (cost, chi2, st.gk, st.a, st.b, p)
    return False


def _phase1_step(st: _Fit, p: _PassState) -> tuple[NDArray, NDArray]:
    """Steps 6-7 at the nominal gains: eq. 15's weighted least squares for the update of the
    free knots, ``(delta, rhs)``; sets the resolution (a tenth of g's statistical error)."""
    K, free = st.s.knots.n, st.free
    rhs = -p.g_gradient() - p.lam * (p.P_s @ st.gk)
    delta = np.zeros(K)
    Hf = p.Hs[np.ix_(free, free)]
    try:
        delta[free] = np.linalg.solve(Hf, rhs[free])
        st.resolution = RESOLUTION * float(np.mean(np.sqrt(np.maximum(
            np.diag(np.linalg.inv(Hf)), 0.0))))
    except np.linalg.LinAlgError:
        delta[free] = np.linalg.lstsq(Hf, rhs[free], rcond=None)[0]
    return delta, rhs


def _prior_width(st: _Fit, chi2: float) -> float:
    """The a-priori bound's width in the units of the pools' actual spread: the pools' χ² counts
    the misfit in units of their statistical errors, and where the model does not fit a real
    camera (χ²/dof well above 1: its toe, its JPEG) those units are too small, and an image the
    bracket barely sees (a night scene's shortest) chased the misfit with its gain. Scaled by
    the square root of χ²/dof (no change where the model fits)."""
    return float(st.opts.gain_prior) / math.sqrt(max(1.0, chi2))


def _phase2_step(st: _Fit, p: _PassState) -> NDArray:
    """Steps 6-8 of the white-balance fit: one joint step of g, the gains and the offsets in
    their gauge (:func:`ccdcore.response.tsin.gauge.joint_step`); the gains and offsets are
    moved, the update of g returned."""
    K = st.s.knots.n
    Hfull = p.JWfull.T @ p.Jm
    Hfull[:K, :K] += p.lam * p.P_s
    grad = -(p.Jm.T @ (p.W * p.tm))
    grad[:K] -= p.lam * (p.P_s @ st.gk)
    delta, a_new, st.b, st.radius = joint_step(Hfull, grad, st.free, st.a, st.b, st.t,
                                               _prior_width(st, st.chi2), st.opts.eta,
                                               st.radius,
                                               st.where)
    st.a_step = float(np.max(np.abs(a_new / st.a - 1.0)))
    st.a = a_new
    return delta


def _check_converged(st: _Fit, chi2: float) -> None:
    """Step 10 after an accepted step: converged below the tolerance; with white balance, the
    move from phase 1 to phase 2."""
    opts = st.opts
    if not st.fit_a:
        if st.step < max(opts.tol, st.resolution):  # step 10
            st.converged = st.done = True
        return
    if st.phase == 1:
        # g at the nominal times only needs to come near: once it has, or once its fit
        # stops improving (gains far off the nominal times then pull it away), the gains
        # are freed, and g(z_lo) is held where it is (with offsets free, g and s g + c fit
        # alike: both fixed points)
        worse = len(st.history) > 1 and chi2 > st.history[-2]["chi2"]
        if st.step < max(opts.tol, 1e-4) or worse:
            st.phase = 2
            st.free[st.k_lo] = False
        return
    if st.step < opts.tol and st.a_step < opts.tol:
        st.converged = st.done = True


def _result(st: _Fit, sampled: int) -> ChannelResponse:
    """The band, the noise terms and the pool's errors from the last pass, on the reported
    scale."""
    s, opts, here, data = st.s, st.opts, st.here, st.s.data
    N, L, K = data.n_images, int(data.levels), s.knots.n
    fit_a, t, a, history = st.fit_a, st.t, st.a, st.history
    n = np.diff(s.offsets).astype(np.float64)
    tm, sig, se = here.tm, here.sig, here.se
    after = pick_pool(s, here.resid, st.gk, like=st.before)
    gk, b, err, a_err, b_err = band(here, s.offsets, st.gk, a, st.b, t, st.free, st.k_rep,
                                    fit_a and here.J.shape[1] == K + 2 * N, int(opts.groups),
                                    TRIM)
    theta_n, theta_e, _ = noise_fit(here.X / n[:, None], sig, n)
    codes = np.arange(L, dtype=np.float64)
    # the reported scale: g(z_hi) = z_hi / (L - 1); a, b follow
    g_rep, sc, c0 = normalize(np.interp(codes, s.knots.codes, gk), L)
    ss, ss_e = _sqrt_err(theta_n[0] * sc, theta_e[0] * sc)
    s1, s1_e = _sqrt_err(theta_n[1] * sc * sc, theta_e[1] * sc * sc)
    s2, s2_e = _sqrt_err(theta_n[2], theta_e[2])
    chi2_last = history[-1]["chi2"] if history else float("nan")
    # convergence means the fit moved and stopped improving: a curve still at its straight
    # starting line has not converged, whatever the steps said (measured on real brackets
    # whose listed exposures were wrong: every step was taken back and the line reported)
    moved = bool(np.max(np.abs(g_rep - codes / (L - 1.0))) > START_TOLERANCE)
    converged = bool(st.converged and moved)
    notes = estimate_notes(opts, data, s, sampled=sampled, converged=st.converged,
                            step=st.step, chi2=chi2_last, theta=theta_n)
    if not moved:
        notes.append("the fit never left its straight starting line g = z/(levels - 1): every "
                     "step made the fit worse, so the curve is not an estimate")
    pools = PoolTable(s.rows[:, 0].copy(), s.knots.codes[s.rows[:, 1]], s.rows[:, 2].copy(),
                      n.astype(np.int64), tm * sc, sig * sc, se * sc)
    before = st.before
    return ChannelResponse(
        channel=data.channel, method="tsin", g=g_rep,
        g_err=np.interp(codes, s.knots.codes, err) * sc, a=a * sc if fit_a else a,
        a_err=a_err * sc, b=b * sc + c0 if fit_a else b, b_err=b_err * sc, t=t, sigma_s=ss,
        sigma_c1=s1, sigma_c2=s2, sigma_s_err=ss_e,
        sigma_c1_err=s1_e, sigma_c2_err=s2_e, iterations=st.it, converged=converged,
        white_balance=fit_a, pools=pools, history=tuple(history),
        pool_errors={"pool_image": before["pool_image"], "code": before["code"],
                     "predicted_image": before["predicted_image"], "before": before["values"],
                     "after": after["values"]},
        notes=tuple(notes))


@dataclass(eq=False)
class _PassState:
    """One pass at (a, b, g) and what steps 6-7 make of it (:func:`_measure`)."""

    J: NDArray            # rows' summed linearisations (eq. 13), in g (and a, b)
    X: NDArray            # rows' eq. 17 regressors
    resid: NDArray        # every prediction error (eq. 10), by row
    egrp: NDArray         # the block of each error's pixel (for the sandwich)
    tm: NDArray           # rows' trimmed means (eq. 11)
    sig: NDArray          # rows' MAD sigmas (eq. 12)
    se: NDArray           # the trimmed means' standard errors
    lo: NDArray           # winsorising limits
    hi: NDArray
    wmean: NDArray        # winsorised means
    n: NDArray            # the rows' pixels
    W: NDArray            # rows' weights (1 / se², floored)
    H: NDArray            # eq. 15's normal matrix in g
    dg: NDArray           # its diagonal
    lam: float            # the smoothness weight
    P_s: NDArray          # the smoothness relative to the slope (:func:`_smoothness`)
    Hs: NDArray           # H + lam P_s

    @cached_property
    def Jm(self) -> NDArray:
        """J per pixel of the row (eq. 13's mean); made when asked (white balance, the band)."""
        return self.J / self.n[:, None]

    @cached_property
    def JWfull(self) -> NDArray:
        """Jm W."""
        return self.Jm * self.W[:, None]

    @property
    def JW(self) -> NDArray:
        """Its g part."""
        return self.JWfull[:, :self.H.shape[0]]

    def g_gradient(self) -> NDArray:
        """Jm[:, :K]ᵀ (W tm) without forming Jm: eq. 15's data term of the right-hand side."""
        K = self.H.shape[0]
        return self.J[:, :K].T @ (self.W * self.tm / self.n)


def _measure(s: _Setup, a: NDArray, b: NDArray, gk: NDArray, fit_a: bool, mad_c: float,
             bw: float, D2: NDArray) -> _PassState:
    """Steps 3-7's inputs at (a, b, g): radiance (eq. 9 with eq. 18's weights), errors (eq. 10),
    trimmed means and MAD sigmas (eqs. 11-12), eq. 13 per pool, eq. 15's normal matrix with
    the smoothness term; the pass also collects eq. 17's regressors (the last pass serves the
    noise fit and the band)."""
    L, K = int(s.data.levels), s.knots.n
    n = np.diff(s.offsets).astype(np.float64)
    J, X, resid, egrp = _pass(s, a, b, gk, want_noise=True, with_a=fit_a,
                              wcode=_eq18_codes(s, gk))
    tm, sig, se, lo, hi, wmean = row_stats(_sorted_rows(s, resid), s.offsets, TRIM, mad_c)
    # a pool's mean error cannot be known better than its codes' quantisation (1/12 DN²) at a
    # tenth of the curve's mean slope: where a step flattened g, the errors there vanish with
    # the slope and their weights would grow without bound
    floor = 0.1 * max(float(gk[-1] - gk[0]), 1e-12) / (L - 1) / np.sqrt(12.0 * n)
    W = 1.0 / np.maximum(se, floor) ** 2
    # eq. 15's normal matrix Σ_rows W (J/n)(J/n)ᵀ as one symmetric product of the rows scaled by
    # √W / n (half the work of forming J/n and (J/n) W apart, and no copies of them)
    Js = J[:, :K] * (np.sqrt(W) / n)[:, None]
    H = Js.T @ Js
    del Js
    dg = np.diag(H)
    lam = bw ** 4 * float(np.median(dg[dg > 0])) if np.any(dg > 0) else 0.0
    P_s = _smoothness(gk, D2)
    return _PassState(J, X, resid, egrp, tm, sig, se, lo, hi, wmean, n, W, H, dg,
                      lam, P_s, H + lam * P_s)


def _shorter_step(obj0: float, obj_t: float, gain: float, eta_t: float) -> float:
    """The step to try after a step ``eta_t`` raised the objective from ``obj0`` to ``obj_t``:
    the minimum of the parabola through both with eq. 15's slope at the accepted curve.

    Eq. 15's model of the objective along the update δ is obj0 - 2 η q + η² q with
    q = δᵀ H δ = ``gain`` (the update solves H δ = rhs): its slope at η = 0 is -2 q. With the
    measured value at ``eta_t`` the parabola obj0 - 2 q η + c η² gives η* = q / c, kept within
    [0.1, 0.5] of ``eta_t`` (a safeguarded quadratic backtrack; halving alone took four passes
    to find that no step helps where the trimmed means wobble near the minimum)."""
    c = (obj_t - obj0 + 2.0 * gain * eta_t) / (eta_t * eta_t)
    if not (gain > 0.0 and c > 0.0 and math.isfinite(c)):
        return 0.5 * eta_t
    return float(min(max(gain / c, 0.1 * eta_t), 0.5 * eta_t))


def _smoothness(gk: NDArray, D2: NDArray) -> NDArray[np.float64]:
    """The smoothness of g relative to its slope, Σ (g''/g')² (scale-free; see the module
    notes), as a quadratic form: each second difference weighted by (median slope / slope)²
    at the current g; a flat run does not stiffen it without bound (:data:`SLOPE_FLOOR`)."""
    gpk = np.gradient(gk)[1:-1]
    gmed = float(np.median(gpk[gpk > 0])) if np.any(gpk > 0) else 1.0
    gpk = np.maximum(gpk, SLOPE_FLOOR * gmed)
    return D2.T @ (((gmed / gpk) ** 2)[:, None] * D2)


def noise_terms(data: BracketData, g: ArrayLike, a: ArrayLike | None = None,
                b: ArrayLike | None = None, *, options: TsinOptions | None = None
                ) -> dict[str, float]:
    """σ_s, σ_c1, σ_c2 (eq. 17) and their errors for a given response (any method's ``g`` on
    every code; ``a`` = nominal times and ``b`` = 0 when not given), from the same pools as
    :func:`estimate`."""
    opts = options or TsinOptions()
    data, _ = _sample(data)
    s = _setup(data, opts)
    g = np.asarray(g, np.float64)
    gk = np.interp(s.knots.codes, np.arange(g.size, dtype=np.float64), g)
    a = np.asarray(data.t if a is None else a, np.float64)
    b = np.zeros(data.n_images) if b is None else np.asarray(b, np.float64)
    mad_c = float(opts.mad_factor) if opts.mad_factor else data.mad_factor
    _, X, resid, _ = _pass(s, a, b, gk, want_noise=True)
    n = np.diff(s.offsets).astype(np.float64)
    _, sig, _, _, _, _ = row_stats(_sorted_rows(s, resid), s.offsets, TRIM, mad_c)
    th, te, chi2 = noise_fit(X / n[:, None], sig, n)
    ss, ss_e = _sqrt_err(th[0], te[0])
    s1, s1_e = _sqrt_err(th[1], te[1])
    s2, s2_e = _sqrt_err(th[2], te[2])
    return {"sigma_s": ss, "sigma_c1": s1, "sigma_c2": s2, "sigma_s_err": ss_e,
            "sigma_c1_err": s1_e, "sigma_c2_err": s2_e, "chi2": chi2}

