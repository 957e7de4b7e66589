"""Keep Python's full garbage collections short in the API processes.

A full (generation 2) collection walks every tracked object of the process: after the imports of the API
(SQLAlchemy, pydantic, numpy, pyproj, ...) about 100 000 of them, 66-70 ms on the 2-core development
machine, during which the process answers nothing (it holds the GIL). Under a steady load they come back
every few thousand requests and land in the latency tail. Nearly all of those objects live as long as the
process (modules, classes, compiled statements), so after start-up, and again after any request that
imported new modules (several result formats import their libraries on first use), the heap is collected
once and frozen (`gc.freeze()`): frozen objects are never walked again, a full collection then only sees
what requests allocated since (0.0 ms measured right after freezing). Requests keep their ordinary
collections; nothing is disabled."""

from __future__ import annotations

import gc
import sys


def freeze_heap() -> None:
    """Collect what is garbage now, then move every surviving object out of the collector's sight."""
    gc.collect()
    gc.freeze()


class HeapFreeze:
    """Pure ASGI middleware: freezes the heap after the first request and after any request that grew
    sys.modules (checked once per request: one len())."""

    def __init__(self, app):
        self.app = app
        self._modules_at_freeze = -1

    async def __call__(self, scope, receive, send):
        try:
            await self.app(scope, receive, send)
        finally:
            if scope["type"] == "http" and len(sys.modules) != self._modules_at_freeze:
                self._modules_at_freeze = len(sys.modules)
                freeze_heap()
