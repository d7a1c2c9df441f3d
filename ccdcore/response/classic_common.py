"""What the classic inverse-response estimators of :mod:`ccdcore.response.classic` share: the
bracket checked and packed for them, and their curve finished on the reported scale.

Public objects
--------------
Checked
    One channel's bracket as the classic methods read it: codes (the smallest unsigned type, 0
    where not usable), mask, increasing exposure times and the usable observations per code, per
    image and code, and per pixel.
check_bracket(data, method, pairs=False)
    The bracket's arrays, checked for what every method needs; images sorted by exposure.
finish_curve(g, known, weights, levels, notes, where, method)
    Codes without data filled, g made non-decreasing and put on the reported scale.
code_dtype(levels)
    The smallest unsigned integer type holding the codes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import isotonic_regression

from ..errors import CcdError
from .brackets import BracketData
from .scale import normalize, reference_codes

__all__ = ["Checked", "check_bracket", "finish_curve", "code_dtype"]


@dataclass(frozen=True, eq=False)
class Checked:
    where: str
    z: NDArray[np.unsignedinteger]  # (N, P) codes, 0 wherever not usable; uint8/uint16/uint32
    valid: NDArray[np.bool_]        # (N, P)
    t: NDArray[np.float64]          # (N,), increasing
    levels: int
    counts: NDArray[np.int64]       # usable observations per code
    row_counts: NDArray[np.int64]   # (N, levels) usable observations per image and code
    n_valid: NDArray[np.integer]    # (P,) usable observations per pixel


def code_dtype(levels: int) -> type:
    """The smallest unsigned integer type holding the codes ``0 .. levels - 1``."""
    return np.uint8 if levels <= 2 ** 8 else np.uint16 if levels <= 2 ** 16 else np.uint32


def _per_pixel_count(valid: NDArray[np.bool_]) -> NDArray[np.integer]:
    """Usable observations of every pixel (a row-by-row sum: several times faster than
    ``valid.sum(axis=0)`` on a wide bracket)."""
    n = valid.shape[0]
    out = np.zeros(valid.shape[1], np.uint8 if n < 256 else np.int64)
    for row in valid:
        out += row
    return out


def check_bracket(data: BracketData, method: str, *, pairs: bool = False) -> Checked:
    """The bracket's arrays, checked for what every method needs; images sorted by exposure."""
    where = data.files[0] if data.files else f"channel {data.channel}"
    z = np.asarray(data.z)
    valid = np.asarray(data.valid, dtype=bool)
    t = np.asarray(data.t, dtype=np.float64).reshape(-1)
    levels = int(data.levels)
    if z.ndim != 2 or valid.shape != z.shape or t.size != z.shape[0]:
        raise CcdError(where, f"{method}: inconsistent bracket: codes {z.shape}, mask "
                              f"{valid.shape}, {t.size} exposure times")
    n = z.shape[0]
    if n < 2:
        raise CcdError(where, f"{method} needs at least two exposures, the bracket has {n}")
    if levels < 2:
        raise CcdError(where, f"{method}: the bracket has {levels} code levels")
    if not (np.all(np.isfinite(t)) and np.all(t > 0)):
        raise CcdError(where, f"{method}: exposure times must be positive, got {t.tolist()}")
    if np.any(np.diff(t) <= 0):              # brackets arrive sorted: reorder only when not
        order = np.argsort(t, kind="stable")
        t, z, valid = t[order], z[order], valid[order]
        if np.any(np.diff(t) <= 0):
            raise CcdError(where, f"{method}: two images have the same exposure time")
    if not valid.any():
        raise CcdError(where, f"{method}: channel {data.channel} has no usable observation "
                              "(every code clipped, near a saturated pixel or on the border)")
    zc = np.where(valid, z, 0)                # one pass; the codes' range checked on it
    if zc.min() < 0 or zc.max() >= levels:
        zv = z[valid]
        raise CcdError(where, f"{method}: codes {int(zv.min())}..{int(zv.max())} fall outside "
                              f"0..{levels - 1}")
    # the smallest unsigned type: every later pass over the codes reads less memory
    zc = zc.astype(code_dtype(levels), copy=False)
    # row by row (faster than one pass over (N, P)), the masked observations (code 0 in zc)
    # taken out
    row_counts = np.stack([np.bincount(row, minlength=levels) for row in zc])
    row_counts[:, 0] -= np.array([valid.shape[1] - np.count_nonzero(row) for row in valid])
    counts = row_counts.sum(axis=0)
    if np.count_nonzero(counts) < 2:
        only = int(np.flatnonzero(counts)[0])
        raise CcdError(where, f"{method}: only one code ({only}) has usable data; a "
                              "response needs at least two")
    n_valid = _per_pixel_count(valid)
    if pairs:
        if not any(np.any(valid[k] & valid[k + 1]) for k in range(n - 1)):
            raise CcdError(where, f"{method}: no pixel is usable in two consecutive exposures, "
                                  "nothing links the images")
    elif not np.any(n_valid >= 2):
        raise CcdError(where, f"{method}: no pixel is usable in two exposures, nothing links "
                              "the images")
    return Checked(where, zc, valid, t, levels, counts, row_counts, n_valid)


def _span(mask: NDArray[np.bool_]) -> str:
    """Codes where ``mask`` is True as compact ranges, e.g. ``"0, 255"`` or ``"0..3"``."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return ""
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]])
    parts = [f"{a}" if a == b else f"{a}..{b}" for a, b in zip(starts.tolist(), ends.tolist())]
    if len(parts) > 6:
        parts = parts[:3] + ["..."] + parts[-2:]
    return ", ".join(parts)


def finish_curve(g: NDArray[np.float64], known: NDArray[np.bool_], weights: NDArray[np.float64],
            levels: int, notes: list[str], where: str, method: str) -> NDArray[np.float64]:
    """Fill codes without data, make g non-decreasing, put it on the reported scale."""
    g = np.asarray(g, dtype=np.float64).copy()
    known = known & np.isfinite(g)
    codes = np.arange(levels)
    kc = np.flatnonzero(known)
    if kc.size < 2:
        raise CcdError(where, f"{method}: fewer than two codes with a usable estimate")
    lo, hi = int(kc[0]), int(kc[-1])
    inner = ~known & (codes > lo) & (codes < hi)
    if inner.any():
        g[inner] = np.interp(codes[inner], kc, g[kc])
        notes.append(f"codes {_span(inner)} have no data: interpolated")
    k_end = max(3, int(round(0.02 * levels)))
    if lo > 0:
        sel = kc[:k_end]
        if sel.size >= 2:
            slope, icpt = np.polyfit(sel.astype(np.float64), g[sel], 1)
            line = slope * codes[:lo] + icpt
        else:
            line = np.full(lo, g[lo])
        g[:lo] = np.clip(line, min(0.0, g[lo]), g[lo])
        notes.append(f"codes {_span(codes < lo)} have no data: extrapolated")
    if hi < levels - 1:
        sel = kc[-k_end:]
        if sel.size >= 2:
            slope, icpt = np.polyfit(sel.astype(np.float64), g[sel], 1)
            line = slope * codes[hi + 1:] + icpt
        else:
            line = np.full(levels - 1 - hi, g[hi])
        g[hi + 1:] = np.maximum(line, g[hi])
        notes.append(f"codes {_span(codes > hi)} have no data: extrapolated")
    w = np.maximum(np.asarray(weights, dtype=np.float64), 1.0)
    if np.any(np.diff(g) < 0):
        mono = isotonic_regression(g, weights=w, increasing=True).x
        moved = np.abs(mono - g) > 1e-12 * max(1.0, float(np.max(np.abs(g))))
        notes.append(f"monotonicity enforced (pool-adjacent-violators) on codes {_span(moved)}")
        g = mono
    z_lo, z_hi = reference_codes(levels)
    if not g[z_hi] > 0:
        raise CcdError(where, f"{method}: the fitted response is not positive at the reference "
                              f"code {z_hi}: the bracket does not support this method")
    g = normalize(g, levels)[0]
    g[z_hi] = z_hi / (levels - 1)             # exact, whatever the rounding of s * g
    g[:z_hi] = np.minimum(g[:z_hi], g[z_hi])
    g[z_hi + 1:] = np.maximum(g[z_hi + 1:], g[z_hi])
    return g
