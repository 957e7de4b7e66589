"""/auth: password login for the browser, logout, who am I, password change."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response

from ...schemas.accounts import LoginIn, LoginOut, MeOut, PasswordIn, UserOut
from ...services import accounts
from ..deps import CSRF_COOKIE, SESSION_COOKIE, CtxDep, PublicCtxDep
from ..responses import json_response

router = APIRouter(prefix="/auth", tags=["auth"])


@router.post("/login", response_model=LoginOut, summary="Log in with e-mail and password (sets the session cookie)",
             responses={429: {"description": "too many failed logins for the account or the client address: "
                                             "wait Retry-After seconds"}})
def login(body: LoginIn, ctx: PublicCtxDep, request: Request):
    # the client's address as uvicorn sees it (behind a proxy: --proxy-headers with the proxy's address in
    # --forwarded-allow-ips, and a proxy that overwrites X-Forwarded-For; docs/security.md)
    cookie, sess, user = accounts.login(ctx, body.email, body.password,
                                        request.client.host if request.client else None)
    resp = json_response(request, LoginOut(user=UserOut.model_validate(user), csrf_token=sess.csrf_token,
                                           expires_at=sess.expires_at))
    max_age = int(ctx.settings.session_hours * 3600)
    secure = ctx.settings.cookie_secure
    resp.set_cookie(SESSION_COOKIE, cookie, max_age=max_age, httponly=True, secure=secure, samesite="lax", path="/")
    resp.set_cookie(CSRF_COOKIE, sess.csrf_token, max_age=max_age, httponly=False, secure=secure, samesite="lax",
                    path="/")
    return resp


@router.post("/logout", status_code=204, summary="End the session")
def logout(ctx: CtxDep):
    accounts.logout(ctx)
    resp = Response(status_code=204)
    resp.delete_cookie(SESSION_COOKIE, path="/")
    resp.delete_cookie(CSRF_COOKIE, path="/")
    return resp


@router.get("/me", response_model=MeOut, summary="The current user, organisation, site roles and CSRF token")
def me(ctx: CtxDep, request: Request):
    return json_response(request, MeOut.model_validate(accounts.me(ctx), from_attributes=True))


@router.post("/password", status_code=204, summary="Change my password (ends my other sessions)")
def change_password(body: PasswordIn, ctx: CtxDep):
    accounts.change_password(ctx, body.current_password, body.new_password)
    return Response(status_code=204)
