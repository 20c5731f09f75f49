"""The isopleth maps served, each computed at most once per ``ttl`` seconds a process.

``GET /air/isopleths`` (and its PNG) is public and dashboards poll it. Interpolating and
contouring takes from milliseconds (IDW, 50 cameras) to seconds (kriging, thousands of
cameras: ``bench/isopleths.py``), and every viewer's poll recomputed a map that a city's
readings change only slowly, so a dashboard with many viewers, or anyone on the internet,
could keep the cores busy. A map is kept for ``ttl`` seconds by its request (representation,
bbox, window, method, resolution, max_distance); its ``computed_at`` says when it was made,
and its ETag (a digest of the body) lets a client revalidate it for a 304.
"""

from __future__ import annotations

import hashlib
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable

Clock = Callable[[], float]


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
        self._items: OrderedDict[Hashable, tuple[float, bytes, str]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def kept(self, key: Hashable) -> tuple[bytes, str] | None:
        """The body for ``key`` and its ETag while kept; None when it must be computed."""
        now = self.clock()
        with self._lock:
            item = self._items.get(key)
            if item is not None and now - item[0] < self.ttl:
                self._items.move_to_end(key)
                return item[1], item[2]
        return None

    def get(self, key: Hashable, compute: Callable[[], bytes]) -> tuple[bytes, str]:
        """The body for ``key`` and its ETag: kept, or computed now (and kept for ``ttl``)."""
        hit = self.kept(key)
        if hit is not None:
            return hit
        now = self.clock()
        body = compute()  # outside the lock: two first requests may both compute it
        # weak: the body may go gzipped (app.compression), a representation of its own
        etag = 'W/"' + hashlib.sha256(body).hexdigest()[:32] + '"'
        if self.ttl > 0 and len(body) <= self.max_bytes:
            with self._lock:
                old = self._items.pop(key, None)
                self._bytes -= len(old[1]) if old else 0
                self._items[key] = (now, body, etag)
                self._bytes += len(body)
                while len(self._items) > self.max_entries or self._bytes > self.max_bytes:
                    _, (_, dropped, _) = self._items.popitem(last=False)
                    self._bytes -= len(dropped)
        return body, etag
