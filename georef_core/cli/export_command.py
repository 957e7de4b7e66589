"""`georef export OUT_DIR`: a run folder's deliverables (contours, stockpile outlines, surveyed points, the
TIN, the orthophoto overlay, tables) in the formats surveyors' and GIS software read
(docs/deliverables.md, "Exports")."""

from __future__ import annotations

import json


# the formats of deliverables.exports.FORMATS (not imported here: `georef --help` loads no science code)
FORMATS = ("geojson", "dxf", "gpkg", "shp", "landxml", "kmz", "xlsx", "csv")


def register(sub) -> None:
    p = sub.add_parser("export", help="a run's deliverables as DXF, GeoPackage, Shapefile, LandXML, KMZ, XLSX, ...",
                       description="Writes what the run folder holds (dense/dsm.tif, dense/ortho.tif, dtm/dtm.tif, "
                                   "volumes/, residuals.json; the survey's gcp/points.csv with --survey) to "
                                   "OUT_DIR/exports (or --to) in each --format, and says what it skipped.")
    p.add_argument("out_dir", metavar="OUT_DIR", help="the run folder (what `georef georef`/`georef dense` wrote)")
    p.add_argument("--format", action="append", metavar="FMT",
                   help=f"{'|'.join(FORMATS)}; repeat or comma-separate (default: all)")
    p.add_argument("--to", metavar="DIR", help="write here instead of OUT_DIR/exports")
    p.add_argument("--survey", metavar="SURVEY_DIR", help="the survey folder (its gcp/points.csv: surveyed points)")
    p.add_argument("--surface", choices=("dsm", "dtm"), default="dsm",
                   help="contours and TIN from the DSM or the DTM (dtm/dtm.tif; the DSM when there is none)")
    p.add_argument("--interval", type=float, metavar="M", help="contour interval, metres (default: automatic)")
    p.add_argument("--index-every", type=int, default=5, metavar="N", help="index contour every N levels (5)")
    p.add_argument("--tin-spacing", type=float, metavar="M", help="LandXML TIN vertex spacing, metres (default: "
                                                                  "0.5 m or more, at most 250 000 vertices)")
    p.add_argument("--geojson-crs", choices=("wgs84", "site"), default="wgs84")
    p.add_argument("--kmz-tile-px", type=int, default=2048, metavar="PX",
                   help="an orthophoto longer than this is written to the KMZ as tiles (a super-overlay), "
                        "else as one image (2048)")
    p.add_argument("--json", action="store_true", help="print the manifest as JSON")
    p.set_defaults(func=cmd_export)


def cmd_export(args) -> int:
    from ..deliverables.exports import export_run

    formats = [f.strip() for v in (args.format or []) for f in v.split(",") if f.strip()] or None
    m = export_run(args.out_dir, args.to, formats, args.interval, args.surface, args.survey, args.index_every,
                   tin_spacing_m=args.tin_spacing, geojson_crs=args.geojson_crs,
                   kmz_tile_threshold_px=args.kmz_tile_px)
    if args.json:
        print(json.dumps(m, indent=1, default=str))
        return 0
    print(f"CRS {m['crs']}, heights: {m['vertical_datum']}")
    for fmt, files in m["written"].items():
        print(f"  {fmt:<8} {', '.join(files)}")
    for what, why in m["skipped"].items():
        print(f"  skipped {what}: {why}")
    return 0
