"""Progress reporting shared by every step.

A step calls ``progress(stage, done, total)`` as it works (``total`` 0 when unknown). The caller (the
CLI's progress bar, a Celery task updating the database) may raise
:class:`georef_core.errors.StepCancelled` from the callback to cancel the step.
"""

from __future__ import annotations

from typing import Callable

ProgressFn = Callable[[str, int, int], None]


def no_progress(stage: str, done: int, total: int) -> None:
    """The default callback: report nothing."""
    return None
