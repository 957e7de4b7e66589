"""/sites/{id}/surveys, /surveys/{id}: surveys, their files, points and the pre-flight check."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Header, Query, Request, Response

from ...schemas.common import PageOut
from ...schemas.surveys import (CheckOut, FileRoleIn, PointOut, PointRoleIn, SurveyFileOut, SurveyIn, SurveyOut,
                                SurveyPatch)
from ...services import results, surveys
from ..deps import CtxDep
from ..responses import blob_response, json_response, model_response, page_response

router = APIRouter(tags=["surveys"])


@router.get("/sites/{site_id}/surveys", response_model=PageOut[SurveyOut])
def list_surveys(site_id: str, ctx: CtxDep, request: Request,
                 q: Annotated[str | None, Query(max_length=200)] = None,
                 flown_after: datetime | None = None, flown_before: datetime | None = None,
                 limit: Annotated[int, Query(ge=1, le=500)] = 50, offset: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0):
    return page_response(request, surveys.list_surveys(ctx, site_id, q, flown_after, flown_before, limit, offset),
                         SurveyOut)


@router.post("/sites/{site_id}/surveys", status_code=201, response_model=SurveyOut, summary="Create a survey (editor)")
def create_survey(site_id: str, body: SurveyIn, ctx: CtxDep, request: Request):
    s = surveys.create_survey(ctx, site_id, body.name, body.flown_at, body.notes, body.settings)
    return model_response(request, SurveyOut, s, 201, headers={"Location": f"/api/v1/surveys/{s.id}"})


@router.get("/surveys/{survey_id}", response_model=SurveyOut)
def get_survey(survey_id: str, ctx: CtxDep, request: Request):
    return model_response(request, SurveyOut, surveys.get_survey(ctx, survey_id))


@router.patch("/surveys/{survey_id}", response_model=SurveyOut)
def update_survey(survey_id: str, body: SurveyPatch, ctx: CtxDep, request: Request,
                  if_match: Annotated[str | None, Header()] = None):
    s = surveys.update_survey(ctx, survey_id, body.model_dump(exclude_unset=True), if_match)
    return model_response(request, SurveyOut, s)


@router.delete("/surveys/{survey_id}", status_code=204)
def delete_survey(survey_id: str, ctx: CtxDep, if_match: Annotated[str | None, Header()] = None):
    surveys.delete_survey(ctx, survey_id, if_match)
    return Response(status_code=204)


@router.get("/surveys/{survey_id}/files", response_model=list[SurveyFileOut], summary="The survey folder")
def list_files(survey_id: str, ctx: CtxDep, request: Request):
    return json_response(request, [SurveyFileOut.model_validate(f) for f in surveys.list_files(ctx, survey_id)])


@router.patch("/surveys/{survey_id}/files/{file_id}", response_model=SurveyFileOut,
              summary="Say whether an observation file is the rover's or the base's")
def set_file_role(survey_id: str, file_id: str, body: FileRoleIn, ctx: CtxDep, request: Request):
    return json_response(request, SurveyFileOut.model_validate(surveys.set_file_role(ctx, survey_id, file_id,
                                                                                      body.role)))


@router.delete("/surveys/{survey_id}/files/{file_id}", status_code=204)
def delete_file(survey_id: str, file_id: str, ctx: CtxDep):
    surveys.delete_file(ctx, survey_id, file_id)
    return Response(status_code=204)


@router.get("/surveys/{survey_id}/check", response_model=CheckOut, summary="Pre-flight check before processing")
def check(survey_id: str, ctx: CtxDep, request: Request):
    return json_response(request, surveys.preflight(ctx, survey_id))


@router.get("/surveys/{survey_id}/points", response_model=list[PointOut], summary="Control and check points")
def list_points(survey_id: str, ctx: CtxDep, request: Request):
    return json_response(request, surveys.list_points(ctx, survey_id))


@router.patch("/surveys/{survey_id}/points/{name}", response_model=PointOut,
              summary="Switch a point between control and check")
def set_point_role(survey_id: str, name: str, body: PointRoleIn, ctx: CtxDep, request: Request):
    return json_response(request, surveys.set_point_role(ctx, survey_id, name, body.role))


@router.get("/surveys/{survey_id}/report.pdf", summary="PDF accuracy report of the latest run that made one",
            responses={200: {"content": {"application/pdf": {}}}})
def survey_report(survey_id: str, ctx: CtxDep, request: Request):
    run, o = results.latest_report_output(ctx, survey_id)
    return blob_response(request, ctx.storage, o.sha256, o.size, "application/pdf",
                         f"accuracy_report_run{run.number}.pdf")
