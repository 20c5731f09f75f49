"""Random bits for ids, from the OS's CSPRNG a pool at a time."""

from __future__ import annotations

import os
import threading
import uuid

_POOL_BYTES = 4096
"""Random bytes read from the OS at once: ``os.urandom`` is a system call that lets go of the
GIL, and every upload paid it twice (its frame id and its request id), with a wait to take the
GIL back under load, for 10 and 16 bytes. On the event loop's thread that wait held up every
request: 0.11 ms a frame of the loop's time in a profile of the upload under load
(`py-spy`, 16 clients, PostgreSQL), against 0.01 for the bare endpoint."""


class _RandomPool:
    """Bytes of ``os.urandom``, read a pool at a time and handed out once each. Forgotten in a
    forked child, which would otherwise hand out its parent's next bytes again (the same ids
    in two processes)."""

    def __init__(self) -> None:
        self._forget()
        os.register_at_fork(after_in_child=self._forget)

    def _forget(self) -> None:
        self._lock = threading.Lock()
        self._bytes = b""
        self._at = 0

    def take(self, n: int) -> bytes:
        with self._lock:
            if self._at + n > len(self._bytes):
                self._bytes, self._at = os.urandom(max(n, _POOL_BYTES)), 0
            start, self._at = self._at, self._at + n
            return self._bytes[start : self._at]


_pool = _RandomPool()


def random_bytes(n: int) -> bytes:
    """``n`` bytes of the OS's CSPRNG, never handed out before (in this process or another)."""
    return _pool.take(n)


def uuid4_hex() -> str:
    """A random (version-4) UUID as 32 hex digits, as ``uuid.uuid4().hex`` gives it."""
    return uuid.UUID(bytes=_pool.take(16), version=4).hex
