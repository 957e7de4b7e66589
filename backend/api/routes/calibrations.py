"""/sites/{id}/calibration: the site's calibration (localisation), applied by the datum step of every run of the
site unless the survey or the run gives its own."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Request, Response

from ...schemas.calibrations import SiteCalibrationIn, SiteCalibrationOut
from ...services import calibrations
from ..deps import CtxDep
from ..responses import json_response

router = APIRouter(tags=["sites"])


def _out(request: Request, c, status: int = 200) -> Response:
    from ...core.etag import version_etag

    return json_response(request, SiteCalibrationOut.model_validate(calibrations.calibration_out(c)), status,
                         version_etag(c))


@router.put("/sites/{site_id}/calibration", response_model=SiteCalibrationOut,
            summary="Set the site's calibration (admin): a calibration JSON document or a CSV of control pairs "
                    "(solved in the site CRS and datum); checked at once (422 naming the problem); If-Match supported")
def put_calibration(site_id: str, body: SiteCalibrationIn, ctx: CtxDep, request: Request,
                    if_match: Annotated[str | None, Header()] = None):
    return _out(request, calibrations.set_site_calibration(ctx, site_id, body.model_dump(), if_match))


@router.get("/sites/{site_id}/calibration", response_model=SiteCalibrationOut,
            summary="The site's calibration: parameters, sigmas, residuals per point")
def get_calibration(site_id: str, ctx: CtxDep, request: Request):
    return _out(request, calibrations.get_site_calibration(ctx, site_id))


@router.delete("/sites/{site_id}/calibration", status_code=204, summary="Remove the site's calibration (admin)")
def delete_calibration(site_id: str, ctx: CtxDep, if_match: Annotated[str | None, Header()] = None):
    calibrations.delete_site_calibration(ctx, site_id, if_match)
    return Response(status_code=204)
