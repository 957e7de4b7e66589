"""/runs/{id}/tiles and /runs/{id}/wmts: web map tiles of a run's rasters (XYZ, EPSG:3857) and the WMTS
document QGIS, ArcGIS and GDAL read. Authentication as everywhere (session, Bearer token) plus, here only,
a tile token as `?token=` (docs/security.md)."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response

from ...services import tiles
from ..deps import TileCtxDep
from ..responses import json_response
from ...core.etag import if_none_match_hits

router = APIRouter(prefix="/runs/{run_id}", tags=["tiles"])


def _base_url(request: Request) -> str:
    return str(request.base_url).rstrip("/") + "/api/v1"


@router.get("/tiles", summary="The run's map layers (XYZ tile URL templates, extent, zooms, legends)")
def list_layers(run_id: str, ctx: TileCtxDep, request: Request):
    return json_response(request, {"run_id": run_id, "layers": tiles.layers(ctx, run_id, _base_url(request))})


@router.get("/tiles/{layer}/legend.json", summary="Colours of a ramped layer against values (m)")
def legend(run_id: str, layer: str, ctx: TileCtxDep, request: Request):
    return json_response(request, tiles.legend(ctx, run_id, layer))


@router.get("/tiles/{layer}/{z}/{x}/{y}.png", summary="One 256 x 256 Web Mercator tile (PNG; transparent outside)",
            responses={200: {"content": {"image/png": {}}}})
def tile(run_id: str, layer: str, z: int, x: int, y: int, ctx: TileCtxDep, request: Request):
    t = tiles.tile(ctx, run_id, layer, z, x, y)
    h = {"ETag": t.etag, "Cache-Control": tiles.CACHE_CONTROL}
    if if_none_match_hits(request.headers.get("if-none-match"), t.etag):
        return Response(status_code=304, headers=h)
    return Response(t.body, media_type="image/png", headers=h)


@router.get("/wmts/1.0.0/WMTSCapabilities.xml", summary="OGC WMTS 1.0.0 capabilities of the run's map layers",
            responses={200: {"content": {"application/xml": {}}}})
def wmts(run_id: str, ctx: TileCtxDep, request: Request):
    body = tiles.wmts_capabilities(ctx, run_id, _base_url(request), request.query_params.get("token"))
    return Response(body, media_type="application/xml", headers={"Cache-Control": "private, no-cache"})
