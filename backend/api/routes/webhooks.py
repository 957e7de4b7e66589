"""/webhooks: HMAC-signed notifications to GIS systems when runs finish."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Query, Request, Response

from ...schemas.sites import DeliveryOut, WebhookCreatedOut, WebhookIn, WebhookOut, WebhookPatch
from ...services import webhooks
from ..deps import CtxDep
from ..responses import json_response, model_response

router = APIRouter(prefix="/webhooks", tags=["webhooks"])


@router.get("", response_model=list[WebhookOut], summary="Webhooks of the sites I administer")
def list_webhooks(ctx: CtxDep, request: Request, site_id: Annotated[str | None, Query(max_length=36)] = None):
    return json_response(request, [WebhookOut.model_validate(w) for w in webhooks.list_webhooks(ctx, site_id)])


@router.post("", status_code=201, response_model=WebhookCreatedOut, summary="Register a webhook (site admin)")
def create_webhook(body: WebhookIn, ctx: CtxDep, request: Request):
    wh = webhooks.create_webhook(ctx, body.site_id, body.url, body.events)
    out = {**WebhookOut.model_validate(wh).model_dump(mode="json"), "secret": wh.secret}
    return json_response(request, out, 201, headers={"Location": f"/api/v1/webhooks/{wh.id}",
                                                     "Cache-Control": "no-store"})


@router.get("/{webhook_id}", response_model=WebhookOut)
def get_webhook(webhook_id: str, ctx: CtxDep, request: Request):
    return model_response(request, WebhookOut, webhooks.get_webhook(ctx, webhook_id))


@router.patch("/{webhook_id}", response_model=WebhookOut)
def update_webhook(webhook_id: str, body: WebhookPatch, ctx: CtxDep, request: Request,
                   if_match: Annotated[str | None, Header()] = None):
    wh = webhooks.update_webhook(ctx, webhook_id, body.model_dump(exclude_unset=True), if_match)
    return model_response(request, WebhookOut, wh)


@router.delete("/{webhook_id}", status_code=204)
def delete_webhook(webhook_id: str, ctx: CtxDep):
    webhooks.delete_webhook(ctx, webhook_id)
    return Response(status_code=204)


@router.get("/{webhook_id}/deliveries", response_model=list[DeliveryOut])
def list_deliveries(webhook_id: str, ctx: CtxDep, request: Request,
                    limit: Annotated[int, Query(ge=1, le=500)] = 50):
    return json_response(request, [DeliveryOut.model_validate(d) for d in webhooks.list_deliveries(ctx, webhook_id,
                                                                                                     limit)])
