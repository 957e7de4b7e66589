from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field

from .common import ORM


class SurveyIn(BaseModel):
    name: str = Field(min_length=1, max_length=200)
    flown_at: datetime | None = None
    notes: str = Field(default="", max_length=20000)
    settings: dict = Field(default_factory=dict, description="processing options by step: {gnss: {...}, ...}")


class SurveyPatch(BaseModel):
    name: str | None = Field(default=None, min_length=1, max_length=200)
    flown_at: datetime | None = None
    notes: str | None = Field(default=None, max_length=20000)
    settings: dict | None = None


class SurveyOut(ORM):
    id: str
    site_id: str
    name: str
    flown_at: datetime | None
    flown_at_source: str | None = Field(default=None, description="'user' (given), or read from the survey's data "
                                        "by a run: 'gnss', 'dji-mrk', 'exif'")
    notes: str
    settings: dict
    created_at: datetime
    updated_at: datetime
    version: int


class SurveyFileOut(ORM):
    id: str
    path: str
    kind: str
    role: str | None
    size: int
    sha256: str
    meta: dict | None
    created_at: datetime


class FileRoleIn(BaseModel):
    role: Literal["rover", "base"]


class PointOut(BaseModel):
    name: str
    easting_m: float
    northing_m: float
    ellipsoidal_height_m: float
    role: str


class PointRoleIn(BaseModel):
    role: Literal["control", "check"]


class CheckProblem(BaseModel):
    severity: Literal["error", "warning", "info"]
    code: str
    message: str
    files: list[str]


class CheckOut(BaseModel):
    survey_id: str
    ok: bool
    errors: int
    warnings: int
    problems: list[CheckProblem]
    files: dict[str, int]
    summary: str = Field(default="", description='what was found, in one line: "2 flights, 419 photos, MRK 419 '
                                                 'exposures, RTCM 3 rover log, base: 3 RINEX files, no navigation '
                                                 'file needed"')


# file_kinds.HINTS (GET /file-kinds), and the underscore spellings of earlier versions (HINT_ALIASES)
UploadKind = Literal["rover", "base", "nav", "images", "image", "events", "points", "gcp-list", "survey-metadata",
                     "archive", "flight", "gcp_list", "survey_metadata", "site-calibration"]


class UploadIn(BaseModel):
    filename: str = Field(min_length=1, max_length=1000)
    size: int = Field(gt=0, description="bytes")
    sha256: str = Field(pattern=r"^[0-9a-fA-F]{64}$")
    kind: UploadKind | None = Field(default=None, description="what the file is expected to be (checked against "
                                    "its content); flight: a file of a DJI flight folder (photo, Timestamp.MRK, "
                                    "raw log, navigation file), stored in flights/<folder's name>/")
    role: Literal["rover", "base"] | None = None
    folder: str | None = Field(default=None, max_length=1000,
                               description="the relative folder the file was dropped in (e.g. DCIM/100_0004); "
                                           "needed with kind=flight: its last name names the flight folder")


class UploadOut(ORM):
    id: str
    survey_id: str
    filename: str
    size: int
    sha256: str
    kind: str | None
    role: str | None
    folder: str | None = None
    state: str
    received_bytes: int
    error: str | None
    result: dict | None
    created_at: datetime
    expires_at: datetime | None
    max_chunk_bytes: int = 0
