"""Viewer tokens (read-only: the boards and their read endpoints) and the one-time sign-in
codes that kiosk links carry instead of a token.

The admin makes a viewer token (``POST /viewers``, its secret shown once) or a sign-in code
(``POST /signin-codes``): a link ``/farm#code=…`` that a screen opens once; the page exchanges
the code (``POST /signin-codes/redeem``) for a viewer token of its own, kept in the tab's
session storage. The code is good once and for minutes; no token ever stands in an address.
"""

from __future__ import annotations

import uuid
from datetime import datetime, timedelta
from typing import Annotated

from fastapi import APIRouter, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import Field
from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from app.platform.auth import hash_token, new_token
from app.platform.db.models import SigninCode, ViewerToken
from app.platform.http.deps import Admin, RecordId, SessionDep, TimingDep
from app.platform.http.errors import Unprocessable
from app.platform.http.responses import AUTH_ERRORS, NOT_FOUND, UNPROCESSABLE
from app.platform.lookup import get_or_404
from app.platform.schemas import Out, Schema

router = APIRouter(tags=["viewers"])

CODE_TTL = timedelta(minutes=10)
"""How long a sign-in code may wait to be redeemed, by default."""

Name = Annotated[str, Field(min_length=1, max_length=200, examples=["lobby screen"])]


class ViewerIn(Schema):
    name: Name


class ViewerOut(Out):
    id: str
    name: str
    created_at: datetime


class ViewerCreated(ViewerOut):
    token: str = Field(description="The viewer's token (vv_…), shown this once.")


class CodeIn(Schema):
    name: Name = Field(description="The name of the viewer token the code becomes.")
    minutes: int = Field(
        default=CODE_TTL // timedelta(minutes=1),
        ge=1,
        le=1440,
        description="How long it may wait [min].",
    )


class CodeOut(Out):
    code: str = Field(description="Good once, until expires_at.")
    expires_at: datetime
    farm: str = Field(description="A link to the farm board that signs in with the code.")
    cells: str = Field(description="Likewise for the cells page.")


class RedeemIn(Schema):
    code: Annotated[str, Field(min_length=1, max_length=100)]


def create_viewer(session: Session, name: str) -> tuple[ViewerToken, str]:
    token = new_token("vv")
    row = ViewerToken(id=str(uuid.uuid4()), name=name, token_hash=hash_token(token))
    session.add(row)
    session.flush()
    return row, token


def redeem(session: Session, code: str, now: datetime) -> tuple[ViewerToken, str]:
    """The code's viewer token, made now, and the code spent (expired ones swept). Unknown,
    used or expired codes are one 422, so an answer tells a guesser nothing."""
    digest = hash_token(code)
    row = session.get(SigninCode, digest, with_for_update=True)
    session.execute(delete(SigninCode).where(SigninCode.expires_at < now))
    if row is None or row.expires_at < now:
        raise Unprocessable("the sign-in code is unknown, used or expired", code="bad_code")
    session.delete(row)
    return create_viewer(session, row.name)


@router.post("/viewers", status_code=201, response_model=ViewerCreated, responses=AUTH_ERRORS)
def post_viewer(body: ViewerIn, session: SessionDep, _: Admin) -> ViewerCreated:
    """A read-only token: the farm and cells boards and their read endpoints, nothing else."""
    row, token = create_viewer(session, body.name)
    return ViewerCreated(id=row.id, name=row.name, created_at=row.created_at, token=token)


@router.get("/viewers", response_model=list[ViewerOut], responses=AUTH_ERRORS)
def list_viewers(session: SessionDep, _: Admin) -> list[ViewerOut]:
    """The viewer tokens, oldest first, without their secrets."""
    rows = session.scalars(select(ViewerToken).order_by(ViewerToken.created_at, ViewerToken.id))
    return [ViewerOut.model_validate(r) for r in rows]


@router.delete("/viewers/{viewer_id}", status_code=204, responses={**AUTH_ERRORS, **NOT_FOUND})
def revoke_viewer(viewer_id: RecordId, session: SessionDep, _: Admin) -> Response:
    """Revoke a viewer token: it is refused (401) from now on."""
    row = get_or_404(session, ViewerToken, viewer_id, "viewer token")
    session.delete(row)
    return Response(status_code=204)


@router.post("/signin-codes", status_code=201, response_model=CodeOut, responses=AUTH_ERRORS)
def post_code(body: CodeIn, session: SessionDep, timing: TimingDep, _: Admin) -> CodeOut:
    """A one-time code for a kiosk's link: ``/farm#code=…`` signs the screen in as a new
    viewer token named ``name``; the link is useless once opened or after ``minutes``."""
    code = new_token("sc")
    expires = timing.now() + timedelta(minutes=body.minutes)
    session.add(SigninCode(code_hash=hash_token(code), name=body.name, expires_at=expires))
    return CodeOut(
        code=code, expires_at=expires, farm=f"/farm#code={code}", cells=f"/cells#code={code}"
    )


@router.post(
    "/signin-codes/redeem",
    status_code=201,
    response_model=ViewerCreated,
    responses=UNPROCESSABLE,
)
async def redeem_code(body: RedeemIn, session: SessionDep, timing: TimingDep) -> ViewerCreated:
    """Exchange a sign-in code for a viewer token of its own (public: the code is the
    credential, good once)."""
    row, token = await run_in_threadpool(redeem, session, body.code, timing.now())
    return ViewerCreated(id=row.id, name=row.name, created_at=row.created_at, token=token)
