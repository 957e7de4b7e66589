"""`georef dtm OUT_DIR [--max-object M] [--slope S] [--tolerance M] [--cell M] [--json]`: ground classification of
a run folder's dense surface and the bare-earth DTM (docs/deliverables.md, "Bare-earth DTM")."""

from __future__ import annotations

import argparse
import json


def register(sub) -> None:
    p = sub.add_parser("dtm", help="ground classification of the dense cloud and the bare-earth DTM (COG, LAZ)",
                       description="Removes machines, vehicles and other steep-sided objects from the dense step's "
                                   "DSM (progressive morphological filter; stockpiles are ground and stay), "
                                   "interpolates the ground under them and classifies the dense points (ASPRS 2 "
                                   "ground, 1 objects, 7 low noise). Reads OUT_DIR/dense/, writes OUT_DIR/dtm/.")
    p.add_argument("out_dir", help="run folder: reads OUT_DIR/dense/dsm.tif and points.laz, writes OUT_DIR/dtm/")
    p.add_argument("--max-object", type=float, metavar="M", help="objects up to this wide on their narrow side are "
                                                                 "removed (m; default 14)")
    p.add_argument("--slope", type=float, metavar="S", help="steepest ground, rise over run (default 1.2 = 50 deg: "
                                                            "stockpiles at their angle of repose stay ground)")
    p.add_argument("--tolerance", type=float, metavar="M", help="cells and points within this above the ground are "
                                                                "ground (m; default 0.25)")
    p.add_argument("--cell", type=float, metavar="M", help="classification cell (m; default 0.5)")
    p.add_argument("--threshold", type=float, metavar="M", help="elevation threshold added to slope x cell (m; "
                                                                "default 0.3)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.set_defaults(func=cmd_dtm)


def cmd_dtm(args: argparse.Namespace) -> int:
    from ..steps.dtm import options_from_dict, run_dtm
    from .dense_command import _progress

    given = {"max_object_m": args.max_object, "slope": args.slope, "ground_tolerance_m": args.tolerance,
             "cell_m": args.cell, "elevation_threshold_m": args.threshold}
    o = options_from_dict({k: v for k, v in given.items() if v is not None})
    report, close = _progress(not args.quiet and not args.json)
    try:
        s = run_dtm(args.out_dir, o, progress=report)
    finally:
        close()
    if args.json:
        print(json.dumps(s, indent=2))
        return 0
    d, p, r = s["dtm"], s["points"], s["removed_objects"]
    print(f"DTM {d['width']} x {d['height']} cells of {s['resolution_m']:g} m: {100 * d['ground_share']:.2f} % ground, "
          f"{d['removed_area_m2']:,.1f} m2 removed and interpolated")
    print(f"removed objects: {r['count']} ({r['area_m2']:,.1f} m2, largest {r['largest_area_m2']:,.1f} m2), "
          f"spikes: {r['spikes']}")
    for it in r["items"][:10]:
        ring = "" if it["ground_ring_rms_m"] is None else f", ground around it: plane RMS {it['ground_ring_rms_m']:.3f} m"
        print(f"  at E {it['centre_e_m']:.1f} N {it['centre_n_m']:.1f}: {it['area_m2']:.1f} m2, up to "
              f"{it['max_height_m']:.2f} m high{ring}")
    print(f"points: {p['total']:,}, ground {100 * p['ground_share']:.1f} %, objects {p['unclassified']:,}, "
          f"low noise {p['low_noise']:,}")
    c = s.get("interpolation_check")
    if c:
        print(f"interpolation check ({c['patches']} hidden ground patches of {c['patch_side_m']:g} m): RMS "
              f"{c['rmse_m']:.3f} m, 95 % within {c['p95_abs_m']:.3f} m")
    print(f"{s['timings_s']['total']:.1f} s")
    for k, v in s["outputs"].items():
        print(f"  {k}: {v}")
    return 0
