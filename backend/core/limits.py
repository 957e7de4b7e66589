"""Admission control: at most N requests inside the application at once per process.

Without it, a burst of requests all open their database session (authentication runs first) and then
wait for a worker thread while holding the connection: the pool runs dry and requests fail after the
pool timeout. Requests beyond N wait here, holding nothing, in arrival order. A request leaves the
limit when its response starts: streamed bodies (server-sent events, file downloads) do not count."""

from __future__ import annotations

import asyncio


class ConcurrencyLimit:
    def __init__(self, app, limit: int):
        self.app = app
        self.limit = limit
        self._sem: asyncio.Semaphore | None = None

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or self.limit <= 0:
            await self.app(scope, receive, send)
            return
        if self._sem is None:
            self._sem = asyncio.Semaphore(self.limit)
        sem = self._sem
        await sem.acquire()
        released = False

        def release():
            nonlocal released
            if not released:
                released = True
                sem.release()

        async def send_wrapper(message):
            if message["type"] == "http.response.start":
                release()
            await send(message)

        try:
            await self.app(scope, receive, send_wrapper)
        finally:
            release()
