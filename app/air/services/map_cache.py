"""The isopleth maps served, each computed at most once per ``ttl`` seconds a process.

``GET /air/isopleths`` (and its PNG) is public and dashboards poll it. Interpolating and
contouring takes from milliseconds (IDW, 50 cameras) to seconds (kriging, thousands of
cameras: ``bench/isopleths.py``), and every viewer's poll recomputed a map that a city's
readings change only slowly, so a dashboard with many viewers, or anyone on the internet,
could keep the cores busy. A map is kept for ``ttl`` seconds by its request (representation,
bbox, window, method, resolution, max_distance); its ``computed_at`` says when it was made,
and its ETag (a digest of the body) lets a client revalidate it for a 304. A GeoJSON map is
also kept gzipped, compressed once when computed rather than at every browser's poll.
"""

from __future__ import annotations

import hashlib
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import NamedTuple

from app.platform.http.compression import gzipped

Clock = Callable[[], float]


class Kept(NamedTuple):
    body: bytes
    etag: str
    """Weak: the body may go gzipped (``http.compression``), a representation of its own."""
    gzipped: bytes | None
    """The body gzipped (``get(compress=True)``, bodies from 1 KiB), else None."""


class MapCache:
    """The maps served last (a PNG or a GeoJSON body, tens of kB to a few MB each), at most
    ``max_entries`` of them and ``max_bytes`` in all: a bbox varied at every request costs
    memory only up to that."""

    def __init__(
        self,
        ttl: float,
        max_entries: int = 64,
        max_bytes: int = 64 * 1024 * 1024,
        clock: Clock = time.monotonic,
    ) -> None:
        self.ttl = ttl
        self.max_entries = max_entries
        self.max_bytes = max_bytes
        self.clock = clock
        self._items: OrderedDict[Hashable, tuple[float, Kept]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def kept(self, key: Hashable) -> Kept | None:
        """The map for ``key`` while kept; None when it must be computed."""
        now = self.clock()
        with self._lock:
            item = self._items.get(key)
            if item is not None and now - item[0] < self.ttl:
                self._items.move_to_end(key)
                return item[1]
        return None

    def get(self, key: Hashable, compute: Callable[[], bytes], *, compress: bool = False) -> Kept:
        """The map for ``key``: kept, or computed now (and kept for ``ttl``); with
        ``compress``, its body gzipped too."""
        hit = self.kept(key)
        if hit is not None:
            return hit
        now = self.clock()
        body = compute()  # outside the lock: two first requests may both compute it
        etag = 'W/"' + hashlib.sha256(body).hexdigest()[:32] + '"'
        kept = Kept(body, etag, gzipped(body) if compress else None)
        size = _size(kept)
        if self.ttl > 0 and size <= self.max_bytes:
            with self._lock:
                old = self._items.pop(key, None)
                self._bytes -= _size(old[1]) if old else 0
                self._items[key] = (now, kept)
                self._bytes += size
                while len(self._items) > self.max_entries or self._bytes > self.max_bytes:
                    _, (_, dropped) = self._items.popitem(last=False)
                    self._bytes -= _size(dropped)
        return kept


def _size(kept: Kept) -> int:
    return len(kept.body) + len(kept.gzipped or b"")
