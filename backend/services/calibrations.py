"""A site's calibration (localisation: horizontal similarity + inclined-plane vertical adjustment, the JSON
document of georef_core.datums.site_calibration): set from a calibration document or a CSV of control pairs
(solved here in the site CRS and the site's height datum), checked at once by the core's reader; the datum step
of every run of the site applies it unless the survey or the run gives its own (jobs.run_context -> worker
pipeline context "site_calibration" -> georef_core.steps.datum). docs/datums.md."""

from __future__ import annotations

import csv
import tempfile
from pathlib import Path

from ..core.problems import NotFound, Unprocessable
from ..models import Site, SiteCalibration
from .context import Ctx
from .permissions import require_site
from .sites import check_if_match


def _cal(doc: dict, where: str):
    from georef_core.datums.site_calibration import calibration_from_dict
    from georef_core.errors import InputFileError

    try:
        return calibration_from_dict(doc, where)
    except InputFileError as exc:
        raise Unprocessable(f"{where}: {exc.problem}", slug="bad-calibration") from None


def calibration_out(c: SiteCalibration) -> dict:
    cal = _cal(c.document, "stored calibration")
    return {"site_id": c.site_id, "name": cal.name, "source_name": c.source_name, "crs": cal.crs,
            "height_datum": cal.height_datum, "summary": cal.summary(), "document": c.document, "set_by": c.set_by,
            "created_at": c.created_at, "updated_at": c.updated_at, "version": c.version}


def _check_matches_site(cal, site: Site, where: str) -> None:
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    from georef_core.datums.vertical_datum import resolve

    try:
        same = CRS.from_user_input(cal.crs).equals(CRS.from_user_input(site.crs), ignore_axis_order=True)
    except CRSError:
        same = False
    if not same:
        raise Unprocessable(f"{where}: the calibration is in {cal.crs or 'no CRS'}, the site in {site.crs}: calibrate "
                            "in the site CRS (georef datum calibrate --crs)", slug="bad-calibration")
    try:
        cal_datum, site_datum = resolve(cal.height_datum), resolve(site.vertical_datum)
    except ValueError as exc:
        raise Unprocessable(f"{where}: height datum: {exc}", slug="bad-calibration") from None
    if cal_datum.code != site_datum.code:
        raise Unprocessable(f"{where}: the calibration's heights are {cal_datum.label}, the site's are "
                            f"{site_datum.label}: calibrate on the site's datum (georef datum calibrate "
                            "--height-datum)", slug="bad-calibration")


def _from_pairs(ctx: Ctx, site: Site, text: str, name: str, where: str):
    from georef_core.datums.site_calibration import read_control_pairs, solve_calibration
    from georef_core.datums.vertical_datum import resolve
    from georef_core.errors import InputFileError, ProcessingError

    work = ctx.settings.resolved_work_dir() / "tmp"
    work.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=work) as tmp:
        path = Path(tmp) / "pairs.csv"
        path.write_bytes(text.encode("utf-8", errors="replace"))
        try:
            pairs = read_control_pairs(path)
            return solve_calibration(pairs, crs=site.crs, height_datum=resolve(site.vertical_datum).code, name=name)
        except InputFileError as exc:
            line = f" (line {exc.line})" if getattr(exc, "line", None) else ""
            raise Unprocessable(f"{where}: {exc.problem}{line}", slug="bad-calibration") from None
        except (ProcessingError, csv.Error, ValueError, ArithmeticError) as exc:   # LinAlgError is a ValueError
            raise Unprocessable(f"{where}: {exc}", slug="bad-calibration") from None


def _check_finite(cal, where: str) -> None:
    import math

    vals = [cal.a, cal.b, cal.c0_m, cal.slope_north, cal.slope_east, *cal.origin_source_m, *cal.origin_local_m,
            *cal.vertical_origin_m]
    for p in cal.pairs:
        vals += [*p.source_m, *p.local_m]
    if not all(math.isfinite(v) for v in vals):
        raise Unprocessable(f"{where}: the calibration holds a value that is not a finite number", slug="bad-calibration")


def set_site_calibration(ctx: Ctx, site_id: str, body: dict, if_match: str | None = None) -> SiteCalibration:
    """The site's calibration from ``body`` ({document} or {pairs_csv}, optional name and source_name); admin,
    as the site's CRS and datum. Replaces the one before (runs already made keep theirs)."""
    site = require_site(ctx, site_id, "admin")
    c = ctx.db.get(SiteCalibration, site_id)
    if c is not None:
        check_if_match(c, if_match)
    doc, csv_text = body.get("document"), body.get("pairs_csv")
    if (doc is None) == (csv_text is None):
        raise Unprocessable("give either document (a calibration JSON document) or pairs_csv (a CSV of control pairs)")
    source = (body.get("source_name") or "").strip()[:255]
    where = source or ("document" if doc is not None else "pairs_csv")
    if doc is not None:
        cal = _cal(doc, where)
        if body.get("name"):
            cal.name = body["name"]
    else:
        cal = _from_pairs(ctx, site, csv_text, body.get("name") or Path(source).stem or "site calibration", where)
    _check_finite(cal, where)
    _check_matches_site(cal, site, where)
    if c is None:
        c = SiteCalibration(site_id=site_id, version=0)
        ctx.db.add(c)
    c.document, c.source_name, c.set_by = cal.to_dict(), source, ctx.user.id
    c.version = (c.version or 0) + 1
    ctx.db.flush()
    return c


def get_site_calibration(ctx: Ctx, site_id: str) -> SiteCalibration:
    require_site(ctx, site_id, "viewer")
    c = ctx.db.get(SiteCalibration, site_id)
    if c is None:
        raise NotFound("this site has no calibration: set one (PUT /api/v1/sites/{id}/calibration)",
                       slug="no-calibration")
    return c


def delete_site_calibration(ctx: Ctx, site_id: str, if_match: str | None = None) -> None:
    require_site(ctx, site_id, "admin")
    c = ctx.db.get(SiteCalibration, site_id)
    if c is None:
        raise NotFound("this site has no calibration", slug="no-calibration")
    check_if_match(c, if_match)
    ctx.db.delete(c)
    ctx.db.flush()


def calibration_context(s, site_id: str) -> dict | None:
    """What a run's datum step needs (jobs.run_context site "calibration"): the document and where it is from."""
    c = s.get(SiteCalibration, site_id)
    if c is None:
        return None
    return {"document": c.document, "version": c.version, "source_name": c.source_name,
            "updated_at": c.updated_at.isoformat() if c.updated_at else None}
