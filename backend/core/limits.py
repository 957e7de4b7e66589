"""Admission control: at most N requests inside the application at once per process, and at most R of
them reads (GET/HEAD).

Without it, a burst of requests all open their database session (authentication runs first) and then
wait for a worker thread while holding the connection: the pool runs dry and requests fail after the
pool timeout. Requests beyond the limit wait here, holding nothing, in arrival order. A request leaves the
limit when its response starts: streamed bodies (server-sent events, file downloads) do not count.

Reads have their own, lower limit: they are short and CPU-bound (a few milliseconds of Python and one or
two queries), so more of them at once only share the cores and the GIL and lengthen every one of them.
On the 2-core development machine with PostgreSQL, 200 readers at 1 request/s: p99 197 ms with 32 reads
at once per process, 73-95 ms with 8, 39-58 ms with 4 (docs/deploy.md). Writes (uploads stream their
chunks in) keep the general limit only, so slow uploads do not hold back readers."""

from __future__ import annotations

import asyncio

SAFE_METHODS = ("GET", "HEAD")


class ConcurrencyLimit:
    def __init__(self, app, limit: int, read_limit: int = 0):
        self.app = app
        self.limit = limit
        self.read_limit = read_limit
        self._sem: asyncio.Semaphore | None = None
        self._read_sem: asyncio.Semaphore | None = None

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or self.limit <= 0:
            await self.app(scope, receive, send)
            return
        if self._sem is None:
            self._sem = asyncio.Semaphore(self.limit)
            self._read_sem = asyncio.Semaphore(self.read_limit) if self.read_limit > 0 else None
        sems = [self._sem]
        if self._read_sem is not None and scope.get("method") in SAFE_METHODS:
            sems.insert(0, self._read_sem)
        for sem in sems:
            await sem.acquire()
        released = False

        def release():
            nonlocal released
            if not released:
                released = True
                for sem in sems:
                    sem.release()

        async def send_wrapper(message):
            if message["type"] == "http.response.start":
                release()
            await send(message)

        try:
            await self.app(scope, receive, send_wrapper)
        finally:
            release()
