"""Progress of long computations, and a way to stop them.

The one convention
------------------
Every long function of ``ccdcore``, ``ccdcore_report`` and the app that reports its progress
takes a :class:`Progress`: ``progress(fraction, message)``, ``fraction`` the part of the whole
done (a float in [0, 1], never decreasing over one computation) and ``message`` what is being
done, for a person ("fixed pattern", "channel R: iteration 3 ..."). ``None`` means nobody
listens. A function that runs another long function as a part of its own work hands it
:func:`within` its own progress and the part's range (the callee's [0, 1] is mapped onto
it), never a callback of its own that recomputes fractions or swaps arguments.

Frames
------
Every reduction over frames reads them through :meth:`ccdcore.session.Session.iter_frames`,
which calls :func:`checkpoint` once per frame. Outside a :func:`tracking` block that costs one
context-variable lookup and does nothing; inside one it records how many of the step's frames
are done and raises :class:`Cancelled` once :meth:`Tracker.cancel` was called (from any thread).
So a caller (the app) can show what is being computed, how far it is, and stop it between two
frames, without any estimator taking a callback argument.

Public objects
--------------
Progress
    The protocol of every progress callback: ``progress(fraction, message) -> None``.
silent
    The :class:`Progress` that does nothing.
within(progress, start, end, prefix="")
    A :class:`Progress` for a part of a computation: its [0, 1] is ``[start, end]`` of
    ``progress`` (``None``: :data:`silent`).
Steps(progress, table)
    Reports a table of named steps (``(name, start)``, as
    :data:`ccdcore.product.make.ESTIMATE_STEPS`): ``steps(name)`` is ``progress(start, name)``;
    ``steps.within(name)`` the :func:`within` of that step's range.
Cancelled
    Raised inside a tracked computation after :meth:`Tracker.cancel`; not an input error.
Tracker
    The progress of one computation: current step, fraction done, frames of the step; cancel().
    It is a :class:`Progress` (each call starts a step).
tracking(tracker)
    Context manager making ``tracker`` the one :func:`checkpoint` reports to (per thread/task:
    a :mod:`contextvars` variable, so concurrent computations of several app sessions never
    mix, and ``asyncio.to_thread`` carries it into the worker thread).
checkpoint(done=None, total=None)
    Called by the frame readers: count a frame and stop here if cancelled.
"""
from __future__ import annotations

import threading
from contextlib import contextmanager
from contextvars import ContextVar
from numbers import Real
from typing import Iterator, Protocol, Sequence

__all__ = ["Progress", "silent", "within", "Steps", "Cancelled", "Tracker", "tracking",
           "checkpoint"]


class Progress(Protocol):
    """``progress(fraction, message)``: the one progress callback of ccdcore.

    ``fraction`` is the part of the whole computation done, a float in [0, 1] that never
    decreases over one computation; ``message`` says what is being done, for a person. A
    callback may raise (:class:`Cancelled`, from a cancelled :class:`Tracker`) to stop the
    computation. The parameters are positional: any callable ``f(fraction, message)`` is one.
    """

    def __call__(self, fraction: float, message: str, /) -> None: ...


def _fraction(fraction: float, message: str) -> float:
    """``fraction`` as a float, refusing the arguments of the old ``(step, fraction)`` order."""
    if isinstance(fraction, str) or not isinstance(fraction, Real) \
            or not isinstance(message, str):
        raise TypeError(f"progress(fraction, message) takes a number and a str, not "
                        f"({fraction!r}, {message!r})")
    return float(fraction)


def _silent(fraction: float, message: str, /) -> None:
    return None


#: the :class:`Progress` that does nothing (what ``progress=None`` means)
silent: Progress = _silent


def within(progress: Progress | None, start: float, end: float, *,
           prefix: str = "") -> Progress:
    """A :class:`Progress` for the part ``[start, end]`` of ``progress``'s computation.

    Its own fraction ``f`` (clamped to [0, 1]) is reported as ``start + (end - start) * f``,
    its message with ``prefix`` before it. Nested calls compose: ``within(within(p, 0.5, 1.0),
    0.0, 0.5)`` covers [0.5, 0.75] of ``p``. ``progress=None`` gives :data:`silent`.
    """
    if progress is None:
        return silent
    lo, hi = float(start), float(end)
    if not (0.0 <= lo <= hi <= 1.0):
        raise ValueError(f"within: need 0 <= start <= end <= 1, not [{start}, {end}]")

    def part(fraction: float, message: str, /) -> None:
        f = min(max(_fraction(fraction, message), 0.0), 1.0)
        progress(lo + (hi - lo) * f, prefix + message)
    return part


class Steps:
    """Reports the named steps of a computation to ``progress``.

    ``table`` lists the steps in order with the overall fraction at which each starts, e.g.
    :data:`ccdcore.product.make.ESTIMATE_STEPS`; a step runs up to the next one's start (the last
    one's to 1). ``steps(name)`` reports ``progress(start, name)``; ``steps.within(name)`` is
    the :func:`within` of the step's range, for a long function run as that step.
    ``progress=None``: nothing is reported.
    """

    def __init__(self, progress: Progress | None, table: Sequence[tuple[str, float]]):
        self.progress = progress
        self.table = tuple((str(name), float(start)) for name, start in table)
        self._range: dict[str, tuple[float, float]] = {}
        for i, (name, start) in enumerate(self.table):
            end = self.table[i + 1][1] if i + 1 < len(self.table) else 1.0
            self._range[name] = (start, max(start, end))

    def __call__(self, name: str) -> None:
        """Start the step ``name``."""
        if self.progress is not None:
            self.progress(self._range[name][0], name)

    def within(self, name: str, *, prefix: str = "") -> Progress:
        """A :class:`Progress` over the range of step ``name`` (see :func:`within`)."""
        start, end = self._range[name]
        return within(self.progress, start, end, prefix=prefix)


class Cancelled(Exception):
    """The computation was cancelled by its user (:meth:`Tracker.cancel`)."""


class Tracker:
    """Progress of one computation made of named steps, and its cancellation.

    Parameters
    ----------
    steps
        The steps in order with the overall fraction at which each starts, e.g.
        ``(("dark reference", 0.0), ("fixed pattern", 0.4), ("done", 1.0))`` (as
        :data:`ccdcore.product.make.ESTIMATE_STEPS`). A step runs up to the next one's start; within
        it the fraction advances with the frames read. Without steps the computation is one
        step from 0 to 1.

    The tracker is also a :class:`Progress` (:func:`ccdcore.product.make.estimate_all` takes one):
    each call ``tracker(fraction, message)`` starts the step ``message`` at the overall
    ``fraction``. Reading its attributes from another thread is safe (each is one atomic
    assignment).
    """

    def __init__(self, steps: Sequence[tuple[str, float]] = ()):
        self._starts = [(str(name), float(start)) for name, start in steps]
        self._cancel = threading.Event()
        self.step = ""
        self._start, self._end = 0.0, 1.0
        self.fraction = 0.0
        self.done = 0
        self.total: int | None = None

    def __call__(self, fraction: float, message: str, /) -> None:
        """Start the step ``message`` at the overall ``fraction`` (raises :class:`Cancelled`
        if cancelled)."""
        fraction = _fraction(fraction, message)
        self.check()
        later = [start for _, start in self._starts if start > fraction]
        self._start, self._end = fraction, (min(later) if later else 1.0)
        self.done, self.total = 0, None
        self.step = message
        self.fraction = max(self.fraction, fraction)

    def frame(self, done: int | None = None, total: int | None = None) -> None:
        """One more frame of the current step read (``done`` of ``total`` when known)."""
        self.check()
        self.done = self.done + 1 if done is None else int(done)
        if total is not None:
            self.total = int(total)
        if self.total:
            within = min(self.done / self.total, 1.0)
            self.fraction = max(self.fraction,
                                self._start + (self._end - self._start) * within)

    def cancel(self) -> None:
        """Ask the computation to stop at its next frame or step."""
        self._cancel.set()

    @property
    def cancelled(self) -> bool:
        return self._cancel.is_set()

    def check(self) -> None:
        """Raise :class:`Cancelled` if :meth:`cancel` was called."""
        if self._cancel.is_set():
            raise Cancelled(f"cancelled during {self.step or 'the computation'}")

    def describe(self) -> str:
        """One line for a person: the step and, when known, the frames of it read."""
        text = self.step or "starting"
        if self.total:
            text += f": frame {min(self.done, self.total)} of {self.total}"
        elif self.done:
            text += f": {self.done} frames read"
        return text


_active: ContextVar[Tracker | None] = ContextVar("ccdcore_progress", default=None)


@contextmanager
def tracking(tracker: Tracker) -> Iterator[Tracker]:
    """Within this block (this thread or task), :func:`checkpoint` reports to ``tracker``."""
    token = _active.set(tracker)
    try:
        yield tracker
    finally:
        _active.reset(token)


def checkpoint(done: int | None = None, total: int | None = None) -> None:
    """Count one frame read (``done`` of ``total`` in the current loop) for the active tracker,
    and raise :class:`Cancelled` if it was cancelled. No tracker: nothing happens."""
    tracker = _active.get()
    if tracker is not None:
        tracker.frame(done, total)
