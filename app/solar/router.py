"""The solar endpoints: panels and baselines, the fleet model, robots, the cleaning queue, the
operator's webhook, the panels' output and the farm's prices."""

from fastapi import APIRouter

from app.solar.routers import cleaning, energy, fleet, panels, robots, webhook

router = APIRouter()
for part in (panels, energy, fleet, robots, cleaning, webhook):
    router.include_router(part.router)
