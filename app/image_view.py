"""Image and histogram views as plain Bokeh figures, built once and fed new data in place.

A page builds its views once; showing another frame, channel or map, moving a colour range or
zooming replaces the data of their sources and a few model properties, so the browser redraws
without building a plot (docs/architecture.md, "How app pages draw and compute"). Every method
that changes the figures holds the document's events (:func:`ccdcore_app.batch.batched`): that sends
them as one message, and makes it safe to call from any callback of a served page (a raw Bokeh
model changed outside Panel's document lock is refused).

ImageView(frame_width=560, max_frame_height=560, cmap="gray", ...)
    A zoomable view of one 2-D plane at screen resolution (:func:`ccdcore_app.plots.base.overview`;
    a frame larger than memory as an :class:`ccdcore_app.tiles.TiledPlane`, drawn from the pyramid
    level that fits the zoom, :func:`ccdcore_app.tiles.overview`), with
    square pixels, a colour bar, a hover readout, optional linked zoom with other views, a
    crosshair, a box and marked pixels; Python callbacks for the pointer, a tap and a drawn box.
HistogramView(height=220, ...)
    The histogram of a plane's finite values with the colour range as a band.
palette(cmap, n=256)
    A colour-map name (as HoloViews names them) or a list of colours -> a list of colours.
frame_size(shape, frame_width, max_frame_height)
    The frame size giving square pixels (:func:`ccdcore_app.plots.base.frame_size`).
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from .plots import base as plots
from . import tiles
from .plots.base import frame_size
from .tiles import TiledPlane
from .batch import batched

__all__ = ["ImageView", "HistogramView", "palette", "frame_size", "view_pane"]

_TOOLS = "pan,wheel_zoom,box_zoom,reset,save"


def palette(cmap: Any, n: int = 256) -> list[str]:
    """The colours of ``cmap``: a list of colours as given, a name (``"gray"``, ``"viridis"``,
    ``"RdBu_r"``, ...) through HoloViews' colour maps, sampled to ``n`` colours."""
    if isinstance(cmap, (list, tuple)):
        return [str(c) for c in cmap]
    from holoviews.plotting.util import process_cmap

    return list(process_cmap(cmap, ncolors=n))



class ImageView:
    """A plane (rows × columns) drawn at screen resolution in a plain Bokeh figure.

    Pixel ``(row, col)`` is centred on ``(x, y) = (col, row)`` with row 0 at the top. Each zoom
    or pan (Bokeh's ``RangesUpdate``, once a gesture ends) draws the visible part again through
    :func:`ccdcore_app.plots.base.overview`: when more pixels than screen pixels are visible,
    blocks of f × f pixels become one value (``how``: ``"mean"``, ``"extreme"`` -- the pixel
    farthest from ``centre`` -- or ``"max"``), and the title says so. A
    :class:`ccdcore_app.tiles.TiledPlane` is drawn from its pyramid (always block means): only the
    visible region of the level that fits the zoom is read.

    Parameters
    ----------
    frame_width, max_frame_height
        The plot frame: this wide, narrower when a tall plane would exceed the height.
    cmap
        Colour map name or list of colours; ``levels`` draws that many colours (categories).
    label
        Colour-bar title (``"DN"``); ``symbol`` names the value in the hover readout.
    select
        Add a box-select tool (active): :attr:`on_box` gets ``(x0, y0, x1, y1)`` of a drawn box.
    link
        Another view to share the zoom and pan with (same plane shape).
    css_classes
        Classes of the figure (browser tests find it by them).
    """

    def __init__(self, *, frame_width: int = 560, max_frame_height: int = 560, cmap: Any = "gray",
                 label: str = "DN", symbol: str = "DN", title: str = "", select: bool = False,
                 link: "ImageView | None" = None, levels: int | None = None,
                 css_classes: Sequence[str] = ()):
        from bokeh.events import MouseMove, RangesUpdate, SelectionGeometry, Tap
        from bokeh.models import (BoxSelectTool, ColorBar, ColumnDataSource, HoverTool,
                                  LinearColorMapper, Range1d, WheelZoomTool)
        from bokeh.plotting import figure

        self.frame_width, self.max_frame_height = int(frame_width), int(max_frame_height)
        self.plane: NDArray | None = None
        self.title = title
        self.how, self.centre, self.factor = "mean", 0.0, 1
        #: the pyramid level drawn from (a TiledPlane shown; 0: the file itself)
        self.level = 0
        self.symbol = symbol
        #: callbacks: ``on_pointer(x, y)``, ``on_tap(x, y)``, ``on_box((x0, y0, x1, y1))``
        self.on_pointer: Callable[[float, float], None] | None = None
        self.on_tap: Callable[[float, float], None] | None = None
        self.on_box: Callable[[tuple[float, float, float, float]], None] | None = None
        self._drawn_for: tuple | None = None
        if link is not None:
            x_range, y_range = link.figure.x_range, link.figure.y_range
            self.group = link.group
        else:   # y runs downwards: row 0 at the top
            x_range, y_range = Range1d(-0.5, 0.5), Range1d(0.5, -0.5)
            self.group = []
        self.group.append(self)
        self.source = ColumnDataSource({"image": [np.full((1, 1), np.nan, np.float32)],
                                        "x": [-0.5], "y": [-0.5], "dw": [1.0], "dh": [1.0]})
        self.mapper = LinearColorMapper(palette=palette(cmap, levels or 256), low=0.0, high=1.0,
                                        nan_color="rgba(0, 0, 0, 0)")
        fig = figure(frame_width=self.frame_width, frame_height=self.frame_width,
                     x_range=x_range, y_range=y_range, tools=_TOOLS, title=title,
                     x_axis_label="x (column)", y_axis_label="y (row)",
                     output_backend="canvas", css_classes=list(css_classes))
        fig.toolbar.logo = None
        fig.grid.visible = False
        self.renderer = fig.image(image="image", x="x", y="y", dw="dw", dh="dh",
                                  source=self.source, color_mapper=self.mapper)
        fig.add_tools(HoverTool(renderers=[self.renderer], tooltips=[
            ("x", "$x{0}"), ("y", "$y{0}"), (symbol, "@image")]))
        self.color_bar = ColorBar(color_mapper=self.mapper, title=label, width=12)
        fig.add_layout(self.color_bar, "right")
        fig.toolbar.active_scroll = fig.select_one({"type": WheelZoomTool})
        if select:
            box = BoxSelectTool(dimensions="both")
            fig.add_tools(box)
            fig.toolbar.active_drag = box
            fig.on_event(SelectionGeometry, self._selection)
        fig.on_event(RangesUpdate, self._ranges)
        fig.on_event(MouseMove, self._mouse)
        fig.on_event(Tap, self._tap)
        self.figure = fig
        self._spans: tuple[Any, Any] | None = None
        self._box: Any = None
        self._points: Any = None

    # ------------------------------------------------------------------ data ----------------
    @batched
    def show(self, plane: NDArray | None, *, clim: tuple[float, float] | None = None,
             title: str | None = None, how: str | None = None, centre: float | None = None,
             reset: bool = True) -> None:
        """Show ``plane`` (``None``: nothing) in the colour range ``clim``. ``reset`` zooms out
        to the whole plane (every linked view follows); otherwise the zoom is kept when the
        shape is the same."""
        if title is not None:
            self.title = title
        if how is not None:
            if how not in plots.OVERVIEWS:
                raise ValueError(f"how: expected one of {', '.join(plots.OVERVIEWS)}, got {how!r}")
            self.how = how
        if centre is not None:
            self.centre = float(centre)
        old = None if self.plane is None else self.plane.shape
        self.plane = None if plane is None else \
            plane if isinstance(plane, TiledPlane) else np.asarray(plane)
        if clim is not None:
            self.set_clim(clim)
        if self.plane is None:
            self.source.data = {"image": [np.full((1, 1), np.nan, np.float32)], "x": [-0.5],
                                "y": [-0.5], "dw": [1.0], "dh": [1.0]}
            self.figure.title.text = self.title
            return
        if self.plane.ndim != 2:
            raise ValueError(f"plane: expected a 2-D array, got shape {self.plane.shape}")
        h, w = self.plane.shape
        fw, fh = frame_size((h, w), self.frame_width, self.max_frame_height)
        if (self.figure.frame_width, self.figure.frame_height) != (fw, fh):
            self.figure.update(frame_width=fw, frame_height=fh)
        self._drawn_for = None
        if reset or old != self.plane.shape:
            self.zoom_out()
        else:
            self.redraw()

    def release(self) -> None:
        """Let go of the plane (the browser session ended: no figure changes, nothing is sent)."""
        self.plane = None
        self._drawn_for = None

    @batched
    def zoom_out(self) -> None:
        """Show the whole plane (the reset tool's extent too) in this view and its linked ones."""
        if self.plane is None:
            return
        h, w = self.plane.shape
        self.figure.x_range.update(start=-0.5, end=w - 0.5, reset_start=-0.5, reset_end=w - 0.5)
        self.figure.y_range.update(start=h - 0.5, end=-0.5, reset_start=h - 0.5, reset_end=-0.5)
        for view in self.group:
            view.redraw()

    @batched
    def resize(self, frame_width: int) -> None:
        """A new frame width (the height follows, square pixels)."""
        self.frame_width = int(frame_width)
        if self.plane is not None:
            fw, fh = frame_size(self.plane.shape, self.frame_width, self.max_frame_height)
            self.figure.update(frame_width=fw, frame_height=fh)
            self._drawn_for = None
            self.redraw()

    @batched
    def set_clim(self, clim: tuple[float, float]) -> None:
        lo, hi = (float(c) for c in clim)
        self.mapper.update(low=lo, high=hi)

    def set_how(self, how: str, centre: float | None = None) -> None:
        """How a zoomed-out screen pixel is made (a key of
        :data:`ccdcore_app.plots.base.OVERVIEWS`)."""
        self.show(self.plane, how=how, centre=centre, reset=False)

    def visible_ranges(self) -> tuple[tuple[float, float], tuple[float, float]]:
        xr, yr = self.figure.x_range, self.figure.y_range
        return (float(xr.start), float(xr.end)), (float(yr.start), float(yr.end))

    @batched
    def redraw(self) -> None:
        """Draw the visible part of the plane again (nothing when already drawn for it)."""
        if self.plane is None:
            return
        x_range, y_range = self.visible_ranges()
        key = (x_range, y_range, self.how, self.centre, self.figure.frame_width,
               self.figure.frame_height)
        if key == self._drawn_for:
            return
        self._drawn_for = key
        if isinstance(self.plane, TiledPlane):    # only the visible region of one level read
            data, (left, bottom, right, top), factor, self.level = tiles.overview(
                self.plane, x_range, y_range, self.figure.frame_width,
                self.figure.frame_height)
        else:
            data, (left, bottom, right, top), factor = plots.overview(
                self.plane, x_range, y_range, self.figure.frame_width,
                self.figure.frame_height, how=self.how, centre=self.centre)
        self.factor = factor
        image = np.asarray(data, dtype=np.float32)
        self.source.data = {"image": [image], "x": [left], "y": [bottom],
                            "dw": [right - left], "dh": [top - bottom]}
        self.figure.title.text = self.title if factor <= 1 else plots.with_note(
            self.title, f"{plots.OVERVIEWS[self.how]} of {factor}\u00d7{factor} px")

    # ------------------------------------------------------------------ marks ---------------
    @batched
    def set_crosshair(self, row: float | None, col: float | None) -> None:
        """Dashed lines through row ``row`` and column ``col`` (``None``: hidden)."""
        if self._spans is None:
            from bokeh.models import Span

            style = dict(line_color="#00c853", line_width=1, line_dash="dashed", line_alpha=0.9)
            self._spans = (Span(dimension="width", location=0, visible=False, **style),
                           Span(dimension="height", location=0, visible=False, **style))
            for span in self._spans:
                self.figure.add_layout(span)
        across, down = self._spans
        across.update(location=float(row or 0), visible=row is not None)
        down.update(location=float(col or 0), visible=col is not None)

    @batched
    def set_box(self, box: tuple[int, int, int, int] | None) -> None:
        """Outline the pixels ``(x, y, w, h)`` (column, row, width, height; ``None``: hidden)."""
        if self._box is None:
            from bokeh.models import BoxAnnotation

            self._box = BoxAnnotation(fill_alpha=0.0, line_color="#ff7f0e", line_width=2,
                                      visible=False)
            self.figure.add_layout(self._box)
        if box is None:
            self._box.visible = False
            return
        x, y, w, h = box
        self._box.update(left=x - 0.5, right=x + w - 0.5, top=y - 0.5, bottom=y + h - 0.5,
                         visible=True)

    @batched
    def set_points(self, rows: NDArray | None, cols: NDArray | None) -> None:
        """Red crosses on the pixels ``(rows[i], cols[i])`` (``None`` or empty: none), drawn
        above the image at every zoom."""
        if self._points is None:
            if rows is None or len(rows) == 0:
                return
            from bokeh.models import ColumnDataSource

            source = ColumnDataSource({"x": [], "y": []})
            self._points = self.figure.scatter(
                "x", "y", source=source, marker="x", size=8, line_color="#d62728",
                line_width=1.5)
        if rows is None or cols is None or len(rows) == 0:
            self._points.data_source.data = {"x": [], "y": []}
            self._points.visible = False
            return
        self._points.data_source.data = {"x": np.asarray(cols, dtype=float),
                                         "y": np.asarray(rows, dtype=float)}
        self._points.visible = True

    # ------------------------------------------------------------------ events --------------
    def _ranges(self, event: Any) -> None:
        for view in self.group:
            view.redraw()

    def _mouse(self, event: Any) -> None:
        if self.on_pointer is not None and event.x is not None and event.y is not None:
            self.on_pointer(float(event.x), float(event.y))

    def _tap(self, event: Any) -> None:
        if self.on_tap is not None and event.x is not None and event.y is not None:
            self.on_tap(float(event.x), float(event.y))

    def _selection(self, event: Any) -> None:
        geometry = getattr(event, "geometry", None) or {}
        if self.on_box is None or geometry.get("type") != "rect":
            return
        try:
            box = tuple(float(geometry[k]) for k in ("x0", "y0", "x1", "y1"))
        except (KeyError, TypeError, ValueError):
            return
        self.on_box(box)  # type: ignore[arg-type]


def view_pane(view: "ImageView") -> Any:
    """A view in a Panel Column, hidden until it has data (``visible`` on a Bokeh pane fails),
    as wide as the figure: Panel would otherwise take the figure's nominal ``width`` (600 px,
    unused beside ``frame_width``) as the Column's minimum width, and two views in a row would
    overflow the page."""
    import panel as pn

    view.figure.width = None
    return pn.Column(pn.pane.Bokeh(view.figure, sizing_mode=None), margin=0, visible=False,
                     sizing_mode=None)


class HistogramView:
    """The histogram of a plane's finite values (plain Bokeh, built once) with the colour range
    as a translucent band; :meth:`show` replaces the bars, :meth:`set_band` moves the band.

    Integer planes get one bin per code when they span at most ``bins`` codes
    (:func:`ccdcore_app.plots.base.histogram_edges`). Counts read as plain numbers with thousands
    separators.
    """

    def __init__(self, *, height: int = 220, title: str = "Histogram", label: str = "DN",
                 symbol: str = "DN", bins: int = 256, css_classes: Sequence[str] = ()):
        from bokeh.models import (BoxAnnotation, ColumnDataSource, HoverTool,
                                  NumeralTickFormatter)
        from bokeh.plotting import figure

        self.bins = bins
        self.source = ColumnDataSource({"left": [], "right": [], "top": []})
        fig = figure(height=height, sizing_mode="stretch_width", title=title,
                     x_axis_label=label, y_axis_label="count", output_backend="canvas",
                     tools=_TOOLS, css_classes=list(css_classes))
        fig.toolbar.logo = None
        fig.yaxis.formatter = NumeralTickFormatter(format="0,0")
        bars = fig.quad(left="left", right="right", bottom=0, top="top", source=self.source,
                        fill_color="#4a6fa5", line_color=None)
        self.hover = HoverTool(renderers=[bars], tooltips=[
            (symbol, "@left{0.[0000]} \u2013 @right{0.[0000]}"), ("count", "@top{0,0}")])
        fig.add_tools(self.hover)
        self.band = BoxAnnotation(left=0.0, right=0.0, fill_color="#f0ad4e", fill_alpha=0.2,
                                  line_alpha=0, visible=False)
        fig.add_layout(self.band)
        self.figure = fig

    @batched
    def show(self, values: NDArray | None, clim: tuple[float, float] | None = None, *,
             bins: int | None = None, title: str | None = None, label: str | None = None
             ) -> None:
        """Bars of ``values`` (``None``: none); the band at ``clim`` when given."""
        if values is None:
            self.source.data = {"left": [], "right": [], "top": []}
        else:
            counts, edges = plots.histogram_counts(values, bins or self.bins)
            self.source.data = {"left": edges[:-1], "right": edges[1:], "top": counts}
        if title is not None:
            self.figure.title.text = title
        if label is not None:
            self.figure.xaxis.axis_label = label
        if clim is not None:
            self.set_band(clim)

    @batched
    def set_band(self, clim: tuple[float, float] | None) -> None:
        if clim is None:
            self.band.visible = False
            return
        self.band.update(left=float(clim[0]), right=float(clim[1]), visible=True)
