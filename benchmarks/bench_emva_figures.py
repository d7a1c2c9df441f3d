"""The EMVA 1288 figures against the reference implementation and against truth, with run times.

The ``emva1288`` package (PyPI 1.0.2) writes exposure-time series with its own
``DatasetGenerator`` (its camera simulator: Poisson light and dark electrons, Gaussian read noise
of variance ``sigma2_dark_0`` e², a DSNU map in e⁻ and a PRNU map, system gain K DN/e⁻, full well
``u_esat``, 12-bit ADC); for each of ``--seeds`` data sets both tools compute, from the same files,
every EMVA 1288 figure (release 3.1 definitions): K, QE, σ_y.dark, σ_d, μ_p.min, μ_p.sat,
μ_e.sat, SNR_max, DR (dB), LE_min, LE_max, DSNU1288, PRNU1288; ccdcore also gives each one's
standard error and σ_d from its photon-transfer intercept (``sigma_d_ptc``).

Truth of the generator, where the camera has it: K = ``cam.K``; QE = the mean of its spectral QE
(the generator's light is flat in photons per wavelength); σ_d = √(σ²_d0 + 1/(12K²)) e⁻ (the
generator dithers by U(−½, ½) DN before rounding, so its frames carry the quantisation variance
twice and σ_d keeps one of them: ``bench_ptc_emva.py``); DSNU1288 = the standard deviation of the
DSNU map (e⁻); PRNU1288 = 100 × that of the PRNU map over its mean (%).  μ_p.sat, μ_e.sat,
SNR_max, DR and LE have no simulated truth (they are defined by the measured series).

``--camera clean`` (the default) simulates a DSNU of 4 e⁻ and a PRNU of 1 %, a dark signal of
50 e⁻ (no dark electron is clipped at 0) and a full well of 60000 e⁻ (above the ADC range: the
series ends in ADC saturation); ``--camera defaults`` keeps the generator's own camera (no DSNU
nor PRNU, full well 15000 e⁻ = 1500 DN: the package's saturation search then stops on the
plateau after saturation, and both tools report the same, noted, figures).

Run times, same files, in one process, ``--repeat`` times each after a warm-up round,
alternated: emva1288 (parse, load, ``Data1288``, every figure of ``Results1288``); ccdcore
(``open_session`` on the descriptor, ``emva_figures`` without photon transfer: the same work);
ccdcore + photon transfer (``emva_figures`` computing ``sigma_d_ptc`` too, as ``calibrate``
has it).  Peak RSS: each tool once in a fresh child process.  The data are generated once, in a
child process, into ``benchmarks/_data/emva_figures_<camera>_<size>_<seed>`` (reused when the
parameters match).

Run by hand (not part of the tests)::

    .venv/bin/python benchmarks/bench_emva_figures.py        # 640x480, 20 steps, L = 16, 3 seeds
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
PATTERN_SEED = 12880


def make_data(folder: Path, width: int, height: int, bits: int, steps: int, L: int, seed: int,
              camera: str) -> dict:
    """Write one data set (once) and return the generator's truth."""
    from emva1288.camera.dataset_generator import DatasetGenerator

    stamp = json.dumps([width, height, bits, steps, L, seed, camera])
    truth_file = folder / "truth.json"
    if truth_file.exists() and (folder / ".stamp").read_text() == stamp:
        return json.loads(truth_file.read_text())
    if folder.exists():
        shutil.rmtree(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    kwargs: dict = {}
    dsnu = prnu = None
    if camera == "clean":
        rng = np.random.default_rng(PATTERN_SEED)
        dsnu = rng.normal(0.0, 4.0, (height, width))
        prnu = 1.0 + rng.normal(0.0, 0.01, (height, width))
        kwargs = dict(dsnu=dsnu, prnu=prnu, u_esat=60000.0, dark_signal_0=50.0)
    t0 = time.perf_counter()
    gen = DatasetGenerator(steps=steps, L=L, image_format="tif", outdir=str(folder),
                           width=width, height=height, bit_depth=bits, seed=seed, **kwargs)
    cam = gen.cam
    truth = {"K": float(cam.K), "QE": 100.0 * float(cam.qe.qe.mean()),
             "sigma_d": math.sqrt(cam._sigma2_dark_0 + 1.0 / (12.0 * cam.K ** 2)),
             "DSNU1288": None if dsnu is None else float(np.std(dsnu, ddof=1)),
             "PRNU1288": None if prnu is None else 100.0 * float(np.std(prnu, ddof=1)
                                                                 / np.mean(prnu)),
             "descriptor": str(Path(gen.descriptor_path).relative_to(folder)),
             "generation_s": time.perf_counter() - t0}
    truth_file.write_text(json.dumps(truth, indent=2))
    (folder / ".stamp").write_text(stamp)
    return truth


def run_emva(descriptor: Path) -> dict:
    from emva1288.process import Data1288, LoadImageData, ParseEmvaDescriptorFile, Results1288

    t0 = time.perf_counter()
    parser = ParseEmvaDescriptorFile(str(descriptor))
    res = Results1288(Data1288(LoadImageData(parser.images).data).data)
    with np.errstate(invalid="ignore"):
        out = {name: float(getattr(res, name)) for name in FIGURES if name != "DR_dB"}
        out["DR_dB"] = float(res.DR_dB())
    out["index_u_ysat"] = int(res.index_u_ysat)
    out["seconds"] = time.perf_counter() - t0
    return out


def run_ccdcore(descriptor: Path, with_ptc: bool) -> dict:
    from ccdcore.datasheet import emva_figures
    from ccdcore.session import open_session

    t0 = time.perf_counter()
    f = emva_figures(open_session(descriptor), with_ptc=with_ptc)
    elapsed = time.perf_counter() - t0
    out = {name: getattr(f, name) for name in FIGURES}
    out.update({f"{name}_err": getattr(f, f"{name}_err", None) for name in FIGURES})
    out.update(sigma_d_ptc=f.sigma_d_ptc, sigma_d_ptc_err=f.sigma_d_ptc_err,
               index_u_ysat=f.index_u_ysat, notes=list(f.notes), seconds=elapsed)
    return out


def child(tool: str, descriptor: Path) -> None:
    """Run one tool once in this (fresh) process and print its time and peak RSS as JSON."""
    base = _report.max_rss_mb()
    if tool == "emva1288":
        out = run_emva(descriptor)
    else:
        out = run_ccdcore(descriptor, with_ptc=tool == "ccdcore+ptc")
    print(json.dumps({"seconds": out["seconds"], "peak_rss_mb": _report.max_rss_mb(),
                      "base_rss_mb": base}))


def _num(v: float | None, fmt: str = ".6g") -> str:
    return "–" if v is None or not math.isfinite(v) else format(v, fmt)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", choices=["emva1288", "ccdcore", "ccdcore+ptc"],
                    help=argparse.SUPPRESS)
    ap.add_argument("--make-data", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--descriptor", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--size", default="640x480", help="WxH (default 640x480)")
    ap.add_argument("--bits", type=int, default=12)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--spatial", type=int, default=16, help="images of the spatial set (L)")
    ap.add_argument("--seeds", default="1288,1289,1290",
                    help="generator seeds, comma-separated (default 1288,1289,1290)")
    ap.add_argument("--camera", choices=["clean", "defaults"], default="clean",
                    help="the simulated camera (module docstring; default clean)")
    ap.add_argument("--repeat", type=int, default=5,
                    help="timed runs per tool and seed, alternated (default 5)")
    ap.add_argument("--warmup", type=int, default=1, help="untimed rounds first (default 1)")
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
    if args.child:
        from ccdcore.datasheet import emva_figures  # noqa: F401  (imports are not the tool's)
        import emva1288.process  # noqa: F401
        logging.disable(logging.INFO)   # emva1288 logs every file it opens at INFO
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
    memory = {tool: _report.run_json([sys.executable, __file__, "--child", tool,
                                      "--descriptor", str(first)]) for tool in tools}

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
        results[seed] = (runs["emva1288"][-1], runs["ccdcore+ptc"][-1])
        for name in ("emva1288", "ccdcore"):
            if len({json.dumps([r[k] for k in FIGURES]) for r in runs[name]}) != 1:
                print(f"WARNING: {name}'s figures differ between runs (seed {seed})")

    t0 = truths[seeds[0]]
    print(f"EMVA1288 DatasetGenerator ({args.camera} camera): {width}x{height}, {args.bits} bits, "
          f"{args.steps} steps, L = {args.spatial}, seeds {', '.join(map(str, seeds))}; truth "
          f"K = {t0['K']:.6g} DN/e, QE = {t0['QE']:.5g} %, sigma_d = {t0['sigma_d']:.5g} e "
          "(effective: with the generator's extra dither)"
          + (f", DSNU1288 = {t0['DSNU1288']:.5g} e, PRNU1288 = {t0['PRNU1288']:.5g} %"
             if t0["DSNU1288"] is not None else ""))
    worst: dict[str, float] = {}
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
        for note in ours["notes"]:
            print(f"  note: {note}")
    print()
    print("largest relative difference ccdcore vs emva1288 over the seeds: " + ", ".join(
        f"{k} {v:.1e}" for k, v in worst.items()))
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
        f"{tool} {m['peak_rss_mb']:.0f} MB ({m['peak_rss_mb'] - m['base_rss_mb']:.0f} MB)"
        for tool, m in memory.items()))
    _report.footer(children=True)


if __name__ == "__main__":
    main()
