"""`georef gnss solve ROVER BASE NAV... --out FILE.pos` and its options."""

from __future__ import annotations

import json
import sys

from ..errors import GeorefError
from ..gnss.rtk_options import RtkOptions, read_rtklib_conf
from .arguments import parse_position

_FREQ = {"l1": 1, "l1+l2": 2, "l1+l2+l5": 3}


def register(sub) -> None:
    gnss = sub.add_parser("gnss", help="GNSS baseline processing")
    gsub = gnss.add_subparsers(dest="gnss_command", required=True)
    p = gsub.add_parser("solve", help="PPK: rover + base + navigation -> trajectory (.pos, .parquet, events)")
    p.add_argument("rover", help="rover observations: RINEX 2/3 (.obs/.##o/.crx/.##d, gz/Z) or u-blox .ubx")
    p.add_argument("base", help="base observations (same formats)")
    p.add_argument("nav", nargs="*", help="navigation files (RINEX nav; UBX logs carry their own)")
    p.add_argument("--out", required=True, help="output .pos file; .parquet, _events.csv, _summary.json beside it")
    p.add_argument("--rtklib-conf", help="RTKLIB rnx2rtkp configuration file (shared options are applied)")
    p.add_argument("--mode", choices=["kinematic", "static", "known-start", "single"])
    p.add_argument("--freq", choices=list(_FREQ), help="frequencies: l1, l1+l2, l1+l2+l5")
    p.add_argument("--filter", choices=["forward", "backward", "combined"], help="filter direction (default combined)")
    p.add_argument("--ar", choices=["off", "continuous", "instantaneous", "fix-and-hold"], help="ambiguity resolution")
    p.add_argument("--ratio", type=float, help="ratio-test threshold (default 3)")
    p.add_argument("--elmask", type=float, help="elevation mask, degrees (default 15)")
    p.add_argument("--snr-mask", type=float, help="C/N0 mask, dB-Hz (default off)")
    p.add_argument("--navsys", help="systems to use, e.g. G,E,J or G,R (default all)")
    p.add_argument("--troposphere", choices=["saastamoinen", "hopfield", "off"])
    p.add_argument("--ionosphere", choices=["broadcast", "off"])
    p.add_argument("--dynamics", choices=["off", "random-walk", "constant-velocity"])
    p.add_argument("--base-pos", help="base antenna position: LAT,LON,H (deg, m ellipsoidal) or X,Y,Z (ECEF m); "
                                      "default: RINEX header. Write --base-pos=X,Y,Z when the first value is negative")
    p.add_argument("--known-start", help="surveyed take-off position for --mode known-start: LAT,LON,H or X,Y,Z")
    p.add_argument("--max-age", type=float, help="maximum age of base corrections, s (default 30)")
    p.add_argument("--no-base-interpolation", action="store_true", help="no interpolation: each rover epoch takes the nearest base epoch, older or newer (as RTKLIB demo5)")
    p.add_argument("--event-edge", choices=["falling", "rising"],
                   help="the TIM-TM2 edge of a UBX rover log that marks the exposure (default falling, as convbin; "
                        "rising for an active-high trigger; docs/gnss.md)")
    p.add_argument("--no-reverse-witness", action="store_true",
                   help="forward/backward: do not run the other pass as a witness (fixes it contradicts are "
                        "otherwise output as float; docs/gnss.md)")
    p.add_argument("--tdcp-slips", type=float, metavar="M",
                   help="threshold of the check for slips the receivers did not flag (time-differenced carrier "
                        "phase), m (default 0.05; 0 = off)")
    p.add_argument("--hold-variance", type=float, metavar="CYC2",
                   help="fix-and-hold: variance of the held ambiguities, cycles^2 (default 0.1 as demo5; "
                        "0.001 as RTKLIB 2.4.3)")
    p.add_argument("--fix-max-sigma", type=float, metavar="M",
                   help="a fix whose position's formal 3-D sigma exceeds this is output as float, m (default "
                        "0.05; 0 = off; docs/gnss.md)")
    p.add_argument("--events", help="camera trigger times: a CSV (column gps_time_s) or a DJI Timestamp.MRK; "
                                    "default: events in the rover file")
    p.add_argument("--crs", type=int, help="also write coordinates in this EPSG CRS (e.g. 32631)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--no-server", action="store_true",
                   help="solve in this process, not in the resident solver (also: GEOREF_GNSS_SERVER=0; docs/gnss.md)")
    p.set_defaults(func=cmd_solve)
    srv = gsub.add_parser("server", help="the resident solver that makes `georef gnss solve` start fast "
                                         "(started by the first solve; docs/gnss.md)")
    srv.add_argument("action", choices=["start", "stop", "status"])
    srv.add_argument("--wait", type=float, default=0.0, metavar="S",
                     help="start: wait up to S seconds until it answers")
    srv.add_argument("--idle-s", type=float, help="start: exit after this many seconds without a solve (default 900)")
    srv.add_argument("--json", action="store_true", help="status: as JSON")
    srv.set_defaults(func=_cmd_server)


def _cmd_server(args) -> int:
    from .solver_client import cmd_server

    return cmd_server(args)


def options_from_args(args) -> tuple[RtkOptions, list[str]]:
    notes: list[str] = []
    opts = RtkOptions()
    if args.rtklib_conf:
        res = read_rtklib_conf(args.rtklib_conf, opts)
        opts = res.options
        for key, why in res.unsupported.items():
            notes.append(f"{args.rtklib_conf}: {key} not applied: {why}")
        for key in res.unknown:
            notes.append(f"{args.rtklib_conf}: unknown option {key!r} ignored")
    changes = {}
    if args.mode:
        changes["mode"] = args.mode
    if args.freq:
        changes["n_bands"] = _FREQ[args.freq]
    if args.filter:
        changes["filter_direction"] = args.filter
    if args.ar:
        changes["ar_mode"] = args.ar
    if args.ratio is not None:
        changes["ratio_threshold"] = args.ratio
    if args.elmask is not None:
        changes["elevation_mask_deg"] = args.elmask
    if args.snr_mask is not None:
        changes["snr_mask_dbhz"] = args.snr_mask
    if args.navsys:
        systems = tuple(s.strip().upper() for s in args.navsys.split(",") if s.strip())
        bad = [s for s in systems if s not in ("G", "R", "E", "J", "C")]
        if bad:
            raise GeorefError(f"--navsys: unknown system(s) {','.join(bad)}; use G,R,E,J,C")
        changes["systems"] = systems
    if args.troposphere:
        changes["troposphere"] = args.troposphere
    if args.ionosphere:
        changes["ionosphere"] = args.ionosphere
    if args.dynamics:
        changes["dynamics"] = args.dynamics
    if args.base_pos:
        changes["base_position_ecef_m"] = parse_position(args.base_pos, "--base-pos")
    if args.known_start:
        changes["known_start_position_ecef_m"] = parse_position(args.known_start, "--known-start")
        changes.setdefault("mode", "known-start")
    if args.max_age is not None:
        changes["max_age_s"] = args.max_age
    if args.no_base_interpolation:
        changes["base_interpolation"] = False
    if args.event_edge:
        changes["ubx_event_edge"] = args.event_edge
    if args.no_reverse_witness:
        changes["reverse_witness"] = False
    if args.tdcp_slips is not None:
        changes["slip_tdcp_threshold_m"] = args.tdcp_slips
    if args.hold_variance is not None:
        changes["hold_variance_cyc2"] = args.hold_variance
    if args.fix_max_sigma is not None:
        changes["fix_max_sigma_m"] = args.fix_max_sigma
    opts = opts.replace(**changes)
    try:
        opts.validate()
    except ValueError as exc:
        raise GeorefError(str(exc)) from None
    return opts, notes


def cmd_solve(args) -> int:
    from ..gnss import kernel_loader

    # the kernels compiled ahead of time (make install), when present and current: numba is not imported
    aot = kernel_loader.prefer_aot()
    from ..steps.gnss_solve import run_gnss_solve

    opts, notes = options_from_args(args)
    for n in notes:
        print(f"georef: warning: {n}", file=sys.stderr)
    if not aot:
        from ..warmup import GNSS_COMPILE_ESTIMATE_S, gnss_kernels_cached
        from .numba_start import trim_numba_start

        trim_numba_start()   # this process solves once and ends: skip what numba loads that the solve never uses
    if not aot and not gnss_kernels_cached():
        print(f"georef: first run: compiling the GNSS kernels, about {GNSS_COMPILE_ESTIMATE_S} s (once; "
              "`georef warmup` does it ahead of time)", file=sys.stderr, flush=True)
    summary = run_gnss_solve(args.rover, args.base, args.nav, args.out, opts, events_csv=args.events, epsg=args.crs)
    for w in summary["warnings"]:
        print(f"georef: warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        n = summary["epochs"]
        print(f"{n} epochs: {summary['fix']} fixed ({100 * summary['fix_rate']:.1f} %), {summary['float']} float, "
              f"{summary['single']} single")
        if "events" in summary:
            ev = summary["events"]
            print(f"{ev['count']} camera events: {ev['fixed']} on fixed epochs, {ev['without_solution']} without solution "
                  f"-> {ev['csv']}")
        print(f"written: {summary['outputs']['pos']}, {summary['outputs']['parquet']}")
    return 0
