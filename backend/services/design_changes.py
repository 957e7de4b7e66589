"""The change between two surveys of a site's design, surface against surface, as a queued job whose state is in
the database (table design_changes): design-progress asks for it (request_changes; a row per pair of design
results, area and common-bias figure, queued once, its message sent after commit), a worker computes it
(worker/tasks.design_change: claim -> compute -> finish, fenced by the attempt number) and design-progress serves
the stored result. The API never reads a raster for it. docs/design.md "Change between surveys".

The bias common to both surveys (georef_core.design.surface_change ``common_bias_m``): when both runs read the same
control-point files (identical gcp/ checksums), each block's vertical offset absorbs the same mean error of those
n control heights: common_bias_m = CONTROL_POINT_SIGMA_V_M / sqrt(n) (the points' errors independent of each
other; sigma the vertical survey accuracy georef_core assigns a surveyed point, the point files carry none).
Different or no control: 0 (the surveys' biases independent)."""

from __future__ import annotations

import hashlib
import json
import math
import tempfile
from datetime import timedelta
from pathlib import Path

from sqlalchemy import select, update
from sqlalchemy.exc import IntegrityError

from ..models import DesignChangeJob, Run, RunOutput
from ..models.base import utcnow
from .context import Ctx

MODEL_VERSION = 2   # the sigma model (2: common bias and resampling); a new one computes the changes again
CONTROL_POINT_SIGMA_V_M = 0.02   # georef_core.adjustment.control_points.GroundPoint's vertical survey accuracy
FILES = ("design/difference.tif", "design/cut_fill.json")


def _files(s, run_id: str) -> dict[str, str]:
    rows = s.execute(select(RunOutput.path, RunOutput.sha256).where(RunOutput.run_id == run_id,
                                                                    RunOutput.path.in_(FILES))).all()
    return dict(rows)


def _control(s, run_id: str) -> dict[str, str]:
    inputs = s.scalar(select(Run.inputs).where(Run.id == run_id)) or {}
    return {p: sha for p, sha in inputs.items() if p.startswith("gcp/")}


def pair_inputs(s, prev: dict, cur: dict, area: dict) -> dict:
    """What the change of ``cur`` against ``prev`` (design-progress entries) is computed from: both runs' design
    files (checksums), the area and the shared control files. ValueError (why) when a run lacks its files."""
    out = {"model": MODEL_VERSION, "area": area}
    for which, e in (("earlier", prev), ("later", cur)):
        f = _files(s, e["run_id"])
        if set(f) != set(FILES):
            raise ValueError(f"run {e['run_number']} of {e['survey_name']!r} kept no design difference raster")
        out[which] = {"run_id": e["run_id"], "label": f"run {e['run_number']} of {e['survey_name']!r}",
                      "difference": f["design/difference.tif"], "cut_fill": f["design/cut_fill.json"]}
    ce, cl = _control(s, prev["run_id"]), _control(s, cur["run_id"])
    out["control"] = ce if ce and ce == cl else None
    return out


def job_key(inputs: dict) -> str:
    from .runs import canonical_json

    doc = {k: v for k, v in inputs.items() if k not in ("earlier", "later")}
    doc["files"] = [inputs[w][k] for w in ("earlier", "later") for k in ("difference", "cut_fill")]
    return hashlib.sha256(canonical_json(doc).encode()).hexdigest()


def _stale(job: DesignChangeJob, settings) -> bool:
    """Left queued or running longer than settings.requeue_queued_after_s: its message or its worker lost."""
    since = job.started_at if job.state == "running" else job.queued_at
    return job.state in ("queued", "running") and since is not None and \
        since < utcnow() - timedelta(seconds=settings.requeue_queued_after_s)


def _view(job: DesignChangeJob) -> dict:
    return {"id": job.id, "state": job.state, "result": job.result, "error": job.error}


def queue_job(s, site_id: str, inputs: dict, key: str, settings=None) -> tuple[dict, tuple | None]:
    """In session ``s``: the job for ``key`` created queued, or (with ``settings``) a stale one queued again; (its
    view, the message to send after commit or None)."""
    job = s.scalar(select(DesignChangeJob).where(DesignChangeJob.key == key))
    if job is None:
        job = DesignChangeJob(site_id=site_id, key=key, earlier_run_id=inputs["earlier"]["run_id"],
                              later_run_id=inputs["later"]["run_id"], inputs=inputs, state="queued", attempt=0,
                              queued_at=utcnow())
        try:
            with s.begin_nested():
                s.add(job)
        except IntegrityError:   # another request created it meanwhile
            job = s.scalar(select(DesignChangeJob).where(DesignChangeJob.key == key))
            return _view(job), None
        return _view(job), ("design-change", job.id)
    if settings is not None and _stale(job, settings):
        job.state, job.queued_at, job.worker = "queued", utcnow(), None
        s.flush()
        return _view(job), ("design-change", job.id)
    return _view(job), None


def request_changes(ctx: Ctx, site_id: str, pairs: list[dict], database=None) -> dict[str, dict]:
    """The stored jobs of these pairs (pair_inputs), by job_key: {id, state, result, error}. A pair without one is
    queued (and a stale one queued again): written through ``database`` (its own transaction, committed and its
    messages sent here: a GET's session is read-only) or, without it, in ctx.db with the messages in ctx.outbox."""
    keys = {job_key(i): i for i in pairs}
    if not keys:
        return {}
    found = {j.key: j for j in ctx.db.scalars(select(DesignChangeJob).where(DesignChangeJob.key.in_(list(keys))))}
    out = {k: _view(j) for k, j in found.items()}
    need = [k for k in keys if k not in found or _stale(found[k], ctx.settings)]
    if not need:
        return out
    if database is None:
        for k in need:
            out[k], msg = queue_job(ctx.db, site_id, keys[k], k, ctx.settings)
            if msg:
                ctx.outbox.append(msg)
        return out
    msgs = []
    with database.session() as s:
        for k in need:
            out[k], msg = queue_job(s, site_id, keys[k], k, ctx.settings)
            if msg:
                msgs.append(msg)
    from ..core.queue import send_design_change

    for m in msgs:
        send_design_change(ctx.settings, m[1])
    return out


# ------------------------------------------------------------------------------------------------- the worker


def claim(db, job_id: str, worker: str) -> tuple[dict, int] | None:
    """Take a queued job (atomically: UPDATE ... WHERE state = 'queued'): (its inputs, attempt), or None."""
    with db.session() as s:
        res = s.execute(update(DesignChangeJob).where(DesignChangeJob.id == job_id, DesignChangeJob.state == "queued")
                        .values(state="running", worker=worker, started_at=utcnow(),
                                attempt=DesignChangeJob.attempt + 1))
        if res.rowcount != 1:
            return None
        job = s.get(DesignChangeJob, job_id)
        return dict(job.inputs), job.attempt


def finish(db, job_id: str, attempt: int, result: dict | None = None, error: str | None = None) -> bool:
    """Record the result (or the error) of the attempt that still holds the job; False when it no longer does."""
    with db.session() as s:
        res = s.execute(update(DesignChangeJob).where(DesignChangeJob.id == job_id, DesignChangeJob.attempt == attempt,
                                                      DesignChangeJob.state == "running")
                        .values(state="failed" if error is not None else "succeeded", result=result, error=error,
                                finished_at=utcnow()))
        return res.rowcount == 1


def common_bias(storage, control: dict | None, tmp: Path) -> tuple[float, str]:
    """(1 sigma of the vertical bias common to both surveys, where the figure comes from): module docstring."""
    from georef_core.adjustment.control_points import parse_points_table, read_gcp_list

    from ..storage import blob_key

    if not control:
        return 0.0, "the surveys read different (or no) control-point files: their vertical biases independent"
    names: set[str] = set()
    roles: dict[str, str] = {}
    for path, sha in sorted(control.items()):
        local = tmp / "control" / path
        storage.fetch(blob_key(sha), local, link_ok=True)
        name = Path(path).name.lower()
        if name.endswith(".csv"):
            for row in parse_points_table(local.read_text(errors="replace"), source=path):
                roles[row["name"]] = row["role"]
        elif name == "gcp_list.txt":
            names |= set(read_gcp_list(local)[1])
    n = sum(1 for p in names | set(roles) if roles.get(p, "control") == "control")
    if n == 0:
        return 0.0, "the shared control-point files hold no control point: the vertical biases independent"
    sigma = CONTROL_POINT_SIGMA_V_M / math.sqrt(n)
    return sigma, (f"both surveys tied to the same {n} control point(s) ({', '.join(sorted(control))}): "
                   f"{CONTROL_POINT_SIGMA_V_M} m / sqrt({n})")


def compute(storage, inputs: dict, work_dir: Path) -> dict:
    """The change (georef_core.design.surface_change) from the stored files. Raises ValueError (why) for a file
    that cannot be read; the core's InputFileError / ProcessingError pass through."""
    from georef_core.design.surface_change import SurveyAccuracy, surface_change
    from georef_core.errors import InputFileError

    from ..storage import blob_key

    work_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=work_dir) as tmp:
        tmp = Path(tmp)
        acc, diff = {}, {}
        for which in ("earlier", "later"):
            f = inputs[which]
            where = f"{f['label']}: design/cut_fill.json"
            try:
                doc = json.loads(storage.read_bytes(blob_key(f["cut_fill"])))
            except (OSError, ValueError) as exc:
                raise ValueError(f"{where}: unreadable ({exc})") from None
            acc[which] = SurveyAccuracy.from_cut_fill(doc, where)
            diff[which] = tmp / f"{which}.tif"
            storage.fetch(blob_key(f["difference"]), diff[which], link_ok=True)
        common, source = common_bias(storage, inputs.get("control"), tmp)
        try:
            out = surface_change(diff["earlier"], diff["later"], inputs["area"], acc["earlier"], acc["later"],
                                 common_bias_m=common)
        except InputFileError as exc:   # named as the user knows the file, not by the worker's temporary path
            which = "earlier" if exc.path and Path(exc.path).name.startswith("earlier") else "later"
            raise ValueError(f"{inputs[which]['label']}: design/difference.tif: {exc.problem}") from None
    out["accuracy"]["common_bias_source"] = source
    return out
