"""The worker's Celery application: configured from the same settings as the API (GEOREF_* variables).

    celery -A worker.celery_app worker -Q georef,heavy --concurrency 2      # a worker for both queues
    celery -A worker.celery_app worker -Q heavy --concurrency 1             # a georef/dense-only worker
    celery -A worker.celery_app beat                                         # schedules, reaper
"""

from __future__ import annotations

from celery.signals import worker_ready

from backend.core.queue import make_celery_app
from backend.core.settings import get_settings

from .beat import beat_schedule

settings = get_settings()
app = make_celery_app(settings)
app.conf.beat_schedule = beat_schedule(settings)
app.conf.include = ["worker.tasks"]
app.set_default()


@worker_ready.connect
def _on_ready(sender=None, **_):
    """A starting worker re-sends steps whose worker died (after the lease) and cleans its scratch."""
    from .tasks import clean_scratch, reap_stale_steps

    clean_scratch()
    reap_stale_steps.delay()
