"""The guided calibration: its steps, and the gate of each step (what passed, what failed, why,
and what to capture or change next).

The app's Walkthrough page shows these steps; the verdicts are made here, from ccdcore's own
results, so that a script reaches the same verdicts as the page.

Steps (:data:`STEPS`)
    ``plan`` (:mod:`ccdcore.capture`), ``session`` (validation, :func:`session_gate`), ``dark``
    (:func:`dark_step`), ``ptc`` (:func:`ptc_gate`), ``pattern`` (:func:`pattern_step`: K̂ with
    the plan of sec. V-B, the flat field with SNUP on held-out flats), ``response``
    (:func:`response_gate`), ``verify`` (:func:`verify`: a product applied to frames the
    calibration did not use), ``export``.

Gate rules (each also in the gate's own reasons, in words)
    * session: an error fails; warnings pass with a warning; each problem gets the fix of its
      code (:attr:`ProblemCode.fix <ccdcore.session.records.ProblemCode>`, :data:`FIXES`);
    * dark: more than 0.5 % hot or dead pixels, or more than 1 % of the dark frames' values at
      exactly zero (the offset clips the dark signal: de Lasarte's ZDI case) warn; the level per exposure and its
      drift (DN/s, least squares over the exposures) are reported;
    * photon transfer (:func:`ptc_gate`): judged on the size of the deviation, not on χ²
      alone -- with millions of pixels the points' statistical errors are far below any real
      sensor's nonlinearity, so χ² (eq. 42) resolves it on every good camera.  When χ² resolves
      a deviation (Q < 0.01, eq. 67) the points' relative deviation from the line
      (σ̂²_N − line)/line passes within ±3 %, warns within ±10 % and fails beyond; the
      linearity error of the means (EMVA 1288 sec. 6.7, when the levels carry photon counts)
      passes within ±1 %, warns within ±3 % and fails beyond; σ(A)/A with the nonlinearity
      included (× √(χ²/ν) when χ²/ν > 1, the Birge ratio) above 5 % warns; fewer than 3 levels
      used fails; χ², ν and Q are always among the reasons;
    * fixed pattern and flat field: fewer configurations or frames than the plan warn; a flat
      correction that leaves a held-out flat less uniform than before fails;
    * verify: the corrected frames' SNUP must not exceed the raw frames'; it passes when it is
      within 1.5× the temporal-noise floor 100·σ_N(μ)/μ of the noise model.

Public objects
--------------
STEPS, StepInfo, GateStatus, Gate, FIXES
session_gate(session), dark_step(session), ptc_gate(noise, emva=None), ptc_deviation(noise),
ptc_linearity(noise), pattern_step(session, ...), session_plan(session) (the steps a
session's frames allow, :class:`SessionPlan`),
response_gate(response), held_out_frames(session, product), verify(session, product, ...)
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from .channels import Layout
from .gates import (GAIN_ERROR_LIMIT, LINEARITY_FAIL, LINEARITY_PASS, PTC_DEVIATION_FAIL,
                    PTC_DEVIATION_PASS, Q_RESOLVED, STATUS_LABELS, Gate, GateStatus, pct,
                    ptc_deviation, ptc_gate, ptc_linearity)
from .map_names import MapName
from .session.records import ProblemCode

__all__ = ["STEPS", "StepInfo", "GateStatus", "Gate", "FIXES", "session_gate", "DarkStep",
           "dark_step", "ptc_gate", "PatternStep", "pattern_step", "response_gate", "VerifyRow",
           "Verification", "held_out_frames", "verify", "HOT_DEAD_LIMIT", "ZERO_DARK_LIMIT",
           "Q_RESOLVED", "PTC_DEVIATION_PASS", "PTC_DEVIATION_FAIL", "LINEARITY_PASS",
           "LINEARITY_FAIL", "GAIN_ERROR_LIMIT", "ptc_deviation", "ptc_linearity",
           "SessionPlan", "session_plan", "MISSING", "LAB_ROLES", "STATUS_LABELS"]

#: fraction of hot + dead pixels above which the dark step warns
HOT_DEAD_LIMIT = 0.005
#: fraction of D̂_D pixels at exactly zero above which the dark step warns (clipped offset)
ZERO_DARK_LIMIT = 0.01
#: a corrected frame within this factor of the temporal-noise floor passes the verify step
FLOOR_FACTOR = 1.5


@dataclass(frozen=True)
class StepInfo:
    """One step: ``slug`` (its URL name), ``title``, ``plain`` (what it does, in plain words)
    and ``details`` (symbols and equation numbers)."""

    slug: str
    title: str
    plain: str
    details: str


STEPS: tuple[StepInfo, ...] = (
    StepInfo("plan", "Plan the captures",
             "What the loaded session's frames allow and what they lack; for a lab session "
             "(or none), before touching the camera: how many dark frames, which exposures for "
             "photon "
             "transfer, how many card configurations and frames for the fixed-pattern map, "
             "which flat-field exposures and which bracket — each sized from the camera's bit "
             "depth and a rough noise model.",
             "s: σ²_N(dark)/s ≤ q²/10 (sec. V-A); ladder: predicted σ(A) from eq. 66; n1, n2: "
             "sec. V-B; flats: de Lasarte et al. 2007 (base in the linear range, N by SNUP); "
             "bracket: Tsin et al. sec. 3.2."),
    StepInfo("session", "Load and validate the session",
             "Every file is opened once and every problem is listed with its fix; an estimate "
             "only refuses the frames whose problems concern it.",
             "Roles: dark, ptc (level), fixed_pattern (config), flat (level, exposure), "
             "bracket (exposure, stack), scene; docs/session.md lists every check."),
    StepInfo("dark", "Dark reference",
             "The average of the lens-capped frames is subtracted from every image; pixels far "
             "brighter (hot, noisy) or darker (dead, stuck) than the rest are flagged; the dark "
             "level per exposure shows drift and dark current.",
             "D̂_D(a, b) = mean of s dark frames (sec. V-A, eq. 43), variance σ²_N/s; hot/dead "
             "by 6 robust σ and the χ² law of the temporal variance."),
    StepInfo("ptc", "Photon transfer",
             "Pairs of frames at several light levels give the camera's noise against its "
             "signal; the straight line through them gives the gain (DN per electron) and the "
             "read noise. The gate judges how far the points stray from the line against a "
             "stated tolerance; χ² and Q say whether their errors resolve that deviation.",
             "σ²_N = A·μ + σ²_C (eq. 41) from difference images (eqs. 37–40), weighted fit "
             "eqs. 59–66, Q from χ² with P − 2 degrees of freedom (eq. 67)."),
    StepInfo("pattern", "Fixed pattern and flat field",
             "How much each pixel's sensitivity differs from its neighbours' (K̂), from frames "
             "of a uniform card in several configurations; for colour cameras the flat-field "
             "gain and offset maps. Frames the maps did not use show whether they help.",
             "K̂ = mean of the kept slopes m_i (eqs. 45–50), n1 × n2 by sec. V-B; G, O and "
             "SNUP = 100·σ/mean (de Lasarte et al. 2007)."),
    StepInfo("response", "Response curve and HDR",
             "From a bracket of a static scene: the curve that maps codes back to exposure, its "
             "noise terms, and radiance with a per-pixel uncertainty.",
             "g by the estimator of Tsin et al. sec. 3.2 (eqs. 8–17), HDR by eqs. 18–19."),
    StepInfo("verify", "Verify",
             "The correction applied to frames the calibration did not use: how uniform they "
             "are before and after, against the floor the camera's own noise sets, and how "
             "many pixels the correction changed by more than one code.",
             "D_C = (D − D̂_D)/K̂ (eq. 51) or DL_c = O + G·DL; floor 100·σ_N(μ)/μ from eq. 41."),
    StepInfo("export", "Export",
             "Save the calibration product (maps and estimates, loadable by `ccdcore apply`) "
             "and the report (one HTML file that opens offline).",
             "calibration.json + maps/*.exr (docs/cli.md); the report: docs/report.md."),
)


#: the fix of each validation problem code, ``{code: fix}`` (:class:`ProblemCode`, whose members
#: carry their fix as ``.fix``; docs/session.md)
FIXES: dict[str, str] = {code.value: code.fix for code in ProblemCode}


# ---------------------------------------------------------------------------------------------
def session_gate(session: Any) -> Gate:
    """Validation: every problem with its fix (:data:`FIXES`)."""
    reasons = tuple(f"{p.severity}: {p} — fix: {FIXES.get(p.code, 'see docs/session.md')}"
                    for p in session.problems)
    roles = ", ".join(f"{n} {r}" for r, n in session.roles().items()) or "no frames"
    if session.errors:
        return Gate(GateStatus.FAIL, f"{len(session.errors)} error(s) in {session.label}: the "
                                     "estimates that use those frames cannot run", reasons,
                    ("fix the errors listed, then reopen the session",))
    if session.warnings:
        return Gate(GateStatus.WARN, f"{len(session.frames)} frames ({roles}), "
                                     f"{len(session.warnings)} warning(s)", reasons)
    return Gate(GateStatus.PASS, f"{len(session.frames)} frames ({roles}), no problems")


# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class DarkStep:
    """The dark reference, the dark level per exposure and the gate.

    ``levels``: per exposure ``{"exposure", "n", "mean", "sem"}`` (DN; sem = spatial mean's
    standard error from the frames' scatter); ``drift``: the dark current, DN/s (least squares
    of the level on the exposure), ``None`` with fewer than two exposures.
    """

    dark: Any
    levels: tuple[dict[str, Any], ...]
    drift: float | None
    gate: Gate


def dark_step(session: Any, *, dark: Any = None) -> DarkStep:
    """Dark reference (sec. V-A) of the session's dark frames, its level per exposure and the
    gate (see the module docstring); ``dark`` may pass an already computed reference."""
    from .dark.frame import dark_reference

    recs = session.dark_frames()
    if not recs:
        return DarkStep(None, (), None, Gate(
            GateStatus.SKIP, "no dark frames: the dark reference is skipped",
            next=("capture 16 or more lens-capped frames at the exposure of the other "
                  "frames (role = dark)",)))
    if session.camera.layout != Layout.MONO:
        return DarkStep(None, (), None, Gate(
            GateStatus.SKIP, f"{session.camera.layout} camera: D̂_D of sec. V-A is made for "
                             "mono frames; the flat field's dark image DL_0 serves instead"))
    groups: dict[Any, list[float]] = {}
    zeros = total = 0
    for rec, frame in session.iter_frames(recs):
        groups.setdefault(rec.exposure, []).append(float(np.mean(frame, dtype=np.float64)))
        zeros += int(np.count_nonzero(frame == 0))
        total += frame.size
    levels = []
    for t, means in sorted(groups.items(), key=lambda kv: (kv[0] is None, kv[0] or 0.0)):
        m = np.asarray(means)
        sem = float(np.std(m, ddof=1) / math.sqrt(m.size)) if m.size > 1 else float("nan")
        levels.append({"exposure": t, "n": int(m.size), "mean": float(m.mean()), "sem": sem})
    known = [lv for lv in levels if lv["exposure"] is not None]
    drift = None
    if len(known) >= 2:
        t = np.array([lv["exposure"] for lv in known])
        y = np.array([lv["mean"] for lv in known])
        drift = float(np.polyfit(t, y, 1)[0])
    if dark is None:
        use = None
        if len(groups) > 1:   # the fixed-pattern exposure, else the one with most frames
            fp_exposures = {r.exposure for r in session.by_role("fixed_pattern")} - {None}
            use = next(iter(fp_exposures)) if len(fp_exposures) == 1 else max(
                (t for t in groups if t is not None), key=lambda t: (len(groups[t]), t))
        dark = dark_reference(session, exposure=use)
    n = dark.mean_map.size
    hot, dead = int(dark.hot_mask.sum()), int(dark.dead_mask.sum())
    zero = zeros / total
    reasons = [f"D̂_D from {dark.s} frames: mean {dark.mean:.4g} DN, spatial σ "
               f"{dark.spatial_std:.3g} DN; {hot} hot and {dead} dead pixels "
               f"({pct((hot + dead) / n)})"]
    nxt: list[str] = []
    status = GateStatus.PASS
    if (hot + dead) / n > HOT_DEAD_LIMIT:
        status = GateStatus.WARN
        reasons.append(f"more than {pct(HOT_DEAD_LIMIT)} of the pixels are flagged")
        nxt.append("check for light leaks and the sensor temperature; flagged pixels are "
                   "masked in every map")
    if zero > ZERO_DARK_LIMIT:
        status = GateStatus.WARN
        reasons.append(f"{pct(zero)} of the dark frames' pixel values are exactly 0: the "
                       "offset clips the dark signal, so D̂_D is biased upwards there")
        nxt.append("raise the camera's offset (black level) so the dark frames sit above zero")
    if drift is not None:
        reasons.append(f"dark level over {len(known)} exposures: drift {drift:.4g} DN/s")
    if dark.s < 16:
        status = GateStatus.WARN if status == GateStatus.PASS else status
        reasons.append(f"only {dark.s} dark frames: D̂_D's own noise σ_N/√s is large")
        nxt.append("capture at least 16 dark frames (the capture plan says how many)")
    summary = {GateStatus.PASS: "dark reference made, flags within limits",
               GateStatus.WARN: "dark reference made, with warnings"}[status]
    return DarkStep(dark, tuple(levels), drift, Gate(status, summary, tuple(reasons), tuple(nxt)))


# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PatternStep:
    """K̂ and its checks, the flat field and its held-out SNUP, and the gate.

    ``snup_rows``: per held-out flat frame and channel ``{"frame", "channel", "before",
    "after"}`` (SNUP, %).
    """

    fixed_pattern: Any
    plan: Any
    plan_warnings: tuple[str, ...]
    correction_check: Any
    flat: Any
    snup_rows: tuple[dict[str, Any], ...]
    gate: Gate


def pattern_step(session: Any, *, dark: Any = None, noise: Any = None, window: int = 9,
                 p: float = 1.5, max_held_out: int = 4) -> PatternStep:
    """K̂ (eqs. 45–50) against the plan of sec. V-B, and the flat field (de Lasarte et al.)
    with SNUP before and after on up to ``max_held_out`` flat frames outside the base group."""
    from .fixedpattern import correction_check, fixed_pattern_map
    from .flatfield.fit import flat_field_from_session
    from .planning import check_session_plan, plan_acquisition
    from .flatfield.uniformity import snup

    reasons: list[str] = []
    nxt: list[str] = []
    status = GateStatus.SKIP
    fp = plan = check = flat = None
    warnings: tuple[str, ...] = ()
    rows: list[dict[str, Any]] = []
    if session.fixed_pattern_configs() and dark is not None:
        fp = fixed_pattern_map(session, dark, window=window, p=p)
        status = GateStatus.PASS
        reasons.append(f"K̂ from {fp.n1} configurations: spatial σ_K = {fp.spatial_std:.3g}, "
                       f"slope spread σ̂ = {fp.sigma_hat:.3g}")
        if noise is not None and session.camera.bits:
            plan = plan_acquisition(noise, bits=session.camera.bits, fixed_pattern=fp)
            warnings = tuple(check_session_plan(session, plan))
            if warnings:
                status = GateStatus.WARN
                reasons += list(warnings)
                nxt.append(f"capture n1 = {plan.n1_required} configurations × n2 = "
                           f"{plan.n2_required} frames for K̂ to meet sec. V-B")
        rec = session.max_intensity_frame()
        if rec is not None:
            check = correction_check(session.read(rec), dark, fp)
            reasons.append(f"on the held-out maximum-intensity frame, eq. 51 changes "
                           f"{pct(check.frac_gt_1q)} of the pixels by more than 1 q (at most "
                           f"{check.max_change_q:.3g} q)")
    elif session.fixed_pattern_configs():
        reasons.append("fixed-pattern frames but no dark reference: K̂ needs D̂_D (eq. 46)")
        nxt.append("capture dark frames at the fixed-pattern exposure")
    if session.flat_groups():
        flat = flat_field_from_session(session, base="auto")
        status = GateStatus.PASS if status == GateStatus.SKIP else status
        reasons.append(f"flat field from base group {flat.base_key} (level, exposure)")
        full = 2.0 ** session.camera.bits - 1 if session.camera.bits else None
        held = [(key, recs) for key, recs in session.flat_groups().items()
                if key != flat.base_key]
        picked = []
        for key, recs in held:
            frame = session.read(recs[0])
            level = float(np.mean(frame))
            if full is None or 0.1 * full < level < 0.9 * full:
                picked.append((recs[0], frame))
            if len(picked) >= max_held_out:
                break
        worse = 0
        for rec, frame in picked:
            before = snup(frame, layout=session.camera.layout)
            after = snup(flat.correct(frame, where=rec.relpath), layout=session.camera.layout)
            for c in before.channels:
                rows.append({"frame": rec.relpath, "channel": c.name, "before": c.snup,
                             "after": after[c.name].snup})
                worse += after[c.name].snup > c.snup
        if not picked:
            reasons.append("no flat frame outside the base group lies within 10–90 % of full "
                           "scale: the correction is not checked on held-out frames")
            nxt.append("capture flats at two or more exposures inside the linear range")
            status = GateStatus.WARN if status == GateStatus.PASS else status
        elif worse:
            status = GateStatus.FAIL
            reasons.append(f"{worse} of {len(rows)} held-out channel(s) are less uniform after "
                           "the correction")
            nxt.append("choose another base exposure inside the linear range, or average more "
                       "base frames")
        else:
            reasons.append(f"every held-out frame is more uniform after the correction "
                           f"({len(picked)} frames)")
    if status == GateStatus.SKIP:
        return PatternStep(None, None, (), None, None, (), Gate(
            GateStatus.SKIP,
            "no fixed-pattern or flat frames: K̂ and the flat field are skipped",
            tuple(reasons) or ("the session has neither fixed_pattern nor flat frames",),
            tuple(nxt) or ("capture n1 × n2 frames of a uniform card (role = fixed_pattern) "
                           "or flats of a uniform source (role = flat); the capture plan "
                           "sizes them",)))
    summary = {GateStatus.PASS: "maps made and checked",
               GateStatus.WARN: "maps made, with warnings",
               GateStatus.FAIL: "the correction does not help on held-out frames"}[status]
    return PatternStep(fp, plan, warnings, check, flat, tuple(rows),
                       Gate(status, summary, tuple(reasons), tuple(nxt)))


# ---------------------------------------------------------------------------------------------
def response_gate(response: Any, hdr: Any = None) -> Gate:
    """The response step's gate from a :class:`~ccdcore.response.methods.ResponseResult`: its
    verdict (:mod:`ccdcore.response.verdict`) in its own words -- trusted passes, doubtful
    warns, failed fails, the verdict's next step as the gate's; with ``hdr`` (a
    :class:`~ccdcore.response.hdr.HdrResult` of the bracket) the pixels merged and flagged and
    the median relative sigma σ_E/E (eq. 19) among the reasons."""
    from .response.verdict import DOUBTFUL, FAILED, response_verdict

    verdict = response.verdict if response.verdict is not None else \
        response_verdict(response, response.compared)
    reasons = []
    if response.exposures is not None:
        ex = response.exposures.summary()
        reasons.append(ex.line())
        reasons += list(ex.off_runs())
    if response.selection:
        reasons.append(f"method: {response.method} ({response.selection})")
    if hdr is not None:
        from .response.hdr import FLAG_OK

        ok = (hdr.flags == FLAG_OK) & np.isfinite(hdr.radiance) & (hdr.radiance > 0)
        rel = hdr.sigma[ok] / hdr.radiance[ok]
        reasons.append(f"HDR radiance: {int(ok.sum()):,} of {ok.size:,} values merged, "
                       f"{int(ok.size - ok.sum()):,} flagged (saturated or dark in every image, "
                       "or next to a saturated pixel); median σ_E/E = "
                       f"{100 * float(np.median(rel)) if rel.size else float('nan'):.3g} %")
    for name in response.channels:
        c = response[name]
        reasons.append(f"{name}: {c.iterations} iterations"
                       f"{'' if c.converged else ', not converged'}; σ_s = {c.sigma_s:.3g}, "
                       f"σ_c2 = {c.sigma_c2:.3g} DN")
    nxt = (f"run `ccdcore response` with {verdict.next_step}",) if verdict.next_step else ()
    status = {FAILED: GateStatus.FAIL, DOUBTFUL: GateStatus.WARN}.get(verdict.status,
                                                                       GateStatus.PASS)
    return Gate(status, verdict.line(), tuple(reasons), nxt)


# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class VerifyRow:
    """One held-out frame and channel.

    ``before``/``after``: SNUP = 100·σ/mean over the frame (%); ``local_before``/``local_after``:
    the pixel-scale nonuniformity 100·σ(D − D̄_w)/mean, D̄_w the mean over a w × w window
    (what K̂ of eqs. 45–50 corrects; illumination shading, which K̂ leaves by design, is
    removed); ``floor``: the temporal noise's part of it, 100·σ_N(μ)/μ·√(1 − 1/w²) (eq. 41;
    ``None`` without a noise model); ``changed``: pixels changed by more than one code beyond
    the offset every pixel shares.
    """

    frame: str
    role: str
    channel: str
    before: float
    after: float
    local_before: float
    local_after: float
    floor: float | None
    changed: int
    n_pixels: int

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in (
            "frame", "role", "channel", "before", "after", "local_before", "local_after",
            "floor", "changed", "n_pixels")}


@dataclass(frozen=True)
class Verification:
    """The rows of :func:`verify`, the frames left out (with why) and the gate."""

    rows: tuple[VerifyRow, ...]
    left_out: tuple[str, ...]
    gate: Gate

    def to_dict(self) -> dict[str, Any]:
        return {"rows": [r.to_dict() for r in self.rows], "left_out": list(self.left_out),
                "gate": self.gate.to_dict()}


def held_out_frames(session: Any, product: Any) -> list[Any]:
    """Frames of uniform light that the product's maps did not use: the maximum-intensity
    scene frame, the first frame of each flat group outside the base group, and the first
    frame of each photon-transfer level (pairs serve the noise model only, never a map)."""
    out = []
    rec = session.max_intensity_frame()
    if rec is not None:
        out.append(rec)
    ff = product.estimates.flat_field
    base = tuple(ff.base) if ff is not None and ff.base is not None else None
    for key, recs in session.flat_groups().items():
        if base is None or tuple(key) != base:
            out.append(recs[0])
    for recs in session.ptc_levels().values():
        out.append(recs[0])
    return out


def _local_nonuniformity(plane: np.ndarray, window: int) -> float:
    from scipy.ndimage import uniform_filter

    x = np.asarray(plane, dtype=np.float64)
    local = uniform_filter(x, size=window, mode="reflect")
    return float(100.0 * np.std(x - local) / np.mean(x))


def verify(session: Any, product: Any, *, records: Sequence[Any] | None = None,
           noise: Any = None, window: int = 9, limit: int = 6) -> Verification:
    """Apply ``product`` (:meth:`~ccdcore.product.make.CalibrationProduct.correct`) to held-out
    frames (:func:`held_out_frames` unless ``records``; at most ``limit``, spread over the
    list) and compare their nonuniformity before and after (:class:`VerifyRow`).

    Frames whose mean lies below 10 % or whose pixels reach full scale (more than 1 % at the
    top code) are left out: outside the linear range the maps do not hold (de Lasarte et al.)
    and clipping, not the correction, sets the uniformity. When the product corrects by
    eq. 51 (D − D̂_D)/K̂, the raw frame is compared after removing the mean dark level (the
    offset eq. 51 removes), so that both SNUPs divide by the signal.

    The gate fails when the measure the correction is made to lower grows: SNUP for a flat
    field, the pixel-scale nonuniformity for K̂ (which keeps illumination shading by design);
    it warns when the pixel-scale nonuniformity stays above 1.5× its noise floor.
    """
    from .channels import split_channels

    layout = session.camera.layout
    bits = session.camera.bits
    top = 2 ** bits - 1 if bits else None
    recs = list(records) if records is not None else held_out_frames(session, product)
    flat_product = MapName.FLAT_G in product.maps
    offset = float(np.mean(product.maps[MapName.DARK])) if not flat_product and \
        MapName.DARK in product.maps else 0.0
    b0 = getattr(noise, "black_level_dn", None) if noise is not None else None
    b0 = float(b0) if b0 is not None and math.isfinite(b0) else 0.0
    picked, left_out = [], []
    for rec in recs:
        raw = session.read(rec)
        if top is not None and np.mean(raw >= top) > 0.01:
            left_out.append(f"{rec.relpath}: more than 1 % of its pixels at full scale")
        elif top is not None and np.mean(raw) < 0.1 * top:
            left_out.append(f"{rec.relpath}: mean below 10 % of full scale")
        else:
            picked.append(rec)
    if len(picked) > limit:
        picked = _spread(picked, limit)
    rows: list[VerifyRow] = []
    for rec in picked:
        raw = session.read(rec)
        corr = product.correct(raw, name=rec.relpath).astype(np.float64)
        before = split_channels(raw.astype(np.float64) - offset, layout)
        after = split_channels(corr, layout)
        delta = corr - raw
        changed = int(np.count_nonzero(np.abs(delta - np.median(delta)) > 1.0))
        for name, plane in before.items():
            mean = float(np.mean(plane))
            floor = None
            if noise is not None and mean + offset - b0 > 0:
                mu = mean + offset - b0
                floor = 100.0 * math.sqrt(max(noise.A * mu + noise.sigma_c2, 0.0)) / mean \
                    * math.sqrt(1.0 - 1.0 / window ** 2)
            rows.append(VerifyRow(
                rec.relpath, rec.role, name, float(100.0 * np.std(plane) / mean),
                float(100.0 * np.std(after[name]) / np.mean(after[name])),
                _local_nonuniformity(plane, window), _local_nonuniformity(after[name], window),
                floor, changed, int(plane.size)))
    if not rows:
        return Verification((), tuple(left_out), Gate(
            GateStatus.SKIP, "no held-out frame to verify on", tuple(left_out),
            ("capture a frame of a uniform card at about half of full scale that the "
             "calibration does not use (role = scene, flags = [\"max-intensity\"])",)))
    # the measure each correction is made to lower: SNUP for the flat field (de Lasarte et
    # al. measure it over the frame), the pixel-scale part for K̂ (local means, eqs. 45-50)
    worse = [r for r in rows if (r.after > r.before if flat_product else
                                 r.local_after > r.local_before)]
    above = [r for r in rows if r.floor is not None and r.local_after > FLOOR_FACTOR * r.floor]
    reasons = [f"{r.frame} ({r.channel}): pixel-scale nonuniformity {r.local_before:.3g} % → "
               f"{r.local_after:.3g} %"
               + (f" (noise floor {r.floor:.3g} %)" if r.floor is not None else "")
               + f", SNUP {r.before:.3g} % → {r.after:.3g} %; {r.changed:,} pixels changed by "
               "more than 1 code" for r in rows]
    reasons += [f"left out: {why}" for why in left_out]
    if worse:
        return Verification(tuple(rows), tuple(left_out), Gate(
            GateStatus.FAIL,
            f"{len(worse)} held-out frame(s) are less uniform after the correction",
            tuple(reasons), ("recalibrate with frames taken under the same settings as these "
                             "frames (gain, offset, temperature)",)))
    if above:
        return Verification(tuple(rows), tuple(left_out), Gate(
            GateStatus.WARN, f"the correction helps, but {len(above)} frame(s) stay above "
                             f"{FLOOR_FACTOR}× the noise floor", tuple(reasons),
            ("more configurations or frames for the maps lower their own noise (sec. V-B)",)))
    return Verification(tuple(rows), tuple(left_out), Gate(
        GateStatus.PASS, "every held-out frame is more uniform after the correction"
                         + (", within 1.5× the noise floor" if any(r.floor for r in rows) else ""),
        tuple(reasons)))


def _spread(items: Sequence[Any], n: int) -> list[Any]:
    """``n`` items spread evenly over ``items`` (first and last included)."""
    idx = np.unique(np.linspace(0, len(items) - 1, n).round().astype(int))
    return [items[i] for i in idx]


# ---------------------------------------------------------------------------------------------
#: the roles of a lab session, whose steps follow the full capture plan
LAB_ROLES = ("ptc", "fixed_pattern")
#: what each missing kind of frame costs, in plain words (:func:`session_plan`)
MISSING: dict[str, str] = {
    "dark": "dark frames (lens capped, at the exposure of the other frames): without them the "
            "dark level is not measured and not removed",
    "ptc": "photon-transfer pairs (two frames of a uniform card at each of several light "
           "levels): without them there is no gain or read noise, so no noise floor for the "
           "checks and no EMVA 1288 figures",
    "pattern": "frames of a uniform card in several positions (role = fixed_pattern) or flats "
               "of a uniform source (role = flat): without them there is no map of each pixel's "
               "sensitivity",
    "bracket": "a bracket of a static scene (role = bracket): without it there is no response "
               "curve, which HDR radiance and a nonlinear camera need",
}


@dataclass(frozen=True)
class SessionPlan:
    """What a session's frames allow: ``kind`` (``"none"`` without a session, ``"empty"``,
    ``"lab"`` with photon-transfer or fixed-pattern frames, ``"flats"``, ``"bracket"``,
    ``"darks"``, ``"change"`` (reference or target frames), ``"scenes"``), the ``steps``
    shown (slugs of :data:`STEPS`, in order), ``lab_plan`` (whether the full capture plan of :mod:`ccdcore.capture` is proposed), a one
    line ``summary`` and ``missing``: what the session lacks and why, in plain words."""

    kind: str
    steps: tuple[str, ...]
    lab_plan: bool
    summary: str
    missing: tuple[str, ...] = ()

    def gate(self) -> Gate:
        """The plan step's gate for a session that gets no lab plan: passes with what the
        frames allow (warns when they allow nothing), the missing frames as reasons."""
        titles = ", ".join(s.title for s in STEPS if s.slug in self.steps
                           and s.slug not in ("plan", "session", "export"))
        status = GateStatus.WARN if self.kind in ("scenes", "empty") else GateStatus.PASS
        nxt = ("declare the frames' roles in a session.toml (docs/session.md), or capture "
               "the frames the missing list names",) if status == GateStatus.WARN else ()
        return Gate(status, self.summary + (f"; the steps its frames allow: {titles}"
                                            if titles else ""), self.missing, nxt)


def session_plan(session: Any) -> SessionPlan:
    """The steps a session's frames allow and what it lacks (:class:`SessionPlan`).

    No session, or a lab session (photon-transfer or fixed-pattern frames: the captures of
    Healey & Kondepudy's lab), gets every step and the full capture plan; a session of flats,
    of a bracket, of darks or of scenes only gets the steps its frames allow -- the flat field
    (pattern, verify) for flats, the response curve and HDR for a bracket -- and is not given
    a lab plan sized from default camera figures."""
    every = tuple(s.slug for s in STEPS)
    if session is None:
        return SessionPlan("none", every, True, "no session loaded: the plan of a full lab "
                                                "calibration, from the camera figures entered")
    roles = session.roles()
    held = ", ".join(f"{n} {r}" for r, n in roles.items()) or "no frames"
    has = {r for r, n in roles.items() if n}
    missing = []
    if "ptc" not in has:
        missing.append(MISSING["ptc"])
    if not has & {"fixed_pattern", "flat"}:
        missing.append(MISSING["pattern"])
    if has & set(LAB_ROLES):
        if "dark" not in has:
            missing.insert(0, MISSING["dark"])
        if "bracket" not in has:
            missing.append(MISSING["bracket"])
        return SessionPlan("lab", every, True, f"a lab session ({held}): the full plan of the "
                                               "captures, from the camera figures entered",
                           tuple(missing))
    steps = ["plan", "session"]
    if "dark" in has and session.camera.layout == Layout.MONO:   # else DL_0 of the flat field
        steps.append("dark")
    if "flat" in has:
        steps += ["pattern", "verify"]
    if "bracket" in has:
        steps.append("response")
    if has & {"dark", "flat", "bracket"}:
        steps.append("export")
    kind = next((k for k, r in (("flats", "flat"), ("bracket", "bracket"), ("darks", "dark"),
                                ("change", "reference"), ("change", "target"),
                                ("scenes", "scene")) if r in has), "empty")
    if kind == "flats":
        if "dark" not in has:
            missing.insert(0, "dark frames: the flat field is made in de Lasarte et al.'s zero "
                              "dark image case (DL_0 = 0), right only when the camera's black "
                              "level is zero")
        if len(session.flat_groups()) < 2:
            missing.append("flats at a second exposure: with one level no held-out flat checks "
                           "the correction (de Lasarte et al.: it should hold across the linear "
                           "range)")
    elif kind == "bracket":
        missing = ["dark frames, photon-transfer pairs and frames of a uniform card: a bracket "
                   "of a scene gives the response curve and HDR radiance only -- its pixels see "
                   "different radiances and each exposure is one frame, so it cannot measure "
                   "the gain, the read noise or each pixel's sensitivity; a full radiometric "
                   "calibration needs a lab session (the plan step without a session lists it)"]
    elif kind in ("scenes", "empty"):
        n = roles.get("scene", 0)
        missing = ([f"{n} frames are read as scenes, a role nothing is calibrated from: if "
                    "they are flats or a bracket, declare their role in a session.toml "
                    "([[frames]] role = \"flat\" or \"bracket\"; a folder without one is read "
                    "by its folder names)"] if n else []) + missing
    summary = {"flats": f"a flat-field session ({held})",
               "bracket": f"an exposure bracket ({held})",
               "darks": f"dark frames only ({held})",
               "scenes": f"nothing to calibrate from ({held})",
               "change": f"frames to compare ({held}): change detection runs on the Change "
                         "detection page and `ccdcore change`; these steps calibrate a camera",
               "empty": "the session holds no frames"}[kind]
    return SessionPlan(kind, tuple(s for s in every if s in steps), False, summary,
                       tuple(missing))
