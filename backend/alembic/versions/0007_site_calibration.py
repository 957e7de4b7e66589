"""site_calibrations: a site's calibration (localisation) that the datum step of every run applies unless the
survey or the run gives its own

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-26
"""
from __future__ import annotations

import sqlalchemy as sa
from alembic import op

import backend.models.base

revision = '0007'
down_revision = '0006'
branch_labels = None
depends_on = None


def upgrade() -> None:
    dt = backend.models.base.UTCDateTime(timezone=True)
    op.create_table('site_calibrations',
    sa.Column('site_id', sa.String(length=36), nullable=False),
    sa.Column('document', sa.JSON(), nullable=False),
    sa.Column('source_name', sa.String(length=255), nullable=False),
    sa.Column('set_by', sa.String(length=36), nullable=True),
    sa.Column('created_at', dt, nullable=False),
    sa.Column('updated_at', dt, nullable=False),
    sa.Column('version', sa.Integer(), nullable=False),
    sa.ForeignKeyConstraint(['site_id'], ['sites.id'], name=op.f('fk_site_calibrations_site_id_sites'),
                            ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['set_by'], ['users.id'], name=op.f('fk_site_calibrations_set_by_users'),
                            ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('site_id', name=op.f('pk_site_calibrations'))
    )


def downgrade() -> None:
    op.drop_table('site_calibrations')
