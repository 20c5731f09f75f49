"""whether a verdict's frame was usable (the quality gate's finding)

Rows from before say it only in their reason: those whose reason is one of the quality gate's
(too dark, blank, glare, greyscale, occluded) are marked unusable; the others stay usable.

Revision ID: 5b7e2c9d41f3
Revises: 83094b1d8bb0
Create Date: 2026-11-24 03:30:00.000000
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = '5b7e2c9d41f3'
down_revision: str | None = '83094b1d8bb0'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

QUALITY_REASONS = (  # how app/core/quality.py began each reason when this was written
    'too dark to judge%',
    'blank frame:%',
    'glare:%',
    'greyscale frame%',
    'occluded:%',
)


def upgrade() -> None:
    with op.batch_alter_table('verdicts', schema=None) as batch_op:
        batch_op.add_column(sa.Column('usable', sa.Boolean(), server_default=sa.true(), nullable=False))

    verdicts = sa.table('verdicts', sa.column('reason', sa.String), sa.column('usable', sa.Boolean))
    op.execute(
        verdicts.update()
        .where(sa.or_(*(verdicts.c.reason.like(p) for p in QUALITY_REASONS)))
        .values(usable=False)
    )


def downgrade() -> None:
    with op.batch_alter_table('verdicts', schema=None) as batch_op:
        batch_op.drop_column('usable')
