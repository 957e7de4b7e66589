"""Webhooks: a site admin registers a URL; when a run finishes the platform POSTs a JSON body signed
with HMAC-SHA256 (header `Georef-Signature: t=<unix time>,v1=<hex HMAC of "<t>.<body>">`), retrying
transient failures (connection errors, timeouts, 408/429/5xx) with exponential back-off."""

from __future__ import annotations

import json
import time
from urllib.parse import urlparse

from sqlalchemy import select

from ..core import security
from ..core.problems import Unprocessable
from ..models import Webhook, WebhookDelivery
from ..models.base import utcnow
from .context import Ctx
from .permissions import require_site, require_webhook, site_ids_with_role
from .sites import check_if_match

EVENTS = ("run.finished", "run.succeeded", "run.failed", "run.cancelled")


def _validate_url(url: str) -> str:
    u = urlparse(url)
    if u.scheme not in ("http", "https") or not u.netloc:
        raise Unprocessable("url: an http(s) URL expected")
    return url


def _validate_events(events: list[str]) -> list[str]:
    bad = [e for e in events if e not in EVENTS]
    if bad or not events:
        raise Unprocessable(f"events: choose among {', '.join(EVENTS)}")
    return sorted(set(events))


def create_webhook(ctx: Ctx, site_id: str, url: str, events: list[str]) -> Webhook:
    require_site(ctx, site_id, "admin")
    wh = Webhook(site_id=site_id, url=_validate_url(url), events=_validate_events(events),
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
        wh.url = _validate_url(changes["url"])
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


def deliver(db, delivery_id: str, timeout_s: float, max_attempts: int) -> str:
    """One delivery attempt: 'delivered', 'failed' (permanent), or raises TransientDeliveryError."""
    import httpx

    with db.session() as s:
        d = s.get(WebhookDelivery, delivery_id)
        if d is None or d.state != "pending":
            return d.state if d else "missing"
        wh = s.get(Webhook, d.webhook_id)
        if wh is None or not wh.active:
            d.state, d.last_error = "failed", "webhook deleted or disabled"
            return "failed"
        d.attempts += 1
        attempt, url, secret = d.attempts, wh.url, wh.secret
        body = json.dumps({"id": d.id, "event": d.event, "created_at": d.created_at.isoformat(), "data": d.payload},
                          sort_keys=True).encode()
        event = d.event
    ts = int(time.time())
    headers = {"Content-Type": "application/json", "User-Agent": "Georef-Webhooks/1", "Georef-Event": event,
               "Georef-Delivery": delivery_id,
               "Georef-Signature": f"t={ts},v1={security.sign_webhook(secret, ts, body)}"}
    status, error = None, None
    try:
        r = httpx.post(url, content=body, headers=headers, timeout=timeout_s, follow_redirects=False)
        status = r.status_code
    except httpx.HTTPError as exc:
        error = f"{type(exc).__name__}: {exc}"
    transient = status is None or status in (408, 425, 429) or status >= 500
    with db.session() as s:
        d = s.get(WebhookDelivery, delivery_id)
        d.last_status, d.last_error = status, error
        if status is not None and 200 <= status < 300:
            d.state, d.delivered_at = "delivered", utcnow()
            return "delivered"
        if not transient or attempt >= max_attempts:
            d.state = "failed"
            d.last_error = error or f"HTTP {status}" + ("" if transient else " (not retried)")
            return "failed"
    raise TransientDeliveryError(error or f"HTTP {status}")
