"""Cross-origin reads of the public air-quality endpoints, for dashboards in a browser.

Every ``GET /air/...`` is public (no token), and a city's dashboard is usually served from
another origin than the service: without ``Access-Control-Allow-Origin`` the browser hides
the answer from the page. Only those paths answer cross-origin, and only to GET without
credentials or custom headers, so a page elsewhere can read the map but cannot call an
admin endpoint with a token it holds. The other paths (the frame upload above all) pass
straight through, with no CORS work on them.
"""

from __future__ import annotations

from collections.abc import Sequence

from starlette.middleware.cors import CORSMiddleware
from starlette.types import ASGIApp, Receive, Scope, Send

PUBLIC_PREFIX = "/air/"
EXPOSED = ["Link", "ETag", "Retry-After", "X-Request-ID"]
"""Headers a page may read besides the CORS-safelisted ones (Content-Type, Cache-Control …):
without ``Link`` a dashboard elsewhere could not page through the readings, whose next page
only ``Link`` names."""


class PublicReadCors:
    def __init__(self, app: ASGIApp, *, origins: Sequence[str]) -> None:
        self.app = app
        self.cors = CORSMiddleware(
            app,
            allow_origins=list(origins),
            allow_methods=["GET"],
            allow_headers=["If-None-Match"],  # a page revalidating the map itself
            expose_headers=EXPOSED,
            max_age=600,
        )

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["path"].startswith(PUBLIC_PREFIX):
            await self.cors(scope, receive, send)
        else:
            await self.app(scope, receive, send)
