"""The ``ccdcore`` command line (the contract is in ``docs/cli.md``).

Every analysis verb prints a human summary, or with ``--json`` one JSON object on stdout. Bad input
exits with code 2 and one line on stderr naming the file and the problem, never a traceback.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import textwrap
import warnings
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from . import __version__
import numpy as np

from .channels import LAYOUTS, is_bayer
from .common import Roi, format_pm, format_size
from .errors import CcdError, require_extra
from .reduce import STREAMED_NAME

__all__ = ["main", "build_parser"]

EXIT_BAD_INPUT = 2


class _Parser(argparse.ArgumentParser):
    """argparse with our one-line error style (exit code 2)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def _size(text: str) -> tuple[int, int]:
    """WxH, at most the library's pixel limit: a frame no read would accept is not written
    (100000x100000 would ask 75 GiB per float frame before failing)."""
    from .io import pixel_limit

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


def _bloom_radius(text: str) -> int:
    """0 .. MAX_BLOOM_RADIUS: the blooming disk's cost grows with its area (3000 would ask
    hundreds of GiB), and a halo wider than that is lens flare, not blooming."""
    from .response.brackets import MAX_BLOOM_RADIUS

    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number of pixels") from None
    if not 0 <= n <= MAX_BLOOM_RADIUS:
        raise argparse.ArgumentTypeError(
            f"must be in 0..{MAX_BLOOM_RADIUS} pixels, got {n} (blooming spills a few pixels; "
            "a halo wider than that is lens flare, not blooming)")
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


def _positive(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"'{text}' must be at least 1")
    return n


def _seconds(text: str) -> float:
    """A positive exposure time in seconds."""
    try:
        t = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number of seconds") from None
    if not (math.isfinite(t) and t > 0):
        raise argparse.ArgumentTypeError(f"'{text}' must be a positive number of seconds")
    return t


def _roi(text: str) -> Roi:
    try:
        x, y, w, h = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"ROI '{text}' is not X,Y,W,H, e.g. 10,10,100,100") from None
    if w < 1 or h < 1 or x < 0 or y < 0:
        raise argparse.ArgumentTypeError(f"ROI '{text}' needs X, Y >= 0 and W, H >= 1")
    return Roi(x, y, w, h)


def _print_json(obj: Any) -> None:
    json.dump(obj, sys.stdout, indent=2, sort_keys=False, allow_nan=False, default=str)
    sys.stdout.write("\n")


# --------------------------------------------------------------------------------------------
# printing
# --------------------------------------------------------------------------------------------
_WIDTH = 100


def _say(label: str, text: str, *, file: Any = None, indent: str = "  ") -> None:
    """Print ``label: text`` wrapped at 100 characters, continuation lines indented."""
    lines = textwrap.wrap(f"{label}: {text}" if label else text, width=_WIDTH,
                          initial_indent=indent, subsequent_indent=indent + "    ",
                          break_long_words=False, break_on_hyphens=False)
    print("\n".join(lines), file=file or sys.stdout)


def _channel(name: str) -> str:
    """A channel's name for a reader: ``L`` is the one channel of a mono camera."""
    return "L (mono)" if name == "L" else str(name)


def _cores() -> int:
    """The CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


#: below this many pixels read (frames x pixels per frame), streaming them takes about a second
#: and a local cluster's start-up (seconds) cannot pay off
_SMALL_SESSION_PIXELS = 100_000_000


@contextlib.contextmanager
def _reducer(args: argparse.Namespace) -> Iterator[Any]:
    """The reducer of ``--scheduler`` / ``--workers`` (:func:`ccdcore.distributed.open_reducer`),
    its errors naming the flag rather than the parameter."""
    from .distributed import open_reducer

    try:
        cm = open_reducer(args.scheduler, args.workers)
        reducer = cm.__enter__()
    except CcdError as err:
        if err.where in ("scheduler", "workers"):
            raise CcdError(f"--{err.where}", err.problem) from None
        raise
    with contextlib.ExitStack() as stack:
        stack.push(cm)
        yield reducer


def _workers_note_for(workers: int | None, session: Any, records: Sequence[Any]) -> None:
    """:func:`_workers_note` for ``records`` of ``session``, their pixels from the cached
    headers (no pixel is read)."""
    if workers is None:
        return
    pixels = 0
    for rec in records:
        hdr = session.header_or_none(rec)
        pixels += 0 if hdr is None else int(hdr.width) * int(hdr.height)
    _workers_note(workers, len(records), pixels)


def _workers_note(workers: int | None, frames: int, pixels: int) -> None:
    """With ``--workers N``: one note on stderr when a local cluster is unlikely to be faster
    than the streamed default (few cores, or a small session), so ``--json`` stays clean."""
    if workers is None:
        return
    cores = _cores()
    why = []
    if cores <= 2 or workers > cores:
        why.append(f"this machine has {cores} CPU core{'s' if cores != 1 else ''}")
    if pixels < _SMALL_SESSION_PIXELS:
        why.append(f"the session is small ({frames} frames, {pixels / 1e6:.3g} megapixels in "
                   "all)")
    if why:
        _say("note", f"--workers {workers}: {' and '.join(why)}; starting a local cluster of "
                     f"{workers} worker process{'es' if workers != 1 else ''} takes seconds, so "
                     "the streamed default (no --workers) is likely faster here",
             file=sys.stderr, indent="")


def _print_problems(problems: Sequence[Any], label: str, limit: int = 3) -> None:
    """Each problem on its own line; beyond ``limit`` of one kind (code), the first ``limit``
    and a count of the rest, so a thousand-frame session stays readable."""
    shown: dict[str, int] = {}
    for p in problems:
        shown[p.code] = shown.get(p.code, 0) + 1
        if shown[p.code] <= limit:
            _say(label, str(p))
    for code, n in shown.items():
        if n > limit:
            _say(label, f"… and {n - limit} more of the same kind ({code}); "
                        "--json lists every one")


def _get(d: dict, key: str) -> float:
    """A number of a JSON summary (``None`` -> NaN so the formatter says n/a)."""
    v = d.get(key)
    return float("nan") if v is None else v


# --------------------------------------------------------------------------------------------
# verbs
# --------------------------------------------------------------------------------------------
def _cmd_simulate(args: argparse.Namespace) -> int:
    from .simulate import simulate

    truth = simulate(args.preset, args.out_dir, seed=args.seed, size=args.size,
                     force=args.force)
    if args.json:
        _print_json({"preset": args.preset, "out_dir": str(args.out_dir), "seed": args.seed,
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
    from .session import draft_manifest, open_session

    session = open_session(args.session)
    draft = draft_manifest(session) if args.draft else None
    if args.json:
        out = session.to_dict()
        if draft is not None:
            out["draft"] = str(draft)
        _print_json(out)
    else:
        cam = session.camera
        bits = f"{cam.bits}-bit" if cam.bits else "unknown bit depth"
        print(f"session {session.label} ({session.source}): camera '{cam.name}', {bits}, "
              f"{cam.layout}, {len(session.frames)} frames")
        for row in session.groups_table():
            print(f"  {row['role']:<14} {_group_text(row)}")
        _print_problems(session.errors, "error")
        _print_problems(session.warnings, "warning")
        if draft is not None:
            print(f"manifest draft written to {draft}: check it, then rename it session.toml")
        n = len(session.errors)
        print("valid" + (f" ({len(session.warnings)} warning"
                         f"{'s' if len(session.warnings) != 1 else ''})" if session.warnings
                         else "") if session.ok else
              f"invalid: {n} error{'s' if n != 1 else ''}")
    session.raise_if_invalid()  # exit 2 with the first error and the count of the others
    return 0


def _cmd_ptc(args: argparse.Namespace) -> int:
    from .noise import EMVA_FIT_FRACTION, photon_transfer

    with _reducer(args) as reducer:
        res = photon_transfer(args.session, roi=args.roi, robust=args.robust,
                              exclude_levels=tuple(args.exclude or ()), reducer=reducer,
                              fit_fraction=EMVA_FIT_FRACTION if args.emva_range else None)
    _workers_note(args.workers, sum(2 * p.n_pairs for p in res.points),
                  sum(2 * p.n_pairs * p.n_pixels for p in res.points))
    if args.json:
        _print_json(res.to_dict())
        return 0
    print(f"photon transfer of {res.source or args.session}, "
          + (f"ROI {Roi(*res.roi)} (X,Y,W,H)" if res.roi else "whole frame"))
    print(f"{'level':>5} {'mean [DN]':>10} {'var [DN²]':>11} {'± err':>9}  used")
    for p in res.points:
        used = "yes" if p.used else f"no ({p.exclusion})"
        print(f"{p.level:>5} {p.mu:>10.3f} {p.var:>11.4f} {p.var_err:>9.4f}  {used}")
    _say("fit range", res.fit_range + ("" if args.emva_range else
                                       "; --emva-range fits only the levels up to 70 % of the "
                                       "saturation signal (the EMVA 1288 range)"), indent="")
    print(f"gain        A = {format_pm(res.A, res.A_err, unit='DN/e⁻')} (DN per electron; "
          f"conversion gain {format_pm(res.conversion_gain_e_per_dn, res.conversion_gain_e_per_dn_err, unit='e⁻/DN')})")
    print(f"signal-independent noise σ²_C = {format_pm(res.sigma_c2, res.sigma_c2_err, unit='DN²')}"
          f" (read noise {format_pm(res.read_noise_dn, res.read_noise_dn_err, unit='DN')} = "
          f"{format_pm(res.read_noise_e, res.read_noise_e_err, unit='e⁻')}; quantisation "
          f"q²/12 = {res.quantisation_dn2:.4g} DN²)")
    print(f"fit         χ² = {res.chi2:.4g} with {res.dof} degrees of freedom, Q = {res.Q:.3g} "
          f"(chance of so large a χ² if the line fits): {res.verdict}")
    print(f"black level b0 = {res.black_level_dn:.4g} DN ({res.black_level_source})")
    if args.robust:
        dropped = res.robust_dropped
        print("robust mode  on: a level more than 3 σ off the line is dropped and the line "
              "refitted, one at a time; " + (
                  f"dropped level{'s' if len(dropped) != 1 else ''} "
                  f"{', '.join(map(str, dropped))}" if dropped else "no level dropped"))
    advice = _ptc_advice(res, robust=bool(args.robust))
    if advice:
        _say("advice", advice, indent="")
    for note in res.notes:
        _say("note", note, indent="")
    return 0


def _ptc_advice(res: Any, *, robust: bool) -> str:
    """What to do when the photon-transfer line does not fit its points (verdict poor or
    model rejected), naming the worst levels; empty when the fit is acceptable."""
    if res.verdict not in ("poor", "model rejected"):
        return ""
    named = ", ".join(f"level {level} ({z:+.1f} σ)" for level, z in res.worst_levels(2))
    top = max((p.mu for p in res.points if p.used and p.var_err > 0), default=float("nan"))
    steps = [f"the fit is {res.verdict}: the points scatter about the line more than their "
             f"errors allow (largest residuals: {named or 'none'})",
             f"leave out levels near saturation (--exclude LEVEL; the brightest used level has "
             f"a mean of {top:.4g} DN above b0) and levels in the dark floor",
             "check the fit range with a region of uniform light (--roi X,Y,W,H)"]
    if not robust:
        steps.append("or try --robust, which drops levels more than 3 σ off the line")
    return "; ".join(steps)


def _print_product(product: Any, folder: Path) -> None:
    est = product.estimates
    print(f"calibration product written to {folder}")
    if "noise" in est:
        n = est["noise"]
        print(f"  noise model    A = {format_pm(_get(n, 'A'), _get(n, 'A_err'), unit='DN/e⁻')}, "
              f"σ²_C = {format_pm(_get(n, 'sigma_c2'), _get(n, 'sigma_c2_err'), unit='DN²')}, "
              f"fit Q = {_get(n, 'Q'):.3g} ({n['verdict']})")
    if "dark" in est:
        d = est["dark"]
        print(f"  dark D̂_D       {d['s']} frames, mean {format_pm(_get(d, 'mean'), _get(d, 'mean_sem'), unit='DN')}, "
              f"spatial std {_get(d, 'spatial_std'):.4g} DN, {d['n_hot']} hot and {d['n_dead']} dead pixels "
              "(D̂_D: the mean dark frame)")
        for note in d.get("notes") or ():
            _say("dark note", note, indent="    ")
    if "fixed_pattern" in est:
        k = est["fixed_pattern"]
        bound = "infinite" if k["var_bound"] is None else format(k["var_bound"], ".3g")
        print(f"  fixed pattern  K̂ (each pixel's relative gain, no unit) from n1 = {k['n1']} "
              f"card/lamp positions × n2 = {k['n2']} frames: mean {_get(k, 'mean'):.6g}, "
              f"spatial std {_get(k, 'spatial_std'):.4g}, mean error variance "
              f"{_get(k, 'K_var_mean'):.3g} (eq. 50 bound {bound})")
    if "correction_check" in est:
        c = est["correction_check"]
        print(f"  correction     eq. 51 on the max-intensity frame changes "
              f"{100 * c['frac_gt_1q']:.1f} % of pixels by more than 1 quantisation step q "
              f"(1 DN), {100 * c['frac_gt_2q']:.1f} % by more than 2 q; the largest change is "
              f"{c['max_change_q']:.2f} q")
    if "flat_field" in est:
        ff = est["flat_field"]
        ks = ", ".join(f"{_channel(c['name'])} {c['k']:.4g} DN" for c in ff["channels"])
        base = ff.get("base")
        if isinstance(base, (list, tuple)) and len(base) == 2:
            level, t = base
            where = ("level " + ("–" if level is None else f"{level:g}" if isinstance(
                level, (int, float)) else str(level)) + ", exposure "
                     + ("–" if t is None else f"{t:g} s"))
        else:
            where = str(base)
        print(f"  flat field     gain and offset maps G, O (corrected = O + G·raw) from the "
              f"recommended base flat: {where} ({ff['n_base']} frames), and {ff['n_dark']} "
              f"dark frames; target level k per channel: {ks}; {ff['n_flagged']} pixels "
              "flagged")
    if "plan" in est:
        pl = est["plan"]
        print(f"  plan           n1 = {pl['n1_required']} card/lamp positions needed, "
              f"n2 = {pl['n2_required']} frames per position")
    if "response" in est:
        r = est["response"]
        noise = "; ".join(
            f"{_channel(c)}: shot σ_s {_fmt(r['sigma_s'][i])} (√g), dark/input σ_c1 "
            f"{_fmt(r['sigma_c1'][i])} (g), output/read σ_c2 {_fmt(r['sigma_c2'][i])} DN"
            for i, c in enumerate(r["channels"]))
        print(f"  response       inverse response g (code -> relative exposure) per channel "
              f"({', '.join(_channel(c) for c in r['channels'])}, {r['levels']} codes) by "
              f"{r['method']}; noise {noise}")
        ag = r.get("agreement")
        if isinstance(ag, dict) and ag.get("rms") is not None:
            print(f"                 predicts its images within {ag['rms']:.2f} DN RMS from a "
                  f"neighbour ({_fmt(ag.get('rms_fitted'))} DN with fitted ratios; sec. 4.2)")
        for w in r.get("warnings") or ():
            _say("warning", f"response: {w}")
    for name, sv in est.get("scene", {}).items():
        print(f"  scene {name:<8} V_S = {format_pm(_get(sv, 'V_S'), _get(sv, 'V_S_err'))} "
              "(relative variance of the surface, no unit)")
    if product.emva1288 is not None:
        _print_emva(product.emva1288)
    print(f"  maps           {', '.join(sorted(product.maps)) or 'none (curves only)'}")
    for warning in product.warnings:
        _say("warning", warning)
    for note in product.notes:
        _say("note", note)


#: the datasheet's sections as the calibrate summary labels them (15 characters at most)
_EMVA_SECTION_LABELS = {"Spatial nonuniformity": "nonuniformity"}


def _print_emva(e: dict) -> None:
    """The EMVA 1288 block of ``calibrate``: the datasheet's rows
    (:func:`ccdcore.emva_sheet.datasheet_rows`), one line per section, then the notes."""
    from .emva_sheet import datasheet_rows

    print("  EMVA 1288      (release 3.1, with release 4.0's DSNU/PRNU parts; as emva1288 "
          "computes them)")
    sections: dict[str, list[str]] = {}
    for r in datasheet_rows(e):
        if r.value is None and r.key == "sigma_d_ptc":
            continue                                 # photon transfer not run: nothing to say
        text = (format_pm(r.value, r.error, unit=r.unit) if r.value is not None
                else "not determined (see the notes)")
        name = f"{r.symbol} from photon transfer" if r.key == "sigma_d_ptc" else r.symbol
        # no line break inside a figure: only between them
        sections.setdefault(r.section, []).append(f"{name} = {text}".replace(" ", "\u00a0"))
    for section, items in sections.items():
        label = _EMVA_SECTION_LABELS.get(section, section.lower())
        lines = textwrap.wrap(f"{label:<15}" + "; ".join(items), width=_WIDTH,
                              initial_indent="    ", subsequent_indent="        ",
                              break_long_words=False, break_on_hyphens=False)
        print("\n".join(lines).replace("\u00a0", " "))
    for note in e.get("notes", ()):
        _say("EMVA note", note, indent="    ")


def _fmt(v: Any) -> str:
    return "–" if v is None else f"{float(v):.4g}"


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from .io import check_outputs
    from .product import PRODUCT_FILE, calibrate, session_inputs
    from .session import open_session

    session = open_session(args.session)
    inputs = session_inputs(session)
    # before the work: the product's files must not be (or hold) the session's
    check_outputs(args.out, {PRODUCT_FILE: False, "maps": True}, inputs)
    earlier = (Path(args.out) / PRODUCT_FILE).is_file()
    try:
        _workers_note_for(args.workers, session, session.frames)
        with _reducer(args) as reducer:
            product = calibrate(session, roi=args.roi, reducer=reducer,
                                dark_exposure=args.dark_exposure)
        folder = product.save(args.out, inputs=inputs)   # atomic: Ctrl+C leaves no part of it
    except KeyboardInterrupt:
        print("ccdcore calibrate: interrupted: nothing was written" + (
            f"; the earlier product in {args.out} is kept as it was" if earlier else ""),
              file=sys.stderr)
        return 130
    if args.json:
        out = product.to_dict()
        out["folder"] = str(folder)
        _print_json(out)
    else:
        _print_product(product, folder)
    for skip in product.skipped:  # on stderr, so --json stays one object on stdout
        _say(f"skipped {skip.estimate}", skip.reason, file=sys.stderr)
    return 0


def _product_manifest(path: Path) -> Path | None:
    """``calibration.json`` of a calibration product folder (or the file itself), else None."""
    from .product import PRODUCT_FILE

    if path.is_dir() and (path / PRODUCT_FILE).is_file():
        return path / PRODUCT_FILE
    if path.is_file() and path.name == PRODUCT_FILE:
        return path
    return None


def _product_emva(manifest: Path) -> dict:
    """The EMVA 1288 figures a product holds, or one line saying why there are none and how
    to get them."""
    from .product import load_product

    product = load_product(manifest.parent)
    if product.emva1288 is not None:
        return product.emva1288
    skip = {s.estimate: s for s in product.skipped}.get("emva1288")
    why = f" (calibrate skipped them: {skip.reason})" if skip is not None else ""
    raise CcdError(manifest, f"the product holds no EMVA 1288 figures{why}; they are made from "
                             "a session whose ptc frames carry photon counts (an EMVA1288 "
                             "descriptor, or photons = N in the manifest): run ccdcore "
                             "datasheet on that session, or calibrate it again")


def _cmd_datasheet(args: argparse.Namespace) -> int:
    require_extra("matplotlib", "datasheet", "the datasheet")   # before any work
    from .common import json_safe
    from .datasheet_files import OUTPUTS, plot_plan, write_datasheet
    from .emva_sheet import datasheet_rows
    from .io import check_outputs

    source = Path(args.source)
    manifest = _product_manifest(source)
    if manifest is not None:
        inputs = [manifest, manifest.parent / "maps"]
        check_outputs(args.out, OUTPUTS, inputs)
        emva = _product_emva(manifest)
        where = str(manifest)
    else:
        from .datasheet import emva_figures
        from .product import session_inputs
        from .session import open_session

        session = open_session(source)
        inputs = session_inputs(session)
        check_outputs(args.out, OUTPUTS, inputs)   # before the work
        emva = json_safe(emva_figures(session).to_dict())
        where = session.label
    plan = plot_plan(emva)
    paths = write_datasheet(emva, args.out, inputs=inputs, where=where)
    rows = datasheet_rows(emva)
    used = {r.note for r in rows if r.note}
    notes = [n for n in emva.get("notes") or () if isinstance(n, str) and n not in used]
    if args.json:
        _print_json({"source": where, "out": str(args.out), "files": [str(p) for p in paths],
                     "rows": [r.to_dict() for r in rows], "notes": notes,
                     "plots": plan.to_dict()})
    else:
        _print_datasheet(where, rows, notes, Path(args.out), paths)
    for name, reason in plan.skipped:   # on stderr, so --json stays one object on stdout
        _say(f"skipped plot {name}", reason, file=sys.stderr)
    return 0


def _print_datasheet(source: str, rows: Sequence[Any], notes: Sequence[str], out: Path,
                     paths: Sequence[Path]) -> None:
    """The rows as a table (name, symbol, value ± error unit, or why there is none), the other
    notes, then the files."""
    print(f"EMVA 1288 datasheet of {source} (release 3.1; DSNU and PRNU parts of release 4.0)")
    name_w = max(len(r.name) for r in rows)
    sym_w = max(len(r.symbol) for r in rows)
    section = None
    for r in rows:
        if r.section != section:
            section = r.section
            print(f"  {section}")
        head = f"    {r.name:<{name_w}}  {r.symbol:<{sym_w}}  "
        if r.value is not None:
            print(head + format_pm(r.value, r.error, unit=r.unit))
        else:   # the reason below the row, at full width
            print(head + "not determined")
            _say("", r.note or "", indent="      ")
    for note in notes:
        _say("note", note)
    from .datasheet_files import PLOTS_FOLDER

    plots = [p for p in paths if p.parent.name == PLOTS_FOLDER]
    print(f"written to {out}:")
    for p in paths:
        if p not in plots:
            print(f"  {p}")
    if plots:
        stems = list(dict.fromkeys(p.stem for p in plots))
        kinds = " and ".join(dict.fromkeys(p.suffix[1:].upper() for p in plots))
        _say(f"  {plots[0].parent}/ ({len(stems)} plots, {kinds} each)", ", ".join(stems),
             indent="")


def _cmd_snup(args: argparse.Namespace) -> int:
    from .common import check_roi
    from .io import read_header, read_image, read_region
    from .uniformity import snup

    images = []
    for path in args.images:
        header = read_header(path)
        layout = args.layout or header.layout
        if args.roi is None:
            data = read_image(path)
        else:  # decode only the region: a huge frame need not fit the pixel limit
            roi = check_roi(args.roi, header.shape, path, even=is_bayer(layout))
            data = read_region(path, *roi)
        res = snup(data, layout=layout, where=str(path))
        images.append({"path": str(path), "layout": layout,
                       "channels": res.to_dict()["channels"]})
    if args.json:
        _print_json({"images": images})
        return 0
    for img in images:
        print(f"{img['path']} ({img['layout']})" + (f", ROI {args.roi}" if args.roi else ""))
        for ch in img["channels"]:
            print(f"  {ch['name']:<3} mean {_get(ch, 'mean'):10.3f} DN   SNUP "
                  f"{format_pm(_get(ch, 'snup'), _get(ch, 'snup_err'), unit='%')}")
    return 0


def _cmd_apply(args: argparse.Namespace) -> int:
    from .product import apply_product

    written = apply_product(args.calib, args.images, args.out_dir, compression=args.compression,
                            linearise=args.linearise)
    for path in written:
        print(path)
    _say("", _applied_text(args.calib, linearise=args.linearise, n=len(written)), indent="")
    return 0


def _applied_text(calib: Any, *, linearise: bool, n: int) -> str:
    """What ``apply`` did to each image, from the product's maps (read from its description,
    not its maps): dark subtracted, fixed pattern divided, flat-field gain/offset, or the
    response; the product named."""
    from .product import PRODUCT_FILE, MapName

    try:
        doc = json.loads((Path(calib) / PRODUCT_FILE).read_text())
        maps = set(doc.get("maps") or ())
        channels = (doc.get("estimates", {}).get("response") or {}).get("channels") or []
    except (OSError, ValueError, AttributeError):
        maps, channels = set(), []
    images = f"{n} image{'s' if n != 1 else ''}"
    if linearise:
        what = ("codes mapped through the inverse response g"
                + (f" of channel{'s' if len(channels) != 1 else ''} "
                   f"{', '.join(_channel(c) for c in channels)}" if channels else "")
                + " (values linear in exposure, g's scale)")
    elif MapName.FLAT_G in maps:
        what = ("flat-field corrected with the gain and offset maps flat_G, flat_O: "
                "corrected = O + G·raw (dark image, PRNU and vignetting removed; de Lasarte et "
                "al. 2007)")
    elif MapName.K in maps:
        what = ("dark reference subtracted and the fixed pattern divided out with the maps "
                "dark, K: corrected = (raw − D̂_D)/K̂ (eq. 51)")
    elif MapName.DARK in maps:
        what = ("dark reference subtracted with the map dark: corrected = raw − D̂_D (no "
                "fixed-pattern map K in the product)")
    else:
        what = "corrected"
    return f"applied to {images} (listed above, float32): {what}; product {Path(calib)}"


def _print_response(res: Any) -> None:
    from .response.methods import METHODS
    from .response.scale import reference_codes

    _, z_hi = reference_codes(res.levels)
    top = res.levels - 1
    print(f"inverse response by {METHODS[res.method].label} from {len(res.files)} exposures "
          f"({', '.join(f'{t:.4g}' for t in res.t)} s), {res.levels} codes")
    _say("", f"g(z) is the inverse response: the relative exposure (light × time) that gives "
             f"the code z, on a scale of its own: g({z_hi}) = {z_hi}/{top} = "
             f"{z_hi / top:.4g} (the code 90 % up the range maps to 0.9; no unit)")
    codes = sorted({round(top * f) for f in (0.05, 0.1, 0.25, 0.5, 0.75, 0.95)})
    names = [_channel(c) for c in res.channels]
    print(f"  {'code z':>7} " + " ".join(f"{'g, ' + c:>20}" for c in names))
    for z in codes:
        print(f"  {z:>7} " + " ".join(
            f"{format_pm(float(r.g[z]), float(r.g_err[z])):>20}" for r in res.responses))
    for ch, r in zip(res.channels, res.responses):
        noise = ", ".join(f"{label} = {format_pm(v, e, unit=u)}" for label, v, e, u in (
            ("shot noise σ_s", r.sigma_s, r.sigma_s_err, "√g"),
            ("dark/input noise σ_c1", r.sigma_c1, r.sigma_c1_err, "g"),
            ("output/read noise σ_c2", r.sigma_c2, r.sigma_c2_err, "DN")) if v is not None)
        state = (f"{r.iterations} iteration{'s' if r.iterations != 1 else ''}"
                 + ("" if r.converged else ", not converged"))
        _say(_channel(ch), f"noise (eq. 7: σ² = σ_s²·(g − b) + σ_c1² + g'²·σ_c2²) "
                           f"{noise or 'not estimated'}; {state}")
        if r.white_balance:
            _say(_channel(ch), "white balance, per exposure: gain a_k/t_k (relative to the "
                               "nominal time; gauge: zero mean and trend of the logs) and "
                               "offset b_k (units of g; the smallest-norm choice)")
            print(f"    {'t_k [s]':>10} {'a_k/t_k':>20} {'b_k':>22}")
            for a, a_err, b, b_err, t in zip(r.a, r.a_err, r.b, r.b_err, r.t):
                print(f"    {t:>10.4g} {format_pm(a / t, a_err / t):>20} "
                      f"{format_pm(float(b), float(b_err)):>22}")
        for note in r.notes:
            _say("note", note, indent="    ")
    ag = res.agreement
    if ag is not None:
        print(f"  agreement (sec. 4.2): {ag.summary()}")
        for c in ag.channels:
            worst = c.worst_pair()
            tail = (f"; worst pair {res.t[worst.j]:.4g} s -> {res.t[worst.k]:.4g} s: "
                    f"{worst.rms:.2f} DN ({worst.rms_fitted:.2f} fitted, ratio "
                    f"{worst.ratio_fitted / worst.ratio:.3f} x nominal)") if worst else ""
            print(f"    {c.channel}: {c.rms:.2f} DN, {c.rms_fitted:.2f} DN fitted, "
                  f"{c.rms_blend:.2f} DN from the blend{tail}")
    for w in res.warnings():
        _say("warning", w)


def _cmd_response(args: argparse.Namespace) -> int:
    from .response.methods import session_response

    res = session_response(args.session, args.method, stack=args.stack,
                           bloom_radius=args.bloom_radius, white_balance=args.white_balance)
    if args.json:
        _print_json(res.to_dict())
    else:
        _print_response(res)
    return 0


def _out_folder(out_dir: Path, names: Sequence[str], session: Any,
                calib: Path | None = None) -> Path:
    """The output folder, checked before any work (:func:`ccdcore.io.check_outputs`): a clear
    error when an output would be (or be inside) an input of the run -- the session's files,
    the product folder -- or is a FIFO or a device. The files are then written as one set
    (:func:`ccdcore.io.output_set`), which creates the folder."""
    from .io import check_outputs
    from .product import session_inputs

    inputs = session_inputs(session) + ([Path(calib)] if calib is not None else [])
    check_outputs(out_dir, names, inputs)
    return Path(out_dir)


def _cmd_change(args: argparse.Namespace) -> int:
    from .change import ChangeOptions, session_change
    from .io import write_image, write_map, write_outputs
    from .product import session_inputs
    from .response.brackets import bracket_records
    from .session import open_session

    session = open_session(args.session)
    session.raise_if_invalid()
    opts = ChangeOptions(pfa=args.pfa)
    opts.check()
    names = ("change_mask.png", "labels.png", "d2.exr", "predicted_target.exr")
    records = [r for role in ("reference", "target") for r in bracket_records(session, role=role)]
    folder = _out_folder(args.out_dir, names, session, args.calib)
    with _reducer(args) as reducer:
        res, inputs = session_change(session, opts, calib=args.calib,
                                     bloom_radius=args.bloom_radius, reducer=reducer)
        scheduler = reducer.description
    _workers_note(args.workers, len(records), len(records) * int(res.labels.size))
    change = np.where(res.labels == 255, 255, 0).astype(np.uint8)
    d2 = np.where(res.valid, res.d2_best, np.nan).astype(np.float32)
    paths = write_outputs(folder, {   # as one set: never new and old files mixed
        names[0]: lambda p: write_image(p, change),
        names[1]: lambda p: write_image(p, res.labels),
        names[2]: lambda p: write_map(p, d2),
        names[3]: lambda p: write_map(p, res.predicted.astype(np.float32))},
        inputs=session_inputs(session) + ([args.calib] if args.calib else []))
    summary = res.to_dict()
    if args.json:
        _print_json({"source": inputs["source"], "channels": list(inputs["channels"]),
                     **summary, "files": [str(p) for p in paths], "scheduler": scheduler})
        return 0
    print(f"change detection (Tsin et al. 2001, sec. 5), {inputs['source']}")
    channels = [str(c) for c in inputs["channels"]]
    if scheduler != STREAMED_NAME:
        print(f"  brackets merged on {scheduler}")
    print(f"  threshold d² {res.threshold:.3g} for a false-alarm rate of {res.pfa:g} "
          f"(χ²_{res.dof}: {summary['threshold_chi2']:.3g}; observed on the background "
          f"{summary['pfa_observed']:.3g}, {summary['pfa_observed_at_chi2_threshold']:.3g} at "
          "the χ² threshold)")
    if res.clusters and len(channels) != res.clusters[0].M.shape[0]:
        channels = [str(i + 1) for i in range(res.clusters[0].M.shape[0])]
    if res.clusters:
        _say("", "each cluster's colour transform M (eq. 20) maps a pixel's reference radiance "
                 "to its target radiance, E_target = E_reference · M (row vectors): row k = "
                 "reference channel k, column j = target channel j, so M[k, j] is how much of "
                 "reference channel k goes into target channel j (no unit; 1 on the diagonal "
                 "means unchanged light)")
    for c in res.clusters:
        what = "background" if c.label == 0 else f"shadow {c.label}"
        print(f"  cluster {c.label} ({what}): {c.pixels} pixels, median d² {c.d2_median:.2f}")
        print(f"    {'M':<9}" + "".join(f"{'target ' + j:>18}" for j in channels))
        for k, row, err in zip(channels, c.M, np.sqrt(np.diag(c.M_cov)).reshape(c.M.shape)):
            print(f"    {'ref ' + k:<9}" + "".join(f"{f'{v:.4f} ± {e:.4f}':>18}"
                                                   for v, e in zip(row, err)))
    print(f"  changed pixels {summary['changed_pixels']}, undetermined "
          f"{summary['undetermined_pixels']}; background mean d² "
          f"{summary['background_d2_mean']:.2f}")
    for n in res.notes:
        print(f"  note: {n}")
    _say("written", "change mask (255 = changed), labels (0 background, 1.. shadows, 255 "
                    "changed, 254 undetermined), d² under the best cluster, predicted target "
                    "radiance")
    for p in paths:
        print(f"  {p}")
    return 0


def _cmd_hdr(args: argparse.Namespace) -> int:
    from .io import write_image, write_map, write_outputs
    from .product import load_product, session_inputs
    from .response.brackets import check_times, bracket_records, load_bracket
    from .response.hdr import merge_bracket
    from .response.methods import response_of
    from .session import open_session

    session = open_session(args.session)
    session.raise_if_invalid()
    records = bracket_records(session, args.stack)
    names = ("radiance.exr", "sigma.exr", "flags.png")
    _workers_note_for(args.workers, session, records)
    folder = _out_folder(args.out_dir, names, session, args.calib)
    with _reducer(args) as reducer:
        # read once here for the traces and the merge; with a calibration only when the
        # merge wants the frames as read (streamed)
        frames = (reducer.preload(session, records) if args.calib is not None
                  else [session.read(r) for r in records])
        if frames is None:
            # the workers read the frames: only what the calibration's models need here
            files = [r.relpath for r in records]
            if session.camera.bits is None:
                raise CcdError(files[0], "the camera's bit depth is unknown: give [camera] "
                                         "bits in the manifest (the response has 2**bits "
                                         "values)")
            levels = 2 ** int(session.camera.bits)
            times = np.sort(check_times([r.exposure for r in records], files), kind="stable")
        else:
            brackets = load_bracket(session, args.stack, bloom_radius=args.bloom_radius,
                                    frames=frames)
            first = next(iter(brackets.values()))
            levels, times = first.levels, first.t
        if args.calib is not None:
            models = load_product(args.calib).response_models(args.calib)
            for ch, m in models.items():
                if m.levels != levels:
                    raise CcdError(args.calib, f"its response has {m.levels} codes, the "
                                               f"bracket's camera {levels}: another camera?")
                # the product's a, b were its own bracket's nominal times: take this one's
                models[ch] = type(m)(m.g, times.copy(), np.zeros(times.size), m.sigma_s,
                                     m.sigma_c1, m.sigma_c2)
            source = f"response of {args.calib}"
        else:
            res = response_of(brackets, "tsin", bloom_radius=args.bloom_radius,
                              white_balance=args.white_balance)
            models = res.models()
            source = "response estimated from this bracket (sec. 3.2)"
        out = merge_bracket(records, models, layout=session.camera.layout,
                            bloom_radius=args.bloom_radius, frames=frames, reducer=reducer,
                            session=session)
        scheduler = reducer.description
    paths = write_outputs(folder, {   # as one set: never new and old files mixed
        names[0]: lambda p: write_map(p, out.radiance),
        names[1]: lambda p: write_map(p, out.sigma),
        names[2]: lambda p: write_image(p, out.flag_image())},
        inputs=session_inputs(session) + ([args.calib] if args.calib else []))
    if args.json:
        _print_json({"source": source, "channels": list(out.channels),
                     "files": [str(p) for p in paths],
                     "flags": {"ok": int(np.sum(out.flag_image() == 0)),
                               "flagged": int(np.sum(out.flag_image() != 0))},
                     "scheduler": scheduler})
    else:
        print(f"HDR radiance of {len(records)} exposures ({source}), channels "
              f"{', '.join(out.channels)}")
        if scheduler != STREAMED_NAME:
            print(f"  merged on {scheduler}")
        for p in paths:
            print(f"  {p}")
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
    check_port(args.port)  # a busy port is one line, before "serving on" is claimed
    print(f"serving the ccdcore app on http://127.0.0.1:{args.port} (Ctrl+C to stop)", flush=True)
    serve(args.session, port=args.port, show=False)
    return 0


# --------------------------------------------------------------------------------------------
# parser
# --------------------------------------------------------------------------------------------
_SESSION_HELP = ("a session folder (with session.toml), a session.toml, a plain folder of images "
                 "or an EMVA1288 descriptor file")
_ROI_HELP = "region of interest X,Y,W,H in pixels (left, top, width, height), e.g. 10,10,100,80"


def _verb(sub: Any, name: str, help_: str, func: Callable[[argparse.Namespace], int],
          needs: str = "") -> argparse.ArgumentParser:
    """A verb's parser: its help, what it needs (in its description) and its command."""
    p = sub.add_parser(name, help=help_, description=help_ + (f". Needs: {needs}" if needs
                                                               else ""))
    p.set_defaults(func=func)
    return p


def _cluster_args(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="reduce the frames on this Dask scheduler (tcp://host:8786); "
                        "default $CCDCORE_SCHEDULER, else streamed in this process")
    g.add_argument("--workers", type=_positive, metavar="N", default=None,
                   help="reduce the frames on a local Dask cluster of N worker processes "
                        "(one thread each), started and stopped by this command")


def _json_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true",
                   help="print one JSON object on stdout instead of the summary")


def _bloom_arg(p: argparse.ArgumentParser) -> None:
    from .response.brackets import DEFAULT_BLOOM_RADIUS, MAX_BLOOM_RADIUS

    p.add_argument("--bloom-radius", type=_bloom_radius, default=DEFAULT_BLOOM_RADIUS,
                   metavar="R", help="pixels within R of a saturated pixel are dropped as "
                                     f"blooming (default {DEFAULT_BLOOM_RADIUS}; 0 keeps them; "
                                     f"at most {MAX_BLOOM_RADIUS})")


def _bracket_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("session", type=Path, help=_SESSION_HELP)
    p.add_argument("--stack", type=int, default=None,
                   help="which bracket of the session (its 'stack'; default the first)")
    _bloom_arg(p)


def _add_simulate(sub: Any) -> None:
    from .simulate import PRESETS

    p = _verb(sub, "simulate", "write a simulated capture session and its truth.json",
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
    _json_flag(p)


def _add_session(sub: Any) -> None:
    p = _verb(sub, "session", "inspect and validate a capture session", _cmd_session,
              needs="any session; exits 2 when it has errors")
    p.add_argument("session", type=Path, help=_SESSION_HELP)
    p.add_argument("--draft", action="store_true",
                   help="write session.toml.draft beside the frames (a manifest to review, e.g. "
                        "for a plain folder or a descriptor)")
    _json_flag(p)


def _add_ptc(sub: Any) -> None:
    p = _verb(sub, "ptc", "photon transfer: noise model A, sigma_C^2 (Healey & Kondepudy 1994)",
              _cmd_ptc, needs="ptc frames at 3 or more light levels (two or more frames each); "
                              "dark frames give the black level")
    p.add_argument("session", type=Path, help=_SESSION_HELP)
    p.add_argument("--roi", type=_roi, metavar="X,Y,W,H", help=_ROI_HELP)
    p.add_argument("--robust", action="store_true",
                   help="drop levels whose residual is beyond 3 sigma, one at a time")
    p.add_argument("--exclude", type=int, action="append", metavar="LEVEL",
                   help="exclude a light level from the fit (repeatable)")
    p.add_argument("--emva-range", action="store_true",
                   help="fit only the levels up to 70 %% of the saturation signal (that of the "
                        "level of largest variance), the EMVA 1288 range; the others are "
                        "listed as excluded (range)")
    _cluster_args(p)
    _json_flag(p)


def _add_calibrate(sub: Any) -> None:
    p = _verb(sub, "calibrate", "every estimate the session allows, saved as a calibration product",
              _cmd_calibrate, needs="any of: ptc frames (noise model), dark frames (dark "
                                    "reference), fixed_pattern and dark frames (K map), flat and "
                                    "dark frames (flat field); what cannot be made is listed")
    p.add_argument("session", type=Path, help=_SESSION_HELP)
    p.add_argument("--roi", type=_roi, metavar="X,Y,W,H", help="ROI X,Y,W,H for the photon-transfer statistics")
    p.add_argument("--dark-exposure", type=_seconds, metavar="SECONDS", default=None,
                   help="with dark frames at several exposures, make the dark reference and "
                        "its hot and dead pixel maps from those at this exposure (default: the "
                        "one nearest the fixed-pattern, flat or ptc frames' median exposure)")
    p.add_argument("-o", "--out", type=Path, required=True,
                   help="product folder to write (new, empty, or an earlier product, which "
                        "is replaced whole: its calibration.json and maps/, so maps this "
                        "calibration does not make are removed; other files are left alone)")
    _cluster_args(p)
    _json_flag(p)


def _add_datasheet(sub: Any) -> None:
    p = _verb(sub, "datasheet", "the EMVA 1288 datasheet as files: datasheet.csv, datasheet.json and "
                           "its plots (PNG and SVG)", _cmd_datasheet,
              needs="a session whose ptc frames carry photon counts (an EMVA1288 descriptor) "
                    "and its dark frames, or a calibration product with EMVA 1288 figures; "
                    "matplotlib (pip install 'ccdcore[datasheet]')")
    p.add_argument("source", type=Path,
                   help=_SESSION_HELP + "; or a calibration product folder (ccdcore calibrate) "
                                        "with EMVA 1288 figures")
    p.add_argument("-o", "--out", type=Path, required=True, metavar="OUT_DIR",
                   help="folder to write datasheet.csv, datasheet.json and plots/ into (an "
                        "earlier datasheet there is replaced whole; other files are left alone)")
    _json_flag(p)


def _add_apply(sub: Any) -> None:
    p = _verb(sub, "apply", "correct images with a calibration product, float32 out", _cmd_apply,
              needs="a product with a flat field (de Lasarte: O + G·DL) or a dark map "
                    "(Healey & Kondepudy eq. 51: (D − D̂_D)/K̂)")
    p.add_argument("calib", type=Path, help="a calibration product folder (ccdcore calibrate)")
    p.add_argument("images", type=Path, nargs="+", help="images of the calibrated camera")
    p.add_argument("-o", "--out-dir", type=Path, required=True,
                   help="folder for the corrected images (same base names)")
    p.add_argument("--compression", choices=["none", "zip"], default="none",
                   help="TIFF/EXR compression of the float32 outputs (default none: about six "
                        "times faster to write than zip, a quarter larger)")
    p.add_argument("--linearise", action="store_true",
                   help="map the codes through the product's inverse response g instead "
                        "(values linear in exposure)")


def _add_snup(sub: Any) -> None:
    p = _verb(sub, "snup", "spatial nonuniformity percentage SNUP = 100 sigma/mean per channel "
                      "(de Lasarte et al. 2007)", _cmd_snup, needs="images of a uniform field")
    p.add_argument("images", type=Path, nargs="+", help="image files")
    p.add_argument("--roi", type=_roi, metavar="X,Y,W,H", help=_ROI_HELP + " (even values on Bayer data)")
    p.add_argument("--layout", choices=list(LAYOUTS),
                   help="channel layout (default: from the file; give it for mosaicked raw data)")
    _json_flag(p)


def _add_response(sub: Any) -> None:
    from .response.methods import METHODS

    p = _verb(sub, "response", "inverse camera response g per channel, with its band and the noise "
                          "terms (Tsin et al. 2001 and classic methods)", _cmd_response,
              needs="an exposure bracket (role = bracket, one exposure per frame)")
    _bracket_args(p)
    p.add_argument("--method", choices=list(METHODS), default="tsin",
                   help="estimation method (default tsin: Tsin, Ramesh & Kanade sec. 3.2)")
    p.add_argument("--white-balance", action="store_true",
                   help="estimate each image's gain a_k and offset b_k too (tsin; up to a common "
                        "factor and a trend in the exposure, which no bracket fixes)")
    _json_flag(p)


def _add_hdr(sub: Any) -> None:
    p = _verb(sub, "hdr", "HDR radiance map and its per-pixel sigma (Tsin et al. eqs. 9, 18, 19)",
              _cmd_hdr, needs="an exposure bracket; a product's response with --calib")
    _bracket_args(p)
    p.add_argument("--calib", type=Path,
                   help="a calibration product with a response (default: estimate it from "
                        "this bracket)")
    p.add_argument("--white-balance", action="store_true",
                   help="without --calib: estimate the gains and offsets too (see response)")
    p.add_argument("-o", "--out-dir", type=Path, required=True,
                   help="folder for radiance.exr, sigma.exr and flags.png")
    _cluster_args(p)
    _json_flag(p)


def _add_change(sub: Any) -> None:
    p = _verb(sub, "change", "illumination-invariant change and shadow masks (Tsin et al. sec. 5)",
              _cmd_change, needs="reference and target brackets (roles reference, target)")
    p.add_argument("session", type=Path, help=_SESSION_HELP)
    p.add_argument("--pfa", type=float, default=0.01,
                   help="false-alarm probability per background pixel (default 0.01)")
    p.add_argument("--calib", type=Path,
                   help="a calibration product with a response (default: estimate it from "
                        "the reference bracket)")
    _bloom_arg(p)
    p.add_argument("-o", "--out-dir", type=Path, required=True,
                   help="folder for change_mask.png, labels.png, d2.exr, predicted_target.exr")
    _cluster_args(p)
    _json_flag(p)


def _add_report(sub: Any) -> None:
    p = _verb(sub, "report", "one self-contained HTML calibration report: every estimate with its "
                        "error, plots and maps, skipped estimates, provenance (opens offline)",
              _cmd_report, needs="a session (it is calibrated first; with reference and target "
                                 "brackets, change detection runs too) or a calibration product "
                                 "folder (ccdcore calibrate)")
    p.add_argument("source", type=Path,
                   help=_SESSION_HELP + "; or a calibration product folder")
    p.add_argument("-o", "--out", type=Path, required=True,
                   help="the HTML file to write (replaced atomically; never an input)")


def _add_app(sub: Any) -> None:
    p = _verb(sub, "app", "serve the browser app on 127.0.0.1", _cmd_app)
    p.add_argument("session", nargs="?", default=None,
                   help="session to open (default: the bundled demo)")
    p.add_argument("--port", type=_port, default=5006, help="port, 1..65535 (default 5006)")


#: the verbs in the order ``ccdcore --help`` lists them
_VERBS: tuple[Callable[[Any], None], ...] = (
    _add_simulate, _add_session, _add_ptc, _add_calibrate, _add_datasheet, _add_apply, _add_snup,
    _add_response, _add_hdr, _add_change, _add_report, _add_app)


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
        inputs = [str(v) for k, v in vars(args).items()
                  if isinstance(v, Path) and k not in ("out", "out_dir")]
        where = f"{', '.join(inputs)}: " if inputs else ""
        print(f"ccdcore {args.verb}: error: {where}a file holds tables or arrays nested too "
              "deeply to read (corrupt?)", file=sys.stderr)
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
