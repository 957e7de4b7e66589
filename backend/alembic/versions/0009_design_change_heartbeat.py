"""design_changes.heartbeat_at: a running design-change job's worker proves itself alive, and a job whose
heartbeat stopped is queued again (before: a job running longer than requeue_queued_after_s was)

Revision ID: 0009
Revises: 0008
Create Date: 2026-11-27
"""
from __future__ import annotations

import sqlalchemy as sa
from alembic import op

import backend.models.base

revision = '0009'
down_revision = '0008'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('design_changes', schema=None) as batch_op:
        batch_op.add_column(sa.Column('heartbeat_at', backend.models.base.UTCDateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('design_changes', schema=None) as batch_op:
        batch_op.drop_column('heartbeat_at')
