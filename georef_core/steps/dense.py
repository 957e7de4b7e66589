"""Step: dense reconstruction. Reads ``OUT_DIR/oriented_images.json`` (or another oriented-images file),
writes ``OUT_DIR/dense/``: ``points.laz`` (coloured point cloud, project CRS, ellipsoidal heights),
``dsm.tif`` (COG, float32), ``dsm_filled_mask.tif`` (COG, uint8: 0 measured, 1 filled, 255 no data),
``ortho.tif`` (COG, RGBA) and ``dense_summary.json``. The CLI (``georef dense``) and the worker call this
same function; re-running it rewrites these files. Method: docs/dense.md.
"""

from __future__ import annotations

import json
import shutil
import threading
import time
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from ..dense.coarse_pass import CoarseOptions
from ..dense.depth_fusion import FusionOptions
from ..dense.orthophoto import OrthoOptions
from ..dense.pair_selection import PairSelectionOptions
from ..dense.rectified_stereo import StereoOptions
from ..errors import InputFileError, ProcessingError
from ..progress import ProgressFn

DENSE_DIR = "dense"


@dataclass
class DenseOptions:
    oriented_path: str | None = None  # default OUT_DIR/oriented_images.json
    max_image_size: int = 1600  # images are matched at most this large (longer side, px)
    depth_map_downscale: float = 2.0  # depth maps (and the fused cloud) at this fraction of the matching size
    resolution_m: float | None = None  # DSM cell; default 2 x the ground sample distance of the matched images
    ortho_resolution_m: float | None = None  # default half the DSM cell (~ the GSD)
    workers: int = 2  # threads (and OpenCV threads)
    max_gap_m: float = 3.0  # DSM gaps at the border of the coverage up to twice this are filled
    min_points_per_cell: int = 1
    outlier_k: float = 4.0  # surface outlier test: k robust sigmas (0: off)
    outlier_min_offset_m: float = 0.10
    voxel_m: float | None = None  # thin the LAS cloud to one point per voxel (None: keep all fused points)
    ortho: bool = True
    ortho_compress: str = "DEFLATE"  # or "JPEG" (RGB + mask instead of an alpha band)
    keep_depth_maps: bool = False
    pairs: PairSelectionOptions = field(default_factory=PairSelectionOptions)
    stereo: StereoOptions = field(default_factory=StereoOptions)
    fusion: FusionOptions = field(default_factory=FusionOptions)
    ortho_options: OrthoOptions = field(default_factory=OrthoOptions)
    coarse: CoarseOptions = field(default_factory=CoarseOptions)  # coarse pass filling weakly textured areas
    tiles: int = 0  # spatial tiles (steps/dense_tiles.py): 0 auto (1 up to 250 images, then ~1 per 100), 1 one run
    tile_margin: float = 0.25  # a tile takes the images whose footprint meets its core grown by this many footprints

    @classmethod
    def from_dict(cls, d: dict) -> "DenseOptions":
        """From plain JSON-like values (the worker's job options); nested option groups as dicts. Unknown
        names are refused."""
        nested = {"pairs": PairSelectionOptions, "stereo": StereoOptions, "fusion": FusionOptions,
                  "ortho_options": OrthoOptions, "coarse": CoarseOptions}
        kw = {}
        for k, v in (d or {}).items():
            if k not in cls.__dataclass_fields__:
                raise ProcessingError(f"unknown dense option {k!r}")
            if k in nested and isinstance(v, dict):
                known = nested[k].__dataclass_fields__
                bad = [x for x in v if x not in known]
                if bad:
                    raise ProcessingError(f"unknown dense option {k}.{bad[0]}")
                v = nested[k](**v)
            kw[k] = v
        return cls(**kw)


@dataclass
class _Timer:
    timings: dict = field(default_factory=dict)

    def stage(self, name: str):
        timer = self

        class _Ctx:
            def __enter__(self):
                self.t0 = time.perf_counter()

            def __exit__(self, *exc):
                timer.timings[name] = timer.timings.get(name, 0.0) + time.perf_counter() - self.t0

        return _Ctx()


def _nice(x: float) -> float:
    """Round a resolution to 5 mm (1 mm below 2 cm)."""
    step = 0.005 if x >= 0.02 else 0.001
    return max(step, round(x / step) * step)


def _rolling_summary(views) -> dict | None:
    """How many rolling-shutter images were read as a global shutter's, and their readout; None if none."""
    rs = [v for v in views if v.rolling_shutter and v.scene_depth_m]
    if not rs:
        return None
    return {"corrected_images": len(rs), "readout_s": sorted({round(v.readout_s, 6) for v in rs}),
            "method": "each image resampled to a global shutter's from its middle row's camera centre, at its "
                      "median scene depth (docs/dense.md)"}


def run_dense(out_dir, options: DenseOptions | dict | None = None, progress: ProgressFn | None = None) -> dict:
    """Dense point cloud, DSM and orthophoto of the oriented images of ``out_dir``; returns the summary.
    ``options`` may also be a dict (:meth:`DenseOptions.from_dict`)."""
    if isinstance(options, dict):
        options = DenseOptions.from_dict(options)
    import cv2
    from threadpoolctl import threadpool_limits

    # the parallelism is OpenCV's and the step's threads; multi-threaded BLAS on the many small (3 x 3) @ (3 x N)
    # products only adds contention (measured 5x slower on the loaded 2-core machine)
    cv_threads = cv2.getNumThreads()
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            return _run_dense(out_dir, options, progress)
    finally:
        cv2.setNumThreads(cv_threads)


def _run_dense(out_dir, options: DenseOptions | None, progress: ProgressFn | None) -> dict:
    import cv2

    from ..dense import cog_writer, dsm_raster
    from ..dense.camera_views import views_from_oriented
    from ..dense.coarse_pass import coarse_points, coarse_views
    from ..dense.dsm_support import SUPPORT_NODATA, tiered_dsm
    from ..dense.depth_fusion import concatenate, fuse_view, fusion_neighbours
    from ..dense.orthophoto import build_orthophoto
    from ..dense.pair_selection import select_sources
    from ..dense.point_cloud_filter import surface_outliers, voxel_thin
    from ..dense.point_cloud_io import write_point_cloud
    from ..dense.rectified_stereo import median_depth_map, pair_depth_map
    from ..dense.sparse_prior import build_sparse_prior
    from ..photo.oriented_images import read_oriented_images

    opts = options or DenseOptions()
    report = progress or (lambda stage, done, total: None)
    out_dir = Path(out_dir)
    oriented_path = Path(opts.oriented_path) if opts.oriented_path else out_dir / "oriented_images.json"
    if opts.workers < 1:
        raise ProcessingError("workers must be at least 1")
    if opts.max_image_size < 64:
        raise ProcessingError("max_image_size must be at least 64 px")
    if not opts.depth_map_downscale >= 1.0:
        raise ProcessingError("depth_map_downscale must be at least 1")
    for name in ("resolution_m", "ortho_resolution_m"):
        v = getattr(opts, name)
        if v is not None and not (v > 0 and np.isfinite(v)):
            raise ProcessingError(f"{name} must be a positive number of metres, not {v}")
    cv2.setNumThreads(int(opts.workers))
    t_start = time.perf_counter()
    timer = _Timer()

    report("reading", 0, 1)
    with timer.stage("read"):
        oriented = read_oriented_images(oriented_path)
        if len(oriented.images) < 2:
            raise InputFileError(oriented_path, f"dense reconstruction needs at least 2 oriented images, "
                                                f"found {len(oriented.images)}")
        for im in oriented.images:
            if not oriented.image_path(im).is_file():
                raise InputFileError(oriented.image_path(im), f"image of {oriented_path.name} not found")
        views = views_from_oriented(oriented, opts.max_image_size, source=oriented_path)
        grids = [v.scaled(1.0 / opts.depth_map_downscale) if opts.depth_map_downscale != 1 else v for v in views]
    frame = oriented.frame
    dense_dir = out_dir / DENSE_DIR
    dense_dir.mkdir(parents=True, exist_ok=True)
    work = dense_dir / "depthmaps"
    if work.exists():
        shutil.rmtree(work)
    work.mkdir()

    report("sparse prior", 0, 1)
    with timer.stage("sparse_prior"):
        prior = build_sparse_prior(views, oriented.sparse_xyz_enu_m)
        # rolling-shutter images are read as a global shutter's, at each image's median scene depth
        views = [replace(v, scene_depth_m=prior.views[k].depth_med_m) if v.rolling_shutter else v
                 for k, v in enumerate(views)]
    report("sparse prior", 1, 1)

    with timer.stage("pair_selection"):
        sources = select_sources(views, prior, opts.pairs)
    n_pairs = sum(len(s) for s in sources)
    if n_pairs == 0:
        raise ProcessingError("no image pair overlaps enough for stereo matching (check the orientations and the "
                              "overlap of the flight)")

    # ---- depth maps (parallel over reference images) --------------------------------------------
    cache_lock = threading.Lock()
    gray_cache: OrderedDict[int, np.ndarray] = OrderedDict()

    def gray(k: int) -> np.ndarray:
        with cache_lock:
            if k in gray_cache:
                gray_cache.move_to_end(k)
                return gray_cache[k]
        img = views[k].read_image(gray=True)
        with cache_lock:
            gray_cache[k] = img
            while len(gray_cache) > 4 * opts.workers + 8:
                gray_cache.popitem(last=False)
        return img

    depth_paths: dict[int, Path] = {}
    pair_info: list[dict] = []
    stage_times = {"stereo": 0.0}

    def depth_for(i: int):
        t0 = time.perf_counter()
        maps, infos = [], []
        pv = prior.views[i]
        for p in sources[i]:
            dm, info = pair_depth_map(views[i], views[p.src], gray(i), gray(p.src), pv.depth_lo_m, pv.depth_hi_m,
                                      grids[i], opts.stereo)
            info.update({"ref": views[i].name, "src": views[p.src].name, "overlap": round(p.overlap, 3),
                         "b_over_d": round(p.b_over_d, 3)})
            infos.append(info)
            if dm is not None:
                maps.append(dm)
        depth = median_depth_map(maps) if maps else None
        return i, depth, infos, time.perf_counter() - t0

    report("depth maps", 0, len(views))
    t0 = time.perf_counter()
    todo = [i for i in range(len(views)) if sources[i]]
    with ThreadPoolExecutor(max_workers=opts.workers) as pool:
        futures = [pool.submit(depth_for, i) for i in todo]
        try:
            for done, fut in enumerate(as_completed(futures), start=1):
                i, depth, infos, dt = fut.result()
                stage_times["stereo"] += dt
                pair_info.extend(infos)
                if depth is not None and np.isfinite(depth).any():
                    path = work / f"{i:05d}.npy"
                    np.save(path, depth)
                    depth_paths[i] = path
                report("depth maps", done, len(todo))
        except BaseException:
            for f in futures:
                f.cancel()
            raise
    timer.timings["depth_maps"] = time.perf_counter() - t0
    if len(depth_paths) < 2:
        raise ProcessingError(f"stereo matching gave depth for only {len(depth_paths)} image(s)")

    # ---- fusion -----------------------------------------------------------------------------------
    with timer.stage("fusion"):
        have = sorted(depth_paths)
        neighbours = fusion_neighbours(views, have, [p.ground_up_m for p in prior.views],
                                       [p.depth_hi_m for p in prior.views], opts.fusion)
        used = {i: np.zeros((grids[i].height, grids[i].width), bool) for i in have}
        depth_cache: OrderedDict[int, np.ndarray] = OrderedDict()

        def depth_of(k: int) -> np.ndarray:
            if k not in depth_cache:
                depth_cache[k] = np.load(depth_paths[k])
                if len(depth_cache) > 2 * opts.fusion.max_neighbours + 2:
                    depth_cache.popitem(last=False)
            depth_cache.move_to_end(k)
            return depth_cache[k]

        parts = []
        report("fusion", 0, len(have))
        for n_done, i in enumerate(have, start=1):
            g = grids[i]
            mx, my = views[i].undistort_maps(g)
            colours = cv2.remap(views[i].read_image(), mx, my, cv2.INTER_LINEAR)[:, :, ::-1]
            parts.append(fuse_view(i, grids, depth_of, used, [j for j in neighbours[i] if j in used], colours,
                                   opts.fusion))
            report("fusion", n_done, len(have))
        if opts.fusion.edge_min_b_over_d > 0:  # second sweep: two-view points at edges and beside occluders
            for i in have:
                g = grids[i]
                mx, my = views[i].undistort_maps(g)
                colours = cv2.remap(views[i].read_image(), mx, my, cv2.INTER_LINEAR)[:, :, ::-1]
                parts.append(fuse_view(i, grids, depth_of, used, [j for j in neighbours[i] if j in used], colours,
                                       opts.fusion, edge=True))
        fused = concatenate(parts)
        del parts
    if len(fused.xyz_enu_m) < 100:
        raise ProcessingError(f"only {len(fused.xyz_enu_m)} points were confirmed by {opts.fusion.min_views} views: "
                              "the orientations are inconsistent or the images do not overlap")

    # ---- to the project CRS, outliers -------------------------------------------------------------
    with timer.stage("to_project_crs"):
        pts = frame.enu_to_grid(fused.xyz_enu_m)
    native_gsd = [prior.views[k].depth_med_m / oriented.cameras[oriented.images[k].camera_id].K()[0, 0]
                  for k in range(len(views))]
    working_gsd = [prior.views[k].depth_med_m / views[k].focal_px for k in range(len(views))]
    gsd = float(np.median(native_gsd))
    wgsd = float(np.median(working_gsd))
    res = float(opts.resolution_m) if opts.resolution_m else _nice(2.0 * wgsd)
    ortho_res = float(opts.ortho_resolution_m) if opts.ortho_resolution_m else _nice(res / 2.0)
    n_fused = len(pts)
    with timer.stage("outliers"):
        if opts.outlier_k > 0:
            bad = surface_outliers(pts[:, 0], pts[:, 1], pts[:, 2], res, k=opts.outlier_k,
                                   min_offset_m=opts.outlier_min_offset_m)
        else:
            bad = np.zeros(len(pts), bool)
        keep = ~bad
        pts, rgb, n_views = pts[keep], fused.rgb[keep], fused.n_views[keep]
        xyz_enu = fused.xyz_enu_m[keep]
        # precision of a fused point: the views' scatter about their mean, s^2 / (n - 1) (RMS over the cloud)
        nv = fused.n_views[keep].astype(np.float64)
        sigma_mean = np.sqrt(fused.spread_m[keep].astype(np.float64) ** 2 / np.maximum(nv - 1.0, 1.0))
        precision_m = float(np.sqrt(np.mean(sigma_mean ** 2))) if len(sigma_mean) else None

    # ---- coarse pass: the same pairs at 1/4 of the size, where weak texture left the fine pass empty -----
    coarse_pts = coarse_nv = coarse_res = None
    coarse_info = None
    views_c = coarse_views(views, opts.coarse)
    if views_c is not None:
        with timer.stage("coarse_pass"):
            cfused, coarse_info = coarse_points(views_c, prior, sources, opts.stereo, opts.fusion, opts.workers, report)
            if len(cfused.xyz_enu_m):
                coarse_pts = frame.enu_to_grid(cfused.xyz_enu_m)
                coarse_nv = cfused.n_views
                coarse_res = _nice(res * opts.coarse.factor / opts.depth_map_downscale)
                if opts.outlier_k > 0:
                    cbad = surface_outliers(coarse_pts[:, 0], coarse_pts[:, 1], coarse_pts[:, 2], coarse_res,
                                            k=opts.outlier_k, min_offset_m=opts.outlier_min_offset_m)
                    coarse_pts, coarse_nv = coarse_pts[~cbad], coarse_nv[~cbad]
                    coarse_info["outliers_removed"] = int(cbad.sum())
                coarse_info["dsm_cell_m"] = coarse_res

    # ---- DSM ---------------------------------------------------------------------------------------
    report("dsm", 0, 1)
    with timer.stage("dsm"):
        dgrid = dsm_raster.grid_covering(pts[:, 0], pts[:, 1], res)
        tiers = tiered_dsm(dgrid, pts, n_views, opts.fusion.min_views, coarse_pts, coarse_nv, coarse_res,
                           opts.max_gap_m / res, opts.min_points_per_cell)
        dsm_filled, mask, counts = tiers.dsm, tiers.mask, tiers.counts
        tags = dict(cog_writer.HEIGHT_TAGS, RESOLUTION_M=f"{res:g}")
        cog_writer.write_cog(dense_dir / "dsm.tif", np.where(np.isfinite(dsm_filled), dsm_filled,
                                                              dsm_raster.NODATA).astype(np.float32),
                             dgrid.transform, frame.epsg, nodata=dsm_raster.NODATA, overview_resampling="AVERAGE",
                             descriptions=["ellipsoidal height"], units="metre", tags=tags)
        cog_writer.write_cog(dense_dir / "dsm_filled_mask.tif", mask, dgrid.transform, frame.epsg,
                             nodata=dsm_raster.MASK_NODATA, overview_resampling="NEAREST",
                             descriptions=["0 measured, 2 measured at coarse resolution, 1 filled, 255 no data"],
                             tags={"VALUES": "0 measured, 2 measured at coarse resolution (coarse pass only), "
                                             "1 filled (interpolated), 255 no data"})
        cog_writer.write_cog(dense_dir / "dsm_support.tif", tiers.support, dgrid.transform, frame.epsg,
                             nodata=SUPPORT_NODATA, overview_resampling="NEAREST",
                             descriptions=["views agreeing on the cell (0: interpolated, no support)"],
                             tags={"VALUES": "median number of views that agreed on the cell's points; 0 interpolated "
                                             "(no measurement); 255 no data"})
    report("dsm", 1, 1)

    # ---- orthophoto --------------------------------------------------------------------------------
    ortho_info = None
    if opts.ortho:
        with timer.stage("orthophoto"):
            ogrid = dgrid.with_resolution(ortho_res)
            gmin, gmax = np.percentile(xyz_enu[:, 2], [0.5, 99.5]) if len(xyz_enu) else (0.0, 0.0)
            rgba = build_orthophoto(views, dsm_filled, dgrid, ogrid, frame, (float(gmin), float(gmax)),
                                    [p.depth_med_m for p in prior.views], opts.ortho_options, report,
                                    info=(ortho_run := {}))
            from ..dense.cog_writer import RGBA

            comp = opts.ortho_compress.upper()
            cog_writer.write_cog(dense_dir / "ortho.tif", rgba, ogrid.transform, frame.epsg, compress=comp,
                                 colorinterp=RGBA, overview_resampling="AVERAGE",
                                 tags={"PRODUCER": "georef dense step", "RESOLUTION_M": f"{ortho_res:g}"})
            ortho_info = {"resolution_m": ortho_res, "width": ogrid.width, "height": ogrid.height,
                          "coverage_fraction": float(np.mean(rgba[3] > 0)),
                          "radiometry": ortho_run.get("radiometry"), "radiometry_s": round(ortho_run["radiometry_s"], 3),
                          "mosaic_s": round(ortho_run["mosaic_s"], 3)}

    # ---- point cloud file ----------------------------------------------------------------------------
    report("point cloud", 0, 1)
    with timer.stage("las"):
        las_xyz, las_rgb, las_views = pts, rgb, n_views
        if opts.voxel_m:
            thin_enu, las_rgb = voxel_thin(xyz_enu, rgb, opts.voxel_m)
            las_xyz, las_views = frame.enu_to_grid(thin_enu), None
        write_point_cloud(dense_dir / "points.laz", las_xyz, las_rgb, frame.epsg, n_views=las_views)
    report("point cloud", 1, 1)
    if not opts.keep_depth_maps:
        shutil.rmtree(work, ignore_errors=True)

    timer.timings["total"] = time.perf_counter() - t_start
    n_img = len(views)
    measured = int(np.count_nonzero(mask == dsm_raster.MASK_MEASURED))
    filled = int(np.count_nonzero(mask == dsm_raster.MASK_FILLED))
    coarse_cells = int(np.count_nonzero(mask == dsm_raster.MASK_COARSE))
    valid_fracs = [p["valid_fraction"] for p in pair_info if p.get("rectified")]
    check_bias = _check_height_bias(out_dir / "residuals.json")
    summary = {
        "oriented_images": str(oriented_path),
        "project_crs": f"EPSG:{frame.epsg}",
        "heights": "ellipsoidal (WGS84)",
        "n_images": n_img,
        "matching_image_size_px": [views[0].width, views[0].height],
        "depth_map_size_px": [grids[0].width, grids[0].height],
        "gsd_m": round(gsd, 4),
        "matching_gsd_m": round(wgsd, 4),
        "dsm_resolution_m": res,
        "sparse_prior": {"source": prior.source, "points": int(len(prior.xyz_enu_m))},
        "rolling_shutter": _rolling_summary(views),
        "pairs": {"count": n_pairs, "rectified": int(sum(1 for p in pair_info if p.get("rectified"))),
                  "mean_valid_disparity_fraction": round(float(np.mean(valid_fracs)), 4) if valid_fracs else None,
                  "images_without_partner": [views[i].name for i in range(n_img) if not sources[i]]},
        "points": {"fused": int(n_fused), "outliers_removed": int(np.count_nonzero(bad)), "written": int(len(las_xyz)),
                   "mean_views_per_point": round(float(np.mean(n_views)), 3) if len(n_views) else None},
        "dsm": {"width": dgrid.width, "height": dgrid.height, "measured_cells": measured, "filled_cells": filled,
                "coarse_cells": coarse_cells, "two_view_cells": tiers.stats["two_view_cells"],
                "hole_fraction": round(filled / max(1, measured + filled + coarse_cells), 5),
                "coarse_minus_fine_m": tiers.stats.get("coarse_minus_fine_m"),
                "bounds": [dgrid.west, dgrid.north - dgrid.height * res, dgrid.west + dgrid.width * res, dgrid.north],
                "mean_points_per_measured_cell": round(float(counts[mask == 0].mean()), 3) if measured else None},
        "ortho": ortho_info,
        "coarse_pass": coarse_info,
        # read by the volume uncertainty model (docs/volumes.md)
        "dsm_vertical_rmse_m": round(precision_m, 4) if precision_m is not None else None,
        # how far a height edge (a stockpile's toe) spreads in the DSM: half the matching window on the ground
        # plus one cell (cell averaging, bilinear sampling); volume outlines sample the ground beyond it
        "dsm_smoothing_radius_m": round(0.5 * max(opts.stereo.block_size, opts.stereo.refine_window) * wgsd + res, 4),
        "dsm_vertical_rmse_source": "internal estimate: agreement of the views fused into each point (random "
                                    "part only; the georeferencing bias is not in it)",
        **({"check_height_bias_m": round(check_bias, 4)} if check_bias is not None else {}),
        "timings_s": {k: round(v, 3) for k, v in timer.timings.items()},
        "time_per_image_s": round(timer.timings["total"] / n_img, 3),
        "depth_map_thread_s_per_image": round(stage_times["stereo"] / n_img, 3),  # summed over the threads
        "workers": opts.workers,
        "outputs": {k: str(dense_dir / f) for k, f in (("points", "points.laz"), ("dsm", "dsm.tif"),
                                                      ("dsm_filled_mask", "dsm_filled_mask.tif"),
                                                      ("dsm_support", "dsm_support.tif"),
                                                      ("ortho", "ortho.tif"))
                    if k != "ortho" or opts.ortho},
        "options": _options_dict(opts),
    }
    (dense_dir / "dense_summary.json").write_text(json.dumps(summary, indent=2))
    report("done", 1, 1)
    return summary


def _check_height_bias(path: Path) -> float | None:
    """Mean dz of the georeferencing step's check points (residuals.json), when there are any."""
    try:
        st = json.loads(path.read_text())["statistics"]
        return float(st["dz"]["mean_m"]) if st.get("n") else None
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _options_dict(opts: DenseOptions) -> dict:
    d = {}
    for k, v in opts.__dict__.items():
        d[k] = asdict(v) if hasattr(v, "__dataclass_fields__") else v
    return d


def step_entry(workspace, options: dict, progress, context: dict) -> dict:
    """The dense step as the contract runs it (specs.DENSE): one run, or (``tiles`` > 1, or auto on a large
    block) the tiles' plan, parts and merge in this process (contract.run_split; steps/dense_tiles.py)."""
    from . import dense_tiles
    from .contract import get_spec, run_split

    opts = DenseOptions.from_dict(dict(options or {}))
    if dense_tiles.tile_count(opts.tiles, dense_tiles.count_images(workspace, opts)) <= 1:
        return run_dense(workspace.out_dir, dict(options or {}) or None, progress)
    return run_split(get_spec("dense"), workspace, dict(options or {}), progress, context)
