"""Webhooks: a site admin registers a URL; when a run finishes the platform POSTs a JSON body signed
with HMAC-SHA256 (header `Georef-Signature: t=<unix time>,v1=<hex HMAC of "<t>.<body>">`), retrying
transient failures (connection errors, timeouts, 408/425/429/5xx) with exponential back-off.

Targets must be public http(s) addresses (core/netguard.py; the operator may allow private networks
with `webhook_allowed_networks`): checked when the URL is set, and again at each delivery, which then
connects to the address it checked (DNS rebinding). Delivery outcomes are recorded as a status class
and a generic reason, never the receiver's answer or the network error's text: the delivery log must not
tell a caller what listens where."""

from __future__ import annotations

import json
import time

from sqlalchemy import select

from ..core import netguard, security
from ..core.problems import Unprocessable
from ..models import Webhook, WebhookDelivery
from ..models.base import utcnow
from .context import Ctx
from .permissions import require_site, require_webhook, site_ids_with_role
from .sites import check_if_match

EVENTS = ("run.finished", "run.succeeded", "run.failed", "run.cancelled")

# what a delivery records (last_error): generic reasons only
REASON_REFUSED = "target refused: not a public address, or not an allowed URL"
REASON_UNRESOLVED = "the host name did not resolve"
REASON_TIMEOUT = "no answer in time"
REASON_CONNECT = "connection failed"
REASON_REDIRECT = "the receiver answered with a redirect (not followed)"
REASON_REJECTED = "the receiver rejected the delivery"
REASON_BUSY = "the receiver asked to retry later"
REASON_SERVER = "the receiver failed"
REASON_DISABLED = "webhook deleted or disabled"


def _validate_url(url: str, settings) -> str:
    try:
        netguard.check_url(url, settings.webhook_allowed_networks)
    except netguard.TargetRefused as exc:
        raise Unprocessable(str(exc), slug="webhook-target-refused") from None
    return url


def _validate_events(events: list[str]) -> list[str]:
    bad = [e for e in events if e not in EVENTS]
    if bad or not events:
        raise Unprocessable(f"events: choose among {', '.join(EVENTS)}")
    return sorted(set(events))


def create_webhook(ctx: Ctx, site_id: str, url: str, events: list[str]) -> Webhook:
    require_site(ctx, site_id, "admin")
    wh = Webhook(site_id=site_id, url=_validate_url(url, ctx.settings), events=_validate_events(events),
                 secret=security.random_secret(32), created_by=ctx.user.id)
    ctx.db.add(wh)
    ctx.db.flush()
    return wh


def list_webhooks(ctx: Ctx, site_id: str | None) -> list[Webhook]:
    stmt = select(Webhook).where(Webhook.site_id.in_(site_ids_with_role(ctx, "admin")))
    if site_id:
        require_site(ctx, site_id, "admin")
        stmt = stmt.where(Webhook.site_id == site_id)
    from .permissions import require_scope

    require_scope(ctx, "admin")
    return list(ctx.db.scalars(stmt.order_by(Webhook.created_at)))


def get_webhook(ctx: Ctx, webhook_id: str) -> Webhook:
    return require_webhook(ctx, webhook_id, "admin")


def update_webhook(ctx: Ctx, webhook_id: str, changes: dict, if_match: str | None = None) -> Webhook:
    wh = require_webhook(ctx, webhook_id, "admin")
    check_if_match(wh, if_match)
    if changes.get("url") is not None:
        wh.url = _validate_url(changes["url"], ctx.settings)
    if changes.get("events") is not None:
        wh.events = _validate_events(changes["events"])
    if changes.get("active") is not None:
        wh.active = bool(changes["active"])
    wh.version += 1
    ctx.db.flush()
    return wh


def delete_webhook(ctx: Ctx, webhook_id: str) -> None:
    wh = require_webhook(ctx, webhook_id, "admin")
    ctx.db.delete(wh)
    ctx.db.flush()


def list_deliveries(ctx: Ctx, webhook_id: str, limit: int = 50) -> list[WebhookDelivery]:
    require_webhook(ctx, webhook_id, "admin")
    return list(ctx.db.scalars(select(WebhookDelivery).where(WebhookDelivery.webhook_id == webhook_id)
                               .order_by(WebhookDelivery.created_at.desc()).limit(max(1, min(limit, 500)))))


def enqueue_event(s, site_id: str, event: str, payload: dict) -> list[tuple]:
    """Delivery rows for every active webhook of the site that wants the event; messages to send."""
    out = []
    for wh in s.scalars(select(Webhook).where(Webhook.site_id == site_id, Webhook.active.is_(True))):
        wanted = set(wh.events)
        if event in wanted or (event.startswith("run.") and "run.finished" in wanted):
            d = WebhookDelivery(webhook_id=wh.id, event=event, payload=payload)
            s.add(d)
            s.flush()
            out.append(("webhook", d.id))
    return out


class TransientDeliveryError(Exception):
    pass


def _outcome(status: int) -> tuple[bool, bool, str | None]:
    """(delivered, transient, reason) of an HTTP status."""
    if 200 <= status < 300:
        return True, False, None
    if status in (408, 425, 429):
        return False, True, REASON_BUSY
    if status >= 500:
        return False, True, REASON_SERVER
    if 300 <= status < 400:
        return False, False, REASON_REDIRECT
    return False, False, REASON_REJECTED


def deliver(db, delivery_id: str, timeout_s: float, max_attempts: int, allowed_networks=()) -> str:
    """One delivery attempt: 'delivered', 'failed' (permanent), or raises TransientDeliveryError.

    The URL is checked again here (its name may resolve elsewhere now) and the request goes to the
    address that passed the check; a refused target fails the delivery for good, without a request."""
    import httpx

    with db.session() as s:
        d = s.get(WebhookDelivery, delivery_id)
        if d is None or d.state != "pending":
            return d.state if d else "missing"
        wh = s.get(Webhook, d.webhook_id)
        if wh is None or not wh.active:
            d.state, d.last_error = "failed", REASON_DISABLED
            return "failed"
        d.attempts += 1
        attempt, url, secret = d.attempts, wh.url, wh.secret
        body = json.dumps({"id": d.id, "event": d.event, "created_at": d.created_at.isoformat(), "data": d.payload},
                          sort_keys=True).encode()
        event = d.event
    status, error, transient = None, None, False
    try:
        target = netguard.check_url(url, allowed_networks)
    except netguard.TargetRefused as exc:
        target = None
        # a name that does not resolve (now) may be a passing DNS failure; anything else is final
        transient = isinstance(exc, netguard.TargetUnresolved)
        error = REASON_UNRESOLVED if transient else REASON_REFUSED
    if target is not None:
        ts = int(time.time())
        headers = {"Content-Type": "application/json", "User-Agent": "Georef-Webhooks/1", "Georef-Event": event,
                   "Georef-Delivery": delivery_id,
                   "Georef-Signature": f"t={ts},v1={security.sign_webhook(secret, ts, body)}"}
        try:
            status = netguard.post_pinned(target, body, headers, timeout_s)
        except httpx.TimeoutException:
            error, transient = REASON_TIMEOUT, True
        except (httpx.HTTPError, OSError, ValueError):
            error, transient = REASON_CONNECT, True
    with db.session() as s:
        d = s.get(WebhookDelivery, delivery_id)
        d.last_status = status
        if status is not None:
            delivered, transient, error = _outcome(status)
            if delivered:
                d.state, d.delivered_at, d.last_error = "delivered", utcnow(), None
                return "delivered"
        d.last_error = error
        if not transient or attempt >= max_attempts:
            d.state = "failed"
            return "failed"
    raise TransientDeliveryError(error or "delivery failed")
