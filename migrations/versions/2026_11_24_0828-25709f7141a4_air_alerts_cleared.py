"""air alerts cleared

Revision ID: 25709f7141a4
Revises: 74b0f14b7e71
Create Date: 2026-11-24 08:28:50.372183
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = '25709f7141a4'
down_revision: str | None = '74b0f14b7e71'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # every alert so far was raised (an air quality entering Poor or Very Poor)
    with op.batch_alter_table('air_alerts', schema=None) as batch_op:
        batch_op.add_column(sa.Column('kind', sa.String(length=8), server_default='raised', nullable=False))


def downgrade() -> None:
    with op.batch_alter_table('air_alerts', schema=None) as batch_op:
        batch_op.drop_column('kind')
