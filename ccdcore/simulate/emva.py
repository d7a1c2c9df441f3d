"""Preset ``emva1288``: a linear camera measured as EMVA Standard 1288 prescribes.

The session is the exposure-time series of the photon transfer method (EMVA Standard 1288
release 3.1 sec. 6, evaluated as in sec. 6.6; release 4.0 keeps it): a constant irradiance,
``steps`` exposure times from nearly dark to beyond saturation, at each a pair of bright frames
with its mean number of photons per pixel μ_p and a pair of dark frames; then the spatial sets
of sec. 8: L bright frames at about 50 % of saturation and L dark frames at their exposure.  The
camera has a known dark current (sec. 3.1) and known row, column and pixel patterns of its
offset (DSNU) and its response (PRNU) (sec. 4.1), the three parts release 4.0 separates
(:mod:`ccdcore.emva.spatial`).

Camera model
------------
Per pixel [m, n] (row m of M, column n of N) and frame, for an exposure t with μ_p photons per
pixel (release 3.1 sec. 2.1 linear signal model, sec. 2.2 noise model, sec. 3.1 dark current):

    charge    q = min(Poisson(η μ_p P[m, n]) + Poisson(μ_I t), μ_e.full)        (e⁻)
    electrons e = q + μ_d.off + D[m, n] + N(0, σ²_d0)                           (e⁻)
    output    y = clip(rint(K e + b), 0, 2^bits − 1)                            (DN)

* η the quantum efficiency, K the system gain (DN/e⁻), b the black offset (DN), μ_d.off a dark
  offset (e⁻, keeps the dark output well above code 0), σ_d0 the temporal dark noise (read noise,
  e⁻), μ_I the dark current (e⁻/s, Poisson: the thermal electrons have shot noise);
* the full well μ_e.full caps the charge the pixel collects (photo and thermal electrons); the
  offsets and the read noise belong to the readout and are added after it, so a full pixel
  still shows the read noise;
* PRNU map P[m, n] = 1 + r_P[m] + c_P[n] + p_P[m, n] and DSNU map D[m, n] = r_D[m] + c_D[n] +
  p_D[m, n] (e⁻), every part iid normal with its own standard deviation (``prnu_parts`` in %,
  ``dsnu_parts`` in e⁻; row, column, pixel).  The DSNU is an offset: it does not grow with t;
* rint rounds to the nearest code (ties to even): a plain ADC, no dither;
* optionally (``nonlinearity`` = a ≠ 0) the conversion is slightly nonlinear, as a real
  sensor's is: K e becomes K e·(1 + a·(1 − 8x(1 − x))), x = K e/(K μ_e.full) the fraction of
  the saturation signal -- a smooth bowl, +a at both ends and −a at half of saturation: the
  mean deviates from proportionality by ±a (a line fitted with an offset, as EMVA 1288 sec.
  6.7's LE, takes up part of it: for a = 0.5 % the LE over the used levels of the 0–70 % range
  is about ±0.1 %; the measured reference CCD shows −0.62 … +0.48 %).  The variance follows
  the squared slope of the response, so the photon-transfer points deviate from the line by
  about 2·(1 − 16x + 24x²)·a before the fit, some ±3a over 0–70 %
  (``truth["nonlinearity"]``).  A polynomial of the four basic operations, so the bytes are
  the same on every CPU; with a = 0 (the default) the frames and the truth are those of the
  linear camera, unchanged.

So μ_y = K(η μ_p P̄ + μ_I t + μ_d.off + D̄) + b and, below saturation,
σ²_y = K²(η μ_p P̄ + μ_I t + σ²_d0) + σ²_q with σ²_q = 1/12 DN² (sec. 2.2), where P̄ and D̄ are
the maps' means.  The irradiance is set so that the mean charge η μ_p + μ_I t reaches the full
well at ``saturation_at`` × the longest exposure; μ_p = Φ t.  Exposure times are whole
microseconds and photon counts are written with three decimals (as the reference generator
writes them) and simulated from the written value, so the descriptor is exact.

Truth (``truth.json``)
----------------------
``K``
    K (DN/e⁻).
``QE``
    100 η P̄ (%): the responsivity the camera shows, R = K η P̄, over K.  ``qe`` is the η drawn
    around (the two differ by the mean of the drawn PRNU map, a few 10⁻⁴).
``sigma_d``
    σ_d0 (e⁻).  The standard defines σ_d by σ²_y.dark = K² σ²_d + σ²_q with σ²_q = 1/12 DN², the
    variance of the rounding of a uniform quantiser (sec. 2.2).  This ADC rounds without dither:
    when the temporal noise it rounds spans more than about half a code, the variance of the
    rounded value is K²σ²_d0 + 1/12 up to a ripple with the level's position between two codes
    (Sheppard's correction; computed from the normal distribution: ±1.3·10⁻³ DN² for the
    defaults' K σ_d0 = 0.6 DN, 0.3 % of σ²_y.dark; ±8·10⁻³ DN² at 0.5 DN), and the DSNU spreads
    the pixels' levels over several codes (0.54 DN standard deviation), where the ripple averages
    to −3·10⁻⁵ DN².  So σ_d is the read noise itself.  The defaults put
    σ_y.dark = √(K²σ²_d0 + 1/12) = 0.67 DN above the 0.5 DN below which quantisation dominates
    (the datasheet then notes it, and floors σ²_y.dark at 0.24 DN²).  (The reference generator
    dithers by U(−½, ½) before rounding, which doubles σ²_q, so its σ_d keeps one 1/12 DN² over
    K²; this camera needs no such correction.)  The dark current's shot noise is not in σ_d:
    σ²_y.dark is taken at t → 0.
``u_I_mean``, ``u_I_var``
    μ_I (e⁻/s), what the slope of the dark mean (K μ_I) and of the dark variance (K² μ_I)
    against the exposure time measure.
``DSNU1288_row``, ``_col``, ``_pixel`` (e⁻) and ``DSNU1288``
    √s²_part of :func:`ccdcore.emva.spatial.variance_split` applied to the noiseless DSNU map
    (``variance_split(D, 0.0, 1)``; the total is √s²_y, the release 3.1 DSNU1288).
``PRNU1288_row``, ``_col``, ``_pixel`` (%) and ``PRNU1288``
    100 √s²_part / P̄ of the same split of the PRNU map P.

Why the split of the drawn patterns and not the generating standard deviations: the release
4.0 equations are unbiased for the generating variances only in expectation over draws of the
pattern.  One draw of M row offsets has a sample variance that scatters by √(2/(M − 1)) of the
generating one (about 20 % for M = 48, 10 % on a standard deviation), far more than what the
temporal noise leaves in the datasheet's value, and a real camera *is* one draw.  The split of
the noiseless map is what the definitions measure on this camera once the temporal noise is
gone; the datasheet's standard errors describe the temporal noise only.  The generating
standard deviations are recorded too (``generating``).

One more difference is the definition's, not the camera's: PRNU1288.part subtracts the dark
split from the bright split, and the bright average image holds K(η μ_p P + D), so each part of
the difference carries, besides K²(η μ_p)² s²_part(P), twice the same combination of the
cross products of P and D (zero in expectation over draws, not for one draw).  Its size relative
to the PRNU part is about 2 σ_D / (η μ_p σ_P √dof) (dof = M − 1 rows, N − 1 columns,
(M − 1)(N − 1) pixels).  Measured over 30 seeds of the defaults (64 × 48 and 128 × 96), the
difference is, in units of the datasheet's standard error, 0.5–0.7 rms (at most 1.8) for the
row and column parts, 0.1 for the pixel part and 0.3–0.4 for the release 3.1 total.
``PRNU1288_row_images``, ``_col_images``, ``_pixel_images`` and ``PRNU1288_images`` (the total)
give the definition applied to the noiseless expected bright and dark images (the split of the
one less that of the other over the signal; cross term included, temporal noise absent), so the
difference can be checked.

Files
-----
``EMVA1288descriptor.txt``
    The EMVA1288 descriptor (what a lab's measurement has; the reference implementation and
    :func:`ccdcore.session.open_session` read it): ``v``, ``n bits width height``, for each
    exposure a ``b exposure_ns photons`` line with its two images and a ``d exposure_ns`` line
    with its two, then the spatial ``b`` line with its L images and its ``d`` line with L.
    Image paths use ``\\`` as separator, as the reference generator writes them.
``images/imageNNNN.tif`` (or ``.png``)
    12-bit codes in 16-bit containers, numbered in descriptor order.
``session.toml``
    The same frames as a manifest (``ptc`` levels numbered as the descriptor's ``b`` points,
    with ``photons``; ``dark`` frames in the same order), so the folder itself opens as a session
    (``ccdcore calibrate OUT``); dark frames carry ``photons = 0`` as the descriptor's reader
    gives them, so both open as the same records and give the same figures.
``truth/dsnu.exr``, ``truth/prnu.exr``
    The maps D (e⁻) and P, float32.

Public objects
--------------
simulate
    Write the session and return the truth dictionary.
bowl(signal, a, saturation)
    The smooth nonlinearity of ``nonlinearity`` (also used by the ``healey94`` preset).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..emva.spatial import variance_split
from ..errors import CcdError
from ..io.frames import atomic_write_text
from ._common import SessionWriter
from .sensor import child_rng

__all__ = ["simulate", "DESCRIPTOR_NAME", "bowl"]

CAMERA_NAME = "EMVA 1288 simulated camera"
#: the descriptor's file name (the reference generator's)
DESCRIPTOR_NAME = "EMVA1288descriptor.txt"
_FORMATS = ("tif", "png")


def bowl(signal: np.ndarray, a: float, saturation: float) -> np.ndarray:
    """A real sensor's slight nonlinearity: ``signal``·(1 + a·(1 − 8x(1 − x))), x =
    ``signal``/``saturation`` -- +a at both ends, −a at half of ``saturation``, so the mean
    deviates from proportionality by ±a and the photon-transfer variance, which follows the
    squared slope, by 2·(1 − 16x + 24x²)·a.
    Only the four basic operations: the same bytes on every CPU."""
    x = signal / saturation
    return signal * (1.0 + a * (1.0 - 8.0 * x * (1.0 - x)))


def _check(cond: bool, name: str, problem: str) -> None:
    if not cond:
        raise CcdError(name, problem)


def _three(values: Sequence[float], name: str) -> tuple[float, float, float]:
    v = tuple(float(x) for x in values)
    _check(len(v) == 3 and all(np.isfinite(x) and x >= 0 for x in v), name,
           "give three standard deviations >= 0: (row, column, pixel)")
    return v  # type: ignore[return-value]


def _pattern(shape: tuple[int, int], stds: tuple[float, float, float], seed: int,
             name: str) -> np.ndarray:
    """row[m] + col[n] + pixel[m, n], each iid normal with its std (one stream per part)."""
    h, w = shape
    row = stds[0] * child_rng(seed, f"{name}_row").standard_normal(h)
    col = stds[1] * child_rng(seed, f"{name}_col").standard_normal(w)
    pixel = stds[2] * child_rng(seed, f"{name}_pixel").standard_normal(shape)
    return row[:, None] + col[None, :] + pixel


def _parts(split: Any, scale: float) -> dict[str, float | None]:
    """√(part variance) · scale for row, col, pixel and the total (None when not positive)."""
    out: dict[str, float | None] = {}
    for part, v in (("row", split.s2_row), ("col", split.s2_col), ("pixel", split.s2_pixel),
                    ("total", split.s2)):
        out[part] = float(np.sqrt(v)) * scale if v > 0 else None
    return out


def _micro(t: float) -> int:
    """An exposure time in whole microseconds (at least 1)."""
    return max(int(round(t * 1e6)), 1)


def _seconds(us: int) -> float:
    """The exposure as the descriptor's reader has it: nanoseconds / 1e9."""
    return float(us * 1000) / 1e9


def _checked_parts(w: int, h: int, steps: int, L: int, bits: int, K: float, qe: float,
                   sigma_d0_e: float, dark_current_e: float, full_well_e: float,
                   exposure_min: float, exposure_max: float, saturation_at: float,
                   spatial_fraction: float, dsnu_parts: Sequence[float],
                   prnu_parts: Sequence[float], image_format: str
                   ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Check :func:`simulate`'s arguments; the DSNU (e⁻) and PRNU (%) parts' standard
    deviations."""
    _check(w >= 10 and h >= 10, "size", f"{w}x{h} is too small; the spatial split needs at "
                                        "least 10x10")
    _check(int(steps) >= 3, "steps", f"need at least 3 exposure times, got {steps}")
    _check(int(L) >= 3, "L", f"a spatial set needs at least 3 frames, got {L}")
    _check(8 <= int(bits) <= 16, "bits", f"bit depth must be 8..16, got {bits}")
    _check(K > 0 and 0 < qe <= 1, "K/qe", "K must be positive and qe in (0, 1]")
    _check(sigma_d0_e >= 0 and dark_current_e >= 0 and full_well_e > 0,
           "sigma_d0_e/dark_current_e/full_well_e",
           "the noise and the dark current must be >= 0 and the full well positive")
    _check(0 < exposure_min < exposure_max, "exposure_min/exposure_max",
           "need 0 < exposure_min < exposure_max")
    _check(0 < saturation_at and 0 < spatial_fraction < 1, "saturation_at/spatial_fraction",
           "saturation_at must be positive and spatial_fraction in (0, 1)")
    _check(image_format in _FORMATS, "image_format", f"choose one of {', '.join(_FORMATS)}")
    dsnu_std = _three(dsnu_parts, "dsnu_parts")
    prnu_pc = _three(prnu_parts, "prnu_parts")
    _check(sum(prnu_pc) < 20.0, "prnu_parts", "the PRNU parts must stay small (sum < 20 %) so "
                                             "the response map stays positive")
    return dsnu_std, prnu_pc


@dataclass(frozen=True)
class _Series:
    """The exposure times (whole µs) of the temporal series and of the spatial sets, the
    saturation exposure and the photon flux Φ (photons/pixel/s)."""

    t_sat: float
    flux_p: float
    exposures_us: list[int]
    spatial_us: int

    def photons(self, us: int) -> float:
        """μ_p at ``us`` as the descriptor holds it (three decimals)."""
        return float(f"{self.flux_p * _seconds(us):.3f}")


def _series(steps: int, qe: float, dark_current_e: float, full_well_e: float,
            exposure_min: float, exposure_max: float, saturation_at: float,
            spatial_fraction: float) -> _Series:
    """Exposure times and photon flux: the mean charge reaches the full well at
    ``saturation_at`` × ``exposure_max``."""
    t_sat = saturation_at * exposure_max
    flux_e = (full_well_e - dark_current_e * t_sat) / t_sat        # η Φ, e⁻/s of signal
    _check(flux_e > 0, "dark_current_e", "the dark current alone fills the well before "
                                         "saturation_at x exposure_max")
    flux_p = flux_e / qe                                            # Φ, photons/pixel/s
    exposures_us = [_micro(t) for t in np.linspace(exposure_min, exposure_max, steps)]
    _check(len(set(exposures_us)) == steps, "steps", "exposure times closer than 1 µs")
    spatial_us = _micro(spatial_fraction * t_sat)
    return _Series(t_sat, flux_p, exposures_us, spatial_us)


@dataclass(frozen=True)
class _Camera:
    """The simulated camera (module docstring): its parameters, its DSNU map D (e⁻) and PRNU
    map P, and the frames' noise stream (shared by every frame, in capture order)."""

    shape: tuple[int, int]
    K: float
    qe: float
    sigma_d0_e: float
    dark_current_e: float
    dark_offset_e: float
    black_offset_dn: float
    full_well_e: float
    full_scale: int
    D: np.ndarray
    P: np.ndarray
    rng: np.random.Generator
    nonlinearity: float = 0.0

    def frame(self, mu_p: float, t: float) -> np.ndarray:
        """One frame of ``mu_p`` photons per pixel at exposure ``t`` (s), uint16 codes."""
        shape, P = self.shape, self.P
        charge = self.rng.poisson(self.dark_current_e * t, shape).astype(np.float64)
        if mu_p > 0:
            charge += self.rng.poisson(np.maximum(self.qe * mu_p * P, 0.0))
        np.minimum(charge, self.full_well_e, out=charge)
        e = charge + self.dark_offset_e + self.D + self.sigma_d0_e * self.rng.standard_normal(shape)
        v = e * self.K
        if self.nonlinearity:
            v = bowl(v, self.nonlinearity, self.K * self.full_well_e)
        y = np.rint(v + self.black_offset_dn)
        np.clip(y, 0, self.full_scale, out=y)
        return y.astype(np.uint16)


def _shoot(writer: SessionWriter, cam: _Camera, series: _Series, L: int, image_format: str,
           bits: int, w: int, h: int) -> list[str]:
    """Expose and write every frame in descriptor order (a bright and a dark pair at each
    exposure, then the spatial sets); the descriptor's lines."""
    lines = ["v 4.0", f"n {bits} {w} {h}"]
    count = 0
    level = 0

    def point(mu_p: float | None, us: int, n: int) -> None:
        nonlocal count, level
        t = _seconds(us)
        if mu_p is None:
            lines.append(f"d {us * 1000:.1f}")
        else:
            level += 1
            lines.append(f"b {us * 1000:.1f} {mu_p:.3f}")
        for _ in range(n):
            name = f"image{count:04d}.{image_format}"
            count += 1
            lines.append(f"i images\\{name}")
            meta: dict[str, Any] = ({"role": "dark", "photons": 0.0} if mu_p is None else
                                    {"role": "ptc", "level": level, "photons": mu_p})
            writer.add_frame(f"images/{name}", cam.frame(mu_p or 0.0, t), exposure=t, **meta)

    for us in series.exposures_us:
        point(series.photons(us), us, 2)
        point(None, us, 2)
    point(series.photons(series.spatial_us), series.spatial_us, L)
    point(None, series.spatial_us, L)
    return lines


def _image_parts(cam: _Camera, series: _Series) -> dict[str, float | None]:
    """The PRNU1288 parts (%) of the definition applied to the noiseless expected spatial
    images (module docstring)."""
    K, D = cam.K, cam.D
    t_sp = _seconds(series.spatial_us)
    dark_img = K * (cam.dark_current_e * t_sp + cam.dark_offset_e + D) + cam.black_offset_dn
    bright_img = K * cam.qe * series.photons(series.spatial_us) * cam.P + dark_img
    sb, sd = variance_split(bright_img, 0.0, 1), variance_split(dark_img, 0.0, 1)
    signal = float(bright_img.mean() - dark_img.mean())
    images = {}
    for part in ("row", "col", "pixel", "total"):
        v = sb.part(part)[0] - sd.part(part)[0]
        images[part] = 100.0 * float(np.sqrt(v)) / signal if v > 0 else None
    return images


def _truth(cam: _Camera, series: _Series, seed: int, w: int, h: int, bits: int, steps: int,
           L: int, dsnu_std: tuple[float, float, float],
           prnu_pc: tuple[float, float, float]) -> dict[str, Any]:
    """The truth dictionary (module docstring)."""
    K, qe, D, P = cam.K, cam.qe, cam.D, cam.P
    sigma_d0_e, dark_current_e = cam.sigma_d0_e, cam.dark_current_e
    P_mean = float(P.mean())
    dsnu = _parts(variance_split(D, 0.0, 1), 1.0)
    prnu = _parts(variance_split(P, 0.0, 1), 100.0 / P_mean)
    images = _image_parts(cam, series)
    t_sp = _seconds(series.spatial_us)
    sigma2_y_dark = K * K * sigma_d0_e ** 2 + 1.0 / 12.0
    photons, exposures_us, spatial_us = series.photons, series.exposures_us, series.spatial_us
    return {
        "preset": "emva1288", "seed": int(seed), "size": [w, h], "bits": bits,
        "K": float(K), "QE": 100.0 * qe * P_mean, "qe": float(qe),
        "sigma_d": float(sigma_d0_e), "sigma_y_dark": float(np.sqrt(sigma2_y_dark)),
        "u_I_mean": float(dark_current_e), "u_I_var": float(dark_current_e),
        "DSNU1288": dsnu["total"], "PRNU1288": prnu["total"],
        **{f"DSNU1288_{p}": dsnu[p] for p in ("row", "col", "pixel")},
        **{f"PRNU1288_{p}": prnu[p] for p in ("row", "col", "pixel")},
        "PRNU1288_images": images["total"],
        **{f"PRNU1288_{p}_images": images[p] for p in ("row", "col", "pixel")},
        "generating": {"dsnu_row_e": dsnu_std[0], "dsnu_col_e": dsnu_std[1],
                       "dsnu_pixel_e": dsnu_std[2], "prnu_row_percent": prnu_pc[0],
                       "prnu_col_percent": prnu_pc[1], "prnu_pixel_percent": prnu_pc[2]},
        "P_mean": P_mean, "D_mean_e": float(D.mean()),
        "dark_offset_e": float(cam.dark_offset_e), "black_offset_dn": float(cam.black_offset_dn),
        "full_well_e": float(cam.full_well_e), "full_scale": cam.full_scale,
        "photon_flux": series.flux_p, "saturation_exposure": series.t_sat,
        "exposures": [_seconds(us) for us in exposures_us],
        "photons": [photons(us) for us in exposures_us],
        "spatial": {"exposure": t_sp, "photons": photons(spatial_us), "L": L},
        "steps": steps, "L": L, "descriptor": DESCRIPTOR_NAME,
        "notes": {
            "QE": "100 qe mean(P): the camera's responsivity over K",
            "sigma_d": "read noise sigma_d0; the ADC rounds without dither, its rounding is the "
                       "standard's 1/12 DN2",
            "DSNU1288_*": "sqrt of variance_split(D, 0, 1) parts of the noiseless DSNU map, e-",
            "PRNU1288_*": "100 sqrt(variance_split(P, 0, 1) part) / mean(P), %",
            "PRNU1288_*_images": "the split of the noiseless expected bright image less that of "
                                 "the dark image over the signal, % (cross term of P and D "
                                 "included)",
            "generating": "the standard deviations the parts were drawn with"},
    }


def simulate(out_dir: str | Path, *, seed: int = 0, size: tuple[int, int] = (128, 96),
             steps: int = 16, L: int = 16, bits: int = 12, K: float = 0.1, qe: float = 0.5,
             sigma_d0_e: float = 6.0, dark_current_e: float = 1500.0,
             dark_offset_e: float = 50.0, black_offset_dn: float = 100.0,
             full_well_e: float = 35000.0, exposure_min: float = 0.001,
             exposure_max: float = 0.5, saturation_at: float = 0.85,
             spatial_fraction: float = 0.5,
             dsnu_parts: Sequence[float] = (2.0, 3.0, 4.0),
             prnu_parts: Sequence[float] = (0.4, 0.6, 1.0),
             image_format: str = "tif", nonlinearity: float = 0.0) -> dict[str, Any]:
    """Write the ``emva1288`` session into ``out_dir`` and return its truth.

    Parameters
    ----------
    out_dir
        Session folder (created).
    seed
        Seed; the same seed gives the same bytes.  The patterns and the frames' noise are
        separate streams (:func:`~ccdcore.simulate.sensor.child_rng`).
    size
        ``(width, height)`` in pixels; at least 10 × 10 (the row/column/pixel split and the
        5 × 5 high-pass filter of the spatial section need it).
    steps
        Exposure times of the temporal series (at least 3), linear from ``exposure_min`` to
        ``exposure_max``.
    L
        Frames of each spatial set (at least 3: two would make a temporal point).
    bits
        ADC bit depth, 8 to 16.
    K, qe, sigma_d0_e, dark_current_e, dark_offset_e, black_offset_dn, full_well_e
        K (DN/e⁻), η, σ_d0 (e⁻), μ_I (e⁻/s), μ_d.off (e⁻), b (DN), μ_e.full (e⁻) of the model
        (module docstring).
    exposure_min, exposure_max
        Shortest and longest exposure time, seconds (rounded to whole microseconds).
    saturation_at
        The fraction of ``exposure_max`` at which the mean charge reaches the full well (< 1:
        the last points lie beyond saturation).
    spatial_fraction
        The spatial sets' exposure as a fraction of the saturation exposure (0.5: 50 % of
        saturation, sec. 8).
    dsnu_parts
        Standard deviations of the row, column and pixel parts of the DSNU map, e⁻.
    prnu_parts
        Standard deviations of the row, column and pixel parts of the PRNU map, % of the mean.
    image_format
        ``"tif"`` or ``"png"`` (16-bit containers either way).
    nonlinearity
        a, the amplitude of the smooth deviation of the response (module docstring), a
        fraction: 0.005 is a good camera's few tenths of a percent; 0 (default) a linear camera
        with the frames and truth unchanged.  |a| below 0.1.

    Returns
    -------
    dict
        The truth written to ``truth.json`` (module docstring).
    """
    w, h = (int(size[0]), int(size[1]))
    dsnu_std, prnu_pc = _checked_parts(w, h, steps, L, bits, K, qe, sigma_d0_e, dark_current_e,
                                       full_well_e, exposure_min, exposure_max, saturation_at,
                                       spatial_fraction, dsnu_parts, prnu_parts, image_format)
    _check(abs(float(nonlinearity)) < 0.1, "nonlinearity",
           "give the amplitude as a fraction below 0.1 (0.005 = 0.5 %)")
    steps, L, bits = int(steps), int(L), int(bits)
    shape = (h, w)
    # ---- exposure times and photon counts ----------------------------------------------------
    series = _series(steps, qe, dark_current_e, full_well_e, exposure_min, exposure_max,
                     saturation_at, spatial_fraction)
    # ---- the camera's patterns ----------------------------------------------------------------
    D = _pattern(shape, dsnu_std, seed, "dsnu")                                 # e⁻
    P = 1.0 + _pattern(shape, tuple(p / 100.0 for p in prnu_pc), seed, "prnu")  # relative
    cam = _Camera(shape, K, qe, sigma_d0_e, dark_current_e, dark_offset_e, black_offset_dn,
                  full_well_e, 2 ** bits - 1, D, P, child_rng(seed, "frames"),
                  float(nonlinearity))
    # ---- frames and descriptor ----------------------------------------------------------------
    writer = SessionWriter(out_dir, camera={"name": CAMERA_NAME, "bits": bits,
                                            "layout": "mono"})
    lines = _shoot(writer, cam, series, L, image_format, bits, w, h)
    atomic_write_text(Path(out_dir) / DESCRIPTOR_NAME, "\n".join(lines) + "\n")

    writer.add_map("truth/dsnu.exr", D, name="dsnu")
    writer.add_map("truth/prnu.exr", P, name="prnu")
    # ---- truth --------------------------------------------------------------------------------
    truth = _truth(cam, series, seed, w, h, bits, steps, L, dsnu_std, prnu_pc)
    if nonlinearity:
        truth["nonlinearity"] = {
            "amplitude": float(nonlinearity), "saturation_dn": float(K * full_well_e),
            "model": "K e (1 + a (1 - 8 x (1 - x))), x = K e / (K full_well_e)",
            "note": "the other figures are those of the linear camera"}
    return writer.finish(truth, note=f"ccdcore simulate emva1288 --seed {int(seed)} "
                                     f"--size {w}x{h}\nthe same frames: {DESCRIPTOR_NAME}")
