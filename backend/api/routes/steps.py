"""/steps: the processing steps' declared contract (options as JSON Schema, outputs, downloads), what the
browser builds its settings form and downloads list from, and what a GIS system reads to know the options."""

from __future__ import annotations

from fastapi import APIRouter, Request

from ...services import steps_catalog
from ..deps import CtxDep
from ..responses import json_response

router = APIRouter(prefix="/steps", tags=["steps"])


@router.get("", summary="Every step's spec: options (JSON Schema), outputs, downloads, summary")
def list_steps(ctx: CtxDep, request: Request):
    ctx.user    # a login or a token: 401 otherwise
    return json_response(request, {"items": [s.as_dict() for s in steps_catalog.STEPS]})


@router.get("/{name}", summary="One step's spec")
def get_step(name: str, ctx: CtxDep, request: Request):
    from ...core.problems import NotFound

    ctx.user
    spec = steps_catalog.BY_NAME.get(name)
    if spec is None:
        raise NotFound(f"no step {name!r}; steps are {', '.join(steps_catalog.ORDER)}")
    return json_response(request, spec.as_dict())
