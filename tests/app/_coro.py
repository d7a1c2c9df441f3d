"""Running the app's coroutines from synchronous tests."""
from __future__ import annotations

import asyncio
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Coroutine


def run(coro: Coroutine[Any, Any, Any]) -> Any:
    """Run a coroutine to completion in its own thread: the browser tests' event loop may be
    running in this one, as the Panel server runs async callbacks on its loop."""
    with ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, coro).result()
