"""Webhook delivery as Standard Webhooks (https://www.standardwebhooks.com) describes it.

Each POST carries ``webhook-id`` (the same on every attempt of one message: a receiver drops a
repeat by it), ``webhook-timestamp`` (the attempt's Unix time) and, with a signing secret,
``webhook-signature`` (``v1,`` and the base64 HMAC-SHA256 of ``id.timestamp.body``), so a
receiver can tell the service's messages from anyone's who learnt its address, with any
Standard Webhooks library. Only a 2xx answer to the POST itself is a delivery; a redirect is
not followed (urllib would follow a 301 or 302 with a GET without the message). A failed
attempt waits ``backoff`` before the next.
"""

from __future__ import annotations

import asyncio
import base64
import binascii
import contextlib
import hashlib
import hmac
import http.client
import json
import logging
import socket
import threading
import urllib.error
import urllib.request
import uuid
from collections.abc import Callable
from datetime import datetime, timedelta
from functools import partial
from typing import Any
from urllib.parse import urlsplit

from sqlalchemy.orm import Session, sessionmaker

from app.platform.background import in_thread

log = logging.getLogger("vantage.webhooks")

TIMEOUT_S = 5.0
"""How long a POST waits to connect, and for each read of the answer."""


DEADLINE_S = 10.0
"""How long a POST may take in all, its whole answer read."""


RETRY_CAP = timedelta(minutes=10)
"""The longest wait between two attempts."""


def backoff(attempts: int) -> timedelta:
    """The wait after the ``attempts``-th failure: 2, 4, 8 … s, at most ``RETRY_CAP``."""
    return min(timedelta(seconds=2 ** min(attempts, 20)), RETRY_CAP)


def check_url(url: str) -> str:
    """A receiver's URL: http or https with a host. Raises ValueError otherwise."""
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ValueError(f"a webhook URL is http(s)://host/…; got {url!r}")
    return url


SECRET_PREFIX = "whsec_"


def signing_key(secret: str) -> bytes:
    """The key of a Standard Webhooks secret: ``whsec_`` and the base64 of 24–64 random bytes
    (the README shows a command that makes one). Raises ValueError for anything else."""
    try:
        key = base64.b64decode(secret.removeprefix(SECRET_PREFIX), validate=True)
    except (binascii.Error, ValueError):
        raise ValueError("a webhook secret is 'whsec_' and base64") from None
    if not 24 <= len(key) <= 64:
        raise ValueError(f"a webhook secret holds 24–64 bytes; this one {len(key)}")
    return key


def signature(key: bytes, msg_id: str, timestamp: int, body: bytes) -> str:
    """Standard Webhooks' ``v1`` signature: HMAC-SHA256 of ``{id}.{timestamp}.{body}``."""
    mac = hmac.new(key, f"{msg_id}.{timestamp}.".encode() + body, hashlib.sha256).digest()
    return "v1," + base64.b64encode(mac).decode()


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args: object, **kwargs: object) -> None:
        return None  # the 3xx then raises HTTPError


def _connect(
    address: tuple[str, int], timeout: float | None = None, source: Any = None
) -> socket.socket:
    """``socket.create_connection``, its name lookup bounded by ``TIMEOUT_S`` too. The lookup
    runs in a thread of its own and is left behind when it does not answer in time (its
    answer then goes nowhere: nothing is sent). The resolver's own bound lies beyond the
    POST's deadline (glibc's defaults: up to 30 s with no name server answering)."""
    host, port = address
    answer: list[list[tuple[Any, ...]] | OSError] = []
    answered = threading.Event()

    def lookup() -> None:
        try:
            answer.append(socket.getaddrinfo(host, port, type=socket.SOCK_STREAM))
        except OSError as exc:
            answer.append(exc)
        finally:
            answered.set()

    threading.Thread(target=lookup, name="webhook-lookup", daemon=True).start()
    if not answered.wait(TIMEOUT_S):
        raise TimeoutError(f"no address for {host!r} within {TIMEOUT_S:g} s")
    found = answer[0]
    if isinstance(found, OSError):
        raise found
    failed: OSError = OSError(f"no address for {host!r}")
    for *_, sockaddr in found:  # in the resolver's order, as create_connection tries them
        try:
            return socket.create_connection((sockaddr[0], sockaddr[1]), timeout, source)
        except OSError as exc:
            failed = exc
    raise failed


class _Kept:
    """Keeps the connections its handler opens (in ``made``), so that they can be cut, and
    bounds their name lookup (``_connect``)."""

    def __init__(self, made: list[http.client.HTTPConnection]) -> None:
        super().__init__()
        self.made = made

    def do_open(self, http_class: Any, req: urllib.request.Request, **kwargs: Any) -> Any:
        def connection(*args: Any, **kw: Any) -> http.client.HTTPConnection:
            made: http.client.HTTPConnection = http_class(*args, **kw)
            made._create_connection = _connect  # type: ignore[attr-defined]
            self.made.append(made)
            return made

        return super().do_open(connection, req, **kwargs)  # type: ignore[misc]


class _KeptHTTP(_Kept, urllib.request.HTTPHandler):
    pass


class _KeptHTTPS(_Kept, urllib.request.HTTPSHandler):
    pass


class DeliveryFailed(Exception):
    """The receiver did not take the alert."""


def _cut(made: list[http.client.HTTPConnection], cut: threading.Event) -> None:
    """Shut the POST's sockets down: the read blocked on one returns at once."""
    cut.set()
    for connection in made:
        if connection.sock is not None:
            with contextlib.suppress(OSError):
                connection.sock.shutdown(socket.SHUT_RDWR)


def post(url: str, body: bytes, headers: dict[str, str]) -> None:
    """POST ``body``; raise DeliveryFailed unless the receiver answers 2xx within
    ``DEADLINE_S``. ``TIMEOUT_S`` bounds each wait on the socket, which a receiver sending its
    answer a byte every few seconds never meets: the sockets are shut down at the deadline,
    so one slow receiver cannot hold the sweep past its claim."""
    request = urllib.request.Request(
        url,
        data=body,
        headers={"Content-Type": "application/json", "User-Agent": "vantage-alerts", **headers},
        method="POST",
    )
    made: list[http.client.HTTPConnection] = []
    cut = threading.Event()
    opener = urllib.request.build_opener(_NoRedirect, _KeptHTTP(made), _KeptHTTPS(made))
    deadline = threading.Timer(DEADLINE_S, _cut, (made, cut))
    deadline.daemon = True
    deadline.start()
    try:
        with opener.open(request, timeout=TIMEOUT_S) as response:
            if cut.is_set():  # http.client takes the end of what came for the end of headers
                raise DeliveryFailed(f"no whole answer within {DEADLINE_S:g} s")
            if not 200 <= response.status < 300:
                raise DeliveryFailed(f"HTTP {response.status}")
    except (OSError, http.client.HTTPException) as exc:
        if cut.is_set():
            raise DeliveryFailed(f"no whole answer within {DEADLINE_S:g} s") from None
        raise _failed(exc) from None
    finally:
        deadline.cancel()


def _failed(exc: OSError | http.client.HTTPException) -> DeliveryFailed:
    """Why the POST failed, from what urllib raised: an HTTP error, or the connection refused,
    timed out, not HTTP, cut."""
    if isinstance(exc, urllib.error.HTTPError):
        if 300 <= exc.code < 400:
            return DeliveryFailed(
                f"HTTP {exc.code} redirect to {exc.headers.get('Location')!r}, not followed:"
                " set the webhook URL to the address that takes the POST"
            )
        return DeliveryFailed(f"HTTP {exc.code} {exc.reason}")
    return DeliveryFailed(f"{type(exc).__name__}: {exc}")


def signed_headers(msg_id: str, body: bytes, now: datetime, key: bytes | None) -> dict[str, str]:
    """The Standard Webhooks headers of a POST made at ``now``."""
    sent = int(now.timestamp())
    headers = {"webhook-id": msg_id, "webhook-timestamp": str(sent)}
    if key is not None:
        headers["webhook-signature"] = signature(key, msg_id, sent, body)
    return headers


def send_test(url: str, now: datetime, *, key: bytes | None) -> tuple[str, str | None]:
    """POST a test alert (``kind: "test"``, recorded nowhere) as the sweep posts alerts:
    its id, and why it was not taken (None when the receiver answered 2xx)."""
    msg_id = f"test_{uuid.uuid4()}"
    body = json.dumps(
        {
            "alert_id": msg_id,
            "kind": "test",
            "created_at": now.isoformat(),
            "message": "A test of the air-quality alert webhook: no air was measured.",
        }
    ).encode()
    try:
        post(url, body, signed_headers(msg_id, body, now, key))
    except DeliveryFailed as exc:
        return msg_id, str(exc)[:500]
    return msg_id, None


Claim = Callable[[datetime], "tuple[str, int, bytes] | None"]
"""Takes the next due message at a time, committed as claimed: its id, its attempts with this
one, and the body to POST; None when none is due."""


def deliver_due(
    sessions: sessionmaker[Session],
    model: type[Any],
    claim: Claim,
    url: str,
    clock: Callable[[], datetime],
    *,
    key: bytes | None,
    batch: int,
    stopping: threading.Event | None,
    outcome: Callable[[bool], None] | None = None,
) -> int:
    """POST each due message once (at most ``batch``), one at a time; returns how many were
    delivered. ``model`` is the stored message's class (its ``delivered``, ``last_error`` and
    ``next_attempt_at`` record each outcome); ``outcome`` hears of each once it is recorded.

    Each message is claimed, posted and recorded in turn: a process that dies during a sweep
    sends again, once its claim has run out, at most the message it was posting. The POST
    holds no transaction (a receiver that never answers would hold a database connection, with
    SQLite every request's). Once ``stopping`` is set (a shutdown waiting for this sweep), the
    messages not yet tried are left for the next one."""
    delivered = 0
    for _ in range(batch):
        if stopping is not None and stopping.is_set():
            break
        # the time of each attempt, not the sweep's start: a sweep of many messages to a slow
        # receiver takes minutes, and a claim dated from its start would run out before it
        # was posted (another process would then send it too)
        now = clock()
        claimed = claim(now)
        if claimed is None:
            break
        message_id, attempts, body = claimed
        try:
            post(url, body, signed_headers(message_id, body, now, key))
        except DeliveryFailed as exc:
            error: str | None = str(exc)[:500]
            log.warning("%s not delivered (attempt %d): %s", message_id, attempts, exc)
        else:
            error = None
            delivered += 1
        with sessions() as session:
            message = session.get(model, message_id)
            if message is not None:  # not swept away by retention meanwhile
                message.delivered = error is None
                message.last_error = error
                message.next_attempt_at = None if error is None else now + backoff(attempts)
                session.commit()
        if outcome is not None:
            outcome(error is None)
    return delivered


async def keep_sweeping(
    sweep: Callable[[threading.Event], object], every: float, what: str
) -> None:
    """Run ``sweep`` every ``every`` seconds forever (until cancelled), in a worker thread so the
    event loop stays free; a shutdown sets its event and waits for the POST under way, not for
    the rest. ``what`` names the sweep in the log."""
    stopping = threading.Event()
    while True:
        try:
            await in_thread(partial(sweep, stopping), on_cancel=stopping.set)
        except Exception:
            log.exception("webhook sweep of %s failed", what)
        await asyncio.sleep(every)
