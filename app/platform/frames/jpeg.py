"""JPEG header inspection and guarded decoding.

The header is read before anything is decoded, so a small file that declares an enormous image
(a decompression bomb) is refused for the price of reading a few hundred bytes.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

SOI = b"\xff\xd8"
EOI = b"\xff\xd9"
# start-of-frame markers carry the dimensions; C4 (DHT), C8 (JPG) and CC (DAC) do not
_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
# markers without a length field
_STANDALONE = frozenset(range(0xD0, 0xD8)) | {0x01, 0xD8}


class JpegError(ValueError):
    """The bytes are not a usable JPEG."""


class NotJpegError(JpegError):
    """The bytes do not start like a JPEG at all (wrong format)."""


class CorruptJpegError(JpegError):
    """The bytes start like a JPEG but are truncated or undecodable."""


class TooManyPixelsError(JpegError):
    """The header declares more pixels than allowed."""


@dataclass(frozen=True, slots=True)
class JpegHeader:
    width: int
    """[px]"""
    height: int
    """[px]"""
    components: int
    """1 (greyscale) or 3 (colour)."""
    progressive: bool

    @property
    def pixels(self) -> int:
        return self.width * self.height


def read_header(data: bytes | memoryview) -> JpegHeader:
    """Read the dimensions from the first start-of-frame segment, without decoding.

    Raises
    ------
    NotJpegError
        ``data`` does not begin with the SOI marker.
    CorruptJpegError
        The marker chain is broken or ends before a start-of-frame segment.
    """
    buf = memoryview(data)
    n = len(buf)
    if n < 4 or bytes(buf[:2]) != SOI:
        raise NotJpegError("not a JPEG: the data does not start with the SOI marker FF D8")
    i = 2
    while True:
        # skip to the next marker, allowing fill bytes (FF FF ...)
        if i >= n or buf[i] != 0xFF:
            raise CorruptJpegError(f"broken JPEG marker chain at byte {i}")
        while i < n and buf[i] == 0xFF:
            i += 1
        if i >= n:
            raise CorruptJpegError("JPEG ends inside a marker")
        marker = buf[i]
        i += 1
        if marker in _STANDALONE:
            continue
        if marker == 0xD9 or marker == 0xDA:
            raise CorruptJpegError("JPEG has no start-of-frame segment before its scan data")
        if i + 2 > n:
            raise CorruptJpegError("JPEG ends inside a segment length")
        length = (buf[i] << 8) | buf[i + 1]
        if length < 2 or i + length > n:
            raise CorruptJpegError(f"JPEG segment FF{marker:02X} runs past the end of the data")
        if marker in _SOF_MARKERS:
            if length < 8:
                raise CorruptJpegError("JPEG start-of-frame segment is too short")
            height = (buf[i + 3] << 8) | buf[i + 4]
            width = (buf[i + 5] << 8) | buf[i + 6]
            components = buf[i + 7]
            if width == 0 or height == 0:
                raise CorruptJpegError(f"JPEG declares an empty image ({width}×{height})")
            if components not in (1, 3):
                raise CorruptJpegError(f"JPEG has {components} colour components; expected 1 or 3")
            return JpegHeader(width, height, components, progressive=marker in (0xC2, 0xC6))
        i += length


def has_end_marker(data: bytes | memoryview) -> bool:
    """Whether the data ends with EOI (trailing zero padding allowed): a cut-off upload does not.

    libjpeg decodes a truncated file into a grey-padded image with only a warning, so truncation
    has to be detected from the bytes themselves.
    """
    tail = bytes(data[-4096:]).rstrip(b"\x00")
    return tail.endswith(EOI)


def decode_rgb(
    data: bytes | memoryview, *, max_pixels: int, reduce: int = 1
) -> tuple[JpegHeader, NDArray[np.uint8]]:
    """Check the header, then decode to an RGB array of shape (H, W, 3), uint8.

    Parameters
    ----------
    data : JPEG bytes.
    max_pixels : refuse images that declare more pixels than this [px].
    reduce : 1, 2, 4 or 8; decode at 1/reduce of the size through libjpeg's DCT scaling.
    """
    header = read_header(data)
    if header.pixels > max_pixels:
        raise TooManyPixelsError(
            f"JPEG declares {header.width}×{header.height} = {header.pixels} pixels; "
            f"the limit is {max_pixels}"
        )
    if not has_end_marker(data):
        raise CorruptJpegError("JPEG is truncated: no end-of-image marker")
    flags = {
        1: cv2.IMREAD_COLOR_RGB,
        2: cv2.IMREAD_REDUCED_COLOR_2,
        4: cv2.IMREAD_REDUCED_COLOR_4,
        8: cv2.IMREAD_REDUCED_COLOR_8,
    }
    if reduce not in flags:
        raise ValueError(f"reduce must be 1, 2, 4 or 8; got {reduce}")
    arr = np.frombuffer(data, dtype=np.uint8)
    image = _imdecode(arr, flags[reduce] | cv2.IMREAD_IGNORE_ORIENTATION, "JPEG")
    if image is None or image.ndim != 3 or image.shape[2] != 3:
        raise CorruptJpegError("JPEG could not be decoded")
    if reduce != 1:  # the reduced modes have no RGB variant
        return header, np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2RGB), dtype=np.uint8)
    return header, np.asarray(image, dtype=np.uint8)


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


TIFF_SIGNATURES = (b"II*\x00", b"MM\x00*")
"""A TIFF's first bytes: little- or big-endian (Bouguet's toolbox ships its boards as TIFF)."""


def tiff_size(data: bytes | memoryview) -> tuple[int, int]:
    """(width, height) [px] from a TIFF's first image directory (tags 256 and 257), read
    before decoding so that the pixel limit holds. Raises CorruptJpegError when absent.

    TIFF 6.0 (§2) requires a directory's entries in ascending tag order, each tag once. A file
    that repeats or reorders them is refused: readers disagree on which copy counts (libtiff
    decodes by the first ImageWidth, a reader taking the last would see another size), and
    the limit must hold for the size the decoder uses."""
    raw = bytes(data)
    order: Literal["little", "big"] = "little" if raw[:2] == b"II" else "big"
    found: dict[int, int] = {}
    try:
        ifd = int.from_bytes(raw[4:8], order)
        count = int.from_bytes(raw[ifd : ifd + 2], order)
        previous = -1
        for k in range(count):
            entry = raw[ifd + 2 + 12 * k : ifd + 14 + 12 * k]
            if len(entry) < 12:
                raise CorruptJpegError("TIFF directory runs past the end of the data")
            tag, kind = int.from_bytes(entry[0:2], order), int.from_bytes(entry[2:4], order)
            if tag <= previous:
                raise CorruptJpegError(
                    f"TIFF directory repeats or reorders its tags (tag {tag} after {previous});"
                    " TIFF 6.0 requires each tag once, in ascending order"
                )
            previous = tag
            if tag in (256, 257):  # ImageWidth, ImageLength: SHORT (3) or LONG (4)
                size = 2 if kind == 3 else 4
                found[tag] = int.from_bytes(entry[8 : 8 + size], order)
    except (IndexError, ValueError) as exc:
        if isinstance(exc, CorruptJpegError):
            raise
        found = {}
    if 256 not in found or 257 not in found:
        raise CorruptJpegError("TIFF without its image width and length")
    return found[256], found[257]


DECODER_CAP_VARIABLE = "OPENCV_IO_MAX_IMAGE_PIXELS"
"""OpenCV's own limit on the pixels it decodes, read once when OpenCV loads; ``app`` sets it
from ``VANTAGE_MAX_PIXELS`` before anything imports cv2."""


def decoder_cap() -> int:
    """OpenCV's pixel cap [px] in this process: no image of more pixels is decoded, whatever
    its format and however its header was read here (the second line behind the header checks).
    """
    try:
        return int(os.environ.get(DECODER_CAP_VARIABLE, str(1 << 30)))
    except ValueError:
        return 1 << 30


def _imdecode(buf: NDArray[np.uint8], flags: int, kind: str) -> NDArray[np.uint8] | None:
    """``cv2.imdecode``; OpenCV's pixel cap (``decoder_cap``) reported as TooManyPixelsError."""
    try:
        image = cv2.imdecode(buf, flags)
    except cv2.error as exc:
        if "CV_IO_MAX_IMAGE_PIXELS" in str(exc):
            raise TooManyPixelsError(
                f"{kind} declares more pixels than the limit of {decoder_cap()}"
            ) from None
        raise CorruptJpegError(f"{kind} could not be decoded") from None
    return None if image is None else np.asarray(image, dtype=np.uint8)


def _check_pixels(kind: str, width: int, height: int, max_pixels: int) -> None:
    if width * height > max_pixels:
        raise TooManyPixelsError(
            f"{kind} declares {width}×{height} = {width * height} pixels; the limit is {max_pixels}"
        )


def decode_image(data: bytes | memoryview, *, max_pixels: int) -> NDArray[np.uint8]:
    """A JPEG, PNG or TIFF decoded to RGB (H, W, 3), uint8, its size checked from the header
    first.

    Raises NotJpegError for any other format, TooManyPixelsError, CorruptJpegError.
    """
    raw = bytes(data[:32])
    if raw.startswith(SOI):
        return decode_rgb(data, max_pixels=max_pixels)[1]
    if raw.startswith(PNG_SIGNATURE):
        if len(raw) < 24 or raw[12:16] != b"IHDR":
            raise CorruptJpegError("PNG without its IHDR header")
        width, height = int.from_bytes(raw[16:20], "big"), int.from_bytes(raw[20:24], "big")
        _check_pixels("PNG", width, height, max_pixels)
        kind = "PNG"
    elif raw.startswith(TIFF_SIGNATURES):
        _check_pixels("TIFF", *tiff_size(data), max_pixels)
        kind = "TIFF"
    else:
        raise NotJpegError("not a JPEG, PNG or TIFF image")
    image = _imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR_RGB, kind)
    if image is None:
        raise CorruptJpegError(f"{kind} could not be decoded")
    return np.asarray(image, dtype=np.uint8)
