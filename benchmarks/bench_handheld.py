"""Handheld and moving brackets, end to end: frames aligned before the merge, moving objects
found by the noise model -- ``ccdcore hdr`` against OpenCV's AlignMTB + MergeDebevec.

Data
----
* **Simulated** (known truth), written to a temporary folder by
  ``ccdcore.simulate.simulate("tsin01-camera", out, seed=S, size=(512, 384), ...)`` (the camera
  model: Bayer, sRGB-like tone with a knee, vignetting, sharpening, JPEG; 10 exposures one stop
  apart, the listed times off by about 3 %), in a child process:

  - ``handheld+mover sN``: ``handheld_shift=3.0, handheld_rotation=0.2, movers=1`` for each seed
    of ``--seeds`` (default 1, 2): every frame but the middle one shifted by ~N(0, 3) px and
    turned by ~N(0, 0.2) degrees about the centre, one ellipse walking 12 px per frame;
  - ``movers only``: ``movers=1``, no shake (tripod with a walker);
  - ``tripod``: no handheld option (nothing moves: every flagged pixel is a false alarm).

  Truth (``truth.json``, ``truth/``): ``transforms`` (per frame file ``dx, dy, rotation_deg`` in
  the aligner's convention, ``aligned(p) = frame(c + R(theta)(p - c) + (dx, dy))``), the radiance
  the reference frame records without movers (``truth/E_effective.exr``, the key
  ``radiance_map``: the scene with vignetting, through the Bayer mosaic and its interpolation;
  ``truth/E.exr`` before the mosaic), ``truth/moving_mask.npy`` (H, W: the union over the frames
  of the movers in the reference grid, where the aligned exposures disagree) and
  ``truth/movers.npy`` (per frame, its own grid).
* **Real** brackets: every session folder under ``../shared/data/brackets`` (``taipei``,
  ``desktop``, ``living_room1``: Nikon, 8-bit PNG; ``living_room1`` is measurably handheld,
  frames shifted by up to about 1 px). No truth. When the folder is absent the script says so
  and runs the simulated group only (exit 0).

Methods (each in a fresh process, end to end: start, reading, fitting, merging, writing; wall
time and peak resident memory (``ru_maxrss``) of that process from ``os.wait4``)
------------------------------------------------------------------------------------------------
* ``ccdcore hdr``: ``ccdcore hdr SESSION -o OUT --json`` (registration, response fitted on the
  aligned frames with the suspect pixels left out, merge, moving pixels merged from one exposure:
  flag 4 in ``flags.png``);
* ``ccdcore hdr --align off``: the same without registration;
* ``OpenCV MTB+Debevec``: a short script (``python -c``) that reads the frames with
  ``cv2.imread`` (BGR uint8), sorts them by exposure, ``cv2.createAlignMTB(cut=False).process``
  (Ward's median threshold bitmaps, integer shifts onto the middle frame; ``cut=False`` keeps
  the reference's pixel grid, the uncovered border filled with 0; the output list is a copy of
  the input, since OpenCV assigns the pivot frame's header rather than writing into a
  pre-allocated array), ``cv2.createCalibrateDebevec().process`` and
  ``cv2.createMergeDebevec().process`` with the listed times (float32), ``np.save`` of the
  result (RGB);
* ``OpenCV Debevec``: the same without AlignMTB.

Metrics
-------
Every image measure leaves out a border of :data:`BORDER` px (the strip an aligned frame does
not cover; OpenCV fills it with 0, ccdcore with a reflection). Non-finite radiance (OpenCV's
MergeDebevec can return inf/nan) and radiance <= 0 in some channel (ccdcore's merge can return
it for dark codes: ``(g(z) - b) / a``) are masked, and counted in the notes.

* ``edge r ref``: the issue's measure -- the Pearson correlation between the gradient magnitude
  (``np.gradient``) of the tone-mapped log radiance (``log`` of the luminance 0.2126 R + 0.7152 G
  + 0.0722 B, scaled linearly to 0..1, not clipped: clipping at percentiles flattens the lights
  of a night scene, whose edges are the strongest) and the gradient
  magnitude of the reference (middle) frame's luminance in codes, over the pixels not clipped in
  the reference (no channel at 255, not every channel at 0). A ghost or a blur lowers it; the
  two tone curves differ, so even a perfect merge stays below 1.
* ``edge r truth`` (simulated): the same correlation against the true radiance's tone-mapped log
  luminance, over the static pixels (outside ``moving_mask``).
* ``shift err px`` (simulated): ``|(dx, dy) estimated - true|`` per frame other than the
  reference, median / max and [how many beyond 1 px]: ccdcore from ``--json``
  ``registration.shifts`` (frames it could not register are not counted; the notes name them),
  OpenCV's from ``AlignMTB.calculateShift`` of each frame's grey image against the middle one's
  (what ``process`` applies; integer shifts, no rotation; its sign flipped to the convention
  above), recomputed after the timed runs. For the unaligned variants the cell, in parentheses,
  is the error of assuming no motion (the true shifts' size). ``rot err`` the largest
  ``|rotation - true|`` in degrees (OpenCV has no rotation). ``left out``: frames dropped from
  ccdcore's merge (``--json`` ``frames``; a frame that cannot be registered is dropped when
  others moved, kept when none did).
* ``moving recall`` / ``flagged outside`` (ccdcore): the fraction of ``moving_mask`` flagged 4
  and the fraction of the rest of the frame flagged 4 (for the tripod: every flagged pixel).
* ``ghost |dlog E|`` / ``static |dlog E|`` (simulated): ``|log(E / (k E_true))|``, median (90th
  percentile), per channel ``k`` = the median ratio ``E / E_true`` over the static pixels (the
  radiance is on each method's own scale); ghost = ``moving_mask`` minus the pixels the mover
  covers in the reference frame (``movers.npy[ref]``: there the reference shows the mover and
  the static truth does not apply); static = outside ``moving_mask``.
* real brackets: ``edge r ref``; ``max shift px`` the largest registered shift (ccdcore: of the
  frames it resampled, with their count; OpenCV: of ``calculateShift``, with the count of frames
  shifted at all); ``flagged moving`` the fraction of the frame flagged 4 (no truth: false
  alarms plus whatever did move between the exposures).
* ``time s``, ``peak MB``: one run each (a busy 2-core machine: one run, no repeat, to keep the
  whole script near 10 minutes), of the whole process.

Memory: on Linux a child started by ``subprocess`` inherits the launcher's high-water mark as
the floor of its ``ru_maxrss``; the launcher therefore writes the simulations in child processes
and reads no image until every timed run is done; the footer prints its peak.

Run::

    .venv/bin/python benchmarks/bench_handheld.py                      # everything (~8-10 min)
    .venv/bin/python benchmarks/bench_handheld.py --seeds 1 --no-real  # quicker
    .venv/bin/python benchmarks/bench_handheld.py --json /tmp/handheld.json --keep /tmp/hh

Prints one markdown table per group (simulated, real) and a few notes.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))
import _report  # noqa: E402

#: the shared real data, next to the repository (not part of the project)
DATA = Path(os.environ.get("CCDCORE_SHARED", str(ROOT.parent / "shared"))) / "data" / "brackets"
#: pixels at each side left out of every image measure (the strip aligned frames do not cover)
BORDER = 12
#: simulated frame size (W, H)
SIZE = (512, 384)
HANDHELD = {"handheld_shift": 3.0, "handheld_rotation": 0.2}
METHODS = ("ccdcore", "ccdcore-noalign", "opencv-mtb", "opencv")
LABELS = {"ccdcore": "ccdcore hdr", "ccdcore-noalign": "ccdcore hdr --align off",
          "opencv-mtb": "OpenCV MTB+Debevec", "opencv": "OpenCV Debevec"}

#: the peer's own short script (``python -c``): argv = out.npy, align (0/1), JSON [[path, t]...]
OPENCV_SCRIPT = r"""
import json, sys
import numpy as np
import cv2
out, align, pairs = sys.argv[1], sys.argv[2] == "1", json.loads(sys.argv[3])
pairs.sort(key=lambda p: p[1])
imgs = [cv2.imread(p, cv2.IMREAD_COLOR) for p, _ in pairs]
bad = [p for (p, _), im in zip(pairs, imgs) if im is None]
if bad:
    raise SystemExit("OpenCV cannot read " + bad[0])
times = np.asarray([t for _, t in pairs], np.float32)
if align:
    aligned = [im.copy() for im in imgs]   # the pivot is assigned, not written: keep a copy
    cv2.createAlignMTB(cut=False).process(imgs, aligned)
    imgs = aligned
resp = cv2.createCalibrateDebevec().process(imgs, times)
hdr = cv2.createMergeDebevec().process(imgs, times, resp)
np.save(out, np.ascontiguousarray(hdr[..., ::-1], dtype=np.float32))
"""

SIMULATE_SCRIPT = r"""
import json, sys
from ccdcore.simulate import simulate
out, seed, w, h, opts = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), \
    json.loads(sys.argv[5])
simulate("tsin01-camera", out, seed=seed, size=(w, h), **opts)
"""


# ------------------------------------------------------------------------------ the cases --
@dataclass
class Case:
    group: str                       # "simulated" or "real"
    name: str
    session: Path
    frames: list[tuple[str, float]]  # (absolute path, listed exposure), increasing exposure
    relpaths: list[str]
    truth: dict | None = None
    runs: dict[str, dict] = field(default_factory=dict)
    error: str | None = None

    @property
    def reference(self) -> int:
        return len(self.frames) // 2


def read_case(group: str, name: str, session: Path) -> Case:
    """The bracket of a session folder from its manifest (no image read: see the module's notes
    on memory)."""
    doc = tomllib.loads((session / "session.toml").read_text())
    recs = [f for f in doc.get("frames", []) if f.get("role", "bracket") == "bracket"]
    stacks = sorted({f.get("stack", 0) for f in recs})
    recs = [f for f in recs if f.get("stack", 0) == stacks[0]]
    recs.sort(key=lambda f: float(f["exposure"]))
    truth = None
    if (session / "truth.json").is_file():
        truth = json.loads((session / "truth.json").read_text())
    return Case(group, name, session, [(str(session / f["path"]), float(f["exposure"]))
                                       for f in recs], [f["path"] for f in recs], truth)


def simulated_cases(tmp: Path, seeds: list[int], size: tuple[int, int]) -> list[Case]:
    plan = [(f"handheld+mover s{s}", s, {**HANDHELD, "movers": 1}) for s in seeds]
    plan += [(f"movers only s{seeds[0]}", seeds[0], {"movers": 1}),
             (f"tripod s{seeds[0]}", seeds[0], {})]
    cases = []
    for name, seed, opts in plan:
        out = tmp / name.replace(" ", "_").replace("+", "_")
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-c", SIMULATE_SCRIPT, str(out), str(seed),
                               str(size[0]), str(size[1]), json.dumps(opts)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        if proc.returncode != 0:
            c = Case("simulated", name, out, [], [])
            c.error = "simulate failed: " + " | ".join(proc.stderr.strip().splitlines()[-3:])
            cases.append(c)
            continue
        print(f"   simulated {name} ({size[0]}x{size[1]}, {opts or 'no option'}) in "
              f"{time.perf_counter() - t0:.1f} s")
        sys.stdout.flush()
        cases.append(read_case("simulated", name, out))
    return cases


def real_cases(folders: list[Path]) -> list[Case]:
    return [read_case("real", f.name, f) for f in folders]


# ------------------------------------------------------------------------------- the runs --
def run_process(cmd: list[str], log: Path, timeout: float) -> dict[str, Any]:
    """``cmd`` in a fresh process (stdout and stderr to files next to ``log``): its wall time,
    peak RSS (``os.wait4``), exit status, stdout; killed after ``timeout`` s."""
    out_path, err_path = log.with_suffix(".out"), log.with_suffix(".err")
    with open(out_path, "wb") as fo, open(err_path, "wb") as fe:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=fo, stderr=fe)
        timed_out = False
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() - t0 > timeout:
                os.kill(proc.pid, signal.SIGKILL)
                pid, status, usage = os.wait4(proc.pid, 0)
                timed_out = True
                break
            time.sleep(0.02)
        wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)   # reaped here, not by Popen
    stdout = out_path.read_text(errors="replace")
    err = None
    if timed_out:
        err = f"timed out after {timeout:g} s"
    elif proc.returncode != 0:
        tail = err_path.read_text(errors="replace").strip().splitlines()[-3:]
        err = f"exit status {proc.returncode}: " + " | ".join(tail)
    return {"time_s": wall, "peak_mb": usage.ru_maxrss / 1024.0, "error": err,
            "stdout": stdout}


def run_case(case: Case, work: Path, timeout: float) -> None:
    ccd = shutil.which("ccdcore", path=str(Path(sys.executable).parent)) or \
        shutil.which("ccdcore") or "ccdcore"
    base = work / (case.group + "_" + case.name.replace(" ", "_").replace("+", "_"))
    base.mkdir(parents=True, exist_ok=True)
    for key in METHODS:
        out = base / key
        out.mkdir(exist_ok=True)
        if key.startswith("ccdcore"):
            cmd = [ccd, "hdr", str(case.session), "-o", str(out), "--json"]
            if key == "ccdcore-noalign":
                cmd += ["--align", "off"]
        else:
            cmd = [sys.executable, "-c", OPENCV_SCRIPT, str(out / "hdr.npy"),
                   "1" if key == "opencv-mtb" else "0", json.dumps(case.frames)]
        rec = run_process(cmd, out / "run", timeout)
        rec["out"] = str(out)
        if key.startswith("ccdcore") and rec["error"] is None:
            try:
                rec["json"] = json.loads(rec["stdout"])
            except json.JSONDecodeError as e:
                rec["error"] = f"no JSON from ccdcore hdr --json: {e}"
        rec.pop("stdout")
        case.runs[key] = rec
        state = rec["error"] or "ok"
        print(f"   {case.name:22s} {LABELS[key]:26s} {rec['time_s']:7.1f} s "
              f"{rec['peak_mb']:6.0f} MB  {state}")
        sys.stdout.flush()


# ---------------------------------------------------------------------------- the metrics --
def _luminance(rgb):
    import numpy as np

    rgb = np.asarray(rgb, np.float64)
    return 0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2]


def _tone_log(rgb):
    """The tone-mapped log luminance: log Y scaled linearly to 0..1 between its minimum and
    maximum (no clipping: a clip at percentiles flattens the lights of a night scene, whose
    edges are the strongest); NaN where the radiance is not finite and positive (every
    channel)."""
    import numpy as np

    Y = _luminance(rgb)
    ok = np.isfinite(Y) & np.all(np.isfinite(rgb), axis=-1) & np.all(rgb > 0, axis=-1)
    L = np.full(Y.shape, np.nan)
    L[ok] = np.log(Y[ok])
    if ok.sum() < 100:
        return L
    lo, hi = float(L[ok].min()), float(L[ok].max())
    return (L - lo) / max(hi - lo, 1e-12)


def _grad(a):
    import numpy as np

    gy, gx = np.gradient(np.asarray(a, np.float64))
    return np.hypot(gx, gy)


def _border_mask(shape):
    import numpy as np

    m = np.zeros(shape, bool)
    m[BORDER:shape[0] - BORDER, BORDER:shape[1] - BORDER] = True
    return m


def _corr(a, b, mask) -> float:
    import numpy as np

    sel = mask & np.isfinite(a) & np.isfinite(b)
    if sel.sum() < 100:
        return float("nan")
    x, y = a[sel], b[sel]
    x = x - x.mean()
    y = y - y.mean()
    d = math.sqrt(float((x * x).sum()) * float((y * y).sum()))
    return float((x * y).sum()) / d if d > 0 else float("nan")


def _read_radiance(key: str, out: Path):
    import numpy as np

    from ccdcore.io.frames import read_image

    if key.startswith("ccdcore"):
        rad = np.asarray(read_image(out / "radiance.exr"), np.float64)
        flags = np.asarray(read_image(out / "flags.png"))
        if flags.ndim == 3:
            flags = flags.max(axis=2)
        return rad, flags
    return np.asarray(np.load(out / "hdr.npy"), np.float64), None


def _mtb_shifts(case: Case) -> list[tuple[int, int]]:
    """OpenCV's integer shifts of every frame onto the middle one, in the convention
    ``aligned(x, y) = frame(x + dx, y + dy)`` (``calculateShift`` returns the motion that
    ``shiftMat`` applies to the frame: the opposite sign)."""
    import cv2

    mtb = cv2.createAlignMTB()
    imgs = [cv2.imread(p, cv2.IMREAD_COLOR) for p, _ in case.frames]
    ref = cv2.cvtColor(imgs[case.reference], cv2.COLOR_RGB2GRAY)   # as AlignMTB.process
    out = []
    for k, im in enumerate(imgs):
        if k == case.reference:
            out.append((0, 0))
            continue
        sx, sy = mtb.calculateShift(ref, cv2.cvtColor(im, cv2.COLOR_RGB2GRAY))
        out.append((-int(sx), -int(sy)))
    return out


def _true_transforms(case: Case) -> list[tuple[float, float, float]]:
    by_file = {t["file"]: t for t in (case.truth or {}).get("transforms", [])}
    return [(float(by_file[r]["dx"]), float(by_file[r]["dy"]), float(by_file[r]["rotation_deg"]))
            if r in by_file else (0.0, 0.0, 0.0) for r in case.relpaths]


def _estimated(case: Case, key: str, mtb: list[tuple[int, int]] | None
               ) -> list[tuple[float, float, float] | None] | None:
    """Per frame (bracket order) the estimated (dx, dy, rotation), ``None`` for a frame left
    out; ``None`` when the run has no registration."""
    if key == "ccdcore":
        reg = (case.runs[key].get("json") or {}).get("registration")
        if not reg:
            return None
        by_name = {s["name"]: s for s in reg["shifts"]}
        out: list[tuple[float, float, float] | None] = []
        for r in case.relpaths:
            s = by_name.get(r)
            out.append(None if s is None or not s["registered"]
                       else (float(s["dx"]), float(s["dy"]), float(s["rotation"])))
        return out
    if key == "opencv-mtb" and mtb is not None:
        return [(float(dx), float(dy), 0.0) for dx, dy in mtb]
    return [(0.0, 0.0, 0.0)] * len(case.relpaths)      # no registration: no motion assumed


def measure(case: Case) -> None:
    """Every run's figures, into ``case.runs[key]["m"]``."""
    import numpy as np

    from ccdcore.io.frames import read_image

    import cv2

    ref_bgr = cv2.imread(case.frames[case.reference][0], cv2.IMREAD_COLOR)
    ref_rgb = ref_bgr[..., ::-1]
    shape = ref_rgb.shape[:2]
    inner = _border_mask(shape)
    unclipped = (ref_rgb.max(axis=-1) < 255) & (ref_rgb.max(axis=-1) > 0)
    g_ref = _grad(_luminance(ref_rgb))
    try:
        mtb = _mtb_shifts(case)
    except Exception as e:                         # noqa: BLE001 -- a figure, not the run
        mtb = None
        case.error = f"calculateShift: {type(e).__name__}: {e}"
    sim = case.group == "simulated" and case.truth is not None
    if sim:
        key_map = case.truth.get("radiance_map", "E")
        rel = case.truth.get("maps", {}).get(key_map, f"truth/{key_map}.exr")
        E_true = np.asarray(read_image(case.session / rel), np.float64)
        mm_path = case.session / "truth" / "moving_mask.npy"
        moving = np.load(mm_path) if mm_path.is_file() else np.zeros(shape, bool)
        own = case.session / "truth" / "movers.npy"
        at_ref = np.load(own)[case.reference] if own.is_file() else np.zeros(shape, bool)
        ghost = moving & ~at_ref & inner
        static = ~moving & inner
        g_true = _grad(_tone_log(E_true))
        truth_tr = _true_transforms(case)
    for key, rec in case.runs.items():
        m: dict[str, Any] = {}
        rec["m"] = m
        if rec["error"]:
            continue
        try:
            rad, flags = _read_radiance(key, Path(rec["out"]))
        except Exception as e:                     # noqa: BLE001
            rec["error"] = f"cannot read the result: {type(e).__name__}: {e}"
            continue
        if rad.shape[:2] != shape:
            rec["error"] = f"result of shape {rad.shape} for frames of {shape}"
            continue
        m["nonfinite"] = int(np.count_nonzero(~np.all(np.isfinite(rad), axis=-1)))
        m["nonpositive"] = int(np.count_nonzero(np.any(rad <= 0, axis=-1)))
        if flags is not None:
            m["nonpositive_ok"] = int(np.count_nonzero(np.any(rad <= 0, axis=-1) & (flags == 0)))
        g = _grad(_tone_log(rad))
        m["edge_ref"] = _corr(g, g_ref, inner & unclipped)
        est = _estimated(case, key, mtb)
        if key.startswith("ccdcore"):
            # frames dropped from the merge (a frame that could not be registered is kept as
            # it is when no other frame moved: a tripod bracket)
            m["left_out"] = len(case.relpaths) - len(rec["json"].get("frames", case.relpaths))
        if key == "ccdcore" and est is not None:
            reg = rec["json"]["registration"]
            m["unregistered"] = sum(1 for s in reg["shifts"] if not s["registered"])
            moved = [s for s in reg["shifts"] if s["applied"]]
            m["moved"] = len(moved)
            m["max_shift"] = max((math.hypot(s["dx"], s["dy"]) for s in moved), default=0.0)
            if reg.get("reference_name") != case.relpaths[case.reference]:
                m["note"] = f"ccdcore's reference is {reg.get('reference_name')}"
        if key == "opencv-mtb" and mtb is not None:
            if sim:
                m["far"] = [(Path(case.relpaths[k]).name, e, t) for k, (e, t)
                            in enumerate(zip(mtb, truth_tr))
                            if math.hypot(e[0] - t[0], e[1] - t[1]) > 2.0]
            else:
                m["far"] = [(Path(case.relpaths[k]).name, e, None) for k, e in enumerate(mtb)
                            if math.hypot(*e) > 5.0]
            m["moved"] = sum(1 for s in mtb if s != (0, 0))
            m["max_shift"] = max(math.hypot(*s) for s in mtb)
        if flags is not None:
            f4 = flags == 4
            m["flagged"] = float(f4.mean())
        if not sim:
            continue
        m["edge_truth"] = _corr(g, g_true, static)
        if est is not None:
            errs, rots = [], []
            for k, (t, e) in enumerate(zip(truth_tr, est)):
                if k == case.reference or e is None:
                    continue
                errs.append(math.hypot(e[0] - t[0], e[1] - t[1]))
                rots.append(abs(e[2] - t[2]))
            if errs:
                m["shift_err"] = (float(np.median(errs)), float(np.max(errs)),
                                  sum(1 for e in errs if e > 1.0))
                m["rot_err"] = float(np.max(rots))
        if flags is not None:
            m["recall"] = float(f4[moving].mean()) if moving.any() else None
            m["outside"] = float(f4[~moving].mean())
        ok = np.isfinite(rad) & (rad > 0) & (E_true > 0)
        ratio = np.full(rad.shape, np.nan)
        ratio[ok] = rad[ok] / E_true[ok]
        k = np.array([np.nanmedian(ratio[..., c][static]) for c in range(rad.shape[-1])])
        dlog = np.abs(np.log(ratio / k))
        for name, region in (("static", static), ("ghost", ghost)):
            v = dlog[region]
            v = v[np.isfinite(v)]
            m[name] = (float(np.median(v)), float(np.percentile(v, 90))) if v.size else None


# ------------------------------------------------------------------------------ the tables --
def _f(v: Any, fmt: str = ".3f") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "—"
    return f"{v:{fmt}}"


def _pair(v: Any, fmt: str = ".3f") -> str:
    return "—" if v is None else f"{v[0]:{fmt}} ({v[1]:{fmt}})"


def _shift_cell(m: dict, key: str) -> str:
    if "shift_err" not in m:
        return "—"
    a, b, n = m["shift_err"]
    cell = f"{a:.2f} / {b:.2f} [{n}]"
    return cell if key in ("ccdcore", "opencv-mtb") else f"({cell})"


def sim_table(cases: list[Case]) -> list[str]:
    rows = ["| case | method | edge r ref | edge r truth | shift err px med / max [> 1 px] | "
            "rot err ° max | left out | moving recall | flagged outside | ghost \\|dlog E\\| "
            "med (p90) | static \\|dlog E\\| med (p90) | time s | peak MB |",
            "|" + "---|" * 14]
    for c in cases:
        if c.error and not c.runs:
            rows.append(f"| {c.name} | error: {c.error} |" + " |" * 12)
            continue
        for key in METHODS:
            rec = c.runs.get(key)
            if rec is None:
                continue
            if rec["error"]:
                rows.append(f"| {c.name} | {LABELS[key]} | error: {rec['error'][:120]} |"
                            + " |" * 9 + f" {rec['time_s']:.1f} | {rec['peak_mb']:.0f} |")
                continue
            m = rec["m"]
            rot = m.get("rot_err")
            rot_cell = _f(rot, ".2f") if key in ("ccdcore", "opencv-mtb") else \
                ("—" if rot is None else f"({rot:.2f})")
            rows.append(
                f"| {c.name} | {LABELS[key]} | {_f(m.get('edge_ref'))} | "
                f"{_f(m.get('edge_truth'))} | {_shift_cell(m, key)} | {rot_cell} | "
                f"{m.get('left_out', '—')} | "
                f"{_f(m.get('recall'), '.2f')} | {_f(m.get('outside'), '.4f')} | "
                f"{_pair(m.get('ghost'))} | {_pair(m.get('static'))} | "
                f"{rec['time_s']:.1f} | {rec['peak_mb']:.0f} |")
    return rows


def real_table(cases: list[Case]) -> list[str]:
    rows = ["| bracket | method | edge r ref | max shift px (frames moved) | left out | "
            "flagged moving | time s | peak MB |", "|" + "---|" * 8]
    for c in cases:
        for key in METHODS:
            rec = c.runs.get(key)
            if rec is None:
                continue
            if rec["error"]:
                rows.append(f"| {c.name} | {LABELS[key]} | error: {rec['error'][:120]} |"
                            + " |" * 3 + f" {rec['time_s']:.1f} | {rec['peak_mb']:.0f} |")
                continue
            m = rec["m"]
            shift = (f"{m['max_shift']:.2f} ({m['moved']})" if "max_shift" in m else "—")
            rows.append(f"| {c.name} | {LABELS[key]} | {_f(m.get('edge_ref'))} | {shift} | "
                        f"{m.get('left_out', '—')} | "
                        f"{_f(m.get('flagged'), '.4f')} | {rec['time_s']:.1f} | "
                        f"{rec['peak_mb']:.0f} |")
    return rows


def notes(cases: list[Case]) -> list[str]:
    out = []
    for c in cases:
        if c.error:
            out.append(f"- {c.name}: {c.error}")
        for key, rec in c.runs.items():
            m = rec.get("m") or {}
            if m.get("nonfinite"):
                out.append(f"- {c.name}, {LABELS[key]}: {m['nonfinite']} pixels with a non-finite "
                           "radiance (masked)")
            if m.get("nonpositive"):
                ok = (f", {m['nonpositive_ok']} of them flagged 0 (merged)"
                      if "nonpositive_ok" in m else "")
                out.append(f"- {c.name}, {LABELS[key]}: {m['nonpositive']} pixels with a radiance "
                           f"<= 0 in some channel (masked from the edge measures){ok}")
            far = m.get("far") or []
            if far and far[0][2] is not None:
                out.append(f"- {c.name}, OpenCV AlignMTB off by more than 2 px: " + ", ".join(
                    f"{n} ({e[0]:+d}, {e[1]:+d}) for ({t[0]:+.1f}, {t[1]:+.1f})"
                    for n, e, t in far))
            elif far:
                out.append(f"- {c.name}, OpenCV AlignMTB shifted by more than 5 px: " + ", ".join(
                    f"{n} by ({e[0]:+d}, {e[1]:+d})" for n, e, _ in far))
            if m.get("note"):
                out.append(f"- {c.name}, {LABELS[key]}: {m['note']}")
            j = rec.get("json") or {}
            if key == "ccdcore" and j.get("registration"):
                left = [s["reason"] for s in j["registration"]["shifts"] if not s["registered"]]
                if left:
                    kept = (" (kept in the merge: no other frame moved)"
                            if not m.get("left_out") else "")
                    out.append(f"- {c.name}, ccdcore could not register{kept}: "
                               + "; ".join(left))
            if key == "ccdcore" and j.get("verdict"):
                v = j["verdict"]
                if v.get("status") != "trusted":
                    out.append(f"- {c.name}, ccdcore verdict {v.get('status')}: "
                               f"{v.get('reason', '')[:200]}")
    return out


# ----------------------------------------------------------------------------------- main --
def bracket_folders() -> list[Path]:
    if not DATA.is_dir():
        return []
    return sorted(p for p in DATA.iterdir() if (p / "session.toml").is_file())


def _clean(v: Any) -> Any:
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    return v


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="1,2",
                    help="seeds of the handheld+mover simulations (default 1,2; the first also "
                         "seeds the movers-only and tripod cases)")
    ap.add_argument("--size", default=f"{SIZE[0]}x{SIZE[1]}",
                    help=f"simulated frame size WxH (default {SIZE[0]}x{SIZE[1]})")
    ap.add_argument("--no-sim", action="store_true", help="skip the simulated group")
    ap.add_argument("--no-real", action="store_true", help="skip the real brackets")
    ap.add_argument("--timeout", type=float, default=600.0,
                    help="seconds one run may take (default 600)")
    ap.add_argument("--keep", type=Path, default=None,
                    help="write the sessions and results here (kept) instead of a temp folder")
    ap.add_argument("--json", metavar="OUT", default=None, help="save every figure to OUT")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    w, h = (int(v) for v in args.size.lower().split("x"))

    _report.header(__file__, 1, warmup=0,
                   note="one run per method and case, each a fresh process (end to end); "
                        f"image measures leave out a {BORDER} px border")
    folders = [] if args.no_real else bracket_folders()
    if not args.no_real and not folders:
        print(f"no real brackets: {DATA} is absent or holds no session folder (the shared data "
              "are not part of the project); the real group is skipped\n")
    tmp_ctx = tempfile.TemporaryDirectory(prefix="bench_handheld_") if args.keep is None \
        else None
    work = Path(tmp_ctx.name) if tmp_ctx is not None else args.keep
    work.mkdir(parents=True, exist_ok=True)
    try:
        cases: list[Case] = []
        if not args.no_sim:
            print("== simulated brackets")
            cases += simulated_cases(work / "sessions", seeds, (w, h))
        cases += real_cases(folders)
        # every timed run first, while the launcher is small (its high-water mark is the floor
        # of every child's ru_maxrss)
        print("== runs (wall s, peak MB)")
        for c in cases:
            if c.error is None:
                run_case(c, work / "runs", args.timeout)
        launcher_runs_mb = _report.max_rss_mb()
        print("== measuring")
        sys.stdout.flush()
        for c in cases:
            if c.runs:
                measure(c)
        sim = [c for c in cases if c.group == "simulated"]
        real = [c for c in cases if c.group == "real"]
        print()
        if sim:
            print(f"### Simulated brackets (tsin01-camera, {w}x{h}, 10 exposures; truth known)\n")
            print("\n".join(sim_table(sim)))
            print()
        if real:
            print("### Real brackets (../shared/data/brackets; no truth)\n")
            print("\n".join(real_table(real)))
            print()
        print("Notes:")
        print("- edge r ref: correlation of the gradient magnitudes of the tone-mapped log "
              "radiance and of the middle frame's luminance codes (unclipped pixels); edge r "
              "truth: against the true radiance's, static pixels")
        print("- shift err: |estimated - true| (dx, dy) per frame, px, median / max [frames "
              "beyond 1 px]; in parentheses for the unaligned runs: the true motion left "
              "uncorrected; OpenCV MTB: integer shifts, no rotation")
        print("- ghost: moving_mask minus the mover's pixels in the reference frame; |dlog E| = "
              "|log(E / k E_true)|, k per channel from the static pixels")
        for line in notes(cases):
            print(line)
        print(f"- launcher peak RSS during the runs {launcher_runs_mb:.0f} MB (the floor of "
              "the children's peak MB; the footer's figure includes the measuring after them)")
        if args.json:
            doc = {"script": Path(__file__).name, "machine": _report.machine(),
                   "date": _report.today(), "border": BORDER,
                   "cases": [{"group": c.group, "name": c.name, "session": str(c.session),
                              "error": c.error,
                              "runs": {k: {kk: vv for kk, vv in r.items() if kk != "json"}
                                       | {"registration": (r.get("json") or {}).get(
                                           "registration"),
                                          "moving": (r.get("json") or {}).get("moving")}
                                       for k, r in c.runs.items()}} for c in cases]}
            Path(args.json).write_text(json.dumps(_clean(doc), indent=1, default=str))
            print(f"figures saved to {args.json}")
    finally:
        if tmp_ctx is not None:
            tmp_ctx.cleanup()
    _report.footer(children=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
