"""What a finished run changed against the previous successful run of the same survey (inputs,
settings, GNSS fix rate, check-point RMSE, stockpile volumes), and the notifications of its end."""

from __future__ import annotations

import json
import logging

from sqlalchemy import select

from ..models import Run, RunOutput, VolumeMeasurement
from ..storage import Storage, blob_key
from . import result_files
from .webhooks import enqueue_event

log = logging.getLogger("georef.changes")


def _json_output(s, storage: Storage, run_id: str, paths) -> dict | None:
    for p in paths:
        o = s.scalar(select(RunOutput).where(RunOutput.run_id == run_id, RunOutput.path == p))
        if o is not None:
            try:
                return json.loads(storage.read_bytes(blob_key(o.sha256)))
            except (OSError, ValueError):
                return None
    return None


def _rmse(s, storage: Storage, run_id: str) -> float | None:
    oj = s.scalar(select(RunOutput).where(RunOutput.run_id == run_id, RunOutput.path == "residuals.json"))
    oc = s.scalar(select(RunOutput).where(RunOutput.run_id == run_id, RunOutput.path == "residuals.csv"))
    if oj is None and oc is None:
        return None
    try:
        res = result_files.normalise_residuals(storage.read_bytes(blob_key(oj.sha256)).decode() if oj else None,
                                               storage.read_bytes(blob_key(oc.sha256)).decode() if oc else None)
    except (OSError, ValueError):
        return None
    return result_files.rmse_3d_m(res)


def _volumes(s, run_id: str) -> dict[str, float | None]:
    return {v.stockpile_name: v.volume_m3 for v in s.scalars(select(VolumeMeasurement)
                                                             .where(VolumeMeasurement.run_id == run_id))}


def run_metrics(s, storage: Storage, run_id: str) -> dict:
    gs = _json_output(s, storage, run_id, ("ppk/summary.json", "ppk/trajectory_summary.json")) or {}
    return {"fix_rate": gs.get("fix_rate"), "rmse_d_m": _rmse(s, storage, run_id), "volumes": _volumes(s, run_id)}


def compute_changes(s, storage: Storage, run: Run) -> dict:
    prev = s.get(Run, run.previous_run_id) if run.previous_run_id else None
    now = run_metrics(s, storage, run.id)
    if prev is None:
        return {"previous_run_id": None, "note": "first successful run of this survey", "current": now}
    before = run_metrics(s, storage, prev.id)
    a, b = prev.inputs or {}, run.inputs or {}
    inputs = {"added": sorted(set(b) - set(a)), "removed": sorted(set(a) - set(b)),
              "modified": sorted(k for k in set(a) & set(b) if a[k] != b[k])}
    settings_changed = sorted(k for k in set(prev.settings or {}) | set(run.settings or {})
                              if (prev.settings or {}).get(k) != (run.settings or {}).get(k))
    vols = {}
    for name in sorted(set(before["volumes"]) | set(now["volumes"])):
        v0, v1 = before["volumes"].get(name), now["volumes"].get(name)
        vols[name] = {"previous_m3": v0, "current_m3": v1,
                      "change_m3": (v1 - v0) if (v0 is not None and v1 is not None) else None}

    def delta(k):
        x0, x1 = before.get(k), now.get(k)
        return {"previous": x0, "current": x1, "change": (x1 - x0) if (x0 is not None and x1 is not None) else None}

    return {"previous_run_id": prev.id, "previous_run_number": prev.number, "inputs": inputs,
            "settings_changed": settings_changed, "fix_rate": delta("fix_rate"), "rmse_d_m": delta("rmse_d_m"),
            "volumes": vols}


def record_changes(s, storage: Storage, run: Run) -> None:
    """run.changes: the comparison with the previous successful run (never an error for the run itself)."""
    try:
        run.changes = compute_changes(s, storage, run)
    except Exception as exc:   # a comparison must never turn a finished run into an error
        run.changes = {"error": f"comparison failed: {type(exc).__name__}: {exc}"}


def on_run_finished(db, storage: Storage, run_id: str) -> list[tuple]:
    """Record the comparison and queue the webhook deliveries; messages to send after commit."""
    with db.session() as s:
        run = s.get(Run, run_id)
        if run is None:
            return []
        if run.state == "succeeded" and run.changes is None:   # normally recorded with the run's end (jobs)
            record_changes(s, storage, run)
        payload = {"run_id": run.id, "run_number": run.number, "survey_id": run.survey_id, "site_id": run.site_id,
                   "state": run.state, "error": run.error, "trigger": run.trigger,
                   "finished_at": run.finished_at.isoformat() if run.finished_at else None,
                   "changes": run.changes if run.state == "succeeded" else None}
        msgs = enqueue_event(s, run.site_id, f"run.{run.state}", payload)
        if run.state == "succeeded":   # the site's design changes between surveys, computed ahead of the first view
            from .designs import queue_changes_after_run

            try:
                with s.begin_nested():
                    msgs += queue_changes_after_run(s, run)
            except Exception as exc:   # never an error for the run: design-progress queues them when asked
                log.warning("design changes of run %s not queued: %s", run.id, exc)
        return msgs
