"""Surveys, the files of their folder, their control/check points and the pre-flight check."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import func, select

from ..core.problems import Conflict, NotFound, Unprocessable
from ..models import Survey, SurveyFile
from ..storage import blob_key
from . import file_kinds
from .context import Ctx
from .pagination import Page, paginate
from .permissions import require_site, require_survey
from .sites import check_if_match

SETTINGS_SECTIONS = ("gnss", "georef", "dense", "volumes", "report")


def validate_settings(settings: dict | None) -> dict:
    settings = dict(settings or {})
    bad = [k for k in settings if k not in SETTINGS_SECTIONS]
    if bad:
        raise Unprocessable(f"settings: unknown section(s) {', '.join(bad)}; sections are {', '.join(SETTINGS_SECTIONS)}")
    for k, v in settings.items():
        if not isinstance(v, dict):
            raise Unprocessable(f"settings.{k}: an object of options expected")
    return settings


def create_survey(ctx: Ctx, site_id: str, name: str, flown_at: datetime | None, notes: str, settings: dict | None) -> Survey:
    require_site(ctx, site_id, "editor")
    s = Survey(site_id=site_id, name=name, flown_at=flown_at, notes=notes, settings=validate_settings(settings),
               created_by=ctx.user.id)
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
    for k, v in changes.items():
        if k == "name" and v is None:
            continue
        setattr(s, k, v)
    s.version += 1
    ctx.db.flush()
    return s


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
    if f.kind not in ("rinex-obs", "ubx"):
        raise Unprocessable("only GNSS observation files have a role (rover or base)")
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
        from .schedules import note_new_data

        note_new_data(ctx, s, "points")
    return hit


# ----------------------------------------------------------------------------------------- pre-flight


def _problem(severity: str, code: str, message: str, files=()) -> dict:
    return {"severity": severity, "code": code, "message": message, "files": list(files)}


def preflight(ctx: Ctx, survey_id: str) -> dict:
    """Problems to fix before processing, each with a code the UI can key on."""
    s = require_survey(ctx, survey_id, "viewer")
    files = survey_files(ctx.db, survey_id)
    by_kind: dict[str, list[SurveyFile]] = {}
    for f in files:
        by_kind.setdefault(f.kind, []).append(f)
    obs = by_kind.get("rinex-obs", []) + by_kind.get("ubx", [])
    rover = [f for f in obs if f.role == "rover"]
    base = [f for f in obs if f.role == "base"]
    unassigned = [f for f in obs if f.role not in ("rover", "base")]
    problems: list[dict] = []
    if unassigned:
        problems.append(_problem("error", "observation-role-unknown", "observation file(s) not assigned to the rover "
                                 "or the base: set their role", [f.path for f in unassigned]))
    if not rover:
        problems.append(_problem("error", "missing-rover", "no rover (drone) GNSS observations"))
    if len(rover) > 1:
        problems.append(_problem("error", "several-rover-files", "more than one rover observation file; keep one",
                                 [f.path for f in rover]))
    if not base:
        problems.append(_problem("error", "missing-base", "no base station observations"))
    if len(base) > 1:
        problems.append(_problem("error", "several-base-files", "more than one base observation file; keep one",
                                 [f.path for f in base]))
    has_ubx_nav = any(f.kind == "ubx" for f in obs)
    if not by_kind.get("rinex-nav") and not has_ubx_nav:
        problems.append(_problem("error", "missing-navigation", "no navigation (ephemeris) file: upload the RINEX "
                                 "navigation file of the day (e.g. from the base receiver or an IGS/CORS server)"))

    def span(f):
        m = f.meta or {}
        a, b = m.get("first_gps_time_s"), m.get("last_gps_time_s")
        return (a, b) if a is not None and b is not None else None

    if len(rover) == 1 and len(base) == 1:
        rs, bs = span(rover[0]), span(base[0])
        if rs and bs:
            overlap = min(rs[1], bs[1]) - max(rs[0], bs[0])
            dur = max(rs[1] - rs[0], 1e-9)
            if overlap <= 0:
                problems.append(_problem("error", "no-time-overlap", "rover and base observations do not overlap in "
                                         "time", [rover[0].path, base[0].path]))
            elif overlap < 0.95 * dur:
                problems.append(_problem("warning", "partial-time-overlap",
                                         f"the base covers {100 * overlap / dur:.0f} % of the rover's "
                                         f"{dur / 60:.1f} min", [rover[0].path, base[0].path]))
        else:
            problems.append(_problem("info", "time-span-unknown", "observation time spans could not be read before "
                                     "processing (compressed or UBX without raw measurements)",
                                     [f.path for f in rover + base if not span(f)]))
    images = by_kind.get("image", [])
    events_file = next((f for f in by_kind.get("events", []) if f.path == "events.csv"), None)
    rover_marks = sum(int((f.meta or {}).get("event_marks", 0)) for f in rover)
    if not images:
        problems.append(_problem("warning", "no-images", "no images: only the GNSS trajectory can be computed"))
    else:
        if events_file is not None:
            listed = set((events_file.meta or {}).get("images") or [])
            n_events = int((events_file.meta or {}).get("events", 0))
            names = {f.path.rsplit("/", 1)[-1] for f in images}
            if listed:
                missing = sorted(names - listed)
                if missing:
                    problems.append(_problem("warning", "images-without-events",
                                             f"{len(missing)} image(s) have no camera event in events.csv",
                                             [f"images/{n}" for n in missing[:50]]))
                unknown = sorted(listed - names)
                if unknown:
                    problems.append(_problem("warning", "events-without-images",
                                             f"{len(unknown)} event(s) name images that were not uploaded", unknown[:50]))
            elif n_events != len(images):
                problems.append(_problem("warning", "images-without-events",
                                         f"{len(images)} images but {n_events} camera events in events.csv"))
        elif rover_marks:
            if rover_marks != len(images):
                problems.append(_problem("warning", "images-without-events",
                                         f"{len(images)} images but {rover_marks} event marks in the rover file"))
        else:
            problems.append(_problem("warning", "images-without-events", "no camera events: neither events.csv nor "
                                     "event marks in the rover observations; images will be matched by EXIF time"))
    pts = next((f for f in by_kind.get("points", []) if f.path == POINTS_PATH), None)
    if pts is None:
        problems.append(_problem("warning", "no-points", "no control/check points: no residual table can be computed"))
    elif not (pts.meta or {}).get("check"):
        problems.append(_problem("warning", "no-check-points", "no check point: accuracy cannot be verified "
                                 "independently (switch some points to check)", [pts.path]))
    gl = next((f for f in by_kind.get("gcp-list", [])), None)
    if gl is not None and images:
        names = {f.path.rsplit("/", 1)[-1] for f in images}
        unknown = sorted(set((gl.meta or {}).get("images") or []) - names)
        if unknown:
            problems.append(_problem("warning", "gcp-list-unknown-images",
                                     f"gcp_list.txt measures {len(unknown)} image(s) that were not uploaded",
                                     unknown[:50]))
    site = require_site(ctx, s.site_id, "viewer")
    if gl is not None:
        crs = str((gl.meta or {}).get("crs", "")).upper()
        if crs.startswith("EPSG:") and crs != site.crs.upper():
            problems.append(_problem("warning", "crs-mismatch", f"gcp_list.txt is in {crs}, the site in {site.crs}",
                                     [gl.path]))
    errors = sum(p["severity"] == "error" for p in problems)
    return {"survey_id": s.id, "ok": errors == 0, "errors": errors,
            "warnings": sum(p["severity"] == "warning" for p in problems), "problems": problems,
            "files": {k: len(v) for k, v in sorted(by_kind.items())}}
