"""Sites and their members (per-site roles)."""

from __future__ import annotations

from functools import lru_cache

from sqlalchemy import delete, func, select

from ..core.problems import Conflict, NotFound, PreconditionFailed, Unprocessable
from ..models import Site, SiteRole, User
from .context import Ctx
from .pagination import Page, paginate
from .permissions import ROLE_RANK, require_scope, require_site, site_ids_with_role


@lru_cache(maxsize=256)
def _crs_info(text: str) -> tuple[str, bool, bool, str]:
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        crs = CRS.from_user_input(text)
    except CRSError as exc:
        raise Unprocessable(f"crs {text!r} is not a known coordinate reference system ({exc})") from None
    auth = crs.to_authority()
    code = f"{auth[0]}:{auth[1]}" if auth else text
    return code, crs.is_projected, crs.is_vertical, crs.name


def validate_crs(text: str) -> str:
    code, projected, _, name = _crs_info(text.strip())
    if not projected:
        raise Unprocessable(f"crs {text!r} ({name}) is not a projected CRS; sites need easting/northing in metres "
                            "(e.g. a UTM zone, EPSG:32631)")
    return code


def validate_vertical(text: str | None) -> str | None:
    if not text:
        return None
    code, _, vertical, name = _crs_info(text.strip())
    if not vertical:
        raise Unprocessable(f"vertical_datum {text!r} ({name}) is not a vertical CRS (e.g. EPSG:5773 EGM96 height)")
    return code


def check_if_match(obj, if_match: str | None) -> None:
    """Optimistic concurrency: If-Match must name the row's current ETag (W/ prefix tolerated)."""
    if not if_match:
        return
    from ..core.etag import version_etag  # the one ETag formula

    want = version_etag(obj)
    tags = [t.strip().removeprefix("W/") for t in if_match.split(",")]
    if "*" not in tags and want not in tags:
        raise PreconditionFailed("the resource changed since you read it (ETag mismatch); reload and retry")


def create_site(ctx: Ctx, name: str, crs: str, vertical_datum: str | None, geoid: str | None,
                description: str, tolerance_horizontal_m: float = 0.03, tolerance_vertical_m: float = 0.05) -> Site:
    require_scope(ctx, "write")
    site = Site(organisation_id=ctx.user.organisation_id, name=name, crs=validate_crs(crs),
                vertical_datum=validate_vertical(vertical_datum), geoid=geoid or None, description=description,
                tolerance_horizontal_m=tolerance_horizontal_m, tolerance_vertical_m=tolerance_vertical_m)
    ctx.db.add(site)
    ctx.db.flush()
    ctx.db.add(SiteRole(site_id=site.id, user_id=ctx.user.id, role="admin"))
    ctx.db.flush()
    return site


def list_sites(ctx: Ctx, q: str | None, limit: int, offset: int) -> Page:
    require_scope(ctx, "read")
    stmt = select(Site).where(Site.id.in_(site_ids_with_role(ctx))).order_by(Site.name, Site.id)
    if q:
        stmt = stmt.where(func.lower(Site.name).contains(q.lower()))
    return paginate(ctx, stmt, limit, offset)


def get_site(ctx: Ctx, site_id: str) -> Site:
    return require_site(ctx, site_id, "viewer")


def update_site(ctx: Ctx, site_id: str, changes: dict, if_match: str | None = None) -> Site:
    site = require_site(ctx, site_id, "admin")
    check_if_match(site, if_match)
    if "crs" in changes and changes["crs"] is not None:
        changes["crs"] = validate_crs(changes["crs"])
    if "vertical_datum" in changes:
        changes["vertical_datum"] = validate_vertical(changes["vertical_datum"])
    for k, v in changes.items():
        if k in ("name", "crs", "description", "tolerance_horizontal_m", "tolerance_vertical_m") and v is None:
            continue
        setattr(site, k, v)
    site.version += 1
    ctx.db.flush()
    return site


def delete_site(ctx: Ctx, site_id: str, if_match: str | None = None) -> None:
    site = require_site(ctx, site_id, "admin")
    check_if_match(site, if_match)
    ctx.db.delete(site)
    ctx.db.flush()


def list_members(ctx: Ctx, site_id: str) -> list[dict]:
    require_site(ctx, site_id, "viewer")
    rows = ctx.db.execute(select(SiteRole, User).join(User, User.id == SiteRole.user_id)
                          .where(SiteRole.site_id == site_id).order_by(User.email)).all()
    return [{"user_id": u.id, "email": u.email, "name": u.name, "role": r.role} for r, u in rows]


def _admins(ctx: Ctx, site_id: str) -> int:
    return ctx.db.scalar(select(func.count()).select_from(SiteRole)
                         .where(SiteRole.site_id == site_id, SiteRole.role == "admin")) or 0


def set_member(ctx: Ctx, site_id: str, user_id: str, role: str) -> dict:
    site = require_site(ctx, site_id, "admin")
    if role not in ROLE_RANK:
        raise Unprocessable("role: viewer, editor or admin")
    user = ctx.db.get(User, user_id)
    if user is None or user.organisation_id != site.organisation_id:
        raise NotFound("user not found in the site's organisation")
    row = ctx.db.get(SiteRole, (site_id, user_id))
    if row is None:
        ctx.db.add(SiteRole(site_id=site_id, user_id=user_id, role=role))
    else:
        if row.role == "admin" and role != "admin" and _admins(ctx, site_id) <= 1:
            raise Conflict("a site keeps at least one admin")
        row.role = role
    ctx.db.flush()
    return {"user_id": user.id, "email": user.email, "name": user.name, "role": role}


def remove_member(ctx: Ctx, site_id: str, user_id: str) -> None:
    require_site(ctx, site_id, "admin")
    row = ctx.db.get(SiteRole, (site_id, user_id))
    if row is None:
        raise NotFound("member not found")
    if row.role == "admin" and _admins(ctx, site_id) <= 1:
        raise Conflict("a site keeps at least one admin")
    ctx.db.execute(delete(SiteRole).where(SiteRole.site_id == site_id, SiteRole.user_id == user_id))
