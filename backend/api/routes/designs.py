"""/sites/{id}/design: the site's design surface (file, area, tolerance) and /sites/{id}/design-progress."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Header, Query, Request, Response
from starlette.concurrency import run_in_threadpool

from ...core.problems import Unprocessable
from ...schemas.designs import DesignOut, DesignPatch
from ...services import designs
from ..deps import CtxDep
from ..request_body import body_in_temp_file
from ..responses import blob_response, json_response

router = APIRouter(tags=["design"])


def _out(request: Request, d, status: int = 200, headers: dict | None = None) -> Response:
    from ...core.etag import version_etag

    return json_response(request, DesignOut.model_validate(designs.design_out(d)), status, version_etag(d), headers)


def _check_then_end_transaction(ctx, site_id: str) -> None:
    """The caller's role is checked before the body is received; no transaction is held while it arrives."""
    designs.require_editor(ctx, site_id)
    ctx.db.commit()


@router.put("/sites/{site_id}/design/file", response_model=DesignOut,
            summary="Upload the site's design surface: LandXML, DXF or GeoTIFF as the raw body (editor); read and "
                    "checked at once (422 naming the problem)",
            openapi_extra={"requestBody": {"required": True, "content": {"application/octet-stream": {
                "schema": {"type": "string", "format": "binary"}}}}})
async def put_design_file(site_id: str, ctx: CtxDep, request: Request,
                          filename: Annotated[str, Query(min_length=1, max_length=255)],
                          surface_name: Annotated[str | None, Query(max_length=200)] = None,
                          if_match: Annotated[str | None, Header()] = None):
    await run_in_threadpool(_check_then_end_transaction, ctx, site_id)
    limit = ctx.settings.max_chunk_bytes
    suffix = Path(filename.replace("\\", "/").rsplit("/", 1)[-1]).suffix.lower()[:10]
    async with body_in_temp_file(request, ctx.settings.resolved_work_dir(), "design-", limit,
                                 f"design file longer than {limit} bytes",
                                 suffix if suffix.isascii() else "") as (tmp, received):
        if received == 0:
            raise Unprocessable(f"{filename}: empty body; the design file's bytes are expected")
        d = await run_in_threadpool(designs.upload_design, ctx, site_id, filename, tmp, surface_name, if_match)
        return _out(request, d)


@router.get("/sites/{site_id}/design", response_model=DesignOut, summary="The site's design surface")
def get_design(site_id: str, ctx: CtxDep, request: Request):
    return _out(request, designs.get_design(ctx, site_id))


@router.patch("/sites/{site_id}/design", response_model=DesignOut,
              summary="The design area (GeoJSON, site CRS), tolerance or LandXML surface (editor); If-Match supported")
def update_design(site_id: str, body: DesignPatch, ctx: CtxDep, request: Request,
                  if_match: Annotated[str | None, Header()] = None):
    return _out(request, designs.update_design(ctx, site_id, body.model_dump(exclude_unset=True), if_match))


@router.delete("/sites/{site_id}/design", status_code=204, summary="Remove the site's design surface (editor)")
def delete_design(site_id: str, ctx: CtxDep, if_match: Annotated[str | None, Header()] = None):
    designs.delete_design(ctx, site_id, if_match)
    return Response(status_code=204)


@router.get("/sites/{site_id}/design/file", summary="The design file as uploaded",
            responses={200: {"content": {"application/octet-stream": {}}}})
def get_design_file(site_id: str, ctx: CtxDep, request: Request):
    d = designs.get_design(ctx, site_id)
    media = {"landxml": "application/xml", "dxf": "image/vnd.dxf", "geotiff": "image/tiff"}[d.format]
    return blob_response(request, ctx.storage, d.sha256, d.size, media, d.filename)


@router.get("/sites/{site_id}/design-progress",
            summary="Cut, fill, net (+- 1 sigma) and on-grade share to the site's design over its surveys; 202 while "
                    "a change between surveys is still being computed by a worker (the figures are then the totals')",
            responses={202: {"description": "a change between surveys is queued or running: ask again"}})
def design_progress(site_id: str, ctx: CtxDep, request: Request):
    doc = designs.design_progress(ctx, site_id, request.app.state.database)
    if doc["changes_pending"]:
        return json_response(request, doc, 202, headers={"Retry-After": "5"})
    return json_response(request, doc)
