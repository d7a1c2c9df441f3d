"""The ``ccdcore`` command line (contract in DESIGN.md).

Every analysis verb prints a human summary, or with ``--json`` one JSON object on stdout. Bad input
exits with code 2 and one line on stderr naming the file and the problem, never a traceback.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any, Callable, Sequence

from . import __version__
from .errors import CcdError

__all__ = ["main", "build_parser"]

EXIT_BAD_INPUT = 2


class _Parser(argparse.ArgumentParser):
    """argparse with our one-line error style (exit code 2)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size '{text}' is not WxH, e.g. 256x192") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"size '{text}' must be positive")
    return w, h


def _roi(text: str) -> tuple[int, int, int, int]:
    try:
        x, y, w, h = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"ROI '{text}' is not X,Y,W,H, e.g. 10,10,100,100") from None
    if w < 1 or h < 1 or x < 0 or y < 0:
        raise argparse.ArgumentTypeError(f"ROI '{text}' needs x, y >= 0 and w, h >= 1")
    return x, y, w, h


def _print_json(obj: Any) -> None:
    json.dump(obj, sys.stdout, indent=2, sort_keys=False, allow_nan=False, default=str)
    sys.stdout.write("\n")


# --------------------------------------------------------------------------------------------
# verbs
# --------------------------------------------------------------------------------------------
def _cmd_simulate(args: argparse.Namespace) -> int:
    from .simulate import simulate

    truth = simulate(args.preset, args.out_dir, seed=args.seed, size=args.size)
    if args.json:
        _print_json({"preset": args.preset, "out_dir": str(args.out_dir), "seed": args.seed,
                     "truth": truth})
        return 0
    n_frames = sum(1 for _ in Path(args.out_dir).rglob("*") if _.is_file()) - 2
    print(f"wrote {args.preset} session to {args.out_dir} (seed {args.seed}, {n_frames} files)")
    print(f"  manifest: {Path(args.out_dir) / 'session.toml'}")
    print(f"  truth:    {Path(args.out_dir) / 'truth.json'}")
    return 0


def _cmd_session(args: argparse.Namespace) -> int:
    from .session import draft_manifest, open_session, size_text

    session = open_session(args.session)
    draft = draft_manifest(session) if args.draft else None
    if args.json:
        out = session.to_dict()
        if draft is not None:
            out["draft"] = str(draft)
        _print_json(out)
    else:
        cam = session.camera
        print(f"session {session.root} ({session.source}), camera '{cam.name}', "
              f"{cam.bits} bits, {cam.layout}")
        for row in session.groups_table():
            row = {("size" if k == "shape" else k): (size_text(v) if k == "shape" else v)
                   for k, v in row.items()}                       # sizes read WxH, like --size
            desc = ", ".join(f"{k}={v}" for k, v in row.items() if k not in ("role",) and v not in (None, ""))
            print(f"  {row['role']:<14} {desc}")
        for problem in session.problems:
            print(f"  {problem.severity}: {problem}")
        if draft is not None:
            print(f"manifest draft written to {draft}")
    session.raise_if_invalid()  # exit 2 with the first error and the count of the others
    return 0


def _cmd_ptc(args: argparse.Namespace) -> int:
    from .noise import photon_transfer

    res = photon_transfer(args.session, roi=args.roi, robust=args.robust,
                          exclude_levels=tuple(args.exclude or ()))
    if args.json:
        _print_json(res.to_dict())
        return 0
    print(f"photon transfer of {args.session}" + (f", ROI {args.roi}" if args.roi else ""))
    print(f"{'level':>5} {'mu [DN]':>10} {'var [DN2]':>11} {'+/-':>9}  used")
    for p in res.points:
        used = "yes" if p.used else f"no: {p.reason}"
        print(f"{p.level:>5} {p.mu:>10.3f} {p.var:>11.4f} {p.var_err:>9.4f}  {used}")
    print(f"A        = {res.A:.6g} +/- {res.A_err:.2g} DN/e   "
          f"(conversion gain {res.conversion_gain_e_per_dn:.4g} +/- "
          f"{res.conversion_gain_e_per_dn_err:.2g} e/DN)")
    print(f"sigma_C2 = {res.sigma_c2:.5g} +/- {res.sigma_c2_err:.2g} DN2  "
          f"(read noise {res.read_noise_e:.4g} +/- {res.read_noise_e_err:.2g} e, "
          f"quantisation q2/12 = {res.quantisation_dn2:.4g} DN2)")
    print(f"chi2 = {res.chi2:.4g} with {res.dof} dof, Q = {res.Q:.4g}: {res.verdict}")
    print(f"black level {res.black_level_dn:.4g} DN ({res.black_level_source})")
    if res.robust_dropped:
        print(f"robust mode dropped levels {', '.join(map(str, res.robust_dropped))}")
    for note in res.notes:
        print(f"note: {note}")
    return 0


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from .product import calibrate

    product = calibrate(args.session, roi=args.roi)
    folder = product.save(args.out)
    if args.json:
        out = product.to_dict()
        out["folder"] = str(folder)
        _print_json(out)
        return 0
    est = product.estimates
    print(f"calibration product written to {folder}")
    if "noise" in est:
        n = est["noise"]
        print(f"  noise model   A = {n['A']:.6g} +/- {n['A_err']:.2g} DN/e, sigma_C2 = "
              f"{n['sigma_c2']:.5g} +/- {n['sigma_c2_err']:.2g} DN2, Q = {n['Q']:.3g} ({n['verdict']})")
    if "dark" in est:
        d = est["dark"]
        print(f"  dark          s = {d['s']}, mean {d['mean']:.4g} DN, spatial std "
              f"{d['spatial_std']:.4g} DN, {d['n_hot']} hot, {d['n_dead']} dead")
    if "fixed_pattern" in est:
        k = est["fixed_pattern"]
        print(f"  fixed pattern n1 = {k['n1']}, n2 = {k['n2']}, K mean {k['mean']:.6g}, "
              f"spatial std {k['spatial_std']:.4g}, error var {k['K_var_mean']:.3g} "
              f"(eq. 50 bound {'infinite' if k['var_bound'] is None else format(k['var_bound'], '.3g')})")
    if "correction_check" in est:
        c = est["correction_check"]
        print(f"  correction    eq. 51 on the max-intensity frame changes {100 * c['frac_gt_1q']:.1f} % "
              f"of pixels by > 1 q, {100 * c['frac_gt_2q']:.1f} % by > 2 q, at most "
              f"{c['max_change_q']:.2f} q")
    if "flat_field" in est:
        ff = est["flat_field"]
        ks = ", ".join(f"{c['name']} {c['k']:.4g}" for c in ff["channels"])
        print(f"  flat field    base {ff['base']} ({ff['n_base']} frames), {ff['n_dark']} darks, "
              f"k: {ks}; {ff['n_flagged']} pixels flagged")
    if "plan" in est:
        pl = est["plan"]
        print(f"  plan          n1 >= {pl['n1_required']}, n2 >= {pl['n2_required']}")
    for name, sv in est.get("scene", {}).items():
        print(f"  scene {name:<8} V_S = {sv['V_S']:.4g} +/- {sv['V_S_err']:.2g}")
    for note in product.notes:
        print(f"  note: {note}")
    print(f"  maps: {', '.join(sorted(product.maps))}")
    return 0


def _cmd_snup(args: argparse.Namespace) -> int:
    from .io import read_frame
    from .uniformity import snup

    images = []
    for path in args.images:
        data, header = read_frame(path)
        layout = args.layout or header.layout
        res = snup(data, roi=args.roi, layout=layout, where=str(path))
        images.append({"path": str(path), "layout": layout,
                       "channels": res.to_dict()["channels"]})
    if args.json:
        _print_json({"images": images})
        return 0
    for img in images:
        print(f"{img['path']} ({img['layout']})" + (f", ROI {args.roi}" if args.roi else ""))
        for ch in img["channels"]:
            print(f"  {ch['name']:<3} mean {ch['mean']:10.3f} DN   SNUP {ch['snup']:.4f} "
                  f"+/- {ch['snup_err']:.4f} %")
    return 0


def _cmd_apply(args: argparse.Namespace) -> int:
    from .product import apply_product

    written = apply_product(args.calib, args.images, args.out_dir)
    for path in written:
        print(path)
    return 0


def _cmd_app(args: argparse.Namespace) -> int:
    from app.main import serve

    if args.session is not None and not Path(args.session).exists():
        raise CcdError(args.session, "session not found")
    print(f"serving the ccdcore app on http://127.0.0.1:{args.port} (Ctrl+C to stop)", flush=True)
    serve(args.session, port=args.port, show=False)
    return 0


def _not_built(verb: str, what: str) -> Callable[[argparse.Namespace], int]:
    def run(args: argparse.Namespace) -> int:
        raise CcdError(f"ccdcore {verb}", f"{what} is not built yet in this version")

    return run


# --------------------------------------------------------------------------------------------
# parser
# --------------------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="ccdcore", description="Radiometric camera calibration toolkit.")
    parser.add_argument("--version", action="version", version=f"ccdcore {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB", parser_class=_Parser)
    sub.required = True

    def verb(name: str, help_: str, func: Callable[[argparse.Namespace], int]) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_, description=help_)
        p.set_defaults(func=func)
        return p

    from .simulate import PRESETS

    p = verb("simulate", "write a simulated capture session and its truth.json", _cmd_simulate)
    p.add_argument("preset", choices=sorted(PRESETS))
    p.add_argument("out_dir", type=Path)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--size", type=_size, default=None, help="frame size WxH")
    p.add_argument("--json", action="store_true")

    p = verb("session", "inspect and validate a capture session", _cmd_session)
    p.add_argument("session", type=Path)
    p.add_argument("--draft", action="store_true",
                   help="write session.toml.draft (for a plain folder or descriptor)")
    p.add_argument("--json", action="store_true")

    p = verb("ptc", "photon transfer: noise model A, sigma_C^2 (Healey & Kondepudy 1994)",
             _cmd_ptc)
    p.add_argument("session", type=Path)
    p.add_argument("--roi", type=_roi)
    p.add_argument("--robust", action="store_true",
                   help="drop levels whose residual is beyond 3 sigma, one at a time")
    p.add_argument("--exclude", type=int, action="append", metavar="LEVEL",
                   help="exclude a light level from the fit (repeatable)")
    p.add_argument("--json", action="store_true")

    p = verb("calibrate", "every estimate the session allows, saved as a calibration product",
             _cmd_calibrate)
    p.add_argument("session", type=Path)
    p.add_argument("--roi", type=_roi, help="ROI for the photon-transfer statistics")
    p.add_argument("-o", "--out", type=Path, required=True)
    p.add_argument("--json", action="store_true")

    p = verb("apply", "correct images with a calibration product (eq. 51), float32 out",
             _cmd_apply)
    p.add_argument("calib", type=Path)
    p.add_argument("images", type=Path, nargs="+")
    p.add_argument("-o", "--out-dir", type=Path, required=True)

    p = verb("snup", "spatial nonuniformity percentage SNUP = 100 sigma/mean per channel "
                     "(de Lasarte et al. 2007)", _cmd_snup)
    p.add_argument("images", type=Path, nargs="+")
    p.add_argument("--roi", type=_roi)
    p.add_argument("--layout", choices=["mono", "rgb", "bayer-rggb", "bayer-bggr", "bayer-grbg",
                                        "bayer-gbrg"],
                   help="channel layout (default: from the file; give it for mosaicked raw data)")
    p.add_argument("--json", action="store_true")

    p = verb("response", "inverse camera response per channel",
             _not_built("response", "response-curve estimation"))
    p.add_argument("session", type=Path)
    p.add_argument("--method", choices=["tsin", "debevec", "robertson", "mitsunaga"], default="tsin")
    p.add_argument("--json", action="store_true")

    p = verb("hdr", "HDR radiance map and its sigma map", _not_built("hdr", "HDR radiance"))
    p.add_argument("session", type=Path)
    p.add_argument("--calib", type=Path)
    p.add_argument("-o", "--out-dir", type=Path, required=True)

    p = verb("change", "illumination-invariant change and shadow masks",
             _not_built("change", "change detection"))
    p.add_argument("session", type=Path)
    p.add_argument("--pfa", type=float, default=0.01)
    p.add_argument("-o", "--out-dir", type=Path, required=True)
    p.add_argument("--json", action="store_true")

    p = verb("app", "serve the browser app on 127.0.0.1", _cmd_app)
    p.add_argument("session", nargs="?", default=None)
    p.add_argument("--port", type=int, default=5006)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 ok, 2 bad input)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, inside the handler below
        return code
    except CcdError as err:
        print(f"ccdcore {args.verb}: error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:
        # the reader went away (``ccdcore session ... | head``): stop quietly, as Unix tools do
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 141
    except (OSError, PermissionError) as err:
        where = getattr(err, "filename", None) or ""
        print(f"ccdcore {args.verb}: error: {where}{': ' if where else ''}{err.strerror or err}",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
