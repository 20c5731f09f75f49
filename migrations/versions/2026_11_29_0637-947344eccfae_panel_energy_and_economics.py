"""Panels' daily energy, the farm's economics, and what opened a cleaning

Revision ID: 947344eccfae
Revises: 788228666834
Create Date: 2026-11-29 06:37:37.218749

Panels gain kwp, tilt and azimuth (null until given); tasks and verdicts say what evidence
opened a cleaning.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

import app.platform.db.base


revision: str = '947344eccfae'
down_revision: str | None = '788228666834'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('solar_economics',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('energy_price_per_kwh', sa.Float(), nullable=False),
    sa.Column('cleaning_cost', sa.Float(), nullable=False),
    sa.Column('cost_per', sa.String(length=8), nullable=False),
    sa.Column('panels_per_visit', sa.Integer(), nullable=False),
    sa.Column('currency', sa.String(length=3), nullable=True),
    sa.Column('trigger', sa.String(length=16), nullable=False),
    sa.Column('updated_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=False),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_solar_economics'))
    )
    op.create_table('panel_energy_days',
    sa.Column('panel_id', sa.String(length=64), nullable=False),
    sa.Column('day', sa.Date(), nullable=False),
    sa.Column('kwh', sa.Float(), nullable=False),
    sa.Column('expected_kwh', sa.Float(), nullable=False),
    sa.Column('expected_from', sa.String(length=8), nullable=False),
    sa.Column('poa_kwh_m2', sa.Float(), nullable=True),
    sa.Column('ghi_kwh_m2', sa.Float(), nullable=True),
    sa.Column('rain_mm', sa.Float(), nullable=True),
    sa.Column('received_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['panel_id'], ['panels.id'], name=op.f('fk_panel_energy_days_panel_id_panels')),
    sa.PrimaryKeyConstraint('panel_id', 'day', name=op.f('pk_panel_energy_days'))
    )
    with op.batch_alter_table('cleaning_tasks', schema=None) as batch_op:
        batch_op.add_column(sa.Column('evidence', sa.String(length=300), nullable=True))

    with op.batch_alter_table('panel_verdicts', schema=None) as batch_op:
        batch_op.add_column(sa.Column('cleaning', sa.String(length=300), nullable=True))

    with op.batch_alter_table('panels', schema=None) as batch_op:
        batch_op.add_column(sa.Column('kwp', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('tilt', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('azimuth', sa.Float(), nullable=True))



def downgrade() -> None:
    with op.batch_alter_table('panels', schema=None) as batch_op:
        batch_op.drop_column('azimuth')
        batch_op.drop_column('tilt')
        batch_op.drop_column('kwp')

    with op.batch_alter_table('panel_verdicts', schema=None) as batch_op:
        batch_op.drop_column('cleaning')

    with op.batch_alter_table('cleaning_tasks', schema=None) as batch_op:
        batch_op.drop_column('evidence')

    op.drop_table('panel_energy_days')
    op.drop_table('solar_economics')
