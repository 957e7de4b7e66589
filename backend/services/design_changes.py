"""The change between two surveys of a site's design, surface against surface, as a queued job whose state is in
the database (table design_changes): design-progress asks for it (request_changes; a row per pair of design
results, area and common-bias figure, queued once, its message sent after commit), a worker computes it
(worker/tasks.design_change: claim -> compute -> finish, fenced by the attempt number, a heartbeat thread beating
meanwhile as for a step) and design-progress serves the stored result. A running job whose heartbeat is older than
settings.step_lease_s (its worker lost) is queued again, by the next request or the reaper; a queued one older than
requeue_queued_after_s (its message lost) is sent again. The API never reads a raster for it. docs/design.md
"Change between surveys".

The bias common to both surveys (georef_core.design.surface_change ``common_bias_m``): when both runs read the same
control-point files (identical gcp/ checksums), each block's vertical offset absorbs the same mean error of those
n control heights: common_bias_m = CONTROL_POINT_SIGMA_V_M / sqrt(n) (the points' errors independent of each
other; sigma the vertical survey accuracy georef_core assigns a surveyed point, the point files carry none).
A shared base position (two surveys without control points whose camera positions are PPK against the same base
position: the gnss steps' base_position_ecef_m within BASE_POSITION_MATCH_M of each other and the same source, the
georef steps resting on it and on no control point): every PPK position of both surveys is relative to that
position, so its error is common to both: common_bias_m = the base position's vertical sigma as the gnss step
states it (an averaged single-point or receiver-fix position), or SURVEYED_BASE_SIGMA_V_M for a position taken as
surveyed (given in the settings or in the file's header: Georef states no sigma of its own for it). Different or no
control and no shared base: 0 (the surveys' biases independent)."""

from __future__ import annotations

import hashlib
import json
import math
import tempfile
from datetime import timedelta
from pathlib import Path

from sqlalchemy import func, select, update
from sqlalchemy.exc import IntegrityError

from ..models import DesignChangeJob, Run, RunOutput, RunStep
from ..models.base import utcnow
from .context import Ctx

MODEL_VERSION = 3   # the sigma model (2: common bias and resampling; 3: a shared base); a new one computes them again
CONTROL_POINT_SIGMA_V_M = 0.02   # georef_core.adjustment.control_points.GroundPoint's vertical survey accuracy
# a base position taken as surveyed (given, or a RINEX header / RTCM station record): the same assumed vertical
# survey accuracy as a surveyed control point (Georef states none for it, ppk.base_position_basis)
SURVEYED_BASE_SIGMA_V_M = CONTROL_POINT_SIGMA_V_M
BASE_POSITION_MATCH_M = 0.001   # two runs' base positions (ECEF) closer than this are the same position
FILES = ("design/difference.tif", "design/cut_fill.json")


def _files(s, run_id: str) -> dict[str, str]:
    rows = s.execute(select(RunOutput.path, RunOutput.sha256).where(RunOutput.run_id == run_id,
                                                                    RunOutput.path.in_(FILES))).all()
    return dict(rows)


def _control(s, run_id: str) -> dict[str, str]:
    inputs = s.scalar(select(Run.inputs).where(Run.id == run_id)) or {}
    return {p: sha for p, sha in inputs.items() if p.startswith("gcp/")}


def base_of(gnss_summary: dict | None, georef_summary: dict | None) -> dict | None:
    """The base position a survey rests on alone, from its gnss and georef steps' summaries: {position_ecef_m,
    source, sigma_v_m (None: taken as surveyed), text}; None when the georef step used control points, did not
    rest on PPK positions relative to a base, or either summary lacks what is needed (a skipped gnss step, an
    older run)."""
    if not isinstance(gnss_summary, dict) or not isinstance(georef_summary, dict) or gnss_summary.get("skipped"):
        return None
    basis = (georef_summary.get("absolute_accuracy") or {}).get("basis") or []
    kinds = {b.get("kind") for b in basis if isinstance(b, dict)}
    if "base position" not in kinds or "control points" in kinds:
        return None
    pos, bp = gnss_summary.get("base_position_ecef_m"), gnss_summary.get("base_position") or {}
    try:
        pos = [float(v) for v in pos]
    except (TypeError, ValueError):
        return None
    if len(pos) != 3 or not all(math.isfinite(v) for v in pos) or not bp.get("source"):
        return None
    sigma = bp.get("sigma_enu_m")
    try:
        sigma_v = None if sigma is None else float(sigma[2])
    except (TypeError, ValueError, IndexError):
        return None
    return {"position_ecef_m": pos, "source": str(bp["source"]), "sigma_v_m": sigma_v,
            "text": str(bp.get("text") or bp["source"])}


def shared_base(earlier: dict | None, later: dict | None) -> dict | None:
    """The base position both surveys rest on (base_of of each): the same source and positions within
    BASE_POSITION_MATCH_M; else None."""
    if not earlier or not later or earlier["source"] != later["source"]:
        return None
    if math.dist(earlier["position_ecef_m"], later["position_ecef_m"]) > BASE_POSITION_MATCH_M:
        return None
    return earlier


def _base(s, run_id: str) -> dict | None:
    rows = dict(s.execute(select(RunStep.name, RunStep.summary).where(RunStep.run_id == run_id,
                                                                      RunStep.name.in_(("gnss", "georef")))).all())
    return base_of(rows.get("gnss"), rows.get("georef"))


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
    out["base"] = shared_base(_base(s, prev["run_id"]), _base(s, cur["run_id"])) if out["control"] is None else None
    return out


def job_key(inputs: dict) -> str:
    from .runs import canonical_json

    doc = {k: v for k, v in inputs.items() if k not in ("earlier", "later")}
    doc["files"] = [inputs[w][k] for w in ("earlier", "later") for k in ("difference", "cut_fill")]
    return hashlib.sha256(canonical_json(doc).encode()).hexdigest()


def _stale(job: DesignChangeJob, settings) -> bool:
    """Queued for longer than settings.requeue_queued_after_s (its message lost), or running with no heartbeat for
    settings.step_lease_s (its worker lost: a job that runs long while its worker beats is left alone, as a step
    is; a row claimed before heartbeats existed counts from its start)."""
    now = utcnow()
    if job.state == "queued":
        return job.queued_at is not None and job.queued_at < now - timedelta(seconds=settings.requeue_queued_after_s)
    if job.state == "running":
        beat = job.heartbeat_at or job.started_at
        return beat is not None and beat < now - timedelta(seconds=settings.step_lease_s)
    return False


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
                        .values(state="running", worker=worker, started_at=utcnow(), heartbeat_at=utcnow(),
                                attempt=DesignChangeJob.attempt + 1))
        if res.rowcount != 1:
            return None
        job = s.get(DesignChangeJob, job_id)
        return dict(job.inputs), job.attempt


def heartbeat(db, job_id: str, attempt: int) -> bool:
    """The worker of ``attempt`` is alive: heartbeat_at = now. False once the job is no longer its (queued again
    after a stale heartbeat, or claimed by another worker): the worker's result will not be recorded."""
    with db.session() as s:
        res = s.execute(update(DesignChangeJob).where(DesignChangeJob.id == job_id, DesignChangeJob.attempt == attempt,
                                                      DesignChangeJob.state == "running")
                        .values(heartbeat_at=utcnow()))
        return res.rowcount == 1


def reap(db, settings) -> list[tuple]:
    """The reaper's share (worker.tasks.reap_stale_steps, every few seconds as for steps): jobs running with no
    heartbeat for settings.step_lease_s are queued again, jobs queued for settings.requeue_queued_after_s have
    their message sent again; the messages to send. Safe beside a request doing the same: the claim is atomic."""
    now = utcnow()
    with db.session() as s:
        ids = list(s.scalars(update(DesignChangeJob).where(
            DesignChangeJob.state == "running",
            func.coalesce(DesignChangeJob.heartbeat_at, DesignChangeJob.started_at) <
            now - timedelta(seconds=settings.step_lease_s))
            .values(state="queued", queued_at=now, worker=None).returning(DesignChangeJob.id)))
        ids += list(s.scalars(update(DesignChangeJob).where(
            DesignChangeJob.state == "queued",
            DesignChangeJob.queued_at < now - timedelta(seconds=settings.requeue_queued_after_s))
            .values(queued_at=now).returning(DesignChangeJob.id)))
    return [("design-change", i) for i in ids]


def finish(db, job_id: str, attempt: int, result: dict | None = None, error: str | None = None) -> bool:
    """Record the result (or the error) of the attempt that still holds the job; False when it no longer does."""
    with db.session() as s:
        res = s.execute(update(DesignChangeJob).where(DesignChangeJob.id == job_id, DesignChangeJob.attempt == attempt,
                                                      DesignChangeJob.state == "running")
                        .values(state="failed" if error is not None else "succeeded", result=result, error=error,
                                finished_at=utcnow()))
        return res.rowcount == 1


def common_bias(storage, control: dict | None, tmp: Path, base: dict | None = None) -> tuple[float, str]:
    """(1 sigma of the vertical bias common to both surveys, where the figure comes from): module docstring.
    ``control``: the shared control-point files (pair_inputs), ``base``: the shared base position (shared_base)."""
    from georef_core.adjustment.control_points import parse_points_table, read_gcp_list

    from ..storage import blob_key

    if not control and base:
        xyz = ", ".join(f"{v:.3f}" for v in base["position_ecef_m"])
        if base.get("sigma_v_m") is not None:
            return float(base["sigma_v_m"]), (
                f"both surveys PPK against the same base position ({base['source']}: {base['text']}; ECEF {xyz} m) "
                f"and no control points: its stated vertical sigma {float(base['sigma_v_m']):.3f} m is common to both")
        return SURVEYED_BASE_SIGMA_V_M, (
            f"both surveys PPK against the same base position ({base['source']}: {base['text']}; ECEF {xyz} m) "
            f"and no control points: taken as surveyed, the vertical survey accuracy assumed for a surveyed point "
            f"({SURVEYED_BASE_SIGMA_V_M} m) is common to both")
    if not control:
        return 0.0, ("the surveys read different (or no) control-point files and rest on no common base position: "
                     "their vertical biases independent")
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
        common, source = common_bias(storage, inputs.get("control"), tmp, inputs.get("base"))
        try:
            out = surface_change(diff["earlier"], diff["later"], inputs["area"], acc["earlier"], acc["later"],
                                 common_bias_m=common)
        except InputFileError as exc:   # named as the user knows the file, not by the worker's temporary path
            which = "earlier" if exc.path and Path(exc.path).name.startswith("earlier") else "later"
            raise ValueError(f"{inputs[which]['label']}: design/difference.tif: {exc.problem}") from None
    out["accuracy"]["common_bias_source"] = source
    return out
