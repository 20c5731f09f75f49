"""The service plus a bare endpoint that only decodes and histograms: the ingest ceiling."""

from __future__ import annotations

from fastapi import FastAPI, Request
from fastapi.concurrency import run_in_threadpool

from app.core.jpeg import decode_rgb
from app.core.stats import channel_stats
from app.main import create_app
from app.uploads import read_capped


def create_bench_app() -> FastAPI:
    import os, sys
    if os.environ.get("SWITCH"):
        sys.setswitchinterval(float(os.environ["SWITCH"]))
    app = create_app()
    if os.environ.get("HOLD"):
        import time, atexit, threading
        from sqlalchemy import event
        holds = []
        t0 = {}
        @event.listens_for(app.state.engine, "checkout")
        def _co(dbapi, rec, proxy):
            t0[id(rec)] = time.perf_counter()
        @event.listens_for(app.state.engine, "checkin")
        def _ci(dbapi, rec):
            holds.append(time.perf_counter() - t0.pop(id(rec), time.perf_counter()))
        def report():
            import numpy as np
            a = np.array(holds) * 1000
            print("HOLD n", len(a), "mean", a.mean(), "p50", np.median(a), "p99", np.percentile(a, 99), "sum s", a.sum() / 1000, flush=True)
        atexit.register(report)
        import signal
        signal.signal(signal.SIGTERM, lambda *a: (report(), os._exit(0)))
    settings = app.state.settings

    def _decode(data: bytes) -> list[int]:
        _, image = decode_rgb(data, max_pixels=settings.max_pixels)
        return [int(m) for m in channel_stats(image).modes]

    @app.post("/bare", include_in_schema=False)
    async def bare(request: Request) -> dict[str, list[int]]:
        data = await read_capped(request, settings.max_body_bytes)
        return {"modes": await run_in_threadpool(_decode, data)}

    return app
