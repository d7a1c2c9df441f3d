"""Moving objects in a bracket, found by the noise model of sec. 3.2 (Tsin, Ramesh & Kanade 2001,
eqs. 7, 9, 18, 19), and merged from one exposure.

A static pixel's exposures all predict one radiance: image k's prediction
p_k = (g(z_k) - b_k) / a_k has standard deviation σ(a_k, z_k) / a_k (eq. 7), so over the N
usable codes of a pixel (unclipped, outside the blooming masks, as the merge takes them)

    χ² = Σ_k (p_k - Ē)² (a_k / σ_k)²,   Ē = Σ_k p_k (a_k/σ_k)² / Σ_k (a_k/σ_k)²

is χ² with N - 1 degrees of freedom, summed over the channels of a colour pixel. Where
something moved between the exposures (a person, a car, leaves), the exposures disagree far
beyond it. The test:

1. **Calibrated on the bracket itself.** Eq. 7's terms come from the fit, which a camera's
   demosaicing, sharpening and compression bend, and no two frames are registered to the last
   fraction of a pixel. Each prediction's variance gets a registration term δ² |∇Ē|² (Ē's
   gradient, per channel), δ the smallest of 0-2 px at which the χ² of the steepest tenth of
   the gradients is at most 1.5 times that of the flattest half (on an even sample of 100 000
   pixels; reported). The scale s of the statistic is then the median of χ² / median(χ²_dof)
   over the pixels of each of 32 levels of Ē (equal counts), at least the whole bracket's
   (most of a bracket is static; a curve or noise model wrong over a range of codes raises
   every pixel of that level, a moving object a few of each), as the change detector
   calibrates its threshold on its background.
2. **A pixel is raw-moving** when χ² > s · χ²_dof quantile 1 - ``p`` (default 1e-4).
3. **Not near bright pixels.** Within ``SATURATION_HALO`` (8) pixels of a code in the top
   tenth of the range in an exposure, that exposure's code disagrees through the camera
   (blooming, sharpening halos, 8 × 8 JPEG blocks change as the light nears clipping): it is
   left out of the test, as the merge's blooming mask leaves codes within 3 pixels of a
   saturated one out (a simulated static camera bracket flagged 3-5 % of its pixels around
   its lights without this; leaving every pixel near a pixel saturated in any exposure out
   left nothing to test in a bracket whose longest exposures saturate most of the frame).
4. **Regions, not edges.** A residual misregistration or a sharpened edge leaves lines a pixel
   or two wide; a moving object is a region: the raw mask is opened with a 3 × 3 square (lines
   and single pixels go), then dilated by ``grow`` pixels (the object's blurred rim).

Moving pixels are merged from one exposure: the reference frame's where its code is well
exposed (10-90 % of the range), else the well-exposed exposure nearest it (in bracket order)
that agrees with the reference's own code within 3 sigma, else the reference's usable code,
else the nearest usable one; σ_E is that image's σ/a (eq. 19 with
N = 1), the flag ``FLAG_MOVING`` (4 in ``flags.png``).

The test needs the response; the response's fit must not see the moving pixels. Fitting twice
(once to find them, once without) doubled the time of ``response`` and ``hdr`` (4.2 → 8.4 s
on the 10-image ``taipei``) for the same curve. Before the fit, :func:`suspect_moving` finds
them without a response: between neighbouring exposures k and k+1 a static pixel's code
follows the bracket's own code-to-code mapping (the comparagram's median of z_{k+1} at each
z_k, any monotone response and exposure ratio); a pixel more than ``SUSPECT_Z`` robust
standard deviations (the comparagram's interquartile range / 1.349, at least one code) off it
in any pair and channel is suspect, as regions (the same opening and growth). The suspects are
left out of the fit (:func:`ccdcore.response.brackets.bracket_data`'s ``exclude``); the flags
come from the noise model's test above.

Public objects
--------------
FLAG_MOVING
    The flag of a pixel merged from one exposure because its exposures disagree (defined in
    :mod:`ccdcore.response.hdr_merge` with the merge's other flags).
MovingPixels
    The mask, its count, the statistic's scale s, the reference frame.
find_moving(frames, models, ...)
    The test above on a bracket's frames.
suspect_moving(frames, levels, ...)
    The pixels left out of the fit: off the bracket's own code-to-code mapping.
merge_moving(result, frames, models, moving)
    The merged result with the moving pixels taken from one exposure and flagged.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage, stats

from .. import channels as chan
from .brackets import DEFAULT_BLOOM_RADIUS, bloom_mask, dilate_disk
from .hdr_merge import FLAG_MOVING, HdrResult, ResponseModel, noise_sigma

__all__ = ["FLAG_MOVING", "MovingPixels", "find_moving", "merge_moving", "suspect_moving",
           "MOVING_P", "SUSPECT_Z"]

#: per-pixel false-alarm probability of the raw test (before the opening)
MOVING_P = 1e-4
#: pixels the opened mask is grown by (a mover's blurred rim)
MOVING_GROW = 2
#: rows per band of the test (temporaries of a few float64 planes of this many rows)
BAND_ROWS = 256
#: an exposure's codes within this radius of its own bright pixels (:data:`BRIGHT`) are not
#: tested (blooming, sharpening halos and 8 x 8 JPEG blocks change as the light clips)
SATURATION_HALO = 8
#: a code in this top fraction of the range is bright: its halo is left out of the test
BRIGHT = 0.9
#: codes a moving pixel is taken from first (fractions of the range): the reference frame's
#: where its code lies here, else the nearest frame's that does
WELL_EXPOSED = (0.1, 0.9)
#: a pixel this many robust standard deviations off the comparagram's median is suspect
SUSPECT_Z = 6.0
#: registration residuals tried (pixels), the smallest that explains the edges taken
DELTAS = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.75, 1.0, 1.5, 2.0)
#: the steepest tenth of the gradients may have this many times the flattest half's χ²
EDGE_EXCESS = 1.5
#: pixels the registration residual is calibrated on (an even sample)
CALIBRATION_PIXELS = 100_000
#: bins (equal counts) of the mean prediction over which the statistic's scale is taken
LEVEL_BINS = 32


@dataclass(frozen=True, eq=False)
class MovingPixels:
    """Pixels whose exposures disagree beyond the noise model: ``mask`` (H, W), ``count``,
    the statistic's scale ``scale`` (s), the raw test's ``p``, the ``reference`` frame (index in
    bracket order) and its name, and the pixels tested (``tested``: two usable codes or
    more) and ``excluded``, the pixels left out of the response's fit (:func:`suspect_moving`;
    ``None`` when the response was not fitted here)."""

    mask: NDArray[np.bool_]
    count: int
    scale: float
    p: float
    reference: int
    reference_name: str
    tested: int
    excluded: int | None = None
    #: the registration residual δ (pixels) whose variance δ² |∇E|² the test adds
    delta: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"pixels": int(self.count), "fraction": self.count / max(self.mask.size, 1),
                "scale": float(self.scale) if np.isfinite(self.scale) else None,
                "p": float(self.p), "tested": int(self.tested),
                "reference": self.reference_name, "registration_residual_px": self.delta,
                "excluded_from_fit": None if self.excluded is None else int(self.excluded)}

    def describe(self) -> str:
        """One line in plain words (the same on every surface)."""
        if self.tested == 0:
            return ("moving objects: not tested (no pixel has two exposures with a usable code "
                    "away from saturated pixels)")
        fit = ("" if self.excluded is None else
               f"; {self.excluded:,} pixels off the bracket's own code-to-code mapping were "
               "left out of the response fit")
        if self.count == 0:
            return (f"moving objects: none (every pixel's exposures agree within the noise "
                f"model, scaled by s = {self.scale:.3g}, and a registration residual of "
                f"{self.delta:g} px){fit}")
        return (f"moving objects: {self.count:,} pixels "
                f"({100 * self.count / max(self.mask.size, 1):.2g} %) whose exposures disagree "
                f"beyond the noise model (s = {self.scale:.3g}) and a registration residual of "
                f"{self.delta:g} px are merged from one exposure "
                f"({self.reference_name} where usable), flag {FLAG_MOVING} in flags.png{fit}")


def _tables(model: ResponseModel) -> tuple[NDArray, NDArray]:
    """Per image and code: the weight (a/σ)² and the prediction (g - b)/a; weight 0 at the
    clipped codes."""
    L, N = model.levels, model.a.size
    codes = np.arange(L)
    w = np.empty((N, L))
    pred = np.empty((N, L))
    for k in range(N):
        w[k] = (model.a[k] / np.maximum(noise_sigma(model, codes, k), 1e-12)) ** 2
        pred[k] = (model.g - model.b[k]) / model.a[k]
    w[:, [0, L - 1]] = 0.0
    return w, pred


def _sums(zs: Sequence[NDArray], blooms: Sequence[NDArray | None], w_tab: NDArray,
          p_tab: NDArray, extra: NDArray | None = None) -> tuple[NDArray, NDArray, NDArray]:
    """Over the usable codes ``zs`` (one array per image, any shape): the inverse-variance mean
    of the images' predictions, the χ² about it and its degrees of freedom. ``extra``: a
    variance added to every image's prediction (the registration term)."""
    s0 = np.zeros(zs[0].shape)
    s1 = np.zeros_like(s0)
    s2 = np.zeros_like(s0)
    n = np.zeros(zs[0].shape, np.int32)
    for k, z8 in enumerate(zs):
        z = z8.astype(np.intp)
        wk = np.take(w_tab[k], z)
        if blooms[k] is not None:
            wk[blooms[k]] = 0.0
        if extra is not None:
            wk = wk / (1.0 + wk * extra)
        pk = np.take(p_tab[k], z)
        s0 += wk
        s1 += wk * pk
        s2 += wk * pk * pk
        n += wk > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(s0 > 0, s1 / s0, 0.0)
        c = np.where(s0 > 0, s2 - s1 * mean, 0.0)
    return mean, np.maximum(c, 0.0), np.maximum(n - 1, 0)


def _channel(planes: list[NDArray], model: ResponseModel, bloom_radius: int
             ) -> tuple[list[NDArray | None], NDArray, NDArray, NDArray]:
    """One channel's masks of the codes left out (each exposure's blooming disk, and its
    codes within :data:`SATURATION_HALO` of a code in the top :data:`BRIGHT` of the range),
    its tables and the gradient magnitude of its mean prediction (radiance per pixel)."""
    blooms: list[NDArray | None] = []
    top = BRIGHT * (model.levels - 1)
    for plane in planes:
        b = bloom_mask(plane, model.levels, bloom_radius) if bloom_radius > 0 else None
        bright = plane >= top
        if bright.any():
            halo = dilate_disk(bright, SATURATION_HALO)
            b = halo if b is None else (b | halo)
        blooms.append(b if b is not None and b.any() else None)
    w_tab, p_tab = _tables(model)
    mean = np.empty(planes[0].shape)
    for y0 in range(0, mean.shape[0], BAND_ROWS):
        rows = slice(y0, y0 + BAND_ROWS)
        mean[rows] = _sums([p[rows] for p in planes],
                           [None if b is None else b[rows] for b in blooms], w_tab, p_tab)[0]
    gy, gx = np.gradient(mean)
    return blooms, w_tab, p_tab, np.hypot(gx, gy)


def _registration(chans: list[tuple], planes: list[list[NDArray]], tested: NDArray[np.bool_]
                  ) -> float:
    """The registration residual δ (pixels): the smallest of :data:`DELTAS` at which the χ²
    of the pixels on the steepest tenth of the gradients is at most
    :data:`EDGE_EXCESS` times that of the flattest half (on an even sample)."""
    idx = np.flatnonzero(tested.ravel())
    if idx.size < 100:
        return 0.0
    idx = idx[np.linspace(0, idx.size - 1, min(idx.size, CALIBRATION_PIXELS)).astype(np.int64)]
    grad = np.zeros(idx.size)
    for (_, _, _, g) in chans:
        grad = np.maximum(grad, g.ravel()[idx])
    steep = grad >= np.quantile(grad, 0.9)
    flat = grad <= np.quantile(grad, 0.5)
    sub = [([p.ravel()[idx] for p in pl], [None if b is None else b.ravel()[idx] for b in bl],
            w, pt, g.ravel()[idx]) for pl, (bl, w, pt, g) in zip(planes, chans)]
    for delta in DELTAS:
        chi2 = np.zeros(idx.size)
        dof = np.zeros(idx.size, np.int64)
        for zs, bl, w, pt, g in sub:
            _, c, d = _sums(zs, bl, w, pt, (delta * g) ** 2 if delta else None)
            chi2 += c
            dof += d
        ok = dof > 0
        u = chi2[ok] / stats.chi2.ppf(0.5, dof[ok])
        lo, hi = np.median(u[flat[ok]]), np.median(u[steep[ok]])
        if hi <= EDGE_EXCESS * lo:
            return float(delta)
    return float(DELTAS[-1])


def _level_scale(u: NDArray, level: NDArray, scale: float) -> NDArray:
    """The statistic's scale at each pixel's level: the median of the normalised χ² ``u`` in
    its bin of :data:`LEVEL_BINS` equal counts of the mean prediction, at least ``scale`` (the
    whole bracket's). A response or noise model wrong over a range of codes (the knee of a
    camera's curve, a display's flicker) raises the statistic of every pixel there; a moving
    object is a few pixels of each level."""
    if u.size < 20 * LEVEL_BINS:
        return np.full(u.size, scale)
    edges = np.quantile(level, np.linspace(0.0, 1.0, LEVEL_BINS + 1)[1:-1])
    idx = np.searchsorted(edges, level)
    med = np.array([np.median(u[idx == b]) if np.any(idx == b) else scale
                    for b in range(LEVEL_BINS)])
    return np.maximum(med, scale)[idx]


def find_moving(frames: Sequence[ArrayLike], models: Mapping[str, Any], *,
                layout: str | None = None, reference: int | None = None,
                names: Sequence[str] = (), bloom_radius: int = DEFAULT_BLOOM_RADIUS,
                p: float = MOVING_P, grow: int = MOVING_GROW) -> MovingPixels:
    """The moving pixels of a bracket (the module's test). ``frames`` in the order of the
    models' ``a``, ``b`` (bracket order); ``reference``: default the middle frame."""
    arrays = [np.asarray(f) for f in frames]
    n_frames = len(arrays)
    ref = n_frames // 2 if reference is None else int(reference)
    lay = chan.check_layout(arrays[0].shape, layout, "bracket")
    split = [chan.split_channels(a, lay) for a in arrays]
    planes = [[s[c] for s in split] for c in split[0]]
    chans = [_channel(pl, ResponseModel.of(models[c]), bloom_radius)
             for pl, c in zip(planes, split[0])]
    shape = arrays[0].shape[:2]
    dof = np.zeros(shape, np.int32)
    for pl, (bl, w, pt, _) in zip(planes, chans):
        for y0 in range(0, shape[0], BAND_ROWS):
            rows = slice(y0, y0 + BAND_ROWS)
            dof[rows] += _sums([q[rows] for q in pl], [None if b is None else b[rows]
                                                       for b in bl], w, pt)[2]
    tested = dof > 0
    name = str(names[ref]) if len(names) > ref else f"frame {ref}"
    if not tested.any():
        return MovingPixels(np.zeros(shape, bool), 0, float("nan"), p, ref, name, 0)
    delta = _registration(chans, planes, tested)
    chi2 = np.zeros(shape)
    for pl, (bl, w, pt, g) in zip(planes, chans):
        for y0 in range(0, shape[0], BAND_ROWS):
            rows = slice(y0, y0 + BAND_ROWS)
            chi2[rows] += _sums([q[rows] for q in pl], [None if b is None else b[rows]
                                                        for b in bl], w, pt,
                                (delta * g[rows]) ** 2 if delta else None)[1]
    med = stats.chi2.ppf(0.5, np.arange(int(dof.max()) + 1).clip(1))
    u = chi2[tested] / med[dof[tested]]
    scale = max(float(np.median(u)), 1e-12)
    level = np.zeros(shape)
    for pl, (bl, w, pt, _) in zip(planes, chans):
        level += np.abs(np.where(tested, _sums(pl, bl, w, pt)[0], 0.0))
    by_level = _level_scale(u, level[tested], scale)
    cut = stats.chi2.isf(p, np.arange(int(dof.max()) + 1).clip(1))
    raw = np.zeros(shape, bool)
    raw[tested] = chi2[tested] > by_level * cut[dof[tested]]
    mask = _regions(raw, grow) & tested
    return MovingPixels(mask, int(np.count_nonzero(mask)), scale, p, ref, name,
                        int(np.count_nonzero(tested)), delta=delta)


def _regions(raw: NDArray[np.bool_], grow: int) -> NDArray[np.bool_]:
    """The raw mask opened with a 3 x 3 square (lines and single pixels go), grown by
    ``grow`` pixels."""
    mask = ndimage.binary_opening(raw, structure=np.ones((3, 3), bool))
    if grow > 0 and mask.any():
        mask = ndimage.binary_dilation(mask, structure=np.ones((3, 3), bool),
                                       iterations=int(grow))
    return mask


def _off_mapping(u: NDArray, v: NDArray, levels: int, z: float) -> NDArray[np.bool_]:
    """Pixels whose code ``v`` (image k+1) is more than ``z`` robust standard deviations off
    the comparagram's median of v at their code ``u`` (image k); clipped codes never are."""
    L = int(levels)
    ok = (u > 0) & (u < L - 1) & (v > 0) & (v < L - 1)
    ui = u.astype(np.intp)
    counts = np.bincount((ui[ok] * L + v[ok]).ravel(), minlength=L * L).reshape(L, L)
    cum = np.cumsum(counts, axis=1)
    total = cum[:, -1]
    q = np.empty((3, L))
    for i, frac in enumerate((0.25, 0.5, 0.75)):
        q[i] = np.argmax(cum >= np.maximum(frac * total, 1)[:, None], axis=1)
    spread = np.maximum((q[2] - q[0]) / 1.349, 1.0)
    dev = np.abs(v.astype(np.float64) - q[1][ui]) / spread[ui]
    return ok & (dev > z) & (total[ui] >= 5)


def suspect_moving(frames: Sequence[ArrayLike], levels: int, *, layout: str | None = None,
                   z: float = SUSPECT_Z, grow: int = MOVING_GROW) -> NDArray[np.bool_]:
    """Pixels off the bracket's own code-to-code mapping between neighbouring exposures (the
    module notes), as regions: left out of the response's fit. ``frames`` in bracket order."""
    arrays = [np.asarray(f) for f in frames]
    lay = chan.check_layout(arrays[0].shape, layout, "bracket")
    split = [chan.split_channels(a, lay) for a in arrays]
    raw = np.zeros(arrays[0].shape[:2], bool)
    for c in split[0]:
        for k in range(len(split) - 1):
            raw |= _off_mapping(split[k][c], split[k + 1][c], levels, z)
    return _regions(raw, grow)


def merge_moving(result: HdrResult, frames: Sequence[ArrayLike], models: Mapping[str, Any],
                 moving: MovingPixels, *, bloom_radius: int = DEFAULT_BLOOM_RADIUS
                 ) -> HdrResult:
    """``result`` with the moving pixels merged from one exposure: the reference frame's code
    where it is well exposed (:data:`WELL_EXPOSED`), else the well-exposed one nearest the
    reference in bracket order whose prediction agrees with the reference's within 3 sigma
    (the same surface, not the mover), else the reference's usable code, else the nearest
    usable one; σ_E = σ/a of that image; ``used`` 1; flag :data:`FLAG_MOVING`."""
    if moving.count == 0:
        return result
    arrays = [np.asarray(f) for f in frames]
    lay = result.layout
    split = [chan.split_channels(a, lay) for a in arrays]
    ys, xs = np.nonzero(moving.mask)
    order = sorted(range(len(arrays)), key=lambda k: (abs(k - moving.reference), k))
    radiance, sigma = result.radiance.copy(), result.sigma.copy()
    flags, used = result.flags.copy(), result.used.copy()
    for i, c in enumerate(result.channels):
        model = ResponseModel.of(models[c])
        L = model.levels
        preds, sigs, usable = [], [], []
        for k in range(len(arrays)):
            z = split[k][c][ys, xs].astype(np.intp)
            ok = (z > 0) & (z < L - 1)
            if bloom_radius > 0 and ok.any():
                ok &= ~bloom_mask(split[k][c], L, bloom_radius)[ys, xs]
            preds.append((model.g[z] - model.b[k]) / model.a[k])
            sigs.append(noise_sigma(model, z, k) / model.a[k])
            usable.append((ok, ok & (z >= WELL_EXPOSED[0] * (L - 1))
                           & (z <= WELL_EXPOSED[1] * (L - 1))))
        r = moving.reference
        val = np.full(ys.size, np.nan)
        sig = np.full(ys.size, np.nan)
        # the reference where well exposed; else the nearest well-exposed frame that agrees
        # with the reference's own (poorly exposed) code within 3 sigma; else the reference
        # where usable; else the nearest usable frame
        agree = [np.abs(preds[k] - preds[r]) <= 3.0 * np.hypot(sigs[k], sigs[r])
                 for k in range(len(arrays))]
        steps = [(k, usable[k][1] & (agree[k] | ~usable[r][0])) for k in order]
        steps += [(r, usable[r][0])] + [(k, usable[k][0]) for k in order]
        for k, ok in steps:
            ok = ok & np.isnan(val)
            val[ok], sig[ok] = preds[k][ok], sigs[k][ok]
        got = ~np.isnan(val)
        at = (ys[got], xs[got]) if radiance.ndim == 2 else (ys[got], xs[got], i)
        radiance[at], sigma[at], used[at], flags[at] = val[got], sig[got], 1, FLAG_MOVING
    return replace(result, radiance=radiance, sigma=sigma, flags=flags, used=used)
