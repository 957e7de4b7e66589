"""EXIF GPS heights that drift: detected against the block and the block levelled on the nadir-axis
assumption instead of tilted (photo/exif_heights.py). Known truth: the small simulated survey (session SfM
shared with test_sfm.py), its true camera centres given EXIF-like noise (the simulator's own 1.5 m / 3 m)
and an injected altitude drift of +60 m over the flight."""

from __future__ import annotations

import json
import math

import numpy as np

from georef_core.photo.align import fit_similarity
from georef_core.photo.exif_heights import NADIR_SIGMA_DEG, check_exif_heights
from georef_core.photo.photo_positions import EXIF_GPS_SIGMA_M


def _block(sim_sfm, photo_sim):
    poses = json.loads((photo_sim.truth_dir / "camera_poses.json").read_text())["images"]
    by_name = sim_sfm.reconstruction.image_by_name()
    rows = [p for p in poses if p["name"] in by_name]
    names = [p["name"] for p in rows]
    truth = np.array([p["camera_centre_enu_m"] for p in rows])
    t = np.array([p["exposure_gps_time_s"] for p in rows])
    C = np.array([by_name[n].centre for n in names])
    A = np.array([by_name[n].R_cam_from_world[2] for n in names])
    return truth, t, C, A


def _tilt_error_deg(C_sfm, enu_m, truth_enu_m) -> float:
    """The angle between the vertical a similarity onto ``enu_m`` gives the SfM block and the true one."""
    sim, _ = fit_similarity(C_sfm, enu_m)
    true, _ = fit_similarity(C_sfm, truth_enu_m)
    up = np.array([0.0, 0.0, 1.0])
    return math.degrees(math.acos(float(np.clip((sim.R.T @ up) @ (true.R.T @ up), -1, 1))))


def test_drifting_exif_heights_are_detected_and_the_block_levelled(sim_sfm, photo_sim):
    truth, t, C, A = _block(sim_sfm, photo_sim)
    assert len(truth) >= 10
    rng = np.random.default_rng(26)
    noise = rng.standard_normal(truth.shape) * np.array([1.5, 1.5, 3.0])
    drift = 60.0 * (t - t.min()) / np.ptp(t)
    exif = truth + noise
    exif[:, 2] += drift

    before = _tilt_error_deg(C, exif, truth)
    out = check_exif_heights(C, A, exif, t, EXIF_GPS_SIGMA_M[1], sigma_h_m=1.0)
    assert out["inconsistent"] and "inconsistent with the block" in out["text"] and "nadir" in out["text"]
    # the drift it names is the injected one within its own 3 sigma plus the levelling's share
    assert abs(out["drift_m"] - 60.0) < 3 * out["drift_sigma_m"] + 10.0, out
    levelled = exif.copy()
    levelled[:, 2] = out["height_enu_m"]
    after = _tilt_error_deg(C, levelled, truth)
    print(f"tilt vs truth: heights as given {before:.1f} deg; levelled {after:.2f} deg "
          f"(stated sigma {out['level_sigma_deg']} deg); {out['text']}")
    assert before > 3 * NADIR_SIGMA_DEG           # the drift tilts a block fitted to the heights
    assert after < out["level_sigma_deg"]          # levelled within the stated sigma
    assert out["sigma_v_m"] >= EXIF_GPS_SIGMA_M[1]
    # the horizontal sigma raised from 1 m to the scatter about the levelled block: the drawn 1.5 m, roughly
    assert 1.0 < out["sigma_h_m"] < 3.0, out["sigma_h_m"]


def test_heights_without_drift_are_kept(sim_sfm, photo_sim):
    truth, t, C, A = _block(sim_sfm, photo_sim)
    rng = np.random.default_rng(27)
    exif = truth + rng.standard_normal(truth.shape) * np.array([1.5, 1.5, 3.0])
    out = check_exif_heights(C, A, exif, t, EXIF_GPS_SIGMA_M[1])
    assert not out["inconsistent"] and "consistent" in out["text"] and "height_enu_m" not in out, out
    # without times there is nothing to test: said, not guessed
    out = check_exif_heights(C, A, exif, np.full(len(t), np.nan), EXIF_GPS_SIGMA_M[1])
    assert not out["inconsistent"] and "not checked" in out["text"]
