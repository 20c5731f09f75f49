"""frames paged newest first across cameras

Revision ID: d79576668f3d
Revises: 5b7e2c9d41f3
Create Date: 2026-11-24 05:38:24.833040
"""

from collections.abc import Sequence

from alembic import op


revision: str = 'd79576668f3d'
down_revision: str | None = '5b7e2c9d41f3'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # built without blocking the frames' writers on PostgreSQL (a month of a city's frames
    # takes a while to index): outside a transaction, CONCURRENTLY
    with op.get_context().autocommit_block():
        op.create_index(
            'ix_frames_captured_at_id',
            'frames',
            ['captured_at', 'id'],
            unique=False,
            postgresql_concurrently=True,
        )


def downgrade() -> None:
    with op.get_context().autocommit_block():
        op.drop_index('ix_frames_captured_at_id', table_name='frames', postgresql_concurrently=True)
