"""Login throttling: failed password checks counted per account and per client address, in the database
(table login_throttle), so that every API process (uvicorn --workers N, several containers) sees them.

Each key has a few free failures (settings.login_max_failures_per_account / _per_client); from there on
each failure blocks the key for login_backoff_base_s, doubling with every further failure up to
login_backoff_max_s (exponential back-off). A blocked key answers 429 with Retry-After BEFORE the
password is looked at: a throttled attempt costs a primary-key read, not an Argon2 verification.
Counts are forgotten after login_failure_memory_s without a failure; a successful login clears its
account's count (and takes back its own attempt from the client's count, which otherwise decays).

An attempt is counted when it starts (committed before the slow password check, `reserve`) and taken
back when it succeeds (`release`): parallel guesses cannot all slip through before the first failure is
recorded. The account key is a hash of the e-mail, whether or not such an account exists (the throttle
does not reveal which addresses have accounts); IPv6 clients are counted per /64."""

from __future__ import annotations

import ipaddress
import math
from dataclasses import dataclass
from datetime import datetime, timedelta

from sqlalchemy import and_, delete, or_, select

from ..core import security
from ..core.problems import TooManyRequests
from ..models import LoginThrottle


@dataclass(frozen=True)
class Key:
    key: str
    limit: int


def account_key(email: str, settings) -> Key:
    return Key("a:" + security.sha256_hex(email.strip().lower()), settings.login_max_failures_per_account)


def client_key(address: str | None, settings) -> Key | None:
    if not address:
        return None
    try:
        ip = ipaddress.ip_address(address.split("%", 1)[0])
    except ValueError:
        return Key("c:" + address[:70], settings.login_max_failures_per_client)
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    if isinstance(ip, ipaddress.IPv6Address):
        return Key("c:" + str(ipaddress.ip_network(f"{ip}/64", strict=False)), settings.login_max_failures_per_client)
    return Key("c:" + str(ip), settings.login_max_failures_per_client)


def keys_for(email: str, address: str | None, settings) -> list[Key]:
    out = [account_key(email, settings)]
    c = client_key(address, settings)
    if c is not None:
        out.append(c)
    return out


def _delay_s(settings, failures: int, limit: int) -> float:
    return min(settings.login_backoff_max_s, settings.login_backoff_base_s * 2.0 ** min(failures - limit, 40))


def _too_many(retry_s: float) -> TooManyRequests:
    secs = max(1, math.ceil(retry_s))
    return TooManyRequests(f"too many failed logins; try again in {secs} s", headers={"Retry-After": str(secs)},
                           retry_after_s=secs)


def _blocked_for(rows, now: datetime) -> float:
    waits = [(r.blocked_until - now).total_seconds() for r in rows if r.blocked_until is not None
             and r.blocked_until > now]
    return max(waits, default=0.0)


def _insert_missing(db, keys: list[str], now: datetime) -> None:
    if not keys:
        return
    # in key order, as the locks below: two logins sharing keys never wait on each other in a cycle
    values = [{"key": k, "failures": 0, "last_failure_at": now, "blocked_until": None} for k in sorted(keys)]
    dialect = db.get_bind().dialect.name
    if dialect == "postgresql":
        from sqlalchemy.dialects.postgresql import insert
    elif dialect == "sqlite":
        from sqlalchemy.dialects.sqlite import insert
    else:   # pragma: no cover - the two supported databases above
        for v in values:
            with db.begin_nested():
                if db.get(LoginThrottle, v["key"]) is None:
                    db.add(LoginThrottle(**v))
        return
    db.execute(insert(LoginThrottle).values(values).on_conflict_do_nothing(index_elements=["key"]))


def check(db, keys: list[Key], now: datetime) -> None:
    """TooManyRequests when one of the keys is blocked now (a read, no write)."""
    rows = list(db.scalars(select(LoginThrottle).where(LoginThrottle.key.in_([k.key for k in keys]))))
    wait = _blocked_for(rows, now)
    if wait > 0:
        raise _too_many(wait)


def reserve(db, keys: list[Key], settings, now: datetime) -> None:
    """Count one attempt on every key (pessimistically, as a failure), or raise TooManyRequests when one
    is blocked. The caller commits before checking the password."""
    check(db, keys, now)
    _insert_missing(db, [k.key for k in keys], now)
    rows = {r.key: r for r in db.scalars(select(LoginThrottle).where(LoginThrottle.key.in_([k.key for k in keys]))
                                         .order_by(LoginThrottle.key).with_for_update()
                                         .execution_options(populate_existing=True))}
    wait = _blocked_for(rows.values(), now)   # blocked meanwhile by another process
    if wait > 0:
        raise _too_many(wait)
    forget_before = now - timedelta(seconds=settings.login_failure_memory_s)
    for k in keys:
        r = rows[k.key]
        if r.last_failure_at is None or r.last_failure_at < forget_before:
            r.failures = 0
        r.failures += 1
        r.last_failure_at = now
        if r.failures >= k.limit:
            r.blocked_until = now + timedelta(seconds=_delay_s(settings, r.failures, k.limit))
    db.flush()


def release(db, keys: list[Key], now: datetime) -> None:
    """The attempt succeeded: the account's count is cleared, the client's attempt taken back; rows
    forgotten long ago are deleted on the way."""
    if not keys:
        return
    db.execute(delete(LoginThrottle).where(LoginThrottle.key == keys[0].key))
    for k in keys[1:]:
        r = db.scalar(select(LoginThrottle).where(LoginThrottle.key == k.key).with_for_update())
        if r is not None:
            r.failures = max(0, r.failures - 1)
            if r.failures < k.limit:
                r.blocked_until = None
    db.flush()


def prune(db, settings, now: datetime) -> int:
    forget_before = now - timedelta(seconds=settings.login_failure_memory_s)
    return db.execute(delete(LoginThrottle).where(and_(
        LoginThrottle.last_failure_at < forget_before,
        or_(LoginThrottle.blocked_until.is_(None), LoginThrottle.blocked_until < now)))).rowcount or 0
