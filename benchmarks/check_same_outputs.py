"""Run every verb on every demo session and write what it produced, to compare two trees.

A refactoring that moves modules must not change what a user gets: products, reports,
datasheets, JSON and ``--help`` texts. Run this before and after the change (each in its own
checkout: ``PYTHONPATH=CHECKOUT python benchmarks/check_same_outputs.py OUT``) and compare the
two folders with ``--compare A B``: byte-equal files are "same"; files holding a clock time, a
run's duration or the output folder's own path are compared with those masked.

Run by hand, never by the tests (it takes a few minutes).
"""
from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT / "assets"
DEMOS = ("healey94", "delasarte07", "emva1288", "tsin01", "tsin01-camera", "change")
VERBS = ("simulate", "session", "ptc", "calibrate", "datasheet", "apply", "snup", "response",
         "hdr", "change", "report", "app")


def ccdcore(args: list[str], cwd: Path) -> tuple[int, str, str]:
    """``ccdcore ARGS`` in a fresh process of this interpreter (the checkout on PYTHONPATH)."""
    code = "import sys; from ccdcore.cli.command import main; sys.exit(main())"
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          cwd=cwd, env={**os.environ, "COLUMNS": "100"})
    return proc.returncode, proc.stdout, proc.stderr


def runs(out: Path) -> list[tuple[str, list[str]]]:
    """(name, arguments) of every run: help texts, then the verbs on every demo."""
    items: list[tuple[str, list[str]]] = [("help", ["--help"])]
    items += [(f"help-{v}", [v, "--help"]) for v in VERBS]
    for demo in DEMOS:
        s = str(ASSETS / demo)
        o = out / demo
        items += [(f"{demo}-session", ["session", s, "--json"]),
                  (f"{demo}-calibrate", ["calibrate", s, "-o", str(o / "calib"), "--json"]),
                  (f"{demo}-report", ["report", str(o / "calib"), "-o", str(o / "report.html")])]
    items += [("healey94-ptc", ["ptc", str(ASSETS / "healey94"), "--json"]),
              ("emva1288-datasheet", ["datasheet", str(ASSETS / "emva1288"), "-o",
                                      str(out / "emva1288" / "datasheet")]),
              ("tsin01-response", ["response", str(ASSETS / "tsin01"), "--json"]),
              ("tsin01-camera-hdr", ["hdr", str(ASSETS / "tsin01-camera"), "-o",
                                     str(out / "tsin01-camera" / "hdr"), "--json"]),
              ("change-change", ["change", str(ASSETS / "change"), "-o",
                                 str(out / "change" / "change"), "--json"]),
              ("delasarte07-snup", ["snup", str(ASSETS / "delasarte07"), "--json"])]
    return items


def produce(out: Path) -> int:
    out.mkdir(parents=True, exist_ok=False)
    for name, args in runs(out):
        rc, so, se = ccdcore(args, ROOT)
        (out / f"{name}.txt").write_text(f"exit {rc}\n--- stdout\n{so}\n--- stderr\n{se}")
        print(f"{name}: exit {rc}", flush=True)
    return 0


#: what legitimately differs between two runs: clock times, durations, the output's own path,
#: random ids
MASKS = [re.compile(p) for p in (
    r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(?:\.\d+)?(?:[+-]\d\d:\d\d|Z)?",
    r"\d{4}-\d\d-\d\d \d\d:\d\d(?::\d\d)?(?: UTC)?",
    r"\"(?:seconds|elapsed|duration|time_s|wall_s)\": [0-9.e+-]+",
    r"in \d+(?:\.\d+)? s\b",
    r"\d+(?:\.\d+)? s elapsed",
    r"[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}",   # Bokeh's document ids
)]


def masked(data: bytes, root: Path) -> bytes:
    text = data.decode("utf-8", errors="surrogateescape").replace(str(root), "<OUT>")
    for m in MASKS:
        text = m.sub("<MASKED>", text)
    return text.encode("utf-8", errors="surrogateescape")


def compare(a: Path, b: Path) -> int:
    files = sorted({p.relative_to(a) for p in a.rglob("*") if p.is_file()}
                   | {p.relative_to(b) for p in b.rglob("*") if p.is_file()})
    bad = 0
    same = masked_same = 0
    for rel in files:
        pa, pb = a / rel, b / rel
        if not pa.exists() or not pb.exists():
            print(f"only in {'B' if not pa.exists() else 'A'}: {rel}")
            bad += 1
            continue
        da, db = pa.read_bytes(), pb.read_bytes()
        if da == db:
            same += 1
        elif masked(da, a) == masked(db, b):
            masked_same += 1
        else:
            print(f"differs: {rel} ({hashlib.sha256(da).hexdigest()[:12]} against "
                  f"{hashlib.sha256(db).hexdigest()[:12]})")
            bad += 1
    print(f"{len(files)} files: {same} byte-equal, {masked_same} equal once clock times and the "
          f"output path are masked, {bad} different")
    return 1 if bad else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, nargs="?")
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("A", "B"))
    args = ap.parse_args()
    if args.compare:
        return compare(*args.compare)
    if args.out is None:
        ap.error("give OUT, or --compare A B")
    if args.out.exists():
        shutil.rmtree(args.out)
    return produce(args.out)


if __name__ == "__main__":
    sys.exit(main())
