"""Base observations brought to the rover's epochs (base_alignment.py) and loss-of-lock flags
(cycle_slips.lli_slips): receivers whose clocks tag epochs a few milliseconds apart, half-cycle flag
transitions, slips carried to the first rover epoch that uses a base epoch."""

from __future__ import annotations

import numpy as np
import pytest

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


def test_base_epochs_with_another_ephemeris_record_than_the_rover_epoch_give_no_base_data():
    # G01's record changes between base epochs 20 and 40 (a base gap across the change), G02's does not;
    # rover epochs 21..39 pair with 20 (older) or 40 (newer); a rover epoch after the change paired with the
    # base epoch before it (or interpolated with it) carries the records' discontinuity: no base data there
    base_t = np.array([10.0, 20.0, 40.0])
    base = _base(base_t)
    res = base.phase_cyc * 1.0
    rover_t = np.array([20.0, 25.0, 29.0, 31.0, 35.0, 40.0])
    rec_base = np.array([[0, 5], [0, 5], [1, 5]])
    rec_rover = np.array([[0, 5], [0, 5], [1, 5], [1, 5], [1, 5], [1, 5]])   # G01 changes record at 28 s
    el = np.full((3, 2), 0.5)
    plain = align_base_to_rover(rover_t, base, res, res.copy(), el, 30.0, interpolate=False)
    near = align_base_to_rover(rover_t, base, res, res.copy(), el, 30.0, interpolate=False,
                               records=(rec_base, rec_rover))
    # nearest pairing: 29 s takes the 20 s epoch (old record) with the rover's new one; 31 s takes 40 s (new)
    np.testing.assert_array_equal(np.isnan(near.phase_res_m[:, 0, 0]), [False, False, True, False, False, False])
    np.testing.assert_array_equal(np.isnan(near.code_res_m[:, 0, 0]), [False, False, True, False, False, False])
    np.testing.assert_array_equal(near.phase_res_m[:, 1, 0], plain.phase_res_m[:, 1, 0])   # G02 unchanged
    np.testing.assert_array_equal(near.age_s, plain.age_s)
    # interpolation across the gap uses both epochs: every rover epoch strictly inside it mixes the records
    interp = align_base_to_rover(rover_t, base, res, res.copy(), el, 30.0, interpolate=True,
                                 records=(rec_base, rec_rover))
    np.testing.assert_array_equal(np.isnan(interp.phase_res_m[:, 0, 0]), [False, True, True, True, True, False])
    assert np.isfinite(interp.phase_res_m[:, 1, 0]).all()
    with pytest.raises(ValueError, match="do not fit"):
        align_base_to_rover(rover_t, base, res, res.copy(), el, 30.0, interpolate=True,
                            records=(rec_base, rec_rover[:3]))


def test_ephemeris_records_change_at_the_glonass_record_boundary_of_the_shipped_file():
    # the shipped navigation file (simulated cases, bench/gnss_sim_vs_demo5.py): GLONASS records every 30 min;
    # the engine changes record at 08:30:18 GPST (the middle between two records), GPS keeps its record
    from georef_core.gnss.base_alignment import ephemeris_records
    from georef_core.gnss.gnss_time import calendar_to_gps_time_s
    from georef_core.gnss.rinex_nav import read_rinex_nav
    from georef_core.sim.survey_gnss import SHIPPED_NAV

    nav = read_rinex_nav(SHIPPED_NAV)
    t = calendar_to_gps_time_s(2024, 6, 24, 8, 30, 0) + np.array([10.0, 17.0, 19.0, 30.0])
    glo = ephemeris_records(nav, sorted(nav.glonass), t)
    glo = glo[:, (glo >= 0).all(axis=0)]                 # satellites with a healthy record at these times
    assert glo.shape[1] >= 3
    np.testing.assert_array_equal(glo[0], glo[1])
    np.testing.assert_array_equal(glo[2], glo[3])
    assert (glo[2] != glo[1]).all()
    gps = ephemeris_records(nav, sorted(nav.kepler)[:4], t)
    assert (gps >= 0).all() and (gps == gps[0]).all()
