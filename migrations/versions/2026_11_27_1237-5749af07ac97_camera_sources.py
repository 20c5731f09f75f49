"""Camera sources: streams and snapshot URLs the service pulls frames from

Revision ID: 5749af07ac97
Revises: c00404936905
Create Date: 2026-11-27 12:37:41.782154
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

import app.platform.db.base


revision: str = '5749af07ac97'
down_revision: str | None = 'c00404936905'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('camera_sources',
    sa.Column('camera_id', sa.String(length=64), nullable=False),
    sa.Column('url', sa.String(length=2048), nullable=False),
    sa.Column('every_seconds', sa.Integer(), nullable=False),
    sa.Column('username', sa.String(length=200), nullable=True),
    sa.Column('password', sa.String(length=200), nullable=True),
    sa.Column('state', sa.String(length=16), nullable=False),
    sa.Column('failures', sa.Integer(), nullable=False),
    sa.Column('last_error', sa.String(length=500), nullable=True),
    sa.Column('last_error_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=True),
    sa.Column('last_frame_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=True),
    sa.Column('last_frame_id', sa.String(length=36), nullable=True),
    sa.Column('next_due_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=False),
    sa.Column('lease_owner', sa.String(length=64), nullable=True),
    sa.Column('lease_expires_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=True),
    sa.ForeignKeyConstraint(['camera_id'], ['cameras.id'], name=op.f('fk_camera_sources_camera_id_cameras')),
    sa.PrimaryKeyConstraint('camera_id', name=op.f('pk_camera_sources'))
    )
    with op.batch_alter_table('camera_sources', schema=None) as batch_op:
        batch_op.create_index('ix_camera_sources_next_due_at', ['next_due_at'], unique=False)



def downgrade() -> None:
    with op.batch_alter_table('camera_sources', schema=None) as batch_op:
        batch_op.drop_index('ix_camera_sources_next_due_at')

    op.drop_table('camera_sources')
