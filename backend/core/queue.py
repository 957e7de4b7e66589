"""The Celery application, configured from the settings: the API sends tasks by name through it and
the worker (worker/celery_app.py) runs them. Same code for the embedded broker (SQLite file through
kombu's SQLAlchemy transport) and for Redis."""

from __future__ import annotations

import logging
import threading

from celery import Celery

from .settings import Settings

log = logging.getLogger("georef.queue")

RUN_STEP_TASK = "georef.run_step"
RUN_PART_TASK = "georef.run_part"
DELIVER_WEBHOOK_TASK = "georef.deliver_webhook"
DESIGN_CHANGE_TASK = "georef.design_change"

_apps: dict[str, Celery] = {}
_lock = threading.Lock()


def make_celery_app(settings: Settings) -> Celery:
    broker = settings.resolved_broker_url()
    app = Celery("georef", broker=broker, set_as_current=False)
    transport_options = {"visibility_timeout": settings.visibility_timeout_s,
                         "unacked_restore_interval": settings.broker_restore_interval_s,
                         "unacked_restore_throttle": 1}
    if broker.startswith("sqla+"):
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        transport_options = {}
    app.conf.update(
        task_serializer="json", accept_content=["json"], result_serializer="json",
        task_ignore_result=True, result_backend=None,
        task_acks_late=True, task_reject_on_worker_lost=True, worker_prefetch_multiplier=1,
        task_default_queue=settings.default_queue, broker_transport_options=transport_options,
        broker_connection_retry_on_startup=True, worker_hijack_root_logger=False,
        worker_cancel_long_running_tasks_on_connection_loss=True,
        timezone="UTC", enable_utc=True,
    )
    return app


def client_for(settings: Settings) -> Celery:
    """One sending app per broker URL (connection pool reused across requests)."""
    key = settings.resolved_broker_url()
    with _lock:
        app = _apps.get(key)
        if app is None:
            app = _apps[key] = make_celery_app(settings)
        return app


def send_step(settings: Settings, run_id: str, step: str) -> bool:
    from ..services.steps_catalog import queue_for

    queue = queue_for(step, settings.default_queue, settings.heavy_queue)
    try:
        client_for(settings).send_task(RUN_STEP_TASK, args=[run_id, step], queue=queue, retry=True,
                                       retry_policy={"max_retries": 2, "interval_start": 0.2, "interval_step": 0.5})
        return True
    except Exception as exc:   # broker down: the step stays queued; the reaper re-sends it
        log.warning("could not send step %s of run %s to the broker (%s); it will be re-sent", step, run_id, exc)
        return False


def send_part(settings: Settings, run_id: str, step: str, index: int) -> bool:
    """One part of a step that runs on several workers, to the step's queue."""
    from ..services.steps_catalog import queue_for

    queue = queue_for(step, settings.default_queue, settings.heavy_queue)
    try:
        client_for(settings).send_task(RUN_PART_TASK, args=[run_id, step, int(index)], queue=queue, retry=True,
                                       retry_policy={"max_retries": 2, "interval_start": 0.2, "interval_step": 0.5})
        return True
    except Exception as exc:   # broker down: the part stays queued; the reaper re-sends it
        log.warning("could not send part %s of step %s of run %s (%s); it will be re-sent", index, step, run_id, exc)
        return False


def send_webhook(settings: Settings, delivery_id: str, countdown: float = 0.0) -> bool:
    try:
        client_for(settings).send_task(DELIVER_WEBHOOK_TASK, args=[delivery_id], queue=settings.default_queue,
                                       countdown=countdown or None)
        return True
    except Exception as exc:
        log.warning("could not send webhook delivery %s (%s); it will be re-sent", delivery_id, exc)
        return False


def send_design_change(settings: Settings, job_id: str) -> bool:
    """The change between two surveys of a design (services/design_changes), to the default queue."""
    try:
        client_for(settings).send_task(DESIGN_CHANGE_TASK, args=[job_id], queue=settings.default_queue, retry=True,
                                       retry_policy={"max_retries": 2, "interval_start": 0.2, "interval_step": 0.5})
        return True
    except Exception as exc:   # broker down: the job stays queued; the reaper (or a request) re-sends it
        log.warning("could not send design change %s (%s); it will be re-sent", job_id, exc)
        return False
