"""Viewer tokens and sign-in codes

Revision ID: 62e18f692616
Revises: f5b46379f5d2
Create Date: 2026-11-28 16:24:51.192046

Read-only viewer tokens for the boards, and one-time codes that kiosk links carry instead of
a token.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

import app.platform.db.base


revision: str = '62e18f692616'
down_revision: str | None = 'f5b46379f5d2'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('signin_codes',
    sa.Column('code_hash', sa.String(length=64), nullable=False),
    sa.Column('name', sa.String(length=200), nullable=False),
    sa.Column('expires_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=False),
    sa.PrimaryKeyConstraint('code_hash', name=op.f('pk_signin_codes'))
    )
    with op.batch_alter_table('signin_codes', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_signin_codes_expires_at'), ['expires_at'], unique=False)

    op.create_table('viewer_tokens',
    sa.Column('id', sa.String(length=36), nullable=False),
    sa.Column('name', sa.String(length=200), nullable=False),
    sa.Column('token_hash', sa.String(length=64), nullable=False),
    sa.Column('created_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=False),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_viewer_tokens')),
    sa.UniqueConstraint('token_hash', name=op.f('uq_viewer_tokens_token_hash'))
    )


def downgrade() -> None:
    op.drop_table('viewer_tokens')
    with op.batch_alter_table('signin_codes', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_signin_codes_expires_at'))

    op.drop_table('signin_codes')
