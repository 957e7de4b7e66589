"""`georef design`: cut/fill of a surveyed surface against a design surface (LandXML, DXF or GeoTIFF) inside
a polygon, on-grade share within a tolerance, and which cells differ significantly given the survey's
accuracy (docs/design.md)."""

from __future__ import annotations

import json


def register(sub) -> None:
    p = sub.add_parser("design", help="cut / fill / on-grade share of a surveyed surface against a design surface",
                       description="d = surveyed - design per DSM cell inside the polygon: cut (above design, to "
                                   "remove), fill (below design, to place), net, on-grade share within +-tolerance, "
                                   "cells not significantly different from the design given the survey's accuracy.")
    p.add_argument("--dsm", required=True, help="surveyed surface GeoTIFF (a DSM or DTM; projected CRS in metres)")
    p.add_argument("--design", required=True, help="design surface: LandXML (.xml), DXF (.dxf: 3DFACE / polyface) "
                                                   "or GeoTIFF grid (.tif)")
    p.add_argument("--polygon", required=True, help="GeoJSON area to compare (several features: their union)")
    p.add_argument("--tolerance", type=float, default=0.05, metavar="M", help="on grade within +-M (default 0.05)")
    p.add_argument("--k", type=float, default=1.96, help="significance: |d| < k sigma_cell is not significant "
                                                         "(default 1.96: 95 %%)")
    p.add_argument("--surface-name", help="which LandXML surface (needed when the file holds several)")
    p.add_argument("--crs", help="site CRS of a design file without one (DXF, LandXML without CoordinateSystem; "
                                 "default: the DSM's)")
    p.add_argument("--polygon-crs", metavar="CRS", help="CRS of the polygon file if it has no 'crs' member and is "
                                                        "not longitude/latitude")
    g = p.add_argument_group("survey accuracy (default: --run's dense_summary.json and residuals.json, else "
                             "5 cm noise, 2 cm vertical RMSE, 1 m correlation)")
    g.add_argument("--run", metavar="RUN_DIR", help="the run folder of the survey (residuals.json, "
                                                    "dense/dense_summary.json); default: two levels above the DSM")
    g.add_argument("--dsm-sigma", type=float, metavar="M", help="DSM height noise per cell, 1 sigma")
    g.add_argument("--vertical-rmse", type=float, metavar="M", help="the survey's vertical check-point RMSE")
    g.add_argument("--corr-length", type=float, metavar="M", help="correlation length of the DSM noise")
    g.add_argument("--design-sigma", type=float, default=0.0, metavar="M", help="the design's own height error "
                                                                                "(default 0: exact)")
    p.add_argument("--out", metavar="DIR", help="write DIR/difference.tif, classes.tif, contours.geojson, "
                                                "cut_fill.json")
    p.add_argument("--json", action="store_true", help="print the quantities as JSON")
    p.set_defaults(func=cmd_design)


def cmd_design(args) -> int:
    from ..steps.design import run_design

    options = {"tolerance_m": args.tolerance, "k": args.k, "dsm_sigma_m": args.dsm_sigma,
               "vertical_rmse_m": args.vertical_rmse, "correlation_length_m": args.corr_length,
               "design_sigma_m": args.design_sigma}
    doc = run_design(args.dsm, args.design, args.polygon, args.out, options, args.surface_name, args.crs,
                     args.polygon_crs, args.run)
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    u = doc["uncertainty"]
    og = doc["on_grade"]
    sig = doc["significance"]
    print(f"design {doc['design']['name']!r} ({doc['design']['kind']}) vs {doc['dsm']['path']}, "
          f"polygon {doc['polygon']['name']!r}: {doc['area_m2']:.2f} m2 compared")
    for key, what in (("cut_m3", "cut  (above design, to remove)"), ("fill_m3", "fill (below design, to place)"),
                      ("net_m3", "net  (cut - fill)")):
        print(f"  {what:<32} {doc[key]:12.3f} m3  +- {u[key]['sigma_m3']:.3f} (1 sigma), +- {u[key]['ci95_m3']:.3f} (95 %)")
    print(f"  on grade (+-{doc['tolerance_m']:g} m): {100 * og['share']:.1f} %  (expected {100 * og['expected_share']:.1f} %,"
          f" surely {100 * og['surely_share']:.1f} %, possibly {100 * og['possibly_share']:.1f} %)")
    print(f"  not significant: {doc['classes_m2']['not_significant']:.2f} m2 (|d| < {sig['threshold_m']:.3f} m = "
          f"{doc['k']:g} x {sig['sigma_cell_m']:.3f} m)")
    for w in doc["warnings"]:
        print(f"  warning: {w}")
    if doc.get("outputs"):
        print("  outputs: " + ", ".join(doc["outputs"].values()))
    return 0
