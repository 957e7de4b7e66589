"""The dense plan's block-wide choices (sparse prior per view, stereo partners, fusion neighbours, ORB pairs) find
each image's candidates without testing every pair (images^2 at 1000 images): the same choices as the exact test
over every pair (written out here as the reference), on a synthetic block of nadir and tilted views."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from georef_core.dense.camera_views import CameraView
from georef_core.dense.depth_fusion import FusionOptions, fusion_neighbours
from georef_core.dense.pair_selection import (PairSelectionOptions, candidate_pairs, footprint_overlap,
                                              _within_reach)
from georef_core.dense.sparse_prior import SparsePrior, ViewDepth, _PointsNear, build_sparse_prior, nearest_neighbours


def _rot(yaw_deg: float, tilt_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """World (ENU) -> camera (x right, y down, z forward): nadir looking down, then tilted about camera x."""
    nadir = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])
    y, t, r = np.radians([yaw_deg, tilt_deg, roll_deg])
    Rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    Ry = np.array([[np.cos(r), 0, np.sin(r)], [0, 1, 0], [-np.sin(r), 0, np.cos(r)]])
    return Ry @ Rx @ nadir @ Rz.T


def _view(k: int, centre, R) -> CameraView:
    w, h, f = 400, 300, 380.0
    K = np.array([[f, 0, w / 2 - 0.5], [0, f, h / 2 - 0.5], [0, 0, 1.0]])
    return CameraView(f"img{k:04d}.jpg", Path(f"img{k:04d}.jpg"), w, h, K, np.zeros(5), R,
                      np.asarray(centre, float), w, h)


def _block(n_lines: int = 10, per_line: int = 16, seed: int = 3) -> list[CameraView]:
    """A lawnmower block at ~60 m over 0-6 m relief: 80 % forward, 70 % side overlap, jittered attitudes;
    a few strongly tilted views (45 and 80 degrees: a corner ray at or above the horizon) and one view flown
    below the highest points."""
    rng = np.random.default_rng(seed)
    views = []
    for li in range(n_lines):
        for k in range(per_line):
            x = li * 18.0 + rng.normal(0, 0.5)
            y = (k if li % 2 == 0 else per_line - 1 - k) * 12.0 + rng.normal(0, 0.5)
            yaw = (0.0 if li % 2 == 0 else 180.0) + rng.normal(0, 3)
            views.append(_view(len(views), [x, y, 60.0 + rng.normal(0, 1)],
                               _rot(yaw, rng.normal(0, 2), rng.normal(0, 2))))
    for tilt in (45.0, 80.0):
        views.append(_view(len(views), [100.0, 100.0, 62.0], _rot(30.0, tilt)))
    views.append(_view(len(views), [60.0, 60.0, 4.0], _rot(0.0, 0.0)))   # below the highest points
    return views


def _ground_points(n: int = 20000, seed: int = 4) -> np.ndarray:
    rng = np.random.default_rng(seed)
    xy = rng.uniform([-40, -40], [280, 300], size=(n, 2))
    z = 3.0 + 3.0 * np.sin(xy[:, 0] / 30.0) * np.cos(xy[:, 1] / 40.0)
    return np.column_stack([xy, z])


def _prior_reference(views, xyz) -> list[tuple]:
    """Every point projected into every view (the exact test build_sparse_prior applies)."""
    out = []
    for v in views:
        uv, z = v.project_pinhole(xyz)
        ok = (z > 0) & v.inside(uv)
        if ok.sum() >= 10:
            lo, md, hi = np.percentile(z[ok], [2, 50, 98])
            out.append((lo, md, hi, float(np.median(xyz[ok, 2])), int(ok.sum())))
        else:
            out.append(None)
    return out


def test_points_near_a_view_are_a_superset_of_those_it_sees_and_few():
    views = _block()
    xyz = _ground_points()
    near = _PointsNear(xyz)
    fractions = []
    for v in views:
        idx = near.in_view(v)
        uv, z = v.project_pinhole(xyz)
        seen = np.flatnonzero((z > 0) & v.inside(uv))
        assert np.all(np.isin(seen, idx)), v.name              # nothing the view sees is left out
        assert np.all(np.diff(idx) > 0)                          # original order, each point once
        fractions.append(len(idx) / len(xyz))
    # a nadir view over a 320 x 340 m point cloud gets a few % of the points (its footprint ~63 x 47 m), not all
    assert np.median(fractions) < 0.06
    # the 80-degree view (a corner ray above the horizon) and the one below the highest points get them all
    assert fractions[-2] == 1.0 and fractions[-1] == 1.0


def test_sparse_prior_is_that_of_every_point_in_every_view():
    views = _block()
    xyz = _ground_points()
    prior = build_sparse_prior(views, xyz)
    ref = _prior_reference(views, xyz)
    # build_sparse_prior cuts gross outliers first: none here (a smooth surface)
    assert len(prior.xyz_enu_m) == len(xyz)
    for got, want in zip(prior.views, ref):
        if want is None:
            assert got.n_points == 0
            continue
        assert got.n_points == want[4]
        np.testing.assert_allclose([got.depth_lo_m, got.depth_med_m, got.depth_hi_m, got.ground_up_m], want[:4],
                                   rtol=1e-12, atol=1e-9)


def _candidates_reference(views, prior, opts):
    """Every ordered pair through the exact tests (the loop candidate_pairs ran before)."""
    C = np.array([v.centre_enu_m for v in views])
    A = np.array([v.optical_axis_enu for v in views])
    out = []
    for i, ref in enumerate(views):
        depth, ground = prior.views[i].depth_med_m, prior.views[i].ground_up_m
        got = []
        for j, src in enumerate(views):
            if j == i:
                continue
            bd = float(np.linalg.norm(C[j] - C[i])) / depth
            if not (opts.min_b_over_d <= bd <= opts.max_b_over_d):
                continue
            if float(np.degrees(np.arccos(np.clip(A[i] @ A[j], -1.0, 1.0)))) > opts.max_axis_angle_deg:
                continue
            ov = footprint_overlap(ref, src, ground)
            if ov >= opts.min_overlap:
                got.append((j, ov))
        out.append(got)
    return out


def _flat_prior(views) -> SparsePrior:
    return SparsePrior(np.zeros((0, 3)), [ViewDepth(0.8 * (v.centre_enu_m[2] - 3), v.centre_enu_m[2] - 3,
                                                    1.2 * (v.centre_enu_m[2] - 3), 3.0, 100) for v in views], "test")


def test_stereo_candidates_are_those_of_the_test_over_every_pair():
    views = _block(6, 11)
    prior = _flat_prior(views)
    opts = PairSelectionOptions()
    got = candidate_pairs(views, prior, opts)
    ref = _candidates_reference(views, prior, opts)
    assert sum(len(r) for r in ref) > 5 * len(views)           # the block has pairs to find
    for i, (g, r) in enumerate(zip(got, ref)):
        assert sorted((p.src, p.overlap) for p in g) == sorted(r), i
    # the prefilter leaves a handful of candidates per image, not the block
    C = np.array([v.centre_enu_m for v in views])
    A = np.array([v.optical_axis_enu for v in views])
    reach = [len(_within_reach(C, A, i, prior.views[i].depth_med_m, opts)) for i in range(len(views))]
    assert np.median(reach) < 0.25 * len(views)
    # a view without a usable depth sends every other view to the exact test (which rejects them all)
    bad = SparsePrior(prior.xyz_enu_m, [ViewDepth(np.nan, np.nan, np.nan, 3.0, 0)] + prior.views[1:], "test")
    assert len(_within_reach(C, A, 0, np.nan, opts)) == len(views) - 1
    assert candidate_pairs(views, bad, opts)[0] == []


def test_fusion_neighbours_are_those_of_the_test_over_every_pair():
    views = _block(6, 11)
    have = [i for i in range(len(views)) if i % 5 != 2]          # not every view has a depth map
    ground = [3.0] * len(views)
    depth_hi = [1.2 * (v.centre_enu_m[2] - 3) for v in views]
    opts = FusionOptions()
    got = fusion_neighbours(views, have, ground, depth_hi, opts)
    C = np.array([v.centre_enu_m for v in views])
    A = np.array([v.optical_axis_enu for v in views])
    for i in have:
        v = views[i]
        reach = 2.0 * depth_hi[i] * 0.5 * np.hypot(v.width, v.height) / v.focal_px
        cand = []
        for j in have:
            if j == i or A[i] @ A[j] < np.cos(np.radians(45.0)) or np.linalg.norm(C[j] - C[i]) > reach:
                continue
            ov = footprint_overlap(v, views[j], ground[i])
            if ov >= opts.min_neighbour_overlap:
                cand.append((ov, j))
        cand.sort(reverse=True)
        assert got[i] == [j for _, j in cand[: opts.max_neighbours]], i
    assert np.mean([len(g) for g in got.values()]) > 4


def test_orb_pairs_are_each_images_k_nearest_with_a_similar_axis():
    views = _block(6, 10)
    C = np.array([v.centre_enu_m for v in views])
    A = np.array([v.optical_axis_enu for v in views])
    d = np.linalg.norm(C[:, None] - C[None], axis=2)
    np.fill_diagonal(d, np.inf)
    want = set()
    for i in range(len(views)):
        order = [j for j in np.argsort(d[i]) if np.isfinite(d[i, j]) and A[i] @ A[j] >= np.cos(np.radians(45.0))]
        want |= {(min(i, int(j)), max(i, int(j))) for j in order[:4]}
    assert nearest_neighbours(views, 4) == sorted(want)


@pytest.mark.parametrize("n_lines", [20])
def test_the_prior_on_a_large_block_takes_a_fraction_of_every_point_in_every_view(n_lines):
    """The point of the index: at ~450 views and 100 000 points the per-view statistics take a fraction of the
    exact test over every point (the reference loop), on the same machine in the same test."""
    views = _block(n_lines, 22)
    xyz = _ground_points(100000)
    t0 = time.perf_counter()
    build_sparse_prior(views, xyz)
    t_index = time.perf_counter() - t0
    t0 = time.perf_counter()
    _prior_reference(views[:60], xyz)
    t_every = (time.perf_counter() - t0) * len(views) / 60
    assert t_index < 0.5 * t_every, (t_index, t_every)
