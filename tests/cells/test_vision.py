"""Outlines and conditioned images over HTTP."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.cells.services import vision as vision_service
from app.main import create_app
from tests.cells.scenes import PRISM_OUTLINE, cylinder_scene, light_prism_scene, prism_scene
from tests.factories import ADMIN_TOKEN, SHARED_DATA, empty_tables
from tests.factories.cells import corner_error


def encode(image: np.ndarray, ext: str = ".png") -> bytes:
    ok, buf = cv2.imencode(ext, image, [cv2.IMWRITE_JPEG_QUALITY, 100] if ext == ".jpg" else [])
    assert ok
    return buf.tobytes()


def post(client: TestClient, path: str, data: bytes, headers: dict[str, str], **params: object):  # type: ignore[no-untyped-def]
    return client.post(
        path,
        files={"file": ("f", data, "application/octet-stream")},
        headers=headers,
        params=params,
    )


class TestOutline:
    def test_prism_corners(self, client: TestClient, admin: dict[str, str]) -> None:
        r = post(client, "/vision/outline", encode(prism_scene()), admin)
        assert r.status_code == 200, r.text
        out = r.json()
        assert out["shape"] == "polygon"
        assert corner_error(np.array(out["corners"]), PRISM_OUTLINE) <= 2.0
        assert len(out["lines"]) == 6
        assert out["shadow_theta"] is not None

    def test_jpeg_and_roi_keep_full_image_coordinates(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        data = encode(cv2.cvtColor(prism_scene(), cv2.COLOR_GRAY2BGR), ".jpg")
        r = post(client, "/vision/outline", data, admin, roi="150,60,450,380")
        assert r.status_code == 200, r.text
        out = r.json()
        assert out["roi_offset"] == [150, 60]
        assert corner_error(np.array(out["corners"]), PRISM_OUTLINE) <= 2.0

    def test_a_light_part_on_a_dark_table(self, client: TestClient, admin: dict[str, str]) -> None:
        data = encode(light_prism_scene())
        out = post(client, "/vision/outline", data, admin).json()
        assert out["part"] == "light"
        assert corner_error(np.array(out["corners"]), PRISM_OUTLINE) <= 2.0
        told_dark = post(client, "/vision/outline", data, admin, part="dark")
        assert told_dark.status_code == 422
        assert told_dark.json()["code"] == "outline_not_found"
        assert (
            post(client, "/vision/outline", encode(prism_scene()), admin).json()["part"] == "dark"
        )
        assert post(client, "/vision/outline", data, admin, part="grey").status_code == 422

    def test_a_gradient_is_no_outline(self, client: TestClient, admin: dict[str, str]) -> None:
        ramp = np.tile(np.linspace(0, 255, 320), (240, 1)).astype(np.uint8)
        r = post(client, "/vision/outline", encode(ramp), admin)
        assert r.status_code == 422
        assert r.headers["content-type"] == "application/problem+json"
        assert r.json()["code"] == "outline_not_found"
        assert "no part stands out" in r.json()["detail"]

    def test_the_answer_says_how_well_it_fits(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        out = post(client, "/vision/outline", encode(prism_scene()), admin).json()
        assert 0 < out["residual_px"] < 0.5
        assert 0.9 < out["edge_support"] <= 1.0

    def test_cylinder_is_curved(self, client: TestClient, admin: dict[str, str]) -> None:
        out = post(client, "/vision/outline", encode(cylinder_scene()), admin).json()
        assert out["shape"] == "curved"
        assert out["corners"] == []
        assert len(out["ellipses"]) == 2

    def test_dissertation_parameters(self, client: TestClient, admin: dict[str, str]) -> None:
        r = post(client, "/vision/outline", encode(prism_scene()), admin, dissertation=True)
        assert r.status_code == 200
        low, high = r.json()["canny_thresholds"]
        assert low == pytest.approx(0.4 * high)

    def test_debug_png(self, client: TestClient, admin: dict[str, str]) -> None:
        r = post(client, "/vision/outline.png", encode(prism_scene()), admin)
        assert r.status_code == 200
        assert r.headers["content-type"] == "image/png"
        image = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
        assert image.shape == (480, 640, 3)
        assert (image[..., 2] > 200).any()  # red corners drawn


class TestEnhance:
    def test_stretch_spans_the_range(self, client: TestClient, admin: dict[str, str]) -> None:
        r = post(client, "/vision/enhance", encode(prism_scene()), admin, pipeline="stretch")
        assert r.status_code == 200
        image = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_GRAYSCALE)
        assert (image.min(), image.max()) == (0, 255)

    def test_shadow_pipeline_whitens_the_shadow(
        self, client: TestClient, admin: dict[str, str]
    ) -> None:
        r = client.post(
            "/vision/enhance?pipeline=stretch&pipeline=shadow",
            files={"file": ("f", encode(prism_scene()), "image/png")},
            headers=admin,
        )
        image = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_GRAYSCALE)
        assert image[300, 500] == 255  # in the shadow
        assert image[250, 260] < 128  # on the part


class TestBadInput:
    @pytest.mark.parametrize(
        ("data", "status"),
        [
            (b"hello, not an image", 415),
            (b"", 422),
            (encode(np.zeros((1, 1), np.uint8)), 422),
            (encode(np.zeros((64, 64), np.uint8)), 422),
        ],
        ids=["text", "empty", "one-pixel", "all-black"],
    )
    def test_refused(
        self, client: TestClient, admin: dict[str, str], data: bytes, status: int
    ) -> None:
        r = post(client, "/vision/outline", data, admin)
        assert r.status_code == status, r.text
        assert r.headers["content-type"] == "application/problem+json"

    def test_roi_outside(self, client: TestClient, admin: dict[str, str]) -> None:
        r = post(client, "/vision/outline", encode(prism_scene()), admin, roi="600,400,100,100")
        assert r.status_code == 422
        assert "does not lie inside" in r.json()["detail"]

    def test_png_bomb(self, client: TestClient, admin: dict[str, str]) -> None:
        data = bytearray(encode(np.zeros((8, 8), np.uint8)))
        data[16:24] = (60000).to_bytes(4, "big") * 2
        r = post(client, "/vision/outline", bytes(data), admin)
        assert r.status_code == 422
        assert "pixels" in r.json()["detail"]

    def test_needs_a_token(self, client: TestClient) -> None:
        assert post(client, "/vision/outline", encode(prism_scene()), {}).status_code == 401


PARTS = SHARED_DATA / "parts"


@pytest.mark.skipif(not PARTS.exists(), reason="shared data absent")
class TestRealParts:
    """The three real photos of ``../shared/data/parts`` with their hand-checked corners
    (``corners.json``: the crossings of the fitted sides, to about 2 px)."""

    def _truth(self, name: str) -> np.ndarray:
        import json

        return np.array(json.loads((PARTS / "corners.json").read_text())[name]["corners"])

    def test_the_pcb_on_grey_within_2_px(self, client: TestClient, admin: dict[str, str]) -> None:
        r = post(client, "/vision/outline", (PARTS / "pcb_plate_grey.jpg").read_bytes(), admin)
        assert r.status_code == 200, r.text
        found = np.array(r.json()["corners"])
        truth = self._truth("pcb_plate_grey.jpg")
        assert len(found) == len(truth) == 4
        # the truth runs clockwise on screen, the answer counter-clockwise: nearest to each
        nearest = np.linalg.norm(found[None, :, :] - truth[:, None, :], axis=2).min(axis=1)
        assert nearest.max() <= 2.0

    @pytest.mark.parametrize("name", ["box_doorway_carpet.jpg", "parcel_blue_carpet.jpg"])
    @pytest.mark.parametrize("part", ["auto", "dark", "light"])
    def test_parts_on_carpet_are_refused_in_one_voice(
        self, client: TestClient, admin: dict[str, str], name: str, part: str
    ) -> None:
        """No outline on carpet yet: a 422 that says what was looked for, as what, and what
        to try, the shade named alike throughout."""
        data = (PARTS / name).read_bytes()
        r = post(client, "/vision/outline", data, admin, part=part)
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        assert r.json()["code"] == "outline_not_found"
        looked = "lighter" if "looked for as lighter" in detail else "darker"
        assert f"is {looked} than its surroundings (the part was looked for as {looked}" in detail
        other = {"lighter": "dark", "darker": "light"}[looked]
        assert f"try part={other}" in detail
        if part != "auto":
            assert f"as asked (part={part})" in detail


@pytest.mark.parametrize("threads", [1, 3])
def test_image_work_runs_at_most_image_threads_at_once(
    settings: Any, engine: Any, monkeypatch: pytest.MonkeyPatch, threads: int
) -> None:
    # each outline holds its image's pixels: ``image_threads`` bounds how many at once (the
    # others wait their turn), where FastAPI's pool would run 40
    active, peak, lock = [0], [0], threading.Lock()
    real = vision_service.find_outline

    def tracked(*args: Any, **kwargs: Any) -> Any:
        with lock:
            active[0] += 1
            peak[0] = max(peak[0], active[0])
        time.sleep(0.2)  # long enough for the other requests to arrive meanwhile
        try:
            return real(*args, **kwargs)
        finally:
            with lock:
                active[0] -= 1

    monkeypatch.setattr(vision_service, "find_outline", tracked)
    empty_tables(engine)
    app = create_app(settings.model_copy(update={"image_threads": threads}))
    image = encode(prism_scene())
    admin = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
    with TestClient(app) as client, ThreadPoolExecutor(6) as pool:
        statuses = list(
            pool.map(lambda _: post(client, "/vision/outline", image, admin).status_code, range(6))
        )
    assert statuses == [200] * 6
    assert peak[0] == threads  # never more, and the requests did overlap
