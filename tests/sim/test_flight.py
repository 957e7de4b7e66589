"""Flight plan, true trajectory, attitude, camera events and frames (no rendering)."""

from __future__ import annotations

import numpy as np
import pytest

from georef_core.gnss.frames import ecef_to_crs, ecef_to_geodetic
from georef_core.sim import CameraModel, CameraOptions, FlightOptions, SiteOptions, Trajectory, build_site, simulate_flight
from georef_core.sim.truth import camera_poses


@pytest.fixture(scope="module")
def flown():
    site = build_site(SiteOptions(size_m=(100.0, 60.0), stockpiles=("cone", "windrow", "slope_cone"),
                                  stockpile_scale=0.5), seed=11)
    cam = CameraModel.from_options(CameraOptions())
    fo = FlightOptions(height_m=50.0, speed_m_s=6.0, static_before_s=10.0, static_after_s=5.0)
    traj, events, plan = simulate_flight(site, cam, fo, seed=11)
    return site, cam, fo, traj, events, plan


def test_velocity_is_derivative_of_position(flown):
    _, _, _, traj, _, _ = flown
    t = np.linspace(traj.t_start + 1.0, traj.t_end - 1.0, 400)
    # gps_time_s ~ 1.4e9 s is resolved to ~2.4e-7 s: divide by the actual float differences
    t1, t2 = t - 1e-3, t + 1e-3
    dt = (t2 - t1)[:, None]
    tm = t1 + 0.5 * (t2 - t1)
    fd = (traj.position_ecef(t2) - traj.position_ecef(t1)) / dt
    v = traj.velocity_ecef(tm)
    assert np.max(np.abs(fd - v)) < 1e-5
    fd_enu = (traj.position_enu(t2) - traj.position_enu(t1)) / dt
    assert np.max(np.abs(fd_enu - traj.velocity_enu(tm))) < 1e-5
    # and on a coarse step, against the acceleration
    a_fd = (traj.velocity_enu(t2) - traj.velocity_enu(t1)) / dt
    assert np.max(np.abs(a_fd - traj.acceleration_enu(tm))) < 1e-4
    # the ECEF velocity is the ENU velocity rotated
    np.testing.assert_allclose(v, traj.velocity_enu(t) @ traj.frame.R_ecef_to_enu, atol=1e-9)


def test_trajectory_shape(flown):
    site, _, fo, traj, events, plan = flown
    t = np.linspace(traj.t_start, traj.t_end, 3000)
    p = traj.position_enu(t)
    v = traj.velocity_enu(t)
    # static at the start and end, on the ground
    assert np.all(np.linalg.norm(v[t < traj.t_start + fo.static_before_s - 2.0], axis=1) < 1e-6)
    ground = traj.frame.site_to_enu(*plan.takeoff_xy, plan.takeoff_ground_h + fo.antenna_height_m)
    np.testing.assert_allclose(p[0], ground, atol=1e-6)
    np.testing.assert_allclose(p[-1], ground, atol=1e-6)
    # speeds and accelerations physically plausible, height reached
    assert np.max(np.linalg.norm(v[:, :2], axis=1)) < fo.transit_speed_m_s + 0.6
    assert np.max(np.abs(traj.acceleration_enu(t))) < 4.0
    h = traj.frame.enu_to_grid(p)[:, 2]
    assert abs(h.max() - plan.flight_h) < 1.0
    # attitude: unit rotations, tilt within a few degrees on the lines
    te = np.array([e.exposure_gps_time_s for e in events])
    ypr = traj.yaw_pitch_roll_deg(te)
    assert np.all(np.abs(ypr[:, 1:]) < 15.0)
    R = traj.R_cam_to_enu(te)
    np.testing.assert_allclose(R @ np.transpose(R, (0, 2, 1)), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)
    assert np.all(R[:, 2, 2] < -0.95)  # optical axis looks down


def test_events(flown):
    site, cam, fo, traj, events, plan = flown
    assert len(events) == sum(len(ln["triggers_s"]) for ln in plan.lines)
    trig = np.array([e.trigger_gps_time_s for e in events])
    assert np.all(np.diff(trig) > 0)
    assert np.allclose([e.exposure_gps_time_s - e.trigger_gps_time_s for e in events], fo.trigger_delay_s, atol=1e-6)
    assert [e.name for e in events] == [f"IMG_{i + 1:04d}.JPG" for i in range(len(events))]
    # consecutive images on a line: antenna moved one trigger spacing (distance triggering)
    pos = traj.position_enu(trig)
    for a, b, pa, pb in zip(events[:-1], events[1:], pos[:-1], pos[1:]):
        if a.line == b.line:
            assert abs(np.linalg.norm(pb[:2] - pa[:2]) - plan.trigger_spacing_m) < 0.1
    # forward and side overlap from the footprint
    across, along = plan.footprint_m
    assert 1 - plan.trigger_spacing_m / along >= fo.forward_overlap - 1e-9
    assert 1 - plan.line_spacing_m / across >= fo.side_overlap - 1e-9


def test_lever_arm_and_delay_convention(flown):
    _, _, fo, traj, events, _ = flown
    poses = camera_poses(traj, events, fo.lever_arm_cam_m, fo.trigger_delay_s)
    lever = np.asarray(fo.lever_arm_cam_m)
    for e, p in zip(events, poses):
        te = e.exposure_gps_time_s
        c = traj.position_ecef(te) + traj.R_cam_to_ecef(te) @ lever
        np.testing.assert_allclose(p["camera_centre_ecef_m"], c, atol=1e-9)
        # the first-order model of the georeferencing step is good to a few mm on the lines
        tt = e.trigger_gps_time_s
        model = traj.position_ecef(tt) + traj.R_cam_to_ecef(te) @ lever + traj.velocity_ecef(tt) * fo.trigger_delay_s
        assert np.linalg.norm(model - c) < 5e-3
        assert p["first_order_model_error_m"] < 5e-3
        # the centre in the project CRS agrees with gnss.frames.ecef_to_crs
        np.testing.assert_allclose(p["camera_centre_crs_m"], ecef_to_crs(c, traj.frame.epsg), atol=1e-6)


def test_trajectory_csv_round_trip(flown, tmp_path):
    _, _, _, traj, _, _ = flown
    path = tmp_path / "trajectory.csv"
    traj.to_csv(path)
    back = Trajectory.from_csv(path, traj.frame)
    t = np.linspace(traj.t_start, traj.t_end, 2000)
    assert np.max(np.abs(back.position_ecef(t) - traj.position_ecef(t))) < 1e-5
    assert np.max(np.abs(back.velocity_ecef(t) - traj.velocity_ecef(t))) < 1e-4
    assert np.max(np.abs(back.R_cam_to_enu(t) - traj.R_cam_to_enu(t))) < 1e-8
    data = np.genfromtxt(path, delimiter=",", names=True)
    llh = ecef_to_geodetic(np.stack([data["x_ecef_m"], data["y_ecef_m"], data["z_ecef_m"]], -1))
    np.testing.assert_allclose(llh[:, 2], data["h_ell_m"], atol=2e-6)


def test_frames_consistent(flown):
    site = flown[0]
    f = site.frame
    e = f.origin_e + np.array([-50.0, 0.0, 70.0])
    n = f.origin_n + np.array([30.0, 0.0, -40.0])
    h = np.array([75.0, 80.0, 130.0])
    ecef = f.grid_to_ecef(e, n, h)
    np.testing.assert_allclose(ecef_to_crs(ecef, f.epsg), np.stack([e, n, h], -1), atol=1e-6)
    enu = f.ecef_to_enu(ecef)
    np.testing.assert_allclose(f.enu_to_ecef(enu), ecef, atol=1e-8)
    np.testing.assert_allclose(f.site_to_enu(0.0, 0.0, f.h_ref), 0.0, atol=1e-6)
    R = f.R_enu_to_grid_axes(f.origin_e, f.origin_n, f.h_ref)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    gamma, k = f.grid_factors(f.origin_e, f.origin_n)
    # grid north seen from ENU at the origin is true north turned by the convergence
    assert abs(np.arctan2(R[1, 0], R[1, 1]) - float(gamma)) < 1e-6


def test_two_height_calibration_flight():
    """--second-height: every other pair of lines at the second height, triggered along the line as usual."""
    site = build_site(SiteOptions(size_m=(100.0, 60.0), stockpiles=("cone",), stockpile_scale=0.5), seed=12)
    cam = CameraModel.from_options(CameraOptions())
    fo = FlightOptions(height_m=50.0, second_height_m=80.0, speed_m_s=6.0, second_speed_m_s=9.0, static_before_s=10.0,
                       static_after_s=5.0)
    traj, events, plan = simulate_flight(site, cam, fo, seed=12)
    assert len(plan.lines) >= 4
    assert [ln["height_m"] for ln in plan.lines[:4]] == [50.0, 50.0, 80.0, 80.0]
    h = traj.frame.enu_to_grid(traj.position_enu(np.array([e.trigger_gps_time_s for e in events])))[:, 2]
    for e, hk in zip(events, h):
        want = plan.flight_h + plan.lines[e.line]["height_m"] - fo.height_m
        assert abs(hk - want) < 1.0, (e.name, hk, want)
    assert len(events) == sum(len(ln["triggers_s"]) for ln in plan.lines)
    # the second pair of lines is flown faster
    trig = np.array([e.trigger_gps_time_s for e in events])
    speed = np.linalg.norm(traj.velocity_enu(trig)[:, :2], axis=1)
    for e, v in zip(events, speed):
        if 0 < events.index(e) < len(events) - 1 and abs(v - plan.lines[e.line]["speed_m_s"]) > 0.5:
            raise AssertionError((e.name, v, plan.lines[e.line]["speed_m_s"]))
