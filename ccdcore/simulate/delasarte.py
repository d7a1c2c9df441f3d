"""Preset ``delasarte07``: the 3-CCD colour camera set-up of de Lasarte et al. (2007).

A colour camera with one CCD per channel (layout ``rgb``, 8 bits by default) looks into an
integrating cube that gives a spatially uniform radiance field.  Each channel follows the camera
model of eq. 20 of Healey & Kondepudy (1994) (:class:`~ccdcore.simulate.sensor.SensorModel`) with
its own gain A_c (DN/e) and its own black level set by the camera's offset register.  The spatial
nonuniformity to correct is the true flat field

    F_c(i, j) = V_c(i, j)·K_c(i, j) / ⟨V_c·K_c⟩,

a cos⁴ lens vignetting V_c (optical centre slightly shifted per channel, as the three sensors of a
prism camera are aligned separately) times the per-channel PRNU K_c (mean 1, std ``prnu_std``).
So the expected flat frame is DL_c = b_c + d_c(i, j)·t + S_c·F_c(i, j), with S_c the mean signal
(DN), d_c the dark-current rate and b_c the black level; de Lasarte's gain image
G = (⟨DL_B⟩ − ⟨DL_0⟩)/(DL_B − DL_0) is 1/F_c.  The response is linear up to a soft knee
(``knee_fraction`` of full scale), then saturates and clips at 2^b − 1.

Offset settings (the paper's Table 2), recorded in every frame's manifest entry as
``setting = "NZDI"`` or ``setting = "ZDI"`` (and in the file path, ``nzdi/`` or ``zdi/``), so
:meth:`ccdcore.session.Session.flat_groups` / ``dark_groups(setting=...)`` select them; the
manifest ``gain`` is the camera's gain setting (1.0 = the nominal per-channel gains A_c, the same
for both settings):

``NZDI`` (non-zero dark image)
    offset register 1400: positive black levels (≈ 7–9 DN); the dark image never touches 0.
``ZDI`` (zero dark image)
    offset register 1000: negative black levels (≈ −1.5 to −2.5 DN), so the ADC clips the dark
    image (and the darkest part of dim flats) at zero.

Frames, for each setting (role, manifest keys):

``<setting>/dark_ENN_K.tif``  (``dark``; ``exposure``)
    ``n_dark`` dark frames at every exposure time (dark current grows with exposure).
``<setting>/flat_LN_ENN_K.tif``  (``flat``; ``level`` = radiance level id 1..L, ``exposure``)
    ``n_frames`` frames per (radiance level, exposure); at the base condition ``base`` (inside the
    linear range) ``n_average`` frames, so averages of N = 1, 2, 4, 8 frames can be studied
    (the paper's Table 1).  The largest exposures saturate.

``truth.json``: camera and per-channel parameters (``A``, ``read_noise_e``, ``sigma_c2``,
``black_level_dn`` and ``offset_register`` per setting, ``dark_current_dn_per_s``), radiance levels
and exposure times, the base condition, ``linear_range_dn`` (per setting and channel: the pixel
values in which E[DL] is linear in the signal to within 0.05 DN), ``saturation_dn``, and per frame
its expected spatial mean per channel (``mean_dn``, including clipping; ``mean_dn_linear`` without
knee and clipping), ``in_linear_range`` and ``saturated_fraction``.  Maps: ``truth/flatfield.exr``
(F_c, mean 1 per channel), ``truth/vignetting.exr`` (V_c), ``truth/dark_rate.exr`` (d_c, DN/s),
``truth/dark_NZDI.exr`` and ``truth/dark_ZDI.exr`` (expected dark frame at the base exposure, DN,
including the clip at zero).

Public objects
--------------
simulate
    Write the session and return the truth dictionary.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CcdError
from ._common import SessionWriter
from .sensor import SensorModel, child_rng, clipped_normal_mean

__all__ = ["simulate", "SETTINGS", "CHANNELS"]

CAMERA_NAME = "3-CCD colour camera (de Lasarte-like, simulated)"
CHANNELS = ("R", "G", "B")
#: offset setting -> (offset register value, black level per channel in DN at 8 bits)
SETTINGS: dict[str, tuple[int, tuple[float, float, float]]] = {
    "NZDI": (1400, (8.0, 7.0, 9.0)),
    "ZDI": (1000, (-2.0, -2.5, -1.5)),
}


def _check(cond: bool, name: str, problem: str) -> None:
    if not cond:
        raise CcdError(name, problem)


def _vignetting(shape: tuple[int, int], centre: tuple[float, float], corner: float) -> np.ndarray:
    """cos⁴ falloff cos⁴θ with tanθ = r/f; f puts ``corner`` at the frame corner from the centre.

    Evaluated as cos⁴θ = 1/(1 + r²/f²)² (cos(arctan u) = 1/√(1 + u²)) with
    f² = r_c²·c²/(1 − c²), c = corner^¼ = √√corner (tan(arccos c) = √(1 − c²)/c): basic
    arithmetic only, so the map -- which sets the Poisson means of the flat frames -- has the same
    bits on every CPU (NumPy's vector cos/arctan/power differ in the last bit).
    """
    h, w = shape
    r_corner2 = (w / 2.0) * (w / 2.0) + (h / 2.0) * (h / 2.0)
    c = math.sqrt(math.sqrt(float(corner)))
    f2 = r_corner2 * (c * c) / (1.0 - c * c) if c < 1.0 else math.inf
    y, x = np.mgrid[0:h, 0:w].astype(float)
    dx, dy = x + 0.5 - centre[0], y + 0.5 - centre[1]
    q = 1.0 / (1.0 + (dx * dx + dy * dy) / f2)
    return q * q


def _linear_low(model: SensorModel, tol: float = 0.05) -> float:
    """Smallest expected value (DN) from which clipping at 0 biases E[D] by less than ``tol``."""
    grid = np.linspace(model.black_level_dn, model.full_scale, 4 * model.full_scale + 1)
    grid = grid[grid >= min(model.black_level_dn, 0.0)]
    s = np.sqrt(model.sigma_c2)
    bias = np.abs(clipped_normal_mean(grid, s, 0.0, float(model.full_scale)) - grid)
    ok = np.nonzero(bias < tol)[0]
    return float(max(grid[ok[0]], 0.0)) if ok.size else float(model.full_scale)


@dataclass(frozen=True)
class _Camera:
    """The simulated 3-CCD camera: per-channel gains (DN/e⁻, at the gain setting and bit
    depth), read noise, dark-current rates (DN/s), spatial spreads, bit depth, the 8-bit to
    ``bits`` scale and the response's knee (DN)."""

    A: tuple[float, ...]
    read_noise_e: float
    dark_dn_per_s: tuple[float, ...]
    dark_spatial_std: float
    prnu_std: float
    bits: int
    scale: float
    knee: float

    def model(self, c: int, setting: str) -> SensorModel:
        """Channel ``c``'s sensor at offset ``setting``."""
        a = self.A[c]
        return SensorModel(A=a, read_noise_e=self.read_noise_e,
                           dark_current_e=self.dark_dn_per_s[c] / a,
                           dark_spatial_std=self.dark_spatial_std, sigma_K=self.prnu_std,
                           bits=self.bits, black_level_dn=SETTINGS[setting][1][c] * self.scale,
                           full_well_e=None, q=1.0, exposure_ref=1.0, knee_dn=self.knee)


def _true_maps(cam: _Camera, seed: int, shape: tuple[int, int], centre_jitter: float,
               vignetting_corner: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per channel: the cos⁴ vignetting about a jittered optical centre, the flat field
    F_c = V_c K_c / mean (PRNU K_c) and the dark-current map (electrons per second)."""
    h, w = shape
    geo = child_rng(seed, "vignetting")
    vign = np.empty(shape + (3,))
    flat = np.empty(shape + (3,))
    dark_rate_e = np.empty(shape + (3,))  # dark electrons per second
    for c in range(3):
        m0 = cam.model(c, "NZDI")
        centre = (w / 2.0 + geo.uniform(-1, 1) * centre_jitter * w,
                  h / 2.0 + geo.uniform(-1, 1) * centre_jitter * h)
        vign[..., c] = _vignetting(shape, centre, vignetting_corner)
        K = m0.draw_K(shape, child_rng(seed, f"prnu_{CHANNELS[c]}"))
        vk = vign[..., c] * K
        flat[..., c] = vk / vk.mean()
        dark_rate_e[..., c] = m0.draw_dark_map(shape, child_rng(seed, f"dark_{CHANNELS[c]}"))
    return vign, flat, dark_rate_e


@dataclass
class _Shooter:
    """Exposes and writes the frames, in capture order (one frame-noise stream), and keeps
    each frame's truth."""

    cam: _Camera
    writer: SessionWriter
    flat: np.ndarray
    dark_rate_e: np.ndarray
    noise_rng: np.random.Generator
    levels: list[float]
    signal_dn_per_s: tuple[float, ...]
    linear_low: dict[str, list[float]]
    gain: float
    frames_truth: list[dict[str, Any]] = field(default_factory=list)

    def signal_e(self, c: int, level: float, t: float) -> np.ndarray:
        m = self.cam.model(c, "NZDI")
        return self.signal_dn_per_s[c] * level * t / m.A * self.flat[..., c]

    def shoot(self, relpath: str, setting: str, role: str, t: float,
              level_id: int | None) -> None:
        models = [self.cam.model(c, setting) for c in range(3)]
        level = 0.0 if level_id is None else self.levels[level_id - 1]
        fs = 2 ** self.cam.bits - 1
        chans, mean, mean_lin, lin_ok, sat = [], [], [], True, []
        for c, m in enumerate(models):
            I = self.signal_e(c, level, t)
            d = m.dark_electrons(self.dark_rate_e[..., c], t)
            chans.append(m.expose(I, 1.0, d, self.noise_rng))
            mean.append(float(m.expected_pixel_mean(I, 1.0, d).mean()))
            lin = m.expected_mean(I, 1.0, d)
            mean_lin.append(float(lin.mean()))
            lin_ok = lin_ok and bool(np.all((lin >= self.linear_low[setting][c])
                                            & (lin <= self.cam.knee)))
            sat.append(float(np.mean(m.response(lin) >= fs - 0.5)))
        frame = np.stack(chans, axis=-1)
        self.writer.add_frame(relpath, frame, role=role, level=level_id, exposure=t,
                              gain=self.gain, setting=setting)
        self.frames_truth.append({"path": relpath, "role": role, "setting": setting,
                                  "level": level_id, "exposure": t, "mean_dn": mean,
                                  "mean_dn_linear": mean_lin, "in_linear_range": lin_ok,
                                  "saturated_fraction": sat})


def _truth_maps(writer: SessionWriter, cam: _Camera, settings: Sequence[str], flat: np.ndarray,
                vign: np.ndarray, dark_rate_e: np.ndarray, t_base: float,
                linear_low: dict[str, list[float]]) -> dict[str, Any]:
    """The true maps (flat field, vignetting, dark rate, each setting's dark at the base
    exposure) into ``truth/``, and each setting's truth."""
    writer.add_map("truth/flatfield.exr", flat, name="flatfield")
    writer.add_map("truth/vignetting.exr", vign, name="vignetting")
    writer.add_map("truth/dark_rate.exr",
                   dark_rate_e * np.array([cam.model(c, "NZDI").A for c in range(3)]),
                   name="dark_rate")
    per_setting: dict[str, Any] = {}
    for setting in settings:
        ms = [cam.model(c, setting) for c in range(3)]
        dark_base = np.stack([ms[c].expected_pixel_mean(0.0, 1.0, ms[c].dark_electrons(
            dark_rate_e[..., c], t_base)) for c in range(3)], axis=-1)
        rel = writer.add_map(f"truth/dark_{setting}.exr", dark_base, name=f"dark_{setting}")
        per_setting[setting] = {
            "offset_register": SETTINGS[setting][0],
            "black_level_dn": [m.black_level_dn for m in ms],
            "linear_range_dn": [[linear_low[setting][c], cam.knee] for c in range(3)],
            "dark_map": rel, "dark_map_exposure": t_base,
            "dark_mean_dn_at_base": [float(x) for x in dark_base.reshape(-1, 3).mean(axis=0)],
        }
    return per_setting


def _check_args(w: int, h: int, bits: int, A: Sequence[float],
                signal_dn_per_s: Sequence[float], dark_current_dn_per_s: Sequence[float],
                levels: Sequence[float], exposures: Sequence[float], n_frames: int,
                n_average: int, base: tuple[int, int], n_dark: int, settings: Sequence[str],
                vignetting_corner: float) -> None:
    """Check :func:`simulate`'s arguments."""
    _check(w >= 8 and h >= 8, "size", f"{w}x{h} is too small; use at least 8x8")
    _check(1 <= int(bits) <= 16, "bits", f"bit depth must be 1..16, got {bits}")
    _check(len(A) == 3 and len(signal_dn_per_s) == 3 and len(dark_current_dn_per_s) == 3,
           "A/signal_dn_per_s/dark_current_dn_per_s", "give one value per channel (R, G, B)")
    _check(len(levels) >= 1 and len(exposures) >= 2, "levels/exposures",
           "need at least one radiance level and two exposure times")
    _check(n_frames >= 1 and n_average >= n_frames and n_dark >= 1, "n_frames/n_average/n_dark",
           "need n_frames >= 1, n_average >= n_frames, n_dark >= 1")
    _check(1 <= base[0] <= len(levels) and 1 <= base[1] <= len(exposures), "base",
           f"base condition {tuple(base)} is not a (level id, exposure index) of this session")
    for s in settings:
        _check(s in SETTINGS, "settings", f"unknown offset setting {s!r}; choose NZDI or ZDI")
    _check(0 < vignetting_corner <= 1, "vignetting_corner", "must be in (0, 1]")


def _shoot_session(shooter: _Shooter, settings: Sequence[str], levels: Sequence[float],
                   exposures: Sequence[float], n_dark: int, n_frames: int, n_average: int,
                   base: tuple[int, int]) -> None:
    """Every frame in capture order: per offset setting, the darks at each exposure, then the
    flats of each level and exposure (``n_average`` of them at the base condition)."""
    for setting in settings:                    # darks, then flats, per offset setting
        tag = setting.lower()
        for ei, t in enumerate(exposures, start=1):
            for k in range(n_dark):
                shooter.shoot(f"{tag}/dark_E{ei:02d}_{k}.tif", setting, "dark", t, None)
        for li in range(1, len(levels) + 1):
            for ei, t in enumerate(exposures, start=1):
                n = n_average if (li, ei) == tuple(base) else n_frames
                for k in range(n):
                    shooter.shoot(f"{tag}/flat_L{li}_E{ei:02d}_{k}.tif", setting, "flat", t,
                                  li)


def _truth(cam: _Camera, shooter: _Shooter, seed: int, w: int, h: int,
           exposures: list[float], n_frames: int, n_average: int, n_dark: int,
           base: tuple[int, int], t_base: float, vignetting_corner: float,
           per_setting: dict[str, Any]) -> dict[str, Any]:
    """The truth dictionary (module docstring)."""
    m_nz = [cam.model(c, "NZDI") for c in range(3)]
    flat, levels = shooter.flat, shooter.levels
    fs = 2 ** cam.bits - 1
    return {
        "preset": "delasarte07", "seed": int(seed), "size": [w, h], "bits": cam.bits,
        "layout": "rgb", "channels": list(CHANNELS), "gain_setting": shooter.gain,
        "A": [m.A for m in m_nz], "conversion_gain_e_per_dn": [1.0 / m.A for m in m_nz],
        "read_noise_e": cam.read_noise_e, "sigma_c2": [m.sigma_c2 for m in m_nz],
        "q": 1.0, "full_scale": fs, "saturation_dn": fs, "knee_dn": cam.knee,
        "signal_dn_per_s": list(shooter.signal_dn_per_s),
        "dark_current_dn_per_s": list(cam.dark_dn_per_s),
        "dark_spatial_std": cam.dark_spatial_std, "prnu_std": cam.prnu_std,
        "vignetting_corner": float(vignetting_corner),
        "flatfield_snup": [float(100 * flat[..., c].std() / flat[..., c].mean()) for c in range(3)],
        "radiance_levels": {str(i): v for i, v in enumerate(levels, start=1)},
        "exposures": exposures, "n_frames": int(n_frames), "n_average": int(n_average),
        "n_dark": int(n_dark),
        "base": {"level": int(base[0]), "exposure": t_base},
        "settings": per_setting,
        "setting_key": "manifest key setting = '<NZDI|ZDI>'",
        "flatfield_map": "truth/flatfield.exr",
        "frames": shooter.frames_truth,
        "notes": {"mean_dn": "spatial mean of E[DL] per channel incl. knee and clipping "
                             "(Gaussian approx.)",
                  "mean_dn_linear": "black + A(E_DC + signal): the ideal linear response",
                  "flatfield": "F_c = V_c K_c / mean; de Lasarte's G = 1/F_c",
                  "dark_rate": "dark-current signal per second, DN/s; dark(t) = black + rate*t, "
                               "then clipped at 0"},
    }


def simulate(out_dir: str | Path, *, seed: int = 0, size: tuple[int, int] = (96, 64),
             bits: int = 8, gain: float = 1.0,
             A: Sequence[float] = (0.0125, 0.0100, 0.0150), read_noise_e: float = 60.0,
             signal_dn_per_s: Sequence[float] = (2600.0, 3000.0, 2200.0),
             levels: Sequence[float] = (0.25, 0.5, 1.0),
             exposures: Sequence[float] = (0.005, 0.01, 0.02, 0.04, 0.08, 0.16),
             n_frames: int = 2, n_average: int = 8, base: tuple[int, int] = (3, 4),
             n_dark: int = 4, settings: Sequence[str] = ("NZDI", "ZDI"),
             dark_current_dn_per_s: Sequence[float] = (2.0, 2.0, 2.5),
             dark_spatial_std: float = 0.3, prnu_std: float = 0.01,
             vignetting_corner: float = 0.75, centre_jitter: float = 0.03,
             knee_fraction: float = 0.85) -> dict[str, Any]:
    """Write the ``delasarte07`` session into ``out_dir`` and return its truth.

    Parameters
    ----------
    out_dir
        Session folder (created).
    seed
        Seed; the same seed gives the same bytes.
    size
        ``(width, height)`` in pixels.
    bits
        ADC bit depth; DN-valued parameters below are given for 8 bits and scaled by
        (2^b − 1)/255 (so are the gains A_c).
    gain
        Camera gain setting (multiplies every A_c); written as the frames' ``gain``.
    A
        Per-channel gain in DN per electron at gain 1 (R, G, B).
    read_noise_e
        Read noise σ_R in electrons (all channels).
    signal_dn_per_s
        Mean signal (DN/s) per channel at relative radiance 1.
    levels
        Relative radiance of the uniform field for radiance level ids 1..L.
    exposures
        Exposure times, seconds.
    n_frames
        Flat frames per (level, exposure).
    n_average
        Flat frames at the base condition (for averaging N = 1, 2, 4, 8).
    base
        ``(level id, exposure index 1..)`` of the base correction condition.
    n_dark
        Dark frames per exposure and setting.
    settings
        Offset settings to simulate, among :data:`SETTINGS`.
    dark_current_dn_per_s, dark_spatial_std
        Mean dark-current rate per channel (DN/s) and its relative spatial std.
    prnu_std
        Spatial std of the PRNU K_c (mean 1).
    vignetting_corner
        cos⁴ falloff at the frame corner (relative to the optical centre).
    centre_jitter
        Per-channel shift of the optical centre, as a fraction of the frame size (uniform ±).
    knee_fraction
        Start of the non-linear (saturating) part of the response, fraction of full scale.

    Returns
    -------
    dict
        The truth written to ``truth.json`` (see the module docstring).
    """
    w, h = (int(size[0]), int(size[1]))
    _check_args(w, h, bits, A, signal_dn_per_s, dark_current_dn_per_s, levels, exposures,
                n_frames, n_average, base, n_dark, settings, vignetting_corner)
    shape = (h, w)
    scale = (2 ** int(bits) - 1) / 255.0
    fs = 2 ** int(bits) - 1
    knee = float(knee_fraction) * fs
    exposures = [float(t) for t in exposures]
    levels = [float(v) for v in levels]
    t_base = exposures[base[1] - 1]
    # ---- the camera and its true maps ---------------------------------------------------------
    cam = _Camera(tuple(float(a) * float(gain) * scale for a in A), float(read_noise_e),
                  tuple(float(v) * scale for v in dark_current_dn_per_s), float(dark_spatial_std),
                  float(prnu_std), int(bits), scale, knee)
    vign, flat, dark_rate_e = _true_maps(cam, seed, shape, float(centre_jitter),
                                         float(vignetting_corner))
    linear_low = {st: [_linear_low(cam.model(c, st)) for c in range(3)] for st in settings}
    # ---- shooting the frames ------------------------------------------------------------------
    writer = SessionWriter(out_dir, camera={"name": CAMERA_NAME, "bits": int(bits), "layout": "rgb"})
    shooter = _Shooter(cam, writer, flat, dark_rate_e, child_rng(seed, "frame_noise"), levels,
                       tuple(float(v) * scale for v in signal_dn_per_s), linear_low,
                       float(gain))
    _shoot_session(shooter, settings, levels, exposures, n_dark, n_frames, n_average, base)
    # ---- the truth ----------------------------------------------------------------------------
    per_setting = _truth_maps(writer, cam, settings, flat, vign, dark_rate_e, t_base,
                              linear_low)
    truth = _truth(cam, shooter, seed, w, h, exposures, n_frames, n_average, n_dark, base,
                   t_base, vignetting_corner, per_setting)
    return writer.finish(truth, note=f"ccdcore simulate delasarte07 --seed {int(seed)} --size {w}x{h}")
