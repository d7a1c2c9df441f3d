"""The report's map sections: every map of the calibration product, and change detection (Tsin,
Ramesh & Kanade 2001, sec. 5) with its label and d² maps.  Part of
:mod:`ccdcore_report.sections`, which re-exports every public name.

Public objects
--------------
maps_section, change_section
    One section each.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from ccdcore.common import format_pm
from ccdcore.errors import CcdError
from ccdcore.product.make import CalibrationProduct, MapName

if TYPE_CHECKING:     # the change detector is imported where it runs
    from ccdcore.change.detector import ChangeInputs

from .. import figures
from ..figures import MAP_SPECS, MapSpec
from ..html import Doc, Html, bullets, esc, facts, num, para, table

__all__ = ["maps_section", "change_section"]

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
    flat = product.estimates.flat_field
    layout = str((flat.layout if flat is not None else None) or product.camera.layout or "mono")
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
        ("shade pixels", summary.get("shade_pixels") if summary.get("shade") else "not tested",
         "the background's light times one factor "
         f"{summary['shade'][0]:g}–{summary['shade'][1]:g} (soft shadows), not change"
         if summary.get("shade") else "mono frames or the test turned off"),
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


def change_section(doc: Doc, change: Any, inputs: ChangeInputs | None) -> None:
    """Change detection (Tsin et al. sec. 5): the response used, the thresholds, each cluster
    with its transform M, then the label and d² maps."""
    summary = change.to_dict()
    with doc.section("change", "Change detection"):
        doc.add(para("Tsin, Ramesh & Kanade 2001, sec. 5: the reference and target brackets as "
                     "radiance with its per-pixel sigma; one colour transform M per cluster "
                     "(background, each shade of shadow), d\u00b2 of each pixel under it, and "
                     "the threshold calibrated on the background for the requested false-alarm "
                     "rate."))
        if inputs is not None:
            doc.add(para(f"Response: {inputs.source or 'n/a'}; channels "
                         f"{', '.join(map(str, inputs.channels))}."))
        doc.add(_change_facts(summary))
        doc.add(_clusters_table(summary))
        doc.add(bullets(summary.get("notes") or ()))
        _change_maps(doc, change)
