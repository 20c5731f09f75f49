"""the region of interest a verdict and a baseline were measured in

Rows from before are taken to have been measured in their camera's present region (a baseline:
in that of its panel's first camera in service), the best that is known of them.

Revision ID: a4aaa009e2ad
Revises: 362c29eee263
Create Date: 2026-11-24 01:59:48.411917
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = 'a4aaa009e2ad'
down_revision: str | None = '362c29eee263'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('baselines', schema=None) as batch_op:
        batch_op.add_column(sa.Column('roi', sa.JSON(), nullable=True))

    with op.batch_alter_table('verdicts', schema=None) as batch_op:
        batch_op.add_column(sa.Column('roi', sa.JSON(), nullable=True))

    op.execute(
        "UPDATE verdicts SET roi = (SELECT cameras.roi FROM cameras"
        " WHERE cameras.id = verdicts.camera_id)"
    )
    op.execute(
        "UPDATE baselines SET roi = (SELECT cameras.roi FROM cameras"
        " WHERE cameras.panel_id = baselines.panel_id"
        " ORDER BY cameras.retired_at IS NOT NULL, cameras.id LIMIT 1)"
    )


def downgrade() -> None:
    with op.batch_alter_table('verdicts', schema=None) as batch_op:
        batch_op.drop_column('roi')

    with op.batch_alter_table('baselines', schema=None) as batch_op:
        batch_op.drop_column('roi')
