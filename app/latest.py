"""A newest-wins guard for a page's asynchronous requests.

A page that starts work on a widget change (read a frame, fit, apply a product) may get a newer
change while the first is still running; only the newest request may draw. Each request takes
a ticket before its first ``await`` and asks, after each one, whether it is still the newest:

    ticket = self._preview.next()
    plane = await ...
    if not self._preview.is_current(ticket):
        return

One class for every page, instead of a counter and its comparisons hand-written in each.
"""
from __future__ import annotations

__all__ = ["Latest"]


class Latest:
    """Tickets of one kind of request; the last one handed out is the current one."""

    __slots__ = ("_n",)

    def __init__(self) -> None:
        self._n = 0

    def next(self) -> int:
        """A ticket for a new request: every earlier ticket stops being current."""
        self._n += 1
        return self._n

    def is_current(self, ticket: int | None) -> bool:
        """True while ``ticket`` is the newest request's (``None``: no ticket asked, true)."""
        return ticket is None or ticket == self._n

    @property
    def ticket(self) -> int:
        """The newest ticket (without starting a request)."""
        return self._n
