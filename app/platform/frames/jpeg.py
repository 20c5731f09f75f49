"""JPEG header inspection and guarded decoding.

The header is read before anything is decoded, so a small file that declares an enormous image
(a decompression bomb) is refused for the price of reading a few hundred bytes.
"""

from __future__ import annotations

import os
import re
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
    """[px], of the upright image: the EXIF orientation applied (as decoded here)."""
    height: int
    """[px], likewise."""
    components: int
    """1 (greyscale), 3 (colour) or 4 (CMYK, as some cameras and editors write)."""
    progressive: bool
    orientation: int = 1
    """EXIF orientation (1–8; 1 when absent or unreadable): how the stored pixels turn to
    the upright image. 5–8 swap width and height."""

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
    orientation = 1
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
            if components not in (1, 3, 4):
                raise CorruptJpegError(
                    f"JPEG has {components} colour components; expected 1, 3 or 4"
                )
            if orientation >= 5:  # a quarter turn: the upright image is height × width
                width, height = height, width
            progressive = marker in (0xC2, 0xC6)
            return JpegHeader(width, height, components, progressive, orientation)
        if marker == 0xE1 and orientation == 1:  # APP1: EXIF comes before the frame header
            orientation = exif_orientation(bytes(buf[i + 2 : i + length]))
        i += length


def exif_orientation(app1: bytes) -> int:
    """The Orientation tag (0x0112) of an APP1 segment's EXIF IFD0, 1–8; 1 when the segment is
    not EXIF, has no such tag, or says something outside 1–8 (EXIF 2.32 §4.6.4, TIFF 6.0)."""
    if not app1.startswith(b"Exif\x00\x00") or len(app1) < 14:
        return 1
    tiff = app1[6:]
    if tiff[:4] == b"II*\x00":
        order: Literal["little", "big"] = "little"
    elif tiff[:4] == b"MM\x00*":
        order = "big"
    else:
        return 1
    ifd = int.from_bytes(tiff[4:8], order)
    if ifd + 2 > len(tiff):
        return 1
    for k in range(int.from_bytes(tiff[ifd : ifd + 2], order)):
        entry = tiff[ifd + 2 + 12 * k : ifd + 14 + 12 * k]
        if len(entry) < 12:
            return 1
        if int.from_bytes(entry[0:2], order) == 0x0112:
            value = int.from_bytes(entry[8:10], order)  # SHORT, left-justified
            return value if 1 <= value <= 8 else 1
    return 1


# in entropy-coded data a marker is FF followed by neither 00 (a stuffed FF) nor D0–D7 (restart
# markers, which sit inside the data); of fill bytes (FF FF … D9) the last FF matches. Without
# a leading "+" the search runs at C speed (32 µs for a 640×480 frame; 540 µs with it)
_NEXT_MARKER = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")


def image_end(data: bytes | memoryview) -> int:
    """The offset just past the image's end-of-image marker, found by walking the file's
    segments and scans (ITU T.81 §B.2); bytes after it (a phone's trailer, a motion photo's
    video) are not the image's. Raises CorruptJpegError when the data end first: a file cut
    short, or scan data that stop before the image is complete.

    libjpeg decodes a truncated file into a grey-padded image with only a warning, so the
    end is found from the structure, not from the file's last bytes."""
    raw = bytes(data)
    n = len(raw)
    i = 2
    while i < n:
        if raw[i] != 0xFF:
            raise CorruptJpegError(f"broken JPEG marker chain at byte {i}")
        while i < n and raw[i] == 0xFF:
            i += 1
        if i >= n:
            break
        marker = raw[i]
        i += 1
        if marker == 0xD9:
            return i
        if marker in _STANDALONE:
            continue
        if i + 2 > n:
            break
        length = (raw[i] << 8) | raw[i + 1]
        if length < 2 or i + length > n:
            break
        i += length
        if marker == 0xDA:  # a scan: its entropy-coded data run to the next marker
            found = _NEXT_MARKER.search(raw, i)
            if found is None:
                break
            i = found.start()
    raise CorruptJpegError(
        "JPEG is truncated: its data end before the end-of-image marker (a cut-off upload)"
    )


def upright(image: NDArray[np.uint8], orientation: int) -> NDArray[np.uint8]:
    """The stored pixels (H, W, C) turned to the upright image by their EXIF orientation
    (1: as stored; 2 mirrored; 3 turned 180°; 4 flipped; 5 transposed; 6 turned 90°
    clockwise; 7 transversed; 8 turned 90° anticlockwise), as a viewer shows the photo."""
    if orientation == 2:
        out = image[:, ::-1]
    elif orientation == 3:
        out = image[::-1, ::-1]
    elif orientation == 4:
        out = image[::-1]
    elif orientation == 5:
        out = image.transpose(1, 0, 2)
    elif orientation == 6:
        out = image.transpose(1, 0, 2)[:, ::-1]
    elif orientation == 7:
        out = image.transpose(1, 0, 2)[::-1, ::-1]
    elif orientation == 8:
        out = image.transpose(1, 0, 2)[::-1]
    else:
        return image
    return np.ascontiguousarray(out)


def decode_rgb(
    data: bytes | memoryview, *, max_pixels: int, reduce: int = 1
) -> tuple[JpegHeader, NDArray[np.uint8]]:
    """Check the header, then decode to an RGB array of shape (H, W, 3), uint8.

    Parameters
    ----------
    data : JPEG bytes.
    max_pixels : refuse images that declare more pixels than this [px].
    reduce : 1, 2, 4 or 8; decode at 1/reduce of the size through libjpeg's DCT scaling.

    The image is returned upright (its EXIF orientation applied, ``upright``), and the header
    gives the upright size: every pixel coordinate the service answers is in that image. Data
    after the end-of-image marker are ignored; a file that ends before it is refused.
    """
    header = read_header(data)
    if header.pixels > max_pixels:
        raise TooManyPixelsError(
            f"JPEG declares {header.width}×{header.height} = {header.pixels} pixels; "
            f"the limit is {max_pixels}"
        )
    image_end(data)
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
        image = np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2RGB), dtype=np.uint8)
    return header, upright(np.asarray(image, dtype=np.uint8), header.orientation)


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
