"""Sites (a construction site with its CRS), per-site roles, stockpiles and reprocessing schedules."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import JSON, BigInteger, Boolean, ForeignKey, String, Text, UniqueConstraint
from sqlalchemy.orm import Mapped, mapped_column

from .base import Base, IdMixin, TimestampMixin, VersionMixin, utcnow

ROLES = ("viewer", "editor", "admin")


class Site(IdMixin, TimestampMixin, VersionMixin, Base):
    __tablename__ = "sites"
    organisation_id: Mapped[str] = mapped_column(ForeignKey("organisations.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(200))
    crs: Mapped[str] = mapped_column(String(64))                    # "EPSG:32653": project CRS (E, N)
    vertical_datum: Mapped[str | None] = mapped_column(String(64), default=None)   # e.g. "EPSG:5773"
    geoid: Mapped[str | None] = mapped_column(String(200), default=None)          # geoid model name/file
    description: Mapped[str] = mapped_column(Text, default="")
    # accuracy tolerance of the site's check points (residual tables are coloured against it)
    tolerance_horizontal_m: Mapped[float] = mapped_column(default=0.03)
    tolerance_vertical_m: Mapped[float] = mapped_column(default=0.05)


class SiteRole(Base):
    __tablename__ = "site_roles"
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), primary_key=True)
    user_id: Mapped[str] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), primary_key=True, index=True)
    role: Mapped[str] = mapped_column(String(16))


class Stockpile(IdMixin, TimestampMixin, VersionMixin, Base):
    """A stockpile's persistent outline (GeoJSON Polygon in the site CRS) and how its base is defined."""

    __tablename__ = "stockpiles"
    __table_args__ = (UniqueConstraint("site_id", "name"),)
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(200))
    outline: Mapped[dict] = mapped_column(JSON)
    base: Mapped[str] = mapped_column(String(64), default="plane")
    material: Mapped[str] = mapped_column(String(100), default="")
    density_t_m3: Mapped[float | None] = mapped_column(default=None)


class Schedule(IdMixin, TimestampMixin, VersionMixin, Base):
    """Reprocessing of a site's surveys: on a cadence and/or when new base data or points arrive."""

    __tablename__ = "schedules"
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(200))
    cadence: Mapped[str] = mapped_column(String(16), default="daily")   # none | hourly | daily | weekly
    at_utc: Mapped[str] = mapped_column(String(5), default="02:00")     # HH:MM (daily, weekly); MM (hourly)
    weekday: Mapped[int] = mapped_column(default=0)                     # weekly: 0 = Monday
    on_new_base: Mapped[bool] = mapped_column(Boolean, default=False)
    on_new_points: Mapped[bool] = mapped_column(Boolean, default=False)
    scope: Mapped[str] = mapped_column(String(16), default="latest")   # latest survey | all surveys
    only_if_changed: Mapped[bool] = mapped_column(Boolean, default=True)
    steps: Mapped[list | None] = mapped_column(JSON, default=None)
    settings: Mapped[dict] = mapped_column(JSON, default=dict)
    enabled: Mapped[bool] = mapped_column(Boolean, default=True)
    next_run_at: Mapped[datetime | None] = mapped_column(default=None, index=True)
    pending_survey_ids: Mapped[list] = mapped_column(JSON, default=list)   # new-data triggers waiting
    pending_since: Mapped[datetime | None] = mapped_column(default=None)
    last_run_at: Mapped[datetime | None] = mapped_column(default=None)


class SiteDesign(TimestampMixin, VersionMixin, Base):
    """The site's design surface (one per site): the file (LandXML, DXF or GeoTIFF, content-addressed in storage
    like survey files, checked by georef_core's reader at upload), the area compared (GeoJSON Polygon or
    MultiPolygon in the site CRS) and the on-grade tolerance. The design step of every run reads it."""

    __tablename__ = "site_designs"
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), primary_key=True)
    filename: Mapped[str] = mapped_column(String(255))
    format: Mapped[str] = mapped_column(String(16))                  # landxml | dxf | geotiff
    sha256: Mapped[str] = mapped_column(String(64))
    size: Mapped[int] = mapped_column(BigInteger)
    surface_name: Mapped[str | None] = mapped_column(String(200), default=None)   # LandXML: which surface
    described: Mapped[dict] = mapped_column(JSON, default=dict)      # what the reader found (kind, extent, notes)
    area: Mapped[dict | None] = mapped_column(JSON, default=None)    # GeoJSON geometry, site CRS
    tolerance_m: Mapped[float] = mapped_column(default=0.05)
    uploaded_by: Mapped[str | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), default=None)

    @property
    def id(self) -> str:
        """The ETag's stem (core/etag.version_etag): not the site's own."""
        return "d" + self.site_id


class SiteCalibration(TimestampMixin, VersionMixin, Base):
    """The site's calibration (localisation: horizontal similarity + inclined plane, the JSON document of
    georef_core.datums.site_calibration), applied by the datum step of every run of the site unless the
    survey or the run gives its own (services/calibrations.py, docs/datums.md)."""

    __tablename__ = "site_calibrations"
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), primary_key=True)
    document: Mapped[dict] = mapped_column(JSON)                     # SiteCalibration.to_dict()
    source_name: Mapped[str] = mapped_column(String(255), default="")   # the file or "pairs" it was set from
    set_by: Mapped[str | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), default=None)

    @property
    def id(self) -> str:
        """The ETag's stem (core/etag.version_etag): not the site's own."""
        return "c" + self.site_id


class DesignChangeJob(IdMixin, Base):
    """The change between two surveys of the site's design, surface against surface (georef_core.design.
    surface_change), computed by a worker (worker/tasks.design_change) and stored here: one row per pair of
    design results and area (``key``: their files' checksums, the area, the common-bias figure). queued ->
    running -> succeeded (``result``) | failed (``error``). services/design_changes.py; docs/design.md."""

    __tablename__ = "design_changes"
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    key: Mapped[str] = mapped_column(String(64), unique=True)
    earlier_run_id: Mapped[str] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    later_run_id: Mapped[str] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    inputs: Mapped[dict] = mapped_column(JSON)          # the files (checksums), the area and the common bias
    state: Mapped[str] = mapped_column(String(16), default="queued")   # queued | running | succeeded | failed
    attempt: Mapped[int] = mapped_column(default=0)
    worker: Mapped[str | None] = mapped_column(String(200), default=None)
    result: Mapped[dict | None] = mapped_column(JSON, default=None)
    error: Mapped[str | None] = mapped_column(Text, default=None)
    queued_at: Mapped[datetime] = mapped_column(default=utcnow)
    started_at: Mapped[datetime | None] = mapped_column(default=None)
    # the running attempt's worker proves itself alive (every step_lease_s / 4); older than step_lease_s: requeued
    heartbeat_at: Mapped[datetime | None] = mapped_column(default=None)
    finished_at: Mapped[datetime | None] = mapped_column(default=None)
