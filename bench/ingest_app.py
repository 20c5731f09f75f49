"""The service plus a bare endpoint that only decodes and histograms: the ingest ceiling."""

from __future__ import annotations

import asyncio
import os
from concurrent.futures import ThreadPoolExecutor

from fastapi import FastAPI, Request
from fastapi.concurrency import run_in_threadpool

from app.main import create_app
from app.platform.frames.jpeg import decode_rgb
from app.platform.frames.stats import channel_stats
from app.platform.http.uploads import read_capped

BARE_THREADS_ENV = "VANTAGE_BENCH_BARE_THREADS"
"""Threads the bare endpoint decodes on: unset, as many as the ingest's preparing threads (the
same pool size side by side); 0, FastAPI's shared thread pool (40 threads)."""


def create_bench_app() -> FastAPI:
    app = create_app()
    settings = app.state.settings
    threads = int(os.environ.get(BARE_THREADS_ENV, app.state.writer.preparers))
    pool = ThreadPoolExecutor(threads, "bare") if threads else None

    def _decode(data: bytes) -> list[int]:
        _, image = decode_rgb(data, max_pixels=settings.max_pixels)
        return [int(m) for m in channel_stats(image).modes]

    @app.post("/bare", include_in_schema=False)
    async def bare(request: Request) -> dict[str, list[int]]:
        data = await read_capped(request, settings.max_body_bytes)
        if pool is None:
            return {"modes": await run_in_threadpool(_decode, data)}
        return {"modes": await asyncio.get_running_loop().run_in_executor(pool, _decode, data)}

    # first in the route table. Added last, it was matched after every route of the service:
    # 69 µs a request against 14 µs for the frame upload's route, a cost the ceiling should
    # not pay. First, it costs 1.5 µs (the upload keeps its 14: the bias is now against it).
    app.router.routes.insert(0, app.router.routes.pop())
    return app
