"""The worker id recorded on a claimed step names the process that runs it: in a prefork pool that is the
pool's child, not the parent that imported worker.tasks before forking (found by docker compose up: every
step of a 4-process worker container was recorded as run by the parent)."""

from __future__ import annotations

import multiprocessing
import os
import socket

import pytest


def _child_worker_id(queue) -> None:
    from worker.tasks import worker_id

    queue.put((os.getpid(), worker_id()))


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs fork (a prefork pool)")
def test_worker_id_is_the_forked_childs():
    from worker.tasks import worker_id

    parent = worker_id()
    assert parent == f"{socket.gethostname()}:{os.getpid()}"
    ctx = multiprocessing.get_context("fork")
    q = ctx.Queue()
    p = ctx.Process(target=_child_worker_id, args=(q,))
    p.start()
    child_pid, child_id = q.get(timeout=60)
    p.join(timeout=60)
    assert child_pid != os.getpid()
    assert child_id == f"{socket.gethostname()}:{child_pid}" != parent
