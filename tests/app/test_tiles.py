"""Tiled previews of large frames (ccdcore_app.tiles): the pyramid's levels are block means of the full
frame, a region of a level is its slice, a view draws what it draws for the frame in memory, and
only the visible region is read."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from ccdcore_app import tiles
from ccdcore_app.plots import base as plots
from ccdcore_app.image_view import ImageView
from ccdcore_app.tiles import FramePyramid, TiledPlane, needs_tiles
from ccdcore.io.frames import read_header, write_image
from imagefiles import bomb_tiff


def block_means(plane: np.ndarray, f: int) -> np.ndarray:
    """Means of the finite pixels of f × f blocks (partial at the edges), computed directly."""
    h, w = plane.shape
    nh, nw = -(-h // f), -(-w // f)
    pad = np.full((nh * f, nw * f), np.nan)
    pad[:h, :w] = plane
    finite = np.isfinite(pad)
    sums = np.where(finite, pad, 0.0).reshape(nh, f, nw, f).sum(axis=(1, 3))
    counts = finite.reshape(nh, f, nw, f).sum(axis=(1, 3))
    with np.errstate(invalid="ignore"):
        return sums / counts


@pytest.fixture
def mono(tmp_path: Path) -> tuple[Path, np.ndarray]:
    rng = np.random.default_rng(11)
    frame = rng.integers(0, 4096, (301, 517), dtype=np.uint16)
    return write_image(tmp_path / "mono.tif", frame, bits=12), frame


@pytest.fixture
def pyramid(mono, tmp_path) -> FramePyramid:
    # small bands (16 rows) so that the frame is read in many of them
    return FramePyramid.open(mono[0], "mono", root=tmp_path / "tiles", coarsest=40,
                             band_pixels=517 * 16)


def test_levels_are_block_means_of_the_full_frame(mono, pyramid):
    _, frame = mono
    plane = pyramid.plane()
    assert plane.shape == frame.shape and pyramid.factors == (1, 2, 4, 8, 16)
    for k in range(1, len(pyramid.factors)):
        expected = block_means(frame.astype(np.float64), pyramid.factors[k])
        level = plane.level(k)
        assert isinstance(level, np.memmap) and level.shape == expected.shape
        np.testing.assert_allclose(level, expected, rtol=1e-6)
    lo, hi, mean = plane.stats
    assert (lo, hi) == (frame.min(), frame.max())
    assert mean == pytest.approx(frame.mean(), rel=1e-12)


def test_nan_pixels_and_rgb_channels(tmp_path):
    rng = np.random.default_rng(12)
    frame = rng.normal(100.0, 10.0, (70, 90)).astype(np.float32)
    frame[3:9, 5:7] = np.nan
    frame[64:, 80:] = np.nan                 # a whole bottom-right block of 8 × 8 and more
    pyr = FramePyramid.open(write_image(tmp_path / "f.tif", frame), None,
                            root=tmp_path / "t", coarsest=10, band_pixels=90 * 8)
    for k, f in enumerate(pyr.factors[1:], start=1):
        np.testing.assert_allclose(pyr.plane().level(k), block_means(frame, f), rtol=1e-6)
    assert np.isnan(pyr.plane().level(3)[-1, -1])
    rgb = rng.integers(0, 256, (40, 60, 3), dtype=np.uint8)
    pyr = FramePyramid.open(write_image(tmp_path / "rgb.tif", rgb), "rgb",
                            root=tmp_path / "t", coarsest=16, band_pixels=60 * 4)
    full = plots.channel_planes(rgb, "rgb")
    assert pyr.channels == ("R", "G", "B", "L")
    for name, plane in full.items():
        tiled = pyr.plane(name)
        np.testing.assert_array_equal(tiled.region(0, (0, 40), (0, 60)), plane)
        for k, f in enumerate(pyr.factors[1:], start=1):
            np.testing.assert_allclose(tiled.level(k), block_means(plane.astype(float), f),
                                       rtol=1e-6)
    assert pyr.plane().channel == "L"


def test_a_region_of_each_level_is_its_slice(mono, pyramid):
    _, frame = mono
    plane = pyramid.plane()
    np.testing.assert_array_equal(plane.region(0, (10, 50), (100, 233)), frame[10:50, 100:233])
    assert plane.value(7, 9) == frame[7, 9]
    for k in range(1, len(pyramid.factors)):
        level = np.asarray(plane.level(k))
        h, w = level.shape
        rows, cols = (1, max(h - 2, 2)), (2, max(w - 1, 3))
        np.testing.assert_array_equal(plane.region(k, rows, cols),
                                      level[rows[0]:rows[1], cols[0]:cols[1]])
    # clipped to the level, never empty
    assert plane.region(4, (-5, 100), (-5, 100)).shape == plane.level_shape(4)
    assert plane.region(2, (500, 600), (0, 1)).shape == (1, 1)
    assert plane.coarse(max_pixels=3000).shape == plane.level_shape(3)    # 38 × 65 px
    assert plane.coarse(max_pixels=2000).shape == plane.level_shape(4)    # 19 × 33 px
    assert plane.coarse(max_pixels=10).shape == plane.level_shape(4)      # the coarsest


def test_the_pyramid_is_reused_and_a_changed_file_rebuilds(mono, pyramid, tmp_path, monkeypatch):
    path, frame = mono
    monkeypatch.setattr(FramePyramid, "_build", staticmethod(
        lambda *a, **k: pytest.fail("built again")))
    again = FramePyramid.open(path, "mono", root=tmp_path / "tiles", coarsest=40)
    assert again.folder == pyramid.folder
    monkeypatch.undo()
    st = path.stat()                            # the same bytes, touched: built again
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    touched = FramePyramid.open(path, "mono", root=tmp_path / "tiles", coarsest=40)
    assert touched.folder != pyramid.folder
    write_image(path, frame // 2, bits=12)     # a later modification time, other pixels
    rebuilt = FramePyramid.open(path, "mono", root=tmp_path / "tiles", coarsest=40)
    assert rebuilt.folder != pyramid.folder
    np.testing.assert_allclose(rebuilt.plane().level(1),
                               block_means((frame // 2).astype(float), 2), rtol=1e-6)
    (rebuilt.folder / "mono-2.npy").unlink()   # a damaged pyramid is built again
    assert FramePyramid.open(path, "mono", root=tmp_path / "tiles", coarsest=40
                             ).plane().level(2).shape == rebuilt.plane().level_shape(2)
    assert not list((tmp_path / "tiles").glob(".*.tmp"))


def test_needs_tiles_above_the_threshold_for_mono_and_rgb(mono, tmp_path, monkeypatch):
    header = read_header(mono[0])
    assert not needs_tiles(header, "mono")            # 155 kpx < 16 Mpx
    assert needs_tiles(header, "mono", threshold=1000)
    monkeypatch.setenv(tiles.TILE_PIXELS_ENV, "1000")
    assert needs_tiles(header, None) and not needs_tiles(None)
    assert needs_tiles(header, "rggb")                # odd sizes: read as mono
    even = read_header(write_image(tmp_path / "even.tif", np.zeros((40, 60), np.uint16)))
    assert not needs_tiles(even, "rggb")              # half-size CFA planes: read whole
    assert needs_tiles(even, "mono")
    monkeypatch.setenv(tiles.TILE_PIXELS_ENV, "many")
    assert tiles.tile_threshold() == tiles.TILE_PIXELS


@pytest.mark.parametrize("view, level", [
    (None, 2),                                # whole frame: 4 × 4 blocks, level 2 as it is
    (((99.5, 131.5), (19.5, 51.5)), 0),       # zoomed in: level 0, every pixel
    (((-0.5, 255.5), (63.5, 191.5)), 1),      # half: 2 × 2 blocks from level 1
])
def test_a_view_draws_what_it_draws_for_the_plane_in_memory(tmp_path, view, level):
    rng = np.random.default_rng(13)
    frame = rng.integers(0, 1000, (256, 512), dtype=np.uint16)
    pyr = FramePyramid.open(write_image(tmp_path / "v.tif", frame), "mono",
                            root=tmp_path / "t", coarsest=32)
    memory, tiled = ImageView(frame_width=128, max_frame_height=128), \
        ImageView(frame_width=128, max_frame_height=128)
    memory.show(frame, clim=(0, 1000), title="f", how="mean")
    tiled.show(pyr.plane(), clim=(0, 1000), title="f", how="mean")
    for v in (memory, tiled):
        if view is not None:
            v.figure.x_range.update(start=view[0][0], end=view[0][1])
            v.figure.y_range.update(start=view[1][1], end=view[1][0])
            v.redraw()
    a, b = memory.source.data, tiled.source.data
    for key in ("x", "y", "dw", "dh"):
        assert a[key] == b[key], key
    np.testing.assert_allclose(b["image"][0], a["image"][0], rtol=1e-6)
    assert memory.factor == tiled.factor
    assert memory.figure.title.text == tiled.figure.title.text
    assert tiled.level == level


def test_only_the_visible_region_is_read(tmp_path, monkeypatch):
    frame = np.arange(256 * 512, dtype=np.uint32).reshape(256, 512)
    pyr = FramePyramid.open(write_image(tmp_path / "r.tif", frame), "mono",
                            root=tmp_path / "t", coarsest=32)
    reads: list[tuple[int, int, int, int]] = []
    real = tiles.read_region

    def counted(path, x, y, w, h, **kw):
        reads.append((x, y, w, h))
        return real(path, x, y, w, h, **kw)

    monkeypatch.setattr(tiles, "read_region", counted)
    view = ImageView(frame_width=128, max_frame_height=128)
    view.show(pyr.plane(), clim=(0, 1))
    assert reads == []                                   # zoomed out: from the levels
    view.figure.x_range.update(start=199.5, end=259.5)
    view.figure.y_range.update(start=69.5, end=9.5)
    view.redraw()
    assert reads == [(200, 10, 60, 60)] and view.level == 0
    np.testing.assert_array_equal(view.source.data["image"][0], frame[10:70, 200:260])

    assert isinstance(view.plane, TiledPlane) and view.plane.ndim == 2


# ------------------------------------------------------------------------------ the Session page
def test_the_session_page_previews_a_large_frame_from_its_pyramid(tmp_path, small_session,
                                                                  monkeypatch):
    """With the threshold below the fixture's 24 × 32 frames, the page never reads a frame
    whole: the view, the readout, the range and the channels come from the pyramid."""
    import ccdcore_app.main  # noqa: F401  (the Panel extensions, as serving does)
    from ccdcore_app.pages.session import SessionPage
    from ccdcore_app.state import AppState
    from ccdcore.io.frames import read_image
    from ccdcore.session import Session
    from _coro import run

    monkeypatch.setenv("CCDCORE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv(tiles.TILE_PIXELS_ENV, "500")
    state = AppState(allowed_roots=[tmp_path.resolve()])
    page = SessionPage(state)
    assert state.load(small_session)
    monkeypatch.setattr(Session, "read", lambda *a: pytest.fail("a large frame read whole"))
    page.frame = "ptc/p1.tif"
    run(page._on_frame())
    frame = read_image(small_session / "ptc/p1.tif")
    plane = page.image_view.plane
    assert isinstance(plane, TiledPlane) and plane.shape == frame.shape
    assert list((tmp_path / "cache" / "tiles").iterdir())       # kept in the cache folder
    assert page.clim_slider.start == frame.min() and page.clim_slider.end == frame.max()
    assert "pyramid" in page.frame_info.object and not page.channel_select.visible
    f = plane.factors[plane.coarse_level()]
    assert page.hist_view.source.data["top"].sum() == (-(-24 // f)) * (-(-32 // f))
    assert page.hist_view.figure.title.text == f"Histogram of {f}\u00d7{f} px block means"
    page._on_pointer(x=5.2, y=7.8)
    assert page.readout.object == f"x = 5, y = 8: **{frame[8, 5]} DN**"
    np.testing.assert_array_equal(page.image_view.source.data["image"][0], frame)
    # a colour frame: its four planes from one pyramid
    page.frame = "scene/rgb.tif"
    run(page._on_frame())
    rgb = read_image(small_session / "scene/rgb.tif")
    assert page.channel_select.visible and page.channel == "L"
    page.channel = "R"
    assert page.image_view.plane.channel == "R"
    np.testing.assert_array_equal(page.image_view.source.data["image"][0], rgb[..., 0])
    assert "channel R" in page.frame_info.object
    auto = page.clim_slider.value
    page.clim_slider.value = (page.clim_slider.start, page.clim_slider.start + 1)
    page._on_auto()
    assert page.clim_slider.value == auto
    page.release()
    assert page._tiled is None and page.image_view.plane is None


def test_the_photon_transfer_preview_of_a_large_frame(tmp_path, assets, monkeypatch):
    import ccdcore_app.main  # noqa: F401
    from ccdcore_app.pages.photon_transfer import PhotonTransferPage
    from ccdcore_app.state import AppState
    from ccdcore.io.frames import read_image
    from ccdcore.session import Session
    from _coro import run

    monkeypatch.setenv("CCDCORE_CACHE", str(tmp_path / "cache"))
    state = AppState(allowed_roots=[assets.resolve()])
    assert state.load(assets / "healey94")
    page = PhotonTransferPage(state, auto=False)
    run(page.refresh())
    rec = page._records[page.frame]
    monkeypatch.setenv(tiles.TILE_PIXELS_ENV, "1000")
    monkeypatch.setattr(Session, "read", lambda *a: pytest.fail("a large frame read whole"))
    run(page._on_frame())
    frame = read_image(rec.path)
    view = page.preview_view
    assert isinstance(view.plane, TiledPlane) and view.plane.shape == frame.shape[:2]
    view.figure.x_range.update(start=9.5, end=29.5)
    view.figure.y_range.update(start=19.5, end=4.5)
    view.redraw()
    np.testing.assert_array_equal(view.source.data["image"][0], frame[5:20, 10:30])
    assert page.preview_pane.visible and not page.preview_alert.visible


def test_old_pyramids_are_deleted_beyond_the_bound(tmp_path):
    rng = np.random.default_rng(14)
    paths = [write_image(tmp_path / f"{i}.tif", rng.integers(0, 255, (64, 64), np.uint16))
             for i in range(3)]
    root = tmp_path / "t"
    first = FramePyramid.open(paths[0], "mono", root=root, coarsest=8)
    size = sum(f.stat().st_size for f in first.folder.iterdir())
    bound = 2 * size + 1000                      # room for two (meta.json sizes vary a little)
    second = FramePyramid.open(paths[1], "mono", root=root, coarsest=8, bound=bound)
    past = 1_600_000_000_000_000_000
    os.utime(first.folder / "meta.json", ns=(past, past))
    os.utime(second.folder / "meta.json", ns=(past + 1, past + 1))
    FramePyramid.open(paths[0], "mono", root=root, coarsest=8)   # used again: now the newest
    third = FramePyramid.open(paths[2], "mono", root=root, coarsest=8, bound=bound)
    assert first.folder.is_dir() and third.folder.is_dir() and not second.folder.exists()
    FramePyramid.open(paths[0], "mono", root=root, coarsest=8, bound=0)   # reused: no eviction
    alone = FramePyramid.open(paths[1], "mono", root=root, coarsest=8, bound=0)
    assert [p for p in root.iterdir()] == [alone.folder]        # never the one just built


# ------------------------------------------------------------------------ the pixel limit ---


def _no_decoding(*args, **kwargs):
    raise AssertionError("pixels were decoded")


def test_a_bomb_is_refused_from_its_header(tmp_path, monkeypatch):
    from ccdcore.errors import ImageReadError

    monkeypatch.delenv("CCDCORE_MAX_PIXELS", raising=False)
    bomb = bomb_tiff(tmp_path / "bomb.tif", 40000, 40000)
    assert needs_tiles(read_header(bomb))
    monkeypatch.setattr(tiles, "read_region", _no_decoding)
    with pytest.raises(ImageReadError) as info:
        FramePyramid.open(bomb, root=tmp_path / "tiles")
    message = str(info.value)
    assert message.startswith(str(bomb)) and "40000x40000" in message and "\n" not in message
    assert "over the limit" in message and "CCDCORE_MAX_PIXELS" in message
    assert not [p for p in (tmp_path / "tiles").iterdir()]        # no pyramid left behind


def test_the_limit_counts_every_channel(tmp_path, monkeypatch):
    """An RGB frame whose each band (and each plane) is within the limit, but not the whole
    image with its three channels, is refused (the rule of ccdcore.io.frames.read_frame)."""
    from ccdcore.errors import ImageReadError

    rgb = write_image(tmp_path / "rgb.tif",
                      np.random.default_rng(3).integers(0, 255, (64, 80, 3), dtype=np.uint8))
    monkeypatch.setenv("CCDCORE_MAX_PIXELS", str(64 * 80 * 2))          # below 64 x 80 x 3
    monkeypatch.setattr(tiles, "read_region", _no_decoding)
    with pytest.raises(ImageReadError, match=r"80x64 pixels x 3 channel"):
        FramePyramid.open(rgb, root=tmp_path / "tiles", band_pixels=80 * 8, coarsest=8)
    monkeypatch.undo()
    assert FramePyramid.open(rgb, root=tmp_path / "tiles", coarsest=8).plane("R") is not None
