"""Part outlines and conditioned images for robot cells (``app.cells.core.imaging``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from app.cells.core import imaging
from app.platform.frames.jpeg import JpegError, NotJpegError, TooManyPixelsError, decode_image
from app.platform.http.errors import Unprocessable, UnsupportedMediaType

Pipeline = Literal["stretch", "equalize", "shadow", "luma"]


def decode(data: bytes, *, max_pixels: int) -> NDArray[np.uint8]:
    if not data:
        raise Unprocessable("empty body: expected an image")
    try:
        return decode_image(data, max_pixels=max_pixels)
    except NotJpegError:
        raise UnsupportedMediaType(
            "the file is not a JPEG, PNG or TIFF image", code="not_image"
        ) from None
    except TooManyPixelsError as exc:
        raise Unprocessable(str(exc), code="too_many_pixels") from None
    except JpegError as exc:
        raise Unprocessable(str(exc), code="corrupt_image") from None


def _grey(
    image: NDArray[np.uint8], roi: tuple[int, int, int, int] | None
) -> tuple[NDArray[np.uint8], tuple[int, int]]:
    try:
        region, offset = imaging.crop(image, roi)
    except ValueError as exc:
        raise Unprocessable(str(exc), code="roi_outside_image") from None
    if min(region.shape[:2]) < 8:
        raise Unprocessable(
            f"image too small to outline: {region.shape[1]}×{region.shape[0]} (need ≥ 8×8)"
        )
    grey = imaging.luma(np.ascontiguousarray(region))
    if int(grey.max()) - int(grey.min()) < 2:
        raise Unprocessable(
            f"the image is uniform (levels {grey.min()}–{grey.max()}): nothing to outline"
        )
    return grey, offset


@dataclass(frozen=True, slots=True)
class OutlineResult:
    outline: imaging.Outline
    offset: tuple[int, int]
    grey: NDArray[np.uint8]


def find_outline(
    data: bytes,
    params: imaging.OutlineParams,
    *,
    roi: tuple[int, int, int, int] | None,
    max_pixels: int,
) -> OutlineResult:
    grey, offset = _grey(decode(data, max_pixels=max_pixels), roi)
    try:
        result = imaging.outline(grey, params)
    except ValueError as exc:  # OutlineNotFound among them: the reason, with its figures
        raise Unprocessable(f"no outline found: {exc}", code="outline_not_found") from None
    return OutlineResult(result, offset, grey)


def enhance(
    data: bytes,
    pipeline: list[Pipeline],
    *,
    roi: tuple[int, int, int, int] | None,
    alpha: float,
    theta: float | None,
    max_pixels: int,
) -> bytes:
    """The conditioned image as PNG: the steps applied in order to the luma."""
    grey, _ = _grey(decode(data, max_pixels=max_pixels), roi)
    out = grey
    for step in pipeline:
        if step == "stretch":
            out = imaging.stretch(out)
        elif step == "equalize":
            out = imaging.equalize(out)
        elif step == "shadow":
            out = imaging.suppress_shadow(out, alpha=alpha, theta=theta)[0]
    return png(out)


def png(image: NDArray[np.uint8]) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return bytes(buf.tobytes())


def debug_png(result: OutlineResult) -> bytes:
    """The conditioned image with edges (blue), sides (green), corners numbered (red)."""
    o = result.outline
    base = o.conditioned if o.conditioned is not None else result.grey
    canvas = cv2.cvtColor(base, cv2.COLOR_GRAY2BGR)
    if o.edges is not None:
        canvas[o.edges > 0] = (255, 120, 0)
    for x1, y1, x2, y2 in o.lines:
        cv2.line(canvas, (round(x1), round(y1)), (round(x2), round(y2)), (0, 200, 0), 2)
    for e in o.ellipses:
        box = (e.center, e.axes, e.angle)
        cv2.ellipse(canvas, box, (0, 200, 200), 2)
    for i, (x, y) in enumerate(o.corners, start=1):
        cv2.circle(canvas, (round(x), round(y)), 5, (0, 0, 255), 2)
        cv2.putText(
            canvas,
            str(i),
            (round(x) + 6, round(y) - 6),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.6,
            (0, 0, 255),
            2,
        )
    return png(np.asarray(canvas, dtype=np.uint8))
