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


def depth_grid(view, opts: "DenseOptions"):
    """The pinhole grid a view's depth map is computed on: the view at 1 / depth_map_downscale of its matching size."""
    return view.scaled(1.0 / opts.depth_map_downscale) if opts.depth_map_downscale != 1 else view


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


@dataclass
class BlockDepth:
    """What a tiled run's fusion part (steps/dense_tiles.py) gives ``run_dense`` instead of its own sparse prior,
    pair selection and stereo matching: the block's per-view prior, the depth maps its depth parts computed
    (each image once), the views whose points it keeps (the others only confirm them) and their fusion
    neighbours as the whole block chose them. Indices are those of the run's own oriented images."""

    prior_views: list            # sparse_prior.ViewDepth per view, from the block's prior
    sparse_source: str
    depth_paths: dict            # view -> .npy depth map (fine pass)
    coarse_paths: dict           # view -> .npy depth map (coarse pass)
    references: list             # views whose points are output
    neighbours: dict             # reference view -> its fusion neighbours
    ortho_window: tuple | None = None   # (w, s, e, n): the orthophoto only there (the tile's core and a band)
    keep_box: tuple | None = None       # (w, s, e, n): depth pixels whose point falls outside are left out
    radiometry: dict | None = None      # the block's orthophoto radiometry (block_radiometry.py), None: the tile's own


def run_dense(out_dir, options: DenseOptions | dict | None = None, progress: ProgressFn | None = None,
              block: BlockDepth | None = None) -> dict:
    """Dense point cloud, DSM and orthophoto of the oriented images of ``out_dir``; returns the summary.
    ``options`` may also be a dict (:meth:`DenseOptions.from_dict`). ``block``: a tiled run's fusion part
    (precomputed depth maps, no stereo matching here)."""
    if isinstance(options, dict):
        options = DenseOptions.from_dict(options)
    import cv2
    from threadpoolctl import threadpool_limits

    # the parallelism is OpenCV's and the step's threads; multi-threaded BLAS on the many small (3 x 3) @ (3 x N)
    # products only adds contention (measured 5x slower on the loaded 2-core machine)
    cv_threads = cv2.getNumThreads()
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            return _run_dense(out_dir, options, progress, block)
    finally:
        cv2.setNumThreads(cv_threads)


def _stereo_depth_maps(views, grids, prior, sources, todo: list[int], opts: DenseOptions, work: Path, report,
                       file_name=lambda i: f"{i:05d}.npy") -> tuple[dict, list, float]:
    """The depth maps of the views ``todo`` (each the median over its pairs ``sources``), in parallel over the
    reference images, saved as ``work/file_name(i)`` (only those with some depth): ({view: path}, the pairs'
    figures, the stereo seconds summed over the threads)."""
    from ..dense.depth_pass import depth_maps

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

    def keep(i: int, depth: np.ndarray) -> None:
        depth_paths[i] = work / file_name(i)
        np.save(depth_paths[i], depth)

    pair_info, stereo_s = depth_maps(views, grids, gray, prior, sources, opts.stereo, opts.workers, keep, report,
                                     todo=todo)
    return depth_paths, pair_info, stereo_s


def _run_dense(out_dir, options: DenseOptions | None, progress: ProgressFn | None,
               block: BlockDepth | None = None) -> dict:
    import cv2

    from ..dense import cog_writer, dsm_raster
    from ..dense.camera_views import views_from_oriented
    from ..dense.coarse_pass import coarse_points, coarse_views, fuse_coarse
    from ..dense.dsm_support import (CAUSE_VALUES, SUPPORT_NODATA, cause_counts, hole_causes, images_seeing,
                                     tiered_dsm)
    from ..dense.depth_pass import fuse_depth_maps
    from ..dense.orthophoto import build_orthophoto
    from ..dense.pair_selection import select_sources
    from ..dense.point_cloud_filter import surface_outliers, voxel_thin
    from ..dense.point_cloud_io import write_point_cloud
    from ..dense.sparse_prior import SparsePrior, build_sparse_prior
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
        grids = [depth_grid(v, opts) for v in views]
    frame = oriented.frame
    dense_dir = out_dir / DENSE_DIR
    dense_dir.mkdir(parents=True, exist_ok=True)
    work = dense_dir / "depthmaps"
    if work.exists():
        shutil.rmtree(work)
    work.mkdir()

    report("sparse prior", 0, 1)
    with timer.stage("sparse_prior"):
        if block is None:
            prior = build_sparse_prior(views, oriented.sparse_xyz_enu_m)
        else:   # the block's (the same depth ranges and ground heights as a one run's)
            prior = SparsePrior(np.zeros((0, 3)), list(block.prior_views), block.sparse_source)
        # rolling-shutter images are read as a global shutter's, at each image's median scene depth
        views = [replace(v, scene_depth_m=prior.views[k].depth_med_m) if v.rolling_shutter else v
                 for k, v in enumerate(views)]
    report("sparse prior", 1, 1)

    if block is None:
        with timer.stage("pair_selection"):
            sources = select_sources(views, prior, opts.pairs)
        n_pairs = sum(len(s) for s in sources)
        if n_pairs == 0:
            raise ProcessingError("no image pair overlaps enough for stereo matching (check the orientations and the "
                                  "overlap of the flight)")

        # ---- depth maps (parallel over reference images) ----------------------------------------
        t0 = time.perf_counter()
        todo = [i for i in range(len(views)) if sources[i]]
        depth_paths, pair_info, stereo_s = _stereo_depth_maps(views, grids, prior, sources, todo, opts, work, report)
        stage_times = {"stereo": stereo_s}
        timer.timings["depth_maps"] = time.perf_counter() - t0
    else:   # a tiled run's fusion part: the depth maps its depth parts computed (each image once)
        sources = [[] for _ in views]
        n_pairs = 0
        pair_info = []
        stage_times = {"stereo": 0.0}
        depth_paths = {i: Path(p) for i, p in block.depth_paths.items() if Path(p).is_file()}
    if len(depth_paths) < 2:
        raise ProcessingError(f"stereo matching gave depth for only {len(depth_paths)} image(s)")

    # ---- fusion -----------------------------------------------------------------------------------
    with timer.stage("fusion"):
        have = sorted(depth_paths)
        if block is None:   # neighbours: footprints at the prior's ground height (fuse_depth_maps)
            neighbours, refs = None, have
        else:   # the block's choice; the views around the tile only confirm the tile's points
            neighbours = block.neighbours
            refs = [i for i in have if i in set(block.references)]
        depth_cache: OrderedDict[int, np.ndarray] = OrderedDict()

        clip = None   # a tile: only the points around its core (BlockDepth.keep_box)
        if block is not None and block.keep_box:
            clip = _depth_clipper(frame, block.keep_box, float(np.median([p.ground_up_m for p in prior.views])))

        def depth_of(k: int) -> np.ndarray:
            if k not in depth_cache:
                depth_cache[k] = np.load(depth_paths[k]) if clip is None else clip(grids[k], np.load(depth_paths[k]))
                if len(depth_cache) > 2 * opts.fusion.max_neighbours + 2:
                    depth_cache.popitem(last=False)
            depth_cache.move_to_end(k)
            return depth_cache[k]

        def colours_of(i: int) -> np.ndarray:
            mx, my = views[i].undistort_maps(grids[i])
            return cv2.remap(views[i].read_image(), mx, my, cv2.INTER_LINEAR)[:, :, ::-1]

        fused = fuse_depth_maps(views, grids, have, depth_of, prior, colours_of, opts.fusion, report,
                                references=refs, neighbours=neighbours)
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
            if block is None:
                cfused, coarse_info = coarse_points(views_c, prior, sources, opts.stereo, opts.fusion, opts.workers,
                                                    report)
            else:
                cdepth = {i: np.load(p) if clip is None else clip(views_c[i], np.load(p))
                          for i, p in block.coarse_paths.items() if Path(p).is_file()}
                cfused, coarse_info = fuse_coarse(views_c, prior, cdepth, opts.fusion, references=refs)
                del cdepth
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
        # band 2: why a cell has or lacks a measurement (interpolated or empty where the images saw it without
        # agreeing on a depth, or where fewer than 2 images see it; "see": not hidden behind the measured surface)
        causes = hole_causes(mask, images_seeing(dgrid, dsm_filled, views, frame, mask=mask))
        cog_writer.write_cog(dense_dir / "dsm_support.tif", np.stack([tiers.support, causes]), dgrid.transform,
                             frame.epsg, nodata=SUPPORT_NODATA, overview_resampling="NEAREST",
                             descriptions=["views agreeing on the cell (0: interpolated, no support)",
                                           "cause: " + CAUSE_VALUES],
                             tags={"VALUES": "median number of views that agreed on the cell's points; 0 interpolated "
                                             "(no measurement); 255 no data", "CAUSES": CAUSE_VALUES})
    report("dsm", 1, 1)

    # ---- orthophoto --------------------------------------------------------------------------------
    ortho_info = None
    if opts.ortho:
        with timer.stage("orthophoto"):
            ogrid = dgrid.with_resolution(ortho_res)
            if block is not None and block.ortho_window is not None:
                ogrid = _window_of(ogrid, block.ortho_window)
            gmin, gmax = np.percentile(xyz_enu[:, 2], [0.5, 99.5]) if len(xyz_enu) else (0.0, 0.0)
            given = None
            if block is not None and block.radiometry is not None:   # one model for the whole block
                from ..dense.block_radiometry import model_for_views

                given = model_for_views(block.radiometry, views)
            rgba = build_orthophoto(views, dsm_filled, dgrid, ogrid, frame, (float(gmin), float(gmax)),
                                    [p.depth_med_m for p in prior.views], opts.ortho_options, report,
                                    info=(ortho_run := {}), radiometry=given)
            from ..dense.cog_writer import RGBA

            comp = opts.ortho_compress.upper()
            cog_writer.write_cog(dense_dir / "ortho.tif", rgba, ogrid.transform, frame.epsg, compress=comp,
                                 colorinterp=RGBA, overview_resampling="AVERAGE",
                                 tags={"PRODUCER": "georef dense step", "RESOLUTION_M": f"{ortho_res:g}"})
            ortho_info = {"resolution_m": ortho_res, "width": ogrid.width, "height": ogrid.height,
                          "coverage_fraction": float(np.mean(rgba[3] > 0)),
                          "radiometry": ortho_run.get("radiometry"), "radiometry_s": round(ortho_run["radiometry_s"], 3),
                          "mosaic_s": round(ortho_run["mosaic_s"], 3)}
            model = ortho_run.get("radiometry_model")
            if block is not None and model is not None:   # the tiles' gains are harmonised in the merge
                ortho_info["log_gains"] = {views[k].name: [*(float(x) for x in model.log_gain[k]),
                                                           int(model.observations[k])]
                                           for k in range(len(views)) if model.observations[k] >= 50}

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
                  "images_without_partner": [views[i].name for i in range(n_img) if not sources[i]]
                  if block is None else []},
        "points": {"fused": int(n_fused), "outliers_removed": int(np.count_nonzero(bad)), "written": int(len(las_xyz)),
                   "mean_views_per_point": round(float(np.mean(n_views)), 3) if len(n_views) else None},
        "dsm": {"width": dgrid.width, "height": dgrid.height, "measured_cells": measured, "filled_cells": filled,
                "coarse_cells": coarse_cells, "two_view_cells": tiers.stats["two_view_cells"],
                "hole_fraction": round(filled / max(1, measured + filled + coarse_cells), 5),
                "coarse_minus_fine_m": tiers.stats.get("coarse_minus_fine_m"),
                "cells_by_cause": cause_counts(causes),
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


def run_depth_maps(oriented_path, references: list[str], sources: dict, prior: dict, file_stem: dict, work,
                   options: DenseOptions | dict | None = None, progress: ProgressFn | None = None,
                   radiometry_obs: Path | None = None) -> dict:
    """A tiled run's depth part (steps/dense_tiles.py): the fine and coarse depth maps of the images
    ``references`` of the oriented-images file, with the partners the whole block chose for them (``sources``:
    name -> [pair_selection.StereoPair as a dict, its ``src`` a name, no ``ref``]) and the block's sparse prior (``prior``: name -> [depth lo, median,
    hi, ground up, points]), saved as ``work/<file_stem[name]>.npy`` and ``.coarse.npy`` - the same maps a one
    run computes. ``radiometry_obs``: also the orthophoto radiometry's observations of ground points sampled
    from these maps, saved there (block_radiometry.py). Returns what was computed (names, pairs, seconds)."""
    if isinstance(options, dict) or options is None:
        options = DenseOptions.from_dict(dict(options or {}))
    import cv2
    from threadpoolctl import threadpool_limits

    cv_threads = cv2.getNumThreads()
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            return _run_depth_maps(Path(oriented_path), references, sources, prior, file_stem, Path(work), options,
                                   progress or (lambda stage, done, total: None), radiometry_obs)
    finally:
        cv2.setNumThreads(cv_threads)


def _run_depth_maps(oriented_path: Path, references, sources, prior, file_stem, work: Path, opts: DenseOptions,
                    report, radiometry_obs: Path | None = None) -> dict:
    import cv2

    from ..dense.camera_views import views_from_oriented
    from ..dense.coarse_pass import coarse_depth_maps, coarse_views
    from ..dense.pair_selection import StereoPair
    from ..dense.sparse_prior import SparsePrior, ViewDepth
    from ..photo.oriented_images import read_oriented_images

    cv2.setNumThreads(int(opts.workers))
    t_start = time.perf_counter()
    oriented = read_oriented_images(oriented_path)
    wanted = set(references) | {s["src"] for r in references for s in sources.get(r, [])}
    missing = sorted(wanted - {im.name for im in oriented.images})
    if missing:
        raise InputFileError(oriented_path, f"image {missing[0]} of the dense plan is not in the file")
    subset = replace(oriented, images=[im for im in oriented.images if im.name in wanted])
    for im in subset.images:
        if not subset.image_path(im).is_file():
            raise InputFileError(subset.image_path(im), f"image of {oriented_path.name} not found")
    views = views_from_oriented(subset, opts.max_image_size, source=oriented_path)
    index = {v.name: k for k, v in enumerate(views)}
    pv = [ViewDepth(*[float(x) for x in prior[v.name][:4]], int(prior[v.name][4])) for v in views]
    views = [replace(v, scene_depth_m=pv[k].depth_med_m) if v.rolling_shutter else v for k, v in enumerate(views)]
    grids = [depth_grid(v, opts) for v in views]
    block_prior = SparsePrior(np.zeros((0, 3)), pv, "the block's")
    src = [[StereoPair(**dict(p, ref=k, src=index[p["src"]])) for p in sources.get(v.name, [])]
           if v.name in set(references) else [] for k, v in enumerate(views)]
    todo = [index[n] for n in references if src[index[n]]]
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    depth_paths, pair_info, stereo_s = _stereo_depth_maps(views, grids, block_prior, src, todo, opts, work, report,
                                                          lambda i: f"{file_stem[views[i].name]}.npy")
    t_fine = time.perf_counter() - t0
    coarse_done, t_coarse = [], 0.0
    views_c = coarse_views(views, opts.coarse)
    if views_c is not None:
        cdepth, t_coarse = coarse_depth_maps(views_c, block_prior, src, opts.stereo, opts.workers, report, todo)
        for i, d in cdepth.items():
            np.save(work / f"{file_stem[views[i].name]}.coarse.npy", d)
            coarse_done.append(views[i].name)
    t_rad, n_obs = 0.0, None
    if radiometry_obs is not None:   # the block's orthophoto radiometry: observations from these depth maps
        from ..dense.block_radiometry import depth_observations, save_observations

        t0 = time.perf_counter()
        report("radiometry samples", 0, 1)
        obs, xyz = depth_observations(views, grids, {i: np.load(p) for i, p in depth_paths.items()},
                                      with_points=True)
        save_observations(Path(radiometry_obs), obs, views, points_enu_m=xyz)
        n_obs = int(len(obs.point))
        t_rad = time.perf_counter() - t0
        report("radiometry samples", 1, 1)
    # the images actually matched (the pairs' reference images), each once here
    return {"computed": sorted({p["ref"] for p in pair_info}), "with_depth": sorted(views[i].name for i in depth_paths),
            "coarse_with_depth": sorted(coarse_done),
            "pairs": len(pair_info), "rectified": int(sum(1 for p in pair_info if p.get("rectified"))),
            "valid_fractions": [p["valid_fraction"] for p in pair_info if p.get("rectified")],
            "matching_image_size_px": [views[0].width, views[0].height],
            "depth_map_size_px": [grids[0].width, grids[0].height],
            "timings_s": {"depth_maps": round(t_fine, 3), "coarse_depth_maps": round(t_coarse, 3),
                          **({"radiometry_samples": round(t_rad, 3)} if radiometry_obs is not None else {}),
                          "total": round(time.perf_counter() - t_start, 3)},
            **({"radiometry_observations": n_obs} if n_obs is not None else {}),
            "stereo_thread_s": round(stereo_s, 3)}


def _depth_clipper(frame, box, ground_up_m: float):
    """A function (grid view, depth map) -> the map with NaN where its pixel's point falls outside ``box`` (w, s,
    e, n in the project CRS): a tile fuses only the part of its images around its core. The box is taken to
    ENU (its corners at the ground's height, ``ground_up_m`` in ENU) and tested there on an axis-aligned bound
    (a little more than the box)."""
    w, s_, e, n = box
    h = float(frame.enu_to_grid(np.array([[0.0, 0.0, ground_up_m]]))[0, 2])   # the ground's ellipsoidal height
    corners = frame.grid_to_enu(np.array([w, e, e, w]), np.array([s_, s_, n, n]), np.full(4, h))
    lo, hi = corners[:, :2].min(axis=0), corners[:, :2].max(axis=0)

    def clip(g, depth: np.ndarray) -> np.ndarray:
        v, u = np.nonzero(np.isfinite(depth))
        X = g.centre_enu_m + depth[v, u].astype(np.float64)[:, None] * g.rays_enu(u, v)
        out = (X[:, 0] < lo[0]) | (X[:, 0] > hi[0]) | (X[:, 1] < lo[1]) | (X[:, 1] > hi[1])
        if out.any():
            depth = depth.copy()
            depth[v[out], u[out]] = np.nan
        return depth

    return clip


def _window_of(grid, bounds):
    """The cells of ``grid`` inside ``bounds`` (w, s, e, n), rounded outwards to whole cells of the grid (at
    least one cell)."""
    from ..dense.dsm_raster import RasterGrid

    r = grid.resolution_m
    c0 = int(np.clip(np.floor((bounds[0] - grid.west) / r + 1e-9), 0, grid.width - 1))
    c1 = int(np.clip(np.ceil((bounds[2] - grid.west) / r - 1e-9), c0 + 1, grid.width))
    r0 = int(np.clip(np.floor((grid.north - bounds[3]) / r + 1e-9), 0, grid.height - 1))
    r1 = int(np.clip(np.ceil((grid.north - bounds[1]) / r - 1e-9), r0 + 1, grid.height))
    return RasterGrid(grid.west + c0 * r, grid.north - r0 * r, r, c1 - c0, r1 - r0)


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
