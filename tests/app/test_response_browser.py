"""The Response & HDR page in headless Chromium: on the tsin01 demo the curves are drawn, the
band is ccdcore's, and choosing another method changes the curve the browser holds; on a colour
bracket each channel's curves reach the browser and the agreement tables are shown."""
from __future__ import annotations

import re

import numpy as np
import pytest
from playwright.sync_api import Page, expect

import ccdcore_app.cache
from ccdcore_app.cache import SharedResults
from ccdcore.response.brackets import load_bracket
from ccdcore.response.methods import response_of
from ccdcore.session import open_session

TIMEOUT = 90_000  # four methods with their bands are computed on first visit


@pytest.fixture(autouse=True)
def _own_store(monkeypatch):
    """The served app shares results through a store of this test's own (the page tests'
    results, computed in this process, are not reused)."""
    monkeypatch.setattr(ccdcore_app.cache, "_SHARED", SharedResults())


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


# ------------------------------------------------------------------ a colour bracket ---------
RGB_TIMEOUT = 60_000  # the four methods on the server (about 10 s on an idle machine)

CURVE_AT = """([method, code]) => {
  for (const doc of Bokeh.documents) {
    const src = doc.get_model_by_name('ccd-response-' + method);
    if (src && src.data.g && src.data.g.length > code) return src.data.g[code];
  }
  return null;
}"""


@pytest.fixture(scope="module")
def rgb_bracket(tmp_path_factory):
    """The colour bracket the test opens: one folder holding ``session.toml`` (a small sec. 4.1
    simulation with one E per channel; a bundled colour demo can take its place here)."""
    from ccdcore.simulate import simulate

    root = tmp_path_factory.mktemp("rgb-bracket") / "tsin01-rgb"
    simulate("tsin01", root, seed=7, size=(64, 48), layout="rgb")
    return root


def test_rgb_bracket_shows_each_channel_and_the_agreement(page: Page, serve_app,
                                                          rgb_bracket):
    session = open_session(rgb_bracket)
    assert session.camera.layout == "rgb"
    debevec = response_of(load_bracket(session), "debevec")
    assert debevec.channels == ("R", "G", "B")
    code = 150
    g = {ch: float(debevec[ch].g[code]) for ch in debevec.channels}
    assert min(abs(g["R"] - g["G"]), abs(g["G"] - g["B"]), abs(g["R"] - g["B"])) > 1e-7

    url = serve_app(rgb_bracket, allowed_roots=[rgb_bracket.parent])
    page.set_viewport_size({"width": 1400, "height": 1200})
    page.goto(url + "/?page=response_hdr")
    page.wait_for_function(f"() => ({CURVE_AT})(['debevec', {code}]) !== null",
                           timeout=RGB_TIMEOUT)
    expect(page.locator(".ccd-response-curves canvas").first).to_be_visible()
    # the first channel is shown; each channel button shows that channel's curves
    shown = page.evaluate(CURVE_AT, ["debevec", code])
    assert shown == pytest.approx(g["R"], abs=1e-12), (shown, g)
    for ch in ("G", "B", "R"):
        page.get_by_role("button", name=ch, exact=True).click()
        page.wait_for_function(
            f"() => Math.abs(({CURVE_AT})(['debevec', {code}]) - {g[ch]!r}) < 1e-12",
            timeout=RGB_TIMEOUT)
    expect(page.locator(".ccd-response-error")).to_be_hidden()

    # the pooled agreement of every method, Debevec & Malik's as ccdcore computes it
    a = debevec.agreement
    row = page.locator(".ccd-response-agreement tr", has_text="Debevec & Malik")
    for value in (a.rms, a.rms_fitted, a.rms_blend):
        expect(row).to_contain_text(f"{value:.2f}")
    for label in ("Tsin, Ramesh & Kanade (sec. 3.2)", "Robertson et al.", "Mitsunaga & Nayar"):
        expect(page.locator(".ccd-response-agreement")).to_contain_text(label)
    # the chosen method's pairs of neighbouring images, per channel
    page.get_by_role("button", name="Debevec & Malik", exact=True).click()
    pairs = page.locator(".ccd-response-pairs")
    expect(pairs).to_contain_text("B: ratio fit/nominal")
    first = a["B"].pairs[0]
    row = pairs.locator("tr", has_text="1\u21922")
    expect(row).to_contain_text(f"{first.rms:.2f}")
    expect(row).to_contain_text(f"{first.ratio_fitted / (debevec.t[1] / debevec.t[0]):.3f}")
