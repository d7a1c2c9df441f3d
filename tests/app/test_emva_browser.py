"""The EMVA 1288 parts of the app in headless Chromium, on a set of emva1288's DatasetGenerator:
the Walkthrough's photon-transfer step shows the datasheet and the fit-range control (set to the
EMVA 1288 range) and draws the spatial plots when their card is opened, and the Maps page's EMVA
1288 spatial tab draws the spectrograms."""
from __future__ import annotations

import re
from pathlib import Path

from playwright.sync_api import Page, expect

from test_emva_pages import make_emva_set

TIMEOUT = 60_000  # generous: a busy CI machine draws slowly; passing runs do not wait

#: [title, frame width, frame height] of every drawn Bokeh figure whose title names a
#: spectrogram (0 when Bokeh laid it out at zero size); hidden pages are skipped
_SPECTROGRAMS_JS = """() => {
  const out = [];
  const walk = (v, depth) => {
    if (!v || depth > 40 || (v.model && v.model.visible === false)) return;
    const title = v.model && v.model.title && v.model.title.text;
    if (v.model && v.model.type === 'Figure' && v.frame && title && /spectrogram/.test(title))
      out.push([title, v.frame.bbox.width, v.frame.bbox.height]);
    for (const k of (v.child_views || [])) walk(k, depth + 1);
  };
  for (const v of Object.values(Bokeh.index)) walk(v, 0);
  return out;
}"""


def test_emva_datasheet_range_control_and_spatial_tab(page: Page, serve_app, open_app,
                                                      tmp_path: Path):
    descriptor = make_emva_set(tmp_path / "emva")
    url = serve_app(descriptor, allowed_roots=[descriptor.parent])
    page.set_viewport_size({"width": 1400, "height": 1200})
    open_app(url + "/?page=walkthrough&step=ptc")
    step = page.locator(".ccd-wt-ptc")
    expect(step.get_by_text("Step 4 of 8: Photon transfer")).to_be_visible(timeout=TIMEOUT)
    # the datasheet, in the standard's order, with the dark current and the DSNU split
    sheet = page.locator(".ccd-wt-emva")
    for name in ("Quantum efficiency", "Overall system gain", "Dark current from the mean",
                 "DSNU, row part", "PRNU, pixel part"):
        expect(sheet).to_contain_text(name, timeout=TIMEOUT)
    expect(sheet).to_contain_text("e⁻/s")
    # the fit range: the EMVA 1288 range chosen (photon counts), and the gate says so
    control = page.locator(".ccd-wt-fit-range")
    emva_button = control.get_by_role("button", name="EMVA 1288 range: 0–70 % of saturation")
    expect(emva_button).to_be_visible()
    expect(emva_button).to_have_class(re.compile("active"))
    expect(control.get_by_role("button", name="every level below saturation")).to_be_visible()
    gate = page.locator(".ccd-wt-gate-ptc")
    expect(gate).to_contain_text("fit range: the levels up to 70 % of the saturation signal",
                                 timeout=TIMEOUT)

    # the spatial section's plots are drawn when their card is opened
    page.locator(".ccd-wt-spatial-card").get_by_text("Spatial nonuniformity").click()
    expect(page.locator(".ccd-wt-spatial canvas").first).to_be_visible(timeout=TIMEOUT)

    # the Maps page: its EMVA 1288 spatial tab draws the four spectrograms
    page.locator(".ccd-nav").get_by_role("button", name=re.compile("Maps")).click()
    tab = page.locator(".ccd-maps-tabs").get_by_role("button", name="EMVA 1288 spatial")
    tab.click(timeout=TIMEOUT)
    expect(page.locator(".ccd-emva-note")).to_contain_text("DSNU1288", timeout=TIMEOUT)
    expect(page.locator(".ccd-emva-spatial canvas").first).to_be_visible(timeout=TIMEOUT)
    page.wait_for_function(f"() => ({_SPECTROGRAMS_JS})().length === 4", timeout=TIMEOUT)
    drawn = page.evaluate(_SPECTROGRAMS_JS)
    assert {t for t, _, _ in drawn} >= {"Horizontal spectrogram of the DSNU",
                                        "Vertical spectrogram of the PRNU"}
    assert all(w > 100 and h > 100 for _, w, h in drawn), drawn
