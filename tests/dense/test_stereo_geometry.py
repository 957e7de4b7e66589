"""Geometry of the dense step without images: camera views, rectification, disparity -> depth, sub-pixel
refinement on a synthetic shifted texture, multi-view fusion on synthetic depth maps, pair selection."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from georef_core.dense.camera_views import CameraView, apply_distortion
from georef_core.dense.depth_fusion import FusionOptions, fuse_view, sample_bilinear
from georef_core.dense.rectified_stereo import (RectifiedPair, StereoOptions, depth_in_reference, rectify_pair,
                                                refine_disparity, sgbm_disparity)

DIST = np.array([-0.118, 0.082, 0.00062, -0.00041, -0.012])


def rot_z(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])


def nadir_view(x: float, y: float, h: float = 50.0, yaw_deg: float = 0.0, tilt_deg: float = 0.0,
               dist=DIST, size=(640, 480), f=560.0, name="v") -> CameraView:
    """Camera looking down: camera x = east, y = south (rotated by yaw about the vertical, tilted about x)."""
    R_cam_to_enu = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])
    t = np.radians(tilt_deg)
    tilt = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    R_cam_to_enu = rot_z(yaw_deg) @ R_cam_to_enu @ tilt
    K = np.array([[f, 0, size[0] / 2 + 2.3], [0, f, size[1] / 2 - 1.7], [0, 0, 1.0]])
    return CameraView(name, Path("/nonexistent.jpg"), size[0], size[1], K, np.asarray(dist, float), R_cam_to_enu.T,
                      np.array([x, y, h]), size[0], size[1])


def test_projection_matches_opencv_and_scaling():
    v = nadir_view(3.0, -2.0, yaw_deg=17.0, tilt_deg=4.0)
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-20, 25, 500), rng.uniform(-20, 15, 500), rng.uniform(-1, 3, 500)])
    uv, z = v.project_distorted(X)
    rvec, _ = cv2.Rodrigues(v.R_world_to_cam)
    tvec = -v.R_world_to_cam @ v.centre_enu_m
    ref, _ = cv2.projectPoints(X, rvec, tvec, v.K, v.dist)
    assert np.allclose(uv, ref.reshape(-1, 2), atol=1e-6)
    # back-projection of pinhole pixels at their depth returns the points
    uvp, zp = v.project_pinhole(X)
    assert np.allclose(v.centre_enu_m + zp[:, None] * v.rays_enu(uvp[:, 0], uvp[:, 1]), X, atol=1e-9)
    # scaling by 1/2 maps pixel u to (u + 0.5) / 2 - 0.5
    h = v.scaled(0.5)
    assert (h.width, h.height) == (320, 240)
    uvh, _ = h.project_distorted(X)
    assert np.allclose(uvh, (uv + 0.5) * 0.5 - 0.5, atol=1e-9)
    xd, yd = apply_distortion(np.array([0.0]), np.array([0.0]), v.dist)
    assert xd[0] == 0.0 and yd[0] == 0.0


@pytest.mark.parametrize("offset,yaw", [((8.0, 0.0), 0.0), ((0.5, 9.0), 30.0), ((-7.0, -6.0), -60.0)])
def test_rectification_aligns_rows_and_gives_depth(offset, yaw):
    ref = nadir_view(0.0, 0.0, yaw_deg=yaw, tilt_deg=2.0)
    src = nadir_view(offset[0], offset[1], h=50.6, yaw_deg=yaw + 3.0, tilt_deg=-1.5)
    pair = rectify_pair(ref, src, 46.0, 54.0)
    assert pair is not None
    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(-10, 10, 300), rng.uniform(-10, 10, 300), rng.uniform(-2, 2, 300)])
    pr = (X - ref.centre_enu_m) @ pair.R_world_to_rect.T
    ps = (X - src.centre_enu_m) @ pair.R_world_to_rect.T
    ur = pair.K_ref @ (pr / pr[:, 2:3]).T
    us = pair.K_src @ (ps / ps[:, 2:3]).T
    assert np.allclose(ur[1], us[1], atol=1e-9)  # same row
    d_true = (ur[0] - us[0]) + pair.d_offset_px
    assert np.allclose(pair.f_px * pair.baseline_m / d_true, pr[:, 2], rtol=1e-9)
    # the search range holds every depth of 46..54 m
    lo, hi = pair.min_disparity, pair.min_disparity + pair.num_disparities
    for Z in (46.0, 54.0):
        assert lo <= pair.f_px * pair.baseline_m / Z - pair.d_offset_px <= hi
    # OpenCV's rectification maps follow the same model (R = rotation from the camera to the rectified axes)
    mx, my = cv2.initUndistortRectifyMap(ref.K, ref.dist, pair.R_ref_to_rect, pair.K_ref, (pair.width, pair.height),
                                         cv2.CV_32FC1)
    ok = (ur[0] > 1) & (ur[0] < pair.width - 2) & (ur[1] > 1) & (ur[1] < pair.height - 2)
    uv_img, _ = ref.project_distorted(X[ok])
    mapped = np.column_stack([sample_bilinear(mx.astype(np.float64), ur[0, ok], ur[1, ok]),
                              sample_bilinear(my.astype(np.float64), ur[0, ok], ur[1, ok])])
    assert ok.sum() > 50
    assert np.nanmax(np.abs(mapped - uv_img)) < 0.02


def test_disparity_to_reference_depth_on_a_plane():
    ref = nadir_view(0.0, 0.0, yaw_deg=25.0, tilt_deg=3.0)
    src = nadir_view(9.0, 2.0, yaw_deg=21.0)
    pair = rectify_pair(ref, src, 45.0, 55.0)
    # canvas disparity of the plane z = 0.3 + 0.05 x
    v, u = np.mgrid[0:pair.height, 0:pair.width].astype(np.float64)
    rays = np.stack([(u - pair.K_ref[0, 2]) / pair.f_px, (v - pair.K_ref[1, 2]) / pair.f_px, np.ones_like(u)], -1)
    rays_enu = rays @ pair.R_world_to_rect  # rectified -> ENU
    C = ref.centre_enu_m
    t = (0.3 + 0.05 * C[0] - C[2]) / (rays_enu[..., 2] - 0.05 * rays_enu[..., 0])
    D = (pair.f_px * pair.baseline_m / t - pair.d_offset_px).astype(np.float32)  # t = rectified z (ray z = 1)
    grid = ref.scaled(0.5)
    depth = depth_in_reference(pair, D, grid)
    gv, gu = np.mgrid[0:grid.height, 0:grid.width].astype(np.float64)
    gr = grid.rays_enu(gu.ravel(), gv.ravel())
    tz = ((0.3 + 0.05 * C[0] - C[2]) / (gr[:, 2] - 0.05 * gr[:, 0])).reshape(gu.shape)
    ok = np.isfinite(depth)
    assert ok.mean() > 0.6
    assert np.max(np.abs(depth[ok] - tz[ok])) < 1e-3 * 50


def _texture(h: int, w: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 1.2)
    return np.clip(128 + 60 * t / t.std(), 1, 255).astype(np.uint8)


def test_subpixel_refinement_removes_pixel_locking():
    h, w, d0 = 200, 320, 5.37
    left = _texture(h, w, 3)
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    # right image: the left scene seen d0 pixels further left, 8 % brighter
    right = cv2.remap(left.astype(np.float32), xs + np.float32(d0), ys, cv2.INTER_CUBIC)
    right = np.clip(right * 1.08, 1, 255).astype(np.uint8)
    pair = RectifiedPair(1.0, 1.0, np.eye(3), np.eye(3), np.eye(3), np.eye(3), np.eye(3), w, h, 0.0, 0, 16)
    o = StereoOptions()
    d_sgbm = sgbm_disparity(left, right, pair, o)
    d_ref = refine_disparity(left, right, d_sgbm, o)
    inner = np.zeros((h, w), bool)
    inner[20:-20, 40:-20] = True
    e_sgbm = np.nanmean(np.abs(d_sgbm[inner] - d0))
    e_ref = np.nanmean(np.abs(d_ref[inner] - d0))
    assert np.isfinite(d_ref[inner]).mean() > 0.9
    assert e_ref < 0.05, (e_sgbm, e_ref)
    assert e_ref < 0.5 * e_sgbm, (e_sgbm, e_ref)


def test_fusion_keeps_confirmed_points_once():
    """Four views of the plane z = 0 with 1 cm depth noise; one view has a blob of wrong depths (+2 m)."""
    views = [nadir_view(x, y, dist=np.zeros(5), size=(200, 150), f=200.0, name=f"v{k}")
             for k, (x, y) in enumerate([(0, 0), (8, 0), (0, 8), (8, 8)])]
    rng = np.random.default_rng(5)
    depths = []
    for v in views:
        vv, uu = np.mgrid[0:v.height, 0:v.width]
        r = v.rays_enu(uu.ravel(), vv.ravel())
        z = (-v.centre_enu_m[2] / r[:, 2]).reshape(vv.shape)
        depths.append((z + rng.normal(0, 0.01, z.shape)).astype(np.float32))
    depths[0][40:80, 50:100] += 2.0
    used = [np.zeros(d.shape, bool) for d in depths]
    colours = np.zeros((150, 200, 3), np.uint8)
    opts = FusionOptions(min_views=3, max_relative_depth_diff=0.005)
    parts = [fuse_view(i, views, lambda k: depths[k], used, [j for j in range(4) if j != i], colours, opts)
             for i in range(4)]
    xyz = np.concatenate([p.xyz_enu_m for p in parts])
    n_views = np.concatenate([p.n_views for p in parts])
    assert np.all(n_views >= 3)
    assert np.max(np.abs(xyz[:, 2])) < 0.05  # no outlier survived
    assert np.std(xyz[:, 2]) < 0.01  # averaged: below the 1 cm single-view noise
    # the blob's ground is not output from view 0 ...
    v0 = views[0]
    uv, _ = v0.project_pinhole(parts[0].xyz_enu_m)
    in_blob = (uv[:, 0] > 51) & (uv[:, 0] < 98) & (uv[:, 1] > 41) & (uv[:, 1] < 78)
    assert not in_blob.any()
    # ... and the surface is output about once: far fewer points than the views' pixels
    assert len(xyz) < 0.5 * sum(d.size for d in depths)
    spacing = 50.0 / 200.0  # m per pixel on the ground
    footprint = (200 * spacing + 8) * (150 * spacing + 8)
    assert len(xyz) < 1.6 * footprint / spacing ** 2


def test_pair_selection_on_the_simulated_flight(dense_sim):
    from georef_core.dense.camera_views import views_from_oriented
    from georef_core.dense.pair_selection import select_sources
    from georef_core.dense.sparse_prior import build_sparse_prior
    from georef_core.photo.oriented_images import oriented_images_from_simulator_truth

    oi = oriented_images_from_simulator_truth(dense_sim.out_dir)
    views = views_from_oriented(oi, 1600)
    prior = build_sparse_prior(views)
    assert prior.source.startswith("triangulated")
    for k, pv in enumerate(prior.views):  # 40 m flight over nearly flat ground
        assert 37.0 < pv.depth_med_m < 42.0 and pv.n_points > 100, (k, pv)
    sources = select_sources(views, prior)
    names = [v.name for v in views]
    for i, src in enumerate(sources):
        assert 2 <= len(src) <= 3
        for p in src:
            assert p.overlap >= 0.5 and 0.05 <= p.b_over_d <= 0.6
        dirs = [p.direction_deg for p in src]
        for a in range(len(dirs)):
            for b in range(a):
                assert abs((dirs[a] - dirs[b] + 180) % 360 - 180) >= 40
    # an inner image of a line gets the images before and after it on the line
    i = names.index("IMG_0003.JPG")
    partners = {names[p.src] for p in sources[i]}
    assert {"IMG_0002.JPG", "IMG_0004.JPG"} <= partners


def test_global_shutter_maps_undo_the_readout_motion():
    """A nadir rolling-shutter view flying north (camera -y) at 5 m/s, 40 ms readout, 50 m above flat
    ground: the map takes each pixel of the virtual global-shutter image from where its ground point lay in
    the real image (seen from the row's own camera centre), to 0.02 px; at half scale too."""
    from dataclasses import replace

    from georef_core.dense.camera_views import global_shutter_maps

    view = replace(nadir_view(0.0, 0.0, h=50.0, dist=np.zeros(5)), readout_s=0.040,
                   velocity_enu_m_s=np.array([0.0, 5.0, 0.0]), scene_depth_m=50.0)
    for v_ in (view, view.scaled(0.5)):
        mx, my = global_shutter_maps(v_)
        for u, v in ((10, 10), (320, 240), (600, 30), (50, 470)):
            u, v = u * v_.width // 640, v * v_.height // 480
            ground = v_.centre_enu_m + 50.0 * v_.rays_enu(np.array([float(u)]), np.array([float(v)]))[0]
            # where the real image shows that ground point: its row's camera centre, found by iterating
            row = float(v)
            for _ in range(5):
                full_row = (row + 0.5) * 480 / v_.height - 0.5
                c = v_.centre_enu_m + v_.velocity_enu_m_s * 0.040 * (full_row / 480 - 0.5)
                uv, _ = replace(v_, centre_enu_m=c).project_pinhole(ground[None])
                row = uv[0, 1]
            assert abs(mx[v, u] - uv[0, 0]) < 0.02 and abs(my[v, u] - uv[0, 1]) < 0.02, (u, v, mx[v, u], my[v, u], uv)
    # the motion is along the image's y axis: the rows move by up to f v tau / 2 / h = 1.1 px, the columns not
    mx, my = global_shutter_maps(view)
    u0, v0 = np.meshgrid(np.arange(640.0), np.arange(480.0))
    assert 1.0 < np.abs(my - v0).max() < 1.2 and np.abs(mx - u0).max() < 0.01
