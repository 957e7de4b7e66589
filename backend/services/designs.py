"""A site's design surface: the file (LandXML, DXF or GeoTIFF; checked by georef_core's reader when it is
uploaded and stored content-addressed like survey files), the area compared (GeoJSON, site CRS) and the
on-grade tolerance. The design step of every run reads it (jobs.run_context -> worker materialise ->
pipeline context "design"); design_progress lists its results over the site's surveys. docs/design.md."""

from __future__ import annotations

import hashlib
import math
import tempfile
from pathlib import Path

from sqlalchemy import select

from ..core.problems import NotFound, Unprocessable
from ..models import Run, RunStep, SiteDesign, Survey
from ..schemas.designs import DesignChange
from .context import Ctx
from .permissions import require_site
from .sites import check_if_match

MAX_AREA_VERTICES = 100_000
FORMATS = ("landxml", "dxf", "geotiff")
# what design_progress keeps of each run's design summary (georef_core/steps/design.py summary_of)
PROGRESS_KEYS = ("cut_m3", "fill_m3", "net_m3", "area_m2", "tolerance_m", "on_grade_share", "on_grade_expected_share",
                 "not_significant_m2", "cut_beyond_tolerance_m3", "fill_beyond_tolerance_m3", "noise_inflation_m3",
                 "sigma_cell_m", "surface")


def design_key(d: SiteDesign) -> str:
    """Identifies the design as a run compares with it: the file, the LandXML surface and the area (the
    tolerance is a run's figure, reported with each result). The design step's summary carries it."""
    from .runs import canonical_json

    doc = {"sha256": d.sha256, "surface_name": d.surface_name, "area": d.area}
    return hashlib.sha256(canonical_json(doc).encode()).hexdigest()[:24]


def _area_m2(area: dict | None) -> float | None:
    if not area:
        return None
    from shapely.geometry import shape

    return round(float(shape(area).area), 3)


def design_out(d: SiteDesign) -> dict:
    return {"site_id": d.site_id, "filename": d.filename, "format": d.format, "sha256": d.sha256, "size": d.size,
            "surface_name": d.surface_name, "described": d.described or {}, "area": d.area,
            "area_m2": _area_m2(d.area), "tolerance_m": d.tolerance_m, "key": design_key(d),
            "created_at": d.created_at, "updated_at": d.updated_at, "version": d.version}


def _format_of(path: Path, kind: str) -> str:
    if kind == "grid":
        return "geotiff"
    with open(path, "rb") as f:
        head = f.read(4096).lstrip(b"\xef\xbb\xbf").lstrip()
    return "landxml" if head.startswith(b"<") else "dxf"


def read_design_file(path: Path, filename: str, surface_name: str | None, site_crs: str) -> dict:
    """The design read by georef_core's reader, as at run time: {format, described (kind, name, CRS, points,
    triangles, notes, extent in the site CRS)}. A file the reader refuses: 422 naming the file and the
    problem."""
    from pyproj import CRS

    from georef_core.design.design_surface import read_design
    from georef_core.errors import InputFileError, ProcessingError

    try:
        design = read_design(path, surface_name, site_crs)
        design.prepare(CRS.from_user_input(site_crs))
        described = design.describe()
        bounds = design.bounds()
    except InputFileError as exc:
        raise Unprocessable(f"{filename}: {exc.problem}", slug="bad-design") from None
    except ProcessingError as exc:
        raise Unprocessable(f"{filename}: {exc}", slug="bad-design") from None
    except (ValueError, OSError, UnicodeDecodeError) as exc:   # a reader's library refusing the content
        raise Unprocessable(f"{filename}: not a readable design surface ({type(exc).__name__}: {exc})",
                            slug="bad-design") from None
    described.pop("path", None)                              # a temporary path of the API, not the user's
    rs = getattr(design, "_resampler", None)
    if bounds is None and rs is not None:       # a grid: its extent, in the site CRS
        from pyproj import Transformer

        bounds = rs.info.bounds
        if not rs.same_crs:
            bounds = Transformer.from_crs(rs.info.crs, rs.dst_crs, always_xy=True).transform_bounds(*bounds)
    if bounds is not None and all(math.isfinite(v) for v in bounds):
        described["extent"] = [round(float(v), 3) for v in bounds]
    return {"format": _format_of(path, design.kind), "described": described}


def validate_area(area: dict, extent: list | None) -> dict:
    """A GeoJSON Polygon or MultiPolygon in the site CRS (metres), valid, with area, overlapping the design."""
    from shapely.geometry import box

    from .stockpiles import polygon_geometry

    if not isinstance(area, dict) or area.get("type") not in ("Polygon", "MultiPolygon"):
        raise Unprocessable("area: a GeoJSON Polygon or MultiPolygon (coordinates in the site CRS, metres) expected")
    coords = area.get("coordinates")
    rings = coords if area["type"] == "Polygon" else [r for p in (coords or []) if isinstance(p, list) for r in p]
    if not isinstance(rings, list) or not rings or not all(isinstance(r, list) for r in rings):
        raise Unprocessable("area: coordinates must be rings (lists of [x, y] positions)")
    geom = polygon_geometry(area, rings, "area", MAX_AREA_VERTICES)
    if extent:
        ext = box(*extent)
        if not geom.intersects(ext):
            x0, y0, x1, y1 = geom.bounds
            raise Unprocessable(f"area: the polygon ({x0:.1f}, {y0:.1f} - {x1:.1f}, {y1:.1f}) lies outside the "
                                f"design surface ({extent[0]:.1f}, {extent[1]:.1f} - {extent[2]:.1f}, "
                                f"{extent[3]:.1f}; site CRS): are both in the site CRS?")
    return {"type": area["type"], "coordinates": _floats(coords)}


def _floats(c):
    if isinstance(c, list) and c and isinstance(c[0], (int, float)):
        return [float(v) for v in c[:3]]
    return [_floats(x) for x in c]


def _get(ctx: Ctx, site_id: str, role: str) -> SiteDesign:
    require_site(ctx, site_id, role)
    d = ctx.db.get(SiteDesign, site_id)
    if d is None:
        raise NotFound("this site has no design surface: upload one (PUT /api/v1/sites/{id}/design/file)",
                       slug="no-design")
    return d


def require_editor(ctx: Ctx, site_id: str) -> None:
    """Before a design file's bytes are received: only an editor may send one."""
    require_site(ctx, site_id, "editor")


def upload_design(ctx: Ctx, site_id: str, filename: str, path: Path, surface_name: str | None = None,
                  if_match: str | None = None) -> SiteDesign:
    """Store ``path`` as the site's design surface (replacing the one before; the area and tolerance stay)."""
    from .uploads import sanitise_filename

    site = require_site(ctx, site_id, "editor")
    name = sanitise_filename(filename)
    d = ctx.db.get(SiteDesign, site_id)
    if d is not None:
        check_if_match(d, if_match)
    surface_name = (surface_name or "").strip() or None
    read = read_design_file(path, name, surface_name, site.crs)
    sha, size = ctx.storage.put_blob(path)
    if d is None:
        d = SiteDesign(site_id=site_id, tolerance_m=0.05, version=0)
        ctx.db.add(d)
    d.filename, d.format, d.sha256, d.size = name, read["format"], sha, size
    d.surface_name, d.described = surface_name, read["described"]
    d.uploaded_by = ctx.user.id
    d.version = (d.version or 0) + 1
    if d.area is not None:
        validate_area(d.area, d.described.get("extent"))
    ctx.db.flush()
    return d


def get_design(ctx: Ctx, site_id: str) -> SiteDesign:
    return _get(ctx, site_id, "viewer")


def update_design(ctx: Ctx, site_id: str, changes: dict, if_match: str | None = None) -> SiteDesign:
    """The area, the tolerance, or which LandXML surface (the stored file is read again with it)."""
    d = _get(ctx, site_id, "editor")
    check_if_match(d, if_match)
    if "surface_name" in changes and (changes["surface_name"] or None) != d.surface_name:
        site = require_site(ctx, site_id, "editor")
        name = (changes["surface_name"] or "").strip() or None
        with tempfile.TemporaryDirectory(dir=_tmp_dir(ctx)) as tmp:
            local = Path(tmp) / d.filename
            from ..storage import blob_key

            ctx.storage.fetch(blob_key(d.sha256), local)
            d.described = read_design_file(local, d.filename, name, site.crs)["described"]
        d.surface_name = name
    if changes.get("area") is not None:
        d.area = validate_area(changes["area"], (d.described or {}).get("extent"))
    if changes.get("tolerance_m") is not None:
        d.tolerance_m = float(changes["tolerance_m"])
    d.version += 1
    ctx.db.flush()
    return d


def delete_design(ctx: Ctx, site_id: str, if_match: str | None = None) -> None:
    d = _get(ctx, site_id, "editor")
    check_if_match(d, if_match)
    ctx.db.delete(d)
    ctx.db.flush()


def _tmp_dir(ctx: Ctx) -> Path:
    p = ctx.settings.resolved_work_dir() / "tmp"
    p.mkdir(parents=True, exist_ok=True)
    return p


def design_context(s, site_id: str) -> dict | None:
    """What a run's design step needs (jobs.run_context "design"): the stored file by checksum, the area,
    the tolerance and the key the step's summary carries back. None: no design, or no area yet."""
    d = s.get(SiteDesign, site_id)
    if d is None:
        return None
    return {"sha256": d.sha256, "filename": d.filename, "format": d.format, "surface_name": d.surface_name,
            "area": d.area, "tolerance_m": d.tolerance_m, "key": design_key(d), "name": Path(d.filename).stem}


def _num(v) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else None


def change_between(prev: dict, cur: dict, first: dict) -> dict:
    """``cur`` against ``prev`` (two design-progress entries, prev flown earlier; ``first``: the first
    compared survey): cut removed and fill placed toward the design since prev, the net's change, their 1 sigma,
    what remains and the share done since the first survey (schemas.designs.DesignChange).

    Sigma of a change a_cur - a_prev: each survey's own error (DSM noise, vertical bias of its georeferencing,
    unmeasured area) is independent of the other's; the design's own error (``design_sigma_m3``) is the same
    surface under both, so only the change of its share counts: var = (s_p^2 - d_p^2) + (s_c^2 - d_c^2) +
    (d_c - d_p)^2. Entries without ``design_sigma_m3`` (results older than it) count their sigmas independent."""
    def diff(key, sign):
        a, b = _num(prev.get(key)), _num(cur.get(key))
        return None if a is None or b is None else sign * (b - a)

    def sigma(key):
        sp, sc = _num((prev.get("sigma_m3") or {}).get(key)), _num((cur.get("sigma_m3") or {}).get(key))
        if sp is None or sc is None:
            return None
        dp = _num((prev.get("design_sigma_m3") or {}).get(key)) or 0.0
        dc = _num((cur.get("design_sigma_m3") or {}).get(key)) or 0.0
        return math.sqrt(max(sp * sp - dp * dp, 0.0) + max(sc * sc - dc * dc, 0.0) + (dc - dp) ** 2)

    def done(key):
        f, c = _num(first.get(key)), _num(cur.get(key))
        return None if f is None or c is None or f <= 0 else (f - c) / f

    days = None
    if prev.get("flown_at") and cur.get("flown_at"):
        days = (cur["flown_at"] - prev["flown_at"]).total_seconds() / 86400.0
    notes = []
    if prev.get("surface") != cur.get("surface"):
        notes.append(f"the surveys compared different surfaces with the design ({prev.get('surface')} then "
                     f"{cur.get('surface')}): machines and vegetation on a DSM count as cut")
    if days is None:
        notes.append("a flight date is missing: surveys without one are listed after the dated ones")
    return DesignChange(
        previous_survey_id=prev["survey_id"], previous_survey_name=prev["survey_name"], days=days,
        cut_moved_m3=diff("cut_m3", -1), fill_placed_m3=diff("fill_m3", -1), net_change_m3=diff("net_m3", 1),
        sigma_m3={"cut_moved_m3": sigma("cut_m3"), "fill_placed_m3": sigma("fill_m3"),
                  "net_change_m3": sigma("net_m3")},
        remaining_cut_m3=_num(cur.get("cut_m3")), remaining_fill_m3=_num(cur.get("fill_m3")),
        done_share={"cut_m3": done("cut_m3"), "fill_m3": done("fill_m3")}, notes=notes).model_dump()


def add_changes(entries: list[dict]) -> None:
    """Each entry (oldest flight first) gets ``since_previous``: change_between it and the entry before it
    (None for the first)."""
    for i, e in enumerate(entries):
        e["since_previous"] = change_between(entries[i - 1], e, entries[0]) if i else None


def add_surface_changes(ctx: Ctx, site_id: str, entries: list[dict], area: dict | None, database=None) -> bool:
    """Each ``since_previous`` (add_changes: from the totals) replaced by the stored surface-against-surface change
    (services/design_changes: computed by a worker, never here) where both runs kept their difference rasters;
    queued when there is none yet (its ``surfaces_state`` says queued or running, the figures stay the totals'
    until it is done). Returns whether any is still pending."""
    from . import design_changes

    pairs = {}
    for i in range(1, len(entries)):
        c = entries[i].get("since_previous")
        if c is None or not area:
            continue
        try:
            pairs[i] = design_changes.pair_inputs(ctx.db, entries[i - 1], entries[i], area)
        except ValueError as exc:
            c["notes"].append(f"computed from the two results' cut/fill totals, not surface against surface: {exc}")
    jobs = design_changes.request_changes(ctx, site_id, list(pairs.values()), database)
    pending = False
    for i, inputs in pairs.items():
        c, job = entries[i]["since_previous"], jobs[design_changes.job_key(inputs)]
        c["surfaces_state"] = job["state"]
        if job["state"] in ("queued", "running"):
            pending = True
            c["notes"].append("surface against surface: being computed by a worker; these figures are the totals' "
                              "until it is done")
            continue
        if job["state"] == "failed" or not job["result"]:
            c["notes"].append(f"computed from the two results' cut/fill totals, not surface against surface: "
                              f"{job['error'] or 'no result'}")
            continue
        sc = job["result"]
        c.update(method="surfaces", cut_moved_m3=sc["cut_moved_m3"], fill_placed_m3=sc["fill_placed_m3"],
                 net_change_m3=sc["net_change_m3"], sigma_m3=dict(sc["sigma_m3"]),
                 cut_below_design_m3=sc["cut_below_design_m3"], fill_above_design_m3=sc["fill_above_design_m3"],
                 area_m2=sc["area_m2"], uncertainty={**sc["uncertainty"], "model": sc.get("accuracy")})
        c["notes"].extend(sc["notes"])
    return pending


def progress_entries(s, site_id: str, key: str) -> tuple[list[dict], list[dict]]:
    """(entries, not compared) of design_progress: each survey's latest successful run whose design step compared
    with the design ``key``, oldest flight first; the others with the reason. No permission check (the caller's)."""
    surveys = list(s.scalars(select(Survey).where(Survey.site_id == site_id)))
    rows = s.execute(
        select(Run.id, Run.number, Run.survey_id, Run.finished_at, RunStep.summary, RunStep.state)
        .join(RunStep, RunStep.run_id == Run.id)
        .where(Run.site_id == site_id, Run.state == "succeeded", RunStep.name == "design",
               RunStep.state.in_(("succeeded", "skipped")))
        .order_by(Run.survey_id, Run.number.desc())).all()
    latest: dict[str, tuple] = {}
    other_design: set[str] = set()
    for run_id, number, survey_id, finished_at, summary, _state in rows:
        if not isinstance(summary, dict) or summary.get("skipped"):
            continue
        if summary.get("design_key") != key:
            other_design.add(survey_id)
            continue
        latest.setdefault(survey_id, (run_id, number, finished_at, summary))
    entries, missing = [], []
    for sv in surveys:
        hit = latest.get(sv.id)
        base = {"survey_id": sv.id, "survey_name": sv.name, "flown_at": sv.flown_at}
        if hit is None:
            missing.append({**base, "reason": (
                "its runs compared with another design, area or surface: process it again" if sv.id in other_design
                else "no successful run with the design step")})
            continue
        run_id, number, finished_at, summary = hit
        entry = {**base, "run_id": run_id, "run_number": number, "processed_at": finished_at}
        entry.update({k: summary.get(k) for k in PROGRESS_KEYS})
        entry["sigma_m3"] = summary.get("sigma_m3") or {}
        entry["design_sigma_m3"] = summary.get("design_sigma_m3") or {}
        entry["warnings"] = summary.get("warnings") or []
        entries.append(entry)
    order = lambda e: (e["flown_at"] is None, e["flown_at"].isoformat() if e["flown_at"] else "", e["survey_name"])  # noqa: E731
    entries.sort(key=order)
    missing.sort(key=order)
    return entries, missing


def design_progress(ctx: Ctx, site_id: str, database=None) -> dict:
    """The site's design against every survey's latest successful run that compared with it (this file,
    surface and area), oldest flight first: cut, fill, net with their 1-sigma, on-grade share. Surveys
    without such a run are listed with the reason."""
    d = _get(ctx, site_id, "viewer")
    key = design_key(d)
    entries, missing = progress_entries(ctx.db, site_id, key)
    add_changes(entries)
    pending = add_surface_changes(ctx, site_id, entries, d.area, database)
    return {"design": {"filename": d.filename, "format": d.format, "sha256": d.sha256, "key": key,
                       "surface_name": d.surface_name, "area_m2": _area_m2(d.area), "tolerance_m": d.tolerance_m},
            "conventions": "cut_m3: surveyed above design (to remove); fill_m3: below design (to place); net_m3 = "
                           "cut - fill; sigma_m3: 1 sigma; on_grade_share: share of the area within +- tolerance_m; "
                           "since_previous: cut_moved_m3 (ground lowered: removed) and fill_placed_m3 (raised: placed) since the "
                           "survey before, surface against surface inside the design area (method), "
                           "remaining_cut_m3 / remaining_fill_m3 still to do",
            "surveys": entries, "not_compared": missing, "changes_pending": pending}


def queue_changes_after_run(s, run: Run) -> list[tuple]:
    """When a run whose design step succeeded ends: the changes design-progress will show for its site, queued ahead
    (jobs that exist are left as they are); the messages to send after commit."""
    from . import design_changes

    step = s.scalar(select(RunStep).where(RunStep.run_id == run.id, RunStep.name == "design",
                                          RunStep.state == "succeeded"))
    d = s.get(SiteDesign, run.site_id)
    if step is None or d is None or not d.area or not isinstance(step.summary, dict) or step.summary.get("skipped"):
        return []
    entries, _ = progress_entries(s, run.site_id, design_key(d))
    msgs = []
    for prev, cur in zip(entries, entries[1:]):
        try:
            inputs = design_changes.pair_inputs(s, prev, cur, d.area)
        except ValueError:   # a run without its files: design-progress shows the totals with the reason
            continue
        _, msg = design_changes.queue_job(s, run.site_id, inputs, design_changes.job_key(inputs))
        if msg:
            msgs.append(msg)
    return msgs
