"""The Maps page in headless Chromium: the maps are computed on first show and drawn, the
statistics and the planning warning appear, hovering reads values, another map can be chosen."""
from __future__ import annotations

import re

from playwright.sync_api import Page, expect

TIMEOUT = 60_000  # generous: a busy CI machine draws slowly; passing runs do not wait

#: width and height of every shown Bokeh plot frame (0 when Bokeh laid a plot out at zero size);
#: the hidden pages (visited before, kept in the document) are skipped
_FRAMES_JS = """() => {
  const out = [];
  const walk = (v, depth) => {
    if (!v || depth > 40 || (v.model && v.model.visible === false)) return;
    if (v.model && v.model.type === 'Figure' && v.frame)
      out.push([v.frame.bbox.width, v.frame.bbox.height]);
    for (const k of (v.child_views || [])) walk(k, depth + 1);
  };
  for (const v of Object.values(Bokeh.index)) walk(v, 0);
  return out;
}"""


def test_maps_page_computes_draws_reads_and_warns(page: Page, serve_app, healey94, settled_box):
    url = serve_app(healey94)
    page.set_viewport_size({"width": 1400, "height": 1000})
    page.goto(url)
    expect(page.get_by_text("Loaded healey94")).to_be_visible(timeout=TIMEOUT)
    page.get_by_role("button", name=re.compile("Maps")).click()

    # computed automatically on first show (the demo has dark frames): K̂'s statistics beside
    # the paper's, and the warning that 12 configurations x 4 frames are fewer than planned
    expect(page.get_by_text("K̂ spatial std")).to_be_visible(timeout=TIMEOUT)
    expect(page.get_by_text("0.99998")).to_be_visible()
    expect(page.get_by_text(
        "This session has fewer frames than the acquisition plan requires")).to_be_visible()
    expect(page.get_by_text(re.compile(r"fixed_pattern: 12 configurations, the plan needs "
                                       r"n1 = \d+"))).to_be_visible()

    # the two default maps are drawn, none at zero size (a Bokeh layout pitfall of nested
    # layouts)
    canvas = page.locator(".ccd-maps canvas").first
    expect(canvas).to_be_visible(timeout=TIMEOUT)
    page.wait_for_timeout(1500)
    frames = page.evaluate(_FRAMES_JS)
    assert len(frames) >= 2 + 2 + 2     # maps, histograms, profiles
    assert all(w > 50 and h > 50 for w, h in frames), frames

    # hovering a map reads the value of every map under the cursor
    box = settled_box(canvas)
    for dx in (0.3, 0.35, 0.4, 0.45):
        page.mouse.move(box["x"] + box["width"] * dx, box["y"] + box["height"] * 0.5)
        page.wait_for_timeout(300)
    expect(page.get_by_text(re.compile(r"x = \d+, y = \d+: .*K̂ = \d\.\d{5}"))).to_be_visible(
        timeout=TIMEOUT)

    # choose another map: its colour range control replaces K̂'s
    page.get_by_role("combobox", name="Selected map").select_option(
        label="Dark reference D̂_D")
    expect(page.get_by_text("Colour range of D̂_D (DN)")).to_be_visible(timeout=TIMEOUT)
    expect(page.get_by_text(re.compile(r"mean of s = 16 dark frames"))).to_be_visible()
