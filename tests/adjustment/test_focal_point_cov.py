"""The check points' stated covariance carries the adjustment's global parameters (docs/dji.md, "Those check-point
height errors are the focal length's"): in a GNSS-aided nadir block at one height the focal length is set by its factory-calibration
prior, and a prior off by df moves every triangulated point along the axis by -(df/f) x the flying height. The image
noise alone (the triangulation's covariance) states a few millimetres for that; globals_point_cov adds the focal
length's (and the other globals') share. Synthetic block of make_block (no images), all cameras at 60 m."""

import numpy as np

from georef_core.adjustment.bundle_adjustment import BundleOptions, adjust
from georef_core.adjustment.camera_model import free_mask
from georef_core.adjustment.triangulation import triangulate
from georef_core.steps.georef import _Adjusted, globals_point_cov
from tests.adjustment.test_bundle_adjustment import TRUE_DELAY, TRUE_INTR, TRUE_LEVER, make_block

F_PRIOR_REL_SIGMA = 5e-4          # georef's FACTORY_CALIBRATION_SIGMA["f_rel"]
HEIGHT_M = 60.0


def _adjusted_from(res, n_cam: int) -> _Adjusted:
    p = res.problem
    return _Adjusted(names=[f"I{i}" for i in range(n_cam)], R_cam_to_enu=p.R_cam_to_enu, centre_enu_m=p.centre_enu_m,
                     centre_cov_enu_m2=res.camera_cov[:, 3:, 3:], intrinsics=np.asarray(p.intrinsics).reshape(1, 8),
                     intrinsics_sigma=[{}], lever_arm_cam_m=p.lever_arm_cam_m, lever_arm_sigma_m=None, delay_s=p.delay_s,
                     delay_sigma_s=None, correlations={}, points_enu_m=p.points_enu_m, points_rgb=None, gnss_rows=[],
                     blunders=[], used_measurements={}, stats={}, camera_group=np.zeros(n_cam, int),
                     global_names=res.global_names, global_cov=res.global_cov, camera_global_cov=res.camera_global_cov)


def test_check_point_height_sigma_carries_the_focal_length_prior():
    """The factory calibration's focal length 3 sigma (0.15 %) short: the adjusted focal length stays more than its
    sigma short (1.2 sigma here: the relief and the cameras' height spread tell it a little), the check points come
    out about a centimetre high (the cameras' rotations take part of it). The image noise (0.1 px) states 5 mm:
    vertical NEES > 4. With globals_point_cov the vertical sigma is about the focal length's sigma x the height
    (0.8-1.5 times) and the NEES is below 2, every error within 3 sigma."""
    prob, truth = make_block(3, per_line=8, heights=(HEIGHT_M,) * 4, relief=1.0, n_points=500, px_sigma=0.1)
    prob.lever_arm_cam_m, prob.delay_s = TRUE_LEVER.copy(), TRUE_DELAY
    prior = TRUE_INTR.copy()
    prior[0] *= 1.0 - 3.0 * F_PRIOR_REL_SIGMA
    prob.intrinsics_prior = prior
    prob.intrinsics_prior_sigma = np.array([F_PRIOR_REL_SIGMA * prior[0], 1.0, 1.0, 0.02, 0.02, 0.02, 0.002, 0.002])
    res = adjust(prob, BundleOptions(free_intrinsics=free_mask("brown"), estimate_lever_arm=False, estimate_delay=False))
    p = res.problem
    f_est, f_sigma = res.value("f")
    assert f_est < TRUE_INTR[0] - f_sigma, (f_est, f_sigma)      # the block leaves it short, as its prior
    adj = _adjusted_from(res, len(truth["C"]))
    seen = np.bincount(p.obs_point, minlength=len(p.points_enu_m))
    rng = np.random.default_rng(7)
    checks = rng.choice(np.flatnonzero(seen >= 6), size=12, replace=False)
    dz, s_img, s_all = [], [], []
    for j in checks:
        m = p.obs_point == j
        uv, cams = p.obs_uv_px[m], p.obs_camera[m]
        t = triangulate(uv, cams, p.R_cam_to_enu, p.centre_enu_m, adj.camera_intrinsics(), sigma_px=0.1)
        g = globals_point_cov(adj, uv, cams, p.R_cam_to_enu, p.centre_enu_m, adj.intrinsics)
        dz.append(t.xyz_enu_m[2] - truth["P"][j][2])
        s_img.append(np.sqrt(t.cov_enu_m2[2, 2]))
        s_all.append(np.sqrt(t.cov_enu_m2[2, 2] + g[2, 2]))
    dz, s_img, s_all = np.array(dz), np.array(s_img), np.array(s_all)
    expected_sigma = f_sigma / f_est * (HEIGHT_M - truth["P"][checks][:, 2])
    print(f"f {f_est:.2f} +- {f_sigma:.2f} px; check dz mean {1e3 * dz.mean():+.1f} mm; vertical sigma image only "
          f"{1e3 * np.median(s_img):.1f} mm, with the globals {1e3 * np.median(s_all):.1f} mm "
          f"(f sigma x height {1e3 * np.median(expected_sigma):.1f} mm)")
    assert dz.mean() > 0.008
    assert np.mean((dz / s_img) ** 2) > 4.0                          # the image noise alone does not state it
    assert np.all((s_all / expected_sigma > 0.8) & (s_all / expected_sigma < 1.5)), s_all / expected_sigma
    assert np.mean((dz / s_all) ** 2) < 2.0 and np.all(np.abs(dz) < 3.0 * s_all), dz / s_all
