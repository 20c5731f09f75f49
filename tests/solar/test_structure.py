"""How a photo is built (``core.structure``): known answers on images whose build is known."""

from __future__ import annotations

import numpy as np
import pytest

from app.solar.core.structure import STRUCTURE_FEATURES, structure_features


def named(grey: np.ndarray) -> dict[str, float]:
    return dict(zip(STRUCTURE_FEATURES, structure_features(grey), strict=True))


def stripes(period: int, shape: tuple[int, int] = (128, 192)) -> np.ndarray:
    """Vertical bright lines 1 px wide every ``period`` px on a dark ground."""
    grey = np.full(shape, 40, np.uint8)
    grey[:, ::period] = 200
    return grey


def test_a_flat_image_has_no_structure() -> None:
    """Every gradient, band and Laplacian is 0: the energies, edges and detail are 0; the
    orientations, with no energy, are spread evenly: top bin 0, entropy 0."""
    f = named(np.full((64, 96), 120, np.uint8))
    assert len(STRUCTURE_FEATURES) == 21
    for name in STRUCTURE_FEATURES:
        assert f[name] == pytest.approx(0.0, abs=1e-6), name


def test_parallel_lines_are_coherent_and_of_one_orientation() -> None:
    """Vertical stripes: every gradient is horizontal, so the structure tensor's coherence
    is 1 and all gradient energy falls in the orientation bin of 0°."""
    f = named(stripes(12))
    assert f["coherence_w5"] == pytest.approx(1.0, abs=1e-3)
    assert f["coherence_w13"] == pytest.approx(1.0, abs=1e-3)
    assert f["orientation_top"] == pytest.approx(1.0, abs=1e-3)
    assert f["orientation_entropy"] == pytest.approx(0.0, abs=1e-2)


def test_a_grid_puts_its_spectrum_in_a_few_peaks_and_noise_does_not() -> None:
    """A grid of 16 px repeats: its gradient image's energy sits in the harmonics of 1/16
    px⁻¹ (over half of it in 50 frequencies); seeded white noise spreads its energy over
    all ~12,000 (50 of them hold about 50/12,000 of it, a few times that at most)."""
    grid = np.full((128, 192), 60, np.uint8)
    grid[::16, :] = 180
    grid[:, ::16] = 180
    noise = np.random.default_rng(0).integers(0, 256, (128, 192)).astype(np.uint8)
    assert named(grid)["spectrum_top50"] > 0.5
    assert named(noise)["spectrum_top50"] < 0.05


def test_sky_over_a_street_is_brighter_and_smoother_above() -> None:
    """Top half a smooth bright sky, bottom half seeded texture: the top third's detail is
    nearly none, the bottom third's above the whole's mean, and the top third brighter."""
    rng = np.random.default_rng(1)
    grey = np.empty((120, 180), np.uint8)
    grey[:60] = 210
    grey[60:] = rng.integers(20, 120, (60, 180))
    f = named(grey)
    assert f["detail_top"] < 0.05
    assert f["detail_bottom"] > 1.0
    assert f["brightness_drop"] > 0.4


def test_a_finer_pattern_puts_more_energy_in_the_finest_band() -> None:
    """Stripes every 2 px live in the finest octave; every 16 px, their energy spreads to
    the coarser ones: the finest band's share is the larger for the finer pattern."""

    def share(period: int) -> float:
        f = named(stripes(period))
        bands = [f[f"band{k}_mean"] for k in range(4)]
        return bands[0] / sum(bands)

    assert share(2) > share(16)


def test_too_small_an_image_is_refused() -> None:
    with pytest.raises(ValueError, match="at least 8×8"):
        structure_features(np.zeros((7, 40), np.uint8))
