"""Webhooks that notify GIS systems (HMAC-signed), and their delivery attempts."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import JSON, Boolean, ForeignKey, Integer, String, Text
from sqlalchemy.orm import Mapped, mapped_column

from .base import Base, IdMixin, TimestampMixin, VersionMixin, utcnow


class Webhook(IdMixin, TimestampMixin, VersionMixin, Base):
    __tablename__ = "webhooks"
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    url: Mapped[str] = mapped_column(String(2000))
    secret: Mapped[str] = mapped_column(String(128))      # needed in clear to sign; shown once to the creator
    events: Mapped[list] = mapped_column(JSON, default=list)
    active: Mapped[bool] = mapped_column(Boolean, default=True)
    created_by: Mapped[str | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), default=None)


class WebhookDelivery(IdMixin, Base):
    __tablename__ = "webhook_deliveries"
    webhook_id: Mapped[str] = mapped_column(ForeignKey("webhooks.id", ondelete="CASCADE"), index=True)
    event: Mapped[str] = mapped_column(String(64))
    payload: Mapped[dict] = mapped_column(JSON)
    state: Mapped[str] = mapped_column(String(16), default="pending")   # pending | delivered | failed
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    last_status: Mapped[int | None] = mapped_column(Integer, default=None)   # internal: the API shows the class
    last_error: Mapped[str | None] = mapped_column(Text, default=None)       # a generic reason, never the answer
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    delivered_at: Mapped[datetime | None] = mapped_column(default=None)

    @property
    def status_class(self) -> str | None:
        """'2xx', '4xx', ... of the last answer (None without one)."""
        s = self.last_status
        return f"{s // 100}xx" if s is not None and 100 <= s <= 599 else None
