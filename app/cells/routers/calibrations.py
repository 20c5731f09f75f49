"""Camera and stereo-pair calibration from checkerboard images."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Annotated, Any, Literal, TypedDict

from fastapi import APIRouter, Query, Request
from fastapi.responses import JSONResponse

from app.cells.models import Calibration
from app.cells.services import calibrations, hand_eye
from app.cells.services.calibrations import Board
from app.platform.http.deps import (
    Admin,
    Limit,
    Offset,
    Reader,
    RecordId,
    SessionDep,
    SettingsDep,
    TimingDep,
    image_work,
)
from app.platform.http.errors import Unprocessable, UnsupportedMediaType
from app.platform.http.responses import (
    AUTH_ERRORS,
    BODY_ERRORS,
    NOT_FOUND,
    UNPROCESSABLE,
    multipart_body,
)
from app.platform.http.uploads import content_type, read_form
from app.platform.settings import Settings
from app.platform.timing import Timing

router = APIRouter(prefix="/calibrations", tags=["stereo"])

# OpenCV's detectors need at least 3 inner corners each way
Cols = Annotated[
    int, Query(ge=3, le=100, description="Inner corners per row (a ChArUco board: squares across).")
]
Rows = Annotated[
    int,
    Query(ge=3, le=100, description="Inner corners per column (a ChArUco board: squares down)."),
]
Square = Annotated[
    float,
    Query(
        gt=0, le=1e6, description="Square size, in the unit results (T, extrinsics) are wanted in."
    ),
]


def _out(row: Any) -> dict[str, Any]:
    return {
        "id": row.id,
        "created_at": row.created_at.isoformat(),
        "kind": row.kind,
        "name": None,
        **row.result,
    }


def _body(row: Any) -> JSONResponse:
    return JSONResponse(_out(row), status_code=201)


def _name(form: Any) -> str | None:
    """The optional ``name`` field (the camera's, as people call it), up to 200 characters."""
    given = (form.fields.get("name") or [""])[0].strip()
    if len(given) > 200:
        raise Unprocessable("name: at most 200 characters")
    return given or None


class _BoardParts(TypedDict):
    pattern_cols: str
    pattern_rows: str
    square_size: str
    name: str
    board: str
    dictionary: str
    marker_size: str


BOARD_PARTS = _BoardParts(
    pattern_cols="text",
    pattern_rows="text",
    square_size="text",
    name="text",
    board="text",
    dictionary="text",
    marker_size="text",
)
"""The board's fields in the uploads' OpenAPI schemas."""

PATTERN_FIELDS = tuple(BOARD_PARTS)
"""Text fields a calibration upload may carry: the pattern instead of the query parameters,
the board's kind, and the calibration's name."""


async def _form(request: Request, limit: int, *parts: str) -> Any:
    """The upload's multipart body: the route's ``parts`` (files and text) and the board's."""
    if content_type(request) != "multipart/form-data":
        raise UnsupportedMediaType("send the board's views as multipart/form-data")
    return await read_form(request, limit, max_files=500, parts=(*parts, *PATTERN_FIELDS))


async def _calibrated(
    request: Request,
    form: Any,
    default: Board,
    settings: Settings,
    timing: Timing,
    run: Callable[..., Calibration],
) -> JSONResponse:
    """Run a calibration (``run`` given the board, the name, the pixel limit and the time) off
    the event loop, among the image workers, and answer 201 with what it stored."""
    board = _board(form, default)
    work = partial(
        run, board=board, name=_name(form), max_pixels=settings.max_pixels, now=timing.now()
    )
    return _body(await image_work(request, work))


def _board(form: Any, default: Board) -> Board:
    """The pattern from the multipart fields when given there, else from the query; a ChArUco
    board (``board=charuco``) with its ``dictionary`` and ``marker_size``."""
    fields = form.fields
    kind = (fields.get("board") or ["checkerboard"])[0]
    if kind not in ("checkerboard", "charuco"):
        raise Unprocessable(f"board {kind!r}: checkerboard or charuco", code="bad_board")
    try:
        cols = int(fields.get("pattern_cols", [default.cols])[0])
        rows = int(fields.get("pattern_rows", [default.rows])[0])
        square = float(fields.get("square_size", [default.square])[0])
        marker = float(fields["marker_size"][0]) if "marker_size" in fields else None
    except ValueError:
        raise Unprocessable(
            "pattern_cols, pattern_rows must be integers, square_size and marker_size numbers"
        ) from None
    if not (3 <= cols <= 100 and 3 <= rows <= 100) or not 0 < square <= 1e6:
        raise Unprocessable("pattern_cols, pattern_rows must be 3–100 and square_size > 0")
    if kind == "checkerboard":
        return Board(cols, rows, square)
    if marker is None:
        raise Unprocessable(
            "a ChArUco board needs marker_size (its markers' side, in square_size's unit)",
            code="bad_board",
        )
    dictionary = (fields.get("dictionary") or ["DICT_5X5_100"])[0]
    made = Board(cols, rows, square, "charuco", dictionary, marker)
    made.charuco()  # 422 now for a board OpenCV cannot make
    return made


@router.post(
    "",
    status_code=201,
    responses={**AUTH_ERRORS, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra=multipart_body(files="files", **BOARD_PARTS),
)
async def calibrate(
    request: Request,
    session: SessionDep,
    settings: SettingsDep,
    timing: TimingDep,
    _: Admin,
    pattern_cols: Cols = 9,
    pattern_rows: Rows = 6,
    square_size: Square = 1.0,
) -> JSONResponse:
    """Calibrate a camera from checkerboard images (multipart ``files``): K, distortion
    [k1, k2, p1, p2, k3], RMS and per-view reprojection error, standard deviations, and which
    views were used or rejected (and why)."""
    form = await _form(request, settings.max_upload_bytes, "files")
    files = form.files_of("files")
    if not files:
        raise Unprocessable("no images in field files")
    default = Board(pattern_cols, pattern_rows, square_size)
    run = partial(calibrations.calibrate_camera, session, files)
    return await _calibrated(request, form, default, settings, timing, run)


@router.post(
    "/stereo",
    status_code=201,
    responses={**AUTH_ERRORS, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra=multipart_body(left="files", right="files", **BOARD_PARTS),
)
async def calibrate_stereo(
    request: Request,
    session: SessionDep,
    settings: SettingsDep,
    timing: TimingDep,
    _: Admin,
    pattern_cols: Cols = 9,
    pattern_rows: Rows = 6,
    square_size: Square = 1.0,
) -> JSONResponse:
    """Calibrate a camera pair from simultaneous views (multipart ``left`` and ``right``, in
    the same order): both cameras' intrinsics, then R, T (x_right = R x_left + T) and the
    baseline |T| with the intrinsics held fixed."""
    form = await _form(request, settings.max_upload_bytes, "left", "right")
    left, right = form.files_of("left"), form.files_of("right")
    run = partial(calibrations.calibrate_pair, session, left, right)
    default = Board(pattern_cols, pattern_rows, square_size)
    return await _calibrated(request, form, default, settings, timing, run)


def _hand_eye_fields(form: Any) -> dict[str, Any]:
    """The hand-eye upload's own fields: the camera's calibration, the setup, the poses."""
    fields = form.fields
    setup = (fields.get("setup") or ["eye_to_hand"])[0]
    if setup not in ("eye_to_hand", "eye_in_hand"):
        raise Unprocessable(f"setup {setup!r}: eye_to_hand or eye_in_hand")
    calibration_id = (fields.get("calibration_id") or [""])[0]
    if not calibration_id:
        raise Unprocessable("calibration_id: the camera's calibration (POST /calibrations)")
    return {
        "calibration_id": calibration_id,
        "files": form.required_files("files"),
        "poses": fields.get("poses", []),
        "setup": setup,
    }


@router.post(
    "/hand-eye",
    status_code=201,
    responses={**AUTH_ERRORS, **BODY_ERRORS, **UNPROCESSABLE},
    openapi_extra=multipart_body(
        files="files", poses="text", calibration_id="text", setup="text", **BOARD_PARTS
    ),
)
async def calibrate_hand_eye(
    request: Request,
    session: SessionDep,
    settings: SettingsDep,
    timing: TimingDep,
    _: Admin,
    pattern_cols: Cols = 9,
    pattern_rows: Rows = 6,
    square_size: Square = 0.025,
) -> JSONResponse:
    """Where a camera is on a robot, from views of a board (multipart ``files``) and the
    flange's pose in the base for each (``poses``, one JSON text per file, in order:
    ``{"rotation": 3×3, "translation": [x, y, z]}`` or ``{"rvec", "tvec"}``, in metres), with
    the camera's ``calibration_id`` and ``setup`` (``eye_to_hand``: a fixed camera, the board
    on the flange; ``eye_in_hand``: the camera on the flange). Answers ``camera_to_base`` or
    ``camera_to_flange`` (4×4: camera coordinates into that frame), the board's pose, and
    residuals per view and RMS in px, mm and degrees. ``square_size`` is in metres."""
    form = await _form(
        request, settings.max_upload_bytes, "files", "poses", "calibration_id", "setup"
    )
    run = partial(hand_eye.calibrate, session, **_hand_eye_fields(form))
    default = Board(pattern_cols, pattern_rows, square_size)
    return await _calibrated(request, form, default, settings, timing, run)


@router.get("", responses=AUTH_ERRORS)
def list_calibrations(
    session: SessionDep,
    _: Reader,
    kind: Annotated[
        Literal["single", "stereo", "hand_eye"] | None,
        Query(description="Only cameras (single), stereo pairs or hand-eye calibrations."),
    ] = None,
    limit: Limit = 50,
    offset: Offset = 0,
) -> JSONResponse:
    """Calibrations, newest first (a stereo pair's id makes a rig: POST /rigs)."""
    rows = calibrations.listed(session, kind=kind, limit=limit, offset=offset)
    return JSONResponse([_out(row) for row in rows])


@router.get("/{calibration_id}", responses={**AUTH_ERRORS, **NOT_FOUND})
def get_calibration(calibration_id: RecordId, session: SessionDep, _: Reader) -> JSONResponse:
    """One calibration."""
    return JSONResponse(_out(calibrations.get(session, calibration_id)))
