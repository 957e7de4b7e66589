"""Organisations, users, password login (browser sessions) and API tokens."""

from __future__ import annotations

from datetime import timedelta

from sqlalchemy import select, update

from ..core import passwords, security
from ..core.problems import BadRequest, Conflict, Forbidden, NotFound, Unauthorized, Unprocessable
from ..models import ApiToken, Organisation, Site, SiteRole, User, UserSession
from ..models.base import utcnow
from . import login_throttle
from .context import SCOPES, Ctx, Principal, expand_scopes


def normalise_email(email: str) -> str:
    return email.strip().lower()


def check_password_strength(password: str, email: str | None = None) -> None:
    """The password policy (core/passwords.py): 422 naming the rule that failed."""
    try:
        passwords.check(password, email)
    except passwords.WeakPassword as exc:
        raise Unprocessable(str(exc), slug="weak-password", rule=exc.rule) from None


# ----------------------------------------------------------------------------------------- bootstrap


def create_organisation(db, name: str) -> Organisation:
    org = Organisation(name=name)
    db.add(org)
    db.flush()
    return org


def create_user(db, organisation_id: str, email: str, password: str, name: str = "", is_org_admin: bool = False) -> User:
    email = normalise_email(email)
    if "@" not in email or len(email) > 320:
        raise Unprocessable("email: not an e-mail address")
    check_password_strength(password, email)
    if db.scalar(select(User.id).where(User.email == email)):
        raise Conflict(f"a user with e-mail {email} already exists")
    user = User(organisation_id=organisation_id, email=email, name=name, password_hash=security.hash_password(password),
                is_org_admin=is_org_admin)
    db.add(user)
    db.flush()
    return user


# ----------------------------------------------------------------------------------------- sessions


def login(ctx: Ctx, email: str, password: str, client_address: str | None = None) -> tuple[str, UserSession, User]:
    """(cookie value, session row, user); Unauthorized with one message whatever was wrong (unknown
    e-mail, wrong password, deactivated account); TooManyRequests (429, Retry-After) while the account or
    the client address is throttled, decided before the password is looked at (services/login_throttle.py)."""
    now = utcnow()
    keys = login_throttle.keys_for(normalise_email(email), client_address, ctx.settings)
    login_throttle.reserve(ctx.db, keys, ctx.settings, now)
    ctx.db.commit()   # the attempt is counted, for every API process, before the slow check
    user = ctx.db.scalar(select(User).where(User.email == normalise_email(email)))
    ctx.db.commit()   # no transaction (no SQLite write lock) held through the Argon2 verification
    ok = security.verify_password(user.password_hash if user else None, password)
    if not ok or user is None or not user.is_active:
        raise Unauthorized("e-mail or password is wrong")
    login_throttle.release(ctx.db, keys, now)
    login_throttle.prune(ctx.db, ctx.settings, now)
    if security.needs_rehash(user.password_hash):
        user.password_hash = security.hash_password(password)
    cookie = security.random_secret(32)
    sess = UserSession(id=security.sha256_hex(cookie), user_id=user.id, csrf_token=security.random_secret(24),
                       expires_at=utcnow() + timedelta(hours=ctx.settings.session_hours))
    ctx.db.add(sess)
    # expired sessions of this user are cleaned up on the way
    ctx.db.execute(UserSession.__table__.delete().where(UserSession.user_id == user.id,
                                                        UserSession.expires_at < utcnow()))
    ctx.db.flush()
    return cookie, sess, user


def logout(ctx: Ctx) -> None:
    p = ctx.principal
    if p is not None and p.session_id:
        ctx.db.execute(UserSession.__table__.delete().where(UserSession.id == p.session_id))


def principal_from_session(db, cookie: str) -> Principal | None:
    if not cookie or len(cookie) > 200:
        return None
    sess = db.get(UserSession, security.sha256_hex(cookie))
    if sess is None or sess.expires_at < utcnow():
        return None
    user = db.get(User, sess.user_id)
    if user is None or not user.is_active:
        return None
    return Principal(user=user, via="session", session_id=sess.id, csrf_token=sess.csrf_token)


# token -> (principal, valid until monotonic time): result readers poll; re-reading the token and its
# user on every request costs two queries. A revoked token is refused at once by the process that
# revoked it and within TOKEN_CACHE_S by the others.
TOKEN_CACHE_S = 5.0
_token_cache: dict[str, tuple[Principal, float]] = {}


def _forget_token(token_id: str) -> None:
    for k, (p, _) in list(_token_cache.items()):
        if p.token_id == token_id:
            _token_cache.pop(k, None)


def principal_from_token(db, token: str) -> Principal | None:
    import time

    if not token.startswith(security.TOKEN_PREFIX) or len(token) > 200:
        return None
    token_hash = security.sha256_hex(token)
    hit = _token_cache.get(token_hash)
    if hit is not None and hit[1] > time.monotonic():
        p = hit[0]
        return Principal(user=p.user, via="token", scopes=p.scopes, token_id=p.token_id)
    p = _load_token_principal(db, token_hash)
    if p is not None:
        if len(_token_cache) > 10000:
            _token_cache.clear()
        _token_cache[token_hash] = (p, time.monotonic() + TOKEN_CACHE_S)
    else:
        _token_cache.pop(token_hash, None)
    return p


def _load_token_principal(db, token_hash: str) -> Principal | None:
    row = db.scalar(select(ApiToken).where(ApiToken.token_hash == token_hash))
    now = utcnow()
    if row is None or row.revoked_at is not None or (row.expires_at is not None and row.expires_at < now):
        return None
    user = db.get(User, row.user_id)
    if user is None or not user.is_active:
        return None
    db.expunge(user)   # cached across requests: detached, plain attributes only
    stale = row.last_used_at is None or (now - row.last_used_at).total_seconds() > 60
    return Principal(user=user, via="token", scopes=expand_scopes(row.scopes), token_id=row.id, needs_touch=stale)


def change_password(ctx: Ctx, current: str, new: str) -> None:
    """Throttled like a login (per account): a stolen session cannot try passwords at full speed."""
    _require_session(ctx)
    user = ctx.user
    check_password_strength(new, user.email)
    now = utcnow()
    keys = [login_throttle.account_key(user.email, ctx.settings)]
    login_throttle.reserve(ctx.db, keys, ctx.settings, now)
    ctx.db.commit()
    if not security.verify_password(user.password_hash, current):
        raise Forbidden("current password is wrong")
    login_throttle.release(ctx.db, keys, now)
    user.password_hash = security.hash_password(new)
    # every other session of the user ends
    ctx.db.execute(UserSession.__table__.delete().where(UserSession.user_id == user.id,
                                                        UserSession.id != (ctx.principal.session_id or "")))


def me(ctx: Ctx) -> dict:
    user = ctx.user
    org = ctx.db.get(Organisation, user.organisation_id)
    roles = ctx.db.execute(select(SiteRole.site_id, SiteRole.role, Site.name).join(Site, Site.id == SiteRole.site_id)
                           .where(SiteRole.user_id == user.id).order_by(Site.name)).all()
    return {"user": user, "organisation": org, "auth": ctx.principal.via, "scopes": sorted(ctx.principal.scopes),
            "csrf_token": ctx.principal.csrf_token,
            "site_roles": [{"site_id": r.site_id, "site_name": r.name, "role": r.role} for r in roles]}


# ----------------------------------------------------------------------------------------- tokens


def _require_session(ctx: Ctx) -> None:
    if ctx.principal is None:
        raise Unauthorized("authentication required")
    if ctx.principal.via != "session":
        raise Forbidden("API tokens are managed from a logged-in session, not with a token")


def list_tokens(ctx: Ctx) -> list[ApiToken]:
    _require_session(ctx)
    return list(ctx.db.scalars(select(ApiToken).where(ApiToken.user_id == ctx.user.id)
                               .order_by(ApiToken.created_at.desc())))


def create_token(ctx: Ctx, name: str, scopes: list[str], expires_in_days: int | None) -> tuple[ApiToken, str]:
    _require_session(ctx)
    bad = [s for s in scopes if s not in SCOPES]
    if bad or not scopes:
        raise Unprocessable(f"scopes: choose among {', '.join(SCOPES)}" + (f" (not {', '.join(bad)})" if bad else ""))
    token = security.new_api_token()
    row = ApiToken(user_id=ctx.user.id, name=name, prefix=token[:8], token_hash=security.sha256_hex(token),
                   scopes=sorted(set(scopes)),
                   expires_at=utcnow() + timedelta(days=expires_in_days) if expires_in_days else None)
    ctx.db.add(row)
    ctx.db.flush()
    return row, token


TILE_TOKEN_MAX_DAYS = 90


def create_tile_token(ctx: Ctx, name: str, expires_in_days: int = 30) -> tuple[ApiToken, str]:
    """A tile token (scope "tiles"): reads map tiles and the WMTS document of the sites its user can see,
    nothing else; always expires (at most TILE_TOKEN_MAX_DAYS, and never after the API token it is made
    with). It may travel in a URL (`?token=`) for GIS clients that cannot set headers: docs/security.md."""
    if ctx.principal is None:
        raise Unauthorized("authentication required")
    if ctx.principal.via == "token" and not ctx.principal.has_scope("read"):
        raise Forbidden("a tile token is made from a session or an API token with the 'read' scope")
    days = int(expires_in_days)
    if not 1 <= days <= TILE_TOKEN_MAX_DAYS:
        raise Unprocessable(f"expires_in_days: 1 to {TILE_TOKEN_MAX_DAYS} (a tile token always expires)")
    expires = utcnow() + timedelta(days=days)
    if ctx.principal.token_id:
        parent = ctx.db.get(ApiToken, ctx.principal.token_id)
        if parent is not None and parent.expires_at is not None:
            expires = min(expires, parent.expires_at)
    token = security.new_api_token()
    row = ApiToken(user_id=ctx.user.id, name=name or "map tiles", prefix=token[:8],
                   token_hash=security.sha256_hex(token), scopes=["tiles"], expires_at=expires)
    ctx.db.add(row)
    ctx.db.flush()
    return row, token


def revoke_token(ctx: Ctx, token_id: str) -> None:
    _require_session(ctx)
    n = ctx.db.execute(update(ApiToken).where(ApiToken.id == token_id, ApiToken.user_id == ctx.user.id,
                                              ApiToken.revoked_at.is_(None)).values(revoked_at=utcnow())).rowcount
    _forget_token(token_id)
    if n == 0:
        exists = ctx.db.scalar(select(ApiToken.id).where(ApiToken.id == token_id, ApiToken.user_id == ctx.user.id))
        if not exists:
            raise NotFound("token not found")


# ----------------------------------------------------------------------------------------- users


def list_users(ctx: Ctx) -> list[User]:
    if ctx.principal is None:
        raise Unauthorized("authentication required")
    return list(ctx.db.scalars(select(User).where(User.organisation_id == ctx.user.organisation_id)
                               .order_by(User.email)))


def add_user(ctx: Ctx, email: str, password: str, name: str, is_org_admin: bool) -> User:
    if ctx.principal is None:
        raise Unauthorized("authentication required")
    if not ctx.user.is_org_admin:
        raise Forbidden("only an organisation admin adds users")
    if not ctx.principal.has_scope("admin"):
        raise Forbidden("this API token lacks the 'admin' scope")
    if not email:
        raise BadRequest("email is required")
    return create_user(ctx.db, ctx.user.organisation_id, email, password, name, is_org_admin)


def _forget_user_tokens(user_id: str) -> None:
    for k, (p, _) in list(_token_cache.items()):
        if p.user.id == user_id:
            _token_cache.pop(k, None)


def update_user(ctx: Ctx, user_id: str, changes: dict) -> User:
    """An organisation admin (de)activates a user of the organisation. A deactivated user cannot log in;
    their sessions end at once and their API tokens are refused (within TOKEN_CACHE_S in the other API
    processes); reactivation restores the tokens, not the sessions."""
    if ctx.principal is None:
        raise Unauthorized("authentication required")
    if not ctx.user.is_org_admin:
        raise Forbidden("only an organisation admin changes users")
    if not ctx.principal.has_scope("admin"):
        raise Forbidden("this API token lacks the 'admin' scope")
    user = ctx.db.get(User, user_id) if user_id else None
    if user is None or user.organisation_id != ctx.user.organisation_id:
        raise NotFound("user not found")
    active = changes.get("is_active")
    if active is not None:
        if not active and user.id == ctx.user.id:
            raise Conflict("you cannot deactivate your own account (ask another organisation admin)")
        user.is_active = bool(active)
        if not active:
            ctx.db.execute(UserSession.__table__.delete().where(UserSession.user_id == user.id))
            _forget_user_tokens(user.id)
    if changes.get("name") is not None:
        user.name = changes["name"]
    ctx.db.flush()
    return user
