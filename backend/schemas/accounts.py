from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field

from .common import ORM

Scope = Literal["read", "write", "admin"]


class LoginIn(BaseModel):
    email: str = Field(min_length=3, max_length=320)
    password: str = Field(min_length=1, max_length=1024)


class UserOut(ORM):
    id: str
    email: str
    name: str
    organisation_id: str
    is_org_admin: bool
    is_active: bool = True


class OrganisationOut(ORM):
    id: str
    name: str


class SiteRoleOut(BaseModel):
    site_id: str
    site_name: str
    role: str


class MeOut(BaseModel):
    user: UserOut
    organisation: OrganisationOut
    auth: str
    scopes: list[str]
    csrf_token: str | None
    site_roles: list[SiteRoleOut]


class LoginOut(BaseModel):
    user: UserOut
    csrf_token: str
    expires_at: datetime


class PasswordIn(BaseModel):
    current_password: str = Field(max_length=1024)
    new_password: str = Field(max_length=1024)


class TokenIn(BaseModel):
    name: str = Field(min_length=1, max_length=200)
    scopes: list[Scope] = Field(min_length=1)
    expires_in_days: int | None = Field(default=None, ge=1, le=3650)


class TokenOut(ORM):
    id: str
    name: str
    prefix: str
    scopes: list[str]
    created_at: datetime
    expires_at: datetime | None
    last_used_at: datetime | None
    revoked_at: datetime | None


class TokenCreatedOut(TokenOut):
    token: str = Field(description="the secret; shown once, store it now")


class UserIn(BaseModel):
    email: str = Field(min_length=3, max_length=320)
    name: str = Field(default="", max_length=200)
    password: str = Field(max_length=1024)
    is_org_admin: bool = False


class UserPatch(BaseModel):
    is_active: bool | None = Field(default=None, description="false: the user can no longer log in; their "
                                                               "sessions end and their API tokens are refused")
    name: str | None = Field(default=None, max_length=200)
