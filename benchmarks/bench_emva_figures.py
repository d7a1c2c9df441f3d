"""The EMVA 1288 figures against the reference implementation and against truth, with run times.

The ``emva1288`` package (PyPI 1.0.2) writes exposure-time series with its own
``DatasetGenerator`` (its camera simulator: Poisson light and dark electrons, Gaussian read noise
of variance ``sigma2_dark_0`` e², a DSNU map in e⁻ and a PRNU map, system gain K DN/e⁻, full well
``u_esat``, 12-bit ADC); for each of ``--seeds`` data sets both tools compute, from the same files,
every EMVA 1288 figure (release 3.1 definitions): K, QE, σ_y.dark, σ_d, μ_p.min, μ_p.sat,
μ_e.sat, SNR_max, DR (dB), LE_min, LE_max, DSNU1288, PRNU1288; ccdcore also gives each one's
standard error and σ_d from its photon-transfer intercept (``sigma_d_ptc``).  Then the newer
figures: the dark current from the mean and from the variance (``u_I_mean``, ``u_I_var``, e⁻/s;
release 3.1 sec. 3.1), the release 4.0 row/column/pixel split of DSNU1288 and PRNU1288, and the
arrays of the spatial section's plots (spectrograms, histograms, profiles; release 3.1 sec. 8).

Truth of the generator, where the camera has it: K = ``cam.K``; QE = the mean of its spectral QE
(the generator's light is flat in photons per wavelength); σ_d = √(σ²_d0 + 1/(12K²)) e⁻ (the
generator dithers by U(−½, ½) DN before rounding, so its frames carry the quantisation variance
twice and σ_d keeps one of them: ``bench_ptc_emva.py``); DSNU1288 = the standard deviation of the
DSNU map (e⁻); PRNU1288 = 100 × that of the PRNU map over its mean (%).  μ_p.sat, μ_e.sat,
SNR_max, DR and LE have no simulated truth (they are defined by the measured series).  The dark
current is ``cam._u_i()`` (e⁻/s: the reference current scaled to the sensor's temperature; the
generator draws Poisson(μ_I t) dark electrons, uniform over the sensor).  u_I_var reads the slope
of σ²_y.dark along the series, and the generator's rounding adds to σ²_y.dark: rint(s + U) with
U ~ U(−½, ½) adds f(1 − f) for a signal at a fraction f of a code, 1/6 on average only when the
dark levels spread over many codes; as the dark level climbs with the exposure that average
moves.  The script computes the slope this alone gives for the camera (its DSNU map, offset,
read noise, gain and current; ``quantisation_bias``) and prints it as a current: the part of
u_I_var − truth that is the data's, not the estimator's (both tools share it).  The mean is
unbiased (the dither), so u_I_mean has no such part.

Truth of the row/column/pixel split.  The DSNU and PRNU maps are drawn once (``PATTERN_SEED``)
and every frame of every seed carries the same ones, so the quantity the split estimates is the
split of *that* drawn pattern, not the variances the maps were drawn with: the average dark image
is c + K·dsnu + n (n the temporal noise left, white, variance σ²_y.stack/L per pixel; the
dither makes the rounding unbiased), and the split is a fixed linear combination of the sums of
squares of its row means, column means and residual whose noise terms are removed in
expectation (up to 1/(MN) of σ²_n).  So the truth is ``variance_split(dsnu_map, 0.0, 1)`` (no
noise to remove), √part in e⁻; for PRNU the signal image K·ū_e·prnu (ū_e the mean electrons of
the bright spatial set; the DSNU cancels in bright − dark) gives 100·√part(prnu_map)/mean(prnu_map)
in %.  The bright − dark *variances* that PRNU1288 subtracts also keep the cross term
2·cov(ū_e·prnu, dsnu) of the two drawn maps (the maps are independent, but a finite draw of them
correlates by chance: a column part of 0.4 % shifts by about 1e-3 of itself, and a camera
without a PRNU column part but with a DSNU one gets a PRNU column part of a few 1e-3 %); the
``exact`` column (x) is the PRNU truth with it (``split(ū_e·prnu + dsnu) − split(dsnu)``, from
the generator's own mean-electron map of the bright spatial set), and the z-score against it is
the one that tests the errors.  A part the drawn map does not have (a camera without row DSNU)
splits to ±(the pixel part's leakage, a few 1e-4 of the pixel variance), printed as its signed
variance; the truth column is its root (0 when negative).  The ``(c-t)/err`` columns use
ccdcore's stated errors; over seeds only the temporal noise changes (the pattern is the same).
``--scatter N`` draws N more dark spatial sets from the camera (its ``Camera``, set up as the
generator does, L dark frames at the spatial exposure) and gives the mean and spread of the
DSNU parts' z-scores in DN² with K known: more than three seeds' worth of the errors' test.

Cameras (``--camera``):

* ``clean`` (the default) simulates a DSNU of 4 e⁻ and a PRNU of 1 % (pixel parts only), a dark
  signal of 50 e⁻ (no dark electron is clipped at 0), a full well of 60000 e⁻ (above the ADC
  range: the series ends in ADC saturation) and the generator's dark current (15 e⁻/s);
* ``defaults`` keeps the generator's own camera (no DSNU nor PRNU, full well 15000 e⁻ = 1500 DN:
  the package's saturation search then stops on the plateau after saturation, and both tools
  report the same, noted, figures);
* ``split``: as ``clean`` with a dark current of 600 e⁻/s (300 e⁻ at the longest exposure,
  0.5 s) and maps with row, column and pixel parts: DSNU 1, 2, 3 e⁻ and PRNU 0.2, 0.4, 0.8 %
  (standard deviations drawn with);
* ``faint``: the package's failure modes: a dark current of 0.004 e⁻/s (2e-3 e⁻ at 0.5 s, below
  what the series resolves: the package returns a number of either sign for u_I_mean and NaN
  for a falling variance, ccdcore ``None`` with a bound), a DSNU without row part (1.5 e⁻ column,
  3 e⁻ pixel) and a PRNU without column part (0.3 % row, 0.8 % pixel): the package returns NaN for
  a part whose variance comes out negative and a number for one that comes out positive, ccdcore
  ``None`` with a bound unless the variance is above zero by two errors (the PRNU column part
  can be: the cross term above).

Plot arrays, same files (L = L_dark, as the generator writes): the package's are those its
plotting classes draw (``routines.FFT1288`` and ``GetFrecs`` as ``PlotHorizontalSpectrogramDSNU``
etc. call them, ``Results1288.histogram_DSNU/_PRNU(_accumulated)``, ``ProfileBase``'s profiles).
Spectrograms: the DSNU ones must be equal (both √power in DN of the dark average); the PRNU ones
are ours = 100 · package / √μ (μ the mean signal: the package plots √(power/μ), √DN, ours
100·√power/μ, %), checked on the data, and on analytic images (white relative pattern of 1 %:
ours at 1 % whatever the signal, the package's at 0.01·√μ, moving with the exposure; a cosine of
period 8 pixels: ours at 0.125 cycles per pixel, the package's ``GetFrecs`` at k/(2(n/2 + 1))).
Parseval: the rms of our PRNU spectrogram is 100·std(signal image)/μ, in the unit of the
PRNU1288 line drawn on it.  Histograms (DSNU: ours in e⁻, the package's in DN; PRNU: ours in %,
the package's in DN; the package bins integer sums, ours bins the dark average in whole steps of
its 1/L_dark DN grid and the PRNU image in 256 equal bins): compared in DN, as distributions: the
standard deviation each histogram gives (bin centres) against that of the image, the bins and
the empty ones inside the range, the model's total against the pixel count; each accumulated
histogram against the image's own fraction at its edges (ours about the mean, the package's
about its centre int(mean), the truncated mean of the integer sums), and the percentage of
pixels deviating by 1 and 3 σ about the mean and about int(mean).  Profiles: mean, minimum,
maximum and middle line per column and per row, bright − dark and dark (equal when L = L_dark;
above 1024 columns ours are reduced to 1024 blocks, and compared with the package's reduced the
same way).  One more descriptor per first seed keeps only the first L/2 frames of the dark
spatial set (L_dark = L/2, same images): the package's plots then divide the dark sum by the
bright L; ours are compared with the temporal points at the spatial exposure.

Run times, same files, in one process, ``--repeat`` times each after a warm-up round,
alternated: emva1288 (parse, load, ``Data1288``, every figure of ``Results1288`` including
u_I_mean, u_I_var and the six split parts, and the plot arrays above: the work ``emva_figures``
does now); ccdcore (``open_session`` on the descriptor, ``emva_figures`` without photon transfer:
the same work); ccdcore + photon transfer (``emva_figures`` computing ``sigma_d_ptc`` too, as
``calibrate`` has it).  The new parts are not separable from ``emva_figures`` by an option, so
they are timed alone on the first seed's data: ccdcore ``dark_current`` (from the dark points),
``variance_split`` ×2 + ``nonuniformity_split`` (from the average images) and
``spatial_plots``; the package's ``u_I_mean`` and ``u_I_var``, ``Data1288._get_spatial_data``
×2 (from the sum and pseudo-variance images; it also makes the release 3.1 spatial statistics)
+ the six split properties (each refits K, as the package does), and its histograms (4),
spectrograms (4) and profiles.  Peak RSS: each tool once in a fresh child
process (the spatial parts from their inputs saved by a child: the increment over the inputs).
The data are generated once, in a child process, into
``benchmarks/_data/emva_figures_<camera>_<size>_<seed>`` (reused when the parameters match).

Run by hand (not part of the tests)::

    .venv/bin/python benchmarks/bench_emva_figures.py        # 640x480, 20 steps, L = 16, 3 seeds
    .venv/bin/python benchmarks/bench_emva_figures.py --camera split --scatter 40
    .venv/bin/python benchmarks/bench_emva_figures.py --camera faint --scatter 20
    .venv/bin/python benchmarks/bench_emva_figures.py --camera split --size 1280x1024 --seeds 1288
    .venv/bin/python benchmarks/bench_emva_figures.py --camera defaults --seeds 1288
    .venv/bin/python benchmarks/bench_emva_figures.py --size 320x240 --repeat 3
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import shutil
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

# emva1288 1.0.2 calls np.asfarray, removed in NumPy 2 (docs/notes.md)
np.asfarray = lambda a, dtype=np.float64: np.asarray(a, dtype=dtype)  # noqa: E731

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

import _report  # noqa: E402  (benchmarks/_report.py, beside this script)

#: the figures compared, Results1288's attribute names (DR_dB is a method there)
FIGURES = ("K", "QE", "sigma_y_dark", "sigma_d", "u_p_min", "u_p_sat", "u_e_sat", "SNR_max",
           "DR_dB", "LE_min", "LE_max", "DSNU1288", "PRNU1288")
UNITS = {"K": "DN/e", "QE": "%", "sigma_y_dark": "DN", "sigma_d": "e", "u_p_min": "p",
         "u_p_sat": "p", "u_e_sat": "e", "SNR_max": "", "DR_dB": "dB", "LE_min": "%",
         "LE_max": "%", "DSNU1288": "e", "PRNU1288": "%"}
PARTS = ("row", "col", "pixel")
SPLIT = tuple(f"{w}_{p}" for w in ("DSNU1288", "PRNU1288") for p in PARTS)
#: the newer figures: dark current and the release 4.0 split (Results1288's names)
NEW_FIGURES = ("u_I_mean", "u_I_var") + SPLIT
NEW_UNITS = {"u_I_mean": "e/s", "u_I_var": "e/s", **{k: "e" if k.startswith("DSNU") else "%"
                                                     for k in SPLIT}}
PATTERN_SEED = 12880
CAMERAS = ("clean", "defaults", "split", "faint")
#: the generator's camera at 22 °C runs at half its reference dark current (30 °C, doubling 8 °C)
_DARK_CURRENT_REF = {"split": 1200.0, "faint": 0.008}
#: the standard deviations the split cameras' maps are drawn with (row, column, pixel):
#: DSNU in e⁻, PRNU relative
_PARTS_DRAWN = {"split": ((1.0, 2.0, 3.0), (0.002, 0.004, 0.008)),
                "faint": ((0.0, 1.5, 3.0), (0.003, 0.0, 0.008))}
#: the first seed of the extra dark sets of ``--scatter``
SCATTER_SEED = 100000
#: the truth's layout (a change makes make_data write the data again)
TRUTH_VERSION = 2


def draw_camera(camera: str, height: int, width: int
                ) -> tuple[dict, np.ndarray | None, np.ndarray | None]:
    """The generator's camera keywords and the DSNU (e⁻) and PRNU (relative) maps drawn for it
    with ``PATTERN_SEED`` (``None`` where the camera has none)."""
    rng = np.random.default_rng(PATTERN_SEED)
    if camera == "clean":
        dsnu = rng.normal(0.0, 4.0, (height, width))
        prnu = 1.0 + rng.normal(0.0, 0.01, (height, width))
        return dict(dsnu=dsnu, prnu=prnu, u_esat=60000.0, dark_signal_0=50.0), dsnu, prnu
    if camera in _PARTS_DRAWN:
        maps = []
        for sds in _PARTS_DRAWN[camera]:
            m = np.zeros((height, width))
            for sd, shape in zip(sds, ((height, 1), (1, width), (height, width))):
                draw = rng.normal(0.0, 1.0, shape)   # drawn even at sd 0: the same stream
                m = m + sd * draw
            maps.append(m)
        dsnu, prnu = maps[0], 1.0 + maps[1]
        return (dict(dsnu=dsnu, prnu=prnu, u_esat=60000.0, dark_signal_0=50.0,
                     dark_current_ref=_DARK_CURRENT_REF[camera]), dsnu, prnu)
    return {}, None, None


def drawn_parts(camera: str) -> dict[str, float]:
    """The standard deviations each part of the camera's maps is drawn with (e⁻; relative)."""
    if camera in _PARTS_DRAWN:
        sds = _PARTS_DRAWN[camera]
    elif camera == "clean":
        sds = ((0.0, 0.0, 4.0), (0.0, 0.0, 0.01))
    else:
        sds = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    return {f"{w}_{p}": sd for w, row in zip(("DSNU1288", "PRNU1288"), sds)
            for p, sd in zip(PARTS, row)}


def split_truth(dsnu: np.ndarray, prnu: np.ndarray, u_e: np.ndarray | None) -> dict:
    """The split of the noiseless drawn maps (module docstring): DSNU parts in e⁻, PRNU parts
    in %, the signed variances (e², and relative² for PRNU), and the PRNU parts with the cross
    term of the two maps (``PRNU_exact``, from the generator's mean-electron map ``u_e``)."""
    from ccdcore.emva.spatial import variance_split

    vd = variance_split(dsnu, 0.0, 1)
    vp = variance_split(prnu, 0.0, 1)
    mean_p = float(np.mean(prnu))
    out: dict = {"values": {}, "variances": {}, "PRNU_exact": {}}
    for part in PARTS:
        sd, _ = vd.part(part)
        sp, _ = vp.part(part)
        out["variances"][f"DSNU1288_{part}"] = sd
        out["variances"][f"PRNU1288_{part}"] = sp
        out["values"][f"DSNU1288_{part}"] = math.sqrt(max(sd, 0.0))
        out["values"][f"PRNU1288_{part}"] = 100.0 * math.sqrt(max(sp, 0.0)) / mean_p
    if u_e is not None:
        vb = variance_split(u_e + dsnu, 0.0, 1)
        for part in PARTS:
            diff = vb.part(part)[0] - vd.part(part)[0]
            out["PRNU_exact"][f"PRNU1288_{part}"] = (100.0 * math.sqrt(max(diff, 0.0))
                                                     / float(np.mean(u_e)))
    return out


def make_data(folder: Path, width: int, height: int, bits: int, steps: int, L: int, seed: int,
              camera: str) -> dict:
    """Write one data set (once) and return the generator's truth."""
    from emva1288.camera.dataset_generator import DatasetGenerator

    stamp = json.dumps([width, height, bits, steps, L, seed, camera, TRUTH_VERSION])
    truth_file = folder / "truth.json"
    if truth_file.exists() and (folder / ".stamp").read_text() == stamp:
        return json.loads(truth_file.read_text())
    if folder.exists():
        shutil.rmtree(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    kwargs, dsnu, prnu = draw_camera(camera, height, width)
    t0 = time.perf_counter()
    gen = DatasetGenerator(steps=steps, L=L, image_format="tif", outdir=str(folder),
                           width=width, height=height, bit_depth=bits, seed=seed, **kwargs)
    elapsed = time.perf_counter() - t0
    cam = gen.cam
    # the mean electrons of the bright spatial set (PRNU applied), for the exact PRNU truth
    texp, radiances = next(iter(gen.points["spatial"].items()))
    cam.exposure = texp
    u_e = np.asarray(cam._u_e(radiances[0]), np.float64)
    maps = (np.zeros((height, width)) if dsnu is None else dsnu,
            np.ones((height, width)) if prnu is None else prnu)
    truth = {"K": float(cam.K), "QE": 100.0 * float(cam.qe.qe.mean()),
             "sigma_d": math.sqrt(cam._sigma2_dark_0 + 1.0 / (12.0 * cam.K ** 2)),
             "DSNU1288": None if dsnu is None else float(np.std(dsnu, ddof=1)),
             "PRNU1288": None if prnu is None else 100.0 * float(np.std(prnu, ddof=1)
                                                                 / np.mean(prnu)),
             "u_I": float(cam._u_i()),
             "split": split_truth(maps[0], maps[1], u_e),
             "spatial_exposure_s": float(texp) / 1e9,
             "descriptor": str(Path(gen.descriptor_path).relative_to(folder)),
             "generation_s": elapsed}
    truth_file.write_text(json.dumps(truth, indent=2))
    (folder / ".stamp").write_text(stamp)
    return truth


def short_dark_descriptor(descriptor: Path, L_dark: int) -> Path:
    """A copy of ``descriptor`` (beside it, same images) whose dark spatial set keeps its first
    ``L_dark`` frames."""
    out, block, kind = [], [], None

    def flush() -> None:
        if kind == "d" and len(block) > 2:
            out.extend(block[:L_dark])
        else:
            out.extend(block)

    for line in descriptor.read_text().splitlines():
        if line.startswith("i "):
            block.append(line)
            continue
        flush()
        block = []
        kind = line.split()[0] if line.strip() else None
        out.append(line)
    flush()
    path = descriptor.with_name(f"{descriptor.stem}_dark{L_dark}.txt")
    path.write_text("\n".join(out) + "\n")
    return path


# --------------------------------------------------------------------------------------------
# the tools
# --------------------------------------------------------------------------------------------
def _pkg_profiles(image: np.ndarray, vertical: bool) -> dict:
    """``ProfileBase._get_image_profiles`` (the package's profile plots) of one image."""
    from emva1288.process.plotting import ProfileBase

    shim = SimpleNamespace(vertical=vertical)
    shim._get_x_y = lambda p: ProfileBase._get_x_y(shim, p)
    d = ProfileBase._get_image_profiles(shim, image)
    return {k: np.asarray(v[1], np.float64) for k, v in d.items()}


def emva_plot_arrays(res) -> dict:
    """The arrays the package's spatial plots draw (``plotting.py``), from a ``Results1288``."""
    from emva1288.process import routines

    sp = res.spatial
    L = sp["L"]
    signal = (sp["sum"] - sp["sum_dark"]) / L          # PlotHorizontalSpectrogramPRNU
    mu = float(np.mean(signal))
    spectra = {}
    for rotate, name in ((False, "horizontal"), (True, "vertical")):
        s = routines.FFT1288(sp["sum_dark"], rotate=rotate, n=L)
        spectra[f"DSNU_{name}"] = {"f": routines.GetFrecs(s), "amplitude": np.sqrt(s)}
        s = routines.FFT1288(signal, rotate=rotate) / mu
        spectra[f"PRNU_{name}"] = {"f": routines.GetFrecs(s), "amplitude": np.sqrt(s)}
    bimg = (sp["sum"] - sp["sum_dark"]) / L            # ProfileBase.plot
    dimg = sp["sum_dark"] / L
    profiles = {f"{what}_{name}": _pkg_profiles(img, vertical)
                for what, img in (("bright", bimg), ("dark", dimg))
                for vertical, name in ((False, "horizontal"), (True, "vertical"))}
    return {"spectrograms": spectra, "signal_mean": mu,
            "histograms": {"DSNU": res.histogram_DSNU, "PRNU": res.histogram_PRNU},
            "accumulated": {"DSNU": res.histogram_DSNU_accumulated,
                            "PRNU": res.histogram_PRNU_accumulated},
            "profiles": profiles}


def run_emva(descriptor: Path) -> dict:
    from emva1288.process import Data1288, LoadImageData, ParseEmvaDescriptorFile, Results1288

    t0 = time.perf_counter()
    parser = ParseEmvaDescriptorFile(str(descriptor))
    res = Results1288(Data1288(LoadImageData(parser.images).data).data)
    with np.errstate(invalid="ignore"):
        out = {name: float(getattr(res, name)) for name in FIGURES + NEW_FIGURES
               if name != "DR_dB"}
        out["DR_dB"] = float(res.DR_dB())
    plots = emva_plot_arrays(res)
    out["seconds"] = time.perf_counter() - t0
    out["index_u_ysat"] = int(res.index_u_ysat)
    out["plots"] = plots
    out["res"] = res
    return out


def run_ccdcore(descriptor: Path, with_ptc: bool) -> dict:
    from ccdcore.emva.datasheet import emva_figures
    from ccdcore.session import open_session

    t0 = time.perf_counter()
    f = emva_figures(open_session(descriptor), with_ptc=with_ptc)
    elapsed = time.perf_counter() - t0
    out = {name: getattr(f, name) for name in FIGURES}
    out.update({f"{name}_err": getattr(f, f"{name}_err", None) for name in FIGURES})
    new = dict.fromkeys(k + e for k in NEW_FIGURES for e in ("", "_err"))
    if f.dark_current is not None:
        new.update(f.dark_current.figures())
        new["u_I_mean_bound"] = f.dark_current.u_I_mean_bound
        new["u_I_var_bound"] = f.dark_current.u_I_var_bound
    if f.split is not None:
        new.update(f.split.figures())
        new.update({f"{k}_bound": v for k, v in f.split.bounds})
    out.update(new)
    out.update(sigma_d_ptc=f.sigma_d_ptc, sigma_d_ptc_err=f.sigma_d_ptc_err,
               index_u_ysat=f.index_u_ysat, notes=list(f.notes), seconds=elapsed, fig=f)
    return out


# --------------------------------------------------------------------------------------------
# the new parts alone, from the spatial sets (timed and measured on their own)
# --------------------------------------------------------------------------------------------
def prepare_spatial(descriptor: Path, out: Path) -> None:
    """Save the inputs of the spatial parts of both tools for one data set: ccdcore's average
    images, their temporal variances and K; the package's sum and pseudo-variance images and its
    temporal data (``Results1288`` needs them for K)."""
    from emva1288.process import Data1288, LoadImageData, ParseEmvaDescriptorFile

    from ccdcore.emva.datasheet import emva_figures
    from ccdcore.session import open_session

    f = emva_figures(open_session(descriptor), with_ptc=False)
    loaded = LoadImageData(ParseEmvaDescriptorFile(str(descriptor)).images).data
    texp = next(iter(loaded["spatial"]))
    sets = loaded["spatial"][texp]
    dark, bright = sets[0.0], sets[max(sets)]
    temporal = Data1288(loaded).data["temporal"]
    np.savez(out, b_avg=f.spatial.image, d_avg=f.spatial_dark.image,
             s2b=f.spatial.s2_stack, s2d=f.spatial_dark.s2_stack, L=f.spatial.L,
             L_dark=f.spatial_dark.L, K=f.K, K_err=f.K_err, DSNU1288=f.DSNU1288,
             PRNU1288=f.PRNU1288, sum=bright["sum"], pvar=bright["pvar"],
             sum_dark=dark["sum"], pvar_dark=dark["pvar"], L_pkg=bright["L"],
             L_dark_pkg=dark["L"], texp=texp, u_p=max(sets),
             dark_t=[d.exposure for d in f.dark_points], dark_u=[d.u_y_dark for d in f.dark_points],
             dark_u_err=[d.u_y_dark_err for d in f.dark_points],
             dark_s2=[d.s2_y_dark for d in f.dark_points],
             dark_s2_err=[d.s2_y_dark_err for d in f.dark_points],
             **{f"t_{k}": np.asarray(v) for k, v in temporal.items()})


def load_spatial(path: Path) -> dict:
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def ours_split(inp: dict):
    from ccdcore.emva.spatial import nonuniformity_split, variance_split

    return nonuniformity_split(variance_split(inp["b_avg"], float(inp["s2b"]), int(inp["L"])),
                               variance_split(inp["d_avg"], float(inp["s2d"]),
                                              int(inp["L_dark"])),
                               float(inp["K"]), float(inp["K_err"]))


def ours_dark(inp: dict):
    from ccdcore.emva.dark import dark_current

    return dark_current(list(inp["dark_t"]), inp["dark_u"], inp["dark_u_err"], inp["dark_s2"],
                        inp["dark_s2_err"], float(inp["K"]), float(inp["K_err"]))


def pkg_dark(res) -> tuple[float, float]:
    with np.errstate(invalid="ignore"):
        return float(res.u_I_mean), float(res.u_I_var)


def ours_plots(inp: dict):
    from ccdcore.emva.spatial import spatial_plots

    return spatial_plots(inp["b_avg"], inp["d_avg"], L=int(inp["L"]), L_dark=int(inp["L_dark"]),
                         s2_stack=float(inp["s2b"]), s2_stack_dark=float(inp["s2d"]),
                         K=float(inp["K"]), DSNU1288=float(inp["DSNU1288"]),
                         PRNU1288=float(inp["PRNU1288"]))


def pkg_split(inp: dict):
    """``Data1288._get_spatial_data`` of both sets and the six split properties."""
    from emva1288.process import Data1288, Results1288

    M, N = inp["sum"].shape
    shim = SimpleNamespace(rows=M, cols=N)
    sp = {"texp": float(inp["texp"]), "u_p": float(inp["u_p"])}
    sp.update(Data1288._get_spatial_data(shim, {"sum": inp["sum_dark"],
                                                "pvar": inp["pvar_dark"],
                                                "L": int(inp["L_dark_pkg"])}, postfix="_dark"))
    sp.update(Data1288._get_spatial_data(shim, {"sum": inp["sum"], "pvar": inp["pvar"],
                                                "L": int(inp["L_pkg"])}))
    temporal = {k[2:]: inp[k] for k in inp if k.startswith("t_")}
    res = Results1288({"temporal": temporal, "spatial": sp}, loglevel=logging.WARNING)
    with np.errstate(invalid="ignore"):
        vals = [float(getattr(res, k)) for k in SPLIT]
    return res, vals


def pkg_plots(res) -> dict:
    return emva_plot_arrays(res)


def child(tool: str, descriptor: Path) -> None:
    """Run one tool once in this (fresh) process and print its time and peak RSS as JSON."""
    if tool.endswith("-spatial"):
        inp = load_spatial(descriptor)
        base = _report.max_rss_mb()
        t0 = time.perf_counter()
        if tool == "ccdcore-spatial":
            ours_dark(inp)
            ours_split(inp)
            ours_plots(inp)
        else:
            res, _ = pkg_split(inp)
            pkg_dark(res)
            pkg_plots(res)
        print(json.dumps({"seconds": time.perf_counter() - t0,
                          "peak_rss_mb": _report.max_rss_mb(), "base_rss_mb": base}))
        return
    base = _report.max_rss_mb()
    if tool == "emva1288":
        out = run_emva(descriptor)
    else:
        out = run_ccdcore(descriptor, with_ptc=tool == "ccdcore+ptc")
    print(json.dumps({"seconds": out["seconds"], "peak_rss_mb": _report.max_rss_mb(),
                      "base_rss_mb": base}))


# --------------------------------------------------------------------------------------------
# comparisons of the new figures and of the plot arrays
# --------------------------------------------------------------------------------------------
def _num(v: float | None, fmt: str = ".6g") -> str:
    return "–" if v is None or not math.isfinite(v) else format(v, fmt)


def _finite(v) -> bool:
    return v is not None and math.isfinite(v)


def new_truth(truth: dict, name: str) -> float | None:
    if name in ("u_I_mean", "u_I_var"):
        return truth["u_I"]
    return truth["split"]["values"][name]


def new_figure_rows(emva: dict, ours: dict, truth: dict) -> list[dict]:
    """One row per new figure: truth (and the exact PRNU truth), the package's value, ours with
    its error or bound, the relative difference and the z-scores against truth."""
    exact = truth["split"]["PRNU_exact"]
    rows = []
    for name in NEW_FIGURES:
        e, o, err = emva[name], ours[name], ours[f"{name}_err"]
        bound = ours.get(f"{name}_bound")
        t = new_truth(truth, name)
        x = exact.get(name)
        row = {"name": name, "truth": t, "exact": x, "emva": e, "ours": o, "err": err,
               "bound": bound, "rel": None, "z": None, "z_exact": None, "in_bound": None,
               "in_bound_exact": None}
        if _finite(o) and _finite(e) and e != 0:
            row["rel"] = abs(o - e) / abs(e)
        if _finite(o) and _finite(err) and err > 0:
            row["z"] = (o - t) / err
            if x is not None:
                row["z_exact"] = (o - x) / err
        if o is None and bound is not None:
            row["in_bound"] = t <= bound
            if x is not None:
                row["in_bound_exact"] = x <= bound
        rows.append(row)
    return rows


def _z_or_bound(z: float | None, in_bound: bool | None) -> str:
    if z is not None:
        return _num(z, "+.2f")
    return {True: "< bound", False: "> BOUND", None: "–"}[in_bound]


def print_new_rows(rows: list[dict], truth: dict, camera: str) -> None:
    print(f"{'new figure':<16}{'unit':<5}{'truth':>10}{'exact':>11}{'emva1288':>13}"
          f"{'ccdcore':>26}{'|c-e|/|e|':>11}{'(c-t)/err':>11}{'(c-x)/err':>11}")
    for r in rows:
        if r["ours"] is not None:
            pm = _num(r["ours"]) + (f" ± {r['err']:.2g}" if _finite(r["err"]) else "")
        else:
            pm = "None" + (f" (< {r['bound']:.3g})" if r["bound"] is not None else "")
        e = r["emva"]
        zx = "" if r["exact"] is None else _z_or_bound(r["z_exact"], r["in_bound_exact"])
        print(f"{r['name']:<16}{NEW_UNITS[r['name']]:<5}{_num(r['truth'], '.5g'):>10}"
              f"{_num(r['exact'], '.5g'):>11}"
              f"{('nan' if not _finite(e) else format(e, '.6g')):>13}{pm:>26}"
              f"{_num(r['rel'], '.1e'):>11}{_z_or_bound(r['z'], r['in_bound']):>11}{zx:>11}")
    var = truth["split"]["variances"]
    drawn = drawn_parts(camera)
    zero = [k for k in SPLIT if drawn[k] == 0.0]
    if zero:
        print("  drawn without " + ", ".join(zero) + " parts; the split of the drawn maps "
              "there: " + ", ".join(f"{var[k]:+.2g} {'e²' if k.startswith('DSNU') else 'rel²'}"
                                    for k in zero)
              + " (the pixel part's leakage; the truth column is its root, 0 if negative)")
    print("  exact (x): the PRNU parts with the cross term 2 cov(u_e prnu, dsnu) of the drawn "
          "maps, which bright - dark variances keep")


def _one_sided_rms(amp: np.ndarray, n: int) -> float:
    """The rms over all frequencies of a spectrogram given for 0 … n/2 (Parseval: the standard
    deviation of the image)."""
    p = np.asarray(amp, np.float64) ** 2
    w = np.full(p.size, 2.0)
    w[0] = 1.0
    if n % 2 == 0:
        w[-1] = 1.0
    return math.sqrt(float(np.sum(w * p)) / n)


def _hist_sd(lower: np.ndarray, count: np.ndarray, offset: float) -> float:
    c = np.asarray(lower, np.float64) + offset
    n = float(np.sum(count))
    m = float(np.sum(count * c)) / n
    return math.sqrt(float(np.sum(count * (c - m) ** 2)) / n)


def _max_rel(a: np.ndarray, b: np.ndarray) -> float:
    """max |a/b − 1| over every frequency, DC included (where b is not 0)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        return math.inf
    nz = b != 0
    return float(np.max(np.abs(a[nz] / b[nz] - 1.0))) if np.all(a[~nz] == 0) else math.inf


def _reduce(x: np.ndarray, points: int, how: str) -> np.ndarray:
    """The package's per-column profile reduced as ours is (blocks of neighbouring columns)."""
    n = x.size
    if n <= points:
        return x
    edges = np.linspace(0, n, points + 1).astype(np.int64)
    fn = {"mean": np.mean, "min": np.min, "max": np.max, "mid": np.mean}[how]
    return np.array([fn(x[a:b]) for a, b in zip(edges[:-1], edges[1:])])


def histogram_checks(kind: str, e_plots: dict, o_sp: dict, values_dn: np.ndarray,
                     unit_dn: float, scale_pkg: float, centre_pkg: float) -> dict:
    """The distribution each tool's histograms give, in DN, against the image's (``values_dn``):
    standard deviation from the bins, P(|dev| ≥ kσ) from the accumulated histograms, the model's
    total over the pixel count, the bin width. ``unit_dn`` turns ours into DN, ``scale_pkg`` is
    the package's integer scale (DN = sum units / scale), ``centre_pkg`` its accumulated
    histogram's centre (DN)."""
    v = values_dn.ravel()
    sd = float(np.std(v))
    dev = np.abs(v - float(np.mean(v)))
    oh, eh = o_sp["histograms"][kind], e_plots["histograms"][kind]
    ox, oc = np.asarray(oh["x"]) * unit_dn, np.asarray(oh["count"])
    o_w = ox[1] - ox[0]
    ex, ec = np.asarray(eh["bins"], np.float64), np.asarray(eh["values"])
    W = round((ex[1] - ex[0]) * scale_pkg)
    def empty(count: np.ndarray) -> int:
        nz = np.flatnonzero(count)
        return int(np.sum(count[nz[0]:nz[-1] + 1] == 0))

    out = {"sd_image": sd, "sd_ours": _hist_sd(ox, oc, o_w / 2.0),
           "bins_ours": (len(oc), empty(oc)), "bins_pkg": (len(ec), empty(ec)),
           "sd_pkg": _hist_sd(ex, ec, (W - 1) / (2.0 * scale_pkg)),
           "width_ours": o_w, "width_pkg": W / scale_pkg,
           "model_ours": float(np.sum(oh["model"])) / v.size,
           "model_pkg": float(np.sum(eh["model"])) / v.size}
    oa, ea = o_sp["accumulated"][kind], e_plots["accumulated"][kind]
    oax, oap = np.asarray(oa["x"]) * unit_dn, np.asarray(oa["percent"])
    eax, eap = np.asarray(ea["bins"], np.float64), np.asarray(ea["values"], np.float64)
    # every accumulated value against the image's own fraction at that deviation (true mean)
    exact_o = np.array([100.0 * np.mean(dev >= x - 1e-9 * sd) for x in oax])
    dev_c = np.abs(v - centre_pkg)
    exact_ec = np.array([100.0 * np.mean(dev_c >= x - 1e-9 * sd) for x in eax])
    out.update(acc_ours=float(np.max(np.abs(oap - exact_o))),
               acc_pkg_own_centre=float(np.max(np.abs(eap - exact_ec))),
               centre_offset_sd=(centre_pkg - float(np.mean(v))) / sd)
    for k in (1, 3):
        out[f"P{k}_mean"] = 100.0 * float(np.mean(dev >= k * sd))
        out[f"P{k}_centre"] = 100.0 * float(np.mean(dev_c >= k * sd))
    return out


def plot_checks(e_plots: dict, o_sp: dict, fig, res) -> dict:
    """Every comparison of the plot arrays of one data set (module docstring)."""
    from emva1288.process import routines

    from ccdcore.emva.spatial import high_pass

    sp = res.spatial
    L, Ld = sp["L"], sp["L_dark"]
    d_avg = sp["sum_dark"] / Ld
    b_avg = sp["sum"] / L
    signal = b_avg - d_avg
    mu = float(np.mean(signal))
    M, N = d_avg.shape
    c: dict = {"avg_images": max(float(np.max(np.abs(fig.spatial_dark.image - d_avg))),
                                 float(np.max(np.abs(fig.spatial.image - b_avg))))}
    for name, n in (("horizontal", N), ("vertical", M)):
        od = np.asarray(o_sp["spectrograms"][f"DSNU_{name}"]["amplitude"])
        ed = e_plots["spectrograms"][f"DSNU_{name}"]["amplitude"]
        c[f"dsnu_{name}"] = _max_rel(od, ed)
        op = np.asarray(o_sp["spectrograms"][f"PRNU_{name}"]["amplitude"])
        ep = e_plots["spectrograms"][f"PRNU_{name}"]["amplitude"]
        c[f"prnu_{name}"] = _max_rel(op, 100.0 * ep / math.sqrt(e_plots["signal_mean"]))
        of = np.asarray(o_sp["spectrograms"][f"PRNU_{name}"]["f"])
        ef = e_plots["spectrograms"][f"PRNU_{name}"]["f"]
        c[f"f_{name}"] = (float(of[-1]), float(ef[-1]), float(np.max(np.abs(ef[1:] / of[1:] - 1))))
        c[f"rms_dsnu_{name}"] = (_one_sided_rms(od, n), float(np.std(d_avg)))
        c[f"rms_prnu_{name}"] = (_one_sided_rms(op, n), 100.0 * float(np.std(signal)) / mu,
                                 _one_sided_rms(ep, n))
    noise = 100.0 * math.sqrt(fig.spatial.s2_stack / L + fig.spatial_dark.s2_stack / Ld) / mu
    c["prnu_expected"] = (math.hypot(fig.PRNU1288, noise), fig.PRNU1288)
    c["dsnu_expected"] = math.sqrt((fig.DSNU1288 * fig.K) ** 2 + fig.spatial_dark.s2_stack / Ld)
    # histograms, in DN
    K = fig.K
    c["hist_DSNU"] = histogram_checks(
        "DSNU", e_plots, o_sp, d_avg, K, float(Ld),
        int(np.mean(sp["sum_dark"])) / Ld)
    hp = routines.high_pass_filter(sp["sum"] - sp["sum_dark"], 5)
    hp_dn = hp["img"] / (L * hp["multiplicator"])
    c["high_pass"] = float(np.max(np.abs(high_pass(signal) - hp_dn)))
    c["hist_PRNU"] = histogram_checks(
        "PRNU", e_plots, o_sp, hp_dn, mu / 100.0, float(L * hp["multiplicator"]),
        int(np.mean(hp["img"])) / (L * hp["multiplicator"]))
    # profiles
    worst = 0.0
    for key, pk in e_plots["profiles"].items():
        ok = o_sp["profiles"][key]
        level = float(np.mean(np.abs(pk["mean"]))) or 1.0
        for how in ("mean", "min", "max", "mid"):
            ref = _reduce(pk[how], len(ok[how]), how)
            worst = max(worst, float(np.max(np.abs(np.asarray(ok[how]) - ref))) / level)
    c["profiles"] = worst
    c["profile_points"] = len(o_sp["profiles"]["bright_horizontal"]["mean"])
    return c


def analytic_spectrogram_checks() -> list[str]:
    """Spectrograms of known images: a white relative pattern at two signal levels, a cosine."""
    from emva1288.process import routines

    from ccdcore.emva.spatial import spectrogram

    rng = np.random.default_rng(PATTERN_SEED)
    M, N = 480, 640
    white = rng.normal(0.0, 0.01, (M, N))
    lines = []
    for mu in (1000.0, 4000.0):
        img = mu * (1.0 + white)
        _, amp = spectrogram(img)
        ours = 100.0 * amp / float(img.mean())
        pkg = np.sqrt(routines.FFT1288(img) / float(img.mean()))
        lines.append(f"white relative pattern of 1 % on a signal of {mu:g} DN: ours median "
                     f"{np.median(ours[1:]):.4f} %, the package's {np.median(pkg[1:]):.4f} "
                     f"(sqrt DN; 0.01 x sqrt(mu) = {0.01 * math.sqrt(mu):.4f})")
    x = np.arange(N)
    img = 100.0 + np.cos(2.0 * math.pi * x / 8.0)[None, :] * np.ones((M, 1))
    f, amp = spectrogram(img)
    pk = routines.FFT1288(img)
    pf = routines.GetFrecs(pk)
    lines.append(f"cosine of period 8 pixels along the rows ({N} columns): peak at "
                 f"{f[np.argmax(amp)]:.5f} cycles/pixel in ours, {pf[np.argmax(pk)]:.5f} in the "
                 f"package's GetFrecs (true 0.125); amplitudes equal to "
                 f"{np.max(np.abs(amp ** 2 - pk) / np.max(pk)):.1e}")
    return lines


def scatter_dark(camera: str, width: int, height: int, bits: int, L: int, texp_s: float,
                 n: int) -> dict[str, list[float]]:
    """z-scores of the dark split's parts over ``n`` more dark spatial sets of the camera: its
    ``Camera`` set up as ``DatasetGenerator`` does (black offset and gain searched), L dark frames
    at the spatial exposure; z = (s²_part − K² s²_part(dsnu map)) / stated error, in DN² (K is
    the camera's, so K's error is not in it)."""
    from ccdcore.emva.spatial import variance_split

    _, dsnu, _ = draw_camera(camera, height, width)
    truth = variance_split(np.zeros((height, width)) if dsnu is None else dsnu, 0.0, 1)
    zs: dict[str, list[float]] = {p: [] for p in PARTS}
    for i in range(n):
        cam = _generator_camera(camera, width, height, bits, SCATTER_SEED + i)
        cam.exposure = round(texp_s * 1e9, 1)
        s = q = 0.0
        for _ in range(L):
            y = cam.grab(0).astype(np.float64)
            s = s + y
            q = q + y * y
        var = (q - s * s / L) / (L - 1)
        v = variance_split(s / L, float(var.mean()), L)
        for p in PARTS:
            val, err = v.part(p)
            zs[p].append((val - cam.K ** 2 * truth.part(p)[0]) / err)
    return zs


def _generator_camera(camera: str, width: int, height: int, bits: int, seed: int):
    """The camera as ``DatasetGenerator`` sets it up (black offset and gain searched)."""
    from emva1288.camera.camera import Camera
    from emva1288.camera.dataset_generator import _get_emva_blackoffset, _get_emva_gain

    kwargs, _, _ = draw_camera(camera, height, width)
    cam = Camera(width=width, height=height, bit_depth=bits, seed=seed, **kwargs)
    cam.exposure = cam.exposure_min
    cam.blackoffset = _get_emva_blackoffset(cam)
    cam.K = _get_emva_gain(cam)
    return cam


def quantisation_bias(camera: str, width: int, height: int, bits: int, steps: int) -> float:
    """The slope (e⁻/s, as u_I_var reads it) that the generator's dithered rounding adds to
    σ²_y.dark over the exposure series: y = rint(s + U), U ~ U(−½, ½), adds f(1 − f) for a
    signal s at a fraction f of a code, 1/6 only when the dark levels spread over many codes; as
    the dark level climbs with the exposure the mean over the pixels moves (computed exactly for
    20000 of the camera's pixels: its DSNU, offset, read noise, gain and dark current, the dark
    electrons taken as normal)."""
    from scipy.stats import norm

    cam = _generator_camera(camera, width, height, bits, SCATTER_SEED)
    K, bo, mu_I = float(cam.K), float(cam.blackoffset), float(cam._u_i())
    d = np.asarray(cam.DSNU, np.float64).ravel()
    d = d[np.random.default_rng(PATTERN_SEED).choice(d.size, min(d.size, 20000), replace=False)]
    t = np.round(np.linspace(cam.exposure_min, cam.exposure_max, steps), 1) / 1e9
    u = (np.arange(16) + 0.5) / 16 - 0.5
    q = []
    for ti in t:
        m = bo + K * (cam._dark_signal_0 + d + mu_I * ti)
        sd = K * math.sqrt(cam._sigma2_dark_0 + mu_I * ti)
        k = np.arange(math.floor(m.min() - 8 * sd) - 1, math.ceil(m.max() + 8 * sd) + 2)
        p = np.zeros((m.size, k.size))
        for ui in u:
            p += (norm.cdf((k[None, :] + 0.5 - ui - m[:, None]) / sd)
                  - norm.cdf((k[None, :] - 0.5 - ui - m[:, None]) / sd))
        p /= u.size
        q.append(float(np.mean(p @ (k * k) - (p @ k) ** 2)) - sd * sd)
    return float(np.polyfit(t, q, 1)[0]) / K ** 2


def ldark_checks(descriptor: Path, L: int) -> list[str]:
    """Both tools on a copy of the descriptor whose dark spatial set has L/2 frames."""
    Ld = L // 2
    short = short_dark_descriptor(descriptor, Ld)
    emva = run_emva(short)
    ours = run_ccdcore(short, with_ptc=False)
    f, res = ours["fig"], emva["res"]
    o_sp = f.to_dict()["spatial_plots"]
    e_pl = emva["plots"]
    texp = f.spatial.exposure
    point = next(p for p in f.points if p.exposure is not None
                 and math.isclose(p.exposure, texp, rel_tol=1e-9))
    dark_level = point.u_y_dark
    sig_level = point.u_y - point.u_y_dark
    o_dark = float(np.mean(o_sp["profiles"]["dark_horizontal"]["mean"]))
    e_dark = float(np.mean(e_pl["profiles"]["dark_horizontal"]["mean"]))
    o_sig = float(np.mean(o_sp["profiles"]["bright_horizontal"]["mean"]))
    e_sig = float(np.mean(e_pl["profiles"]["bright_horizontal"]["mean"]))
    od = np.asarray(o_sp["spectrograms"]["DSNU_horizontal"]["amplitude"])[1:]
    ed = e_pl["spectrograms"]["DSNU_horizontal"]["amplitude"][1:]
    op = np.asarray(o_sp["spectrograms"]["PRNU_horizontal"]["amplitude"])[1:]
    ep = 100.0 * e_pl["spectrograms"]["PRNU_horizontal"]["amplitude"][1:] / math.sqrt(
        e_pl["signal_mean"])
    rel = [abs(ours[k] - emva[k]) / abs(emva[k]) for k in SPLIT + ("DSNU1288", "PRNU1288")
           if _finite(ours[k]) and _finite(emva[k]) and emva[k]]
    n = f.spatial.image.shape[1]
    ours_rms = _one_sided_rms(np.asarray(o_sp["spectrograms"]["PRNU_horizontal"]["amplitude"]), n)
    noise = 100.0 * math.sqrt(f.spatial.s2_stack / L + f.spatial_dark.s2_stack / Ld) / o_sig
    return [
        f"descriptor {short.name}: L = {L}, L_dark = {res.spatial['L_dark']} (same images)",
        f"dark profile level: temporal dark point at the spatial exposure {dark_level:.4f} DN; "
        f"ours {o_dark:.4f} DN, the package's {e_dark:.4f} DN (ratio {e_dark / o_dark:.4f}; "
        f"L_dark/L = {Ld / L:g})",
        f"signal profile level: temporal point mu_y - mu_y.dark {sig_level:.3f} DN; ours "
        f"{o_sig:.3f} DN, the package's {e_sig:.3f} DN (its bright sum less a dark sum of "
        f"L_dark frames, over L)",
        f"DSNU spectrogram, package / ours: median {np.median(ed / od):.4f} "
        f"(range {np.min(ed / od):.4f}–{np.max(ed / od):.4f})",
        f"PRNU spectrogram, package transformed to % / ours: median {np.median(ep / op):.3f} "
        f"(range {np.min(ep / op):.3f}–{np.max(ep / op):.3f}); ours' rms {ours_rms:.4f} % "
        f"= PRNU1288 {f.PRNU1288:.4f} % with the temporal noise left "
        f"({math.hypot(f.PRNU1288, noise):.4f} %)",
        f"the split, DSNU1288 and PRNU1288 (the package divides each set by its own L there): "
        f"largest relative difference {max(rel):.1e}"]



# --------------------------------------------------------------------------------------------
# the printed tables
# --------------------------------------------------------------------------------------------
def _fmt_pair(v: tuple, fmt: str) -> str:
    return " / ".join(format(x, fmt) for x in v)


#: (label, cell) of the plot-array table, one column per seed
PLOT_ROWS = [
    ("average images, max |ccdcore - emva1288| (DN)", lambda c: f"{c['avg_images']:.1e}"),
    ("DSNU spectrogram H, max |ours/package - 1|", lambda c: f"{c['dsnu_horizontal']:.1e}"),
    ("DSNU spectrogram V, max |ours/package - 1|", lambda c: f"{c['dsnu_vertical']:.1e}"),
    ("PRNU spectrogram H, max |ours/(100 pkg/sqrt(mu)) - 1|",
     lambda c: f"{c['prnu_horizontal']:.1e}"),
    ("PRNU spectrogram V, max |ours/(100 pkg/sqrt(mu)) - 1|",
     lambda c: f"{c['prnu_vertical']:.1e}"),
    ("last frequency H: ours / package (cycles/px)", lambda c: _fmt_pair(c["f_horizontal"][:2],
                                                                          ".5f")),
    ("last frequency V: ours / package (cycles/px)", lambda c: _fmt_pair(c["f_vertical"][:2],
                                                                          ".5f")),
    ("frequencies, max |f_package/f_ours - 1| H / V",
     lambda c: f"{c['f_horizontal'][2]:.2e} / {c['f_vertical'][2]:.2e}"),
    ("DSNU spectrogram H rms / std(dark avg) (DN)", lambda c: _fmt_pair(c["rms_dsnu_horizontal"],
                                                                         ".5f")),
    ("  expected: sqrt(DSNU1288_DN^2 + s2_stack_dark/L_dark)",
     lambda c: f"{c['dsnu_expected']:.5f}"),
    ("PRNU spectrogram H rms: ours (%) / 100 std/mu (%)",
     lambda c: _fmt_pair(c["rms_prnu_horizontal"][:2], ".5f")),
    ("  PRNU1288 (%) with the noise left / PRNU1288 (%)", lambda c: _fmt_pair(c["prnu_expected"],
                                                                               ".5f")),
    ("  the package's rms (sqrt DN), drawn with PRNU1288 (%)",
     lambda c: f"{c['rms_prnu_horizontal'][2]:.5f}"),
    ("high-pass images, max |ours - package| (DN)", lambda c: f"{c['high_pass']:.1e}"),
    ("profiles (16 arrays), max |ours - package| / level", lambda c: f"{c['profiles']:.1e}"),
    ("  points per profile (ours)", lambda c: str(c["profile_points"])),
]


def _hist_rows(kind: str) -> list:
    h = f"hist_{kind}"
    rows = [
        (f"{kind} histogram: sd image / ours / package (DN)",
         lambda c: _fmt_pair((c[h]["sd_image"], c[h]["sd_ours"], c[h]["sd_pkg"]), ".5f")),
        ("  bin width ours / package (DN)",
         lambda c: _fmt_pair((c[h]["width_ours"], c[h]["width_pkg"]), ".4g")),
        ("  bins (empty inside the range): ours / package",
         lambda c: f"{c[h]['bins_ours'][0]} ({c[h]['bins_ours'][1]}) / "
                   f"{c[h]['bins_pkg'][0]} ({c[h]['bins_pkg'][1]})"),
        ("  model total / pixels: ours / package",
         lambda c: _fmt_pair((c[h]["model_ours"], c[h]["model_pkg"]), ".4f")),
        ("  accumulated vs the image at its edges, max |diff|",
         lambda c: f"{c[h]['acc_ours']:.0e} / {c[h]['acc_pkg_own_centre']:.0e}"),
        ("    (% points; ours about the mean / package about int(mean))", lambda c: ""),
        ("  package's centre int(mean) - mean (sd)",
         lambda c: f"{c[h]['centre_offset_sd']:+.4f}"),
    ]
    for k in (1, 3):
        rows.append((f"  % deviating >= {k} sd about the mean / int(mean)",
                     lambda c, k=k: _fmt_pair((c[h][f"P{k}_mean"], c[h][f"P{k}_centre"]),
                                              ".3f")))
    return rows


def print_plot_table(checks: dict) -> None:
    seeds = list(checks)
    rows = PLOT_ROWS + _hist_rows("DSNU") + _hist_rows("PRNU")
    width = max(len(label) for label, _ in rows) + 2
    cells = {s: [fn(checks[s]) for _, fn in rows] for s in seeds}
    colw = max(12, *(len(x) for s in seeds for x in cells[s])) + 2
    print(f"{'plot arrays, same files (L = L_dark)':<{width}}"
          + "".join(f"{'seed ' + str(s):>{colw}}" for s in seeds))
    for i, (label, _) in enumerate(rows):
        print(f"{label:<{width}}" + "".join(f"{cells[s][i]:>{colw}}" for s in seeds))


def time_spatial(inp: dict, repeat: int, warmup: int) -> dict[str, list[float]]:
    """Run times of the new parts alone, alternated (ms)."""
    res, _ = pkg_split(inp)

    def timed(fn):
        def run() -> float:
            t0 = time.perf_counter()
            fn()
            return 1e3 * (time.perf_counter() - t0)
        return run

    return _report.interleaved({
        "ccdcore dark_current": timed(lambda: ours_dark(inp)),
        "ccdcore variance_split x2 + nonuniformity_split": timed(lambda: ours_split(inp)),
        "ccdcore spatial_plots": timed(lambda: ours_plots(inp)),
        "emva1288 u_I_mean + u_I_var": timed(lambda: pkg_dark(res)),
        "emva1288 _get_spatial_data x2 + 6 split properties": timed(lambda: pkg_split(inp)),
        "emva1288 histograms + spectrograms + profiles": timed(lambda: pkg_plots(res))},
        repeat=repeat, warmup=warmup)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", choices=["emva1288", "ccdcore", "ccdcore+ptc", "ccdcore-spatial",
                                        "emva1288-spatial", "prepare", "camera"],
                    help=argparse.SUPPRESS)
    ap.add_argument("--texp", type=float, help=argparse.SUPPRESS)
    ap.add_argument("--make-data", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--descriptor", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--size", default="640x480", help="WxH (default 640x480)")
    ap.add_argument("--bits", type=int, default=12)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--spatial", type=int, default=16, help="images of the spatial set (L)")
    ap.add_argument("--seeds", default="1288,1289,1290",
                    help="generator seeds, comma-separated (default 1288,1289,1290)")
    ap.add_argument("--camera", choices=CAMERAS, default="clean",
                    help="the simulated camera (module docstring; default clean)")
    ap.add_argument("--repeat", type=int, default=5,
                    help="timed runs per tool and seed, alternated (default 5)")
    ap.add_argument("--warmup", type=int, default=1, help="untimed rounds first (default 1)")
    ap.add_argument("--scatter", type=int, default=0,
                    help="more dark spatial sets of the camera for the z-scores of the DSNU "
                         "parts (module docstring; default 0)")
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    seeds = [int(s) for s in args.seeds.split(",")]

    def folder_of(seed: int) -> Path:
        return HERE / "_data" / (f"emva_figures_{args.camera}_{width}x{height}_{args.bits}b_"
                                 f"{args.steps}_{args.spatial}_{seed}")

    if args.make_data:
        truth = make_data(folder_of(args.seed), width, height, args.bits, args.steps,
                          args.spatial, args.seed, args.camera)
        print(json.dumps(truth))
        return
    if args.child == "camera":   # the generator's camera holds a QE cube of H x W x 100 floats
        out = {"quantisation": quantisation_bias(args.camera, width, height, args.bits,
                                                 args.steps)}
        if args.scatter:
            out["scatter"] = scatter_dark(args.camera, width, height, args.bits, args.spatial,
                                          args.texp, args.scatter)
        print(json.dumps(out))
        return
    if args.child:
        from ccdcore.emva.datasheet import emva_figures  # noqa: F401  (imports are not the tool's)
        import emva1288.process  # noqa: F401
        import emva1288.process.plotting  # noqa: F401
        logging.disable(logging.INFO)   # emva1288 logs every file it opens at INFO
        if args.child == "prepare":
            prepare_spatial(args.descriptor, args.out)
            print(json.dumps({"written": str(args.out)}))
            return
        child(args.child, args.descriptor)
        return
    logging.disable(logging.INFO)

    tools = ("emva1288", "ccdcore", "ccdcore+ptc")
    _report.header(__file__, args.repeat, args.warmup, order=tools)
    truths = {}
    for seed in seeds:   # in a child: the launcher's peak RSS is the floor of every child's
        truths[seed] = _report.run_json([sys.executable, __file__, "--make-data", "--seed",
                                         str(seed), "--size", args.size, "--bits",
                                         str(args.bits), "--steps", str(args.steps),
                                         "--spatial", str(args.spatial), "--camera",
                                         args.camera])
    first = folder_of(seeds[0]) / truths[seeds[0]]["descriptor"]
    inputs = folder_of(seeds[0]) / "spatial_inputs.npz"
    _report.run_json([sys.executable, __file__, "--child", "prepare", "--descriptor", str(first),
                      "--out", str(inputs)])
    memory = {tool: _report.run_json([sys.executable, __file__, "--child", tool,
                                      "--descriptor", str(first)]) for tool in tools}
    memory.update({tool: _report.run_json([sys.executable, __file__, "--child", tool,
                                           "--descriptor", str(inputs)])
                   for tool in ("ccdcore-spatial", "emva1288-spatial")})

    times: dict[str, list[float]] = {t: [] for t in tools}
    results = {}
    for seed in seeds:
        desc = folder_of(seed) / truths[seed]["descriptor"]
        runs = _report.interleaved({"emva1288": lambda: run_emva(desc),
                                    "ccdcore": lambda: run_ccdcore(desc, False),
                                    "ccdcore+ptc": lambda: run_ccdcore(desc, True)},
                                   repeat=args.repeat, warmup=args.warmup)
        for t in tools:
            times[t] += [r["seconds"] for r in runs[t]]
            for r in runs[t][:-1]:          # keep the arrays of the last run only
                for k in ("res", "plots", "fig"):
                    r.pop(k, None)
        results[seed] = (runs["emva1288"][-1], runs["ccdcore+ptc"][-1])
        for name in ("emva1288", "ccdcore"):
            keys = FIGURES + NEW_FIGURES
            if len({json.dumps([r[k] for k in keys]) for r in runs[name]}) != 1:
                print(f"WARNING: {name}'s figures differ between runs (seed {seed})")

    t0 = truths[seeds[0]]
    print(f"EMVA1288 DatasetGenerator ({args.camera} camera): {width}x{height}, {args.bits} bits, "
          f"{args.steps} steps, L = {args.spatial}, seeds {', '.join(map(str, seeds))}; truth "
          f"K = {t0['K']:.6g} DN/e, QE = {t0['QE']:.5g} %, sigma_d = {t0['sigma_d']:.5g} e "
          "(effective: with the generator's extra dither)"
          + (f", DSNU1288 = {t0['DSNU1288']:.5g} e, PRNU1288 = {t0['PRNU1288']:.5g} %"
             if t0["DSNU1288"] is not None else "")
          + f", dark current {t0['u_I']:.5g} e/s")
    worst: dict[str, float] = {}
    worst_new: dict[str, float] = {}
    z_new: dict[str, list[float]] = {}
    checks = {}
    for seed in seeds:
        emva, ours = results[seed]
        truth = truths[seed]
        print()
        print(f"seed {seed} (generated in {truth['generation_s']:.1f} s)")
        print(f"{'figure':<16}{'unit':<6}{'truth':>12}{'emva1288':>14}{'ccdcore':>26}"
              f"{'|c-e|/err':>11}{'(c-t)/err':>11}")
        for name in FIGURES:
            e, o, err = emva[name], ours[name], ours[f"{name}_err"]
            t = truth.get(name)
            pm = _num(o) + (f" ± {err:.2g}" if err is not None and math.isfinite(err) else "")
            de = abs(o - e) / err if err and math.isfinite(err) and math.isfinite(e) else None
            dt = (o - t) / err if t is not None and err and math.isfinite(err) else None
            if math.isfinite(e) and o is not None and math.isfinite(o) and e != 0:
                worst[name] = max(worst.get(name, 0.0), abs(o - e) / abs(e))
            print(f"{name:<16}{UNITS[name]:<6}{_num(t):>12}{_num(e):>14}{pm:>26}"
                  f"{_num(de, '.1e'):>11}{_num(dt, '+.2f'):>11}")
        ptc, ptc_err = ours["sigma_d_ptc"], ours["sigma_d_ptc_err"]
        print(f"{'sigma_d_ptc':<16}{'e':<6}{_num(truth['sigma_d']):>12}{'':>14}"
              f"{_num(ptc) + ' ± ' + _num(ptc_err, '.2g'):>26}"
              f"{'':>11}{_num((ptc - truth['sigma_d']) / ptc_err, '+.2f'):>11}")
        print(f"saturation index: emva1288 {emva['index_u_ysat']}, ccdcore {ours['index_u_ysat']}")
        print()
        rows = new_figure_rows(emva, ours, truth)
        print_new_rows(rows, truth, args.camera)
        for r in rows:
            if r["rel"] is not None:
                worst_new[r["name"]] = max(worst_new.get(r["name"], 0.0), r["rel"])
            if r["z"] is not None:
                z_new.setdefault(r["name"], []).append(r["z"])
            if r["z_exact"] is not None:
                z_new.setdefault(r["name"] + " (exact)", []).append(r["z_exact"])
        f = ours["fig"]
        if f.split is not None:
            for what, unit in (("DSNU1288", "e"), ("PRNU1288", "%")):
                parts = [f.split.figures()[f"{what}_{p}"] for p in PARTS]
                if all(_finite(p) for p in parts) and _finite(getattr(f, what)):
                    tot = getattr(f, what)
                    print(f"  {what}: row² + col² + pixel² = {sum(p * p for p in parts):.6g} "
                          f"{unit}², total² = {tot * tot:.6g} {unit}²")
        for note in ours["notes"]:
            print(f"  note: {note}")
        if f.spatial_plots is not None:
            checks[seed] = plot_checks(emva["plots"], f.to_dict()["spatial_plots"], f,
                                       emva["res"])
    print()
    print("largest relative difference ccdcore vs emva1288 over the seeds: " + ", ".join(
        f"{k} {v:.1e}" for k, v in worst.items()))
    print("new figures, largest relative difference where both give a number: " + (", ".join(
        f"{k} {v:.1e}" for k, v in worst_new.items()) or "none"))
    print("new figures, (ccdcore - truth)/error over the seeds: " + (", ".join(
        f"{k} {min(v):+.2f}…{max(v):+.2f}" for k, v in z_new.items()) or "none"))
    extras = _report.run_json([sys.executable, __file__, "--child", "camera", "--camera",
                               args.camera, "--size", args.size, "--bits", str(args.bits),
                               "--steps", str(args.steps), "--spatial", str(args.spatial),
                               "--scatter", str(args.scatter), "--texp",
                               repr(t0["spatial_exposure_s"])])
    qb = extras["quantisation"]
    print(f"u_I_var: the generator's dithered rounding alone moves sigma2_y.dark along the series "
          f"as a current of {qb:+.3g} e/s would ({100 * qb / t0['u_I']:+.2g} % of the truth; "
          "module docstring), in both tools' value")
    if checks:
        print()
        print_plot_table(checks)
        print()
        print("analytic spectrograms:")
        for line in analytic_spectrogram_checks():
            print(f"  {line}")
        if args.scatter:
            zs = extras["scatter"]
            print()
            print(f"dark split over {args.scatter} more dark spatial sets of the camera (K known), "
                  "z = (s2_part - K^2 s2_part(map)) / stated error: " + ", ".join(
                      f"{p} mean {np.mean(z):+.2f} ± {np.std(z, ddof=1) / math.sqrt(len(z)):.2f}, "
                      f"sd {np.std(z, ddof=1):.2f}" for p, z in zs.items()))
        print()
        print(f"L_dark < L (seed {seeds[0]}):")
        for line in ldark_checks(first, args.spatial):
            print(f"  {line}")
    print()
    n = len(seeds) * args.repeat
    print(f"{'run time, same files':<34}{'median (min–max) [s], ' + str(n) + ' runs':>34}")
    for t in tools:
        print(f"{t:<34}{_report.summary(times[t]).format('.3f'):>34}")
    print(f"speed ratio emva1288 / ccdcore (same work): "
          f"{_report.ratio_text(times['emva1288'], times['ccdcore'])}")
    print(f"speed ratio emva1288 / ccdcore+ptc: "
          f"{_report.ratio_text(times['emva1288'], times['ccdcore+ptc'])}")
    print("peak RSS of one run in a fresh process (after imports): " + ", ".join(
        f"{tool} {memory[tool]['peak_rss_mb']:.0f} MB "
        f"({memory[tool]['peak_rss_mb'] - memory[tool]['base_rss_mb']:.0f} MB)"
        for tool in tools))
    print()
    spatial_repeat = 4 * args.repeat
    parts = time_spatial(load_spatial(inputs), spatial_repeat, args.warmup)
    print(f"{'the new parts alone, seed ' + str(seeds[0]) + ' (' + args.size + ')':<54}"
          f"{'median (min–max) [ms], ' + str(spatial_repeat) + ' runs':>34}")
    for name, v in parts.items():
        print(f"{name:<54}{_report.summary(v).format('.2f'):>34}")
    ours_new = [sum(x) for x in zip(*(v for k, v in parts.items() if k.startswith("ccdcore")))]
    pkg_new = [sum(x) for x in zip(*(v for k, v in parts.items() if k.startswith("emva1288")))]
    med = _report.summary(times["ccdcore"]).median
    print(f"{'ccdcore new parts together':<54}{_report.summary(ours_new).format('.2f'):>34}"
          f"  ({100 * _report.summary(ours_new).median / 1e3 / med:.0f} % of emva_figures' "
          f"median {med:.3f} s)")
    print(f"{'emva1288 equivalent together':<54}{_report.summary(pkg_new).format('.2f'):>34}")
    print("peak RSS increment over the inputs, fresh process: " + ", ".join(
        f"{tool} {memory[tool]['peak_rss_mb'] - memory[tool]['base_rss_mb']:.1f} MB "
        f"({memory[tool]['peak_rss_mb']:.0f} MB peak)"
        for tool in ("ccdcore-spatial", "emva1288-spatial")))
    _report.footer(children=True)


if __name__ == "__main__":
    main()
