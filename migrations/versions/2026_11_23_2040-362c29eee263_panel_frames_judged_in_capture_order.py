"""panel frames judged in capture order

Revision ID: 362c29eee263
Revises: f8aae8bcad92
Create Date: 2026-11-23 20:40:13.528259
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

import app.platform.db.base


revision: str = '362c29eee263'
down_revision: str | None = 'f8aae8bcad92'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('panel_verdicts', schema=None) as batch_op:
        batch_op.add_column(sa.Column('late', sa.Boolean(), server_default=sa.false(), nullable=False))

    with op.batch_alter_table('panels', schema=None) as batch_op:
        batch_op.add_column(sa.Column('last_judged_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('panels', schema=None) as batch_op:
        batch_op.drop_column('last_judged_at')

    with op.batch_alter_table('panel_verdicts', schema=None) as batch_op:
        batch_op.drop_column('late')
