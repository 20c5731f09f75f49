"""Solar panels."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from app.deps import Admin, PanelId, SessionDep
from app.routers.responses import AUTH_ERRORS, CONFLICT, NOT_FOUND, UNPROCESSABLE
from app.schemas import PanelCreate, PanelOut
from app.services import registry

router = APIRouter(tags=["panels"])


@router.post(
    "/panels",
    status_code=201,
    response_model=PanelOut,
    responses={**AUTH_ERRORS, **CONFLICT, **UNPROCESSABLE},
)
def create_panel(body: PanelCreate, session: SessionDep, _: Admin) -> PanelOut:
    """Register a solar panel."""
    return PanelOut.model_validate(registry.create_panel(session, body))


@router.get("/panels", response_model=list[PanelOut], responses=AUTH_ERRORS)
def list_panels(
    session: SessionDep,
    _: Admin,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> list[PanelOut]:
    """List panels, ordered by id."""
    return [
        PanelOut.model_validate(p)
        for p in registry.list_panels(session, limit=limit, offset=offset)
    ]


@router.get("/panels/{panel_id}", response_model=PanelOut, responses={**AUTH_ERRORS, **NOT_FOUND})
def get_panel(panel_id: PanelId, session: SessionDep, _: Admin) -> PanelOut:
    """One panel."""
    return PanelOut.model_validate(registry.get_panel(session, panel_id))
