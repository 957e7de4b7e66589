"""Compiled (numba) single point positioning, one epoch at a time (spp.py prepares the arrays and documents
the model): weighted Gauss-Newton on L1 code with one receiver clock per system, elevation-dependent
weights, broadcast ionosphere and troposphere, iterative rejection of the worst pseudorange beyond 5 sigma,
then the receiver velocity and clock drift from Doppler."""

from __future__ import annotations

import numpy as np
from .kernel_loader import njit

from .atmosphere_kernels import (
    IONO_OFF_VARIANCE_M2,
    azimuth_elevation,
    enu_basis,
    geodetic,
    ionosphere_scale,
    klobuchar_l1_m,
    troposphere_slant,
    troposphere_zenith,
)
from .constants import CLIGHT_M_S, OMEGA_EARTH_RAD_S, WGS84_A_M

N_CLOCKS = 4
MAX_ITERATIONS = 10
CONVERGED_M = 1e-4
REJECT_SIGMA = 5.0
SPP_HUMIDITY = 0.7
DOPPLER_ITERATIONS = 3
DOPPLER_REJECT_SIGMA = 4.0


@njit(cache=True)
def spp_epoch(t, code, used, sat_pos, sat_clock_m, sat_var, sys_col, sys_fact2, lam0, x, elmask_rad, f_a, f_b,
              tropo_model, iono_on, alpha, beta, max_rejections, az, el):
    """One epoch. x (3 + N_CLOCKS,) is the starting point and is updated in place; `used` (S,) in place: the
    satellites kept. az, el (S,) are filled. Returns (covariance (7, 7) or NaN, solved at least once)."""
    n_s = code.shape[0]
    nx = 3 + N_CLOCKS
    cov = np.full((nx, nx), np.nan)
    converged_once = False
    mask = np.zeros(n_s, np.bool_)
    v = np.zeros(n_s)
    var = np.ones(n_s)
    los = np.zeros(3)
    h = np.zeros(nx)
    normal = np.zeros((nx, nx))
    rhs = np.zeros(nx)
    clock_seen = np.zeros(N_CLOCKS, np.bool_)
    for rejection_round in range(max_rejections + 1):
        solvable = False
        n_obs = 0
        n_unk = 3
        for it in range(MAX_ITERATIONS):
            located = np.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]) > 1e6
            if located:
                lat, lon, hgt = geodetic(x[0], x[1], x[2])
            else:
                lat, lon, hgt = geodetic(WGS84_A_M, 0.0, 0.0)
            basis = enu_basis(lat, lon)
            zenith = troposphere_zenith(tropo_model, lat, hgt, SPP_HUMIDITY)
            normal[:] = 0.0
            rhs[:] = 0.0
            clock_seen[:] = False
            n_obs = 0
            for s in range(n_s):
                if not used[s]:
                    # an unusable satellite's position is zeroed: from a receiver not yet located (also at
                    # the Earth's centre) its range would be 0
                    mask[s] = False
                    v[s] = 0.0
                    continue
                dx_, dy_, dz_ = sat_pos[s, 0] - x[0], sat_pos[s, 1] - x[1], sat_pos[s, 2] - x[2]
                r = np.sqrt(dx_ * dx_ + dy_ * dy_ + dz_ * dz_)
                los[0], los[1], los[2] = dx_ / r, dy_ / r, dz_ / r
                az[s], el[s] = azimuth_elevation(basis, los)
                mask[s] = used[s] and ((located and el[s] >= elmask_rad) or not located)
                if not mask[s]:
                    v[s] = 0.0
                    continue
                rng = r + OMEGA_EARTH_RAD_S * (sat_pos[s, 0] * x[1] - sat_pos[s, 1] * x[0]) / CLIGHT_M_S
                if located:
                    trop, trop_var = troposphere_slant(tropo_model, zenith, hgt, el[s])
                    if iono_on:
                        iono = klobuchar_l1_m(t, lat, lon, az[s], el[s], alpha, beta) * ionosphere_scale(lam0[s])
                        iono_var = (0.5 * iono) ** 2
                    else:
                        iono, iono_var = 0.0, IONO_OFF_VARIANCE_M2
                    sinel = max(np.sin(el[s]), 0.05)
                    extra_var = trop_var + iono_var
                else:
                    trop = iono = 0.0
                    sinel = 1.0
                    extra_var = 100.0
                c = sys_col[s]
                pred = rng + x[3 + c] - sat_clock_m[s] + trop + iono
                v[s] = code[s] - pred
                var[s] = sys_fact2[s] * (f_a**2 + (f_b / sinel) ** 2) + sat_var[s] + extra_var
                w = 1.0 / var[s]
                h[:] = 0.0
                h[0], h[1], h[2] = -los[0], -los[1], -los[2]
                h[3 + c] = 1.0
                for i in range(nx):
                    hw = h[i] * w
                    rhs[i] += hw * v[s]
                    for j in range(nx):
                        normal[i, j] += hw * h[j]
                clock_seen[c] = True
                n_obs += 1
            # clocks of systems without observations: pseudo-observation clock = 0
            n_unk = 3
            for c in range(N_CLOCKS):
                if clock_seen[c]:
                    n_unk += 1
                else:
                    normal[3 + c, 3 + c] += 1.0
            solvable = n_obs >= n_unk
            step = 0.0
            if solvable:
                try:
                    dx = np.linalg.solve(normal, rhs)
                except Exception:  # noqa: BLE001 - singular normal matrix
                    dx = np.linalg.lstsq(normal, rhs)[0]
                for i in range(nx):
                    x[i] += dx[i]
                step = np.sqrt(dx[0] * dx[0] + dx[1] * dx[1] + dx[2] * dx[2])
            if step < CONVERGED_M and it >= 2:
                break
        used[:] = mask
        if solvable:
            try:
                cov = np.linalg.inv(normal)
            except Exception:  # noqa: BLE001
                cov = np.full((nx, nx), np.nan)
            converged_once = True
        # outlier rejection: drop the worst normalised residual where the residuals fail a 5-sigma test
        worst = 0
        worst_z = 0.0
        for s in range(n_s):
            z = np.abs(v[s]) / np.sqrt(var[s]) if mask[s] else 0.0
            if z > worst_z:
                worst, worst_z = s, z
        bad = worst_z > REJECT_SIGMA and n_obs > n_unk + 1
        if rejection_round == max_rejections or not bad:
            break
        used[worst] = False
    return cov, converged_once


@njit(cache=True)
def spp_all(time_s, code, usable, sat_pos, sat_clock_m, sat_var, sys_col, sys_fact2, lam0, x0, elmask_rad, f_a,
            f_b, tropo_model, iono_on, alpha, beta, max_rejections):
    """spp_epoch for every epoch; x0 (7,) the common starting point. Returns (x (E, 7), covariance (E, 7, 7),
    solved at least once (E,), used (E, S), azimuth (E, S), elevation (E, S))."""
    n_e, n_s = code.shape
    nx = 3 + N_CLOCKS
    x = np.zeros((n_e, nx))
    cov = np.full((n_e, nx, nx), np.nan)
    converged = np.zeros(n_e, np.bool_)
    used = usable.copy()
    az = np.zeros((n_e, n_s))
    el = np.zeros((n_e, n_s))
    for e in range(n_e):
        x[e] = x0
        cov[e], converged[e] = spp_epoch(time_s[e], code[e], used[e], sat_pos[e], sat_clock_m[e], sat_var[e], sys_col,
                                         sys_fact2, lam0, x[e], elmask_rad, f_a, f_b, tropo_model, iono_on, alpha,
                                         beta, max_rejections, az[e], el[e])
    return x, cov, converged, used, az, el


@njit(cache=True)
def doppler_velocity(rate_obs, ok_in, sat_pos, sat_vel, sat_drift_m_s, pos, sigma):
    """Receiver velocity and clock drift (m/s) of every epoch from range rates rate_obs (E, S) = -lambda *
    Doppler, by weighted least squares (three passes, each dropping residuals beyond 4 sigma).
    Returns (velocity (E, 3), covariance (E, 3, 3), clock drift (E,)), NaN where fewer than 5 satellites."""
    n_e, n_s = rate_obs.shape
    vel = np.full((n_e, 3), np.nan)
    vcov = np.full((n_e, 3, 3), np.nan)
    drift = np.full(n_e, np.nan)
    los = np.zeros((n_s, 3))
    h = np.zeros(4)
    for e in range(n_e):
        ok = ok_in[e].copy()
        rcv = pos[e]
        for s in range(n_s):
            d0, d1, d2 = sat_pos[e, s, 0] - rcv[0], sat_pos[e, s, 1] - rcv[1], sat_pos[e, s, 2] - rcv[2]
            r = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if r == 0:
                r = 1.0
            los[s, 0], los[s, 1], los[s, 2] = d0 / r, d1 / r, d2 / r
        x = np.zeros(4)
        normal = np.zeros((4, 4))
        for _ in range(DOPPLER_ITERATIONS):
            normal = np.zeros((4, 4))
            rhs = np.zeros(4)
            n_ok = 0
            v = np.zeros(n_s)
            for s in range(n_s):
                if not ok[s]:
                    continue
                sp, sv = sat_pos[e, s], sat_vel[e, s]
                sag = OMEGA_EARTH_RAD_S / CLIGHT_M_S * (sv[1] * rcv[0] + sp[1] * x[0] - sv[0] * rcv[1] - sp[0] * x[1])
                pred = (los[s, 0] * (sv[0] - x[0]) + los[s, 1] * (sv[1] - x[1]) + los[s, 2] * (sv[2] - x[2])) + x[3] \
                    - sat_drift_m_s[e, s] + sag
                v[s] = rate_obs[e, s] - pred
                w = 1.0 / sigma[e, s] ** 2
                h[0], h[1], h[2], h[3] = -los[s, 0], -los[s, 1], -los[s, 2], 1.0
                for i in range(4):
                    rhs[i] += h[i] * w * v[s]
                    for j in range(4):
                        normal[i, j] += h[i] * w * h[j]
                n_ok += 1
            if n_ok < 5:
                break
            dx = np.linalg.solve(normal + 1e-9 * np.eye(4), rhs)
            x += dx
            for s in range(n_s):
                if ok[s]:
                    after = v[s] - (-los[s, 0] * dx[0] - los[s, 1] * dx[1] - los[s, 2] * dx[2] + dx[3])
                    if np.abs(after) > DOPPLER_REJECT_SIGMA * sigma[e, s]:
                        ok[s] = False
        if ok.sum() >= 5:
            vel[e] = x[:3]
            drift[e] = x[3]
            vcov[e] = np.linalg.inv(normal + 1e-9 * np.eye(4))[:3, :3]
    return vel, vcov, drift
