"""The band reductions of :mod:`ccdcore.distributed.client`: bands of rows, reading a band of a
frame on a worker, the tasks, submitting and gathering, and the reductions built on them (issue
#14).

On the cluster the frame is cut into horizontal **bands** of rows (:func:`bands`); one task per
(band, group of frames) opens each frame's file itself by path, through the same reader as the
streamed path (:func:`read_band`, :func:`ccdcore.io.frames.read_region`), and folds the band into
the same accumulator in the same frame order: per-pixel moments (:func:`band_moments`,
:func:`group_moments`, :func:`iter_group_moments`), zero counts (:func:`zero_counts`),
photon-transfer pairs (:func:`pair_sums`) and frame sums (:func:`frame_sums`).  See
:mod:`ccdcore.distributed.client` for the accuracy of each, the memory per task and the failures.

Tests patch :data:`BAND_BYTES` and :func:`bands` here: every reduction looks them up in this
module when it runs (:mod:`ccdcore.distributed.hdr` and :mod:`ccdcore.distributed.kmap` as
``dask_bands.bands``).  Task functions are module-level, so Dask pickles them by reference.

Imports: :mod:`ccdcore.errors`, :mod:`ccdcore.io.frames`, :mod:`ccdcore.progress`,
:mod:`ccdcore.stats`, :mod:`ccdcore.channels` only (never :mod:`ccdcore.distributed.client`, which
re-exports the public names of this module).

Public objects
--------------
Frame, frames_of(records), headers_of(records, session), check_averageable(frame, header, first)
    A frame as a task reads it; per record or path; with its header; the averaging checks.
check_pixels(path, shape)
    The streamed reader's pixel limit, from a header, before anything is submitted.
bands(height, width, ...)
    The bands ``(y0, rows)`` of a frame.
band_moments, group_moments, iter_group_moments, zero_counts, pair_sums, PairSums, frame_sums
    The band reductions.
BAND_BYTES, RETRIES, PTC_RTOL
    Band size target, task retries, σ̂²_N tolerance.
read_band(frame, x, y, w, h), portable_error(err), rebuilt_error(parts)
    Helpers of the tasks (shared with :mod:`ccdcore.distributed.hdr` and
    :mod:`ccdcore.distributed.kmap`): a band of a frame with the streamed reader's errors; a
    :class:`CcdError` as picklable parts and back.
submit_tasks(client, func, args_list), gather_in_order(client, groups, counter, total, place)
    Submitting tasks with :data:`RETRIES`; gathering their results in band order.
"""
from __future__ import annotations

import contextlib
import math
import os
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

import numpy as np

from ..errors import CcdError, ImageReadError
from ..io.frames import read_image, read_region
from ..progress import Cancelled, checkpoint
from ..stats import MomentsResult, PixelMoments

__all__ = ["Frame", "frames_of", "headers_of", "check_averageable", "check_pixels", "bands",
           "band_moments", "group_moments", "iter_group_moments", "zero_counts", "pair_sums",
           "PairSums", "frame_sums", "BAND_BYTES", "RETRIES", "PTC_RTOL", "read_band",
           "portable_error", "rebuilt_error", "submit_tasks", "gather_in_order"]

#: target size of one band's accumulators (bytes) when ``band_rows`` is not given
BAND_BYTES = 32 * 2 ** 20
#: how many times Dask reruns a task whose worker was lost
RETRIES = 3
#: relative tolerance of σ̂²_N (eq. 38) merged over bands against the streamed two-pass value
PTC_RTOL = 1e-12


@dataclass(frozen=True)
class Frame:
    """One frame as a task reads it: the file's ``path`` and the ``name`` messages use (the
    record's ``relpath``, as in the streamed path)."""

    path: str
    name: str


def frames_of(records: Iterable[Any]) -> tuple[Frame, ...]:
    """:class:`Frame` per :class:`~ccdcore.session.FrameRecord` (``path``, ``relpath``) or path."""
    out = []
    for r in records:
        if isinstance(r, Frame):
            out.append(r)
        elif hasattr(r, "path") and hasattr(r, "relpath"):
            out.append(Frame(str(r.path), str(r.relpath)))
        elif isinstance(r, (str, os.PathLike)):
            out.append(Frame(str(r), str(r)))
        else:
            raise CcdError("frames", "on a cluster, frames are given as session records or file "
                                     f"paths (the workers read them), not {type(r).__name__}")
    return tuple(out)


def headers_of(records: Sequence[Any], session: Any = None) -> list[tuple[Frame, Any]]:
    """``(Frame, ImageHeader)`` per record or path, in order: from the session's header cache
    for its records, else read here (:func:`ccdcore.io.frames.read_header`: the streamed reader's
    error for a file whose header does not read); a frame above the pixel limit is refused
    (:func:`check_pixels`)."""
    from ..io.frames import read_header

    out = []
    for rec, frame in zip(records, frames_of(records)):
        if session is not None and hasattr(rec, "relpath"):
            out.append((frame, session.header(rec)))
        else:
            out.append((frame, read_header(frame.path)))
        check_pixels(frame.path, out[-1][1].shape)
    return out


def check_averageable(frame: Frame, header: Any, first: tuple[int, ...] | None
                      ) -> tuple[int, ...]:
    """The checks :meth:`ccdcore.stats.PixelMoments.add` makes of a frame, from its header and
    with the same messages (shape of the first frame, a numeric dtype); returns the first
    frame's shape (``header``'s when ``first`` is ``None``)."""
    shape = tuple(header.shape)
    if first is not None and shape != tuple(first):
        raise CcdError(frame.name, f"frame shape {shape} differs from the first frame's "
                                   f"{tuple(first)}")
    if np.dtype(header.dtype).kind not in "uifb":
        raise CcdError(frame.name, f"cannot average frames of dtype {header.dtype}")
    return shape if first is None else tuple(first)


# --------------------------------------------------------------------------------------------
# bands
# --------------------------------------------------------------------------------------------
def bands(height: int, width: int, *, channels: int = 1, band_rows: int | None = None,
          even: bool = False) -> list[tuple[int, int]]:
    """The bands ``(y0, rows)`` covering ``height`` rows, top to bottom.

    At most ``band_rows`` rows each (default: the rows whose three float64 accumulators take
    about :data:`BAND_BYTES`), as many bands as that needs, of nearly equal heights (so no
    short last band idles the cluster).  ``even`` (Bayer data) keeps the heights even, so every
    band starts on the CFA's first row.
    """
    if band_rows is None:
        band_rows = max(1, BAND_BYTES // (3 * 8 * max(1, width * channels)))
    rows = int(band_rows)
    if rows < 1:
        raise CcdError("band_rows", f"must be at least 1, got {band_rows}")
    if even:
        rows = max(2, rows - rows % 2)
    count = -(-height // rows)
    rows = -(-height // count)
    if even:
        rows += rows % 2
    return [(y, min(rows, height - y)) for y in range(0, height, rows)]


def check_pixels(path: str | os.PathLike, shape: Sequence[int]) -> None:
    """Refuse a frame of ``shape`` (from its header) above the pixel limit of the streamed
    reader (:func:`ccdcore.io.frames.pixel_limit`: width x height x channels pixel values), before
    anything is submitted or decoded.

    A band read (:func:`ccdcore.io.frames.read_region`) only bounds the band, so without this a
    small file declaring 40000 x 40000 pixels would be decoded band after band for minutes, and the
    client would allocate its full-size maps. Raises :class:`ImageReadError` naming ``path``.
    """
    from ..io.frames import check_pixel_limit

    h, w = int(shape[0]), int(shape[1])
    c = int(shape[2]) if len(shape) > 2 else 1
    check_pixel_limit(path, w, h, c)


_CHECKED: dict[tuple[str, int, int], tuple[int, ...]] = {}


def _check_file_pixels(path: str) -> None:
    """:func:`check_pixels` of a file from its header, on a worker: each file (by path, size
    and modification time) is read for its header once per process."""
    from ..io.frames import read_header

    try:
        st = os.stat(path)
    except OSError:
        return                      # the read that follows gives the streamed error
    key = (path, st.st_size, st.st_mtime_ns)
    shape = _CHECKED.get(key)
    if shape is None:
        shape = tuple(read_header(path).shape)
        if len(_CHECKED) > 4096:
            _CHECKED.clear()
        _CHECKED[key] = shape
    check_pixels(path, shape)


def read_band(frame: Frame, x: int, y: int, w: int, h: int) -> np.ndarray:
    """Rows ``y:y+h``, columns ``x:x+w`` of a frame; a file that does not decode gives the
    streamed reader's own error (it is read whole with :func:`read_image`), one whose header
    declares more pixels than the limit the streamed reader's refusal (nothing decoded)."""
    _check_file_pixels(frame.path)
    try:
        return read_region(frame.path, x, y, w, h)
    except ImageReadError:
        read_image(frame.path)
        raise


def portable_error(err: CcdError) -> tuple[type, str | None, str]:
    """A :class:`CcdError` as (class, where, problem): the error classes take two arguments,
    which pickle does not pass back, so the error travels as its parts."""
    return type(err), err.where, err.problem


def rebuilt_error(parts: tuple[type, str | None, str]) -> CcdError:
    """The :class:`CcdError` of :func:`portable_error`'s parts, as it was raised."""
    cls, where, problem = parts
    return cls(where, problem)


# --------------------------------------------------------------------------------------------
# tasks (run on the workers; plain functions of their arguments, so Dask can rerun them)
# --------------------------------------------------------------------------------------------
def _moments_task(frames: tuple[Frame, ...], x: int, y: int, w: int, h: int) -> tuple:
    """PixelMoments over one band of ``frames``, in order: ("ok", mean, var, n) or
    ("error", position, CcdError)."""
    acc = PixelMoments()
    for k, f in enumerate(frames):
        try:
            acc.add(read_band(f, x, y, w, h), name=f.name)
        except CcdError as err:
            return ("error", k, portable_error(err))
    res = acc.result(in_place=True)
    return ("ok", res.mean, res.var, res.n)


def _zeros_task(frames: tuple[Frame, ...], x: int, y: int, w: int, h: int,
                layout: str) -> tuple:
    """Per channel, the zero pixel values of one band of ``frames`` (the flat field's
    zero-dark check): ("ok", {channel: zeros}) or ("error", position, CcdError)."""
    from ..channels import split_channels

    zeros: dict[str, int] = {}
    for k, f in enumerate(frames):
        try:
            band = read_band(f, x, y, w, h)
        except CcdError as err:
            return ("error", k, portable_error(err))
        for c, v in split_channels(band, layout).items():
            zeros[c] = zeros.get(c, 0) + int(np.count_nonzero(v == 0))
    return ("ok", zeros)


def _pairs_task(pairs: tuple[tuple[Frame, Frame], ...], x: int, y: int, w: int, h: int,
                full: float | None) -> tuple:
    """Per pair, the band's [Σa, Σb, n, Σd, Σ(d − d̄)², clipped, non-finite a, non-finite b]
    (d = a − b, d̄ the band's mean of d): ("ok", array (n_pairs, 8)) or ("error", position of
    the frame in the pairs' order, CcdError)."""
    out = np.zeros((len(pairs), 8))
    for i, (f1, f2) in enumerate(pairs):
        arrays = []
        for j, f in enumerate((f1, f2)):
            try:
                arrays.append(read_band(f, x, y, w, h))
            except CcdError as err:
                return ("error", 2 * i + j, portable_error(err))
        p1, p2 = arrays
        bad = [int(np.count_nonzero(~np.isfinite(p))) if p.dtype.kind == "f" else 0
               for p in (p1, p2)]
        a = np.asarray(p1, dtype=np.float64)
        b = np.asarray(p2, dtype=np.float64)
        n = a.size
        d = a - b
        sd = float(d.sum())
        d -= sd / n
        d *= d
        clipped = 0
        if full is not None:
            clipped = int(np.count_nonzero(p1 <= 0) + np.count_nonzero(p1 >= full)
                          + np.count_nonzero(p2 <= 0) + np.count_nonzero(p2 >= full))
        out[i] = (a.sum(), b.sum(), n, sd, d.sum(), clipped, bad[0], bad[1])
    return ("ok", out)


def _sums_task(frames: tuple[Frame, ...], x: int, y: int, w: int, h: int) -> tuple:
    """Per frame, the band's [sum, count, non-finite] (float64): ("ok", array (n, 3)) or
    ("error", position, CcdError)."""
    out = np.zeros((len(frames), 3))
    for k, f in enumerate(frames):
        try:
            p = read_band(f, x, y, w, h)
        except CcdError as err:
            return ("error", k, portable_error(err))
        bad = int(np.count_nonzero(~np.isfinite(p))) if p.dtype.kind == "f" else 0
        out[k] = (p.sum(dtype=np.float64), p.size, bad)
    return ("ok", out)


# --------------------------------------------------------------------------------------------
# submitting and gathering
# --------------------------------------------------------------------------------------------
def submit_tasks(client: Any, func: Callable, args_list: Sequence[tuple]) -> list:
    """One future of ``func(*args)`` per ``args`` of ``args_list``, each rerun up to
    :data:`RETRIES` times on a lost worker."""
    return [client.submit(func, *args, retries=RETRIES, pure=False) for args in args_list]


def gather_in_order(client: Any, groups: list[list], counter: list[int], total: int,
                     place: Callable[[int, int, tuple], None] | None = None
                     ) -> Iterator[list]:
    """Yield each group's results (in band order) once its futures are done, group by group.

    Each band is fetched as soon as it is done and its future released (the worker drops it);
    with ``place(group, band, result)`` the result is handed over there and not kept (the
    list then holds ``None``), so the client holds one copy of the maps.  Each finished band
    counts as one step for :func:`ccdcore.progress.checkpoint`.  A group whose tasks report
    read errors raises the error of the earliest frame (streamed order); on any exit the
    remaining futures are cancelled.
    """
    from distributed import as_completed

    try:
        for g, futures in enumerate(groups):
            index = {f.key: i for i, f in enumerate(futures)}
            results: list = [None] * len(futures)
            errors = []
            for fut in as_completed(futures):
                counter[0] += 1
                checkpoint(counter[0], total)
                r = fut.result()
                fut.release()
                if r[0] == "error":
                    errors.append(r)
                elif place is not None:
                    place(g, index[fut.key], r)
                else:
                    results[index[fut.key]] = r
            if errors:
                raise rebuilt_error(min(errors, key=lambda r: r[1])[2])
            yield results
    except (Exception, Cancelled, GeneratorExit):
        # best effort: a generator dropped late may find its client already closed
        with contextlib.suppress(Exception):
            for futures in groups:
                client.cancel(futures)
        raise


def _region(shape: tuple[int, ...], roi: Sequence[int] | None) -> tuple[int, int, int, int]:
    if roi is None:
        return 0, 0, shape[1], shape[0]
    x, y, w, h = (int(v) for v in roi)
    return x, y, w, h


def iter_group_moments(client: Any, groups: Mapping[Any, Sequence[Any]], *,
                       shape: tuple[int, ...], band_rows: int | None = None,
                       even: bool = False) -> Iterator[tuple[Any, MomentsResult]]:
    """``(key, MomentsResult)`` of each group of frames, in the groups' order.

    Every group's bands are submitted at once; the client then holds one group's maps at a
    time.  ``shape`` is the frames' shape (checked by the caller, from the headers).
    """
    h, w = shape[0], shape[1]
    chans = shape[2] if len(shape) == 3 else 1
    cut = bands(h, w, channels=chans, band_rows=band_rows, even=even)
    keys = list(groups)
    submitted = []
    for key in keys:
        frames = frames_of(groups[key])
        if not frames:
            raise CcdError(str(key), "no frames")
        check_pixels(frames[0].path, shape)
        submitted.append(submit_tasks(client, _moments_task,
                                 [(frames, 0, y0, w, rows) for y0, rows in cut]))
    total = sum(len(f) for f in submitted)
    maps: dict[int, tuple[np.ndarray, np.ndarray, list[int]]] = {}

    def place(g: int, i: int, result: tuple) -> None:
        if g not in maps:
            maps[g] = (np.empty(shape), np.empty(shape), [])
        mean, var, counts = maps[g]
        y0, rows = cut[i]
        mean[y0:y0 + rows] = result[1]
        var[y0:y0 + rows] = result[2]
        counts.append(result[3])

    with contextlib.closing(gather_in_order(client, submitted, [0], total, place)) as done:
        for g, _ in enumerate(done):
            mean, var, counts = maps.pop(g)
            yield keys[g], MomentsResult(mean=mean, var=var, n=int(counts[0]))


def group_moments(client: Any, groups: Mapping[Any, Sequence[Any]], *,
                  shape: tuple[int, ...], band_rows: int | None = None,
                  even: bool = False) -> dict[Any, MomentsResult]:
    """:func:`iter_group_moments` as a dict (every group's maps in memory at once)."""
    return dict(iter_group_moments(client, groups, shape=shape, band_rows=band_rows, even=even))


def band_moments(client: Any, frames: Sequence[Any], *, shape: tuple[int, ...] | None = None,
                 band_rows: int | None = None, even: bool = False) -> MomentsResult:
    """Per-pixel mean and variance of ``frames`` (records or paths) on the cluster,
    bit-identical to :func:`ccdcore.stats.pixel_moments` over the same frames in order.

    ``shape`` defaults to the first frame's header (read here); every frame must have it.
    """
    fr = frames_of(frames)
    if not fr:
        raise CcdError(None, "no frames to average")
    if shape is None:
        from ..io.frames import read_header

        shape = read_header(fr[0].path).shape
    return next(iter_group_moments(client, {"frames": fr}, shape=shape, band_rows=band_rows,
                                   even=even))[1]


def zero_counts(client: Any, frames: Sequence[Any], *, shape: tuple[int, ...], layout: str,
                band_rows: int | None = None) -> dict[str, tuple[int, int]]:
    """Per channel ``(zero pixel values, pixel values)`` over ``frames`` (the flat field's
    zero-dark fraction), counted band by band on the cluster (exact)."""
    from ..channels import is_bayer, split_channels

    fr = frames_of(frames)
    if fr:
        check_pixels(fr[0].path, shape)
    h, w = shape[0], shape[1]
    chans = shape[2] if len(shape) == 3 else 1
    cut = bands(h, w, channels=chans, band_rows=band_rows, even=is_bayer(layout))
    futures = submit_tasks(client, _zeros_task,
                           [(fr, 0, y0, w, rows, layout) for y0, rows in cut])
    with contextlib.closing(gather_in_order(client, [futures], [0], len(futures))) as done:
        results = next(done)
    sizes = {c: v.size for c, v in split_channels(
        np.broadcast_to(np.zeros((), np.uint8), shape), layout).items()}
    out: dict[str, tuple[int, int]] = {}
    for c, size in sizes.items():
        out[c] = (sum(r[1].get(c, 0) for r in results), size * len(fr))
    return out


# --------------------------------------------------------------------------------------------
# photon transfer
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PairSums:
    """One pair's statistics merged over the bands (eqs. 37, 38, 40): μ̂, σ̂²_N, M and the
    clipped pixel values of both frames."""

    mu: float
    var: float
    var_var: float
    m: int
    clipped: int


def _merge_pair(rows: np.ndarray) -> PairSums:
    """Bands' [Σa, Σb, n, Σd, M2, clipped, ...] of one pair -> :class:`PairSums`.

    μ̂ = (Σa + Σb)/(2M) (eq. 37); the sum of squared deviations of d = a − b about its mean is
    merged band by band, M2 = M2_A + M2_B + δ²·n_A·n_B/(n_A + n_B) with δ the difference of the
    bands' means (Chan, Golub & LeVeque 1979), then σ̂²_N = M2/(2(M − 1)) (eq. 38) and
    var[σ̂²_N] = 2(σ̂²_N)²/(M − 1) (eq. 40).
    """
    n_a, mean_a, m2 = 0.0, 0.0, 0.0
    for _, _, n_b, s_b, m2_b, *_ in rows:
        mean_b = s_b / n_b
        n = n_a + n_b
        delta = mean_b - mean_a
        m2 += m2_b + delta * delta * n_a * n_b / n
        mean_a += delta * n_b / n
        n_a = n
    m = int(n_a)
    mu = (float(rows[:, 0].sum()) + float(rows[:, 1].sum())) / (2.0 * m)
    var = float(m2 / (2.0 * (m - 1)))
    return PairSums(mu=float(mu), var=var, var_var=2.0 * var * var / (m - 1), m=m,
                    clipped=int(rows[:, 5].sum()))


def pair_sums(client: Any, levels: Mapping[Any, Sequence[tuple[Any, Any]]], *,
              shapes: Mapping[Any, tuple[int, ...]], roi: Sequence[int] | None,
              full: float | None, band_rows: int | None = None,
              nonfinite: Callable[[str, int], CcdError] | None = None
              ) -> dict[Any, list[PairSums]]:
    """Per level, the :class:`PairSums` of its pairs ``(record1, record2)``, on the cluster.

    ``shapes`` gives each level's frame shape (the band grid covers ``roi`` of it, or all of
    it).  Frames are taken in the streamed order (level by level, pair by pair); the first
    frame that cannot be read, or that holds non-finite values (``nonfinite(name, count)``
    makes that error), raises as in the streamed path.  σ̂²_N agrees with
    :func:`ccdcore.noise.pair_statistics` to a relative :data:`PTC_RTOL`.
    """
    keys = list(levels)
    submitted, pairs_of = [], []
    for key in keys:
        pairs = tuple((frames_of([a])[0], frames_of([b])[0]) for a, b in levels[key])
        pairs_of.append(pairs)
        if pairs:
            check_pixels(pairs[0][0].path, shapes[key])
        x, y, w, h = _region(shapes[key], roi)
        cut = [(y + y0, rows) for y0, rows in bands(h, w, band_rows=band_rows)]
        submitted.append(submit_tasks(client, _pairs_task,
                                 [(pairs, x, y0, w, rows, full) for y0, rows in cut]))
    total = sum(len(f) for f in submitted)
    counter = [0]
    out: dict[Any, list[PairSums]] = {}
    with contextlib.closing(gather_in_order(client, submitted, counter, total)) as gathered:
        for key, pairs, results in zip(keys, pairs_of, gathered):
            stack = np.stack([r[1] for r in results])          # (bands, pairs, 8)
            if nonfinite is not None:
                for i, (f1, f2) in enumerate(pairs):
                    for j, f in enumerate((f1, f2)):
                        bad = int(stack[:, i, 6 + j].sum())
                        if bad:
                            raise nonfinite(f.name, bad)
            out[key] = [_merge_pair(stack[:, i]) for i in range(len(pairs))]
    return out


def frame_sums(client: Any, frames: Sequence[Any], *, shape: tuple[int, ...],
               roi: Sequence[int] | None, band_rows: int | None = None,
               nonfinite: Callable[[str, int], CcdError] | None = None
               ) -> list[tuple[float, int]]:
    """Per frame ``(sum, pixel count)`` over ``roi`` (or the frame), on the cluster (exact for
    integer data; sums over bands otherwise, to float64 rounding)."""
    fr = frames_of(frames)
    if fr:
        check_pixels(fr[0].path, shape)
    x, y, w, h = _region(shape, roi)
    cut = [(y + y0, rows) for y0, rows in bands(h, w, band_rows=band_rows)]
    futures = submit_tasks(client, _sums_task, [(fr, x, y0, w, rows) for y0, rows in cut])
    with contextlib.closing(gather_in_order(client, [futures], [0], len(futures))) as done:
        results = next(done)
    stack = np.stack([r[1] for r in results])              # (bands, frames, 3)
    out = []
    for k, f in enumerate(fr):
        bad = int(stack[:, k, 2].sum())
        if bad and nonfinite is not None:
            raise nonfinite(f.name, bad)
        out.append((float(math.fsum(stack[:, k, 0])), int(stack[:, k, 1].sum())))
    return out
