"""Processing runs: one row per run, one per step (the job state the worker advances), outputs and logs."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import JSON, BigInteger, Boolean, ForeignKey, Integer, String, Text, UniqueConstraint
from sqlalchemy.orm import Mapped, mapped_column

from .base import Base, IdMixin, VersionMixin, utcnow

RUN_STATES = ("queued", "running", "succeeded", "failed", "cancelled")
STEP_STATES = ("pending", "queued", "running", "succeeded", "skipped", "failed", "cancelled")


class Run(IdMixin, VersionMixin, Base):
    __tablename__ = "runs"
    __table_args__ = (UniqueConstraint("survey_id", "number"),)
    survey_id: Mapped[str] = mapped_column(ForeignKey("surveys.id", ondelete="CASCADE"), index=True)
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    number: Mapped[int] = mapped_column(Integer)
    state: Mapped[str] = mapped_column(String(16), default="queued", index=True)
    trigger: Mapped[str] = mapped_column(String(32), default="manual")   # manual | rerun | schedule | new-data
    parent_run_id: Mapped[str | None] = mapped_column(ForeignKey("runs.id", ondelete="SET NULL"), default=None)
    previous_run_id: Mapped[str | None] = mapped_column(ForeignKey("runs.id", ondelete="SET NULL"), default=None)
    from_step: Mapped[str | None] = mapped_column(String(32), default=None)
    steps: Mapped[list] = mapped_column(JSON, default=list)
    settings: Mapped[dict] = mapped_column(JSON, default=dict)
    settings_hash: Mapped[str] = mapped_column(String(64), default="")
    inputs: Mapped[dict] = mapped_column(JSON, default=dict)    # survey path -> sha256 at run creation
    cancel_requested: Mapped[bool] = mapped_column(Boolean, default=False)
    error: Mapped[str | None] = mapped_column(Text, default=None)
    changes: Mapped[dict | None] = mapped_column(JSON, default=None)   # against previous_run_id
    created_by: Mapped[str | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), default=None)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    started_at: Mapped[datetime | None] = mapped_column(default=None)
    finished_at: Mapped[datetime | None] = mapped_column(default=None)


class ClaimMixin:
    """The columns of a unit of work that a worker claims and advances: a step (RunStep) or a part of a split
    step (RunStepPart). The claim is atomic; its attempt number fences the heartbeats and the final write."""

    attempt: Mapped[int] = mapped_column(Integer, default=0)          # fencing token of the current claim
    worker: Mapped[str | None] = mapped_column(String(200), default=None)
    queued_at: Mapped[datetime | None] = mapped_column(default=None)
    started_at: Mapped[datetime | None] = mapped_column(default=None)
    heartbeat_at: Mapped[datetime | None] = mapped_column(default=None)
    finished_at: Mapped[datetime | None] = mapped_column(default=None)
    progress_stage: Mapped[str] = mapped_column(String(200), default="")
    progress_done: Mapped[int] = mapped_column(Integer, default=0)
    progress_total: Mapped[int] = mapped_column(Integer, default=0)


class RunStep(ClaimMixin, IdMixin, Base):
    __tablename__ = "run_steps"
    __table_args__ = (UniqueConstraint("run_id", "name"),)
    run_id: Mapped[str] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(32))
    position: Mapped[int] = mapped_column(Integer)
    state: Mapped[str] = mapped_column(String(16), default="pending", index=True)
    force: Mapped[bool] = mapped_column(Boolean, default=False)       # do not reuse an earlier identical result
    input_hash: Mapped[str | None] = mapped_column(String(64), default=None)
    reused_from_step_id: Mapped[str | None] = mapped_column(String(36), default=None)
    summary: Mapped[dict | None] = mapped_column(JSON, default=None)
    error: Mapped[str | None] = mapped_column(Text, default=None)
    # a step that runs as parts on several workers (contract.Split): None (one worker), "parts" (its parts
    # are queued or running: RunStepPart rows), "merge" (all parts done: the next claim merges them)
    phase: Mapped[str | None] = mapped_column(String(8), default=None)


class RunStepPart(ClaimMixin, IdMixin, Base):
    """One part of a split step (contract.Split), advanced like a step: an atomic claim whose attempt number
    fences heartbeats and the final write; its outputs are recorded with the step's name."""

    __tablename__ = "run_step_parts"
    __table_args__ = (UniqueConstraint("run_step_id", "index"),)
    run_step_id: Mapped[str] = mapped_column(ForeignKey("run_steps.id", ondelete="CASCADE"), index=True)
    run_id: Mapped[str] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    step_name: Mapped[str] = mapped_column(String(32))
    index: Mapped[int] = mapped_column(Integer)
    descriptor: Mapped[dict] = mapped_column(JSON, default=dict)     # what the plan said this part does
    state: Mapped[str] = mapped_column(String(16), default="queued", index=True)   # waiting|queued|running|succeeded


class RunOutput(IdMixin, Base):
    __tablename__ = "run_outputs"
    __table_args__ = (UniqueConstraint("run_id", "path"),)
    run_id: Mapped[str] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    step_name: Mapped[str] = mapped_column(String(32))
    path: Mapped[str] = mapped_column(String(500))      # relative to the run folder: "ppk/trajectory.pos"
    sha256: Mapped[str] = mapped_column(String(64))
    size: Mapped[int] = mapped_column(BigInteger)


class RunLog(Base):
    __tablename__ = "run_logs"
    id: Mapped[int] = mapped_column(BigInteger().with_variant(Integer, "sqlite"), primary_key=True, autoincrement=True)
    run_id: Mapped[str] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    step_name: Mapped[str | None] = mapped_column(String(32), default=None)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    level: Mapped[str] = mapped_column(String(8), default="info")
    message: Mapped[str] = mapped_column(Text)


class VolumeMeasurement(IdMixin, Base):
    """A stockpile volume measured by a run (the volume history of a stockpile across surveys)."""

    __tablename__ = "volume_measurements"
    __table_args__ = (UniqueConstraint("run_id", "stockpile_name"),)
    run_id: Mapped[str] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    survey_id: Mapped[str] = mapped_column(ForeignKey("surveys.id", ondelete="CASCADE"), index=True)
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    stockpile_id: Mapped[str | None] = mapped_column(ForeignKey("stockpiles.id", ondelete="SET NULL"), default=None,
                                                     index=True)
    stockpile_name: Mapped[str] = mapped_column(String(200))
    base: Mapped[str] = mapped_column(String(64), default="")
    volume_m3: Mapped[float | None] = mapped_column(default=None)
    fill_m3: Mapped[float | None] = mapped_column(default=None)
    cut_m3: Mapped[float | None] = mapped_column(default=None)
    area_m2: Mapped[float | None] = mapped_column(default=None)
    details: Mapped[dict | None] = mapped_column(JSON, default=None)
    measured_at: Mapped[datetime | None] = mapped_column(default=None)   # survey flight time
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
