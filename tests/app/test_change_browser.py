"""The Change detection page on the bundled change demo in headless Chromium: the result is
drawn, and moving the false-alarm slider changes the changed-pixel count to ccdcore's count at
the new false-alarm probability, at once (no refit)."""
from __future__ import annotations

import re
import time

import numpy as np
from playwright.sync_api import Page, expect

from ccdcore_app.pages.change import DEFAULT_PFA, PFA_STEPS
from ccdcore.change.detector import LABEL_CHANGE, ChangeOptions
from ccdcore.change.session import session_change
from ccdcore.session import open_session

TIMEOUT = 90_000  # both brackets' radiance, the response and the clusters on first visit
#: a slider move must show its count within this (measured: well under a second)
SLIDER_BUDGET = 5.0


def _count(result, pfa: float) -> int:
    return int(np.count_nonzero(result.at(pfa)[0] == LABEL_CHANGE))


def test_false_alarm_slider_changes_the_count(page: Page, serve_app, assets, settled_box):
    demo = assets / "change"
    result, _ = session_change(open_session(demo), ChangeOptions(pfa=DEFAULT_PFA))
    steps = list(PFA_STEPS.values())
    start = steps.index(DEFAULT_PFA)
    higher, lower = steps[start + 2], steps[start - 3]
    expected = {p: _count(result, p) for p in (DEFAULT_PFA, higher, lower)}
    assert len(set(expected.values())) == 3, expected      # each move is visible

    url = serve_app(demo)
    page.set_viewport_size({"width": 1400, "height": 1200})
    page.goto(url)
    expect(page.get_by_text("Loaded change")).to_be_visible(timeout=TIMEOUT)
    page.get_by_role("button", name=re.compile("Change detection")).click()
    count = page.locator(".ccd-change-count")
    expect(count).to_contain_text(f"{expected[DEFAULT_PFA]:,}", timeout=TIMEOUT)
    for name in ("labels", "reference", "target", "predicted", "d2", "hist"):
        expect(page.locator(f".ccd-change-{name} canvas").first).to_be_visible(timeout=TIMEOUT)
    expect(page.locator(".ccd-change-legend")).to_contain_text("change")
    expect(page.locator(".ccd-change-clusters")).to_contain_text("unchanged (background)")
    expect(page.locator(".ccd-change-error")).to_be_hidden()
    page.wait_for_timeout(1000)   # let the first render settle before using the slider

    handle = page.locator(".ccd-change-pfa .noUi-handle").first
    settled_box(handle)
    handle.focus()
    for key, pfa, presses in (("ArrowRight", higher, 2), ("ArrowLeft", lower, 5)):
        t0 = time.perf_counter()
        for _ in range(presses):
            handle.press(key)
        expect(count).to_contain_text(f"{expected[pfa]:,}", timeout=TIMEOUT)
        elapsed = time.perf_counter() - t0
        print(f"slider to P = {pfa:g}: count shown after {elapsed:.2f} s")
        assert elapsed < SLIDER_BUDGET, f"the count took {elapsed:.1f} s to follow the slider"
        expect(page.locator(".ccd-change-pfa").first).to_contain_text(f"{pfa:g}")
        expect(page.locator(".ccd-change-details")).to_contain_text(
            f"{_percent_observed(result, pfa)} of the background sample")


def _percent_observed(result, pfa: float) -> str:
    thr = result.at(pfa)[1]
    return f"{100 * result.observed_pfa(thr):.3g} %"
