"""Slips the receivers did not flag, found in time-differenced carrier phase (tdcp_slips), on a simulated
u-blox L1 flight with known slips; and the lone-fix rule of the combined solution."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from georef_core.gnss.ppk import prepare
from georef_core.gnss.rtk_filter import STATUS_FIX, STATUS_FLOAT, FilterOutput
from georef_core.gnss.rtk_options import RtkOptions
from georef_core.gnss.smoothing import combine
from georef_core.gnss.tdcp_slips import time_differenced_slips
from georef_core.sim.gnss_observations import CycleSlip, ReceiverOptions, epoch_grid, simulate_survey

from .test_ppk_simulated import _drone_flight, _satellites_by_elevation, _site

pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered in power:RuntimeWarning")


def _new_slips(sv, nav, threshold_m):
    """(E, S, F) slips found by the time-differenced check alone (beyond LLI and the other detectors)."""
    opts = RtkOptions(base_position_ecef_m=tuple(sv.base_position_ecef_m), n_bands=1, systems=("G", "R"))
    off = prepare(sv.rover, sv.base, nav, dataclasses.replace(opts, slip_tdcp_threshold_m=0.0))[0]
    on = prepare(sv.rover, sv.base, nav, dataclasses.replace(opts, slip_tdcp_threshold_m=threshold_m))[0]
    return np.diff(on.slip_cum - off.slip_cum, axis=0) > 0, on


@pytest.mark.parametrize("cycles", [(1, 2, -3), (0.5,)])
def test_unflagged_slips_are_found_at_their_epoch_and_nowhere_else(cycles):
    """Three satellites slip together without an LLI flag in a 5 Hz u-blox L1 flight (turns, multipath,
    1 Hz base), or one by half a cycle: exactly those signals at exactly that epoch are flagged. (Several
    small slips at once on a few satellites can hide in the fit's clock and displacement: a limit.)"""
    nav, base, t0 = _site("multi")
    tr = _drone_flight(base, t0)
    span = tr.end_gps_s - t0 + 2.0
    gps = [s for s in _satellites_by_elevation(nav, tr, base, t0) if s[0] == "G"]
    slips = tuple(CycleSlip(t0 + 100.0, s, cycles=k, flagged=False) for s, k in zip(gps, cycles))
    sv = simulate_survey(nav, tr.position_ecef, tr.velocity_ecef, epoch_grid(t0, span, 5), base,
                         epoch_grid(t0, span, 1), seed=3,
                         rover_options=ReceiverOptions.ublox_l1(marker_name="ROVR", slips=slips),
                         base_options=ReceiverOptions.ublox_l1(marker_name="BASE", multipath_period_s=(60.0, 600.0)))
    found, data = _new_slips(sv, nav, 0.05)
    e_slip = int(np.argmin(np.abs(data.time_s - (t0 + 100.0))))
    if data.time_s[e_slip] < t0 + 100.0:
        e_slip += 1
    where = {(int(e), data.sat_ids[s]) for e, s, _ in np.argwhere(found)}
    assert where == {(e_slip, s) for s in gps[:len(cycles)]}, sorted(where)


def test_no_slip_no_flag_and_threshold_off():
    """A flight without slips: nothing flagged over 1400 epochs; threshold 0 turns the check off."""
    nav, base, t0 = _site("multi")
    tr = _drone_flight(base, t0)
    span = tr.end_gps_s - t0 + 2.0
    sv = simulate_survey(nav, tr.position_ecef, tr.velocity_ecef, epoch_grid(t0, span, 5), base,
                         epoch_grid(t0, span, 1), seed=4, rover_options=ReceiverOptions.ublox_l1(marker_name="ROVR"),
                         base_options=ReceiverOptions.ublox_l1(marker_name="BASE", multipath_period_s=(60.0, 600.0)))
    found, data = _new_slips(sv, nav, 0.05)
    assert len(data.time_s) > 1000
    assert not found.any(), np.argwhere(found)[:10]
    sd = np.zeros((3, 8, 1))
    assert not time_differenced_slips(np.arange(3.0), sd, np.ones((3, 8, 3)) / np.sqrt(3), np.zeros(8, np.int64),
                                      np.zeros((3, 8, 1), bool), threshold_m=0.0).any()


def test_time_differenced_fit_separates_displacement_clock_and_slip():
    """Synthetic geometry: a 1.3 m displacement and clock changes per system are absorbed by the fit; a
    0.1 m jump on one signal is the only flag; a pair of epochs too far apart is not checked."""
    rng = np.random.default_rng(7)
    n_e, n_s = 4, 10
    los = rng.normal(size=(n_s, 3))
    los[:, 2] = np.abs(los[:, 2]) + 0.3
    los = np.broadcast_to(los / np.linalg.norm(los, axis=1, keepdims=True), (n_e, n_s, 3))
    sys_code = np.array([0] * 6 + [1] * 4)
    pos = np.cumsum(rng.normal(scale=1.0, size=(n_e, 3)), axis=0)
    clock = rng.normal(scale=100.0, size=(n_e, 2))
    sd = (-np.einsum("esk,ek->es", los, pos) + clock[:, sys_code] + rng.normal(scale=0.002, size=(n_e, n_s)))[..., None]
    sd[2:, 4, 0] += 0.1                      # slip of 0.1 m on satellite 4 into epoch 2
    time_s = np.array([0.0, 1.0, 2.0, 40.0])  # epoch 3 is 38 s after epoch 2: not checked
    sd[3, 7, 0] += 0.5
    found = time_differenced_slips(time_s, sd, los, sys_code, np.zeros(sd.shape, bool))
    assert [tuple(x) for x in np.argwhere(found)] == [(2, 4, 0)]


def _output(status, pos):
    n = len(status)
    return FilterOutput(np.array(status), np.array(pos, float), np.tile(np.eye(3) * 1e-4, (n, 1, 1)), np.full(n, 8),
                        np.where(np.array(status) == STATUS_FIX, 3.5, 1.2), np.zeros((n, 2, 1)), np.zeros(n, np.int64))


def test_combined_solution_does_not_take_a_lone_fix_against_a_float():
    """A fix alone in its pass (float before and after) where the other pass is float is refused: the epoch
    is the covariance-weighted mean of the two floats (the u-blox walk's only combined fixes the carrier
    phase contradicts were such); a fix with a fixed neighbour is taken as before."""
    f, x = STATUS_FLOAT, STATUS_FIX
    fwd = _output([f, f, f, x, x, f, x], np.zeros((7, 3)))
    bwd = _output([f, x, f, f, f, f, f], np.ones((7, 3)))
    for p in (fwd, bwd):      # each pass's float solution: zeros forward, 2 m backward
        p.float_position_ecef_m = np.full((7, 3), 0.0 if p is fwd else 2.0)
        p.float_covariance_ecef_m2 = p.covariance_ecef_m2.copy()
        p.position_ecef_m[p.status == f] = p.float_position_ecef_m[p.status == f]
    out, conflict = combine(fwd, bwd)
    assert list(out.status) == [f, f, f, x, x, f, f]
    assert not conflict.any()
    np.testing.assert_allclose(out.position_ecef_m[1], np.ones(3))      # the mean of the floats, not the lone fix
    np.testing.assert_array_equal(out.position_ecef_m[3], np.zeros(3))   # forward's run of two fixes
    np.testing.assert_allclose(out.position_ecef_m[6], np.ones(3))      # forward's lone fix at the end: refused too


def test_combined_solution_keeps_the_smoothed_float_beside_the_fix():
    """The combined output's float solution (what a refused fix falls back to) is the covariance-weighted
    mean of the two passes' floats where both exist, else the one that exists."""
    f, x = STATUS_FLOAT, STATUS_FIX
    fwd = _output([x, x, f], np.zeros((3, 3)))
    bwd = _output([x, f, f], np.ones((3, 3)))
    fwd.float_position_ecef_m = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [np.nan, np.nan, np.nan]])
    fwd.float_covariance_ecef_m2 = np.stack([np.eye(3) * 1.0, np.eye(3) * 1.0, np.full((3, 3), np.nan)])
    bwd.float_position_ecef_m = np.array([[3.0, 3.0, 3.0], [4.0, 4.0, 4.0], [5.0, 5.0, 5.0]])
    bwd.float_covariance_ecef_m2 = np.stack([np.eye(3) * 3.0, np.eye(3) * 1.0, np.eye(3) * 2.0])
    out, _ = combine(fwd, bwd)
    np.testing.assert_allclose(out.float_position_ecef_m[0], [0.75] * 3)      # weights 1 and 1/3
    np.testing.assert_allclose(out.float_covariance_ecef_m2[0], np.eye(3) * 0.75)
    np.testing.assert_allclose(out.float_position_ecef_m[1], [2.5] * 3)
    np.testing.assert_allclose(out.float_position_ecef_m[2], [5.0] * 3)       # backward's only
    np.testing.assert_allclose(out.float_covariance_ecef_m2[2], np.eye(3) * 2.0)
