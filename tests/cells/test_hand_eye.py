"""Hand-eye calibration: the closed form and the refinement on exact synthetic poses, and
POST /calibrations/hand-eye on rendered views (the camera's intrinsics calibrated by the
service from the same views, K known only to the renderer)."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.cells.core import hand_eye
from app.cells.core.calibration import board_points
from tests.factories.cells import (
    BOARD_ON_FLANGE,
    CAMERA_IN_BASE,
    CENTRE,
    SQUARE,
    angle_deg,
    board_poses,
    flange_of,
    pose_json,
    render,
)


class TestCore:
    """On exact projections with 0.2 px of noise (seeded), through a known camera."""

    K = np.array([[900.0, 0.0, 640.0], [0.0, 900.0, 480.0], [0.0, 0.0, 1.0]])

    def _views(self, cs: list[np.ndarray], seed: int = 1) -> tuple[list[Any], list[Any]]:
        rng = np.random.default_rng(seed)
        obj = board_points(9, 6, SQUARE).astype(np.float64)
        pts, seen = [], []
        for c in cs:
            rvec = cv2.Rodrigues(c[:3, :3])[0]
            p = cv2.projectPoints(obj, rvec, c[:3, 3], self.K, np.zeros(5))[0].reshape(-1, 2)
            p = (p + rng.normal(0, 0.2, p.shape)).astype(np.float32)
            ok, rv, tv = cv2.solvePnP(obj.astype(np.float32), p, self.K, np.zeros(5))
            assert ok
            pts.append(p)
            seen.append(hand_eye.rigid(cv2.Rodrigues(rv)[0], tv.ravel()))
        return pts, seen

    def test_eye_to_hand_recovers_the_camera(self) -> None:
        cs = board_poses(14, seed=3)
        pts, seen = self._views(cs)
        obj = [board_points(9, 6, SQUARE)] * len(cs)
        got = hand_eye.solve(
            [flange_of(c) for c in cs], seen, obj, pts, self.K, np.zeros(5), eye_in_hand=False
        )
        assert np.linalg.norm(got.X[:3, 3] - CAMERA_IN_BASE[:3, 3]) < 0.5e-3  # m
        assert angle_deg(got.X, CAMERA_IN_BASE) < 0.05
        assert np.linalg.norm(got.Y[:3, 3] - BOARD_ON_FLANGE[:3, 3]) < 0.5e-3
        # the refinement over the corners does better than the closed form it starts from
        closed = np.linalg.norm(got.closed_form[:3, 3] - CAMERA_IN_BASE[:3, 3])
        assert np.linalg.norm(got.X[:3, 3] - CAMERA_IN_BASE[:3, 3]) <= closed
        # the noise put in: 0.2 px on each coordinate, √2 · 0.2 px a point
        assert got.rms_px == pytest.approx(0.2 * np.sqrt(2), rel=0.1)

    def test_eye_in_hand_recovers_the_camera_on_the_flange(self) -> None:
        on_flange = hand_eye.rigid(cv2.Rodrigues(np.r_[0.2, 0.1, -0.1])[0], np.r_[0.05, 0, 0.1])
        board_in_base = hand_eye.rigid(cv2.Rodrigues(np.r_[0, 0, 0.5])[0], np.r_[0.9, 0.2, 0])
        cs = board_poses(14, seed=4)
        pts, seen = self._views(cs)
        # F X C = Y: F = Y C⁻¹ X⁻¹
        flange = [board_in_base @ hand_eye.inverse(c) @ hand_eye.inverse(on_flange) for c in cs]
        got = hand_eye.solve(
            flange,
            seen,
            [board_points(9, 6, SQUARE)] * len(cs),
            pts,
            self.K,
            np.zeros(5),
            eye_in_hand=True,
        )
        assert np.linalg.norm(got.X[:3, 3] - on_flange[:3, 3]) < 0.5e-3
        assert angle_deg(got.X, on_flange) < 0.05

    def test_views_numbered_from_the_other_end_or_misnumbered(self) -> None:
        """A checkerboard numbered from its other end in some views (it looks the same turned
        by 180°) is read as the robot's motion says; a view whose corners are shifted by a
        square (a detector's misnumbering) is left out."""
        cs = board_poses(14, seed=5)
        pts, _ = self._views(cs)
        obj = board_points(9, 6, SQUARE)
        k, dist = self.K, np.zeros(5)
        grid = [p.reshape(6, 9, 2) for p in pts]
        readings = []
        for n, p in enumerate(grid):
            if n in (2, 6, 9):
                p = p[::-1, ::-1]  # numbered from the other end
            if n == 4:
                p = np.concatenate([p[:, 1:], p[:, -1:] + (p[:, -1:] - p[:, -2:-1])], axis=1)
            corners = np.ascontiguousarray(p.reshape(-1, 1, 2), dtype=np.float32)
            ways = []
            for c in (corners, corners[::-1].copy()):
                _, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, c, k, dist, flags=cv2.SOLVEPNP_IPPE)
                for rv, tv in zip(rvecs, tvecs, strict=True):
                    pose = hand_eye.rigid(cv2.Rodrigues(rv)[0], tv.ravel())
                    ways.append(hand_eye.Reading(pose, obj, c))
            readings.append(ways)
        got, kept, dropped = hand_eye.solve_numbered(
            [flange_of(c) for c in cs], readings, k, dist, eye_in_hand=False
        )
        assert dropped == [4]
        assert len(kept) == 13
        assert np.linalg.norm(got.X[:3, 3] - CAMERA_IN_BASE[:3, 3]) < 0.5e-3
        assert angle_deg(got.X, CAMERA_IN_BASE) < 0.05

    def test_turning_about_one_axis_is_not_observable(self) -> None:
        cs = []
        for k in range(8):
            r = cv2.Rodrigues(np.r_[0.0, 0.0, 0.25 * k - 1.0])[0]
            cs.append(hand_eye.rigid(r, -r @ CENTRE + np.r_[0.0, 0.0, 0.6]))
        pts, seen = self._views(cs)
        with pytest.raises(hand_eye.HandEyeError, match="not observable"):
            hand_eye.solve(
                [flange_of(c) for c in cs],
                seen,
                [board_points(9, 6, SQUARE)] * len(cs),
                pts,
                self.K,
                np.zeros(5),
                eye_in_hand=False,
            )

    @pytest.mark.parametrize(
        ("rotation", "translation", "says"),
        [
            (np.diag([1.0, 1.0, 1.1]), np.zeros(3), "not orthonormal"),
            (np.diag([1.0, 1.0, -1.0]), np.zeros(3), "reflection"),
            (np.eye(3), np.r_[450.0, 120.0, 800.0], "millimetres"),
        ],
    )
    def test_impossible_poses(self, rotation: Any, translation: Any, says: str) -> None:
        assert says in (hand_eye.check_pose(rotation, translation) or "")


@pytest.fixture(scope="module")
def views() -> tuple[list[np.ndarray], list[bytes]]:
    cs = board_poses(14, seed=11)
    return cs, render(cs)


def post(client: TestClient, admin: dict[str, str], **form: Any) -> Any:
    files = form.pop("files")
    return client.post(
        "/calibrations/hand-eye",
        files=[("files", (f"v{i}.png", f, "image/png")) for i, f in enumerate(files)],
        data={"pattern_cols": "9", "pattern_rows": "6", "square_size": str(SQUARE), **form},
        headers=admin,
    )


def intrinsics(client: TestClient, admin: dict[str, str], files: list[bytes]) -> str:
    r = client.post(
        "/calibrations",
        files=[("files", (f"v{i}.png", f, "image/png")) for i, f in enumerate(files)],
        data={"pattern_cols": "9", "pattern_rows": "6", "square_size": str(SQUARE)},
        headers=admin,
    )
    assert r.status_code == 201, r.text
    return str(r.json()["id"])


def test_the_camera_is_found_in_the_robots_base(
    client: TestClient, admin: dict[str, str], views: Any
) -> None:
    """The accuracy asked of it: 14 rendered poses, a 9 × 6 board of 30 mm, intrinsics the service
    calibrated from the same views: within 3 mm and 0.3° of the truth."""
    cs, files = views
    cid = intrinsics(client, admin, files)
    poses = [pose_json(flange_of(c)) for c in cs]
    r = post(client, admin, files=files, poses=poses, calibration_id=cid, setup="eye_to_hand")
    assert r.status_code == 201, r.text
    out = r.json()
    assert out["kind"] == "hand_eye"
    x = np.array(out["camera_to_base"])
    assert np.linalg.norm(x[:3, 3] - CAMERA_IN_BASE[:3, 3]) < 3e-3
    assert angle_deg(x, CAMERA_IN_BASE) < 0.3
    assert np.array(out["board_on_flange"]).shape == (4, 4)
    assert len(out["per_view"]) == 14
    assert out["rms_mm"] < 3
    assert out["rms_deg"] < 0.3
    listed = client.get("/calibrations", params={"kind": "hand_eye"}, headers=admin).json()
    assert [c["id"] for c in listed] == [out["id"]]


def test_a_rig_carrying_it_answers_in_the_robots_base(
    client: TestClient, admin: dict[str, str], views: Any
) -> None:
    """A stereo rig in mm whose camera 0 was hand-eye calibrated: triangulate with
    frame=robot puts a point where the hand-eye puts it, within 3 mm of the truth."""
    cs, files = views
    cid = intrinsics(client, admin, files)
    poses = [pose_json(flange_of(c)) for c in cs]
    r = post(client, admin, files=files, poses=poses, calibration_id=cid, setup="eye_to_hand")
    x = np.array(r.json()["camera_to_base"])
    cam = client.get(f"/calibrations/{cid}", headers=admin).json()
    k, dist = np.array(cam["K"]), np.array(cam["dist"])
    cameras = [
        {"K": cam["K"], "dist": cam["dist"], "R": np.eye(3).tolist(), "t": [0.0, 0.0, 0.0]},
        {"K": cam["K"], "dist": cam["dist"], "R": np.eye(3).tolist(), "t": [-100.0, 0.0, 0.0]},
    ]
    robot = {"hand_eye_id": r.json()["id"], "camera": 0, "rig_unit_m": 0.001}
    body = {"id": "cell", "kind": "calibrated", "cameras": cameras, "robot": robot}
    assert client.post("/rigs", json=body, headers=admin).status_code == 201
    in_cam = np.array([[0.02, 0.01, 0.5], [-0.05, 0.03, 0.7]])  # before camera 0 [m]
    truth = in_cam @ CAMERA_IN_BASE[:3, :3].T + CAMERA_IN_BASE[:3, 3]  # in the base
    observations = []
    for p in in_cam * 1000:  # the rig's mm
        seen = []
        for c in cameras:
            uv = cv2.projectPoints(p[None], np.zeros(3), np.array(c["t"]), k, dist)[0]
            seen.append(uv.ravel().tolist())
        observations.append(seen)
    got = client.post(
        "/rigs/cell/triangulate",
        json={"observations": observations, "frame": "robot"},
        headers=admin,
    ).json()
    assert got["frame"] == "robot"
    points = np.array(got["points"])
    expected = in_cam @ x[:3, :3].T + x[:3, 3]  # where the hand-eye puts them
    np.testing.assert_allclose(points, expected, atol=1e-6)
    assert np.abs(points - truth).max() < 3e-3
    rig = client.post(
        "/rigs/cell/triangulate", json={"observations": observations}, headers=admin
    ).json()
    np.testing.assert_allclose(np.array(rig["points"]), in_cam * 1000, atol=1e-3)
    plain = {"id": "plain", "kind": "calibrated", "cameras": cameras}
    assert client.post("/rigs", json=plain, headers=admin).status_code == 201
    refused = client.post(
        "/rigs/plain/triangulate",
        json={"observations": observations, "frame": "robot"},
        headers=admin,
    )
    assert refused.status_code == 422
    assert "no hand-eye calibration" in refused.json()["detail"]
    other = {**body, "id": "other", "robot": {**robot, "hand_eye_id": cid}}
    assert client.post("/rigs", json=other, headers=admin).status_code == 422


class TestRefused:
    """422 naming the pose; nothing stored."""

    def _stored(self, client: TestClient, admin: dict[str, str]) -> int:
        return len(client.get("/calibrations", params={"kind": "hand_eye"}, headers=admin).json())

    @pytest.mark.parametrize(
        ("change", "says"),
        [
            ("fewer", "13 poses for 14 files (fewer poses than files)"),
            ("not_orthonormal", "poses[2]: the rotation is not orthonormal"),
            ("millimetres", "poses[5]: the flange is"),
            ("not_json", "poses[0]: not JSON"),
        ],
    )
    def test_bad_poses(
        self, client: TestClient, admin: dict[str, str], views: Any, change: str, says: str
    ) -> None:
        cs, files = views
        poses = [pose_json(flange_of(c)) for c in cs]
        if change == "fewer":
            poses = poses[:-1]
        elif change == "not_orthonormal":
            bad = flange_of(cs[2])
            bad[:3, :3] *= 1.01
            poses[2] = pose_json(bad)
        elif change == "millimetres":
            bad = flange_of(cs[5])
            bad[:3, 3] *= 1000
            poses[5] = pose_json(bad)
        else:
            poses[0] = "{rotation"
        r = post(client, admin, files=files, poses=poses, calibration_id="x", setup="eye_to_hand")
        assert r.status_code == 422, r.text
        assert says in r.json()["detail"]
        assert self._stored(client, admin) == 0

    def test_one_axis_only(self, client: TestClient, admin: dict[str, str], views: Any) -> None:
        cs = []
        for k in range(6):
            r = (
                cv2.Rodrigues(np.r_[0.0, 0.0, 0.3 * k - 0.8])[0]
                @ cv2.Rodrigues(np.r_[0.3, 0, 0])[0]
            )
            cs.append(hand_eye.rigid(r, -r @ CENTRE + np.r_[0.0, 0.0, 0.6]))
        files = render(cs)
        _, calibrated = views
        cid = intrinsics(client, admin, calibrated)
        # the flange turns about one axis: its rotations all share the board's z axis
        base = hand_eye.rigid(np.eye(3), np.r_[0.5, 0.0, 0.4])
        poses = [pose_json(base @ hand_eye.inverse(cs[0]) @ c) for c in cs]
        r = post(client, admin, files=files, poses=poses, calibration_id=cid, setup="eye_in_hand")
        assert r.status_code == 422, r.text
        assert "not observable" in r.json()["detail"]
        assert r.json()["code"] == "not_observable"
        assert self._stored(client, admin) == 0
