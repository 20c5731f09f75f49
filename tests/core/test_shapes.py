"""Matching corner points to the library of regular shapes."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from app.core.shapes import match


def rotation(seed: int) -> np.ndarray:
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_box() -> None:
    corners = np.array(list(itertools.product((-0.2, 0.2), (-0.1, 0.1), (-0.05, 0.05))))
    p = (
        corners @ rotation(1).T
        + [1.0, 2.0, 3.0]
        + np.random.default_rng(0).normal(0, 0.001, (8, 3))
    )
    best = match(p)[0]
    assert best.shape == "box"
    assert best.dimensions["length"] == pytest.approx(0.4, abs=0.005)
    assert best.dimensions["width"] == pytest.approx(0.2, abs=0.005)
    assert best.dimensions["height"] == pytest.approx(0.1, abs=0.005)
    np.testing.assert_allclose(best.centre, [1, 2, 3], atol=0.002)
    assert best.rms < 0.003


def test_prism() -> None:
    tri = np.array([[0.0, 0.0], [0.3, 0.0], [0.1, 0.2]])
    p = np.array([[x, y, z] for z in (0.0, 0.5) for x, y in tri]) @ rotation(2).T
    best = match(p)[0]
    assert best.shape == "prism"
    assert best.dimensions["length"] == pytest.approx(0.5, abs=1e-6)
    assert sorted(v for k, v in best.dimensions.items() if k.startswith("side")) == pytest.approx(
        sorted([0.3, np.hypot(0.1, 0.2), np.hypot(0.2, 0.2)]), abs=1e-6
    )


def test_cylinder() -> None:
    a = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    p = (
        np.array([[0.1 * np.cos(t), 0.1 * np.sin(t), z] for z in (0.0, 0.4) for t in a])
        @ rotation(3).T
    )
    best = match(p)[0]
    assert best.shape == "cylinder"
    assert best.dimensions["radius"] == pytest.approx(0.1, abs=1e-6)
    assert best.dimensions["height"] == pytest.approx(0.4, abs=1e-6)


def test_bad_input() -> None:
    with pytest.raises(ValueError, match="at least 6"):
        match(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="finite"):
        match(np.full((8, 3), np.nan))
