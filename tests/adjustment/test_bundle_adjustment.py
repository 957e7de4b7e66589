"""The GNSS-aided bundle adjustment on synthetic blocks with known truth (no images: the measurements
are exact projections plus seeded noise), so the recovered lever arm, delay, intrinsics and the
honesty of the posterior sigmas can be checked in physical units."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from georef_core.adjustment.bundle_adjustment import BundleOptions, BundleProblem, adjust
from georef_core.adjustment.camera_model import free_mask, project_camera_points

TRUE_INTR = np.array([1400.0, 801.3, 598.2, -0.11, 0.08, -0.01, 0.0006, -0.0004])
TRUE_LEVER = np.array([0.012, -0.105, 0.216])
TRUE_DELAY = 0.038


def make_block(seed: int, n_lines=4, per_line=10, heights=(50.0, 50.0, 75.0, 75.0), speed=5.0, spacing=12.0, line_gap=25.0,
               gnss_sigma=0.004, px_sigma=0.3, relief=4.0, n_points=1000, readout_s=0.0):
    """readout_s > 0: a rolling-shutter camera, row v exposed (v / 1200 - 0.5) readout_s after the trigger
    (the measurements are the exact projections from where the camera was then)."""
    rng = np.random.default_rng(seed)
    R_list, C_list, V_list = [], [], []
    for li in range(n_lines):
        heading = 0.0 if li % 2 == 0 else np.pi  # alternate directions (north, south)
        sp = speed * (1.0 + 0.3 * li)            # lines flown at different speeds separate lever arm and delay
        for k in range(per_line):
            y = (k - per_line / 2) * spacing * (1 if li % 2 == 0 else -1)
            x = (li - n_lines / 2) * line_gap
            C_list.append([x, y, heights[li % len(heights)] + rng.normal(0, 0.3)])
            v = sp * np.array([np.sin(heading), np.cos(heading), 0.0])
            V_list.append(v)
            # nadir camera: x right, y down (image) -> camera y along -travel, z down
            fwd = v / np.linalg.norm(v)
            right = np.cross(fwd, [0, 0, 1.0])
            Rm = np.column_stack([right, -fwd, [0, 0, -1.0]])
            small = Rotation.from_rotvec(rng.normal(0, 0.02, 3)).as_matrix()
            R_list.append(small @ Rm)
    R = np.array(R_list)
    C = np.array(C_list)
    V = np.array(V_list)
    # terrain points with relief
    P = np.column_stack([rng.uniform(-70, 70, n_points), rng.uniform(-75, 75, n_points), np.zeros(n_points)])
    P[:, 2] = relief * np.sin(P[:, 0] / 15.0) * np.cos(P[:, 1] / 20.0) + rng.normal(0, 0.3, len(P))
    obs_c, obs_p, obs_uv = [], [], []
    for i in range(len(C)):
        pc = (P - C[i]) @ R[i]
        uv = project_camera_points(pc, TRUE_INTR)
        for _ in range(4 if readout_s else 0):  # the row's time depends on the row: a fixed point
            shift = V[i] * readout_s * (uv[:, 1:2] / 1200.0 - 0.5)
            uv = project_camera_points(np.einsum("nj,ji->ni", P - C[i] - shift, R[i]), TRUE_INTR)
        # inside the image, and inside the field of view: the distortion polynomial folds rays from far
        # outside the field back into the image, which a real lens does not
        r_norm = np.hypot(pc[:, 0], pc[:, 1]) / np.maximum(pc[:, 2], 1e-9)
        ok = (pc[:, 2] > 0) & (r_norm < 0.8) & (uv[:, 0] > 0) & (uv[:, 0] < 1600) & (uv[:, 1] > 0) & (uv[:, 1] < 1200)
        idx = np.flatnonzero(ok)
        obs_c += [i] * len(idx)
        obs_p += list(idx)
        obs_uv.append(uv[idx] + rng.normal(0, px_sigma, (len(idx), 2)))
    obs_c, obs_p = np.array(obs_c), np.array(obs_p)
    obs_uv = np.vstack(obs_uv)
    counts = np.bincount(obs_p, minlength=len(P))
    keep = counts >= 2
    remap = -np.ones(len(P), int)
    remap[keep] = np.arange(keep.sum())
    m = keep[obs_p]
    antenna = C - np.einsum("kij,j->ki", R, TRUE_LEVER) - V * TRUE_DELAY + rng.normal(0, gnss_sigma, C.shape)
    truth = dict(R=R, C=C, P=P[keep])
    # perturbed start: the block as SfM + similarity would give it
    R0 = np.array([Rotation.from_rotvec(rng.normal(0, 0.002, 3)).as_matrix() @ r for r in R])
    C0 = C + rng.normal(0, 0.05, C.shape)
    X0 = P[keep] + rng.normal(0, 0.05, (keep.sum(), 3))
    # intrinsics as SfM's self-calibration leaves them: focal length 0.5 % off, distortion roughly right
    intr0 = TRUE_INTR.copy()
    intr0[0] *= 1.005
    intr0[1:3] += [3.0, -2.0]
    intr0[3:6] *= [0.9, 0.7, 0.0]
    intr0[6:] = 0.0
    prob = BundleProblem(R_cam_to_enu=R0, centre_enu_m=C0, intrinsics=intr0, points_enu_m=X0,
                         obs_camera=obs_c[m], obs_point=remap[obs_p[m]], obs_uv_px=obs_uv[m],
                         obs_sigma_px=np.full(m.sum(), 1.0), obs_group=np.zeros(m.sum(), int),
                         gnss_camera=np.arange(len(C)), antenna_enu_m=antenna, antenna_velocity_enu_m_s=V,
                         antenna_cov_enu_m2=np.repeat((np.eye(3) * gnss_sigma ** 2)[None], len(C), 0))
    if readout_s:
        prob.camera_velocity_enu_m_s = V.copy()
        prob.image_height_px = 1200.0
    return prob, truth


def _with_control(prob, truth, sel, sigma_h=0.005, sigma_v=0.01):
    prob.control_point = np.asarray(sel)
    prob.control_enu_m = truth["P"][sel]
    prob.control_cov_enu_m2 = np.repeat(np.diag([sigma_h ** 2, sigma_h ** 2, sigma_v ** 2])[None], len(sel), 0)
    return prob


def _lever(res):
    lever = np.array([res.value(k)[0] for k in ("lever_x", "lever_y", "lever_z")])
    sig = np.array([res.value(k)[1] for k in ("lever_x", "lever_y", "lever_z")])
    return lever, sig


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_lever_arm_delay_and_camera_with_three_control_points(seed):
    """Daakir's mode (c) calibration: everything jointly, with a few control points fixing the height datum."""
    prob, truth = make_block(seed)
    P = truth["P"]
    sel = [int(np.argmin(np.linalg.norm(P[:, :2] - xy, axis=1))) for xy in ((-40, -40), (40, 0), (-10, 45))]
    _with_control(prob, truth, sel)
    res = adjust(prob, BundleOptions(free_intrinsics=free_mask("brown"), min_gnss_sigma_m=0.0))
    lever, lever_sig = _lever(res)
    delay, delay_sig = res.value("delay")
    # Honest sigmas: every error within 3 sigma. The sigmas themselves are what this block can give
    # (lever y and delay are separated only by the different line speeds), so they are bounded, and the
    # errors are bounded in physical units.
    assert np.all(np.abs(lever - TRUE_LEVER) < 3.0 * lever_sig), (lever - TRUE_LEVER, lever_sig)
    assert abs(delay - TRUE_DELAY) < 3.0 * delay_sig, (delay - TRUE_DELAY, delay_sig)
    assert np.all(lever_sig < 0.015) and delay_sig < 0.002
    assert np.all(np.abs(lever - TRUE_LEVER) < 0.03) and abs(delay - TRUE_DELAY) < 0.004
    f, f_sig = res.value("f")
    assert abs(f - TRUE_INTR[0]) < max(3.5 * f_sig, 0.5)
    # the image noise (0.3 px against an a-priori 1 px) is found by the variance components
    assert 0.2 < res.sigma0["image"] < 0.4
    # camera centres within a centimetre of the truth
    err = np.linalg.norm(prob.centre_enu_m - truth["C"], axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 0.025


def test_without_control_the_vertical_lever_arm_is_reported_as_undetermined():
    """Nadir images: a vertical lever-arm change moves every camera and point up or down together, so
    without control the height of the lever arm is not observable. The adjustment must still recover
    the horizontal lever arm and the delay (alternating headings and speeds) and must *say* that the
    vertical component is undetermined (large sigma, strong correlation), not return a confident number."""
    prob, truth = make_block(1)
    res = adjust(prob, BundleOptions(free_intrinsics=free_mask("brown"), min_gnss_sigma_m=0.0))
    lever, lever_sig = _lever(res)
    delay, _ = res.value("delay")
    _, delay_sig = res.value("delay")
    assert np.all(np.abs(lever[:2] - TRUE_LEVER[:2]) < 3.0 * lever_sig[:2]), (lever, lever_sig)
    assert np.all(lever_sig[:2] < 0.015)
    assert abs(delay - TRUE_DELAY) < 3.0 * delay_sig and delay_sig < 0.002
    assert lever_sig[2] > 3 * lever_sig[0], lever_sig          # z much weaker than x
    assert abs(lever[2] - TRUE_LEVER[2]) < 3.5 * lever_sig[2]
    # with the calibrated lever arm as a prior (the operational zero-GCP case) the height comes back
    prob2, truth2 = make_block(1)
    prob2.lever_arm_prior_cam_m = TRUE_LEVER.copy()
    prob2.lever_arm_prior_sigma_m = np.full(3, 0.005)
    res2 = adjust(prob2, BundleOptions(free_intrinsics=free_mask("brown"), min_gnss_sigma_m=0.0))
    assert abs(res2.value("lever_z")[0] - TRUE_LEVER[2]) < 0.01
    P_err = prob2.points_enu_m - truth2["P"]
    assert abs(np.mean(P_err[:, 2])) < 0.01
    assert np.median(np.linalg.norm(P_err, axis=1)) < 0.03    # (edge points seen twice are noisier)


def test_gnss_outlier_epoch_is_flagged_and_does_not_pull_the_solution():
    prob, truth = make_block(5)
    bad = 7
    prob.antenna_enu_m[bad] += np.array([0.0, 0.0, 0.35])  # a wrong fix: 35 cm up
    res = adjust(prob, BundleOptions(free_intrinsics=free_mask("brown"), min_gnss_sigma_m=0.0))
    assert res.gnss_outlier[bad]
    assert res.gnss_outlier.sum() <= 2
    lever, lever_sig = _lever(res)
    assert np.all(np.abs(lever[:2] - TRUE_LEVER[:2]) < 3.0 * lever_sig[:2])
    assert abs(res.gnss_residual_enu_m[bad, 2]) > 0.25      # the wrong fix shows in its residual, not spread out


def test_control_points_only_no_gnss():
    """Classic indirect georeferencing: no GNSS, five control points. The ground comes out right; the
    camera heights do not (focal length and flying height trade off over flat-ish ground) and the
    posterior sigmas say so."""
    prob, truth = make_block(3)
    P = truth["P"]
    sel = [int(np.argmin(np.linalg.norm(P[:, :2] - xy, axis=1)))
           for xy in ((-50, -55), (50, -55), (50, 55), (-50, 55), (0, 0))]
    prob.gnss_camera = np.zeros(0, int)
    prob.antenna_enu_m = np.zeros((0, 3))
    prob.antenna_velocity_enu_m_s = np.zeros((0, 3))
    prob.antenna_cov_enu_m2 = np.zeros((0, 3, 3))
    _with_control(prob, truth, sel, sigma_h=0.01, sigma_v=0.02)
    res = adjust(prob, BundleOptions(free_intrinsics=free_mask("brown")))
    assert "lever_x" not in res.global_names and "delay" not in res.global_names
    p_err = prob.points_enu_m - P
    assert np.sqrt(np.mean(np.sum(p_err ** 2, axis=1))) < 0.06
    c_err = prob.centre_enu_m - truth["C"]
    c_sig = np.sqrt(np.einsum("nii->ni", res.camera_cov[:, 3:, 3:]))
    assert np.all(np.abs(c_err) < 3.5 * c_sig)


def test_needs_a_datum():
    prob, _ = make_block(4)
    prob.gnss_camera = np.zeros(0, int)
    prob.antenna_enu_m = np.zeros((0, 3))
    prob.antenna_velocity_enu_m_s = np.zeros((0, 3))
    prob.antenna_cov_enu_m2 = np.zeros((0, 3, 3))
    from georef_core.errors import ProcessingError

    with pytest.raises(ProcessingError, match="datum"):
        adjust(prob)


@pytest.mark.parametrize("seed", [0, 1])
def test_rolling_shutter_readout_is_estimated_and_removes_the_skew(seed):
    """A rolling-shutter camera (30 ms readout, 5-8 m/s: the camera moves 15-24 cm while the rows are
    read): with the readout estimated the lever arm, delay and camera centres come back as for a global
    shutter and the readout within 3 sigma (and 2 ms); the same measurements adjusted as if from a global
    shutter leave the skew in the residuals and the estimates."""
    true_readout = 0.030
    prob, truth = make_block(seed, readout_s=true_readout)
    P = truth["P"]
    sel = [int(np.argmin(np.linalg.norm(P[:, :2] - xy, axis=1))) for xy in ((-40, -40), (40, 0), (-10, 45))]
    _with_control(prob, truth, sel)
    ignored, _ = make_block(seed, readout_s=true_readout)
    ignored.camera_velocity_enu_m_s = None  # the same measurements, the shutter not modelled
    _with_control(ignored, truth, sel)
    opts = BundleOptions(free_intrinsics=free_mask("brown"), min_gnss_sigma_m=0.0, estimate_readout=True)
    res = adjust(prob, opts)
    res_ignored = adjust(ignored, opts)
    assert "readout" in res.global_names and "readout" not in res_ignored.global_names
    readout, readout_sig = res.value("readout")
    assert abs(readout - true_readout) < 3.0 * readout_sig and abs(readout - true_readout) < 0.002, (readout, readout_sig)
    lever, lever_sig = _lever(res)
    delay, delay_sig = res.value("delay")
    assert np.all(np.abs(lever - TRUE_LEVER) < 3.0 * lever_sig) and np.all(np.abs(lever - TRUE_LEVER) < 0.03)
    assert abs(delay - TRUE_DELAY) < 3.0 * delay_sig and abs(delay - TRUE_DELAY) < 0.004
    assert 0.2 < res.sigma0["image"] < 0.4
    centre_rms = np.sqrt(np.mean(np.sum((prob.centre_enu_m - truth["C"]) ** 2, axis=1)))
    assert centre_rms < 0.025
    # not modelled: the image block absorbs the skew (a 15-24 cm along-track shear of every image) in a way
    # the GNSS positions and the control points contradict
    assert res_ignored.sigma0["gnss"] > 2.5 * res.sigma0["gnss"], (res_ignored.sigma0, res.sigma0)
    p_rms = np.sqrt(np.mean(np.sum((prob.points_enu_m - P) ** 2, axis=1)))
    p_rms_ignored = np.sqrt(np.mean(np.sum((ignored.points_enu_m - P) ** 2, axis=1)))
    assert p_rms < 0.5 * p_rms_ignored, (p_rms, p_rms_ignored)
