"""site_designs: a site's design surface (the file, content-addressed in storage, the area compared and the
on-grade tolerance) that the design step of every run compares the surveyed surface with

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-27
"""
from __future__ import annotations

import sqlalchemy as sa
from alembic import op

import backend.models.base

revision = '0006'
down_revision = '0005'
branch_labels = None
depends_on = None


def upgrade() -> None:
    dt = backend.models.base.UTCDateTime(timezone=True)
    op.create_table('site_designs',
    sa.Column('site_id', sa.String(length=36), nullable=False),
    sa.Column('filename', sa.String(length=255), nullable=False),
    sa.Column('format', sa.String(length=16), nullable=False),
    sa.Column('sha256', sa.String(length=64), nullable=False),
    sa.Column('size', sa.BigInteger(), nullable=False),
    sa.Column('surface_name', sa.String(length=200), nullable=True),
    sa.Column('described', sa.JSON(), nullable=False),
    sa.Column('area', sa.JSON(), nullable=True),
    sa.Column('tolerance_m', sa.Double(), nullable=False),   # Mapped[float]'s type (PostgreSQL: float8 either way)
    sa.Column('uploaded_by', sa.String(length=36), nullable=True),
    sa.Column('created_at', dt, nullable=False),
    sa.Column('updated_at', dt, nullable=False),
    sa.Column('version', sa.Integer(), nullable=False),
    sa.ForeignKeyConstraint(['site_id'], ['sites.id'], name=op.f('fk_site_designs_site_id_sites'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['uploaded_by'], ['users.id'], name=op.f('fk_site_designs_uploaded_by_users'),
                            ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('site_id', name=op.f('pk_site_designs'))
    )


def downgrade() -> None:
    op.drop_table('site_designs')
