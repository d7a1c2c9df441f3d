"""``ccdcore calibrate`` on a 2048x2048 healey94 session: wall time, peak memory, time per step.

Simulates a ``healey94`` session (the simulator's default capture: 16 dark frames, 8 ptc levels x
2 frames, n1 = 12 fixed-pattern configurations x n2 = 4 frames, 3 scene patches x 5 levels and a
max-intensity frame; 8-bit TIFF) of ``--size`` x ``--size`` frames into
``benchmarks/_data/calibrate_healey94_<size>`` (once, in a child process; gitignored), then runs,
each time in a fresh process so that the peak RSS is its own, what ``ccdcore calibrate SESSION -o
OUT`` runs: :func:`ccdcore.product.make.calibrate` (its progress callback marks the steps) and
:meth:`CalibrationProduct.save` into a temporary folder.

Each run is a fresh process: its times exclude start-up and imports, its peak RSS (``ru_maxrss``)
includes them; 'after import' is the RSS before the timed work.

Run by hand (not part of the tests)::

    .venv/bin/python benchmarks/bench_calibrate.py                  # 2048x2048, 5 runs
    .venv/bin/python benchmarks/bench_calibrate.py --size 512 --repeat 3   # quick
"""
from __future__ import annotations

import argparse
import json
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

import _report  # noqa: E402  (benchmarks/_report.py, beside this script)

SEED = 1
#: the progress steps of ccdcore.product.make.estimate_all, in order, and how this script names them
STEPS = (("photon transfer", "photon transfer (eqs. 37-42)"),
         ("dark reference", "dark reference D̂_D (sec. V-A)"),
         ("fixed pattern", "fixed pattern K̂ (eqs. 45-50)"),
         ("planning", "acquisition plan"),
         ("correction check", "correction check (sec. VII-A)"),
         ("scene variation", "scene variation V_S (eqs. 53-58)"),
         ("flat field", "flat field + plan check"),
         ("done", "product maps (float32)"))


def make_data(folder: Path, size: int) -> None:
    from ccdcore.simulate import simulate

    stamp = folder / ".stamp"
    want = f"healey94 seed={SEED} size={size}"
    if stamp.exists() and stamp.read_text() == want:
        return
    if folder.exists():
        shutil.rmtree(folder)
    t0 = time.perf_counter()
    simulate("healey94", folder, seed=SEED, size=(size, size))
    stamp.write_text(want)
    print(f"simulated {folder.name} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run_once(folder: Path) -> dict:
    """One calibrate + save in this (fresh) process: step times, totals, peak RSS."""
    from ccdcore.product.make import calibrate

    marks: list[tuple[str, float]] = []
    base = _rss_mb()
    t0 = time.perf_counter()
    product = calibrate(folder, progress=lambda step, _f: marks.append(
        (step, time.perf_counter())))
    t1 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        product.save(Path(tmp) / "cal")
        t2 = time.perf_counter()
    ends = [t for _, t in marks[1:]] + [t1]
    steps = {step: end - start for (step, start), end in zip(marks, ends)}
    est = product.estimates
    return {"steps": steps, "calibrate_s": t1 - t0, "save_s": t2 - t1, "total_s": t2 - t0,
            "base_rss_mb": base, "peak_rss_mb": _rss_mb(),
            "shape": list(product.shape or ()), "n_frames": product.provenance["n_frames"],
            "K_mean": est["fixed_pattern"]["mean"], "K_std": est["fixed_pattern"]["spatial_std"],
            "V_S": {k: v["V_S"] for k, v in est["scene"].items()}}


def _child(size: int, *extra: str) -> dict:
    return _report.run_json([sys.executable, __file__, "--size", str(size), *extra])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=2048)
    ap.add_argument("--run", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--make-data", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--repeat", type=int, default=5,
                    help="timed runs (fresh processes; default 5)")
    ap.add_argument("--warmup", type=int, default=1,
                    help="untimed runs first, to warm the page cache and numba's cache "
                         "(default 1)")
    args = ap.parse_args()
    folder = HERE / "_data" / f"calibrate_healey94_{args.size}"
    if args.run:
        print(json.dumps(run_once(folder)))
        return
    if args.make_data:
        make_data(folder, args.size)
        print(json.dumps({"folder": str(folder)}))
        return
    _report.header(__file__, args.repeat, args.warmup,
                   note="each run is a fresh process: its times exclude start-up and imports, "
                        "its peak RSS (ru_maxrss) includes them; 'after import' is the RSS "
                        "before the timed work")
    _child(args.size, "--make-data")  # in a child: our peak RSS is the floor of theirs
    runs = _report.interleaved({"calibrate": lambda: _child(args.size, "--run")},
                               repeat=args.repeat, warmup=args.warmup)["calibrate"]
    r = runs[-1]
    h, w = r["shape"]
    print(f"healey94 session, seed {SEED}: {r['n_frames']} frames of {w}x{h} uint8 TIFF")
    print(f"{'step':<36}{'seconds median (min–max)':>26}")
    for key, label in STEPS:
        vals = [x["steps"].get(key, 0.0) for x in runs]
        print(f"{label:<36}{_report.summary(vals).format('.2f'):>26}")
    for key, label in (("calibrate_s", "calibrate(), all steps"),
                       ("save_s", "save (7 EXR maps + calibration.json)"),
                       ("total_s", "calibrate + save")):
        print(f"{label:<36}{_report.summary([x[key] for x in runs]).format('.2f'):>26}")
    base = _report.summary([x["base_rss_mb"] for x in runs])
    peak = _report.summary([x["peak_rss_mb"] for x in runs])
    print(f"peak RSS {peak.format('.0f', 'MB')}, after import {base.median:.0f} MB, "
          f"above the imports {peak.median - base.median:.0f} MB")
    if len({json.dumps([x["K_mean"], x["K_std"], x["V_S"]]) for x in runs}) != 1:
        print("WARNING: the estimates differ between the runs")
    vs = ", ".join(f"{k} {v:.6g}" for k, v in r["V_S"].items())
    print(f"K̂ mean {r['K_mean']:.6f}, spatial std {r['K_std']:.4e}; V_S: {vs}")
    _report.footer(children=True)


if __name__ == "__main__":
    main()
