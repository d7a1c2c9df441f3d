"""Pure plot-building functions of the Photon transfer page (no widgets, no state).

Every function takes ccdcore's photon-transfer results (:class:`~ccdcore.noise.PtcPoint`,
:class:`~ccdcore.noise.PhotonTransfer`) and returns a HoloViews element or overlay, so the
plotting pipeline is tested without a browser. Every number drawn comes from ccdcore: the points
(eqs. 37, 38, 40 of Healey & Kondepudy 1994), the fitted line σ²_N = A·μ + σ²_C (eq. 41) and its
1-σ band from the covariance of (A, σ²_C) (eq. 66, :meth:`ccdcore.noise.LineFit.predict`). The
plots only change units for display (σ = √σ²_N on the log-log view, residuals in units of each
point's standard error).

Public objects
--------------
USED_COLOR, EXCLUDED_COLOR, FIT_COLOR
    The colours of used points, excluded points and the fitted model.
points_table(points, result=None)
    The points as a DataFrame (level, μ, σ̂²_N, its error, σ̂_N, status, reason, residual/σ).
mu_grid(points, n=200, log=False)
    Abscissae for drawing the model over the measured range of μ.
transfer_plot(points, result=None)
    σ̂²_N against μ: points with error bars (excluded ones hollow and grey, with the reason in
    the hover), the fitted line and its 1-σ confidence band.
residual_plot(result)
    (σ̂²_N − fit)/σ against μ with reference lines at 0, ±1 and ±3.
loglog_plot(points, result=None, height=600)
    The EMVA 1288 view: temporal noise σ̂_N (DN) against μ (DN) on log axes, with the model
    √(A·μ + σ²_C), the read-noise floor √σ²_C and the shot-noise asymptote √(A·μ).
roi_box(x, y, w, h)
    The ROI ``(x, y, w, h)`` as an ``hv.Rectangles`` outline in the pixel coordinates of
    :func:`app.plots.image_element`.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import holoviews as hv
import numpy as np
import pandas as pd
from numpy.typing import NDArray

from ccdcore.noise import PhotonTransfer, PtcPoint

__all__ = ["USED_COLOR", "EXCLUDED_COLOR", "FIT_COLOR", "points_table", "mu_grid",
           "transfer_plot", "residual_plot", "loglog_plot", "roi_box",
           "hide_empty_legend_items"]

#: colour of the levels used by the fit
USED_COLOR = "#1f5f99"
#: colour of the levels left out (drawn hollow)
EXCLUDED_COLOR = "#8c959f"
#: colour of the fitted model and its confidence band
FIT_COLOR = "#d9622b"

_HEIGHT = 380
_TOOLS = ["hover"]

_COLUMNS = ["level", "mu", "var", "var_err", "sigma", "sigma_err", "n_pairs", "n_pixels",
            "used", "status", "reason", "residual"]
_DTYPES = {"level": "int64", "mu": "float64", "var": "float64", "var_err": "float64",
           "sigma": "float64", "sigma_err": "float64", "n_pairs": "int64", "n_pixels": "int64",
           "used": "bool", "status": "object", "reason": "object", "residual": "float64"}


def _status(p: PtcPoint) -> str:
    return "used" if p.used else "excluded"


def points_table(points: Sequence[PtcPoint], result: PhotonTransfer | None = None
                 ) -> pd.DataFrame:
    """One row per light level, display-ready.

    Columns: ``level``, ``mu`` (μ̂ − b₀, DN), ``var`` (σ̂²_N, DN²), ``var_err`` (its standard
    error, √eq. 40), ``sigma`` = √σ̂²_N and ``sigma_err`` = var_err/(2σ̂_N) (DN, first-order),
    ``n_pairs``, ``n_pixels``, ``used``, ``status`` (``"used"``/``"excluded"``), ``reason``
    (``""`` when used) and ``residual`` = (σ̂²_N − A·μ − σ²_C)/var_err when ``result`` is given
    (NaN otherwise).
    """
    rows = []
    for p in points:
        sigma = math.sqrt(p.var) if p.var > 0 else float("nan")
        sigma_err = p.var_err / (2.0 * sigma) if sigma > 0 else float("nan")
        if result is not None and p.var_err > 0:
            residual = (p.var - float(result.sigma_n2(p.mu))) / p.var_err
        else:
            residual = float("nan")
        rows.append({"level": int(p.level), "mu": float(p.mu), "var": float(p.var),
                     "var_err": float(p.var_err), "sigma": sigma, "sigma_err": sigma_err,
                     "n_pairs": int(p.n_pairs), "n_pixels": int(p.n_pixels),
                     "used": bool(p.used), "status": _status(p), "reason": p.reason or "",
                     "residual": residual})
    return pd.DataFrame(rows, columns=_COLUMNS).astype(_DTYPES)  # typed even when empty


def mu_grid(points: Sequence[PtcPoint], n: int = 200, log: bool = False) -> NDArray[np.float64]:
    """``n`` abscissae spanning the points' μ (from 0 on a linear axis, 5 % margins).

    With ``log`` the grid is geometric from the power of ten below the smallest positive μ to 1.5
    times the largest; an empty or non-positive set gives 1..10 DN.
    """
    mus = np.array([p.mu for p in points], dtype=np.float64)
    mus = mus[np.isfinite(mus)]
    if log:
        pos = mus[mus > 0]
        if pos.size == 0:
            return np.geomspace(1.0, 10.0, n)
        lo, hi = 10.0 ** math.floor(math.log10(pos.min() / 1.5)), pos.max() * 1.5
        if not hi > lo:
            lo, hi = lo / 10.0, hi * 10.0
        return np.geomspace(lo, hi, n)
    if mus.size == 0:
        return np.linspace(0.0, 1.0, n)
    lo, hi = min(0.0, float(mus.min())), float(mus.max())
    span = hi - lo if hi > lo else 1.0
    return np.linspace(lo, hi + 0.05 * span, n)


def _point_layers(df: pd.DataFrame, x: str, y: str, err: str, xlabel: str, ylabel: str
                  ) -> list[hv.Element]:
    """Error bars and markers of the used (filled) and excluded (hollow, grey) points.

    Always the same four layers (ErrorBars and Scatter of the used levels, then of the excluded
    ones), empty when no level is in the group: a plot fed through a stream keeps its Bokeh
    glyphs and only their data change (:func:`hide_empty_legend_items` hides the empty group's
    legend entry).
    """
    layers: list[hv.Element] = []
    kx = hv.Dimension(x, label=xlabel)
    vy = hv.Dimension(y, label=ylabel)
    vdims = [vy, hv.Dimension(err, label="\u00b1 (1\u03c3)"), "level", "n_pairs", "status",
             "reason"]
    for used, color, name in ((True, USED_COLOR, "used levels"),
                              (False, EXCLUDED_COLOR, "excluded levels")):
        part = df[df["used"] == used]
        bars = hv.ErrorBars(part, kdims=[kx], vdims=[vy, err], label=name).opts(
            color=color, line_width=1.5, lower_head=None, upper_head=None)
        marks = hv.Scatter(part, kdims=[kx], vdims=vdims, label=name)
        if used:
            marks = marks.opts(color=color, size=8, marker="circle")
        else:
            marks = marks.opts(color=EXCLUDED_COLOR, fill_alpha=0.0, line_color=EXCLUDED_COLOR,
                               line_width=2, size=10, marker="circle")
        marks = marks.opts(tools=_TOOLS, hover_tooltips=[
            ("level", "@level"), (xlabel, f"@{{{x}}}{{0.000}}"),
            (ylabel, f"@{{{y}}}{{0.0000}}"), ("\u00b1", f"@{{{err}}}{{0.0000}}"),
            ("pairs", "@n_pairs"), ("status", "@status"), ("reason", "@reason")])
        layers += [bars, marks]
    return layers


def _framewise(layers: list[hv.Element]) -> hv.Overlay:
    """The overlay of ``layers`` with ``framewise=True`` on every layer: a plot fed through a
    stream then fits its axes to each new frame (on the overlay alone the first ranges stay)."""
    return hv.Overlay([layer.opts(framewise=True) for layer in layers])


def hide_empty_legend_items(plot: Any, element: Any) -> None:
    """HoloViews plot hook: hide the legend entries whose glyphs have no data (an empty group of
    levels, the model before a fit), so a plot updated in place never lists what it does not
    draw. HoloViews runs hooks after the first render and after every update."""
    for legend in getattr(plot.state, "legend", []) or []:
        for item in legend.items:
            item.visible = any(len(next(iter(r.data_source.data.values()), ())) > 0
                               for r in item.renderers)


def transfer_plot(points: Sequence[PtcPoint], result: PhotonTransfer | None = None
                  ) -> hv.Overlay:
    """σ̂²_N against μ (the photon-transfer curve, eq. 41 of Healey & Kondepudy 1994).

    Parameters
    ----------
    points
        The measured levels (normally ``result.points``); ``used`` and ``reason`` decide how each
        is drawn: used levels filled, excluded levels hollow and grey with the reason in the hover.
    result
        The fit. When given, the line σ²_N = A·μ + σ²_C (in the black-level-corrected μ the fit
        uses) and its 1-σ confidence band ``hv.Spread`` from
        :meth:`~ccdcore.noise.LineFit.predict` are drawn under the points.

    Returns
    -------
    holoviews.Overlay
        Spread (band) and Curve (line), empty without a fit, then ErrorBars and Scatter for the
        used and the excluded levels (empty when a group has none): the same layers whatever the
        data, so the page updates one plot in place.
    """
    df = points_table(points, result)
    xlabel, ylabel = "\u03bc \u2212 b\u2080 (DN)", "\u03c3\u0302\u00b2_N (DN\u00b2)"
    if result is not None:
        grid = mu_grid(points)
        value, std = result.fit.predict(grid)
    else:
        grid = value = std = np.empty(0)
    band = pd.DataFrame({"mu": grid, "var": value, "std": std})
    layers: list[hv.Element] = [
        hv.Spread(band, kdims=["mu"], vdims=["var", "std"], label="fit \u00b11\u03c3").opts(
            color=FIT_COLOR, alpha=0.25, line_alpha=0),
        hv.Curve(band, kdims=["mu"], vdims=["var"],
                 label="\u03c3\u00b2_N = A\u00b7\u03bc + \u03c3\u00b2_C").opts(
            color=FIT_COLOR, line_width=2)]
    layers += _point_layers(df, "mu", "var", "var_err", xlabel, ylabel)
    title = "Photon transfer: noise variance against mean signal"
    return _framewise(layers).opts(
        responsive=True, height=_HEIGHT, title=title, xlabel=xlabel, ylabel=ylabel,
        legend_position="top_left", show_grid=True, framewise=True,
        hooks=[hide_empty_legend_items])


def residual_plot(result: PhotonTransfer | None) -> hv.Overlay:
    """Residuals (σ̂²_N − A·μ − σ²_C)/σ of every level (σ = its ``var_err``), against μ.

    Used levels are filled, excluded ones hollow and grey; each has an error bar of ±1 (its own
    standard error in these units). Reference lines: 0 (solid), ±1 (dashed) and ±3 (dotted, the
    robust mode's limit). Without a fit (``None``) the point layers are empty.
    """
    df = points_table(result.points if result is not None else (), result)
    df = df.assign(unit=np.where(np.isfinite(df["residual"]), 1.0, np.nan))
    xlabel, ylabel = "\u03bc \u2212 b\u2080 (DN)", "residual / \u03c3"
    layers: list[hv.Element] = [hv.HLine(0.0).opts(color="#444444", line_width=1)]
    for k, dash in ((1, "dashed"), (3, "dotted")):
        for sign in (1, -1):
            layers.append(hv.HLine(sign * k).opts(color="#999999", line_dash=dash,
                                                  line_width=1))
    layers += _point_layers(df, "mu", "residual", "unit", xlabel, ylabel)
    finite = df["residual"][np.isfinite(df["residual"])]
    top = max(3.8, float(finite.abs().max()) + 1.2) if len(finite) else 3.8
    return _framewise(layers).opts(
        responsive=True, height=220, title="Residuals in units of each point's standard error",
        xlabel=xlabel, ylabel=ylabel, ylim=(-top, top), show_legend=False, show_grid=True,
        framewise=True)


def loglog_plot(points: Sequence[PtcPoint], result: PhotonTransfer | None = None, *,
                height: int = 600) -> hv.Overlay:
    """The EMVA 1288 style view: temporal noise σ̂_N = √σ̂²_N (DN) against μ (DN), log axes.

    Only levels with μ > 0 can be drawn on a log axis. With ``result``: the model
    √(A·μ + σ²_C), the read-noise floor √σ²_C (horizontal, dashed) and the shot-noise asymptote
    √(A·μ) (dotted); the two cross at μ = σ²_C/A. The three curves are always there (empty
    without a fit, or when σ²_C or A is not positive), like the points' layers, so the page
    updates the plot in place.
    """
    positive = [p for p in points if p.mu > 0 and p.var > 0]
    df = points_table(positive, result)
    xlabel, ylabel = "\u03bc \u2212 b\u2080 (DN)", "\u03c3\u0302_N (DN)"
    empty = np.empty(0)
    grid = mu_grid(positive, log=True) if result is not None else empty
    model = floor = shot = empty
    floor_grid = shot_grid = empty
    if result is not None:
        model = np.sqrt(np.maximum(np.asarray(result.sigma_n2(grid)), 0.0))
        if result.sigma_c2 > 0:
            floor_grid, floor = grid, np.full_like(grid, math.sqrt(result.sigma_c2))
        if result.A > 0:
            shot_grid, shot = grid, np.sqrt(result.A * grid)
    layers: list[hv.Element] = [
        hv.Curve((grid, model), kdims=["mu"], vdims=["sigma"],
                 label="\u221a(A\u00b7\u03bc + \u03c3\u00b2_C)").opts(
            color=FIT_COLOR, line_width=2),
        hv.Curve((floor_grid, floor), kdims=["mu"], vdims=["sigma"],
                 label="read-noise floor \u221a\u03c3\u00b2_C").opts(
            color="#6f42c1", line_dash="dashed", line_width=1.5),
        hv.Curve((shot_grid, shot), kdims=["mu"], vdims=["sigma"],
                 label="shot noise \u221a(A\u00b7\u03bc)").opts(
            color="#2a9d8f", line_dash="dotted", line_width=2)]
    layers += _point_layers(df, "mu", "sigma", "sigma_err", xlabel, ylabel)
    ylim: tuple[float, float] | tuple[None, None] = (None, None)
    lows = [float(s) for s in df["sigma"] if s > 0]
    if result is not None and result.sigma_c2 > 0:
        lows.append(math.sqrt(result.sigma_c2))
    if lows:  # a quarter of the lowest noise shown: the asymptote does not squash the points
        highs = [float(s) for s in df["sigma"] if s > 0] or lows
        ylim = (0.25 * min(lows), 1.6 * max(highs))
    return _framewise(layers).opts(
        responsive=True, height=height, logx=True, logy=True, show_grid=True, ylim=ylim,
        title="Temporal noise against signal (log-log, EMVA 1288 style)", xlabel=xlabel,
        ylabel=ylabel, legend_position="bottom_right", framewise=True,
        hooks=[hide_empty_legend_items])


def roi_box(x: int, y: int, w: int, h: int) -> hv.Rectangles:
    """The ROI ``(x, y, w, h)`` (columns x..x+w−1, rows y..y+h−1) as a rectangle outline.

    Pixel centres are at integer coordinates (:func:`app.plots.image_element`), so the outline
    runs along the pixel edges: from (x − ½, y − ½) to (x + w − ½, y + h − ½).
    """
    x0, y0 = float(x) - 0.5, float(y) - 0.5
    return hv.Rectangles([(x0, y0, x0 + float(w), y0 + float(h))]).opts(
        fill_alpha=0.08, fill_color=FIT_COLOR, line_color=FIT_COLOR, line_width=2,
        line_dash="dashed")
