"""The newest-wins guard of the pages' asynchronous requests."""
from __future__ import annotations

import asyncio
import threading

from ccdcore_app.latest import Latest


def test_only_the_newest_ticket_is_current():
    latest = Latest()
    assert latest.is_current(None) and latest.ticket == 0
    first = latest.next()
    assert latest.is_current(first)
    second = latest.next()
    assert not latest.is_current(first) and latest.is_current(second)
    assert latest.ticket == second and latest.is_current(None)


def test_overlapping_requests_draw_once_and_the_newest():
    """Three requests started before any finishes (the slowest first): only the last draws."""
    latest, drawn = Latest(), []

    async def request(value: int, delay: float) -> None:
        ticket = latest.next()
        await asyncio.sleep(delay)
        if latest.is_current(ticket):
            drawn.append(value)

    async def main() -> None:
        await asyncio.gather(request(1, 0.03), request(2, 0.02), request(3, 0.01))

    # a loop of its own in a thread of its own: the browser tests leave one running here
    worker = threading.Thread(target=asyncio.run, args=(main(),))
    worker.start()
    worker.join(timeout=10)
    assert drawn == [3]
