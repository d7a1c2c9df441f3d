"""The report's HTML: escaping, numbers as text, tables and lists, the document being assembled
and the page around it (our CSS, BokehJS and every figure inline).

Every string that comes from a session or a product goes through :func:`esc` (or :func:`cell`,
which leaves :class:`Html` fragments as they are). Bokeh is imported only when the page is
written (:func:`page`).

Public objects
--------------
Html
    A fragment that is already HTML.
esc(value), cell(value)
    A value as escaped text; a table cell (escaped unless :class:`Html`).
finite(v), num(v, fmt, unit), value_text(v), short(values)
    Numbers and JSON values as text ("n/a" for None or non-finite).
json_floats(values)
    JSON numbers (``None`` written for NaN) back as float64.
table(rows, header, cls=, numeric=), facts(rows), bullets(items), para(text)
    Tables, a list, a paragraph.
Doc
    The report in document order: fragments, Bokeh roots and the table of contents.
page(doc, title), CSS
    The whole HTML file; the report's style sheet in it.
"""
from __future__ import annotations

import html
import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Sequence

import numpy as np
from numpy.typing import NDArray

from ccdcore import __version__

__all__ = ["Html", "esc", "cell", "finite", "num", "value_text", "short", "json_floats",
           "table", "facts", "bullets", "para", "Doc", "page", "CSS"]

#: the longest list of values (files, levels ...) written out in the provenance
MAX_LIST = 12


# ---------------------------------------------------------------------------------------------
# text and numbers
# ---------------------------------------------------------------------------------------------
class Html(str):
    """A fragment that is already HTML (not escaped again by :func:`cell`)."""


def esc(value: Any) -> str:
    return html.escape(str(value), quote=True)


def cell(value: Any) -> str:
    return value if isinstance(value, Html) else esc(value)


def finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def num(v: Any, fmt: str = ".4g", unit: str = "") -> str:
    """A number for a table (``"n/a"`` for None or non-finite)."""
    if not finite(v):
        return "n/a"
    return f"{v:{fmt}}" + (f" {unit}" if unit else "")


def short(values: Sequence[Any], limit: int = MAX_LIST) -> str:
    shown = ", ".join(value_text(v) for v in values[:limit])
    more = len(values) - limit
    return shown + (f", \u2026 and {more} more" if more > 0 else "")


def value_text(v: Any) -> str:
    """A JSON value of the provenance as a short text."""
    if v is None:
        return "none"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return "[" + short(list(v)) + "]"
    if isinstance(v, dict):
        return "; ".join(f"{k} = {value_text(x)}" for k, x in v.items())
    return str(v)


def json_floats(values: Any) -> NDArray[np.float64]:
    """A JSON list of numbers (``None`` for NaN) as float64."""
    if values is None:
        return np.empty(0)
    return np.array([np.nan if v is None else v for v in np.ravel(np.asarray(values, object))],
                    np.float64)


# ---------------------------------------------------------------------------------------------
# tables, lists, paragraphs
# ---------------------------------------------------------------------------------------------
def table(rows: Iterable[Sequence[Any]], header: Sequence[str] | None = None, *,
          cls: str = "", numeric: Sequence[int] = ()) -> str:
    """An HTML table; cells are escaped unless they are :class:`Html`; the columns in
    ``numeric`` are right-aligned."""
    out = [f'<table class="{esc(cls)}">' if cls else "<table>"]
    if header:
        out.append("<thead><tr>" + "".join(f"<th>{esc(h)}</th>" for h in header)
                   + "</tr></thead>")
    out.append("<tbody>")
    for row in rows:
        out.append("<tr>" + "".join(
            f'<td class="num">{cell(c)}</td>' if i in numeric else f"<td>{cell(c)}</td>"
            for i, c in enumerate(row)) + "</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def facts(rows: Iterable[tuple[str, Any] | tuple[str, Any, str]], cls: str = "facts") -> str:
    """A two- or three-column table: quantity, value (right-aligned), meaning."""
    rows = list(rows)
    three = any(len(r) > 2 for r in rows)
    return table([(r[0], r[1], r[2] if len(r) > 2 else "") if three else r for r in rows],
                 cls=cls, numeric=(1,))


def bullets(items: Iterable[Any], cls: str = "notes") -> str:
    """A ``<ul>`` of the items that are not empty (nothing when none is)."""
    items = [i for i in items if i not in (None, "")]
    if not items:
        return ""
    return f'<ul class="{cls}">' + "".join(f"<li>{cell(i)}</li>" for i in items) + "</ul>"


def para(text: Any, cls: str = "") -> str:
    return (f'<p class="{cls}">' if cls else "<p>") + cell(text) + "</p>"


# ---------------------------------------------------------------------------------------------
# the document being assembled
# ---------------------------------------------------------------------------------------------
@dataclass
class Doc:
    """The report in document order: HTML fragments and Bokeh roots, and the table of contents."""

    parts: list[tuple[str, Any]] = field(default_factory=list)
    toc: list[tuple[str, str]] = field(default_factory=list)
    roots: list[Any] = field(default_factory=list)

    def add(self, fragment: str) -> None:
        if fragment:
            self.parts.append(("html", fragment))

    @staticmethod
    def _section_open(id_: str, title: str) -> str:
        return f'<section id="{esc(id_)}" class="ccd-report-section"><h2>{esc(title)}</h2>'

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
        self.parts.append(("html", f'<figure class="{classes}" id="{esc(id_)}"{style}>'))
        self.parts.append(("root", name))
        self.parts.append(("html", f"<figcaption>{cell(caption)}</figcaption></figure>"))


class _Section:
    """``with doc.section(id, title):`` -- an entry of the table of contents and the
    ``<section>`` around what is added inside."""

    def __init__(self, doc: Doc, id_: str, title: str):
        self.doc, self.id, self.title = doc, id_, title

    def __enter__(self) -> Doc:
        self.doc.toc.append((self.id, self.title))
        self.doc.add(Doc._section_open(self.id, self.title))
        return self.doc

    def __exit__(self, *exc: Any) -> None:
        self.doc.add("</section>")


# ---------------------------------------------------------------------------------------------
# the page
# ---------------------------------------------------------------------------------------------
CSS = """
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


def _toc(doc: Doc) -> str:
    return ('<nav class="toc" aria-label="Contents"><h2>Contents</h2><ol>'
            + "".join(f'<li><a href="#{esc(i)}">{esc(t)}</a></li>' for i, t in doc.toc)
            + "</ol></nav>")


def page(doc: Doc, title: str) -> str:
    """The whole HTML file: the table of contents after the header, our CSS and fragments,
    BokehJS and the figures inline."""
    from bokeh.embed import components

    parts = list(doc.parts)
    at = next((i for i, (k, v) in enumerate(parts) if k == "html" and v == "</header>"), 0)
    parts.insert(at + 1, ("html", _toc(doc)))
    script, divs, js, css = "", {}, "", ""
    if doc.roots:           # nothing to draw: no BokehJS either
        script, divs = components({r.name: r for r in doc.roots})
        js, css = _bokeh_resources(doc.roots)
    body = "\n".join(divs[v] if kind == "root" else v for kind, v in parts)
    return ('<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            f'<meta name="generator" content="ccdcore {esc(__version__)}">\n'
            f"<title>{esc(title)}</title>\n{css}<style>{CSS}</style>\n{js}</head>\n"
            f"<body>\n{body}\n{script}\n</body>\n</html>\n")
