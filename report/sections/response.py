"""The report's response-curves section (Tsin, Ramesh & Kanade 2001, sec. 3.2): the noise terms
per channel, g at six codes, the prediction agreement and the curves.  Part of
:mod:`ccdcore_report.sections`, which re-exports every public name.

Public objects
--------------
response_section
    The section.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from ccdcore.common import format_pm
from ccdcore.response.methods import ResponseSummary

from .. import figures
from ..agreement import AGREEMENT_COLUMNS, channel_agreement_rows, pair_rows
from ..html import Doc, bullets, json_floats, num, para, table, value_text

__all__ = ["response_section"]

# ---------------------------------------------------------------------------------------------
# response curves
# ---------------------------------------------------------------------------------------------
def _response_noise_table(r: ResponseSummary, channels: Sequence[str]) -> str:
    """Per channel σ_s, σ_c1, σ_c2 ± errors, iterations, convergence, white balance (a
    per-channel figure the record lacks, e.g. white balance of an older product: n/a, no)."""
    rows = []
    for i, ch in enumerate(channels):
        def pick(key: str) -> Any:
            v = getattr(r, key)
            return v[i] if i < len(v) else None

        rows.append((ch,
                     format_pm(pick("sigma_s"), pick("sigma_s_err")),
                     format_pm(pick("sigma_c1"), pick("sigma_c1_err")),
                     format_pm(pick("sigma_c2"), pick("sigma_c2_err"), unit="DN"),
                     pick("iterations"), "yes" if pick("converged") else "no",
                     "yes" if pick("white_balance") else "no"))
    return table(rows, ("channel", "\u03c3_s", "\u03c3_c1", "\u03c3_c2", "iterations",
                        "converged", "white balance"),
                 cls="ccd-report-response-noise", numeric=(1, 2, 3, 4))


def _g_table(channels: Sequence[str], gs: Sequence[NDArray], errs: Sequence[NDArray],
             levels: int) -> str:
    """g ± error of every channel at six codes (5 % to 95 % of the range)."""
    top = levels - 1
    codes = sorted({round(top * f) for f in (0.05, 0.1, 0.25, 0.5, 0.75, 0.95)})
    errs_or_none = errs if len(errs) == len(gs) else [np.empty(0)] * len(gs)
    rows = [[z] + [format_pm(float(g[z]), float(e[z]) if z < e.size else None)
                   if z < g.size else "n/a" for g, e in zip(gs, errs_or_none)]
            for z in codes]
    return table(rows, ["code z"] + [f"g, {ch}" for ch in channels],
                 cls="ccd-report-response-g", numeric=tuple(range(len(channels) + 1)))


def response_section(doc: Doc, r: ResponseSummary) -> None:
    """The response's noise terms per channel, its exposures, g at six codes, the prediction
    agreement, the notes and the curves with their bands.

    Parameters
    ----------
    doc
        The report being assembled.
    r
        The product's response (``product.estimates.response``).
    """
    channels = list(r.channels)
    scale = r.scale
    with doc.section("response", "Response curves"):
        doc.add(para("Tsin, Ramesh & Kanade 2001, sec. 3.2: the inverse response g per channel "
                     f"by {r.method}, with its band and the noise terms of eq. 7 "
                     f"(\u03c3_s and \u03c3_c1 in units of g, \u03c3_c2 in DN). Scale: "
                     f"g({scale.fixed_code}) = {num(scale.g_at_fixed_code, '.4g')}."))
        if r.verdict is not None:
            # the library's verdict in its own words (ccdcore.response.verdict), as every verb
            # and page shows it
            doc.add(para(f"Verdict: {r.verdict.line()}",
                         f"ccd-report-response-verdict ccd-verdict-{r.verdict.status}"))
            if r.verdict.details():
                # the frames' registration and the moving pixels, the verdict's own lines
                doc.add(bullets(r.verdict.details()))
        if r.selection:
            doc.add(para(f"Method: {r.requested or r.method}: {r.selection}"))
        if r.exposures is not None:
            doc.add(bullets((r.exposures.line(), *r.exposures.off_runs())))
        doc.add(_response_noise_table(r, channels))
        times = r.exposure_times
        doc.add(para(f"{len(times)} exposures: " + ", ".join(num(t, ".4g") for t in times)
                     + " s; bloom radius " + value_text(r.bloom_radius) + " px."))
        gs = [json_floats(g) for g in r.g]
        errs = [json_floats(e) for e in r.g_err]
        levels = int(r.levels or (gs[0].size if gs else 0))
        if gs and levels > 1:
            doc.add(_g_table(channels, gs, errs, levels))
        _agreement_tables(doc, r)
        doc.add(bullets(f"{ch}: {n}" for ch, ns in r.notes.items() for n in ns))
        if not gs:
            return
        doc.plot(figures.response_figures(channels, gs, errs), id_="response-curves",
                 caption="g(z) of every channel with its \u00b12\u03c3 band; below, the 1\u03c3 "
                         "error itself (0 at the fixed code, which sets the scale).")


def _agreement_tables(doc: Doc, r: ResponseSummary) -> None:
    """The response's prediction agreement (Tsin et al. sec. 4.2, ``r.agreement``; nothing
    when not computed): the pooled figures and each channel's, then each pair of neighbouring
    images per channel."""
    a = r.agreement
    if a is None:
        return
    rng = a.code_range
    doc.add(para(f"How well the curves predict the bracket's own images (sec. 4.2), in DN "
                 f"over the codes {rng[0]}..{rng[-1]} both images read: each image from a "
                 "neighbour with the result's exposure ratio, with each pair's ratio fitted "
                 "(the difference is what exposure errors cost), and from the blend of all "
                 "the other images."))
    rows = channel_agreement_rows(a)
    header = ["channel", *AGREEMENT_COLUMNS.values(), "predictions"]
    doc.add(table([[row[h] for h in header] for row in rows], header,
                  cls="ccd-report-response-agreement", numeric=(1, 2, 3, 4)))
    pairs = pair_rows(a, json_floats(r.exposure_times))
    if pairs:
        header = list(pairs[0])
        doc.add(table([[row.get(h, "n/a") for h in header] for row in pairs], header,
                      cls="ccd-report-response-pairs", numeric=tuple(range(2, len(header)))))
        doc.add(para("Per pair of neighbouring images (numbered from 1, shortest exposure "
                     "first): the RMS with the result's ratio, with the pair's fitted ratio, "
                     "and the fitted ratio over the nominal t_k / t_j. A frame with a wrong "
                     "exposure time, or one that moved, shows in the pairs it takes part in.",
                     "note"))
