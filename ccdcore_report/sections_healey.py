"""The report's sections of Healey & Kondepudy (1994): photon transfer (the noise model), dark
reference, fixed pattern, acquisition plan, correction check and scene variation.  Part of
:mod:`ccdcore_report.sections`, which re-exports every public name.

Public objects
--------------
noise_section, dark_section, fixed_pattern_section, plan_section, correction_section,
scene_section
    One section each.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

from . import figures
from .html import Doc, bullets, facts, finite, num, para, pm, table, value_text

__all__ = ["noise_section", "dark_section", "fixed_pattern_section", "plan_section",
           "correction_section", "scene_section"]

_VERDICTS = {
    "acceptable": "the line \u03c3\u00b2_N = A\u00b7\u03bc + \u03c3\u00b2_C fits the points "
                  "within their errors",
    "poor": "a poor fit: the points scatter more than their errors allow (Q < 0.05)",
    "model rejected": "the model is rejected (Q < 0.001): the points do not lie on a straight "
                      "line within their errors",
}


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
