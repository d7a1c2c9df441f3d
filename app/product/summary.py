"""What a calibration product holds, for people: the summary tables of the Calibration product tab.

Public objects
--------------
camera_markdown(product, folder)
    The product's camera, frame size, correction and source as a two-column table.
estimates_frame(product), estimate_headline(summary)
    One row per estimate with its headline figures (the EMVA 1288 figures too), which are its
    rows (``summary.rows()``, on one line by :func:`ccdcore.records.rows_text`); one
    estimate's.
maps_frame(product), skipped_frame(product), provenance_markdown(product)
    The maps with their sizes, the estimates skipped and why, the provenance.
MAP_MEANINGS, EMVA
    What each map of a product is; the name the EMVA 1288 figures are listed under.
code_span(text)
    ``text`` as a Markdown code span.

Pure functions of ccdcore's results (:class:`ccdcore.product.make.CalibrationProduct`), shown by
:class:`ccdcore_app.product.panel.ProductPanel`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd

from ccdcore.common import format_size
from ccdcore.product.make import CalibrationProduct, MapName, requirement
from ccdcore.records import Record, rows_text

__all__ = ["camera_markdown", "estimates_frame", "estimate_headline", "maps_frame",
           "skipped_frame", "provenance_markdown", "MAP_MEANINGS", "EMVA", "code_span"]

#: what each map of a product is (CalibrationProduct.maps)
MAP_MEANINGS: dict[str, str] = {
    MapName.DARK: "dark reference D\u0302_D (DN)",
    MapName.DARK_VAR: "temporal variance of the dark frames (DN\u00b2)",
    MapName.HOT: "hot pixels (1 = flagged)", MapName.DEAD: "dead pixels (1 = flagged)",
    MapName.K: "fixed-pattern map K\u0302 (eq. 49)", MapName.K_VAR: "error variance of K\u0302",
    MapName.N1_USED: "configurations used per pixel n'_1", MapName.FLAT_G: "flat-field gain G",
    MapName.FLAT_O: "flat-field offset O (DN)",
    MapName.FLAT_FLAGS: "flagged pixels of the flat field",
    MapName.FLAT_DARK: "dark image DL_0 (DN)", MapName.FLAT_BASE: "base image DL_B (DN)"}

_METHODS = {"flat_field": "the flat field: DL_c = O + G\u00b7DL (de Lasarte et al. 2007)",
            "fixed_pattern": "D_C = (D \u2212 D\u0302_D)/K\u0302 (eq. 51)",
            "dark": "D \u2212 D\u0302_D (no K\u0302 in the product)"}


def code_span(text: Any) -> str:
    """``text`` as a Markdown code span."""
    return "`" + str(text).replace("`", "'") + "`"


# ----------------------------------------------------------------------------- summary -------
def camera_markdown(product: CalibrationProduct, folder: str | Path | None = None) -> str:
    """The product's camera, frame size, correction and source as a two-column table."""
    cam = product.camera
    rows = [("Camera", cam.name or "(unnamed)"),
            ("ADC bits", "unknown" if cam.bits is None else str(cam.bits)),
            ("Layout", cam.layout),
            ("Black level", "not given" if cam.black_level is None else
             f"{cam.black_level:g} DN"),
            ("Frame size", "no frame maps" if product.shape is None else
             f"{format_size(product.shape)} px"),
            ("Corrects with", _METHODS[product.method] if product.shape is not None else
             "nothing (no dark reference nor flat field)"),
            ("Linearises", "yes (inverse response g)" if product.estimates.response is not None
             else "no (no response curve)")]
    rows.append(("Folder", "not saved (calibrated in the app)" if folder is None
                 else code_span(folder)))
    return "| | |\n|---|---|\n" + "\n".join(f"| {k} | {v} |" for k, v in rows)


#: the EMVA 1288 figures of a product (``CalibrationProduct.emva1288``), listed as an estimate
EMVA = "emva1288"


def estimate_headline(summary: Record | Mapping[str, Record]) -> str:
    """One line of the headline figures of an estimate: its rows (``summary.rows()``), or for
    the scene variation (patch name -> summary) each patch's."""
    if isinstance(summary, Mapping):
        if not summary:
            return "no patches"
        return "; ".join(f"{name}: " + rows_text(s.rows()) for name, s in summary.items())
    return rows_text(summary.rows())


def _purpose(name: str) -> str:
    if name == EMVA:
        return "the EMVA 1288 figures (photon counts of the ptc levels)"
    try:
        return requirement(name).purpose
    except KeyError:
        return ""


def estimates_frame(product: CalibrationProduct) -> pd.DataFrame:
    """One row per estimate made: its name, what it is, its headline numbers (and the EMVA 1288
    figures when the product has them)."""
    summaries = dict(product.estimates.items())
    if product.emva1288 is not None:
        summaries[EMVA] = product.emva1288
    rows = [{"estimate": name, "what": _purpose(name), "headline": estimate_headline(summary)}
            for name, summary in summaries.items()]
    return pd.DataFrame(rows, columns=["estimate", "what", "headline"])


def maps_frame(product: CalibrationProduct) -> pd.DataFrame:
    """One row per map: name, what it is, size (width first), dtype and value range."""
    rows = []
    for name in sorted(product.maps):
        m = product.maps[name]
        finite = m[np.isfinite(m)] if m.dtype.kind == "f" else m
        rng = f"{float(finite.min()):.5g} \u2026 {float(finite.max()):.5g}" if finite.size \
            else "no finite values"
        rows.append({"map": name, "what": MAP_MEANINGS.get(name, ""),
                     "size (W\u00d7H)": format_size(m.shape), "dtype": str(m.dtype),
                     "range": rng})
    return pd.DataFrame(rows, columns=["map", "what", "size (W\u00d7H)", "dtype", "range"])


def skipped_frame(product: CalibrationProduct) -> pd.DataFrame:
    """One row per skipped estimate: name, code and reason."""
    rows = [{"estimate": s.estimate, "code": s.code, "reason": s.reason}
            for s in product.skipped]
    return pd.DataFrame(rows, columns=["estimate", "code", "reason"])


def _params(step: Record) -> str:
    parts = []
    for key, value in step.items():
        if key == "method":
            continue
        if isinstance(value, (list, tuple)) and len(value) > 4:
            value = f"{len(value)} items"
        elif isinstance(value, tuple):
            value = list(value)
        parts.append(f"{key} = {value}")
    return "; ".join(parts)


def _or_unknown(value: Any) -> Any:
    return "?" if value is None else value


def provenance_markdown(product: CalibrationProduct) -> str:
    """Which ccdcore, which session, and per step its method and parameters; the product's
    warnings and notes."""
    prov = product.provenance
    lines = [f"Made by ccdcore {_or_unknown(prov.ccdcore)} from "
             f"{code_span(_or_unknown(prov.session))} ({_or_unknown(prov.source)}, "
             f"{_or_unknown(prov.n_frames)} frames)."]
    known = ("ccdcore", "session", "source", "n_frames", "steps")
    lines += [f"- {key}: {code_span(value)}" for key, value in prov.items()
              if key not in known and isinstance(value, (str, int, float))]
    if prov.steps is not None:
        for name, step in prov.steps.items():
            extra = _params(step)
            lines.append(f"- **{name}**: {step.method}" + (f" ({extra})" if extra else ""))
    if product.warnings:
        lines.append("\n**Warnings:**")
        lines += [f"- {w}" for w in product.warnings]
    if product.notes:
        lines.append("\n**Notes:**")
        lines += [f"- {n}" for n in product.notes]
    return "\n".join(lines)
