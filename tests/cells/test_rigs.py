"""Rigs over HTTP: register, triangulate."""

from __future__ import annotations

import functools
import json
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, insert

from app.cells.core.triangulation import CrossRig, View, project_views
from app.cells.models import Rig
from tests.factories.cells import RIG, calibrated_views, points


def test_cross_rig(client: TestClient, admin: dict[str, str]) -> None:
    body = {
        "id": "cell-1",
        "kind": "cross",
        "f_px": 800,
        "ax": 0.3,
        "ay": 0.2,
        "principal_point": [320, 240],
    }
    assert client.post("/rigs", json=body, headers=admin).status_code == 201
    assert client.post("/rigs", json=body, headers=admin).status_code == 409
    p = points(5)
    obs = RIG.project(p).tolist()
    obs[4][1] = None
    obs[4][2] = None
    obs[4][3] = None  # one view only: no point
    r = client.post("/rigs/cell-1/triangulate", json={"observations": obs}, headers=admin)
    assert r.status_code == 200, r.text
    out = r.json()
    np.testing.assert_allclose(out["points"][:4], p[:4], rtol=1e-9)
    assert out["points"][4] is None
    assert len(out["z_estimates"][0]) == 10
    # the same pixel in every camera (no disparity: at infinity) is no point either, not a 500
    obs[4] = [[320, 240]] * 4
    r = client.post("/rigs/cell-1/triangulate", json={"observations": obs}, headers=admin)
    assert r.status_code == 200, r.text
    assert r.json()["points"][4] is None
    np.testing.assert_allclose(r.json()["points"][:4], p[:4], rtol=1e-9)


@pytest.mark.parametrize("method", ["least_squares", "weighted", "mean"])
def test_a_point_not_found_says_why(client: TestClient, admin: dict[str, str], method: str) -> None:
    body = {"kind": "cross", "f_px": 800, "ax": 0.3, "ay": 0.2, "principal_point": [320, 240]}
    assert client.post("/rigs", json={"id": "cell-1", **body}, headers=admin).status_code == 201
    p = points(4)
    seen = RIG.project(p)
    once = [seen[0][0].tolist(), None, None, None]
    swapped = seen[1][[1, 0, 3, 2]].tolist()  # cameras 1↔2 and 3↔4: mirrored behind the lens
    nowhere = [[320.0, 240.0]] * 4  # no disparity in any pair
    obs = [once, swapped, nowhere, seen[3].tolist()]
    r = client.post(
        "/rigs/cell-1/triangulate", json={"observations": obs, "method": method}, headers=admin
    )
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["null_reasons"] == ["too_few_views", "behind_camera", "no_depth", None]
    assert out["points"][:3] == [None, None, None]
    np.testing.assert_allclose(out["points"][3], p[3], rtol=1e-9)


def test_a_rig_given_new_geometry_measures_with_it(
    client: TestClient, admin: dict[str, str]
) -> None:
    # the cell's cameras were spread wider (ax 0.3 → 0.5) and the rig told so: the same points,
    # projected through the new cross, come back where they are only with the new geometry
    body = {"kind": "cross", "f_px": 800, "ax": 0.3, "ay": 0.2, "principal_point": [320, 240]}
    assert client.post("/rigs", json={"id": "cell-1", **body}, headers=admin).status_code == 201
    wider = CrossRig(f=800.0, ax=0.5, ay=0.2, cx=320.0, cy=240.0)
    p = points(5)
    obs = {"observations": wider.project(p).tolist()}
    before = client.post("/rigs/cell-1/triangulate", json=obs, headers=admin).json()
    assert not np.allclose(before["points"], p, atol=1e-3)  # the old geometry measures wrong

    r = client.put("/rigs/cell-1", json={**body, "ax": 0.5}, headers=admin)
    assert r.status_code == 200, r.text
    assert r.json()["spec"]["ax"] == 0.5
    assert r.json()["updated_at"] is not None
    after = client.post("/rigs/cell-1/triangulate", json=obs, headers=admin).json()
    np.testing.assert_allclose(after["points"], p, rtol=1e-9)
    assert client.get("/rigs/cell-1", headers=admin).json()["spec"]["ax"] == 0.5

    robot = client.post("/robots", json={"id": "arm"}, headers=admin).json()["token"]
    as_robot = {"Authorization": f"Bearer {robot}"}
    assert [g["id"] for g in client.get("/rigs", headers=as_robot).json()] == ["cell-1"]
    assert client.put("/rigs/cell-1", json=body, headers=as_robot).status_code == 403
    assert client.delete("/rigs/cell-1", headers=as_robot).status_code == 403
    # a replacement that is no rig changes nothing
    bad = client.put("/rigs/cell-1", json={**body, "ax": None}, headers=admin)
    assert bad.status_code == 422
    assert client.get("/rigs/cell-1", headers=admin).json()["spec"]["ax"] == 0.5
    assert client.put("/rigs/nope", json=body, headers=admin).status_code == 404
    # the body POST took, id and all, is taken when the id is the rig's
    same = client.put("/rigs/cell-1", json={"id": "cell-1", **body, "ax": 0.5}, headers=admin)
    assert same.status_code == 200, same.text
    other = client.put("/rigs/cell-1", json={"id": "cell-2", **body}, headers=admin)
    assert other.status_code == 422
    assert client.get("/rigs/cell-1", headers=admin).json()["spec"]["ax"] == 0.5

    assert client.delete("/rigs/cell-1", headers=admin).status_code == 204
    assert client.get("/rigs/cell-1", headers=admin).status_code == 404
    assert client.post("/rigs/cell-1/triangulate", json=obs, headers=admin).status_code == 404
    assert client.get("/rigs", headers=admin).json() == []
    assert client.delete("/rigs/cell-1", headers=admin).status_code == 404
    assert client.post("/rigs", json={"id": "cell-1", **body}, headers=admin).status_code == 201


def test_calibrated_rig(client: TestClient, admin: dict[str, str]) -> None:
    views = calibrated_views()
    cams = [
        {"K": v.K.tolist(), "dist": v.dist.tolist(), "R": v.R.tolist(), "t": v.t.tolist()}
        for v in views
    ]
    assert (
        client.post(
            "/rigs", json={"id": "r", "kind": "calibrated", "cameras": cams}, headers=admin
        ).status_code
        == 201
    )
    p = points(10) + [0, 0, 1.0]
    obs = project_views(views, p).tolist()
    r = client.post("/rigs/r/triangulate", json={"observations": obs}, headers=admin)
    assert r.status_code == 200, r.text
    np.testing.assert_allclose(r.json()["points"], p, rtol=1e-7)
    assert r.json()["null_reasons"] == [None] * 10
    obs[0] = [obs[0][0], None, None, None]
    r = client.post("/rigs/r/triangulate", json={"observations": obs}, headers=admin)
    assert r.json()["null_reasons"][:2] == ["too_few_views", None]


def test_a_point_behind_a_calibrated_pair_says_so(
    client: TestClient, admin: dict[str, str]
) -> None:
    k = [[800.0, 0, 320], [0, 800, 240], [0, 0, 1]]
    eye = np.eye(3).tolist()
    cams = [{"K": k, "R": eye, "t": [x, 0.0, 0.0]} for x in (0.0, -0.3)]
    r = client.post(
        "/rigs", json={"id": "pair", "kind": "calibrated", "cameras": cams}, headers=admin
    )
    assert r.status_code == 201, r.text
    views = [
        View(np.array(k), np.zeros(5), np.eye(3), np.array([x, 0.0, 0.0])) for x in (0.0, -0.3)
    ]
    p = points(2, seed=6) + [0, 0, 1.0]
    obs = project_views(views, p)
    obs[1] = obs[1][::-1]  # each camera given the other's pixel
    parallel = [[320.0, 240.0], [320.0, 240.0]]  # both rays along the optical axis
    body = {"observations": [*obs.tolist(), parallel]}
    r = client.post("/rigs/pair/triangulate", json=body, headers=admin)
    assert r.json()["null_reasons"] == [None, "behind_camera", "no_depth"]
    np.testing.assert_allclose(r.json()["points"][0], p[0], rtol=1e-7)


def test_bad_rigs_and_observations(client: TestClient, admin: dict[str, str]) -> None:
    bad_r = {
        "id": "x",
        "kind": "calibrated",
        "cameras": [
            {
                "K": [[800, 0, 320], [0, 800, 240], [0, 0, 1]],
                "R": [[2, 0, 0], [0, 1, 0], [0, 0, 1]],
                "t": [0, 0, 0],
            },
            {
                "K": [[800, 0, 320], [0, 800, 240], [0, 0, 1]],
                "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
                "t": [1, 0, 0],
            },
        ],
    }
    assert client.post("/rigs", json=bad_r, headers=admin).status_code == 422
    # two cameras with one lens centre (the same t given twice, a pose pasted over another):
    # no baseline, so no point could ever be triangulated
    one_centre = {
        "id": "one-centre",
        "kind": "calibrated",
        "cameras": [
            {"K": [[800, 0, 320], [0, 800, 240], [0, 0, 1]], "R": r, "t": t}
            for r, t in [
                ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], [0.5, 0, 2]),
                # turned 90° about y: its centre −Rᵀt is the first's, (−0.5, 0, −2)
                ([[0, 0, -1], [0, 1, 0], [1, 0, 0]], [-2, 0, 0.5]),
            ]
        ],
    }
    r = client.post("/rigs", json=one_centre, headers=admin)
    assert r.status_code == 422
    assert "centre" in r.json()["detail"]
    assert client.get("/rigs/one-centre", headers=admin).status_code == 404
    assert (
        client.post(
            "/rigs", json={"id": "y", "kind": "cross", "f_px": 800}, headers=admin
        ).status_code
        == 422
    )
    client.post(
        "/rigs", json={"id": "c", "kind": "cross", "f_px": 800, "ax": 0.3, "ay": 0.2}, headers=admin
    )
    r = client.post("/rigs/c/triangulate", json={"observations": [[[1, 2], [3, 4]]]}, headers=admin)
    assert r.status_code == 422
    r = client.post(
        "/rigs/c/triangulate",
        content=b'{"observations": [[[NaN, 1], null, null, null]]}',
        headers={**admin, "Content-Type": "application/json"},
    )
    assert r.status_code == 422
    assert (
        client.post("/rigs/none/triangulate", json={"observations": []}, headers=admin).status_code
        == 404
    )


def render_views(
    rig: object, point: np.ndarray, *, distractor: bool = False, seed: int = 0
) -> list[bytes]:
    """Four 640×480 photos of a grey scene with the laser dot (a red Gaussian spot, σ 1.5 px)
    where the cross sees ``point``; optionally a red label in camera 2."""
    import cv2

    rng = np.random.default_rng(seed)
    uv = RIG.project(point[None])[0]
    y, x = np.mgrid[0:480, 0:640]
    out = []
    for i in range(4):
        image = np.full((480, 640, 3), 110.0) + rng.normal(0, 3, (480, 640, 3))
        g = np.exp(-((x - uv[i, 0]) ** 2 + (y - uv[i, 1]) ** 2) / (2 * 1.5**2))
        image[..., 0] += 145 * g
        image[..., 1] -= 60 * g
        image[..., 2] -= 60 * g
        if distractor and i == 1:
            image[100:106, 500:520] = (230, 30, 30)
        ok, buf = cv2.imencode(".png", np.clip(image, 0, 255).astype(np.uint8)[:, :, ::-1])
        out.append(buf.tobytes())
    return out


CELL = {
    "id": "cell",
    "kind": "cross",
    "f_px": RIG.f,
    "ax": RIG.ax,
    "ay": RIG.ay,
    "principal_point": [RIG.cx, RIG.cy],
}
"""The cross of ``render_views``, registered."""


def as_files(images: list[bytes]) -> list[tuple[str, tuple[str, bytes, str]]]:
    return [("files", (f"{i}.png", im, "image/png")) for i, im in enumerate(images)]


def test_laser_dot_within_1_mm_at_1_m(client: TestClient, admin: dict[str, str]) -> None:
    client.post("/rigs", json=CELL, headers=admin)
    truth = np.array([0.05, -0.03, 1.0])
    images = render_views(RIG, truth, distractor=True)
    r = client.post(
        "/rigs/cell/laser/dot",
        files=as_files(images),
        headers=admin,
    )
    assert r.status_code == 200, r.text
    out = r.json()
    assert np.linalg.norm(np.array(out["point"]) - truth) < 0.001
    np.testing.assert_allclose(out["pixels"], RIG.project(truth[None])[0], atol=0.2)


def recoloured(png: bytes, order: list[int]) -> bytes:
    """The PNG with its RGB channels taken in ``order``: [1, 0, 2] makes a red laser green."""
    import cv2

    rgb = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR_RGB)
    return bytes(cv2.imencode(".png", np.ascontiguousarray(rgb[..., order][..., ::-1]))[1])


def test_a_green_laser_dot(client: TestClient, admin: dict[str, str]) -> None:
    """The same render with the dot (and the red label beside it) green: found when the
    request says the laser is green, within 1 mm at 1 m as the red one; not by default."""
    client.post("/rigs", json=CELL, headers=admin)
    truth = np.array([0.05, -0.03, 1.0])
    images = [recoloured(im, [1, 0, 2]) for im in render_views(RIG, truth, distractor=True)]
    r = client.post(
        "/rigs/cell/laser/dot", params={"laser": "green"}, files=as_files(images), headers=admin
    )
    assert r.status_code == 200, r.text
    assert np.linalg.norm(np.array(r.json()["point"]) - truth) < 0.001
    r = client.post("/rigs/cell/laser/dot", files=as_files(images), headers=admin)
    assert r.status_code == 422
    assert r.json()["code"] == "dot_not_found"
    r = client.post(
        "/rigs/cell/laser/dot", params={"laser": "ir"}, files=as_files(images), headers=admin
    )
    assert r.status_code == 422


def test_laser_dot_not_found(client: TestClient, admin: dict[str, str]) -> None:
    client.post("/rigs", json=CELL, headers=admin)
    images = render_views(RIG, np.array([5.0, 0.0, 1.0]))  # far off every image
    r = client.post(
        "/rigs/cell/laser/dot",
        files=as_files(images),
        headers=admin,
    )
    assert r.status_code == 422
    assert "camera(s) 1, 2, 3, 4" in r.json()["detail"]
    r = client.post("/rigs/cell/laser/dot", files=as_files(images[:1]), headers=admin)
    assert r.status_code == 422


def test_images_of_another_size_than_calibrated_are_refused(
    client: TestClient, admin: dict[str, str]
) -> None:
    """The cross of ``render_views`` as calibrated cameras (R = I, t = (−Xi, Yi, 0); Y flips)
    whose K is for 640×480. The same scene photographed at 1280×960 puts the dot at twice the
    pixels: it was located at (0.250, 0.180, 0.500) instead of (0.05, 0.03, 1.0), with a
    reprojection error of 0.05 px."""

    k = [[RIG.f, 0.0, RIG.cx], [0.0, RIG.f, RIG.cy], [0.0, 0.0, 1.0]]
    eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    centres = [(0.15, 0.0), (-0.15, 0.0), (0.0, 0.1), (0.0, -0.1)]
    cameras = [{"K": k, "R": eye, "t": [-x, y, 0.0], "image_size": [640, 480]} for x, y in centres]
    rig = {"id": "sized", "kind": "calibrated", "cameras": cameras}
    assert client.post("/rigs", json=rig, headers=admin).status_code == 201
    truth = np.array([0.05, -0.03, 1.0])
    images = render_views(RIG, truth)
    r = client.post("/rigs/sized/laser/dot", files=as_files(images), headers=admin)
    assert r.status_code == 200, r.text
    np.testing.assert_allclose(r.json()["point"], [0.05, 0.03, 1.0], atol=0.001)
    pixels = r.json()["pixels"]

    r = client.post(
        "/rigs/sized/laser/dot", files=as_files([doubled(b) for b in images]), headers=admin
    )
    assert r.status_code == 422, r.text
    assert r.json()["code"] == "wrong_image_size"
    assert "camera 1's image is 1280×960 px" in r.json()["detail"]
    assert "calibrated for 640×480" in r.json()["detail"]
    r = client.post(
        "/rigs/sized/laser/grid",
        files=as_files([doubled(b) for b in images]),
        data={"origin": json.dumps(pixels)},
        headers=admin,
    )
    assert r.status_code == 422, r.text
    assert r.json()["code"] == "wrong_image_size"


def doubled(png: bytes) -> bytes:
    """The image at twice its width and height (a camera switched to a larger resolution)."""
    import cv2

    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    big = cv2.resize(image, (1280, 960), interpolation=cv2.INTER_CUBIC)
    return cv2.imencode(".png", big)[1].tobytes()


def test_a_cross_rig_refuses_images_of_another_size_than_its_own(
    client: TestClient, admin: dict[str, str]
) -> None:
    """The cross's f_px and principal point are pixels of 640×480 images. Sent 1280×960
    photos of the dot at (0.05, −0.03, 1.0) m, a cross that does not know its size answers
    200 with a point tens of centimetres off; one registered with its image_size refuses them."""
    truth = np.array([0.05, -0.03, 1.0])
    images = render_views(RIG, truth)
    big = [doubled(b) for b in images]
    assert client.post("/rigs", json=CELL, headers=admin).status_code == 201
    r = client.post("/rigs/cell/laser/dot", files=as_files(big), headers=admin)
    assert r.status_code == 200, r.text
    assert np.linalg.norm(np.array(r.json()["point"]) - truth) > 0.1  # confidently wrong

    sized = {**CELL, "id": "sized", "image_size": [640, 480]}
    r = client.post("/rigs", json=sized, headers=admin)
    assert r.status_code == 201, r.text
    assert r.json()["spec"]["image_size"] == [640, 480]
    r = client.post("/rigs/sized/laser/dot", files=as_files(images), headers=admin)
    assert r.status_code == 200, r.text
    assert np.linalg.norm(np.array(r.json()["point"]) - truth) < 0.001
    pixels = r.json()["pixels"]
    r = client.post("/rigs/sized/laser/dot", files=as_files(big), headers=admin)
    assert (r.status_code, r.json()["code"]) == (422, "wrong_image_size"), r.text
    assert "camera 1's image is 1280×960 px" in r.json()["detail"]
    r = client.post(
        "/rigs/sized/laser/grid",
        files=as_files(big),
        data={"origin": json.dumps(pixels)},
        headers=admin,
    )
    assert (r.status_code, r.json()["code"]) == (422, "wrong_image_size"), r.text

    k = [[RIG.f, 0.0, RIG.cx], [0.0, RIG.f, RIG.cy], [0.0, 0.0, 1.0]]
    eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    two = [{"K": k, "R": eye, "t": [x, 0.0, 0.0]} for x in (0.0, -0.3)]
    r = client.post(
        "/rigs",
        json={"id": "pair", "kind": "calibrated", "cameras": two, "image_size": [640, 480]},
        headers=admin,
    )
    assert r.status_code == 422, r.text
    assert "per camera" in r.json()["detail"]


def test_shape_match(client: TestClient, admin: dict[str, str]) -> None:
    import itertools

    corners = [list(c) for c in itertools.product((0.0, 0.4), (0.0, 0.2), (0.0, 0.1))]
    r = client.post("/shapes/match", json={"points": corners}, headers=admin)
    assert r.status_code == 200, r.text
    best = r.json()[0]
    assert best["shape"] == "box"
    assert sorted(best["dimensions"].values()) == [
        pytest.approx(0.1),
        pytest.approx(0.2),
        pytest.approx(0.4),
    ]
    assert best["hidden_corners"] == 0
    # the far bottom corner unseen: still the box, one corner hidden
    seen = client.post("/shapes/match", json={"points": corners[:7]}, headers=admin).json()[0]
    assert (seen["shape"], seen["hidden_corners"]) == ("box", 1)
    assert sorted(seen["dimensions"].values()) == pytest.approx([0.1, 0.2, 0.4], abs=1e-6)
    assert (
        client.post("/shapes/match", json={"points": corners[:3]}, headers=admin).status_code == 422
    )


@functools.cache
def grid_scene() -> tuple:
    from tests.cells.laser_scenes import Part, Scene, render

    scene = Scene(
        Part("box", (0.20, 0.14, 0.08), (0.01, -0.02), 0.15), table_tilt=0.05, grid_rotation=0.1
    )
    return scene, render(scene, seed=1), render(scene, mode="dot", seed=2)


class TestLaserGrid:
    """``POST /rigs/{id}/laser/grid`` on a ray-traced box (tests/cells/laser_scenes.py)."""

    CROSS = {
        "id": "cell",
        "kind": "cross",
        "f_px": 1000,
        "ax": 0.3,
        "ay": 0.2,
        "principal_point": [320, 240],
    }

    @staticmethod
    def png(images: list[np.ndarray], field: str) -> list[tuple[str, tuple[str, bytes, str]]]:
        import cv2

        return [
            (field, (f"{i}.png", cv2.imencode(".png", im[:, :, ::-1])[1].tobytes(), "image/png"))
            for i, im in enumerate(images)
        ]

    def measure_box(
        self,
        client: TestClient,
        admin: dict[str, str],
        rig: str,
        truth: Any,
        grid: list[np.ndarray],
        dots: list[np.ndarray],
    ) -> dict[str, Any]:
        """POST the grid and dot images; the volume and top area within 2 % of the box's."""
        r = client.post(
            f"/rigs/{rig}/laser/grid",
            files=self.png(grid, "files") + self.png(dots, "dot_files"),
            headers=admin,
        )
        assert r.status_code == 200, r.text
        out: dict[str, Any] = r.json()
        # ground truth: the box's own dimensions
        assert out["volume"] == pytest.approx(truth.part.volume, rel=0.02)
        assert out["surface_area"] == pytest.approx(truth.part.top_area, rel=0.02)
        return out

    def test_a_green_grid(self, client: TestClient, admin: dict[str, str]) -> None:
        """The box's scene with the grid and the dot green (a 532 nm laser), measured as
        the red one is when the request says so."""
        truth, grid, dots = grid_scene()
        assert client.post("/rigs", json=self.CROSS, headers=admin).status_code == 201
        green = [np.ascontiguousarray(im[..., [1, 0, 2]]) for im in grid]
        green_dots = [np.ascontiguousarray(im[..., [1, 0, 2]]) for im in dots]
        r = client.post(
            "/rigs/cell/laser/grid",
            params={"laser": "green"},
            files=self.png(green, "files") + self.png(green_dots, "dot_files"),
            headers=admin,
        )
        assert r.status_code == 200, r.text
        assert r.json()["volume"] == pytest.approx(truth.part.volume, rel=0.02)
        assert r.json()["surface_area"] == pytest.approx(truth.part.top_area, rel=0.02)
        r = client.post(
            "/rigs/cell/laser/grid",
            files=self.png(green, "files") + self.png(green_dots, "dot_files"),
            headers=admin,
        )
        assert r.status_code == 422

    def test_box_area_and_volume(self, client: TestClient, admin: dict[str, str]) -> None:
        truth, grid, dots = grid_scene()
        assert client.post("/rigs", json=self.CROSS, headers=admin).status_code == 201
        out = self.measure_box(client, admin, "cell", truth, grid, dots)
        np.testing.assert_allclose(out["base_plane"], truth.base_plane(), atol=0.005)
        assert len(out["points"]) == len(out["labels"]) == len(out["surfaces"]) > 1400
        assert min(out["nodes_per_view"]) > 1000
        # the dot's node is (0, 0), on the box's top
        dot = out["points"][out["labels"].index([0, 0])]
        assert dot[2] == pytest.approx(0.92, abs=0.002)

        # the dot's pixels (as /laser/dot returns them) serve as the origin too
        pixels = client.post(
            "/rigs/cell/laser/dot", files=self.png(dots, "files"), headers=admin
        ).json()["pixels"]
        r2 = client.post(
            "/rigs/cell/laser/grid",
            files=self.png(grid, "files"),
            data={"origin": json.dumps(pixels), "base_plane": json.dumps(list(truth.base_plane()))},
            headers=admin,
        )
        assert r2.status_code == 200, r2.text
        assert r2.json()["volume"] == pytest.approx(truth.part.volume, rel=0.02)
        np.testing.assert_allclose(r2.json()["base_plane"], truth.base_plane(), atol=1e-9)

    def test_over_exposed_jpeg_photos(self, client: TestClient, admin: dict[str, str]) -> None:
        """The box as a camera sends it: JPEG (quality 80) and over-exposed, the lines' red
        saturated on the brown box. Before, this came back 200 with a volume of 0."""
        import cv2

        from tests.cells.laser_scenes import photographed

        truth, grid, dots = grid_scene()

        def jpeg(images: list[np.ndarray], field: str) -> list[tuple[str, tuple]]:
            quality = [cv2.IMWRITE_JPEG_QUALITY, 80]
            return [
                (
                    field,
                    (
                        f"{i}.jpg",
                        cv2.imencode(".jpg", im[:, :, ::-1], quality)[1].tobytes(),
                        "image/jpeg",
                    ),
                )
                for i, im in enumerate(photographed(im, 1.6) for im in images)
            ]

        client.post("/rigs", json=self.CROSS, headers=admin)
        r = client.post(
            "/rigs/cell/laser/grid",
            files=jpeg(grid, "files") + jpeg(dots, "dot_files"),
            headers=admin,
        )
        assert r.status_code == 200, r.text
        assert r.json()["volume"] == pytest.approx(truth.part.volume, rel=0.02)
        assert r.json()["surface_area"] == pytest.approx(truth.part.top_area, rel=0.02)

    def test_the_same_images_on_a_calibrated_rig(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        """The cross's frame is left-handed (Y up); with Y flipped it is a calibrated rig of four
        cameras with R = I and t = (−Xi, Yi, 0), which sees exactly the same images."""
        truth, grid, dots = grid_scene()
        k = [[1000.0, 0.0, 320.0], [0.0, 1000.0, 240.0], [0.0, 0.0, 1.0]]
        eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        centres = [(0.15, 0.0), (-0.15, 0.0), (0.0, 0.1), (0.0, -0.1)]
        cameras = [{"K": k, "R": eye, "t": [-x, y, 0.0]} for x, y in centres]
        r = client.post(
            "/rigs", json={"id": "flat", "kind": "calibrated", "cameras": cameras}, headers=admin
        )
        assert r.status_code == 201, r.text
        out = self.measure_box(client, admin, "flat", truth, grid, dots)
        a, b, c, d = truth.base_plane()
        np.testing.assert_allclose(out["base_plane"], [a, -b, c, d], atol=0.005)

    def test_a_grid_square_to_the_cross_is_refused(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        """Periodic along the baselines, it can be matched whole cells off: no figures."""
        from tests.cells.laser_scenes import Part, Scene, render

        scene = Scene(Part("box", (0.20, 0.14, 0.08), (0.01, -0.02), 0.15))
        client.post("/rigs", json=self.CROSS, headers=admin)
        r = client.post(
            "/rigs/cell/laser/grid",
            files=self.png(render(scene, seed=1), "files")
            + self.png(render(scene, mode="dot", seed=2), "dot_files"),
            headers=admin,
        )
        assert r.status_code == 422, r.text
        assert r.json()["code"] == "grid_ambiguous"
        assert "rotate the laser" in r.json()["detail"]

    def test_bad_requests(self, client: TestClient, admin: dict[str, str]) -> None:
        _, grid, _ = grid_scene()
        client.post("/rigs", json=self.CROSS, headers=admin)
        url = "/rigs/cell/laser/grid"
        cases = [
            ({"files": self.png(grid[:3], "files")}, "one grid image per camera"),
            (
                {"files": self.png(grid, "files"), "data": {"origin": "[[1, 2], null]"}},
                "origin must be a list of 4",
            ),
            (
                {
                    "files": self.png(grid, "files"),
                    "data": {"origin": "[[NaN, 1], null, null, null]"},
                },
                "origin",
            ),
            (
                {"files": self.png(grid, "files"), "data": {"base_plane": "[0, 0, 0, 1]"}},
                "non-zero normal",
            ),
            (
                {"files": self.png([np.full((480, 640, 3), 90, np.uint8)] * 4, "files")},
                "no laser grid",
            ),
            ({"files": [("files", ("a.png", b"not an image", "image/png"))] * 4}, "not a JPEG"),
        ]
        for kwargs, detail in cases:
            r = client.post(url, headers=admin, **kwargs)
            assert r.status_code in (415, 422), (detail, r.text)
            assert r.headers["content-type"] == "application/problem+json"
            assert detail in r.json()["detail"], r.json()
        assert client.post(url, json={}, headers=admin).status_code == 415
        assert (
            client.post(
                "/rigs/none/laser/grid", files=self.png(grid, "files"), headers=admin
            ).status_code
            == 404
        )


def test_a_rig_registered_twice_at_once_is_one_rig_and_a_409(
    client: TestClient, admin: dict[str, str], engine: Engine
) -> None:
    """The same rig registered by two requests at once (a deploy script run twice, a retry
    after a timeout): the second looks before the first has committed, finds no rig, and its
    insert then collides with the first's row. It gets 409, as it would a moment later, not
    500. The first request here is an insert held uncommitted on another connection."""
    body = {"id": "cell-1", "kind": "cross", "f_px": 800, "ax": 0.3, "ay": 0.2}
    first = {"id": "cell-1", "kind": "cross", "spec": {}, "created_at": datetime.now(UTC)}
    with engine.connect() as other, ThreadPoolExecutor(1) as pool:
        other.execute(insert(Rig).values(first))
        second = pool.submit(client.post, "/rigs", json=body, headers=admin)
        time.sleep(1.0)  # the second has looked, and waits for the first's row
        other.commit()
        r = second.result(timeout=60)
    assert r.status_code == 409, r.text
    assert r.headers["content-type"] == "application/problem+json"
    assert "already exists" in r.json()["detail"]
    assert [g["id"] for g in client.get("/rigs", headers=admin).json()] == ["cell-1"]


GOOD_K = [[800, 0, 320], [0, 800, 240], [0, 0, 1]]
EYE = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]


@pytest.mark.parametrize(
    ("camera", "fault"),
    [
        ({"K": [[-800, 0, 320], [0, -800, 240], [0, 0, 1]]}, "must both be positive"),
        ({"K": [[800, 0, 320], [0, -800, 240], [0, 0, 1]]}, "must both be positive"),
        ({"K": [[800, 0, 320], [0, 800, 240], [0, 0, 2]]}, "[0, 0, 1]"),
        ({"R": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}, "mirror"),
        ({"R": [[1, 0.1, 0], [0, 1, 0], [0, 0, 1]]}, "not a rotation"),
    ],
    ids=["negative focal lengths", "negative fy", "K[2,2] = 2", "mirror", "sheared"],
)
def test_a_rig_camera_that_is_no_camera_is_refused_by_name(
    client: TestClient, admin: dict[str, str], camera: dict[str, Any], fault: str
) -> None:
    """Such a rig was accepted and every point came back null "behind the camera" (with
    fy < 0 the outlier rejection took a square root of a negative number)."""
    cams = [
        {"K": GOOD_K, "R": EYE, "t": [0, 0, 0]},
        {"K": GOOD_K, "R": EYE, "t": [1, 0, 0], **camera},
    ]
    r = client.post(
        "/rigs", json={"id": "bad", "kind": "calibrated", "cameras": cams}, headers=admin
    )
    assert r.status_code == 422
    assert r.json()["detail"].startswith("body.cameras.1.")  # the second camera, by its index
    assert fault in r.json()["detail"]
    assert client.get("/rigs/bad", headers=admin).status_code == 404


def _projection(k: np.ndarray, r: np.ndarray, t: np.ndarray, scale: float) -> list[list[float]]:
    return (scale * k @ np.hstack([r, np.asarray(t)[:, None]])).tolist()


def test_cameras_given_as_projection_matrices(client: TestClient, admin: dict[str, str]) -> None:
    """Multi-view data sets publish P = λ K [R | t]: decomposed, the rig measures as with K, R,
    t; the answer shows the decomposition (skew kept, any positive λ)."""
    k = np.array([[800.0, 0.4, 320], [0, 790, 240], [0, 0, 1]])
    poses = [cv2.Rodrigues(np.radians([2.0, (i - 1.5) * 8, 1.0]))[0] for i in range(3)]
    ts = [-r @ np.array([(i - 1) * 0.3, 0.02 * i, 0.0]) for i, r in enumerate(poses)]
    cams = [
        {"P": _projection(k, r, t, scale)}
        for r, t, scale in zip(poses, ts, (1.0, 0.01, 37.5), strict=True)
    ]
    body = {"id": "multi", "kind": "calibrated", "cameras": cams}
    r = client.post("/rigs", json=body, headers=admin)
    assert r.status_code == 201, r.text
    shown = client.get("/rigs/multi", headers=admin).json()["spec"]["cameras"]
    for camera, rot, t in zip(shown, poses, ts, strict=True):
        np.testing.assert_allclose(camera["K"], k, atol=1e-9)
        np.testing.assert_allclose(camera["R"], rot, atol=1e-12)
        np.testing.assert_allclose(camera["t"], t, atol=1e-12)
        assert "P" not in camera
    views = [View(k, np.zeros(5), rot, t) for rot, t in zip(poses, ts, strict=True)]
    p = points(10) + [0, 0, 1.0]
    obs = project_views(views, p).tolist()
    out = client.post("/rigs/multi/triangulate", json={"observations": obs}, headers=admin)
    np.testing.assert_allclose(out.json()["points"], p, rtol=1e-7)


@pytest.mark.parametrize(
    ("camera", "fault"),
    [
        ({"P": _projection(np.diag([800.0, 800, 1]), np.eye(3), np.zeros(3), -1.0)}, "mirror"),
        (
            {"P": _projection(np.diag([800.0, 800, 1]), np.diag([1.0, -1, 1]), np.zeros(3), 1.0)},
            "mirror",
        ),
        ({"P": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]]}, "singular"),
        ({"P": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, "3 × 4"),
        ({"P": _projection(np.eye(3), np.eye(3), np.zeros(3), 1.0), "K": GOOD_K}, "not both"),
    ],
    ids=["negative-scale", "reflected", "singular", "not-3x4", "P-and-K"],
)
def test_a_projection_matrix_that_is_no_camera_is_refused(
    client: TestClient, admin: dict[str, str], camera: dict[str, Any], fault: str
) -> None:
    cams = [{"K": GOOD_K, "R": EYE, "t": [0, 0, 0]}, {"t": [1, 0, 0], **camera}]
    if "P" in camera:
        del cams[1]["t"]
    r = client.post(
        "/rigs", json={"id": "bad-p", "kind": "calibrated", "cameras": cams}, headers=admin
    )
    assert r.status_code == 422, r.text
    assert r.json()["detail"].startswith("body.cameras.1")
    assert fault in r.json()["detail"]
    assert client.get("/rigs/bad-p", headers=admin).status_code == 404


class TestPanTiltHeads:
    """Cameras on pan/tilt heads: declared with their pose at zero and the head's pivot; each
    request gives the angles. Observations are rendered from cameras moved by hand (the lens
    centre swung about the pivot), not through the service's own composition."""

    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    PIVOTS = [None, [0.3, 0.0, -0.05], [0.6, 0.1, -0.04]]
    ANGLES = [None, [12.0, -5.0], [-20.0, 8.0]]

    def zero_pose(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        r = cv2.Rodrigues(np.radians([0.0, (1 - i) * 10.0, 0.0]))[0]
        return r, -r @ np.array([0.3 * i, 0.0, 0.0])

    def moved(self, i: int) -> View:
        r0, t0 = self.zero_pose(i)
        pivot, angles = self.PIVOTS[i], self.ANGLES[i]
        if pivot is None or angles is None:
            return View(self.K, np.zeros(5), r0, t0)
        pan, tilt = np.radians(angles)
        ct, st, cp, sp = np.cos(pan), np.sin(pan), np.cos(tilt), np.sin(tilt)
        turn = np.array([[ct, st, 0], [-st * cp, ct * cp, sp], [st * sp, -ct * sp, cp]])
        centre = np.array(pivot) + turn.T @ (-r0.T @ t0 - np.array(pivot))
        r = r0 @ turn
        return View(self.K, np.zeros(5), r, -r @ centre)

    def register(self, client: TestClient, admin: dict[str, str]) -> None:
        cams = []
        for i, pivot in enumerate(self.PIVOTS):
            r0, t0 = self.zero_pose(i)
            cam: dict[str, Any] = {"K": self.K.tolist(), "R": r0.tolist(), "t": t0.tolist()}
            if pivot is not None:
                cam["head"] = {"pivot": pivot}
            cams.append(cam)
        body = {"id": "heads", "kind": "calibrated", "cameras": cams}
        assert client.post("/rigs", json=body, headers=admin).status_code == 201

    def test_triangulation_with_the_heads_turned(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        self.register(client, admin)
        views = [self.moved(i) for i in range(3)]
        p = points(20) + [0.3, 0, 1.2]
        obs = project_views(views, p).tolist()
        r = client.post(
            "/rigs/heads/triangulate",
            json={"observations": obs, "pan_tilt_deg": self.ANGLES},
            headers=admin,
        )
        assert r.status_code == 200, r.text
        np.testing.assert_allclose(r.json()["points"], p, rtol=1e-9)
        assert max(r.json()["reprojection_rms_px"]) < 1e-6
        # the same pixels with the heads taken as standing at zero: wrong by far
        zero = [None, [0.0, 0.0], [0.0, 0.0]]
        r = client.post(
            "/rigs/heads/triangulate",
            json={"observations": obs, "pan_tilt_deg": zero},
            headers=admin,
        )
        assert min(x or 1e9 for x in r.json()["reprojection_rms_px"]) > 5

    @pytest.mark.parametrize(
        ("angles", "fault"),
        [
            (None, "camera 1 is on a pan/tilt head"),
            ([None, [1, 2]], "2 entries for 3 cameras"),
            ([[1, 2], [1, 2], [1, 2]], "camera 0 is not on a pan/tilt head"),
            ([None, None, [1, 2]], "camera 1 is on a pan/tilt head"),
        ],
    )
    def test_angles_that_do_not_fit_the_heads(
        self, client: TestClient, admin: dict[str, str], angles: Any, fault: str
    ) -> None:
        self.register(client, admin)
        r = client.post(
            "/rigs/heads/triangulate",
            json={"observations": [[[320, 240]] * 3], "pan_tilt_deg": angles},
            headers=admin,
        )
        assert r.status_code == 422
        assert fault in r.json()["detail"]

    def test_the_laser_dot_with_the_heads_turned(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        self.register(client, admin)
        truth = np.array([0.32, -0.02, 1.1])
        uv = project_views([self.moved(i) for i in range(3)], truth[None])[0]
        y, x = np.mgrid[0:480, 0:640]
        rng = np.random.default_rng(4)
        files = []
        for i in range(3):
            image = np.full((480, 640, 3), 110.0) + rng.normal(0, 3, (480, 640, 3))
            g = np.exp(-((x - uv[i, 0]) ** 2 + (y - uv[i, 1]) ** 2) / (2 * 1.5**2))
            image[..., 0] += 145 * g
            image[..., 1:] -= 60 * g[..., None]
            png = cv2.imencode(".png", np.clip(image, 0, 255).astype(np.uint8)[:, :, ::-1])[1]
            files.append(("files", (f"{i}.png", png.tobytes(), "image/png")))
        r = client.post(
            "/rigs/heads/laser/dot",
            files=files,
            data={"pan_tilt_deg": json.dumps(self.ANGLES)},
            headers=admin,
        )
        assert r.status_code == 200, r.text
        assert np.linalg.norm(np.array(r.json()["point"]) - truth) < 0.001
        r = client.post("/rigs/heads/laser/dot", files=files, headers=admin)
        assert r.status_code == 422
        assert "pan/tilt head" in r.json()["detail"]
