"""The Change detection page's plots: plain Bokeh figures built once and fed in place.

RgbView
    An :class:`ccdcore_app.image_view.ImageView` showing a colour picture (H, W, 3 values in [0,
    1]) as RGBA, with the same linked zoom, screen-resolution redraw and pointer callbacks.
D2Histogram
    The background's d² against the χ² density with ``dof`` degrees of freedom (Tsin, Ramesh &
    Kanade 2001, Fig. 6), with the threshold and the χ² threshold as vertical lines.
log_colours(view, low, high)
    Give an ImageView a logarithmic colour scale (d² spans decades).
tone_map_rgb(radiance, white, stops)
    An (H, W, C) radiance for display only (gamma 2.2, one white point for every channel).
white_point(*radiances)
    The common white point of several radiance maps (their 99.5th percentile).
label_rgb(labels, base, overlay)
    The label map as colours, over a grey picture or alone.
label_name(label), label_colour(label)
    What a label means and how it is drawn.
histogram_columns(background, bins, x_max), chi2_columns(dof, scale, x_max)
    The columns of :class:`D2Histogram` (pure functions, for the tests).
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from ccdcore.change.detector import LABEL_CHANGE, LABEL_SHADE, LABEL_UNDETERMINED
from ccdcore_report.figures import (BACKGROUND_COLOUR, CHANGE_COLOUR, SHADE_COLOUR,
                                     UNDETERMINED_COLOUR, label_colour, label_name)

from . import base as plots
from ..batch import batched
from ..image_view import ImageView

__all__ = ["RgbView", "D2Histogram", "log_colours", "tone_map_rgb", "white_point", "label_rgb",
           "label_name", "label_colour", "histogram_columns", "chi2_columns", "LABEL_COLOURS",
           "BACKGROUND_COLOUR"]

#: label -> colour: the report's (one home, :mod:`ccdcore_report.figures`)
LABEL_COLOURS = {LABEL_CHANGE: CHANGE_COLOUR, LABEL_UNDETERMINED: UNDETERMINED_COLOUR,
                 LABEL_SHADE: SHADE_COLOUR}
#: colour of the above-threshold bars and the threshold line
ABOVE_COLOUR = CHANGE_COLOUR
BELOW_COLOUR = "#4a6fa5"


def _rgb(colour: str) -> NDArray[np.float64]:
    c = colour.lstrip("#")
    return np.array([int(c[i:i + 2], 16) / 255.0 for i in (0, 2, 4)])


# ----------------------------------------------------------------------------- display ---------
def white_point(*radiances: NDArray) -> float:
    """The 99.5th percentile of the finite positive values of every map (one white point, so
    the pictures compare)."""
    vals = [np.asarray(r, np.float64).ravel() for r in radiances]
    v = np.concatenate(vals) if vals else np.zeros(0)
    v = v[np.isfinite(v) & (v > 0)]
    if v.size == 0:
        return 1.0
    if v.size > 2_000_000:
        v = v[:: v.size // 1_000_000]
    return float(np.percentile(v, 99.5))


def tone_map_rgb(radiance: NDArray, white: float, stops: float = 0.0) -> NDArray[np.float64]:
    """``radiance`` (H, W, C; C = 1 is drawn grey) in [0, 1] for display: ``white`` times
    2^-stops maps to 1, gamma 2.2. Non-finite values become NaN (drawn transparent)."""
    E = np.asarray(radiance, np.float64)
    if E.ndim == 2:
        E = E[..., None]
    if E.shape[-1] == 1:
        E = np.repeat(E, 3, axis=-1)
    w = max(float(white), 1e-300) / 2.0 ** float(stops)
    with np.errstate(invalid="ignore", over="ignore"):
        out = np.clip(np.maximum(E, 0.0) / w, 0.0, 1.0) ** (1 / 2.2)
    out[~np.isfinite(E)] = np.nan
    return out


def label_rgb(labels: NDArray, base: NDArray | None = None, *, alpha: float = 0.65
              ) -> NDArray[np.float64]:
    """The labels as colours (H, W, 3). With ``base`` (a display picture (H, W, 3)): drawn over
    its grey at ``alpha``, the background left as the grey picture; without: every label in its
    colour (the background light grey)."""
    labels = np.asarray(labels)
    present = np.unique(labels)
    if base is None:
        out = np.empty(labels.shape + (3,))
        for lab in present:
            out[labels == lab] = _rgb(label_colour(int(lab)))
        return out
    b = np.asarray(base, np.float64)
    grey = np.nan_to_num(b @ np.asarray(plots.LUMINANCE_WEIGHTS), nan=0.0)
    out = np.repeat(grey[..., None], 3, axis=-1)
    for lab in present:
        if lab == 0:
            continue
        hit = labels == lab
        out[hit] = (1.0 - alpha) * out[hit] + alpha * _rgb(label_colour(int(lab)))
    return out


# ----------------------------------------------------------------------------- views -----------
class RgbView(ImageView):
    """A colour picture in an :class:`ImageView`'s figure: its zoom (linked with other views),
    its redraw at screen resolution (blocks of f × f pixels averaged per channel) and its
    pointer callbacks; no colour bar. :meth:`show_rgb` takes (H, W, 3) values in [0, 1] (NaN:
    transparent)."""

    def __init__(self, **kwargs: Any):
        from bokeh.models import ColumnDataSource, HoverTool

        kwargs.setdefault("label", "")
        super().__init__(**kwargs)
        self.rgb: NDArray | None = None
        self.renderer.visible = False
        self.color_bar.visible = False
        self.rgba = ColumnDataSource({"image": [np.zeros((1, 1), np.uint32)], "x": [-0.5],
                                      "y": [-0.5], "dw": [1.0], "dh": [1.0]})
        self.rgba_renderer = self.figure.image_rgba(image="image", x="x", y="y", dw="dw",
                                                    dh="dh", source=self.rgba)
        for tool in self.figure.select({"type": HoverTool}):
            tool.renderers = [self.rgba_renderer]
            tool.tooltips = [("x", "$x{0}"), ("y", "$y{0}")]

    @batched
    def show_rgb(self, rgb: NDArray | None, *, title: str | None = None, reset: bool = True
                 ) -> None:
        """Show ``rgb`` (H, W, 3 in [0, 1]; ``None``: nothing); ``reset`` zooms out."""
        if rgb is None:
            self.rgb = None
            self.rgba.data = {"image": [np.zeros((1, 1), np.uint32)], "x": [-0.5], "y": [-0.5],
                              "dw": [1.0], "dh": [1.0]}
            self.show(None, title=title)
            return
        rgb = np.asarray(rgb, np.float64)
        if rgb.ndim != 3 or rgb.shape[-1] != 3:
            raise ValueError(f"rgb: expected an (H, W, 3) array, got shape {rgb.shape}")
        self.rgb = rgb
        # the base class keeps a plane for the shape, the zoom and the reset extent
        self.show(np.zeros(rgb.shape[:2], np.float32), title=title, how="mean", reset=reset)

    def release(self) -> None:
        self.rgb = None
        super().release()

    @batched
    def redraw(self) -> None:
        if self.plane is None or self.rgb is None:
            return
        x_range, y_range = self.visible_ranges()
        key = (x_range, y_range, self.figure.frame_width, self.figure.frame_height)
        if key == self._drawn_for:
            return
        self._drawn_for = key
        parts = []
        for c in range(3):
            data, bounds, factor = plots.overview(
                self.rgb[..., c], x_range, y_range, self.figure.frame_width,
                self.figure.frame_height, how="mean")
            parts.append(np.asarray(data, np.float64))
        left, bottom, right, top = bounds
        self.factor = factor
        self.rgba.data = {"image": [pack_rgba(np.stack(parts, axis=-1))], "x": [left],
                          "y": [bottom], "dw": [right - left], "dh": [top - bottom]}
        self.figure.title.text = (self.title if factor <= 1 else
                                  plots.with_note(self.title, f"mean of {factor}\u00d7{factor} px"))

    def shown_rgba(self) -> NDArray[np.uint32]:
        """The packed RGBA image the figure holds (tests)."""
        return np.asarray(self.rgba.data["image"][0])


def pack_rgba(rgb: NDArray) -> NDArray[np.uint32]:
    """(h, w, 3) values in [0, 1] (NaN: transparent) -> (h, w) uint32 RGBA for ``image_rgba``."""
    ok = np.all(np.isfinite(rgb), axis=-1)
    out = np.zeros(rgb.shape[:2] + (4,), np.uint8)
    out[..., :3] = np.round(np.clip(np.nan_to_num(rgb), 0.0, 1.0) * 255).astype(np.uint8)
    out[..., 3] = np.where(ok, 255, 0)
    return np.ascontiguousarray(out).view(np.uint32).reshape(rgb.shape[:2])


def log_colours(view: ImageView, low: float = 0.1, high: float = 100.0) -> None:
    """Give ``view`` (before it is drawn) a logarithmic colour mapper and colour bar."""
    from bokeh.models import LogColorMapper

    old = view.mapper
    mapper = LogColorMapper(palette=old.palette, low=low, high=high, nan_color=old.nan_color)
    view.renderer.glyph.color_mapper = mapper
    view.color_bar.color_mapper = mapper
    view.mapper = mapper


# ----------------------------------------------------------------------------- histogram -------
def histogram_columns(background: NDArray, bins: int = 60, x_max: float | None = None
                      ) -> dict[str, NDArray]:
    """The background's d² as a probability density over ``[0, x_max]`` (bars: left, right,
    top, so that Σ top · width = the fraction of the sample in range)."""
    v = np.asarray(background, np.float64)
    v = v[np.isfinite(v)]
    hi = float(x_max) if x_max is not None else (float(v.max()) if v.size else 1.0)
    hi = hi if hi > 0 else 1.0
    counts, edges = np.histogram(v, bins=bins, range=(0.0, hi))
    width = np.diff(edges)
    top = counts / (max(v.size, 1) * width)
    return {"left": edges[:-1], "right": edges[1:], "top": top,
            "centre": 0.5 * (edges[:-1] + edges[1:]), "count": counts.astype(np.int64)}


def chi2_columns(dof: int, scale: float, x_max: float, n: int = 400) -> dict[str, NDArray]:
    """The χ² density with ``dof`` degrees of freedom and the scaled one (d²/s ~ χ²) on
    (0, x_max]."""
    from scipy import stats

    x = np.linspace(x_max / n / 10, x_max, n)
    s = float(scale) if np.isfinite(scale) and scale > 0 else 1.0
    return {"x": x, "chi2": stats.chi2.pdf(x, dof), "scaled": stats.chi2.pdf(x / s, dof) / s}


class D2Histogram:
    """The background's d² (bars, density) against the χ² density (Fig. 6): bars above the
    threshold in orange; the threshold (solid) and the χ² threshold (dashed) as vertical
    lines, moved in place by :meth:`set_threshold`."""

    def __init__(self, *, height: int = 320, css_classes: Sequence[str] = ()):
        from bokeh.models import ColumnDataSource, HoverTool, Legend, LegendItem, Range1d, Span
        from bokeh.plotting import figure

        # fixed ranges, set with the data (data ranges over empty sources warn in the browser)
        self.fig = figure(height=height, sizing_mode="stretch_width", x_range=Range1d(0, 1),
                          y_range=Range1d(0, 1),
                          x_axis_label="d² under the background's transform",
                          y_axis_label="density", tools="pan,wheel_zoom,box_zoom,reset,save",
                          toolbar_location="above", output_backend="canvas",
                          css_classes=list(css_classes))
        self.fig.toolbar.logo = None
        self.bars = ColumnDataSource({"left": [], "right": [], "top": [], "centre": [],
                                      "count": [], "color": []}, name="ccd-change-hist")
        quads = self.fig.quad(left="left", right="right", top="top", bottom=0,
                              source=self.bars, fill_color="color", fill_alpha=0.7,
                              line_color=None)
        self.curve = ColumnDataSource({"x": [], "chi2": [], "scaled": []})
        chi = self.fig.line("x", "chi2", source=self.curve, line_color="black", line_width=2)
        scaled = self.fig.line("x", "scaled", source=self.curve, line_color="black",
                               line_width=1.5, line_dash="dashed", line_alpha=0.7)
        self.span = Span(dimension="height", location=0.0, line_color=ABOVE_COLOUR,
                         line_width=2.5)
        self.chi2_span = Span(dimension="height", location=0.0, line_color="#555555",
                              line_width=1.5, line_dash="dotted")
        self.fig.add_layout(self.span)
        self.fig.add_layout(self.chi2_span)
        # legend entries for the lines: glyphs with the spans' styles on one point (a line of
        # zero length, drawing nothing; the legend leaves out glyphs without data)
        thr = self.fig.line([0, 0], [0, 0], line_color=ABOVE_COLOUR, line_width=2.5)
        thr_chi = self.fig.line([0, 0], [0, 0], line_color="#555555", line_width=1.5,
                                line_dash="dotted")
        self.items = {
            "bars": LegendItem(label="background d² (density)", renderers=[quads]),
            "chi2": LegendItem(label="χ² density", renderers=[chi]),
            "scaled": LegendItem(label="scaled χ²", renderers=[scaled]),
            "threshold": LegendItem(label="threshold", renderers=[thr]),
            "chi2_threshold": LegendItem(label="χ² threshold", renderers=[thr_chi]),
        }
        self.fig.add_layout(Legend(items=list(self.items.values()), location="top_right"))
        self.fig.add_tools(HoverTool(renderers=[quads], tooltips=[
            ("d²", "@left{0.00} \u2013 @right{0.00}"), ("pixels", "@count{0,0}"),
            ("density", "@top{0.0000}")]))

    @batched
    def show(self, background: NDArray, dof: int, scale: float, x_max: float,
             threshold: float, chi2_threshold: float) -> None:
        """New data: the bars, the densities, the x range and both thresholds."""
        cols = histogram_columns(background, 60, x_max)
        cols["color"] = _bar_colours(cols["centre"], threshold)
        self.bars.data = cols
        self.curve.data = chi2_columns(dof, scale, x_max)
        self._label("chi2", f"χ² density, {dof} degrees of freedom")
        self._label("scaled", f"scaled χ²: d²/s ~ χ², s = {scale:.3g}")
        bars = float(np.max(cols["top"], initial=0.0))
        curves = max(float(np.max(self.curve.data[k], initial=0.0)) for k in ("chi2", "scaled"))
        # χ² with 1 degree of freedom diverges at 0: the bars set the scale when there are any
        top = 1.08 * (max(bars, min(curves, 1.5 * bars)) if bars > 0 else curves)
        top = top if np.isfinite(top) and top > 0 else 1.0
        self.fig.x_range.update(start=0.0, end=float(x_max), reset_start=0.0,
                                reset_end=float(x_max))
        self.fig.y_range.update(start=0.0, end=top, reset_start=0.0, reset_end=top)
        self.set_threshold(threshold, chi2_threshold)

    @batched
    def set_threshold(self, threshold: float, chi2_threshold: float) -> None:
        """Move the threshold lines and colour the bars above the threshold."""
        self.span.location = float(threshold)
        self.chi2_span.location = float(chi2_threshold)
        self._label("threshold", f"threshold {threshold:.4g}")
        self._label("chi2_threshold", f"χ² threshold {chi2_threshold:.4g}")
        data = dict(self.bars.data)
        if len(data.get("centre", [])):
            data["color"] = _bar_colours(data["centre"], threshold)
            self.bars.data = data

    def _label(self, item: str, text: str) -> None:
        from bokeh.core.properties import value

        self.items[item].label = value(text)

    def labels(self) -> dict[str, str]:
        """The legend's texts (tests)."""
        return {k: item.label.value for k, item in self.items.items()}


def _bar_colours(centre: NDArray, threshold: float) -> list[str]:
    return [ABOVE_COLOUR if c > threshold else BELOW_COLOUR for c in np.asarray(centre)]
