"""Pure plot-building functions of the Maps page (no widgets, no state).

The maps come straight from ccdcore's result objects (:class:`ccdcore.dark.frame.DarkReference`,
:class:`ccdcore.fixedpattern.FixedPattern`); nothing here estimates anything, it only arranges
arrays for display. Functions return views, HoloViews elements or plain numbers, so the pipeline is
tested without a browser.

Public objects
--------------
MapLayer
    One inspectable map: key, title, symbol, unit, the (H, W) data, colour map and kind.
MAP_TITLES
    Map key -> title, in display order.
map_layers(dark=None, fixed_pattern=None)
    Every map the results allow: D̂_D, its temporal variance, K̂, K̂'s error, n'_1, rejected
    configurations, hot/dead flags.
default_clim(layer)
    The colour range a map opens with (0.5–99.5 % percentiles; symmetric about 1 for K̂; the
    category range for flags).
layer_view(layer, frame_width=380, link=None), show_layer(view, layer, clim, how)
    A zoomable view (:class:`ccdcore_app.image_view.ImageView`) in the map's colour map, built once
    per map key and linked to the others, and drawing a map in it at screen resolution with a
    stated reduction (extreme or mean) when zoomed out.
overview_how(layer, how), overview_centre(layer)
    The reduction a zoomed-out view of a map uses, and the value "extreme" measures from.
histogram_input(layer)
    The values and bin count of a map's histogram (:class:`ccdcore_app.image_view.HistogramView`).
profile_columns(layer, row, col), ProfileFigures
    One row and one column of a map as source columns, and their two Bokeh figures built once.
pixel_values(layers, x, y)
    The value of every map at a cursor position (for the readout line).
scaled_uint16(data, clim)
    A map scaled to a colour range as 16-bit grey levels (0 at ``clim[0]``, 65535 at ``clim[1]``).
scene_fit_plot(variations)
    Fig. 3 of Healey & Kondepudy 1994: σ̂²_D − σ̂²_KN against μ̂²_D per patch with the fitted
    lines V_S·μ̂²_D (eq. 57).
budget_plot(budget)
    Fig. 4: the fractions of the variance of an uncorrected region against intensity, stacked.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import holoviews as hv
import numpy as np
from numpy.typing import NDArray

from ccdcore.product.make import MapName

from . import base as plots
from ..image_view import ImageView

__all__ = ["overview_how", "overview_centre", "MapLayer",
           "MAP_TITLES", "FLAG_COLORS", "FLAG_LABELS", "map_layers", "default_clim",
           "layer_view", "show_layer", "histogram_input", "profile_columns", "ProfileFigures",
           "pixel_values", "scaled_uint16", "scene_fit_plot", "budget_plot", "BUDGET_COLORS"]

#: map key -> title, in display order (a product's map by its :class:`ccdcore.product.make.MapName`)
MAP_TITLES: dict[str, str] = {
    MapName.DARK: "Dark reference D\u0302_D",
    MapName.DARK_VAR: "Dark temporal variance \u03c3\u00b2_N",
    MapName.K: "Fixed pattern K\u0302",
    "K_err": "K\u0302 error \u221avar[K\u0302]",
    MapName.N1_USED: "Slopes kept n'_1",
    "n_rejected": "Rejected configurations n1 \u2212 n'_1",
    "flags": "Hot / dead pixels",
}

#: flag value -> label and colour of the hot/dead map (0 = normal)
FLAG_LABELS: dict[int, str] = {0: "normal", 1: "hot", 2: "dead"}
FLAG_COLORS: tuple[str, ...] = ("#e9ecef", "#d62728", "#1f4e9c")

#: colours of the variance-budget components (Fig. 4), in BUDGET_COMPONENTS order
BUDGET_COLORS: dict[str, str] = {"dark spatial": "#7f7f7f", "sigma_C^2": "#9467bd",
                                 "shot noise": "#2ca02c", "K variation": "#ff7f0e",
                                 "scene": "#1f77b4"}
_BUDGET_LABELS = {"dark spatial": "dark spatial", "sigma_C^2": "\u03c3\u00b2_C",
                  "shot noise": "shot noise", "K variation": "K variation",
                  "scene": "scene V_S"}


@dataclass(frozen=True, eq=False)
class MapLayer:
    """One map of the Maps page.

    Attributes
    ----------
    key
        Short name (a key of :data:`MAP_TITLES`; also the export file's base name).
    title
        Title shown above the map.
    symbol
        Value dimension name (hover label, histogram axis), e.g. ``"K\u0302"``.
    unit
        Unit of the values (``"DN"``, ``"DN\u00b2"``, ``""``).
    data
        The (H, W) values, float32 or float64 as ccdcore returned them (flags: 0/1/2).
    cmap
        Colour map name or list of colours.
    kind
        ``"value"``, ``"diverging"`` (centred on ``centre``), ``"count"`` or ``"flags"``.
    centre
        Centre of a diverging map (1 for K̂).
    note
        One line saying what the map is (paper equation, rule).
    """

    key: str
    title: str
    symbol: str
    unit: str
    data: NDArray
    cmap: Any = "gray"
    kind: str = "value"
    centre: float = 0.0
    note: str = ""

    @property
    def label(self) -> str:
        """``symbol (unit)`` for axes."""
        return f"{self.symbol} ({self.unit})" if self.unit else self.symbol

    @property
    def integer(self) -> bool:
        return self.kind in ("count", "flags")


def map_layers(dark: Any = None, fixed_pattern: Any = None) -> dict[str, MapLayer]:
    """Every map the results allow, keyed as :data:`MAP_TITLES` and in that order.

    Parameters
    ----------
    dark
        A :class:`~ccdcore.dark.frame.DarkReference` (or ``None``): D̂_D, its temporal variance
        σ̂²_N (sec. V-A, eq. 43) and the hot/dead flags.
    fixed_pattern
        A :class:`~ccdcore.fixedpattern.FixedPattern` (or ``None``): K̂ (eq. 49), its per-pixel
        error √var[K̂], n'_1 and the rejected-configuration count n1 − n'_1.
    """
    out: dict[str, MapLayer] = {}
    if dark is not None:
        out[MapName.DARK] = MapLayer(MapName.DARK, MAP_TITLES[MapName.DARK], "D\u0302_D", "DN",
                                     dark.mean_map, "gray",
                                     note=f"mean of s = {dark.s} dark frames (sec. V-A)")
        out[MapName.DARK_VAR] = MapLayer(MapName.DARK_VAR, MAP_TITLES[MapName.DARK_VAR],
                                         "\u03c3\u00b2_N", "DN\u00b2", dark.var_map, "viridis",
                                         note="per-pixel temporal sample variance (eq. 43), "
                                              "ddof = 1")
    if fixed_pattern is not None:
        fp = fixed_pattern
        out[MapName.K] = MapLayer(MapName.K, MAP_TITLES[MapName.K], "K\u0302", "", fp.K,
                                  "RdBu_r", kind="diverging", centre=1.0,
                                  note="eq. 49: mean of the slopes kept inside "
                                       "centre \u00b1 p\u00b7\u03c3\u0302")
        if fp.K_var is not None:
            out["K_err"] = MapLayer("K_err", MAP_TITLES["K_err"], "\u03c3(K\u0302)", "",
                                    np.sqrt(fp.K_var), "viridis",
                                    note="std error of the mean of the kept slopes "
                                         "(FixedPattern.K_var)")
        out[MapName.N1_USED] = MapLayer(MapName.N1_USED, MAP_TITLES[MapName.N1_USED], "n'_1", "",
                                        fp.n1_used.astype(np.float32), "viridis", kind="count",
                                        note=f"of n1 = {fp.n1} configurations (eq. 49)")
        out["n_rejected"] = MapLayer("n_rejected", MAP_TITLES["n_rejected"], "rejected", "",
                                     (fp.n1 - fp.n1_used).astype(np.float32), "inferno",
                                     kind="count",
                                     note=f"slopes outside centre "
                                          f"\u00b1 {fp.p:g}\u00b7\u03c3\u0302")
    if dark is not None:
        flags = np.where(dark.dead_mask, 2, np.where(dark.hot_mask, 1, 0)).astype(np.float32)
        out["flags"] = MapLayer("flags", MAP_TITLES["flags"], "flag", "", flags,
                                list(FLAG_COLORS), kind="flags",
                                note="0 normal, 1 hot, 2 dead (rules of dark_reference)")
    return out


def default_clim(layer: MapLayer) -> tuple[float, float]:
    """The colour range a map opens with.

    Values: the 0.5–99.5 % percentiles (:func:`ccdcore_app.plots.base.auto_clim`); diverging maps:
    the same made symmetric about ``layer.centre`` (so 1 is white for K̂); counts: their integer
    range (± 0.5); flags: the three categories.
    """
    if layer.kind == "flags":
        return (-0.5, 2.5)
    data = layer.data
    if layer.kind == "count":
        finite = data[np.isfinite(data)]
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        return (lo - 0.5, hi + 0.5)
    lo, hi = plots.auto_clim(data)
    if layer.kind == "diverging":
        half = max(abs(lo - layer.centre), abs(hi - layer.centre)) or 0.5
        return (layer.centre - half, layer.centre + half)
    return (lo, hi)


def overview_how(layer: MapLayer, how: str) -> str:
    """The reduction a zoomed-out view of ``layer`` uses: ``how`` for values, ``"max"`` for
    counts and flags (a single rejected slope or hot pixel must stay visible)."""
    return "max" if layer.kind in ("count", "flags") else how


def overview_centre(layer: MapLayer) -> float:
    """The value "extreme" measures deviations from: the centre of a diverging map (1 for K̂),
    the median of the finite values otherwise."""
    if layer.kind == "diverging":
        return float(layer.centre)
    finite = plots.subsample(layer.data)
    finite = finite[np.isfinite(finite)]
    return float(np.median(finite)) if finite.size else 0.0


#: the tallest a map is drawn (pixels of the frame)
MAP_MAX_HEIGHT = 500


def layer_view(layer: MapLayer, *, frame_width: int = 380, link: Any = None) -> ImageView:
    """A view for ``layer``'s maps (built once per map key, then fed with :func:`show_layer`):
    its colour map and colour-bar label, the hover symbol; hot/dead flags as three labelled
    categories. ``link``: another view to share the zoom with."""
    flags = layer.kind == "flags"
    # at most 500 px high: a square sensor's map (a 1024 x 1024 CCD) then keeps its upper half
    # in the first view at 1400 x 900 below the page's controls
    view = ImageView(frame_width=frame_width, max_frame_height=MAP_MAX_HEIGHT, cmap=layer.cmap,
                     label=layer.label, symbol=layer.symbol, title=layer.title,
                     link=link, levels=len(FLAG_COLORS) if flags else None)
    if flags:
        from bokeh.models import FixedTicker

        view.color_bar.update(ticker=FixedTicker(ticks=list(FLAG_LABELS)),
                              major_label_overrides={k: v for k, v in FLAG_LABELS.items()})
    return view


def show_layer(view: ImageView, layer: MapLayer, clim: tuple[float, float], how: str) -> None:
    """Draw ``layer`` in ``view`` in the colour range ``clim``, keeping the zoom (a zoomed-out
    screen pixel shows :func:`overview_how` of its block; "extreme" measures from
    :func:`overview_centre`)."""
    how = overview_how(layer, how)
    view.show(layer.data, clim=clim, title=layer.title, how=how,
              centre=overview_centre(layer) if how == "extreme" else None, reset=False)


def histogram_input(layer: MapLayer) -> tuple[NDArray, int]:
    """What a map's histogram counts: ``(values, bins)``; integer maps get one bin per value
    (:func:`ccdcore_app.plots.base.histogram_edges`), others 100 bins over their range."""
    if layer.integer:
        return layer.data.astype(np.int32), 256
    return layer.data, 100


def profile_columns(layer: MapLayer | None, row: int, col: int) -> dict[str, dict[str, Any]]:
    """The row ``row`` and the column ``col`` of a map (clipped to the map) as source columns:
    ``{"row": {"x", "value"}, "col": {"x", "value"}}`` with ``x`` the column (row) index and the
    clipped ``row``/``col`` used; empty without a map."""
    if layer is None:
        empty = {"x": np.empty(0), "value": np.empty(0)}
        return {"row": dict(empty), "col": dict(empty), "at": {"row": 0, "col": 0}}
    h, w = layer.data.shape
    row, col = int(np.clip(row, 0, h - 1)), int(np.clip(col, 0, w - 1))
    return {"row": {"x": np.arange(w), "value": np.asarray(layer.data[row], dtype=np.float64)},
            "col": {"x": np.arange(h), "value": np.asarray(layer.data[:, col], dtype=np.float64)},
            "at": {"row": row, "col": col}}


class ProfileFigures:
    """The row and column profiles of the selected map, built once as Bokeh figures (steps
    centred on the pixels); :meth:`update` replaces their data, titles and axis labels."""

    def __init__(self, height: int = 220):
        from bokeh.models import ColumnDataSource, HoverTool
        from bokeh.plotting import figure

        self.sources: dict[str, Any] = {}
        self.figures: dict[str, Any] = {}
        for key, xlabel, color in (("row", "x (column)", "#1f3b57"),
                                   ("col", "y (row)", "#8c2d04")):
            src = ColumnDataSource({"x": np.empty(0), "value": np.empty(0)})
            fig = figure(height=height, sizing_mode="stretch_width", x_axis_label=xlabel,
                         tools="pan,wheel_zoom,box_zoom,reset,save", output_backend="canvas",
                         title="Row profile" if key == "row" else "Column profile")
            fig.toolbar.logo = None
            fig.step("x", "value", source=src, mode="center", line_color=color, line_width=1)
            fig.add_tools(HoverTool(tooltips=[(xlabel, "@x"), ("value", "@value{0.00000}")],
                                    mode="vline"))
            self.sources[key], self.figures[key] = src, fig

    @property
    def row(self) -> Any:
        return self.figures["row"]

    @property
    def col(self) -> Any:
        return self.figures["col"]

    def update(self, layer: MapLayer | None, row: int, col: int) -> None:
        cols = profile_columns(layer, row, col)
        at = cols["at"]
        for key in ("row", "col"):
            self.sources[key].data = cols[key]
            self.figures[key].yaxis.axis_label = layer.label if layer is not None else ""
        self.row.title.text = f"Row profile, y = {at['row']}" if layer else "Row profile"
        self.col.title.text = f"Column profile, x = {at['col']}" if layer else "Column profile"


def _format(value: float, layer: MapLayer) -> str:
    if not math.isfinite(value):
        return "NaN"
    if layer.kind == "flags":
        return FLAG_LABELS.get(int(value), f"{value:g}")
    if layer.integer:
        return f"{int(value)}"
    if layer.kind == "diverging":
        return f"{value:.5f}"
    return f"{value:.4g}"


def pixel_values(layers: Mapping[str, MapLayer], x: float | None, y: float | None
                 ) -> tuple[int, int, dict[str, str]] | None:
    """``(col, row, {key: formatted value})`` of every map at the cursor ``(x, y)``; ``None``
    outside the maps (or without a position)."""
    if x is None or y is None or not layers:
        return None
    col, row = int(round(x)), int(round(y))
    shape = next(iter(layers.values())).data.shape
    if not (0 <= row < shape[0] and 0 <= col < shape[1]):
        return None
    return col, row, {k: _format(float(l.data[row, col]), l) for k, l in layers.items()}


def scaled_uint16(data: NDArray, clim: tuple[float, float]) -> NDArray[np.uint16]:
    """``data`` scaled linearly so ``clim[0]`` -> 0 and ``clim[1]`` -> 65535, clipped, rounded;
    non-finite values become 0. (What the PNG export writes: a picture of the map in the chosen
    colour range, not its values.)"""
    lo, hi = (float(c) for c in clim)
    if not hi > lo:
        raise ValueError(f"clim: need lo < hi, got {clim}")
    a = np.asarray(data, dtype=np.float64)
    scaled = np.clip((a - lo) / (hi - lo), 0.0, 1.0) * 65535.0
    scaled = np.where(np.isfinite(scaled), scaled, 0.0)
    return np.rint(scaled).astype(np.uint16)


# -------------------------------------------------------------------------- scene (Figs. 3, 4)
_PALETTE = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2",
            "#17becf")


def scene_fit_plot(variations: Mapping[str, Any]) -> hv.Overlay:
    """Fig. 3: y = σ̂²_D − σ̂²_KN (− σ̂²_cal) against x = μ̂²_D, per patch, with error bars
    √var_y and the fitted line V_S·x of eq. 57 (``ccdcore.scene.SceneVariation``).

    Measurements left out of the fit (clipped pixels) are drawn as open markers.
    """
    layers = []
    for i, (name, var) in enumerate(variations.items()):
        color = _PALETTE[i % len(_PALETTE)]
        ms = var.measurements
        used = var.used or tuple(True for _ in ms)
        x = np.array([m.mu_D ** 2 for m in ms])
        y = np.array([m.y for m in ms])
        err = np.sqrt(np.maximum([m.var_y for m in ms], 0.0))
        levels = [m.level if m.level is not None else -1 for m in ms]
        data = {"x": x, "y": y, "err": err, "level": levels, "used": list(used)}
        kd, vd = [hv.Dimension("x", label="\u03bc\u0302\u00b2_D (DN\u00b2)")], \
            [hv.Dimension("y", label="\u03c3\u0302\u00b2_D \u2212 "
                                     "\u03c3\u0302\u00b2_KN (DN\u00b2)"),
             "err", "level", "used"]
        pts = hv.Scatter(data, kdims=kd, vdims=vd, label=f"{name}")
        keep = pts.select(used=True) if not all(used) else pts
        layers.append(hv.ErrorBars(data, kdims=kd, vdims=vd[:2]).opts(color=color,
                                                                      line_width=1))
        layers.append(keep.opts(color=color, size=7, tools=["hover"]))
        if not all(used):
            layers.append(pts.select(used=False).opts(color=color, size=7, fill_alpha=0,
                                                      marker="circle"))
        if math.isfinite(var.V_S) and x.size:
            xs = np.linspace(0.0, float(x.max()) * 1.05, 50)
            layers.append(hv.Curve((xs, var.V_S * xs), kdims=kd, vdims=vd[:1],
                                   label=f"{name}: V_S = {var.V_S:.3e}").opts(
                color=color, line_width=1.5, line_dash="dashed"))
    if not layers:
        return hv.Overlay([hv.Curve([])])
    return hv.Overlay(layers).opts(
        title="Scene variation: \u03c3\u0302\u00b2_D \u2212 \u03c3\u0302\u00b2_KN "
              "= V_S\u00b7\u03bc\u0302\u00b2_D "
              "(eq. 57, Fig. 3)",
        legend_position="top_left", responsive=True, height=360, show_grid=True)


def budget_plot(budget: Any) -> hv.Overlay:
    """Fig. 4: the fractions of the variance of an uncorrected region against its mean,
    stacked (``ccdcore.scene.VarianceBudget``)."""
    from ccdcore.scene import BUDGET_COMPONENTS

    mu = np.asarray(budget.mu, dtype=np.float64)
    areas = []
    kd = hv.Dimension("mu", label="region mean \u03bc (DN)")
    for name in BUDGET_COMPONENTS:
        frac = np.asarray(budget.fractions[name], dtype=np.float64)
        areas.append(hv.Area((mu, frac), kdims=[kd],
                             vdims=[hv.Dimension("fraction", label="fraction of the variance")],
                             label=_BUDGET_LABELS.get(name, name)).opts(
            color=BUDGET_COLORS.get(name, "#999999"), line_width=0, alpha=0.85))
    stacked = hv.Area.stack(hv.Overlay(areas))
    return stacked.opts(
        hv.opts.Area(tools=["hover"]),
        hv.opts.Overlay(title="Variance budget of an uncorrected region (Fig. 4)",
                        legend_position="right", responsive=True, height=360,
                        ylim=(0, 1), show_grid=True))
