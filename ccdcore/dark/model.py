"""A per-pixel dark model from biases and darks at several exposures: offset + current × time.

Healey & Kondepudy 1994 model a dark frame (I ≡ 0) by eq. 43, ``D = (N_DC + N_S + N_R)·A + N_Q``:
its mean is the dark current E[N_DC]·A, which grows in proportion to the exposure time t, on
top of the camera's bias (black level).  Per pixel (a, b)::

    E[D(a, b; t)] = o(a, b) + c(a, b)·t        o: offset (bias), DN;  c: dark current, DN/s

so the dark D̂_D(t) of sec. V-A at *any* exposure comes from the model, not from the dark
frames that happen to have the nearest exposure, and a hot pixel's large current is part of
its c.  Biases are dark frames of 0 s.  The frames used are those within
:data:`~ccdcore.session.temperature.TEMPERATURE_TOLERANCE` of the temperature of the frames
they correct (dark current roughly doubles every 6 °C); the others are listed as excluded.

The fit, streamed (never a stack of frames; memory: a few float64 maps whatever the number
of frames), three passes over the frames:

1. ordinary least squares per pixel from the sums Σy, Σt·y (and the scalars n, Σt, Σt²):
   o₁, c₁;
2. the temporal variance of each frame, ``v_i = median_pixels(r²)/0.4549/(1 − h_i)`` from the
   residuals r = y − o₁ − c₁·t (0.4549 is the median of χ²₁; h_i the frame's leverage; the
   median ignores hot pixels), and the frame noise model ``σ²(t) = a + b·t`` (read noise plus
   the dark current's shot noise, eq. 43) fitted to the v_i by least squares (b >= 0);
3. weighted least squares with the weights ``w_i = 1/σ²(t_i)``, accumulated per pixel on the
   residuals of pass 1 (so no precision is lost to large offsets): o, c, and the weighted
   residual sum of squares RSS(a, b).  The residual scatter gives the per-pixel scale
   φ = RSS/(n − 2) (φ ≈ 1 where the noise model fits; a noisy/RTS pixel has φ ≫ 1) and the
   covariance of (o, c) is φ·(XᵀWX)⁻¹, X = [1, t]:
   ``var o = φ·Σw t²/Δ``, ``var c = φ·Σw/Δ``, ``cov = −φ·Σw t/Δ``, Δ = Σw·Σw t² − (Σw t)².

Public objects
--------------
DarkModel
    The fitted maps, their errors, the noise model and what the fit was made from;
    ``dark_at(t)``, ``error_var_at(t)``, ``noise_var_at(t)``, ``moments_at(t)``.
DarkModelSummary
    Its record in ``calibration.json`` (``summary()``), with ``rows()``.
fit_dark_model(frames, ...)
    The fit from ``(exposure, frame)`` pairs or ``(record, frame)`` pairs (streamed).
session_dark_model(session, ...)
    The fit from a session's dark frames at the temperature of the frames they correct.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator, Sequence

import numpy as np
from numpy.typing import NDArray

from ..common import json_safe
from ..errors import CcdError
from ..records import Record, Row
from ..session.temperature import (TEMPERATURE_TOLERANCE, match_temperature, target_temperature,
                                  temperatures_text)
from ..stats import MomentsResult

__all__ = ["DarkModel", "DarkModelSummary", "fit_dark_model", "session_dark_model", "select_darks",
           "MEDIAN_CHI2_1", "HOT_SIGMA"]

#: the median of the χ² distribution with one degree of freedom (median r²/σ² of a Gaussian)
MEDIAN_CHI2_1 = 0.45493642311957283
#: a pixel's current is counted hot when it is this many robust spatial σ above the median
HOT_SIGMA = 6.0


@dataclass(frozen=True, eq=False)
class DarkModel:
    """The per-pixel dark model o + c·t (module docstring) and what it was made from.

    Attributes
    ----------
    offset, current
        o (DN) and c (DN/s), float64 maps.
    offset_var, current_var, covariance
        Their error variances and covariance per pixel (φ·(XᵀWX)⁻¹; NaN with two frames).
    scale
        φ per pixel: weighted residual variance over the noise model (≈ 1 where it fits).
    noise_a, noise_b
        The frames' temporal noise model σ²(t) = a + b·t (DN², DN²/s).
    n
        Frames fitted.
    exposures
        Their distinct exposure times (s).
    temperature, tolerance
        The temperature the model is for (°C, ``None`` when unknown) and the matching tolerance.
    frames, excluded
        Relative paths of the frames fitted, and of the dark frames left out (other temperature).
    notes
        Decisions taken.
    """

    offset: NDArray[np.float64]
    current: NDArray[np.float64]
    offset_var: NDArray[np.float64]
    current_var: NDArray[np.float64]
    covariance: NDArray[np.float64]
    scale: NDArray[np.float64]
    noise_a: float
    noise_b: float
    n: int
    exposures: tuple[float, ...]
    temperature: float | None = None
    tolerance: float = TEMPERATURE_TOLERANCE
    frames: tuple[str, ...] = ()
    excluded: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def shape(self) -> tuple[int, ...]:
        return self.offset.shape

    def dark_at(self, t: float) -> NDArray[np.float64]:
        """The mean dark frame at exposure ``t`` (s): o + c·t (eq. 43's mean, sec. V-A)."""
        return self.offset + self.current * float(t)

    def error_var_at(self, t: float) -> NDArray[np.float64]:
        """The error variance of :meth:`dark_at` per pixel: var o + t²·var c + 2t·cov."""
        t = float(t)
        return self.offset_var + t * t * self.current_var + 2.0 * t * self.covariance

    def noise_var_at(self, t: float) -> NDArray[np.float64]:
        """The temporal variance of one dark frame at ``t`` per pixel, φ·σ²(t) (eq. 43's σ²_N)."""
        return self.scale * max(self.noise_a + self.noise_b * float(t), 0.0)

    def moments_at(self, t: float) -> MomentsResult:
        """The dark at ``t`` as the moments of ``n`` frames would give it, for
        :func:`ccdcore.flatfield.fit.flat_field`: mean o + c·t and ``var`` such that var/n is the
        model's error variance (so the flag rule's σ_Δ uses the model's error)."""
        err = self.error_var_at(t)
        err = np.where(np.isfinite(err), err, self.noise_var_at(t) / max(self.n, 1))
        return MomentsResult(mean=self.dark_at(t), var=err * self.n, n=self.n)

    @property
    def hot_current(self) -> NDArray[np.bool_]:
        """Pixels whose current is more than :data:`HOT_SIGMA` robust spatial σ (1.4826·MAD)
        above the median current: hot pixels, corrected by the model like any other."""
        med = float(np.median(self.current))
        r = 1.4826 * float(np.median(np.abs(self.current - med))) or float(self.current.std())
        return (self.current - med) > HOT_SIGMA * max(r, 1e-12)

    def summary(self) -> DarkModelSummary:
        """The record a product stores: medians of the maps and errors, hot pixels, noise
        model, frames."""
        def med(a: NDArray) -> float | None:
            return json_safe(float(np.nanmedian(a))) if np.isfinite(a).any() else None

        return DarkModelSummary(
            n=int(self.n), exposures=tuple(float(t) for t in self.exposures),
            temperature=json_safe(self.temperature), tolerance=float(self.tolerance),
            offset_median=med(self.offset), offset_err_median=med(np.sqrt(self.offset_var)),
            current_median=med(self.current), current_err_median=med(np.sqrt(self.current_var)),
            current_mean=json_safe(float(self.current.mean())),
            n_hot=int(self.hot_current.sum()), noise_a=json_safe(self.noise_a),
            noise_b=json_safe(self.noise_b), scale_median=med(self.scale),
            frames=self.frames, excluded=self.excluded, notes=self.notes)


@dataclass(frozen=True)
class DarkModelSummary(Record):
    """A :class:`DarkModel` as ``calibration.json`` stores it (no maps)."""

    #: frames fitted and their distinct exposure times (s)
    n: int
    exposures: tuple[float, ...]
    #: the temperature the model is for (°C) and the matching tolerance
    temperature: float | None
    tolerance: float
    #: medians over the pixels of o, its standard error, c and its standard error; mean c
    offset_median: float | None
    offset_err_median: float | None
    current_median: float | None
    current_err_median: float | None
    current_mean: float | None
    #: pixels whose current is more than HOT_SIGMA robust σ above the median
    n_hot: int
    #: the frames' temporal noise model σ²(t) = a + b·t, and the median residual scale φ
    noise_a: float | None
    noise_b: float | None
    scale_median: float | None
    #: relative paths of the frames fitted and of the darks left out (other temperature)
    frames: tuple[str, ...] = ()
    excluded: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    def rows(self) -> tuple[Row, ...]:
        """Frames and exposures, temperature, offset and current with their errors, hot
        pixels, noise model."""
        temp = ("unknown" if self.temperature is None
                else f"{self.temperature:g} ± {self.tolerance:g} °C")
        return (
            Row("frames", self.n, None, "frames", "biases and darks fitted, exposures "
                + ", ".join(f"{t:g}" for t in self.exposures) + " s", f"{self.n} frames"),
            Row("temperature", self.temperature, None, "°C",
                f"darks used: within {self.tolerance:g} °C; {len(self.excluded)} left out at "
                "other temperatures", temp),
            Row("offset o (median)", self.offset_median, self.offset_err_median, "DN",
                "bias per pixel, ± its median standard error"),
            Row("dark current c (median)", self.current_median, self.current_err_median,
                "DN/s", "per pixel, ± its median standard error; the dark at t is o + c·t"),
            Row("dark current (mean)", self.current_mean, None, "DN/s", "hot pixels included"),
            Row("hot pixels (current)", self.n_hot, meaning=f"current more than {HOT_SIGMA:g} "
                "robust σ above the median; corrected by the model"),
            Row("frame noise σ²(t)", self.noise_a, None, "DN²",
                f"a + b·t with b = {self.noise_b if self.noise_b is not None else float('nan'):.4g}"
                " DN²/s (read noise + dark shot noise); weights 1/σ²(t)"),
        )


# --------------------------------------------------------------------------------------------
def _pairs(items: Any) -> Callable[[], Iterator[tuple[str, float, NDArray]]]:
    """A re-iterable source of ``(name, exposure, frame)`` from ``(exposure or record, frame)``
    pairs (a list; records give ``.exposure`` and ``.relpath``)."""
    items = list(items)

    def it() -> Iterator[tuple[str, float, NDArray]]:
        for k, (key, frame) in enumerate(items):
            t = getattr(key, "exposure", key)
            name = getattr(key, "relpath", f"dark frame {k}")
            if t is None or not math.isfinite(float(t)) or float(t) < 0:
                raise CcdError(name, f"the dark model needs each frame's exposure, got {t!r}")
            yield name, float(t), np.asarray(frame, dtype=np.float64)
    return it


def fit_dark_model(frames: Any, *, temperature: float | None = None,
                   tolerance: float = TEMPERATURE_TOLERANCE, frames_used: Sequence[str] = (),
                   excluded: Sequence[str] = (), notes: Sequence[str] = ()) -> DarkModel:
    """Fit o + c·t per pixel by weighted least squares (module docstring, eq. 43).

    Parameters
    ----------
    frames
        ``(exposure, frame)`` or ``(record, frame)`` pairs (a list of arrays, or a callable
        returning a fresh iterator of ``(name, exposure, frame)`` for streaming: the frames are
        read three times).  Biases have exposure 0.
    temperature, tolerance, frames_used, excluded, notes
        Recorded in the result.

    Raises
    ------
    CcdError
        Fewer than two frames, fewer than two distinct exposures, frames of different shapes
        or not 2-D (colour frames are fitted per pixel and channel alike).
    """
    source = frames if callable(frames) else _pairs(frames)
    # pass 1: ordinary least squares
    n, st, stt, sy, sty, shape, times, names = 0, 0.0, 0.0, None, None, None, [], []
    for name, t, y in source():
        if y.ndim not in (2, 3):
            raise CcdError(name, f"expected a 2-D frame (or H×W×channels), got shape "
                                 f"{y.shape}")
        if shape is None:
            shape, sy, sty = y.shape, np.zeros(y.shape), np.zeros(y.shape)
        elif y.shape != shape:
            raise CcdError(name, f"shape {y.shape} differs from the other dark frames' {shape}")
        n, st, stt = n + 1, st + t, stt + t * t
        sy += y
        sty += t * y
        times.append(t)
        names.append(name)
    if n < 2 or len(set(times)) < 2:
        raise CcdError("dark", f"the dark model o + c·t needs dark frames at two or more "
                               f"exposures (biases count as 0 s); got {n} frame(s) at "
                               f"{sorted(set(times))} s")
    d = n * stt - st * st
    c1 = (n * sty - st * sy) / d
    o1 = (sy - c1 * st) / n
    del sy, sty
    # pass 2: each frame's temporal variance from the residuals (robust), then σ²(t) = a + b·t
    tbar, sxx = st / n, stt - st * st / n
    v = []
    for (name, t, y), lev_t in zip(source(), times):
        r2 = (y - o1 - c1 * t) ** 2
        h = 1.0 / n + (lev_t - tbar) ** 2 / sxx
        v.append(float(np.median(r2)) / MEDIAN_CHI2_1 / max(1.0 - h, 1e-6))
    a, b = _noise_line(np.asarray(times), np.asarray(v))
    # pass 3: weighted least squares on the residuals of pass 1
    w_of = {t: 1.0 / max(a + b * t, 1e-12) for t in set(times)}
    W = Wt = Wtt = 0.0
    sy, sty, syy = np.zeros(shape), np.zeros(shape), np.zeros(shape)
    for name, t, y in source():
        w = w_of[t]
        r = y - o1 - c1 * t
        W, Wt, Wtt = W + w, Wt + w * t, Wtt + w * t * t
        sy += w * r
        sty += (w * t) * r
        syy += w * r * r
    dw = W * Wtt - Wt * Wt
    dc = (W * sty - Wt * sy) / dw
    do = (Wtt * sy - Wt * sty) / dw
    rss = np.maximum(syy - do * sy - dc * sty, 0.0)
    notes = list(notes)
    if n > 2:
        phi = rss / (n - 2)
    else:
        phi = np.full(shape, np.nan)
        notes.append("two frames: no residual scatter, the model's errors are unknown")
    return DarkModel(offset=o1 + do, current=c1 + dc, offset_var=phi * Wtt / dw,
                     current_var=phi * W / dw, covariance=-phi * Wt / dw,
                     scale=np.where(np.isfinite(phi), phi, 1.0), noise_a=a, noise_b=b, n=n,
                     exposures=tuple(sorted(set(times))), temperature=temperature,
                     tolerance=float(tolerance), frames=tuple(frames_used or names),
                     excluded=tuple(excluded), notes=tuple(notes))


def _noise_line(t: NDArray, v: NDArray) -> tuple[float, float]:
    """σ²(t) = a + b·t fitted to the frames' variances by least squares, b >= 0 and a > 0."""
    if np.ptp(t) > 0:
        b, a = np.polyfit(t, v, 1)
        if b < 0:
            a, b = float(v.mean()), 0.0
    else:
        a, b = float(v.mean()), 0.0
    a = max(float(a), 1e-3 * float(max(v.min(), 1e-12)))
    return a, float(b)


def session_dark_model(session: Any, *, temperature: float | None = None,
                       tolerance: float = TEMPERATURE_TOLERANCE,
                       roles: Sequence[str] | None = None, setting: str | None = None,
                       gain: float | None = None) -> DarkModel:
    """The dark model from a session's dark frames (biases included, exposure 0) at the
    temperature of the frames they correct.

    Parameters
    ----------
    session
        A :class:`~ccdcore.session.Session`.
    temperature
        The temperature wanted (°C); default the median temperature of the flat frames, else
        the fixed-pattern, else the ptc frames (``roles`` changes that order), else none.
    tolerance
        Darks within this many °C of it are used (:data:`TEMPERATURE_TOLERANCE`).
    setting, gain
        As :meth:`Session.select` takes them.

    Raises
    ------
    CcdError
        No dark frames; none within the tolerance (the message names the temperatures); the
        matched darks at fewer than two exposures (:func:`fit_dark_model`).
    """
    recs = [r for r in session.select("dark", setting=setting, gain=gain)]
    where = str(getattr(session, "root", "session"))
    if not recs:
        raise CcdError(where, "no dark frames (role = 'dark'): the dark model needs biases "
                              "and darks")
    recs, excluded, target, notes = select_darks(session, recs, temperature, tolerance, roles)
    if not recs:
        raise CcdError(where, f"no dark frames within {tolerance:g} °C of {target:g} °C (the "
                              f"dark frames are at "
                              f"{temperatures_text([r.temperature for r in excluded])})")
    missing = [r.relpath for r in recs if r.exposure is None]
    if missing:
        raise CcdError(missing[0], "the dark model needs each dark frame's exposure (0 for a "
                                   "bias)")

    def source() -> Iterator[tuple[str, float, NDArray]]:
        for rec, frame in session.iter_frames(recs):
            yield rec.relpath, float(rec.exposure), np.asarray(frame, dtype=np.float64)
    return fit_dark_model(source, temperature=target, tolerance=tolerance,
                          frames_used=[r.relpath for r in recs],
                          excluded=[r.relpath for r in excluded], notes=notes)


def select_darks(session: Any, recs: Iterable[Any], temperature: float | None,
                 tolerance: float = TEMPERATURE_TOLERANCE, roles: Sequence[str] | None = None
                 ) -> tuple[list, list, float | None, list[str]]:
    """``(matched, excluded, target, notes)``: the dark records within ``tolerance`` of the
    temperature (given, or that of the frames they correct; with neither, the temperature
    most darks share), the others, the target and notes saying what was chosen."""
    recs = list(recs)
    notes: list[str] = []
    target, role = temperature, None
    if target is None:
        kw = {} if roles is None else {"roles": tuple(roles)}
        target, role = target_temperature(session.frames, **kw)
    temps = [r.temperature for r in recs if r.temperature is not None]
    if target is None and temps:
        # no frame to match: the temperature most darks share (within the tolerance)
        target = max(temps, key=lambda x: (sum(abs(u - x) <= tolerance for u in temps), -x))
        role = "most dark frames"
    matched, excluded = match_temperature(recs, target, tolerance)
    if excluded:
        notes.append(f"{len(excluded)} dark frame(s) at "
                     f"{temperatures_text([r.temperature for r in excluded])} left out: not "
                     f"within {tolerance:g} °C of the "
                     + (f"{role} frames' " if role and role != "most dark frames" else
                        "wanted " if role is None else "")
                     + f"{target:g} °C" + (" (the temperature most dark frames share)"
                                          if role == "most dark frames" else ""))
    unknown = sum(1 for r in matched if r.temperature is None)
    if unknown and target is not None:
        notes.append(f"{unknown} dark frame(s) without a temperature used as they are")
    return matched, excluded, target, notes
