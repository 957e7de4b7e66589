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
    """The page and the total in one round trip: the total rides on every row as a window count over the
    filtered rows (computed before LIMIT/OFFSET). Only a page past the end, with no row to carry it, counts
    separately."""
    limit = max(1, min(int(limit), MAX_LIMIT))
    offset = max(0, int(offset))
    rows = ctx.db.execute(stmt.add_columns(func.count().over().label("total_rows")).limit(limit).offset(offset)).all()
    if rows:
        return Page([r[0] for r in rows], int(rows[0][-1]), limit, offset)
    total = ctx.db.scalar(select(func.count()).select_from(stmt.order_by(None).subquery())) if offset else 0
    return Page([], int(total or 0), limit, offset)
