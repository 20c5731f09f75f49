"""Reference stations and their readings

Revision ID: 21d32fcedfab
Revises: d95e23710f3e
Create Date: 2026-11-29 01:37:01.224519
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

import app.platform.db.base


revision: str = '21d32fcedfab'
down_revision: str | None = 'd95e23710f3e'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('air_stations',
    sa.Column('id', sa.String(length=64), nullable=False),
    sa.Column('name', sa.String(length=200), nullable=True),
    sa.Column('lat', sa.Float(), nullable=False),
    sa.Column('lon', sa.Float(), nullable=False),
    sa.Column('created_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=False),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_air_stations'))
    )
    op.create_table('air_station_readings',
    sa.Column('station_id', sa.String(length=64), nullable=False),
    sa.Column('at', app.platform.db.base.UTCDateTime(timezone=True), nullable=False),
    sa.Column('pm25', sa.Float(), nullable=False),
    sa.ForeignKeyConstraint(['station_id'], ['air_stations.id'], name=op.f('fk_air_station_readings_station_id_air_stations'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('station_id', 'at', name=op.f('pk_air_station_readings'))
    )

def downgrade() -> None:
    op.drop_table('air_station_readings')
    op.drop_table('air_stations')