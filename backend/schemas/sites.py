from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field, computed_field

from .common import ORM

Role = Literal["viewer", "editor", "admin"]


class SiteIn(BaseModel):
    name: str = Field(min_length=1, max_length=200)
    crs: str = Field(min_length=1, max_length=64, examples=["EPSG:32631"])
    vertical_datum: str | None = Field(default=None, max_length=64, examples=["EPSG:5773"])
    geoid: str | None = Field(default=None, max_length=200)
    description: str = Field(default="", max_length=10000)
    tolerance_horizontal_m: float = Field(default=0.03, gt=0, le=10)
    tolerance_vertical_m: float = Field(default=0.05, gt=0, le=10)


class SitePatch(BaseModel):
    name: str | None = Field(default=None, min_length=1, max_length=200)
    crs: str | None = Field(default=None, min_length=1, max_length=64)
    vertical_datum: str | None = Field(default=None, max_length=64)
    geoid: str | None = Field(default=None, max_length=200)
    description: str | None = Field(default=None, max_length=10000)
    tolerance_horizontal_m: float | None = Field(default=None, gt=0, le=10)
    tolerance_vertical_m: float | None = Field(default=None, gt=0, le=10)


class SiteOut(ORM):
    id: str
    organisation_id: str
    name: str
    crs: str
    vertical_datum: str | None
    geoid: str | None
    description: str
    tolerance_horizontal_m: float
    tolerance_vertical_m: float
    created_at: datetime
    updated_at: datetime
    version: int


class MemberIn(BaseModel):
    role: Role


class MemberOut(BaseModel):
    user_id: str
    email: str
    name: str
    role: str


class StockpileIn(BaseModel):
    name: str = Field(min_length=1, max_length=200)
    outline: dict = Field(description="GeoJSON Polygon, coordinates in the site CRS (E, N[, h]) in metres")
    base: str = Field(default="plane", max_length=64, description="lowest|highest|mean|plane|tin|elevation:Z")
    material: str = Field(default="", max_length=100)
    density_t_m3: float | None = Field(default=None, gt=0, lt=30)


class StockpilePatch(BaseModel):
    name: str | None = Field(default=None, min_length=1, max_length=200)
    outline: dict | None = None
    base: str | None = Field(default=None, max_length=64)
    material: str | None = Field(default=None, max_length=100)
    density_t_m3: float | None = Field(default=None, gt=0, lt=30)


class StockpileOut(ORM):
    id: str
    site_id: str
    name: str
    outline: dict
    base: str
    material: str
    density_t_m3: float | None
    created_at: datetime
    updated_at: datetime
    version: int

    @computed_field(description="the material as people read it ('crushed_stone' -> 'Crushed stone'; words as typed)")
    @property
    def material_label(self) -> str:
        from ..services.display import material_label

        return material_label(self.material)


class VolumePointOut(BaseModel):
    run_id: str
    run_number: int
    run_state: str
    survey_id: str
    survey_name: str
    measured_at: datetime | None
    base: str
    volume_m3: float | None
    sigma_m3: float | None = None
    fill_m3: float | None
    cut_m3: float | None
    area_m2: float | None
    tonnes: float | None


Cadence = Literal["none", "hourly", "daily", "weekly"]


class ScheduleIn(BaseModel):
    name: str = Field(min_length=1, max_length=200)
    cadence: Cadence = "daily"
    at_utc: str = Field(default="02:00", pattern=r"^([01]\d|2[0-3]):([0-5]\d)$")
    weekday: int = Field(default=0, ge=0, le=6)
    on_new_base: bool = False
    on_new_points: bool = False
    scope: Literal["latest", "all"] = "latest"
    only_if_changed: bool = True
    steps: list[str] | None = None
    settings: dict = Field(default_factory=dict)
    enabled: bool = True


class SchedulePatch(BaseModel):
    name: str | None = Field(default=None, min_length=1, max_length=200)
    cadence: Cadence | None = None
    at_utc: str | None = Field(default=None, pattern=r"^([01]\d|2[0-3]):([0-5]\d)$")
    weekday: int | None = Field(default=None, ge=0, le=6)
    on_new_base: bool | None = None
    on_new_points: bool | None = None
    scope: Literal["latest", "all"] | None = None
    only_if_changed: bool | None = None
    steps: list[str] | None = None
    settings: dict | None = None
    enabled: bool | None = None


class ScheduleOut(ORM):
    id: str
    site_id: str
    name: str
    cadence: str
    at_utc: str
    weekday: int
    on_new_base: bool
    on_new_points: bool
    scope: str
    only_if_changed: bool
    steps: list[str] | None
    settings: dict
    enabled: bool
    next_run_at: datetime | None
    last_run_at: datetime | None
    pending_survey_ids: list[str]
    version: int


class WebhookIn(BaseModel):
    site_id: str
    url: str = Field(min_length=8, max_length=2000)
    events: list[str] = Field(default_factory=lambda: ["run.finished"])


class WebhookPatch(BaseModel):
    url: str | None = Field(default=None, min_length=8, max_length=2000)
    events: list[str] | None = None
    active: bool | None = None


class WebhookOut(ORM):
    id: str
    site_id: str
    url: str
    events: list[str]
    active: bool
    created_at: datetime
    version: int


class WebhookCreatedOut(WebhookOut):
    secret: str = Field(description="HMAC-SHA256 key of the signatures; shown once")


class DeliveryOut(ORM):
    id: str
    event: str
    state: str
    attempts: int
    status_class: str | None = Field(description="class of the receiver's last answer: 2xx, 3xx, 4xx or 5xx")
    last_error: str | None = Field(description="a generic reason (connection failed, no answer in time, ...); "
                                               "never the receiver's answer")
    created_at: datetime
    delivered_at: datetime | None
