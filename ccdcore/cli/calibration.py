"""The calibration verbs of the command line: ``ptc``, ``calibrate``, ``datasheet``, ``apply`` and
``snup`` (the contract is in ``docs/cli.md``; :mod:`ccdcore.cli.command` runs them)."""
from __future__ import annotations

import argparse
import json
import math
import sys
import textwrap
import unicodedata
from pathlib import Path
from typing import Any, Iterable, Sequence

from ..channels import LAYOUTS, is_bayer
from .response import response_args, response_options
from .session import role_arg
from .common import (SESSION_HELP, WIDTH, add_verb, channel_name, cluster_args, json_flag,
                         print_json, reducer_of, say, workers_note, workers_note_for)
from ..common import Roi, float_or_nan, format_pm
from ..errors import CcdError, require_extra
from ..records import Row


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


# --------------------------------------------------------------------------------------------
# verbs
# --------------------------------------------------------------------------------------------
def _cmd_ptc(args: argparse.Namespace) -> int:
    from ..guide import ptc_gate
    from ..noise import EMVA_FIT_FRACTION, photon_transfer

    with reducer_of(args) as reducer:
        res = photon_transfer(args.session, roi=args.roi, robust=args.robust,
                              exclude_levels=tuple(args.exclude or ()), reducer=reducer,
                              fit_fraction=EMVA_FIT_FRACTION if args.emva_range else None)
    workers_note(args.workers, sum(2 * p.n_pairs for p in res.points),
                 sum(2 * p.n_pairs * p.n_pixels for p in res.points))
    if args.json:
        print_json({**res.to_dict(), "gate": ptc_gate(res).to_dict()})
        return 0
    print(f"photon transfer of {res.source or args.session}, "
          + (f"ROI {Roi(*res.roi)} (X,Y,W,H)" if res.roi else "whole frame"))
    print(f"{'level':>5} {'mean [DN]':>10} {'var [DN²]':>11} {'± err':>9}  used")
    for p in res.points:
        used = "yes" if p.used else f"no ({p.exclusion})"
        print(f"{p.level:>5} {p.mu:>10.3f} {p.var:>11.4f} {p.var_err:>9.4f}  {used}")
    say("fit range", res.fit_range + ("" if args.emva_range else
                                      "; --emva-range fits only the levels up to 70 % of the "
                                      "saturation signal (the EMVA 1288 range)"), indent="")
    print(f"gain        A = {format_pm(res.A, res.A_err, unit='DN/e⁻')} (DN per electron; "
          f"conversion gain {format_pm(res.conversion_gain_e_per_dn, res.conversion_gain_e_per_dn_err, unit='e⁻/DN')})")
    print(f"signal-independent noise σ²_C = {format_pm(res.sigma_c2, res.sigma_c2_err, unit='DN²')}"
          f" (read noise {format_pm(res.read_noise_dn, res.read_noise_dn_err, unit='DN')} = "
          f"{format_pm(res.read_noise_e, res.read_noise_e_err, unit='e⁻')}; quantisation "
          f"q²/12 = {res.quantisation_dn2:.4g} DN²)")
    print(f"fit         χ² = {res.chi2:.4g} with {res.dof} degrees of freedom, Q = {res.Q:.3g} "
          "(chance of so large a χ² if the line fits)")
    gate = ptc_gate(res)
    say("verdict", gate.line(), indent="")       # the Walkthrough's and the page's words
    print(f"black level b0 = {res.black_level_dn:.4g} DN ({res.black_level_source})")
    if args.robust:
        dropped = res.robust_dropped
        print("robust mode  on: a level more than 3 σ off the line is dropped and the line "
              "refitted, one at a time; " + (
                  f"dropped level{'s' if len(dropped) != 1 else ''} "
                  f"{', '.join(map(str, dropped))}" if dropped else "no level dropped"))
    for reason in gate.reasons[1:]:
        say("", reason, indent="  ")
    advice = _ptc_advice(res, gate, robust=bool(args.robust))
    if advice:
        say("advice", advice, indent="")
    for note in res.notes:
        say("note", note, indent="")
    return 0


def _ptc_advice(res: Any, gate: Any, *, robust: bool) -> str:
    """What to do when the photon-transfer gate (:func:`ccdcore.guide.ptc_gate`) does not pass,
    naming the worst levels; empty when it passes."""
    if gate.status == "pass":
        return ""
    named = ", ".join(f"level {level} ({z:+.1f} σ)" for level, z in res.worst_levels(2))
    top = max((p.mu for p in res.points if p.used and p.var_err > 0), default=float("nan"))
    steps = [f"{gate.label.lower()}: {gate.summary} (largest residuals: {named or 'none'})",
             f"leave out levels near saturation (--exclude LEVEL; the brightest used level has "
             f"a mean of {top:.4g} DN above b0) and levels in the dark floor",
             "check the fit range with a region of uniform light (--roi X,Y,W,H)"]
    if not robust:
        steps.append("or try --robust, which drops levels more than 3 σ off the line")
    return "; ".join(steps)


#: how the calibrate summary names each estimate
_TITLES = {"noise": "noise model (photon transfer)", "dark": "dark reference D̂_D",
           "fixed_pattern": "fixed pattern K̂", "plan": "acquisition plan",
           "correction_check": "correction check", "flat_field": "flat field",
           "response": "response"}
#: the widest the label and the value columns of a row grow (columns: label, value, meaning)
_LABEL_WIDTH, _VALUE_WIDTH = 32, 28


def _print_rows(title: str, rows: Iterable[Row]) -> None:
    """One estimate's rows (``summary.rows()``, the same rows the app's product panel shows)
    under its title: the label, the value with its error and unit, what it means (wrapped)."""
    rows = tuple(rows)
    label_w = min(max((_width(r.label) for r in rows), default=0), _LABEL_WIDTH)
    value_w = min(max((_width(r.shown) for r in rows), default=0), _VALUE_WIDTH)
    print(f"  {title}")
    indent = " " * (8 + label_w + value_w)
    for r in rows:
        meaning = textwrap.wrap(r.meaning, width=max(20, WIDTH - len(indent)),
                                break_long_words=False, break_on_hyphens=False) \
            if r.meaning else []
        if _width(r.shown) > value_w:
            # a value wider than its column (a verdict's line) has the row's first lines to
            # itself, the meaning in its own column below: the columns never break
            for i, line in enumerate(textwrap.wrap(r.shown, width=WIDTH - 6 - label_w,
                                                   break_long_words=False)):
                print(f"    {_padded(r.label if i == 0 else '', label_w)}  {line}")
            lines = [("", "", text) for text in meaning]
        else:
            lines = [(r.label if i == 0 else "", r.shown if i == 0 else "", text)
                     for i, text in enumerate(meaning or [""])]
        for label, value, text in lines:
            print(f"    {_padded(label, label_w)}  {_padded(value, value_w)}  {text}".rstrip())


def _width(text: str) -> int:
    """The columns ``text`` takes (a combining accent, as in D̂, takes none)."""
    return sum(1 for c in text if not unicodedata.combining(c))


def _padded(text: str, width: int) -> str:
    """``text`` padded to ``width`` columns."""
    return text + " " * max(width - _width(text), 0)


def _print_product(product: Any, folder: Path) -> None:
    """What ``calibrate`` made: each estimate's rows (the same rows the app's product panel
    shows), the notes and warnings of each, the EMVA 1288 block, the maps."""
    est = product.estimates
    print(f"calibration product written to {folder}")
    for name, summary in est.items():
        if name == "scene":
            for patch, sv in summary.items():
                _print_rows(f"scene variation of {patch}", sv.rows())
            continue
        _print_rows(_TITLES.get(name, name), summary.rows())
        if name == "dark":
            for note in summary.notes:
                say("dark note", note, indent="    ")
        elif name == "flat_field":
            for note in summary.notes:
                say("flat note", note, indent="    ")
            if summary.held_out is not None and summary.held_out.verdict != "pass":
                say("warning", "flat field: the held-out flat keeps more nonuniformity than "
                    "its noise allows: " + summary.held_out.text(), indent="    ")
        elif name == "response":
            for w in summary.warnings:
                say("warning", f"response: {w}")
    if product.emva1288 is not None:
        _print_emva(product.emva1288)
    print(f"  maps           {', '.join(sorted(product.maps)) or 'none (curves only)'}")
    for names, used in frames_text(product.frames):
        say(f"frames of {names}", used, indent="    ")
    for warning in product.warnings:
        say("warning", warning)
    for note in product.notes:
        say("note", note)


def frames_text(frames: dict[str, Sequence[str]]) -> list[tuple[str, str]]:
    """The frames each map was made from, compactly: maps made from the same frames share a
    line; a list is its count and, per folder and file-name pattern, the first and last name
    (``"26 frames: bias-Neg5-Vis.00000000.BIAS.FIT … darks-expos60s-Neg5-Vis.00000000.DARK.FIT"``
    for long lists; every name up to 4)."""
    by: dict[tuple[str, ...], list[str]] = {}
    for name in sorted(frames):
        by.setdefault(tuple(frames[name]), []).append(name)
    out = []
    for used, names in by.items():
        n = len(used)
        shown = (", ".join(used) if n <= 4 else
                 f"{', '.join(used[:2])} … {used[-1]}")
        out.append((", ".join(names), f"{n} frame{'s' if n != 1 else ''}: {shown}"))
    return out


#: the datasheet's sections as the calibrate summary labels them (15 characters at most)
_EMVA_SECTION_LABELS = {"Spatial nonuniformity": "nonuniformity"}


def _print_emva(e: Any) -> None:
    """The EMVA 1288 block of ``calibrate`` for the figures ``e`` (an
    :class:`~ccdcore.emva.results.EmvaSummary`): the datasheet's rows
    (:func:`ccdcore.emva.sheet.datasheet_rows`), one line per section, then the notes."""
    from ..emva.sheet import datasheet_rows

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
        lines = textwrap.wrap(f"{label:<15}" + "; ".join(items), width=WIDTH,
                              initial_indent="    ", subsequent_indent="        ",
                              break_long_words=False, break_on_hyphens=False)
        print("\n".join(lines).replace("\u00a0", " "))
    for note in e.notes:
        say("EMVA note", note, indent="    ")


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from ..io.frames import check_outputs
    from ..product.make import PRODUCT_FILE, calibrate, session_inputs
    from ..session import open_session

    session = open_session(args.session, role=args.role)
    inputs = session_inputs(session)
    # before the work: the product's files must not be (or hold) the session's
    check_outputs(args.out, {PRODUCT_FILE: False, "maps": True}, inputs)
    earlier = (Path(args.out) / PRODUCT_FILE).is_file()
    try:
        workers_note_for(args.workers, session, session.frames)
        with reducer_of(args) as reducer:
            product = calibrate(session, roi=args.roi, reducer=reducer,
                                dark_exposure=args.dark_exposure,
                                response_options={"method": args.method,
                                                  **response_options(args)})
        folder = product.save(args.out, inputs=inputs)   # atomic: Ctrl+C leaves no part of it
    except KeyboardInterrupt:
        print("ccdcore calibrate: interrupted: nothing was written" + (
            f"; the earlier product in {args.out} is kept as it was" if earlier else ""),
              file=sys.stderr)
        return 130
    if args.json:
        out = product.to_dict()
        out["folder"] = str(folder)
        print_json(out)
    else:
        _print_product(product, folder)
    _print_skipped(product.skipped)
    return 0


def _print_skipped(skipped: Sequence[Any]) -> None:
    """The estimates not made, on stderr (``--json`` stays one object on stdout): each with
    its reason, but those whose frames the session holds none of (a photo card's darks, EMVA
    sets, fixed-pattern cards) in one line, their needs in ``--json``'s ``skipped``."""
    from ..product.make import requirement

    def absent(skip: Any) -> bool:
        try:
            roles = set(requirement(skip.estimate).roles)
        except KeyError:
            return False
        return skip.code == "missing-frames" and roles <= set(skip.roles)

    for skip in skipped:
        if not absent(skip):
            say(f"skipped {skip.estimate}", skip.reason, file=sys.stderr)
    names = [skip.estimate for skip in skipped if absent(skip)]
    if names:
        say("not made", f"{', '.join(names)}: the session holds none of the frames they need "
                        "(--json lists, under \"skipped\", what to capture for each)",
            file=sys.stderr)


def _product_manifest(path: Path) -> Path | None:
    """``calibration.json`` of a calibration product folder (or the file itself), else None."""
    from ..product.make import PRODUCT_FILE

    if path.is_dir() and (path / PRODUCT_FILE).is_file():
        return path / PRODUCT_FILE
    if path.is_file() and path.name == PRODUCT_FILE:
        return path
    return None


def _product_emva(manifest: Path) -> Any:
    """The EMVA 1288 figures a product holds (an :class:`~ccdcore.emva.results.EmvaSummary`,
    checked when the product is loaded), or one line saying why there are none and how to get
    them."""
    from ..product.make import load_product

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
    from ..emva.datasheet_files import OUTPUTS, plot_plan, write_datasheet
    from ..emva.sheet import datasheet_rows
    from ..io.frames import check_outputs

    source = Path(args.source)
    manifest = _product_manifest(source)
    if manifest is not None:
        inputs = [manifest, manifest.parent / "maps"]
        check_outputs(args.out, OUTPUTS, inputs)
        emva = _product_emva(manifest)
        where = str(manifest)
    else:
        from ..emva.datasheet import emva_figures
        from ..product.make import session_inputs
        from ..session import open_session

        session = open_session(source)
        inputs = session_inputs(session)
        check_outputs(args.out, OUTPUTS, inputs)   # before the work
        emva = emva_figures(session).summary()
        where = session.label
    plan = plot_plan(emva)
    paths = write_datasheet(emva, args.out, inputs=inputs)
    rows = datasheet_rows(emva)
    used = {r.note for r in rows if r.note}
    notes = [n for n in emva.notes if n not in used]
    if args.json:
        print_json({"source": where, "out": str(args.out), "files": [str(p) for p in paths],
                    "rows": [r.to_dict() for r in rows], "notes": notes,
                    "plots": plan.to_dict()})
    else:
        _print_datasheet(where, rows, notes, Path(args.out), paths)
    for name, reason in plan.skipped:   # on stderr, so --json stays one object on stdout
        say(f"skipped plot {name}", reason, file=sys.stderr)
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
            say("", r.note or "", indent="      ")
    for note in notes:
        say("note", note)
    from ..emva.datasheet_files import PLOTS_FOLDER

    plots = [p for p in paths if p.parent.name == PLOTS_FOLDER]
    print(f"written to {out}:")
    for p in paths:
        if p not in plots:
            print(f"  {p}")
    if plots:
        stems = list(dict.fromkeys(p.stem for p in plots))
        kinds = " and ".join(dict.fromkeys(p.suffix[1:].upper() for p in plots))
        say(f"  {plots[0].parent}/ ({len(stems)} plots, {kinds} each)", ", ".join(stems),
            indent="")


def _cmd_snup(args: argparse.Namespace) -> int:
    from ..common import check_roi
    from ..io.frames import read_header, read_image, read_region
    from ..flatfield.uniformity import snup

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
        print_json({"images": images})
        return 0
    for img in images:
        print(f"{img['path']} ({img['layout']})" + (f", ROI {args.roi}" if args.roi else ""))
        for ch in img["channels"]:
            print(f"  {ch['name']:<3} mean {float_or_nan(ch.get('mean')):10.3f} DN   SNUP "
                  f"{format_pm(float_or_nan(ch.get('snup')), float_or_nan(ch.get('snup_err')), unit='%')}")
    return 0


def _cmd_apply(args: argparse.Namespace) -> int:
    from ..product.make import apply_product

    written = apply_product(args.calib, args.images, args.out_dir, compression=args.compression,
                            linearise=args.linearise)
    for path in written:
        print(path)
    say("", _applied_text(args.calib, linearise=args.linearise, n=len(written)), indent="")
    return 0


def _applied_text(calib: Any, *, linearise: bool, n: int) -> str:
    """What ``apply`` did to each image, from the product's maps (read from its description,
    not its maps): dark subtracted, fixed pattern divided, flat-field gain/offset, or the
    response; the product named."""
    from ..product.make import PRODUCT_FILE, MapName

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
                   f"{', '.join(channel_name(c) for c in channels)}" if channels else "")
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


# --------------------------------------------------------------------------------------------
# parser
# --------------------------------------------------------------------------------------------
_ROI_HELP = "region of interest X,Y,W,H in pixels (left, top, width, height), e.g. 10,10,100,80"


def add_ptc(sub: Any) -> None:
    p = add_verb(sub, "ptc", "photon transfer: noise model A, sigma_C^2 (Healey & Kondepudy 1994)",
                 _cmd_ptc, needs="ptc frames at 3 or more light levels (two or more frames each); "
                                 "dark frames give the black level")
    p.add_argument("session", type=Path, help=SESSION_HELP)
    p.add_argument("--roi", type=_roi, metavar="X,Y,W,H", help=_ROI_HELP)
    p.add_argument("--robust", action="store_true",
                   help="drop levels whose residual is beyond 3 sigma, one at a time")
    p.add_argument("--exclude", type=int, action="append", metavar="LEVEL",
                   help="exclude a light level from the fit (repeatable)")
    p.add_argument("--emva-range", action="store_true",
                   help="fit only the levels up to 70 %% of the saturation signal (that of the "
                        "level of largest variance), the EMVA 1288 range; the others are "
                        "listed as excluded (range)")
    cluster_args(p)
    json_flag(p)


def add_calibrate(sub: Any) -> None:
    p = add_verb(sub, "calibrate",
                 "every estimate the session allows, saved as a calibration product",
                 _cmd_calibrate, needs="any of: ptc frames (noise model), dark frames (dark "
                                       "reference), fixed_pattern and dark frames (K map), "
                                       "flat and dark frames (flat field); what cannot be made "
                                       "is listed")
    p.add_argument("session", type=Path, help=SESSION_HELP)
    p.add_argument("--roi", type=_roi, metavar="X,Y,W,H", help="ROI X,Y,W,H for the photon-transfer statistics")
    p.add_argument("--dark-exposure", type=_seconds, metavar="SECONDS", default=None,
                   help="with dark frames at several exposures, make the dark reference and "
                        "its hot and dead pixel maps from those at this exposure (default: the "
                        "one nearest the fixed-pattern, flat or ptc frames' median exposure; "
                        "with darks and biases at two or more exposures, the dark model's dark "
                        "at this exposure, default the frames' median exposure)")
    role_arg(p)
    p.add_argument("-o", "--out", type=Path, required=True,
                   help="product folder to write (new, empty, or an earlier product, which "
                        "is replaced whole: its calibration.json and maps/, so maps this "
                        "calibration does not make are removed; other files are left alone)")
    response_args(p, "with a bracket: ")
    cluster_args(p)
    json_flag(p)


def add_datasheet(sub: Any) -> None:
    p = add_verb(sub, "datasheet", "the EMVA 1288 datasheet as files: datasheet.csv, "
                              "datasheet.json and its plots (PNG and SVG)", _cmd_datasheet,
                 needs="a session whose ptc frames carry photon counts (an EMVA1288 descriptor) "
                       "and its dark frames, or a calibration product with EMVA 1288 figures; "
                       "matplotlib (pip install 'ccdcore[datasheet]')")
    p.add_argument("source", type=Path,
                   help=SESSION_HELP + "; or a calibration product folder (ccdcore calibrate) "
                                       "with EMVA 1288 figures")
    p.add_argument("-o", "--out", type=Path, required=True, metavar="OUT_DIR",
                   help="folder to write datasheet.csv, datasheet.json and plots/ into (an "
                        "earlier datasheet there is replaced whole; other files are left alone)")
    json_flag(p)


def add_apply(sub: Any) -> None:
    p = add_verb(sub, "apply", "correct images with a calibration product, float32 out", _cmd_apply,
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


def add_snup(sub: Any) -> None:
    p = add_verb(sub, "snup", "spatial nonuniformity percentage SNUP = 100 sigma/mean per channel "
                         "(de Lasarte et al. 2007)", _cmd_snup, needs="images of a uniform field")
    p.add_argument("images", type=Path, nargs="+", help="image files")
    p.add_argument("--roi", type=_roi, metavar="X,Y,W,H", help=_ROI_HELP + " (even values on Bayer data)")
    p.add_argument("--layout", choices=list(LAYOUTS),
                   help="channel layout (default: from the file; give it for mosaicked raw data)")
    json_flag(p)
