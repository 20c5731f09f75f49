"""Fleet models keep how many groups (panels) their folds kept together

Revision ID: 48aea2ca1893
Revises: 5749af07ac97
Create Date: 2026-11-28 05:57:42.580804
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = '48aea2ca1893'
down_revision: str | None = '5749af07ac97'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('fleet_models', schema=None) as batch_op:
        batch_op.add_column(sa.Column('n_groups', sa.Integer(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('fleet_models', schema=None) as batch_op:
        batch_op.drop_column('n_groups')
