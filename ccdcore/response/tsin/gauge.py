"""The gauge of the white-balance fit of :mod:`ccdcore.response.tsin.estimator` (sec. 3.2 with the
gains a_k and offsets b_k free) and the band of g: a sandwich covariance over blocks of pixels,
carried through the gauge to the reported curve.

A bracket cannot tell g, a_k, b_k from g^u with a_k^u (the u-ambiguity), a common factor of the
gains from the scale of E, an offset of g (with every b_k) nor one of the radiance (with every
b_k - beta a_k): every step is taken within a gauge that fixes those directions, and the result
is reported with the offsets of smallest norm.

Public objects
--------------
MAX_GAIN_STEP, MAX_RADIUS
    The trust region of the gains' step.
gain_gauge(a, t), ab_gauge(a, t), joint_frame(free, a, t)
    Steps ``T y + off`` of the gains, of the gains and offsets, of g with both, in the gauge.
in_gauge(a, t)
    The gains moved into their gauge.
least_offsets(gk, a, b, k_hi)
    The offsets of smallest norm and the Jacobian of the reported (g, a, b).
joint_step(Hfull, grad, free, a, b, t, gain_prior, eta, radius, where)
    One Gauss-Newton step of g, the gains and the offsets in the gauge, with the a-priori bound
    on the gains and the trust region.
sandwich(bread, scores, frame=None)
    The sandwich covariance from the scores of blocks of pixels.
band(p, offsets, gk, a, b, t, free, k_rep, joint, groups, trim)
    The 1-sigma band of g (and the errors of a, b) from one pass over the pools.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ...errors import CcdError
from .kernels import group_sums

__all__ = ["MAX_GAIN_STEP", "MAX_RADIUS", "gain_gauge", "in_gauge", "ab_gauge", "joint_frame",
           "least_offsets", "joint_step", "sandwich", "band"]

#: the largest relative change of a gain a_k in one step of the white-balance fit
MAX_GAIN_STEP = 0.05
#: the white-balance fit's trust region grows to at most this many MAX_GAIN_STEP after accepted
#: steps (on a real bracket the gains travel far in one direction, step after step)
MAX_RADIUS = 8.0


def gain_gauge(a, t) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The gauge of the gains: steps δa = T y + off keep ln(a_k / t_k) at zero mean and zero
    trend in ln t_k (linearised). A bracket cannot tell a_k^u (with g^u) from a_k, nor a common
    factor of every a_k from the scale of E (sec. 3.2's u-ambiguity)."""
    N = a.size
    lt = np.log(t) - np.mean(np.log(t))
    C = np.stack([np.ones(N), lt])
    d0 = -np.linalg.pinv(C) @ (C @ np.log(a / t))
    Q = np.linalg.svd(C)[2][2:].T
    return a[:, None] * Q, a * d0


def in_gauge(a, t) -> NDArray[np.float64]:
    """The gains with ln(a_k / t_k) of zero mean and zero trend in ln t_k."""
    la, lt = np.log(a / t), np.log(t) - np.mean(np.log(t))
    C = np.stack([np.ones(a.size), lt], axis=1)
    return t * np.exp(la - C @ np.linalg.lstsq(C, la, rcond=None)[0])


def ab_gauge(a, t) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Steps (δa, δb) = T y + off: the gains in their gauge (:func:`gain_gauge`), b_0 = 0
    (the offsets are defined up to b_k + c a_k)."""
    N = a.size
    Tg, off_a = gain_gauge(a, t)
    T = np.zeros((2 * N, Tg.shape[1] + N - 1))
    T[:N, :Tg.shape[1]] = Tg
    T[N + 1:, Tg.shape[1]:] = np.eye(N - 1)
    return T, np.concatenate([off_a, np.zeros(N)])


def joint_frame(free, a, t) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Steps (δg, δa, δb) = T y + off: the knots marked ``free`` and the gains and offsets in
    their gauge (:func:`ab_gauge`)."""
    K, N = free.size, a.size
    Tg, off_ab = ab_gauge(a, t)
    fk = np.flatnonzero(free)
    T = np.zeros((K + 2 * N, fk.size + Tg.shape[1]))
    T[fk, np.arange(fk.size)] = 1.0
    T[K:, fk.size:] = Tg
    return T, np.concatenate([np.zeros(K), off_ab])


def least_offsets(gk, a, b, k_hi):
    """``(g + c, b + c - beta a, D)``: the offsets of smallest norm and the Jacobian ``D`` of
    the reported (g, a, b) -- g then scaled to its value at knot ``k_hi`` -- on the fitted ones.

    With offsets free the bracket cannot tell an offset c of g (with every b_k + c) nor an
    offset beta of the radiance (with every b_k - beta a_k): g(z) = a_k E + b_k fits as well.
    Of that family the reported one has the smallest offsets, i.e. b is orthogonal to 1 and
    to a -- the truth's offsets are small and unrelated to the gains."""
    K, N = gk.size, a.size
    A = np.stack([np.ones(N), -a], axis=1)
    pinv = np.linalg.pinv(A)                        # (c, beta) = pinv @ (-b)
    c, beta = pinv @ (-b)
    g_new, b_new = gk + c, b + c - beta * a
    # d g_new / d b = -pinv[0] on every knot; d b_new / d b = I - A pinv
    D = np.eye(K + 2 * N)
    D[:K, K + N:] = -pinv[0][None, :]
    D[K + N:, K + N:] = np.eye(N) - A @ pinv
    # then g / g[k_hi] (the reported scale): its Jacobian on g
    S = np.eye(K) - np.outer(g_new / g_new[k_hi], np.eye(K)[k_hi])
    D[:K] = S @ D[:K]
    return g_new, b_new, D


def joint_step(Hfull: NDArray, grad: NDArray, free: NDArray, a: NDArray, b: NDArray,
               t: NDArray, gain_prior: float, eta: float, radius: float, where: str
               ) -> tuple[NDArray, NDArray, NDArray, float]:
    """One Gauss-Newton step of g, the gains and the offsets together, within the gauge
    (:func:`joint_frame`), with sec. 3.2's a-priori bound on the gains and a trust region:
    ``(Δg, a, b, radius)`` after the step.

    The bound: ln(a_k / t_k) ~ N(0, gain_prior²); it only holds directions the data leave
    loose (a nearly saturated image). The trust region: no gain moves by more than
    :data:`MAX_GAIN_STEP` × ``radius`` in one step (far from the solution the linearised step
    overshoots along the loosely held directions); the radius then doubles, up to
    :data:`MAX_RADIUS`."""
    K, N = free.size, a.size
    Tf, off = joint_frame(free, a, t)
    Hfull, grad = Hfull.copy(), grad.copy()
    if gain_prior:
        ia = np.arange(K, K + N)
        Hfull[ia, ia] += 1.0 / (a * gain_prior) ** 2
        grad[K:K + N] -= np.log(a / t) / (a * gain_prior ** 2)
    y = np.linalg.lstsq(Tf.T @ Hfull @ Tf, Tf.T @ (grad - Hfull @ off), rcond=None)[0]
    d = Tf @ y + off
    rel = float(np.max(np.abs(eta * d[K:K + N] / a)))
    if rel > MAX_GAIN_STEP * radius:
        d = d * (MAX_GAIN_STEP * radius / rel)
    a_new = a + eta * d[K:K + N]
    if np.any(a_new <= 0):
        raise CcdError(where, "an image's gain went non-positive: the bracket does not "
                              "constrain it")
    a_new = in_gauge(a_new, t)                   # exactly, whatever the step's length
    return d[:K], a_new, b + eta * d[K + N:], min(MAX_RADIUS, 2.0 * radius)


def sandwich(bread: NDArray, scores: NDArray, frame: NDArray | None = None
              ) -> NDArray[np.float64]:
    """The sandwich covariance B⁻¹ (Ψ Ψᵀ G/(G − 1)) B⁻¹ from the blocks' scores Ψ (one column
    per block of rows; one pixel's noise enters many pools' rows, and neighbours of an
    interpolated colour frame are correlated), mapped by ``frame`` (T B⁻¹ … B⁻¹ Tᵀ) when
    given; NaN where the bread is singular."""
    G = scores.shape[1]
    n = bread.shape[0] if frame is None else frame.shape[0]
    try:
        Bi = np.linalg.inv(bread)
    except np.linalg.LinAlgError:
        return np.full((n, n), np.nan)
    cov = Bi @ ((scores @ scores.T) * (G / (G - 1.0))) @ Bi
    return cov if frame is None else frame @ cov @ frame.T


def band(p: Any, offsets: NDArray, gk: NDArray, a: NDArray, b: NDArray, t: NDArray,
         free: NDArray, k_rep: int, joint: bool, groups: int, trim: float
         ) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
    """The 1-sigma band of g (and the errors of a, b) from the pass ``p``: a sandwich over
    blocks of pixels, carried to the reported scale (g(z_hi) fixed) and, with ``joint`` (the
    white-balance fit), to the offsets of smallest norm. Returns ``(g, b, g_err, a_err,
    b_err)`` with g and b moved to those offsets. ``p``: one pass of
    :mod:`ccdcore.response.tsin.estimator` and what steps 6-7 make of it; ``offsets`` its rows' CSR
    into
    the errors; ``trim`` the fraction the trimmed mean keeps (eq. 11)."""
    K, N = gk.size, a.size
    Sg = group_sums(p.resid, p.egrp, offsets, p.lo, p.hi, p.wmean, trim, groups)
    if joint:
        Tf, _ = joint_frame(free, a, t)
        Hfull = p.JWfull.T @ p.Jm
        Hfull[:K, :K] += p.lam * p.P_s
        cov_f = sandwich(Tf.T @ Hfull @ Tf, Tf.T @ (p.JWfull.T @ Sg), Tf)
        gk, b, D = least_offsets(gk, a, b, k_rep)
        cov_f = D @ cov_f @ D.T
        err, a_err, b_err = (np.sqrt(np.maximum(np.diag(cov_f)[part], 0.0))
                             for part in (slice(0, K), slice(K, K + N), slice(K + N, None)))
        return gk, b, err, a_err, b_err
    cov = np.zeros((K, K))
    cov[np.ix_(free, free)] = sandwich(p.Hs[np.ix_(free, free)], (p.JW.T @ Sg)[free])
    # g is reported with g(z_hi) fixed instead of the fit's fixed point: the band follows
    S = np.eye(K) - np.outer(gk / gk[k_rep], np.eye(K)[k_rep])
    err = np.sqrt(np.maximum(np.diag(S @ cov @ S.T), 0.0))
    return gk, b, err, np.zeros(N), np.zeros(N)
