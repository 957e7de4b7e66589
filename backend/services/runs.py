"""Processing runs as seen from the API: plan and start, cancel, re-run from a step, read state and logs.

The job state lives in the database (runs + run_steps); the worker advances it one step at a time
(services/jobs.py). Starting a run commits the rows, then sends the first step to the broker."""

from __future__ import annotations

import hashlib
import json

from sqlalchemy import func, select, update

from ..core.problems import Conflict, NotFound, Unprocessable
from ..models import Run, RunLog, RunStep, Survey
from ..models.base import utcnow
from . import steps_catalog
from .context import Ctx
from .pagination import Page, paginate
from .permissions import require_run, require_survey
from .surveys import survey_files, validate_settings

TERMINAL_RUN_STATES = ("succeeded", "failed", "cancelled")
TERMINAL_STEP_STATES = ("succeeded", "skipped", "failed", "cancelled", "unavailable")


def canonical_json(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def settings_hash(settings: dict) -> str:
    return hashlib.sha256(canonical_json(settings).encode()).hexdigest()


def merge_settings(base: dict, override: dict | None) -> dict:
    out = {k: dict(v) for k, v in (base or {}).items()}
    for k, v in (override or {}).items():
        out.setdefault(k, {}).update(v)
    return out


def add_log(db, run_id: str, message: str, step: str | None = None, level: str = "info") -> None:
    db.add(RunLog(run_id=run_id, step_name=step, message=message[:20000], level=level))


def create_run(ctx: Ctx, survey_id: str, steps: list[str] | None = None, settings: dict | None = None,
               trigger: str = "manual", parent: Run | None = None, from_step: str | None = None,
               check_role: bool = True) -> Run:
    survey = require_survey(ctx, survey_id, "editor") if check_role else ctx.db.get(Survey, survey_id)
    try:
        planned = steps_catalog.plan(steps)
    except ValueError as exc:
        raise Unprocessable(f"steps: {exc}") from None
    if from_step is not None and from_step not in planned:
        raise Unprocessable(f"from_step: {from_step!r} is not among the run's steps ({', '.join(planned)})")
    base_settings = parent.settings if parent is not None else survey.settings
    merged = merge_settings(base_settings, validate_settings(settings))
    files = survey_files(ctx.db, survey_id)
    if not files:
        raise Conflict("the survey has no file yet: upload its data first")
    previous = ctx.db.scalar(select(Run).where(Run.survey_id == survey_id, Run.state == "succeeded")
                             .order_by(Run.number.desc()).limit(1))
    number = (ctx.db.scalar(select(func.max(Run.number)).where(Run.survey_id == survey_id)) or 0) + 1
    run = Run(survey_id=survey_id, site_id=survey.site_id, number=number, state="queued", trigger=trigger,
              parent_run_id=parent.id if parent else None, previous_run_id=previous.id if previous else None,
              from_step=from_step, steps=planned, settings=merged, settings_hash=settings_hash(merged),
              inputs={f.path: f.sha256 for f in files},
              created_by=ctx.principal.user.id if ctx.principal else None)
    ctx.db.add(run)
    ctx.db.flush()
    forced = False
    for i, name in enumerate(planned):
        forced = forced or (name == from_step)
        ctx.db.add(RunStep(run_id=run.id, name=name, position=i, force=forced,
                           state="queued" if i == 0 else "pending", queued_at=utcnow() if i == 0 else None))
    add_log(ctx.db, run.id, f"run {number} created ({trigger}): steps {', '.join(planned)}"
            + (f", recomputing from {from_step}" if from_step else ""))
    ctx.db.flush()
    ctx.outbox.append(("step", run.id, planned[0]))
    return run


def list_runs(ctx: Ctx, survey_id: str, state: str | None, limit: int, offset: int) -> Page:
    require_survey(ctx, survey_id, "viewer")
    stmt = select(Run).where(Run.survey_id == survey_id)
    if state:
        stmt = stmt.where(Run.state == state)
    return paginate(ctx, stmt.order_by(Run.number.desc()), limit, offset)


def run_steps(db, run_id: str) -> list[RunStep]:
    """The run's steps in order, each with ``parts``: the parts of a step that runs on several workers
    (RunStepPart rows in index order; empty for a step that runs on one)."""
    from ..models import RunStepPart

    steps = list(db.scalars(select(RunStep).where(RunStep.run_id == run_id).order_by(RunStep.position)))
    parts: dict[str, list] = {}
    for p in db.scalars(select(RunStepPart).where(RunStepPart.run_id == run_id).order_by(RunStepPart.index)):
        parts.setdefault(p.run_step_id, []).append(p)
    for st in steps:
        st.parts = parts.get(st.id, [])
    return steps


def get_run(ctx: Ctx, run_id: str) -> tuple[Run, list[RunStep]]:
    run = require_run(ctx, run_id, "viewer")
    return run, run_steps(ctx.db, run_id)


def cancel_run(ctx: Ctx, run_id: str) -> Run:
    run = require_run(ctx, run_id, "editor")
    if run.state in TERMINAL_RUN_STATES:
        raise Conflict(f"run already {run.state}")
    ctx.db.execute(update(Run).where(Run.id == run_id).values(cancel_requested=True, version=Run.version + 1))
    # steps not yet claimed are cancelled right away; a running step stops at its next progress report
    ctx.db.execute(update(RunStep).where(RunStep.run_id == run_id, RunStep.state.in_(("pending", "queued")))
                   .values(state="cancelled", finished_at=utcnow(), error="cancelled by the user"))
    running = ctx.db.scalar(select(func.count()).select_from(RunStep)
                            .where(RunStep.run_id == run_id, RunStep.state == "running"))
    if not running:
        ctx.db.execute(update(Run).where(Run.id == run_id, Run.state.in_(("queued", "running")))
                       .values(state="cancelled", finished_at=utcnow()))
    add_log(ctx.db, run_id, f"cancel requested by {ctx.user.email}", level="warning")
    ctx.db.flush()
    ctx.db.refresh(run)
    return run


def rerun(ctx: Ctx, run_id: str, from_step: str, settings: dict | None) -> Run:
    parent = require_run(ctx, run_id, "editor")
    if from_step not in steps_catalog.ORDER:
        raise Unprocessable(f"from_step: one of {', '.join(steps_catalog.ORDER)}")
    steps = list(parent.steps)
    if from_step not in steps:
        steps = steps_catalog.plan(steps + [from_step])
    return create_run(ctx, parent.survey_id, steps, settings, trigger="rerun", parent=parent, from_step=from_step)


def list_logs(ctx: Ctx, run_id: str, after_id: int, limit: int, offset: int = 0, step: str | None = None) -> Page:
    """A page of the run's log in order (the list endpoints' pagination); ``after_id`` keeps only the lines
    after that one (what a client that has the earlier lines asks for)."""
    require_run(ctx, run_id, "viewer")
    stmt = select(RunLog).where(RunLog.run_id == run_id, RunLog.id > after_id)
    if step:
        stmt = stmt.where(RunLog.step_name == step)
    return paginate(ctx, stmt.order_by(RunLog.id), limit, offset)


def logs_after(db, run_id: str, after_id: int, limit: int = 500, step: str | None = None) -> list[RunLog]:
    stmt = select(RunLog).where(RunLog.run_id == run_id, RunLog.id > after_id)
    if step:
        stmt = stmt.where(RunLog.step_name == step)
    return list(db.scalars(stmt.order_by(RunLog.id).limit(max(1, min(limit, 5000)))))


def get_changes(ctx: Ctx, run_id: str) -> dict:
    run = require_run(ctx, run_id, "viewer")
    if run.changes is None:
        if run.state not in TERMINAL_RUN_STATES:
            raise Conflict("the run has not finished; changes are computed when it ends")
        raise NotFound("no comparison recorded for this run")
    return run.changes
