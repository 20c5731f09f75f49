"""HEAD answered wherever GET is: the same status and headers, no body.

RFC 9110 §9.1 asks every general-purpose server to support HEAD, and load balancers and uptime
checks probe ``/health`` with it; FastAPI routes declare GET alone, so HEAD got 405 and a healthy
service looked down. Here a HEAD request runs as GET (a safe method: it changes nothing) and its
body is dropped; the headers, ``Content-Length`` among them, are GET's.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send


class HeadAsGet:
    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "HEAD":
            await self.app(scope, receive, send)
            return

        async def headers_only(message: Message) -> None:
            if message["type"] == "http.response.body":
                if message.get("more_body", False):
                    return
                message = {"type": "http.response.body", "body": b"", "more_body": False}
            await send(message)

        await self.app({**scope, "method": "GET"}, receive, headers_only)
