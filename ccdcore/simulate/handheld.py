"""A handheld bracket for ``tsin01``: camera shake between frames and objects moving in the scene.

Real brackets are often shot without a tripod -- each frame is shifted by a few pixels and
rotated by a fraction of a degree against the others -- and contain moving objects (people
walking through).  An HDR merge needs an alignment step and must not average a moving object
with the background it uncovers.  This module holds the pure building blocks and the plan
:func:`ccdcore.simulate.tsin.simulate` follows when its options ``handheld_shift``,
``handheld_rotation`` or ``movers`` are set (:data:`DEFAULTS`; all off by default, and then
nothing here runs and every session keeps its bytes).

Sign convention of a frame's transform ``(dx, dy, theta)``
----------------------------------------------------------
Pixel coordinates ``(x, y)``: ``x`` to the right (column), ``y`` down (row), pixel centres at
integers; the centre of rotation is the frame's centre ``c = ((W - 1) / 2, (H - 1) / 2)``;
``theta`` is ``rotation_deg`` in degrees and::

    R(theta) = [[cos theta, -sin theta],
                [sin theta,  cos theta]]         (positive theta turns +x towards +y:
                                                  clockwise as displayed, y pointing down)

The transform is the motion of the *image content*: the scene point the reference frame shows at
pixel ``p`` appears in frame ``k`` at::

    q = c + R(theta) (p - c) + (dx, dy)                                   (forward)

(the camera itself moved the other way).  Hence

* frame ``k``'s pixel ``q`` sees the reference point ``p = c + R(theta)^T (q - (dx, dy) - c)``
  (:func:`warp_scene` samples the scene there);
* ``aligned(p) = frame(c + R(theta) (p - c) + (dx, dy))`` brings frame ``k`` back onto the
  reference (:func:`align_frame`).  Without rotation this is ``aligned(x, y) = frame(x + dx,
  y + dy)``: an aligner that reports its shift in that convention should find the truth's
  ``(dx, dy)`` itself, with the same sign.  With rotation, resample at ``(x, y)`` rotated by
  ``theta`` about ``c``, then shifted by ``(dx, dy)``.
* the 2x3 ``matrix`` ``[[cos, -sin, tx], [sin, cos, ty]]``, ``(tx, ty) = c - R c + (dx, dy)``,
  maps the reference pixel ``(x, y, 1)`` to the frame pixel ``q``.

The reference frame (index ``n // 2``, the middle of the bracket) has the transform ``(0, 0, 0)``
exactly; the others draw ``dx, dy ~ Normal(0, shift_sigma)`` px and ``theta ~ Normal(0,
rotation_sigma)`` degrees (rounded to 12 significant digits, the values ``truth.json`` holds).

Scene, margin, interpolation.  The scene is rendered larger than the frame, by a margin
(:func:`margin_for`) large enough that no frame samples outside it; the reference pixel
``(x, y)`` is the scene's ``(x + margin, y + margin)``.  Frames sample it bilinearly (``order=1``,
computed here in plain arithmetic so the bytes are the same on every CPU and equal
``scipy.ndimage.map_coordinates(..., order=1, mode="reflect")`` to rounding; bilinear also keeps
the radiance positive next to the structured scene's very bright lights, where a cubic spline
would ring below zero).  ``order=3`` uses ``map_coordinates`` itself.  The camera motion applies
to the *scene* radiance; vignetting, sensor, tone curve, Bayer and JPEG belong to the camera and
follow as before.

Movers.  Ellipses (height ``size`` x the frame height, width 0.6 x that) of a uniform colour with
an 8 % texture that moves with them, whose centre moves linearly by ``speed`` px per frame (mostly
horizontally, like people walking), at the reference frame's time in the middle of the view.  A
mover occludes the scene: its radiance replaces the scene's where its mask is set.  Movers live
in the scene (reference-frame coordinates), so the camera's shake moves them too.

Public objects
--------------
DEFAULTS
    The options ``tsin01`` takes from here and their defaults (off).
CONVENTION
    The sign convention above, as written to ``truth.json``.
frame_transforms(rng, n, shift_sigma, rotation_sigma, reference)
    ``(dx, dy, rotation_deg)`` per frame, the reference's exactly ``(0, 0, 0)``.
margin_for(transforms, shape)
    The scene margin (px) no frame samples beyond.
warp_scene(E, transform, out_shape, margin, order)
    The scene radiance as frame ``k`` sees it.
align_frame(frame, transform, order)
    The documented inverse: a frame resampled onto the reference.
transform_matrix(transform, shape)
    The 2x3 affine map from reference to frame pixels.
Mover, draw_movers(...), render_movers(...), movers(...)
    Moving objects: drawn, rendered in one frame, or all frames' masks and radiance.
Plan, plan(opts, seed, n_frames, shape)
    What :func:`ccdcore.simulate.tsin.simulate` does with the options (``None`` when off).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import CcdError
from ._common import round_sig

__all__ = ["DEFAULTS", "CONVENTION", "frame_transforms", "margin_for", "warp_scene",
           "align_frame", "transform_matrix", "cos_sin_deg", "Mover", "draw_movers",
           "render_movers", "movers", "Plan", "plan", "check_options"]

#: the options of ``tsin01`` handled here; at these values nothing moves
DEFAULTS: dict[str, Any] = {
    "handheld_shift": 0.0,       # px, standard deviation of dx and dy per frame
    "handheld_rotation": 0.0,    # degrees, standard deviation of the rotation per frame
    "movers": 0,                 # number of moving objects
    "mover_size": 0.12,          # height of a mover, fraction of the frame height
    "mover_speed": 12.0,         # px per frame
}

CONVENTION = ("transform (dx, dy, rotation_deg = theta) of frame k = motion of the image content; "
              "pixel coordinates x right (column), y down (row), centre c = ((W-1)/2, (H-1)/2), "
              "R(theta) = [[cos, -sin], [sin, cos]] (positive theta turns +x towards +y, "
              "clockwise as displayed): the scene point at reference pixel p appears in frame k "
              "at q = c + R(theta) (p - c) + (dx, dy) (matrix: [R | c - R c + (dx, dy)] maps "
              "(x, y, 1) of the reference to q); so aligned(p) = frame(c + R(theta) (p - c) + "
              "(dx, dy)) brings frame k onto the reference, for theta = 0 aligned(x, y) = "
              "frame(x + dx, y + dy): an aligner reporting its shift in that convention finds "
              "(dx, dy) with the same sign")

_DEG = math.pi / 180.0
_MOVER_ASPECT = 0.6          # width / height of a mover
_MOVER_TEXTURE = 0.08        # relative standard deviation of a mover's texture


def check_options(opts: dict[str, Any]) -> None:
    """Raise :class:`CcdError` for a negative sigma, speed or count, or a size outside (0, 1]."""
    for key in ("handheld_shift", "handheld_rotation", "mover_speed"):
        if not float(opts[key]) >= 0.0:
            raise CcdError(key, f"must be >= 0, got {opts[key]}")
    n = opts["movers"]
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or int(n) < 0:
        raise CcdError("movers", f"must be an integer >= 0, got {n!r}")
    if not 0.0 < float(opts["mover_size"]) <= 1.0:
        raise CcdError("mover_size", f"must be in (0, 1], got {opts['mover_size']}")


def cos_sin_deg(theta_deg: float) -> tuple[float, float]:
    """``cos`` and ``sin`` of an angle in degrees, by a fixed Horner series in plain float
    arithmetic (the C library's ``cos`` has CPU-dispatched variants): the same bits everywhere,
    within 1e-15 of ``math.cos``/``math.sin``."""
    t = math.fmod(float(theta_deg), 360.0)           # exact
    if t > 180.0:
        t -= 360.0                                   # exact (Sterbenz)
    elif t < -180.0:
        t += 360.0
    x = t * _DEG
    x2 = x * x
    s = c = 1.0
    for k in range(20, 0, -1):                       # |x| <= pi: x^40 / 40! is negligible
        s = 1.0 - x2 * s / ((2 * k) * (2 * k + 1))
        c = 1.0 - x2 * c / ((2 * k - 1) * (2 * k))
    return c, x * s


def frame_transforms(rng: np.random.Generator, n: int, shift_sigma: float,
                     rotation_sigma: float, reference: int | None = None
                     ) -> list[tuple[float, float, float]]:
    """``(dx, dy, rotation_deg)`` per frame (module notes for the convention).

    Every frame draws three standard normals (the reference too, so the others' draws do not
    depend on which is the reference); ``dx, dy = shift_sigma N``, ``rotation_deg =
    rotation_sigma N``, rounded to 12 significant digits; the reference frame (default
    ``n // 2``) is exactly ``(0.0, 0.0, 0.0)``.
    """
    n = int(n)
    reference = n // 2 if reference is None else int(reference)
    if not 0 <= reference < n:
        raise CcdError("reference", f"frame {reference} is not in 0..{n - 1}")
    draws = rng.standard_normal((n, 3))
    scale = (float(shift_sigma), float(shift_sigma), float(rotation_sigma))
    out = []
    for k in range(n):
        if k == reference:
            out.append((0.0, 0.0, 0.0))
        else:   # + 0.0: no -0.0 when a sigma is 0
            out.append(tuple(round_sig(scale[i] * float(draws[k, i])) + 0.0 for i in range(3)))
    return out


def _centre(shape: Sequence[int]) -> tuple[float, float]:
    return (int(shape[1]) - 1) / 2.0, (int(shape[0]) - 1) / 2.0


def transform_matrix(transform: Sequence[float], shape: Sequence[int]) -> list[list[float]]:
    """The 2x3 affine ``[R | c - R c + (dx, dy)]`` mapping a reference pixel ``(x, y, 1)`` to
    the pixel of the frame (``shape`` = the frame's ``(H, W)``) where that scene point appears."""
    dx, dy, theta = (float(v) for v in transform)
    cos, sin = cos_sin_deg(theta)
    cx, cy = _centre(shape)
    return [[cos, -sin, cx - (cos * cx - sin * cy) + dx],
            [sin, cos, cy - (sin * cx + cos * cy) + dy]]


def margin_for(transforms: Sequence[Sequence[float]], shape: Sequence[int]) -> int:
    """The margin (px) around the frame of ``shape`` = ``(H, W)`` that no frame of
    ``transforms`` samples beyond: the largest displacement of a frame corner's sample point
    (the displacement is affine, so a corner's is the largest), rounded up, plus 2 for the
    bilinear support; 0 when every transform is the identity."""
    h, w = int(shape[0]), int(shape[1])
    cx, cy = _centre(shape)
    worst = 0.0
    for dx, dy, theta in transforms:
        if (dx, dy, theta) == (0.0, 0.0, 0.0):
            continue
        cos, sin = cos_sin_deg(theta)
        for x, y in ((0.0, 0.0), (w - 1.0, 0.0), (0.0, h - 1.0), (w - 1.0, h - 1.0)):
            u, v = x - dx - cx, y - dy - cy
            px, py = cx + cos * u + sin * v, cy - sin * u + cos * v
            worst = max(worst, abs(px - x), abs(py - y))
    return 0 if worst == 0.0 else int(math.ceil(worst)) + 2


def _reflect(i: NDArray, n: int) -> NDArray:
    """Indices folded into ``0 .. n-1`` as ``scipy.ndimage``'s ``mode="reflect"`` (d c b a |
    a b c d | d c b a)."""
    i = np.mod(i, 2 * n)
    return np.where(i >= n, 2 * n - 1 - i, i)


def _sample(A: NDArray, X: NDArray, Y: NDArray, order: int) -> NDArray[np.float64]:
    """``A`` (``(H, W)`` or ``(H, W, C)``) at the fractional indices ``(Y, X)``, mode reflect."""
    A = np.asarray(A, dtype=np.float64)
    if order == 1:
        x0, y0 = np.floor(X), np.floor(Y)
        fx, fy = X - x0, Y - y0
        ix0, iy0 = x0.astype(np.intp), y0.astype(np.intp)
        ix0, ix1 = _reflect(ix0, A.shape[1]), _reflect(ix0 + 1, A.shape[1])
        iy0, iy1 = _reflect(iy0, A.shape[0]), _reflect(iy0 + 1, A.shape[0])
        if A.ndim == 3:
            fx, fy = fx[..., None], fy[..., None]
        top = (1.0 - fx) * A[iy0, ix0] + fx * A[iy0, ix1]
        bottom = (1.0 - fx) * A[iy1, ix0] + fx * A[iy1, ix1]
        return (1.0 - fy) * top + fy * bottom
    if order != 3:
        raise CcdError("order", f"interpolation order must be 1 or 3, got {order}")
    from scipy import ndimage

    coords = np.stack([Y, X])
    if A.ndim == 2:
        return ndimage.map_coordinates(A, coords, order=3, mode="reflect")
    return np.stack([ndimage.map_coordinates(A[..., ch], coords, order=3, mode="reflect")
                     for ch in range(A.shape[2])], axis=2)


def _grid(transform: Sequence[float], out_shape: Sequence[int], inverse: bool
          ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Sample points ``(X, Y)`` of every output pixel, in the output's own coordinates:
    ``inverse=False`` (warp): ``c + R^T (q - d - c)``; ``inverse=True`` (align):
    ``c + R (p - c) + d``."""
    dx, dy, theta = (float(v) for v in transform)
    cos, sin = cos_sin_deg(theta)
    cx, cy = _centre(out_shape)
    xs = np.arange(int(out_shape[1]), dtype=np.float64)[None, :]
    ys = np.arange(int(out_shape[0]), dtype=np.float64)[:, None]
    if inverse:
        u, v = xs - cx, ys - cy
        return (cos * u - sin * v) + (cx + dx), (sin * u + cos * v) + (cy + dy)
    u, v = xs - (dx + cx), ys - (dy + cy)
    return (cos * u + sin * v) + cx, (cos * v - sin * u) + cy


def warp_scene(E: ArrayLike, transform: Sequence[float], out_shape: Sequence[int],
               margin: int, order: int = 1) -> NDArray[np.float64]:
    """The scene radiance as seen by a frame whose content moved by ``transform``.

    ``E`` is the scene with ``margin`` pixels on every side (``(H + 2m, W + 2m)`` or with
    channels), ``out_shape`` the frame's ``(H, W)``.  The frame's pixel ``q = (x, y)`` sees the
    reference point ``p = c + R(theta)^T (q - (dx, dy) - c)``, i.e. ``E[p_y + m, p_x + m]``
    (module notes): the scene point at reference pixel ``p`` appears at ``q = c + R(theta)
    (p - c) + (dx, dy)``.  :func:`align_frame` undoes it.  The identity is an exact crop.
    ``order`` 1 (bilinear, CPU-independent) or 3 (``scipy.ndimage.map_coordinates``), both with
    ``mode="reflect"``; with a margin of :func:`margin_for` nothing reflects.
    """
    E = np.asarray(E)
    h, w, m = int(out_shape[0]), int(out_shape[1]), int(margin)
    if E.shape[0] < h + 2 * m or E.shape[1] < w + 2 * m:
        raise CcdError("E", f"a scene of {E.shape[:2]} has no margin {m} around {h}x{w}")
    if tuple(float(v) for v in transform) == (0.0, 0.0, 0.0):
        return np.array(E[m:m + h, m:m + w], dtype=np.float64)
    X, Y = _grid(transform, (h, w), inverse=False)
    return _sample(E, X + m, Y + m, order)


def align_frame(frame: ArrayLike, transform: Sequence[float], order: int = 1
                ) -> NDArray[np.float64]:
    """Frame ``k`` brought back onto the reference: ``aligned(p) = frame(c + R(theta) (p - c) +
    (dx, dy))`` (for ``theta = 0``: ``aligned(x, y) = frame(x + dx, y + dy)``), ``mode
    "reflect"`` where that falls outside the frame (the border strip of the frame's motion)."""
    frame = np.asarray(frame)
    if tuple(float(v) for v in transform) == (0.0, 0.0, 0.0):
        return np.array(frame, dtype=np.float64)
    X, Y = _grid(transform, frame.shape[:2], inverse=True)
    return _sample(frame, X, Y, order)


@dataclass(frozen=True)
class Mover:
    """A moving object: an upright ellipse whose centre is ``centre`` (reference-frame pixels,
    ``(x, y)``) at frame ``reference`` and moves by ``velocity`` px per frame; semi-axes
    ``radii = (rx, ry)``; radiance ``colour`` (per channel) times ``texture`` (a relative
    pattern on a grid centred on the mover, looked up at the nearest node)."""

    centre: tuple[float, float]
    velocity: tuple[float, float]
    radii: tuple[float, float]
    colour: tuple[float, ...]
    texture: NDArray[np.float64]
    reference: int

    def centre_at(self, k: int) -> tuple[float, float]:
        """The centre ``(x, y)`` in frame ``k``: ``centre + (k - reference) velocity``."""
        s = float(int(k) - self.reference)
        return self.centre[0] + s * self.velocity[0], self.centre[1] + s * self.velocity[1]

    def describe(self, n_frames: int) -> dict[str, Any]:
        return {"centre": [list(self.centre_at(k)) for k in range(int(n_frames))],
                "velocity": list(self.velocity), "radii": list(self.radii),
                "colour": list(self.colour), "reference": self.reference}


def draw_movers(rng: np.random.Generator, n_movers: int, n_frames: int, shape: Sequence[int],
                size: float, speed: float, *, n_channels: int = 3, level: float = 0.5,
                reference: int | None = None) -> list[Mover]:
    """``n_movers`` movers in a frame of ``shape`` = ``(H, W)``: height ``size H``, width 0.6
    of that; at frame ``reference`` (default ``n_frames // 2``) centred uniformly in the middle
    half of the width and 40 % of the height; moving ``speed`` px per frame, left or right with
    a slope in ``[-0.25, 0.25]``; colour ``level`` x ``U(0.4, 2.5)`` per channel; texture
    ``1 + 0.08 N`` (clipped to ``[0.6, 1.4]``)."""
    h, w = int(shape[0]), int(shape[1])
    reference = int(n_frames) // 2 if reference is None else int(reference)
    ry = max(2.0, 0.5 * float(size) * h)
    rx = max(1.5, _MOVER_ASPECT * ry)
    half = int(math.ceil(ry)) + 1
    out = []
    for _ in range(int(n_movers)):
        cx, cy = float(rng.uniform(0.25 * w, 0.75 * w)), float(rng.uniform(0.3 * h, 0.7 * h))
        sign = 1.0 if rng.integers(2) else -1.0
        slope = float(rng.uniform(-0.25, 0.25))
        norm = math.sqrt(1.0 + slope * slope)
        velocity = (round_sig(sign * float(speed) / norm) + 0.0,
                    round_sig(slope * float(speed) / norm) + 0.0)
        colour = tuple(round_sig(float(level) * float(c))
                       for c in rng.uniform(0.4, 2.5, int(n_channels)))
        texture = np.clip(1.0 + _MOVER_TEXTURE * rng.standard_normal((2 * half + 1,) * 2),
                          0.6, 1.4)
        out.append(Mover((round_sig(cx), round_sig(cy)), velocity, (rx, ry), colour, texture,
                         reference))
    return out


def render_movers(items: Sequence[Mover], k: int, shape: Sequence[int], *, offset: int = 0,
                  n_channels: int | None = None
                  ) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """Mask ``(H, W)`` and radiance ``(H, W, C)`` (0 outside the mask) of the movers in frame
    ``k`` on a grid of ``shape`` where the reference pixel ``(x, y)`` is ``(x + offset,
    y + offset)``; a later mover occludes an earlier one.  A pixel is the mover's when its
    centre lies in the ellipse."""
    h, w = int(shape[0]), int(shape[1])
    nc = int(n_channels) if n_channels is not None else (len(items[0].colour) if items else 1)
    mask = np.zeros((h, w), dtype=bool)
    rad = np.zeros((h, w, nc))
    for mv in items:
        cx, cy = mv.centre_at(k)
        cx, cy = cx + offset, cy + offset
        rx, ry = mv.radii
        x0, x1 = max(0, int(math.floor(cx - rx))), min(w, int(math.ceil(cx + rx)) + 1)
        y0, y1 = max(0, int(math.floor(cy - ry))), min(h, int(math.ceil(cy + ry)) + 1)
        if x0 >= x1 or y0 >= y1:
            continue
        X = np.arange(x0, x1, dtype=np.float64)[None, :] - cx
        Y = np.arange(y0, y1, dtype=np.float64)[:, None] - cy
        inside = (X / rx) * (X / rx) + (Y / ry) * (Y / ry) <= 1.0
        half = mv.texture.shape[0] // 2
        tx = np.clip(np.rint(X).astype(np.intp) + half, 0, 2 * half)
        ty = np.clip(np.rint(Y).astype(np.intp) + half, 0, 2 * half)
        tex = mv.texture[ty, tx]                                  # (y1 - y0, x1 - x0)
        colour = np.asarray(mv.colour, dtype=np.float64)[:nc]
        sub = rad[y0:y1, x0:x1]
        sub[inside] = (tex[..., None] * colour)[inside]
        mask[y0:y1, x0:x1] |= inside
    return mask, rad


def movers(rng: np.random.Generator, n_movers: int, n_frames: int, shape: Sequence[int],
           size: float, speed: float, *, n_channels: int = 3, level: float = 0.5,
           reference: int | None = None
           ) -> tuple[NDArray[np.bool_], NDArray[np.float64], list[Mover]]:
    """All frames' movers (:func:`draw_movers`, :func:`render_movers`): masks
    ``(n_frames, H, W)`` bool, radiance ``(n_frames, H, W, C)`` to paste over the scene where
    the mask is set (0 elsewhere), and the movers."""
    items = draw_movers(rng, n_movers, n_frames, shape, size, speed, n_channels=n_channels,
                        level=level, reference=reference)
    frames = [render_movers(items, k, shape, n_channels=n_channels) for k in range(n_frames)]
    return (np.stack([f[0] for f in frames]), np.stack([f[1] for f in frames]), items)


@dataclass
class Plan:
    """The handheld bracket of one ``tsin01`` session: per-frame transforms (the same for every
    stack), the scene margin, the movers (drawn by :meth:`attach`) and the static scene."""

    opts: dict[str, Any]
    seed: int
    shape: tuple[int, int]
    transforms: list[tuple[float, float, float]]
    reference: int
    margin: int
    movers: list[Mover] = field(default_factory=list)
    scene: NDArray | None = None
    V: NDArray | None = None

    def grown(self, shape: tuple[int, ...]) -> tuple[int, ...]:
        """``shape`` with the margin on every side."""
        m = 2 * self.margin
        return (shape[0] + m, shape[1] + m) + tuple(shape[2:])

    def pad(self, E: NDArray) -> NDArray:
        """A given radiance of the frame's shape grown by the margin (mirrored, as
        ``mode="reflect"``)."""
        m = self.margin
        return np.pad(E, [(m, m), (m, m)] + [(0, 0)] * (E.ndim - 2), mode="symmetric")

    def crop(self, E: NDArray) -> NDArray:
        """The reference frame's part of the scene (exact, no interpolation)."""
        m, (h, w) = self.margin, self.shape
        return E[m:m + h, m:m + w]

    def attach(self, scene: NDArray, V: NDArray | None) -> None:
        """Keep the static scene (with the margin, before vignetting) and the vignetting map;
        draw the movers (own stream ``[seed, 4]``) at the scene's median radiance."""
        self.scene, self.V = scene, V
        n = int(self.opts["movers"])
        if n:
            nc = scene.shape[2] if scene.ndim == 3 else 1
            self.movers = draw_movers(np.random.default_rng([self.seed, 4]), n,
                                      len(self.transforms), self.shape,
                                      float(self.opts["mover_size"]),
                                      float(self.opts["mover_speed"]), n_channels=nc,
                                      level=float(np.median(scene)), reference=self.reference)

    def _layers(self, k: int) -> tuple[NDArray, NDArray[np.bool_]]:
        """Frame ``k``'s scene with its movers pasted (margin grid), and their mask there."""
        assert self.scene is not None
        if not self.movers:
            return self.scene, np.zeros(self.scene.shape[:2], dtype=bool)
        mask, rad = render_movers(self.movers, k, self.scene.shape[:2], offset=self.margin)
        rad = rad[..., 0] if self.scene.ndim == 2 else rad
        sel = mask if self.scene.ndim == 2 else mask[..., None]
        return np.where(sel, rad, np.asarray(self.scene, dtype=np.float64)), mask

    def frame_radiance(self, k: int) -> NDArray[np.float32]:
        """What frame ``k``'s camera sees: the scene with its movers, warped by the frame's
        transform, times the vignetting, as float32 (as ``truth/E.exr``)."""
        S, _ = self._layers(k)
        F = warp_scene(S, self.transforms[k], self.shape, self.margin)
        if self.V is not None:
            F = F * (self.V if F.ndim == 2 else self.V[..., None])
        return np.asarray(F, dtype=np.float32)

    def masks(self) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
        """Per frame, the movers' pixels in the frame's own grid (any bilinear weight on a
        mover) and in the reference grid (where they are in the scene), ``(n, H, W)`` each."""
        own, ref = [], []
        for k, tr in enumerate(self.transforms):
            _, mask = self._layers(k)
            own.append(warp_scene(mask.astype(np.float64), tr, self.shape, self.margin) > 0.0)
            ref.append(np.array(self.crop(mask)))
        return np.stack(own), np.stack(ref)

    def truth(self, out_dir: str | Path, frames: Sequence[dict[str, Any]]) -> dict[str, Any]:
        """Write the movers' masks (``.npy``: a plain-folder reader would take an image in the
        session for a frame) and return the keys ``transforms``, ``handheld``, ``movers``."""
        transforms = [{"file": f["path"], "stack": f["stack"], "index": f["index"],
                       "dx": self.transforms[f["index"]][0], "dy": self.transforms[f["index"]][1],
                       "rotation_deg": self.transforms[f["index"]][2],
                       "matrix": transform_matrix(self.transforms[f["index"]], self.shape)}
                      for f in frames]
        ref_file = next(f["path"] for f in frames if f["index"] == self.reference)
        out: dict[str, Any] = {"transforms": transforms, "handheld": {
            "shift_sigma": float(self.opts["handheld_shift"]),
            "rotation_sigma": float(self.opts["handheld_rotation"]),
            "convention": CONVENTION, "reference": ref_file, "reference_index": self.reference,
            "centre": list(_centre(self.shape)), "margin": self.margin,
            "scene_map": "truth/scene_margin.exr" if self.margin else None,
            "interpolation": "bilinear (order 1), mode reflect; the reference frame is an exact "
                             "crop of the scene",
            "E": "truth/E.exr is the static scene as the reference frame sees it (no movers)",
            "scene_grid": "scene_margin.exr and the scene's description (patches, lights) are "
                          "in the margin grid: reference pixel (x, y) = scene (x + margin, "
                          "y + margin)"}}
        if self.movers:
            own, ref = self.masks()
            root = Path(out_dir) / "truth"
            root.mkdir(parents=True, exist_ok=True)
            np.save(root / "movers.npy", own)
            np.save(root / "movers_aligned.npy", ref)
            np.save(root / "moving_mask.npy", ref.any(axis=0))
            out["movers"] = {
                "count": len(self.movers), "size": float(self.opts["mover_size"]),
                "speed": float(self.opts["mover_speed"]),
                "masks": "truth/movers.npy", "aligned_masks": "truth/movers_aligned.npy",
                "moving_mask": "truth/moving_mask.npy", "shape": list(own.shape),
                "pixels": [int(m.sum()) for m in own],
                "aligned_pixels": [int(m.sum()) for m in ref],
                "moving_pixels": int(ref.any(axis=0).sum()),
                "note": "movers.npy[k]: frame k's pixels with any mover in them (frame k's own "
                        "grid); movers_aligned.npy[k]: the same in the reference grid (frame "
                        "k aligned); moving_mask.npy: union of movers_aligned over the frames "
                        "(where the aligned exposures disagree); bool, one mask per frame "
                        "index, the same in every stack",
                "tracks": [mv.describe(len(self.transforms)) for mv in self.movers]}
        return out

    def note(self) -> str:
        """A line for the manifest's note."""
        return ("\nHandheld bracket: frames shifted/rotated (truth.json: transforms, handheld)"
                + (f", {len(self.movers)} moving object(s) (truth.json: movers)"
                   if self.movers else "") + ".")


def plan(opts: dict[str, Any], seed: int, n_frames: int, shape: Sequence[int]) -> Plan | None:
    """The handheld plan of a ``tsin01`` session, or ``None`` when the options are off.

    The transforms draw from their own stream ``[seed, 3]`` (the session's other draws stay where
    they are); ``shape`` is the frame's ``(H, W)``.
    """
    shift, rot = float(opts["handheld_shift"]), float(opts["handheld_rotation"])
    if shift == 0.0 and rot == 0.0 and int(opts["movers"]) == 0:
        return None
    h, w = int(shape[0]), int(shape[1])
    transforms = frame_transforms(np.random.default_rng([int(seed), 3]), int(n_frames), shift,
                                  rot)
    return Plan(opts=opts, seed=int(seed), shape=(h, w), transforms=transforms,
                reference=int(n_frames) // 2, margin=margin_for(transforms, (h, w)))
