"""design_changes: the change between two surveys of a site's design, computed by a worker and stored (the API
no longer computes it in the request)

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-26
"""
from __future__ import annotations

import sqlalchemy as sa
from alembic import op

import backend.models.base

revision = '0008'
down_revision = '0007'
branch_labels = None
depends_on = None


def upgrade() -> None:
    dt = backend.models.base.UTCDateTime(timezone=True)
    op.create_table('design_changes',
    sa.Column('site_id', sa.String(length=36), nullable=False),
    sa.Column('key', sa.String(length=64), nullable=False),
    sa.Column('earlier_run_id', sa.String(length=36), nullable=False),
    sa.Column('later_run_id', sa.String(length=36), nullable=False),
    sa.Column('inputs', sa.JSON(), nullable=False),
    sa.Column('state', sa.String(length=16), nullable=False),
    sa.Column('attempt', sa.Integer(), nullable=False),
    sa.Column('worker', sa.String(length=200), nullable=True),
    sa.Column('result', sa.JSON(), nullable=True),
    sa.Column('error', sa.Text(), nullable=True),
    sa.Column('queued_at', dt, nullable=False),
    sa.Column('started_at', dt, nullable=True),
    sa.Column('finished_at', dt, nullable=True),
    sa.Column('id', sa.String(length=36), nullable=False),
    sa.ForeignKeyConstraint(['site_id'], ['sites.id'], name=op.f('fk_design_changes_site_id_sites'),
                            ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['earlier_run_id'], ['runs.id'], name=op.f('fk_design_changes_earlier_run_id_runs'),
                            ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['later_run_id'], ['runs.id'], name=op.f('fk_design_changes_later_run_id_runs'),
                            ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_design_changes')),
    sa.UniqueConstraint('key', name=op.f('uq_design_changes_key'))
    )
    with op.batch_alter_table('design_changes', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_design_changes_site_id'), ['site_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_design_changes_earlier_run_id'), ['earlier_run_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_design_changes_later_run_id'), ['later_run_id'], unique=False)


def downgrade() -> None:
    with op.batch_alter_table('design_changes', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_design_changes_later_run_id'))
        batch_op.drop_index(batch_op.f('ix_design_changes_earlier_run_id'))
        batch_op.drop_index(batch_op.f('ix_design_changes_site_id'))
    op.drop_table('design_changes')
