"""Sky verdicts: uncertain, with the regression's estimate and its interval

Revision ID: c00404936905
Revises: 1bcd23ef5df2
Create Date: 2026-11-27 12:08:42.755613
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

import app.platform.db.base


revision: str = 'c00404936905'
down_revision: str | None = '1bcd23ef5df2'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('sky_verdicts', schema=None) as batch_op:
        batch_op.add_column(sa.Column('uncertain', sa.Boolean(), server_default=sa.false(), nullable=False))
        batch_op.add_column(sa.Column('estimate', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('estimate_low', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('estimate_high', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('estimate_unit', sa.String(length=8), nullable=True))



def downgrade() -> None:
    with op.batch_alter_table('sky_verdicts', schema=None) as batch_op:
        batch_op.drop_column('estimate_unit')
        batch_op.drop_column('estimate_high')
        batch_op.drop_column('estimate_low')
        batch_op.drop_column('estimate')
        batch_op.drop_column('uncertain')

