"""Per-flight GNSS offsets in the adjustment (docs/georeferencing.md, "Several flights"): synthetic two-flight
blocks with known truth (make_block, no images), each flight's GNSS camera positions shifted by a common
offset; the camera-centre and check-point covariances must be honest (ANEES) with the offsets modelled, the
offsets recovered within their sigma with one control point; and the step's flight detection and prior."""

import numpy as np
import pytest

from georef_core.adjustment.bundle_adjustment import BundleOptions, adjust, flight_offset_prior_cov
from georef_core.adjustment.camera_model import free_mask
from georef_core.errors import ProcessingError
from georef_core.steps.georef import (GeorefOptions, ImageGnss, flight_offset_point_cov, flight_offset_prior,
                                     georef_options_from_dict, image_flights)
from tests.adjustment.test_bundle_adjustment import TRUE_DELAY, TRUE_LEVER, make_block

FIXED_OFFSETS_M = np.array([[0.03, 0.03, 0.03], [-0.04, -0.04, -0.04]])   # flight 1 +3 cm, flight 2 -4 cm


def two_flight_block(seed: int, offsets_m: np.ndarray, n_control: int, gcp_sigma=(0.01, 0.02), n_checks=12,
                     per_line=10, n_points=1000):
    """(problem, truth, check point indices): the block of make_block with its cameras' GNSS positions
    shifted by ``offsets_m[flight]`` (flight 0: lines 1-2, flight 1: lines 3-4); ``n_control`` (0 or 1)
    control point near the block's centre, surveyed with noise of ``gcp_sigma`` (horizontal, vertical)."""
    rng = np.random.default_rng(1000 + seed)
    prob, truth = make_block(seed, per_line=per_line, n_points=n_points, relief=6.0)
    n_cam = len(truth["C"])
    flight = (np.arange(n_cam) >= n_cam // 2).astype(int)
    prob.antenna_enu_m = prob.antenna_enu_m + offsets_m[flight]
    prob.lever_arm_cam_m, prob.delay_s = TRUE_LEVER.copy(), TRUE_DELAY   # held (known) in these runs
    prob.gnss_flight = flight
    P = truth["P"]
    seen = np.bincount(prob.obs_point, minlength=len(P))
    centre = int(np.argmin(np.linalg.norm(P[:, :2], axis=1) + 100.0 * (seen < 6)))
    if n_control:
        sh, sv = gcp_sigma
        cov = np.diag([sh ** 2, sh ** 2, sv ** 2])
        prob.control_point = np.array([centre])
        prob.control_enu_m = P[[centre]] + rng.normal(0, 1, 3) * np.array([sh, sh, sv])
        prob.control_cov_enu_m2 = cov[None]
    # check points: well-seen tie points spread over the block, away from the control point
    cand = np.flatnonzero((seen >= 6) & (np.linalg.norm(P[:, :2] - P[centre, :2], axis=1) > 15))
    checks = rng.choice(cand, size=min(n_checks, len(cand)), replace=False)
    return prob, truth, checks


def anees(err: np.ndarray, cov: np.ndarray) -> float:
    return float(np.mean(np.einsum("ni,nij,nj->n", err, np.linalg.inv(cov), err)) / 3.0)


def run_case(seed, offsets_m, n_control, model: bool, common_sigma, flight_sigma, **block):
    prob, truth, checks = two_flight_block(seed, offsets_m, n_control, **block)
    if model:
        prob.flight_offset_prior_cov_m2 = flight_offset_prior_cov(2, common_sigma, flight_sigma)
    else:
        prob.gnss_flight = None
    res = adjust(prob, BundleOptions(free_intrinsics=free_mask("brown"), estimate_lever_arm=False,
                                     estimate_delay=False, cov_points=tuple(int(c) for c in checks)))
    p = res.problem
    e_c = p.centre_enu_m - truth["C"]
    a_c = anees(e_c, res.camera_cov[:, 3:, 3:])
    e_p = p.points_enu_m[checks] - truth["P"][checks]
    a_p = anees(e_p, np.array([res.point_cov_enu_m2[int(c)] for c in checks]))
    out = {"anees_cameras": a_c, "anees_checks": a_p, "sigma0_gnss": res.sigma0["gnss"],
           "mean_camera_error_m": e_c.mean(axis=0), "median_camera_sigma_m": np.median(np.sqrt(
               np.einsum("nii->ni", res.camera_cov[:, 3:, 3:])), axis=0)}
    if model:
        out["offsets_m"] = res.flight_offset_enu_m
        out["offsets_sigma_m"] = np.sqrt(np.diag(res.flight_offset_cov_m2)).reshape(-1, 3)
    return out




# the test's block: 4 lines of 8 photos, 500 ground points (the bench's is 4 x 10, 1000); prior per flight
# 3.5 cm on each axis, no common part (a surveyed base)
SMALL = {"per_line": 8, "n_points": 500}
FLIGHT_SIGMA = 0.035


def test_zero_control_points_offsets_make_covariances_honest():
    """Two flights, +3 and -4 cm (each axis), no control point: without the offsets the camera centres' and
    check points' covariances are far too small (ANEES tens); with them the prior is propagated into the
    covariances (ANEES not above 2) and the tie points measure the flights' difference."""
    off = run_case(0, FIXED_OFFSETS_M, 0, False, 0.0, FLIGHT_SIGMA, **SMALL)
    on = run_case(0, FIXED_OFFSETS_M, 0, True, 0.0, FLIGHT_SIGMA, **SMALL)
    assert off["anees_cameras"] > 10 and off["anees_checks"] > 5, off
    assert on["anees_cameras"] < 2 and on["anees_checks"] < 2, on
    # without control only the flights' difference is measured: 7 cm on each axis, to about 1.5 cm
    diff = on["offsets_m"][0] - on["offsets_m"][1]
    assert np.all(np.abs(diff - (FIXED_OFFSETS_M[0] - FIXED_OFFSETS_M[1])) < 0.02), diff
    # and the common part stays at its prior: the sigmas are the prior's over sqrt(2), not shrunk, not inflated
    assert np.all(np.abs(on["offsets_sigma_m"] - FLIGHT_SIGMA / np.sqrt(2)) < 0.006), on["offsets_sigma_m"]


def test_one_control_point_recovers_the_offsets_within_their_sigma():
    """The same survey with one control point (surveyed with 1 cm / 2 cm noise): the offsets are estimated,
    within 2 sigma of the truth on every axis, with sigmas well below the prior's; the camera centres' and
    check points' covariances stay honest (ANEES within [0.2, 2] on this one survey)."""
    on = run_case(0, FIXED_OFFSETS_M, 1, True, 0.0, FLIGHT_SIGMA, **SMALL)
    z = (on["offsets_m"] - FIXED_OFFSETS_M) / on["offsets_sigma_m"]
    assert np.all(np.abs(z) < 2.0), (on["offsets_m"], on["offsets_sigma_m"])
    assert np.all(on["offsets_sigma_m"] < 0.8 * FLIGHT_SIGMA), on["offsets_sigma_m"]
    assert 0.1 < on["anees_cameras"] < 2 and 0.2 < on["anees_checks"] < 2, on


def test_offset_prior_covariance_and_point_propagation():
    cov = flight_offset_prior_cov(2, [0.02, 0.02, 0.04], [0.01, 0.01, 0.015])
    assert cov.shape == (6, 6)
    assert np.isclose(cov[2, 2], 0.04 ** 2 + 0.015 ** 2) and np.isclose(cov[2, 5], 0.04 ** 2) and cov[0, 1] == 0
    # a point seen by cameras that move one for one with flight 1's offset carries that offset's covariance
    Co = np.diag([1e-4, 1e-4, 4e-4, 9e-4, 9e-4, 9e-4])
    cam = np.repeat(Co[None, :3, :], 4, 0)              # Cov(C_i, o) = [I 0] Cov(o)
    assert np.allclose(flight_offset_point_cov(cam, Co), Co[:3, :3])


def _gnss(t, from_photos=False, kind=""):
    n = len(t)
    return ImageGnss([f"IMG_{k:03d}.JPG" for k in range(n)], np.asarray(t, float), np.zeros((n, 3)), np.zeros((n, 3)),
                     np.full((n, 3), 0.01), np.ones(n, int), "test", from_photos=from_photos, kind=kind)


def test_flights_from_time_gaps_and_flight_folders(tmp_path):
    g = _gnss([100, 102, 104, 400, 402, 900])
    fl, how = image_flights(g, None, 120.0)
    assert [fl[n] for n in g.names] == [0, 0, 0, 1, 1, 2] and "120 s" in how
    csv_path = tmp_path / "camera_offsets.csv"
    csv_path.write_text("image,trigger_gps_time_s,north_m,east_m,down_m,mrk_quality,flight\n" + "".join(
        f"{n},{t},0,0,0,50,{f}\n" for n, t, f in zip(g.names, g.trigger_gps_time_s, [1, 1, 1, 1, 0, 0])))
    fl, how = image_flights(g, csv_path, 120.0)
    assert [fl[n] for n in g.names] == [0, 0, 0, 0, 1, 1] and "camera_offsets.csv" in how


def test_offset_prior_choices():
    opts = GeorefOptions()
    # one flight over a surveyed base: auto leaves the adjustment as it was
    assert flight_offset_prior(opts, _gnss([0, 1]), 1, {"source": "given", "sigma_enu_m": None}) is None
    two = flight_offset_prior(opts, _gnss([0, 1]), 2, {"source": "given", "sigma_enu_m": None})
    assert two["common_sigma_enu_m"] == [0, 0, 0] and two["flight_sigma_enu_m"] == [0.01, 0.01, 0.015]
    # an unsurveyed base: its sigma is the part common to every flight, even with one flight
    one = flight_offset_prior(opts, _gnss([0, 1]), 1, {"source": "averaged-single-point", "sigma_enu_m": [1.1, 1.2, 2.3]})
    assert one["common_sigma_enu_m"] == [1.1, 1.2, 2.3]
    assert flight_offset_prior(GeorefOptions(flight_offsets="off"), _gnss([0, 1]), 2, None) is None
    assert flight_offset_prior(opts, _gnss([0, 1], True, "exif-gps"), 2, None) is None
    assert flight_offset_prior(opts, _gnss([0, 1], True, "rtk"), 2, None) is not None
    with pytest.raises(ProcessingError, match="flight_offset_sigma_m"):
        flight_offset_prior(GeorefOptions(flight_offsets="on", flight_offset_sigma_m=(0.0, 0.01)), _gnss([0, 1]), 2, None)
    with pytest.raises(ProcessingError, match="flight_offsets"):
        georef_options_from_dict({"flight_offsets": "maybe"})
