"""The Response & HDR page's plots: plain Bokeh figures built once and fed in place.

ResponseFigure
    g(z) of every method as lines, the chosen method's 2-sigma band, the simulator's true g
    (dashed) when the session has one.
PoolHistogram
    The relative prediction errors of one pool before and after calibration (Tsin et al. 2001,
    Fig. 3c-d).
tone_map(radiance, stops, curve)
    A radiance plane for display only: gamma 2.2 or logarithmic, ``stops`` of exposure.
histogram(values, bins)
    Counts and edges of finite values, for :class:`PoolHistogram`.
agreement_rows(named), channel_agreement_rows(agreement), pair_rows(agreement, t)
    The prediction agreement of Tsin et al. sec. 4.2 (:mod:`ccdcore.response.agreement`, as
    its records: ``Agreement.summary_record()``) as table rows of text: pooled per method,
    per channel, per pair of neighbouring images (the page's tables and the report's; from
    :mod:`ccdcore_report.agreement`, with ``AGREEMENT_COLUMNS`` and ``dn``).
md_text(text)
    Any text (file names, the library's sentences) as Markdown that shows it literally.
verdict_markdown(verdict), details_markdown(verdict)
    A response verdict in the library's words: its line, then its registration and moving
    pixels, a paragraph each (the Walkthrough); the registration and moving pixels alone, as a
    list (below the Response & HDR page's curves).
VERDICT_ALERTS
    A response verdict's status (:mod:`ccdcore.response.verdict`) -> the alert type that shows
    it: trusted ``success``, doubtful ``warning``, failed ``danger``.
"""
from __future__ import annotations

import re
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from ccdcore_report.agreement import (AGREEMENT_COLUMNS, agreement_rows, channel_agreement_rows,
                                      dn, pair_rows)

__all__ = ["ResponseFigure", "PoolHistogram", "tone_map", "histogram", "TONE_CURVES",
           "METHOD_COLOURS", "hdr_views", "hdr_planes", "agreement_rows",
           "channel_agreement_rows", "pair_rows", "AGREEMENT_COLUMNS", "dn", "md_text",
           "verdict_markdown", "details_markdown", "VERDICT_ALERTS"]

#: display curves of the HDR radiance (the data are never changed)
TONE_CURVES = ("gamma 2.2", "log")
#: one colour per method (colour-blind safe, Okabe-Ito)
METHOD_COLOURS = {"auto": "#E69F00", "tsin": "#D55E00", "debevec": "#0072B2",
                  "robertson": "#009E73", "mitsunaga-nayar": "#CC79A7"}
#: a response verdict's status -> the alert type showing it
VERDICT_ALERTS = {"trusted": "success", "doubtful": "warning", "failed": "danger"}
_PUNCTUATION = re.compile(r"([!-/:-@\[-`{-~])")


def md_text(text: Any) -> str:
    """``text`` for a Markdown pane, shown as it is: every ASCII punctuation character
    backslash-escaped (CommonMark), so neither a file name's ``_`` or ``*`` nor an HTML tag,
    a link or ``$`` (math) in it is interpreted."""
    return _PUNCTUATION.sub(r"\\\1", str(text))


def verdict_markdown(verdict: Any) -> str:
    """The verdict's line, then its registration and moving pixels (``details()``), a
    Markdown paragraph each, shown as they are (:func:`md_text`)."""
    return "\n\n".join(md_text(t) for t in (verdict.line(), *verdict.details()))


def details_markdown(verdict: Any) -> str:
    """The verdict's registration and moving pixels (``details()``), a Markdown list item
    each, shown as they are (:func:`md_text`); empty when there are none."""
    return "\n".join(f"- {md_text(t)}" for t in verdict.details())


def tone_map(radiance: NDArray, stops: float = 0.0, curve: str = "gamma 2.2"
             ) -> NDArray[np.float64]:
    """``radiance`` (one plane) scaled for display into [0, 1]: ``gamma 2.2`` maps the 99.5th
    percentile times 2^stops to white; ``log`` spans four decades below that white point.
    Non-finite values (no usable code) become NaN (drawn transparent)."""
    E = np.asarray(radiance, np.float64)
    ok = np.isfinite(E) & (E > 0)
    if not ok.any():
        return np.full(E.shape, np.nan)
    white = float(np.percentile(E[ok], 99.5)) / 2.0 ** float(stops)
    with np.errstate(divide="ignore", invalid="ignore"):
        if curve == "log":
            out = (np.log10(np.maximum(E, 1e-300) / white) + 4.0) / 4.0
        elif curve == "gamma 2.2":
            out = np.maximum(E, 0.0) / white
            out = out ** (1 / 2.2)
        else:
            raise ValueError(f"unknown tone curve {curve!r}; one of {', '.join(TONE_CURVES)}")
    out = np.clip(out, 0.0, 1.0)
    out[~np.isfinite(E)] = np.nan
    return out


def histogram(values: NDArray, bins: int = 60, span: tuple[float, float] | None = None
              ) -> tuple[NDArray, NDArray]:
    """Counts and bin edges of the finite ``values`` over ``span`` (default their 0.5-99.5 %
    range)."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return np.zeros(0), np.zeros(1)
    if span is None:
        span = (float(np.percentile(v, 0.5)), float(np.percentile(v, 99.5)))
    lo, hi = span
    if not hi > lo:
        hi = lo + 1e-9
    counts, edges = np.histogram(v, bins=bins, range=(lo, hi))
    return counts.astype(np.float64), edges


class ResponseFigure:
    """g(z) per method, the chosen method's band, the true curve; sources updated in place."""

    def __init__(self, methods: Sequence[str], labels: dict[str, str], *, height: int = 420):
        from bokeh.models import ColumnDataSource, HoverTool, Legend, LegendItem
        from bokeh.plotting import figure

        self.fig = figure(height=height, sizing_mode="stretch_width",
                          x_axis_label="code z", y_axis_label="g(z)  (linear, g(z_hi) fixed)",
                          tools="pan,wheel_zoom,box_zoom,reset,save", toolbar_location="above",
                          css_classes=["ccd-response-curves"])
        self.band = ColumnDataSource({"z": [], "lo": [], "hi": []}, name="ccd-response-band")
        self.band_area = self.fig.varea("z", "lo", "hi", source=self.band,
                                        fill_color="#D55E00", fill_alpha=0.25)
        self.truth = ColumnDataSource({"z": [], "g": []})
        truth_line = self.fig.line("z", "g", source=self.truth, line_dash="dashed",
                                   line_color="black", line_width=1.5)
        self.sources: dict[str, Any] = {}
        self.lines: dict[str, Any] = {}
        items = [("simulator's truth", [truth_line])]
        for m in methods:
            src = ColumnDataSource({"z": [], "g": [], "err": []}, name=f"ccd-response-{m}")
            line = self.fig.line("z", "g", source=src, line_width=2,
                                 line_color=METHOD_COLOURS.get(m, "gray"))
            self.sources[m] = src
            self.lines[m] = line
            items.append((labels.get(m, m), [line]))
        self.truth_line = truth_line
        self.legend = Legend(items=[LegendItem(label=label, renderers=r) for label, r in items],
                             location="top_left")
        # the truth's entry only where there is a truth (a simulation), never on a real bracket
        self.legend.items[0].visible = False
        self.fig.add_layout(self.legend)
        self.fig.add_tools(HoverTool(renderers=list(self.lines.values()),
                                     tooltips=[("z", "@z"), ("g", "@g{0.00000}"),
                                               ("± 1σ", "@err{0.00000}")]))

    def show(self, curves: dict[str, tuple[NDArray, NDArray]], chosen: str, compare: bool,
             truth: NDArray | None = None) -> None:
        """``curves``: method -> (g, g_err) on every code (a method missing: no line); the
        band is ±2σ of ``chosen`` (none when ``chosen`` is missing)."""
        for m, src in self.sources.items():
            if m in curves:
                g, err = curves[m]
                z = np.arange(g.size)
                src.data = {"z": z, "g": np.asarray(g), "err": np.nan_to_num(err)}
            else:
                src.data = {"z": [], "g": [], "err": []}
            self.lines[m].visible = (m == chosen) or compare
            self.lines[m].glyph.line_width = 3 if m == chosen else 1.5
        # a legend entry only for a curve drawn (a method not computed has none)
        for item, m in zip(self.legend.items[1:], self.sources):
            item.visible = m in curves and self.lines[m].visible
        self.band_area.glyph.fill_color = METHOD_COLOURS.get(chosen, "gray")
        if chosen in curves:
            g, err = curves[chosen]
            e = np.nan_to_num(np.asarray(err))
            self.band.data = {"z": np.arange(g.size), "lo": g - 2 * e, "hi": g + 2 * e}
        else:
            self.band.data = {"z": [], "lo": [], "hi": []}
        if truth is None:
            self.truth.data = {"z": [], "g": []}
        else:
            self.truth.data = {"z": np.arange(truth.size), "g": truth}
        self.truth_line.visible = self.legend.items[0].visible = truth is not None

    def curve(self, method: str) -> NDArray:
        """The g shown for ``method`` (tests)."""
        return np.asarray(self.sources[method].data["g"])


class PoolHistogram:
    """Relative prediction errors of one pool, before and after calibration (Fig. 3c-d)."""

    def __init__(self, *, height: int = 300):
        from bokeh.models import ColumnDataSource, Legend
        from bokeh.plotting import figure

        self.fig = figure(height=height, sizing_mode="stretch_width",
                          x_axis_label="prediction error e / g(z)  (%)",
                          y_axis_label="pixels", tools="pan,wheel_zoom,reset,save",
                          toolbar_location="above", css_classes=["ccd-response-pool"])
        self.before = ColumnDataSource({"left": [], "right": [], "top": []})
        self.after = ColumnDataSource({"left": [], "right": [], "top": []})
        b = self.fig.quad(left="left", right="right", top="top", bottom=0, source=self.before,
                          fill_color="#999999", fill_alpha=0.5, line_color=None)
        a = self.fig.quad(left="left", right="right", top="top", bottom=0, source=self.after,
                          fill_color="#D55E00", fill_alpha=0.6, line_color=None)
        self.fig.add_layout(Legend(items=[("before (straight-line g)", [b]),
                                          ("after calibration", [a])], location="top_right"))

    def show(self, before: NDArray | None, after: NDArray | None) -> None:
        vals = [np.asarray(v, np.float64) * 100 for v in (before, after) if v is not None]
        if not vals or not any(v.size for v in vals):
            self.before.data = self.after.data = {"left": [], "right": [], "top": []}
            return
        both = np.concatenate(vals)
        both = both[np.isfinite(both)]
        span = (float(np.percentile(both, 0.5)), float(np.percentile(both, 99.5)))
        for src, v in ((self.before, before), (self.after, after)):
            if v is None:
                src.data = {"left": [], "right": [], "top": []}
                continue
            counts, edges = histogram(np.asarray(v) * 100, 60, span)
            src.data = {"left": edges[:-1], "right": edges[1:], "top": counts}


def hdr_views(width: int, classes: tuple[str, str]) -> tuple[Any, Any]:
    """The HDR radiance view (tone-mapped for display) and its relative-sigma view, zoom
    linked (:class:`ccdcore_app.image_view.ImageView`), with CSS classes ``classes``."""
    from ..image_view import ImageView

    rad = ImageView(frame_width=width, max_frame_height=width, cmap="gray", label="display",
                    symbol="display", css_classes=[classes[0]])
    sig = ImageView(frame_width=width, max_frame_height=width, cmap="viridis",
                    label="\u03c3_E / E (%)", symbol="\u03c3_E/E %", link=rad,
                    css_classes=[classes[1]])
    return rad, sig


def hdr_planes(hdr: Any, index: int, stops: float = 0.0, curve: str = "gamma 2.2"
               ) -> dict[str, Any]:
    """One channel of an :class:`~ccdcore.response.hdr.HdrResult` for display: ``E``, ``S``,
    ``F`` (radiance, sigma, flags), ``display`` (:func:`tone_map`), ``rel`` (100·σ_E/E where
    merged, NaN elsewhere) and ``top`` (its 99th percentile, the colour range)."""
    from ccdcore.response.hdr import FLAG_OK

    def plane(a: NDArray) -> NDArray:
        return a if a.ndim == 2 else a[..., index]

    E, S, F = plane(hdr.radiance), plane(hdr.sigma), plane(hdr.flags)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where((F == FLAG_OK) & (E > 0), 100.0 * S / E, np.nan)
    finite = rel[np.isfinite(rel)]
    top = float(np.percentile(finite, 99)) if finite.size else 1.0
    return {"E": E, "S": S, "F": F, "display": tone_map(E, stops, curve), "rel": rel,
            "top": max(top, 1e-6)}
