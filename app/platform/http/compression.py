"""GET answers compressed for clients that accept gzip: a city's map, readings and latest levels.

A dashboard's pulls are large JSON that compresses well: with 1,000 cameras the isopleths are
257 kB (41 kB gzipped), ``/air/latest`` 245 kB (23 kB) and a page of 1,000 readings 150 kB
(7 kB). Starlette's ``GZipMiddleware`` does the work (bodies from 1 KiB, JPEG and PNG left
alone, the largest compressed off the event loop); this layer only keeps it to GET (and so
HEAD, answered as GET): the frame upload's small verdict is not worth it, and every frame
would pay for the layer.

Validators stay right: a representation compressed here differs from the identity one, so a
strong ETag would name two different bodies; the service's ETags on compressible bodies are
weak (``W/"…"``, the map's), and ``If-None-Match`` compares weakly (RFC 9110 §13.1.2).
"""

from __future__ import annotations

import gzip

from starlette.datastructures import Headers, MutableHeaders
from starlette.middleware.gzip import GZipMiddleware
from starlette.types import ASGIApp, Message, Receive, Scope, Send

MINIMUM_BYTES = 1024
"""Smaller bodies go as they are: a few hundred bytes saved at most."""
LEVEL = 6
"""zlib's default: Starlette's level 9 costs several times the CPU for bodies a few per cent
smaller (bench/README.md, "Dashboards' answers gzipped")."""

OFF_LOOP_BYTES = 32 * 1024
"""Bodies from this size are compressed on a worker thread (Starlette's default: 128 KiB). The
map compressed at ~12 µs a kB at level 6 (257 kB in 3.06 ms), so a body just under 128 KiB held
the event loop, and every upload waiting on it, for ~1.5 ms; under 32 KiB, ~0.4 ms at most."""


def gzipped(body: bytes) -> bytes | None:
    """``body`` gzipped as this layer sends it, for a body kept and served many times (the map
    cache compresses once, not at every poll); None below ``MINIMUM_BYTES``, which go as they
    are."""
    return gzip.compress(body, LEVEL, mtime=0) if len(body) >= MINIMUM_BYTES else None


def accepts_gzip(headers: Headers) -> bool:
    """Whether the request takes gzip (read as Starlette's ``GZipMiddleware`` reads it)."""
    return "gzip" in headers.get("accept-encoding", "")


class CompressedReads:
    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self.gzip = GZipMiddleware(app, MINIMUM_BYTES, LEVEL, thread_minimum_size=OFF_LOOP_BYTES)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "GET":
            await self.app(scope, receive, send)
            return
        await self.gzip(scope, receive, _weak_etag_when_gzipped(send))


def _weak_etag_when_gzipped(send: Send) -> Send:
    """A strong ETag names one byte sequence, so the gzipped body, another one, goes with it
    made weak (RFC 9110 §8.8.1): the docs pages' static files carry Starlette's strong ETags.
    ``If-None-Match`` compares weakly, so the client's next request still gets its 304."""

    async def wrapped(message: Message) -> None:
        if message["type"] == "http.response.start":
            headers = MutableHeaders(scope=message)
            etag = headers.get("etag")
            if headers.get("content-encoding") == "gzip" and etag and not etag.startswith("W/"):
                headers["etag"] = f"W/{etag}"
        await send(message)

    return wrapped
