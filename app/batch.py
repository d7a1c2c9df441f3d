"""One browser update for many changes: the ``batched`` method decorator.

A page that reacts to a new result changes many widgets, panes and plots in a row. Sent one by
one, each change makes BokehJS lay out the page's root again (reading every plot's styles), and
makes Bokeh walk the whole document's model graph on the server. Inside ``batched`` the changes
are held and sent as one message when the method returns (``panel.io.hold``), and the model
graph is recomputed once (``freeze=True``). Outside a served document (scripts, tests) it does
nothing.
"""
from __future__ import annotations

import functools
from typing import Any, Callable, TypeVar

from panel.io import hold

__all__ = ["batched"]

F = TypeVar("F", bound=Callable[..., Any])


def batched(method: F) -> F:
    """Run ``method`` with the document's events held and its model graph frozen."""

    @functools.wraps(method)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with hold(freeze=True):
            return method(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
