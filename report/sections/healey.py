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

from ccdcore.common import format_pm
from ccdcore.dark.map import DarkSummary
from ccdcore.guide import ptc_gate
from ccdcore.kmap_kernels import FixedPatternSummary
from ccdcore.planning import PlanSummary
from ccdcore.ptc_fit import PhotonTransferSummary
from ccdcore.scene_summary import CorrectionCheckSummary, SceneSummary

from .. import figures
from ..html import Doc, bullets, facts, finite, num, para, table, value_text

__all__ = ["noise_section", "dark_section", "fixed_pattern_section", "plan_section",
           "correction_section", "scene_section"]

# ---------------------------------------------------------------------------------------------
# photon transfer
# ---------------------------------------------------------------------------------------------
def _verdict_text(noise: PhotonTransferSummary) -> str:
    """The photon-transfer gate (:func:`ccdcore.guide.ptc_gate`) in the words every surface
    shows it with (the Walkthrough, the Photon transfer page, ``ccdcore ptc``)."""
    if not finite(noise.Q):
        return ("untested: no degrees of freedom are left (as many light levels as the line "
                "has parameters)")
    return ptc_gate(noise).line()


def _noise_facts(noise: PhotonTransferSummary) -> str:
    """The fitted line, the noise figures derived from it and the goodness of fit."""
    n = noise
    return facts([
        ("gain A", format_pm(n.A, n.A_err, unit="DN/e\u207b"), "DN per electron"),
        ("conversion gain 1/A",
         format_pm(n.conversion_gain_e_per_dn, n.conversion_gain_e_per_dn_err, unit="e\u207b/DN"),
         "electrons per DN"),
        ("\u03c3\u00b2_C", format_pm(n.sigma_c2, n.sigma_c2_err, unit="DN\u00b2"),
         "signal-independent noise, A\u00b2\u03c3\u00b2_R + q\u00b2/12 (eq. 27)"),
        ("read noise \u03c3_R", format_pm(n.read_noise_e, n.read_noise_e_err, unit="e\u207b"),
         "\u221a(\u03c3\u00b2_C \u2212 q\u00b2/12)/A"),
        ("read noise in DN", format_pm(n.read_noise_dn, n.read_noise_dn_err, unit="DN"),
         "A\u00b7\u03c3_R"),
        ("quantisation q\u00b2/12", num(n.quantisation_dn2, ".4g", "DN\u00b2"), ""),
        ("black level b\u2080", num(n.black_level_dn, ".4g", "DN"), n.black_level_source),
        ("\u03c7\u00b2", num(n.chi2, ".4g"), f"with {n.dof} degrees of freedom"),
        ("goodness of fit Q", num(n.Q, ".3g"), _verdict_text(n)),
        ("region", "whole frame" if not n.roi
         else "ROI " + ", ".join(map(str, n.roi)) + " (X, Y, W, H)", ""),
    ])


def _levels_table(noise: PhotonTransferSummary) -> str:
    """Every light level: μ, σ̂²_N ± error, pairs, exposure, used or why not."""
    rows = []
    for p in noise.points:
        why = p.reason or p.exclusion
        rows.append((p.level, num(p.mu, ".4f"), format_pm(p.var, p.var_err), p.n_pairs,
                     num(p.exposure, ".4g"), "used" if p.used else f"excluded: {why}"))
    return table(rows, ("level", "\u03bc \u2212 b\u2080 (DN)", "\u03c3\u0302\u00b2_N (DN\u00b2)",
                        "pairs", "exposure (s)", "fit"),
                 cls="ccd-report-points", numeric=(0, 1, 2, 3, 4))


def _ptc_plots(doc: Doc, noise: PhotonTransferSummary) -> None:
    """The app's photon-transfer plots of the summary."""
    from bokeh.layouts import column

    figs = figures.ptc_figures(figures.photon_transfer_of(noise))
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


def noise_section(doc: Doc, noise: PhotonTransferSummary) -> None:
    """The photon-transfer fit, the levels it used, its notes and its plots."""
    with doc.section("noise", "Photon transfer (noise model)"):
        doc.add(para("Healey & Kondepudy 1994, eqs. 37\u201342 and 59\u201367: the temporal "
                     "noise variance \u03c3\u00b2_N of frame pairs against the mean signal "
                     "\u03bc \u2212 b\u2080, fitted by the weighted line "
                     "\u03c3\u00b2_N = A\u00b7\u03bc + \u03c3\u00b2_C (eq. 41)."))
        doc.add(_noise_facts(noise))
        if noise.robust_dropped:
            doc.add(para("The robust mode dropped levels "
                         + ", ".join(map(str, noise.robust_dropped)) + "."))
        doc.add("<h3>Light levels</h3>")
        doc.add(_levels_table(noise))
        doc.add(bullets(noise.notes))
        _ptc_plots(doc, noise)


# ---------------------------------------------------------------------------------------------
# Healey & Kondepudy: dark, fixed pattern, plan, correction check, scene
# ---------------------------------------------------------------------------------------------
def dark_section(doc: Doc, d: DarkSummary) -> None:
    """The dark reference D̂_D: its level, spread, noise and the hot and dead pixels."""
    with doc.section("dark", "Dark reference"):
        doc.add(para("Healey & Kondepudy sec. V-A: the mean D\u0302_D of s dark frames, with "
                     "hot and dead pixels flagged by the rules below (maps under Maps)."))
        doc.add(facts([
            ("frames s", d.s, ""),
            ("exposure", num(d.exposure, ".4g", "s"), ""),
            ("mean level", format_pm(d.mean, d.mean_sem, unit="DN"), "\u00b1 its standard error"),
            ("spatial std", num(d.spatial_std, ".4g", "DN"), "of D\u0302_D"),
            ("spatial std of the signal", num(d.spatial_std_signal, ".4g", "DN"),
             "without the averaging noise \u03c3\u00b2_N/s"),
            ("temporal noise \u03c3\u00b2_N", num(d.noise_var, ".4g", "DN\u00b2"),
             "mean per-pixel variance"),
            ("hot pixels", d.n_hot, d.hot_rule),
            ("dead pixels", d.n_dead, d.dead_rule),
        ]))
        doc.add(bullets(d.notes))


def fixed_pattern_section(doc: Doc, k: FixedPatternSummary) -> None:
    """K̂: its configurations, spread, error and the eq. 50 bound, and the rejected slopes."""
    bound = k.var_bound
    k_var = k.K_var_mean
    rejected = k.fraction_pixels_with_rejection
    with doc.section("fixed-pattern", "Fixed pattern K\u0302"):
        doc.add(para("Healey & Kondepudy eqs. 45\u201350: per pixel, the mean of the slopes of "
                     "n1 card/lamp configurations kept within centre \u00b1 p\u00b7\u03c3\u0302 "
                     "(maps under Maps)."))
        doc.add(facts([
            ("configurations n1 \u00d7 frames n2", f"{k.n1} \u00d7 {k.n2}", ""),
            ("window, p", f"{k.window}, {value_text(k.p)}",
             "local mean window (pixels) and the rejection width"),
            ("mean of K\u0302", num(k.mean, ".6g"), ""),
            ("spatial spread of K\u0302", num(k.spatial_std, ".4g"), "standard deviation"),
            ("slope spread \u03c3\u0302", num(k.sigma_hat, ".4g"), "eq. 48"),
            ("error of K\u0302 (mean)", num(math.sqrt(k_var) if finite(k_var) else None, ".3g"),
             f"\u221a of the mean error variance {num(k_var, '.3g')}"),
            ("eq. 50 bound", "infinite" if bound is None else num(bound, ".3g"),
             f"error variance bound (std {num(k.sd_bound, '.3g')})"),
            ("pixels with a rejected slope",
             num(100 * rejected, ".3g", "%") if finite(rejected) else "n/a",
             f"{k.n_rejected} slopes rejected in all"),
        ]))
        doc.add(bullets(k.notes))


def plan_section(doc: Doc, p: PlanSummary) -> None:
    """n1 and n2 with their formulas and readings, and what the session lacks against them."""
    with doc.section("plan", "Acquisition plan"):
        doc.add(para("Healey & Kondepudy sec. V-B: how many card/lamp configurations n1 and "
                     "frames per configuration n2 the fixed-pattern map needs."))
        doc.add(facts([
            ("n1 (configurations)", p.n1_required, p.n1_formula),
            ("n2 (frames each)", p.n2_required, p.n2_formula),
            ("reading of the n2 rule", p.n2_reading,
             "; ".join(f"{k}: {v}" for k, v in p.n2_alternatives.items())),
        ]))
        if p.warnings:
            doc.add("<h3>What the session lacks against the plan</h3>")
            doc.add(bullets(p.warnings, "warnings"))
        doc.add(bullets(p.notes))


def correction_section(doc: Doc, c: CorrectionCheckSummary) -> None:
    """How much the correction changes a maximum-intensity image, in steps q."""
    def pct(v: float | None) -> str:
        return num(100 * v, ".3g", "%") if finite(v) else "n/a"

    with doc.section("correction-check", "Correction check"):
        doc.add(para("Healey & Kondepudy sec. VII-A: how much eq. 51 changes a maximum-intensity "
                     "image, in quantisation steps q."))
        doc.add(facts([
            ("pixels changed by more than 1 q", pct(c.frac_gt_1q), ""),
            ("pixels changed by more than 2 q", pct(c.frac_gt_2q), ""),
            ("largest change", num(c.max_change_q, ".3g", "q"), ""),
            ("mean level of the image", num(c.mean_level, ".4g", "DN"), ""),
        ]))


def scene_section(doc: Doc, scene: dict[str, SceneSummary]) -> None:
    """V_S of each patch with its fit, the levels used and excluded."""
    with doc.section("scene", "Scene variation"):
        doc.add(para("Healey & Kondepudy sec. VI: the relative variance V_S of each uniform "
                     "surface, with the calibration maps' own errors (eqs. 53\u201358)."))
        rows = []
        for name, sv in scene.items():
            used = sum(1 for m in sv.measurements if m.used)
            rows.append((name, format_pm(sv.V_S, sv.V_S_err), num(sv.chi2, ".4g"), sv.dof,
                         num(sv.Q, ".3g"), used, len(sv.excluded)))
        doc.add(table(rows, ("patch", "V_S", "\u03c7\u00b2", "dof", "Q", "levels used",
                             "excluded"), cls="ccd-report-scene", numeric=(1, 2, 3, 4, 5, 6)))
        notes = sorted({n for sv in scene.values() for n in sv.notes})
        doc.add(bullets(notes))
