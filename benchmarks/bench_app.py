"""The served app in headless Chromium: start, first view, page switches, widget changes, stalls
and memory.

Starts ``ccdcore app SESSION --port P`` as a child process and times, with Playwright driving
Debian's Chromium:

* **server start**: from launching the process until ``/liveness`` answers 200, and until the
  first page's HTML answers (that request opens one server session, never connected);
* **first view**: from ``page.goto`` until the Session page is fully drawn with the session loaded
  ("Session: NAME" in the header or "Loaded NAME" on the page, no spinner);
* **page switches**: from the click on the sidebar button of "Photon transfer", "Maps" and
  "Flat field" until fully drawn, on the first visit and on a revisit;
* **widget changes**: on Photon transfer, unticking the last checked level of the fit; on Maps,
  choosing another map in "Selected map" and moving the upper handle of the colour range one
  step (each "n/a" when the page has no such widget).

"Fully drawn" (``_browser.Driver.settle``): the server answered, no Panel loading overlay nor
spinning indicator is visible, every visible Bokeh canvas has a nonzero size, the page title (or
the session name) is visible, and no DOM mutation (in any shadow root), browser long task,
websocket message or animation frame followed for 0.3 s; the time reported is that of the last
such activity, not the end of the quiet window; the server's event loop must also have answered
``/liveness`` from 0.1 s after it (Panel acknowledges an event at once and handles it 50 ms later).

Meanwhile a thread asks ``/liveness`` every 50 ms: its longest response time during a phase is how
long the server's event loop was blocked (a stall every browser session feels).  "long tasks" is
the total duration of the browser's long tasks (> 50 ms of main-thread work) during the phase.

Each of ``--repeat`` runs is one full visit: a new browser context and page, the first view, every
page (first visits, widget changes, revisits), then the context is closed.  The server's RSS is
read after start, after each visit, and then every second for ``--linger`` seconds while the Bokeh
server destroys the closed sessions (unused-session lifetime 15 s, checked every 17 s).

    .venv/bin/python benchmarks/bench_app.py                  # the bundled demo assets/healey94
    .venv/bin/python benchmarks/bench_app.py --big            # a 2048x2048 healey94 simulation
    .venv/bin/python benchmarks/bench_app.py --session PATH [--repeat 3] [--port 5006]
    .venv/bin/python benchmarks/bench_app.py --baseline [--repeat 9]   # first view vs a bare page

``--baseline`` times only first views, the app's against a bare Panel page served by a second
child process (``benchmarks/_bare_app.py``: the app's template class, design, title, header,
raw CSS, extensions and scripts, but one Markdown pane "Loaded NAME" as its content), with the
same "fully drawn" criterion: one discarded warm-up first view of each, then ``--repeat`` pairs
alternating bare, app, bare, app ... (each in a new browser context), so that a load from
another job on the machine falls on both alike; it prints both medians and their ratio.

``--big`` writes the session once into ``benchmarks/_data/app_healey94_2048`` (gitignored) with
``ccdcore simulate healey94 DIR --seed 1 --size 2048x2048`` in a child process.  The server's
output goes to ``benchmarks/_out/bench_app_server.log``.
"""
from __future__ import annotations

import argparse
import re
import shutil
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import _browser  # noqa: E402
import _report  # noqa: E402
from _browser import Settled  # noqa: E402

PAGES = ("Photon transfer", "Maps", "Flat field")
BIG = "2048x2048"
VIEWPORT = {"width": 1400, "height": 1000}


def ccdcore_cmd() -> list[str]:
    """The ``ccdcore`` console script next to this Python (the project's virtualenv)."""
    exe = Path(sys.executable).parent / "ccdcore"
    if exe.is_file():
        return [str(exe)]
    found = shutil.which("ccdcore")
    if found is None:
        sys.exit("bench_app: the ccdcore command is missing (pip install -e . in the venv)")
    return [found]


def big_session() -> Path:
    """The 2048x2048 healey94 simulation under benchmarks/_data (written once, in a child)."""
    folder = HERE / "_data" / "app_healey94_2048"
    if (folder / "session.toml").is_file():
        return folder
    if folder.exists():
        shutil.rmtree(folder)       # a half-written folder from an interrupted run
    folder.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    print(f"writing the {BIG} session into {folder} ...", flush=True)
    subprocess.run([*ccdcore_cmd(), "simulate", "healey94", str(folder), "--seed", "1",
                    "--size", BIG], check=True, stdout=subprocess.DEVNULL)
    print(f"  written in {time.perf_counter() - t0:.0f} s", flush=True)
    return folder


# ------------------------------------------------------------------------------ one visit -----
class Visit:
    """One browser page visiting the whole app; results go to ``phases[name]`` (lists)."""

    def __init__(self, driver: _browser.Driver, url: str, session_name: str,
                 phases: dict[str, list[Settled]]):
        self.d, self.page, self.url = driver, driver.page, url
        self.session_name, self.phases = session_name, phases

    def record(self, name: str, result: Settled) -> Settled:
        self.phases.setdefault(name, []).append(result)
        return result

    def nav_button(self, word: str) -> Any:
        """The sidebar button whose label contains ``word`` (the first such button anywhere if
        the template has no #sidebar)."""
        name = re.compile(re.escape(word))
        sidebar = self.page.locator("#sidebar")
        scope = sidebar if sidebar.count() else self.page
        return scope.get_by_role("button", name=name).first

    def title(self, word: str) -> Any:
        return self.page.get_by_role("heading", name=re.compile(re.escape(word)))

    def first_view(self) -> Settled:
        # the header ("Session: NAME") or the Session page's status ("Loaded NAME: ...")
        expect = self.page.get_by_text(re.compile(
            rf"(Session:\s*|Loaded ){re.escape(self.session_name)}"))
        return self.record("first view (Session)", self.d.settle(
            lambda: self.page.goto(self.url), navigation=True, need_idle=True, expect=expect))

    def switch(self, word: str, label: str) -> Settled:
        return self.record(f"{label} {word}", self.d.settle(
            lambda: self.nav_button(word).click(), expect=self.title(word)))

    def widget(self, name: str, find: Callable[[], tuple[Any, Callable[[], Any]] | None],
               page_ok: bool) -> Settled:
        """``find()`` -> (expected locator or None, trigger) or None when the page has no such
        widget."""
        if not page_ok:
            return self.record(name, Settled(None, "n/a", detail="the page was not drawn"))
        try:
            found = find()
        except Exception as err:   # re-rendered under us, a changed widget ...
            found = None
            detail = f"{type(err).__name__}: {str(err).splitlines()[0][:120]}"
        else:
            detail = "no such widget on the page"
        if found is None:
            return self.record(name, Settled(None, "n/a", detail=detail))
        expect, trigger = found
        return self.record(name, self.d.settle(trigger, expect=expect))

    # ---- the widgets ------------------------------------------------------------------------
    def untick_level(self) -> tuple[Any, Callable[[], Any]] | None:
        boxes = self.page.get_by_role("checkbox", name=re.compile(r"^\s*Level\b"))
        checked = [b for b in boxes.all() if b.is_visible() and b.is_checked()]
        if len(checked) < 2:
            return None
        return None, checked[-1].click

    def choose_map(self) -> tuple[Any, Callable[[], Any]] | None:
        select = self.page.get_by_role("combobox", name=re.compile("Selected map"))
        if select.count() == 0:
            return None
        select = select.first
        index, n = select.evaluate("e => [e.selectedIndex, e.options.length]")
        if n < 2:
            return None
        return None, lambda: select.select_option(index=(index + 1) % n)

    def colour_range(self) -> tuple[Any, Callable[[], Any]] | None:
        handles = self.page.locator(".noUi-handle-upper")
        shown = [handles.nth(i) for i in range(handles.count()) if handles.nth(i).is_visible()]
        if not shown:          # (visited pages stay in the document, hidden)
            return None
        handle = shown[0]

        def move() -> None:
            handle.focus()
            handle.press("ArrowLeft")

        return None, move

    # ---- the whole visit ----------------------------------------------------------------------
    def run(self) -> None:
        self.first_view()
        ok: dict[str, bool] = {}
        for word in PAGES:
            ok[word] = self.switch(word, "first visit").status == "ok"
            if word == "Photon transfer":
                self.widget("Photon transfer: untick a level", self.untick_level, ok[word])
            elif word == "Maps":
                self.widget("Maps: choose another map", self.choose_map, ok[word])
                self.widget("Maps: colour range one step", self.colour_range, ok[word])
        for word in PAGES:
            self.switch(word, "revisit")


# ------------------------------------------------------------------------------ baseline ------
def baseline(args: argparse.Namespace, session: Path, timeout: float) -> None:
    """``--baseline``: the app's first view against a bare Panel page's, alternating."""
    from playwright.sync_api import sync_playwright

    port_app = args.port or _browser.free_port()
    port_bare = _browser.free_port()
    while port_bare == port_app:
        port_bare = _browser.free_port()
    servers = {
        "bare": _browser.Server([sys.executable, str(HERE / "_bare_app.py"), session.name,
                                 "--port", str(port_bare)], port_bare,
                                HERE / "_out" / "bench_app_bare_server.log"),
        "app": _browser.Server([*ccdcore_cmd(), "app", str(session), "--port", str(port_app)],
                               port_app, HERE / "_out" / "bench_app_server.log"),
    }
    pollers = {k: _browser.Liveness(s.url + "/liveness") for k, s in servers.items()}
    runs: dict[str, list[Settled]] = {"bare": [], "app": []}
    warm: dict[str, Settled] = {}
    notes: list[str] = []
    try:
        for k, server in servers.items():    # one after the other: no start competes
            server.launch()
            server.wait_live()
            pollers[k].start()
            server.wait_html()
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=_browser.CHROMIUM,
                                         args=_browser.CHROMIUM_ARGS)

            def first_view(k: str) -> Settled:
                context = browser.new_context(viewport=VIEWPORT)
                context.add_init_script(_browser.INIT_JS)
                driver = _browser.Driver(context.new_page(), quiet=args.quiet,
                                         timeout=timeout, liveness=pollers[k])
                phases: dict[str, list[Settled]] = {}
                try:
                    r = Visit(driver, servers[k].url, session.name, phases).first_view()
                finally:
                    context.close()
                r.stall, r.slow = pollers[k].window(r.t0, r.t_end)
                notes.extend(f"{k}: server error: {e[:160]}" for e in driver.server_errors)
                notes.extend(f"{k}: console: {e[:160]}" for e in driver.console_errors)
                notes.extend(f"{k}: failed request: {u}" for u in driver.failed_requests)
                return r

            try:
                for k in servers:                # warm-up, discarded
                    warm[k] = first_view(k)
                for i in range(args.repeat):
                    for k in ("bare", "app"):
                        runs[k].append(first_view(k))
                    print(f"pair {i + 1} of {args.repeat}: bare "
                          f"{_fmt(runs['bare'][-1].seconds)} s, app "
                          f"{_fmt(runs['app'][-1].seconds)} s", file=sys.stderr, flush=True)
            finally:
                browser.close()
    finally:
        for k, server in servers.items():
            if pollers[k].is_alive():
                pollers[k].stop()
            server.stop()

    print(f"session {session.name}; first view only, {args.repeat} pair(s) alternating bare, app "
          "(each after one discarded warm-up first view); 'bare' is benchmarks/_bare_app.py, "
          "the app's template, design and resources around one Markdown pane")
    print(f"{'page':10s}{'seconds median (min–max)':>28s}{'ok':>5s}{'stall max s':>13s}"
          f"{'long tasks s':>14s}{'plots':>7s}   runs (s)")
    medians: dict[str, float] = {}
    for k in ("bare", "app"):
        good = [r.seconds for r in runs[k] if r.status == "ok" and r.seconds is not None]
        stalls = [r.stall for r in runs[k] if r.stall == r.stall]
        longs = [r.longtasks for r in runs[k] if r.longtasks == r.longtasks]
        if good:
            medians[k] = statistics.median(good)
        print(f"{k:10s}{_report.summary(good).format('.2f') if good else 'none':>28s}"
              f"{f'{len(good)}/{len(runs[k])}':>5s}"
              f"{_fmt(max(stalls) if stalls else None):>13s}"
              f"{_fmt(statistics.median(longs) if longs else None):>14s}"
              f"{'/'.join(map(str, sorted({r.plots for r in runs[k]}))):>7s}   "
              + " ".join(_fmt(r.seconds) if r.status == "ok" else r.status for r in runs[k]))
    print(f"warm-up (discarded): bare {_fmt(warm.get('bare', Settled(None, '')).seconds)} s, "
          f"app {_fmt(warm.get('app', Settled(None, '')).seconds)} s")
    if len(medians) == 2:
        print(f"first view: bare {medians['bare']:.2f} s, app {medians['app']:.2f} s, "
              f"ratio app/bare {medians['app'] / medians['bare']:.2f}")
    failed = [(k, r) for k in runs for r in runs[k] if r.status != "ok" or r.detail]
    if failed:
        print("\nruns that did not settle or showed an error alert:")
        for k, r in failed:
            print(f"  {k}: {r.status} {r.detail}")
    if notes:
        print("\nnotes: server errors, browser console errors, failed requests (deduplicated):")
        for n in sorted(set(notes)):
            print(f"  {n}")
    _report.footer()


# ------------------------------------------------------------------------------ output --------
def _fmt(v: float | None, fmt: str = ".2f") -> str:
    return "–" if v is None or v != v else f"{v:{fmt}}"


def table(phases: dict[str, list[Settled]]) -> list[str]:
    head = (f"{'phase':38s}{'seconds median (min–max)':>28s}{'ok':>5s}{'stall max s':>13s}"
            f"{'>0.2 s':>8s}{'long tasks s':>14s}{'plots':>7s}")
    lines = [head]
    for name, results in phases.items():
        good = [r for r in results if r.status == "ok" and r.seconds is not None]
        secs = (_report.summary([r.seconds for r in good]).format(".2f") if good else
                "/".join(sorted({r.status for r in results})))
        stalls = [r.stall for r in results if r.stall == r.stall]
        longs = [r.longtasks for r in results if r.longtasks == r.longtasks]
        plots = sorted({r.plots for r in good})
        lines.append(
            f"{name:38s}{secs:>28s}{f'{len(good)}/{len(results)}':>5s}"
            f"{_fmt(max(stalls) if stalls else None):>13s}{sum(r.slow for r in results):>8d}"
            f"{_fmt(statistics.median(longs) if longs else None):>14s}"
            f"{'/'.join(map(str, plots)) if plots else '–':>7s}")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--session", type=Path, default=None,
                    help="session to serve (default: assets/healey94)")
    ap.add_argument("--big", action="store_true",
                    help=f"serve a {BIG} healey94 simulation (written once under _data)")
    ap.add_argument("--repeat", type=int, default=3, help="full visits (default 3)")
    ap.add_argument("--port", type=int, default=0, help="server port (default: a free one)")
    ap.add_argument("--timeout", type=float, default=None,
                    help="seconds to wait for one phase (default 120, 600 with --big)")
    ap.add_argument("--linger", type=float, default=45.0,
                    help="seconds to watch the RSS after the last visit (default 45)")
    ap.add_argument("--quiet", type=float, default=0.3,
                    help="quiet window that ends a phase, s (default 0.3; not counted)")
    ap.add_argument("--baseline", action="store_true",
                    help="time only first views, alternating with a bare Panel page of the "
                         "app's template (benchmarks/_bare_app.py); print both medians and "
                         "the ratio")
    args = ap.parse_args()
    if args.big and args.session is not None:
        ap.error("--big and --session exclude each other")
    timeout = args.timeout or (600.0 if args.big else 120.0)

    # an ordinary `kill` must still stop the server (the finally clauses below)
    signal.signal(signal.SIGTERM, lambda *a: sys.exit(143))
    session = big_session() if args.big else (args.session or HERE.parent / "assets/healey94")
    session = session.expanduser().resolve()
    if not session.exists():
        sys.exit(f"bench_app: {session} does not exist")
    port = args.port or _browser.free_port()

    _report.header(Path(__file__).name, repeat=args.repeat, warmup=1 if args.baseline else 0,
                   note=("first view against a bare page (--baseline); " if args.baseline
                         else "")
                   + f"session: {session}; Chromium {_browser.CHROMIUM} headless, viewport "
                     f"{VIEWPORT['width']}x{VIEWPORT['height']}; quiet window "
                     f"{args.quiet:g} s; phase timeout {timeout:g} s")
    if args.baseline:
        baseline(args, session, timeout)
        return
    from playwright.sync_api import sync_playwright

    phases: dict[str, list[Settled]] = {}
    memory: list[tuple[str, float | None]] = []
    notes: list[str] = []
    server = _browser.Server([*ccdcore_cmd(), "app", str(session), "--port", str(port)], port,
                             HERE / "_out" / "bench_app_server.log")
    poller = _browser.Liveness(server.url + "/liveness")
    try:
        server.launch()
        server.wait_live()
        poller.start()
        server.wait_html()
        phases["server start: /liveness answers"] = [Settled(
            server.t_live - server.t_launch, "ok", server.t_launch, server.t_live,
            server.t_live)]
        phases["server start: first page HTML"] = [Settled(
            server.t_html - server.t_launch, "ok", server.t_live, server.t_html,
            server.t_html)]
        memory.append(("after start (first HTML)", server.rss()))
        drivers: list[_browser.Driver] = []
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=_browser.CHROMIUM,
                                         args=_browser.CHROMIUM_ARGS)
            try:
                for i in range(args.repeat):
                    context = browser.new_context(viewport=VIEWPORT)
                    context.add_init_script(_browser.INIT_JS)
                    driver = _browser.Driver(context.new_page(), quiet=args.quiet,
                                             timeout=timeout, liveness=poller)
                    drivers.append(driver)
                    try:
                        Visit(driver, server.url, session.name, phases).run()
                    except Exception as err:   # a crashed page: keep the figures so far
                        notes.append(f"visit {i + 1} aborted: {type(err).__name__}: "
                                     f"{str(err).splitlines()[0][:160]}")
                    finally:
                        context.close()
                    memory.append((f"after visit {i + 1}", server.rss()))
                    print(f"visit {i + 1} of {args.repeat} done", file=sys.stderr, flush=True)
            finally:
                browser.close()
        t_closed = time.time()
        series = []
        while time.time() - t_closed < args.linger:
            time.sleep(1.0)
            series.append((time.time() - t_closed, server.rss()))
        for k in range(10, int(args.linger) + 10, 10):   # about every 10 s, and the last
            t, rss = next(((t, m) for t, m in series if t >= k - 0.5), series[-1])
            if not memory[-1][0].startswith(f"{t:.0f} s "):
                memory.append((f"{t:.0f} s after the last visit closed", rss))
        memory.append(("peak (VmHWM)", server.hwm()))
        poller.stop()
        for results in phases.values():
            for r in results:
                r.stall, r.slow = poller.window(r.t0, r.t_end)
        for d in drivers:
            notes += [f"server error: {e[:160]}" for e in d.server_errors]
            notes += [f"console: {e[:160]}" for e in d.console_errors]
            notes += [f"failed request: {u}" for u in d.failed_requests]
    finally:
        if poller.is_alive():
            poller.stop()
        server.stop()

    print(f"session {session.name}; server start measured once, every other phase over "
          f"{args.repeat} visit(s); 'stall max' is the longest /liveness response during the "
          "phase (max over visits), '>0.2 s' how many responses took longer (all visits), "
          "'long tasks' the browser's long-task total (median), 'plots' the Bokeh canvases "
          "drawn")
    for line in table(phases):
        print(line)
    failed = [(name, r) for name, rs in phases.items() for r in rs
              if r.status != "ok" or r.detail]
    if failed:
        print()
        print("phases that did not settle, were skipped or showed an error alert:")
        for name, r in failed:
            print(f"  {name}: {r.status} {r.detail}")
    print()
    print("server RSS (MB):")
    for label, rss in memory:
        print(f"  {label:36s}{_fmt(rss, '.0f'):>8s}")
    whole = [(t0, t1) for t0, t1, _ in poller.samples]
    if whole:
        longest = max(t1 - t0 for t0, t1 in whole)
        print(f"\n/liveness over the whole run: {len(whole)} requests, longest {longest:.2f} s, "
              f"{sum(t1 - t0 > 0.2 for t0, t1 in whole)} over 0.2 s")
    if notes:
        print()
        print("notes: server errors, browser console errors, failed requests (deduplicated):")
        for n in sorted(set(notes)):
            print(f"  {n}")
    _report.footer()


if __name__ == "__main__":
    main()
