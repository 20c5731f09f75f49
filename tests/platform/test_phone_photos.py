"""Photos as phones and cameras make them, made here: data after the image (a Samsung-style
trailer, a motion photo's video), a file cut mid-scan, every EXIF orientation, progressive
and CMYK JPEGs; each through the frame upload and the outline endpoint.

Pillow (here for its ``ImageOps.exif_transpose``) is the reference for what upright means."""

from __future__ import annotations

import io
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image, ImageOps

from app.platform.frames import jpeg
from tests.cells.scenes import PRISM_OUTLINE, prism_scene
from tests.factories import make_jpeg
from tests.factories.cells import corner_error

TRAILER = b"SEFH" + bytes(range(60)) + b"\xff\xd9SEFT"  # a trailer that even holds FF D9
VIDEO = b"\x00\x00\x00\x18ftypmp42" + np.random.default_rng(3).bytes(40_000)  # a motion photo
INVERSE = {
    1: None,
    2: Image.Transpose.FLIP_LEFT_RIGHT,
    3: Image.Transpose.ROTATE_180,
    4: Image.Transpose.FLIP_TOP_BOTTOM,
    5: Image.Transpose.TRANSPOSE,
    6: Image.Transpose.ROTATE_90,  # stored turned back: the viewer turns it 90° clockwise
    7: Image.Transpose.TRANSVERSE,
    8: Image.Transpose.ROTATE_270,
}
"""For each EXIF orientation, how an upright picture is stored so that it reads upright."""


def marked(width: int = 96, height: int = 64) -> np.ndarray:
    """An RGB picture whose every turn and mirror differs: a red block at the top left, a
    blue one at the top right, on grey."""
    image = np.full((height, width, 3), 128, np.uint8)
    image[4:20, 4:28] = (230, 20, 20)
    image[4:20, width - 20 : width - 4] = (20, 20, 230)
    return image


def with_orientation(upright: np.ndarray, orientation: int, **save: Any) -> bytes:
    """``upright`` stored as a camera held otherwise stores it, with its EXIF orientation."""
    picture = Image.fromarray(upright)
    if INVERSE[orientation] is not None:
        picture = picture.transpose(INVERSE[orientation])
    exif = Image.Exif()
    exif[0x0112] = orientation
    out = io.BytesIO()
    picture.save(out, format="JPEG", quality=95, exif=exif.tobytes(), **save)
    data = out.getvalue()
    reference = np.asarray(ImageOps.exif_transpose(Image.open(io.BytesIO(data))))
    assert reference.shape == upright.shape  # the case reads upright to Pillow too
    return data


def near(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and float(np.abs(a.astype(int) - b.astype(int)).mean()) < 4


class TestDecode:
    def test_data_after_the_image_is_not_the_image(self) -> None:
        data = make_jpeg(64, 48, noise=20)
        end = jpeg.image_end(data)
        assert end == len(data)
        for tail in (TRAILER, VIDEO, b"\x00" * 16):
            header, image = jpeg.decode_rgb(data + tail, max_pixels=10**6)
            assert jpeg.image_end(data + tail) == end
            assert np.array_equal(image, jpeg.decode_rgb(data, max_pixels=10**6)[1])

    @pytest.mark.parametrize("progressive", [False, True])
    def test_cut_mid_scan_is_refused(self, progressive: bool) -> None:
        image = np.random.default_rng(1).integers(0, 255, (240, 320, 3), np.uint8)
        flags = [cv2.IMWRITE_JPEG_QUALITY, 90, cv2.IMWRITE_JPEG_PROGRESSIVE, int(progressive)]
        data = cv2.imencode(".jpg", image, flags)[1].tobytes()
        assert jpeg.read_header(data).progressive is progressive
        for cut in (len(data) // 2, len(data) - 3):
            with pytest.raises(jpeg.CorruptJpegError, match="truncated"):
                jpeg.decode_rgb(data[:cut], max_pixels=10**6)
            # a cut upload padded with zeros is still cut
            with pytest.raises(jpeg.CorruptJpegError, match="truncated"):
                jpeg.decode_rgb(data[:cut] + bytes(64), max_pixels=10**6)
        assert jpeg.decode_rgb(data, max_pixels=10**6)[1].shape == (240, 320, 3)

    @pytest.mark.parametrize("orientation", range(1, 9))
    def test_every_orientation_decodes_upright(self, orientation: int) -> None:
        upright = marked()
        data = with_orientation(upright, orientation)
        for reduce in (1, 2):
            header, image = jpeg.decode_rgb(data, max_pixels=10**6, reduce=reduce)
            assert (header.width, header.height) == (96, 64)
            assert header.orientation == orientation
            expected = cv2.resize(
                upright, (96 // reduce, 64 // reduce), interpolation=cv2.INTER_AREA
            )
            assert near(image, expected), (orientation, reduce)

    def test_cmyk_decodes_to_rgb(self) -> None:
        out = io.BytesIO()
        Image.fromarray(marked()).convert("CMYK").save(out, format="JPEG", quality=95)
        header, image = jpeg.decode_rgb(out.getvalue(), max_pixels=10**6)
        assert header.components == 4
        assert image.shape == (64, 96, 3)
        reference = np.asarray(Image.open(io.BytesIO(out.getvalue())).convert("RGB"))
        assert near(image, reference)


@pytest.fixture
def rig(client: TestClient, admin: dict[str, str]) -> dict[str, str]:
    r = client.post("/cameras", json={"id": "phone", "kind": "rig"}, headers=admin)
    return {"Authorization": f"Bearer {r.json()['token']}", "Content-Type": "image/jpeg"}


def upload(client: TestClient, headers: dict[str, str], data: bytes) -> Any:
    return client.post("/cameras/phone/frames", content=data, headers=headers)


class TestFrameUpload:
    def test_kinds_of_file(
        self, client: TestClient, admin: dict[str, str], rig: dict[str, str]
    ) -> None:
        base = make_jpeg(96, 64, noise=10)
        progressive = cv2.imencode(
            ".jpg", cv2.cvtColor(marked(), cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]
        )[1].tobytes()
        cmyk = io.BytesIO()
        Image.fromarray(marked()).convert("CMYK").save(cmyk, format="JPEG")
        for name, data in (
            ("trailer", base + TRAILER),
            ("video", base + VIDEO),
            ("progressive", progressive),
            ("cmyk", cmyk.getvalue()),
        ):
            r = upload(client, rig, data)
            assert r.status_code == 201, (name, r.text)
            frame = client.get(f"/frames/{r.json()['frame_id']}", headers=admin).json()
            assert (frame["width"], frame["height"]) == (96, 64), name
            stored = client.get(f"/frames/{r.json()['frame_id']}/image.jpg", headers=admin)
            if stored.status_code == 200:  # the bytes as received: hashes hold
                assert stored.content == data, name
        # the same bytes again are the same frame (idempotent by content)
        again = upload(client, rig, base + TRAILER)
        assert again.status_code in (200, 201)

    def test_cut_mid_scan_is_refused_and_nothing_stored(
        self, client: TestClient, admin: dict[str, str], rig: dict[str, str]
    ) -> None:
        data = make_jpeg(320, 240, noise=40)
        r = upload(client, rig, data[: len(data) // 2])
        assert r.status_code == 422
        assert r.headers["content-type"] == "application/problem+json"
        assert "truncated" in r.json()["detail"]
        assert r.json()["code"] == "corrupt_jpeg"
        assert client.get("/cameras/phone/frames", headers=admin).json() == []

    @pytest.mark.parametrize("orientation", [1, 3, 6, 8])
    def test_orientation_sizes_and_regions_are_upright(
        self, client: TestClient, admin: dict[str, str], rig: dict[str, str], orientation: int
    ) -> None:
        """The frame is 96×64 upright whatever its storage; a region given in the upright
        picture's pixels (the red block) is where its statistics come from."""
        client.patch("/cameras/phone", json={"roi": [4, 4, 24, 16]}, headers=admin)
        r = upload(client, rig, with_orientation(marked(), orientation))
        assert r.status_code == 201, r.text
        frame = client.get(f"/frames/{r.json()['frame_id']}", headers=admin).json()
        assert (frame["width"], frame["height"]) == (96, 64)
        modes = r.json()["verdict"]["modes"]
        assert modes[0] > 180, (orientation, modes)  # red: the upright picture's top left
        assert modes[2] < 60, (orientation, modes)
        region = client.get(f"/frames/{r.json()['frame_id']}/region.jpg", headers=admin)
        shown = cv2.cvtColor(
            cv2.imdecode(np.frombuffer(region.content, np.uint8), 1), cv2.COLOR_BGR2RGB
        )
        assert shown.shape == (64, 96, 3)
        assert shown[10, 10, 0] > 150  # the red block at the top left of what is shown

    def test_a_region_is_checked_against_the_upright_size(
        self, client: TestClient, admin: dict[str, str], rig: dict[str, str]
    ) -> None:
        """A 96×64 landscape picture stored as 64×96 portrait with orientation 6: a region 90
        wide fits, as it does in the picture a person sees; one 90 high does not."""
        client.patch("/cameras/phone", json={"roi": [0, 0, 90, 60]}, headers=admin)
        assert upload(client, rig, with_orientation(marked(), 6)).status_code == 201
        # and a region of the stored (portrait) shape is refused against the upright one
        changed = client.patch("/cameras/phone", json={"roi": [0, 0, 60, 90]}, headers=admin)
        assert changed.status_code == 422
        assert "96×64 frame" in changed.json()["detail"]


class TestOutline:
    @pytest.mark.parametrize("orientation", range(1, 9))
    def test_corners_are_in_the_upright_image(
        self, client: TestClient, admin: dict[str, str], orientation: int
    ) -> None:
        scene = cv2.cvtColor(prism_scene(), cv2.COLOR_GRAY2RGB)
        data = with_orientation(scene, orientation) + TRAILER
        r = client.post("/vision/outline", files={"file": ("p.jpg", data)}, headers=admin)
        assert r.status_code == 200, r.text
        assert corner_error(np.array(r.json()["corners"]), PRISM_OUTLINE) <= 2.0

    @pytest.mark.parametrize("kind", ["trailer", "video", "progressive", "cmyk"])
    def test_kinds_of_file(self, client: TestClient, admin: dict[str, str], kind: str) -> None:
        scene = prism_scene()
        if kind == "cmyk":
            out = io.BytesIO()
            Image.fromarray(scene).convert("CMYK").save(out, format="JPEG", quality=95)
            data = out.getvalue()
        else:
            flags = [cv2.IMWRITE_JPEG_QUALITY, 95, cv2.IMWRITE_JPEG_PROGRESSIVE, 1]
            plain = cv2.imencode(".jpg", scene, flags if kind == "progressive" else flags[:2])
            data = plain[1].tobytes() + {"trailer": TRAILER, "video": VIDEO}.get(kind, b"")
        r = client.post("/vision/outline", files={"file": ("p.jpg", data)}, headers=admin)
        assert r.status_code == 200, (kind, r.text)
        assert corner_error(np.array(r.json()["corners"]), PRISM_OUTLINE) <= 2.0

    def test_a_cut_photo_is_refused(self, client: TestClient, admin: dict[str, str]) -> None:
        data = cv2.imencode(".jpg", prism_scene())[1].tobytes()
        r = client.post(
            "/vision/outline", files={"file": ("p.jpg", data[: len(data) // 2])}, headers=admin
        )
        assert r.status_code == 422
        assert "truncated" in r.json()["detail"]


def phone_photo(width: int = 8000, height: int = 6000) -> bytes:
    """A 48 MP photo as a phone stores it: sensor-sized, turned by EXIF, a trailer after."""
    small = np.random.default_rng(5).integers(0, 255, (height // 50, width // 50, 3), np.uint8)
    picture = Image.fromarray(cv2.resize(small, (width, height), interpolation=cv2.INTER_LINEAR))
    exif = Image.Exif()
    exif[0x0112] = 6
    out = io.BytesIO()
    picture.save(out, format="JPEG", quality=85, exif=exif.tobytes())
    return out.getvalue() + TRAILER


def test_a_48_mp_phone_photo_is_taken_reduced(
    client: TestClient, admin: dict[str, str], rig: dict[str, str]
) -> None:
    """Stored 8000×6000 with orientation 6: a 6000×8000 upright frame, its statistics from a
    decode at 1/2 (12 MP), within the pixel limit."""
    r = upload(client, rig, phone_photo())
    assert r.status_code == 201, r.text
    frame = client.get(f"/frames/{r.json()['frame_id']}", headers=admin).json()
    assert (frame["width"], frame["height"]) == (6000, 8000)


def test_a_48_mp_photo_decodes_within_its_memory_budget() -> None:
    """Its measuring (the ingest's analysis) allocates a 12 MP RGB image's worth twice (the
    decode and its upright turn, 72 MB) and little more, not the 144 MB of one full-size
    decode."""
    from app.platform.frames.kinds import STATISTICS_PIXELS
    from tests.memory import traced_peak

    peak, size = traced_peak(
        """
        from app.main import register_kinds
        from app.platform.frames import ingest
        from app.platform.frames.camera_info import CameraInfo
        from app.platform.db.models import CameraKind
        from tests.platform.test_phone_photos import phone_photo
        register_kinds()
        data = phone_photo()
        camera = CameraInfo("phone", CameraKind.rig, None, None, False, None)
        """,
        """
        decoded = ingest.analyse(data, camera=camera, max_pixels=50_000_000)
        result = [decoded.header.width, decoded.header.height, decoded.reduction]
        """,
    )
    assert size == [6000, 8000, 2]
    assert peak < 2.1 * STATISTICS_PIXELS * 3, peak


def test_a_calibration_from_photos_held_in_portrait(
    client: TestClient, admin: dict[str, str]
) -> None:
    """Boards rendered through K_RENDER, each stored turned with its EXIF orientation (6 and
    8 alternately): the corners are found in the upright pictures, so the calibration gives
    back that K, its principal point where the upright image has it."""
    from tests.factories.cells import K_RENDER, rendered_views, upload

    views = []
    for i, data in enumerate(rendered_views(5)):
        upright = cv2.cvtColor(cv2.imdecode(np.frombuffer(data, np.uint8), 1), cv2.COLOR_BGR2RGB)
        views.append((f"v{i}.jpg", with_orientation(upright, 6 if i % 2 else 8)))
    status, c = upload(client, admin, views)
    assert status == 201, c
    np.testing.assert_allclose(c["K"], K_RENDER, rtol=0.002, atol=0.5)
    assert c["rms_px"] < 0.2
