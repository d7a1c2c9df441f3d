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
this process, and :func:`ccdcore.distributed.client.band_merge` on each band of rows (with a halo)
on a Dask cluster, which is why it sits below both.  Nothing here reads files.  Every public name is
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
FLAG_OK, FLAG_DARK, FLAG_SATURATED, FLAG_BLOOMED, FLAG_MOVING
    The flag values (also the codes of ``flags.png``).

A merged radiance can be 0 or below where the true one is near black: eq. 9 averages the
images' predictions (g(z) - b_k)/a_k, and a dark code's prediction scatters around zero (and a
fitted curve's toe can lie below it). Such a value with its σ_E says "consistent with black";
it is not clipped, which would bias every dark pixel upwards.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import channels as chan
from ..errors import CcdError
from .brackets import DEFAULT_BLOOM_RADIUS, bloom_mask

__all__ = ["ResponseModel", "HdrResult", "merge", "noise_sigma", "FLAG_OK", "FLAG_DARK",
           "FLAG_SATURATED", "FLAG_BLOOMED", "FLAG_MOVING"]

FLAG_OK, FLAG_DARK, FLAG_SATURATED, FLAG_BLOOMED = 0, 1, 2, 3
#: merged from one exposure: its exposures disagree beyond the noise model (a moving object;
#: :mod:`ccdcore.response.moving`)
FLAG_MOVING = 4


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

    def flag_counts(self) -> dict[str, int]:
        """Pixels of :meth:`flag_image` by flag: ``merged``, ``dark`` (an upper bound: dark in
        every image), ``saturated`` (a lower bound), ``bloomed`` (merged from codes the
        blooming mask had removed), ``moving`` (merged from one exposure: a moving object)."""
        counts = np.bincount(self.flag_image().ravel(), minlength=5)
        return {name: int(counts[f]) for name, f in (
            ("merged", FLAG_OK), ("dark", FLAG_DARK), ("saturated", FLAG_SATURATED),
            ("bloomed", FLAG_BLOOMED), ("moving", FLAG_MOVING))}

    def describe(self) -> list[str]:
        """What the radiance is, in a few lines: its scale and range, its relative error, and
        the pixels flagged (the words ``hdr`` prints)."""
        ok = (self.flags == FLAG_OK) & np.isfinite(self.radiance) & (self.radiance > 0)
        lines = ["radiance E = g(z)/t per pixel: the relative exposure per second on the "
                 "response's own scale (g(z_hi) = 0.9), no absolute unit; sigma the same "
                 "units (eq. 19)"]
        if ok.any():
            e = self.radiance[ok]
            rel = self.sigma[ok] / e
            lo, med, hi = np.percentile(e, [1, 50, 99])
            lines.append(f"merged pixels: E {lo:.3g} … {hi:.3g} (1st to 99th percentile, "
                         f"median {med:.3g}; a range of {hi / lo:.3g}), relative error σ_E/E "
                         f"median {100 * float(np.median(rel)):.2g} %")
        black = (self.flags == FLAG_OK) & (self.radiance <= 0)
        if black.any():
            within = black & (self.radiance >= -2.0 * self.sigma)
            lines.append(f"{int(np.count_nonzero(black))} merged values at or below 0 (dark "
                         f"codes scatter around black; {int(np.count_nonzero(within))} of them "
                         "within 2 σ_E of it): kept, not clipped, so dark pixels stay unbiased")
        c = self.flag_counts()
        total = max(1, sum(c.values()))
        lines.append(f"flags.png: {c['merged']} merged ({100 * c['merged'] / total:.3g} %), "
                     f"{c['dark']} dark in every image (1: an upper bound), {c['saturated']} "
                     f"saturated in every image (2: a lower bound), {c['bloomed']} merged from "
                     f"codes the blooming mask had removed (3), {c['moving']} merged from one "
                     "exposure because something moved there (4)")
        return lines


def noise_sigma(model: ResponseModel, z: ArrayLike, k: int) -> NDArray[np.float64]:
    """σ(a_k, z) of eq. 7 (linear shot term) for codes ``z`` of image ``k``, in units of g."""
    z = np.asarray(z)
    gz = model.g[z]
    dg = np.gradient(model.g)[z]
    var = (model.sigma_s ** 2 * np.maximum(gz - model.b[k], 0.0) + model.sigma_c1 ** 2
           + (dg * model.sigma_c2) ** 2)
    return np.sqrt(var)


#: output pixels per band of the merge (with its blooming halo): a band's temporaries are a
#: dozen float64 arrays of this size, whatever the frame's size and the number of images
BAND_PIXELS = 2 ** 18
#: threads merging bands at once (NumPy releases the GIL in its per-pixel loops)
MERGE_THREADS = max(1, min(2, os.cpu_count() or 1))


def _tables(model: ResponseModel) -> tuple[NDArray, NDArray]:
    """Per image k and code z: a_k / σ(a_k, z) (floored σ, eq. 18) and (g(z) - b_k) / a_k, the
    values the merge looks up per pixel (the same float64 operations as on the pixels), both
    0 at the clipped codes 0 and L - 1 (never merged)."""
    L, N = model.levels, model.a.size
    codes = np.arange(L)
    q = np.empty((N, L))
    pred = np.empty((N, L))
    for k in range(N):
        q[k] = model.a[k] / np.maximum(noise_sigma(model, codes, k), 1e-12)
        pred[k] = (model.g - model.b[k]) / model.a[k]
    q[:, [0, L - 1]] = 0.0
    pred[:, [0, L - 1]] = 0.0
    return q, pred


def _combine(zs: list[NDArray], blooms: list[NDArray | None] | None, tables: tuple[NDArray, NDArray]
             ) -> tuple[NDArray, NDArray, NDArray]:
    """Eqs. 9, 18, 19 over the unclipped codes of the images, those in ``blooms`` left out,
    image after image (the order of a sum over the stacked images' axis: bit for bit)."""
    q, pred = tables
    unclipped = np.ones(q.shape[1], bool)
    unclipped[[0, -1]] = False
    total = num = n = None
    for k, z8 in enumerate(zs):
        z = z8.astype(np.intp)            # (NumPy's take is ten times faster with intp indices)
        qk = np.take(q[k], z)                                   # a_k / σ(a_k, z_k), 0 if unused
        term = np.take(pred[k], z)
        used = np.take(unclipped, z)
        del z
        bloom = None if blooms is None else blooms[k]
        if bloom is not None:
            np.copyto(qk, 0.0, where=bloom)
            np.copyto(term, 0.0, where=bloom)
            used &= ~bloom
        term *= qk
        if total is None:
            total, num, n = qk, term, used.astype(np.int16)
        else:
            total += qk
            num += term
            n += used
    with np.errstate(invalid="ignore", divide="ignore"):
        num /= total                                                  # eqs. 9, 18
        sigma = np.sqrt(n.astype(np.float64)) / total                 # eq. 19
    return num, sigma, n


def _merge_band(planes: list[NDArray], model: ResponseModel, tables: tuple[NDArray, NDArray],
                bloom_radius: int, saturates: list[bool], lo: int, y0: int, y1: int, hi: int,
                out: tuple[NDArray, NDArray, NDArray, NDArray]) -> None:
    """Rows ``y0 .. y1`` of the merge, the blooming masks made on rows ``lo .. hi`` (the halo
    that the disk reaches), written into ``out``'s rows. ``saturates[k]``: image k has a
    saturated pixel somewhere (else it has no blooming mask)."""
    L = model.levels
    zs = [p[y0:y1] for p in planes]
    blooms: list[NDArray | None] = []
    for p, sat in zip(planes, saturates):
        bloom = bloom_mask(p[lo:hi], L, bloom_radius)[y0 - lo:y1 - lo] if sat else None
        blooms.append(bloom if bloom is not None and bloom.any() else None)
    radiance, sigma, n = _combine(zs, blooms, tables)
    flags = np.zeros(radiance.shape, np.uint8)
    ys, xs = np.nonzero(n == 0)
    if ys.size:             # no usable code: the pixels merged again without blooming masks
        sub = [z[ys, xs] for z in zs]
        r2, s2, n2 = _combine(sub, None, tables)
        bloom_only = n2 > 0
        at = (ys[bloom_only], xs[bloom_only])
        radiance[at], sigma[at], n[at] = r2[bloom_only], s2[bloom_only], n2[bloom_only]
        flags[at] = FLAG_BLOOMED
        rest = ~bloom_only
        order = np.argsort(model.a)
        short, long_ = int(order[0]), int(order[-1])
        sat = rest & (sub[short] >= L - 1)
        dark = rest & ~sat
        radiance[ys[sat], xs[sat]] = (model.g[L - 1] - model.b[short]) / model.a[short]
        radiance[ys[dark], xs[dark]] = (model.g[1] - model.b[long_]) / model.a[long_]
        sigma[ys[rest], xs[rest]] = np.inf
        flags[ys[sat], xs[sat]] = FLAG_SATURATED
        flags[ys[dark], xs[dark]] = FLAG_DARK
    for o, v in zip(out, (radiance, sigma, flags, n)):
        o[y0:y1] = v


def _merge_plane(planes: list[NDArray], model: ResponseModel, bloom_radius: int,
                 out: tuple[NDArray, NDArray, NDArray, NDArray] | None = None,
                 band_rows: int | None = None) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """One channel's merge, in bands of rows (each with the halo of rows its blooming disk
    reaches, as :func:`ccdcore.distributed.hdr.merge_halo`): bit-identical to the whole plane at
    once, in a band's memory. ``out``: radiance, sigma (float64), flags (uint8) and used (int16)
    arrays of the plane's shape to fill (views of a colour result), else new ones."""
    planes = [np.asarray(p) for p in planes]
    N = len(planes)
    if model.a.size != N or model.b.size != N:
        raise CcdError("response", f"the calibration has {model.a.size} images, the bracket "
                                   f"{N}")
    L = model.levels
    saturates = []
    for p in planes:
        top = int(p.max()) if p.size else 0
        if top >= L or (p.size and int(p.min()) < 0):
            raise CcdError("bracket", f"codes outside 0..{L - 1} of the calibration's response")
        saturates.append(top >= L - 1)
    h, w = planes[0].shape
    if out is None:
        out = (np.empty((h, w)), np.empty((h, w)), np.empty((h, w), np.uint8),
               np.empty((h, w), np.int16))
    tables = _tables(model)
    r = max(0, int(bloom_radius))
    rows = int(band_rows) if band_rows else max(1, BAND_PIXELS // max(1, w))
    cuts = [(max(0, y0 - r), y0, min(h, y0 + rows), min(h, y0 + rows + r))
            for y0 in range(0, h, rows)]

    def run(cut: tuple[int, int, int, int]) -> None:
        _merge_band(planes, model, tables, bloom_radius, saturates, *cut, out=out)

    if MERGE_THREADS > 1 and len(cuts) > 1:
        with ThreadPoolExecutor(MERGE_THREADS, thread_name_prefix="hdr-merge") as pool:
            list(pool.map(run, cuts))
    else:
        for cut in cuts:
            run(cut)
    return out


def merge(frames: Sequence[ArrayLike], models: Mapping[str, Any] | Any, *,
          layout: str | None = None, bloom_radius: int = DEFAULT_BLOOM_RADIUS) -> HdrResult:
    """Radiance and σ_E of a bracket (eqs. 9, 18, 19).

    Parameters
    ----------
    frames : sequence of array_like
        The bracket's images (integer codes, all of one shape) in the order of the models' ``a``
        and ``b``.
    models : mapping of str to ResponseModel, or ResponseModel
        Maps each channel name (:func:`ccdcore.channels.split_channels`) to its
        :class:`ResponseModel` (or an object with the same attributes); a mono bracket may pass
        one model.
    layout : str or None, optional
        ``"mono"``, ``"rgb"``, ``"bayer-rggb"`` ...; ``None`` infers mono or rgb from the shape.
    bloom_radius : int, optional
        Radius (pixels) around a saturated pixel whose codes are not merged (blooming).

    Returns
    -------
    HdrResult
        ``radiance`` and its ``sigma`` σ_E (float64, the frames' shape), ``flags`` and ``used``
        (how many images each value merged), per channel in ``channels`` order along the last
        axis for colour, and the ``layout``.

    Raises
    ------
    CcdError
        No frames; a frame of another shape than the first or not of integer codes; a layout
        that does not fit the frames; one model for several channels, or a channel without a
        model; a model for another number of images, or codes beyond its response; a
        ``bloom_radius`` out of range (when a frame saturates).

    Examples
    --------
    >>> import numpy as np
    >>> from ccdcore.response import ResponseModel
    >>> g = np.arange(256, dtype=float)                 # a linear camera: g(z) = z
    >>> model = ResponseModel(g, a=np.array([1.0, 4.0]), b=np.zeros(2), sigma_s=0.0,
    ...                       sigma_c1=0.0, sigma_c2=0.5)
    >>> scene = np.full((2, 3), 20.0)                   # the radiance
    >>> hdr = merge([np.uint8(scene * 1.0), np.uint8(scene * 4.0)], model)
    >>> hdr.radiance.tolist()[0], bool((hdr.sigma < 0.5).all())
    ([20.0, 20.0, 20.0], True)
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
    h, w = split[0][names[0]].shape
    tail = () if len(names) == 1 else (len(names),)
    maps = (np.empty((h, w) + tail), np.empty((h, w) + tail), np.empty((h, w) + tail, np.uint8),
            np.empty((h, w) + tail, np.int16))
    for i, c in enumerate(names):           # each channel's bands written into the result
        _merge_plane([s[c] for s in split], ResponseModel.of(models[c]), bloom_radius,
                     out=maps if not tail else tuple(m[..., i] for m in maps))
    r, s, f, n = maps
    return HdrResult(r, s, f, n, names, lay)
