"""Resumable chunked uploads: create, PUT chunks (Content-Range), GET status, complete, abort."""

from __future__ import annotations

from fastapi import APIRouter, Header, Request, Response
from starlette.concurrency import run_in_threadpool

from ...core.problems import Unprocessable
from ...schemas.surveys import UploadIn, UploadOut
from ...services import uploads
from ..deps import CtxDep
from ..request_body import body_in_temp_file
from ..responses import json_response

router = APIRouter(tags=["uploads"])


def _out(ctx, up) -> dict:
    d = UploadOut.model_validate(up).model_dump(mode="json")
    d["max_chunk_bytes"] = ctx.settings.max_chunk_bytes
    return d


@router.post("/surveys/{survey_id}/uploads", status_code=201, response_model=UploadOut,
             summary="Announce a file (name, size, SHA-256); then PUT its chunks")
def create_upload(survey_id: str, body: UploadIn, ctx: CtxDep, request: Request):
    up = uploads.create_upload(ctx, survey_id, body.filename, body.size, body.sha256, body.kind, body.role,
                               body.folder)
    return json_response(request, _out(ctx, up), 201, headers={"Location": f"/api/v1/uploads/{up.id}"})


@router.get("/surveys/{survey_id}/uploads", response_model=list[UploadOut])
def list_uploads(survey_id: str, ctx: CtxDep, request: Request):
    return json_response(request, [_out(ctx, u) for u in uploads.list_uploads(ctx, survey_id)])


@router.get("/uploads/{upload_id}", response_model=UploadOut, summary="State and received bytes (resume from there)")
def get_upload(upload_id: str, ctx: CtxDep, request: Request):
    return json_response(request, _out(ctx, uploads.get_upload(ctx, upload_id)))


@router.put("/uploads/{upload_id}", response_model=UploadOut,
            summary="Send a chunk: raw body with Content-Range: bytes START-END/SIZE, START = received_bytes",
            openapi_extra={"requestBody": {"required": True, "content": {"application/octet-stream": {
                "schema": {"type": "string", "format": "binary"}}}}})
async def put_chunk(upload_id: str, ctx: CtxDep, request: Request,
                    content_range: str | None = Header(default=None),
                    content_length: int | None = Header(default=None)):
    start, end, total = uploads.parse_content_range(content_range, content_length)
    done = await run_in_threadpool(_check_then_end_transaction, ctx, upload_id, start, end, total)
    if done is not None:
        # drain the body of an already-received chunk (idempotent retry)
        async for _ in request.stream():
            pass
        return json_response(request, _out(ctx, done))
    limit = end - start
    async with body_in_temp_file(request, ctx.settings.resolved_work_dir(), "chunk-", limit,
                                 f"body longer than the {limit} bytes announced by Content-Range") as (tmp, received):
        if received == 0 and limit > 0:
            raise Unprocessable("empty body; the chunk's bytes are expected")
        up = await run_in_threadpool(uploads.store_chunk, ctx, upload_id, start, end, tmp, True)
    return json_response(request, _out(ctx, up))


def _check_then_end_transaction(ctx, upload_id: str, start: int, end: int, total: int | None):
    """The chunk is checked in a transaction that ends before the body is read and stored: no database
    lock is held while bytes are copied (store_chunk advances received_bytes in a short one of its own,
    conditional on the upload still being where the check saw it)."""
    done = uploads.check_chunk(ctx, upload_id, start, end, total)
    ctx.db.commit()
    return done


@router.post("/uploads/{upload_id}/complete", response_model=UploadOut,
             summary="Verify size and SHA-256, recognise the content, attach the file(s) to the survey")
def complete_upload(upload_id: str, ctx: CtxDep, request: Request):
    return json_response(request, _out(ctx, uploads.complete_upload(ctx, upload_id)))


@router.delete("/uploads/{upload_id}", status_code=204, summary="Abort an upload")
def abort_upload(upload_id: str, ctx: CtxDep):
    uploads.abort_upload(ctx, upload_id)
    return Response(status_code=204)
