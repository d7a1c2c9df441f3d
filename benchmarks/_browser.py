"""Helpers for timing the served app in headless Chromium (used by ``bench_app.py``).

* :class:`Server` -- ``ccdcore app SESSION --port P`` as a child process: start times, RSS, stop;
* :class:`Liveness` -- a thread polling ``/liveness`` every 50 ms: the server's main-loop stalls;
* :class:`Driver` -- one browser page with an init script that records DOM mutations (in every
  shadow root), browser long tasks and websocket traffic, and :meth:`Driver.settle`, which waits
  until the page is fully drawn after a trigger (a navigation, a click, a key press ...).

"Fully drawn" means, after the trigger: the server answered at least once (a websocket message
arrived); no Panel loading overlay (``.pn-loading``) and no spinning indicator (``.loader.spin``)
is visible; every visible Bokeh canvas (``.bk-Canvas``) has a nonzero size; an optional expected
element is visible; no DOM mutation, long task, websocket message or animation frame happened for
``quiet`` seconds; and (with a :class:`Liveness` poller) a ``/liveness`` request sent at least
:data:`SERVER_LAG` after the last such activity was answered -- Panel acknowledges a browser event
at once and handles it 50 ms later on the server's loop, so a quiet browser alone does not mean
the server is done.  The
time reported is that of the last activity (the quiet window is not counted).
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import threading
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _get(url: str, timeout: float) -> int:
    with urllib.request.urlopen(url, timeout=timeout) as r:
        r.read()
        return r.status


def _status_mb(pid: int, field: str) -> float | None:
    """A ``/proc/PID/status`` memory field (``VmRSS``, ``VmHWM``) of ``pid`` in MB, None if gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) / 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def rss_mb(pid: int) -> float | None:
    """Resident set size of ``pid`` in MB, None if gone."""
    return _status_mb(pid, "VmRSS")


def hwm_mb(pid: int) -> float | None:
    """Peak resident set size of ``pid`` in MB, None if gone."""
    return _status_mb(pid, "VmHWM")


class Server:
    """``cmd`` (a ``ccdcore app ...`` command line) as a child process in its own session, its
    output in ``log``; :meth:`stop` ends it (also on errors: use it as a context manager)."""

    def __init__(self, cmd: Sequence[str], port: int, log: Path):
        self.cmd, self.port, self.log = list(cmd), port, log
        self.url = f"http://127.0.0.1:{port}"
        self.proc: subprocess.Popen | None = None
        self.t_launch = self.t_live = self.t_html = float("nan")

    def __enter__(self) -> "Server":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    def launch(self) -> None:
        self.log.parent.mkdir(parents=True, exist_ok=True)
        out = self.log.open("w")
        self.t_launch = time.time()
        self.proc = subprocess.Popen(self.cmd, stdout=out, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, start_new_session=True)
        out.close()

    def _wait(self, path: str, timeout: float) -> float:
        deadline = time.time() + timeout
        while True:
            if self.proc is not None and self.proc.poll() is not None:
                raise RuntimeError(f"the server exited with code {self.proc.returncode}; "
                                   f"see {self.log}")
            try:
                if _get(self.url + path, timeout=5) == 200:
                    return time.time()
            except (urllib.error.URLError, ConnectionError, TimeoutError, OSError):
                pass
            if time.time() > deadline:
                raise RuntimeError(f"{self.url}{path} did not answer within {timeout:.0f} s; "
                                   f"see {self.log}")
            time.sleep(0.02)

    def wait_live(self, timeout: float = 300) -> None:
        self.t_live = self._wait("/liveness", timeout)

    def wait_html(self, timeout: float = 300) -> None:
        self.t_html = self._wait("/", timeout)

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    def rss(self) -> float | None:
        return rss_mb(self.pid) if self.proc is not None else None

    def hwm(self) -> float | None:
        return hwm_mb(self.pid) if self.proc is not None else None

    def stop(self) -> None:
        """Terminate the server (SIGTERM, then SIGKILL after 10 s) and its process group."""
        proc, self.proc = self.proc, None
        if proc is None or proc.poll() is not None:
            return
        for sig, wait in ((signal.SIGTERM, 10), (signal.SIGKILL, 5)):
            try:
                os.killpg(proc.pid, sig)   # its own group (start_new_session): only its processes
            except ProcessLookupError:
                return
            try:
                proc.wait(wait)
                return
            except subprocess.TimeoutExpired:
                continue


class Liveness(threading.Thread):
    """Polls ``url`` every ``interval`` s (one request at a time); keeps (start, end, ok) of
    each request (epoch seconds)."""

    def __init__(self, url: str, interval: float = 0.05):
        super().__init__(daemon=True, name="liveness")
        self.url, self.interval = url, interval
        self.samples: list[tuple[float, float, bool]] = []
        self._halt = threading.Event()

    def run(self) -> None:
        while not self._halt.is_set():
            t0 = time.time()
            try:
                ok = _get(self.url, timeout=120) == 200
            except (urllib.error.URLError, ConnectionError, TimeoutError, OSError):
                ok = False
            self.samples.append((t0, time.time(), ok))
            self._halt.wait(self.interval)

    def stop(self) -> None:
        self._halt.set()
        self.join(timeout=130)

    def answered_after(self, t: float) -> bool:
        """Whether a request sent at or after ``t`` (epoch s) has been answered."""
        return any(t0 >= t and ok for t0, _, ok in reversed(self.samples[-20:]))

    def window(self, a: float, b: float, slow: float = 0.2) -> tuple[float, int]:
        """Longest response time of the requests overlapping [a, b] and how many took > slow."""
        durs = [t1 - t0 for t0, t1, _ in list(self.samples) if t0 < b and t1 > a]
        return (max(durs) if durs else float("nan"), sum(d > slow for d in durs))


# ----------------------------------------------------------------------------- the page -------
#: installed before any page script: records activity into window.__bench (epoch milliseconds)
INIT_JS = r"""
(() => {
  if (window.__bench) return;
  const now = () => performance.timeOrigin + performance.now();
  const B = window.__bench = {roots: [], lastMutation: 0, mutations: 0, longtasks: [],
                              recv: 0, lastRecv: 0, sent: 0, lastRaf: 0, inputAt: 0};
  try {
    new PerformanceObserver(list => {
      for (const e of list.getEntries())
        B.longtasks.push([performance.timeOrigin + e.startTime, e.duration]);
    }).observe({type: 'longtask', buffered: true});
  } catch (e) { B.noLongtask = String(e); }
  const opts = {subtree: true, childList: true, attributes: true, characterData: true};
  const mo = new MutationObserver(recs => { B.lastMutation = now(); B.mutations += recs.length; });
  const attach = Element.prototype.attachShadow;
  Element.prototype.attachShadow = function (init) {
    const root = attach.call(this, init);
    try { mo.observe(root, opts); B.roots.push(root); } catch (e) {}
    return root;
  };
  const observeDoc = () => mo.observe(document, opts);
  if (document) observeDoc(); else addEventListener('DOMContentLoaded', observeDoc);
  const WS = window.WebSocket;
  const Hooked = function (...args) {
    const ws = new WS(...args);
    ws.addEventListener('message', () => { B.recv++; B.lastRecv = now(); });
    const send = ws.send;
    ws.send = function (data) { B.sent++; return send.call(this, data); };
    return ws;
  };
  Hooked.prototype = WS.prototype;
  for (const k of ['CONNECTING', 'OPEN', 'CLOSING', 'CLOSED']) Hooked[k] = WS[k];
  window.WebSocket = Hooked;
  const raf = window.requestAnimationFrame.bind(window);
  window.requestAnimationFrame = cb => raf(t => { try { return cb(t); }
                                                  finally { B.lastRaf = now(); } });
  for (const type of ['pointerdown', 'keydown', 'input'])
    addEventListener(type, () => { if (!B.inputAt) B.inputAt = now(); }, true);
})();
"""

#: the page's current state as seen by :meth:`Driver.settle`
STATE_JS = r"""
() => {
  const B = window.__bench;
  if (!B) return null;
  const vis = el => el.checkVisibility ? el.checkVisibility() : el.getClientRects().length > 0;
  const roots = [document];
  for (const r of B.roots) if (r.host && r.host.isConnected) roots.push(r);
  let loading = 0, spinning = 0, plots = 0, empty = 0;
  const alerts = [];
  for (const r of roots) {
    for (const el of r.querySelectorAll('.alert-danger'))
      if (vis(el) && el.textContent.trim()) alerts.push(el.textContent.trim().slice(0, 160));
    for (const el of r.querySelectorAll('.pn-loading')) if (vis(el)) loading++;
    for (const el of r.querySelectorAll('.loader.spin')) if (vis(el)) spinning++;
    for (const el of r.querySelectorAll('.bk-Canvas')) {
      if (!vis(el)) continue;
      plots++;
      const box = el.getBoundingClientRect();
      const canvases = [...el.querySelectorAll('canvas'),
                        ...(el.shadowRoot ? el.shadowRoot.querySelectorAll('canvas') : [])];
      const drawn = canvases.some(c => c.width > 0 && c.height > 0);
      if (!(box.width > 0 && box.height > 0 && drawn)) empty++;
    }
  }
  let lastLong = 0;
  for (const [t, d] of B.longtasks) lastLong = Math.max(lastLong, t + d);
  return {now: performance.timeOrigin + performance.now(), lastMutation: B.lastMutation,
          lastLong, lastRecv: B.lastRecv, lastRaf: B.lastRaf, recv: B.recv,
          inputAt: B.inputAt, loading, spinning, plots, empty, alerts,
          noLongtask: B.noLongtask || ''};
}
"""

#: total duration (ms) of the long tasks overlapping [a, b] (epoch ms)
LONGTASKS_JS = r"""
([a, b]) => {
  let total = 0;
  for (const [t, d] of window.__bench.longtasks)
    total += Math.max(0, Math.min(b, t + d) - Math.max(a, t));
  return total;
}
"""


#: s after the last activity from which the server's loop must answer /liveness: Panel handles
#: a browser event 50 ms (its debounce) after acknowledging it, so an earlier answer proves nothing
SERVER_LAG = 0.1


@dataclass
class Settled:
    """One trigger's outcome: ``seconds`` to fully drawn (None unless ``status`` is 'ok')."""

    seconds: float | None
    status: str                        # 'ok', 'timeout', 'error', 'n/a'
    t0: float = float("nan")           # trigger (epoch s)
    t1: float = float("nan")           # the last activity, or when given up (epoch s)
    t_end: float = float("nan")        # when the wait ended (epoch s; t1 + the quiet window)
    longtasks: float = float("nan")    # s of browser long tasks in [t0, t1]
    plots: int = 0
    detail: str = ""
    stall: float = float("nan")        # filled in later from the Liveness samples
    slow: int = 0


@dataclass
class Driver:
    """One browser page (its context must have had :data:`INIT_JS` added)."""

    page: Any
    quiet: float = 0.3
    timeout: float = 120.0
    liveness: Liveness | None = None   # when given, the server must have answered after the
                                       # last activity (its event loop was free)
    raf: bool = True                   # count animation frames as activity
    idle: bool = False                 # Bokeh logged "document idle"
    server_errors: list[str] = field(default_factory=list)
    console_errors: list[str] = field(default_factory=list)
    failed_requests: list[str] = field(default_factory=list)
    last_error: str = ""

    def __post_init__(self) -> None:
        self.page.on("console", self._console)
        self.page.on("pageerror", lambda e: self.console_errors.append(f"page error: {e}"))
        self.page.on("requestfailed", lambda r: self.failed_requests.append(r.url))

    def _console(self, msg: Any) -> None:
        text = msg.text
        if "document idle" in text:
            self.idle = True
        if "ERROR reply" in text:
            self.server_errors.append(text)
        elif msg.type == "error":
            self.console_errors.append(text)

    def state(self) -> dict | None:
        """The page's state (:data:`STATE_JS`), None while no document is ready."""
        try:
            return self.page.evaluate(STATE_JS)
        except Exception as err:  # a navigation destroyed the context: ask again later
            if self.page.is_closed():
                raise
            self.last_error = str(err)
            return None

    def settle(self, trigger: Callable[[], Any], *, expect: Any = None, need_idle: bool = False,
               navigation: bool = False) -> Settled:
        """Run ``trigger`` and wait until the page is fully drawn (see the module's doc).

        ``expect``: a Playwright locator that must be visible; ``need_idle``: Bokeh must have
        logged "document idle"; ``navigation``: the trigger loads a new document (its time
        starts when ``trigger`` is called, not at the first input event).
        """
        page = self.page
        recv0 = 0
        if not navigation:
            recv0 = page.evaluate("() => { window.__bench.inputAt = 0; "
                                  "return window.__bench.recv; }")
        n_errors = len(self.server_errors)
        t_call = time.time()
        try:
            trigger()
        except Exception as err:  # the element vanished, the click was refused ...
            return Settled(None, "error", t_call, time.time(), time.time(),
                           detail=f"trigger failed: {type(err).__name__}: "
                                  f"{str(err).splitlines()[0][:160]}")
        deadline = t_call + self.timeout
        t0 = t_call
        error_deadline = None
        last: dict | None = None
        pending: list[str] = []
        while True:
            s = self.state()
            if s is not None:
                last = s
                if not navigation and s["inputAt"] and t0 == t_call:
                    t0 = max(t_call, s["inputAt"] / 1000)
                acts = [s["lastMutation"], s["lastLong"], s["lastRecv"]]
                if self.raf:
                    acts.append(s["lastRaf"])
                activity = max(acts) / 1000
                pending = []
                if s["recv"] <= recv0:
                    pending.append("no message from the server yet")
                if s["loading"]:
                    pending.append(f"{s['loading']} loading overlay(s)")
                if s["spinning"]:
                    pending.append("busy spinner")
                if s["empty"]:
                    pending.append(f"{s['empty']} of {s['plots']} plots with an empty canvas")
                if need_idle and not self.idle:
                    pending.append("Bokeh document not idle")
                if not pending and expect is not None:
                    try:
                        if not expect.first.is_visible():
                            pending.append("expected content not visible")
                    except Exception:
                        pending.append("expected content not visible")
                quiet_since = max(activity, t0)
                if (not pending and self.liveness is not None
                        and not self.liveness.answered_after(quiet_since + SERVER_LAG)):
                    # Panel acknowledges a browser event at once and handles it SERVER_LAG
                    # later (its debounce): a loop busy with it answers /liveness late
                    pending.append("the server's event loop has not answered since")
                if not pending and s["now"] / 1000 - quiet_since >= self.quiet:
                    alerts = "; ".join(s["alerts"])
                    return self._done(Settled(quiet_since - t0, "ok", t0, quiet_since,
                                              s["now"] / 1000, plots=s["plots"],
                                              detail=f"error alert shown: {alerts}"
                                              if alerts else ""))
            if len(self.server_errors) > n_errors and error_deadline is None:
                error_deadline = time.time() + 5.0
            now = time.time()
            if error_deadline is not None and now > error_deadline:
                text = self.server_errors[n_errors]
                return self._done(Settled(None, "error", t0, now, now,
                                          plots=last["plots"] if last else 0,
                                          detail="server error: " + text[:200]))
            if now > deadline:
                return self._done(Settled(None, "timeout", t0, now, now,
                                          plots=last["plots"] if last else 0,
                                          detail="still pending: " + ("; ".join(pending)
                                                                      or "activity")))
            page.wait_for_timeout(50)

    def _done(self, r: Settled) -> Settled:
        try:
            r.longtasks = self.page.evaluate(LONGTASKS_JS, [r.t0 * 1000, r.t1 * 1000]) / 1000
        except Exception:
            pass
        return r
