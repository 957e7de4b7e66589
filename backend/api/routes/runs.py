"""/surveys/{id}/runs, /runs/{id}: start, cancel, re-run, progress (server-sent events) and logs."""

from __future__ import annotations

import asyncio
import json
from typing import Annotated

from fastapi import APIRouter, Header, Query, Request
from fastapi.responses import StreamingResponse
from starlette.concurrency import run_in_threadpool

from ...schemas.common import PageOut
from ...schemas.runs import LogOut, RerunIn, RunDetailOut, RunIn, RunOut, StepOut
from ...services import results, runs
from .results import OutlineIn
from ..deps import CtxDep
from ..responses import json_response, page_response

router = APIRouter(tags=["runs"])


def run_detail(run, steps) -> dict:
    d = RunOut.model_validate(run).model_dump(mode="json")
    d["step_details"] = [StepOut.model_validate(s).model_dump(mode="json") for s in steps]
    d["changes"] = run.changes
    return d


@router.get("/surveys/{survey_id}/runs", response_model=PageOut[RunOut])
def list_runs(survey_id: str, ctx: CtxDep, request: Request,
              state: Annotated[str | None, Query(pattern="^(queued|running|succeeded|failed|cancelled)$")] = None,
              limit: Annotated[int, Query(ge=1, le=500)] = 50, offset: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0):
    return page_response(request, runs.list_runs(ctx, survey_id, state, limit, offset), RunOut)


@router.post("/surveys/{survey_id}/runs", status_code=201, response_model=RunDetailOut,
             summary="Start processing (editor)")
def create_run(survey_id: str, body: RunIn, ctx: CtxDep, request: Request):
    run = runs.create_run(ctx, survey_id, list(body.steps) if body.steps else None, body.settings)
    ctx.db.flush()
    return json_response(request, run_detail(run, runs.run_steps(ctx.db, run.id)), 201,
                         headers={"Location": f"/api/v1/runs/{run.id}"})


@router.get("/runs/{run_id}", response_model=RunDetailOut)
def get_run(run_id: str, ctx: CtxDep, request: Request):
    run, steps = runs.get_run(ctx, run_id)
    return json_response(request, run_detail(run, steps))


@router.post("/runs/{run_id}/cancel", response_model=RunDetailOut, summary="Cancel a queued or running run")
def cancel_run(run_id: str, ctx: CtxDep, request: Request):
    run = runs.cancel_run(ctx, run_id)
    return json_response(request, run_detail(run, runs.run_steps(ctx.db, run.id)))


@router.post("/runs/{run_id}/rerun", status_code=201, response_model=RunDetailOut,
             summary="A new run recomputing from a step (earlier identical steps are reused)")
def rerun(run_id: str, body: RerunIn, ctx: CtxDep, request: Request):
    run = runs.rerun(ctx, run_id, body.from_step, body.settings)
    ctx.db.flush()
    return json_response(request, run_detail(run, runs.run_steps(ctx.db, run.id)), 201,
                         headers={"Location": f"/api/v1/runs/{run.id}"})


@router.get("/runs/{run_id}/logs", response_model=PageOut[LogOut], summary="The run's log, oldest first (paginated)")
def list_logs(run_id: str, ctx: CtxDep, request: Request, after_id: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0,
              limit: Annotated[int, Query(ge=1, le=500)] = 50, offset: Annotated[int, Query(ge=0, le=1_000_000_000)] = 0,
              step: Annotated[str | None, Query(max_length=32)] = None):
    return page_response(request, runs.list_logs(ctx, run_id, after_id, limit, offset, step), LogOut)


@router.post("/runs/{run_id}/volumes", summary="Volume of an outline on the run's DSM (nothing saved; viewer)")
def adhoc_volume(run_id: str, body: OutlineIn, ctx: CtxDep, request: Request):
    return json_response(request, results.adhoc_volume(ctx, run_id, body.outline, body.base))


@router.get("/runs/{run_id}/changes", summary="What changed against the previous successful run")
def changes(run_id: str, ctx: CtxDep, request: Request):
    return json_response(request, runs.get_changes(ctx, run_id))


def _snapshot(database, run_id: str, after_log: int) -> tuple[dict, list[dict]]:
    with database.session(read_only=True) as s:
        from ...models import Run

        run = s.get(Run, run_id)
        detail = run_detail(run, runs.run_steps(s, run_id))
        logs = [LogOut.model_validate(x).model_dump(mode="json") for x in runs.logs_after(s, run_id, after_log, 500)]
        return detail, logs


@router.get("/runs/{run_id}/events", summary="Live progress: server-sent events (state, log, end)",
            responses={200: {"content": {"text/event-stream": {}}}})
async def events(run_id: str, ctx: CtxDep, request: Request,
                 last_event_id: Annotated[str | None, Header()] = None,
                 poll_s: Annotated[float, Query(ge=0.1, le=10)] = 0.5,
                 max_s: Annotated[float, Query(gt=0, le=86400, description="close the stream after this")] = 3600):
    await run_in_threadpool(runs.get_run, ctx, run_id)   # permission check (404 when no role)
    database = request.app.state.database
    try:
        after = int(last_event_id) if last_event_id else 0
    except ValueError:
        after = 0

    async def stream():
        nonlocal after
        last_state = None
        idle = 0.0
        t_end = asyncio.get_running_loop().time() + max_s
        yield "retry: 2000\n\n"
        while asyncio.get_running_loop().time() < t_end:
            if await request.is_disconnected():
                return
            detail, logs = await run_in_threadpool(_snapshot, database, run_id, after)
            for lg in logs:
                after = lg["id"]
                yield f"id: {lg['id']}\nevent: log\ndata: {json.dumps(lg)}\n\n"
            state = json.dumps(detail, sort_keys=True)
            if state != last_state:
                last_state = state
                idle = 0.0
                yield f"event: state\ndata: {state}\n\n"
            if detail["state"] in runs.TERMINAL_RUN_STATES and not logs:
                yield f"event: end\ndata: {json.dumps({'state': detail['state']})}\n\n"
                return
            await asyncio.sleep(poll_s)
            idle += poll_s
            if idle >= 15:
                idle = 0.0
                yield ": keep-alive\n\n"

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})
