"""Every page's main figure is in the first view at 1400 x 900 (issue: pages at a real session's
size): the page title, its alerts and its controls leave the figure on screen without
scrolling, on each page's demo."""
from __future__ import annotations

import re

import pytest
from playwright.sync_api import Page, expect

TIMEOUT = 90_000

#: page button, demo, what the page says once computed, the main figure's selector
PAGES = [
    ("Maps", "healey94", "K̂ spatial std", ".ccd-maps canvas"),
    ("Flat field", "delasarte07", "Recommended base image", ".ccd-flat-before canvas"),
    ("Response & HDR", "tsin01", None, ".ccd-response-curves canvas"),
    ("Change detection", "change", None, ".ccd-change-labels canvas"),
]


@pytest.mark.parametrize("button, demo, computed, figure", PAGES,
                         ids=[p[0].split()[0].lower() for p in PAGES])
def test_the_main_figure_is_in_the_first_view(page: Page, serve_app, assets, button, demo,
                                              computed, figure):
    url = serve_app(assets / demo)
    page.set_viewport_size({"width": 1400, "height": 900})
    page.goto(url)
    expect(page.get_by_text(f"Loaded {demo}")).to_be_visible(timeout=TIMEOUT)
    page.get_by_role("button", name=re.compile(re.escape(button))).click()
    if computed is not None:
        expect(page.get_by_text(computed).first).to_be_visible(timeout=TIMEOUT)
    plot = page.locator(figure).first
    expect(plot).to_be_visible(timeout=TIMEOUT)
    page.evaluate("window.scrollTo(0, 0)")
    page.wait_for_timeout(300)
    box = plot.bounding_box()
    # at least the figure's top half on screen, without scrolling
    assert box is not None and box["y"] >= 0 and box["y"] + 0.5 * box["height"] <= 900, box


def test_a_square_ccds_dark_map_is_in_the_first_view(page: Page, serve_app, tmp_path):
    """A cooled CCD's biases, darks and flats on a square sensor (as a 1024 x 1024 real one):
    what the session cannot give folds into one line, and the dark map's upper half is on
    screen without scrolling (it started 3 px too low on the real set)."""
    from ccdcore.simulate.ccdlab import simulate

    root = tmp_path / "lab"
    simulate(root, seed=1, size=(256, 256))
    url = serve_app(root, allowed_roots=[tmp_path.resolve()])
    page.set_viewport_size({"width": 1400, "height": 900})
    page.goto(url)
    expect(page.get_by_text("Loaded lab")).to_be_visible(timeout=TIMEOUT)
    page.get_by_role("button", name=re.compile("Maps")).click()
    plot = page.locator(".ccd-maps canvas").first
    expect(plot).to_be_visible(timeout=TIMEOUT)
    expect(page.locator(".ccd-maps-info-card").first).to_be_visible(timeout=TIMEOUT)
    page.evaluate("window.scrollTo(0, 0)")
    page.wait_for_timeout(300)
    box = plot.bounding_box()
    assert box is not None and box["y"] >= 0 and box["y"] + 0.5 * box["height"] <= 900, box
