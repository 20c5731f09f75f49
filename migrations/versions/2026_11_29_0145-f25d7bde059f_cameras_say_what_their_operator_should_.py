"""Cameras say what their operator should do

Revision ID: f25d7bde059f
Revises: 21d32fcedfab
Create Date: 2026-11-29 01:45:23.595105

Null for every camera until a domain asks something of it ("recalibrate: …").
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = 'f25d7bde059f'
down_revision: str | None = '21d32fcedfab'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('cameras', schema=None) as batch_op:
        batch_op.add_column(sa.Column('attention', sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('cameras', schema=None) as batch_op:
        batch_op.drop_column('attention')
