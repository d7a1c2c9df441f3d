"""Progress of long reductions, and a way to stop them.

Every reduction over frames reads them through :meth:`ccdcore.session.Session.iter_frames`,
which calls :func:`checkpoint` once per frame. Outside a :func:`tracking` block that costs one
context-variable lookup and does nothing; inside one it records how many of the step's frames
are done and raises :class:`Cancelled` once :meth:`Tracker.cancel` was called (from any thread).
So a caller (the app) can show what is being computed, how far it is, and stop it between two
frames, without any estimator taking a callback argument.

Public objects
--------------
Cancelled
    Raised inside a tracked computation after :meth:`Tracker.cancel`; not an input error.
Tracker
    The progress of one computation: current step, fraction done, frames of the step; cancel().
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
from typing import Iterator, Sequence

__all__ = ["Cancelled", "Tracker", "tracking", "checkpoint"]


class Cancelled(Exception):
    """The computation was cancelled by its user (:meth:`Tracker.cancel`)."""


class Tracker:
    """Progress of one computation made of named steps, and its cancellation.

    Parameters
    ----------
    steps
        The steps in order with the overall fraction at which each starts, e.g.
        ``(("dark reference", 0.0), ("fixed pattern", 0.4), ("done", 1.0))`` (as
        :data:`ccdcore.product.ESTIMATE_STEPS`). A step runs up to the next one's start; within
        it the fraction advances with the frames read. Without steps the computation is one
        step from 0 to 1.

    The tracker is also a ``progress(step, fraction)`` callback (:func:`ccdcore.product.
    estimate_all` takes one): each call starts a step. Reading its attributes from another
    thread is safe (each is one atomic assignment).
    """

    def __init__(self, steps: Sequence[tuple[str, float]] = ()):
        self._starts = [(str(name), float(start)) for name, start in steps]
        self._cancel = threading.Event()
        self.step = ""
        self._start, self._end = 0.0, 1.0
        self.fraction = 0.0
        self.done = 0
        self.total: int | None = None

    def __call__(self, step: str, fraction: float) -> None:
        """Start ``step`` at the overall ``fraction`` (raises :class:`Cancelled` if cancelled)."""
        self.check()
        later = [start for _, start in self._starts if start > fraction]
        self._start, self._end = float(fraction), (min(later) if later else 1.0)
        self.done, self.total = 0, None
        self.step = step
        self.fraction = max(self.fraction, float(fraction))

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
