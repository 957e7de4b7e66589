"""The deliverables of a run folder (`georef export OUT_DIR`, the "exports" step) and the contours of one
surface (`georef contours`).

A run folder holds what the steps wrote: ``dense/dsm.tif`` and ``dense/ortho.tif`` (dense step),
``dtm/dtm.tif`` (DTM step), ``volumes/volumes.json`` with the stockpile outlines ``volumes/stockpiles_*.geojson``
(volumes step), ``residuals.json`` (georef step: check-point residuals). The surveyed points come from the
survey's ``gcp/points.csv`` (a survey folder given beside the run). ``export_run`` writes each requested
format from what exists and lists what it skipped and why; ``exports/exports.json`` is that manifest.

Formats and files (under ``exports/``):

=========  ==============================================================================================
geojson    contours.geojson, stockpiles.geojson, points.geojson (RFC 7946 WGS 84, or the site CRS)
dxf        site.dxf + site.prj: CONTOUR_MINOR, CONTOUR_INDEX, CONTOUR_LABEL, STOCKPILE_OUTLINE,
           CONTROL_POINTS / CHECK_POINTS (+ POINT_LABELS)
gpkg       site.gpkg: layers contours, stockpiles, points
shp        shapefiles/{contours,stockpiles,points}.shp (+ .shx .dbf .prj .cpg) and shapefiles.zip
landxml    surface.xml: the surveyed TIN (LandXML 1.2)
kmz        ortho.kmz: the orthophoto as a Google Earth overlay (a tiled super-overlay when large)
xlsx       site.xlsx: About, Points, Volumes
csv        points.csv, volumes.csv
=========  ==============================================================================================
"""

from __future__ import annotations

import json
import math
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputFileError, ProcessingError
from .contours import ContourSet, format_level, label_positions, trace_contours
from .surface import Surface, read_surface

FORMATS = ("geojson", "dxf", "gpkg", "shp", "landxml", "kmz", "xlsx", "csv")
CONTOUR_SUFFIXES = {".geojson": "geojson", ".json": "geojson", ".gpkg": "gpkg", ".dxf": "dxf", ".shp": "shp"}


# ------------------------------------------------------------------------------------------------ contours
def contour_layer(cs: ContourSet):
    """The contours as a vector layer: LineString Z at their level; fields elevation_m, index (bool),
    vertical_datum (Shapefile: elev_m, index, vdatum)."""
    import shapely

    from .vector_writer import VectorLayer

    geoms = [shapely.LineString(np.column_stack([c.xy_m, np.full(len(c.xy_m), c.level_m)])) for c in cs.lines]
    return VectorLayer("contours", "LineString Z", geoms,
                       {"elevation_m": [c.level_m for c in cs.lines], "index": [bool(c.index) for c in cs.lines],
                        "vertical_datum": [cs.surface.vertical_datum] * len(cs.lines)},
                       shp_names={"elevation_m": "elev_m", "index": "index", "vertical_datum": "vdatum"})


def label_height_m(surface: Surface) -> float:
    """Text height of labels: 1/150 of the surface's larger extent, between 0.2 and 5 m."""
    ext = max(surface.z_m.shape) * surface.cell_m
    return float(np.clip(ext / 150.0, 0.2, 5.0))


def contour_dxf_entities(cs: ContourSet, text_height_m: float | None = None):
    """(polylines, texts) of the contours for dxf_writer.write_dxf: minor and index contours as LWPOLYLINEs at
    their elevation on CONTOUR_MINOR / CONTOUR_INDEX, index contours labelled with their level on
    CONTOUR_LABEL (a TEXT along the line every 40 text heights of line, at least one per line 8 text
    heights long)."""
    from .dxf_writer import DxfPolyline, DxfText

    h = text_height_m or label_height_m(cs.surface)
    polys, texts = [], []
    for c in cs.lines:
        polys.append(DxfPolyline("CONTOUR_INDEX" if c.index else "CONTOUR_MINOR", c.xy_m, c.closed, c.level_m))
        if c.index:
            for x, y, rot in label_positions(c, 40.0 * h, 8.0 * h):
                texts.append(DxfText("CONTOUR_LABEL", format_level(c.level_m, cs.interval_m), (x, y, c.level_m), h, rot))
    return polys, texts


def write_contours(cs: ContourSet, out_path, geojson_crs: str = "wgs84") -> list[Path]:
    """Writes the contours in the format of ``out_path``'s extension (.geojson/.json, .gpkg, .dxf, .shp)."""
    from .dxf_writer import write_dxf
    from .vector_writer import write_geojson, write_gpkg, write_shapefiles

    out = Path(out_path)
    kind = CONTOUR_SUFFIXES.get(out.suffix.lower())
    if kind is None:
        raise InputFileError(out, f"unknown contour format {out.suffix or '(no extension)'}: use .geojson, .gpkg, "
                                  ".dxf or .shp")
    if not cs.lines:
        raise ProcessingError(f"{cs.surface.path}: no contour at a {cs.interval_m:g} m interval (the surface's "
                              "relief is smaller than the interval)")
    s = cs.surface
    meta = {"interval_m": cs.interval_m, "index_interval_m": round(cs.index_interval_m, 6),
            "vertical_datum": s.vertical_datum, "source": s.path.name, "smoothing_sigma_m": round(cs.smoothing_m, 4)}
    layer = contour_layer(cs)
    if kind == "geojson":
        return [write_geojson(out, layer, s.crs, s.vertical_datum, geojson_crs, extra=meta)]
    if kind == "gpkg":
        return [write_gpkg(out, [layer], s.crs_3d, metadata=meta)]
    if kind == "shp":
        layer.name = out.stem
        return write_shapefiles(out.parent, [layer], s.crs_3d)
    polys, texts = contour_dxf_entities(cs)
    return write_dxf(out, polys, (), texts, crs=s.crs, vertical_datum=s.vertical_datum)


def run_contours(surface_path, out_path, interval_m: float | None = None, index_every: int = 5,
                 smoothing_m: float | None = None, geojson_crs: str = "wgs84", what: str = "surface") -> dict:
    """`georef contours`: contours of a surface GeoTIFF written to ``out_path``; returns their summary."""
    surface = read_surface(surface_path, what)
    cs = trace_contours(surface, interval_m, index_every, smoothing_m)
    files = write_contours(cs, out_path, geojson_crs)
    return {**cs.summary(), "files": [str(f) for f in files]}


# ------------------------------------------------------------------------------------------------- run data
@dataclass
class RunData:
    """What a run folder holds that the exports use (None / empty where absent)."""

    surface: Surface | None
    surface_name: str
    ortho: Path | None
    volumes: list[dict]
    outlines: list           # (name, shapely polygon in the surface CRS)
    points: list[dict]
    notes: dict              # what is missing and why


def _volume_rows(doc: dict) -> list[dict]:
    rows = []
    for r in doc.get("stockpiles") or []:          # the volumes step's shape (steps/volumes.stockpile_record)
        d = r.get("details") or {}
        rows.append({"name": r.get("stockpile_name"), "base": r.get("base"), "volume_m3": r.get("volume_m3"),
                     "cut_m3": r.get("cut_m3"), "fill_m3": r.get("fill_m3"), "area_m2": r.get("area_m2"),
                     "sigma_m3": d.get("sigma_m3"), "ci95_m3": d.get("ci95_m3"),
                     "base_elevation_m": d.get("base_elevation_m")})
    for r in doc.get("results") or []:            # `georef volume --out` (steps/volumes.run_volumes)
        u = r.get("uncertainty") or {}
        rows.append({"name": r.get("name"), "base": doc.get("base"), "volume_m3": r.get("net_m3"),
                     "cut_m3": r.get("cut_m3"), "fill_m3": r.get("fill_m3"), "area_m2": r.get("area_m2"),
                     "sigma_m3": u.get("sigma_m3"), "ci95_m3": u.get("ci95_m3"),
                     "base_elevation_m": (r.get("base") or {}).get("elevation_m")})
    return rows


def _read_points(survey_dir: Path | None, run_dir: Path, crs) -> tuple[list[dict], str | None]:
    """Surveyed control / check points (survey gcp/points.csv, in ``crs``) with the check-point residuals of
    the run's residuals.json joined by name; (rows, why none)."""
    from pyproj import CRS, Transformer

    from ..adjustment.control_points import parse_points_table

    if survey_dir is None:
        return [], "no survey folder given (its gcp/points.csv holds the surveyed points)"
    pts_csv = Path(survey_dir) / "gcp" / "points.csv"
    if not pts_csv.is_file():
        return [], f"no {pts_csv}"
    try:
        text = pts_csv.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(pts_csv, f"cannot read the point file ({exc})") from None
    rows = parse_points_table(text, "check", pts_csv)
    src = None
    sj = Path(survey_dir) / "survey.json"
    if sj.is_file():
        try:
            src = json.loads(sj.read_text()).get("points_crs")
        except (json.JSONDecodeError, AttributeError):
            src = None
    gl = Path(survey_dir) / "gcp" / "gcp_list.txt"
    if src is None and gl.is_file():
        first = gl.read_text(errors="replace").splitlines()[:1]
        src = first[0].strip() if first and first[0].strip() else None
    xyz = np.array([[r["easting_m"], r["northing_m"], r["ellipsoidal_height_m"]] for r in rows], float)
    if src is not None and crs is not None:
        try:
            s = CRS.from_user_input(src)
        except Exception:
            s = None
        horiz = crs.sub_crs_list[0] if crs.is_compound else crs
        if s is not None and not s.equals(horiz, ignore_axis_order=True):
            tr = Transformer.from_crs(s, horiz, always_xy=True)
            xyz[:, 0], xyz[:, 1] = tr.transform(xyz[:, 0], xyz[:, 1])
    res = {}
    rj = run_dir / "residuals.json"
    if rj.is_file():
        try:
            res = {p["name"]: p for p in json.loads(rj.read_text()).get("points", []) if isinstance(p, dict)}
        except (json.JSONDecodeError, AttributeError, KeyError):
            raise InputFileError(rj, "not a residual table (JSON with 'points')") from None
    out = []
    for r, (e, n, h) in zip(rows, xyz):
        d = res.get(r["name"], {})
        out.append({"name": r["name"], "role": r["role"], "easting_m": round(float(e), 4),
                    "northing_m": round(float(n), 4), "height_m": round(float(h), 4),
                    **{k: d.get(k) for k in ("dx_m", "dy_m", "dz_m", "d3_m")}})
    return out, None


def read_run(run_dir, surface: str = "dsm", survey_dir=None, heights: str = "site") -> RunData:
    """Collects what the exports use from a run folder (see the module's description). ``heights="site"``:
    the DSM in the site's vertical datum (``datum/dsm_orthometric.tif``, the datum step's) where there is
    one; "ellipsoidal": the dense step's DSM as it is."""
    from ..volumes.polygons import read_polygons

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise InputFileError(run_dir, "not a folder (a run folder: what `georef georef`/`georef dense` wrote)")
    notes: dict[str, str] = {}
    dsm, dtm = run_dir / "dense" / "dsm.tif", run_dir / "dtm" / "dtm.tif"
    if surface not in ("dsm", "dtm"):
        raise ProcessingError(f"surface {surface!r}: dsm or dtm")
    if heights not in ("site", "ellipsoidal"):
        raise ProcessingError(f"heights {heights!r}: site or ellipsoidal")
    site_dsm = run_dir / "datum" / "dsm_orthometric.tif"
    if heights == "site" and site_dsm.is_file():
        dsm = site_dsm
    path, name = (dtm, "DTM") if surface == "dtm" and dtm.is_file() else (dsm, "DSM")
    if surface == "dtm" and not dtm.is_file():
        notes["dtm"] = f"no {dtm}: contours and TIN from the DSM instead"
    surf = read_surface(path, name) if path.is_file() else None
    if surf is None:
        notes["surface"] = f"no {path}"
    ortho = run_dir / "dense" / "ortho.tif"
    if not ortho.is_file():
        notes["ortho"] = f"no {ortho}"
        ortho = None
    volumes: list[dict] = []
    vj = run_dir / "volumes" / "volumes.json"
    if vj.is_file():
        try:
            volumes = _volume_rows(json.loads(vj.read_text()))
        except (json.JSONDecodeError, AttributeError, TypeError) as exc:
            raise InputFileError(vj, f"not a volumes file ({exc})") from None
    else:
        notes["volumes"] = f"no {vj}"
    outlines = []
    for f in sorted((run_dir / "volumes").glob("stockpiles_*.geojson")):
        for p in read_polygons(f):
            if surf is not None:
                p = p.to_crs(surf.crs)
            outlines.append((p.name, p.geometry))
    if not outlines:
        notes["outlines"] = f"no stockpile outlines ({run_dir / 'volumes'}/stockpiles_*.geojson)"
    points, why = _read_points(Path(survey_dir) if survey_dir else None, run_dir, surf.crs if surf else None)
    if why:
        notes["points"] = why
    return RunData(surf, name, ortho, volumes, outlines, points, notes)


# -------------------------------------------------------------------------------------------------- exports
def _draped(geom, surface: Surface | None):
    """A 2-D polygon's exterior ring with heights from the surface at its vertices (the ring's median where
    a vertex falls on no-data; 0 without a surface): (n, 3)."""
    ring = np.asarray(geom.exterior.coords)[:, :2] if hasattr(geom, "exterior") else \
        np.asarray(max(geom.geoms, key=lambda g: g.area).exterior.coords)[:, :2]
    z = surface.height_at(ring[:, 0], ring[:, 1]) if surface is not None else np.zeros(len(ring))
    fill = float(np.nanmedian(z)) if np.isfinite(z).any() else 0.0
    return np.column_stack([ring, np.where(np.isfinite(z), z, fill)])


def _layers(data: RunData, cs: ContourSet | None):
    import shapely

    from .vector_writer import VectorLayer

    layers = []
    if cs is not None and cs.lines:
        layers.append(contour_layer(cs))
    vd = data.surface.vertical_datum if data.surface else "ellipsoidal height (WGS 84)"
    if data.outlines:
        by_name = {v["name"]: v for v in data.volumes}
        rings = [_draped(g, data.surface) for _, g in data.outlines]
        names = [n for n, _ in data.outlines]
        f = {"name": names}
        for k in ("volume_m3", "cut_m3", "fill_m3", "area_m2", "sigma_m3"):
            f[k] = [float("nan") if by_name.get(n, {}).get(k) is None else float(by_name[n][k]) for n in names]
        f["vertical_datum"] = [vd] * len(names)
        layers.append(VectorLayer("stockpiles", "Polygon Z", [shapely.Polygon(r) for r in rings], f,
                                  shp_names={"volume_m3": "volume_m3", "cut_m3": "cut_m3", "fill_m3": "fill_m3",
                                             "area_m2": "area_m2", "sigma_m3": "sigma_m3",
                                             "vertical_datum": "vdatum"}))
    if data.points:
        p = data.points
        f = {"name": [r["name"] for r in p], "role": [r["role"] for r in p]}
        for k in ("dx_m", "dy_m", "dz_m"):
            f[k] = [float("nan") if r.get(k) is None else float(r[k]) for r in p]
        f["vertical_datum"] = [vd] * len(p)
        layers.append(VectorLayer("points", "Point Z", [shapely.Point(r["easting_m"], r["northing_m"], r["height_m"])
                                                        for r in p], f, shp_names={"vertical_datum": "vdatum"}))
    return layers


POINT_COLUMNS = ["name", "role", "easting_m", "northing_m", "height_m", "dx_m", "dy_m", "dz_m", "d3_m"]
VOLUME_COLUMNS = ["name", "base", "volume_m3", "cut_m3", "fill_m3", "area_m2", "sigma_m3", "ci95_m3",
                  "base_elevation_m"]


def export_run(run_dir, out_dir=None, formats=None, interval_m: float | None = None, surface: str = "dsm",
               survey_dir=None, index_every: int = 5, smoothing_m: float | None = None,
               tin_spacing_m: float | None = None, geojson_crs: str = "wgs84", kmz_max_px: int = 4096,
               heights: str = "site", progress=None, kmz_tile_threshold_px: int = 2048,
               kmz_max_tiles: int | None = 4096) -> dict:
    """Writes the requested ``formats`` (default all of FORMATS) of a run folder to ``out_dir`` (default
    ``run_dir/exports``) and ``exports.json``; returns that manifest: {"written": {format: [files]},
    "skipped": {format or item: why}, "contours": summary, "tin": summary, "crs", "vertical_datum"}."""
    from .dxf_writer import DxfPoint, DxfPolyline, write_dxf
    from .kmz_writer import write_kmz
    from .landxml_writer import tin_from_surface, write_landxml
    from .tables_writer import Table, write_csv, write_xlsx
    from .vector_writer import write_geojson, write_gpkg, write_shapefiles

    formats = list(FORMATS) if not formats else [f.lower() for f in formats]
    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise ProcessingError(f"unknown export format(s) {', '.join(bad)}; formats are {', '.join(FORMATS)}")
    run_dir = Path(run_dir)
    out = Path(out_dir) if out_dir else run_dir / "exports"
    data = read_run(run_dir, surface, survey_dir, heights)
    out.mkdir(parents=True, exist_ok=True)
    written: dict[str, list[str]] = {}
    skipped: dict[str, str] = dict(data.notes)
    s = data.surface
    cs = None
    # no server paths in what a client downloads: the run folder by name, the surface relative to it
    manifest: dict = {"run_dir": run_dir.name, "surface": data.surface_name if s else None,
                      "surface_file": _relative_name(s.path, run_dir) if s else None}
    if s is not None and any(f in formats for f in ("geojson", "dxf", "gpkg", "shp")):
        cs = trace_contours(s, interval_m, index_every, smoothing_m)
        manifest["contours"] = cs.summary()
        if not cs.lines:
            skipped["contours"] = f"no contour at a {cs.interval_m:g} m interval"
    layers = _layers(data, cs)
    vd = s.vertical_datum if s else None
    crs, crs3 = (s.crs, s.crs_3d) if s else (None, None)
    steps = len(formats)

    def done(fmt, files):
        written[fmt] = [str(Path(f).relative_to(out)) for f in files]

    for n, fmt in enumerate(formats):
        if progress:
            progress(f"exports: {fmt}", n, steps)
        if fmt in ("geojson", "dxf", "gpkg", "shp") and crs is None:
            skipped[fmt] = "no surface (dense/dsm.tif): its CRS places every vector product"
            continue
        if fmt in ("geojson", "gpkg", "shp") and not layers:
            skipped[fmt] = "nothing to write (no contour, outline or point)"
            continue
        if fmt == "geojson":
            done(fmt, [write_geojson(out / f"{lay.name}.geojson", lay, crs, vd, geojson_crs) for lay in layers])
        elif fmt == "gpkg":
            done(fmt, [write_gpkg(out / "site.gpkg", layers, crs3, {"vertical_datum": vd})])
        elif fmt == "shp":
            files = write_shapefiles(out / "shapefiles", layers, crs3)
            zpath = out / "shapefiles.zip"
            with zipfile.ZipFile(zpath, "w", zipfile.ZIP_DEFLATED) as z:
                for shp in files:
                    for part in sorted(shp.parent.glob(shp.stem + ".*")):
                        z.write(part, part.name)
            done(fmt, [*files, zpath])
        elif fmt == "dxf":
            polys, texts = contour_dxf_entities(cs) if cs is not None else ([], [])
            polys += [DxfPolyline("STOCKPILE_OUTLINE", _draped(g, s), True) for _, g in data.outlines]
            pts = [DxfPoint("CHECK_POINTS" if p["role"] == "check" else "CONTROL_POINTS",
                            (p["easting_m"], p["northing_m"], p["height_m"]), p["name"]) for p in data.points]
            if not (polys or pts):
                skipped[fmt] = "nothing to draw (no contour, outline or point)"
                continue
            done(fmt, write_dxf(out / "site.dxf", polys, pts, texts, crs=crs, vertical_datum=vd,
                                point_size_m=label_height_m(s)))
        elif fmt == "landxml":
            if s is None:
                skipped[fmt] = "no surface for the TIN"
                continue
            tin = tin_from_surface(s, tin_spacing_m)
            desc = f"{data.surface_name} of {run_dir.name}, TIN at {tin.spacing_m:g} m"
            done(fmt, [write_landxml(out / "surface.xml", tin, s, data.surface_name, desc)])
            manifest["tin"] = {"points": int(len(tin.xyz_m)), "faces": int(len(tin.faces)),
                               "spacing_m": round(tin.spacing_m, 4), "deviation_from_surface": tin.deviation}
        elif fmt == "kmz":
            if data.ortho is None:
                skipped[fmt] = "no orthophoto (dense/ortho.tif)"
                continue
            manifest["kmz"] = write_kmz(data.ortho, out / "ortho.kmz", kmz_max_px,
                                        tile_threshold_px=kmz_tile_threshold_px, max_tiles=kmz_max_tiles)
            done(fmt, [out / "ortho.kmz"])
        elif fmt in ("xlsx", "csv"):
            tables = [t for t in (Table("Points", POINT_COLUMNS, data.points),
                                  Table("Volumes", VOLUME_COLUMNS, data.volumes)) if t.rows]
            if not tables:
                skipped[fmt] = "no points and no volumes"
                continue
            if fmt == "csv":
                done(fmt, [write_csv(out / f"{t.name.lower()}.csv", t) for t in tables])
            else:
                about = {"run": run_dir.name, "crs": s.crs_label() if s else "", "heights": vd or "",
                         "units": "metres, square metres, cubic metres",
                         "residuals": "d = estimated - surveyed (check points; control points: leave-one-out)"}
                done(fmt, [write_xlsx(out / "site.xlsx", tables, about)])
    if progress:
        progress("exports", steps, steps)
    manifest.update({"crs": s.crs_label() if s else None, "vertical_datum": vd, "written": written,
                     "skipped": skipped})
    manifest = _without_run_path(manifest, run_dir)
    (out / "exports.json").write_text(json.dumps(manifest, indent=1, default=_jsonable))
    return manifest


def _without_run_path(obj, run_dir: Path):
    """``obj`` (the manifest: dicts, lists, strings) with the run folder's own path taken out of every text, so
    that paths read relative to the run folder: the manifest reaches clients (API, browser), which must not see
    the server's folders."""
    prefixes = sorted({str(run_dir.resolve()) + "/", str(run_dir) + "/"}, key=len, reverse=True)

    def clean(v):
        if isinstance(v, str):
            for pre in prefixes:
                v = v.replace(pre, "")
            return v
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v

    return clean(obj)


def _relative_name(path, run_dir: Path) -> str:
    """``path`` relative to the run folder where it lies inside it, else its file name (never an absolute path)."""
    try:
        return Path(path).resolve().relative_to(run_dir.resolve()).as_posix()
    except ValueError:
        return Path(path).name


def _jsonable(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return str(v)
