"""bench/gnss_tdcp_chain.tdcp_steps on a synthetic rover: the chain keeps to the filter's elevation mask, so a
horizon signal whose time-differenced phase has a steady rate the model lacks (the walk's satellites at 0-5
degrees: 6-25 mm/s) cannot bias every step; one clock change for all systems bridges a step with too few
signals for one per system."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "bench"))

from gnss_tdcp_chain import tdcp_steps  # noqa: E402

from georef_core.gnss.constants import CLIGHT_M_S, OMEGA_EARTH_RAD_S  # noqa: E402
from georef_core.gnss.frames import ecef_to_enu_rotation, geodetic_to_ecef_m  # noqa: E402
from georef_core.gnss.rtk_kernels import FilterArrays  # noqa: E402

N_EPOCHS = 120
HORIZON_RATE_M_S = 0.02


def _walk(rng, horizon: bool = True):
    lat, lon = np.radians(35.0), np.radians(137.0)
    origin = geodetic_to_ecef_m(lat, lon, 50.0)
    r_enu = ecef_to_enu_rotation(lat, lon)
    step_enu = np.array([0.8, 0.5, 0.0])                       # m per 1 s epoch
    rover = origin + (np.arange(N_EPOCHS)[:, None] * step_enu) @ r_enu
    # (azimuth deg, elevation deg, system 0 GPS / 1 GLONASS); the last one near the horizon
    sky = [(10, 70, 0), (100, 40, 0), (200, 55, 0), (300, 25, 0), (45, 30, 1), (150, 65, 1), (260, 35, 1),
           (330, 50, 1), (80, 2, 0)]
    if not horizon:
        sky = sky[:-1]
    n_s = len(sky)
    sat = np.empty((N_EPOCHS, n_s, 3))
    el = np.empty((N_EPOCHS, n_s))
    for s, (az_deg, el_deg, _) in enumerate(sky):
        az, e0 = np.radians(az_deg), np.radians(el_deg)
        e_t = e0 + 1e-4 * np.arange(N_EPOCHS)                 # satellites rise slowly
        u = np.stack([np.cos(e_t) * np.sin(az), np.cos(e_t) * np.cos(az), np.sin(e_t)], axis=1)
        sat[:, s] = origin + 2.2e7 * (u @ r_enu)
        el[:, s] = e_t
    rng_m = np.linalg.norm(sat - rover[:, None], axis=2)
    rng_m += OMEGA_EARTH_RAD_S * (sat[..., 0] * rover[:, 1:2] - sat[..., 1] * rover[:, 0:1]) / CLIGHT_M_S
    sys_code = np.array([c for *_, c in sky])
    # the receiver clock (m) with a constant inter-system bias for GLONASS
    clock = np.cumsum(rng.normal(0, 3.0, N_EPOCHS))[:, None] + np.array([0.0, 30.0])
    phase = rng_m + clock[:, sys_code] + rng.normal(0, 0.002, (N_EPOCHS, n_s))
    if horizon:
        phase[:, -1] += HORIZON_RATE_M_S * np.arange(N_EPOCHS)
    unused = {f: np.zeros(1) for f in FilterArrays._fields}
    arrays = FilterArrays(**{**unused, **dict(
        el=el, rover_phase_m=phase[..., None], base_phase_res_m=np.zeros((N_EPOCHS, n_s, 1)),
        rover_code_m=rng_m[..., None], sat_pos=sat, slip_cum=np.zeros((N_EPOCHS + 1, n_s, 1), np.int32),
        sys_code=sys_code, trop_ref=rover.copy(), up=np.tile(r_enu[2], (N_EPOCHS, 1)),
        sat_clock_m=np.zeros((N_EPOCHS, n_s)), trop_m=np.zeros((N_EPOCHS, n_s)), trop_dh=np.zeros((N_EPOCHS, n_s)))})
    rough = rover + rng.normal(0, 1.0, rover.shape)            # a float position, metres off
    return arrays, rover, rough


def _chain_error_m(dx, rover):
    return float(np.linalg.norm(np.nansum(dx, axis=0) - (rover[-1] - rover[0])))


def test_elevation_mask_removes_the_horizon_signals_drift():
    arrays, rover, rough = _walk(np.random.default_rng(5))
    dx_all, _, n_all = tdcp_steps(arrays, rough, min_elevation_deg=-90.0)
    dx_mask, _, n_mask = tdcp_steps(arrays, rough, min_elevation_deg=15.0)
    assert np.isfinite(dx_all).all() and np.isfinite(dx_mask).all()
    assert (n_all == 9).all() and (n_mask == 8).all()          # the 2 cm/s signal is never dropped as an outlier
    err_all, err_mask = _chain_error_m(dx_all, rover), _chain_error_m(dx_mask, rover)
    assert err_all > 0.3                                       # mm per step, chained over 119 steps
    assert err_mask < 0.03


def test_one_clock_bridges_a_step_with_too_few_signals():
    arrays, rover, rough = _walk(np.random.default_rng(6), horizon=False)
    # step 60 -> 61: only three GPS and three GLONASS signals unbroken (too few for a clock per system)
    arrays.slip_cum[62:, [2, 7], 0] = 1
    dx2, _, _ = tdcp_steps(arrays, rough)
    dx1, _, n1 = tdcp_steps(arrays, rough, one_clock=True)
    assert not np.isfinite(dx2[60]).any()
    assert np.isfinite(dx1[60]).all() and n1[60] == 6
    assert np.linalg.norm(dx1[60] - (rover[61] - rover[60])) < 0.02
