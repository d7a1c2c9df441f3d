"""The EMVA 1288 datasheet as rows: every figure in the standard's order, with its name, symbol,
unit, value, standard error and, where it could not be determined, the reason.

One list serves every place a person reads the datasheet: the report's section, the CLI's
``datasheet`` files (CSV and JSON), the app. The order is that of the summary datasheet of EMVA
Standard 1288 release 3.1 (sensitivity, noise, saturation, dynamic range, linearity, dark
current, spatial nonuniformity), with release 4.0's row, column and pixel parts of DSNU and PRNU
after the release 3.1 totals.

Public objects
--------------
SheetRow
    One figure of the datasheet.
DATASHEET
    (section, key, name, symbol, unit) of every figure, in order.
section_markdown(emva, section)
    One section's rows as Markdown list items (the app's pages).
linearity_deviation(emva)
    The deviation from linearity of every point (the report's and the datasheet files' plot).
datasheet_rows(emva)
    The rows of a result's ``to_dict()`` (:meth:`ccdcore.datasheet.EmvaFigures.to_dict`, or the
    ``emva1288`` entry of a calibration product).
"""
from __future__ import annotations

import html
import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
from numpy.typing import NDArray

__all__ = ["SheetRow", "DATASHEET", "datasheet_rows", "section_markdown", "linearity_deviation"]

#: (section, key under emva1288's names, the standard's name, symbol, unit), in order
DATASHEET: tuple[tuple[str, str, str, str, str], ...] = (
    ("Sensitivity", "QE", "Quantum efficiency", "η", "%"),
    ("Sensitivity", "R", "Responsivity", "R", "DN/p"),
    ("Sensitivity", "K", "Overall system gain", "K", "DN/e⁻"),
    ("Noise", "sigma_d", "Temporal dark noise", "σ_d", "e⁻"),
    ("Noise", "sigma_y_dark", "Temporal dark noise", "σ_y.dark", "DN"),
    ("Noise", "sigma_d_ptc", "Temporal dark noise from the photon-transfer intercept", "σ_d",
     "e⁻"),
    ("Saturation", "u_p_min", "Absolute sensitivity threshold", "μ_p.min", "p"),
    ("Saturation", "u_p_sat", "Saturation capacity", "μ_p.sat", "p"),
    ("Saturation", "u_e_sat", "Saturation capacity", "μ_e.sat", "e⁻"),
    ("Saturation", "SNR_max", "Maximum signal-to-noise ratio", "SNR_max", ""),
    ("Dynamic range", "DR_dB", "Dynamic range", "DR", "dB"),
    ("Dynamic range", "DR", "Dynamic range", "DR", ""),
    ("Linearity", "LE_min", "Linearity error, minimum", "LE_min", "%"),
    ("Linearity", "LE_max", "Linearity error, maximum", "LE_max", "%"),
    ("Dark current", "u_I_mean", "Dark current from the mean", "μ_I.mean", "e⁻/s"),
    ("Dark current", "u_I_var", "Dark current from the variance", "μ_I.var", "e⁻/s"),
    ("Spatial nonuniformity", "DSNU1288", "Dark signal nonuniformity", "DSNU1288", "e⁻"),
    ("Spatial nonuniformity", "DSNU1288_row", "DSNU, row part", "DSNU1288.row", "e⁻"),
    ("Spatial nonuniformity", "DSNU1288_col", "DSNU, column part", "DSNU1288.col", "e⁻"),
    ("Spatial nonuniformity", "DSNU1288_pixel", "DSNU, pixel part", "DSNU1288.pixel", "e⁻"),
    ("Spatial nonuniformity", "PRNU1288", "Photo response nonuniformity", "PRNU1288", "%"),
    ("Spatial nonuniformity", "PRNU1288_row", "PRNU, row part", "PRNU1288.row", "%"),
    ("Spatial nonuniformity", "PRNU1288_col", "PRNU, column part", "PRNU1288.col", "%"),
    ("Spatial nonuniformity", "PRNU1288_pixel", "PRNU, pixel part", "PRNU1288.pixel", "%"),
)


@dataclass(frozen=True)
class SheetRow:
    """One figure: where it belongs, what the standard calls it, its value and standard error
    (``None`` when not determined) and, then, why (``note``: the reason, and a bound when the
    data give one)."""

    section: str
    key: str
    name: str
    symbol: str
    unit: str
    value: float | None
    error: float | None
    note: str | None

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _number(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    return float(v) if math.isfinite(v) else None


def _why(emva: Mapping[str, Any], key: str) -> str:
    """The note that names ``key`` (the estimators write ``"<key> is not ..."``), with the bound
    when one was found; else a plain reason."""
    notes = [n for n in emva.get("notes") or () if isinstance(n, str)]
    for note in notes:
        if note.startswith(f"{key} "):
            return note
    if key.startswith("u_I_"):
        for note in notes:
            if note.startswith("no dark current"):
                return note
    if key.startswith(("DSNU1288", "PRNU1288")) and not emva.get("spatial"):
        return "no spatial sets (L bright and L dark frames at one point, sec. 8) in the session"
    if key == "sigma_d_ptc":
        return "photon transfer was not run with the figures"
    return "not determined from this session (see the notes)"


def section_markdown(emva: Mapping[str, Any], section: str) -> list[str]:
    """The rows of one ``section`` of the datasheet as Markdown list items: "- name, symbol =
    **value ± error unit**", or "- name, symbol: not determined — the reason" (HTML-escaped)."""
    from .common import format_pm

    lines = []
    for r in datasheet_rows(emva):
        if r.section != section:
            continue
        if r.value is None:
            lines.append(f"- {r.name}, {r.symbol}: not determined — {html.escape(r.note or '')}")
        else:
            lines.append(f"- {r.name}, {r.symbol} = **{format_pm(r.value, r.error, unit=r.unit)}**")
    return lines


def linearity_deviation(emva: Mapping[str, Any]) -> dict[str, NDArray] | None:
    """The deviation from linearity of every point (sec. 6.7), as LE_min and LE_max are
    taken: ``deviation`` = 100 (Y − (a μ_p + b)) / (a μ_p + b) % with Y = μ_y − μ_y.dark and
    a, b the figures' ``linearity_slope`` and ``linearity_offset``; with ``u_p``, ``level``
    and ``in_fit`` (the point is in the linearity fit: its ``in_linearity_fit``, else the
    index range of the fit). Points without a finite μ_p, μ_y or μ_y.dark are left out.
    ``None`` without the fitted line or points."""
    a, b = _number(emva.get("linearity_slope")), _number(emva.get("linearity_offset"))
    points = emva.get("points")
    if a is None or b is None or not isinstance(points, list):
        return None
    keep = [i for i, p in enumerate(points) if isinstance(p, Mapping)
            and all(_finite(p.get(k)) for k in ("u_p", "u_y", "u_y_dark"))]
    if not keep:
        return None
    rows = [points[i] for i in keep]
    u_p = np.array([p["u_p"] for p in rows], np.float64)
    Y = np.array([p["u_y"] - p["u_y_dark"] for p in rows], np.float64)
    fitted = a * u_p + b
    with np.errstate(divide="ignore", invalid="ignore"):
        deviation = np.where(fitted != 0, 100.0 * (Y - fitted) / fitted, np.nan)
    lo, hi = emva.get("index_linearity_min"), emva.get("index_linearity_max")
    if all("in_linearity_fit" in p for p in rows):
        in_fit = np.array([bool(p["in_linearity_fit"]) for p in rows])
    elif _finite(lo) and _finite(hi):
        in_fit = np.array([lo <= i <= hi for i in keep])
    else:
        in_fit = np.ones(len(rows), bool)
    level = np.array([float(p["level"]) if _finite(p.get("level")) else np.nan
                      for p in rows])
    return {"u_p": u_p, "deviation": deviation, "in_fit": in_fit & np.isfinite(deviation),
            "level": level}


def datasheet_rows(emva: Mapping[str, Any]) -> list[SheetRow]:
    """Every figure of :data:`DATASHEET` from the JSON-safe figures ``emva``, in order."""
    rows = []
    for section, key, name, symbol, unit in DATASHEET:
        value = _number(emva.get(key))
        error = _number(emva.get(f"{key}_err")) if value is not None else None
        rows.append(SheetRow(section, key, name, symbol, unit, value, error,
                             None if value is not None else _why(emva, key)))
    return rows
