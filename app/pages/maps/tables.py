"""The Maps page's tables, exports and EMVA 1288 spatial figures (pure helpers, no page state).

Public objects
--------------
dark_summary(dark), fixed_pattern_summary(fp), correction_summary(check)
    The summary tables (DataFrames: quantity, this session, paper).
scene_patch_frame(scene), scene_level_frame(variation)
    The scene tables (DataFrames).
export_bytes(layer, fmt, clim), EXPORT_FORMATS
    A map as the bytes of an EXR, FITS or 16-bit PNG file; format -> file extension.
has_emva_spatial(session), emva_spatial_figures(session), emva_spatial_layout(emva),
emva_spatial_text(emva)
    The EMVA 1288 spatial tab: whether the session has it, its figures, their plots and text.
fmt_value(value, spec), round_sig(value, digits), display_frame(df)
    Numbers (and tables of them) for people.
maps_alert(text, kind), stats_pane(), data_table(df), MAPS_CSS
    The page's alerts, summary tables, read-only tables and style sheet.

Every number comes from ccdcore (:mod:`ccdcore_app.pages.maps.page` says which functions).
"""
from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Any

import pandas as pd
import panel as pn

from ccdcore.common import format_pm
from ccdcore.emva.results import EmvaSummary
from ccdcore.emva.sheet import section_markdown
from ccdcore.io.frames import write_image, write_map
from ccdcore.session import Session

from ...plots import maps as map_plots
from ...plots.maps import MapLayer

__all__ = ["dark_summary", "fixed_pattern_summary", "correction_summary", "scene_patch_frame",
           "scene_level_frame", "export_bytes", "EXPORT_FORMATS", "has_emva_spatial",
           "emva_spatial_figures", "emva_spatial_layout", "emva_spatial_text", "fmt_value",
           "round_sig", "display_frame", "maps_alert", "stats_pane", "data_table", "MAPS_CSS"]

#: export format -> file extension
EXPORT_FORMATS = {"exr": ".exr", "fits": ".fits", "png": ".png"}

#: the page's style sheet (the readout, the plan's numbers and formulas)
MAPS_CSS = """
.ccd-readout { font-family: var(--bs-font-monospace, monospace); font-size: 0.92em; }
.ccd-big { font-size: 1.6em; font-weight: 600; color: #1f3b57; }
.ccd-formula code { white-space: pre-wrap; }
"""


def fmt_value(value: Any, spec: str = ".4g") -> str:
    """``value`` formatted with ``spec``; a dash for none or not finite."""
    if value is None:
        return "—"
    try:
        v = float(value)
    except (TypeError, ValueError):
        return str(value)
    if not math.isfinite(v):
        return "—"
    return format(v, spec)


def round_sig(value: float, digits: int = 6) -> float:
    """``value`` to ``digits`` significant digits (inputs a person can read)."""
    return float(f"{float(value):.{digits}g}")


def dark_summary(dark: Any) -> pd.DataFrame:
    """The dark reference's statistics (``DarkReference.summary()``) beside the paper's
    (sec. VII-A: mean 10.74, spatial std 0.555)."""
    d = dark.summary()
    rows = [
        ("D̂_D mean (DN)", format_pm(d.mean, d.mean_sem), "10.74"),
        ("D̂_D spatial std (DN)", fmt_value(d.spatial_std, ".4g"), "0.555"),
        ("  without the averaging noise σ²_N/s", fmt_value(d.spatial_std_signal, ".4g"), ""),
        ("dark frames averaged s", str(d.s), ""),
        ("mean temporal variance σ²_N (DN²)", fmt_value(d.noise_var, ".4g"), ""),
        ("hot pixels", str(d.n_hot), ""),
        ("dead pixels", str(d.n_dead), ""),
    ]
    return pd.DataFrame(rows, columns=["quantity", "this session", "paper"])


def fixed_pattern_summary(fp: Any) -> pd.DataFrame:
    """K̂'s statistics (``FixedPattern.summary()``) beside the paper's (sec. VII-A: mean
    0.99998, spatial std 3.72e-3), with the eq. 50 bound and the measured error."""
    d = fp.summary()
    k_var = d.K_var_mean
    rows = [
        ("K̂ mean", fmt_value(d.mean, ".6f"), "0.99998"),
        ("K̂ spatial std", fmt_value(d.spatial_std, ".4g"), "3.72e-3"),
        ("σ̂ (std of the slopes m_i)", fmt_value(d.sigma_hat, ".4g"), ""),
        ("configurations n1 × frames n2", f"{d.n1} × {d.n2}", "20 × 20"),
        ("n̂_1 = min n'_1", str(d.n1_hat), ""),
        ("eq. 50 bound √((p·σ̂)²/n̂_1)", fmt_value(d.sd_bound, ".4g"), ""),
        ("measured error √mean(var[K̂])", fmt_value(math.sqrt(k_var) if k_var is not None else None,
                                               ".4g"), ""),
        ("pixels with a rejected slope",
         f"{100 * d.fraction_pixels_with_rejection:.1f} %", ""),
        ("window m, rejection p", f"{d.window}, {d.p:g}", "9, 1.5"),
    ]
    return pd.DataFrame(rows, columns=["quantity", "this session", "paper"])


def correction_summary(check: Any) -> pd.DataFrame:
    """The sec. VII-A correction check (``CorrectionCheck.summary()``) beside the paper's
    (27 % of pixels changed by more than one quantisation step, 3 % by more than two, at most
    five steps)."""
    d = check.summary()
    rows = [
        ("pixels changed by > 1 q", f"{100 * d.frac_gt_1q:.1f} %", "27 %"),
        ("pixels changed by > 2 q", f"{100 * d.frac_gt_2q:.1f} %", "3 %"),
        ("  (of those > 1 q)", f"{100 * d.frac_gt_2q_of_gt_1q:.1f} %", ""),
        ("largest change (steps q)", fmt_value(d.max_change_q, ".3g"), "5"),
        ("mean level above dark (DN)", fmt_value(d.mean_level, ".4g"), ""),
    ]
    return pd.DataFrame(rows, columns=["quantity", "this session", "paper"])


def scene_patch_frame(scene: dict[str, Any]) -> pd.DataFrame:
    """One row per patch: V_S ± error and the χ²/dof/Q of the eq. 57 fit."""
    rows = []
    for name, var in scene.items():
        d = var.summary()
        rows.append({"patch": name, "V_S": d.V_S, "± err": d.V_S_err,
                     "χ²": d.chi2, "dof": d.dof, "Q": d.Q,
                     "levels used": f"{sum(var.used)} of {len(var.measurements)}"})
    return pd.DataFrame(rows, columns=["patch", "V_S", "± err", "χ²", "dof", "Q",
                                       "levels used"])


def scene_level_frame(variation: Any) -> pd.DataFrame:
    """One row per light level of a patch: μ̂_D, σ̂²_D, σ̂²_KN, σ̂²_cal, V_S ± error."""
    rows = []
    for m in variation.summary().measurements:
        rows.append({"level": m.level, "frame": m.path, "μ̂_D (DN)": m.mu_D,
                     "σ̂²_D (DN²)": m.var_D, "σ̂²_KN (DN²)": m.sigma_KN2,
                     "σ̂²_cal (DN²)": m.sigma_cal2, "V_S": m.V_S, "± err": m.V_S_err,
                     "used": m.used})
    return pd.DataFrame(rows, columns=["level", "frame", "μ̂_D (DN)", "σ̂²_D (DN²)",
                                       "σ̂²_KN (DN²)", "σ̂²_cal (DN²)", "V_S", "± err", "used"])


def export_bytes(layer: MapLayer, fmt: str, clim: tuple[float, float] | None = None) -> bytes:
    """The bytes of ``layer`` written as a file.

    ``"exr"`` and ``"fits"``: the float32 map (:func:`ccdcore.io.frames.write_map`, bit-exact when
    read back). ``"png"``: a 16-bit greyscale picture of the map scaled to ``clim`` (0 at its low
    end, 65535 at its high end, :func:`ccdcore_app.plots.maps.scaled_uint16`), not the values
    themselves.
    """
    if fmt not in EXPORT_FORMATS:
        raise ValueError(f"fmt: expected one of {', '.join(EXPORT_FORMATS)}, got {fmt!r}")
    with tempfile.TemporaryDirectory(prefix="ccdcore-export-") as tmp:
        path = Path(tmp) / f"{layer.key}{EXPORT_FORMATS[fmt]}"
        if fmt == "png":
            clim = map_plots.default_clim(layer) if clim is None else clim
            write_image(path, map_plots.scaled_uint16(layer.data, clim))
        else:
            write_map(path, layer.data)
        return path.read_bytes()

def maps_alert(text: str, kind: str, **kw: Any) -> pn.pane.Alert:
    """An alert of ``kind`` showing ``text``, hidden while it is empty."""
    return pn.pane.Alert(text, alert_type=kind, visible=bool(text), sizing_mode="stretch_width",
                         **kw)


_STATS_CSS = """
table { border-collapse: collapse; width: 100%; font-size: 0.86em; }
th, td { padding: 3px 6px; border-bottom: 1px solid #dee2e6; text-align: left; }
th { background: #f1f3f5; }
td:nth-child(2), td:nth-child(3) { white-space: nowrap; }
td:first-child, th:first-child { text-align: left !important; }
"""


def stats_pane() -> pn.pane.DataFrame:
    """A summary table (quantity, this session, paper) as compact HTML."""
    return pn.pane.DataFrame(pd.DataFrame(), index=False, escape=True, border=0,
                             stylesheets=[_STATS_CSS], sizing_mode="stretch_width")


def display_frame(df: pd.DataFrame) -> pd.DataFrame:
    """A copy of ``df`` with floats as 4 significant digits (tables of small numbers)."""
    out = df.copy()
    for col in out.columns:
        if out[col].dtype.kind == "f" or out[col].map(lambda v: isinstance(v, float)).any():
            out[col] = out[col].map(lambda v: fmt_value(v, ".4g") if isinstance(v, (float, int))
                                    and not isinstance(v, bool) else v)
    return out


def data_table(df: pd.DataFrame | None = None, **kw: Any) -> pn.widgets.Tabulator:
    """A read-only Tabulator of ``df``."""
    return pn.widgets.Tabulator(pd.DataFrame() if df is None else df, disabled=True,
                                show_index=False, selectable=False, layout="fit_data_stretch",
                                sizing_mode="stretch_width", **kw)


def has_emva_spatial(session: Session | None) -> bool:
    """The session is an EMVA 1288 set (its ptc frames carry photon counts) with a spatial set
    (a ptc level of more than two frames, sec. 8)."""
    if session is None or not any(r.photons for r in session.by_role("ptc")):
        return False
    return any(len(recs) > 2 for recs in session.ptc_levels().values())


def emva_spatial_figures(session: Session) -> EmvaSummary:
    """The EMVA 1288 figures of ``session`` as their record
    (:meth:`ccdcore.emva.datasheet.EmvaFigures.summary`; no photon transfer of our own: the
    spatial section does not use it)."""
    from ccdcore.emva.datasheet import emva_figures

    return emva_figures(session, with_ptc=False).summary()


def emva_spatial_layout(emva: EmvaSummary) -> Any | None:
    """The plots of the spatial section (sec. 8) as one Bokeh layout, two side by side: the
    DSNU and the PRNU spectrograms (horizontal, vertical), the logarithmic and the accumulated
    histograms (DSNU, PRNU), the profiles (horizontal, vertical); ``None`` when the figures
    have none (:mod:`ccdcore_report.emva_figures`)."""
    from bokeh.layouts import column, row

    from ccdcore_report.emva_figures import (HISTOGRAMS, PROFILES, SPECTROGRAMS,
                                             accumulated_histogram_figure, histogram_figure,
                                             profile_figure, spectrogram_figure)

    groups = ([spectrogram_figure(emva, w) for w in SPECTROGRAMS[:2]],
              [spectrogram_figure(emva, w) for w in SPECTROGRAMS[2:]],
              [histogram_figure(emva, w) for w in HISTOGRAMS],
              [accumulated_histogram_figure(emva, w) for w in HISTOGRAMS],
              [profile_figure(emva, w) for w in PROFILES])
    rows = [row(*shown, sizing_mode="stretch_width")
            for shown in ([f for f in group if f is not None] for group in groups) if shown]
    return column(*rows, sizing_mode="stretch_width") if rows else None


def emva_spatial_text(emva: EmvaSummary) -> str:
    """The spatial section's figures (:func:`ccdcore.emva.sheet.datasheet_rows`) as Markdown:
    each with its standard error, or why it is not determined."""
    lines = section_markdown(emva, "Spatial nonuniformity")
    sets = []
    for s, what in ((emva.spatial, "bright"), (emva.spatial_dark, "dark")):
        if s is not None and s.L:
            sets.append(f"{s.L} {what} frames")
    head = ("**EMVA 1288 spatial nonuniformity** (release 3.1 sec. 8; the row, column and pixel "
            "parts of release 4.0)" + (f", from the averages of {' and '.join(sets)}" if sets
                                       else "") + ":")
    return "\n".join([head, ""] + lines)
