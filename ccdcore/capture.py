"""Capture planning before touching the camera: which frames to take, how many, at what exposure.

From the camera's bit depth and a rough noise model (a gain A in DN per electron and a read
noise, from the data sheet or a first short session), :func:`plan_captures` lays out a whole
calibration session, each part sized by the rule of the paper it serves:

dark frames (Healey & Kondepudy 1994, sec. V-A)
    D̂_D averages s dark frames; its error variance σ²_N(dark)/s enters every corrected pixel
    through eq. 46.  s is chosen so that it stays below q²/10, the allowance sec. V-B gives the
    error of K̂ itself: ``s = max(16, ceil(σ²_N(dark) / (0.1 q²)))`` (16: the smallest stack
    on which the hot/dead-pixel rule of sec. V-A is stable).
photon-transfer ladder (eqs. 37–42 and the appendix fit, eqs. 59–67)
    P pairs of frames at mean levels spread evenly from 5 % to 85 % of the usable range (above
    the black level, below full scale, away from the knee); exposures scale linearly from the
    exposure that gives half of full scale.  The predicted standard error of A follows from the
    appendix fit: each level's σ²_N is measured from a difference image of M pixels, so its
    variance is 2σ⁴_N/(M − 1) (the χ² law of a sample variance, eq. 38), and the covariance of
    (A, σ²_C) is (Xᵀ W X)⁻¹ with W = 1/var (eq. 66).
fixed pattern, n1 configurations × n2 frames (sec. V-B)
    n2 from the paper's rule at maximum intensity (:func:`ccdcore.planning.plan_acquisition`).
    n1 needs σ̂, the spread of the slopes m_i over configurations.  Without a pilot capture it
    is predicted from the sensor noise alone: m_i = e_i / ē_i with e_i the average of n2 frames
    less D̂_D, so σ̂² ≈ (σ²_N(μ_K)/n2 + σ²_N(dark)/s) / (μ_K − b0)² at the card level μ_K (75 %
    of full scale).  Card texture and lamp drift add to it; the plan says so and a pilot
    (``fixed_pattern=``) replaces the prediction by the measured σ̂ and worst-case ratio.
flat fields (de Lasarte et al. 2007)
    Exposures a factor 2 apart from 5 % to about 95 % of full scale (the linear range and its
    knee, Fig. 2), each with dark frames at the same exposure; the base exposure is the one
    nearest mid-range, "a mean digital level placed in the linear response range", and takes N
    frames so that their average's temporal noise adds at most ``flat_noise_snup`` (%) to the
    SNUP = 100 σ/mean: ``N = ceil((100 σ_N(μ_B)/(μ_B − b0) / flat_noise_snup)²)``.
exposure bracket (Tsin, Ramesh & Kanade 2001, sec. 3.2 and 4.1)
    Exposures a factor ``bracket_ratio`` apart, from the one that puts the brightest scene point
    at 90 % of full scale to the one that lifts the darkest (``scene_range`` times darker) to
    25 %; at least 5 exposures, so that every code value is seen at several exposures.

Public objects
--------------
CapturePlan
    The plan: every group of frames with its count, exposure and reason; ``checklist()`` (a
    printable Markdown list), ``to_toml()`` (a ``session.toml`` template naming every file to
    capture), ``to_dict()``.
plan_captures(bits, gain, ...)
    The plan from the camera's bit depth and rough noise model.
predicted_gain_error(mu, A, sigma_c2, pixels)
    The standard error of A the photon-transfer fit will reach on a ladder (eq. 66).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from .channels import LAYOUTS, Layout
from .errors import CcdError
from .planning import AcquisitionPlan, plan_acquisition

__all__ = ["CaptureGroup", "CapturePlan", "plan_captures", "predicted_gain_error",
           "MIN_DARKS", "MIN_BRACKET"]

#: the fewest dark frames planned (sec. V-A's hot/dead rule needs a stable per-pixel variance)
MIN_DARKS = 16
#: the fewest exposures of a bracket
MIN_BRACKET = 5
#: the photon-transfer ladder spans this fraction of the usable range (above the black level)
PTC_SPAN = (0.05, 0.85)
#: the fixed-pattern card level, as a fraction of full scale (sec. V-B takes such frames near
#: the top of the range, below the knee)
FP_LEVEL = 0.75


@dataclass(frozen=True)
class CaptureGroup:
    """One kind of frame to capture.

    ``role`` and ``folder`` name the session role and the sub-folder of the files; ``frames``
    lists each file as (relative path, manifest keys); ``why`` says in plain words what the
    group is for and how its size was chosen.
    """

    role: str
    title: str
    why: str
    frames: tuple[tuple[str, dict[str, Any]], ...]
    rule: str = ""

    @property
    def count(self) -> int:
        return len(self.frames)

    def to_dict(self) -> dict[str, Any]:
        return {"role": self.role, "title": self.title, "why": self.why, "rule": self.rule,
                "count": self.count,
                "frames": [{"path": p, **keys} for p, keys in self.frames]}


@dataclass(frozen=True)
class CapturePlan:
    """A whole calibration session to capture (see the module docstring).

    Attributes
    ----------
    camera
        ``name``, ``bits``, ``layout``, ``black_level`` for the manifest's ``[camera]`` table.
    inputs
        The numbers the plan was made from (A, σ²_C, read noise, pixels, exposures ...).
    groups
        Dark, photon-transfer, fixed-pattern, flat-field and bracket groups, in capture order.
    fixed_pattern
        The sec. V-B plan behind the fixed-pattern group.
    gain_rel_err
        The predicted relative standard error of A from the ladder (eq. 66).
    sigma_hat
        σ̂ used for n1 (predicted from the noise model, or measured by a pilot).
    notes
        Assumptions to check at the camera.
    """

    camera: dict[str, Any]
    inputs: dict[str, Any]
    groups: tuple[CaptureGroup, ...]
    fixed_pattern: AcquisitionPlan
    gain_rel_err: float
    sigma_hat: float
    notes: tuple[str, ...] = ()

    @property
    def n_frames(self) -> int:
        return sum(g.count for g in self.groups)

    def group(self, title: str) -> CaptureGroup:
        for g in self.groups:
            if g.title == title:
                return g
        raise KeyError(title)

    def to_dict(self) -> dict[str, Any]:
        return {"camera": dict(self.camera), "inputs": dict(self.inputs),
                "groups": [g.to_dict() for g in self.groups],
                "fixed_pattern": self.fixed_pattern.to_dict(),
                "gain_rel_err": self.gain_rel_err, "sigma_hat": self.sigma_hat,
                "n_frames": self.n_frames, "notes": list(self.notes)}

    def checklist(self) -> str:
        """A printable Markdown checklist: one box per group, its exposures and counts."""
        cam = self.camera
        lines = [f"# Capture checklist: {cam['name'] or 'camera'}", "",
                 f"{cam['bits']}-bit {cam['layout']} camera, A ≈ {self.inputs['A']:.4g} DN/e⁻, "
                 f"σ²_C ≈ {self.inputs['sigma_c2']:.4g} DN²; {self.n_frames} frames in all. "
                 "Keep gain, offset and temperature fixed for the whole session.", ""]
        for g in self.groups:
            exposures = sorted({k["exposure"] for _, k in g.frames if "exposure" in k})
            shown = ", ".join(_fmt_s(t) for t in exposures[:12])
            more = f" … ({len(exposures)} exposures)" if len(exposures) > 12 else ""
            lines.append(f"- [ ] **{g.title}**: {g.count} frames "
                         f"(`{g.frames[0][0].split('/')[0]}/`), exposures {shown}{more}")
            lines.append(f"  {g.why}")
            if g.rule:
                lines.append(f"  Rule: {g.rule}")
        if self.notes:
            lines += ["", "Check at the camera:"] + [f"- {n}" for n in self.notes]
        return "\n".join(lines) + "\n"

    def to_toml(self) -> str:
        """A ``session.toml`` naming every file to capture (``ccdcore session`` then checks the
        captured folder against it)."""
        cam = self.camera
        out = ["# session.toml planned by ccdcore (capture plan); save each frame under the",
               "# path given, then run: ccdcore session <folder>", "schema = 1", "",
               "[camera]", f"name = {_toml_str(cam['name'])}", f"bits = {int(cam['bits'])}",
               f"layout = {_toml_str(cam['layout'])}",
               f"black_level = {float(cam['black_level'])!r}", ""]
        for g in self.groups:
            out.append(f"# {g.title}: {g.count} frames")
            for path, keys in g.frames:
                out.append("[[frames]]")
                out.append(f"path = {_toml_str(path)}")
                out.append(f"role = {_toml_str(g.role)}")
                for k, v in keys.items():
                    out.append(f"{k} = {_toml_value(v)}")
                out.append("")
        return "\n".join(out)


def _toml_str(s: str) -> str:
    return '"' + str(s).replace("\\", "\\\\").replace('"', '\\"') + '"'


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(float(f"{v:.6g}"))
    return _toml_str(v)


def _fmt_s(t: float) -> str:
    return f"{t * 1e3:.4g} ms" if t < 1 else f"{t:.4g} s"


def predicted_gain_error(mu: Sequence[float], A: float, sigma_c2: float, pixels: int,
                         black_level: float = 0.0) -> float:
    """The standard error of A that the appendix fit (eqs. 59–67) reaches on the levels ``mu``.

    Each level's σ²_N = A(μ − b0) + σ²_C (eq. 41) is measured from a difference image of
    ``pixels`` pixels (eq. 38), a sample variance with variance 2σ⁴_N/(M − 1); the weighted
    fit's covariance is (Xᵀ W X)⁻¹ with W = diag(1/var) (eq. 66).
    """
    m = np.asarray(mu, dtype=np.float64) - float(black_level)
    if m.size < 2 or pixels < 2:
        raise CcdError("ptc", "the fit needs at least two levels and two pixels")
    s2 = A * m + sigma_c2
    w = (pixels - 1) / (2.0 * s2 ** 2)
    X = np.column_stack([m, np.ones_like(m)])
    cov = np.linalg.inv(X.T @ (w[:, None] * X))
    return float(math.sqrt(cov[0, 0]))


def _ceil(x: float) -> int:
    return int(math.ceil(x - 1e-9))


def _exposure(level_dn: float, full: float, b0: float, t_half: float) -> float:
    """Exposure that gives ``level_dn`` when ``t_half`` gives half of full scale (linear)."""
    return float(f"{t_half * (level_dn - b0) / (0.5 * full - b0):.4g}")


def plan_captures(bits: int, gain: float, *, read_noise_e: float | None = None,
                  sigma_c2: float | None = None, black_level: float = 0.0,
                  pixels: int = 256 * 192, layout: str = "mono", name: str = "",
                  exposure_half: float = 0.01, ptc_levels: int = 8, p: float = 1.5,
                  fixed_pattern: Any = None, flat_noise_snup: float = 0.3,
                  scene_range: float = 100.0, bracket_ratio: float = math.sqrt(2.0),
                  ext: str = "tif") -> CapturePlan:
    """Plan a calibration session (see the module docstring for each rule).

    Parameters
    ----------
    bits
        ADC bit depth b (full scale 2^b − 1 DN, q = 1 DN).
    gain
        A, DN per electron (a data-sheet value or a first photon-transfer estimate).
    read_noise_e, sigma_c2
        The read noise σ_R in electrons, or σ²_C in DN² directly (eq. 27: σ²_C = A²σ²_R +
        q²/12); one of them.
    black_level
        b0, the electronic offset in DN.
    pixels
        Pixels in the region the photon-transfer statistics use (for the predicted error of A).
    exposure_half
        Exposure (s) that gives about half of full scale under the lamp used for the ladder, the
        flats and the card.
    ptc_levels
        Light levels P of the photon-transfer ladder (at least 3).
    fixed_pattern
        A pilot :class:`~ccdcore.fixedpattern.FixedPattern`: its measured σ̂ and worst-case ratio
        replace the predicted ones.
    flat_noise_snup
        SNUP (%) the base flat's temporal noise may add.
    scene_range, bracket_ratio
        Radiance ratio of the bracketed scene (brightest/darkest) and the exposure factor between
        bracket frames.

    Raises
    ------
    CcdError
        Non-physical inputs, naming the one at fault.
    """
    sensor = _Sensor.checked(bits, gain, read_noise_e, sigma_c2, black_level, exposure_half,
                             ext)
    if ptc_levels < 3:
        raise CcdError("ptc_levels", f"the photon-transfer fit needs at least 3 levels, got "
                                     f"{ptc_levels}")
    if not scene_range > 1 or not bracket_ratio > 1 or not flat_noise_snup > 0 or pixels < 2:
        raise CcdError("plan", "exposure, flat-field noise and pixel count must be positive, "
                               "scene range and bracket ratio above 1")
    if layout not in LAYOUTS:
        raise CcdError("layout", f"unknown layout {layout!r}")

    notes: list[str] = []
    dark, s = _dark_group(sensor)
    ptc, a_err = _ptc_group(sensor, ptc_levels, pixels)
    fp, fp_plan, sigma_hat = _fixed_pattern_group(sensor, s, p, fixed_pattern, notes)
    flats = _flat_groups(sensor, flat_noise_snup)
    bracket = _bracket_group(sensor, scene_range, bracket_ratio)
    notes.append(f"exposures assume {_fmt_s(exposure_half)} gives about half of full scale "
                 "under your lamp (and that the bracket's brightest point is as bright as the "
                 "card); scale them all if it does not")
    if layout != Layout.MONO:
        notes.append(f"{layout} camera: the dark reference and K̂ of Healey & Kondepudy are made "
                     "for mono frames; the flat field's DL_0 serves instead")

    camera = {"name": name, "bits": sensor.bits, "layout": layout, "black_level": sensor.b0}
    inputs = {"A": sensor.gain, "sigma_c2": sensor.sigma_c2, "read_noise_e":
              None if read_noise_e is None else float(read_noise_e), "bits": sensor.bits,
              "black_level": sensor.b0, "pixels": int(pixels),
              "exposure_half": float(exposure_half), "ptc_levels": int(ptc_levels),
              "p": float(p), "flat_noise_snup": float(flat_noise_snup),
              "scene_range": float(scene_range), "bracket_ratio": float(bracket_ratio)}
    return CapturePlan(camera=camera, inputs=inputs, groups=(dark, ptc, fp, *flats, bracket),
                       fixed_pattern=fp_plan, gain_rel_err=a_err / sensor.gain,
                       sigma_hat=sigma_hat, notes=tuple(notes))


@dataclass(frozen=True)
class _Sensor:
    """What every group's rule needs of the camera and the lamp: bit depth, full scale, black
    level b0, gain A, σ²_C, the exposure giving half of full scale, the frames' extension."""

    bits: int
    full: float
    b0: float
    gain: float
    sigma_c2: float
    exposure_half: float
    ext: str

    @classmethod
    def checked(cls, bits: Any, gain: float, read_noise_e: float | None,
                sigma_c2: float | None, black_level: float, exposure_half: float, ext: str
                ) -> "_Sensor":
        """The sensor of :func:`plan_captures`'s arguments (:class:`CcdError` naming the one
        at fault)."""
        if not isinstance(bits, (int, np.integer)) or not 1 <= int(bits) <= 32:
            raise CcdError("bits", f"the bit depth must be 1..32, got {bits!r}")
        full = float(2 ** int(bits) - 1)
        if not (math.isfinite(gain) and gain > 0):
            raise CcdError("gain", f"the gain A (DN per electron) must be positive, got {gain!r}")
        if sigma_c2 is None:
            if read_noise_e is None or not (read_noise_e >= 0):
                raise CcdError("read noise", "give the read noise in electrons (≥ 0) or σ²_C in "
                                             "DN²")
            sigma_c2 = (gain * read_noise_e) ** 2 + 1.0 / 12.0
        if not (math.isfinite(sigma_c2) and sigma_c2 > 0):
            raise CcdError("sigma_c2", f"σ²_C must be positive, got {sigma_c2!r}")
        b0 = float(black_level)
        if not 0 <= b0 < 0.5 * full:
            raise CcdError("black_level", f"the black level must lie in [0, {0.5 * full:g}) DN, "
                                          f"got {black_level!r}")
        if not exposure_half > 0:
            raise CcdError("plan", "exposure, flat-field noise and pixel count must be positive, "
                                   "scene range and bracket ratio above 1")
        return cls(int(bits), full, b0, float(gain), float(sigma_c2), float(exposure_half), ext)

    def noise(self, mu: float) -> float:
        """σ²_N at mean μ: eq. 41 with the black level removed."""
        return self.gain * max(mu - self.b0, 0.0) + self.sigma_c2

    def level(self, fraction: float) -> float:
        """The mean (DN) at ``fraction`` of the range above the black level."""
        return self.b0 + fraction * (self.full - self.b0)

    def exposure(self, level_dn: float) -> float:
        return _exposure(level_dn, self.full, self.b0, self.exposure_half)


def _dark_group(sensor: _Sensor) -> tuple[CaptureGroup, int]:
    """The dark frames of the dark reference (sec. V-A) and their count s."""
    s_rule = sensor.noise(sensor.b0) / 0.1
    s = max(MIN_DARKS, _ceil(s_rule))
    t_fp = sensor.exposure(sensor.level(FP_LEVEL))
    return CaptureGroup(
        "dark", "Dark frames",
        "Lens capped, at the fixed-pattern exposure: the dark reference D̂_D and its hot and "
        "dead pixels (sec. V-A).",
        tuple((f"dark/dark_{i:03d}.{sensor.ext}", {"exposure": t_fp}) for i in range(s)),
        f"σ²_N(dark)/s ≤ q²/10 with σ²_N(dark) = σ²_C = {sensor.sigma_c2:.4g} DN² gives "
        f"s ≥ {s_rule:.3g}; at least {MIN_DARKS}"), s


def _ptc_group(sensor: _Sensor, ptc_levels: int, pixels: int) -> tuple[CaptureGroup, float]:
    """The photon-transfer ladder (eqs. 37–42) and the predicted error of A (eq. 66)."""
    pad = len(str(max(ptc_levels, 99)))
    fr = np.linspace(PTC_SPAN[0], PTC_SPAN[1], ptc_levels)
    mus = sensor.b0 + fr * (sensor.full - sensor.b0)
    a_err = predicted_gain_error(mus, sensor.gain, sensor.sigma_c2, pixels, sensor.b0)
    ptc = []
    for k, mu in enumerate(mus, start=1):
        t = sensor.exposure(mu)
        for side in "ab":
            ptc.append((f"ptc/L{k:0{pad}d}_{side}.{sensor.ext}", {"level": k, "exposure": t}))
    return CaptureGroup(
        "ptc", "Photon transfer pairs",
        f"Two frames per level at {ptc_levels} levels from {fr[0]:.0%} to {fr[-1]:.0%} of the "
        "range above the black level: the noise model A, σ²_C (eqs. 37–42). Same lamp, change "
        "only the exposure (or a neutral filter).",
        tuple(ptc),
        f"predicted σ(A)/A = {a_err / sensor.gain:.2%} over {pixels:,} pixels (eq. 66 with "
        "var σ²_N = 2σ⁴_N/(M − 1))"), a_err


def _fixed_pattern_group(sensor: _Sensor, s: int, p: float, fixed_pattern: Any,
                         notes: list[str]) -> tuple[CaptureGroup, Any, float]:
    """The fixed-pattern configurations (eqs. 45–50): n2 first, then n1 from σ̂ (sec. V-B);
    the plan of :func:`plan_acquisition` and σ̂ (measured by a pilot, else predicted)."""
    b0, gain, sigma_c2, bits = sensor.b0, sensor.gain, sensor.sigma_c2, sensor.bits
    mu_k = sensor.level(FP_LEVEL)
    t_fp = sensor.exposure(mu_k)
    n2_plan = plan_acquisition(gain, sigma_c2, bits, sigma_hat=0.0, black_level=b0, s=s,
                               dark_level=b0)
    n2 = n2_plan.n2_required
    if fixed_pattern is not None:
        sigma_hat = float(fixed_pattern.sigma_hat)
        notes.append(f"σ̂ = {sigma_hat:.4g} measured by the pilot fixed-pattern capture")
    else:
        sigma_hat = math.sqrt(sensor.noise(mu_k) / n2 + sensor.noise(b0) / s) / (mu_k - b0)
        notes.append(f"σ̂ = {sigma_hat:.4g} predicted from the sensor noise alone (card level "
                     f"{mu_k:.0f} DN, n2 = {n2}, s = {s}); card texture and lamp drift add to "
                     "it: capture 3 configurations first and plan again from them")
    fp_plan = plan_acquisition(gain, sigma_c2, bits, sigma_hat=sigma_hat, p=p, black_level=b0,
                               fixed_pattern=fixed_pattern, s=s, dark_level=b0)
    n1 = fp_plan.n1_required
    cpad = len(str(max(n1, 9)))
    fpad = len(str(max(n2 - 1, 9)))
    group = CaptureGroup(
        "fixed_pattern", "Fixed-pattern configurations",
        f"A uniform card at about {FP_LEVEL:.0%} of full scale: {n1} configurations (move card "
        f"and lamp between them) × {n2} frames each: the fixed-pattern map K̂ (eqs. 45–50).",
        tuple((f"fixed_pattern/c{c:0{cpad}d}_{j:0{fpad}d}.{sensor.ext}",
               {"config": c, "exposure": t_fp})
              for c in range(1, n1 + 1) for j in range(n2)),
        f"{fp_plan.n1_formula}; {fp_plan.n2_formula}")
    return group, fp_plan, sigma_hat


def _flat_groups(sensor: _Sensor, flat_noise_snup: float) -> tuple[CaptureGroup, CaptureGroup]:
    """The flat fields of de Lasarte et al. (2007) at exposures a factor 2 apart up to the knee,
    the base one averaged to ``flat_noise_snup``, and their dark frames (DL_0)."""
    b0, full, ext = sensor.b0, sensor.full, sensor.ext
    t_lo = sensor.exposure(sensor.level(0.05))
    flat_t = [t_lo * 2 ** k for k in range(12)]
    flat_t = [float(f"{t:.4g}") for t in flat_t
              if b0 + (full - b0) * 0.05 * (t / t_lo) <= b0 + 0.95 * (full - b0) * 1.0001]
    levels = [b0 + 0.05 * (full - b0) * t / t_lo for t in flat_t]
    base = int(np.argmin([abs(m - sensor.level(0.5)) for m in levels]))
    mu_b = levels[base]
    snup_one = 100.0 * math.sqrt(sensor.noise(mu_b)) / (mu_b - b0)
    n_base = max(2, _ceil((snup_one / flat_noise_snup) ** 2))
    flats: list[tuple[str, dict[str, Any]]] = []
    flat_darks: list[tuple[str, dict[str, Any]]] = []
    for e, t in enumerate(flat_t, start=1):
        n = n_base if e - 1 == base else 2
        flats += [(f"flat/flat_E{e:02d}_{j:02d}.{ext}", {"level": 1, "exposure": t})
                  for j in range(n)]
        flat_darks += [(f"flat_dark/dark_E{e:02d}_{j}.{ext}", {"exposure": t}) for j in range(4)]
    return CaptureGroup(
        "flat", "Flat fields",
        f"A uniform source (integrating sphere or diffuser) at {len(flat_t)} exposures a factor "
        f"2 apart, up to the knee: the linear range and the G/O correction maps. The base "
        f"exposure {_fmt_s(flat_t[base])} (≈ {mu_b:.0f} DN, mid-range) gets {n_base} frames.",
        tuple(flats),
        f"100·σ_N/μ = {snup_one:.3g} % per frame at the base; N = ceil(({snup_one:.3g}/"
        f"{flat_noise_snup:g})²) = {n_base} keeps the average's noise ≤ {flat_noise_snup:g} % "
        "SNUP"), CaptureGroup(
        "dark", "Flat-field dark frames",
        "Lens capped, 4 at each flat exposure: DL_0 of the correction (de Lasarte et al.).",
        tuple(flat_darks))


def _bracket_group(sensor: _Sensor, scene_range: float, bracket_ratio: float) -> CaptureGroup:
    """The exposure bracket of Tsin et al. (2001): the brightest point at 90 % in the first
    frame, a point ``scene_range`` times darker at 25 % in the last."""
    span = 0.25 * scene_range / 0.9
    n_br = max(MIN_BRACKET, _ceil(math.log(span) / math.log(bracket_ratio)) + 1)
    t0 = sensor.exposure_half * 0.9 / 0.5     # the brightest point taken as bright as the card
    bracket = [(f"bracket/b_{k:02d}.{sensor.ext}",
                {"exposure": float(f"{t0 * bracket_ratio ** k:.6g}"), "stack": 0})
               for k in range(n_br)]
    return CaptureGroup(
        "bracket", "Exposure bracket",
        f"A static scene on a tripod, {n_br} exposures a factor {bracket_ratio:.3g} apart: the "
        "inverse response g, its noise terms and HDR radiance (Tsin et al. sec. 3.2). Fix "
        "white balance, gain and aperture; change only the exposure time.",
        tuple(bracket),
        f"the brightest point at 90 % in the first frame, a point {scene_range:g}× darker at "
        f"25 % in the last: {span:.3g}× in exposure, at least {MIN_BRACKET} frames")
