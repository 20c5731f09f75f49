"""JPEG header reading and guarded decoding."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.platform.frames.jpeg import (
    CorruptJpegError,
    NotJpegError,
    TooManyPixelsError,
    decode_rgb,
    image_end,
    read_header,
)
from tests.factories import make_jpeg


@pytest.mark.parametrize(("width", "height"), [(1, 1), (640, 480), (1920, 1080), (17, 3)])
def test_header_dimensions_match_the_encoder(width: int, height: int) -> None:
    header = read_header(make_jpeg(width, height))
    assert (header.width, header.height, header.components) == (width, height, 3)
    assert not header.progressive


def test_progressive_and_greyscale_headers() -> None:
    grey = np.full((30, 40), 128, np.uint8)
    ok, buf = cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])
    assert ok
    header = read_header(buf.tobytes())
    assert (header.width, header.height, header.components, header.progressive) == (40, 30, 1, True)
    _, image = decode_rgb(buf.tobytes(), max_pixels=10_000)
    assert image.shape == (30, 40, 3)  # greyscale comes back as three equal channels


def test_decode_returns_rgb_order() -> None:
    _, image = decode_rgb(make_jpeg(32, 32, (250, 10, 10), quality=100), max_pixels=10_000)
    assert image[16, 16, 0] > 240
    assert image[16, 16, 2] < 20


@pytest.mark.parametrize("reduce", [2, 4, 8])
def test_reduced_decode_keeps_rgb_and_scales(reduce: int) -> None:
    _, image = decode_rgb(
        make_jpeg(64, 48, (250, 10, 10), quality=100), max_pixels=10_000, reduce=reduce
    )
    assert image.shape == (48 // reduce, 64 // reduce, 3)
    assert image[0, 0, 0] > 240


def test_pixel_limit_checked_before_decoding() -> None:
    data = bytearray(make_jpeg(1, 1))
    sof = data.index(b"\xff\xc0")
    data[sof + 5 : sof + 9] = (60000).to_bytes(2, "big") * 2
    with pytest.raises(TooManyPixelsError, match="60000×60000"):
        decode_rgb(bytes(data), max_pixels=40_000_000)


@pytest.mark.parametrize(
    ("data", "error"),
    [
        (b"", NotJpegError),
        (b"\x89PNG\r\n\x1a\n" + b"\0" * 20, NotJpegError),
        (b"\xff\xd8\xff\xda\x00\x02", CorruptJpegError),  # scan before any frame header
        (b"\xff\xd8\xff\xe0\xff\xff", CorruptJpegError),  # segment runs past the end
        (b"\xff\xd8\x00\x00\x00\x00", CorruptJpegError),  # no marker after SOI
    ],
)
def test_broken_headers(data: bytes, error: type[Exception]) -> None:
    with pytest.raises(error):
        read_header(data)


def test_truncation_is_detected() -> None:
    data = make_jpeg(320, 240, noise=40)
    assert image_end(data) == len(data)
    assert image_end(data + b"\0" * 16) == len(data)  # zero padding after EOI is allowed
    for cut in (len(data) // 3, len(data) - 1):
        with pytest.raises(CorruptJpegError, match="truncated"):
            image_end(data[:cut])
        with pytest.raises(CorruptJpegError, match="truncated"):
            decode_rgb(data[:cut], max_pixels=10**6)


def test_bit_flipped_scan_does_not_crash() -> None:
    rng = np.random.default_rng(7)
    data = bytearray(make_jpeg(64, 64, noise=30))
    for _ in range(200):
        mutated = bytearray(data)
        for i in rng.integers(2, len(mutated) - 2, size=8):
            mutated[i] ^= 1 << int(rng.integers(0, 8))
        try:
            _, image = decode_rgb(bytes(mutated), max_pixels=10**6)
        except (CorruptJpegError, NotJpegError, TooManyPixelsError):
            continue
        assert image.dtype == np.uint8
        assert image.ndim == 3
