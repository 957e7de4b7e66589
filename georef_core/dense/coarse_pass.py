"""The coarse pass of the dense step: the same pairs matched again at a lower resolution, fused into a
second point cloud that fills the DSM where the full-resolution pass found no support.

Why: semi-global matching needs texture at the scale of its window (5 px). Graded soil, gravel pads,
water-smoothed sand and crop rows often have none at the ground sample distance but plenty at 4-8 x
that scale (colour mottling, tyre tracks, clods). Matching the images reduced by ``factor`` sees that
texture with the same window; each coarse depth pixel covers ``factor`` x ``factor`` matching pixels.
The coarse depth maps are fused with the same multi-view consistency rule (and the same edge sweep) as
the fine ones, so a coarse point is still confirmed by independent views: it is *measured*, at a lower
resolution (a pile's crest or a kerb is smoothed over ~factor matching pixels), not interpolated.

Cost: 1/factor^2 of the pixels: about 1/10 of the fine pass at factor 4 (measured in docs/dense.md).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .camera_views import CameraView
from .depth_fusion import FusedPoints, FusionOptions, concatenate, fuse_view, fusion_neighbours
from .rectified_stereo import StereoOptions, median_depth_map, pair_depth_map


@dataclass
class CoarseOptions:
    factor: float = 4.0  # the coarse pass matches at 1/factor of the matching size (<= 1: no coarse pass)
    min_size_px: int = 160  # no coarse pass when the coarse images would be smaller than this (longer side)


def coarse_views(views: list[CameraView], options: CoarseOptions) -> list[CameraView] | None:
    """The views at 1/factor of their size, or None when the coarse pass is off or would be too small."""
    if options.factor <= 1.0:
        return None
    out = [v.scaled(1.0 / options.factor) for v in views]
    if max(out[0].width, out[0].height) < options.min_size_px:
        return None
    return out


def coarse_points(views_c: list[CameraView], prior, sources, stereo: StereoOptions, fusion: FusionOptions,
                  workers: int, report=None) -> tuple[FusedPoints, dict]:
    """Depth maps of every image at the coarse scale (pairs ``sources`` of the fine pass, depth ranges of
    ``prior``), fused (first sweep, then the edge sweep); the points (ENU) and figures."""
    report = report or (lambda stage, done, total: None)
    t0 = time.perf_counter()
    grays: dict[int, np.ndarray] = {}

    def gray(k: int) -> np.ndarray:
        g = grays.get(k)
        if g is None:
            g = grays[k] = views_c[k].read_image(gray=True)
        return g

    def depth_for(i: int):
        maps = []
        pv = prior.views[i]
        for p in sources[i]:
            dm, _ = pair_depth_map(views_c[i], views_c[p.src], gray(i), gray(p.src), pv.depth_lo_m, pv.depth_hi_m,
                                   views_c[i], stereo)
            if dm is not None:
                maps.append(dm)
        return i, (median_depth_map(maps) if maps else None)

    todo = [i for i in range(len(views_c)) if sources[i]]
    for k in range(len(views_c)):  # small images: all in memory (200 KB each at 400 x 300)
        gray(k)
    depth: dict[int, np.ndarray] = {}
    report("coarse depth maps", 0, len(todo))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for n, (i, d) in enumerate(pool.map(depth_for, todo), start=1):
            if d is not None and np.isfinite(d).any():
                depth[i] = d
            report("coarse depth maps", n, len(todo))
    t_depth = time.perf_counter() - t0
    grays.clear()
    have = sorted(depth)
    info = {"factor_size_px": [views_c[0].width, views_c[0].height], "images_with_depth": len(have)}
    if len(have) < 2:
        info["timings_s"] = {"depth_maps": round(t_depth, 3), "fusion": 0.0}
        return concatenate([]), info
    t1 = time.perf_counter()
    # footprints: the prior's ground height; neighbours as in the fine pass
    neighbours = fusion_neighbours(views_c, have, [p.ground_up_m for p in prior.views],
                                   [p.depth_hi_m for p in prior.views], fusion)
    used = {i: np.zeros((views_c[i].height, views_c[i].width), bool) for i in have}
    blank = {}
    parts = []
    sweeps = (False, True) if fusion.edge_min_b_over_d > 0 else (False,)
    for edge in sweeps:
        for i in have:
            if i not in blank:
                blank[i] = np.zeros((views_c[i].height, views_c[i].width, 3), np.uint8)
            parts.append(fuse_view(i, views_c, depth.__getitem__, used, [j for j in neighbours[i] if j in used],
                                   blank[i], fusion, edge=edge))
    fused = concatenate(parts)
    info["timings_s"] = {"depth_maps": round(t_depth, 3), "fusion": round(time.perf_counter() - t1, 3)}
    info["points"] = int(len(fused.xyz_enu_m))
    return fused, info
