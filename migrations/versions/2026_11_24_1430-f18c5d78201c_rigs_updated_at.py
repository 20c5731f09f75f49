"""rigs replaced: when their geometry last changed

Revision ID: f18c5d78201c
Revises: 25709f7141a4
Create Date: 2026-11-24 14:30:41.167376
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

import app.platform.db.base


revision: str = 'f18c5d78201c'
down_revision: str | None = '25709f7141a4'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('rigs', schema=None) as batch_op:
        batch_op.add_column(sa.Column('updated_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('rigs', schema=None) as batch_op:
        batch_op.drop_column('updated_at')
