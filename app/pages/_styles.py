"""Stylesheets the pages give their table panes (each pane renders in its own shadow root, so
a page's rules reach a table only through the pane's ``stylesheets``).

TABLE_CSS
    A results table: left-aligned columns, a rule under the header, striped rows.
KEY_VALUE_CSS
    A two-column Markdown table of names and values with an empty header row (hidden).
"""
from __future__ import annotations

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
