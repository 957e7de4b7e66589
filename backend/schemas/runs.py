from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, Field

from .common import ORM

# a step of the catalogue (GET /steps); unknown names are refused by the service with a 422 naming them
StepName = str


class RunIn(BaseModel):
    steps: list[StepName] | None = Field(default=None, description="default: every step")
    settings: dict = Field(default_factory=dict, description="overrides of the survey's settings, by step")


class RerunIn(BaseModel):
    from_step: StepName
    settings: dict = Field(default_factory=dict)


class PartOut(ORM):
    """One part of a step that runs on several workers (its progress: the UI shows one bar per part)."""
    index: int
    state: str
    attempt: int
    worker: str | None
    started_at: datetime | None
    finished_at: datetime | None
    progress_stage: str
    progress_done: int
    progress_total: int


class StepOut(ORM):
    id: str
    name: str
    position: int
    state: str
    attempt: int
    worker: str | None
    force: bool
    input_hash: str | None
    reused_from_step_id: str | None
    queued_at: datetime | None
    started_at: datetime | None         # a split step's: its plan's claim, kept through its merge (jobs.claim_step)
    finished_at: datetime | None
    heartbeat_at: datetime | None
    progress_stage: str
    progress_done: int
    progress_total: int
    summary: dict | None
    error: str | None
    phase: str | None = None            # a step on several workers: "parts" while they run, "merge" after
    parts: list[PartOut] = []


class RunOut(ORM):
    id: str
    survey_id: str
    site_id: str
    number: int
    state: str
    trigger: str
    parent_run_id: str | None
    previous_run_id: str | None
    from_step: str | None
    steps: list[str]
    settings: dict
    settings_hash: str
    inputs: dict[str, str]
    cancel_requested: bool
    error: str | None
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None


class RunDetailOut(RunOut):
    step_details: list[StepOut]
    changes: dict | None


class LogOut(ORM):
    id: int
    step_name: str | None
    created_at: datetime
    level: str
    message: str


class OutputOut(ORM):
    path: str
    step_name: str
    sha256: str
    size: int
    media_type: str = ""
    url: str = ""
