"""Stockpiles: a persistent outline (GeoJSON Polygon, site CRS) and base definition per site, and their
volume history over the runs of the site's surveys."""

from __future__ import annotations

import math
import re

from sqlalchemy import select

from ..core.problems import Conflict, Unprocessable
from ..models import Run, Stockpile, Survey, VolumeMeasurement
from .context import Ctx
from .permissions import require_site, require_stockpile
from .sites import check_if_match

_BASES = re.compile(r"^(lowest|highest|mean|plane|tin|elevation:-?\d+(\.\d+)?)$")


MAX_OUTLINE_VERTICES = 10_000     # a surveyed stockpile toe has tens to hundreds; the work is bounded by this
MAX_OUTLINE_RINGS = 100


def polygon_geometry(polygon: dict, rings: list, field: str, max_vertices: int, simplify_hint: str = ""):
    """The shapely geometry of a GeoJSON (Multi)Polygon whose ``rings`` are lists: at most ``max_vertices``
    positions, each [x, y] or [x, y, z] finite numbers, valid and with an area; 422 naming ``field`` otherwise
    (bounded work before any geometry is built: docs/security.md)."""
    from shapely.geometry import shape

    n = sum(len(r) for r in rings)
    if n > max_vertices:
        raise Unprocessable(f"{field}: {n} vertices; at most {max_vertices} are accepted: simplify the "
                            f"outline{simplify_hint}", slug="too-many-vertices")
    if not all(isinstance(pt, list) and 2 <= len(pt) <= 3 and all(
            isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in pt)
            for r in rings for pt in r):
        raise Unprocessable(f"{field}: every position must be [x, y] or [x, y, z] finite numbers")
    try:
        geom = shape(polygon)
    except Exception as exc:   # shapely raises several types on malformed coordinates
        raise Unprocessable(f"{field}: malformed polygon ({exc})") from None
    if geom.is_empty or not geom.is_valid or geom.area <= 0:
        raise Unprocessable(f"{field}: the polygon is empty, self-intersecting or has no area")
    return geom


def validate_outline(outline: dict) -> dict:
    if not isinstance(outline, dict) or outline.get("type") != "Polygon":
        raise Unprocessable("outline: a GeoJSON Polygon (coordinates in the site CRS, metres) expected")
    rings = outline.get("coordinates")
    if not isinstance(rings, list) or not rings or not all(isinstance(r, list) for r in rings):
        raise Unprocessable("outline: coordinates must be a list of rings (lists of [x, y] positions)")
    if len(rings) > MAX_OUTLINE_RINGS:
        raise Unprocessable(f"outline: {len(rings)} rings; at most {MAX_OUTLINE_RINGS} (the outer ring and its "
                            "holes) are accepted", slug="too-many-vertices")
    geom = polygon_geometry(outline, rings, "outline", MAX_OUTLINE_VERTICES, " (a stockpile toe needs far fewer)")
    if geom.area > 1e8:
        raise Unprocessable(f"outline: area {geom.area:.0f} m^2 is implausible for a stockpile (site CRS metres?)")
    return {"type": "Polygon", "coordinates": [[[float(c) for c in pt[:3]] for pt in ring]
                                               for ring in outline["coordinates"]]}


def validate_base(base: str) -> str:
    if not _BASES.match(base or ""):
        raise Unprocessable("base: lowest, highest, mean, plane, tin or elevation:Z (metres)")
    return base


def create_stockpile(ctx: Ctx, site_id: str, name: str, outline: dict, base: str, material: str,
                     density_t_m3: float | None) -> Stockpile:
    require_site(ctx, site_id, "editor")
    if ctx.db.scalar(select(Stockpile.id).where(Stockpile.site_id == site_id, Stockpile.name == name)):
        raise Conflict(f"a stockpile named {name!r} exists on this site")
    sp = Stockpile(site_id=site_id, name=name, outline=validate_outline(outline), base=validate_base(base),
                   material=material, density_t_m3=density_t_m3)
    ctx.db.add(sp)
    ctx.db.flush()
    return sp


def list_stockpiles(ctx: Ctx, site_id: str) -> list[Stockpile]:
    require_site(ctx, site_id, "viewer")
    return site_stockpiles(ctx.db, site_id)


def site_stockpiles(db, site_id: str) -> list[Stockpile]:
    return list(db.scalars(select(Stockpile).where(Stockpile.site_id == site_id).order_by(Stockpile.name)))


def get_stockpile(ctx: Ctx, stockpile_id: str) -> Stockpile:
    return require_stockpile(ctx, stockpile_id, "viewer")


def update_stockpile(ctx: Ctx, stockpile_id: str, changes: dict, if_match: str | None = None) -> Stockpile:
    sp = require_stockpile(ctx, stockpile_id, "editor")
    check_if_match(sp, if_match)
    if changes.get("outline") is not None:
        sp.outline = validate_outline(changes["outline"])
    if changes.get("base") is not None:
        sp.base = validate_base(changes["base"])
    if changes.get("name") is not None and changes["name"] != sp.name:
        if ctx.db.scalar(select(Stockpile.id).where(Stockpile.site_id == sp.site_id, Stockpile.name == changes["name"])):
            raise Conflict(f"a stockpile named {changes['name']!r} exists on this site")
        sp.name = changes["name"]
    for k in ("material", "density_t_m3"):
        if k in changes and (changes[k] is not None or k == "density_t_m3"):
            setattr(sp, k, changes[k])
    sp.version += 1
    ctx.db.flush()
    return sp


def delete_stockpile(ctx: Ctx, stockpile_id: str, if_match: str | None = None) -> None:
    sp = require_stockpile(ctx, stockpile_id, "editor")
    check_if_match(sp, if_match)
    ctx.db.delete(sp)
    ctx.db.flush()


def volume_history(ctx: Ctx, stockpile_id: str) -> list[dict]:
    sp = require_stockpile(ctx, stockpile_id, "viewer")
    rows = ctx.db.execute(
        select(VolumeMeasurement, Run.number, Run.state, Survey.name)
        .join(Run, Run.id == VolumeMeasurement.run_id).join(Survey, Survey.id == VolumeMeasurement.survey_id)
        .where(VolumeMeasurement.stockpile_id == sp.id)
        .order_by(VolumeMeasurement.measured_at.asc().nulls_last(), VolumeMeasurement.created_at)).all()
    out = []
    for vm, number, state, survey_name in rows:
        out.append({"run_id": vm.run_id, "run_number": number, "run_state": state, "survey_id": vm.survey_id,
                    "survey_name": survey_name, "measured_at": vm.measured_at, "base": vm.base,
                    "volume_m3": vm.volume_m3, "sigma_m3": (vm.details or {}).get("sigma_m3"),
                    "fill_m3": vm.fill_m3, "cut_m3": vm.cut_m3, "area_m2": vm.area_m2,
                    "tonnes": (vm.volume_m3 * sp.density_t_m3) if (vm.volume_m3 is not None and sp.density_t_m3)
                    else None})
    return out
