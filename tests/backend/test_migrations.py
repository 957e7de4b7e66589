"""The migration history and the models describe one schema: a database brought to the head revision
differs from the models in nothing Alembic's autogenerate would write (tables, columns, types, nullability,
indexes, unique and foreign keys); the claim columns a step and a part of a split step share are declared
once (runs.ClaimMixin) and are the same in both tables."""

from __future__ import annotations

import sqlalchemy as sa
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext

from backend.db.migrate import downgrade, upgrade
from backend.models import Base, RunStep, RunStepPart
from backend.models.runs import ClaimMixin


def _diffs(url: str) -> list:
    engine = sa.create_engine(url)
    try:
        with engine.connect() as conn:
            ctx = MigrationContext.configure(conn, opts={"compare_type": True, "render_as_batch": True})
            return compare_metadata(ctx, Base.metadata)
    finally:
        engine.dispose()


def test_head_matches_the_models(tmp_path):
    url = f"sqlite:///{tmp_path / 'schema.db'}"
    upgrade(url)
    assert _diffs(url) == []
    engine = sa.create_engine(url)
    cols = {t: {c["name"]: (str(c["type"]), c["nullable"]) for c in sa.inspect(engine).get_columns(t)}
            for t in ("run_steps", "run_step_parts")}
    engine.dispose()
    # the claim columns a step and a part share (ClaimMixin) are in both tables, with the same types
    shared = set(ClaimMixin.__annotations__)
    assert shared == {"attempt", "worker", "queued_at", "started_at", "heartbeat_at", "finished_at",
                      "progress_stage", "progress_done", "progress_total"}
    for name in shared:
        assert cols["run_steps"][name] == cols["run_step_parts"][name], name
        assert name in RunStep.__table__.c and name in RunStepPart.__table__.c
    # the check does see a difference: the database taken back to the revision before the step parts
    downgrade(url, "0004")
    assert any("run_step_parts" in repr(d) for d in _diffs(url))
