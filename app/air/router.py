"""The air-quality endpoints: calibration (admin); latest, readings, alerts and the map
(public)."""

from fastapi import APIRouter

from app.air.routers import alerts, calibration, maps, readings, stations

router = APIRouter()
for part in (calibration, readings, alerts, maps, stations):
    router.include_router(part.router)
