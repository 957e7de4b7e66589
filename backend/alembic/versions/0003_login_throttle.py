"""login_throttle: failed password checks per account and per client address (login throttling);
webhook deliveries keep a generic reason only (errors recorded before this revision are replaced)

Revision ID: 0003
Revises: 0002
Create Date: 2025-12-01
"""
from __future__ import annotations

import sqlalchemy as sa
from alembic import op

import backend.models.base

revision = '0003'
down_revision = '0002'
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table('login_throttle',
    sa.Column('key', sa.String(length=80), nullable=False),
    sa.Column('failures', sa.Integer(), nullable=False),
    sa.Column('last_failure_at', backend.models.base.UTCDateTime(timezone=True), nullable=False),
    sa.Column('blocked_until', backend.models.base.UTCDateTime(timezone=True), nullable=True),
    sa.PrimaryKeyConstraint('key', name=op.f('pk_login_throttle'))
    )
    with op.batch_alter_table('login_throttle', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_login_throttle_last_failure_at'), ['last_failure_at'], unique=False)
    # delivery errors used to quote the network error or the receiver's answer (a port scanner's output)
    op.execute(sa.text("UPDATE webhook_deliveries SET last_error = 'delivery failed' WHERE last_error IS NOT NULL"))


def downgrade() -> None:
    with op.batch_alter_table('login_throttle', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_login_throttle_last_failure_at'))
    op.drop_table('login_throttle')
