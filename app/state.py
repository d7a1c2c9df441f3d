"""The app's one state object, shared by every page of a browser session.

Public objects
--------------
AppState
    The loaded capture session, the computed results and the user-facing status: ``load(path)``
    (and its off-the-UI-thread twin ``load_async``) opens a session and turns any bad input into
    an ``error`` message instead of an exception.
Results
    The results the pages compute and share, as typed attributes (``ptc``, ``ptc_points``,
    ``estimates`` and its parts ``dark``, ``fixed_pattern``, ``plan``, ``scene``,
    ``correction_check``; the Flat field page's caches in ``flat``), cleared on a new session.
FlatResults
    The Flat field page's results, cached by offset setting and base group.
assets_dir()
    The bundled demo sessions folder (``<repo>/assets``).
demo_sessions(assets=None)
    Name -> folder of the bundled demo sessions (sub-folders holding ``session.toml``).
default_roots(extra=())
    The folders the user may open sessions from: the assets, the home and the working folder.
is_allowed(path, roots)
    Whether ``path`` lies inside one of ``roots``.

Finished results are kept on disk (:mod:`ccdcore_app.cache.store`) by
:meth:`AppState.cached_compute`, keyed by the session's content hash: a session reopened (in this
or another browser session, or after a restart) shows them without computing again.
:meth:`AppState.shared_compute` also shares them in memory between the browser sessions of one
server (:class:`ccdcore_app.cache.store.SharedResults`): a computation one session started is
waited for by the others, never started twice.
"""
from __future__ import annotations

import asyncio
import copy
import logging
import os
import threading
import traceback
from collections import OrderedDict
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import param

from ccdcore.dark.frame import DarkReference
from ccdcore.errors import CcdError
from ccdcore.fixedpattern import CorrectionCheck, FixedPattern
from ccdcore.flatfield.fit import SettingsComparison
from ccdcore.noise import PhotonTransfer
from ccdcore.planning import AcquisitionPlan
from ccdcore.product.make import Estimates
from ccdcore.progress import Cancelled, Tracker, tracking
from ccdcore.scene import SceneVariation
from ccdcore.session import MANIFEST_NAME, Session, open_session
from ccdcore.simulate.demos import ensure_demos, user_demos_dir

from .cache.store import ResultCache, SharedResults, code_version, default_cache, shared_results

__all__ = ["AppState", "Results", "FlatResults", "ASSETS_ENV", "assets_dir", "demo_sessions",
           "default_roots", "is_allowed"]

log = logging.getLogger(__name__)


#: environment variable naming another demo sessions folder (e.g. for an installed package)
ASSETS_ENV = "CCDCORE_ASSETS"


def assets_dir() -> Path:
    """The demo sessions' folder: ``<repo>/assets`` next to the ``ccdcore_app`` package in a
    checkout; for an installed package (no ``assets`` beside it), the user's demos folder
    (:func:`ccdcore.simulate.demos.user_demos_dir`), where :func:`demo_sessions` writes them on
    first use.

    The environment variable ``CCDCORE_ASSETS``, when set, names another folder instead.
    """
    override = os.environ.get(ASSETS_ENV)
    if override:
        return Path(override).expanduser().resolve()
    import ccdcore_app

    repo = Path(ccdcore_app.__file__).resolve().parents[1] / "assets"
    if (repo / "regenerate.py").is_file():
        return repo
    return user_demos_dir()


def demo_sessions(assets: Path | None = None) -> dict[str, Path]:
    """Name -> folder of every demo session (a sub-folder of ``assets`` with ``session.toml``).

    In the user's demos folder of an installed package the demos it lacks are written first
    (the simulators, deterministic, about 3 s once); a folder that cannot be written to gives
    the demos it has, with a logged warning."""
    assets = assets_dir() if assets is None else Path(assets)
    if assets == user_demos_dir():
        try:
            ensure_demos(assets, say=log.warning)
        except (OSError, CcdError) as exc:
            log.warning("cannot write the demo sessions into %s: %s", assets, exc)
    if not assets.is_dir():
        return {}
    return {p.name: p for p in sorted(assets.iterdir())
            if p.is_dir() and (p / MANIFEST_NAME).is_file()}


def default_roots(extra: Iterable[str | Path] = ()) -> list[Path]:
    """Folders sessions may be opened from: the assets, ``~``, the working folder, ``extra``."""
    roots: list[Path] = []
    for p in (assets_dir(), Path.home(), Path.cwd(), *extra):
        rp = Path(p).expanduser().resolve()
        if rp not in roots:
            roots.append(rp)
    return roots


def is_allowed(path: str | Path, roots: Iterable[Path]) -> bool:
    """True when the resolved ``path`` is one of ``roots`` or lies inside one of them."""
    p = Path(path).expanduser().resolve()
    return any(p == r or p.is_relative_to(r) for r in roots)


class FlatResults(param.Parameterized):
    """The Flat field page's results for the loaded session (de Lasarte et al. 2007).

    Each cache is keyed by what the result depends on: the offset setting (``None`` when the
    session names none) and, for results of one base image, the base group's
    ``(level, exposure)`` key. The page fills them as it computes; a new session starts empty.
    """

    recommendations = param.Dict(default={}, doc=(
        "setting -> BaseRecommendation (ccdcore.flatfield.fit.recommend_base): the recommended "
        "base image, with the linearity analysis."))
    fields = param.Dict(default={}, doc=(
        "(setting, base key) -> FlatField (ccdcore.flatfield.fit.flat_field_from_session): the "
        "gain and offset maps G, O for that base image."))
    averaging = param.Dict(default={}, doc=(
        "(setting, base key) -> AveragingResult "
        "(ccdcore.flatfield.uniformity.snup_vs_averaging) of the base group's frames (Table 1)."))
    zero_dark = param.Dict(default={}, doc=(
        "setting -> ZeroDark (ccdcore.flatfield.fit.zero_dark) of the setting's dark frames."))
    studies = param.Dict(default={}, doc=(
        "setting -> BaseStudy (ccdcore.flatfield.fit.base_image_study): Fig. 3, Tables 3-5."))
    kmaps = param.Dict(default={}, doc=(
        "setting -> (KMapComparison, with_truth): ccdcore.flatfield.fit.compare_with_k_map and "
        "whether the simulator's true flat field was compared too."))
    settings = param.ClassSelector(class_=SettingsComparison, default=None, allow_None=True,
                                   doc="Table 2 (ccdcore.flatfield.fit.compare_dark_settings), "
                                       "when the session has several offset settings.")


class Results(param.Parameterized):
    """The results the pages compute and share, for the loaded session only.

    Pages read and write the attributes; :meth:`clear` (called when another session is opened)
    resets every one. ``dark``, ``fixed_pattern``, ``plan``, ``scene`` and ``correction_check``
    are read-only views of ``estimates``.
    """

    ptc = param.ClassSelector(class_=PhotonTransfer, default=None, allow_None=True, doc=(
        "The photon-transfer fit the pages share (ccdcore.noise.photon_transfer): the Photon "
        "transfer page's, with the user's excluded levels, robust mode and ROI; else the one "
        "the Maps page's estimate_all made."))
    ptc_points = param.ClassSelector(class_=tuple, default=None, allow_None=True, doc=(
        "The measured photon-transfer levels (a tuple of ccdcore.noise.PtcPoint) over the "
        "Photon transfer page's ROI; also set when too few levels allow a fit."))
    estimates = param.ClassSelector(class_=Estimates, default=None, allow_None=True, doc=(
        "ccdcore.product.make.estimate_all on the session (the Maps page): the dark reference, K̂, "
        "the acquisition plan, the scene variation, the correction check (computed once, on "
        "the max-intensity frame) and what was skipped, with why."))
    flat = param.ClassSelector(class_=FlatResults, doc="The Flat field page's results.")
    response = param.Dict(default={}, doc=(
        "The Response & HDR page's results: (blooming radius, white balance, exposures) -> "
        "{'responses': method -> "
        "ccdcore.response.methods.ResponseResult, 'hdr': method -> "
        "ccdcore.response.hdr.HdrResult}."))
    change = param.Dict(default={}, doc=(
        "The Change detection page's results: the detector's options (a frozen ChangeOptions) -> "
        "(ccdcore.change.detector.ChangeResult, inputs: the radiance maps with their sigmas) of "
        "ccdcore.change.session.session_change."))

    def __init__(self, **params: Any):
        params.setdefault("flat", FlatResults())
        super().__init__(**params)

    def clear(self) -> None:
        """Forget every result (one batch of events)."""
        self.param.update(ptc=None, ptc_points=None, estimates=None, flat=FlatResults(),
                          response={}, change={})

    def _part(self, name: str) -> Any:
        return None if self.estimates is None else getattr(self.estimates, name)

    @property
    def dark(self) -> DarkReference | None:
        """The dark reference D̂_D (``estimates.dark``)."""
        return self._part("dark")

    @property
    def fixed_pattern(self) -> FixedPattern | None:
        """The fixed-pattern map K̂ (``estimates.fixed_pattern``)."""
        return self._part("fixed_pattern")

    @property
    def plan(self) -> AcquisitionPlan | None:
        """The acquisition plan n1, n2 (``estimates.plan``)."""
        return self._part("plan")

    @property
    def scene(self) -> dict[str, SceneVariation] | None:
        """The scene variation V_S per patch (``estimates.scene``)."""
        return self._part("scene")

    @property
    def correction_check(self) -> CorrectionCheck | None:
        """The sec. VII-A correction check (``estimates.correction_check``)."""
        return self._part("correction_check")


#: sessions opened in this process: resolved path -> (the files' signature, the session); each
#: browser session gets its own copy (:func:`open_session_cached`)
_OPENED: "OrderedDict[Path, tuple[tuple, Session]]" = OrderedDict()
_OPENED_LOCK = threading.Lock()
#: at most this many opened sessions are kept
OPENED_MAX = 8


def _stat(path: Path) -> tuple[str, int, int] | tuple[str]:
    try:
        st = path.stat()
    except OSError:
        return (str(path),)
    return (str(path), st.st_mtime_ns, st.st_size)


def session_signature(path: Path, session: Session) -> tuple:
    """What opening ``path`` read, as (path, mtime, size) triples: the path itself, the
    manifest, every frame and every folder under the session's root (a file added or removed
    changes its folder's time)."""
    paths = [path, session.root]
    if session.manifest_path is not None:
        paths.append(Path(session.manifest_path))
    paths += [Path(rec.path) for rec in session.frames]
    if session.root.is_dir():
        for folder, dirs, _ in os.walk(session.root):
            dirs.sort()
            paths += [Path(folder) / d for d in dirs]
    return tuple(_stat(p) for p in paths)


def open_session_cached(path: Path, role: str | None = None) -> Session:
    """:func:`ccdcore.session.open_session`, once per process while none of the files it read
    changed: opening reads the header of every frame (0.07 s for the 96 frames of the demo,
    on each first view of a served session); a copy of the opened session, checked against
    :func:`session_signature`, takes a few milliseconds. Each caller gets its own copy.
    ``role``: every image of a plain folder is a frame of that role (``open_session``'s)."""
    key = (path, role)
    with _OPENED_LOCK:
        hit = _OPENED.get(key)
    if hit is not None:
        signature, session = hit
        if session_signature(path, session) == signature:
            with _OPENED_LOCK:
                _OPENED.move_to_end(key)
            return copy.deepcopy(session)
    session = open_session(path, role=role)
    signature = session_signature(path, session)
    with _OPENED_LOCK:
        _OPENED[key] = (signature, copy.deepcopy(session))
        while len(_OPENED) > OPENED_MAX:
            _OPENED.popitem(last=False)
    return session


class AppState(param.Parameterized):
    """State shared by the pages of one browser session.

    Pages read ``session`` and ``results`` and watch ``session`` (and the attributes of
    ``results``) to refresh; they report long work through ``busy``/``progress`` and problems
    through ``error`` (shown as a red alert), never by raising. Long computations run through
    :meth:`compute` (off the UI thread); the pages store what it returns in ``results``.
    """

    session = param.ClassSelector(class_=Session, default=None, allow_None=True,
                                  doc="The loaded capture session, or None.")
    session_path = param.String(default="", doc="Path the current session was opened from.")
    results = param.ClassSelector(class_=Results, constant=True, doc=(
        "The results computed for the loaded session (one object per browser session, "
        "cleared when another session is opened)."))
    status = param.String(default="No session loaded.", doc="Last status message for the user.")
    error = param.String(default="", doc="Last error message for the user ('' when none).")
    busy = param.Boolean(default=False, doc="True while a long task runs.")
    progress = param.Integer(default=-1, bounds=(-1, 100),
                             doc="Percent done of the current task; -1 when unknown.")
    allowed_roots = param.List(default=[], item_type=Path,
                               doc="Folders sessions may be opened from (resolved paths).")
    cache = param.ClassSelector(class_=ResultCache, default=None, allow_None=True, doc=(
        "The disk cache of finished results (ccdcore_app.cache.store.default_cache() unless "
        "given; None: "
        "nothing cached)."))

    def __init__(self, **params: Any):
        params.setdefault("allowed_roots", default_roots())
        params.setdefault("results", Results())
        if "cache" not in params:
            params["cache"] = default_cache()
        super().__init__(**params)
        self._trackers: set[Tracker] = set()   # the running computations
        #: the loaded session and the task hashing its content
        #: (ccdcore_app.cache.store.session_hash)
        self._hashing: tuple[Session, asyncio.Future] | None = None

    # ---- opening sessions ---------------------------------------------------------------------
    def check_allowed(self, path: str | Path) -> Path:
        """Return ``path`` resolved, or raise :class:`CcdError` if outside ``allowed_roots``."""
        text = str(path).strip()
        if not text:
            raise CcdError("path", "empty; type a session folder, its session.toml, a folder of "
                                   "images or an EMVA1288 descriptor")
        p = Path(text).expanduser()
        if not p.is_absolute():
            p = Path.cwd() / p
        p = p.resolve()
        if not is_allowed(p, self.allowed_roots):
            roots = ", ".join(str(r) for r in self.allowed_roots)
            raise CcdError(p, f"outside the folders this app may open ({roots})")
        return p

    def _open(self, path: str | Path, role: str | None = None
              ) -> tuple[Path, Session | None, str]:
        """Open a session without touching any parameter (safe in a worker thread); ``role``:
        every image of a plain folder is a frame of that role (a camera folder of flats).

        Returns the resolved path, the session (None on failure) and the error message.
        """
        try:
            p = self.check_allowed(path)
            return p, open_session_cached(p, role), ""
        except CcdError as err:
            return Path(str(path)), None, str(err)
        except Exception as err:  # a bug or an OS error must not reach the user as a traceback
            log.error("opening %s failed:\n%s", path, traceback.format_exc())
            return Path(str(path)), None, f"{path}: unexpected error: {type(err).__name__}: {err}"

    def _apply(self, path: Path, session: Session | None, error: str) -> bool:
        """Publish the outcome of :meth:`_open` (one batched update)."""
        with param.parameterized.batch_call_watchers(self):
            self.busy = False
            self.progress = -1
            if session is None:
                self.error = error
                self.status = "Could not open the session." if self.session is None else \
                    f"Could not open the session; still showing {self.session_path}."
                return False
            self.results.clear()
            self._hashing = None
            self.session_path = str(path)
            self.session = session
            self.error = ""
            self.status = self.summary(session)
        return True

    def _start(self, path: str | Path) -> None:
        self.error = ""
        self.status = f"Opening {path} ..."
        self.progress = -1
        self.busy = True

    def load(self, path: str | Path, role: str | None = None) -> bool:
        """Open the session at ``path`` (in this thread); True on success. ``role``: every
        image of a plain folder is a frame of that role (``ccdcore app FOLDER --role flat``).

        On bad input (path outside ``allowed_roots``, missing, not a session, TOML syntax error,
        a role given for a session with a manifest) the current session stays loaded and
        ``error`` says what is wrong.
        """
        self._start(path)
        return self._apply(*self._open(path, role))

    async def load_async(self, path: str | Path, role: str | None = None) -> bool:
        """:meth:`load` with the opening (header reads of every frame) in a worker thread."""
        self._start(path)
        result = await asyncio.to_thread(self._open, path, role)
        return self._apply(*result)

    def close(self) -> None:
        """The browser session ended: drop the capture session and every result, so that their
        memory comes back even while Panel still holds the page objects.

        No watcher runs: the pages' document is gone, so nothing may be redrawn."""
        discard = param.parameterized.discard_events
        with discard(self), discard(self.results):
            self.results.clear()
            self._hashing = None
            self.session = None
            self.session_path = ""
            self.status = "Session closed."

    # ---- computed results -----------------------------------------------------------------------
    def _run_safely(self, func: Callable[..., Any], args: tuple, kwargs: dict
                    ) -> tuple[Any, str | None]:
        """Call ``func`` (in a worker thread); the result and the user-facing error message
        ("" when none, None when the user cancelled it)."""
        try:
            return func(*args, **kwargs), ""
        except CcdError as err:
            return None, str(err)
        except Cancelled:       # the user stopped it (AppState.cancel): no error to show
            return None, None
        except Exception as err:  # a bug must reach the user as a message, not a traceback
            log.error("computing with %s failed:\n%s", getattr(func, "__name__", func),
                      traceback.format_exc())
            return None, f"unexpected error: {type(err).__name__}: {err}"

    def _run_tracked(self, tracker: Tracker, func: Callable[..., Any], args: tuple,
                     kwargs: dict) -> tuple[Any, str | None]:
        """:meth:`_run_safely` reporting to ``tracker``; error ``None`` means cancelled."""
        with tracking(tracker):
            return self._run_safely(func, args, kwargs)

    def _show_progress(self, tracker: Tracker, label: str) -> None:
        if not tracker.cancelled:
            self.param.update(progress=min(int(100 * tracker.fraction), 99),
                              status=f"Computing {label}: {tracker.describe()} ...")

    async def compute(self, func: Callable[..., Any], *args: Any, label: str = "results",
                      steps: Sequence[tuple[str, float]] = (), pass_progress: bool = False,
                      tracker: Tracker | None = None, **kwargs: Any) -> Any | None:
        """Run ``func(*args, **kwargs)`` off the UI thread and return its result.

        While it runs ``busy`` is set, and four times a second ``progress`` (percent) and
        ``status`` say what is computed (``label``), which step and how many of its frames are
        read (:mod:`ccdcore.progress`: every frame reader reports; ``steps`` names the steps
        and where each starts, ``pass_progress`` hands the tracker to ``func`` as its
        ``progress``, a :class:`ccdcore.progress.Progress`, with no adapter). :meth:`cancel` stops
        it at the next frame: ``None`` is returned and ``status`` says it was cancelled. A
        :class:`CcdError` (bad input: too few levels, missing frames ...) becomes ``error`` and
        ``None`` is returned, as it is when another session was opened meanwhile. The caller stores
        the result in :attr:`results`. ``tracker``: the :class:`~ccdcore.progress.Tracker` to
        report to (made from ``steps`` when not given), for a caller that shows it elsewhere too
        (:meth:`shared_compute`).
        """
        session = self.session
        tracker = Tracker(steps) if tracker is None else tracker
        if pass_progress:
            kwargs["progress"] = tracker
        self._trackers.add(tracker)
        with param.parameterized.batch_call_watchers(self):
            self.error = ""
            self.busy = True
            self.progress = -1
            self.status = f"Computing {label} ..."
        try:
            task = asyncio.ensure_future(
                asyncio.to_thread(self._run_tracked, tracker, func, args, kwargs))
            while not task.done():
                await asyncio.wait({task}, timeout=0.25)
                if not task.done():
                    self._show_progress(tracker, label)
            result, error = task.result()
        finally:
            self._trackers.discard(tracker)
        with param.parameterized.batch_call_watchers(self):
            self.busy = bool(self._trackers)
            self.progress = -1
            if self.session is not session:  # another session was opened meanwhile
                return None
            if error is None:
                self.status = f"Cancelled {label}."
                return None
            if error:
                self.error = error
                self.status = f"Could not compute {label}."
                return None
            self.status = f"Computed {label}."
        return result

    def cancel(self) -> None:
        """Stop the running computations at their next frame (:meth:`compute` returns None)."""
        for tracker in list(self._trackers):
            tracker.cancel()
        if self._trackers:
            self.status = "Cancelling ..."

    @property
    def cancellable(self) -> bool:
        """True while a computation that :meth:`cancel` can stop is running."""
        return bool(self._trackers)

    # ---- cached results ---------------------------------------------------------------------
    def _hash_or_none(self, cache: ResultCache | None, session: Session) -> str | None:
        """The session's content hash through the cache's stat index (in a worker thread;
        without a disk cache, :meth:`Session.content_hash`, remembered in this process); None
        when a file cannot be read (the result is then computed, not cached)."""
        try:
            code_version()   # read ccdcore's sources once, here rather than on the event loop
            return session.content_hash() if cache is None else cache.session_hash(session)
        except Exception as err:  # CcdError, OSError: no caching, the computation says more
            log.warning("no cache for %s: %s: %s", session.label, type(err).__name__, err)
            return None

    async def session_hash(self) -> str | None:
        """The loaded session's content hash (off the UI thread, once per session: concurrent
        callers share one hashing; through the disk cache's stat index when there is a cache),
        or None without a session or a readable file."""
        session, cache = self.session, self.cache
        if session is None:
            return None
        loop = asyncio.get_running_loop()
        if self._hashing is not None and self._hashing[0] is session:
            task = self._hashing[1]
            if task.done() and not task.cancelled():
                return task.result()
            if not task.done() and task.get_loop() is loop:
                return await asyncio.shield(task)
        task = asyncio.ensure_future(asyncio.to_thread(self._hash_or_none, cache, session))
        self._hashing = (session, task)
        return await asyncio.shield(task)

    async def cache_key(self, name: str, params: dict[str, Any]) -> str | None:
        """The cache key of computation ``name`` with ``params`` on the loaded session (None
        when nothing can be cached)."""
        cache = self.cache
        if cache is None:
            return None
        content = await self.session_hash()
        return None if content is None else cache.key(content, name, params)

    async def _known_hash(self, cache: ResultCache, session: Session) -> str | None:
        """The content hash when already known: hashed for this session, or in the cache's
        stat index (files stat'ed, none read); None otherwise."""
        memo = self._hashing
        if memo is not None and memo[0] is session and memo[1].done() \
                and not memo[1].cancelled():
            return memo[1].result()

        def known() -> str | None:
            code_version()   # read ccdcore's sources once, here rather than on the event loop
            return cache.known_hash(session)
        return await asyncio.to_thread(known)

    async def cached_compute(self, name: str, params: dict[str, Any],
                             func: Callable[..., Any], *args: Any, label: str = "results",
                             **kwargs: Any) -> Any | None:
        """:meth:`compute`, through the disk cache: the result of ``name`` with ``params``
        (plain data naming everything the result depends on besides the session's content)
        is read back when present, else computed and stored.

        A session the cache's stat index knows is looked up at once (no frame read); a new
        session, or one with a changed file, is computed at once while its content hash is
        made in another worker thread (every byte read), and the result stored under it (a
        cancelled or failed computation returns at once, the hashing goes on). A
        result read back sets ``status`` to say it came from the cache; an unreadable entry is
        computed again. ``args`` and ``kwargs`` go to :meth:`compute` as they are.
        """
        session, cache = self.session, self.cache
        if session is None or cache is None:
            return await self.compute(func, *args, label=label, **kwargs)
        content = await self._known_hash(cache, session)
        if self.session is not session:
            return None
        if content is None:     # hash while computing: the user does not wait for it
            hashing = asyncio.ensure_future(self.session_hash())
            result = await self.compute(func, *args, label=label, **kwargs)
            if result is None:  # cancelled or failed: the hashing goes on in the background
                return None
            content = await hashing   # (one pass over the files, the computation's first)
        else:
            value = await asyncio.to_thread(cache.get, cache.key(content, name, params))
            if self.session is not session:
                return None
            if value is not None:
                self.param.update(error="", status=f"Loaded {label} from the cache (computed "
                                                   "earlier on the same files).")
                return value
            result = await self.compute(func, *args, label=label, **kwargs)
        if result is not None and content is not None and self.session is session:
            await asyncio.to_thread(cache.put, cache.key(content, name, params), result)
        return result

    async def shared_compute(self, name: str, params: dict[str, Any],
                             func: Callable[..., Any], *args: Any, label: str = "results",
                             disk: bool = True, hold: bool = True,
                             store: SharedResults | None = None, **kwargs: Any) -> Any | None:
        """:meth:`cached_compute` (``disk=False``: :meth:`compute`), shared by every browser
        session of this server: the result of ``name`` with ``params`` on the session's
        content is computed once per process (:class:`ccdcore_app.cache.store.SharedResults`, by
        default
        :func:`ccdcore_app.cache.store.shared_results`; ``hold=False`` keeps a large result only
        while some session holds it).

        The first caller computes (off the UI thread, with progress and cancel); a caller
        arriving meanwhile, from this or another browser session, waits for that computation
        without blocking the event loop, its progress bar following the first one's, and gets
        its result or its error. Its Cancel stops its own wait only. A computation that ends
        without a result (cancelled by its user, its session closed) is taken over by a
        waiter. The result reaches the store even when the session that started it was
        closed or changed meanwhile. ``None`` is returned as :meth:`compute` returns it.
        """
        store = shared_results() if store is None else store
        session = self.session
        content = await self.session_hash() if session is not None else None
        if self.session is not session:
            return None
        if content is None:         # no session or an unreadable file: nothing to share by
            return await (self.cached_compute(name, params, func, *args, label=label, **kwargs)
                          if disk else self.compute(func, *args, label=label, **kwargs))
        key = ResultCache.key(content, name, params)
        while True:
            value, entry, owner = store.claim(key)
            if value is not None:
                self.param.update(error="", status=f"Computed {label} (shared).")
                return value
            if owner:
                break
            outcome = await self._wait_shared(entry, label)
            if outcome is None or self.session is not session:
                return None             # this session stopped waiting, or moved on
            value, error = outcome
            if value is not None:
                self.param.update(error="", status=f"Computed {label} (shared).")
                return value
            if error:
                self.param.update(error=error, status=f"Could not compute {label}.")
                return None
            # the computation ended without a result: claim it again (this caller computes)
        entry.tracker = tracker = Tracker(kwargs.pop("steps", ()))
        publish = _Publisher(store, entry, func, hold)
        result = None
        try:
            if disk:
                result = await self.cached_compute(name, params, publish, *args, label=label,
                                                   tracker=tracker, **kwargs)
            else:
                result = await self.compute(publish, *args, label=label, tracker=tracker,
                                            **kwargs)
        finally:
            if not publish.ran:     # read back from the disk cache, or never started
                store.finish(entry, result, None, hold=hold)
        return result

    async def _wait_shared(self, entry: Any, label: str) -> tuple[Any, str | None] | None:
        """Wait for another caller's computation ``entry`` (:meth:`shared_compute`) showing
        its progress; its outcome, or None when :meth:`cancel` stopped this wait."""
        mine = Tracker()            # cancel() stops this wait, not the other computation
        self._trackers.add(mine)
        with param.parameterized.batch_call_watchers(self):
            self.error = ""
            self.busy = True
            self.progress = -1
            self.status = f"Computing {label} (started in another browser tab) ..."
        waiting = asyncio.wrap_future(entry.future)
        try:
            while not waiting.done() and not mine.cancelled:
                await asyncio.wait({waiting}, timeout=0.25)
                other = entry.tracker
                if not waiting.done() and other is not None and not mine.cancelled:
                    self.param.update(progress=min(int(100 * other.fraction), 99),
                                      status=f"Computing {label} (started in another browser "
                                             f"tab): {other.describe()} ...")
        finally:
            self._trackers.discard(mine)
            with param.parameterized.batch_call_watchers(self):
                self.busy = bool(self._trackers)
                self.progress = -1
        if not waiting.done():
            self.status = f"Stopped waiting for {label}."
            return None
        return waiting.result()

    @staticmethod
    def summary(session: Session) -> str:
        """One line describing a session: name, frame count per role, problem counts."""
        roles = ", ".join(f"{n} {role}" for role, n in session.roles().items()) or "no frames"
        n_err, n_warn = len(session.errors), len(session.warnings)
        checks = "valid" if not session.problems else \
            f"{n_err} error(s), {n_warn} warning(s)"
        return f"Loaded {session.root.name}: {len(session.frames)} frames ({roles}); {checks}."


class _Publisher:
    """``func`` run for :meth:`AppState.shared_compute`: its result or error goes to the store
    from the worker thread, as soon as it is known, whatever happens to the caller."""

    def __init__(self, store: SharedResults, entry: Any, func: Callable[..., Any], hold: bool):
        self.store, self.entry, self.func, self.hold = store, entry, func, hold
        self.ran = False
        self.__name__ = getattr(func, "__name__", "shared")

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        self.ran = True
        try:
            value = self.func(*args, **kwargs)
        except CcdError as err:
            self.store.finish(self.entry, None, str(err))
            raise
        except Cancelled:
            self.store.finish(self.entry, None, None)
            raise
        except Exception as err:
            self.store.finish(self.entry, None,
                              f"unexpected error: {type(err).__name__}: {err}")
            raise
        self.store.finish(self.entry, value, hold=self.hold)
        return value
