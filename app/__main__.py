"""``python -m ccdcore_app [SESSION] [--port N] [--show]``: serve the app on 127.0.0.1."""
from __future__ import annotations

import argparse
import sys


def _port(text: str) -> int:
    """A TCP port, 1..65535 (Bokeh asserts on a larger one)."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if not 1 <= n <= 65535:
        raise argparse.ArgumentTypeError(f"must be in 1..65535, got {n}")
    return n


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ccdcore_app",
                                     description="Serve the ccdcore app on 127.0.0.1.")
    parser.add_argument("session", nargs="?", default=None,
                        help="session folder, session.toml, folder of images or EMVA1288 "
                             "descriptor to open")
    parser.add_argument("--port", type=_port, default=5006, help="port, 1..65535 (default 5006)")
    parser.add_argument("--show", action="store_true", help="open a browser tab")
    args = parser.parse_args(argv)
    from ccdcore.errors import CcdError

    from .main import serve

    try:
        serve(args.session, port=args.port, show=args.show)
    except CcdError as err:  # a busy port: one line, exit 2, as the ccdcore command line does
        print(f"{parser.prog}: error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
