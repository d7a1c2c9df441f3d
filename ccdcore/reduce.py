"""The reduction layer: every per-pixel reduction over frames that an estimator needs, run by
one :class:`Reducer` chosen once for a whole computation.

An estimator (:mod:`ccdcore.dark.frame`, :mod:`ccdcore.noise`, :mod:`ccdcore.fixedpattern`,
:mod:`ccdcore.flatfield.fit`, :mod:`ccdcore.response.hdr`) takes ``reducer=`` (``None``:
:data:`STREAMED`), checks its own inputs and calls the reducer's methods; it never imports Dask and
never asks where the work runs. Two reducers exist:

* :class:`Reducer` itself (:data:`STREAMED`): the frames are streamed through this process,
  read ahead in threads (:meth:`ccdcore.session.Session.iter_frames`), into the compiled
  accumulators below (:class:`~ccdcore.stats.PixelMoments`, :func:`~ccdcore.stats.pair_statistics`,
  :mod:`ccdcore.kmap_kernels`, :func:`ccdcore.response.hdr_merge.merge`);
* :class:`ccdcore.distributed.client.DaskReducer`: the same reductions on a Dask cluster, band by
band
  of rows, bit-identical (photon-transfer variances to 1e-12); it checks the frames from their
  headers first, with the messages the streamed path gives.
  :func:`ccdcore.distributed.client.open_reducer` makes the one a command asks for (``--workers``,
  ``--scheduler``).

The estimator-specific checks of a frame are handed in as callables ``check(name, frame)``; the
cluster calls them with a zero-memory stand-in of the frame built from its header (a broadcast
array of the header's shape and dtype), so one check serves both.

Public objects
--------------
Reducer, STREAMED
    The reductions, streamed; the one streamed reducer.
READ_AHEAD
    Frames decoded ahead in threads by the streamed reductions.
Check
    The type of a frame check: ``check(name, frame) -> None``, raising :class:`CcdError`.
stand_in(header)
    A zero-memory array of a header's shape and dtype, for checks made from headers.
"""
from __future__ import annotations

import contextlib
import itertools
import os
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

import numpy as np

from . import channels as chan
from .common import named_frames
from .errors import CcdError
from .reduce_names import STREAMED_NAME
from .kmap_kernels import (NO_SIGMA, NOT_LIT, FixedPattern, eq49_reject, fixed_pattern_of,
                           local_mean, slope_moments, slopes_into)
from .stats import MomentsResult, PixelMoments, pair_statistics

__all__ = ["Reducer", "STREAMED", "READ_AHEAD", "Check", "stand_in", "PairLevel"]

#: frames decoded ahead in threads by the streamed reductions
READ_AHEAD = min(4, os.cpu_count() or 1)

#: ``check(name, frame)``: raise :class:`CcdError` for a frame the estimator cannot use
Check = Callable[[str, np.ndarray], None]
#: per level: the pairs' μ̂ and σ̂²_N (eqs. 37, 38), clipped and all ROI values, and M
PairLevel = tuple[list[float], list[float], int, int, int]


def stand_in(header: Any) -> np.ndarray:
    """A zero-memory array of ``header``'s shape and dtype (checks made from headers)."""
    return np.broadcast_to(np.zeros((), header.dtype), tuple(header.shape))


def _is_session(obj: Any) -> bool:
    return hasattr(obj, "iter_frames") and hasattr(obj, "header")


class Reducer:
    """The per-pixel reductions over frames, streamed through this process.

    Subclasses (:class:`ccdcore.distributed.client.DaskReducer`) run the same reductions elsewhere
    with the same results; every method says what it returns, whoever runs it."""

    #: what a product's provenance records as the scheduler
    description: str = STREAMED_NAME

    # ------------------------------------------------------------------------------ moments --
    def moments(self, frames: Any, *, what: str, session: Any = None,
                check: Check | None = None, zeros: dict | None = None,
                layout: str | None = None, even: bool = False,
                name: Callable[[int], str] | None = None, empty: str | None = None
                ) -> tuple[MomentsResult, str]:
        """The per-pixel mean and variance of ``frames`` and the first frame's name.

        ``frames``: records or paths of ``session`` (read ahead), arrays or ``(record, array)``
        pairs. ``check`` is called on every frame before it is added; ``name(i)`` names a frame
        without a record (default ``"<what> frame <i>"``, NaN and infinite values refused).
        ``zeros``: filled per channel of ``layout`` with (zero values, values), the flat
        field's check of its dark image. ``even`` keeps bands of even height on a cluster
        (colour mosaics); the streamed sums do not depend on it. Raises ``CcdError(what,
        empty)`` (default "no <what> frames") when there is none."""
        acc = PixelMoments()
        first = None
        lay = layout
        # closed on an error too: the read-ahead threads of a session's stream stop at once
        with contextlib.closing(self._named(frames, what, session, name)) as named:
            for nm, arr in named:
                if check is not None:
                    check(nm, arr)
                first = first or nm
                acc.add(arr, name=nm)
                if zeros is not None:
                    lay = chan.check_layout(arr.shape, lay, nm)
                    for c, v in chan.split_channels(arr, lay).items():
                        z, n = zeros.get(c, (0, 0))
                        zeros[c] = (z + int(np.count_nonzero(v == 0)), n + v.size)
        if acc.n == 0:
            raise CcdError(what, empty or f"no {what} frames")
        return acc.result(in_place=True), str(first)

    @staticmethod
    def _named(frames: Any, what: str, session: Any, name: Callable[[int], str] | None
               ) -> Iterator[tuple[str, np.ndarray]]:
        """``(name, array)`` of every frame, records read through the session ahead."""
        items = list(frames) if not isinstance(frames, (Iterator, np.ndarray)) else frames
        if (session is not None and isinstance(items, list) and items
                and hasattr(items[0], "relpath") and not isinstance(items[0], tuple)):
            items = session.iter_frames(items, read_ahead=READ_AHEAD)
        with contextlib.closing(items) if hasattr(items, "close") else contextlib.nullcontext():
            if name is None:
                yield from named_frames(items, what)
                return
            for k, item in enumerate(items):
                rec, arr = item if isinstance(item, tuple) else (None, item)
                yield getattr(rec, "relpath", None) or name(k), np.asarray(arr)

    # ---------------------------------------------------------------------------- frame sums --
    def frame_sums(self, session: Any, records: Sequence[Any], *,
                   pixels: Callable[[Any, np.ndarray], np.ndarray],
                   header_pixels: Callable[[Any], np.ndarray],
                   roi: tuple[int, int, int, int] | None,
                   nonfinite: Callable[[str, int], CcdError]
                   ) -> Iterator[tuple[Any, tuple[float, int]]]:
        """Per frame in order: the sum and the number of its ROI pixel values (exact for
        integer data). ``pixels(record, frame)`` checks a frame and gives its ROI values;
        ``header_pixels(record)`` makes the same checks from the header (cluster);
        ``nonfinite(name, count)`` is the error of a frame with NaN or infinite values."""
        for rec, frame in session.iter_frames(records, read_ahead=READ_AHEAD):
            pix = pixels(rec, frame)
            yield rec, (float(pix.sum(dtype=np.float64)), pix.size)

    # --------------------------------------------------------------------------- pair sums --
    def pair_stats(self, session: Any, paired: Mapping[int, Sequence[Any]], *,
                   pixels: Callable[[Any, np.ndarray], np.ndarray],
                   header_pixels: Callable[[Any], np.ndarray],
                   roi: tuple[int, int, int, int] | None, full: float | None,
                   nonfinite: Callable[[str, int], CcdError]) -> Iterator[PairLevel]:
        """Per level of ``paired`` (records in pairs 0-1, 2-3, ...), in order: the pairs' μ̂
        and σ̂²_N (eqs. 37, 38), the clipped (<= 0 or >= ``full``) and all ROI pixel values, and
        M. One stream over the frames; the arguments as :meth:`frame_sums`."""
        stream = session.iter_frames([r for recs in paired.values() for r in recs],
                                     read_ahead=READ_AHEAD)
        for level, recs in paired.items():
            mus, vars_, clipped, count, m = [], [], 0, 0, 0
            frames = itertools.islice(stream, len(recs))
            for (r1, f1), (r2, f2) in zip(frames, frames):
                p1, p2 = pixels(r1, f1), pixels(r2, f2)
                if p1.shape != p2.shape:
                    raise CcdError(r2.relpath, f"shape {p2.shape} differs from {r1.relpath} "
                                               f"{p1.shape}")
                if full is not None:
                    clipped += int(np.count_nonzero(p1 <= 0) + np.count_nonzero(p1 >= full)
                                   + np.count_nonzero(p2 <= 0) + np.count_nonzero(p2 >= full))
                count += p1.size + p2.size
                mu, var, _, m = pair_statistics(p1, p2)
                mus.append(mu)
                vars_.append(var)
            yield mus, vars_, clipped, count, m

    # ---------------------------------------------------------------------------- HDR merge --
    def preload(self, session: Any, records: Sequence[Any]) -> list[np.ndarray] | None:
        """The frames of ``records`` read in this process when :meth:`merge` wants them as
        read (streamed); ``None`` when its workers read them. Decoded :data:`READ_AHEAD` at a
        time in threads (the same arrays as ``session.read``, in order)."""
        return [frame for _, frame in session.iter_frames(list(records), read_ahead=READ_AHEAD)]

    def merge(self, records: Sequence[Any], models: Any, *, layout: str | None,
              bloom_radius: int, frames: Sequence[Any] | None = None, session: Any = None,
              band_rows: int | None = None) -> Any:
        """The HDR merge of a bracket (:func:`ccdcore.response.hdr_merge.merge`): ``frames``
        when already read, else every record's file read here. ``session`` (header cache) and
        ``band_rows`` (band height) serve a cluster."""
        from .io.frames import read_image
        from .response.hdr_merge import merge

        if frames is None:
            frames = [read_image(getattr(r, "path", r)) for r in records]
        return merge(frames, models, layout=layout, bloom_radius=bloom_radius)

    # ----------------------------------------------------------------------- fixed pattern K̂ --
    def fixed_pattern(self, source: Any, *, dark_of: Callable[[Any], np.ndarray], window: int,
                      p: float, center: str) -> FixedPattern:
        """K̂ (eqs. 45–50) of the fixed-pattern frames ``source`` (a session, a mapping
        ``config id -> frames``, a sequence of such iterables or an ``(n1, n2, H, W)`` array);
        ``dark_of(session)`` gives the dark map D̂_D (``session`` ``None`` without one), asked
        after the configurations are counted. Raises as
        :func:`ccdcore.fixedpattern.fixed_pattern_map` documents."""
        configs, session = self.configurations(source)
        where = str(getattr(session, "root", "fixed_pattern"))
        notes: list[str] = []
        dmap = self._dark_map(session, dark_of, configs, where, notes)
        shape = dmap.shape
        n1 = len(configs)
        slopes = np.empty((n1,) + shape, dtype=np.float32)   # the n1 slope maps m_i (eq. 47)
        e_bar = np.empty(shape)                               # ē_i, reused for every configuration
        ids, levels, noises, n2s = [], [], [], []
        averages = (_average_config(cid, frames, shape, "the dark reference")
                    for cid, frames in configs)
        for i, ((cid, _), (e, noise, n2, name)) in enumerate(zip(configs, averages)):
            np.subtract(e, dmap, out=e)                             # eq. 46, e_i = average − D̂_D
            local_mean(e, window, e_bar)                           # ē_i, the m×m local mean
            level = float(e.mean())
            if level <= 0:
                raise CcdError(name, NOT_LIT.format(cid=cid, level=level))
            slopes_into(e, e_bar, slopes[i])                       # eq. 47
            ids.append(cid)
            levels.append(level)
            noises.append(noise)
            n2s.append(n2)
            del e
        del e_bar
        # eq. 48: m̄, and the per-pixel sample std of the slopes (one compiled pass)
        m_bar = np.empty(shape)
        sd = np.empty(shape)
        slope_moments(slopes.reshape(n1, -1), m_bar.reshape(-1), sd.reshape(-1))
        sigma_hat = float(np.nanmean(sd)) if np.isfinite(sd).any() else float("nan")
        del sd
        if not np.isfinite(sigma_hat):
            raise CcdError(where, NO_SIGMA)
        K, rejected, used, K_var, none = eq49_reject(slopes, m_bar, p * sigma_hat, center)
        del slopes
        return fixed_pattern_of(K, used, rejected, m_bar, K_var, sigma_hat=sigma_hat, p=p,
                                window=window, center=center, none=none, ids=ids,
                                levels=levels, noises=noises, n2s=n2s, notes=notes)

    @staticmethod
    def _dark_map(session: Any, dark_of: Callable[[Any], np.ndarray], configs: list,
                  where: str, notes: list[str]) -> np.ndarray:
        """The dark map of K̂, asked once the configurations are counted (that message
        comes first)."""
        n1 = len(configs)
        if n1 < 2:
            raise CcdError(where, f"{n1} fixed-pattern configuration{'s' if n1 != 1 else ''}: "
                                  "K̂ needs at least 2 (sec. V-B; the paper used 20), each a "
                                  "new position of card and lamp")
        if n1 < 3:
            notes.append(f"only n1 = {n1} configurations: outlier rejection cannot tell which "
                         "slope is the outlier (capture at least 3, better 10-20)")
        dmap = dark_of(session)
        if dmap.ndim != 2:
            raise CcdError("dark", f"the dark reference must be a 2-D map, got shape "
                                   f"{dmap.shape}")
        return dmap

    def configurations(self, source: Any) -> tuple[list[tuple[Any, Any]], Any]:
        """``[(config id, frames)]`` of the fixed-pattern frames ``source`` and its session (or
        ``None``); streamed, one stream over every configuration read ahead in threads."""
        if hasattr(source, "fixed_pattern_configs") and _is_session(source):
            cfgs = source.fixed_pattern_configs()
            stream = source.iter_frames([r for recs in cfgs.values() for r in recs],
                                        read_ahead=READ_AHEAD)
            return ([(cid, itertools.islice(stream, len(recs))) for cid, recs in cfgs.items()],
                    source)
        if isinstance(source, Mapping):
            return list(source.items()), None
        if isinstance(source, np.ndarray):
            if source.ndim != 4:
                raise CcdError("configs", f"an array of configurations must be (n1, n2, H, W), "
                                          f"got shape {source.shape}")
            return [(i + 1, source[i]) for i in range(source.shape[0])], None
        return [(i + 1, c) for i, c in enumerate(source)], None


def _average_config(cid: Any, frames: Iterable, ref_shape: tuple | None,
                    ref_name: str | None) -> tuple[np.ndarray, float, int, str]:
    """Stream-average one configuration's frames (eq. 45): mean, mean variance, n2, first name."""
    acc = PixelMoments()
    first = None
    if isinstance(frames, np.ndarray) and frames.ndim == 2:
        frames = [frames]  # an already averaged configuration
    for k, item in enumerate(frames):
        rec, arr = item if isinstance(item, tuple) else (None, item)
        name = getattr(rec, "relpath", None) or f"configuration {cid} frame {k}"
        arr = np.asarray(arr)
        if arr.ndim == 3:
            raise CcdError(name, f"colour frames {arr.shape}: the fixed-pattern map is mono only "
                                 "for now; per channel support comes with the flat-field work")
        if first is None:
            first = name
            if ref_shape is not None and arr.shape != ref_shape:
                raise CcdError(name, f"frame shape {arr.shape} differs from {ref_name}'s "
                                     f"{ref_shape}")
        acc.add(arr, name=name)
    if acc.n == 0:
        raise CcdError(f"configuration {cid}", "has no frames")
    res = acc.result(in_place=True)   # the mean is then e_i's buffer (eq. 46)
    noise = float(np.mean(res.var)) / res.n if res.n > 1 else float("nan")
    return res.mean, noise, res.n, first


#: the one streamed reducer
STREAMED = Reducer()
