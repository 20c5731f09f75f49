"""baselines and panel verdicts say whether their modes are of full-size images; baselines
what dust veil they can detect; fleet models of a kernel and heads for snow and droppings

Rows from before were measured on frames decoded at 1/2-1/8 scale: false, i.e. stale.

Revision ID: deb8c27b961b
Revises: f18c5d78201c
Create Date: 2026-11-27 09:27:34.304708
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = 'deb8c27b961b'
down_revision: str | None = 'f18c5d78201c'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('baselines', schema=None) as batch_op:
        batch_op.add_column(sa.Column('full_resolution', sa.Boolean(), server_default=sa.false(), nullable=False))
        batch_op.add_column(sa.Column('detectable_veil', sa.Float(), nullable=True))

    with op.batch_alter_table('panel_verdicts', schema=None) as batch_op:
        batch_op.add_column(sa.Column('full_resolution', sa.Boolean(), server_default=sa.false(), nullable=False))
        batch_op.add_column(sa.Column('condition', sa.String(length=16), nullable=True))

    with op.batch_alter_table('fleet_models', schema=None) as batch_op:
        batch_op.add_column(sa.Column('kernel', sa.JSON(), nullable=True))
        batch_op.add_column(sa.Column('heads', sa.JSON(), nullable=True))
        batch_op.add_column(sa.Column('n_snow', sa.Integer(), server_default='0', nullable=False))
        batch_op.add_column(sa.Column('n_bird_drop', sa.Integer(), server_default='0', nullable=False))



def downgrade() -> None:
    with op.batch_alter_table('fleet_models', schema=None) as batch_op:
        batch_op.drop_column('n_bird_drop')
        batch_op.drop_column('n_snow')
        batch_op.drop_column('heads')
        batch_op.drop_column('kernel')

    with op.batch_alter_table('panel_verdicts', schema=None) as batch_op:
        batch_op.drop_column('condition')
        batch_op.drop_column('full_resolution')

    with op.batch_alter_table('baselines', schema=None) as batch_op:
        batch_op.drop_column('detectable_veil')
        batch_op.drop_column('full_resolution')

