"""Measuring rigs: register, then triangulate image observations into 3-D points."""

from __future__ import annotations

import math
from functools import partial
from typing import Annotated

import numpy as np
from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from sqlalchemy.orm import Session

from app.cells.core import laser, shapes
from app.cells.models import Rig
from app.cells.schemas import (
    LaserDotOut,
    LaserGridOut,
    RigCreate,
    RigOut,
    RigReplace,
    ShapeFitOut,
    ShapeMatchIn,
    TriangulateIn,
    TriangulateOut,
)
from app.cells.services import grid, rigs
from app.platform.db.session import release
from app.platform.http.deps import (
    Admin,
    AnyReader,
    Limit,
    Offset,
    RigId,
    RobotOrAdmin,
    SessionDep,
    SettingsDep,
    image_work,
)
from app.platform.http.errors import Unprocessable, UnsupportedMediaType
from app.platform.http.responses import (
    AUTH_ERRORS,
    BODY_ERRORS,
    CONFLICT,
    NOT_FOUND,
    UNPROCESSABLE,
    multipart_body,
)
from app.platform.http.uploads import Form, content_type, read_form
from app.platform.settings import Settings

router = APIRouter(prefix="/rigs", tags=["stereo"])


@router.post(
    "",
    status_code=201,
    response_model=RigOut,
    responses={**AUTH_ERRORS, **CONFLICT, **UNPROCESSABLE},
)
def create_rig(body: RigCreate, session: SessionDep, _: Admin) -> RigOut:
    """Register a 4-camera cross (f_px, ax, ay, principal_point), or 2+ calibrated cameras
    (``cameras``, or the ``calibration_id`` of a stereo calibration)."""
    return RigOut.model_validate(rigs.create(session, body.id, body))


@router.get("", response_model=list[RigOut], responses=AUTH_ERRORS)
def list_rigs(
    session: SessionDep, _: AnyReader, limit: Limit = 100, offset: Offset = 0
) -> list[RigOut]:
    """Rigs, ordered by id."""
    return [RigOut.model_validate(r) for r in rigs.listed(session, limit=limit, offset=offset)]


@router.get("/{rig_id}", response_model=RigOut, responses={**AUTH_ERRORS, **NOT_FOUND})
def get_rig(rig_id: RigId, session: SessionDep, _: AnyReader) -> RigOut:
    """One rig."""
    return RigOut.model_validate(rigs.get(session, rig_id))


@router.put(
    "/{rig_id}",
    response_model=RigOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **UNPROCESSABLE},
)
def replace_rig(rig_id: RigId, body: RigReplace, session: SessionDep, _: Admin) -> RigOut:
    """Give a rig new geometry (its cameras moved, or were calibrated again), the same fields
    as when it was registered (the id may be left out): every measurement from now on uses it,
    on every server process (``updated_at`` says when)."""
    if body.id is not None and body.id != rig_id:
        raise Unprocessable(f"the body names rig {body.id!r}, the path {rig_id!r}")
    return RigOut.model_validate(rigs.replace(session, rig_id, body))


@router.delete(
    "/{rig_id}", status_code=204, response_class=Response, responses={**AUTH_ERRORS, **NOT_FOUND}
)
def delete_rig(rig_id: RigId, session: SessionDep, _: Admin) -> Response:
    """Remove a rig; its id can be registered again."""
    rigs.delete(session, rig_id)
    return Response(status_code=204)


def _clean(values: np.ndarray) -> list[float | None]:
    return [None if not math.isfinite(float(v)) else float(v) for v in values]


@router.post(
    "/{rig_id}/triangulate",
    response_model=TriangulateOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **UNPROCESSABLE},
)
def triangulate(
    rig_id: RigId, body: TriangulateIn, session: SessionDep, _: RobotOrAdmin
) -> TriangulateOut:
    """Points in the rig's frame (or, ``frame=robot``, the robot's base [m], for a rig carrying
    a hand-eye calibration) from pixel observations (null for a camera that did not see the
    point), with per-point reprojection RMS; for the cross, the ten pairwise depths."""
    row = rigs.get(session, rig_id)
    n_cams = rigs.cameras(row)
    obs = np.full((len(body.observations), n_cams, 2), np.nan)
    for i, point in enumerate(body.observations):
        if len(point) != n_cams:
            raise Unprocessable(f"point {i}: {len(point)} observations for {n_cams} cameras")
        for k, uv in enumerate(point):
            if uv is not None:
                if len(uv) != 2:
                    raise Unprocessable(f"point {i}, camera {k}: expected [u, v]")
                obs[i, k] = uv
    out = rigs.triangulate(row, obs, body.method, body.pan_tilt_deg)
    points = rigs.in_base(row, out.points) if body.frame == "robot" else out.points
    return TriangulateOut(
        frame=body.frame,
        points=[None if not np.isfinite(p).all() else p.tolist() for p in points],
        reprojection_rms_px=_clean(out.reprojection_rms),
        null_reasons=out.reasons,
        z_estimates=None if out.z_estimates is None else [_clean(e) for e in out.z_estimates],
        z_spread=None if out.z_spread is None else _clean(out.z_spread),
    )


async def _rig_and_form(
    rig_id: str, request: Request, session: Session, settings: Settings, *parts: str
) -> tuple[Rig, Form]:
    """The rig, and the images (and fields: ``parts``) of a multipart upload to it. The
    session is released before the upload is read and measured, which may take seconds."""
    row = await run_in_threadpool(_rig_released, session, rig_id)
    if content_type(request) != "multipart/form-data":
        raise UnsupportedMediaType("send the images as multipart/form-data (files)")
    form = await read_form(request, settings.max_upload_bytes, max_files=64, parts=parts)
    return row, form


def _rig_released(session: Session, rig_id: str) -> Rig:
    try:
        return rigs.get(session, rig_id)
    finally:
        release(session)


LaserQuery = Annotated[
    laser.Colour,
    Query(
        alias="laser",
        description="The laser's colour: red (the dissertation's), green (532 nm) or blue. "
        "The dot and the grid are told from the scene by that channel's excess over the "
        "other two.",
    ),
]


def _dot(
    row: Rig,
    files: list[tuple[str | None, bytes]],
    max_pixels: int,
    colour: laser.Colour,
    pan_tilt: list[str],
) -> LaserDotOut:
    geometry = rigs.geometry_of(row, grid.pan_tilt_field(pan_tilt))
    dot = grid.locate_dot(geometry, files, max_pixels, rigs.sizes_of(row), colour)
    return LaserDotOut(
        point=dot.point.tolist(),
        pixels=[list(p) if p is not None else None for p in dot.pixels],
        reprojection_rms_px=dot.reprojection_rms,
    )


@router.post(
    "/{rig_id}/laser/dot",
    response_model=LaserDotOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra=multipart_body(files="files", pan_tilt_deg="text"),
)
async def laser_dot(
    rig_id: RigId,
    request: Request,
    session: SessionDep,
    settings: SettingsDep,
    _: RobotOrAdmin,
    colour: LaserQuery = "red",
) -> LaserDotOut:
    """Locate the laser dot: one image per camera (multipart ``files``, in camera order); the
    dot's 3-D point and its pixel in each view; 422 naming the cameras that miss it. Cameras on
    pan/tilt heads: ``pan_tilt_deg`` (JSON, per camera [pan, tilt] or null)."""
    row, form = await _rig_and_form(rig_id, request, session, settings, "files", "pan_tilt_deg")
    return await image_work(
        request,
        partial(
            _dot,
            row,
            form.files_of("files"),
            settings.max_pixels,
            colour,
            form.fields.get("pan_tilt_deg", []),
        ),
    )


@router.post(
    "/{rig_id}/laser/grid",
    response_model=LaserGridOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra=multipart_body(
        files="files", dot_files="files", origin="text", base_plane="text", pan_tilt_deg="text"
    ),
)
async def laser_grid_measure(
    rig_id: RigId,
    request: Request,
    session: SessionDep,
    settings: SettingsDep,
    _: RobotOrAdmin,
    colour: LaserQuery = "red",
) -> LaserGridOut:
    """Measure a part under the laser grid: one grid image per camera (``files``, in camera
    order) → every node in 3-D, surface area, volume and the base plane. The dot gives the
    grid's origin: its images (``dot_files``) or its pixels (``origin``, JSON, per camera
    [u, v] or null, e.g. from ``/laser/dot``). ``base_plane`` (JSON [a, b, c, d]) is fitted to
    the support surface when not given. Cameras on pan/tilt heads: ``pan_tilt_deg`` (JSON,
    per camera [pan, tilt] or null)."""
    row, form = await _rig_and_form(
        rig_id,
        request,
        session,
        settings,
        "files",
        "dot_files",
        "origin",
        "base_plane",
        "pan_tilt_deg",
    )
    geometry = rigs.geometry_of(row, grid.pan_tilt_field(form.fields.get("pan_tilt_deg", [])))
    return await image_work(
        request,
        partial(
            grid.measure,
            geometry,
            form.files_of("files"),
            dot_files=form.files_of("dot_files"),
            origin=form.fields.get("origin", []),
            base_plane=form.fields.get("base_plane", []),
            max_pixels=settings.max_pixels,
            sizes=rigs.sizes_of(row),
            colour=colour,
        ),
    )


shapes_router = APIRouter(prefix="/shapes", tags=["stereo"])


@shapes_router.post(
    "/match", response_model=list[ShapeFitOut], responses={**AUTH_ERRORS, **UNPROCESSABLE}
)
def match_shape(body: ShapeMatchIn, _: RobotOrAdmin) -> list[ShapeFitOut]:
    """Fit the library of regular parts (box, triangular prism, cylinder) to located points:
    shape, dimensions, pose and residual, best first."""
    if any(len(p) != 3 for p in body.points):
        raise Unprocessable("every point must be [X, Y, Z]")
    try:
        fits = shapes.match(np.array(body.points))
    except ValueError as exc:
        raise Unprocessable(str(exc)) from None
    return [
        ShapeFitOut(
            shape=f.shape,
            dimensions=f.dimensions,
            centre=f.centre.tolist(),
            axes=f.axes.tolist(),
            rms=f.rms,
            hidden_corners=f.hidden,
        )
        for f in fits
    ]
