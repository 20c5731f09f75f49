"""Calibrating the air-quality grading: from uploaded sky images or stored frames, with levels
or reference PM2.5 or AQI values; which calibration grades which camera."""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import (
    and_,
    or_,
    select,
)
from sqlalchemy.orm import Session, selectinload

from app.air.core import airquality
from app.air.models import AirCalibration, AirCalibrationCamera, SkyVerdict
from app.air.schemas import (
    AirCalibrationFromFrames,
)
from app.air.services.cameras import graded_cameras, sky_camera
from app.air.services.references import (
    Raw,
    as_levels,
    check_references,
    choose,
)
from app.platform.db.models import Camera, CameraKind, Frame
from app.platform.db.session import release
from app.platform.frames import ingest
from app.platform.frames.camera_info import (
    CameraInfo,
    Region,
    describe_region,
    one_view,
    region_now,
    uploads_in,
)
from app.platform.frames.verdicts import check_usable
from app.platform.http.errors import (
    NotFound,
    Unprocessable,
)
from app.platform.memo import ById
from app.stats import hotelling


def from_uploads(
    session: Session,
    files: list[tuple[str | None, bytes]],
    raw: Raw,
    table: str | None,
    camera_id: str | None,
    significance: float,
    shrinkage: float,
    max_pixels: int,
    now: datetime,
    method: str | None,
    applies_to: list[str],
    groups: list[str] | None,
) -> AirCalibration:
    """A calibration from uploaded sky images and their references (``raw``), measured in
    the region of ``upload_region``; the session is released while the images decode."""
    refs = as_levels(session, raw, table, applies_to)
    camera, warnings = upload_region(session, camera_id, applies_to)
    release(session)  # while decoding
    decoded = ingest.decode_all(files, camera, max_pixels=max_pixels)
    feats = np.array([d.features for d in decoded], dtype=np.float64)
    return new_calibration(
        session,
        ingest.modes_of(decoded),
        refs.levels,
        significance=significance,
        shrinkage=shrinkage,
        frame_ids=None,
        now=now,
        method=method,
        features=feats,
        camera_ids=applies_to,
        warnings=[*refs.notes, *warnings],
        reference=refs.reference,
        groups=groups,
        table=refs.table,
    )


def from_frames(
    session: Session,
    body: AirCalibrationFromFrames,
    significance: float,
    shrinkage: float,
    now: datetime,
    method: str | None,
    applies_to: list[str],
    table: str | None,
) -> AirCalibration:
    """A calibration from stored sky frames (their kept modes and features, each measured
    where its camera measured it) and their references, grouped by the day each was taken."""
    refs = as_levels(session, (body.levels, body.pm25, body.aqi), table, applies_to)
    if len(body.frame_ids) != len(refs.levels):
        raise Unprocessable(f"{len(body.frame_ids)} frames but {len(refs.levels)} reference values")
    stored = of_frames(session, body.frame_ids)
    return new_calibration(
        session,
        stored.modes,
        refs.levels,
        significance=significance,
        shrinkage=shrinkage,
        frame_ids=body.frame_ids,
        now=now,
        method=method,
        features=stored.features,
        camera_ids=applies_to,
        regions=stored.regions,
        warnings=refs.notes,
        reference=refs.reference,
        groups=stored.days,
        table=refs.table,
    )


def calibration_for(session: Session, camera_id: str | None) -> AirCalibration | None:
    """The calibration that grades a camera's frames: the newest made for that camera, else
    the newest city-wide one (made for no camera in particular). ``None``: the city-wide one."""
    return grading(session, camera_id).calibration


@dataclass(frozen=True, slots=True)
class Grading:
    calibration: AirCalibration | None
    own: bool
    """Made for this camera (not the city-wide one)."""
    region: Region
    """Its own: the camera's region of interest when it was made."""


def grading(session: Session, camera_id: str | None) -> Grading:
    """What grades a camera's frames (``calibration_for``), and whether it is its own.

    One query (it runs for every sky frame, on the writer): the camera's own calibrations and
    the city-wide ones, its own first. For ``None`` the join's ``camera_id IS NULL`` matches no
    row, which leaves the city-wide ones.
    """
    mine = and_(
        AirCalibrationCamera.calibration_id == AirCalibration.id,
        AirCalibrationCamera.camera_id == camera_id,
    )
    row = session.execute(
        select(AirCalibration, AirCalibrationCamera.camera_id, AirCalibrationCamera.roi)
        .outerjoin(AirCalibrationCamera, mine)
        .where(or_(AirCalibrationCamera.camera_id.is_not(None), AirCalibration.city_wide))
        .order_by(
            AirCalibrationCamera.camera_id.is_(None),  # its own first (false sorts before true)
            AirCalibration.created_at.desc(),
            AirCalibration.id,
        )
        .limit(1)
    ).first()
    if row is None:
        return Grading(None, False, None)
    return Grading(row[0], row[1] is not None, row[2])


def release_camera(session: Session, camera_id: str) -> None:
    """Grade the sky camera by the city-wide calibration again: it is taken off every
    calibration made for it (which keep grading their other cameras). NotFound when it has none
    of its own."""
    sky_camera(session, camera_id)
    links = session.scalars(
        select(AirCalibrationCamera).where(AirCalibrationCamera.camera_id == camera_id)
    ).all()
    if not links:
        raise NotFound(f"sky camera {camera_id!r} has no calibration of its own")
    for link in links:
        session.delete(link)
    session.flush()


def calibrations(
    session: Session, *, camera_id: str | None, limit: int, offset: int
) -> Sequence[AirCalibration]:
    """Calibrations, newest first (only those made for ``camera_id`` when given), with the
    cameras each was made for loaded."""
    q = select(AirCalibration).options(selectinload(AirCalibration.cameras))
    if camera_id is not None:
        q = q.join(AirCalibrationCamera).where(AirCalibrationCamera.camera_id == camera_id)
    q = q.order_by(AirCalibration.created_at.desc(), AirCalibration.id)
    return session.scalars(q.limit(limit).offset(offset)).all()


def with_cameras(session: Session, row: AirCalibration) -> AirCalibration:
    """The calibration with the cameras it was made for loaded (for its ``camera_ids``)."""
    session.refresh(row, ["cameras"])
    return row


def as_core(row: AirCalibration) -> airquality.Calibration:
    clusters = tuple(
        airquality.Cluster(
            levels=tuple(c["levels"]),
            level=int(c["level"]),
            baseline=hotelling.Baseline(
                n=int(c["n"]),
                mean_modes=np.asarray(c["mean_modes"], dtype=np.float64),
                covariance=np.asarray(c["covariance"], dtype=np.float64),
                significance=float(c["significance"]),
                f_critical=float(c["f_critical"]),
                condition_number=float(c["condition_number"]),
                shrinkage=float(c["shrinkage"]),
            ),
        )
        for c in row.clusters
    )
    return airquality.Calibration(clusters, tuple(row.warnings))


def fit_regression(
    features: NDArray[np.float64],
    targets: Sequence[float],
    *,
    unit: str = "level",
    groups: Sequence[str] | None = None,
    table: str = "us_epa",
) -> dict[str, Any]:
    """The ridge regression of ``targets`` (levels, or the reference in ``unit``, whose levels
    come by the breakpoint ``table``) on the sky features (``airquality.fit_regression``), as
    the calibration keeps it."""
    if len(targets) < 10 or len({airquality.level_of(t, unit, table) for t in targets}) < 3:
        raise Unprocessable("the regression needs at least 10 images of at least 3 levels")
    if features.ndim != 2 or features.shape[1] != len(airquality.SKY_FEATURES):
        raise Unprocessable(
            "some images' sky features were measured by an earlier version: re-grade their "
            "cameras first (POST /air/cameras/{id}/regrade) or upload the images",
            code="stale_features",
        )
    if not np.isfinite(features).all():
        raise Unprocessable("some images gave non-finite features")
    model, alpha = airquality.fit_regression(
        features, targets, unit=unit, groups=groups, table=table
    )
    left_out = airquality.groups_left_out(groups)
    assert model.gram_inv is not None
    return {
        "features": list(airquality.SKY_FEATURES),
        "unit": unit,
        "breakpoints": table,
        "mean": model.mean.tolist(),
        "scale": model.scale.tolist(),
        "coef": model.coef.tolist(),
        "intercept": model.intercept,
        "alpha": alpha,
        "gram_inv": model.gram_inv.tolist(),
        "n": model.n,
        "sigma": model.sigma,
        "dof": model.dof,
        "max_leverage": model.max_leverage,
        "day_share": model.day_share,
        "interval": airquality.INTERVAL,
        "sigma_from": "images left out" if left_out is None else "days left out",
        "groups": left_out,
    }


_REGRESSIONS: ById[airquality.Regression | None] = ById()
"""Regressions as read, by calibration id: a calibration never changes once made."""


def as_regression(row: AirCalibration) -> airquality.Regression | None:
    """The calibration's regression; None without one, or one made on features that are no
    longer measured (its frames must be graded by a new calibration). One made before
    features were added grades by the features it was fitted on."""
    return _REGRESSIONS.get(row.id, lambda: _read_regression(row.regression))


def _read_regression(r: dict[str, Any] | None) -> airquality.Regression | None:
    if not r:
        return None
    names = list(airquality.SKY_FEATURES)
    fitted_on = r.get("features", [])
    if not fitted_on or not set(fitted_on) <= set(names):
        return None
    gram = r.get("gram_inv")
    return airquality.Regression(
        np.asarray(r["mean"]),
        np.asarray(r["scale"]),
        np.asarray(r["coef"]),
        float(r["intercept"]),
        unit=str(r.get("unit", "level")),
        gram_inv=None if gram is None else np.asarray(gram, dtype=np.float64),
        n=int(r.get("n", 0)),
        sigma=r.get("sigma"),
        dof=float(r.get("dof", 1.0)),
        max_leverage=r.get("max_leverage"),
        table=str(r.get("breakpoints", "us_epa")),  # made before the choice: the EPA's
        day_share=float(r.get("day_share", 1.0)),  # made before it was measured: all shared
        columns=None if fitted_on == names else tuple(names.index(n) for n in fitted_on),
    )


def new_calibration(
    session: Session,
    modes: NDArray[np.float64],
    levels: Sequence[int],
    *,
    significance: float,
    shrinkage: float,
    frame_ids: list[str] | None,
    now: datetime,
    method: str | None = "clusters",
    features: NDArray[np.float64] | None = None,
    camera_ids: Sequence[str] = (),
    warnings: Sequence[str] = (),
    regions: Sequence[tuple[str, str, Region]] = (),
    reference: tuple[str, Sequence[float]] | None = None,
    groups: Sequence[str] | None = None,
    table: str = "us_epa",
) -> AirCalibration:
    """The level clusters (always) and, for ``method="regression"``, the regression too:
    fitted to ``reference`` (unit "pm25" or "aqi", one value per image) when given, so its
    verdicts carry an estimate in that unit, made a level by the breakpoint ``table``; else to
    the levels. ``groups``: each image's capture day, for the regression's out-of-sample
    residuals. ``method=None``: the one that measures best on days left out
    (``selection.choose``) for reference values, the clusters for levels; the choice and both
    scores are kept (``selection``). Reference values all equal, or of fewer than three
    days, are refused (422).

    ``warnings`` are kept in the model beside its own (levels pooled for want of images).
    ``regions``: (frame, camera, region) of stored frames it is made from; a camera it is made
    for must have measured its own frames among them where it measures now.

    Made for ``camera_ids`` (sky cameras), it grades those cameras' frames from now on; made for
    none, it is the city-wide calibration of every camera without one of its own.
    """
    cameras = sorted(set(camera_ids))
    sky = _sky_cameras_named(session, cameras)
    _check_regions(sky, regions)
    check_references(reference, groups)
    chosen = None
    if method is None and reference is not None:
        chosen = choose(modes, features, levels, reference, groups, table, significance, shrinkage)
        method = chosen.chosen
    method = method or "clusters"
    regression = None
    if method == "regression":
        if features is None:
            raise Unprocessable("the regression needs the images' sky features")
        unit, targets = reference if reference is not None else ("level", levels)
        regression = fit_regression(features, list(targets), unit=unit, groups=groups, table=table)
    try:
        cal = airquality.level_clusters(
            modes, levels, significance=significance, shrinkage=shrinkage
        )
    except hotelling.BaselineError as exc:
        if regression is None:
            raise Unprocessable(f"cannot calibrate: {exc}", code="bad_calibration") from None
        # the regression grades without the clusters (they grade only a frame stored without
        # sky features): a level whose modes vary along fewer than three directions (one grey
        # sky at several exposures) refused a regression for a covariance it never uses
        cal = airquality.Calibration(
            (), (f"no T² clusters, the regression grades without them: {exc}",)
        )
    except ValueError as exc:
        raise Unprocessable(str(exc)) from None
    row = AirCalibration(
        id=str(uuid.uuid4()),
        created_at=now,
        clusters=[_cluster_kept(c) for c in cal.clusters],
        warnings=[*cal.warnings, *warnings],
        n_images=len(levels),
        frame_ids=frame_ids,
        method=method,
        regression=regression,
        selection=None if chosen is None else chosen.kept(),
        city_wide=not cameras,
        cameras=[AirCalibrationCamera(camera_id=c, roi=region_now(sky[c])) for c in cameras],
    )
    session.add(row)
    session.flush()
    return row


def _sky_cameras_named(session: Session, cameras: Sequence[str]) -> dict[str, Camera]:
    """The sky cameras ``cameras`` names, by id; Unprocessable naming the first id that is
    not one."""
    if not cameras:
        return {}
    sky = {
        c.id: c
        for c in session.scalars(
            select(Camera).where(Camera.id.in_(cameras), Camera.kind == CameraKind.sky)
        )
    }
    missing = [c for c in cameras if c not in sky]
    if missing:
        raise Unprocessable(
            f"applies_to: no sky camera {missing[0]!r}"
            + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""),
            code="not_a_sky_camera",
        )
    return sky


def _check_regions(sky: dict[str, Camera], regions: Sequence[tuple[str, str, Region]]) -> None:
    """Refuse a stored frame of a camera in ``sky`` measured elsewhere than the camera
    measures now: a calibration made for it would grade another part of its view."""
    for frame_id, camera_id, region in regions:
        now_at = region_now(sky[camera_id]) if camera_id in sky else region
        if region != now_at:
            raise Unprocessable(
                f"frame {frame_id} of camera {camera_id!r} was measured in "
                f"{describe_region(region)}, but the camera now measures "
                f"{describe_region(now_at)}: a calibration made for it from that frame would "
                "grade another part of the view; use frames taken since its roi changed",
                code="region_not_in_use",
            )


def _cluster_kept(c: airquality.Cluster) -> dict[str, Any]:
    """A level cluster as the calibration keeps it (JSON; ``as_core`` reads it back)."""
    return {
        "levels": list(c.levels),
        "level": c.level,
        "n": c.baseline.n,
        "mean_modes": c.baseline.mean_modes.tolist(),
        "covariance": c.baseline.covariance.tolist(),
        "significance": c.baseline.significance,
        "f_critical": c.baseline.f_critical,
        "condition_number": c.baseline.condition_number,
        "shrinkage": c.baseline.shrinkage,
    }


@dataclass(frozen=True, slots=True)
class StoredSkies:
    modes: NDArray[np.float64]
    features: NDArray[np.float64] | None
    """None unless every frame kept them."""
    regions: list[tuple[str, str, Region]]
    """(frame, camera, the region it was measured in) of each frame."""
    days: list[str]
    """The day each frame was captured, by the sun at its camera (``solar_day``)."""


def solar_day(captured_at: datetime, lon: float | None) -> str:
    """The ISO date of ``captured_at`` by the sun at longitude ``lon`` [° east]: UTC shifted
    by lon/15 h (mean solar time), so that a day's frames, which share its weather, share a
    date; at 151° E daylight runs across UTC midnight. UTC's date without a longitude."""
    shift = timedelta(hours=(lon or 0.0) / 15.0)
    return (captured_at.astimezone(UTC) + shift).date().isoformat()


def of_frames(session: Session, frame_ids: Sequence[str]) -> StoredSkies:
    """Mode vectors, sky features and regions of stored sky frames."""
    rows = session.execute(
        select(
            SkyVerdict.frame_id,
            SkyVerdict.mode_r,
            SkyVerdict.mode_g,
            SkyVerdict.mode_b,
            SkyVerdict.details,
            SkyVerdict.camera_id,
            SkyVerdict.roi,
            SkyVerdict.usable,
            SkyVerdict.reason,
            Frame.captured_at,
            Camera.lon,
        )
        .join(Frame, Frame.id == SkyVerdict.frame_id)
        .join(Camera, Camera.id == SkyVerdict.camera_id)
        .where(SkyVerdict.frame_id.in_(frame_ids))
    ).all()
    found = {r[0]: r for r in rows}
    missing = [f for f in frame_ids if f not in found]
    if missing:
        raise Unprocessable(f"no sky frames {', '.join(missing[:10])}", missing=missing)
    check_usable([(r[0], r[8]) for r in rows if not r[7]])
    modes = np.array([found[f][1:4] for f in frame_ids], dtype=np.float64)
    feats = [(found[f][4] or {}).get("features") for f in frame_ids]
    regions = [(f, found[f][5], found[f][6]) for f in frame_ids]
    days = [solar_day(found[f][9], found[f][10]) for f in frame_ids]
    if any(x is None for x in feats) or len({len(x or ()) for x in feats}) != 1:
        return StoredSkies(modes, None, regions, days)
    return StoredSkies(modes, np.array(feats, dtype=np.float64), regions, days)


def upload_region(
    session: Session, camera_id: str | None, applies_to: Sequence[str]
) -> tuple[CameraInfo, list[str]]:
    """How uploaded calibration images are measured (a camera's region, or the whole image),
    and warnings naming the cameras the calibration grades that measure another region.

    A calibration's features must be measured where its cameras measure their frames: a
    calibration from whole photos of street and sky grades a camera that sees only its sky
    region as far hazier than it is. The region is the named camera's (``camera_id``); else,
    when every camera in ``applies_to`` measures the same region, theirs (the uploads are their
    frames); else the whole image, each upload being taken to be a sky image.
    """
    source = sky_camera(session, camera_id) if camera_id is not None else None
    graded = session.scalars(graded_cameras(applies_to).order_by(Camera.id)).all()
    if source is None and applies_to:
        source = one_view(graded)
    region = source.roi if source is not None else None
    differ = [c.id for c in graded if c.roi != region]
    measured = uploads_in(source, CameraKind.sky)
    if not differ:
        return measured, []
    where = (
        f"camera {source.id!r}'s region"
        if source is not None and region is not None
        else "the whole image"
    )
    named = ", ".join(differ[:5]) + (f" and {len(differ) - 5} more" if len(differ) > 5 else "")
    return measured, [
        f"the uploads were measured over {where}, but the cameras it grades {named} measure "
        "another region: unless the uploads are just what those regions see, calibrate with "
        "camera_id naming a camera whose full frames they are, or each group of cameras with "
        "one region with applies_to"
    ]
