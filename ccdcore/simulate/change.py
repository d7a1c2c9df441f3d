"""Preset ``change``: the illumination-invariant change scene of Tsin et al. (2001), sec. 5.

A static camera looks at a planar, Lambertian, textured background.  Under the reference
illumination its radiance is ``E(x)`` (RGB, a row vector per pixel).  Hours later the light has
changed: every background pixel obeys one 3x3 colour transform, ``E'(x) = E(x) M`` (eq. 20, row
vectors, after Slater & Healey), pixels in shadow obey transforms of their own (one per shade), and
inserted objects ("parked cars") carry a new radiance unrelated to ``E``.  Both scenes are imaged
as exposure brackets through the pipeline of eq. 3 (:func:`ccdcore.simulate.tsin.expose`): the
``reference`` bracket sees ``E``, the ``target`` bracket sees ``E'``; 8-bit RGB.

Scene
-----
* Background: a smooth blend of ``n_colours`` random colours (softmax of smoothed noise fields),
  times a smooth brightness modulation and a fine texture; radiance about 0.02 .. 0.6.
* Objects: ``n_objects`` rectangles and ellipses with a random colour and texture, each in its own
  cell of a grid so that objects and their shadows never overlap one another.
* Shadows: shade 1 is cast by each object (its mask shifted by 40 % of its width and 30 % of its
  height, minus the object), transform ``M_shadows[0]``; shade 2 is a band along the left edge
  (a building's shadow), transform ``M_shadows[1]``.  Priority: object > shade 1 > shade 2.

Truth (``truth.json``): ``M``, ``M_shadows``, the objects (shape, box, colour, pixel area), the
mask areas, the response ``g`` and ``gamma``, exposure times ``t`` and ``a``/``b`` of both brackets,
the noise parameters; files ``truth/E.exr`` (reference radiance), ``truth/E_target.exr``,
``truth/change_mask.png`` (uint8, 1 on objects) and ``truth/shadow_mask.png`` (uint8 labels:
0 none, 1 .. number of shades); with ``bayer`` also ``truth/E_effective.exr`` and
``truth/E_target_effective.exr`` (``demosaic(mosaic(E))``, see :mod:`ccdcore.simulate.tsin`).
Floats carry 12 significant digits, except ``g`` (all digits, see
:func:`ccdcore.simulate.tsin.response_table`).

Reproducibility: the same seed gives the same bytes whatever the CPU's vector features.  The
smoothing, the colour blend and the transforms use only basic arithmetic in a fixed order and the
CPU-independent ``exp`` of :mod:`ccdcore.simulate._det` (not NumPy's vector ``exp``, ``einsum`` or
BLAS ``@``); the brackets go through :func:`ccdcore.simulate.tsin.expose`.

Public objects
--------------
DEFAULTS
    Default options of :func:`simulate`.
DEFAULT_M, DEFAULT_M_SHADOWS
    Default colour transforms (background: warm direct sun; shadows: bluish skylight).
background_radiance(rng, shape, n_colours)
    The textured background ``E``.
scene_layout(rng, shape, n_objects)
    Object and shadow masks plus the object list.
apply_transform(E, M)
    ``E M`` per pixel (eq. 20).
simulate(out_dir, *, seed, size, **options)
    Write the ``change`` session and its ``truth.json``.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from .. import channels
from ..errors import CcdError
from ..io.frames import write_image
from . import _det
from ._common import SessionWriter
from .tsin import (QUANTISATION_NOTE, SHOT_NOISE_NOTE, effective_radiance, expose, exposure_times,
                   response_table, white_balance)

__all__ = ["DEFAULTS", "DEFAULT_M", "DEFAULT_M_SHADOWS", "background_radiance", "scene_layout",
           "apply_transform", "simulate"]

#: background transform, row-vector convention E' = E M (eq. 20): warmer and brighter (sunlight)
DEFAULT_M: tuple[tuple[float, ...], ...] = ((1.25, 0.06, 0.00),
                                            (0.10, 1.10, 0.04),
                                            (0.00, 0.05, 0.80))
#: shadow transforms: shade 1 (cast by the objects, deep) and shade 2 (building, lighter)
DEFAULT_M_SHADOWS: tuple[tuple[tuple[float, ...], ...], ...] = (
    ((0.30, 0.01, 0.02), (0.02, 0.36, 0.04), (0.00, 0.03, 0.55)),
    ((0.50, 0.02, 0.02), (0.03, 0.55, 0.04), (0.00, 0.04, 0.70)),
)

#: default options of :func:`simulate`
DEFAULTS: dict[str, Any] = {
    "n_exposures": 7,
    "ratio": 2.0,
    "t_max": 8.0,
    "gamma": 1.2,
    "sigma_s": 0.015,
    "sigma_c1": 0.01,
    "sigma_c2": 1.0,
    "white_balance": False,
    "wb_sigma": 0.05,
    "offset_sigma": 0.01,
    "bayer": None,
    "n_colours": 4,
    "n_objects": 3,
    "band_fraction": 0.2,
    "M": DEFAULT_M,
    "M_shadows": DEFAULT_M_SHADOWS,
}

SHADOW_LABELS = {"1": "cast by the inserted objects (shade 1)",
                 "2": "band along the left edge, a building's shadow (shade 2)"}


def _smooth_field(rng: np.random.Generator, shape: tuple[int, int], sigma: float) -> NDArray:
    """Gaussian-smoothed white noise, zero mean, unit standard deviation."""
    f = _det.gaussian_filter(rng.standard_normal(shape), sigma)     # as ndimage's, mode="reflect"
    f -= f.mean()
    return f / max(float(f.std()), 1e-12)


def background_radiance(rng: np.random.Generator, shape: tuple[int, int],
                        n_colours: int = 4) -> NDArray[np.float32]:
    """Textured planar background: a smooth blend of ``n_colours`` colours (RGB radiance).

    Parameters
    ----------
    rng
        Random generator.
    shape
        ``(H, W)``.
    n_colours
        Number of palette colours (at least 3, so that the colours span RGB and ``M`` of eq. 20
        is identifiable from the background).

    Returns
    -------
    ndarray
        ``(H, W, 3)`` float32 radiance in about ``[0.02, 0.6]``.
    """
    if int(n_colours) < 3:
        raise CcdError("n_colours", f"need at least 3 colours to span RGB, got {n_colours}")
    h, w = shape
    for _ in range(100):
        palette = rng.uniform(0.05, 0.5, size=(int(n_colours), 3))
        # LAPACK's condition number may differ in the last bit between CPUs; only a value within
        # ~1e-15 of 20 could change the choice
        if np.linalg.cond(palette[:3]) < 20.0:
            break
    scale = min(h, w)
    fields = np.stack([_smooth_field(rng, shape, scale / 10.0) for _ in range(int(n_colours))])
    weights = _det.exp(fields / 0.35)
    weights /= weights.sum(axis=0, keepdims=True)
    # sum_j weights_j palette_j in a fixed order (einsum may fuse multiply-adds on some CPUs)
    E = np.zeros(shape + (3,))
    for j in range(int(n_colours)):
        E = E + weights[j][..., None] * palette[j]
    modulation = 1.0 + 0.2 * _smooth_field(rng, shape, scale / 6.0)
    texture = 1.0 + 0.05 * _smooth_field(rng, shape, 1.0)
    E *= np.clip(modulation * texture, 0.5, 1.5)[..., None]
    return np.clip(E, 0.02, 0.6).astype(np.float32)


def _ellipse(h: int, w: int) -> NDArray[np.bool_]:
    yy, xx = np.mgrid[0:h, 0:w]
    cy, cx = (h - 1) / 2.0, (w - 1) / 2.0
    return ((yy - cy) / (h / 2.0)) ** 2 + ((xx - cx) / (w / 2.0)) ** 2 <= 1.0


def scene_layout(rng: np.random.Generator, shape: tuple[int, int], n_objects: int = 3,
                 band_fraction: float = 0.2
                 ) -> tuple[NDArray[np.uint8], NDArray[np.uint8], list[dict[str, Any]]]:
    """Place the objects and the shadows.

    Parameters
    ----------
    rng
        Random generator.
    shape
        ``(H, W)``.
    n_objects
        Number of inserted objects, each in its own grid cell (with its cast shadow).
    band_fraction
        Mean width of the shade-2 band along the left edge, as a fraction of ``W`` (0: none).

    Returns
    -------
    change, shadow, objects
        ``change``: uint8 mask (1 on objects); ``shadow``: uint8 labels (0 none, 1 cast by the
        objects, 2 band); ``objects``: list of dicts ``{id, shape, x, y, w, h, shadow_dx,
        shadow_dy, area}`` (``area`` = pixel count of the object).
    """
    h, w = shape
    n = int(n_objects)
    change = np.zeros(shape, dtype=np.uint8)
    cast = np.zeros(shape, dtype=bool)
    objects: list[dict[str, Any]] = []
    if n > 0:
        ncols = max(1, math.ceil(math.sqrt(n * w / h)))
        nrows = math.ceil(n / ncols)
        cw, ch = w // ncols, h // nrows
        if cw < 8 or ch < 8:
            raise CcdError("size", f"{w}x{h} is too small for {n} objects of at least 8x8 "
                                   f"pixels each: give a larger --size (e.g. "
                                   f"{8 * ncols}x{8 * nrows} or more), or fewer n_objects")
        cells = rng.permutation(ncols * nrows)[:n]
        for i, cell in enumerate(sorted(int(c) for c in cells)):
            r, c = divmod(cell, ncols)
            ow = max(3, int(round(rng.uniform(0.35, 0.55) * cw)))
            oh = max(3, int(round(rng.uniform(0.35, 0.55) * ch)))
            dx, dy = int(round(0.4 * ow)), int(round(0.3 * oh))
            x = c * cw + int(rng.integers(0, cw - ow - dx + 1))
            y = r * ch + int(rng.integers(0, ch - oh - dy + 1))
            kind = "rectangle" if rng.random() < 0.5 else "ellipse"
            local = np.ones((oh, ow), bool) if kind == "rectangle" else _ellipse(oh, ow)
            obj = np.zeros(shape, dtype=bool)
            obj[y:y + oh, x:x + ow] = local
            shifted = np.zeros(shape, dtype=bool)
            shifted[y + dy:y + dy + oh, x + dx:x + dx + ow] = local
            cast |= shifted & ~obj
            change[obj] = 1
            objects.append({"id": i + 1, "shape": kind, "x": x, "y": y, "w": ow, "h": oh,
                            "shadow_dx": dx, "shadow_dy": dy, "area": int(obj.sum())})
    shadow = np.zeros(shape, dtype=np.uint8)
    if band_fraction > 0:
        yy, xx = np.mgrid[0:h, 0:w]
        slope = 0.5 * band_fraction * w / h
        band = xx < band_fraction * w + slope * (yy - (h - 1) / 2.0)
        shadow[band] = 2
    shadow[cast] = 1
    shadow[change > 0] = 0
    return change, shadow, objects


def apply_transform(E: ArrayLike, M: ArrayLike) -> NDArray[np.float64]:
    """``E'(x) = E(x) M`` for every pixel, ``E`` of shape ``(..., 3)`` (row vectors, eq. 20).

    Evaluated as ``E_0 M_0 + E_1 M_1 + E_2 M_2`` (rows ``M_i``) in this order rather than with
    ``@``, whose BLAS kernel depends on the CPU: the same bits everywhere.
    """
    M = np.asarray(M, dtype=np.float64)
    if M.shape != (3, 3):
        raise CcdError("M", f"expected a 3x3 colour transform, got shape {M.shape}")
    E = np.asarray(E, dtype=np.float64)
    return (E[..., 0:1] * M[0] + E[..., 1:2] * M[1]) + E[..., 2:3] * M[2]


def _object_radiance(rng: np.random.Generator, shape: tuple[int, int]) -> NDArray[np.float64]:
    colour = rng.uniform(0.05, 0.8, size=3)
    texture = 1.0 + 0.08 * _smooth_field(rng, shape, 1.5)
    return np.clip(colour[None, None, :] * texture[..., None], 0.01, 0.9)


def simulate(out_dir: str | Path, *, seed: int = 0, size: tuple[int, int] = (128, 96),
             **options: Any) -> dict[str, Any]:
    """Write the ``change`` session (Tsin et al. 2001, sec. 5) and return its truth.

    Parameters
    ----------
    out_dir
        Session folder to write.
    seed
        Seed of the random generator; the same seed and options give the same bytes.
    size
        ``(width, height)``.
    **options
        See :data:`DEFAULTS`: bracket (``n_exposures``, ``ratio``, ``t_max``), pipeline
        (``gamma``, ``sigma_s``, ``sigma_c1``, ``sigma_c2``, ``white_balance``, ``wb_sigma``,
        ``offset_sigma``, ``bayer``), scene (``n_colours``, ``n_objects``, ``band_fraction``) and
        the transforms ``M`` (3x3) and ``M_shadows`` (list of 3x3, one per shade; two shades).

    Returns
    -------
    dict
        The content of ``truth.json``.
    """
    opts = {**DEFAULTS, **options}
    unknown = sorted(set(opts) - set(DEFAULTS))
    if unknown:
        raise CcdError("change", f"unknown option(s) {', '.join(unknown)}; known: "
                                 f"{', '.join(DEFAULTS)}")
    width, height = int(size[0]), int(size[1])
    bayer = None if opts["bayer"] is None else channels.check_pattern(opts["bayer"])
    if bayer and (width % 2 or height % 2):
        raise CcdError("size", f"a Bayer camera needs even width and height, got "
                                 f"{width}x{height}")
    M = np.asarray(opts["M"], dtype=np.float64)
    M_shadows = [np.asarray(m, dtype=np.float64) for m in opts["M_shadows"]]
    if M.shape != (3, 3) or len(M_shadows) != 2 or any(m.shape != (3, 3) for m in M_shadows):
        raise CcdError("M", "expected M as 3x3 and M_shadows as two 3x3 transforms")
    shape = (height, width)
    rng = np.random.default_rng(int(seed))

    E = background_radiance(rng, shape, int(opts["n_colours"]))
    change, shadow, objects = scene_layout(rng, shape, int(opts["n_objects"]),
                                           float(opts["band_fraction"]))
    target = apply_transform(E, M)
    for label, Ms in enumerate(M_shadows, start=1):
        sel = shadow == label
        target[sel] = apply_transform(E[sel], Ms)
    for obj in objects:
        ys, xs = slice(obj["y"], obj["y"] + obj["h"]), slice(obj["x"], obj["x"] + obj["w"])
        local = change[ys, xs] > 0
        rad = _object_radiance(rng, (obj["h"], obj["w"]))
        target[ys, xs][local] = rad[local]
        obj["colour"] = rad[local].mean(axis=0)
    E_target = target.astype(np.float32)

    t = exposure_times(opts["n_exposures"], opts["ratio"], opts["t_max"])
    gamma = float(opts["gamma"])
    noise = {k: float(opts[k]) for k in ("sigma_s", "sigma_c1", "sigma_c2")}
    camera = {"name": "change-scene simulated camera" + (f" (Bayer {bayer}, bilinear)" if bayer
                                                         else ""),
              "bits": 8, "layout": "rgb"}
    writer = SessionWriter(out_dir, camera)
    writer.add_map("truth/E.exr", E)
    writer.add_map("truth/E_target.exr", E_target)
    if bayer:
        writer.add_map("truth/E_effective.exr", effective_radiance(E, bayer))
        writer.add_map("truth/E_target_effective.exr", effective_radiance(E_target, bayer))
    root = Path(out_dir)
    write_image(root / "truth/change_mask.png", change)
    write_image(root / "truth/shadow_mask.png", shadow)

    brackets: dict[str, dict[str, Any]] = {}
    for role, radiance in (("reference", E), ("target", E_target)):
        a, b = white_balance(t, rng, enabled=bool(opts["white_balance"]), channels=3,
                             wb_sigma=float(opts["wb_sigma"]),
                             offset_sigma=float(opts["offset_sigma"]))
        paths = []
        for k in range(t.size):
            shot = expose(radiance, a[k], b[k], rng, gamma=gamma, bayer=bayer, **noise)
            rel = f"{role}/k{k:02d}.tif"
            writer.add_frame(rel, shot.z, role=role, exposure=float(t[k]))
            paths.append(rel)
        brackets[role] = {"a": a, "b": b, "frames": paths}

    areas = {"change": int(np.count_nonzero(change)),
             "shadow": {str(i): int(np.count_nonzero(shadow == i)) for i in (1, 2)},
             "background": int(np.count_nonzero((change == 0) & (shadow == 0)))}
    truth: dict[str, Any] = {
        "preset": "change",
        "paper": "Tsin, Ramesh & Kanade 2001, sec. 5, eq. 20",
        "seed": int(seed),
        "size": [width, height],
        "layout": "rgb",
        "bayer": bayer,
        "convention": "row vectors: E'(x) = E(x) M (eq. 20)",
        "M": M,
        "M_shadows": M_shadows,
        "shadow_labels": SHADOW_LABELS,
        "objects": objects,
        "areas": areas,
        "masks": {"change": "truth/change_mask.png", "shadow": "truth/shadow_mask.png"},
        "g": response_table(gamma),
        "gamma": gamma,
        "f": f"f(v) = 255 * clip(v, 0, 1) ** (1 / {gamma:g}); g(z) = (z / 255) ** {gamma:g}",
        "t": t,
        "ratio": float(opts["ratio"]),
        "white_balance": bool(opts["white_balance"]),
        "reference": brackets["reference"],
        "target": brackets["target"],
        **noise,
        "noise_model": "sigma^2(a, z) = sigma_s^2 a E + sigma_c1^2 + g'(z)^2 sigma_c2^2 (eq. 7)",
        "shot_noise": SHOT_NOISE_NOTE,
        "quantisation": QUANTISATION_NOTE,
    }
    note = (f"change-scene simulation (Tsin, Ramesh & Kanade 2001, sec. 5), seed {int(seed)}.\n"
            "Truth in truth.json.")
    return writer.finish(truth, note=note, exact=("g",))
