"""The robot-cell endpoints: outlines, camera calibrations, rigs and shapes."""

from fastapi import APIRouter

from app.cells.routers import calibrations, rigs, vision

router = APIRouter()
for part in (vision, calibrations, rigs):
    router.include_router(part.router)
router.include_router(rigs.shapes_router)
