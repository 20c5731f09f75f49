"""Anonymous crowds: per-client rate limits on requests without a token, and a bounded queue
for the public computations.

Anyone may call the public endpoints (the air readings, maps, pages), so a crowd, or one
client in a loop, could hold the process's CPU and keep cameras' uploads waiting. Two limits
per client address, kept in this process by the ``limits`` library's moving window: every
request without a token (``VANTAGE_PUBLIC_REQUESTS_PER_MINUTE``), and of those the ones that
compute (maps, aggregates: ``VANTAGE_PUBLIC_WORK_PER_MINUTE``); past either, 429 with
Retry-After. The computations themselves run one at a time (``public_work``) and at most
``VANTAGE_PUBLIC_WORK_QUEUE`` wait for their turn: one more is answered 503 with Retry-After
at once, instead of waiting tens of seconds behind the others. nginx's ``limit_req`` is the
first line in front of several processes (deploy/nginx.conf); these hold for one process
served alone.

A refusal is answered at once, ten times a minute per client; a client that keeps asking
regardless (it ignores Retry-After) has its further refusals held for ``TARPIT_SECONDS``
first, a wait that costs the process no CPU. Answered at once, a flood in a tight loop came
straight back: 50 such clients drew ~900 refusals a second and the cameras' uploads fell
from 132 to 19 a second (bench/crowds.py). The client is the connection's peer: behind a
proxy, uvicorn's ``--forwarded-allow-ips`` makes it the proxy's ``X-Forwarded-For``.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from collections import OrderedDict

from limits import RateLimitItemPerMinute
from limits.storage import MemoryStorage
from limits.strategies import MovingWindowRateLimiter
from starlette.requests import Request
from starlette.types import ASGIApp, Receive, Scope, Send

from app.platform.auth import hash_token
from app.platform.http.credentials import credentials_of
from app.platform.http.errors import (
    ServiceUnavailable,
    TooManyRequests,
    Unauthorized,
    problem,
)

TARPIT_SECONDS = 1.0
"""How long a client's refusals past ``FAST_REFUSALS`` a minute wait before they are sent."""
FAST_REFUSALS = RateLimitItemPerMinute(10)
TRUST_SECONDS = 600.0
"""How long an accepted token's requests skip the anonymous limits before it is checked again."""
MAX_TRUSTED = 100_000

EXEMPT = ("/health", "/metrics")
"""Probes and scrapers: never limited (a load balancer's checks must not be refused)."""


def client_of(scope: Scope) -> str:
    client = scope.get("client")
    return str(client[0]) if client else "unknown"


def _token(scope: Scope) -> str | None:
    """The token an Authorization header carries, unchecked; None without one or when it is
    malformed (the request counts as anonymous, and its route says why)."""
    for name, value in scope.get("headers", []):
        if name == b"authorization":
            try:
                return credentials_of(value.decode("latin-1"))[0]
            except Unauthorized:
                return None
    return None


class Crowds:
    """This process's limits on anonymous callers and its public work queue."""

    def __init__(self, *, requests_per_minute: int, work_per_minute: int, queue: int) -> None:
        self.limiter = MovingWindowRateLimiter(MemoryStorage())
        self.requests = RateLimitItemPerMinute(requests_per_minute) if requests_per_minute else None
        self.work = RateLimitItemPerMinute(work_per_minute) if work_per_minute else None
        self.queue = queue
        self._waiting = 0
        self._lock = threading.Lock()
        self._trusted: OrderedDict[str, float] = OrderedDict()
        """Hashes of tokens the service accepted lately → until when they count as known."""

    @property
    def waiting(self) -> int:
        """Public computations running or waiting now."""
        with self._lock:
            return self._waiting

    def trust(self, digest: str) -> None:
        """A token (its hash) the service just accepted: its requests skip the anonymous
        limits for ``TRUST_SECONDS`` (a revoked token is refused by the routes anyway)."""
        with self._lock:
            self._trusted[digest] = time.monotonic() + TRUST_SECONDS
            self._trusted.move_to_end(digest)
            while len(self._trusted) > MAX_TRUSTED:
                self._trusted.popitem(last=False)

    def anonymous(self, scope: Scope) -> bool:
        """Whether the request counts as anonymous: no token, or one not accepted lately (a
        made-up header buys nothing)."""
        token = _token(scope)
        if token is None:
            return True
        digest = hash_token(token)
        with self._lock:
            until = self._trusted.get(digest)
        return until is None or until < time.monotonic()

    def _retry_after(self, item: RateLimitItemPerMinute, *identifiers: str) -> int:
        reset = self.limiter.get_window_stats(item, *identifiers).reset_time
        return max(1, math.ceil(reset - time.time()))

    def refusal_delay(self, scope: Scope) -> float:
        """Seconds to hold this client's refusal before sending it: 0 for its first ten a
        minute, ``TARPIT_SECONDS`` after."""
        fast = self.limiter.hit(FAST_REFUSALS, "refused", client_of(scope))
        return 0.0 if fast else TARPIT_SECONDS

    def request_refusal(self, scope: Scope) -> int | None:
        """Seconds to wait when this anonymous request is one too many, else None (counted)."""
        if self.requests is None or scope["path"] in EXEMPT or not self.anonymous(scope):
            return None
        key = client_of(scope)
        if self.limiter.hit(self.requests, "requests", key):
            return None
        return self._retry_after(self.requests, "requests", key)

    def enter_work(self, request: Request) -> None:
        """Take a place among the public computations running or waiting (``leave_work``
        gives it back). 429 when an anonymous client has asked for too many this minute; 503
        when ``queue`` places are taken. Callers with a token skip the per-client limit, not
        the queue."""
        if self.work is not None and self.anonymous(request.scope):
            key = client_of(request.scope)
            if not self.limiter.hit(self.work, "work", key):
                wait = self._retry_after(self.work, "work", key)
                raise TooManyRequests(
                    f"more than {self.work.amount} computed maps or aggregates a minute from "
                    "one client; cached maps are not counted",
                    retry_after=wait,
                    code="rate_limited",
                )
        with self._lock:
            if self._waiting >= self.queue:
                raise ServiceUnavailable(
                    f"{self.queue} public computations are waiting already: try again later",
                    retry_after=2,
                    code="busy",
                )
            self._waiting += 1

    def leave_work(self) -> None:
        with self._lock:
            self._waiting -= 1


class AnonymousLimit:
    """ASGI middleware: the per-client limit on requests without a token (``Crowds``)."""

    def __init__(self, app: ASGIApp, *, crowds: Crowds) -> None:
        self.app = app
        self.crowds = crowds

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            wait = self.crowds.request_refusal(scope)
            if wait is not None:
                await asyncio.sleep(self.crowds.refusal_delay(scope))
                response = problem(
                    429,
                    "Too many requests",
                    "too many requests without a token from this client; try again after "
                    "Retry-After",
                    headers={"Retry-After": str(wait)},
                    code="rate_limited",
                )
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)
