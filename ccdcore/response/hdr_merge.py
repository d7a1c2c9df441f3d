"""The HDR merge of a bracket: radiance with per-pixel uncertainty (Tsin, Ramesh & Kanade 2001,
eqs. 9, 18 and 19), on frames in memory.

Given a calibrated camera -- the inverse response g, the white-balance scale a_k and offset b_k
of every image and the noise terms of eq. 7 -- the radiance of a pixel is the weighted mean of
its images' predictions (eq. 9)::

    Ê = Σ_k w_k (g(z_k) - b_k) / a_k,   w_k = (a_k / σ(a_k, z_k)) / Σ_i a_i / σ(a_i, z_i)   (eq. 18)

with standard deviation (eq. 19)::

    σ_E = √N / Σ_i a_i / σ(a_i, z_i)

over the N images whose code is usable at that pixel. (Each prediction (g(z_k) - b_k)/a_k has
standard deviation σ(a_k, z_k)/a_k; with the weights of eq. 18 the variance of their sum is
N / (Σ a_i/σ_i)², which is eq. 19.) The noise variance is eq. 7 with the shot term linear in the
signal, σ²(a, z) = σ_s² (g(z) - b) + σ_c1² + g'(z)² σ_c2² (docs/response.md), σ_c2 in codes.

A code is usable when it is not clipped (0 or levels - 1) and, by default, not within
``bloom_radius`` of a saturated pixel of the same image (sec. 2). Pixels without a usable code
are never returned as 0 or NaN without a flag:

* saturated in every image (the shortest exposure saturated): the radiance is the lower bound
  (g(levels - 1) - b_k) / a_k of the shortest exposure, σ_E is +inf, flag ``SATURATED``;
* dark in every image (the longest exposure at code 0): the upper bound (g(1) - b_k) / a_k of the
  longest exposure, σ_E +inf, flag ``DARK``;
* otherwise (every usable code lost to the blooming mask): merged from the unmasked, unclipped
  codes, flag ``BLOOMED``.

This is the kernel both paths run: :func:`ccdcore.response.hdr.merge_bracket` on whole frames in
this process, and :func:`ccdcore.distributed.band_merge` on each band of rows (with a halo) on a
Dask cluster, which is why it sits below both.  Nothing here reads files.  Every public name is
re-exported by :mod:`ccdcore.response.hdr`, its usual address.

Public objects
--------------
ResponseModel
    What the merge needs of one channel's calibration: g, a, b, σ_s, σ_c1, σ_c2.
HdrResult
    Radiance, σ_E and flags per pixel (and channel), the number of images merged per pixel.
merge(frames, models, ...)
    Eqs. 9, 18, 19 over a bracket's frames (one model per channel).
noise_sigma(model, z, k)
    σ(a_k, z) of eq. 7 for codes z of image k.
FLAG_OK, FLAG_DARK, FLAG_SATURATED, FLAG_BLOOMED
    The flag values (also the codes of ``flags.png``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import channels as chan
from ..errors import CcdError
from .brackets import DEFAULT_BLOOM_RADIUS, bloom_mask

__all__ = ["ResponseModel", "HdrResult", "merge", "noise_sigma", "FLAG_OK", "FLAG_DARK",
           "FLAG_SATURATED", "FLAG_BLOOMED"]

FLAG_OK, FLAG_DARK, FLAG_SATURATED, FLAG_BLOOMED = 0, 1, 2, 3


@dataclass(frozen=True, eq=False)
class ResponseModel:
    """One channel's calibration as the merge uses it.

    ``g`` has one value per code (levels = g.size); ``a``, ``b`` one per image, in the order of
    the frames given to :func:`merge`; ``sigma_s``, ``sigma_c1`` in units of g, ``sigma_c2`` in
    codes (eq. 7).
    """

    g: NDArray[np.float64]
    a: NDArray[np.float64]
    b: NDArray[np.float64]
    sigma_s: float
    sigma_c1: float
    sigma_c2: float

    @classmethod
    def of(cls, source: Any) -> "ResponseModel":
        """From any object with those attributes (e.g. a response estimate)."""
        return cls(np.asarray(source.g, np.float64), np.asarray(source.a, np.float64),
                   np.asarray(source.b, np.float64), float(source.sigma_s or 0.0),
                   float(source.sigma_c1 or 0.0), float(source.sigma_c2 or 0.0))

    @property
    def levels(self) -> int:
        return int(self.g.size)


@dataclass(frozen=True, eq=False)
class HdrResult:
    """The merged bracket: ``radiance`` and ``sigma`` (float64, the frames' shape), ``flags``
    (uint8, same shape) and ``used`` (how many images each value merged), per channel in
    ``channels`` order along the last axis for colour."""

    radiance: NDArray[np.float64]
    sigma: NDArray[np.float64]
    flags: NDArray[np.uint8]
    used: NDArray[np.int16]
    channels: tuple[str, ...]
    layout: str

    def flag_image(self) -> NDArray[np.uint8]:
        """One flag per pixel (the largest over the channels): what ``flags.png`` holds."""
        return self.flags if self.flags.ndim == 2 else self.flags.max(axis=2)


def noise_sigma(model: ResponseModel, z: ArrayLike, k: int) -> NDArray[np.float64]:
    """σ(a_k, z) of eq. 7 (linear shot term) for codes ``z`` of image ``k``, in units of g."""
    z = np.asarray(z)
    gz = model.g[z]
    dg = np.gradient(model.g)[z]
    var = (model.sigma_s ** 2 * np.maximum(gz - model.b[k], 0.0) + model.sigma_c1 ** 2
           + (dg * model.sigma_c2) ** 2)
    return np.sqrt(var)


def _merge_plane(planes: list[NDArray], model: ResponseModel, bloom_radius: int
                 ) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    L = model.levels
    z = np.stack([np.asarray(p) for p in planes]).astype(np.int64)      # (N, H, W)
    N = z.shape[0]
    if model.a.size != N or model.b.size != N:
        raise CcdError("response", f"the calibration has {model.a.size} images, the bracket "
                                   f"{N}")
    if int(z.max()) >= L or int(z.min()) < 0:
        raise CcdError("bracket", f"codes outside 0..{L - 1} of the calibration's response")
    clipped = (z <= 0) | (z >= L - 1)
    bloomed = np.stack([bloom_mask(p, L, bloom_radius) for p in z])
    usable = ~clipped & ~bloomed
    fallback = ~clipped
    a = model.a[:, None, None]
    b = model.b[:, None, None]
    sig = np.stack([noise_sigma(model, z[k], k) for k in range(N)])
    sig = np.maximum(sig, 1e-12)
    pred = (model.g[z] - b) / a

    def combine(mask: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        q = np.where(mask, a / sig, 0.0)                 # a_i / σ(a_i, z_i)
        total = q.sum(axis=0)
        n = mask.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            radiance = (q * np.where(mask, pred, 0.0)).sum(axis=0) / total   # eqs. 9, 18
            sigma = np.sqrt(n) / total                                        # eq. 19
        return radiance, sigma, n

    radiance, sigma, n = combine(usable)
    flags = np.zeros(z.shape[1:], np.uint8)
    none = n == 0
    if none.any():
        r2, s2, n2 = combine(fallback)
        bloom_only = none & (n2 > 0)
        radiance = np.where(bloom_only, r2, radiance)
        sigma = np.where(bloom_only, s2, sigma)
        n = np.where(bloom_only, n2, n)
        flags[bloom_only] = FLAG_BLOOMED
        rest = none & (n2 == 0)
        order = np.argsort(model.a)
        short, long_ = int(order[0]), int(order[-1])
        sat = rest & (z[short] >= L - 1)
        dark = rest & ~sat
        radiance = np.where(sat, (model.g[L - 1] - model.b[short]) / model.a[short], radiance)
        radiance = np.where(dark, (model.g[1] - model.b[long_]) / model.a[long_], radiance)
        sigma = np.where(rest, np.inf, sigma)
        flags[sat] = FLAG_SATURATED
        flags[dark] = FLAG_DARK
    return radiance, sigma, flags, n.astype(np.int16)


def merge(frames: Sequence[ArrayLike], models: Mapping[str, Any] | Any, *,
          layout: str | None = None, bloom_radius: int = DEFAULT_BLOOM_RADIUS) -> HdrResult:
    """Radiance and σ_E of a bracket (eqs. 9, 18, 19).

    ``frames`` are the bracket's images in the order of the models' ``a`` and ``b``; ``models``
    maps each channel name (:func:`ccdcore.channels.split_channels`) to its
    :class:`ResponseModel` (or an object with the same attributes); a mono bracket may pass one
    model.
    """
    if len(frames) < 1:
        raise CcdError("bracket", "no frames to merge")
    arrays = [np.asarray(f) for f in frames]
    for k, f in enumerate(arrays):
        if f.shape != arrays[0].shape:
            raise CcdError(f"frame {k}", f"shape {f.shape} differs from the first frame's "
                                         f"{arrays[0].shape}")
        if not np.issubdtype(f.dtype, np.integer):
            raise CcdError(f"frame {k}", f"expected integer codes, got {f.dtype}")
    lay = chan.check_layout(arrays[0].shape, layout, "bracket")
    split = [chan.split_channels(a, lay) for a in arrays]
    names = tuple(split[0])
    if not isinstance(models, Mapping):
        if len(names) != 1:
            raise CcdError("response", f"one model per channel is needed ({', '.join(names)})")
        models = {names[0]: models}
    missing = [c for c in names if c not in models]
    if missing:
        raise CcdError("response", f"no calibration for channel(s) {', '.join(missing)}")
    out = [_merge_plane([s[c] for s in split], ResponseModel.of(models[c]), bloom_radius)
           for c in names]
    if len(out) == 1:
        r, s, f, n = out[0]
    else:
        r, s, f, n = (np.stack([o[i] for o in out], axis=-1) for i in range(4))
    return HdrResult(r, s, f, n, names, lay)
