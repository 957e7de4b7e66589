"""Results of a run, in the formats GIS systems and surveyors use: JSON, CSV, GeoJSON (RFC 7946: WGS84
longitude/latitude, ellipsoidal height as third coordinate), RTKLIB .pos, COG GeoTIFF, LAS/LAZ, PDF.

Rendered representations are cached in memory keyed by the SHA-256 of their source file (content
addressed: a cache entry can never be stale); the SHA is also the ETag."""

from __future__ import annotations

import csv
import io
import json
import re
import threading
from collections import OrderedDict
from dataclasses import dataclass
from functools import lru_cache

from sqlalchemy import select

from ..core.problems import Conflict, NotFound, Unprocessable
from ..models import Run, RunOutput, Site, Survey, VolumeMeasurement
from ..storage import blob_key
from . import result_files, steps_catalog
from .context import Ctx
from .display import iso_time
from .permissions import require_run, require_run_with_outputs, require_survey

def _declared(step: str, key: str) -> tuple[str, ...]:
    return (steps_catalog.BY_NAME[step].output(key).path,)


# the files each result endpoint serves: the outputs the steps declare (georef_core.steps.specs), by name
PATHS = {
    "trajectory": _declared("gnss", "trajectory"),
    "camera_positions": _declared("gnss", "camera_positions"),
    "gnss_summary": _declared("gnss", "summary"),
    "residuals_json": _declared("georef", "residuals_json"),
    "residuals_csv": _declared("georef", "residuals_csv"),
    "lever_arm": _declared("georef", "lever_arm"),
    "dsm": _declared("dense", "dsm"),
    "dense_summary": _declared("dense", "summary"),
    "ortho": _declared("dense", "ortho"),
    "point_cloud": _declared("dense", "point_cloud"),
    "report": _declared("report", "report"),
    "volumes": _declared("volumes", "volumes"),
}
MEDIA = {".json": "application/json", ".csv": "text/csv; charset=utf-8", ".pos": "text/plain; charset=utf-8",
         ".tif": "image/tiff; application=geotiff; profile=cloud-optimized", ".laz": "application/vnd.laszip",
         ".las": "application/vnd.las", ".pdf": "application/pdf", ".png": "image/png",
         ".parquet": "application/vnd.apache.parquet", ".txt": "text/plain; charset=utf-8",
         ".geojson": "application/geo+json",
         # the exports step's deliverables (georef_core/deliverables; .xml LandXML stays a plain download)
         ".dxf": "image/vnd.dxf", ".gpkg": "application/geopackage+sqlite3", ".zip": "application/zip",
         ".kmz": "application/vnd.google-earth.kmz", ".prj": "text/plain; charset=utf-8",
         ".xlsx": "application/vnd.openxmlformats-officedocument.spreadsheetml.sheet"}


def media_type(path: str) -> str:
    for ext, mt in MEDIA.items():
        if path.lower().endswith(ext):
            return mt
    return "application/octet-stream"


@dataclass
class Rendered:
    body: bytes
    media_type: str
    etag: str
    filename: str | None = None


class _Cache:
    def __init__(self, max_bytes: int = 256 * 1024**2):
        self.max_bytes = max_bytes
        self.size = 0
        self.items: OrderedDict[tuple, Rendered] = OrderedDict()
        self.lock = threading.Lock()

    def get(self, key):
        with self.lock:
            v = self.items.get(key)
            if v is not None:
                self.items.move_to_end(key)
            return v

    def put(self, key, value: Rendered):
        with self.lock:
            if key in self.items:
                return
            self.items[key] = value
            self.size += len(value.body)
            while self.size > self.max_bytes and self.items:
                _, old = self.items.popitem(last=False)
                self.size -= len(old.body)


_cache = _Cache()


def list_outputs(ctx: Ctx, run_id: str) -> list[RunOutput]:
    require_run(ctx, run_id, "viewer")
    return list(ctx.db.scalars(select(RunOutput).where(RunOutput.run_id == run_id).order_by(RunOutput.path)))


def _outputs_of(ctx: Ctx, run: Run, paths: tuple[str, ...]) -> dict[str, RunOutput]:
    return {o.path: o for o in ctx.db.scalars(select(RunOutput).where(RunOutput.run_id == run.id,
                                                                      RunOutput.path.in_(paths)))}


def _output(ctx: Ctx, run: Run, what: str, required: bool = True) -> RunOutput | None:
    return _pick_output(run, what, _outputs_of(ctx, run, PATHS[what]), required)


def _run_and_output(ctx: Ctx, run_id: str, what: str) -> tuple[Run, RunOutput]:
    """The run (the caller may read it) and its output `what`, in one query."""
    run, rows = require_run_with_outputs(ctx, run_id, PATHS[what], "viewer")
    return run, _pick_output(run, what, rows, True)


def _pick_output(run: Run, what: str, rows: dict[str, RunOutput], required: bool) -> RunOutput | None:
    for p in PATHS[what]:
        if p in rows:
            return rows[p]
    if required:
        if run.state in ("queued", "running"):
            raise Conflict(f"{what.replace('_', ' ')} not produced yet (run is {run.state})")
        raise NotFound(f"this run has no {what.replace('_', ' ')} (step not run, unavailable or failed)")
    return None


def output_by_path(ctx: Ctx, run_id: str, path: str) -> RunOutput:
    require_run(ctx, run_id, "viewer")
    o = ctx.db.scalar(select(RunOutput).where(RunOutput.run_id == run_id, RunOutput.path == path))
    if o is None:
        raise NotFound(f"no output {path!r} in this run")
    return o


def output_for(ctx: Ctx, run_id: str, what: str) -> RunOutput:
    return _run_and_output(ctx, run_id, what)[1]


def _text(ctx: Ctx, o: RunOutput) -> str:
    return ctx.storage.read_bytes(blob_key(o.sha256)).decode("utf-8", errors="replace")


@lru_cache(maxsize=64)
def _to_wgs84(crs: str):
    from pyproj import Transformer

    return Transformer.from_crs(crs, "EPSG:4326", always_xy=True)


# CSV cells a spreadsheet would run as a formula (=HYPERLINK(...), +cmd|..., -2+3, @SUM(...)), OWASP's list;
# numbers keep their sign (a negative residual is data, not a formula)
_FORMULA_START = ("=", "+", "-", "@", "\t", "\r", "\n")
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(nan|inf|infinity)$", re.I)


def csv_safe_cell(value):
    """A cell value that a spreadsheet shows as text: a leading ' before a formula-like string."""
    if isinstance(value, str) and value.startswith(_FORMULA_START) and not _NUMBER.match(value):
        return "'" + value
    return value


def _csv_field(value) -> str:
    text = "" if value is None else str(value)
    if any(c in text for c in ',"\r\n'):
        return '"' + text.replace('"', '""') + '"'
    return text


def _csv_lines(rows) -> bytes:
    """RFC 4180 fields (quoted when they hold a comma, a quote, CR or LF: the csv module leaves a bare CR
    unquoted with a LF line terminator), LF-terminated rows, formula-like cells neutralised."""
    out = []
    for r in rows:
        cells = [_csv_field(csv_safe_cell(c)) for c in r]
        out.append(",".join(cells) if cells != [""] else '""')
    return ("\n".join(out) + "\n").encode() if out else b""


def csv_safe_bytes(data: bytes) -> bytes:
    """A CSV file as stored, with formula-like cells neutralised (the file unchanged when it has none)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        text = data.decode("utf-8", errors="replace")
    rows = list(csv.reader(io.StringIO(text, newline="")))
    if not any(csv_safe_cell(c) is not c for r in rows for c in r):
        return data
    return _csv_lines(rows)


def _csv_bytes(rows: list[dict], columns: list[str] | None = None) -> bytes:
    cols = columns or (list(rows[0].keys()) if rows else [])
    return _csv_lines([cols] + [[r.get(k) for k in cols] for r in rows])


def _geojson_bytes(features: list[dict], extra: dict | None = None) -> bytes:
    fc = {"type": "FeatureCollection", "features": features}
    if extra:
        fc.update(extra)
    return json.dumps(fc, separators=(",", ":")).encode()


def _json_bytes(obj) -> bytes:
    return json.dumps(obj, separators=(",", ":"), default=str).encode()


def _check_format(fmt: str, allowed: tuple[str, ...]) -> None:
    if fmt not in allowed:
        raise Unprocessable(f"format: one of {', '.join(allowed)}")


def _cached(key: tuple, build) -> Rendered:
    hit = _cache.get(key)
    if hit is None:
        hit = build()
        _cache.put(key, hit)
    return hit


def _raw(ctx: Ctx, o: RunOutput, media: str, filename: str) -> Rendered:
    """An output file as stored, kept in the rendered cache (no file read per poll); CSV files with their
    formula-like cells neutralised (point and image names come from users)."""
    def build():
        data = ctx.storage.read_bytes(blob_key(o.sha256))
        if media.startswith("text/csv"):
            safe = csv_safe_bytes(data)
            if safe is not data:
                return Rendered(safe, media, f'"{o.sha256[:32]}-safe"', filename)
        return Rendered(data, media, f'"{o.sha256[:32]}"', filename)
    return _cached(("raw", o.sha256, media, filename), build)


raw_output = _raw


def trajectory(ctx: Ctx, run_id: str, fmt: str, every: int) -> Rendered:
    _check_format(fmt, ("json", "csv", "geojson", "pos"))
    every = max(1, min(int(every), 100000))
    run, o = _run_and_output(ctx, run_id, "trajectory")
    if fmt == "pos":
        return _raw(ctx, o, "text/plain; charset=utf-8", f"run{run.number}_trajectory.pos")

    def build():
        rows = result_files.parse_pos(_text(ctx, o))[::every]
        etag = f'"{o.sha256[:24]}-{fmt}-{every}"'
        if fmt == "json":
            return Rendered(_json_bytes({"run_id": run_id, "count": len(rows), "heights": "ellipsoidal (WGS84)",
                                         "epochs": rows}), "application/json", etag)
        if fmt == "csv":
            return Rendered(_csv_bytes(rows), "text/csv; charset=utf-8", etag, f"run{run.number}_trajectory.csv")
        feats = [{"type": "Feature", "geometry": {"type": "LineString",
                                                  "coordinates": [[r["lon_deg"], r["lat_deg"], r["height_m"]]
                                                                  for r in rows]},
                  "properties": {"kind": "trajectory", "epochs": len(rows)}}] if len(rows) >= 2 else []
        feats += [{"type": "Feature", "geometry": {"type": "Point", "coordinates": [r["lon_deg"], r["lat_deg"],
                                                                                    r["height_m"]]},
                   "properties": {k: v for k, v in r.items() if k not in ("lat_deg", "lon_deg", "height_m")}}
                  for r in rows]
        return Rendered(_geojson_bytes(feats), "application/geo+json", etag, f"run{run.number}_trajectory.geojson")
    return _cached(("traj", o.sha256, fmt, every), build)


def camera_positions(ctx: Ctx, run_id: str, fmt: str) -> Rendered:
    _check_format(fmt, ("json", "csv", "geojson"))
    run, o = _run_and_output(ctx, run_id, "camera_positions")
    if fmt == "csv":
        return _raw(ctx, o, "text/csv; charset=utf-8", f"run{run.number}_camera_positions.csv")

    def build():
        rows = result_files.parse_csv(_text(ctx, o))
        etag = f'"{o.sha256[:24]}-{fmt}"'
        if fmt == "json":
            return Rendered(_json_bytes({"run_id": run_id, "count": len(rows), "events": rows}), "application/json", etag)
        feats = [{"type": "Feature", "geometry": {"type": "Point", "coordinates": [r["lon_deg"], r["lat_deg"],
                                                                                   r.get("height_ellipsoid_m")]},
                  "properties": {k: v for k, v in r.items() if k not in ("lat_deg", "lon_deg")}}
                 for r in rows if r.get("lat_deg") is not None]
        return Rendered(_geojson_bytes(feats), "application/geo+json", etag)
    return _cached(("cam", o.sha256, fmt), build)


def _points_of_run(ctx: Ctx, run: Run) -> dict[str, dict]:
    sha = (run.inputs or {}).get("gcp/points.csv")
    if not sha:
        return {}
    from .file_kinds import parse_points_csv

    try:
        pts = parse_points_csv(ctx.storage.read_bytes(blob_key(sha)).decode("utf-8-sig", errors="replace"))
    except ValueError:
        return {}
    return {p["name"]: p for p in pts}


_RESIDUAL_PATHS = PATHS["residuals_json"] + PATHS["residuals_csv"]


def _residual_files(run: Run, rows: dict[str, RunOutput]) -> tuple[RunOutput | None, RunOutput | None]:
    """(JSON, CSV) residual tables of the run among its outputs `rows`; raises when it has neither."""
    oj = _pick_output(run, "residuals_json", rows, False)
    oc = _pick_output(run, "residuals_csv", rows, False)
    if oj is None and oc is None:
        _pick_output(run, "residuals_json", rows, True)   # raises the right problem
    return oj, oc


def _residuals_from(ctx: Ctx, oj: RunOutput | None, oc: RunOutput | None) -> dict:
    return result_files.normalise_residuals(_text(ctx, oj) if oj else None, _text(ctx, oc) if oc else None)


def residuals_data(ctx: Ctx, run: Run) -> dict:
    return _residuals_from(ctx, *_residual_files(run, _outputs_of(ctx, run, _RESIDUAL_PATHS)))


def residuals(ctx: Ctx, run_id: str, fmt: str) -> Rendered:
    _check_format(fmt, ("json", "csv", "geojson"))
    run, rows = require_run_with_outputs(ctx, run_id, _RESIDUAL_PATHS, "viewer")
    oj, oc = _residual_files(run, rows)
    src = (oj or oc).sha256
    if fmt == "csv" and oc is not None:
        return _raw(ctx, oc, "text/csv; charset=utf-8", f"run{run.number}_residuals.csv")

    def build():
        data = _residuals_from(ctx, oj, oc)
        etag = f'"{src[:24]}-{fmt}"'
        pts = [{k: v for k, v in p.items() if not isinstance(v, (dict, list))} for p in data["points"]]
        if fmt == "json":
            return Rendered(_json_bytes({"run_id": run_id, "units": "m", "points": pts, "stats": data["stats"],
                                         "source": data["raw"]}), "application/json", etag)
        if fmt == "csv":
            return Rendered(_csv_bytes(pts), "text/csv; charset=utf-8", etag, f"run{run.number}_residuals.csv")
        site = ctx.db.get(Site, run.site_id)
        known = _points_of_run(ctx, run)
        tr = _to_wgs84(site.crs)
        feats = []
        for p in pts:
            k = known.get(p.get("name"))
            if k is None:
                continue
            lon, lat = tr.transform(k["easting_m"], k["northing_m"])
            feats.append({"type": "Feature", "geometry": {"type": "Point",
                                                          "coordinates": [lon, lat, k["ellipsoidal_height_m"]]},
                          "properties": {**p, "role": p.get("role") or k["role"]}})
        return Rendered(_geojson_bytes(feats), "application/geo+json", etag)
    return _cached(("res", src, fmt, run.site_id), build)


def lever_arm(ctx: Ctx, run_id: str) -> Rendered:
    run, o = _run_and_output(ctx, run_id, "lever_arm")
    return Rendered(ctx.storage.read_bytes(blob_key(o.sha256)), "application/json", f'"{o.sha256[:32]}"')


def volumes_rows(db, run_id: str) -> list[VolumeMeasurement]:
    return list(db.scalars(select(VolumeMeasurement).where(VolumeMeasurement.run_id == run_id)
                           .order_by(VolumeMeasurement.stockpile_name)))


def volumes(ctx: Ctx, run_id: str, fmt: str) -> Rendered:
    _check_format(fmt, ("json", "csv", "geojson"))
    run = require_run(ctx, run_id, "viewer")
    rows = volumes_rows(ctx.db, run_id)
    if not rows:
        _output(ctx, run, "volumes")   # raises: not produced
    data = [{"stockpile_id": r.stockpile_id, "name": r.stockpile_name, "base": r.base, "volume_m3": r.volume_m3,
             "sigma_m3": (r.details or {}).get("sigma_m3"), "ci95_m3": (r.details or {}).get("ci95_m3"),
             "cut_m3": r.cut_m3, "fill_m3": r.fill_m3, "area_m2": r.area_m2,
             "base_elevation_m": (r.details or {}).get("base_elevation_m"),
             "measured_at": iso_time(r.measured_at)} for r in rows]
    body_key = json.dumps(data, sort_keys=True, default=str).encode()
    import hashlib

    etag = f'"{hashlib.sha256(body_key).hexdigest()[:24]}-{fmt}"'
    if fmt == "json":
        return Rendered(_json_bytes({"run_id": run_id, "units": {"volume": "m3", "area": "m2"},
                                     "conventions": "volume_m3 = cut_m3 - fill_m3 (material above the base minus "
                                                    "voids below it); sigma_m3: 1-sigma uncertainty",
                                     "stockpiles": data}),
                        "application/json", etag)
    if fmt == "csv":
        return Rendered(_csv_bytes(data), "text/csv; charset=utf-8", etag, f"run{run.number}_volumes.csv")
    from .stockpiles import site_stockpiles

    site = ctx.db.get(Site, run.site_id)
    tr = _to_wgs84(site.crs)
    outlines = {sp.id: sp.outline for sp in site_stockpiles(ctx.db, run.site_id)}
    feats = []
    for d in data:
        ol = outlines.get(d["stockpile_id"])
        geom = None
        if ol:
            rings = []
            for ring in ol["coordinates"]:
                xs, ys = tr.transform([c[0] for c in ring], [c[1] for c in ring])
                rings.append([[x, y] for x, y in zip(xs, ys)])
            geom = {"type": "Polygon", "coordinates": rings}
        feats.append({"type": "Feature", "geometry": geom, "properties": d})
    return Rendered(_geojson_bytes(feats), "application/geo+json", etag)


def latest_report_output(ctx: Ctx, survey_id: str) -> tuple[Run, RunOutput]:
    require_survey(ctx, survey_id, "viewer")
    row = ctx.db.execute(select(Run, RunOutput).join(RunOutput, RunOutput.run_id == Run.id)
                         .where(Run.survey_id == survey_id, RunOutput.path == PATHS["report"][0])
                         .order_by(Run.number.desc()).limit(1)).first()
    if row is None:
        raise NotFound("no accuracy report yet: process the survey (the report step writes it)")
    return row[0], row[1]


def survey_of(ctx: Ctx, run: Run) -> Survey:
    return ctx.db.get(Survey, run.survey_id)


def check_rmse(stats: dict) -> dict | None:
    """Horizontal, vertical and 3D RMSE of a residual table, from the core's statistics (one definition)."""
    if not stats or not stats.get("n"):
        return None
    return {"horizontal": stats["horizontal"]["rmse_m"], "vertical": stats["dz"]["rmse_m"],
            "3d": stats["3d"]["rmse_m"], "n": stats["n"]}


def site_summary(ctx: Ctx, site_id: str) -> dict:
    """One request for the site overview: surveys, latest survey and run, check-point RMSE of the
    latest run that has residuals, and the net volume of the stockpiles in the latest run with volumes.
    Two queries (the site with the caller's role, then everything else as subqueries of one row), plus
    the residual and volume rows where such runs exist."""
    from sqlalchemy import func, true

    from .permissions import require_site

    site = require_site(ctx, site_id, "viewer")
    n_surveys = select(func.count()).select_from(Survey).where(Survey.site_id == site_id).scalar_subquery()
    res_run_id = (select(Run.id).join(RunOutput, RunOutput.run_id == Run.id)
                  .where(Run.site_id == site_id, Run.state == "succeeded",
                         RunOutput.path.in_(_RESIDUAL_PATHS))
                  .order_by(Run.finished_at.desc()).limit(1).scalar_subquery())
    vol_run_id = (select(Run.id).join(VolumeMeasurement, VolumeMeasurement.run_id == Run.id)
                  .where(Run.site_id == site_id, Run.state == "succeeded")
                  .order_by(Run.finished_at.desc()).limit(1).scalar_subquery())
    ls = (select(Survey.id, Survey.name, Survey.flown_at).where(Survey.site_id == site_id)
          .order_by(Survey.flown_at.desc().nulls_last(), Survey.created_at.desc()).limit(1).subquery())
    lr = (select(Run.id, Run.survey_id, Run.number, Run.state, Run.finished_at).where(Run.site_id == site_id)
          .order_by(Run.created_at.desc()).limit(1).subquery())
    row = ctx.db.execute(select(n_surveys, res_run_id, vol_run_id, ls.c.id, ls.c.name, ls.c.flown_at, lr.c.id,
                                lr.c.survey_id, lr.c.number, lr.c.state, lr.c.finished_at)
                         .select_from(Site).outerjoin(ls, true()).outerjoin(lr, true())
                         .where(Site.id == site_id)).one()
    n, res_id, vol_id = row[0], row[1], row[2]
    rmse = None
    if res_id is not None:
        rmse = check_rmse(residuals_data(ctx, ctx.db.get(Run, res_id))["stats"])
    net = None
    if vol_id is not None:
        vols = [v.volume_m3 for v in volumes_rows(ctx.db, vol_id) if v.volume_m3 is not None]
        net = sum(vols) if vols else None
    return {"site_id": site.id, "surveys": int(n or 0),
            "latest_survey": None if row[3] is None else {"id": row[3], "name": row[4], "flown_at": row[5]},
            "latest_run": None if row[6] is None else {
                "id": row[6], "survey_id": row[7], "number": row[8], "state": row[9], "finished_at": row[10]},
            "check_rmse_m": rmse, "check_rmse_run_id": res_id,
            "stockpiles_net_m3": net, "volumes_run_id": vol_id,
            "tolerance_horizontal_m": site.tolerance_horizontal_m, "tolerance_vertical_m": site.tolerance_vertical_m}


def adhoc_volume(ctx: Ctx, run_id: str, outline: dict, base: str) -> dict:
    """Volume of an outline on the run's DSM without saving a stockpile (synchronous: one polygon on one
    DSM takes well under a second). Same computation as the volumes step (georef_core)."""
    import json
    import tempfile
    from pathlib import Path

    from .stockpiles import validate_base, validate_outline

    outline, base = validate_outline(outline), validate_base(base)     # bounded (vertices), before any query
    run, rows = require_run_with_outputs(ctx, run_id, PATHS["dsm"] + PATHS["dense_summary"], "viewer")
    o = _pick_output(run, "dsm", rows, True)
    summary = _pick_output(run, "dense_summary", rows, False)
    site_crs = ctx.db.get(Site, run.site_id).crs
    # everything needed is read: end the transaction before the computation (nothing was written; on
    # SQLite an open write transaction would block every other writer while the volume is computed)
    ctx.db.commit()
    try:
        from georef_core.errors import GeorefError
        from georef_core.steps.volumes import run_volumes
    except ModuleNotFoundError:
        raise NotFound("volume computation is not installed on this server") from None
    tmp_root = ctx.settings.resolved_work_dir() / "tmp"
    tmp_root.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=tmp_root) as tmp:
        # the DSM with the dense step's summary beside it, as the volumes step sees it (its noise model and
        # smoothing radius decide the uncertainty and where the outline base is sampled)
        dsm = Path(tmp) / "dsm.tif"
        local = ctx.storage.local_path(blob_key(o.sha256))
        if local is not None:
            dsm.symlink_to(local)
        else:
            ctx.storage.fetch(blob_key(o.sha256), dsm)
        if summary is not None:
            ctx.storage.fetch(blob_key(summary.sha256), Path(tmp) / "dense_summary.json")
        poly = Path(tmp) / "outline.geojson"
        poly.write_text(json.dumps({"type": "FeatureCollection",
                                    "crs": {"type": "name", "properties": {"name": site_crs}},
                                    "features": [{"type": "Feature", "properties": {"name": "outline"},
                                                  "geometry": outline}]}))
        try:
            doc = run_volumes(dsm, poly, None, base=base)
        except GeorefError as exc:
            raise Unprocessable(str(exc).replace(str(tmp) + "/", "")) from None
    r = dict(doc["results"][0])
    r.pop("dsm", None)
    if isinstance(r.get("polygon"), dict):
        r["polygon"] = {k: v for k, v in r["polygon"].items() if k != "source"}
    r["volume_m3"] = r.get("net_m3")
    return {"run_id": run_id, "base": base, "crs": site_crs, **r}
