"""Per-site reprocessing schedules: on a cadence (hourly, daily, weekly at a UTC time) and/or when new
base data or a new points file arrives (debounced, so that a batch of uploads makes one run).

`dispatch_due` is called by Celery beat every minute; each due schedule is claimed atomically
(UPDATE ... WHERE next_run_at = <what I read>) so that two beat processes never start the same run."""

from __future__ import annotations

import logging
import re
from datetime import datetime, timedelta

from sqlalchemy import select, update

from ..core.problems import Unprocessable
from ..models import Run, Schedule, Survey
from ..models.base import utcnow
from . import steps_catalog
from .context import Ctx
from .permissions import require_schedule, require_site
from .sites import check_if_match
from .runs import add_log, create_run, merge_settings, settings_hash
from .surveys import survey_files, validate_settings

log = logging.getLogger("georef.schedules")
CADENCES = ("none", "hourly", "daily", "weekly")
_HHMM = re.compile(r"^([01]\d|2[0-3]):([0-5]\d)$")


def next_due(cadence: str, at_utc: str, weekday: int, now: datetime) -> datetime | None:
    if cadence == "none":
        return None
    m = _HHMM.match(at_utc)
    hh, mm = (int(m.group(1)), int(m.group(2))) if m else (2, 0)
    now = now.replace(second=0, microsecond=0)
    if cadence == "hourly":
        t = now.replace(minute=mm)
        return t if t > now else t + timedelta(hours=1)
    t = now.replace(hour=hh, minute=mm)
    if cadence == "daily":
        return t if t > now else t + timedelta(days=1)
    days = (weekday - t.weekday()) % 7
    t = t + timedelta(days=days)
    return t if t > now else t + timedelta(days=7)


def _validate(fields: dict) -> dict:
    if "cadence" in fields and fields["cadence"] not in CADENCES:
        raise Unprocessable(f"cadence: one of {', '.join(CADENCES)}")
    if "at_utc" in fields and fields["at_utc"] is not None and not _HHMM.match(fields["at_utc"]):
        raise Unprocessable("at_utc: HH:MM (24 h, UTC)")
    if "weekday" in fields and fields["weekday"] is not None and not 0 <= int(fields["weekday"]) <= 6:
        raise Unprocessable("weekday: 0 (Monday) to 6 (Sunday)")
    if "scope" in fields and fields["scope"] not in ("latest", "all"):
        raise Unprocessable("scope: latest or all")
    if fields.get("steps") is not None:
        try:
            fields["steps"] = steps_catalog.plan(fields["steps"])
        except ValueError as exc:
            raise Unprocessable(f"steps: {exc}") from None
    if "settings" in fields:
        fields["settings"] = validate_settings(fields["settings"])
    return fields


def create_schedule(ctx: Ctx, site_id: str, fields: dict) -> Schedule:
    require_site(ctx, site_id, "admin")
    fields = _validate(dict(fields))
    sch = Schedule(site_id=site_id, **fields)
    sch.next_run_at = next_due(sch.cadence or "daily", sch.at_utc or "02:00", sch.weekday or 0, utcnow()) \
        if sch.enabled is not False else None
    ctx.db.add(sch)
    ctx.db.flush()
    return sch


def list_schedules(ctx: Ctx, site_id: str) -> list[Schedule]:
    require_site(ctx, site_id, "viewer")
    return list(ctx.db.scalars(select(Schedule).where(Schedule.site_id == site_id).order_by(Schedule.name)))


def get_schedule(ctx: Ctx, schedule_id: str) -> Schedule:
    return require_schedule(ctx, schedule_id, "viewer")


def update_schedule(ctx: Ctx, schedule_id: str, changes: dict, if_match: str | None = None) -> Schedule:
    sch = require_schedule(ctx, schedule_id, "admin")
    check_if_match(sch, if_match)
    changes = _validate({k: v for k, v in changes.items() if v is not None or k == "steps"})
    for k, v in changes.items():
        setattr(sch, k, v)
    sch.next_run_at = next_due(sch.cadence, sch.at_utc, sch.weekday, utcnow()) if sch.enabled else None
    sch.version += 1
    ctx.db.flush()
    return sch


def delete_schedule(ctx: Ctx, schedule_id: str, if_match: str | None = None) -> None:
    sch = require_schedule(ctx, schedule_id, "admin")
    check_if_match(sch, if_match)
    ctx.db.delete(sch)
    ctx.db.flush()


def _surveys_in_scope(db, sch: Schedule) -> list[Survey]:
    stmt = select(Survey).where(Survey.site_id == sch.site_id).order_by(Survey.flown_at.desc().nulls_last(),
                                                                       Survey.created_at.desc())
    if sch.scope == "latest":
        stmt = stmt.limit(1)
    return list(db.scalars(stmt))


def _unchanged_since_last_run(db, survey: Survey, sch: Schedule) -> bool:
    last = db.scalar(select(Run).where(Run.survey_id == survey.id, Run.state == "succeeded")
                     .order_by(Run.number.desc()).limit(1))
    if last is None:
        return False
    inputs = {f.path: f.sha256 for f in survey_files(db, survey.id)}
    return inputs == last.inputs and settings_hash(merge_settings(survey.settings, sch.settings)) == last.settings_hash


def dispatch_due(ctx: Ctx, now: datetime | None = None) -> list[str]:
    """Start the runs of due schedules; the ids of the runs created."""
    now = now or utcnow()
    created: list[str] = []
    debounce = timedelta(seconds=ctx.settings.new_data_debounce_s)
    for sch in list(ctx.db.scalars(select(Schedule).where(Schedule.enabled.is_(True)))):
        jobs: list[tuple[Survey, str]] = []
        if sch.next_run_at is not None and sch.next_run_at <= now:
            nxt = next_due(sch.cadence, sch.at_utc, sch.weekday, now)
            won = ctx.db.execute(update(Schedule).where(Schedule.id == sch.id, Schedule.next_run_at == sch.next_run_at)
                                 .values(next_run_at=nxt).execution_options(synchronize_session=False)).rowcount
            if won == 1:
                for sv in _surveys_in_scope(ctx.db, sch):
                    if sch.only_if_changed and _unchanged_since_last_run(ctx.db, sv, sch):
                        continue
                    jobs.append((sv, "schedule"))
        if sch.pending_since is not None and sch.pending_since <= now - debounce and sch.pending_survey_ids:
            waiting = list(sch.pending_survey_ids)   # read before the UPDATE refreshes the row
            won = ctx.db.execute(update(Schedule).where(Schedule.id == sch.id,
                                                        Schedule.pending_since == sch.pending_since)
                                 .values(pending_since=None, pending_survey_ids=[])
                                 .execution_options(synchronize_session=False)).rowcount
            if won == 1:
                for sid in waiting:
                    sv = ctx.db.get(Survey, sid)
                    if sv is not None and all(sv.id != j[0].id for j in jobs):
                        jobs.append((sv, "new-data"))
        for sv, trigger in jobs:
            try:
                run = create_run(ctx, sv.id, sch.steps, sch.settings, trigger=trigger, check_role=False)
            except Exception as exc:   # a survey without files: noted, the other surveys go on
                from ..core.problems import Problem

                if not isinstance(exc, Problem):
                    raise
                log.warning("schedule %s: survey %s not processed: %s", sch.name, sv.id, exc)
                continue
            add_log(ctx.db, run.id, f"started by schedule {sch.name!r}")
            created.append(run.id)
        ctx.db.flush()
    return created
