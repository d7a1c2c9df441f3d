"""The Response & HDR page on the tsin01 demo in headless Chromium: the curves are drawn, the
band is ccdcore's, and choosing another method changes the curve the browser holds."""
from __future__ import annotations

import re

import numpy as np
from playwright.sync_api import Page, expect

from ccdcore.response.brackets import load_bracket
from ccdcore.response.methods import response_of
from ccdcore.session import open_session

TIMEOUT = 90_000  # four methods with their bands are computed on first visit

BAND_AT = """(code) => {
  for (const doc of Bokeh.documents) {
    const src = doc.get_model_by_name('ccd-response-band');
    if (src && src.data.hi && src.data.hi.length > code) return src.data.hi[code];
  }
  return null;
}"""


def test_switching_method_changes_the_curve(page: Page, serve_app, assets, settled_box):
    demo = assets / "tsin01"
    brackets = load_bracket(open_session(demo))
    code = 100
    expected = {}
    for name in ("tsin", "debevec"):
        c = response_of(brackets, name)["L"]
        expected[name] = float(c.g[code] + 2 * c.g_err[code])
    assert abs(expected["tsin"] - expected["debevec"]) > 1e-4   # the change is visible

    url = serve_app(demo)
    page.set_viewport_size({"width": 1400, "height": 1200})
    page.goto(url)
    expect(page.get_by_text("Loaded tsin01")).to_be_visible(timeout=TIMEOUT)
    page.get_by_role("button", name=re.compile("Response & HDR")).click()
    expect(page.locator(".ccd-response-curves canvas").first).to_be_visible(timeout=TIMEOUT)
    page.wait_for_function(f"() => ({BAND_AT})({code}) !== null", timeout=TIMEOUT)
    shown = page.evaluate(BAND_AT, code)
    assert np.isclose(shown, expected["tsin"], rtol=0, atol=1e-9), (shown, expected)
    expect(page.get_by_text(re.compile(r"Tsin, Ramesh & Kanade \(sec\. 3\.2\): \d+ "
                                       r"iteration"))).to_be_visible(timeout=TIMEOUT)

    page.get_by_role("button", name="Debevec & Malik", exact=True).click()
    page.wait_for_function(
        f"() => Math.abs(({BAND_AT})({code}) - {expected['debevec']}) < 1e-9", timeout=TIMEOUT)
    expect(page.get_by_text(re.compile(r"Debevec & Malik: 1 iteration"))).to_be_visible(
        timeout=TIMEOUT)
    # the HDR views are drawn and read out radiance ± sigma under the cursor
    expect(page.locator(".ccd-hdr-radiance canvas").first).to_be_visible(timeout=TIMEOUT)
    expect(page.locator(".ccd-hdr-sigma canvas").first).to_be_visible(timeout=TIMEOUT)
    page.wait_for_timeout(1500)  # let the re-rendered plot settle before moving the mouse
    box = settled_box(page.locator(".ccd-hdr-radiance canvas").first)
    for dx in (0.3, 0.4, 0.5, 0.6):
        page.mouse.move(box["x"] + box["width"] * dx, box["y"] + box["height"] * 0.5)
        page.wait_for_timeout(300)
    expect(page.locator(".ccd-hdr-readout")).to_contain_text("E = ", timeout=TIMEOUT)
    expect(page.locator(".ccd-hdr-readout")).to_contain_text("±")
