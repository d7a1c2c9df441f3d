"""The Walkthrough in headless Chromium: the healey94 demo walked from step 1 to the export,
which writes the product and the report; a step's address opens that step."""
from __future__ import annotations

import re
from pathlib import Path

from playwright.sync_api import Page, expect

from ccdcore.guide import STEPS
from ccdcore.product.make import load_product

TIMEOUT = 60_000


def _panel(page: Page, slug: str):
    return page.locator(f".ccd-wt-{slug}")


def test_walk_healey94_from_the_plan_to_the_export(page: Page, serve_app, open_app, assets,
                                                   tmp_path: Path):
    url = serve_app(assets / "healey94", allowed_roots=[tmp_path])
    page.set_viewport_size({"width": 1400, "height": 1200})
    open_app(url + "/?page=walkthrough")
    expect(page.get_by_text("Step 1 of 8: Plan the captures")).to_be_visible(timeout=TIMEOUT)
    # the plan: a table of what to capture and the session.toml template to download
    expect(page.locator(".ccd-wt-plan-table")).to_contain_text("Photon transfer pairs",
                                                               timeout=TIMEOUT)
    with page.expect_download(timeout=TIMEOUT) as dl:
        page.locator(".ccd-wt-toml-download").get_by_role("button").click()
    assert "[[frames]]" in Path(dl.value.path()).read_text()
    for i, step in enumerate(STEPS, start=1):
        panel = _panel(page, step.slug)
        expect(panel.get_by_text(f"Step {i} of 8: {step.title}")).to_be_visible(timeout=TIMEOUT)
        if i > 1:                                  # the step is part of the address
            expect(page).to_have_url(re.compile(f"step={step.slug}"), timeout=TIMEOUT)
        gate = page.locator(f".ccd-wt-gate-{step.slug}")
        expect(gate).not_to_contain_text("Not run yet", timeout=TIMEOUT)
        if step.slug == "response":
            expect(gate).to_contain_text("Skipped")            # healey94 has no bracket
            expect(gate).to_contain_text("bracket")
        if step.slug == "ptc":
            expect(gate).to_contain_text("Passed")
            expect(panel.locator("canvas").first).to_be_visible(timeout=TIMEOUT)
        if step.slug == "export":
            break
        panel.locator(".ccd-wt-next").get_by_role("button").click()
    expect(page).to_have_url(re.compile(r"step=export"))
    folder = tmp_path / "calib"
    box = page.locator(".ccd-wt-folder input")
    box.fill(str(folder))
    box.press("Enter")
    page.locator(".ccd-wt-save").get_by_role("button").click()
    gate = page.locator(".ccd-wt-gate-export")
    expect(gate).to_contain_text("saved the product", timeout=TIMEOUT)
    report = folder / "report.html"
    assert report.is_file() and "<html" in report.read_text().lower()
    assert set(load_product(folder).maps) >= {"dark", "K"}
    with page.expect_download(timeout=TIMEOUT) as dl:
        page.locator(".ccd-wt-report-download").get_by_role("button").click()
    assert dl.value.suggested_filename == "healey94-report.html"
    assert "<html" in Path(dl.value.path()).read_text().lower()
    # every step checked: the progress says so
    expect(page.locator(".ccd-wt-progress-text")).to_contain_text("8 of 8 steps checked")


def test_a_step_address_opens_that_step(page: Page, serve_app, open_app, assets):
    url = serve_app(assets / "healey94")
    page.set_viewport_size({"width": 1400, "height": 1200})
    open_app(url + "/?page=walkthrough&step=ptc")
    expect(page.get_by_text("Step 4 of 8: Photon transfer")).to_be_visible(timeout=TIMEOUT)
    expect(page.get_by_text("Step 1 of 8: Plan the captures")).to_be_hidden()
    expect(page.locator(".ccd-wt-gate-ptc")).to_contain_text("Passed", timeout=TIMEOUT)


def test_the_report_downloads_from_any_page(page: Page, serve_app, open_app, assets):
    url = serve_app(assets / "delasarte07")
    page.set_viewport_size({"width": 1400, "height": 1000})
    open_app(url + "/?page=flat_field")
    download = page.locator(".ccd-report-download").get_by_role("button")
    expect(page.locator(".ccd-session")).to_contain_text("delasarte07", timeout=TIMEOUT)
    expect(download).to_be_disabled()
    page.locator(".ccd-report-prepare").get_by_role("button").click()
    expect(download).to_be_enabled(timeout=TIMEOUT)
    expect(page.locator(".ccd-report-note")).to_contain_text("opens offline")
    with page.expect_download(timeout=TIMEOUT) as dl:
        download.click()
    assert dl.value.suggested_filename == "delasarte07-report.html"
    html = Path(dl.value.path()).read_text()
    assert "SNUP" in html and "<html" in html.lower()
