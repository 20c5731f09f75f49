"""The quality gate: night, glare, blank, greyscale and occluded frames are refused; real panel
photos of every kind are not."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from app.core.jpeg import decode_rgb
from app.core.quality import unusable_reason
from app.core.stats import channel_stats
from tests.conftest import SHARED_DATA


def panel(seed: int = 0) -> np.ndarray:
    """A synthetic daylight panel: blue cells, grey frame lines, noise."""
    rng = np.random.default_rng(seed)
    image = np.empty((120, 160, 3), np.float64)
    image[:] = (56, 60, 84)
    image[::20, :] = (170, 170, 175)
    image[:, ::20] = (170, 170, 175)
    image += rng.normal(0, 8, image.shape)
    return np.clip(image, 0, 255).astype(np.uint8)


def reason(image: np.ndarray) -> str | None:
    return unusable_reason(channel_stats(image))


def test_daylight_panel_passes() -> None:
    assert reason(panel()) is None


@pytest.mark.parametrize(
    ("make", "expected"),
    [
        (lambda p: (p * 0.12).astype(np.uint8), "too dark"),
        (lambda p: np.full_like(p, 128), "blank"),
        (lambda p: np.where(np.arange(160)[None, :, None] < 60, 255, p).astype(np.uint8), "glare"),
        (
            lambda p: np.repeat(p.mean(axis=2, keepdims=True), 3, axis=2).astype(np.uint8),
            "greyscale",
        ),
        (lambda p: np.where(np.arange(160)[None, :, None] < 90, 0, p).astype(np.uint8), "occluded"),
    ],
    ids=["night", "blank", "glare", "greyscale", "occluded"],
)
def test_unusable_frames(make: object, expected: str) -> None:
    image = make(panel())  # type: ignore[operator]
    assert expected in (reason(image) or "")


@pytest.mark.skipif(not (SHARED_DATA / "solar").exists(), reason="shared data absent")
def test_no_real_panel_photo_is_gated() -> None:
    root = SHARED_DATA / "solar"
    with open(root / "labels.csv") as f:
        rows = [r for r in csv.DictReader(f) if r["label"] != "snow"]
    gated = []
    for r in rows:
        _, image = decode_rgb(Path(root / r["file"]).read_bytes(), max_pixels=10**8)
        if (why := reason(image)) is not None:
            gated.append((r["file"], why))
    assert gated == []
