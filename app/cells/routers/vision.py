"""Part outlines and image conditioning for robot cells."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Annotated, Literal

import numpy as np
from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import Response

from app.cells.core.imaging import CannyParams, OutlineParams
from app.cells.schemas import EllipseOut, OutlineOut
from app.cells.services import vision
from app.platform.http.deps import RobotOrAdmin, SettingsDep, image_work
from app.platform.http.errors import Unprocessable
from app.platform.http.responses import AUTH_ERRORS, UNPROCESSABLE, UPLOAD_ERRORS, multipart_body
from app.platform.http.uploads import read_files
from app.platform.settings import Settings

router = APIRouter(prefix="/vision", tags=["vision"])

_FILE_BODY = multipart_body(file="file")

RoiQuery = Annotated[
    str | None,
    Query(
        pattern=r"^\d{1,6},\d{1,6},\d{1,6},\d{1,6}$",
        description="x,y,w,h [px], each below 10⁶; results stay in full-image pixels.",
    ),
]
Shadow = Annotated[
    bool, Query(description="Equalise → shift → equalise before the edges (chapter 3 §IV).")
]
Alpha = Annotated[float, Query(gt=0, le=10, description="α of the shift (eq. 3.1).")]
Theta = Annotated[
    float | None, Query(ge=-255, le=255, description="θ of the shift; default: automatic.")
]
Sigma = Annotated[float, Query(gt=0, le=10, description="Canny's Gaussian σ [px].")]
High = Annotated[
    float | None,
    Query(
        gt=0,
        le=1,
        description="Canny high threshold, 0–1 of the largest gradient (the "
        "dissertation: 0.5); omit for automatic (Otsu on the gradient magnitudes).",
    ),
]


def _roi(value: str | None) -> tuple[int, int, int, int] | None:
    if value is None:
        return None
    x, y, w, h = (int(v) for v in value.split(","))
    if w == 0 or h == 0:
        raise Unprocessable("roi needs w, h ≥ 1")
    return (x, y, w, h)


@dataclass(frozen=True, slots=True)
class OutlineQuery:
    params: OutlineParams
    roi: tuple[int, int, int, int] | None


Part = Annotated[
    Literal["auto", "dark", "light"],
    Query(
        description="The part darker than its background (the dissertation's cells), lighter "
        "(a machined part on a black belt), or auto: the background is what runs along the "
        "image's (or ROI's) edges."
    ),
]


def outline_query(
    roi: RoiQuery = None,
    part: Part = "auto",
    shadow: Shadow = True,
    alpha: Alpha = 1.0,
    theta: Theta = None,
    sigma: Sigma = 1.5,
    canny_high: High = None,
    dissertation: Annotated[
        bool, Query(description="The dissertation's Canny threshold (0.5) instead of automatic.")
    ] = False,
) -> OutlineQuery:
    canny = CannyParams(sigma=sigma, high=0.5 if dissertation else canny_high)
    params = OutlineParams(shadow=shadow, alpha=alpha, theta=theta, canny=canny, part=part)
    return OutlineQuery(params, _roi(roi))


OutlineQueryDep = Annotated[OutlineQuery, Depends(outline_query)]


async def _find(request: Request, settings: Settings, q: OutlineQuery) -> vision.OutlineResult:
    [(_filename, data)] = await read_files(request, "file", settings.max_body_bytes)
    return await image_work(
        request,
        partial(vision.find_outline, data, q.params, roi=q.roi, max_pixels=settings.max_pixels),
    )


@router.post(
    "/outline",
    response_model=OutlineOut,
    responses={**AUTH_ERRORS, **UPLOAD_ERRORS, **UNPROCESSABLE},
    openapi_extra=_FILE_BODY,
)
async def outline(
    request: Request, settings: SettingsDep, q: OutlineQueryDep, _: RobotOrAdmin
) -> OutlineOut:
    """The outline of the part in one image (multipart ``file``): corners counter-clockwise and
    sides, or for curved parts the contour and fitted ellipses, with how well the shape fits
    the part's edges. 422 ``outline_not_found`` (with the reason) when no polygon nor curved
    shape is supported by the edges: a smooth gradient, a textured surface, a part whose
    edges the image does not show."""
    result = await _find(request, settings, q)
    o, (dx, dy) = result.outline, result.offset
    shift = np.array([dx, dy], dtype=np.float64)
    return OutlineOut(
        shape=o.shape,
        corners=(o.corners + shift).tolist(),
        lines=[[x1 + dx, y1 + dy, x2 + dx, y2 + dy] for x1, y1, x2, y2 in o.lines],
        contour=(o.contour + shift).tolist(),
        ellipses=[
            EllipseOut(
                center=[e.center[0] + dx, e.center[1] + dy], axes=list(e.axes), angle=e.angle
            )
            for e in o.ellipses
        ],
        roi_offset=[dx, dy],
        canny_thresholds=list(o.canny_thresholds),
        shadow_theta=o.shadow_theta,
        part=o.part,
        residual_px=o.residual,
        edge_support=o.support,
    )


@router.post(
    "/outline.png",
    response_class=Response,
    responses={200: {"content": {"image/png": {}}}, **AUTH_ERRORS, **UPLOAD_ERRORS},
    openapi_extra=_FILE_BODY,
)
async def outline_png(
    request: Request, settings: SettingsDep, q: OutlineQueryDep, _: RobotOrAdmin
) -> Response:
    """The outline drawn for debugging: edges, sides, numbered corners (of the ROI)."""
    result = await _find(request, settings, q)
    return Response(await image_work(request, vision.debug_png, result), media_type="image/png")


@router.post(
    "/enhance",
    response_class=Response,
    responses={200: {"content": {"image/png": {}}}, **AUTH_ERRORS, **UPLOAD_ERRORS},
    openapi_extra=_FILE_BODY,
)
async def enhance(
    request: Request,
    settings: SettingsDep,
    _: RobotOrAdmin,
    pipeline: Annotated[
        list[Literal["stretch", "equalize", "shadow"]],
        Query(
            description="Steps in order, on the luma: stretch (4.1), equalize (4.3), shadow "
            "(equalise → shift 3.1 → equalise)."
        ),
    ] = ["stretch"],  # noqa: B006
    roi: RoiQuery = None,
    alpha: Alpha = 1.0,
    theta: Theta = None,
) -> Response:
    """The conditioned image (PNG) of one image (multipart ``file``)."""
    [(_filename, data)] = await read_files(request, "file", settings.max_body_bytes)
    body = await image_work(
        request,
        partial(
            vision.enhance,
            data,
            list(pipeline),
            roi=_roi(roi),
            alpha=alpha,
            theta=theta,
            max_pixels=settings.max_pixels,
        ),
    )
    return Response(body, media_type="image/png")
