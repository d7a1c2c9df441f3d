"""The plots of the EMVA 1288 datasheet that :mod:`ccdcore_report.figures` does not draw: the
deviation from linearity (EMVA Standard 1288 release 3.1 sec. 6.7), the dark current (sec. 3.1,
evaluated as sec. 7.1 says) and the spatial nonuniformity (sec. 4 and 8: the spectrograms of
sec. 8.2, the logarithmic and accumulated histograms of sec. 4.3 and 8.3, the profiles of
sec. 8.4).

Every builder takes the figures of a camera as their record,
:class:`ccdcore.emva.results.EmvaSummary` (the ``emva1288`` entry of a calibration product, or
:meth:`ccdcore.emva.datasheet.EmvaFigures.summary`), and returns a Bokeh model, or ``None`` when the
figures lack its data (a product without spatial sets, without dark frames at two exposure
times, or made before these plots). Nothing is estimated here: every number drawn is one the
figures hold, or the deviation from linearity computed from the points and the fitted line
exactly as the figures' LE_min and LE_max are. Bokeh is imported inside the builders.

The glyph renderers carry names (``fig.select(name=...)``): ``dark-points``, ``dark-error``,
``dark-line``; ``spectrum`` and ``level-<key>`` (a key of ``spatial_plots.levels``);
``counts`` and ``model``; ``accumulated``; ``<bright|dark>-<mean|min|max|mid>``;
``deviation-fit``, ``deviation-outside``, ``deviation-off-scale``, ``LE_min``, ``LE_max``.

Public objects
--------------
SPECTROGRAMS, HISTOGRAMS, PROFILES
    The ``which`` each of the spatial builders takes.
dark_signal_figure(emva), dark_variance_figure(emva)
    μ_y.dark and σ²_y.dark against the exposure time with their fitted lines.
dark_current_text(emva, which)
    μ_I.mean or μ_I.var with its error, or why it is not determined and its bound, in a line.
spectrogram_figure(emva, which)
    A spectrogram with the DSNU1288 or PRNU1288 level and the temporal-noise levels.
histogram_figure(emva, which), accumulated_histogram_figure(emva, which)
    The logarithmic and the accumulated histogram of DSNU or PRNU.
profile_figure(emva, which)
    The horizontal or vertical profiles of the signal and of the dark image.
linearity_deviation_figure(emva)
    The deviation from linearity of every point, and its plot with LE_min and LE_max.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ccdcore.common import format_pm
from ccdcore.emva.results import EmvaSummary
from ccdcore.emva.sheet import linearity_deviation

from .figures import line_figure
from .html import json_floats

__all__ = ["SPECTROGRAMS", "HISTOGRAMS", "PROFILES", "dark_signal_figure",
           "dark_variance_figure", "dark_current_text", "spectrogram_figure",
           "histogram_figure", "accumulated_histogram_figure", "profile_figure",
           "linearity_deviation_figure"]

#: the spectrograms of sec. 8.2, the histograms of sec. 8.3 and the profiles of sec. 8.4
SPECTROGRAMS = ("DSNU_horizontal", "DSNU_vertical", "PRNU_horizontal", "PRNU_vertical")
HISTOGRAMS = ("DSNU", "PRNU")
PROFILES = ("horizontal", "vertical")

#: colours (Okabe-Ito, as the report's other plots): data, fitted line, levels, outside a fit
_DATA = "#1f5f99"
_FIT = "#D55E00"
_LEVEL_COLOURS = ("#D55E00", "#009E73", "#6f42c1")
_OUTSIDE = "#8c959f"
_E = "e\u207b"


# ---------------------------------------------------------------------------------------------
# reading the figures
# ---------------------------------------------------------------------------------------------
def _columns(data: Any, *names: str) -> dict[str, NDArray] | None:
    """The named curves of the record ``data`` as float arrays of one length, ``None`` when
    ``data`` is ``None`` or the lengths differ."""
    if data is None:
        return None
    out: dict[str, NDArray] = {name: json_floats(getattr(data, name)) for name in names}
    return out if len({v.size for v in out.values()}) == 1 else None


def _check_which(which: str, allowed: tuple[str, ...]) -> None:
    if which not in allowed:
        raise ValueError(f"which must be one of {', '.join(allowed)}, not {which!r}")


def _number(v: float | None) -> float | None:
    return None if v is None else float(v)


def _figure(title: str, xlabel: str, ylabel: str, *, y_log: bool = False, height: int = 360,
            **kw: Any) -> Any:
    """A stretched figure with the report's tools, its toolbar hidden until hovered (as the
    report's other plots, :mod:`ccdcore_report.figures`)."""
    if y_log:
        kw["y_axis_type"] = "log"
    return line_figure(title, xlabel, ylabel, height, **kw)


def _legend_outside(fig: Any, place: str = "below") -> None:
    """The figure's legend moved out of the plot area (``"below"`` or ``"right"``), so it hides
    no data; below, the figure grows by the legend's rows and keeps its plot area."""
    legend = fig.legend[0]
    if place == "below":
        fig.height += 22 * len(legend.items) + 8
    fig.center = [r for r in fig.center if r is not legend]
    legend.location = "top_left"
    legend.border_line_alpha = 0.0
    legend.margin = 4
    legend.padding = 4
    fig.add_layout(legend, place)


def _hover(fig: Any, renderers: list, tooltips: list[tuple[str, str]]) -> None:
    from bokeh.models import HoverTool

    fig.add_tools(HoverTool(renderers=renderers, tooltips=tooltips))


# ---------------------------------------------------------------------------------------------
# dark current (sec. 3.1, 7.1)
# ---------------------------------------------------------------------------------------------
#: which -> (point key, line key, figure key, symbol, unit of the points, unit of the slope)
_DARK = {"mean": ("u_y_dark", "mean_line", "u_I_mean", "\u03bc_I.mean", "DN", "DN/s"),
         "var": ("s2_y_dark", "var_line", "u_I_var", "\u03bc_I.var", "DN\u00b2",
                 "DN\u00b2/s")}


def dark_current_text(e: EmvaSummary, which: str) -> str:
    """The dark current from the mean (``which="mean"``) or the variance (``"var"``) in one
    line: ``"μ_I.mean = 1497 ± 20 e⁻/s"``, or that it is not determined with the bound the
    exposure range gives (sec. 3.1; :mod:`ccdcore.emva.dark`)."""
    _, _, key, symbol, _, _ = _DARK[which]
    value = _number(getattr(e, key))
    if value is not None:
        return f"{symbol} = {format_pm(value, getattr(e, f'{key}_err'), unit=f'{_E}/s')}"
    dc = e.dark_current
    if dc is None:
        return f"{symbol} not determined"
    bound = _number(getattr(dc, f"{key}_bound"))
    if bound is not None:
        return f"{symbol} not determined: below {bound:.3g} {_E}/s"
    return f"{symbol} not determined"


def _dark_figure(e: EmvaSummary, which: str) -> Any:
    """The dark points of ``which`` against the exposure time with their standard errors and
    the dark-current line; ``None`` below two exposure times."""
    from bokeh.models import ColumnDataSource

    key, line_key, _, _, unit, slope_unit = _DARK[which]
    rows = [p for p in e.dark_points if p.exposure is not None]
    t = np.array([p.exposure for p in rows], np.float64)
    if np.unique(t).size < 2:
        return None
    y = np.array([getattr(p, key) for p in rows], np.float64)
    err = np.nan_to_num(json_floats([getattr(p, f"{key}_err") for p in rows]))
    if which == "mean":
        title = "Mean dark signal against exposure time"
        ylabel = "\u03bc_y.dark (DN)"
        label = "\u03bc_y.dark (mean of two dark frames)"
    else:
        title = "Temporal dark variance against exposure time"
        ylabel = "\u03c3\u00b2_y.dark (DN\u00b2)"
        label = "\u03c3\u00b2_y.dark (from the difference of two dark frames)"
    fig = _figure(f"{title}: {dark_current_text(e, which)}", "exposure time t (s)", ylabel)
    src = ColumnDataSource({"t": t, "y": y, "err": err, "lo": y - err, "hi": y + err})
    fig.segment("t", "lo", "t", "hi", source=src, line_color=_DATA, name="dark-error")
    dots = fig.scatter("t", "y", source=src, size=7, color=_DATA, legend_label=label,
                       name="dark-points")
    line = None if e.dark_current is None else getattr(e.dark_current, line_key)
    if line is not None:
        slope, offset = float(line.slope), float(line.offset)
        ends = np.array([t.min(), t.max()])
        fig.line(ends, offset + slope * ends, line_color=_FIT, line_width=2, name="dark-line",
                 legend_label=f"fitted line {offset:.4g} {unit} + slope \u00b7 t, slope "
                              f"{format_pm(slope, line.slope_err, unit=slope_unit)}")
    _hover(fig, [dots], [("t", "@t{0.00000} s"), (ylabel, "@y{0.0000}"),
                         ("\u00b1", "@err{0.0000}")])
    _legend_outside(fig)
    return fig


def dark_signal_figure(emva: EmvaSummary) -> Any:
    """The mean dark signal μ_y.dark (DN) against the exposure time (s) with its standard
    errors and the line μ_y.dark(0) + K μ_I t whose slope gives μ_I.mean (sec. 3.1, 7.1); the
    title states μ_I.mean or why it is not determined. ``None`` without dark points at two
    exposure times or more."""
    return _dark_figure(emva, "mean")


def dark_variance_figure(emva: EmvaSummary) -> Any:
    """The temporal dark variance σ²_y.dark (DN²) against the exposure time with its standard
    errors and the line K²(σ²_d + μ_I t) + σ²_q whose slope gives μ_I.var (sec. 3.1, 7.1).
    ``None`` without dark points at two exposure times or more."""
    return _dark_figure(emva, "var")


# ---------------------------------------------------------------------------------------------
# spatial nonuniformity (sec. 4, 8)
# ---------------------------------------------------------------------------------------------
def _frames(emva: EmvaSummary, set_key: str) -> str:
    spatial = getattr(emva, set_key)
    return "L" if spatial is None else f"{int(spatial.L)}"


def _levels(emva: EmvaSummary, kind: str) -> list[tuple[str, str]]:
    """(level key, legend) of the horizontal lines of a spectrogram (sec. 8.2)."""
    if kind == "DSNU":
        n = _frames(emva, "spatial_dark")
        return [("DSNU1288_DN", "DSNU1288 in DN"),
                ("sigma_y_stack_dark", "temporal noise of one dark frame, \u03c3_y.stack.dark"),
                ("sigma_y_stack_dark_avg", f"white-noise floor of the average of {n} dark "
                                           "frames, \u03c3_y.stack.dark/\u221aL")]
    n = _frames(emva, "spatial")
    return [("PRNU1288", "PRNU1288"),
            ("sigma_y_stack_percent", "temporal noise of one bright frame, \u03c3_y.stack"),
            ("sigma_y_stack_avg_percent", f"white-noise floor of the average of {n} bright "
                                          "frames, \u03c3_y.stack/\u221aL")]


def spectrogram_figure(e: EmvaSummary, which: str) -> Any:
    """The spectrogram ``which`` (one of :data:`SPECTROGRAMS`) of sec. 8.2: the standard
    deviation of each spatial frequency (DN for DSNU, % of the mean signal for PRNU; log
    scale) against the frequency (cycles per pixel), with DSNU1288 (in DN) or PRNU1288, the
    temporal noise of one frame σ_y.stack and the white-noise floor σ_y.stack/√L that the
    temporal noise leaves in the average of the L frames, each as a labelled line.
    ``None`` when the figures have no spatial plots."""
    _check_which(which, SPECTROGRAMS)
    plots = e.spatial_plots
    if plots is None:
        return None
    data = _columns(getattr(plots.spectrograms, which), "f", "amplitude")
    if data is None:
        return None
    f, amp = data["f"], data["amplitude"]
    ok = np.isfinite(f) & np.isfinite(amp) & (amp > 0)
    if not ok.any():
        return None
    kind, direction = which.split("_")
    unit = "DN" if kind == "DSNU" else "% of the signal"
    short_unit = "DN" if kind == "DSNU" else "%"
    fig = _figure(f"{direction.capitalize()} spectrogram of the {kind}",
                  "spatial frequency (cycles per pixel)", f"standard deviation ({unit})",
                  y_log=True)
    spectrum = fig.line(f[ok], amp[ok], line_color=_DATA, line_width=2, name="spectrum",
                        legend_label="spectrogram")
    ends = [float(f[ok].min()), float(f[ok].max())]
    for (key, label), colour, dash in zip(_levels(e, kind), _LEVEL_COLOURS,
                                          ("dashed", "dashdot", "dotted")):
        v = _number(getattr(plots.levels, key))
        if v is not None and v > 0:
            fig.line(ends, [v, v], line_color=colour, line_width=2, line_dash=dash,
                     name=f"level-{key}", legend_label=f"{label} = {v:.3g} {short_unit}")
    _hover(fig, [spectrum], [("f", "$x{0.000} cycles/pixel"), ("amplitude", "$y{0.000}")])
    _legend_outside(fig)
    return fig


def _axis_text(which: str) -> str:
    if which == "DSNU":
        return f"deviation from the mean dark signal ({_E})"
    return "deviation of the high-pass filtered signal (% of the mean signal)"


def histogram_figure(emva: EmvaSummary, which: str) -> Any:
    """The logarithmic histogram of sec. 4.3.1 and 8.3 (``which`` "DSNU" or "PRNU"): the
    pixel count of each bin at its centre (log scale; empty bins left out) with the normal
    distribution of the same mean and standard deviation as a line. DSNU: the deviation of
    the average dark image from its mean (e⁻); PRNU: the 5 × 5 high-pass filtered signal (%
    of the mean signal). ``None`` when the figures have no spatial plots."""
    from bokeh.models import ColumnDataSource, Range1d

    _check_which(which, HISTOGRAMS)
    plots = emva.spatial_plots
    data = None if plots is None else _columns(getattr(plots.histograms, which), "x", "count",
                                               "model")
    if data is None or not (data["count"] > 0).any():
        return None
    x, count, model = data["x"], data["count"], data["model"]
    width = float(x[1] - x[0]) if x.size > 1 else 0.0     # equal bins (lower edges given)
    centre = x + width / 2.0
    name = "DSNU" if which == "DSNU" else "PRNU"
    # counts are whole pixels: the axis starts at half a pixel, as the package draws it
    fig = _figure(f"Logarithmic histogram of the {name}", _axis_text(which), "pixels per bin",
                  y_log=True, y_range=Range1d(0.5, 2.0 * float(count.max())))
    has = count > 0
    src = ColumnDataSource({"x": centre[has], "count": count[has]})
    dots = fig.scatter("x", "count", source=src, size=5, color=_DATA, name="counts",
                       legend_label="pixels (bin centres)")
    shown = np.isfinite(model) & (model > 0)
    fig.line(centre[shown], model[shown], line_color=_FIT, line_width=2, line_dash="dashed",
             name="model", legend_label="normal distribution of the same mean and std")
    _hover(fig, [dots], [("deviation", "@x{0.000}"), ("pixels", "@count")])
    _legend_outside(fig)
    return fig


def accumulated_histogram_figure(emva: EmvaSummary, which: str) -> Any:
    """The accumulated logarithmic histogram of sec. 4.3.2 and 8.3 (``which`` "DSNU" or
    "PRNU"): the percentage of pixels deviating from the mean by x or more (log scale; 0 %
    left out) against x, in e⁻ (DSNU) or % of the mean signal (PRNU). ``None`` when the
    figures have no spatial plots."""
    from bokeh.models import ColumnDataSource

    _check_which(which, HISTOGRAMS)
    plots = emva.spatial_plots
    data = None if plots is None else _columns(getattr(plots.accumulated, which), "x",
                                               "percent")
    if data is None:
        return None
    x, percent = data["x"], data["percent"]
    has = np.isfinite(x) & np.isfinite(percent) & (percent > 0)
    if not has.any():
        return None
    unit = _E if which == "DSNU" else "% of the mean signal"
    fig = _figure(f"Accumulated histogram of the {which}",
                  f"deviation from the mean, x ({unit})",
                  "pixels deviating by x or more (%)", y_log=True)
    src = ColumnDataSource({"x": x[has], "percent": percent[has]})
    line = fig.line("x", "percent", source=src, line_color=_DATA, line_width=2,
                    name="accumulated")
    _hover(fig, [line], [("x", "@x{0.000}"), ("pixels", "@percent{0.000} %")])
    return fig


#: part of a profile -> (legend, style)
_PROFILE_LINES = (("max", "maximum", dict(line_color="#E69F00", line_width=1)),
                  ("mean", "mean", dict(line_color=_DATA, line_width=2)),
                  ("mid", "middle line", dict(line_color="#009E73", line_width=1,
                                              line_dash="dashed")),
                  ("min", "minimum", dict(line_color="#6f42c1", line_width=1)))


def profile_figure(emva: EmvaSummary, which: str) -> Any:
    """The profiles of sec. 8.4 (``which`` "horizontal" or "vertical"): for each column
    (row), the mean, minimum and maximum over the rows (columns) and the value of the middle
    row (column), in DN; above, the signal (the average bright image less the average dark
    one), below, the average dark image, zoom linked. ``None`` when the figures have no
    spatial plots (one figure when only one of the two profiles is there)."""
    from bokeh.layouts import column

    _check_which(which, PROFILES)
    plots = emva.spatial_plots
    if plots is None:
        return None
    xlabel = "column index x" if which == "horizontal" else "row index y"
    line = "column" if which == "horizontal" else "row"
    figs: list[Any] = []
    for part, what in (("bright", "signal (bright less dark)"), ("dark", "dark image")):
        data = _columns(getattr(plots.profiles, f"{part}_{which}"), "index", "mean", "min",
                        "max", "mid")
        if data is None or data["index"].size == 0:
            continue
        kw = {"x_range": figs[0].x_range} if figs else {}
        fig = _figure(f"{which.capitalize()} profile of the {what}: mean, minimum and maximum "
                      f"of each {line}", xlabel, f"{what} (DN)", height=300, **kw)
        for key, label, style in _PROFILE_LINES:
            fig.line(data["index"], data[key], name=f"{part}-{key}", legend_label=label,
                     **style)
        _legend_outside(fig, "right")
        figs.append(fig)
    if not figs:
        return None
    return column(*figs, sizing_mode="stretch_width")


# ---------------------------------------------------------------------------------------------
# deviation from linearity (sec. 6.7)
# ---------------------------------------------------------------------------------------------
def _deviation_scale(dev: NDArray, in_fit: NDArray, marks: list[float]
                     ) -> tuple[float, float, NDArray]:
    """The y range of the deviation plot and which points lie on it: the points of the fit and
    the LE lines, widened for the other points within one span of them on either side (points
    further off would flatten the fit's range to a line)."""
    core = np.concatenate([dev[in_fit], np.array(marks, np.float64)])
    core = core[np.isfinite(core)]
    if core.size == 0:
        core = dev[np.isfinite(dev)]
    lo, hi = float(core.min()), float(core.max())
    span = hi - lo if hi > lo else max(abs(hi), 1e-3)
    on = np.isfinite(dev) & (dev >= lo - span) & (dev <= hi + span)
    lo, hi = min(lo, float(dev[on].min(initial=lo))), max(hi, float(dev[on].max(initial=hi)))
    pad = 0.08 * (hi - lo if hi > lo else span)
    return lo - pad, hi + pad, on


def linearity_deviation_figure(e: EmvaSummary) -> Any:
    """The deviation from linearity (sec. 6.7, :func:`linearity_deviation`) against μ_p: the
    points of the linearity fit filled and joined, the others hollow grey, LE_min and LE_max
    as labelled lines. Points so far off that they would flatten the fit's range are drawn
    as hollow triangles at the edge of the plot (up: above, down: below; the hover gives
    their value). ``None`` without the fitted line or points."""
    from bokeh.models import ColumnDataSource, Range1d

    d = linearity_deviation(e)
    if d is None or not np.isfinite(d["deviation"]).any():
        return None
    u_p, dev, in_fit = d["u_p"], d["deviation"], d["in_fit"]
    le = [(key, _number(getattr(e, key))) for key in ("LE_min", "LE_max")]
    y0, y1, on = _deviation_scale(dev, in_fit, [v for _, v in le if v is not None])
    fig = _figure("Deviation from linearity", "\u03bc_p (photons per pixel)",
                  "deviation from the fitted line (%)", y_range=Range1d(y0, y1))
    fig.line([float(u_p.min()), float(u_p.max())], [0.0, 0.0], line_color=_OUTSIDE,
             line_width=1)
    renderers = []
    if in_fit.any():
        src = ColumnDataSource({"u_p": u_p[in_fit], "deviation": dev[in_fit],
                                "y": dev[in_fit], "level": d["level"][in_fit]})
        fig.line("u_p", "deviation", source=src, line_color=_DATA, line_width=1)
        renderers.append(fig.scatter("u_p", "deviation", source=src, size=7, color=_DATA,
                                     name="deviation-fit", legend_label="in the linearity fit"))
    out = ~in_fit & on
    if out.any():
        src = ColumnDataSource({"u_p": u_p[out], "deviation": dev[out], "y": dev[out],
                                "level": d["level"][out]})
        renderers.append(fig.scatter("u_p", "deviation", source=src, size=8, fill_alpha=0.0,
                                     line_color=_OUTSIDE, line_width=2,
                                     name="deviation-outside", legend_label="outside the fit"))
    off = np.isfinite(dev) & ~on
    if off.any():
        inset = 0.03 * (y1 - y0)
        above = dev[off] > y1
        src = ColumnDataSource({"u_p": u_p[off], "deviation": dev[off],
                                "y": np.where(above, y1 - inset, y0 + inset),
                                "marker": np.where(above, "triangle", "inverted_triangle"),
                                "level": d["level"][off]})
        renderers.append(fig.scatter("u_p", "y", source=src, marker="marker", size=10,
                                     fill_alpha=0.0, line_color=_OUTSIDE, line_width=2,
                                     name="deviation-off-scale",
                                     legend_label="outside the fit, off the scale"))
    fit_ends = u_p[in_fit] if in_fit.any() else u_p
    ends = [float(fit_ends.min()), float(fit_ends.max())]
    for (key, v), colour in zip(le, ("#6f42c1", _FIT)):
        if v is not None:
            fig.line(ends, [v, v], line_color=colour, line_width=2, line_dash="dashed",
                     name=key, legend_label=f"{key} = "
                     f"{format_pm(v, getattr(e, f'{key}_err'), unit='%')}")
    _hover(fig, renderers, [("level", "@level{0}"), ("\u03bc_p", "@u_p{0.0}"),
                            ("deviation", "@deviation{0.0000} %")])
    _legend_outside(fig)
    return fig
