"""``ccdcore response`` and ``ccdcore hdr`` at a camera's resolution, against OpenCV doing the same
job, end to end: every run is a fresh process timed by ``/usr/bin/time`` (wall seconds and the
peak resident memory), as a user feels it.

Cases: a real bracket (default ``../shared/data/brackets/living_room1``, 1024 x 680 x 9 PNG with
a session.toml) and the same bracket upsampled (``--factor``, default 5: 5120 x 3400, 17 MP)
and saved as JPEGs with EXIF ExposureTime and no manifest, read as a camera card
(:mod:`benchmarks.make_camera_bracket`, written under ``--work``, default /tmp).

Per case:

``ccdcore response DIR``          the Tsin et al. response (default method) with its report;
``opencv calibrate``              ``cv2.imread`` of the files + ``CalibrateDebevec`` (defaults);
``ccdcore hdr DIR -o OUT``        read, estimate the response, merge (eqs. 9, 18, 19), write
                                  radiance.exr, sigma.exr and flags.png;
``opencv hdr``                    ``imread`` + ``CalibrateDebevec`` + ``MergeDebevec`` + write
                                  the radiance (float32 EXR, ZIP; Radiance .hdr when this OpenCV
                                  build has no EXR writer).

OpenCV is not a dependency of ccdcore: ``pip install -e '.[bench]'`` (or
``pip install opencv-python-headless``); without it the OpenCV rows say so.

    .venv/bin/python benchmarks/bench_camera_resolution.py
    .venv/bin/python benchmarks/bench_camera_resolution.py --factor 5 --repeat 2 --json /tmp/c.json
    .venv/bin/python benchmarks/bench_camera_resolution.py --ccdcore-path /tmp/old_tree

The real brackets are not part of the project; when the bracket folder is absent the script
says so and exits 0.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
DEFAULT_BRACKET = REPO.parent / "shared" / "data" / "brackets" / "living_room1"
TIME = "/usr/bin/time"

#: the OpenCV peer: argv = folder, verb ("calibrate" | "hdr"), output folder
PEER = r'''
import sys, tomllib
from pathlib import Path
import numpy as np
import cv2
folder, verb, out = Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3])
manifest = folder / "session.toml"
if manifest.is_file():
    frames = [f for f in tomllib.loads(manifest.read_text())["frames"]
              if f.get("role", "bracket") == "bracket"]
    files = [folder / f["path"] for f in frames]
    times = [float(f["exposure"]) for f in frames]
else:
    from PIL import Image
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".jpg", ".jpeg"))
    times = []
    for p in files:
        with Image.open(p) as im:
            times.append(float(im.getexif().get_ifd(0x8769)[0x829A]))
images = [cv2.imread(str(p)) for p in files]
t = np.asarray(times, np.float32)
curve = cv2.createCalibrateDebevec().process(images, t)
if verb == "hdr":
    hdr = cv2.createMergeDebevec().process(images, t, curve)
    del images
    out.mkdir(parents=True, exist_ok=True)
    ok = False
    try:
        ok = cv2.imwrite(str(out / "radiance.exr"), hdr)
    except cv2.error:
        ok = False
    if not ok:
        ok = cv2.imwrite(str(out / "radiance.hdr"), hdr)
    assert ok, "OpenCV wrote no radiance file"
print("ok", len(files), images[0].shape if verb != "hdr" else hdr.shape)
'''


def timed(cmd: list[str], env: dict[str, str], timeout: float) -> dict:
    """Wall seconds and peak resident MB of one fresh process (``/usr/bin/time``)."""
    with tempfile.NamedTemporaryFile("r", suffix=".time") as tf:
        full = [TIME, "-f", "%e %M", "-o", tf.name] + cmd
        try:
            # run outside the repository: ``python -c`` puts the working folder first on
            # sys.path, which would shadow --ccdcore-path with the checkout's own ccdcore
            proc = subprocess.run(full, env=env, capture_output=True, text=True,
                                  timeout=timeout, cwd=tempfile.gettempdir())
        except subprocess.TimeoutExpired:
            return {"error": f"timed out after {timeout:g} s"}
        fields = tf.read().split()
    if proc.returncode != 0 or len(fields) < 2:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        return {"error": f"exit {proc.returncode}: {tail[0][:160]}"}
    return {"seconds": float(fields[-2]), "peak_mb": int(fields[-1]) / 1024.0}


def best(cmd: list[str], env: dict[str, str], repeat: int, timeout: float) -> dict:
    """The fastest of ``repeat`` runs (the machine is shared: the minimum is the least noisy),
    with the largest peak memory seen."""
    runs = [timed(cmd, env, timeout) for _ in range(max(1, repeat))]
    good = [r for r in runs if "error" not in r]
    if not good:
        return runs[0]
    return {"seconds": min(r["seconds"] for r in good),
            "peak_mb": max(r["peak_mb"] for r in good), "runs": [r["seconds"] for r in good]}


def has_cv2(python: str) -> bool:
    return subprocess.run([python, "-c", "import cv2"], capture_output=True).returncode == 0


def run_case(name: str, folder: Path, args: argparse.Namespace, env: dict[str, str]) -> list:
    py = sys.executable
    ccd = [py, "-c", "import sys; from ccdcore.cli.command import main; sys.exit(main())"]
    rows = []
    out = Path(args.work) / f"bench_out_{name}"
    jobs = [("ccdcore", "response", ccd + ["response", str(folder)]),
            ("opencv", "response", [py, "-c", PEER, str(folder), "calibrate", str(out)])]
    jobs += [("ccdcore", "hdr", ccd + ["hdr", str(folder), "-o", str(out / "ccdcore")]),
             ("opencv", "hdr", [py, "-c", PEER, str(folder), "hdr", str(out / "opencv")])]
    cv2_ok = has_cv2(py)
    for tool, verb, cmd in jobs:
        if tool == "opencv" and not cv2_ok:
            res = {"error": "OpenCV is not installed (pip install -e '.[bench]')"}
        else:
            shutil.rmtree(out / tool, ignore_errors=True)
            res = best(cmd, env, args.repeat, args.timeout)
        rows.append({"case": name, "tool": tool, "verb": verb, **res})
        print(_line(rows[-1]), flush=True)
    shutil.rmtree(out, ignore_errors=True)
    return rows


def _line(r: dict) -> str:
    head = f"  {r['case']:<14} {r['tool']:<8} {r['verb']:<9}"
    if "error" in r:
        return head + f" {r['error']}"
    return head + f" {r['seconds']:>8.2f} s {r['peak_mb']:>9.0f} MB"


def ratios(rows: list[dict]) -> list[str]:
    """ccdcore / OpenCV per case and verb (time and peak memory)."""
    out = []
    for case in dict.fromkeys(r["case"] for r in rows):
        for verb in ("response", "hdr"):
            got = {r["tool"]: r for r in rows if r["case"] == case and r["verb"] == verb}
            a, b = got.get("ccdcore", {}), got.get("opencv", {})
            if "seconds" in a and "seconds" in b:
                out.append(f"  {case:<14} {verb:<9} ccdcore/OpenCV: time "
                           f"{a['seconds'] / b['seconds']:.2f}x, peak memory "
                           f"{a['peak_mb'] / b['peak_mb']:.2f}x")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bracket", nargs="?", type=Path, default=DEFAULT_BRACKET,
                    help="a bracket session folder (default ../shared/data/brackets/"
                         "living_room1)")
    ap.add_argument("--factor", type=float, default=5.0, help="upsampling factor (default 5)")
    ap.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()),
                    help="folder for the camera bracket and the outputs (default /tmp)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per row; the fastest is shown")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per run")
    ap.add_argument("--skip-small", action="store_true", help="only the upsampled bracket")
    ap.add_argument("--ccdcore-path", type=Path, default=None,
                    help="a ccdcore tree to benchmark instead of the installed one "
                         "(prepended to PYTHONPATH)")
    ap.add_argument("--json", type=Path, default=None, help="write the rows as JSON here")
    args = ap.parse_args(argv)
    if not (args.bracket / "session.toml").is_file():
        print(f"{args.bracket}: no bracket here (the real brackets live in ../shared/data, "
              "which is not part of the project); nothing to measure.")
        return 0
    if not Path(TIME).exists():
        print(f"{TIME} is missing: it measures the peak memory of each run; nothing measured.")
        return 0
    env = dict(os.environ, OPENCV_IO_ENABLE_OPENEXR="1")
    if args.ccdcore_path is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(args.ccdcore_path)]
                                            + [p for p in [env.get("PYTHONPATH")] if p])
    sys.path.insert(0, str(HERE))
    from make_camera_bracket import make

    camera = args.work / f"ccdcore_camera_{args.bracket.name}_x{args.factor:g}"
    if not any(camera.glob("*.jpg")):
        print(f"making the camera bracket {camera} ({args.factor:g} x {args.bracket.name}) ...")
        make(args.bracket, camera, args.factor)
    print(f"{'case':<16} {'tool':<8} {'verb':<9} {'wall':>10} {'peak':>12}")
    rows = []
    if not args.skip_small:
        rows += run_case(args.bracket.name, args.bracket, args, env)
    rows += run_case(f"x{args.factor:g}", camera, args, env)
    print("\n".join(ratios(rows)))
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
