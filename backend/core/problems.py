"""RFC 9457 problem details: the exceptions services raise and the handlers that turn every error
(ours, FastAPI's validation errors, Starlette's HTTP errors, unexpected bugs) into application/problem+json."""

from __future__ import annotations

import logging
from http import HTTPStatus

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

log = logging.getLogger("georef.api")

PROBLEM_MEDIA_TYPE = "application/problem+json"
TYPE_BASE = "https://georef.example/problems/"


class Problem(Exception):
    status = 400
    slug = "bad-request"

    def __init__(self, detail: str, *, status: int | None = None, slug: str | None = None,
                 headers: dict | None = None, **extra):
        super().__init__(detail)
        self.detail = detail
        if status is not None:
            self.status = status
        if slug is not None:
            self.slug = slug
        self.headers = headers or {}
        self.extra = extra


class BadRequest(Problem):
    status, slug = 400, "bad-request"


class Unauthorized(Problem):
    status, slug = 401, "unauthorized"


class Forbidden(Problem):
    status, slug = 403, "forbidden"


class NotFound(Problem):
    status, slug = 404, "not-found"


class Conflict(Problem):
    status, slug = 409, "conflict"


class PreconditionFailed(Problem):
    status, slug = 412, "precondition-failed"


class PayloadTooLarge(Problem):
    status, slug = 413, "payload-too-large"


class RangeNotSatisfiable(Problem):
    status, slug = 416, "range-not-satisfiable"


class Unprocessable(Problem):
    status, slug = 422, "unprocessable-content"


class TooManyRequests(Problem):
    status, slug = 429, "too-many-requests"


class ServiceUnavailable(Problem):
    status, slug = 503, "service-unavailable"


class InsufficientStorage(Problem):
    status, slug = 507, "insufficient-storage"


STORAGE_FULL_DETAIL = ("the server's storage is full: what this request sent was not stored (what was stored "
                       "before is intact); retry later, and tell the operator (GET /api/v1/health reports it)")


def storage_full(exc: BaseException | None) -> bool:
    """A full disk or an exhausted quota (ENOSPC, EDQUOT) anywhere in an exception's chain."""
    import errno

    seen = 0
    while exc is not None and seen < 10:
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            return True
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return False


def problem_response(status: int, detail: str, *, slug: str | None = None, instance: str | None = None,
                     headers: dict | None = None, **extra) -> JSONResponse:
    try:
        title = HTTPStatus(status).phrase
    except ValueError:
        title = "Error"
    body = {"type": TYPE_BASE + (slug or title.lower().replace(" ", "-")), "title": title, "status": status,
            "detail": detail}
    if instance:
        body["instance"] = instance
    body.update(extra)
    return JSONResponse(body, status_code=status, headers=headers, media_type=PROBLEM_MEDIA_TYPE)


def install_problem_handlers(app: FastAPI) -> None:
    @app.exception_handler(Problem)
    async def _problem(request: Request, exc: Problem):
        return problem_response(exc.status, exc.detail, slug=exc.slug, instance=request.url.path,
                                headers=exc.headers, **exc.extra)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError):
        errors = []
        for e in exc.errors():
            errors.append({"loc": [str(x) for x in e.get("loc", ())], "msg": str(e.get("msg", "")),
                           "type": str(e.get("type", ""))})
        first = errors[0] if errors else {"loc": [], "msg": "invalid request"}
        detail = f"{'.'.join(first['loc'][1:] or first['loc'])}: {first['msg']}" if first["loc"] else first["msg"]
        return problem_response(422, detail, slug="validation-error", instance=request.url.path, errors=errors)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException):
        detail = exc.detail if isinstance(exc.detail, str) else HTTPStatus(exc.status_code).phrase
        return problem_response(exc.status_code, detail, instance=request.url.path,
                                headers=getattr(exc, "headers", None))

    from sqlalchemy.exc import DBAPIError, OperationalError
    from sqlalchemy.exc import TimeoutError as PoolTimeout

    @app.exception_handler(DBAPIError)
    async def _database(request: Request, exc: DBAPIError):
        orig = getattr(exc, "orig", None)
        if getattr(orig, "sqlite_errorcode", None) == 13 or getattr(orig, "sqlstate", None) == "53100":
            # SQLITE_FULL / PostgreSQL disk_full: the transaction was rolled back, nothing half-written
            log.error("database disk full on %s %s: %s", request.method, request.url.path, orig)
            return problem_response(507, STORAGE_FULL_DETAIL, slug="insufficient-storage",
                                    instance=request.url.path, headers={"Retry-After": "60"})
        if exc.connection_invalidated or isinstance(exc, OperationalError):
            log.warning("database unavailable on %s %s: %s", request.method, request.url.path, exc.orig)
            return problem_response(503, "the database is unavailable or busy; retry shortly", slug="unavailable",
                                    instance=request.url.path, headers={"Retry-After": "2"})
        log.exception("database error on %s %s", request.method, request.url.path)
        return problem_response(500, "internal error; the incident was logged", slug="internal-error",
                                instance=request.url.path)

    @app.exception_handler(PoolTimeout)
    async def _pool(request: Request, exc: PoolTimeout):
        return problem_response(503, "the server is overloaded; retry shortly", slug="unavailable",
                                instance=request.url.path, headers={"Retry-After": "2"})

    @app.exception_handler(OSError)
    async def _os_error(request: Request, exc: OSError):
        """A full disk (ENOSPC, EDQUOT) is 507 with a message; any other OSError is an internal error."""
        if storage_full(exc):
            log.error("storage full on %s %s: %s", request.method, request.url.path, exc)
            return problem_response(507, STORAGE_FULL_DETAIL, slug="insufficient-storage",
                                    instance=request.url.path, headers={"Retry-After": "60"})
        log.error("unhandled error on %s %s", request.method, request.url.path, exc_info=exc)
        return problem_response(500, "internal error; the incident was logged", slug="internal-error",
                                instance=request.url.path)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception):
        if storage_full(exc):
            log.error("storage full on %s %s: %s", request.method, request.url.path, exc)
            return problem_response(507, STORAGE_FULL_DETAIL, slug="insufficient-storage",
                                    instance=request.url.path, headers={"Retry-After": "60"})
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return problem_response(500, "internal error; the incident was logged", slug="internal-error",
                                instance=request.url.path)
