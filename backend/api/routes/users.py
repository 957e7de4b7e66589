"""/users: the users of my organisation (organisation admins add, deactivate and reactivate users)."""

from __future__ import annotations

from fastapi import APIRouter, Request

from ...schemas.accounts import UserIn, UserOut, UserPatch
from ...services import accounts
from ..deps import CtxDep
from ..responses import json_response

router = APIRouter(prefix="/users", tags=["users"])


@router.get("", response_model=list[UserOut], summary="Users of my organisation")
def list_users(ctx: CtxDep, request: Request):
    return json_response(request, [UserOut.model_validate(u) for u in accounts.list_users(ctx)])


@router.post("", status_code=201, response_model=UserOut, summary="Add a user (organisation admin)")
def add_user(body: UserIn, ctx: CtxDep, request: Request):
    u = accounts.add_user(ctx, body.email, body.password, body.name, body.is_org_admin)
    return json_response(request, UserOut.model_validate(u), 201)


@router.patch("/{user_id}", response_model=UserOut,
              summary="Deactivate or reactivate a user of my organisation (organisation admin)")
def update_user(user_id: str, body: UserPatch, ctx: CtxDep, request: Request):
    u = accounts.update_user(ctx, user_id, body.model_dump(exclude_unset=True))
    return json_response(request, UserOut.model_validate(u))
