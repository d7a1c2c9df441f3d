"""The HDR merge of a bracket (eqs. 9, 18, 19) on a Dask cluster, band by band of rows with a
halo covering the blooming disk (issue #14; re-exported by :mod:`ccdcore.distributed.client`).

Each band's task reads its rows of every frame plus :func:`merge_halo` rows above and below
(:func:`ccdcore.distributed.band_tasks.read_band`) and runs the same
:func:`ccdcore.response.hdr_merge.merge` on them: bit-identical to the whole-frame merge.

Imports: :mod:`ccdcore.distributed.band_tasks` (whose :func:`~ccdcore.distributed.band_tasks.bands`
and
:data:`~ccdcore.distributed.band_tasks.BAND_BYTES` are looked up there when a merge runs, so a
patch of them takes effect), :mod:`ccdcore.errors`, :mod:`ccdcore.channels` and
:mod:`ccdcore.response.hdr_merge`.

Public objects
--------------
merge_halo(layout, bloom_radius)
    Rows of halo a band of a bracket needs above and below.
check_bracket(records, session=None, layout=None)
    The merge's checks of its frames, from their headers.
band_merge(client, frames, models, ...)
    The merge of a bracket on the cluster.
"""
from __future__ import annotations

import contextlib
from typing import Any, Mapping, Sequence

import numpy as np

from . import band_tasks as dask_bands
from .band_tasks import (Frame, check_pixels, frames_of, gather_in_order, headers_of,
                         portable_error, read_band, submit_tasks)
from ..errors import CcdError

__all__ = ["merge_halo", "check_bracket", "band_merge"]


def merge_halo(layout: str, bloom_radius: int) -> int:
    """Rows of halo a band of a bracket needs above and below (raw frame rows).

    The only non-local rule of :func:`ccdcore.response.hdr.merge` is the blooming mask: a pixel
    within ``bloom_radius`` (a Euclidean disk, in the channel plane's pixels) of a saturated
    pixel of the same plane.  A disk of radius r reaches r plane rows, which are r frame rows
    for mono and RGB data and 2r for a Bayer mosaic (a CFA plane takes every second row); the
    halo is even then, so the band read still starts on the CFA's first row.  Every other step
    (g, σ, the weights, the fallbacks and their bounds) is per pixel.
    """
    from ..channels import is_bayer

    r = max(0, int(bloom_radius))
    return 2 * r if is_bayer(layout) else r


def check_bracket(records: Sequence[Any], session: Any = None, layout: str | None = None
                  ) -> tuple[tuple[int, ...], str]:
    """The checks :func:`ccdcore.response.hdr.merge` makes of its frames, from the headers and
    with the same messages (every frame of the first one's shape, integer codes, a shape that
    fits ``layout``); returns the frames' shape and the layout."""
    from ..channels import check_layout

    if len(records) < 1:
        raise CcdError("bracket", "no frames to merge")
    first: tuple[int, ...] | None = None
    for k, (_, hdr) in enumerate(headers_of(records, session)):
        shape = tuple(hdr.shape)
        if first is None:
            first = shape
        if shape != first:
            raise CcdError(f"frame {k}", f"shape {shape} differs from the first frame's {first}")
        if not np.issubdtype(np.dtype(hdr.dtype), np.integer):
            raise CcdError(f"frame {k}", f"expected integer codes, got {np.dtype(hdr.dtype)}")
    assert first is not None
    return first, check_layout(first, layout, "bracket")


def _merge_task(frames: tuple[Frame, ...], y0: int, rows: int, top: int, bottom: int,
                width: int, models: Any, layout: str, bloom_radius: int, step: int) -> tuple:
    """:func:`ccdcore.response.hdr.merge` of rows ``y0 - top .. y0 + rows + bottom`` of every
    frame; the rows of the band itself (``step`` frame rows per output row): ("ok", radiance,
    sigma, flags, used, channels) or ("error", position, CcdError), a read error at the
    frame's position, an error of the merge after every frame (position ``len(frames)``)."""
    from ..response.hdr_merge import merge

    y, h = y0 - top, top + rows + bottom
    arrays = []
    for k, f in enumerate(frames):
        try:
            arrays.append(read_band(f, 0, y, width, h))
        except CcdError as err:
            return ("error", k, portable_error(err))
    try:
        res = merge(arrays, models, layout=layout, bloom_radius=bloom_radius)
    except CcdError as err:
        return ("error", len(frames), portable_error(err))
    keep = slice(top // step, (top + rows) // step)
    return ("ok", res.radiance[keep], res.sigma[keep], res.flags[keep], res.used[keep],
            res.channels)


def band_merge(client: Any, paths_or_records: Sequence[Any], models: Any, *, layout: str,
               bloom_radius: int, shape: tuple[int, ...], band_rows: int | None = None) -> Any:
    """:func:`ccdcore.response.hdr.merge` of a bracket on the cluster, one task per row band.

    Each task reads its band of every frame (records or paths, in the order of the models'
    ``a`` and ``b``) plus :func:`merge_halo` rows above and below (fewer at the frame's top and
    bottom, where the whole-frame merge has no rows either), runs the same ``merge`` on it and
    returns the band's own rows; the client writes them into the maps.  Every output pixel then
    sees the same codes within its blooming disk and the same per-pixel operations, so the
    :class:`~ccdcore.response.hdr.HdrResult` is **bit-identical** to ``merge`` on the whole
    frames (radiance, sigma, flags, used).

    ``shape`` is the frames' shape, checked by the caller (:func:`check_bracket`); ``layout``
    the channel layout (Bayer bands and halos keep an even number of rows); ``band_rows``
    the band height in frame rows (default: about
    :data:`~ccdcore.distributed.band_tasks.BAND_BYTES` of the merge's float64 temporaries, which
    hold every frame of the band).  A frame that cannot be read gives the streamed reader's error
    (the first in the bracket's order); an error of the merge itself (codes outside the response, a
    model per channel missing) its own message.
    """
    from ..channels import check_layout, is_bayer
    from ..response.hdr_merge import HdrResult, ResponseModel

    fr = frames_of(paths_or_records)
    if not fr:
        raise CcdError("bracket", "no frames to merge")
    check_pixels(fr[0].path, shape)
    lay = check_layout(tuple(shape), layout, "bracket")
    if isinstance(models, Mapping):
        portable: Any = {c: ResponseModel.of(m) for c, m in models.items()}
    else:
        portable = ResponseModel.of(models)
    h, w = int(shape[0]), int(shape[1])
    chans = shape[2] if len(shape) == 3 else 1
    bayer = is_bayer(lay)
    step = 2 if bayer else 1
    halo = merge_halo(lay, bloom_radius)
    # the merge holds about six float64 (or int64) arrays of N frames per pixel and channel
    cut = dask_bands.bands(h, w, channels=max(1, 2 * chans * len(fr)), band_rows=band_rows,
                           even=bayer)
    args = [(fr, y0, rows, min(halo, y0), min(halo, h - y0 - rows), w, portable, lay,
             int(bloom_radius), step) for y0, rows in cut]
    futures = submit_tasks(client, _merge_task, args)
    maps: list[np.ndarray] = []
    names: list[tuple[str, ...]] = []

    def place(g: int, i: int, result: tuple) -> None:
        if not maps:
            for part, dtype in zip(result[1:5], (np.float64, np.float64, np.uint8, np.int16)):
                maps.append(np.empty((h // step,) + part.shape[1:], dtype))
            names.append(result[5])
        y0, rows = cut[i]
        for m, part in zip(maps, result[1:5]):
            m[y0 // step:(y0 + rows) // step] = part

    with contextlib.closing(gather_in_order(client, [futures], [0], len(futures),
                                             place)) as done:
        next(done)
    radiance, sigma, flags, used = maps
    return HdrResult(radiance, sigma, flags, used, names[0], lay)

