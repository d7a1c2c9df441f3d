"""Pages at a real session's size: a measured EMVA 1288 set has a hundred light levels, and the
Photon transfer page's figure stays in the first view at 1400 x 900 (the levels' list scrolls
in a box of its own; it pushed the figure some 3800 px down)."""
from __future__ import annotations

import re

import pytest
from playwright.sync_api import Page, expect

from ccdcore.simulate import simulate

TIMEOUT = 90_000


@pytest.fixture(scope="module")
def hundred_levels(tmp_path_factory):
    root = tmp_path_factory.mktemp("emva100") / "s"
    simulate("emva1288", root, seed=3, size=(32, 24), steps=100, L=3)
    return root


def test_the_figure_is_in_the_first_view_with_a_hundred_levels(page: Page, serve_app,
                                                               hundred_levels):
    url = serve_app(hundred_levels / "EMVA1288descriptor.txt")
    page.set_viewport_size({"width": 1400, "height": 900})
    page.goto(url)
    expect(page.get_by_text(re.compile(r"Loaded "))).to_be_visible(timeout=TIMEOUT)
    page.get_by_role("button", name=re.compile("Photon transfer")).click()
    plot = page.locator(".ccd-ptc-plot canvas").first
    expect(plot).to_be_visible(timeout=TIMEOUT)
    expect(page.get_by_role("checkbox", name=re.compile(r"^Level 100 "))).to_be_attached(
        timeout=TIMEOUT)
    page.evaluate("window.scrollTo(0, 0)")
    box = plot.bounding_box()
    assert box is not None and box["y"] + 0.5 * box["height"] < 900, box
    levels = page.locator(".ccd-ptc-levels").first.bounding_box()
    assert levels is not None and levels["height"] <= 300, levels
