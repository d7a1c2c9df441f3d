"""The session verbs of the command line: ``simulate``, ``session``, ``report`` and ``app``
(the contract is in ``docs/cli.md``; :mod:`ccdcore.cli.command` runs them)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Sequence

from .common import SESSION_HELP, add_verb, json_flag, print_json, say
from ..common import format_size
from ..errors import CcdError, require_extra


def _size(text: str) -> tuple[int, int]:
    """WxH, at most the library's pixel limit: a frame no read would accept is not written
    (100000x100000 would ask 75 GiB per float frame before failing)."""
    from ..io.frames import pixel_limit

    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size '{text}' is not WxH, e.g. 256x192") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"size '{text}' must be positive")
    try:
        limit = pixel_limit()
    except CcdError as err:  # a bad CCDCORE_MAX_PIXELS
        raise argparse.ArgumentTypeError(str(err)) from None
    if w * h > limit:
        raise argparse.ArgumentTypeError(f"size '{text}' is {w * h:,} pixels, over the pixel "
                                         f"limit of {limit:,} (CCDCORE_MAX_PIXELS)")
    return w, h


def _seed(text: str) -> int:
    """A random seed: NumPy's generators take whole numbers >= 0 only."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"seed '{text}' is not a whole number") from None
    if n < 0:
        raise argparse.ArgumentTypeError(f"seed must be 0 or more, got {n}")
    return n


def _port(text: str) -> int:
    """A TCP port, 1..65535 (Bokeh asserts on 70000; -1 gave a resolver error)."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--port '{text}' is not a whole number") from None
    if not 1 <= n <= 65535:
        raise argparse.ArgumentTypeError(f"must be in 1..65535, got {n}")
    return n


def _print_problems(problems: Sequence[Any], label: str, limit: int = 3,
                    drafted: bool = False) -> None:
    """Each problem on its own line; beyond ``limit`` of one kind (code), the first ``limit``
    and a count of the rest, so a thousand-frame session stays readable. ``drafted``: the
    manifest draft was just written, and the advice points at it."""
    from ..session.folder import after_draft

    shown: dict[str, int] = {}
    for p in problems:
        shown[p.code] = shown.get(p.code, 0) + 1
        if shown[p.code] <= limit:
            say(label, after_draft(str(p)) if drafted else str(p))
    for code, n in shown.items():
        if n > limit:
            say(label, f"… and {n - limit} more of the same kind ({code}); "
                       "--json lists every one")


# --------------------------------------------------------------------------------------------
# verbs
# --------------------------------------------------------------------------------------------
def _cmd_simulate(args: argparse.Namespace) -> int:
    from ..simulate import simulate

    truth = simulate(args.preset, args.out_dir, seed=args.seed, size=args.size,
                     force=args.force)
    if args.json:
        print_json({"preset": args.preset, "out_dir": str(args.out_dir), "seed": args.seed,
                    "truth": truth})
        return 0
    n_frames = sum(1 for _ in Path(args.out_dir).rglob("*") if _.is_file()) - 2
    print(f"wrote {args.preset} session to {args.out_dir} (seed {args.seed}, {n_frames} files)")
    print(f"  manifest: {Path(args.out_dir) / 'session.toml'}")
    print(f"  truth:    {Path(args.out_dir) / 'truth.json'}")
    return 0


def _group_text(row: dict) -> str:
    parts = [f"{row['count']} frame{'s' if row['count'] != 1 else ''}"]
    key_name = row["key_name"]
    if row["key"] is not None:
        unit = " s" if key_name == "exposure" else ""
        parts.insert(0, f"{key_name} {row['key']}{unit}")
    parts.append("size " + ("mixed" if "shape" in row["mixed"] else format_size(row["shape"], "x")))
    parts.append("dtype " + ("mixed" if "dtype" in row["mixed"] else str(row["dtype"])))
    if row["unreadable"]:
        parts.append(f"{row['unreadable']} unreadable")
    if row["exposures"] and row["role"] != "dark":
        exps = row["exposures"]
        parts.append("exposure " + (f"{exps[0]:g} s" if len(exps) == 1 else
                                    f"{exps[0]:g} to {exps[-1]:g} s ({len(exps)} values)"))
    return ", ".join(parts)


def _cmd_session(args: argparse.Namespace) -> int:
    from ..session import draft_manifest, open_session

    session = open_session(args.session, role=args.role)
    draft = draft_manifest(session) if args.draft else None
    if args.json:
        out = session.to_dict()
        if draft is not None:
            out["draft"] = str(draft)
        print_json(out)
    else:
        cam = session.camera
        bits = f"{cam.bits}-bit" if cam.bits else "unknown bit depth"
        print(f"session {session.label} ({session.source}): camera '{cam.name}', {bits}, "
              f"{cam.layout}, {len(session.frames)} frames")
        for row in session.groups_table():
            print(f"  {row['role']:<14} {_group_text(row)}")
        _print_problems(session.errors, "error", drafted=draft is not None)
        _print_problems(session.warnings, "warning", drafted=draft is not None)
        if draft is not None:
            print(f"manifest draft written to {draft}: check it, then rename it session.toml")
        n = len(session.errors)
        print("valid" + (f" ({len(session.warnings)} warning"
                         f"{'s' if len(session.warnings) != 1 else ''})" if session.warnings
                         else "") if session.ok else
              f"invalid: {n} error{'s' if n != 1 else ''}")
    session.raise_if_invalid()  # exit 2 with the first error and the count of the others
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    require_extra("bokeh", "report", "the report")
    from ccdcore_report import write_report  # here: Bokeh loads for this verb only (not Panel)

    last = [""]

    def progress(fraction: float, message: str) -> None:   # a ccdcore.progress.Progress
        if message != last[0]:
            last[0] = message
            print(f"report: {100 * fraction:3.0f} % {message}", file=sys.stderr, flush=True)

    path = write_report(args.source, args.out, progress=progress)
    print(f"report written to {path} ({path.stat().st_size / 1e6:.1f} MB, opens offline)")
    return 0


def _cmd_app(args: argparse.Namespace) -> int:
    require_extra("panel", "app", "the app")
    from ccdcore_app.main import check_port, serve

    if args.session is not None and not Path(args.session).exists():
        raise CcdError(args.session, "session not found")
    if args.role is not None:
        if args.session is None:
            raise CcdError("--role", "give the folder whose images take the role")
        from ccdcore_app.state import open_session_cached

        # a wrong role or a manifest: one line before serving; opened through the app's cache
        # of opened sessions, so the server's first opening reads no header again
        open_session_cached(Path(args.session).expanduser().resolve(), args.role)
    check_port(args.port)  # a busy port is one line, before "serving on" is claimed
    print(f"serving the ccdcore app on http://127.0.0.1:{args.port} (Ctrl+C to stop)", flush=True)
    serve(args.session, port=args.port, show=False, role=args.role)
    return 0


# --------------------------------------------------------------------------------------------
# parser
# --------------------------------------------------------------------------------------------
def add_simulate(sub: Any) -> None:
    from ..simulate import PRESETS

    p = add_verb(sub, "simulate", "write a simulated capture session and its truth.json",
                 _cmd_simulate)
    p.add_argument("preset", choices=sorted(PRESETS),
                   help="which capture procedure: a paper's, or the EMVA 1288 series")
    p.add_argument("out_dir", type=Path, help="folder to write (created): new, empty, or an "
                                              "earlier simulation (its truth.json)")
    p.add_argument("--force", action="store_true",
                   help="write into a folder that holds other files (those of the same names "
                        "are replaced)")
    p.add_argument("--seed", type=_seed, default=0, help="random seed, 0 or more (default 0)")
    p.add_argument("--size", type=_size, default=None, metavar="WxH",
                   help="frame size WxH in pixels (default: the preset's)")
    json_flag(p)


def role_arg(p: Any) -> None:
    """``--role ROLE``: every image of a plain folder takes that role (``ccdcore session`` and
    ``ccdcore calibrate``)."""
    # no choices= here: building the parser must not import ccdcore.session (startup time);
    # open_folder refuses an unknown role in one line
    p.add_argument("--role", default=None, metavar="ROLE",
                   help="for a plain folder of images without session.toml: take every image "
                        "as a frame of this role (dark, ptc, fixed_pattern, flat, bracket, "
                        "scene, reference, target), e.g. --role flat for a camera's flat "
                        "fields named as the camera named them (with --draft, the draft says "
                        "so)")


def add_session(sub: Any) -> None:
    p = add_verb(sub, "session", "inspect and validate a capture session", _cmd_session,
                 needs="any session; exits 2 when it has errors")
    p.add_argument("session", type=Path, help=SESSION_HELP)
    p.add_argument("--draft", action="store_true",
                   help="write session.toml.draft beside the frames (a manifest to review, e.g. "
                        "for a plain folder or a descriptor)")
    role_arg(p)
    json_flag(p)


def add_report(sub: Any) -> None:
    p = add_verb(sub, "report", "one self-contained HTML calibration report: every estimate with "
                           "its error, plots and maps, skipped estimates, provenance (opens "
                           "offline)",
                 _cmd_report, needs="a session (it is calibrated first; with reference and target "
                                    "brackets, change detection runs too) or a calibration product "
                                    "folder (ccdcore calibrate)")
    p.add_argument("source", type=Path,
                   help=SESSION_HELP + "; or a calibration product folder")
    p.add_argument("-o", "--out", type=Path, required=True,
                   help="the HTML file to write (replaced atomically; never an input)")


def add_app(sub: Any) -> None:
    p = add_verb(sub, "app", "serve the browser app on 127.0.0.1", _cmd_app)
    p.add_argument("session", nargs="?", default=None,
                   help="session to open (default: the bundled demo)")
    p.add_argument("--port", type=_port, default=5006, help="port, 1..65535 (default 5006)")
    role_arg(p)
