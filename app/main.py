"""The app shell: template, navigation, header, and the server entry point.

Public objects
--------------
create_app(session_path=None, *, allowed_roots=None)
    A fresh app (one per browser session): a Bootstrap template with the page registry in the
    sidebar and the loaded session in the header.
serve(session_path=None, port=5006, show=False, threaded=False, address="127.0.0.1")
    Serve the app (what ``ccdcore app [SESSION] [--port N]`` and ``python -m ccdcore_app`` call).
AppShell
    The navigation between the registry's pages (built on the first visit, then kept in the
    document and only hidden: a revisit draws nothing new).

The Bootstrap template is used because it loads nothing from outside hosts (its CSS and JS are
served by Panel itself), unlike templates that fetch Google web fonts; lab machines are offline.
"""
from __future__ import annotations

import html
import logging
import threading
import time
from pathlib import Path
from typing import Any, Iterable

import holoviews as hv
import panel as pn
import param
from panel.theme import Bootstrap

from .plots import base as plots
from .pages import PAGES, PageSpec, build_page
from .batch import batched, frozen_models
from .report_box import ReportBox
from .state import AppState, default_roots

__all__ = ["create_app", "serve", "check_port", "AppShell", "TITLE"]

log = logging.getLogger(__name__)

TITLE = "ccdcore \u00b7 radiometric camera calibration"
#: the app's own scripts, served under STATIC_ROUTE
STATIC_DIR = Path(__file__).resolve().parent / "static"
STATIC_ROUTE = "ccd-static"

pn.extension("tabulator", sizing_mode="stretch_width", notifications=False)
hv.extension("bokeh", logo=False)
# Canvas, not WebGL: HoloViews asks Bokeh for WebGL by default, which on machines without a GPU
# (lab VMs, headless servers, CI) runs in software; the plots here have few glyphs, where Canvas
# is as fast.
hv.renderer("bokeh").webgl = False

class AppDesign(Bootstrap):
    """Panel's Bootstrap design without Bootstrap's own stylesheet inside every component.

    Panel gives each component rendered with the first page its own copy of
    ``bootstrap.min.css`` (220 kB, thousands of rules) in its shadow root; with some sixty of
    them the browser spent a third of a page visit recomputing styles (docs/notes.md, "Where
    the app's time goes"). The page's head still loads the stylesheet for the template, and the
    components keep the design's theme sheets, which style them.
    """

    @classmethod
    def _get_modifiers(cls, viewable: Any, theme: Any = None, isolated: bool = True) -> Any:
        modifiers, child_modifiers = super()._get_modifiers(viewable, theme, isolated)
        sheets = modifiers.get("stylesheets")
        if sheets:
            modifiers["stylesheets"] = [s for s in sheets if not _is_bootstrap_css(s)]
        return modifiers, child_modifiers


class AppTemplate(pn.template.BootstrapTemplate):
    """Panel's Bootstrap template, adding its roots to a new document in one go.

    Bokeh's ``Document.add_root`` walks every model of the document after each root (the app
    has sixteen: header items, sidebar items, one holder per page); under one
    :func:`~ccdcore_app.batch.frozen_models` the walk happens once, when the page's document is
    complete (``server_doc`` 0.82 s instead of 1.0 s under cProfile on the demo).
    """

    def _init_doc(self, doc: Any = None, *args: Any, **kwargs: Any) -> Any:
        with frozen_models(doc if doc is not None else pn.state.curdoc):
            return super()._init_doc(doc, *args, **kwargs)


def _is_bootstrap_css(sheet: Any) -> bool:
    """Whether ``sheet`` (a URL) is Bootstrap's own stylesheet (not Panel's theme for it)."""
    return isinstance(sheet, str) and sheet.split("?")[0].endswith(BOOTSTRAP_CSS)


#: the file name of Bootstrap's stylesheet in Panel's bundle
BOOTSTRAP_CSS = "bootstrap5/css/bootstrap.min.css"


_CSS = """
.ccd-session { color: #e8eef5; font-size: 0.95em; white-space: nowrap; overflow: hidden;
  text-overflow: ellipsis; }
.ccd-session code { color: #ffffff; background: rgba(255,255,255,0.12); padding: 1px 5px;
  border-radius: 4px; }
"""

_NAV_CSS = """
:host { --ccd-nav: 1; }
.bk-btn-group { gap: 4px; }
.bk-btn-group .bk-btn { text-align: left; font-size: 0.98em; border-radius: 6px !important;
  margin: 0 !important; background: #f8f9fa !important; border: 1px solid #f8f9fa !important;
  color: #212529 !important; box-shadow: none !important; }
.bk-btn-group .bk-btn:hover { background: #e2e6ea !important; }
.bk-btn-group .bk-btn.bk-active { background: #0d6efd !important;
  border-color: #0d6efd !important; color: #ffffff !important; }
"""


class AppShell(param.Parameterized):
    """Sidebar navigation over :data:`ccdcore_app.pages.PAGES` and the main area showing one
    page."""

    page = param.Selector(default=PAGES[0].slug, objects=[p.slug for p in PAGES],
                          doc="Slug of the page shown.")

    def __init__(self, state: AppState, **params: Any):
        super().__init__(**params)
        self.state = state
        self._pages: dict[str, pn.viewable.Viewable] = {}
        #: the sidebar's page buttons: one Bokeh model for all (eight buttons and their
        #: column cost the first view some 40 ms on the server and in the browser)
        self.nav = pn.widgets.RadioButtonGroup(
            options={f"{spec.icon}  {spec.title}": spec.slug for spec in PAGES},
            value=self.page, orientation="vertical",
            sizing_mode="stretch_width", margin=(2, 4), stylesheets=[_NAV_CSS],
            css_classes=["ccd-nav"])
        self.nav.param.watch(lambda event: self._go(event.new), "value")
        #: slug -> the holder of each page (the template's main area shows each holder as its
        #: own Bokeh root): empty until the first visit, then the page, shown or hidden, never
        #: rebuilt. A change in one page then never makes the browser lay out another.
        self.holders: dict[str, pn.Column] = {
            spec.slug: pn.Column(sizing_mode="stretch_width", margin=0, visible=False,
                                 css_classes=["ccd-main", f"ccd-page-{spec.slug}"])
            for spec in PAGES}
        self._show()

    def _go(self, slug: str, event: Any = None) -> None:
        self.page = slug

    def page_view(self, slug: str) -> pn.viewable.Viewable:
        """The page ``slug`` (built on first visit, then kept with its widget state)."""
        if slug not in self._pages:
            spec: PageSpec = next(p for p in PAGES if p.slug == slug)
            self._pages[slug] = build_page(spec, self.state)
        return self._pages[slug]

    def close(self) -> None:
        """The browser session ended: the state drops its session and results
        (:meth:`AppState.close`), and every built page lets go of the arrays it shows (its
        ``release()``), with no redraw. Panel may hold the page objects a while longer."""
        self.state.close()
        for page in self._pages.values():
            release = getattr(page, "release", None)
            if callable(release):
                release()

    def holder(self, slug: str) -> pn.Column:
        """The holder of page ``slug``, holding the page (built on first call)."""
        holder = self.holders[slug]
        if not holder.objects:
            holder.objects = [self.page_view(slug)]
        return holder

    @param.depends("page", watch=True)
    @batched
    def _show(self) -> None:
        """Show the chosen page and hide the others. A visited page stays in the document with
        its plots (hidden): a revisit draws nothing new. A page may define ``on_show()``
        (e.g. to compute on first show)."""
        self.nav.value = self.page
        shown = self.holder(self.page)
        for holder in self.holders.values():
            if holder is not shown:
                holder.visible = False
        shown.visible = True
        hook = getattr(self.page_view(self.page), "on_show", None)
        if callable(hook):
            hook()


def _session_header(path: str, status: str, busy: bool) -> str:
    if busy:
        text = html.escape(status or "working\u2026")
    elif path:
        text = f"Session: <code>{html.escape(Path(path).name)}</code> " \
               f"<span style='opacity:0.75'>{html.escape(path)}</span>"
    else:
        text = "No session loaded"
    return f"<div class='ccd-session'>{text}</div>"


def _progress_bar(state: AppState) -> pn.Row:
    """The header's progress bar (percent done, or moving when unknown) and Cancel button,
    shown while a computation runs; the step and frame counts are in the status line."""
    bar = pn.indicators.Progress(value=-1, max=100, width=160, height=16, bar_color="info",
                                 margin=(20, 6, 0, 6), sizing_mode="fixed",
                                 css_classes=["ccd-progress"])
    cancel = pn.widgets.Button(label="Cancel", color="light", width=76, height=30,
                               margin=(12, 6, 0, 0), sizing_mode="fixed",
                               css_classes=["ccd-cancel"],
                               description="Stop the computation at its next frame")
    cancel.on_click(lambda event: state.cancel())
    row = pn.Row(bar, cancel, visible=False, sizing_mode="fixed", width=260, height=48, margin=0)

    def sync(*events: Any) -> None:
        running = state.busy and state.cancellable
        bar.param.update(value=state.progress if state.progress >= 0 else -1,
                         active=running and state.progress < 0)
        row.visible = running

    state.param.watch(sync, ["busy", "progress"])
    return row


#: what a request for another host than the app listens on gets instead of the app
WRONG_HOST = ("This app answers only at the addresses it listens on ({hosts}); the request "
              "named the host {host!r}. Open it at one of those addresses.")


def host_allowed(host: str | None, hosts: Iterable[str] | None) -> bool:
    """Whether a request's ``Host`` header names an address the app listens on (``hosts``:
    ``name:port`` strings; ``None``: any). A page elsewhere that resolves its own name to this
    machine (DNS rebinding) sends its own name as the host, and gets no app."""
    if hosts is None:
        return True
    return host is not None and host.strip().lower() in {h.lower() for h in hosts}


def create_app(session_path: str | Path | None = None, *,
               allowed_roots: Iterable[str | Path] | None = None,
               hosts: Iterable[str] | None = None,
               role: str | None = None) -> pn.viewable.Viewable:
    """Build a fresh app for one browser session.

    Parameters
    ----------
    session_path
        A session to open when the page loads (folder, ``session.toml``, folder of images or
        EMVA1288 descriptor). Its folder is added to the allowed roots: the user named it.
        A bad path shows an alert in the page; the app keeps working.
    allowed_roots
        Folders the user may open sessions from; default: the bundled assets, the home folder
        and the working folder.
    hosts
        When served, the ``name:port`` addresses the server listens on: a request naming
        another host in its ``Host`` header gets one line saying so instead of the app
        (:func:`host_allowed`); ``None`` (a script, a test): no check.
    role
        Every image of ``session_path``, a plain folder, is a frame of this role
        (``ccdcore app FOLDER --role flat``).

    Returns
    -------
    AppTemplate
        A ``panel.template.BootstrapTemplate`` (or, for a request to another host, a Markdown
        pane saying so).
    """
    doc = pn.state.curdoc
    if hosts is not None and doc is not None and doc.session_context is not None:
        host = (pn.state.headers or {}).get("Host")
        if not host_allowed(host, hosts):
            log.warning("refused a request for host %r (serving %s)", host, ", ".join(hosts))
            return pn.pane.Markdown(WRONG_HOST.format(hosts=", ".join(sorted(hosts)),
                                                      host=host))
    extra: list[Path] = []
    if session_path is not None:
        p = Path(session_path).expanduser().resolve()
        extra.append(p if p.is_dir() else p.parent)
    roots = default_roots(extra) if allowed_roots is None else \
        [Path(r).expanduser().resolve() for r in (*allowed_roots, *extra)]
    state = AppState(allowed_roots=roots)
    shell = AppShell(state)

    # Panel's own busy indicator is shared by every browser session of the server (a global
    # list), so one session's events would change another session's document without its lock;
    # each session gets a spinner bound to its own state instead.
    template = AppTemplate(
        design=AppDesign, title=TITLE, sidebar_width=250, header_background="#1f3b57",
        header_color="#ffffff", busy_indicator=None)
    template.header.append(pn.indicators.LoadingSpinner(
        value=state.param.busy, width=22, height=22, color="light", bgcolor="dark",
        margin=(14, 4, 0, 10), sizing_mode="fixed", css_classes=["ccd-busy"]))
    template.header.append(_progress_bar(state))
    template.header.append(pn.pane.HTML(
        pn.bind(_session_header, state.param.session_path, state.param.status,
                state.param.busy),
        stylesheets=[_CSS], sizing_mode="stretch_width", margin=(12, 10)))
    template.sidebar.append(pn.pane.Markdown("#### Pages", margin=(0, 10)))
    template.sidebar.append(shell.nav)
    report_box = ReportBox(state)
    template.sidebar.append(report_box.panel())
    for holder in shell.holders.values():   # one Bokeh root per page
        template.main.append(holder)
    template.config.raw_css.append(_CSS)
    # handles for tests and for later pages
    template.app_state = state  # type: ignore[attr-defined]
    template.app_shell = shell  # type: ignore[attr-defined]
    template.report_box = report_box  # type: ignore[attr-defined]

    if doc is not None and doc.session_context is not None:
        # served: when the browser session ends, its results go (Bokeh destroys a session
        # some seconds after its last connection closed)
        doc.on_session_destroyed(lambda context: shell.close())
    served = doc is not None and doc.session_context is not None
    if served and pn.state.location is not None:
        # the page shown is part of the address (``?page=walkthrough&step=ptc``): a colleague
        # can be sent to it; the page's own state (a Walkthrough step) adds its keys
        pn.state.location.sync(shell, {"page": "page"})
    quick = session_path is not None and quick_to_open(session_path)
    if session_path is not None and (not served or quick):
        # not served (a script or a test), or served and known to open quickly: open it now,
        # so that the first view is drawn with the session (drawing the page empty and then
        # its tables, alerts and texts made the browser lay the page out twice)
        _timed_load(state, session_path, role)
    if served:

        async def _first_view() -> None:  # served: the page shows first, then progress
            if session_path is not None and not quick:
                start = time.perf_counter()
                await state.load_async(str(session_path), role)
                _record_open(session_path, time.perf_counter() - start)
            start_warm_up()               # the other pages' imports, once the first is drawn

        pn.state.onload(_first_view)
    return template


#: the longest time an opening of each session path took in this process (ccdcore_app.main.serve
#: opens the served session once before listening)
_open_seconds: dict[str, float] = {}
#: a session that opened within this many seconds is opened on the event loop while its page is
#: built (the first view is then drawn once, with the session); a slower one opens in a worker
#: thread after the page shows, with progress
QUICK_OPEN_S = 0.5


def _open_key(session_path: str | Path) -> str:
    return str(Path(session_path).expanduser().resolve())


def quick_to_open(session_path: str | Path) -> bool:
    """Whether ``session_path`` always opened within :data:`QUICK_OPEN_S` in this process."""
    return _open_seconds.get(_open_key(session_path), float("inf")) <= QUICK_OPEN_S


def _record_open(session_path: str | Path, seconds: float) -> None:
    """Keep the longest: a copy from the cache of opened sessions is quick, a changed session
    is read again (ccdcore_app.state.open_session_cached)."""
    key = _open_key(session_path)
    _open_seconds[key] = max(_open_seconds.get(key, 0.0), seconds)


def _timed_load(state: AppState, session_path: str | Path, role: str | None = None) -> bool:
    start = time.perf_counter()
    ok = state.load(str(session_path), role)
    _record_open(session_path, time.perf_counter() - start)
    return ok


def measure_open(session_path: str | Path | None, role: str | None = None) -> None:
    """Open ``session_path`` once (outside any browser session) to learn how long it takes."""
    if session_path is None:
        return
    from .state import open_session_cached

    start = time.perf_counter()
    try:
        open_session_cached(Path(session_path).expanduser().resolve(), role)
    except Exception:   # the page says what is wrong, at each visit
        return
    _record_open(session_path, time.perf_counter() - start)


_warm_lock = threading.Lock()
_warmed = False
_warm_thread: threading.Thread | None = None


def start_warm_up() -> None:
    """Run :func:`warm_up` in a background thread, once per process."""
    global _warm_thread
    with _warm_lock:
        if _warm_thread is not None or _warmed:
            return
        _warm_thread = threading.Thread(target=warm_up, name="ccdcore-warm-up", daemon=True)
    _warm_thread.start()


def prepare_first_page() -> None:
    """Import the first page's module and the colour-map registry its views use, and load the
    map reduction's kernels for 8- and 16-bit frames (about 0.6 s; the kernels compile once
    per machine, about 2 s, then load from numba's disk cache)."""
    import importlib

    import numpy as np

    from .image_view import palette

    importlib.import_module(PAGES[0].module)
    palette("gray")
    plots.load_kernels((np.uint8, np.uint16))


def warm_up() -> None:
    """Import, once per process, what the pages need: the pages' modules (pandas, the colour
    maps, HoloViews' plotting), then the estimators' scipy modules (about 1.5 s in all).

    A served app runs this in a background thread (:func:`start_warm_up`) once the first
    browser session has drawn its first view, so no page's first visit or first computation
    waits for an import on the event loop (Python's import lock makes a page built meanwhile
    wait for its own module only).

    The numba kernels (ccdcore's, and the map views' block reduction
    :func:`ccdcore_app.plots.base.overview`) are cached on disk (``cache=True``): loading them
    takes milliseconds. The app does not use datashader, whose kernels numba compiled again in
    every server process (10 s of CPU holding the interpreter against the first pages;
    docs/notes.md).
    """
    global _warmed
    with _warm_lock:
        if _warmed:
            return
        start = time.perf_counter()
        import importlib

        prepare_first_page()
        for spec in PAGES:
            importlib.import_module(spec.module)
        plots.load_kernels()
        import scipy.ndimage  # noqa: F401  (the estimators' imports, off the event loop)
        import scipy.stats  # noqa: F401

        log.info("warm-up took %.1f s", time.perf_counter() - start)
        _warmed = True


def server_resources() -> dict[str, Any]:
    """What a server of the app needs beside the app: its static folder (``pn.serve`` keyword
    arguments), and the app's scripts, registered to load after BokehJS on every page.

    ``app/static/bokeh_speed.js`` makes two BokehJS style reads cheap (docs/notes.md, "Where the
    app's time goes"). It goes into Panel's global ``config.js_files``: BootstrapTemplate does
    not emit a template's own ``js_files``.
    """
    pn.config.js_files["ccd_bokeh_speed"] = f"{STATIC_ROUTE}/bokeh_speed.js"
    return {"static_dirs": {STATIC_ROUTE: str(STATIC_DIR)}}


def check_port(port: int, address: str = "127.0.0.1") -> None:
    """Raise one :class:`~ccdcore.errors.CcdError` line when the app cannot listen on ``port``.

    Checked before anything says "serving on …": Bokeh's own failure comes after that line
    and says "Address already in use" without the port.  The probe binds as Tornado does
    (``SO_REUSEADDR``), so a port left in TIME_WAIT by a stopped app still counts as free.
    """
    import errno
    import socket

    from ccdcore.errors import CcdError

    if not (isinstance(port, int) and 1 <= port <= 65535):
        raise CcdError("--port", f"must be in 1..65535, got {port!r}")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((address, port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise CcdError("--port", f"port {port} is in use: choose another with "
                                         "--port") from None
            raise CcdError("--port", f"cannot listen on {address}:{port}: "
                                     f"{exc.strerror or exc}") from None


def serve(session_path: str | Path | None = None, port: int = 5006, show: bool = False,
          threaded: bool = False, address: str = "127.0.0.1", role: str | None = None) -> Any:
    """Serve the app on ``address:port`` (default 127.0.0.1:5006).

    The first page's module is imported before the server listens; :func:`warm_up` imports
    the other pages' modules in a background thread once a first browser session has drawn its
    first view (earlier, the imports competed with that first view for the interpreter; later,
    a page's first visit would wait for them). ``threaded=True`` returns the running server thread
    (stop it with ``pn.state.kill_all_servers()``); otherwise this blocks until interrupted.
    ``role``: every image of ``session_path``, a plain folder, is a frame of that role.
    """
    check_port(port, address)
    prepare_first_page()
    measure_open(session_path, role)
    # Bokeh checks every model of a page's document before sending it (warnings for a
    # developer: W-1000 ...), some 40-70 ms of each first view's HTML; the tests keep it
    from bokeh.settings import settings as bokeh_settings

    bokeh_settings.perform_document_validation.set_value(False)
    # and it checks the signature of every property callback Panel registers (some 270 for
    # the first view, 25-35 ms): Panel's own callbacks, always well-formed
    bokeh_settings.perform_error_diagnostics.set_value(False)
    origins = [f"{address}:{port}", f"localhost:{port}", f"127.0.0.1:{port}"]

    def app() -> pn.viewable.Viewable:  # a plain function: Panel calls it per session
        return create_app(session_path, hosts=origins, role=role)

    return pn.serve({"/": app}, port=port, address=address, show=show, threaded=threaded,
                    title="ccdcore", liveness=True, websocket_origin=origins, start=True,
                    **server_resources())
