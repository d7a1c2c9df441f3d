"""Deterministic elementwise math for the simulators: the same bits on every CPU.

NumPy picks its ``exp``, ``log``, ``power``, ``tanh``, ``cos``, ``arctan`` ... loops at run time
from the CPU's vector features (AVX2, AVX-512, NEON), and those loops differ in the last bit
(one ulp) from one another and from the C library.  A simulated digital number is
``rint(x)``: a one-ulp change of ``x`` flips it when ``x`` lies within an ulp of a half
integer, and a Poisson draw can flip the same way with its mean.  So everything that feeds a
pixel value is computed here from operations IEEE 754 rounds exactly -- ``+ - * /``, ``sqrt``,
``rint``/``floor``, ``frexp``/``ldexp`` -- each a separate NumPy ufunc call (NumPy never fuses a
multiply and an add across calls, so no FMA contraction either), in a fixed order.  The result is
the same on x86-64 (any vector extension) and arm64.

The algorithms are those of fdlibm (Sun Microsystems, 1993; ``e_exp.c`` and ``e_log.c``, whose
error is below one ulp); ``pow`` and ``tanh`` are built on them and are accurate to a few ulps,
far beyond what a simulator needs.  Correlations (:func:`gaussian_filter`,
:func:`correlate_footprint`) are sums of shifted arrays in a fixed order, instead of
``scipy.ndimage`` whose compiled loops may be contracted into FMAs on some platforms.

Public objects
--------------
exp(x), log(x), pow(x, y), tanh(x)
    Elementwise float64 functions.
gaussian_kernel1d(sigma, radius)
    Normalised Gaussian weights (as ``scipy.ndimage``'s, deterministic).
gaussian_filter(a, sigma, truncate=4.0)
    Separable Gaussian smoothing with ``mode="reflect"`` (as ``scipy.ndimage.gaussian_filter``).
correlate_footprint(a, footprint)
    Sum of ``a`` over a boolean footprint around every pixel, zero outside (``mode="constant"``).
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["exp", "log", "pow", "tanh", "gaussian_kernel1d", "gaussian_filter",
           "correlate_footprint"]

# ---- fdlibm constants (e_exp.c, e_log.c) -----------------------------------------------------
_LN2_HI = 6.93147180369123816490e-01    # 0x3fe62e42fee00000: k * _LN2_HI is exact for |k| < 2^20
_LN2_LO = 1.90821492927058770002e-10
_INV_LN2 = 1.44269504088896338700e+00
_P1 = 1.66666666666666019037e-01
_P2 = -2.77777777770155933842e-03
_P3 = 6.61375632143793436117e-05
_P4 = -1.65339022054652515390e-06
_P5 = 4.13813679705723846039e-08
_LG1 = 6.666666666666735130e-01
_LG2 = 3.999999999940941908e-01
_LG3 = 2.857142874366239149e-01
_LG4 = 2.222219843214978396e-01
_LG5 = 1.818357216161805012e-01
_LG6 = 1.531383769920937332e-01
_LG7 = 1.479819860511658591e-01
_SQRT_HALF = 0.70710678118654752440
_EXP_OVERFLOW = 7.09782712893383973096e+02
_EXP_UNDERFLOW = -7.45133219101941108420e+02


def exp(x: ArrayLike) -> NDArray[np.float64]:
    """``e**x`` elementwise (fdlibm ``e_exp.c``: error below one ulp), float64."""
    x = np.asarray(x, dtype=np.float64)
    xc = np.where(np.isnan(x), 0.0, np.clip(x, -746.0, 710.0))  # k, ldexp in range; fixed below
    k = np.rint(xc * _INV_LN2)
    hi = xc - k * _LN2_HI
    lo = k * _LN2_LO
    r = hi - lo
    t = r * r
    c = r - t * (_P1 + t * (_P2 + t * (_P3 + t * (_P4 + t * _P5))))
    y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi)
    out = np.ldexp(y, k.astype(np.int32))
    out = np.where(x > _EXP_OVERFLOW, np.inf, out)
    out = np.where(x < _EXP_UNDERFLOW, 0.0, out)
    return np.where(np.isnan(x), np.nan, out)


def log(x: ArrayLike) -> NDArray[np.float64]:
    """Natural logarithm elementwise (fdlibm ``e_log.c``: error below one ulp), float64.

    ``log(0) = -inf``, ``log(inf) = inf``, NaN for negative arguments and NaN.
    """
    x = np.asarray(x, dtype=np.float64)
    ok = np.isfinite(x) & (x > 0.0)
    m, e = np.frexp(np.where(ok, x, 1.0))                # m in [0.5, 1), exact
    small = m < _SQRT_HALF
    m = np.where(small, m * 2.0, m)                      # m in [sqrt(1/2), sqrt(2)), exact
    k = (e - small.astype(e.dtype)).astype(np.float64)
    f = m - 1.0                                          # exact (Sterbenz)
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    t1 = w * (_LG2 + w * (_LG4 + w * _LG6))
    t2 = z * (_LG1 + w * (_LG3 + w * (_LG5 + w * _LG7)))
    R = t2 + t1
    hfsq = 0.5 * f * f
    out = k * _LN2_HI - ((hfsq - (s * (hfsq + R) + k * _LN2_LO)) - f)
    out = np.where(x == 0.0, -np.inf, out)
    out = np.where(x == np.inf, np.inf, out)
    return np.where((x < 0.0) | np.isnan(x), np.nan, out)


def pow(x: ArrayLike, y: float) -> NDArray[np.float64]:
    """``x**y`` elementwise for ``x >= 0`` as ``exp(y log x)``, float64.

    Relative error about ``|y log x|`` ulps (a few ulps for the simulators' arguments);
    ``pow(0, y) = 0`` for ``y > 0``, ``pow(1, y) = 1`` exactly.
    """
    x = np.asarray(x, dtype=np.float64)
    y = float(y)
    if y == 0.0:
        return np.ones_like(x)
    if y == 1.0:
        return x.copy()
    return exp(y * log(x))


def tanh(x: ArrayLike) -> NDArray[np.float64]:
    """Hyperbolic tangent elementwise as ``1 - 2/(e^{2x} + 1)`` (odd-symmetric), float64.

    Absolute error a few ulps of 1 (what the response knee needs: it is scaled by a width of DNs
    and added to the knee level).
    """
    x = np.asarray(x, dtype=np.float64)
    ax = np.abs(x)
    t = 1.0 - 2.0 / (exp(2.0 * ax) + 1.0)
    return np.where(x < 0.0, -t, t)


def gaussian_kernel1d(sigma: float, radius: int) -> NDArray[np.float64]:
    """The weights ``exp(-x^2 / (2 sigma^2))``, ``x = -radius .. radius``, normalised to sum 1.

    Symmetric by construction (``w[radius - j] == w[radius + j]``).
    """
    x = np.arange(-int(radius), int(radius) + 1).astype(np.float64)
    phi = exp((-0.5 / (float(sigma) * float(sigma))) * (x * x))
    return phi / phi.sum()


def gaussian_filter(a: ArrayLike, sigma: float, truncate: float = 4.0) -> NDArray[np.float64]:
    """Gaussian smoothing of a 2-D (or N-D) float array along every axis, ``mode="reflect"``.

    The same weights and boundary handling as ``scipy.ndimage.gaussian_filter(a, sigma,
    mode="reflect", truncate=truncate)`` (radius ``int(truncate * sigma + 0.5)``; reflect:
    ``d c b a | a b c d | d c b a``); the sums are taken in a fixed order, so the result agrees
    with SciPy's to rounding and is the same on every CPU.
    """
    out = np.asarray(a, dtype=np.float64)
    sigma = float(sigma)
    if sigma <= 1e-15:
        return out.copy()
    radius = int(float(truncate) * sigma + 0.5)
    w = gaussian_kernel1d(sigma, radius)
    for axis in range(out.ndim):
        n = out.shape[axis]
        pad = [(0, 0)] * out.ndim
        pad[axis] = (radius, radius)
        # np.pad "symmetric" is scipy.ndimage "reflect" (the edge sample is repeated), also when
        # the radius exceeds the length (the reflection is repeated)
        ext = np.pad(out, pad, mode="symmetric")

        def take(offset: int, ext=ext, axis=axis, n=n) -> NDArray[np.float64]:
            sl = [slice(None)] * out.ndim
            sl[axis] = slice(radius + offset, radius + offset + n)
            return ext[tuple(sl)]

        acc = w[radius] * take(0)
        for j in range(1, radius + 1):
            acc = acc + w[radius + j] * (take(-j) + take(j))
        out = acc
    return out


def correlate_footprint(a: ArrayLike, footprint: ArrayLike) -> NDArray[np.float64]:
    """``sum(a[y + dy, x + dx] for (dy, dx) in footprint)`` for every pixel, 0 outside the array.

    ``footprint`` is a boolean ``(2r + 1, 2r + 1)`` array centred on the pixel; ``a`` is 2-D.
    The sum runs over the footprint in row-major order.
    """
    a = np.asarray(a, dtype=np.float64)
    fp = np.asarray(footprint, dtype=bool)
    ry, rx = fp.shape[0] // 2, fp.shape[1] // 2
    h, w = a.shape
    ext = np.zeros((h + 2 * ry, w + 2 * rx))
    ext[ry:ry + h, rx:rx + w] = a
    acc = np.zeros_like(a)
    for dy, dx in zip(*np.nonzero(fp)):
        acc = acc + ext[dy:dy + h, dx:dx + w]
    return acc
