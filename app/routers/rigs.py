"""Measuring rigs: register, then triangulate image observations into 3-D points."""

from __future__ import annotations

import math
from functools import partial

import numpy as np
from fastapi import APIRouter, Request
from sqlalchemy.orm import Session

from app.core import laser_grid, shapes
from app.core.triangulation import CrossRig, View, triangulate_cross, triangulate_views
from app.db.base import utcnow
from app.db.models import Rig
from app.deps import Admin, RigId, RobotOrAdmin, SessionDep, SettingsDep, image_work
from app.errors import Conflict, NotFound, Unprocessable, UnsupportedMediaType
from app.routers.responses import (
    AUTH_ERRORS,
    BODY_ERRORS,
    CONFLICT,
    NOT_FOUND,
    UNPROCESSABLE,
    multipart_body,
)
from app.schemas import (
    LaserDotOut,
    LaserGridOut,
    RigCreate,
    RigOut,
    ShapeFitOut,
    ShapeMatchIn,
    TriangulateIn,
    TriangulateOut,
)
from app.services import calibrations, grid
from app.settings import Settings
from app.uploads import Form, content_type, read_form

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
    if session.get(Rig, body.id) is not None:
        raise Conflict(f"a rig with id {body.id!r} already exists")
    if body.kind == "cross":
        if body.cameras is not None or body.calibration_id is not None:
            raise Unprocessable("a cross rig takes f_px, ax, ay and principal_point")
        if body.f_px is None or body.ax is None or body.ay is None:
            raise Unprocessable("a cross rig needs f_px, ax and ay")
        cx, cy = body.principal_point or [0.0, 0.0]
        spec: dict[str, object] = {
            "f_px": body.f_px,
            "ax": body.ax,
            "ay": body.ay,
            "principal_point": [cx, cy],
            "image_size": body.image_size,
        }
    elif body.image_size is not None:
        raise Unprocessable("a calibrated rig gives image_size per camera (cameras[i].image_size)")
    elif body.calibration_id is not None:
        if body.cameras is not None:
            raise Unprocessable("give the cameras or a calibration_id, not both")
        cameras = calibrations.stereo_cameras(session, body.calibration_id)
        spec = {"cameras": cameras, "calibration_id": body.calibration_id}
    else:
        if not body.cameras or len(body.cameras) < 2:
            raise Unprocessable(
                "a calibrated rig needs at least 2 cameras, or the calibration_id of a stereo pair"
            )
        for i, c in enumerate(body.cameras):
            r = np.array(c.R)
            if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
                raise Unprocessable(f"camera {i}: R is not a rotation")
            if np.linalg.det(np.array(c.K)) == 0:
                raise Unprocessable(f"camera {i}: K is singular")
        spec = {"cameras": [c.model_dump() for c in body.cameras]}
    row = Rig(id=body.id, kind=body.kind, spec=spec, created_at=utcnow())
    session.add(row)
    session.flush()
    return RigOut.model_validate(row)


@router.get("/{rig_id}", response_model=RigOut, responses={**AUTH_ERRORS, **NOT_FOUND})
def get_rig(rig_id: RigId, session: SessionDep, _: RobotOrAdmin) -> RigOut:
    """One rig."""
    row = session.get(Rig, rig_id)
    if row is None:
        raise NotFound(f"no rig {rig_id!r}")
    return RigOut.model_validate(row)


def _cross(row: Rig) -> CrossRig:
    s = row.spec
    return CrossRig(
        f=s["f_px"], ax=s["ax"], ay=s["ay"], cx=s["principal_point"][0], cy=s["principal_point"][1]
    )


def _views(row: Rig) -> list[View]:
    return [
        View(np.array(c["K"]), np.array(c["dist"]), np.array(c["R"]), np.array(c["t"]))
        for c in row.spec["cameras"]
    ]


def _sizes(row: Rig) -> list[tuple[int, int] | None]:
    """Per camera, the image size its K was calibrated for, when known."""
    if row.kind == "cross":
        size = row.spec.get("image_size")  # none on rigs registered before it was asked
        return [(int(size[0]), int(size[1])) if size else None] * 4
    return [
        (int(c["image_size"][0]), int(c["image_size"][1])) if c.get("image_size") else None
        for c in row.spec["cameras"]
    ]


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
    """Points in the rig's frame from pixel observations (null for a camera that did not see
    the point), with per-point reprojection RMS; for the cross, the ten pairwise depths."""
    row = session.get(Rig, rig_id)
    if row is None:
        raise NotFound(f"no rig {rig_id!r}")
    n_cams = 4 if row.kind == "cross" else len(row.spec["cameras"])
    obs = np.full((len(body.observations), n_cams, 2), np.nan)
    for i, point in enumerate(body.observations):
        if len(point) != n_cams:
            raise Unprocessable(f"point {i}: {len(point)} observations for {n_cams} cameras")
        for k, uv in enumerate(point):
            if uv is not None:
                if len(uv) != 2:
                    raise Unprocessable(f"point {i}, camera {k}: expected [u, v]")
                obs[i, k] = uv
    if len(obs) == 0:
        return TriangulateOut(points=[], reprojection_rms_px=[])
    if row.kind == "cross":
        rig = _cross(row)
        few = np.isfinite(obs).all(axis=-1).sum(axis=1) < 2
        safe = np.where(few[:, None, None], rig.project(np.array([[0.0, 0.0, 1.0]]))[0], obs)
        with np.errstate(all="ignore"):
            r = triangulate_cross(rig, safe, method=body.method)
        points = r.points.copy()
        points[few] = np.nan
        est = r.z_estimates.copy()
        est[few] = np.nan
        return TriangulateOut(
            points=[None if not np.isfinite(p).all() else p.tolist() for p in points],
            reprojection_rms_px=_clean(np.where(few, np.nan, r.reprojection_rms)),
            z_estimates=[_clean(e) for e in est],
            z_spread=_clean(np.where(few, np.nan, r.z_spread)),
        )
    views = _views(row)
    res = triangulate_views(views, obs)
    return TriangulateOut(
        points=[None if not np.isfinite(p).all() else p.tolist() for p in res.points],
        reprojection_rms_px=_clean(res.reprojection_rms),
    )


def _geometry(row: Rig) -> laser_grid.Geometry:
    if row.kind == "cross":
        return laser_grid.cross_geometry(_cross(row))
    return laser_grid.views_geometry(_views(row))


async def _rig_and_form(
    rig_id: str, request: Request, session: Session, settings: Settings, *parts: str
) -> tuple[Rig, Form]:
    """The rig, and the images (and fields: ``parts``) of a multipart upload to it."""
    row = session.get(Rig, rig_id)
    if row is None:
        raise NotFound(f"no rig {rig_id!r}")
    if content_type(request) != "multipart/form-data":
        raise UnsupportedMediaType("send the images as multipart/form-data (files)")
    form = await read_form(request, settings.max_upload_bytes, max_files=64, parts=parts)
    return row, form


def _dot(row: Rig, files: list[tuple[str | None, bytes]], max_pixels: int) -> LaserDotOut:
    dot = grid.locate_dot(_geometry(row), files, max_pixels, _sizes(row))
    return LaserDotOut(
        point=dot.point.tolist(),
        pixels=[list(p) if p is not None else None for p in dot.pixels],
        reprojection_rms_px=dot.reprojection_rms,
    )


@router.post(
    "/{rig_id}/laser/dot",
    response_model=LaserDotOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra=multipart_body(files="files"),
)
async def laser_dot(
    rig_id: RigId, request: Request, session: SessionDep, settings: SettingsDep, _: RobotOrAdmin
) -> LaserDotOut:
    """Locate the laser dot: one image per camera (multipart ``files``, in camera order); the
    dot's 3-D point and its pixel in each view; 422 naming the cameras that miss it."""
    row, form = await _rig_and_form(rig_id, request, session, settings, "files")
    return await image_work(
        request, partial(_dot, row, form.files_of("files"), settings.max_pixels)
    )


@router.post(
    "/{rig_id}/laser/grid",
    response_model=LaserGridOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra=multipart_body(
        files="files", dot_files="files", origin="text", base_plane="text"
    ),
)
async def laser_grid_measure(
    rig_id: RigId, request: Request, session: SessionDep, settings: SettingsDep, _: RobotOrAdmin
) -> LaserGridOut:
    """Measure a part under the laser grid: one grid image per camera (``files``, in camera
    order) → every node in 3-D, surface area, volume and the base plane. The dot gives the
    grid's origin: its images (``dot_files``) or its pixels (``origin``, JSON, per camera
    [u, v] or null, e.g. from ``/laser/dot``). ``base_plane`` (JSON [a, b, c, d]) is fitted to
    the support surface when not given."""
    row, form = await _rig_and_form(
        rig_id, request, session, settings, "files", "dot_files", "origin", "base_plane"
    )
    return await image_work(
        request,
        partial(
            grid.measure,
            _geometry(row),
            form.files_of("files"),
            dot_files=form.files_of("dot_files"),
            origin=form.fields.get("origin", []),
            base_plane=form.fields.get("base_plane", []),
            max_pixels=settings.max_pixels,
            sizes=_sizes(row),
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
