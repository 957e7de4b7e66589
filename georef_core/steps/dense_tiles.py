"""The dense step in spatial tiles (contract.Split: plan, parts in two phases, merge), for large blocks and
several workers.

* plan: reads the oriented images once, builds the sparse prior, fixes the output grids for the whole block
  (DSM and orthophoto cells, the block's ground footprint rounded out to whole cells) and cuts the footprint
  into ``nx x ny`` tile cores at quantiles of the images' ground centres (similar image counts). It also
  chooses, once for the block and as a one run chooses them, every image's stereo partners and fusion
  neighbours. Two kinds of parts follow:
* depth parts (phase 1, one per tile's image group: the images whose ground centre lies in the core): the
  fine and coarse depth maps of their images, each image's computed once for the whole block
  (steps/dense.py run_depth_maps), in ``<dense>/parts/<k>/depth/``;
* the radiometry part (phase 1b, after every depth part; when the orthophoto is compensated): the block's
  orthophoto gains and vignetting solved once from the observations the depth parts gathered from their depth
  maps (dense/block_radiometry.py), each first tested against its view's own depth map (every image's exists
  by then; read one at a time), ``<dense>/parts/<k>/radiometry.json``; every tile mosaics with it;
* tiles (phase 2, ``"after"`` the depth parts whose maps they read and the radiometry part): the images whose ground footprint meets
  the core grown by ``tile_margin`` footprints, fused from those depth maps with their block neighbours
  confirming (run_dense with a BlockDepth: no stereo matching), then outliers, DSM and orthophoto on the
  block's cells; only the core is kept: core rasters cut out of the tile's DSM / mask / support / orthophoto
  and the points inside the core (``<dense>/parts/<k>/core_*``). Memory is that of one tile's fusion.
* merge: the cores are disjoint and tile the block; they are written window by window into tiled temporary
  GeoTIFFs and copied to COGs by GDAL (streamed), the points appended tile by tile to one LAZ (the streamed
  writer of dense/point_cloud_io.py): memory does not grow with the block. Without the block's radiometry
  (not solved, or BLOCK_RADIOMETRY off) each tile estimated its own and the merge puts the tiles' gains on one
  gauge from the images they share (harmonise_tile_gains).

Each reader is given only the parts' files it reads (contract.Split.merge_reads, a descriptor's "reads").

Method, figures and limits: docs/dense.md "Large surveys: tiles and workers".
"""

from __future__ import annotations

import json
import math
import shutil
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from ..errors import InputFileError, ProcessingError

STEP = "dense"
# tiles=0: one run while it fits in memory (~30 MB per 1600-px image: 250 images ~ 7.5 GB), then about one tile
# per 100 images. Tiles still cost some CPU (each image is matched once, but the images near a cut are fused and
# mosaicked in both tiles: docs/dense.md), so they are used only where memory needs them
AUTO_IMAGES_PER_TILE = 100
AUTO_ONE_TILE_MAX = 250
MAX_TILES = 64
# a tile's orthophoto covers its core and this many orthophoto cells around it (more than the blending's reach,
# 1.5 x 2^levels cells: the seams and pyramids near the cut see the same cells on both sides)
ORTHO_BAND_CELLS = 64
# the orthophoto's radiometry solved once for the block (a third phase, dense/block_radiometry.py); False: each tile
# estimates its own and the merge harmonises their gauges (the earlier way, kept for comparison: bench)
BLOCK_RADIOMETRY = True


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
    from ..dense.depth_fusion import fusion_neighbours
    from ..dense.orthophoto import view_footprints
    from ..dense.pair_selection import select_sources
    from ..dense.sparse_prior import build_sparse_prior
    from ..photo.oriented_images import read_oriented_images
    from .dense import _nice

    opts = _options(options)
    path = _oriented_path(workspace, opts)
    n_img = count_images(workspace, opts)
    n_tiles = tile_count(opts.tiles, n_img)
    if n_tiles <= 1:
        return [{"tile": "whole"}]   # one part: the step runs as one (steps/dense.py run_dense)
    t_plan = [time.perf_counter()]
    plan_s = {}   # the plan's serial stages (wall seconds), in the grid: the benchmark prints them

    def lap(name):
        t_plan.append(time.perf_counter())
        plan_s[name] = round(t_plan[-1] - t_plan[-2], 3)

    oriented = read_oriented_images(path)
    if len(oriented.images) < 2:
        raise InputFileError(path, f"dense reconstruction needs at least 2 oriented images, found "
                                   f"{len(oriented.images)}")
    views = views_from_oriented(oriented, opts.max_image_size, source=path)
    lap("read")
    prior = build_sparse_prior(views, oriented.sparse_xyz_enu_m)
    lap("sparse_prior")
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
    # the block's pairs, fusion neighbours and prior, chosen once as a one run chooses them: each image's depth
    # map is computed once (phase 1: its group's depth part), the tiles fuse them (phase 2)
    views = [replace(v, scene_depth_m=prior.views[k].depth_med_m) if v.rolling_shutter else v
             for k, v in enumerate(views)]
    lap("footprints")
    sources = select_sources(views, prior, opts.pairs)
    lap("pairs")
    if not any(sources):
        raise ProcessingError("no image pair overlaps enough for stereo matching (check the orientations and the "
                              "overlap of the flight)")
    matched = [i for i in range(len(views)) if sources[i]]
    neighbours = fusion_neighbours(views, matched, [p.ground_up_m for p in prior.views],
                                   [p.depth_hi_m for p in prior.views], opts.fusion)
    lap("neighbours")
    # exact values (JSON keeps a float's digits): the depth parts search the disparities a one run searches
    prior_of = {names[k]: [float(v.depth_lo_m), float(v.depth_med_m), float(v.depth_hi_m), float(v.ground_up_m),
                           int(v.n_points)] for k, v in enumerate(prior.views)}
    stem = {names[k]: f"{k:05d}" for k in range(len(names))}
    grid.update(sparse_source=prior.source, sparse_points=int(len(prior.xyz_enu_m)))
    # depth groups: the images whose ground centre lies in a tile's core (no centre: the nearest core's)
    cx = np.where(ok, centres[:, 0], np.nanmedian(centres[ok, 0]))
    cy = np.where(ok, centres[:, 1], np.nanmedian(centres[ok, 1]))
    gx = np.clip(np.searchsorted(xs, cx, side="right") - 1, 0, len(xs) - 2)
    gy = np.clip(np.searchsorted(ys, cy, side="right") - 1, 0, len(ys) - 2)
    depth_parts, owner = [], {}
    for iy in range(len(ys) - 1):
        for ix in range(len(xs) - 1):
            group = [i for i in matched if gx[i] == ix and gy[i] == iy]
            if not group:
                continue
            for i in group:
                owner[names[i]] = len(depth_parts)
            need = sorted(set(group) | {p.src for i in group for p in sources[i]})
            depth_parts.append({"phase": "depth", "group": [ix, iy], "images": [names[i] for i in group],
                                "sources": {names[i]: [_pair_dict(p, names) for p in sources[i]] for i in group},
                                "prior": {names[i]: prior_of[names[i]] for i in need},
                                "stems": {names[i]: stem[names[i]] for i in group}, "grid": grid})
    grid["depth_parts"] = len(depth_parts)
    radiometry = []   # phase 1b: the block's orthophoto radiometry, once, from every depth part's observations
    if BLOCK_RADIOMETRY and opts.ortho and opts.ortho_options.compensate:
        # it also reads every image's fine depth map (one at a time): each observation's occlusion test in its
        # view's own map, which only exists for the whole block once every depth part has run
        radiometry = [{"phase": "radiometry", "after": list(range(len(depth_parts))),
                       "depth": {n: [owner[n], stem[n]] for n in sorted(owner)},
                       "reads": ["depth_summary.json", "radiometry_obs.npz"]
                       + sorted({f"depth/{stem[n]}.npy" for n in owner}), "grid": grid}]
    grid["first_tile"] = len(depth_parts) + len(radiometry)
    grid["plan_s"] = plan_s
    rad_after = [len(depth_parts)] if radiometry else []
    parts = []
    for iy in range(len(ys) - 1):
        for ix in range(len(xs) - 1):
            core = [xs[ix], ys[iy], xs[ix + 1], ys[iy + 1]]
            grown = [core[0] - margin, core[1] - margin, core[2] + margin, core[3] + margin]
            sees = (ok & (boxes[:, 0] < grown[2]) & (boxes[:, 2] > grown[0]) & (boxes[:, 1] < grown[3])
                    & (boxes[:, 3] > grown[1]))
            refs = [int(i) for i in np.flatnonzero(sees)]
            # the tile's images and their fusion neighbours (which confirm the tile's points, as in a one run)
            needs = sorted(set(refs) | {j for i in refs for j in neighbours.get(i, [])})
            with_depth = [names[i] for i in needs if names[i] in owner]
            parts.append({"phase": "fuse", "tile": [ix, iy], "core": core,
                          "outer": [ix == 0, iy == 0, ix == len(xs) - 2, iy == len(ys) - 2],
                          "images": [names[i] for i in refs], "needs": [names[i] for i in needs],
                          "depth": {n: [owner[n], stem[n]] for n in with_depth},
                          "after": sorted({owner[n] for n in with_depth} | set(rad_after)),
                          # of those parts' files: their summaries, these images' depth maps, the block's radiometry
                          "reads": ["depth_summary.json", "radiometry.json"] + [
                              f"depth/{stem[n]}{suffix}" for n in with_depth for suffix in (".npy", ".coarse.npy")],
                          "prior": {names[i]: prior_of[names[i]] for i in needs},
                          "neighbours": {names[i]: [names[j] for j in neighbours.get(i, [])] for i in refs},
                          "grid": grid})
    lap("parts")   # the tiles' descriptors (filled in: every part shares this grid)
    return depth_parts + radiometry + parts


def _pair_dict(pair, names) -> dict:
    """A StereoPair as a part descriptor carries it (JSON; its partner by name, its reference implied)."""
    d = {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in asdict(pair).items() if k != "ref"}
    d["src"] = str(names[pair.src])
    return d


def _grown(box, d: float) -> list[float]:
    return [box[0] - d, box[1] - d, box[2] + d, box[3] + d]


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
    from ..dense.sparse_prior import ViewDepth
    from ..photo.oriented_images import read_oriented_images
    from .dense import BlockDepth, run_dense

    opts = _options(options)
    k = int(part["index"])
    pdir = workspace.part_dir(STEP, k)
    pdir.mkdir(parents=True, exist_ok=True)
    if part.get("tile") == "whole":
        raise ProcessingError("a one-tile dense plan runs as the step itself, not as a part")
    if part.get("phase") == "depth":
        return _depth_part(workspace, opts, part, progress)
    if part.get("phase") == "radiometry":
        return _radiometry_part(workspace, opts, part, progress)
    grid = part["grid"]
    n_parts = grid["shape"][0] * grid["shape"][1]
    core, res, ores = part["core"], grid["resolution_m"], grid["ortho_resolution_m"]
    report = progress or (lambda stage, done, total: None)
    label = f"tile {k - int(grid.get('first_tile', grid.get('depth_parts', 0))) + 1}/{n_parts}"
    result = {"index": k, "tile": part["tile"], "core": core, "images": len(part["images"])}
    if len(part["images"]) < 2:
        result["skipped"] = "fewer than 2 images see the tile"
        (pdir / "core_summary.json").write_text(json.dumps(result, indent=1))
        report(f"{label}: done", 1, 1)
        return
    path = _oriented_path(workspace, opts)
    oriented = read_oriented_images(path)
    wanted = set(part.get("needs") or part["images"])
    subset = replace(oriented, images=[im for im in oriented.images if im.name in wanted])
    sub_path = subset.write(pdir / "oriented_images.json")
    sub_opts = replace(opts, oriented_path=str(sub_path), resolution_m=res, ortho_resolution_m=ores,
                       keep_depth_maps=False, tiles=1)
    # the depth maps the depth parts computed (their folders: the parts named in "after")
    local = {im.name: j for j, im in enumerate(subset.images)}
    depth = part.get("depth") or {}
    folder = {n: workspace.part_dir(STEP, int(owner)) / "depth" for n, (owner, _) in depth.items()}
    for owner in sorted({int(o) for o, _ in depth.values()}):
        if not (workspace.part_dir(STEP, owner) / "depth_summary.json").is_file():
            raise ProcessingError(f"{label}: depth part {owner} left no result (depth_summary.json missing): the "
                                  "depth parts run before the tiles")
    # the block's orthophoto radiometry (the radiometry part among "after"), when it was solved
    block_model = None
    for j in part.get("after") or []:
        f = workspace.part_dir(STEP, int(j)) / "radiometry.json"
        if f.is_file():
            from ..dense.block_radiometry import read_block_model

            block_model = read_block_model(f)
    block = BlockDepth(
        radiometry=block_model,
        prior_views=[ViewDepth(*[float(x) for x in part["prior"][im.name][:4]], int(part["prior"][im.name][4]))
                     for im in subset.images],
        sparse_source=grid.get("sparse_source", "oriented images"),
        depth_paths={local[n]: folder[n] / f"{stem}.npy" for n, (_, stem) in depth.items()},
        coarse_paths={local[n]: folder[n] / f"{stem}.coarse.npy" for n, (_, stem) in depth.items()},
        references=sorted(local[n] for n in part["images"]),
        neighbours={local[n]: [local[j] for j in nb if j in local] for n, nb in (part.get("neighbours") or {}).items()},
        # the orthophoto over the core and a band (its blending runs on across the cut), not the tile's extent
        ortho_window=tuple(_grown(core, ORTHO_BAND_CELLS * ores)),
        # the points fused: the core and its margin, at least the hole filling's reach and a few cells more (the
        # outlier test and the filling near the core see what a one run sees)
        keep_box=tuple(_grown(core, max(float(grid["margin_m"]), 2.0 * opts.max_gap_m) + 8 * res)))
    t0 = time.perf_counter()
    try:
        summary = run_dense(pdir, sub_opts, lambda stage, done, total: report(f"{label}: {stage}", done, total),
                            block=block)
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


def _depth_part(workspace, opts, part: dict, progress) -> None:
    """Phase 1: the depth maps (fine and coarse) of the part's image group, each image's once for the block,
    into ``parts/<k>/depth/<stem>.npy``; what was computed in ``depth_summary.json``."""
    from .dense import run_depth_maps

    k = int(part["index"])
    pdir = workspace.part_dir(STEP, k)
    n = int(part["grid"].get("depth_parts", 1))
    label = f"depth maps {k + 1}/{n}"
    report = progress or (lambda stage, done, total: None)
    t0 = time.perf_counter()
    from ..dense.block_radiometry import OBS_FILE

    observe = BLOCK_RADIOMETRY and opts.ortho and opts.ortho_options.compensate
    result = run_depth_maps(_oriented_path(workspace, opts), part["images"], part["sources"], part["prior"],
                            part["stems"], pdir / "depth", replace(opts, tiles=1),
                            lambda stage, done, total: report(f"{label}: {stage}", done, total),
                            radiometry_obs=pdir / OBS_FILE if observe else None)
    result.update(index=k, phase="depth", group=part["group"], seconds=round(time.perf_counter() - t0, 3))
    (pdir / "depth_summary.json").write_text(json.dumps(result, indent=1))


def _radiometry_part(workspace, opts, part: dict, progress) -> None:
    """Phase 1b: the block's orthophoto radiometry (gains per image, vignetting per camera) solved once from the
    depth parts' observations (``radiometry.json``; block_radiometry.py); every tile mosaics with it."""
    from ..dense.block_radiometry import MODEL_FILE, OBS_FILE, solve_block

    k = int(part["index"])
    report = progress or (lambda stage, done, total: None)
    report("orthophoto radiometry", 0, 1)
    files = [workspace.part_dir(STEP, int(j)) / OBS_FILE for j in part.get("after") or []]
    missing = [f for f in files if not f.is_file()]
    if missing:
        raise ProcessingError(f"orthophoto radiometry: depth part {missing[0].parent.name} left no "
                              f"{OBS_FILE}: the depth parts run before it")
    result = solve_block(files, vignetting=opts.ortho_options.compensate_vignetting,
                         depth_map_of=_depth_map_reader(workspace, opts, part))
    result["index"] = k
    (workspace.part_dir(STEP, k) / MODEL_FILE).write_text(json.dumps(result, indent=1))
    report("orthophoto radiometry", 1, 1)


def _depth_map_reader(workspace, opts, part: dict):
    """name -> (the image's depth-map grid, its fine depth map) or None (no map: the plan named none for it, or
    its depth part left none): the radiometry part's occlusion test reads the maps through it, one at a time."""
    depth = part.get("depth") or {}
    if not depth:
        return None
    from ..dense.camera_views import views_from_oriented
    from ..photo.oriented_images import read_oriented_images
    from .dense import depth_grid

    path = _oriented_path(workspace, opts)
    oriented = read_oriented_images(path)
    subset = replace(oriented, images=[im for im in oriented.images if im.name in depth])
    views = {v.name: v for v in views_from_oriented(subset, opts.max_image_size, source=path)}

    def read(name: str):
        if name not in depth or name not in views:
            return None
        f = workspace.part_dir(STEP, int(depth[name][0])) / "depth" / f"{depth[name][1]}.npy"
        if not f.is_file():
            return None
        d = np.load(f)
        if d.ndim != 2:
            raise ProcessingError(f"orthophoto radiometry: depth map {f} is not a 2-D array (shape {d.shape})")
        v = depth_grid(views[name], opts)
        if (v.height, v.width) != d.shape:   # the grid the map was computed on (same view, its size)
            v = v.scaled_to(d.shape[1], d.shape[0])
        return v, d

    return read


def harmonise_tile_gains(tile_gains: list[dict]) -> tuple[np.ndarray, dict]:
    """Per-tile colour factors that put the tiles' orthophotos on one radiometry. Each tile estimated its
    images' log gains with its own gauge (their mean held at 0, ortho_radiometry.py), so an image seen by two
    tiles has log gains differing by the tiles' gauges: a_k(t) = a_k + c_t. The c_t (per channel, their mean
    0) are fitted by weighted least squares over the images shared by tiles (weight: the observations the
    tile's estimate of that image rests on); a tile's corrected colours (divided by exp(a_k(t))) become the
    block's by multiplying them by exp(c_t). ``tile_gains``: per tile {image: [3 log gains] or [3 log gains,
    observations]} (empty: no estimate). Returns (n_tiles, 3) factors (1 for a tile sharing no image) and
    figures: the weighted RMS of the shared images' gains about their per-image mean, before (c = 0) and
    after the fit."""
    n = len(tile_gains)
    seen: dict[str, list[int]] = {}
    for t, g in enumerate(tile_gains):
        for name in g or {}:
            seen.setdefault(name, []).append(t)
    shared = sorted(k for k, ts in seen.items() if len(ts) > 1)
    linked = sorted({t for k in shared for t in seen[k]})
    factors = np.ones((n, 3))
    if len(linked) < 2:
        return factors, {"shared_images": len(shared), "tiles_linked": len(linked)}
    col = {t: j for j, t in enumerate(linked)}
    nl = len(linked)
    rows, obs, w = [], [], []
    for i, k in enumerate(shared):
        for t in seen[k]:
            r = np.zeros(nl + len(shared))
            r[col[t]] = 1.0
            r[nl + i] = 1.0
            rows.append(r)
            v = tile_gains[t][k]
            obs.append(v[:3])
            w.append(max(float(v[3]), 1e-9) if len(v) > 3 else 1.0)
    A, b, sw = np.array(rows), np.asarray(obs, float), np.sqrt(np.array(w))
    gauge = np.zeros(nl + len(shared))
    gauge[:nl] = 10.0 * sw.max()
    x, *_ = np.linalg.lstsq(np.vstack([A * sw[:, None], gauge]), np.vstack([b * sw[:, None], np.zeros((1, 3))]),
                            rcond=None)
    c = x[:nl]                                              # (tiles linked, 3)
    # before: the same images' gains about their weighted mean per image (no tile offsets)
    a0 = np.array([np.average(b[A[:, nl + i] > 0], axis=0, weights=np.array(w)[A[:, nl + i] > 0])
                   for i in range(len(shared))])
    r0 = b - A[:, nl:] @ a0
    r1 = b - A @ x
    W = np.array(w)[:, None]
    for t in linked:
        factors[t] = np.exp(c[col[t]])
    return factors, {"shared_images": len(shared), "tiles_linked": len(linked),
                     "tile_offsets_percent": [[round(100 * float(v), 3) for v in c[col[t]]] if t in col else None
                                              for t in range(n)],
                     "residual_rms_percent_before": round(100 * float(np.sqrt(np.sum(W * r0 ** 2) / W.sum() / 3)), 3),
                     "residual_rms_percent": round(100 * float(np.sqrt(np.sum(W * r1 ** 2) / W.sum() / 3)), 3)}


def _scale_colours(rgba: np.ndarray, factor) -> np.ndarray:
    """An RGBA (4, h, w) uint8 core with its colours multiplied by ``factor`` (3,), where it has data."""
    out = rgba.copy()
    rgb = rgba[:3].astype(np.float32) * np.asarray(factor, np.float32)[:, None, None]
    out[:3] = np.where(rgba[3] > 0, np.clip(np.rint(rgb), 0, 255), rgba[:3]).astype(np.uint8)
    return out


def _tiled_profile(width, height, count, dtype, transform, epsg, nodata):
    p = {"driver": "GTiff", "width": width, "height": height, "count": count, "dtype": dtype,
         "crs": f"EPSG:{int(epsg)}", "transform": transform, "tiled": True, "blockxsize": 512, "blockysize": 512,
         "compress": "NONE", "BIGTIFF": "IF_SAFER"}
    if nodata is not None:
        p["nodata"] = nodata
    return p


def merge(workspace, options: dict, parts: list[dict], progress, context: dict) -> dict:
    import rasterio
    from rasterio.windows import Window

    from ..dense import cog_writer, dsm_raster
    from ..dense.cog_writer import RGBA, geotiff_to_cog
    from ..dense.dsm_raster import RasterGrid
    from ..dense.dsm_support import CAUSE_VALUES, SUPPORT_NODATA, cause_counts
    from ..dense.point_cloud_io import dense_cloud_header, dense_points, point_cloud_writer
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
    # phase 1 (depth maps, each image's once) and phase 2 (the tiles, fused from them)
    depth_results = []
    block_rad = None
    for p in parts:
        if p.get("phase") in ("depth", "radiometry"):
            name = "depth_summary.json" if p["phase"] == "depth" else "radiometry.json"
            f = workspace.part_dir(STEP, p["index"]) / name
            if not f.is_file():
                raise ProcessingError(f"part {p['index']} of the dense step left no result ({f.name} missing)")
            if p["phase"] == "depth":
                depth_results.append(json.loads(f.read_text()))
            else:
                block_rad = json.loads(f.read_text())
    parts = [p for p in parts if p.get("phase") not in ("depth", "radiometry")]
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
              dsm_raster.MASK_NODATA, dgrid, res), "dsm_support": (2, "uint8", SUPPORT_NODATA, dgrid, res)}
    if opts.ortho:
        layers["ortho"] = (4, "uint8", None, ogrid, ores)
    tmp = {name: out / f".{name}.merge.tif" for name in layers}
    # the tiles' orthophoto gains on one gauge (images shared by tiles): one colour factor per tile
    gain_factors, harmonised = harmonise_tile_gains(
        [((r.get("summary") or {}).get("ortho") or {}).get("log_gains") or {} for r in results])
    stats = {"measured": 0, "filled": 0, "coarse": 0, "ortho_covered": 0, "cnt_weight": 0.0}
    causes: dict[str, int] = {}
    dsts = {}
    try:
        for name, (count, dt, nd, gr, r) in layers.items():
            dsts[name] = rasterio.open(tmp[name], "w", **_tiled_profile(gr.width, gr.height, count, dt,
                                                                         gr.transform, epsg, nd))
        for n_done, (p, r) in enumerate(zip(parts, results), start=1):
            pdir = workspace.part_dir(STEP, p["index"])
            arrays = dict(np.load(pdir / "core_rasters.npz")) if "summary" in r else {}
            if "ortho" in arrays and not np.allclose(gain_factors[n_done - 1], 1.0):
                arrays["ortho"] = _scale_colours(arrays["ortho"], gain_factors[n_done - 1])
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
                if name == "dsm_support" and len(a) > 1:
                    for k2, v in cause_counts(a[1]).items():
                        causes[k2] = causes.get(k2, 0) + v
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
        dsts["dsm_support"].set_band_description(2, "cause: " + CAUSE_VALUES)
        dsts["dsm_support"].update_tags(VALUES="median number of views that agreed on the cell's points; 0 "
                                               "interpolated (no measurement); 255 no data", CAUSES=CAUSE_VALUES)
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
    header = dense_cloud_header(epsg, [math.floor(g["west"]), math.floor(g["north"] - g["height"] * res), 0.0])
    n_points, n_views_sum = 0, 0.0
    with point_cloud_writer(out / "points.laz", header) as writer:
        for p, r in zip(parts, results):
            if "summary" not in r:
                continue
            with np.load(workspace.part_dir(STEP, p["index"]) / "core_points.npz") as z:
                xyz, rgb, nv = z["xyz"], z["rgb"], z["n_views"]
            if not len(xyz):
                continue
            writer.write_points(dense_points(header, xyz, rgb, n_views=nv))
            n_points += len(xyz)
            n_views_sum += float(nv.sum())

    sums = [r["summary"] for r in done]
    timings: dict[str, float] = {}
    for s in sums:
        for k, v in (s.get("timings_s") or {}).items():
            timings[k] = round(timings.get(k, 0.0) + v, 3)
    for d in depth_results:
        for k, v in (d.get("timings_s") or {}).items():
            if k != "total":
                timings[k] = round(timings.get(k, 0.0) + v, 3)
    if block_rad and block_rad.get("seconds") is not None:
        timings["radiometry_solve"] = block_rad["seconds"]
    timings["merge"] = round(time.perf_counter() - t0, 3)
    times_computed: dict[str, int] = {}
    for d in depth_results:
        for name in d.get("computed") or []:
            times_computed[name] = times_computed.get(name, 0) + 1
    valid_fracs = [v for d in depth_results for v in d.get("valid_fractions") or []]
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
                  "depth_maps_computed": sum(times_computed.values()),
                  "depth_maps_computed_twice": sorted(n for n, c in times_computed.items() if c > 1),
                  "per_depth_part": [{"group": d["group"], "images": len(d.get("computed") or []),
                                      "seconds": d.get("seconds")} for d in depth_results],
                  "per_tile": [{"tile": r["tile"], "core": r["core"], "images": r["images"],
                                "seconds": r.get("seconds"), "points": r.get("core_points"),
                                **({"skipped": r["skipped"]} if r.get("skipped") else {})} for r in results]},
        "sparse_prior": ({"source": g["sparse_source"], "points": g.get("sparse_points")} if "sparse_source" in g
                         else first.get("sparse_prior")),
        "rolling_shutter": first.get("rolling_shutter"),
        "pairs": {"count": sum(d.get("pairs", 0) for d in depth_results),
                  "rectified": sum(d.get("rectified", 0) for d in depth_results),
                  "mean_valid_disparity_fraction": round(float(np.mean(valid_fracs)), 4) if valid_fracs else None},
        "points": {"fused": sum((s.get("points") or {}).get("fused", 0) for s in sums),
                   "outliers_removed": sum((s.get("points") or {}).get("outliers_removed", 0) for s in sums),
                   "written": int(n_points),
                   "mean_views_per_point": round(n_views_sum / n_points, 3) if n_points else None},
        "dsm": {"width": dgrid.width, "height": dgrid.height, "measured_cells": measured, "filled_cells": filled,
                "coarse_cells": coarse, "hole_fraction": round(filled / max(1, measured + filled + coarse), 5),
                "cells_by_cause": causes,
                "bounds": [dgrid.west, dgrid.north - dgrid.height * res, dgrid.west + dgrid.width * res,
                           dgrid.north]},
        "ortho": ({"resolution_m": ores, "width": ogrid.width, "height": ogrid.height,
                   "coverage_fraction": stats["ortho_covered"] / max(1, ogrid.width * ogrid.height),
                   "radiometry": ("the block's: one gain per image and one vignetting per camera, solved once from "
                                  "the depth parts' observations and used by every tile"
                                  if block_rad and block_rad.get("solved") else
                                  "estimated per tile (its images and margin), the tiles' gains harmonised on the "
                                  "images they share"),
                   **({"block_radiometry": {k2: block_rad.get(k2)
                                            for k2 in ("summary", "observations", "seconds", "occlusion")}}
                      if block_rad else {}),
                   "tile_harmonisation": harmonised} if opts.ortho else None),
        "dsm_vertical_rmse_m": round(rmse, 4) if rmse is not None else None,
        "dsm_smoothing_radius_m": max(s.get("dsm_smoothing_radius_m") or 0.0 for s in sums),
        "dsm_vertical_rmse_source": "internal estimate: agreement of the views fused into each point (random "
                                    "part only; the georeferencing bias is not in it), RMS over the tiles",
        **({"check_height_bias_m": round(check_bias, 4)} if check_bias is not None else {}),
        "timings_s": timings,
        "time_per_image_s": round(sum(r.get("seconds") or 0.0 for r in results + depth_results) / g["n_images"] +
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
