"""/sites/{id}/schedules, /schedules/{id}: scheduled and data-triggered reprocessing."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Request, Response

from ...schemas.sites import ScheduleIn, ScheduleOut, SchedulePatch
from ...services import schedules
from ..deps import CtxDep
from ..responses import json_response, model_response

router = APIRouter(tags=["schedules"])


@router.get("/sites/{site_id}/schedules", response_model=list[ScheduleOut])
def list_schedules(site_id: str, ctx: CtxDep, request: Request):
    return json_response(request, [ScheduleOut.model_validate(s) for s in schedules.list_schedules(ctx, site_id)])


@router.post("/sites/{site_id}/schedules", status_code=201, response_model=ScheduleOut)
def create_schedule(site_id: str, body: ScheduleIn, ctx: CtxDep, request: Request):
    sch = schedules.create_schedule(ctx, site_id, body.model_dump())
    return model_response(request, ScheduleOut, sch, 201, headers={"Location": f"/api/v1/schedules/{sch.id}"})


@router.get("/schedules/{schedule_id}", response_model=ScheduleOut)
def get_schedule(schedule_id: str, ctx: CtxDep, request: Request):
    return model_response(request, ScheduleOut, schedules.get_schedule(ctx, schedule_id))


@router.patch("/schedules/{schedule_id}", response_model=ScheduleOut)
def update_schedule(schedule_id: str, body: SchedulePatch, ctx: CtxDep, request: Request,
                    if_match: Annotated[str | None, Header()] = None):
    sch = schedules.update_schedule(ctx, schedule_id, body.model_dump(exclude_unset=True), if_match)
    return model_response(request, ScheduleOut, sch)


@router.delete("/schedules/{schedule_id}", status_code=204)
def delete_schedule(schedule_id: str, ctx: CtxDep, if_match: Annotated[str | None, Header()] = None):
    schedules.delete_schedule(ctx, schedule_id, if_match)
    return Response(status_code=204)
