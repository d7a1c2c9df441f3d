"""Classic inverse-response estimators from an exposure bracket: Debevec & Malik (1997),
Robertson, Borman & Stevenson (2003) and Mitsunaga & Nayar (1999).

Each takes one channel of a bracket (:class:`ccdcore.response.brackets.BracketData`: codes
``z_kj`` of pixel ``j`` in image ``k``, nominal exposure times ``t_k``) and returns the inverse
response g at every code ``0 .. levels - 1`` on the reported scale of
:mod:`ccdcore.response.scale` (``g(z_hi) = z_hi / (levels - 1)``, no offset). Unlike Tsin et al.
(2001, sec. 3.2) they take the nominal exposure times as the true exposures
(no white-balance scale or offset; Mitsunaga & Nayar refine the ratios only).

Methods
-------
Debevec & Malik (1997), "Recovering high dynamic range radiance maps from photographs",
SIGGRAPH 97, sec. 2.1 and the appendix (``gsolve.m``)
    The log response ``g(z) = ln E_j + ln t_k`` at every code, and the log radiance ``ln E_j``
    of every sampled pixel, minimise the weighted objective::

        O = sum_jk {w(z_kj) [g(z_kj) - ln E_j - ln t_k]}^2 + lambda sum_z [w(z) g''(z)]^2

    with the hat weights ``w(z) = z - z_min`` for ``z <= (z_min + z_max)/2``, else
    ``z_max - z`` (``z_min = 0``, ``z_max = levels - 1``; scaled to a peak of 1, which changes
    nothing), ``g''(z) = g(z-1) - 2 g(z) + g(z+1)`` and the unit fixed by ``g(z_mid) = 0``.
    ``smoothness`` is gsolve's row factor ``l`` (``lambda = l^2``), taken relative to the data:
    the smoothness rows are multiplied by the square root of the mean number of observations per
    8-bit code step, and the second differences of deep codes' knots are scaled to those of 256
    codes, so that one value means the same whatever the number of pixels sampled or the bit
    depth (gsolve's ``l`` with about one observation per code). The linear least squares is
    solved exactly by eliminating the ``ln E_j`` (each is the weighted mean of its pixel's
    ``g(z_kj) - ln t_k``, the paper's radiance formula): normal equations in g alone, at most 1024
    unknowns (SuperLU), summed directly from the observations (bincounts, and one sparse
    product over the pixels for the eliminated radiances) without the paper's tall matrix.
    The pixels are a systematic sample (``samples``, shuffled by ``seed``)
    of the pixels sorted by their code in the middle exposure, so every band of codes keeps its
    share, topped up with one pixel for every code with data the sample missed: every code with
    data is in the system. (Equal shares per band over-weight the rare dark and bright pixels:
    on the tsin01 protocol that raised the error by half at 20,000 pixels and doubled it at
    1,000.) With the default 20,000 pixels a channel of a 0.4-Mpixel, 10-image bracket takes
    about 0.07 s, mostly checking and sampling the bracket; more pixels did not predict the
    real taipei bracket better (sec. 4.2 agreement 4.73 DN at 20,000 and at 50,000 pixels).
    The log curve is exponentiated.
Robertson, Borman & Stevenson (2003), "Estimation-theoretic approach to dynamic range
enhancement using multiple exposures", J. Electronic Imaging 12(2), 219-228
    Maximum likelihood by alternation: the exposure of every pixel given the response::

        x_j = sum_k w(z_kj) t_k I(z_kj) / sum_k w(z_kj) t_k^2

    then the response at every code given the exposures, the mean of ``t_k x_j`` over the
    observations at that code (``I(m) = mean over {(k, j): z_kj = m} of t_k x_j``), with the
    Gaussian-like weights ``w(z) = exp(-4 (z - c)^2 / c^2)``, ``c = (levels - 1)/2``. I is
    normalised to 1 at the middle code (the code with data nearest it) every iteration. Both
    steps are linear in I, so one iteration is a product with a fixed G x G matrix, built once
    from every pixel usable in two images (``C = diag(1/n_m) U^T diag(1 / sum_k w t_k^2) V``; at
    code resolution ``w`` depends on the column's code only, and ``U^T diag(.) U`` is a
    symmetric joint histogram of the codes of every two images of a pixel: one weighted bincount
    per pair of images; for deep codes' knots, a sparse product). It starts from the straight
    line and stops when the relative change of I (largest change over largest value) falls below
    ``tol``, or after ``max_iter`` iterations. Pixels with fewer than two usable observations
    carry no information and are left out. Early iterations can lie closer to the truth than the
    converged estimate (the converged I at a code is the mean exposure of the observations at
    that code, pulled wherever the radiances thin out); the result is the converged one.
Mitsunaga & Nayar (1999), "Radiometric self calibration", CVPR 99
    Polynomial response ``g(M) = sum_{n=0}^{D} c_n M^n`` of the normalised code
    ``M = z / (levels - 1)``, scaled so that ``g(1) = sum_n c_n = 1``, minimising over
    consecutive images ``q, q+1`` and the pixels ``p`` usable in both::

        eps = sum_q sum_p [g(M_p,q) - R_q,q+1 g(M_p,q+1)]^2

    with the exposure ratios ``R_q,q+1`` first the nominal ``t_q / t_q+1``, then refined as the
    mean over pixels of ``g(M_p,q) / g(M_p,q+1)``, g fitted again, until g changes by less than
    ``tol`` (largest change over the codes with data). Both sums only depend on the pair of
    codes ``(z_p,q, z_p,q+1)``: they are computed from the joint histogram of the codes of every
    two consecutive images, built once (the distinct code pairs and their counts), so that each
    fit and refinement costs the number of distinct pairs, not of pixels. The degree is the
    ``D`` in ``1 .. max_degree`` with the smallest final error. Two safeguards, both needed on
    noisy data:

    * The scale. ``eps`` is quadratic in the ``c_n``: minimised under the single constraint
      ``g(1) = 1`` it rewards any curve whose value at M = 1 (a clipped code, no data) is large
      against the rest, and a degree-8 fit of the tsin01 protocol put a spike of +0.16 there
      (RMS error 0.018). Here the ``c_n`` minimise ``eps / sum_q sum_p [g(M_p,q)^2 +
      R^2 g(M_p,q+1)^2]`` (the error relative to the data's energy, a generalised eigenvalue
      problem in the shifted Legendre basis, well conditioned), and that curve is scaled to
      ``g(1) = 1``; this ratio is the "error" compared between iterations and degrees.
    * The exponent ambiguity (the paper's own caveat; Grossberg & Nayar 2003): with free ratios,
      ``g^u`` with ratios ``R^u`` explains the same data for any ``u``, and the refinement can
      drift to the trivial ``g = M^u``, ``u -> 0``, all ratios 1. Every refined set of ratios is
      raised to the common power that keeps their product equal to the nominal one -- that
      common power is exactly the ambiguity, the individual ratios still adjust --; the ratios
      are estimated from the pixels with ``g(M_p,q+1) >= 0.05`` (the ratio of near-zero values
      is noise); only the ratios of image pairs with at least 100 common pixels are refined (next
      to saturation a handful of pixels gives a ratio of noise, which the common power would
      spread over all the others); and the refinement stops, keeping the previous g and ratios,
      as soon as the error stops decreasing. With exact nominal times (tsin01 without white
      balance) the first refinement already raises the error and the nominal ratios are kept;
      with 5 % errors in the exposures (white balance, no offsets) refinement lowered the RMS
      error of g by 30 to 60 % (three seeds).

Public objects
--------------
ClassicFit
    Frozen result: g at every code on the reported scale, iterations, convergence, notes in plain
    words and the method's own numbers (``extra``).
debevec(data, smoothness=..., samples=..., seed=0)
    Debevec & Malik 1997 (gsolve) on one channel.
robertson(data, max_iter=50, tol=1e-6)
    Robertson, Borman & Stevenson 2003 on one channel.
mitsunaga_nayar(data, max_degree=..., max_iter=..., tol=...)
    Mitsunaga & Nayar 1999 on one channel.
MAX_NODES
    Most codes at which g is estimated (deeper codes: knots, linear in between).
DEBEVEC_SMOOTHNESS, DEBEVEC_SAMPLES, MN_MAX_DEGREE, MN_MAX_ITER, MN_TOL, MN_RATIO_FLOOR,
MN_MIN_PAIRS
    Defaults of the methods' settings.

The bracket check and the finishing of every curve (codes without data, monotonicity, the
reported scale) are shared with :mod:`ccdcore.response.classic_common`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
from numpy.polynomial import legendre as npleg
from numpy.polynomial import polynomial as nppoly
from numpy.typing import NDArray
from scipy import sparse
from scipy.linalg import eigh
from scipy.sparse.linalg import splu

from ..errors import CcdError
from .brackets import BracketData
from .classic_common import Checked, check_bracket, code_dtype, finish_curve
from .scale import MAX_NODES, Knots

__all__ = ["ClassicFit", "debevec", "robertson", "mitsunaga_nayar", "MAX_NODES",
           "DEBEVEC_SMOOTHNESS", "DEBEVEC_SAMPLES", "MN_MAX_DEGREE", "MN_MAX_ITER", "MN_TOL",
           "MN_RATIO_FLOOR", "MN_MIN_PAIRS"]

#: Debevec & Malik: lambda, gsolve's row factor ``l`` for one observation per code
DEBEVEC_SMOOTHNESS = 20.0
#: Debevec & Malik: pixels sampled into the linear system
DEBEVEC_SAMPLES = 20000
#: Mitsunaga & Nayar: highest polynomial degree tried
MN_MAX_DEGREE = 8
#: Mitsunaga & Nayar: most ratio refinements per degree
MN_MAX_ITER = 20
#: Mitsunaga & Nayar: stop refining when g changes by less than this (largest, 0..1 scale)
MN_TOL = 1e-5
#: Mitsunaga & Nayar: the ratios are estimated from pixels with g(M_q+1) at least this
MN_RATIO_FLOOR = 0.05
#: Mitsunaga & Nayar: a ratio is refined only when its pair of images has this many pixels
MN_MIN_PAIRS = 100


@dataclass(frozen=True, eq=False)
class ClassicFit:
    """One channel's inverse response by a classic method.

    Attributes
    ----------
    g
        ``(levels,)`` g at every code ``0 .. levels - 1``, non-decreasing, on the reported scale
        (:func:`ccdcore.response.scale.normalize`, offset off: ``g(z_hi) = z_hi/(levels-1)``).
    iterations
        Iterations run (Debevec: 1, a direct solve; Mitsunaga & Nayar: the chosen degree's ratio
        refinements).
    converged
        The stopping rule was met (always True for Debevec's direct solve).
    notes
        Remarks in plain words (codes extrapolated, monotonicity enforced, sample size, ...).
    extra
        The method's own numbers (Debevec: smoothness, samples, fixed code; Robertson: the final
        relative change; Mitsunaga & Nayar: degree, monomial coefficients, refined ratios, the
        error of every degree).
    """

    g: NDArray[np.float64]
    iterations: int
    converged: bool
    notes: tuple[str, ...] = ()
    extra: dict = field(default_factory=dict)


# ------------------------------------------------------------------------------ helpers ------
def _mid_node(node_counts: NDArray, centre: float) -> int:
    """The knot with data nearest ``centre`` (a knot index)."""
    have = np.flatnonzero(node_counts > 0)
    return int(have[np.argmin(np.abs(have - centre))])


# ------------------------------------------------------------------------------ Debevec ------
def _stratified_sample(chk: Checked, samples: int, seed: int) -> NDArray[np.int64]:
    """Pixel columns for Debevec's system: a systematic sample of the pixels sorted by their
    code in the middle exposure (shuffled within a code by ``seed``), so every stratum of codes
    gets its share in proportion to its pixels, topped up with one pixel for every code with
    data the sample missed. Only pixels usable in two images are candidates."""
    N, P = chk.z.shape
    usable = chk.n_valid >= 2
    cand = np.flatnonzero(usable)
    if samples >= cand.size:
        return cand
    rng = np.random.default_rng(seed)
    # the code of every pixel in its usable image nearest the middle of the bracket (the
    # lower one of two as near): rows written from the farthest to the nearest
    mid = (N - 1) / 2.0
    nearest_first = sorted(range(N), key=lambda k: (abs(k - mid), k))
    key = np.zeros(P, np.uint16 if chk.levels <= 2 ** 16 else np.int64)
    for k in reversed(nearest_first):
        np.copyto(key, chk.z[k], where=chk.valid[k], casting="unsafe")
    key = key[cand]
    perm = rng.permutation(cand.size)
    order = perm[np.argsort(key[perm], kind="stable")]          # a radix sort on 16 bits
    step = cand.size / samples
    pos = np.floor((np.arange(samples) + rng.random()) * step).astype(np.int64)
    pick = np.sort(cand[order[np.minimum(pos, cand.size - 1)]])
    # every code with data in the system: one pixel for each code the sample misses (the
    # first usable candidate in image order, then pixel order)
    have = np.zeros(chk.levels, bool)
    zp, vp = chk.z[:, pick], chk.valid[:, pick]
    have[zp[vp]] = True
    missing = (chk.counts > 0) & ~have
    if missing.any():
        extra = []
        for k in range(N):
            if not np.any(chk.row_counts[k, missing]):       # no such code in this image
                continue
            hit = np.flatnonzero(np.take(missing, chk.z[k]) & chk.valid[k] & usable)
            if hit.size == 0:
                continue
            codes, first = np.unique(chk.z[k, hit], return_index=True)
            extra.append(hit[first])
            missing[codes] = False
            if not missing.any():
                break
        if extra:
            pick = np.unique(np.concatenate([pick] + extra))
    return pick


def debevec(data: BracketData, *, smoothness: float = DEBEVEC_SMOOTHNESS,
            samples: int = DEBEVEC_SAMPLES, seed: int = 0) -> ClassicFit:
    """Debevec & Malik (1997): the weighted, smoothed least squares of sec. 2.1 (gsolve) on a
    sample of pixels, exponentiated.

    Parameters
    ----------
    data
        One channel of a bracket; only its usable observations are read.
    smoothness
        gsolve's ``l`` (``lambda = l^2``) for about one observation per 8-bit code; the
        smoothness rows are scaled by the square root of the mean observations per code, so the
        default suits any sample size and bit depth (see the module notes).
    samples
        Pixels sampled (a systematic sample over the middle-exposure code, shuffled by
        ``seed``), topped up so every code with data is in the system; all the pixels usable in
        two images when there are fewer.
    seed
        Seed of the sample.

    Returns
    -------
    ClassicFit
        ``extra``: ``smoothness``, ``samples`` (pixels used), ``observations``, ``fixed_code``
        (the code with ``ln g = 0`` in the solve).
    """
    method = "Debevec & Malik"
    chk = check_bracket(data, method)
    if not (np.isfinite(smoothness) and smoothness >= 0):
        raise CcdError("smoothness", f"must be >= 0, got {smoothness}")
    if int(samples) < 1:
        raise CcdError("samples", f"must be >= 1, got {samples}")
    levels = chk.levels
    grid = Knots(levels)
    G = grid.n
    cols = _stratified_sample(chk, int(samples), int(seed))
    z = chk.z[:, cols]
    v = chk.valid[:, cols]
    half = (levels - 1) / 2.0
    zf = z.astype(np.float64)
    w = np.where(zf <= half, zf, (levels - 1) - zf) / half          # hat, peak 1
    w = np.where(v, w, 0.0)
    w2 = w * w
    W = w2.sum(axis=0)
    keep = (np.count_nonzero(w2 > 0, axis=0) >= 2) & (W > 0)
    if not keep.any():
        raise CcdError(chk.where, f"{method}: no pixel has two observations of non-zero weight")
    z, w2, W = z[:, keep], w2[:, keep], W[keep]
    S = z.shape[1]
    lnt = np.log(chk.t)[:, None]
    # the normal equations of gsolve's rows with the ln E_j eliminated, assembled from sums
    # over the observations (bincount): K = Bw^T Bw - Bt^T Bt, rhs = Bw^T y - Bt^T r, with
    # Bw the data rows (w per observation and knot term), Bt[j] = sum_k w^2 e_z / sqrt(W_j)
    terms = grid.terms(z)
    idx = np.concatenate([i for i, _ in terms]).astype(np.intp)      # (terms * N, S)
    coef = np.concatenate([f for _, f in terms])
    T = len(terms)
    w2c = np.tile(w2, (T, 1)) * coef                                 # w^2 x knot share
    n_obs = int(np.count_nonzero(w2))
    node_w = np.bincount(idx.ravel(), (w2c * coef).ravel(), minlength=G)     # diag(Bw^T Bw)
    if T == 1:
        K = np.diag(node_w)
    else:
        K = np.zeros(G * G)
        for ia, fa in terms:
            for ib, fb in terms:
                K += np.bincount((ia * G + ib).ravel(), (w2 * fa * fb).ravel(), minlength=G * G)
        K = K.reshape(G, G)
    bt = w2c / np.sqrt(W)
    K -= _pixel_gram(idx, bt, bt, G)
    r = (w2 * lnt).sum(axis=0) / W                                   # (sum_k w^2 ln t) / W_j
    rhs = np.bincount(idx.ravel(), (w2c * (np.tile(lnt, (T, 1)) - r)).ravel(), minlength=G)
    # knots the data reach, and the smoothness rows inside them
    have = np.flatnonzero(node_w > 0)
    a, b = int(have[0]), int(have[-1])
    # lambda relative to the data: per 8-bit code step (1/255 of the range) with data, and the
    # knots' second differences scaled to those of 256 codes (the sum of squared second
    # differences over G knots is ~ (G - 1)^-3 times the integral of g''^2)
    span8 = max(int(np.count_nonzero(chk.counts)), 1) * 255.0 / (levels - 1)
    lam = float(smoothness) * np.sqrt(n_obs / span8 * ((G - 1) / 255.0) ** 3)
    inner = np.arange(a + 1, b)
    if inner.size and lam > 0:
        zk = grid.codes[inner]
        wk = np.where(zk <= half, zk, (levels - 1) - zk) / half
        rows = np.repeat(np.arange(inner.size), 3)
        colz = np.stack([inner - 1, inner, inner + 1], axis=1).ravel()
        vals = (lam * wk[:, None] * np.array([1.0, -2.0, 1.0])[None, :]).ravel()
        D = sparse.csr_matrix((vals, (rows, colz)), shape=(inner.size, G))
        K += (D.T @ D).toarray()
    active = np.arange(a, b + 1)
    fixed = _mid_node(node_w, ((levels - 1) / 2.0) / grid.step)
    free = active[active != fixed]
    A = K[np.ix_(free, free)]
    bvec = rhs[free]
    sol = _solve(A, bvec)
    lng = np.full(G, np.nan)
    lng[free] = sol
    lng[fixed] = 0.0
    known_nodes = np.zeros(G, bool)
    known_nodes[active] = True
    g_nodes = np.exp(lng)
    notes = [f"{S} pixels sampled of {chk.z.shape[1]} ({n_obs} observations)"]
    g, known = _to_codes(grid, g_nodes, known_nodes)
    g = finish_curve(g, known, chk.counts, levels, notes, chk.where, method)
    extra = {"smoothness": float(smoothness), "samples": int(S), "observations": n_obs,
             "fixed_code": int(round(grid.codes[fixed])), "knots": int(G)}
    return ClassicFit(g, 1, True, tuple(notes), extra)


def _pixel_gram(idx: NDArray[np.intp], u: NDArray, v: NDArray, G: int) -> NDArray[np.float64]:
    """``U^T V = sum_j u_j v_j^T`` over the pixels ``j`` (columns), with ``u_j = sum_r u[r, j]
    e_idx[r, j]`` and ``v_j`` alike (rows ``r``: the images, times the knot terms): the G x G
    sums of the products of every two observations of one pixel. ``U`` and ``V`` are built
    directly in CSR form (``rows`` entries per pixel, zeros included: no sorting, no COO)."""
    R, S = idx.shape
    indptr = np.arange(0, R * S + 1, R)
    cols = np.ascontiguousarray(idx.T).ravel()
    U = sparse.csr_matrix((np.ascontiguousarray(u.T).ravel(), cols, indptr), shape=(S, G))
    V = U if v is u else sparse.csr_matrix((np.ascontiguousarray(v.T).ravel(), cols, indptr),
                                           shape=(S, G))
    return (U.T @ V).toarray()


def _solve(A: NDArray, b: NDArray) -> NDArray[np.float64]:
    """``A x = b`` by SuperLU (a multi-threaded LAPACK call on a busy 2-core machine can take a
    hundred times longer than the work); least squares when ``A`` is singular."""
    try:
        x = splu(sparse.csc_matrix(A)).solve(b)
        if np.all(np.isfinite(x)):
            return x
    except RuntimeError:
        pass
    return np.linalg.lstsq(A, b, rcond=None)[0]


def _to_codes(grid: Knots, g_nodes: NDArray, known_nodes: NDArray[np.bool_]
              ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Knot values to every code; a code is known when it lies between known knots."""
    if grid.identity:
        return np.where(known_nodes, g_nodes, np.nan), known_nodes.copy()
    kn = np.flatnonzero(known_nodes)
    codes = np.arange(grid.levels)
    g = np.interp(codes, grid.codes[kn], g_nodes[kn])
    known = (codes >= grid.codes[kn[0]]) & (codes <= grid.codes[kn[-1]])
    return g, known


# ---------------------------------------------------------------------------- Robertson ------
def _trace_gram(zi: NDArray, t: NDArray, weights: NDArray, levels: int) -> NDArray[np.float64]:
    """``H[m, m'] = sum_j weights_j sum_{k, k'} t_k t_k' [z_kj = m] [z_k'j = m']`` over the
    usable observations (``zi``: the codes, ``levels`` where unusable): the products of every
    two observations of one pixel, summed pixel by pixel at code resolution, in one pass over
    the pixels (:func:`_trace_gram_kernel` releases the GIL: the channels of a bracket run side
    by side). H is symmetric: the pairs ``k < k'`` are summed once."""
    off, diag = _trace_gram_kernel(np.ascontiguousarray(zi), np.asarray(t, np.float64),
                                   np.ascontiguousarray(weights, np.float64), int(levels))
    H = off + off.T
    H[np.diag_indices(levels + 1)] += diag
    return H[:levels, :levels]


@numba.njit(cache=True, nogil=True)
def _trace_gram_kernel(zi, t, weights, levels):  # pragma: no cover - compiled
    """The pair sums (k < k', upper part) and the diagonal of :func:`_trace_gram`, pair by
    pair of images (each pass streams two rows of codes)."""
    N, P = zi.shape
    L1 = levels + 1
    off = np.zeros((L1, L1))
    diag = np.zeros(L1)
    for k in range(N):
        zk = zi[k]
        tk2 = t[k] * t[k]
        for p in range(P):
            diag[zk[p]] += weights[p] * tk2
        for k2 in range(k + 1, N):
            z2 = zi[k2]
            tw = t[k] * t[k2]
            for p in range(P):
                off[zk[p], z2[p]] += weights[p] * tw
    return off, diag


def robertson(data: BracketData, *, max_iter: int = 50, tol: float = 1e-6) -> ClassicFit:
    """Robertson, Borman & Stevenson (2003): the response by alternating maximum likelihood
    (exposures given I, then I given the exposures; see the module notes).

    Parameters
    ----------
    data
        One channel of a bracket; only its usable observations are read.
    max_iter
        Most iterations (one iteration: every x_j, then I at every code).
    tol
        Stop when max |I_new - I| / max I falls below this.

    Returns
    -------
    ClassicFit
        ``extra``: ``change`` (the last relative change of I), ``pixels`` (usable in two images
        or more), ``knots``.
    """
    method = "Robertson, Borman & Stevenson"
    chk = check_bracket(data, method)
    if int(max_iter) < 1:
        raise CcdError("max_iter", f"must be >= 1, got {max_iter}")
    levels = chk.levels
    grid = Knots(levels)
    G = grid.n
    use = chk.n_valid >= 2
    P = int(np.count_nonzero(use))
    c = (levels - 1) / 2.0
    # both steps are linear in I: x = (V I) / den and I_new = U^T x / n with
    # V[j, m] = sum_k w(z_kj) t_k [z_kj = m], U[j, m] = sum_k t_k [z_kj = m] (knot shares for
    # deep codes); one iteration is I <- C I with C = diag(1/n) U^T diag(1/den) V (G x G),
    # built once, summed pixel by pixel; the pixels with one usable observation get no weight
    if grid.identity:
        # w depends on the column's code only: U^T diag(1/den) V = H diag(w), H symmetric
        codes = np.arange(levels + 1)
        w_code = np.exp(-4.0 * (codes - c) ** 2 / (c * c))           # Gaussian-like
        w_code[levels] = 0.0                                          # unusable
        zi = np.where(chk.valid, chk.z, np.asarray(levels, code_dtype(levels + 1)))
        den = np.zeros(zi.shape[1])
        for k in range(zi.shape[0]):
            den += np.take(w_code * chk.t[k] ** 2, zi[k])
        inv_den = np.divide(1.0, den, out=np.zeros_like(den), where=use)
        single = np.flatnonzero(chk.n_valid == 1)
        node_n = chk.counts - np.bincount(chk.z[:, single][chk.valid[:, single]],
                                          minlength=levels)
        UV = _trace_gram(zi, chk.t, inv_den, levels) * w_code[None, :levels]
    else:
        z = chk.z[:, use]
        v = chk.valid[:, use]
        t = chk.t[:, None]
        w = np.where(v, np.exp(-4.0 * (z - c) ** 2 / (c * c)), 0.0)   # Gaussian-like
        inv_den = 1.0 / (w * t * t).sum(axis=0)
        terms = grid.terms(z)
        T = len(terms)
        idx = np.concatenate([i for i, _ in terms]).astype(np.intp)  # (terms * N, P)
        share = np.concatenate([f for _, f in terms]) * np.tile(v, (T, 1))
        node_n = np.bincount(idx.ravel(), share.ravel(), minlength=G)
        tt = np.tile(t, (T, 1))
        UV = _pixel_gram(idx, share * tt, share * np.tile(w, (T, 1)) * tt * inv_den, G)
    have = node_n > 0
    ref = _mid_node(node_n, c / grid.step)
    C = UV[np.ix_(have, have)] / node_n[have][:, None]
    I = grid.codes / (levels - 1)                                   # the straight line
    I = I / I[ref]
    Ih = I[have]
    ref_h = int(np.count_nonzero(have[:ref]))
    converged = False
    change = np.inf
    it = 0
    for it in range(1, int(max_iter) + 1):
        new = C @ Ih                                                # x_j, then I(m)
        new = new / new[ref_h]
        change = float(np.max(np.abs(new - Ih)) / np.max(np.abs(new)))
        Ih = new
        if change < tol:
            converged = True
            break
    I[have] = Ih
    notes = [f"{P} pixels usable in two images or more"]
    if not converged:
        notes.append(f"not converged after {it} iterations (relative change {change:.2g}, "
                     f"tolerance {tol:g})")
    g, known = _to_codes(grid, I, have)
    g = finish_curve(g, known, chk.counts, levels, notes, chk.where, method)
    extra = {"change": change, "pixels": int(P), "knots": int(G)}
    return ClassicFit(g, it, converged, tuple(notes), extra)


# ---------------------------------------------------------------------- Mitsunaga & Nayar ------
def _mn_solve(H: NDArray, Nm: NDArray) -> tuple[NDArray[np.float64], float] | None:
    """The coefficients minimising ``a^T H a / a^T Nm a`` (the error relative to the data's
    energy), scaled to ``sum(a) = g(1) = 1``, and that relative error; ``None`` when the degree
    is too high for the data (``Nm`` singular) or the curve vanishes at M = 1."""
    try:
        rho, V = eigh(H, Nm)
    except (np.linalg.LinAlgError, ValueError):
        return None
    a = V[:, 0]
    s = float(a.sum())
    if not (np.all(np.isfinite(a)) and abs(s) > 1e-9 * float(np.abs(a).sum())):
        return None
    return a / s, max(float(rho[0]), 0.0)


def _code_pairs(z0: NDArray, z1: NDArray, ok: NDArray[np.bool_], levels: int
                ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64]]:
    """The joint histogram of the codes ``(z0, z1)`` of the pixels ``ok``: the distinct pairs
    and their counts (a bincount over ``levels^2`` bins up to 10 bits, a sort beyond)."""
    key = z0.astype(np.intp) * levels + z1
    if levels <= 1024:
        h = np.bincount(key[ok], minlength=levels * levels)
        pairs = np.flatnonzero(h)
        n = h[pairs]
    else:
        pairs, n = np.unique(key[ok], return_counts=True)
    return pairs // levels, pairs % levels, n.astype(np.float64)


def mitsunaga_nayar(data: BracketData, *, max_degree: int = MN_MAX_DEGREE,
                    max_iter: int = MN_MAX_ITER, tol: float = MN_TOL) -> ClassicFit:
    """Mitsunaga & Nayar (1999): polynomial g with refined exposure ratios (see the module
    notes for the scale and the exponent ambiguity).

    Parameters
    ----------
    data
        One channel of a bracket; only pixels usable in two consecutive images are read.
    max_degree
        The degrees ``1 .. max_degree`` are tried (at most one less than the codes with data);
        the one with the smallest final error wins.
    max_iter
        Most ratio refinements per degree; 0 keeps the nominal ratios (exposure times trusted).
    tol
        Stop refining when g changes by less than this at every code with data (0..1 scale).

    Returns
    -------
    ClassicFit
        ``extra``: ``degree``; ``coefficients`` (monomial ``c_0 .. c_D`` of ``g(M)``, ``sum = 1``,
        before the normalisation to the reported scale); ``ratios`` (refined ``R_q,q+1``; ``nan``
        for a pair of images without common pixels) and ``nominal_ratios``; ``errors`` (final
        relative error per degree: eps over the sum of ``g(M_q)^2 + R^2 g(M_q+1)^2``);
        ``history`` (the chosen degree's error at each refinement); ``pairs`` (pixel pairs).
    """
    method = "Mitsunaga & Nayar"
    chk = check_bracket(data, method, pairs=True)
    if int(max_degree) < 1:
        raise CcdError("max_degree", f"must be >= 1, got {max_degree}")
    if int(max_iter) < 0:
        raise CcdError("max_iter", f"must be >= 0, got {max_iter}")
    system = _MnSystem.of(chk, int(max_degree), method)
    results = [r for D in range(1, system.Dmax + 1)
               if (r := system.refined(D, int(max_iter), tol)) is not None]
    if not results:
        raise CcdError(chk.where, f"{method}: no polynomial fits the bracket (too few distinct "
                                  "codes)")
    errors = {r.degree: r.err for r in results}
    best = min(results, key=lambda r: r.err)
    mono = _shift_poly(npleg.leg2poly(best.a))                    # Legendre in 2M - 1 -> M^n
    notes = system.notes(best, int(max_iter))
    known = np.zeros(chk.levels, bool)
    uc = np.flatnonzero(system.used)
    known[uc[0]:uc[-1] + 1] = True
    g = finish_curve(best.gz, known, chk.counts, chk.levels, notes, chk.where, method)
    ratios = np.where(system.n_pairs > 0, best.R, np.nan)
    extra: dict[str, Any] = {"degree": int(best.degree), "coefficients": [float(x) for x in mono],
                             "ratios": [float(x) for x in ratios],
                             "nominal_ratios": [float(x) for x in system.nominal],
                             "errors": {int(k): float(e) for k, e in errors.items()},
                             "history": [float(x) for x in best.history],
                             "pairs": system.n_total}
    return ClassicFit(g, int(best.iterations), bool(best.converged), tuple(notes), extra)


@dataclass(frozen=True)
class _MnDegree:
    """One degree's fit: its final error, Legendre coefficients, ratios, g at every code,
    refinements, convergence and the error after each refinement."""

    err: float
    degree: int
    a: NDArray
    R: NDArray
    gz: NDArray
    iterations: int
    converged: bool
    history: list[float]


@dataclass(frozen=True)
class _MnSystem:
    """Mitsunaga & Nayar's error eps and ratio refinement as sums over the distinct code pairs
    of consecutive images.

    eps and the refined ratios are sums over pixels of functions of the pair of codes
    (z_q, z_q+1): computed once on the joint histogram of every pair of images (the distinct
    code pairs and their counts), every refinement then costs O(distinct pairs). Every pair's
    Gram matrices (eps = a^T [S0 - R S01 + R^2 S1] a) are stacked over the pairs."""

    basis: NDArray            # shifted Legendre polynomials at every code, P(1) = 1
    S0: NDArray
    S01: NDArray
    S1: NDArray
    S0_sum: NDArray           # S0 summed over the pairs
    nominal: NDArray          # the nominal ratios t_q / t_q+1
    n_pairs: NDArray          # pixel pairs of each consecutive pair of images
    live: NDArray             # the pairs with pixels
    free: NDArray             # the pairs whose ratio is refined
    used: NDArray             # the codes with data
    Dmax: int
    q_of: NDArray             # the free pairs' distinct code pairs, in one array
    z0: NDArray
    z1: NDArray
    n: NDArray

    @property
    def n_total(self) -> int:
        return int(self.n_pairs.sum())

    @classmethod
    def of(cls, chk: Any, max_degree: int, method: str) -> "_MnSystem":
        levels, N = chk.levels, chk.t.size
        pairs = [_code_pairs(chk.z[q], chk.z[q + 1], chk.valid[q] & chk.valid[q + 1], levels)
                 for q in range(N - 1)]
        n_pairs = np.array([int(p[2].sum()) for p in pairs])
        live = np.flatnonzero(n_pairs > 0)
        used = np.zeros(levels, bool)
        for q in live:
            used[pairs[q][0]] = True
            used[pairs[q][1]] = True
        n_used = int(np.count_nonzero(used))
        if n_used < 2:
            raise CcdError(chk.where, f"{method}: the pixels usable in two consecutive exposures "
                                      "show a single code; a response needs at least two")
        Dmax = min(max_degree, n_used - 1)
        M = np.arange(levels) / float(levels - 1)
        basis = npleg.legvander(2.0 * M - 1.0, Dmax)
        S0 = np.zeros((N - 1, Dmax + 1, Dmax + 1))
        S01 = np.zeros_like(S0)
        S1 = np.zeros_like(S0)
        for q in live:
            # summed over the codes, not the pixel pairs: B^T diag(h) B with the histograms h
            # of z_q and of z_q+1, and sum_p n_p B(z_q) B(z_q+1)^T = B^T Bm, Bm[z] = sum over
            # the pairs with z_q = z of n_p B(z_q+1) (bincounts; small products: a
            # multi-threaded BLAS on a busy 2-core machine took ten times longer on the
            # pixel-pair products)
            z0, z1, n = pairs[q]
            h0 = np.bincount(z0, n, minlength=levels)
            h1 = np.bincount(z1, n, minlength=levels)
            Bm = np.stack([np.bincount(z0, n * basis[z1, i], minlength=levels)
                           for i in range(Dmax + 1)], axis=1)
            X = basis.T @ Bm
            S0[q], S01[q], S1[q] = basis.T @ (h0[:, None] * basis), X + X.T, \
                basis.T @ (h1[:, None] * basis)
        # only ratios of pairs with MN_MIN_PAIRS pixels are refined (a handful of pixels next
        # to saturation gives a ratio of noise, and the common power would spread it over the
        # others)
        free = live[n_pairs[live] >= MN_MIN_PAIRS]
        q_of = np.repeat(free, [pairs[q][0].size for q in free])
        z0f, z1f, nf = (np.concatenate([pairs[q][i] for q in free] + [empty])
                        for i, empty in enumerate((q_of[:0], q_of[:0], np.zeros(0))))
        return cls(basis, S0, S01, S1, S0.sum(axis=0), chk.t[:-1] / chk.t[1:], n_pairs, live,
                   free, used, Dmax, q_of, z0f, z1f, nf)

    def fit(self, R: NDArray, D: int) -> tuple[NDArray, float] | None:
        """The degree-``D`` coefficients minimising eps at the ratios ``R``, and eps."""
        k = D + 1
        S1R = np.einsum("q,qij->ij", R * R, self.S1[:, :k, :k])
        S0 = self.S0_sum[:k, :k]
        H = S0 - np.einsum("q,qij->ij", R, self.S01[:, :k, :k]) + S1R          # eps
        return _mn_solve(H, S0 + S1R)

    def refine(self, gz: NDArray, R: NDArray) -> NDArray:
        """Every free pair's mean of g(M_q) / g(M_q+1) over its pixels (g(M_q+1) >=
        MN_RATIO_FLOOR, g(M_q) > 0), raised to the common power that keeps the nominal product
        of the ratios (the u-ambiguity); the last ratios where none is usable."""
        free, N1 = self.free, self.nominal.size
        g0, g1 = gz[self.z0], gz[self.z1]
        ok = (g1 >= MN_RATIO_FLOOR) & (g0 > 0)
        num = np.bincount(self.q_of[ok], self.n[ok] * (g0[ok] / g1[ok]), minlength=N1)
        cnt = np.bincount(self.q_of[ok], self.n[ok], minlength=N1)
        if np.any(cnt[free] <= 0):
            return R.copy()
        new = R.copy()
        new[free] = num[free] / cnt[free]
        lr = np.log(np.clip(new[free], 1e-300, None))
        total = float(lr.sum())
        if not total < 0:
            return R.copy()
        new[free] = np.exp(lr * (float(np.sum(np.log(self.nominal[free]))) / total))
        return new

    def refined(self, D: int, max_iter: int, tol: float) -> _MnDegree | None:
        """Degree ``D`` from the nominal ratios, the ratios refined until the error stops
        decreasing or g changes by less than ``tol`` at every code with data."""
        R = self.nominal.copy()
        first = self.fit(R, D)
        if first is None:
            return None
        a, err = first
        gz = self.basis[:, :D + 1] @ a
        it, converged = 0, True
        hist = [err]
        if max_iter > 0:
            converged = False
            for step in range(1, max_iter + 1):
                R_new = self.refine(gz, R)
                nxt = self.fit(R_new, D)
                if nxt is None or not nxt[1] < err:     # the error stops decreasing: keep the last
                    converged = True
                    break
                a, err = nxt
                g_new = self.basis[:, :D + 1] @ a
                change = float(np.max(np.abs(g_new[self.used] - gz[self.used])))
                R, gz, it = R_new, g_new, step
                hist.append(err)
                if change < tol:
                    converged = True
                    break
        return _MnDegree(err, D, a, R, gz, it, converged, hist)

    def notes(self, best: _MnDegree, max_iter: int) -> list[str]:
        notes = [f"degree {best.degree} chosen among 1..{self.Dmax} (smallest error)",
                 f"{self.n_total} pixel pairs in {self.live.size} consecutive image pairs"]
        if max_iter == 0:
            notes.append("nominal exposure ratios kept (no refinement asked)")
        elif best.iterations == 0:
            notes.append("nominal exposure ratios kept: refining them did not lower the error")
        elif not best.converged:
            notes.append(f"ratio refinement not converged after {best.iterations} iterations")
        else:
            notes.append(f"exposure ratios refined in {best.iterations} iteration(s)")
        dropped = np.setdiff1d(np.arange(self.nominal.size), self.live)
        if dropped.size:
            notes.append("no pixel usable in both images of pair(s) "
                         + ", ".join(f"{q}-{q + 1}" for q in dropped.tolist()))
        return notes


def _shift_poly(c: NDArray) -> NDArray[np.float64]:
    """Monomial coefficients in M of ``sum_n c_n (2M - 1)^n``."""
    out = np.zeros(1)
    power = np.ones(1)
    for cn in c:
        out = nppoly.polyadd(out, cn * power)
        power = nppoly.polymul(power, [-1.0, 2.0])
    return out
