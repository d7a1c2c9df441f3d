"""Dark reference image D̂_D(a, b) and hot/dead pixel flags (sec. V-A of Healey & Kondepudy 1994).

A dark frame (I ≡ 0) is modelled by eq. 43, ``D = (N_DC + N_S + N_R)·A + N_Q``: per pixel mean
E_DC(a, b)·A (plus the camera's black level, which this estimate simply includes) and variance
σ²_N(a, b).  Averaging ``s`` dark frames gives D̂_D(a, b) with variance σ²_N(a, b)/s.  The frames
are streamed through :class:`ccdcore.stats.PixelMoments` (memory: three float64 frames, whatever
``s``).

Hot and dead pixels (the rules, also returned in :attr:`DarkReference.hot_rule` / ``dead_rule``):

* the *robust spatial scale* of the mean map is ``r = 1.4826·MAD(D̂_D)`` (MAD about the median;
  1.4826·MAD is the standard deviation for Gaussian data);
* **hot**: ``D̂_D − median(D̂_D) > k·r`` (k = ``hot_sigma``, default 6), or *noisy* (RTS /
  telegraph pixels): temporal variance above the ``1 − 1e-6`` quantile of the scaled χ²_{s−1}
  distribution a normal pixel's sample variance follows (scale from the median variance), times
  ``noisy_factor`` (default 1);
* **dead**: ``median(D̂_D) − D̂_D > k·r`` (a cold pixel, e.g. stuck at 0), or *stuck*: temporal
  variance exactly 0 while a normal pixel practically never gives s identical quantised values
  (the rule is applied only when the expected number of such false flags over the array is below
  0.01; otherwise it is skipped and a note says so).

Public objects
--------------
DarkReference
    Frozen result: mean map D̂_D, variance map, s, mean, spatial std, hot/dead masks and rules
    (defined in :mod:`ccdcore.dark.map`, re-exported here).
dark_reference(frames_or_session, ...)
    Stream dark frames (arrays, ``(record, array)`` pairs, or a Session's dark frames).
as_dark_map(dark, where="dark")
    D̂_D as a float64 array from a :class:`DarkReference`, an array or a scalar (defined in
    :mod:`ccdcore.dark.map`, re-exported here).
"""
from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Sequence

import numpy as np
from scipy import special

from .map import DarkReference, as_dark_map
from .model import DarkModel, select_darks
from ..errors import CcdError
from ..reduce import STREAMED, Reducer
from ..session.temperature import TEMPERATURE_TOLERANCE, temperatures_text
from ..stats import MomentsResult

__all__ = ["DarkReference", "dark_reference", "dark_reference_from_model", "reference_model",
           "as_dark_map",
           "exposures_text", "nearest_exposure"]

#: false-alarm probability per pixel of the "noisy" (temporal variance) rule
NOISY_ALPHA = 1e-6


def _is_session(obj: Any) -> bool:
    return hasattr(obj, "dark_frames") and hasattr(obj, "iter_frames")


def _check_mono(a: np.ndarray, where: str | None) -> None:
    if a.ndim == 3:
        raise CcdError(where, f"colour frames {a.shape}: the dark reference is mono only for now; "
                              "per channel support comes with the flat-field work")
    if a.ndim != 2:
        raise CcdError(where, f"expected a 2-D frame, got shape {a.shape}")


def _session_darks(session: Any, exposure: float | None,
                   temperature: float | None = None) -> tuple[list, float | None, list[str]]:
    recs = list(session.dark_frames())
    where = str(getattr(session, "root", "session"))
    if not recs:
        raise CcdError(where, "no dark frames (role = 'dark'): the dark reference D̂_D of "
                              "sec. V-A needs lens-capped frames")
    recs, other, target, notes = select_darks(session, recs, temperature)
    if not recs:
        raise CcdError(where, f"no dark frames within {TEMPERATURE_TOLERANCE:g} °C of "
                              f"{target:g} °C (the dark frames are at "
                              f"{temperatures_text([r.temperature for r in other])})")
    exposures = sorted({r.exposure for r in recs if r.exposure is not None})
    if exposure is not None:
        recs = [r for r in recs if r.exposure is not None and math.isclose(r.exposure, exposure,
                                                                           rel_tol=1e-6)]
        if not recs:
            raise CcdError(where, f"no dark frames at exposure {exposure:g} s (the dark frames "
                                  f"are at {exposures_text(exposures)})")
        return recs, float(exposure), notes
    if len(exposures) > 1:
        raise CcdError(where, f"dark frames at {exposures_text(exposures)}: choose one with "
                              "exposure=")
    return recs, (exposures[0] if exposures else None), notes


def exposures_text(exposures: Sequence[float]) -> str:
    """A set of exposure times in a few words: all of them up to four ("0.1, 0.2 and 0.4 s"),
    else their number and range ("51 exposures, 4e-05 to 0.05 s")."""
    xs = sorted(exposures)
    if not xs:
        return "no known exposure"
    if len(xs) == 1:
        return f"{xs[0]:g} s"
    if len(xs) <= 4:
        return ", ".join(f"{x:g}" for x in xs[:-1]) + f" and {xs[-1]:g} s"
    return f"{len(xs)} exposures, {xs[0]:g} to {xs[-1]:g} s"


def nearest_exposure(exposures: Sequence[float], target: float) -> float:
    """The exposure of ``exposures`` nearest ``target`` in ratio (|log t − log target|; ties:
    the longer)."""
    xs = sorted(x for x in exposures if x > 0)
    if not xs or not target > 0:
        raise ValueError("positive exposures and target needed")
    return min(xs, key=lambda x: (abs(math.log(x / target)), -x))


def dark_reference(frames_or_session: Any, *, hot_sigma: float = 6.0,
                   noisy_factor: float = 1.0, exposure: float | None = None,
                   reducer: Reducer | None = None,
                   temperature: float | None = None) -> DarkReference:
    """Average dark frames into the dark reference image D̂_D(a, b) (sec. V-A, eq. 43).

    Parameters
    ----------
    frames_or_session : Session or iterable
        A :class:`~ccdcore.session.Session` (its ``dark`` frames are used), or an iterable of 2-D
        arrays or ``(record, array)`` pairs (as :meth:`Session.iter_frames` yields).  Streamed.
    hot_sigma : float, optional
        k of the hot/dead rules: a pixel whose mean is more than k robust spatial standard
        deviations (1.4826·MAD) above (hot) or below (dead) the median is flagged.
    noisy_factor : float, optional
        Multiplies the χ² threshold of the temporal-variance ("noisy"/RTS) rule; ``inf`` disables.
    exposure : float or None, optional
        With a session whose darks have several exposures, the exposure to use (seconds).
    reducer : Reducer or None, optional
        Runs the moments (:mod:`ccdcore.reduce`; default streamed here). On a Dask cluster
        (:class:`ccdcore.distributed.client.DaskReducer`) they are reduced in bands of rows, each
        worker reading its band of every frame; the maps are bit-identical to the streamed
        ones, and the hot/dead rules run here on them. ``frames_or_session`` is then a session
        or a sequence of records or file paths.
    temperature : float or None, optional
        With a session: use only the darks within
        :data:`~ccdcore.session.temperature.TEMPERATURE_TOLERANCE` of this temperature (°C);
        default the temperature of the frames they correct (flat, fixed-pattern, ptc), else
        the one most darks share (:func:`ccdcore.dark.model.select_darks`; noted).

    Returns
    -------
    DarkReference
        D̂_D (``mean_map``) with its temporal variance map, the number of frames s, its spatial
        mean and standard deviation, the hot and dead masks with their rules, the exposure, the
        notes and (with a session) the frames it was made from.

    Raises
    ------
    CcdError
        No frames, frames of different shapes (naming the file), colour frames, or a session
        with darks at several exposures and no ``exposure``; a session with no dark frames
        within the temperature tolerance or none at ``exposure``; a single 2-D frame given
        instead of an iterable of frames.

    Examples
    --------
    >>> import tempfile
    >>> from ccdcore.simulate import simulate
    >>> tmp = tempfile.TemporaryDirectory()
    >>> from ccdcore.session import open_session
    >>> _ = simulate("healey94", tmp.name, seed=1, size=(64, 48))
    >>> dark = dark_reference(open_session(tmp.name))
    >>> dark.mean_map.shape, len(dark.frames)
    ((48, 64), 16)
    >>> tmp.cleanup()
    """
    session = frames_or_session if _is_session(frames_or_session) else None
    if session is not None:
        items, exp, notes = _session_darks(session, exposure, temperature)
    else:
        items, exp, notes = frames_or_session, exposure, []
        if isinstance(items, np.ndarray) and items.ndim == 2:
            raise CcdError("frames", "give an iterable of dark frames (or a (s, H, W) stack), "
                                     "not a single frame")
    res, _ = (reducer or STREAMED).moments(
        items, what="dark", session=session, check=lambda name, a: _check_mono(a, name),
        name=lambda k: f"dark frame {k}", empty="no dark frames given")
    ref = _reference(res, exp, notes, hot_sigma, noisy_factor)
    if session is not None:
        ref = replace(ref, frames=tuple(r.relpath for r in items))
    return ref


def reference_model(session: Any, wanted: float | None) -> DarkModel | None:
    """The dark model (:func:`ccdcore.dark.model.session_dark_model`) the dark reference at
    exposure ``wanted`` should come from, or ``None`` when the darks are averaged as they are:
    ``None`` when ``wanted`` is unknown, when the darks at the matched temperature have fewer
    than two exposures (or one without an exposure), or when two or more of them are at
    ``wanted`` itself (their average is D̂_D of sec. V-A)."""
    from .model import session_dark_model

    if wanted is None:
        return None
    recs, _, target, _ = select_darks(session, session.dark_frames(), None)
    exps = {r.exposure for r in recs}
    exact = [r for r in recs if r.exposure is not None
             and math.isclose(r.exposure, wanted, rel_tol=1e-6)]
    if len(exps) < 2 or None in exps or len(exact) >= 2:
        return None
    return session_dark_model(session, temperature=target)


def dark_reference_from_model(model: DarkModel, exposure: float, *, hot_sigma: float = 6.0,
                              noisy_factor: float = 1.0,
                              notes: tuple[str, ...] = ()) -> DarkReference:
    """The dark reference D̂_D at ``exposure`` from the dark model o + c·t (sec. V-A, eq. 43;
    :mod:`ccdcore.dark.model`): D̂_D = o + c·t, the temporal variance σ²_N = φ·σ²(t) of one
    frame at t (``var_map``), the model's own error variance (``err_var_map``, which
    :attr:`DarkReference.sem_map` uses) and the hot/dead rules of :func:`dark_reference` with
    ``s`` = the frames fitted (the noisy rule's χ² then has s − 1 degrees of freedom where the
    fit leaves s − 2: a slightly looser threshold)."""
    t = float(exposure)
    res = MomentsResult(mean=model.dark_at(t), var=model.noise_var_at(t), n=model.n)
    lead = [f"from the dark model o + c·t of {model.n} frames ("
            f"{exposures_text(model.exposures)}"
            + ("" if model.temperature is None else f", {model.temperature:g} °C")
            + f") at {t:g} s", *notes, *model.notes]
    ref = _reference(res, t, lead, hot_sigma, noisy_factor)
    return replace(ref, frames=model.frames, err_var_map=model.error_var_at(t),
                   model=model.summary())


def _reference(res: MomentsResult, exp: float | None, notes: list[str], hot_sigma: float,
               noisy_factor: float) -> DarkReference:
    """D̂_D with its hot/dead flags from the dark frames' moments (rules: module docstring)."""
    s = res.n
    mean_map, var_map = res.mean, res.var
    if s < 2:
        notes.append("one dark frame: no variance map, no noisy/stuck rules, sem unknown")

    med = float(np.median(mean_map))
    mad = float(np.median(np.abs(mean_map - med)))
    r = 1.4826 * mad
    if r == 0.0:
        # quantised, very quiet darks: fall back to the std so that the rule is not "any change"
        r = float(mean_map.std()) or 1e-12
        notes.append("MAD of the dark mean map is 0; the std is used as the spatial scale")
    hot = (mean_map - med) > hot_sigma * r
    dead = (med - mean_map) > hot_sigma * r
    hot_rule = (f"hot: D̂_D − median > {hot_sigma:g}·1.4826·MAD (= {hot_sigma * r:.4g} DN above "
                f"{med:.4g} DN)")
    dead_rule = (f"dead: median − D̂_D > {hot_sigma:g}·1.4826·MAD (= {hot_sigma * r:.4g} DN "
                 f"below {med:.4g} DN)")
    if s >= 2:
        dof = s - 1
        med_var = float(np.median(var_map))
        # sample variance of a normal pixel: σ²·χ²_dof/dof; σ² from the median variance
        sigma2 = med_var / (special.chdtri(dof, 0.5) / dof)   # chdtri: χ² inverse survival
        if np.isfinite(noisy_factor) and sigma2 > 0:
            thr = noisy_factor * sigma2 * special.chdtri(dof, NOISY_ALPHA) / dof
            hot |= var_map > thr
            hot_rule += (f"; or noisy: temporal variance > {thr:.4g} DN² (the 1 − {NOISY_ALPHA:g} "
                         f"quantile of σ²·χ²_{dof}/{dof}, σ² = {sigma2:.4g} from the median"
                         + (f", × {noisy_factor:g}" if noisy_factor != 1 else "") + ")")
        # probability that s quantised values of a normal pixel are identical: at most
        # P(one bin)^(s-1), P(one bin) <= erf(0.5 / (σ√2)) for q = 1 DN
        sigma = math.sqrt(sigma2) if sigma2 > 0 else 0.0
        p_bin = float(special.erf(0.5 / (sigma * math.sqrt(2)))) if sigma > 0 else 1.0
        false_stuck = mean_map.size * p_bin ** dof
        if false_stuck < 0.01:
            dead |= var_map == 0
            dead_rule += f"; or stuck: temporal variance 0 over the {s} frames"
        else:
            notes.append(f"stuck-pixel rule (variance 0) skipped: a normal pixel would give {s} "
                         f"identical values too often (expected {false_stuck:.3g} false flags)")
    hot &= ~dead
    spatial_mean = float(mean_map.mean())
    return DarkReference(mean_map=mean_map, var_map=var_map, s=s, mean=spatial_mean,
                         spatial_std=float(mean_map.std()), hot_mask=hot, dead_mask=dead,
                         hot_rule=hot_rule, dead_rule=dead_rule, exposure=exp, notes=tuple(notes))
