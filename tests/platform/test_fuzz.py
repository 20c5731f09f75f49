"""Thousands of mutated JPEGs at the ingest path: never a 5xx, never a crash, memory bounded."""

from __future__ import annotations

import resource
import tracemalloc
from collections import Counter
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.factories import make_jpeg


def mutations(seed: int, n: int) -> list[bytes]:
    rng = np.random.default_rng(seed)
    seeds = [
        make_jpeg(w, h, noise=25, seed=i)
        # one pixel thin: a panel frame of that shape was a 500 (the fleet features' sampling)
        for i, (w, h) in enumerate([(64, 48), (320, 240), (17, 5), (400, 1), (1, 400)])
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


KINDS = ("panel", "sky", "rig")
"""Each kind analyses a frame its own way (fleet features, sky features, statistics only)."""


@pytest.mark.slow
def test_mutated_jpegs(client: TestClient, admin: dict[str, str], settings: Any) -> None:
    headers = {}
    for kind in KINDS:
        r = client.post("/cameras", json={"id": kind, "kind": kind}, headers=admin)
        headers[kind] = {
            "Authorization": f"Bearer {r.json()['token']}",
            "Content-Type": "image/jpeg",
        }
    statuses: Counter[int] = Counter()
    peak_start = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    for k, data in enumerate(mutations(seed=2024, n=3000)):
        kind = KINDS[k // 7 % len(KINDS)]  # not in step with the 5 seeds and 6 mutations
        r = client.post(f"/cameras/{kind}/frames", content=data, headers=headers[kind])
        statuses[r.status_code] += 1
        if r.status_code != 201:
            assert r.headers["content-type"] == "application/problem+json", r.text
        if k == 299:
            tracemalloc.start()  # what is allocated from here on and still alive at the end
    assert set(statuses) <= {201, 415, 422}, statuses
    assert statuses[422] > 500  # the fuzzing reached the decoder's refusals
    # memory bounded: a frame's peak is a small multiple of a decoded frame at the pixel limit
    # (the bogus declared sizes reach it); a 36 MP sky frame's features took ~1.9 GB
    decoded_mib = settings.max_pixels * 3 / 2**20
    peak_growth = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - peak_start
    assert peak_growth < 3 * decoded_mib, (peak_growth, decoded_mib)
    # and nothing accumulates from frame to frame: of what the last 2,700 frames allocated
    # (Python objects and NumPy arrays), less than 20 MiB is still alive: 3.3–3.5 MiB here,
    # and keeping 10 kB a frame made it 29. (Not the resident size: the allocator keeps freed
    # memory in its arenas, and that moved by up to 89 MiB.)
    alive_mib = tracemalloc.get_traced_memory()[0] / 2**20
    tracemalloc.stop()
    assert alive_mib < 20, alive_mib


def test_mutation_kinds_are_deterministic() -> None:
    assert mutations(1, 12) == mutations(1, 12)
