"""A session's bracket from its files to a response that holds on handheld and moving brackets:
the frames registered (:mod:`ccdcore.response.align`), the pixels off the bracket's own
code-to-code mapping left out (:func:`ccdcore.response.moving.suspect_moving`), the response
fitted (sec. 3.2 or the method asked, :mod:`ccdcore.response.methods`) and the pixels whose
exposures disagree beyond its noise model found (:func:`ccdcore.response.moving.find_moving`).

Every verb and page that fits a session's bracket goes through :func:`fit_bracket`, so the
registration and the moving pixels are part of the one verdict record
(:class:`ccdcore.response.verdict.ResponseVerdict`'s ``registration`` and ``moving``) that
``response``, ``hdr``, ``calibrate``, the report and the app show.

Public objects
--------------
BracketFit
    The result: the response, the frames as fitted (aligned), their records, the registration,
    the pixels without data in some aligned frame, the moving pixels.
fit_bracket(session, stack, ...)
    The steps above.
session_response(session, method, ...)
    :func:`fit_bracket`'s response of a session (a path or an open session).
merge_fit(fit)
    The HDR merge of a :class:`BracketFit`'s own frames with its response, the moving pixels
    from one exposure.
prepare_bracket(session, stack, ...), finish_fit(result, prepared)
    The steps before and after the fit, for a caller that fits several methods on one
    bracket (the app's Response & HDR page).
register_frames(frames, names, align)
    The registration step alone: the frames aligned, the :class:`Registration` and the pixels
    where an aligned frame has no data, the frames kept.
Registration
    The alignment with its description.
ALIGN_CHOICES
    ``auto`` (register, resample only frames that moved), ``off``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from ..errors import CcdError
from ..progress import Progress
from .brackets import DEFAULT_BLOOM_RADIUS, DEFAULT_BORDER, bracket_records, load_bracket

__all__ = ["BracketFit", "PreparedBracket", "Registration", "session_response", "merge_fit", "fit_bracket", "prepare_bracket", "finish_fit",
           "register_frames", "ALIGN_CHOICES"]

ALIGN_CHOICES = ("auto", "off")
#: a frame that cannot be registered is kept as it is when no other frame moved by more than
#: this (pixels: a tripod's drift), else left out
TRIPOD_DRIFT = 1.0


@dataclass(frozen=True, eq=False)
class BracketFit:
    """A bracket's response with the frames it was fitted on: ``result`` (a
    :class:`ccdcore.response.methods.ResponseResult` whose verdict carries the registration and
    the moving pixels), ``frames`` (aligned, bracket order, the frames left out dropped),
    ``records`` (theirs), ``alignment`` (``None`` when not tried), ``no_data`` (pixels where an
    aligned frame has no data; ``None``: none), ``moving``
    (:class:`ccdcore.response.moving.MovingPixels`)."""

    result: Any
    frames: list[NDArray]
    records: list[Any]
    alignment: Any
    no_data: NDArray[np.bool_] | None
    moving: Any


def register_frames(frames: Sequence[NDArray], names: Sequence[str], align: str = "auto"
                    ) -> tuple[list[NDArray], Any, NDArray[np.bool_] | None, list[int]]:
    """The frames aligned to the bracket's middle frame (``align="auto"``): the frames (the
    same arrays where nothing moved), the registration (a :class:`Registration`; ``None`` with
    ``"off"`` or a single frame), the pixels where an aligned frame has no data (``None``:
    none) and the indices of the frames kept.

    A frame that cannot be registered (too little structure: the shortest exposure of a night
    scene) is left out when the others moved; when none moved by more than
    :data:`TRIPOD_DRIFT` (a tripod bracket) it is kept as it is, and the registration says
    so."""
    if align not in ALIGN_CHOICES:
        raise CcdError("align", f"expected one of {', '.join(ALIGN_CHOICES)}, got {align!r}")
    frames = list(frames)
    keep = list(range(len(frames)))
    if align == "off" or len(frames) < 2:
        return frames, None, None, keep
    from .align import TILE_MIN, apply_alignment, estimate_alignment

    h, w = np.asarray(frames[0]).shape[:2]
    if min(h, w) < 2 * TILE_MIN:
        return frames, Registration(None, f"frames not registered: {w} x {h} pixels is too "
                                          f"small (at least {2 * TILE_MIN} a side)"), None, keep
    alignment = estimate_alignment(frames, list(names))
    registered = [k for k, s in enumerate(alignment.shifts) if s.registered]
    if len(registered) < 2:
        # nothing to register against (a reference without structure, a saturated bracket):
        # the frames as they are, said so; the fit says what else is wrong
        return frames, Registration(alignment, "frames not registered, taken as they are: "
                                    + "; ".join(sh.reason for sh in alignment.shifts
                                                if not sh.registered)), None, keep
    unregistered = [k for k, sh in enumerate(alignment.shifts) if not sh.registered]
    drift = max(_displacement(sh, (h, w)) for sh in alignment.shifts if sh.registered)
    if not alignment.any_applied:
        text = ("frames registered (tripod): every shift within its error or 0.25 px, no frame "
                "resampled")
    else:
        text = alignment.describe()
    if unregistered and drift <= TRIPOD_DRIFT:
        # a tripod's drift: a frame too plain to register (the shortest of a night scene,
        # which holds its lights) is worth more kept as it is than left out
        text = text.split("; 1 left out")[0].split(f"; {len(unregistered)} left out")[0]
        text += (f"; kept as {'they are' if len(unregistered) > 1 else 'it is'}, the others "
                 f"having moved by at most {drift:.2f} px: "
                 + "; ".join(alignment.shifts[k].reason for k in unregistered))
        registered = keep
    if not alignment.any_applied:
        return [frames[k] for k in registered], Registration(alignment, text), None, registered
    aligned, valid = apply_alignment(frames, alignment)
    no_data = ~np.asarray(valid, bool)
    return ([aligned[k] for k in registered], Registration(alignment, text),
            no_data if no_data.any() else None, registered)


def _displacement(shift: Any, shape: tuple[int, int]) -> float:
    """The largest displacement (pixels) of a frame's registration: its shift plus what its
    rotation moves the corners by."""
    h, w = shape
    reach = abs(np.radians(shift.rotation)) * 0.5 * float(np.hypot(h - 1, w - 1))
    return float(np.hypot(shift.dx, shift.dy) + reach)


@dataclass(frozen=True, eq=False)
class Registration:
    """The bracket's registration: the :class:`ccdcore.response.align.Alignment` (``None``:
    frames too small to register) and its description in the result's words (``text``: what was aligned, by how much, what was left
    out or kept as it is)."""

    alignment: Any
    text: str

    def describe(self) -> str:
        return self.text

    def to_dict(self) -> dict[str, Any]:
        base = {} if self.alignment is None else self.alignment.to_dict()
        return {**base, "describe": self.text}


@dataclass(frozen=True, eq=False)
class PreparedBracket:
    """A bracket ready for any method's fit: ``brackets`` (channel ->
    :class:`ccdcore.response.brackets.BracketData`, the suspects and the pixels without data
    left out), the registered ``frames`` and their ``records``, the ``alignment``, ``no_data``
    and ``suspects`` (``None``: not looked for)."""

    brackets: dict[str, Any]
    frames: list[NDArray]
    records: list[Any]
    alignment: Any
    no_data: NDArray[np.bool_] | None
    suspects: NDArray[np.bool_] | None
    layout: str | None
    bloom_radius: int


def prepare_bracket(session: Any, stack: Any = None, *, frames: Sequence[NDArray] | None = None,
                    align: str = "auto", moving: bool = True,
                    bloom_radius: int = DEFAULT_BLOOM_RADIUS, border: int = DEFAULT_BORDER
                    ) -> PreparedBracket:
    """The bracket ``stack`` of ``session`` read (or ``frames``, in
    :func:`ccdcore.response.brackets.bracket_records` order), registered (``align``) and, with
    ``moving``, its pixels off its own code-to-code mapping left out of the traces."""
    from .moving import suspect_moving

    records = bracket_records(session, stack)
    if hasattr(session, "raise_if_invalid"):
        session.raise_if_invalid(roles=("bracket",))
    if frames is None:
        frames = [session.read(r) for r in records]
    frames, alignment, no_data, keep = register_frames(frames, [r.relpath for r in records],
                                                       align)
    records = [records[k] for k in keep]
    layout = session.camera.layout
    exclude, suspects = no_data, None
    if moving and session.camera.bits is not None:
        suspects = suspect_moving(frames, 2 ** int(session.camera.bits), layout=layout)
        exclude = suspects if exclude is None else (exclude | suspects)
    brackets = load_bracket(session, stack, bloom_radius=bloom_radius, border=border,
                            frames=frames, records=records, exclude=exclude)
    return PreparedBracket(brackets, frames, records, alignment, no_data, suspects, layout,
                           bloom_radius)


def finish_fit(res: Any, prepared: PreparedBracket, moving: bool = True) -> BracketFit:
    """``res`` (a response fitted on ``prepared.brackets``) with the moving pixels found by its
    noise model, its verdict carrying the registration and the moving pixels."""
    from .moving import find_moving

    found = None
    if moving:
        found = replace(find_moving(prepared.frames, res.models(), layout=prepared.layout,
                                    names=[r.relpath for r in prepared.records],
                                    bloom_radius=prepared.bloom_radius),
                        excluded=None if prepared.suspects is None
                        else int(np.count_nonzero(prepared.suspects)))
    if res.verdict is not None:
        al = prepared.alignment
        res = replace(res, verdict=replace(
            res.verdict, registration="" if al is None else al.describe(),
            moving="" if found is None else found.describe()))
    return BracketFit(res, prepared.frames, prepared.records, prepared.alignment,
                      prepared.no_data, found)


def fit_bracket(session: Any, stack: Any = None, *, method: str = "auto",
                frames: Sequence[NDArray] | None = None, align: str = "auto",
                moving: bool = True, bloom_radius: int = DEFAULT_BLOOM_RADIUS,
                border: int = DEFAULT_BORDER, progress: Progress | None = None,
                white_balance: bool = False, exposures: str = "auto") -> BracketFit:
    """The response of the bracket ``stack`` of ``session`` (the first when ``None``), its
    frames registered and its moving pixels left out (module notes):
    :func:`prepare_bracket`, the fit, :func:`finish_fit`.

    ``frames``: the frames already read, in :func:`ccdcore.response.brackets.bracket_records`
    order. ``align``: :data:`ALIGN_CHOICES`. ``moving``: leave the suspects out of the fit and
    find the pixels whose exposures disagree. The other options are
    :func:`ccdcore.response.methods.response_of`'s.
    """
    from .methods import response_of

    prepared = prepare_bracket(session, stack, frames=frames, align=align, moving=moving,
                               bloom_radius=bloom_radius, border=border)
    res = response_of(prepared.brackets, method, progress=progress, bloom_radius=bloom_radius,
                      white_balance=white_balance, exposures=exposures)
    return finish_fit(res, prepared, moving)


def session_response(session: Any, method: str = "auto", *, stack: Any = None,
                     bloom_radius: int = DEFAULT_BLOOM_RADIUS, border: int = DEFAULT_BORDER,
                     progress: Progress | None = None, white_balance: bool = False,
                     exposures: str = "auto", align: str = "auto", moving: bool = True) -> Any:
    """The response of a session's bracket ``stack``: :func:`fit_bracket`'s.

    The frames are registered (``align``) and the moving pixels left out (``moving``), both
    said in the result's verdict.

    Parameters
    ----------
    session : Session or str or PathLike
        A path (anything :func:`~ccdcore.session.open_session` opens) or an open session.
    method : str, optional
        A key of :data:`ccdcore.response.methods.METHODS`, or ``"auto"``: sec. 3.2 unless
        Debevec & Malik's curve predicts the bracket clearly better
        (:func:`ccdcore.response.methods.response_of`).
    stack : hashable or None, optional
        The stack id of the bracket (its frames' ``stack``); ``None``: the first bracket.
    bloom_radius : int, optional
        Radius (pixels) around a saturated pixel whose codes are dropped (sec. 2: blooming).
    border : int, optional
        Width (pixels) of the frame boundary dropped (sec. 3.2, step 1).
    progress : Progress or None, optional
        A :class:`ccdcore.progress.Progress` that follows the fit's steps.
    white_balance : bool, optional
        Also estimate the gains a_k of the channels (the ``tsin`` method only).
    exposures : str, optional
        One of :data:`ccdcore.response.names.EXPOSURE_MODES`: the bracket's own exposures
        (:func:`ccdcore.response.exposures.estimate_exposures`) are estimated unless
        ``"listed"``, and taken when the images disagree with the listed ones (``"auto"``) or
        always (``"estimated"``).
    align : str, optional
        One of :data:`ALIGN_CHOICES`: ``"auto"`` registers the frames to the bracket's middle
        one (resampling only the frames that moved), ``"off"`` takes them as they are.
    moving : bool, optional
        Leave the pixels off the bracket's own code-to-code mapping out of the fit and find the
        pixels whose exposures disagree beyond the noise model.

    Returns
    -------
    ccdcore.response.methods.ResponseResult
        One response per channel (the inverse response g with its band and the noise terms),
        the method kept and why, the exposures, the agreement with the bracket's own images and
        the verdict, which carries the registration and the moving pixels.

    Raises
    ------
    CcdError
        A path that :func:`~ccdcore.session.open_session` refuses; no ``bracket`` frames, or no
        bracket ``stack``; a session error touching the bracket; an unknown ``method``,
        ``exposures`` or ``align``; ``white_balance`` with a method that takes the exposures as
        exact; a ``bloom_radius`` out of range; a bracket of fewer than two exposures or with a
        missing, zero or repeated exposure time, or one the method cannot fit.

    Examples
    --------
    >>> import tempfile
    >>> from ccdcore.simulate import simulate
    >>> tmp = tempfile.TemporaryDirectory()
    >>> from ccdcore.session import open_session
    >>> _ = simulate("tsin01", tmp.name, seed=1, size=(64, 48))
    >>> result = session_response(open_session(tmp.name))
    >>> result.channels, result.verdict.status
    (('L',), 'trusted')
    >>> tmp.cleanup()
    """
    from ..session import open_session

    if not hasattr(session, "bracket_stacks"):
        session = open_session(session)
    return fit_bracket(session, stack, method=method, align=align, moving=moving,
                       bloom_radius=bloom_radius, border=border, progress=progress,
                       white_balance=white_balance, exposures=exposures).result


def merge_fit(fit: BracketFit, layout: str | None = None) -> Any:
    """The HDR radiance (:class:`ccdcore.response.hdr.HdrResult`) of ``fit``'s registered
    frames with its response (eqs. 9, 18, 19), the moving pixels merged from one exposure
    (:func:`ccdcore.response.moving.merge_moving`)."""
    from .hdr_merge import merge
    from .moving import merge_moving

    res = fit.result
    models = res.models()
    out = merge(fit.frames, models, layout=layout, bloom_radius=res.bloom_radius)
    if fit.moving is None:
        return out
    return merge_moving(out, fit.frames, models, fit.moving, bloom_radius=res.bloom_radius)
