"""Fixed-pattern map K̂(a, b) and the correction D_C = (D − D̂_D)/K̂ (sec. V-B, VII-A of
Healey & Kondepudy 1994).

Method (eqs. 45–51)
-------------------
For each of the n1 imaging configurations (card and lamp moved), the n2 frames are stream-averaged
(:class:`ccdcore.stats.PixelMoments`), an estimate of (K·I_i + E_DC)·A (eq. 45), and the dark
reference D̂_D is subtracted: e_i(a, b) ≈ K(a, b)·I_i(a, b)·A (eq. 46).  The local mean ē_i(a, b)
over an m×m window (default 9×9) estimates I_i(a, b)·A; the slopes are m_i = e_i/ē_i (eq. 47) and
their mean m̄ (eq. 48).  σ̂ is the per-pixel sample standard deviation (ddof = 1) of the m_i over
the configurations, averaged over all locations (the paper's "averaging the sample standard deviation
in m_i over many different locations").  Slopes outside centre ± p·σ̂ (default p = 1.5) are
rejected and the rest averaged into K̂ (eq. 49); n'_1(a, b) counts them, and the bound of eq. 50
is var[K̂] ≤ (p·σ̂)²/n̂_1 with n̂_1 = min n'_1.

The centre of the rejection interval: the paper uses the mean m̄ (eq. 48, ``center="mean"``).  One
spot of relative contrast c among n1 configurations pulls m̄ by c/n1; once that exceeds p·σ̂
(c = 0.25, n1 = 12: 0.021 against p·σ̂ ≈ 0.01 on the simulator) *every* slope of that pixel falls
outside m̄ ± p·σ̂ and nothing is left to average.  The default ``center="median"`` uses the
per-pixel median of the slopes instead, which a minority of outliers cannot move; on spot-free
pixels median and mean agree to within the noise, so K̂ is the paper's estimate there.  m̄ is
reported either way.

Border rule: ē_i is ``scipy.ndimage.uniform_filter(e_i, window, mode="reflect")``: near the edge
the window is completed by mirroring the image about its edge (``d c b a | a b c d``), so every
pixel has a full m×m mean, edge pixels' neighbours counting twice.  It is computed by
:func:`_local_mean`, a compiled copy of scipy's running sums (the same bits with scipy 1.17).

Where no slope survives the rejection (possible with n1 = 2, when the two slopes are more than
2·p·σ̂ apart), K̂ falls back to the median of the slopes; those pixels are counted in ``notes`` and
have n'_1 = 0.  Pixels with ē_i ≤ 0 give no slope for configuration i (rejected).

Memory: the n1 slope maps are kept as one (n1, H, W) float32 array (n1·H·W·4 bytes; 80 MB for 20
configurations of 1024²) plus the (n1, H, W) boolean rejection array (n1·H·W bytes) and a few
float64 (H, W) maps (the running average of one configuration, ē_i, m̄, K̂, its variance); nothing
grows with n2.  Eqs. 48 and 49 (m̄, σ̂, the median, the rejection, K̂ and its variance) are compiled
passes over the slopes pixel by pixel (numba, as :mod:`ccdcore.stats`), with no full-size
temporaries; they sum in the same order as the array formulas they replace, so the results are
the same to the bit.  The frames of the next configuration are decoded ahead in worker threads
(``Session.iter_frames(read_ahead=...)``).

On a Dask cluster (``client=``), eqs. 45–50 run band by band of rows on the workers
(:func:`ccdcore.distributed.fixed_pattern_bands`): each band's averages e_i are read with a halo
of m//2 + 1 rows above and m//2 below; ē_i's column running sums are handed from band to band
(:func:`_box_mean_band`), and the whole-frame means (the levels, the noise, σ̂) are rebuilt from
the bands' shares of numpy's pairwise sums (:func:`_pw_pieces`, :func:`_pw_total`), so the result
is the streamed one to the bit, with no process holding the n1 full-frame averages.

Public objects
--------------
FixedPattern
    Frozen result: K̂, n'_1 map, rejections, m̄, σ̂, the eq. 50 bound, summary statistics.
fixed_pattern_map(session_or_configs, dark, ...)
    Estimate K̂ from a Session or from per-configuration frame iterables.
correct(frame, dark, K)
    D_C = (D − D̂_D)/K̂ (eq. 51), float32.
CorrectionCheck, correction_check(frame, dark, K, q)
    How much the correction modifies a maximum-intensity image (sec. VII-A: 27 %, 3 %, 5 steps).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping

import numba
import numpy as np
from scipy.ndimage import uniform_filter

from .darkframe import DarkReference, as_dark_map, dark_reference
from .errors import CcdError
from .noise import READ_AHEAD
from .stats import PixelMoments

__all__ = ["FixedPattern", "fixed_pattern_map", "correct", "CorrectionCheck",
           "correction_check"]


@dataclass(frozen=True, eq=False)
class FixedPattern:
    """The fixed-pattern map K̂(a, b) of eq. 49 and its diagnostics.

    Attributes
    ----------
    K
        K̂(a, b), float64 (H, W) (eq. 49).
    n1_used
        n'_1(a, b): slopes kept per pixel (int16 map).
    rejected
        (n1, H, W) boolean: ``rejected[i, a, b]`` is True when configuration i's slope at (a, b)
        was removed as an outlier (chosen over a count map because it shows *which*
        configuration had the spot; the count is ``n1 − n1_used``).
    m_bar
        m̄(a, b), the mean of the n1 slopes (eq. 48).
    sigma_hat
        σ̂, the per-pixel sample std of the slopes averaged over locations.
    p, window, n1, n2
        Rejection width (in σ̂), local window m, configurations, frames per configuration (the
        smallest n2 when configurations differ).
    var_bound
        (p·σ̂)²/n̂_1 with n̂_1 = min n'_1 (eq. 50).
    mean, spatial_std
        Mean and std (ddof = 0) of K̂ over the array (paper: 0.99998, 3.72e-3).
    config_ids, config_levels
        Configuration ids and the mean of e_i (DN above dark) per configuration.
    noise_var_e
        Mean over configurations and pixels of the temporal variance of e_i from the n2 frames,
        σ²_N/n2 (NaN when n2 = 1).
    notes
        Warnings (few configurations, fallbacks ...).
    K_var
        Per-pixel variance of K̂ (the squared standard error of the mean of eq. 49): the sample
        variance of the n'_1 kept slopes divided by n'_1; where fewer than two slopes are kept,
        the eq. 50 bound (p·σ̂)²/max(n'_1, 1).  Measured, so usually well below the bound.
    """

    K: np.ndarray
    n1_used: np.ndarray
    rejected: np.ndarray
    m_bar: np.ndarray
    sigma_hat: float
    p: float
    window: int
    n1: int
    n2: int
    var_bound: float
    mean: float
    spatial_std: float
    config_ids: tuple = ()
    config_levels: tuple[float, ...] = ()
    noise_var_e: float = float("nan")
    notes: tuple[str, ...] = ()
    K_var: np.ndarray | None = None

    @property
    def n1_hat(self) -> int:
        """n̂_1: the smallest n'_1 over the image (eq. 50)."""
        return int(self.n1_used.min())

    @property
    def worst_ratio(self) -> float:
        """n1/n̂_1, configurations captured per configuration kept at the worst pixel (sec. V-B);
        used by :func:`ccdcore.planning.plan_acquisition`."""
        return self.n1 / self.n1_hat if self.n1_hat > 0 else float("inf")

    def to_dict(self) -> dict[str, Any]:
        """Summary statistics only (no maps), JSON-friendly."""
        return {
            "n1": self.n1, "n2": self.n2, "window": self.window, "p": self.p,
            "shape": list(self.K.shape), "mean": self.mean, "spatial_std": self.spatial_std,
            "sigma_hat": self.sigma_hat, "n1_hat": self.n1_hat,
            # None when some pixel kept no slope (n̂_1 = 0): the bound of eq. 50 is then infinite
            "var_bound": self.var_bound if math.isfinite(self.var_bound) else None,
            "sd_bound": math.sqrt(self.var_bound) if math.isfinite(self.var_bound) else None,
            "worst_ratio": self.worst_ratio if math.isfinite(self.worst_ratio) else None,
            "fraction_pixels_with_rejection": float(np.mean(self.n1_used < self.n1)),
            "n_rejected": int(self.rejected.sum()),
            "config_ids": list(self.config_ids), "config_levels": list(self.config_levels),
            "noise_var_e": None if math.isnan(self.noise_var_e) else self.noise_var_e,
            "K_var_mean": float(np.mean(self.K_var)) if self.K_var is not None else None,
            "notes": list(self.notes),
        }


# --------------------------------------------------------------------------------------------
def _configs_from(source: Any) -> tuple[list[tuple[Any, Iterable]], Any]:
    """[(config id, iterable of frames or (record, frame) pairs)] and the session (or None)."""
    if hasattr(source, "fixed_pattern_configs") and hasattr(source, "iter_frames"):
        cfgs = source.fixed_pattern_configs()
        # one stream over every configuration, decoded ahead in worker threads: the next
        # configuration's first frames are read while this one is filtered
        stream = source.iter_frames([r for recs in cfgs.values() for r in recs],
                                    read_ahead=READ_AHEAD)
        return [(cid, itertools.islice(stream, len(recs))) for cid, recs in cfgs.items()], source
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


def _config_records(source: Any) -> tuple[list[tuple[Any, tuple]], Any]:
    """[(config id, records or paths)] and the session (or None), for a cluster."""
    if hasattr(source, "fixed_pattern_configs") and hasattr(source, "iter_frames"):
        return list(source.fixed_pattern_configs().items()), source
    if isinstance(source, Mapping):
        return [(cid, tuple(recs)) for cid, recs in source.items()], None
    raise CcdError("configs", "on a cluster, give a session or a mapping config id -> records "
                              "or file paths (the workers read the frames), not arrays")


def _check_cluster_configs(configs: list[tuple[Any, tuple]], session: Any,
                           ref_shape: tuple) -> None:
    """The streamed path's checks of every configuration's frames, from their headers (same
    messages), before anything is submitted to a cluster."""
    from .distributed import check_averageable, headers_of

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


def fixed_pattern_map(session_or_configs: Any, dark: DarkReference | np.ndarray | None = None,
                      *, window: int = 9, p: float = 1.5,
                      center: str = "median", client: Any = None) -> FixedPattern:
    """Estimate the fixed-pattern map K̂(a, b) (eqs. 45–50 of Healey & Kondepudy 1994).

    Parameters
    ----------
    session_or_configs
        A :class:`~ccdcore.session.Session` (its ``fixed_pattern`` frames grouped by ``config``);
        a mapping ``config id -> iterable of frames`` (arrays or ``(record, array)`` pairs); a
        sequence of such iterables; or an ``(n1, n2, H, W)`` array.  Frames are streamed.
    dark
        The dark reference D̂_D (:class:`~ccdcore.darkframe.DarkReference` or an array).  With a
        session it may be omitted: it is then computed from the session's dark frames.
    window
        m, the side of the local window whose mean ē_i estimates I_i·A (odd, ≥ 3; default 9).
    p
        Rejection half-width in units of σ̂ (default 1.5, the paper's value).
    center
        Centre of the rejection interval: ``"median"`` (default) of the n1 slopes, or ``"mean"``,
        the paper's m̄ of eq. 48 (see the module docstring for why the median is the default).
    client
        A Dask :class:`distributed.Client`: eqs. 45–50 run on the cluster band by band of rows
        (:func:`ccdcore.distributed.fixed_pattern_bands`), so that no process holds the n1
        full-frame averages; the result equals the streamed one (every map ``np.array_equal``,
        the summary statistics ``==``).  ``session_or_configs`` is then a session or a mapping
        ``config id -> records or file paths``; a dark reference computed here uses the cluster
        too.

    Returns
    -------
    FixedPattern

    Raises
    ------
    CcdError
        Fewer than 2 configurations; frames of different shapes (naming the file); no dark
        reference; colour frames; a bad window or p.
    """
    window = int(window)
    if window < 3 or window % 2 == 0:
        raise CcdError("window", f"the local window m must be odd and at least 3, got {window}")
    if center not in ("median", "mean"):
        raise CcdError("center", f"choose 'median' or 'mean', got {center!r}")
    if not (p > 0):
        raise CcdError("p", f"the rejection width p must be positive, got {p}")
    if client is None:
        configs, session = _configs_from(session_or_configs)
    else:
        configs, session = _config_records(session_or_configs)
    where = str(getattr(session, "root", "fixed_pattern"))
    n1 = len(configs)
    if n1 < 2:
        raise CcdError(where, f"{n1} fixed-pattern configuration{'s' if n1 != 1 else ''}: K̂ "
                              "needs at least 2 (sec. V-B; the paper used 20), each a new "
                              "position of card and lamp")
    notes: list[str] = []
    if n1 < 3:
        notes.append(f"only n1 = {n1} configurations: outlier rejection cannot tell which slope "
                     "is the outlier (capture at least 3, better 10-20)")
    if dark is None:
        if session is None:
            raise CcdError("dark", "no dark reference D̂_D: K̂ needs e_i = average − D̂_D "
                                   "(eq. 46); pass dark= (see dark_reference())")
        if not session.dark_frames():
            raise CcdError(where, "no dark frames (role = 'dark'): K̂ needs the dark reference "
                                  "D̂_D (eq. 46); capture lens-capped frames or pass dark=")
        # darks at several exposures: use those at the fixed-pattern frames' exposure
        fp_exp = {r.exposure for cfg in session.fixed_pattern_configs().values() for r in cfg}
        dark_exp = {r.exposure for r in session.dark_frames()}
        pick = next(iter(fp_exp)) if len(dark_exp) > 1 and len(fp_exp) == 1 else None
        dark = dark_reference(session, exposure=pick, client=client)
    dmap = as_dark_map(dark)
    if dmap.ndim != 2:
        raise CcdError("dark", f"the dark reference must be a 2-D map, got shape {dmap.shape}")

    shape = dmap.shape
    if client is not None:
        from .distributed import fixed_pattern_bands

        _check_cluster_configs(configs, session, shape)
        return fixed_pattern_bands(client, configs, dmap, window=window, p=p, center=center,
                                   notes=notes, where=where)
    slopes = np.empty((n1,) + shape, dtype=np.float32)   # the n1 slope maps m_i (eq. 47)
    e_bar = np.empty(shape)                               # ē_i, reused for every configuration
    ids, levels, noises, n2s = [], [], [], []
    averages = (_average_config(cid, frames, shape, "the dark reference")
                for cid, frames in configs)
    for i, ((cid, _), (e, noise, n2, name)) in enumerate(zip(configs, averages)):
        np.subtract(e, dmap, out=e)                             # eq. 46, e_i = average − D̂_D
        _local_mean(e, window, e_bar)                           # ē_i, the m×m local mean
        level = float(e.mean())
        if level <= 0:
            raise CcdError(name, _NOT_LIT.format(cid=cid, level=level))
        _slopes_into(e, e_bar, slopes[i])                       # eq. 47
        ids.append(cid)
        levels.append(level)
        noises.append(noise)
        n2s.append(n2)
        del e
    del e_bar

    # eq. 48: m̄, and the per-pixel sample std of the slopes (one compiled pass over the n1 maps)
    m_bar = np.empty(shape)
    sd = np.empty(shape)
    _slope_moments(slopes.reshape(n1, -1), m_bar.reshape(-1), sd.reshape(-1))
    sigma_hat = float(np.nanmean(sd)) if np.isfinite(sd).any() else float("nan")
    del sd
    if not math.isfinite(sigma_hat):
        raise CcdError(where, _NO_SIGMA)
    K, rejected, used, K_var, none = _eq49(slopes, m_bar, p * sigma_hat, center)
    del slopes
    return _finish(K, used, rejected, m_bar, K_var, sigma_hat=sigma_hat, p=p, window=window,
                   center=center, none=none, ids=ids, levels=levels, noises=noises, n2s=n2s,
                   notes=notes)


_NOT_LIT = ("configuration {cid} is not above the dark level (mean e_i = {level:.3g} DN): is it "
            "a lit card?")
_NO_SIGMA = "no pixel has two usable slopes (ē_i > 0): cannot estimate σ̂"


def _slopes_into(e: np.ndarray, e_bar: np.ndarray, out: np.ndarray) -> None:
    """Eq. 47: m_i = e_i/ē_i into ``out`` (float32), NaN where ē_i ≤ 0; ``e`` is overwritten."""
    with np.errstate(divide="ignore", invalid="ignore"):
        np.divide(e, e_bar, out=e)
    e[~(e_bar > 0)] = np.nan                                    # no slope where ē_i ≤ 0
    out[...] = e


def _eq49(slopes: np.ndarray, m_bar: np.ndarray, half: float, center: str
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """Eq. 49 over the (n1, ...) slopes: K̂, the rejections, n'_1, K̂'s variance and the number
    of pixels that kept no slope (K̂ there is the median slope).

    Reject slopes outside centre ± half (centre m̄, or the per-pixel median of the slopes) and
    re-average; where nothing is kept, the median slope; and K̂'s error variance (see
    FixedPattern.K_var).  One compiled pass over the n1 maps, pixel by pixel, so a band of rows
    gives the rows of the whole frame's result.
    """
    n1, shape = slopes.shape[0], slopes.shape[1:]
    K = np.empty(shape)
    if center == "median":     # the centres go into K̂'s buffer, which eq. 49 then overwrites
        _median_slopes(slopes.reshape(n1, -1), K.reshape(-1))
    rejected = np.empty((n1,) + shape, dtype=bool)
    used = np.empty(shape, np.int16)
    K_var = np.empty(shape)
    _reject_and_average(slopes.reshape(n1, -1), (m_bar if center == "mean" else K).reshape(-1),
                        half, half ** 2, rejected.reshape(n1, -1), K.reshape(-1),
                        used.reshape(-1), K_var.reshape(-1))
    none = used == 0
    count = int(none.sum())
    if count:
        K[none] = _median_map(slopes[:, none])
    return K, rejected, used, K_var, count


def _finish(K: np.ndarray, used: np.ndarray, rejected: np.ndarray, m_bar: np.ndarray,
            K_var: np.ndarray, *, sigma_hat: float, p: float, window: int, center: str,
            none: int, ids: list, levels: list, noises: list, n2s: list,
            notes: list[str]) -> FixedPattern:
    """The :class:`FixedPattern` of the maps of eqs. 48–49: notes, n̂_1 and the bound of eq. 50,
    and the summary statistics over the whole maps."""
    if len(set(n2s)) > 1:
        notes.append(f"configurations have different frame counts ({min(n2s)}..{max(n2s)})")
    if none:
        notes.append(f"{none} pixel(s) kept no slope inside the centre ± p·σ̂ "
                     f"(centre = {center}); K̂ there is the median slope and n'_1 = 0")
    half = p * sigma_hat
    n1_hat = int(used.min())
    var_bound = half ** 2 / n1_hat if n1_hat > 0 else float("inf")   # eq. 50
    n2_min = min(n2s)
    noise_e = float(np.nanmean(noises)) if n2_min > 1 else float("nan")
    return FixedPattern(K=K, n1_used=used, rejected=rejected, m_bar=m_bar,
                        sigma_hat=sigma_hat, p=float(p), window=window, n1=len(ids), n2=n2_min,
                        var_bound=var_bound, mean=float(np.nanmean(K)),
                        spatial_std=float(np.nanstd(K)), config_ids=tuple(ids),
                        config_levels=tuple(levels), noise_var_e=noise_e, notes=tuple(notes),
                        K_var=K_var)


def _local_mean(e: np.ndarray, window: int, out: np.ndarray) -> None:
    """ē = ``uniform_filter(e, window, mode="reflect")`` (float64) into ``out``.

    The compiled :func:`_box_mean` repeats scipy's running sums operation for operation (with
    scipy 1.17 the same bits; ``tests/test_fixedpattern.py`` checks it to rounding) without
    scipy's strided column pass, which took most of the filter's time (0.2 s of 0.26 s on a
    2048² float64 map); frames smaller than the window, whose mirrored border folds more than
    once, go to scipy.
    """
    if e.shape[0] < window or e.shape[1] < window:
        uniform_filter(e, size=window, mode="reflect", output=out)
    else:
        _box_mean(np.ascontiguousarray(e, dtype=np.float64), window, out)


@numba.njit(cache=True, nogil=True)
def _box_mean(e, size, out):  # pragma: no cover - compiled
    """scipy.ndimage.uniform_filter(e, size, mode="reflect") of a 2-D float64 array, H, W ≥ size.

    Per line, scipy sums the first ``size`` values of the mirrored line, then adds the entering
    and subtracts the leaving value per step, each output being the running sum / ``size``;
    first along the columns (here a row of running sums at a time, into ``out``), then along the
    rows of that (each row copied to a line buffer first).
    """
    h, w = e.shape
    s1 = size // 2                       # samples mirrored in before the first one
    tmp = np.zeros(w)
    for k in range(size):                # the first window of every column
        r = k - s1
        r = -r - 1 if r < 0 else r
        for x in range(w):
            tmp[x] += e[r, x]
    for x in range(w):
        out[0, x] = tmp[x] / size
    for y in range(1, h):
        r_in = y - 1 + size - s1
        r_in = 2 * h - r_in - 1 if r_in >= h else r_in
        r_out = y - 1 - s1
        r_out = -r_out - 1 if r_out < 0 else r_out
        for x in range(w):
            tmp[x] += e[r_in, x] - e[r_out, x]
            out[y, x] = tmp[x] / size
    _row_means(out, tmp, size)


@numba.njit(cache=True, nogil=True)
def _row_means(out, line, size):  # pragma: no cover - compiled
    """The row pass of the box mean (scipy's running sum along each row, the mirror rule at the
    ends), in place on every row of ``out``; ``line`` is a scratch row."""
    w = out.shape[1]
    s1 = size // 2
    for y in range(out.shape[0]):
        line[:] = out[y]
        t = 0.0
        for k in range(size):
            c = k - s1
            c = -c - 1 if c < 0 else c
            t += line[c]
        out[y, 0] = t / size
        for x in range(1, w):
            c_in = x - 1 + size - s1
            c_in = 2 * w - c_in - 1 if c_in >= w else c_in
            c_out = x - 1 - s1
            c_out = -c_out - 1 if c_out < 0 else c_out
            t += line[c_in] - line[c_out]
            out[y, x] = t / size


@numba.njit(cache=True, nogil=True)
def _box_mean_band(e, size, h, ys, y0, tmp, out):  # pragma: no cover - compiled
    """Rows ``y0 .. y0 + len(out)`` of :func:`_box_mean` of an ``h``-row frame, from the rows
    ``ys ..`` of it held in ``e`` (the band and its halo) and the column running sums ``tmp``
    after row ``y0 − 1`` (ignored when ``y0 = 0``; left after the band's last row).

    The same operations in the same order as :func:`_box_mean`: scipy's column pass is a running
    sum down each column, so row y's ē depends on the rounding of every row above; carrying
    ``tmp`` from band to band keeps it.  Needs rows ``y0 − 1 − m//2 .. y0 + rows − 1 + m//2`` of
    the frame (fewer at its top and bottom, mirrored as on the whole frame), ``h ≥ size``.
    """
    w = e.shape[1]
    rows = out.shape[0]
    s1 = size // 2
    for y in range(y0, y0 + rows):
        if y == 0:
            for x in range(w):
                tmp[x] = 0.0
            for k in range(size):
                r = k - s1
                r = -r - 1 if r < 0 else r
                for x in range(w):
                    tmp[x] += e[r - ys, x]
            for x in range(w):
                out[0, x] = tmp[x] / size
        else:
            r_in = y - 1 + size - s1
            r_in = 2 * h - r_in - 1 if r_in >= h else r_in
            r_out = y - 1 - s1
            r_out = -r_out - 1 if r_out < 0 else r_out
            for x in range(w):
                tmp[x] += e[r_in - ys, x] - e[r_out - ys, x]
                out[y - y0, x] = tmp[x] / size
    _row_means(out, np.empty(w), size)


#: numpy's pairwise summation: blocks of at most this many values are summed 8-way unrolled
PW_BLOCK = 128


def _pw_leaves(n: int, lo: int = 0, hi: int | None = None) -> list[tuple[int, int]]:
    """The blocks ``(start, length)`` of numpy's pairwise sum of ``n`` contiguous values (its
    recursion: halve, rounding the first half down to a multiple of 8, down to ≤ 128 values),
    in order, those that meet ``lo .. hi`` only."""
    hi = n if hi is None else hi
    out: list[tuple[int, int]] = []
    stack = [(0, n)]
    while stack:
        s, m = stack.pop()
        if s >= hi or s + m <= lo or m == 0:
            continue
        if m <= PW_BLOCK:
            out.append((s, m))
            continue
        n2 = m // 2
        n2 -= n2 % 8
        stack.append((s + n2, m - n2))
        stack.append((s, n2))
    return out


@numba.njit(cache=True, nogil=True)
def _pw_block(a):  # pragma: no cover - compiled
    """numpy's pairwise-sum block (≤ 128 values of a 1-D float64 array): a plain loop below 8
    values, else 8 running sums combined as ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7)),
    then the rest."""
    n = a.shape[0]
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[i]
        return res
    r = a[:8].copy()
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] += a[i + j]
        i += 8
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        res += a[i]
        i += 1
    return res


def _pw_pieces(values: np.ndarray, lo: int, n: int) -> tuple:
    """One band's share of numpy's pairwise sum of ``n`` values: ``values`` (flat float64) are
    the values ``lo .. lo + len(values)``; returns ``(first, sums, last)``: the sums of the
    blocks inside, and the band's part ``(start, length, values)`` of a block that begins before
    it (``first``) or ends after it (``last``), else ``None``."""
    hi = lo + values.size
    first = last = None
    inside = []
    for s, m in _pw_leaves(n, lo, hi):
        if s >= lo and s + m <= hi:
            inside.append((s - lo, m))
        else:
            part = (s, m, values[max(s, lo) - lo:min(s + m, hi) - lo].copy())
            if s < lo:
                first = part
            else:
                last = part
    blocks = np.array(inside, dtype=np.int64).reshape(-1, 2)
    sums = np.empty(len(blocks))
    _pw_blocks(values, blocks, sums)
    return first, sums, last


@numba.njit(cache=True, nogil=True)
def _pw_blocks(values, blocks, out):  # pragma: no cover - compiled
    """:func:`_pw_block` of ``values[start:start + length]`` per row of ``blocks``."""
    for k in range(blocks.shape[0]):
        out[k] = _pw_block(values[blocks[k, 0]:blocks[k, 0] + blocks[k, 1]])


@numba.njit(cache=True, nogil=True)
def _pw_tree(m, sums, pos):  # pragma: no cover - compiled
    """numpy's pairwise recursion over ``m`` values whose blocks' sums are ``sums[pos:]``:
    (the sum, the next block's position)."""
    if m <= PW_BLOCK:
        return sums[pos], pos + 1
    n2 = m // 2
    n2 -= n2 % 8
    left, pos = _pw_tree(n2, sums, pos)
    right, pos = _pw_tree(m - n2, sums, pos)
    return left + right, pos


def _pw_total(n: int, pieces: Iterable[tuple]) -> float:
    """``numpy.sum`` of the ``n`` values whose bands gave ``pieces`` (:func:`_pw_pieces`, in
    order): the same blocks and the same additions, so the same bits."""
    sums: list[float] = []
    pending: list = []

    def feed(part: tuple | None) -> None:
        if part is not None:
            pending.append(part[2])
            if sum(v.size for v in pending) == part[1]:   # the block is complete
                sums.append(_pw_block(np.concatenate(pending)))
                pending.clear()

    for first, block_sums, last in pieces:
        feed(first)
        sums.extend(block_sums.tolist())
        feed(last)
    return float(_pw_tree(n, np.array(sums, dtype=np.float64), 0)[0])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _slope_moments(slopes, m_bar, sd):  # pragma: no cover - compiled
    """Eq. 48 per pixel j of the (n1, N) slopes: m̄ (mean of the finite slopes) and the sample
    standard deviation (ddof = 1) about it, float64, summed in configuration order."""
    n1, npix = slopes.shape
    for j in range(npix):
        s1 = 0.0
        cnt = 0
        for i in range(n1):
            m = np.float64(slopes[i, j])
            if np.isfinite(m):
                s1 += m
                cnt += 1
        mean = s1 / cnt
        s2 = 0.0
        for i in range(n1):
            d = np.float64(slopes[i, j]) - mean
            if np.isfinite(d):
                s2 += d * d
        m_bar[j] = mean
        sd[j] = np.sqrt(s2 / (cnt - 1))


def _median_map(slopes: np.ndarray) -> np.ndarray:
    """Per-pixel median of the (n1, ...) float32 slopes, NaNs left out (NaN where all are NaN),
    as ``numpy.nanmedian`` gives it, float64 of shape ``slopes.shape[1:]``."""
    out = np.empty(slopes.shape[1:])
    _median_slopes(np.ascontiguousarray(slopes).reshape(slopes.shape[0], -1), out.reshape(-1))
    return out


@numba.njit(cache=True, nogil=True)
def _median_slopes(slopes, out):  # pragma: no cover - compiled
    """Median of the non-NaN values of each column j of the (n1, N) float32 ``slopes``: the
    middle value, or the float32 mean of the two middle values (as ``numpy.median`` of float32).

    Blocks of pixels are sorted together by odd-even transposition (n1 rounds of
    compare-exchanges between neighbouring configurations, vectorised over the pixels of the
    block; NaN counts as +inf and is not counted), then each pixel takes its middle values.
    """
    n1, npix = slopes.shape
    B = 256
    tmp = np.empty((n1, B), np.float32)
    cnt = np.empty(B, np.int64)
    for j0 in range(0, npix, B):
        nb = min(B, npix - j0)
        for b in range(nb):
            cnt[b] = 0
        for i in range(n1):
            for b in range(nb):
                v = slopes[i, j0 + b]
                nan = np.isnan(v)
                tmp[i, b] = np.inf if nan else v
                cnt[b] += 0 if nan else 1
        for r in range(n1):
            for i in range(r % 2, n1 - 1, 2):
                for b in range(nb):
                    lo = tmp[i, b]
                    hi = tmp[i + 1, b]
                    tmp[i, b] = lo if lo < hi else hi
                    tmp[i + 1, b] = hi if lo < hi else lo
        for b in range(nb):
            k = cnt[b]
            if k == 0:
                out[j0 + b] = np.nan
            elif k % 2:
                out[j0 + b] = tmp[k // 2, b]
            else:
                out[j0 + b] = (tmp[k // 2 - 1, b] + tmp[k // 2, b]) / np.float32(2.0)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _reject_and_average(slopes, centre, half, half2, rejected, K, used,
                        K_var):  # pragma: no cover - compiled
    """Eq. 49 per pixel j of the (n1, N) slopes (``centre`` may be ``K``: each pixel's centre
    is read before its K̂ is written).

    A slope is kept when |m_i − centre| ≤ half (NaN slopes are rejected); K̂ is the mean of the
    kept slopes (float64, in configuration order; NaN where none is kept, for the caller to
    fill); ``K_var`` = Σ(m_i − K̂)²/((n'_1 − 1)·n'_1) over the kept slopes, or
    half²/max(n'_1, 1) where fewer than two are kept.
    """
    n1, npix = slopes.shape
    for j in range(npix):
        c = centre[j]
        s1 = 0.0
        n = 0
        for i in range(n1):
            m = np.float64(slopes[i, j])
            keep = abs(m - c) <= half
            rejected[i, j] = not keep
            if keep:
                s1 += m
                n += 1
        k = s1 / n
        ss = 0.0
        for i in range(n1):
            m = np.float64(slopes[i, j])
            if abs(m - c) <= half:
                d = m - k
                ss += d * d
        K[j] = k
        used[j] = n
        K_var[j] = ss / ((n - 1.0) * n) if n >= 2 else half2 / max(n, 1)


# --------------------------------------------------------------------------------------------
def _k_map(K: FixedPattern | np.ndarray) -> np.ndarray:
    return K.K if isinstance(K, FixedPattern) else np.asarray(K, dtype=np.float64)


def _operands(frame: Any, dark: Any, K: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    D = np.asarray(frame)
    if D.ndim != 2:
        raise CcdError("frame", f"expected a 2-D mono frame, got shape {D.shape}")
    dmap, kmap = as_dark_map(dark), _k_map(K)
    for name, a in (("dark", dmap), ("K", kmap)):
        if a.ndim and a.shape != D.shape:
            raise CcdError(name, f"map shape {a.shape} differs from the frame's {D.shape}")
    return D.astype(np.float64), dmap, kmap


def correct(frame: np.ndarray, dark: DarkReference | np.ndarray,
            K: FixedPattern | np.ndarray) -> np.ndarray:
    """The corrected image D_C(a, b) = (D(a, b) − D̂_D(a, b)) / K̂(a, b) (eq. 51).

    Computed in float64 and returned as float32.
    """
    D, dmap, kmap = _operands(frame, dark, K)
    return ((D - dmap) / kmap).astype(np.float32)


@dataclass(frozen=True)
class CorrectionCheck:
    """How much dividing by K̂ changes a (maximum-intensity) image, in quantisation steps q.

    The *modification* of a pixel is what eq. 51's division by K̂ changes beyond the dark
    subtraction: ``c = D_C − (D − D̂_D) = (D − D̂_D)(1/K̂ − 1)``.

    Attributes
    ----------
    frac_gt_1q
        Fraction of all pixels with |c| > q (paper: 27 %).
    frac_gt_2q
        Fraction of *all* pixels with |c| > 2q (paper: "3 % of these modifications"; for the
        paper's σ_K = 3.72e-3 at about 244 DN above dark, a Gaussian K gives 27 % above 1q and
        2.8 % of all pixels above 2q, i.e. 10 % of the 27 %; so the 3 % is read as a fraction of
        all pixels).
    frac_gt_2q_of_gt_1q
        The other reading: the fraction of the > 1q pixels that exceed 2q.
    max_change_q
        max |c| / q (paper: five steps).
    mean_level
        Mean of D − D̂_D over the image (DN).
    n_pixels
        Pixels considered (finite values).
    """

    frac_gt_1q: float
    frac_gt_2q: float
    frac_gt_2q_of_gt_1q: float
    max_change_q: float
    mean_level: float
    n_pixels: int
    q: float = 1.0

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in ("frac_gt_1q", "frac_gt_2q", "frac_gt_2q_of_gt_1q",
                                              "max_change_q", "mean_level", "n_pixels", "q")}


def correction_check(frame: np.ndarray, dark: DarkReference | np.ndarray,
                     K: FixedPattern | np.ndarray, q: float = 1.0) -> CorrectionCheck:
    """The paper's check of K̂ (sec. VII-A): how much eq. 51 modifies a maximum-intensity image.

    Parameters
    ----------
    frame
        An image D of a uniform card at maximum intensity (not clipped).
    dark, K
        D̂_D and K̂.
    q
        Quantisation step in DN (1 for integer DN).

    Returns
    -------
    CorrectionCheck
        Fractions of pixels whose modification ``(D − D̂_D)(1/K̂ − 1)`` exceeds q and 2q, and the
        largest modification in units of q.
    """
    if not q > 0:
        raise CcdError("q", f"the quantisation step must be positive, got {q}")
    D, dmap, kmap = _operands(frame, dark, K)
    level = D - dmap
    change = np.abs(level * (1.0 / kmap - 1.0)) / q
    ok = np.isfinite(change)
    c = change[ok]
    n = int(c.size)
    if n == 0:
        raise CcdError("frame", "no finite pixel to check")
    n1, n2 = int(np.count_nonzero(c > 1.0)), int(np.count_nonzero(c > 2.0))
    return CorrectionCheck(frac_gt_1q=n1 / n, frac_gt_2q=n2 / n,
                           frac_gt_2q_of_gt_1q=n2 / n1 if n1 else 0.0,
                           max_change_q=float(c.max()), mean_level=float(level[ok].mean()),
                           n_pixels=n, q=float(q))
