"""The ``tsin01-camera`` preset: ``tsin01`` with the option bundle ``camera="real"``.

An 8-bit JPEG camera's bracket (:data:`ccdcore.simulate.camera.CAMERAS` ``["real"]``: 10 frames
one stop apart, Bayer RGGB, the sRGB-like tone curve with toe and knee, a structured scene with
vignetting, exposure errors, per-frame white balance, sharpening, JPEG), written by
:func:`ccdcore.simulate.tsin.simulate`; ``simulate("tsin01", out, camera="real")`` gives the same
bytes.  It sits above both modules it joins: :mod:`ccdcore.simulate.tsin` (the pipeline) imports
:mod:`ccdcore.simulate.camera` (the building blocks), and neither imports this one.

Public objects
--------------
simulate(out_dir, *, seed, size, **options)
    The ``tsin01-camera`` preset (:data:`ccdcore.simulate.PRESETS`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from .tsin import simulate as tsin_simulate

__all__ = ["simulate"]


def simulate(out_dir: str | Path, *, seed: int = 0, size: tuple[int, int] | None = None,
             **options: Any) -> dict[str, Any]:
    """The ``tsin01-camera`` preset: ``tsin01`` with ``camera="real"``
    (:data:`ccdcore.simulate.camera.CAMERAS`).

    ``size`` defaults to :data:`ccdcore.simulate.camera.DEFAULT_SIZE`; ``options`` override the
    bundle's, and ``camera="real-listed-wrong"`` picks the bundle whose listed exposures are wrong
    for four of its pairs.
    """
    options.setdefault("camera", "real")
    return tsin_simulate(out_dir, seed=seed, size=size, **options)
