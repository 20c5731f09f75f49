"""What the repeated-parameter check (``app/query.py``) costs a frame upload, in-process.

Two minimal apps with a route shaped like the upload (a path parameter, an optional
``captured_at``), one with ``CheckedQuery`` and one without, alternating; process CPU per
request through httpx's ASGI transport, with and without a query string:

    python bench/query_guard.py
"""

from __future__ import annotations

import asyncio
import sys
import time
from pathlib import Path

from fastapi import FastAPI

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import httpx2 as httpx  # noqa: E402

from app.platform.http.query import CheckedQuery  # noqa: E402


def service(guarded: bool) -> FastAPI:
    app = FastAPI()

    @app.post("/cameras/{camera_id}/frames")
    async def upload(camera_id: str, captured_at: str | None = None) -> dict[str, str]:
        return {}

    if guarded:
        app.add_middleware(CheckedQuery, service=app)
    return app


async def cpu_per_request(app: FastAPI, n: int, query: str) -> float:
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://bench") as client:
        for _ in range(200):  # warm-up
            await client.post("/cameras/a/frames" + query)
        t0 = time.process_time()
        for _ in range(n):
            await client.post("/cameras/a/frames" + query)
        return (time.process_time() - t0) / n * 1e6


def main() -> None:
    for query in ("", "?captured_at=2026-01-01T00:00:00Z"):
        for _ in range(3):
            bare = asyncio.run(cpu_per_request(service(False), 3000, query))
            guarded = asyncio.run(cpu_per_request(service(True), 3000, query))
            print(f"query {query or '(none)'!r}: without {bare:.0f} µs, with {guarded:.0f} µs")


if __name__ == "__main__":
    main()
