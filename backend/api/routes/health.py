"""/health: is the service usable (database, storage, broker)?"""

from __future__ import annotations

from fastapi import APIRouter, Request
from sqlalchemy import text

from ...storage.base import StorageFull
from ..deps import PublicCtxDep
from ..responses import json_response

router = APIRouter(tags=["service"])


@router.get("/health", summary="Database, storage and broker reachability")
def health(ctx: PublicCtxDep, request: Request):
    checks = {}
    try:
        ctx.db.execute(text("SELECT 1"))
        checks["database"] = "ok"
    except Exception as exc:   # report, do not raise: this endpoint is for monitoring
        checks["database"] = f"error: {type(exc).__name__}"
    minimum = ctx.settings.min_free_storage_bytes
    try:
        ctx.storage.check(minimum)
        checks["storage"] = "ok"
    except StorageFull:
        checks["storage"] = "full"
    except Exception as exc:
        checks["storage"] = f"error: {type(exc).__name__}"
    # the work folder: upload chunks and request bodies are received there before they are stored
    try:
        checks["work_disk"] = "full" if _free_bytes(ctx.settings.resolved_work_dir()) < max(minimum, 1) else "ok"
    except OSError as exc:
        checks["work_disk"] = f"error: {type(exc).__name__}"
    checks["broker"] = broker_status(ctx.settings.resolved_broker_url(), BROKER_TIMEOUT_S)
    if not all(v == "ok" for v in checks.values()):
        from ...core.problems import problem_response

        bad = ", ".join(k for k, v in checks.items() if v != "ok")
        return problem_response(503, f"unavailable: {bad}", slug="degraded", instance=request.url.path, checks=checks)
    return json_response(request, {"status": "ok", "checks": checks})


def _free_bytes(path) -> int:
    import os

    path.mkdir(parents=True, exist_ok=True)
    st = os.statvfs(path)
    return st.f_bavail * st.f_frsize


# --- broker ----------------------------------------------------------------------------------------------
BROKER_TIMEOUT_S = 1.0


def broker_status(url: str, timeout_s: float = BROKER_TIMEOUT_S) -> str:
    """'ok' or 'error: <type>': can the broker be reached within ``timeout_s``? Redis (production shape): a
    PING; the embedded shape's broker is the SQLite file its local worker reads (kombu's SQLAlchemy
    transport): the file is opened and its header read; another broker: a kombu connection."""
    try:
        if url.startswith(("redis://", "rediss://", "unix://")):
            import redis

            client = redis.Redis.from_url(url, socket_connect_timeout=timeout_s, socket_timeout=timeout_s)
            try:
                client.ping()
            finally:
                client.close()
        elif url.startswith("sqla+sqlite:///"):
            import sqlite3

            con = sqlite3.connect(url.removeprefix("sqla+sqlite:///"), timeout=timeout_s)
            try:
                con.execute("PRAGMA schema_version").fetchone()
            finally:
                con.close()
        else:
            from kombu import Connection

            with Connection(url, connect_timeout=timeout_s) as conn:
                conn.ensure_connection(max_retries=1, interval_start=0, interval_step=0, timeout=timeout_s)
        return "ok"
    except Exception as exc:   # reported, not raised (monitoring)
        return f"error: {type(exc).__name__}"
