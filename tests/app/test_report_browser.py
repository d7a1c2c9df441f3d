"""The HTML calibration report in headless Chromium, opened from disk with every request that is
not a file blocked and recorded: nothing is requested, Bokeh draws every plot section (pixels on
its canvases, not just elements), and the console shows no error; the change labels are drawn
in the app's colours and the response band is g ± 2σ of the product."""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from playwright.sync_api import Page, expect

from ccdcore_report import write_report

DEMOS = ("healey94", "delasarte07", "tsin01", "change")


@pytest.fixture(scope="module")
def reports(tmp_path_factory, assets: Path) -> dict[str, Path]:
    """One report per demo, built once (each demo session is calibrated first)."""
    tmp = tmp_path_factory.mktemp("reports")
    return {name: write_report(assets / name, tmp / f"{name}.html") for name in DEMOS}


def _colours(png: bytes) -> int:
    from PIL import Image

    return len(np.unique(np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).reshape(-1, 3),
                         axis=0))


@pytest.mark.parametrize("demo", DEMOS)
def test_the_report_draws_offline_without_errors(page: Page, reports, demo):
    outside, errors = [], []

    def route(r) -> None:
        if r.request.url.startswith("file:"):
            r.continue_()
        else:
            outside.append(r.request.url)
            r.abort()

    page.route("**/*", route)
    page.on("request", lambda r: None if r.url.startswith(("file:", "data:", "blob:"))
            else outside.append(r.url))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.set_viewport_size({"width": 1280, "height": 900})
    page.goto(reports[demo].as_uri())
    page.wait_for_function("() => window.Bokeh !== undefined && Bokeh.documents.length > 0",
                           timeout=30_000)

    figures = page.locator("figure.ccd-report-plot")
    ids = [figures.nth(i).get_attribute("id") for i in range(figures.count())]
    assert ids and len(set(ids)) == len(ids), ids
    # one Bokeh root per plot section, each drawn on a canvas
    assert page.evaluate("Bokeh.documents[0].roots().length") == len(ids)
    for id_ in ids:
        expect(page.locator(f"[id='{id_}'] canvas").first).to_be_visible(timeout=30_000)
    # the canvases hold a picture, not a blank frame: the first plot and the first map
    maps = [i for i in ids if i.startswith(("map-", "change-"))]
    for id_ in {ids[0], *maps[:1]}:
        shot = page.locator(f"[id='{id_}']").screenshot()
        assert _colours(shot) > 20, (demo, id_)
    # the table of contents leads to its sections
    for href in page.locator("nav.toc a").evaluate_all("links => links.map(a => a.hash)"):
        assert page.locator(href).count() == 1, href

    assert outside == [], f"the report asked the network for {outside}"
    assert errors == [], errors


def _open(page: Page, path: Path) -> None:
    page.set_viewport_size({"width": 1280, "height": 900})
    page.goto(path.as_uri())
    page.wait_for_function("() => window.Bokeh !== undefined && Bokeh.documents.length > 0",
                           timeout=30_000)


def test_change_labels_are_drawn_in_the_apps_colours(page: Page, reports, assets):
    from PIL import Image

    from ccdcore_app.plots.change import label_colour
    from ccdcore.change.session import session_change
    from ccdcore.session import open_session

    result, _ = session_change(open_session(assets / "change"))
    counts = result.counts()
    _open(page, reports["change"])
    canvas = page.locator("[id='change-labels'] canvas").first
    expect(canvas).to_be_visible(timeout=30_000)
    rgb = np.asarray(Image.open(io.BytesIO(canvas.screenshot())).convert("RGB")).reshape(-1, 3)
    drawn = {lab: int(np.all(rgb == [int(label_colour(lab)[i:i + 2], 16) for i in (1, 3, 5)],
                             axis=1).sum()) for lab in counts}
    total, pixels = sum(drawn.values()), sum(counts.values())
    assert total > 10 * pixels / 4, drawn                  # the map fills its frame
    for lab, n in counts.items():    # each label's share of the frame is its share of pixels
        assert abs(drawn[lab] / total - n / pixels) < 0.02, (lab, drawn, counts)


def test_the_response_band_is_two_sigma_of_the_products_curve(page: Page, reports, assets):
    from ccdcore.product.make import calibrate

    r = calibrate(assets / "tsin01").estimates.response
    _open(page, reports["tsin01"])
    for i, ch in enumerate(r.channels):
        data = page.evaluate("""name => {
            for (const m of Bokeh.documents[0].all_models)
                if (m.name === name) return Object.fromEntries(
                    ["g", "err", "lo", "hi"].map(k => [k, Array.from(m.data[k])]));
            return null; }""", f"ccd-response-{ch}")
        assert data is not None, ch
        g, err = np.asarray(r.g[i], float), np.asarray(r.g_err[i], float)
        np.testing.assert_allclose(data["g"], g, rtol=0, atol=1e-15)
        np.testing.assert_allclose(data["err"], err, rtol=0, atol=1e-15)
        np.testing.assert_allclose(data["hi"], g + 2 * err, rtol=0, atol=1e-12)
        np.testing.assert_allclose(data["lo"], g - 2 * err, rtol=0, atol=1e-12)
