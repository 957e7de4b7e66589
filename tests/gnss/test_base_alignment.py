"""Base observations brought to the rover's epochs (base_alignment.py) and loss-of-lock flags
(cycle_slips.lli_slips): receivers whose clocks tag epochs a few milliseconds apart, half-cycle flag
transitions, slips carried to the first rover epoch that uses a base epoch."""

from __future__ import annotations

import numpy as np

from georef_core.gnss.base_alignment import SYNC_TOLERANCE_S, align_base_to_rover
from georef_core.gnss.cycle_slips import lli_slips
from georef_core.gnss.observations import ObservationSet


def _base(time_s, lli=None, n_s=2):
    n_e = len(time_s)
    shape = (n_e, n_s, 1)
    phase = np.arange(n_e, dtype=float)[:, None, None] * 10.0 + np.arange(n_s)[None, :, None] + np.zeros(shape)
    return ObservationSet("base.obs", np.asarray(time_s, dtype=float), [f"G{k + 1:02d}" for k in range(n_s)],
                          phase.copy(), phase, np.full(shape, np.nan), np.full(shape, 45.0),
                          np.zeros(shape, np.uint8) if lli is None else lli, np.zeros(shape, np.uint8), ["", "C1C"],
                          None, np.empty(0))


def test_base_epoch_a_few_ms_after_the_rover_epoch_is_that_epochs_own():
    # u-blox pair: rover tags x.987 s, base x.990 s (each on its own clock); base logs 1 of 7 epochs
    base_t = np.array([100.990, 107.990])
    rover_t = 100.987 + np.arange(8.0)
    base = _base(base_t)
    res = base.phase_cyc * 1.0
    out = align_base_to_rover(rover_t, base, res, res.copy(), np.full((2, 2), 0.5), 30.0, interpolate=True)
    np.testing.assert_allclose(out.age_s, [0.003, 0.997, 1.997, 2.997, 3.003, 2.003, 1.003, 0.003], atol=1e-9)
    np.testing.assert_array_equal(out.phase_res_m[7, :, 0], res[1, :, 0])   # not epoch 100.99, 7 s older
    np.testing.assert_array_equal(out.phase_res_m[0, :, 0], res[0, :, 0])
    # 30 ms after is not the same epoch any more
    late = align_base_to_rover(np.array([107.960]), base, res, res.copy(), np.full((2, 2), 0.5), 30.0, False)
    assert SYNC_TOLERANCE_S < 0.03 and abs(late.age_s[0] - 0.03) < 1e-9


def test_without_interpolation_the_nearest_base_epoch_is_used_and_its_slips_follow():
    # RTKLIB demo5's pairing: nearest base epoch, older or newer (rover 104.987 takes 106.99, 2.003 s ahead)
    base_t = np.array([100.990, 106.990, 108.990])
    lli = np.zeros((3, 2, 1), np.uint8)
    lli[1, 0, 0] = 1                        # G01 lost lock between base epochs 100.99 and 106.99
    base = _base(base_t, lli)
    res = base.phase_cyc * 1.0
    rover_t = 100.987 + np.arange(9.0)
    out = align_base_to_rover(rover_t, base, res, res.copy(), np.full((3, 2), 0.5), 30.0, interpolate=False)
    np.testing.assert_allclose(out.age_s, [0.003, 0.997, 1.997, 2.997, 2.003, 1.003, 0.003, 0.997, 0.003],
                               atol=1e-9)
    used = [0, 0, 0, 0, 1, 1, 1, 1, 2]
    np.testing.assert_array_equal(out.phase_res_m[:, :, 0], res[used, :, 0])
    # the slip applies from the first rover epoch that uses base epoch 106.99: 104.987, before it in time
    np.testing.assert_array_equal(np.nonzero(out.slip_into[:, 0, 0])[0], [4])
    assert not out.slip_into[:, 1, 0].any()


def test_interpolation_between_base_epochs_and_slip_carried_to_first_use():
    base_t = np.array([10.0, 12.0, 14.0])
    lli = np.zeros((3, 2, 1), np.uint8)
    lli[2, 1, 0] = 1                       # G02 lost lock before base epoch 14
    base = _base(base_t, lli)
    res = base.phase_cyc * 1.0
    rover_t = np.array([10.0, 11.0, 13.0, 14.0])
    out = align_base_to_rover(rover_t, base, res, res.copy(), np.full((3, 2), 0.5), 30.0, interpolate=True)
    np.testing.assert_allclose(out.phase_res_m[1, :, 0], 0.5 * (res[0, :, 0] + res[1, :, 0]))
    # between 12 and 14 G02 slipped: its residual is not interpolated across the slip (latest older epoch)
    assert out.phase_res_m[2, 0, 0] == 0.5 * (res[1, 0, 0] + res[2, 0, 0])
    assert out.phase_res_m[2, 1, 0] == res[1, 1, 0]
    np.testing.assert_array_equal(out.slip_into[:, 1, 0], [False, False, False, True])
    assert not out.slip_into[:, 0, 0].any()


def test_half_cycle_flag_change_is_a_slip_in_both_directions():
    # LLI bit 1 (half-cycle ambiguity unresolved) on, then resolved (the receiver shifts the phase by half a
    # cycle), on again after a gap in tracking; bit 0 (lost lock) as usual
    lli = np.array([2, 2, 0, 0, 0, 2, 2, 1, 0], np.uint8)[:, None, None]
    phase = np.arange(9.0)[:, None, None]
    phase[4] = np.nan                       # not observed at epoch 4: compare with epoch 3
    flags = lli_slips(lli, phase)[:, 0, 0]
    np.testing.assert_array_equal(flags, [False, False, True, False, False, True, False, True, False])
    # without the phases only bit 0 counts (as before)
    np.testing.assert_array_equal(lli_slips(lli)[:, 0, 0], lli[:, 0, 0] & 1 == 1)
