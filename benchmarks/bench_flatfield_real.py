"""Darks and flats of a real CCD: ``ccdcore calibrate`` + ``ccdcore apply`` beside astropy ccdproc.

On the SBIG STL-1001E set of ``../shared/data/ccd/sbig_stl1001e`` (when present; else this says
so and exits 0): biases, darks at 0–300 s and two temperatures, 10 flats of 23 s at −5 °C.  One
flat (``flat-…00000009``) is held out; the other 9 and every bias and dark are copied into
``benchmarks/_data/sbig_fit`` (gitignored; copies, since a session refuses symbolic links
leading outside it).  Then, each in a fresh process (its peak RSS, ``ru_maxrss``, is its own; its
time excludes start-up and imports):

``ccdcore``
    ``ccdcore calibrate sbig_fit -o product`` (the dark model o + c·t from the biases and darks at
    −5 °C, the −10 °C ones left out; the flat field G, O with DL_0 the model's dark at 23 s) and
    ``ccdcore apply product held-out -o out``: the CLI's own code, in-process.
``ccdproc``
    The usual recipe: master bias = average of the −5 °C biases; master dark = average of the
    ten 60 s darks at −5 °C minus the bias; master flat = average of the 9 flats minus the bias
    minus the dark scaled to 23 s (``subtract_dark(..., scale=True)``); the held-out flat minus
    bias minus scaled dark, then ``flat_correct``.

Reported: wall time, peak RSS, and the held-out flat's SNUP (de Lasarte et al. 2007, eq. 5)
against the floor sqrt(1 + 1/N) × its temporal noise as a fraction of the corrected mean
(N = 9; the temporal noise from the 9 flats, each scaled to a common level; the floor is taken
relative to each tool's own corrected mean, since ccdcore's output keeps the mean dark level
⟨DL_0⟩ and ccdproc's does not).  The check passes at SNUP <= 1.15 × floor.  Both SNUPs leave
out ccdcore's flagged pixels (``flat_flags``: DL_B − DL_0 not above 5σ, i.e. dead pixels, which
no flat field corrects); the SNUP over every pixel is printed beside it.

Run by hand (needs ``pip install ccdproc`` in the venv; not part of the tests)::

    .venv/bin/python benchmarks/bench_flatfield_real.py --repeat 3
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import shutil
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

import _report  # noqa: E402  (benchmarks/_report.py, beside this script)

SBIG = ROOT.parent / "shared" / "data" / "ccd" / "sbig_stl1001e"
HELD = "flat-expos23s-Neg5-Vis.00000009.FIT"
FIT = HERE / "_data" / "sbig_fit"
WORK = HERE / "_data" / "sbig_runs"


def make_data() -> None:
    """Copy the set without the held-out flat into FIT (once)."""
    stamp = FIT / ".stamp"
    want = f"sbig without {HELD}"
    if stamp.exists() and stamp.read_text() == want:
        return
    if FIT.exists():
        shutil.rmtree(FIT)
    FIT.mkdir(parents=True)
    for p in sorted(SBIG.glob("*.FIT")):
        if p.name != HELD:
            shutil.copy2(p, FIT / p.name)
    stamp.write_text(want)


def _snup(a: np.ndarray, mask: np.ndarray | None = None) -> float:
    from ccdcore.flatfield.uniformity import snup
    return float(snup(np.asarray(a, np.float64), mask=mask)["L"].snup)


def _flags() -> np.ndarray:
    """ccdcore's flagged pixels (flat_flags: DL_B − DL_0 not above 5σ, dead pixels): left out
    of both tools' SNUP (a dead pixel cannot be corrected; ccdproc divides by about 0 there)."""
    from ccdcore.io.frames import read_image
    return np.asarray(read_image(WORK / "ccdcore_product" / "maps" / "flat_flags.exr")) > 0


def run_ccdcore() -> dict:
    from ccdcore.cli.command import main

    out, applied = WORK / "ccdcore_product", WORK / "ccdcore_applied"
    shutil.rmtree(applied, ignore_errors=True)
    base = _report.max_rss_mb()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["calibrate", str(FIT), "-o", str(out)]) == 0
        assert main(["apply", str(out), str(SBIG / HELD), "-o", str(applied)]) == 0
    t1 = time.perf_counter()
    from ccdcore.io.frames import read_image
    corrected = read_image(applied / HELD)
    doc = json.loads((out / "calibration.json").read_text())
    model = doc["estimates"]["dark"]["model"]
    return {"tool": "ccdcore", "seconds": t1 - t0, "base_rss_mb": base,
            "peak_rss_mb": _report.max_rss_mb(), "snup": _snup(corrected, _flags()),
            "snup_all": _snup(corrected),
            "mean": float(np.mean(corrected)),
            "in_product_check": doc["estimates"]["flat_field"].get("held_out"),
            "model": {k: model[k] for k in ("n", "temperature", "offset_median",
                                            "offset_err_median", "current_median",
                                            "current_err_median", "current_mean", "n_hot")},
            "n_excluded": len(model["excluded"])}


def run_ccdproc() -> dict:
    import astropy.units as u
    import ccdproc
    from astropy.nddata import CCDData

    names = sorted(p.name for p in FIT.glob("*.FIT"))
    biases = [str(FIT / n) for n in names if n.startswith("biases-Neg5")]
    darks = [str(FIT / n) for n in names if n.startswith("darks-expos1-Neg5")]   # 10 x 60 s
    flats = [str(FIT / n) for n in names if n.startswith("flat-")]
    base = _report.max_rss_mb()
    t0 = time.perf_counter()
    bias = ccdproc.combine(biases, method="average", unit="adu")
    dark = ccdproc.subtract_bias(ccdproc.combine(darks, method="average", unit="adu"), bias)
    flat = ccdproc.subtract_bias(ccdproc.combine(flats, method="average", unit="adu"), bias)
    flat = ccdproc.subtract_dark(flat, dark, dark_exposure=60 * u.s, data_exposure=23 * u.s,
                                 scale=True)
    test = ccdproc.subtract_bias(CCDData.read(SBIG / HELD, unit="adu"), bias)
    test = ccdproc.subtract_dark(test, dark, dark_exposure=60 * u.s, data_exposure=23 * u.s,
                                 scale=True)
    out = ccdproc.flat_correct(test, flat)
    t1 = time.perf_counter()
    data = np.asarray(out.data, np.float64)
    return {"tool": "ccdproc", "seconds": t1 - t0, "base_rss_mb": base,
            "peak_rss_mb": _report.max_rss_mb(), "snup": _snup(data, _flags()),
            "snup_all": _snup(data), "mean": float(data.mean())}


def temporal_noise() -> tuple[float, int]:
    """σ_t (DN): the per-pixel temporal std of the 9 fitted flats, each scaled to the first's
    mean level, averaged in variance over the frame; and N."""
    from ccdcore.io.frames import read_image
    from ccdcore.stats import PixelMoments

    acc, ref = PixelMoments(), None
    flats = sorted(FIT.glob("flat-*.FIT"))
    for p in flats:
        a = np.asarray(read_image(p), np.float64)
        ref = ref or float(a.mean())
        acc.add(a * ref / a.mean(), name=p.name)
    return math.sqrt(float(acc.result().var.mean())), len(flats)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", choices=("ccdproc", "ccdcore"), help=argparse.SUPPRESS)
    ap.add_argument("--repeat", type=int, default=3,
                    help="timed runs per tool (fresh processes, alternated; default 3)")
    ap.add_argument("--warmup", type=int, default=1, help="untimed rounds first (default 1)")
    args = ap.parse_args()
    if not SBIG.is_dir():
        print(f"the SBIG set is absent ({SBIG}): nothing to measure")
        return
    if args.run:
        WORK.mkdir(parents=True, exist_ok=True)
        print(json.dumps(run_ccdproc() if args.run == "ccdproc" else run_ccdcore()))
        return
    try:
        import ccdproc  # noqa: F401
    except ImportError:
        print("ccdproc is not installed (pip install ccdproc): only ccdcore is measured")
        tools: tuple[str, ...] = ("ccdcore",)
    else:
        tools = ("ccdcore", "ccdproc")
    _report.header(__file__, args.repeat, args.warmup, order=tools,
                   note="each run is a fresh process: its time excludes start-up and imports, "
                        "its peak RSS (ru_maxrss) includes them")
    make_data()
    sigma_t, n = temporal_noise()
    _report.run_json([sys.executable, __file__, "--run", "ccdcore"])   # its flags first
    runs = _report.interleaved(
        {t: (lambda t=t: _report.run_json([sys.executable, __file__, "--run", t]))
         for t in tools}, repeat=args.repeat, warmup=args.warmup)
    print(f"SBIG STL-1001E 512x512: {HELD} held out, maps from the other {n} flats; temporal "
          f"noise σ_t = {sigma_t:.2f} DN")
    print(f"{'tool':10s}{'wall s median (min–max)':>26s}{'peak RSS MB median':>20s}"
          f"{'SNUP %':>9s}{'floor %':>9s}{'SNUP/floor':>11s}  verdict  (SNUP % with the "
          "flagged pixels)")
    for t in tools:
        r = runs[t][-1]
        floor = 100 * math.sqrt(1 + 1 / n) * sigma_t / r["mean"]
        ratio = r["snup"] / floor
        wall = _report.summary([x["seconds"] for x in runs[t]])
        peak = _report.summary([x["peak_rss_mb"] for x in runs[t]])
        print(f"{t:10s}{wall.format('.2f'):>26s}{peak.median:>20.0f}{r['snup']:>9.4f}"
              f"{floor:>9.4f}{ratio:>11.3f}  {'pass' if ratio <= 1.15 else 'warn'}     "
              f"({r['snup_all']:.4f})")
    core = runs["ccdcore"][-1]
    m = core["model"]
    print(f"ccdcore dark model: {m['n']} frames at {m['temperature']:g} °C "
          f"({core['n_excluded']} left out at −10 °C); offset median {m['offset_median']:.1f} "
          f"± {m['offset_err_median']:.2f} DN, current median {m['current_median']:.4f} ± "
          f"{m['current_err_median']:.4f} DN/s (mean {m['current_mean']:.4f}), "
          f"{m['n_hot']} hot pixels")
    chk = core["in_product_check"]
    if chk:
        c = chk["channels"][0]
        print(f"the product's own held-out check (within the 9 flats: {chk['held_out']} held "
              f"out, N = {chk['n_fit']}): SNUP {c['snup']:.4f} % vs floor {c['floor']:.4f} % "
              f"(× {c['ratio']:.3f}), {chk['verdict']}")
    _report.footer(children=True)


if __name__ == "__main__":
    main()
