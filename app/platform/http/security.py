"""Security headers on every answer: what a browser may run, embed and send on.

Every response says ``X-Content-Type-Options: nosniff`` and ``Referrer-Policy: no-referrer``.
HTML answers (the pages, ``/docs``, ``/redoc``) carry a Content-Security-Policy that runs no
inline script: the pages load their scripts from ``/static`` and read their settings from a
``<script type="application/json">`` block (data, never executed); the documentation pages'
few inline scripts are allowed by their SHA-256 hashes (CSP Level 2 §4.2.4), computed from
the page as served. Those pages are made by FastAPI from the app's own settings, never from
what a client stored, so hashing them allows nothing an attacker wrote. Who may frame the
pages is ``frame-ancestors`` (``'none'`` unless the operator lists origins).
"""

from __future__ import annotations

import base64
import hashlib
import re
from collections.abc import Iterable
from urllib.parse import urlsplit

from starlette.datastructures import MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

_INLINE_SCRIPT = re.compile(rb"<script(?![^>]*\bsrc=)[^>]*>(.*?)</script>", re.S | re.I)


def tile_source(template: str) -> str | None:
    """The CSP source of a Leaflet tile URL template (``{s}`` subdomains as ``*``); None when
    the template names no http(s) host."""
    parts = urlsplit(template.replace("{s}", "*"))
    if parts.scheme not in ("http", "https") or not parts.netloc:
        return None
    return f"{parts.scheme}://{parts.netloc}"


def script_hashes(html: bytes) -> list[str]:
    """``'sha256-…'`` of each inline script of ``html`` (those without ``src``)."""
    return [
        "'sha256-" + base64.b64encode(hashlib.sha256(m.group(1)).digest()).decode() + "'"
        for m in _INLINE_SCRIPT.finditer(html)
        if m.group(1).strip()
    ]


class SecurityHeaders:
    """Adds the headers above. ``docs_paths``: HTML made by the framework whose inline scripts
    are allowed by hash; ``img_sources``: where the pages' images may come from besides the
    service (map tiles); ``frame_ancestors``: origins that may frame the pages."""

    def __init__(
        self,
        app: ASGIApp,
        *,
        docs_paths: Iterable[str],
        img_sources: Iterable[str] = (),
        frame_ancestors: Iterable[str] = (),
    ) -> None:
        self.app = app
        self.docs_paths = frozenset(docs_paths)
        ancestors = " ".join(frame_ancestors) or "'none'"
        self.frame_ancestors = ancestors
        images = " ".join(["'self'", "data:", "blob:", *img_sources])
        self.page_policy = "; ".join(
            [
                "default-src 'self'",
                "script-src 'self'",
                "style-src 'self' 'unsafe-inline'",  # Leaflet and Chart.js set styles
                f"img-src {images}",
                "connect-src 'self'",
                "object-src 'none'",
                "base-uri 'none'",
                "form-action 'self'",
                f"frame-ancestors {ancestors}",
            ]
        )

    def docs_policy(self, html: bytes) -> str:
        scripts = " ".join(["'self'", *script_hashes(html)])
        return "; ".join(
            [
                "default-src 'self'",
                f"script-src {scripts}",
                "style-src 'self' 'unsafe-inline'",
                "img-src 'self' data:",
                "worker-src 'self' blob:",  # ReDoc's search runs in a worker
                "connect-src 'self'",
                "object-src 'none'",
                "base-uri 'none'",
                f"frame-ancestors {self.frame_ancestors}",
            ]
        )

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        docs = scope["path"] in self.docs_paths
        held: list[Message] = []

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                headers["X-Content-Type-Options"] = "nosniff"
                headers["Referrer-Policy"] = "no-referrer"
                html = headers.get("content-type", "").startswith("text/html")
                if html and docs:
                    held.append(message)  # its policy needs the body's scripts
                    return
                if html:
                    headers["Content-Security-Policy"] = self.page_policy
                    if self.frame_ancestors == "'none'":
                        headers["X-Frame-Options"] = "DENY"
            elif held:
                held.append(message)
                if message.get("more_body", False):
                    return
                start, *parts = held
                body = b"".join(p.get("body", b"") for p in parts)
                headers = MutableHeaders(scope=start)
                headers["Content-Security-Policy"] = self.docs_policy(body)
                if self.frame_ancestors == "'none'":
                    headers["X-Frame-Options"] = "DENY"
                await send(start)
                await send({"type": "http.response.body", "body": body, "more_body": False})
                return
            await send(message)

        await self.app(scope, receive, with_headers)
