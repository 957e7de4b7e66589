"""Surveys, the files of their folder, their control/check points and the pre-flight check."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import func, select, update

from ..core.problems import Conflict, NotFound, Unprocessable
from ..models import Survey, SurveyFile, VolumeMeasurement
from ..storage import blob_key
from . import file_kinds
from .context import Ctx
from .new_data import note_new_data
from .pagination import Page, paginate
from .permissions import require_site, require_survey
from .sites import check_if_match

def validate_settings(settings: dict | None) -> dict:
    """Settings ({step: {option: value}}) checked against the steps' specs (steps_catalog.validate_settings):
    an unknown section or option, a wrong type, range or choice is a 422 naming it, before anything runs."""
    from georef_core.errors import ProcessingError

    from .steps_catalog import validate_settings as check

    if settings is not None and not isinstance(settings, dict):
        raise Unprocessable("settings: an object of sections expected")
    try:
        return check(dict(settings or {}))
    except ProcessingError as exc:
        raise Unprocessable(str(exc)) from None


def create_survey(ctx: Ctx, site_id: str, name: str, flown_at: datetime | None, notes: str, settings: dict | None) -> Survey:
    require_site(ctx, site_id, "editor")
    s = Survey(site_id=site_id, name=name, flown_at=flown_at, flown_at_source="user" if flown_at else None,
               notes=notes, settings=validate_settings(settings), created_by=ctx.user.id)
    ctx.db.add(s)
    ctx.db.flush()
    return s


def list_surveys(ctx: Ctx, site_id: str, q: str | None, flown_after: datetime | None, flown_before: datetime | None,
                 limit: int, offset: int) -> Page:
    require_site(ctx, site_id, "viewer")
    stmt = select(Survey).where(Survey.site_id == site_id)
    if q:
        stmt = stmt.where(func.lower(Survey.name).contains(q.lower()))
    if flown_after:
        stmt = stmt.where(Survey.flown_at >= flown_after)
    if flown_before:
        stmt = stmt.where(Survey.flown_at < flown_before)
    stmt = stmt.order_by(Survey.created_at.desc(), Survey.id)
    return paginate(ctx, stmt, limit, offset)


def get_survey(ctx: Ctx, survey_id: str) -> Survey:
    return require_survey(ctx, survey_id, "viewer")


def update_survey(ctx: Ctx, survey_id: str, changes: dict, if_match: str | None = None) -> Survey:
    s = require_survey(ctx, survey_id, "editor")
    check_if_match(s, if_match)
    if "settings" in changes:
        changes["settings"] = validate_settings(changes["settings"])
    if "flown_at" in changes:
        # a date given is kept; null hands the date back to the data (the next run reads it)
        when = changes.pop("flown_at")
        set_flown_at(ctx.db, s, when, "user" if when else None, bump=False)
    for k, v in changes.items():
        if k == "name" and v is None:
            continue
        setattr(s, k, v)
    s.version += 1
    ctx.db.flush()
    return s


def set_flown_at(db, survey: Survey, when: datetime | None, source: str | None, bump: bool = True) -> None:
    """The survey's flight time and where it comes from ('user', or the data: 'gnss', 'dji-mrk', 'exif');
    its volume measurements are dated by it (VolumeMeasurement.measured_at), so they follow it."""
    survey.flown_at, survey.flown_at_source = when, source
    if bump:
        survey.version += 1
    if when is not None:
        db.execute(update(VolumeMeasurement).where(VolumeMeasurement.survey_id == survey.id).values(measured_at=when))


def delete_survey(ctx: Ctx, survey_id: str, if_match: str | None = None) -> None:
    s = require_survey(ctx, survey_id, "editor")
    check_if_match(s, if_match)
    ctx.db.delete(s)
    ctx.db.flush()


# ----------------------------------------------------------------------------------------- files


def survey_files(db, survey_id: str) -> list[SurveyFile]:
    return list(db.scalars(select(SurveyFile).where(SurveyFile.survey_id == survey_id).order_by(SurveyFile.path)))


def list_files(ctx: Ctx, survey_id: str) -> list[SurveyFile]:
    require_survey(ctx, survey_id, "viewer")
    return survey_files(ctx.db, survey_id)


def _file(ctx: Ctx, survey_id: str, file_id: str) -> SurveyFile:
    f = ctx.db.get(SurveyFile, file_id)
    if f is None or f.survey_id != survey_id:
        raise NotFound("file not found")
    return f


def set_file_role(ctx: Ctx, survey_id: str, file_id: str, role: str) -> SurveyFile:
    s = require_survey(ctx, survey_id, "editor")
    f = _file(ctx, survey_id, file_id)
    if f.kind not in file_kinds.OBSERVATION_KINDS:
        raise Unprocessable("only GNSS observation files have a role (rover or base)")
    if f.path.startswith("flights/"):
        raise Unprocessable(f"{f.path} is the raw log of a DJI flight folder: it is the rover's")
    if role not in ("rover", "base"):
        raise Unprocessable("role: rover or base")
    new_path = f"{role}/{f.path.rsplit('/', 1)[-1]}"
    if new_path != f.path:
        clash = ctx.db.scalar(select(SurveyFile.id).where(SurveyFile.survey_id == survey_id, SurveyFile.path == new_path))
        if clash:
            raise Conflict(f"{new_path} already exists in the survey")
    f.role, f.path = role, new_path
    s.version += 1
    ctx.db.flush()
    return f


def delete_file(ctx: Ctx, survey_id: str, file_id: str) -> None:
    s = require_survey(ctx, survey_id, "editor")
    f = _file(ctx, survey_id, file_id)
    ctx.db.delete(f)
    s.version += 1
    ctx.db.flush()


# ----------------------------------------------------------------------------------------- points

POINTS_PATH = "gcp/points.csv"


def _points_file(ctx: Ctx, survey_id: str) -> SurveyFile | None:
    return ctx.db.scalar(select(SurveyFile).where(SurveyFile.survey_id == survey_id, SurveyFile.path == POINTS_PATH))


def read_points(ctx: Ctx, f: SurveyFile) -> list[dict]:
    text = ctx.storage.read_bytes(blob_key(f.sha256)).decode("utf-8-sig", errors="replace")
    try:
        return file_kinds.parse_points_csv(text)
    except ValueError as exc:
        raise Unprocessable(f"{POINTS_PATH}: {exc}") from None


def list_points(ctx: Ctx, survey_id: str) -> list[dict]:
    require_survey(ctx, survey_id, "viewer")
    f = _points_file(ctx, survey_id)
    return [] if f is None else read_points(ctx, f)


def set_point_role(ctx: Ctx, survey_id: str, name: str, role: str) -> dict:
    """Switch a point between control and check: a new points.csv (new checksum: the next run redoes
    the steps that depend on it, the earlier ones are reused)."""
    s = require_survey(ctx, survey_id, "editor")
    if role not in ("control", "check"):
        raise Unprocessable("role: control or check")
    f = _points_file(ctx, survey_id)
    if f is None:
        raise NotFound("the survey has no points file")
    points = read_points(ctx, f)
    hit = next((p for p in points if p["name"] == name), None)
    if hit is None:
        raise NotFound(f"point {name!r} not found")
    if hit["role"] != role:
        hit["role"] = role
        sha, size = ctx.storage.put_blob_bytes(file_kinds.format_points_csv(points).encode())
        f.sha256, f.size = sha, size
        f.meta = {"points": len(points), "control": sum(p["role"] == "control" for p in points),
                  "check": sum(p["role"] == "check" for p in points)}
        s.version += 1
        ctx.db.flush()
        note_new_data(ctx, s, "points")
    return hit


# ----------------------------------------------------------------------------------------- pre-flight


def preflight(ctx: Ctx, survey_id: str) -> dict:
    """Problems to fix before processing, each with a code the UI can key on, and a summary line of what
    was found (services/preflight.py)."""
    from . import preflight as checks

    s = require_survey(ctx, survey_id, "viewer")
    site = require_site(ctx, s.site_id, "viewer")
    return checks.run(ctx, s, survey_files(ctx.db, survey_id), site)
