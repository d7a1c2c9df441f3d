"""One verdict per response result: trusted, doubtful or failed, computed here once and shown in
the same words by every verb (``response``, ``hdr``, ``calibrate``, ``change``), the report,
``--json``, the Response & HDR page and the Walkthrough's gate.

A response curve is judged by what it does on the user's own bracket (Tsin, Ramesh & Kanade
2001, sec. 4.2: each image predicted from its neighbour through the curve and the exposure
ratio), by whether its fit moved and stopped improving, and against another method's curve on
the same bracket:

``failed``
    A curve still at its starting line (the fit never moved), a collapsed curve (flat over a
    tenth of the readable codes), or no agreement at all (nothing to predict).
``doubtful``
    A fit that stopped without converging; images that disagree with the exposures the result
    used (RMS more than :data:`EXPOSURE_FACTOR` times the RMS with each pair's ratio fitted
    plus :data:`EXPOSURE_DN`); another method's curve that predicts the bracket clearly better
    (RMS below the result's by more than :data:`BETTER_FACTOR` and :data:`BETTER_DN`); the
    bracket's own exposures used but their estimate did not settle.
``trusted``
    None of these.

Each verdict names the frames involved and gives at most one next step: a flag of the command
that printed it (``--exposures estimated``, ``--method NAME``, ``--method NAME without
--white-balance`` -- also ``--method tsin without --white-balance`` for a gains' fit that did
not converge), only where it helps the case that triggered it (the tests run the suggestions
through the command line).

Public objects
--------------
ResponseVerdict
    The record (``calibration.json``'s ``response.verdict``; ``--json``'s ``"verdict"``), with
    ``line()``, the words every surface prints.
response_verdict(result, challengers)
    The verdict of a :class:`ccdcore.response.methods.ResponseResult`.
TRUSTED, DOUBTFUL, FAILED
    The three statuses.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..records import Record, Row
from .agreement import code_range

__all__ = ["ResponseVerdict", "response_verdict", "TRUSTED", "DOUBTFUL", "FAILED",
           "EXPOSURE_FACTOR", "EXPOSURE_DN", "BETTER_FACTOR", "BETTER_DN", "at_start",
           "longest_flat_run"]

TRUSTED, DOUBTFUL, FAILED = "trusted", "doubtful", "failed"
#: images disagree with the exposures used when the RMS with them exceeds this factor times ...
EXPOSURE_FACTOR = 1.5
#: ... the RMS with each pair's ratio fitted, plus this (DN)
EXPOSURE_DN = 1.0
#: another curve is clearly better when its RMS is below the result's divided by this ...
BETTER_FACTOR = 1.10
#: ... and by more than this (DN)
BETTER_DN = 0.25
#: a curve within this of the straight starting line (fraction of full scale, every readable
#: code) has not moved
START_TOLERANCE = 1e-6


@dataclass(frozen=True)
class ResponseVerdict(Record):
    """Whether a response result can be trusted, in plain words (see the module notes)."""

    #: "trusted", "doubtful" or "failed"
    status: str
    #: why, in plain words
    reason: str
    #: the frames involved (file names), empty when none stands out
    frames: tuple[str, ...] = ()
    #: the one next step that helps (a flag of the command), empty when none
    next_step: str = ""
    #: how the frames were registered before the fit (:meth:`ccdcore.response.align.Alignment.describe`;
    #: empty when not tried)
    registration: str = ""
    #: the pixels whose exposures disagree, left out of the fit and merged from one exposure
    #: (:meth:`ccdcore.response.moving.MovingPixels.describe`; empty when not tested)
    moving: str = ""

    def line(self) -> str:
        """The verdict in one line, as every surface prints it."""
        out = f"{self.status}: {self.reason}"
        if self.frames:
            out += f" (frames {', '.join(self.frames)})"
        if self.next_step:
            out += f"; next step: {self.next_step}"
        return out

    def details(self) -> tuple[str, ...]:
        """The frames' registration and the moving pixels, a line each (those known)."""
        return tuple(t for t in (self.registration, self.moving) if t)

    @property
    def trusted(self) -> bool:
        return self.status == TRUSTED

    def rows(self) -> tuple[Row, ...]:
        """The status as its value, the whole line as its meaning (wrapped); then the
        registration and the moving pixels, where known."""
        out = [Row("verdict", None, None, "", self.line(), self.status)]
        if self.registration:
            out.append(Row("registration", None, None, "", self.registration, ""))
        if self.moving:
            out.append(Row("moving objects", None, None, "", self.moving, ""))
        return tuple(out)


def longest_flat_run(g: Any, levels: int) -> int:
    """The longest run of readable codes over which g does not rise."""
    lo, hi = code_range(levels)
    g = np.asarray(g, np.float64)[lo:hi + 1]
    flat = np.diff(g) <= 1e-9 * max(float(g[-1] - g[0]), 1e-300)
    best = cur = 0
    for v in flat.tolist():
        cur = cur + 1 if v else 0
        best = max(best, cur)
    return best


def at_start(g: Any, levels: int) -> bool:
    """Whether g is still the straight starting line g = z / (levels − 1) on the readable codes
    (on the reported scale, which keeps that line)."""
    lo, hi = code_range(levels)
    g = np.asarray(g, np.float64)
    z = np.arange(g.size, dtype=np.float64) / (levels - 1.0)
    return bool(np.max(np.abs(g[lo:hi + 1] - z[lo:hi + 1])) < START_TOLERANCE)


def _worst_pair_frames(result: Any) -> tuple[str, ...]:
    """The two frames of the pair whose images disagree most with the exposures used."""
    ag = result.agreement
    if ag is None:
        return ()
    worst = None
    for c in ag.channels:
        for p in c.pairs:
            if p.n > 0 and math.isfinite(p.rms) and math.isfinite(p.rms_fitted):
                gap = p.rms - p.rms_fitted
                if worst is None or gap > worst[0]:
                    worst = (gap, p.j, p.k)
    if worst is None:
        return ()
    files = result.files
    return tuple(str(files[i]) for i in (worst[1], worst[2]) if i < len(files))


def response_verdict(result: Any, challengers: Mapping[str, Any] | None = None
                     ) -> ResponseVerdict:
    """The verdict of ``result`` (a :class:`ccdcore.response.methods.ResponseResult`);
    ``challengers``: method name -> its :class:`ccdcore.response.agreement.Agreement` on the same
    bracket (and the same exposures)."""
    levels = int(result.levels)
    ag = result.agreement
    method = result.method
    exposures = getattr(result, "exposures", None)
    used_estimated = exposures is not None and exposures.used == "estimated"
    wb = any(r.white_balance for r in result.responses)
    # the images disagree with the exposures used: the cause to remove first
    off = (ag is not None and math.isfinite(ag.rms)
           and ag.rms > EXPOSURE_FACTOR * ag.rms_fitted + EXPOSURE_DN)
    step_exposures = "--exposures estimated" if off and not used_estimated and not wb else ""
    better = _better(result, challengers)
    # the challengers take the exposures as exact: with the gains estimated, the step drops them
    step_better = (f"--method {better[0]}" + (" without --white-balance" if wb else "")
                   if better else "")
    step_failed = step_exposures or step_better
    # failed: the fit never moved, a collapsed curve, nothing to predict
    stuck = [ch for ch, r in zip(result.channels, result.responses)
             if r.method == "tsin" and at_start(r.g, levels)]
    if stuck:
        return ResponseVerdict(
            FAILED, f"the fit of channel{'s' if len(stuck) > 1 else ''} {', '.join(stuck)} "
                    "never left its starting line g = z/(levels − 1): the curve is not an "
                    "estimate", _worst_pair_frames(result) if off else (), step_failed)
    lo, hi = code_range(levels)
    flat = [(ch, longest_flat_run(r.g, levels)) for ch, r in zip(result.channels,
                                                                 result.responses)]
    flat = [(ch, n) for ch, n in flat if n >= 0.1 * (hi - lo)]
    if flat:
        ch, n = flat[0]
        return ResponseVerdict(FAILED, f"g of channel {ch} is flat over {n} codes of "
                                       f"{lo}..{hi} (a collapsed curve): it cannot tell those "
                                       "codes apart", (), step_failed)
    if ag is None or not math.isfinite(ag.rms):
        return ResponseVerdict(FAILED, "no pair of neighbouring images shares readable codes: "
                                       "nothing checks the curve", (), "")
    # doubtful
    figures = (f"{ag.rms:.2f} DN RMS from a neighbour with its exposures, "
               f"{ag.rms_fitted:.2f} DN with each pair's ratio fitted")
    if off:
        return ResponseVerdict(DOUBTFUL, f"the images disagree with the exposures used "
                                         f"({figures})", _worst_pair_frames(result),
                               step_exposures)
    if better:
        name, rms_other = better
        return ResponseVerdict(DOUBTFUL, f"the {name} curve predicts this bracket clearly "
                                         f"better ({rms_other:.2f} DN against {ag.rms:.2f} DN "
                                         "RMS from a neighbour)", (), step_better)
    unconverged = [ch for ch, r in zip(result.channels, result.responses) if not r.converged]
    if unconverged:
        # the gains' joint fit can crawl along a direction the bracket barely fixes; the fit of
        # g alone (at the exposures used) stops
        step = f"--method {method} without --white-balance" if wb and method == "tsin" else ""
        return ResponseVerdict(DOUBTFUL, f"the fit of channel{'s' if len(unconverged) > 1 else ''}"
                                         f" {', '.join(unconverged)} stopped after "
                                         f"{max(r.iterations for r in result.responses)} "
                                         f"iterations without converging ({figures})", (), step)
    if used_estimated and not exposures.converged:
        return ResponseVerdict(DOUBTFUL, "the bracket's own exposures did not settle in "
                                         f"{exposures.iterations} alternations ({figures})",
                               (), "")
    own = " with the bracket's own exposures" if used_estimated else ""
    return ResponseVerdict(TRUSTED, f"the {method} curve converged{own} and predicts the images "
                                    f"within {figures}", (), "")


def _better(result: Any, challengers: Mapping[str, Any] | None) -> tuple[str, float] | None:
    """The challenger whose curve predicts the bracket clearly better than the result's."""
    ag = result.agreement
    if not challengers or ag is None or not math.isfinite(ag.rms):
        return None
    best = None
    for name, other in challengers.items():
        if name == result.method or other is None or not math.isfinite(other.rms):
            continue
        if other.rms * BETTER_FACTOR < ag.rms and ag.rms - other.rms > BETTER_DN:
            if best is None or other.rms < best[1]:
                best = (name, float(other.rms))
    return best
