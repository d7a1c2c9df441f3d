"""Single-frame change pairs (Tsin, Ramesh & Kanade 2001, sec. 5, eq. 20) as a video camera takes
them: an unknown response, 8-bit frames without exposure metadata, a global change of light.

What the lobby of the I2R sequence taught (a fixed video camera, automatic gain, a light switched
off): the frames come through a tone curve nobody gives (here :class:`SrgbKneeTone`, sRGB-like
with a toe and a highlight shoulder, so not the sRGB curve the detector assumes), the camera's
automatic gain partly undoes the dimming, the light's colour shifts, and the noise is a DN or two.
:func:`frame_pair` makes such a pair in memory, :func:`write_frame_pair` a plain session folder of
it (``reference/`` and ``target/`` PNG frames, no manifest, no exposure) with the truth.
Presets of :mod:`ccdcore.simulate.change` are untouched (their bytes are pinned).

The scene: :func:`ccdcore.simulate.change.background_radiance` (a textured blend of colours); the
target's light E' = E M (eq. 20), M = ``gain`` × diag(``tint``) (+ ``mix`` off the diagonal);
inserted objects (ellipses of a uniform random colour with a fine texture) on ``n_objects``; the
camera: linear signal k·E (k = ``exposure``, then k·``auto_gain`` for the target: automatic gain
brings a dim frame partly back up), shot noise ``sigma_shot`` √(signal) and read noise
``sigma_read`` (both in units of full well, before the curve), the curve, rounding to 8 bits.
Each of ``n_reference`` / ``n_target`` frames draws its own noise.

Soft shadows (``n_shadows``, what the lobby's person taught: the shadow cast on the wall and
floor beside them is a penumbra, the light scaled by a factor that runs smoothly from
``shadow_depth`` at its core to 1 at its edge, a continuum of shades no single M describes):
the target's light there is k(x) E M with a Gaussian fall-off of k. They are not change: the
truth holds them apart (``shadow`` in the result, ``truth/shadow_mask.npy``: k < 0.97).

Public objects
--------------
frame_pair(seed, size, ...)
    Reference frames, target frames, the truth mask of the inserted objects, the parameters.
write_frame_pair(out_dir, seed, ...)
    The same as a session folder with ``truth/change_mask.png`` and ``truth.json``.
PAIR_DEFAULTS
    The options and their defaults.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import CcdError
from ..io.frames import write_image
from .camera import SrgbKneeTone
from .change import background_radiance

__all__ = ["frame_pair", "write_frame_pair", "PAIR_DEFAULTS"]

PAIR_DEFAULTS: dict[str, Any] = {
    "n_reference": 1, "n_target": 1,
    "gain": 0.55,                  # the light's dimming (lights off: mean level 119 -> 78)
    "tint": (1.0, 0.95, 0.85),     # the new light's colour
    "mix": 0.02,                   # off-diagonal colour mixing of M
    "auto_gain": 1.3,              # the camera's automatic gain on the target
    "exposure": 0.6,               # signal at full well per unit radiance
    "sigma_shot": 0.004, "sigma_read": 0.002,
    "n_objects": 2, "object_size": 0.22,
    "n_shadows": 0, "shadow_depth": 0.6, "shadow_size": 0.08,
}


def _objects(rng: np.random.Generator, shape: tuple[int, int], n: int, size: float
             ) -> tuple[NDArray[np.bool_], NDArray[np.float64], list[dict[str, int]]]:
    """``n`` ellipses (a mask), their radiance (a colour each with a 5 % texture), boxes."""
    h, w = shape
    mask = np.zeros(shape, bool)
    rad = np.zeros(shape + (3,))
    boxes = []
    for _ in range(int(n)):
        oh = max(4, int(round(size * h * rng.uniform(0.7, 1.3))))
        ow = max(4, int(round(0.6 * size * h * rng.uniform(0.7, 1.3))))
        y, x = int(rng.integers(0, h - oh)), int(rng.integers(0, w - ow))
        yy, xx = np.mgrid[0:oh, 0:ow]
        ell = ((yy - (oh - 1) / 2) / (oh / 2)) ** 2 + ((xx - (ow - 1) / 2) / (ow / 2)) ** 2 <= 1
        colour = rng.uniform(0.03, 0.6, 3)
        tex = 1.0 + 0.05 * rng.standard_normal((oh, ow, 1))
        sub = rad[y:y + oh, x:x + ow]
        sub[ell] = (colour * tex)[ell]
        mask[y:y + oh, x:x + ow] |= ell
        boxes.append({"x": x, "y": y, "w": ow, "h": oh})
    return mask, rad, boxes


def _soft_shadows(rng: np.random.Generator, shape: tuple[int, int], n: int, depth: float,
                  size: float) -> NDArray[np.float64]:
    """The light's factor k(x) of ``n`` soft shadows: 1 - (1 - depth) exp(-r²/2) around a random
    centre, r in units of ``size`` × height (the smallest factor of overlapping shadows)."""
    h, w = shape
    k = np.ones(shape)
    yy, xx = np.mgrid[0:h, 0:w]
    for _ in range(int(n)):
        cy, cx = rng.uniform(0.15, 0.85) * h, rng.uniform(0.15, 0.85) * w
        s = float(size) * h * rng.uniform(0.7, 1.3)
        r2 = ((yy - cy) ** 2 + (0.7 * (xx - cx)) ** 2) / (s * s)
        k = np.minimum(k, 1.0 - (1.0 - float(depth)) * np.exp(-0.5 * r2))
    return k


def frame_pair(seed: int = 0, size: tuple[int, int] = (160, 128), **options: Any
               ) -> dict[str, Any]:
    """A single-frame change pair (or a few frames each), in memory.

    Parameters
    ----------
    seed
        Seed of the random generator.
    size
        ``(width, height)``.
    **options
        :data:`PAIR_DEFAULTS`; ``n_objects=0`` gives a pair without change.

    Returns
    -------
    dict
        ``reference``, ``target`` (lists of (H, W, 3) uint8 frames), ``mask`` (bool, the
        inserted objects), ``M`` (the light's transform, eq. 20), ``options``, ``boxes``,
        ``shade`` (the soft shadows' factor k per pixel, 1 outside them) and ``shadow`` (bool,
        k < 0.97 outside the objects).
    """
    opts = {**PAIR_DEFAULTS, **options}
    unknown = sorted(set(opts) - set(PAIR_DEFAULTS))
    if unknown:
        raise CcdError("change_frames", f"unknown option(s) {', '.join(unknown)}; known: "
                                        f"{', '.join(PAIR_DEFAULTS)}")
    width, height = int(size[0]), int(size[1])
    rng = np.random.default_rng(int(seed))
    shape = (height, width)
    E = background_radiance(rng, shape, 4).astype(np.float64)
    M = float(opts["gain"]) * np.diag(np.asarray(opts["tint"], np.float64))
    M = M + float(opts["mix"]) * float(opts["gain"]) * (1.0 - np.eye(3))
    Et = E @ M
    mask, rad, boxes = _objects(rng, shape, int(opts["n_objects"]), float(opts["object_size"]))
    shade = _soft_shadows(rng, shape, int(opts["n_shadows"]), float(opts["shadow_depth"]),
                          float(opts["shadow_size"])) if int(opts["n_shadows"]) else np.ones(shape)
    Et = Et * shade[..., None]
    Et[mask] = rad[mask]
    tone = SrgbKneeTone()

    def shoot(radiance: NDArray, k: float) -> NDArray[np.uint8]:
        v = k * radiance
        v = v + np.sqrt(np.maximum(v, 0.0)) * float(opts["sigma_shot"]) * rng.standard_normal(
            v.shape) + float(opts["sigma_read"]) * rng.standard_normal(v.shape)
        return np.clip(np.round(tone.f(v)), 0, 255).astype(np.uint8)

    k = float(opts["exposure"])
    ref = [shoot(E, k) for _ in range(int(opts["n_reference"]))]
    tgt = [shoot(Et, k * float(opts["auto_gain"])) for _ in range(int(opts["n_target"]))]
    return {"reference": ref, "target": tgt, "mask": mask, "M": M, "options": opts,
            "boxes": boxes, "shade": shade, "shadow": (shade < 0.97) & ~mask}


def write_frame_pair(out_dir: str | Path, seed: int = 0, size: tuple[int, int] = (160, 128),
                     **options: Any) -> dict[str, Any]:
    """:func:`frame_pair` as a plain session folder: ``reference/ref_NN.png``,
    ``target/tgt_NN.png`` (8-bit RGB, no exposure), ``truth/change_mask.npy`` (bool: not an
    image, which the plain-folder reader would take for a frame) and
    ``truth.json`` (the options, M, the boxes); returns that truth."""
    pair = frame_pair(seed, size, **options)
    root = Path(out_dir)
    for role, stem in (("reference", "ref"), ("target", "tgt")):
        (root / role).mkdir(parents=True, exist_ok=True)
        for i, z in enumerate(pair[role]):
            write_image(root / role / f"{stem}_{i:02d}.png", z)
    (root / "truth").mkdir(parents=True, exist_ok=True)
    np.save(root / "truth" / "change_mask.npy", pair["mask"])  # an image would read as a frame
    np.save(root / "truth" / "shadow_mask.npy", pair["shadow"])
    truth = {"preset": "change-frames", "seed": int(seed), "size": [int(size[0]), int(size[1])],
             "paper": "Tsin, Ramesh & Kanade 2001, sec. 5, eq. 20",
             "tone": "srgb-knee (gamma 2.4, toe 0.01, knee 0.8, headroom 2)",
             "M": pair["M"].tolist(), "boxes": pair["boxes"],
             "options": {k: list(v) if isinstance(v, tuple) else v
                         for k, v in pair["options"].items()},
             "changed_pixels": int(pair["mask"].sum()),
             "shadow_pixels": int(pair["shadow"].sum())}
    (root / "truth.json").write_text(json.dumps(truth, indent=1))
    return truth
