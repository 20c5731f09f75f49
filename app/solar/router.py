"""The solar endpoints: panels and baselines, the fleet model, robots, the cleaning queue, the
operator's webhook."""

from fastapi import APIRouter

from app.solar.routers import cleaning, fleet, panels, robots, webhook

router = APIRouter()
for part in (panels, fleet, robots, cleaning, webhook):
    router.include_router(part.router)
