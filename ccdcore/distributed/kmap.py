"""The fixed-pattern map K̂ (eqs. 45–50, :func:`ccdcore.fixedpattern.fixed_pattern_map`) on a
Dask cluster, band by band of rows, so that no process holds the n1 full-frame configuration
averages (issue #14; re-exported by :mod:`ccdcore.distributed.client`).

:func:`fixed_pattern_bands` runs the three steps of its docstring, one function each
(1. :func:`_submit_averages`, :func:`_read_levels`; 2. :func:`_submit_slopes`,
:func:`_sigma_hat`; 3. :func:`_reject`; the slope chain is submitted before step 1 is
gathered, so it runs behind the reading), on the module-level tasks ``_kmap_average_task``,
``_kmap_slopes_task``, ``_kmap_reject_task`` and ``_kmap_pick`` (Dask pickles them by
reference).

Imports: :mod:`ccdcore.distributed.band_tasks` (whose :func:`~ccdcore.distributed.band_tasks.bands`
and
:data:`~ccdcore.distributed.band_tasks.BAND_BYTES` are looked up there when K̂ runs, so a patch of
them takes effect), :mod:`ccdcore.errors`, :mod:`ccdcore.stats`, :mod:`ccdcore.dark.map` and
:mod:`ccdcore.kmap_kernels`.

Public objects
--------------
fixed_pattern_bands(client, configs, dark, ...)
    K̂ band by band on the workers, the streamed :class:`~ccdcore.fixedpattern.FixedPattern`
    to the bit.
"""
from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from . import band_tasks as dask_bands
from .band_tasks import (RETRIES, Frame, frames_of, gather_in_order, portable_error,
                         read_band, rebuilt_error, submit_tasks)
from ..errors import CcdError
from ..stats import PixelMoments

__all__ = ["fixed_pattern_bands"]


# --------------------------------------------------------------------------------------------
# tasks (run on the workers)
# --------------------------------------------------------------------------------------------
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
    from ..kmap_kernels import pw_pieces

    y, hh = y0 - top, top + rows + bottom
    e = np.empty((len(configs), hh, width))
    parts: list = []
    lo, n = y0 * width, height * width
    inner = slice(top, top + rows)
    for i, frames in enumerate(configs):
        acc = PixelMoments()
        for k, f in enumerate(frames):
            try:
                acc.add(read_band(f, 0, y, width, hh), name=f.name)
            except CcdError as err:
                return {"e": None, "parts": parts, "error": (i, k, portable_error(err))}
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
    from ..kmap_kernels import (box_mean_band, local_mean, pw_pieces, slope_moments,
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
    (:func:`ccdcore.kmap_kernels.eq49_reject`): ("ok", K̂, n'_1, rejected, K_var, m̄, pixels that
    kept
    no slope)."""
    from ..kmap_kernels import eq49_reject

    K, rejected, used, K_var, none = eq49_reject(s["slopes"], s["m_bar"], half, center)
    return ("ok", K, used, rejected, K_var, s["m_bar"], none)



# --------------------------------------------------------------------------------------------
# K̂ by bands, on the client
# --------------------------------------------------------------------------------------------
@dataclass
class _Run:
    """One run of :func:`fixed_pattern_bands` on the client: the bands ``cut`` (``(y0, rows)``)
    of a ``height`` × ``width`` frame, their halos (``(top, bottom)``), whether there is a
    ``single`` band, the progress ``counter`` over ``total`` steps, and the futures submitted
    so far (the band averages ``p1``, the slope ``chain`` and its ``links``: cancelled on
    failure)."""

    client: Any
    height: int
    width: int
    cut: list
    halos: list
    single: bool
    total: int
    counter: list = field(default_factory=lambda: [0])
    p1: list = field(default_factory=list)
    chain: list = field(default_factory=list)
    links: list = field(default_factory=list)

    def cancel(self) -> None:
        """Cancel the futures not yet released (best effort)."""
        with contextlib.suppress(Exception):
            self.client.cancel([f for f in self.p1 + self.chain + self.links
                                if f.status != "released"])


def _plan(client: Any, h: int, w: int, n1: int, window: int, band_rows: int | None) -> _Run:
    """The bands of K̂ and their halos: m//2 + 1 rows above, m//2 below, none beyond the
    frame's edges, none for a single band (one band when the window exceeds the frame)."""
    s1 = int(window) // 2
    if h < window or w < window:      # the mirrored border folds more than once: scipy, whole
        cut = [(0, h)]
    else:
        cut = dask_bands.bands(h, w, channels=n1 // 2 + 1, band_rows=band_rows)
    single = len(cut) == 1
    halos = [(0, 0) if single else (min(s1 + 1, y0), min(s1, h - y0 - rows))
             for y0, rows in cut]
    return _Run(client, h, w, cut, halos, single, 3 * len(cut))


def _release(futures: list, i: int) -> None:
    with contextlib.suppress(Exception):
        futures[i].release()


def _submit_averages(run: _Run, groups: tuple, dmap: np.ndarray) -> None:
    """Step 1, submitted: one average task per band (band and halo of every frame)."""
    h, w = run.height, run.width
    run.p1 = submit_tasks(run.client, _kmap_average_task,
                          [(groups, dmap[y0 - top:y0 + rows + bottom], y0, rows, top, bottom,
                            w, h) for (y0, rows), (top, bottom) in zip(run.cut, run.halos)])


def _read_levels(run: _Run, configs: list, groups: tuple) -> tuple[list, list, list, list]:
    """Step 1, gathered: per configuration in order, the streamed read error or unlit-card
    error, else its id, level ``e_i.mean()``, noise ``mean(var)/n2`` and n2."""
    from ..kmap_kernels import NOT_LIT, pw_total

    client, n = run.client, run.height * run.width
    picks = [client.submit(_kmap_pick, f, "parts", "error", retries=RETRIES, pure=False)
             for f in run.p1]
    with contextlib.closing(gather_in_order(client, [picks], run.counter, run.total)) as done:
        firsts = next(done)
    ids, levels, noises, n2s = [], [], [], []
    for i, (cid, _) in enumerate(configs):
        errors = [r[2] for r in firsts if r[2] is not None and r[2][0] == i]
        if errors:
            raise rebuilt_error(min(errors, key=lambda r: r[1])[2])
        n2 = int(firsts[0][1][i][0])
        level = pw_total(n, (r[1][i][1] for r in firsts)) / n
        if level <= 0:
            raise CcdError(groups[i][0].name, NOT_LIT.format(cid=cid, level=level))
        var_mean = pw_total(n, (r[1][i][2] for r in firsts)) / n
        ids.append(cid)
        levels.append(level)
        noises.append(var_mean / n2 if n2 > 1 else float("nan"))
        n2s.append(n2)
    return ids, levels, noises, n2s


def _submit_slopes(run: _Run, window: int) -> None:
    """Step 2, submitted: the chain of slope tasks, each after its band's averages and the
    column sums (``_kmap_pick`` of ``"tmp"``) of the band above."""
    client, tmp = run.client, None
    for fut, (y0, rows), (top, _) in zip(run.p1, run.cut, run.halos):
        run.chain.append(client.submit(_kmap_slopes_task, fut, tmp, y0, rows, top, run.height,
                                       int(window), run.single, retries=RETRIES, pure=False))
        tmp = client.submit(_kmap_pick, run.chain[-1], "tmp", retries=RETRIES, pure=False)
        run.links.append(tmp)


def _sigma_hat(run: _Run, where: str) -> float:
    """Step 2, gathered: σ̂, the nanmean of the per-pixel std over the whole frame from the
    bands' pairwise-sum pieces (each band's averages released as its summary arrives)."""
    from ..kmap_kernels import NO_SIGMA, pw_total

    summaries: list = [None] * len(run.cut)

    def keep(g: int, i: int, r: tuple) -> None:
        _release(run.p1, i)                 # band i's averages are no longer needed
        summaries[i] = r[1]

    picks = [run.client.submit(_kmap_pick, f, "summary", retries=RETRIES, pure=False)
             for f in run.chain]
    with contextlib.closing(gather_in_order(run.client, [picks], run.counter, run.total,
                                            keep)) as done:
        next(done)
    if any(s[2] for s in summaries):
        tot = pw_total(run.height * run.width, (s[0] for s in summaries))
        sigma_hat = float(tot / sum(s[1] for s in summaries))
    else:
        sigma_hat = float("nan")
    if not math.isfinite(sigma_hat):
        raise CcdError(where, NO_SIGMA)
    return sigma_hat


def _reject(run: _Run, n1: int, half: float, center: str) -> tuple:
    """Step 3: one rejection task per band (eq. 49); the client assembles
    ``(K̂, n'_1, rejected, m̄, K_var, pixels that kept no slope)``."""
    h, w = run.height, run.width
    K, K_var, m_bar = np.empty((h, w)), np.empty((h, w)), np.empty((h, w))
    used = np.empty((h, w), np.int16)
    rejected = np.empty((n1, h, w), dtype=bool)
    none = [0]

    def place(g: int, i: int, r: tuple) -> None:
        y0, rows = run.cut[i]
        _release(run.chain, i)
        K[y0:y0 + rows], used[y0:y0 + rows] = r[1], r[2]
        rejected[:, y0:y0 + rows], K_var[y0:y0 + rows] = r[3], r[4]
        m_bar[y0:y0 + rows] = r[5]
        none[0] += r[6]

    finals = submit_tasks(run.client, _kmap_reject_task,
                          [(c, half, center) for c in run.chain])
    with contextlib.closing(gather_in_order(run.client, [finals], run.counter, run.total,
                                            place)) as done:
        next(done)
    return K, used, rejected, m_bar, K_var, none[0]


def fixed_pattern_bands(client: Any, configs: Any, dark: Any, *, window: int = 9,
                        p: float = 1.5, center: str = "median", band_rows: int | None = None,
                        notes: list[str] | None = None, where: str = "fixed_pattern") -> Any:
    """The fixed-pattern map K̂ (eqs. 45–50) on the cluster, band by band of rows.

    ``configs``: ``[(config id, records or paths)]`` or a mapping (checked by the caller, see
    :func:`ccdcore.fixedpattern.fixed_pattern_map`, which calls this with a client); ``dark``
    the dark map D̂_D; ``window``, ``p``, ``center`` as there; ``notes`` the caller's notes so
    far; ``band_rows`` the band height (default: the n1 band averages and slopes take about
    :data:`~ccdcore.distributed.band_tasks.BAND_BYTES`).

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
    from ..dark.map import as_dark_map
    from ..kmap_kernels import fixed_pattern_of

    configs = list(configs.items()) if isinstance(configs, Mapping) else list(configs)
    notes = [] if notes is None else notes
    dmap = np.asarray(as_dark_map(dark), dtype=np.float64)
    h, w = dmap.shape
    groups = tuple(frames_of(recs) for _, recs in configs)
    run = _plan(client, h, w, len(configs), window, band_rows)
    try:
        _submit_averages(run, groups, dmap)                                  # step 1
        _submit_slopes(run, window)                     # step 2, queued behind the reading
        ids, levels, noises, n2s = _read_levels(run, configs, groups)        # step 1
        sigma_hat = _sigma_hat(run, where)                                   # step 2
        K, used, rejected, m_bar, K_var, none = _reject(run, len(configs), p * sigma_hat,
                                                        center)              # step 3
    except BaseException:
        run.cancel()
        raise
    return fixed_pattern_of(K, used, rejected, m_bar, K_var, sigma_hat=sigma_hat, p=p,
                            window=window, center=center, none=none, ids=ids,
                            levels=levels, noises=noises, n2s=n2s, notes=notes)
