"""Access rules in one place: per-site roles (viewer < editor < admin) and token scopes.

A site on which the caller has no role answers NotFound, exactly as a site that does not exist (no
enumeration); a role too low, or a token without the scope, answers Forbidden."""

from __future__ import annotations

from sqlalchemy import and_, select
from sqlalchemy.orm import defer

from ..core.problems import Forbidden, NotFound, Unauthorized
from ..models import Run, RunOutput, Schedule, Site, SiteRole, Stockpile, Survey, Upload, Webhook
from .context import Ctx

ROLE_RANK = {"viewer": 1, "editor": 2, "admin": 3}
ROLE_SCOPE = {"viewer": "read", "editor": "write", "admin": "admin"}


def role_on_site(ctx: Ctx, site_id: str) -> str | None:
    if ctx.principal is None:
        return None
    return ctx.db.scalar(select(SiteRole.role).where(SiteRole.site_id == site_id,
                                                     SiteRole.user_id == ctx.principal.user.id))


def require_scope(ctx: Ctx, scope: str) -> None:
    if ctx.principal is None:
        raise Unauthorized("authentication required")
    if not ctx.principal.has_scope(scope):
        raise Forbidden(f"this API token lacks the {scope!r} scope")


def _check(ctx: Ctx, have: str | None, role: str, what: str) -> None:
    if have is None:
        raise NotFound(f"{what} not found")
    require_scope(ctx, ROLE_SCOPE[role])
    if ROLE_RANK[have] < ROLE_RANK[role]:
        raise Forbidden(f"this needs the {role} role on the site; you are {have}")


def _caller_role_on(ctx: Ctx, site_col):
    """Join condition of the caller's SiteRole row on the site in `site_col` (for an outer join)."""
    return and_(SiteRole.site_id == site_col, SiteRole.user_id == ctx.principal.user.id)


def _with_role(ctx: Ctx, model, obj_id: str, site_col):
    """(object, caller's role on its site) in one query; (None, None) when the object does not exist."""
    if not obj_id:
        return None, None
    row = ctx.db.execute(select(model, SiteRole.role).outerjoin(SiteRole, _caller_role_on(ctx, site_col))
                         .where(model.id == obj_id)).first()
    return (row[0], row[1]) if row is not None else (None, None)


def require_site(ctx: Ctx, site_id: str, role: str = "viewer", what: str = "site") -> Site:
    """The site, when the caller holds at least `role` on it (and the token the matching scope)."""
    if ctx.principal is None:
        raise Unauthorized("authentication required")
    site, have = _with_role(ctx, Site, site_id, Site.id)
    _check(ctx, have, role, what)
    return site


def _require_child(ctx: Ctx, model, obj_id: str, role: str, what: str):
    if ctx.principal is None:
        raise Unauthorized("authentication required")
    obj, have = _with_role(ctx, model, obj_id, model.site_id)
    _check(ctx, have, role, what)
    return obj


def require_survey(ctx: Ctx, survey_id: str, role: str = "viewer") -> Survey:
    return _require_child(ctx, Survey, survey_id, role, "survey")


def require_run(ctx: Ctx, run_id: str, role: str = "viewer") -> Run:
    return _require_child(ctx, Run, run_id, role, "run")


def require_run_with_outputs(ctx: Ctx, run_id: str, paths: tuple[str, ...],
                             role: str = "viewer") -> tuple[Run, dict[str, RunOutput]]:
    """require_run, plus the run's outputs among `paths` (by path), in the same query: the result
    endpoints that GIS systems poll need one round trip to the database instead of two."""
    if ctx.principal is None:
        raise Unauthorized("authentication required")
    run, have, outputs = _run_role_and_outputs(ctx, run_id, paths)
    _check(ctx, have, role, "run")
    return run, outputs


def _run_role_and_outputs(ctx: Ctx, run_id: str, paths: tuple[str, ...]):
    """(run, the caller's role on its site, its outputs among `paths` by path) in one query; (None, None, {})
    when the run does not exist. The run's JSON columns are not read (its inputs list every image of the
    survey: tens of kilobytes to parse on each poll of a result or tile); they load on first access."""
    rows = ctx.db.execute(select(Run, SiteRole.role, RunOutput)
                          .options(defer(Run.inputs), defer(Run.settings), defer(Run.changes))
                          .outerjoin(SiteRole, _caller_role_on(ctx, Run.site_id))
                          .outerjoin(RunOutput, and_(RunOutput.run_id == Run.id, RunOutput.path.in_(paths)))
                          .where(Run.id == run_id)).all() if run_id else []
    run, have = (rows[0][0], rows[0][1]) if rows else (None, None)
    return run, have, {r[2].path: r[2] for r in rows if r[2] is not None}


def require_stockpile(ctx: Ctx, stockpile_id: str, role: str = "viewer") -> Stockpile:
    return _require_child(ctx, Stockpile, stockpile_id, role, "stockpile")


def require_schedule(ctx: Ctx, schedule_id: str, role: str = "viewer") -> Schedule:
    return _require_child(ctx, Schedule, schedule_id, role, "schedule")


def require_webhook(ctx: Ctx, webhook_id: str, role: str = "admin") -> Webhook:
    return _require_child(ctx, Webhook, webhook_id, role, "webhook")


def require_upload(ctx: Ctx, upload_id: str, role: str = "viewer") -> Upload:
    up = ctx.db.get(Upload, upload_id) if upload_id else None
    if up is None:
        raise NotFound("upload not found")
    survey = ctx.db.get(Survey, up.survey_id)
    if survey is None:
        raise NotFound("upload not found")
    require_site(ctx, survey.site_id, role, "upload")
    return up


def site_ids_with_role(ctx: Ctx, role: str = "viewer"):
    """A sub-select of the ids of the sites on which the caller holds at least `role`."""
    allowed = [r for r, rank in ROLE_RANK.items() if rank >= ROLE_RANK[role]]
    return select(SiteRole.site_id).where(SiteRole.user_id == ctx.principal.user.id, SiteRole.role.in_(allowed))


def require_run_for_tiles(ctx: Ctx, run_id: str, paths: tuple[str, ...]) -> tuple[Run, dict[str, RunOutput]]:
    """require_run_with_outputs for the map tiles and the WMTS document: the viewer role, and a token with
    the read scope or a tile token (scope "tiles", which reads nothing else)."""
    if ctx.principal is None:
        raise Unauthorized("authentication required")
    p = ctx.principal
    if not (p.has_scope("read") or p.has_scope("tiles")):
        raise Forbidden("this API token lacks the 'read' or 'tiles' scope")
    run, have, outputs = _run_role_and_outputs(ctx, run_id, paths)
    if have is None:
        raise NotFound("run not found")
    return run, outputs
