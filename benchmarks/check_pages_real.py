"""Every page of the app on the largest real session of each kind: no traceback, and the page's
main figure in the first view at 1400 x 900 (or the page's message saying what it needs).

Data: ``../shared/data`` (``/work/shared/data``; ``CCDCORE_SHARED`` overrides ``/work/shared``):
the 13-image ``brackets/desktop``, the SBIG CCD's FITS darks and flats ``ccd/sbig_stl1001e``, the
Nikon D200's JPEG flats ``flats/nikon_d200`` (served with ``--role flat``) and the lobby's frames
``change/lobby`` (five lights-on frames as ``reference/``, one with a person as ``target/``, in a
temporary folder). Absent: this prints so and exits 0.

For each set, ``ccdcore app SET`` is served in a child process and each page opened in headless
Chromium (``/usr/bin/chromium``); a page is *done* when its main figure is drawn or, on a page
whose estimate the set cannot give, when its message is shown (both within ``WAIT`` s). Printed:
a markdown table of set, page, what was shown (the figure's top and middle in px, or the first
message), and whether the figure's upper half is on screen without scrolling. The app's log is
searched for tracebacks.

Run: ``python benchmarks/check_pages_real.py`` (about 5-10 minutes on two cores).
"""
from __future__ import annotations

import os
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _browser import CHROMIUM, CHROMIUM_ARGS, Server, free_port  # noqa: E402

DATA = Path(os.environ.get("CCDCORE_SHARED", "/work/shared")) / "data"
WAIT = 240.0
#: page button, the main figure's selector (None: the page has no single main figure)
PAGES = [
    ("Session", "session", ".ccd-groups"),
    ("Photon transfer", "photon_transfer", ".ccd-ptc-plot canvas"),
    ("Maps", "maps", ".ccd-maps canvas"),
    ("Flat field", "flat_field", ".ccd-flat-before canvas"),
    ("Response & HDR", "response_hdr", ".ccd-response-curves canvas"),
    ("Change detection", "change", ".ccd-change-labels canvas"),
    ("Walkthrough", "walkthrough", None),
]
#: Panel's alerts (pn.pane.Alert) and the pages' own messages
MESSAGE = ".alert"
#: the text of an element and of every shadow root below it (Bokeh draws Panel's panes in
#: shadow roots, which innerText does not enter)
DEEP_TEXT = """el => { const walk = n => { let t = '';
  if (n.shadowRoot) t += walk(n.shadowRoot);
  for (const c of n.childNodes) {
    if (c.nodeName === 'STYLE' || c.nodeName === 'SCRIPT') continue;
    t += c.nodeType === 3 ? c.textContent : walk(c); }
  return t; }; return walk(el); }"""


def lobby(tmp: Path) -> Path:
    root = tmp / "lobby"
    for role, ids in (("reference", range(1000, 1005)), ("target", [1390])):
        (root / role).mkdir(parents=True)
        for i in ids:
            shutil.copy(DATA / "change" / "lobby" / f"SwitchLight{i}.bmp", root / role)
    return root


def first_message(page, slug: str) -> str:
    """The first non-empty alert shown in the page's own holder (``.ccd-page-SLUG``)."""
    for loc in page.locator(f".ccd-page-{slug} {MESSAGE}").all():
        try:
            if loc.is_visible():
                text = " ".join(loc.evaluate(DEEP_TEXT).split())
                if text:
                    return text[:110]
        except Exception:  # noqa: BLE001 - a node replaced while read
            continue
    return ""


def check_page(page, button: str, slug: str, figure: str | None) -> tuple[str, str]:
    page.get_by_role("button", name=re.compile(re.escape(button))).click()
    t0 = time.monotonic()
    while time.monotonic() - t0 < WAIT:
        if figure is not None:
            plot = page.locator(figure).first
            if plot.count() and plot.is_visible():
                box = plot.bounding_box()
                if box and box["height"] > 0:
                    page.evaluate("window.scrollTo(0, 0)")
                    page.wait_for_timeout(300)
                    box = plot.bounding_box()
                    ok = box["y"] >= 0 and box["y"] + 0.5 * box["height"] <= 900
                    return (f"figure at y {box['y']:.0f}-{box['y'] + box['height']:.0f} px "
                            f"({time.monotonic() - t0:.0f} s)", "yes" if ok else "NO")
        msg = first_message(page, slug)
        if msg and (figure is None or time.monotonic() - t0 > 60):
            if "Traceback" in msg:
                return msg, "NO (traceback)"
            return f"message: {msg}", "n/a" if figure is not None else "yes"
        page.wait_for_timeout(500)
    return "nothing shown", "NO (timed out)"


def main() -> int:
    if not DATA.is_dir():
        print(f"{DATA} is absent: nothing to check")
        return 0
    from playwright.sync_api import sync_playwright

    rows = ["| set | page | shown | in the first view |", "|---|---|---|---|"]
    tracebacks = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        sets = [("brackets/desktop", DATA / "brackets" / "desktop", []),
                ("ccd/sbig_stl1001e", DATA / "ccd" / "sbig_stl1001e", []),
                ("flats/nikon_d200 --role flat", DATA / "flats" / "nikon_d200",
                 ["--role", "flat"]),
                ("change/lobby (5 + 1 frames)", lobby(tmp), [])]
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            for name, path, extra in sets:
                port = free_port()
                log = tmp / f"app-{port}.log"
                cmd = [shutil.which("ccdcore") or "ccdcore", "app", str(path), "--port",
                       str(port), *extra]
                with Server(cmd, port, log) as server:
                    server.launch()
                    server.wait_live()
                    page = browser.new_page(viewport={"width": 1400, "height": 900})
                    page.goto(server.url)
                    page.get_by_text(re.compile(r"Loaded ")).first.wait_for(timeout=WAIT * 1000)
                    for button, slug, figure in PAGES:
                        shown, first = check_page(page, button, slug, figure)
                        rows.append(f"| {name} | {button} | {shown} | {first} |")
                        print(rows[-1], flush=True)
                    page.close()
                text = log.read_text(errors="replace") if log.exists() else ""
                if "Traceback" in text:
                    tracebacks.append((name, text[text.index("Traceback"):][:2000]))
            browser.close()
    print()
    print("\n".join(rows))
    for name, text in tracebacks:
        print(f"\ntraceback in the app's log for {name}:\n{text}")
    if not tracebacks:
        print("\nno traceback in any app log")
    return 0


if __name__ == "__main__":
    sys.exit(main())
