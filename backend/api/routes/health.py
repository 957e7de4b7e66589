"""/health: is the service usable (database, storage, broker)?"""

from __future__ import annotations

from fastapi import APIRouter, Request
from sqlalchemy import text

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
    try:
        ctx.storage.check()
        checks["storage"] = "ok"
    except Exception as exc:
        checks["storage"] = f"error: {type(exc).__name__}"
    if request.query_params.get("broker") == "1":
        try:
            from ...core.queue import client_for

            with client_for(ctx.settings).connection_for_write() as conn:
                conn.ensure_connection(max_retries=1)
            checks["broker"] = "ok"
        except Exception as exc:
            checks["broker"] = f"error: {type(exc).__name__}"
    if not all(v == "ok" for v in checks.values()):
        from ...core.problems import problem_response

        bad = ", ".join(k for k, v in checks.items() if v != "ok")
        return problem_response(503, f"unavailable: {bad}", slug="degraded", instance=request.url.path, checks=checks)
    return json_response(request, {"status": "ok", "checks": checks})
