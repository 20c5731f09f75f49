"""Prometheus metrics of a server whose workers share one port (the Docker image's
``python -m app.serve --workers N``): every scrape sums them."""

from __future__ import annotations

import re
from pathlib import Path

import httpx2 as httpx
import pytest
from sqlalchemy import Engine

from tests.factories import ADMIN_TOKEN, empty_tables, make_jpeg
from tests.servers import free_port, server_env, start_server

ADMIN = {"Authorization": f"Bearer {ADMIN_TOKEN}"}


@pytest.mark.slow
def test_every_scrape_counts_the_frames_of_every_worker(
    database_url: str, engine: Engine, tmp_path: Path
) -> None:
    """40 frames through 2 workers on one port, then 12 scrapes: each reads 40. With a
    registry per worker the scrapes read 16, 24, 16, 24 … (each worker's own share), which
    Prometheus takes for a counter reset every scrape."""
    empty_tables(engine)
    env = server_env(database_url, tmp_path / "data")
    env.pop("PROMETHEUS_MULTIPROC_DIR", None)
    port = free_port()
    proc = start_server(env, port, workers=2)
    base = f"http://127.0.0.1:{port}"
    try:
        made = httpx.post(f"{base}/cameras", json={"id": "c", "kind": "rig"}, headers=ADMIN)
        assert made.status_code == 201, made.text
        for k in range(40):  # a connection each: the kernel spreads them over the workers
            r = httpx.post(
                f"{base}/cameras/c/frames",
                content=make_jpeg(64, 48, seed=k),
                headers={**ADMIN, "Content-Type": "image/jpeg"},
            )
            assert r.status_code == 201, r.text
        counted = []
        for _ in range(12):
            text = httpx.get(f"{base}/metrics", headers=ADMIN).text
            found = re.search(r'^vantage_frames_received_total\{camera_id="c"\} (\S+)$', text, re.M)
            assert found, text[:500]
            counted.append(float(found.group(1)))
            histogram = re.search(r"^vantage_ingest_seconds_count (\S+)$", text, re.M)
            assert histogram
            assert float(histogram.group(1)) == 40
    finally:
        proc.terminate()
        proc.wait(10)
    assert counted == [40.0] * 12
