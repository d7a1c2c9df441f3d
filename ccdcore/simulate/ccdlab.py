"""A cooled astronomy CCD as a lab captures it: biases, darks at several exposures and two
temperatures, hot pixels, and flats at one exposure (or flats without any dark frame).

Modelled on the SBIG STL-1001E set of ``docs/darks_flats.md``: a mono 16-bit CCD with a bias
(offset) map o(x) (level ``bias_dn`` plus a small fixed pattern), a dark current c_T(x) in DN/s
that doubles every ``doubling_c`` °C (``c_T = c_ref · 2^((T − T_ref)/doubling_c)``, each pixel
its own rate with a ``dark_spread`` relative spread; a fraction ``hot_fraction`` of hot pixels
with ``hot_factor`` times the median current), and a flat field F(x) (cos⁴-like vignetting times
a PRNU of ``prnu_std``, mean 1).  A frame of exposure t at temperature T is::

    DL = round(o + [Poisson(g·(c_T·t + S·F·t/t_flat)) / g] + N(0, σ_R²))     (g: e⁻/DN)

the model of eq. 43 of Healey & Kondepudy 1994 (dark current, shot and read noise,
quantisation) with the flat signal S (DN) for the flats.  The expected dark at t is o + c_T·t,
which :mod:`ccdcore.dark.model` fits.  Every frame carries its ``temperature`` (the set point) in
the manifest, as a FITS ``SET-TEMP`` would.

Frames (role; manifest keys ``exposure``, ``temperature``):

``bias/T<T>_<k>.tif`` (``dark``, exposure 0)
    ``n_bias`` per temperature.
``dark/T<T>_<t>s_<k>.tif`` (``dark``)
    ``n_dark`` per exposure of ``exposures`` and temperature (``darks=False``: no biases nor
    darks at all, de Lasarte's zero-dark case).
``flat/flat_<k>.tif`` (``flat``; exposure ``flat_exposure``, temperature ``flat_temperature``)
    ``n_flats`` flats.

``truth.json``: the parameters, ``maps``: ``truth/offset.exr`` (o, DN), ``truth/current_<T>.exr``
(c_T, DN/s, per temperature), ``truth/flatfield.exr`` (F, mean 1), ``truth/hot.exr`` (0/1).

The preset ``ccdlab`` of ``ccdcore simulate``.

Public objects
--------------
simulate(out_dir, ...)
    Write the session and return the truth.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CcdError
from ._common import SessionWriter
from .sensor import child_rng

__all__ = ["simulate", "CAMERA_NAME"]

CAMERA_NAME = "cooled CCD (SBIG-like, simulated)"


def _maps(shape: tuple[int, int], seed: int, bias_dn: float, bias_std: float,
          dark_spread: float, hot_fraction: float, hot_factor: float, prnu_std: float,
          vignetting_corner: float) -> dict[str, np.ndarray]:
    """The true offset map, relative current map (median 1, hot pixels included), hot mask and
    flat field (mean 1)."""
    rng = child_rng(seed, "ccdlab_maps")
    h, w = shape
    offset = bias_dn + bias_std * rng.standard_normal(shape)
    rel = np.clip(1.0 + dark_spread * rng.standard_normal(shape), 0.05, None)
    hot = rng.random(shape) < hot_fraction
    rel = np.where(hot, hot_factor * (1.0 + rng.random(shape)), rel)
    y, x = np.mgrid[0:h, 0:w]
    r2 = ((x - (w - 1) / 2) ** 2 + (y - (h - 1) / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    vign = 1.0 - (1.0 - vignetting_corner) * r2
    flat = vign * (1.0 + prnu_std * rng.standard_normal(shape))
    return {"offset": offset, "current_rel": rel, "hot": hot, "flat": flat / flat.mean()}


def simulate(out_dir: str | Path, *, seed: int = 0, size: tuple[int, int] = (64, 48),
             bias_dn: float = 1000.0, bias_std: float = 3.0, gain_e_per_dn: float = 2.0,
             read_noise_dn: float = 7.0, dark_current_dn_per_s: float = 0.5,
             reference_temperature: float = -5.0, doubling_c: float = 6.0,
             dark_spread: float = 0.1, hot_fraction: float = 0.003, hot_factor: float = 30.0,
             temperatures: Sequence[float] = (-10.0, -5.0), n_bias: int = 6,
             exposures: Sequence[float] = (10.0, 30.0, 60.0, 150.0, 300.0), n_dark: int = 2,
             darks: bool = True, flat_temperature: float = -5.0, flat_exposure: float = 23.0,
             flat_level_dn: float = 20000.0, n_flats: int = 10, prnu_std: float = 0.01,
             vignetting_corner: float = 0.85) -> dict[str, Any]:
    """Write the lab session into ``out_dir`` and return its truth (module docstring).

    Parameters
    ----------
    out_dir
        Session folder (created).
    seed
        Seed; the same seed gives the same bytes.
    size
        ``(width, height)``.
    bias_dn, bias_std
        Bias level and the spatial std of the bias map (DN).
    gain_e_per_dn, read_noise_dn
        Conversion gain g (e⁻/DN) and read noise σ_R (DN).
    dark_current_dn_per_s, reference_temperature, doubling_c
        Median dark current (DN/s) at the reference temperature and the temperature step
        (°C) that doubles it.
    dark_spread, hot_fraction, hot_factor
        Relative spatial spread of the current; fraction of hot pixels and their current over
        the median (times 1 to 2).
    temperatures
        Set points of the biases and darks (°C).
    n_bias, exposures, n_dark
        Biases per temperature; dark exposure times (s) and darks per exposure and temperature.
    darks
        ``False``: no biases nor darks (flats without darks).
    flat_temperature, flat_exposure, flat_level_dn, n_flats
        The flats' set point, exposure, mean signal above the dark (DN) and number.
    prnu_std, vignetting_corner
        PRNU (relative std) and the vignetting at the corners (relative).

    Returns
    -------
    dict
        The truth written to ``truth.json``.
    """
    w, h = int(size[0]), int(size[1])
    if w < 8 or h < 8:
        raise CcdError("size", f"{w}x{h} is too small; use at least 8x8")
    if n_flats < 1 or (darks and (n_bias < 0 or n_dark < 1)):
        raise CcdError("n_flats/n_bias/n_dark", "need n_flats >= 1, n_bias >= 0, n_dark >= 1")
    shape = (h, w)
    m = _maps(shape, seed, bias_dn, bias_std, dark_spread, hot_fraction, hot_factor, prnu_std,
              vignetting_corner)
    rng = child_rng(seed, "ccdlab_noise")
    g = float(gain_e_per_dn)

    def current(temp: float) -> np.ndarray:
        return dark_current_dn_per_s * 2.0 ** ((temp - reference_temperature) / doubling_c) \
            * m["current_rel"]

    def frame(t: float, temp: float, signal: np.ndarray | float = 0.0) -> np.ndarray:
        electrons = rng.poisson(g * (current(temp) * t + signal))
        v = m["offset"] + electrons / g + read_noise_dn * rng.standard_normal(shape)
        return np.clip(np.rint(v), 0, 65535).astype(np.uint16)

    writer = SessionWriter(out_dir, camera={"name": CAMERA_NAME, "bits": 16, "layout": "mono"})
    temps = [float(x) for x in temperatures]
    if darks:
        for temp in temps:
            for k in range(n_bias):
                writer.add_frame(f"bias/T{temp:g}_{k}.tif", frame(0.0, temp), role="dark",
                                 exposure=0.0, temperature=temp)
            for t in exposures:
                for k in range(n_dark):
                    writer.add_frame(f"dark/T{temp:g}_{float(t):g}s_{k}.tif", frame(t, temp),
                                     role="dark", exposure=float(t), temperature=temp)
    for k in range(n_flats):
        writer.add_frame(f"flat/flat_{k}.tif",
                         frame(flat_exposure, flat_temperature, flat_level_dn * m["flat"]),
                         role="flat", exposure=float(flat_exposure),
                         temperature=float(flat_temperature))
    writer.add_map("truth/offset.exr", m["offset"], name="offset")
    for temp in sorted(set(temps) | {float(flat_temperature)}):
        writer.add_map(f"truth/current_{temp:g}.exr", current(temp), name=f"current_{temp:g}")
    writer.add_map("truth/flatfield.exr", m["flat"], name="flatfield")
    writer.add_map("truth/hot.exr", m["hot"].astype(np.float32), name="hot")
    truth = {"preset": "ccdlab", "seed": int(seed), "size": [w, h], "bits": 16,
             "layout": "mono", "bias_dn": bias_dn, "gain_e_per_dn": g,
             "read_noise_dn": read_noise_dn, "dark_current_dn_per_s": dark_current_dn_per_s,
             "reference_temperature": reference_temperature, "doubling_c": doubling_c,
             "temperatures": temps if darks else [], "exposures": [float(t) for t in exposures],
             "n_bias": n_bias if darks else 0, "n_dark": n_dark if darks else 0,
             "darks": bool(darks), "flat_temperature": float(flat_temperature),
             "flat_exposure": float(flat_exposure), "flat_level_dn": flat_level_dn,
             "n_flats": n_flats, "n_hot": int(m["hot"].sum())}
    return writer.finish(truth, note=f"ccdcore.simulate.ccdlab.simulate(seed={int(seed)}, "
                                     f"size=({w}, {h}), darks={bool(darks)})")
