"""The report's sections, one function each, in document order: camera and session, photon
transfer, EMVA 1288 datasheet, dark reference, fixed pattern, acquisition plan, correction check,
scene variation, flat field, response curves, maps, change detection, skipped estimates and
provenance (docs/report.md lists what each holds).

Every section writes into a :class:`ccdcore_report.html.Doc`: its text and tables from the
product's JSON summaries and maps, its plots from :mod:`ccdcore_report.figures` (the EMVA 1288
datasheet's from :mod:`ccdcore_report.emva_figures`). Nothing is estimated here but the SNUP of
the flat-field section's images (:func:`ccdcore.uniformity.snup`).

Public objects
--------------
MAX_HELD_OUT
    Most flat frames (one per flat group) corrected for the held-out SNUP table.
ESTIMATE_TITLES
    Estimate key -> the title the report gives it.
summary_section, noise_section, emva_section, dark_section, fixed_pattern_section,
plan_section, correction_section, scene_section, flat_section, response_section, maps_section,
change_section, skipped_section, provenance_section
    One section each.
"""
from __future__ import annotations

import itertools
import math
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from ccdcore import __version__
from ccdcore.common import format_pm, format_size, sort_key
from ccdcore.datasheet import LINEARITY_RANGE, SENSITIVITY_FRACTION
from ccdcore.emva_sheet import SheetRow, datasheet_rows
from ccdcore.emva_spatial import HIGH_PASS_SIZE
from ccdcore.errors import CcdError
from ccdcore.product import CalibrationProduct, MapName
from ccdcore.session import Session

from . import emva_figures, figures
from .agreement import AGREEMENT_COLUMNS, channel_agreement_rows, pair_rows
from .figures import MAP_SPECS, MapSpec
from .html import (Doc, Html, bullets, esc, facts, finite, json_float, json_floats, num, para,
                   pm, table, value_text)

__all__ = ["MAX_HELD_OUT", "ESTIMATE_TITLES", "summary_section", "noise_section",
           "emva_section", "dark_section", "fixed_pattern_section", "plan_section",
           "correction_section", "scene_section", "flat_section", "response_section",
           "maps_section", "change_section", "skipped_section", "provenance_section"]

#: most flat groups whose first frame is corrected for the held-out SNUP table (one frame
#: read and corrected per group)
MAX_HELD_OUT = 24

ESTIMATE_TITLES = {"noise": "Photon transfer", "dark": "Dark reference",
                   "fixed_pattern": "Fixed pattern", "plan": "Acquisition plan",
                   "correction_check": "Correction check", "scene": "Scene variation",
                   "flat_field": "Flat field", "response": "Response curves",
                   "emva1288": "EMVA 1288 datasheet"}

_VERDICTS = {
    "acceptable": "the line \u03c3\u00b2_N = A\u00b7\u03bc + \u03c3\u00b2_C fits the points "
                  "within their errors",
    "poor": "a poor fit: the points scatter more than their errors allow (Q < 0.05)",
    "model rejected": "the model is rejected (Q < 0.001): the points do not lie on a straight "
                      "line within their errors",
}


# ---------------------------------------------------------------------------------------------
# camera and session
# ---------------------------------------------------------------------------------------------
def _frame_shape(product: CalibrationProduct | None, session: Session | None
                 ) -> tuple[int, ...] | None:
    if session is not None:
        shapes = {tuple(r["shape"]) for r in session.groups_table() if r["shape"] is not None}
        if len(shapes) == 1:
            return shapes.pop()
    if product is not None:
        if product.shape is not None:
            return tuple(product.shape)
        for est in product.estimates.values():
            if isinstance(est, dict) and isinstance(est.get("shape"), list):
                return tuple(int(n) for n in est["shape"])
    return None


def _camera_facts(product: CalibrationProduct, session: Session | None) -> str:
    """The camera and where the session came from (the session's, else the product's record)."""
    cam = product.camera
    prov = product.provenance
    shape = _frame_shape(product, session)
    return facts([
        ("camera", cam.name or "unnamed"),
        ("bit depth", f"{cam.bits} bits" if cam.bits else "unknown"),
        ("colour layout", cam.layout),
        ("frame size (W \u00d7 H)", format_size(shape) if shape else "unknown"),
        ("black level (manifest)", num(cam.black_level, ".6g", "DN")
         if cam.black_level is not None else "not given"),
        ("session", session.label if session is not None else prov.get("session", "unknown")),
        ("session source", session.source if session is not None
         else prov.get("source", "unknown")),
        ("frames", len(session.frames) if session is not None
         else prov.get("n_frames", "unknown")),
    ])


def _roles_table(session: Session) -> str:
    """Every role and group of the session: frames, size, type, the first exposures."""
    rows = []
    for row in session.groups_table():
        key = "" if row["key"] is None else f"{row['key_name']} {value_text(row['key'])}"
        exps = row["exposures"]
        rows.append((row["role"], key, row["count"],
                     format_size(row["shape"]) if row["shape"] else "mixed",
                     row["dtype"] or "mixed",
                     ", ".join(f"{t:g}" for t in exps[:4]) + (" \u2026" if len(exps) > 4
                                                                else "")))
    return table(rows, ("role", "group", "frames", "size", "type", "exposure (s)"),
                 cls="ccd-report-roles", numeric=(2,))


def _made_text(product: CalibrationProduct, change: Any) -> str:
    """Which estimates were made and which skipped, in one sentence."""
    made = [ESTIMATE_TITLES.get(k, k) for k in product.estimates]
    if getattr(product, "emva1288", None):
        made.append(ESTIMATE_TITLES["emva1288"])
    if change is not None:
        made.append("Change detection")
    return ("Estimates made: " + (", ".join(made) if made else "none") + ". Skipped: "
            + (", ".join(ESTIMATE_TITLES.get(s.estimate, s.estimate) for s in product.skipped)
               or "none")
            + " (see Skipped estimates).")


def summary_section(doc: Doc, product: CalibrationProduct, session: Session | None,
                    change: Any) -> None:
    """The camera, the frames by role and group (from a session), what was made and skipped,
    then the product's warnings (those of the plan are in its own section) and notes."""
    with doc.section("summary", "Camera and session"):
        doc.add(_camera_facts(product, session))
        if session is not None:
            doc.add("<h3>Frames by role and group</h3>")
            doc.add(_roles_table(session))
        else:
            doc.add(para("This report was made from a calibration product: the frames' roles "
                         "are not stored in it (the estimates below say what they used).",
                         "note"))
        doc.add(para(_made_text(product, change)))
        plan_warnings = set((product.estimates.get("plan") or {}).get("warnings") or ())
        other = [w for w in product.warnings if w not in plan_warnings]
        if other:
            doc.add("<h3>Warnings</h3>" + bullets(other, "warnings"))
        if product.notes:
            doc.add("<h3>Notes</h3>" + bullets(product.notes))


# ---------------------------------------------------------------------------------------------
# photon transfer
# ---------------------------------------------------------------------------------------------
def _verdict_text(noise: Mapping[str, Any]) -> str:
    verdict = str(noise.get("verdict", ""))
    q = noise.get("Q")
    if not finite(q):
        return ("untested: no degrees of freedom are left (as many light levels as the line "
                "has parameters)")
    return f"Q = {q:.3g}: {_VERDICTS.get(verdict, verdict)}"


def _noise_facts(noise: Mapping[str, Any]) -> str:
    """The fitted line, the noise figures derived from it and the goodness of fit."""
    return facts([
        ("gain A", pm(noise, "A", unit="DN/e\u207b"), "DN per electron"),
        ("conversion gain 1/A",
         pm(noise, "conversion_gain_e_per_dn", unit="e\u207b/DN"), "electrons per DN"),
        ("\u03c3\u00b2_C", pm(noise, "sigma_c2", unit="DN\u00b2"),
         "signal-independent noise, A\u00b2\u03c3\u00b2_R + q\u00b2/12 (eq. 27)"),
        ("read noise \u03c3_R", pm(noise, "read_noise_e", unit="e\u207b"),
         "\u221a(\u03c3\u00b2_C \u2212 q\u00b2/12)/A"),
        ("read noise in DN", pm(noise, "read_noise_dn", unit="DN"), "A\u00b7\u03c3_R"),
        ("quantisation q\u00b2/12", num(noise.get("quantisation_dn2"), ".4g", "DN\u00b2"), ""),
        ("black level b\u2080", num(noise.get("black_level_dn"), ".4g", "DN"),
         str(noise.get("black_level_source") or "")),
        ("\u03c7\u00b2", num(noise.get("chi2"), ".4g"),
         f"with {noise.get('dof')} degrees of freedom"),
        ("goodness of fit Q", num(noise.get("Q"), ".3g"), _verdict_text(noise)),
        ("region", "whole frame" if not noise.get("roi")
         else "ROI " + ", ".join(map(str, noise["roi"])) + " (X, Y, W, H)", ""),
    ])


def _levels_table(noise: Mapping[str, Any]) -> str:
    """Every light level: μ, σ̂²_N ± error, pairs, exposure, used or why not."""
    rows = []
    for p in noise.get("points", ()):
        why = p.get("reason") or p.get("exclusion")
        rows.append((p.get("level"), num(p.get("mu"), ".4f"), pm(p, "var"),
                     p.get("n_pairs"), num(p.get("exposure"), ".4g"),
                     "used" if p.get("used") else f"excluded: {why}"))
    return table(rows, ("level", "\u03bc \u2212 b\u2080 (DN)", "\u03c3\u0302\u00b2_N (DN\u00b2)",
                        "pairs", "exposure (s)", "fit"),
                 cls="ccd-report-points", numeric=(0, 1, 2, 3, 4))


def _ptc_plots(doc: Doc, noise: Mapping[str, Any]) -> None:
    """The app's photon-transfer plots of the summary (a warning when it cannot be read)."""
    from bokeh.layouts import column

    try:
        result = figures.photon_transfer_of(noise)
    except (KeyError, TypeError, ValueError) as exc:
        doc.add(para(f"The photon-transfer plots cannot be drawn from this product: {exc}",
                     "warning"))
        return
    figs = figures.ptc_figures(result)
    doc.plot(column(figs.transfer, figs.residual, sizing_mode="stretch_width"), id_="ptc",
             caption="Photon transfer: \u03c3\u0302\u00b2_N of each light level with its "
                     "standard error (\u221aeq. 40), the fitted line and its 1-\u03c3 band "
                     "from the covariance of (A, \u03c3\u00b2_C) (eq. 66); below, the "
                     "residuals in units of each point's standard error. Hollow grey "
                     "points were left out of the fit (the table says why).")
    doc.plot(figs.loglog, id_="ptc-loglog",
             caption="The same on log axes (EMVA 1288 style): temporal noise \u03c3\u0302_N "
                     "against the signal, with the model, the read-noise floor and the "
                     "shot-noise asymptote.")


def noise_section(doc: Doc, noise: Mapping[str, Any]) -> None:
    """The photon-transfer fit, the levels it used, its notes and its plots."""
    with doc.section("noise", "Photon transfer (noise model)"):
        doc.add(para("Healey & Kondepudy 1994, eqs. 37\u201342 and 59\u201367: the temporal "
                     "noise variance \u03c3\u00b2_N of frame pairs against the mean signal "
                     "\u03bc \u2212 b\u2080, fitted by the weighted line "
                     "\u03c3\u00b2_N = A\u00b7\u03bc + \u03c3\u00b2_C (eq. 41)."))
        doc.add(_noise_facts(noise))
        if noise.get("robust_dropped"):
            doc.add(para("The robust mode dropped levels "
                         + ", ".join(map(str, noise["robust_dropped"])) + "."))
        doc.add("<h3>Light levels</h3>")
        doc.add(_levels_table(noise))
        doc.add(bullets(noise.get("notes") or ()))
        _ptc_plots(doc, noise)


# ---------------------------------------------------------------------------------------------
# Healey & Kondepudy: dark, fixed pattern, plan, correction check, scene
# ---------------------------------------------------------------------------------------------
def dark_section(doc: Doc, d: Mapping[str, Any]) -> None:
    with doc.section("dark", "Dark reference"):
        doc.add(para("Healey & Kondepudy sec. V-A: the mean D\u0302_D of s dark frames, with "
                     "hot and dead pixels flagged by the rules below (maps under Maps)."))
        doc.add(facts([
            ("frames s", d.get("s"), ""),
            ("exposure", num(d.get("exposure"), ".4g", "s"), ""),
            ("mean level", pm(d, "mean", "mean_sem", unit="DN"), "\u00b1 its standard error"),
            ("spatial std", num(d.get("spatial_std"), ".4g", "DN"), "of D\u0302_D"),
            ("spatial std of the signal", num(d.get("spatial_std_signal"), ".4g", "DN"),
             "without the averaging noise \u03c3\u00b2_N/s"),
            ("temporal noise \u03c3\u00b2_N", num(d.get("noise_var"), ".4g", "DN\u00b2"),
             "mean per-pixel variance"),
            ("hot pixels", d.get("n_hot"), str(d.get("hot_rule") or "")),
            ("dead pixels", d.get("n_dead"), str(d.get("dead_rule") or "")),
        ]))
        doc.add(bullets(d.get("notes") or ()))


def fixed_pattern_section(doc: Doc, k: Mapping[str, Any]) -> None:
    bound = k.get("var_bound")
    k_var = k.get("K_var_mean")
    with doc.section("fixed-pattern", "Fixed pattern K\u0302"):
        doc.add(para("Healey & Kondepudy eqs. 45\u201350: per pixel, the mean of the slopes of "
                     "n1 card/lamp configurations kept within centre \u00b1 p\u00b7\u03c3\u0302 "
                     "(maps under Maps)."))
        doc.add(facts([
            ("configurations n1 \u00d7 frames n2", f"{k.get('n1')} \u00d7 {k.get('n2')}", ""),
            ("window, p", f"{k.get('window')}, {value_text(k.get('p'))}",
             "local mean window (pixels) and the rejection width"),
            ("mean of K\u0302", num(k.get("mean"), ".6g"), ""),
            ("spatial spread of K\u0302", num(k.get("spatial_std"), ".4g"), "standard deviation"),
            ("slope spread \u03c3\u0302", num(k.get("sigma_hat"), ".4g"), "eq. 48"),
            ("error of K\u0302 (mean)", num(math.sqrt(k_var) if finite(k_var) else None, ".3g"),
             f"\u221a of the mean error variance {num(k_var, '.3g')}"),
            ("eq. 50 bound", "infinite" if bound is None else num(bound, ".3g"),
             f"error variance bound (std {num(k.get('sd_bound'), '.3g')})"),
            ("pixels with a rejected slope",
             num(100 * k["fraction_pixels_with_rejection"], ".3g", "%")
             if finite(k.get("fraction_pixels_with_rejection")) else "n/a",
             f"{k.get('n_rejected')} slopes rejected in all"),
        ]))
        doc.add(bullets(k.get("notes") or ()))


def plan_section(doc: Doc, p: Mapping[str, Any]) -> None:
    with doc.section("plan", "Acquisition plan"):
        doc.add(para("Healey & Kondepudy sec. V-B: how many card/lamp configurations n1 and "
                     "frames per configuration n2 the fixed-pattern map needs."))
        alternatives = p.get("n2_alternatives") or {}
        doc.add(facts([
            ("n1 (configurations)", p.get("n1_required"), str(p.get("n1_formula") or "")),
            ("n2 (frames each)", p.get("n2_required"), str(p.get("n2_formula") or "")),
            ("reading of the n2 rule", p.get("n2_reading", ""),
             "; ".join(f"{k}: {v}" for k, v in alternatives.items())),
        ]))
        if p.get("warnings"):
            doc.add("<h3>What the session lacks against the plan</h3>")
            doc.add(bullets(p["warnings"], "warnings"))
        doc.add(bullets(p.get("notes") or ()))


def correction_section(doc: Doc, c: Mapping[str, Any]) -> None:
    def pct(key: str) -> str:
        v = c.get(key)
        return num(100 * v, ".3g", "%") if finite(v) else "n/a"

    with doc.section("correction-check", "Correction check"):
        doc.add(para("Healey & Kondepudy sec. VII-A: how much eq. 51 changes a maximum-intensity "
                     "image, in quantisation steps q."))
        doc.add(facts([
            ("pixels changed by more than 1 q", pct("frac_gt_1q"), ""),
            ("pixels changed by more than 2 q", pct("frac_gt_2q"), ""),
            ("largest change", num(c.get("max_change_q"), ".3g", "q"), ""),
            ("mean level of the image", num(c.get("mean_level"), ".4g", "DN"), ""),
        ]))


def scene_section(doc: Doc, scene: Mapping[str, Any]) -> None:
    with doc.section("scene", "Scene variation"):
        doc.add(para("Healey & Kondepudy sec. VI: the relative variance V_S of each uniform "
                     "surface, with the calibration maps' own errors (eqs. 53\u201358)."))
        rows = []
        for name, sv in scene.items():
            used = sum(1 for m in sv.get("measurements", ()) if m.get("used"))
            rows.append((name, pm(sv, "V_S"), num(sv.get("chi2"), ".4g"), sv.get("dof"),
                         num(sv.get("Q"), ".3g"), used, len(sv.get("excluded") or ())))
        doc.add(table(rows, ("patch", "V_S", "\u03c7\u00b2", "dof", "Q", "levels used",
                             "excluded"), cls="ccd-report-scene", numeric=(1, 2, 3, 4, 5, 6)))
        notes = sorted({n for sv in scene.values() for n in (sv.get("notes") or ())})
        doc.add(bullets(notes))


# ---------------------------------------------------------------------------------------------
# flat field
# ---------------------------------------------------------------------------------------------
def _snup_rows(result: Any) -> dict[str, str]:
    return {c.name: format_pm(c.snup, c.snup_err, unit="%") for c in result.channels}


def _flat_facts(ff: Mapping[str, Any]) -> str:
    base = ff.get("base")
    return facts([
        ("offset setting", ff.get("setting") or "none named", ""),
        ("base image", "level {}, exposure {} s".format(*base) if base and len(base) == 2
         else "n/a", f"{ff.get('n_base')} frames averaged"),
        ("dark image", f"{ff.get('n_dark')} frames",
         f"exposure {num(ff.get('dark_exposure'), '.4g', 's')}"),
        ("flagged pixels", ff.get("n_flagged"), str(ff.get("flag_rule") or "")),
    ])


def _flat_channels_table(ff: Mapping[str, Any]) -> str:
    rows = [(c.get("name"), num(c.get("k"), ".5g"), num(c.get("dark_level"), ".4g"),
             num(c.get("base_level"), ".4g"), c.get("n_flagged"),
             num(100 * c["dark_zero_fraction"], ".3g", "%")
             if finite(c.get("dark_zero_fraction")) else "n/a")
            for c in ff.get("channels", ())]
    return table(rows, ("channel", "k (DN)", "\u27e8DL_0\u27e9 (DN)", "\u27e8DL_B\u27e9 (DN)",
                        "flagged", "dark pixels at 0"),
                 cls="ccd-report-flat-channels", numeric=(1, 2, 3, 4, 5))


def _base_snup(doc: Doc, product: CalibrationProduct, layout: str) -> None:
    """SNUP of the base image DL_B and of DL_B − DL_0 per channel, from the maps."""
    from ccdcore.uniformity import snup

    if MapName.FLAT_BASE not in product.maps or MapName.FLAT_DARK not in product.maps:
        return
    dlb, dl0 = product.maps[MapName.FLAT_BASE], product.maps[MapName.FLAT_DARK]
    try:
        raw = _snup_rows(snup(dlb, layout=layout, where=MapName.FLAT_BASE))
        sub = _snup_rows(snup(dlb.astype(np.float64) - dl0, layout=layout,
                              where="flat_base - flat_dark"))
    except CcdError as err:
        doc.add(para(f"SNUP of the base image: {err}", "warning"))
        return
    doc.add("<h3>SNUP of the base image, before correction</h3>")
    doc.add(table([(ch, raw[ch], sub.get(ch, "n/a")) for ch in raw],
                  ("channel", "SNUP of DL_B", "SNUP of DL_B \u2212 DL_0"),
                  cls="ccd-report-snup ccd-report-snup-base", numeric=(1, 2)))
    doc.add(para("After correction the base image is flat by construction (G is made from "
                 "it); the held-out frames below measure the correction.", "note"))


def flat_section(doc: Doc, product: CalibrationProduct, session: Session | None) -> None:
    """The flat field's inputs and per-channel figures, the base image's SNUP and the SNUP of
    held-out frames before and after correction."""
    ff = product.estimates["flat_field"]
    layout = str(ff.get("layout") or product.camera.layout)
    with doc.section("flat-field", "Flat field"):
        doc.add(para("De Lasarte et al. 2007: DL_c = O + G\u00b7DL (eqs. 1\u20134) per channel, "
                     "from the dark image DL_0 and the base image DL_B (maps under Maps). "
                     "SNUP = 100\u00b7\u03c3/mean (eq. 5) measures the nonuniformity."))
        doc.add(_flat_facts(ff))
        doc.add(_flat_channels_table(ff))
        doc.add(bullets(ff.get("notes") or ()))
        _base_snup(doc, product, layout)
        _held_out(doc, product, session, layout)


def _held_out_keys(session: Session, ff: Mapping[str, Any]) -> tuple[list[Any], Any]:
    """The flat groups other than the base, those at the base's exposure first, and the groups
    themselves."""
    base = tuple(ff.get("base") or ())
    groups = session.flat_groups(setting=ff.get("setting"))
    base_t = base[1] if len(base) == 2 else None
    keys = sorted((k for k in groups if tuple(k) != base),
                  key=lambda k: (tuple(k)[1:2] != (base_t,), sort_key(tuple(k))))
    return keys, groups


def _held_out_rows(rec: Any, key: Any, before: Any, after: Any) -> list[str]:
    """One row per channel of a held-out frame; the frame, level, exposure and mean span them."""
    level, exposure = (tuple(key) + (None, None))[:2]
    mean = float(np.mean([c.mean for c in before.channels]))
    b, a = _snup_rows(before), _snup_rows(after)
    n = len(b)
    rows = []
    for i, ch in enumerate(b):
        lead = "".join(f'<td rowspan="{n}"{cls}>{esc(v)}</td>' for v, cls in (
            (rec.relpath, ""), (value_text(level), ' class="num"'),
            (num(exposure, ".4g"), ' class="num"'), (num(mean, ".4g"), ' class="num"'))
                       ) if i == 0 else ""
        first = ' class="first"' if i == 0 else ""
        rows.append(f'<tr{first}>{lead}<td>{esc(ch)}</td>'
                    f'<td class="num">{esc(b[ch])}</td>'
                    f'<td class="num">{esc(a.get(ch, "n/a"))}</td></tr>')
    return rows


def _held_out(doc: Doc, product: CalibrationProduct, session: Session | None,
              layout: str) -> None:
    """SNUP before and after correction of the first frame of each flat group other than the
    base (the groups at the base's exposure first; at most :data:`MAX_HELD_OUT`), when the
    session is at hand."""
    from ccdcore.flatfield import correct
    from ccdcore.uniformity import snup

    doc.add("<h3>SNUP of held-out flat frames, before and after correction</h3>")
    if session is None or MapName.FLAT_G not in product.maps:
        doc.add(para("Not measured: the report was made from the calibration product alone. "
                     "Make it from the session (ccdcore report SESSION) to correct one frame of "
                     "each flat group that G was not made from.", "note"))
        return
    keys, groups = _held_out_keys(session, product.estimates["flat_field"])
    if not keys:
        doc.add(para("None: every flat frame belongs to the base group.", "note"))
        return
    G, O = product.maps[MapName.FLAT_G], product.maps[MapName.FLAT_O]
    body, problems = [], []
    for key in keys[:MAX_HELD_OUT]:
        rec = groups[key][0]
        try:
            frame = session.read(rec)
            before = snup(frame, layout=layout, where=rec.relpath)
            after = snup(correct(frame, G, O, where=rec.relpath), layout=layout,
                         where=rec.relpath)
        except CcdError as err:
            problems.append(str(err))
            continue
        body += _held_out_rows(rec, key, before, after)
    if body:
        head = "".join(f"<th>{esc(h)}</th>" for h in (
            "frame", "level", "exposure (s)", "mean (DN)", "channel", "SNUP before",
            "SNUP after"))
        doc.add(f'<table class="ccd-report-snup ccd-report-snup-held-out"><thead><tr>{head}'
                f'</tr></thead><tbody>{"".join(body)}</tbody></table>')
    more = len(keys) - MAX_HELD_OUT
    doc.add(para("The first frame of each flat group but the base (those at the base's "
                 "exposure first), corrected with the product's G and O; SNUP \u00b1 its "
                 "standard error per channel, the mean before correction."
                 + (f" {more} more group{'s' if more > 1 else ''} not shown." if more > 0
                    else ""), "note"))
    doc.add(bullets(problems, "warnings"))


# ---------------------------------------------------------------------------------------------
# response curves
# ---------------------------------------------------------------------------------------------
def _response_noise_table(r: Mapping[str, Any], channels: Sequence[str]) -> str:
    """Per channel σ_s, σ_c1, σ_c2 ± errors, iterations, convergence, white balance."""
    rows = []
    for i, ch in enumerate(channels):
        def pick(key: str) -> Any:
            v = r.get(key)
            return v[i] if isinstance(v, list) and i < len(v) else None

        rows.append((ch,
                     format_pm(json_float(pick("sigma_s")), pick("sigma_s_err")),
                     format_pm(json_float(pick("sigma_c1")), pick("sigma_c1_err")),
                     format_pm(json_float(pick("sigma_c2")), pick("sigma_c2_err"), unit="DN"),
                     pick("iterations"), "yes" if pick("converged") else "no",
                     "yes" if pick("white_balance") else "no"))
    return table(rows, ("channel", "\u03c3_s", "\u03c3_c1", "\u03c3_c2", "iterations",
                        "converged", "white balance"),
                 cls="ccd-report-response-noise", numeric=(1, 2, 3, 4))


def _g_table(channels: Sequence[str], gs: Sequence[NDArray], errs: Sequence[NDArray],
             levels: int) -> str:
    """g ± error of every channel at six codes (5 % to 95 % of the range)."""
    top = levels - 1
    codes = sorted({round(top * f) for f in (0.05, 0.1, 0.25, 0.5, 0.75, 0.95)})
    errs_or_none = errs if len(errs) == len(gs) else [np.empty(0)] * len(gs)
    rows = [[z] + [format_pm(float(g[z]), float(e[z]) if z < e.size else None)
                   if z < g.size else "n/a" for g, e in zip(gs, errs_or_none)]
            for z in codes]
    return table(rows, ["code z"] + [f"g, {ch}" for ch in channels],
                 cls="ccd-report-response-g", numeric=tuple(range(len(channels) + 1)))


def response_section(doc: Doc, r: Mapping[str, Any]) -> None:
    """The response's noise terms per channel, its exposures, g at six codes, the prediction
    agreement, the notes and the curves with their bands."""
    channels = [str(c) for c in r.get("channels", ())]
    scale = r.get("scale") or {}
    with doc.section("response", "Response curves"):
        doc.add(para("Tsin, Ramesh & Kanade 2001, sec. 3.2: the inverse response g per channel "
                     f"by {r.get('method')}, with its band and the noise terms of eq. 7 "
                     f"(\u03c3_s and \u03c3_c1 in units of g, \u03c3_c2 in DN). Scale: "
                     f"g({scale.get('fixed_code')}) = "
                     f"{num(scale.get('g_at_fixed_code'), '.4g')}."))
        doc.add(_response_noise_table(r, channels))
        times = r.get("exposure_times") or []
        doc.add(para(f"{len(times)} exposures: " + ", ".join(num(t, ".4g") for t in times)
                     + " s; bloom radius " + value_text(r.get("bloom_radius")) + " px."))
        gs = [json_floats(g) for g in r.get("g") or ()]
        errs = [json_floats(e) for e in r.get("g_err") or ()]
        levels = int(r.get("levels") or (gs[0].size if gs else 0))
        if gs and levels > 1:
            doc.add(_g_table(channels, gs, errs, levels))
        _agreement_tables(doc, r)
        notes = r.get("notes") or {}
        if isinstance(notes, dict):
            doc.add(bullets(f"{ch}: {n}" for ch, ns in notes.items() for n in ns))
        else:
            doc.add(bullets(notes))
        if not gs:
            return
        doc.plot(figures.response_figures(channels, gs, errs), id_="response-curves",
                 caption="g(z) of every channel with its \u00b12\u03c3 band; below, the 1\u03c3 "
                         "error itself (0 at the fixed code, which sets the scale).")


def _agreement_tables(doc: Doc, r: Mapping[str, Any]) -> None:
    """The response's prediction agreement (Tsin et al. sec. 4.2, ``r["agreement"]``): the
    pooled figures and each channel's, then each pair of neighbouring images per channel."""
    a = r.get("agreement")
    if not isinstance(a, dict):
        return
    rng = a.get("code_range") or ("?", "?")
    doc.add(para(f"How well the curves predict the bracket's own images (sec. 4.2), in DN "
                 f"over the codes {rng[0]}..{rng[-1]} both images read: each image from a "
                 "neighbour with the result's exposure ratio, with each pair's ratio fitted "
                 "(the difference is what exposure errors cost), and from the blend of all "
                 "the other images."))
    rows = channel_agreement_rows(a)
    header = ["channel", *AGREEMENT_COLUMNS.values(), "predictions"]
    doc.add(table([[row[h] for h in header] for row in rows], header,
                  cls="ccd-report-response-agreement", numeric=(1, 2, 3, 4)))
    pairs = pair_rows(a, json_floats(r.get("exposure_times")))
    if pairs:
        header = list(pairs[0])
        doc.add(table([[row.get(h, "n/a") for h in header] for row in pairs], header,
                      cls="ccd-report-response-pairs", numeric=tuple(range(2, len(header)))))
        doc.add(para("Per pair of neighbouring images (numbered from 1, shortest exposure "
                     "first): the RMS with the result's ratio, with the pair's fitted ratio, "
                     "and the fitted ratio over the nominal t_k / t_j. A frame with a wrong "
                     "exposure time, or one that moved, shows in the pairs it takes part in.",
                     "note"))


# ---------------------------------------------------------------------------------------------
# maps
# ---------------------------------------------------------------------------------------------
def _product_maps(product: CalibrationProduct) -> dict[str, NDArray]:
    """The maps to draw: the product's, with hot and dead combined and K̂'s error as a
    standard deviation."""
    maps = dict(product.maps)
    out: dict[str, NDArray] = {}
    if MapName.HOT in maps or MapName.DEAD in maps:
        shape = (maps[MapName.HOT] if MapName.HOT in maps else maps[MapName.DEAD]).shape
        hot = maps.pop(MapName.HOT, np.zeros(shape, np.float32)) > 0
        dead = maps.pop(MapName.DEAD, np.zeros(shape, np.float32)) > 0
        out["hot_dead"] = np.where(dead, 2, np.where(hot, 1, 0)).astype(np.float32)
    if MapName.K_VAR in maps:
        out["K_err"] = np.sqrt(np.maximum(maps.pop(MapName.K_VAR), 0.0)).astype(np.float32)
    out.update(maps)
    order = {k: i for i, k in enumerate(figures.MAP_ORDER)}
    return dict(sorted(out.items(), key=lambda kv: (order.get(kv[0], len(order)), kv[0])))


def _planes(name: str, data: NDArray, layout: str) -> dict[str, NDArray]:
    """Channel -> 2-D plane of a map (one plane ``""`` for mono maps)."""
    from ccdcore.channels import Layout, split_channels

    if data.ndim == 2 and (not name.startswith("flat_") or layout == Layout.MONO):
        return {"": data}
    try:
        return split_channels(data, layout)
    except CcdError:
        if data.ndim == 3:
            return {f"channel {i}": data[..., i] for i in range(data.shape[2])}
        return {"": data}


def _map_families(product: CalibrationProduct) -> dict[str, list[tuple[str, dict[str, NDArray]]]]:
    """The product's maps split into channel planes, by family (flat field; dark reference and
    fixed pattern; others), in drawing order."""
    flat = product.estimates.get("flat_field") or {}
    layout = str(flat.get("layout") or product.camera.layout or "mono")
    families: dict[str, list[tuple[str, dict[str, NDArray]]]] = {}
    for name, data in _product_maps(product).items():
        family = ("Flat field" if name.startswith("flat_") else
                  "Dark reference and fixed pattern" if name in MAP_SPECS else "Other maps")
        families.setdefault(family, []).append((name, _planes(name, np.asarray(data), layout)))
    return families


def maps_section(doc: Doc, product: CalibrationProduct) -> None:
    """Every map of the product, by family: the one-plane maps side by side in one row, each
    colour or Bayer map in a row of its own (one figure per channel)."""
    families = _map_families(product)
    if not families:
        return
    with doc.section("maps", "Maps"):
        doc.add(para("Every map of the calibration product, each in its own colour scale "
                     "(0.5\u201399.5 % of the values drawn); hover for the value under the "
                     "cursor, drag to pan, scroll to zoom."))
        for family, entries in families.items():
            doc.add(f"<h3>{esc(family)}</h3>")
            singles = [(n, p) for n, p in entries if len(p) == 1]
            rows = ([singles] if singles else []) + [[(n, p)] for n, p in entries if len(p) > 1]
            for row in rows:
                doc.add('<div class="ccd-map-row">')
                empty = [note for name, planes in row for note in _map_plots(doc, name, planes)]
                doc.add("</div>")
                doc.add("".join(empty))


def _map_plots(doc: Doc, name: str, planes: Mapping[str, NDArray]) -> list[str]:
    """One figure per channel plane of the map ``name``, each with its caption; flag maps
    without a flagged pixel are not drawn: their notes are returned instead."""
    spec = MAP_SPECS.get(name, MapSpec(name))
    labels = figures.FLAT_FLAG_LABELS if name == MapName.FLAT_FLAGS else None
    how = "maximum" if spec.kind in ("flags", "count") else "mean"
    n = len(planes)
    side = min(380, (figures.CONTENT_WIDTH - (n - 1) * figures.MAP_GAP) // n
               - figures.MAP_MARGIN)
    empty: list[str] = []
    for channel, plane in planes.items():
        title = spec.title + (f" \u2014 {channel}" if channel else "")
        key = f"map-{name}" + (f"-{channel}" if channel else "")
        if spec.kind == "flags" and not np.any(np.nan_to_num(plane)):
            empty.append(f'<p class="note ccd-report-empty-map" id="{esc(key)}">{esc(title)}: '
                         "no pixel is flagged (map not drawn).</p>")
            continue
        fig, factor = figures.map_figure(plane, spec, title=title, side=side, labels=labels)
        caption = " ".join(p for p in (
            (spec.note[0].upper() + spec.note[1:] + ".") if spec.note else "",
            figures.resolution_text(plane.shape, factor, how)) if p)
        doc.plot(fig, id_=key, caption=caption, cls="ccd-report-map",
                 width=fig.frame_width + figures.MAP_MARGIN)
    return empty


# ---------------------------------------------------------------------------------------------
# change detection
# ---------------------------------------------------------------------------------------------
def _matrix_text(M: Sequence[Sequence[float]], err: Sequence[Sequence[float]]) -> Html:
    """A matrix with the error of each element, as a small table."""
    rows = "".join("<tr>" + "".join(f"<td>{esc(format_pm(float(v), float(e)))}</td>"
                                    for v, e in zip(row, erow)) + "</tr>"
                   for row, erow in zip(M, err))
    return Html(f'<table class="matrix">{rows}</table>')


def _change_facts(summary: Mapping[str, Any]) -> str:
    """The false-alarm rates, both thresholds, the d² scale and the pixel counts."""
    return facts([
        ("false-alarm rate requested", num(summary.get("pfa_requested"), ".3g"),
         "per background pixel"),
        ("threshold d\u00b2", num(summary.get("threshold"), ".4g"),
         f"calibrated on {summary.get('background_sample')} background values"),
        ("\u03c7\u00b2 threshold", num(summary.get("threshold_chi2"), ".4g"),
         f"{summary.get('dof')} degrees of freedom, without the calibration"),
        ("observed false-alarm rate", num(summary.get("pfa_observed"), ".3g"),
         f"{num(summary.get('pfa_observed_at_chi2_threshold'), '.3g')} at the \u03c7\u00b2 "
         "threshold"),
        ("d\u00b2 scale", num(summary.get("d2_scale"), ".4g"),
         "median background d\u00b2 over \u03c7\u00b2's median"),
        ("background mean d\u00b2", num(summary.get("background_d2_mean"), ".3g"), ""),
        ("changed pixels", summary.get("changed_pixels"), ""),
        ("undetermined pixels", summary.get("undetermined_pixels"),
         "no radiance in one of the brackets"),
    ])


def _clusters_table(summary: Mapping[str, Any]) -> str:
    rows = []
    for c in summary.get("clusters", ()):
        rows.append((c["label"], figures.label_name(int(c["label"])), c["pixels"],
                     num(c.get("d2_median"), ".3g"), _matrix_text(c["M"], c["M_err"])))
    return table(rows, ("label", "cluster", "pixels", "median d\u00b2", "M \u00b1 error"),
                 cls="ccd-report-clusters", numeric=(0, 2, 3))


def _change_maps(doc: Doc, change: Any) -> None:
    """The label map with a legend of the pixel counts, and the d² map, side by side."""
    labels = np.asarray(change.labels)
    h, w = labels.shape
    counts = change.counts()
    factor = figures.map_factor(labels.shape)
    fig = figures.change_label_figure(labels, counts, factor)
    legend = "".join(
        f'<li><span class="swatch" style="background:{figures.label_colour(lab)}"></span>'
        f"{esc(lab)}: {esc(figures.label_name(lab))} \u2014 {n:,} pixels</li>"
        for lab, n in sorted(counts.items()))
    caption = Html('Labels of every pixel: <ul class="ccd-change-legend legend">' + legend
                   + "</ul>" + esc(figures.resolution_text((h, w), factor, "maximum")))
    doc.add('<div class="ccd-map-row">')
    doc.plot(fig, id_="change-labels", caption=caption, width=fig.frame_width + figures.MAP_MARGIN)
    fig = figures.change_d2_figure(np.asarray(change.d2_best, np.float64), factor)
    doc.plot(fig, id_="change-d2",
             caption="d\u00b2 of every pixel under the cluster that explains it best "
                     f"(logarithmic colour scale; threshold {num(change.threshold, '.4g')}). "
                     + figures.resolution_text((h, w), factor, "mean"),
             width=fig.frame_width + figures.MAP_MARGIN)
    doc.add("</div>")


def change_section(doc: Doc, change: Any, inputs: Mapping[str, Any] | None) -> None:
    """Change detection (Tsin et al. sec. 5): the response used, the thresholds, each cluster
    with its transform M, then the label and d² maps."""
    summary = change.to_dict()
    with doc.section("change", "Change detection"):
        doc.add(para("Tsin, Ramesh & Kanade 2001, sec. 5: the reference and target brackets as "
                     "radiance with its per-pixel sigma; one colour transform M per cluster "
                     "(background, each shade of shadow), d\u00b2 of each pixel under it, and "
                     "the threshold calibrated on the background for the requested false-alarm "
                     "rate."))
        if inputs:
            doc.add(para(f"Response: {inputs.get('source', 'n/a')}; channels "
                         f"{', '.join(map(str, inputs.get('channels', ())))}."))
        doc.add(_change_facts(summary))
        doc.add(_clusters_table(summary))
        doc.add(bullets(summary.get("notes") or ()))
        _change_maps(doc, change)


# ---------------------------------------------------------------------------------------------
# EMVA 1288 datasheet
# ---------------------------------------------------------------------------------------------
def _columns(obj: Any, wanted: Mapping[str, Sequence[str]]) -> dict[str, NDArray[np.float64]]:
    """Columns of a dict of lists or a list of dicts: name -> values of the first key of
    ``wanted[name]`` present (names without any are left out)."""
    out: dict[str, NDArray[np.float64]] = {}
    if isinstance(obj, dict):
        for name, keys in wanted.items():
            key = next((k for k in keys if k in obj), None)
            if key is not None and isinstance(obj[key], list):
                out[name] = json_floats(obj[key])
    elif isinstance(obj, list) and all(isinstance(p, dict) for p in obj):
        for name, keys in wanted.items():
            key = next((k for k in keys if obj and k in obj[0]), None)
            if key is not None:
                out[name] = json_floats([p.get(key) for p in obj])
    n = min((v.size for v in out.values()), default=0)
    return {k: v[:n] for k, v in out.items()}


def _sheet_value(row: SheetRow) -> str:
    """A datasheet row's value ± error with its unit, or "not determined"."""
    if row.value is None:
        return "not determined"
    return format_pm(row.value, row.error, unit=row.unit)


def _datasheet_table(rows: Sequence[SheetRow]) -> str:
    """The datasheet's rows grouped by the standard's sections, in its order: name, symbol,
    value ± error and, when a figure is not determined, a column with the reason (and the
    bound the data give)."""
    why = any(r.note for r in rows)
    out = ['<table class="ccd-report-emva ccd-report-datasheet"><thead><tr><th>figure</th>'
           "<th>symbol</th><th style=\"text-align: right\">value</th>"
           + ("<th>why not determined</th>" if why else "") + "</tr></thead>"]
    for section, group in itertools.groupby(rows, key=lambda r: r.section):
        out.append(f'<tbody><tr class="ccd-sheet-group"><th colspan="{4 if why else 3}" '
                   'scope="rowgroup" style="background: #f6f8fa">' f"{esc(section)}</th></tr>")
        for r in group:
            out.append(f"<tr><td>{esc(r.name)}</td><td>{esc(r.symbol)}</td>"
                       f'<td class="num">{esc(_sheet_value(r))}</td>'
                       + (f"<td>{esc(r.note or '')}</td>" if why else "") + "</tr>")
        out.append("</tbody>")
    out.append("</table>")
    return "".join(out)


def _note_of(rows: Sequence[SheetRow], key: str) -> str:
    """The reason the datasheet gives for ``key`` not being determined ("" when it is)."""
    return next((r.note or "" for r in rows if r.key == key), "")


def _sentence(text: str) -> str:
    text = text.strip()
    return text if not text or text.endswith(".") else text + "."


def _transfer_plots(doc: Doc, emva: Mapping[str, Any]) -> None:
    """Sensitivity, linearity and noise (sec. 6.6, 2.3, 6.7): the photon transfer, the SNR,
    the linearity and its deviation, each when its data are in the figures."""
    doc.add("<h3>Sensitivity, linearity and noise</h3>")
    drawn = len(doc.roots)
    lo, hi = (round(100 * f) for f in LINEARITY_RANGE)
    pts = _columns(emva.get("points"), {k: (k,) for k in (
        "u_p", "u_y", "u_y_dark", "s2_y", "s2_y_dark", "u_y_err", "s2_y_err",
        "in_sensitivity_fit", "in_linearity_fit")})
    if {"u_y", "u_y_dark", "s2_y", "s2_y_dark"} <= set(pts):
        doc.plot(figures.emva_ptc_figure(pts), id_="emva-ptc",
                 caption="Photon transfer (sec. 6.6): the temporal variance of the signal "
                         "against its mean, both less their dark values, with the standard "
                         "errors of \u03c3\u00b2_y. The slope of the filled points (up to "
                         f"{round(100 * SENSITIVITY_FRACTION)} % of saturation) is the system "
                         "gain K; hollow points are outside that fit. Read: a linear camera "
                         "with shot noise puts the points on a straight line through the "
                         "origin; the bend at the top is saturation.")
    snr = _columns(emva.get("snr_curve"), {"u_p": ("u_p",), "snr": ("snr", "snr_measured"),
                                           "model": ("snr_model",), "total": ("snr_total",)})
    if "u_p" in snr and ("snr" in snr or "model" in snr):
        doc.plot(figures.emva_snr_figure(snr), id_="emva-snr",
                 caption="Signal-to-noise ratio (sec. 2.3): the measured SNR (eq. 10) against "
                         "the mean number of photons per pixel, with the model of the "
                         "temporal noise (eq. 11) and, with the spatial sets, the model with "
                         "DSNU1288 and PRNU1288 added (log-log). Read: the slope is 1 where "
                         "the dark noise dominates, \u00bd where the photon shot noise does; "
                         "the highest point is SNR_max, at saturation.")
    if {"u_p", "u_y", "u_y_dark"} <= set(pts):
        doc.plot(figures.emva_linearity_figure(pts), id_="emva-linearity",
                 caption="Linearity (sec. 6.7): the mean signal less the dark signal against "
                         f"the irradiation; filled: the points between {lo} and {hi} % of "
                         "saturation that the line is fitted to, hollow: outside it. Read: a "
                         "linear camera gives a straight line; its deviation is drawn next.")
    fig = emva_figures.linearity_deviation_figure(emva)
    if fig is not None:
        doc.plot(fig, id_="emva-linearity-deviation",
                 caption="Deviation from linearity (sec. 6.7): 100\u00b7(Y \u2212 (a\u00b7\u03bc_p "
                         "+ b))/(a\u00b7\u03bc_p + b) % of each point, with Y = \u03bc_y \u2212 "
                         "\u03bc_y.dark and the line a\u00b7\u03bc_p + b fitted to the filled "
                         f"points ({lo}\u2013{hi} % of saturation); LE_min and LE_max are "
                         "their extreme deviations. Hollow grey: outside the fit; a triangle "
                         "at the edge stands for a point off the scale (hover for its value). "
                         "Read: a linear camera scatters about zero by its temporal noise; a "
                         "systematic bow is a nonlinear response.")
    if len(doc.roots) == drawn:
        doc.add(para("No photon-transfer, SNR or linearity plots: the figures hold no light "
                     "points.", "note"))


def _dark_caption(emva: Mapping[str, Any], rows: Sequence[SheetRow], which: str) -> str:
    """What a dark-current plot shows, the dark current it gives and, when not determined,
    why; then how to read it."""
    dc = emva.get("dark_current")
    line = dc.get(f"{which}_line") if isinstance(dc, dict) else None
    fit = ""
    if isinstance(line, dict) and finite(line.get("chi2_dof")):
        fit = (f" The points scatter about the line with \u03c7\u00b2/\u03bd = "
               f"{line['chi2_dof']:.3g} (\u03bd = {line.get('dof')}).")
    note = _note_of(rows, f"u_I_{which}").strip().rstrip(".")
    result = (f"not determined ({note})." if note
              else emva_figures.dark_current_text(emva, which) + ".")
    if which == "mean":
        return ("Dark signal against exposure time (sec. 3.1, 7.1): the mean \u03bc_y.dark of "
                "the two dark frames at each exposure time with its standard error, and the "
                "least-squares line \u03bc_y.dark(0) + K\u00b7\u03bc_I\u00b7t, whose slope "
                f"divided by K is the dark current from the mean: {result}{fit} Read: "
                "the points lie on the line when the dark current is steady; a slope "
                "within its error of zero means this exposure range is too short to see it; "
                "a camera that compensates the dark current keeps this line flat.")
    return ("Dark variance against exposure time (sec. 3.1, 7.1): the temporal variance "
            "\u03c3\u00b2_y.dark at each exposure time (from the difference of its two dark "
            "frames) with its standard error, and the least-squares line "
            "K\u00b2(\u03c3\u00b2_d + \u03bc_I\u00b7t) + \u03c3\u00b2_q, whose slope divided "
            f"by K\u00b2 is the dark current from the variance: {result}{fit} Read: the "
            "dark electrons are shot noise, so this estimate agrees with the one from the "
            "mean; it still gives the dark current when the camera compensates the mean "
            "(sec. 3.1).")


def _dark_plots(doc: Doc, emva: Mapping[str, Any], rows: Sequence[SheetRow]) -> None:
    """Dark current (sec. 3.1, 7.1): the dark signal and the dark variance against time."""
    doc.add("<h3>Dark current</h3>")
    drawn = False
    for which, id_, build in (("mean", "emva-dark-signal", emva_figures.dark_signal_figure),
                              ("var", "emva-dark-variance",
                               emva_figures.dark_variance_figure)):
        fig = build(emva)
        if fig is not None:
            doc.plot(fig, id_=id_, caption=_dark_caption(emva, rows, which))
            drawn = True
    if not drawn:
        points = emva.get("dark_points")
        why = (_note_of(rows, "u_I_mean") if isinstance(points, list) and points else
               "the product holds no dark points (it was made before they were kept)")
        doc.add(para("No dark-current plots: " + _sentence(why), "note"))


#: the image each spectrogram is made of (sec. 8.2)
_SPECTROGRAM_CAPTIONS = {
    "DSNU": "the average dark image (DN)",
    "PRNU": "the signal image, the average bright image less the average dark one (% of its "
            "mean)",
}


def _spectrogram_caption(which: str) -> str:
    kind, direction = which.split("_")
    along, other = ("each row", "rows") if direction == "horizontal" else ("each column",
                                                                           "columns")
    total, stack = (("DSNU1288 (in DN)", "\u03c3_y.stack.dark") if kind == "DSNU"
                    else ("PRNU1288", "\u03c3_y.stack"))
    return (f"{direction.capitalize()} spectrogram of the {kind} (sec. 8.2): the standard "
            f"deviation of each spatial frequency along {along} of "
            f"{_SPECTROGRAM_CAPTIONS[kind]}, averaged over the {other} (log scale); the value "
            f"at frequency 0 is the variation of the {other}' means. The lines are {total}, "
            f"the temporal noise of one frame {stack} and what is left of it in the average "
            f"of the L frames, {stack}/\u221aL. Read: a pixel-to-pixel (white) "
            "nonuniformity is flat; peaks are periodic patterns; a rise towards low "
            "frequencies is shading. Where the spectrum lies on the white-noise floor, the "
            "temporal noise left in the average hides any fixed pattern.")


def _histogram_caption(which: str, accumulated: bool) -> str:
    image = ("the deviation of each pixel of the average dark image from its mean, in e\u207b"
             if which == "DSNU" else
             f"the signal image (average bright less average dark) after the "
             f"{HIGH_PASS_SIZE} \u00d7 {HIGH_PASS_SIZE} high-pass filter of sec. 8.3 (each "
             "pixel less the mean of its neighbourhood, which removes shading), in % of the "
             "mean signal")
    if accumulated:
        return (f"Accumulated histogram of the {which} (sec. 4.3.2, 8.3): the percentage of "
                f"pixels whose absolute deviation from the mean is x or more, for {image} "
                "(log scale). Read: at a tolerance x the curve gives the share of pixels a "
                "defect list with that threshold would hold; a long flat tail after the fall "
                "is a population of defect pixels.")
    tails = ("hot pixels lie to the right" if which == "DSNU" else
             "pixels far left respond much less than their neighbours, far right much more")
    return (f"Logarithmic histogram of the {which} (sec. 4.3.1, 8.3): the number of pixels "
            f"in each of equal bins of {image} (log scale, empty bins left out), with the "
            "normal distribution of the same mean and standard deviation. Read: a normal "
            "nonuniformity follows the model, an inverted parabola on this scale; pixels in "
            f"tails far beyond it are defect pixels ({tails}).")


def _profile_caption(which: str) -> str:
    line, other = ("column", "row") if which == "horizontal" else ("row", "column")
    return (f"{which.capitalize()} profiles (sec. 8.4): for each {line}, the mean, minimum "
            f"and maximum over its pixels and its value in the middle {other} of the image; "
            "above for the signal (the average bright image less the average dark one), "
            f"below for the average dark image, in DN (a very wide image is drawn in blocks "
            f"of neighbouring {line}s). Read: shading shows as a trend of the mean, {line} "
            "patterns as a jagged mean; lone spikes of the minimum or maximum are single "
            "defect pixels.")


def _spatial_absent(emva: Mapping[str, Any]) -> str:
    """Why the figures hold no spatial plots."""
    if ("spatial" in emva or "spatial_dark" in emva) and not (
            emva.get("spatial") and emva.get("spatial_dark")):
        return ("the session has no spatial sets (L bright frames at one operating point and "
                "L dark frames at its exposure, sec. 8)")
    notes = [n for n in emva.get("notes") or () if isinstance(n, str)]
    return next((n for n in notes if "no spatial plots" in n),
                "the product holds no spatial plots (it was made before ccdcore drew them)")


def _spatial_plots(doc: Doc, emva: Mapping[str, Any]) -> None:
    """Spatial nonuniformity and defect pixels (sec. 4, 8): the four spectrograms, the two
    logarithmic and the two accumulated histograms, the two profiles."""
    doc.add("<h3>Spatial nonuniformity and defect pixels</h3>")
    plots = []
    for which in emva_figures.SPECTROGRAMS:
        plots.append((emva_figures.spectrogram_figure(emva, which),
                      f"emva-spectrogram-{which.lower().replace('_', '-')}",
                      _spectrogram_caption(which)))
    for which in emva_figures.HISTOGRAMS:
        plots.append((emva_figures.histogram_figure(emva, which),
                      f"emva-histogram-{which.lower()}", _histogram_caption(which, False)))
    for which in emva_figures.HISTOGRAMS:
        plots.append((emva_figures.accumulated_histogram_figure(emva, which),
                      f"emva-accumulated-{which.lower()}", _histogram_caption(which, True)))
    for which in emva_figures.PROFILES:
        plots.append((emva_figures.profile_figure(emva, which), f"emva-profile-{which}",
                      _profile_caption(which)))
    if all(fig is None for fig, _, _ in plots):
        doc.add(para("No spatial nonuniformity plots: " + _sentence(_spatial_absent(emva)),
                     "note"))
        return
    for fig, id_, caption in plots:
        if fig is not None:
            doc.plot(fig, id_=id_, caption=caption)


def emva_section(doc: Doc, emva: Mapping[str, Any]) -> None:
    """The EMVA 1288 datasheet: its figures in the standard's order with their errors (or
    why each is not determined), the other notes, then its plots in the standard's order
    (photon transfer, SNR, linearity and its deviation; dark current; spatial
    nonuniformity)."""
    rows = datasheet_rows(emva)
    with doc.section("emva1288", ESTIMATE_TITLES["emva1288"]):
        doc.add(para("The summary datasheet of the EMVA 1288 standard "
                     f"({emva.get('standard', 'EMVA 1288 release 3.1')}, with release 4.0's "
                     "row, column and pixel parts of DSNU1288 and PRNU1288), in the standard's "
                     "order, each figure with its standard error; definitions of "
                     f"{emva.get('definitions', 'the standard')}. A figure this session "
                     "cannot give is \u201cnot determined\u201d, with the reason and, where "
                     "the data give one, an upper bound."))
        doc.add(_datasheet_table(rows))
        shown = {r.note for r in rows if r.note}
        notes = emva.get("notes")
        notes = notes if isinstance(notes, list) else [notes] if notes else []
        doc.add(bullets(n for n in notes if n not in shown))
        _transfer_plots(doc, emva)
        _dark_plots(doc, emva, rows)
        _spatial_plots(doc, emva)


# ---------------------------------------------------------------------------------------------
# skipped, provenance
# ---------------------------------------------------------------------------------------------
def skipped_section(doc: Doc, product: CalibrationProduct) -> None:
    with doc.section("skipped", "Skipped estimates"):
        if not product.skipped:
            doc.add(para("None: every estimate was made."))
            return
        doc.add(table([(ESTIMATE_TITLES.get(s.estimate, s.estimate), s.code, s.reason,
                        ", ".join(s.roles)) for s in product.skipped],
                      ("estimate", "code", "reason", "roles missing"),
                      cls="ccd-report-skipped"))


def provenance_section(doc: Doc, product: CalibrationProduct, session: Session | None,
                       now: str) -> None:
    """The versions of the product and of the report, the session, its hash and the product's
    date (each said when the product does not record it), then every step's parameters."""
    prov = product.provenance
    digest = prov.get("session_hash")
    date = prov.get("date")
    with doc.section("provenance", "Provenance"):
        doc.add(facts([
            ("product made by", f"ccdcore {prov.get('ccdcore', 'unknown version')}", ""),
            ("report made by", f"ccdcore {__version__}", now),
            ("session", session.label if session is not None else prov.get("session", "unknown"),
             prov.get("source", "")),
            ("session hash", digest if digest else "unavailable",
             "" if digest else "this product records no hash of its session"),
            ("date of the product", date if date else now,
             "" if date else "the product records no date: this is the report's date"),
        ]))
        steps = prov.get("steps") or {}
        if steps:
            doc.add("<h3>Parameters per step</h3>")
            doc.add(table([(ESTIMATE_TITLES.get(k, k), _parameters(v))
                           for k, v in steps.items()],
                          ("step", "parameters"), cls="ccd-report-steps"))


def _parameters(params: Any) -> Html:
    """A step's parameters, one ``key: value`` per line."""
    if not isinstance(params, dict):
        return Html(esc(value_text(params)))
    return Html("<br>".join(f"<b>{esc(k)}</b>: {esc(value_text(v))}"
                            for k, v in params.items()))
