"""The frame store's checks and reads made for requests, bounded in time.

A disk store on a network mount whose server has gone away (NFS mounted ``hard``, its default)
blocks every call into it for as long as the server is gone, and no timeout can be set on a
``stat`` or a ``read``: ``/health``, probed every few seconds, would hold a request thread per
probe until none is left. Here those calls run on a few threads of their own and are awaited,
holding no request thread, for at most ``seconds``; a check still running is awaited again
rather than started once more. A hung store then costs these few threads, and its callers a 503
after ``seconds``. (Uploads have their own deadline: ``frames.router._within``.)
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import TypeVar

from app.platform.frames.storage import FrameStore, StoreUnavailable

T = TypeVar("T")

THREADS = 4
"""Calls into the store under way at once; beyond them a call gets 503 at once (the store is
slow or hung, and a thread more would hang too)."""


class BoundedStore:
    """``store``'s ``check`` and ``read`` for requests: each waits at most ``seconds``."""

    def __init__(self, store: FrameStore, *, seconds: float) -> None:
        self.store = store
        self.seconds = seconds
        self._running = 0
        self._check: Future[None] | None = None
        self._lock = threading.Lock()

    async def check(self) -> None:
        """Raise StoreUnavailable (DiskFull among them) unless the store answers in time."""
        with self._lock:
            if self._check is None or self._check.done():
                self._check = self._start(self.store.check)
            running = self._check
        await self._answer(running)

    async def read(self, relative: str) -> bytes | None:
        """The stored bytes (None when they are no longer kept); StoreUnavailable unless the
        store answers in time."""
        with self._lock:
            call = self._start(self.store.read, relative)
        return await self._answer(call)

    def _start(self, fn: Callable[..., T], *args: object) -> Future[T]:
        """``fn(*args)`` on a thread of its own (a daemon: one hung in the store must not keep
        the process from exiting, as a ``ThreadPoolExecutor``'s would). Under ``_lock``."""
        future: Future[T] = Future()
        if self._running >= THREADS:
            future.set_exception(
                StoreUnavailable(f"{THREADS} calls into the frame store are still waiting for it")
            )
            return future
        self._running += 1

        def run() -> None:
            try:
                future.set_result(fn(*args))
            except BaseException as exc:  # handed to the caller, as an executor does
                future.set_exception(exc)
            finally:
                with self._lock:
                    self._running -= 1

        threading.Thread(target=run, name="vantage-store", daemon=True).start()
        return future

    async def _answer(self, future: Future[T]) -> T:
        try:
            # shielded: a check is awaited by every probe that comes while it runs
            return await asyncio.wait_for(asyncio.shield(asyncio.wrap_future(future)), self.seconds)
        except TimeoutError:
            raise StoreUnavailable(
                f"the frame store did not answer within {self.seconds:g} s (a network mount "
                "whose server is gone?): try again shortly"
            ) from None
