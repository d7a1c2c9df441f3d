"""The prediction agreement of a response (Tsin, Ramesh & Kanade 2001, sec. 4.2) as table rows
of text: pooled per method, per channel, per pair of neighbouring images.

The rows are read from the records ``calibration.json`` stores
(:class:`ccdcore.response.agreement.AgreementSummary`, :class:`ChannelAgreementSummary
<ccdcore.response.agreement.ChannelAgreementSummary>` and :class:`PairAgreementSummary
<ccdcore.response.agreement.PairAgreementSummary>`): ``Agreement.summary_record()`` of a fresh
result, ``ResponseSummary.agreement`` of a product.  The report's response section and the app's
Response & HDR page draw the same tables from these functions
(:mod:`ccdcore_app.plots.response` imports them from here).

Public objects
--------------
AGREEMENT_COLUMNS
    The pooled figures (attribute -> column heading).
dn(v, fmt=".2f")
    A figure as text ("n/a" for None or non-finite).
agreement_rows(named), channel_agreement_rows(agreement), pair_rows(agreement, t)
    Pooled per method, per channel, per pair of neighbouring images.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

from ccdcore.response.agreement import AgreementSummary, ChannelAgreementSummary

__all__ = ["AGREEMENT_COLUMNS", "dn", "agreement_rows", "channel_agreement_rows", "pair_rows"]

#: the pooled figures of :class:`ccdcore.response.agreement.AgreementSummary` (and of each
#: channel's), attribute -> the tables' heading
AGREEMENT_COLUMNS = {"rms": "RMS, own ratios (DN)",
                     "rms_fitted": "RMS, each pair's ratio fitted (DN)",
                     "rms_blend": "RMS from the blend of the others (DN)"}


def dn(v: Any, fmt: str = ".2f") -> str:
    """A figure of the agreement as text ("n/a" for None or non-finite)."""
    if v is None or isinstance(v, bool):
        return "n/a"
    v = float(v)
    return f"{v:{fmt}}" if math.isfinite(v) else "n/a"


def _figures(s: AgreementSummary | ChannelAgreementSummary | None) -> dict[str, str]:
    """The pooled figures of an agreement or a channel's (``None``: all "n/a") by heading."""
    return {head: dn(None if s is None else getattr(s, key))
            for key, head in AGREEMENT_COLUMNS.items()}


def agreement_rows(named: Sequence[tuple[str, AgreementSummary | None]]
                   ) -> list[dict[str, str]]:
    """One row per ``(name, agreement)`` (``None``: not computed): the figures pooled over the
    channels."""
    return [{"method": name, **_figures(a)} for name, a in named]


def channel_agreement_rows(agreement: AgreementSummary) -> list[dict[str, str]]:
    """The pooled figures, then one row per channel, with the predictions counted."""
    rows = [{"channel": "all", **_figures(agreement),
             "predictions": str(sum(c.n for c in agreement.channels))}]
    for c in agreement.channels:
        rows.append({"channel": c.channel, **_figures(c), "predictions": str(c.n)})
    return rows


def pair_rows(agreement: AgreementSummary, t: Sequence[float]) -> list[dict[str, str]]:
    """One row per pair of neighbouring images (numbered from 1, as the page's other tables):
    their nominal exposure times, then per channel the RMS (DN) with the result's ratio and
    with the pair's fitted ratio, and the fitted ratio over the nominal one (t_k / t_j): one
    frame with a wrong exposure, or moved, shows in the pairs it takes part in."""
    t = [float(v) for v in t]
    pairs: dict[tuple[int, int], dict[str, str]] = {}
    for c in agreement.channels:
        ch = c.channel
        for p in c.pairs:
            j, k = p.j, p.k
            row = pairs.get((j, k))
            if row is None:
                times = (f"{t[j]:.4g} \u2192 {t[k]:.4g}" if j < len(t) and k < len(t)
                         else "n/a")
                row = pairs[(j, k)] = {"images": f"{j + 1}\u2192{k + 1}", "t (s)": times}
            nominal = t[k] / t[j] if j < len(t) and k < len(t) and t[j] > 0 else float("nan")
            fitted = p.ratio_fitted
            rel = float(fitted) / nominal if fitted is not None and nominal > 0 else None
            row[f"{ch}: RMS"] = dn(p.rms)
            row[f"{ch}: fitted"] = dn(p.rms_fitted)
            row[f"{ch}: ratio fit/nominal"] = dn(rel, ".3f")
    return [pairs[key] for key in sorted(pairs)]
