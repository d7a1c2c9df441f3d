"""The photon-transfer plots: pure data functions and the figures built once.

The app's Photon transfer page and the report's noise section draw the same figures from here
(the app's Photon transfer page and Walkthrough import it); Bokeh and pandas only.

Every number drawn comes from ccdcore's photon-transfer results (:class:`~ccdcore.noise.PtcPoint`,
:class:`~ccdcore.noise.PhotonTransfer`): the points (eqs. 37, 38, 40 of Healey & Kondepudy 1994),
the fitted line σ²_N = A·μ + σ²_C (eq. 41) and its 1-σ band from the covariance of (A, σ²_C)
(eq. 66, :meth:`ccdcore.noise.LineFit.predict`). The plots only change units for display
(σ = √σ²_N on the log-log view, residuals in units of each point's standard error).

The figures are plain Bokeh, built once per page (:class:`PtcFigures`); a refit replaces their
sources' data. (HoloViews DynamicMaps did the same at 0.1–0.3 s of server time per plot and
update; plain sources cost milliseconds; docs/notes.md.) The data functions are tested without
a browser.

Public objects
--------------
USED_COLOR, EXCLUDED_COLOR, FIT_COLOR
    The colours of used points, excluded points and the fitted model.
points_table(points, result=None)
    The points as a DataFrame (level, μ, σ̂²_N, its error, σ̂_N, status, reason, residual/σ).
mu_grid(points, n=200, log=False)
    Abscissae for drawing the model over the measured range of μ.
transfer_columns(points, result=None), residual_columns(result), loglog_columns(points, result)
    What each plot draws, as source columns (band and line, used and excluded points, curves).
residual_limit(columns), loglog_limits(columns)
    The y ranges of the residual and the log-log plots (the residuals' from the used levels).
clip_residuals(columns, limit)
    The excluded levels' residuals split into those inside ±limit and those drawn clipped at the
    plot's edge (triangles pointing off the plot).
PtcFigures
    The three figures with their sources; ``update(points, result)``.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from ccdcore.noise import PhotonTransfer, PtcPoint

__all__ = ["USED_COLOR", "EXCLUDED_COLOR", "FIT_COLOR", "points_table", "mu_grid",
           "transfer_columns", "residual_columns", "loglog_columns", "residual_limit",
           "clip_residuals", "loglog_limits", "PtcFigures"]

#: colour of the levels used by the fit
USED_COLOR = "#1f5f99"
#: colour of the levels left out (drawn hollow)
EXCLUDED_COLOR = "#8c959f"
#: colour of the fitted model and its confidence band
FIT_COLOR = "#d9622b"

_HEIGHT = 380

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


#: columns of the point sources (one per group: used, excluded)
_POINT_COLUMNS = ("level", "mu", "err", "lo", "hi", "n_pairs", "status", "reason")


def _point_columns(df: pd.DataFrame, y: str, err: str) -> dict[str, dict[str, list]]:
    """The used and the excluded points of ``df`` as Bokeh source columns: ``mu``, ``y`` (named
    as given), ``err`` (its 1-σ error), ``lo``/``hi`` (the error bar's ends) and the hover
    columns ``level``, ``n_pairs``, ``status``, ``reason``."""
    out = {}
    for name, used in (("used", True), ("excluded", False)):
        part = df[(df["used"] == used) & np.isfinite(df[y])]
        value, error = part[y].to_numpy(float), part[err].to_numpy(float)
        out[name] = {"level": part["level"].tolist(), "mu": part["mu"].to_numpy(float),
                     y: value, "err": error, "lo": value - error, "hi": value + error,
                     "n_pairs": part["n_pairs"].tolist(), "status": part["status"].tolist(),
                     "reason": part["reason"].tolist()}
    return out


def transfer_columns(points: Sequence[PtcPoint], result: PhotonTransfer | None = None
                     ) -> dict[str, dict[str, Any]]:
    """What the photon-transfer plot draws (eq. 41 of Healey & Kondepudy 1994), as source columns.

    ``"band"``: ``mu``, ``var`` (the line σ²_N = A·μ + σ²_C) and ``lower``/``upper`` (its 1-σ
    band from :meth:`~ccdcore.noise.LineFit.predict`), empty without a fit; ``"used"`` and
    ``"excluded"``: the points σ̂²_N (``var``) against μ with their standard errors (√eq. 40), the
    excluded ones with the reason in ``reason`` (see :func:`_point_columns`).
    """
    df = points_table(points, result)
    if result is not None:
        grid = mu_grid(points)
        value, std = result.fit.predict(grid)
    else:
        grid = value = std = np.empty(0)
    return {"band": {"mu": grid, "var": value, "lower": value - std, "upper": value + std},
            **_point_columns(df, "var", "var_err")}


def residual_columns(result: PhotonTransfer | None) -> dict[str, dict[str, Any]]:
    """The residuals (σ̂²_N − A·μ − σ²_C)/σ of every level (σ its ``var_err``) with a ±1 bar, as
    ``"used"``/``"excluded"`` source columns (``residual``); none without a fit."""
    df = points_table(result.points if result is not None else (), result)
    df = df.assign(unit=np.where(np.isfinite(df["residual"]), 1.0, np.nan))
    return _point_columns(df, "residual", "unit")


def residual_limit(columns: Mapping[str, Mapping[str, Any]]) -> float:
    """The residual plot's half height: ±3.8, or the largest residual of a *used* level plus 1.2.

    The excluded levels do not widen it: a level beyond saturation can be millions of σ off the
    line, and an axis scaled to it would flatten the used levels' residuals to zero. Those are
    drawn clipped at the edge (:func:`clip_residuals`)."""
    values = np.asarray(columns["used"]["residual"], float)
    values = values[np.isfinite(values)]
    return max(3.8, float(np.abs(values).max()) + 1.2) if values.size else 3.8


#: where a clipped residual is drawn, as a fraction of the plot's half height
CLIP_AT = 0.92


def clip_residuals(columns: Mapping[str, Mapping[str, Any]], limit: float
                   ) -> dict[str, dict[str, Any]]:
    """The excluded levels of ``columns`` (:func:`residual_columns`) against the half height
    ``limit`` (:func:`residual_limit`).

    Returns ``"excluded"``: those with |residual| ≤ ``limit``, drawn as they are (same columns);
    ``"clipped"``: the others, drawn at ``y`` = ±``CLIP_AT``·``limit`` with ``marker``
    ``"triangle"`` (above the plot) or ``"inverted_triangle"`` (below), keeping their true
    ``residual`` (and ``level``, ``mu``, ``n_pairs``, ``status``, ``reason``) for the hover.
    """
    ex = columns["excluded"]
    r = np.asarray(ex["residual"], float)
    inside = np.abs(r) <= limit
    keep = {k: (np.asarray(v)[inside] if isinstance(v, np.ndarray) else
                [x for x, ok in zip(v, inside) if ok]) for k, v in ex.items()}
    out = ~inside
    clipped = {"level": [x for x, o in zip(ex["level"], out) if o],
               "mu": np.asarray(ex["mu"], float)[out],
               "residual": r[out],
               "y": np.sign(r[out]) * CLIP_AT * limit,
               "marker": ["triangle" if v > 0 else "inverted_triangle" for v in r[out]],
               "n_pairs": [x for x, o in zip(ex["n_pairs"], out) if o],
               "status": [x for x, o in zip(ex["status"], out) if o],
               "reason": [x for x, o in zip(ex["reason"], out) if o]}
    return {"excluded": keep, "clipped": clipped}


def loglog_columns(points: Sequence[PtcPoint], result: PhotonTransfer | None = None
                   ) -> dict[str, dict[str, Any]]:
    """The EMVA 1288 view as source columns: the points σ̂_N = √σ̂²_N (``sigma``, DN) with
    ``err`` = var_err/(2σ̂_N) (first order) against μ (only μ > 0 and σ̂²_N > 0 can be drawn on
    log axes); with a fit the model √(A·μ + σ²_C) (``"model"``), the read-noise floor √σ²_C
    (``"floor"``, when σ²_C > 0) and the shot-noise asymptote √(A·μ) (``"shot"``, when A > 0),
    each ``mu``/``sigma``; the curves cross at μ = σ²_C/A."""
    positive = [p for p in points if p.mu > 0 and p.var > 0]
    df = points_table(positive, result)
    empty = {"mu": np.empty(0), "sigma": np.empty(0)}
    curves = {"model": empty, "floor": empty, "shot": empty}
    if result is not None:
        grid = mu_grid(positive, log=True)
        curves["model"] = {"mu": grid,
                           "sigma": np.sqrt(np.maximum(np.asarray(result.sigma_n2(grid)), 0.0))}
        if result.sigma_c2 > 0:
            curves["floor"] = {"mu": grid, "sigma": np.full_like(grid, math.sqrt(result.sigma_c2))}
        if result.A > 0:
            curves["shot"] = {"mu": grid, "sigma": np.sqrt(result.A * grid)}
    return {**curves, **_point_columns(df, "sigma", "sigma_err")}


def loglog_limits(columns: Mapping[str, Mapping[str, Any]]) -> tuple[float, float] | None:
    """The log-log plot's σ range: from a quarter of the lowest noise shown (the points and the
    read-noise floor) to 1.6 times the highest point, so the shot-noise asymptote does not squash
    the points; None when nothing is drawn."""
    points = np.concatenate([np.asarray(columns[k]["sigma"], float) for k in ("used",
                                                                            "excluded")])
    points = points[np.isfinite(points) & (points > 0)]
    floor = np.asarray(columns["floor"]["sigma"], float)
    lows = [float(points.min())] if points.size else []
    if floor.size:
        lows.append(float(floor[0]))
    if not lows:
        return None
    high = float(points.max()) if points.size else max(lows)
    return 0.25 * min(lows), 1.6 * high


_XLABEL = "\u03bc \u2212 b\u2080 (DN)"
_TOOLS = "pan,wheel_zoom,box_zoom,reset,save"


def _figure(title: str, ylabel: str, height: int, **kw: Any) -> Any:
    from bokeh.plotting import figure

    fig = figure(title=title, height=height, sizing_mode="stretch_width", tools=_TOOLS,
                 x_axis_label=_XLABEL, y_axis_label=ylabel, output_backend="canvas", **kw)
    fig.toolbar.logo = None
    return fig


def _point_renderers(fig: Any, sources: Mapping[str, Any], y: str, ylabel: str,
                     legend: list[Any]) -> list[Any]:
    """Error bars and markers of the used (filled) and excluded (hollow, grey) levels."""
    from bokeh.models import HoverTool, LegendItem

    marks = []
    for name, color, label in (("used", USED_COLOR, "used levels"),
                               ("excluded", EXCLUDED_COLOR, "excluded levels")):
        src = sources[name]
        bars = fig.segment(x0="mu", y0="lo", x1="mu", y1="hi", source=src, line_color=color,
                           line_width=1.5)
        if name == "used":
            dots = fig.scatter("mu", y, source=src, size=8, color=color)
        else:
            dots = fig.scatter("mu", y, source=src, size=10, fill_alpha=0.0, line_color=color,
                               line_width=2)
        legend.append(LegendItem(label=label, renderers=[bars, dots]))
        marks.append(dots)
    fig.add_tools(HoverTool(renderers=marks, tooltips=[
        ("level", "@level"), (_XLABEL, "@mu{0.000}"), (ylabel, f"@{{{y}}}{{0.0000}}"),
        ("\u00b1", "@err{0.0000}"), ("pairs", "@n_pairs"), ("status", "@status"),
        ("reason", "@reason")]))
    return marks


class PtcFigures:
    """The three photon-transfer plots, built once as Bokeh figures; :meth:`update`
    gives them new points and fit by replacing their sources' data (no new figure: the browser
    only redraws).

    Attributes
    ----------
    transfer, residual, loglog
        The figures: σ̂²_N against μ with the fitted line and its 1-σ band (eq. 41); the
        residuals in units of each point's standard error with lines at 0, ±1 and ±3 (the robust
        mode's limit), scaled to the used levels (excluded ones beyond it as triangles at the
        edge); temporal noise against signal on log axes (EMVA 1288 style) with the
        model, the read-noise floor and the shot-noise asymptote.
    sources
        ``(figure name, layer) -> ColumnDataSource``.
    """

    def __init__(self, height: int = _HEIGHT, loglog_height: int = 600):
        from bokeh.models import ColumnDataSource, Legend, LegendItem, Range1d, Span

        cols = transfer_columns(())
        self.sources: dict[tuple[str, str], Any] = {}

        def src(fig: str, layer: str, data: Mapping[str, Any]) -> Any:
            self.sources[(fig, layer)] = ColumnDataSource(dict(data))
            return self.sources[(fig, layer)]

        # ---- sigma^2_N against mu
        t = _figure("Photon transfer: noise variance against mean signal",
                    "\u03c3\u0302\u00b2_N (DN\u00b2)", height)
        band = src("transfer", "band", cols["band"])
        items: list[Any] = []
        area = t.varea(x="mu", y1="lower", y2="upper", source=band, fill_color=FIT_COLOR,
                       fill_alpha=0.25)
        line = t.line("mu", "var", source=band, line_color=FIT_COLOR, line_width=2)
        items += [LegendItem(label="fit \u00b11\u03c3", renderers=[area]),
                  LegendItem(label="\u03c3\u00b2_N = A\u00b7\u03bc + \u03c3\u00b2_C",
                             renderers=[line])]
        _point_renderers(t, {k: src("transfer", k, cols[k]) for k in ("used", "excluded")},
                         "var", "\u03c3\u0302\u00b2_N (DN\u00b2)", items)
        t.add_layout(Legend(items=items, location="top_left"))
        self.transfer = t

        # ---- residuals
        rcols = residual_columns(None)
        r = _figure("Residuals in units of each point's standard error", "residual / \u03c3",
                    220, y_range=Range1d(-3.8, 3.8), x_range=t.x_range)
        for k, dash in ((0, "solid"), (1, "dashed"), (3, "dotted")):
            for sign in ((1,) if k == 0 else (1, -1)):
                r.add_layout(Span(location=sign * k, dimension="width",
                                  line_color="#444444" if k == 0 else "#999999",
                                  line_dash=dash, line_width=1))
        _point_renderers(r, {k: src("residual", k, rcols[k]) for k in ("used", "excluded")},
                         "residual", "residual / \u03c3", [])
        # excluded levels beyond the axis: a hollow triangle at the edge, the true value on hover
        from bokeh.core.properties import field
        from bokeh.models import HoverTool

        clipped = r.scatter("mu", "y", source=src("residual", "clipped",
                                                  clip_residuals(rcols, 3.8)["clipped"]),
                            marker=field("marker"), size=11, fill_alpha=0.0,
                            line_color=EXCLUDED_COLOR, line_width=2)
        r.add_tools(HoverTool(renderers=[clipped], tooltips=[
            ("level", "@level"), (_XLABEL, "@mu{0.000}"),
            ("residual / \u03c3", "@residual{0.0000} (off the plot)"), ("pairs", "@n_pairs"),
            ("status", "@status"), ("reason", "@reason")]))
        self.residual = r

        # ---- log-log
        lcols = loglog_columns(())
        lg = _figure("Temporal noise against signal (log-log, EMVA 1288 style)",
                     "\u03c3\u0302_N (DN)", loglog_height, x_axis_type="log", y_axis_type="log",
                     y_range=Range1d(0.1, 10.0))
        litems: list[Any] = []
        for key, label, style in (
                ("model", "\u221a(A\u00b7\u03bc + \u03c3\u00b2_C)",
                 dict(line_color=FIT_COLOR, line_width=2)),
                ("floor", "read-noise floor \u221a\u03c3\u00b2_C",
                 dict(line_color="#6f42c1", line_dash="dashed", line_width=1.5)),
                ("shot", "shot noise \u221a(A\u00b7\u03bc)",
                 dict(line_color="#2a9d8f", line_dash="dotted", line_width=2))):
            curve = lg.line("mu", "sigma", source=src("loglog", key, lcols[key]), **style)
            litems.append(LegendItem(label=label, renderers=[curve]))
        _point_renderers(lg, {k: src("loglog", k, lcols[k]) for k in ("used", "excluded")},
                         "sigma", "\u03c3\u0302_N (DN)", litems)
        lg.add_layout(Legend(items=litems, location="bottom_right"))
        self.loglog = lg
        for fig in (t, r, lg):
            fig.xgrid.grid_line_alpha = fig.ygrid.grid_line_alpha = 0.6

    def update(self, points: Sequence[PtcPoint], result: PhotonTransfer | None) -> None:
        """Draw ``points`` and the fit ``result`` (None: the points only)."""
        residual = residual_columns(result)
        limit = residual_limit(residual)              # from the used levels only
        data = {"transfer": transfer_columns(points, result),
                "residual": {**residual, **clip_residuals(residual, limit)},
                "loglog": loglog_columns(points, result)}
        for (fig, layer), source in self.sources.items():
            source.data = dict(data[fig][layer])
        self.residual.y_range.update(start=-limit, end=limit)
        limits = loglog_limits(data["loglog"])
        if limits is not None:
            self.loglog.y_range.update(start=limits[0], end=limits[1])
        for fig in (self.transfer, self.loglog):   # no legend entry for what is not drawn
            for item in fig.legend[0].items:
                item.visible = any(len(r.data_source.data["mu"]) for r in item.renderers)

