"""New data arrived for a survey (base observations, control points): the site's schedules that react to
it get the survey queued (the scheduler, schedules.dispatch_due, starts the runs). A module of its own so
that the services that receive data (uploads, surveys) need not import the scheduler."""

from __future__ import annotations

from sqlalchemy import select

from ..models import Schedule, Survey
from ..models.base import utcnow
from .context import Ctx


def note_new_data(ctx: Ctx, survey: Survey, what: str) -> None:
    """New base data / points for a survey: schedules that react to it get the survey queued."""
    flag = Schedule.on_new_base if what == "base" else Schedule.on_new_points
    for sch in ctx.db.scalars(select(Schedule).where(Schedule.site_id == survey.site_id, Schedule.enabled.is_(True),
                                                      flag.is_(True))):
        pending = list(sch.pending_survey_ids or [])
        if survey.id not in pending:
            pending.append(survey.id)
        sch.pending_survey_ids = pending
        if sch.pending_since is None:
            sch.pending_since = utcnow()
