"""`georef dense OUT_DIR [--oriented FILE] [--resolution M] [--max-image-size PX] [--workers N]`: dense point
cloud, DSM and orthophoto of a run folder's oriented images (docs/dense.md)."""

from __future__ import annotations

import argparse
import json
import sys
import time


def register(sub) -> None:
    p = sub.add_parser("dense", help="dense point cloud (LAZ), DSM and orthophoto (COG) from oriented images",
                       description="Stereo matching of overlapping image pairs, multi-view depth fusion, DSM, "
                                   "orthophoto and point cloud in the project CRS. Writes OUT_DIR/dense/.")
    p.add_argument("out_dir", help="run folder: reads OUT_DIR/oriented_images.json, writes OUT_DIR/dense/")
    p.add_argument("--oriented", metavar="FILE", help="oriented-images JSON to use instead of "
                                                      "OUT_DIR/oriented_images.json")
    p.add_argument("--resolution", type=float, metavar="M", help="DSM cell size (m; default 2 x the ground sample "
                                                                 "distance of the matched images)")
    p.add_argument("--ortho-resolution", type=float, metavar="M", help="orthophoto cell size (m; default half "
                                                                       "the DSM cell)")
    p.add_argument("--max-image-size", type=int, default=1600, metavar="PX",
                   help="match images at most this large, longer side (default 1600)")
    p.add_argument("--workers", type=int, default=2, metavar="N", help="threads (default 2)")
    p.add_argument("--sources", type=int, metavar="N", help="stereo partners per image (default 3)")
    p.add_argument("--min-views", type=int, metavar="N", help="views that must agree on a point, the image's own "
                                                              "included (default 3)")
    p.add_argument("--voxel", type=float, metavar="M", help="thin the LAZ cloud to one point per voxel of M metres")
    p.add_argument("--no-ortho", action="store_true", help="skip the orthophoto")
    p.add_argument("--ortho-jpeg", action="store_true", help="JPEG-compressed orthophoto (RGB + mask, ~6x smaller) "
                                                            "instead of lossless RGBA")
    p.add_argument("--keep-depth-maps", action="store_true", help="keep OUT_DIR/dense/depthmaps/*.npy")
    p.add_argument("--tiles", type=int, default=0, metavar="N",
                   help="spatial tiles run one after the other, memory of one tile (default 0: automatic, one run up "
                        "to 150 images; 1: one run); docs/dense.md \"Large surveys\"")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.set_defaults(func=cmd_dense)


def _progress(enabled: bool):
    state = {"stage": None, "t0": time.perf_counter()}

    def report(stage: str, done: int, total: int) -> None:
        if not enabled:
            return
        if stage != state["stage"] and state["stage"] is not None:
            print(file=sys.stderr)
        state["stage"] = stage
        frac = f" {done}/{total}" if total else ""
        print(f"\r{stage:<14}{frac:<12} {time.perf_counter() - state['t0']:6.1f} s", end="", file=sys.stderr,
              flush=True)

    def close() -> None:
        if enabled and state["stage"] is not None:
            print(file=sys.stderr)

    return report, close


def _run(out_dir, o, report) -> dict:
    """One run, or the tiles' plan, parts and merge in this process (as the step's own function does)."""
    from ..steps import dense_tiles
    from ..steps.contract import Workspace, get_spec, run_split
    from ..steps.dense import _options_dict, run_dense

    ws = Workspace(out_dir, out_dir)
    if dense_tiles.tile_count(o.tiles, dense_tiles.count_images(ws, o)) <= 1:
        return run_dense(out_dir, o, progress=report)
    return run_split(get_spec("dense"), ws, _options_dict(o), report, {})


def cmd_dense(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from ..steps.dense import DenseOptions

    o = DenseOptions(oriented_path=args.oriented, resolution_m=args.resolution,
                     ortho_resolution_m=args.ortho_resolution, max_image_size=args.max_image_size,
                     workers=args.workers, voxel_m=args.voxel, ortho=not args.no_ortho,
                     ortho_compress="JPEG" if args.ortho_jpeg else "DEFLATE", keep_depth_maps=args.keep_depth_maps,
                     tiles=max(0, args.tiles))
    if args.sources is not None:
        o.pairs = replace(o.pairs, n_sources=args.sources)
    if args.min_views is not None:
        o.fusion = replace(o.fusion, min_views=args.min_views)
    report, close = _progress(not args.quiet and not args.json)
    try:
        s = _run(args.out_dir, o, report)
    finally:
        close()
    if args.json:
        print(json.dumps(s, indent=2))
        return 0
    d = s["dsm"]
    print(f"dense: {s['n_images']} images, {s['pairs']['count']} pairs, {s['points']['written']} points "
          f"(mean {s['points']['mean_views_per_point']} views), GSD {s['gsd_m'] * 100:.1f} cm")
    print(f"DSM {d['width']} x {d['height']} cells of {s['dsm_resolution_m']:g} m, "
          f"{100 * d['hole_fraction']:.1f} % filled")
    if s.get("ortho"):
        print(f"orthophoto {s['ortho']['width']} x {s['ortho']['height']} cells of {s['ortho']['resolution_m']:g} m")
    t = s["timings_s"]
    print(f"{t['total']:.1f} s ({s['time_per_image_s']:.2f} s per image; "
          + ", ".join(f"{k} {v:.1f}" for k, v in t.items() if k != "total") + ")")
    for k, v in s["outputs"].items():
        print(f"  {k}: {v}")
    return 0
