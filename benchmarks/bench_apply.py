"""Writing corrected frames: ``ccdcore apply`` with and without compression.

10 frames of 2048×2048 uint16 TIFF corrected with a dark + K̂ product into float32 TIFF, once per
compression choice (``none``, the default, and ``zip``), alternated, median (min–max) of
``--repeat`` runs, and the size on disk of the outputs.

    .venv/bin/python benchmarks/bench_apply.py [--size 2048] [--frames 10] [--repeat 5]
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _report  # noqa: E402

from ccdcore.io.frames import write_image  # noqa: E402
from ccdcore.product.make import COMPRESSIONS, CalibrationProduct, apply_product  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=2048)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=1)
    args = ap.parse_args()
    _report.header(Path(__file__).name, repeat=args.repeat, warmup=args.warmup,
                   order=COMPRESSIONS)
    rng = np.random.default_rng(1)
    shape = (args.size, args.size)
    product = CalibrationProduct(
        maps={"dark": rng.normal(10, 0.5, shape).astype(np.float32),
              "K": rng.normal(1, 0.004, shape).astype(np.float32)}, estimates={})
    work = Path(tempfile.mkdtemp(prefix="bench_apply_"))
    try:
        frames = [write_image(work / f"f{i:02d}.tif",
                              rng.poisson(1000, shape).astype(np.uint16)) for i in range(args.frames)]
        outs = {c: work / f"out_{c}" for c in COMPRESSIONS}

        def run(c: str) -> float:
            t0 = time.perf_counter()
            apply_product(product, frames, outs[c], compression=c)
            return time.perf_counter() - t0

        runs = _report.interleaved({c: (lambda c=c: run(c)) for c in COMPRESSIONS},
                                   repeat=args.repeat, warmup=args.warmup)
        print(f"{args.frames} frames of {args.size}x{args.size} uint16 -> float32 TIFF")
        print(f"{'compression':12s}{'seconds median (min–max)':>28s}{'MB on disk':>12s}")
        for c in COMPRESSIONS:
            size = sum(p.stat().st_size for p in outs[c].iterdir()) / 1e6
            print(f"{c:12s}{str(_report.summary(runs[c])):>28s}{size:12.1f}")
        print("time zip / none: " + _report.ratio_text(runs["zip"], runs["none"]))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    _report.footer()


if __name__ == "__main__":
    main()
