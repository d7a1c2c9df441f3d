"""Change detection between single frames or a few frames of each role: Tsin, Ramesh & Kanade
(2001), sec. 5, without exposure brackets.

Most users have two frames, not two brackets: a reference and a target of one frame each (8-bit
video frames, no exposure metadata), or a few frames each. The frames of one role at a single
exposure (or without any exposure) are a *frame set*; :func:`frames_change` turns each role into
the radiance Ê and its sigma that :func:`ccdcore.change.detector.detect` takes (eq. 20 and the
steps of
:mod:`ccdcore.change.detector`), and says where the response and the noise came from.

The response g (code -> relative exposure), in this order:

1. a calibration product's (``calib``);
2. estimated (sec. 3.2) from an exposure bracket of the same camera in the session: the frames of
   role ``bracket``, or the reference or target when that role is itself a bracket;
3. an assumption the result names: the sRGB standard curve (IEC 61966-2-1), the usual tone curve
   of video and consumer cameras. Under a global change of light a wrong curve bends eq. 20's
   straight line; the threshold's calibration on the background (step 3 of
   :mod:`ccdcore.change.detector`) absorbs what remains, and ``d2_scale`` shows how much.

The radiance of a frame set is the mean over its frames of g(z) / a (a the exposure when every
frame has one, else 1: the transform M absorbs any common gain), eq. 9 with equal weights.

The noise (the per-pixel sigma of that mean), in this order:

1. the frames' own spread, where a role has two frames or more at the same exposure: the per-pixel
   variance s² of g(z) over the frames (N - 1 degrees of freedom), shrunk towards eq. 7's model
   σ² = σ_s² g + σ_c1² + g'(z)² σ_c2² fitted to those variances (:func:`fit_noise_terms`): the
   posterior of a scaled-inverse-χ² prior worth ``PRIOR_FRAMES`` frames,
   ((N - 1) s² + ν₀ σ²) / (N - 1 + ν₀). The spread of 2-5 frames alone would make d² heavy-tailed
   (a Student t with 1-4 degrees of freedom); the model alone would miss a pixel that flickers (a
   screen, a leaf). The sigma of the mean is that over √N (eq. 19 with equal weights). A role of
   one frame takes the model fitted to the other role's frames (the same camera);
2. the noise terms of eq. 7 of the calibration product or of the bracket's response estimate;
3. an assumption the result names (:data:`ASSUMED_NOISE`): eq. 7 with σ_s = 0.01 (units √g),
   σ_c1 = 0, σ_c2 = levels / 256 codes, about 1-1.5 DN at mid-grey on the sRGB curve, what 8-bit
   video cameras show. A wrong overall level is absorbed by the threshold's calibration.

A code at either end of the range (0 or levels - 1) in any frame of a set leaves the pixel
without a radiance (label 254). A frame set with its exposures mixed (some frames with one, some
without; or several exposures, some repeated) is neither a frame set nor a bracket: a clear error
names the file. Single 8-bit frames give one per-pixel test each at the requested false-alarm
rate, scattered over the frame; :data:`FRAME_MIN_REGION` (``ChangeOptions.min_region``) drops the
changed regions smaller than a 3 x 3 block, the default for frame sets (docs/change.md).

Public objects
--------------
frames_change(session, options, ...)
    Sec. 5 on a session whose reference or target is a frame set.
role_kind(records)
    ``"bracket"`` or ``"frames"`` for one role's records, or a :class:`CcdError`.
session_kinds(session)
    Both roles' kinds, after the session's own validation (missing exposures allowed).
srgb_inverse(levels)
    The sRGB curve's inverse, g(z) on 0..1.
fit_noise_terms(gbar, var, slope, dof)
    Eq. 7's terms fitted to per-pixel variances of repeated frames.
ASSUMED_NOISE, FRAME_MIN_REGION, PRIOR_FRAMES, RESPONSES
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy import optimize, stats

from .detector import ChangeInputs, ChangeOptions, ChangeResult, detect
from ..errors import CcdError, SessionError
from ..progress import Progress, within

__all__ = ["frames_change", "role_kind", "session_kinds", "srgb_inverse", "fit_noise_terms",
           "ASSUMED_NOISE", "FRAME_MIN_REGION", "PRIOR_FRAMES", "RESPONSES"]

#: eq. 7's noise terms assumed without frames to measure them: σ_s (√g units), σ_c1 (g units),
#: σ_c2 (codes, per 256 levels)
ASSUMED_NOISE = {"sigma_s": 0.01, "sigma_c1": 0.0, "sigma_c2": 1.0}
#: smallest changed region kept for frame sets (pixels, 8-connected): a 3 x 3 block
FRAME_MIN_REGION = 9
#: frames' worth of the noise model in the per-pixel variance (the prior's degrees of freedom)
PRIOR_FRAMES = 8
#: the ``response`` choices: ``auto`` (product, bracket, else sRGB) or ``srgb`` (always)
RESPONSES = ("auto", "srgb")
ROLES = ("reference", "target")


def srgb_inverse(levels: int) -> NDArray[np.float64]:
    """The inverse of the sRGB curve (IEC 61966-2-1) on ``levels`` codes: g(z) in 0..1."""
    u = np.arange(int(levels), dtype=np.float64) / (int(levels) - 1)
    return np.where(u <= 0.04045, u / 12.92, ((u + 0.055) / 1.055) ** 2.4)


def role_kind(records: Sequence[Any]) -> str:
    """``"frames"`` when every frame has the same exposure or none has one, ``"bracket"`` when
    every frame has its own exposure (two or more); else a :class:`CcdError` naming a file."""
    if not records:
        raise CcdError("session", "no frames")
    exp = [r.exposure for r in records]
    known = [e for e in exp if e is not None]
    if not known:
        return "frames"
    if len(known) < len(exp):
        bad = next(r for r in records if r.exposure is None)
        raise CcdError(bad.relpath, f"no exposure, while {len(known)} other {records[0].role} "
                                    "frame(s) have one: give every frame of the role an "
                                    "exposure (a bracket) or none (a frame set)")
    distinct = sorted(set(float(e) for e in known))
    if len(distinct) == 1:
        return "frames"
    if len(distinct) < len(known):
        seen: set[float] = set()
        for r in records:
            if float(r.exposure) in seen:
                raise CcdError(r.relpath, f"its exposure {r.exposure:g} s repeats, while the "
                                          f"{records[0].role} frames have {len(distinct)} "
                                          "exposures: neither a bracket (one frame per "
                                          "exposure) nor a frame set (one exposure)")
            seen.add(float(r.exposure))
    return "bracket"


def session_kinds(session: Any, roles: Sequence[str] | None = None) -> dict[str, str]:
    """The kind of the reference and target (:func:`role_kind`), once the session has no error
    touching ``roles`` (every error for ``None``) but the missing exposures of reference or
    target frames (a frame set needs none): else a :class:`SessionError` as
    :meth:`ccdcore.session.Session.raise_if_invalid` raises it."""
    from ..response.brackets import bracket_records
    from ..session import ProblemCode

    errors = [p for p in session.errors_for(roles) if not (
        p.code == ProblemCode.MISSING_EXPOSURE and set(p.roles) <= set(ROLES) and p.roles)]
    if errors:
        n = len(errors) - 1
        more = f" (and {n} more problem{'s' if n > 1 else ''})" if n else ""
        raise SessionError(errors[0].where, errors[0].message + more, problems=tuple(errors))
    return {role: role_kind(bracket_records(session, role=role)) for role in ROLES}


def fit_noise_terms(gbar: NDArray, var: NDArray, slope: NDArray, dof: int,
                    bins: int = 32) -> tuple[float, float, float]:
    """Eq. 7's σ_s, σ_c1, σ_c2 from per-pixel variances ``var`` of g over repeated frames
    (``dof`` = N - 1 each) at mean ``gbar``, ``slope`` = g'(z̄).

    The pixels are binned by ``gbar`` (equal counts); each bin's median variance over the median
    of χ²_dof / dof is its robust variance (a moving object in a few pixels does not inflate it);
    σ_s², σ_c1², σ_c2² are the non-negative least squares fit of var = σ_s² g + σ_c1² +
    g'² σ_c2², each bin's row divided by its variance (relative errors)."""
    ok = np.isfinite(gbar) & np.isfinite(var) & np.isfinite(slope)
    gbar, var, slope = gbar[ok], var[ok], slope[ok]
    if gbar.size < 50:
        raise CcdError("noise", f"{gbar.size} pixels with a code in every frame: too few to "
                                "measure the noise from the frames' spread")
    order = np.argsort(gbar)
    parts = np.array_split(order, min(bins, max(1, gbar.size // 25)))
    corr = float(stats.chi2.median(dof)) / dof
    rows, rhs = [], []
    for idx in parts:
        v = float(np.median(var[idx])) / corr
        if not v > 0:
            continue
        rows.append(np.array([np.median(gbar[idx]), 1.0, np.median(slope[idx] ** 2)]) / v)
        rhs.append(1.0)
    if len(rows) < 3:
        raise CcdError("noise", "the frames' spread is zero almost everywhere: identical "
                                "frames (copies) cannot measure the noise")
    A = np.asarray(rows)
    scale = np.maximum(A.max(axis=0), 1e-300)
    x, _ = optimize.nnls(A / scale, np.asarray(rhs))
    x = x / scale
    return float(np.sqrt(x[0])), float(np.sqrt(x[1])), float(np.sqrt(x[2]))


def _model_var(g: NDArray, slope: NDArray, terms: tuple[float, float, float]) -> NDArray:
    s_s, s_c1, s_c2 = terms
    return s_s ** 2 * np.maximum(g, 0.0) + s_c1 ** 2 + (slope * s_c2) ** 2


# -- the response -----------------------------------------------------------------------------
def _terms(model: Any) -> tuple[float, float, float]:
    return (float(getattr(model, "sigma_s", 0.0) or 0.0), float(getattr(model, "sigma_c1", 0.0)
            or 0.0), float(getattr(model, "sigma_c2", 0.0) or 0.0))


def _assumed_terms(levels: int) -> tuple[float, float, float]:
    return (ASSUMED_NOISE["sigma_s"], ASSUMED_NOISE["sigma_c1"],
            ASSUMED_NOISE["sigma_c2"] * levels / 256.0)


def _response(session: Any, kinds: dict[str, str], channels: Sequence[str], levels: int,
              calib: str | Path | None, response: str, method: str, opts: dict[str, Any],
              radius: int, progress: Progress | None) -> tuple[dict, str, Any, str | None]:
    """Channel -> (g, noise terms), the response's source in words, the response estimate
    (or ``None``) and what the noise terms are (``None``: none came with the response)."""
    if response not in RESPONSES:
        raise CcdError("response", f"unknown response '{response}'; choose one of "
                                   f"{', '.join(RESPONSES)}")
    if calib is not None and response == "auto":
        from ..product.make import load_product

        models = load_product(calib).response_models(calib)
        return ({c: (np.asarray(m.g, np.float64), _terms(m)) for c, m in models.items()},
                f"response of the calibration product {calib}", None,
                f"the noise terms of {calib} (eq. 7)")
    role = next((r for r in ("bracket", *ROLES) if (r == "bracket" and session.by_role(
        "bracket")) or kinds.get(r) == "bracket"), None) if response == "auto" else None
    if role is not None:
        from ..response.brackets import load_bracket
        from ..response.methods import response_of

        br = load_bracket(session, None, role=role, bloom_radius=radius)
        res = response_of(br, method, bloom_radius=radius, progress=within(progress, 0.0, 0.5),
                          **opts)
        models = res.models()
        return ({c: (np.asarray(m.g, np.float64), _terms(m)) for c, m in models.items()},
                f"response estimated from the session's {role} bracket ({len(res.files)} "
                f"exposures, {res.method})", res, "the noise terms of that response estimate "
                                                  "(eq. 7)")
    why = ("as asked (--response srgb)" if response == "srgb" else
           "no calibration product (--calib) and no exposure bracket in the session")
    g = srgb_inverse(levels)
    return ({c: (g, _assumed_terms(levels)) for c in channels},
            f"assumed: the sRGB standard curve (IEC 61966-2-1), not measured: {why}", None, None)


# -- each role's radiance and sigma -----------------------------------------------------------
def _checked_frames(session: Any, recs: dict[str, list]) -> tuple[dict[str, list], np.dtype]:
    """Every frame of both roles, read; one shape and sample type, else an error naming it."""
    frames = {role: [session.read(r) for r in recs[role]] for role in ROLES}
    first = recs["reference"][0]
    shape0, dtype0 = frames["reference"][0].shape, frames["reference"][0].dtype
    for role in ROLES:
        for r, f in zip(recs[role], frames[role]):
            if f.shape != shape0:
                raise CcdError(r.relpath, f"shape {f.shape} differs from the reference frame "
                                          f"{first.relpath}'s {shape0}: the same camera and "
                                          "framing are needed")
            if f.dtype != dtype0:
                raise CcdError(r.relpath, f"sample type {f.dtype} differs from the reference "
                                          f"frame {first.relpath}'s {dtype0}: another camera "
                                          "or bit depth?")
    if not np.issubdtype(dtype0, np.integer):
        raise CcdError(first.relpath, f"expected the camera's integer codes, got {dtype0}")
    return frames, dtype0


def _frame_set(planes: list[NDArray], g: NDArray, a: float) -> dict[str, NDArray]:
    """The mean of g(z)/a over the frames, their spread, the mean code and the clipped pixels
    (code 0 or levels - 1 in any frame) of one channel."""
    L = g.size
    z = np.stack(planes).astype(np.intp)
    if int(z.max()) >= L:
        raise CcdError("frames", f"codes up to {int(z.max())} exceed the response's {L} levels")
    G = g[z]
    n = z.shape[0]
    out = {"E": G.mean(axis=0) / a, "zbar": z.mean(axis=0), "clipped": np.any(
        (z == 0) | (z == L - 1), axis=0), "var": G.var(axis=0, ddof=1) if n > 1 else None}
    out["slope"] = np.interp(out["zbar"], np.arange(L), np.gradient(g))
    out["gbar"] = G.mean(axis=0)
    return out


def _measured_terms(sets: dict[str, dict], n: int) -> tuple[float, float, float]:
    """Eq. 7's terms from the spread of ``n`` frames (every channel's unclipped pixels)."""
    take = [(s["gbar"][~s["clipped"]], s["var"][~s["clipped"]], s["slope"][~s["clipped"]])
            for s in sets.values()]
    gb, var, sl = (np.concatenate([t[k] for t in take]) for k in range(3))
    return fit_noise_terms(gb, var, sl, n - 1)


def _describe(terms: tuple[float, float, float]) -> str:
    return (f"σ_s = {terms[0]:.3g} √g, σ_c1 = {terms[1]:.3g}, σ_c2 = {terms[2]:.3g} code(s)")


def _role_maps(session: Any, kinds: dict[str, str], recs: dict[str, list],
               frames: dict[str, list], resp: dict, resp_noise: str | None, levels: int,
               radius: int) -> tuple[dict[str, tuple[NDArray, NDArray]], str]:
    """Per role (E, sigma) as (H, W, C), and the noise's source in words."""
    from ..channels import split_channels
    from ..response.hdr import ResponseModel, merge

    layout = session.camera.layout
    chans = list(resp)
    sets: dict[str, dict[str, dict]] = {}
    measured: dict[str, tuple[float, float, float]] = {}
    for role in ROLES:
        if kinds[role] != "frames":
            continue
        exp = recs[role][0].exposure
        a = float(exp) if exp is not None else 1.0
        split = [split_channels(f, layout) for f in frames[role]]
        sets[role] = {c: _frame_set([s[c] for s in split], resp[c][0], a) for c in chans}
        for c in chans:
            sets[role][c]["a"] = a
        if len(frames[role]) > 1:
            measured[role] = _measured_terms(sets[role], len(frames[role]))
    out: dict[str, tuple[NDArray, NDArray]] = {}
    words = []
    for role in ROLES:
        n = len(frames[role])
        if kinds[role] == "bracket":
            t = np.asarray([r.exposure for r in recs[role]], np.float64)
            ms = {c: ResponseModel(resp[c][0], t, np.zeros(t.size), *(resp[c][1] if resp_noise
                                   else _assumed_terms(levels))) for c in chans}
            hdr = merge(frames[role], ms, layout=layout, bloom_radius=radius)
            E, s = hdr.radiance, hdr.sigma
            if E.ndim == 2:
                E, s = E[..., None], s[..., None]
            words.append(f"{role}: a bracket of {n} exposures merged (eqs. 9, 18, 19) with "
                         + (resp_noise or "assumed noise terms (" + _describe(
                             _assumed_terms(levels)) + ")"))
            out[role] = (E, s)
            continue
        other = next((r for r in ROLES if r != role and r in measured), None)
        if role in measured:
            terms = measured[role]
            words.append(f"{role}: measured from the spread of its {n} frames (eq. 7 fitted: "
                         f"{_describe(terms)}; per pixel with a prior worth {PRIOR_FRAMES} "
                         "frames)")
        elif other is not None:
            terms = measured[other]
            words.append(f"{role}: 1 frame, the noise measured on the {other} frames (the same "
                         "camera)")
        elif resp_noise is not None:
            terms = resp[chans[0]][1]
            words.append(f"{role}: {n} frame{'s' if n > 1 else ''}, {resp_noise}")
        else:
            terms = _assumed_terms(levels)
            words.append(f"{role}: assumed ({n} frame, nothing to measure it): eq. 7 with "
                         f"{_describe(terms)}, about 1-1.5 DN at mid-grey")
        Es, ss = [], []
        for c in chans:
            st = sets[role][c]
            tc = terms if (role in measured or other is not None or resp_noise is None) \
                else resp[c][1]
            var = _model_var(st["gbar"], st["slope"], tc)
            if st["var"] is not None:
                var = ((n - 1) * st["var"] + PRIOR_FRAMES * var) / (n - 1 + PRIOR_FRAMES)
            sig = np.sqrt(var / n) / st["a"]
            Es.append(st["E"])
            ss.append(np.where(st["clipped"], np.inf, sig))
        out[role] = (np.stack(Es, axis=-1), np.stack(ss, axis=-1))
        usable = np.isfinite(out[role][1]).all(axis=-1)
        if not usable.any():
            raise CcdError(recs[role][0].relpath, f"no usable pixel in the {role} frame"
                                                  f"{'s' if n > 1 else ''}: every pixel has a "
                                                  f"code 0 or {levels - 1} (clipped) in a "
                                                  "channel")
    return out, "; ".join(words)


def frames_change(session: Any, options: ChangeOptions | None = None, *,
                  calib: str | Path | None = None, response: str = "auto",
                  bloom_radius: int | None = None, progress: Progress | None = None,
                  method: str = "auto", white_balance: bool = False, exposures: str = "auto",
                  kinds: dict[str, str] | None = None) -> tuple[ChangeResult, ChangeInputs]:
    """Sec. 5 on a session whose reference or target (or both) is a frame set.

    The response and the noise come from the sources of the module docstring, in that order;
    ``response="srgb"`` takes the sRGB curve whatever the session holds. ``options`` default to
    ``ChangeOptions(min_region=FRAME_MIN_REGION)``. ``method``, ``white_balance``,
    ``exposures`` are :func:`ccdcore.response.methods.response_of`'s for a bracket's response.
    Returns the result (its ``sources``: the response and the noise in words) and the
    :class:`ChangeInputs` (``source`` the response's, ``noise`` the noise's, ``kinds``).

    Raises :class:`CcdError` naming the file: a frame of another shape or sample type, a role
    whose exposures are mixed (:func:`role_kind`), a frame set without a usable pixel.
    """
    from ..response.brackets import DEFAULT_BLOOM_RADIUS, bracket_records

    radius = DEFAULT_BLOOM_RADIUS if bloom_radius is None else int(bloom_radius)
    kinds = kinds or session_kinds(session, ROLES)
    recs = {role: bracket_records(session, role=role) for role in ROLES}
    frames, dtype = _checked_frames(session, recs)
    bits = session.camera.bits
    levels = 2 ** int(bits) if bits is not None else (256 if dtype.itemsize == 1 else 65536)
    from ..channels import channel_names, check_layout

    chans = channel_names(check_layout(frames["reference"][0].shape, session.camera.layout,
                                       recs["reference"][0].relpath))
    resp, source, res, resp_noise = _response(
        session, kinds, chans, levels, calib, response, method,
        {"white_balance": white_balance, "exposures": exposures}, radius, progress)
    sizes = {np.asarray(g).size for g, _ in resp.values()}
    if sizes != {levels}:
        raise CcdError(str(calib or recs["reference"][0].relpath),
                       f"the response has {sorted(sizes)} codes, the camera {levels}")
    maps, noise = _role_maps(session, kinds, recs, frames, resp, resp_noise, levels, radius)
    del frames
    opts = options or ChangeOptions(min_region=FRAME_MIN_REGION)
    first = (recs["reference"][0].relpath, recs["target"][0].relpath)
    result = detect(maps["reference"][0], maps["reference"][1], maps["target"][0],
                    maps["target"][1], opts, names=first,
                    progress=within(progress, 0.5 if res is not None else 0.1, 1.0))
    result.sources = {"response": source, "noise": noise}
    inputs = ChangeInputs(maps["reference"][0], maps["reference"][1], maps["target"][0],
                          maps["target"][1], tuple(chans), source,
                          tuple(r.relpath for role in ROLES for r in recs[role]), res, {},
                          noise=noise, kinds=dict(kinds))
    return result, inputs
