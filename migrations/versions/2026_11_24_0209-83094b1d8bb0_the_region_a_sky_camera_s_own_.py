"""the region a sky camera's own calibration was made in

A calibration made before for a camera is taken to have been made in the camera's present
region, the best that is known of it.

Revision ID: 83094b1d8bb0
Revises: a4aaa009e2ad
Create Date: 2026-11-24 02:09:00.811352
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = '83094b1d8bb0'
down_revision: str | None = 'a4aaa009e2ad'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('air_calibration_cameras', schema=None) as batch_op:
        batch_op.add_column(sa.Column('roi', sa.JSON(), nullable=True))

    op.execute(
        "UPDATE air_calibration_cameras SET roi = (SELECT cameras.roi FROM cameras"
        " WHERE cameras.id = air_calibration_cameras.camera_id)"
    )


def downgrade() -> None:
    with op.batch_alter_table('air_calibration_cameras', schema=None) as batch_op:
        batch_op.drop_column('roi')
