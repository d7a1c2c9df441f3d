"""ccdcore_app.image_view: plain Bokeh image and histogram views fed in place."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ccdcore_app.image_view import HistogramView, ImageView, frame_size, palette


def _drawn(view: ImageView) -> tuple[np.ndarray, float, float, float, float]:
    d = view.source.data
    return d["image"][0], d["x"][0], d["y"][0], d["dw"][0], d["dh"][0]


def test_frame_size_gives_square_pixels():
    assert frame_size((100, 200), 400) == (400, 200)
    assert frame_size((400, 100), 400, max_frame_height=560) == (140, 560)   # tall: narrower


def test_a_plane_that_fits_is_drawn_pixel_for_pixel_with_row_zero_on_top():
    plane = np.arange(12 * 20, dtype=np.uint16).reshape(12, 20)
    view = ImageView(frame_width=200)
    view.show(plane, clim=(0, 100), title="frame")
    image, x, y, dw, dh = _drawn(view)
    np.testing.assert_array_equal(image, plane.astype(np.float32))  # rows in frame order
    assert (x, y, dw, dh) == (-0.5, -0.5, 20.0, 12.0)               # pixel edges
    assert view.figure.y_range.start == 11.5 and view.figure.y_range.end == -0.5  # row 0 on top
    assert view.figure.title.text == "frame" and view.factor == 1
    assert (view.mapper.low, view.mapper.high) == (0.0, 100.0)
    assert (view.figure.frame_width, view.figure.frame_height) == (200, 120)


def test_zoomed_out_view_says_how_and_keeps_a_single_pixel_with_extreme():
    plane = np.full((400, 600), 1.0)
    plane[123, 457] = 0.2                              # one cold pixel
    view = ImageView(frame_width=150, max_frame_height=150)
    view.show(plane, title="K", how="mean")
    image, *_ = _drawn(view)
    assert view.factor == 4 and image.shape == (100, 150)
    assert view.figure.title.text == "K \u00b7 mean of 4\u00d74 px"
    assert image.min() == pytest.approx(1 - 0.8 / 16, rel=1e-6)   # diluted by f^2
    view.set_how("extreme", centre=1.0)
    image, *_ = _drawn(view)
    assert image.min() == pytest.approx(0.2, rel=1e-6)            # kept
    assert int(np.argmin(image)) == np.ravel_multi_index((123 // 4, 457 // 4), image.shape)
    assert "extreme pixel of 4\u00d74 px" in view.figure.title.text
    with pytest.raises(ValueError, match="how"):
        view.set_how("median")


def test_zoom_draws_the_visible_part_in_every_linked_view():
    a_plane = np.arange(300 * 300, dtype=np.float64).reshape(300, 300)
    a = ImageView(frame_width=100, max_frame_height=100)
    b = ImageView(frame_width=100, max_frame_height=100, link=a)
    a.show(a_plane)
    b.show(-a_plane)
    assert a.factor == b.factor == 3
    assert b.figure.x_range is a.figure.x_range and b.group is a.group
    # the user zooms to columns 10..59, rows 20..69 (the browser sets the shared ranges)
    a.figure.x_range.update(start=9.5, end=59.5)
    a.figure.y_range.update(start=69.5, end=19.5)
    a._ranges(None)                                    # Bokeh's RangesUpdate
    for view, sign in ((a, 1), (b, -1)):
        image, x, y, dw, dh = _drawn(view)
        assert view.factor == 1 and (x, y, dw, dh) == (9.5, 19.5, 50.0, 50.0)
        np.testing.assert_array_equal(image, sign * a_plane[20:70, 10:60].astype(np.float32))
    # a new plane of the same shape keeps the zoom unless reset
    a.show(a_plane * 2, reset=False)
    assert _drawn(a)[1] == 9.5
    a.zoom_out()
    assert a.figure.x_range.start == -0.5 and a.figure.x_range.end == 299.5
    assert _drawn(b)[0].shape == (100, 100)


def test_events_reach_the_callbacks_and_marks_cover_pixel_edges():
    view = ImageView(select=True)
    view.show(np.zeros((10, 10)))
    got: dict[str, object] = {}
    view.on_pointer = lambda x, y: got.__setitem__("pointer", (x, y))
    view.on_tap = lambda x, y: got.__setitem__("tap", (x, y))
    view.on_box = lambda box: got.__setitem__("box", box)
    view._mouse(SimpleNamespace(x=1.5, y=2.5))
    view._tap(SimpleNamespace(x=3.0, y=4.0))
    view._selection(SimpleNamespace(geometry={"type": "rect", "x0": 1, "y0": 2, "x1": 3, "y1": 4}))
    view._selection(SimpleNamespace(geometry={"type": "poly", "x": [1], "y": [2]}))  # ignored
    assert got == {"pointer": (1.5, 2.5), "tap": (3.0, 4.0), "box": (1.0, 2.0, 3.0, 4.0)}
    view.set_box((2, 3, 4, 5))
    assert (view._box.left, view._box.right, view._box.top, view._box.bottom) == \
        (1.5, 5.5, 2.5, 7.5)
    view.set_box(None)
    assert not view._box.visible
    view.set_crosshair(4, 7)
    across, down = view._spans
    assert (across.location, down.location, across.visible) == (4.0, 7.0, True)


def test_marked_pixels_are_crosses_at_their_centres():
    from ccdcore_app.plots.flat import flagged_pixels

    view = ImageView()
    view.set_points(np.array([], int), np.array([], int))
    assert view._points is None                       # nothing marked: no renderer added
    flags = np.zeros((6, 8), bool)
    flags[1, 5] = flags[4, 2] = True
    rows, cols = flagged_pixels(flags)
    view.set_points(rows, cols)
    data = view._points.data_source.data
    assert list(data["x"]) == [5.0, 2.0] and list(data["y"]) == [1.0, 4.0]   # x column, y row
    assert view._points.visible
    view.set_points(None, None)
    assert not view._points.visible and len(view._points.data_source.data["x"]) == 0
    assert len(flagged_pixels(np.ones((300, 300), bool), limit=100)[0]) == 100


def test_clearing_shows_nothing_and_a_3d_array_is_refused():
    view = ImageView()
    view.show(np.ones((4, 4)), title="x")
    view.show(None)
    assert view.plane is None and np.isnan(_drawn(view)[0]).all()
    with pytest.raises(ValueError, match="2-D"):
        view.show(np.ones((4, 4, 3)))


def test_histogram_view_counts_every_finite_value_and_moves_its_band():
    values = np.array([[0, 1, 1], [2, 2, 2]], dtype=np.uint16)
    hist = HistogramView()
    hist.show(values, (0.5, 1.5))
    d = hist.source.data
    np.testing.assert_array_equal(d["top"], [1, 2, 3])          # one bin per code
    np.testing.assert_array_equal(d["left"], [-0.5, 0.5, 1.5])
    assert (hist.band.left, hist.band.right, hist.band.visible) == (0.5, 1.5, True)
    hist.show(np.array([np.nan, 1.0, 2.0]), bins=4)
    assert hist.source.data["top"].sum() == 2                    # NaN left out
    hist.show(None)
    assert len(hist.source.data["top"]) == 0


def test_palette_names_and_lists():
    assert palette(["#000000", "#ffffff"]) == ["#000000", "#ffffff"]
    grey = palette("gray", 4)
    assert len(grey) == 4 and grey[0].lower() == "#000000" and grey[-1].lower() == "#ffffff"


def test_a_zoomed_out_view_without_a_title_has_no_stray_separator():
    view = ImageView(frame_width=150, max_frame_height=150)
    view.show(np.ones((400, 600)), title="", how="mean")
    assert view.factor == 4 and view.figure.title.text == "mean of 4\u00d74 px"
