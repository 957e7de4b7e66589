"""`georef datum`: vertical datums (list, convert a DSM / point cloud / point table, one point) and site
calibrations (calibrate from control pairs, apply to points or a DSM). docs/datums.md."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from ..errors import GeorefError, InputFileError

DATUM_HELP = "ellipsoidal, egm96, egm2008, jgd2011 or an EPSG vertical CRS code (EPSG:5773)"


def register(sub) -> None:
    p = sub.add_parser("datum", help="vertical datums (geoid heights) and site calibrations",
                       description="Heights in the site's vertical datum and coordinates in its local grid "
                                   "(docs/datums.md). Grids are read from installed files only, never downloaded.")
    ss = p.add_subparsers(dest="action", required=True)
    ls = ss.add_parser("list", help="the vertical datums and whether their grid is installed here")
    ls.add_argument("--json", action="store_true")
    ls.set_defaults(func=cmd_list)

    c = ss.add_parser("convert", help="a DSM (.tif), point cloud (.las/.laz) or point table (.csv) to another "
                                      "vertical datum, the datum written into the output")
    c.add_argument("--in", dest="src", required=True, help="input file (.tif, .las, .laz, .csv)")
    c.add_argument("--out", required=True, help="output file (same kind)")
    c.add_argument("--to", required=True, help=f"target datum: {DATUM_HELP}")
    c.add_argument("--from", dest="from_datum", help="the input's datum when its file does not state it (a CSV "
                                                     "always needs it; default for rasters and clouds: their CRS)")
    c.add_argument("--crs", help="horizontal CRS of a CSV's easting/northing (e.g. EPSG:32631)")
    c.add_argument("--step", type=float, default=10.0, metavar="M",
                   help="PROJ at nodes this far apart, bilinear in between (rasters, clouds; default 10 m)")
    c.add_argument("--json", action="store_true")
    c.set_defaults(func=cmd_convert)

    pt = ss.add_parser("point", help="one height in another datum: LAT LON HEIGHT")
    pt.add_argument("lat", type=float)
    pt.add_argument("lon", type=float)
    pt.add_argument("height", type=float)
    pt.add_argument("--from", dest="from_datum", default="ellipsoidal", help=f"datum of HEIGHT: {DATUM_HELP}")
    pt.add_argument("--to", required=True, help=f"target datum: {DATUM_HELP}")
    pt.set_defaults(func=cmd_point)

    k = ss.add_parser("calibrate", help="a site calibration (localisation) from control pairs",
                      description="4-parameter similarity about the centroid plus an inclined-plane vertical "
                                  "adjustment, least squares; residuals per point.")
    k.add_argument("--points", required=True, help="CSV: name, easting_m, northing_m, height_m, local_e_m, "
                                                   "local_n_m, local_h_m[, use: hv | h | v]")
    k.add_argument("--out", required=True, help="calibration JSON to write")
    k.add_argument("--crs", default="", help="the projected CRS of easting/northing (recorded in the file)")
    k.add_argument("--height-datum", default="ellipsoidal", help=f"datum of height_m: {DATUM_HELP}")
    k.add_argument("--name", default="", help="a name for the local grid")
    k.add_argument("--json", action="store_true")
    k.set_defaults(func=cmd_calibrate)

    a = ss.add_parser("apply", help="a calibration applied to a point table (.csv) or a DSM (.tif)")
    a.add_argument("--calibration", required=True, help="calibration JSON (georef datum calibrate)")
    a.add_argument("--in", dest="src", required=True, help="CSV (name, easting_m, northing_m, height_m) or GeoTIFF")
    a.add_argument("--out", required=True)
    a.add_argument("--inverse", action="store_true", help="CSV: local grid -> projected CRS")
    a.set_defaults(func=cmd_apply)


def _datum(text):
    from ..datums.vertical_datum import resolve

    try:
        return resolve(text)
    except ValueError as exc:
        raise GeorefError(str(exc)) from None


def cmd_list(args) -> int:
    from ..datums.grids import grid_dirs
    from ..datums.vertical_datum import registry

    reg = registry()
    if args.json:
        print(json.dumps({"datums": reg, "grid_dirs": [str(d) for d in grid_dirs()]}, indent=1))
        return 0
    for d in reg:
        state = "available" if d["available"] else "grid not installed"
        print(f"{d['key']:<12} {d['label']:<28} {state}" + (f"  ({d['grid']})" if d["grid"] else ""))
    print(f"grid folders: {', '.join(str(d) for d in grid_dirs()) or 'none'}; any EPSG vertical CRS whose grid is "
          "installed also works (EPSG:code)")
    return 0


def _read_table(path: Path) -> tuple[list[str], list[dict]]:
    if not path.is_file():
        raise InputFileError(path, "file not found")
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    head = [h.strip() for h in (rows[0].keys() if rows else [])]
    need = [c for c in ("name", "easting_m", "northing_m", "height_m") if c not in head]
    if not rows or need:
        raise InputFileError(path, f"needs the columns name, easting_m, northing_m, height_m (missing: "
                                   f"{', '.join(need) or 'every row'})")
    return head, rows


def _floats(path: Path, rows: list[dict], *cols: str):
    import numpy as np

    out = []
    for c in cols:
        try:
            out.append(np.array([float(r[c]) for r in rows]))
        except (TypeError, ValueError):
            raise InputFileError(path, f"column {c}: a value is missing or not a number") from None
    return out


def cmd_convert(args) -> int:
    src, dst = Path(args.src), Path(args.out)
    to = _datum(args.to)
    frm = _datum(args.from_datum) if args.from_datum else None
    ext = src.suffix.lower()
    if ext in (".tif", ".tiff"):
        from ..datums.raster_heights import convert_raster_heights

        out = convert_raster_heights(src, dst, to, frm, step_m=args.step)
    elif ext in (".las", ".laz"):
        from ..datums.point_cloud_heights import convert_point_cloud_heights

        out = convert_point_cloud_heights(src, dst, to, frm, step_m=args.step)
    elif ext == ".csv":
        out = _convert_csv(src, dst, to, frm, args.crs)
    else:
        raise InputFileError(src, "expected a .tif, .las, .laz or .csv file")
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        dz = out.get("dz_m") or {}
        print(f"{dst}: {out['from']} -> {out['to']}" + (f", height change {dz['min']:+.4f} .. {dz['max']:+.4f} m"
                                                       if dz.get("min") is not None else ""))
    return 0


def _convert_csv(src: Path, dst: Path, to, frm, crs: str | None) -> dict:
    from ..datums.point_tables import write_points_csv
    from ..datums.vertical_datum import convert_heights, lat_lon_of

    if frm is None or not crs:
        raise GeorefError(f"{src}: a CSV states neither its CRS nor its heights' datum: give --crs and --from")
    _, rows = _read_table(src)
    e, n, z = _floats(src, rows, "easting_m", "northing_m", "height_m")
    lat, lon = lat_lon_of(crs, e, n)
    zz = convert_heights(lat, lon, z, frm, to)
    out_rows = [{"name": r["name"], "role": r.get("role", ""), "easting_m": float(a), "northing_m": float(b),
                 "height_m": float(c)} for r, a, b, c in zip(rows, e, n, zz)]
    write_points_csv(dst, out_rows, crs, to)
    d = zz - z
    return {"from": frm.label, "to": to.label, "path": str(dst), "points": len(out_rows),
            "dz_m": {"min": round(float(d.min()), 4), "max": round(float(d.max()), 4)}}


def cmd_point(args) -> int:
    from ..datums.vertical_datum import convert_heights

    a, b = _datum(args.from_datum), _datum(args.to)
    z = float(convert_heights(args.lat, args.lon, args.height, a, b))
    print(f"{z:.4f} m {b.label}  ({args.height:.4f} m {a.label}; change {z - args.height:+.4f} m)")
    return 0


def cmd_calibrate(args) -> int:
    from ..datums.site_calibration import read_control_pairs, solve_calibration

    datum = _datum(args.height_datum)
    cal = solve_calibration(read_control_pairs(args.points), crs=args.crs, height_datum=datum.code, name=args.name)
    cal.write(args.out)
    print(json.dumps(cal.to_dict(), indent=1) if args.json else cal.format_text())
    return 0


def cmd_apply(args) -> int:
    from ..datums.site_calibration import calibrate_raster, read_calibration

    cal = read_calibration(args.calibration)
    src, dst = Path(args.src), Path(args.out)
    if src.suffix.lower() in (".tif", ".tiff"):
        if args.inverse:
            raise GeorefError("--inverse applies to point tables only")
        out = calibrate_raster(cal, src, dst)
        print(f"{dst}: {out['width']} x {out['height']} cells of {out['cell_m']:.3f} m in the local grid")
        return 0
    if src.suffix.lower() != ".csv":
        raise InputFileError(src, "expected a .csv point table or a .tif raster")
    if args.inverse:
        head, rows = _read_table_local(src)
        e, n, z = _floats(src, rows, "local_e_m", "local_n_m", "local_h_m")
        E, N, H = cal.to_source(e, n, z)
        cols = ["name", "easting_m", "northing_m", "height_m"]
    else:
        head, rows = _read_table(src)
        e, n, z = _floats(src, rows, "easting_m", "northing_m", "height_m")
        E, N, H = cal.to_local(e, n, z)
        cols = ["name", "local_e_m", "local_n_m", "local_h_m"]
    dst.parent.mkdir(parents=True, exist_ok=True)
    with open(dst, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols + ["system"])
        system = (f"local grid {cal.name}".strip() if not args.inverse
                  else f"{cal.crs or 'projected CRS'} + {cal.height_datum}")
        for r, a, b, c in zip(rows, E, N, H):
            w.writerow([r["name"], f"{a:.4f}", f"{b:.4f}", f"{c:.4f}", system])
    print(f"{dst}: {len(rows)} points")
    return 0


def _read_table_local(path: Path):
    if not path.is_file():
        raise InputFileError(path, "file not found")
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    need = [c for c in ("name", "local_e_m", "local_n_m", "local_h_m") if not rows or c not in rows[0]]
    if need:
        raise InputFileError(path, f"needs the columns name, local_e_m, local_n_m, local_h_m (missing: "
                                   f"{', '.join(need)})")
    return list(rows[0].keys()), rows
