"""Fleet models keep their sure figure and what the farm's labels did

Revision ID: 788228666834
Revises: f25d7bde059f
Create Date: 2026-11-29 03:39:13.438226

Null (and no farm frames) for models trained before.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = '788228666834'
down_revision: str | None = 'f25d7bde059f'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('fleet_models', schema=None) as batch_op:
        batch_op.add_column(sa.Column('cv_sure_balanced_accuracy', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('cv_answered', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('n_farm', sa.Integer(), server_default='0', nullable=False))
        batch_op.add_column(sa.Column('cv_without_farm', sa.Float(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('fleet_models', schema=None) as batch_op:
        batch_op.drop_column('cv_without_farm')
        batch_op.drop_column('n_farm')
        batch_op.drop_column('cv_answered')
        batch_op.drop_column('cv_sure_balanced_accuracy')
