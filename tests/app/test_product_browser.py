"""A calibration product round trip through the app in headless Chromium: ccdcore calibrates the
healey94 demo into a folder; on the Session page the product opens, is applied to a frame (the
before and after views draw, ccdcore's SNUP shows, the readout gives both pixel values) and the
corrected frames of a role are saved, equal to what ``ccdcore.product.make.apply_product`` writes."""
from __future__ import annotations

import re

from playwright.sync_api import Page, expect

from ccdcore.common import format_pm
from ccdcore.io.frames import RECORD, read_image
from ccdcore.product.make import apply_product, calibrate, load_product
from ccdcore.session import open_session
from ccdcore.flatfield.uniformity import snup

TIMEOUT = 60_000  # generous: a busy CI machine draws slowly; passing runs do not wait
FRAME = "scene/paper_L02.tif"


def test_product_round_trip_through_the_app(page: Page, serve_app, open_app, healey94,
                                            tmp_path, settled_box):
    folder = calibrate(healey94).save(tmp_path / "product")
    product = load_product(folder)
    session = open_session(healey94)
    rec = next(r for r in session.frames if r.relpath == FRAME)
    after = snup(product.correct(session.read(rec)), layout="mono")["L"]
    shown_after = format_pm(after.snup, after.snup_err)
    scene = session.by_role("scene")

    url = serve_app(healey94, allowed_roots=[tmp_path, healey94.parent])
    page.set_viewport_size({"width": 1400, "height": 1100})
    open_app(url)
    expect(page.get_by_text("Loaded healey94")).to_be_visible(timeout=TIMEOUT)

    # open the product in its tab: the summary lists its estimates and what it skipped
    page.locator(".bk-tab").filter(has_text="Calibration product").click()
    box = page.get_by_placeholder("/path/to/product")
    expect(box).to_be_visible(timeout=TIMEOUT)
    box.fill(str(tmp_path / "missing"))
    box.press("Enter")
    alert = page.locator(".ccd-product-error").get_by_text(re.compile(r"missing.*calibration"))
    expect(alert).to_be_visible(timeout=TIMEOUT)
    box.fill(str(folder))
    page.get_by_role("button", name="Open product").click()
    estimates = page.locator(".ccd-product-estimates")
    expect(estimates.get_by_text("fixed_pattern", exact=True)).to_be_visible(timeout=TIMEOUT)
    noise = product.estimates.noise
    expect(estimates.get_by_text(format_pm(noise.A, noise.A_err), exact=False)) \
        .to_be_visible()
    expect(page.locator(".ccd-product-skipped").get_by_text("flat_field")).to_be_visible()
    expect(alert).to_be_hidden()

    # apply it to another frame: ccdcore's SNUP after correction, both views drawn
    select = page.locator(".ccd-product select").nth(1)
    label = next(t for t in select.locator("option").all_inner_texts() if t.startswith(FRAME))
    select.select_option(label=label)
    table = page.locator(".ccd-product-snup")
    expect(table.get_by_text(shown_after, exact=True)).to_be_visible(timeout=TIMEOUT)
    expect(page.get_by_text(re.compile(r"SNUP of .*paper_L02\.tif"))).to_be_visible()
    for side in ("before", "after"):
        expect(page.locator(f".ccd-product-{side} canvas").first).to_be_visible(timeout=TIMEOUT)

    # the readout gives the pixel before and after
    page.wait_for_timeout(1000)  # let the re-rendered plot settle before moving the mouse
    canvas = settled_box(page.locator(".ccd-product-after canvas").first)
    for dx in (0.3, 0.4, 0.5, 0.6):
        page.mouse.move(canvas["x"] + canvas["width"] * dx, canvas["y"] + canvas["height"] * 0.5)
        page.wait_for_timeout(300)
    expect(page.locator(".ccd-product-readout").get_by_text(
        re.compile(r"x = \d+, y = \d+: before \d+ DN, after [-\d.e+]+ DN"))).to_be_visible(
        timeout=TIMEOUT)

    # save every frame of the role: the files equal apply_product's
    out = tmp_path / "corrected"
    page.get_by_placeholder("/path/to/output").fill(str(out))
    page.get_by_role("button", name="Every frame of the role").click()
    page.get_by_role("button", name="Save corrected frames").click()
    expect(page.locator(".ccd-product-saved").get_by_text(
        re.compile(rf"Wrote {len(scene)} files"))).to_be_visible(timeout=TIMEOUT)
    reference = apply_product(product, [r.path for r in scene], tmp_path / "reference")
    written = sorted(p for p in out.iterdir() if p.name != RECORD)   # and the record of ours
    assert (out / RECORD).is_file()
    assert [p.name for p in written] == sorted(p.name for p in reference)
    for got, want in zip(written, sorted(reference)):
        assert read_image(got).tobytes() == read_image(want).tobytes()
