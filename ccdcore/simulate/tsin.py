"""Preset ``tsin01``: the imaging pipeline of Tsin, Ramesh & Kanade (2001), eq. 3.

Each exposure ``k`` of a static scene with radiance ``E(x)`` is imaged as (eq. 3)::

    z_k(x) = f(a_k E(x) + N_s + N_c1 + b_k) + N_c2

with the camera response ``f`` (its inverse ``g = f^-1`` is the *response function* the estimators
recover), the white-balance scale ``a_k = t_k w_k`` (nominal exposure time ``t_k`` times a
white-balance gain ``w_k``) and offset ``b_k`` (eq. 2), shot noise ``N_s``, thermal noise ``N_c1``
and the output noise ``N_c2`` (amplifier, A/D), then quantised to 8 bits with clipping.

The defaults follow the simulation protocol of sec. 4.1: ``N = 8`` exposures with ratio ``sqrt 2``
between consecutive ones, ``g(z) = (z / 255) ** 1.2`` so ``f(v) = 255 v ** (1 / 1.2)`` on
``[0, 1]``, radiance ``E`` uniform on ``[0, 1]`` per pixel (per channel for colour), and noise
``sigma_s = 0.015``, ``sigma_c1 = 0.01`` (both in units of ``g``, i.e. of ``aE + b``) and
``sigma_c2 = 1`` DN.

Modelling choices (all recorded in ``truth.json``)
--------------------------------------------------
Shot noise.  Eq. 7 as extracted reads ``sigma^2 = a^2 E^2 + ...``, but sec. 2 says the shot-noise
variance "is proportional to Et", and the paper's own remark in sec. 4.1 ("when calibrated
``aE ~ g(z)``; if ``g(z)`` has a similar form as ``g'(z)^2`` it is not easy to discriminate the
contributions of ``sigma_s^2`` and ``sigma_c2^2``") only holds if the shot term is linear in the
signal.  Photon counting is Poisson, whose variance equals its mean.  We therefore draw
``N_s ~ Normal(0, sigma_s^2 a_k E)``, so that the noise variance of eq. 7 becomes::

    sigma^2(a, z) = sigma_s^2 a E + sigma_c1^2 + g'(z)^2 sigma_c2^2      (eq. 7, linear shot term)

Consequence: the shot-noise standard deviation grows as ``sqrt(aE)`` (``sigma_s`` is the shot
standard deviation at full scale ``aE = 1``), not proportionally to ``aE`` as the extracted
``a^2 E^2`` would give; relative noise falls with signal, and an estimator fitting eq. 17 must use
the linear form to recover ``sigma_s``.

Exposure times.  ``t_k = t_max ratio^(k - N + 1)``, ``k = 0 .. N-1``; with the defaults
``t_max = sqrt 2`` this is ``t_k = 2^(-3) sqrt(2)^k = 0.125 ... 1.414``: the shortest image maps the
brightest pixel (``E = 1``) to ``g = 0.125`` (z ~ 45), the second-longest puts it exactly at full
scale and the longest saturates every pixel with ``E > 1/sqrt 2`` (29 % of them), so the bracket
runs from dark to saturated as the paper's 8-exposure sequence implies.

White balance.  Off by default (``a_k = t_k``, ``b_k = 0``, the paper's first experiment).  With
``white_balance=True`` (second experiment) ``w_k ~ Normal(1, 0.05)`` per image (per image and
channel for colour) and ``b_k ~ Normal(0, offset_sigma)``, except that ``b`` of the first image is
0: the offsets are only defined up to ``b_k + c a_k`` and sec. 3.2 fixes one of them.

Full well, quantisation.  The signal ``v = aE + N_s + N_c1 + b`` saturates at ``v = 1`` (the top of
``f``'s domain); a site at full scale reads 255 (the camera's white clip: ``N_c2`` does not pull a
saturated pixel below 255).  Elsewhere ``z = clip(round(f(v) + N_c2), 0, 255)``, so the output
noise seen in the data is ``sigma_c2^2 + 1/12`` DN^2 (rounding adds 1/12).

Colour and Bayer.  ``layout="rgb"`` draws an independent ``E`` per channel.  ``bayer="rggb"`` (or
another pattern) samples ``E`` through the colour filter array, adds the noise per *sensor site*,
applies white balance per colour and interpolates bilinearly (:func:`ccdcore.channels.demosaic_bilinear`)
before ``f`` -- the paper's camera.  Interpolated pixels then carry averaged, spatially correlated
noise, and the noise-free image obeys eq. 5 with the *effective* radiance
``demosaic(mosaic(E))``, written as ``truth/E_effective.exr`` next to the scene ``truth/E.exr``.

Blooming.  With ``blooming=True`` the charge above full well at a saturated site spills evenly onto
the sites within radius ``r = 3`` (sec. 2 removes "pixels surrounding a saturated pixel within a
certain radius ... usually 3 pixels").  Per image a label mask is written
(``truth/bloom_s<j>_k<kk>.png``: 0 clean, 1 contaminated = within ``r`` of a saturated site,
2 saturated).  For Bayer output the contamination is widened by the 3x3 interpolation support.

Camera model (beyond sec. 4.1).  Real brackets -- 8-bit JPEGs of a demosaicing, tone-mapping,
sharpening, compressing camera -- differ from the protocol where it matters for response
estimation; these options (:mod:`ccdcore.simulate.camera`, ``docs/camera_simulation.md``) model
it.  At their defaults the session is the protocol's, byte for byte, and ``truth.json`` has none
of the keys below.

* ``tone``: ``"gamma"`` (``g = (z/255)^gamma``) or ``"srgb-knee"``, an sRGB-like curve with a
  linear toe and a highlight shoulder (``tone_gamma`` 2.4, ``toe`` 0.01, ``knee`` 0.8,
  ``headroom`` 2), analytic both ways: ``truth.json``'s ``g`` is its exact inverse on the codes,
  ``tone`` its parameters.
* ``scene``: ``"uniform"`` (iid, sec. 4.1) or ``"structured"`` (smooth log-normal field,
  piecewise-constant patches with hard edges, a few very bright lights with a glow; drawn from its
  own random stream; described in ``truth.json``'s ``scene``); ``vignetting`` ``s``: ``E`` times
  ``1 / (1 + s rho^2)^2`` (``truth/vignetting.exr``; ``truth/E.exr`` is the vignetted irradiance).
* ``exposure_error``: the actual exposure is ``t_k exp(sigma N(0, 1))`` (own stream), recorded in
  ``a`` (``a_k = t_k x factor_k x w_kc``) and in ``exposure_factor``.
* ``listed_step_factors``: the listed exposures are wrong for part of the bracket, as on real
  cameras whose shutter did not change for a few steps.  A mapping from the neighbour-pair index
  ``p`` (frames ``p`` and ``p + 1`` in increasing listed exposure) to the factor ``f_p`` by which
  that pair's true exposure ratio differs from the listed one (``{4: 0.5, 5: 0.5}``: pairs 4 and 5
  are truly ratio 1, not 2, on a one-stop bracket).  The manifest keeps the listed ``t_k``; frame
  ``k`` is exposed ``c_k t_k`` with ``c_0 = 1``, ``c_(k+1) = c_k f_k``
  (:func:`camera.listed_steps`): the frames before the first wrong pair are as listed, the later
  ones shorter (for ``f < 1``).  ``c_k`` multiplies the lognormal factor in ``exposure_factor`` and
  ``a``; ``truth.json`` also holds ``listed_step_factors`` (every pair's ``f_p``),
  ``listed_step_cumulative`` (``c_k``) and ``true_exposure`` (``t_k x exposure_factor_k``, per
  stack, and in each frame entry).
* ``black_level``: a pedestal added to ``v`` in every frame (recorded in ``b``).
* ``sharpen``: unsharp mask ``y + s (y - G_1px * y)`` of ``f(v)`` (DN) before ``N_c2``.
* ``jpeg_quality``: a deterministic baseline-JPEG round trip of the 8-bit frame (YCbCr 4:2:0, 8x8
  DCT, IJG tables).
* ``camera``: an option bundle, ``"real"`` (:data:`camera.CAMERAS`: 10 frames one stop apart,
  Bayer RGGB, all of the above but ``listed_step_factors``, per-frame white balance) or
  ``"real-listed-wrong"`` (the same camera, 12 frames listed one stop apart of which pairs 4 .. 7
  are truly ratio 1); explicit options override it.  The preset ``tsin01-camera`` is
  ``camera="real"``.

With any of them set, ``truth.json`` also holds ``camera_model`` (the bundle, every option's value,
the pipeline), ``tone``, ``scene``, ``vignetting``, ``exposure_error``, ``exposure_factor``,
``black_level``, ``sharpen`` and ``jpeg``, and each frame its ``exposure_factor``.

Handheld bracket (:mod:`ccdcore.simulate.handheld`, off by default).  ``handheld_shift`` (px)
and ``handheld_rotation`` (degrees) are the standard deviations of each frame's shift and
rotation against the middle frame ``n // 2`` (exactly still); ``movers`` objects of height
``mover_size`` x H cross the scene at ``mover_speed`` px per frame.  The motion applies to the
scene radiance (rendered with a margin, ``truth/scene_margin.exr``), before vignetting and the
camera.  ``truth.json`` then holds ``transforms`` (per frame file; the convention in
``handheld.convention``: content at reference pixel ``p`` appears at ``c + R(theta)(p - c) +
(dx, dy)``, so ``aligned(x, y) = frame(x + dx, y + dy)``), ``handheld`` and ``movers`` (masks in
``truth/movers.npy``, ``truth/movers_aligned.npy``, ``truth/moving_mask.npy``).

Reproducibility.  The same seed gives the same bytes whatever the CPU's vector features: ``f`` uses
the CPU-independent ``pow`` of :mod:`ccdcore.simulate._det` (NumPy's vector ``power`` differs in the
last bit between AVX2 and AVX-512, which could flip a rounded digital number), blooming sums shifted
arrays, and the bilinear interpolation's weights (1/4, 1/2, 1) are powers of two, so its products
are exact; the camera model uses the same means (its JPEG is plain IEEE arithmetic, not
libjpeg).  The ``g`` of ``truth.json`` is computed with the C library's scalar ``pow``
(:func:`response_table`) and written with all its digits; the other floats of ``truth.json`` carry
12 significant digits.

Public objects
--------------
DEFAULTS
    Default options of :func:`simulate`.
CAMERA_OPTIONS
    The options of the camera model (off at their defaults).
Exposure
    One simulated frame: ``z`` (uint8), the signal ``v`` entering ``f``, blooming labels.
inverse_response(z, gamma), response(v, gamma)
    ``g(z) = (z/255)^gamma`` and ``f(v) = 255 clip(v, 0, 1)^(1/gamma)``.
response_table(gamma)
    ``g(0) .. g(255)`` as written to ``truth.json`` (scalar ``pow``, the same on every CPU).
exposure_times(n, ratio, t_max)
    Nominal exposure times ``t_k`` of the bracket.
white_balance(t, rng, ...)
    Draw ``a_k = t_k w_k`` and ``b_k``.
uniform_radiance(rng, shape)
    ``E`` uniform on ``[0, 1]`` (float32).
effective_radiance(E, bayer)
    ``demosaic(mosaic(E))`` for a Bayer camera, ``E`` otherwise.
expose(E, a, b, rng, ...)
    Image one exposure through the pipeline of eq. 3 (and the camera's tone, sharpening, JPEG).
bloom_kernel(radius)
    Disk footprint of the blooming neighbourhood.
SHOT_NOISE_NOTE, QUANTISATION_NOTE
    The modelling notes recorded in ``truth.json``.
simulate(out_dir, *, seed, size, **options)
    Write the ``tsin01`` session and its ``truth.json``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from .. import channels
from ..errors import CcdError
from ..io.frames import write_image
from . import _det
from . import camera as _cam
from . import handheld as _hh
from ._common import TRUTH_DIGITS, SessionWriter, round_sig

__all__ = ["DEFAULTS", "CAMERA_OPTIONS", "Exposure", "inverse_response", "response",
           "response_table", "exposure_times",
           "white_balance", "uniform_radiance", "effective_radiance", "expose", "bloom_kernel",
           "simulate", "SHOT_NOISE_NOTE", "QUANTISATION_NOTE"]

#: default options of :func:`simulate` (sec. 4.1 of Tsin et al. 2001)
DEFAULTS: dict[str, Any] = {
    "n_exposures": 8,
    "ratio": math.sqrt(2.0),
    "t_max": math.sqrt(2.0),
    "gamma": 1.2,
    "sigma_s": 0.015,
    "sigma_c1": 0.01,
    "sigma_c2": 1.0,
    "white_balance": False,
    "wb_sigma": 0.05,
    "offset_sigma": 0.01,
    "layout": "mono",
    "bayer": None,
    "blooming": False,
    "bloom_radius": 3,
    "bloom_strength": 1.0,
    "n_stacks": 1,
    "radiance": None,
    # camera-model options (camera.py); at these values the sec. 4.1 protocol is unchanged
    "camera": None,
    "tone": "gamma",
    "tone_gamma": 2.4,
    "toe": 0.01,
    "knee": 0.8,
    "headroom": 2.0,
    "scene": "uniform",
    "vignetting": 0.0,
    "exposure_error": 0.0,
    "black_level": 0.0,
    "sharpen": 0.0,
    "jpeg_quality": None,
    "listed_step_factors": None,
    # handheld bracket (handheld.py): camera shake and moving objects, off at these values
    **_hh.DEFAULTS,
}

#: the options of the camera model: when all are at their defaults the session is the sec. 4.1
#: protocol, byte for byte, and truth.json has none of the camera-model keys
CAMERA_OPTIONS = ("camera", "tone", "tone_gamma", "toe", "knee", "headroom", "scene", "vignetting",
                  "exposure_error", "black_level", "sharpen", "jpeg_quality",
                  "listed_step_factors")
#: options recorded in ``camera_model.options`` only when set (added after sessions were
#: committed whose truth.json must stay byte for byte the same)
_RECORDED_WHEN_SET = ("listed_step_factors", *_hh.DEFAULTS)

SHOT_NOISE_NOTE = ("N_s ~ Normal(0, sigma_s^2 * a_k * E): shot-noise variance proportional to the "
                   "signal (Poisson), so eq. 7 reads sigma^2 = sigma_s^2 a E + sigma_c1^2 + "
                   "g'(z)^2 sigma_c2^2 (the extracted a^2 E^2 is read as sigma_s^2 a E).")
QUANTISATION_NOTE = ("z = clip(round(f(v) + N_c2), 0, 255) as uint8; sites with v >= 1 (full well) "
                     "read 255; rounding adds 1/12 DN^2 to sigma_c2^2.")

CAMERA_PIPELINE_NOTE = ("v = a_k E + N_s + N_c1 + b_k per sensor site (E: scene x vignetting; "
                        "b_k includes black_level) -> full well -> Bayer bilinear demosaicing -> "
                        "tone f(v) in DN -> unsharp mask -> + N_c2 -> round, clip to 8 bits "
                        "(255 at full well) -> JPEG round trip; a_k = t_k x exposure_factor_k "
                        "(x white balance w_kc)")

LISTED_STEPS_NOTE = ("the manifest lists the nominal t_k; frame k was exposed t_k x "
                     "exposure_factor_k = true_exposure_k, exposure_factor_k = "
                     "listed_step_cumulative_k x the lognormal exposure error; "
                     "listed_step_cumulative_0 = 1, listed_step_cumulative_(k+1) = "
                     "listed_step_cumulative_k x listed_step_factors_k (the factor of pair k's "
                     "true exposure ratio against its listed one)")

LABEL_CLEAN, LABEL_CONTAMINATED, LABEL_SATURATED = 0, 1, 2


@dataclass(frozen=True)
class Exposure:
    """One simulated frame.

    Attributes
    ----------
    z
        Observed 8-bit image (``uint8``), ``(H, W)`` or ``(H, W, 3)``.
    v
        The signal ``aE + N_s + N_c1 + b`` entering ``f`` (after full-well clipping, blooming and,
        for Bayer, interpolation), float64, same shape as ``z``.
    bloom
        ``uint8`` labels (0 clean, 1 contaminated, 2 saturated), ``(H, W)``, or ``None`` when
        blooming is off.
    """

    z: NDArray[np.uint8]
    v: NDArray[np.float64]
    bloom: NDArray[np.uint8] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"shape": list(self.z.shape), "saturated": int(np.count_nonzero(self.z == 255)),
                "bloom": None if self.bloom is None else int(np.count_nonzero(self.bloom))}


def inverse_response(z: ArrayLike, gamma: float = 1.2) -> NDArray[np.float64]:
    """The response function ``g(z) = (z / 255) ** gamma`` of sec. 4.1 (``g = f^-1``, eq. 5)."""
    return (np.asarray(z, dtype=np.float64) / 255.0) ** gamma


def response_table(gamma: float = 1.2) -> list[float]:
    """``g(z)`` for ``z = 0 .. 255``, each computed with the C library's scalar ``pow``.

    This is the ``g`` of ``truth.json``: correctly rounded in practice and, unlike NumPy's vector
    ``power`` (whose AVX-512 loop differs from its AVX2 loop in the last bit), the same on every
    CPU.
    """
    gamma = float(gamma)
    return [(z / 255.0) ** gamma for z in range(256)]


def response(v: ArrayLike, gamma: float = 1.2) -> NDArray[np.float64]:
    """The camera response ``f(v) = 255 clip(v, 0, 1) ** (1 / gamma)`` (eq. 3), in DN.

    The power is :func:`ccdcore.simulate._det.pow` (a few ulps, the same bits on every CPU): the
    result is rounded to a digital number, which must not depend on NumPy's vector loops.
    """
    return 255.0 * _det.pow(np.clip(np.asarray(v, dtype=np.float64), 0.0, 1.0), 1.0 / gamma)


def exposure_times(n: int = 8, ratio: float = math.sqrt(2.0),
                   t_max: float = math.sqrt(2.0)) -> NDArray[np.float64]:
    """Nominal exposure times ``t_k = t_max ratio^(k - n + 1)``, ``k = 0 .. n-1`` (sec. 4.1).

    The times are rounded to 12 significant digits (consecutive ratios exact to 1e-12).
    """
    if int(n) < 1:
        raise CcdError("n_exposures", f"need at least 1 exposure, got {n}")
    if not ratio > 1.0 or not t_max > 0.0:
        raise CcdError("ratio", f"need ratio > 1 and t_max > 0, got {ratio}, {t_max}")
    t = [t_max * ratio ** (k - int(n) + 1) for k in range(int(n))]
    # round to 12 significant digits so that manifests show 0.125, not 0.12499999999999994
    return np.array([round_sig(x, TRUTH_DIGITS) for x in t], dtype=np.float64)


def white_balance(t: ArrayLike, rng: np.random.Generator, *, enabled: bool, channels: int = 1,
                  wb_sigma: float = 0.05, offset_sigma: float = 0.01
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """White-balance scales ``a_k = t_k w_k`` and offsets ``b_k`` (eq. 2, sec. 4.1).

    Parameters
    ----------
    t
        Nominal exposure times, shape ``(N,)``.
    rng
        Random generator (always advanced by the same amount, whatever ``enabled``).
    enabled
        ``False``: ``a_k = t_k``, ``b_k = 0``.  ``True``: ``w_k ~ Normal(1, wb_sigma)``,
        ``b_k ~ Normal(0, offset_sigma)`` with ``b`` of the first image fixed at 0 (sec. 3.2).
    channels
        1 for mono (returns ``(N,)`` arrays), 3 for colour (``(N, 3)``).

    Returns
    -------
    a, b
        With white balance, rounded to 12 significant digits (like the exposure times), so that
        ``truth.json`` holds exactly the values simulated.
    """
    t = np.asarray(t, dtype=np.float64)
    shape = t.shape if channels == 1 else t.shape + (channels,)
    w = 1.0 + wb_sigma * rng.standard_normal(shape)
    b = offset_sigma * rng.standard_normal(shape)
    tt = t if channels == 1 else t[:, None]
    if not enabled:
        return np.broadcast_to(tt, shape).copy(), np.zeros(shape)
    b[0] = 0.0
    # rounded like the exposure times, so truth.json holds exactly the a_k and b_k simulated
    rnd = np.vectorize(round_sig, otypes=[np.float64])
    return rnd(tt * w), rnd(b)


def uniform_radiance(rng: np.random.Generator, shape: tuple[int, ...]) -> NDArray[np.float32]:
    """Radiance ``E`` uniform on ``[0, 1]`` per pixel and channel (sec. 4.1), float32."""
    return rng.random(shape, dtype=np.float32)


def effective_radiance(E: ArrayLike, bayer: str | None) -> NDArray[np.float64]:
    """Radiance the noise-free output obeys eq. 5 with: ``demosaic(mosaic(E))`` for Bayer."""
    E = np.asarray(E, dtype=np.float64)
    if bayer is None:
        return E
    return channels.demosaic_bilinear(channels.mosaic(E, bayer), bayer)


def bloom_kernel(radius: int) -> NDArray[np.bool_]:
    """Disk footprint of the sites within ``radius`` of the centre (centre included)."""
    r = int(radius)
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    return (xx * xx + yy * yy) <= r * r


def _per_site(value: ArrayLike, E: NDArray, bayer: str | None) -> NDArray[np.float64]:
    """Broadcast a scalar / per-channel parameter to the sensor array."""
    val = np.asarray(value, dtype=np.float64)
    if val.ndim == 0:
        return np.full(E.shape[:2] if bayer else E.shape, float(val))
    if E.ndim != 3 or val.shape != (E.shape[2],):
        raise CcdError("a/b", f"per-channel parameters of shape {val.shape} do not fit E of "
                              f"shape {E.shape}")
    full = np.broadcast_to(val, E.shape)
    return channels.mosaic(full, bayer) if bayer else np.array(full)


def expose(E: ArrayLike, a: ArrayLike, b: ArrayLike, rng: np.random.Generator, *,
           sigma_s: float = 0.015, sigma_c1: float = 0.01, sigma_c2: float = 1.0,
           gamma: float = 1.2, bayer: str | None = None, blooming: bool = False,
           bloom_radius: int = 3, bloom_strength: float = 1.0, tone: Any = None,
           sharpen: float = 0.0, jpeg_quality: int | None = None) -> Exposure:
    """Image one exposure: ``z = f(aE + N_s + N_c1 + b) + N_c2`` (eq. 3), quantised to 8 bits.

    Parameters
    ----------
    E
        Radiance, ``(H, W)`` mono or ``(H, W, 3)`` colour (required for ``bayer``).
    a, b
        White-balance scale ``a_k = t_k w_k`` and offset ``b_k``: scalars or per channel ``(3,)``.
    rng
        Random generator; draws ``N_s``, ``N_c1`` (per sensor site) then ``N_c2`` (per output
        value), the same numbers whatever ``blooming``.
    sigma_s, sigma_c1
        Shot noise (variance ``sigma_s^2 a E``, see the module notes) and thermal noise, in units
        of ``g``.
    sigma_c2
        Output noise in DN.
    gamma
        ``f(v) = 255 v^(1/gamma)``.
    bayer
        ``None``, or a pattern of :data:`ccdcore.channels.PATTERNS`: noise per CFA site, then bilinear
        interpolation before ``f``.
    blooming, bloom_radius, bloom_strength
        Spill ``bloom_strength`` times the charge above full well (``v > 1``) evenly onto the other
        sites of the disk of radius ``bloom_radius``.
    tone
        ``None`` (``f`` of ``gamma``) or a tone curve of :mod:`ccdcore.simulate.camera`
        (``GammaTone``, ``SrgbKneeTone``) whose ``f`` replaces it.
    sharpen
        Unsharp-mask amount applied to ``f(v)`` (in DN, before ``N_c2``); 0 = off.
    jpeg_quality
        ``None``, or the quality of the JPEG round trip applied to the 8-bit image
        (:func:`ccdcore.simulate.camera.jpeg_roundtrip`).

    Returns
    -------
    Exposure
    """
    E = np.asarray(E, dtype=np.float64)
    if bayer is not None:
        bayer = channels.check_pattern(bayer)
        if E.ndim != 3 or E.shape[2] != 3:
            raise CcdError("E", f"a Bayer camera needs an (H, W, 3) radiance, got {E.shape}")
        sensor_E = channels.mosaic(E, bayer)
    else:
        if E.ndim not in (2, 3):
            raise CcdError("E", f"expected an (H, W) or (H, W, C) radiance, got {E.shape}")
        sensor_E = E
    a_s, b_s = _per_site(a, E, bayer), _per_site(b, E, bayer)
    signal = a_s * sensor_E                                    # aE
    n_s = rng.standard_normal(sensor_E.shape)
    n_c1 = rng.standard_normal(sensor_E.shape)
    n_c2 = rng.standard_normal(E.shape)
    v = signal + sigma_s * np.sqrt(np.maximum(signal, 0.0)) * n_s + sigma_c1 * n_c1 + b_s
    labels = None
    if blooming:
        footprint = bloom_kernel(bloom_radius)
        excess = np.maximum(v - 1.0, 0.0)
        primary = excess > 0.0 if v.ndim == 2 else np.any(excess > 0.0, axis=2)
        ring = footprint.copy()
        r = int(bloom_radius)
        ring[r, r] = False
        n_ring = max(float(ring.sum()), 1.0)
        # sums of shifted arrays in a fixed order (not ndimage.convolve): the same bits on every CPU
        if v.ndim == 2:
            spill = _det.correlate_footprint(excess, ring) / n_ring
        else:
            spill = np.stack([_det.correlate_footprint(excess[..., c], ring) / n_ring
                              for c in range(v.shape[2])], axis=2)
        v = np.minimum(v, 1.0) + bloom_strength * spill
        near = ndimage.binary_dilation(primary, structure=footprint)
        v = np.minimum(v, 1.0)
        saturated = v >= 1.0 if v.ndim == 2 else np.any(v >= 1.0, axis=2)
        labels = np.zeros(primary.shape, dtype=np.uint8)
        labels[near] = LABEL_CONTAMINATED
        labels[saturated] = LABEL_SATURATED
        if bayer is not None:
            # each output pixel is interpolated from its 3x3 neighbourhood
            wide = ndimage.binary_dilation(labels > 0, structure=np.ones((3, 3), bool))
            labels = np.where(wide & (labels == 0), LABEL_CONTAMINATED, labels).astype(np.uint8)
    else:
        v = np.minimum(v, 1.0)
    if bayer is not None:
        v = channels.demosaic_bilinear(v, bayer)
    y = response(v, gamma) if tone is None else tone.f(v)
    if sharpen:
        y = _cam.sharpen(y, float(sharpen))
    zf = np.rint(y + sigma_c2 * n_c2)
    zf[v >= 1.0] = 255.0                                       # white clip at full well
    z = np.clip(zf, 0.0, 255.0).astype(np.uint8)
    if jpeg_quality is not None:
        z = _cam.jpeg_roundtrip(z, int(jpeg_quality))
    return Exposure(z=z, v=v, bloom=labels)


def _check_options(opts: dict[str, Any], size: tuple[int, int]) -> None:
    unknown = sorted(set(opts) - set(DEFAULTS))
    if unknown:
        raise CcdError("tsin01", f"unknown option(s) {', '.join(unknown)}; known: "
                                 f"{', '.join(DEFAULTS)}")
    if opts["layout"] not in ("mono", "rgb"):
        raise CcdError("layout", f"layout must be 'mono' or 'rgb', got {opts['layout']!r}")
    if opts["bayer"] is not None:
        opts["bayer"] = channels.check_pattern(opts["bayer"])
        opts["layout"] = "rgb"
        if size[0] % 2 or size[1] % 2:
            raise CcdError("size", f"a Bayer camera needs even width and height, got "
                                     f"{size[0]}x{size[1]}")
    if int(opts["n_stacks"]) < 1:
        raise CcdError("n_stacks", f"need at least one stack, got {opts['n_stacks']}")
    for key in ("sigma_s", "sigma_c1", "sigma_c2", "wb_sigma", "offset_sigma", "bloom_strength",
                "vignetting", "exposure_error", "black_level", "sharpen"):
        if not float(opts[key]) >= 0.0:
            raise CcdError(key, f"must be >= 0, got {opts[key]}")
    if not float(opts["gamma"]) > 0.0:
        raise CcdError("gamma", f"must be > 0, got {opts['gamma']}")
    if opts["tone"] not in ("gamma", "srgb-knee"):
        raise CcdError("tone", f"tone must be 'gamma' or 'srgb-knee', got {opts['tone']!r}")
    if opts["scene"] not in ("uniform", "structured"):
        raise CcdError("scene", f"scene must be 'uniform' or 'structured', got {opts['scene']!r}")
    steps = opts["listed_step_factors"]
    if steps is not None:
        # validated against the bracket, then kept as {pair: factor} (None when empty)
        pairs, _ = _cam.listed_steps(int(opts["n_exposures"]), steps)
        named = sorted({int(p) for p in steps}) if isinstance(steps, dict) else range(len(pairs))
        opts["listed_step_factors"] = {p: pairs[p] for p in named} or None
    q = opts["jpeg_quality"]
    if q is not None and (isinstance(q, bool) or not isinstance(q, (int, np.integer))
                          or not 1 <= int(q) <= 100):
        raise CcdError("jpeg_quality", f"must be None or an integer in 1..100, got {q!r}")
    _hh.check_options(opts)


def _options(options: dict[str, Any]) -> dict[str, Any]:
    """:data:`DEFAULTS`, then the bundle ``camera`` names (:data:`camera.CAMERAS`), then
    ``options``."""
    bundle = options.get("camera")
    if bundle is None:
        return {**DEFAULTS, **options}
    if bundle not in _cam.CAMERAS:
        raise CcdError("camera", f"unknown camera bundle {bundle!r}; choose one of "
                                 f"{', '.join(_cam.CAMERAS)}")
    return {**DEFAULTS, **_cam.CAMERAS[bundle], **options}


def _scene(opts: dict[str, Any], rng: np.random.Generator, seed: int, shape: tuple[int, ...],
           n_channels: int, hh: _hh.Plan | None = None
           ) -> tuple[NDArray[np.float32], dict[str, Any], NDArray | None, float]:
    """The radiance E the camera sees (given, uniform or structured, times the vignetting),
    the scene's description, the vignetting map (``None`` without) and its strength.  A handheld
    plan ``hh`` gets the scene drawn with its margin (:meth:`handheld.Plan.attach`); E is then
    the reference frame's crop."""
    scene: dict[str, Any] = {"kind": "uniform"}
    grown = shape if hh is None else hh.grown(shape)
    if opts["radiance"] is not None:
        E = np.asarray(opts["radiance"], dtype=np.float32)
        if E.shape != shape:
            raise CcdError("radiance", f"expected shape {shape}, got {E.shape}")
        E = E if hh is None else hh.pad(E)
        scene = {"kind": "given"}
    elif opts["scene"] == "uniform":
        E = uniform_radiance(rng, grown)
    else:
        # its own stream: the main generator's draws (white balance, noise) stay where they are
        E, scene = _cam.structured_scene(np.random.default_rng([int(seed), 1]), grown)
    if hh is not None:                       # float32: truth/scene_margin.exr is what is warped
        full = np.asarray(E, dtype=np.float32)
        E = hh.crop(full)
    vignetting = float(opts["vignetting"])
    V = None
    if vignetting > 0.0:
        V = _cam.vignetting_map(shape, vignetting)
        E = np.asarray(E, dtype=np.float64) * (V if n_channels == 1 else V[..., None])
    E = np.asarray(E, dtype=np.float32)        # what is simulated is what truth/E.exr holds
    if hh is not None:
        hh.attach(full, V)
    return E, scene, V, vignetting


def _camera_name(opts: dict[str, Any], camera_model: bool, jpeg: int | None) -> str:
    """The manifest's camera name: the Bayer pattern and the camera model's main options."""
    bayer = opts["bayer"]
    name = "tsin01 simulated camera" + (f" (Bayer {bayer}, bilinear)" if bayer else "")
    if camera_model:
        name += "; " + ", ".join([f"{opts['tone']} tone", f"{opts['scene']} scene"]
                                 + ([f"JPEG q{jpeg}"] if jpeg is not None else []))
    return name


@dataclass
class _Shots:
    """What the brackets were shot with, per stack: a_k, b_k, the exposure factors, the true
    exposures, the frames' truth entries and the bloom masks' paths."""

    a: list[Any] = field(default_factory=list)
    b: list[Any] = field(default_factory=list)
    eps: list[Any] = field(default_factory=list)
    true_exposure: list[list[float]] = field(default_factory=list)
    frames: list[dict[str, Any]] = field(default_factory=list)
    bloom_paths: list[list[str]] = field(default_factory=list)


def _shoot_stacks(writer: SessionWriter, out_dir: str | Path, E: NDArray, t: NDArray,
                  rng: np.random.Generator, seed: int, opts: dict[str, Any], n_channels: int,
                  camera_model: bool, gamma: float, noise: dict[str, float],
                  engine: dict[str, Any], hh: _hh.Plan | None = None) -> _Shots:
    """Every stack's bracket (sec. 4.1): its white balance, exposure errors (lognormal, and the
    wrong listed steps' cumulative factor) and black level, then one frame per exposure time
    (with its bloom mask when blooming; each frame's own radiance with a handheld plan)."""
    bayer = opts["bayer"]
    rnd = np.vectorize(round_sig, otypes=[np.float64])
    eps_rng = np.random.default_rng([int(seed), 2])
    steps = opts["listed_step_factors"]
    cumulative = None if steps is None else np.array(_cam.listed_steps(t.size, steps)[1])
    shots = _Shots()
    for j in range(int(opts["n_stacks"])):
        a, b = white_balance(t, rng, enabled=bool(opts["white_balance"]), channels=n_channels,
                             wb_sigma=float(opts["wb_sigma"]),
                             offset_sigma=float(opts["offset_sigma"]))
        eps = np.ones(t.size)
        if float(opts["exposure_error"]) > 0.0:
            eps = _cam.exposure_factors(eps_rng, t.size, float(opts["exposure_error"]))
        if cumulative is not None:
            eps = rnd(eps * cumulative)
        if float(opts["exposure_error"]) > 0.0 or cumulative is not None:
            a = rnd(a * (eps if n_channels == 1 else eps[:, None]))
        true_exposure = [round_sig(x) for x in (t * eps).tolist()]
        if float(opts["black_level"]) > 0.0:
            b = rnd(b + float(opts["black_level"]))
        shots.a.append(a)
        shots.b.append(b)
        shots.eps.append(eps)
        shots.true_exposure.append(true_exposure)
        stack_blooms = []
        for k in range(t.size):
            shot = expose(E if hh is None else hh.frame_radiance(k), a[k], b[k], rng,
                          gamma=gamma, bayer=bayer,
                          blooming=bool(opts["blooming"]), bloom_radius=int(opts["bloom_radius"]),
                          bloom_strength=float(opts["bloom_strength"]), **noise, **engine)
            rel = f"bracket/s{j}_k{k:02d}.tif"
            writer.add_frame(rel, shot.z, role="bracket", exposure=float(t[k]), stack=j)
            entry = {"path": rel, "stack": j, "index": k, "exposure": float(t[k]),
                     "a": a[k], "b": b[k]}
            if camera_model:
                entry["exposure_factor"] = float(eps[k])
            if cumulative is not None:
                entry["true_exposure"] = true_exposure[k]
            shots.frames.append(entry)
            if shot.bloom is not None:
                mask_rel = f"truth/bloom_s{j}_k{k:02d}.png"
                write_image(Path(out_dir) / mask_rel, shot.bloom)
                stack_blooms.append(mask_rel)
        shots.bloom_paths.append(stack_blooms)
    return shots


def _truth(opts: dict[str, Any], seed: int, width: int, height: int, tone: Any, gamma: float,
           t: NDArray, noise: dict[str, float], shots: _Shots) -> dict[str, Any]:
    """The truth of the sec. 4.1 protocol (with the bloom masks when blooming)."""
    bayer = opts["bayer"]
    truth: dict[str, Any] = {
        "preset": "tsin01",
        "paper": "Tsin, Ramesh & Kanade 2001, eq. 3 and sec. 4.1",
        "seed": int(seed),
        "size": [width, height],
        "layout": opts["layout"],
        "bayer": bayer,
        "g": tone.table(),
        "gamma": gamma if opts["tone"] == "gamma" else None,
        "f": tone.describe(),
        "t": t,
        "ratio": float(opts["ratio"]),
        "a": shots.a,
        "b": shots.b,
        "white_balance": bool(opts["white_balance"]),
        "wb_sigma": float(opts["wb_sigma"]) if opts["white_balance"] else 0.0,
        **noise,
        "noise_model": "sigma^2(a, z) = sigma_s^2 a E + sigma_c1^2 + g'(z)^2 sigma_c2^2 (eq. 7)",
        "shot_noise": SHOT_NOISE_NOTE,
        "quantisation": QUANTISATION_NOTE,
        "radiance_map": "E_effective" if bayer else "E",
        "n_stacks": int(opts["n_stacks"]),
        "frames": shots.frames,
    }
    if opts["blooming"]:
        truth["blooming"] = {"radius": int(opts["bloom_radius"]),
                             "strength": float(opts["bloom_strength"]),
                             "labels": {"0": "clean", "1": "contaminated", "2": "saturated"},
                             "masks": shots.bloom_paths}
    return truth


def _camera_model_truth(truth: dict[str, Any], opts: dict[str, Any], tone: Any,
                        scene: dict[str, Any], vignetting: float, V: NDArray | None,
                        shots: _Shots, jpeg: int | None) -> None:
    """Add the camera model's keys to ``truth`` (module notes)."""
    truth["camera_model"] = {
        "bundle": opts["camera"],
        "options": {k: opts[k] for k in DEFAULTS if k != "radiance"
                    and (k not in _RECORDED_WHEN_SET or _differs(opts[k], DEFAULTS[k]))},
        "pipeline": CAMERA_PIPELINE_NOTE,
    }
    truth["tone"] = tone.params()
    truth["scene"] = scene
    truth["vignetting"] = {"strength": vignetting,
                           "law": "E = E_scene / (1 + s rho^2)^2, rho = 1 at the corners",
                           "map": "truth/vignetting.exr" if V is not None else None}
    truth["exposure_error"] = float(opts["exposure_error"])
    truth["exposure_factor"] = shots.eps
    if opts["listed_step_factors"] is not None:
        pairs, cumulative = _cam.listed_steps(len(truth["t"]), opts["listed_step_factors"])
        truth["listed_step_factors"] = pairs
        truth["listed_step_cumulative"] = cumulative
        truth["true_exposure"] = shots.true_exposure
        truth["listed_steps"] = LISTED_STEPS_NOTE
    truth["black_level"] = float(opts["black_level"])
    truth["sharpen"] = {"amount": float(opts["sharpen"]), "sigma": _cam.SHARPEN_SIGMA}
    truth["jpeg"] = None if jpeg is None else {"quality": jpeg, "model": _cam.JPEG_NOTE}


def _note(opts: dict[str, Any], seed: int, camera_model: bool) -> str:
    """The manifest's note."""
    note = (f"tsin01 simulation (Tsin, Ramesh & Kanade 2001, sec. 4.1), seed {int(seed)}.\n"
            "Truth in truth.json.")
    if camera_model:
        note = ("tsin01 simulation with a camera model"
                + (f" (camera={opts['camera']!r})" if opts["camera"] else "")
                + f", seed {int(seed)}.\nTruth in truth.json (camera_model, tone, scene ...).")
    steps = opts["listed_step_factors"]
    if steps is not None:
        note += ("\nThe exposures listed are the nominal ones; the true ones differ: pair(s) "
                 + ", ".join(f"{p} (x{f:g})" for p, f in steps.items())
                 + " of the listed ratio (truth.json: true_exposure).")
    return note


def simulate(out_dir: str | Path, *, seed: int = 0, size: tuple[int, int] | None = None,
             **options: Any) -> dict[str, Any]:
    """Write the ``tsin01`` session (sec. 4.1 of Tsin et al. 2001) and return its truth.

    Parameters
    ----------
    out_dir
        Session folder to write.
    seed
        Seed of the random generator; the same seed and options give the same bytes.
    size
        ``(width, height)``; ``None``: 128 x 128, or ``camera.DEFAULT_SIZE`` (256 x 192) with a
        ``camera`` bundle.
    **options
        See :data:`DEFAULTS`: ``n_exposures``, ``ratio``, ``t_max`` (bracket), ``gamma``,
        ``sigma_s``, ``sigma_c1``, ``sigma_c2`` (noise), ``white_balance``, ``wb_sigma``,
        ``offset_sigma``, ``layout`` (``"mono"``/``"rgb"``), ``bayer`` (pattern or ``None``),
        ``blooming``, ``bloom_radius``, ``bloom_strength``, ``n_stacks`` (sequences of the same
        scene, new noise and white balance each) and ``radiance`` (an explicit ``E`` array);
        the camera model (module notes): ``camera`` (a bundle of :data:`camera.CAMERAS`,
        ``"real"``, ``"real-listed-wrong"``), ``tone`` (``"gamma"``/``"srgb-knee"``) with
        ``tone_gamma``, ``toe``, ``knee``, ``headroom``, ``scene``
        (``"uniform"``/``"structured"``), ``vignetting``, ``exposure_error``, ``black_level``,
        ``sharpen``, ``jpeg_quality`` and ``listed_step_factors`` (``{pair: factor}``: pairs
        whose true exposure ratio differs from the listed one); the handheld bracket
        (module notes): ``handheld_shift``, ``handheld_rotation``, ``movers``, ``mover_size``,
        ``mover_speed``.

    Returns
    -------
    dict
        The content of ``truth.json``.
    """
    opts = _options(options)
    if size is None:
        size = _cam.DEFAULT_SIZE if opts["camera"] is not None else (128, 128)
    width, height = int(size[0]), int(size[1])
    _check_options(opts, (width, height))
    camera_model = any(_differs(opts[k], DEFAULTS[k]) for k in CAMERA_OPTIONS)
    rng = np.random.default_rng(int(seed))
    n_channels = 3 if opts["layout"] == "rgb" else 1
    shape = (height, width) if n_channels == 1 else (height, width, 3)
    t = exposure_times(opts["n_exposures"], opts["ratio"], opts["t_max"])
    hh = _hh.plan(opts, seed, t.size, (height, width))
    E, scene, V, vignetting = _scene(opts, rng, seed, shape, n_channels, hh)
    bayer = opts["bayer"]
    gamma = float(opts["gamma"])
    tone = _cam.make_tone(opts["tone"], gamma=gamma, tone_gamma=float(opts["tone_gamma"]),
                          toe=float(opts["toe"]), knee=float(opts["knee"]),
                          headroom=float(opts["headroom"]))
    noise = {k: float(opts[k]) for k in ("sigma_s", "sigma_c1", "sigma_c2")}
    jpeg = None if opts["jpeg_quality"] is None else int(opts["jpeg_quality"])
    engine = {"tone": None if opts["tone"] == "gamma" else tone,
              "sharpen": float(opts["sharpen"]), "jpeg_quality": jpeg}

    camera = {"name": _camera_name(opts, camera_model, jpeg), "bits": 8,
              "layout": opts["layout"]}
    writer = SessionWriter(out_dir, camera)
    writer.add_map("truth/E.exr", E)
    if bayer:
        writer.add_map("truth/E_effective.exr", effective_radiance(E, bayer))
    if V is not None:
        writer.add_map("truth/vignetting.exr", V)
    if hh is not None and hh.margin:
        writer.add_map("truth/scene_margin.exr", hh.scene)
    shots = _shoot_stacks(writer, out_dir, E, t, rng, seed, opts, n_channels, camera_model,
                          gamma, noise, engine, hh)
    truth = _truth(opts, seed, width, height, tone, gamma, t, noise, shots)
    if camera_model:
        _camera_model_truth(truth, opts, tone, scene, vignetting, V, shots, jpeg)
    note = _note(opts, seed, camera_model)
    if hh is not None:
        truth.update(hh.truth(out_dir, shots.frames))
        note += hh.note()
    return writer.finish(truth, note=note, exact=("g",))


def _differs(value: Any, default: Any) -> bool:
    """Whether an option's value is not its default (numbers compared as numbers: 0 == 0.0)."""
    def number(x: Any) -> bool:
        return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool)

    if number(value) and number(default):
        return float(value) != float(default)
    return type(value) is not type(default) or value != default
