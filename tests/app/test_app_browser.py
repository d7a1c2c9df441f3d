"""The real app in headless Chromium: open a demo, see its tables, preview a frame, read a pixel."""
from __future__ import annotations

import re

from playwright.sync_api import Page, expect

TIMEOUT = 60_000  # generous: a busy CI machine draws slowly; passing runs do not wait


def _outside(requests: list[str]) -> list[str]:
    return [u for u in requests if not re.match(r"^(https?|wss?)://127\.0\.0\.1[:/]", u)
            and not u.startswith(("data:", "blob:", "about:"))]


def _scroll_to(page: Page, placeholder_text: str) -> None:
    """Scroll to a part of the Session page put into the page when it comes near the viewport
    (ccdcore_app.pages.session.InView), and wait until it replaced its placeholder."""
    from playwright.sync_api import Error

    placeholder = page.get_by_text(placeholder_text)
    for _ in range(20):
        if placeholder.count() == 0:      # replaced (already in view, or the scroll did it)
            break
        try:
            placeholder.first.scroll_into_view_if_needed(timeout=5_000)
        except Error:                     # replaced or re-rendered meanwhile: look again
            page.wait_for_timeout(250)
    expect(placeholder).to_have_count(0, timeout=TIMEOUT)


def _scroll_to_preview(page: Page) -> None:
    """Scroll to the Frame preview card (its body is put into the page when in view)."""
    _scroll_to(page, "Scroll here to preview the frame.")
    expect(page.locator(".ccd-clim").first).to_be_visible(timeout=TIMEOUT)


def test_demo_session_tables_preview_histogram_and_pixel_readout(page: Page, serve_app, open_app,
                                                                  healey94, settled_box):
    requests: list[str] = []
    page.on("request", lambda r: requests.append(r.url))
    url = serve_app(healey94)
    page.set_viewport_size({"width": 1400, "height": 1000})
    open_app(url)

    # the groups and per-frame metadata tables (the frames table, below the fold, is put into
    # the page when scrolled to)
    expect(page.get_by_text("Loaded healey94")).to_be_visible(timeout=TIMEOUT)
    _scroll_to(page, "Scroll here to list the frames.")
    expect(page.get_by_role("gridcell", name="dark/dark_000.tif").first).to_be_visible(
        timeout=TIMEOUT)
    expect(page.get_by_text("XC-77-like simulated CCD")).to_be_visible()
    expect(page.get_by_text("No problems found: the session is valid.")).to_be_visible()

    # the first frame is previewed once the session loads; the preview sits below the fold and
    # is drawn when scrolled to (a placeholder until then)
    _scroll_to_preview(page)
    expect(page.get_by_text(re.compile(r"dark_000\.tif.*dark, exposure 0\.033 s"))).to_be_visible(
        timeout=TIMEOUT)

    # select another frame in the table: the preview follows
    page.get_by_role("gridcell", name="dark/dark_003.tif").first.click()
    expect(page.get_by_text(re.compile(r"dark_003\.tif.*dark, exposure 0\.033 s"))).to_be_visible(
        timeout=TIMEOUT)
    # the rasterised image and its histogram are drawn (bokeh canvases)
    canvas = page.locator(".ccd-image canvas").first
    expect(canvas).to_be_visible(timeout=TIMEOUT)
    expect(page.locator(".ccd-histogram canvas").first).to_be_visible(timeout=TIMEOUT)

    # hovering the image reports the pixel value under the cursor
    page.wait_for_timeout(1500)  # let the re-rendered plot settle before moving the mouse
    box = settled_box(page.locator(".ccd-image canvas").first)
    for dx in (0.3, 0.4, 0.5, 0.6):
        page.mouse.move(box["x"] + box["width"] * dx, box["y"] + box["height"] * 0.5)
        page.wait_for_timeout(400)
    expect(page.get_by_text(re.compile(r"x = \d+, y = \d+: \d+ DN"))).to_be_visible(
        timeout=TIMEOUT)

    # a lab machine is offline: nothing may be fetched from another host
    assert _outside(requests) == []
    # the app's BokehJS speed-ups (app/static/bokeh_speed.js) found what they patch
    assert page.evaluate("() => window.ccdBokehSpeed") == ["css-variables", "base-font-size"]
    # Bootstrap's stylesheet is loaded once by the page, in no component (ccdcore_app.main.AppDesign)
    inside, outside = page.evaluate("""() => {
        const roots = [];
        const walk = (node) => { for (const el of node.querySelectorAll('*')) {
            if (el.shadowRoot) { roots.push(el.shadowRoot); walk(el.shadowRoot); } } };
        walk(document);
        const sel = 'link[href*="bootstrap.min.css"]';
        return [roots.reduce((n, r) => n + r.querySelectorAll(sel).length, 0),
                document.querySelectorAll(sel).length];
    }""")
    assert (inside, outside) == (0, 1)


def test_bad_path_shows_an_alert_and_the_app_keeps_working(page: Page, serve_app, open_app,
                                                           tmp_path, healey94):
    url = serve_app(None, allowed_roots=[tmp_path, healey94.parent])
    open_app(url)
    box = page.get_by_placeholder("/path/to/session")
    expect(box).to_be_visible(timeout=TIMEOUT)
    box.fill(str(tmp_path / "no-such-session"))
    box.press("Enter")
    alert = page.get_by_text(re.compile(r"Error:.*no-such-session"))
    expect(alert).to_be_visible(timeout=TIMEOUT)

    # still working: open the demo next
    box.fill(str(healey94))
    box.press("Enter")
    expect(page.get_by_text("Loaded healey94")).to_be_visible(timeout=TIMEOUT)
    expect(alert).to_be_hidden()


def test_the_walkthrough_opens_from_the_navigation(page: Page, serve_app, open_app):
    url = serve_app(None)
    open_app(url)
    page.get_by_role("button", name=re.compile("Walkthrough")).click()
    expect(page.get_by_text("Step 1 of 8: Plan the captures")).to_be_visible(timeout=TIMEOUT)


def test_colour_demo_channels_colour_range_and_hover_tooltip(page: Page, serve_app, open_app,
                                                            assets, settled_box):
    """RGB frames: channel buttons, the auto colour range reaches the browser intact, and the
    hover tooltip shows the exact DN of the pixel under the cursor."""
    import numpy as np

    from ccdcore_app.plots import base as plots
    from ccdcore.session import open_session

    url = serve_app(None)
    page.set_viewport_size({"width": 1400, "height": 1000})
    open_app(url)
    page.locator(".ccd-demo select").select_option("change")
    page.get_by_role("button", name="Open demo").click()
    expect(page.get_by_text("Loaded change")).to_be_visible(timeout=TIMEOUT)

    session = open_session(assets / "change")
    first = session.frames[0]
    red = plots.channel_data(session.read(first), "R")
    _scroll_to_preview(page)
    red_button = page.locator(".ccd-channel").get_by_role("button", name="R", exact=True)
    expect(red_button).to_be_visible(timeout=TIMEOUT)
    red_button.click()
    expect(page.get_by_text(re.compile(r"channel R; min \d+, max \d+"))).to_be_visible(
        timeout=TIMEOUT)

    # the editable range shows the 0.5-99.5 % range of the R plane (not clamped on the way)
    lo, hi = plots.auto_clim(red)
    inputs = page.locator(".ccd-clim input")
    expect(inputs.nth(0)).to_have_value(f"{lo:.1f}", timeout=TIMEOUT)
    expect(inputs.nth(1)).to_have_value(f"{hi:.1f}", timeout=TIMEOUT)

    # the bokeh hover tooltip: x, y and the DN of that pixel of the R plane
    page.wait_for_timeout(1500)  # let the re-rendered plot settle before moving the mouse
    box = settled_box(page.locator(".ccd-image canvas").first)
    tooltip = page.locator(".bk-tooltip-content").filter(has_text="DN")
    for dx in (0.35, 0.45, 0.55):
        page.mouse.move(box["x"] + box["width"] * dx, box["y"] + box["height"] * 0.5)
        page.wait_for_timeout(300)
    expect(tooltip.first).to_be_visible(timeout=TIMEOUT)
    text = tooltip.first.inner_text()
    m = re.search(r"x:\s*(\d+)\s*y:\s*(\d+)\s*DN:\s*([\d.]+)", text)
    assert m, text
    x, y, dn = int(m[1]), int(m[2]), float(m[3])
    # at this zoom a screen pixel is smaller than a frame pixel: the value is the pixel's own
    assert dn == float(red[y, x]), (x, y, dn, red[y - 1:y + 2, x - 1:x + 2])
    assert np.issubdtype(red.dtype, np.integer)


def test_closing_the_browser_session_releases_its_results(page: Page, serve_app, open_app,
                                                          healey94, monkeypatch):
    """When the tab closes, Bokeh destroys the session (here 0.3 s after the last connection)
    and the app drops the session's capture session and results."""
    import time

    from ccdcore_app.state import AppState

    states: list[AppState] = []
    closed: list[AppState] = []
    init, close = AppState.__init__, AppState.close

    def recording_init(self, **params):
        init(self, **params)
        states.append(self)

    def recording_close(self):
        close(self)
        closed.append(self)

    monkeypatch.setattr(AppState, "__init__", recording_init)
    monkeypatch.setattr(AppState, "close", recording_close)
    from ccdcore_app.main import AppShell
    shells: list[AppShell] = []
    shell_init = AppShell.__init__

    def recording_shell(self, state, **params):
        shell_init(self, state, **params)
        shells.append(self)

    monkeypatch.setattr(AppShell, "__init__", recording_shell)
    url = serve_app(healey94, check_unused_sessions_milliseconds=300,
                    unused_session_lifetime_milliseconds=300)
    open_app(url)
    expect(page.get_by_text("Loaded healey94")).to_be_visible(timeout=TIMEOUT)
    page.get_by_role("button", name=re.compile("Photon transfer")).click()
    expect(page.get_by_text("Passed", exact=True).first).to_be_visible(timeout=TIMEOUT)
    [state] = [s for s in states if s.results.ptc is not None]   # this tab's
    assert state.session is not None and state not in closed
    [shell] = [sh for sh in shells if sh.state is state]
    deadline = time.monotonic() + 30
    while shell._pages["photon_transfer"].preview_view.plane is None \
            and time.monotonic() < deadline:            # the ROI preview reads its frame
        time.sleep(0.2)
    assert shell._pages["session"].image_view.plane is not None
    assert shell._pages["photon_transfer"].preview_view.plane is not None

    page.close()
    deadline = time.monotonic() + 30
    while state not in closed and time.monotonic() < deadline:
        time.sleep(0.2)
    assert state in closed
    assert state.session is None and state.results.ptc is None
    assert state.results.ptc_points is None and state.results.estimates is None
    # the pages let go of the frames they showed
    assert shell._pages["session"].image_view.plane is None
    assert shell._pages["session"]._plane is None
    assert shell._pages["photon_transfer"].preview_view.plane is None
