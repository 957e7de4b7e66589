"""/sites/{id}/stockpiles, /stockpiles/{id}: outlines, bases and volume history."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Request, Response

from ...schemas.sites import StockpileIn, StockpileOut, StockpilePatch, VolumePointOut
from ...services import inventory, stockpiles
from ..deps import CtxDep
from ...core.etag import bytes_etag
from ..responses import bytes_response, json_response, model_response

router = APIRouter(tags=["stockpiles"])


@router.get("/sites/{site_id}/stockpiles", response_model=list[StockpileOut])
def list_stockpiles(site_id: str, ctx: CtxDep, request: Request):
    return json_response(request, [StockpileOut.model_validate(s) for s in stockpiles.list_stockpiles(ctx, site_id)])


@router.post("/sites/{site_id}/stockpiles", status_code=201, response_model=StockpileOut)
def create_stockpile(site_id: str, body: StockpileIn, ctx: CtxDep, request: Request):
    sp = stockpiles.create_stockpile(ctx, site_id, body.name, body.outline, body.base, body.material, body.density_t_m3)
    return model_response(request, StockpileOut, sp, 201, headers={"Location": f"/api/v1/stockpiles/{sp.id}"})


@router.get("/stockpiles/{stockpile_id}", response_model=StockpileOut)
def get_stockpile(stockpile_id: str, ctx: CtxDep, request: Request):
    return model_response(request, StockpileOut, stockpiles.get_stockpile(ctx, stockpile_id))


@router.patch("/stockpiles/{stockpile_id}", response_model=StockpileOut)
def update_stockpile(stockpile_id: str, body: StockpilePatch, ctx: CtxDep, request: Request,
                     if_match: Annotated[str | None, Header()] = None):
    sp = stockpiles.update_stockpile(ctx, stockpile_id, body.model_dump(exclude_unset=True), if_match)
    return model_response(request, StockpileOut, sp)


@router.delete("/stockpiles/{stockpile_id}", status_code=204)
def delete_stockpile(stockpile_id: str, ctx: CtxDep, if_match: Annotated[str | None, Header()] = None):
    stockpiles.delete_stockpile(ctx, stockpile_id, if_match)
    return Response(status_code=204)


@router.get("/stockpiles/{stockpile_id}/volumes", response_model=list[VolumePointOut],
            summary="Volume of the stockpile in every run that measured it")
def volume_history(stockpile_id: str, ctx: CtxDep, request: Request):
    return json_response(request, [VolumePointOut.model_validate(v) for v in stockpiles.volume_history(ctx, stockpile_id)])


@router.get("/sites/{site_id}/inventory", summary="All stockpiles at a date: volume, tonnes, change, +- uncertainty",
            responses={200: {"content": {"application/json": {}, "text/csv": {}, inventory.XLSX: {}}}})
def site_inventory(site_id: str, ctx: CtxDep, request: Request, date: str | None = None, format: str = "json"):
    body, media, filename = inventory.inventory(ctx, site_id, date, format)
    return bytes_response(request, body, media, bytes_etag(body), filename if format != "json" else None)
