"""The dense step in spatial tiles (contract.Split: plan, parts, merge), for large blocks and several workers.

* plan: reads the oriented images once, builds the sparse prior, fixes the output grids for the whole block
  (DSM and orthophoto cells, the block's ground footprint rounded out to whole cells) and cuts the footprint
  into ``nx x ny`` tile cores at quantiles of the images' ground centres (similar image counts). A part gets
  the images whose ground footprint meets its core grown by one footprint (the margin): every image that sees
  the core, and the fusion neighbours of those.
* part: the one-process dense step (steps/dense.py run_dense) on that subset, on the block's cells (the same
  DSM and orthophoto resolutions, cells aligned on multiples of the resolution), then only the core is kept:
  core rasters cut out of the tile's DSM / mask / support / orthophoto and the points inside the core
  (``<dense>/parts/<k>/core_*``). Memory is that of one tile's run.
* merge: the cores are disjoint and tile the block; they are written window by window into tiled temporary
  GeoTIFFs and copied to COGs by GDAL (streamed), the points appended tile by tile to one LAZ (laspy chunked
  writer): memory does not grow with the block.

Method, figures and limits: docs/dense.md "Large surveys: tiles and workers".
"""

from __future__ import annotations

import json
import math
import shutil
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import InputFileError, ProcessingError

STEP = "dense"
# tiles=0: one run while it fits in memory (~30 MB per 1600-px image: 250 images ~ 7.5 GB), then about one tile
# per 100 images (a part near 300 tile-images, ~8-9 GB). Tiles cost CPU (images near a cut are matched in both
# tiles: ~3 x one run's time on a 100-image block, docs/dense.md), so they are used only where memory needs them
AUTO_IMAGES_PER_TILE = 100
AUTO_ONE_TILE_MAX = 250
MAX_TILES = 64


def tile_count(tiles: int, n_images: int) -> int:
    """Tiles for ``n_images`` images: the option's value, or (0: auto) 1 up to 250 images, then one per ~100."""
    if tiles and tiles > 0:
        return int(min(tiles, MAX_TILES))
    if n_images <= AUTO_ONE_TILE_MAX:
        return 1
    return int(min(MAX_TILES, math.ceil(n_images / AUTO_IMAGES_PER_TILE)))


def _options(options):
    from .dense import DenseOptions

    return options if isinstance(options, DenseOptions) else DenseOptions.from_dict(dict(options or {}))


def _oriented_path(workspace, opts) -> Path:
    return Path(opts.oriented_path) if opts.oriented_path else Path(workspace.out_dir) / "oriented_images.json"


def count_images(workspace, options) -> int:
    """Images in the oriented-images file (cheap: the JSON only)."""
    path = _oriented_path(workspace, _options(options))
    try:
        return len(json.loads(path.read_text()).get("images") or [])
    except (OSError, ValueError):
        return 0   # the dense step itself names the file and its problem


def _shape(n: int, width_m: float, height_m: float) -> tuple[int, int]:
    """(nx, ny) with nx * ny >= n tiles close to square on the ground."""
    nx = max(1, min(n, int(round(math.sqrt(n * max(width_m, 1e-6) / max(height_m, 1e-6))))))
    ny = max(1, math.ceil(n / nx))
    return nx, ny


def _cuts(values: np.ndarray, lo: float, hi: float, k: int, unit: float) -> list[float]:
    """k + 1 cut positions from lo to hi: inner cuts at the quantiles of ``values``, on multiples of ``unit``."""
    inner = [round(float(np.quantile(values, j / k)) / unit) * unit for j in range(1, k)] if len(values) else []
    cuts = [lo] + [c for c in inner if lo < c < hi] + [hi]
    out = [cuts[0]]
    for c in cuts[1:]:
        if c - out[-1] >= unit - 1e-9:
            out.append(c)
    out[-1] = hi
    return out


def plan(workspace, options: dict, context: dict) -> list[dict]:
    from ..dense.camera_views import views_from_oriented
    from ..dense.orthophoto import view_footprints
    from ..dense.sparse_prior import build_sparse_prior
    from ..photo.oriented_images import read_oriented_images
    from .dense import _nice

    opts = _options(options)
    path = _oriented_path(workspace, opts)
    n_img = count_images(workspace, opts)
    n_tiles = tile_count(opts.tiles, n_img)
    if n_tiles <= 1:
        return [{"tile": "whole"}]   # one part: the step runs as one (steps/dense.py run_dense)
    oriented = read_oriented_images(path)
    if len(oriented.images) < 2:
        raise InputFileError(path, f"dense reconstruction needs at least 2 oriented images, found "
                                   f"{len(oriented.images)}")
    views = views_from_oriented(oriented, opts.max_image_size, source=path)
    prior = build_sparse_prior(views, oriented.sparse_xyz_enu_m)
    native = [prior.views[k].depth_med_m / oriented.cameras[oriented.images[k].camera_id].K()[0, 0]
              for k in range(len(views))]
    working = [prior.views[k].depth_med_m / views[k].focal_px for k in range(len(views))]
    res = float(opts.resolution_m) if opts.resolution_m else _nice(2.0 * float(np.median(working)))
    ortho_res = float(opts.ortho_resolution_m) if opts.ortho_resolution_m else _nice(res / 2.0)
    if ortho_res > res + 1e-12:
        raise ProcessingError(f"a tiled dense run needs ortho_resolution_m ({ortho_res:g}) at most resolution_m "
                              f"({res:g}); set tiles=1 for a coarser orthophoto")
    ortho_res = res / max(1, round(res / ortho_res))   # whole orthophoto cells in a DSM cell: tiles line up
    ground = np.array([p.ground_up_m for p in prior.views], float)
    ground = ground[np.isfinite(ground)]
    if not len(ground):
        raise ProcessingError("no ground height from the sparse points: cannot place the tiles")
    boxes, centres = view_footprints(views, oriented.frame, float(ground.min()), float(ground.max()))
    ok = np.all(np.isfinite(boxes), axis=1) & np.all(np.isfinite(centres), axis=1)
    if ok.sum() < 2:
        raise ProcessingError("fewer than 2 images look at the ground: cannot place the tiles")
    b = boxes[ok]
    size = np.maximum(b[:, 2] - b[:, 0], b[:, 3] - b[:, 1])
    # every image that sees the core (margin 0), and (default 0.25 footprint) those around it, so that pair
    # selection near the core, the outlier test and the hole filling see what a one-tile run sees
    margin = float(opts.tile_margin) * float(np.median(size))
    pad = 0.05 * float(np.median(size))               # the surface may stand above the highest sparse ground point
    west = math.floor((b[:, 0].min() - pad) / res) * res
    south = math.floor((b[:, 1].min() - pad) / res) * res
    east = math.ceil((b[:, 2].max() + pad) / res) * res
    north = math.ceil((b[:, 3].max() + pad) / res) * res
    nx, ny = _shape(n_tiles, east - west, north - south)
    xs = _cuts(centres[ok, 0], west, east, nx, res)
    ys = _cuts(centres[ok, 1], south, north, ny, res)
    grid = {"west": west, "north": north, "resolution_m": res, "width": int(round((east - west) / res)),
            "height": int(round((north - south) / res)), "ortho_resolution_m": ortho_res,
            "epsg": int(oriented.frame.epsg), "margin_m": round(margin, 3), "shape": [len(xs) - 1, len(ys) - 1],
            "gsd_m": round(float(np.median(native)), 4), "n_images": len(views)}
    names = np.array([im.name for im in oriented.images])
    parts = []
    for iy in range(len(ys) - 1):
        for ix in range(len(xs) - 1):
            core = [xs[ix], ys[iy], xs[ix + 1], ys[iy + 1]]
            grown = [core[0] - margin, core[1] - margin, core[2] + margin, core[3] + margin]
            sees = (ok & (boxes[:, 0] < grown[2]) & (boxes[:, 2] > grown[0]) & (boxes[:, 1] < grown[3])
                    & (boxes[:, 3] > grown[1]))
            parts.append({"tile": [ix, iy], "core": core, "outer": [ix == 0, iy == 0, ix == len(xs) - 2,
                                                                   iy == len(ys) - 2],
                          "images": names[np.where(sees, True, False)].tolist(), "grid": grid})
    return parts


def _core_window(transform, core, res) -> tuple[int, int, int, int]:
    """(col_off, row_off, width, height) of ``core`` (w, s, e, n) in a raster with ``transform``."""
    c0 = int(round((core[0] - transform.c) / res))
    r0 = int(round((transform.f - core[3]) / res))
    return c0, r0, int(round((core[2] - core[0]) / res)), int(round((core[3] - core[1]) / res))


def _read_core(path: Path, core, res, fill) -> np.ndarray:
    import rasterio
    from rasterio.windows import Window

    with rasterio.open(path) as ds:
        c0, r0, w, h = _core_window(ds.transform, core, res)
        return ds.read(window=Window(c0, r0, w, h), boundless=True, fill_value=fill)


def part(workspace, options: dict, part: dict, progress, context: dict) -> None:
    from ..dense import dsm_raster
    from ..dense.dsm_support import SUPPORT_NODATA
    from ..dense.point_cloud_io import read_point_cloud
    from ..photo.oriented_images import read_oriented_images
    from .dense import run_dense

    opts = _options(options)
    k = int(part["index"])
    pdir = workspace.part_dir(STEP, k)
    pdir.mkdir(parents=True, exist_ok=True)
    if part.get("tile") == "whole":
        raise ProcessingError("a one-tile dense plan runs as the step itself, not as a part")
    grid = part["grid"]
    n_parts = grid["shape"][0] * grid["shape"][1]
    core, res, ores = part["core"], grid["resolution_m"], grid["ortho_resolution_m"]
    report = progress or (lambda stage, done, total: None)
    label = f"tile {k + 1}/{n_parts}"
    result = {"index": k, "tile": part["tile"], "core": core, "images": len(part["images"])}
    if len(part["images"]) < 2:
        result["skipped"] = "fewer than 2 images see the tile"
        (pdir / "core_summary.json").write_text(json.dumps(result, indent=1))
        report(f"{label}: done", 1, 1)
        return
    path = _oriented_path(workspace, opts)
    oriented = read_oriented_images(path)
    wanted = set(part["images"])
    subset = replace(oriented, images=[im for im in oriented.images if im.name in wanted])
    sub_path = subset.write(pdir / "oriented_images.json")
    sub_opts = replace(opts, oriented_path=str(sub_path), resolution_m=res, ortho_resolution_m=ores,
                       keep_depth_maps=False, tiles=1)
    t0 = time.perf_counter()
    try:
        summary = run_dense(pdir, sub_opts, lambda stage, done, total: report(f"{label}: {stage}", done, total))
    except ProcessingError as exc:   # a tile with too little overlap: its core stays empty, the others go on
        result["skipped"] = str(exc)
        summary = None
    d = pdir / "dense"
    if summary is not None:
        import rasterio

        with rasterio.open(d / "dsm.tif") as ds:
            if abs(ds.transform.a - res) > 1e-9:
                raise ProcessingError(f"{label}: DSM cell {ds.transform.a} m, the plan's {res} m")
        layers = {"dsm": (dsm_raster.NODATA, "float32"), "dsm_filled_mask": (dsm_raster.MASK_NODATA, "uint8"),
                  "dsm_support": (SUPPORT_NODATA, "uint8")}
        arrays = {name: _read_core(d / f"{name}.tif", core, res, fill).astype(dt)
                  for name, (fill, dt) in layers.items()}
        if sub_opts.ortho:
            arrays["ortho"] = _read_core(d / "ortho.tif", core, ores, 0).astype(np.uint8)
        np.savez(pdir / "core_rasters.npz", **arrays)
        xyz, rgb, _, las = read_point_cloud(d / "points.laz")
        outer = part.get("outer") or [False] * 4
        inside = np.ones(len(xyz), bool)
        for axis, lo_or_hi, bound, open_side in ((0, 0, core[0], outer[0]), (1, 0, core[1], outer[1]),
                                                 (0, 1, core[2], outer[2]), (1, 1, core[3], outer[3])):
            if not open_side:
                inside &= (xyz[:, axis] >= bound) if lo_or_hi == 0 else (xyz[:, axis] < bound)
        np.savez(pdir / "core_points.npz", xyz=xyz[inside], rgb=rgb[inside],
                 n_views=np.asarray(las.user_data)[inside])
        result.update(summary={k2: summary.get(k2) for k2 in (
            "timings_s", "pairs", "points", "dsm_vertical_rmse_m", "dsm_smoothing_radius_m", "matching_image_size_px",
            "depth_map_size_px", "gsd_m", "matching_gsd_m", "sparse_prior", "rolling_shutter", "ortho",
            "coarse_pass", "depth_map_thread_s_per_image")},
            core_points=int(inside.sum()))
        shutil.rmtree(d, ignore_errors=True)   # the tile's full rasters: only its core is kept
    result["seconds"] = round(time.perf_counter() - t0, 3)
    (pdir / "core_summary.json").write_text(json.dumps(result, indent=1))


def _tiled_profile(width, height, count, dtype, transform, epsg, nodata):
    p = {"driver": "GTiff", "width": width, "height": height, "count": count, "dtype": dtype,
         "crs": f"EPSG:{int(epsg)}", "transform": transform, "tiled": True, "blockxsize": 512, "blockysize": 512,
         "compress": "NONE", "BIGTIFF": "IF_SAFER"}
    if nodata is not None:
        p["nodata"] = nodata
    return p


def merge(workspace, options: dict, parts: list[dict], progress, context: dict) -> dict:
    import laspy
    import pyproj
    import rasterio
    from rasterio.windows import Window

    from ..dense import cog_writer, dsm_raster
    from ..dense.cog_writer import RGBA, geotiff_to_cog
    from ..dense.dsm_raster import RasterGrid
    from ..dense.dsm_support import SUPPORT_NODATA
    from .dense import DENSE_DIR, _check_height_bias, _options_dict

    opts = _options(options)
    t0 = time.perf_counter()
    report = progress or (lambda stage, done, total: None)
    out = Path(workspace.out_dir) / DENSE_DIR
    out.mkdir(parents=True, exist_ok=True)
    g = parts[0]["grid"]
    res, ores = g["resolution_m"], g["ortho_resolution_m"]
    dgrid = RasterGrid(g["west"], g["north"], res, g["width"], g["height"])
    ogrid = dgrid.with_resolution(ores)
    epsg = g["epsg"]
    results = []
    for p in parts:
        f = workspace.part_dir(STEP, p["index"]) / "core_summary.json"
        if not f.is_file():
            raise ProcessingError(f"part {p['index']} of the dense step left no result ({f.name} missing)")
        results.append(json.loads(f.read_text()))
    done = [r for r in results if "summary" in r]
    if not done:
        raise ProcessingError("no tile of the dense step gave a surface: " +
                              "; ".join(f"tile {r['index'] + 1}: {r.get('skipped')}" for r in results))
    layers = {"dsm": (1, "float32", dsm_raster.NODATA, dgrid, res), "dsm_filled_mask": (1, "uint8",
              dsm_raster.MASK_NODATA, dgrid, res), "dsm_support": (1, "uint8", SUPPORT_NODATA, dgrid, res)}
    if opts.ortho:
        layers["ortho"] = (4, "uint8", None, ogrid, ores)
    tmp = {name: out / f".{name}.merge.tif" for name in layers}
    stats = {"measured": 0, "filled": 0, "coarse": 0, "ortho_covered": 0, "cnt_weight": 0.0}
    dsts = {}
    try:
        for name, (count, dt, nd, gr, r) in layers.items():
            dsts[name] = rasterio.open(tmp[name], "w", **_tiled_profile(gr.width, gr.height, count, dt,
                                                                         gr.transform, epsg, nd))
        for n_done, (p, r) in enumerate(zip(parts, results), start=1):
            pdir = workspace.part_dir(STEP, p["index"])
            arrays = dict(np.load(pdir / "core_rasters.npz")) if "summary" in r else {}
            for name, (count, dt, nd, gr, rr) in layers.items():
                c0, r0, w, h = _core_window(gr.transform, p["core"], rr)
                a = arrays.get(name)
                if a is None:
                    a = np.full((count, h, w), 0 if nd is None else nd, dt)
                dsts[name].write(a, window=Window(c0, r0, w, h))
                if name == "dsm_filled_mask":
                    stats["measured"] += int(np.count_nonzero(a == dsm_raster.MASK_MEASURED))
                    stats["filled"] += int(np.count_nonzero(a == dsm_raster.MASK_FILLED))
                    stats["coarse"] += int(np.count_nonzero(a == dsm_raster.MASK_COARSE))
                if name == "ortho":
                    stats["ortho_covered"] += int(np.count_nonzero(a[3] > 0))
            del arrays
            report("merging tiles", n_done, len(parts))
        dsts["dsm"].set_band_description(1, "ellipsoidal height")
        dsts["dsm"].units = ["metre"]
        dsts["dsm"].update_tags(**cog_writer.HEIGHT_TAGS, RESOLUTION_M=f"{res:g}", TILES=str(len(parts)))
        dsts["dsm_filled_mask"].set_band_description(1, "0 measured, 2 measured at coarse resolution, 1 filled, "
                                                        "255 no data")
        dsts["dsm_filled_mask"].update_tags(VALUES="0 measured, 2 measured at coarse resolution (coarse pass only), "
                                                   "1 filled (interpolated), 255 no data")
        dsts["dsm_support"].set_band_description(1, "views agreeing on the cell (0: interpolated, no support)")
        dsts["dsm_support"].update_tags(VALUES="median number of views that agreed on the cell's points; 0 "
                                               "interpolated (no measurement); 255 no data")
        if "ortho" in dsts:
            dsts["ortho"].colorinterp = RGBA
            dsts["ortho"].update_tags(PRODUCER="georef dense step", RESOLUTION_M=f"{ores:g}")
    finally:
        for ds in dsts.values():
            ds.close()
    try:
        report("writing COGs", 0, len(layers))
        for n_done, name in enumerate(layers, start=1):
            comp = opts.ortho_compress.upper() if name == "ortho" else "DEFLATE"
            geotiff_to_cog(tmp[name], out / f"{name}.tif", compress=comp,
                           overview_resampling="AVERAGE" if name in ("dsm", "ortho") else "NEAREST")
            report("writing COGs", n_done, len(layers))
    finally:
        for f in tmp.values():
            f.unlink(missing_ok=True)

    # the points, tile by tile (one tile's points in memory)
    header = laspy.LasHeader(point_format=7, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([math.floor(g["west"]), math.floor(g["north"] - g["height"] * res), 0.0])
    header.add_crs(pyproj.CRS.from_epsg(int(epsg)).to_3d())
    header.system_identifier = "georef dense"
    header.generating_software = "georef"
    las_tmp = out / "points.part.laz"
    n_points, n_views_sum = 0, 0.0
    with laspy.open(str(las_tmp), mode="w", header=header, do_compress=True) as writer:
        for p, r in zip(parts, results):
            if "summary" not in r:
                continue
            with np.load(workspace.part_dir(STEP, p["index"]) / "core_points.npz") as z:
                xyz, rgb, nv = z["xyz"], z["rgb"], z["n_views"]
            if not len(xyz):
                continue
            rec = laspy.ScaleAwarePointRecord.zeros(len(xyz), header=header)
            rec.x, rec.y, rec.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
            rgb16 = rgb.astype(np.uint16) * 257
            rec.red, rec.green, rec.blue = rgb16[:, 0], rgb16[:, 1], rgb16[:, 2]
            rec.classification = np.ones(len(xyz), np.uint8)
            rec.user_data = nv.astype(np.uint8)
            writer.write_points(rec)
            n_points += len(xyz)
            n_views_sum += float(nv.sum())
    las_tmp.replace(out / "points.laz")

    sums = [r["summary"] for r in done]
    timings: dict[str, float] = {}
    for s in sums:
        for k, v in (s.get("timings_s") or {}).items():
            timings[k] = round(timings.get(k, 0.0) + v, 3)
    timings["merge"] = round(time.perf_counter() - t0, 3)
    w_pts = np.array([max(1, (s.get("points") or {}).get("written") or 1) for s in sums], float)
    rm = np.array([s.get("dsm_vertical_rmse_m") or np.nan for s in sums], float)
    okr = np.isfinite(rm)
    rmse = float(np.sqrt(np.sum(w_pts[okr] * rm[okr] ** 2) / np.sum(w_pts[okr]))) if okr.any() else None
    measured, filled, coarse = stats["measured"], stats["filled"], stats["coarse"]
    first = sums[0]
    check_bias = _check_height_bias(Path(workspace.out_dir) / "residuals.json")
    tile_images = sum(r["images"] for r in results)
    summary = {
        "oriented_images": str(_oriented_path(workspace, opts)),
        "project_crs": f"EPSG:{epsg}",
        "heights": "ellipsoidal (WGS84)",
        "n_images": g["n_images"],
        "matching_image_size_px": first.get("matching_image_size_px"),
        "depth_map_size_px": first.get("depth_map_size_px"),
        "gsd_m": g["gsd_m"],
        "matching_gsd_m": first.get("matching_gsd_m"),
        "dsm_resolution_m": res,
        "tiles": {"count": len(parts), "shape": g["shape"], "margin_m": g["margin_m"],
                  "images_processed": tile_images, "overlap_factor": round(tile_images / g["n_images"], 3),
                  "per_tile": [{"tile": r["tile"], "core": r["core"], "images": r["images"],
                                "seconds": r.get("seconds"), "points": r.get("core_points"),
                                **({"skipped": r["skipped"]} if r.get("skipped") else {})} for r in results]},
        "sparse_prior": first.get("sparse_prior"),
        "rolling_shutter": first.get("rolling_shutter"),
        "pairs": {"count": sum((s.get("pairs") or {}).get("count", 0) for s in sums),
                  "rectified": sum((s.get("pairs") or {}).get("rectified", 0) for s in sums)},
        "points": {"fused": sum((s.get("points") or {}).get("fused", 0) for s in sums),
                   "outliers_removed": sum((s.get("points") or {}).get("outliers_removed", 0) for s in sums),
                   "written": int(n_points),
                   "mean_views_per_point": round(n_views_sum / n_points, 3) if n_points else None},
        "dsm": {"width": dgrid.width, "height": dgrid.height, "measured_cells": measured, "filled_cells": filled,
                "coarse_cells": coarse, "hole_fraction": round(filled / max(1, measured + filled + coarse), 5),
                "bounds": [dgrid.west, dgrid.north - dgrid.height * res, dgrid.west + dgrid.width * res,
                           dgrid.north]},
        "ortho": ({"resolution_m": ores, "width": ogrid.width, "height": ogrid.height,
                   "coverage_fraction": stats["ortho_covered"] / max(1, ogrid.width * ogrid.height),
                   "radiometry": "estimated per tile (its images and margin)"} if opts.ortho else None),
        "dsm_vertical_rmse_m": round(rmse, 4) if rmse is not None else None,
        "dsm_smoothing_radius_m": max(s.get("dsm_smoothing_radius_m") or 0.0 for s in sums),
        "dsm_vertical_rmse_source": "internal estimate: agreement of the views fused into each point (random "
                                    "part only; the georeferencing bias is not in it), RMS over the tiles",
        **({"check_height_bias_m": round(check_bias, 4)} if check_bias is not None else {}),
        "timings_s": timings,
        "time_per_image_s": round(sum(r.get("seconds") or 0.0 for r in results) / g["n_images"] +
                                  timings["merge"] / g["n_images"], 3),
        "workers": opts.workers,
        "outputs": {k: str(out / f) for k, f in (("points", "points.laz"), ("dsm", "dsm.tif"),
                                                ("dsm_filled_mask", "dsm_filled_mask.tif"),
                                                ("dsm_support", "dsm_support.tif"), ("ortho", "ortho.tif"))
                    if k != "ortho" or opts.ortho},
        "options": _options_dict(opts),
    }
    (out / "dense_summary.json").write_text(json.dumps(summary, indent=2))
    if not opts.keep_depth_maps:
        shutil.rmtree(out / "parts", ignore_errors=True)
    report("done", 1, 1)
    return summary
