"""The compiled kernels of :mod:`ccdcore.response.tsin.estimator` (numba): the pools, one pass over
them and the rows' statistics.

A pool is the pixels of image j at code ẑ (one code; bins of codes beyond 10 bits); a row is a
pool's prediction of one image k of its trace (its errors, eq. 10, stored row by row in CSR
``offsets``). Codes map to knots by :func:`knot`.

Public objects
--------------
pool_counts(pb, obs, clip, K)
    Per pool (j, m) and image i: the pixels observed in i, and those clipped there.
pool_members(pb, obs, clip, K, cap)
    The pixels of every pool (CSR), at most ``cap`` each, evenly spread over the frame.
trace(q, j, m, mflag, inc, paper, idx)
    The images of one membership's trace within its pool.
row_counts(start, mflag, inc, paper, K)
    Pixels per (pool, predicted image): the rows' sizes.
knot(code, step, identity, K)
    The knot and fraction of a code.
pool_rows(start, mz, mflag, mgrp, inc, paper, rowid, offsets, a, b, gk, gpc, wimg, wcode, K,
step, identity, want_noise, with_a)
    One pass: every prediction error by row, the rows' summed linearisations (eq. 13) and
    eq. 17's regressors; per pool :func:`pool_sums` (with :func:`pixel_weights` and
    :func:`missing_images` per pixel) and :func:`write_rows`.
row_stats(resid, offsets, trim, mad_c)
    Per row: trimmed mean (eq. 11), MAD sigma (eq. 12), the trimmed mean's standard error and
    the winsorising limits.
sorted_mad(x, c)
    median |x - c| of a sorted array.
group_sums(resid, egrp, offsets, lo, hi, wmean, trim, G)
    Per row and block of pixels: the summed influence on the row's trimmed mean.
"""
from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["sort_rows", "pool_counts", "pool_members", "trace", "row_counts", "knot", "pixel_weights",
           "missing_images", "pool_sums", "write_rows", "pool_rows", "row_stats", "sorted_mad",
           "group_sums"]


@numba.njit(cache=True, nogil=True)
def pool_counts(pb, obs, clip, K):  # pragma: no cover - compiled
    """seen[j, m, i]: pixels of pool (j, m) observed in image i; clipped[j, m, i] those clipped."""
    N, P = pb.shape
    seen = np.zeros((N, K, N), np.int64)
    clipped = np.zeros((N, K, N), np.int64)
    for p in range(P):
        for j in range(N):
            if not obs[j, p] or clip[j, p]:
                continue
            m = pb[j, p]
            for i in range(N):
                if obs[i, p]:
                    seen[j, m, i] += 1
                    if clip[i, p]:
                        clipped[j, m, i] += 1
    return seen, clipped


@numba.njit(cache=True, nogil=True)
def pool_members(pb, obs, clip, K, cap):  # pragma: no cover - compiled
    """The pixels of every pool (j, m), pool by pool (CSR: ``start`` indexed j * K + m); a
    pool larger than ``cap`` keeps ``cap`` of its pixels, evenly spread over the frame."""
    N, P = pb.shape
    full = np.zeros(N * K, np.int64)
    for p in range(P):
        for j in range(N):
            if obs[j, p] and not clip[j, p]:
                full[j * K + pb[j, p]] += 1
    counts = np.zeros(N * K + 1, np.int64)
    for q in range(N * K):
        counts[q + 1] = min(full[q], cap)
    start = np.cumsum(counts)
    members = np.empty(start[-1], np.int64)
    cur = start[:-1].copy()
    seen = np.zeros(N * K, np.int64)
    for p in range(P):
        for j in range(N):
            if obs[j, p] and not clip[j, p]:
                q = j * K + pb[j, p]
                i = seen[q]
                seen[q] += 1
                n = full[q]
                if n > cap and (i * cap) // n == ((i + 1) * cap) // n:
                    continue
                members[cur[q]] = p
                cur[q] += 1
    return start, members


@numba.njit(cache=True, nogil=True)
def trace(q, j, m, mflag, inc, paper, idx):  # pragma: no cover - compiled
    """The images of membership q's trace within pool (j, m), written to idx; their number.
    ``mflag`` bit 0: observed, bit 1: clipped."""
    N = mflag.shape[1]
    ns = 0
    for i in range(N):
        fl = mflag[q, i]
        if not fl & 1:
            continue
        if paper:
            if not fl & 2:
                idx[ns] = i
                ns += 1
        elif i != j and inc[j, m, i]:
            idx[ns] = i
            ns += 1
    return ns


@numba.njit(cache=True, nogil=True)
def row_counts(start, mflag, inc, paper, K):  # pragma: no cover - compiled
    N = mflag.shape[1]
    counts = np.zeros((N, K, N), np.int64)
    idx = np.empty(N, np.int64)
    for j in range(N):
        for m in range(K):
            for q in range(start[j * K + m], start[j * K + m + 1]):
                ns = trace(q, j, m, mflag, inc, paper, idx)
                if ns < 2:
                    continue
                if paper:
                    counts[j, m, j] += 1
                else:
                    for kk in range(ns):
                        counts[j, m, idx[kk]] += 1
    return counts


@numba.njit(cache=True, nogil=True)
def knot(code, step, identity, K):  # pragma: no cover - compiled
    """Knot j0 and fraction f of a code: g(z) = (1 - f) g[j0] + f g[j0 + 1]."""
    if identity:
        return code, 0.0
    u = code / step
    j0 = min(int(u), K - 2)
    return j0, u - j0


@numba.njit(cache=True, nogil=True, inline="always")
def pixel_weights(q, ns, idx, mz, wimg, wcode, wv):  # pragma: no cover - compiled
    """Eq. 9's weights of membership q's trace, w_i ∝ wimg_i wcode(z_i) (eq. 18: a_i / σ(z_i);
    or constant), normalised to sum 1, written to ``wv`` at the trace's images."""
    sw = 0.0
    for ii in range(ns):
        i = idx[ii]
        wv[i] = wimg[i] * wcode[mz[q, i]]
        sw += wv[i]
    for ii in range(ns):
        wv[idx[ii]] /= sw


@numba.njit(cache=True, nogil=True, inline="always")
def missing_images(j, m, ns, idx, rowid, paper, miss):  # pragma: no cover - compiled
    """``miss[k]``: pool (j, m) has a row for image k that this pixel's trace lacks; their
    number."""
    N = miss.size
    nmiss = 0
    for k in range(N):
        miss[k] = (not paper) and rowid[j, m, k] >= 0
    for kk in range(ns):
        miss[idx[kk]] = False
    for k in range(N):
        if miss[k]:
            nmiss += 1
    return nmiss


@numba.njit(cache=True, nogil=True)
def pool_sums(j, m, q0, q1, mz, mflag, mgrp, inc, paper, rowid, a, b, gk, gpc, wimg, wcode, K,
              step, identity, want_noise, with_a, resid, egrp, cursor, U, C, H,
              Hs):  # pragma: no cover - compiled
    """The memberships q0..q1 of pool (j, m): every pixel's radiance (eq. 9) and prediction
    errors (eq. 10), stored in their rows with their blocks; the pool's sums ``U`` (u in g, the
    eq. 17 terms and, with ``with_a``, the terms of the derivatives in a), ``C[k]`` (the same
    over the pixels lacking image k) and the per-row sums ``H`` (Σ δ(ẑ_k)) and ``Hs``. The
    scratch arrays are local: passed in from :func:`pool_rows` they made the pass slower."""
    N = mz.shape[1]
    idx = np.empty(N, np.int64)
    gv = np.empty(N)
    jv = np.empty(N, np.int64)
    fv = np.empty(N)
    wv = np.empty(N)
    miss = np.empty(N, np.bool_)
    ux = np.zeros(10)
    cols = np.zeros(10, np.int64)
    for q in range(q0, q1):
        ns = trace(q, j, m, mflag, inc, paper, idx)
        if ns < 2:
            continue
        # eq. 9's weights: w_i ∝ wimg_i wcode(z_i) (eq. 18: a_i / σ(z_i); or constant)
        pixel_weights(q, ns, idx, mz, wimg, wcode, wv)
        nmiss = missing_images(j, m, ns, idx, rowid, paper, miss)
        E = 0.0
        for ii in range(ns):
            i = idx[ii]
            jq, f = knot(mz[q, i], step, identity, K)
            jv[i] = jq
            fv[i] = f
            gv[i] = gk[jq] if f == 0.0 else (1.0 - f) * gk[jq] + f * gk[jq + 1]
            E += wv[i] * (gv[i] - b[i]) / a[i]
        for ii in range(ns):
            i = idx[ii]
            c = wv[i] / a[i]
            f = fv[i]
            ux[0] = c * (1.0 - f)
            cols[0] = jv[i]
            nterm = 1
            if f != 0.0:
                ux[1] = c * f
                cols[1] = jv[i] + 1
                nterm = 2
            if want_noise:
                gpi = gpc[mz[q, i]]
                ux[nterm] = c * c * max(gv[i] - b[i], 0.0)
                cols[nterm] = K
                ux[nterm + 1] = c * c
                cols[nterm + 1] = K + 1
                ux[nterm + 2] = c * c * gpi * gpi
                cols[nterm + 2] = K + 2
                nterm += 3
            if with_a:
                ux[nterm] = c * (gv[i] - b[i]) / a[i]
                cols[nterm] = K + 3 + i
                ux[nterm + 1] = c
                cols[nterm + 1] = K + 4 + N + i
                nterm += 2
            for t in range(nterm):
                U[cols[t]] += ux[t]
            if nmiss:
                for k in range(N):
                    if miss[k]:
                        for t in range(nterm):
                            C[k, cols[t]] += ux[t]
        if with_a:
            U[K + 3 + N] += E
            if nmiss:
                for k in range(N):
                    if miss[k]:
                        C[k, K + 3 + N] += E
        for kk in range(ns):
            k = idx[kk]
            if paper and k != j:
                continue
            r = rowid[j, m, k]
            if r < 0:
                continue
            e = a[k] * E + b[k] - gv[k]
            pos = cursor[r]
            resid[pos] = e
            egrp[pos] = mgrp[q]
            cursor[r] = pos + 1
            f = fv[k]
            if f == 0.0:
                H[k, jv[k]] += 1.0
            else:
                H[k, jv[k]] += 1.0 - f
                H[k, jv[k] + 1] += f
            if with_a:
                Hs[k, 3] += wv[k] * (gv[k] - b[k]) / a[k]
                Hs[k, 4] += 1.0
            if want_noise:
                gpk = gpc[mz[q, k]]
                Hs[k, 0] += 1.0 - 2.0 * wv[k]
                Hs[k, 1] += (1.0 - 2.0 * wv[k]) * max(gv[k] - b[k], 0.0)
                Hs[k, 2] += (1.0 - 2.0 * wv[k]) * gpk * gpk


@numba.njit(cache=True, nogil=True)
def write_rows(j, m, rowid, paper, a, K, U, C, H, Hs, want_noise, with_a, J,
               X):  # pragma: no cover - compiled
    """Pool (j, m)'s rows of ``J`` (eq. 13, summed over the row's pixels) and, with
    ``want_noise``, of ``X`` (eq. 17's regressors) from the pool's sums."""
    N = a.size
    for k in range(N):
        r = rowid[j, m, k]
        if r < 0 or (paper and k != j):
            continue
        ak = a[k]
        for t in range(K):
            J[r, t] = ak * (U[t] - C[k, t]) - H[k, t]
        if with_a:
            for i in range(N):
                J[r, K + i] = -ak * (U[K + 3 + i] - C[k, K + 3 + i])
            J[r, K + k] = (U[K + 3 + N] - C[k, K + 3 + N]) - Hs[k, 3]
            for i in range(N):
                J[r, K + N + i] = -ak * (U[K + 4 + N + i] - C[k, K + 4 + N + i])
            J[r, K + N + k] += Hs[k, 4]
        if want_noise:
            a2 = ak * ak
            X[r, 0] = a2 * (U[K] - C[k, K]) + Hs[k, 1]
            X[r, 1] = a2 * (U[K + 1] - C[k, K + 1]) + Hs[k, 0]
            X[r, 2] = a2 * (U[K + 2] - C[k, K + 2]) + Hs[k, 2]


@numba.njit(cache=True, nogil=True)
def pool_rows(start, mz, mflag, mgrp, inc, paper, rowid, offsets, a, b, gk, gpc, wimg, wcode, K,
              step, identity, want_noise, with_a):  # pragma: no cover - compiled
    """One pass over the pools: every prediction error (eq. 10) stored by row, the rows' summed
    linearisations (eq. 13) and, when asked, the rows' eq. 17 regressors.

    A pixel's error for image k of its trace is e = a_k Ê + b_k - g(ẑ_k) with
    Ê = Σ_i w (g(ẑ_i) - b_i) / a_i; its derivative in g is a_k u - δ(ẑ_k) with
    u = Σ_i (w / a_i) δ(ẑ_i), the same u for every k. So u (and the like terms of eq. 17)
    are summed once per pool, less the pixels whose trace lacks k, and only the
    δ(ẑ_k) terms per row. The pool's pixels' traces are read from ``mz``, ``mflag``: copies in
    pool order, so that the pass streams through memory.
    """
    N = mz.shape[1]
    R = offsets.size - 1
    J = np.zeros((R, K + (2 * N if with_a else 0)))
    X = np.zeros((R, 3))
    resid = np.empty(offsets[R])
    egrp = np.empty(offsets[R], np.int32)
    cursor = offsets[:R].copy()
    # pool sums: [0:K] u in g, then the eq. 17 terms Σ w² v/a², Σ w²/a², Σ w² g'²/a², then
    # (with_a) Σ w (g_i - b_i)/a_i² per image and Σ Ê, for the derivatives in a
    nu = K + 3 + N + 1 + N
    U = np.zeros(nu)
    C = np.zeros((N, nu))             # the same sums over the pixels lacking image k
    H = np.zeros((N, K))              # per row: Σ δ(ẑ_k)
    Hs = np.zeros((N, 5))             # per row: Σ (1-2w), Σ (1-2w) v_k, Σ (1-2w) g'_k²,
    #                                   Σ w (g_k - b_k)/a_k, n
    for j in range(N):
        for m in range(K):
            q0 = start[j * K + m]
            q1 = start[j * K + m + 1]
            if q1 == q0:
                continue
            any_row = False
            for k in range(N):
                if rowid[j, m, k] >= 0:
                    any_row = True
            if not any_row:
                continue
            U[:] = 0.0
            C[:, :] = 0.0
            H[:, :] = 0.0
            Hs[:, :] = 0.0
            pool_sums(j, m, q0, q1, mz, mflag, mgrp, inc, paper, rowid, a, b, gk, gpc, wimg,
                      wcode, K, step, identity, want_noise, with_a, resid, egrp, cursor, U, C, H,
                      Hs)
            write_rows(j, m, rowid, paper, a, K, U, C, H, Hs, want_noise, with_a, J, X)
    return J, X, resid, egrp



@numba.njit(cache=True, nogil=True)
def sort_rows(resid, offsets, order):  # pragma: no cover - compiled
    """A copy of ``resid`` sorted within each row (``offsets``: the rows' CSR).

    ``order`` (int64, the size of ``resid``) holds, row by row, the positions of the last
    sort's values in their sorted order, or -1 at its first entry when there was none; it is
    updated. A pass's errors sit at the same positions in every pass and move little from one
    pass to the next, so taken in the last pass's order a row is nearly sorted and an insertion
    sort finishes it in about one sweep (a full sort per row cost as much as the whole pass of
    errors on a 13-image bracket)."""
    out = np.empty_like(resid)
    fresh = order.size == 0 or order[0] < 0
    for r in range(offsets.size - 1):
        lo, hi = offsets[r], offsets[r + 1]
        if fresh:
            idx = np.argsort(resid[lo:hi])
            for q in range(hi - lo):
                order[lo + q] = lo + idx[q]
                out[lo + q] = resid[lo + idx[q]]
            continue
        for q in range(lo, hi):
            pos = order[q]
            v = resid[pos]
            i = q - 1
            while i >= lo and out[i] > v:
                out[i + 1] = out[i]
                order[i + 1] = order[i]
                i -= 1
            out[i + 1] = v
            order[i + 1] = pos
    return out


@numba.njit(cache=True, nogil=True)
def row_stats(resid, offsets, trim, mad_c):  # pragma: no cover - compiled
    """Per row (``resid`` sorted within each row): trimmed mean (eq. 11), MAD sigma (eq. 12),
    standard error of the trimmed mean (Tukey-McLaughlin) and the winsorising limits."""
    R = offsets.size - 1
    tm = np.empty(R)
    sig = np.empty(R)
    se = np.empty(R)
    lo = np.empty(R)
    hi = np.empty(R)
    wmean = np.empty(R)
    alpha = 0.5 * (1.0 - trim)
    for r in range(R):
        x = resid[offsets[r]:offsets[r + 1]]
        n = x.size
        # floor(alpha n) with a guard: alpha = 0.5 (1 - 0.66) is 0.16999... in floating point,
        # and at n = 300 alpha n = 50.99999...: one value fewer trimmed than eq. 11's 66 %
        g = int(math.floor(alpha * n + 1e-9))
        tm[r] = x[g:n - g].mean()
        lo[r] = x[g]
        hi[r] = x[n - g - 1]
        w = np.minimum(np.maximum(x, lo[r]), hi[r])
        wm = w.mean()
        wmean[r] = wm
        sw2 = ((w - wm) ** 2).sum() / (n - 1)
        se[r] = math.sqrt(sw2 / (n * trim * trim))
        sig[r] = mad_c * sorted_mad(x, tm[r])
    return tm, sig, se, lo, hi, wmean


@numba.njit(cache=True, nogil=True)
def sorted_mad(x, c):  # pragma: no cover - compiled
    """median |x - c| of a sorted array by merging the deviations on either side of c."""
    n = x.size
    right = np.searchsorted(x, c)
    left = right - 1
    half = n // 2
    prev = 0.0
    cur = 0.0
    for step in range(half + 1):
        dl = c - x[left] if left >= 0 else np.inf
        dr = x[right] - c if right < n else np.inf
        prev = cur
        if dl <= dr:
            cur = dl
            left -= 1
        else:
            cur = dr
            right += 1
    if n % 2 == 1:
        return cur
    return 0.5 * (prev + cur)


@numba.njit(cache=True, nogil=True)
def group_sums(resid, egrp, offsets, lo, hi, wmean, trim, G):  # pragma: no cover - compiled
    """Per row and block of pixels: the summed influence of the row's pixels on its trimmed
    mean (winsorised deviation / ((1 - 2α) n))."""
    R = offsets.size - 1
    S = np.zeros((R, G))
    for r in range(R):
        n = offsets[r + 1] - offsets[r]
        for q in range(offsets[r], offsets[r + 1]):
            v = min(max(resid[q], lo[r]), hi[r])
            S[r, egrp[q]] += (v - wmean[r]) / (trim * n)
    return S

