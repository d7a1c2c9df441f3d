"""Flat-field correction: ccdcore (``flat_field`` + ``correct``) against astropy ccdproc.

Writes 31 uint16 FITS frames of 2048x2048 into ``benchmarks/_data/flatfield_2048`` (once;
gitignored): 10 dark frames, 20 flat frames of a uniform field (cos⁴ vignetting x 1 % PRNU,
shot and read noise, black level 100 DN, ≈ 20000 DN above dark in the centre) and one held-out
flat frame to correct.  Then, each in a fresh process so that the peak RSS (``ru_maxrss``) is its
own:

``ccdproc``
    ``ccdproc.combine`` of the darks and of the flats (method ``average``, its defaults: no
    clipping), ``subtract_dark`` of the master dark from the master flat and from the test frame,
    ``flat_correct`` of the test frame.
``ccdcore``
    :func:`ccdcore.flatfield.fit.flat_field` (streamed averages of the darks and flats through
    :class:`ccdcore.stats.PixelMoments`) and :meth:`FlatField.correct` of the test frame.

Both compute k·(DL − DL_0)/(DL_B − DL_0); the table gives wall time, peak memory and the SNUP
(de Lasarte et al. 2007, eq. 5) of the corrected held-out frame (the shot-noise limit of one
frame is printed beside it).  Each tool runs ``--repeat`` times (after a warm-up round that fills
the page cache), the two alternated; times and peak RSS are median (min–max), ratios come from the
medians.

Run by hand (needs ``pip install ccdproc``; not part of the tests)::

    .venv/bin/python benchmarks/bench_flatfield_ccdproc.py            # 2048x2048
    .venv/bin/python benchmarks/bench_flatfield_ccdproc.py --size 512 --repeat 3  # quick
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

import _report  # noqa: E402  (benchmarks/_report.py, beside this script)

N_DARK, N_FLAT = 10, 20
BLACK, SIGNAL, E_PER_DN, READ_E = 100.0, 20000.0, 2.0, 10.0


def make_data(folder: Path, size: int) -> None:
    from ccdcore.io.frames import write_image

    stamp = folder / ".stamp"
    want = f"flat size={size} darks={N_DARK} flats={N_FLAT} seed=7"
    if stamp.exists() and stamp.read_text() == want:
        return
    t0 = time.perf_counter()
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(7)
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    r = np.hypot(x + 0.5 - size / 2, y + 0.5 - size / 2) / (size / 2)
    vign = np.cos(np.arctan(0.5 * r)) ** 4
    flat = vign * (1 + 0.01 * rng.standard_normal((size, size)))
    flat /= flat.mean()
    np.save(folder / "truth_flat.npy", flat.astype(np.float32))

    def frame(signal_dn: np.ndarray | float) -> np.ndarray:
        e = rng.poisson(np.asarray(signal_dn) * E_PER_DN).astype(np.float64)
        e += READ_E * rng.standard_normal((size, size))
        return np.clip(np.rint(BLACK + e / E_PER_DN), 0, 65535).astype(np.uint16)

    for i in range(N_DARK):
        write_image(folder / f"dark_{i:02d}.fits", frame(np.full((size, size), 5.0)),
                    exposure=1.0)
    for i in range(N_FLAT):
        write_image(folder / f"flat_{i:02d}.fits", frame(SIGNAL * flat), exposure=1.0)
    write_image(folder / "test_flat.fits", frame(SIGNAL * flat), exposure=1.0)
    stamp.write_text(want)
    print(f"wrote {N_DARK + N_FLAT + 1} frames of {size}x{size} in "
          f"{time.perf_counter() - t0:.1f} s", file=sys.stderr)


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _snup(a: np.ndarray) -> dict:
    from ccdcore.flatfield.uniformity import snup
    c = snup(a)["L"]
    return {"snup": c.snup, "snup_err": c.snup_err}


def run_ccdproc(folder: Path) -> dict:
    import astropy.units as u
    import ccdproc
    from astropy.nddata import CCDData

    darks = sorted(str(p) for p in folder.glob("dark_*.fits"))
    flats = sorted(str(p) for p in folder.glob("flat_*.fits"))
    base = _rss_mb()
    t0 = time.perf_counter()
    master_dark = ccdproc.combine(darks, method="average", unit="adu")
    master_flat = ccdproc.combine(flats, method="average", unit="adu")
    master_flat = ccdproc.subtract_dark(master_flat, master_dark, dark_exposure=1 * u.s,
                                        data_exposure=1 * u.s)
    test = CCDData.read(folder / "test_flat.fits", unit="adu")
    test = ccdproc.subtract_dark(test, master_dark, dark_exposure=1 * u.s, data_exposure=1 * u.s)
    out = ccdproc.flat_correct(test, master_flat)
    t1 = time.perf_counter()
    data = np.asarray(out.data, dtype=np.float64)
    return {"tool": "ccdproc", "seconds": t1 - t0, "base_rss_mb": base, "peak_rss_mb": _rss_mb(),
            **_snup(data)}


def run_ccdcore(folder: Path) -> dict:
    from ccdcore.flatfield.fit import flat_field
    from ccdcore.io.frames import read_image

    darks = sorted(folder.glob("dark_*.fits"))
    flats = sorted(folder.glob("flat_*.fits"))
    base = _rss_mb()
    t0 = time.perf_counter()
    ff = flat_field(((p, read_image(p)) for p in darks), ((p, read_image(p)) for p in flats))
    out = ff.correct(read_image(folder / "test_flat.fits"))
    t1 = time.perf_counter()
    res = {"tool": "ccdcore", "seconds": t1 - t0, "base_rss_mb": base,
           "peak_rss_mb": _rss_mb(), **_snup(out.astype(np.float64))}
    # the shot-noise limit of one frame: temporal std of the flats / mean of the test frame
    test = read_image(folder / "test_flat.fits").astype(np.float64)
    res["snup_limit"] = 100 * float(np.sqrt(ff.base.var.mean())) / float(test.mean())
    res["snup_raw"] = _snup(test)["snup"]
    truth = np.load(folder / "truth_flat.npy").astype(np.float64)
    gf = ff.G * truth
    res["G_residual_pct"] = 100 * float(gf.std() / gf.mean())
    return res


def _child(size: int, *extra: str) -> dict:
    return _report.run_json([sys.executable, __file__, "--size", str(size), *extra])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=2048)
    ap.add_argument("--run", choices=("ccdproc", "ccdcore"), help=argparse.SUPPRESS)
    ap.add_argument("--make-data", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--repeat", type=int, default=5,
                    help="timed runs per tool (fresh processes, alternated; default 5)")
    ap.add_argument("--warmup", type=int, default=1,
                    help="untimed rounds first, to warm the page cache (default 1)")
    args = ap.parse_args()
    folder = HERE / "_data" / f"flatfield_{args.size}"
    if args.run:
        fn = run_ccdproc if args.run == "ccdproc" else run_ccdcore
        print(json.dumps(fn(folder)))
        return
    if args.make_data:
        make_data(folder, args.size)
        print(json.dumps({"folder": str(folder)}))
        return
    tools = ("ccdcore", "ccdproc")
    _report.header(__file__, args.repeat, args.warmup, order=tools,
                   note="each run is a fresh process: its time excludes start-up and imports, its "
                        "peak RSS (ru_maxrss) includes them; 'after import' is the RSS before the "
                        "timed work")
    _child(args.size, "--make-data")  # in a child: our peak RSS is the floor of theirs
    runs = _report.interleaved({t: (lambda t=t: _child(args.size, "--run", t)) for t in tools},
                               repeat=args.repeat, warmup=args.warmup)
    for t in tools:
        if len({(r["snup"], r["snup_err"]) for r in runs[t]}) != 1:
            print(f"WARNING: {t}'s SNUP differs between runs")
    secs = {t: [r["seconds"] for r in runs[t]] for t in tools}
    above = {t: [r["peak_rss_mb"] - r["base_rss_mb"] for r in runs[t]] for t in tools}
    core = runs["ccdcore"][-1]
    print(f"{N_DARK} darks + {N_FLAT} flats of {args.size}x{args.size} uint16 FITS, "
          f"one held-out flat corrected")
    print(f"{'tool':10s}{'wall s median (min–max)':>26s}{'peak RSS MB median (min–max)':>31s}"
          f"{'(after import)':>16s}{'SNUP %':>9s}{'± err':>8s}")
    for t in tools:
        r = runs[t][-1]
        wall = _report.summary(secs[t])
        peak = _report.summary([x["peak_rss_mb"] for x in runs[t]])
        base = _report.summary([x["base_rss_mb"] for x in runs[t]])
        print(f"{t:10s}{wall.format('.2f'):>26s}{peak.format('.0f'):>31s}{base.median:>16.0f}"
              f"{r['snup']:>9.4f}{r['snup_err']:>8.4f}")
    mem = _report.summary(above["ccdproc"]).median / _report.summary(above["ccdcore"]).median
    time_ratio = _report.ratio_text(secs["ccdproc"], secs["ccdcore"], ".1f")
    print(f"ratio ccdproc/ccdcore: time {time_ratio}")
    print(f"ratio ccdproc/ccdcore: peak memory above the imports {mem:.1f}x (ratio of medians: "
          f"{_report.summary(above['ccdproc']).median:.0f} MB / "
          f"{_report.summary(above['ccdcore']).median:.0f} MB)")
    print(f"uncorrected SNUP {core['snup_raw']:.3f} %, single-frame shot-noise limit "
          f"{core['snup_limit']:.4f} %, G vs true flat field residual "
          f"{core['G_residual_pct']:.4f} %")
    print("(ccdcore's DL_c = O + G·DL keeps the mean dark level ⟨DL_0⟩ (eq. 2), ccdproc's "
          "output does not: the same noise over a mean larger by the dark level)")
    _report.footer(children=True)


if __name__ == "__main__":
    main()
