"""Tests of georef_core.sim.gnss_observations, the raw GNSS observation simulator (fast, a few seconds).

The simulated observations must (1) load identically in our RINEX reader and in georinex, (2) agree with the
engine's own observation model (georef_core's ephemeris, geometric_range_m, group delays) to < 1 mm once the
recorded truth (clocks, delays, biases, ambiguities, errors) is removed, (3) carry Doppler consistent with the
carrier-phase rate, and (4) give single-point positions within the injected errors of the truth.

Navigation files: the committed GPS-only GSI file (2005) always; the multi-GNSS MatRTKLIB file (2024, GPS,
GLONASS, Galileo, QZSS, BeiDou) from the shared data folder when present (tests needing it skip otherwise).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from tests.gnss.rtklib_cases import shared_gnss_dir

from georef_core.gnss.constants import CLIGHT_M_S
from georef_core.gnss.ephemeris import select_ephemeris
from georef_core.gnss.frames import ecef_delta_to_enu_m, ecef_to_enu_rotation, ecef_to_geodetic, geodetic_to_ecef_m
from georef_core.gnss.gnss_time import calendar_to_gps_time_s
from georef_core.gnss.observations import select_bands
from georef_core.gnss.rinex_nav import read_rinex_nav
from georef_core.gnss.rinex_obs import RINEX2_TO_RINEX3, read_rinex_obs
from georef_core.gnss.rtk_options import RtkOptions
from georef_core.gnss.satellite_geometry import compute_observed_satellites, geometric_range_m
from georef_core.gnss.spp import solve_spp
from georef_core.sim.gnss_observations import (
    ClockOptions,
    CycleSlip,
    Environment,
    ReceiverOptions,
    epoch_grid,
    lawnmower_trajectory,
    simulate_receiver,
    simulate_survey,
    single_difference_ambiguities,
    static_trajectory,
    write_survey_gnss,
)

REPO = Path(__file__).resolve().parents[2]
GSI_NAV = REPO / "tests" / "data" / "gnss" / "gsi_0759_3040" / "30400920.05n"
GSI_BASE = np.array([-3978241.958, 3382840.234, 3649900.853])   # GEONET 3040 (RTKLIB's test coordinates)
GSI_T0 = calendar_to_gps_time_s(2005, 4, 2, 12, 0, 0)
MULTI_T0 = calendar_to_gps_time_s(2024, 6, 24, 8, 20, 0)
MULTI_BASE_LLH = (35.134707705, 136.977577939, 104.853)


def shared_multi_nav() -> Path | None:
    """The multi-GNSS navigation file of the shared data, or None (tests that need it skip)."""
    root = shared_gnss_dir()
    return None if root is None else root / "matrtklib_static_1m" / "base.nav"


MULTI_NAV = shared_multi_nav()
# the engine's SPP evaluates the standard atmosphere at absurd heights during its first iterations (harmless)
pytestmark = pytest.mark.filterwarnings("ignore:invalid value encountered in power:RuntimeWarning")
QUIET = dict(code_sigma_a_m=0.0, code_sigma_b_m=0.0, phase_sigma_a_m=0.0, phase_sigma_b_m=0.0, code_multipath_m=0.0,
             phase_multipath_m=0.0, doppler_sigma_a_hz=0.0, doppler_sigma_b_hz=0.0)


def _site(which: str):
    if which == "gsi":
        return read_rinex_nav(GSI_NAV), GSI_BASE.copy(), GSI_T0, [GSI_NAV]
    if MULTI_NAV is None:
        pytest.skip("multi-GNSS navigation file (shared data matrtklib_static_1m/base.nav) not found")
    lat, lon, h = MULTI_BASE_LLH
    return read_rinex_nav(MULTI_NAV), geodetic_to_ecef_m(np.radians(lat), np.radians(lon), h), MULTI_T0, [MULTI_NAV]


def _enu_offset(base, enu):
    lat, lon, _ = ecef_to_geodetic(base)
    return base + ecef_to_enu_rotation(lat, lon).T @ np.asarray(enu, float)


@pytest.fixture(scope="module", params=["gsi", "multi"])
def quiet_survey(request):
    """Noise-free, multipath-free receivers and an environment without broadcast errors: the observations must
    match the engine's model to the float64 time resolution. The rover flies (5 Hz), the base is static (1 Hz)."""
    nav, base, t0, _ = _site(request.param)
    tr = lawnmower_trajectory(_enu_offset(base, [20.0, 10.0, 0.0]), t0, n_lines=2, line_length_m=60.0,
                              static_before_s=5.0)
    env = Environment(seed=3, orbit_error_m=0.0, clock_error_m=0.0)
    sv = simulate_survey(nav, tr.position_ecef, tr.velocity_ecef, epoch_grid(t0, 120.0, 5), base,
                         epoch_grid(t0, 120.0, 1), seed=5, environment=env,
                         rover_options=ReceiverOptions(marker_name="ROVR", **QUIET),
                         base_options=ReceiverOptions(marker_name="BASE", **QUIET))
    return request.param, nav, sv


def _switch_mask(nav, truth, window_s: float = 65.0) -> np.ndarray:
    """(E, S) True within window_s of a change of the broadcast record (the truth orbit is blended over 120 s
    there, while the model switches record)."""
    out = np.zeros(truth.range_m.shape, bool)
    t = truth.true_time_s
    probe = np.arange(t[0] - window_s - 1.0, t[-1] + window_s + 1.0, 1.0)
    for i, sat in enumerate(truth.sat_ids):
        recs = [select_ephemeris(nav, sat, x) for x in probe]
        for k in range(1, len(recs)):
            if recs[k] is not recs[k - 1]:
                out[np.abs(t - probe[k]) < window_s, i] = True
    return out


# ------------------------------------------------------------------------------------------------------------
# trajectories and epochs
# ------------------------------------------------------------------------------------------------------------

def test_epoch_grid_and_lawnmower_trajectory():
    tags = epoch_grid(1000.05, 2.0, 5)
    np.testing.assert_allclose(tags, 1000.2 + 0.2 * np.arange(10), atol=1e-9)
    origin = _enu_offset(GSI_BASE, [20.0, 10.0, 0.0])
    tr = lawnmower_trajectory(origin, GSI_T0, speed_m_s=5.0, n_lines=3, line_length_m=80.0, line_spacing_m=20.0,
                              height_m=40.0, static_before_s=10.0)
    t = np.linspace(tr.start_gps_s + 0.5, tr.end_gps_s - 0.5, 2000)
    h = 1e-3
    t1, t2 = t - h, t + h
    fd = (tr.position_ecef(t2) - tr.position_ecef(t1)) / (t2 - t1)[:, None]
    np.testing.assert_allclose(fd, tr.velocity_ecef(t1 + 0.5 * (t2 - t1)), atol=2e-4)
    speed = np.linalg.norm(tr.velocity_enu(t), axis=1)
    dt_s = t[1] - t[0]
    assert np.sum(np.abs(speed - 5.0) < 0.02) * dt_s > 3 * 80.0 / 5.0 * 0.8     # flies the lines at 5 m/s
    assert speed.max() < 5.05
    # static on the ground before take-off, at the origin; flies at 40 m
    np.testing.assert_allclose(tr.position_ecef(np.array([GSI_T0, GSI_T0 + 9.0])), np.array([origin, origin]),
                               atol=1e-6)
    assert np.max(tr.position_enu(t)[:, 2]) == pytest.approx(40.0, abs=0.01)
    pos, vel = static_trajectory(GSI_BASE)
    assert pos(np.zeros(4)).shape == (4, 3) and not vel(np.zeros(4)).any()


@pytest.mark.parametrize("which", ["gsi", "multi"])
def test_true_orbits_are_the_broadcast_orbits_away_from_record_changes(which):
    """The interpolated satellite truth (2 s grid, cubic Hermite) equals a direct broadcast evaluation to < 2 um
    (positions), < 1e-4 m/s (velocities), < 1e-6 m (clocks) wherever no record change is within 70 s."""
    from georef_core.gnss.ephemeris import ephemeris_states
    from georef_core.sim.gnss_observations import _OrbitTruth

    nav, _, t0, _ = _site(which)
    sats = sorted(set(nav.kepler) | set(nav.glonass))[::3]
    orbit = _OrbitTruth(nav, sats, t0, -1.0, 1800.0, Environment(orbit_error_m=0.0, clock_error_m=0.0))
    rng = np.random.default_rng(0)
    q = np.round(rng.uniform(0.0, 1800.0, (40, len(sats))) * 1024) / 1024     # exact in t0 + q
    pos, vel, clk, _ = orbit.states(q)
    n = 0
    for i, sat in enumerate(sats):
        probe = np.arange(-80.0, 1880.0, 5.0)
        recs = [select_ephemeris(nav, sat, t0 + x) for x in probe]
        near = np.zeros(len(q), bool)
        for k in range(1, len(recs)):
            if recs[k] is not recs[k - 1]:
                near |= np.abs(q[:, i] - probe[k]) < 70.0
        st = ephemeris_states([select_ephemeris(nav, sat, t0 + x) for x in q[:, i]], t0 + q[:, i])
        ok = st.valid & ~near
        assert np.all(np.isfinite(pos[ok, i]))
        assert np.max(np.linalg.norm(pos[ok, i] - st.position_ecef_m[ok], axis=1), initial=0.0) < 2e-6
        assert np.max(np.linalg.norm(vel[ok, i] - st.velocity_ecef_m_s[ok], axis=1), initial=0.0) < 1e-4
        assert np.max(np.abs(clk[ok, i] - CLIGHT_M_S * st.clock_bias_s[ok]), initial=0.0) < 1e-6
        n += int(ok.sum())
    assert n > 200


# ------------------------------------------------------------------------------------------------------------
# files: our reader and georinex
# ------------------------------------------------------------------------------------------------------------

def _assert_same(back, raw, code_map=None, systems="GREJC", atol=6e-4):
    """Every value of `raw` (systems kept) is in `back` (codes renamed through code_map[sys]), and nothing else."""
    code_map = code_map or {}
    sats = [s for s in raw.sat_ids if s[0] in systems]
    assert back.sat_ids == sats
    np.testing.assert_allclose(back.gps_time_s, raw.gps_time_s, rtol=0, atol=1e-6)
    np.testing.assert_allclose(back.event_gps_time_s, raw.event_gps_time_s, rtol=0, atol=1e-6)
    n = 0
    for j, sat in enumerate(sats):
        s = raw.sat_ids.index(sat)
        for k, code in enumerate(raw.obs_codes):
            mine = raw.values[:, s, k]
            if np.isnan(mine).all():
                continue
            kb = back.obs_codes.index(code_map.get(sat[0], {}).get(code, code))
            theirs = back.values[:, j, kb]
            np.testing.assert_array_equal(np.isnan(theirs), np.isnan(mine), err_msg=f"{sat} {code}")
            ok = ~np.isnan(mine)
            np.testing.assert_allclose(theirs[ok], mine[ok], rtol=0, atol=atol, err_msg=f"{sat} {code}")
            np.testing.assert_array_equal(back.lli[ok, j, kb], raw.lli[ok, s, k], err_msg=f"{sat} {code} LLI")
            np.testing.assert_array_equal(back.ssi[ok, j, kb], raw.ssi[ok, s, k], err_msg=f"{sat} {code} SSI")
            n += int(ok.sum())
    return n


def _assert_matches_georinex(raw, path, rinex2: bool) -> int:
    gr = pytest.importorskip("georinex")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = gr.load(path, useindicators=True)
    gps_epoch = np.datetime64("1980-01-06T00:00:00", "ns")
    t = (ds.time.values.astype("datetime64[ns]") - gps_epoch).astype(np.int64) / 1e9
    np.testing.assert_allclose(t, raw.gps_time_s, rtol=0, atol=1.5e-3)
    n = 0
    for var in ds.data_vars:
        if var.endswith(("lli", "ssi")):
            continue
        for i, sv in enumerate(str(s) for s in ds.sv.values):
            code = RINEX2_TO_RINEX3.get(sv[0], {}).get(var) if rinex2 else var
            g = ds[var].values[:, i].astype(float)
            g[g == 0] = np.nan
            if code is None or sv not in raw.sat_ids or code not in raw.obs_codes:
                assert np.isnan(g).all(), (var, sv)
                continue
            ours = raw.values[:, raw.sat_ids.index(sv), raw.obs_codes.index(code)]
            np.testing.assert_array_equal(np.isnan(ours), np.isnan(g), err_msg=f"{sv} {var}")
            ok = ~np.isnan(g)
            np.testing.assert_allclose(ours[ok], g[ok], rtol=0, atol=5e-4, err_msg=f"{sv} {var}")
            if var + "lli" in ds:
                gi = np.nan_to_num(ds[var + "lli"].values[:, i].astype(float))[ok]
                np.testing.assert_array_equal(raw.lli[ok, raw.sat_ids.index(sv), raw.obs_codes.index(code)], gi)
            n += int(ok.sum())
    return n


@pytest.mark.parametrize("version", [3, 2])
@pytest.mark.parametrize("which", ["gsi", "multi"])
def test_written_files_load_identically_in_our_reader_and_georinex(tmp_path, version, which):
    nav, base, t0, nav_paths = _site(which)
    rover_pos = _enu_offset(base, [40.0, -30.0, 2.0])
    pos, vel = static_trajectory(rover_pos)
    sats_g = [s for s in sorted(nav.kepler) if s[0] == "G"]
    ro = ReceiverOptions(marker_name="ROVR",
                         slips=(CycleSlip(t0 + 1.0, sats_g[0], 3), CycleSlip(t0 + 1.4, sats_g[1], -2, band=0)),
                         outage_rate_per_hour=600.0, outage_duration_s=(0.2, 0.5))
    sv = simulate_survey(nav, pos, vel, epoch_grid(t0, 2.0, 5), base, epoch_grid(t0, 2.0, 1), seed=11,
                         rover_options=ro, events_gps_s=[t0 + 0.33, t0 + 1.5012345])
    out = write_survey_gnss(tmp_path, sv.rover, sv.base, nav_paths, rinex_version=version, truth=sv)
    assert [p.name for p in out["nav"]] == [Path(p).name for p in nav_paths]
    assert (tmp_path / "nav" / Path(nav_paths[0]).name).read_bytes() == Path(nav_paths[0]).read_bytes()
    assert all(p.is_file() for p in out["truth"])
    for folder, raw in (("rover", sv.rover), ("base", sv.base)):
        path = out[folder][0]
        back = read_rinex_obs(path)
        if version == 3:
            assert back.obs_codes == raw.obs_codes
            assert _assert_same(back, raw) > 100
            assert back.header.glonass_fcn == raw.header.glonass_fcn
        else:
            # RINEX 2.11: no QZSS/BeiDou; Galileo types read back as the X attribute
            e_map = {c: c[:2] + "X" for c in raw.obs_codes}
            assert _assert_same(back, raw, code_map={"E": e_map}, systems="GRE") > 100
        np.testing.assert_allclose(back.header.approx_position_ecef_m, raw.header.approx_position_ecef_m, atol=1e-4)
        assert _assert_matches_georinex(back, path, rinex2=version == 2) > 100
    assert (sv.rover.lli & 1).any()            # slips and reacquisitions are flagged
    assert not (sv.rover.lli & 2).any()        # never a half-cycle flag


# ------------------------------------------------------------------------------------------------------------
# consistency with the engine's observation model
# ------------------------------------------------------------------------------------------------------------

def test_code_and_phase_match_the_engine_model(quiet_survey):
    """P - [rho + c dtr - c dts + T + I + c TGD + B] and L lambda - [rho + c dtr - c dts + T - I + N lambda] vanish
    (< 0.5 mm: the engine's float64 transmission time resolution), with rho and dts from the engine's own
    satellite states and geometric_range_m at the true position."""
    which, nav, sv = quiet_survey
    for raw, truth in ((sv.rover, sv.rover_truth), (sv.base, sv.base_truth)):
        obs = select_bands(raw)
        sats = compute_observed_satellites(obs, nav)
        rng, _ = geometric_range_m(np.nan_to_num(sats.position_ecef_m), truth.position_ecef_m[:, None, :])
        model = rng + CLIGHT_M_S * truth.clock_bias_s[:, None] - CLIGHT_M_S * sats.clock_bias_s + truth.troposphere_m
        far = ~_switch_mask(nav, truth)
        n_bands = 2
        for b in range(n_bands):
            lam = truth.wavelength_m[None, :, b]
            code_res = (obs.code_m[..., b] - model - truth.ionosphere_m[..., b] - truth.group_delay_m[None, :, b]
                        - truth.receiver_code_bias_m[None, :, b])
            phase_res = (obs.phase_cyc[..., b] * lam - model + truth.ionosphere_m[..., b]
                         - truth.ambiguity_cyc[..., b] * lam)
            ok = far & np.isfinite(code_res)
            assert ok.sum() > 100
            assert np.max(np.abs(code_res[ok])) < 5e-4, (which, b)
            assert np.max(np.abs(phase_res[ok])) < 5e-4, (which, b)
            # the truth range is the one the engine computes (same satellite, same Earth-rotation term)
            assert np.nanmax(np.abs((truth.range_m - rng)[far])) < 5e-4
        # near ephemeris changes the truth is continuous while the model switches record: decimetres at most
        assert np.nanmax(np.abs(truth.range_m - rng)) < 1.0


def test_recorded_errors_are_what_the_observations_carry():
    """With noise and multipath on, the code/phase residuals to the truth model equal the recorded errors, and
    those errors have the sigmas asked for (a + b / sin(el) white noise plus elevation-dependent multipath)."""
    nav, base, t0, _ = _site("gsi")
    pos, vel = static_trajectory(base)
    o = ReceiverOptions(code_multipath_m=0.0, phase_multipath_m=0.0)
    raw, truth = simulate_receiver(nav, pos, vel, epoch_grid(t0, 600.0, 1), o, np.random.default_rng(1),
                                   environment=Environment(seed=1))
    obs = select_bands(raw)
    model = (truth.range_m + CLIGHT_M_S * truth.clock_bias_s[:, None] - truth.satellite_clock_m + truth.troposphere_m)
    code_res = obs.code_m[..., 0] - model - truth.ionosphere_m[..., 0] - truth.group_delay_m[None, :, 0] \
        - truth.receiver_code_bias_m[None, :, 0]
    np.testing.assert_allclose(code_res[np.isfinite(code_res)], truth.code_error_m[..., 0][np.isfinite(code_res)],
                               atol=1.5e-3)
    lam = truth.wavelength_m[None, :, 0]
    ph_res = obs.phase_cyc[..., 0] * lam - model + truth.ionosphere_m[..., 0] - truth.ambiguity_cyc[..., 0] * lam
    ok = np.isfinite(ph_res)
    np.testing.assert_allclose(ph_res[ok], truth.phase_error_m[..., 0][ok], atol=5e-4)
    # noise sigma a + b / sin(el): normalised errors have unit spread
    sig_c = o.code_sigma_a_m + o.code_sigma_b_m / np.sin(truth.elevation_rad)
    sig_p = o.phase_sigma_a_m + o.phase_sigma_b_m / np.sin(truth.elevation_rad)
    zc = (truth.code_error_m[..., 0] / sig_c)[ok]
    zp = (truth.phase_error_m[..., 0] / sig_p)[ok]
    assert 0.9 < np.std(zc) < 1.1 and abs(np.mean(zc)) < 0.1
    assert 0.9 < np.std(zp) < 1.1 and abs(np.mean(zp)) < 0.1
    # L2W (semi-codeless) is noisier than L1C
    assert np.nanstd(truth.code_error_m[..., 1]) > 1.3 * np.nanstd(truth.code_error_m[..., 0])
    # C/N0 rises with elevation
    el = truth.elevation_rad[ok]
    snr = obs.snr_dbhz[..., 0][ok]
    assert np.mean(snr[el > np.radians(60)]) > np.mean(snr[el < np.radians(20)]) + 6


def test_doppler_is_the_carrier_phase_rate(quiet_survey):
    """-lambda D equals the phase rate (central differences) to < 1 mm/s once the common receiver-clock term
    (white frequency noise, the same for every satellite) is removed; a Doppler velocity lands within 1 cm/s."""
    which, nav, sv = quiet_survey
    raw, truth = sv.rover, sv.rover_truth
    obs = select_bands(raw)
    lam = truth.wavelength_m[None]
    rate = -obs.doppler_hz * lam
    ph = obs.phase_cyc * lam
    t = truth.true_time_s
    dt = (t[2:] - t[:-2])[:, None, None]
    fd = (ph[2:] - ph[:-2]) / dt
    d = fd - rate[1:-1]
    d = d - np.nanmedian(d[..., 0], axis=1)[:, None, None]
    # the central difference is exact to h^2/6 * jerk: keep epochs where the antenna's acceleration is smooth
    v = truth.velocity_ecef_m_s
    jerk = np.linalg.norm(v[2:] - 2 * v[1:-1] + v[:-2], axis=1) / (0.5 * (t[2:] - t[:-2])) ** 2
    smooth = jerk < 0.05
    assert smooth.mean() > 0.5
    assert np.nanmax(np.abs(d[smooth])) < 1e-3
    sats = compute_observed_satellites(obs, nav)
    spp = solve_spp(obs, sats, nav, RtkOptions())
    dv = spp.velocity_ecef_m_s - truth.velocity_ecef_m_s
    assert np.nanmax(np.linalg.norm(dv, axis=1)) < 0.01
    drift = spp.clock_drift_m_s / CLIGHT_M_S
    assert np.nanmax(np.abs(drift - truth.clock_drift_s_s)) < 1e-10


@pytest.mark.parametrize("which", ["gsi", "multi"])
def test_single_point_positions_within_the_injected_errors(which):
    """Code SPP (broadcast ionosphere, Saastamoinen) with a small ionospheric residual, 0.3 m broadcast errors and
    a geodetic receiver: < 5 m horizontally from the truth, and the receiver clock recovered to ~10 ns."""
    nav, base, t0, _ = _site(which)
    tr = lawnmower_trajectory(_enu_offset(base, [20.0, 10.0, 0.0]), t0, n_lines=2, line_length_m=60.0)
    env = Environment(seed=2, iono_residual_m=0.05)
    raw, truth = simulate_receiver(nav, tr.position_ecef, tr.velocity_ecef, epoch_grid(t0, 120.0, 2),
                                   ReceiverOptions(), np.random.default_rng(2), environment=env)
    obs = select_bands(raw)
    sats = compute_observed_satellites(obs, nav)
    spp = solve_spp(obs, sats, nav, RtkOptions())
    assert spp.valid.all()
    enu = ecef_delta_to_enu_m(spp.position_ecef_m - truth.position_ecef_m, base)
    horiz = np.hypot(enu[:, 0], enu[:, 1])
    assert np.max(horiz) < 5.0 and np.median(horiz) < 2.0
    assert np.max(np.abs(enu[:, 2])) < 10.0
    clk = spp.clock_bias_m[:, 0] / CLIGHT_M_S
    assert np.max(np.abs(clk - truth.clock_bias_s)) < 3e-8
    # and through the engine's front door (ppk.solve, mode single)
    from georef_core.gnss.ppk import solve

    bpos, bvel = static_trajectory(base)
    base_raw, _ = simulate_receiver(nav, bpos, bvel, epoch_grid(t0, 120.0, 1), ReceiverOptions(),
                                    np.random.default_rng(3), environment=env)
    sol = solve(raw, base_raw, nav, RtkOptions(mode="single", base_position_ecef_m=tuple(base)))
    assert (sol.status == 5).all()
    np.testing.assert_allclose(sol.position_ecef_m, spp.position_ecef_m, atol=1e-6)
    np.testing.assert_allclose(sol.time_s, truth.true_time_s, atol=1e-7 + 3e-8)


# ------------------------------------------------------------------------------------------------------------
# ambiguities, slips, outages, gaps, clocks
# ------------------------------------------------------------------------------------------------------------

def test_double_differences_reproduce_the_ambiguity_truth(quiet_survey):
    """SD phase - SD truth model - lambda (N_rover - N_base) is the receiver-clock difference alone: its double
    differences vanish, so the recorded single-difference truth is the one in the data (GLONASS included)."""
    which, nav, sv = quiet_survey
    r, b = sv.rover_truth, sv.base_truth
    sd_n = sv.sd_ambiguity_cyc
    assert np.all(np.isnan(sd_n) | (sd_n == np.round(sd_n)))
    common = np.nonzero(np.isin(np.round(r.receiver_time_s, 3), np.round(b.receiver_time_s, 3)))[0]
    jb = np.searchsorted(b.receiver_time_s, r.receiver_time_s[common] - 1e-3)
    ro, bo = select_bands(sv.rover), select_bands(sv.base)
    col = [b.sat_ids.index(s) for s in r.sat_ids]
    checked = 0
    for band in range(2):
        lam = r.wavelength_m[:, band]
        sd = (ro.phase_cyc[common, :, band] - bo.phase_cyc[jb][:, col, band]) * lam \
            - (r.range_m[common] - b.range_m[jb][:, col]) \
            + (r.satellite_clock_m[common] - b.satellite_clock_m[jb][:, col]) \
            - (r.troposphere_m[common] - b.troposphere_m[jb][:, col]) \
            + (r.ionosphere_m[common, :, band] - b.ionosphere_m[jb][:, col, band]) - sd_n[common, :, band] * lam
        clk = CLIGHT_M_S * (r.clock_bias_s[common] - b.clock_bias_s[jb])
        res = sd - clk[:, None]
        ok = np.isfinite(res)
        assert ok.sum() > 200
        assert np.max(np.abs(res[ok])) < 1e-3, (which, band)
        checked += int(ok.sum())
    assert checked > 500


def test_slips_outages_gaps_and_flags():
    nav, base, t0, _ = _site("gsi")
    pos, vel = static_trajectory(_enu_offset(base, [30.0, 40.0, 1.0]))
    tags = epoch_grid(t0, 120.0, 5)
    probe, ptruth = simulate_receiver(nav, pos, vel, tags[:1], ReceiverOptions(), np.random.default_rng(0))
    s1, s2, s3 = ptruth.sat_ids[:3]
    slips = (CycleSlip(t0 + 20.0, s1, cycles=5), CycleSlip(t0 + 30.1, s2, cycles=-3, band=1),
             CycleSlip(t0 + 40.0, s3, cycles=1, flagged=False))
    o = ReceiverOptions(slips=slips, gaps=((t0 + 50.0, t0 + 60.0),), random_gap_rate_per_hour=60.0,
                        random_gap_duration_s=(2.0, 8.0))
    raw, truth = simulate_receiver(nav, pos, vel, tags, o, np.random.default_rng(4))
    # gaps: epochs not written, up to 10 s, the rest at 5 Hz
    assert not ((raw.gps_time_s >= t0 + 50.0) & (raw.gps_time_s < t0 + 60.0)).any()
    steps = np.diff(raw.gps_time_s)
    assert np.max(steps) >= 10.0 - 1e-6
    np.testing.assert_allclose(steps / 0.2, np.round(steps / 0.2), atol=1e-5)
    assert np.median(steps) == pytest.approx(0.2)
    assert len(truth.dropped_epochs_s) == len(tags) - raw.n_epochs
    # slips: the ambiguity jumps by the cycles asked for, LLI bit 0 where flagged only
    assert [(s.sat_id, s.band, s.cycles, s.flagged) for s in truth.slips] == \
        [(s1, 0, 5, True), (s1, 1, 5, True), (s2, 1, -3, True), (s3, 0, 1, False), (s3, 1, 1, False)]
    for s in truth.slips:
        i = raw.sat_ids.index(s.sat_id)
        k = raw.obs_codes.index("L1C" if s.band == 0 else "L2W")
        e = s.epoch
        assert truth.ambiguity_cyc[e, i, s.band] - truth.ambiguity_cyc[e - 1, i, s.band] == s.cycles
        assert raw.lli[e, i, k] == (1 if s.flagged else 0)
        assert raw.gps_time_s[e] >= s.receiver_time_s - 1e-9
    # the other band of s2 did not slip
    i2 = raw.sat_ids.index(s2)
    e2 = truth.slips[2].epoch
    assert truth.ambiguity_cyc[e2, i2, 0] == truth.ambiguity_cyc[e2 - 1, i2, 0]
    assert not (raw.lli & 2).any()
    # outages: no data inside, a new ambiguity and LLI on reacquisition
    o = ReceiverOptions(outage_rate_per_hour=60.0, outage_duration_s=(1.0, 3.0))
    raw, truth = simulate_receiver(nav, pos, vel, tags, o, np.random.default_rng(4))
    assert truth.outages
    n_checked = 0
    for sat, a, b_ in truth.outages:
        i = raw.sat_ids.index(sat)
        inside = (raw.gps_time_s >= a) & (raw.gps_time_s < b_)
        assert np.isnan(raw.values[inside, i]).all()
        after = np.searchsorted(raw.gps_time_s, b_)
        before = np.searchsorted(raw.gps_time_s, a) - 1
        if 0 <= before and after < raw.n_epochs and np.isfinite(raw.values[after, i, 1]) \
                and np.isfinite(raw.values[before, i, 1]):
            assert raw.lli[after, i, raw.obs_codes.index("L1C")] & 1
            assert truth.ambiguity_cyc[after, i, 0] != truth.ambiguity_cyc[before, i, 0]
            n_checked += 1
    assert n_checked > 0
    assert not (raw.lli & 2).any()
    # ambiguities are large integers
    amb = truth.ambiguity_cyc[np.isfinite(truth.ambiguity_cyc)]
    assert np.all(amb == np.round(amb)) and np.max(np.abs(amb)) > 1e5


def test_single_difference_truth_follows_base_gaps():
    nav, base, t0, _ = _site("gsi")
    pos, vel = static_trajectory(_enu_offset(base, [10.0, 0.0, 0.0]))
    sv = simulate_survey(nav, pos, vel, epoch_grid(t0, 30.0, 5), base, epoch_grid(t0, 30.0, 1), seed=3,
                         base_options=ReceiverOptions(gaps=((t0 + 10.5, t0 + 15.5),)))
    sd = single_difference_ambiguities(sv.rover_truth, sv.base_truth)
    assert np.isfinite(sd).any()
    # during the base gap the latest base epoch (t0 + 10) still gives the base ambiguity (no slip: same value)
    e = np.searchsorted(sv.rover_truth.receiver_time_s, t0 + 13.0)
    np.testing.assert_array_equal(np.isfinite(sd[e, :, 0]), np.isfinite(sd[e - 1, :, 0]))
    assert np.all(np.isnan(single_difference_ambiguities(sv.rover_truth, sv.base_truth, max_age_s=1.0)[e]))


def test_receiver_clock_modes():
    nav, base, t0, _ = _site("gsi")
    pos, vel = static_trajectory(base)
    tags = epoch_grid(t0, 300.0, 1)
    free = ReceiverOptions(clock=ClockOptions(mode="free", max_offset_s=5e-4, max_drift_s_s=2e-7))
    raw, truth = simulate_receiver(nav, pos, vel, tags, free, np.random.default_rng(7))
    np.testing.assert_allclose(raw.gps_time_s - truth.true_time_s, truth.clock_bias_s, atol=3e-7)
    assert 1e-6 < np.max(np.abs(truth.clock_bias_s)) < 5.7e-4
    steered = ReceiverOptions(clock=ClockOptions(mode="steered"))
    _, truth_s = simulate_receiver(nav, pos, vel, tags, steered, np.random.default_rng(7))
    assert np.max(np.abs(truth_s.clock_bias_s)) < 1e-6
    jumps = ReceiverOptions.ublox_l1(clock=ClockOptions(max_offset_s=4.9e-4, max_drift_s_s=1e-5,
                                                        millisecond_jumps=True))
    raw_j, truth_j = simulate_receiver(nav, pos, vel, tags, jumps, np.random.default_rng(1))
    assert np.max(np.abs(truth_j.clock_bias_s)) <= 5.0e-4 + 1e-12
    steps = np.diff(truth_j.clock_bias_s)
    big = np.abs(steps) > 5e-4
    assert big.any()
    np.testing.assert_allclose(np.abs(steps[big]), 1e-3, atol=2e-5)
    # code and phase jump with the clock by c * 1 ms (300 km), on every satellite
    e = int(np.nonzero(big)[0][0])
    assert 1 <= e < len(steps) - 1
    for code, scale in (("C1C", 1.0), ("L1C", None)):
        k = raw_j.obs_codes.index(code)
        x = raw_j.values[:, :, k] * (truth_j.wavelength_m[None, :, 0] if scale is None else 1.0)
        step2 = (x[e + 1] - x[e]) - (x[e] - x[e - 1])          # second difference: the jump alone (+- ~1 m)
        ok = np.isfinite(step2)
        assert ok.sum() >= 4
        np.testing.assert_allclose(np.abs(step2[ok]), CLIGHT_M_S * 1e-3, atol=5.0)
    with pytest.raises(ValueError, match="clock mode"):
        simulate_receiver(nav, pos, vel, tags[:2], ReceiverOptions(clock=ClockOptions(mode="atomic")))


def test_signal_profiles_and_header():
    nav, base, t0, _ = _site("multi")
    pos, vel = static_trajectory(base)
    tags = epoch_grid(t0, 5.0, 1)
    raw, truth = simulate_receiver(nav, pos, vel, tags, ReceiverOptions.geodetic(), np.random.default_rng(0))
    assert {s[0] for s in raw.sat_ids} == set("GREJC")
    for code in ("C1C", "L1C", "D1C", "S1C", "C2W", "L2W", "C2P", "L2P", "C7Q", "L7Q", "C2L", "L2L", "C2I", "L2I",
                 "C7I", "L7I"):
        assert code in raw.obs_codes
    k7 = raw.obs_codes.index("L7I")
    for i, sat in enumerate(raw.sat_ids):
        if sat[0] == "C":
            # B2I only from BDS-2 (C01-C18)
            assert np.isfinite(raw.values[:, i, k7]).any() == (int(sat[1:]) <= 18)
    fcn = nav.glonass_fcn()
    assert raw.header.glonass_fcn == {s: fcn[s] for s in raw.sat_ids if s[0] == "R"}
    # every signal tracked is one select_bands maps onto a band
    obs = select_bands(raw)
    assert np.isfinite(obs.phase_cyc[..., 0]).sum() == np.isfinite(truth.ambiguity_cyc[..., 0]).sum()
    assert np.isfinite(obs.phase_cyc[..., 1]).sum() == np.isfinite(truth.ambiguity_cyc[..., 1]).sum()
    ub, ub_truth = simulate_receiver(nav, pos, vel, tags, ReceiverOptions.ublox_l1(), np.random.default_rng(0))
    assert ub.obs_codes == ["C1C", "L1C", "D1C", "S1C"]
    assert {s[0] for s in ub.sat_ids} == {"G", "R"}
    snr = ub.values[..., 3]
    assert np.all(snr[np.isfinite(snr)] == np.round(snr[np.isfinite(snr)]))      # integer dB-Hz
    # elevation mask of tracking
    assert np.nanmin(ub_truth.elevation_rad) >= np.radians(5.0)


def test_deterministic_for_a_seed():
    nav, base, t0, _ = _site("gsi")
    pos, vel = static_trajectory(_enu_offset(base, [5.0, 5.0, 0.0]))
    args = (nav, pos, vel, epoch_grid(t0, 10.0, 1), base, epoch_grid(t0, 10.0, 1))
    a = simulate_survey(*args, seed=9)
    b = simulate_survey(*args, seed=9)
    c = simulate_survey(*args, seed=10)
    np.testing.assert_array_equal(a.rover.values, b.rover.values)
    np.testing.assert_array_equal(a.base.values, b.base.values)
    assert not np.allclose(np.nan_to_num(a.rover.values), np.nan_to_num(c.rover.values))
