"""The solar endpoints: panels and baselines, the fleet model, robots, the cleaning queue."""

from fastapi import APIRouter

from app.solar.routers import cleaning, fleet, panels, robots

router = APIRouter()
for part in (panels, fleet, robots, cleaning):
    router.include_router(part.router)
