"""run_step_parts: the parts of a step that runs on several workers (contract.Split), and run_steps.phase
(None, "parts" while its parts run, "merge" once they are all done)

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-26
"""
from __future__ import annotations

import sqlalchemy as sa
from alembic import op

import backend.models.base

revision = '0005'
down_revision = '0004'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('run_steps', schema=None) as batch_op:
        batch_op.add_column(sa.Column('phase', sa.String(length=8), nullable=True))
    dt = backend.models.base.UTCDateTime(timezone=True)
    op.create_table('run_step_parts',
    sa.Column('run_step_id', sa.String(length=36), nullable=False),
    sa.Column('run_id', sa.String(length=36), nullable=False),
    sa.Column('step_name', sa.String(length=32), nullable=False),
    sa.Column('index', sa.Integer(), nullable=False),
    sa.Column('descriptor', sa.JSON(), nullable=False),
    sa.Column('state', sa.String(length=16), nullable=False),
    sa.Column('attempt', sa.Integer(), nullable=False),
    sa.Column('worker', sa.String(length=200), nullable=True),
    sa.Column('queued_at', dt, nullable=True),
    sa.Column('started_at', dt, nullable=True),
    sa.Column('heartbeat_at', dt, nullable=True),
    sa.Column('finished_at', dt, nullable=True),
    sa.Column('progress_stage', sa.String(length=200), nullable=False),
    sa.Column('progress_done', sa.Integer(), nullable=False),
    sa.Column('progress_total', sa.Integer(), nullable=False),
    sa.Column('id', sa.String(length=36), nullable=False),
    sa.ForeignKeyConstraint(['run_step_id'], ['run_steps.id'], name=op.f('fk_run_step_parts_run_step_id_run_steps'),
                            ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['run_id'], ['runs.id'], name=op.f('fk_run_step_parts_run_id_runs'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_run_step_parts')),
    sa.UniqueConstraint('run_step_id', 'index', name=op.f('uq_run_step_parts_run_step_id'))
    )
    with op.batch_alter_table('run_step_parts', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_run_step_parts_run_step_id'), ['run_step_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_run_step_parts_run_id'), ['run_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_run_step_parts_state'), ['state'], unique=False)


def downgrade() -> None:
    with op.batch_alter_table('run_step_parts', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_run_step_parts_state'))
        batch_op.drop_index(batch_op.f('ix_run_step_parts_run_id'))
        batch_op.drop_index(batch_op.f('ix_run_step_parts_run_step_id'))
    op.drop_table('run_step_parts')
    with op.batch_alter_table('run_steps', schema=None) as batch_op:
        batch_op.drop_column('phase')
