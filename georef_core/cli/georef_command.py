"""`georef georef SURVEY_DIR --out OUT_DIR`: PPK + SfM + GNSS-aided adjustment + check-point table."""

from __future__ import annotations

import sys
from pathlib import Path

from .arguments import parse_three_numbers


def register(sub) -> None:
    p = sub.add_parser("georef", help="georeference a survey's photos: PPK, SfM, lever arm/delay, check-point residuals",
                       description="Georeference the photos of SURVEY_DIR (rover/, base/, nav/, images/, events.csv, "
                                   "gcp/points.csv + gcp/gcp_list.txt, survey.json) into OUT_DIR: oriented_images.json, "
                                   "residuals.csv/json, lever_arm_delay.json, georef_summary.json, plots/.")
    p.add_argument("survey_dir", help="survey folder")
    p.add_argument("--out", required=True, help="output folder (PPK and SfM results in it are reused)")
    p.add_argument("--mode", choices=("joint", "gcp", "similarity", "a", "b", "c"), default="joint",
                   help="joint (c, default): one adjustment of tie points, GNSS positions, lever arm, delay, camera and "
                        "control points; gcp (a): orient with control points, then lever arm + delay; similarity (b): "
                        "7-parameter similarity + delay with a known lever arm, no control")
    p.add_argument("--camera-model", choices=("radial", "brown", "fisheye"), default=None,
                   help="self-calibration model: radial (f, cx, cy, k1, k2), brown (default: f, cx, cy, k1-k3, p1, "
                        "p2) or fisheye (OpenCV fisheye: f, cx, cy, k1-k4); with --calibration, the calibration's")
    p.add_argument("--crs", type=int, metavar="EPSG", help="project CRS EPSG code (default survey.json, else UTM)")
    p.add_argument("--points-crs", help="CRS of gcp/points.csv (e.g. EPSG:32633; default survey.json or gcp_list.txt)")
    p.add_argument("--control", help="control points: 'all', 'none' or NAME,NAME,... (the others become check points; "
                                     "default: the roles in points.csv)")
    p.add_argument("--check", help="NAME,NAME,...: make these check points")
    p.add_argument("--lever-arm", help="known lever arm X,Y,Z (camera frame: x right, y down, z forward; m); write "
                                       "--lever-arm=X,Y,Z when X is negative. Fixed unless --lever-arm-sigma is given")
    p.add_argument("--lever-arm-sigma", type=float, metavar="M",
                   help="uncertainty of --lever-arm: estimate the lever arm with it as a weighted prior")
    p.add_argument("--delay", type=float, metavar="S", help="trigger-to-exposure delay (s), a-priori (default 0)")
    p.add_argument("--fix-delay", action="store_true", help="hold the delay at --delay instead of estimating it")
    p.add_argument("--no-target-refinement", action="store_true",
                   help="use the clicked target positions as they are (default: sub-pixel refinement of checker targets)")
    p.add_argument("--no-leave-one-out", action="store_true", help="skip the leave-one-out table of the control points")
    p.add_argument("--max-tie-points", type=int, default=8000, help="tie points in the adjustment (default 8000)")
    p.add_argument("--threads", type=int, default=2, help="threads for SfM (default 2)")
    p.add_argument("--rerun", action="store_true", help="recompute PPK and SfM even when OUT_DIR has them")
    p.add_argument("--calibration", metavar="CAL_OUT_DIR",
                   help="a calibration flight's output folder: its lever arm (as a prior with its sigma), delay (a "
                        "priori), camera intrinsics (held fixed) and rolling-shutter readout time (held fixed) are "
                        "used; --lever-arm/--delay/--readout-ms override")
    p.add_argument("--exif-time-offset", type=float, metavar="S",
                   help="take trigger times from the images' EXIF time + S seconds (camera clock error negated) "
                        "instead of camera events")
    shutter = p.add_mutually_exclusive_group()
    shutter.add_argument("--rolling-shutter", dest="rolling_shutter", action="store_true", default=None,
                         help="the camera has a rolling shutter (default: from Georef's table of camera models)")
    shutter.add_argument("--global-shutter", dest="rolling_shutter", action="store_false",
                         help="the camera has a global or mechanical shutter")
    p.add_argument("--readout-ms", type=float, metavar="MS",
                   help="rolling-shutter readout time, first to last row (ms), held fixed; implies --rolling-shutter "
                        "(default: estimated in the adjustment for a rolling-shutter camera)")
    p.add_argument("--flight-offsets", choices=("auto", "on", "off"), default="auto",
                   help="a common GNSS offset per flight (battery) with a prior, in every mode (default auto: with "
                        "two or more flights, an unsurveyed base, positions that are not RTK-fixed or RTK-tagged "
                        "photos)")
    p.add_argument("--flight-offset-sigma", metavar="H,V", default=None,
                   help="each flight's own offset sigma, horizontal and vertical (m; default 0.01,0.015; raised to "
                        "the median sigma of the flight's positions, per fixed part and not-fixed stretch)")
    p.add_argument("--flight-gap", type=float, metavar="S", default=120.0,
                   help="without flight folders, a gap of more than S seconds between photos starts a flight (120)")
    p.set_defaults(func=cmd_georef)


def cmd_georef(args) -> int:
    from ..steps.georef import MODE_ALIASES, GeorefOptions, run_georef

    mode = MODE_ALIASES.get(args.mode, args.mode)
    lever = parse_three_numbers(args.lever_arm, "--lever-arm") if args.lever_arm else None
    lever_sigma, delay, intrinsics = args.lever_arm_sigma, args.delay, None
    camera_model = args.camera_model or "brown"
    if args.calibration:
        from ..steps.georef import load_calibration

        cal = load_calibration(args.calibration)
        if args.camera_model and args.camera_model != cal["camera_model"]:
            print(f"georef: --camera-model {args.camera_model} does not match the calibration's camera model "
                  f"{cal['camera_model']} ({cal['source']})", file=sys.stderr)
            return 2
        camera_model = cal["camera_model"]
        if lever is None:
            lever, lever_sigma = cal["lever_arm_cam_m"], lever_sigma or cal["lever_arm_sigma_m"]
        if args.delay is None:
            delay = cal["delay_s"]
        intrinsics = cal["intrinsics"]
        if args.readout_ms is None and cal["readout_s"] is not None and args.rolling_shutter is not False:
            args.readout_ms = 1000.0 * cal["readout_s"]
    opts = GeorefOptions(mode=mode, camera_model=camera_model, project_epsg=args.crs, points_crs=args.points_crs,
                         control=args.control, check=args.check, fixed_intrinsics=intrinsics,
                         lever_arm_cam_m=lever, lever_arm_sigma_m=lever_sigma, delay_s=delay or 0.0,
                         estimate_delay=not args.fix_delay,
                         refine_targets=not args.no_target_refinement, leave_one_out=not args.no_leave_one_out,
                         max_tie_points=args.max_tie_points, num_threads=args.threads, reuse=not args.rerun,
                         exif_time_offset_s=args.exif_time_offset, rolling_shutter=args.rolling_shutter,
                         readout_s=None if args.readout_ms is None else args.readout_ms / 1000.0,
                         flight_offsets=args.flight_offsets, flight_gap_s=args.flight_gap)
    if args.flight_offset_sigma:
        try:
            h, v = (float(x) for x in args.flight_offset_sigma.split(","))
        except ValueError:
            print(f"georef: --flight-offset-sigma {args.flight_offset_sigma!r}: two numbers H,V (m)", file=sys.stderr)
            return 2
        opts.flight_offset_sigma_m = (h, v)

    def progress(stage, done, total):
        if total:
            print(f"\r{stage}: {done}/{total}", end="", file=sys.stderr, flush=True)
            if done >= total:
                print(file=sys.stderr)

    s = run_georef(args.survey_dir, args.out, opts, progress=progress)
    out = Path(args.out)
    im = s["images"]
    print(f"images: {im['registered']}/{im['total']} registered, {im['with_gnss']} with GNSS; mode {s['mode']}; "
          f"camera {s['camera_model']}")
    a = s["adjustment"]
    if "rms_reprojection_px" in a:
        print(f"adjustment: reprojection RMS {a['rms_reprojection_px']} px, sigma0 {a.get('sigma0')}")
    ld = s["lever_arm_delay"]
    lsig = ld["lever_arm_sigma_m"]
    print("lever arm (camera frame, m): " + ", ".join(
        f"{v:+.4f}" + (f" ± {e:.4f}" if lsig else "") for v, e in zip(ld["lever_arm_cam_m"], lsig or [0, 0, 0]))
          + ("" if lsig else " (fixed)"))
    print(f"delay: {1000 * ld['delay_s']:.2f} ms" + (f" ± {1000 * ld['delay_sigma_s']:.2f}" if ld["delay_sigma_s"] else " (fixed)"))
    if len(s.get("cameras") or []) > 1:
        print("cameras: " + "; ".join(f"{c['id']}: {c['label']} ({c['n_images']} images)" for c in s["cameras"]))
    if s.get("doming"):
        print(s["doming"]["text"])
    if s.get("absolute_accuracy"):
        print(f"absolute accuracy: {s['absolute_accuracy']['text']}")
    rs = s.get("rolling_shutter") or {}
    if rs.get("modelled"):
        print(f"rolling-shutter readout: {1000 * rs['readout_s']:.2f} ms"
              + (f" ± {1000 * rs['readout_sigma_s']:.2f}" if rs.get("readout_sigma_s") else " (given)"))
    from ..adjustment.residual_table import ResidualRow, ResidualTable

    for key in ("check_points", "control_leave_one_out"):
        t = s.get(key)
        if t and t["points"]:
            table = ResidualTable(t["kind"], t["crs"], [ResidualRow(**{**r, "sigma_m": None}) for r in t["points"]])
            print()
            print(table.format_text())
    for b in s["blunders"]:
        print(f"blunder: {b['message']}")
    for w in s["warnings"]:
        if not any(w == b["message"] for b in s["blunders"]):
            print(f"georef: warning: {w}", file=sys.stderr)
    print(f"\n-> {out / 'georef_summary.json'}, {out / 'residuals.csv'}, {out / 'oriented_images.json'}")
    return 0
