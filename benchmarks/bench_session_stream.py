"""Streaming a frame stack through ``Session``: throughput and peak memory.

Writes N frames of W x H uint16 TIFF (uncompressed, like camera output) plus a manifest into
``benchmarks/_data/stream``, then, each in a fresh process so peak RSS is its own:

* ``oiio``:   the plain OpenImageIO read loop of the same files (the limit: reading only);
* ``session``: ``open_session`` + ``Session.iter_frames`` + per-pixel mean and variance
  (:class:`ccdcore.stats.PixelMoments`);
* ``numpy``:  the naive way, ``np.stack`` of every frame then ``mean``/``var`` (memory grows
  with N), for scale.

Each variant runs ``--repeat`` times (after a warm-up round that fills the page cache), the variants
alternated (oiio, session, numpy, oiio, ...); the table gives the median (min–max) time and peak
RSS.

Run by hand (not part of the tests)::

    .venv/bin/python benchmarks/bench_session_stream.py            # 64 frames of 2048x2048
    .venv/bin/python benchmarks/bench_session_stream.py --frames 16 --size 512 --repeat 3
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


def make_data(folder: Path, n: int, size: int) -> None:
    from ccdcore.io.frames import atomic_write_text, write_image

    manifest = folder / "session.toml"
    stamp = f"{n} {size}"
    if manifest.exists() and (folder / ".stamp").read_text() == stamp:
        return
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    base = rng.normal(3000, 30, size=(size, size))
    for i in range(n):
        frame = np.clip(base + rng.normal(0, 20, size=(size, size)), 0, 65535).astype(np.uint16)
        write_image(folder / f"frames/f{i:04d}.tif", frame, exposure=0.01,
                    attributes={"compression": "none"})
    atomic_write_text(manifest, 'schema = 1\n[camera]\nname = "bench"\nbits = 16\n'
                                'layout = "mono"\n\n[[groups]]\nglob = "frames/*.tif"\n'
                                'role = "dark"\nexposure = 0.01\n')
    (folder / ".stamp").write_text(stamp)


def run_variant(variant: str, folder: Path) -> dict:
    import OpenImageIO as oiio

    from ccdcore.io.frames import read_image
    from ccdcore.session import open_session
    from ccdcore.stats import PixelMoments

    PixelMoments().add(np.zeros((2, 2), np.uint16))  # load the compiled kernel before timing
    files = sorted((folder / "frames").glob("*.tif"))
    t0 = time.perf_counter()
    if variant == "oiio":
        total = 0
        for f in files:
            inp = oiio.ImageInput.open(str(f))
            a = inp.read_image(format=oiio.UNKNOWN)
            inp.close()
            total += a.size
    elif variant == "session":
        session = open_session(folder)
        acc = PixelMoments()
        for rec, frame in session.iter_frames(session.dark_frames()):
            acc.add(frame, name=rec.relpath)
        res = acc.result()
        total = res.n
    elif variant == "numpy":
        stack = np.stack([read_image(f) for f in files]).astype(np.float64)
        mean, var = stack.mean(axis=0), stack.var(axis=0, ddof=1)
        total = len(stack)
    else:
        raise SystemExit(f"unknown variant {variant}")
    dt = time.perf_counter() - t0
    # peak RSS includes the interpreter and libraries (numba/LLVM ~100 MB): compare across variants
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"variant": variant, "seconds": dt, "frames": len(files), "peak_rss_mb": peak_mb}


def _child(args: argparse.Namespace, *extra: str) -> dict:
    return _report.run_json([sys.executable, __file__, "--frames", str(args.frames), "--size",
                             str(args.size), *extra])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=64)
    ap.add_argument("--size", type=int, default=2048)
    ap.add_argument("--variant", help=argparse.SUPPRESS)
    ap.add_argument("--make-data", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--skip-numpy", action="store_true")
    ap.add_argument("--repeat", type=int, default=5,
                    help="timed runs per variant (fresh processes, alternated; default 5)")
    ap.add_argument("--warmup", type=int, default=1,
                    help="untimed rounds first, to warm the page cache (default 1)")
    args = ap.parse_args()
    folder = HERE / "_data" / f"stream_{args.frames}x{args.size}"
    if args.variant:
        print(json.dumps(run_variant(args.variant, folder)))
        return
    if args.make_data:
        make_data(folder, args.frames, args.size)
        print(json.dumps({"folder": str(folder)}))
        return
    variants = ["oiio", "session"] + ([] if args.skip_numpy else ["numpy"])
    _report.header(__file__, args.repeat, args.warmup, order=variants,
                   note="each run is a fresh process: its time excludes start-up and imports, its "
                        "peak RSS (ru_maxrss) includes the interpreter and libraries")
    _child(args, "--make-data")  # in a child: our peak RSS is the floor of theirs
    frame_mb = args.size * args.size * 2 / 2**20
    runs = _report.interleaved({v: (lambda v=v: _child(args, "--variant", v)) for v in variants},
                               repeat=args.repeat, warmup=args.warmup)
    secs = {v: [r["seconds"] for r in runs[v]] for v in variants}
    print(f"{args.frames} frames of {args.size}x{args.size} uint16 ({frame_mb:.1f} MB each)")
    print(f"{'variant':<10}{'seconds median (min–max)':>26}{'frames/s':>10}{'MB/s':>8}"
          f"{'peak RSS MB median (min–max)':>31}")
    for v in variants:
        t = _report.summary(secs[v])
        rss = _report.summary([r["peak_rss_mb"] for r in runs[v]])
        fps = args.frames / t.median
        print(f"{v:<10}{t.format('.3f'):>26}{fps:>10.1f}{fps * frame_mb:>8.0f}"
              f"{rss.format('.0f'):>31}")
    print("(frames/s and MB/s from the median time)")
    print(f"time session / oiio read loop: {_report.ratio_text(secs['session'], secs['oiio'])}")
    if "numpy" in secs:
        print(f"time numpy / session: {_report.ratio_text(secs['numpy'], secs['session'])}")
    _report.footer(children=True)


if __name__ == "__main__":
    main()
