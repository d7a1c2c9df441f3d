"""The Response & HDR page in headless Chromium: on the tsin01 demo the default curve is drawn
with ccdcore's band and the library's verdict, word for word, and only the default reaches the
browser; choosing another method computes it and changes the curve the browser holds; on a
colour bracket "Compare all methods" adds every method's curves and agreement, and each
channel's curves reach the browser; on a bracket with wrong listed exposures the page says which
exposures it used and which frames look off, and the exposures choice recomputes."""
from __future__ import annotations

import re

import numpy as np
import pytest
from playwright.sync_api import Page, expect

import ccdcore_app.cache.store
from ccdcore_app.cache.store import SharedResults
from ccdcore.response.bracket_fit import finish_fit, prepare_bracket
from ccdcore.response.methods import METHODS, response_of
from ccdcore.session import open_session

TIMEOUT = 90_000  # the default result, then one more method, on a busy machine


@pytest.fixture(autouse=True)
def _own_store(monkeypatch):
    """The served app shares results through a store of this test's own (the page tests'
    results, computed in this process, are not reused)."""
    monkeypatch.setattr(ccdcore_app.cache.store, "_SHARED", SharedResults())


BAND_AT = """(code) => {
  for (const doc of Bokeh.documents) {
    const src = doc.get_model_by_name('ccd-response-band');
    if (src && src.data.hi && src.data.hi.length > code) return src.data.hi[code];
  }
  return null;
}"""

CURVE_AT = """([method, code]) => {
  for (const doc of Bokeh.documents) {
    const src = doc.get_model_by_name('ccd-response-' + method);
    if (src && src.data.g && src.data.g.length > code) return src.data.g[code];
  }
  return null;
}"""

VERDICT = ".ccd-response-verdict"


def _verdict_shown(page: Page, verdict) -> None:
    """The verdict alert holds the verdict's line exactly, styled by its status; its
    registration and moving pixels are listed below the curves."""
    alert = page.locator(VERDICT)
    expect(alert).to_have_text(verdict.line(), timeout=TIMEOUT)
    assert alert.locator("p").all_inner_texts() == [verdict.line()]  # (in a shadow root)
    details = page.locator(".ccd-response-verdict-details li").all_inner_texts()
    assert details == list(verdict.details())
    kind = {"trusted": "success", "doubtful": "warning", "failed": "danger"}[verdict.status]
    expect(alert).to_have_class(re.compile(rf"\balert-{kind}\b"))


def test_default_then_a_chosen_method(page: Page, serve_app, assets, settled_box):
    demo = assets / "tsin01"
    # what the page computes: the bracket registered, its suspects left out, the moving
    # pixels found (ccdcore.response.bracket_fit)
    prepared = prepare_bracket(open_session(demo))
    code = 100
    default = finish_fit(response_of(prepared.brackets), prepared).result
    debevec = finish_fit(response_of(prepared.brackets, "debevec"), prepared).result
    expected = {name: float(r["L"].g[code] + 2 * r["L"].g_err[code])
                for name, r in (("auto", default), ("debevec", debevec))}
    assert abs(expected["auto"] - expected["debevec"]) > 1e-4   # the change is visible

    url = serve_app(demo)
    page.set_viewport_size({"width": 1400, "height": 1200})
    page.goto(url)
    expect(page.get_by_text("Loaded tsin01")).to_be_visible(timeout=TIMEOUT)
    page.get_by_role("button", name=re.compile("Response & HDR")).click()
    page.wait_for_function(f"() => ({BAND_AT})({code}) !== null", timeout=TIMEOUT)
    shown = page.evaluate(BAND_AT, code)
    assert np.isclose(shown, expected["auto"], rtol=0, atol=1e-9), (shown, expected)
    _verdict_shown(page, default.verdict)
    expect(page.locator(".ccd-response-exposures")).to_contain_text(default.selection)
    label = METHODS[default.method].label
    expect(page.get_by_text(re.compile(rf"auto \(default\): {re.escape(label)}: \d+ "
                                       r"iteration"))).to_be_visible(timeout=TIMEOUT)
    # only the default was computed: no other method's curve reached the browser
    for m in METHODS:
        assert page.evaluate(CURVE_AT, [m, code]) is None, m

    page.get_by_role("button", name="Debevec & Malik", exact=True).click()
    page.wait_for_function(
        f"() => Math.abs(({BAND_AT})({code}) - {expected['debevec']}) < 1e-9", timeout=TIMEOUT)
    _verdict_shown(page, debevec.verdict)
    expect(page.get_by_text(re.compile(r"Debevec & Malik: 1 iteration"))).to_be_visible(
        timeout=TIMEOUT)
    # the default's curve stays overlaid
    assert page.evaluate(CURVE_AT, ["auto", code]) == pytest.approx(
        float(default["L"].g[code]), abs=1e-12)
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
@pytest.fixture(scope="module")
def rgb_bracket(tmp_path_factory):
    """The colour bracket the test opens: one folder holding ``session.toml`` (a small sec. 4.1
    simulation with one E per channel; a bundled colour demo can take its place here)."""
    from ccdcore.simulate import simulate

    root = tmp_path_factory.mktemp("rgb-bracket") / "tsin01-rgb"
    simulate("tsin01", root, seed=7, size=(64, 48), layout="rgb")
    return root


def test_rgb_bracket_compares_all_methods_per_channel(page: Page, serve_app, rgb_bracket):
    session = open_session(rgb_bracket)
    assert session.camera.layout == "rgb"
    prepared = prepare_bracket(session)
    debevec = finish_fit(response_of(prepared.brackets, "debevec"), prepared).result
    assert debevec.channels == ("R", "G", "B")
    code = 150
    g = {ch: float(debevec[ch].g[code]) for ch in debevec.channels}
    assert min(abs(g["R"] - g["G"]), abs(g["G"] - g["B"]), abs(g["R"] - g["B"])) > 1e-7

    url = serve_app(rgb_bracket, allowed_roots=[rgb_bracket.parent])
    page.set_viewport_size({"width": 1400, "height": 1200})
    page.goto(url + "/?page=response_hdr")
    page.wait_for_function(f"() => ({CURVE_AT})(['auto', {code}]) !== null",
                           timeout=TIMEOUT)
    expect(page.locator(VERDICT)).to_be_visible(timeout=TIMEOUT)
    assert page.evaluate(CURVE_AT, ["debevec", code]) is None
    page.get_by_role("button", name="Compare all methods").click()
    for m in METHODS:
        page.wait_for_function(f"() => ({CURVE_AT})(['{m}', {code}]) !== null",
                               timeout=TIMEOUT)
    expect(page.locator(".ccd-response-curves canvas").first).to_be_visible()
    # the first channel is shown; each channel button shows that channel's curves
    shown = page.evaluate(CURVE_AT, ["debevec", code])
    assert shown == pytest.approx(g["R"], abs=1e-12), (shown, g)
    for ch in ("G", "B", "R"):
        page.get_by_role("button", name=ch, exact=True).click()
        page.wait_for_function(
            f"() => Math.abs(({CURVE_AT})(['debevec', {code}]) - {g[ch]!r}) < 1e-12",
            timeout=TIMEOUT)
    expect(page.locator(".ccd-response-error")).to_be_hidden()

    # the pooled agreement of every method, Debevec & Malik's as ccdcore computes it
    a = debevec.agreement
    row = page.locator(".ccd-response-agreement tr").filter(
        has=page.get_by_role("cell", name="Debevec & Malik", exact=True))
    for value in (a.rms, a.rms_fitted, a.rms_blend):
        expect(row).to_contain_text(f"{value:.2f}")
    for label in ("auto (default)", "Tsin, Ramesh & Kanade (sec. 3.2)", "Robertson et al.",
                  "Mitsunaga & Nayar"):
        expect(page.locator(".ccd-response-agreement")).to_contain_text(label)
    # the chosen method's pairs of neighbouring images, per channel, and its verdict
    page.get_by_role("button", name="Debevec & Malik", exact=True).click()
    _verdict_shown(page, debevec.verdict)
    pairs = page.locator(".ccd-response-pairs")
    expect(pairs).to_contain_text("B: ratio fit/nominal")
    first = a["B"].pairs[0]
    row = pairs.locator("tr", has_text="1\u21922")
    expect(row).to_contain_text(f"{first.rms:.2f}")
    expect(row).to_contain_text(f"{first.ratio_fitted / (debevec.t[1] / debevec.t[0]):.3f}")


# ------------------------------------------------------------------ wrong listed exposures ---
@pytest.fixture(scope="module")
def wrong_bracket(tmp_path_factory):
    """A camera-like bracket whose listed exposures are wrong for a run of pairs."""
    from ccdcore.simulate import simulate

    root = tmp_path_factory.mktemp("wrong-bracket") / "listed-wrong"
    simulate("tsin01", root, seed=1, camera="real-listed-wrong", size=(96, 64))
    return root


def test_wrong_listed_exposures_and_the_exposures_choice(page: Page, serve_app,
                                                         wrong_bracket):
    prepared = prepare_bracket(open_session(wrong_bracket))
    default = finish_fit(response_of(prepared.brackets), prepared).result
    listed = finish_fit(response_of(prepared.brackets, exposures="listed"), prepared).result
    assert default.exposures.used == "estimated"
    summary = default.exposures.summary()
    runs = summary.off_runs()
    assert runs and "_" in runs[0]        # frame names with underscores, shown as they are

    url = serve_app(wrong_bracket, allowed_roots=[wrong_bracket.parent])
    page.set_viewport_size({"width": 1400, "height": 1200})
    page.goto(url + "/?page=response_hdr")
    _verdict_shown(page, default.verdict)
    note = page.locator(".ccd-response-exposures")
    expect(note).to_contain_text(summary.line())
    for run in runs:
        expect(note).to_contain_text(run)

    page.locator(".ccd-response-exposure-mode").get_by_role(
        "button", name="listed", exact=True).click()
    _verdict_shown(page, listed.verdict)
    expect(note).to_contain_text("exposures: listed")
    expect(note).not_to_contain_text(runs[0])
    expect(page.locator(".ccd-response-error")).to_be_hidden()
