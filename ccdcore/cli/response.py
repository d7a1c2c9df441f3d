"""The exposure-bracket verbs of the command line: ``response``, ``hdr`` and ``change`` (the
contract is in ``docs/cli.md``; :mod:`ccdcore.cli.command` runs them)."""
from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .common import (SESSION_HELP, add_verb, channel_name, cluster_args, json_flag,
                         print_json, reducer_of, say, workers_note, workers_note_for)
from ..common import format_pm
from ..errors import CcdError
from ..reduce_names import STREAMED_NAME


def _bloom_radius(text: str) -> int:
    """0 .. MAX_BLOOM_RADIUS: the blooming disk's cost grows with its area (3000 would ask
    hundreds of GiB), and a halo wider than that is lens flare, not blooming."""
    from ..response.names import MAX_BLOOM_RADIUS

    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number of pixels") from None
    if not 0 <= n <= MAX_BLOOM_RADIUS:
        raise argparse.ArgumentTypeError(
            f"must be in 0..{MAX_BLOOM_RADIUS} pixels, got {n} (blooming spills a few pixels; "
            "a halo wider than that is lens flare, not blooming)")
    return n


# --------------------------------------------------------------------------------------------
# verbs
# --------------------------------------------------------------------------------------------
def print_response(res: Any) -> None:
    from ..response.methods import METHODS
    from ..response.scale import reference_codes

    _, z_hi = reference_codes(res.levels)
    top = res.levels - 1
    print(f"inverse response by {METHODS[res.method].label} from {len(res.files)} exposures "
          f"({', '.join(f'{t:.4g}' for t in res.t)} s listed), {res.levels} codes")
    if res.selection:
        say("method", f"{res.requested}: {res.selection}")
    print_exposures(res.exposures)
    say("", f"g(z) is the inverse response: the relative exposure (light × time) that gives "
            f"the code z, on a scale of its own: g({z_hi}) = {z_hi}/{top} = "
            f"{z_hi / top:.4g} (the code 90 % up the range maps to 0.9; no unit)")
    codes = sorted({round(top * f) for f in (0.05, 0.1, 0.25, 0.5, 0.75, 0.95)})
    names = [channel_name(c) for c in res.channels]
    print(f"  {'code z':>7} " + " ".join(f"{'g, ' + c:>20}" for c in names))
    for z in codes:
        print(f"  {z:>7} " + " ".join(
            f"{format_pm(float(r.g[z]), float(r.g_err[z])):>20}" for r in res.responses))
    say("", "noise terms of eq. 7, σ² = σ_s²·(g − b) + σ_c1² + g'²·σ_c2², in the units each "
            "term needs: σ_s in √g (its variance grows with the signal g), σ_c1 in units of g "
            "(the signal scale above), σ_c2 in DN (codes, before the curve)")
    top = res.levels - 1

    def term(label: str, v: float, e: float | None, unit: str, full: float) -> str:
        # an error beyond the whole range of its unit (the codes for σ_c2, full scale for g)
        # says the bracket does not determine the term: said so, not printed as a figure
        if e is not None and math.isfinite(e) and e > full:
            return f"{label} not determined by this bracket ({format_pm(v, e, unit=unit)})"
        return f"{label} = {format_pm(v, e, unit=unit)}"

    for ch, r in zip(res.channels, res.responses):
        noise = ", ".join(term(label, v, e, u, full) for label, v, e, u, full in (
            ("shot noise σ_s", r.sigma_s, r.sigma_s_err, "√g", 1.0),
            ("dark/input noise σ_c1", r.sigma_c1, r.sigma_c1_err, "g", 1.0),
            ("output/read noise σ_c2", r.sigma_c2, r.sigma_c2_err, "DN", float(top)))
            if v is not None)
        state = (f"{r.iterations} iteration{'s' if r.iterations != 1 else ''}"
                 + ("" if r.converged else ", not converged"))
        say(channel_name(ch), f"noise {noise or 'not estimated'}; {state}")
        if r.white_balance:
            say(channel_name(ch), "white balance, per exposure: gain a_k/t_k (relative to the "
                                  "nominal time; gauge: zero mean and trend of the logs) and "
                                  "offset b_k (units of g; the smallest-norm choice)")
            print(f"    {'t_k [s]':>10} {'a_k/t_k':>20} {'b_k':>22}")
            for a, a_err, b, b_err, t in zip(r.a, r.a_err, r.b, r.b_err, r.t):
                print(f"    {t:>10.4g} {format_pm(a / t, a_err / t):>20} "
                      f"{format_pm(float(b), float(b_err)):>22}")
        for note in r.notes:
            say("note", note, indent="    ")
    ag = res.agreement
    if ag is not None:
        print(f"  agreement (sec. 4.2): {ag.summary()}")
        for c in ag.channels:
            worst = c.worst_pair()
            tail = (f"; worst pair {res.t[worst.j]:.4g} s -> {res.t[worst.k]:.4g} s: "
                    f"{worst.rms:.2f} DN ({worst.rms_fitted:.2f} fitted, ratio "
                    f"{worst.ratio_fitted / worst.ratio:.3f} x the ratio used)") if worst else ""
            print(f"    {c.channel}: {c.rms:.2f} DN, {c.rms_fitted:.2f} DN fitted, "
                  f"{c.rms_blend:.2f} DN from the blend{tail}")
    print_verdict(res)


def print_exposures(estimate: Any, label: str = "", table: bool = True) -> None:
    """Which exposures were taken and why (an
    :class:`ccdcore.response.exposures.ExposureEstimate`; nothing for ``None``), the frames
    that disagree with the listed ones and, with ``table``, each frame's listed and own
    exposure when the own ones were taken."""
    if estimate is None:
        return
    ex = estimate.summary()
    say(label, ex.line())
    for run in ex.off_runs():
        say("", run, indent="    ")
    if table and ex.used == "estimated":
        print(f"    {'frame':>20} {'listed [s]':>12} {'own [s]':>12}")
        for f, t, a in zip(ex.files, ex.listed, ex.estimated):
            print(f"    {f.rsplit('/', 1)[-1]:>20} {t:>12.4g} {a:>12.4g}")


def print_verdict(res: Any) -> None:
    """The response's verdict (:mod:`ccdcore.response.verdict`), the words every surface
    shows: its line, then the frames' registration and the moving pixels."""
    v = res.verdict
    if v is not None:
        say("verdict", v.line())
        for line in v.details():
            say("", line)


def response_options(args: argparse.Namespace) -> dict[str, Any]:
    """The response options of a verb's arguments (``--method``, ``--white-balance``,
    ``--exposures``), as :func:`ccdcore.response.methods.response_of` takes them."""
    return {"white_balance": bool(args.white_balance), "exposures": args.exposures}


def _cmd_response(args: argparse.Namespace) -> int:
    from ..response.bracket_fit import session_response

    res = session_response(args.session, args.method, stack=args.stack,
                           bloom_radius=args.bloom_radius, align=args.align,
                           **response_options(args))
    if args.json:
        print_json(res.to_dict())
    else:
        print_response(res)
    return 0


def _out_folder(out_dir: Path, names: Sequence[str], session: Any,
                calib: Path | None = None) -> Path:
    """The output folder, checked before any work (:func:`ccdcore.io.frames.check_outputs`): a clear
    error when an output would be (or be inside) an input of the run -- the session's files,
    the product folder -- or is a FIFO or a device. The files are then written as one set
    (:func:`ccdcore.io.frames.output_set`), which creates the folder."""
    from ..io.frames import check_outputs
    from ..product.make import session_inputs

    inputs = session_inputs(session) + ([Path(calib)] if calib is not None else [])
    check_outputs(out_dir, names, inputs)
    return Path(out_dir)


def _count(n: int, kind: str) -> str:
    """"1 frame", "5 frames" or "7 exposures (a bracket)"."""
    if kind != "frames":
        return f"{n} exposures (a bracket)"
    return f"{n} frame{'s' if n != 1 else ''}"


def _cmd_change(args: argparse.Namespace) -> int:
    from ..change.detector import LABEL_SHADE, ChangeOptions
    from ..change.session import session_change
    from ..change.frames import FRAME_MIN_REGION, session_kinds
    from ..io.frames import write_image, write_map, write_outputs
    from ..product.make import session_inputs
    from ..response.brackets import bracket_records
    from ..session import open_session

    session = open_session(args.session)
    kinds = session_kinds(session)       # every error but a frame set's missing exposures
    frame_sets = "frames" in kinds.values() or args.response != "auto"
    opts = ChangeOptions(pfa=args.pfa, min_region=args.min_region if args.min_region is not None
                         else FRAME_MIN_REGION if frame_sets else 1, shade=args.shade)
    opts.check()
    names = ("change_mask.png", "labels.png", "d2.exr", "predicted_target.exr")
    records = [r for role in ("reference", "target") for r in bracket_records(session, role=role)]
    folder = _out_folder(args.out_dir, names, session, args.calib)
    res = None
    with reducer_of(args) as reducer:
        res, inputs = session_change(session, opts, calib=args.calib,
                                     bloom_radius=args.bloom_radius, reducer=reducer,
                                     method=args.method, response=args.response,
                                     **response_options(args))
        scheduler = reducer.description
    workers_note(args.workers, len(records), len(records) * int(res.labels.size))
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
        rv = inputs.response
        print_json({"source": inputs.source, "noise": inputs.noise, "kinds": inputs.kinds,
                    "channels": list(inputs.channels),
                    **summary, "files": [str(p) for p in paths], "scheduler": scheduler,
                    "verdict": None if rv is None or rv.verdict is None
                    else rv.verdict.to_dict(),
                    "exposures": {role: None if ex is None else ex.summary().to_dict()
                                  for role, ex in inputs.exposures.items()}})
        return 0
    print("change detection (Tsin et al. 2001, sec. 5), "
          + ", ".join(f"{role}: {_count(len([f for f in records if f.role == role]), kind)}"
                      for role, kind in inputs.kinds.items()))
    say("response", inputs.source)
    say("noise", inputs.noise)
    for role, ex in inputs.exposures.items():
        print_exposures(ex, role, table=False)
    if inputs.response is not None:
        print_verdict(inputs.response)
    channels = [str(c) for c in inputs.channels]
    if scheduler != STREAMED_NAME:
        print(f"  brackets merged on {scheduler}")
    print(f"  threshold d² {res.threshold:.3g} for a false-alarm rate of {res.pfa:g} "
          f"(χ²_{res.dof}: {summary['threshold_chi2']:.3g}; observed on the background "
          f"{summary['pfa_observed']:.3g}, {summary['pfa_observed_at_chi2_threshold']:.3g} at "
          "the χ² threshold)")
    if res.clusters and len(channels) != res.clusters[0].M.shape[0]:
        channels = [str(i + 1) for i in range(res.clusters[0].M.shape[0])]
    if res.clusters:
        say("", "each cluster's colour transform M (eq. 20) maps a pixel's reference radiance "
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
    if res.shade is not None:
        lo, hi = res.shade
        print(f"  shades of the background's light (its prediction times one factor "
              f"{lo:g}-{hi:g}: soft shadows, penumbrae): {summary['shade_pixels']} pixels, "
              f"labelled {LABEL_SHADE}, not change (--shade off counts them as change)")
    print(f"  changed pixels {summary['changed_pixels']}, undetermined "
          f"{summary['undetermined_pixels']}; background mean d² "
          f"{summary['background_d2_mean']:.2f}")
    for n in res.notes:
        print(f"  note: {n}")
    say("written", "change mask (255 = changed), labels (0 background, 1.. shadows, 253 "
                   "shades of the background's light, 255 changed, 254 undetermined), d² under "
                   "the best cluster, predicted target radiance")
    for p in paths:
        print(f"  {p}")
    return 0


def _cmd_hdr(args: argparse.Namespace) -> int:
    from ..io.frames import write_image, write_map, write_outputs
    from ..product.make import session_inputs
    from ..response.brackets import bracket_records
    from ..response.hdr import merge_bracket
    from ..session import open_session

    session = open_session(args.session)
    session.raise_if_invalid()
    records = bracket_records(session, args.stack)
    names = ("radiance.exr", "sigma.exr", "flags.png")
    workers_note_for(args.workers, session, records)
    folder = _out_folder(args.out_dir, names, session, args.calib)
    with reducer_of(args) as reducer:
        models, source, res, calib_exposures, frames, records, moving, alignment = \
            _hdr_models(args, session, records, reducer)
        out = merge_bracket(records, models, layout=session.camera.layout,
                            bloom_radius=args.bloom_radius, frames=frames, reducer=reducer,
                            session=session)
        if moving is not None:
            from ..response.moving import merge_moving

            out = merge_moving(out, frames, models, moving, bloom_radius=args.bloom_radius)
        frames = None      # not needed for writing (460 MB at 17 MP x 9)
        scheduler = reducer.description
    paths = write_outputs(folder, {   # as one set: never new and old files mixed
        names[0]: lambda p: write_map(p, out.radiance),
        names[1]: lambda p: write_map(p, out.sigma),
        names[2]: lambda p: write_image(p, out.flag_image())},
        inputs=session_inputs(session) + ([args.calib] if args.calib else []))
    if args.json:
        print_json({"source": source, "channels": list(out.channels),
                    "files": [str(p) for p in paths],
                    "frames": [r.relpath for r in records],
                    "flags": {"ok": int(np.sum(out.flag_image() == 0)),
                              "flagged": int(np.sum(out.flag_image() != 0)),
                              **out.flag_counts()},
                    "scheduler": scheduler,
                    "verdict": None if res is None or res.verdict is None
                    else res.verdict.to_dict(),
                    "registration": None if alignment is None else alignment.to_dict(),
                    "moving": None if moving is None else moving.to_dict(),
                    "exposures": (res.exposures.summary().to_dict()
                                  if res is not None and res.exposures is not None else
                                  calib_exposures.summary().to_dict()
                                  if calib_exposures is not None else None)})
        return 0
    print(f"HDR radiance of {len(records)} exposures ({source}), channels "
          f"{', '.join(out.channels)}")
    if res is not None:
        print_exposures(res.exposures)
        print_verdict(res)
    else:
        print_exposures(calib_exposures, table=False)
        for line in (alignment.describe() if alignment is not None else
                     "registration: not tried (frames read by the cluster's workers)",
                     moving.describe() if moving is not None else ""):
            if line:
                say("", line)
    if scheduler != STREAMED_NAME:
        print(f"  merged on {scheduler}")
    for line in out.describe():
        say("", line)
    say("written", "radiance, its sigma (float EXR, one channel per colour) and the flags "
                   "(PNG: 0 merged, 1 dark bound, 2 saturated bound, 3 from bloomed codes, "
                   "4 from one exposure where something moved)")
    for p in paths:
        print(f"  {p}")
    return 0


def _hdr_models(args: argparse.Namespace, session: Any, records: list, reducer: Any
                ) -> tuple[Any, ...]:
    """``hdr``'s response: the calibration's curves at this bracket's exposures, or the fit of
    :func:`ccdcore.response.bracket_fit.fit_bracket` (registered, moving pixels left out).
    Returns the models, their source in words, the response result (``None`` with a
    calibration), the calibration's exposure estimate, the frames (``None``: read by the
    workers), their records, the moving pixels and the registration."""
    from ..product.make import load_product
    from ..reduce import READ_AHEAD
    from ..response.bracket_fit import fit_bracket, register_frames
    from ..response.brackets import check_times, load_bracket
    from ..response.exposures import exposures_with_curves
    from ..response.moving import find_moving

    # read once here for the traces and the merge; with a calibration only when the merge
    # wants the frames as read (streamed)
    frames = (reducer.preload(session, records) if args.calib is not None
              else [f for _, f in session.iter_frames(records, read_ahead=READ_AHEAD)])
    if args.calib is None:
        fit = fit_bracket(session, args.stack, method=args.method, frames=frames,
                          align=args.align, bloom_radius=args.bloom_radius,
                          **response_options(args))
        res = fit.result
        return (res.models(), f"response estimated from this bracket ({res.method})", res,
                None, fit.frames, fit.records, fit.moving, fit.alignment)
    alignment = moving = brackets = None
    if frames is None:
        # the workers read the frames: only what the calibration's models need here
        files = [r.relpath for r in records]
        if session.camera.bits is None:
            raise CcdError(files[0], "the camera's bit depth is unknown: give [camera] "
                                     "bits in the manifest (the response has 2**bits values)")
        levels = 2 ** int(session.camera.bits)
        times = np.sort(check_times([r.exposure for r in records], files), kind="stable")
    else:
        frames, alignment, no_data, keep = register_frames(
            frames, [r.relpath for r in records], args.align)
        records = [records[k] for k in keep]
        brackets = load_bracket(session, args.stack, bloom_radius=args.bloom_radius,
                                frames=frames, records=records, exclude=no_data)
        first = next(iter(brackets.values()))
        levels, times = first.levels, first.t
    models = load_product(args.calib).response_models(args.calib)
    for ch, m in models.items():
        if m.levels != levels:
            raise CcdError(args.calib, f"its response has {m.levels} codes, the bracket's "
                                       f"camera {levels}: another camera?")
    times, calib_exposures = exposures_with_curves(brackets, models, times, args.exposures)
    for ch, m in models.items():
        # the product's a, b were its own bracket's: take this one's exposures
        models[ch] = type(m)(m.g, times.copy(), np.zeros(times.size), m.sigma_s, m.sigma_c1,
                             m.sigma_c2)
    if frames is not None:
        moving = find_moving(frames, models, layout=session.camera.layout,
                             names=[r.relpath for r in records], bloom_radius=args.bloom_radius)
    return (models, f"response of {args.calib}", None, calib_exposures, frames, records,
            moving, alignment)


# --------------------------------------------------------------------------------------------
# parser
# --------------------------------------------------------------------------------------------
def _bloom_arg(p: argparse.ArgumentParser) -> None:
    from ..response.names import DEFAULT_BLOOM_RADIUS, MAX_BLOOM_RADIUS

    p.add_argument("--bloom-radius", type=_bloom_radius, default=DEFAULT_BLOOM_RADIUS,
                   metavar="R", help="pixels within R of a saturated pixel are dropped as "
                                     f"blooming (default {DEFAULT_BLOOM_RADIUS}; 0 keeps them; "
                                     f"at most {MAX_BLOOM_RADIUS})")


def _bracket_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("session", type=Path, help=SESSION_HELP)
    p.add_argument("--stack", type=int, default=None,
                   help="which bracket of the session (its 'stack'; default the first)")
    p.add_argument("--align", choices=("auto", "off"), default="auto",
                   help="register the frames to the bracket's middle one before the fit and the "
                        "merge (auto, the default: frames that moved are resampled, a tripod "
                        "bracket is left as it is; off: taken as they are)")
    _bloom_arg(p)


def add_response(sub: Any) -> None:
    p = add_verb(sub, "response", "inverse camera response g per channel, with its band and the "
                             "noise terms (Tsin et al. 2001 and classic methods)", _cmd_response,
                 needs="an exposure bracket (role = bracket, one exposure per frame)")
    _bracket_args(p)
    response_args(p)
    json_flag(p)


def response_args(p: argparse.ArgumentParser, when: str = "") -> None:
    """``--method``, ``--white-balance`` and ``--exposures``, as every verb that estimates a
    response takes them (``when``: a condition put before each help text)."""
    from ..response.names import DEFAULT_METHOD, EXPOSURE_MODES, METHOD_CHOICES

    p.add_argument("--method", choices=list(METHOD_CHOICES), default=DEFAULT_METHOD,
                   help=f"{when}response estimation method (default {DEFAULT_METHOD}: Tsin, "
                        "Ramesh & Kanade sec. 3.2, unless Debevec & Malik's curve predicts the "
                        "bracket clearly better)")
    p.add_argument("--white-balance", action="store_true",
                   help=f"{when}estimate each image's gain a_k and offset b_k too (tsin; up to a "
                        "common factor and a trend in the exposure, which no bracket fixes)")
    p.add_argument("--exposures", choices=list(EXPOSURE_MODES), default=EXPOSURE_MODES[0],
                   help=f"{when}which exposures the response takes: the bracket's own, "
                        "estimated from its images, when they disagree with the listed ones "
                        "(auto, the default), the listed ones, or the bracket's own always")


def add_hdr(sub: Any) -> None:
    p = add_verb(sub, "hdr",
                 "HDR radiance map and its per-pixel sigma (Tsin et al. eqs. 9, 18, 19)",
                 _cmd_hdr, needs="an exposure bracket; a product's response with --calib")
    _bracket_args(p)
    p.add_argument("--calib", type=Path,
                   help="a calibration product with a response (default: estimate it from "
                        "this bracket)")
    response_args(p, "without --calib: ")
    p.add_argument("-o", "--out-dir", type=Path, required=True,
                   help="folder for radiance.exr, sigma.exr and flags.png")
    cluster_args(p)
    json_flag(p)


def _shade_range(text: str) -> tuple[float, float] | None:
    """``--shade``: ``off`` or ``K_MIN,K_MAX`` with 0 < K_MIN < 1 < K_MAX."""
    if text.strip().lower() == "off":
        return None
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected K_MIN,K_MAX (e.g. 0.5,2) or off, got "
                                         f"{text!r}") from None
    if not 0.0 < lo < 1.0 < hi < float("inf"):
        raise argparse.ArgumentTypeError(f"expected 0 < K_MIN < 1 < K_MAX, got {text!r}")
    return lo, hi


def add_change(sub: Any) -> None:
    p = add_verb(sub, "change",
                 "illumination-invariant change and shadow masks (Tsin et al. sec. 5)",
                 _cmd_change, needs="reference and target frames or brackets (roles reference, "
                                    "target)")
    p.add_argument("session", type=Path, help=SESSION_HELP)
    p.add_argument("--pfa", type=float, default=0.01,
                   help="false-alarm probability per background pixel (default 0.01)")
    p.add_argument("--calib", type=Path,
                   help="a calibration product with a response (default: estimate it from "
                        "a bracket of the session, else assume the sRGB curve)")
    p.add_argument("--response", choices=("auto", "srgb"), default="auto",
                   help="auto (default): the product's response, else one estimated from a "
                        "bracket of the session, else the sRGB curve, stated as an "
                        "assumption; srgb: the sRGB standard curve whatever the session holds")
    p.add_argument("--min-region", type=int, default=None, metavar="PIXELS",
                   help="smallest changed region kept, 8-connected (default: 9, a 3 x 3 block, "
                        "for single frames or frame sets; 1, every pixel, for two brackets)")
    p.add_argument("--shade", type=_shade_range, default=(0.5, 2.0), metavar="K_MIN,K_MAX",
                   help="a pixel whose target is the background's prediction times one factor "
                        "k in this range is a shade of the light (a soft shadow), not change "
                        "(default 0.5,2; colour frames); off: every such pixel is change")
    response_args(p, "without --calib: ")
    _bloom_arg(p)
    p.add_argument("-o", "--out-dir", type=Path, required=True,
                   help="folder for change_mask.png, labels.png, d2.exr, predicted_target.exr")
    cluster_args(p)
    json_flag(p)
