"""The coarse pass of the dense step: the same pairs matched again at a lower resolution, fused into a
second point cloud that fills the DSM where the full-resolution pass found no support.

Why: semi-global matching needs texture at the scale of its window (5 px). Graded soil, gravel pads,
water-smoothed sand and crop rows often have none at the ground sample distance but plenty at 4-8 x
that scale (colour mottling, tyre tracks, clods). Matching the images reduced by ``factor`` sees that
texture with the same window; each coarse depth pixel covers ``factor`` x ``factor`` matching pixels.
The coarse depth maps are made and fused by the same loop as the fine ones (depth_pass.py: the same
multi-view consistency rule and the same edge sweep), so a coarse point is still confirmed by independent views: it is *measured*, at a lower
resolution (a pile's crest or a kerb is smoothed over ~factor matching pixels), not interpolated.

Cost: 1/factor^2 of the pixels: about 1/10 of the fine pass at factor 4 (measured in docs/dense.md).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .camera_views import CameraView
from .depth_fusion import FusedPoints, FusionOptions, concatenate
from .depth_pass import depth_maps, fuse_depth_maps
from .rectified_stereo import StereoOptions


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
    depth, t_depth = coarse_depth_maps(views_c, prior, sources, stereo, workers, report)
    return fuse_coarse(views_c, prior, depth, fusion, t_depth)


def coarse_depth_maps(views_c: list[CameraView], prior, sources, stereo: StereoOptions, workers: int, report=None,
                      todo: list[int] | None = None) -> tuple[dict[int, np.ndarray], float]:
    """The coarse depth maps of the views ``todo`` (default: every view with partners): {view: depth} (only
    those with some depth) and the seconds taken. A tiled run computes them once per image
    (steps/dense_tiles.py, its depth parts)."""
    t0 = time.perf_counter()
    todo = [i for i in range(len(views_c)) if sources[i]] if todo is None else list(todo)
    # small images: those matched all in memory (200 KB each at 400 x 300)
    needed = sorted(set(todo) | {p.src for i in todo for p in sources[i]})
    grays = {k: views_c[k].read_image(gray=True) for k in needed}
    depth: dict[int, np.ndarray] = {}
    depth_maps(views_c, views_c, grays.__getitem__, prior, sources, stereo, workers, depth.__setitem__, report,
               stage="coarse depth maps", todo=todo)
    return depth, time.perf_counter() - t0


def fuse_coarse(views_c: list[CameraView], prior, depth: dict[int, np.ndarray], fusion: FusionOptions,
                t_depth: float = 0.0, references: list[int] | None = None) -> tuple[FusedPoints, dict]:
    """The coarse depth maps ``depth`` fused (first sweep, then the edge sweep), the views ``references``
    (default: all) as references, the others confirming only; the points (ENU) and figures."""
    have = sorted(depth)
    info = {"factor_size_px": [views_c[0].width, views_c[0].height], "images_with_depth": len(have)}
    if len(have) < 2:
        info["timings_s"] = {"depth_maps": round(t_depth, 3), "fusion": 0.0}
        return concatenate([]), info
    t1 = time.perf_counter()
    blank: dict[int, np.ndarray] = {}    # the coarse points take no colour

    def colours_of(i: int) -> np.ndarray:
        if i not in blank:
            blank[i] = np.zeros((views_c[i].height, views_c[i].width, 3), np.uint8)
        return blank[i]

    fused = fuse_depth_maps(views_c, views_c, have, depth.__getitem__, prior, colours_of, fusion,
                            references=references)
    info["timings_s"] = {"depth_maps": round(t_depth, 3), "fusion": round(time.perf_counter() - t1, 3)}
    info["points"] = int(len(fused.xyz_enu_m))
    return fused, info
