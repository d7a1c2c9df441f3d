"""What the front of the command line (:mod:`ccdcore.cli.command`) and its verb modules
share.

The printing (wrapped at 100 characters), the ``--scheduler`` / ``--workers`` reducer and its note,
and the parser pieces every verb uses. It imports no verb module, so each of them can import it.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import textwrap
from typing import Any, Callable, Iterator, Sequence

from ..errors import CcdError


# --------------------------------------------------------------------------------------------
# printing
# --------------------------------------------------------------------------------------------
def print_json(obj: Any) -> None:
    json.dump(obj, sys.stdout, indent=2, sort_keys=False, allow_nan=False, default=str)
    sys.stdout.write("\n")


WIDTH = 100


def say(label: str, text: str, *, file: Any = None, indent: str = "  ") -> None:
    """Print ``label: text`` wrapped at 100 characters, continuation lines indented."""
    lines = textwrap.wrap(f"{label}: {text}" if label else text, width=WIDTH,
                          initial_indent=indent, subsequent_indent=indent + "    ",
                          break_long_words=False, break_on_hyphens=False)
    print("\n".join(lines), file=file or sys.stdout)


def channel_name(name: str) -> str:
    """A channel's name for a reader: ``L`` is the one channel of a mono camera."""
    return "L (mono)" if name == "L" else str(name)


def cpu_cores() -> int:
    """The CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


#: below this many pixels read (frames x pixels per frame), streaming them takes about a second
#: and a local cluster's start-up (seconds) cannot pay off
_SMALL_SESSION_PIXELS = 100_000_000


@contextlib.contextmanager
def reducer_of(args: argparse.Namespace) -> Iterator[Any]:
    """The reducer of ``--scheduler`` / ``--workers`` (:func:`ccdcore.distributed.client.open_reducer`),
    its errors naming the flag rather than the parameter."""
    from ..distributed.client import open_reducer

    with contextlib.ExitStack() as stack:
        try:
            reducer = stack.enter_context(open_reducer(args.scheduler, args.workers))
        except CcdError as err:
            if err.where in ("scheduler", "workers"):
                raise CcdError(f"--{err.where}", err.problem) from None
            raise
        yield reducer


def workers_note_for(workers: int | None, session: Any, records: Sequence[Any]) -> None:
    """:func:`workers_note` for ``records`` of ``session``, their pixels from the cached
    headers (no pixel is read)."""
    if workers is None:
        return
    pixels = 0
    for rec in records:
        hdr = session.header_or_none(rec)
        pixels += 0 if hdr is None else int(hdr.width) * int(hdr.height)
    workers_note(workers, len(records), pixels)


def workers_note(workers: int | None, frames: int, pixels: int) -> None:
    """With ``--workers N``: one note on stderr when a local cluster is unlikely to be faster
    than the streamed default (few cores, or a small session), so ``--json`` stays clean."""
    if workers is None:
        return
    cores = cpu_cores()
    why = []
    if cores <= 2 or workers > cores:
        why.append(f"this machine has {cores} CPU core{'s' if cores != 1 else ''}")
    if pixels < _SMALL_SESSION_PIXELS:
        why.append(f"the session is small ({frames} frames, {pixels / 1e6:.3g} megapixels in "
                   "all)")
    if why:
        say("note", f"--workers {workers}: {' and '.join(why)}; starting a local cluster of "
                    f"{workers} worker process{'es' if workers != 1 else ''} takes seconds, so "
                    "the streamed default (no --workers) is likely faster here",
            file=sys.stderr, indent="")


# --------------------------------------------------------------------------------------------
# parser
# --------------------------------------------------------------------------------------------
SESSION_HELP = ("a session folder (with session.toml), a session.toml, a plain folder of images "
                "or an EMVA1288 descriptor file")


def add_verb(sub: Any, name: str, help_: str, func: Callable[[argparse.Namespace], int],
             needs: str = "") -> argparse.ArgumentParser:
    """A verb's parser: its help, what it needs (in its description) and its command."""
    p = sub.add_parser(name, help=help_, description=help_ + (f". Needs: {needs}" if needs
                                                               else ""))
    p.set_defaults(func=func)
    return p


def _positive(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"'{text}' must be at least 1")
    return n


def cluster_args(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="reduce the frames on this Dask scheduler (tcp://host:8786); "
                        "default $CCDCORE_SCHEDULER, else streamed in this process")
    g.add_argument("--workers", type=_positive, metavar="N", default=None,
                   help="reduce the frames on a local Dask cluster of N worker processes "
                        "(one thread each), started and stopped by this command")


def json_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true",
                   help="print one JSON object on stdout instead of the summary")
