"""Uncertain sky verdicts keep the categories their interval spans

Revision ID: f5b46379f5d2
Revises: 48aea2ca1893
Create Date: 2026-11-28 07:24:14.441048

Verdicts graded before it keep no span: they say "not sure" without naming the categories
until re-graded (POST /air/cameras/{id}/regrade).
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = 'f5b46379f5d2'
down_revision: str | None = '48aea2ca1893'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('sky_verdicts', schema=None) as batch_op:
        batch_op.add_column(sa.Column('span', sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('sky_verdicts', schema=None) as batch_op:
        batch_op.drop_column('span')
