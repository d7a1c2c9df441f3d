"""The page registry: every page of the app, in navigation order.

A page is a module ``ccdcore_app.pages.<slug>`` defining ``create_page(state: AppState) -> Viewable``.
Pages listed here whose module does not exist yet are shown as *coming*: a badge in the navigation
and a placeholder page saying what is planned. Adding a page means writing its module; the entry
below is already there.

Public objects
--------------
PageSpec
    One navigation entry: slug, title, icon and what the page will offer.
PAGES
    The registry, in navigation order.
is_available(spec), build_page(spec, state), get_page(slug)
    Whether a page module exists, the page (or its *coming* placeholder), lookup by slug.
"""
from __future__ import annotations

import importlib
import importlib.util
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from panel.viewable import Viewable

    from ..state import AppState

__all__ = ["PageSpec", "PAGES", "is_available", "build_page", "get_page"]


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
    planned
        What the page will offer (shown while the page is *coming*): the feature, its paper and
        the ccdcore module it will call.
    """

    slug: str
    title: str
    icon: str
    planned: str

    @property
    def module(self) -> str:
        return f"{__name__}.{self.slug}"


PAGES: tuple[PageSpec, ...] = (
    PageSpec("session", "Session", "\u25a4",
             "Open a capture session, check its manifest and preview its frames."),
    PageSpec("photon_transfer", "Photon transfer", "\u223f",
             "Photon transfer from image pairs (Healey & Kondepudy 1994, eqs. 37\u201342 and the "
             "appendix fit, eqs. 59\u201367): mean\u2013variance points per light level with error "
             "bars, the weighted fit of A (DN per electron) and \u03c3\u00b2_C (eq. 27) with their "
             "covariance, \u03c7\u00b2 and Q, conversion gain and read noise in electrons. "
             "Calls ccdcore's photon-transfer estimator (the `ccdcore ptc` verb)."),
    PageSpec("maps", "Maps", "\u25a6",
             "Dark reference image (Healey & Kondepudy 1994, sec. V-A) and fixed-pattern map "
             "K\u0302 with local-window means and robust slope rejection (eqs. 45\u201350), each "
             "inspectable pixel by pixel with its uncertainty; acquisition planning n1, n2 "
             "(sec. V-B) and the scene variation V_S budget (eqs. 53\u201358)."),
    PageSpec("flat_field", "Flat field", "\u25a1",
             "Flat-field correction of de Lasarte et al. 2007: gain/offset maps G, O from a base "
             "image and a dark image, per RGB channel, and the spatial nonuniformity SNUP = "
             "100\u00b7\u03c3/mean before and after correction (the `ccdcore snup` verb)."),
    PageSpec("response_hdr", "Response & HDR", "\u2197",
             "Inverse camera response g per channel with white balance a_k, b_k (Tsin, Ramesh & "
             "Kanade 2001, sec. 3.2; also Debevec, Robertson, Mitsunaga) and HDR radiance with a "
             "per-pixel sigma map (eqs. 18\u201319): the `ccdcore response` and `ccdcore hdr` "
             "verbs."),
    PageSpec("change", "Change detection", "\u25d1",
             "Illumination-invariant change detection (Tsin et al. 2001, sec. 5): 3\u00d73 colour "
             "transform, LTS + M-estimator clustering, chi-square test at a chosen false-alarm "
             "rate; change and shadow masks over the reference/target brackets (the "
             "`ccdcore change` verb)."),
    PageSpec("walkthrough", "Walkthrough", "\u2691",
             "A guided calibration in eight steps, each with its own address: plan the "
             "captures (a checklist and a session.toml template), validate the session, dark "
             "reference, photon transfer, fixed pattern and flat field, response, verify on "
             "held-out frames, export the product and the report; each step ends in a gate "
             "(ccdcore.guide) saying what passed, why, and what to capture next."),
)


def is_available(spec: PageSpec) -> bool:
    """True when the page's module exists (otherwise the page is *coming*)."""
    return importlib.util.find_spec(spec.module) is not None


def get_page(slug: str) -> PageSpec:
    """The registry entry with this slug (``KeyError`` naming the known slugs otherwise)."""
    for spec in PAGES:
        if spec.slug == slug:
            return spec
    raise KeyError(f"unknown page {slug!r}; known: {', '.join(p.slug for p in PAGES)}")


def build_page(spec: PageSpec, state: AppState) -> Viewable:
    """The page for ``spec``: its module's ``create_page(state)``, or the *coming* placeholder."""
    if is_available(spec):
        return importlib.import_module(spec.module).create_page(state)
    from .coming import coming_page

    return coming_page(spec)
