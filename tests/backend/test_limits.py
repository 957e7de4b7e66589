"""Admission control (backend/core/limits.py): reads wait for their own, lower limit; writes only for the
general one; a slot is given back when the response starts."""

from __future__ import annotations

import asyncio

from backend.core.limits import ConcurrencyLimit
from backend.core.settings import Settings


def _recording_app(inside: list[int], peak: dict, gate: asyncio.Event):
    """Counts requests inside (all, and per method: peak[method] is the most of that method at once)."""
    per_method: dict[str, int] = {}

    async def app(scope, receive, send):
        m = scope["method"]
        inside[0] += 1
        per_method[m] = per_method.get(m, 0) + 1
        peak[m] = max(peak.get(m, 0), per_method[m])
        await gate.wait()
        inside[0] -= 1
        per_method[m] -= 1
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b""})
    return app


async def _call(app, method: str):
    sent = []

    async def receive():
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message):
        sent.append(message)

    await app({"type": "http", "method": method, "path": "/"}, receive, send)
    return sent


def test_reads_have_their_own_limit_and_writes_do_not_wait_for_it():
    async def scenario():
        inside, peak, gate = [0], {}, asyncio.Event()
        app = ConcurrencyLimit(_recording_app(inside, peak, gate), limit=6, read_limit=2)
        reads = [asyncio.create_task(_call(app, "GET")) for _ in range(5)]
        await asyncio.sleep(0.01)
        assert inside[0] == 2                          # two reads in, three waiting
        writes = [asyncio.create_task(_call(app, "POST")) for _ in range(3)]
        await asyncio.sleep(0.01)
        assert inside[0] == 5                          # the writes got in beside the two reads
        gate.set()
        done = await asyncio.gather(*reads, *writes)
        assert all(m[0]["status"] == 200 for m in done)
        assert peak["GET"] == 2 and peak["POST"] == 3 and inside[0] == 0

    asyncio.run(scenario())


def test_general_limit_still_bounds_everything():
    async def scenario():
        inside, peak, gate = [0], {}, asyncio.Event()
        app = ConcurrencyLimit(_recording_app(inside, peak, gate), limit=3, read_limit=8)
        tasks = [asyncio.create_task(_call(app, m)) for m in ("GET", "POST", "GET", "PUT", "GET", "DELETE")]
        await asyncio.sleep(0.01)
        assert inside[0] == 3
        gate.set()
        await asyncio.gather(*tasks)
        assert inside[0] == 0

    asyncio.run(scenario())


def test_default_read_limit_follows_the_cores(monkeypatch):
    monkeypatch.setattr("os.cpu_count", lambda: 8)
    assert Settings(max_concurrent_reads=0).resolved_max_concurrent_reads() == 16
    monkeypatch.setattr("os.cpu_count", lambda: 1)
    assert Settings(max_concurrent_reads=0).resolved_max_concurrent_reads() == 4
    assert Settings(max_concurrent_reads=6).resolved_max_concurrent_reads() == 6
