"""The worker's Celery application: configured from the same settings as the API (GEOREF_* variables).

    celery -A worker.celery_app worker -Q georef,heavy --concurrency 2      # a worker for both queues
    celery -A worker.celery_app worker -Q heavy --concurrency 1             # a georef/dense-only worker
    celery -A worker.celery_app beat                                         # schedules, reaper
"""

from __future__ import annotations

import signal
import threading

from celery.signals import beat_embedded_init, task_postrun, worker_init, worker_process_init, worker_ready

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


# --- clean shutdown --------------------------------------------------------------------------------------
# pycolmap (through glog's failure signal handler) replaces the process's SIGTERM handler when it is first
# imported, at C level: after a georef step the worker no longer shut down warmly on SIGTERM but printed a
# native stack trace and died at once, leaving its embedded beat child running with parent 1. Loaded here,
# before Celery installs its own handlers (worker_init runs before them), Celery's handlers are the ones in
# force; after every task the Python-level handlers are put back in force again, in case a library
# installed a native one meanwhile.
_SHUTDOWN_SIGNALS = ("SIGTERM", "SIGINT", "SIGQUIT")


def _load_native_libraries() -> None:
    try:
        import pycolmap  # noqa: F401
    except ImportError:     # a worker without the SfM extra: nothing replaces the handlers
        pass


def rearm_signal_handlers() -> None:
    """Re-install the Python-level handlers of the shutdown signals (main thread only): a native library
    that replaced one with sigaction() no longer intercepts the signal."""
    if threading.current_thread() is not threading.main_thread():
        return
    for name in _SHUTDOWN_SIGNALS:
        sig = getattr(signal, name, None)
        if sig is None:
            continue
        handler = signal.getsignal(sig)
        if handler is not None:
            signal.signal(sig, handler)


@worker_init.connect
def _on_worker_init(**_):
    _load_native_libraries()


@worker_process_init.connect
def _on_worker_process_init(**_):
    # a prefork child: the library is already loaded (inherited); its handlers are the ones Celery set
    rearm_signal_handlers()


@task_postrun.connect
def _on_task_postrun(**_):
    rearm_signal_handlers()


@beat_embedded_init.connect
def _on_beat_embedded_init(**_):
    """The beat child of ``celery worker -B`` ends with the worker, however the worker ends."""
    die_with_parent()


def die_with_parent(sig: int = signal.SIGTERM) -> None:
    """Linux: this process gets ``sig`` when its parent dies (PR_SET_PDEATHSIG)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(sig))
    except (OSError, AttributeError):
        return
    import os

    if os.getppid() == 1:       # the parent died before the request took effect
        os.kill(os.getpid(), sig)
