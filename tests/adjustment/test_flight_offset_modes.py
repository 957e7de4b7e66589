"""Per-flight GNSS offsets in the modes `similarity` (7 parameters + delay, known lever arm) and `gcp` (lever arm +
delay from cameras oriented by control points): synthetic two-flight blocks with known truth (the cameras of
make_block, no images, no bundle adjustment), each flight's GNSS positions shifted by an offset drawn from the prior
(docs/georeferencing.md, "Several flights"). Modelled, the camera centres' (similarity) and the lever arm's (gcp)
covariances are honest over the draws; not modelled, they are not."""

import numpy as np
from scipy.spatial.transform import Rotation

from georef_core.adjustment.bundle_adjustment import flight_offset_prior_cov
from georef_core.adjustment.lever_arm_delay import estimate_lever_arm_delay, fit_similarity_delay, similarity_centre_cov
from tests.adjustment.test_bundle_adjustment import TRUE_DELAY, TRUE_LEVER, make_block

GNSS_SIGMA_M = 0.004
CAMERA_SIGMA_M = 0.003          # the cameras oriented by control points (mode gcp)
PRIOR = flight_offset_prior_cov(2, 0.0, 0.035)     # 3.5 cm per flight and axis, no common part
LEVER_NAMES = ("lever_x", "lever_y", "lever_z")


def _geometry():
    """Three blocks' true cameras (4 lines of 8 photos; lines 1-2 flight 1, lines 3-4 flight 2: each flight flies
    both headings)."""
    out = []
    for seed in range(3):
        prob, truth = make_block(seed, per_line=8, n_points=50)
        n = len(truth["C"])
        out.append((truth["C"], truth["R"], prob.antenna_velocity_enu_m_s, (np.arange(n) >= n // 2).astype(int)))
    return out


def _draws(n: int, seed: int = 1):
    """n surveys: a block, offsets drawn from PRIOR, fresh GNSS noise; yields (C, R, V, antenna, cov, flight, offsets)."""
    rng = np.random.default_rng(seed)
    geo = _geometry()
    for k in range(n):
        C, R, V, fl = geo[k % len(geo)]
        off = rng.multivariate_normal(np.zeros(6), PRIOR).reshape(2, 3)
        A = (C - np.einsum("kij,j->ki", R, TRUE_LEVER) - V * TRUE_DELAY + off[fl]
             + rng.normal(0, GNSS_SIGMA_M, C.shape))
        yield C, R, V, A, np.repeat((np.eye(3) * GNSS_SIGMA_M ** 2)[None], len(C), 0), fl, off, rng


def _nees(e, cov):
    return np.einsum("ni,nij,nj->n", e, np.linalg.inv(cov), e) / 3.0


def test_similarity_one_offset_per_flight_makes_camera_covariances_honest():
    """Mode similarity: the SfM model (the true cameras in a model frame, 2 mm of noise) fitted to the GNSS positions.
    Modelled, the flights' difference is measured within its sigma and the camera centres' ANEES over 16 surveys is
    in [0.6, 1.5]; not modelled it is above 3 (the translation stated to a few mm, wrong by the offsets' mean)."""
    s_true, R_true, t_true = 0.37, Rotation.from_rotvec([0.1, -0.2, 0.7]).as_matrix(), np.array([5.0, -3.0, 2.0])
    nees = {True: [], False: []}
    z_diff = []
    for C, R, V, A, cov, fl, off, rng in _draws(16):
        c = (C - t_true) @ R_true / s_true + rng.normal(0, 0.002 / s_true, C.shape)
        Rm = np.einsum("ji,kjl->kil", R_true, R)
        for model in (False, True):
            fit = fit_similarity_delay(c, Rm, A, V, cov + np.eye(3) * 1e-5, TRUE_LEVER, flight=fl if model else None,
                                       offset_prior_cov_m2=PRIOR if model else None)
            s, Rs, t = fit.similarity
            sim_cov, cross = similarity_centre_cov(fit, c)
            # the step's camera covariance: one position's noise plus the similarity's own uncertainty
            ccov = sim_cov + np.mean(np.trace(cov, axis1=1, axis2=2)) / 3 * fit.sigma0 ** 2 * np.eye(3)
            nees[model].append(np.mean(_nees(s * c @ Rs.T + t - C, ccov)))
            if model:
                assert cross.shape == (len(C), 3, 6) and fit.names[-6:] == [f"flight{f}.offset_{a}" for f in (1, 2)
                                                                            for a in "enu"]
                d_cov = fit.flight_offset_cov_m2[:3, :3] + fit.flight_offset_cov_m2[3:, 3:] \
                    - 2 * fit.flight_offset_cov_m2[:3, 3:]
                d = fit.flight_offset_enu_m[0] - fit.flight_offset_enu_m[1]
                z_diff.append((d - (off[0] - off[1])) / np.sqrt(np.diag(d_cov)))
    on, off_ = float(np.mean(nees[True])), float(np.mean(nees[False]))
    print(f"similarity, 16 surveys: camera centres ANEES modelled {on:.2f}, not modelled {off_:.2f}; flights' "
          f"difference z RMS {np.sqrt(np.mean(np.square(z_diff), axis=0)).round(2)}")
    assert 0.6 <= on <= 1.5 and off_ > 3.0, (on, off_)
    assert np.all(np.sqrt(np.mean(np.square(z_diff), axis=0)) < 1.5)


def test_gcp_mode_lever_arm_with_offsets_is_honest():
    """Mode gcp: the lever arm and delay from cameras known to 3 mm. Not modelled, the flights' vertical offsets go
    into the lever arm's z with a sigma of a few mm (z-score RMS above 3 over 40 surveys); modelled, every z-score RMS
    of the lever arm, delay and offsets is in [0.6, 1.5], and the lever arm z's sigma carries the vertical prior."""
    z = {True: [], False: []}
    z_off, sig_z = [], []
    for C, R, V, A, cov, fl, off, rng in _draws(40, seed=2):
        Cg = C + rng.normal(0, CAMERA_SIGMA_M, C.shape)
        for model in (False, True):
            fit = estimate_lever_arm_delay(R, Cg, A, V, cov + np.eye(3) * CAMERA_SIGMA_M ** 2,
                                           flight=fl if model else None, offset_prior_cov_m2=PRIOR if model else None)
            est = np.r_[fit.lever_arm_cam_m, fit.delay_s]
            sd = np.array([fit.sigma(k) for k in LEVER_NAMES + ("delay",)])
            z[model].append((est - np.r_[TRUE_LEVER, TRUE_DELAY]) / sd)
            if model:
                z_off.append(((fit.flight_offset_enu_m - off).ravel() / np.sqrt(np.diag(fit.flight_offset_cov_m2))))
                sig_z.append(sd[2])
    rms_on = np.sqrt(np.mean(np.square(z[True]), axis=0))
    rms_off = np.sqrt(np.mean(np.square(z[False]), axis=0))
    rms_o = np.sqrt(np.mean(np.square(z_off), axis=0))
    print(f"gcp, 40 surveys: z-score RMS (lever x, y, z, delay) modelled {rms_on.round(2)}, not modelled "
          f"{rms_off.round(2)}; offsets {rms_o.round(2)}; lever z sigma {1000 * np.median(sig_z):.1f} mm")
    assert rms_off[2] > 3.0, rms_off
    assert np.all((rms_on > 0.6) & (rms_on < 1.5)) and np.all((rms_o > 0.6) & (rms_o < 1.5)), (rms_on, rms_o)
    # the lever arm z is told from the flights' vertical offsets by their prior only (3.5 cm / sqrt(2) for the mean)
    assert 0.015 < np.median(sig_z) < 0.03


def test_offsets_in_the_linear_fits_need_one_flight_per_position():
    C, R, V, A, cov, fl, off, rng = next(_draws(1))
    import pytest

    with pytest.raises(ValueError, match="one flight index per GNSS position"):
        estimate_lever_arm_delay(R, C, A, V, cov, flight=fl[:-1], offset_prior_cov_m2=PRIOR)
    with pytest.raises(ValueError, match="offset_prior_cov_m2"):
        estimate_lever_arm_delay(R, C, A, V, cov, flight=fl, offset_prior_cov_m2=PRIOR[:3, :3])
