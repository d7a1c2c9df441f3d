"""Flat-field correction with gain and offset maps G, O (de Lasarte et al. 2007, eqs. 1–4).

M. de Lasarte, J. Pujol, M. Arjona, M. Vilaseca, "Optimized algorithm for the spatial
nonuniformity correction of an imaging system based on a charge-coupled device color camera",
Applied Optics 46(2), 2007.  With DL_0 the dark image and DL_B the base correction image (each the
streamed average of its frames, :class:`ccdcore.stats.PixelMoments`) the corrected image is

    DL_c(i, j) = k·(DL(i, j) − DL_0(i, j)) / (DL_B(i, j) − DL_0(i, j))          (eq. 1)
               = O(i, j) + G(i, j)·DL(i, j)                                       (eq. 2)
    G(i, j) = (⟨DL_B⟩ − ⟨DL_0⟩) / (DL_B(i, j) − DL_0(i, j))                       (eq. 3)
    O(i, j) = ⟨DL_0⟩ − G(i, j)·DL_0(i, j)                                         (eq. 4)

with ⟨·⟩ the spatial mean of a channel.  Eq. 2 with eqs. 3–4 is eq. 1 plus the constant ⟨DL_0⟩:
the corrected image keeps the camera's mean dark level.  The reference level k is, by default,
the paper's optimum "the mean digital level of the [base] image": k = ⟨DL_B − DL_0⟩ over the
channel's unflagged pixels (``k=`` overrides it, one number or one per channel).  Everything is
per channel: ``L`` (mono), ``R``, ``G``, ``B`` (rgb), or on raw Bayer data the four CFA planes
``R``, ``G1``, ``G2``, ``B`` without demosaicing; G and O are stored in the frame's own layout
(the full mosaic for Bayer data), each plane computed from its own sites only.

Flagged pixels (never a division by zero)
-----------------------------------------
Δ = DL_B − DL_0 has the per-pixel standard error σ_Δ = sqrt(s²_B/n_B + s²_0/n_0) from the
per-pixel temporal variances of the n_B base and n_0 dark frames.  A pixel is flagged when
Δ <= c·σ_Δ (``noise_limit`` c, default 5: G would be uncertain by more than 20 %; a non-positive
Δ is always flagged).  A flagged pixel gets G = k / Δ̃ with Δ̃ the mean Δ of the *unflagged*
pixels of the same channel in a ``window`` × ``window`` neighbourhood (default 9, in plane pixels
for Bayer data), so vignetting is still corrected there; with no unflagged neighbour, Δ̃ is the
channel's mean Δ (G = 1 for the default k).  O follows eq. 4.  With a single base and a single
dark frame σ_Δ is unknown and only Δ <= 0 is flagged (noted).

Base image, settings, dark image (the paper's sections on the optimised algorithm)
---------------------------------------------------------------------------------
:func:`recommend_base` picks, among the flat groups (radiance level, exposure) of a setting, the
one inside the linear response range whose mean level is closest to the middle of that range (see
:func:`recommend_base`); :func:`base_image_study` corrects every flat group with every candidate
base (Fig. 3, Tables 3–5).  :func:`zero_dark` detects a dark image clipped at zero (the ZDI
setting, which loses the negative half of the dark noise and biases DL_0);
:func:`compare_dark_settings` gives the SNUP after correction for each captured setting (Table 2).

Healey–Kondepudy K̂ against G (issue 4, item 7)
----------------------------------------------
:func:`compare_with_k_map` corrects the same uniform-field frames with D_C = (D − D̂_D)/K̂
(eq. 51 of Healey & Kondepudy 1994, :func:`ccdcore.fixedpattern.correct`) and with O + G·DL.
A uniform-field session has no card/lamp configurations, so K̂ is built as the paper would from
several *flat groups* treated as configurations (each group's average minus its dark, eqs.
45–49).  K̂ divides each configuration by its local m×m mean, so it keeps only the high-frequency
pixel-to-pixel gain (PRNU) and, by construction, none of the low-frequency vignetting; G is
measured against the *global* mean and holds both.  On the ``delasarte07`` simulator, after
correction a uniform field keeps, with K̂, essentially all of its vignetting (SNUP ≈ that of the
true flat field, about 6 %), while with G it drops to the shot-noise limit; both recover the PRNU
(their high-pass residuals against the true flat field are equally small).  Use K̂ for scenes
whose illumination is not uniform (and vignetting is part of the scene); use G where the goal is
a flat response of the whole optical system.

Public objects
--------------
FlatChannel, FlatField
    Per-channel summary; the result with G, O, flags, DL_0/DL_B moments, ``correct()``, ``maps()``.
FlatChannelSummary, FlatFieldSummary
    Their records as ``calibration.json`` stores them (``summary()``), with ``rows()``.
flat_field(dark_frames, base_frames, ...)
    G and O from dark and base frames (eqs. 1–4).
flat_field_from_session(session, ...)
    The same from a session: setting, darks at the base exposure and temperature (or the dark
    model o + c·t of :mod:`ccdcore.dark.model`, or DL_0 = 0 without darks), ``base="auto"``.
FlatDark, session_dark(session, groups, key, ...)
    The dark image DL_0 chosen for a flat group.
held_out_check(session, groups, key, dark, ...)
    G, O from all flats of a group but one; that one corrected against the noise floor
    (:mod:`ccdcore.flatfield.check`).
correct(frame, G, O)
    DL_c = O + G·DL as float32 (for saved maps).
BaseRecommendation, recommend_base(session, ...)
    The base correction image inside the linear range, with the reason.
BaseStudy, base_image_study(session, ...)
    SNUP after correction for every image group and candidate base (Fig. 3, Tables 3–5).
ZeroDark, zero_dark(darks, ...)
    Fraction of zero pixels per channel and the warning of a zero-clipped dark image.
SettingsComparison, compare_dark_settings(session, ...)
    SNUP after correction per offset setting (Table 2).
KMapComparison, compare_with_k_map(session, ...)
    G/O against Healey–Kondepudy's K̂ on the same uniform-field data.
NOISE_LIMIT, WINDOW, ZERO_LIMIT
    Defaults of the flag rule and of the zero-dark warning.

The results (FlatChannel, FlatField, their summaries, BaseRecommendation, BaseStudy, ZeroDark,
SettingsComparison, KMapComparison), correct and the three defaults are defined in
:mod:`ccdcore.flatfield.results` and re-exported here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import uniform_filter

from ..channels import channel_names, channel_slices, check_layout, split_channels
from ..common import group_by, named_frames, sort_key
from ..dark.frame import DarkReference
from ..dark.model import DarkModel, select_darks, session_dark_model
from .check import HELD_OUT_FACTOR, HeldOutCheck, held_out_figures
from ..session.temperature import TEMPERATURE_TOLERANCE, temperatures_text
from ..errors import CcdError
from .results import (NOISE_LIMIT, WINDOW, ZERO_LIMIT, BaseRecommendation, BaseStudy,
                                FlatChannel, FlatChannelSummary, FlatField, FlatFieldSummary,
                                KMapComparison, SettingsComparison, ZeroDark, correct,
                                group_words)
from ..reduce import STREAMED, Reducer
from ..stats import MomentsResult, PixelMoments
from .uniformity import Linearity, linearity, snup

__all__ = ["FlatChannel", "FlatField", "FlatChannelSummary", "FlatFieldSummary", "flat_field",
           "flat_field_from_session", "correct", "BaseRecommendation", "recommend_base",
           "BaseStudy", "base_image_study", "ZeroDark", "zero_dark", "SettingsComparison",
           "compare_dark_settings", "KMapComparison", "compare_with_k_map", "NOISE_LIMIT",
           "WINDOW", "ZERO_LIMIT", "FlatDark", "session_dark", "held_out_check"]


# --------------------------------------------------------------------------------------------
# G and O
# --------------------------------------------------------------------------------------------
def _moments(reducer: Reducer, src: Any, what: str, counts: dict | None,
             layout: str | None, session: Any = None) -> tuple[MomentsResult, str]:
    """The frames' per-pixel moments by ``reducer`` (a MomentsResult or DarkReference is taken
    as is); with ``counts``, their zero values per channel of ``layout``."""
    if isinstance(src, MomentsResult):
        return src, what
    if isinstance(src, DarkReference):
        return MomentsResult(mean=src.mean_map, var=src.var_map, n=src.s), what
    if src is None:
        raise CcdError(what, f"no {what} frames")
    return reducer.moments(src, what=what, session=session, zeros=counts, layout=layout)


def _channel_k(k: Any, names: tuple[str, ...]) -> dict[str, float | None]:
    if k is None:
        return {n: None for n in names}
    if isinstance(k, Mapping):
        missing = [n for n in names if n not in k]
        if missing:
            raise CcdError("k", f"no reference level for channel(s) {', '.join(missing)}")
        return {n: float(k[n]) for n in names}
    if np.ndim(k) == 0:
        return {n: float(k) for n in names}
    ks = list(k)
    if len(ks) != len(names):
        raise CcdError("k", f"give one reference level per channel {names}, got {len(ks)}")
    return {n: float(v) for n, v in zip(names, ks)}


def flat_field(dark_frames: Any, base_frames: Any, *, layout: str | None = None,
               k: float | Sequence[float] | Mapping[str, float] | None = None,
               noise_limit: float = NOISE_LIMIT, window: int = WINDOW,
               reducer: Reducer | None = None, session: Any = None) -> FlatField:
    """Gain and offset maps G, O of the flat-field correction (eqs. 1–4, de Lasarte et al. 2007).

    Parameters
    ----------
    dark_frames
        Dark frames (arrays or ``(record, array)`` pairs, streamed), a
        :class:`~ccdcore.stats.MomentsResult` or a :class:`~ccdcore.dark.frame.DarkReference`:
        DL_0 is their average.
    base_frames
        Frames of the base correction image (uniform field), same forms: DL_B is their average.
    layout
        ``"mono"``, ``"rgb"``, ``"bayer-rggb"`` ...; ``None`` infers mono or rgb from the shape.
    k
        Reference level(s); default the paper's ⟨DL_B − DL_0⟩ per channel (over unflagged pixels).
    noise_limit, window
        c and the neighbourhood of the flag rule (module docstring).
    reducer
        Runs the averages (:mod:`ccdcore.reduce`; default streamed here). On a Dask cluster
        (:class:`ccdcore.distributed.client.DaskReducer`) DL_0 and DL_B (and the dark image's zero
        counts) are reduced in bands of rows, bit-identical to the streamed averages; frames
        are then given as session records or file paths (a
        :class:`~ccdcore.stats.MomentsResult` or :class:`~ccdcore.dark.frame.DarkReference` is
        taken as is).
    session
        The session whose records the frames are (its header cache and read-ahead).

    Returns
    -------
    FlatField

    Raises
    ------
    CcdError
        No dark or no base frames; frames of different shapes (naming the file); NaN or infinite
        values; a layout that does not fit the frames; a channel with no usable pixel.

    Examples
    --------
    >>> dark = [np.full((4, 4), 10.0)] * 2
    >>> base = [np.full((4, 4), 110.0)] * 2
    >>> ff = flat_field(dark, base)
    >>> float(ff.correct(np.full((4, 4), 60.0))[0, 0])
    60.0
    """
    if not noise_limit >= 0:
        raise CcdError("noise_limit", f"must be >= 0, got {noise_limit}")
    window = int(window)
    if window < 1:
        raise CcdError("window", f"must be >= 1, got {window}")
    zeros: dict[str, tuple[int, int]] = {}
    red = reducer or STREAMED
    dark, dname = _moments(red, dark_frames, "dark", zeros, layout, session)
    base, bname = _moments(red, base_frames, "base", None, layout, session)
    return _gain_offset(dark, dname, base, bname, zeros, layout, k, noise_limit, window)


def _gain_offset(dark: MomentsResult, dname: str, base: MomentsResult, bname: str,
                 zeros: dict[str, tuple[int, int]], layout: str | None, k: Any,
                 noise_limit: float, window: int) -> FlatField:
    """G, O and the flags from DL_0 and DL_B (eqs. 1–4; flag rule of the module docstring)."""
    if base.mean.shape != dark.mean.shape:
        raise CcdError(bname, f"base frames have shape {base.mean.shape}, the dark frames "
                              f"{dark.mean.shape}")
    lay = check_layout(base.mean.shape, layout, bname)
    names = channel_names(lay)
    kk = _channel_k(k, names)
    notes: list[str] = []
    delta = base.mean - dark.mean
    if base.n > 1 or dark.n > 1:
        vb = base.var / base.n if base.n > 1 else 0.0
        vd = dark.var / dark.n if dark.n > 1 else 0.0
        if base.n == 1 or dark.n == 1:
            notes.append(f"one {'base' if base.n == 1 else 'dark'} frame: its temporal noise is "
                         "left out of the flag rule")
        flags = ~(delta > noise_limit * np.sqrt(vb + vd))
    else:
        notes.append("one base and one dark frame: no temporal variance, only DL_B − DL_0 <= 0 "
                     "is flagged")
        flags = ~(delta > 0)
    G = np.empty(delta.shape, np.float32)
    O = np.empty(delta.shape, np.float32)
    chans = []
    for c, idx in channel_slices(delta.shape, lay).items():
        d, f, d0 = delta[idx], flags[idx], dark.mean[idx]
        ok = ~f
        if not ok.any():
            raise CcdError(bname, f"channel {c}: the base image is nowhere above the dark image "
                                  f"by more than {noise_limit}·σ (mean DL_B − DL_0 = "
                                  f"{float(d.mean()):.3g} DN); is it a lit flat?")
        k_c = float(d[ok].mean()) if kk[c] is None else kk[c]
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.where(ok, k_c / np.where(ok, d, 1.0), 0.0)
        if f.any():
            okf = ok.astype(np.float64)
            num = uniform_filter(np.where(ok, d, 0.0), window, mode="reflect")
            den = uniform_filter(okf, window, mode="reflect")
            with np.errstate(divide="ignore", invalid="ignore"):
                local = np.where(den > 1e-12, num / den, np.nan)
            local = np.where(np.isfinite(local) & (local > 0), local, float(d[ok].mean()))
            g = np.where(ok, g, k_c / local)
        dl0 = float(d0.mean())
        G[idx] = g
        O[idx] = dl0 - g * d0
        z = zeros.get(c)
        chans.append(FlatChannel(name=c, k=k_c, dark_level=dl0,
                                 base_level=float(base.mean[idx].mean()),
                                 n_flagged=int(f.sum()), n_pixels=int(f.size),
                                 dark_zero_fraction=None if z is None else z[0] / z[1]))
    worst = max((c.dark_zero_fraction or 0.0) for c in chans)
    if worst > ZERO_LIMIT:
        notes.append(ZeroDark.warning_text(worst))
    return FlatField(G=G, O=O, flags=flags, dark=dark, base=base, layout=lay,
                     channels=tuple(chans), noise_limit=float(noise_limit), window=window,
                     notes=tuple(notes))


def _pick_darks(session: Any, setting: str | None, gain: float | None,
                exposure: float | None, recs: Sequence[Any] | None = None
                ) -> tuple[tuple, float | None, list[str]]:
    """Dark frames at ``exposure`` (of ``recs``, default every dark of the setting and gain)."""
    groups = (session.dark_groups(setting=setting, gain=gain) if recs is None
              else group_by(recs, lambda r: r.exposure))
    where = str(session.root)
    if not groups:
        raise CcdError(where, "no dark frames (role = 'dark')"
                       + (f" with setting = {setting!r}" if setting else "")
                       + ": the flat-field correction needs the dark image DL_0")
    if exposure is not None:
        for t, rs in groups.items():
            if t is not None and math.isclose(t, exposure, rel_tol=1e-6):
                return rs, t, []
    if None in groups:
        return groups[None], None, ["dark frames without exposure time used"]
    if len(groups) == 1:
        t, rs = next(iter(groups.items()))
        return rs, t, [f"dark frames at {t} s used for base frames at {exposure} s"]
    have = ", ".join(str(t) for t in groups)
    raise CcdError(where, f"no dark frames at exposure {exposure} s (have {have} s); pass "
                          "dark_exposure=")


@dataclass(frozen=True, eq=False)
class FlatDark:
    """The dark image DL_0 chosen for a flat group (:func:`session_dark`).

    ``source`` is what :func:`flat_field` takes (dark records, or the moments of the model or
    of zero); ``kind`` is ``None`` (dark frames averaged), ``"model"`` or ``"zero"``."""

    source: Any
    exposure: float | None
    notes: tuple[str, ...]
    frames: tuple[str, ...]
    kind: str | None = None
    model: DarkModel | None = None

    def text(self) -> str:
        """DL_0 in a few words, for the held-out check's record."""
        at = "" if self.exposure is None else f" at {self.exposure:g} s"
        return {"zero": "zero dark (DL_0 = 0)", "model": f"dark model o + c·t{at}"}.get(
            self.kind or "", f"{len(self.frames)} dark frames{at}")


def session_dark(session: Any, groups: Mapping, key: tuple, *, setting: str | None = None,
                 gain: float | None = None, dark_exposure: float | None = None,
                 dark_model: DarkModel | None = None) -> FlatDark:
    """DL_0 for the flat group ``key`` of ``groups``: darks matched to its temperature.

    * no dark frames at all (and no ``dark_model``): de Lasarte's zero-dark form, DL_0 = 0
      (noted);
    * darks (biases included) within the temperature tolerance of the flats
      (:func:`ccdcore.dark.model.select_darks`) with two or more frames at the flats' exposure
      (or at ``dark_exposure`` when named), or at one exposure only: their average, as eqs.
      1-4 take DL_0 (:func:`_pick_darks`);
    * otherwise, matched darks at two or more exposures: the dark model o + c·t
      (:mod:`ccdcore.dark.model`) at the flats' exposure (``dark_model`` when given and at the
      flats' temperature, else fitted; a session without darks uses a given model as it
      is), not the
      darks of the nearest exposure; ``dark_exposure`` then serves the dark reference only
      (noted when it differs).

    Raises
    ------
    CcdError
        Darks but none within the tolerance of the flats' temperature (naming both).
    """
    recs = list(session.select("dark", setting=setting, gain=gain))
    base_recs = groups[key]
    t_base = key[1]
    if not recs and dark_model is None:
        shape = session.header(base_recs[0]).shape
        zero = MomentsResult(mean=np.zeros(shape), var=np.zeros(shape), n=0)
        return FlatDark(zero, None, ("no dark frames: the flat field is made in de Lasarte's "
                                     "zero-dark form, DL_0 = 0 (eqs. 1-4 with a zero dark "
                                     "image; the camera's black level, if any, stays in the "
                                     "frames and in G)",), (), "zero")
    temps = [r.temperature for r in base_recs if r.temperature is not None]
    target = float(np.median(temps)) if temps else None
    if recs:                  # a model given is reused only where the darks call for one
        given = dark_model if dark_model is not None and (
            target is None or dark_model.temperature is None
            or abs(dark_model.temperature - target) <= TEMPERATURE_TOLERANCE) else None
        dark_model = None
        matched, other, target, notes = select_darks(session, recs, target)
        if not matched:
            raise CcdError(str(session.root), f"no dark frames within {TEMPERATURE_TOLERANCE:g} "
                                              f"°C of the flats' {target:g} °C (the dark frames "
                                              "are at "
                                              f"{temperatures_text([r.temperature for r in other])}"
                                              "): the flat field needs darks at its temperature")
        exps = {r.exposure for r in matched}
        want = t_base if dark_exposure is None else dark_exposure
        exact = [r for r in matched if want is not None and r.exposure is not None
                 and math.isclose(r.exposure, want, rel_tol=1e-6)]
        if len(exps) >= 2 and None not in exps and len(exact) < 2:
            dark_model = given or session_dark_model(session, temperature=target,
                                                     setting=setting, gain=gain)
        else:
            picked, t_used, more = _pick_darks(session, setting, gain,
                                               t_base if dark_exposure is None else dark_exposure,
                                               matched)
            if dark_exposure is not None and t_base is not None and t_used is not None and \
                    not math.isclose(t_used, t_base, rel_tol=1e-6):
                more = [*more, f"DL_0 from the {len(picked)} dark frames at {t_used:g} s, as "
                               f"named (the base flats are at {t_base:g} s)"]
            return FlatDark(picked, t_used, tuple(notes + more),
                            tuple(r.relpath for r in picked))
    t = 0.0 if t_base is None else float(t_base)
    notes = [f"DL_0 from the dark model o + c·t of {dark_model.n} biases and darks (exposures "
             + ", ".join(f"{x:g}" for x in dark_model.exposures) + " s"
             + ("" if dark_model.temperature is None else f", {dark_model.temperature:g} °C")
             + f") at the flats' {t:g} s", *dark_model.notes]
    if t_base is None:
        notes.append("the flats have no exposure time: the model's offset (t = 0) is DL_0")
    if dark_exposure is not None and not math.isclose(dark_exposure, t, rel_tol=1e-6):
        notes.append(f"dark_exposure {dark_exposure:g} s is not used for the flat field: its "
                     f"DL_0 is the model's dark at the flats' own {t:g} s")
    return FlatDark(dark_model.moments_at(t), t, tuple(notes), dark_model.frames, "model",
                    dark_model)


def flat_field_from_session(session: Any, *, setting: str | None = None,
                            base: tuple[Any, Any] | str = "auto", gain: float | None = None,
                            dark_exposure: float | None = None, reducer: Reducer | None = None,
                            dark_model: DarkModel | None = None, held_out: bool = False,
                            **options: Any) -> FlatField:
    """:func:`flat_field` from a session's frames.

    Parameters
    ----------
    session : Session
        A :class:`~ccdcore.session.Session` with dark and flat frames.  Only darks within the
        temperature tolerance of the base flats are used; with no dark frames at all, DL_0 = 0
        (de Lasarte's zero-dark form, noted; ``dark_source = "zero"``).
    setting : str or None, optional
        Offset setting (manifest key ``setting``); ``None`` takes the first of
        several (noted) or all frames when none is named.
    base : tuple or str, optional
        ``(level, exposure)`` of the flat group used as the base image, or ``"auto"``: the
        recommendation of :func:`recommend_base`.
    gain : float or None, optional
        Gain setting, when the session has several.
    dark_exposure : float or None, optional
        Exposure of the dark frames; default the base frames' exposure (a single dark exposure,
        or darks without exposure, are used as they are, noted).  With darks at two or more
        exposures the dark model serves instead, at the base exposure (:func:`session_dark`).
    reducer : Reducer or None, optional
        Runs the averages (see :func:`flat_field`; bit-identical maps on a cluster).
    dark_model : DarkModel or None, optional
        A :class:`~ccdcore.dark.model.DarkModel` to take DL_0 from (at the base exposure);
        default: fitted when the matched darks have two or more exposures.
    held_out : bool, optional
        Also make the held-out check (:func:`held_out_check`) into ``FlatField.held_out``.
    **options
        ``k``, ``noise_limit``, ``window`` of :func:`flat_field`.

    Returns
    -------
    FlatField
        G, O (eqs. 3–4), their flags and what they were made from; with ``held_out``, the check.

    Raises
    ------
    CcdError
        No flat frames; a bad ``base``; the errors of :func:`session_dark` and :func:`flat_field`.

    Examples
    --------
    >>> import tempfile
    >>> from ccdcore.simulate import simulate
    >>> tmp = tempfile.TemporaryDirectory()
    >>> from ccdcore.session import open_session
    >>> _ = simulate("delasarte07", tmp.name, seed=1, size=(64, 48))
    >>> flat = flat_field_from_session(open_session(tmp.name))
    >>> [c.name for c in flat.channels], flat.shape
    (['R', 'G', 'B'], (48, 64, 3))
    >>> tmp.cleanup()
    """
    setting, notes = session.resolve_setting(setting)
    groups = session.flat_groups(setting=setting, gain=gain)
    if not groups:
        raise CcdError(str(session.root), "no flat frames (role = 'flat')"
                       + (f" with setting = {setting!r}" if setting else ""))
    if isinstance(base, str):
        if base != "auto":
            raise CcdError("base", f"give (level, exposure) or 'auto', got {base!r}")
        rec = recommend_base(session, setting=setting, gain=gain)
        key = rec.key
        notes.append(f"base image: {rec.reason}")
    else:
        key = tuple(base)
        if key not in groups:
            raise CcdError("base", f"no flat group (level, exposure) = {key}; have "
                                   f"{', '.join(map(str, groups))}")
    dark = session_dark(session, groups, key, setting=setting, gain=gain,
                        dark_exposure=dark_exposure, dark_model=dark_model)
    # the held-out check first: its own fit's moments are freed before the maps' fit holds
    # theirs (the other way round a DSLR's ten 10 MP flats peaked at 3.0 GB, now 2.25)
    check = held_out_check(session, groups, key, dark, **options) if held_out else None
    ff = flat_field(dark.source, groups[key], layout=session.camera.layout, reducer=reducer,
                    session=session, **options)
    return replace(ff, base_key=key, setting=setting, dark_exposure=dark.exposure,
                   notes=tuple(notes) + dark.notes + ff.notes, dark_source=dark.kind,
                   dark_model=dark.model, base_frames=tuple(r.relpath for r in groups[key]),
                   dark_frames=dark.frames, held_out=check)


def held_out_check(session: Any, groups: Mapping, key: tuple, dark: FlatDark, *,
                   factor: float = HELD_OUT_FACTOR, hold_out: int = -1,
                   **options: Any) -> HeldOutCheck | None:
    """The held-out check (:mod:`ccdcore.flatfield.check`) of flat group ``key``: G, O from all its
    flats but one (``hold_out``, an index into the group's frames, default the last), that
    one corrected and its SNUP compared with the noise floor; ``None`` with fewer than three
    flats (two to fit with a variance, one to hold out).  ``dark`` is the :class:`FlatDark`
    of the group (the same DL_0 as the maps').  Streamed: the fitted flats are read once more,
    the held-out one once."""
    recs = list(groups[key])
    if len(recs) < 3:
        return None
    held = recs.pop(hold_out)
    scaled = PixelMoments()
    lay = check_layout(session.header(held).shape, session.camera.layout, held.relpath)
    ref: dict[str, float] = {}

    def frames() -> Iterable[tuple[Any, NDArray]]:
        # each fitted flat also goes, scaled to the first one's level per channel, into the
        # moments whose variance is the floor's temporal noise (a lamp's frame-to-frame level
        # change is not pixel noise)
        for rec, frame in session.iter_frames(recs):
            a = np.array(frame, dtype=np.float64)
            for c, idx in channel_slices(a.shape, lay).items():
                m = float(a[idx].mean())
                a[idx] *= ref.setdefault(c, m) / m if m else 1.0
            scaled.add(a, name=rec.relpath)
            yield rec, frame
    src = dark.source
    if not isinstance(src, (MomentsResult, DarkReference)):
        src = session.iter_frames(list(src))          # dark records: read them
    ff = flat_field(src, frames(), layout=session.camera.layout, **options)
    group = group_words(key)
    return held_out_figures(ff, session.read(held), n_fit=len(recs), held_out=held.relpath,
                            group=group, dark=dark.text(), factor=factor,
                            temporal_var=scaled.result().var)


# --------------------------------------------------------------------------------------------
# base image (item 5)
# --------------------------------------------------------------------------------------------
_BASE_RULE = ("among the flat groups inside the linear range (linear in every channel, pixels "
              "between the range's low end and the lowest non-linear level), the one whose mean "
              "level is closest to the middle of the range (mean over channels of |mean − mid| "
              "/ width); within 0.05 range widths of the closest, the group with most frames")


def recommend_base(session: Any, *, setting: str | None = None, gain: float | None = None,
                   linearity_result: Linearity | None = None, **linearity_options: Any
                   ) -> BaseRecommendation:
    """The base correction image inside the linear response range (the paper's optimum).

    de Lasarte et al. obtain the best correction "by using an image with a mean digital level
    placed in the linear response range of the camera as the base correction image".  The exact
    rule (``BaseRecommendation.rule``): among groups inside the linear range
    (:meth:`ccdcore.flatfield.uniformity.Linearity.in_range`), the one whose mean level is closest
    to the middle of [lo, upper] of each channel (far from the noisy, possibly clipped bottom and
    from the knee at the top); among groups within 0.05 range widths of the closest, the one with
    the most frames (least noise in DL_B).  When no group is inside (too few exposures to fit), the
    unsaturated group closest to the middle of [dark level, full scale] (noted in the reason).

    Parameters
    ----------
    session
        Session with flat (and dark) frames.
    setting, gain
        As in :func:`flat_field_from_session`.
    linearity_result
        A :func:`ccdcore.flatfield.uniformity.linearity` result to reuse; else computed.
    **linearity_options
        ``tolerance`` ... of :func:`~ccdcore.flatfield.uniformity.linearity`.
    """
    setting, _ = session.resolve_setting(setting)
    lin = linearity_result or linearity(session, setting=setting, gain=gain, **linearity_options)
    groups = session.flat_groups(setting=setting, gain=gain)
    rows = []
    for key, recs in groups.items():
        pts = lin.group_points(key, gain)
        inside = lin.in_range(key, gain)
        dist = []
        for p in pts:
            r = lin.ranges.get(p.channel)
            lo = r[0] if r else p.dark_dn
            up = lin.upper.get(p.channel, math.inf)
            if not math.isfinite(up):
                up = r[1] if r else p.mean_dn
            width = max(up - lo, 1e-9)
            dist.append(abs(p.mean_dn - 0.5 * (lo + up)) / width)
        rows.append({"key": key, "n_frames": len(recs),
                     "mean_dn": {p.channel: p.mean_dn for p in pts},
                     "p_high_dn": {p.channel: p.p_high_dn for p in pts},
                     "saturated": any(p.saturated_fraction > 0 for p in pts),
                     "in_linear_range": inside, "distance": float(np.mean(dist)) if dist else None})
    pool = [r for r in rows if r["in_linear_range"]]
    where = (f"inside the linear range (tolerance {100 * lin.tolerance:g} %), closest to its "
             "middle")
    if not pool:
        pool = [r for r in rows if not r["saturated"]] or rows
        where = (f"no group could be shown linear (tolerance {100 * lin.tolerance:g} %): the "
                 "unsaturated group closest to mid-scale")
    best = min(r["distance"] for r in pool)
    near = [r for r in pool if r["distance"] <= best + 0.05]
    pick = min(near, key=lambda r: (-r["n_frames"], r["distance"]))
    means = ", ".join(f"{c} {m:.1f}" for c, m in pick["mean_dn"].items())
    reason = (f"flat group {group_words(pick['key'])}: mean {means} DN, {where}, with "
              f"{pick['n_frames']} frames")
    for r in rows:
        if not r["in_linear_range"]:
            r["distance"] = None
    return BaseRecommendation(key=pick["key"], reason=reason, rule=_BASE_RULE,
                              candidates=tuple(rows), linearity=lin)


def _base_maps(session, setting, gain, keys, groups, **options
               ) -> dict[tuple, tuple[NDArray[np.float32], NDArray[np.float32], str, float]]:
    """``(G, O, layout, mean base level over channels)`` of each candidate base, its DL_0
    chosen by :func:`session_dark` (darks at its exposure and temperature, the dark model or
    zero).  Only the float32 G and O are kept (not the float64 means and variances of DL_0 and
    DL_B), and one dark average at a time: candidates are taken by dark exposure."""
    darks = {key: session_dark(session, groups, key, setting=setting, gain=gain)
             for key in keys}
    out = {}
    dark_id, dark = object(), None
    for key in sorted(keys, key=lambda k: sort_key(darks[k].exposure)):
        fd = darks[key]
        ident = (fd.kind, fd.exposure, fd.frames)
        if ident != dark_id:
            dark_id = ident
            dark = fd.source if fd.kind is not None else \
                _moments(STREAMED, session.iter_frames(fd.source), "dark", None, None)[0]
        ff = flat_field(dark, session.iter_frames(groups[key]), layout=session.camera.layout,
                        **options)
        out[key] = (ff.G, ff.O, ff.layout, float(np.mean([c.base_level for c in ff.channels])))
    return {key: out[key] for key in keys}


def base_image_study(session: Any, *, setting: str | None = None, gain: float | None = None,
                     candidates: Iterable[tuple] | None = None,
                     images: Iterable[tuple] | None = None, nearest: bool = False,
                     roi: Sequence[int] | None = None, **options: Any) -> BaseStudy:
    """SNUP after correction for every image group and every candidate base image.

    Each frame of each image group is corrected with the G, O of each candidate base (darks at
    the base's exposure) and its SNUP taken per channel; rows give the mean and standard
    deviation over the group's frames, plus the uncorrected SNUP (``base = None``).  Memory: the
    float32 G and O of every candidate (pass ``candidates`` to limit them); each frame is read
    once for the maps and once for the study.

    Parameters
    ----------
    session, setting, gain
        As in :func:`flat_field_from_session`.
    candidates, images
        Flat groups ``(level, exposure)`` used as bases / corrected; default all.
    nearest
        Instead of every base, correct each image group with the candidate whose mean level
        (mean over channels) is nearest its own, the image group itself excluded.
    roi
        ``(x, y, w, h)`` for the SNUP.
    **options
        Passed to :func:`flat_field`.
    """
    setting, _ = session.resolve_setting(setting)
    groups = session.flat_groups(setting=setting, gain=gain)
    cands = list(groups) if candidates is None else [tuple(c) for c in candidates]
    imgs = list(groups) if images is None else [tuple(c) for c in images]
    for key in cands + imgs:
        if key not in groups:
            raise CcdError("base_image_study", f"no flat group (level, exposure) = {key}")
    ffs = _base_maps(session, setting, gain, cands, groups, **options)
    level = {key: m[3] for key, m in ffs.items()}
    rows = []
    for img in imgs:
        bases = list(ffs)
        if nearest:
            others = [b for b in bases if b != img]
            if not others:
                raise CcdError("nearest", "needs at least one candidate base besides the image")
            bases = []
        per: dict[Any, dict[str, list[float]]] = {}
        img_level = []
        for rec, frame in session.iter_frames(groups[img]):
            raw = snup(frame, roi=roi, layout=session.camera.layout, where=rec.relpath)
            img_level.append(np.mean([c.mean for c in raw.channels]))
            for c in raw.channels:
                per.setdefault(None, {}).setdefault(c.name, []).append(c.snup)
            if nearest and not bases:
                bases = [min(others, key=lambda b: abs(level[b] - img_level[0]))]
            for b in bases:
                G, O, layout, _ = ffs[b]
                r = snup(correct(frame, G, O, where=rec.relpath), roi=roi, layout=layout,
                         where=rec.relpath)
                for c in r.channels:
                    per.setdefault(b, {}).setdefault(c.name, []).append(c.snup)
        for b, chans in per.items():
            for c, vals in chans.items():
                rows.append({"base": b, "image": img, "channel": c,
                             "snup_mean": float(np.mean(vals)),
                             "snup_std": float(np.std(vals, ddof=1)) if len(vals) > 1 else None,
                             "n": len(vals), "image_mean_dn": float(np.mean(img_level)),
                             "base_mean_dn": None if b is None else level[b],
                             "self": b == img})
    try:
        rec_key = recommend_base(session, setting=setting, gain=gain).key
    except CcdError:
        rec_key = None
    return BaseStudy(rows=tuple(rows), setting=setting, nearest=nearest, recommended=rec_key)


# --------------------------------------------------------------------------------------------
# zero dark image and settings (item 6)
# --------------------------------------------------------------------------------------------
def zero_dark(darks: Any, *, layout: str | None = None, limit: float = ZERO_LIMIT) -> ZeroDark:
    """Detect a dark image clipped at zero: the fraction of zero values per channel.

    Parameters
    ----------
    darks
        One dark frame or mean dark image (array), an iterable of dark frames (streamed), a
        :class:`~ccdcore.stats.MomentsResult`, a :class:`~ccdcore.dark.frame.DarkReference` or a
        :class:`FlatField` (its dark frames' counts; for averages, a pixel counts as zero when
        its mean is 0, i.e. every frame read 0).
    layout
        Frame layout (``None``: mono or rgb from the shape).
    limit
        Fraction above which the dark image counts as clipped (default 1 %).
    """
    counts: dict[str, list[int]] = {}

    def add(arr: NDArray, lay: str | None) -> str:
        lay = check_layout(arr.shape, lay)
        for c, v in split_channels(arr, lay).items():
            cnt = counts.setdefault(c, [0, 0])
            cnt[0] += int(np.count_nonzero(v == 0))
            cnt[1] += v.size
        return lay

    if isinstance(darks, FlatField):
        fr = {c.name: c.dark_zero_fraction for c in darks.channels}
        if None in fr.values():
            add(darks.dark.mean, darks.layout)
            fr = {c: z / n for c, (z, n) in counts.items()}
    else:
        if isinstance(darks, (MomentsResult, DarkReference)):
            darks = darks.mean if isinstance(darks, MomentsResult) else darks.mean_map
        if isinstance(darks, np.ndarray) and (darks.ndim == 2 or (darks.ndim == 3 and
                                                                  darks.shape[2] == 3)):
            add(darks, layout)
        else:
            for _, arr in named_frames(darks, "dark"):
                layout = add(arr, layout)
        if not counts:
            raise CcdError("dark", "no dark frames")
        fr = {c: z / n for c, (z, n) in counts.items()}
    worst = max(fr.values())
    clipped = worst > limit
    return ZeroDark(fractions=fr, limit=float(limit), clipped=clipped,
                    warning=ZeroDark.warning_text(worst) if clipped else None)


def compare_dark_settings(session: Any, *, settings: Sequence[str] | None = None,
                          gain: float | None = None, roi: Sequence[int] | None = None,
                          **options: Any) -> SettingsComparison:
    """SNUP after correction for each captured offset setting (ZDI / NZDI, Table 2).

    For each setting: G, O from its recommended base and its darks; every frame of the flat
    groups inside the linear range of *every* compared setting (bases excluded, so each setting is
    judged on the same radiance levels and exposures) corrected; mean and std of their SNUP per
    channel.
    """
    names = list(settings) if settings is not None else list(session.settings())
    if not names:
        raise CcdError(str(session.root), "the session names no offset settings "
                                          "(manifest key setting)")
    rows, zd = [], {}
    recs_by = {s: recommend_base(session, setting=s, gain=gain) for s in names}
    common = None   # the same image groups for every setting: inside each linear range
    for s, rec in recs_by.items():
        keys = {k for k in session.flat_groups(setting=s, gain=gain)
                if rec.linearity.in_range(k, gain) and k != rec.key}
        common = keys if common is None else common & keys
    for s in names:
        rec = recs_by[s]
        ff = flat_field_from_session(session, setting=s, gain=gain, base=rec.key, **options)
        zd[s] = zero_dark(ff)
        per: dict[str, list[float]] = {}
        for key, recs in session.flat_groups(setting=s, gain=gain).items():
            if key not in common:
                continue
            for r, frame in session.iter_frames(recs):
                for c in snup(ff.correct(frame, where=r.relpath), roi=roi, layout=ff.layout,
                              where=r.relpath).channels:
                    per.setdefault(c.name, []).append(c.snup)
        for c, vals in per.items():
            rows.append({"setting": s, "channel": c, "snup_mean": float(np.mean(vals)),
                         "snup_std": float(np.std(vals, ddof=1)) if len(vals) > 1 else None,
                         "n": len(vals), "zero_fraction": zd[s].fractions.get(c),
                         "base": rec.key})
    return SettingsComparison(rows=tuple(rows), zero_dark=zd)


# --------------------------------------------------------------------------------------------
# K̂ against G (item 7)
# --------------------------------------------------------------------------------------------
_K_CONCLUSION = ("K̂ (Healey & Kondepudy) is normalised by its local window mean, so it corrects "
                 "the pixel-to-pixel gain (PRNU) but leaves the low-frequency vignetting in the "
                 "image; G (de Lasarte) is normalised by the global mean and corrects both. On a "
                 "uniform field G reaches the shot-noise limit while K̂ leaves about the SNUP of "
                 "the vignetting; their high-pass residuals against the true flat field are "
                 "comparable.")


def _residuals(est: NDArray, truth: NDArray, window: int) -> tuple[float, float]:
    r = est / truth
    r = r / r.mean()
    hf = r / uniform_filter(r, window, mode="reflect")
    return 100.0 * float(r.std()), 100.0 * float(hf.std())


def compare_with_k_map(session: Any, *, setting: str | None = None, gain: float | None = None,
                       evaluate: tuple[Any, Any] | None = None, truth_flatfield: ArrayLike | None
                       = None, window: int = 9, p: float = 1.5) -> KMapComparison:
    """Correct the same uniform-field frames with K̂ (eq. 51 of Healey & Kondepudy) and with G/O.

    Parameters
    ----------
    session
        A uniform-field session (dark and flat frames at several levels/exposures).
    setting, gain
        As in :func:`flat_field_from_session`.
    evaluate
        The held-out flat group ``(level, exposure)`` whose frames are corrected; default the
        linear-range group, other than the recommended base, with the most frames and then the
        highest level.  Neither estimate sees these frames.
    truth_flatfield
        The true flat field F (mean 1 per channel, e.g. the simulator's ``truth/flatfield.exr``)
        for the residuals; optional.
    window, p
        K̂'s local window m and rejection width (:func:`ccdcore.fixedpattern.fixed_pattern_map`).

    Returns
    -------
    KMapComparison
        G/O uses the recommended base; K̂ uses every other linear-range group as a configuration
        (its average minus the dark at its exposure).
    """
    from ..fixedpattern import correct as k_correct
    from ..fixedpattern import fixed_pattern_map

    setting, _ = session.resolve_setting(setting)
    rec = recommend_base(session, setting=setting, gain=gain)
    groups = session.flat_groups(setting=setting, gain=gain)
    inside = [k for k in groups if rec.linearity.in_range(k, gain)]
    if evaluate is None:
        others = [k for k in inside if k != rec.key]
        if not others:
            raise CcdError(str(session.root), "needs a second flat group inside the linear "
                                              "range to evaluate on")
        evaluate = max(others, key=lambda k: (len(groups[k]), k[0] or 0, k[1] or 0))
    evaluate = tuple(evaluate)
    if evaluate == rec.key:
        raise CcdError("evaluate", "the evaluation group must not be the G/O base image")
    configs = [k for k in inside if k != evaluate]
    if len(configs) < 2:
        raise CcdError(str(session.root), "K̂ needs at least 2 flat groups (configurations) "
                                          "inside the linear range besides the evaluated one")
    ff = flat_field_from_session(session, setting=setting, gain=gain, base=rec.key)
    lay = ff.layout
    dark_cache: dict[Any, NDArray] = {}

    def dark_at(key):
        fd = session_dark(session, groups, key, setting=setting, gain=gain)
        ident = (fd.kind, fd.exposure, fd.frames)
        if ident not in dark_cache:
            dark_cache[ident] = fd.source.mean if fd.kind is not None else _moments(
                STREAMED, session.iter_frames(fd.source), "dark", None, None)[0].mean
        return dark_cache[ident]

    e = {key: _moments(STREAMED, session.iter_frames(groups[key]), "flat", None, None)[0].mean
         - dark_at(key) for key in configs}
    K = np.empty(ff.shape, np.float64)
    for c, idx in channel_slices(ff.shape, lay).items():
        fp = fixed_pattern_map({key: np.ascontiguousarray(v[idx]) for key, v in e.items()},
                               np.zeros(np.shape(K[idx])), window=window, p=p)
        K[idx] = fp.K
    d_eval = dark_at(evaluate)
    acc = PixelMoments()
    sn: dict[str, dict[str, list[float]]] = {}
    for r, frame in session.iter_frames(groups[evaluate]):
        acc.add(frame, name=r.relpath)
        kc = np.empty(ff.shape, np.float64)
        for c, idx in channel_slices(ff.shape, lay).items():
            # eq. 51, plus the channel's mean dark level as eq. 2 keeps it: same SNUP mean
            kc[idx] = k_correct(np.asarray(frame)[idx], d_eval[idx], K[idx]) + d_eval[idx].mean()
        for label, img in (("raw", frame), ("G", ff.correct(frame)), ("K", kc)):
            for ch in snup(img, layout=lay, where=r.relpath).channels:
                sn.setdefault(ch.name, {}).setdefault(label, []).append(ch.snup)
    var = split_channels(acc.result().var, lay) if acc.n > 1 else None
    mean = split_channels(acc.result().mean, lay)
    F = None if truth_flatfield is None else np.asarray(truth_flatfield, dtype=np.float64)
    if F is not None and F.shape != ff.shape:
        raise CcdError("truth_flatfield", f"shape {F.shape} differs from the frames' {ff.shape}")
    rows = []
    for c, idx in channel_slices(ff.shape, lay).items():
        row: dict[str, Any] = {"channel": c}
        for label in ("raw", "G", "K"):
            row[f"snup_{label}"] = float(np.mean(sn[c][label]))
        row["snup_limit"] = (100.0 * math.sqrt(float(np.mean(var[c]))) / float(mean[c].mean())
                             if var is not None else None)
        if F is not None:
            Fg = 1.0 / ff.G[idx].astype(np.float64)
            row["residual_G_pct"], row["residual_hf_G_pct"] = _residuals(Fg, F[idx], window)
            row["residual_K_pct"], row["residual_hf_K_pct"] = _residuals(K[idx], F[idx], window)
        rows.append(row)
    return KMapComparison(rows=tuple(rows), evaluate=evaluate, base=rec.key,
                          configurations=tuple(configs), window=window, conclusion=_K_CONCLUSION)
