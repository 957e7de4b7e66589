"""surveys.flown_at_source: where the flight time comes from (given by the user, or read from the survey's
data by a run: GNSS solution, DJI MRK, EXIF)

Revision ID: 0004
Revises: 0003
Create Date: 2026-01-15
"""
from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = '0004'
down_revision = '0003'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('surveys', schema=None) as batch_op:
        batch_op.add_column(sa.Column('flown_at_source', sa.String(length=16), nullable=True))
    # dates recorded before this revision were typed in by someone
    op.execute(sa.text("UPDATE surveys SET flown_at_source = 'user' WHERE flown_at IS NOT NULL"))


def downgrade() -> None:
    with op.batch_alter_table('surveys', schema=None) as batch_op:
        batch_op.drop_column('flown_at_source')
