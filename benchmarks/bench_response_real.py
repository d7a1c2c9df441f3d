"""Response curves of real exposure brackets: every ccdcore method against OpenCV's.

For every bracket (a session folder with ``role = "bracket"`` frames and their exposures), the
default (``auto``: the bracket's own exposures where the listed ones are wrong, sec. 3.2 unless
Debevec's curve predicts clearly better) and every method of
:data:`ccdcore.response.methods.METHODS` (``tsin``, also with ``--white-balance``,
``debevec``, ``robertson``, ``mitsunaga-nayar``; each with the default exposures) are run
through :func:`ccdcore.response.methods.response_of`, and OpenCV's ``CalibrateDebevec`` and
``CalibrateRobertson`` (defaults; the listed exposures, which OpenCV takes as exact) on the same
files. Real brackets have no true curve: each
result is judged by the prediction agreement of Tsin, Ramesh & Kanade (2001), sec. 4.2
(:mod:`ccdcore.response.agreement`): every image predicted from its neighbours through the curve
and the exposure ratio, RMS in DN over codes 10..245, pooled over the channels --

``RMS nominal``  with the result's own exposures (the nominal times for every method but
                 ``tsin --white-balance``, which estimates them);
``RMS fitted``   with each pair's ratio fitted (what remains is the curve's shape);
``RMS blend``    each image predicted from the blend of all the others.

OpenCV's curves (BGR, codes 0..255; Robertson's codes without data, NaN, interpolated) enter the
same agreement as ``g`` per channel with ``a`` = the nominal times and ``b`` = 0.

Times (wall, s):

``curve``        the estimator alone, every channel: the classic functions of
                 :mod:`ccdcore.response.classic` (median and range of ``--repeat`` runs after a
                 warm-up), OpenCV's ``process`` (idem); for ``tsin``, whose band and noise terms
                 come with the estimate, the ``response_of`` time minus the agreement's (idem);
``+ read``       the same plus reading the bracket: ccdcore's ``open_session`` + ``load_bracket``
                 (one run per bracket, shared by all ccdcore methods: border and blooming masks
                 included), OpenCV's ``imread`` of the files (every run);
``response_of``  the whole of ``response_of`` (one run): for the classic methods the curve, its
                 jackknife band (8 refits), the noise terms of eq. 17 and the agreement.

``peak MB``: the peak resident memory above the level before the run (Linux: the process's
high-water mark reset through /proc/self/clear_refs; elsewhere tracemalloc's peak, numpy
allocations only), during the first ``response_of`` for ccdcore and during the first imread +
process for OpenCV (later runs reuse memory the allocators kept).

Every method runs on every bracket in a fresh child process (which reads the bracket again):
its memory is its own, and a method that fails, crashes or outlasts ``--timeout`` prints its
error in its row while the others still run.

    .venv/bin/python benchmarks/bench_response_real.py                     # ../shared/data/brackets/*
    .venv/bin/python benchmarks/bench_response_real.py path/to/bracket ... # given session folders
    .venv/bin/python benchmarks/bench_response_real.py --methods debevec,robertson,opencv \\
        --json /tmp/real.json

The real brackets are not part of the project: by default they are read from
``../shared/data/brackets`` next to the repository (every sub-folder holding a session.toml);
when that folder is absent the script says so and exits 0.
"""
from __future__ import annotations

import argparse
import gc
import json
import math
import re
import subprocess
import sys
import time
import traceback
import tracemalloc
from pathlib import Path
from typing import Any, Callable

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))
import _report  # noqa: E402

from ccdcore.response import classic  # noqa: E402
from ccdcore.response.agreement import agreement  # noqa: E402
from ccdcore.response.brackets import bracket_records, load_bracket  # noqa: E402
from ccdcore.response.methods import AUTO, METHODS, response_of  # noqa: E402
from ccdcore.session import open_session  # noqa: E402

#: the shared real data, next to the repository (not part of the project)
DATA = ROOT.parent / "shared" / "data" / "brackets"
#: the estimator alone of each classic method (timed apart from response_of's band and noise)
CLASSIC: dict[str, Callable[..., Any]] = {"debevec": classic.debevec,
                                          "robertson": classic.robertson,
                                          "mitsunaga-nayar": classic.mitsunaga_nayar}
OPENCV = {"opencv-debevec": "OpenCV CalibrateDebevec",
          "opencv-robertson": "OpenCV CalibrateRobertson"}
#: OpenCV's channel order (imread: BGR; a grey frame read as three equal channels)
CV_CHANNEL = {"B": 0, "G": 1, "R": 2, "L": 0}


# -------------------------------------------------------------------------------- methods --
def ours() -> dict[str, tuple[str, bool]]:
    """Selectable ccdcore variants: key -> (method name, white balance)."""
    out: dict[str, tuple[str, bool]] = {AUTO: (AUTO, False)}
    for name, m in METHODS.items():
        out[name] = (name, False)
        if m.white_balance:
            out[f"{name}-wb"] = (name, True)
    return out


def label(key: str) -> str:
    if key in OPENCV:
        return OPENCV[key]
    name, wb = ours()[key]
    if name == AUTO:
        return "ccdcore response (default)"
    return f"ccdcore --method {name}" + (" --white-balance" if wb else "")


def choose(text: str | None) -> list[str]:
    """The variants named in ``--methods`` (comma-separated; ``opencv`` = both OpenCV ones,
    ``ours`` = every ccdcore one), in the table's order."""
    every = list(ours()) + list(OPENCV)
    if not text:
        return every
    want: set[str] = set()
    for item in (s.strip() for s in text.split(",")):
        if not item:
            continue
        if item == "opencv":
            want.update(OPENCV)
        elif item == "ours":
            want.update(ours())
        elif item in every:
            want.add(item)
        else:
            raise SystemExit(f"--methods: unknown method {item!r}; choose among "
                             f"{', '.join(every)}, opencv, ours")
    return [k for k in every if k in want]


# ------------------------------------------------------------------------------ measuring --
def _status_mb(field: str) -> float:
    text = Path("/proc/self/status").read_text()
    m = re.search(rf"^{field}:\s+(\d+)\s+kB", text, re.MULTILINE)
    if m is None:
        raise OSError(f"no {field} in /proc/self/status")
    return int(m.group(1)) / 1024


def _malloc_trim() -> None:
    """Hand the memory freed so far back to the system (glibc), so that a block's peak is not
    hidden by memory the allocator kept from earlier work."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


class PeakMemory:
    """Peak memory (MB) of a block above the level at its start: the resident high-water mark
    reset through /proc/self/clear_refs (Linux), else tracemalloc's peak."""

    def __enter__(self) -> "PeakMemory":
        gc.collect()
        _malloc_trim()
        self.mb = float("nan")
        try:
            with open("/proc/self/clear_refs", "w") as f:
                f.write("5")                          # resets VmHWM to the current RSS
            self.base = _status_mb("VmRSS")
            self.kind = "rss"
        except OSError:
            tracemalloc.start()
            self.kind = "traced"
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.kind == "rss":
            self.mb = _status_mb("VmHWM") - self.base
        else:
            self.mb = tracemalloc.get_traced_memory()[1] / 2 ** 20
            tracemalloc.stop()


def _fill_nan(curve: np.ndarray) -> np.ndarray:
    """OpenCV's curve with its codes without data (NaN) interpolated."""
    ok = np.isfinite(curve)
    if not ok.any():
        raise ValueError("OpenCV's curve has no finite value")
    z = np.arange(curve.size)
    return np.interp(z, z[ok], curve[ok])


def _figures(agree: Any) -> dict[str, Any]:
    return {"rms": agree.rms, "rms_fitted": agree.rms_fitted, "rms_blend": agree.rms_blend,
            "agreement": agree.to_dict()}


def run_ours(key: str, brackets: dict, repeat: int) -> dict[str, Any]:
    name, wb = ours()[key]
    rec: dict[str, Any] = {"method": key, "label": label(key), "error": None}
    try:
        with PeakMemory() as mem:
            t0 = time.perf_counter()
            res = (response_of(brackets, name, white_balance=True) if wb
                   else response_of(brackets, name))
            total = time.perf_counter() - t0
        t0 = time.perf_counter()
        agree = agreement(brackets, res.models())
        t_agree = time.perf_counter() - t0
        if res.agreement is not None:
            agree = res.agreement
        rec.update(_figures(agree))
        rec.update(kept=res.method, exposures=None if res.exposures is None
                   else res.exposures.used, verdict=res.verdict.status)
        rec.update(response_of_s=total, agreement_s=t_agree, peak_mb=mem.mb,
                   memory=mem.kind, iterations=[int(r.iterations) for r in res.responses],
                   converged=[bool(r.converged) for r in res.responses])
        if name in CLASSIC and not wb:
            fn = CLASSIC[name]
            times = []
            for _ in range(repeat):
                t0 = time.perf_counter()
                for data in brackets.values():
                    fn(data)
                times.append(time.perf_counter() - t0)
            rec.update(curve_s=times, curve="the estimator alone")
        else:
            # the first run above is the warm-up (it loads the numba kernels from their
            # cache): the timed runs follow, as for every other estimator
            times = []
            for _ in range(repeat):
                t0 = time.perf_counter()
                (response_of(brackets, name, white_balance=True) if wb
                 else response_of(brackets, name))
                times.append(time.perf_counter() - t0 - t_agree)
            rec.update(curve_s=times, curve="response_of minus the agreement")
    except Exception as e:                            # one failing method: its row says why
        rec.update(error=f"{type(e).__name__}: {e}", traceback=traceback.format_exc())
    return rec


def run_opencv(key: str, brackets: dict, paths: list[str], t: np.ndarray, bits: int | None,
               repeat: int) -> dict[str, Any]:
    rec: dict[str, Any] = {"method": key, "label": label(key), "error": None}
    try:
        import cv2

        if bits != 8:
            raise ValueError(f"OpenCV's calibration takes 8-bit images only; this bracket has "
                             f"{bits} bits")
        missing = [ch for ch in brackets if ch not in CV_CHANNEL]
        if missing:
            raise ValueError(f"channels {', '.join(missing)} have no OpenCV counterpart "
                             "(grey or RGB frames only)")
        make = cv2.createCalibrateDebevec if key == "opencv-debevec" else \
            cv2.createCalibrateRobertson
        times32 = np.asarray(t, np.float32)

        def once() -> tuple[float, float, Any]:
            t0 = time.perf_counter()
            imgs = [cv2.imread(p, cv2.IMREAD_COLOR) for p in paths]
            t1 = time.perf_counter()
            bad = [p for p, im in zip(paths, imgs) if im is None]
            if bad:
                raise ValueError(f"OpenCV cannot read {bad[0]}")
            resp = make().process(imgs, times32)
            return t1 - t0, time.perf_counter() - t1, resp

        # the cold run gives the peak memory (later runs reuse the memory the allocators
        # kept); its time is discarded (warm-up)
        with PeakMemory() as mem:
            once()
        reads, procs = [], []
        for _ in range(repeat):
            t_read, t_proc, resp = once()
            reads.append(t_read)
            procs.append(t_proc)
        curves = np.asarray(resp, np.float64).reshape(-1, 3)
        models = {}
        for ch, data in brackets.items():
            g = _fill_nan(curves[:, CV_CHANNEL[ch]])
            if g.size != data.levels:
                raise ValueError(f"OpenCV's curve has {g.size} codes, the bracket "
                                 f"{data.levels}")
            models[ch] = {"g": g, "a": np.asarray(data.t, np.float64),
                          "b": np.zeros(data.n_images)}
        rec.update(_figures(agreement(brackets, models)))
        rec.update(curve_s=procs, read_s=reads, with_read_s=[a + b for a, b in zip(reads, procs)],
                   peak_mb=mem.mb, memory=mem.kind, curve="process() alone")
    except Exception as e:
        rec.update(error=f"{type(e).__name__}: {e}", traceback=traceback.format_exc())
    return rec


# -------------------------------------------------------------------------------- the table --
COLUMNS = (f"{'method':34s} {'RMS nominal':>11s} {'RMS fitted':>10s} {'RMS blend':>9s} "
           f"{'curve s':>22s} {'+ read s':>8s} {'response_of s':>13s} {'peak MB':>7s}")


def _f(v: Any, fmt: str, width: int) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return f"{'—':>{width}s}"
    return f"{v:{width}{fmt}}"


def row(rec: dict[str, Any], load_s: float | None) -> str:
    name = rec["label"]
    if rec.get("error"):
        msg = rec["error"].replace("\n", " ")
        if len(msg) > 140:
            msg = msg[:137] + "..."
        return f"{name:34s} error: {msg}"
    curve = _report.summary(rec["curve_s"])
    curve_txt = (curve.format(".3f") if curve.n > 1 else f"{curve.median:.3f}")
    if "with_read_s" in rec:
        with_read = _report.summary(rec["with_read_s"]).median
    else:
        with_read = curve.median + load_s if load_s is not None else None
    tail = (f"  [{rec['kept']}, exposures {rec['exposures'] or 'listed'}, {rec['verdict']}]"
            if "verdict" in rec else "")
    return (f"{name:34s} {_f(rec['rms'], '.3f', 11)} {_f(rec['rms_fitted'], '.3f', 10)} "
            f"{_f(rec['rms_blend'], '.3f', 9)} {curve_txt:>22s} {_f(with_read, '.3f', 8)} "
            f"{_f(rec.get('response_of_s'), '.2f', 13)} {_f(rec.get('peak_mb'), '.0f', 7)}"
            + tail)


# ------------------------------------------------------------------------------- brackets --
def bracket_folders(given: list[str]) -> list[Path]:
    if given:
        return [Path(p) for p in given]
    if not DATA.is_dir():
        return []
    return sorted(p for p in DATA.iterdir() if (p / "session.toml").is_file())


def child(key: str, folder: Path, repeat: int) -> None:
    """One method on one bracket, in this (child) process: the record as the last line."""
    try:
        session = open_session(folder)
        brackets = load_bracket(session)
        paths = [str(r.path) for r in bracket_records(session)]
    except Exception as e:
        rec = {"method": key, "label": label(key), "error": f"{type(e).__name__}: {e}",
               "traceback": traceback.format_exc()}
    else:
        first = next(iter(brackets.values()))
        if key in OPENCV:
            rec = run_opencv(key, brackets, paths, first.t, session.camera.bits, repeat)
        else:
            rec = run_ours(key, brackets, repeat)
    print(json.dumps(_clean(rec), default=_json_default))


def run_child(key: str, folder: Path, repeat: int, timeout: float) -> dict[str, Any]:
    """``child`` in a fresh process: its own peak memory, and a crash or a hang of one method
    (``timeout`` s) costs only its row."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", key, str(folder),
           "--repeat", str(repeat)]
    base = {"method": key, "label": label(key)}
    try:
        proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        return {**base, "error": f"timed out after {timeout:g} s (--timeout)"}
    lines = proc.stdout.strip().splitlines()
    try:
        return json.loads(lines[-1])
    except (IndexError, json.JSONDecodeError):
        tail = " | ".join(proc.stderr.strip().splitlines()[-3:])
        return {**base, "error": f"the run exited with status {proc.returncode}: {tail}",
                "stderr": proc.stderr[-4000:]}


def bench_bracket(folder: Path, keys: list[str], repeat: int, timeout: float
                  ) -> dict[str, Any]:
    out: dict[str, Any] = {"name": folder.name, "path": str(folder), "methods": []}
    print(f"== bracket {folder.name} ({folder})")
    t0 = time.perf_counter()
    try:
        session = open_session(folder)
        brackets = load_bracket(session)
        records = bracket_records(session)          # checked here, read again by the runs
    except Exception as e:
        out["error"] = f"{type(e).__name__}: {e}"
        print(f"   cannot load the bracket: {out['error']}\n")
        return out
    load_s = time.perf_counter() - t0
    first = next(iter(brackets.values()))
    h, w = first.shape
    bits = session.camera.bits
    out.update(images=first.n_images, shape=[int(h), int(w)], channels=list(brackets),
               bits=bits, exposures=[float(x) for x in first.t], load_s=load_s)
    print(f"   {first.n_images} images {w}×{h}, channels {', '.join(brackets)}, {bits} bits, "
          f"exposures {float(first.t[0]):g} .. {float(first.t[-1]):g}; open_session + "
          f"load_bracket {load_s:.2f} s")
    print(COLUMNS)
    sys.stdout.flush()
    del brackets, records
    for key in keys:
        rec = run_child(key, folder, repeat, timeout)
        out["methods"].append(rec)
        print(row(rec, load_s))
        sys.stdout.flush()
    print()
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folders", nargs="*",
                    help=f"bracket session folders (default: every sub-folder of {DATA} "
                         "holding a session.toml)")
    ap.add_argument("--methods", default=None,
                    help="comma-separated subset of: " + ", ".join(list(ours()) + list(OPENCV))
                         + "; 'opencv' = both OpenCV methods, 'ours' = every ccdcore one "
                           "(default: all)")
    ap.add_argument("--repeat", type=int, default=3,
                    help="timed runs of each estimator alone and of OpenCV, after one warm-up "
                         "(default 3)")
    ap.add_argument("--timeout", type=float, default=3600.0,
                    help="seconds one method may take on one bracket (default 3600)")
    ap.add_argument("--json", metavar="OUT", default=None, help="save every figure to OUT")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    repeat = max(int(args.repeat), 1)
    if args.child:                                    # one method, one bracket (internal)
        child(args.child, Path(args.folders[0]), repeat)
        return 0
    keys = choose(args.methods)
    folders = bracket_folders(args.folders)
    if not folders:
        if args.folders:
            print("no bracket folder given")
        else:
            print(f"no real brackets: {DATA} is absent or holds no session folder (the shared "
                  "data are not part of the project); nothing to benchmark")
        return 0
    _report.header(__file__, repeat, warmup=1,
                   note="agreement of Tsin et al. sec. 4.2 in DN, pooled over the channels; "
                        "curve s: median (min–max) of the estimator alone; + read s: with "
                        "reading the bracket; response_of s: one run of the whole pipeline "
                        "(band, noise terms, agreement); peak MB: resident memory above the "
                        "level before the run")
    results = []
    for folder in folders:
        if not folder.exists():
            print(f"== bracket {folder}: not found, skipped\n")
            results.append({"name": folder.name, "path": str(folder), "error": "not found"})
            continue
        results.append(bench_bracket(folder, keys, repeat, args.timeout))
    failed = [f"{b['name']}: {m['label']}" for b in results for m in b.get("methods", [])
              if m.get("error")]
    if failed:
        print(f"{len(failed)} method run(s) failed: {'; '.join(failed)}")
    if args.json:
        doc = {"script": Path(__file__).name, "machine": _report.machine(),
               "date": _report.today(), "repeat": repeat, "methods": keys,
               "brackets": results}
        Path(args.json).write_text(json.dumps(_clean(doc), indent=1, default=_json_default))
        print(f"figures saved to {args.json}")
    _report.footer()
    return 0


def _clean(v: Any) -> Any:
    """Non-finite numbers as null (strict JSON)."""
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    return v


def _json_default(v: Any) -> Any:
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return str(v)


if __name__ == "__main__":
    sys.exit(main())
