"""The report's Bokeh figures: maps with a colour bar and a hover readout, the photon-transfer
plots (:class:`ccdcore_report.ptc.PtcFigures`, as the app draws them), the response curves, the
change-detection maps and the EMVA 1288 plots.

Every builder takes the numbers a product (or a change result) holds and returns Bokeh models;
nothing is estimated here. Bokeh is imported inside the builders, so importing this module
costs NumPy only.

Public objects
--------------
MAX_MAP_SIDE
    The longest side, in pixels, a map is drawn with (larger maps are reduced by block means).
MapSpec, MAP_SPECS, MAP_ORDER
    How each map of a product is drawn (title, unit, colour scale, kind) and in which order.
FLAG_LABELS, FLAT_FLAG_LABELS, CHANNEL_COLOURS, SHADOW_COLOURS, label_colour(label),
label_name(label)
    Names and colours of flags, channels and change labels.
CONTENT_WIDTH, MAP_MARGIN, MAP_GAP
    The width of the report's text column and what a map adds to its frame.
reduce_blocks(plane, factor, how), map_factor(shape), resolution_text(shape, factor, how)
    A map reduced for drawing, by how much, and the caption that says so.
image_figure(title, w, h, side), map_figure(plane, spec, title=, side=, labels=)
    An empty figure for an image with square pixels; a map drawn in it with a colour bar and a
    hover readout.
photon_transfer_of(noise), ptc_figures(result)
    The photon-transfer result of a product's ``noise`` summary, and its figures.
response_figures(channels, gs, errs)
    g(z) per channel with its ±2σ band, and the band's half-width below.
change_label_figure(labels, counts, factor), change_d2_figure(d2, factor)
    The label map in the app's colours and the d² map of a change result.
emva_snr_figure(snr), emva_ptc_figure(pts), emva_linearity_figure(pts)
    The EMVA 1288 plots.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from ccdcore.common import format_size
from ccdcore.map_names import MapName

from .scales import auto_clim

if TYPE_CHECKING:
    from ccdcore.noise import PhotonTransfer
    from ccdcore.ptc_fit import PhotonTransferSummary

__all__ = ["MAX_MAP_SIDE", "MapSpec", "MAP_SPECS", "MAP_ORDER", "FLAG_LABELS",
           "FLAT_FLAG_LABELS", "CHANNEL_COLOURS", "SHADOW_COLOURS", "CHANGE_COLOUR",
           "UNDETERMINED_COLOUR", "BACKGROUND_COLOUR", "label_colour", "label_name",
           "CONTENT_WIDTH", "MAP_MARGIN", "MAP_GAP", "reduce_blocks", "map_factor",
           "resolution_text", "image_figure", "map_figure", "photon_transfer_of", "ptc_figures",
           "response_figures", "change_label_figure", "change_d2_figure", "emva_snr_figure",
           "emva_ptc_figure", "emva_linearity_figure"]

#: the longest side a map is drawn with: larger maps are reduced by block means (flags and
#: counts by block maxima), which keeps a 2048 x 2048 map to about 1 MB of the file
MAX_MAP_SIDE = 512

# ---------------------------------------------------------------------------------------------
# palettes and names (maps, channels, change labels)
# ---------------------------------------------------------------------------------------------
#: colours of hot/dead flags (0 normal, 1 hot, 2 dead) and of flat-field flags (0, 1)
FLAG_COLOURS = ("#e9ecef", "#d62728", "#1f4e9c")
FLAG_LABELS = {0: "normal", 1: "hot", 2: "dead"}
FLAT_FLAG_LABELS = {0: "normal", 1: "flagged"}
#: channel -> line colour (Okabe-Ito, colour-blind safe)
CHANNEL_COLOURS = {"L": "#333333", "R": "#D55E00", "G": "#009E73", "B": "#0072B2",
                   "G1": "#009E73", "G2": "#56B4E9"}
#: shadow clusters 1..n take these colours in turn (Okabe-Ito), as on the app's Change page
SHADOW_COLOURS = ("#0072B2", "#56B4E9", "#CC79A7", "#009E73", "#E69F00")


#: the change labels' colours (Okabe-Ito, colour-blind safe): changed, undetermined, the
#: unchanged background when the labels are drawn alone; shadows 1..n take SHADOW_COLOURS in turn
CHANGE_COLOUR = "#D55E00"
UNDETERMINED_COLOUR = "#F0E442"
BACKGROUND_COLOUR = "#d9d9d9"
#: a shade of the background's light (label 253): a darker grey than the background's
SHADE_COLOUR = "#8c8c8c"


def label_colour(label: int) -> str:
    """The colour of a change label (Tsin et al. sec. 5), in the report and on the app's
    Change detection page."""
    from ccdcore.change.detector import LABEL_CHANGE, LABEL_SHADE, LABEL_UNDETERMINED

    label = int(label)
    fixed = {0: BACKGROUND_COLOUR, LABEL_CHANGE: CHANGE_COLOUR,
             LABEL_UNDETERMINED: UNDETERMINED_COLOUR, LABEL_SHADE: SHADE_COLOUR}
    return fixed.get(label) or SHADOW_COLOURS[(label - 1) % len(SHADOW_COLOURS)]


def label_name(label: int) -> str:
    """What a change label means, as the report's legend and cluster table say it."""
    from ccdcore.change.detector import LABEL_CHANGE, LABEL_SHADE, LABEL_UNDETERMINED

    return {0: "unchanged (background)", LABEL_CHANGE: "change",
            LABEL_UNDETERMINED: "undetermined (no radiance)",
            LABEL_SHADE: "shade of the background's light"}.get(label, f"shadow {label}")


@dataclass(frozen=True)
class MapSpec:
    """How one map of a product is drawn: title, unit, colour scale and kind."""

    title: str
    unit: str = ""
    kind: str = "value"          # value | diverging | count | flags
    palette: str = "Viridis256"
    note: str = ""


#: the product's maps (:class:`ccdcore.product.make.MapName`, hot and dead drawn as one
#: ``hot_dead``,
#: K_var as its square root ``K_err``)
MAP_SPECS: dict[str, MapSpec] = {
    MapName.DARK: MapSpec("Dark reference D\u0302_D", "DN", palette="Greys256",
                          note="mean of the dark frames (Healey & Kondepudy sec. V-A)"),
    MapName.DARK_VAR: MapSpec("Dark temporal variance \u03c3\u00b2_N", "DN\u00b2",
                              note="per-pixel temporal variance of the dark frames (eq. 43)"),
    "hot_dead": MapSpec("Hot and dead pixels", kind="flags",
                        note="the rules are in the dark reference's table"),
    MapName.K: MapSpec("Fixed pattern K\u0302", kind="diverging",
                       note="eq. 49; the colour scale is symmetric about 1"),
    "K_err": MapSpec("Error of K\u0302, \u221avar[K\u0302]",
                     note="standard error of the mean of the kept slopes"),
    MapName.N1_USED: MapSpec("Slopes kept n'_1", kind="count",
                             note="configurations whose slope eq. 48 kept, per pixel"),
    MapName.FLAT_G: MapSpec("Flat-field gain G", note="eq. 3 of de Lasarte et al. 2007"),
    MapName.FLAT_O: MapSpec("Flat-field offset O", "DN", note="eq. 4 of de Lasarte et al. 2007"),
    MapName.FLAT_FLAGS: MapSpec("Flagged pixels of G", kind="flags",
                                note="DL_B \u2212 DL_0 not positive or noise dominated; G "
                                     "from the neighbours there"),
    MapName.FLAT_DARK: MapSpec("Dark image DL_0", "DN", palette="Greys256"),
    MapName.FLAT_BASE: MapSpec("Base image DL_B", "DN", palette="Greys256"),
}
#: the order maps are drawn in (others follow, alphabetically)
MAP_ORDER = (MapName.DARK, MapName.DARK_VAR, "hot_dead", MapName.K, "K_err", MapName.N1_USED,
             MapName.FLAT_G, MapName.FLAT_O, MapName.FLAT_FLAGS, MapName.FLAT_DARK,
             MapName.FLAT_BASE)

#: the width of the report's text column and what a map adds to its frame (axis, colour bar)
CONTENT_WIDTH = 1050
MAP_MARGIN = 110
MAP_GAP = 24

_TOOLS = "pan,wheel_zoom,box_zoom,reset"


# ---------------------------------------------------------------------------------------------
# maps
# ---------------------------------------------------------------------------------------------
def reduce_blocks(plane: NDArray, factor: int, how: str) -> NDArray[np.float32]:
    """``plane`` reduced by ``factor`` in each direction: the mean (``how="mean"``) or the
    maximum (``"max"``) of each block of finite values (edge blocks may be partial)."""
    a = np.asarray(plane, np.float32)
    if factor <= 1:
        return a
    h, w = a.shape
    H, W = -(-h // factor) * factor, -(-w // factor) * factor
    padded = np.full((H, W), np.nan, np.float32)
    padded[:h, :w] = a
    blocks = padded.reshape(H // factor, factor, W // factor, factor)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # blocks without a finite value
        out = (np.nanmax(blocks, axis=(1, 3)) if how == "max"
               else np.nanmean(blocks, axis=(1, 3), dtype=np.float64))
    return out.astype(np.float32)


def map_factor(shape: tuple[int, ...]) -> int:
    """The reduction factor that brings the longer side of ``shape`` to :data:`MAX_MAP_SIDE`
    at most (1: every pixel)."""
    h, w = shape[:2]
    return max(1, math.ceil(max(h, w) / MAX_MAP_SIDE))


def resolution_text(shape: tuple[int, int], factor: int, how: str) -> str:
    size = format_size(shape)
    if factor <= 1:
        return f"{size} px, every pixel drawn."
    return (f"{size} px drawn at 1:{factor} (each screen pixel is the {how} of a "
            f"{factor}\u00d7{factor} block, to keep this file small); the product holds every "
            "pixel.")


def _frame_size(w: int, h: int, side: int) -> tuple[int, int]:
    """Frame width and height with square pixels, the longer side ``side`` pixels."""
    if w >= h:
        return side, max(40, round(side * h / w))
    return max(40, round(side * w / h)), side


def image_figure(title: str, w: int, h: int, side: int) -> Any:
    """An empty figure for a w × h image with square pixels (row 0 at the top, the longer side
    ``side`` screen pixels), its toolbar hidden until hovered."""
    from bokeh.models import Range1d
    from bokeh.plotting import figure

    fw, fh = _frame_size(w, h, side)
    fig = figure(title=title, frame_width=fw, frame_height=fh,
                 x_range=Range1d(-0.5, w - 0.5), y_range=Range1d(h - 0.5, -0.5),
                 tools=_TOOLS, toolbar_location="above",
                 x_axis_label="x (px)", y_axis_label="y (px)")
    fig.toolbar.logo = None
    fig.toolbar.autohide = True
    fig.grid.visible = False
    return fig


def _colour_scale(shown: NDArray, spec: MapSpec, names: Mapping[int, str]
                  ) -> tuple[Any, float, float]:
    """Palette and range of a map by its kind: one colour per flag; counts whole; diverging
    symmetric about 1; values over their 0.5–99.5 % percentiles."""
    from bokeh.palettes import RdBu11, interp_palette
    import bokeh.palettes as palettes

    if spec.kind == "flags":
        return list(FLAG_COLOURS[:len(names)]), -0.5, len(names) - 0.5
    if spec.kind == "count":
        finite = shown[np.isfinite(shown)]
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        return getattr(palettes, spec.palette), lo - 0.5, hi + 0.5
    if spec.kind == "diverging":
        lo, hi = auto_clim(shown)
        half = max(abs(lo - 1.0), abs(hi - 1.0)) or 0.5
        return interp_palette(RdBu11, 256), 1.0 - half, 1.0 + half
    low, high = auto_clim(shown)
    return getattr(palettes, spec.palette), low, high


def map_figure(plane: NDArray, spec: MapSpec, *, title: str, side: int = 420,
               labels: Mapping[int, str] | None = None) -> tuple[Any, int]:
    """A map as a Bokeh image with a colour bar and a hover readout; returns the figure and
    the reduction factor used (1: every pixel).

    The map is reduced to :data:`MAX_MAP_SIDE` (flags and counts by block maxima, values by
    block means), coloured by its kind (:func:`_colour_scale`; flags named by ``labels``) and
    drawn with square pixels, the longer side ``side`` screen pixels."""
    from bokeh.models import ColorBar, FixedTicker, HoverTool, LinearColorMapper

    h, w = plane.shape
    factor = map_factor(plane.shape)
    how = "max" if spec.kind in ("flags", "count") else "mean"
    shown = reduce_blocks(plane, factor, how)
    names = dict(labels or FLAG_LABELS)
    palette, low, high = _colour_scale(shown, spec, names)
    fig = image_figure(title, w, h, side)
    mapper = LinearColorMapper(palette=palette, low=low, high=high,
                               nan_color="rgba(0, 0, 0, 0)")
    image = fig.image(image=[shown], x=-0.5, y=-0.5, dw=w, dh=h, color_mapper=mapper)
    bar = ColorBar(color_mapper=mapper, width=12, title=spec.unit or None)
    if spec.kind == "flags":
        bar.ticker = FixedTicker(ticks=list(names))
        bar.major_label_overrides = {int(k): v for k, v in names.items()}
    fig.add_layout(bar, "right")
    value = "block " + ("maximum" if how == "max" else "mean") if factor > 1 else "value"
    fig.add_tools(HoverTool(renderers=[image], tooltips=[
        ("x, y", "$x{0}, $y{0}"), (value, "@image{%.5g}")], formatters={"@image": "printf"}))
    return fig, factor


# ---------------------------------------------------------------------------------------------
# photon transfer
# ---------------------------------------------------------------------------------------------
def photon_transfer_of(noise: PhotonTransferSummary) -> PhotonTransfer:
    """The photon-transfer result of a product's ``noise`` summary (for the app's plots):
    :meth:`ccdcore.noise.PhotonTransfer.from_summary`."""
    from ccdcore.noise import PhotonTransfer

    return PhotonTransfer.from_summary(noise)


def ptc_figures(result: Any) -> Any:
    """The app's photon-transfer figures (:class:`ccdcore_report.ptc.PtcFigures`) of a
    :class:`~ccdcore.noise.PhotonTransfer` (:func:`photon_transfer_of` a product's ``noise``
    summary), their toolbars hidden until hovered."""
    from .ptc import PtcFigures

    figs = PtcFigures(height=340, loglog_height=420)
    figs.update(result.points, result)
    for fig in (figs.transfer, figs.residual, figs.loglog):
        fig.toolbar.autohide = True
    return figs


# ---------------------------------------------------------------------------------------------
# response curves
# ---------------------------------------------------------------------------------------------
def line_figure(title: str, xlabel: str, ylabel: str, height: int, **kw: Any) -> Any:
    """A stretched figure with the report's tools, its toolbar hidden until hovered."""
    from bokeh.plotting import figure

    fig = figure(height=height, sizing_mode="stretch_width", x_axis_label=xlabel,
                 y_axis_label=ylabel, tools=_TOOLS, toolbar_location="above", title=title, **kw)
    fig.toolbar.logo = None
    fig.toolbar.autohide = True
    return fig


def response_figures(channels: Sequence[str], gs: Sequence[NDArray],
                     errs: Sequence[NDArray]) -> Any:
    """g(z) of every channel with its ±2σ band (hover: z, g, ±1σ) above the 1σ error itself,
    zoom linked, as one column."""
    from bokeh.layouts import column
    from bokeh.models import ColumnDataSource, HoverTool

    fig = line_figure("Inverse response g(z) per channel, \u00b12\u03c3 band", "code z",
                       "g(z) (linear in exposure)", 400)
    lines, sources = [], []
    for i, (ch, g) in enumerate(zip(channels, gs)):
        e = errs[i] if i < len(errs) and errs[i].size == g.size else np.zeros_like(g)
        e = np.nan_to_num(e)
        colour = CHANNEL_COLOURS.get(ch, SHADOW_COLOURS[i % len(SHADOW_COLOURS)])
        src = ColumnDataSource({"z": np.arange(g.size), "g": g, "err": e,
                                "lo": g - 2 * e, "hi": g + 2 * e}, name=f"ccd-response-{ch}")
        sources.append(src)
        fig.varea("z", "lo", "hi", source=src, fill_color=colour, fill_alpha=0.25,
                  legend_label=f"{ch} \u00b12\u03c3")
        lines.append(fig.line("z", "g", source=src, line_color=colour, line_width=2,
                              legend_label=f"g, {ch}"))
    fig.legend.location = "top_left"
    fig.add_tools(HoverTool(renderers=lines, tooltips=[("z", "@z"), ("g", "@g{0.00000}"),
                                                       ("\u00b11\u03c3", "@err{0.00000}")]))
    err_fig = line_figure("The band's half-width: the 1\u03c3 error of g(z)", "code z",
                           "\u03c3 of g(z)", 200, x_range=fig.x_range)
    for src, line in zip(sources, lines):
        err_fig.line("z", "err", source=src, line_color=line.glyph.line_color, line_width=2)
    return column(fig, err_fig, sizing_mode="stretch_width")


# ---------------------------------------------------------------------------------------------
# change detection
# ---------------------------------------------------------------------------------------------
def change_label_figure(labels: NDArray, counts: Mapping[int, int], factor: int) -> Any:
    """The label map (reduced by block maxima) in the app's colours, with the label on hover."""
    from bokeh.models import HoverTool, LinearColorMapper

    h, w = labels.shape
    palette = ["#ffffff"] * 256
    for lab in counts:
        palette[lab] = label_colour(lab)
    shown = reduce_blocks(labels.astype(np.float32), factor, "max")
    fig = image_figure("Labels", w, h, 380)
    mapper = LinearColorMapper(palette=palette, low=-0.5, high=255.5)
    img = fig.image(image=[shown], x=-0.5, y=-0.5, dw=w, dh=h, color_mapper=mapper)
    fig.add_tools(HoverTool(renderers=[img], tooltips=[("x, y", "$x{0}, $y{0}"),
                                                       ("label", "@image{0}")]))
    return fig


def change_d2_figure(d2: NDArray, factor: int) -> Any:
    """d² under the best cluster (reduced by block means) on a logarithmic colour scale from
    the 1st to the 99.5th percentile of its positive values."""
    from bokeh.models import ColorBar, HoverTool, LogColorMapper
    from bokeh.palettes import Viridis256

    h, w = d2.shape
    shown = reduce_blocks(d2, factor, "mean")
    pos = shown[np.isfinite(shown) & (shown > 0)]
    low, high = (float(np.percentile(pos, 1)), float(np.percentile(pos, 99.5))) \
        if pos.size else (1e-3, 1.0)
    if not high > low:
        high = low * 10
    fig = image_figure("d\u00b2 under the best cluster", w, h, 380)
    mapper = LogColorMapper(palette=Viridis256, low=low, high=high,
                            nan_color="rgba(0, 0, 0, 0)")
    img = fig.image(image=[shown], x=-0.5, y=-0.5, dw=w, dh=h, color_mapper=mapper)
    fig.add_layout(ColorBar(color_mapper=mapper, width=12, title="d\u00b2"), "right")
    fig.add_tools(HoverTool(renderers=[img], tooltips=[("x, y", "$x{0}, $y{0}"),
                                                       ("d\u00b2", "@image{%.4g}")],
                            formatters={"@image": "printf"}))
    return fig


# ---------------------------------------------------------------------------------------------
# EMVA 1288
# ---------------------------------------------------------------------------------------------
def _scatter_figure(title: str, xlabel: str, ylabel: str, *, log: bool = False) -> Any:
    from bokeh.plotting import figure

    kw = {"x_axis_type": "log", "y_axis_type": "log"} if log else {}
    fig = figure(title=title, height=360, sizing_mode="stretch_width", x_axis_label=xlabel,
                 y_axis_label=ylabel, tools=_TOOLS, toolbar_location="above", **kw)
    fig.toolbar.logo = None
    fig.toolbar.autohide = True
    return fig


def _fit_points(fig: Any, x: NDArray, y: NDArray, used: NDArray | None, label: str) -> None:
    """Points of an EMVA plot: filled where ``used`` (in a fit), hollow grey elsewhere."""
    inside = np.ones(x.size, bool) if used is None else used > 0
    fig.scatter(x[inside], y[inside], size=7, color="#1f5f99", legend_label=label)
    if (~inside).any():
        fig.scatter(x[~inside], y[~inside], size=8, fill_alpha=0.0, line_color="#8c959f",
                    line_width=2, legend_label="outside the fit")
    fig.legend.location = "top_left"


def emva_snr_figure(snr: Mapping[str, NDArray]) -> Any:
    """SNR against μ_p (log-log): the model lines (``model``, ``total``) and the measured
    points (``snr``), each where present and positive."""
    fig = _scatter_figure("Signal-to-noise ratio against irradiation",
                          "\u03bc_p (photons per pixel)", "SNR", log=True)
    x = snr["u_p"]
    for key, label, style in (("model", "model (eq. 11)",
                               dict(line_color="#D55E00", line_width=2)),
                              ("total", "model with DSNU and PRNU",
                               dict(line_color="#6f42c1", line_width=2, line_dash="dashed"))):
        if key in snr:
            ok = (x > 0) & (snr[key] > 0)
            fig.line(x[ok], snr[key][ok], legend_label=label, **style)
    if "snr" in snr:
        ok = (x > 0) & (snr["snr"] > 0)
        fig.scatter(x[ok], snr["snr"][ok], size=7, color="#1f5f99", legend_label="measured")
    fig.legend.location = "top_left"
    return fig


def emva_ptc_figure(pts: Mapping[str, NDArray]) -> Any:
    """σ²_y − σ²_y.dark against μ_y − μ_y.dark with the errors of σ²_y; points outside the
    fit of K hollow."""
    fig = _scatter_figure("Photon transfer", "\u03bc_y \u2212 \u03bc_y.dark (DN)",
                          "\u03c3\u00b2_y \u2212 \u03c3\u00b2_y.dark (DN\u00b2)")
    x, y = pts["u_y"] - pts["u_y_dark"], pts["s2_y"] - pts["s2_y_dark"]
    if "s2_y_err" in pts:
        e = np.nan_to_num(pts["s2_y_err"])
        fig.segment(x, y - e, x, y + e, line_color="#1f5f99")
    _fit_points(fig, x, y, pts.get("in_sensitivity_fit"), "in the K fit")
    return fig


def emva_linearity_figure(pts: Mapping[str, NDArray]) -> Any:
    """μ_y − μ_y.dark against μ_p; points outside the linearity fit hollow."""
    fig = _scatter_figure("Linearity", "\u03bc_p (photons per pixel)",
                          "\u03bc_y \u2212 \u03bc_y.dark (DN)")
    _fit_points(fig, pts["u_p"], pts["u_y"] - pts["u_y_dark"], pts.get("in_linearity_fit"),
                "in the linearity fit")
    return fig
