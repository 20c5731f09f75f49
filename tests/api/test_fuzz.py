"""Thousands of mutated JPEGs at the ingest path: never a 5xx, never a crash, memory bounded."""

from __future__ import annotations

import resource
from collections import Counter

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.conftest import make_jpeg


def mutations(seed: int, n: int) -> list[bytes]:
    rng = np.random.default_rng(seed)
    seeds = [
        make_jpeg(w, h, noise=25, seed=i)
        for i, (w, h) in enumerate([(64, 48), (320, 240), (17, 5)])
    ]
    out = []
    for k in range(n):
        data = bytearray(seeds[k % len(seeds)])
        kind = k % 6
        if kind == 0:  # truncation
            data = data[: int(rng.integers(0, len(data)))]
        elif kind == 1:  # bit flips
            for i in rng.integers(0, len(data), size=int(rng.integers(1, 20))):
                data[i] ^= 1 << int(rng.integers(0, 8))
        elif kind == 2:  # bogus declared size: up to 65535 × 65535
            sof = data.find(b"\xff\xc0")
            if sof > 0:
                data[sof + 5 : sof + 9] = rng.integers(0, 256, 4, dtype=np.uint8).tobytes()
        elif kind == 3:  # random bytes after a valid SOI/APP0 start
            data = data[:20] + bytearray(
                rng.integers(0, 256, int(rng.integers(0, 4000)), dtype=np.uint8).tobytes()
            )
        elif kind == 4:  # segment lengths scrambled
            for i in rng.integers(2, min(len(data), 600), size=4):
                data[i] = int(rng.integers(0, 256))
        else:  # pure noise, no JPEG at all
            data = bytearray(
                rng.integers(0, 256, int(rng.integers(0, 3000)), dtype=np.uint8).tobytes()
            )
        out.append(bytes(data))
    return out


@pytest.mark.slow
def test_mutated_jpegs(client: TestClient, admin: dict[str, str]) -> None:
    token = client.post("/cameras", json={"id": "f", "kind": "panel"}, headers=admin).json()[
        "token"
    ]
    headers = {"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"}
    statuses: Counter[int] = Counter()
    rss_start = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for data in mutations(seed=2024, n=3000):
        r = client.post("/cameras/f/frames", content=data, headers=headers)
        statuses[r.status_code] += 1
        if r.status_code != 201:
            assert r.headers["content-type"] == "application/problem+json", r.text
    rss_growth_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss_start) / 1024
    assert set(statuses) <= {201, 415, 422}, statuses
    assert statuses[422] > 500  # the fuzzing reached the decoder's refusals
    assert rss_growth_mb < 200, rss_growth_mb


def test_mutation_kinds_are_deterministic() -> None:
    assert mutations(1, 12) == mutations(1, 12)
