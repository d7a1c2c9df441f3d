"""The held-out check of a flat field: a flat not used in the fit, corrected, against the noise
floor.

G and O (de Lasarte et al. 2007, eqs. 1–4) are made from N flats of one group; one more flat of
the same group, not in the fit, is corrected, ``DL_c = O + G·DL`` (eq. 2), and its SNUP
(eq. 5, ``100·σ/mean``, :func:`ccdcore.flatfield.uniformity.snup`, flagged pixels left out)
compared with the floor a perfect correction leaves: the flat's own temporal noise and that of the
N averaged base frames, carried through G::

    floor = 100 · sqrt(1 + 1/N) · sqrt(⟨G² · s²⟩) / ⟨DL_c⟩          per channel

with s² the per-pixel temporal variance of the N fitted flats (their sample variance, each
flat first scaled to a common mean level so that a lamp's frame-to-frame change of level, which
is not pixel noise, is left out; an estimate of the held-out flat's own) and ⟨·⟩ the channel's
mean.  The check passes when ``SNUP <= factor × floor`` (:data:`HELD_OUT_FACTOR`, 1.15): the
correction leaves at most 15 % more nonuniformity than noise alone; otherwise it warns.

What it catches and what it cannot: a wrong G (a flat of another group, another aperture or
focus, a gain map transposed or from other frames) and an O inconsistent with G (eq. 4 with
another dark than eq. 3's) raise the SNUP above the floor.  An error of the dark image DL_0
used consistently in G and O does *not* show here: a flat at the base's own level is corrected
to k + ⟨DL_0⟩ whatever DL_0 is (to first order); it shows only on frames at other levels.

Public objects
--------------
HELD_OUT_FACTOR
    1.15.
HeldOutChannel, HeldOutCheck
    The figures per channel and the verdict (records, stored in ``calibration.json``).
held_out_figures(ff, frame, ...)
    The check of one corrected frame against a :class:`~ccdcore.flatfield.fit.FlatField`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..channels import channel_slices
from ..common import json_safe
from ..records import Record, Row
from .uniformity import snup

__all__ = ["HELD_OUT_FACTOR", "HeldOutChannel", "HeldOutCheck", "held_out_figures"]

#: the check passes when the held-out flat's SNUP is at most this many times the noise floor
HELD_OUT_FACTOR = 1.15


@dataclass(frozen=True)
class HeldOutChannel(Record):
    """One channel of the held-out check (percentages of the corrected mean)."""

    name: str
    #: SNUP of the corrected held-out flat, %, and the floor sqrt(1 + 1/N)·temporal noise, %
    snup: float | None
    floor: float | None
    #: SNUP / floor
    ratio: float | None
    #: the temporal noise of one flat as a fraction of its corrected mean, % (no 1/N term)
    temporal: float | None
    #: SNUP of the held-out flat before correction, %
    snup_raw: float | None


@dataclass(frozen=True)
class HeldOutCheck(Record):
    """The held-out check of a flat field (module :mod:`ccdcore.flatfield.check`)."""

    #: relative path of the flat held out, and the number N of flats the maps were fitted on
    held_out: str
    n_fit: int
    #: the flat group ``(level, exposure)`` as text
    group: str
    #: the pass threshold on SNUP / floor, and the verdict ``"pass"`` or ``"warn"``
    factor: float
    verdict: str
    channels: tuple[HeldOutChannel, ...]
    #: what the dark image DL_0 was ("dark model at 23 s", "zero dark (DL_0 = 0)" ...)
    dark: str = ""
    rule: str = ("pass when SNUP(held-out flat corrected) <= factor × sqrt(1 + 1/N) × its "
                 "temporal noise as a fraction of its mean (noise carried through G)")

    @property
    def worst_ratio(self) -> float | None:
        vals = [c.ratio for c in self.channels if c.ratio is not None]
        return max(vals) if vals else None

    def text(self) -> str:
        """One line: verdict, SNUP against floor per channel."""
        parts = "; ".join(f"{c.name}: SNUP {_pct(c.snup)} vs floor {_pct(c.floor)} "
                          f"(× {c.ratio:.3f})" if c.ratio is not None else f"{c.name}: n/a"
                          for c in self.channels)
        return (f"{self.verdict}: {self.held_out} held out, maps from N = {self.n_fit} flats "
                f"({self.group}); {parts}; limit × {self.factor:g}")

    def rows(self) -> tuple[Row, ...]:
        out = [Row("held-out check", None, None, "", self.rule,
                   f"{self.verdict} ({self.held_out}, N = {self.n_fit})")]
        for c in self.channels:
            out.append(Row(f"held-out SNUP, {c.name}", c.snup, None, "%",
                           f"floor {_pct(c.floor)} (× {self.factor:g} allowed); before "
                           f"correction {_pct(c.snup_raw)}",
                           None if c.ratio is None else
                           f"{_pct(c.snup)} = {c.ratio:.3f} × floor"))
        return tuple(out)


def _pct(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.4g} %"


def held_out_figures(ff: Any, frame: Any, *, n_fit: int, held_out: str, group: str = "",
                     dark: str = "", factor: float = HELD_OUT_FACTOR,
                     temporal_var: Any = None) -> HeldOutCheck:
    """The held-out check of ``frame`` (not in the fit) against ``ff`` (a
    :class:`~ccdcore.flatfield.fit.FlatField` made from ``n_fit`` flats; module docstring).

    Parameters
    ----------
    ff
        The flat field; its ``base.var`` is the per-pixel temporal variance of the fitted flats.
    frame
        The held-out flat (same shape).
    n_fit
        N, the flats averaged into DL_B.
    held_out, group, dark
        Its relative path, the group and the dark image in words (recorded).
    factor
        The pass threshold on SNUP / floor.
    temporal_var
        The per-pixel temporal variance s² of a flat; default ``ff.base.var``.  Give the
        variance of the fitted flats each scaled to a common mean level (as
        :func:`ccdcore.flatfield.fit.held_out_check` does) so that a lamp's frame-to-frame level
        change, which is no pixel noise, does not raise the floor.
    """
    raw = np.asarray(frame)
    corrected = ff.correct(raw, where=held_out)
    mask = ff.flags
    sn = snup(corrected, layout=ff.layout, mask=mask, where=held_out)
    sn_raw = snup(raw, layout=ff.layout, mask=mask, where=held_out)
    var = ff.base.var if temporal_var is None else np.asarray(temporal_var, np.float64)
    g2v = ff.G.astype(np.float64) ** 2 * var
    chans = []
    for c, idx in channel_slices(ff.shape, ff.layout).items():
        keep = ~mask[idx]
        mean_c = float(np.asarray(corrected[idx], np.float64)[keep].mean())
        noise = math.sqrt(float(g2v[idx][keep].mean())) if ff.base.n > 1 else float("nan")
        temporal = 100.0 * noise / mean_c
        floor = temporal * math.sqrt(1.0 + 1.0 / n_fit)
        s = sn[c].snup
        ratio = s / floor if floor > 0 and math.isfinite(floor) else float("nan")
        chans.append(HeldOutChannel(name=c, snup=json_safe(s), floor=json_safe(floor),
                                    ratio=json_safe(ratio), temporal=json_safe(temporal),
                                    snup_raw=json_safe(sn_raw[c].snup)))
    ratios = [c.ratio for c in chans]
    ok = all(r is not None and r <= factor for r in ratios)
    return HeldOutCheck(held_out=held_out, n_fit=int(n_fit), group=group, factor=float(factor),
                        verdict="pass" if ok else "warn", channels=tuple(chans), dark=dark)
