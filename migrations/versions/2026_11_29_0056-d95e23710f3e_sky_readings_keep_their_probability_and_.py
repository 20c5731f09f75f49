"""Sky readings keep their probability and smoothed range; calibrations their choice

Revision ID: d95e23710f3e
Revises: 3c4fff4e598d
Create Date: 2026-11-29 00:56:12.983239

Readings graded before have none (null): their public reading is their smoothed level.
Calibrations made before chose no method (null).
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = 'd95e23710f3e'
down_revision: str | None = '3c4fff4e598d'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('air_alerts', schema=None) as batch_op:
        batch_op.add_column(sa.Column('probability', sa.Float(), nullable=True))

    with op.batch_alter_table('air_calibrations', schema=None) as batch_op:
        batch_op.add_column(sa.Column('selection', sa.JSON(), nullable=True))

    with op.batch_alter_table('sky_verdicts', schema=None) as batch_op:
        batch_op.add_column(sa.Column('probability', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('smoothed_estimate', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('smoothed_low', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('smoothed_high', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('smoothed_probability', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('poor_probability', sa.Float(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('sky_verdicts', schema=None) as batch_op:
        batch_op.drop_column('poor_probability')
        batch_op.drop_column('smoothed_probability')
        batch_op.drop_column('smoothed_high')
        batch_op.drop_column('smoothed_low')
        batch_op.drop_column('smoothed_estimate')
        batch_op.drop_column('probability')

    with op.batch_alter_table('air_calibrations', schema=None) as batch_op:
        batch_op.drop_column('selection')

    with op.batch_alter_table('air_alerts', schema=None) as batch_op:
        batch_op.drop_column('probability')
