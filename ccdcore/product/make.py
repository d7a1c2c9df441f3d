"""Calibration products: every estimate a session allows, saved as a folder that loads back exactly.

The product as a file (:class:`CalibrationProduct`, :func:`load_product`) lives in
:mod:`ccdcore.product.file`; this module makes products and applies them, and re-exports it.

Public objects
--------------
:class:`CalibrationProduct`
    Float32 maps (dark reference, its variance, K̂, n'_1, hot/dead flags ...) plus the summary
    record of each estimate (:class:`ProductEstimates`: noise model, dark reference, fixed
    pattern, acquisition plan, scene variation ...), the EMVA 1288 figures when the session has
    photon counts, and the :class:`Provenance` (which step, which parameters, which session:
    its content hash, and when).
:func:`calibrate`
    Runs every estimate the session's frames allow and returns the product.
:class:`MapName`
    The names of the maps (a ``str`` enum; its home is :mod:`ccdcore.map_names`).
:func:`load_product`, :meth:`CalibrationProduct.save`
    The folder format: ``calibration.json`` + ``maps/<name>.exr`` (float32, bit-exact round trip;
    a map whose name is not a :class:`MapName` is refused).
:func:`apply_product`
    Corrects images: D_C = (D − D̂_D)/K̂ (eq. 51 of Healey & Kondepudy 1994), or D − D̂_D when the
    product has no K̂.

The folder is written atomically: into a temporary sibling folder first, then renamed over the
target (an existing product is replaced only once the new one is complete).
"""
from __future__ import annotations

import contextlib
import datetime
import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Mapping

import numpy as np

from .. import __version__
from ..channels import Layout
from ..dark.frame import DarkReference
from ..emva.datasheet import EmvaFigures
from ..errors import CcdError
from ..fixedpattern import CorrectionCheck, FixedPattern
from ..flatfield.fit import FlatField
from ..io.frames import (FITS_EXTENSIONS, check_outputs, output_set, read_frame, read_header,
                         write_image)
from ..map_names import MapName
from ..noise import PhotonTransfer
from ..planning import AcquisitionPlan
from ..progress import Progress, Steps
from ..reduce import STREAMED, Reducer
from ..scene import SceneVariation
from .file import PRODUCT_FILE, CalibrationProduct, Skipped, load_product, map_problem
from .records import (DarkStep, EmvaStep, FixedPatternStep, FlatFieldStep, NoiseStep,
                              ProductEstimates, ProductSteps, Provenance, ResponseStep,
                              SceneStep)
from ..session import MAX_INTENSITY, Session, open_session

if TYPE_CHECKING:      # imported where a response is estimated (numba's kernels load then)
    from ..response.methods import ResponseResult

__all__ = ["CalibrationProduct", "Estimates", "Skipped", "Requirement", "REQUIREMENTS",
           "requirement", "missing_frames", "estimate_all", "scene_error_terms", "budget_inputs",
           "calibrate", "load_product", "apply_product", "COMPRESSIONS", "PRODUCT_FILE",
           "ESTIMATE_STEPS", "session_inputs", "map_problem", "MapName", "ProductEstimates",
           "Provenance", "frames_used", "wanted_dark_exposure"]

#: the steps of :func:`estimate_all` in order, with the overall fraction at which each starts
#: (its ``progress`` receives ``progress(start, name)`` at each, :class:`ccdcore.progress.Steps`;
#: :class:`ccdcore.progress.Tracker` takes them)
ESTIMATE_STEPS: tuple[tuple[str, float], ...] = (
    ("photon transfer", 0.0), ("EMVA 1288 figures", 0.08), ("dark reference", 0.15),
    ("fixed pattern", 0.3), ("planning", 0.55), ("correction check", 0.6),
    ("scene variation", 0.65), ("flat field", 0.8), ("response", 0.9), ("done", 1.0))


# ---------------------------------------------------------------------------------------------
# what each estimate needs
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Requirement:
    """What one estimate needs from a session.

    ``roles`` are the frame roles it reads; ``capture`` says, for a person, what to capture when
    they are missing; ``flag`` names a frame flag it needs (``max-intensity``); ``patches``: it
    needs scene frames that name a patch or an ROI.
    """

    estimate: str
    roles: tuple[str, ...]
    purpose: str
    capture: str
    flag: str | None = None
    patches: bool = False


#: every estimate :func:`calibrate` makes, in order, and what it needs
REQUIREMENTS: tuple[Requirement, ...] = (
    Requirement("noise", ("ptc",), "the noise model A, σ²_C (photon transfer, eqs. 37–42)",
                "pairs of frames at several light levels (role = ptc, level = 1, 2, …)"),
    Requirement("emva1288", ("ptc", "dark"),
                "the EMVA 1288 figures (K, QE, σ_d, saturation, dynamic range, linearity, "
                "DSNU, PRNU; release 3.1)",
                "an EMVA1288 descriptor: pairs of bright frames with their photon counts from "
                "dark to saturation, two dark frames at each exposure time, and L frames at "
                "50 % of saturation with as many dark frames (role = ptc with photons, "
                "role = dark)"),
    Requirement("dark", ("dark",), "the dark reference D̂_D with hot/dead flags (sec. V-A)",
                "16 or more lens-capped frames at the exposure of the other frames "
                "(role = dark)"),
    Requirement("fixed_pattern", ("fixed_pattern", "dark"),
                "the fixed-pattern map K̂ (eqs. 45–50)",
                "n1 configurations × n2 frames of a uniform card, moving card and lamp between "
                "configurations (role = fixed_pattern, config = 1 … n1), and dark frames"),
    Requirement("plan", ("ptc", "fixed_pattern"), "the acquisition plan n1, n2 (sec. V-B)",
                "photon-transfer pairs and fixed-pattern frames (with [camera] bits set)"),
    Requirement("correction_check", ("scene", "fixed_pattern", "dark"),
                "the check of eq. 51 on a maximum-intensity image (sec. VII-A)",
                "a scene frame of a card at maximum intensity (role = scene, "
                "flags = [\"max-intensity\"])", flag=MAX_INTENSITY),
    Requirement("scene", ("scene", "ptc", "fixed_pattern", "dark"),
                "the scene variation V_S of uniform patches (sec. VI)",
                "uniform surface patches at several light levels (role = scene, patch = NAME "
                "or an roi)", patches=True),
    Requirement("flat_field", ("flat",),
                "the flat-field gain/offset maps G, O (de Lasarte et al. 2007; without dark "
                "frames in the zero-dark form DL_0 = 0)",
                "flat fields of a uniform source (role = flat, level, exposure) and dark frames "
                "(and biases) at their temperature, at their exposure or at two or more "
                "exposures"),
    Requirement("response", ("bracket",),
                "the inverse response g and the noise terms (Tsin et al. 2001, sec. 3.2)",
                "an exposure bracket of a static scene (role = bracket, one exposure per "
                "frame, e.g. 8 exposures a factor of 1.4 apart)"),
)


def requirement(estimate: str) -> Requirement:
    """The :class:`Requirement` of one estimate name (see :data:`REQUIREMENTS`)."""
    for req in REQUIREMENTS:
        if req.estimate == estimate:
            return req
    raise KeyError(estimate)


def missing_frames(session: Session, estimates: Iterable[str] | None = None
                   ) -> list[tuple[Requirement, tuple[str, ...]]]:
    """The estimates (all, or those named) whose frames the session lacks, each with the roles
    (or the flag) it is missing, in :data:`REQUIREMENTS` order."""
    have = session.roles()
    out = []
    for req in REQUIREMENTS:
        if estimates is not None and req.estimate not in estimates:
            continue
        lacking = tuple(r for r in req.roles if not have.get(r))
        if not lacking and req.flag is not None and not session.flagged(req.flag, req.roles[0]):
            lacking = (f"{req.roles[0]} frame with flags = [\"{req.flag}\"]",)
        if not lacking and req.patches and not session.scene_patches():
            lacking = (f"{req.roles[0]} frames with a patch or an roi",)
        if lacking:
            out.append((req, lacking))
    return out


@dataclass(frozen=True, eq=False)
class Estimates:
    """The result objects of :func:`estimate_all` (``None`` where not made; ``skipped`` says why).

    ``plan_warnings`` list what the session lacks compared with the acquisition plan (sec. V-B);
    each result keeps its own notes.
    """

    noise: PhotonTransfer | None = None
    dark: DarkReference | None = None
    fixed_pattern: FixedPattern | None = None
    plan: AcquisitionPlan | None = None
    plan_warnings: tuple[str, ...] = ()
    scene: dict[str, SceneVariation] | None = None
    correction_check: CorrectionCheck | None = None
    flat: FlatField | None = None
    response: ResponseResult | None = None
    skipped: tuple[Skipped, ...] = ()
    emva1288: EmvaFigures | None = None

    @property
    def made(self) -> tuple[str, ...]:
        """The names of the estimates that were made (:data:`REQUIREMENTS` names)."""
        have = {"noise": self.noise, "emva1288": self.emva1288, "dark": self.dark,
                "fixed_pattern": self.fixed_pattern, "plan": self.plan,
                "correction_check": self.correction_check,
                "scene": self.scene, "flat_field": self.flat, "response": self.response}
        return tuple(k for k, v in have.items() if v is not None)


def scene_error_terms(dark: DarkReference, fixed_pattern: FixedPattern) -> dict[str, Any]:
    """The calibration maps' own errors for :func:`ccdcore.scene.scene_variations`.

    D̂_D's error variance σ²_N/s per pixel (sec. V-A), K̂'s measured error variance
    (:attr:`FixedPattern.K_var`) and the level at which K̂ was measured (harmonic mean of the
    configurations' levels), through which K̂ absorbed the D̂_D error (eq. 46).
    """
    levels = np.asarray(fixed_pattern.config_levels, dtype=np.float64)
    return {"dark_var": dark.sem_map ** 2, "K_var": float(np.mean(fixed_pattern.K_var)),
            "fp_level": float(1.0 / np.mean(1.0 / levels))}


def budget_inputs(dark: DarkReference, fp: FixedPattern, noise: PhotonTransfer,
                  variation: SceneVariation, bits: int | None) -> dict[str, Any]:
    """Inputs of :func:`ccdcore.scene.variance_budget` for one patch (Fig. 4 of Healey &
    Kondepudy 1994).

    ``dark_spatial_var``: D̂_D's spatial variance without the averaging noise
    (``DarkReference.spatial_std_signal²``); ``sigma_K2``: K̂'s spatial variance less its mean
    estimation variance (``mean(FixedPattern.K_var)``), clamped at 0; ``V_S``: the patch's fit,
    clamped at 0; black level from the noise model; μ from the dark mean to full scale
    (2^bits − 1, 255 when the bit depth is unknown).
    """
    full = float(2 ** int(bits) - 1) if bits else 255.0
    k_var = float(np.mean(fp.K_var)) if fp.K_var is not None else 0.0
    dark_sig = dark.spatial_std_signal
    b0 = noise.black_level_dn
    b0 = 0.0 if b0 is None or not math.isfinite(b0) else float(b0)
    dbar = max(float(dark.mean), b0)
    return {"mu": np.linspace(dbar, max(full, dbar + 1.0), 200),
            "A": float(noise.A), "sigma_c2": max(float(noise.sigma_c2), 0.0),
            "dark_spatial_var": dark_sig ** 2 if math.isfinite(dark_sig) else 0.0,
            "sigma_K2": max(fp.spatial_std ** 2 - k_var, 0.0),
            "V_S": max(float(variation.V_S), 0.0) if math.isfinite(variation.V_S) else 0.0,
            "black_level": b0, "dark_mean": dbar}


@dataclass(eq=False)
class _Run:
    """One :func:`estimate_all` run: the session, its options, the estimates made so far and
    those skipped; each step :meth:`attempt`\\ s its estimate."""

    session: Session
    roi: tuple[int, int, int, int] | None
    window: int
    p: float
    noise: PhotonTransfer | None
    response: bool
    emva1288: bool
    reducer: Reducer
    dark_exposure: float | None = None
    response_options: dict[str, Any] = field(default_factory=dict)
    made: dict[str, Any] = field(default_factory=dict)
    skipped: list[Skipped] = field(default_factory=list)
    lacking: dict[str, tuple[str, ...]] = field(init=False)

    def __post_init__(self) -> None:
        self.lacking = dict((req.estimate, roles) for req, roles in missing_frames(self.session))

    def attempt(self, name: str, needs: tuple[str, ...], run: Callable[[], Any]) -> None:
        """Make estimate ``name`` with ``run``, or skip it: its frames missing, an estimate
        of ``needs`` not made, its frames refused (:class:`CcdError`) or its maps damaged."""
        if name in self.lacking:
            roles = self.lacking[name]
            what = " and no ".join(r if " " in r else f"{r} frames" for r in roles)
            req = requirement(name)
            self.skipped.append(Skipped(name, "missing-frames", f"no {what}: for {req.purpose}, "
                                                                f"capture {req.capture}", roles))
            return
        absent = [n for n in needs if self.made.get(n) is None]
        if absent:
            self.skipped.append(Skipped(name, "needs", f"needs the {', '.join(absent)} estimate"
                                        f"{'s' if len(absent) > 1 else ''}, which was not made"))
            return
        try:
            result = run()
        except CcdError as err:
            self.skipped.append(Skipped(name, "failed", str(err)))
            return
        problem = _damaged_maps(name, result)
        if problem is not None:  # a product holding it would not load: skip it, say why
            self.skipped.append(Skipped(name, "failed", f"{problem}; the estimate was left out "
                                                        "(a product holding it would be damaged)"))
            return
        self.made[name] = result

    def estimates(self) -> Estimates:
        """What was made, with the plan's warnings against the session."""
        from ..planning import check_session_plan

        made = self.made
        plan = made.get("plan")
        warnings = tuple(check_session_plan(self.session, plan)) if plan is not None else ()
        return Estimates(noise=made.get("noise"), dark=made.get("dark"),
                         fixed_pattern=made.get("fixed_pattern"), plan=plan,
                         plan_warnings=warnings, scene=made.get("scene"),
                         correction_check=made.get("correction_check"),
                         flat=made.get("flat_field"), response=made.get("response"),
                         skipped=tuple(self.skipped), emva1288=made.get("emva1288"))


def _photon_transfer(run: _Run) -> None:
    """``ptc`` levels: the noise model A, σ²_C (or the one given)."""
    from ..noise import photon_transfer

    if run.noise is not None:
        run.made["noise"] = run.noise
    else:
        run.attempt("noise", (), lambda: photon_transfer(run.session, roi=run.roi,
                                                         reducer=run.reducer))


def _emva_figures(run: _Run) -> None:
    """``ptc`` frames with photon counts and darks: the EMVA 1288 figures (not applicable
    without photon counts)."""
    from ..emva.datasheet import emva_figures

    if not run.emva1288:
        return
    no_photons = all(r.photons is None for r in run.session.by_role("ptc"))
    if "emva1288" not in run.lacking and no_photons:
        run.skipped.append(Skipped("emva1288", "not-applicable", "the ptc frames have no photon "
                                   "counts: the EMVA 1288 figures need the photons per pixel of "
                                   "each bright frame (open an EMVA1288 descriptor, or give "
                                   "photons = N in the manifest)", ("ptc",)))
    else:
        run.attempt("emva1288", (), lambda: emva_figures(run.session, noise=run.made.get("noise"),
                                                         with_ptc=False))


def _dark_reference(run: _Run) -> None:
    """``dark`` frames of a mono camera: D̂_D with hot/dead flags, at the fixed-pattern frames'
    exposure when the darks have several."""
    from ..dark.frame import dark_reference, dark_reference_from_model, reference_model

    session = run.session
    if session.roles().get("dark") and session.camera.layout != Layout.MONO:
        run.skipped.append(Skipped("dark", "not-applicable", f"{session.camera.layout} camera: "
                                   "the dark reference D̂_D of sec. V-A is made for mono frames; "
                                   "the flat-field DL_0 serves instead"))
        return

    def make() -> DarkReference:
        wanted = run.dark_exposure if run.dark_exposure is not None else \
            wanted_dark_exposure(session)[0]
        model = reference_model(session, wanted)
        run.made["dark_model"] = model          # reused by the flat field where it applies
        if model is not None and wanted is not None:
            why = "as named" if run.dark_exposure is not None else \
                "the median exposure of the %s frames" % wanted_dark_exposure(session)[1]
            return dark_reference_from_model(model, wanted, notes=(
                f"D̂_D at {wanted:g} s ({why}) from the dark model: fewer than two dark "
                "frames at that exposure",))
        exposure, note = dark_exposure_for(session, run.dark_exposure)
        ref = dark_reference(session, exposure=exposure, reducer=run.reducer)
        return replace(ref, notes=(note, *ref.notes)) if note else ref
    run.attempt("dark", (), make)


#: the roles whose exposure the dark reference is matched to, in order of preference
_DARK_MATCH_ROLES = ("fixed_pattern", "flat", "ptc")


def wanted_dark_exposure(session: Session) -> tuple[float | None, str | None]:
    """The median exposure of the fixed-pattern frames, else of the flats, else of the ptc
    frames, with that role (``(None, None)`` when none has an exposure): the exposure the dark
    reference is wanted at."""
    for role in _DARK_MATCH_ROLES:
        times = [r.exposure for r in session.by_role(role) if r.exposure is not None]
        if times:
            return float(np.median(times)), role
    return None, None


def dark_exposure_for(session: Session, named: float | None = None
                      ) -> tuple[float | None, str | None]:
    """The exposure of the dark frames the dark reference (and its hot and dead pixel maps) is
    made from, and a note saying why: ``named`` when given; with darks at one exposure, that
    one; else the one nearest (in ratio) the median exposure of the fixed-pattern frames, else
    of the flats, else of the ptc frames (an EMVA 1288 set: the bright frames, whose spatial
    set dominates the median); with none of those, the exposure with the most dark frames."""
    from ..dark.frame import exposures_text, nearest_exposure
    from ..dark.model import select_darks

    matched = select_darks(session, session.dark_frames(), None)[0]
    darks = [r.exposure for r in matched if r.exposure is not None]
    have = sorted(set(darks))
    if named is not None:
        return float(named), (f"dark frames at {exposures_text(have)}: the dark reference is "
                              f"made at {named:g} s, as named" if len(have) > 1 else None)
    if len(have) <= 1:
        return None, None
    target, role = wanted_dark_exposure(session)
    if target is not None and role is not None:
        chosen = nearest_exposure(have, target)
        return chosen, (f"dark frames at {exposures_text(have)}: the dark reference is made "
                        f"at {chosen:g} s, the nearest to the {role.replace('_', '-')} "
                        f"frames' median exposure {target:g} s (name another with "
                        "--dark-exposure)")
    counts = {t: darks.count(t) for t in have}
    chosen = max(have, key=lambda t: (counts[t], t))
    return chosen, (f"dark frames at {exposures_text(have)}: the dark reference is made at "
                    f"{chosen:g} s, the exposure with the most dark frames ({counts[chosen]}; "
                    "name another with --dark-exposure)")


def _fixed_pattern(run: _Run) -> None:
    """``fixed_pattern`` configurations and D̂_D: K̂."""
    from ..fixedpattern import fixed_pattern_map

    run.attempt("fixed_pattern", ("dark",),
                lambda: fixed_pattern_map(run.session, run.made["dark"], window=run.window,
                                          p=run.p, reducer=run.reducer))


def _plan(run: _Run) -> None:
    """The noise model and K̂: the acquisition plan n1, n2 (needs the camera's bit depth)."""
    from ..planning import plan_acquisition

    def make() -> AcquisitionPlan:
        if not run.session.camera.bits:
            raise CcdError("camera.bits", "the plan needs the camera bit depth")
        return plan_acquisition(run.made["noise"], bits=run.session.camera.bits,
                                fixed_pattern=run.made["fixed_pattern"])
    run.attempt("plan", ("noise", "fixed_pattern"), make)


def _correction_check(run: _Run) -> None:
    """A ``max-intensity`` scene frame, D̂_D and K̂: the check of eq. 51."""
    from ..fixedpattern import correction_check

    def make() -> CorrectionCheck:
        rec = run.session.max_intensity_frame()
        assert rec is not None  # missing_frames checked the flag
        return correction_check(run.session.read(rec), run.made["dark"],
                                run.made["fixed_pattern"])
    run.attempt("correction_check", ("dark", "fixed_pattern"), make)


def _scene_variation(run: _Run) -> None:
    """``scene`` patches, the noise model, D̂_D and K̂: V_S with the maps' own errors."""
    from ..scene import scene_variations

    made = run.made
    run.attempt("scene", ("noise", "dark", "fixed_pattern"),
                lambda: scene_variations(run.session, made["dark"], made["fixed_pattern"],
                                         made["noise"], **scene_error_terms(
                                             made["dark"], made["fixed_pattern"])))


def _flat_field(run: _Run) -> None:
    """``flat`` frames and darks: the G/O maps."""
    from ..flatfield.fit import flat_field_from_session

    run.attempt("flat_field", (), lambda: flat_field_from_session(
        run.session, base="auto", reducer=run.reducer, dark_exposure=run.dark_exposure,
        dark_model=run.made.get("dark_model"), held_out=True))


def _response(run: _Run) -> None:
    """A ``bracket``: the inverse response g and the noise terms."""
    from ..response.bracket_fit import session_response

    if run.response:
        run.attempt("response", (), lambda: session_response(run.session,
                                                             **run.response_options))


#: the function of each step of :data:`ESTIMATE_STEPS` (but ``done``), in that order
_STEPS: tuple[tuple[str, Callable[[_Run], None]], ...] = (
    ("photon transfer", _photon_transfer), ("EMVA 1288 figures", _emva_figures),
    ("dark reference", _dark_reference), ("fixed pattern", _fixed_pattern),
    ("planning", _plan), ("correction check", _correction_check),
    ("scene variation", _scene_variation), ("flat field", _flat_field),
    ("response", _response))


def estimate_all(session: Session, *, roi: tuple[int, int, int, int] | None = None,
                 window: int = 9, p: float = 1.5, noise: PhotonTransfer | None = None,
                 progress: Progress | None = None, response: bool = True,
                 emva1288: bool = True, reducer: Reducer | None = None,
                 dark_exposure: float | None = None,
                 response_options: Mapping[str, Any] | None = None) -> Estimates:
    """Every estimate the session's frames allow (see :func:`calibrate`).

    An estimate whose frames are missing, or whose frames the method refuses (a
    :class:`CcdError`, e.g. one fixed-pattern configuration where eq. 49 needs several), is
    skipped and listed in :attr:`Estimates.skipped` with its reason; the others are still made.
    ``noise`` may pass an already computed photon-transfer result (e.g. with levels the user
    excluded in the app) instead of computing it here; ``response=False`` leaves the response
    of a bracket out, ``emva1288=False`` the EMVA 1288 figures (their steps are then empty);
    ``response_options`` are :func:`ccdcore.response.bracket_fit.session_response`'s (``method``,
    ``white_balance``, ``exposures``).
    The EMVA 1288 figures need photon counts: a session whose ptc frames have none skips them
    as ``not-applicable``.
    ``progress`` (a :class:`ccdcore.progress.Progress`) gets ``progress(start, name)`` as each
    of :data:`ESTIMATE_STEPS` starts; each step is one function (``_STEPS``).

    ``reducer`` (:mod:`ccdcore.reduce`; default streamed here) runs the reductions over frames
    of the photon transfer, the dark reference, K̂ and the flat field; a
    :class:`ccdcore.distributed.client.DaskReducer` runs them on a Dask cluster
    (``docs/distributed.md`` says what is not distributed yet).
    """
    run = _Run(session, roi=roi, window=window, p=p, noise=noise, response=response,
               emva1288=emva1288, reducer=reducer or STREAMED, dark_exposure=dark_exposure,
               response_options=dict(response_options or {}))
    report = Steps(progress, ESTIMATE_STEPS)
    for step, make in _STEPS:
        report(step)
        make(run)
    result = run.estimates()
    report("done")
    return result


def _damaged_maps(name: str, result: Any) -> str | None:
    """What makes the maps of estimate ``name`` unusable in a product (:func:`map_problem`),
    e.g. all-NaN darks (a non-finite K̂ everywhere) or a single dark frame (no variance)."""
    if name == "dark":
        maps = {MapName.DARK: result.mean_map, MapName.DARK_VAR: result.var_map}
    elif name == "fixed_pattern":
        maps = {MapName.K: result.K, MapName.K_VAR: result.K_var}
    elif name == "flat_field":
        maps = result.maps()
    else:
        return None
    for map_name, m in maps.items():
        if m is not None and (problem := map_problem(map_name, m)) is not None:
            return problem
    return None


def calibrate(session_or_path: Session | str | os.PathLike, *,
              roi: tuple[int, int, int, int] | None = None, window: int = 9, p: float = 1.5,
              progress: Progress | None = None,
              noise: PhotonTransfer | None = None, reducer: Reducer | None = None,
              dark_exposure: float | None = None,
              response_options: Mapping[str, Any] | None = None) -> CalibrationProduct:
    """Run every estimate the session's frames allow.

    - ``ptc`` levels: photon transfer (eqs. 37–42, 59–67), over ``roi`` when given;
    - ``dark`` frames: dark reference D̂_D with hot/dead flags (sec. V-A); with darks at
      several exposures, from those at ``dark_exposure`` or at the one nearest the other
      frames' (:func:`dark_exposure_for`);
    - ``fixed_pattern`` configurations and darks: K̂ (eqs. 45–50, ``window``, ``p``);
    - noise model and K̂: acquisition plan n1, n2 (sec. V-B), with warnings if the session has
      fewer frames;
    - a ``max-intensity`` scene frame: the correction check (sec. VII-A);
    - ``scene`` frames with patches/ROIs, K̂ and the noise model: scene variation V_S (sec. VI);
    - ``flat`` frames and darks: flat-field G/O maps (de Lasarte et al. 2007);
    - a ``bracket``: the inverse response g per channel with its band and the noise terms
      (Tsin et al. 2001, sec. 3.2), for :func:`apply_product` (``linearise``) and the HDR merge;
    - ``ptc`` frames with photon counts (an EMVA1288 descriptor) and dark frames: the EMVA 1288
      figures (:func:`ccdcore.emva.datasheet.emva_figures`), in
      :attr:`CalibrationProduct.emva1288`.

    The product holds every estimate that could be made; each one that could not is listed in
    :attr:`CalibrationProduct.skipped` with its reason (missing frames, or frames the method
    refused).  The provenance records the session's content hash, the date (UTC) and the
    ``scheduler`` the reductions ran on: ``"streamed (this process)"``, or with a Dask
    ``reducer`` (see :func:`estimate_all`) the scheduler's address and its number of workers.

    Parameters
    ----------
    session_or_path : Session or str or os.PathLike
        A :class:`~ccdcore.session.Session` or anything :func:`~ccdcore.session.open_session`
        opens.
    roi : tuple of 4 int or None, optional
        ``(x, y, w, h)`` in pixels, the photon transfer's region; default the whole frame.
    window : int, optional
        m, the side of K̂'s local window (:func:`~ccdcore.fixedpattern.fixed_pattern_map`).
    p : float, optional
        K̂'s rejection half-width in units of σ̂ (:func:`~ccdcore.fixedpattern.fixed_pattern_map`).
    progress : Progress or None, optional
        A :class:`ccdcore.progress.Progress`: ``progress(start, name)`` as each of
        :data:`ESTIMATE_STEPS` starts (:func:`estimate_all`).
    noise : PhotonTransfer or None, optional
        A photon-transfer result already made (e.g. with levels left out or the robust mode, as
        the app's Walkthrough chooses), used instead of estimating it here.
    reducer : Reducer or None, optional
        Runs the reductions over frames (:mod:`ccdcore.reduce`; default streamed here); a Dask
        reducer runs them on its cluster (see :func:`estimate_all`).
    dark_exposure : float or None, optional
        With darks at several exposures, the exposure of the darks the dark reference is made
        from; default the one nearest the other frames' (:func:`dark_exposure_for`).
    response_options : mapping of str to Any, or None, optional
        Options of the bracket's response: see :func:`estimate_all` (``method``,
        ``white_balance``, ``exposures`` of :func:`ccdcore.response.bracket_fit.session_response`).

    Returns
    -------
    CalibrationProduct
        The maps (by :class:`MapName`), the summary of each estimate made, the camera, the
        provenance, the estimates skipped with their reasons, the plan's warnings, the EMVA 1288
        figures and the frames each map was made from; :meth:`CalibrationProduct.save` writes it.

    Raises
    ------
    CcdError
        The session has errors (every error is listed), or no estimate at all could be made
        ("nothing to calibrate", naming the roles that would be needed); a path that
        :func:`~ccdcore.session.open_session` refuses.

    Examples
    --------
    >>> import tempfile
    >>> from ccdcore.simulate import simulate
    >>> tmp = tempfile.TemporaryDirectory()
    >>> _ = simulate("healey94", tmp.name, seed=1, size=(64, 48))
    >>> product = calibrate(tmp.name)
    >>> product.shape, MapName.K in product.maps, MapName.DARK in product.maps
    ((48, 64), True, True)
    >>> folder = product.save(tmp.name + "/calib")
    >>> tmp.cleanup()
    """
    session = session_or_path if isinstance(session_or_path, Session) \
        else open_session(session_or_path)
    session.raise_if_invalid()
    e = estimate_all(session, roi=roi, window=window, p=p, progress=progress, noise=noise,
                     reducer=reducer, dark_exposure=dark_exposure,
                     response_options=response_options)
    if not e.made:
        failed = [s for s in e.skipped if s.code == "failed"]
        why = "; ".join(f"{s.estimate}: {s.reason}" for s in failed) if failed else (
            "the session has none of the frames an estimate needs: " + "; ".join(
                f"{req.estimate} needs {'/'.join(req.roles)}" for req in REQUIREMENTS))
        raise CcdError(session.label, f"nothing to calibrate ({why})")
    maps, estimates, steps = _assembled(e, roi=roi, window=window, p=p)
    provenance = Provenance(
        ccdcore=__version__, session=session.label, source=session.source,
        n_frames=len(session.frames), session_hash=session.content_hash(),
        date=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        scheduler=(reducer or STREAMED).description, steps=steps)
    return CalibrationProduct(
        maps=maps, estimates=estimates, camera=session.camera, provenance=provenance,
        skipped=e.skipped, warnings=e.plan_warnings,
        emva1288=None if e.emva1288 is None else e.emva1288.summary(),
        frames=frames_used(e, session, maps))


def frames_used(e: Estimates, session: Session, maps: Mapping[MapName, Any]
                ) -> dict[str, tuple[str, ...]]:
    """Each map -> the relative paths of the frames it was made from (section 3 of the darks
    and flats issue): the dark reference's darks (or the dark model's frames), K̂'s
    fixed-pattern frames and darks, the flat field's base flats and the darks of DL_0."""
    out: dict[str, tuple[str, ...]] = {}
    dark = tuple(e.dark.frames) if e.dark is not None else ()
    for name in (MapName.DARK, MapName.DARK_VAR, MapName.HOT, MapName.DEAD):
        if name in maps and dark:
            out[name] = dark
    fp = tuple(r.relpath for r in session.by_role("fixed_pattern")) + dark
    for name in (MapName.K, MapName.K_VAR, MapName.N1_USED):
        if name in maps and fp:
            out[name] = fp
    if e.flat is not None:
        base, d0 = tuple(e.flat.base_frames), tuple(e.flat.dark_frames)
        for name, used in ((MapName.FLAT_G, base + d0), (MapName.FLAT_O, base + d0),
                           (MapName.FLAT_FLAGS, base + d0), (MapName.FLAT_DARK, d0),
                           (MapName.FLAT_BASE, base)):
            if name in maps and used:
                out[name] = used
    return out


def _assembled(e: Estimates, *, roi: tuple[int, int, int, int] | None, window: int,
               p: float) -> tuple[dict[MapName, np.ndarray], ProductEstimates, ProductSteps]:
    """The maps (float32), the summary of each estimate made and each step's parameters."""
    maps: dict[MapName, np.ndarray] = {}
    est: dict[str, Any] = {}
    steps: dict[str, Any] = {}
    if e.noise is not None:
        est["noise"] = e.noise.summary()
        steps["noise"] = NoiseStep(
            method="photon transfer, Healey & Kondepudy 1994 eqs. 37-42, 59-67",
            roi=None if roi is None else tuple(int(v) for v in roi))
    if e.dark is not None:
        dark = e.dark
        maps[MapName.DARK] = dark.mean_map.astype(np.float32)
        maps[MapName.DARK_VAR] = dark.var_map.astype(np.float32)
        maps[MapName.HOT] = dark.hot_mask.astype(np.float32)
        maps[MapName.DEAD] = dark.dead_mask.astype(np.float32)
        est["dark"] = dark.summary()
        steps["dark"] = DarkStep(method="streamed average, sec. V-A", s=int(dark.s),
                                 hot_rule=dark.hot_rule, dead_rule=dark.dead_rule)
    if e.fixed_pattern is not None:
        fp = e.fixed_pattern
        maps[MapName.K] = fp.K.astype(np.float32)
        maps[MapName.K_VAR] = fp.K_var.astype(np.float32)
        maps[MapName.N1_USED] = fp.n1_used.astype(np.float32)
        est["fixed_pattern"] = fp.summary()
        steps["fixed_pattern"] = FixedPatternStep(method="eqs. 45-50, sec. V-B",
                                                  window=window, p=p)
    if e.plan is not None:
        est["plan"] = e.plan.summary(warnings=e.plan_warnings)
    if e.correction_check is not None:
        est["correction_check"] = e.correction_check.summary()
    if e.flat is not None:
        maps.update(e.flat.maps())
        est["flat_field"] = e.flat.summary()
        steps["flat_field"] = FlatFieldStep(method="gain/offset maps, de Lasarte et al. 2007",
                                            base=est["flat_field"].base,
                                            flag_rule=e.flat.flag_rule)
    if e.response is not None:
        est["response"] = e.response.summary()
        steps["response"] = ResponseStep(
            method="Tsin, Ramesh & Kanade 2001 sec. 3.2 (instrumented pools), nominal "
                   "exposures", bloom_radius=int(e.response.bloom_radius),
            files=tuple(str(f) for f in e.response.files))
    if e.scene is not None:
        est["scene"] = {name: v.summary() for name, v in e.scene.items()}
        steps["scene"] = SceneStep(
            method="eqs. 53-58, sec. VI, with the calibration maps' errors")
    if e.emva1288 is not None:
        from ..emva.datasheet import LINEARITY_RANGE, SENSITIVITY_FRACTION, SIGMA2_Y_DARK_FLOOR

        steps["emva1288"] = EmvaStep(
            method="EMVA 1288 release 3.1 as the emva1288 1.0.2 package computes it "
                   "(Results1288); errors and sigma_d_ptc by ccdcore",
            sensitivity_fraction=SENSITIVITY_FRACTION,
            linearity_range=tuple(LINEARITY_RANGE), sigma2_y_dark_floor=SIGMA2_Y_DARK_FLOOR)
    return maps, ProductEstimates(**est), ProductSteps(**steps)


def session_inputs(session: Session) -> list[Path]:
    """The files a run over ``session`` reads, which no output of the run may overwrite: its
    frames, its manifest, and a simulation's ``truth.json`` with the true maps it names."""
    files = [Path(r.path) for r in session.frames]
    if session.manifest_path is not None:
        files.append(Path(session.manifest_path))
    truth = Path(session.root) / "truth.json"
    if truth.is_file():
        files.append(truth)
        with contextlib.suppress(OSError, ValueError, AttributeError, TypeError):
            maps = json.loads(truth.read_text(encoding="utf-8")).get("maps") or {}
            files += [Path(session.root) / str(rel) for rel in maps.values()]
    return files


# ---------------------------------------------------------------------------------------------
def _output_name(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in FITS_EXTENSIONS or suffix in (".tif", ".tiff", ".exr"):
        return path.name
    return path.stem + ".tif"


#: compressions :func:`apply_product` offers for TIFF and EXR outputs (OpenImageIO names)
COMPRESSIONS = ("none", "zip")


def apply_product(product: CalibrationProduct | str | os.PathLike,
                  images: Iterable[str | os.PathLike], out_dir: str | os.PathLike, *,
                  compression: str = "none", linearise: bool = False) -> list[Path]:
    """Correct each image with the product (eq. 51) into ``out_dir`` as float32.

    Output keeps the base name; TIFF, EXR and FITS keep their format, others become ``.tif``
    (float32 cannot be stored in PNG/PNM). Inputs are never modified; an output that would
    overwrite an input is refused, and so is one inside the product folder or over a FIFO or a
    device. The images are written as one set (:func:`ccdcore.io.frames.output_set`): a failure or
    SIGTERM leaves the earlier outputs of ``out_dir`` as they were.

    Parameters
    ----------
    product : CalibrationProduct or str or os.PathLike
        The calibration product, or its folder (or its ``calibration.json``), loaded with
        :func:`load_product`.
    images : iterable of str or os.PathLike
        The image files to correct.
    out_dir : str or os.PathLike
        The folder the corrected images are written to.
    compression : str, optional
        One of :data:`COMPRESSIONS`, for TIFF and EXR outputs: ``"none"`` by default, because
        deflating float32 noise saves about a quarter of the size at ten times the write time
        (6x on 2048² frames, benchmarks/bench_apply.py); ``"zip"`` when disk space matters more.
    linearise : bool, optional
        Map each image's codes through the product's inverse response g instead
        (:meth:`CalibrationProduct.linearise`): values linear in exposure.

    Returns
    -------
    list of pathlib.Path
        The files written, ``out_dir`` / each image's output name, in the order of ``images``.

    Raises
    ------
    CcdError
        No images; an unknown ``compression``; an output that would overwrite an input, two
        images with the same output name, an output inside the product folder, over a FIFO or a
        device, or over a file ccdcore did not write there; an image whose shape differs from
        the maps' or whose bit depth exceeds the product's camera's; with ``linearise``, a
        product without a response curve or an image without integer codes, without it a
        product with neither dark reference nor flat field; a product that cannot be loaded
        (:func:`load_product`), an image that cannot be read or an output that cannot be
        written.

    Examples
    --------
    >>> import tempfile
    >>> from ccdcore.simulate import simulate
    >>> tmp = tempfile.TemporaryDirectory()
    >>> from pathlib import Path
    >>> _ = simulate("healey94", tmp.name, seed=1, size=(64, 48))
    >>> product = calibrate(tmp.name)
    >>> scene = sorted(Path(tmp.name, "scene").glob("*.tif"))[:2]
    >>> written = apply_product(product, scene, tmp.name + "/corrected")
    >>> [p.suffix for p in written]
    ['.tif', '.tif']
    >>> tmp.cleanup()
    """
    inputs = [Path(p) for p in images]
    if not isinstance(product, CalibrationProduct):
        given = Path(product)
        inputs.append(given if given.is_dir() else given.parent)
        product = load_product(product)
    if linearise:
        product.response_models()          # a clear error before anything is read
    out_dir = Path(out_dir)
    images = [Path(p) for p in images]
    if not images:
        raise CcdError("images", "no images given")
    if compression not in COMPRESSIONS:
        raise CcdError("compression", f"unknown compression {compression!r}; choose one of "
                                      f"{', '.join(COMPRESSIONS)}")
    targets = [out_dir / _output_name(p) for p in images]
    seen: dict[Path, Path] = {}
    for src, dst in zip(images, targets):
        if dst.resolve() == src.resolve():
            raise CcdError(src, "the output would overwrite the input; choose another -o folder")
        if dst in seen:
            raise CcdError(src, f"has the same output name as {seen[dst]}")
        seen[dst] = src
    check_outputs(out_dir, [t.name for t in targets], inputs)   # before anything is read
    shape = None if linearise else product.shape
    for src in images:  # check every header before writing anything
        header = read_header(src)
        if shape is not None and header.shape != shape:
            raise CcdError(src, f"image shape {header.shape} differs from the calibration "
                                f"maps' {shape}")
        bits = product.camera.bits
        if bits is not None and header.dtype.kind in "ui":
            # a container wider than the camera's (16-bit words for an 8-bit camera), or a
            # depth stated beyond the camera's (a 14-bit raw for a 12-bit product)
            container = header.dtype.itemsize * 8
            if container > 8 * -(-bits // 8) or bits < header.bits < container:
                raise CcdError(src, f"{header.bits}-bit {header.dtype} data, but the product "
                                    f"was made for a {bits}-bit camera: another camera or "
                                    "setting? (apply a product of the same camera)")
    with output_set(out_dir, inputs=inputs) as tmp:   # all images as one set, or none
        for src, dst in zip(images, targets):
            attrs = ({"compression": compression}
                     if dst.suffix.lower() in (".tif", ".tiff", ".exr") else None)
            data, header = read_frame(src)
            fix = product.linearise if linearise else product.correct
            write_image(tmp / dst.name, fix(data, name=str(src)), attributes=attrs,
                        exposure=header.exposure)
    return targets
