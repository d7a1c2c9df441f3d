"""Spatial nonuniformity: SNUP with its standard error, the effect of averaging, the linear range.

Implements the measurements of M. de Lasarte, J. Pujol, M. Arjona and M. Vilaseca, "Optimized
algorithm for the spatial nonuniformity correction of an imaging system based on a
charge-coupled device color camera", Applied Optics 46(2), 2007 (the paper numbers five
equations; the SNUP is its eq. 5), per channel: ``L`` (mono), ``R``, ``G``, ``B`` (rgb) or the
four CFA planes ``R``, ``G1``, ``G2``, ``B`` of raw Bayer data (no demosaicing).

SNUP and its standard error (eq. 5)
-----------------------------------
``SNUP = 100·s/m`` with m the mean and s the sample standard deviation (ddof = 1) of the n pixel
values of a channel.  Its standard error is the delta-method error of the coefficient of
variation c = s/m for n independent pixels, written with the sample central moments m2, m3, m4:

    var(m) = m2/n,  var(s) ≈ (m4 − m2²·(n−3)/(n−1)) / (4·m2·n),  cov(m, s) ≈ m3 / (2·√m2·n),
    var(c) ≈ c²·[var(s)/s² + var(m)/m² − 2·cov(m, s)/(s·m)].

For Gaussian pixels (m3 = 0, m4 = 3·m2²) this is the textbook
var(c) ≈ c²·(1/(2(n−1)) + c²/n); the moment form stays honest for skewed or heavy-tailed pixel
distributions (hot pixels, vignetting).  It treats pixels as independent draws: the error is the
scatter of SNUP between repeated captures of the same kind of image, not including the systematic
part of a fixed pattern that stays the same from capture to capture.

Averaging (the paper's Table 1)
-------------------------------
The average of N frames keeps the fixed pattern and divides the temporal variance by N, so

    SNUP_N² ≈ SNUP_fixed² + SNUP_temporal²/N,

with SNUP_temporal = 100·√⟨σ²_t⟩/m from the per-pixel temporal variances σ²_t of all n frames and
SNUP_fixed² = SNUP_n² − SNUP_temporal²/n from the SNUP of the average of all n frames.

Linear response range (the paper's Fig. 2)
------------------------------------------
For each flat group (radiance ``level``, ``exposure``, ``gain``) the streamed average of its frames
gives, per channel, the mean level, the 0.1 % and 99.9 % pixel percentiles and the fraction of
pixel values at full scale; the dark mean at the same exposure (and setting, gain) is subtracted.
Per (gain, level, channel), the signal above dark is fitted by a straight line in the exposure
time, grown from the bottom: the two shortest exposures start the fit; the next exposure joins
(and the line is refitted) while its deviation from the extrapolated line is at most
``tolerance`` (default 2 %) of the fitted signal or ``abs_tolerance`` (default 0.5 DN, half a
quantisation step), whichever is larger; the first point that deviates more ends the linear
part.  The linear range of a channel is [lo, hi] in DN (raw pixel values, dark level included):
lo is the lowest, hi the highest mean of the linear points (below every non-linear point's mean);
``upper`` is the lowest mean of a non-linear point (full scale when none), so the true edge lies
in (hi, upper].  A group is *inside the linear range* (:meth:`Linearity.in_range`) when it is
linear in every channel and its pixels (0.1–99.9 % percentiles) lie in [lo, upper).
The saturation onset is the first exposure where more than ``saturated_fraction`` (default 0.1 %)
of the pixel values reach full scale 2^bits − 1.

Sessions with several offset settings (manifest key ``setting = "NZDI"`` ...) or gains are
analysed one setting and gain at a time (the groups come from
:meth:`~ccdcore.session.Session.flat_groups` and :meth:`~ccdcore.session.Session.dark_groups`).
Channels of each layout come from :mod:`ccdcore.channels`.

Public objects
--------------
ChannelSnup, SnupResult, snup(image, ...)
    SNUP per channel with its standard error (eq. 5).
AveragingRow, AveragingResult, snup_vs_averaging(frames, ...)
    SNUP of the average of N frames and its prediction (Table 1).
LinearityPoint, LinearityFit, Linearity, linearity(session_or_groups, ...)
    Mean level against exposure, the linear fit, the linear range and saturation onset (Fig. 2).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..channels import channel_names, channel_slices, check_layout, is_bayer, split_channels
from ..common import check_roi, crop, named_frames, sort_key
from ..errors import CcdError
from ..stats import PixelMoments

__all__ = ["ChannelSnup", "SnupResult", "snup", "AveragingRow", "AveragingResult",
           "snup_vs_averaging", "LinearityPoint", "LinearityFit", "Linearity", "linearity",
           "TOLERANCE", "ABS_TOLERANCE", "SATURATED_FRACTION"]

#: default relative tolerance of the linear range (2 %)
TOLERANCE = 0.02
#: absolute floor of the linearity tolerance, DN (half a quantisation step)
ABS_TOLERANCE = 0.5
#: fraction of pixel values at full scale that marks the saturation onset
SATURATED_FRACTION = 1e-3

Frames = Iterable[Any]


# --------------------------------------------------------------------------------------------
# SNUP (eq. 5)
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ChannelSnup:
    """SNUP of one channel: ``snup = 100·std/mean`` (eq. 5) and its standard error."""

    name: str
    mean: float
    std: float
    snup: float
    snup_err: float
    n: int

    def to_dict(self) -> dict[str, Any]:
        """The CLI's JSON shape: ``{"name", "mean", "snup", "snup_err"}`` plus ``std``, ``n``."""
        return {"name": self.name, "mean": self.mean, "snup": self.snup,
                "snup_err": self.snup_err, "std": self.std, "n": self.n}


@dataclass(frozen=True)
class SnupResult:
    """SNUP per channel of one image (over the ROI and the unmasked pixels)."""

    channels: tuple[ChannelSnup, ...]
    layout: str
    roi: tuple[int, int, int, int] | None = None

    def __getitem__(self, name: str) -> ChannelSnup:
        for c in self.channels:
            if c.name == name:
                return c
        raise KeyError(name)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.channels)

    def to_dict(self) -> dict[str, Any]:
        return {"layout": self.layout, "roi": None if self.roi is None else list(self.roi),
                "channels": [c.to_dict() for c in self.channels]}


def _snup_values(v: NDArray, name: str, where: Any) -> ChannelSnup:
    n = int(v.size)
    if n < 2:
        raise CcdError(where, f"channel {name} has {n} usable pixel(s); SNUP needs at least 2")
    mean = float(v.mean())
    if not mean > 0:
        raise CcdError(where, f"channel {name} has mean {mean:.4g} <= 0: SNUP = 100·σ/mean is "
                              "undefined (is it a dark or dark-subtracted frame?)")
    d = v - mean
    d2 = d * d
    m2 = float(d2.mean())
    std = math.sqrt(m2 * n / (n - 1))
    cv = std / mean
    if m2 > 0:
        m3 = float((d2 * d).mean())
        m4 = float((d2 * d2).mean())
        var_s = max(m4 - m2 * m2 * (n - 3) / (n - 1), 0.0) / (4.0 * m2 * n)
        cov = m3 / (2.0 * math.sqrt(m2) * n)
        var_cv = cv * cv * (var_s / std ** 2 + m2 / n / mean ** 2 - 2.0 * cov / (std * mean))
        if not var_cv > 0:   # degenerate moments: the Gaussian form
            var_cv = cv * cv * (1.0 / (2 * (n - 1)) + cv * cv / n)
    else:
        var_cv = 0.0
    return ChannelSnup(name=name, mean=mean, std=std, snup=100.0 * cv,
                       snup_err=100.0 * math.sqrt(var_cv), n=n)


def snup(image: ArrayLike, *, roi: Sequence[int] | None = None, layout: str | None = None,
         mask: ArrayLike | None = None, where: Any = "image") -> SnupResult:
    """SNUP = 100·σ/mean per channel (eq. 5 of de Lasarte et al. 2007) with its standard error.

    Parameters
    ----------
    image : array_like
        One frame: ``(H, W)`` mono or Bayer raw, or ``(H, W, 3)`` rgb; any real dtype.
    roi : sequence of int or None, optional
        ``(x, y, w, h)`` in frame pixels (even values on Bayer data); default the whole frame.
    layout : str or None, optional
        ``"mono"``, ``"rgb"``, ``"bayer-rggb"`` ...; ``None`` infers mono or rgb from the shape.
    mask : array_like or None, optional
        Optional boolean map of the frame's shape (``(H, W)`` or the full shape): True pixels are
        left out (e.g. :attr:`ccdcore.flatfield.fit.FlatField.flags`).
    where : str or PathLike, optional
        Name used in error messages (the file).

    Returns
    -------
    SnupResult
        One :class:`ChannelSnup` per channel (mean, std, SNUP and its standard error over the
        ROI's unmasked pixels; the standard error is in the module docstring), with the layout
        and the ROI.

    Raises
    ------
    CcdError
        NaN or infinite values not masked, a layout that does not fit, a bad ROI, a ``mask`` of
        another shape than the image, a channel mean <= 0 or fewer than 2 pixels.

    Examples
    --------
    >>> r = snup(np.array([[10.0, 11.0], [9.0, 10.0]]))
    >>> round(r["L"].snup, 3)
    8.165
    """
    arr = np.asarray(image)
    name = check_layout(arr.shape, layout, where)
    box = check_roi(roi, arr.shape, where, even=is_bayer(name))
    arr = crop(arr, box)
    m = None
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape[:2] != tuple(np.shape(image))[:2]:
            raise CcdError(where, f"mask shape {m.shape} differs from the image's "
                                  f"{np.shape(image)}")
        m = crop(m, box)
        if m.ndim == 2 and arr.ndim == 3:
            m = np.broadcast_to(m[..., None], arr.shape)
    bad = ~np.isfinite(arr) if arr.dtype.kind == "f" else None
    if bad is not None and bad.any() and (m is None or (bad & ~m).any()):
        raise CcdError(where, f"{int((bad if m is None else bad & ~m).sum())} NaN or infinite "
                              "pixel values; exclude them with mask=")
    out = []
    for cname, idx in channel_slices(arr.shape, name).items():
        v = arr[idx].astype(np.float64)
        if m is not None:
            v = v[~m[idx]]
        out.append(_snup_values(v.ravel(), cname, where))
    return SnupResult(channels=tuple(out), layout=name, roi=box)


# --------------------------------------------------------------------------------------------
# averaging (Table 1)
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AveragingRow:
    """SNUP of the average of the first N frames in one channel, and its prediction."""

    N: int
    channel: str
    snup: float
    snup_err: float
    predicted: float
    reduction_pct: float

    def to_dict(self) -> dict[str, Any]:
        return {"N": self.N, "channel": self.channel, "snup": self.snup,
                "snup_err": self.snup_err, "predicted": self.predicted,
                "reduction_pct": self.reduction_pct}


@dataclass(frozen=True)
class AveragingResult:
    """Table 1: SNUP against the number N of averaged frames, per channel.

    ``snup_fixed`` and ``snup_temporal`` (per channel) give the prediction
    ``sqrt(snup_fixed² + snup_temporal²/N)``; ``reduction_pct`` is ``100·(1 − SNUP_N/SNUP_1)``.
    """

    rows: tuple[AveragingRow, ...]
    snup_fixed: dict[str, float]
    snup_temporal: dict[str, float]
    n_frames: int
    layout: str

    def channel(self, name: str) -> tuple[AveragingRow, ...]:
        return tuple(r for r in self.rows if r.channel == name)

    def to_dict(self) -> dict[str, Any]:
        return {"n_frames": self.n_frames, "layout": self.layout,
                "snup_fixed": dict(self.snup_fixed), "snup_temporal": dict(self.snup_temporal),
                "rows": [r.to_dict() for r in self.rows]}


def snup_vs_averaging(frames: Frames, Ns: Sequence[int] | None = None, *,
                      layout: str | None = None, roi: Sequence[int] | None = None,
                      mask: ArrayLike | None = None,
                      correct: Callable[[NDArray], NDArray] | None = None) -> AveragingResult:
    """SNUP of the average of the first N frames, N in ``Ns`` (Table 1 of de Lasarte et al.).

    Parameters
    ----------
    frames
        Frames of one uniform field (arrays or ``(record, array)`` pairs), streamed once.
    Ns
        Numbers of frames to average; default 1, 2, 4, ... up to the number of frames.
    layout, roi, mask
        As in :func:`snup`.
    correct
        Optional correction applied to every frame first, e.g.
        :meth:`ccdcore.flatfield.fit.FlatField.correct` (then the fixed pattern left is the
        correction's residual and the temporal part dominates).

    Returns
    -------
    AveragingResult
        SNUP_N with its standard error, the prediction sqrt(SNUP_fixed² + SNUP_temporal²/N)
        (module docstring) and the reduction relative to N = 1.
    """
    want = None if Ns is None else sorted({int(n) for n in Ns})
    if want is not None and (not want or want[0] < 1):
        raise CcdError("Ns", f"numbers of frames must be >= 1, got {list(Ns)}")
    acc = PixelMoments()
    total = None
    snups: dict[int, SnupResult] = {}
    name = None
    box = None
    for fname, arr in named_frames(frames, "averaging"):
        if correct is not None:
            arr = correct(arr)
        if name is None:
            name = check_layout(arr.shape, layout, fname)
            box = check_roi(roi, arr.shape, fname, even=is_bayer(name))
        arr = crop(arr, box)
        acc.add(arr, name=fname)
        total = arr.astype(np.float64) if total is None else total + arr
        if (acc.n & (acc.n - 1)) == 0 if want is None else acc.n in want:
            snups[acc.n] = snup(total / acc.n, layout=name, mask=_crop_mask(mask, box), where=fname)
    if acc.n == 0:
        raise CcdError("frames", "no frames to average")
    n = acc.n
    if want is not None and want[-1] > n:
        raise CcdError("Ns", f"N = {want[-1]} frames asked for, only {n} given")
    res = acc.result()
    full = snups.get(n) or snup(res.mean, layout=name, mask=_crop_mask(mask, box))
    var_ch = split_channels(res.var, name)
    m_ch = None if mask is None else split_channels(_mask_full(mask, box, res.var.shape), name)
    fixed, temporal = {}, {}
    for c in full.channels:
        v = var_ch[c.name] if m_ch is None else var_ch[c.name][~m_ch[c.name]]
        t = 100.0 * math.sqrt(float(np.mean(v))) / c.mean if n > 1 else float("nan")
        temporal[c.name] = t
        fixed[c.name] = math.sqrt(max(c.snup ** 2 - t * t / n, 0.0)) if n > 1 else float("nan")
    rows = []
    for N in sorted(snups):
        for c in snups[N].channels:
            first = snups[min(snups)][c.name].snup
            pred = math.sqrt(fixed[c.name] ** 2 + temporal[c.name] ** 2 / N)
            rows.append(AveragingRow(N=N, channel=c.name, snup=c.snup, snup_err=c.snup_err,
                                     predicted=pred, reduction_pct=100.0 * (1 - c.snup / first)))
    return AveragingResult(rows=tuple(rows), snup_fixed=fixed, snup_temporal=temporal,
                           n_frames=n, layout=name)


def _crop_mask(mask: ArrayLike | None, box) -> NDArray | None:
    return None if mask is None else crop(np.asarray(mask, dtype=bool), box)


def _mask_full(mask: ArrayLike, box, shape: tuple[int, ...]) -> NDArray:
    m = crop(np.asarray(mask, dtype=bool), box)
    return np.broadcast_to(m[..., None], shape) if m.ndim == 2 and len(shape) == 3 else m


# --------------------------------------------------------------------------------------------
# linear range (Fig. 2)
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LinearityPoint:
    """One flat group in one channel: levels in DN, the fit and whether it is linear.

    ``mean_dn`` is the raw mean (dark level included), ``signal_dn = mean_dn − dark_dn``;
    ``p_low_dn``/``p_high_dn`` the 0.1 %/99.9 % pixel percentiles of the group's average;
    ``fit_dn`` the fitted signal, ``deviation`` (signal − fit)/fit; ``linear`` None when the
    level has fewer than two exposures (no fit).
    """

    gain: float | None
    level: Any
    exposure: float | None
    channel: str
    n_frames: int
    mean_dn: float
    dark_dn: float
    signal_dn: float
    p_low_dn: float
    p_high_dn: float
    saturated_fraction: float
    fit_dn: float | None = None
    deviation: float | None = None
    linear: bool | None = None

    @property
    def key(self) -> tuple[Any, Any]:
        return (self.level, self.exposure)

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in (
            "gain", "level", "exposure", "channel", "n_frames", "mean_dn", "dark_dn", "signal_dn",
            "p_low_dn", "p_high_dn", "saturated_fraction", "fit_dn", "deviation", "linear")}


@dataclass(frozen=True)
class LinearityFit:
    """The line signal = intercept + slope·exposure of one (gain, level, channel)."""

    gain: float | None
    level: Any
    channel: str
    slope: float
    intercept: float
    n_used: int
    nonlinear_exposure: float | None
    saturation_exposure: float | None

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in ("gain", "level", "channel", "slope", "intercept",
                                              "n_used", "nonlinear_exposure",
                                              "saturation_exposure")}


@dataclass(frozen=True)
class Linearity:
    """Linear response range per channel (module docstring).

    ``ranges[channel]`` is ``(lo, hi)`` in DN or None when nothing could be fitted;
    ``upper[channel]`` the lowest mean of a non-linear point (full scale, or +inf when unknown,
    when none); ``saturation_dn[channel]`` the lowest raw mean of a group past the saturation
    onset (None when no group saturates).
    """

    tolerance: float
    abs_tolerance: float
    channels: tuple[str, ...]
    points: tuple[LinearityPoint, ...]
    fits: tuple[LinearityFit, ...]
    ranges: dict[str, tuple[float, float] | None]
    saturation_dn: dict[str, float | None]
    full_scale: float | None
    upper: dict[str, float]
    setting: str | None = None
    notes: tuple[str, ...] = ()

    def group_points(self, key: tuple[Any, Any], gain: float | None = None
                     ) -> tuple[LinearityPoint, ...]:
        return tuple(p for p in self.points if p.key == key
                     and (gain is None or p.gain is None or math.isclose(p.gain, gain)))

    def in_range(self, key: tuple[Any, Any], gain: float | None = None) -> bool:
        """True when the group is linear in every channel and its 0.1–99.9 % pixel range lies
        in [lo, upper) of each channel (module docstring)."""
        pts = self.group_points(key, gain)
        if not pts:
            return False
        for p in pts:
            r = self.ranges.get(p.channel)
            if not p.linear or r is None or not (
                    r[0] <= p.p_low_dn and p.p_high_dn < self.upper[p.channel]):
                return False
        return True

    def to_dict(self) -> dict[str, Any]:
        return {"tolerance": self.tolerance, "abs_tolerance": self.abs_tolerance,
                "channels": list(self.channels), "setting": self.setting,
                "full_scale": self.full_scale,
                "ranges": {c: None if r is None else list(r) for c, r in self.ranges.items()},
                "upper": {c: None if math.isinf(u) else u for c, u in self.upper.items()},
                "saturation_dn": dict(self.saturation_dn),
                "fits": [f.to_dict() for f in self.fits],
                "points": [p.to_dict() for p in self.points], "notes": list(self.notes)}


def _channel_means(frames: Frames, layout: str | None, what: str) -> tuple[dict, str, int]:
    """Per-channel mean over all pixels and frames (darks), streamed."""
    sums: dict[str, float] = {}
    n = 0
    name = layout
    for fname, arr in named_frames(frames, what):
        name = check_layout(arr.shape, layout if n == 0 else name, fname)
        for c, v in split_channels(arr, name).items():
            sums[c] = sums.get(c, 0.0) + float(v.mean(dtype=np.float64))
        n += 1
    return {c: s / n for c, s in sums.items()} if n else {}, name, n


def _group_stats(frames: Frames, layout: str | None, full_scale: float | None, what: str):
    """A flat group's per-channel mean level, 0.1 and 99.9 percentiles of its average frame and
    saturated fraction. Only the average is needed here, so the frames are summed (one float64
    frame held, added in place), not reduced to per-pixel moments: a DSLR's 10 MP flats took
    1.3 GB in the moments' arrays and their temporaries."""
    total: NDArray[np.float64] | None = None
    n = 0
    at_fs: dict[str, int] = {}
    name = layout
    for fname, arr in named_frames(frames, what):
        name = check_layout(arr.shape, layout, fname)
        if total is None:
            total = np.zeros(arr.shape, np.float64)
        elif arr.shape != total.shape:
            raise CcdError(fname, f"shape {arr.shape} differs from the group's {total.shape}")
        if arr.dtype.kind == "f" and not np.isfinite(arr).all():
            raise CcdError(fname, "holds NaN or infinite values")
        np.add(total, arr, out=total)
        n += 1
        if full_scale is not None:
            for c, v in split_channels(arr, name).items():
                at_fs[c] = at_fs.get(c, 0) + int(np.count_nonzero(v >= full_scale))
    if total is None:
        raise CcdError(what, "has no frames")
    acc_n = n
    mean = np.divide(total, n, out=total)
    out = {}
    for c, v in split_channels(mean, name).items():
        lo, hi = np.percentile(v, [0.1, 99.9])
        out[c] = (float(v.mean()), float(lo), float(hi), at_fs.get(c, 0) / (v.size * acc_n))
    return out, name, acc_n


def _grow_fit(x: NDArray, y: NDArray, tol: float, abs_tol: float) -> tuple[float, float, int]:
    """Line y = a + b·x grown from the smallest x (module docstring): (a, b, points used)."""
    used = 2
    b = (y[1] - y[0]) / (x[1] - x[0]) if x[1] != x[0] else 0.0
    a = y[0] - b * x[0]
    while used < len(x):
        pred = a + b * x[used]
        if abs(y[used] - pred) > max(tol * abs(pred), abs_tol):
            break
        used += 1
        b, a = np.polyfit(x[:used], y[:used], 1)
    return float(a), float(b), used


def linearity(session_or_groups: Any, *, darks: Any = None, setting: str | None = None,
              gain: float | None = None, tolerance: float = TOLERANCE,
              abs_tolerance: float = ABS_TOLERANCE, saturated_fraction: float = SATURATED_FRACTION,
              layout: str | None = None, bits: int | None = None) -> Linearity:
    """Mean level against exposure per channel, the linear fit, range and saturation onset.

    Parameters
    ----------
    session_or_groups
        A :class:`~ccdcore.session.Session` (its flat frames of one setting, per gain, level and
        exposure; darks at each exposure subtracted), or a mapping ``(level, exposure) ->
        frames``.
    darks
        With a mapping: dark frames (one iterable, used for every exposure) or a mapping
        ``exposure -> frames``; None subtracts nothing (the fitted intercept absorbs the dark).
    setting, gain
        Offset setting (manifest key ``setting``) and gain to analyse; see
        :meth:`~ccdcore.session.Session.resolve_setting`.  Without ``gain``, every gain of the
        setting is fitted.
    tolerance, abs_tolerance
        A point is linear while |signal − fit| <= max(tolerance·fit, abs_tolerance); defaults
        2 % and 0.5 DN.
    saturated_fraction
        Fraction of pixel values at full scale marking the saturation onset (default 0.1 %).
    layout, bits
        Frame layout and ADC bit depth (default: the session's camera; for arrays the integer
        dtype's maximum; float frames without ``bits``: no saturation count).

    Returns
    -------
    Linearity
    """
    if not 0 < tolerance < 1:
        raise CcdError("tolerance", f"must be a fraction in (0, 1), got {tolerance}")
    src = _linearity_sources(session_or_groups, darks, setting, gain, layout, bits)
    notes = src.notes
    full_scale = None if src.bits is None else float(2 ** int(src.bits) - 1)
    points, names = _linearity_points(src, full_scale, notes)
    points, fits = _linearity_fits(points, tolerance, abs_tolerance, saturated_fraction, notes)
    ranges: dict[str, tuple[float, float] | None] = {}
    upper: dict[str, float] = {}
    saturation: dict[str, float | None] = {}
    for c in names:
        pc = [p for p in points if p.channel == c]
        bad = [p.mean_dn for p in pc if p.linear is False]
        top = min(bad) if bad else math.inf
        good = [p.mean_dn for p in pc if p.linear and p.mean_dn < top]
        ranges[c] = (min(good), max(good)) if good else None
        upper[c] = top if bad else (full_scale if full_scale is not None else math.inf)
        sat = [p.mean_dn for p in pc if p.saturated_fraction > saturated_fraction]
        saturation[c] = min(sat) if sat else None
    return Linearity(tolerance=float(tolerance), abs_tolerance=float(abs_tolerance),
                     channels=names, points=tuple(points), fits=tuple(fits), ranges=ranges,
                     saturation_dn=saturation, full_scale=full_scale, upper=upper,
                     setting=src.setting,
                     notes=tuple(dict.fromkeys(notes)))


@dataclass
class _LinearitySources:
    """What :func:`linearity` reads: the flat groups (gain, level, exposure, frames), the dark
    frames by (gain, exposure), the layout, bit depth and setting, and notes so far."""

    groups: list[tuple[float | None, Any, float | None, Frames]]
    darks: dict[tuple[float | None, Any], Frames]
    layout: str | None
    bits: int | None
    setting: str | None
    notes: list[str]


def _linearity_sources(session_or_groups: Any, darks: Any, setting: str | None,
                       gain: float | None, layout: str | None, bits: int | None
                       ) -> _LinearitySources:
    notes: list[str] = []
    groups: list[tuple[float | None, Any, float | None, Frames]] = []
    dark_src: dict[tuple[float | None, Any], Frames] = {}
    if hasattr(session_or_groups, "by_role"):
        session = session_or_groups
        setting, notes = session.resolve_setting(setting)
        layout = layout or session.camera.layout
        bits = bits or session.camera.bits
        recs = session.select("flat", setting=setting, gain=gain)
        if not recs:
            raise CcdError(str(session.root), "no flat frames (role = 'flat')"
                           + (f" with setting = {setting!r}" if setting else ""))
        for g in sorted({r.gain for r in recs}, key=sort_key):
            for (lv, t), rs in session.flat_groups(setting=setting, gain=g).items():
                groups.append((g, lv, t, session.iter_frames(rs)))
            for t, rs in session.dark_groups(setting=setting, gain=g).items():
                dark_src[(g, t)] = session.iter_frames(rs)
        if not dark_src:
            notes.append("no dark frames: signal is the raw mean (the intercept holds the dark)")
    else:
        for (lv, t), frames in dict(session_or_groups).items():
            groups.append((gain, lv, t, frames))
        if isinstance(darks, Mapping):
            dark_src = {(gain, t): f for t, f in darks.items()}
        elif darks is not None:
            dark_src = {(gain, None): darks}
    if not groups:
        raise CcdError("flats", "no flat groups to analyse")
    return _LinearitySources(groups, dark_src, layout, bits, setting, list(notes))


def _linearity_points(src: _LinearitySources, full_scale: float | None, notes: list[str]
                      ) -> tuple[list[LinearityPoint], tuple[str, ...]]:
    """Every group's per-channel mean, percentiles and saturated fraction, less the dark of its
    gain at its exposure (else the nearest exposure's, with a note); the channels' names."""
    layout = src.layout
    dark_means: dict[tuple, dict[str, float]] = {}
    for key, frames in src.darks.items():
        dark_means[key] = _channel_means(frames, layout, "dark")[0]

    def dark_for(g, t) -> dict[str, float]:
        if (g, t) in dark_means:
            return dark_means[(g, t)]
        same_gain = {k: v for k, v in dark_means.items() if k[0] == g} or dark_means
        if not same_gain:
            return {}
        if (g, None) in same_gain:
            return same_gain[(g, None)]
        near = min(same_gain, key=lambda k: abs((k[1] or 0.0) - (t or 0.0)))
        notes.append(f"no dark frames at exposure {t}: used those at {near[1]}")
        return same_gain[near]

    points: list[LinearityPoint] = []
    names: tuple[str, ...] = ()
    for g, lv, t, frames in src.groups:
        stats, name, n = _group_stats(frames, layout, full_scale,
                                      f"flat level {lv} exposure {t}")
        layout = name
        names = channel_names(name)
        dk = dark_for(g, t)
        for c, (m, lo, hi, sat) in stats.items():
            d = dk.get(c, 0.0)
            points.append(LinearityPoint(gain=g, level=lv, exposure=t, channel=c, n_frames=n,
                                         mean_dn=m, dark_dn=d, signal_dn=m - d, p_low_dn=lo,
                                         p_high_dn=hi, saturated_fraction=sat))
    return points, names


def _linearity_fits(points: list[LinearityPoint], tolerance: float, abs_tolerance: float,
                    saturated_fraction: float, notes: list[str]
                    ) -> tuple[list[LinearityPoint], list[LinearityFit]]:
    """The line of each (gain, level, channel), grown from the shortest exposure while the
    points stay within the tolerance; the points with their fit, deviation and linearity."""
    fits: list[LinearityFit] = []
    final: dict[int, LinearityPoint] = {}
    series: dict[tuple, list[int]] = {}
    for i, p in enumerate(points):
        series.setdefault((p.gain, p.level, p.channel), []).append(i)
    for (g, lv, c), idx in series.items():
        idx = [i for i in idx if points[i].exposure is not None]
        idx.sort(key=lambda i: points[i].exposure)
        if len({points[i].exposure for i in idx}) < 2:
            notes.append(f"level {lv}, channel {c}: fewer than two exposure times, no fit")
            continue
        x = np.array([points[i].exposure for i in idx])
        y = np.array([points[i].signal_dn for i in idx])
        a, b, used = _grow_fit(x, y, tolerance, abs_tolerance)
        sat_t = next((points[i].exposure for i in idx
                      if points[i].saturated_fraction > saturated_fraction), None)
        fits.append(LinearityFit(gain=g, level=lv, channel=c, slope=b, intercept=a, n_used=used,
                                 nonlinear_exposure=float(x[used]) if used < len(x) else None,
                                 saturation_exposure=sat_t))
        for j, i in enumerate(idx):
            fit = a + b * x[j]
            final[i] = replace(points[i], fit_dn=float(fit),
                                deviation=float((y[j] - fit) / fit) if fit else None,
                                linear=j < used)
    return [final.get(i, p) for i, p in enumerate(points)], fits
