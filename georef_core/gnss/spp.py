"""Single point positioning (code, L1) and Doppler velocity for every epoch of a receiver, vectorised
over epochs: weighted Gauss-Newton with one receiver clock per system, elevation-dependent weights,
broadcast ionosphere and a troposphere model, and iterative rejection of outlying pseudoranges."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .constants import CLIGHT_M_S, OMEGA_EARTH_RAD_S, wavelength_table_m
from .corrections import ionosphere_delay_m, troposphere_delay_m
from .ephemeris import group_delay_s, select_ephemeris
from .frames import azimuth_elevation_batch
from .navigation import NavigationData
from .observations import ObservationSet
from .rtk_options import RtkOptions
from .satellite_geometry import ObservedSatellites, geometric_range_m

CLOCK_COLUMN = {"G": 0, "J": 0, "R": 1, "E": 2, "C": 3}
N_CLOCKS = 4
SPP_SYSTEM_FACTOR = {"R": 1.5}


@dataclass
class SppResult:
    position_ecef_m: np.ndarray       # (E, 3) NaN where no solution
    covariance_ecef_m2: np.ndarray    # (E, 3, 3)
    clock_bias_m: np.ndarray          # (E, N_CLOCKS) receiver clock per system (G/J, R, E, C) times c
    velocity_ecef_m_s: np.ndarray     # (E, 3) from Doppler; NaN where none
    velocity_covariance_m2_s2: np.ndarray
    clock_drift_m_s: np.ndarray       # (E,)
    valid: np.ndarray                 # (E,) bool
    n_used: np.ndarray                # (E,)
    used: np.ndarray                  # (E, S) bool: satellites kept
    azimuth_rad: np.ndarray           # (E, S)
    elevation_rad: np.ndarray         # (E, S)
    gdop: np.ndarray                  # (E,)


def code_group_delays_m(obs: ObservationSet, nav: NavigationData, band: int = 0) -> np.ndarray:
    """(S,) broadcast group delay correction (m) per satellite for code on `band`, from the ephemeris
    valid at the middle of the observation span (it changes rarely)."""
    t_mid = float(np.median(obs.gps_time_s)) if len(obs.gps_time_s) else 0.0
    out = np.zeros(len(obs.sat_ids))
    for i, sat in enumerate(obs.sat_ids):
        if sat[0] == "R":
            continue
        eph = select_ephemeris(nav, sat, t_mid)
        if eph is not None:
            out[i] = CLIGHT_M_S * group_delay_s(eph, band)
    return out


def solve_spp(obs: ObservationSet, sats: ObservedSatellites, nav: NavigationData, opts: RtkOptions,
              initial_ecef_m: np.ndarray | None = None, max_rejections: int = 3) -> SppResult:
    n_e, n_s = len(obs.gps_time_s), len(obs.sat_ids)
    lam = wavelength_table_m(obs.sat_ids, {**obs.header.glonass_fcn, **nav.glonass_fcn()})
    tgd_m = code_group_delays_m(obs, nav)
    code = obs.code_m[..., 0] - tgd_m[None, :]
    sys_ok = np.array([s[0] in opts.systems and s not in opts.excluded_sats for s in obs.sat_ids])
    usable = sats.valid & ~np.isnan(code) & sys_ok[None, :] & ~np.isnan(lam[None, :, 0])
    if opts.snr_mask_dbhz > 0:
        usable &= ~(obs.snr_dbhz[..., 0] < opts.snr_mask_dbhz)
    sys_col = np.array([CLOCK_COLUMN.get(s[0], 0) for s in obs.sat_ids])
    sys_fact = np.array([SPP_SYSTEM_FACTOR.get(s[0], 1.0) for s in obs.sat_ids])
    onehot = np.zeros((n_s, N_CLOCKS))
    onehot[np.arange(n_s), sys_col] = 1.0

    x = np.zeros((n_e, 3 + N_CLOCKS))
    if initial_ecef_m is not None and np.all(np.isfinite(initial_ecef_m)) and np.linalg.norm(initial_ecef_m) > 1e6:
        x[:, :3] = initial_ecef_m
    sat_pos = np.where(usable[..., None], sats.position_ecef_m, 0.0)
    f_a, f_b = opts.code_phase_ratio[0] * opts.phase_error_a_m, opts.code_phase_ratio[0] * opts.phase_error_b_m
    used = usable.copy()
    t_col = obs.gps_time_s[:, None]
    cov = np.full((n_e, 3 + N_CLOCKS, 3 + N_CLOCKS), np.nan)
    converged_once = np.zeros(n_e, dtype=bool)
    az = el = np.zeros((n_e, n_s))
    var = np.ones((n_e, n_s))
    v = np.zeros((n_e, n_s))
    for rejection_round in range(max_rejections + 1):
        for it in range(10):
            rng, los = geometric_range_m(sat_pos, x[:, None, :3])
            located = np.linalg.norm(x[:, :3], axis=1) > 1e6
            az, el, llh = azimuth_elevation_batch(np.where(located[:, None], x[:, :3], [6378137.0, 0, 0]), los)
            mask = used & (located[:, None] & (el >= np.radians(opts.elevation_mask_deg)) | ~located[:, None])
            trop, trop_var = troposphere_delay_m(opts.troposphere, llh[:, 0:1], llh[:, 2:3], el)
            iono, iono_var = ionosphere_delay_m(opts.ionosphere, nav, t_col, llh[:, 0:1], llh[:, 1:2], az, el, lam[None, :, 0])
            trop = np.where(located[:, None], trop, 0.0)
            iono = np.where(located[:, None], iono, 0.0)
            clk = x[:, 3:] @ onehot.T  # (E, S)
            pred = rng + clk - CLIGHT_M_S * np.nan_to_num(sats.clock_bias_s) + trop + iono
            v = np.where(mask, code - pred, 0.0)
            sinel = np.where(located[:, None], np.maximum(np.sin(el), 0.05), 1.0)
            var = (sys_fact**2)[None, :] * (f_a**2 + (f_b / sinel) ** 2) + np.nan_to_num(sats.variance_m2) \
                + np.where(located[:, None], trop_var + iono_var, 100.0)
            w = np.where(mask, 1.0 / var, 0.0)
            h = np.concatenate([-los, np.broadcast_to(onehot, (n_e, n_s, N_CLOCKS))], axis=2)
            h = np.where(mask[..., None], h, 0.0)
            hw = h * w[..., None]
            normal = np.einsum("esi,esj->eij", hw, h)
            rhs = np.einsum("esi,es->ei", hw, v)
            # clocks of systems without observations: pseudo-observation clock = 0
            empty = np.einsum("ij,ej->ei", onehot.T, mask.astype(float)) == 0
            for c in range(N_CLOCKS):
                normal[empty[:, c], 3 + c, 3 + c] += 1.0
            n_obs = mask.sum(axis=1)
            n_unk = 3 + (~empty).sum(axis=1)
            solvable = n_obs >= n_unk
            dx = np.zeros_like(x)
            if solvable.any():
                try:
                    dx[solvable] = np.linalg.solve(normal[solvable], rhs[solvable][..., None])[..., 0]
                except np.linalg.LinAlgError:
                    for e in np.nonzero(solvable)[0]:
                        dx[e] = np.linalg.lstsq(normal[e], rhs[e], rcond=None)[0]
            x += dx
            if np.all(np.linalg.norm(dx[:, :3], axis=1)[solvable] < 1e-4) and it >= 2:
                break
        used = mask
        with np.errstate(invalid="ignore"):
            cov[solvable] = np.linalg.inv(normal[solvable])
        converged_once |= solvable
        # outlier rejection: drop the worst normalised residual where the residuals fail a 5-sigma test
        norm_res = np.where(mask, np.abs(v) / np.sqrt(var), 0.0)
        worst = np.argmax(norm_res, axis=1)
        bad = (norm_res[np.arange(n_e), worst] > 5.0) & (n_obs > n_unk + 1)
        if rejection_round == max_rejections or not bad.any():
            break
        used[np.nonzero(bad)[0], worst[bad]] = False

    n_used = used.sum(axis=1)
    pos = x[:, :3].copy()
    gdop = np.sqrt(np.abs(np.trace(cov, axis1=1, axis2=2)))
    valid = converged_once & (n_used >= 4) & (np.linalg.norm(pos, axis=1) > 6.0e6) & (np.linalg.norm(pos, axis=1) < 6.6e6)
    pos[~valid] = np.nan
    vel, vel_cov, drift, vel_ok = _doppler_velocity(obs, sats, pos, used, lam, el)
    return SppResult(pos, cov[:, :3, :3], x[:, 3:], vel, vel_cov, drift, valid, n_used, used, az, el, gdop)


def _doppler_velocity(obs: ObservationSet, sats: ObservedSatellites, pos: np.ndarray, used: np.ndarray,
                      lam: np.ndarray, el: np.ndarray):
    """Receiver velocity and clock drift from band-0 Doppler, by weighted least squares (two passes,
    the second without residuals beyond 4 sigma)."""
    n_e = len(pos)
    dop = obs.doppler_hz[..., 0]
    ok = used & ~np.isnan(dop) & np.isfinite(pos[:, :1]) & sats.valid
    rate_obs = -lam[None, :, 0] * dop
    sp = np.nan_to_num(sats.position_ecef_m)
    sv = np.nan_to_num(sats.velocity_ecef_m_s)
    rcv = np.nan_to_num(pos)
    d = sp - rcv[:, None, :]
    r = np.linalg.norm(d, axis=-1)
    r[r == 0] = 1.0
    los = d / r[..., None]
    sigma = 0.05 + 0.1 / np.maximum(np.sin(el), 0.1)   # m/s
    vel = np.full((n_e, 3), np.nan)
    vcov = np.full((n_e, 3, 3), np.nan)
    drift = np.full(n_e, np.nan)
    x = np.zeros((n_e, 4))
    for _ in range(3):
        # model: rate = los.(vs - vr) + c*ddtr - c*ddts + Sagnac rate
        sag = OMEGA_EARTH_RAD_S / CLIGHT_M_S * (sv[..., 1] * rcv[:, None, 0] + sp[..., 1] * x[:, None, 0]
                                                 - sv[..., 0] * rcv[:, None, 1] - sp[..., 0] * x[:, None, 1])
        pred = np.einsum("esk,esk->es", los, sv - x[:, None, :3]) + x[:, 3:4] \
            - CLIGHT_M_S * np.nan_to_num(sats.clock_drift_s_s) + sag
        v = np.where(ok, np.nan_to_num(rate_obs) - pred, 0.0)
        h = np.concatenate([-los, np.ones(los.shape[:2] + (1,))], axis=2)
        w = np.where(ok, 1.0 / sigma**2, 0.0)
        hw = h * w[..., None]
        normal = np.einsum("esi,esj->eij", hw, h)
        rhs = np.einsum("esi,es->ei", hw, v)
        solvable = ok.sum(axis=1) >= 5
        if not solvable.any():
            break
        dx = np.zeros_like(x)
        dx[solvable] = np.linalg.solve(normal[solvable] + 1e-9 * np.eye(4), rhs[solvable][..., None])[..., 0]
        x += dx
        v_after = v - np.einsum("esi,ei->es", h, dx)
        ok &= ~(np.abs(v_after) > 4 * sigma)
    solvable = ok.sum(axis=1) >= 5
    if solvable.any():
        vel[solvable] = x[solvable, :3]
        drift[solvable] = x[solvable, 3]
        vcov[solvable] = np.linalg.inv(normal[solvable] + 1e-9 * np.eye(4))[:, :3, :3]
    return vel, vcov, drift, solvable
