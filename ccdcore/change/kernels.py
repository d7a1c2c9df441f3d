"""The numerical kernels of :mod:`ccdcore.change.detector` (Tsin, Ramesh & Kanade 2001, sec. 5): the
error of the transform of eq. 20, E' = E M, and the least trimmed squares search for M.

For pixels given as rows (n, C), the prediction error e = E M - E' has the covariance
Σ_e = Mᵀ Σ_E M + Σ_E' + J Σ_M Jᵀ (first-order propagation) and d² = eᵀ Σ_e⁻¹ e; for RGB (C = 3)
one compiled pass (numba) gives Σ_e's Cholesky factor, d², ln det Σ_e and Σ_e⁻¹ per pixel.  M is
fitted by generalised least squares (the normal equations corrected for the noise of E) and
searched for by FAST-LTS (Rousseeuw & Van Driessen): elemental subsets, C-steps, the cost being
the Gaussian negative log-likelihood of the h pixels of smallest d².

Every name here serves :mod:`ccdcore.change.detector`, which re-exports none of them.

Public objects
--------------
error_d2(E, Et, var, var_t, M, M_cov=None, want_p=True, want_logdet=False)
    d² of every row under M, with Σ_e⁻¹ and ln det Σ_e on request.
design_normal(E, Et, P, w, var=None)
    The normal equations of generalised least squares for vec M.
gls(E, Et, var, var_t, w, M0, iters=3, corrected=False)
    M by generalised least squares and the inverse of the normal matrix.
lts(E, Et, var, var_t, coverage, trials, rng, refined)
    FAST-LTS for M: the transform of the largest group of rows, and its trimmed cost.
shade_d2(E, Et, var, var_t, M, M_cov=None)
    Every row's factor k of the shade E' = k E M and its d² (C - 1 degrees of freedom).
"""
from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from ..errors import CcdError

__all__ = ["error_d2", "design_normal", "gls", "lts", "shade_d2"]


# -- the model of eq. 20 and its error --------------------------------------------------------
def design_normal(E: NDArray, Et: NDArray, P: NDArray, w: NDArray,
                  var: NDArray | None = None) -> tuple[NDArray, NDArray]:
    """Normal equations of generalised least squares for vec M (row-major): e_i = E_i M - E'_i
    with weight matrices w_i P_i (P_i = Σ_i⁻¹, given as (n, C, C)).

    With ``var`` (the variances of E's noise) the moments E_i E_iᵀ are corrected for it,
    E_i E_iᵀ - diag(var_i) (corrected least squares, Fuller 1987): otherwise the noise of the
    reference radiance biases M towards 0 (errors in the variables; 0.4 % on the diagonal of
    the change preset's background, 5-25 times M's standard error)."""
    n, C = E.shape
    EE = E[:, :, None] * E[:, None, :]
    if var is not None:
        idx = np.arange(C)
        EE[:, idx, idx] -= var
    EE = EE.reshape(n, C * C) * w[:, None]
    # N[(k, j), (l, m)] = Σ_i w_i E_ik E_il P_ijm
    N = (EE.T @ P.reshape(n, C * C)).reshape(C, C, C, C).transpose(0, 2, 1, 3)
    PEt = np.einsum("ijm,im->ij", P, Et)
    r = (E * w[:, None]).T @ PEt                      # [k, j]
    return N.reshape(C * C, C * C), r.reshape(C * C)


def _error_cov(E: NDArray, var: NDArray, var_t: NDArray, M: NDArray,
               M_cov: NDArray | None = None) -> NDArray:
    """Σ_e per pixel (n, C, C): Mᵀ diag(σ_E²) M + diag(σ_E'²) (+ J Σ_M Jᵀ)."""
    n, C = E.shape
    S = (var @ (M[:, :, None] * M[:, None, :]).reshape(C, C * C)).reshape(n, C, C)
    idx = np.arange(C)
    S[:, idx, idx] += var_t
    if M_cov is not None and np.any(M_cov):
        # e_j = Σ_k E_k M_kj: ∂e_j/∂M_kj = E_k; cov(M_kj, M_lm) = M_cov[(k, j), (l, m)]
        Mc = M_cov.reshape(C, C, C, C).transpose(0, 2, 1, 3).reshape(C * C, C * C)
        EE = (E[:, :, None] * E[:, None, :]).reshape(n, C * C)
        S += (EE @ Mc).reshape(n, C, C)
    return S


def shade_d2(E: NDArray, Et: NDArray, var: NDArray, var_t: NDArray, M: NDArray,
             M_cov: NDArray | None = None, iters: int = 4) -> tuple[NDArray, NDArray]:
    """The shade of the transform M that explains each row best: E' = k E M with one factor k
    per row, and its d² (χ² with C - 1 degrees of freedom at the truth).

    A shade of one light (a soft shadow, a penumbra, a part of the wall nearer the lamp) scales
    the light's radiance without changing its colour, so it scales the prediction E M. The
    error's covariance is eq. 20's first-order propagation with k in it,
    Σ_e(k) = k² (Mᵀ Σ_E M + J Σ_M Jᵀ) + Σ_E'; k is its generalised least squares estimate,
    k = (Pᵀ Σ_e⁻¹ E') / (Pᵀ Σ_e⁻¹ P) with P = E M, iterated ``iters`` times with Σ_e at the
    last k, from k = 1. Returns (k, d²) per row; NaN where the prediction is 0 in every
    channel. RGB rows only (C = 3; one colour is what tells a shade from an object), in a
    compiled pass (a 3 x 3 Cholesky factor per row)."""
    n, C = E.shape
    if C != 3:
        raise CcdError("channels", f"a shade needs RGB rows (C = 3), got C = {C}")
    A = _error_cov(E, var, np.zeros_like(var_t), M, M_cov)
    P = E @ M
    k = np.full(n, np.nan)
    d2 = np.full(n, np.nan)
    _shade_rgb(np.ascontiguousarray(A), np.ascontiguousarray(P), np.ascontiguousarray(Et),
               np.ascontiguousarray(var_t), int(iters), k, d2)
    return k, d2


@numba.njit(cache=True)
def _shade_rgb(A, P, Et, var_t, iters, k_out, d2_out):  # pragma: no cover - compiled
    n = A.shape[0]
    S = np.empty((3, 3))
    L = np.zeros((3, 3))
    y = np.empty(3)
    for r in range(n):
        k = 1.0
        good = False
        for it in range(iters + 1):
            for i in range(3):
                for j in range(3):
                    S[i, j] = k * k * A[r, i, j]
                S[i, i] += var_t[r, i]
            # Cholesky S = L Lᵀ
            ok = True
            for j in range(3):
                acc = S[j, j]
                for m in range(j):
                    acc -= L[j, m] * L[j, m]
                if not acc > 0.0:
                    ok = False
                    break
                L[j, j] = math.sqrt(acc)
                for i in range(j + 1, 3):
                    acc = S[i, j]
                    for m in range(j):
                        acc -= L[i, m] * L[j, m]
                    L[i, j] = acc / L[j, j]
            if not ok:
                good = False
                break
            # whitened P, E' and error: L⁻¹ x by forward substitution
            pw0 = P[r, 0] / L[0, 0]
            pw1 = (P[r, 1] - L[1, 0] * pw0) / L[1, 1]
            pw2 = (P[r, 2] - L[2, 0] * pw0 - L[2, 1] * pw1) / L[2, 2]
            tw0 = Et[r, 0] / L[0, 0]
            tw1 = (Et[r, 1] - L[1, 0] * tw0) / L[1, 1]
            tw2 = (Et[r, 2] - L[2, 0] * tw0 - L[2, 1] * tw1) / L[2, 2]
            if it == iters:
                y[0] = tw0 - k * pw0
                y[1] = tw1 - k * pw1
                y[2] = tw2 - k * pw2
                d2_out[r] = y[0] * y[0] + y[1] * y[1] + y[2] * y[2]
                break
            den = pw0 * pw0 + pw1 * pw1 + pw2 * pw2
            if not den > 0.0:
                good = False
                break
            k = (pw0 * tw0 + pw1 * tw1 + pw2 * tw2) / den
            good = True
        if good:
            k_out[r] = k
        else:
            d2_out[r] = np.nan


def _chol_inv(S: NDArray) -> tuple[NDArray, NDArray]:
    """L⁻¹ with S = L Lᵀ (Cholesky) for symmetric positive definite (n, C, C) matrices, and
    ln det S (the RGB case has its compiled kernel, :func:`_d2_rgb_kernel`). Cholesky is
    backward stable where the adjugate is not: Σ_e is ill-conditioned for a nearly singular M."""
    if S.shape[1] == 1:
        l11 = np.sqrt(np.maximum(S[:, 0, 0], 1e-300))
        return (1.0 / l11)[:, None, None], 2.0 * np.log(l11)
    L = np.linalg.cholesky(S)
    return np.linalg.inv(L), 2.0 * np.sum(np.log(np.diagonal(L, axis1=1, axis2=2)), axis=1)


_PAIRS3 = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


@numba.njit(cache=True)
def _d2_rgb_kernel(E, Et, var, var_t, M, R, with_mcov, want_p, d2, logdet,
                   P):  # pragma: no cover - compiled
    """Per pixel: the six distinct entries of Σ_e, its Cholesky factor, d² by forward
    substitution, ln det Σ_e and (``want_p``) Σ_e⁻¹ = L⁻ᵀ L⁻¹; one pass, no temporaries."""
    tiny = 1e-300
    S = np.empty(6)
    for i in range(E.shape[0]):
        e0 = E[i, 0] * M[0, 0] + E[i, 1] * M[1, 0] + E[i, 2] * M[2, 0] - Et[i, 0]
        e1 = E[i, 0] * M[0, 1] + E[i, 1] * M[1, 1] + E[i, 2] * M[2, 1] - Et[i, 1]
        e2 = E[i, 0] * M[0, 2] + E[i, 1] * M[1, 2] + E[i, 2] * M[2, 2] - Et[i, 2]
        for q in range(6):
            j, m = _PJ[q], _PM[q]
            acc = var[i, 0] * M[0, j] * M[0, m] + var[i, 1] * M[1, j] * M[1, m] \
                + var[i, 2] * M[2, j] * M[2, m]
            if with_mcov:
                for k in range(3):
                    for l in range(3):
                        acc += E[i, k] * E[i, l] * R[k * 3 + l, q]
            S[q] = acc
        S[0] += var_t[i, 0]
        S[3] += var_t[i, 1]
        S[5] += var_t[i, 2]
        l11 = math.sqrt(max(S[0], tiny))
        l21 = S[1] / l11
        l31 = S[2] / l11
        l22 = math.sqrt(max(S[3] - l21 * l21, tiny))
        l32 = (S[4] - l21 * l31) / l22
        l33 = math.sqrt(max(S[5] - l31 * l31 - l32 * l32, tiny))
        y1 = e0 / l11
        y2 = (e1 - l21 * y1) / l22
        y3 = (e2 - l31 * y1 - l32 * y2) / l33
        d2[i] = y1 * y1 + y2 * y2 + y3 * y3
        logdet[i] = 2.0 * (math.log(l11) + math.log(l22) + math.log(l33))
        if want_p:
            i11 = 1.0 / l11
            i22 = 1.0 / l22
            i33 = 1.0 / l33
            i21 = -l21 * i11 * i22
            i32 = -l32 * i22 * i33
            i31 = -(l31 * i11 + l32 * i21) * i33
            p01 = i21 * i22 + i31 * i32
            p02 = i31 * i33
            p12 = i32 * i33
            P[i, 0, 0] = i11 * i11 + i21 * i21 + i31 * i31
            P[i, 1, 1] = i22 * i22 + i32 * i32
            P[i, 2, 2] = i33 * i33
            P[i, 0, 1] = p01
            P[i, 1, 0] = p01
            P[i, 0, 2] = p02
            P[i, 2, 0] = p02
            P[i, 1, 2] = p12
            P[i, 2, 1] = p12


@numba.njit(cache=True)
def _trial_costs_rgb(E, Et, var, var_t, Ms, h, out):  # pragma: no cover - compiled
    """:func:`_trimmed_cost` of every candidate M of ``Ms`` (T, 3, 3) on these pixels."""
    n = E.shape[0]
    d2 = np.empty(n)
    logdet = np.empty(n)
    P = np.empty((1, 3, 3))
    R = np.zeros((9, 6))
    base = np.empty(n)
    for i in range(n):
        base[i] = math.log(var_t[i, 0]) + math.log(var_t[i, 1]) + math.log(var_t[i, 2])
    for t in range(Ms.shape[0]):
        _d2_rgb_kernel(E, Et, var, var_t, Ms[t], R, False, False, d2, logdet, P)
        cut = np.partition(d2, h - 1)[h - 1]         # the h smallest (ties: all counted)
        acc = 0.0
        for i in range(n):
            if d2[i] <= cut:
                acc += d2[i] + logdet[i] - base[i]
        out[t] = acc


_PJ = np.array([j for j, _ in _PAIRS3])
_PM = np.array([m for _, m in _PAIRS3])


def _d2_rgb(E, Et, var, var_t, M, M_cov, want_p: bool):
    """:func:`error_d2` for C = 3, compiled (see :func:`_d2_rgb_kernel`)."""
    n = E.shape[0]
    with_mcov = M_cov is not None and bool(np.any(M_cov))
    if with_mcov:
        Mc = np.asarray(M_cov, np.float64).reshape(3, 3, 3, 3)            # [k, j, l, m]
        R = np.ascontiguousarray(np.stack([Mc[:, j, :, m].reshape(9) for j, m in _PAIRS3],
                                          axis=1))
    else:
        R = np.zeros((9, 6))
    d2, logdet = np.empty(n), np.empty(n)
    P = np.empty((n, 3, 3)) if want_p else np.empty((1, 3, 3))
    f = np.ascontiguousarray
    _d2_rgb_kernel(f(E, np.float64), f(Et, np.float64), f(var, np.float64),
                   f(var_t, np.float64), f(M, np.float64), R, with_mcov, bool(want_p), d2,
                   logdet, P)
    return d2, (P if want_p else None), logdet


def error_d2(E: NDArray, Et: NDArray, var: NDArray, var_t: NDArray, M: NDArray,
             M_cov: NDArray | None = None, *, want_p: bool = True, want_logdet: bool = False):
    """d² = eᵀ Σ_e⁻¹ e for pixels given as rows (n, C), and Σ_e⁻¹ (``want_p``) and
    ln det Σ_e (``want_logdet``)."""
    if E.shape[1] == 3:
        d2, P, logdet = _d2_rgb(E, Et, var, var_t, M, M_cov, want_p)
    else:
        e = E @ M - Et
        Li, logdet = _chol_inv(_error_cov(E, var, var_t, M, M_cov))
        y = np.einsum("ijm,im->ij", Li, e)
        d2 = np.sum(y * y, axis=1)
        P = np.einsum("ikj,ikm->ijm", Li, Li) if want_p else None
    if want_logdet:
        return d2, P, logdet
    return d2, P


def gls(E, Et, var, var_t, w, M0, iters: int = 3, corrected: bool = False
        ) -> tuple[NDArray, NDArray]:
    """M by generalised least squares with weights ``w`` (Σ_e re-evaluated at each M), and the
    inverse of the normal matrix; ``corrected``: for the noise of E (:func:`design_normal`)."""
    C = E.shape[1]
    M = M0
    Ninv = np.zeros((C * C, C * C))
    for _ in range(iters):
        _, P = error_d2(E, Et, var, var_t, M)
        N, r = design_normal(E, Et, P, w, var if corrected else None)
        try:
            Ninv = np.linalg.inv(N)
        except np.linalg.LinAlgError:
            Ninv = np.linalg.pinv(N)
        M = (Ninv @ r).reshape(C, C)
    return M, Ninv


def _trimmed_cost(E, Et, var, var_t, M, h: int) -> float:
    """The LTS objective of M: over the h pixels of smallest d², the sum of the Gaussian
    negative log-likelihood d² + ln det Σ_e (less ln det Σ_E', which M does not change). d²
    alone would favour a near-singular M whose inflated Σ_e absorbs any error along its range
    (errors in the variables): ln det Σ_e is what makes that cost."""
    d2, _, logdet = error_d2(E, Et, var, var_t, M, want_p=False, want_logdet=True)
    keep = np.argpartition(d2, h - 1)[:h]
    return float(np.sum(d2[keep] + logdet[keep] - np.sum(np.log(var_t[keep]), axis=1)))


def _c_steps(E, Et, var, var_t, M, h: int, cost: float, max_steps: int = 20
             ) -> tuple[NDArray, float]:
    """Rousseeuw & Van Driessen's C-steps: refit on the h pixels of smallest d² until the
    trimmed cost stops decreasing."""
    ones = np.ones(h)
    for _ in range(max_steps):
        d2, _ = error_d2(E, Et, var, var_t, M, want_p=False)
        keep = np.argpartition(d2, h - 1)[:h]
        M_new, _ = gls(E[keep], Et[keep], var[keep], var_t[keep], ones, M, iters=1)
        new_cost = _trimmed_cost(E, Et, var, var_t, M_new, h)
        if not new_cost < cost * (1 - 1e-9):
            break
        M, cost = M_new, new_cost
    return M, cost


def lts(E, Et, var, var_t, coverage: float, trials: int, rng: np.random.Generator,
        refined: int) -> tuple[NDArray, float]:
    """FAST-LTS for M (Rousseeuw & Van Driessen): elemental subsets of C pixels solved exactly,
    each scored by its trimmed cost on a small even sample, the ``refined`` best refined by
    C-steps on all the pixels given; the cost is the sum of the h = coverage n smallest d²."""
    n, C = E.shape
    h = max(C * C + 1, int(round(coverage * n)))
    small = np.unique(np.linspace(0, n - 1, min(n, 600)).astype(np.int64))
    hs = max(C * C + 1, int(round(coverage * small.size)))
    Es, Ets, vs, vts = E[small], Et[small], var[small], var_t[small]
    picks = rng.integers(0, n, size=(int(trials), C))
    if C > 1:                                           # elemental subsets of distinct pixels
        srt = np.sort(picks, axis=1)
        picks = picks[np.all(srt[:, 1:] != srt[:, :-1], axis=1)]
    A, B = E[picks], Et[picks]                          # (T, C, C): rows are pixels
    ok = np.abs(np.linalg.det(A)) > 1e-12 * np.prod(np.linalg.norm(A, axis=2), axis=1)
    if not np.any(ok):
        raise CcdError("change", "no transform could be fitted (the radiance is degenerate: "
                                 "its colours do not span the channels)")
    Ms = np.linalg.solve(A[ok], B[ok])
    Ms = Ms[np.all(np.isfinite(Ms), axis=(1, 2))]
    if C == 3:
        costs = np.empty(len(Ms))
        _trial_costs_rgb(*(np.ascontiguousarray(x, np.float64) for x in (Es, Ets, vs, vts, Ms)),
                         hs, costs)
    else:
        costs = np.array([_trimmed_cost(Es, Ets, vs, vts, M, hs) for M in Ms])
    scored = [(float(c), M) for c, M in zip(costs, Ms)]
    scored.sort(key=lambda c: c[0])
    best_cost, best = math.inf, scored[0][1]
    for _, M in scored[:refined]:
        M, cost = _c_steps(E, Et, var, var_t, M, h,
                           _trimmed_cost(E, Et, var, var_t, M, h))
        if cost < best_cost:
            best_cost, best = cost, M
    return best, best_cost
