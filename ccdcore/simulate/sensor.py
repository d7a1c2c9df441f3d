"""The Healey–Kondepudy CCD camera model as reusable, vectorised building blocks.

A pixel's digital number is (eq. 20 of Healey & Kondepudy 1994)

    D = (K·I + N_DC + N_S + N_R)·A + N_Q,

with K the fixed-pattern gain of the collection site (mean 1, spatial std σ_K), I the ideal number of
photoelectrons, N_DC the dark electrons, N_S the Poisson shot noise of K·I + N_DC, N_R the read noise
(σ_R electrons), A the gain in DN per electron and N_Q the quantisation noise (variance q²/12).  Real
cameras add a constant black level (offset, in DN) before the ADC; it is a parameter here (default 0,
which is the paper's model) and enters the mean only.  Optionally a soft "knee" compresses the
analogue value near the top of the range (the non-linear end of a camera's response, used by the
de Lasarte preset); without it the response is exactly linear up to clipping.

Public objects
--------------
SensorModel
    Frozen dataclass with the camera parameters and the methods ``draw_K``, ``draw_dark_map``,
    ``dark_electrons``, ``expose`` (one simulated integer frame), ``response`` and
    ``response_slope`` (analogue knee), ``expected_mean`` (eq. 22), ``expected_variance``
    (eqs. 26–28), ``expected_pixel_mean`` (per-pixel mean including full well, knee and clipping,
    Gaussian approximation) and the properties ``sigma_c2`` (eq. 27), ``full_scale``, ``dtype``.
child_rng
    A named, order-independent child generator of a seed (``SeedSequence`` spawn keys).
smooth_field
    A smooth random relative field (mean 0, given standard deviation) for illumination patterns.
clipped_normal_mean
    E[clip(X, lo, hi)] for X ~ N(m, s²), vectorised.
"""
from __future__ import annotations

import math
import zlib
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import ndtr

from . import _det

__all__ = ["SensorModel", "child_rng", "smooth_field", "clipped_normal_mean"]


def child_rng(seed: int, name: str) -> np.random.Generator:
    """A generator derived deterministically from ``seed`` and a stream ``name``.

    The stream key is the CRC-32 of ``name``, so streams do not depend on the order in which they
    are created and adding a new stream never changes an existing one.
    """
    ss = np.random.SeedSequence(int(seed), spawn_key=(zlib.crc32(name.encode("utf-8")),))
    return np.random.default_rng(ss)


def smooth_field(shape: tuple[int, int], rng: np.random.Generator, std: float,
                 order: int = 2) -> NDArray[np.float64]:
    """A smooth random field of zero spatial mean and spatial standard deviation ``std``.

    A random bivariate polynomial of total degree ``order`` over normalised coordinates in
    [-1, 1] plus a broad Gaussian blob at a random position: the kind of slow variation a real lamp
    and card produce.  Used for nonuniform illumination (sec. III, eq. 10 of Healey & Kondepudy).
    Computed with basic arithmetic and :func:`ccdcore.simulate._det.exp`, so the same bits on
    every CPU.
    """
    h, w = shape
    y, x = np.meshgrid(np.linspace(-1.0, 1.0, h), np.linspace(-1.0, 1.0, w), indexing="ij")
    # powers by repeated multiplication and the CPU-independent exp of ._det: the field feeds
    # the Poisson means of the frames, so it must not change with NumPy's vector loops
    xp, yp = [np.ones(shape)], [np.ones(shape)]
    for _ in range(order):
        xp.append(xp[-1] * x)
        yp.append(yp[-1] * y)
    f = np.zeros(shape)
    for i in range(order + 1):
        for j in range(order + 1 - i):
            if i + j:
                f += rng.normal() * xp[i] * yp[j]
    cx, cy = rng.uniform(-0.8, 0.8, size=2)
    width = rng.uniform(0.5, 1.0)
    dx, dy = x - cx, y - cy
    f += rng.normal() * _det.exp(-(dx * dx + dy * dy) / (2 * width * width))
    f -= f.mean()
    sd = f.std()
    return f * (std / sd) if sd > 0 else f


def clipped_normal_mean(m: ArrayLike, s: ArrayLike, lo: float, hi: float) -> NDArray[np.float64]:
    """E[clip(X, lo, hi)] for X ~ N(m, s²), elementwise (s > 0)."""
    m = np.asarray(m, dtype=float)
    s = np.maximum(np.asarray(s, dtype=float), 1e-12)
    a = (lo - m) / s
    b = (hi - m) / s
    pa, pb = ndtr(a), ndtr(b)
    phi_a = _det.exp(-0.5 * a * a) / math.sqrt(2 * math.pi)
    phi_b = _det.exp(-0.5 * b * b) / math.sqrt(2 * math.pi)
    return lo * pa + hi * (1.0 - pb) + m * (pb - pa) + s * (phi_a - phi_b)


@dataclass(frozen=True)
class SensorModel:
    """Parameters of the camera model of eq. 20 (Healey & Kondepudy 1994) plus a black level.

    Parameters
    ----------
    A
        Combined gain of amplifier and camera circuitry, DN per electron (eq. 3).
    read_noise_e
        σ_R, standard deviation of the read noise N_R in electrons.
    dark_current_e
        Mean number of dark electrons E_DC per pixel and frame at the exposure ``exposure_ref``.
    dark_spatial_std
        Relative spatial standard deviation of E_DC(a, b) over the array (dark-signal
        nonuniformity); the dark map is gamma distributed, so it stays positive.
    sigma_K
        Spatial standard deviation of the fixed-pattern gain K(a, b), whose mean is 1 (sec. II-B).
    bits
        ADC bit depth b; output values are integers in [0, 2^b − 1] (eq. 5).
    black_level_dn
        Constant offset in DN added before quantisation (0 in the paper's model).  A negative value
        makes the ADC clip the dark image at zero (a "zero dark image" setting).
    full_well_e
        Electrons a collection site holds; charge beyond it is lost (no blooming).  ``None``: no limit.
    q
        Quantisation step in DN (1 for integer DN).
    exposure_ref
        Exposure (seconds) at which ``dark_current_e`` applies; dark electrons scale linearly with
        exposure (sec. II-B).  ``None``: the dark signal does not depend on exposure.
    knee_dn
        Optional analogue value (DN, after the black level) above which the response is compressed
        smoothly towards saturation; ``None``: linear up to the ADC clip.
    """

    A: float = 0.0034
    read_noise_e: float = 297.0
    dark_current_e: float = 3150.0
    dark_spatial_std: float = 0.05
    sigma_K: float = 3.7e-3
    bits: int = 8
    black_level_dn: float = 0.0
    full_well_e: float | None = None
    q: float = 1.0
    exposure_ref: float | None = None
    knee_dn: float | None = None

    # ---- derived quantities -----------------------------------------------------------------
    @property
    def full_scale(self) -> int:
        """Largest output value, 2^b − 1 (eq. 5)."""
        return int(2 ** int(self.bits) - 1)

    @property
    def dtype(self) -> np.dtype:
        """Output sample type: uint8 for b ≤ 8, else uint16."""
        return np.dtype(np.uint8 if self.bits <= 8 else np.uint16)

    @property
    def sigma_c2(self) -> float:
        """σ_C² = A²σ_R² + q²/12 in DN², the signal-independent noise variance (eq. 27)."""
        return float(self.A ** 2 * self.read_noise_e ** 2 + self.q ** 2 / 12.0)

    def to_dict(self) -> dict[str, Any]:
        """The parameters plus ``sigma_c2`` and ``full_scale`` as plain JSON types."""
        d = asdict(self)
        d["sigma_c2"] = self.sigma_c2
        d["full_scale"] = self.full_scale
        return d

    # ---- random maps ------------------------------------------------------------------------
    def draw_K(self, shape: tuple[int, ...], rng: np.random.Generator) -> NDArray[np.float64]:
        """Fixed-pattern gains K(a, b): independent N(1, σ_K²) per site, floored at 0.01."""
        K = 1.0 + self.sigma_K * rng.standard_normal(shape)
        return np.maximum(K, 0.01)

    def draw_dark_map(self, shape: tuple[int, ...], rng: np.random.Generator) -> NDArray[np.float64]:
        """Mean dark electrons E_DC(a, b) at ``exposure_ref``: gamma distributed, mean
        ``dark_current_e`` and relative spatial std ``dark_spatial_std``."""
        mean = float(self.dark_current_e)
        s = float(self.dark_spatial_std)
        if mean <= 0:
            return np.zeros(shape)
        if s <= 0:
            return np.full(shape, mean)
        k = 1.0 / (s * s)
        return rng.gamma(k, mean / k, size=shape)

    def dark_electrons(self, dark_map: ArrayLike, exposure: float | None = None) -> NDArray[np.float64]:
        """E_DC(a, b) at ``exposure`` seconds (scaled from ``exposure_ref`` when both are given)."""
        d = np.asarray(dark_map, dtype=float)
        if self.exposure_ref is None or exposure is None:
            return d
        return d * (float(exposure) / float(self.exposure_ref))

    # ---- the forward model ------------------------------------------------------------------
    def response(self, V: ArrayLike) -> NDArray[np.float64]:
        """Analogue value (DN, incl. black level) after the optional soft knee.

        Identity below ``knee_dn``; above, ``knee + w·tanh((V − knee)/w)`` with
        ``w = full_scale + 1 − knee``, so the value approaches (and the ADC clips at) full scale.
        ``tanh`` is the CPU-independent one of :mod:`ccdcore.simulate._det` (the value is rounded
        to a digital number).
        """
        V = np.asarray(V, dtype=float)
        if self.knee_dn is None:
            return V
        k = float(self.knee_dn)
        w = self.full_scale + 1.0 - k
        return np.where(V > k, k + w * _det.tanh((V - k) / w), V)

    def response_slope(self, V: ArrayLike) -> NDArray[np.float64]:
        """d response / dV: 1 below the knee, 1 − tanh² above."""
        V = np.asarray(V, dtype=float)
        if self.knee_dn is None:
            return np.ones_like(V)
        k = float(self.knee_dn)
        w = self.full_scale + 1.0 - k
        t = _det.tanh((V - k) / w)
        return np.where(V > k, 1.0 - t * t, 1.0)

    def expose(self, I_e: ArrayLike, K: ArrayLike, dark_e: ArrayLike,
               rng: np.random.Generator) -> NDArray[np.integer]:
        """One frame D(a, b) of eq. 20.

        Poisson electrons with mean K·I + E_DC (shot noise N_S on signal and dark current), capped
        at the full well, plus Gaussian read noise N_R (σ_R electrons), times A, plus the black
        level, through the optional knee, rounded to the nearest multiple of q (N_Q, eq. 4) and
        clipped to [0, 2^b − 1] (eq. 5).

        Parameters
        ----------
        I_e
            Ideal photoelectrons I(a, b) (eq. 16); any shape.
        K
            Fixed-pattern gains, broadcastable to ``I_e``.
        dark_e
            Mean dark electrons E_DC(a, b) for this exposure, broadcastable to ``I_e``.
        rng
            Random generator (consumed: one Poisson and one normal draw per pixel).

        Returns
        -------
        numpy.ndarray
            Integer frame of :attr:`dtype`, shape of ``I_e`` broadcast with ``K`` and ``dark_e``.
        """
        lam = np.asarray(K, dtype=float) * np.asarray(I_e, dtype=float) + np.asarray(dark_e, dtype=float)
        lam = np.maximum(lam, 0.0)
        electrons = rng.poisson(lam).astype(np.float64)
        if self.full_well_e is not None:
            np.minimum(electrons, float(self.full_well_e), out=electrons)
        electrons += self.read_noise_e * rng.standard_normal(lam.shape)
        V = self.response(electrons * self.A + self.black_level_dn)
        D = np.rint(V / self.q) * self.q
        np.clip(D, 0, self.full_scale, out=D)
        return D.astype(self.dtype)

    # ---- expectations (for truth and tests) -------------------------------------------------
    def expected_mean(self, I_e: ArrayLike, K: ArrayLike = 1.0,
                      dark_e: ArrayLike = 0.0) -> NDArray[np.float64]:
        """μ(a, b) = K·I·A + E_DC·A (eq. 22) plus the black level; no knee, no clipping."""
        return (np.asarray(K, dtype=float) * np.asarray(I_e, dtype=float)
                + np.asarray(dark_e, dtype=float)) * self.A + self.black_level_dn

    def expected_variance(self, I_e: ArrayLike, K: ArrayLike = 1.0,
                          dark_e: ArrayLike = 0.0) -> NDArray[np.float64]:
        """σ²_N(a, b) = A²(K·I + E_DC) + σ_C² (eqs. 26–28); no full-well cap, knee or clipping."""
        return (np.asarray(K, dtype=float) * np.asarray(I_e, dtype=float)
                + np.asarray(dark_e, dtype=float)) * self.A ** 2 + self.sigma_c2

    def expected_pixel_mean(self, I_e: ArrayLike, K: ArrayLike = 1.0,
                            dark_e: ArrayLike = 0.0) -> NDArray[np.float64]:
        """Per-pixel E[D] including the full well, knee and ADC clipping (approximation).

        The knee is applied to the noiseless mean; the clip to [0, 2^b − 1] uses a Gaussian of
        variance σ²_N (eq. 28) with the rounding as additive uniform noise (Gaussian approximation,
        exact in the linear range far from both ends).
        """
        e = np.asarray(K, dtype=float) * np.asarray(I_e, dtype=float) + np.asarray(dark_e, dtype=float)
        if self.full_well_e is not None:
            e = np.minimum(e, float(self.full_well_e))
        V = e * self.A + self.black_level_dn
        m = self.response(V)
        slope = self.response_slope(V)
        # analogue noise passes the knee with its local slope; rounding adds q²/12 (uniform), so
        # the clip points stay at 0 and full scale
        s = np.sqrt((e * self.A ** 2 + (self.A * self.read_noise_e) ** 2) * slope ** 2
                    + self.q ** 2 / 12.0)
        return clipped_normal_mean(m, s, 0.0, float(self.full_scale))
