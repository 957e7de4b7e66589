"""The job state machine the worker drives, all in short transactions with atomic claims.

A step is claimed by `UPDATE run_steps SET state='running', attempt=attempt+1 ... WHERE state='queued'`:
exactly one worker wins. Its attempt number is a fencing token: heartbeats, progress and the final
write all say `WHERE attempt = <mine> AND state = 'running'`, so a worker presumed dead (and replaced)
cannot record anything once its step was taken over. Outputs are recorded in the same transaction
that marks the step done, so a crash never leaves half a result; the next step is queued in that
transaction and sent to the broker after the commit."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta

from sqlalchemy import delete, select, update

from ..db.session import Database
from ..models import Run, RunOutput, RunStep, Schedule, Survey, VolumeMeasurement
from ..models.base import utcnow
from . import steps_catalog
from .runs import TERMINAL_STEP_STATES, add_log


@dataclass
class Claim:
    step_id: str
    run_id: str
    step: str
    attempt: int
    force: bool
    survey_id: str
    site_id: str
    worker: str


def claim_step(db: Database, run_id: str, step: str, worker: str) -> Claim | str:
    """The claim, or a word saying why there is nothing to do ('succeeded', 'running', 'cancelled', ...)."""
    now = utcnow()
    with db.session() as s:
        row = s.execute(
            update(RunStep).where(RunStep.run_id == run_id, RunStep.name == step, RunStep.state == "queued")
            .values(state="running", attempt=RunStep.attempt + 1, worker=worker, started_at=now, heartbeat_at=now,
                    finished_at=None, error=None, progress_stage="starting", progress_done=0, progress_total=0)
            .returning(RunStep.id, RunStep.attempt, RunStep.force)).first()
        if row is None:
            st = s.scalar(select(RunStep.state).where(RunStep.run_id == run_id, RunStep.name == step))
            return st or "missing"
        run = s.get(Run, run_id)
        if run.cancel_requested:
            s.execute(update(RunStep).where(RunStep.id == row.id).values(state="cancelled", finished_at=now,
                                                                        error="cancelled by the user"))
            _end_run(s, run, "cancelled", None)
            return "cancelled"
        s.execute(update(Run).where(Run.id == run_id, Run.state == "queued")
                  .values(state="running", started_at=now, version=Run.version + 1))
        add_log(s, run_id, f"step {step} started on {worker} (attempt {row.attempt})", step)
        return Claim(row.id, run_id, step, row.attempt, row.force, run.survey_id, run.site_id, worker)


def heartbeat(db: Database, claim: Claim) -> bool:
    """Still ours? (False once another worker took the step over.)"""
    with db.session() as s:
        n = s.execute(update(RunStep).where(RunStep.id == claim.step_id, RunStep.attempt == claim.attempt,
                                            RunStep.state == "running").values(heartbeat_at=utcnow())).rowcount
        return n == 1


def report_progress(db: Database, claim: Claim, stage: str, done: int, total: int) -> tuple[bool, bool]:
    """(still ours, cancel requested)."""
    with db.session() as s:
        n = s.execute(update(RunStep).where(RunStep.id == claim.step_id, RunStep.attempt == claim.attempt,
                                            RunStep.state == "running")
                      .values(progress_stage=stage[:200], progress_done=int(done), progress_total=int(total),
                              heartbeat_at=utcnow())).rowcount
        cancel = bool(s.scalar(select(Run.cancel_requested).where(Run.id == claim.run_id)))
        return n == 1, cancel


def log(db: Database, run_id: str, message: str, step: str | None = None, level: str = "info") -> None:
    with db.session() as s:
        add_log(s, run_id, message, step, level)


def run_context(db: Database, run_id: str) -> dict:
    """What a step needs to know about its run: settings, inputs, earlier outputs."""
    from ..models import Site, Stockpile

    with db.session(read_only=True) as s:
        run = s.get(Run, run_id)
        site = s.get(Site, run.site_id)
        survey = s.get(Survey, run.survey_id)
        outputs = list(s.scalars(select(RunOutput).where(RunOutput.run_id == run_id)))
        piles = list(s.scalars(select(Stockpile).where(Stockpile.site_id == run.site_id).order_by(Stockpile.name)))
        steps = list(s.scalars(select(RunStep).where(RunStep.run_id == run_id).order_by(RunStep.position)))
        return {"run_id": run.id, "survey_id": run.survey_id, "site_id": run.site_id, "settings": run.settings,
                "inputs": dict(run.inputs), "steps": list(run.steps), "number": run.number,
                "previous_run_id": run.previous_run_id,
                "site": {"name": site.name, "crs": site.crs, "vertical_datum": site.vertical_datum, "geoid": site.geoid},
                "survey": {"name": survey.name, "flown_at": survey.flown_at.isoformat() if survey.flown_at else None,
                           "flown_at_source": survey.flown_at_source},
                "stockpiles": [{"id": p.id, "name": p.name, "outline": p.outline, "base": p.base} for p in piles],
                "step_states": [{"name": st.name, "state": st.state, "error": st.error} for st in steps],
                "outputs": [{"step": o.step_name, "path": o.path, "sha256": o.sha256, "size": o.size} for o in outputs]}


def volumes_of_run(db: Database, run_id: str, with_material: bool = False) -> list[dict]:
    """The run's volume rows (as finish_step stores them); ``with_material``: each with its stockpile's
    material too (the report shows it; not a column of the measurement)."""
    from ..models import Stockpile

    with db.session(read_only=True) as s:
        rows = list(s.scalars(select(VolumeMeasurement).where(VolumeMeasurement.run_id == run_id)))
        out = [{"stockpile_id": v.stockpile_id, "stockpile_name": v.stockpile_name, "base": v.base,
                "volume_m3": v.volume_m3, "fill_m3": v.fill_m3, "cut_m3": v.cut_m3, "area_m2": v.area_m2,
                "details": v.details} for v in rows]
        if with_material:
            ids = [v["stockpile_id"] for v in out if v["stockpile_id"]]
            materials = dict(s.execute(select(Stockpile.id, Stockpile.material).where(Stockpile.id.in_(ids))).all()) \
                if ids else {}
            for v in out:
                v["material"] = materials.get(v["stockpile_id"]) or ""
        return out


def record_flight_time(s, survey_id: str, flight_time) -> None:
    """The flight time a step read from the survey's data (summary ``flight_time``: start, source) becomes the
    survey's ``flown_at`` unless someone gave one; the survey's volume measurements follow it."""
    from datetime import datetime

    from .surveys import set_flown_at

    if not isinstance(flight_time, dict) or not isinstance(flight_time.get("start"), str):
        return
    survey = s.get(Survey, survey_id)
    if survey is None or survey.flown_at_source == "user" or (survey.flown_at and survey.flown_at_source is None):
        return
    try:
        start = datetime.fromisoformat(flight_time["start"].replace("Z", "+00:00"))
    except ValueError:
        return
    source = str(flight_time.get("source") or "data")[:16]
    if survey.flown_at != start or survey.flown_at_source != source:
        set_flown_at(s, survey, start, source)


def find_reusable(db: Database, survey_id: str, step: str, input_hash: str, run_id: str):
    """An earlier finished step of the same survey with the same input hash: (step id, summary, outputs,
    run id)."""
    with db.session(read_only=True) as s:
        prev = s.execute(
            select(RunStep.id, RunStep.run_id, RunStep.summary).join(Run, Run.id == RunStep.run_id)
            .where(Run.survey_id == survey_id, RunStep.name == step, RunStep.input_hash == input_hash,
                   RunStep.state == "succeeded", RunStep.run_id != run_id)
            .order_by(RunStep.finished_at.desc()).limit(1)).first()
        if prev is None:
            return None
        outs = list(s.scalars(select(RunOutput).where(RunOutput.run_id == prev.run_id, RunOutput.step_name == step)))
        return prev.id, prev.summary, [(o.path, o.sha256, o.size) for o in outs], prev.run_id


def finish_step(db: Database, claim: Claim, input_hash: str, outputs: list[tuple[str, str, int]], summary: dict,
                reused_from: str | None = None, volumes: list[dict] | None = None,
                storage=None) -> tuple[bool, list[tuple]]:
    """Record the outputs and mark the step done, queue the next; (recorded, messages to send). With the
    storage, a run that ends here gets its comparison with the previous run in the same transaction."""
    now = utcnow()
    # a step with nothing to do (the GNSS step of a survey of photos alone) ends "skipped" with its reason
    nothing_to_do = not reused_from and isinstance(summary, dict) and summary.get("skipped") is True
    with db.session() as s:
        n = s.execute(update(RunStep).where(RunStep.id == claim.step_id, RunStep.attempt == claim.attempt,
                                            RunStep.state == "running")
                      .values(state="skipped" if reused_from or nothing_to_do else "succeeded", finished_at=now,
                              heartbeat_at=now,
                              input_hash=input_hash, summary=summary, reused_from_step_id=reused_from,
                              progress_stage="done", error=None)).rowcount
        if n != 1:
            return False, []
        s.execute(delete(RunOutput).where(RunOutput.run_id == claim.run_id, RunOutput.step_name == claim.step))
        # a file an earlier step wrote and this one rewrote now belongs to this step
        s.execute(delete(RunOutput).where(RunOutput.run_id == claim.run_id,
                                          RunOutput.path.in_([o[0] for o in outputs])))
        if isinstance(summary, dict) and summary.get("flight_time"):
            record_flight_time(s, claim.survey_id, summary["flight_time"])
        if volumes is not None:
            s.execute(delete(VolumeMeasurement).where(VolumeMeasurement.run_id == claim.run_id))
            run = s.get(Run, claim.run_id)
            survey = s.get(Survey, run.survey_id)
            for v in volumes:
                s.add(VolumeMeasurement(run_id=run.id, survey_id=run.survey_id, site_id=run.site_id,
                                        measured_at=survey.flown_at or run.created_at, **v))
        for path, sha, size in outputs:
            s.add(RunOutput(run_id=claim.run_id, step_name=claim.step, path=path, sha256=sha, size=size))
        if nothing_to_do:
            add_log(s, claim.run_id, f"step {claim.step} skipped: {summary.get('reason') or 'nothing to do'}",
                    claim.step, "warning")
        else:
            add_log(s, claim.run_id, (f"step {claim.step} reused identical earlier result ({len(outputs)} files)"
                                      if reused_from else f"step {claim.step} done: {len(outputs)} output files"),
                    claim.step)
        s.flush()
        return True, _advance(s, claim.run_id, storage)


def mark_unavailable(db: Database, claim: Claim, reason: str, storage=None) -> tuple[bool, list[tuple]]:
    with db.session() as s:
        n = s.execute(update(RunStep).where(RunStep.id == claim.step_id, RunStep.attempt == claim.attempt,
                                            RunStep.state == "running")
                      .values(state="unavailable", finished_at=utcnow(), error=reason)).rowcount
        if n != 1:
            return False, []
        add_log(s, claim.run_id, f"step {claim.step} skipped: {reason}", claim.step, "warning")
        s.flush()
        return True, _advance(s, claim.run_id, storage)


def fail_step(db: Database, claim: Claim, reason: str, cancelled: bool = False) -> tuple[bool, list[tuple]]:
    now = utcnow()
    with db.session() as s:
        n = s.execute(update(RunStep).where(RunStep.id == claim.step_id, RunStep.attempt == claim.attempt,
                                            RunStep.state == "running")
                      .values(state="cancelled" if cancelled else "failed", finished_at=now, error=reason)).rowcount
        if n != 1:
            return False, []
        s.execute(update(RunStep).where(RunStep.run_id == claim.run_id, RunStep.state.in_(("pending", "queued")))
                  .values(state="cancelled", finished_at=now,
                          error="cancelled by the user" if cancelled else f"not run: step {claim.step} failed"))
        add_log(s, claim.run_id, f"step {claim.step} {'cancelled' if cancelled else 'failed'}: {reason}", claim.step,
                "warning" if cancelled else "error")
        run = s.get(Run, claim.run_id)
        return True, _end_run(s, run, "cancelled" if cancelled else "failed",
                              None if cancelled else f"step {claim.step} failed: {reason}")


def fail_unclaimed_step(db: Database, run_id: str, step: str, reason: str) -> list[tuple]:
    """Fail a step that is queued (e.g. after giving up on transient errors) and its run."""
    with db.session() as s:
        n = s.execute(update(RunStep).where(RunStep.run_id == run_id, RunStep.name == step,
                                            RunStep.state.in_(("queued", "running")))
                      .values(state="failed", finished_at=utcnow(), error=reason)).rowcount
        if n != 1:
            return []
        s.execute(update(RunStep).where(RunStep.run_id == run_id, RunStep.state.in_(("pending", "queued")))
                  .values(state="cancelled", finished_at=utcnow(), error=f"not run: step {step} failed"))
        add_log(s, run_id, f"step {step} failed: {reason}", step, "error")
        return _end_run(s, s.get(Run, run_id), "failed", f"step {step} failed: {reason}")


def release_step(db: Database, claim: Claim, reason: str) -> list[tuple]:
    """Give a claimed step back to the queue (transient error; it will be retried)."""
    with db.session() as s:
        n = s.execute(update(RunStep).where(RunStep.id == claim.step_id, RunStep.attempt == claim.attempt,
                                            RunStep.state == "running")
                      .values(state="queued", queued_at=utcnow(), error=f"retrying after: {reason}")).rowcount
        if n == 1:
            add_log(s, claim.run_id, f"step {claim.step}: transient error, retrying ({reason})", claim.step, "warning")
        return []


def _advance(s, run_id: str, storage=None) -> list[tuple]:
    """Queue the next pending step (marking those whose dependency is unavailable), or end the run."""
    steps = list(s.scalars(select(RunStep).where(RunStep.run_id == run_id).order_by(RunStep.position)))
    state = {st.name: st.state for st in steps}
    for st in steps:
        if st.state in ("queued", "running"):
            return []
        if st.state != "pending":
            continue
        missing = [d for d in steps_catalog.BY_NAME[st.name].depends_on
                   if state.get(d) in ("unavailable",) or d not in state]
        if missing:
            st.state, st.finished_at = "unavailable", utcnow()
            st.error = f"needs step {missing[0]}, which did not run"
            state[st.name] = "unavailable"
            add_log(s, run_id, f"step {st.name} skipped: {st.error}", st.name, "warning")
            continue
        st.state, st.queued_at = "queued", utcnow()
        return [("step", run_id, st.name)]
    run = s.get(Run, run_id)
    if all(st.state in TERMINAL_STEP_STATES for st in steps):
        return _end_run(s, run, "succeeded", None, storage)
    return []


def _end_run(s, run: Run, state: str, error: str | None, storage=None) -> list[tuple]:
    """End the run. A successful one gets its comparison in the same transaction when the storage is
    given: a client that sees 'succeeded' finds the changes too (GET /runs/{id}/changes)."""
    n = s.execute(update(Run).where(Run.id == run.id, Run.state.in_(("queued", "running")))
                  .values(state=state, error=error, finished_at=utcnow(), version=Run.version + 1)).rowcount
    if n != 1:
        return []
    if state == "succeeded" and storage is not None:
        from .changes import record_changes

        s.refresh(run)
        record_changes(s, storage, run)
    add_log(s, run.id, f"run {state}" + (f": {error}" if error else ""), None, "error" if state == "failed" else "info")
    if run.trigger in ("schedule", "new-data"):
        s.execute(update(Schedule).where(Schedule.site_id == run.site_id).values(last_run_at=utcnow()))
    return [("run-finished", run.id)]


def reap(db: Database, lease_s: float, requeue_queued_after_s: float) -> list[tuple]:
    """Steps whose worker stopped sending heartbeats go back to the queue; queued steps whose message
    may have been lost (broker down when sent) are sent again. Both are safe: the claim is atomic."""
    now = utcnow()
    out: list[tuple] = []
    with db.session() as s:
        stale = now - timedelta(seconds=lease_s)
        rows = s.execute(update(RunStep).where(RunStep.state == "running", RunStep.heartbeat_at < stale)
                         .values(state="queued", queued_at=now, worker=None,
                                 error="worker stopped responding; step restarted")
                         .returning(RunStep.run_id, RunStep.name)).all()
        for r in rows:
            add_log(s, r.run_id, f"step {r.name}: no heartbeat for {lease_s:.0f} s, restarting it on another worker",
                    r.name, "warning")
            out.append(("step", r.run_id, r.name))
        old = now - timedelta(seconds=requeue_queued_after_s)
        rows = s.execute(update(RunStep).where(RunStep.state == "queued", RunStep.queued_at < old)
                         .values(queued_at=now).returning(RunStep.run_id, RunStep.name)).all()
        out.extend(("step", r.run_id, r.name) for r in rows)
    return out
