"""Celery tasks: thin, idempotent, taking ids. The state machine is backend/services/jobs.py; the
science is georef_core (worker/pipeline.py binds the two).

run_step(run_id, step):
  claim the step atomically -> materialise inputs (survey files by checksum, earlier outputs) ->
  input hash (settings + checksums) -> reuse an identical earlier result, or call the step with a
  progress callback (throttled DB writes; raises StepCancelled when the run was cancelled) while a
  heartbeat thread proves the worker alive -> store new/changed files content-addressed -> record
  outputs and queue the next step in one transaction (fenced by the attempt number) -> send.

A step that can run as parts (contract.Split, docs/architecture.md) is planned under its claim; when the plan
has more than one part, the plan's files and the parts are recorded and each part is sent as
run_part(run_id, step, index): claimed, materialised in a folder of its own, run, its files stored, fenced
like a step. The last part queues the step again; that claim merges the parts and finishes the step."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import shutil
import socket
import threading
import time
import traceback
from pathlib import Path

from celery import shared_task
from sqlalchemy.exc import OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeoutError

from backend.core.queue import send_part, send_step, send_webhook
from backend.core.settings import get_settings
from backend.db.session import get_database
from backend.services import jobs, steps_catalog
from backend.services.changes import on_run_finished, run_metrics
from backend.services.context import Ctx
from backend.services.runs import canonical_json
from backend.storage import blob_key, storage_for
from backend.storage.base import sha256_of_file

from . import pipeline

log = logging.getLogger("georef.worker")


def worker_id() -> str:
    """host:pid of the process running the step (a prefork pool's child, not the parent that imported
    this module: the id is taken when the step is claimed)."""
    return f"{socket.gethostname()}:{os.getpid()}"


PROGRESS_INTERVAL_S = 0.5
MANIFEST = ".georef_outputs.json"


class LostClaim(Exception):
    """Another worker took this step over (we were presumed dead): stop, record nothing."""


def _transient_types() -> tuple[type[BaseException], ...]:
    types: list[type[BaseException]] = [OperationalError, PoolTimeoutError, ConnectionError, TimeoutError]
    try:
        from botocore.exceptions import ConnectionClosedError, EndpointConnectionError, ReadTimeoutError

        types += [EndpointConnectionError, ConnectionClosedError, ReadTimeoutError]
    except ImportError:
        pass
    return tuple(types)


TRANSIENT = _transient_types()


def _env():
    settings = get_settings()
    return settings, get_database(settings.resolved_database_url()), storage_for(settings)


def _send(settings, db, storage, messages: list[tuple]) -> None:
    for m in messages:
        if m[0] == "step":
            send_step(settings, m[1], m[2])
        elif m[0] == "part":
            send_part(settings, m[1], m[2], m[3])
        elif m[0] == "webhook":
            send_webhook(settings, m[1])
        elif m[0] == "design-change":
            from backend.core.queue import send_design_change

            send_design_change(settings, m[1])
        elif m[0] == "run-finished":
            _send(settings, db, storage, on_run_finished(db, storage, m[1]))
            shutil.rmtree(settings.resolved_work_dir() / "runs" / m[1], ignore_errors=True)


# ----------------------------------------------------------------------------------------------- folders


def _relevant(path: str, prefixes: tuple[str, ...]) -> bool:
    return "" in prefixes or any(path == p or path.startswith(p) for p in prefixes) or not prefixes


def materialise(storage, run: dict, step: str, run_dir: Path, part: int | None = None) -> tuple[Path, Path]:
    """The survey's files and the run's recorded outputs the step reads, in run_dir/survey and run_dir/out.
    A split step's own recorded files (its plan's; and its parts' for the merge) are given to it too; a
    part (``part``: its index) gets the plan's files and none of the other parts'."""
    info = steps_catalog.BY_NAME[step]
    survey_dir, out_dir = run_dir / "survey", run_dir / "out"
    survey_dir.mkdir(parents=True, exist_ok=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    for path, sha in sorted(run["inputs"].items()):
        if not _relevant(path, info.inputs if info.inputs else ("",)):
            continue
        dest = survey_dir / path
        if dest.exists() and dest.stat().st_size == (storage.size(blob_key(sha)) or -1) and \
                _manifest(survey_dir).get(path) == sha:
            continue
        storage.fetch(blob_key(sha), dest, link_ok=True)   # survey files are read-only inputs: links are fine
        _set_manifest(survey_dir, path, sha)
    if "survey.json" not in run["inputs"]:
        (survey_dir / "survey.json").write_text(json.dumps({"project_crs": run["site"]["crs"],
                                                            "points_crs": run["site"]["crs"],
                                                            "heights": "ellipsoidal (WGS84)"}, indent=1))
    # the run folder holds exactly the recorded outputs of earlier steps (copies: steps may rewrite them)
    recorded = {o["path"]: o["sha256"] for o in run["outputs"]
                if o["step"] != step or _own_file_wanted(o["path"], step, part, run)}
    have = _manifest(out_dir)
    for f in sorted(out_dir.rglob("*")):
        rel = f.relative_to(out_dir).as_posix()
        if f.is_file() and rel != MANIFEST and recorded.get(rel) != have.get(rel):
            f.unlink()
    for path, sha in recorded.items():
        dest = out_dir / path
        if not dest.exists() or have.get(path) != sha:
            storage.fetch(blob_key(sha), dest, link_ok=False)
    _write_manifest(out_dir, recorded)
    if "design" in info.site_data:
        _materialise_design(storage, run, run_dir)
    return survey_dir, out_dir


def _materialise_design(storage, run: dict, run_dir: Path) -> None:
    """The site's design file (jobs.run_context "design") in run_dir/site/design/ under its uploaded name; its
    path goes into the run's design context (pipeline._context)."""
    design = run.get("design")
    if not design or not design.get("sha256"):
        return
    folder = run_dir / "site" / "design"
    dest = folder / design["filename"]
    if not (dest.exists() and _manifest(folder).get(design["filename"]) == design["sha256"]):
        for f in folder.glob("*") if folder.exists() else ():
            if f.is_file() and f.name != MANIFEST:
                f.unlink()
        folder.mkdir(parents=True, exist_ok=True)
        storage.fetch(blob_key(design["sha256"]), dest, link_ok=True)   # read only
        _write_manifest(folder, {design["filename"]: design["sha256"]})
    design["path"] = str(dest)


def _own_file_wanted(path: str, step: str, part: int | None, run: dict) -> bool:
    """Whether a file the step itself recorded (a split step's plan or parts) goes into its folder: while the
    step waits for its parts or merges them (run["own_files"]: set by the caller), the plan's files, and the
    parts' files for the merge only - and for a part, the files of the earlier parts it reads (its
    descriptor's ``after``, run["part_reads"]: set by the caller). Of a part's files, only those the reader
    declared it reads: the merge, its Split's ``merge_reads``; a part, its descriptor's ``reads``
    (run["part_read_patterns"]: set by the caller) - the tiled dense step's merge needs none of the depth maps."""
    from georef_core.steps.contract import part_file_read, part_prefix

    if not run.get("own_files"):
        return False
    if path.startswith(part_prefix(step)):
        rest = path[len(part_prefix(step)):]
        within = rest.split("/", 1)[1] if "/" in rest else ""
        if part is None:
            split = getattr(steps_catalog.BY_NAME.get(step), "split", None)
            return part_file_read(within, split.merge_reads if split is not None else ())
        return (any(path.startswith(part_prefix(step, j)) for j in run.get("part_reads") or ())
                and part_file_read(within, run.get("part_read_patterns")))
    return True


def _manifest(folder: Path) -> dict:
    try:
        return json.loads((folder / MANIFEST).read_text())
    except (OSError, ValueError):
        return {}


def _write_manifest(folder: Path, data: dict) -> None:
    (folder / MANIFEST).write_text(json.dumps(data))


def _set_manifest(folder: Path, path: str, sha: str) -> None:
    m = _manifest(folder)
    m[path] = sha
    _write_manifest(folder, m)


def collect_outputs(storage, out_dir: Path, before: dict, under: str = "") -> list[tuple[str, str, int]]:
    """Files the step created or changed (under the run-relative folder ``under``), stored content-addressed:
    [(path, sha256, size)]."""
    out = []
    for f in sorted((out_dir / under).rglob("*") if (out_dir / under).is_dir() else ()):
        if not f.is_file() or f.is_symlink():
            continue
        rel = f.relative_to(out_dir).as_posix()
        if rel == MANIFEST:
            continue
        sha = sha256_of_file(f)
        if before.get(rel) == sha:
            continue
        storage.put_blob(f, sha)
        out.append((rel, sha, f.stat().st_size))
    return out


def input_hash(run: dict, step: str) -> str:
    info = steps_catalog.BY_NAME[step]
    deps = set(info.depends_on) | set(steps_catalog.SOFT_AFTER.get(step, ()))
    site = run["site"]
    site_data = {"crs": site["crs"]}
    if "vertical" in info.site_data:
        site_data.update(vertical=site["vertical_datum"], geoid=site["geoid"])
        if site.get("calibration"):   # a new site calibration: the datum step computed again (none: hash unchanged)
            site_data["calibration"] = site["calibration"].get("document")
    if "stockpiles" in info.site_data:
        site_data["stockpiles"] = [{k: p[k] for k in ("id", "name", "outline", "base")} for p in run["stockpiles"]]
    if "design" in info.site_data:   # a new design file, area, surface or tolerance: computed again
        design = run.get("design") or {}
        site_data["design"] = {k: design.get(k) for k in ("sha256", "surface_name", "area", "tolerance_m")}
    doc = {"step": step, "version": info.version,
           "settings": {k: run["settings"].get(k) for k in info.settings},
           "inputs": {p: s for p, s in sorted(run["inputs"].items())
                      if _relevant(p, info.inputs if info.inputs else ("",))},
           "site": site_data,
           "upstream": sorted((o["path"], o["sha256"]) for o in run["outputs"] if o["step"] in deps)}
    if step == "report":   # the report shows the run number, names and dates: never reused
        doc["run"] = run["run_id"]
    return hashlib.sha256(canonical_json(doc).encode()).hexdigest()


# ----------------------------------------------------------------------------------------------- progress


class _Liveness:
    """Heartbeat thread + throttled progress callback for one claimed step (or part: ``heartbeat`` and
    ``report`` are then the part's functions)."""

    def __init__(self, db, claim, lease_s: float, heartbeat=jobs.heartbeat, report=jobs.report_progress):
        self.db, self.claim = db, claim
        self._heartbeat, self._report = heartbeat, report
        self.lost = False
        self.cancel = False
        self._last = 0.0
        self._stop = threading.Event()
        self._period = max(0.5, lease_s / 4)
        self._thread = threading.Thread(target=self._beat, name=f"heartbeat-{claim.step}", daemon=True)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join(timeout=5)

    def _beat(self):
        while not self._stop.wait(self._period):
            try:
                if not self._heartbeat(self.db, self.claim):
                    self.lost = True
                    return
            except Exception as exc:   # a missed beat is not fatal; the lease allows several
                log.warning("heartbeat failed: %s", exc)

    def progress(self, stage: str, done: int, total: int) -> None:
        from georef_core.errors import StepCancelled

        if self.lost:
            raise LostClaim("step taken over by another worker")
        now = time.monotonic()
        if now - self._last >= PROGRESS_INTERVAL_S or (total and done >= total):
            self._last = now
            try:
                ours, cancel = self._report(self.db, self.claim, stage, done, total)
            except TRANSIENT as exc:
                log.warning("progress not recorded: %s", exc)
                return
            if not ours:
                self.lost = True
                raise LostClaim("step taken over by another worker")
            if cancel:
                self.cancel = True
                raise StepCancelled(f"run cancelled during {self.claim.step}")


# ----------------------------------------------------------------------------------------------- the step


def execute_step(run_id: str, step: str) -> str:
    """Claim and run one step; returns what happened. Raises only transient errors (to be retried)."""

    settings, db, storage = _env()
    claim = jobs.claim_step(db, run_id, step, worker_id())
    if not isinstance(claim, jobs.Claim):
        if claim == "cancelled":
            _send(settings, db, storage, [("run-finished", run_id)])
        log.info("run %s step %s: nothing to do (%s)", run_id, step, claim)
        return f"skipped: {claim}"
    run = jobs.run_context(db, run_id)
    try:
        pipeline.check_available(step, run)
    except pipeline.StepUnavailable as exc:
        ok, msgs = jobs.mark_unavailable(db, claim, f"not available in this installation: {exc}", storage=storage)
        _send(settings, db, storage, msgs)
        return "unavailable"
    h = input_hash(run, step)
    merging = claim.phase == "merge"
    if merging:
        run["own_files"] = True   # the plan's and the parts' files (materialise)
    if not claim.force and not merging:
        reuse = jobs.find_reusable(db, claim.survey_id, step, h, run_id)
        if reuse is not None and all(storage.exists(blob_key(sha)) for _, sha, _ in reuse[2]):
            step_id, summary, outputs, src_run = reuse
            volumes = jobs.volumes_of_run(db, src_run) if step == "volumes" else None
            ok, msgs = jobs.finish_step(db, claim, h, outputs, summary or {}, reused_from=step_id, volumes=volumes,
                                           storage=storage)
            _send(settings, db, storage, msgs)
            return "reused" if ok else "lost"
    run_dir = settings.resolved_work_dir() / "runs" / run_id
    try:
        with _Liveness(db, claim, settings.step_lease_s) as live:
            survey_dir, out_dir = materialise(storage, run, step, run_dir)
            before = _manifest(out_dir)
            if step == "report":
                run["volumes"] = jobs.volumes_of_run(db, run_id, with_material=True)
                if run.get("previous_run_id"):
                    with db.session(read_only=True) as s:
                        prev = run_metrics(s, storage, run["previous_run_id"])
                    run["previous_metrics"] = prev
            t0 = time.monotonic()
            options = dict(run["settings"].get(step) or {})
            split = None
            if merging:
                summary = pipeline.merge_parts(step, survey_dir, out_dir, options, jobs.part_descriptors(db, claim),
                                               live.progress, run)
            else:
                parts = pipeline.plan_parts(step, survey_dir, out_dir, options, run)
                if parts is not None and len(parts) > 1:   # to the workers: the plan's files and the parts
                    split = (collect_outputs(storage, out_dir, before), parts)
                    _write_manifest(out_dir, {**before, **{p: s for p, s, _ in split[0]}})
                    summary = {}
                else:
                    summary = pipeline.REGISTRY[step].adapter(survey_dir, out_dir, options, live.progress, run) or {}
            if split is None:
                if step in ("gnss", "georef"):   # when the survey was flown, from its data (jobs.finish_step stores it)
                    from georef_core.steps.flight_time import add_flight_time

                    add_flight_time(summary, survey_dir, out_dir)
                # what the platform stores of the step's results is read from its declared outputs
                volumes = pipeline.stored_volumes(out_dir) if step == "volumes" else None
                summary = json.loads(_relative(json.dumps(summary, default=str), run_dir))
                summary["duration_s"] = round(time.monotonic() - t0, 2)
            if live.lost:
                raise LostClaim("step taken over by another worker")
            if split is None:
                outputs = collect_outputs(storage, out_dir, before)
                _write_manifest(out_dir, {**before, **{p: s for p, s, _ in outputs}})
        if split is not None:
            ok, msgs = jobs.start_parts(db, claim, h, split[0], split[1])
            _send(settings, db, storage, msgs)
            return f"split into {len(split[1])} parts" if ok else "lost"
        ok, msgs = jobs.finish_step(db, claim, h, outputs, summary, volumes=volumes, storage=storage)
        _send(settings, db, storage, msgs)
        return "done" if ok else "lost"
    except LostClaim:
        log.warning("run %s step %s: taken over by another worker; result discarded", run_id, step)
        return "lost"
    except TRANSIENT:
        raise
    except Exception as exc:
        return _record_failure(settings, db, storage, run_id, step, run_dir, exc,
                               lambda reason, cancelled: jobs.fail_step(db, claim, reason, cancelled=cancelled))


def execute_part(run_id: str, step: str, index: int) -> str:
    """Claim and run one part of a split step in a folder of its own (two parts on one machine never share
    one); record its files and, for the last part, queue the merge. Raises only transient errors."""
    from georef_core.steps.contract import part_after, part_prefix

    settings, db, storage = _env()
    pc = jobs.claim_part(db, run_id, step, index, worker_id())
    if not isinstance(pc, jobs.PartClaim):
        if pc == "cancelled":
            _send(settings, db, storage, [("run-finished", run_id)])
        log.info("run %s step %s part %s: nothing to do (%s)", run_id, step, index, pc)
        return f"skipped: {pc}"
    run = jobs.run_context(db, run_id)
    run["own_files"] = True              # the plan's files (materialise)
    run["part_reads"] = part_after(pc.descriptor)   # and those of the earlier parts it reads
    run["part_read_patterns"] = pc.descriptor.get("reads")   # (only the files it declared, contract.Split)
    run_dir = settings.resolved_work_dir() / "runs" / run_id / "parts" / f"{step}-{index:04d}"
    try:
        with _Liveness(db, pc, settings.step_lease_s, jobs.part_heartbeat, jobs.report_part_progress) as live:
            survey_dir, out_dir = materialise(storage, run, step, run_dir, part=index)
            shutil.rmtree(out_dir / part_prefix(step, index), ignore_errors=True)   # an earlier attempt's files
            before = _manifest(out_dir)
            pipeline.run_part(step, survey_dir, out_dir, dict(run["settings"].get(step) or {}),
                              dict(pc.descriptor, index=index), live.progress, run)
            if live.lost:
                raise LostClaim("part taken over by another worker")
            outputs = collect_outputs(storage, out_dir, before, under=part_prefix(step, index))
        ok, msgs = jobs.finish_part(db, pc, outputs)
        _send(settings, db, storage, msgs)
        return "done" if ok else "lost"
    except LostClaim:
        log.warning("run %s step %s part %s: no longer ours; result discarded", run_id, step, index)
        return "lost"
    except TRANSIENT:
        raise
    except Exception as exc:
        return _record_failure(settings, db, storage, run_id, step, run_dir, exc,
                               lambda reason, cancelled: jobs.fail_part(db, pc, reason, cancelled=cancelled))


def _record_failure(settings, db, storage, run_id: str, step: str, run_dir: Path, exc: Exception, fail) -> str:
    """What a step or a part that raised records (``fail(reason, cancelled) -> (recorded, messages)``, called
    inside the except block): a cancellation; the project's own error, its files named relative to the run
    folder; anything else as an internal error with its traceback in the run's log. Returns the outcome."""
    from georef_core.errors import GeorefError, InputFileError, StepCancelled

    if isinstance(exc, StepCancelled):
        ok, msgs = fail(str(exc) or "cancelled", True)
        _send(settings, db, storage, msgs)
        return "cancelled"
    if isinstance(exc, GeorefError):
        reason = _relative(str(exc), run_dir)
        if not reason and isinstance(exc, InputFileError) and exc.path:
            reason = f"{Path(exc.path).name}: {exc.problem}"
    else:   # a bug: the run records it with the traceback in its log
        jobs.log(db, run_id, "internal error:\n" + _relative(traceback.format_exc(limit=8), run_dir), step, "error")
        reason = f"internal error ({type(exc).__name__}: {_relative(str(exc), run_dir)})"
    ok, msgs = fail(reason, False)
    _send(settings, db, storage, msgs)
    return "failed"


def _relative(text: str, run_dir: Path) -> str:
    """Messages name files relative to the survey/run folder (the user's view), not worker paths."""
    return text.replace(str(run_dir / "survey") + "/", "").replace(str(run_dir / "out") + "/", "")


def release_after_transient(run_id: str, step: str, exc: BaseException) -> None:
    settings, db, storage = _env()
    try:
        with db.session() as s:
            from sqlalchemy import update

            from backend.models import RunStep
            from backend.models.base import utcnow

            s.execute(update(RunStep).where(RunStep.run_id == run_id, RunStep.name == step,
                                            RunStep.state == "running", RunStep.worker == worker_id())
                      .values(state="queued", queued_at=utcnow(), error=f"retrying after: {exc}"))
    except Exception as inner:   # the database itself may be what is down: the reaper will requeue
        log.warning("could not release step %s of run %s: %s", step, run_id, inner)


def give_up(run_id: str, step: str, exc: BaseException) -> None:
    settings, db, storage = _env()
    _send(settings, db, storage, jobs.fail_unclaimed_step(db, run_id, step,
                                                          f"gave up after repeated transient errors: {exc}"))


# ----------------------------------------------------------------------------------------------- tasks


@shared_task(name="georef.run_step", bind=True, acks_late=True, reject_on_worker_lost=True, max_retries=None)
def run_step(self, run_id: str, step: str) -> str:
    settings = get_settings()
    try:
        return execute_step(run_id, step)
    except TRANSIENT as exc:
        release_after_transient(run_id, step, exc)
        if self.request.retries >= settings.task_max_retries:
            give_up(run_id, step, exc)
            return "failed"
        raise self.retry(exc=exc, countdown=min(60, 2 ** self.request.retries))


@shared_task(name="georef.run_part", bind=True, acks_late=True, reject_on_worker_lost=True, max_retries=None)
def run_part(self, run_id: str, step: str, index: int) -> str:
    settings = get_settings()
    try:
        return execute_part(run_id, step, int(index))
    except TRANSIENT as exc:
        try:
            jobs.release_part(_env()[1], run_id, step, int(index), worker_id(), str(exc))
        except Exception as inner:   # the database itself may be down: the reaper will requeue
            log.warning("could not release part %s of step %s of run %s: %s", index, step, run_id, inner)
        if self.request.retries >= settings.task_max_retries:
            return "gave up (the reaper will re-send it)"
        raise self.retry(exc=exc, countdown=min(60, 2 ** self.request.retries))


@shared_task(name="georef.reap_stale_steps", acks_late=True)
def reap_stale_steps() -> int:
    settings, db, storage = _env()
    msgs = jobs.reap(db, settings.step_lease_s, settings.requeue_queued_after_s)
    from backend.services import design_changes

    msgs += design_changes.reap(db, settings)   # design-change jobs: stale heartbeat / lost message
    _send(settings, db, storage, msgs)
    return len(msgs)


@shared_task(name="georef.dispatch_schedules", acks_late=True)
def dispatch_schedules() -> int:
    from backend.services.schedules import dispatch_due

    settings, db, storage = _env()
    s = db.sessionmaker()
    ctx = Ctx(db=s, settings=settings, storage=storage)
    try:
        created = dispatch_due(ctx)
        ctx.commit()
    finally:
        s.close()
    return len(created)


@shared_task(name="georef.deliver_webhook", bind=True, acks_late=True, max_retries=None)
def deliver_webhook(self, delivery_id: str) -> str:
    from backend.services.webhooks import TransientDeliveryError, deliver

    settings, db, storage = _env()
    try:
        return deliver(db, delivery_id, settings.webhook_timeout_s, settings.webhook_max_attempts,
                       settings.webhook_allowed_networks)
    except TransientDeliveryError as exc:
        raise self.retry(exc=exc, countdown=min(3600, 2 ** self.request.retries * 5))


@dataclasses.dataclass(frozen=True)
class _DesignChangeClaim:
    job_id: str
    attempt: int
    step: str = "design-change"   # _Liveness names its thread after it


def _design_change_heartbeat(db, claim: _DesignChangeClaim) -> bool:
    from backend.services import design_changes

    return design_changes.heartbeat(db, claim.job_id, claim.attempt)


def execute_design_change(job_id: str) -> str:
    """Claim and compute one change between two surveys of a design (backend/services/design_changes); the
    result or the error (a file named, as for steps) stored on the job. Raises only transient errors."""
    from georef_core.errors import GeorefError

    from backend.services import design_changes

    settings, db, storage = _env()
    claimed = design_changes.claim(db, job_id, worker_id())
    if claimed is None:
        return "skipped: not queued"
    inputs, attempt = claimed
    work = settings.resolved_work_dir() / "design-changes"
    # a heartbeat thread as a step's (every step_lease_s / 4): a job whose heartbeat stops is queued again after
    # step_lease_s, however long a live one runs; a beat refused (the job taken over) only stops the beats: the
    # result is then not recorded (finish is fenced by the attempt)
    beat = _DesignChangeClaim(job_id, attempt)
    try:
        with _Liveness(db, beat, settings.step_lease_s, heartbeat=_design_change_heartbeat):
            result = design_changes.compute(storage, inputs, work)
    except TRANSIENT:
        with db.session() as s:   # back to the queue for the retry
            from sqlalchemy import update

            from backend.models import DesignChangeJob

            s.execute(update(DesignChangeJob).where(DesignChangeJob.id == job_id, DesignChangeJob.attempt == attempt)
                      .values(state="queued"))
        raise
    except (GeorefError, ValueError, OSError) as exc:
        design_changes.finish(db, job_id, attempt, error=_relative(str(exc), work))
        return "failed"
    except Exception as exc:   # a bug: recorded on the job, with its type
        log.exception("design change %s failed", job_id)
        design_changes.finish(db, job_id, attempt, error=f"internal error ({type(exc).__name__}: {exc})")
        return "failed"
    return "done" if design_changes.finish(db, job_id, attempt, result=result) else "lost"


@shared_task(name="georef.design_change", bind=True, acks_late=True, max_retries=None)
def design_change(self, job_id: str) -> str:
    settings = get_settings()
    try:
        return execute_design_change(job_id)
    except TRANSIENT as exc:
        if self.request.retries >= settings.task_max_retries:
            return "gave up (the reaper or the next design-progress request re-sends it)"
        raise self.retry(exc=exc, countdown=min(60, 2 ** self.request.retries))


@shared_task(name="georef.expire_uploads", acks_late=True)
def expire_uploads() -> int:
    from backend.services.uploads import expire_uploads as expire

    settings, db, storage = _env()
    with db.session() as s:
        return expire(s, storage)


def clean_scratch() -> None:
    """Remove this machine's run folders of runs that have ended."""
    settings, db, storage = _env()
    root = settings.resolved_work_dir() / "runs"
    if not root.is_dir():
        return
    from sqlalchemy import select

    from backend.models import Run

    try:
        with db.session(read_only=True) as s:
            ids = [p.name for p in root.iterdir() if p.is_dir()]
            ended = set(s.scalars(select(Run.id).where(Run.id.in_(ids),
                                                       Run.state.in_(("succeeded", "failed", "cancelled")))))
    except OperationalError:
        return
    for i in ended:
        shutil.rmtree(root / i, ignore_errors=True)
