"""Surveys (one flight), the files of the survey folder, and resumable uploads."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import JSON, BigInteger, ForeignKey, String, Text, UniqueConstraint
from sqlalchemy.orm import Mapped, mapped_column

from .base import Base, IdMixin, TimestampMixin, VersionMixin, utcnow


class Survey(IdMixin, TimestampMixin, VersionMixin, Base):
    __tablename__ = "surveys"
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(200))
    flown_at: Mapped[datetime | None] = mapped_column(default=None)
    # where flown_at comes from: "user" (given), or read from the data by a run: "gnss" (GNSS solution),
    # "dji-mrk" (MRK exposures), "exif" (photos' DateTimeOriginal); None with a date: given (before 0004)
    flown_at_source: Mapped[str | None] = mapped_column(String(16), default=None)
    notes: Mapped[str] = mapped_column(Text, default="")
    settings: Mapped[dict] = mapped_column(JSON, default=dict)     # processing options of this survey
    created_by: Mapped[str | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), default=None)


class SurveyFile(IdMixin, Base):
    """One file of the survey folder (pipeline contract layout), content-addressed in storage."""

    __tablename__ = "survey_files"
    __table_args__ = (UniqueConstraint("survey_id", "path"),)
    survey_id: Mapped[str] = mapped_column(ForeignKey("surveys.id", ondelete="CASCADE"), index=True)
    path: Mapped[str] = mapped_column(String(500))        # "rover/rover.obs", "images/IMG_0001.JPG", "flights/F/..."
    kind: Mapped[str] = mapped_column(String(32))         # rinex-obs | rinex-nav | ubx | rtcm3 | dji-mrk | image | ...
    role: Mapped[str | None] = mapped_column(String(16), default=None)   # rover | base for observations
    sha256: Mapped[str] = mapped_column(String(64))
    size: Mapped[int] = mapped_column(BigInteger)
    meta: Mapped[dict | None] = mapped_column(JSON, default=None)        # what recognition read (time span, ...)
    upload_id: Mapped[str | None] = mapped_column(ForeignKey("uploads.id", ondelete="SET NULL"), default=None)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Upload(IdMixin, TimestampMixin, Base):
    __tablename__ = "uploads"
    survey_id: Mapped[str] = mapped_column(ForeignKey("surveys.id", ondelete="CASCADE"), index=True)
    filename: Mapped[str] = mapped_column(String(255))
    size: Mapped[int] = mapped_column(BigInteger)
    sha256: Mapped[str] = mapped_column(String(64))
    kind: Mapped[str | None] = mapped_column(String(32), default=None)
    role: Mapped[str | None] = mapped_column(String(16), default=None)
    # the folder the file was dropped in (relative path, kind=flight: its last name is the flight's folder)
    folder: Mapped[str | None] = mapped_column(String(500), default=None)
    state: Mapped[str] = mapped_column(String(16), default="open")   # open | verifying | complete | failed | aborted
    received_bytes: Mapped[int] = mapped_column(BigInteger, default=0)
    error: Mapped[str | None] = mapped_column(Text, default=None)
    result: Mapped[dict | None] = mapped_column(JSON, default=None)  # files attached on completion
    created_by: Mapped[str | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), default=None)
    expires_at: Mapped[datetime | None] = mapped_column(default=None)


class UploadChunk(IdMixin, Base):
    __tablename__ = "upload_chunks"
    __table_args__ = (UniqueConstraint("upload_id", "offset"),)
    upload_id: Mapped[str] = mapped_column(ForeignKey("uploads.id", ondelete="CASCADE"), index=True)
    offset: Mapped[int] = mapped_column(BigInteger)
    length: Mapped[int] = mapped_column(BigInteger)
    key: Mapped[str] = mapped_column(String(200))
