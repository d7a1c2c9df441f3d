"""Placeholder for pages listed in the registry whose module is not written yet.

Public objects
--------------
coming_page(spec)
    A page that says the feature is coming and what it will offer: no plots, no fake content.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import panel as pn

if TYPE_CHECKING:
    from . import PageSpec

__all__ = ["coming_page"]


def coming_page(spec: PageSpec) -> pn.Column:
    """The *coming* placeholder for ``spec``."""
    return pn.Column(
        pn.pane.Markdown(f"## {spec.title} <span class='ccd-badge'>coming</span>",
                         css_classes=["ccd-page-title"]),
        pn.pane.Alert(f"**Not built yet.** This page is planned: {spec.planned}",
                      alert_type="info", sizing_mode="stretch_width"),
        pn.pane.Markdown("Meanwhile, open and check your capture session on the **Session** "
                         "page: the frames this page will need are listed there by role."),
        name=spec.title, sizing_mode="stretch_width", css_classes=["ccd-coming"],
    )
