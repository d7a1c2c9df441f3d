"""The report's EMVA 1288 datasheet section: the datasheet's figures in the standard's order, then
its plots (photon transfer, SNR, linearity and its deviation; dark current; spatial
nonuniformity), from :mod:`ccdcore_report.emva_figures`.  Part of
:mod:`ccdcore_report.sections`, which re-exports every public name.

Public objects
--------------
emva_section
    The section.
"""
from __future__ import annotations

import itertools
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from ccdcore.common import format_pm
from ccdcore.emva.datasheet import LINEARITY_RANGE, SENSITIVITY_FRACTION
from ccdcore.emva.results import EmvaSummary
from ccdcore.emva.sheet import SheetRow, datasheet_rows
from ccdcore.emva.spatial import HIGH_PASS_SIZE

from .. import emva_figures
from .. import figures
from ..html import Doc, bullets, esc, json_floats, para
from .summary import ESTIMATE_TITLES

__all__ = ["emva_section"]

# ---------------------------------------------------------------------------------------------
# EMVA 1288 datasheet
# ---------------------------------------------------------------------------------------------
def _columns(columns: Mapping[str, Sequence[Any] | None]) -> dict[str, NDArray[np.float64]]:
    """Columns of the same length as float arrays: name -> values (``None`` for NaN), cut to
    the shortest; a column that is ``None`` is left out."""
    out = {name: json_floats(values) for name, values in columns.items() if values is not None}
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


def _transfer_plots(doc: Doc, emva: EmvaSummary) -> None:
    """Sensitivity, linearity and noise (sec. 6.6, 2.3, 6.7): the photon transfer, the SNR,
    the linearity and its deviation, each when its data are in the figures."""
    doc.add("<h3>Sensitivity, linearity and noise</h3>")
    drawn = len(doc.roots)
    lo, hi = (round(100 * f) for f in LINEARITY_RANGE)
    pts = _columns({k: [getattr(p, k) for p in emva.points] for k in (
        "u_p", "u_y", "u_y_dark", "s2_y", "s2_y_dark", "u_y_err", "s2_y_err",
        "in_sensitivity_fit", "in_linearity_fit")})
    if emva.points:
        doc.plot(figures.emva_ptc_figure(pts), id_="emva-ptc",
                 caption="Photon transfer (sec. 6.6): the temporal variance of the signal "
                         "against its mean, both less their dark values, with the standard "
                         "errors of \u03c3\u00b2_y. The slope of the filled points (up to "
                         f"{round(100 * SENSITIVITY_FRACTION)} % of saturation) is the system "
                         "gain K; hollow points are outside that fit. Read: a linear camera "
                         "with shot noise puts the points on a straight line through the "
                         "origin; the bend at the top is saturation.")
    curve = emva.snr_curve
    snr = _columns({"u_p": curve.u_p, "snr": curve.snr, "model": curve.snr_model,
                    "total": curve.snr_total})
    if curve.u_p:
        doc.plot(figures.emva_snr_figure(snr), id_="emva-snr",
                 caption="Signal-to-noise ratio (sec. 2.3): the measured SNR (eq. 10) against "
                         "the mean number of photons per pixel, with the model of the "
                         "temporal noise (eq. 11) and, with the spatial sets, the model with "
                         "DSNU1288 and PRNU1288 added (log-log). Read: the slope is 1 where "
                         "the dark noise dominates, \u00bd where the photon shot noise does; "
                         "the highest point is SNR_max, at saturation.")
    if emva.points:
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


def _dark_caption(emva: EmvaSummary, rows: Sequence[SheetRow], which: str) -> str:
    """What a dark-current plot shows, the dark current it gives and, when not determined,
    why; then how to read it."""
    dc = emva.dark_current
    line = None if dc is None else dc.mean_line if which == "mean" else dc.var_line
    fit = ""
    if line is not None and line.chi2_dof is not None:
        fit = (f" The points scatter about the line with \u03c7\u00b2/\u03bd = "
               f"{line.chi2_dof:.3g} (\u03bd = {line.dof}).")
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


def _dark_plots(doc: Doc, emva: EmvaSummary, rows: Sequence[SheetRow]) -> None:
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
        why = (_note_of(rows, "u_I_mean") if emva.dark_points else
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


def _spatial_absent(emva: EmvaSummary) -> str:
    """Why the figures hold no spatial plots."""
    if emva.spatial is None or emva.spatial_dark is None:
        return ("the session has no spatial sets (L bright frames at one operating point and "
                "L dark frames at its exposure, sec. 8)")
    return next((n for n in emva.notes if "no spatial plots" in n),
                "the product holds no spatial plots (it was made before ccdcore drew them)")


def _spatial_plots(doc: Doc, emva: EmvaSummary) -> None:
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


def emva_section(doc: Doc, emva: EmvaSummary) -> None:
    """The EMVA 1288 datasheet of the figures ``emva`` (a calibration product's, checked when it
    was loaded): its figures in the standard's order with their errors (or why each is not
    determined), the other notes, then its plots in the standard's order (photon transfer,
    SNR, linearity and its deviation; dark current; spatial nonuniformity)."""
    rows = datasheet_rows(emva)
    with doc.section("emva1288", ESTIMATE_TITLES["emva1288"]):
        doc.add(para("The summary datasheet of the EMVA 1288 standard "
                     f"({emva.standard}, with release 4.0's "
                     "row, column and pixel parts of DSNU1288 and PRNU1288), in the standard's "
                     "order, each figure with its standard error; definitions of "
                     f"{emva.definitions}. A figure this session "
                     "cannot give is \u201cnot determined\u201d, with the reason and, where "
                     "the data give one, an upper bound."))
        doc.add(_datasheet_table(rows))
        shown = {r.note for r in rows if r.note}
        doc.add(bullets(n for n in emva.notes if n not in shown))
        _transfer_plots(doc, emva)
        _dark_plots(doc, emva, rows)
        _spatial_plots(doc, emva)
