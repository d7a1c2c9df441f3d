"""Reductions over frames on a Dask cluster, in horizontal bands of rows (issue #14).

Every reduction over frames runs either streamed in this process (the default, ``client=None``)
or on a Dask cluster (``client=`` a :class:`distributed.Client`).  On the cluster the frame is cut
into horizontal **bands** of rows; one task per (band, group of frames) opens each frame's file
itself by path, through the same reader as the streamed path (:func:`ccdcore.io.frames.read_region`:
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
again whole with :func:`ccdcore.io.frames.read_image` (the streamed reader) on the worker, whose
:class:`~ccdcore.errors.ImageReadError` names the file; when several frames fail, the first one
in the streamed order is reported.  Shapes, dtypes and layouts are checked on the client from the
session's cached headers before anything is submitted, with the streamed path's messages.

Modules: this module holds the client (:func:`get_client`, :func:`describe`), the reducer
(:class:`DaskReducer`, :func:`open_reducer`) and re-exports the rest, which lives below it:
:mod:`ccdcore.distributed.band_tasks` (frames, bands, tasks, submitting and gathering; the moments,
zero counts, pair sums and frame sums), :mod:`ccdcore.distributed.hdr` (the HDR merge of a bracket)
and
:mod:`ccdcore.distributed.kmap` (K̂ by bands).  :data:`BAND_BYTES` and :func:`bands` are looked up
in
:mod:`ccdcore.distributed.band_tasks` when a reduction runs: patch them there (the names here are
the same objects, for reading); :data:`CONNECT_TIMEOUT` is read here.

Imports: the estimators (:mod:`ccdcore.dark.frame`, :mod:`ccdcore.noise`,
:mod:`ccdcore.fixedpattern`, :mod:`ccdcore.flatfield.fit`, :mod:`ccdcore.response.hdr`) reach
these modules through :class:`ccdcore.reduce.Reducer` (the CLI through :func:`open_reducer`);
they import none of them, only modules below them: :mod:`ccdcore.reduce`, :mod:`ccdcore.io.frames`,
:mod:`ccdcore.errors`, :mod:`ccdcore.progress`, :mod:`ccdcore.stats`, :mod:`ccdcore.channels`,
and the pieces they share with the streamed paths, :mod:`ccdcore.kmap_kernels` (K̂'s kernels
and :class:`~ccdcore.fixedpattern.FixedPattern`), :mod:`ccdcore.dark.map` (D̂_D as a map) and
:mod:`ccdcore.response.hdr_merge` (the HDR merge); :mod:`ccdcore.reduce` imports none of them.
``tests/test_imports.py`` checks there is no import cycle, imports inside functions included.

Public objects
--------------
Frame
    What a task needs to read one frame: its path and the name messages use.
frames_of(records), headers_of(records, session)
    :class:`Frame` per :class:`~ccdcore.session.FrameRecord` (or path); with its header.
check_averageable(frame, header, first)
    :class:`~ccdcore.stats.PixelMoments`' checks of a frame, from its header.
check_pixels(path, shape)
    The streamed reader's pixel limit (:func:`ccdcore.io.frames.pixel_limit`) of a frame, from its
    header, before anything is submitted.
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
merge_halo(layout, bloom_radius)
    The rows of halo a band of a bracket needs above and below.
fixed_pattern_bands(client, configs, dark, ...)
    K̂ (eqs. 45–50) band by band on the workers, the streamed
    :class:`~ccdcore.fixedpattern.FixedPattern` to the bit, no process holding the n1
    full-frame averages.
DaskReducer(client), open_reducer(scheduler=None, workers=None)
    The :class:`ccdcore.reduce.Reducer` on a cluster; the reducer a command asks for
    (:data:`ccdcore.reduce.STREAMED` or a :class:`DaskReducer`), closed on exit.
BAND_BYTES, RETRIES, PTC_RTOL, SCHEDULER_ENV, STREAMED, CONNECT_TIMEOUT, DASHBOARD_ENV,
LOCAL_HOST, MAX_WORKERS
    The constants (see each); :func:`max_workers` the largest ``--workers``.
"""
from __future__ import annotations

import contextlib
import os
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np

from .band_tasks import (BAND_BYTES, PTC_RTOL, RETRIES, Frame, PairSums, band_moments, bands,
                         check_averageable, check_pixels, frame_sums, frames_of,
                         group_moments, headers_of, iter_group_moments, pair_sums,
                         zero_counts)
from .hdr import band_merge, check_bracket, merge_halo
from .kmap import fixed_pattern_bands
from ..errors import CcdError, require_extra
from ..reduce import STREAMED as STREAMED_REDUCER
from ..reduce import STREAMED_NAME, Check, PairLevel, Reducer, stand_in
from ..stats import MomentsResult

__all__ = ["Frame", "frames_of", "headers_of", "check_averageable", "check_pixels",
           "get_client", "describe", "bands", "band_moments",
           "group_moments", "iter_group_moments", "zero_counts", "pair_sums", "PairSums",
           "frame_sums", "check_bracket", "band_merge", "merge_halo",
           "BAND_BYTES", "RETRIES", "PTC_RTOL", "SCHEDULER_ENV", "STREAMED", "CONNECT_TIMEOUT",
           "DASHBOARD_ENV", "LOCAL_HOST", "MAX_WORKERS", "max_workers",
           "fixed_pattern_bands", "DaskReducer", "open_reducer"]

#: environment variable naming the default scheduler address of the CLI
SCHEDULER_ENV = "CCDCORE_SCHEDULER"
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
        interrupted = False
        try:
            with LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                              host=LOCAL_HOST, dashboard_address=dashboard,
                              worker_dashboard_address=None,
                              scheduler_kwargs={"dashboard": dashboard is not None,
                                                "dashboard_address": dashboard
                                                or f"{LOCAL_HOST}:0"}) as cluster, \
                    Client(cluster) as client:
                try:
                    yield client
                except KeyboardInterrupt:
                    interrupted = True
                    raise
        except Exception:
            # Ctrl+C reaches the worker processes too (one process group): closing a cluster
            # whose workers are already gone can fail (an AssertionError in Dask's close),
            # and that error would replace the interrupt the user asked for
            if interrupted:
                raise KeyboardInterrupt from None
            raise
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
# the reducer
# --------------------------------------------------------------------------------------------


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
        from ..channels import check_layout, is_bayer

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
