"""The job state machine the worker drives, all in short transactions with atomic claims.

A step is claimed by `UPDATE run_steps SET state='running', attempt=attempt+1 ... WHERE state='queued'`:
exactly one worker wins. Its attempt number is a fencing token: heartbeats, progress and the final
write all say `WHERE attempt = <mine> AND state = 'running'`, so a worker presumed dead (and replaced)
cannot record anything once its step was taken over. Outputs are recorded in the same transaction
that marks the step done, so a crash never leaves half a result; the next step is queued in that
transaction and sent to the broker after the commit.

A step that can run as parts (contract.Split) is planned under its claim; `start_parts` records the plan's
files and one RunStepPart per part and sets the step's phase to "parts" (the step stays "running"; its
own heartbeat no longer matters, each part has one). Parts are claimed, fenced and reaped like steps. A part
whose descriptor names ``after`` (earlier parts: a second phase, contract.Split) waits in state "waiting"
and is queued when the last of those succeeds. The last part to finish puts the step back in the queue with
phase "merge": the next claim merges, keeping the step's started_at (its plan's claim: the step's time in the API
is plan, parts and merge)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta

from sqlalchemy import and_, case, delete, func, literal, or_, select, update

from georef_core.steps.contract import part_after

from ..db.session import Database
from ..models import Run, RunOutput, RunStep, RunStepPart, Schedule, Survey, VolumeMeasurement
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
    phase: str | None = None     # "merge": the parts of this split step are done, merge them


def _claim_started_at(now):
    """The ``started_at`` a claim writes: the claim's time, except for the merge of a split step, which keeps its
    plan's claim time (a split step is claimed for its plan and again for its merge; its started_at .. finished_at
    is the whole step: plan, parts, merge). A merge claimed again (its worker died) keeps it too; a step claimed
    again before it was split (attempt 2 of its plan) gets the new claim's time."""
    return case((and_(RunStep.phase == "merge", RunStep.started_at.is_not(None)), RunStep.started_at),
                else_=literal(now, RunStep.__table__.c.started_at.type))


def claim_step(db: Database, run_id: str, step: str, worker: str) -> Claim | str:
    """The claim, or a word saying why there is nothing to do ('succeeded', 'running', 'cancelled', ...)."""
    now = utcnow()
    with db.session() as s:
        row = s.execute(
            update(RunStep).where(RunStep.run_id == run_id, RunStep.name == step, RunStep.state == "queued")
            .values(state="running", attempt=RunStep.attempt + 1, worker=worker, started_at=_claim_started_at(now),
                    heartbeat_at=now,
                    finished_at=None, error=None, progress_stage="starting", progress_done=0, progress_total=0)
            .returning(RunStep.id, RunStep.attempt, RunStep.force, RunStep.phase)).first()
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
        add_log(s, run_id, f"step {step} {'merging its parts' if row.phase == 'merge' else 'started'} on {worker} "
                           f"(attempt {row.attempt})", step)
        return Claim(row.id, run_id, step, row.attempt, row.force, run.survey_id, run.site_id, worker, row.phase)


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
    from ..models import Organisation, Site, Stockpile

    with db.session(read_only=True) as s:
        run = s.get(Run, run_id)
        site = s.get(Site, run.site_id)
        org = s.get(Organisation, site.organisation_id)
        survey = s.get(Survey, run.survey_id)
        outputs = list(s.scalars(select(RunOutput).where(RunOutput.run_id == run_id)))
        piles = list(s.scalars(select(Stockpile).where(Stockpile.site_id == run.site_id).order_by(Stockpile.name)))
        steps = list(s.scalars(select(RunStep).where(RunStep.run_id == run_id).order_by(RunStep.position)))
        return {"run_id": run.id, "survey_id": run.survey_id, "site_id": run.site_id, "settings": run.settings,
                "inputs": dict(run.inputs), "steps": list(run.steps), "number": run.number,
                "previous_run_id": run.previous_run_id,
                "site": {"name": site.name, "crs": site.crs, "vertical_datum": site.vertical_datum, "geoid": site.geoid,
                         # the report's cover and verdict
                         "organisation": org.name if org is not None else None,
                         "tolerance_horizontal_m": site.tolerance_horizontal_m,
                         "tolerance_vertical_m": site.tolerance_vertical_m,
                         # the site's calibration: the datum step applies it unless the survey or run gives its own
                         "calibration": _calibration_context(s, run.site_id)},
                "survey": {"name": survey.name, "flown_at": survey.flown_at.isoformat() if survey.flown_at else None,
                           "flown_at_source": survey.flown_at_source},
                "stockpiles": [{"id": p.id, "name": p.name, "outline": p.outline, "base": p.base} for p in piles],
                "design": _design_context(s, run.site_id),
                "step_states": [{"name": st.name, "state": st.state, "error": st.error} for st in steps],
                "outputs": [{"step": o.step_name, "path": o.path, "sha256": o.sha256, "size": o.size} for o in outputs]}


def _calibration_context(s, site_id: str) -> dict | None:
    """The site's calibration for the datum step (services/calibrations.calibration_context)."""
    from .calibrations import calibration_context

    return calibration_context(s, site_id)


def _design_context(s, site_id: str) -> dict | None:
    """The site's design surface for the design step (services/designs.design_context)."""
    from .designs import design_context

    return design_context(s, site_id)


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
            piles = {i: (m, d) for i, m, d in s.execute(select(Stockpile.id, Stockpile.material, Stockpile.density_t_m3)
                                                         .where(Stockpile.id.in_(ids))).all()} if ids else {}
            for v in out:
                material, density = piles.get(v["stockpile_id"], ("", None))
                v["material"] = material or ""
                v["density_t_m3"] = density       # the report's tonnage
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
                              heartbeat_at=now, phase=None,
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
        # a step whose parts run has no heartbeat of its own: its parts are reaped below
        rows = s.execute(update(RunStep).where(RunStep.state == "running", RunStep.heartbeat_at < stale,
                                               or_(RunStep.phase.is_(None), RunStep.phase != "parts"))
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
        rows = s.execute(update(RunStepPart).where(RunStepPart.state == "running", RunStepPart.heartbeat_at < stale)
                         .values(state="queued", queued_at=now, worker=None)
                         .returning(RunStepPart.run_id, RunStepPart.step_name, RunStepPart.index)).all()
        for r in rows:
            add_log(s, r.run_id, f"step {r.step_name} part {r.index}: no heartbeat for {lease_s:.0f} s, restarting it "
                                 "on another worker", r.step_name, "warning")
            out.append(("part", r.run_id, r.step_name, r.index))
        rows = s.execute(update(RunStepPart).where(RunStepPart.state == "queued", RunStepPart.queued_at < old)
                         .values(queued_at=now)
                         .returning(RunStepPart.run_id, RunStepPart.step_name, RunStepPart.index)).all()
        out.extend(("part", r.run_id, r.step_name, r.index) for r in rows)
    return out


# ------------------------------------------------------------------------------------- steps run as parts


@dataclass
class PartClaim:
    part_id: str
    step_id: str
    run_id: str
    step: str
    index: int
    attempt: int
    descriptor: dict
    worker: str


def start_parts(db: Database, claim: Claim, input_hash: str, plan_outputs: list[tuple[str, str, int]],
                parts: list[dict]) -> tuple[bool, list[tuple]]:
    """The planned step goes to its parts: the plan's files recorded (every part gets them), one queued part
    per descriptor, the step's phase "parts"; (recorded, the part messages to send)."""
    now = utcnow()
    with db.session() as s:
        n = s.execute(update(RunStep).where(RunStep.id == claim.step_id, RunStep.attempt == claim.attempt,
                                            RunStep.state == "running")
                      .values(phase="parts", input_hash=input_hash, heartbeat_at=now, progress_stage="parts",
                              progress_done=0, progress_total=len(parts))).rowcount
        if n != 1:
            return False, []
        s.execute(delete(RunStepPart).where(RunStepPart.run_step_id == claim.step_id))
        s.execute(delete(RunOutput).where(RunOutput.run_id == claim.run_id, RunOutput.step_name == claim.step))
        for path, sha, size in plan_outputs:
            s.add(RunOutput(run_id=claim.run_id, step_name=claim.step, path=path, sha256=sha, size=size))
        for k, d in enumerate(parts):
            waits = bool(part_after(d))    # a second-phase part: queued when the parts it reads are done
            s.add(RunStepPart(run_step_id=claim.step_id, run_id=claim.run_id, step_name=claim.step, index=k,
                              descriptor=d, state="waiting" if waits else "queued", attempt=0,
                              queued_at=None if waits else now, progress_stage="", progress_done=0, progress_total=0))
        add_log(s, claim.run_id, f"step {claim.step} split into {len(parts)} parts", claim.step)
        return True, [("part", claim.run_id, claim.step, k) for k in range(len(parts)) if not part_after(parts[k])]


def part_descriptors(db: Database, claim: Claim) -> list[dict]:
    """The parts of a claimed split step, as its plan described them, each with its ``index``."""
    with db.session(read_only=True) as s:
        rows = s.execute(select(RunStepPart.index, RunStepPart.descriptor)
                         .where(RunStepPart.run_step_id == claim.step_id).order_by(RunStepPart.index)).all()
        return [dict(r.descriptor or {}, index=r.index) for r in rows]


def claim_part(db: Database, run_id: str, step: str, index: int, worker: str) -> PartClaim | str:
    """The part's claim, or why there is nothing to do ('succeeded', 'running', 'cancelled', 'step failed' ...).
    A run whose cancellation was asked cancels the step here."""
    now = utcnow()
    with db.session() as s:
        st = s.execute(select(RunStep.id, RunStep.state, RunStep.phase)
                       .where(RunStep.run_id == run_id, RunStep.name == step)).first()
        if st is None:
            return "missing"
        if st.state != "running" or st.phase != "parts":
            return f"step {st.state}"
        if s.scalar(select(Run.cancel_requested).where(Run.id == run_id)):
            _end_split_step(s, run_id, st.id, step, "cancelled by the user", cancelled=True)
            return "cancelled"
        row = s.execute(
            update(RunStepPart).where(RunStepPart.run_step_id == st.id, RunStepPart.index == index,
                                      RunStepPart.state == "queued")
            .values(state="running", attempt=RunStepPart.attempt + 1, worker=worker, started_at=now, heartbeat_at=now,
                    finished_at=None, progress_stage="starting", progress_done=0, progress_total=0)
            .returning(RunStepPart.id, RunStepPart.attempt, RunStepPart.descriptor)).first()
        if row is None:
            return s.scalar(select(RunStepPart.state).where(RunStepPart.run_step_id == st.id,
                                                            RunStepPart.index == index)) or "missing"
        add_log(s, run_id, f"step {step} part {index} started on {worker} (attempt {row.attempt})", step)
        return PartClaim(row.id, st.id, run_id, step, index, row.attempt, dict(row.descriptor or {}), worker)


def _part_is_ours(s, pc: PartClaim):
    return (RunStepPart.id == pc.part_id, RunStepPart.attempt == pc.attempt, RunStepPart.state == "running")


def _step_waits_for_parts(s, pc: PartClaim) -> bool:
    return s.scalar(select(func.count()).select_from(RunStep).where(
        RunStep.id == pc.step_id, RunStep.state == "running", RunStep.phase == "parts")) == 1


def part_heartbeat(db: Database, pc: PartClaim) -> bool:
    """Still ours, and its step still waiting for it?"""
    with db.session() as s:
        n = s.execute(update(RunStepPart).where(*_part_is_ours(s, pc)).values(heartbeat_at=utcnow())).rowcount
        return n == 1 and _step_waits_for_parts(s, pc)


def report_part_progress(db: Database, pc: PartClaim, stage: str, done: int, total: int) -> tuple[bool, bool]:
    """(still ours, cancel requested)."""
    with db.session() as s:
        n = s.execute(update(RunStepPart).where(*_part_is_ours(s, pc))
                      .values(progress_stage=stage[:200], progress_done=int(done), progress_total=int(total),
                              heartbeat_at=utcnow())).rowcount
        cancel = bool(s.scalar(select(Run.cancel_requested).where(Run.id == pc.run_id)))
        return n == 1 and _step_waits_for_parts(s, pc), cancel


def finish_part(db: Database, pc: PartClaim, outputs: list[tuple[str, str, int]]) -> tuple[bool, list[tuple]]:
    """Record the part's files and mark it done; the last part puts its step back in the queue to merge."""
    now = utcnow()
    with db.session() as s:
        # parts finishing at the same moment are serialised on their step's row (PostgreSQL: FOR UPDATE;
        # SQLite: BEGIN IMMEDIATE already), so exactly one of them sees all parts done and queues the merge
        st = s.execute(select(RunStep.state, RunStep.phase).where(RunStep.id == pc.step_id).with_for_update()).first()
        if st is None or st.state != "running" or st.phase != "parts":
            return False, []
        n = s.execute(update(RunStepPart).where(*_part_is_ours(s, pc))
                      .values(state="succeeded", finished_at=now, heartbeat_at=now, progress_stage="done")).rowcount
        if n != 1:
            return False, []
        if outputs:
            s.execute(delete(RunOutput).where(RunOutput.run_id == pc.run_id,
                                              RunOutput.path.in_([o[0] for o in outputs])))
        for path, sha, size in outputs:
            s.add(RunOutput(run_id=pc.run_id, step_name=pc.step, path=path, sha256=sha, size=size))
        s.flush()
        counts = dict(s.execute(select(RunStepPart.state, func.count()).where(RunStepPart.run_step_id == pc.step_id)
                                .group_by(RunStepPart.state)).all())
        total, done = sum(counts.values()), counts.get("succeeded", 0)
        add_log(s, pc.run_id, f"step {pc.step} part {pc.index} done on {pc.worker} ({done} of {total})", pc.step)
        if done < total:
            s.execute(update(RunStep).where(RunStep.id == pc.step_id).values(progress_done=done, heartbeat_at=now))
            return True, _release_waiting_parts(s, pc, now)
        s.execute(update(RunStep).where(RunStep.id == pc.step_id, RunStep.state == "running", RunStep.phase == "parts")
                  .values(state="queued", phase="merge", queued_at=now, progress_stage="merge", progress_done=done))
        return True, [("step", pc.run_id, pc.step)]


def _release_waiting_parts(s, pc: PartClaim, now) -> list[tuple]:
    """The waiting parts of the step whose ``after`` parts have all succeeded: queued; their messages."""
    rows = s.execute(select(RunStepPart.index, RunStepPart.state, RunStepPart.descriptor)
                     .where(RunStepPart.run_step_id == pc.step_id)).all()
    succeeded = {r.index for r in rows if r.state == "succeeded"}
    ready = [r.index for r in rows if r.state == "waiting" and set(part_after(r.descriptor or {})) <= succeeded]
    if not ready:
        return []
    s.execute(update(RunStepPart).where(RunStepPart.run_step_id == pc.step_id, RunStepPart.index.in_(ready),
                                        RunStepPart.state == "waiting").values(state="queued", queued_at=now))
    add_log(s, pc.run_id, f"step {pc.step}: part(s) {', '.join(map(str, ready))} ready (the parts they read are done)",
            pc.step)
    return [("part", pc.run_id, pc.step, k) for k in ready]


def fail_part(db: Database, pc: PartClaim, reason: str, cancelled: bool = False) -> tuple[bool, list[tuple]]:
    """A part failed (or was cancelled): so does its step, and the run."""
    with db.session() as s:
        n = s.execute(update(RunStepPart).where(*_part_is_ours(s, pc))
                      .values(state="cancelled" if cancelled else "failed", finished_at=utcnow())).rowcount
        if n != 1:
            return False, []
        return True, _end_split_step(s, pc.run_id, pc.step_id, pc.step,
                                     reason if cancelled else f"part {pc.index}: {reason}", cancelled)


def release_part(db: Database, run_id: str, step: str, index: int, worker: str, reason: str) -> None:
    """Give a claimed part back to the queue (transient error; it will be retried)."""
    with db.session() as s:
        s.execute(update(RunStepPart).where(RunStepPart.run_id == run_id, RunStepPart.step_name == step,
                                            RunStepPart.index == index, RunStepPart.state == "running",
                                            RunStepPart.worker == worker)
                  .values(state="queued", queued_at=utcnow()))
        add_log(s, run_id, f"step {step} part {index}: transient error, retrying ({reason})", step, "warning")


def _end_split_step(s, run_id: str, step_id: str, step: str, reason: str, cancelled: bool) -> list[tuple]:
    """Fail (or cancel) a step waiting for its parts, the parts not yet run, the steps after it, the run."""
    now = utcnow()
    n = s.execute(update(RunStep).where(RunStep.id == step_id, RunStep.state == "running", RunStep.phase == "parts")
                  .values(state="cancelled" if cancelled else "failed", finished_at=now, error=reason)).rowcount
    if n != 1:
        return []
    s.execute(update(RunStepPart).where(RunStepPart.run_step_id == step_id,
                                        RunStepPart.state.in_(("queued", "waiting")))
              .values(state="cancelled", finished_at=now))
    s.execute(update(RunStep).where(RunStep.run_id == run_id, RunStep.state.in_(("pending", "queued")))
              .values(state="cancelled", finished_at=now,
                      error="cancelled by the user" if cancelled else f"not run: step {step} failed"))
    add_log(s, run_id, f"step {step} {'cancelled' if cancelled else 'failed'}: {reason}", step,
            "warning" if cancelled else "error")
    run = s.get(Run, run_id)
    return _end_run(s, run, "cancelled" if cancelled else "failed", None if cancelled else f"step {step} failed: {reason}")
