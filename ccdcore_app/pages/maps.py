"""The Maps page: dark and fixed-pattern maps, acquisition planning and scene variation.

Healey & Kondepudy 1994: the dark reference D̂_D with hot/dead flags (sec. V-A), the
fixed-pattern map K̂ with n'_1 and the rejected slopes (eqs. 45–50), the acquisition plan n1, n2
(sec. V-B), the correction check (sec. VII-A) and the scene variation V_S with the variance budget
(sec. VI, VII-B/C, Figs. 3 and 4).

Public objects
--------------
MapsPage
    The page (a :class:`panel.viewable.Viewer`) with three tabs:

    * **Maps**: a grid of rasterised maps with linked zoom, the values of every map under the
      cursor, a histogram per shown map, row and column profiles (tap a map or use the sliders),
      colour range control and export of the selected map as EXR, FITS or 16-bit PNG; the
      summary statistics and the correction check next to them.
    * **Scene**: V_S ± error per patch and per light level, the eq. 57 fit (Fig. 3) and the
      variance budget (Fig. 4) of a chosen patch.
    * **Planning**: n1 and n2 from typed or estimated inputs, with their formulas.
    * **EMVA 1288 spatial** (an EMVA 1288 set with a spatial set only): the spatial
      nonuniformity of EMVA Standard 1288 (release 3.1 sec. 8, release 4.0's row, column and
      pixel parts): DSNU1288 and PRNU1288 with their parts, the spectrograms, the logarithmic and
      accumulated histograms and the profiles (:mod:`ccdcore_report.emva_figures`), computed
      once per session when the tab is first shown (off the UI thread, through the disk cache).

    Warnings that the session has fewer configurations or frames than the plan requires are shown
    at the top of the page; missing frames give an info alert saying what to capture.
create_page(state)
    The registry entry point.
dark_summary(dark), fixed_pattern_summary(fp), correction_summary(check)
    The summary tables (DataFrames: quantity, this session, paper).
scene_patch_frame(scene), scene_level_frame(variation)
    The scene tables (DataFrames).
export_bytes(layer, fmt, clim)
    A map as the bytes of an EXR, FITS or 16-bit PNG file.
missing_sentences(session)
    What the session lacks for this page's estimates, as Markdown sentences made of ccdcore's
    :class:`~ccdcore.product.Requirement` texts (:func:`ccdcore.product.missing_frames`).
MAPS_ESTIMATES
    The estimates of :func:`ccdcore.product.estimate_all` this page shows.
has_emva_spatial(session), emva_spatial_figures(session)
    Whether the session is an EMVA 1288 set with a spatial set; its EMVA 1288 figures (the
    JSON dict of :func:`ccdcore.datasheet.emva_figures`) for the EMVA 1288 spatial tab.
emva_spatial_layout(emva), emva_spatial_text(emva)
    The spatial section's plots as one Bokeh layout; its figures as Markdown.

Every number comes from ccdcore: :func:`ccdcore.product.estimate_all` (the same estimates, with
the same parameters, as ``calibrate()`` and the ``ccdcore calibrate`` verb: D̂_D, K̂, the plan and
its warnings, V_S and the correction check on the session's max-intensity frame),
:func:`ccdcore.planning.plan_acquisition`, :func:`ccdcore.product.budget_inputs` and
:func:`ccdcore.scene.variance_budget`. Results are shared with the other pages through
``state.results`` (``estimates``; ``ptc``, the noise model, is read and, when missing, filled).
The page's own state (maps shown and selected, the patch, the planning inputs) is declared with
``param``; watchers (``@param.depends(..., watch=True)``) redraw what depends on it, once per
change: the page sets choices together with their options and data through
:func:`ccdcore_app.pages._choices.set_choices`.
"""
from __future__ import annotations

import asyncio
import html
import io
import logging
import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import panel as pn
import param

from ccdcore.common import format_pm
from ccdcore.emva_sheet import section_markdown
from ccdcore.errors import CcdError
from ccdcore.io import write_image, write_map
from ccdcore.planning import DEFAULT_WORST_RATIO, plan_acquisition
from ccdcore.product import (ESTIMATE_STEPS, MapName, budget_inputs, estimate_all,
                              missing_frames, requirement)
from ccdcore.scene import variance_budget
from ccdcore.session import ROLES, Session

from .. import map_plots, plots
from ..cache import estimates_entry, photon_transfer_entry
from ..batch import batched
from ..image_view import HistogramView, ImageView
from ..map_plots import MapLayer
from ..state import AppState
from ._choices import set_choices

__all__ = ["MapsPage", "create_page", "dark_summary", "fixed_pattern_summary",
           "correction_summary", "scene_patch_frame", "scene_level_frame", "export_bytes",
           "missing_sentences", "MAPS_ESTIMATES", "PAPER_PLAN_INPUTS", "PLAN_INPUTS",
           "DEFAULT_SHOWN", "EXPORT_FORMATS", "EMVA_TAB", "has_emva_spatial",
           "emva_spatial_figures", "emva_spatial_layout", "emva_spatial_text"]

log = logging.getLogger(__name__)

#: the paper's noise model and bit depth (sec. VII-A); σ̂ is not reported by the paper:
#: 2.7e-3 is inside the interval (2.604e-3, 2.731e-3] that gives its n̂_1 = 11 (ccdcore.planning)
PAPER_PLAN_INPUTS: dict[str, Any] = {"A": 0.003384, "sigma_c2": 1.1196, "bits": 8,
                                     "sigma_hat": 2.7e-3, "p": 1.5,
                                     "worst_ratio": DEFAULT_WORST_RATIO, "black_level": 0.0,
                                     "n2_reading": "paper"}
#: maps shown in the grid when they exist
DEFAULT_SHOWN = (MapName.K, MapName.DARK)
#: the inputs of :func:`ccdcore.planning.plan_acquisition` the Planning tab asks for
PLAN_INPUTS = ("A", "sigma_c2", "bits", "sigma_hat", "p", "worst_ratio", "black_level",
               "n2_reading")
#: export format -> file extension
EXPORT_FORMATS = {"exr": ".exr", "fits": ".fits", "png": ".png"}
#: the estimates of ccdcore.product.estimate_all shown on this page (in REQUIREMENTS order);
#: the flat field has its own page
MAPS_ESTIMATES = ("noise", "dark", "fixed_pattern", "plan", "correction_check", "scene")
#: the tab of the EMVA 1288 spatial nonuniformity (an EMVA 1288 set with a spatial set only)
EMVA_TAB = "EMVA 1288 spatial"

_READINGS = {"paper (σ²_N/n2 ≤ 0.2 q², the literal text)": "paper",
             "with the dark reference's error": "with_dark",
             "difference-image variance 2σ²_N": "difference",
             "requantised average (+ q²/12)": "requantised"}
_READING_TEXT = {v: k for k, v in _READINGS.items()}

_CSS = """
.ccd-readout { font-family: var(--bs-font-monospace, monospace); font-size: 0.92em; }
.ccd-big { font-size: 1.6em; font-weight: 600; color: #1f3b57; }
.ccd-formula code { white-space: pre-wrap; }
"""


# ============================================================================ pure helpers ====
def _fmt(value: Any, spec: str = ".4g") -> str:
    if value is None:
        return "—"
    try:
        v = float(value)
    except (TypeError, ValueError):
        return str(value)
    if not math.isfinite(v):
        return "—"
    return format(v, spec)


def _round(value: float, digits: int = 6) -> float:
    """``value`` to ``digits`` significant digits (inputs a person can read)."""
    return float(f"{float(value):.{digits}g}")


def dark_summary(dark: Any) -> pd.DataFrame:
    """The dark reference's statistics (from ``DarkReference.to_dict()``) beside the paper's
    (sec. VII-A: mean 10.74, spatial std 0.555)."""
    d = dark.to_dict()
    rows = [
        ("D̂_D mean (DN)", format_pm(d["mean"], d["mean_sem"]), "10.74"),
        ("D̂_D spatial std (DN)", _fmt(d["spatial_std"], ".4g"), "0.555"),
        ("  without the averaging noise σ²_N/s", _fmt(d["spatial_std_signal"], ".4g"), ""),
        ("dark frames averaged s", str(d["s"]), ""),
        ("mean temporal variance σ²_N (DN²)", _fmt(d["noise_var"], ".4g"), ""),
        ("hot pixels", str(d["n_hot"]), ""),
        ("dead pixels", str(d["n_dead"]), ""),
    ]
    return pd.DataFrame(rows, columns=["quantity", "this session", "paper"])


def fixed_pattern_summary(fp: Any) -> pd.DataFrame:
    """K̂'s statistics (from ``FixedPattern.to_dict()``) beside the paper's (sec. VII-A: mean
    0.99998, spatial std 3.72e-3), with the eq. 50 bound and the measured error."""
    d = fp.to_dict()
    k_var = d.get("K_var_mean")
    rows = [
        ("K̂ mean", _fmt(d["mean"], ".6f"), "0.99998"),
        ("K̂ spatial std", _fmt(d["spatial_std"], ".4g"), "3.72e-3"),
        ("σ̂ (std of the slopes m_i)", _fmt(d["sigma_hat"], ".4g"), ""),
        ("configurations n1 × frames n2", f"{d['n1']} × {d['n2']}", "20 × 20"),
        ("n̂_1 = min n'_1", str(d["n1_hat"]), ""),
        ("eq. 50 bound √((p·σ̂)²/n̂_1)", _fmt(d["sd_bound"], ".4g"), ""),
        ("measured error √mean(var[K̂])", _fmt(math.sqrt(k_var) if k_var is not None else None,
                                               ".4g"), ""),
        ("pixels with a rejected slope",
         f"{100 * d['fraction_pixels_with_rejection']:.1f} %", ""),
        ("window m, rejection p", f"{d['window']}, {d['p']:g}", "9, 1.5"),
    ]
    return pd.DataFrame(rows, columns=["quantity", "this session", "paper"])


def correction_summary(check: Any) -> pd.DataFrame:
    """The sec. VII-A correction check (``CorrectionCheck.to_dict()``) beside the paper's
    (27 % of pixels changed by more than one quantisation step, 3 % by more than two, at most
    five steps)."""
    d = check.to_dict()
    rows = [
        ("pixels changed by > 1 q", f"{100 * d['frac_gt_1q']:.1f} %", "27 %"),
        ("pixels changed by > 2 q", f"{100 * d['frac_gt_2q']:.1f} %", "3 %"),
        ("  (of those > 1 q)", f"{100 * d['frac_gt_2q_of_gt_1q']:.1f} %", ""),
        ("largest change (steps q)", _fmt(d["max_change_q"], ".3g"), "5"),
        ("mean level above dark (DN)", _fmt(d["mean_level"], ".4g"), ""),
    ]
    return pd.DataFrame(rows, columns=["quantity", "this session", "paper"])


def scene_patch_frame(scene: dict[str, Any]) -> pd.DataFrame:
    """One row per patch: V_S ± error and the χ²/dof/Q of the eq. 57 fit."""
    rows = []
    for name, var in scene.items():
        d = var.to_dict()
        rows.append({"patch": name, "V_S": d["V_S"], "± err": d["V_S_err"],
                     "χ²": d["chi2"], "dof": d["dof"], "Q": d["Q"],
                     "levels used": f"{sum(var.used)} of {len(var.measurements)}"})
    return pd.DataFrame(rows, columns=["patch", "V_S", "± err", "χ²", "dof", "Q",
                                       "levels used"])


def scene_level_frame(variation: Any) -> pd.DataFrame:
    """One row per light level of a patch: μ̂_D, σ̂²_D, σ̂²_KN, σ̂²_cal, V_S ± error."""
    rows = []
    for m in variation.to_dict()["measurements"]:
        rows.append({"level": m["level"], "frame": m["path"], "μ̂_D (DN)": m["mu_D"],
                     "σ̂²_D (DN²)": m["var_D"], "σ̂²_KN (DN²)": m["sigma_KN2"],
                     "σ̂²_cal (DN²)": m["sigma_cal2"], "V_S": m["V_S"], "± err": m["V_S_err"],
                     "used": m["used"]})
    return pd.DataFrame(rows, columns=["level", "frame", "μ̂_D (DN)", "σ̂²_D (DN²)",
                                       "σ̂²_KN (DN²)", "σ̂²_cal (DN²)", "V_S", "± err", "used"])


def export_bytes(layer: MapLayer, fmt: str, clim: tuple[float, float] | None = None) -> bytes:
    """The bytes of ``layer`` written as a file.

    ``"exr"`` and ``"fits"``: the float32 map (:func:`ccdcore.io.write_map`, bit-exact when read
    back). ``"png"``: a 16-bit greyscale picture of the map scaled to ``clim`` (0 at its low end,
    65535 at its high end, :func:`ccdcore_app.map_plots.scaled_uint16`), not the values themselves.
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


def _lacking(what: tuple[str, ...]) -> str:
    """What a session lacks, to follow "No": ``("scene", "ptc", "dark")`` -> "`scene`, `ptc`
    or `dark` frames"; a described frame (not a role) is added with "and no"."""
    roles = [f"`{r}`" for r in what if r in ROLES]
    parts = [r for r in what if r not in ROLES]
    if roles:
        head = roles[0] if len(roles) == 1 else ", ".join(roles[:-1]) + " or " + roles[-1]
        parts.insert(0, f"{head} frames")
    return " and no ".join(parts)


def missing_sentences(session: Session) -> list[str]:
    """What the session lacks for this page's estimates (:data:`MAPS_ESTIMATES`), one Markdown
    sentence per estimate: what is missing, what it is for and what to capture, all in the words
    of ccdcore's requirements (:func:`ccdcore.product.missing_frames`)."""
    return [f"**No {_lacking(lacking)}** for {req.purpose}: capture {req.capture}."
            for req, lacking in missing_frames(session, MAPS_ESTIMATES)]


def _purpose(estimate: str) -> str:
    """What an estimate of estimate_all is, for a person (its requirement's purpose)."""
    try:
        return requirement(estimate).purpose
    except KeyError:
        return estimate


def _alert(text: str, kind: str, **kw: Any) -> pn.pane.Alert:
    return pn.pane.Alert(text, alert_type=kind, visible=bool(text), sizing_mode="stretch_width",
                         **kw)


_STATS_CSS = """
table { border-collapse: collapse; width: 100%; font-size: 0.86em; }
th, td { padding: 3px 6px; border-bottom: 1px solid #dee2e6; text-align: left; }
th { background: #f1f3f5; }
td:nth-child(2), td:nth-child(3) { white-space: nowrap; }
td:first-child, th:first-child { text-align: left !important; }
"""


def _stats_pane() -> pn.pane.DataFrame:
    return pn.pane.DataFrame(pd.DataFrame(), index=False, escape=True, border=0,
                             stylesheets=[_STATS_CSS], sizing_mode="stretch_width")


def _display(df: pd.DataFrame) -> pd.DataFrame:
    """A copy of ``df`` with floats as 4 significant digits (tables of small numbers)."""
    out = df.copy()
    for col in out.columns:
        if out[col].dtype.kind == "f" or out[col].map(lambda v: isinstance(v, float)).any():
            out[col] = out[col].map(lambda v: _fmt(v, ".4g") if isinstance(v, (float, int))
                                    and not isinstance(v, bool) else v)
    return out


def _table(df: pd.DataFrame | None = None, **kw: Any) -> pn.widgets.Tabulator:
    return pn.widgets.Tabulator(pd.DataFrame() if df is None else df, disabled=True,
                                show_index=False, selectable=False, layout="fit_data_stretch",
                                sizing_mode="stretch_width", **kw)


def has_emva_spatial(session: Session | None) -> bool:
    """The session is an EMVA 1288 set (its ptc frames carry photon counts) with a spatial set
    (a ptc level of more than two frames, sec. 8)."""
    if session is None or not any(r.photons for r in session.by_role("ptc")):
        return False
    return any(len(recs) > 2 for recs in session.ptc_levels().values())


def emva_spatial_figures(session: Session) -> dict[str, Any]:
    """The EMVA 1288 figures of ``session`` as their JSON dict
    (:meth:`ccdcore.datasheet.EmvaFigures.to_dict`; no photon transfer of our own: the
    spatial section does not use it)."""
    from ccdcore.datasheet import emva_figures

    return emva_figures(session, with_ptc=False).to_dict()


def emva_spatial_layout(emva: dict[str, Any]) -> Any | None:
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


def emva_spatial_text(emva: dict[str, Any]) -> str:
    """The spatial section's figures (:func:`ccdcore.emva_sheet.datasheet_rows`) as Markdown:
    each with its standard error, or why it is not determined."""
    lines = section_markdown(emva, "Spatial nonuniformity")
    sets = []
    for key, what in (("spatial", "bright"), ("spatial_dark", "dark")):
        s = emva.get(key)
        if isinstance(s, dict) and s.get("L"):
            sets.append(f"{s['L']} {what} frames")
    head = ("**EMVA 1288 spatial nonuniformity** (release 3.1 sec. 8; the row, column and pixel "
            "parts of release 4.0)" + (f", from the averages of {' and '.join(sets)}" if sets
                                       else "") + ":")
    return "\n".join([head, ""] + lines)


# ================================================================================ the page ====
class MapsPage(pn.viewable.Viewer):
    """Dark and fixed-pattern maps, planning and scene variation (see the module docstring)."""

    state = param.ClassSelector(class_=AppState, doc="The app state shared by all pages.")
    auto_compute = param.Boolean(default=True, doc=(
        "Compute the maps when the page is shown and the session has dark frames but no "
        "estimates yet."))
    computing = param.Boolean(default=False, precedence=-1, doc=(
        "True while the page computes the estimates (a request meanwhile is ignored)."))
    # ---- the Maps tab
    layers = param.Dict(default={}, precedence=-1, doc=(
        "The maps on the page: key -> ccdcore_app.map_plots.MapLayer, from the dark reference and K̂."))
    shown = param.ListSelector(default=[], objects=[], doc=(
        "Keys of the maps shown in the grid (linked zoom), in display order."))
    active = param.Selector(default=None, objects=[], allow_None=True, doc=(
        "Key of the selected map: its colour range, profiles and export."))
    overview = param.Selector(default="extreme", objects=list(plots.OVERVIEWS)[:2], doc=(
        "What a screen pixel of a zoomed-out value map shows: the value of its block farthest "
        "from the map's centre (a single deviating pixel stays visible) or the block mean."))
    # ---- the Scene tab
    scene = param.Dict(default=None, allow_None=True, precedence=-1, doc=(
        "The scene variation per patch shown (state.results.scene), or None."))
    patch = param.Selector(default=None, objects=[], allow_None=True, doc=(
        "The scene patch whose light levels and variance budget (Fig. 4) are shown."))
    # ---- the Planning tab: the inputs of ccdcore.planning.plan_acquisition
    A = param.Number(default=PAPER_PLAN_INPUTS["A"], allow_None=True,
                     doc="A: the gain in DN per electron (photon transfer).")
    sigma_c2 = param.Number(default=PAPER_PLAN_INPUTS["sigma_c2"], allow_None=True,
                            doc="σ²_C: the noise intercept in DN² (photon transfer).")
    bits = param.Integer(default=PAPER_PLAN_INPUTS["bits"], allow_None=True,
                         doc="b: the ADC bit depth.")
    sigma_hat = param.Number(default=PAPER_PLAN_INPUTS["sigma_hat"], allow_None=True,
                             doc="σ̂: the standard deviation of the fixed-pattern slopes m_i.")
    p = param.Number(default=PAPER_PLAN_INPUTS["p"], allow_None=True,
                     doc="p: the width of the slope rejection (eq. 48).")
    worst_ratio = param.Number(default=PAPER_PLAN_INPUTS["worst_ratio"], allow_None=True,
                               doc="n1/n̂_1 at the worst pixel (slopes rejected there).")
    black_level = param.Number(default=PAPER_PLAN_INPUTS["black_level"], allow_None=True,
                               doc="b0: the black level in DN.")
    n2_reading = param.Selector(default=PAPER_PLAN_INPUTS["n2_reading"], objects=_READINGS,
                                doc="Which reading of the paper's n2 rule to plan with.")
    # ---- the EMVA 1288 spatial tab
    emva = param.Dict(default=None, allow_None=True, precedence=-1, doc=(
        "The EMVA 1288 figures of the session (emva_spatial_figures), computed when the EMVA "
        "1288 spatial tab is first shown; None before and for another session."))
    emva_computing = param.Boolean(default=False, precedence=-1, doc=(
        "True while the page computes the EMVA 1288 figures."))

    def __init__(self, state: AppState | None = None, **params: Any):
        super().__init__(state=state if state is not None else AppState(), **params)
        #: the colour range of each map (the one slider shows the selected map's), and the
        #: slider's bounds, step, label and state per map
        self.clims: dict[str, tuple[float, float]] = {}
        self._clim_specs: dict[str, dict[str, Any]] = {}
        self._syncing_clim = False
        #: one view and one histogram per map key, built when the map is first shown, then
        #: fed in place; every map view shares the first one's zoom (linked)
        self.map_views: dict[str, ImageView] = {}
        self.hist_views: dict[str, HistogramView] = {}
        self._map_panes: dict[str, pn.pane.Bokeh] = {}
        self._hist_panes: dict[str, pn.pane.Bokeh] = {}
        self._shown_objects: tuple = (None, None)   # (dark, fp) the maps were built from
        self.plan_result: Any = None          # the planning panel's AcquisitionPlan
        self.budget: Any = None               # the chosen patch's variance budget
        self._build_header()
        self._build_maps_tab()
        self._build_scene_tab()
        self._build_planning_tab()
        self._build_emva_tab()
        self._layout: pn.viewable.Viewable | None = None
        self.state.param.watch(self._on_session, "session")
        self.state.results.param.watch(self._on_results, ["ptc", "estimates"])
        self.state.param.watch(self._on_state_message, ["error", "status", "busy"])
        self._update_plan()
        self._on_session()
        self._on_state_message()

    # ====================================================================== building ========
    def _build_header(self) -> None:
        self.compute_button = pn.widgets.Button(
            label="Compute maps", color="primary", width=170,
            description="D̂_D, K̂, the acquisition plan and V_S from this session's frames "
                        "(the same estimates as `ccdcore calibrate`)")
        self.compute_button.on_click(self._on_compute)
        self.status_pane = pn.pane.Markdown("", sizing_mode="stretch_width", margin=(8, 10))
        self.error_alert = _alert("", "danger", css_classes=["ccd-maps-error"])
        self.plan_alert = _alert("", "warning", css_classes=["ccd-plan-warning"])
        self.info_alert = _alert("", "info", css_classes=["ccd-maps-info"])

    def _build_maps_tab(self) -> None:
        self.shown_select = pn.widgets.MultiChoice.from_param(
            self.param.shown, label="Maps shown (linked zoom)", sizing_mode="stretch_width",
            min_width=320)
        self.active_select = pn.widgets.Select.from_param(self.param.active,
                                                          label="Selected map", width=280)
        # one slider, reconfigured in place for the selected map (a widget swapped into the
        # page is built again in the browser: 0.5 s per choice)
        self.clim_slider = pn.widgets.EditableRangeSlider(
            label="Colour range", start=0.0, end=1.0, value=(0.0, 1.0), step=0.001,
            sizing_mode="stretch_width", format="0.[00000]", visible=False)
        self.clim_slider.param.watch(self._on_clim, "value")
        # the zoomed-out views follow the choice in place
        self.overview_select = pn.widgets.RadioButtonGroup.from_param(
            self.param.overview, options={"extreme pixel": "extreme", "mean": "mean"},
            color="default", width=220,
            description="When a map has more pixels than the screen shows, each screen pixel "
                        "shows its block's pixel farthest from the centre (1 for K̂, the "
                        "median otherwise) or the block's mean; counts and flags show the "
                        "largest. The map's title says which.")
        self.param.watch(self._on_overview, "overview")
        self.auto_button = pn.widgets.Button(label="Auto (0.5–99.5 %)", align="end", width=150)
        self.auto_button.on_click(self._on_auto)
        self.row_slider = pn.widgets.IntSlider(label="Profile row y", start=0, end=1, value=0,
                                               sizing_mode="stretch_width")
        self.col_slider = pn.widgets.IntSlider(label="Profile column x", start=0, end=1,
                                               value=0, sizing_mode="stretch_width")
        self.row_slider.param.watch(self._update_profiles, "value")
        self.col_slider.param.watch(self._update_profiles, "value")
        self.download_exr = pn.widgets.FileDownload(
            callback=lambda: self._download("exr"), filename="map.exr", label="EXR",
            color="default", embed=False, width=90,
            description="The selected map as float32 OpenEXR (values, bit-exact)")
        self.download_fits = pn.widgets.FileDownload(
            callback=lambda: self._download("fits"), filename="map.fits", label="FITS",
            color="default", embed=False, width=90,
            description="The selected map as float32 FITS (values, bit-exact)")
        self.download_png = pn.widgets.FileDownload(
            callback=lambda: self._download("png"), filename="map.png", label="PNG",
            color="default", embed=False, width=90,
            description="A 16-bit greyscale picture of the selected map scaled to the current "
                        "colour range (low end 0, high end 65535) — not the values")
        # the shown maps' views side by side, wrapping (fixed-size figures; a GridBox whose
        # children and column count change in one batch fails in BokehJS 3.9)
        self.grid_pane = pn.FlexBox(flex_wrap="wrap", sizing_mode="stretch_width",
                                    css_classes=["ccd-maps"])
        self.readout = pn.pane.Markdown(
            "Move the cursor over a map to read the values of every map; tap to set the "
            "profile row and column.", css_classes=["ccd-readout"], stylesheets=[_CSS],
            sizing_mode="stretch_width")
        self.hist_row = pn.FlexBox(sizing_mode="stretch_width", css_classes=["ccd-histograms"])
        # side by side in a FlexBox: a Row of stretching plots nested this deep makes Bokeh
        # lay the map grid out at zero size
        # built once (plain Bokeh): the sliders and the selected map replace their data
        self.profiles = map_plots.ProfileFigures()
        self.row_profile_pane = pn.pane.Bokeh(
            self.profiles.row, sizing_mode="stretch_width", height=240, min_width=300,
            styles={"flex": "1 1 45%"})
        self.col_profile_pane = pn.pane.Bokeh(
            self.profiles.col, sizing_mode="stretch_width", height=240, min_width=300,
            styles={"flex": "1 1 45%"})
        self.profiles.row.css_classes = self.profiles.col.css_classes = ["ccd-profile"]
        self.map_note = pn.pane.Markdown("", sizing_mode="stretch_width", margin=(0, 10),
                                         styles={"color": "#6c757d", "font-size": "0.9em"})
        self.dark_table = _stats_pane()
        self.fp_table = _stats_pane()
        self.check_table = _stats_pane()
        self.rules_pane = pn.pane.Markdown("", sizing_mode="stretch_width",
                                           styles={"font-size": "0.85em", "color": "#495057"})
        self.check_note = pn.pane.Markdown("", sizing_mode="stretch_width",
                                           styles={"font-size": "0.85em", "color": "#495057"})
        self.dark_card = pn.Card(self.dark_table, self.rules_pane,
                                 title="Dark reference D̂_D (sec. V-A)", collapsible=False,
                                 width=355, visible=False, margin=5)
        self.fp_card = pn.Card(self.fp_table, title="Fixed pattern K̂ (eqs. 45–50)",
                               collapsible=False, width=355, visible=False, margin=5)
        self.check_card = pn.Card(self.check_table, self.check_note,
                                  title="Correction check (sec. VII-A)", collapsible=False,
                                  width=355, visible=False, margin=5)
        self.maps_empty = pn.pane.Markdown("No maps yet.", sizing_mode="stretch_width")

    def _build_scene_tab(self) -> None:
        self.patch_table = _table()
        self.patch_select = pn.widgets.Select.from_param(self.param.patch, label="Patch",
                                                         width=260)
        self.level_table = _table()
        self.fit_pane = pn.pane.HoloViews(None, sizing_mode="stretch_width", height=380,
                                          linked_axes=False, css_classes=["ccd-scene-fit"])
        self.budget_pane = pn.pane.HoloViews(None, sizing_mode="stretch_width", height=380,
                                             linked_axes=False, css_classes=["ccd-budget"])
        self.budget_note = pn.pane.Markdown("", sizing_mode="stretch_width",
                                            styles={"font-size": "0.88em", "color": "#495057"})
        self.scene_alert = _alert("", "danger")
        self.scene_empty = pn.pane.Markdown(
            "No scene variation yet: compute the maps with a session holding photon-transfer "
            f"frames and {requirement('scene').capture}.", sizing_mode="stretch_width")

    def _build_planning_tab(self) -> None:
        self.plan_A = pn.widgets.FloatInput.from_param(self.param.A, label="A (DN per electron)",
                                                       step=1e-4, start=0.0, width=170)
        self.plan_sigma_c2 = pn.widgets.FloatInput.from_param(
            self.param.sigma_c2, label="σ²_C (DN²)", step=0.01, start=0.0, width=170)
        self.plan_bits = pn.widgets.IntInput.from_param(self.param.bits, label="bits b", start=1,
                                                        end=32, width=120)
        self.plan_sigma_hat = pn.widgets.FloatInput.from_param(
            self.param.sigma_hat, label="σ̂ (slope std)", step=1e-4, start=0.0, width=170)
        self.plan_p = pn.widgets.FloatInput.from_param(self.param.p, label="p (rejection width)",
                                                       step=0.1, start=0.1, width=150)
        self.plan_worst = pn.widgets.FloatInput.from_param(
            self.param.worst_ratio, label="worst ratio n1/n̂_1", step=0.05, start=1.0, width=170)
        self.plan_black = pn.widgets.FloatInput.from_param(
            self.param.black_level, label="black level b0 (DN)", step=1.0, width=150)
        self.plan_reading = pn.widgets.Select.from_param(self.param.n2_reading,
                                                         label="n2 reading", width=330)
        self._plan_inputs = (self.plan_A, self.plan_sigma_c2, self.plan_bits,
                             self.plan_sigma_hat, self.plan_p, self.plan_worst,
                             self.plan_black, self.plan_reading)
        self.paper_button = pn.widgets.Button(label="Paper's values", width=150)
        self.paper_button.on_click(self._on_paper_inputs)
        self.session_inputs_button = pn.widgets.Button(
            label="This session's estimates", width=200, disabled=True,
            description="A, σ²_C and b0 from photon transfer; σ̂ and the worst ratio from K̂")
        self.session_inputs_button.on_click(self._on_session_inputs)
        self.plan_source = pn.pane.Markdown("", sizing_mode="stretch_width",
                                            styles={"color": "#6c757d", "font-size": "0.9em"})
        self.plan_numbers = pn.pane.HTML("", sizing_mode="stretch_width", stylesheets=[_CSS],
                                         css_classes=["ccd-plan-numbers"])
        self.plan_formulas = pn.pane.Markdown("", sizing_mode="stretch_width",
                                              css_classes=["ccd-formula"], stylesheets=[_CSS])
        self.plan_alternatives = _table()
        self.plan_error = _alert("", "danger")

    def _build_emva_tab(self) -> None:
        self.emva_note = pn.pane.Markdown("", sizing_mode="stretch_width",
                                          css_classes=["ccd-emva-note"])
        # one Bokeh layout for the section's twelve plots (one pane: the cheapest to send)
        # (never hidden: Panel's Bokeh pane takes its visibility from the Bokeh model's)
        self.emva_pane = pn.pane.Bokeh(None, sizing_mode="stretch_width",
                                       css_classes=["ccd-emva-spatial"])
        #: the Bokeh layout of ``emva`` (built with it, off the UI thread)
        self._emva_layout: Any = None
        self._emva_status()

    # ======================================================================== layout =======
    def on_show(self) -> None:
        """Called by the navigation each time it shows the page: compute on first show."""
        if self.auto_compute and self._wants_auto_compute():
            pn.state.execute(self.compute)

    def __panel__(self) -> pn.viewable.Viewable:
        if self._layout is None:
            self._layout = self._build_layout()
        return self._layout

    def _build_layout(self) -> pn.viewable.Viewable:
        controls = pn.Column(
            pn.FlexBox(self.shown_select, self.active_select, sizing_mode="stretch_width"),
            pn.Row(pn.Column(self.clim_slider, sizing_mode="stretch_width", min_width=300),
                   self.auto_button, sizing_mode="stretch_width"),
            pn.Row(pn.pane.Markdown("**Zoomed out**, a screen pixel of a map shows:",
                                    margin=(12, 10, 0, 10)),
                   self.overview_select, sizing_mode="stretch_width"),
            sizing_mode="stretch_width")
        export = pn.Row(pn.pane.Markdown("**Export the selected map:**", margin=(12, 10)),
                        self.download_exr, self.download_fits, self.download_png)
        stats = pn.FlexBox(self.dark_card, self.fp_card, self.check_card,
                           sizing_mode="stretch_width", css_classes=["ccd-map-stats"])
        maps_body = pn.Column(
            controls, self.map_note, self.grid_pane, self.readout, stats,
            pn.Card(self.hist_row, title="Histograms (the band is the colour range)",
                    sizing_mode="stretch_width"),
            pn.Card(pn.Row(self.row_slider, self.col_slider, sizing_mode="stretch_width"),
                    pn.FlexBox(self.row_profile_pane, self.col_profile_pane,
                               sizing_mode="stretch_width"),
                    title="Profiles through the selected map (tap a map to move them)",
                    sizing_mode="stretch_width"),
            export, sizing_mode="stretch_width")
        self.maps_body = maps_body
        maps_tab = pn.Column(self.maps_empty, maps_body, sizing_mode="stretch_width",
                             name="Maps")
        scene_tab = pn.Column(
            self.scene_empty, self.scene_alert,
            pn.Row(pn.Card(self.patch_table, title="V_S per patch (eq. 57 fit across levels)",
                           collapsible=False, sizing_mode="stretch_width"),
                   sizing_mode="stretch_width"),
            self.fit_pane,
            pn.Card(self.patch_select, self.level_table,
                    title="Per light level (eqs. 54–58)", collapsible=False,
                    sizing_mode="stretch_width"),
            self.budget_pane, self.budget_note,
            sizing_mode="stretch_width", name="Scene")
        inputs = pn.FlexBox(*self._plan_inputs, sizing_mode="stretch_width")
        planning_tab = pn.Column(
            pn.pane.Markdown(
                "How many fixed-pattern configurations **n1** and frames per configuration "
                "**n2** to capture for K̂ (sec. V-B): the error of K̂ at full scale below "
                "q²/10 (n1) and the variance of each configuration's average below 0.2 q² (n2)."
                " Type your camera's values before capture, or take them from this session's "
                "estimates.", sizing_mode="stretch_width"),
            pn.Row(self.paper_button, self.session_inputs_button), self.plan_source,
            inputs, self.plan_error, self.plan_numbers, self.plan_formulas,
            pn.Card(self.plan_alternatives, title="n2 under each reading of the paper",
                    sizing_mode="stretch_width", collapsed=False),
            sizing_mode="stretch_width", name="Planning")
        # a button bar switching the content (Bokeh's Tabs lay a grid of fixed-size plots out
        # at zero size; swapping the content also renders each view only when it is shown)
        emva_tab = pn.Column(self.emva_note, self.emva_pane, sizing_mode="stretch_width",
                             name=EMVA_TAB)
        self._tab_views = {"Maps": maps_tab, "Scene": scene_tab, "Planning": planning_tab,
                           EMVA_TAB: emva_tab}
        self.tab_bar = pn.widgets.RadioButtonGroup(
            options=self._tab_names(), value="Maps", color="primary",
            variant="outline", css_classes=["ccd-maps-tabs"], margin=(10, 10, 0, 10))
        self.tab_content = pn.Column(maps_tab, sizing_mode="stretch_width")
        self.tab_bar.param.watch(self._on_tab, "value")
        return pn.Column(
            pn.pane.Markdown("## Maps", css_classes=["ccd-page-title"]),
            pn.Row(self.compute_button, self.status_pane, sizing_mode="stretch_width"),
            self.error_alert, self.plan_alert, self.info_alert, self.tab_bar,
            pn.layout.Divider(margin=(0, 10)), self.tab_content,
            sizing_mode="stretch_width", name="Maps", stylesheets=[_CSS])

    def _tab_names(self) -> list[str]:
        """The tabs the session has (the EMVA 1288 spatial one for an EMVA set with a spatial
        set only)."""
        return [name for name in self._tab_views
                if name != EMVA_TAB or has_emva_spatial(self.state.session)]

    def _update_tabs(self) -> None:
        if self._layout is None:
            return
        names = self._tab_names()
        shown = self.tab_bar.value if self.tab_bar.value in names else "Maps"
        self.tab_bar.param.update(options=names, value=shown)
        if shown == EMVA_TAB and self.emva is None:      # another EMVA set, its tab shown
            pn.state.execute(self.compute_emva)

    def _on_tab(self, event: Any = None) -> None:
        self.tab_content.objects = [self._tab_views[self.tab_bar.value]]
        if self.tab_bar.value == EMVA_TAB and self.emva is None:
            pn.state.execute(self.compute_emva)

    # ===================================================================== computing ========
    def _wants_auto_compute(self) -> bool:
        s = self.state.session
        return (s is not None and not self.computing and bool(s.roles().get("dark"))
                and self.state.results.estimates is None and not self.state.busy)

    async def _on_compute(self, event: Any = None) -> None:
        await self.compute()

    async def compute(self) -> None:
        """Compute D̂_D, K̂, the plan, V_S and the correction check (``estimate_all``, off the
        UI thread) and publish them as ``state.results.estimates`` (the noise model, when the
        Photon transfer page has not made it, as ``state.results.ptc``)."""
        session = self.state.session
        if session is None or self.computing:
            return
        self.computing = True
        try:
            results = self.state.results
            noise, options = results.ptc, {"emva1288": False}
            name, params = estimates_entry(noise, **options)
            est = await self.state.cached_compute(
                name, params, estimate_all, session, noise=noise, steps=ESTIMATE_STEPS,
                pass_progress=True,
                label="dark reference, K̂, plan, scene variation and correction check",
                **options)
            if est is not None and self.state.session is session:
                results.param.update(estimates=est,
                                     ptc=est.noise if est.noise is not None else results.ptc)
                if noise is None and est.noise is not None:
                    await self._link_cached(est, options)
        finally:
            self.computing = False

    async def _link_cached(self, est: Any, options: dict[str, Any]) -> None:
        """Estimates made with their own noise model are also those given that model (the
        Photon transfer page's full-frame fit when it ran first) and hold photon_transfer's
        full-frame result: the disk cache learns both (links, not copies)."""
        state, cache = self.state, self.state.cache
        key = await state.cache_key(*estimates_entry(None, **options))
        if cache is None or key is None:
            return
        ptc_key = await state.cache_key(*photon_transfer_entry(None))
        given_key = await state.cache_key(*estimates_entry(est.noise, **options))

        def store() -> None:
            if given_key is not None:
                cache.link(given_key, key)
            if ptc_key is not None and cache.get(ptc_key) is None:
                cache.put(ptc_key, est.noise)
        await asyncio.to_thread(store)

    async def compute_emva(self) -> None:
        """Compute the EMVA 1288 figures of the session (:func:`emva_spatial_figures`, off the
        UI thread, through the disk cache) for the EMVA 1288 spatial tab, once per session."""
        session = self.state.session
        if not has_emva_spatial(session) or self.emva_computing or self.emva is not None:
            return
        self.emva_computing = True
        try:
            found = await self.state.cached_compute(
                "emva_figures", {"with_ptc": False}, emva_spatial_figures, session,
                label="the EMVA 1288 spatial nonuniformity")
            if found is not None and self.state.session is session:
                # twelve figures (some 0.3 s): built off the UI thread too
                layout = await asyncio.to_thread(emva_spatial_layout, found)
                if self.state.session is session:
                    self._emva_layout = layout
                    self.emva = found
        finally:
            self.emva_computing = False
        if self.state.session is not session:          # opened meanwhile: its own figures
            self._update_tabs()

    @param.depends("emva", watch=True)
    @batched
    def _show_emva(self) -> None:
        if self.emva is None:
            self._emva_layout = None
        self.emva_pane.object = self._emva_layout
        self._emva_status()

    @param.depends("emva_computing", watch=True)
    def _emva_status(self) -> None:
        if self.emva is not None:
            text = emva_spatial_text(self.emva)
        elif self.emva_computing:
            text = "Computing the EMVA 1288 figures … (progress and **Cancel** in the header)"
        else:
            text = ("The EMVA 1288 figures are computed when this tab is shown"
                    + (" (the last try failed: see the error above; show the tab again to "
                       "retry)." if self.state.error else "."))
        self.emva_note.object = text

    @param.depends("computing", watch=True)
    def _on_computing(self) -> None:
        self.compute_button.loading = self.computing
        self._update_info(self.state.session)

    # ===================================================================== watchers =========
    def _on_session(self, event: Any = None) -> None:
        self.compute_button.disabled = self.state.session is None
        self.emva = None
        self._update_tabs()
        self._refresh()
        if event is not None and self._layout is not None and self.auto_compute \
                and self._wants_auto_compute():
            pn.state.execute(self.compute)

    def _on_results(self, *events: Any) -> None:
        self._refresh()

    def _on_state_message(self, *events: Any) -> None:
        # the step and frame counts are in the header (a text changing four times a second
        # here would make the browser lay this page out again each time)
        self.status_pane.object = "Computing… (progress and **Cancel** in the header)" \
            if self.state.busy else ""
        self._update_errors()
        self._update_info(self.state.session)

    # ====================================================================== refresh =========
    @batched
    def _refresh(self) -> None:
        """Bring every tab in line with ``state.session`` and ``state.results``."""
        session, results = self.state.session, self.state.results
        dark, fp = results.dark, results.fixed_pattern
        if dark is not self._shown_objects[0] or fp is not self._shown_objects[1]:
            self._shown_objects = (dark, fp)
            self._set_layers(map_plots.map_layers(dark, fp))
        self._update_stats(session, results)
        self._update_errors()
        self._update_info(session)
        self._update_plan_warnings(results.estimates)
        self._set_scene(results.scene)
        self._prefill_plan(results)

    def _update_errors(self) -> None:
        """The app's error and the estimates whose frames the method refused (``failed``)."""
        parts = [f"**Error:** {html.escape(self.state.error)}"] if self.state.error else []
        est = self.state.results.estimates
        if est is not None:
            parts += [f"**Not estimated — {html.escape(_purpose(s.estimate))}:** "
                      f"{html.escape(s.reason)}" for s in est.skipped if s.code == "failed"]
        text = "\n\n".join(parts)
        self.error_alert.object = text
        self.error_alert.visible = bool(text)

    def _update_info(self, session: Session | None) -> None:
        if session is None:
            text = "Open a session on the Session page; the Planning tab works without one."
        else:
            # estimates skipped for missing frames say so in missing_sentences; those skipped
            # because an estimate they build on is missing, and the remarks, are notes
            est = self.state.results.estimates
            lines = missing_sentences(session)
            if est is not None:
                lines += [f"Note: {_purpose(s.estimate)} not made: {s.reason}"
                          for s in est.skipped if s.code in ("needs", "not-applicable")]
            elif session.roles().get("dark") and not self.computing and not self.state.error:
                lines.insert(0, "Press **Compute maps** to estimate D̂_D, K̂, the plan and V_S.")
            text = "\n\n".join(lines)
        self.info_alert.object = text
        self.info_alert.visible = bool(text)

    def _update_plan_warnings(self, est: Any) -> None:
        warnings = est.plan_warnings if est is not None and est.plan is not None else ()
        if warnings:
            items = "\n".join(f"- {html.escape(w)}" for w in warnings)
            text = ("**This session has fewer frames than the acquisition plan requires "
                    f"(sec. V-B)** — K̂ is less accurate than the plan's target:\n\n{items}")
        else:
            text = ""
        self.plan_alert.object = text
        self.plan_alert.visible = bool(text)

    def _update_stats(self, session: Session | None, results: Any) -> None:
        dark, fp, check = results.dark, results.fixed_pattern, results.correction_check
        self.dark_card.visible = dark is not None
        if dark is not None:
            self.dark_table.object = dark_summary(dark)
            self.rules_pane.object = (f"Rules — {html.escape(dark.hot_rule)}; "
                                      f"{html.escape(dark.dead_rule)}.")
        self.fp_card.visible = fp is not None
        if fp is not None:
            self.fp_table.object = fixed_pattern_summary(fp)
        rec = session.max_intensity_frame() if session is not None else None
        self.check_card.visible = fp is not None
        if check is not None and fp is not None:
            self.check_table.object = correction_summary(check)
            self.check_table.visible = True
            self.check_note.object = (f"How much dividing by K̂ (eq. 51) changes "
                                      f"`{rec.relpath if rec else 'the max-intensity frame'}`.")
        elif fp is not None:
            self.check_table.visible = False
            self.check_note.object = (
                f"No maximum-intensity scene frame: capture "
                f"{requirement('correction_check').capture}, just below saturation, to check "
                "how much K̂ changes it." if rec is None
                else "Not computed yet: press **Compute maps**.")

    # ========================================================================= maps =========
    def _set_layers(self, layers: dict[str, MapLayer]) -> None:
        """Show ``layers``: new colour-range sliders, the choices, then (one batch of events)
        the grid and the selected map once each."""
        clims, specs = {}, {}
        for key, layer in layers.items():
            lo, hi = map_plots.default_clim(layer)
            finite = layer.data[np.isfinite(layer.data)]
            start = min(lo, float(finite.min())) if finite.size else lo
            end = max(hi, float(finite.max())) if finite.size else hi
            if layer.kind == "diverging":
                half = max(layer.centre - start, end - layer.centre)
                start, end = layer.centre - half, layer.centre + half
            if not end > start:
                end = start + 1.0
            step = 0.5 if layer.integer else (end - start) / 1000
            clims[key] = (lo, hi)
            specs[key] = dict(
                label=f"Colour range of {layer.symbol}" + (f" ({layer.unit})" if layer.unit
                                                         else ""),
                start=start, end=end, step=step, disabled=layer.kind == "flags")
        self.clims, self._clim_specs = clims, specs
        options = {l.title: k for k, l in layers.items()}
        shown = [k for k in self.shown if k in layers] or \
            [k for k in DEFAULT_SHOWN if k in layers]
        active = self.active if self.active in layers else next(iter(shown), None)
        self.maps_empty.visible = not layers
        if hasattr(self, "maps_body"):
            self.maps_body.visible = bool(layers)
        if layers:
            h, w = next(iter(layers.values())).data.shape
            self.row_slider.param.update(end=max(h - 1, 1), value=h // 2)
            self.col_slider.param.update(end=max(w - 1, 1), value=w // 2)
        set_choices(self, {"shown": (self.shown_select, options, shown),
                           "active": (self.active_select, options, active)}, layers=layers)

    @property
    def active_layer(self) -> MapLayer | None:
        """The selected map (colour range, profiles and export apply to it)."""
        return self.layers.get(self.active)

    @param.depends("layers", "shown", watch=True)
    @batched
    def _build_grid(self) -> None:
        """Show the chosen maps: their views (built on a map's first showing, then fed the new
        data in place) in the grid, and their histograms."""
        for key, view in self.map_views.items():   # maps gone: their data goes too
            if key not in self.layers and view.plane is not None:
                view.show(None)
                self.hist_views[key].show(None)
        keys = [k for k in self.shown if k in self.layers]
        frame_width = 640 if len(keys) == 1 else 380
        maps, hists = [], []
        for key in keys:
            layer, clim = self.layers[key], self.clims[key]
            view = self.map_views.get(key)
            if view is None:
                link = next(iter(self.map_views.values()), None)
                view = self.map_views[key] = map_plots.layer_view(
                    layer, frame_width=frame_width, link=link)
                view.on_pointer, view.on_tap = self._on_pointer, self._on_tap
                self._map_panes[key] = pn.pane.Bokeh(view.figure)
                self.hist_views[key] = HistogramView(height=200,
                                                     title=f"Histogram of {layer.symbol}",
                                                     label=layer.label, symbol=layer.symbol)
                self._hist_panes[key] = pn.pane.Bokeh(
                    self.hist_views[key].figure, height=220, min_width=260,
                    sizing_mode="stretch_width", styles={"flex": "1 1 45%"})
            else:
                view.resize(frame_width)
            if view.plane is not layer.data:
                map_plots.show_layer(view, layer, clim, self.overview)
                values, bins = map_plots.histogram_input(layer)
                self.hist_views[key].show(values, clim, bins=bins)
            view.set_crosshair(self.row_slider.value, self.col_slider.value)
            maps.append(self._map_panes[key])
            hists.append(self._hist_panes[key])
        self.grid_pane.objects = maps
        self.hist_row.objects = hists

    @property
    def grid_views(self) -> list[ImageView]:
        """The views of the shown maps, in display order."""
        return [self.map_views[k] for k in self.shown if k in self.layers and k in self.map_views]

    def release(self) -> None:
        """The browser session ended: drop the maps (no watcher runs, nothing is redrawn)."""
        for view in self.map_views.values():
            view.release()
        with param.parameterized.discard_events(self):
            self.layers = {}
            self.emva = None
        self._emva_layout = None

    def _on_clim(self, event: Any) -> None:
        """The slider moved: the selected map's colour range, its view and histogram band."""
        key = self.active
        if self._syncing_clim or key not in self.clims:
            return
        self.clims[key] = tuple(event.new)
        if key in self.map_views:
            self.map_views[key].set_clim(event.new)
            self.hist_views[key].set_band(event.new)

    @batched
    def _on_overview(self, event: Any = None) -> None:
        for key, view in self.map_views.items():
            layer = self.layers.get(key)
            if layer is not None and view.plane is layer.data:
                how = map_plots.overview_how(layer, self.overview)
                view.set_how(how, centre=map_plots.overview_centre(layer)
                             if how == "extreme" else None)

    @param.depends("layers", "active", watch=True)
    @batched
    def _on_active(self) -> None:
        layer = self.active_layer
        if layer is None:
            self.clim_slider.visible = False
            self.map_note.object = ""
        else:
            self._syncing_clim = True
            try:   # bounds, step, label and value at once (one message)
                self.clim_slider.param.update(value=self.clims[layer.key], visible=True,
                                              **self._clim_specs[layer.key])
            finally:
                self._syncing_clim = False
            self.map_note.object = f"**{html.escape(layer.title)}**: {html.escape(layer.note)}."
            for fmt, widget in (("exr", self.download_exr), ("fits", self.download_fits),
                                ("png", self.download_png)):
                widget.filename = f"{layer.key}{EXPORT_FORMATS[fmt]}"
        for w in (self.auto_button, self.download_exr, self.download_fits, self.download_png):
            w.disabled = layer is None
        self._update_profiles()

    @batched
    def _update_profiles(self, event: Any = None) -> None:
        row, col = self.row_slider.value, self.col_slider.value
        self.profiles.update(self.active_layer, row, col)
        for view in self.grid_views:
            view.set_crosshair(row, col)

    def _on_pointer(self, x: float | None = None, y: float | None = None) -> None:
        hit = map_plots.pixel_values(self.layers, x, y)
        if hit is None:
            return
        col, row, values = hit
        parts = []
        for key, text in values.items():
            layer = self.layers[key]
            unit = f" {layer.unit}" if layer.unit and text != "NaN" else ""
            parts.append(f"{layer.symbol} = **{text}**{unit}")
        self.readout.object = f"x = {col}, y = {row}: " + " · ".join(parts)

    def _on_tap(self, x: float | None = None, y: float | None = None) -> None:
        hit = map_plots.pixel_values(self.layers, x, y)
        if hit is not None:
            col, row, _ = hit
            self.row_slider.value, self.col_slider.value = row, col

    def _on_auto(self, event: Any = None) -> None:
        layer = self.active_layer
        if layer is not None:
            spec = self._clim_specs[layer.key]
            lo, hi = map_plots.default_clim(layer)
            self.clim_slider.value = (max(spec["start"], lo), min(spec["end"], hi))

    def export(self, fmt: str) -> bytes:
        """The selected map as the bytes of an EXR, FITS or PNG file (see :func:`export_bytes`;
        PNG uses the selected map's current colour range)."""
        layer = self.active_layer
        if layer is None:
            raise CcdError("export", "no map to export: compute the maps first")
        return export_bytes(layer, fmt, self.clims[layer.key])

    def _download(self, fmt: str) -> io.BytesIO | None:
        try:
            return io.BytesIO(self.export(fmt))
        except (CcdError, OSError, ValueError) as err:
            self.state.error = f"export as {fmt.upper()} failed: {err}"
            return None

    # ======================================================================== scene =========
    def _set_scene(self, scene: dict | None) -> None:
        """Show ``scene`` (V_S per patch): its patches to choose from, keeping the chosen one."""
        if scene is self.scene:
            return
        names = list(scene or {})
        patch = self.patch if self.patch in names else next(iter(names), None)
        set_choices(self, {"patch": (self.patch_select, names, patch)}, scene=scene)

    @param.depends("scene", watch=True)
    def _show_scene(self) -> None:
        scene = self.scene
        has = bool(scene)
        self.scene_empty.visible = not has
        for w in (self.patch_table, self.fit_pane, self.patch_select, self.level_table,
                  self.budget_pane, self.budget_note):
            w.visible = has
        if has:
            self.patch_table.value = _display(scene_patch_frame(scene))
            self.fit_pane.object = map_plots.scene_fit_plot(scene)

    @param.depends("scene", "patch", watch=True)
    def _update_patch(self) -> None:
        variation = (self.scene or {}).get(self.patch)
        if variation is None:
            return
        self.level_table.value = _display(scene_level_frame(variation))
        results = self.state.results
        dark, fp, noise = results.dark, results.fixed_pattern, results.ptc
        self.scene_alert.visible = False
        if dark is None or fp is None or noise is None:
            self.budget_pane.object = None
            return
        bits = getattr(getattr(self.state.session, "camera", None), "bits", None)
        inputs = budget_inputs(dark, fp, noise, variation, bits)
        try:
            budget = variance_budget(**inputs)
        except CcdError as err:
            self.scene_alert.object = f"**Variance budget:** {html.escape(str(err))}"
            self.scene_alert.visible = True
            self.budget_pane.object = None
            return
        self.budget = budget
        self.budget_pane.object = map_plots.budget_plot(budget)
        self.budget_note.object = (
            f"Patch **{html.escape(variation.name)}**: V_S = {inputs['V_S']:.4g}, "
            f"A = {inputs['A']:.4g} DN/e⁻, σ²_C = {inputs['sigma_c2']:.4g} DN², dark spatial "
            f"variance {inputs['dark_spatial_var']:.4g} DN² (D̂_D without its averaging noise), "
            f"σ_K² = {inputs['sigma_K2']:.4g} (K̂'s spatial variance less its mean estimation "
            f"variance), b0 = {inputs['black_level']:g} DN, D̄ = {inputs['dark_mean']:.4g} DN. "
            "Below the crossing the sensor noise dominates; above it K and the scene texture do.")

    # ===================================================================== planning =========
    def plan_inputs(self) -> dict[str, Any]:
        """The Planning tab's inputs, as keyword arguments of ``plan_acquisition``."""
        return {k: getattr(self, k) for k in PLAN_INPUTS}

    @param.depends(*PLAN_INPUTS, watch=True)
    def _update_plan(self) -> None:
        kw = self.plan_inputs()
        try:
            if any(v is None for v in kw.values()):
                raise CcdError("planning", "fill in every input")
            plan = plan_acquisition(**kw)
        except CcdError as err:
            self.plan_result = None
            self.plan_error.object = f"**Cannot plan:** {html.escape(str(err))}"
            self.plan_error.visible = True
            self.plan_numbers.object = self.plan_formulas.object = ""
            self.plan_alternatives.value = pd.DataFrame()
            return
        self.plan_result = plan
        self.plan_error.visible = False
        self.plan_numbers.object = (
            "<div>Capture <span class='ccd-big'>n1 = "
            f"{plan.n1_required}</span> configurations &times; <span class='ccd-big'>n2 = "
            f"{plan.n2_required}</span> frames per configuration "
            f"({plan.n1_required * plan.n2_required} fixed-pattern frames); "
            f"n̂_1 = {plan.n1_hat} slopes kept at the worst pixel.</div>")
        notes = "\n".join(f"- {html.escape(n)}" for n in plan.notes)
        self.plan_formulas.object = (
            f"**n1** (text after eq. 50): `{plan.n1_formula}`\n\n"
            f"**n2** (end of sec. V-B, reading *{plan.n2_reading}*): `{plan.n2_formula}`"
            + (f"\n\n{notes}" if notes else ""))
        self.plan_alternatives.value = pd.DataFrame(
            [{"reading": _READING_TEXT.get(k, k), "n2": v,
              "chosen": "✓" if k == plan.n2_reading else ""}
             for k, v in plan.n2_alternatives.items()],
            columns=["reading", "n2", "chosen"])

    def _set_plan_inputs(self, values: dict[str, Any], source: str) -> None:
        """Set the planning inputs (one plan update for all of them)."""
        self.param.update(**{k: v for k, v in values.items()
                             if k in PLAN_INPUTS and v is not None})
        self.plan_source.object = source

    def session_plan_inputs(self) -> dict[str, Any] | None:
        """Planning inputs from the session's results (``None`` without a noise model)."""
        results, session = self.state.results, self.state.session
        noise, fp = results.ptc, results.fixed_pattern
        if noise is None:
            return None
        b0 = noise.black_level_dn
        values: dict[str, Any] = {"A": _round(noise.A), "sigma_c2": _round(noise.sigma_c2),
                                  "black_level": float(b0) if b0 is not None else 0.0}
        bits = getattr(getattr(session, "camera", None), "bits", None)
        if bits:
            values["bits"] = int(bits)
        if fp is not None:
            values["sigma_hat"] = _round(fp.sigma_hat)
            if math.isfinite(fp.worst_ratio):
                values["worst_ratio"] = _round(fp.worst_ratio)
            values["p"] = float(fp.p)
        return values

    def _prefill_plan(self, results: Any) -> None:
        key = (id(results.ptc), id(results.fixed_pattern))
        if key == getattr(self, "_prefilled", None):
            return
        self._prefilled = key
        values = self.session_plan_inputs()
        self.session_inputs_button.disabled = values is None
        if values is None:
            self._set_plan_inputs(PAPER_PLAN_INPUTS, "Inputs: the paper's values (sec. VII-A; "
                                  "σ̂ = 2.7e-3 reproduces its n̂_1 = 11). Edit them for your "
                                  "camera.")
        else:
            self._on_session_inputs()

    def _on_paper_inputs(self, event: Any = None) -> None:
        self._set_plan_inputs(PAPER_PLAN_INPUTS, "Inputs: the paper's values (sec. VII-A; "
                              "σ̂ = 2.7e-3 reproduces its n̂_1 = 11).")

    def _on_session_inputs(self, event: Any = None) -> None:
        values = self.session_plan_inputs()
        if values is None:
            return
        has_fp = self.state.results.fixed_pattern is not None
        self._set_plan_inputs(values, "Inputs: this session's photon transfer (A, σ²_C, b0)"
                              + (" and fixed pattern (σ̂, worst ratio, p)." if has_fp else
                                 "; σ̂ and the worst ratio are the paper's / the default until "
                                 "K̂ is computed."))


def create_page(state: AppState) -> MapsPage:
    """Registry entry point: the Maps page bound to ``state``."""
    return MapsPage(state)
