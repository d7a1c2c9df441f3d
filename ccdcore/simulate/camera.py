"""A real camera's processing for the ``tsin01`` bracket: tone curve, scene, exposure errors, JPEG.

The sec. 4.1 protocol of Tsin, Ramesh & Kanade (2001) -- iid uniform radiance, ``g = (z/255)^1.2``,
exact exposure times -- is kind to response estimators.  A bracket from a real camera (8-bit
JPEGs out of a demosaicing, tone-mapping, sharpening, compressing engine) is not, and the ways it
is not are what this module models (``docs/camera_simulation.md`` says why each matters):

* :class:`SrgbKneeTone` -- an sRGB-like tone curve with a linear toe and a highlight shoulder
  (knee), analytic both ways, so the true ``g`` on the 256 codes is exact;
* :func:`structured_scene` -- regions with edges, a smooth log-normal field, small very bright
  lights with a glow: a wide dynamic range with most pixels dark; :func:`vignetting_map`, the
  ``cos^4``-like falloff of the irradiance towards the corners;
* :func:`exposure_factors` -- the actual exposure differs from the nominal time by a lognormal
  factor per frame;
* :func:`listed_steps` -- the listed (manifest, EXIF) exposures are wrong for part of the bracket:
  some neighbouring pairs' true ratio differs from the listed one by a factor (a shutter that did
  not change for a few steps of a real bracket gives 0.5 on a listed ratio of 2);
* :func:`sharpen` -- the unsharp mask of the camera's engine (halos at edges, anticorrelated noise
  at two pixels' distance);
* :func:`jpeg_roundtrip` -- baseline-JPEG compression and decompression (JFIF YCbCr, 4:2:0 chroma,
  8x8 DCT, the IJG quantisation tables at a quality), implemented here in basic arithmetic.

Everything that feeds a digital number is computed with ``+ - * /``, ``sqrt``, ``rint`` and the
CPU-independent :mod:`ccdcore.simulate._det` functions, in a fixed order, so a seed gives the same
bytes on every CPU (x86-64 with AVX2 or AVX-512, arm64).  That is why the JPEG is not libjpeg's:
libjpeg-turbo's SIMD paths, its versions and the other libjpeg builds OpenImageIO may link differ
in their DCT and colour-conversion rounding, while this one is plain IEEE arithmetic.  The DCT
basis is built from nested square roots (``cos(pi/16)`` = ``sqrt(2 + sqrt(2 + sqrt 2)) / 2`` ...),
not from the C library's ``cos``; sums over the 8 taps run in a fixed order (no BLAS).

The preset ``tsin01-camera`` (:func:`ccdcore.simulate.tsin_camera.simulate`) is ``tsin01`` with
the bundle :data:`CAMERAS` ``["real"]``: ``simulate("tsin01", out, camera="real")`` gives the same
bytes.  This module holds the building blocks only: :mod:`ccdcore.simulate.tsin` imports it, and
it imports neither that pipeline nor the preset.

Public objects
--------------
CAMERAS
    Option bundles of ``tsin01`` (``camera=<name>``): ``"real"``, ``"real-listed-wrong"``.
GammaTone, SrgbKneeTone, make_tone(name, ...)
    Tone curves: ``f(v)`` in DN (CPU-independent) and the exact ``g`` table.
structured_scene(rng, shape, median)
    A deterministic textured radiance map and its description.
vignetting_map(shape, strength)
    ``1 / (1 + s rho^2)^2`` (``cos^4`` of the field angle), ``rho = 1`` at the corners.
exposure_factors(rng, n, sigma)
    Lognormal factors ``exp(sigma N(0, 1))`` of the actual exposure against the nominal time.
listed_steps(n, factors)
    Per-pair factors of the true against the listed exposure ratio, and the per-frame cumulative
    factor of the true against the listed exposure (1 before the first wrong pair).
sharpen(y, amount, sigma)
    Unsharp mask ``y + amount (y - G_sigma * y)`` per channel.
dct_matrix(), quant_table(quality, chroma), jpeg_roundtrip(z, quality)
    The deterministic baseline-JPEG model.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import CcdError
from . import _det

__all__ = ["CAMERAS", "DEFAULT_SIZE", "GammaTone", "SrgbKneeTone", "make_tone", "structured_scene",
           "vignetting_map", "exposure_factors", "listed_steps", "sharpen", "dct_matrix",
           "quant_table", "jpeg_roundtrip", "SHARPEN_SIGMA", "JPEG_NOTE"]

#: option bundles of ``tsin01``: ``simulate("tsin01", out, camera=name)``; explicit options win.
#: ``"real"``: an 8-bit JPEG camera bracket -- 10 frames one stop apart, Bayer RGGB with bilinear
#: demosaicing, the sRGB-like tone curve with toe and knee, a structured night-like scene with
#: vignetting, 3 % exposure errors, per-frame white balance, a black pedestal, sharpening and
#: JPEG quality 90.  Noise in units of ``v`` (full well 1): read noise 5e-4 (about 1.7 DN in the
#: toe), shot noise 0.01 at full scale; both give 1-3 DN, the noise of a real JPEG bracket's
#: shadows and mid-tones.
CAMERAS: dict[str, dict[str, Any]] = {
    "real": {
        "n_exposures": 10,
        "ratio": 2.0,
        "t_max": 1.0,
        "layout": "rgb",
        "bayer": "rggb",
        "tone": "srgb-knee",
        "scene": "structured",
        "vignetting": 0.35,
        "exposure_error": 0.03,
        "white_balance": True,
        "wb_sigma": 0.03,
        "offset_sigma": 0.0,
        "black_level": 5e-4,
        "sigma_s": 0.01,
        "sigma_c1": 5e-4,
        "sigma_c2": 0.5,
        "sharpen": 0.5,
        "jpeg_quality": 90,
    },
}
#: ``"real-listed-wrong"``: the ``"real"`` camera with a bracket whose listed exposures are wrong
#: for part of it, as in real Nikon brackets (four neighbouring pairs listed one stop apart whose
#: images fit a ratio of about 1): 12 frames listed one stop apart, 1/128 ... 16 s, of which pairs
#: 4, 5, 6 and 7 (frames 4 -> 8) are truly one-half as far apart as listed (ratio 1, not 2) -- 7
#: of the 11 pairs are right.  Frames 0 .. 4 are exposed as listed (1/128 ... 1/8), frames 5 .. 8
#: like frame 4 and frames 9 .. 11 at 1/4, 1/2, 1: the true bracket ends at ``a = 1`` like
#: ``"real"``'s.
CAMERAS["real-listed-wrong"] = {
    **CAMERAS["real"],
    "n_exposures": 12,
    "t_max": 16.0,
    "listed_step_factors": {4: 0.5, 5: 0.5, 6: 0.5, 7: 0.5},
}

#: default ``(width, height)`` of the ``tsin01-camera`` preset
DEFAULT_SIZE = (256, 192)

#: standard deviation (pixels) of the Gaussian of the unsharp mask
SHARPEN_SIGMA = 1.0

JPEG_NOTE = ("baseline JPEG model, deterministic: RGB -> YCbCr (JFIF, rounded to 8 bits), chroma "
             "4:2:0 (2x2 mean), 8x8 orthonormal DCT, quantisation rint(F/Q)*Q with the IJG "
             "tables (ITU-T T.81 Annex K) scaled to the quality, inverse DCT, chroma upsampled "
             "with libjpeg's triangle ('fancy') filter, YCbCr -> RGB rounded and clipped to 0..255")


# =============================================================================================
# tone curves
# =============================================================================================
class GammaTone:
    """``g(z) = (z / 255)^gamma``, ``f(v) = 255 clip(v, 0, 1)^(1/gamma)`` (sec. 4.1)."""

    name = "gamma"

    def __init__(self, gamma: float = 1.2):
        self.gamma = float(gamma)
        if not self.gamma > 0.0:
            raise CcdError("gamma", f"must be > 0, got {gamma}")

    def f(self, v: ArrayLike) -> NDArray[np.float64]:
        """The response in DN (not rounded), the same bits on every CPU."""
        return 255.0 * _det.pow(np.clip(np.asarray(v, dtype=np.float64), 0.0, 1.0),
                                1.0 / self.gamma)

    def g(self, z: ArrayLike) -> NDArray[np.float64]:
        """The inverse response at (possibly fractional) codes."""
        return (np.clip(np.asarray(z, dtype=np.float64), 0.0, 255.0) / 255.0) ** self.gamma

    def table(self) -> list[float]:
        """``g(0) .. g(255)`` with the C library's scalar ``pow`` (as ``tsin.response_table``)."""
        return [(z / 255.0) ** self.gamma for z in range(256)]

    def params(self) -> dict[str, Any]:
        return {"name": self.name, "gamma": self.gamma}

    def describe(self) -> str:
        return (f"f(v) = 255 * clip(v, 0, 1) ** (1 / {self.gamma:g}); "
                f"g(z) = (z / 255) ** {self.gamma:g}")


class SrgbKneeTone:
    """An sRGB-like camera curve with a linear toe and a highlight shoulder, analytic both ways.

    With ``u = headroom * v`` (``v`` the signal, full well ``v = 1``) the curve is, in output
    units ``y = z / 255``::

        x(u) = s u                          for u < toe          (linear toe)
             = (1 + alpha) u^(1/gamma) - alpha   otherwise       (sRGB-like power law)
        y(x) = x                            for x <= knee
             = knee + w / (1 + w / L)       otherwise, w = x - knee   (shoulder)

    ``alpha`` and ``s`` make ``x`` continuous with a continuous slope at the toe (sRGB's
    construction: ``gamma = 2.4``, ``toe = 0.0031308`` give sRGB's 0.055 and 12.92);
    ``L = d w1 / (w1 - d)`` with ``d = 1 - knee`` and ``w1 = x(headroom) - knee`` makes the
    shoulder meet slope 1 at the knee and reach ``y = 1`` exactly at full well ``v = 1``: the
    ``headroom`` times the exposure at which the power law alone would reach white is folded into
    ``[knee, 1]`` (the slope at white is ``(d / w1)^2`` of the power law's).  The inverse is closed
    form::

        x = y                               for y <= knee
          = knee + w / (1 - w / L),  w = y - knee
        u = x / s                           for x < s toe
          = ((x + alpha) / (1 + alpha))^gamma
        g(z) = u / headroom,  y = z / 255

    so ``g(0) = 0`` and ``g(255) = 1`` (set exactly; the formula gives it to an ulp).
    """

    name = "srgb-knee"

    def __init__(self, gamma: float = 2.4, toe: float = 0.01, knee: float = 0.8,
                 headroom: float = 2.0):
        self.gamma, self.toe, self.knee, self.headroom = (float(gamma), float(toe), float(knee),
                                                          float(headroom))
        if not self.gamma > 1.0:
            raise CcdError("tone_gamma", f"must be > 1, got {gamma}")
        if not 0.0 < self.toe < 0.5:
            raise CcdError("toe", f"must lie in (0, 0.5), got {toe}")
        if not self.headroom > 1.0:
            raise CcdError("headroom", f"must be > 1, got {headroom}")
        p = 1.0 / self.gamma
        # constants through _det.pow: they feed every digital number, so they must not depend on
        # the C library's pow (which may differ in the last bit between builds)
        tp = float(_det.pow(np.float64(self.toe), p))
        c = tp * (1.0 - p)
        self.alpha = c / (1.0 - c)
        self.slope = (1.0 + self.alpha) * p * tp / self.toe
        self.x_toe = self.slope * self.toe
        x_white = (1.0 + self.alpha) * float(_det.pow(np.float64(self.headroom), p)) - self.alpha
        if not self.x_toe < self.knee < 1.0:
            raise CcdError("knee", f"must lie in ({self.x_toe:.4g}, 1) (above the toe), got {knee}")
        d = 1.0 - self.knee
        self.w_white = x_white - self.knee
        self.L = d * self.w_white / (self.w_white - d)

    def f(self, v: ArrayLike) -> NDArray[np.float64]:
        """The response in DN (not rounded): basic arithmetic and :func:`_det.pow` only."""
        u = self.headroom * np.clip(np.asarray(v, dtype=np.float64), 0.0, 1.0)
        lin = self.slope * u
        pw = (1.0 + self.alpha) * _det.pow(u, 1.0 / self.gamma) - self.alpha
        x = np.where(u < self.toe, lin, pw)
        w = np.maximum(x - self.knee, 0.0)
        shoulder = self.knee + w / (1.0 + w / self.L)
        return 255.0 * np.where(x <= self.knee, x, shoulder)

    def _g_scalar(self, z: float) -> float:
        y = z / 255.0
        if y <= self.knee:
            x = y
        else:
            w = y - self.knee
            x = self.knee + w / (1.0 - w / self.L)
        if x < self.x_toe:
            u = x / self.slope
        else:
            u = ((x + self.alpha) / (1.0 + self.alpha)) ** self.gamma
        return u / self.headroom

    def g(self, z: ArrayLike) -> NDArray[np.float64]:
        """The inverse response at (possibly fractional) codes in ``[0, 255]``."""
        zz = np.clip(np.asarray(z, dtype=np.float64), 0.0, 255.0)
        return np.vectorize(self._g_scalar, otypes=[np.float64])(zz)

    def table(self) -> list[float]:
        """``g(0) .. g(255)`` (scalar arithmetic; ``g(0) = 0``, ``g(255) = 1`` exactly)."""
        g = [self._g_scalar(float(z)) for z in range(256)]
        g[0], g[255] = 0.0, 1.0
        return g

    def params(self) -> dict[str, Any]:
        return {"name": self.name, "gamma": self.gamma, "toe": self.toe, "knee": self.knee,
                "headroom": self.headroom, "alpha": self.alpha, "toe_slope": self.slope,
                "shoulder_L": self.L, "toe_code": 255.0 * self.x_toe,
                "knee_code": 255.0 * self.knee}

    def describe(self) -> str:
        return ("u = headroom v; x = s u (u < toe) else (1 + alpha) u^(1/gamma) - alpha; "
                "y = x (x <= knee) else knee + w / (1 + w / L), w = x - knee; f = 255 y; "
                "g(z) = f^-1(z) in closed form (see tone)")


def make_tone(name: str, *, gamma: float = 1.2, tone_gamma: float = 2.4, toe: float = 0.01,
              knee: float = 0.8, headroom: float = 2.0) -> GammaTone | SrgbKneeTone:
    """The tone curve ``name`` (``"gamma"`` uses ``gamma``; ``"srgb-knee"`` the others)."""
    if name == "gamma":
        return GammaTone(gamma)
    if name == "srgb-knee":
        return SrgbKneeTone(tone_gamma, toe, knee, headroom)
    raise CcdError("tone", f"tone must be 'gamma' or 'srgb-knee', got {name!r}")


# =============================================================================================
# scene
# =============================================================================================
def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], sigma: float
                  ) -> NDArray[np.float64]:
    """White noise smoothed by a Gaussian, scaled to unit standard deviation (away from borders).

    The scale is the analytic one, ``1 / sum(w_i^2)`` for the separable kernel ``w``, not a
    sample statistic.
    """
    white = rng.standard_normal(shape)
    radius = int(4.0 * float(sigma) + 0.5)
    w = _det.gaussian_kernel1d(sigma, radius)
    s2 = 0.0
    for wi in w.tolist():          # a fixed-order Python sum
        s2 += wi * wi
    return _det.gaussian_filter(white, sigma) / s2


def structured_scene(rng: np.random.Generator, shape: tuple[int, ...], median: float = 0.06
                     ) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """A textured radiance map with regions, edges and a few very bright lights.

    Built in log radiance: a smooth log-normal field (``ln median + 1.2 n_big + 0.2 n_fine``,
    ``n_big`` Gaussian-smoothed with ``sigma = max(H, W) / 8``, ``n_fine`` with 1.5 px, each of unit
    standard deviation), then piecewise-constant patches (rectangles and ellipses, each one
    constant radiance ``median exp(1.3 N(0, 1))`` and colour, hard edges), then small discs of
    radiance log-uniform in ``[20, 4000]`` (lights; the first in ``[1000, 4000]``, so that one
    saturates every frame of a 10-stop bracket ending at ``a = 1``) with a Gaussian glow (3 % of
    their flux spread with ``sigma = 2.5`` px).
    Colour: a global tint, a smooth per-channel variation (``0.15`` in log), a tint per patch.

    Returns
    -------
    E, description
        ``(H, W)`` or ``(H, W, 3)`` float64 radiance (``v = a E`` reaches full well at
        ``E = 1 / a``), and a JSON-able description (the patches and lights drawn).
    """
    h, w = int(shape[0]), int(shape[1])
    nc = int(shape[2]) if len(shape) == 3 else 1
    ln_med = float(_det.log(np.float64(median)))
    L = ln_med + 1.2 * _smooth_noise(rng, (h, w), max(h, w) / 8.0) \
        + 0.2 * _smooth_noise(rng, (h, w), 1.5)
    base_tint = np.array([0.0, -0.1, -0.25])[:nc] if nc == 3 else np.zeros(1)
    tint = np.stack([base_tint[c] + 0.15 * _smooth_noise(rng, (h, w), max(h, w) / 6.0)
                     for c in range(nc)], axis=2) if nc == 3 else np.zeros((h, w, 1))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    patches = []
    n_patches = max(4, int(round(h * w / 2500.0)))
    for _ in range(n_patches):
        kind = "rect" if rng.integers(2) == 0 else "ellipse"
        cy, cx = float(rng.uniform(0, h)), float(rng.uniform(0, w))
        ry = float(rng.uniform(0.04, 0.2)) * h
        rx = float(rng.uniform(0.04, 0.2)) * w
        level = ln_med + 1.3 * float(rng.standard_normal())
        ptint = 0.25 * rng.standard_normal(3)
        if kind == "rect":
            m = (np.abs(yy - cy) <= ry) & (np.abs(xx - cx) <= rx)
        else:
            dy, dx = (yy - cy) / ry, (xx - cx) / rx
            m = (dy * dy + dx * dx) <= 1.0
        L = np.where(m, level, L)
        for c in range(nc):
            tint[..., c] = np.where(m, (base_tint[c] + ptint[c]) if nc == 3 else 0.0,
                                    tint[..., c])
        patches.append({"kind": kind, "centre": [cx, cy], "half_size": [rx, ry],
                        "radiance": float(_det.exp(np.float64(level))),
                        "tint": [float(x) for x in ptint[:nc]] if nc == 3 else []})
    E = np.stack([_det.exp(L + tint[..., c]) for c in range(nc)], axis=2)
    lights = []
    light_map = np.zeros((h, w, nc))
    n_lights = max(3, int(round(h * w / 8000.0)))
    colours = {"sodium": (1.0, 0.72, 0.4), "white": (1.0, 1.0, 1.0), "led": (0.75, 0.9, 1.0)}
    names = list(colours)
    ln_lo, ln_mid, ln_hi = (float(_det.log(np.float64(x))) for x in (20.0, 1000.0, 4000.0))
    for i in range(n_lights):
        cy, cx = float(rng.uniform(2, h - 2)), float(rng.uniform(2, w - 2))
        r = float(rng.uniform(0.8, 2.2))
        # the first light is at least 1000: it saturates every frame of a 10-stop bracket
        level = float(_det.exp(np.float64(float(rng.uniform(ln_mid if i == 0 else ln_lo, ln_hi)))))
        colour = names[int(rng.integers(len(names)))]
        dy, dx = yy - cy, xx - cx
        m = (dy * dy + dx * dx) <= r * r
        if not m.any():                              # at least the nearest pixel
            m[int(cy), int(cx)] = True
        rgb = colours[colour] if nc == 3 else (1.0,)
        for c in range(nc):
            light_map[..., c] = np.where(m, level * rgb[c], light_map[..., c])
        lights.append({"centre": [cx, cy], "radius": r, "radiance": level, "colour": colour,
                       "pixels": int(m.sum())})
    for c in range(nc):
        glow = _det.gaussian_filter(light_map[..., c], 2.5)
        E[..., c] = np.where(light_map[..., c] > 0.0, light_map[..., c], E[..., c]) + 0.03 * glow
    if nc == 1:
        E = E[..., 0]
    description = {"kind": "structured", "median": float(median), "log_sigma_big": 1.2,
                   "log_sigma_fine": 0.2, "patches": patches, "lights": lights,
                   "glow": {"fraction": 0.03, "sigma": 2.5}}
    return E, description


def vignetting_map(shape: tuple[int, ...], strength: float) -> NDArray[np.float64]:
    """``1 / (1 + s rho^2)^2``, ``rho`` the distance from the centre over the half diagonal.

    The ``cos^4`` law of the field angle ``theta`` with ``tan^2 theta = s rho^2``: ``s = 0.35``
    loses 0.9 stop in the corners.  ``(H, W)`` float64, 1 at the centre.
    """
    h, w = int(shape[0]), int(shape[1])
    cy, cx = (h - 1) / 2.0, (w - 1) / 2.0
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    rho2 = ((yy - cy) * (yy - cy) + (xx - cx) * (xx - cx)) / (cy * cy + cx * cx)
    q = 1.0 + float(strength) * rho2
    return 1.0 / (q * q)


def exposure_factors(rng: np.random.Generator, n: int, sigma: float) -> NDArray[np.float64]:
    """``exp(sigma N(0, 1))`` for ``n`` frames (``_det.exp``), rounded to 12 significant digits."""
    from ._common import round_sig

    eps = _det.exp(float(sigma) * rng.standard_normal(int(n)))
    return np.array([round_sig(x) for x in eps.tolist()], dtype=np.float64)


def listed_steps(n: int, factors: Any) -> tuple[list[float], list[float]]:
    """Where the listed exposures of an ``n``-frame bracket are wrong, pair by pair.

    Parameters
    ----------
    n
        Number of frames, in increasing listed exposure.
    factors
        A mapping from the neighbour-pair index ``p`` (frames ``p`` and ``p + 1``, ``0 <= p <=
        n - 2``; an integer or its decimal string, as JSON writes it) to the factor ``f_p > 0`` by
        which that pair's true exposure ratio differs from the listed one; pairs not named are
        right (``f_p = 1``).  A sequence of ``n - 1`` factors is taken as well.

    Returns
    -------
    pairs, cumulative
        ``f_0 .. f_(n-2)`` and ``c_0 .. c_(n-1)`` with ``c_0 = 1``, ``c_(k+1) = c_k f_k``: frame
        ``k``'s true exposure is ``c_k`` times its listed one, so the frames before the first wrong
        pair are exactly as listed and ``true_(k+1) / true_k = f_k listed_(k+1) / listed_k``.
        Both rounded to 12 significant digits (the product is formed unrounded, in order).
    """
    from ._common import round_sig

    n = int(n)
    if isinstance(factors, dict):
        items = list(factors.items())
    elif isinstance(factors, (list, tuple, np.ndarray)):
        if len(factors) != n - 1:
            raise CcdError("listed_step_factors", f"a sequence needs one factor per pair, "
                                                  f"{n - 1}, got {len(factors)}")
        items = list(enumerate(factors))
    else:
        raise CcdError("listed_step_factors", f"expected a mapping pair -> factor, got "
                                              f"{type(factors).__name__}")
    pairs = [1.0] * max(n - 1, 0)
    for key, value in items:
        try:
            p = int(key) if not isinstance(key, (bool, float)) else None
        except (TypeError, ValueError):
            p = None
        if p is None or not 0 <= p <= n - 2:
            raise CcdError("listed_step_factors", f"pair {key!r} is not an index 0 .. {n - 2} "
                                                  f"of the {n}-frame bracket's neighbour pairs")
        f = float(value) if not isinstance(value, bool) else math.nan
        if not (math.isfinite(f) and f > 0.0):
            raise CcdError("listed_step_factors", f"the factor of pair {p} must be finite and "
                                                  f"> 0, got {value!r}")
        pairs[p] = f
    cumulative, c = [1.0], 1.0
    for f in pairs:
        c *= f
        cumulative.append(round_sig(c))
    return [round_sig(f) for f in pairs], cumulative


# =============================================================================================
# the engine: sharpening and JPEG
# =============================================================================================
def sharpen(y: ArrayLike, amount: float, sigma: float = SHARPEN_SIGMA) -> NDArray[np.float64]:
    """Unsharp mask ``y + amount (y - G_sigma * y)``, each channel of ``(H, W[, C])``."""
    y = np.asarray(y, dtype=np.float64)
    if amount == 0.0:
        return y
    if y.ndim == 2:
        return y + amount * (y - _det.gaussian_filter(y, sigma))
    return np.stack([sharpen(y[..., c], amount, sigma) for c in range(y.shape[2])], axis=2)


_LUMA_Q = np.array([
    [16, 11, 10, 16, 24, 40, 51, 61], [12, 12, 14, 19, 26, 58, 60, 55],
    [14, 13, 16, 24, 40, 57, 69, 56], [14, 17, 22, 29, 51, 87, 80, 62],
    [18, 22, 37, 56, 68, 109, 103, 77], [24, 35, 55, 64, 81, 104, 113, 92],
    [49, 64, 78, 87, 103, 121, 120, 101], [72, 92, 95, 98, 112, 100, 103, 99]])
_CHROMA_Q = np.full((8, 8), 99)
_CHROMA_Q[:4, :4] = [[17, 18, 24, 47], [18, 21, 26, 66], [24, 26, 56, 99], [47, 66, 99, 99]]


def quant_table(quality: int, chroma: bool = False) -> NDArray[np.float64]:
    """The IJG quantisation table at ``quality`` (1..100), as libjpeg's ``jpeg_set_quality``."""
    q = int(quality)
    if not 1 <= q <= 100:
        raise CcdError("jpeg_quality", f"must lie in 1..100, got {quality}")
    scale = 5000 // q if q < 50 else 200 - 2 * q
    base = _CHROMA_Q if chroma else _LUMA_Q
    return np.clip((base * scale + 50) // 100, 1, 255).astype(np.float64)


def _cos16() -> list[float]:
    """``cos(k pi / 16)``, ``k = 0 .. 8``, from nested square roots (correctly rounded steps)."""
    s2 = math.sqrt(2.0)
    c8 = math.sqrt(2.0 + s2) / 2.0              # cos(pi/8)
    s8 = math.sqrt(2.0 - s2) / 2.0              # cos(3pi/8)
    return [1.0,
            math.sqrt(2.0 + math.sqrt(2.0 + s2)) / 2.0,   # cos(pi/16)
            c8,
            math.sqrt(2.0 + math.sqrt(2.0 - s2)) / 2.0,   # cos(3pi/16)
            s2 / 2.0,                                     # cos(pi/4)
            math.sqrt(2.0 - math.sqrt(2.0 - s2)) / 2.0,   # cos(5pi/16)
            s8,
            math.sqrt(2.0 - math.sqrt(2.0 + s2)) / 2.0,   # cos(7pi/16)
            0.0]


def dct_matrix() -> NDArray[np.float64]:
    """The orthonormal 8-point DCT-II matrix ``C[u, x] = c_u cos((2x + 1) u pi / 16)``."""
    cos16 = _cos16()

    def cos_k(m: int) -> float:               # cos(m pi / 16) for any integer m
        m %= 32
        if m > 16:
            m = 32 - m
        return -cos16[16 - m] if m > 8 else cos16[m]

    C = np.empty((8, 8))
    for u in range(8):
        cu = math.sqrt(0.125) if u == 0 else 0.5
        for x in range(8):
            C[u, x] = cu * cos_k((2 * x + 1) * u)
    return C


def _apply8(X: NDArray[np.float64], M: NDArray[np.float64], axis: int) -> NDArray[np.float64]:
    """``out[.., u, ..] = sum_x M[u, x] X[.., x, ..]`` along ``axis`` (length 8), fixed order."""
    taps = [np.take(X, i, axis=axis) for i in range(8)]
    out = []
    for u in range(8):
        acc = M[u, 0] * taps[0]
        for i in range(1, 8):
            acc = acc + M[u, i] * taps[i]
        out.append(acc)
    return np.stack(out, axis=axis)


def _dct_quantise(plane: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Level shift, 8x8 DCT, ``rint(F / q) q``, inverse DCT of a plane whose sides are
    multiples of 8."""
    h, w = plane.shape
    C = dct_matrix()
    blocks = (plane - 128.0).reshape(h // 8, 8, w // 8, 8)
    F = _apply8(_apply8(blocks, C, 1), C, 3)
    qq = q[None, :, None, :]
    Fq = np.rint(F / qq) * qq
    back = _apply8(_apply8(Fq, C.T, 1), C.T, 3)
    return back.reshape(h, w) + 128.0


def _pad_to(a: NDArray, mult: int) -> NDArray:
    h, w = a.shape[:2]
    ph, pw = (-h) % mult, (-w) % mult
    if ph == 0 and pw == 0:
        return a
    pad = [(0, ph), (0, pw)] + [(0, 0)] * (a.ndim - 2)
    return np.pad(a, pad, mode="edge")


def _upsample2(c: NDArray[np.float64], axis: int) -> NDArray[np.float64]:
    """libjpeg's 'fancy' upsampling along one axis: 3/4 nearer + 1/4 farther sample."""
    n = c.shape[axis]
    idx = np.arange(n)
    prev = np.take(c, np.maximum(idx - 1, 0), axis=axis)
    nxt = np.take(c, np.minimum(idx + 1, n - 1), axis=axis)
    even = 0.75 * c + 0.25 * prev
    odd = 0.75 * c + 0.25 * nxt
    out = np.stack([even, odd], axis=axis + 1)
    shape = list(c.shape)
    shape[axis] = 2 * n
    return out.reshape(shape)


def jpeg_roundtrip(z: ArrayLike, quality: int) -> NDArray[np.uint8]:
    """Compress and decompress an 8-bit image with the baseline-JPEG model (:data:`JPEG_NOTE`).

    ``(H, W)`` images are coded as luminance only; ``(H, W, 3)`` as YCbCr with 4:2:0 chroma.
    Sides that are not multiples of the block (8, or 16 with subsampled chroma) are padded by
    repeating the last row/column, as encoders do, and cropped after decoding.
    """
    z = np.asarray(z)
    if z.dtype != np.uint8:
        raise CcdError("jpeg", f"expected an 8-bit image, got {z.dtype}")
    h, w = z.shape[:2]
    qy, qc = quant_table(quality), quant_table(quality, chroma=True)
    if z.ndim == 2:
        y = _dct_quantise(_pad_to(z.astype(np.float64), 8), qy)
        return np.clip(np.rint(y[:h, :w]), 0.0, 255.0).astype(np.uint8)
    if z.ndim != 3 or z.shape[2] != 3:
        raise CcdError("jpeg", f"expected (H, W) or (H, W, 3), got {z.shape}")
    rgb = _pad_to(z.astype(np.float64), 16)
    R, G, B = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    Y = np.clip(np.rint(0.299 * R + 0.587 * G + 0.114 * B), 0.0, 255.0)
    Cb = np.clip(np.rint(-0.168736 * R - 0.331264 * G + 0.5 * B + 128.0), 0.0, 255.0)
    Cr = np.clip(np.rint(0.5 * R - 0.418688 * G - 0.081312 * B + 128.0), 0.0, 255.0)

    def down(c: NDArray[np.float64]) -> NDArray[np.float64]:
        return 0.25 * (((c[0::2, 0::2] + c[0::2, 1::2]) + c[1::2, 0::2]) + c[1::2, 1::2])

    Y2 = _dct_quantise(Y, qy)
    Cb2 = _upsample2(_upsample2(_dct_quantise(down(Cb), qc), 0), 1) - 128.0
    Cr2 = _upsample2(_upsample2(_dct_quantise(down(Cr), qc), 0), 1) - 128.0
    out = np.stack([Y2 + 1.402 * Cr2,
                    (Y2 - 0.344136 * Cb2) - 0.714136 * Cr2,
                    Y2 + 1.772 * Cb2], axis=2)
    return np.clip(np.rint(out[:h, :w]), 0.0, 255.0).astype(np.uint8)
