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
* :func:`header` / :func:`footer` -- the block printed at the start and end of each script's output;
* :func:`run_json` -- run a child process and parse the JSON line it prints last.

Peak memory is measured as a child process's ``ru_maxrss``.  On Linux a child started with
``subprocess`` (vfork + exec) inherits the launching process's high-water mark as the floor of its
own ``ru_maxrss``: a launcher that once held 400 MB (e.g. while writing the test data) makes every
child report at least 400 MB.  So the scripts write their data in a child process too, and the
footer prints the launcher's own peak, the floor of every figure.
"""
from __future__ import annotations

import datetime
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

_START: float | None = None
_STAT0: list[int] | None = None
_OURS0: float = 0.0


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
                for flag, name in (("avx512f", "AVX-512"), ("avx2", "AVX2"), ("avx", "AVX"),
                                   ("sse4_2", "SSE4.2")):
                    if flag in flags:
                        return name
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


def _cpu_times() -> list[int] | None:
    """The ``cpu`` line of /proc/stat: user nice system idle iowait irq softirq steal ... ticks."""
    try:
        line = Path("/proc/stat").read_text().splitlines()[0]
        return [int(v) for v in line.split()[1:]]
    except (OSError, ValueError, IndexError):
        return None


def _our_cpu_seconds() -> float:
    """CPU time (user + system) of this process and of its finished children."""
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def max_rss_mb() -> float:
    """This process's peak resident set size (``ru_maxrss``) in MB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run_json(cmd: Sequence[str]) -> Any:
    """Run ``cmd`` (stdout captured, stderr passed through); parse its last stdout line as JSON."""
    proc = subprocess.run(list(cmd), stdout=subprocess.PIPE, text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def timed(fn: Callable[[], Any], repeat: int = 5, warmup: int = 1) -> list[float]:
    """Wall times (s, ``perf_counter``) of ``repeat`` calls of ``fn``, after ``warmup`` calls."""
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
    global _START, _STAT0, _OURS0
    _START = time.perf_counter()
    _STAT0 = _cpu_times()
    _OURS0 = _our_cpu_seconds()
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


def footer(children: bool = False) -> None:
    """Print the script's run time, the load average and how much CPU others took meanwhile.

    With ``children`` (the script measured peak memory in child processes), also this process's
    own peak RSS, the floor of theirs.
    """
    print()
    wall = time.perf_counter() - _START if _START is not None else float("nan")
    total = f"{wall:.0f} s"
    la = load_average()
    print(f"total run time of the script: {total}"
          + (f"; load average at end (1/5/15 min): {la}" if la else ""))
    stat1 = _cpu_times()
    if _STAT0 is not None and stat1 is not None and len(stat1) >= 8:
        d = [b - a for a, b in zip(_STAT0, stat1)]
        total_ticks = sum(d[:8]) or 1
        busy = total_ticks - d[3] - d[4]
        hz = os.sysconf("SC_CLK_TCK")
        others = busy / hz - (_our_cpu_seconds() - _OURS0)
        print(f"CPU meanwhile (all {os.cpu_count()} cores): busy {100 * busy / total_ticks:.0f} %; "
              f"other processes used about {max(others, 0.0) / wall:.2f} cores on average; "
              f"hypervisor steal {100 * d[7] / total_ticks:.1f} %")
    if children:
        print(f"launcher peak RSS {max_rss_mb():.0f} MB (on Linux the floor of every child's "
              f"ru_maxrss)")
    sys.stdout.flush()
