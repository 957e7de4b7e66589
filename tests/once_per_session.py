"""Expensive fixtures (a rendered survey, a georeferenced survey, one dense run, a real block's SfM) computed
once per test session, not once per xdist worker.

Under ``pytest -n 2`` each worker process has its own session, so a session or module fixture used by tests
that land on both workers was computed twice: on a 2-core machine that doubles its cost in wall time. (Keeping a
module's tests on one worker instead, ``--dist loadgroup``, was slower here: the whole suite took 24 min 20 s,
a module of heavy tests then runs on one worker alone.) Here the first worker
that asks computes the value into a folder shared by the workers (the session's base temporary folder's
parent, which is this run's own ``pytest-N``), pickles it beside, and the other worker waits on a file lock and
loads it. Without xdist it is an ordinary session fixture.

Only for values that tests read and do not change: a test that writes into the folder would change it for the
other worker too.
"""

from __future__ import annotations

import fcntl
import os
import pickle
from pathlib import Path
from typing import Callable, TypeVar

T = TypeVar("T")


def once_per_session(tmp_path_factory, key: str, make: Callable[[Path], T]) -> T:
    """``make(folder)`` once for the whole test session (all xdist workers), its value pickled for the others.

    ``key`` names the folder and must be unique among the session's shared fixtures."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return make(tmp_path_factory.mktemp(key))
    root = tmp_path_factory.getbasetemp().parent / "once_per_session"
    root.mkdir(exist_ok=True)
    folder, stored = root / key, root / f"{key}.pickle"
    with open(root / f"{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)       # released when the file closes, also on an exception
        if stored.is_file():
            return pickle.loads(stored.read_bytes())
        folder.mkdir(exist_ok=True)
        value = make(folder)
        tmp = stored.with_suffix(".part")
        tmp.write_bytes(pickle.dumps(value))
        tmp.replace(stored)
        return value
