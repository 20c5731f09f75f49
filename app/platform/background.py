"""Background work in worker threads that a shutdown waits for."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")


async def in_thread(
    fn: Callable[..., T], *args: Any, on_cancel: Callable[[], None] | None = None
) -> T:
    """``fn(*args)`` in a worker thread; when cancelled, still waits for the thread to finish.

    ``asyncio.to_thread`` alone returns at once when its awaiter is cancelled, and the thread
    goes on. At shutdown that thread would still hold a database connection when the engine is
    disposed, and the connection would be left for the garbage collector to close.
    ``on_cancel`` is called first, to ask a long ``fn`` to stop early.
    """
    task = asyncio.ensure_future(asyncio.to_thread(fn, *args))
    try:
        return await asyncio.shield(task)
    except asyncio.CancelledError:
        if on_cancel is not None:
            on_cancel()
        with contextlib.suppress(Exception):
            await task
        raise
