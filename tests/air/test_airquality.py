"""Chapter 6 grading, smoothing and the isopleth bands against synthetic known answers."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from itertools import pairwise
from typing import Any

import cv2
import numpy as np
import pytest
from shapely.geometry import Point, shape

from app.air.core import airquality, breakpoints
from app.air.core.isopleths import (
    EARTH_RADIUS,
    IsoplethError,
    band_at,
    bands,
    cell_size_m,
    default_bbox,
    interpolate,
    uncertainty_bands,
)
from tests.factories.air import CLEAN, HAZE
from tests.memory import traced_peak

# very clean sky: R 30, G 78, B 180 (Figure 6.3a); haze moves it towards grey


def sky_modes(level: int, n: int, seed: int) -> np.ndarray:
    t = (10 - level) / 9
    rng = np.random.default_rng(seed)
    return (1 - t) * CLEAN + t * HAZE + rng.normal(0, 2.0, (n, 3))


class TestCategories:
    @pytest.mark.parametrize(
        ("level", "name"),
        [
            (10, "Very Good"),
            (9, "Very Good"),
            (8, "Good"),
            (7, "Good"),
            (6, "Fair"),
            (5, "Fair"),
            (4, "Poor"),
            (3, "Poor"),
            (2, "Very Poor"),
            (1, "Very Poor"),
            (8.49, "Good"),
            (8.5, "Very Good"),
            (4.5, "Fair"),
            (4.49, "Poor"),
        ],
    )
    def test_every_boundary(self, level: float, name: str) -> None:
        assert airquality.category(level) == name

    @pytest.mark.parametrize("level", [0, 0.49, 10.5, 11, float("nan")])
    def test_out_of_range(self, level: float) -> None:
        with pytest.raises(ValueError, match="1–10"):
            airquality.category(level)

    def test_message(self) -> None:
        assert airquality.message("Good") == "Today's Air Quality is Good"


class TestCalibration:
    def test_well_separated_clusters_classify_held_out_frames(self) -> None:
        levels = [1, 3, 5, 7, 10]
        modes = np.vstack([sky_modes(v, 12, seed=v) for v in levels])
        labels = np.repeat(levels, 12)
        cal = airquality.level_clusters(modes, labels, significance=0.01)
        assert [c.level for c in cal.clusters] == levels
        assert cal.warnings == ()
        for v in levels:
            for x in sky_modes(v, 10, seed=100 + v):
                assert airquality.grade(cal, x).level == v

    def test_sparse_level_is_pooled_with_a_warning(self) -> None:
        modes = np.vstack([sky_modes(2, 10, 1), sky_modes(3, 2, 2), sky_modes(8, 10, 3)])
        labels = [2] * 10 + [3] * 2 + [8] * 10
        cal = airquality.level_clusters(modes, labels)
        assert [c.levels for c in cal.clusters] == [(2, 3), (8,)]
        assert "pooled" in cal.warnings[0]

    def test_a_singular_cluster_gets_the_rounding_variance_and_a_warning(self) -> None:
        """Level 5's blue mode is the same in all six images: its Σ̂ is singular. The
        calibration is made with 1/12 level² on that cluster's diagonal, and says so; the
        other clusters are eq. 6.13 unchanged."""
        modes = np.vstack([np.round(sky_modes(v, 6, seed=v)) for v in (2, 5, 8)])
        modes[6:12, 2] = 175.0
        labels = np.repeat([2, 5, 8], 6)
        cal = airquality.level_clusters(modes, labels)
        assert [c.level for c in cal.clusters] == [2, 5, 8]
        [warning] = cal.warnings
        assert warning.startswith("level 5: the B mode is the same in all 6 images")
        assert "1/12" in warning
        by_level = {c.level: c.baseline for c in cal.clusters}
        expected = np.cov(modes[6:12], rowvar=False, ddof=1) + np.eye(3) / 12
        np.testing.assert_allclose(by_level[5].covariance, expected, rtol=1e-12)
        np.testing.assert_allclose(
            by_level[2].covariance, np.cov(modes[:6], rowvar=False, ddof=1), rtol=1e-12
        )
        assert by_level[2].shrinkage == 0.0

    def test_outside_calibration_is_said_not_guessed(self) -> None:
        cal = airquality.level_clusters(sky_modes(10, 10, 1), [10] * 10)
        g = airquality.grade(cal, [200.0, 40.0, 40.0])  # a red sunset
        assert g.level is None
        assert "outside calibration" in (g.reason or "")


class TestNowcast:
    def test_steady_air_is_the_plain_mean(self) -> None:
        now = datetime(2026, 6, 1, 12, tzinfo=UTC)
        times = [now - timedelta(hours=h) for h in range(6)]
        assert airquality.nowcasts(times, [7.0] * 6, [now])[0] == pytest.approx(7.0)

    def test_changing_air_weighs_the_latest_hours(self) -> None:
        now = datetime(2026, 6, 1, 12, tzinfo=UTC)
        times = [now - timedelta(hours=h) for h in range(6)]
        levels = [2.0, 8.0, 8.0, 8.0, 8.0, 8.0]  # it turned bad this hour
        s = airquality.nowcasts(times, levels, [now])[0]
        # w = max(2/8, 0.5) = 0.5: (2 + 8(0.5 + 0.25 + 0.125 + 0.0625 + 0.03125)) / 1.96875
        assert s == pytest.approx((2 + 8 * 0.96875) / 1.96875)
        assert s < np.mean(levels)

    def test_no_recent_reading(self) -> None:
        now = datetime(2026, 6, 1, 12, tzinfo=UTC)
        assert airquality.nowcasts([now - timedelta(hours=5)], [5.0], [now])[0] is None

    def test_at_many_times_as_defined_reading_by_reading(self) -> None:
        """``nowcasts`` (running sums at hour boundaries) against the definition written out
        reading by reading: each reading 0 ≤ age < 12 h in hour ⌊age⌋, weights wᵏ. Seeded
        random times, a third of them on whole minutes so that readings exactly k hours
        before a time occur, in random order."""
        rng = np.random.default_rng(7)
        t0 = datetime(2026, 6, 1, tzinfo=UTC)
        minutes, seconds = rng.integers(0, 1440, 300), rng.random(300) * 86400
        times = [
            t0 + timedelta(minutes=int(minutes[k]))
            if k % 3 == 0
            else t0 + timedelta(seconds=float(seconds[k]))
            for k in range(300)
        ]
        levels = [float(x) for x in rng.integers(1, 11, 300)]
        at = times[:100] + [t0 + timedelta(hours=h) for h in range(25)]

        def defined(now: datetime) -> float | None:
            hourly: dict[int, list[float]] = {}
            for t, v in zip(times, levels, strict=True):
                age = now - t
                if timedelta(0) <= age < timedelta(hours=12):
                    hourly.setdefault(age // timedelta(hours=1), []).append(v)
            if not any(k < 3 for k in hourly):
                return None
            means = {k: float(np.mean(v)) for k, v in hourly.items()}
            w = max(min(means.values()) / max(means.values()), 0.5)
            return sum(w**k * m for k, m in means.items()) / sum(w**k for k in means)

        expected = [defined(a) for a in at]
        got = airquality.nowcasts(times, levels, at)
        assert sum(e is None for e in expected) >= 1  # t0 itself: nothing before it
        assert [g is None for g in got] == [e is None for e in expected]
        assert [g for g in got if g is not None] == pytest.approx(
            [e for e in expected if e is not None], rel=1e-12
        )
        on_the_hour = [a for a in at if any(a - t == timedelta(hours=2) for t in times)]
        assert on_the_hour  # the boundary case occurs


def smooth_field(n: int = 60, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cameras over ~20 km sampling a level that rises from west (1) to east (10)."""
    rng = np.random.default_rng(seed)
    lon = 9.05 + 0.25 * rng.random(n)
    lat = 45.40 + 0.15 * rng.random(n)
    return lon, lat, 1 + 9 * (lon - 9.05) / 0.25


class TestIsopleths:
    @pytest.mark.parametrize("method", ["idw", "kriging", "rbf"])
    def test_bands_contain_the_cameras_of_their_category(self, method: str) -> None:
        lon, lat, level = smooth_field()
        f = interpolate(
            lon,
            lat,
            level,
            bbox=default_bbox(lon, lat),
            method=method,  # type: ignore[arg-type]
            resolution=96,
            max_distance=8000,
        )
        features = bands(f)
        names = [ft["properties"]["category"] for ft in features]
        assert names == ["Very Poor", "Poor", "Fair", "Good", "Very Good"]
        geoms = [shape(ft["geometry"]) for ft in features]
        for g in geoms:
            assert g.is_valid
            for poly in getattr(g, "geoms", [g]):
                assert poly.exterior.is_ccw  # RFC 7946 right-hand rule
        for i in range(len(geoms)):
            for j in range(i + 1, len(geoms)):
                assert geoms[i].intersection(geoms[j]).area < 1e-9  # no overlaps
        inside = 0
        for x, y, v in zip(lon, lat, level, strict=True):
            band = geoms[names.index(airquality.category(v))]
            near_boundary = any(abs(v - e) < 0.4 for e in (2.5, 4.5, 6.5, 8.5))
            if not near_boundary:
                assert band.buffer(1e-4).contains(Point(x, y)), (x, y, v)
                inside += 1
        assert inside > 30

    @pytest.mark.parametrize("level", [2.5, 4.5, 6.5, 8.5, 1.0, 10.0])
    def test_a_level_on_a_category_edge_is_drawn_in_its_own_category(self, level: float) -> None:
        """Halves go up (``airquality.rounded``): a camera whose smoothed level is 4.5 reads
        Fair, and the PNG and ``band_at`` paint it Fair. The GeoJSON's one band was Poor
        (contourpy fills lower < z <= upper), so the same camera was Fair on its own page and
        Poor on the dashboards' map."""
        lon, lat = np.array([9.19]), np.array([45.46])
        f = interpolate(lon, lat, np.array([level]), bbox=default_bbox(lon, lat))
        assert [ft["properties"]["category"] for ft in bands(f)] == [airquality.category(level)]
        assert band_at(f, lon, lat) == [airquality.category(level)]

    @pytest.mark.parametrize("method", ["idw", "kriging", "rbf"])
    def test_cameras_reading_alike_on_an_edge_are_one_band(self, method: str) -> None:
        """Three cameras all at 8.5: kriging interpolated 8.5 ± 2e-15, and the noise made a
        Good band of one polygon and a Very Good one of 209 that overlapped it by 0.4 % of
        its area. The map is one Very Good polygon, as every camera reads."""
        lon = np.array([9.18, 9.20, 9.19])
        lat = np.array([45.46, 45.465, 45.48])
        f = interpolate(
            lon, lat, np.full(3, 8.5), bbox=default_bbox(lon, lat),
            method=method, resolution=64, max_distance=50_000,  # type: ignore[arg-type]
        )  # fmt: skip
        features = bands(f)
        assert [ft["properties"]["category"] for ft in features] == ["Very Good"]
        assert features[0]["geometry"]["type"] == "Polygon"

    def test_no_vertex_lies_on_a_straight_line(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """Every vertex of a band is a corner: one camera's map, a single band over the whole
        grid, is the grid's rectangle in 5 points (contourpy gave 509, a point per cell along
        its edges); a city's bands are contourpy's, point for point, less the points on a
        straight line, and no three consecutive points of any ring are collinear."""
        one = interpolate(
            np.array([9.2073]), np.array([45.4746]), np.array([5.3]),
            bbox=(9.1973, 45.4646, 9.2173, 45.4846), resolution=128,
        )  # fmt: skip
        (feature,) = bands(one)
        assert len(feature["geometry"]["coordinates"][0]) == 5
        assert shape(feature["geometry"]).area == pytest.approx(0.02 * 0.02, rel=1e-9)

        lon, lat, level = smooth_field()
        f = interpolate(
            lon, lat, level, bbox=default_bbox(lon, lat), resolution=96, max_distance=8000
        )
        ours = [shape(ft["geometry"]) for ft in bands(f)]
        monkeypatch.setattr("shapely.simplify", lambda g, _tolerance: g)
        contourpys = [shape(ft["geometry"]) for ft in bands(f)]
        assert len(ours) == len(contourpys) == 5

        def rings(g: Any) -> list[Any]:
            return [r for p in getattr(g, "geoms", [g]) for r in (p.exterior, *p.interiors)]

        for a, b in zip(ours, contourpys, strict=True):
            assert a.symmetric_difference(b).area < 1e-12 * b.area
            assert sum(len(r.coords) for r in rings(a)) < sum(len(r.coords) for r in rings(b))
            for r in rings(a):
                xy = np.asarray(r.coords)[:-1]
                u, v = np.roll(xy, -1, axis=0) - xy, np.roll(xy, -2, axis=0) - np.roll(xy, -1, 0)
                assert np.all(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0] != 0)

    def test_far_cells_are_masked(self) -> None:
        lon, lat, level = smooth_field()
        f = interpolate(
            lon,
            lat,
            level,
            bbox=(8.0, 45.0, 10.5, 46.0),
            method="idw",
            resolution=64,
            max_distance=3000,
        )
        assert np.isnan(f.value).mean() > 0.5
        assert f.uncertainty_kind == "nearest_camera_m"

    def test_kriging_variance_is_the_uncertainty_layer(self) -> None:
        lon, lat, level = smooth_field()
        f = interpolate(
            lon,
            lat,
            level,
            bbox=default_bbox(lon, lat),
            method="kriging",
            resolution=32,
            max_distance=50_000,
        )
        assert f.uncertainty_kind == "kriging_sd"
        assert np.isfinite(f.uncertainty).all()

    def test_kriging_weighs_each_camera_by_its_error(self) -> None:
        """Cameras' errors (their readings' ranges) in kriging with measurement error: zero
        errors are kriging as before, exact at a camera; a camera reading 1.5 levels above a
        smooth gradient sets the map at its place when sure, and hardly moves it when its
        error is 5 levels (the map there follows its neighbours, with their doubt)."""
        rng = np.random.default_rng(3)
        lon = 9.0 + rng.uniform(0, 0.1, 12)
        lat = 45.0 + rng.uniform(0, 0.1, 12)
        level = 2.0 + 60.0 * (lon - 9.0)  # a smooth west-to-east gradient, 2–8
        trend = float(level[0])
        level[0] += 1.5  # one camera reads above it
        box = (
            float(lon[0]) - 1e-3,
            float(lat[0]) - 1e-3,
            float(lon[0]) + 1e-3,
            float(lat[0]) + 1e-3,
        )

        def at_camera(errors: np.ndarray | None) -> tuple[float, float]:
            f = interpolate(
                lon, lat, level, bbox=box, method="kriging", resolution=3,
                max_distance=50_000, errors=errors,
            )  # fmt: skip
            return float(f.value[1, 1]), float(f.uncertainty[1, 1])

        sure, unsure = np.zeros(12), np.zeros(12)
        unsure[0] = 5.0
        assert at_camera(sure) == at_camera(None)
        plain, plain_sd = at_camera(None)
        pulled, pulled_sd = at_camera(unsure)
        assert plain == pytest.approx(level[0], abs=1e-6)  # an exact interpolator at a camera
        assert plain_sd == pytest.approx(0.0, abs=1e-6)
        assert abs(pulled - trend) < 0.5  # an unsure reading: near its neighbours' trend
        assert pulled_sd > 0.5

    def test_bad_input(self) -> None:
        lon, lat, level = smooth_field(5)
        with pytest.raises(IsoplethError, match="one point"):
            interpolate(np.full(4, 9.1), np.full(4, 45.4), np.arange(4.0), bbox=(9, 45, 10, 46))
        with pytest.raises(IsoplethError, match="NaN"):
            interpolate(
                np.array([9.1, np.nan]), np.array([45.4, 45.5]), np.ones(2), bbox=(9, 45, 10, 46)
            )
        with pytest.raises(IsoplethError, match="min < max"):
            interpolate(lon, lat, level, bbox=(10, 45, 9, 46))

    @pytest.mark.parametrize("method", ["idw", "kriging", "rbf"])
    def test_two_cameras_on_one_mast_are_one_station(self, method: str) -> None:
        # a second camera on the mast of camera 0 (a few cm away) reporting another level: the
        # place counts once, at the mean level (rbf used to fail on the singular system)
        lon, lat, level = smooth_field()
        twin = level[0] + 2.0
        lon2, lat2 = np.append(lon, lon[0] + 1e-7), np.append(lat, lat[0])
        kw: dict[str, Any] = {
            "bbox": default_bbox(lon, lat),
            "method": method,
            "resolution": 48,
            "max_distance": 8000,
        }
        merged = interpolate(lon2, lat2, np.append(level, twin), **kw)
        alone = interpolate(lon, lat, level, **kw)  # without the twin
        moved = level.copy()
        moved[0] += 1.0  # the mean of the two
        expected = interpolate(lon, lat, moved, **kw)
        # the same to within what moving the place by 4 mm (to the two cameras' mean) changes
        np.testing.assert_allclose(merged.value, expected.value, atol=1e-3)
        assert not np.allclose(merged.value, alone.value, atol=1e-3, equal_nan=True)

    def test_rbf_needs_three_places_off_one_line(self) -> None:
        bbox = (9.0, 45.3, 9.3, 45.5)
        with pytest.raises(IsoplethError, match="3 places"):
            interpolate(
                np.array([9.1, 9.2]),
                np.array([45.4, 45.45]),
                np.array([3.0, 8.0]),
                bbox=bbox,
                method="rbf",
            )
        with pytest.raises(IsoplethError, match="one line"):
            interpolate(
                np.array([9.1, 9.15, 9.2]),
                np.full(3, 45.4),
                np.array([3.0, 5.0, 8.0]),
                bbox=bbox,
                method="rbf",
            )
        # idw takes both
        f = interpolate(
            np.array([9.1, 9.2]),
            np.array([45.4, 45.45]),
            np.array([3.0, 8.0]),
            bbox=bbox,
            method="idw",
            resolution=16,
            max_distance=50_000,
        )
        assert np.nanmin(f.value) >= 3.0 - 1e-9
        assert np.nanmax(f.value) <= 8.0 + 1e-9

    @pytest.mark.parametrize(
        "bbox", [(-181, 0, 0, 1), (0, -91, 1, 0), (0, 0, 181, 1), (0, 0, 1, 90.5)], ids=str
    )
    def test_a_bbox_off_the_globe_is_refused(self, bbox: tuple[float, ...]) -> None:
        lon, lat, level = smooth_field(5)
        with pytest.raises(IsoplethError, match="±180"):
            interpolate(lon, lat, level, bbox=bbox)  # type: ignore[arg-type]

    def test_the_default_bbox_stays_on_the_globe(self) -> None:
        box = default_bbox(np.array([179.99, 179.5]), np.array([89.995, 89.9]))
        assert box[2] == 180.0
        assert box[3] == 90.0
        assert box[0] < 179.5
        assert box[1] < 89.9

    def test_band_at_agrees_with_the_polygons(self) -> None:
        """``band_at`` (what the answer says the map shows at each camera) against the band
        polygons themselves, away from their boundaries."""
        lon, lat, level = smooth_field()
        f = interpolate(lon, lat, level, bbox=default_bbox(lon, lat), resolution=96)
        geoms = {ft["properties"]["category"]: shape(ft["geometry"]) for ft in bands(f)}
        drawn = band_at(f, lon, lat)
        checked = 0
        for x, y, v, d in zip(lon, lat, level, drawn, strict=True):
            if any(abs(v - e) < 0.4 for e in (2.5, 4.5, 6.5, 8.5)):
                continue
            assert d == airquality.category(v)
            assert geoms[d].buffer(1e-4).contains(Point(x, y))
            checked += 1
        assert checked > 30
        assert band_at(f, np.array([0.0]), np.array([0.0])) == [None]  # off the grid

    def test_cells_coarser_than_the_cameras_are_told(self) -> None:
        """Two cities 300 km apart under the default bbox: at 128 cells a side (2.6 km) a
        smooth field puts cameras in other categories' bands; at 512 (640 m), none."""
        rng = np.random.default_rng(0)
        lon = np.r_[9.19 + rng.uniform(0, 0.05, 10), 12.49 + rng.uniform(0, 0.05, 10)]
        lat = np.r_[45.46 + rng.uniform(0, 0.05, 10), 41.9 + rng.uniform(0, 0.05, 10)]
        level = np.round(np.clip(5.5 + 4.5 * np.sin(lon * 40) * np.cos(lat * 40), 1, 10))
        wrong = {}
        for resolution in (128, 512):
            f = interpolate(lon, lat, level, bbox=default_bbox(lon, lat), resolution=resolution)
            drawn = band_at(f, lon, lat)
            wrong[resolution] = sum(
                d != airquality.category(v) for d, v in zip(drawn, level, strict=True)
            )
            assert cell_size_m(f)[0] == pytest.approx(
                (default_bbox(lon, lat)[2] - default_bbox(lon, lat)[0])
                / (resolution - 1)
                * np.pi
                / 180
                * 6_371_008.8
                * np.cos(np.radians(f.lat[resolution // 2])),
                rel=1e-9,
            )
        assert wrong[128] >= 3
        assert wrong[512] == 0

    def test_no_field_no_features(self) -> None:
        lon, lat, level = smooth_field()
        f = interpolate(lon, lat, level, bbox=(0, 0, 1, 1), method="idw", resolution=16)
        assert bands(f) == []
        assert uncertainty_bands(f) == []


class TestUncertaintyLayer:
    """Bands of how far to trust the map: the distance to the nearest camera (idw, rbf) or
    kriging's standard deviation."""

    def test_distance_bands_hold_the_points_at_that_distance(self) -> None:
        """Two cameras 8 km apart on the equator-parallel at 45° N; points due north of the
        first at known distances lie in the band of that distance, and nothing is drawn past
        ``max_distance``."""
        lat0 = 45.0
        east = 8_000 / (EARTH_RADIUS * np.cos(np.radians(lat0))) * 180 / np.pi
        lon = np.array([9.0, 9.0 + east])
        f = interpolate(
            lon, np.array([lat0, lat0]), np.array([3.0, 8.0]),
            bbox=(8.95, 44.95, 9.15, 45.05), method="idw", resolution=400, max_distance=3_000,
        )  # fmt: skip
        features = uncertainty_bands(f)
        assert {ft["properties"]["kind"] for ft in features} == {"nearest_camera_m"}
        assert {ft["properties"]["unit"] for ft in features} == {"m"}
        spans = [
            (ft["properties"]["uncertainty_min"], ft["properties"]["uncertainty_max"])
            for ft in features
        ]
        assert spans == [(0, 250), (250, 500), (500, 1000), (1000, 2000), (2000, 5000)]
        shapes = [shape(ft["geometry"]) for ft in features]
        assert all(s.is_valid for s in shapes)
        for a in range(len(shapes)):
            for b in range(a + 1, len(shapes)):
                assert shapes[a].intersection(shapes[b]).area < 1e-12  # no overlaps
        for metres, band in ((120, 0), (400, 1), (800, 2), (1500, 3), (2600, 4)):
            north = lat0 + metres / EARTH_RADIUS * 180 / np.pi
            inside = [i for i, s in enumerate(shapes) if s.contains(Point(9.0, north))]
            assert inside == [band], metres
        beyond = lat0 + 3_300 / EARTH_RADIUS * 180 / np.pi  # unpainted: no evidence there
        assert not any(s.contains(Point(9.0, beyond)) for s in shapes)

    def test_kriging_bands_grow_away_from_the_cameras(self) -> None:
        lon, lat, level = smooth_field()
        f = interpolate(
            lon, lat, level, bbox=default_bbox(lon, lat), method="kriging", resolution=96,
            max_distance=20_000,
        )  # fmt: skip
        features = uncertainty_bands(f)
        assert {ft["properties"]["kind"] for ft in features} == {"kriging_sd"}
        assert all(shape(ft["geometry"]).is_valid for ft in features)
        lows = [ft["properties"]["uncertainty_min"] for ft in features]
        assert lows == sorted(lows)
        shapes = [shape(ft["geometry"]) for ft in features]

        def band(x: float, y: float) -> int:  # the band holding (or, on an edge, touching) it
            return int(np.argmin([s.distance(Point(x, y)) for s in shapes]))

        # at the cameras the deviation is small (the nugget's); the painted cell farthest from
        # every camera (distances in metres on the local plane) lies in a band above theirs
        at_cameras = [band(x, y) for x, y in zip(lon, lat, strict=True)]
        assert max(features[i]["properties"]["uncertainty_max"] for i in at_cameras) <= 1.0
        glon, glat = np.meshgrid(f.lon, f.lat)
        k = np.cos(np.radians(45.475))
        d = np.hypot(
            (glon.ravel()[:, None] - lon[None, :]) * k, glat.ravel()[:, None] - lat[None, :]
        ).min(axis=1)
        d[np.isnan(f.value.ravel())] = -1
        far = int(np.argmax(d))
        assert band(glon.ravel()[far], glat.ravel()[far]) > max(at_cameras)


@pytest.mark.parametrize(
    ("earlier", "smoothed", "alert"),
    [
        ([], 4.0, "Poor"),  # a camera's first smoothed level
        ([], 5.0, None),
        ([5.0], 4.0, "Poor"),  # Fair → Poor
        ([7.0], 2.0, "Very Poor"),  # Good → Very Poor at once
        ([4.0], 2.0, "Very Poor"),  # Poor → Very Poor: worse again (was no alert)
        ([3.0], 2.4, "Very Poor"),
        ([2.0], 3.0, None),  # Very Poor → Poor: better
        ([3.0], 4.0, None),  # within Poor
        ([1.0], 1.0, None),
        ([5.0], 4.5, None),  # 4.5 is Fair (category rounds half up); Python's round made it 4
        ([4.6], 4.49, "Poor"),  # from Fair, with nothing earlier to say it was Poor before
        # hysteresis (ALERT_REARM = 0.5): back into Poor after only reaching 4.5–5.0 is the
        # same episode; after reaching 5.0, a new one
        ([4.52, 4.3, 6.0], 4.4, None),
        ([4.52, 4.99, 4.3], 4.4, None),
        ([4.52, 5.0, 4.3], 4.4, "Poor"),
        ([4.6, 4.7, 6.0], 4.4, "Poor"),  # first entry, through the band
        ([2.6, 2.9, 2.3], 2.4, None),  # the same for Very Poor, edge 2.5
        ([2.6, 3.0, 2.3], 2.4, "Very Poor"),
        ([2.6, 2.2, 4.0], 4.4, None),  # Poor again from Very Poor: better, not an alert
    ],
)
def test_alert_category(earlier: list[float], smoothed: float, alert: str | None) -> None:
    assert airquality.alert_category(smoothed, earlier) == alert


def test_air_hovering_on_the_poor_edge_is_one_alert() -> None:
    """Six hours of frames every 5 minutes graded 4 or 5 at random (seeded): the smoothed level
    wanders between 4.0 and 4.75 and crosses the Fair/Poor edge (4.5) again and again. Judged
    from the previous level alone that was 5 alerts (06:00, 07:00, 07:30, 08:00, 08:30); it is
    one episode of Poor air, so one alert."""
    rng = np.random.default_rng(1)
    t0 = datetime(2026, 11, 24, 6, tzinfo=UTC)
    times: list[datetime] = []
    levels: list[float] = []
    smoothed: list[float] = []
    alerts = []
    for k in range(72):
        times.append(t0 + timedelta(minutes=5 * k))
        levels.append(float(rng.choice([4, 5])))
        s = airquality.nowcasts(times, levels, [times[-1]])[0]
        assert s is not None
        a = airquality.alert_category(s, reversed(smoothed))
        if a is not None:
            alerts.append((times[-1], a))
        smoothed.append(s)
    crossings = sum(1 for a, b in pairwise(smoothed) if a >= 4.5 > b)
    assert crossings >= 3  # the edge was crossed downwards repeatedly
    assert alerts == [(t0, "Poor")]


def test_a_calibration_without_clusters_grades_no_modes() -> None:
    """A regression's calibration may have no clusters (a level's covariance was singular):
    grading modes by it says so instead of failing on an empty list."""
    g = airquality.grade(airquality.Calibration(()), [120.0, 130.0, 180.0])
    assert (g.level, g.statistic, g.p_value) == (None, None, None)
    assert g.reason == "the calibration has no clusters to grade modes by"


class TestSkyFeatures:
    """``sky_features`` against NumPy's own statistics of the same pixels."""

    def image(self, h: int, w: int, seed: int = 3) -> np.ndarray:
        rng = np.random.default_rng(seed)
        return rng.integers(0, 256, (h, w, 3), dtype=np.uint8)

    @pytest.mark.parametrize("band_pixels", [1 << 20, 1000, 1])
    def test_the_darkest_channel_in_bands_is_numpys(
        self, monkeypatch: pytest.MonkeyPatch, band_pixels: int
    ) -> None:
        """The median of each pixel's darkest channel (feature 7), the region taken a band of
        rows at a time (one band, bands of two rows, of one row: all the same)."""
        monkeypatch.setattr(airquality, "BAND_PIXELS", band_pixels)
        sky = self.image(61, 480)
        f = airquality.sky_features(sky)
        assert f[7] == np.median(sky.min(axis=2))
        np.testing.assert_allclose(f[3:6], sky.reshape(-1, 3).mean(axis=0), rtol=1e-12)

    def test_a_large_region_takes_little_memory_beyond_itself(self) -> None:
        """A 24 MP region (69 MiB): the darkest channel came from ``cv2.min`` of the channels'
        views, which copied each whole first, 69 MiB more at once."""
        peak, n = traced_peak(
            """
            import numpy as np
            from app.air.core import airquality
            sky = np.random.default_rng(0).integers(0, 256, (4000, 6000, 3), dtype=np.uint8)
            """,
            """
            result = len(airquality.sky_features(sky))
            """,
        )
        assert n == len(airquality.SKY_FEATURES)
        assert peak < 8 * 2**20, peak / 2**20

    def test_log_contrasts_of_flat_bands(self) -> None:
        """Bands of one grey each: every percentile is that grey, so each band's contrast is
        (S − L)/(S + 1) for sky median S; a band as bright as the sky clips at MIN_CONTRAST."""
        h = 100
        strip = np.empty((h, 10, 3), dtype=np.uint8)
        greys = (40, 90, 150, 200)
        for (lo, hi), g in zip(airquality.SKYLINE_BANDS, greys, strict=True):
            strip[int(lo * h) : int(hi * h)] = g
        strip[int(0.34 * h) : int(0.42 * h)] = 255  # between bands: never read
        sky = np.array([200.0, 210.0, 220.0])
        got = airquality.log_contrasts(sky, strip).reshape(4, 2, 3)
        for b, g in enumerate(greys):
            want = np.log(np.maximum((sky - g) / (sky + 1), airquality.MIN_CONTRAST))
            np.testing.assert_allclose(got[b, 0], want, rtol=1e-12)
            np.testing.assert_allclose(got[b, 1], want, rtol=1e-12)

    def test_skyline_edges_of_a_ramp(self) -> None:
        """A grey ramp of 1 level/px, 200 px wide (under ``EDGE_WIDTH``: not resized): the
        scaled Sobel derivative is 1 inside and 0 in the two edge columns (reflected border),
        so every band's mean is (W − 2)/W, exactly in float32."""
        w = 200
        ramp = np.arange(20, 20 + w, dtype=np.uint8)
        strip = np.repeat(np.repeat(ramp[None, :, None], 3, axis=2), 40, axis=0)
        np.testing.assert_allclose(
            airquality.skyline_edges(airquality.luma(strip)), np.log((w - 2) / w), atol=1e-6
        )

    def scene(self) -> np.ndarray:
        """A skyline-like luma field (seeded blocks, blurred), 1920×320, float."""
        blocks = np.random.default_rng(0).integers(30, 200, (40, 240)).astype(np.float64)
        scene = cv2.resize(blocks, (1920, 320), interpolation=cv2.INTER_NEAREST)
        return np.repeat(cv2.GaussianBlur(scene, (0, 0), 3)[..., None], 3, axis=2)

    @pytest.mark.parametrize("t", [0.3, 0.6])
    def test_a_veil_lowers_each_bands_edges_by_its_transmission(self, t: float) -> None:
        """Koschmieder: a veil of transmission 1 − t towards a sky of 230 scales every
        gradient by 1 − t, so each band's feature falls by ln(1 − t) (to 0.001: the rounding
        to whole grey levels moves it by 1.2e-4 at most)."""
        scene = self.scene()
        clear = airquality.skyline_edges(airquality.luma(scene.round().astype(np.uint8)))
        veiled = airquality.luma(((1 - t) * scene + t * 230).round().astype(np.uint8))
        np.testing.assert_allclose(
            airquality.skyline_edges(veiled) - clear, np.log(1 - t), rtol=0, atol=0.001
        )

    def test_skyline_edges_are_the_same_at_half_the_resolution(self) -> None:
        """The same view from a camera of half the resolution (area-averaged): both are
        measured at ``EDGE_WIDTH`` px across, so the features agree (to 0.001; 4e-5 seen)."""
        full = self.scene().round().astype(np.uint8)
        half = cv2.resize(full, (960, 160), interpolation=cv2.INTER_AREA)
        edges = [airquality.skyline_edges(airquality.luma(im)) for im in (half, full)]
        np.testing.assert_allclose(edges[0], edges[1], rtol=0, atol=0.001)

    def test_no_strip_or_a_flat_one_has_no_edges(self) -> None:
        floor = np.log(airquality.MIN_GRADIENT)
        flat = np.full((40, 50, 3), 128, np.uint8)
        np.testing.assert_array_equal(airquality.skyline_edges(airquality.luma(flat)), floor)
        np.testing.assert_array_equal(airquality.skyline_edges(None), floor)
        f = airquality.sky_features(self.image(40, 60))
        np.testing.assert_array_equal(f[-len(airquality.SKYLINE_BANDS) :], floor)

    def test_no_strip_is_no_contrast(self) -> None:
        f = airquality.sky_features(self.image(40, 60))
        n = len(airquality.SKYLINE_BANDS) * len(airquality.SKYLINE_QUANTILES) * 3
        np.testing.assert_array_equal(f[11 : 11 + n], np.log(airquality.MIN_CONTRAST))


class TestRegression:
    """The ridge regression's intervals and doubt on data of known noise (seeded)."""

    def data(self, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng(seed)
        x = rng.normal(0, 1, (n, 5))
        y = 3.0 + x @ np.array([0.3, -0.2, 0.1, 0.0, 0.05]) + rng.normal(0, 0.25, n)
        return x, y

    def test_the_interval_covers_as_promised(self) -> None:
        """σ = 0.25 in ln(1 + PM2.5): σ is found within 10 %, and the 80 % interval holds
        fresh values 80 ± 3 % of the time (2,000 draws: binomial s.e. 0.9 %)."""
        x, y = self.data(400, 0)
        model, _ = airquality.fit_regression(x, np.expm1(y), unit="pm25")
        assert model.sigma is not None
        assert abs(model.sigma - 0.25) < 0.025
        xt, yt = self.data(2000, 1)
        inside = []
        for f, v in zip(xt, np.expm1(yt), strict=True):
            e = model.estimate(f)
            assert e.low is not None
            assert e.high is not None
            inside.append(e.low <= v <= e.high)
            assert e.level == breakpoints.level_of_pm25(e.value)
        assert abs(np.mean(inside) - airquality.INTERVAL) < 0.03

    def test_days_left_out_carry_the_days_error(self) -> None:
        """With days as groups, σ comes from days left out: a day-wide offset (σ 0.5) the
        features do not see adds to the within-day noise (0.25): √(0.25² + 0.5²) = 0.56."""
        rng = np.random.default_rng(2)
        x, y = self.data(300, 3)
        days = np.repeat(np.arange(30), 10).astype(str)
        y = y + np.repeat(rng.normal(0, 0.5, 30), 10)
        by_day, _ = airquality.fit_regression(x, y, groups=list(days))
        assert by_day.sigma is not None
        assert 0.45 < by_day.sigma < 0.7

    def test_the_penalty_is_chosen_with_days_left_out(self) -> None:
        """Ten features that are constant within a day and noise across days let a fit
        remember each day's offset (σ 0.5) when single frames are left out, so leave-one-out
        picks a small α. With days as groups, α is the grid value of least mean squared
        error over days left out, computed here by the closed-form ridge (intercept
        unpenalised) on the same standardised features: a larger one."""
        rng = np.random.default_rng(7)
        x, y = self.data(240, 8)
        days = np.repeat(np.arange(24), 10)
        x = np.hstack([x, np.repeat(rng.normal(0, 1, (24, 10)), 10, axis=0)])
        y = y + np.repeat(rng.normal(0, 0.5, 24), 10)
        grid = np.logspace(-2, 3, 30)
        _, by_frame = airquality.fit_regression(x, y)
        _, by_day = airquality.fit_regression(x, y, groups=[str(d) for d in days])

        z = (x - x.mean(0)) / x.std(0)

        def error(alpha: float) -> float:
            per_day = []
            for d in range(24):
                tr, te = days != d, days == d
                zm, ym = z[tr].mean(0), y[tr].mean()
                zc = z[tr] - zm
                beta = np.linalg.solve(zc.T @ zc + alpha * np.eye(z.shape[1]), zc.T @ (y[tr] - ym))
                per_day.append(np.mean((y[te] - ym - (z[te] - zm) @ beta) ** 2))
            return float(np.mean(per_day))

        assert by_day == pytest.approx(grid[np.argmin([error(a) for a in grid])], rel=1e-12)
        assert by_day > by_frame

    def test_a_frame_far_outside_is_uncertain(self) -> None:
        x, y = self.data(200, 4)
        model, _ = airquality.fit_regression(x, y)
        far = np.array([0.0, 0.0, 0.0, 25.0, 0.0])
        e = model.estimate(far)
        assert e.uncertain is not None
        assert e.uncertain.startswith("outside the calibration")
        assert e.outside is True
        assert model.estimate(np.zeros(5)).leverage == pytest.approx(0.0, abs=1e-3)

    def test_an_interval_across_a_category_edge_is_uncertain(self) -> None:
        """Levels 1–10 and a level estimate of ≈ 4.5 (the Poor/Fair edge): uncertain;
        ≈ 9.5 ± 0.3 inside Very Good: sure."""
        rng = np.random.default_rng(5)
        x = rng.uniform(1, 10, (300, 1))
        y = x[:, 0] + rng.normal(0, 0.3, 300)
        model, _ = airquality.fit_regression(x, y)
        edge = model.estimate([4.5])
        assert edge.uncertain is not None
        assert "interval spans Poor to Fair" in edge.uncertain
        assert edge.span == ("Fair", "Poor")  # clearest first
        assert edge.outside is False  # inside the calibration: its level stands, doubted
        sure = model.estimate([9.6])
        assert sure.uncertain is None
        assert sure.level == 10
        assert sure.span is None

    def test_a_frame_far_outside_names_no_span(self) -> None:
        """Outside the calibration the interval is extrapolation: no categories to offer."""
        x, y = self.data(200, 4)
        model, _ = airquality.fit_regression(x, y)
        e = model.estimate(np.array([0.0, 0.0, 0.0, 25.0, 0.0]))
        assert e.outside is True
        assert e.span is None
