"""Reductions over frames on a Dask cluster, in horizontal bands of rows (issue #14).

Every reduction over frames runs either streamed in this process (the default, ``client=None``)
or on a Dask cluster (``client=`` a :class:`distributed.Client`).  On the cluster the frame is cut
into horizontal **bands** of rows; one task per (band, group of frames) opens each frame's file
itself by path, through the same reader as the streamed path (:func:`ccdcore.io.read_region`:
strip TIFFs decode only the strips a band covers), and folds the band into the same accumulator
in the same frame order:

* per-pixel moments (:func:`band_moments`, :func:`group_moments`): a task runs
  :class:`ccdcore.stats.PixelMoments` (the same numba kernel, the first frame as shift) over its
  band of each frame in turn.  Every output pixel depends only on that pixel's values, in the
  same order, so each band's mean and variance is **bit-identical** to the streamed result; the
  client writes the bands into the full maps;
* photon-transfer pairs (:func:`pair_sums`): a task gives, per pair of a level, the band's sums
  of D₁ and D₂ (eq. 37), the count, sum and sum of squared deviations of D₁ − D₂ about the band's
  own mean (eq. 38), and the clipped and non-finite counts; the client merges the bands with the
  pairwise update of Chan, Golub & LeVeque (1979).  Sums of integer pixel values are exact in
  float64, so μ̂ is identical; σ̂²_N agrees with the two-pass streamed value to a relative
  :data:`PTC_RTOL` (1e-12);
* dark sums for the black level (:func:`frame_sums`): per frame, the band's sum and count.

Memory per task: the band's accumulators (three float64 band images for moments) plus one band
of one frame; the band height is chosen so the accumulators take about :data:`BAND_BYTES`
(32 MiB) unless ``band_rows`` is given, whatever the number of frames or the session size.

Failures: tasks are submitted with ``retries=`` :data:`RETRIES`, so the tasks of a worker lost
mid-reduction are run again elsewhere by Dask (a task is a pure function of its files).  A file
that cannot be read gives the error the streamed path gives: a band that fails to decode is read
again whole with :func:`ccdcore.io.read_image` (the streamed reader) on the worker, whose
:class:`~ccdcore.errors.ImageReadError` names the file; when several frames fail, the first one
in the streamed order is reported.  Shapes, dtypes and layouts are checked on the client from the
session's cached headers before anything is submitted, with the streamed path's messages.

Imports: the estimators (:mod:`ccdcore.darkframe`, :mod:`ccdcore.noise`,
:mod:`ccdcore.fixedpattern`, :mod:`ccdcore.flatfield`, :mod:`ccdcore.response.hdr`) import this
module, inside the functions that take a ``client``; this module imports none of them, only
modules below them: :mod:`ccdcore.io`, :mod:`ccdcore.errors`, :mod:`ccdcore.progress`,
:mod:`ccdcore.stats`, :mod:`ccdcore.channels`, and the pieces it shares with the streamed paths,
:mod:`ccdcore.kmap_kernels` (K̂'s kernels and :class:`~ccdcore.fixedpattern.FixedPattern`),
:mod:`ccdcore.darkmap` (D̂_D as a map) and :mod:`ccdcore.response.hdr_merge` (the HDR merge).
``tests/test_imports.py`` checks there is no import cycle, imports inside functions included.

Public objects
--------------
Frame
    What a task needs to read one frame: its path and the name messages use.
frames_of(records), headers_of(records, session)
    :class:`Frame` per :class:`~ccdcore.session.FrameRecord` (or path); with its header.
check_averageable(frame, header, first)
    :class:`~ccdcore.stats.PixelMoments`' checks of a frame, from its header.
get_client(scheduler=None, workers=None)
    Context manager: a client on ``scheduler`` (or ``CCDCORE_SCHEDULER``), on a new local
    cluster of ``workers`` processes (on 127.0.0.1, no dashboard unless
    ``CCDCORE_DASK_DASHBOARD`` asks), or ``None`` (streamed); :func:`max_workers` bounds
    ``workers``, :data:`CONNECT_TIMEOUT` the whole connection to a scheduler.
describe(client)
    What a product's provenance records: ``"streamed (this process)"`` or the address and
    number of workers.
bands(height, width, ...)
    The bands ``(y0, rows)`` of a frame.
band_moments(client, frames, ...), group_moments(client, groups, ...), iter_group_moments
    Per-pixel mean and variance (:class:`~ccdcore.stats.MomentsResult`) on the cluster.
zero_counts(client, frames, ...)
    Per channel, the zero pixel values of frames (the flat field's zero-dark check).
pair_sums(client, levels, ...), PairSums
    Per-pair photon-transfer statistics (eqs. 37, 38) merged over bands.
frame_sums(client, frames, ...)
    Per-frame sum and pixel count (the dark mean of the black level).
check_bracket(records, session=None, layout=None), band_merge(client, frames, models, ...)
    The HDR merge of a bracket (:func:`ccdcore.response.hdr.merge`) band by band, each band
    read with a halo of rows covering the blooming disk: bit-identical to the whole-frame merge.
BAND_BYTES, RETRIES, PTC_RTOL, SCHEDULER_ENV, STREAMED
fixed_pattern_bands(client, configs, dark, ...)
    K̂ (eqs. 45–50) band by band on the workers, the streamed :class:`~ccdcore.fixedpattern.FixedPattern`
    to the bit, no process holding the n1 full-frame averages.
"""
from __future__ import annotations

import contextlib
import math
import os
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

import numpy as np

from .errors import CcdError, ImageReadError, require_extra
from .io import read_image, read_region
from .progress import Cancelled, checkpoint
from .reduce import STREAMED as STREAMED_REDUCER
from .reduce import STREAMED_NAME, Check, PairLevel, Reducer, stand_in
from .stats import MomentsResult, PixelMoments

__all__ = ["Frame", "frames_of", "headers_of", "check_averageable", "check_pixels", "get_client", "describe", "bands", "band_moments",
           "group_moments", "iter_group_moments", "zero_counts", "pair_sums", "PairSums",
           "frame_sums", "check_bracket", "band_merge", "merge_halo",
           "BAND_BYTES", "RETRIES", "PTC_RTOL", "SCHEDULER_ENV", "STREAMED", "CONNECT_TIMEOUT",
           "DASHBOARD_ENV", "LOCAL_HOST", "MAX_WORKERS", "max_workers"]

#: environment variable naming the default scheduler address of the CLI
SCHEDULER_ENV = "CCDCORE_SCHEDULER"
#: target size of one band's accumulators (bytes) when ``band_rows`` is not given
BAND_BYTES = 32 * 2 ** 20
#: how many times Dask reruns a task whose worker was lost
RETRIES = 3
#: relative tolerance of σ̂²_N (eq. 38) merged over bands against the streamed two-pass value
PTC_RTOL = 1e-12
#: provenance of a reduction run in this process
STREAMED = STREAMED_NAME
#: seconds to wait for a scheduler before giving up: the whole connection and handshake, not
#: each of Dask's retries (a server that accepts and never answers, or answers something else,
#: fails within this)
CONNECT_TIMEOUT = 10
#: environment variable asking for the local cluster's Dask dashboard: ``host:port`` or
#: ``port`` (bound to 127.0.0.1 when no host is given); unset: no dashboard
DASHBOARD_ENV = "CCDCORE_DASK_DASHBOARD"
#: the interface a local cluster's scheduler and workers listen on (never every interface)
LOCAL_HOST = "127.0.0.1"
#: the most local worker processes ``--workers`` may start, whatever the number of cores
MAX_WORKERS = 256


def max_workers() -> int:
    """The largest ``--workers``: four per core, at most :data:`MAX_WORKERS` (a typo such as
    ``--workers 99999999999999999999`` is refused in one line, not tried)."""
    return max(1, min(MAX_WORKERS, 4 * (os.cpu_count() or 1)))


def _dashboard_address() -> str | None:
    """The dashboard address ``CCDCORE_DASK_DASHBOARD`` asks for (``port`` alone, or an empty
    host, bound to 127.0.0.1), or None (no dashboard: nothing listens that was not asked for)."""
    value = os.environ.get(DASHBOARD_ENV, "").strip()
    if not value:
        return None
    host, sep, port = value.rpartition(":")
    if not sep:
        host, port = "", value
    if not port.isdigit() or int(port) > 65535:
        raise CcdError(DASHBOARD_ENV, f"{value!r} is not host:port or port (e.g. "
                                      f"127.0.0.1:8787)")
    return f"{host or LOCAL_HOST}:{int(port)}"


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
    for its records, else read here (:func:`ccdcore.io.read_header`: the streamed reader's
    error for a file whose header does not read); a frame above the pixel limit is refused
    (:func:`check_pixels`)."""
    from .io import read_header

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
# the client
# --------------------------------------------------------------------------------------------
@contextlib.contextmanager
def get_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """A Dask client for the reductions, closed (with any cluster it started) on exit.

    Parameters
    ----------
    scheduler
        Address of a running scheduler (``tcp://host:8786``); default the environment variable
        ``CCDCORE_SCHEDULER``.
    workers
        Start a local cluster of this many worker processes (one thread each) instead, at most
        :func:`max_workers`. Its scheduler and workers listen on 127.0.0.1 only, and it has no
        dashboard unless ``CCDCORE_DASK_DASHBOARD`` asks for one (``host:port``, or ``port``
        on 127.0.0.1).

    Yields
    ------
    distributed.Client or None
        ``None`` when neither is given: the reductions run streamed in this process.

    Raises
    ------
    CcdError
        Both given, ``workers`` < 1 or above :func:`max_workers`, or the scheduler cannot be
        reached, or does not answer as a Dask scheduler, within :data:`CONNECT_TIMEOUT`
        seconds (one line naming it).
    """
    if scheduler is None and workers is None:
        scheduler = os.environ.get(SCHEDULER_ENV) or None
    if scheduler is not None and workers is not None:
        raise CcdError("scheduler", "give a scheduler address or a number of local workers, "
                                      "not both")
    if scheduler is None and workers is None:
        yield None
        return
    require_extra("distributed", "distributed", "a Dask cluster")
    from distributed import Client, LocalCluster

    if workers is not None:
        n = int(workers)
        if n < 1:
            raise CcdError("workers", f"must be at least 1, got {workers}")
        if n > max_workers():
            raise CcdError("workers", f"{workers} worker processes is more than the limit of "
                                        f"{max_workers()} (4 per core, at most {MAX_WORKERS})")
        # scheduler and workers on the loopback interface only; the dashboard (an HTTP server
        # showing the tasks and the files' paths) only when asked for, by default on loopback.
        # (Dask's scheduler always serves a few HTTP routes (health, metrics): without a
        # dashboard they go to a free port of 127.0.0.1 rather than to 8787.)
        dashboard = _dashboard_address()
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host=LOCAL_HOST,
                          dashboard_address=dashboard, worker_dashboard_address=None,
                          scheduler_kwargs={"dashboard": dashboard is not None,
                                            "dashboard_address": dashboard
                                            or f"{LOCAL_HOST}:0"}) as cluster, \
                Client(cluster) as client:
            yield client
        return
    yield from _connected(scheduler)


def _connected(scheduler: str) -> Iterator[Any]:
    """A client of the scheduler at ``scheduler``, within :data:`CONNECT_TIMEOUT` seconds in
    all: Dask's own ``timeout`` bounds each attempt, and a server that accepts but is not a
    scheduler (silent, or speaking HTTP) can keep it retrying, so the whole connection runs in
    a thread that is given up on (and its client closed when it does end) after the bound."""
    import concurrent.futures
    import threading

    from distributed import Client

    timeout = float(CONNECT_TIMEOUT)
    done: concurrent.futures.Future = concurrent.futures.Future()
    abandoned = threading.Event()

    def connect() -> None:
        try:
            client = Client(scheduler, timeout=timeout)
        except BaseException as exc:          # reported by the caller, whatever it is
            done.set_exception(exc)
            return
        if abandoned.is_set():                # answered after the caller gave up
            with contextlib.suppress(Exception):
                client.close()
            return
        done.set_result(client)

    threading.Thread(target=connect, name="ccdcore-dask-connect", daemon=True).start()
    try:
        client = done.result(timeout=timeout)
    except concurrent.futures.TimeoutError:
        abandoned.set()
        if done.done() and done.exception() is None:     # (a race at the very end)
            client = done.result()
        else:
            raise CcdError(scheduler, f"cannot reach the Dask scheduler (no Dask answer "
                                      f"within {timeout:g} s)") from None
    except Exception as exc:
        text = str(exc).splitlines()[0] if str(exc).strip() else "no answer"
        raise CcdError(scheduler, f"cannot reach the Dask scheduler ({type(exc).__name__}: "
                                  f"{text})") from None
    with client:
        yield client


def describe(client: Any) -> str:
    """``"streamed (this process)"``, or ``"dask <address> (<n> workers)"``."""
    if client is None:
        return STREAMED
    n = len(client.scheduler_info().get("workers", {}))
    return f"dask {client.scheduler.address} ({n} worker{'s' if n != 1 else ''})"


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
    reader (:func:`ccdcore.io.pixel_limit`: width x height x channels pixel values), before
    anything is submitted or decoded.

    A band read (:func:`ccdcore.io.read_region`) only bounds the band, so without this a small
    file declaring 40000 x 40000 pixels would be decoded band after band for minutes, and the
    client would allocate its full-size maps. Raises :class:`ImageReadError` naming ``path``.
    """
    from .io import check_pixel_limit

    h, w = int(shape[0]), int(shape[1])
    c = int(shape[2]) if len(shape) > 2 else 1
    check_pixel_limit(path, w, h, c)


_CHECKED: dict[tuple[str, int, int], tuple[int, ...]] = {}


def _check_file_pixels(path: str) -> None:
    """:func:`check_pixels` of a file from its header, on a worker: each file (by path, size
    and modification time) is read for its header once per process."""
    from .io import read_header

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


def _read_band(frame: Frame, x: int, y: int, w: int, h: int) -> np.ndarray:
    """Rows ``y:y+h``, columns ``x:x+w`` of a frame; a file that does not decode gives the
    streamed reader's own error (it is read whole with :func:`read_image`), one whose header
    declares more pixels than the limit the streamed reader's refusal (nothing decoded)."""
    _check_file_pixels(frame.path)
    try:
        return read_region(frame.path, x, y, w, h)
    except ImageReadError:
        read_image(frame.path)
        raise


def _portable(err: CcdError) -> tuple[type, str | None, str]:
    """A :class:`CcdError` as (class, where, problem): the error classes take two arguments,
    which pickle does not pass back, so the error travels as its parts."""
    return type(err), err.where, err.problem


def _rebuilt(parts: tuple[type, str | None, str]) -> CcdError:
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
            acc.add(_read_band(f, x, y, w, h), name=f.name)
        except CcdError as err:
            return ("error", k, _portable(err))
    res = acc.result(in_place=True)
    return ("ok", res.mean, res.var, res.n)


def _zeros_task(frames: tuple[Frame, ...], x: int, y: int, w: int, h: int,
                layout: str) -> tuple:
    """Per channel, the zero pixel values of one band of ``frames`` (the flat field's
    zero-dark check): ("ok", {channel: zeros}) or ("error", position, CcdError)."""
    from .channels import split_channels

    zeros: dict[str, int] = {}
    for k, f in enumerate(frames):
        try:
            band = _read_band(f, x, y, w, h)
        except CcdError as err:
            return ("error", k, _portable(err))
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
                arrays.append(_read_band(f, x, y, w, h))
            except CcdError as err:
                return ("error", 2 * i + j, _portable(err))
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
            p = _read_band(f, x, y, w, h)
        except CcdError as err:
            return ("error", k, _portable(err))
        bad = int(np.count_nonzero(~np.isfinite(p))) if p.dtype.kind == "f" else 0
        out[k] = (p.sum(dtype=np.float64), p.size, bad)
    return ("ok", out)


# --------------------------------------------------------------------------------------------
# submitting and gathering
# --------------------------------------------------------------------------------------------
def _submit(client: Any, func: Callable, args_list: Sequence[tuple]) -> list:
    return [client.submit(func, *args, retries=RETRIES, pure=False) for args in args_list]


def _gather_in_order(client: Any, groups: list[list], counter: list[int], total: int,
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
                raise _rebuilt(min(errors, key=lambda r: r[1])[2])
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
        submitted.append(_submit(client, _moments_task,
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

    with contextlib.closing(_gather_in_order(client, submitted, [0], total, place)) as done:
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
        from .io import read_header

        shape = read_header(fr[0].path).shape
    return next(iter_group_moments(client, {"frames": fr}, shape=shape, band_rows=band_rows,
                                   even=even))[1]


def zero_counts(client: Any, frames: Sequence[Any], *, shape: tuple[int, ...], layout: str,
                band_rows: int | None = None) -> dict[str, tuple[int, int]]:
    """Per channel ``(zero pixel values, pixel values)`` over ``frames`` (the flat field's
    zero-dark fraction), counted band by band on the cluster (exact)."""
    from .channels import is_bayer, split_channels

    fr = frames_of(frames)
    if fr:
        check_pixels(fr[0].path, shape)
    h, w = shape[0], shape[1]
    chans = shape[2] if len(shape) == 3 else 1
    cut = bands(h, w, channels=chans, band_rows=band_rows, even=is_bayer(layout))
    futures = _submit(client, _zeros_task, [(fr, 0, y0, w, rows, layout) for y0, rows in cut])
    with contextlib.closing(_gather_in_order(client, [futures], [0], len(futures))) as done:
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
        submitted.append(_submit(client, _pairs_task,
                                 [(pairs, x, y0, w, rows, full) for y0, rows in cut]))
    total = sum(len(f) for f in submitted)
    counter = [0]
    out: dict[Any, list[PairSums]] = {}
    with contextlib.closing(_gather_in_order(client, submitted, counter, total)) as gathered:
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
    futures = _submit(client, _sums_task, [(fr, x, y0, w, rows) for y0, rows in cut])
    with contextlib.closing(_gather_in_order(client, [futures], [0], len(futures))) as done:
        results = next(done)
    stack = np.stack([r[1] for r in results])              # (bands, frames, 3)
    out = []
    for k, f in enumerate(fr):
        bad = int(stack[:, k, 2].sum())
        if bad and nonfinite is not None:
            raise nonfinite(f.name, bad)
        out.append((float(math.fsum(stack[:, k, 0])), int(stack[:, k, 1].sum())))
    return out


# --------------------------------------------------------------------------------------------
# HDR merge of a bracket (eqs. 9, 18, 19) with a halo
# --------------------------------------------------------------------------------------------
def merge_halo(layout: str, bloom_radius: int) -> int:
    """Rows of halo a band of a bracket needs above and below (raw frame rows).

    The only non-local rule of :func:`ccdcore.response.hdr.merge` is the blooming mask: a pixel
    within ``bloom_radius`` (a Euclidean disk, in the channel plane's pixels) of a saturated
    pixel of the same plane.  A disk of radius r reaches r plane rows, which are r frame rows
    for mono and RGB data and 2r for a Bayer mosaic (a CFA plane takes every second row); the
    halo is even then, so the band read still starts on the CFA's first row.  Every other step
    (g, σ, the weights, the fallbacks and their bounds) is per pixel.
    """
    from .channels import is_bayer

    r = max(0, int(bloom_radius))
    return 2 * r if is_bayer(layout) else r


def check_bracket(records: Sequence[Any], session: Any = None, layout: str | None = None
                  ) -> tuple[tuple[int, ...], str]:
    """The checks :func:`ccdcore.response.hdr.merge` makes of its frames, from the headers and
    with the same messages (every frame of the first one's shape, integer codes, a shape that
    fits ``layout``); returns the frames' shape and the layout."""
    from .channels import check_layout

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
    from .response.hdr_merge import merge

    y, h = y0 - top, top + rows + bottom
    arrays = []
    for k, f in enumerate(frames):
        try:
            arrays.append(_read_band(f, 0, y, width, h))
        except CcdError as err:
            return ("error", k, _portable(err))
    try:
        res = merge(arrays, models, layout=layout, bloom_radius=bloom_radius)
    except CcdError as err:
        return ("error", len(frames), _portable(err))
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
    the band height in frame rows (default: about :data:`BAND_BYTES` of the merge's
    float64 temporaries, which hold every frame of the band).  A frame that cannot be read
    gives the streamed reader's error (the first in the bracket's order); an error of the merge
    itself (codes outside the response, a model per channel missing) its own message.
    """
    from .channels import check_layout, is_bayer
    from .response.hdr_merge import HdrResult, ResponseModel

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
    cut = bands(h, w, channels=max(1, 2 * chans * len(fr)), band_rows=band_rows, even=bayer)
    args = [(fr, y0, rows, min(halo, y0), min(halo, h - y0 - rows), w, portable, lay,
             int(bloom_radius), step) for y0, rows in cut]
    futures = _submit(client, _merge_task, args)
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

    with contextlib.closing(_gather_in_order(client, [futures], [0], len(futures),
                                             place)) as done:
        next(done)
    radiance, sigma, flags, used = maps
    return HdrResult(radiance, sigma, flags, used, names[0], lay)


# --- fixed pattern per band ---
# K̂ (eqs. 45–50, :func:`ccdcore.fixedpattern.fixed_pattern_map`) band by band of rows, so that
# no process holds the n1 full-frame configuration averages.
__all__ += ["fixed_pattern_bands"]


def _kmap_pick(result: dict, *keys: str) -> tuple:
    """("ok", the ``keys`` of a task's result): the small part the client or the next task
    needs, fetched without the band maps."""
    return ("ok",) + tuple(result[k] for k in keys)


def _kmap_average_task(configs: tuple[tuple[Frame, ...], ...], dark: np.ndarray, y0: int,
                       rows: int, top: int, bottom: int, width: int, height: int) -> dict:
    """Pass 1 of :func:`fixed_pattern_bands` for rows ``y0 - top .. y0 + rows + bottom``: per
    configuration, :class:`~ccdcore.stats.PixelMoments` of its frames in order (eq. 45) minus
    the dark band, e_i (eq. 46), kept here as ``"e"`` (n1, rows + top + bottom, width); per
    configuration ``(n2, pieces of Σ e_i, pieces of Σ var)`` over the band's own rows
    (:func:`ccdcore.kmap_kernels.pw_pieces`, numpy's pairwise sum of the whole frame cut at
    the band); a read error stops the task: ``"error"`` = (configuration, position, error)."""
    from .kmap_kernels import pw_pieces

    y, hh = y0 - top, top + rows + bottom
    e = np.empty((len(configs), hh, width))
    parts: list = []
    lo, n = y0 * width, height * width
    inner = slice(top, top + rows)
    for i, frames in enumerate(configs):
        acc = PixelMoments()
        for k, f in enumerate(frames):
            try:
                acc.add(_read_band(f, 0, y, width, hh), name=f.name)
            except CcdError as err:
                return {"e": None, "parts": parts, "error": (i, k, _portable(err))}
        res = acc.result(in_place=True)
        np.subtract(res.mean, dark, out=e[i])                  # eq. 46
        parts.append((res.n, pw_pieces(e[i, inner].ravel(), lo, n),
                      pw_pieces(np.ascontiguousarray(res.var[inner]).ravel(), lo, n)))
    return {"e": e, "parts": parts, "error": None}


def _kmap_slopes_task(p1: dict, tmp: tuple | None, y0: int, rows: int, top: int,
                      height: int, window: int, single: bool) -> dict:
    """The slopes of one band (eqs. 47, 48), after the band above (``tmp``: the column running
    sums of ē_i after row ``y0 − 1``, per configuration): ē_i by the whole frame's running sums
    (:func:`ccdcore.kmap_kernels.box_mean_band`, or ``local_mean`` for a single band),
    m_i = e_i/ē_i (float32), m̄ and the per-pixel sample std; keeps the slopes and m̄, gives
    ``"tmp"`` for the band below and ``"summary"`` = (pieces of Σ sd with NaN as 0, the
    non-NaN count, any finite sd) for σ̂.  After a failed band: empty."""
    from .kmap_kernels import (box_mean_band, local_mean, pw_pieces, slope_moments,
                               slopes_into)

    e = p1["e"]
    tmp = None if tmp is None else tmp[1]          # ("ok", sums) from the band above
    if e is None or (y0 > 0 and not single and tmp is None):
        return {"slopes": None, "m_bar": None, "tmp": None, "summary": None}
    n1, _, width = e.shape
    tmp = np.zeros((n1, width)) if tmp is None else tmp.copy()
    slopes = np.empty((n1, rows, width), dtype=np.float32)
    e_bar = np.empty((rows, width))
    for i in range(n1):
        if single:
            local_mean(e[i], window, e_bar)
        else:
            box_mean_band(e[i], window, height, y0 - top, y0, tmp[i], e_bar)
        slopes_into(e[i, top:top + rows].copy(), e_bar, slopes[i])       # eq. 47
    m_bar = np.empty((rows, width))
    sd = np.empty((rows, width))
    slope_moments(slopes.reshape(n1, -1), m_bar.reshape(-1), sd.reshape(-1))   # eq. 48
    nan = np.isnan(sd)
    summary = (pw_pieces(np.where(nan, 0.0, sd).ravel(), y0 * width, height * width),
               int(np.count_nonzero(~nan)), bool(np.isfinite(sd).any()))
    return {"slopes": slopes, "m_bar": m_bar, "tmp": tmp, "summary": summary}


def _kmap_reject_task(s: dict, half: float, center: str) -> tuple:
    """Pass 2 of :func:`fixed_pattern_bands`: eq. 49 over one band's slopes
    (:func:`ccdcore.kmap_kernels.eq49_reject`): ("ok", K̂, n'_1, rejected, K_var, m̄, pixels that kept
    no slope)."""
    from .kmap_kernels import eq49_reject

    K, rejected, used, K_var, none = eq49_reject(s["slopes"], s["m_bar"], half, center)
    return ("ok", K, used, rejected, K_var, s["m_bar"], none)


def fixed_pattern_bands(client: Any, configs: Any, dark: Any, *, window: int = 9,
                        p: float = 1.5, center: str = "median", band_rows: int | None = None,
                        notes: list[str] | None = None, where: str = "fixed_pattern") -> Any:
    """The fixed-pattern map K̂ (eqs. 45–50) on the cluster, band by band of rows.

    ``configs``: ``[(config id, records or paths)]`` or a mapping (checked by the caller, see
    :func:`ccdcore.fixedpattern.fixed_pattern_map`, which calls this with a client); ``dark``
    the dark map D̂_D; ``window``, ``p``, ``center`` as there; ``notes`` the caller's notes so
    far; ``band_rows`` the band height (default: the n1 band averages and slopes take about
    :data:`BAND_BYTES`).

    1. One task per band reads its rows of every frame plus a halo (m//2 + 1 rows above, m//2
       below, none beyond the frame's own edges) and keeps e_i = average − D̂_D (eqs. 45, 46)
       of every configuration on its worker; the client gets per configuration the band's
       share of numpy's pairwise sums of e_i and of the variance map, and combines them into
       the streamed ``e_i.mean()`` and ``mean(var)`` (the same blocks and additions: the same
       bits); then, in configuration order, the streamed read error or unlit-card error.
    2. ē_i: scipy's column pass is a running sum down each column, whose rounding at a row
       depends on every row above; so the bands' slope tasks run in a chain, each handing the
       column sums after its last row to the next (a row of floats per configuration) while
       the reading of the other bands proceeds.  Each computes m_i (eq. 47), m̄ and the
       per-pixel std (eq. 48) and keeps its slopes; σ̂ is the nanmean of the std over the whole
       frame, again from the bands' pairwise-sum pieces (the same bits).
    3. One task per band rejects and re-averages (eq. 49); the client assembles K̂, n'_1, the
       rejections, K_var and m̄ and the summary statistics (eq. 50) as the streamed code does.

    The result equals the streamed :class:`~ccdcore.fixedpattern.FixedPattern` exactly (every
    map ``np.array_equal``, every summary value ``==``).  Memory: a task holds one band's n1
    float64 averages (band and halo) or its n1 float32 slopes and rejections; the averages wait
    on their worker until the band's slope task (released then), the slopes until σ̂, which
    needs every band, is known, so a worker holds its share of the n1 slope maps in between.
    """
    from .darkmap import as_dark_map
    from .kmap_kernels import NO_SIGMA, NOT_LIT, fixed_pattern_of, pw_total

    configs = list(configs.items()) if isinstance(configs, Mapping) else list(configs)
    notes = [] if notes is None else notes
    dmap = np.asarray(as_dark_map(dark), dtype=np.float64)
    h, w = dmap.shape
    n, n1, s1 = h * w, len(configs), int(window) // 2
    groups = tuple(frames_of(recs) for _, recs in configs)
    if h < window or w < window:      # the mirrored border folds more than once: scipy, whole
        cut = [(0, h)]
    else:
        cut = bands(h, w, channels=n1 // 2 + 1, band_rows=band_rows)
    single = len(cut) == 1
    halos = [(0, 0) if single else (min(s1 + 1, y0), min(s1, h - y0 - rows))
             for y0, rows in cut]
    total, counter = 3 * len(cut), [0]
    p1: list = []
    chain: list = []
    links: list = []
    try:
        p1 = _submit(client, _kmap_average_task,
                     [(groups, dmap[y0 - top:y0 + rows + bottom], y0, rows, top, bottom, w, h)
                      for (y0, rows), (top, bottom) in zip(cut, halos)])
        tmp = None
        for fut, (y0, rows), (top, _) in zip(p1, cut, halos):
            chain.append(client.submit(_kmap_slopes_task, fut, tmp, y0, rows, top, h,
                                       int(window), single, retries=RETRIES, pure=False))
            tmp = client.submit(_kmap_pick, chain[-1], "tmp", retries=RETRIES, pure=False)
            links.append(tmp)
        picks = [client.submit(_kmap_pick, f, "parts", "error", retries=RETRIES, pure=False)
                 for f in p1]
        with contextlib.closing(_gather_in_order(client, [picks], counter, total)) as done:
            firsts = next(done)
        ids, levels, noises, n2s = [], [], [], []
        for i, (cid, _) in enumerate(configs):
            errors = [r[2] for r in firsts if r[2] is not None and r[2][0] == i]
            if errors:
                raise _rebuilt(min(errors, key=lambda r: r[1])[2])
            n2 = int(firsts[0][1][i][0])
            level = pw_total(n, (r[1][i][1] for r in firsts)) / n
            if level <= 0:
                raise CcdError(groups[i][0].name, NOT_LIT.format(cid=cid, level=level))
            var_mean = pw_total(n, (r[1][i][2] for r in firsts)) / n
            ids.append(cid)
            levels.append(level)
            noises.append(var_mean / n2 if n2 > 1 else float("nan"))
            n2s.append(n2)
        del firsts

        def release(futures: list, i: int) -> None:
            with contextlib.suppress(Exception):
                futures[i].release()

        summaries: list = [None] * len(cut)

        def keep(g: int, i: int, r: tuple) -> None:
            release(p1, i)                  # band i's averages are no longer needed
            summaries[i] = r[1]

        picks = [client.submit(_kmap_pick, f, "summary", retries=RETRIES, pure=False)
                 for f in chain]
        with contextlib.closing(_gather_in_order(client, [picks], counter, total,
                                                 keep)) as done:
            next(done)
        if any(s[2] for s in summaries):
            tot = pw_total(n, (s[0] for s in summaries))
            sigma_hat = float(tot / sum(s[1] for s in summaries))
        else:
            sigma_hat = float("nan")
        if not math.isfinite(sigma_hat):
            raise CcdError(where, NO_SIGMA)

        half = p * sigma_hat
        K, K_var, m_bar = np.empty((h, w)), np.empty((h, w)), np.empty((h, w))
        used = np.empty((h, w), np.int16)
        rejected = np.empty((n1, h, w), dtype=bool)
        none = [0]

        def place(g: int, i: int, r: tuple) -> None:
            y0, rows = cut[i]
            release(chain, i)
            K[y0:y0 + rows], used[y0:y0 + rows] = r[1], r[2]
            rejected[:, y0:y0 + rows], K_var[y0:y0 + rows] = r[3], r[4]
            m_bar[y0:y0 + rows] = r[5]
            none[0] += r[6]

        finals = _submit(client, _kmap_reject_task, [(c, half, center) for c in chain])
        with contextlib.closing(_gather_in_order(client, [finals], counter, total,
                                                 place)) as done:
            next(done)
    except BaseException:
        with contextlib.suppress(Exception):
            client.cancel([f for f in p1 + chain + links if f.status != "released"])
        raise
    return fixed_pattern_of(K, used, rejected, m_bar, K_var, sigma_hat=sigma_hat, p=p,
                            window=window, center=center, none=none[0], ids=ids,
                            levels=levels, noises=noises, n2s=n2s, notes=notes)


# --------------------------------------------------------------------------------------------
# the reducer
# --------------------------------------------------------------------------------------------
__all__ += ["DaskReducer", "open_reducer"]


class DaskReducer(Reducer):
    """The reductions of :class:`ccdcore.reduce.Reducer` on the Dask cluster of ``client``,
    band by band of rows, each worker reading its band of every frame: the same results
    (photon-transfer variances to :data:`PTC_RTOL`). Every frame is checked first from its
    header, with the messages the streamed reductions give, before anything is submitted;
    frames are given as session records or file paths (the workers read them)."""

    def __init__(self, client: Any):
        self.client = client

    @property
    def description(self) -> str:                      # type: ignore[override]
        return describe(self.client)

    def moments(self, frames: Any, *, what: str, session: Any = None,
                check: Check | None = None, zeros: dict | None = None,
                layout: str | None = None, even: bool = False,
                name: Callable[[int], str] | None = None, empty: str | None = None
                ) -> tuple[MomentsResult, str]:
        from .channels import check_layout, is_bayer

        if isinstance(frames, np.ndarray):
            raise CcdError("frames", f"on a cluster, give the {what} frames as session records "
                                     "or file paths (the workers read them), not arrays")
        recs = list(frames)
        if not recs:
            raise CcdError(what, empty or f"no {what} frames")
        first = None
        lay = layout
        named = []
        for frame, hdr in headers_of(recs, session):
            named.append(frame)
            if check is not None:
                check(frame.name, stand_in(hdr))
            first = check_averageable(frame, hdr, first)
            if zeros is not None:
                lay = check_layout(hdr.shape, lay, frame.name)
        try:
            even = even or is_bayer(check_layout(first, lay, named[0].name))
        except CcdError:  # reported by the estimator's own check, after the averages
            pass
        res = band_moments(self.client, recs, shape=first, even=even)
        if zeros is not None:
            zeros.update(zero_counts(self.client, recs, shape=first, layout=lay))
        return res, named[0].name

    def frame_sums(self, session: Any, records: Sequence[Any], *,
                   pixels: Callable[[Any, np.ndarray], np.ndarray],
                   header_pixels: Callable[[Any], np.ndarray],
                   roi: tuple[int, int, int, int] | None,
                   nonfinite: Callable[[str, int], CcdError]
                   ) -> Iterator[tuple[Any, tuple[float, int]]]:
        for rec in records:
            header_pixels(rec)
        shape = session.header(records[0]).shape
        yield from zip(records, frame_sums(self.client, records, shape=shape, roi=roi,
                                           nonfinite=nonfinite))

    def pair_stats(self, session: Any, paired: Mapping[int, Sequence[Any]], *,
                   pixels: Callable[[Any, np.ndarray], np.ndarray],
                   header_pixels: Callable[[Any], np.ndarray],
                   roi: tuple[int, int, int, int] | None, full: float | None,
                   nonfinite: Callable[[str, int], CcdError]) -> Iterator[PairLevel]:
        pairs, shapes = {}, {}
        for level, recs in paired.items():
            pairs[level] = list(zip(recs[0::2], recs[1::2]))
            for r1, r2 in pairs[level]:
                p1, p2 = header_pixels(r1), header_pixels(r2)
                if p1.shape != p2.shape:
                    raise CcdError(r2.relpath, f"shape {p2.shape} differs from {r1.relpath} "
                                               f"{p1.shape}")
            if recs:
                shapes[level] = session.header(recs[0]).shape
        sums = pair_sums(self.client, {lv: p for lv, p in pairs.items() if p}, shapes=shapes,
                         roi=roi, full=full, nonfinite=nonfinite)
        for level in paired:
            got = sums.get(level, [])
            yield ([p.mu for p in got], [p.var for p in got], sum(p.clipped for p in got),
                   sum(2 * p.m for p in got), got[-1].m if got else 0)

    def preload(self, session: Any, records: Sequence[Any]) -> list[np.ndarray] | None:
        return None

    def merge(self, records: Sequence[Any], models: Any, *, layout: str | None,
              bloom_radius: int, frames: Sequence[Any] | None = None, session: Any = None,
              band_rows: int | None = None) -> Any:
        shape, lay = check_bracket(records, session, layout)
        return band_merge(self.client, records, models, layout=lay, bloom_radius=bloom_radius,
                          shape=shape, band_rows=band_rows)

    def configurations(self, source: Any) -> tuple[list[tuple[Any, Any]], Any]:
        if hasattr(source, "fixed_pattern_configs") and hasattr(source, "iter_frames"):
            return list(source.fixed_pattern_configs().items()), source
        if isinstance(source, Mapping):
            return [(cid, tuple(recs)) for cid, recs in source.items()], None
        raise CcdError("configs", "on a cluster, give a session or a mapping config id -> "
                                  "records or file paths (the workers read the frames), not "
                                  "arrays")

    def fixed_pattern(self, source: Any, *, dark_of: Callable[[Any], np.ndarray], window: int,
                      p: float, center: str) -> Any:
        configs, session = self.configurations(source)
        where = str(getattr(session, "root", "fixed_pattern"))
        notes: list[str] = []
        dmap = self._dark_map(session, dark_of, configs, where, notes)
        _check_configurations(configs, session, dmap.shape)
        return fixed_pattern_bands(self.client, configs, dmap, window=window, p=p,
                                   center=center, notes=notes, where=where)


def _check_configurations(configs: list[tuple[Any, tuple]], session: Any,
                          ref_shape: tuple) -> None:
    """The streamed K̂'s checks of every configuration's frames, from their headers (same
    messages), before anything is submitted."""
    for cid, recs in configs:
        if not recs:
            raise CcdError(f"configuration {cid}", "has no frames")
        first = None
        for frame, hdr in headers_of(recs, session):
            if len(hdr.shape) == 3:
                raise CcdError(frame.name, f"colour frames {hdr.shape}: the fixed-pattern map is "
                                           "mono only for now; per channel support comes with "
                                           "the flat-field work")
            if first is None and hdr.shape != ref_shape:
                raise CcdError(frame.name, f"frame shape {hdr.shape} differs from the dark "
                                           f"reference's {ref_shape}")
            first = check_averageable(frame, hdr, first)


@contextlib.contextmanager
def open_reducer(scheduler: str | None = None, workers: int | None = None
                 ) -> Iterator[Reducer]:
    """The reducer a command asks for, chosen once: :data:`ccdcore.reduce.STREAMED`, or a
    :class:`DaskReducer` on the client of :func:`get_client` (closed, with any cluster it
    started, on exit). Raises as :func:`get_client`."""
    with get_client(scheduler, workers) as client:
        yield STREAMED_REDUCER if client is None else DaskReducer(client)
