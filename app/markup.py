"""No markup from a file runs in the page: Markdown is rendered without raw HTML.

Every string the app shows may come from a file the user opened -- a manifest's camera name or
a frame's role, a product's notes and warnings, EXIF make and model, file names -- and a
session folder can come from anyone. Panel renders Markdown with markdown-it's ``gfm-like``
preset, which passes raw HTML through: ``<img src=x onerror=...>`` as a camera name ran as
script in the page (and a script in the page can drive every widget). Escaping each string
where it is shown leaves every future string to be remembered; instead, every Markdown pane
(and ``Alert``, a Markdown pane) of the app renders with markdown-it's ``html`` option off, so
markup anywhere in a Markdown text is shown as text. markdown-it also refuses ``javascript:``
and ``data:`` links by itself. The app's own HTML goes through ``pn.pane.HTML`` panes, whose
file-derived parts are escaped with :func:`html.escape` where they are built.

Public objects
--------------
forbid_raw_html()
    Make Panel's Markdown panes render raw HTML as text (idempotent; done on import of
    :mod:`ccdcore_app.pages`).
SAFE_RENDERER_OPTIONS
    The markdown-it options used.
"""
from __future__ import annotations

import panel as pn

__all__ = ["forbid_raw_html", "SAFE_RENDERER_OPTIONS"]

#: markdown-it options of every Markdown pane: raw HTML off (shown as text)
SAFE_RENDERER_OPTIONS = {"html": False}


def forbid_raw_html() -> None:
    """Every Markdown (and Alert) pane made from now on renders raw HTML as text."""
    pn.pane.Markdown.param.renderer_options.default = dict(SAFE_RENDERER_OPTIONS)
