"""Satellite positions and clocks at signal transmission for every observation of a receiver,
computed in one vectorised pass, plus the geometric range with the Earth-rotation (Sagnac) term."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .constants import CLIGHT_M_S, OMEGA_EARTH_RAD_S
from .ephemeris import satellite_states_indexed
from .navigation import NavigationData
from .observations import ObservationSet


@dataclass
class ObservedSatellites:
    """Satellite states for each (epoch, satellite) of an ObservationSet; invalid entries are NaN."""

    position_ecef_m: np.ndarray      # (E, S, 3) at transmission, in the ECEF frame of transmission time
    velocity_ecef_m_s: np.ndarray    # (E, S, 3)
    clock_bias_s: np.ndarray         # (E, S)   includes the relativistic term
    clock_drift_s_s: np.ndarray      # (E, S)
    variance_m2: np.ndarray          # (E, S)   ephemeris/clock error variance
    valid: np.ndarray                # (E, S)   bool


def _first_available_code_m(obs: ObservationSet) -> np.ndarray:
    code = obs.code_m[..., 0].copy()
    for b in range(1, obs.code_m.shape[2]):
        missing = np.isnan(code)
        code[missing] = obs.code_m[..., b][missing]
    return code


def compute_observed_satellites(obs: ObservationSet, nav: NavigationData) -> ObservedSatellites:
    """Transmission time t_tx = t_rx - P/c - dts (the receiver clock cancels in t_rx - P/c);
    the position is moved from the first guess by velocity * dts (|dts| < 1 ms)."""
    n_e, n_s = len(obs.gps_time_s), len(obs.sat_ids)
    code = _first_available_code_m(obs)
    e_idx, s_idx = np.nonzero(~np.isnan(code))
    pos = np.full((n_e, n_s, 3), np.nan)
    vel = np.full((n_e, n_s, 3), np.nan)
    clk = np.full((n_e, n_s), np.nan)
    drift = np.full((n_e, n_s), np.nan)
    var = np.full((n_e, n_s), np.nan)
    valid = np.zeros((n_e, n_s), dtype=bool)
    if len(e_idx):
        t_tx = obs.gps_time_s[e_idx] - code[e_idx, s_idx] / CLIGHT_M_S
        st = satellite_states_indexed(nav, obs.sat_ids, s_idx, t_tx)
        ok = np.asarray(st.valid, dtype=bool)
        dts = np.asarray(st.clock_bias_s)
        p = np.asarray(st.position_ecef_m) - np.asarray(st.velocity_ecef_m_s) * dts[:, None]
        pos[e_idx[ok], s_idx[ok]] = p[ok]
        vel[e_idx[ok], s_idx[ok]] = np.asarray(st.velocity_ecef_m_s)[ok]
        clk[e_idx[ok], s_idx[ok]] = dts[ok]
        drift[e_idx[ok], s_idx[ok]] = np.asarray(st.clock_drift_s_s)[ok]
        var[e_idx[ok], s_idx[ok]] = np.asarray(st.variance_m2)[ok]
        valid[e_idx[ok], s_idx[ok]] = True
    return ObservedSatellites(pos, vel, clk, drift, var, valid)


def geometric_range_m(sat_ecef_m: np.ndarray, rcv_ecef_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Range with the Sagnac correction and unit line-of-sight vectors receiver->satellite.
    Broadcasts: sat (..., 3), receiver (..., 3)."""
    d = sat_ecef_m - rcv_ecef_m
    r = np.linalg.norm(d, axis=-1)
    los = d / r[..., None]
    sagnac = OMEGA_EARTH_RAD_S * (sat_ecef_m[..., 0] * rcv_ecef_m[..., 1] - sat_ecef_m[..., 1] * rcv_ecef_m[..., 0]) / CLIGHT_M_S
    return r + sagnac, los
