"""Heap freezing of the API processes (backend/core/heap_freeze.py): after the first request and after any
request that imported modules, the long-lived heap is out of the collector's sight, so full collections
stay short; other requests do not freeze again."""

from __future__ import annotations

import asyncio
import gc
import sys
import types

from backend.core.heap_freeze import HeapFreeze
from backend.core.settings import Settings


def _app(imports: list[str]):
    async def app(scope, receive, send):
        for name in imports:                       # a request that imports a module on first use
            sys.modules.setdefault(name, types.ModuleType(name))
        imports.clear()
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"ok"})
    return app


async def _get(app) -> int:
    sent = []

    async def receive():
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message):
        sent.append(message)

    await app({"type": "http", "method": "GET", "path": "/"}, receive, send)
    return sent[0]["status"]


def test_heap_frozen_after_first_request_and_after_imports():
    gc.unfreeze()
    imports: list[str] = []
    app = HeapFreeze(_app(imports))
    try:
        assert gc.get_freeze_count() == 0
        assert asyncio.run(_get(app)) == 200
        first = gc.get_freeze_count()
        assert first > 10_000                      # this test process's modules, classes, functions ...
        walked = len(gc.get_objects())             # what a full collection walks now (frozen ones excluded)
        assert walked < first / 10
        assert asyncio.run(_get(app)) == 200
        assert gc.get_freeze_count() == first      # no new module: no second freeze
        imports.append("georef_test_heap_freeze_module")
        junk = [[i] for i in range(1000)]          # live objects created since: frozen with the module
        assert asyncio.run(_get(app)) == 200
        assert gc.get_freeze_count() >= first + 1000
        del junk
    finally:
        gc.unfreeze()
        sys.modules.pop("georef_test_heap_freeze_module", None)


def test_heap_freeze_is_a_setting(tmp_path):
    from backend.main import create_app

    def classes(settings):
        return [m.cls for m in create_app(settings).user_middleware]

    assert HeapFreeze in classes(Settings(data_dir=tmp_path))
    assert HeapFreeze not in classes(Settings(data_dir=tmp_path, freeze_heap=False))
