"""The prediction agreement of a response (Tsin, Ramesh & Kanade 2001, sec. 4.2) as table rows
of text: pooled per method, per channel, per pair of neighbouring images.

The rows are read from :class:`ccdcore.response.agreement.Agreement` in its ``to_dict()`` form.
The report's response section and the app's Response & HDR page draw the same tables from
these functions (:mod:`ccdcore_app.response_plots` imports them from here).

Public objects
--------------
AGREEMENT_COLUMNS
    The pooled figures (key -> column heading).
dn(v, fmt=".2f")
    A figure as text ("n/a" for None or non-finite).
agreement_rows(named), channel_agreement_rows(agreement), pair_rows(agreement, t)
    Pooled per method, per channel, per pair of neighbouring images.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

__all__ = ["AGREEMENT_COLUMNS", "dn", "agreement_rows", "channel_agreement_rows", "pair_rows"]

#: the pooled figures of :class:`ccdcore.response.agreement.Agreement`, as the tables head them
AGREEMENT_COLUMNS = {"rms": "RMS, own ratios (DN)",
                     "rms_fitted": "RMS, each pair's ratio fitted (DN)",
                     "rms_blend": "RMS from the blend of the others (DN)"}


def dn(v: Any, fmt: str = ".2f") -> str:
    """A figure of the agreement as text ("n/a" for None or non-finite)."""
    if v is None or isinstance(v, bool):
        return "n/a"
    v = float(v)
    return f"{v:{fmt}}" if math.isfinite(v) else "n/a"


def agreement_rows(named: Sequence[tuple[str, Mapping[str, Any] | None]]
                   ) -> list[dict[str, str]]:
    """One row per ``(name, agreement.to_dict())``: the figures pooled over the channels."""
    rows = []
    for name, a in named:
        a = a or {}
        rows.append({"method": name, **{head: dn(a.get(key))
                                        for key, head in AGREEMENT_COLUMNS.items()}})
    return rows


def channel_agreement_rows(agreement: Mapping[str, Any]) -> list[dict[str, str]]:
    """The pooled figures, then one row per channel, with the predictions counted."""
    rows = [{"channel": "all", **{head: dn(agreement.get(key))
                                  for key, head in AGREEMENT_COLUMNS.items()},
             "predictions": str(sum(int(c.get("n") or 0)
                                    for c in agreement.get("channels") or ()))}]
    for c in agreement.get("channels") or ():
        rows.append({"channel": str(c.get("channel")),
                     **{head: dn(c.get(key)) for key, head in AGREEMENT_COLUMNS.items()},
                     "predictions": str(int(c.get("n") or 0))})
    return rows


def pair_rows(agreement: Mapping[str, Any], t: Sequence[float]) -> list[dict[str, str]]:
    """One row per pair of neighbouring images (numbered from 1, as the page's other tables):
    their nominal exposure times, then per channel the RMS (DN) with the result's ratio and
    with the pair's fitted ratio, and the fitted ratio over the nominal one (t_k / t_j): one
    frame with a wrong exposure, or moved, shows in the pairs it takes part in."""
    t = [float(v) for v in t]
    channels = list(agreement.get("channels") or ())
    pairs: dict[tuple[int, int], dict[str, str]] = {}
    for c in channels:
        ch = str(c.get("channel"))
        for p in c.get("pairs") or ():
            j, k = int(p["j"]), int(p["k"])
            row = pairs.get((j, k))
            if row is None:
                times = (f"{t[j]:.4g} \u2192 {t[k]:.4g}" if j < len(t) and k < len(t)
                         else "n/a")
                row = pairs[(j, k)] = {"images": f"{j + 1}\u2192{k + 1}", "t (s)": times}
            nominal = t[k] / t[j] if j < len(t) and k < len(t) and t[j] > 0 else float("nan")
            fitted = p.get("ratio_fitted")
            rel = float(fitted) / nominal if fitted is not None and nominal > 0 else None
            row[f"{ch}: RMS"] = dn(p.get("rms"))
            row[f"{ch}: fitted"] = dn(p.get("rms_fitted"))
            row[f"{ch}: ratio fit/nominal"] = dn(rel, ".3f")
    return [pairs[key] for key in sorted(pairs)]
