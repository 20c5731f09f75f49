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
    """The last ``max_entries`` maps (a PNG or a GeoJSON body, tens of kB to a few MB)."""

    def __init__(self, ttl: float, max_entries: int = 64, clock: Clock = time.monotonic) -> None:
        self.ttl = ttl
        self.max_entries = max_entries
        self.clock = clock
        self._items: OrderedDict[Hashable, tuple[float, bytes, str]] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: Hashable, compute: Callable[[], bytes]) -> tuple[bytes, str]:
        """The body for ``key`` and its ETag: kept, or computed now (and kept for ``ttl``)."""
        now = self.clock()
        with self._lock:
            item = self._items.get(key)
            if item is not None and now - item[0] < self.ttl:
                self._items.move_to_end(key)
                return item[1], item[2]
        body = compute()  # outside the lock: two first requests may both compute it
        etag = '"' + hashlib.sha256(body).hexdigest()[:32] + '"'
        if self.ttl > 0:
            with self._lock:
                self._items[key] = (now, body, etag)
                self._items.move_to_end(key)
                while len(self._items) > self.max_entries:
                    self._items.popitem(last=False)
        return body, etag


def not_modified(if_none_match: str | None, etag: str) -> bool:
    """Whether a client's ``If-None-Match`` names this ETag (or ``*``)."""
    if not if_none_match:
        return False
    tags = {t.strip().removeprefix("W/") for t in if_none_match.split(",")}
    return etag in tags or "*" in tags
