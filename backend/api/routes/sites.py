"""/sites and their members."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Query, Request, Response

from ...schemas.common import PageOut
from ...schemas.sites import MemberIn, MemberOut, SiteIn, SiteOut, SitePatch
from ...services import results, sites
from ..deps import CtxDep
from ..responses import json_response, model_response, page_response

router = APIRouter(tags=["sites"])
Limit = Annotated[int, Query(ge=1, le=500)]
Offset = Annotated[int, Query(ge=0, le=1_000_000_000)]


@router.get("/sites", response_model=PageOut[SiteOut], summary="Sites I have a role on")
def list_sites(ctx: CtxDep, request: Request, q: Annotated[str | None, Query(max_length=200)] = None,
               limit: Limit = 50, offset: Offset = 0):
    return page_response(request, sites.list_sites(ctx, q, limit, offset), SiteOut)


@router.post("/sites", status_code=201, response_model=SiteOut, summary="Create a site (I become its admin)")
def create_site(body: SiteIn, ctx: CtxDep, request: Request):
    s = sites.create_site(ctx, body.name, body.crs, body.vertical_datum, body.geoid, body.description,
                          body.tolerance_horizontal_m, body.tolerance_vertical_m)
    return model_response(request, SiteOut, s, 201, headers={"Location": f"/api/v1/sites/{s.id}"})


@router.get("/sites/{site_id}", response_model=SiteOut)
def get_site(site_id: str, ctx: CtxDep, request: Request):
    return model_response(request, SiteOut, sites.get_site(ctx, site_id))


@router.patch("/sites/{site_id}", response_model=SiteOut, summary="Change a site (admin); If-Match supported")
def update_site(site_id: str, body: SitePatch, ctx: CtxDep, request: Request,
                if_match: Annotated[str | None, Header()] = None):
    s = sites.update_site(ctx, site_id, body.model_dump(exclude_unset=True), if_match)
    return model_response(request, SiteOut, s)


@router.delete("/sites/{site_id}", status_code=204, summary="Delete a site and everything in it (admin)")
def delete_site(site_id: str, ctx: CtxDep, if_match: Annotated[str | None, Header()] = None):
    sites.delete_site(ctx, site_id, if_match)
    return Response(status_code=204)


@router.get("/sites/{site_id}/summary", summary="Overview figures of a site in one request")
def site_summary(site_id: str, ctx: CtxDep, request: Request):
    return json_response(request, results.site_summary(ctx, site_id))


@router.get("/sites/{site_id}/members", response_model=list[MemberOut])
def list_members(site_id: str, ctx: CtxDep, request: Request):
    return json_response(request, sites.list_members(ctx, site_id))


@router.put("/sites/{site_id}/members/{user_id}", response_model=MemberOut, summary="Give a user a role (admin)")
def set_member(site_id: str, user_id: str, body: MemberIn, ctx: CtxDep, request: Request):
    return json_response(request, sites.set_member(ctx, site_id, user_id, body.role))


@router.delete("/sites/{site_id}/members/{user_id}", status_code=204, summary="Remove a user's role (admin)")
def remove_member(site_id: str, user_id: str, ctx: CtxDep):
    sites.remove_member(ctx, site_id, user_id)
    return Response(status_code=204)
