"""No markup from a file runs in the app, and the app answers only at its own address.

Strings from files -- a manifest's camera name and roles, file names, a product's notes -- are
shown as text (ccdcore_app.markup: Markdown without raw HTML); a request naming another host
(DNS rebinding) gets no app (ccdcore_app.main.host_allowed)."""
from __future__ import annotations

import html
import http.client
import re
from pathlib import Path

import numpy as np
import panel as pn
import pytest
from playwright.sync_api import Page, expect

from ccdcore.io.frames import write_image
from ccdcore_app.main import host_allowed
from ccdcore_app.markup import forbid_raw_html

#: a payload that sets a flag in the page if any of it runs as markup
PAYLOAD = '<img src=x onerror="window.__pwned=1">'
TIMEOUT = 60_000


def _rendered(pane) -> str:
    return pane._transform_object(pane.object)["object"]


@pytest.mark.parametrize("kind", [pn.pane.Markdown, pn.pane.Alert])
def test_markdown_panes_show_raw_html_as_text(kind):
    """The markup arrives in the browser escaped (as text), whatever pane shows it; the app's
    own Markdown (bold, code) still renders."""
    forbid_raw_html()
    out = html.unescape(_rendered(kind(f"**camera** {PAYLOAD} `code` "
                                       "<script>window.__pwned=2</script>")))
    assert "<img" not in out and "<script" not in out
    assert "&lt;img" in out
    assert "strong" in out and "code" in out


def test_host_check():
    hosts = ["127.0.0.1:5006", "localhost:5006"]
    assert host_allowed("127.0.0.1:5006", hosts)
    assert host_allowed("LOCALHOST:5006", hosts)
    assert not host_allowed("evil.example:5006", hosts)
    assert not host_allowed("127.0.0.1:5007", hosts)
    assert not host_allowed(None, hosts)
    assert host_allowed("anything", None)


def _get(port: int, host: str) -> tuple[int, str]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    conn.request("GET", "/", headers={"Host": host})
    r = conn.getresponse()
    body = r.read().decode("utf-8", "replace")
    conn.close()
    return r.status, body


def test_a_request_for_another_host_gets_no_app(serve_main, healey94):
    """The page served for a foreign Host header is not the app (no template, no session:
    the app's document for it is one line, :data:`WRONG_HOST`); at the listened address it is."""
    url, port = serve_main(healey94)
    status, body = _get(port, f"127.0.0.1:{port}")
    assert status == 200 and "radiometric camera calibration" in body
    status, body = _get(port, f"rebind.example:{port}")
    assert "radiometric camera calibration" not in body and "healey94" not in body


def _hostile_session(root: Path) -> Path:
    """A session whose camera name, a frame's role and a file name carry markup."""
    rng = np.random.default_rng(3)
    root.mkdir(parents=True)
    name = 'd<img src=x onerror="window.__pwned=3">.tif'
    write_image(root / name, rng.integers(90, 110, (16, 16)).astype(np.uint16), bits=12)
    write_image(root / "d1.tif", rng.integers(90, 110, (16, 16)).astype(np.uint16), bits=12)
    (root / "session.toml").write_text(
        "schema = 1\n[camera]\nname = '" + PAYLOAD + "'\nbits = 12\nlayout = \"mono\"\n\n"
        f"[[frames]]\npath = '{name}'\nrole = \"dark\"\nexposure = 0.01\n\n"
        "[[frames]]\npath = \"d1.tif\"\nrole = '<img src=y onerror=\"window.__pwned=4\">'\n")
    return root


def test_markup_in_a_session_runs_nowhere(page: Page, serve_app, open_app, tmp_path):
    """Opened in the browser, the hostile session's strings are shown as text and nothing runs
    (no image element from them, no flag set)."""
    root = _hostile_session(tmp_path / "hostile")
    url = serve_app(root, allowed_roots=[tmp_path])
    open_app(url)
    expect(page.get_by_text(re.compile(r'onerror="window.__pwned=1"')).first).to_be_visible(
        timeout=TIMEOUT)
    page.wait_for_timeout(500)
    assert page.evaluate("window.__pwned === undefined")
    assert page.locator("img[src='x'], img[src='y']").count() == 0
