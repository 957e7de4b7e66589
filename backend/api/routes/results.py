"""/runs/{id}/results: outputs of a run as JSON, CSV, GeoJSON, RTKLIB .pos, COG GeoTIFF, LAS/LAZ, PDF."""

from __future__ import annotations

import os
import tempfile
from typing import Annotated

from fastapi import APIRouter, Query, Request
from fastapi.responses import FileResponse
from pydantic import BaseModel, Field
from starlette.background import BackgroundTask

from ...core.problems import Unprocessable
from ...schemas.runs import OutputOut
from ...services import results
from ...storage import blob_key
from ..deps import CtxDep
from ..responses import blob_response, bytes_response, json_response

router = APIRouter(prefix="/runs/{run_id}/results", tags=["results"])
Fmt = Query(pattern="^(json|csv|geojson)$")


def _send(request: Request, r: results.Rendered):
    return bytes_response(request, r.body, r.media_type, r.etag, r.filename)


@router.get("", response_model=list[OutputOut], summary="Output files of the run")
def list_results(run_id: str, ctx: CtxDep, request: Request):
    out = []
    for o in results.list_outputs(ctx, run_id):
        d = OutputOut.model_validate(o).model_dump()
        d["media_type"] = results.media_type(o.path)
        d["url"] = f"/api/v1/runs/{run_id}/results/files/{o.path}"
        out.append(d)
    return json_response(request, out)


@router.get("/trajectory", summary="PPK trajectory: json, csv, geojson or RTKLIB pos")
def trajectory(run_id: str, ctx: CtxDep, request: Request,
               format: Annotated[str, Query(pattern="^(json|csv|geojson|pos)$")] = "json",
               every: Annotated[int, Query(ge=1, le=100000, description="keep one epoch in N")] = 1):
    return _send(request, results.trajectory(ctx, run_id, format, every))


@router.get("/camera-positions", summary="Antenna position at each camera trigger")
def camera_positions(run_id: str, ctx: CtxDep, request: Request, format: Annotated[str, Fmt] = "json"):
    return _send(request, results.camera_positions(ctx, run_id, format))


@router.get("/residuals", summary="Check-point residual table and statistics")
def residuals(run_id: str, ctx: CtxDep, request: Request, format: Annotated[str, Fmt] = "json"):
    return _send(request, results.residuals(ctx, run_id, format))


@router.get("/lever-arm", summary="Lever arm and trigger delay (JSON)")
def lever_arm(run_id: str, ctx: CtxDep, request: Request):
    return _send(request, results.lever_arm(ctx, run_id))


@router.get("/volumes", summary="Stockpile volumes")
def volumes(run_id: str, ctx: CtxDep, request: Request, format: Annotated[str, Fmt] = "json"):
    return _send(request, results.volumes(ctx, run_id, format))


class OutlineIn(BaseModel):
    outline: dict = Field(description="GeoJSON Polygon in the site CRS (metres)")
    base: str = Field(default="plane", max_length=64, description="lowest|highest|mean|plane|tin|elevation:Z")


def _file(request: Request, ctx, run_id: str, what: str, filename: str):
    o = results.output_for(ctx, run_id, what)
    return blob_response(request, ctx.storage, o.sha256, o.size, results.media_type(o.path), filename)


@router.get("/dsm", summary="Digital surface model (COG GeoTIFF, ellipsoidal heights)",
            responses={200: {"content": {"image/tiff": {}}}})
def dsm(run_id: str, ctx: CtxDep, request: Request):
    return _file(request, ctx, run_id, "dsm", "dsm.tif")


@router.get("/ortho", summary="Orthophoto (COG GeoTIFF)", responses={200: {"content": {"image/tiff": {}}}})
def ortho(run_id: str, ctx: CtxDep, request: Request):
    return _file(request, ctx, run_id, "ortho", "ortho.tif")


@router.get("/point-cloud", summary="Dense point cloud, LAZ (default) or LAS",
            responses={200: {"content": {"application/vnd.laszip": {}, "application/vnd.las": {}}}})
def point_cloud(run_id: str, ctx: CtxDep, request: Request,
                format: Annotated[str, Query(pattern="^(laz|las)$")] = "laz"):
    o = results.output_for(ctx, run_id, "point_cloud")
    if format == "laz" or o.path.endswith(".las") and format == "las":
        return blob_response(request, ctx.storage, o.sha256, o.size, results.media_type(o.path),
                             "points." + o.path.rsplit(".", 1)[-1])
    if format == "las" and o.path.endswith(".laz"):
        from georef_core.dense.point_cloud_io import copy_point_cloud

        src = ctx.storage.local_path(blob_key(o.sha256))
        tmp_dir = ctx.settings.resolved_work_dir() / "tmp"
        tmp_dir.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(suffix=".las", dir=tmp_dir)
        os.close(fd)
        src_tmp = None
        try:
            if src is None:
                fd2, src_tmp = tempfile.mkstemp(suffix=".laz", dir=tmp_dir)
                os.close(fd2)
                ctx.storage.fetch(blob_key(o.sha256), src_tmp)
                src = src_tmp
            copy_point_cloud(src, tmp)       # streamed: a million points at a time
        finally:
            if src_tmp:
                os.unlink(src_tmp)
        return FileResponse(tmp, media_type="application/vnd.las", filename="points.las",
                            background=BackgroundTask(os.unlink, tmp))
    raise Unprocessable("format: laz or las")


@router.get("/report.pdf", summary="PDF accuracy report", responses={200: {"content": {"application/pdf": {}}}})
def report(run_id: str, ctx: CtxDep, request: Request):
    return _file(request, ctx, run_id, "report", "accuracy_report.pdf")


@router.get("/files/{path:path}", summary="Any output file of the run")
def output_file(run_id: str, path: str, ctx: CtxDep, request: Request):
    o = results.output_by_path(ctx, run_id, path)
    media = results.media_type(o.path)
    if media.startswith("text/csv"):   # spreadsheet formulas in user-named cells neutralised (no ranges)
        return _send(request, results.raw_output(ctx, o, media, o.path.rsplit("/", 1)[-1]))
    return blob_response(request, ctx.storage, o.sha256, o.size, media, o.path.rsplit("/", 1)[-1])
