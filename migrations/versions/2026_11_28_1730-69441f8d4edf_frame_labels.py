"""Frame labels

Revision ID: 69441f8d4edf
Revises: 6afd06df7729
Create Date: 2026-11-28 17:30:13.254709

What the farm says its panel frames show: an operator's labels of the frames the fleet model
doubted.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

import app.platform.db.base


revision: str = '69441f8d4edf'
down_revision: str | None = '6afd06df7729'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('frame_labels',
    sa.Column('frame_id', sa.String(length=36), nullable=False),
    sa.Column('label', sa.String(length=16), nullable=False),
    sa.Column('source', sa.String(length=16), nullable=False),
    sa.Column('labelled_at', app.platform.db.base.UTCDateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['frame_id'], ['frames.id'], name=op.f('fk_frame_labels_frame_id_frames')),
    sa.PrimaryKeyConstraint('frame_id', name=op.f('pk_frame_labels'))
    )
    with op.batch_alter_table('frame_labels', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_frame_labels_labelled_at'), ['labelled_at'], unique=False)



def downgrade() -> None:
    with op.batch_alter_table('frame_labels', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_frame_labels_labelled_at'))

    op.drop_table('frame_labels')
