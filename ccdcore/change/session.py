"""Change detection on a session (Tsin, Ramesh & Kanade 2001, sec. 5): the reference and
target frames of a session to radiance with its sigma, then :func:`ccdcore.change.detector.detect`.

Two brackets are merged with the response (eqs. 9, 18, 19: :func:`bracket_change`); a role of
single frames, or of frames at one exposure, goes to :func:`ccdcore.change.frames.frames_change`
(its response and noise sources). :func:`session_change` chooses.

Public objects
--------------
session_change(session, options=None, ...)
    Sec. 5 on a session's ``reference`` and ``target`` frames: ``(ChangeResult, ChangeInputs)``.
bracket_change(session, options=None, ...)
    The same on two brackets.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .detector import ChangeInputs, ChangeOptions, ChangeResult, detect
from .frames import frames_change, role_kind
from ..errors import CcdError
from ..progress import Progress, within
from ..reduce import STREAMED, Reducer
from ..response.brackets import bracket_records

__all__ = ["session_change", "bracket_change"]


def session_change(session: Any, options: ChangeOptions | None = None, *,
                   calib: str | Path | None = None, bloom_radius: int | None = None,
                   progress: Progress | None = None, reducer: Reducer | None = None,
                   band_rows: int | None = None, method: str = "auto",
                   white_balance: bool = False, exposures: str = "auto",
                   response: str = "auto") -> tuple[ChangeResult, ChangeInputs]:
    """Sec. 5 on a session's ``reference`` and ``target`` brackets.

    When either role is a frame set (one frame, or frames at one exposure or without any:
    :func:`ccdcore.change.frames.role_kind`) or ``response`` is ``"srgb"``, this is
    :func:`ccdcore.change.frames.frames_change` (its response and noise sources; ``options``
    default to a ``min_region`` of a 3 x 3 block there).

    The response (g and the noise terms) comes from ``calib`` (a calibration product) or is
    estimated from the reference bracket (sec. 3.2); both brackets are merged with it at their
    nominal times (eqs. 9, 18, 19).

    With a Dask reducer (:class:`ccdcore.distributed.client.DaskReducer`) both merges run band
    by band, the workers reading the frames (:func:`ccdcore.response.hdr.merge_bracket`;
    ``band_rows`` sets the band height): the radiance and sigma maps are bit-identical to the
    streamed ones, hence so is everything after.  The shapes and sample types are then checked
    first, from the headers.  What stays in this process: the response estimated from the
    reference bracket without ``calib`` (it reads the reference frames here, as the streamed
    path does: the pixel traces of every pixel), and the fit of M and d² (:func:`detect`),
    which need the whole radiance maps -- the streamed path holds them too.

    Parameters
    ----------
    session : Session
        An open session with ``reference`` and ``target`` frames.
    options : ChangeOptions or None, optional
        The settings of :func:`detect`; default ``ChangeOptions()`` (frame sets: see above).
    calib : str or Path or None, optional
        A calibration product (its folder or its ``calibration.json``) whose response (g and the
        noise terms) is used; default: the response estimated from the reference bracket.
    bloom_radius : int or None, optional
        Radius (pixels) around a saturated pixel whose codes are dropped; ``None``:
        :data:`ccdcore.response.names.DEFAULT_BLOOM_RADIUS`.
    progress : Progress or None, optional
        A :class:`ccdcore.progress.Progress`: the response estimate takes its first half
        (without ``calib``), :func:`detect` the rest.
    reducer : Reducer or None, optional
        Runs both merges (:mod:`ccdcore.reduce`; default streamed here; a Dask reducer: see
        above).
    band_rows : int or None, optional
        The height of the bands of rows a Dask reducer's merges run in.
    method : str, optional
        :func:`ccdcore.response.methods.response_of`'s, for the reference bracket's response
        (without ``calib``).
    white_balance : bool, optional
        :func:`ccdcore.response.methods.response_of`'s, for the reference bracket's response
        (without ``calib``).
    exposures : str, optional
        :func:`ccdcore.response.methods.response_of`'s, for the reference bracket's response
        (without ``calib``); each bracket is merged at its own exposures when ``exposures``
        asks for them or the images disagree with the listed ones: the reference's from its
        response, the other brackets' estimated with the curve
        (:func:`ccdcore.response.exposures.exposures_with_curves`, on frames read here even when
        a cluster's workers merge them).
    response : str, optional
        ``"auto"``, or ``"srgb"``: the sRGB curve whatever the session holds (frame sets).

    Returns
    -------
    tuple of ChangeResult and ChangeInputs
        The result (:func:`detect`'s, its ``sources`` the response and the noise in words) and
        its :class:`ChangeInputs` (both radiance maps with their sigma, the channels, the
        response's source, the frames).

    Raises
    ------
    CcdError
        No ``reference`` or ``target`` frames, or a role whose exposures are mixed; a session
        error touching them; frames of another shape or sample type than the reference's; a
        response (``calib``'s or estimated) with another number of codes than the camera's; an
        unknown ``response``, ``method`` or ``exposures``; a ``calib`` that cannot be loaded or
        has no response; the errors of :func:`detect`.

    Examples
    --------
    >>> import tempfile
    >>> from ccdcore.simulate import simulate
    >>> tmp = tempfile.TemporaryDirectory()
    >>> from ccdcore.session import open_session
    >>> _ = simulate("change", tmp.name, seed=1, size=(64, 48))
    >>> result, inputs = session_change(open_session(tmp.name))
    >>> inputs.channels, result.dof          # eq. 20's 3 x 3 colour transform: 3 degrees of freedom
    (('R', 'G', 'B'), 3)
    >>> tmp.cleanup()
    """
    kinds = {role: role_kind(bracket_records(session, None, role=role))
             for role in ("reference", "target")}
    if response != "auto" or "frames" in kinds.values():
        return frames_change(session, options, calib=calib, response=response,
                             bloom_radius=bloom_radius, progress=progress, method=method,
                             white_balance=white_balance, exposures=exposures, kinds=kinds)
    return bracket_change(session, options, calib=calib, bloom_radius=bloom_radius,
                           progress=progress, reducer=reducer, band_rows=band_rows,
                           method=method, white_balance=white_balance, exposures=exposures)


def bracket_change(session: Any, options: ChangeOptions | None = None, *,
                   calib: str | Path | None = None, bloom_radius: int | None = None,
                   progress: Progress | None = None, reducer: Reducer | None = None,
                   band_rows: int | None = None, method: str = "auto",
                   white_balance: bool = False, exposures: str = "auto"
                   ) -> tuple[ChangeResult, ChangeInputs]:
    """:func:`session_change` on two brackets (its docstring)."""
    from ..response.brackets import DEFAULT_BLOOM_RADIUS, load_bracket
    from ..response.exposures import exposures_with_curves
    from ..response.hdr import ResponseModel, merge_bracket
    from ..response.methods import response_of

    radius = DEFAULT_BLOOM_RADIUS if bloom_radius is None else int(bloom_radius)
    recs = {role: bracket_records(session, None, role=role) for role in ("reference", "target")}
    kinds = {role: "bracket" for role in recs}
    first = {role: recs[role][0].relpath for role in recs}
    red = reducer or STREAMED
    # the frames the merge takes as read (None: its workers read them); else their headers
    frames: dict[str, Any] = {role: red.preload(session, recs[role]) for role in recs}
    described = {role: ([(f.shape, f.dtype) for f in frames[role]] if frames[role] is not None
                        else [(tuple(h.shape), np.dtype(h.dtype)) for h in
                              (session.header(r) for r in recs[role])]) for role in recs}
    (ref_shape, ref_dtype), (tgt_shape, tgt_dtype) = (described["reference"][0],
                                                      described["target"][0])
    if ref_shape != tgt_shape:
        raise CcdError(first["target"], f"shape {tgt_shape} differs from the reference "
                                        f"bracket's {ref_shape} ({first['reference']}): the "
                                        "same camera and framing are needed")
    if ref_dtype != tgt_dtype:
        raise CcdError(first["target"], f"sample type {tgt_dtype} differs from the reference "
                                        f"bracket's {ref_dtype}: another camera or bit depth?")
    for role in recs:
        shape0, dtype0 = described[role][0]
        for r, (shape, dtype) in zip(recs[role], described[role]):
            if shape != shape0 or dtype != dtype0:
                raise CcdError(r.relpath, f"shape {shape} {dtype} differs from its "
                                          f"bracket's first frame {shape0} {dtype0}")
    layout = session.camera.layout

    res = None
    if calib is not None:
        from ..product.make import load_product

        models = load_product(calib).response_models(calib)
        source = f"response of {calib}"
        noise = f"the noise terms of {calib} (eq. 7), through the merge (eq. 19)"
    else:
        ref_frames = frames["reference"]
        if ref_frames is None:
            ref_frames = [session.read(r) for r in recs["reference"]]
        brackets = load_bracket(session, None, role="reference", bloom_radius=radius,
                                frames=ref_frames)
        del ref_frames
        res = response_of(brackets, method, bloom_radius=radius, white_balance=white_balance,
                          exposures=exposures, progress=within(progress, 0.0, 0.5))
        models = res.models()
        source = f"response estimated from the reference bracket ({res.method})"
        noise = "the noise terms estimated with the response (eq. 7), through the merge (eq. 19)"
    levels = {m.levels for m in models.values()}
    bits = session.camera.bits
    if bits is not None and levels != {2 ** int(bits)}:
        raise CcdError(calib or first["reference"], f"the response has {sorted(levels)} codes, "
                                                    f"the camera {2 ** int(bits)}")
    out = {}
    own: dict[str, Any] = {}
    for role in ("reference", "target"):
        t = np.asarray([r.exposure for r in recs[role]], np.float64)
        if role == "reference" and res is not None:
            own[role] = res.exposures
            if res.exposures is not None and res.exposures.used == "estimated":
                t = np.asarray(res.exposures.estimated, np.float64)   # the bracket's own
        elif exposures != "listed":
            # a bracket the curve was not fitted to: its own exposures with that curve (read
            # here when a cluster's workers merge it, as the reference is for its response).
            # A bracket the estimate cannot use keeps its listed times: the merge and the
            # detector say what is wrong with it
            read = frames[role] if frames[role] is not None else \
                [session.read(r) for r in recs[role]]
            try:
                br = load_bracket(session, None, role=role, bloom_radius=radius, frames=read)
                t, own[role] = exposures_with_curves(br, models, t, exposures)
            except CcdError:
                own[role] = None
            del read
        else:
            own[role] = None
        ms = {ch: ResponseModel(np.asarray(m.g, np.float64), t, np.zeros(t.size),
                                float(m.sigma_s), float(m.sigma_c1), float(m.sigma_c2))
              for ch, m in models.items()}
        out[role] = merge_bracket(recs[role], ms, layout=layout, bloom_radius=radius,
                                  frames=frames[role], reducer=red, session=session,
                                  band_rows=band_rows)
        frames[role] = None
    inputs = ChangeInputs(out["reference"].radiance, out["reference"].sigma,
                          out["target"].radiance, out["target"].sigma,
                          tuple(out["reference"].channels), source,
                          tuple(r.relpath for role in recs for r in recs[role]), res, own,
                          noise=noise, kinds=kinds)
    result = detect(inputs.E_ref, inputs.sigma_ref, inputs.E_tgt, inputs.sigma_tgt,
                    options, names=(first["reference"], first["target"]),
                    progress=within(progress, 0.5 if calib is None else 0.1, 1.0))
    result.sources = {"response": source, "noise": noise}
    return result, inputs
