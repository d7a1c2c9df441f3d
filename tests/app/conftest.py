"""Fixtures for the app tests: small sessions on disk, the bundled demos, a served app and
Playwright (pytest-playwright) running Debian's Chromium headless."""
from __future__ import annotations

import socket
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import pytest

from ccdcore_app.state import assets_dir


def pytest_configure(config: pytest.Config) -> None:
    # Two deprecations inside third-party code, not ours: bokeh calls pandas' reset_index(inplace=)
    # and pytest-base-url defines its session fixture as a method.  Our own warnings still show.
    config.addinivalue_line("filterwarnings",
                            "ignore:The inplace keyword in DataFrame.reset_index is deprecated")
    config.addinivalue_line("filterwarnings",
                            "ignore:Session-scoped fixtures defined as instance methods")
from ccdcore.io.frames import write_image

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]


@pytest.fixture(scope="session", autouse=True)
def _no_result_cache_in_shared_fixtures():
    """The same for module- and session-scoped fixtures, which run before any function-scoped
    one: a page computed once per module must not be read from (or written to) the user's
    cache either (it was: a module's count of computations then depended on what an earlier
    run had left there)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("CCDCORE_CACHE", "off")
        yield


@pytest.fixture(autouse=True)
def _no_result_cache(monkeypatch: pytest.MonkeyPatch) -> None:
    """No test reads or fills the user's result cache (app/cache.py), and no test sees another
    test's results; a test of the cache points CCDCORE_CACHE at its own folder."""
    monkeypatch.setenv("CCDCORE_CACHE", "off")
    # nor the server-wide store of shared results (app/cache.py): a fresh one per test
    import ccdcore_app.cache.store as cache
    monkeypatch.setattr(cache, "_SHARED", None)


# ------------------------------------------------------------------------------ sessions -------
@pytest.fixture(scope="session")
def assets() -> Path:
    """The bundled demo sessions folder (the lead guarantees it is populated at test time)."""
    folder = assets_dir()
    missing = [p for p in ("healey94", "delasarte07", "tsin01", "change")
               if not (folder / p / "session.toml").is_file()]
    if missing:
        pytest.fail(f"bundled demo sessions missing in {folder}: {', '.join(missing)} "
                    "(run .venv/bin/python assets/regenerate.py)")
    return folder


@pytest.fixture(scope="session")
def healey94(assets: Path) -> Path:
    return assets / "healey94"


def _frames(rng: np.random.Generator, n: int, shape: tuple[int, ...], mean: float
            ) -> list[np.ndarray]:
    return [np.clip(rng.normal(mean, 3.0, shape), 0, 4095).astype(np.uint16) for _ in range(n)]


def make_session(root: Path, *, extra_toml: str = "", rgb: bool = True) -> Path:
    """A small valid session: 2 darks, one ptc pair (mono 12-bit) and an RGB scene."""
    rng = np.random.default_rng(7)
    root.mkdir(parents=True, exist_ok=True)
    entries = []
    for i, frame in enumerate(_frames(rng, 2, (24, 32), 100.0)):
        write_image(root / f"dark/d{i}.tif", frame, exposure=0.01, bits=12)
        entries.append(f'[[frames]]\npath = "dark/d{i}.tif"\nrole = "dark"\nexposure = 0.01\n')
    for i, frame in enumerate(_frames(rng, 2, (24, 32), 900.0)):
        write_image(root / f"ptc/p{i}.tif", frame, exposure=0.01, bits=12)
        entries.append(f'[[frames]]\npath = "ptc/p{i}.tif"\nrole = "ptc"\nlevel = 1\n'
                       'exposure = 0.01\n')
    if rgb:
        scene = rng.integers(0, 4096, (24, 32, 3), dtype=np.uint16)
        scene[..., 0] = 4000  # a flat red channel: R differs visibly from G and B
        write_image(root / "scene/rgb.tif", scene, exposure=0.02, bits=12)
        entries.append('[[frames]]\npath = "scene/rgb.tif"\nrole = "scene"\n')
    text = ('schema = 1\n[camera]\nname = "test camera"\nbits = 12\nlayout = "mono"\n\n'
            + "\n".join(entries) + extra_toml)
    (root / "session.toml").write_text(text)
    return root


@pytest.fixture
def small_session(tmp_path: Path) -> Path:
    return make_session(tmp_path / "small")


@pytest.fixture
def broken_manifest(tmp_path: Path) -> Path:
    """A session whose session.toml is not valid TOML (line 3)."""
    root = make_session(tmp_path / "broken")
    (root / "session.toml").write_text('schema = 1\n[camera]\nname = "unterminated\n')
    return root


@pytest.fixture
def problem_session(tmp_path: Path) -> Path:
    """Valid TOML with validation problems: a missing file and an unknown role."""
    extra = ('\n[[frames]]\npath = "dark/missing.tif"\nrole = "dark"\n'
             '\n[[frames]]\npath = "dark/d0.tif"\nrole = "darkish"\n')
    return make_session(tmp_path / "problems", extra_toml=extra)


@pytest.fixture
def unreadable_session(tmp_path: Path) -> Path:
    """A session whose scene frame is garbage bytes with a .tif name."""
    root = make_session(tmp_path / "unreadable", rgb=False)
    (root / "scene").mkdir()
    (root / "scene/bad.tif").write_bytes(b"this is not a TIFF file" * 10)
    with (root / "session.toml").open("a") as f:
        f.write('\n[[frames]]\npath = "scene/bad.tif"\nrole = "scene"\n')
    return root


@pytest.fixture
def plain_folder(tmp_path: Path) -> Path:
    """A folder of images without a manifest (roles from folder names)."""
    root = tmp_path / "plain"
    rng = np.random.default_rng(3)
    for i, frame in enumerate(_frames(rng, 2, (16, 20), 50.0)):
        write_image(root / f"darks/d{i}.tif", frame, exposure=0.05, bits=12)
    for i, frame in enumerate(_frames(rng, 2, (16, 20), 800.0)):
        write_image(root / f"flats/f{i}.tif", frame, exposure=0.05, bits=12)
    return root


# ------------------------------------------------------------------------------ browser --------
@pytest.fixture(scope="session")
def browser_type_launch_args(browser_type_launch_args: dict) -> dict:
    """Debian's Chromium, headless, with no background traffic (playwright cannot download)."""
    if not CHROMIUM.is_file():
        pytest.fail(f"{CHROMIUM} is missing: install Debian's chromium "
                    "(apt-get install -y chromium); the browser tests need it")
    return {**browser_type_launch_args, "executable_path": str(CHROMIUM),
            "args": CHROMIUM_ARGS}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_alive(url: str, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while True:
        try:
            with urllib.request.urlopen(url + "/liveness", timeout=2) as r:
                if r.status == 200:
                    return
        except (urllib.error.URLError, ConnectionError, TimeoutError):
            pass
        if time.monotonic() > deadline:
            raise RuntimeError(f"the app did not come up at {url} within {timeout} s")
        time.sleep(0.1)


@pytest.fixture(scope="session")
def warmed() -> None:
    """Import the estimators' scipy modules once for the whole run (as ``serve`` does)."""
    from ccdcore_app.main import warm_up

    warm_up()


@pytest.fixture
def serve_app(warmed: None) -> Iterator[Callable[..., str]]:
    """``serve_app(session_path=None, allowed_roots=None, **server_options) -> url``: the app on
    a free port, served threaded as ``ccdcore_app.main.serve`` does (``server_options`` go to the Bokeh
    server); every server is stopped after the test."""
    import panel as pn

    from ccdcore_app.main import create_app, server_resources

    def start(session_path: str | Path | None = None, allowed_roots=None,
              **server_options: Any) -> str:
        port = _free_port()

        def app():  # a plain function (Panel renders a functools.partial as text)
            return create_app(session_path, allowed_roots=allowed_roots)

        pn.serve({"/": app},
                 port=port, address="127.0.0.1", threaded=True, show=False, liveness=True,
                 websocket_origin=[f"127.0.0.1:{port}"], title="ccdcore",
                 **{**server_resources(), **server_options})
        url = f"http://127.0.0.1:{port}"
        _wait_alive(url)
        return url

    yield start
    pn.state.kill_all_servers()


@pytest.fixture
def serve_main(warmed: None) -> Iterator[Callable[..., str]]:
    """``serve_main(session_path=None) -> (url, port)``: the app served by
    :func:`ccdcore_app.main.serve` itself (its host check, its origins), threaded on a free
    port; stopped after the test."""
    import panel as pn

    from ccdcore_app.main import serve

    def start(session_path: str | Path | None = None) -> tuple[str, int]:
        port = _free_port()
        serve(session_path, port=port, threaded=True)
        url = f"http://127.0.0.1:{port}"
        _wait_alive(url)
        return url, port

    yield start
    pn.state.kill_all_servers()


@pytest.fixture
def open_app(page) -> Callable[[str], None]:
    """``open_app(url)``: load the app and wait until its websocket is connected and the document
    is idle. Widgets are drawn from the page's HTML before the connection opens; a click or a
    choice made earlier can be lost, so interact only after this returns."""

    def go(url: str, timeout: float = 60_000) -> None:
        with page.expect_console_message(lambda m: "document idle" in m.text, timeout=timeout):
            page.goto(url)

    return go


@pytest.fixture
def settled_box(page) -> Callable[..., dict]:
    """``settled_box(locator) -> box``: scroll the element into view and return its bounding
    box once it stays attached and in place. A plot that is re-rendered replaces its element,
    so a box read mid-render would point at a detached element."""
    from playwright.sync_api import Error

    def get(locator, timeout: float = 30.0) -> dict:
        deadline = time.monotonic() + timeout
        last = None
        while time.monotonic() < deadline:
            try:
                locator.scroll_into_view_if_needed(timeout=5_000)
                box = locator.bounding_box(timeout=5_000)
            except Error:  # detached while re-rendering: look it up again
                box = None
            if box is not None and box == last:
                return box
            last = box
            page.wait_for_timeout(300)
        raise AssertionError(f"{locator} did not settle within {timeout} s")

    return get
