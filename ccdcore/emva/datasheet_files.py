"""The files of an EMVA 1288 datasheet: the figures as CSV and JSON, and the datasheet's plots as
PNG and SVG (``ccdcore datasheet``).

The figures are those of :func:`ccdcore.emva.datasheet.emva_figures` (EMVA Standard 1288 release
3.1, with release 4.0's row, column and pixel parts of DSNU and PRNU), given as their record
(:class:`ccdcore.emva.results.EmvaSummary`: :meth:`~ccdcore.emva.datasheet.EmvaFigures.summary`, or
the ``emva1288`` entry of a calibration product, checked when it was loaded). The rows are
:func:`ccdcore.emva.sheet.datasheet_rows`, in the standard's order.

Files (written as one set into a folder, :func:`ccdcore.io.frames.output_set`)
------------------------------------------------------------------------
``datasheet.csv``
    One row per figure: section, key, name, symbol, unit, value, error, note (UTF-8, a header
    line). Numbers are written as Python's ``repr`` of the float, the shortest text that reads
    back to the same float, so the file round-trips exactly; an empty value is a figure not
    determined, with its reason in ``note``.
``datasheet.json``
    ``{"emva1288": <the figures' JSON object, emva.to_dict()>, "rows": [<one object per
    row>], "plots": {"drawn": [...], "skipped": [{"plot", "reason"}]}}``.
``plots/<name>.png``, ``plots/<name>.svg``
    The plots of release 3.1 (sec. 6.6 photon transfer and SNR, sec. 6.7 linearity and its
    deviation, sec. 7 dark signal and dark variance against the exposure time, sec. 8.2
    spectrograms, sec. 8.3 logarithmic and accumulated histograms, sec. 8.4 profiles; names in
    :data:`PLOTS`). A plot whose data the figures lack is skipped with its reason
    (:func:`plot_plan`). Drawn with matplotlib (the ``datasheet`` extra), imported only here.

Public objects
--------------
write_datasheet(emva, out_dir, inputs=(), plots=True)
    Write the files; the paths written.
datasheet_csv(emva), datasheet_document(emva, plan=None)
    The CSV text and the JSON document (no plotting package needed).
plot_plan(emva)
    Which plots the figures allow, and why the others are skipped.
PLOTS, PlotPlan, CSV_FILE, JSON_FILE, PLOTS_FOLDER, CSV_COLUMNS, PLOT_FORMATS, OUTPUTS
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from ..common import format_pm, json_safe
from .results import EmvaPointSummary, EmvaSummary
from .sheet import datasheet_rows, linearity_deviation
from .spatial import SpatialPlotsSummary
from ..errors import require_extra

__all__ = ["write_datasheet", "datasheet_csv", "datasheet_document", "plot_plan", "PlotPlan",
           "draw_plot",
           "PLOTS", "CSV_FILE", "JSON_FILE", "PLOTS_FOLDER", "CSV_COLUMNS", "PLOT_FORMATS",
           "OUTPUTS"]

CSV_FILE = "datasheet.csv"
JSON_FILE = "datasheet.json"
PLOTS_FOLDER = "plots"
#: the columns of ``datasheet.csv`` (the fields of :class:`ccdcore.emva.sheet.SheetRow`)
CSV_COLUMNS = ("section", "key", "name", "symbol", "unit", "value", "error", "note")
#: every plot is written in these formats
PLOT_FORMATS = ("png", "svg")
#: the entries a datasheet writes into its folder, ``name -> is a folder`` (for
#: :func:`ccdcore.io.frames.check_outputs` before the work)
OUTPUTS: dict[str, bool] = {CSV_FILE: False, JSON_FILE: False, PLOTS_FOLDER: True}

_DPI = 120
_SVG_SALT = "ccdcore-datasheet"   # fixed element ids in the SVG


# --------------------------------------------------------------------------------------------
# CSV and JSON
# --------------------------------------------------------------------------------------------
def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    return str(v)


def datasheet_csv(emva: EmvaSummary) -> str:
    """``datasheet.csv`` of the figures ``emva``: a header of :data:`CSV_COLUMNS`, then one line
    per :func:`~ccdcore.emva.sheet.datasheet_rows` row; floats as ``repr`` (exact round trip),
    an undetermined value (and its error) empty."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for row in datasheet_rows(emva):
        d = row.to_dict()
        writer.writerow([_cell(d[c]) for c in CSV_COLUMNS])
    return buf.getvalue()


def datasheet_document(emva: EmvaSummary, plan: PlotPlan | None = None) -> dict[str, Any]:
    """``datasheet.json``: the figures ``emva`` whole (``emva.to_dict()``), the rows, and (with
    ``plan``) the plots drawn and skipped. JSON-safe (NaN written as ``None``)."""
    doc: dict[str, Any] = {"emva1288": emva.to_dict(),
                           "rows": [json_safe(r.to_dict()) for r in datasheet_rows(emva)]}
    if plan is not None:
        doc["plots"] = plan.to_dict()
    return doc


# --------------------------------------------------------------------------------------------
# plot data
# --------------------------------------------------------------------------------------------
def _floats(values: Sequence[float | None]) -> np.ndarray:
    """A curve of the figures (``None`` for a value not finite) as float64 with NaN."""
    return np.array([math.nan if x is None else x for x in values], dtype=np.float64)


def _column(points: Sequence[Any], name: str) -> np.ndarray:
    return _floats([getattr(p, name) for p in points])


def _flags(points: Sequence[EmvaPointSummary], name: str) -> np.ndarray:
    return np.array([bool(getattr(p, name)) for p in points], dtype=bool)


# --------------------------------------------------------------------------------------------
# what each plot needs
# --------------------------------------------------------------------------------------------
_NO_SPATIAL = ("no spatial sets (L bright and L dark frames at one operating point, EMVA 1288 "
               "sec. 8) in the session")


def _needs_points(emva: EmvaSummary) -> str | None:
    if not emva.points:
        return "no bright points in the figures"
    return None


def _needs_snr(emva: EmvaSummary) -> str | None:
    if not emva.snr_curve.u_p:
        return "no SNR curve in the figures"
    return None


def _needs_dark(emva: EmvaSummary) -> str | None:
    times = {d.exposure for d in emva.dark_points} - {None}
    if len(times) < 2:
        return (f"the dark points are at {len(times)} known exposure time"
                f"{'s' if len(times) != 1 else ''}; a plot against the exposure time needs "
                "two or more (three or more for the dark current)")
    return None


def _needs_spatial(emva: EmvaSummary) -> str | None:
    if emva.spatial_plots is None:
        return _NO_SPATIAL
    return None


# --------------------------------------------------------------------------------------------
# drawing (matplotlib's object API: no pyplot, no global state)
# --------------------------------------------------------------------------------------------
_FIT = dict(marker="o", linestyle="none", color="C0", markersize=5)
_OUT = dict(marker="o", linestyle="none", markerfacecolor="none", color="C0", markersize=5)
_LINE = dict(color="C3", linewidth=1.2)


def _axes(fig: Any, title: str, xlabel: str, ylabel: str) -> Any:
    ax = fig.add_subplot(1, 1, 1)
    ax.set_title(title)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, which="major", alpha=0.3)
    return ax


def _log(ax: Any, which: str) -> None:
    """A logarithmic ``which`` ("x" or "y") axis labelled in plain numbers (0.1, 2, 10000);
    within less than a decade the minor ticks 2, 3 and 5 are labelled too (all of them within
    less than 0.4 of a decade)."""
    from matplotlib.ticker import FuncFormatter

    (ax.set_xscale if which == "x" else ax.set_yscale)("log")
    axis = ax.xaxis if which == "x" else ax.yaxis

    def minor(v: float, _pos: Any) -> str:
        lo, hi = sorted(axis.get_view_interval())
        if not (lo > 0 and v > 0):
            return ""
        decades = math.log10(hi / lo)
        mantissa = round(v / 10.0 ** math.floor(math.log10(v)), 6)
        return f"{v:g}" if decades < 0.4 or (decades < 1.0 and mantissa in (2, 3, 5)) else ""

    axis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
    axis.set_minor_formatter(FuncFormatter(minor))


def _draw_ptc(fig: Any, emva: EmvaSummary) -> None:
    """Release 3.1 sec. 6.6: σ²_y − σ²_y.dark against μ_y − μ_y.dark, the fit of K through the
    origin over the points up to 70 % of saturation."""
    pts = emva.points
    x = _column(pts, "u_y") - _column(pts, "u_y_dark")
    y = _column(pts, "s2_y") - _column(pts, "s2_y_dark")
    fit, sat = _flags(pts, "in_sensitivity_fit"), _flags(pts, "saturation")
    ax = _axes(fig, "Photon transfer", "μ_y − μ_y.dark [DN]", "σ²_y − σ²_y.dark [DN²]")
    ax.plot(x[fit], y[fit], label="points of the fit (to 70 % of saturation)", **_FIT)
    ax.plot(x[~fit], y[~fit], label="other points", **_OUT)
    if sat.any():
        ax.plot(x[sat], y[sat], marker="x", linestyle="none", color="k", markersize=9,
                label="saturation")
    K = float(emva.K)
    top = float(np.nanmax(x[fit])) if fit.any() and np.isfinite(x[fit]).any() else \
        float(np.nanmax(x))
    xs = np.array([0.0, top])
    ax.plot(xs, K * xs, label=f"K = {format_pm(K, emva.K_err, unit='DN/e⁻')}", **_LINE)
    ax.legend(loc="best", fontsize="small")


def _draw_snr(fig: Any, emva: EmvaSummary) -> None:
    """Release 3.1 sec. 2.3 and 6.6: the measured SNR against μ_p (log-log) with the model of
    eq. 11, and with DSNU1288 and PRNU1288 when the spatial sets gave them."""
    curve = emva.snr_curve
    u_p = _floats(curve.u_p)
    ax = _axes(fig, "Signal-to-noise ratio", "μ_p [photons per pixel]", "SNR")
    _log(ax, "x")
    _log(ax, "y")
    good = u_p > 0
    snr = _floats(curve.snr)
    if snr.size == u_p.size:
        ok = good & (snr > 0)
        ax.plot(u_p[ok], snr[ok], label="measured", **_FIT)
    for key, label, style in (("snr_model", "model (eq. 11)", "-"),
                              ("snr_total", "model with DSNU1288 and PRNU1288", "--")):
        values = getattr(curve, key)
        if values:
            m = _floats(values)
            if m.size == u_p.size:
                ok = good & (m > 0)
                ax.plot(u_p[ok], m[ok], linestyle=style, label=label,
                        color="C3" if key == "snr_model" else "C2")
    for v, label, side in ((emva.u_p_min, "μ_p.min", 1), (emva.u_p_sat, "μ_p.sat", -1)):
        if v > 0:
            v = float(v)
            ax.axvline(v, color="0.4", linestyle=":", linewidth=1)
            ax.annotate(label, (v, 1.0), xycoords=("data", "axes fraction"),
                        xytext=(3 * side, -12), textcoords="offset points",
                        ha="left" if side > 0 else "right", fontsize="small")
    ax.legend(loc="lower right", fontsize="small")


def _draw_linearity(fig: Any, emva: EmvaSummary) -> None:
    """Release 3.1 sec. 6.7: μ_y − μ_y.dark against μ_p with the line a·μ_p + b fitted over
    5–95 % of the saturation signal."""
    pts = emva.points
    u_p = _column(pts, "u_p")
    Y = _column(pts, "u_y") - _column(pts, "u_y_dark")
    fit, sat = _flags(pts, "in_linearity_fit"), _flags(pts, "saturation")
    a, b = float(emva.linearity_slope), float(emva.linearity_offset)
    ax = _axes(fig, "Linearity", "μ_p [photons per pixel]", "μ_y − μ_y.dark [DN]")
    ax.plot(u_p[fit], Y[fit], label="points of the fit (5–95 % of saturation)", **_FIT)
    ax.plot(u_p[~fit], Y[~fit], label="other points", **_OUT)
    if sat.any():
        ax.plot(u_p[sat], Y[sat], marker="x", linestyle="none", color="k", markersize=9,
                label="saturation")
    xs = np.array([0.0, float(np.nanmax(u_p[fit])) if fit.any() else float(np.nanmax(u_p))])
    ax.plot(xs, a * xs + b, label=f"fit a·μ_p + b: a = {a:.5g} DN/p, b = {b:.4g} DN", **_LINE)
    ax.legend(loc="best", fontsize="small")


def _draw_deviation(fig: Any, emva: EmvaSummary) -> None:
    """Release 3.1 sec. 6.7: the deviation 100·(Y − (a·μ_p + b))/(a·μ_p + b) of the points of
    the linearity fit (5–95 % of the saturation signal), with LE_min and LE_max, its extremes.
    The points outside that range are not drawn: near zero signal a small offset is a large
    relative deviation, which would hide the range the standard rates."""
    d = linearity_deviation(emva)
    assert d is not None                          # plot_plan: the figures have points
    u_p, dev, fit = d["u_p"], d["deviation"], d["in_fit"]
    ax = _axes(fig, "Deviation from linearity (the points of the fit, 5–95 % of saturation)",
               "μ_p [photons per pixel]", "100·(Y − (a·μ_p + b))/(a·μ_p + b) [%]")
    ax.plot(u_p[fit], dev[fit], label="points of the fit", **_FIT)
    ax.axhline(0.0, color="0.5", linewidth=0.8)
    for label, v, err in (("LE_min", emva.LE_min, emva.LE_min_err),
                          ("LE_max", emva.LE_max, emva.LE_max_err)):
        v = float(v)
        ax.axhline(v, color="C3", linestyle=":", linewidth=1,
                   label=f"{label} = {format_pm(v, err, unit='%')}")
    ax.legend(loc="best", fontsize="small")


def _draw_dark(fig: Any, emva: EmvaSummary, *, variance: bool) -> None:
    """Release 3.1 sec. 3.1 and 7: μ_y.dark (or σ²_y.dark) of the dark points against the
    exposure time with the line offset + slope·t whose slope gives the dark current."""
    rows = [d for d in emva.dark_points if d.exposure is not None]
    t = _column(rows, "exposure")
    name = "s2_y_dark" if variance else "u_y_dark"
    y = _column(rows, name)
    err = _column(rows, f"{name}_err")
    title, ylabel = (("Dark variance", "σ²_y.dark [DN²]") if variance else
                     ("Dark signal", "μ_y.dark [DN]"))
    ax = _axes(fig, title, "exposure time [s]", ylabel)
    ax.errorbar(t, y, yerr=np.where(np.isfinite(err), err, 0.0), fmt="o", color="C0",
                markersize=5, capsize=2, label="dark points (± standard error)")
    dc = emva.dark_current
    line = None if dc is None else dc.var_line if variance else dc.mean_line
    if dc is not None and line is not None:
        key = "u_I_var" if variance else "u_I_mean"
        symbol = "μ_I.var" if variance else "μ_I.mean"
        value = getattr(dc, key)
        if value is not None:
            what = (f"{symbol} = "
                    f"{format_pm(float(value), getattr(dc, f'{key}_err'), unit='e⁻/s')}")
        else:
            bound = getattr(dc, f"{key}_bound")
            what = f"{symbol} not resolved" + (f" (below {float(bound):.3g} e⁻/s)"
                                               if bound is not None else "")
        ts = np.array([float(np.nanmin(t)), float(np.nanmax(t))])
        unit = "DN²/s" if variance else "DN/s"
        slope = float(line.slope)
        ax.plot(ts, float(line.offset) + slope * ts,
                label=f"line: slope {slope:.4g} {unit}; {what}", **_LINE)
    ax.legend(loc="best", fontsize="small")


_SPECTRA = {"DSNU": ("DN", (("DSNU1288_DN", "DSNU1288", "C3", "-"),
                            ("sigma_y_stack_dark", "σ_y.stack.dark (one frame)", "C2", "--"),
                            ("sigma_y_stack_dark_avg", "σ_y.stack.dark/√L (noise of the average)",
                             "C1", ":"))),
            "PRNU": ("%", (("PRNU1288", "PRNU1288", "C3", "-"),
                           ("sigma_y_stack_percent", "σ_y.stack (one frame)", "C2", "--"),
                           ("sigma_y_stack_avg_percent", "σ_y.stack/√L (noise of the average)",
                            "C1", ":")))}
_DIRECTIONS = {"horizontal": "along the rows", "vertical": "along the columns"}


def _spatial(emva: EmvaSummary) -> SpatialPlotsSummary:
    """The arrays of the spatial plots (:func:`plot_plan` draws them only when there are)."""
    plots = emva.spatial_plots
    assert plots is not None, "plot_plan: the figures have the spatial plots"
    return plots


def _draw_spectrogram(fig: Any, emva: EmvaSummary, *, what: str, direction: str) -> None:
    """Release 3.1 sec. 8.2: the spectrogram of the dark (DSNU) or the bright less the dark
    (PRNU) average image, with DSNU1288/PRNU1288 and the temporal noise levels."""
    plots = _spatial(emva)
    spec = getattr(plots.spectrograms, f"{what}_{direction}")
    f, amp = _floats(spec.f), _floats(spec.amplitude)
    unit, lines = _SPECTRA[what]
    ax = _axes(fig, f"Spectrogram {what}, {direction} ({_DIRECTIONS[direction]})",
               "spatial frequency [cycles/pixel]", f"amplitude [{unit}]")
    _log(ax, "y")
    n = min(f.size, amp.size)
    ok = np.isfinite(amp[:n]) & (amp[:n] > 0)
    ax.plot(f[:n][ok], amp[:n][ok], color="C0", linewidth=1, label="spectrogram")
    for name, label, colour, style in lines:
        v = getattr(plots.levels, name)
        if v is not None and v > 0:
            v = float(v)
            ax.axhline(v, color=colour, linestyle=style, linewidth=1,
                       label=f"{label} = {v:.3g} {unit}")
    ax.legend(loc="best", fontsize="small")


_HIST_UNITS = {"DSNU": ("e⁻", "deviation from the mean dark level"),
               "PRNU": ("%", "deviation from the mean signal, high-pass filtered")}


def _edges(x: np.ndarray) -> np.ndarray:
    width = float(x[1] - x[0]) if x.size > 1 else 1.0
    return np.append(x, x[-1] + width)


def _draw_histogram(fig: Any, emva: EmvaSummary, *, what: str) -> None:
    """Release 3.1 sec. 8.3: the logarithmic histogram of the DSNU (dark) or PRNU image with
    the normal distribution of the same mean and standard deviation."""
    h = getattr(_spatial(emva).histograms, what)
    x, count, model = _floats(h.x), _floats(h.count), _floats(h.model)
    unit, label = _HIST_UNITS[what]
    ax = _axes(fig, f"Logarithmic histogram {what}", f"{label} [{unit}]",
               "pixels per bin")
    _log(ax, "y")
    if x.size and count.size == x.size:
        edges = _edges(x)
        ax.stairs(count, edges, color="C0", label="pixels")
        if model.size == x.size:
            centre = 0.5 * (edges[:-1] + edges[1:])
            ok = np.isfinite(model) & (model >= 0.1)
            ax.plot(centre[ok], model[ok], color="C3", linewidth=1,
                    label="normal distribution, same mean and deviation")
        ax.set_ylim(bottom=0.5)
    ax.legend(loc="best", fontsize="small")


def _draw_accumulated(fig: Any, emva: EmvaSummary, *, what: str) -> None:
    """Release 3.1 sec. 8.3: the accumulated histogram, the percentage of pixels that deviate
    from the mean by x or more."""
    h = getattr(_spatial(emva).accumulated, what)
    x, percent = _floats(h.x), _floats(h.percent)
    unit, label = _HIST_UNITS[what]
    ax = _axes(fig, f"Accumulated histogram {what}", f"|{label}| x [{unit}]",
               "pixels deviating by x or more [%]")
    _log(ax, "y")
    if x.size and percent.size == x.size:
        ok = np.isfinite(percent) & (percent > 0)
        ax.step(x[ok], percent[ok], where="post", color="C0", label="pixels")
    ax.legend(loc="best", fontsize="small")


def _draw_profiles(fig: Any, emva: EmvaSummary, *, which: str) -> None:
    """Release 3.1 sec. 8.4: the horizontal and vertical profiles of the bright less the dark
    (or the dark) average image: mean, minimum, maximum and middle line across each axis."""
    profiles = _spatial(emva).profiles
    unit = "μ_y − μ_y.dark [DN]" if which == "bright" else "μ_y.dark [DN]"
    title = ("bright average image less the dark one" if which == "bright"
             else "dark average image")
    fig.suptitle(f"Profiles of the {title}")
    for i, (direction, across) in enumerate((("horizontal", "column"), ("vertical", "row"))):
        p = getattr(profiles, f"{which}_{direction}")
        index = _floats(p.index)
        ax = fig.add_subplot(1, 2, i + 1)
        ax.set_title(f"{direction} (each {across})")
        ax.set_xlabel(f"{across} index")
        ax.set_ylabel(unit)
        ax.grid(True, alpha=0.3)
        for name, label, colour in (("max", "maximum", "C3"), ("mean", "mean", "C0"),
                                    ("mid", "middle line", "C2"), ("min", "minimum", "C1")):
            v = _floats(getattr(p, name))
            if v.size == index.size and v.size:
                ax.plot(index, v, color=colour, linewidth=1, label=label)
        ax.legend(loc="best", fontsize="small")


@dataclass(frozen=True)
class _Plot:
    name: str
    needs: Callable[[EmvaSummary], str | None]
    draw: Callable[[Any, EmvaSummary], None]
    size: tuple[float, float] = (7.0, 4.8)


def _partial(draw: Callable[..., None], **kw: Any) -> Callable[[Any, EmvaSummary], None]:
    def bound(fig: Any, emva: EmvaSummary) -> None:
        draw(fig, emva, **kw)
    return bound


_ALL: tuple[_Plot, ...] = (
    _Plot("photon_transfer", _needs_points, _draw_ptc),
    _Plot("snr", _needs_snr, _draw_snr),
    _Plot("linearity", _needs_points, _draw_linearity),
    _Plot("linearity_deviation", _needs_points, _draw_deviation),
    _Plot("dark_signal", _needs_dark, _partial(_draw_dark, variance=False)),
    _Plot("dark_variance", _needs_dark, _partial(_draw_dark, variance=True)),
    *(_Plot(f"spectrogram_{what.lower()}_{direction}", _needs_spatial,
            _partial(_draw_spectrogram, what=what, direction=direction))
      for what in ("DSNU", "PRNU") for direction in ("horizontal", "vertical")),
    *(_Plot(f"histogram_{what.lower()}", _needs_spatial, _partial(_draw_histogram, what=what))
      for what in ("DSNU", "PRNU")),
    *(_Plot(f"accumulated_histogram_{what.lower()}", _needs_spatial,
            _partial(_draw_accumulated, what=what)) for what in ("DSNU", "PRNU")),
    *(_Plot(f"profiles_{which}", _needs_spatial, _partial(_draw_profiles, which=which),
            size=(11.0, 4.8)) for which in ("bright", "dark")),
)
#: every plot of a datasheet, in the standard's order (file stems in ``plots/``)
PLOTS: tuple[str, ...] = tuple(p.name for p in _ALL)


def draw_plot(name: str, fig: Any, emva: EmvaSummary) -> None:
    """Draw the datasheet plot ``name`` (one of :data:`PLOTS`) of ``emva`` on the matplotlib
    figure ``fig`` (what the files hold; the tests read the drawn data back)."""
    by_name = {p.name: p for p in _ALL}
    if name not in by_name:
        raise KeyError(f"no datasheet plot {name!r}; the plots are {', '.join(PLOTS)}")
    by_name[name].draw(fig, emva)


@dataclass(frozen=True)
class PlotPlan:
    """The plots the figures allow (``drawn``, in :data:`PLOTS` order) and the others with
    the reason each is skipped (``skipped``: ``(name, reason)``)."""

    drawn: tuple[str, ...]
    skipped: tuple[tuple[str, str], ...]

    def to_dict(self) -> dict[str, Any]:
        return {"drawn": list(self.drawn),
                "skipped": [{"plot": n, "reason": r} for n, r in self.skipped]}


def plot_plan(emva: EmvaSummary) -> PlotPlan:
    """Which plots of :data:`PLOTS` the figures ``emva`` have the data for (no plotting
    package needed)."""
    drawn, skipped = [], []
    for p in _ALL:
        why = p.needs(emva)
        if why is None:
            drawn.append(p.name)
        else:
            skipped.append((p.name, why))
    return PlotPlan(tuple(drawn), tuple(skipped))


def _render(plot: _Plot, emva: EmvaSummary, folder: Path) -> list[Path]:
    """Draw one plot and save it in every format of :data:`PLOT_FORMATS`."""
    from matplotlib import rc_context, style
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    # matplotlib's own defaults whatever a matplotlibrc says: the same figures give the same files
    with style.context("default"), rc_context({"svg.hashsalt": _SVG_SALT, "font.size": 9}):
        fig = Figure(figsize=plot.size, dpi=_DPI, layout="constrained")
        FigureCanvasAgg(fig)
        plot.draw(fig, emva)
        out = []
        for fmt in PLOT_FORMATS:
            path = folder / f"{plot.name}.{fmt}"
            # no date in the SVG: the same figures give the same file
            fig.savefig(path, format=fmt, metadata={"Date": None} if fmt == "svg" else None)
            out.append(path)
            fig.set_layout_engine("none")   # laid out once: the other formats keep its places
    return out


# --------------------------------------------------------------------------------------------
# the set of files
# --------------------------------------------------------------------------------------------
def write_datasheet(emva: EmvaSummary, out_dir: str | os.PathLike, *,
                    inputs: Iterable[str | os.PathLike] = (), plots: bool = True) -> list[Path]:
    """Write ``datasheet.csv``, ``datasheet.json`` and (with ``plots``) ``plots/*.png`` and
    ``plots/*.svg`` of the EMVA 1288 figures ``emva`` (module docstring) into ``out_dir`` as
    one set: an earlier datasheet there is replaced whole (its plots folder too, so no plot of
    it is left beside the new ones), other files are left alone, and a failure leaves the
    earlier set untouched. ``inputs`` (the files the figures were read from) must not be
    overwritten. Returns the paths written (in ``out_dir``): the CSV, the JSON, then the plots
    in :data:`PLOTS` order.

    Raises
    ------
    MissingExtra
        ``plots`` and matplotlib is not installed (``pip install 'ccdcore[datasheet]'``).
    CcdError
        An output is (or is inside) an input, or not writable.
    """
    from ..io.frames import atomic_write_text, output_set

    if plots:
        require_extra("matplotlib", "datasheet", "drawing the datasheet's plots")
    plan = plot_plan(emva)
    folder = Path(out_dir)
    csv_text = datasheet_csv(emva)
    doc = datasheet_document(emva, plan if plots else None)
    json_text = json.dumps(doc, indent=2, allow_nan=False, ensure_ascii=False) + "\n"
    by_name = {p.name: p for p in _ALL}
    written: list[Path] = []
    with output_set(folder, inputs=inputs, replaces=tuple(OUTPUTS)) as tmp:
        atomic_write_text(tmp / CSV_FILE, csv_text)
        atomic_write_text(tmp / JSON_FILE, json_text)
        if plots and plan.drawn:
            (tmp / PLOTS_FOLDER).mkdir()
            for name in plan.drawn:
                written += _render(by_name[name], emva, tmp / PLOTS_FOLDER)
    return [folder / CSV_FILE, folder / JSON_FILE] + [
        folder / PLOTS_FOLDER / p.name for p in written]
