"""Shared helpers for the benchmark scripts: the machine and the date, repeated timings, summaries.

A single wall-time measurement on a shared machine is noise (the same "x faster than" was measured
0.72x and 1.19x on two reruns), so every script times each variant several times, alternating the
variants (A B A B ...) so that background load falls on all of them, and reports the median with
the min–max spread; ratios are computed from the medians.

* :func:`machine` -- one line: CPU model, logical cores, memory, Python, numpy and OS versions;
* :func:`today` -- the ISO date;
* :func:`timed` -- wall times of ``repeat`` calls of one function (after ``warmup`` calls);
* :func:`interleaved` -- the return values of several functions called in turn, round by round;
* :func:`summary` -- median and min–max of a list of numbers (:class:`Summary`);
* :func:`header` / :func:`footer` -- the block printed at the start and end of each script's output.
"""
from __future__ import annotations

import datetime
import os
import platform
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

_START: float | None = None


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def _simd() -> str:
    """The widest x86 vector extension the CPU reports (numpy picks kernels by it)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                flags = set(line.split(":", 1)[1].split())
                for name in ("avx512f", "avx2", "avx", "sse4_2"):
                    if name in flags:
                        return name.upper().replace("AVX512F", "AVX-512").replace("SSE4_2", "SSE4.2")
    except OSError:
        pass
    return ""


def _memory_gib() -> float | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return int(line.split()[1]) / 2 ** 20
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 ** 30
    except (ValueError, OSError, AttributeError):
        return None


def _os() -> str:
    name = ""
    try:
        name = platform.freedesktop_os_release().get("PRETTY_NAME", "")
    except (OSError, AttributeError):
        pass
    kernel = f"{platform.system()} {platform.release()} {platform.machine()}"
    return f"{name}, {kernel}" if name else kernel


def machine() -> str:
    """One line describing the machine and the software versions that set the timings."""
    import numpy as np

    cores = os.cpu_count() or 0
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = cores
    cpu = _cpu_model()
    simd = _simd()
    if simd:
        cpu += f" ({simd})"
    parts = [cpu, f"{cores} logical cores" + (f" ({usable} usable)" if usable != cores else "")]
    mem = _memory_gib()
    if mem is not None:
        parts.append(f"{mem:.1f} GiB RAM")
    parts.append(f"Python {platform.python_version()}")
    parts.append(f"numpy {np.__version__}")
    parts.append(_os())
    return ", ".join(parts)


def today() -> str:
    """Today's date, ISO 8601."""
    return datetime.date.today().isoformat()


def load_average() -> str:
    """The 1, 5 and 15 minute load averages (how busy the machine was), or '' if unknown."""
    try:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    except (OSError, AttributeError):
        return ""


def timed(fn: Callable[[], Any], repeat: int = 5, warmup: int = 1) -> list[float]:
    """Wall times (s, ``time.perf_counter``) of ``repeat`` calls of ``fn``, after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def interleaved(fns: Mapping[str, Callable[[], Any]], repeat: int = 5,
                warmup: int = 1) -> dict[str, list[Any]]:
    """Call every function once per round, in turn (A B A B ...), ``warmup + repeat`` rounds.

    Returns each function's return values of the ``repeat`` timed rounds (the warm-up rounds are
    discarded), so that a function may measure its own time (e.g. in a child process) and return
    it with its other results.  Round ``i`` of every list ran back to back.
    """
    out: dict[str, list[Any]] = {name: [] for name in fns}
    for r in range(warmup + repeat):
        for name, fn in fns.items():
            value = fn()
            if r >= warmup:
                out[name].append(value)
    return out


@dataclass(frozen=True)
class Summary:
    """Median and range of repeated measurements."""

    median: float
    min: float
    max: float
    n: int

    def format(self, fmt: str = ".3f", unit: str = "") -> str:
        """``'0.412 s (0.398–0.450)'``-style text."""
        u = f" {unit}" if unit else ""
        return f"{self.median:{fmt}}{u} ({self.min:{fmt}}–{self.max:{fmt}})"

    def __str__(self) -> str:
        return self.format()


def summary(values: Sequence[float]) -> Summary:
    """Median and min–max of ``values`` (e.g. the list :func:`timed` returns)."""
    vals = [float(v) for v in values]
    if not vals:
        raise ValueError("summary: values is empty")
    return Summary(statistics.median(vals), min(vals), max(vals), len(vals))


def ratio_text(slow: Sequence[float], fast: Sequence[float], fmt: str = ".2f") -> str:
    """``median(slow) / median(fast)``, with the range of the per-round ratios ``slow[i]/fast[i]``.

    The two lists must come from the same rounds of :func:`interleaved` (round ``i`` of each ran
    back to back, under the same background load).
    """
    r = statistics.median(slow) / statistics.median(fast)
    per_round = summary([s / f for s, f in zip(slow, fast)])
    return (f"{r:{fmt}}x (ratio of medians; per-round ratios {per_round.min:{fmt}}–"
            f"{per_round.max:{fmt}}x over {per_round.n} rounds)")


def header(script: str, repeat: int, warmup: int = 1, order: Sequence[str] = (),
           note: str = "") -> None:
    """Print the block that opens each benchmark's output: script, machine, date, repeat count."""
    global _START
    _START = time.perf_counter()
    name = Path(script).name
    args = " ".join(sys.argv[1:])
    print(f"== {name}{(' ' + args) if args else ''}")
    print(f"machine: {machine()}")
    print(f"date: {today()}")
    alt = f", alternated {' '.join(order)} ..." if len(order) > 1 else ""
    print(f"repeat: {repeat} timed runs per variant after {warmup} warm-up round(s) "
          f"(discarded){alt}; times are median (min–max)")
    la = load_average()
    if la:
        print(f"load average at start (1/5/15 min): {la}")
    if note:
        print(note)
    print()
    sys.stdout.flush()


def footer() -> None:
    """Print the script's total run time and the load average at the end."""
    print()
    total = f"{time.perf_counter() - _START:.0f} s" if _START is not None else "?"
    la = load_average()
    print(f"total run time of the script: {total}"
          + (f"; load average at end (1/5/15 min): {la}" if la else ""))
    sys.stdout.flush()
