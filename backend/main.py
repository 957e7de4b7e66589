"""The ASGI application: `backend.main:app` (uvicorn backend.main:app)."""

from __future__ import annotations

import logging
from pathlib import Path

from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import FileResponse

from .api.router import include_api
from .core.heap_freeze import HeapFreeze
from .core.limits import ConcurrencyLimit, RequestBodyGuard
from .core.problems import NotFound, install_problem_handlers
from .core.settings import Settings, get_settings
from .db.session import get_database
from .storage import storage_for

API_DESCRIPTION = """Georef web platform: sites, surveys, resumable uploads, processing runs (PPK, georeferencing,
dense surface, volumes, report), results as JSON/CSV/GeoJSON/COG/LAS/LAZ/PDF.

Authentication: browser session cookie + `X-CSRF-Token` header on unsafe methods, or `Authorization: Bearer grf_...`
API tokens. Errors are `application/problem+json` (RFC 9457). See docs/api.md."""


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or get_settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    app = FastAPI(title="Georef API", version="1.0.0", description=API_DESCRIPTION, openapi_url="/openapi.json",
                  docs_url="/docs", redoc_url=None)
    app.state.settings = settings
    app.state.database = get_database(settings.resolved_database_url())
    app.state.storage = storage_for(settings)
    install_problem_handlers(app)
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_credentials=True,
                           allow_methods=["*"], allow_headers=["*"], expose_headers=["ETag", "Link", "X-Total-Count", "Retry-After"])

    app.add_middleware(SecurityHeaders)
    if settings.freeze_heap:
        app.add_middleware(HeapFreeze)
    app.add_middleware(ConcurrencyLimit, limit=settings.max_concurrent_requests,
                       read_limit=settings.resolved_max_concurrent_reads())
    # outermost: a request is admitted only once its body is here (slow senders hold no admission slot)
    app.add_middleware(RequestBodyGuard, settings=settings)
    include_api(app)
    dist = settings.resolved_frontend_dist()
    if dist is not None:
        _serve_frontend(app, dist)
    logging.getLogger("georef").setLevel(logging.INFO)
    return app


class SecurityHeaders:
    """Pure ASGI (no per-request task, unlike BaseHTTPMiddleware): a few headers on every response."""

    HEADERS = [(b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"same-origin"),
               (b"x-frame-options", b"DENY")]

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                have = {k.lower() for k, _ in message.get("headers", [])}
                message = {**message, "headers": list(message.get("headers", []))
                           + [h for h in self.HEADERS if h[0] not in have]}
            await send(message)

        await self.app(scope, receive, send_with_headers)


def _serve_frontend(app: FastAPI, dist: Path) -> None:
    """The built browser UI at / (single-page app: unknown paths get index.html)."""
    root = dist.resolve()

    @app.get("/{path:path}", include_in_schema=False)
    def spa(path: str):
        if path.startswith("api/"):
            raise NotFound("no such API endpoint")
        target = (root / path).resolve()
        if path and root in target.parents and target.is_file():
            return FileResponse(target)
        return FileResponse(root / "index.html", headers={"Cache-Control": "no-cache"})


app = create_app()
