"""Offset pagination shared by the list endpoints."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import Select, func, select

MAX_LIMIT = 500


@dataclass
class Page:
    items: list[Any]
    total: int
    limit: int
    offset: int


def paginate(ctx, stmt: Select, limit: int, offset: int) -> Page:
    limit = max(1, min(int(limit), MAX_LIMIT))
    offset = max(0, int(offset))
    total = ctx.db.scalar(select(func.count()).select_from(stmt.order_by(None).subquery()))
    items = list(ctx.db.scalars(stmt.limit(limit).offset(offset)))
    return Page(items, int(total or 0), limit, offset)
