"""panels retired

Revision ID: 74b0f14b7e71
Revises: d79576668f3d
Create Date: 2026-11-24 05:58:43.206047
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

import app.platform.db.base


revision: str = '74b0f14b7e71'
down_revision: str | None = 'd79576668f3d'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('panels', schema=None) as batch_op:
        batch_op.add_column(sa.Column('retired_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('panels', schema=None) as batch_op:
        batch_op.drop_column('retired_at')
