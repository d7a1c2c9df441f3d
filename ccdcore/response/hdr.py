"""High-dynamic-range radiance with per-pixel uncertainty: Tsin, Ramesh & Kanade (2001), eqs. 9,
18 and 19, on a bracket's files.

Given a calibrated camera (the inverse response g, the white-balance scale a_k and offset b_k of
every image, the noise terms of eq. 7), the radiance of a pixel is the weighted mean of its
images' predictions (eq. 9), with the weights of eq. 18 and the standard deviation of eq. 19;
pixels without a usable code get a bound and a flag (``SATURATED``, ``DARK``, ``BLOOMED``).
The merge itself, on frames in memory, is :mod:`ccdcore.response.hdr_merge` (its docstring gives
the method); this module adds :func:`merge_bracket`, which reads the bracket here or runs the
merge band by band on a Dask cluster (through :mod:`ccdcore.reduce`), and re-exports the merge's names, so that
``ccdcore.response.hdr`` remains their address.

Public objects
--------------
ResponseModel
    What the merge needs of one channel's calibration: g, a, b, σ_s, σ_c1, σ_c2.
HdrResult
    Radiance, σ_E and flags per pixel (and channel), the number of images merged per pixel.
merge(frames, models, ...)
    Eqs. 9, 18, 19 over a bracket's frames (one model per channel).
merge_bracket(records, models, ..., reducer=None)
    The same over a bracket's files: read here (streamed), or band by band by the workers of a
    Dask reducer (:func:`ccdcore.distributed.client.band_merge`, bit-identical).
noise_sigma(model, z, k)
    σ(a_k, z) of eq. 7 for codes z of image k.
FLAG_OK, FLAG_DARK, FLAG_SATURATED, FLAG_BLOOMED
    The flag values (also the codes of ``flags.png``).

All but :func:`merge_bracket` are defined in :mod:`ccdcore.response.hdr_merge`.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

from numpy.typing import ArrayLike

from ..reduce import STREAMED, Reducer
from .brackets import DEFAULT_BLOOM_RADIUS
from .hdr_merge import (FLAG_BLOOMED, FLAG_DARK, FLAG_OK, FLAG_SATURATED, HdrResult,
                        ResponseModel, merge, noise_sigma)

__all__ = ["ResponseModel", "HdrResult", "merge", "merge_bracket", "noise_sigma", "FLAG_OK", "FLAG_DARK",
           "FLAG_SATURATED", "FLAG_BLOOMED"]


def merge_bracket(records: Sequence[Any], models: Mapping[str, Any] | Any, *,
                  layout: str | None = None, bloom_radius: int = DEFAULT_BLOOM_RADIUS,
                  frames: Sequence[ArrayLike] | None = None, reducer: Reducer | None = None,
                  session: Any = None, band_rows: int | None = None) -> HdrResult:
    """:func:`merge` of a bracket given as its frame records (or paths), in the models' order,
    by ``reducer`` (:meth:`ccdcore.reduce.Reducer.merge`).

    Streamed (the default): the frames (``frames`` when already read, else each file read
    here with :func:`ccdcore.io.frames.read_image`) are merged whole.  With a Dask reducer
    (:class:`ccdcore.distributed.client.DaskReducer`) the frames are read by the workers, band by
    band with a halo covering the blooming disk (:func:`ccdcore.distributed.client.band_merge`); the
    result is bit-identical.  The frames' shapes, integer codes and layout are then checked
    first, from the headers (``session``'s cache when given), with :func:`merge`'s messages;
    ``band_rows`` sets the band height (frame rows).
    """
    return (reducer or STREAMED).merge(records, models, layout=layout,
                                       bloom_radius=bloom_radius, frames=frames,
                                       session=session, band_rows=band_rows)
