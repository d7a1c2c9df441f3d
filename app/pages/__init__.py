"""The page registry: every page of the app, in navigation order.

A page is a module ``ccdcore_app.pages.<slug>`` defining ``create_page(state: AppState) ->
Viewable``; adding a page means writing its module and its entry below.

Public objects
--------------
PageSpec
    One navigation entry: slug, title and icon.
PAGES
    The registry, in navigation order.
build_page(spec, state), get_page(slug)
    The page, lookup by slug.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..markup import forbid_raw_html

if TYPE_CHECKING:
    from panel.viewable import Viewable

    from ..state import AppState

__all__ = ["PageSpec", "PAGES", "build_page", "get_page"]

# no markup from a file runs in any page (ccdcore_app.markup): before any page makes a pane
forbid_raw_html()


@dataclass(frozen=True)
class PageSpec:
    """One navigation entry.

    Attributes
    ----------
    slug
        Module name under ``ccdcore_app.pages`` (and the page id).
    title
        Navigation label and page heading.
    icon
        A short unicode symbol shown before the title.
    """

    slug: str
    title: str
    icon: str

    @property
    def module(self) -> str:
        return f"{__name__}.{self.slug}"


PAGES: tuple[PageSpec, ...] = (
    PageSpec("session", "Session", "\u25a4"),
    PageSpec("photon_transfer", "Photon transfer", "\u223f"),
    PageSpec("maps", "Maps", "\u25a6"),
    PageSpec("flat_field", "Flat field", "\u25a1"),
    PageSpec("response_hdr", "Response & HDR", "\u2197"),
    PageSpec("change", "Change detection", "\u25d1"),
    PageSpec("walkthrough", "Walkthrough", "\u2691"),
)


def get_page(slug: str) -> PageSpec:
    """The registry entry with this slug (``KeyError`` naming the known slugs otherwise)."""
    for spec in PAGES:
        if spec.slug == slug:
            return spec
    raise KeyError(f"unknown page {slug!r}; known: {', '.join(p.slug for p in PAGES)}")


def build_page(spec: PageSpec, state: AppState) -> Viewable:
    """The page for ``spec``: its module's ``create_page(state)``."""
    return importlib.import_module(spec.module).create_page(state)
