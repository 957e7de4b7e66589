"""/tokens: long-lived scoped API tokens for GIS systems (shown once, stored hashed, revocable)."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response
from pydantic import BaseModel, Field

from ...schemas.accounts import TokenCreatedOut, TokenIn, TokenOut
from ...services import accounts
from ..deps import CtxDep
from ..responses import json_response

router = APIRouter(prefix="/tokens", tags=["tokens"])


@router.get("", response_model=list[TokenOut], summary="My API tokens (never their secret)")
def list_tokens(ctx: CtxDep, request: Request):
    return json_response(request, [TokenOut.model_validate(t) for t in accounts.list_tokens(ctx)])


@router.post("", status_code=201, response_model=TokenCreatedOut, summary="Create a token; the secret is shown once")
def create_token(body: TokenIn, ctx: CtxDep, request: Request):
    row, secret = accounts.create_token(ctx, body.name, list(body.scopes), body.expires_in_days)
    out = TokenCreatedOut.model_validate({**TokenOut.model_validate(row).model_dump(), "token": secret})
    return json_response(request, out, 201, headers={"Cache-Control": "no-store"})


class TileTokenIn(BaseModel):
    name: str = Field(default="map tiles", max_length=200)
    expires_in_days: int = Field(default=30, ge=1, le=accounts.TILE_TOKEN_MAX_DAYS)


@router.post("/tile", status_code=201, response_model=TokenCreatedOut,
             summary="Create a read-only, expiring tile token (may be sent as ?token= to the tile endpoints)")
def create_tile_token(body: TileTokenIn, ctx: CtxDep, request: Request):
    row, secret = accounts.create_tile_token(ctx, body.name, body.expires_in_days)
    out = TokenCreatedOut.model_validate({**TokenOut.model_validate(row).model_dump(), "token": secret})
    return json_response(request, out, 201, headers={"Cache-Control": "no-store"})


@router.delete("/{token_id}", status_code=204, summary="Revoke a token")
def revoke_token(token_id: str, ctx: CtxDep):
    accounts.revoke_token(ctx, token_id)
    return Response(status_code=204)
