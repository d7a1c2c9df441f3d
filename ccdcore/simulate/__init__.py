"""Physical camera simulators: the ground truth every estimator is tested against.

Presets (each a module with ``simulate(out_dir, *, seed, size, **options) -> dict``):

``healey94``
    Healey & Kondepudy (1994) CCD model, eq. 20: fixed pattern K, dark current, shot, read and
    quantisation noise; dark frames, photon-transfer pairs, fixed-pattern configurations, scene
    patches with known scene variation V_S.
``delasarte07``
    de Lasarte et al. (2007) RGB camera with gain/offset settings, vignetting and PRNU, uniform
    fields at several radiance levels and exposure times.
``tsin01``
    Tsin, Ramesh & Kanade (2001) imaging pipeline, eq. 3: response f, white balance a_k, b_k,
    three noise terms, sec. 4.1 bracket protocol; options for a real camera's processing (tone
    curve with toe and knee, structured scene, vignetting, exposure errors, JPEG), see
    :mod:`ccdcore.simulate.camera`.
``tsin01-camera``
    ``tsin01`` with the option bundle ``camera="real"``: an 8-bit JPEG camera's bracket
    (:mod:`ccdcore.simulate.tsin_camera`).
``change``
    Tsin et al. (2001) sec. 5 change scene: planar textured background, 3x3 colour transforms for
    the illumination change and shadows, inserted objects, truth masks.
``emva1288``
    An EMVA 1288 exposure-time series (:mod:`ccdcore.simulate.emva`): photon counts, dark pairs
    at every exposure, spatial sets; a known dark current and DSNU/PRNU maps with row, column and
    pixel parts; written as an EMVA1288 descriptor and a manifest.

``ccdlab``
    A cooled astronomy CCD as labs capture it (:mod:`ccdcore.simulate.ccdlab`): biases, darks
    at several exposures and two sensor temperatures (dark current doubling every few degrees,
    hot pixels), flats at one exposure, FITS headers with ``SET-TEMP`` and ``CCD-TEMP``.

Every preset writes a capture session (``session.toml`` + frames) and ``truth.json``. The same seed
gives the same bytes whatever the CPU's vector features (AVX2, AVX-512, NEON): what feeds a digital
number is computed with basic arithmetic and the CPU-independent functions of
:mod:`ccdcore.simulate._det` instead of NumPy's CPU-dispatched ``exp``/``power``/``tanh``/BLAS
loops (the random draws are NumPy's ``Generator``, whose C code is not dispatched), and the floats
of ``truth.json`` carry 12 significant digits (see :mod:`ccdcore.simulate._common`).  Frame metadata
goes into the manifest's keys (``setting``, ``patch``, ``flags``), never into ``note``.

:func:`load_truth` / :func:`find_truth` read a session's ``truth.json`` into a :class:`Truth`
(values by key, true maps by :meth:`Truth.map`); see :mod:`ccdcore.simulate.truth`.
"""
from __future__ import annotations

import importlib
import json
from pathlib import Path
from typing import Any

from ..errors import CcdError
from .truth import Truth, find_truth, load_truth

__all__ = ["PRESETS", "simulate", "is_simulation", "Truth", "load_truth", "find_truth"]

#: preset name -> module (relative to this package) implementing it
PRESETS: dict[str, str] = {
    "healey94": "healey",
    "delasarte07": "delasarte",
    "tsin01": "tsin",
    "tsin01-camera": "tsin_camera",
    "change": "change",
    "emva1288": "emva",
    "ccdlab": "ccdlab",
}


def is_simulation(folder: str | Path) -> bool:
    """Whether ``folder`` holds a session an earlier :func:`simulate` wrote: its ``truth.json``
    is an object naming one of :data:`PRESETS` and the seed (a real capture has no such
    file, and a user's files are never taken for one)."""
    try:
        truth = json.loads((Path(folder) / "truth.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(truth, dict) and truth.get("preset") in PRESETS and "seed" in truth


def simulate(preset: str, out_dir: str | Path, *, seed: int = 0,
             size: tuple[int, int] | None = None, force: bool = False,
             **options: Any) -> dict[str, Any]:
    """Write the session of ``preset`` into ``out_dir`` and return its truth dictionary.

    Parameters
    ----------
    preset
        One of :data:`PRESETS`.
    out_dir
        Folder to write into (created if needed): new, empty, or an earlier simulation
        (:func:`is_simulation`), whose files of the same names are replaced. A folder holding
        anything else (a real session, say) is refused unless ``force``.
    seed
        Seed of the random generator; the same seed gives the same bytes.
    size
        ``(width, height)`` of the frames; ``None`` uses the preset's default.
    force
        Write into a folder that holds other files too.
    **options
        Preset-specific options (numbers of frames, noise parameters ...), see each module.

    The session is written as one set (:func:`ccdcore.io.frames.output_set`): into a temporary
    folder, then renamed into ``out_dir``, so a failure or SIGTERM leaves ``out_dir`` as it was.
    """
    from ..io.frames import TEMP_PREFIX, check_output, output_set   # here: importing stays light

    if preset not in PRESETS:
        raise CcdError(preset, f"unknown preset; choose one of {', '.join(PRESETS)}")
    module = importlib.import_module(f".{PRESETS[preset]}", __name__)
    kwargs: dict[str, Any] = dict(options)
    if size is not None:
        w, h = size
        if w < 8 or h < 8:
            raise CcdError("size", f"{w}x{h} is too small; use at least 8x8")
        kwargs["size"] = (int(w), int(h))
    out = Path(out_dir)
    check_output(out, folder=True)
    if (not force and out.is_dir() and not is_simulation(out)
            and any(not p.name.startswith(TEMP_PREFIX) for p in out.iterdir())):
        raise CcdError(out, "holds files that are not an earlier simulation (no truth.json of "
                            "ours); choose a new or empty folder, or give --force to write "
                            "into it")
    # the folder was taken as it is above (an earlier simulation, or --force)
    with output_set(out, force=True, record=False) as tmp:
        return module.simulate(tmp, seed=int(seed), **kwargs)
