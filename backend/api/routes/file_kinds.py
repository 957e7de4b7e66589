"""/file-kinds: the kinds of survey file the server recognises by content and the upload hints a client may
give, with the names the browser's pre-check uses too (frontend/src/lib/sniff.ts)."""

from __future__ import annotations

from fastapi import APIRouter, Request

from ...services.file_kinds import served_kinds
from ..deps import CtxDep
from ..responses import json_response

router = APIRouter(prefix="/file-kinds", tags=["uploads"])


@router.get("", summary="File kinds recognised by content, upload hints and their accepted kinds")
def list_file_kinds(ctx: CtxDep, request: Request):
    ctx.user    # a login or a token: 401 otherwise
    return json_response(request, served_kinds())
