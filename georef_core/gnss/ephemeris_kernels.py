"""Compiled (numba) kernels of ephemeris.py: broadcast record selection for many times at once, Kepler
orbits and clocks for many records and times at once, and GLONASS orbit integration (RK4 on the 60 s grid
from toe, then one shorter step, RTKLIB's step pattern)."""

from __future__ import annotations

import numpy as np
from .kernel_loader import njit

from .constants import GLO_A_M, GLO_J2, GM_GLO_M3_S2, OMEGA_EARTH_GLO_RAD_S

GLONASS_STEP_S = 60.0
GLONASS_MIN_STEP_S = 1e-9


@njit(cache=True)
def select_records(toes, inav, galileo, t, max_age_s):
    """Index of the record to use at each time t (-1: none), records sorted by toe. RTKLIB demo5 rule: the
    record whose toe is nearest to t within max_age_s (ties: the later record); Galileo (galileo=True):
    I/NAV records (inav) are preferred whenever one is within the limit, and a record with toe >= t only
    when no earlier one is."""
    n_r = toes.shape[0]
    out = np.full(t.shape[0], -1, np.int64)
    for k in range(t.shape[0]):
        tk = t[k]
        if not np.isfinite(tk):
            continue
        any_inav = False
        any_past_inav = False
        any_past = False
        any_cand = False
        for i in range(n_r):
            if abs(toes[i] - tk) <= max_age_s:
                any_cand = True
                past = toes[i] < tk
                any_past |= past
                if inav[i]:
                    any_inav = True
                    any_past_inav |= past
        if not any_cand:
            continue
        need_inav = galileo and any_inav
        need_past = galileo and (any_past_inav if need_inav else any_past)
        best = -1
        best_dt = np.inf
        for i in range(n_r):
            d = abs(toes[i] - tk)
            if d > max_age_s or (need_inav and not inav[i]) or (need_past and not toes[i] < tk):
                continue
            if d <= best_dt:
                best = i
                best_dt = d
        out[k] = best
    return out


@njit(cache=True)
def _derivative(x, acc):
    """PZ-90 equations of motion in the rotating frame: central force, J2, Coriolis/centrifugal and the
    broadcast luni-solar acceleration (GLONASS ICD 5.1, A.3.1.2)."""
    px, py, pz, vx, vy, vz = x[0], x[1], x[2], x[3], x[4], x[5]
    out = np.zeros(6)
    r2 = px * px + py * py + pz * pz
    if r2 <= 0.0:
        return out
    r3 = r2 * np.sqrt(r2)
    w = OMEGA_EARTH_GLO_RAD_S
    a = 1.5 * GLO_J2 * GM_GLO_M3_S2 * GLO_A_M * GLO_A_M / r2 / r3
    b = 5.0 * pz * pz / r2
    c = -GM_GLO_M3_S2 / r3 - a * (1.0 - b)
    out[0], out[1], out[2] = vx, vy, vz
    out[3] = (c + w * w) * px + 2.0 * w * vy + acc[0]
    out[4] = (c + w * w) * py - 2.0 * w * vx + acc[1]
    out[5] = (c - 2.0 * a) * pz + acc[2]
    return out


@njit(cache=True)
def rk4_step(x, h, acc):
    """One classical Runge-Kutta step of length h (s) of the state (x, y, z, vx, vy, vz)."""
    k1 = _derivative(x, acc)
    k2 = _derivative(x + k1 * h / 2.0, acc)
    k3 = _derivative(x + k2 * h / 2.0, acc)
    k4 = _derivative(x + k3 * h, acc)
    return x + (k1 + 2.0 * k2 + 2.0 * k3 + k4) * h / 6.0


@njit(cache=True)
def glonass_states(x0, acc, toe, record, t):
    """States (N, 6) of GLONASS records at times t (N,): record[k] indexes the per-record arrays x0 (R, 6)
    state at toe, acc (R, 3) luni-solar acceleration and toe (R,). Full 60 s steps from toe while the
    remaining span is >= 60 s, then one shorter step if it exceeds 1e-9 s; the 60 s grid of each record
    is integrated once."""
    n = t.shape[0]
    n_rec = toe.shape[0]
    steps = np.zeros(n, np.int64)
    rest = np.zeros(n)
    sign = np.ones(n)
    k_max = np.zeros((n_rec, 2), np.int64)     # largest grid index needed, forward and backward
    for q in range(n):
        dt = t[q] - toe[record[q]]
        if dt < 0.0:
            sign[q] = -1.0
        span = abs(dt)
        k = int(span // GLONASS_STEP_S)
        r = span - k * GLONASS_STEP_S
        if r < 0.0:
            k -= 1
            r += GLONASS_STEP_S
        steps[q] = k
        rest[q] = r
        side = 0 if sign[q] > 0 else 1
        k_max[record[q], side] = max(k_max[record[q], side], k)
    offset = np.zeros((n_rec, 2), np.int64)
    total = 0
    for j in range(n_rec):
        for side in range(2):
            offset[j, side] = total
            total += k_max[j, side] + 1
    grid = np.empty((total, 6))
    for j in range(n_rec):
        for side in range(2):
            h = GLONASS_STEP_S if side == 0 else -GLONASS_STEP_S
            o = offset[j, side]
            grid[o] = x0[j]
            for k in range(1, k_max[j, side] + 1):
                grid[o + k] = rk4_step(grid[o + k - 1], h, acc[j])
    out = np.empty((n, 6))
    for q in range(n):
        side = 0 if sign[q] > 0 else 1
        x = grid[offset[record[q], side] + steps[q]]
        if rest[q] > GLONASS_MIN_STEP_S:
            x = rk4_step(x, sign[q] * rest[q], acc[record[q]])
        out[q] = x
    return out


# Columns of the Kepler parameter rows (ephemeris._kepler_row)
(K_TOE, K_TOC, K_AF0, K_AF1, K_AF2, K_A, K_E, K_I0, K_OM0, K_OMG, K_M0, K_DN, K_IDOT, K_OMDOT, K_CUC, K_CUS,
 K_CRC, K_CRS, K_CIC, K_CIS, K_TOES, K_MU, K_WE, K_GEO, K_VAR, K_IODE) = range(26)


@njit(cache=True)
def kepler_states(rows, t, tolerance_rad, max_iterations, clight_m_s, cos_m5, sin_m5):
    """Broadcast Kepler orbits (IS-GPS-200 with the velocity terms; BeiDou GEO rotated by -5 deg about X
    and by the Earth's rotation since toe about Z) at times t. rows: (N, 26) parameter rows. Returns
    position (N, 3), velocity (N, 3), clock bias (N,) with the relativistic term, drift (N,).

    Kepler's equation is iterated for all rows together until the largest correction is below the
    tolerance, as the numpy version it replaced did (same iterates)."""
    n = rows.shape[0]
    pos = np.empty((n, 3))
    vel = np.empty((n, 3))
    clock = np.empty(n)
    drift = np.empty(n)
    tk = np.empty(n)
    mean_motion = np.empty(n)
    M = np.empty(n)
    E = np.empty(n)
    for i in range(n):
        A = rows[i, K_A]
        tk[i] = t[i] - rows[i, K_TOE]
        mean_motion[i] = np.sqrt(rows[i, K_MU] / (A * A * A)) + rows[i, K_DN]
        M[i] = rows[i, K_M0] + mean_motion[i] * tk[i]
        E[i] = M[i]
    for _ in range(max_iterations):
        converged = True
        for i in range(n):
            e = rows[i, K_E]
            dE = (E[i] - e * np.sin(E[i]) - M[i]) / (1.0 - e * np.cos(E[i]))
            E[i] -= dE
            if abs(dE) > tolerance_rad:
                converged = False
        if converged:
            break
    for i in range(n):
        r_ = rows[i]
        A, e, mu = r_[K_A], r_[K_E], r_[K_MU]
        sinE, cosE = np.sin(E[i]), np.cos(E[i])
        one_m_ecos = 1.0 - e * cosE
        sq = np.sqrt(1.0 - e * e)
        phi = np.arctan2(sq * sinE, cosE - e) + r_[K_OMG]
        s2, c2 = np.sin(2.0 * phi), np.cos(2.0 * phi)
        cus, cuc, crs, crc, cis, cic = r_[K_CUS], r_[K_CUC], r_[K_CRS], r_[K_CRC], r_[K_CIS], r_[K_CIC]
        u = phi + cus * s2 + cuc * c2
        r = A * one_m_ecos + crs * s2 + crc * c2
        inc = r_[K_I0] + r_[K_IDOT] * tk[i] + cis * s2 + cic * c2
        E_dot = mean_motion[i] / one_m_ecos
        phi_dot = sq * E_dot / one_m_ecos
        u_dot = phi_dot * (1.0 + 2.0 * (cus * c2 - cuc * s2))
        r_dot = A * e * sinE * E_dot + 2.0 * phi_dot * (crs * c2 - crc * s2)
        i_dot = r_[K_IDOT] + 2.0 * phi_dot * (cis * c2 - cic * s2)
        cu, su = np.cos(u), np.sin(u)
        xp, yp = r * cu, r * su
        xp_dot = r_dot * cu - yp * u_dot
        yp_dot = r_dot * su + xp * u_dot
        we = r_[K_WE]
        geo = r_[K_GEO] > 0.5
        node_rate = r_[K_OMDOT] - (0.0 if geo else we)
        node = r_[K_OM0] + node_rate * tk[i] - we * r_[K_TOES]
        cO, sO, ci, si = np.cos(node), np.sin(node), np.cos(inc), np.sin(inc)
        X = xp * cO - yp * ci * sO
        Y = xp * sO + yp * ci * cO
        Z = yp * si
        Xd = xp_dot * cO - yp_dot * ci * sO + yp * si * sO * i_dot - node_rate * Y
        Yd = xp_dot * sO + yp_dot * ci * cO - yp * si * cO * i_dot + node_rate * X
        Zd = yp_dot * si + yp * ci * i_dot
        if geo:
            ang = we * tk[i]
            ca, sa = np.cos(ang), np.sin(ang)
            w0, w1, w2 = X, Y * cos_m5 + Z * sin_m5, -Y * sin_m5 + Z * cos_m5
            w0d, w1d, w2d = Xd, Yd * cos_m5 + Zd * sin_m5, -Yd * sin_m5 + Zd * cos_m5
            X, Y, Z = w0 * ca + w1 * sa, -w0 * sa + w1 * ca, w2
            Xd = w0d * ca + w1d * sa + we * Y
            Yd = -w0d * sa + w1d * ca - we * X
            Zd = w2d
        dtc = t[i] - r_[K_TOC]
        rel = 2.0 * np.sqrt(mu * A) * e / (clight_m_s * clight_m_s)
        clock[i] = r_[K_AF0] + r_[K_AF1] * dtc + r_[K_AF2] * dtc * dtc - rel * sinE
        drift[i] = r_[K_AF1] + 2.0 * r_[K_AF2] * dtc - rel * cosE * E_dot
        pos[i, 0], pos[i, 1], pos[i, 2] = X, Y, Z
        vel[i, 0], vel[i, 1], vel[i, 2] = Xd, Yd, Zd
    return pos, vel, clock, drift
