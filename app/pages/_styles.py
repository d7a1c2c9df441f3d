"""Stylesheets the pages give their table panes (each pane renders in its own shadow root, so
a page's rules reach a table only through the pane's ``stylesheets``).

TABLE_CSS
    A results table: left-aligned columns, a rule under the header, striped rows.
KEY_VALUE_CSS
    A two-column Markdown table of names and values with an empty header row (hidden).
heading(title, intro=None)
    A page's title and its muted introduction, the first panes of every page.
progress_row(css_class)
    A page's progress: a bar and its message in a row, hidden until work starts.
"""
from __future__ import annotations

from typing import Any

#: the colour of a page's introduction and notes
MUTED = "#495057"


def heading(title: str, intro: str | None = None) -> list[Any]:
    """A page's title (``## title``) and, when given, its introduction, as Markdown panes."""
    import panel as pn

    panes = [pn.pane.Markdown(f"## {title}", css_classes=["ccd-page-title"])]
    if intro:
        panes.append(pn.pane.Markdown(intro, sizing_mode="stretch_width",
                                      styles={"color": MUTED}))
    return panes

def progress_row(css_class: str) -> tuple[Any, Any, Any]:
    """A page's progress while it computes: ``(bar, text, row)``, the bar indeterminate until a
    fraction arrives, the text muted (``css_class`` for tests), the row hidden until shown."""
    import panel as pn

    bar = pn.indicators.Progress(value=-1, max=100, width=220, height=16, bar_color="info",
                                 margin=(12, 10, 0, 10), sizing_mode="fixed", active=True)
    text = pn.pane.Markdown("", sizing_mode="stretch_width",
                            styles={"font-size": "0.88em", "color": "#6c757d"},
                            css_classes=[css_class])
    return bar, text, pn.Row(bar, text, visible=False, sizing_mode="stretch_width")


TABLE_CSS = """
table { width: 100%; border-collapse: collapse; font-size: 0.95em; }
th { text-align: left !important; color: #495057; border-bottom: 2px solid #dee2e6;
     padding: 4px 8px; white-space: nowrap; }
td { text-align: left !important; padding: 4px 8px; border-bottom: 1px solid #eef0f2; }
tr:nth-child(even) td { background: #f8f9fa; }
"""

KEY_VALUE_CSS = """
table { width: 100%; border-collapse: collapse; border: none; }
thead { display: none; }
td { border: none; border-bottom: 1px solid #eef0f2; padding: 4px 6px; vertical-align: top; }
td:first-child { color: #495057; white-space: nowrap; }
code { color: #a6306a; }
"""
