"""One frame preview for the Session and Photon transfer pages.

Public objects
--------------
FramePreview
    A frame's image view in its pane (optionally with the histogram of what it shows), the alert
    saying why a frame cannot be previewed, and the reading of a frame off the UI thread (the
    newest request wins: :class:`ccdcore_app.latest.Latest`). The figures are plain Bokeh, built
    once (at once, or on first use for a preview below the fold of the first view) and fed in
    place: another frame or channel replaces their data.
read_frame(session, record, plane=False)
    Read a frame to preview (worker thread): as stored, or the pyramid of a large one
    (:mod:`ccdcore_app.tiles`); with ``plane`` its own pixel grid (a raw mosaic as it is, the
    luminance of colour). The error message instead of raising.
PREVIEW_ERROR
    How the alert starts.

The pages keep their own state (the frame chosen, declared with ``param``) and what they show
around the preview (the Session page's channels, colour range and readout; the Photon transfer
page's ROI box); this module only reads, shows and says why not.
"""
from __future__ import annotations

import asyncio
import logging
import traceback
from typing import Any, Callable, Sequence

import numpy as np
import panel as pn
import param

from ccdcore.errors import CcdError
from ccdcore.session import FrameRecord, Session

from .plots import base as plots
from . import tiles
from .image_view import HistogramView, ImageView
from .latest import Latest
from .tiles import FramePyramid, TiledPlane

__all__ = ["FramePreview", "read_frame", "PREVIEW_ERROR"]

log = logging.getLogger(__name__)

#: the alert's text before the reason
PREVIEW_ERROR = "**Cannot preview the frame:** "

#: what :func:`read_frame` gives: the frame (or its pyramid, or one plane), and the error
Read = tuple[Any, str]


def read_frame(session: Session, rec: FrameRecord, plane: bool = False) -> Read:
    """Read a frame to preview, or open the pyramid of a large one (worker thread); the error
    message instead of raising.

    ``plane=False``: the frame as stored, or its pyramid by the camera's layout (the Session
    page shows its channels). ``plane=True``: the frame's own pixel grid (a raw mosaic as it is,
    the luminance of colour), read whole or, for a large frame, one plane of its pyramid (read by
    the region).
    """
    try:
        if plane:
            if tiles.needs_tiles(session.header_or_none(rec), None):
                return FramePyramid.open(rec.path, None).plane(), ""
            return plots.channel_data(session.read(rec)), ""
        layout = session.camera.layout
        if tiles.needs_tiles(session.header_or_none(rec), layout):
            return FramePyramid.open(rec.path, layout), ""
        return session.read(rec), ""
    except CcdError as err:
        return None, str(err)
    except Exception as err:  # unreadable in an unforeseen way: still an alert, not a crash
        log.error("reading %s failed:\n%s", rec.path, traceback.format_exc())
        return None, f"{rec.relpath}: unexpected error: {type(err).__name__}: {err}"


class FramePreview(param.Parameterized):
    """A frame's image view, its optional histogram, its error alert and its reading.

    Parameters
    ----------
    frame_width, max_frame_height, css_class, select
        The image view's (:class:`ccdcore_app.image_view.ImageView`): size, CSS class (browser
        tests find the figure by it), box-select tool.
    histogram
        CSS class of a histogram of what is shown, with the colour range as a band (``None``:
        no histogram).
    error_css_classes
        CSS classes of the error alert.
    on_pointer, on_box
        The view's callbacks: the cursor moved to ``(x, y)``; a box was drawn.
    lazy
        Build the figures on first use (:attr:`view`, :meth:`build`) instead of at once.
    """

    deferred = param.Boolean(default=False, doc=(
        "Hold what is shown until the figures are built (a preview not yet in the page): "
        "building them draws it."))

    def __init__(self, *, frame_width: int, max_frame_height: int, css_class: str,
                 select: bool = False, histogram: str | None = None,
                 error_css_classes: Sequence[str] = (),
                 on_pointer: Callable[[float, float], None] | None = None,
                 on_box: Callable[[Any], None] | None = None, lazy: bool = False,
                 **params: Any):
        super().__init__(**params)
        self.alert = pn.pane.Alert("", alert_type="danger", visible=False,
                                   sizing_mode="stretch_width",
                                   css_classes=list(error_css_classes))
        self._spec = dict(frame_width=frame_width, max_frame_height=max_frame_height,
                          select=select, css_classes=[css_class])
        self._histogram = histogram
        self._on_pointer, self._on_box = on_pointer, on_box
        self._views: tuple[ImageView, HistogramView | None, pn.Column, pn.Column | None] | None \
            = None
        self._pending: list | None = None   # [plane, clim, title, hist, hist_title] held
        self._requests = Latest()           # reading requests (older ones drop)
        if not lazy:
            self.build()

    # ================================================================ the figures ==========
    @property
    def built(self) -> bool:
        """The figures exist."""
        return self._views is not None

    def build(self) -> None:
        """Build the figures (once); what was held meanwhile is drawn."""
        if self._views is not None:
            return
        view = ImageView(**self._spec)
        if self._on_pointer is not None:
            view.on_pointer = self._on_pointer
        if self._on_box is not None:
            view.on_box = self._on_box
        # (shown with a frame; visibility goes on a Column around a Bokeh pane: setting it on
        # the pane makes Panel copy the figure's stylesheets into the pane, which fails)
        image_pane = pn.Column(pn.pane.Bokeh(view.figure), margin=0, visible=False)
        hist = hist_pane = None
        if self._histogram is not None:
            hist = HistogramView(height=240, css_classes=[self._histogram])
            hist_pane = pn.Column(pn.pane.Bokeh(hist.figure, height=240,
                                                sizing_mode="stretch_width"),
                                  sizing_mode="stretch_width", margin=0, visible=False)
        self._views = (view, hist, image_pane, hist_pane)
        if self._pending is not None:   # a frame chosen before the preview was shown
            self.show(*self._pending)

    @property
    def view(self) -> ImageView:
        """The image view (built on first use)."""
        self.build()
        return self._views[0]  # type: ignore[index]

    @property
    def hist_view(self) -> HistogramView | None:
        """The histogram (built on first use; None without one)."""
        self.build()
        return self._views[1]  # type: ignore[index]

    @property
    def image_pane(self) -> pn.Column:
        """The image view's pane (hidden while nothing is shown)."""
        self.build()
        return self._views[2]  # type: ignore[index]

    @property
    def hist_pane(self) -> pn.Column | None:
        """The histogram's pane (hidden while nothing is shown; None without one)."""
        self.build()
        return self._views[3]  # type: ignore[index]

    # ================================================================ reading ==============
    async def fetch(self, session: Session, rec: FrameRecord, *, plane: bool = False,
                    spinner: Any = None) -> Read | None:
        """:func:`read_frame` in a worker thread, ``spinner`` (a Panel object, or None) loading
        meanwhile; None when a newer request came meanwhile (the caller draws nothing)."""
        request = self._requests.next()
        if spinner is not None:
            spinner.loading = True
        try:
            result = await asyncio.to_thread(read_frame, session, rec, plane)
        finally:
            if spinner is not None and self._requests.is_current(request):
                spinner.loading = False
        return result if self._requests.is_current(request) else None

    # ================================================================ showing ==============
    def show(self, plane: np.ndarray | TiledPlane, clim: Any, title: str, hist: Any = None,
             hist_title: str = "Histogram") -> None:
        """Show ``plane`` in ``clim`` (and the histogram of ``hist``); while :attr:`deferred`
        and not built, only remember them (:meth:`build` draws them)."""
        if self._views is None and self.deferred:
            self._pending = [plane, clim, title, hist, hist_title]
            return
        self._pending = None
        self.build()
        view, hist_view, image_pane, hist_pane = self._views  # type: ignore[misc]
        view.show(plane, clim=clim, title=title, how="mean")
        image_pane.visible = True
        if hist_view is not None:
            hist_view.show(hist, clim, title=hist_title)
            hist_pane.visible = True

    def set_clim(self, clim: tuple[float, float]) -> None:
        """The colour range of the image and the histogram's band (of what is held, when not
        built yet)."""
        if self._views is not None:
            view, hist_view = self._views[:2]
            view.set_clim(clim)
            if hist_view is not None:
                hist_view.set_band(clim)
        elif self._pending is not None:
            self._pending[1] = tuple(clim)

    def set_box(self, box: tuple[int, int, int, int] | None) -> None:
        """Outline ``box`` (x, y, w, h) on the image."""
        self.view.set_box(box)

    def fail(self, message: str) -> None:
        """Say why the frame cannot be previewed."""
        self.alert.param.update(object=PREVIEW_ERROR + message, visible=True)

    def hide_error(self) -> None:
        """Hide the alert (a frame is shown)."""
        self.alert.visible = False

    def clear(self) -> None:
        """Show nothing (the figures keep their models)."""
        self._pending = None
        if self._views is not None:
            view, hist_view, image_pane, hist_pane = self._views
            view.show(None)
            image_pane.visible = False
            if hist_view is not None:
                hist_view.show(None)
                hist_pane.visible = False

    def release(self) -> None:
        """The browser session ended: drop the frame shown (no redraw)."""
        if self._views is not None:
            self._views[0].release()
        self._pending = None
