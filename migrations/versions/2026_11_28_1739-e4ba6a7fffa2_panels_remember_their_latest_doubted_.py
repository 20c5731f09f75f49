"""Panels remember their latest doubted frame

Revision ID: e4ba6a7fffa2
Revises: 69441f8d4edf
Create Date: 2026-11-28 17:39:41.166329

The farm board says when a panel's latest frame was one the fleet model would not judge.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

import app.platform.db.base

revision: str = 'e4ba6a7fffa2'
down_revision: str | None = '69441f8d4edf'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('panels', schema=None) as batch_op:
        batch_op.add_column(sa.Column('last_doubted_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('panels', schema=None) as batch_op:
        batch_op.drop_column('last_doubted_at')
