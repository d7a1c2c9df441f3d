"""One browser update for many changes: the ``batched`` method decorator.

A page that reacts to a new result changes many widgets, panes and plots in a row. Sent one by
one, each change makes BokehJS lay out the page's root again (reading every plot's styles), and
makes Bokeh walk the whole document's model graph on the server. Inside ``batched`` the changes
are held and sent as one message when the method returns (``panel.io.hold``), and the model
graph is recomputed at most once (:func:`frozen_models`). Outside a served document (scripts,
tests) it does nothing.

frozen_models(doc)
    Bokeh's ``doc.models.freeze()``, except that the graph is walked at the end only when it
    changed meanwhile.
batched(method)
    The decorator.
in_document(doc, callback)
    Run a callback holding a served document's lock (from a coroutine after a worker thread).
"""
from __future__ import annotations

import contextlib
import functools
from typing import Any, Callable, Iterator, TypeVar

from panel.io import hold
from panel.io.state import set_curdoc, state

__all__ = ["batched", "frozen_models", "in_document"]

F = TypeVar("F", bound=Callable[..., Any])


@contextlib.contextmanager
def frozen_models(doc: Any) -> Iterator[None]:
    """Defer the document's model-graph walk to the end, and skip it when nothing changed.

    Bokeh's own ``freeze`` walks every model reachable from the roots when it ends
    (``DocumentModelManager.recompute``, 0.2 s for the 1,200 models of the app with its pages
    built), even when the batch only replaced data or moved a band. The graph changes only
    through a property whose old or new value holds a model (Bokeh then calls ``invalidate``)
    or through a root added or removed (under a nested ``freeze``); either marks it changed
    here, and only then is it walked, once, at the end. Nested uses leave the decision to the
    outermost.
    """
    models = getattr(doc, "models", None)
    if models is None or "_push_freeze" in vars(models):   # no document, or already inside
        yield
        return
    cls = type(models)
    changed = False

    def invalidate() -> None:          # frozen: Bokeh's own would wait for the end too
        nonlocal changed
        changed = True

    def push_freeze() -> None:         # add_root, remove_root, Panel's model swaps
        nonlocal changed
        changed = True
        cls._push_freeze(models)

    cls._push_freeze(models)
    models.invalidate, models._push_freeze = invalidate, push_freeze
    try:
        yield
    finally:
        del models.invalidate, models._push_freeze
        models._freeze_count -= 1
        if models._freeze_count == 0 and changed:
            models.recompute()


def batched(method: F) -> F:
    """Run ``method`` with the document's events held and its model graph frozen."""

    @functools.wraps(method)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with hold(), frozen_models(state.curdoc):
            return method(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


def in_document(doc: Any, callback: Callable[[], Any]) -> None:
    """Run ``callback`` in a callback of ``doc`` (the browser session's document, holding its
    lock, so model changes reach the browser; changes made from a coroutine after a worker
    thread can get lost), or at once without a served document."""
    doc = doc if doc is not None else state.curdoc
    if doc is None or doc.session_context is None:
        callback()
        return
    with set_curdoc(doc):
        state.execute(callback, schedule=True)
