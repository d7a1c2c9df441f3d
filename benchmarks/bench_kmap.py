"""Dark reference + fixed-pattern map K̂ (sec. V of Healey & Kondepudy 1994): time and peak memory.

Simulates a ``healey94`` session of 1024x1024 frames with n1 = 20 configurations x n2 = 20 frames
and s = 20 dark frames into ``benchmarks/_data/kmap_1024`` (once; gitignored), then runs, each in a
fresh process so that the peak RSS is its own, ``dark_reference`` + ``fixed_pattern_map`` on:

* n1 = 20, n2 = 20  (the paper's capture)
* n1 = 20, n2 = 5   (same configurations, fewer frames: peak memory must not change)
* n1 = 10, n2 = 20  (fewer configurations: peak memory drops by the slope maps, 10·H·W·5 bytes)

The expected memory: n1 float32 slope maps + the (n1, H, W) bool rejection array (n1·H·W·5 bytes,
100 MB at n1 = 20) plus about a dozen float64 (H, W) maps (8 MB each), independent of n2.  For
scale, ``np.stack`` of all n1·n2 frames in float64 would be n1·n2·H·W·8 bytes (3.4 GB here).

Each variant runs ``--repeat`` times (after a warm-up round that fills the page cache), the variants
alternated; the tables give median (min–max) times and peak RSS.

Run by hand (not part of the tests)::

    .venv/bin/python benchmarks/bench_kmap.py                 # 1024x1024
    .venv/bin/python benchmarks/bench_kmap.py --size 256 --repeat 3   # quick
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

import _report  # noqa: E402  (benchmarks/_report.py, beside this script)

N1, N2, S = 20, 20, 20


def make_data(folder: Path, size: int) -> None:
    from ccdcore.simulate import simulate

    stamp = folder / ".stamp"
    want = f"healey94 seed=1 size={size} n1={N1} n2={N2} s={S}"
    if stamp.exists() and stamp.read_text() == want:
        return
    t0 = time.perf_counter()
    simulate("healey94", folder, seed=1, size=(size, size), n1=N1, n2=N2, n_dark=S, levels=3,
             scene_levels=(0.5,), patches=(("matte_grey", 0.01),))
    stamp.write_text(want)
    print(f"simulated {folder.name} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run_variant(folder: Path, n1: int, n2: int) -> dict:
    from ccdcore.dark.frame import dark_reference
    from ccdcore.fixedpattern import fixed_pattern_map
    from ccdcore.session import open_session

    session = open_session(folder)
    base = _rss_mb()
    t0 = time.perf_counter()
    dark = dark_reference(session)
    t1 = time.perf_counter()
    configs = list(session.fixed_pattern_configs().items())[:n1]
    fp = fixed_pattern_map({cid: session.iter_frames(recs[:n2]) for cid, recs in configs}, dark)
    t2 = time.perf_counter()
    return {"n1": n1, "n2": n2, "s": dark.s, "dark_s": t1 - t0, "kmap_s": t2 - t1,
            "base_rss_mb": base, "peak_rss_mb": _rss_mb(), "K_mean": fp.mean,
            "K_std": fp.spatial_std, "sigma_hat": fp.sigma_hat, "n1_hat": fp.n1_hat,
            "shape": list(fp.K.shape)}


def _child(size: int, *extra: str) -> dict:
    return _report.run_json([sys.executable, __file__, "--size", str(size), *extra])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--variant", help=argparse.SUPPRESS)
    ap.add_argument("--make-data", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--repeat", type=int, default=5,
                    help="timed runs per variant (fresh processes, alternated; default 5)")
    ap.add_argument("--warmup", type=int, default=1,
                    help="untimed rounds first, to warm the page cache (default 1)")
    args = ap.parse_args()
    folder = HERE / "_data" / f"kmap_{args.size}"
    if args.variant:
        n1, n2 = map(int, args.variant.split(","))
        print(json.dumps(run_variant(folder, n1, n2)))
        return
    if args.make_data:
        make_data(folder, args.size)
        print(json.dumps({"folder": str(folder)}))
        return
    variants = ((N1, N2), (N1, 5), (10, N2))
    names = [f"{n1}x{n2}" for n1, n2 in variants]
    _report.header(__file__, args.repeat, args.warmup, order=names,
                   note="each run is a fresh process: its times exclude start-up and imports, "
                        "its peak RSS (ru_maxrss) includes them; 'base' is the RSS after imports")
    _child(args.size, "--make-data")  # in a child: our peak RSS is the floor of theirs
    runs = _report.interleaved(
        {name: (lambda v=v: _child(args.size, "--variant", f"{v[0]},{v[1]}"))
         for name, v in zip(names, variants)},
        repeat=args.repeat, warmup=args.warmup)
    hw = args.size * args.size
    print(f"dark_reference (s = {S}) + fixed_pattern_map on {args.size}x{args.size} uint8 frames")
    print(f"{'n1':>3}{'n2':>4}{'frames':>8}{'dark s median (min–max)':>25}"
          f"{'K map s median (min–max)':>26}{'frames/s':>10}")
    for name in names:
        rs = runs[name]
        r = rs[0]
        frames = r["n1"] * r["n2"]
        dark = _report.summary([x["dark_s"] for x in rs])
        kmap = _report.summary([x["kmap_s"] for x in rs])
        fps = (frames + r["s"]) / (dark.median + kmap.median)
        print(f"{r['n1']:>3}{r['n2']:>4}{frames:>8}{dark.format('.2f'):>25}"
              f"{kmap.format('.2f'):>26}{fps:>10.1f}")
    print("(frames/s: dark + K-map frames over the median dark + K map times)")
    print()
    print(f"{'n1':>3}{'n2':>4}{'base MB':>9}{'peak MB median (min–max)':>26}{'peak-base':>11}"
          f"{'model MB':>10}{'np.stack MB':>13}")
    for name in names:
        rs = runs[name]
        r = rs[0]
        frames = r["n1"] * r["n2"]
        base = _report.summary([x["base_rss_mb"] for x in rs])
        peak = _report.summary([x["peak_rss_mb"] for x in rs])
        above = _report.summary([x["peak_rss_mb"] - x["base_rss_mb"] for x in rs])
        model = (r["n1"] * hw * 5 + 12 * hw * 8) / 2 ** 20
        stack = frames * hw * 8 / 2 ** 20
        print(f"{r['n1']:>3}{r['n2']:>4}{base.median:>9.0f}{peak.format('.0f'):>26}"
              f"{above.median:>11.0f}{model:>10.0f}{stack:>13.0f}")
    print("(base, peak-base: medians over the runs)")
    r = runs[names[0]][-1]
    for name in names:
        if len({(x["K_mean"], x["K_std"], x["sigma_hat"]) for x in runs[name]}) != 1:
            print(f"WARNING: K̂ differs between the runs of {name}")
    print(f"K̂ (n1 = {r['n1']}, n2 = {r['n2']}): mean {r['K_mean']:.5f}, spatial std "
          f"{r['K_std']:.3e}, σ̂ {r['sigma_hat']:.3e}, n̂_1 {r['n1_hat']}")
    _report.footer(children=True)


if __name__ == "__main__":
    main()
