"""`georef contours`: contour lines of a DSM or DTM GeoTIFF at a chosen interval, index contours labelled, as
GeoJSON, GeoPackage, DXF or Shapefile by the output's extension (docs/deliverables.md, "Contours")."""

from __future__ import annotations

import json


def register(sub) -> None:
    p = sub.add_parser("contours", help="contours of a DSM/DTM (GeoJSON, GeoPackage, DXF or Shapefile)",
                       description="Contours of an elevation GeoTIFF every --interval metres, lightly smoothed "
                                   "(Gaussian, 1.5 cells), stopping at no-data; every 5th an index contour "
                                   "(attribute index, DXF layer CONTOUR_INDEX with labels).")
    p.add_argument("--dsm", "--surface", dest="surface", required=True, metavar="SURFACE.tif",
                   help="DSM or DTM GeoTIFF (projected CRS in metres)")
    p.add_argument("--interval", type=float, metavar="M", help="contour interval in metres (default: a round "
                                                                "interval giving at most 40 levels)")
    p.add_argument("--out", required=True, metavar="FILE", help="output: .geojson, .gpkg, .dxf (+ .prj) or .shp")
    p.add_argument("--index-every", type=int, default=5, metavar="N", help="every N-th level is an index contour "
                                                                           "(default 5)")
    p.add_argument("--smoothing", type=float, metavar="M", help="Gaussian sigma of the smoothing before tracing, "
                                                                "metres (default 1.5 cells; 0: none)")
    p.add_argument("--geojson-crs", choices=("wgs84", "site"), default="wgs84",
                   help="GeoJSON coordinates: wgs84 (RFC 7946, default) or the surface's CRS with a 'crs' member")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=cmd_contours)


def cmd_contours(args) -> int:
    from ..deliverables.exports import run_contours

    s = run_contours(args.surface, args.out, args.interval, args.index_every, args.smoothing, args.geojson_crs)
    if args.json:
        print(json.dumps(s, indent=1))
    else:
        print(f"{s['lines']} contours ({s['index_lines']} index) every {s['interval_m']:g} m "
              f"(index every {s['index_interval_m']:g} m), {s['length_m']:.0f} m of line; heights: "
              f"{s['vertical_datum']}; CRS {s['crs']}")
        for f in s["files"]:
            print(f"  {f}")
    return 0
