"""The ground check of the EXIF-heights levelling (photo/exif_heights.py ground_plane): cameras that all look one
way with no recorded attitude scatter like a nadir block's and were levelled their tilt wrong on their mean axis;
the sparse cloud's ground plane, tilted by that much in the mean-axis frame, shows it, and the block is levelled on
the ground instead. A synthetic block with known truth (fast: no rendering, no SfM): a serpentine of 40 photos (4 lines) at
50 m over a 120 x 80 m site with mounds, its "SfM" frame an arbitrary similarity of the true one."""

from __future__ import annotations

import math

import numpy as np
import pytest

from georef_core.photo.align import fit_similarity
from georef_core.photo.exif_heights import SITE_SLOPE_MAX_DEG, check_exif_heights, ground_plane


def _rot(axis, deg):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    t = math.radians(deg)
    return np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * k @ k


def _block(seed: int, look: str, slope_deg: float = 0.0):
    """(true centres, times, SfM centres, SfM axes, SfM points) of a synthetic block; ``look``: "one-way" (every
    camera 30 deg off nadir towards north), "serpentine" (30 deg forward along each line: the lines look opposite
    ways) or "nadir"; each camera's axis also wobbles 3 deg (the body's attitude); the ground slopes ``slope_deg``
    towards east, with three 6 m mounds."""
    rng = np.random.default_rng(seed)
    xs = np.linspace(0.0, 120.0, 10)
    C, t, fwd = [], [], []
    for k, y in enumerate((5.0, 28.0, 51.0, 74.0)):
        xx = xs if k % 2 == 0 else xs[::-1]
        for j, x in enumerate(xx):
            C.append((x, y, 50.0))
            t.append(k * 40.0 + 2.0 * j)
            fwd.append(1.0 if k % 2 == 0 else -1.0)
    C, t, fwd = np.array(C), np.array(t), np.array(fwd)
    C[:, 2] += math.tan(math.radians(slope_deg)) * C[:, 0]          # the flight follows the slope
    A = []
    for f in fwd:
        if look == "one-way":
            a = _rot([1.0, 0, 0], 30.0) @ np.array([0.0, 0, -1])    # towards north
        elif look == "serpentine":
            a = _rot([0, -f, 0], 30.0) @ np.array([0.0, 0, -1])     # forward along the line
        else:
            a = np.array([0.0, 0, -1])
        A.append(_rot(rng.normal(size=3), abs(rng.normal(0, 3.0))) @ a)
    A = np.array(A)
    P = np.column_stack([rng.uniform(-20, 140, 4000), rng.uniform(-10, 90, 4000), np.zeros(4000)])
    P[:, 2] = math.tan(math.radians(slope_deg)) * P[:, 0] + rng.normal(0, 0.1, len(P))
    for cx, cy in ((30.0, 30.0), (80.0, 60.0), (100.0, 20.0)):
        P[:, 2] += 6.0 * np.exp(-((P[:, 0] - cx) ** 2 + (P[:, 1] - cy) ** 2) / (2 * 10.0 ** 2))
    # the SfM frame: scale 0.37, an arbitrary rotation, a shift
    Rm = _rot([0.3, -0.5, 0.8], 71.0)
    to_model = lambda X: 0.37 * X @ Rm.T + np.array([3.0, -2.0, 7.0])  # noqa: E731
    return C, t, to_model(C), A @ Rm.T, to_model(P)


def _tilt_error_deg(C_sfm, enu_m, truth_enu_m) -> float:
    sim, _ = fit_similarity(C_sfm, enu_m)
    true, _ = fit_similarity(C_sfm, truth_enu_m)
    up = np.array([0.0, 0.0, 1.0])
    return math.degrees(math.acos(float(np.clip((sim.R.T @ up) @ (true.R.T @ up), -1, 1))))


def _exif(truth, t, seed, drift_m=60.0):
    rng = np.random.default_rng(100 + seed)
    exif = truth + rng.standard_normal(truth.shape) * np.array([1.5, 1.5, 3.0])
    exif[:, 2] += drift_m * (t - t.min()) / np.ptp(t)
    return exif


def _levelled_tilt(out, exif, C, truth):
    lv = exif.copy()
    lv[:, 2] = out["height_enu_m"]
    return _tilt_error_deg(C, lv, truth)


@pytest.mark.parametrize("seed", [1, 2])
def test_one_way_obliques_are_levelled_on_the_ground(seed):
    truth, t, C, A, P = _block(seed, "one-way")
    exif = _exif(truth, t, seed)
    # without the sparse cloud: taken as a nadir block (small scatter) and levelled ~30 deg wrong, silently
    blind = check_exif_heights(C, A, exif, t, 5.0)
    assert blind["levelled"] and blind["level_method"] == "nadir" and blind["axis_rms_deg"] < 10
    assert _levelled_tilt(blind, exif, C, truth) > 20.0
    # with it: the ground in the mean-axis frame tilts ~30 deg, far beyond a level site; levelled on the ground
    out = check_exif_heights(C, A, exif, t, 5.0, points_sfm=P)
    g = out["ground"]
    assert g["level_rejected"] and g["of_level"] == "nadir" and g["tilt_deg"] > g["threshold_deg"] > SITE_SLOPE_MAX_DEG
    assert 25.0 < g["tilt_deg"] < 35.0, g
    assert out["levelled"] and out["level_method"] == "ground-plane" and out["inconsistent"]
    assert f"tilts {g['tilt_deg']:.1f} deg" in out["text"] and "looking one way" in out["text"]
    after = _levelled_tilt(out, exif, C, truth)
    assert after < out["level_sigma_deg"], (after, out["level_sigma_deg"])
    assert abs(out["drift_m"] - 60.0) < 3 * out["drift_sigma_m"] + 10.0, out


def test_one_way_obliques_without_drift_stay_consistent():
    """Levelled 30 deg wrong, the block's heights against the EXIF ones look like a drift on a serpentine; on the
    ground-levelled block they do not."""
    truth, t, C, A, P = _block(3, "one-way")
    exif = _exif(truth, t, 3, drift_m=0.0)
    out = check_exif_heights(C, A, exif, t, 5.0, points_sfm=P)
    assert out["ground"]["level_rejected"] and not out["inconsistent"], out["text"]
    assert "ground would tilt" in out["text"]


@pytest.mark.parametrize("look, slope_deg", [("nadir", 0.0), ("nadir", 6.0), ("serpentine", 0.0)])
def test_level_sites_and_balanced_blocks_keep_their_level(look, slope_deg):
    truth, t, C, A, P = _block(4, look, slope_deg)
    exif = _exif(truth, t, 4)
    out = check_exif_heights(C, A, exif, t, 5.0, points_sfm=P)
    want = "balanced-oblique" if look == "serpentine" else "nadir"
    assert out["level_method"] == want and not out["ground"]["level_rejected"], out["ground"]
    # the ground's tilt in the mean-axis frame: the site's slope within the body's wobble
    assert abs(out["ground"]["tilt_deg"] - slope_deg) < 4.0, out["ground"]
    assert out["ground"]["tilt_sigma_deg"] < 2.0


def test_ground_plane_ignores_mounds_and_states_its_sigma():
    rng = np.random.default_rng(5)
    P = np.column_stack([rng.uniform(0, 100, 3000), rng.uniform(0, 60, 3000), np.zeros(3000)])
    P[:, 2] = math.tan(math.radians(4.0)) * P[:, 1] + rng.normal(0, 0.05, 3000)
    pile = (P[:, 0] - 30) ** 2 + (P[:, 1] - 30) ** 2 < 15 ** 2
    P[pile, 2] += 8.0                                           # a stockpile on one side: not ground
    gp = ground_plane(P, np.array([[50.0, 30.0, 60.0]]), np.array([0.0, 0, 1]))
    assert abs(gp["tilt_deg"] - 4.0) < 0.2 and gp["n_inliers"] < len(P) - pile.sum() // 2
    assert gp["normal"][2] > 0 and 0 < gp["tilt_sigma_deg"] < 1.0
    assert ground_plane(P[:10], P[:1], np.array([0.0, 0, 1])) is None


def test_georef_step_gives_the_sparse_cloud_to_the_check():
    """steps/georef.py _exif_heights passes the reconstruction's points: a one-way block is levelled on the ground
    and the warning names the tilt; the heights given to the adjustment are the ground-levelled block's."""
    from types import SimpleNamespace

    from georef_core.steps.georef import ImageGnss, _exif_heights

    truth, t, C, A, P = _block(6, "one-way")
    exif = _exif(truth, t, 6)
    names = [f"p{k:02d}.jpg" for k in range(len(t))]
    images = {nm: SimpleNamespace(centre=C[k], R_cam_from_world=np.vstack([np.zeros((2, 3)), A[k]]))
              for k, nm in enumerate(names)}
    rec = SimpleNamespace(image_by_name=lambda: images, points_xyz=P)
    n = len(names)
    gnss = ImageGnss(names, t, np.zeros((n, 3)), np.zeros((n, 3)), np.ones((n, 3)), np.full(n, 5), "EXIF GPS",
                     from_photos=True, kind="exif-gps", gimbal_deg=None, heights_from_takeoff=True)
    gnss_enu = {nm: (exif[k], np.zeros(3), np.diag([9.0, 9.0, 25.0]), 5, t[k]) for k, nm in enumerate(names)}
    warnings: list[str] = []
    out = _exif_heights(rec, gnss, gnss_enu, warnings, {nm: 0 for nm in names})
    assert out["level_method"] == "ground-plane" and len(warnings) == 1
    assert "ground plane" in warnings[0] and f"{out['ground']['tilt_deg']:.1f} deg" in warnings[0]
    z = np.array([gnss_enu[nm][0][2] for nm in names])
    lv = exif.copy()
    lv[:, 2] = z
    assert _tilt_error_deg(C, lv, truth) < out["level_sigma_deg"]
