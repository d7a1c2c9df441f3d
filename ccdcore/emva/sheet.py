"""The EMVA 1288 datasheet as rows: every figure in the standard's order, with its name, symbol,
unit, value, standard error and, where it could not be determined, the reason.

One list serves every place a person reads the datasheet: the report's section, the CLI's
``datasheet`` files (CSV and JSON), the app, and the headline of a calibration product
(:meth:`ccdcore.emva.results.EmvaSummary.rows`, the :data:`HEADLINE` figures of these rows).
The order is that of the summary datasheet of EMVA Standard 1288 release 3.1 (sensitivity,
noise, saturation, dynamic range, linearity, dark current, spatial nonuniformity), with release
4.0's row, column and pixel parts of DSNU and PRNU after the release 3.1 totals.

Every function takes the figures as their record, :class:`ccdcore.emva.results.EmvaSummary`
(``EmvaFigures.summary()``, or the ``emva1288`` entry of a calibration product). The rows
themselves (:data:`DATASHEET`, :data:`HEADLINE`, :class:`SheetRow`, :func:`datasheet_rows`) live
beside the record in :mod:`ccdcore.emva.results`, whose :meth:`~EmvaSummary.rows` gives the
headline from them; this module re-exports them and renders them.

Public objects
--------------
SheetRow
    One figure of the datasheet.
DATASHEET
    (section, key, name, symbol, unit) of every figure, in order.
HEADLINE
    The keys of the figures a product's headline shows.
section_markdown(emva, section)
    One section's rows as Markdown list items (the app's pages).
linearity_deviation(emva)
    The deviation from linearity of every point (the report's and the datasheet files' plot).
datasheet_rows(emva)
    The rows of the figures.
"""
from __future__ import annotations

import html
import numpy as np
from numpy.typing import NDArray

from .results import DATASHEET, HEADLINE, EmvaSummary, SheetRow, datasheet_rows

__all__ = ["SheetRow", "DATASHEET", "HEADLINE", "datasheet_rows", "section_markdown",
           "linearity_deviation"]

def section_markdown(emva: EmvaSummary, section: str) -> list[str]:
    """The rows of one ``section`` of the datasheet as Markdown list items: "- name, symbol =
    **value ± error unit**", or "- name, symbol: not determined — the reason" (HTML-escaped)."""
    from ..common import format_pm

    lines = []
    for r in datasheet_rows(emva):
        if r.section != section:
            continue
        if r.value is None:
            lines.append(f"- {r.name}, {r.symbol}: not determined — {html.escape(r.note or '')}")
        else:
            lines.append(f"- {r.name}, {r.symbol} = **{format_pm(r.value, r.error, unit=r.unit)}**")
    return lines


def linearity_deviation(e: EmvaSummary) -> dict[str, NDArray] | None:
    """The deviation from linearity of every point (sec. 6.7), as LE_min and LE_max are
    taken: ``deviation`` = 100 (Y − (a μ_p + b)) / (a μ_p + b) % with Y = μ_y − μ_y.dark and
    a, b the figures' ``linearity_slope`` and ``linearity_offset``; with ``u_p``, ``level``
    and ``in_fit`` (the point is in the linearity fit, its ``in_linearity_fit``). ``None``
    without points."""
    rows = e.points
    if not rows:
        return None
    a, b = e.linearity_slope, e.linearity_offset
    u_p = np.array([p.u_p for p in rows], np.float64)
    Y = np.array([p.u_y - p.u_y_dark for p in rows], np.float64)
    fitted = a * u_p + b
    with np.errstate(divide="ignore", invalid="ignore"):
        deviation = np.where(fitted != 0, 100.0 * (Y - fitted) / fitted, np.nan)
    in_fit = np.array([p.in_linearity_fit for p in rows])
    level = np.array([float(p.level) for p in rows])
    return {"u_p": u_p, "deviation": deviation, "in_fit": in_fit & np.isfinite(deviation),
            "level": level}
