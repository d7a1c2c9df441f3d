"""Photon transfer against the EMVA 1288 reference implementation, on data with known truth.

The ``emva1288`` package (PyPI 1.0.2) writes an exposure-time series with its own
``DatasetGenerator`` (its camera simulator: Poisson light and dark electrons, Gaussian read noise
of variance ``sigma2_dark_0`` e², system gain K DN/e, full well ``u_esat``, 12-bit ADC); both tools
then estimate, from the same files:

* the system gain K (DN/e; ccdcore's A, the slope of eq. 41 of Healey & Kondepudy 1994);
* the temporal dark (read) noise in electrons (emva1288's σ_d; ccdcore's σ_R of eq. 27);

and their run times are measured on the same files (emva1288: parse, load, ``Data1288``,
``Results1288.K`` and ``.sigma_d``; ccdcore: ``open_session`` on the descriptor, then
``photon_transfer``), ``--repeat`` times each in one process, alternating the two tools after a
warm-up round, as median (min–max); the speed ratio is the ratio of the medians.  The data are
generated once into ``benchmarks/_data/emva_ptc`` (reused when the parameters match).

Truth of the generator: K = ``cam.K``; read noise √``sigma2_dark_0`` e.  The generator adds a
uniform dither U(−½, ½) DN *before* rounding, so its frames carry the quantisation variance twice
(≈ 2·q²/12); both tools remove q²/12 once, so the read noise they can recover is
√(σ²_d0 + q²/(12 K²)) e ("effective" below).

Note (docs/notes.md): emva1288's automatic saturation search can stop on the plateau after saturation;
ccdcore excludes the clipped and non-linear levels with stated reasons (listed below the table).

Run by hand (not part of the tests)::

    .venv/bin/python benchmarks/bench_ptc_emva.py                # 640x480, 12 bits, 20 steps
    .venv/bin/python benchmarks/bench_ptc_emva.py --steps 10 --size 320x240 --repeat 5
    .venv/bin/python benchmarks/bench_ptc_emva.py --size 2048x512 --bits 8 --steps 100 \
        --format png --repeat 3                                   # a measured-set-sized series
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

import numpy as np

# emva1288 1.0.2 calls np.asfarray, removed in NumPy 2 (docs/notes.md)
np.asfarray = lambda a, dtype=np.float64: np.asarray(a, dtype=dtype)  # noqa: E731

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

import _report  # noqa: E402  (benchmarks/_report.py, beside this script)


def make_data(folder: Path, width: int, height: int, bits: int, steps: int, L: int,
              seed: int, image_format: str = "tif") -> dict:
    """Write the dataset (once) and return the generator's truth."""
    from emva1288.camera.dataset_generator import DatasetGenerator

    from ccdcore.simulate import find_truth

    stamp = json.dumps([width, height, bits, steps, L, seed, image_format])
    truth_file = folder / "truth.json"
    cached = find_truth(folder)
    if cached is not None and (folder / ".stamp").read_text() == stamp:
        return dict(cached.values)
    if folder.exists():
        shutil.rmtree(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    gen = DatasetGenerator(steps=steps, L=L, image_format=image_format, outdir=str(folder),
                           width=width, height=height, bit_depth=bits, seed=seed)
    cam = gen.cam
    truth = {"K": float(cam.K), "sigma2_dark_0": float(cam._sigma2_dark_0),
             "read_noise_e": math.sqrt(cam._sigma2_dark_0),
             "read_noise_e_effective": math.sqrt(cam._sigma2_dark_0 + 1 / (12 * cam.K ** 2)),
             "blackoffset": float(cam.blackoffset), "u_esat": float(cam._u_esat),
             "descriptor": str(Path(gen.descriptor_path).relative_to(folder)),
             "generation_s": time.perf_counter() - t0}
    truth_file.write_text(json.dumps(truth, indent=2))
    (folder / ".stamp").write_text(stamp)
    return truth


def run_emva(descriptor: Path) -> dict:
    from emva1288.process import Data1288, LoadImageData, ParseEmvaDescriptorFile, Results1288

    t0 = time.perf_counter()
    parser = ParseEmvaDescriptorFile(str(descriptor))
    imgs = LoadImageData(parser.images)
    data = Data1288(imgs.data)
    res = Results1288(data.data)
    K, sigma_d = float(res.K), float(res.sigma_d)
    elapsed = time.perf_counter() - t0
    return {"K": K, "read_noise_e": sigma_d, "seconds": elapsed,
            "index_sensitivity_max": int(res.index_sensitivity_max),
            "index_u_ysat": int(res.index_u_ysat)}


def run_ccdcore(descriptor: Path) -> dict:
    from ccdcore.noise import photon_transfer
    from ccdcore.session import open_session

    t0 = time.perf_counter()
    pt = photon_transfer(open_session(descriptor))
    elapsed = time.perf_counter() - t0
    return {"K": pt.A, "K_err": pt.A_err, "read_noise_e": pt.read_noise_e,
            "read_noise_e_err": pt.read_noise_e_err, "seconds": elapsed, "result": pt}


def child(tool: str, descriptor: Path) -> None:
    """Run one tool once in this (fresh) process and print its time and peak RSS as JSON."""
    base = _report.max_rss_mb()
    out = (run_emva if tool == "emva1288" else run_ccdcore)(descriptor)
    print(json.dumps({"seconds": out["seconds"], "peak_rss_mb": _report.max_rss_mb(),
                      "base_rss_mb": base}))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", choices=["emva1288", "ccdcore"], help=argparse.SUPPRESS)
    ap.add_argument("--descriptor", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--size", default="640x480", help="WxH (default 640x480)")
    ap.add_argument("--bits", type=int, default=12)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--spatial", type=int, default=8, help="images of the spatial point (L)")
    ap.add_argument("--seed", type=int, default=1288)
    ap.add_argument("--format", default="tif", choices=["tif", "png"],
                    help="image files the generator writes (png: 8 bits only as emva1288 "
                         "writes them; default tif)")
    ap.add_argument("--repeat", type=int, default=9,
                    help="timed runs per tool, alternated emva1288/ccdcore (default 9)")
    ap.add_argument("--warmup", type=int, default=1, help="untimed rounds first (default 1)")
    args = ap.parse_args(argv)
    if args.child:
        from ccdcore.noise import photon_transfer  # noqa: F401  (imports are not the tool's)
        import emva1288.process  # noqa: F401
        logging.disable(logging.INFO)   # emva1288 logs every file it opens at INFO
        child(args.child, args.descriptor)
        return
    width, height = (int(v) for v in args.size.lower().split("x"))

    _report.header(__file__, args.repeat, args.warmup, order=("emva1288", "ccdcore"))
    default = (args.size, args.bits, args.steps, args.format) == ("640x480", 12, 20, "tif")
    folder = HERE / "_data" / ("emva_ptc" if default else
                               f"emva_ptc_{width}x{height}_{args.bits}b_{args.steps}_{args.format}")
    truth = make_data(folder, width, height, args.bits, args.steps, args.spatial, args.seed,
                      args.format)
    descriptor = folder / truth["descriptor"]

    # peak memory first, each tool once in a fresh child, while this process is still small
    # (a child's ru_maxrss starts from its parent's)
    memory = {tool: _report.run_json([sys.executable, __file__, "--child", tool,
                                      "--descriptor", str(descriptor)])
              for tool in ("emva1288", "ccdcore")}

    runs = _report.interleaved({"emva1288": lambda: run_emva(descriptor),
                                "ccdcore": lambda: run_ccdcore(descriptor)},
                               repeat=args.repeat, warmup=args.warmup)
    emva_runs, ours_runs = runs["emva1288"], runs["ccdcore"]
    emva, ours = emva_runs[-1], ours_runs[-1]
    # the estimates do not depend on the run: say so if they ever do
    for name, rs in (("emva1288", emva_runs), ("ccdcore", ours_runs)):
        if len({(r["K"], r["read_noise_e"]) for r in rs}) != 1:
            print(f"WARNING: {name}'s estimates differ between runs")
    t_emva = [r["seconds"] for r in emva_runs]
    t_ours = [r["seconds"] for r in ours_runs]
    pt = ours["result"]

    print(f"EMVA1288 DatasetGenerator: {width}x{height}, {args.bits} bits, {args.steps} steps, "
          f"L = {args.spatial}, seed {args.seed}; truth K = {truth['K']:.6g} DN/e, read noise "
          f"{truth['read_noise_e']:.4g} e (effective {truth['read_noise_e_effective']:.4g} e "
          f"with the generator's extra dither)")
    rows = [("system gain K [DN/e]", truth["K"], emva["K"],
             f"{ours['K']:.6g} ± {ours['K_err']:.2g}"),
            ("read noise [e]", truth["read_noise_e_effective"], emva["read_noise_e"],
             f"{ours['read_noise_e']:.4g} ± {ours['read_noise_e_err']:.2g}")]
    print(f"{'quantity':<22}{'truth':>12}{'emva1288':>12}{'ccdcore':>22}")
    for name, t, e, o in rows:
        print(f"{name:<22}{t:>12.6g}{e:>12.6g}{o:>22}")
    print(f"{'K error [%]':<22}{'':>12}{100 * (emva['K'] / truth['K'] - 1):>12.3f}"
          f"{100 * (ours['K'] / truth['K'] - 1):>22.3f}")
    print(f"{'read noise error [%]':<22}{'':>12}"
          f"{100 * (emva['read_noise_e'] / truth['read_noise_e_effective'] - 1):>12.3f}"
          f"{100 * (ours['read_noise_e'] / truth['read_noise_e_effective'] - 1):>22.3f}")
    print()
    print(f"{'run time, same files':<22}{'median (min–max) [s]':>24}")
    for name, ts in (("emva1288", t_emva), ("ccdcore", t_ours)):
        print(f"{name:<22}{_report.summary(ts).format('.3f'):>24}")
    print(f"speed ratio emva1288 / ccdcore: {_report.ratio_text(t_emva, t_ours)}")
    print("peak RSS of one run in a fresh process (after imports): " + ", ".join(
        f"{tool} {m['peak_rss_mb']:.0f} MB ({m['peak_rss_mb'] - m['base_rss_mb']:.0f} MB)"
        for tool, m in memory.items()))
    print()
    print(f"emva1288: sensitivity fit up to index {emva['index_sensitivity_max']}, saturation "
          f"index {emva['index_u_ysat']}")
    used = [p.level for p in pt.points if p.used]
    print(f"ccdcore: {len(used)} of {len(pt.points)} levels used, chi2 = {pt.chi2:.4g} "
          f"(dof {pt.dof}), Q = {pt.Q:.3g} ({pt.verdict}); black level {pt.black_level_dn:.4g} DN "
          f"({pt.black_level_source})")
    for p in pt.points:
        if not p.used:
            print(f"  level {p.level}: {p.reason}")
    _report.footer()


if __name__ == "__main__":
    main()
