"""Multi-view consistency filtering of per-image depth maps and their fusion into one point cloud.

Each image has a depth map on its own pinhole grid (the median over its stereo pairs). For each image in
turn, every depth pixel is turned into a 3-D point and projected into the neighbouring images; a
neighbour *confirms* it when its own depth map, interpolated at the projection, agrees with the
point's depth there within ``max_relative_depth_diff``. Pixels confirmed by at least
``min_views - 1`` neighbours (``min_views`` views in all, the reference included) are kept; the output
point is the mean of the reference's point and the confirming neighbours' points (their depths
back-projected along their own rays), which averages the noise of the independent matches. The
confirming neighbour pixels are then marked as used, so that the same surface element is not output
again when their image is the reference: the cloud has about one point per depth-map pixel of surface,
not one per view.

Edges and occlusions (a second sweep, ``fuse_view(..., edge=True)``, over the pixels the first left
unused): at the border of the block and beside tall objects a surface element is seen by only two
views. Such a pixel is kept when one neighbour agrees, no neighbour *contradicts* it (a neighbour whose
depth at the projection is larger than the point's, beyond the threshold, looks through the place where
the point would be: free-space violation; a smaller depth there is an occluder and no contradiction),
and the agreeing neighbour's baseline is at least ``edge_min_b_over_d`` of the depth (a good
intersection angle). The first sweep runs over every image before the second, so a surface element that
three views agree on is always output from the first.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera_views import CameraView


@dataclass
class FusionOptions:
    min_views: int = 3  # views agreeing on a point, the reference included
    max_relative_depth_diff: float = 0.005  # |z_neighbour - z_point| / z_point
    max_neighbours: int = 12
    min_neighbour_overlap: float = 0.1
    # second sweep (edges, occlusions): 2 agreeing views, no contradicting one, baseline >= this x depth (0: off)
    edge_min_b_over_d: float = 0.1


@dataclass
class FusedPoints:
    xyz_enu_m: np.ndarray  # (N, 3) float64
    rgb: np.ndarray  # (N, 3) uint8
    n_views: np.ndarray  # (N,) uint8, views agreeing (reference included)
    spread_m: np.ndarray  # (N,) float32, RMS distance of the views' points from their mean


def fusion_neighbours(views: list[CameraView], have: list[int], ground_up_m: list[float], depth_hi_m: list[float],
                      opts: FusionOptions) -> dict[int, list[int]]:
    """For each view with a depth map: the views (with depth maps) whose ground footprint covers at least
    ``min_neighbour_overlap`` of its own, most overlapping first, at most ``max_neighbours``."""
    from .pair_selection import footprint_overlap

    C = np.array([v.centre_enu_m for v in views])
    A = np.array([v.optical_axis_enu for v in views])
    have_arr = np.asarray(list(have), int)
    out = {}
    for i in have:
        v = views[i]
        # footprints cannot meet beyond twice the footprint radius
        reach = 2.0 * depth_hi_m[i] * 0.5 * np.hypot(v.width, v.height) / v.focal_px
        cand = []
        # those within reach found at once (a loop over every pair grows as images^2: seconds at 1000 images);
        # a slightly wider test than the exact one below, which decides
        if len(have_arr):
            dist = np.sqrt(np.sum((C[have_arr] - C[i]) ** 2, axis=1))
            near = ~(A[have_arr] @ A[i] < np.cos(np.radians(45.0)) - 1e-9) & ~(dist > reach * (1 + 1e-9) + 1e-9)
            candidates = [int(j) for j in have_arr[near]]
        else:
            candidates = []
        for j in candidates:
            if j == i or A[i] @ A[j] < np.cos(np.radians(45.0)) or np.linalg.norm(C[j] - C[i]) > reach:
                continue
            ov = footprint_overlap(v, views[j], ground_up_m[i])
            if ov >= opts.min_neighbour_overlap:
                cand.append((ov, j))
        cand.sort(reverse=True)
        out[i] = [j for _, j in cand[: opts.max_neighbours]]
    return out


def sample_bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of a float image at (u, v) (pixel centres at integers); NaN outside the image
    or when any of the four neighbours is NaN."""
    h, w = img.shape
    u0 = np.floor(u).astype(np.int64)
    v0 = np.floor(v).astype(np.int64)
    ok = (u0 >= 0) & (v0 >= 0) & (u0 < w - 1) & (v0 < h - 1)
    u0c = np.where(ok, u0, 0)
    v0c = np.where(ok, v0, 0)
    fu = (u - u0c).astype(np.float32)
    fv = (v - v0c).astype(np.float32)
    a = img[v0c, u0c]
    b = img[v0c, u0c + 1]
    c = img[v0c + 1, u0c]
    d = img[v0c + 1, u0c + 1]
    out = (a * (1 - fu) + b * fu) * (1 - fv) + (c * (1 - fu) + d * fu) * fv
    out[~ok] = np.nan
    return out


def fuse_view(i: int, grids: list[CameraView], depth_of, used: list[np.ndarray], neighbours: list[int],
              colours: np.ndarray, opts: FusionOptions, edge: bool = False) -> FusedPoints:
    """Fuse the not-yet-used pixels of view ``i``; marks the confirming pixels of the neighbours as used.
    ``depth_of(k)`` returns view k's depth map; ``colours`` is view i's RGB image on its grid. ``edge``:
    the second sweep's rule (two agreeing views, none contradicting, a good baseline; module docstring)."""
    g = grids[i]
    D = np.asarray(depth_of(i))
    sel = np.isfinite(D) & ~used[i]
    v, u = np.nonzero(sel)
    z = D[v, u].astype(np.float64)
    X = g.centre_enu_m + z[:, None] * g.rays_enu(u, v)
    total = np.zeros_like(X)  # sums of the confirming points' offsets from the reference's point
    total_sq = np.zeros(len(X))
    count = np.ones(len(X), np.int32)
    conflict = np.zeros(len(X), bool)
    best_bd = np.zeros(len(X))  # largest baseline / depth of an agreeing neighbour
    marks = []
    for m in neighbours:
        gm = grids[m]
        uv, zm = gm.project_pinhole(X)
        inside = (zm > 0) & gm.inside(uv)
        idx = np.nonzero(inside)[0]
        if len(idx) == 0:
            continue
        um, vm = uv[idx, 0], uv[idx, 1]
        zs = sample_bilinear(np.asarray(depth_of(m)), um, vm).astype(np.float64)
        with np.errstate(invalid="ignore"):
            ok = np.abs(zs - zm[idx]) <= opts.max_relative_depth_diff * zm[idx]
            if edge:
                conflict[idx[zs > (1.0 + opts.max_relative_depth_diff) * zm[idx]]] = True
        idx, um, vm, zs = idx[ok], um[ok], vm[ok], zs[ok]
        if edge:
            bd = float(np.linalg.norm(gm.centre_enu_m - g.centre_enu_m)) / z[idx]
            best_bd[idx] = np.maximum(best_bd[idx], bd)
        Xm = gm.centre_enu_m + zs[:, None] * gm.rays_enu(um, vm)
        dX = Xm - X[idx]
        total[idx] += dX
        total_sq[idx] += np.sum(dX * dX, axis=1)
        count[idx] += 1
        marks.append((m, idx, np.rint(um).astype(np.int64), np.rint(vm).astype(np.int64)))
    if edge:
        keep = (count >= 2) & ~conflict & (best_bd >= opts.edge_min_b_over_d)
    else:
        keep = count >= opts.min_views
    for m, idx, um, vm in marks:
        k = keep[idx]
        hm, wm = used[m].shape
        um_k = np.clip(um[k], 0, wm - 1)
        vm_k = np.clip(vm[k], 0, hm - 1)
        used[m][vm_k, um_k] = True
    mean_offset = total[keep] / count[keep, None]
    mean = X[keep] + mean_offset
    var = total_sq[keep] / count[keep] - np.sum(mean_offset * mean_offset, axis=1)
    spread = np.sqrt(np.maximum(var, 0.0)).astype(np.float32)
    rgb = colours[v[keep], u[keep]]
    used[i][v[keep], u[keep]] = True
    return FusedPoints(mean, rgb, count[keep].astype(np.uint8), spread)


def concatenate(parts: list[FusedPoints]) -> FusedPoints:
    if not parts:
        return FusedPoints(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0, np.uint8), np.zeros(0, np.float32))
    return FusedPoints(np.concatenate([p.xyz_enu_m for p in parts]), np.concatenate([p.rgb for p in parts]),
                       np.concatenate([p.n_views for p in parts]), np.concatenate([p.spread_m for p in parts]))
