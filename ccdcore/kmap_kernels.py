"""The compiled per-pixel kernels of the fixed-pattern map K̂ (Healey & Kondepudy 1994, eqs. 45–50).

They sit below both callers: :mod:`ccdcore.fixedpattern` (the streamed estimate) and
:mod:`ccdcore.distributed.client` (K̂ band by band on a Dask cluster), which run the same kernels so
the two give the same map to the bit. Nothing here reads files or knows a session.

Public objects
--------------
slopes_into, local_mean, box_mean, box_mean_band
    The slopes e / ē of one configuration (eqs. 46–47), ē the box mean of ``window`` pixels.
slope_moments, eq49_reject, median_map
    m̄ and the per-pixel spread of the slopes (eq. 48); the rejection and average of eq. 49.
pw_pieces, pw_total, PW_BLOCK
    Pairwise sums in fixed blocks, so a sum over bands equals the sum over the whole frame.
NOT_LIT, NO_SIGMA
    The messages of a configuration not above the dark level and of no usable slopes.
FixedPattern, fixed_pattern_of(K, used, rejected, m_bar, K_var, ...)
    The result K̂ and its diagnostics, and its assembly from the maps of eqs. 48–49 (notes,
    n̂_1, the bound of eq. 50, the summary statistics); both are re-exported by
    :mod:`ccdcore.fixedpattern`, their usual address.
FixedPatternSummary
    The record a calibration product stores of K̂ (:meth:`FixedPattern.summary`; no maps),
    with its displayable ``rows()``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable

import numba
import numpy as np
from scipy.ndimage import uniform_filter

from .common import json_safe
from .records import Record, Row

NOT_LIT = ("configuration {cid} is not above the dark level (mean e_i = {level:.3g} DN): is it "
            "a lit card?")
NO_SIGMA = "no pixel has two usable slopes (ē_i > 0): cannot estimate σ̂"


def slopes_into(e: np.ndarray, e_bar: np.ndarray, out: np.ndarray) -> None:
    """Eq. 47: m_i = e_i/ē_i into ``out`` (float32), NaN where ē_i ≤ 0; ``e`` is overwritten."""
    with np.errstate(divide="ignore", invalid="ignore"):
        np.divide(e, e_bar, out=e)
    e[~(e_bar > 0)] = np.nan                                    # no slope where ē_i ≤ 0
    out[...] = e


def eq49_reject(slopes: np.ndarray, m_bar: np.ndarray, half: float, center: str
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """Eq. 49 over the (n1, ...) slopes: K̂, the rejections, n'_1, K̂'s variance and the number
    of pixels that kept no slope (K̂ there is the median slope).

    Reject slopes outside centre ± half (centre m̄, or the per-pixel median of the slopes) and
    re-average; where nothing is kept, the median slope; and K̂'s error variance (see
    FixedPattern.K_var).  One compiled pass over the n1 maps, pixel by pixel, so a band of rows
    gives the rows of the whole frame's result.
    """
    n1, shape = slopes.shape[0], slopes.shape[1:]
    K = np.empty(shape)
    if center == "median":     # the centres go into K̂'s buffer, which eq. 49 then overwrites
        median_slopes(slopes.reshape(n1, -1), K.reshape(-1))
    rejected = np.empty((n1,) + shape, dtype=bool)
    used = np.empty(shape, np.int16)
    K_var = np.empty(shape)
    reject_and_average(slopes.reshape(n1, -1), (m_bar if center == "mean" else K).reshape(-1),
                        half, half ** 2, rejected.reshape(n1, -1), K.reshape(-1),
                        used.reshape(-1), K_var.reshape(-1))
    none = used == 0
    count = int(none.sum())
    if count:
        K[none] = median_map(slopes[:, none])
    return K, rejected, used, K_var, count


def local_mean(e: np.ndarray, window: int, out: np.ndarray) -> None:
    """ē = ``uniform_filter(e, window, mode="reflect")`` (float64) into ``out``.

    The compiled :func:`box_mean` repeats scipy's running sums operation for operation (with
    scipy 1.17 the same bits; ``tests/test_fixedpattern.py`` checks it to rounding) without
    scipy's strided column pass, which took most of the filter's time (0.2 s of 0.26 s on a
    2048² float64 map); frames smaller than the window, whose mirrored border folds more than
    once, go to scipy.
    """
    if e.shape[0] < window or e.shape[1] < window:
        uniform_filter(e, size=window, mode="reflect", output=out)
    else:
        box_mean(np.ascontiguousarray(e, dtype=np.float64), window, out)


@numba.njit(cache=True, nogil=True)
def box_mean(e, size, out):  # pragma: no cover - compiled
    """scipy.ndimage.uniform_filter(e, size, mode="reflect") of a 2-D float64 array, H, W ≥ size.

    Per line, scipy sums the first ``size`` values of the mirrored line, then adds the entering
    and subtracts the leaving value per step, each output being the running sum / ``size``;
    first along the columns (here a row of running sums at a time, into ``out``), then along the
    rows of that (each row copied to a line buffer first).
    """
    h, w = e.shape
    s1 = size // 2                       # samples mirrored in before the first one
    tmp = np.zeros(w)
    for k in range(size):                # the first window of every column
        r = k - s1
        r = -r - 1 if r < 0 else r
        for x in range(w):
            tmp[x] += e[r, x]
    for x in range(w):
        out[0, x] = tmp[x] / size
    for y in range(1, h):
        r_in = y - 1 + size - s1
        r_in = 2 * h - r_in - 1 if r_in >= h else r_in
        r_out = y - 1 - s1
        r_out = -r_out - 1 if r_out < 0 else r_out
        for x in range(w):
            tmp[x] += e[r_in, x] - e[r_out, x]
            out[y, x] = tmp[x] / size
    row_means(out, tmp, size)


@numba.njit(cache=True, nogil=True)
def row_means(out, line, size):  # pragma: no cover - compiled
    """The row pass of the box mean (scipy's running sum along each row, the mirror rule at the
    ends), in place on every row of ``out``; ``line`` is a scratch row."""
    w = out.shape[1]
    s1 = size // 2
    for y in range(out.shape[0]):
        line[:] = out[y]
        t = 0.0
        for k in range(size):
            c = k - s1
            c = -c - 1 if c < 0 else c
            t += line[c]
        out[y, 0] = t / size
        for x in range(1, w):
            c_in = x - 1 + size - s1
            c_in = 2 * w - c_in - 1 if c_in >= w else c_in
            c_out = x - 1 - s1
            c_out = -c_out - 1 if c_out < 0 else c_out
            t += line[c_in] - line[c_out]
            out[y, x] = t / size


@numba.njit(cache=True, nogil=True)
def box_mean_band(e, size, h, ys, y0, tmp, out):  # pragma: no cover - compiled
    """Rows ``y0 .. y0 + len(out)`` of :func:`box_mean` of an ``h``-row frame, from the rows
    ``ys ..`` of it held in ``e`` (the band and its halo) and the column running sums ``tmp``
    after row ``y0 − 1`` (ignored when ``y0 = 0``; left after the band's last row).

    The same operations in the same order as :func:`box_mean`: scipy's column pass is a running
    sum down each column, so row y's ē depends on the rounding of every row above; carrying
    ``tmp`` from band to band keeps it.  Needs rows ``y0 − 1 − m//2 .. y0 + rows − 1 + m//2`` of
    the frame (fewer at its top and bottom, mirrored as on the whole frame), ``h ≥ size``.
    """
    w = e.shape[1]
    rows = out.shape[0]
    s1 = size // 2
    for y in range(y0, y0 + rows):
        if y == 0:
            for x in range(w):
                tmp[x] = 0.0
            for k in range(size):
                r = k - s1
                r = -r - 1 if r < 0 else r
                for x in range(w):
                    tmp[x] += e[r - ys, x]
            for x in range(w):
                out[0, x] = tmp[x] / size
        else:
            r_in = y - 1 + size - s1
            r_in = 2 * h - r_in - 1 if r_in >= h else r_in
            r_out = y - 1 - s1
            r_out = -r_out - 1 if r_out < 0 else r_out
            for x in range(w):
                tmp[x] += e[r_in - ys, x] - e[r_out - ys, x]
                out[y - y0, x] = tmp[x] / size
    row_means(out, np.empty(w), size)


#: numpy's pairwise summation: blocks of at most this many values are summed 8-way unrolled
PW_BLOCK = 128


def pw_leaves(n: int, lo: int = 0, hi: int | None = None) -> list[tuple[int, int]]:
    """The blocks ``(start, length)`` of numpy's pairwise sum of ``n`` contiguous values (its
    recursion: halve, rounding the first half down to a multiple of 8, down to ≤ 128 values),
    in order, those that meet ``lo .. hi`` only."""
    hi = n if hi is None else hi
    out: list[tuple[int, int]] = []
    stack = [(0, n)]
    while stack:
        s, m = stack.pop()
        if s >= hi or s + m <= lo or m == 0:
            continue
        if m <= PW_BLOCK:
            out.append((s, m))
            continue
        n2 = m // 2
        n2 -= n2 % 8
        stack.append((s + n2, m - n2))
        stack.append((s, n2))
    return out


@numba.njit(cache=True, nogil=True)
def pw_block(a):  # pragma: no cover - compiled
    """numpy's pairwise-sum block (≤ 128 values of a 1-D float64 array): a plain loop below 8
    values, else 8 running sums combined as ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7)),
    then the rest."""
    n = a.shape[0]
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[i]
        return res
    r = a[:8].copy()
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] += a[i + j]
        i += 8
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        res += a[i]
        i += 1
    return res


def pw_pieces(values: np.ndarray, lo: int, n: int) -> tuple:
    """One band's share of numpy's pairwise sum of ``n`` values: ``values`` (flat float64) are
    the values ``lo .. lo + len(values)``; returns ``(first, sums, last)``: the sums of the
    blocks inside, and the band's part ``(start, length, values)`` of a block that begins before
    it (``first``) or ends after it (``last``), else ``None``."""
    hi = lo + values.size
    first = last = None
    inside = []
    for s, m in pw_leaves(n, lo, hi):
        if s >= lo and s + m <= hi:
            inside.append((s - lo, m))
        else:
            part = (s, m, values[max(s, lo) - lo:min(s + m, hi) - lo].copy())
            if s < lo:
                first = part
            else:
                last = part
    blocks = np.array(inside, dtype=np.int64).reshape(-1, 2)
    sums = np.empty(len(blocks))
    pw_blocks(values, blocks, sums)
    return first, sums, last


@numba.njit(cache=True, nogil=True)
def pw_blocks(values, blocks, out):  # pragma: no cover - compiled
    """:func:`pw_block` of ``values[start:start + length]`` per row of ``blocks``."""
    for k in range(blocks.shape[0]):
        out[k] = pw_block(values[blocks[k, 0]:blocks[k, 0] + blocks[k, 1]])


@numba.njit(cache=True, nogil=True)
def pw_tree(m, sums, pos):  # pragma: no cover - compiled
    """numpy's pairwise recursion over ``m`` values whose blocks' sums are ``sums[pos:]``:
    (the sum, the next block's position)."""
    if m <= PW_BLOCK:
        return sums[pos], pos + 1
    n2 = m // 2
    n2 -= n2 % 8
    left, pos = pw_tree(n2, sums, pos)
    right, pos = pw_tree(m - n2, sums, pos)
    return left + right, pos


def pw_total(n: int, pieces: Iterable[tuple]) -> float:
    """``numpy.sum`` of the ``n`` values whose bands gave ``pieces`` (:func:`pw_pieces`, in
    order): the same blocks and the same additions, so the same bits."""
    sums: list[float] = []
    pending: list = []

    def feed(part: tuple | None) -> None:
        if part is not None:
            pending.append(part[2])
            if sum(v.size for v in pending) == part[1]:   # the block is complete
                sums.append(pw_block(np.concatenate(pending)))
                pending.clear()

    for first, block_sums, last in pieces:
        feed(first)
        sums.extend(block_sums.tolist())
        feed(last)
    return float(pw_tree(n, np.array(sums, dtype=np.float64), 0)[0])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def slope_moments(slopes, m_bar, sd):  # pragma: no cover - compiled
    """Eq. 48 per pixel j of the (n1, N) slopes: m̄ (mean of the finite slopes) and the sample
    standard deviation (ddof = 1) about it, float64, summed in configuration order."""
    n1, npix = slopes.shape
    for j in range(npix):
        s1 = 0.0
        cnt = 0
        for i in range(n1):
            m = np.float64(slopes[i, j])
            if np.isfinite(m):
                s1 += m
                cnt += 1
        mean = s1 / cnt
        s2 = 0.0
        for i in range(n1):
            d = np.float64(slopes[i, j]) - mean
            if np.isfinite(d):
                s2 += d * d
        m_bar[j] = mean
        sd[j] = np.sqrt(s2 / (cnt - 1))


def median_map(slopes: np.ndarray) -> np.ndarray:
    """Per-pixel median of the (n1, ...) float32 slopes, NaNs left out (NaN where all are NaN),
    as ``numpy.nanmedian`` gives it, float64 of shape ``slopes.shape[1:]``."""
    out = np.empty(slopes.shape[1:])
    median_slopes(np.ascontiguousarray(slopes).reshape(slopes.shape[0], -1), out.reshape(-1))
    return out


@numba.njit(cache=True, nogil=True)
def median_slopes(slopes, out):  # pragma: no cover - compiled
    """Median of the non-NaN values of each column j of the (n1, N) float32 ``slopes``: the
    middle value, or the float32 mean of the two middle values (as ``numpy.median`` of float32).

    Blocks of pixels are sorted together by odd-even transposition (n1 rounds of
    compare-exchanges between neighbouring configurations, vectorised over the pixels of the
    block; NaN counts as +inf and is not counted), then each pixel takes its middle values.
    """
    n1, npix = slopes.shape
    B = 256
    tmp = np.empty((n1, B), np.float32)
    cnt = np.empty(B, np.int64)
    for j0 in range(0, npix, B):
        nb = min(B, npix - j0)
        for b in range(nb):
            cnt[b] = 0
        for i in range(n1):
            for b in range(nb):
                v = slopes[i, j0 + b]
                nan = np.isnan(v)
                tmp[i, b] = np.inf if nan else v
                cnt[b] += 0 if nan else 1
        for r in range(n1):
            for i in range(r % 2, n1 - 1, 2):
                for b in range(nb):
                    lo = tmp[i, b]
                    hi = tmp[i + 1, b]
                    tmp[i, b] = lo if lo < hi else hi
                    tmp[i + 1, b] = hi if lo < hi else lo
        for b in range(nb):
            k = cnt[b]
            if k == 0:
                out[j0 + b] = np.nan
            elif k % 2:
                out[j0 + b] = tmp[k // 2, b]
            else:
                out[j0 + b] = (tmp[k // 2 - 1, b] + tmp[k // 2, b]) / np.float32(2.0)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def reject_and_average(slopes, centre, half, half2, rejected, K, used,
                        K_var):  # pragma: no cover - compiled
    """Eq. 49 per pixel j of the (n1, N) slopes (``centre`` may be ``K``: each pixel's centre
    is read before its K̂ is written).

    A slope is kept when |m_i − centre| ≤ half (NaN slopes are rejected); K̂ is the mean of the
    kept slopes (float64, in configuration order; NaN where none is kept, for the caller to
    fill); ``K_var`` = Σ(m_i − K̂)²/((n'_1 − 1)·n'_1) over the kept slopes, or
    half²/max(n'_1, 1) where fewer than two are kept.
    """
    n1, npix = slopes.shape
    for j in range(npix):
        c = centre[j]
        s1 = 0.0
        n = 0
        for i in range(n1):
            m = np.float64(slopes[i, j])
            keep = abs(m - c) <= half
            rejected[i, j] = not keep
            if keep:
                s1 += m
                n += 1
        k = s1 / n
        ss = 0.0
        for i in range(n1):
            m = np.float64(slopes[i, j])
            if abs(m - c) <= half:
                d = m - k
                ss += d * d
        K[j] = k
        used[j] = n
        K_var[j] = ss / ((n - 1.0) * n) if n >= 2 else half2 / max(n, 1)


# --------------------------------------------------------------------------------------------
# the result: what the streamed and the cluster paths assemble from the same maps
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class FixedPattern:
    """The fixed-pattern map K̂(a, b) of eq. 49 and its diagnostics.

    Attributes
    ----------
    K
        K̂(a, b), float64 (H, W) (eq. 49).
    n1_used
        n'_1(a, b): slopes kept per pixel (int16 map).
    rejected
        (n1, H, W) boolean: ``rejected[i, a, b]`` is True when configuration i's slope at (a, b)
        was removed as an outlier (chosen over a count map because it shows *which*
        configuration had the spot; the count is ``n1 − n1_used``).
    m_bar
        m̄(a, b), the mean of the n1 slopes (eq. 48).
    sigma_hat
        σ̂, the per-pixel sample std of the slopes averaged over locations.
    p, window, n1, n2
        Rejection width (in σ̂), local window m, configurations, frames per configuration (the
        smallest n2 when configurations differ).
    var_bound
        (p·σ̂)²/n̂_1 with n̂_1 = min n'_1 (eq. 50).
    mean, spatial_std
        Mean and std (ddof = 0) of K̂ over the array (paper: 0.99998, 3.72e-3).
    config_ids, config_levels
        Configuration ids and the mean of e_i (DN above dark) per configuration.
    noise_var_e
        Mean over configurations and pixels of the temporal variance of e_i from the n2 frames,
        σ²_N/n2 (NaN when n2 = 1).
    notes
        Warnings (few configurations, fallbacks ...).
    K_var
        Per-pixel variance of K̂ (the squared standard error of the mean of eq. 49): the sample
        variance of the n'_1 kept slopes divided by n'_1; where fewer than two slopes are kept,
        the eq. 50 bound (p·σ̂)²/max(n'_1, 1).  Measured, so usually well below the bound.
    """

    K: np.ndarray
    n1_used: np.ndarray
    rejected: np.ndarray
    m_bar: np.ndarray
    sigma_hat: float
    p: float
    window: int
    n1: int
    n2: int
    var_bound: float
    mean: float
    spatial_std: float
    config_ids: tuple = ()
    config_levels: tuple[float, ...] = ()
    noise_var_e: float = float("nan")
    notes: tuple[str, ...] = ()
    K_var: np.ndarray | None = None

    @property
    def n1_hat(self) -> int:
        """n̂_1: the smallest n'_1 over the image (eq. 50)."""
        return int(self.n1_used.min())

    @property
    def worst_ratio(self) -> float:
        """n1/n̂_1, configurations captured per configuration kept at the worst pixel (sec. V-B);
        used by :func:`ccdcore.planning.plan_acquisition`."""
        return self.n1 / self.n1_hat if self.n1_hat > 0 else float("inf")

    def summary(self) -> FixedPatternSummary:
        """The summary statistics (no maps) as the record a product stores
        (``estimates["fixed_pattern"]``): plain numbers, infinite bounds and NaN as ``None``."""
        bounded = math.isfinite(self.var_bound)
        return FixedPatternSummary(
            n1=json_safe(self.n1), n2=json_safe(self.n2), window=json_safe(self.window),
            p=json_safe(self.p), shape=tuple(int(n) for n in self.K.shape),
            mean=json_safe(self.mean), spatial_std=json_safe(self.spatial_std),
            sigma_hat=json_safe(self.sigma_hat), n1_hat=self.n1_hat,
            # None when some pixel kept no slope (n̂_1 = 0): the bound of eq. 50 is then infinite
            var_bound=json_safe(self.var_bound),
            sd_bound=json_safe(math.sqrt(self.var_bound)) if bounded else None,
            worst_ratio=json_safe(self.worst_ratio),
            fraction_pixels_with_rejection=float(np.mean(self.n1_used < self.n1)),
            n_rejected=int(self.rejected.sum()),
            config_ids=tuple(json_safe(c) for c in self.config_ids),
            config_levels=tuple(json_safe(v) for v in self.config_levels),
            noise_var_e=json_safe(self.noise_var_e),
            K_var_mean=json_safe(float(np.mean(self.K_var))) if self.K_var is not None else None,
            notes=tuple(self.notes))

    def to_dict(self) -> dict[str, Any]:
        """Summary statistics only (no maps), JSON-friendly: :meth:`summary` as its JSON
        object."""
        return self.summary().to_dict()


@dataclass(frozen=True)
class FixedPatternSummary(Record):
    """The fixed-pattern map K̂ (eqs. 45–50) as a product stores it
    (``estimates["fixed_pattern"]``, :meth:`FixedPattern.summary`): its statistics and
    diagnostics; the maps are stored apart."""

    #: configurations n1 and frames per configuration n2 (the smallest when they differ)
    n1: int
    n2: int
    #: the local window m (pixels) and the rejection width p (in σ̂)
    window: int
    p: float
    #: the shape (H, W) of K̂
    shape: tuple[int, int]
    #: mean and std (ddof = 0) of K̂ over the array (paper: 0.99998, 3.72e-3)
    mean: float
    spatial_std: float
    #: σ̂, the per-pixel sample std of the slopes averaged over locations (eq. 48)
    sigma_hat: float
    #: n̂_1 = min n'_1, the fewest slopes kept at a pixel (eq. 50)
    n1_hat: int
    #: the bound (p·σ̂)²/n̂_1 of eq. 50 on the error variance of K̂ and its square root
    #: (``None``: infinite, some pixel kept no slope)
    var_bound: float | None
    sd_bound: float | None
    #: n1/n̂_1, configurations captured per configuration kept at the worst pixel (sec. V-B;
    #: ``None``: infinite)
    worst_ratio: float | None
    #: fraction of pixels with a rejected slope, and the slopes rejected in all (eq. 49)
    fraction_pixels_with_rejection: float
    n_rejected: int
    #: configuration ids and the mean of e_i (DN above dark) per configuration
    config_ids: tuple[int | str, ...]
    config_levels: tuple[float, ...]
    #: mean temporal variance σ²_N/n2 of e_i, DN² (``None`` when n2 = 1)
    noise_var_e: float | None
    #: mean of the per-pixel error variance of K̂ (``None``: not measured)
    K_var_mean: float | None
    #: warnings (few configurations, fallbacks ...)
    notes: tuple[str, ...] = ()

    def rows(self) -> tuple[Row, ...]:
        """The headline figures: configurations and frames, the statistics of K̂, σ̂, its
        measured error and the eq. 50 bound, the pixels with a rejected slope."""
        k_sd = math.sqrt(self.K_var_mean) if self.K_var_mean is not None else None
        return (
            Row("configurations n1", self.n1, meaning="card/lamp positions (sec. V-B)"),
            Row("frames n2", self.n2, meaning="frames per configuration"),
            Row("mean of K̂", self.mean, meaning="each pixel's relative gain, no unit"),
            Row("spatial spread of K̂", self.spatial_std, meaning="standard deviation"),
            Row("slope spread σ̂", self.sigma_hat, meaning="eq. 48"),
            Row("error of K̂ (mean)", k_sd, meaning="√ of the mean error variance"),
            Row("eq. 50 bound", self.var_bound, meaning="error variance bound (p·σ̂)²/n̂_1",
                text="infinite" if self.var_bound is None else None),
            Row("pixels with a rejected slope", 100.0 * self.fraction_pixels_with_rejection,
                None, "%", f"{self.n_rejected} slopes rejected in all (eq. 49)"),
        )


def fixed_pattern_of(K: np.ndarray, used: np.ndarray, rejected: np.ndarray, m_bar: np.ndarray,
            K_var: np.ndarray, *, sigma_hat: float, p: float, window: int, center: str,
            none: int, ids: list, levels: list, noises: list, n2s: list,
            notes: list[str]) -> FixedPattern:
    """The :class:`FixedPattern` of the maps of eqs. 48–49: notes, n̂_1 and the bound of eq. 50,
    and the summary statistics over the whole maps."""
    if len(set(n2s)) > 1:
        notes.append(f"configurations have different frame counts ({min(n2s)}..{max(n2s)})")
    if none:
        notes.append(f"{none} pixel(s) kept no slope inside the centre ± p·σ̂ "
                     f"(centre = {center}); K̂ there is the median slope and n'_1 = 0")
    half = p * sigma_hat
    n1_hat = int(used.min())
    var_bound = half ** 2 / n1_hat if n1_hat > 0 else float("inf")   # eq. 50
    n2_min = min(n2s)
    noise_e = float(np.nanmean(noises)) if n2_min > 1 else float("nan")
    return FixedPattern(K=K, n1_used=used, rejected=rejected, m_bar=m_bar,
                        sigma_hat=sigma_hat, p=float(p), window=window, n1=len(ids), n2=n2_min,
                        var_bound=var_bound, mean=float(np.nanmean(K)),
                        spatial_std=float(np.nanstd(K)), config_ids=tuple(ids),
                        config_levels=tuple(levels), noise_var_e=noise_e, notes=tuple(notes),
                        K_var=K_var)
