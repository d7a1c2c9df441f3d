"""The Flat field page of the delasarte07 demo in headless Chromium: the after-correction SNUP of
ccdcore is shown, and choosing another base image changes the SNUP shown."""
from __future__ import annotations

import re

from playwright.sync_api import Page, expect

from ccdcore_app.plots.flat import group_label
from ccdcore_app.pages.flat_field import default_frame
from ccdcore.common import format_pm
from ccdcore.flatfield.fit import flat_field_from_session, recommend_base
from ccdcore.session import open_session
from ccdcore.flatfield.uniformity import snup

TIMEOUT = 60_000  # generous: a busy CI machine draws slowly; passing runs do not wait
OTHER_BASE = (2, 0.04)


def test_choosing_a_base_image_updates_the_after_correction_snup(page: Page, serve_app,
                                                                 assets):
    demo = assets / "delasarte07"
    # what the page must display: ccdcore's after-correction SNUP (channel G) of the first frame
    # shown, with the recommended base and with another base
    session = open_session(demo)
    rec = recommend_base(session, setting="NZDI")
    groups = session.flat_groups(setting="NZDI")
    relpath = default_frame(rec, groups)
    frame = session.read(next(r for rs in groups.values() for r in rs if r.relpath == relpath))

    def after_g(base):
        ff = flat_field_from_session(session, setting="NZDI", base=base)
        c = snup(ff.correct(frame), layout="rgb")["G"]
        return format_pm(c.snup, c.snup_err)

    shown_rec, shown_other = after_g(rec.key), after_g(OTHER_BASE)
    assert shown_rec != shown_other  # otherwise the test could not see the change

    url = serve_app(demo)
    page.set_viewport_size({"width": 1400, "height": 1200})
    page.goto(url)
    expect(page.get_by_text("Loaded delasarte07")).to_be_visible(timeout=TIMEOUT)
    page.get_by_role("button", name=re.compile("Flat field")).click()

    # the recommended base is chosen, marked and explained; ccdcore's SNUP after correction
    expect(page.get_by_text(f"Recommended base image: {group_label(rec.key)}")).to_be_visible(
        timeout=TIMEOUT)
    base = page.get_by_role("combobox", name=re.compile("Base image"))
    expect(base).to_have_value(re.compile(r"\(recommended\)"), timeout=TIMEOUT)
    expect(page.get_by_text(shown_rec, exact=True)).to_be_visible(timeout=TIMEOUT)
    expect(page.locator(".ccd-flat-after canvas").first).to_be_visible(timeout=TIMEOUT)

    # choose another base image: the SNUP after correction follows
    label = next(t for t in base.locator("option").all_inner_texts()
                 if t.startswith(group_label(OTHER_BASE) + " "))
    base.select_option(label=label)
    expect(page.get_by_text(shown_other, exact=True)).to_be_visible(timeout=TIMEOUT)
    expect(page.get_by_text(shown_rec, exact=True)).to_be_hidden()
    expect(page.get_by_text(f"corrected with base {group_label(OTHER_BASE)}")).to_be_visible()
