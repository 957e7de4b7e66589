"""Request dependencies: the service context (database session, settings, storage) and who is calling.

Browser: the `georef_session` cookie, and on unsafe methods the `X-CSRF-Token` header matching the
session's token. GIS systems: `Authorization: Bearer grf_...`. GET/HEAD requests get a read-only
session (parallel readers on SQLite); writes are committed, and queued broker messages sent, before the
response leaves (dependency scope "function").

The dependency itself does no I/O on the event loop: the caller is authenticated lazily, on first use
of `ctx.principal`, in the worker thread that runs the route (one thread hop per request, not three)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Annotated, AsyncIterator

from fastapi import Depends, Request
from sqlalchemy import update
from sqlalchemy.exc import OperationalError
from starlette.concurrency import run_in_threadpool

from ..core.problems import Forbidden, Unauthorized
from ..core.security import constant_time_equal
from ..models import ApiToken
from ..models.base import utcnow
from ..services import accounts
from ..services.context import Ctx, Principal

SESSION_COOKIE = "georef_session"
CSRF_COOKIE = "georef_csrf"
CSRF_HEADER = "X-CSRF-Token"
SAFE_METHODS = ("GET", "HEAD", "OPTIONS")
_touch_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="token-touch")


def authenticate(request: Request, db, tiles: bool = False) -> Principal | None:
    """The caller. `tiles`: a map-tile route, where a tile token (scope "tiles") is accepted, in the header
    or, for GIS clients that cannot set headers, as `?token=` (docs/security.md); anywhere else a tile
    token is refused, and no other token is taken from a URL."""
    p = _authenticate(request, db, tiles)
    if p is not None and p.tiles_only and not tiles:
        raise Forbidden("a tile token only reads map tiles (/runs/{id}/tiles/..., /runs/{id}/wmts/...)",
                        slug="tile-token")
    return p


def _authenticate(request: Request, db, tiles: bool) -> Principal | None:
    auth = request.headers.get("authorization", "")
    url_token = request.query_params.get("token") if tiles else None
    if url_token and not auth:
        p = accounts.principal_from_token(db, url_token.strip())
        if p is None:
            raise Unauthorized("tile token unknown, expired or revoked", headers={"WWW-Authenticate": "Bearer"})
        if not p.tiles_only:
            raise Unauthorized("only a tile token (POST /api/v1/tokens/tile: read-only, expiring) may be sent in "
                               "a URL; send other API tokens in the Authorization header",
                               headers={"WWW-Authenticate": "Bearer"})
        return p
    if auth:
        scheme, _, value = auth.partition(" ")
        if scheme.lower() != "bearer" or not value.strip():
            raise Unauthorized("Authorization header: 'Bearer <API token>' expected",
                               headers={"WWW-Authenticate": "Bearer"})
        p = accounts.principal_from_token(db, value.strip())
        if p is None:
            raise Unauthorized("API token unknown, expired or revoked", headers={"WWW-Authenticate": "Bearer"})
        return p
    cookie = request.cookies.get(SESSION_COOKIE)
    if cookie:
        p = accounts.principal_from_session(db, cookie)
        if p is None:
            raise Unauthorized("session expired; log in again")
        if request.method not in SAFE_METHODS:
            sent = request.headers.get(CSRF_HEADER, "")
            if not sent or not constant_time_equal(sent, p.csrf_token or ""):
                raise Forbidden(f"CSRF check failed: send the session's csrf_token in the {CSRF_HEADER} header",
                                slug="csrf")
        return p
    return None


def _touch_token(app_state, db, read_only: bool, principal: Principal) -> None:
    """Record a token's last use, at most once a minute: in the request's transaction when it writes
    anyway, else in a short one of its own off the request path."""
    stmt = update(ApiToken).where(ApiToken.id == principal.token_id).values(last_used_at=utcnow())
    if not read_only:
        db.execute(stmt)
        return

    def touch():
        try:
            with app_state.database.session() as s:
                s.execute(stmt)
        except OperationalError:
            pass
    _touch_pool.submit(touch)


class RequestCtx(Ctx):
    """A Ctx whose principal is resolved on first access (in the thread that runs the route)."""

    _request: Request
    _require_auth: bool
    _tiles: bool = False
    _resolved: bool = False

    @property
    def principal(self) -> Principal | None:   # type: ignore[override]
        if not self._resolved:
            self._resolved = True
            p = authenticate(self._request, self.db, self._tiles)
            if self._require_auth and p is None:
                raise Unauthorized("authentication required: log in, or send 'Authorization: Bearer <API token>'",
                                   headers={"WWW-Authenticate": "Bearer"})
            self.__dict__["_principal"] = p
            if p is not None and p.needs_touch:
                _touch_token(self._request.app.state, self.db, self._request.method in SAFE_METHODS, p)
        return self.__dict__.get("_principal")

    @principal.setter
    def principal(self, value) -> None:
        self.__dict__["_principal"] = value
        self._resolved = value is not None


def _dependency(require_auth: bool, tiles: bool = False):
    """The context dependency (one generator, so that FastAPI's throw() at the yield reaches the finally
    that ends the transaction at once: on SQLite a write transaction left open would block all writers)."""

    async def dependency(request: Request) -> AsyncIterator[Ctx]:
        state = request.app.state
        read_only = request.method in SAFE_METHODS
        db = (state.database.read_sessionmaker if read_only else state.database.sessionmaker)()
        ctx = RequestCtx(db=db, settings=state.settings, storage=state.storage)
        ctx._request, ctx._require_auth, ctx._tiles = request, require_auth, tiles
        try:
            yield ctx
            if not read_only:
                await run_in_threadpool(ctx.commit)
        finally:
            # ending a read-only transaction is a local call, no round trip worth a thread hop
            if read_only:
                db.close()
            else:
                await run_in_threadpool(_close, db)

    return dependency


def _close(db) -> None:
    try:
        db.rollback()
    finally:
        db.close()


get_ctx = _dependency(True)
get_public_ctx = _dependency(False)
get_tile_ctx = _dependency(True, tiles=True)


CtxDep = Annotated[Ctx, Depends(get_ctx, scope="function")]
PublicCtxDep = Annotated[Ctx, Depends(get_public_ctx, scope="function")]
TileCtxDep = Annotated[Ctx, Depends(get_tile_ctx, scope="function")]
