"""Celery beat: the periodic tasks (reprocessing schedules, stale-step reaper, expired uploads)."""

from __future__ import annotations

from datetime import timedelta

from backend.core.settings import Settings


def beat_schedule(settings: Settings) -> dict:
    return {
        "dispatch-schedules": {"task": "georef.dispatch_schedules",
                               "schedule": timedelta(seconds=settings.schedule_tick_s)},
        "reap-stale-steps": {"task": "georef.reap_stale_steps",
                             "schedule": timedelta(seconds=max(2.0, settings.step_lease_s / 2))},
        "expire-uploads": {"task": "georef.expire_uploads", "schedule": timedelta(hours=1)},
    }
