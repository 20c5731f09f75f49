"""Panels say where they are in words

Revision ID: 6afd06df7729
Revises: 62e18f692616
Create Date: 2026-11-28 17:24:50.333536

A robot claiming a task learns its panel's place: lat, lon and the operator's words.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '6afd06df7729'
down_revision: str | None = '62e18f692616'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('panels', schema=None) as batch_op:
        batch_op.add_column(sa.Column('location', sa.String(length=200), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('panels', schema=None) as batch_op:
        batch_op.drop_column('location')
