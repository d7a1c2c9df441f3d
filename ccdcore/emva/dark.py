"""The dark current of an EMVA 1288 datasheet (release 3.1 sec. 3.1, as the emva1288 package
computes it: ``Results1288.u_I_mean`` and ``Results1288.u_I_var``).

The dark signal grows with the exposure time t at the dark current μ_I (e⁻/s):

* from the mean: μ_y.dark(t) = μ_y.dark(0) + K μ_I t, so μ_I = (slope of μ_y.dark against t) / K;
* from the variance: σ²_y.dark(t) = K² (σ²_d + μ_I t) + σ²_q (the thermal electrons are Poisson),
  so μ_I = (slope of σ²_y.dark against t) / K².

Both slopes are the unweighted least-squares lines of the package (``routines.LinearB``) through
the dark points (two dark frames at each exposure time). Their standard errors propagate the
points' errors through the line, √(Σ cᵢ² var_yᵢ) with cᵢ = (tᵢ − t̄)/S_tt, scaled by √(χ²/ν)
when the points scatter more than their errors (χ² of the weighted line, ν = n − 2), then K's
error.

Where the package returns a number whatever it means, here a current is reported when it is
*resolved*: positive by at least :data:`RESOLVED_Z` standard errors. Otherwise the figure is
``None`` and its note gives the reason and the bound the exposure range gives (the slope plus
:data:`RESOLVED_Z` errors, at least zero): never a negative current without a word. Fewer than
three exposure times cannot give a current (the package's rule: NaN).

Public objects
--------------
DarkCurrent, dark_current(exposures, u_y_dark, u_y_dark_err, s2_y_dark, s2_y_dark_err, K, K_err)
DarkCurrentSummary, DarkLineSummary
    The records of a :class:`DarkCurrent` and of its lines as ``calibration.json`` stores them
    (``DarkCurrent.summary()``, ``DarkLine.summary()``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import chi2

from ..common import json_safe
from ..records import Record, Row

__all__ = ["DarkCurrent", "dark_current", "DarkCurrentSummary", "DarkLineSummary", "RESOLVED_Z",
           "MIN_EXPOSURES", "POOR_FIT_Q"]

#: a dark current is resolved when it is positive by this many standard errors
RESOLVED_Z = 2.0
#: the fewest distinct exposure times that can give a dark current (the package's rule)
MIN_EXPOSURES = 3
#: a line whose points scatter with a goodness of fit Q below this gets a note
POOR_FIT_Q = 1e-3


#: the unit of the dark current
_UNIT = "e\u207b/s"


@dataclass(frozen=True)
class DarkLineSummary(Record):
    """A :class:`DarkLine` as ``calibration.json`` stores it (``dark_current.mean_line`` and
    ``dark_current.var_line``)."""

    #: the slope of the unweighted line against the exposure time and its standard error
    #: (DN/s for the mean dark signal, DN²/s for the dark variance)
    slope: float
    slope_err: float
    #: the line at zero exposure (DN or DN²)
    offset: float
    #: χ²/ν of the points about the weighted line (``None``: no degrees of freedom, or a point
    #: without an error) and ν = n − 2
    chi2_dof: float | None
    dof: int

    def q(self) -> float | None:
        """The goodness of fit Q = P(χ² ≥ χ²_observed) for ν degrees of freedom; ``None``
        without χ²/ν."""
        if self.chi2_dof is None or self.dof <= 0:
            return None
        return float(chi2.sf(self.chi2_dof * self.dof, self.dof))

    def rows(self) -> tuple[Row, ...]:
        """The slope, the offset and the fit's goodness (χ²/ν, ν, Q)."""
        return (Row("slope", self.slope, self.slope_err, "",
                    "change of the dark signal per second of exposure"),
                Row("offset", self.offset, None, "", "the line at zero exposure time"),
                Row("chi2/dof", self.chi2_dof, None, "",
                    "scatter of the dark points about the line relative to their errors"),
                Row("dof", self.dof, None, "", "degrees of freedom of the line"),
                Row("Q", self.q(), None, "",
                    "probability of a scatter this large by chance (goodness of fit)"))


@dataclass(frozen=True)
class DarkLine:
    """One unweighted line y = offset + slope · t with the slope's standard error, the reduced
    chi-square of the points about the weighted line (their own errors) and the degrees of
    freedom."""

    slope: float
    slope_err: float
    offset: float
    chi2_dof: float
    dof: int

    def summary(self) -> DarkLineSummary:
        """The record ``calibration.json`` stores (NaN χ²/ν as ``None``)."""
        return DarkLineSummary(slope=json_safe(self.slope), slope_err=json_safe(self.slope_err),
                               offset=json_safe(self.offset), chi2_dof=json_safe(self.chi2_dof),
                               dof=json_safe(self.dof))

    def to_dict(self) -> dict[str, Any]:
        return self.summary().to_dict()


def _line(t: np.ndarray, y: np.ndarray, var_y: np.ndarray) -> DarkLine:
    tm = float(t.mean())
    stt = float(np.sum((t - tm) ** 2))
    slope = float(np.sum((t - tm) * (y - y.mean())) / stt)
    offset = float(y.mean() - slope * tm)
    c = (t - tm) / stt
    err = math.sqrt(float(np.sum(c * c * var_y)))
    dof = t.size - 2
    chi2_dof = math.nan
    if dof > 0 and np.all(var_y > 0):
        # whether the points scatter more than their errors: the χ² of the weighted line (the
        # unweighted line's residuals at precise points carry the noisy points' pull: with
        # errors spanning decades its χ² was 3 times ν for points scattered by their errors)
        w = 1.0 / var_y
        tw = float(np.sum(w * t) / np.sum(w))
        sw = float(np.sum(w * (t - tw) ** 2))
        b = float(np.sum(w * (t - tw) * y) / sw)
        a = float(np.sum(w * (y - b * t)) / np.sum(w))
        chi2_dof = float(np.sum(w * (y - a - b * t) ** 2)) / dof
        if chi2_dof > 1.0:
            err *= math.sqrt(chi2_dof)
    return DarkLine(slope=slope, slope_err=err, offset=offset, chi2_dof=chi2_dof, dof=dof)


@dataclass(frozen=True)
class DarkCurrentSummary(Record):
    """A :class:`DarkCurrent` as ``calibration.json`` stores it (``emva1288.dark_current``)."""

    #: μ_I from the mean dark signal (slope / K) and its standard error, e⁻/s; ``None`` where
    #: not resolved
    u_I_mean: float | None
    u_I_mean_err: float | None
    #: μ_I from the dark variance (slope / K²) and its standard error, e⁻/s; ``None`` where
    #: not resolved
    u_I_var: float | None
    u_I_var_err: float | None
    #: the upper bounds of an unresolved μ_I.mean and μ_I.var, e⁻/s (``None``: resolved, or
    #: too few exposure times)
    u_I_mean_bound: float | None
    u_I_var_bound: float | None
    #: the lines of μ_y.dark (DN) and σ²_y.dark (DN²) against t (s); ``None`` below three
    #: exposure times
    mean_line: DarkLineSummary | None
    var_line: DarkLineSummary | None
    #: the exposure times of the dark points, s
    exposures: tuple[float, ...]
    #: why a figure is missing or doubtful
    notes: tuple[str, ...]

    def _current(self, name: str, symbol: str, how: str) -> Row:
        value, err = getattr(self, name), getattr(self, f"{name}_err")
        bound = getattr(self, f"{name}_bound")
        text = None
        if value is None:
            text = ("not determined" if bound is None
                    else f"not determined: below {bound:.3g} {_UNIT}")
        return Row(f"Dark current from the {how}, {symbol}", value, err, _UNIT,
                   f"thermal electrons per second, from the growth of the dark {how} with "
                   "the exposure time", text)

    def rows(self) -> tuple[Row, ...]:
        """Both dark currents (or their bounds), the number of exposure times and the
        goodness of both lines."""
        out = [self._current("u_I_mean", "\u03bc_I.mean", "mean"),
               self._current("u_I_var", "\u03bc_I.var", "variance"),
               Row("exposure times", len(set(self.exposures)), None, "",
                   "distinct exposure times of the dark points")]
        for what, line in (("mean", self.mean_line), ("variance", self.var_line)):
            if line is not None:
                q = line.q()
                out.append(Row(f"{what} line chi2/dof", line.chi2_dof, None, "",
                               f"scatter of the dark {what} about its line relative to the "
                               f"errors (\u03bd = {line.dof}"
                               + ("" if q is None else f", Q = {q:.2g}") + ")"))
        return tuple(out)


@dataclass(frozen=True)
class DarkCurrent:
    """The dark current from the mean dark signal (``u_I_mean``) and from the dark variance
    (``u_I_var``), e⁻/s, with their standard errors; ``None`` where not resolved (then
    ``u_I_mean_bound`` / ``u_I_var_bound`` is the upper bound, and ``notes`` say why). The lines
    (``mean_line`` in DN against s, ``var_line`` in DN² against s; ``None`` below three exposure
    times) serve the plots."""

    u_I_mean: float | None
    u_I_mean_err: float | None
    u_I_var: float | None
    u_I_var_err: float | None
    u_I_mean_bound: float | None
    u_I_var_bound: float | None
    mean_line: DarkLine | None
    var_line: DarkLine | None
    exposures: tuple[float, ...]
    notes: tuple[str, ...]

    def figures(self) -> dict[str, float | None]:
        return {"u_I_mean": self.u_I_mean, "u_I_mean_err": self.u_I_mean_err,
                "u_I_var": self.u_I_var, "u_I_var_err": self.u_I_var_err}

    def summary(self) -> DarkCurrentSummary:
        """The record ``calibration.json`` stores (NaN as ``None``)."""
        return DarkCurrentSummary(
            u_I_mean=json_safe(self.u_I_mean), u_I_mean_err=json_safe(self.u_I_mean_err),
            u_I_var=json_safe(self.u_I_var), u_I_var_err=json_safe(self.u_I_var_err),
            u_I_mean_bound=json_safe(self.u_I_mean_bound),
            u_I_var_bound=json_safe(self.u_I_var_bound),
            mean_line=None if self.mean_line is None else self.mean_line.summary(),
            var_line=None if self.var_line is None else self.var_line.summary(),
            exposures=tuple(json_safe(list(self.exposures))), notes=tuple(self.notes))

    def to_dict(self) -> dict[str, Any]:
        return self.summary().to_dict()


def _resolve(name: str, what: str, slope: float, slope_err: float, scale: float,
             scale_rel_err: float, t_span: tuple[float, float], notes: list[str]
             ) -> tuple[float | None, float | None, float | None]:
    """(value, error, bound) of one dark current: slope / scale in e⁻/s when resolved."""
    value = slope / scale
    err_stat = slope_err / scale
    err = math.hypot(err_stat, value * scale_rel_err)
    span = f"{t_span[0]:g} to {t_span[1]:g} s"
    if slope > RESOLVED_Z * slope_err and slope > 0:
        return value, err, None
    bound = max(value, 0.0) + RESOLVED_Z * err_stat
    if value < 0:
        notes.append(f"{name} is not determinable: the {what} falls with the exposure time "
                     f"({value:.3g} ± {err_stat:.2g} e-/s over {span}), which a dark current "
                     f"cannot do (offset drift or too short a range); the range bounds it below "
                     f"{bound:.3g} e-/s")
    else:
        notes.append(f"{name} is not resolved: {value:.3g} ± {err_stat:.2g} e-/s over {span} is "
                     f"within {RESOLVED_Z:g} standard errors of zero (longer exposures would "
                     f"resolve it); it is below {bound:.3g} e-/s")
    return None, None, bound


def dark_current(exposures: Sequence[float | None], u_y_dark: ArrayLike, u_y_dark_err: ArrayLike,
                 s2_y_dark: ArrayLike, s2_y_dark_err: ArrayLike, K: float, K_err: float
                 ) -> DarkCurrent:
    """The dark current (module docstring) from the dark points: exposure times (s), mean dark
    signal μ_y.dark (DN) and temporal dark variance σ²_y.dark (DN²) with their standard errors,
    and the system gain K (DN/e⁻) with its error."""
    notes: list[str] = []
    known = [i for i, t in enumerate(exposures) if t is not None]
    t = np.array([exposures[i] for i in known], np.float64)
    distinct = np.unique(t)
    if distinct.size < MIN_EXPOSURES or len(known) < len(exposures):
        why = ("some dark points have no exposure time" if len(known) < len(exposures) else
               f"the dark points are at {distinct.size} exposure time"
               f"{'s' if distinct.size != 1 else ''}")
        notes.append(f"no dark current: {why}; it needs dark frames at "
                     f"{MIN_EXPOSURES} or more exposure times (an exposure-time series)")
        return DarkCurrent(None, None, None, None, None, None, None, None,
                           tuple(float(x) for x in t), tuple(notes))
    mu = np.asarray(u_y_dark, np.float64)[known]
    mu_var = np.asarray(u_y_dark_err, np.float64)[known] ** 2
    s2 = np.asarray(s2_y_dark, np.float64)[known]
    s2_var = np.asarray(s2_y_dark_err, np.float64)[known] ** 2
    mean_line = _line(t, mu, mu_var)
    var_line = _line(t, s2, s2_var)
    span = (float(t.min()), float(t.max()))
    rel_K = K_err / K if K > 0 else math.nan
    m, m_err, m_bound = _resolve("u_I_mean", "mean dark signal", mean_line.slope,
                                 mean_line.slope_err, K, rel_K, span, notes)
    v, v_err, v_bound = _resolve("u_I_var", "dark variance", var_line.slope, var_line.slope_err,
                                 K * K, 2.0 * rel_K, span, notes)
    for name, what, line in (("u_I_mean", "mean dark signal", mean_line),
                             ("u_I_var", "dark variance", var_line)):
        q = chi2.sf(line.chi2_dof * line.dof, line.dof) if math.isfinite(line.chi2_dof) else 1.0
        if q < POOR_FIT_Q:
            notes.append(f"{name}: the {what} scatters about its line far more than its errors "
                         f"allow (chi²/dof = {line.chi2_dof:.3g}, Q = {q:.2g}); its error is "
                         f"scaled by √(chi²/dof), but the line may not describe the darks "
                         "(quantised dark frames, a drifting dark level)")
    return DarkCurrent(u_I_mean=m, u_I_mean_err=m_err, u_I_var=v, u_I_var_err=v_err,
                       u_I_mean_bound=m_bound, u_I_var_bound=v_bound, mean_line=mean_line,
                       var_line=var_line, exposures=tuple(float(x) for x in t),
                       notes=tuple(notes))
