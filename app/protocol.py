"""uvicorn's HTTP/1.1 protocol, with bounds on what a client sends and how slowly it reads.

uvicorn bounds nothing a client sends. A connection that sends no byte, or its headers a byte
at a time, or stops in the middle of a body (a camera that lost power or its link mid-upload,
whose connection no FIN or RST ever ends), is held for good, with its file descriptor:
measured, 1,100 connections that sent nothing made a process with the usual limit of 1,024
files answer no one (`/health` reset at once) for as long as they stayed open. Its keep-alive
timeout runs only between requests, and any byte restarts it.

Here, as a reverse proxy's ``client_header_timeout``, ``client_body_timeout`` and
``send_timeout`` would:
- a request's line and headers must arrive within ``VANTAGE_REQUEST_HEADER_TIMEOUT_SECONDS``
  of its first byte (of the connection, for its first request);
- while its body arrives, no more than ``VANTAGE_REQUEST_IDLE_TIMEOUT_SECONDS`` may pass
  without a byte (a slow upload goes on for as long as bytes keep coming);
- while an answer is sent, no more than that may pass with the client reading nothing (a
  client that stops reading held the answer in memory and the connection for good: uvicorn's
  close waits for what it buffered to be sent).
- once the process is told to stop (SIGTERM), a body still arriving has
  ``VANTAGE_SHUTDOWN_GRACE_SECONDS`` more to come in whole: uvicorn waited for it however long
  it took (a camera on a bad link trickling its frame held a rolling restart until the
  orchestrator killed the process).
Past any, the connection is closed: the endpoint reading the body sees the client gone, and
nothing is stored. No deadline runs while the request is being answered, nor while the body
waits for the endpoint to read it (uvicorn stops reading past 64 kB unread).

And, as a proxy would: headers of more than ``MAX_HEADER_BYTES`` get 431, and a connection
pipelining more than ``MAX_PIPELINED`` requests is closed; uvicorn's httptools kept them all.

Served with ``uvicorn --http app.protocol:DeadlineProtocol`` (``python -m app.serve`` and
``make run`` do).
"""

from __future__ import annotations

import asyncio
import functools
import json
import logging
import os
from typing import Any, NamedTuple

from prometheus_client import Counter
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

log = logging.getLogger("vantage.protocol")

MAX_PIPELINED = 16
"""Requests a connection may send ahead of the answers (HTTP/1.1 pipelining, which browsers,
curl and cameras do not use). uvicorn parsed every one it received into a request of its own,
kept until answered: 1 MB of pipelined GETs made the process grow by 71 MB."""
HEADER_TIMEOUT_ENV = "VANTAGE_REQUEST_HEADER_TIMEOUT_SECONDS"
IDLE_TIMEOUT_ENV = "VANTAGE_REQUEST_IDLE_TIMEOUT_SECONDS"
SHUTDOWN_GRACE_ENV = "VANTAGE_SHUTDOWN_GRACE_SECONDS"
HEADER_TIMEOUT_S = 30.0
IDLE_TIMEOUT_S = 60.0
SHUTDOWN_GRACE_S = 20.0
"""Under the orchestrators' own grace before they kill (Kubernetes: 30 s)."""
MAX_HEADER_BYTES = 64 * 1024
"""A request's line and headers at most (nginx takes 32 kB, Node 16 kB). httptools, unlike h11,
bounds nothing: measured, one connection sent 300 MB of headers in 3 s and the process grew by
356 MB, its answer still pending; within the header deadline one client could have sent
gigabytes."""

CLOSED = Counter(
    "vantage_connections_timed_out_total",
    "Connections closed because the client sent its request, or read the answer, too slowly "
    "(phase shutdown: its body was still arriving after the stop's grace)",
    ["phase"],
)


class Deadlines(NamedTuple):
    """[s], as ``HEADER_TIMEOUT_ENV``, ``IDLE_TIMEOUT_ENV`` and ``SHUTDOWN_GRACE_ENV`` say."""

    header: float
    idle: float
    grace: float


@functools.cache
def deadlines() -> Deadlines:
    """The header and idle timeouts and the shutdown grace [s], from the environment as the
    settings read theirs: uvicorn makes the protocol apart from the application. Read once;
    ``app.serve`` reads them before serving, so that a wrong value stops the start, not each
    connection."""
    return Deadlines(
        _seconds(HEADER_TIMEOUT_ENV, HEADER_TIMEOUT_S),
        _seconds(IDLE_TIMEOUT_ENV, IDLE_TIMEOUT_S),
        _seconds(SHUTDOWN_GRACE_ENV, SHUTDOWN_GRACE_S),
    )


def _seconds(name: str, default: float) -> float:
    raw = os.environ.get(name)
    if raw is None:
        return default
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not 0 < value <= 3600:
        raise SystemExit(f"{name} must be a number of seconds in (0, 3600], not {raw!r}")
    return value


class DeadlineProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol, closing connections whose client is too slow or sends
    too much. Where a request stands comes from the parser's own callbacks (a message begun,
    its headers in, its end parsed): the body of a request answered early (401, 413) goes on
    arriving after its answer, and is neither the next request's headers nor exempt."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._header_timeout, self._idle_timeout, self._grace = deadlines()
        self._stopping_since: float | None = None
        """When the server was told to stop, or None."""
        self._headers_since: float | None = None
        """When the request whose headers are awaited began (its first byte; the connection's
        opening for its first): None while no headers are awaited."""
        self._header_bytes = 0
        """Bytes received since the last request's headers were in (the next's line and
        headers, and what came with them)."""
        self._in_body = False
        """The request's headers are in and the end of its body is not."""
        self._last_byte = 0.0
        self._stalled_since: float | None = None
        """Since when the answer waits for the client to read what was sent (uvicorn stops
        writing past 64 kB unsent)."""
        self._timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._headers_since = self._last_byte = self.loop.time()
        self._watch()

    # the parser's callbacks, in the order a request makes them
    def on_message_begin(self) -> None:
        super().on_message_begin()
        if self._headers_since is None:  # a kept-alive connection's next request
            self._headers_since = self.loop.time()

    def on_headers_complete(self) -> None:
        super().on_headers_complete()
        self._headers_since = None
        self._header_bytes = 0
        self._in_body = True

    def on_message_complete(self) -> None:
        super().on_message_complete()
        self._in_body = False

    def data_received(self, data: bytes) -> None:
        self._last_byte = self.loop.time()
        awaited = self._headers_since is not None
        if not self._in_body:
            # a request's line and headers, counted as they come: httptools keeps a header
            # line unfinished in a buffer of its own, which no callback shows
            self._header_bytes += len(data)
        super().data_received(data)
        if self.transport.is_closing():
            return  # a request the parser refused (400), answered and closed
        if self._headers_since is not None and self._header_bytes > MAX_HEADER_BYTES:
            self._refuse_headers()
            return
        if len(self.pipeline) > MAX_PIPELINED:
            CLOSED.labels("pipelined").inc()
            self.transport.close()  # what is queued is dropped with it
            return
        if self._timer is None or (self._headers_since is not None and not awaited):
            # else the timer armed already fires no later than the deadline now (a body's
            # bytes only move it on), and looks again then
            self._watch()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._watch()

    def pause_writing(self) -> None:
        super().pause_writing()
        self._stalled_since = self.loop.time()
        self._watch()

    def resume_writing(self) -> None:
        super().resume_writing()
        self._stalled_since = None

    def shutdown(self) -> None:
        """The server stops: uvicorn closes the connection if it is between requests, else
        lets the request finish and closes it then; a body still arriving gets the grace."""
        self._stopping_since = self.loop.time()
        super().shutdown()
        self._watch()

    def connection_lost(self, exc: Exception | None) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        super().connection_lost(exc)

    def _refuse_headers(self) -> None:
        """431 and close: headers past ``MAX_HEADER_BYTES`` and still coming."""
        CLOSED.labels("header_size").inc()
        body = json.dumps(
            {
                "type": "about:blank",
                "title": "Request header fields too large",
                "status": 431,
                "detail": f"the request's line and headers exceed {MAX_HEADER_BYTES} bytes",
                "code": "headers_too_large",
            }
        ).encode()
        self.transport.write(
            b"HTTP/1.1 431 Request Header Fields Too Large\r\n"
            b"content-type: application/problem+json\r\n"
            b"content-length: %d\r\nconnection: close\r\n\r\n%s" % (len(body), body)
        )
        self.transport.close()

    def _deadline(self) -> tuple[float, str] | None:
        """When the connection is to be closed, and why; None while no deadline runs."""
        if self._stalled_since is not None:
            return self._stalled_since + self._idle_timeout, "response"
        if self._headers_since is not None:
            return self._headers_since + self._header_timeout, "headers"
        if not self._in_body:
            return None  # between requests (uvicorn's keep-alive), or being answered
        if self.flow.read_paused:  # the endpoint has not read what came: not the client's
            self._last_byte = self.loop.time()
            return None
        idle = self._last_byte + self._idle_timeout
        if self._stopping_since is not None and self._stopping_since + self._grace < idle:
            return self._stopping_since + self._grace, "shutdown"
        return idle, "body"

    def _watch(self) -> None:
        """Arm the one timer for the deadline that runs now (or for a look later), unless it
        is armed for no later already: a body's bytes move its deadline on, and the timer,
        once it fires, looks again rather than being set anew for every chunk."""
        if self.transport.is_closing() and self._stalled_since is None:
            return  # closed, or closing with nothing left to send
        deadline = self._deadline()
        at = self.loop.time() + self._idle_timeout if deadline is None else deadline[0]
        if self._timer is not None:
            if self._timer.when() <= at:
                return
            self._timer.cancel()
        self._timer = self.loop.call_at(at, self._expire)

    def _expire(self) -> None:
        self._timer = None
        deadline = self._deadline()
        if self.transport.is_closing() and self._stalled_since is None:
            return
        if deadline is None or deadline[0] > self.loop.time():
            self._watch()
            return
        phase = deadline[1]
        CLOSED.labels(phase).inc()
        log.debug("connection from %s closed: its %s was too slow", self.client, phase)
        # close() would wait to send what is buffered: for good, to a client that reads nothing
        self.transport.abort()
