"""Step 3, dark: the dark reference D̂_D with its hot and dead pixels, and the dark level per
exposure (a table for a few exposures, a plot for a dark-current series); for an EMVA 1288 set,
the dark current of the datasheet (release 3.1 sec. 3.1): the mean dark signal and the dark
variance against the exposure time with their lines, μ_I.mean and μ_I.var with their errors or
why they are not determined.

The dark current is in e⁻/s: it needs the gain K of the EMVA 1288 figures, which the
photon-transfer step makes (``results.emva``); for an EMVA set this step runs that step's
computation when its figures are missing.

The spatial nonuniformity plots (DSNU and PRNU) are in the photon-transfer step, beside the
datasheet's rows they explain (see :mod:`.ptc`).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd
import panel as pn

from ccdcore import guide
from ccdcore.emva.results import EmvaSummary

from ...batch import batched, in_document
from ...image_view import ImageView, view_pane
from ._common import IMAGE_WIDTH, Step, table
from .ptc import is_emva_set

#: the dark step lists the dark level per exposure as a table up to this many exposures, and
#: plots it against the exposure beyond
DARK_TABLE_MAX = 8


def dark_level_columns(levels: list[dict[str, Any]]) -> dict[str, Any]:
    """The dark step's plot of dark level against exposure, as Bokeh source columns: the levels
    of :func:`ccdcore.guide.dark_step` with a known exposure, sorted by it: ``exposure`` (s),
    ``mean`` (DN), ``sem`` (its standard error, 0 when unknown), ``lo``/``hi`` (the error bar's
    ends) and ``n`` (frames)."""
    known = sorted((lv for lv in levels if lv["exposure"] is not None),
                   key=lambda lv: lv["exposure"])
    t = np.array([float(lv["exposure"]) for lv in known])
    mean = np.array([float(lv["mean"]) for lv in known])
    sem = np.array([float(lv["sem"]) if math.isfinite(lv["sem"]) else 0.0 for lv in known])
    return {"exposure": t, "mean": mean, "sem": sem, "lo": mean - sem, "hi": mean + sem,
            "n": [int(lv["n"]) for lv in known]}


def dark_level_figure() -> tuple[Any, Any]:
    """The dark-level figure (built once, fed through its source): mean dark level (DN) with a
    ±1 standard-error bar against the exposure (s)."""
    from bokeh.models import ColumnDataSource, HoverTool
    from bokeh.plotting import figure

    src = ColumnDataSource(dark_level_columns([]))
    fig = figure(title="Dark level against exposure", height=300, sizing_mode="stretch_width",
                 tools="pan,wheel_zoom,box_zoom,reset,save", x_axis_label="exposure (s)",
                 y_axis_label="mean dark level (DN)", output_backend="canvas")
    fig.toolbar.logo = None
    fig.segment(x0="exposure", y0="lo", x1="exposure", y1="hi", source=src,
                line_color="#1f5f99", line_width=1.5)
    dots = fig.scatter("exposure", "mean", source=src, size=7, color="#1f5f99")
    fig.add_tools(HoverTool(renderers=[dots], tooltips=[
        ("exposure", "@exposure{0.0000} s"), ("mean", "@mean{0.0000} DN"),
        ("\u00b1", "@sem{0.0000} DN"), ("frames", "@n")]))
    return fig, src


def dark_current_data(figures: EmvaSummary | None) -> tuple:
    """What the dark-current plots draw (they are rebuilt only when this changes): the dark
    points and the dark-current lines of the EMVA 1288 figures."""
    if figures is None:
        return (None, None)
    return (figures.dark_points, figures.dark_current)


def dark_current_markdown(figures: EmvaSummary) -> str:
    """μ_I.mean and μ_I.var of the EMVA 1288 figures as Markdown: each with its standard
    error, or why it is not determined (:func:`ccdcore.emva.sheet.datasheet_rows`)."""
    from ccdcore.emva.sheet import section_markdown

    lines = ["**Dark current** (EMVA 1288 release 3.1 sec. 3.1: the slope of the mean dark "
             "signal over K, and of the dark variance over K², against the exposure time):", ""]
    return "\n".join(lines + section_markdown(figures, "Dark current"))


def dark_level_table(levels: tuple[dict[str, Any], ...]) -> pd.DataFrame:
    """The dark level per exposure as table rows: exposure, frames, mean and its error."""
    return pd.DataFrame([
        {"exposure (s)": "–" if lv["exposure"] is None else f"{lv['exposure']:.4g}",
         "frames": lv["n"], "mean (DN)": f"{lv['mean']:.4f}",
         "± (DN)": "–" if not math.isfinite(lv["sem"]) else f"{lv['sem']:.2g}"}
        for lv in levels])


class DarkStep(Step):
    """The dark step; its result is :class:`ccdcore.guide.DarkStep` (``results.dark``)."""

    slug = "dark"

    def build(self) -> list[pn.viewable.Viewable]:
        self.view = ImageView(frame_width=IMAGE_WIDTH, max_frame_height=IMAGE_WIDTH,
                              cmap="viridis", label="DN", symbol="D̂_D",
                              title="Dark reference D̂_D (DN)", css_classes=["ccd-wt-dark-map"])
        self.pane = view_pane(self.view)
        self.levels_table = table("ccd-wt-dark-levels")
        # many exposures (a dark-current series): a plot of the level against the exposure
        self.level_fig, self.level_source = dark_level_figure()
        self.level_plot = pn.Column(pn.pane.Bokeh(self.level_fig, sizing_mode="stretch_width"),
                                    visible=False, sizing_mode="stretch_width",
                                    css_classes=["ccd-wt-dark-plot"])
        # an EMVA 1288 set: the dark current, its two plots in one Bokeh layout
        self.current_text = pn.pane.Markdown("", sizing_mode="stretch_width",
                                             css_classes=["ccd-wt-dark-current"])
        self.current_pane = pn.pane.Bokeh(None, sizing_mode="stretch_width",
                                          css_classes=["ccd-wt-dark-current-plots"])
        self.current_holder = pn.Column(self.current_text, self.current_pane, visible=False,
                                        sizing_mode="stretch_width")
        self._current_shown: tuple = (None, None)
        return [pn.Row(self.pane, pn.Column(
            pn.pane.Markdown("**Dark level per exposure** (red crosses on the map: hot and dead "
                             "pixels)"), self.levels_table, self.level_plot,
            sizing_mode="stretch_width"), sizing_mode="stretch_width"),
            self.current_holder]

    async def run(self) -> None:
        """The dark reference and its gate (:meth:`Step.run`); for an EMVA 1288 set then the
        dark current, from the photon-transfer step's EMVA 1288 figures (made when missing)."""
        await super().run()
        session = self.page.state.session
        if self.result is None or not is_emva_set(session):
            return
        if self.results.emva is None:
            await self.page.steps["ptc"].ensure()
        if self.page.state.session is not session:
            return
        in_document(self.page.doc, batched(self.draw_current if self.results.emva is not None
                                           else self._no_current))

    def _no_current(self) -> None:
        self._current_shown = (None, None)
        self.current_pane.object = None
        self.current_text.object = ("**Dark current**: not made — it needs the EMVA 1288 "
                                    "figures, which could not be made (step 4's gate says "
                                    "why).")
        self.current_holder.visible = True

    async def ensure(self) -> guide.DarkStep | None:
        """The dark step's result, computed once (``None`` when it failed: the gate says why)."""
        return await self.once(lambda: self.compute(
            guide.dark_step, self.page.state.session, label="the dark reference"))

    def draw(self, step: guide.DarkStep) -> None:
        if step.dark is not None:
            m = step.dark.mean_map
            lo, hi = np.percentile(m, [0.5, 99.5])
            self.view.show(m, clim=(float(lo), float(max(hi, lo + 1e-6))))
            flagged = np.nonzero(step.dark.hot_mask | step.dark.dead_mask)
            self.view.set_points(flagged[0][:2000], flagged[1][:2000])
            self.pane.visible = True
        cols = dark_level_columns(step.levels)
        plot = len(cols["exposure"]) > DARK_TABLE_MAX    # a series: plot it, no long table
        self.level_source.data = cols
        self.level_plot.visible = plot
        self.levels_table.visible = not plot
        self.levels_table.object = (dark_level_table(step.levels)
                                    if step.levels and not plot else pd.DataFrame())
        self.draw_current()

    def draw_current(self) -> None:
        """The dark current of the EMVA 1288 figures (``results.emva``): its text and its
        plots, built again only when the dark points changed. Shown, the dark-signal plot
        replaces the plain dark-level plot (the same points, with the line)."""
        from ccdcore_report.emva_figures import dark_signal_figure, dark_variance_figure

        figures = self.results.emva
        shown = bool(figures) and is_emva_set(self.page.state.session)
        self.current_holder.visible = shown
        if not shown:
            return
        self.current_text.object = dark_current_markdown(figures)
        data = dark_current_data(figures)
        if data != self._current_shown:
            from bokeh.layouts import row

            self._current_shown = data
            figs = [f for f in (dark_signal_figure(figures), dark_variance_figure(figures))
                    if f is not None]
            self.current_pane.object = row(*figs, sizing_mode="stretch_width") if figs else None
        if self.current_pane.object is not None:
            self.level_plot.visible = False

    def release(self) -> None:
        self.view.release()
