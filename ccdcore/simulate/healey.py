"""Preset ``healey94``: the monochrome CCD video camera of Healey & Kondepudy (1994).

Simulates, with the camera model of eq. 20 (:class:`~ccdcore.simulate.sensor.SensorModel`), every
capture the paper uses, with parameters close to its Sony XC-77 + frame grabber (sec. VII-A):
A = 0.0034 DN/e, σ_C² ≈ 1.10 DN² (σ_R ≈ 297 e, eq. 27), dark image mean 10.7 DN with spatial std
≈ 0.52 DN, σ_K = 3.7·10⁻³, 8 bits, 1/30 s exposure.

The manifest's ``[camera]`` table states the simulated black level (``black_level``, DN).

With ``nonlinearity`` = a ≠ 0 the camera's conversion is slightly nonlinear, as a real sensor's
is: the analogue signal above the black level, V − b, becomes
(V − b)·(1 + a·(1 − 8x(1 − x))), x = (V − b) over the usable range above the black level
(:func:`ccdcore.simulate.emva.bowl`): the mean deviates from proportionality by ±a, the
photon-transfer variance (which follows the squared slope of the response) by about
2·(1 − 16x + 24x²)·a.  The truth's ``mu`` and ``sigma2_N`` stay those of the linear model
(eq. 41 exactly) and ``truth["nonlinearity"]`` records a; with a = 0 (the default) frames and
truth are unchanged.

Frames written (all ``exposure`` = the fixed exposure time, TIFF, 8-bit unless ``bits`` > 8):

``dark/dark_NNN.tif``  (role ``dark``, ``s`` = ``n_dark`` frames)
    Lens capped, I ≡ 0 (eq. 43).
``ptc/LNN_a.tif``, ``ptc/LNN_b.tif``  (role ``ptc``, ``level`` = 1..P)
    Pairs of a nearly uniform card (reflectance std ``card_reflectance_std``) under a smooth,
    slightly nonuniform illumination (std ``illumination_std``), attenuated by neutral-density
    filters so that the mean levels cover ``ptc_range`` of the usable range (the ADC full scale,
    or the full well if that is lower; sec. IV, VII-A).  With ``saturate_level=True`` one more
    level (P + 1) is written far above the range, so it clips at 2^b − 1 (or at the full well;
    for bad-input tests; flagged ``saturated`` in the truth).
``fixed_pattern/CNN_FMM.tif``  (role ``fixed_pattern``, ``config`` = 1..n1)
    n1 configurations × n2 frames (sec. V-B): for every configuration the card and lamp are moved,
    i.e. a new random card texture with rare outlier spots and a new smooth illumination field, at
    about the same mean level.
``scene/PATCH_LNN.tif``  (role ``scene``, ``level`` = 1..L, ``roi`` = [x, y, w, h], ``patch`` =
``"NAME"``)
    Scene-variation frames (sec. VI, VII-B): each patch is a planar surface of one material that
    fills the field of view (like the 100×100 region inside a painted square of the paper), imaged
    at several neutral-density levels.  The manifest allows one ROI per frame, so we write one frame
    per (patch, level); the ROI is the central region (``scene_margin`` pixels inside the border),
    the same for every frame.  The patch's texture is the same at every level (only the ND filter
    changes), so its scene variation V_S = σ_E²/S² (eq. 57) is the same at every level.
``scene/max_intensity.tif``  (role ``scene``, ``flags`` = ``["max-intensity"]``, no ROI, no patch)
    A uniform card at maximum intensity, for the correction check of sec. VII-A (the paper's 27% of
    pixels changed by more than one quantisation step).

``truth.json`` holds the camera parameters (``A``, ``sigma_c2``, ``read_noise_e``, ``bits``,
``black_level_dn``, ``dark_mean_dn``, ``sigma_K`` ...), per PTC level the true mean μ (eq. 36, dark
included) and the true σ²_N (eq. 35, dark shot noise included; both the pixel average of the exact
per-pixel eqs. 22 and 28, so σ²_N = A·(μ − black) + σ_C² exactly, eq. 41), ``s``, ``n1``, ``n2``, V_S
and ROI per patch, and the true maps ``truth/K.exr`` (K(a, b)) and ``truth/dark.exr`` (expected dark
frame E_DC(a, b)·A + black level, DN), named under ``maps`` and as ``K_map`` / ``dark_map``.

Public objects
--------------
simulate
    Write the session and return the truth dictionary.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CcdError
from ._common import SessionWriter
from .emva import bowl
from .sensor import SensorModel, child_rng, smooth_field

__all__ = ["simulate"]

CAMERA_NAME = "XC-77-like simulated CCD"
DEFAULT_PATCHES: tuple[tuple[str, float], ...] = (("matte_grey", 0.01), ("paper", 0.02),
                                                   ("fabric", 0.04))


@dataclass(frozen=True)
class _NonlinearSensor(SensorModel):
    """The sensor of eq. 20 with the smooth nonlinearity of the module docstring after its
    knee: ``nonlinearity`` a, ``span_dn`` the signal above the black level where x = 1."""

    nonlinearity: float = 0.0
    span_dn: float = 255.0

    def response(self, V: Any) -> np.ndarray:
        S = np.asarray(super().response(V), dtype=float) - self.black_level_dn
        return bowl(S, self.nonlinearity, self.span_dn) + self.black_level_dn


def _check(cond: bool, name: str, problem: str) -> None:
    if not cond:
        raise CcdError(name, problem)


def _ptc_fractions(levels: int | Sequence[float], ptc_range: tuple[float, float]) -> list[float]:
    if isinstance(levels, (int, np.integer)):
        _check(levels >= 2, "levels", f"need at least 2 light levels, got {levels}")
        return [float(f) for f in np.linspace(ptc_range[0], ptc_range[1], int(levels))]
    fr = [float(f) for f in levels]
    _check(len(fr) >= 2 and all(0 < f < 1.5 for f in fr), "levels",
           "give a count >= 2 or a list of at least 2 fractions of the usable range in (0, 1.5)")
    return fr


@dataclass(frozen=True)
class _Rig:
    """The simulated camera as the capture steps use it: its model, drawn K and dark
    electrons, the frame-noise stream (shared by every frame, in capture order), the usable
    range and the session writer's ``add_frame``."""

    model: SensorModel
    K: np.ndarray
    dark_e: np.ndarray
    noise_rng: np.random.Generator
    range_dn: float
    dark_mean_dn: float
    shape: tuple[int, int]
    exposure: float
    add: Callable[..., None]

    def light_e(self, frac: float) -> float:
        """Mean ideal electrons that put the raw frame mean at ``frac`` of the usable range."""
        return max(frac * self.range_dn - self.dark_mean_dn, 0.01 * self.range_dn) / self.model.A

    def expose(self, I: Any) -> np.ndarray:
        return self.model.expose(I, self.K, self.dark_e, self.noise_rng)

    def mean(self, I: Any) -> np.ndarray:
        return self.model.expected_mean(I, self.K, self.dark_e)

    def variance(self, I: Any) -> np.ndarray:
        return self.model.expected_variance(I, self.K, self.dark_e)


def _ptc_levels(rig: _Rig, seed: int, fractions: Sequence[float], ptc_frames: int,
                illumination_std: float, card_reflectance_std: float, saturate_level: bool
                ) -> list[dict[str, Any]]:
    """Photon-transfer frames (sec. IV): ``ptc_frames`` per level of a smooth illumination on
    a textured card; the truth of each level (eqs. 35-36)."""
    model, shape = rig.model, rig.shape
    ptc_field = ((1.0 + smooth_field(shape, child_rng(seed, "ptc_illumination"), illumination_std))
                 * (1.0 + card_reflectance_std * child_rng(seed, "ptc_card").standard_normal(shape)))
    specs = [(f, False) for f in fractions]
    if saturate_level:
        specs.append((1.6, True))
    s_top = max(rig.light_e(f) for f in fractions)
    ptc_truth = []
    for li, (frac, saturated) in enumerate(specs, start=1):
        S = rig.light_e(frac) if not saturated else 1.6 * rig.range_dn / model.A
        I = S * ptc_field
        paths = []
        for k in range(ptc_frames):
            p = f"ptc/L{li:02d}_{chr(97 + k)}.tif"
            rig.add(p, rig.expose(I), role="ptc", level=li, exposure=rig.exposure)
            paths.append(p)
        entry = {"level": li, "nd_transmission": S / s_top, "I_mean_e": float(I.mean()),
                 "mu": float(rig.mean(I).mean()), "sigma2_N": float(rig.variance(I).mean()),
                 "saturated": saturated, "frames": paths}
        if saturated:
            entry["mu_clipped"] = float(model.expected_pixel_mean(I, rig.K, rig.dark_e).mean())
            full = rig.mean(I) >= model.full_scale - 0.5
            if model.full_well_e is not None:
                full |= rig.K * I + rig.dark_e >= model.full_well_e
            entry["clipped_fraction"] = float(np.mean(full))
        ptc_truth.append(entry)
    return ptc_truth


def _fixed_pattern(rig: _Rig, seed: int, n1: int, n2: int, fp_level: float,
                   card_reflectance_std: float, outlier_fraction: float,
                   outlier_contrast: float, illumination_std: float) -> list[float]:
    """Fixed-pattern configurations (sec. V-B): the card and lamp moved between ``n1``
    configurations (a new texture, spots and illumination each), ``n2`` frames each; their
    expected means."""
    shape = rig.shape
    fp_rng = child_rng(seed, "fixed_pattern_scene")
    S_fp = rig.light_e(fp_level)
    fp_means = []
    for c in range(1, n1 + 1):
        refl = 1.0 + card_reflectance_std * fp_rng.standard_normal(shape)
        spots = fp_rng.random(shape) < outlier_fraction
        sign = np.where(fp_rng.random(shape) < 0.5, -1.0, 1.0)
        refl = np.where(spots, refl * (1.0 + sign * outlier_contrast), refl)
        illum = 1.0 + smooth_field(shape, fp_rng, illumination_std)
        I = S_fp * illum * refl
        fp_means.append(float(rig.mean(I).mean()))
        for f in range(n2):
            rig.add(f"fixed_pattern/C{c:02d}_F{f:02d}.tif", rig.expose(I),
                    role="fixed_pattern", config=c, exposure=rig.exposure)
    return fp_means


def _scene_patches(rig: _Rig, seed: int, patches: Sequence[tuple[str, float]],
                   scene_levels: Sequence[float], scene_illumination_std: float, m: int,
                   roi: list[int]) -> list[dict[str, Any]]:
    """Scene patches (sec. VI, VII-B): one frame per (patch, level); each patch's scene
    variation V_S (eq. 57) over the ROI inside the margin ``m``."""
    model, shape = rig.model, rig.shape
    h, w = shape
    sl = (slice(m, h - m), slice(m, w - m))
    scene_rng = child_rng(seed, "scene_patches")
    patch_truth = []
    s_scene_top = max(rig.light_e(f) for f in scene_levels)
    for name, rel_std in patches:
        texture = ((1.0 + float(rel_std) * scene_rng.standard_normal(shape))
                   * (1.0 + smooth_field(shape, scene_rng, scene_illumination_std)))
        tex_roi = texture[sl]
        v_s = float(tex_roi.var(ddof=1) / tex_roi.mean() ** 2)
        frames = []
        for li, frac in enumerate(scene_levels, start=1):
            S = rig.light_e(frac)
            I = S * texture
            p = f"scene/{name}_L{li:02d}.tif"
            rig.add(p, rig.expose(I), role="scene", level=li, exposure=rig.exposure, roi=roi,
                    patch=name)
            frames.append({"level": li, "path": p, "nd_transmission": S / s_scene_top,
                           "mu_D": float(model.A * I[sl].mean()),
                           "mu_raw": float(rig.mean(I)[sl].mean()),
                           "sigma2_N": float(rig.variance(I)[sl].mean())})
        patch_truth.append({"name": name, "roi": roi, "rel_std": float(rel_std), "V_S": v_s,
                            "V_S_model": float((1 + rel_std ** 2)
                                               * (1 + scene_illumination_std ** 2) - 1),
                            "frames": frames})
    return patch_truth


def _max_intensity(rig: _Rig, seed: int, level: float, illumination_std: float
                   ) -> dict[str, Any]:
    """The maximum-intensity frame of the correction check (sec. VII-A) and what dividing by
    K (eq. 51) changes in it."""
    model = rig.model
    I = rig.light_e(level) * (1.0 + smooth_field(
        rig.shape, child_rng(seed, "max_illumination"), illumination_std))
    p = "scene/max_intensity.tif"
    rig.add(p, rig.expose(I), role="scene", exposure=rig.exposure, flags=["max-intensity"])
    change = np.abs(rig.K - 1.0) * I * model.A  # what dividing by K (eq. 51) changes, in DN
    return {"path": p, "mu": float(rig.mean(I).mean()),
            "fraction_changed_gt_1q": float(np.mean(change > model.q)),
            "fraction_changed_gt_2q": float(np.mean(change > 2 * model.q))}


def _check_args(w: int, h: int, n_dark: int, ptc_frames: int, n1: int, n2: int, bits: int,
                A: float, read_noise_e: float, sigma_K: float, scene_margin: int,
                scene_levels: Sequence[float]) -> None:
    """Check :func:`simulate`'s arguments (the PTC levels are checked by
    :func:`_ptc_fractions`)."""
    _check(w >= 8 and h >= 8, "size", f"{w}x{h} is too small; use at least 8x8")
    _check(n_dark >= 1, "n_dark", "need at least one dark frame")
    _check(ptc_frames >= 2, "ptc_frames", "need at least 2 frames per PTC level")
    _check(ptc_frames <= 26, "ptc_frames", "at most 26 frames per PTC level")
    _check(n1 >= 1 and n2 >= 1, "n1/n2", "need at least one configuration and one frame")
    _check(1 <= int(bits) <= 16, "bits", f"bit depth must be 1..16, got {bits}")
    _check(A > 0 and read_noise_e >= 0 and sigma_K >= 0, "A/read_noise_e/sigma_K",
           "A must be positive and the noise parameters non-negative")
    _check(2 * scene_margin < min(w, h) - 2, "size",
           f"{w}x{h} leaves no scene ROI inside the scene margin of {scene_margin} pixels: give "
           f"at least {2 * scene_margin + 3} pixels a side (--size), or a smaller scene_margin")
    _check(len(scene_levels) >= 1 and all(0 < f < 1.5 for f in scene_levels), "scene_levels",
           "give at least one scene level as a fraction of the usable range in (0, 1.5)")


def _camera(out_dir: str | Path, seed: int, shape: tuple[int, int], A: float,
            read_noise_e: float, sigma_K: float, bits: int, black_level_dn: float,
            dark_current_dn: float, dark_std_dn: float, full_well_e: float | None,
            exposure: float, nonlinearity: float = 0.0
            ) -> tuple[SessionWriter, _Rig, np.ndarray]:
    """The camera: its sensor model, drawn K and dark maps and usable range; the session
    writer, the rig the capture steps use and the expected dark frame (DN)."""
    model = SensorModel(A=float(A), read_noise_e=float(read_noise_e),
                        dark_current_e=float(dark_current_dn) / float(A),
                        dark_spatial_std=(float(dark_std_dn) / float(dark_current_dn)
                                          if dark_current_dn > 0 else 0.0),
                        sigma_K=float(sigma_K), bits=int(bits), black_level_dn=float(black_level_dn),
                        full_well_e=None if full_well_e is None else float(full_well_e),
                        q=1.0, exposure_ref=float(exposure))
    fs = model.full_scale
    if nonlinearity:
        span = (float(fs) if model.full_well_e is None else min(
            float(fs), model.full_well_e * model.A + model.black_level_dn)) - model.black_level_dn
        model = _NonlinearSensor(**asdict(model), nonlinearity=float(nonlinearity),
                                 span_dn=span)
    K = model.draw_K(shape, child_rng(seed, "K"))
    dark_e = model.dark_electrons(model.draw_dark_map(shape, child_rng(seed, "dark_map")), exposure)
    dark_dn_map = dark_e * model.A + model.black_level_dn
    # usable range: the ADC's full scale, or the full well if that is reached first
    range_dn = float(fs) if model.full_well_e is None else min(
        float(fs), model.full_well_e * model.A + model.black_level_dn)
    # the simulated camera's electronic offset is known, so the manifest states it ([camera]
    # black_level, DN): the photon-transfer fit then needs no dark-frame estimate of it
    writer = SessionWriter(out_dir, camera={"name": CAMERA_NAME, "bits": int(bits),
                                            "layout": "mono",
                                            "black_level": float(model.black_level_dn)})
    rig = _Rig(model, K, dark_e, child_rng(seed, "frame_noise"), range_dn,
               float(dark_dn_map.mean()), shape, float(exposure), writer.add_frame)
    return writer, rig, dark_dn_map


def _truth(rig: _Rig, dark_dn_map: np.ndarray, seed: int, w: int, h: int, n_dark: int,
           n1: int, n2: int, ptc_truth: list[dict[str, Any]], fp_means: list[float],
           patch_truth: list[dict[str, Any]], max_truth: dict[str, Any] | None,
           card_reflectance_std: float, outlier_fraction: float, outlier_contrast: float,
           illumination_std: float) -> dict[str, Any]:
    """The truth dictionary (module docstring)."""
    model, K, dark_e = rig.model, rig.K, rig.dark_e
    return {
        "preset": "healey94", "seed": int(seed), "size": [w, h],
        "A": model.A, "sigma_c2": model.sigma_c2, "read_noise_e": model.read_noise_e,
        "conversion_gain_e_per_dn": 1.0 / model.A, "q": model.q, "bits": model.bits,
        "full_scale": model.full_scale, "usable_range_dn": rig.range_dn,
        "black_level_dn": model.black_level_dn,
        "full_well_e": model.full_well_e,
        "exposure": rig.exposure,
        "dark_mean_dn": rig.dark_mean_dn, "dark_std_dn": float(dark_dn_map.std()),
        "dark_current_e": float(dark_e.mean()),
        "dark_sigma2_dn": float(model.expected_variance(0.0, K, dark_e).mean()),
        "sigma_K": model.sigma_K, "K_mean": float(K.mean()), "K_std": float(K.std(ddof=1)),
        "s": int(n_dark), "n_dark": int(n_dark), "n1": int(n1), "n2": int(n2),
        "ptc": ptc_truth,
        "fixed_pattern": {"n1": int(n1), "n2": int(n2), "mean_dn": fp_means,
                          "card_reflectance_std": float(card_reflectance_std),
                          "outlier_fraction": float(outlier_fraction),
                          "outlier_contrast": float(outlier_contrast),
                          "illumination_std": float(illumination_std)},
        "scene": {"layout": "one frame per (patch, level); the patch fills the frame; roi in the "
                            "manifest and here; manifest key patch = 'NAME'",
                  "patches": patch_truth},
        "max_intensity": max_truth,
        "K_map": "truth/K.exr", "dark_map": "truth/dark.exr",
        "sensor": model.to_dict(),
        "notes": {"mu": "eq. 36: pixel mean of A(K I + E_DC) + black level",
                  "sigma2_N": "eqs. 35/28: pixel mean of A^2(K I + E_DC) + sigma_c2 "
                              "= A(mu - black) + sigma_c2",
                  "V_S": "eq. 57: sample variance / mean^2 of the ideal irradiance I over the ROI",
                  "dark_map": "expected dark frame E_DC A + black level, DN"},
    }


def simulate(out_dir: str | Path, *, seed: int = 0, size: tuple[int, int] = (128, 96),
             n_dark: int = 16, levels: int | Sequence[float] = 8, ptc_frames: int = 2,
             ptc_range: tuple[float, float] = (0.05, 0.90), n1: int = 12, n2: int = 4,
             A: float = 0.0034, read_noise_e: float = 297.0, sigma_K: float = 3.7e-3,
             bits: int = 8, black_level_dn: float = 0.0, dark_current_dn: float = 10.7,
             dark_std_dn: float = 0.52, full_well_e: float | None = 1.0e5,
             exposure: float = 0.033, illumination_std: float = 0.02,
             card_reflectance_std: float = 0.002, fp_level: float = 0.7,
             outlier_fraction: float = 0.003, outlier_contrast: float = 0.25,
             patches: Sequence[tuple[str, float]] = DEFAULT_PATCHES,
             scene_levels: Sequence[float] = (0.2, 0.35, 0.5, 0.6, 0.7),
             scene_illumination_std: float = 0.003, scene_margin: int = 8,
             max_intensity: float | None = 0.92, saturate_level: bool = False,
             nonlinearity: float = 0.0) -> dict[str, Any]:
    """Write the ``healey94`` session into ``out_dir`` and return its truth.

    Parameters
    ----------
    out_dir
        Session folder (created).
    seed
        Seed; the same seed gives the same bytes.  Streams are derived per purpose
        (:func:`~ccdcore.simulate.sensor.child_rng`).
    size
        ``(width, height)`` in pixels.
    n_dark
        Number s of dark frames (sec. V-A).
    levels
        Number P of PTC light levels (means spread linearly over ``ptc_range`` of the usable
        range), or a list of mean levels as fractions of the usable range (full scale 2^b − 1,
        or the full well times A plus the black level if that is lower).
    ptc_frames
        Frames per PTC level (2 = a pair, eqs. 29–31).
    ptc_range
        Lowest and highest PTC mean level as fractions of the usable range.
    n1, n2
        Fixed-pattern configurations and frames per configuration (sec. V-B).
    A, read_noise_e, sigma_K, bits, black_level_dn, full_well_e
        Camera parameters (see :class:`~ccdcore.simulate.sensor.SensorModel`).
    dark_current_dn, dark_std_dn
        Mean and spatial std of the dark-current signal E_DC·A in DN (paper: 10.74 and 0.555).
    exposure
        Exposure time of every frame, seconds.
    illumination_std
        Relative std of the smooth illumination field of PTC, fixed-pattern and max frames.
    card_reflectance_std
        Relative std of the calibration card's per-pixel reflectance texture.
    fp_level
        Mean level of the fixed-pattern frames as a fraction of the usable range.
    outlier_fraction, outlier_contrast
        Fraction of card pixels that are spots in each fixed-pattern configuration, and their
        relative reflectance change (±).
    patches
        ``(name, relative texture std)`` per scene patch.
    scene_levels
        Mean levels of the scene frames as fractions of the usable range (one frame per patch and
        level).
    scene_illumination_std
        Smooth illumination variation over the scene patches (part of their V_S).
    scene_margin
        Border (pixels) outside the scene ROI.
    max_intensity
        Mean level of the max-intensity frame as a fraction of the usable range; ``None``: no
        such frame.
    saturate_level
        Add one PTC level far above full scale (clipped), for bad-input tests.
    nonlinearity
        a, the amplitude of the smooth deviation of the response (module docstring), a
        fraction: 0.005 is a good camera's few tenths of a percent; 0 (default) linear, frames
        and truth unchanged.  |a| below 0.1.

    Returns
    -------
    dict
        The truth written to ``truth.json`` (see the module docstring).
    """
    w, h = (int(size[0]), int(size[1]))
    _check_args(w, h, n_dark, ptc_frames, n1, n2, bits, A, read_noise_e, sigma_K, scene_margin,
                scene_levels)
    _check(abs(float(nonlinearity)) < 0.1, "nonlinearity",
           "give the amplitude as a fraction below 0.1 (0.005 = 0.5 %)")
    fractions = _ptc_fractions(levels, ptc_range)
    writer, rig, dark_dn_map = _camera(out_dir, seed, (h, w), A, read_noise_e, sigma_K, bits,
                                       black_level_dn, dark_current_dn, dark_std_dn,
                                       full_well_e, exposure, nonlinearity)
    for i in range(n_dark):                     # dark frames (sec. V-A, eq. 43)
        rig.add(f"dark/dark_{i:03d}.tif", rig.expose(0.0), role="dark", exposure=exposure)
    ptc_truth = _ptc_levels(rig, seed, fractions, ptc_frames, illumination_std,
                            card_reflectance_std, saturate_level)
    fp_means = _fixed_pattern(rig, seed, n1, n2, fp_level, card_reflectance_std,
                              outlier_fraction, outlier_contrast, illumination_std)
    m = int(scene_margin)
    roi = [m, m, w - 2 * m, h - 2 * m]
    patch_truth = _scene_patches(rig, seed, patches, scene_levels, scene_illumination_std, m,
                                 roi)
    max_truth = (None if max_intensity is None else
                 _max_intensity(rig, seed, float(max_intensity), illumination_std))

    writer.add_map("truth/K.exr", rig.K, name="K")
    writer.add_map("truth/dark.exr", dark_dn_map, name="dark")
    truth = _truth(rig, dark_dn_map, seed, w, h, n_dark, n1, n2, ptc_truth, fp_means,
                   patch_truth, max_truth, card_reflectance_std, outlier_fraction,
                   outlier_contrast, illumination_std)
    if nonlinearity:
        truth["nonlinearity"] = {
            "amplitude": float(nonlinearity), "span_dn": rig.model.span_dn,
            "model": "b + (V - b)(1 + a (1 - 8 x (1 - x))), x = (V - b) / span_dn",
            "note": "mu and sigma2_N are those of the linear model"}
    return writer.finish(truth, note=f"ccdcore simulate healey94 --seed {int(seed)} --size {w}x{h}")
