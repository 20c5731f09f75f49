"""Air-quality calibration (admin): make, list, release, re-grade."""

from __future__ import annotations

from functools import partial
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response
from pydantic import StringConstraints

from app.air.core import breakpoints
from app.air.schemas import (
    AirCalibrationFromFrames,
    AirCalibrationOut,
    AirRegradeOut,
)
from app.air.services import calibration, cameras, grading, references, stations
from app.platform.http.deps import (
    ID_PATTERN,
    Admin,
    CameraId,
    IdFilter,
    Limit,
    Offset,
    SessionDep,
    SettingsDep,
    Shrinkage,
    Significance,
    TimingDep,
    UtcTime,
    image_work,
)
from app.platform.http.errors import (
    NotFound,
)
from app.platform.http.responses import (
    AUTH_ERRORS,
    BODY_ERRORS,
    NOT_FOUND,
    UNPROCESSABLE,
    multipart_body,
)
from app.platform.http.uploads import images_or_frames
from app.platform.state import app_state

router = APIRouter(prefix="/air", tags=["air quality"])


UploadsCamera = Annotated[
    str | None,
    Query(
        description="The sky camera whose region (ROI) the uploads are measured in: they "
        "are its full frames. Default: the region of the cameras in applies_to when they "
        "all have the same one, else the whole image (a warning names the cameras graded "
        "that measure another region)."
    ),
]
AppliesTo = Annotated[
    list[Annotated[str, StringConstraints(pattern=ID_PATTERN)]] | None,
    Query(
        max_length=10_000,
        description="Sky cameras this calibration grades from now on (repeat the "
        "parameter). Without it, it is the city-wide calibration of every camera that has "
        "none of its own: calibrate a camera from its own labelled frames where its view "
        "or white balance differs from the rest.",
    ),
]
Method = Annotated[
    Literal["clusters", "regression"] | None,
    Query(
        description="Grade by the T² level clusters (the dissertation, eqs. 6.19–6.22) or "
        "by a ridge regression on richer sky features. Default: for reference values (pm25, "
        "aqi) the one with the smaller category error on days left out (both scores kept in "
        "selection); for levels, the clusters."
    ),
]
BreakpointsTable = Annotated[
    breakpoints.Table | None,
    Query(
        alias="breakpoints",
        description="The table that makes reference pm25 values levels: the US EPA AQI "
        "breakpoints (2024) or the European Air Quality Index's PM2.5 bands (EEA, 2017), "
        "finer between 5 and 50 µg/m³ and narrower in its categories. PM2.5 only. "
        "Default: the European index when the cameras it grades (applies_to; else every "
        "sky camera) all stand in Europe, else the EPA's.",
    ),
]


From = Annotated[
    Literal["stations"] | None,
    Query(
        alias="from",
        description="stations: no body; each camera of applies_to is calibrated from its "
        "stored frames paired with the readings of the reference stations within "
        "max_distance_km (within 30 minutes of each frame; of several stations, the "
        "inverse-distance-weighted mean).",
    ),
]
MaxDistanceKm = Annotated[
    float,
    Query(gt=0, le=1000, description="from=stations: stations this far from a camera [km]."),
]


def _calibration_out(row: Any) -> AirCalibrationOut:
    return AirCalibrationOut.model_validate(row)


@router.post(
    "/calibration",
    status_code=201,
    response_model=AirCalibrationOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra=multipart_body(
        json=AirCalibrationFromFrames,
        files="files",
        levels="texts",
        pm25="texts",
        aqi="texts",
        groups="texts",
    ),
)
async def calibrate(
    request: Request,
    session: SessionDep,
    settings: SettingsDep,
    timing: TimingDep,
    _: Admin,
    significance: Significance = 0.05,
    shrinkage: Shrinkage = 0.0,
    camera_id: UploadsCamera = None,
    applies_to: AppliesTo = None,
    method: Method = None,
    breakpoints_table: BreakpointsTable = None,
    source: From = None,
    max_distance_km: MaxDistanceKm = 10.0,
) -> AirCalibrationOut:
    """Calibrate from labelled sky images (the level clusters, eqs. 6.12–6.13, or the
    regression). Multipart: repeated ``files`` and ``levels`` (1–10, same order), optionally
    ``groups`` (each image's day: left out together, as a day of stored frames is); or JSON
    ``{"frame_ids": [...], "levels": [...]}`` of stored sky frames. In place of ``levels``,
    the reference ``pm25`` [µg/m³] or US ``aqi``, made levels by the US EPA AQI breakpoints
    (2024) or the European index's bands (``breakpoints``; by default the European where the
    graded cameras stand in Europe). ``from=stations``, no body: from the readings of the
    stations near the cameras of ``applies_to``.
    """
    if source == "stations":
        job = partial(
            stations.calibrate_from_stations,
            session,
            applies_to or [],
            max_km=max_distance_km,
            significance=significance,
            shrinkage=shrinkage,
            now=timing.now(),
        )
        return _calibration_out(await run_in_threadpool(job, method, breakpoints_table))
    given = await images_or_frames(
        request,
        AirCalibrationFromFrames,
        upload_limit=settings.max_upload_bytes,
        body_limit=settings.max_body_bytes,
        max_files=5000,
        parts=("files", "levels", "pm25", "aqi", "groups"),
        expected="multipart/form-data (files, levels) or JSON (frame_ids, levels)",
    )
    grades = applies_to or []
    if isinstance(given, AirCalibrationFromFrames):
        row = await run_in_threadpool(  # stored features, no image: no image_work
            calibration.from_frames,
            session,
            given,
            significance,
            shrinkage,
            timing.now(),
            method,
            grades,
            breakpoints_table,
        )
        return _calibration_out(row)
    files = given.files_of("files")
    groups = given.groups_of(len(files))
    given_values = references.of_form(given.fields, len(files), breakpoints_table)
    row = await image_work(
        request,
        partial(
            calibration.from_uploads,
            session,
            files,
            given_values,
            breakpoints_table,
            camera_id,
            significance,
            shrinkage,
            settings.max_pixels,
            timing.now(),
            method,
            grades,
            groups,
        ),
    )
    return _calibration_out(row)


@router.post(
    "/cameras/{camera_id}/regrade",
    response_model=AirRegradeOut,
    responses={**AUTH_ERRORS, **NOT_FOUND, **UNPROCESSABLE},
)
async def regrade(
    request: Request,
    camera_id: CameraId,
    since: Annotated[UtcTime, Query(description="Re-grade the frames taken since this time.")],
    session: SessionDep,
    settings: SettingsDep,
    _: Admin,
    limit: Annotated[
        int, Query(ge=1, le=grading.REGRADE_LIMIT, description="Frames in this call at most.")
    ] = grading.REGRADE_LIMIT,
) -> AirRegradeOut:
    """Grade the sky camera's stored frames taken since ``since`` again by the calibration
    that grades it now (after a new calibration), measured in its region now; smooth its
    readings again. Its history then speaks one calibration: each reading names it
    (``calibration_id``). Raises no alerts (history). Oldest first, ``limit`` at a time."""
    store = app_state(request).frame_store if settings.store_frames else None
    done = await image_work(
        request,
        partial(
            grading.regrade,
            session,
            store,
            camera_id,
            since,
            max_pixels=settings.max_pixels,
            limit=limit,
        ),
    )
    return AirRegradeOut(
        camera_id=done.camera_id,
        calibration_id=done.calibration_id,
        since=done.since,
        regraded=done.regraded,
        missing=done.missing,
        next_since=done.next_since,
    )


@router.get("/calibration", response_model=AirCalibrationOut, responses=NOT_FOUND)
def current_calibration(session: SessionDep, camera_id: IdFilter = None) -> AirCalibrationOut:
    """The calibration in use: the city-wide one, or the one that grades ``camera_id``'s
    frames (its own, else the city-wide one)."""
    if camera_id is not None:
        cameras.sky_camera(session, camera_id)
    row = calibration.calibration_for(session, camera_id)
    if row is None:
        raise NotFound("no air-quality calibration yet")
    return _calibration_out(calibration.with_cameras(session, row))


@router.delete(
    "/cameras/{camera_id}/calibration",
    status_code=204,
    response_class=Response,
    responses={**AUTH_ERRORS, **NOT_FOUND},
)
def release_camera(camera_id: CameraId, session: SessionDep, _: Admin) -> Response:
    """Grade the sky camera by the city-wide calibration again, not by one made for it."""
    calibration.release_camera(session, camera_id)
    return Response(status_code=204)


@router.get(
    "/calibrations",
    response_model=list[AirCalibrationOut],
    responses={**NOT_FOUND, **UNPROCESSABLE},
)
def list_calibrations(
    session: SessionDep,
    camera_id: IdFilter = None,
    limit: Limit = 50,
    offset: Offset = 0,
) -> list[AirCalibrationOut]:
    """Every calibration, newest first, with the cameras each was made for (none: city-wide);
    with ``camera_id``, those made for that sky camera."""
    if camera_id is not None:
        cameras.sky_camera(session, camera_id)
    rows = calibration.calibrations(session, camera_id=camera_id, limit=limit, offset=offset)
    return [_calibration_out(r) for r in rows]
