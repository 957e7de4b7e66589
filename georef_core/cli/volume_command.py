"""`georef volume`, `georef change` and `georef stockpile`: stockpile volumes with their uncertainty, change
between two surveys, and named piles with locked bases measured survey after survey (docs/volumes.md)."""

from __future__ import annotations

import argparse
import json
import sys

from ..errors import GeorefError

BASE_HELP = ("base surface: lowest | highest (low/high percentile of the outline heights), mean, plane (robust "
             "best-fit plane of the outline), tin (triangulated outline), elevation:Z, surface:FILE.tif (default "
             "lowest)")


def _noise_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("uncertainty model (default: dense_summary.json next to the DSM, else 5 cm / 2 cm / 1 m)")
    g.add_argument("--dsm-sigma", type=float, metavar="M", help="DSM height noise per cell, 1 sigma (m)")
    g.add_argument("--height-bias", type=float, metavar="M", help="vertical bias of the DSM (check-point mean dz, m)")
    g.add_argument("--corr-length", type=float, metavar="M", help="correlation length of the DSM noise (m; 0: "
                                                                  "independent cells)")


def _polygon_crs_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--polygon-crs", metavar="CRS", help="CRS of the polygon file if it has no 'crs' member and is not "
                                                        "longitude/latitude (e.g. EPSG:32633)")


def register(sub) -> None:
    p = sub.add_parser("volume", help="cut / fill / net volume of polygons on a DSM, with uncertainty",
                       description="Cut (material above the base), fill (void below it) and net volume of each "
                                   "polygon of a GeoJSON file on a DSM, with a 1-sigma and 95 % uncertainty.")
    p.add_argument("--dsm", help="DSM GeoTIFF (projected CRS in metres; a DTM works the same)")
    p.add_argument("--run", metavar="OUT_DIR", help="instead of --dsm: a run folder, measured on its dense/dsm.tif or, "
                                                    "with --surface dtm, its dtm/dtm.tif")
    p.add_argument("--surface", choices=("dsm", "dtm"), default="dsm",
                   help="with --run: the DSM (default) or the bare-earth DTM (georef dtm: machines removed)")
    p.add_argument("--polygon", required=True, help="GeoJSON polygon(s), any CRS; one result per feature ('name')")
    p.add_argument("--base", default="lowest", help=BASE_HELP)
    p.add_argument("--percentile", type=float, help="percentile of the outline heights for lowest/highest "
                                                    "(default 2 / 98)")
    p.add_argument("--max-fill", type=float, default=5.0, metavar="PERCENT",
                   help="fill DSM holes inside a polygon by interpolation up to this %% of its area (default 5)")
    p.add_argument("--accept-interpolated", action="store_true",
                   help="count interpolated DSM cells (dsm_filled_mask.tif: 1, or no-data filled here) as measured in "
                        "the uncertainty; default: they are reported apart with their own bound")
    p.add_argument("--surface-sigma", type=float, metavar="M", help="noise of a surface: base (default: its "
                                                                    "dense_summary.json, else taken as exact)")
    _noise_arguments(p)
    _polygon_crs_argument(p)
    p.add_argument("--out", metavar="JSON", help="also write the results to this JSON file")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=cmd_volume)

    c = sub.add_parser("change", help="DSM difference between two surveys, cut/fill, stable-ground check",
                       description="dz = after - before; cut = ground lowered (material removed), fill = ground "
                                   "raised (material placed), net = fill - cut.")
    c.add_argument("--before", required=True, help="earlier DSM GeoTIFF")
    c.add_argument("--after", required=True, help="later DSM GeoTIFF (its grid is the output grid)")
    c.add_argument("--polygon", help="GeoJSON polygon(s): cut/fill per polygon")
    c.add_argument("--stable", help="GeoJSON polygon(s) of ground that did not change (roads, pads)")
    c.add_argument("--tolerance", type=float, default=0.05, metavar="M",
                   help="stable ground must agree within this median |dz| and RMS (m, default 0.05)")
    c.add_argument("--align", action="store_true", help="remove the stable ground's median dz before the volumes")
    c.add_argument("--out", metavar="DIR", help="write DIR/dz.tif and DIR/change.json")
    c.add_argument("--json", action="store_true", help="print JSON instead of a summary")
    _noise_arguments(c)
    _polygon_crs_argument(c)
    c.set_defaults(func=cmd_change)

    s = sub.add_parser("stockpile", help="named stockpiles with locked bases, measured survey after survey",
                       description="A site registry (SITE_DIR/stockpiles.json) of piles that keep their outline and "
                                   "their base across surveys.")
    s.add_argument("site_dir", help="site folder holding stockpiles.json")
    ss = s.add_subparsers(dest="action", required=True)
    a = ss.add_parser("add", help="add the polygons of a GeoJSON file as piles (named by 'name')")
    a.add_argument("--polygon", required=True)
    a.add_argument("--name", help="name (single-feature file only)")
    a.add_argument("--material", default="")
    a.add_argument("--base", default="plane", help="how the base is computed when first measured (default plane)")
    _polygon_crs_argument(a)
    a.add_argument("--replace", action="store_true", help="replace piles of the same name")
    m = ss.add_parser("measure", help="measure piles on a survey's DSM (locks each base on first use)")
    m.add_argument("--dsm", required=True)
    m.add_argument("--survey", required=True, help="survey identifier (a re-run replaces its measurement)")
    m.add_argument("--date", default="", help="survey date, ISO (YYYY-MM-DD)")
    m.add_argument("--name", action="append", help="only this pile (repeatable)")
    _noise_arguments(m)
    m.add_argument("--json", action="store_true")
    li = ss.add_parser("list", help="piles, their bases and last volumes")
    li.add_argument("--json", action="store_true")
    se = ss.add_parser("series", help="a pile's volume over the surveys")
    se.add_argument("name")
    se.add_argument("--json", action="store_true")
    s.set_defaults(func=cmd_stockpile)


# ------------------------------------------------------------------------------------------------------


def _fmt(v, nd=2) -> str:
    return "-" if v is None else f"{v:,.{nd}f}"


def _print_volume_table(doc: dict) -> None:
    m = doc["noise_model"]
    src = m["sources"]
    print(f"DSM {doc['dsm']}  ({doc['crs']}, {doc['cell_size_m']:g} m cells)   base: {doc['base']}")
    print(f"uncertainty model: sigma_z {m['sigma_z_m']:.3f} m ({src.get('sigma_z_m')}), correlation length "
          f"{m['correlation_length_m']:g} m ({src.get('correlation_length_m')}), vertical bias {m['height_bias_m']:.3f} m "
          f"({src.get('height_bias_m')})")
    head = f"{'name':<20} {'area m2':>11} {'cut m3':>12} {'fill m3':>12} {'net m3':>12} {'±1σ m3':>9} {'±95% m3':>9}  base"
    print(head)
    print("-" * len(head))
    for r in doc["results"]:
        b = r["base"]
        info = b["method"]
        if "elevation_m" in b:
            info += f" at {b['elevation_m']:.3f} m"
        if b.get("fit", {}).get("rms_m") is not None:
            info += f", fit RMS {b['fit']['rms_m']:.3f} m"
        u = r["uncertainty"]
        print(f"{r['name'][:20]:<20} {_fmt(r['area_m2']):>11} {_fmt(r['cut_m3']):>12} {_fmt(r['fill_m3']):>12} "
              f"{_fmt(r['net_m3']):>12} {_fmt(u['sigma_m3']):>9} {_fmt(u['ci95_m3']):>9}  {info}")
        comp = ", ".join(f"{k.replace('_m3', '')} {v:.2f}" for k, v in u["components_m3"].items() if v)
        if comp:
            print(f"{'':<20}   1-sigma parts (m3): {comp}")
        for w in r.get("warnings", []):
            print(f"{'':<20}   note: {w}")
    if len(doc["results"]) > 1:
        t = doc["totals"]
        print("-" * len(head))
        print(f"{'total':<20} {_fmt(t['area_m2']):>11} {_fmt(t['cut_m3']):>12} {_fmt(t['fill_m3']):>12} "
              f"{_fmt(t['net_m3']):>12} {_fmt(t['sigma_m3']):>9} {_fmt(t['ci95_m3']):>9}")
    print("cut = material above the base, fill = void below it, net = cut - fill (grid m2 x m)")


def cmd_volume(args) -> int:
    from ..steps.volumes import run_volumes
    from ..volumes.volume import VolumeOptions

    if not 0 <= args.max_fill <= 100:
        raise GeorefError("--max-fill must be a percentage (0-100)")
    if (args.dsm is None) == (args.run is None):
        raise GeorefError("give the surface with --dsm FILE or a run folder with --run OUT_DIR (one of them)")
    if args.dsm is not None and args.surface != "dsm":
        raise GeorefError("--surface picks a run folder's raster: use it with --run (or give the DTM file to --dsm)")
    if args.run is not None:
        from pathlib import Path

        args.dsm = str(Path(args.run) / ("dtm/dtm.tif" if args.surface == "dtm" else "dense/dsm.tif"))
        if not Path(args.dsm).is_file():
            from ..errors import InputFileError

            raise InputFileError(args.dsm, "not found: run " + ("georef dtm" if args.surface == "dtm" else "georef dense")
                                 + f" {args.run} first")
    opts = VolumeOptions(percentile=args.percentile, max_fill_fraction=args.max_fill / 100.0,
                         surface_sigma_m=args.surface_sigma, accept_interpolated=args.accept_interpolated)
    doc = run_volumes(args.dsm, args.polygon, args.out, base=args.base, dsm_sigma_m=args.dsm_sigma,
                      height_bias_m=args.height_bias, correlation_length_m=args.corr_length,
                      polygon_crs=args.polygon_crs, options=opts)
    if args.json:
        json.dump(doc, sys.stdout, indent=1)
        print()
    else:
        _print_volume_table(doc)
    return 0


def cmd_change(args) -> int:
    from ..steps.volumes import run_change

    doc = run_change(args.before, args.after, args.out, args.polygon, args.stable, args.tolerance, args.align,
                     args.dsm_sigma, args.height_bias, args.corr_length, args.polygon_crs)
    if args.json:
        json.dump(doc, sys.stdout, indent=1)
        print()
        return 0
    c = doc["common"]
    u = c["uncertainty"]
    print(f"dz = after - before on the grid of {doc['after']} ({doc['crs']}, {doc['cell_size_m']:g} m)")
    print(f"common area with data: {c['valid_area_m2']:,.1f} m2 (no data: {c['nodata_area_m2']:,.1f} m2)")
    print(f"cut (removed) {c['cut_m3']:,.2f} m3, fill (placed) {c['fill_m3']:,.2f} m3, net {c['net_m3']:+,.2f} m3 "
          f"± {u['sigma_m3']:,.2f} (1 sigma), ± {u['ci95_m3']:,.2f} (95 %)")
    print(f"level of detection (95 %) {c['lod95_m']:.3f} m: beyond it cut {c['cut_beyond_lod_m3']:,.2f} m3, "
          f"fill {c['fill_beyond_lod_m3']:,.2f} m3")
    for p in doc["polygons"]:
        pu = p["uncertainty"]
        print(f"  {p['name']}: cut {p['cut_m3']:,.2f}, fill {p['fill_m3']:,.2f}, net {p['net_m3']:+,.2f} m3 "
              f"± {pu['sigma_m3']:,.2f} (1 sigma) over {p['area_m2']:,.1f} m2")
    if doc["stable"]:
        state = "OK" if doc["stable_ok"] else "FLAGGED"
        print(f"stable ground {state} (tolerance {args.tolerance:.3f} m):")
        for s in doc["stable"]:
            print(f"  {s['name']}: median dz {s['median_dz_m']:+.3f} m, median |dz| {s['median_abs_dz_m']:.3f} m, "
                  f"RMS {s['rms_dz_m']:.3f} m over {s['area_m2']:,.1f} m2 {'ok' if s['ok'] else 'MOVED'}")
    else:
        print("no stable areas given: the vertical agreement of the two surveys is not checked")
    if doc["vertical_offset_m"]:
        print(f"vertical offset removed: {doc['vertical_offset_m']:+.4f} m")
    for f in doc["flags"]:
        print(f"FLAG: {f}")
    if doc.get("dz_path"):
        print(f"-> {doc['dz_path']}, {doc.get('output')}")
    return 0


def cmd_stockpile(args) -> int:
    from ..volumes.polygons import read_polygons
    from ..volumes.stockpile_records import StockpileRegistry
    from ..volumes.uncertainty import NoiseModel

    reg = StockpileRegistry.load(args.site_dir)
    if args.action == "add":
        polys = read_polygons(args.polygon, args.polygon_crs)
        if args.name:
            if len(polys) != 1:
                raise GeorefError("--name needs a file with exactly one polygon")
            polys[0].name = args.name
        try:
            for p in polys:
                reg.add(p, args.material, args.base, replace=args.replace)
        except ValueError as exc:
            raise GeorefError(str(exc)) from None
        reg.save()
        print(f"{len(polys)} pile(s) added to {reg.path}: {', '.join(p.name for p in polys)}")
        return 0
    if args.action == "measure":
        names = args.name or list(reg.records)
        if not names:
            raise GeorefError(f"no piles in {reg.path}; add some with 'georef stockpile {args.site_dir} add'")
        try:
            noise = NoiseModel.for_dsm(args.dsm, args.dsm_sigma, args.height_bias, args.corr_length)
        except ValueError as exc:
            raise GeorefError(str(exc)) from None
        out = {}
        for n in names:
            out[n] = reg.measure(n, args.dsm, args.survey, args.date, noise=noise).to_dict()
        reg.save()
        if args.json:
            json.dump(out, sys.stdout, indent=1)
            print()
        else:
            for n, m in out.items():
                print(f"{n}: net {m['net_m3']:,.2f} m3 ± {m['sigma_m3']:,.2f} (1 sigma) (cut {m['cut_m3']:,.2f}, fill "
                      f"{m['fill_m3']:,.2f}), base {m['base_method']}")
        return 0
    if args.action == "list":
        if args.json:
            json.dump(reg.to_dict(), sys.stdout, indent=1)
            print()
            return 0
        for r in reg.records.values():
            lb = r.locked_base
            base = f"locked {lb.method} (survey {lb.survey_id or '?'}, ±{lb.sigma_m:.3f} m)" if lb else \
                f"{r.base_method}, not locked yet"
            last = r.series()[-1] if r.measurements else None
            vol = f"last {last['net_m3']:,.2f} m3 ({last['survey_date'] or last['survey_id']})" if last else "not measured"
            print(f"{r.name}: {r.material or '-'}; base {base}; {vol}; {len(r.measurements)} measurement(s)")
        return 0
    rec = reg.get(args.name)
    ser = rec.series()
    if args.json:
        json.dump({"name": rec.name, "series": ser}, sys.stdout, indent=1)
        print()
        return 0
    print(f"{rec.name} ({rec.material or 'material not given'}), base "
          f"{rec.locked_base.method if rec.locked_base else 'not locked'}")
    print(f"{'date':<12} {'survey':<16} {'net m3':>12} {'±1σ m3':>9} {'change m3':>11}")
    prev = None
    for s in ser:
        ch = "" if prev is None else f"{s['net_m3'] - prev:+,.2f}"
        print(f"{s['survey_date']:<12} {s['survey_id']:<16} {s['net_m3']:>12,.2f} {s['sigma_m3']:>9,.2f} {ch:>11}")
        prev = s["net_m3"]
    return 0
