"""``python -m ccdcore_app [SESSION] [--port N] [--show]``: serve the app on 127.0.0.1."""
from __future__ import annotations

import argparse
import sys


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ccdcore_app",
                                     description="Serve the ccdcore app on 127.0.0.1.")
    parser.add_argument("session", nargs="?", default=None,
                        help="session folder, session.toml, folder of images or EMVA1288 "
                             "descriptor to open")
    parser.add_argument("--port", type=int, default=5006, help="port (default 5006)")
    parser.add_argument("--show", action="store_true", help="open a browser tab")
    args = parser.parse_args(argv)
    from .main import serve

    serve(args.session, port=args.port, show=args.show)
    return 0


if __name__ == "__main__":
    sys.exit(main())
