"""The Photon transfer page of the demo in headless Chromium: the fit is shown, and unticking a
light level refits at once and changes the displayed A."""
from __future__ import annotations

import re

from playwright.sync_api import Page, expect

from ccdcore.common import format_pm
from ccdcore.noise import photon_transfer

TIMEOUT = 60_000  # generous: a busy CI machine draws slowly; passing runs do not wait


def test_photon_transfer_page_shows_the_fit_and_a_level_toggle_changes_A(page: Page, serve_app,
                                                                          healey94):
    # what the page must display: ccdcore's A with and without level 8, as the page formats it
    full = photon_transfer(healey94)
    without_8 = photon_transfer(healey94, exclude_levels=[8])
    a_full = format_pm(full.A, full.A_err)
    a_without_8 = format_pm(without_8.A, without_8.A_err)
    assert a_full != a_without_8  # otherwise the test could not see the change

    url = serve_app(healey94)
    page.set_viewport_size({"width": 1400, "height": 1400})
    page.goto(url)
    expect(page.get_by_text("Loaded healey94")).to_be_visible(timeout=TIMEOUT)
    page.get_by_role("button", name=re.compile("Photon transfer")).click()

    # the parameter table with A, the verdict and the photon-transfer curve
    expect(page.get_by_text("Gain (slope, eq. 41)")).to_be_visible(timeout=TIMEOUT)
    expect(page.get_by_text(a_full, exact=True)).to_be_visible(timeout=TIMEOUT)
    expect(page.get_by_text("Passed", exact=True).first).to_be_visible()
    expect(page.get_by_text("8 of 8", exact=True)).to_be_visible()
    expect(page.locator(".ccd-ptc-plot canvas").first).to_be_visible(timeout=TIMEOUT)

    # untick level 8: the fit follows at once
    level_8 = page.get_by_role("checkbox", name=re.compile(r"^Level 8 "))
    expect(level_8).to_be_checked()
    level_8.uncheck()
    expect(page.get_by_text(a_without_8, exact=True)).to_be_visible(timeout=TIMEOUT)
    expect(page.get_by_text(a_full, exact=True)).to_be_hidden()
    expect(page.get_by_text("7 of 8", exact=True)).to_be_visible()
    expect(page.get_by_text("excluded by user", exact=True)).to_be_visible()
