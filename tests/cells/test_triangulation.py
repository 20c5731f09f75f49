"""Triangulation by simulation: project known 3-D points, then recover them."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.cells.core.triangulation import (
    PAIRS,
    SMALL_BATCH,
    RigArrays,
    View,
    baseline,
    project_views,
    triangulate_cross,
    triangulate_views,
    z_estimates,
)
from tests.factories.cells import RIG, calibrated_views, points


class TestCross:
    def test_geometry_of_the_contract(self) -> None:
        # a point on camera 1's axis is at its principal point
        uv = RIG.project(np.array([[0.15, 0.0, 2.0]]))[0]
        np.testing.assert_allclose(uv[0], [320.0, 240.0])
        assert uv[1, 0] > 320  # camera 2, left of it, sees the point to its right
        assert uv[3, 1] < 240  # camera 4, below, sees it higher (v down)

    @pytest.mark.parametrize("method", ["mean", "weighted", "least_squares"])
    def test_noise_free_is_exact(self, method: str) -> None:
        p = points(500)
        r = triangulate_cross(RIG, RIG.project(p), method=method)
        np.testing.assert_allclose(r.points, p, rtol=1e-9)
        assert np.nanmax(r.reprojection_rms) < 1e-6

    def test_ten_estimates_all_equal_z_without_noise(self) -> None:
        p = points(50)
        est = z_estimates(RIG, RIG.project(p))
        assert est.shape == (50, len(PAIRS)) == (50, 10)
        np.testing.assert_allclose(est, np.repeat(p[:, 2:3], 10, axis=1), rtol=1e-9)

    def test_weighting_beats_the_plain_mean_under_noise(self) -> None:
        rng = np.random.default_rng(1)
        p = points(4000, seed=2)
        obs = RIG.project(p) + rng.normal(0, 0.5, (4000, 4, 2))
        err = {
            m: np.sqrt(np.mean(np.sum((triangulate_cross(RIG, obs, method=m).points - p) ** 2, 1)))
            for m in ("mean", "weighted", "least_squares")
        }
        assert err["weighted"] < err["mean"]
        assert err["least_squares"] <= err["weighted"] * 1.02

    def test_a_missing_view(self) -> None:
        p = points(20)
        obs = RIG.project(p)
        obs[:, 2] = np.nan
        r = triangulate_cross(RIG, obs)
        np.testing.assert_allclose(r.points, p, rtol=1e-9)
        assert np.isnan(r.z_estimates[:, 1]).all()  # the 3–4 pair lacks camera 3

    @pytest.mark.parametrize("method", ["mean", "weighted", "least_squares"])
    def test_a_point_with_no_disparity_is_nan_and_spoils_no_other(self, method: str) -> None:
        # the same pixel in all four cameras: a point at infinity, no depth to solve for (the
        # least-squares normal equations are singular)
        p = points(6)
        obs = RIG.project(p)
        obs[3] = [RIG.cx, RIG.cy]
        r = triangulate_cross(RIG, obs, method=method)  # and no warning (they fail the test)
        assert np.isnan(r.points[3]).all()
        keep = [0, 1, 2, 4, 5]
        np.testing.assert_allclose(r.points[keep], p[keep], rtol=1e-9)

    @pytest.mark.parametrize("method", ["mean", "weighted", "least_squares"])
    def test_views_swapped_between_cameras_are_no_point(self, method: str) -> None:
        """Cameras 1 and 2 (and 3 and 4) given each other's pixels: the disparities change sign
        and the linear solution is the point mirrored behind the lens plane, reprojecting
        exactly. No camera saw that: NaN, as the pairwise estimates already said."""
        p = points(6, seed=4)
        obs = RIG.project(p)
        obs[2] = obs[2][[1, 0, 3, 2]]
        r = triangulate_cross(RIG, obs, method=method)
        assert np.isnan(r.points[2]).all()
        assert np.isnan(r.z_estimates[2]).all()
        assert r.behind.tolist() == [False, False, True, False, False, False]
        keep = [0, 1, 3, 4, 5]
        np.testing.assert_allclose(r.points[keep], p[keep], rtol=1e-9)


class TestCalibratedRig:
    def test_noise_free(self) -> None:
        views = calibrated_views()
        p = points(2000) + [0, 0, 1.0]
        r = triangulate_views(views, project_views(views, p))
        np.testing.assert_allclose(r.points, p, rtol=1e-11)
        assert np.nanmax(r.reprojection_rms) < 1e-8

    def test_noise_free_to_the_corners_of_a_wide_lens(self) -> None:
        """OpenCV's stereo sample (the intrinsics and distortion of its two cameras as the
        data README gives them: k1 −0.27 and −0.28; baseline 3.345 squares along x), seeing
        points out to the image corners. OpenCV's undistortion is five fixed-point steps,
        0.15 px off in the right camera's corners; refined against it, points 40 squares away
        came back up to 0.12 squares (3e-3 of their depth) off, with a reprojection RMS of
        0.05 px. Refined on the pixels themselves, they are exact."""
        left = View(
            np.array([[536.07, 0, 342.37], [0, 536.02, 235.54], [0, 0, 1]]),
            np.array([-0.2651, -0.0467, 0.0018, -0.0003, 0.2523]), np.eye(3), np.zeros(3),
        )  # fmt: skip
        r = cv2.Rodrigues(np.radians([0.0, 0.31, 0.0]))[0]
        right = View(
            np.array([[542.35, 0, 328.32], [0, 541.62, 246.95], [0, 0, 1]]),
            np.array([-0.2805, 0.1043, -0.0006, 0.0013, -0.0237]), r,
            np.array([-3.344, 0.042, 0.053]),
        )  # fmt: skip
        u, v = np.meshgrid(np.linspace(5, 635, 15), np.linspace(5, 475, 11))
        depth = 40.0  # squares: both cameras see the grid
        rays = np.column_stack([(u.ravel() - 342.37) / 536.07, (v.ravel() - 235.54) / 536.02])
        p = np.column_stack([rays * depth, np.full(len(rays), depth)])
        views = [left, right]
        obs = project_views(views, p)
        inside = ((obs >= 0) & (obs <= [640, 480])).all(axis=(1, 2))
        assert inside.sum() > 100
        res = triangulate_views(views, obs[inside])
        np.testing.assert_allclose(res.points, p[inside], rtol=1e-9)
        assert np.nanmax(res.reprojection_rms) < 1e-6

    def test_missing_views_and_an_outlier_view(self) -> None:
        rng = np.random.default_rng(3)
        views = calibrated_views()
        p = points(300) + [0, 0, 1.0]
        obs = project_views(views, p) + rng.normal(0, 0.3, (300, 4, 2))
        obs[:100, 0] = np.nan  # camera 0 missed a third of the points
        clean = triangulate_views(views, obs)
        obs[100:200, 3] += 40.0  # camera 3 is off by 40 px for another third
        r = triangulate_views(views, obs)
        assert not r.used[100:200, 3].any()  # the outlier view is rejected
        assert r.used[100:200, :3].all()
        rms = {
            k: float(np.sqrt(np.mean(np.sum((x.points[100:200] - p[100:200]) ** 2, 1))))
            for k, x in (("clean", clean), ("outlier", r))
        }
        # three good views instead of four: a little worse than clean, nothing like 40 px
        assert rms["outlier"] < 1.6 * rms["clean"]
        obs[200:, 1:] = np.nan  # a single view is not enough
        assert np.isnan(triangulate_views(views, obs).points[200:]).all()

    def test_a_point_behind_a_camera_that_saw_it_is_no_point(self) -> None:
        """Two parallel cameras given each other's pixels: the rays meet behind them (exactly,
        with no reprojection error), which no camera could have seen: NaN, no views used."""
        k = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
        views = [View(k, np.zeros(5), np.eye(3), np.array([x, 0.0, 0.0])) for x in (0.0, -0.3)]
        p = points(5, seed=6) + [0, 0, 1.0]
        obs = project_views(views, p)
        obs[1] = obs[1][::-1]
        r = triangulate_views(views, obs)
        assert np.isnan(r.points[1]).all()
        assert np.isnan(r.reprojection_rms[1])
        assert not r.used[1].any()
        assert r.behind.tolist() == [False, True, False, False, False]
        keep = [0, 2, 3, 4]
        np.testing.assert_allclose(r.points[keep], p[keep], rtol=1e-7)

    def test_rays_that_meet_only_at_the_lenses_are_no_point(self) -> None:
        """Two cameras side by side (baseline 0.1 along x) given pixels with no horizontal
        disparity but 10 px of vertical: the rays diverge, and come closest at the lenses
        themselves. The linear solution was (0.05, 0, 2e-12), returned as a point with a
        reprojection RMS of 2e13 px. A point 1/1000 of the baseline from a lens would show a
        disparity of 1000 f px; such a point was seen by no camera."""
        k = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
        views = [View(k, np.zeros(5), np.eye(3), np.array([x, 0.0, 0.0])) for x in (0.0, -0.1)]
        truth = np.array([[0.2, 0.05, 2.0]])
        obs = np.concatenate([project_views(views, truth), [[[330.0, 240.0], [330.0, 250.0]]]])
        r = triangulate_views(views, obs)
        np.testing.assert_allclose(r.points[0], truth[0], rtol=1e-9)
        assert np.isnan(r.points[1]).all()
        assert np.isnan(r.reprojection_rms[1])
        assert r.behind.tolist() == [False, True]
        # a real point close in, 1/50 of the baseline from the lens plane, is still a point
        near = np.array([[0.05, 0.0, 0.002]])
        np.testing.assert_allclose(
            triangulate_views(views, project_views(views, near)).points, near, rtol=1e-9
        )

    def test_two_gauss_newton_steps_converge(self) -> None:
        """The default steps reach the reprojection minimum: ten more move no point by more
        than a micrometre (points at 1–2 m, 0.3 px noise), and the refined points beat the
        linear ones."""
        rng = np.random.default_rng(5)
        views = calibrated_views()
        p = points(2000) + [0, 0, 1.0]
        obs = project_views(views, p) + rng.normal(0, 0.3, (2000, 4, 2))
        default = triangulate_views(views, obs)
        converged = triangulate_views(views, obs, steps=12)
        assert np.abs(default.points - converged.points).max() < 1e-6
        linear = triangulate_views(views, obs, refine=False)
        assert np.nanmean(default.reprojection_rms) < np.nanmean(linear.reprojection_rms)

    def test_large_batches_split_over_threads_agree(self) -> None:
        rng = np.random.default_rng(6)
        views = calibrated_views()
        p = points(30_000) + [0, 0, 1.0]
        obs = project_views(views, p) + rng.normal(0, 0.3, (30_000, 4, 2))
        obs[::7, 2] = np.nan
        whole = triangulate_views(views, obs)
        parts = [triangulate_views(views, obs[a : a + 10_000]) for a in (0, 10_000, 20_000)]
        np.testing.assert_array_equal(whole.points, np.concatenate([x.points for x in parts]))
        np.testing.assert_array_equal(whole.used, np.concatenate([x.used for x in parts]))

    def test_numpy_and_compiled_paths_agree(self) -> None:
        """Small batches go through NumPy (no compiler to load), large ones through the
        compiled loop: the same points, views used and RMS, outliers, missing views and
        mismatched points included."""
        rng = np.random.default_rng(8)
        views = calibrated_views()
        n = 3000
        p = points(n) + [0, 0, 1.0]
        obs = project_views(views, p) + rng.normal(0, 0.3, (n, 4, 2))
        obs[::5, 0] = np.nan
        obs[1::7, 3] += 40.0
        obs[2::11, 1:] = np.nan
        obs[3::13, 1] = obs[3::13, 1][::-1]
        assert n > SMALL_BATCH
        compiled = triangulate_views(views, obs)
        small = [
            triangulate_views(views, obs[a : a + SMALL_BATCH]) for a in range(0, n, SMALL_BATCH)
        ]
        for name in ("points", "reprojection_rms", "used", "behind"):
            got = np.concatenate([getattr(x, name) for x in small])
            want = getattr(compiled, name)
            if want.dtype == np.bool_:
                np.testing.assert_array_equal(got, want, err_msg=name)
            else:
                np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-9, err_msg=name)


def test_baseline_is_the_largest_distance_between_lens_centres() -> None:
    """Known answers: centres −Rᵀt worked out by hand."""
    k, d, i = np.eye(3), np.zeros(5), np.eye(3)
    turned = np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]])  # 90° about y
    a = View(k, d, i, np.array([0.5, 0, 2]))  # centre (−0.5, 0, −2)
    b = View(k, d, turned, np.array([-2, 0, 0.5]))  # centre (−0.5, 0, −2) too
    c = View(k, d, i, np.array([-2.5, 4, 2]))  # centre (2.5, −4, −2): 5 from the others

    def of(*views: View) -> float:
        rig = RigArrays.of(list(views))
        return baseline(rig.rs, rig.ts)

    assert of(a, b) == 0
    assert of(a, b, c) == pytest.approx(5.0, rel=1e-12)
    # one part in 10¹² of a centre 2 m out is rounding, not a baseline
    assert of(a, View(k, d, i, np.array([0.5, 0, 2 + 2e-12]))) == 0
    assert of(a, View(k, d, i, np.array([0.5, 0, 2 + 1e-6]))) == pytest.approx(1e-6)
