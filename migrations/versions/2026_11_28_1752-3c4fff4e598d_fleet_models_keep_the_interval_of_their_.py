"""Fleet models keep the interval of their accuracy

Revision ID: 3c4fff4e598d
Revises: e4ba6a7fffa2
Create Date: 2026-11-28 17:52:51.848015

Models trained before have none (null): the board then shows the figure alone.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = '3c4fff4e598d'
down_revision: str | None = 'e4ba6a7fffa2'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('fleet_models', schema=None) as batch_op:
        batch_op.add_column(sa.Column('cv_low', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('cv_high', sa.Float(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('fleet_models', schema=None) as batch_op:
        batch_op.drop_column('cv_high')
        batch_op.drop_column('cv_low')
