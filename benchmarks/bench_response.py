"""Response curves on the simulation protocol of Tsin, Ramesh & Kanade (2001), sec. 4.1.

Each sequence: 8 exposures √2 apart of a 256×256 scene with radiance uniform on [0, 1],
g(z) = (z/255)^1.2, σ_s = 0.015, σ_c1 = 0.01, σ_c2 = 1 DN, 8 bits (``ccdcore.simulate.tsin``,
drawn in memory, a new seed per sequence), without white balance and with it (a_k off the
nominal exposure by a Gaussian factor of 5 %, offsets b_k of 0.01; every method is given the
nominal times). For every sequence and method the curve is compared with the truth after its
free scale is fitted over z = 5…250 (``ccdcore.response.scale``); the tables give the RMS error
(median and range over the sequences) and, per band of codes, the bias (mean error over the
sequences) and the spread (standard deviation over the sequences) -- the paper's Fig. 2 in
numbers -- and the run time per sequence.

Methods: ccdcore's estimator of sec. 3.2 (``ccdcore.response.tsin.estimator``, instrumented pools,
and the pools as printed for comparison), Debevec & Malik, Robertson and Mitsunaga & Nayar
(``ccdcore.response.classic``; brackets read as ``load_bracket`` does, without the blooming mask:
this simulation has no blooming and OpenCV uses every pixel), OpenCV's ``CalibrateDebevec``
and ``CalibrateRobertson`` at their defaults (the grey frames given as three equal channels,
which Robertson requires; codes without data, NaN in Robertson's curve, interpolated) and
colour-hdri's ``camera_response_functions_Debevec1997`` at its defaults (Grossberg sampling,
λ = 30, polynomial extrapolation). Every method is given the nominal exposure times, also in the
white-balance study, except "sec. 3.2 + white balance", which estimates the gains a_k and
offsets b_k in the gauge of the u-ambiguity (its curve is compared after its scale and offset).

The sec. 3.2 estimator's band is checked too: the fraction of codes 10..245 whose error lies
within ±2σ of its band, over all sequences ("coverage").

Then the HDR merge (eqs. 9, 18, 19, with the per-pixel sigma) against OpenCV's ``MergeDebevec``
on one 256² × 8 sequence, both given the true response.

    .venv/bin/python benchmarks/bench_response.py                  # 50 sequences each
    .venv/bin/python benchmarks/bench_response.py --sequences 5    # quick
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))
import _report  # noqa: E402

from ccdcore.response import bracket_data, debevec, mitsunaga_nayar, robertson  # noqa: E402
from ccdcore.response.hdr import ResponseModel, merge  # noqa: E402
from ccdcore.response.tsin.estimator import TsinOptions, estimate  # noqa: E402
from ccdcore.response.scale import aligned, rms_error  # noqa: E402
from ccdcore.simulate import tsin  # noqa: E402

#: methods whose curve carries a free offset (white balance with offsets b_k): compared after
#: their scale and offset are fitted, the others after their scale
FREE_OFFSET = {"ccdcore sec. 3.2 + white balance"}
BANDS = ((5, 20), (20, 50), (50, 100), (100, 150), (150, 200), (200, 230), (230, 250))
SIZE = 256


def sequence(seed: int, white_balance: bool) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Frames, nominal times and true g of one sec. 4.1 sequence."""
    rng = np.random.default_rng(seed)
    E = tsin.uniform_radiance(rng, (SIZE, SIZE))
    t = np.asarray(tsin.exposure_times(8, math.sqrt(2.0), math.sqrt(2.0)))
    a, b = tsin.white_balance(t, rng, enabled=white_balance, channels=1, wb_sigma=0.05,
                              offset_sigma=0.01)
    frames = [tsin.expose(E, a[k], b[k], rng).z for k in range(t.size)]
    return frames, t, np.asarray(tsin.response_table(1.2))


def _fill_nan(curve: np.ndarray) -> np.ndarray:
    ok = np.isfinite(curve)
    z = np.arange(curve.size)
    return np.interp(z, z[ok], curve[ok])


def opencv_methods() -> dict[str, Callable]:
    import cv2

    def run(make):
        def fn(frames, t):
            imgs = [np.repeat(f[..., None], 3, axis=2) for f in frames]
            resp = make().process(imgs, np.asarray(t, np.float32))
            return _fill_nan(np.asarray(resp, np.float64)[:, 0, 1])
        return fn

    return {"OpenCV Debevec": run(cv2.createCalibrateDebevec),
            "OpenCV Robertson": run(cv2.createCalibrateRobertson)}


def our_methods() -> dict[str, Callable]:
    def run(method):
        def fn(frames, t):
            data = bracket_data(frames, t, 8, bloom_radius=0, border=0)["L"]
            return method(data).g
        return fn

    return {"ccdcore Tsin sec. 3.2": run(estimate),
            "ccdcore sec. 3.2 + white balance": run(lambda d: estimate(
                d, TsinOptions(white_balance=True, max_iter=80))),
            "ccdcore sec. 3.2 as printed": run(lambda d: estimate(d, TsinOptions(pools="paper"))),
            "ccdcore Debevec": run(debevec), "ccdcore Robertson": run(robertson),
            "ccdcore Mitsunaga-Nayar": run(mitsunaga_nayar)}


def colour_methods() -> dict[str, Callable]:
    from types import SimpleNamespace

    import colour_hdri

    def fn(frames, t):
        data = np.stack([np.repeat((f / 255.0)[..., None], 3, axis=2) for f in frames], axis=-1)
        n = len(frames)
        stack = SimpleNamespace(data=data, f_number=np.ones(n), exposure_time=np.asarray(t),
                                iso=np.full(n, 100.0))
        crf = colour_hdri.camera_response_functions_Debevec1997(stack)
        return _fill_nan(np.asarray(crf, np.float64)[:, 1])

    return {"colour-hdri Debevec 1997": fn}


def study(n: int, white_balance: bool, methods: dict[str, Callable]) -> None:
    errors: dict[str, list[np.ndarray]] = {m: [] for m in methods}
    inside: list[float] = []
    rms: dict[str, list[float]] = {m: [] for m in methods}
    times: dict[str, list[float]] = {m: [] for m in methods}
    for s in range(n):
        frames, t, g_true = sequence(1000 + s, white_balance)
        for name, fn in methods.items():
            t0 = time.perf_counter()
            g = fn(frames, t)
            times[name].append(time.perf_counter() - t0)
            if name == "ccdcore Tsin sec. 3.2" and not white_balance:
                data = bracket_data(frames, t, 8, bloom_radius=0, border=0)["L"]
                r = estimate(data)
                codes = np.r_[10:230, 231:246]
                err = (aligned(r.g, g_true) - g_true)[codes]
                inside.append(float(np.mean(np.abs(err) <= 2 * r.g_err[codes])))
            off = name in FREE_OFFSET          # its g has a free offset: fitted too
            errors[name].append(aligned(g, g_true, offset=off) - g_true)
            rms[name].append(rms_error(g, g_true, offset=off))
    label = "with white balance" if white_balance else "without white balance"
    print(f"{n} sequences {label}")
    print(f"{'method':26s} {'RMS error median (min–max)':>30s} {'s per sequence':>22s}")
    for name in methods:
        r = _report.summary(rms[name])
        print(f"{name:26s} {r.format('.2e'):>30s} {_report.summary(times[name]).format():>22s}")
    print("bias (mean over sequences) / spread (std over sequences) per band of codes, x1e-3:")
    print(f"{'method':26s} " + " ".join(f"{f'{lo}-{hi}':>12s}" for lo, hi in BANDS))
    for name in methods:
        e = np.stack(errors[name])
        cells = []
        for lo, hi in BANDS:
            band = e[:, lo:hi + 1]
            bias = float(np.sqrt(np.mean(band.mean(axis=0) ** 2))) * 1e3
            spread = float(np.sqrt(np.mean(band.std(axis=0) ** 2))) * 1e3
            cells.append(f"{bias:5.2f}/{spread:5.2f}")
        print(f"{name:26s} " + " ".join(f"{c:>12s}" for c in cells))
    if inside:
        print(f"sec. 3.2 band: {100 * np.mean(inside):.0f} % of codes 10..245 within ±2σ "
              f"(range {100 * min(inside):.0f}-{100 * max(inside):.0f} % over the sequences)")
    print()


def merge_timing(repeat: int = 5) -> None:
    """The HDR merge (with sigma) against OpenCV's MergeDebevec, both with the true response."""
    import cv2

    frames, t, g_true = sequence(4242, False)
    model = ResponseModel(g_true, np.asarray(t), np.zeros(len(t)), 0.015, 0.01, 1.0)
    imgs = [np.repeat(f[..., None], 3, axis=2) for f in frames]
    crf = np.repeat(np.maximum(g_true, 1e-6).astype(np.float32)[:, None, None], 3, axis=2)
    merger = cv2.createMergeDebevec()
    ours, theirs = [], []
    for _ in range(repeat + 1):
        t0 = time.perf_counter()
        merge(frames, model, bloom_radius=0)
        ours.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        merger.process(imgs, np.asarray(t, np.float32), crf)
        theirs.append(time.perf_counter() - t0)
    print(f"HDR merge of one 256² × 8 sequence (median of {repeat} after one warm-up):")
    print(f"  ccdcore merge (radiance, sigma, flags; eqs. 9, 18, 19)  "
          f"{_report.summary(ours[1:]).format()} s")
    print(f"  OpenCV MergeDebevec (radiance, 3 channels)             "
          f"{_report.summary(theirs[1:]).format()} s")


def rgb_timing() -> None:
    """A real-sized colour bracket: 640×480 RGB, 16 exposures a factor √2 apart (the issue's
    "several hundred thousand pixels and 16 exposures"), every channel by sec. 3.2."""
    import tracemalloc

    from ccdcore.response.methods import response_of

    rng = np.random.default_rng(16)
    E = tsin.uniform_radiance(rng, (480, 640, 3))
    t = np.asarray(tsin.exposure_times(16, math.sqrt(2.0), math.sqrt(2.0)))
    frames = [tsin.expose(E, t[k], 0.0, rng).z for k in range(t.size)]
    t0 = time.perf_counter()
    tracemalloc.start()
    brackets = bracket_data(frames, t, 8, layout="rgb")
    res = response_of(brackets, "tsin")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    dt = time.perf_counter() - t0
    g_true = np.asarray(tsin.response_table(1.2))
    errs = ", ".join(f"{c} {rms_error(res[c].g, g_true):.1e}" for c in res.channels)
    print(f"640×480 RGB × 16 exposures (blooming mask on): {dt:.1f} s for the three channels, "
          f"peak traced memory {peak / 2**20:.0f} MB; RMS error {errs}")
    print(f"  notes: {'; '.join(res[res.channels[0]].notes)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sequences", type=int, default=50)
    ap.add_argument("--study", choices=("both", "plain", "white-balance"), default="both",
                    help="which study to run (default both), then the timings")
    args = ap.parse_args()
    _report.header(__file__, args.sequences, warmup=0,
                   note="bias per band: RMS over the band's codes of the mean error; spread: "
                        "RMS over the codes of the standard deviation over the sequences")
    methods = {**our_methods(), **opencv_methods(), **colour_methods()}
    frames, t, _ = sequence(999, False)                # warm-up (numba caches, imports)
    for fn in methods.values():
        fn(frames, t)
    for wb in (False, True):
        if args.study == "both" or args.study == ("white-balance" if wb else "plain"):
            study(args.sequences, wb, methods)
    merge_timing()
    rgb_timing()
    _report.footer()


if __name__ == "__main__":
    main()
