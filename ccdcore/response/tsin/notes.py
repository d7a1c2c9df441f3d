"""What a user of a sec. 3.2 curve should be told, and the pool the paper's Fig. 3c-d shows:
the notes of :func:`ccdcore.response.tsin.estimator.estimate` (the sample, convergence, the pool
threshold, the white balance's gauge, exposures the fit could not explain, a noise term forced to
0) and the relative prediction errors of one pool before and after calibration.

Public objects
--------------
estimate_notes(opts, data, s, ...)
    The notes of one channel's fit.
pick_pool(s, resid, gk, like=None)
    One pool's relative prediction errors (the pool at about 78 % of full scale).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..brackets import BracketData

__all__ = ["estimate_notes", "pick_pool"]


def estimate_notes(opts: Any, data: BracketData, s: Any, *, sampled: int,
                   converged: bool, step: float, chi2: float, theta: NDArray) -> list[str]:
    """What a user of the curve should know: the sample, convergence, the pool threshold,
    the white balance's gauge, exposures the fit could not explain, a noise term forced to 0."""
    notes = []
    if sampled:
        notes.append(f"estimated on an even sample of {data.n_pixels} of the bracket's "
                     f"{sampled} pixels (memory bound)")
    if not converged:
        notes.append(f"stopped after {opts.max_iter} iterations (last mean |Δg| {step:.1e}, "
                     f"tolerance {opts.tol:.0e})")
    if s.min_pool < opts.min_pool:
        notes.append(f"pools of at least {s.min_pool} pixels counted (the bracket is small; "
                     f"sec. 4.1 used {opts.min_pool})")
    if opts.white_balance:
        notes.append("gains a_k and offsets b_k estimated (white balance, exposure errors), "
                     "with ln(a_k/t_k) of zero mean and zero trend in ln t_k and the offsets b_k "
                     "of smallest norm (the bracket cannot fix those: a common gain, sec. 3.2's "
                     "u-ambiguity, an offset of g and one of the radiance)")
    if chi2 > 3.0:
        cause = ("the gains and offsets do not explain the exposures" if opts.white_balance else
                 "the images do not follow the exposures taken (white balance or shutter "
                 "errors)")
        notes.append(f"the pools' errors are {math.sqrt(chi2):.1f} times their expected "
                     f"size (chi²/dof {chi2:.0f}): {cause}, or the scene moved; g may be "
                     "distorted (the verdict weighs it by the prediction agreement)")
    if theta[2] == 0 or theta[0] == 0:
        notes.append("a noise term was forced to 0 by the non-negative fit (sec. 4.1: when g and "
                     "g'² look alike, shot and output noise cannot be told apart)")
    return notes


def pick_pool(s: Any, resid: NDArray, gk: NDArray, like: dict | None = None
              ) -> dict[str, Any]:
    """The relative prediction errors of one pool (the paper's Fig. 3c-d shows the pool at code
    199 of 255): the largest row whose pool code is nearest 78 % of full scale."""
    if like and "row" in like:
        r = int(like["row"])
    else:
        target = 0.78 * (s.data.levels - 1)
        codes = s.knots.codes[s.rows[:, 1]]
        n = np.diff(s.offsets)
        d = np.abs(codes - target)
        cand = np.flatnonzero(d == d.min())
        r = int(cand[np.argmax(n[cand])])
    j, m, k = (int(v) for v in s.rows[r])
    gm = float(gk[m]) if gk[m] > 0 else 1.0
    vals = resid[s.offsets[r]:s.offsets[r + 1]] / gm
    return {"row": r, "pool_image": j, "code": float(s.knots.codes[m]), "predicted_image": k,
            "values": vals.copy()}
