"""Previews of frames larger than memory: a pyramid of block means on disk, read by the region.

A frame above :func:`tile_threshold` pixels is not read whole. Its channel planes are reduced
once, in bands of rows read with :func:`ccdcore.io.frames.read_region` (the memory used is that of a
band), to levels of block means of 2 × 2, 4 × 4, 8 × 8 ... pixels, down to a level that fits in
:data:`COARSEST` × :data:`COARSEST`. The levels are ``.npy`` files in the cache folder
(:func:`ccdcore_app.cache.store.cache_folder`, else a temporary folder of this process), keyed by
the file's path, size and modification time, and opened with ``mmap_mode="r"``: a view reads only
the part it shows. Level 0 is the file itself (:func:`ccdcore.io.frames.read_region`).

Public objects
--------------
TiledPlane
    One channel plane of a large frame: ``shape``, ``region(level, rows, cols)``,
    ``value(row, col)``, ``coarse()`` (a small level for the histogram and the colour range) and
    the exact ``stats`` (min, max, mean) gathered while the levels were built.
FramePyramid
    The levels of every channel plane of one frame (:meth:`FramePyramid.open` builds or reuses
    them); ``plane(channel)`` gives a :class:`TiledPlane`.
overview(tiled, x_range, y_range, width, height)
    What :func:`ccdcore_app.plots.base.overview` gives for an in-memory plane (``how="mean"``),
    from the coarsest level still at least as fine as the screen, reading only the visible region.
needs_tiles(header, layout), tile_threshold()
    Whether a frame is previewed from a pyramid: more pixels than ``CCDCORE_TILE_PIXELS``
    (default :data:`TILE_PIXELS`) and a per-pixel channel layout (mono or RGB; a raw Bayer
    frame's half-size CFA planes are still read whole).
"""
from __future__ import annotations

import atexit
import contextlib
import hashlib
import json
import logging
import os
import shutil
import tempfile
import threading
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from ccdcore.distributed.client import check_pixels
from ccdcore.io.frames import ImageHeader, read_header, read_region
from ccdcore.progress import Progress

from .plots import base as plots
from .cache.store import cache_folder, max_bytes

__all__ = ["TiledPlane", "FramePyramid", "overview", "needs_tiles", "tile_threshold",
           "TILE_PIXELS", "TILE_PIXELS_ENV", "COARSEST"]

log = logging.getLogger(__name__)

#: frames with more pixels than this are previewed from a pyramid (16 Mpx)
TILE_PIXELS = 16 * 2 ** 20
#: environment variable overriding :data:`TILE_PIXELS`
TILE_PIXELS_ENV = "CCDCORE_TILE_PIXELS"
#: the pyramid stops at the first level whose longer side is at most this
COARSEST = 1024
#: the histogram and the automatic colour range read the finest level of at most this many px
COARSE_PIXELS = 1 << 20
#: pixels of a band read at once while building (about 8 Mpx, 64 MB as float64)
BAND_PIXELS = 8 * 2 ** 20
#: version of the levels' layout on disk
FORMAT = 1

_TMP_LOCK = threading.Lock()
_TMP_FOLDER: list[Path] = []


def tile_threshold() -> int:
    """:data:`TILE_PIXELS`, or ``CCDCORE_TILE_PIXELS`` when set to a positive whole number."""
    text = os.environ.get(TILE_PIXELS_ENV, "").strip()
    if text:
        try:
            value = int(text)
            if value > 0:
                return value
        except ValueError:
            pass
        log.warning("%s=%r is not a positive whole number; using %d", TILE_PIXELS_ENV, text,
                    TILE_PIXELS)
    return TILE_PIXELS


def _layout(shape: Sequence[int], layout: str | None) -> str:
    return plots.frame_layout(tuple(shape), layout)


def needs_tiles(header: ImageHeader | None, layout: str | None = None,
                threshold: int | None = None) -> bool:
    """True when the frame of ``header`` is previewed from a pyramid: more than ``threshold``
    (:func:`tile_threshold`) pixels, and mono or RGB (one value per pixel and channel)."""
    if header is None:
        return False
    limit = tile_threshold() if threshold is None else int(threshold)
    try:
        kind = _layout(header.shape, layout)
    except Exception:   # a layout the shape does not allow: the page reports it on reading
        return False
    return header.width * header.height > limit and kind in ("mono", "rgb")


def _tiles_root() -> Path:
    """``<cache folder>/tiles``, else a temporary folder removed when the process ends."""
    folder = cache_folder()
    if folder is not None:
        return folder / "tiles"
    with _TMP_LOCK:
        if not _TMP_FOLDER:
            tmp = Path(tempfile.mkdtemp(prefix="ccdcore-tiles-"))
            atexit.register(shutil.rmtree, tmp, ignore_errors=True)
            _TMP_FOLDER.append(tmp)
        return _TMP_FOLDER[0]


def _channels(kind: str) -> tuple[str | None, ...]:
    return (None,) if kind == "mono" else ("R", "G", "B", plots.LUMINANCE)


def _plane(band: NDArray, channel: str | None, layout: str | None) -> NDArray:
    """One channel plane of a band of rows (per-pixel layouts only)."""
    if channel is None:
        return band if band.ndim == 2 else band[:, :, 0]
    return plots.channel_planes(band, layout)[channel]


def _file_name(channel: str | None, level: int) -> str:
    return f"{channel or 'mono'}-{level}.npy"


class TiledPlane:
    """One channel plane of a large frame, read by the region: level 0 from the file, level
    ``k`` ≥ 1 (block means of ``factors[k]`` × ``factors[k]`` pixels, float32) from the
    pyramid's memory-mapped files.

    Pixel ``(row, col)`` of level ``k`` covers the level-0 rows ``row·f .. row·f + f − 1`` and
    columns ``col·f .. col·f + f − 1`` (``f = factors[k]``; partial at the bottom and right).
    """

    ndim = 2

    def __init__(self, pyramid: FramePyramid, channel: str | None):
        self.pyramid, self.channel = pyramid, channel
        self.shape: tuple[int, int] = pyramid.shape
        self.factors: tuple[int, ...] = pyramid.factors
        self.dtype = np.dtype(pyramid.dtype if channel in (None, "R", "G", "B")
                              else np.float32)
        self._levels: dict[int, np.ndarray] = {}

    @property
    def stats(self) -> tuple[float, float, float]:
        """(min, max, mean) of the plane's finite pixels (exact: gathered at level 0)."""
        lo, hi, mean = self.pyramid.stats[str(self.channel)]
        return float(lo), float(hi), float(mean)

    def level_shape(self, level: int) -> tuple[int, int]:
        f = self.factors[level]
        return -(-self.shape[0] // f), -(-self.shape[1] // f)

    def level(self, level: int) -> np.ndarray:
        """Level ``level`` ≥ 1 (memory-mapped, read only)."""
        if level < 1:
            raise ValueError("level: level 0 is read from the file (region())")
        arr = self._levels.get(level)
        if arr is None:
            arr = np.load(self.pyramid.folder / _file_name(self.channel, level), mmap_mode="r")
            self._levels[level] = arr
        return arr

    def region(self, level: int, rows: tuple[int, int], cols: tuple[int, int]) -> np.ndarray:
        """Rows ``rows[0]:rows[1]`` and columns ``cols[0]:cols[1]`` of level ``level`` (clipped
        to it; at least one pixel), read from the file (level 0) or the pyramid."""
        h, w = self.level_shape(level)
        r0, r1 = min(max(int(rows[0]), 0), h - 1), min(max(int(rows[1]), 1), h)
        c0, c1 = min(max(int(cols[0]), 0), w - 1), min(max(int(cols[1]), 1), w)
        r1, c1 = max(r1, r0 + 1), max(c1, c0 + 1)
        if level == 0:
            band = read_region(self.pyramid.path, c0, r0, c1 - c0, r1 - r0)
            return _plane(band, self.channel, self.pyramid.layout)
        return np.asarray(self.level(level)[r0:r1, c0:c1])

    def value(self, row: int, col: int) -> Any:
        """The pixel ``(row, col)`` (read from the file)."""
        return self.region(0, (row, row + 1), (col, col + 1))[0, 0]

    def coarse_level(self, max_pixels: int = COARSE_PIXELS) -> int:
        """The finest level ≥ 1 of at most ``max_pixels`` pixels (the coarsest when none is)."""
        for k in range(1, len(self.factors)):
            h, w = self.level_shape(k)
            if h * w <= max_pixels:
                return k
        return len(self.factors) - 1

    def coarse(self, max_pixels: int = COARSE_PIXELS) -> np.ndarray:
        """The level :meth:`coarse_level` (read into memory)."""
        return np.asarray(self.level(self.coarse_level(max_pixels)))


class FramePyramid:
    """The levels of one frame's channel planes on disk (see the module docstring)."""

    def __init__(self, path: Path, folder: Path, meta: dict[str, Any]):
        self.path, self.folder = Path(path), Path(folder)
        self.shape = (int(meta["shape"][0]), int(meta["shape"][1]))
        self.factors = tuple(int(f) for f in meta["factors"])
        self.channels: tuple[str | None, ...] = tuple(meta["channels"])
        self.layout: str | None = meta["layout"]
        self.dtype = np.dtype(meta["dtype"])
        self.stats: dict[str, list[float]] = meta["stats"]

    def plane(self, channel: str | None = None) -> TiledPlane:
        """The plane of ``channel`` (``None``: the frame's only plane, or the luminance)."""
        if channel is None and self.channels != (None,):
            channel = plots.LUMINANCE
        if channel not in self.channels:
            raise ValueError(f"channel: expected one of {self.channels}, got {channel!r}")
        return TiledPlane(self, channel)

    @staticmethod
    def factors_for(shape: tuple[int, int], coarsest: int = COARSEST) -> tuple[int, ...]:
        """1, 2, 4 ... up to the first factor that fits the longer side in ``coarsest``."""
        factors = [1]
        while -(-max(shape) // factors[-1]) > coarsest:
            factors.append(factors[-1] * 2)
        if len(factors) == 1:
            factors.append(2)
        return tuple(factors)

    @classmethod
    def open(cls, path: str | os.PathLike, layout: str | None = None, *,
             root: str | os.PathLike | None = None, coarsest: int = COARSEST,
             band_pixels: int = BAND_PIXELS, bound: int | None = None,
             progress: Progress | None = None) -> FramePyramid:
        """The pyramid of the frame at ``path``: reused from ``root`` (default: the cache's
        ``tiles`` folder) when built for the same path, size and modification time, else built
        (the file read once, in bands of about ``band_pixels`` pixels; ``progress(fraction,
        message)`` after each band). The least recently used other pyramids under ``root`` are then
        deleted until they all take at most ``bound`` bytes (default
        :func:`ccdcore_app.cache.store.max_bytes`).

        Raises
        ------
        ImageReadError
            The file cannot be read, or its header declares more pixel values (width x height
            x channels) than :func:`ccdcore.io.frames.pixel_limit` (refused before decoding).
        """
        path = Path(path).resolve()
        root = _tiles_root() if root is None else Path(root)
        st = os.stat(path)
        key = json.dumps({"format": FORMAT, "path": str(path), "size": st.st_size,
                          "mtime_ns": st.st_mtime_ns, "layout": layout, "coarsest": coarsest},
                         sort_keys=True)
        folder = root / hashlib.sha256(key.encode("utf-8")).hexdigest()
        meta = cls._read_meta(folder)
        if meta is not None:
            try:
                os.utime(folder / "meta.json")   # the last use, for the eviction
            except OSError:
                pass
            return cls(path, folder, meta)
        root.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(dir=root, prefix=f".{folder.name[:16]}-", suffix=".tmp"))
        try:
            meta = cls._build(path, layout, tmp, coarsest, band_pixels, progress)
            if folder.exists():    # a broken one (no meta), or another builder won the race
                if cls._read_meta(folder) is not None:
                    return cls(path, folder, cls._read_meta(folder))
                shutil.rmtree(folder, ignore_errors=True)
            try:
                os.replace(tmp, folder)
            except OSError:
                if cls._read_meta(folder) is None:
                    raise
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        _evict(root, folder, max_bytes() if bound is None else bound)
        return cls(path, folder, meta)

    @staticmethod
    def _read_meta(folder: Path) -> dict[str, Any] | None:
        try:
            meta = json.loads((folder / "meta.json").read_text())
            if meta.get("format") != FORMAT:
                return None
            for channel in meta["channels"]:
                for k in range(1, len(meta["factors"])):
                    if not (folder / _file_name(channel, k)).is_file():
                        return None
            return meta
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            return None

    @staticmethod
    def _build(path: Path, layout: str | None, folder: Path, coarsest: int, band_pixels: int,
               progress: Progress | None) -> dict[str, Any]:
        header = read_header(path)
        # the whole image against the readers' pixel limit (width x height x channels), from
        # the header: each band is within the limit on its own, so without this a small file
        # declaring 40000 x 40000 would be decoded band after band in full
        check_pixels(path, header.shape)
        h, w = header.height, header.width
        kind = _layout(header.shape, layout)
        if kind not in ("mono", "rgb"):
            raise ValueError(f"layout: a pyramid needs a mono or RGB frame, not {kind}")
        channels = _channels(kind)
        factors = FramePyramid.factors_for((h, w), coarsest)
        top = factors[-1]
        band_rows = top * max(1, band_pixels // max(w, 1) // top)
        stats = {str(c): [np.inf, -np.inf, 0.0, 0] for c in channels}
        # each band gives whole rows of every level, in order: the files are written
        # sequentially (a memory map being written would keep its pages resident)
        with contextlib.ExitStack() as files:
            levels = {}
            for c in channels:
                for k in range(1, len(factors)):
                    fh = files.enter_context(open(folder / _file_name(c, k), "wb"))
                    np.lib.format.write_array_header_1_0(fh, {
                        "descr": np.lib.format.dtype_to_descr(np.dtype(np.float32)),
                        "fortran_order": False,
                        "shape": (-(-h // factors[k]), -(-w // factors[k]))})
                    levels[(c, k)] = fh
            for y in range(0, h, band_rows):
                rows = min(band_rows, h - y)
                band = read_region(path, 0, y, w, rows)
                for c in channels:
                    plane = _plane(band, c, layout)
                    values = plane[np.isfinite(plane)] if plane.dtype.kind == "f" else plane
                    s = stats[str(c)]
                    if values.size:
                        s[0] = min(s[0], float(values.min()))
                        s[1] = max(s[1], float(values.max()))
                        s[2] += float(values.sum(dtype=np.float64))
                        s[3] += int(values.size)
                    for k in range(1, len(factors)):
                        plots.block_reduce(plane, factors[k]).astype(np.float32).tofile(
                            levels[(c, k)])
                del band
                if progress is not None:
                    progress(min((y + rows) / h, 1.0), f"preview tiles: row {y + rows} of {h}")
        out_stats = {c: ([s[0], s[1], s[2] / s[3]] if s[3] else [np.nan, np.nan, np.nan])
                     for c, s in stats.items()}
        meta = {"format": FORMAT, "shape": [h, w], "factors": list(factors),
                "channels": list(channels), "layout": layout, "dtype": str(header.dtype),
                "stats": out_stats, "source": str(path)}
        (folder / "meta.json").write_text(json.dumps(meta))
        return meta


def _folder_size(folder: Path) -> int:
    total = 0
    try:
        for f in folder.iterdir():
            try:
                total += f.stat().st_size
            except OSError:
                pass
    except OSError:
        pass
    return total


def _evict(root: Path, keep: Path, bound: int) -> list[Path]:
    """Delete the least recently used pyramids under ``root`` (their ``meta.json`` touched on
    each use), never ``keep``, until all take at most ``bound`` bytes; the deleted ones."""
    found = []
    for folder in root.iterdir():
        if folder.name.startswith(".") or not folder.is_dir() or folder == keep:
            continue
        try:
            used = (folder / "meta.json").stat().st_mtime_ns
        except OSError:
            used = 0
        found.append((used, folder.name, folder, _folder_size(folder)))
    total = _folder_size(keep) + sum(size for *_, size in found)
    removed = []
    for _, _, folder, size in sorted(found):
        if total <= bound:
            break
        shutil.rmtree(folder, ignore_errors=True)
        removed.append(folder)
        total -= size
    return removed


def overview(tiled: TiledPlane, x_range: tuple[float, float] | None,
             y_range: tuple[float, float] | None, width: int | None, height: int | None
             ) -> tuple[NDArray, tuple[float, float, float, float], int, int]:
    """The visible part of ``tiled`` at screen resolution, as :func:`ccdcore_app.plots.base.overview` with
    ``how="mean"`` gives it for the plane in memory, plus the level read.

    The level is the coarsest whose block size ``F`` does not exceed the factor the screen
    needs (so it still has at least one pixel per screen pixel); only the level's pixels under
    the visible part are read (level 0: from the file), then reduced further by
    :func:`ccdcore_app.plots.base.overview` to fit the screen. Returns the array, its bounds
    ``(left, bottom, right, top)`` in level-0 pixel coordinates, the block size in level-0 pixels
    and the level.
    """
    h, w = tiled.shape
    c0, c1 = plots.visible_span(x_range, w)
    r0, r1 = plots.visible_span(y_range, h)
    need = plots.block_factor(c1 - c0, r1 - r0, width, height)
    level = max(k for k, f in enumerate(tiled.factors) if f <= need)
    f = tiled.factors[level]
    rk0, rk1 = r0 // f, -(-r1 // f)
    ck0, ck1 = c0 // f, -(-c1 // f)
    crop = tiled.region(level, (rk0, rk1), (ck0, ck1))
    data, (left, bottom, right, top), g = plots.overview(crop, None, None, width, height,
                                                         how="mean")

    def to_full(v: float, start: int) -> float:   # level-k edge -> level-0 edge
        return (start + v + 0.5) * f - 0.5

    return data, (to_full(left, ck0), to_full(bottom, rk0), to_full(right, ck0),
                  to_full(top, rk0)), f * g, level
