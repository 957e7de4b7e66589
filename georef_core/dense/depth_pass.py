"""One matching pass of the dense step: a depth map for every image that has stereo partners, then the
multi-view fusion of those maps into points. The full-resolution pass (steps/dense.py) and the coarse pass
(coarse_pass.py) are this same loop on different views: they differ only in where a depth map is kept (on
disk or in memory), how the images are cached and what colours the points take.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor, as_completed

import numpy as np

from .camera_views import CameraView
from .depth_fusion import FusedPoints, FusionOptions, concatenate, fuse_view, fusion_neighbours
from .rectified_stereo import StereoOptions, median_depth_map, pair_depth_map


def depth_maps(views: list[CameraView], grids: list[CameraView], gray, prior, sources, stereo: StereoOptions,
               workers: int, keep, report=None, stage: str = "depth maps",
               todo: list[int] | None = None) -> tuple[list[dict], float]:
    """For each image ``i`` of ``todo`` (default: every image with partners ``sources[i]``, pair_selection;
    a tiled run's part gives its own): one depth map per pair on
    ``grids[i]`` (depth range of ``prior.views[i]``), fused to their per-pixel median. ``gray(k)`` gives
    image k in grey (the caller caches). ``keep(i, depth)`` receives each map with a finite depth, in the
    calling thread, in completion order. Parallel over the reference images (``workers`` threads); a failure
    cancels the images not started. Returns the pairs' figures (pair_depth_map's, with ref, src, overlap and
    baseline / depth) and the threads' summed matching time (s)."""
    report = report or (lambda stage, done, total: None)

    def depth_for(i: int):
        t0 = time.perf_counter()
        maps, infos = [], []
        pv = prior.views[i]
        for p in sources[i]:
            dm, info = pair_depth_map(views[i], views[p.src], gray(i), gray(p.src), pv.depth_lo_m, pv.depth_hi_m,
                                      grids[i], stereo)
            info.update({"ref": views[i].name, "src": views[p.src].name, "overlap": round(p.overlap, 3),
                         "b_over_d": round(p.b_over_d, 3)})
            infos.append(info)
            if dm is not None:
                maps.append(dm)
        depth = median_depth_map(maps) if maps else None
        return i, depth, infos, time.perf_counter() - t0

    todo = [i for i in range(len(views)) if sources[i]] if todo is None else list(todo)
    pair_info: list[dict] = []
    busy_s = 0.0
    report(stage, 0, len(todo))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(depth_for, i) for i in todo]
        try:
            for done, fut in enumerate(as_completed(futures), start=1):
                i, depth, infos, dt = fut.result()
                busy_s += dt
                pair_info.extend(infos)
                if depth is not None and np.isfinite(depth).any():
                    keep(i, depth)
                report(stage, done, len(todo))
        except BaseException:
            for f in futures:
                f.cancel()
            raise
    return pair_info, busy_s


def fuse_depth_maps(views: list[CameraView], grids: list[CameraView], have: list[int], depth_of, prior,
                    colours_of, fusion: FusionOptions, report=None, stage: str = "fusion",
                    references: list[int] | None = None, neighbours: dict | None = None) -> FusedPoints:
    """The depth maps of the images ``have`` (``depth_of(k)``, on ``grids[k]``) fused into points (ENU): each
    reference image's (``references``, default all of ``have``; the others only confirm) not-yet-used pixels
    confirmed by its neighbours (default: footprints at the prior's ground height, fusion_neighbours), then,
    when ``fusion.edge_min_b_over_d`` > 0, the edge sweep. ``colours_of(i)``: image i's RGB on its grid.
    Progress is reported over the first sweep."""
    report = report or (lambda stage, done, total: None)
    refs = list(have) if references is None else [i for i in have if i in set(references)]
    if neighbours is None:
        neighbours = fusion_neighbours(views, have, [p.ground_up_m for p in prior.views],
                                       [p.depth_hi_m for p in prior.views], fusion)
    used = {i: np.zeros((grids[i].height, grids[i].width), bool) for i in have}
    parts = []
    sweeps = (False, True) if fusion.edge_min_b_over_d > 0 else (False,)
    for edge in sweeps:      # second sweep: two-view points at edges and beside occluders
        if not edge:
            report(stage, 0, len(refs))
        for n_done, i in enumerate(refs, start=1):
            parts.append(fuse_view(i, grids, depth_of, used, [j for j in neighbours[i] if j in used], colours_of(i),
                                   fusion, edge=edge))
            if not edge:
                report(stage, n_done, len(refs))
    return concatenate(parts)
