"""The ``ccdcore`` command line (the contract is in ``docs/cli.md``).

Every analysis verb prints a human summary, or with ``--json`` one JSON object on stdout. Bad input
exits with code 2 and one line on stderr naming the file and the problem, never a traceback.

This module is the front: the parser and :func:`main`. The verbs live in the modules below it:
:mod:`ccdcore.cli.session` (simulate, session, report, app), :mod:`ccdcore.cli.calibration`
(ptc, calibrate, datasheet, apply, snup), :mod:`ccdcore.cli.response` (response, hdr, change),
and what they share in :mod:`ccdcore.cli.common`.
"""
from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path
from typing import Any, Callable, Sequence

from .. import __version__
import numpy as np

from .calibration import add_apply, add_calibrate, add_datasheet, add_ptc, add_snup
from .response import add_change, add_hdr, add_response
from .session import add_app, add_report, add_session, add_simulate
from ..errors import CcdError

__all__ = ["main", "build_parser"]

EXIT_BAD_INPUT = 2


class _Parser(argparse.ArgumentParser):
    """argparse with our one-line error style (exit code 2)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


#: the verbs in the order ``ccdcore --help`` lists them
_VERBS: tuple[Callable[[Any], None], ...] = (
    add_simulate, add_session, add_ptc, add_calibrate, add_datasheet, add_apply, add_snup,
    add_response, add_hdr, add_change, add_report, add_app)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="ccdcore", description="Radiometric camera calibration toolkit.",
                     epilog="Each verb's --help says what it needs. Bad input exits with code 2 "
                            "and one line naming the file and the problem.")
    parser.add_argument("--version", action="version", version=f"ccdcore {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB", parser_class=_Parser)
    sub.required = True
    for add in _VERBS:
        add(sub)
    return parser


def _inputs(args: argparse.Namespace) -> str:
    """The command's input paths as the start of an error line ("a, b: "), or ""."""
    inputs = [str(v) for k, v in vars(args).items()
              if isinstance(v, Path) and k not in ("out", "out_dir")]
    return f"{', '.join(inputs)}: " if inputs else ""


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 ok, 2 bad input).

    NumPy's RuntimeWarnings (invalid values met while estimating) are not printed: every
    estimator reports bad input as one error line, so a warning would only precede it.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            code = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, inside the handler below
        return code
    except CcdError as err:
        print(f"ccdcore {args.verb}: error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except RecursionError:
        # Last resort: a parser met input nested deeper than Python's stack (a hostile or
        # corrupt TOML/JSON file, e.g. ten thousand "[" in a row) and did not say which file.
        print(f"ccdcore {args.verb}: error: {_inputs(args)}a file holds tables or arrays "
              "nested too deeply to read (corrupt?)", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError as err:
        # a frame or a stack larger than the memory free (a 400 MP image under a limit): one
        # line with what NumPy could not allocate, never its traceback
        what = str(err) or "an allocation failed"
        print(f"ccdcore {args.verb}: error: {_inputs(args)}not enough memory ({what}); free "
              "memory, or give fewer or smaller frames", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:
        # the reader went away (``ccdcore session ... | head``): stop quietly, as Unix tools do
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 141
    except OSError as err:
        where = getattr(err, "filename", None) or ""
        print(f"ccdcore {args.verb}: error: {where}{': ' if where else ''}{err.strerror or err}",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
