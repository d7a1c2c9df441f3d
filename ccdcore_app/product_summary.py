"""What a calibration product holds, for people: the summary tables of the Calibration product tab.

Public objects
--------------
camera_markdown(product, folder)
    The product's camera, frame size, correction and source as a two-column table.
estimates_frame(product), estimate_headline(name, summary)
    One row per estimate with its headline numbers (the EMVA 1288 figures too); one estimate's.
maps_frame(product), skipped_frame(product), provenance_markdown(product)
    The maps with their sizes, the estimates skipped and why, the provenance.
MAP_MEANINGS, EMVA
    What each map of a product is; the name the EMVA 1288 figures are listed under.
code_span(text)
    ``text`` as a Markdown code span.

Pure functions of ccdcore's results (:class:`ccdcore.product.CalibrationProduct`), shown by
:class:`ccdcore_app.product_panel.ProductPanel`.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd

from ccdcore.common import format_pm, format_size
from ccdcore.product import CalibrationProduct, MapName, requirement

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


def _num(value: Any, fmt: str = ".4g") -> str:
    """A JSON number for people (``?`` when missing or not finite)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return "?"
    return format(value, fmt)


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
            ("Linearises", "yes (inverse response g)" if "response" in product.estimates
             else "no (no response curve)")]
    rows.append(("Folder", "not saved (calibrated in the app)" if folder is None
                 else code_span(folder)))
    return "| | |\n|---|---|\n" + "\n".join(f"| {k} | {v} |" for k, v in rows)


def _noise(e: Mapping[str, Any]) -> str:
    chi = f"\u03c7\u00b2 = {_num(e.get('chi2'), '.3g')} for {e.get('dof', '?')} dof"
    return (f"A = {format_pm(e.get('A'), e.get('A_err'))} DN/e\u207b, "
            f"\u03c3\u00b2_C = {format_pm(e.get('sigma_c2'), e.get('sigma_c2_err'))} DN\u00b2; "
            f"{chi} (Q = {_num(e.get('Q'), '.2g')}, {e.get('verdict', '?')})")


def _dark(e: Mapping[str, Any]) -> str:
    return (f"D\u0302_D mean {format_pm(e.get('mean'), e.get('mean_sem'))} DN from "
            f"s = {e.get('s', '?')} frames, spatial \u03c3 {_num(e.get('spatial_std'))} DN; "
            f"{e.get('n_hot', '?')} hot, {e.get('n_dead', '?')} dead pixels")


def _fixed_pattern(e: Mapping[str, Any]) -> str:
    return (f"K\u0302 mean {_num(e.get('mean'), '.5g')}, spatial \u03c3 "
            f"{_num(e.get('spatial_std'), '.3g')} from n1 = {e.get('n1', '?')} configurations "
            f"\u00d7 n2 = {e.get('n2', '?')} frames (window {e.get('window', '?')}, "
            f"p = {e.get('p', '?')})")


def _plan(e: Mapping[str, Any]) -> str:
    return (f"n1 = {e.get('n1_required', '?')} configurations \u00d7 n2 = "
            f"{e.get('n2_required', '?')} frames (n\u0302_1 = {e.get('n1_hat', '?')}); "
            f"{len(e.get('warnings') or [])} warning(s)")


def _percent(fraction: Any) -> str:
    return "?" if _num(fraction) == "?" else f"{100 * fraction:.1f} %"


def _check(e: Mapping[str, Any]) -> str:
    return (f"{_percent(e.get('frac_gt_1q'))} of the pixels changed by more than 1 q, "
            f"{_percent(e.get('frac_gt_2q'))} by more than 2 q (largest "
            f"{_num(e.get('max_change_q'), '.3g')} q) at mean level "
            f"{_num(e.get('mean_level'), '.4g')} DN")


def _scene(e: Mapping[str, Any]) -> str:
    parts = [f"{name} {format_pm(v.get('V_S'), v.get('V_S_err'))}" for name, v in e.items()
             if isinstance(v, Mapping)]
    return "V_S: " + ("; ".join(parts) if parts else "no patches")


def _flat_field(e: Mapping[str, Any]) -> str:
    base = e.get("base")
    base_text = "?" if not isinstance(base, list) or len(base) != 2 else \
        f"level {base[0]}, {_num(base[1], 'g')} s"
    ks = ", ".join(f"{c.get('name', '?')} {_num(c.get('k'), '.4g')}"
                   for c in e.get("channels") or [] if isinstance(c, Mapping))
    setting = f", setting {e['setting']}" if e.get("setting") else ""
    return (f"base image {base_text} ({e.get('n_base', '?')} frames), {e.get('n_dark', '?')} "
            f"dark frames{setting}; k per channel: {ks or '?'}; {e.get('n_flagged', '?')} "
            "flagged pixels")


def _response(e: Mapping[str, Any]) -> str:
    channels = [str(c) for c in e.get("channels") or []]
    sig = []
    for key, label in (("sigma_s", "\u03c3_s"), ("sigma_c1", "\u03c3_c1"),
                       ("sigma_c2", "\u03c3_c2")):
        vals, errs = e.get(key) or [], e.get(f"{key}_err") or []
        sig.append(f"{label} " + "/".join(
            format_pm(v, errs[i] if i < len(errs) else None) for i, v in enumerate(vals)))
    converged = e.get("converged") or []
    return (f"{e.get('method', '?')} inverse response of channel{'s' if len(channels) != 1 else ''}"
            f" {', '.join(channels) or '?'} over {e.get('levels', '?')} codes; "
            + ", ".join(sig)
            + ("" if all(converged) else "; **not converged**"))


#: the EMVA 1288 figures in a product's headline (keys of :data:`ccdcore.emva_sheet.DATASHEET`)
_EMVA_HEADLINE = ("K", "QE", "sigma_d", "u_e_sat", "DR_dB", "u_I_mean", "DSNU1288", "PRNU1288")


def _emva(e: Mapping[str, Any]) -> str:
    """The headline figures of the datasheet's rows (:func:`ccdcore.emva_sheet.datasheet_rows`),
    those the product has."""
    from ccdcore.emva_sheet import datasheet_rows

    return ", ".join(f"{r.symbol} = {format_pm(r.value, r.error, unit=r.unit)}"
                     for r in datasheet_rows(e)
                     if r.key in _EMVA_HEADLINE and r.value is not None)


#: the EMVA 1288 figures of a product (``CalibrationProduct.emva1288``), listed as an estimate
EMVA = "emva1288"

_HEADLINES = {"noise": _noise, "dark": _dark, "fixed_pattern": _fixed_pattern, "plan": _plan,
              "correction_check": _check, "scene": _scene, "flat_field": _flat_field,
              "response": _response, EMVA: _emva}


def estimate_headline(name: str, summary: Mapping[str, Any]) -> str:
    """One line of the headline numbers of an estimate's JSON summary (``value ± error``,
    :func:`ccdcore.common.format_pm`); an estimate this app does not know lists its keys."""
    func = _HEADLINES.get(name)
    if func is None:
        return "keys: " + ", ".join(sorted(map(str, summary))[:12])
    try:
        return func(summary)
    except (TypeError, ValueError, AttributeError, KeyError, IndexError) as err:
        return f"(cannot summarise: {type(err).__name__}: {err})"


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
    summaries = dict(product.estimates)
    emva = getattr(product, EMVA, None)
    if isinstance(emva, Mapping):
        summaries[EMVA] = emva
    rows = [{"estimate": name, "what": _purpose(name),
             "headline": estimate_headline(name, summary)}
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


def _params(step: Mapping[str, Any]) -> str:
    parts = []
    for key, value in step.items():
        if key == "method":
            continue
        if isinstance(value, list) and len(value) > 4:
            value = f"{len(value)} items"
        parts.append(f"{key} = {value}")
    return "; ".join(parts)


def provenance_markdown(product: CalibrationProduct) -> str:
    """Which ccdcore, which session, and per step its method and parameters; the product's
    warnings and notes."""
    prov = product.provenance
    lines = [f"Made by ccdcore {prov.get('ccdcore', '?')} from {code_span(prov.get('session', '?'))}"
             f" ({prov.get('source', '?')}, {prov.get('n_frames', '?')} frames)."]
    known = ("ccdcore", "session", "source", "n_frames", "steps")
    lines += [f"- {key}: {code_span(value)}" for key, value in prov.items()
              if key not in known and isinstance(value, (str, int, float))]
    steps = prov.get("steps")
    if isinstance(steps, Mapping):
        for name, step in steps.items():
            if isinstance(step, Mapping):
                extra = _params(step)
                lines.append(f"- **{name}**: {step.get('method', '?')}"
                             + (f" ({extra})" if extra else ""))
    if product.warnings:
        lines.append("\n**Warnings:**")
        lines += [f"- {w}" for w in product.warnings]
    if product.notes:
        lines.append("\n**Notes:**")
        lines += [f"- {n}" for n in product.notes]
    return "\n".join(lines)
