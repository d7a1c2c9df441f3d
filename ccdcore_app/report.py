"""One self-contained HTML calibration report: every estimate with its uncertainty, every plot
and map as a Bokeh figure, the skipped estimates and the provenance, in a file that opens offline.

The report is built from a :class:`ccdcore.product.CalibrationProduct` (its JSON summaries and
float32 maps) and, when given, a change-detection result; nothing in it is estimated here. From a
session, the product is made first (:func:`ccdcore.product.calibrate`) and, when the session has
``reference`` and ``target`` brackets, the change masks (:func:`ccdcore.change.session_change`).
BokehJS (Bokeh's own code only, see :func:`_bokeh_resources`) and every figure's data are
inlined: no script, style sheet, font or image is fetched from anywhere (docs/report.md). Bokeh
is imported when a report is built, Panel never, so ``ccdcore report`` starts quickly; the app
can call :func:`build_report` with the product it already holds.

Public objects
--------------
build_report(source, *, product=None, change=None, progress=None)
    The report's HTML text.
write_report(source, out_path, **kw)
    The same, written atomically to ``out_path`` (never over an input).
MAX_MAP_SIDE
    The longest side, in pixels, a map is drawn with (larger maps are reduced by block means).
MAX_HELD_OUT
    Most flat frames (one per flat group) corrected for the held-out SNUP table.
"""
from __future__ import annotations

import datetime
import html
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from ccdcore import __version__
from ccdcore.common import format_pm, format_size, sort_key
from ccdcore.errors import CcdError
from ccdcore.product import (PRODUCT_FILE, REQUIREMENTS, CalibrationProduct, calibrate,
                             estimate_all, load_product, missing_frames)
from ccdcore.session import Session, open_session

from .plots import auto_clim

__all__ = ["build_report", "write_report", "MAX_MAP_SIDE", "MAX_HELD_OUT"]

#: the longest side a map is drawn with: larger maps are reduced by block means (flags and
#: counts by block maxima), which keeps a 2048 x 2048 map to about 1 MB of the file
MAX_MAP_SIDE = 512
#: most flat groups whose first frame is corrected for the held-out SNUP table (one frame
#: read and corrected per group)
MAX_HELD_OUT = 24
#: the longest list of values (files, levels ...) written out in the provenance
_MAX_LIST = 12

Progress = Callable[[str, float], None]

# ---------------------------------------------------------------------------------------------
# palettes and names (maps, channels, change labels)
# ---------------------------------------------------------------------------------------------
#: colours of hot/dead flags (0 normal, 1 hot, 2 dead) and of flat-field flags (0, 1)
_FLAG_COLOURS = ("#e9ecef", "#d62728", "#1f4e9c")
_FLAG_LABELS = {0: "normal", 1: "hot", 2: "dead"}
_FLAT_FLAG_LABELS = {0: "normal", 1: "flagged"}
#: channel -> line colour (Okabe-Ito, colour-blind safe)
_CHANNEL_COLOURS = {"L": "#333333", "R": "#D55E00", "G": "#009E73", "B": "#0072B2",
                    "G1": "#009E73", "G2": "#56B4E9"}
#: shadow clusters 1..n take these colours in turn (Okabe-Ito), as on the app's Change page
_SHADOW_COLOURS = ("#0072B2", "#56B4E9", "#CC79A7", "#009E73", "#E69F00")


def _label_colour(label: int) -> str:
    """The colour of a change label (Tsin et al. sec. 5), as the app's Change detection page
    draws it (a test compares them with :func:`ccdcore_app.change_plots.label_colour`)."""
    from ccdcore.change import LABEL_CHANGE, LABEL_UNDETERMINED

    fixed = {0: "#d9d9d9", LABEL_CHANGE: "#D55E00", LABEL_UNDETERMINED: "#F0E442"}
    return fixed.get(label) or _SHADOW_COLOURS[(label - 1) % len(_SHADOW_COLOURS)]


def _label_name(label: int) -> str:
    from ccdcore.change import LABEL_CHANGE, LABEL_UNDETERMINED

    return {0: "unchanged (background)", LABEL_CHANGE: "change",
            LABEL_UNDETERMINED: "undetermined (no radiance)"}.get(label, f"shadow {label}")


@dataclass(frozen=True)
class _MapSpec:
    """How one map of a product is drawn: title, unit, colour scale and kind."""

    title: str
    unit: str = ""
    kind: str = "value"          # value | diverging | count | flags
    palette: str = "Viridis256"
    note: str = ""


_MAP_SPECS: dict[str, _MapSpec] = {
    "dark": _MapSpec("Dark reference D\u0302_D", "DN", palette="Greys256",
                     note="mean of the dark frames (Healey & Kondepudy sec. V-A)"),
    "dark_var": _MapSpec("Dark temporal variance \u03c3\u00b2_N", "DN\u00b2",
                         note="per-pixel temporal variance of the dark frames (eq. 43)"),
    "hot_dead": _MapSpec("Hot and dead pixels", kind="flags",
                         note="the rules are in the dark reference's table"),
    "K": _MapSpec("Fixed pattern K\u0302", kind="diverging",
                  note="eq. 49; the colour scale is symmetric about 1"),
    "K_err": _MapSpec("Error of K\u0302, \u221avar[K\u0302]",
                      note="standard error of the mean of the kept slopes"),
    "n1_used": _MapSpec("Slopes kept n'_1", kind="count",
                        note="configurations whose slope eq. 48 kept, per pixel"),
    "flat_G": _MapSpec("Flat-field gain G", note="eq. 3 of de Lasarte et al. 2007"),
    "flat_O": _MapSpec("Flat-field offset O", "DN", note="eq. 4 of de Lasarte et al. 2007"),
    "flat_flags": _MapSpec("Flagged pixels of G", kind="flags",
                           note="DL_B \u2212 DL_0 not positive or noise dominated; G from the "
                                "neighbours there"),
    "flat_dark": _MapSpec("Dark image DL_0", "DN", palette="Greys256"),
    "flat_base": _MapSpec("Base image DL_B", "DN", palette="Greys256"),
}
#: the order maps are drawn in (others follow, alphabetically)
_MAP_ORDER = ("dark", "dark_var", "hot_dead", "K", "K_err", "n1_used", "flat_G", "flat_O",
              "flat_flags", "flat_dark", "flat_base")

_ESTIMATE_TITLES = {"noise": "Photon transfer", "dark": "Dark reference",
                    "fixed_pattern": "Fixed pattern", "plan": "Acquisition plan",
                    "correction_check": "Correction check", "scene": "Scene variation",
                    "flat_field": "Flat field", "response": "Response curves",
                    "emva1288": "EMVA 1288 figures"}

_VERDICTS = {
    "acceptable": "the line \u03c3\u00b2_N = A\u00b7\u03bc + \u03c3\u00b2_C fits the points "
                  "within their errors",
    "poor": "a poor fit: the points scatter more than their errors allow (Q < 0.05)",
    "model rejected": "the model is rejected (Q < 0.001): the points do not lie on a straight "
                      "line within their errors",
}


# ---------------------------------------------------------------------------------------------
# HTML pieces
# ---------------------------------------------------------------------------------------------
class _Html(str):
    """A fragment that is already HTML (not escaped again by :func:`_cell`)."""


def _esc(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _cell(value: Any) -> str:
    return value if isinstance(value, _Html) else _esc(value)


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _num(v: Any, fmt: str = ".4g", unit: str = "") -> str:
    """A number for a table (``"n/a"`` for None or non-finite)."""
    if not _finite(v):
        return "n/a"
    return f"{v:{fmt}}" + (f" {unit}" if unit else "")


def _pm(d: Mapping[str, Any], key: str, err: str | None = None, unit: str = "") -> str:
    """``d[key] ± d[err]`` as :func:`ccdcore.common.format_pm` writes it."""
    v, e = d.get(key), d.get(err or f"{key}_err")
    return format_pm(v if _finite(v) else float("nan"), e if _finite(e) else None, unit=unit)


def _table(rows: Iterable[Sequence[Any]], header: Sequence[str] | None = None, *,
           cls: str = "", numeric: Sequence[int] = ()) -> str:
    """An HTML table; cells are escaped unless they are :class:`_Html`; the columns in
    ``numeric`` are right-aligned."""
    out = [f'<table class="{_esc(cls)}">' if cls else "<table>"]
    if header:
        out.append("<thead><tr>" + "".join(f"<th>{_esc(h)}</th>" for h in header)
                   + "</tr></thead>")
    out.append("<tbody>")
    for row in rows:
        out.append("<tr>" + "".join(
            f'<td class="num">{_cell(c)}</td>' if i in numeric else f"<td>{_cell(c)}</td>"
            for i, c in enumerate(row)) + "</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _facts(rows: Iterable[tuple[str, Any] | tuple[str, Any, str]], cls: str = "facts") -> str:
    """A two- or three-column table: quantity, value (right-aligned), meaning."""
    rows = list(rows)
    three = any(len(r) > 2 for r in rows)
    return _table([(r[0], r[1], r[2] if len(r) > 2 else "") if three else r for r in rows],
                  cls=cls, numeric=(1,))


def _list(items: Iterable[Any], cls: str = "notes") -> str:
    items = [i for i in items if i not in (None, "")]
    if not items:
        return ""
    return f'<ul class="{cls}">' + "".join(f"<li>{_cell(i)}</li>" for i in items) + "</ul>"


def _para(text: Any, cls: str = "") -> str:
    return (f'<p class="{cls}">' if cls else "<p>") + _cell(text) + "</p>"


def _short(values: Sequence[Any], limit: int = _MAX_LIST) -> str:
    shown = ", ".join(_value_text(v) for v in values[:limit])
    more = len(values) - limit
    return shown + (f", \u2026 and {more} more" if more > 0 else "")


def _value_text(v: Any) -> str:
    """A JSON value of the provenance as a short text."""
    if v is None:
        return "none"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return "[" + _short(list(v)) + "]"
    if isinstance(v, dict):
        return "; ".join(f"{k} = {_value_text(x)}" for k, x in v.items())
    return str(v)


def _float(v: Any) -> float:
    """A JSON number as a float (``None``, written for NaN, back to NaN)."""
    return float("nan") if v is None else float(v)


def _floats(values: Any) -> NDArray[np.float64]:
    """A JSON list of numbers (``None`` for NaN) as float64."""
    if values is None:
        return np.empty(0)
    return np.array([np.nan if v is None else v for v in np.ravel(np.asarray(values, object))],
                    np.float64)


# ---------------------------------------------------------------------------------------------
# the document being assembled
# ---------------------------------------------------------------------------------------------
@dataclass
class _Doc:
    """The report in document order: HTML fragments and Bokeh roots, and the table of contents."""

    parts: list[tuple[str, Any]] = field(default_factory=list)
    toc: list[tuple[str, str]] = field(default_factory=list)
    roots: list[Any] = field(default_factory=list)

    def add(self, fragment: str) -> None:
        if fragment:
            self.parts.append(("html", fragment))

    @staticmethod
    def _section_open(id_: str, title: str) -> str:
        return f'<section id="{_esc(id_)}" class="ccd-report-section"><h2>{_esc(title)}</h2>'

    def section(self, id_: str, title: str) -> _Section:
        return _Section(self, id_, title)

    def plot(self, model: Any, *, id_: str, caption: str, cls: str = "",
             width: int | None = None) -> None:
        """A Bokeh model in its own ``<figure class="ccd-report-plot" id=...>`` with a caption
        (``width``: the figure's width in CSS pixels, so the caption wraps under the plot)."""
        name = f"ccd-root-{len(self.roots)}"
        model.name = name
        self.roots.append(model)
        classes = "ccd-report-plot" + (f" {cls}" if cls else "")
        style = f' style="width: {int(width)}px"' if width else ""
        self.parts.append(("html", f'<figure class="{classes}" id="{_esc(id_)}"{style}>'))
        self.parts.append(("root", name))
        self.parts.append(("html", f"<figcaption>{_cell(caption)}</figcaption></figure>"))


class _Section:
    def __init__(self, doc: _Doc, id_: str, title: str):
        self.doc, self.id, self.title = doc, id_, title

    def __enter__(self) -> _Doc:
        self.doc.toc.append((self.id, self.title))
        self.doc.add(_Doc._section_open(self.id, self.title))
        return self.doc

    def __exit__(self, *exc: Any) -> None:
        self.doc.add("</section>")


# ---------------------------------------------------------------------------------------------
# maps
# ---------------------------------------------------------------------------------------------
def _reduce(plane: NDArray, factor: int, how: str) -> NDArray[np.float32]:
    """``plane`` reduced by ``factor`` in each direction: the mean (``how="mean"``) or the
    maximum (``"max"``) of each block of finite values (edge blocks may be partial)."""
    a = np.asarray(plane, np.float32)
    if factor <= 1:
        return a
    h, w = a.shape
    H, W = -(-h // factor) * factor, -(-w // factor) * factor
    padded = np.full((H, W), np.nan, np.float32)
    padded[:h, :w] = a
    blocks = padded.reshape(H // factor, factor, W // factor, factor)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # blocks without a finite value
        out = (np.nanmax(blocks, axis=(1, 3)) if how == "max"
               else np.nanmean(blocks, axis=(1, 3), dtype=np.float64))
    return out.astype(np.float32)


#: the width of the report's text column and what a map adds to its frame (axis, colour bar)
_CONTENT_WIDTH = 1050
_MAP_MARGIN = 110
_MAP_GAP = 24


def _image_figure(title: str, w: int, h: int, side: int) -> Any:
    """An empty figure for a w × h image with square pixels (row 0 at the top, the longer side
    ``side`` screen pixels), its toolbar hidden until hovered."""
    from bokeh.models import Range1d
    from bokeh.plotting import figure

    fw, fh = _frame_size(w, h, side)
    fig = figure(title=title, frame_width=fw, frame_height=fh,
                 x_range=Range1d(-0.5, w - 0.5), y_range=Range1d(h - 0.5, -0.5),
                 tools="pan,wheel_zoom,box_zoom,reset", toolbar_location="above",
                 x_axis_label="x (px)", y_axis_label="y (px)")
    fig.toolbar.logo = None
    fig.toolbar.autohide = True
    fig.grid.visible = False
    return fig


def _frame_size(w: int, h: int, side: int) -> tuple[int, int]:
    """Frame width and height with square pixels, the longer side ``side`` pixels."""
    if w >= h:
        return side, max(40, round(side * h / w))
    return max(40, round(side * w / h)), side


def _map_figure(plane: NDArray, spec: _MapSpec, *, title: str, side: int = 420,
                labels: Mapping[int, str] | None = None) -> tuple[Any, int]:
    """A map as a Bokeh image with a colour bar and a hover readout; returns the figure and
    the reduction factor used (1: every pixel)."""
    from bokeh.models import (ColorBar, FixedTicker, HoverTool, LinearColorMapper)
    from bokeh.palettes import RdBu11, interp_palette
    import bokeh.palettes as palettes

    h, w = plane.shape
    factor = max(1, math.ceil(max(h, w) / MAX_MAP_SIDE))
    how = "max" if spec.kind in ("flags", "count") else "mean"
    shown = _reduce(plane, factor, how)
    if spec.kind == "flags":
        names = dict(labels or _FLAG_LABELS)
        palette = list(_FLAG_COLOURS[:len(names)])
        low, high = -0.5, len(names) - 0.5
    elif spec.kind == "count":
        finite = shown[np.isfinite(shown)]
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        low, high = lo - 0.5, hi + 0.5
        palette = getattr(palettes, spec.palette)
    elif spec.kind == "diverging":
        lo, hi = auto_clim(shown)
        half = max(abs(lo - 1.0), abs(hi - 1.0)) or 0.5
        low, high = 1.0 - half, 1.0 + half
        palette = interp_palette(RdBu11, 256)
    else:
        low, high = auto_clim(shown)
        palette = getattr(palettes, spec.palette)
    fig = _image_figure(title, w, h, side)
    mapper = LinearColorMapper(palette=palette, low=low, high=high,
                               nan_color="rgba(0, 0, 0, 0)")
    image = fig.image(image=[shown], x=-0.5, y=-0.5, dw=w, dh=h, color_mapper=mapper)
    bar = ColorBar(color_mapper=mapper, width=12, title=spec.unit or None)
    if spec.kind == "flags":
        bar.ticker = FixedTicker(ticks=list(names))
        bar.major_label_overrides = {int(k): v for k, v in names.items()}
    fig.add_layout(bar, "right")
    value = "block " + ("maximum" if how == "max" else "mean") if factor > 1 else "value"
    fig.add_tools(HoverTool(renderers=[image], tooltips=[
        ("x, y", "$x{0}, $y{0}"), (value, "@image{%.5g}")], formatters={"@image": "printf"}))
    return fig, factor


def _resolution_text(shape: tuple[int, int], factor: int, how: str) -> str:
    size = format_size(shape)
    if factor <= 1:
        return f"{size} px, every pixel drawn."
    return (f"{size} px drawn at 1:{factor} (each screen pixel is the {how} of a "
            f"{factor}\u00d7{factor} block, to keep this file small); the product holds every "
            "pixel.")


def _product_maps(product: CalibrationProduct) -> dict[str, NDArray]:
    """The maps to draw: the product's, with hot and dead combined and K̂'s error as a
    standard deviation."""
    maps = dict(product.maps)
    out: dict[str, NDArray] = {}
    if "hot" in maps or "dead" in maps:
        shape = (maps.get("hot") if "hot" in maps else maps["dead"]).shape
        hot = maps.pop("hot", np.zeros(shape, np.float32)) > 0
        dead = maps.pop("dead", np.zeros(shape, np.float32)) > 0
        out["hot_dead"] = np.where(dead, 2, np.where(hot, 1, 0)).astype(np.float32)
    if "K_var" in maps:
        out["K_err"] = np.sqrt(np.maximum(maps.pop("K_var"), 0.0)).astype(np.float32)
    out.update(maps)
    order = {k: i for i, k in enumerate(_MAP_ORDER)}
    return dict(sorted(out.items(), key=lambda kv: (order.get(kv[0], len(order)), kv[0])))


def _planes(name: str, data: NDArray, layout: str) -> dict[str, NDArray]:
    """Channel -> 2-D plane of a map (one plane ``""`` for mono maps)."""
    from ccdcore.channels import split_channels

    if data.ndim == 2 and (not name.startswith("flat_") or layout == "mono"):
        return {"": data}
    try:
        return split_channels(data, layout)
    except CcdError:
        if data.ndim == 3:
            return {f"channel {i}": data[..., i] for i in range(data.shape[2])}
        return {"": data}


def _maps_section(doc: _Doc, product: CalibrationProduct) -> None:
    maps = _product_maps(product)
    if not maps:
        return
    flat = product.estimates.get("flat_field") or {}
    layout = str(flat.get("layout") or product.camera.layout or "mono")
    families: dict[str, list[tuple[str, dict[str, NDArray]]]] = {}
    for name, data in maps.items():
        family = ("Flat field" if name.startswith("flat_") else
                  "Dark reference and fixed pattern" if name in _MAP_SPECS else "Other maps")
        families.setdefault(family, []).append((name, _planes(name, np.asarray(data), layout)))
    with doc.section("maps", "Maps"):
        doc.add(_para("Every map of the calibration product, each in its own colour scale "
                      "(0.5\u201399.5 % of the values drawn); hover for the value under the "
                      "cursor, drag to pan, scroll to zoom."))
        for family, entries in families.items():
            doc.add(f"<h3>{_esc(family)}</h3>")
            singles = [(n, p) for n, p in entries if len(p) == 1]
            rows = ([singles] if singles else []) + [[(n, p)] for n, p in entries if len(p) > 1]
            for row in rows:
                doc.add('<div class="ccd-map-row">')
                empty = [note for name, planes in row for note in _map_plots(doc, name, planes)]
                doc.add("</div>")
                doc.add("".join(empty))


def _map_plots(doc: _Doc, name: str, planes: Mapping[str, NDArray]) -> list[str]:
    """One figure per channel plane of the map ``name``, each with its caption; flag maps
    without a flagged pixel are not drawn: their notes are returned instead."""
    spec = _MAP_SPECS.get(name, _MapSpec(name))
    labels = _FLAT_FLAG_LABELS if name == "flat_flags" else None
    how = "maximum" if spec.kind in ("flags", "count") else "mean"
    n = len(planes)
    side = min(380, (_CONTENT_WIDTH - (n - 1) * _MAP_GAP) // n - _MAP_MARGIN)
    empty: list[str] = []
    for channel, plane in planes.items():
        title = spec.title + (f" \u2014 {channel}" if channel else "")
        key = f"map-{name}" + (f"-{channel}" if channel else "")
        if spec.kind == "flags" and not np.any(np.nan_to_num(plane)):
            empty.append(f'<p class="note ccd-report-empty-map" id="{_esc(key)}">{_esc(title)}: '
                         "no pixel is flagged (map not drawn).</p>")
            continue
        fig, factor = _map_figure(plane, spec, title=title, side=side, labels=labels)
        caption = " ".join(p for p in (
            (spec.note[0].upper() + spec.note[1:] + ".") if spec.note else "",
            _resolution_text(plane.shape, factor, how)) if p)
        doc.plot(fig, id_=key, caption=caption, cls="ccd-report-map",
                 width=fig.frame_width + _MAP_MARGIN)
    return empty


# ---------------------------------------------------------------------------------------------
# sections: session and estimates
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


def _summary_section(doc: _Doc, product: CalibrationProduct, session: Session | None,
                     change: Any) -> None:
    cam = product.camera
    prov = product.provenance
    shape = _frame_shape(product, session)
    with doc.section("summary", "Camera and session"):
        doc.add(_facts([
            ("camera", cam.name or "unnamed"),
            ("bit depth", f"{cam.bits} bits" if cam.bits else "unknown"),
            ("colour layout", cam.layout),
            ("frame size (W \u00d7 H)", format_size(shape) if shape else "unknown"),
            ("black level (manifest)", _num(cam.black_level, ".6g", "DN")
             if cam.black_level is not None else "not given"),
            ("session", session.label if session is not None else prov.get("session", "unknown")),
            ("session source", session.source if session is not None
             else prov.get("source", "unknown")),
            ("frames", len(session.frames) if session is not None
             else prov.get("n_frames", "unknown")),
        ]))
        if session is not None:
            rows = []
            for row in session.groups_table():
                key = "" if row["key"] is None else f"{row['key_name']} {_value_text(row['key'])}"
                exps = row["exposures"]
                rows.append((row["role"], key, row["count"],
                             format_size(row["shape"]) if row["shape"] else "mixed",
                             row["dtype"] or "mixed",
                             ", ".join(f"{t:g}" for t in exps[:4]) + (" \u2026" if len(exps) > 4
                                                                        else "")))
            doc.add("<h3>Frames by role and group</h3>")
            doc.add(_table(rows, ("role", "group", "frames", "size", "type", "exposure (s)"),
                           cls="ccd-report-roles", numeric=(2,)))
        else:
            doc.add(_para("This report was made from a calibration product: the frames' roles "
                          "are not stored in it (the estimates below say what they used).",
                          "note"))
        made = [_ESTIMATE_TITLES.get(k, k) for k in product.estimates]
        if getattr(product, "emva1288", None):
            made.append(_ESTIMATE_TITLES["emva1288"])
        if change is not None:
            made.append("Change detection")
        doc.add(_para("Estimates made: " + (", ".join(made) if made else "none") + ". Skipped: "
                      + (", ".join(_ESTIMATE_TITLES.get(s.estimate, s.estimate)
                                   for s in product.skipped) or "none")
                      + " (see Skipped estimates)."))
        plan_warnings = set((product.estimates.get("plan") or {}).get("warnings") or ())
        other = [w for w in product.warnings if w not in plan_warnings]
        if other:
            doc.add("<h3>Warnings</h3>" + _list(other, "warnings"))
        if product.notes:
            doc.add("<h3>Notes</h3>" + _list(product.notes))


def _photon_transfer_of(noise: Mapping[str, Any]) -> Any:
    """The photon-transfer result of a product's ``noise`` summary (for the app's plots)."""
    from ccdcore.noise import PhotonTransfer, PtcPoint

    def f(key: str) -> float:
        return _float(noise.get(key))

    points = tuple(PtcPoint(level=int(p["level"]), mu=_float(p.get("mu")), var=_float(p.get("var")),
                            var_err=_float(p.get("var_err")), n_pairs=int(p.get("n_pairs") or 0),
                            n_pixels=int(p.get("n_pixels") or 0), used=bool(p["used"]),
                            reason=p.get("reason"), exposure=p.get("exposure"),
                            mu_raw=_float(p.get("mu_raw")),
                            clipped_fraction=_float(p.get("clipped_fraction")),
                            photons=p.get("photons"), exclusion=p.get("exclusion"))
                   for p in noise.get("points", ()))
    roi = noise.get("roi")
    return PhotonTransfer(
        A=f("A"), A_err=f("A_err"), sigma_c2=f("sigma_c2"), sigma_c2_err=f("sigma_c2_err"),
        cov=np.array(noise["cov"], np.float64), chi2=f("chi2"), dof=int(noise.get("dof") or 0),
        Q=f("Q"), points=points,
        conversion_gain_e_per_dn=f("conversion_gain_e_per_dn"),
        conversion_gain_e_per_dn_err=f("conversion_gain_e_per_dn_err"),
        read_noise_e=f("read_noise_e"), read_noise_e_err=f("read_noise_e_err"),
        read_noise_dn=f("read_noise_dn"), read_noise_dn_err=f("read_noise_dn_err"),
        quantisation_dn2=f("quantisation_dn2"), black_level_dn=f("black_level_dn"),
        black_level_source=str(noise.get("black_level_source", "")),
        roi=None if roi is None else tuple(roi), bits=noise.get("bits"),
        robust_dropped=tuple(noise.get("robust_dropped") or ()),
        notes=tuple(noise.get("notes") or ()), verdict=str(noise.get("verdict", "")),
        source=noise.get("source"))


def _verdict_text(noise: Mapping[str, Any]) -> str:
    verdict = str(noise.get("verdict", ""))
    q = noise.get("Q")
    if not _finite(q):
        return ("untested: no degrees of freedom are left (as many light levels as the line "
                "has parameters)")
    return f"Q = {q:.3g}: {_VERDICTS.get(verdict, verdict)}"


def _noise_section(doc: _Doc, noise: Mapping[str, Any]) -> None:
    from bokeh.layouts import column

    from .ptc_plots import PtcFigures

    with doc.section("noise", "Photon transfer (noise model)"):
        doc.add(_para("Healey & Kondepudy 1994, eqs. 37\u201342 and 59\u201367: the temporal "
                      "noise variance \u03c3\u00b2_N of frame pairs against the mean signal "
                      "\u03bc \u2212 b\u2080, fitted by the weighted line "
                      "\u03c3\u00b2_N = A\u00b7\u03bc + \u03c3\u00b2_C (eq. 41)."))
        chi2 = noise.get("chi2")
        doc.add(_facts([
            ("gain A", _pm(noise, "A", unit="DN/e\u207b"), "DN per electron"),
            ("conversion gain 1/A",
             _pm(noise, "conversion_gain_e_per_dn", unit="e\u207b/DN"), "electrons per DN"),
            ("\u03c3\u00b2_C", _pm(noise, "sigma_c2", unit="DN\u00b2"),
             "signal-independent noise, A\u00b2\u03c3\u00b2_R + q\u00b2/12 (eq. 27)"),
            ("read noise \u03c3_R", _pm(noise, "read_noise_e", unit="e\u207b"),
             "\u221a(\u03c3\u00b2_C \u2212 q\u00b2/12)/A"),
            ("read noise in DN", _pm(noise, "read_noise_dn", unit="DN"), "A\u00b7\u03c3_R"),
            ("quantisation q\u00b2/12", _num(noise.get("quantisation_dn2"), ".4g", "DN\u00b2"),
             ""),
            ("black level b\u2080", _num(noise.get("black_level_dn"), ".4g", "DN"),
             str(noise.get("black_level_source") or "")),
            ("\u03c7\u00b2", _num(chi2, ".4g"), f"with {noise.get('dof')} degrees of freedom"),
            ("goodness of fit Q", _num(noise.get("Q"), ".3g"), _verdict_text(noise)),
            ("region", "whole frame" if not noise.get("roi")
             else "ROI " + ", ".join(map(str, noise["roi"])) + " (X, Y, W, H)", ""),
        ]))
        if noise.get("robust_dropped"):
            doc.add(_para("The robust mode dropped levels "
                          + ", ".join(map(str, noise["robust_dropped"])) + "."))
        rows = []
        for p in noise.get("points", ()):
            why = p.get("reason") or p.get("exclusion")
            rows.append((p.get("level"), _num(p.get("mu"), ".4f"), _pm(p, "var"),
                         p.get("n_pairs"), _num(p.get("exposure"), ".4g"),
                         "used" if p.get("used") else f"excluded: {why}"))
        doc.add("<h3>Light levels</h3>")
        doc.add(_table(rows, ("level", "\u03bc \u2212 b\u2080 (DN)",
                              "\u03c3\u0302\u00b2_N (DN\u00b2)", "pairs", "exposure (s)", "fit"),
                       cls="ccd-report-points", numeric=(0, 1, 2, 3, 4)))
        doc.add(_list(noise.get("notes") or ()))
        try:
            result = _photon_transfer_of(noise)
        except (KeyError, TypeError, ValueError) as exc:
            doc.add(_para(f"The photon-transfer plots cannot be drawn from this product: {exc}",
                          "warning"))
            return
        figs = PtcFigures(height=340, loglog_height=420)
        figs.update(result.points, result)
        for fig in (figs.transfer, figs.residual, figs.loglog):
            fig.toolbar.autohide = True
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


def _dark_section(doc: _Doc, d: Mapping[str, Any]) -> None:
    with doc.section("dark", "Dark reference"):
        doc.add(_para("Healey & Kondepudy sec. V-A: the mean D\u0302_D of s dark frames, with "
                      "hot and dead pixels flagged by the rules below (maps under Maps)."))
        doc.add(_facts([
            ("frames s", d.get("s"), ""),
            ("exposure", _num(d.get("exposure"), ".4g", "s"), ""),
            ("mean level", _pm(d, "mean", "mean_sem", unit="DN"), "\u00b1 its standard error"),
            ("spatial std", _num(d.get("spatial_std"), ".4g", "DN"), "of D\u0302_D"),
            ("spatial std of the signal", _num(d.get("spatial_std_signal"), ".4g", "DN"),
             "without the averaging noise \u03c3\u00b2_N/s"),
            ("temporal noise \u03c3\u00b2_N", _num(d.get("noise_var"), ".4g", "DN\u00b2"),
             "mean per-pixel variance"),
            ("hot pixels", d.get("n_hot"), str(d.get("hot_rule") or "")),
            ("dead pixels", d.get("n_dead"), str(d.get("dead_rule") or "")),
        ]))
        doc.add(_list(d.get("notes") or ()))


def _fixed_pattern_section(doc: _Doc, k: Mapping[str, Any]) -> None:
    bound = k.get("var_bound")
    k_var = k.get("K_var_mean")
    with doc.section("fixed-pattern", "Fixed pattern K\u0302"):
        doc.add(_para("Healey & Kondepudy eqs. 45\u201350: per pixel, the mean of the slopes of "
                      "n1 card/lamp configurations kept within centre \u00b1 p\u00b7\u03c3\u0302 "
                      "(maps under Maps)."))
        doc.add(_facts([
            ("configurations n1 \u00d7 frames n2", f"{k.get('n1')} \u00d7 {k.get('n2')}", ""),
            ("window, p", f"{k.get('window')}, {_value_text(k.get('p'))}",
             "local mean window (pixels) and the rejection width"),
            ("mean of K\u0302", _num(k.get("mean"), ".6g"), ""),
            ("spatial spread of K\u0302", _num(k.get("spatial_std"), ".4g"), "standard deviation"),
            ("slope spread \u03c3\u0302", _num(k.get("sigma_hat"), ".4g"), "eq. 48"),
            ("error of K\u0302 (mean)", _num(math.sqrt(k_var) if _finite(k_var) else None, ".3g"),
             f"\u221a of the mean error variance {_num(k_var, '.3g')}"),
            ("eq. 50 bound", "infinite" if bound is None else _num(bound, ".3g"),
             f"error variance bound (std {_num(k.get('sd_bound'), '.3g')})"),
            ("pixels with a rejected slope",
             _num(100 * k["fraction_pixels_with_rejection"], ".3g", "%")
             if _finite(k.get("fraction_pixels_with_rejection")) else "n/a",
             f"{k.get('n_rejected')} slopes rejected in all"),
        ]))
        doc.add(_list(k.get("notes") or ()))


def _plan_section(doc: _Doc, p: Mapping[str, Any]) -> None:
    with doc.section("plan", "Acquisition plan"):
        doc.add(_para("Healey & Kondepudy sec. V-B: how many card/lamp configurations n1 and "
                      "frames per configuration n2 the fixed-pattern map needs."))
        alternatives = p.get("n2_alternatives") or {}
        doc.add(_facts([
            ("n1 (configurations)", p.get("n1_required"), str(p.get("n1_formula") or "")),
            ("n2 (frames each)", p.get("n2_required"), str(p.get("n2_formula") or "")),
            ("reading of the n2 rule", p.get("n2_reading", ""),
             "; ".join(f"{k}: {v}" for k, v in alternatives.items())),
        ]))
        if p.get("warnings"):
            doc.add("<h3>What the session lacks against the plan</h3>")
            doc.add(_list(p["warnings"], "warnings"))
        doc.add(_list(p.get("notes") or ()))


def _correction_section(doc: _Doc, c: Mapping[str, Any]) -> None:
    def pct(key: str) -> str:
        v = c.get(key)
        return _num(100 * v, ".3g", "%") if _finite(v) else "n/a"

    with doc.section("correction-check", "Correction check"):
        doc.add(_para("Healey & Kondepudy sec. VII-A: how much eq. 51 changes a maximum-intensity "
                      "image, in quantisation steps q."))
        doc.add(_facts([
            ("pixels changed by more than 1 q", pct("frac_gt_1q"), ""),
            ("pixels changed by more than 2 q", pct("frac_gt_2q"), ""),
            ("largest change", _num(c.get("max_change_q"), ".3g", "q"), ""),
            ("mean level of the image", _num(c.get("mean_level"), ".4g", "DN"), ""),
        ]))


def _scene_section(doc: _Doc, scene: Mapping[str, Any]) -> None:
    with doc.section("scene", "Scene variation"):
        doc.add(_para("Healey & Kondepudy sec. VI: the relative variance V_S of each uniform "
                      "surface, with the calibration maps' own errors (eqs. 53\u201358)."))
        rows = []
        for name, sv in scene.items():
            used = sum(1 for m in sv.get("measurements", ()) if m.get("used"))
            rows.append((name, _pm(sv, "V_S"), _num(sv.get("chi2"), ".4g"), sv.get("dof"),
                         _num(sv.get("Q"), ".3g"), used, len(sv.get("excluded") or ())))
        doc.add(_table(rows, ("patch", "V_S", "\u03c7\u00b2", "dof", "Q", "levels used",
                              "excluded"), cls="ccd-report-scene", numeric=(1, 2, 3, 4, 5, 6)))
        notes = sorted({n for sv in scene.values() for n in (sv.get("notes") or ())})
        doc.add(_list(notes))


def _snup_rows(result: Any) -> dict[str, str]:
    return {c.name: format_pm(c.snup, c.snup_err, unit="%") for c in result.channels}


def _flat_section(doc: _Doc, product: CalibrationProduct, session: Session | None) -> None:
    from ccdcore.uniformity import snup

    ff = product.estimates["flat_field"]
    layout = str(ff.get("layout") or product.camera.layout)
    base = ff.get("base")
    with doc.section("flat-field", "Flat field"):
        doc.add(_para("De Lasarte et al. 2007: DL_c = O + G\u00b7DL (eqs. 1\u20134) per channel, "
                      "from the dark image DL_0 and the base image DL_B (maps under Maps). "
                      "SNUP = 100\u00b7\u03c3/mean (eq. 5) measures the nonuniformity."))
        doc.add(_facts([
            ("offset setting", ff.get("setting") or "none named", ""),
            ("base image", "level {}, exposure {} s".format(*base) if base and len(base) == 2
             else "n/a", f"{ff.get('n_base')} frames averaged"),
            ("dark image", f"{ff.get('n_dark')} frames",
             f"exposure {_num(ff.get('dark_exposure'), '.4g', 's')}"),
            ("flagged pixels", ff.get("n_flagged"), str(ff.get("flag_rule") or "")),
        ]))
        rows = [(c.get("name"), _num(c.get("k"), ".5g"), _num(c.get("dark_level"), ".4g"),
                 _num(c.get("base_level"), ".4g"), c.get("n_flagged"),
                 _num(100 * c["dark_zero_fraction"], ".3g", "%")
                 if _finite(c.get("dark_zero_fraction")) else "n/a")
                for c in ff.get("channels", ())]
        doc.add(_table(rows, ("channel", "k (DN)", "\u27e8DL_0\u27e9 (DN)", "\u27e8DL_B\u27e9 (DN)",
                              "flagged", "dark pixels at 0"),
                       cls="ccd-report-flat-channels", numeric=(1, 2, 3, 4, 5)))
        doc.add(_list(ff.get("notes") or ()))
        # SNUP of the base image, from the maps
        if "flat_base" in product.maps and "flat_dark" in product.maps:
            dlb, dl0 = product.maps["flat_base"], product.maps["flat_dark"]
            try:
                raw = _snup_rows(snup(dlb, layout=layout, where="flat_base"))
                sub = _snup_rows(snup(dlb.astype(np.float64) - dl0, layout=layout,
                                      where="flat_base - flat_dark"))
            except CcdError as err:
                doc.add(_para(f"SNUP of the base image: {err}", "warning"))
            else:
                doc.add("<h3>SNUP of the base image, before correction</h3>")
                doc.add(_table([(ch, raw[ch], sub.get(ch, "n/a")) for ch in raw],
                               ("channel", "SNUP of DL_B", "SNUP of DL_B \u2212 DL_0"),
                               cls="ccd-report-snup ccd-report-snup-base", numeric=(1, 2)))
                doc.add(_para("After correction the base image is flat by construction (G is "
                              "made from it); the held-out frames below measure the correction.",
                              "note"))
        _held_out(doc, product, session, layout)


def _held_out(doc: _Doc, product: CalibrationProduct, session: Session | None,
              layout: str) -> None:
    """SNUP before and after correction of the first frame of each flat group other than the
    base (the groups at the base's exposure first; at most :data:`MAX_HELD_OUT`), when the
    session is at hand."""
    from ccdcore.flatfield import correct
    from ccdcore.uniformity import snup

    ff = product.estimates["flat_field"]
    doc.add("<h3>SNUP of held-out flat frames, before and after correction</h3>")
    if session is None or "flat_G" not in product.maps:
        doc.add(_para("Not measured: the report was made from the calibration product alone. "
                      "Make it from the session (ccdcore report SESSION) to correct one frame of "
                      "each flat group that G was not made from.", "note"))
        return
    base = tuple(ff.get("base") or ())
    groups = session.flat_groups(setting=ff.get("setting"))
    base_t = base[1] if len(base) == 2 else None
    keys = sorted((k for k in groups if tuple(k) != base),
                  key=lambda k: (tuple(k)[1:2] != (base_t,), sort_key(tuple(k))))
    if not keys:
        doc.add(_para("None: every flat frame belongs to the base group.", "note"))
        return
    G, O = product.maps["flat_G"], product.maps["flat_O"]
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
        level, exposure = (tuple(key) + (None, None))[:2]
        mean = float(np.mean([c.mean for c in before.channels]))
        b, a = _snup_rows(before), _snup_rows(after)
        n = len(b)
        for i, ch in enumerate(b):
            lead = "".join(f'<td rowspan="{n}"{cls}>{_esc(v)}</td>' for v, cls in (
                (rec.relpath, ""), (_value_text(level), ' class="num"'),
                (_num(exposure, ".4g"), ' class="num"'), (_num(mean, ".4g"), ' class="num"'))
                           ) if i == 0 else ""
            first = ' class="first"' if i == 0 else ""
            body.append(f'<tr{first}>{lead}<td>{_esc(ch)}</td>'
                        f'<td class="num">{_esc(b[ch])}</td>'
                        f'<td class="num">{_esc(a.get(ch, "n/a"))}</td></tr>')
    if body:
        head = "".join(f"<th>{_esc(h)}</th>" for h in (
            "frame", "level", "exposure (s)", "mean (DN)", "channel", "SNUP before",
            "SNUP after"))
        doc.add(f'<table class="ccd-report-snup ccd-report-snup-held-out"><thead><tr>{head}'
                f'</tr></thead><tbody>{"".join(body)}</tbody></table>')
    more = len(keys) - MAX_HELD_OUT
    doc.add(_para("The first frame of each flat group but the base (those at the base's "
                  "exposure first), corrected with the product's G and O; SNUP \u00b1 its "
                  "standard error per channel, the mean before correction."
                  + (f" {more} more group{'s' if more > 1 else ''} not shown." if more > 0
                     else ""), "note"))
    doc.add(_list(problems, "warnings"))


def _response_section(doc: _Doc, r: Mapping[str, Any]) -> None:
    from bokeh.layouts import column
    from bokeh.models import ColumnDataSource, HoverTool
    from bokeh.plotting import figure

    channels = [str(c) for c in r.get("channels", ())]
    scale = r.get("scale") or {}
    with doc.section("response", "Response curves"):
        doc.add(_para("Tsin, Ramesh & Kanade 2001, sec. 3.2: the inverse response g per channel "
                      f"by {r.get('method')}, with its band and the noise terms of eq. 7 "
                      f"(\u03c3_s and \u03c3_c1 in units of g, \u03c3_c2 in DN). Scale: "
                      f"g({scale.get('fixed_code')}) = "
                      f"{_num(scale.get('g_at_fixed_code'), '.4g')}."))
        rows = []
        for i, ch in enumerate(channels):
            def pick(key: str) -> Any:
                v = r.get(key)
                return v[i] if isinstance(v, list) and i < len(v) else None

            rows.append((ch,
                         format_pm(_float(pick("sigma_s")), pick("sigma_s_err")),
                         format_pm(_float(pick("sigma_c1")), pick("sigma_c1_err")),
                         format_pm(_float(pick("sigma_c2")), pick("sigma_c2_err"),
                                   unit="DN"),
                         pick("iterations"), "yes" if pick("converged") else "no",
                         "yes" if pick("white_balance") else "no"))
        doc.add(_table(rows, ("channel", "\u03c3_s", "\u03c3_c1", "\u03c3_c2", "iterations",
                              "converged", "white balance"),
                       cls="ccd-report-response-noise", numeric=(1, 2, 3, 4)))
        times = r.get("exposure_times") or []
        doc.add(_para(f"{len(times)} exposures: " + ", ".join(_num(t, ".4g") for t in times)
                      + " s; bloom radius " + _value_text(r.get("bloom_radius")) + " px."))
        gs = [_floats(g) for g in r.get("g") or ()]
        errs = [_floats(e) for e in r.get("g_err") or ()]
        levels = int(r.get("levels") or (gs[0].size if gs else 0))
        if gs and levels > 1:
            top = levels - 1
            codes = sorted({round(top * f) for f in (0.05, 0.1, 0.25, 0.5, 0.75, 0.95)})
            errs_or_none = errs if len(errs) == len(gs) else [np.empty(0)] * len(gs)
            rows = [[z] + [format_pm(float(g[z]), float(e[z]) if z < e.size else None)
                           if z < g.size else "n/a" for g, e in zip(gs, errs_or_none)]
                    for z in codes]
            doc.add(_table(rows, ["code z"] + [f"g, {ch}" for ch in channels],
                           cls="ccd-report-response-g", numeric=tuple(range(len(channels) + 1))))
        _agreement_tables(doc, r)
        notes = r.get("notes") or {}
        if isinstance(notes, dict):
            doc.add(_list(f"{ch}: {n}" for ch, ns in notes.items() for n in ns))
        else:
            doc.add(_list(notes))
        if not gs:
            return
        fig = figure(height=400, sizing_mode="stretch_width", x_axis_label="code z",
                     y_axis_label="g(z) (linear in exposure)",
                     tools="pan,wheel_zoom,box_zoom,reset", toolbar_location="above",
                     title="Inverse response g(z) per channel, \u00b12\u03c3 band")
        fig.toolbar.logo = None
        fig.toolbar.autohide = True
        lines, sources = [], []
        for i, (ch, g) in enumerate(zip(channels, gs)):
            e = errs[i] if i < len(errs) and errs[i].size == g.size else np.zeros_like(g)
            e = np.nan_to_num(e)
            colour = _CHANNEL_COLOURS.get(ch, _SHADOW_COLOURS[i % len(_SHADOW_COLOURS)])
            src = ColumnDataSource({"z": np.arange(g.size), "g": g, "err": e,
                                    "lo": g - 2 * e, "hi": g + 2 * e}, name=f"ccd-response-{ch}")
            sources.append(src)
            fig.varea("z", "lo", "hi", source=src, fill_color=colour, fill_alpha=0.25,
                      legend_label=f"{ch} \u00b12\u03c3")
            lines.append(fig.line("z", "g", source=src, line_color=colour, line_width=2,
                                  legend_label=f"g, {ch}"))
        fig.legend.location = "top_left"
        fig.add_tools(HoverTool(renderers=lines, tooltips=[("z", "@z"), ("g", "@g{0.00000}"),
                                                           ("\u00b11\u03c3", "@err{0.00000}")]))
        err_fig = figure(height=200, sizing_mode="stretch_width", x_axis_label="code z",
                         y_axis_label="\u03c3 of g(z)", x_range=fig.x_range,
                         tools="pan,wheel_zoom,box_zoom,reset", toolbar_location="above",
                         title="The band's half-width: the 1\u03c3 error of g(z)")
        err_fig.toolbar.logo = None
        err_fig.toolbar.autohide = True
        for src, line in zip(sources, lines):
            err_fig.line("z", "err", source=src, line_color=line.glyph.line_color, line_width=2)
        doc.plot(column(fig, err_fig, sizing_mode="stretch_width"), id_="response-curves",
                 caption="g(z) of every channel with its \u00b12\u03c3 band; below, the 1\u03c3 "
                         "error itself (0 at the fixed code, which sets the scale).")


def _agreement_tables(doc: _Doc, r: Mapping[str, Any]) -> None:
    """The response's prediction agreement (Tsin et al. sec. 4.2, ``r["agreement"]``): the
    pooled figures and each channel's, then each pair of neighbouring images per channel."""
    from .response_plots import AGREEMENT_COLUMNS, channel_agreement_rows, pair_rows

    a = r.get("agreement")
    if not isinstance(a, dict):
        return
    rng = a.get("code_range") or ("?", "?")
    doc.add(_para(f"How well the curves predict the bracket's own images (sec. 4.2), in DN "
                  f"over the codes {rng[0]}..{rng[-1]} both images read: each image from a "
                  "neighbour with the result's exposure ratio, with each pair's ratio fitted "
                  "(the difference is what exposure errors cost), and from the blend of all "
                  "the other images."))
    rows = channel_agreement_rows(a)
    header = ["channel", *AGREEMENT_COLUMNS.values(), "predictions"]
    doc.add(_table([[row[h] for h in header] for row in rows], header,
                   cls="ccd-report-response-agreement", numeric=(1, 2, 3, 4)))
    pairs = pair_rows(a, _floats(r.get("exposure_times")))
    if pairs:
        header = list(pairs[0])
        doc.add(_table([[row.get(h, "n/a") for h in header] for row in pairs], header,
                       cls="ccd-report-response-pairs", numeric=tuple(range(2, len(header)))))
        doc.add(_para("Per pair of neighbouring images (numbered from 1, shortest exposure "
                      "first): the RMS with the result's ratio, with the pair's fitted ratio, "
                      "and the fitted ratio over the nominal t_k / t_j. A frame with a wrong "
                      "exposure time, or one that moved, shows in the pairs it takes part in.",
                      "note"))


# ---------------------------------------------------------------------------------------------
# change detection
# ---------------------------------------------------------------------------------------------
def _matrix_text(M: Sequence[Sequence[float]], err: Sequence[Sequence[float]]) -> _Html:
    """A matrix with the error of each element, as a small table."""
    rows = "".join("<tr>" + "".join(f"<td>{_esc(format_pm(float(v), float(e)))}</td>"
                                    for v, e in zip(row, erow)) + "</tr>"
                   for row, erow in zip(M, err))
    return _Html(f'<table class="matrix">{rows}</table>')


def _change_section(doc: _Doc, change: Any, inputs: Mapping[str, Any] | None) -> None:
    from bokeh.models import HoverTool, LinearColorMapper, LogColorMapper, ColorBar
    from bokeh.palettes import Viridis256

    summary = change.to_dict()
    with doc.section("change", "Change detection"):
        doc.add(_para("Tsin, Ramesh & Kanade 2001, sec. 5: the reference and target brackets as "
                      "radiance with its per-pixel sigma; one colour transform M per cluster "
                      "(background, each shade of shadow), d\u00b2 of each pixel under it, and "
                      "the threshold calibrated on the background for the requested false-alarm "
                      "rate."))
        if inputs:
            doc.add(_para(f"Response: {inputs.get('source', 'n/a')}; channels "
                          f"{', '.join(map(str, inputs.get('channels', ())))}."))
        doc.add(_facts([
            ("false-alarm rate requested", _num(summary.get("pfa_requested"), ".3g"),
             "per background pixel"),
            ("threshold d\u00b2", _num(summary.get("threshold"), ".4g"),
             f"calibrated on {summary.get('background_sample')} background values"),
            ("\u03c7\u00b2 threshold", _num(summary.get("threshold_chi2"), ".4g"),
             f"{summary.get('dof')} degrees of freedom, without the calibration"),
            ("observed false-alarm rate", _num(summary.get("pfa_observed"), ".3g"),
             f"{_num(summary.get('pfa_observed_at_chi2_threshold'), '.3g')} at the \u03c7\u00b2 "
             "threshold"),
            ("d\u00b2 scale", _num(summary.get("d2_scale"), ".4g"),
             "median background d\u00b2 over \u03c7\u00b2's median"),
            ("background mean d\u00b2", _num(summary.get("background_d2_mean"), ".3g"), ""),
            ("changed pixels", summary.get("changed_pixels"), ""),
            ("undetermined pixels", summary.get("undetermined_pixels"),
             "no radiance in one of the brackets"),
        ]))
        rows = []
        for c in summary.get("clusters", ()):
            rows.append((c["label"], _label_name(int(c["label"])), c["pixels"],
                         _num(c.get("d2_median"), ".3g"), _matrix_text(c["M"], c["M_err"])))
        doc.add(_table(rows, ("label", "cluster", "pixels", "median d\u00b2", "M \u00b1 error"),
                       cls="ccd-report-clusters", numeric=(0, 2, 3)))
        doc.add(_list(summary.get("notes") or ()))

        labels = np.asarray(change.labels)
        h, w = labels.shape
        counts = change.counts()
        palette = ["#ffffff"] * 256
        for lab in counts:
            palette[lab] = _label_colour(lab)
        factor = max(1, math.ceil(max(h, w) / MAX_MAP_SIDE))
        shown = _reduce(labels.astype(np.float32), factor, "max")
        fig = _image_figure("Labels", w, h, 380)
        mapper = LinearColorMapper(palette=palette, low=-0.5, high=255.5)
        img = fig.image(image=[shown], x=-0.5, y=-0.5, dw=w, dh=h, color_mapper=mapper)
        fig.add_tools(HoverTool(renderers=[img], tooltips=[("x, y", "$x{0}, $y{0}"),
                                                           ("label", "@image{0}")]))
        legend = "".join(
            f'<li><span class="swatch" style="background:{_label_colour(lab)}"></span>'
            f"{_esc(lab)}: {_esc(_label_name(lab))} \u2014 {n:,} pixels</li>"
            for lab, n in sorted(counts.items()))
        caption = _Html('Labels of every pixel: <ul class="ccd-change-legend legend">' + legend
                        + "</ul>" + _esc(_resolution_text((h, w), factor, "maximum")))
        doc.add('<div class="ccd-map-row">')
        doc.plot(fig, id_="change-labels", caption=caption,
                 width=fig.frame_width + _MAP_MARGIN)

        d2 = np.asarray(change.d2_best, np.float64)
        shown = _reduce(d2, factor, "mean")
        pos = shown[np.isfinite(shown) & (shown > 0)]
        low, high = (float(np.percentile(pos, 1)), float(np.percentile(pos, 99.5))) \
            if pos.size else (1e-3, 1.0)
        if not high > low:
            high = low * 10
        fig = _image_figure("d\u00b2 under the best cluster", w, h, 380)
        mapper = LogColorMapper(palette=Viridis256, low=low, high=high,
                                nan_color="rgba(0, 0, 0, 0)")
        img = fig.image(image=[shown], x=-0.5, y=-0.5, dw=w, dh=h, color_mapper=mapper)
        fig.add_layout(ColorBar(color_mapper=mapper, width=12, title="d\u00b2"), "right")
        fig.add_tools(HoverTool(renderers=[img], tooltips=[("x, y", "$x{0}, $y{0}"),
                                                           ("d\u00b2", "@image{%.4g}")],
                                formatters={"@image": "printf"}))
        doc.plot(fig, id_="change-d2",
                 caption="d\u00b2 of every pixel under the cluster that explains it best "
                         f"(logarithmic colour scale; threshold {_num(change.threshold, '.4g')}). "
                         + _resolution_text((h, w), factor, "mean"),
                 width=fig.frame_width + _MAP_MARGIN)
        doc.add("</div>")


# ---------------------------------------------------------------------------------------------
# EMVA 1288 figures
# ---------------------------------------------------------------------------------------------
#: (key, name, unit) of the EMVA 1288 table, in order; each key's error is ``<key>_err``
#: (units as :class:`ccdcore.datasheet.EmvaFigures` states them)
_EMVA_FIGURES: tuple[tuple[str, str, str], ...] = (
    ("K", "system gain K", "DN/e\u207b"),
    ("QE", "quantum efficiency \u03b7", "%"),
    ("sigma_y_dark", "temporal dark noise \u03c3_y.dark", "DN"),
    ("sigma_d", "dark noise \u03c3_d", "e\u207b"),
    ("sigma_d_ptc", "dark noise \u03c3_d from the photon-transfer intercept", "e\u207b"),
    ("u_e_sat", "saturation capacity \u03bc_e.sat", "e\u207b"),
    ("u_p_sat", "saturation irradiation \u03bc_p.sat", "photons"),
    ("u_p_min", "absolute sensitivity threshold \u03bc_p.min", "photons"),
    ("SNR_max", "maximum signal-to-noise ratio SNR_max", ""),
    ("DR", "dynamic range DR", ""),
    ("DR_dB", "dynamic range DR", "dB"),
    ("LE_min", "linearity error LE_min", "%"),
    ("LE_max", "linearity error LE_max", "%"),
    ("DSNU1288", "DSNU\u2081\u2082\u2088\u2088", "e\u207b"),
    ("PRNU1288", "PRNU\u2081\u2082\u2088\u2088", "%"),
)


def _columns(obj: Any, wanted: Mapping[str, Sequence[str]]) -> dict[str, NDArray[np.float64]]:
    """Columns of a dict of lists or a list of dicts: name -> values of the first key of
    ``wanted[name]`` present (names without any are left out)."""
    out: dict[str, NDArray[np.float64]] = {}
    if isinstance(obj, dict):
        for name, keys in wanted.items():
            key = next((k for k in keys if k in obj), None)
            if key is not None and isinstance(obj[key], list):
                out[name] = _floats(obj[key])
    elif isinstance(obj, list) and all(isinstance(p, dict) for p in obj):
        for name, keys in wanted.items():
            key = next((k for k in keys if obj and k in obj[0]), None)
            if key is not None:
                out[name] = _floats([p.get(key) for p in obj])
    n = min((v.size for v in out.values()), default=0)
    return {k: v[:n] for k, v in out.items()}


def _scatter_figure(title: str, xlabel: str, ylabel: str, *, log: bool = False) -> Any:
    from bokeh.plotting import figure

    kw = {"x_axis_type": "log", "y_axis_type": "log"} if log else {}
    fig = figure(title=title, height=360, sizing_mode="stretch_width", x_axis_label=xlabel,
                 y_axis_label=ylabel, tools="pan,wheel_zoom,box_zoom,reset",
                 toolbar_location="above", **kw)
    fig.toolbar.logo = None
    fig.toolbar.autohide = True
    return fig


def _emva_section(doc: _Doc, emva: Mapping[str, Any]) -> None:
    units = emva.get("units") if isinstance(emva.get("units"), dict) else {}
    with doc.section("emva1288", "EMVA 1288 figures"):
        doc.add(_para("The data-sheet figures of EMVA Standard 1288 as the product states them "
                      f"({emva.get('standard', 'EMVA 1288')}; definitions of "
                      f"{emva.get('definitions', 'the standard')}); n/a: not available from "
                      "this session."))
        rows = []
        for key, name, unit in _EMVA_FIGURES:
            unit = str(units.get(key, unit))
            v, e = emva.get(key), emva.get(f"{key}_err")
            value = format_pm(v, e if _finite(e) else None, unit=unit) if _finite(v) else "n/a"
            rows.append((name, value, key))
        doc.add(_table(rows, ("figure", "value", "key"), cls="ccd-report-emva", numeric=(1,)))
        notes = emva.get("notes")
        doc.add(_list(notes if isinstance(notes, list) else [notes] if notes else ()))
        snr = _columns(emva.get("snr_curve"), {"u_p": ("u_p",),
                                               "snr": ("snr", "snr_measured"),
                                               "model": ("snr_model",),
                                               "total": ("snr_total",)})
        if "u_p" in snr and ("snr" in snr or "model" in snr):
            fig = _scatter_figure("Signal-to-noise ratio against irradiation",
                                  "\u03bc_p (photons per pixel)", "SNR", log=True)
            x = snr["u_p"]
            for key, label, style in (("model", "model (eq. 11)",
                                       dict(line_color="#D55E00", line_width=2)),
                                      ("total", "model with DSNU and PRNU",
                                       dict(line_color="#6f42c1", line_width=2,
                                            line_dash="dashed"))):
                if key in snr:
                    ok = (x > 0) & (snr[key] > 0)
                    fig.line(x[ok], snr[key][ok], legend_label=label, **style)
            if "snr" in snr:
                ok = (x > 0) & (snr["snr"] > 0)
                fig.scatter(x[ok], snr["snr"][ok], size=7, color="#1f5f99",
                            legend_label="measured")
            fig.legend.location = "top_left"
            doc.plot(fig, id_="emva-snr", caption="SNR against the mean number of photons per "
                                                  "pixel, measured (eq. 10) and modelled "
                                                  "(log-log).")
        pts = _columns(emva.get("points"), {k: (k,) for k in (
            "u_p", "u_y", "u_y_dark", "s2_y", "s2_y_dark", "u_y_err", "s2_y_err",
            "in_sensitivity_fit", "in_linearity_fit")})
        if {"u_y", "u_y_dark", "s2_y", "s2_y_dark"} <= set(pts):
            fig = _scatter_figure("Photon transfer", "\u03bc_y \u2212 \u03bc_y.dark (DN)",
                                  "\u03c3\u00b2_y \u2212 \u03c3\u00b2_y.dark (DN\u00b2)")
            x, y = pts["u_y"] - pts["u_y_dark"], pts["s2_y"] - pts["s2_y_dark"]
            if "s2_y_err" in pts:
                e = np.nan_to_num(pts["s2_y_err"])
                fig.segment(x, y - e, x, y + e, line_color="#1f5f99")
            _fit_points(fig, x, y, pts.get("in_sensitivity_fit"), "in the K fit")
            doc.plot(fig, id_="emva-ptc", caption="Temporal variance against the mean signal, "
                                                  "both less their dark values (sec. 6.6), "
                                                  "with the standard errors of \u03c3\u00b2_y; "
                                                  "hollow: outside the fit of K (above 70 % "
                                                  "of saturation).")
        if {"u_p", "u_y", "u_y_dark"} <= set(pts):
            fig = _scatter_figure("Linearity", "\u03bc_p (photons per pixel)",
                                  "\u03bc_y \u2212 \u03bc_y.dark (DN)")
            _fit_points(fig, pts["u_p"], pts["u_y"] - pts["u_y_dark"],
                        pts.get("in_linearity_fit"), "in the linearity fit")
            doc.plot(fig, id_="emva-linearity", caption="Mean signal less the dark signal "
                                                        "against the irradiation (sec. 6.7); "
                                                        "hollow: outside the linearity fit "
                                                        "(5\u201395 % of saturation).")


def _fit_points(fig: Any, x: NDArray, y: NDArray, used: NDArray | None, label: str) -> None:
    """Points of an EMVA plot: filled where ``used`` (in a fit), hollow grey elsewhere."""
    inside = np.ones(x.size, bool) if used is None else used > 0
    fig.scatter(x[inside], y[inside], size=7, color="#1f5f99", legend_label=label)
    if (~inside).any():
        fig.scatter(x[~inside], y[~inside], size=8, fill_alpha=0.0, line_color="#8c959f",
                    line_width=2, legend_label="outside the fit")
    fig.legend.location = "top_left"


# ---------------------------------------------------------------------------------------------
# skipped, provenance
# ---------------------------------------------------------------------------------------------
def _skipped_section(doc: _Doc, product: CalibrationProduct) -> None:
    with doc.section("skipped", "Skipped estimates"):
        if not product.skipped:
            doc.add(_para("None: every estimate was made."))
            return
        doc.add(_table([(_ESTIMATE_TITLES.get(s.estimate, s.estimate), s.code, s.reason,
                         ", ".join(s.roles)) for s in product.skipped],
                       ("estimate", "code", "reason", "roles missing"),
                       cls="ccd-report-skipped"))


def _provenance_section(doc: _Doc, product: CalibrationProduct, session: Session | None,
                        now: str) -> None:
    prov = product.provenance
    digest = prov.get("session_hash")
    date = prov.get("date")
    with doc.section("provenance", "Provenance"):
        doc.add(_facts([
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
            doc.add(_table([(_ESTIMATE_TITLES.get(k, k), _parameters(v))
                            for k, v in steps.items()],
                           ("step", "parameters"), cls="ccd-report-steps"))


def _parameters(params: Any) -> _Html:
    """A step's parameters, one ``key: value`` per line."""
    if not isinstance(params, dict):
        return _Html(_esc(_value_text(params)))
    return _Html("<br>".join(f"<b>{_esc(k)}</b>: {_esc(_value_text(v))}"
                             for k, v in params.items()))


# ---------------------------------------------------------------------------------------------
# the page
# ---------------------------------------------------------------------------------------------
_CSS = """
:root { color-scheme: light; }
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, "Helvetica Neue", Arial,
       "Noto Sans", "Liberation Sans", "DejaVu Sans", sans-serif; color: #1f2328;
       background: #ffffff; line-height: 1.45; max-width: 1120px; margin: 0 auto;
       padding: 1.5rem 2rem 4rem; }
h1 { font-size: 1.9rem; margin: 0 0 0.3rem; }
h2 { font-size: 1.35rem; margin: 2.4rem 0 0.8rem; padding-bottom: 0.25rem;
     border-bottom: 2px solid #d0d7de; }
h3 { font-size: 1.08rem; margin: 1.5rem 0 0.5rem; }
p { margin: 0.5rem 0; max-width: 62rem; }
header .subtitle { color: #57606a; margin: 0; }
table { border-collapse: collapse; margin: 0.6rem 0 1rem; font-size: 0.92rem; }
th, td { padding: 0.3rem 0.75rem; text-align: left; vertical-align: top;
         border-top: 1px solid #d0d7de; border-bottom: 1px solid #d0d7de; }
thead th { background: #f6f8fa; border-bottom: 2px solid #8c959f; font-weight: 600; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
table.facts td:first-child { font-weight: 600; white-space: nowrap; }
table.facts td:last-child { color: #57606a; }
nav.toc { background: #f6f8fa; border: 1px solid #d0d7de; border-radius: 6px;
          padding: 0.6rem 1.2rem; margin: 1.2rem 0; display: inline-block; }
nav.toc h2 { font-size: 1rem; margin: 0.2rem 0 0.4rem; border: none; padding: 0; }
nav.toc ol { margin: 0; padding-left: 1.4rem; columns: 2; column-gap: 3rem; }
a { color: #0b5cad; }
ul.notes, ul.warnings { margin: 0.4rem 0 1rem; padding-left: 1.3rem; max-width: 62rem; }
ul.notes { color: #57606a; font-size: 0.9rem; }
ul.warnings li, p.warning { color: #8a4600; }
p.note { color: #57606a; font-size: 0.9rem; }
figure.ccd-report-plot { margin: 1rem 0 1.6rem; break-inside: avoid; page-break-inside: avoid; }
figure.ccd-report-plot figcaption { font-size: 0.88rem; color: #57606a; margin-top: 0.35rem;
                                    max-width: 60rem; }
.ccd-map-row { display: flex; flex-wrap: wrap; gap: 0.5rem 24px; align-items: flex-start; }
.ccd-map-row figure.ccd-report-plot { margin: 0.4rem 0 1rem; }
ul.legend { list-style: none; padding: 0; margin: 0.3rem 0; }
ul.legend li { margin: 0.1rem 0; }
.swatch { display: inline-block; width: 0.9em; height: 0.9em; margin-right: 0.45em;
          border: 1px solid #8c959f; vertical-align: -0.1em; }
table.ccd-report-snup-held-out tr.first td { border-top: 2px solid #afb8c1; }
table.ccd-report-snup-held-out tr:not(.first) td { border-top-color: #eaeef2; }
table.matrix { margin: 0; font-size: 0.85rem; }
table.matrix td { border: none; padding: 0 0.9rem 0 0; text-align: right;
                  font-variant-numeric: tabular-nums; white-space: nowrap; }
footer { margin-top: 3rem; color: #57606a; font-size: 0.85rem; }
@media print {
  body { max-width: none; padding: 0; font-size: 10.5pt; }
  nav.toc { display: block; break-after: page; }
  a { color: inherit; text-decoration: none; }
  h2, h3 { break-after: avoid; page-break-after: avoid; }
  table { break-inside: avoid; page-break-inside: avoid; }
}
"""

def _bokeh_resources(roots: Sequence[Any]) -> tuple[str, str]:
    """BokehJS as inline ``<script>`` and ``<style>`` text: the core library, plus the widget
    and table libraries only when a root uses them.

    Only Bokeh's own code is taken (``Resources.js_raw``): the script *files* a Bokeh resources
    object lists include every ``__javascript__`` that any imported Bokeh extension declares
    (Panel's, once Panel is imported, as in the app), whatever the document uses, and those
    would be links out of a file that must open offline.
    """
    from bokeh.models import Widget
    from bokeh.models.widgets.tables import TableWidget
    from bokeh.resources import Resources

    components = ["bokeh"]
    models = {m for root in roots for m in root.references()}
    if any(isinstance(m, Widget) for m in models):
        components.append("bokeh-widgets")
    if any(isinstance(m, TableWidget) for m in models):
        components.append("bokeh-tables")
    res = Resources(mode="inline", components=components, log_level="warn")
    js = "".join(f'<script type="text/javascript">\n{code}\n</script>\n' for code in res.js_raw)
    css = "".join(f"<style>\n{code}\n</style>\n" for code in res.css_raw)
    return js, css


def _page(doc: _Doc, title: str) -> str:
    """The whole HTML file: our CSS and fragments, BokehJS and the figures inline."""
    from bokeh.embed import components

    toc = ('<nav class="toc" aria-label="Contents"><h2>Contents</h2><ol>'
           + "".join(f'<li><a href="#{_esc(i)}">{_esc(t)}</a></li>' for i, t in doc.toc)
           + "</ol></nav>")
    parts = list(doc.parts)
    at = next((i for i, (k, v) in enumerate(parts) if k == "html" and v == "</header>"), 0)
    parts.insert(at + 1, ("html", toc))
    script, divs, js, css = "", {}, "", ""
    if doc.roots:           # nothing to draw: no BokehJS either
        script, divs = components({r.name: r for r in doc.roots})
        js, css = _bokeh_resources(doc.roots)
    body = "\n".join(divs[v] if kind == "root" else v for kind, v in parts)
    return ('<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            f'<meta name="generator" content="ccdcore {_esc(__version__)}">\n'
            f"<title>{_esc(title)}</title>\n{css}<style>{_CSS}</style>\n{js}</head>\n"
            f"<body>\n{body}\n{script}\n</body>\n</html>\n")


# ---------------------------------------------------------------------------------------------
# inputs
# ---------------------------------------------------------------------------------------------
def _is_product(path: Path) -> bool:
    return (path.is_dir() and (path / PRODUCT_FILE).is_file()) or (
        path.is_file() and path.name == PRODUCT_FILE)


def _has_change(session: Session) -> bool:
    roles = session.roles()
    return bool(roles.get("reference")) and bool(roles.get("target"))


def _no_progress(step: str, fraction: float) -> None:
    return None


def _calibrate(session: Session, progress: Progress) -> tuple[CalibrationProduct, Any]:
    """The product of ``session`` and, with reference and target brackets, its change result
    (``(result, inputs)`` of :func:`ccdcore.change.session_change`)."""
    session.raise_if_invalid()
    with_change = _has_change(session)
    share = 0.6 if with_change else 0.95
    if with_change and len(missing_frames(session)) == len(REQUIREMENTS):
        # only brackets for change detection: every estimate is skipped, each with its reason
        e = estimate_all(session)
        provenance: dict[str, Any] = {"ccdcore": __version__, "session": session.label,
                                      "source": session.source, "n_frames": len(session.frames)}
        content_hash = getattr(session, "content_hash", None)   # as calibrate records it
        if callable(content_hash):
            provenance["session_hash"] = content_hash()
        provenance["date"] = datetime.datetime.now(datetime.timezone.utc).isoformat(
            timespec="seconds")
        product = CalibrationProduct(maps={}, estimates={}, camera=session.camera,
                                     provenance={**provenance, "steps": {}}, skipped=e.skipped)
    else:
        product = calibrate(session, progress=lambda step, f: progress(f"calibrate: {step}",
                                                                       share * f))
    change = None
    if with_change:
        from ccdcore.change import session_change

        progress("change detection", share)
        change = session_change(
            session, progress=lambda f, msg: progress(f"change detection: {msg}",
                                                      share + (0.95 - share) * f))
    return product, change


@dataclass
class _Inputs:
    product: CalibrationProduct
    session: Session | None
    change: Any
    change_inputs: Mapping[str, Any] | None
    origin: str


def _inputs(source: Any, product: CalibrationProduct | None, change: Any,
            progress: Progress) -> _Inputs:
    session: Session | None = None
    if isinstance(source, CalibrationProduct):
        product = product or source
        origin = f"calibration product of {product.provenance.get('session', 'a session')}"
    elif isinstance(source, Session):
        session = source
        origin = session.label
    else:
        path = Path(source)
        if product is None and _is_product(path):
            product = load_product(path)
            origin = str(path)
        elif product is not None and _is_product(path):
            origin = str(path)
        else:
            session = open_session(path)
            origin = session.label
    if product is None:
        assert session is not None
        product, computed = _calibrate(session, progress)
        change = change if change is not None else computed
    inputs = None
    if isinstance(change, tuple):
        change, inputs = change
    return _Inputs(product, session, change, inputs, origin)


# ---------------------------------------------------------------------------------------------
# public
# ---------------------------------------------------------------------------------------------
def build_report(source: Any, *, product: CalibrationProduct | None = None, change: Any = None,
                 progress: Progress | None = None) -> str:
    """The calibration report of ``source`` as one self-contained HTML text.

    Parameters
    ----------
    source
        A :class:`~ccdcore.session.Session`, a :class:`~ccdcore.product.CalibrationProduct`, or
        a path: a calibration product folder (or its ``calibration.json``), or a session (a
        folder, ``session.toml``, plain folder or EMVA1288 descriptor).
    product
        The session's calibration product when it is already made: nothing is then computed
        (a change result is drawn only when ``change`` is given). Without it, a session is
        calibrated (:func:`ccdcore.product.calibrate`) and, when it has ``reference`` and
        ``target`` brackets, change detection runs (:func:`ccdcore.change.session_change`,
        default options).
    change
        A :class:`ccdcore.change.ChangeResult`, or the ``(result, inputs)`` pair
        :func:`~ccdcore.change.session_change` returns.
    progress
        ``progress(step, fraction)`` called as the computation goes (fraction of the whole,
        0 to 1).

    Returns
    -------
    str
        The HTML text: the estimates with their errors, the plots and maps (Bokeh, inline),
        the skipped estimates and the provenance; nothing is fetched when it is opened.

    Raises
    ------
    CcdError
        The source cannot be opened, the session has errors, or nothing could be calibrated
        (the message names the file and the problem).
    """
    report = progress or _no_progress
    src = _inputs(source, product, change, report)
    report("writing the report", 0.95)
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    p = src.product
    cam = p.camera
    title = "Calibration report" + (f": {cam.name}" if cam.name else "")
    doc = _Doc()
    doc.add('<header class="ccd-report-header">' f"<h1>{_esc(title)}</h1>"
            f'<p class="subtitle">{_esc(src.origin)} \u2014 made by ccdcore {_esc(__version__)} '
            f"on {_esc(now)}</p>")
    doc.add("</header>")
    _summary_section(doc, p, src.session, src.change)
    est = p.estimates
    if isinstance(est.get("noise"), dict):
        _noise_section(doc, est["noise"])
    emva = getattr(p, "emva1288", None)       # EMVA 1288 data-sheet figures, when made
    if isinstance(emva, dict) and emva:
        _emva_section(doc, emva)
    if isinstance(est.get("dark"), dict):
        _dark_section(doc, est["dark"])
    if isinstance(est.get("fixed_pattern"), dict):
        _fixed_pattern_section(doc, est["fixed_pattern"])
    if isinstance(est.get("plan"), dict):
        _plan_section(doc, est["plan"])
    if isinstance(est.get("correction_check"), dict):
        _correction_section(doc, est["correction_check"])
    if isinstance(est.get("scene"), dict) and est["scene"]:
        _scene_section(doc, est["scene"])
    if isinstance(est.get("flat_field"), dict):
        _flat_section(doc, p, src.session)
    if isinstance(est.get("response"), dict):
        _response_section(doc, est["response"])
    _maps_section(doc, p)
    if src.change is not None:
        _change_section(doc, src.change, src.change_inputs)
    _skipped_section(doc, p)
    _provenance_section(doc, p, src.session, now)
    doc.add(f"<footer>Made by ccdcore {_esc(__version__)}. Every figure's data and BokehJS "
            "are in this file; it needs no network.</footer>")
    out = _page(doc, title)
    report("done", 1.0)
    return out


def _input_files(source: Any) -> tuple[list[Path], Any]:
    """The files (and the product folder) a report of ``source`` reads -- an output must not be
    one of them nor inside one -- and the opened source (a session is opened once)."""
    from ccdcore.product import session_inputs

    if isinstance(source, Session):
        return session_inputs(source), source
    if isinstance(source, CalibrationProduct):
        return [], source
    path = Path(source)
    if _is_product(path):
        return [path if path.is_dir() else path.parent], source
    session = open_session(path)
    return session_inputs(session), session


def write_report(source: Any, out_path: str | os.PathLike, **kw: Any) -> Path:
    """:func:`build_report` written to ``out_path`` atomically (a temporary folder beside it,
    :func:`ccdcore.io.output_set`, renamed into place once complete: a failure or SIGTERM
    leaves an earlier report untouched and no temporary file); returns the path.

    Raises
    ------
    CcdError
        As :func:`build_report`; or ``out_path`` is a folder, a FIFO or a device (or a symlink
        to one), one of the files the report reads or inside the product folder (it is
        refused before anything is computed); or writing failed (naming ``out_path``).
    """
    from ccdcore.io import atomic_write_text, check_output, check_outputs, output_set

    out = Path(out_path)
    if out.is_dir():
        raise CcdError(out, "is a folder; give the report's file name, e.g. report.html")
    check_output(out)
    inputs, source = _input_files(source)
    check_outputs(out.parent, [out.name], inputs)
    text = build_report(source, **kw)
    with output_set(out.parent, inputs=inputs) as tmp:
        atomic_write_text(tmp / out.name, text)
    return out
