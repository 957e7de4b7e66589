"""Stereo partners ("source views") of each reference image.

A candidate partner must see a large part of the reference's ground footprint (overlap), have a useful
baseline-to-depth ratio (too small: poor depth precision; too large: perspective differences and
occlusions that defeat window matching) and look in nearly the same direction (rectification of
strongly rotated pairs wastes pixels). Candidates are scored by overlap times a preference for a
baseline/depth near ``target_b_over_d``; the best ones are taken greedily, each new one in a baseline
direction (seen from the reference) at least ``min_direction_separation_deg`` away from those already
chosen, so that a reference gets partners on different sides (ahead, behind, the next flight line)
and parts occluded in one pair are seen in another.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera_views import CameraView
from .sparse_prior import SparsePrior


@dataclass
class PairSelectionOptions:
    n_sources: int = 3
    min_overlap: float = 0.5
    min_b_over_d: float = 0.05
    max_b_over_d: float = 0.6
    target_b_over_d: float = 0.25
    max_axis_angle_deg: float = 20.0
    min_direction_separation_deg: float = 40.0


@dataclass
class StereoPair:
    ref: int
    src: int
    overlap: float
    baseline_m: float
    b_over_d: float
    axis_angle_deg: float
    direction_deg: float  # baseline direction in the reference image (0 = +x, 90 = +y)
    score: float


def footprint_overlap(ref: CameraView, src: CameraView, ground_up_m: float, n: int = 12) -> float:
    """Fraction of an n x n grid of reference pixels whose ground point (rays cut with the horizontal plane
    at ``ground_up_m``) falls inside the partner image."""
    u, v = np.meshgrid((np.arange(n) + 0.5) / n * ref.width - 0.5, (np.arange(n) + 0.5) / n * ref.height - 0.5)
    rays = ref.rays_enu(u.ravel(), v.ravel())
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ground_up_m - ref.centre_enu_m[2]) / rays[:, 2]
    ok = np.isfinite(t) & (t > 0)
    if not ok.any():
        return 0.0
    X = ref.centre_enu_m + t[ok, None] * rays[ok]
    uv, z = src.project_pinhole(X)
    return float(np.count_nonzero((z > 0) & src.inside(uv)) / len(t))


def _within_reach(C: np.ndarray, A: np.ndarray, i: int, depth_m: float, opts: PairSelectionOptions) -> list[int]:
    """Indices j != i whose baseline-to-depth ratio and axis angle may pass candidate_pairs' tests (a superset:
    bounds widened by 1e-9 relative, so that rounding never drops a pair the exact per-pair test keeps)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        bd = np.sqrt(np.sum((C - C[i]) ** 2, axis=1)) / depth_m
    cos_min = np.cos(np.radians(opts.max_axis_angle_deg))
    near = ((bd >= opts.min_b_over_d * (1 - 1e-9)) & (bd <= opts.max_b_over_d * (1 + 1e-9))
            & ~(A @ A[i] < cos_min - 1e-9))   # a NaN axis goes on to the exact test, as before
    near[i] = False
    if not np.isfinite(depth_m) or depth_m <= 0:
        near[:] = True     # no usable depth: every partner goes to the exact test, as before
        near[i] = False
    return [int(j) for j in np.flatnonzero(near)]


def candidate_pairs(views: list[CameraView], prior: SparsePrior, opts: PairSelectionOptions) -> list[list[StereoPair]]:
    """All acceptable partners of each view, best score first."""
    C = np.array([v.centre_enu_m for v in views])
    A = np.array([v.optical_axis_enu for v in views])
    out = []
    for i, ref in enumerate(views):
        depth = prior.views[i].depth_med_m
        ground = prior.views[i].ground_up_m
        cands = []
        # the partners within reach, found at once for the whole block (a loop over every pair costs seconds per
        # hundred images and grows as images^2); a slightly wider test than the exact one below, which decides
        for j in _within_reach(C, A, i, depth, opts):
            src = views[j]
            b = float(np.linalg.norm(C[j] - C[i]))
            bd = b / depth
            if not (opts.min_b_over_d <= bd <= opts.max_b_over_d):
                continue
            ang = float(np.degrees(np.arccos(np.clip(A[i] @ A[j], -1.0, 1.0))))
            if ang > opts.max_axis_angle_deg:
                continue
            ov = footprint_overlap(ref, src, ground)
            if ov < opts.min_overlap:
                continue
            bc = ref.R_world_to_cam @ (C[j] - C[i])
            direction = float(np.degrees(np.arctan2(bc[1], bc[0])))
            score = ov * float(np.exp(-(((bd - opts.target_b_over_d) / 0.15) ** 2)))
            cands.append(StereoPair(i, j, ov, b, bd, ang, direction, score))
        cands.sort(key=lambda p: -p.score)
        out.append(cands)
    return out


def select_sources(views: list[CameraView], prior: SparsePrior,
                   opts: PairSelectionOptions | None = None) -> list[list[StereoPair]]:
    """Up to ``n_sources`` partners per reference view, in distinct baseline directions."""
    opts = opts or PairSelectionOptions()
    chosen_all = []
    for cands in candidate_pairs(views, prior, opts):
        chosen: list[StereoPair] = []
        for p in cands:
            if len(chosen) >= opts.n_sources:
                break
            sep = [abs((p.direction_deg - q.direction_deg + 180.0) % 360.0 - 180.0) for q in chosen]
            if all(s >= opts.min_direction_separation_deg for s in sep):
                chosen.append(p)
        chosen_all.append(chosen)
    return chosen_all
