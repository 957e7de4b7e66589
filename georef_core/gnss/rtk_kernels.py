"""Compiled (numba) pass of the relative-positioning Kalman filter over all epochs; the model is described in
rtk_filter.py, which prepares the arrays (FilterArrays) and options (FilterConfig) and calls filter_pass.

State vector: rover position (+ velocity), then one single-difference ambiguity per satellite s and band b at
index n_kin + s * n_f + b. A state whose variance is 0 is inactive: its row and column of P are zero, and the
matrix products below run over the active states only (`active`, with `pos_in` mapping a state to its place
there). The design matrix of the double differences is sparse (3 position columns and at most 2 ambiguities
per row) and is never formed: H P and H P H^T are accumulated row by row."""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from .kernel_loader import njit

from .ambiguity_kernels import dd_pairs, resolve
from .constants import CLIGHT_M_S, OMEGA_EARTH_RAD_S

STATUS_NONE, STATUS_FIX, STATUS_FLOAT, STATUS_SINGLE = 0, 1, 2, 5
MODE_KINEMATIC, MODE_STATIC, MODE_KNOWN_START, MODE_SINGLE = 0, 1, 2, 3
DYNAMICS_OFF, DYNAMICS_RANDOM_WALK, DYNAMICS_CONSTANT_VELOCITY = 0, 1, 2
AR_OFF, AR_CONTINUOUS, AR_INSTANTANEOUS, AR_FIX_AND_HOLD = 0, 1, 2, 3
VAR_POS_INIT_M2 = 30.0**2
VAR_KNOWN_AMB_CYC2 = 1e-6
MAX_RESETS = 3               # re-initialisations per epoch after post-fit phase residual tests
CULPRIT_SIGMA = 5.0          # post-fit DD phase residual test
FIX_RESIDUAL_SIGMA = 4.0     # fixed-solution DD phase residual test
FIX_ATTEMPTS = 3             # AR attempts per epoch (each excluding the worst signal of the previous one)
ENTRANT_RATIO_FACTOR = 1.1   # ar_filter: a fix taking in new signals needs ratio >= this x threshold or >= half the last
KNOWN_START_MAX_FRACTION_CYC = 0.2

FilterArrays = namedtuple("FilterArrays", [
    "time_s",            # (E,) gps_time_s
    "lam",               # (S, F) wavelength (m)
    "rover_phase_m",     # (E, S, F)
    "rover_code_m",      # (E, S, F)
    "rover_iono_m",      # (E, S, F) code ionospheric delay at the rover
    "sat_pos",           # (E, S, 3) satellite ECEF at transmission (0 where unknown)
    "sat_clock_m",       # (E, S)
    "trop_m",            # (E, S) rover slant troposphere at trop_ref
    "trop_dh",           # (E, S) its change per metre of height
    "trop_ref",          # (E, 3)
    "up",                # (E, 3)
    "el",                # (E, S) elevation (rad)
    "base_phase_res_m",  # (E, S, F)
    "base_code_res_m",   # (E, S, F)
    "age_s",             # (E,)
    "slip_cum",          # (E + 1, S, F) int32
    "half_cycle",        # (E, S, F) bool
    "obs_ok",            # (E, S, F) bool: phase and code at both receivers, satellite usable
    "code_ok",           # (E, S, F) bool: code at both receivers, satellite usable
    "spp_pos",           # (E, 3)
    "spp_cov",           # (E, 3, 3)
    "spp_valid",         # (E,) bool
    "sys_code",          # (S,) int64: index of the satellite's system in the sorted list of systems
    "is_glonass",        # (S,) bool
    "ar_allowed",        # (S,) bool
])

FilterConfig = namedtuple("FilterConfig", [
    "n_systems", "n_kin", "mode", "dynamics", "ar_mode", "max_age_s", "outage_reset_epochs",
    "bias_process_noise_cyc", "initial_bias_var_cyc2", "known_start_var_m2", "position_rw_q", "accel_q",
    "reject_innovation_m", "ratio_threshold", "min_success_rate", "ar_min_lock_epochs", "ar_elevation_mask_rad",
    "ar_min_fix_to_hold", "hold_elevation_mask_rad", "hold_variance_cyc2", "ar_filter", "partial_ar",
    "partial_ar_max_drop",
    "partial_ar_max_float_sigma_m", "min_ambiguities_to_fix", "phase_error_a_m", "phase_error_b_m",
    "code_phase_ratio", "baseline_term_m", "clock_stability", "glonass_error_factor",
])


# ---------------------------------------------------------------------------------------------- geometry
@njit(cache=True)
def code_factor(c, band, is_code):
    """Code/phase error ratio of `band` for code (stats-eratio), 1 for phase."""
    if not is_code:
        return 1.0
    ratios = c.code_phase_ratio
    return ratios[min(band, ratios.shape[0] - 1)]


@njit(cache=True)
def sd_sigma2(c, is_glonass, el, fact, age_s):
    """Single-difference variance (m^2) of one signal: 2 (a^2 + (b / sin el)^2 + baseline^2) + clock^2, with
    a and b scaled by `fact` (code_factor)."""
    if is_glonass:
        fact = fact * c.glonass_error_factor
    a = fact * c.phase_error_a_m
    b = fact * c.phase_error_b_m
    d = CLIGHT_M_S * c.clock_stability * age_s
    sinel = max(np.sin(el), 0.05)
    return 2.0 * (a**2 + (b / sinel) ** 2 + c.baseline_term_m**2) + d**2


@njit(cache=True)
def rover_model_m(d, e, pos, los):
    """Geometric range (Sagnac included) - satellite clock + troposphere at the rover position `pos`, per
    satellite; fills `los` (S, 3) with the unit vectors receiver -> satellite."""
    n_s = d.el.shape[1]
    trop_ref, up, sat_pos = d.trop_ref[e], d.up[e], d.sat_pos[e]
    sat_clock, trop, trop_dh = d.sat_clock_m[e], d.trop_m[e], d.trop_dh[e]
    dh = 0.0
    for k in range(3):
        dh += (pos[k] - trop_ref[k]) * up[k]
    geo = np.empty(n_s)
    for s in range(n_s):
        sx, sy, sz = sat_pos[s, 0], sat_pos[s, 1], sat_pos[s, 2]
        dx, dy, dz = sx - pos[0], sy - pos[1], sz - pos[2]
        r = np.sqrt(dx * dx + dy * dy + dz * dz)
        los[s, 0], los[s, 1], los[s, 2] = dx / r, dy / r, dz / r
        rng = r + OMEGA_EARTH_RAD_S * (sx * pos[1] - sy * pos[0]) / CLIGHT_M_S
        geo[s] = rng - sat_clock[s] + (trop[s] + trop_dh[s] * dh)
    return geo


@njit(cache=True)
def single_differences(d, e, geo):
    """Rover-minus-base single differences of phase and code (m) after the rover model."""
    sd_phase = d.rover_phase_m[e] - (geo[:, None] - d.rover_iono_m[e]) - d.base_phase_res_m[e]
    sd_code = d.rover_code_m[e] - (geo[:, None] + d.rover_iono_m[e]) - d.base_code_res_m[e]
    return sd_phase, sd_code


# ---------------------------------------------------------------------------------------------- states
@njit(cache=True)
def reference_satellite(ok, b, sys_code, sys, el):
    """The reference of the double differences of system ``sys`` on band ``b``: the highest satellite
    with a usable signal (``ok[s, b]``), and how many satellites have one. (ref, count); ref -1 if none."""
    ref = -1
    count = 0
    for s in range(ok.shape[0]):
        if ok[s, b] and sys_code[s] == sys:
            count += 1
            if ref < 0 or el[s] > el[ref]:
                ref = s
    return ref, count


@njit(cache=True)
def reset_state(x, p, i):
    x[i] = 0.0
    p[i, :] = 0.0
    p[:, i] = 0.0


@njit(cache=True)
def active_states(p):
    """Indices of the states with a positive variance, and each state's place among them (-1: inactive)."""
    nx = p.shape[0]
    pos_in = np.full(nx, -1, np.int64)
    active = np.empty(nx, np.int64)
    na = 0
    for i in range(nx):
        if p[i, i] > 0:
            active[na] = i
            pos_in[i] = na
            na += 1
    return active[:na], pos_in


@njit(cache=True)
def init_biases(x, p, new, sd_phase, sd_code, lam, obs_ok, n_kin, init_var):
    """New ambiguity = (SD phase - SD code) / wavelength, shifted by the median offset that continuing
    ambiguities of the same band show between their state and that estimate (a common receiver phase-clock
    term), so new and old states agree in their arbitrary common part."""
    n_s, n_f = new.shape
    amb_diag = np.empty((n_s, n_f))
    for s in range(n_s):
        for b in range(n_f):
            i = n_kin + s * n_f + b
            amb_diag[s, b] = p[i, i]
    offsets = np.empty(n_s)
    for b in range(n_f):
        n_cont = 0
        for s in range(n_s):
            if obs_ok[s, b] and amb_diag[s, b] > 0 and not new[s, b]:
                est = (sd_phase[s, b] - sd_code[s, b]) / lam[s, b]
                offsets[n_cont] = (x[n_kin + s * n_f + b] - est) * lam[s, b]
                n_cont += 1
        offset = np.median(offsets[:n_cont]) if n_cont else 0.0
        for s in range(n_s):
            if new[s, b]:
                i = n_kin + s * n_f + b
                est = (sd_phase[s, b] - sd_code[s, b]) / lam[s, b]
                x[i] = est + offset / lam[s, b]
                p[i, :] = 0.0
                p[:, i] = 0.0
                p[i, i] = init_var


@njit(cache=True)
def known_start_ambiguities(d, c, x, p, obs_ok, sd_phase, e):
    """Daakir et al.: with the antenna at a surveyed point, DD ambiguities follow by rounding.
    Same-wavelength groups only (GLONASS FDMA stays float); fractions beyond 0.2 cycle stay float."""
    n_s, n_f = obs_ok.shape
    el, sys_code, is_glonass, lam = d.el[e], d.sys_code, d.is_glonass, d.lam
    for b in range(n_f):
        for sys in range(c.n_systems):
            ref, count = reference_satellite(obs_ok, b, sys_code, sys, el)
            if count < 2 or is_glonass[ref]:   # (a system is all GLONASS or none)
                continue
            i_ref = c.n_kin + ref * n_f + b
            n_ref = np.round(x[i_ref])
            x[i_ref] = n_ref
            p[i_ref, :] = 0.0
            p[:, i_ref] = 0.0
            p[i_ref, i_ref] = VAR_KNOWN_AMB_CYC2
            for s in range(n_s):
                if s == ref or not (obs_ok[s, b] and sys_code[s] == sys):
                    continue
                dd = (sd_phase[s, b] - sd_phase[ref, b]) / lam[s, b]
                if abs(dd - np.round(dd)) > KNOWN_START_MAX_FRACTION_CYC:
                    continue
                i = c.n_kin + s * n_f + b
                x[i] = n_ref + np.round(dd)
                p[i, :] = 0.0
                p[:, i] = 0.0
                p[i, i] = VAR_KNOWN_AMB_CYC2


# ---------------------------------------------------------------------------------------------- update
@njit(cache=True)
def dd_rows(d, c, e, obs_ok, code_ok, sd_phase, sd_code, x, los):
    """Double-difference rows for phase and code, one block per (band, system, phase|code), the reference
    being the highest satellite of the block. Returns (n_rows, v innovation (m), sig2 (SD variance of the
    row's satellite), block, is_code, sat, band, ref, h_pos (rows, 3) position partials, i_o and i_r the
    ambiguity states (-1 for code), lam_o, lam_r, block_sref (SD variance of each block's reference))."""
    n_s, n_f = obs_ok.shape
    el, sys_code, is_glonass, lam = d.el[e], d.sys_code, d.is_glonass, d.lam
    age = d.age_s[e]
    trop_dh, up = d.trop_dh[e], d.up[e]
    n_kin = c.n_kin
    m_max = 2 * n_s * n_f
    v = np.empty(m_max)
    sig2 = np.empty(m_max)
    block = np.empty(m_max, np.int64)
    is_code_row = np.empty(m_max, np.bool_)
    sat = np.empty(m_max, np.int64)
    band = np.empty(m_max, np.int64)
    refs = np.empty(m_max, np.int64)
    h_pos = np.empty((m_max, 3))
    i_o = np.full(m_max, -1, np.int64)
    i_r = np.full(m_max, -1, np.int64)
    lam_o = np.zeros(m_max)
    lam_r = np.zeros(m_max)
    block_sref = np.empty(2 * n_f * c.n_systems)
    n_rows = 0
    n_blocks = 0
    for b in range(n_f):
        for sys in range(c.n_systems):
            for kind in range(2):
                is_code = kind == 1
                ok = code_ok if is_code else obs_ok
                fact = code_factor(c, b, is_code)
                ref, count = reference_satellite(ok, b, sys_code, sys, el)
                if count < 2:
                    continue
                sref = sd_sigma2(c, is_glonass[ref], el[ref], fact, age)
                for s in range(n_s):
                    if s == ref or not (ok[s, b] and sys_code[s] == sys):
                        continue
                    r = n_rows
                    sig2[r] = sd_sigma2(c, is_glonass[s], el[s], fact, age)
                    block[r] = n_blocks
                    is_code_row[r] = is_code
                    sat[r] = s
                    band[r] = b
                    refs[r] = ref
                    for k in range(3):
                        h_pos[r, k] = -(los[s, k] - los[ref, k]) + (trop_dh[s] - trop_dh[ref]) * up[k]
                    if is_code:
                        v[r] = sd_code[s, b] - sd_code[ref, b]
                    else:
                        io = n_kin + s * n_f + b
                        ir = n_kin + ref * n_f + b
                        i_o[r], i_r[r] = io, ir
                        lam_o[r], lam_r[r] = lam[s, b], lam[ref, b]
                        v[r] = (sd_phase[s, b] - sd_phase[ref, b]) - (lam[s, b] * x[io] - lam[ref, b] * x[ir])
                    n_rows += 1
                block_sref[n_blocks] = sref
                n_blocks += 1
    return (n_rows, v, sig2, block, is_code_row, sat, band, refs, h_pos, i_o, i_r, lam_o, lam_r, block_sref)


@njit(cache=True)
def _hp_and_s(p, active, pos_in, rows, h_pos, i_o, i_r, lam_o, lam_r, r_mat):
    """H P (rows x active) and S = H P H^T + R for the sparse DD design matrix."""
    m = rows.shape[0]
    na = active.shape[0]
    hp = np.zeros((m, na))
    for q in range(m):
        r = rows[q]
        for u in range(na):
            a = active[u]
            acc = h_pos[r, 0] * p[0, a] + h_pos[r, 1] * p[1, a] + h_pos[r, 2] * p[2, a]
            if i_o[r] >= 0:
                acc += lam_o[r] * p[i_o[r], a] - lam_r[r] * p[i_r[r], a]
            hp[q, u] = acc
    s_mat = r_mat.copy()
    for q in range(m):
        for w in range(m):
            r = rows[w]
            acc = hp[q, pos_in[0]] * h_pos[r, 0] + hp[q, pos_in[1]] * h_pos[r, 1] + hp[q, pos_in[2]] * h_pos[r, 2]
            if i_o[r] >= 0:
                acc += hp[q, pos_in[i_o[r]]] * lam_o[r] - hp[q, pos_in[i_r[r]]] * lam_r[r]
            s_mat[q, w] += acc
    return hp, s_mat


@njit(cache=True)
def _apply_gain(x0, p0, active, hp, s_mat, v):
    """x + K v and P - K H P with K = P H^T S^-1, over the active states. Returns (ok, x, p, dx)."""
    na = active.shape[0]
    try:
        kt = np.linalg.solve(s_mat, hp)   # (H P)^T-shaped gain, K = kt^T
    except Exception:  # noqa: BLE001 - singular innovation covariance: no update
        return False, x0, p0, np.zeros(na)
    dx = kt.T @ v
    x = x0.copy()
    for u in range(na):
        x[active[u]] += dx[u]
    kh = kt.T @ hp
    p = p0.copy()
    for u in range(na):
        for w in range(na):
            p[active[u], active[w]] = p0[active[u], active[w]] - kh[u, w]
    for u in range(na):
        for w in range(u + 1, na):
            a, b = active[u], active[w]
            sym = 0.5 * (p[a, b] + p[b, a])
            p[a, b] = sym
            p[b, a] = sym
    return True, x, p, dx


@njit(cache=True)
def _culprit(rows, is_code, sat, band, refs, block, z):
    """The signal (satellite, band) to blame for post-fit phase residuals (normalised: z, one per kept row
    `rows`) beyond CULPRIT_SIGMA: the group's reference when most of the group is offset, else the worst
    satellite; (-1, -1) when none. (Moving on to other satellites once the reference was reset made the real
    u-blox data worse: 78 instead of 43 epochs beyond 5 cm of demo5.)"""
    m = rows.shape[0]
    worst = -1
    for q in range(m):
        if not is_code[rows[q]] and (worst < 0 or z[q] > z[worst]):
            worst = q
    if worst < 0 or z[worst] <= CULPRIT_SIGMA:
        return -1, -1
    w = rows[worst]
    n_members = 0
    n_bad = 0
    for q in range(m):
        if not is_code[rows[q]] and block[rows[q]] == block[w]:
            n_members += 1
            if z[q] > CULPRIT_SIGMA:
                n_bad += 1
    if n_members >= 3 and n_bad > n_members / 2:
        return refs[w], band[w]
    return sat[w], band[w]


@njit(cache=True)
def measurement_update(d, c, e, x, p, obs_ok, code_ok, sd_phase, sd_code, los):
    """EKF update with DD phase and code. Post-fit phase residuals beyond 5 sigma point at a cycle slip or a
    wrong ambiguity: the culprit (the group's reference when the whole group is offset, else the worst
    satellite) has its ambiguity re-initialised and the update is redone from the prior.
    Returns (ok, x, p, used (S, F) bool: the signals of the phase rows, satellites and references)."""
    n_s, n_f = obs_ok.shape
    x0, p0 = x, p
    reset_done = np.zeros((n_s, n_f), np.bool_)
    used = np.zeros((n_s, n_f), np.bool_)
    x_new, p_new = x, p
    for attempt in range(MAX_RESETS + 1):
        n_rows, v_all, sig2, block, is_code, sat, band, refs, h_pos, i_o, i_r, lam_o, lam_r, block_sref = dd_rows(
            d, c, e, obs_ok, code_ok, sd_phase, sd_code, x0, los)
        if n_rows < 4:
            return False, x, p, used
        rows = np.nonzero(np.abs(v_all[:n_rows]) <= c.reject_innovation_m)[0]
        m = rows.shape[0]
        if m < 4:
            return False, x, p, used
        r_mat = np.zeros((m, m))
        for q in range(m):
            for w in range(m):
                if block[rows[q]] == block[rows[w]]:
                    r_mat[q, w] = block_sref[block[rows[q]]]
            r_mat[q, q] += sig2[rows[q]]
        v = v_all[rows]
        active, pos_in = active_states(p0)
        hp, s_mat = _hp_and_s(p0, active, pos_in, rows, h_pos, i_o, i_r, lam_o, lam_r, r_mat)
        ok, x_new, p_new, dx = _apply_gain(x0, p0, active, hp, s_mat, v)
        if not ok:
            return False, x, p, used
        if attempt == MAX_RESETS:
            break
        z = np.empty(m)   # normalised post-fit residuals
        for q in range(m):
            r = rows[q]
            hdx = h_pos[r, 0] * dx[pos_in[0]] + h_pos[r, 1] * dx[pos_in[1]] + h_pos[r, 2] * dx[pos_in[2]]
            if i_o[r] >= 0:
                hdx += lam_o[r] * dx[pos_in[i_o[r]]] - lam_r[r] * dx[pos_in[i_r[r]]]
            z[q] = np.abs(v[q] - hdx) / np.sqrt(r_mat[q, q])
        s_c, b_c = _culprit(rows, is_code, sat, band, refs, block, z)
        if s_c < 0:
            break
        x0, p0 = x0.copy(), p0.copy()
        again = np.zeros((n_s, n_f), np.bool_)
        if reset_done[s_c, b_c]:
            # the reference was re-initialised already and most of its group is still offset: the group's
            # (held) integers cannot be trusted -> re-initialise the whole group (system and band)
            sys_code = d.sys_code
            for s in range(n_s):
                again[s, b_c] = obs_ok[s, b_c] and sys_code[s] == sys_code[s_c]
        else:
            again[s_c, b_c] = True
        reset_done[s_c, b_c] = True
        for s in range(n_s):
            for b in range(n_f):
                if again[s, b]:
                    reset_state(x0, p0, c.n_kin + s * n_f + b)
        init_biases(x0, p0, again, sd_phase, sd_code, d.lam, obs_ok, c.n_kin, c.initial_bias_var_cyc2)
    for q in range(m):
        r = rows[q]
        if not is_code[r]:
            used[sat[r], band[r]] = True
            used[refs[r], band[r]] = True
    return True, x_new, p_new, used


# ---------------------------------------------------------------------------------------------- fixing
@njit(cache=True)
def phase_residuals(d, c, e, pos, xs, ok_all):
    """DD phase residuals (m) at position `pos` with the ambiguities of state `xs`, per satellite and band
    (NaN for references and unused signals), plus the rows in order (band, system, satellite): residual,
    DD sigma, satellite, band."""
    n_s, n_f = ok_all.shape
    los = np.empty((n_s, 3))
    geo = rover_model_m(d, e, pos, los)
    sd_phase = d.rover_phase_m[e] - (geo[:, None] - d.rover_iono_m[e]) - d.base_phase_res_m[e]
    el, sys_code, is_glonass, lam = d.el[e], d.sys_code, d.is_glonass, d.lam
    age = d.age_s[e]
    out = np.full((n_s, n_f), np.nan)
    res = np.empty(n_s * n_f)
    sig = np.empty(n_s * n_f)
    where_s = np.empty(n_s * n_f, np.int64)
    where_b = np.empty(n_s * n_f, np.int64)
    k = 0
    for b in range(n_f):
        for sys in range(c.n_systems):
            ref, count = reference_satellite(ok_all, b, sys_code, sys, el)
            if count < 2:
                continue
            corr_ref = sd_phase[ref, b] - lam[ref, b] * xs[c.n_kin + ref * n_f + b]
            sref = sd_sigma2(c, is_glonass[ref], el[ref], 1.0, age)
            for s in range(n_s):
                if s == ref or not (ok_all[s, b] and sys_code[s] == sys):
                    continue
                out[s, b] = (sd_phase[s, b] - lam[s, b] * xs[c.n_kin + s * n_f + b]) - corr_ref
                res[k] = out[s, b]
                sig[k] = np.sqrt(sd_sigma2(c, is_glonass[s], el[s], 1.0, age) + sref)
                where_s[k] = s
                where_b[k] = b
                k += 1
    return out, res[:k], sig[:k], where_s[:k], where_b[:k]


@njit(cache=True)
def validate_fix(d, c, e, x_fixed, used):
    """Fixed DD phase residuals must stay within FIX_RESIDUAL_SIGMA. Returns (-1, -1) when they do, else the
    (satellite, band) of the worst residual (to be excluded from the next attempt)."""
    _, res, sig, where_s, where_b = phase_residuals(d, c, e, x_fixed[:3], x_fixed, used)
    if res.shape[0] == 0:
        return -1, -1
    z = np.abs(res) / sig
    k = np.argmax(z)
    if z[k] <= FIX_RESIDUAL_SIGMA:
        return -1, -1
    return where_s[k], where_b[k]


@njit(cache=True)
def resolve_epoch(d, c, e, x, p, used, obs_ok, lock):
    """Eligible ambiguities (used, above the AR mask, no half cycle, system allowed, locked long enough),
    double-differenced per system and band against the best-determined one (a freshly initialised
    reference would contaminate every DD of its group), then the highest satellite; then MLAMBDA
    (ambiguity_kernels.resolve). Returns (fixed, ratio, x_fixed, position covariance, pairs, integers)."""
    n_s, n_f = used.shape
    el, sys_code, ar_allowed, half_cycle = d.el[e], d.sys_code, d.ar_allowed, d.half_cycle[e]
    states = np.empty(n_s * n_f, np.int64)
    key = np.empty(n_s * n_f)
    elev = np.empty(n_s * n_f)
    group = np.empty(n_s * n_f, np.int64)
    n = 0
    for s in range(n_s):
        for b in range(n_f):
            if (used[s, b] and obs_ok[s, b] and ar_allowed[s] and el[s] >= c.ar_elevation_mask_rad
                    and not half_cycle[s, b] and lock[s, b] > c.ar_min_lock_epochs):
                i = c.n_kin + s * n_f + b
                states[n] = i
                # variance in tenths of a decade (ties decided by elevation)
                key[n] = -np.rint(np.log10(max(p[i, i], 1e-12)) * 10.0)
                elev[n] = el[s]
                group[n] = sys_code[s] * n_f + b
                n += 1
    pairs, pair_el = dd_pairs(states[:n], key[:n], elev[:n], group[:n])
    if pairs.shape[0] < c.min_ambiguities_to_fix:
        return False, 0.0, x, np.zeros((3, 3)), np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    active, pos_in = active_states(p)
    # searching subsets of an unconverged float solution finds wrong integers that pass the ratio test
    # (simulated L1 starts: float sigma ~1 m, 7 of 8 ambiguities, ratio 4.7, 2.2 m off)
    partial = c.partial_ar and np.sqrt(p[0, 0] + p[1, 1] + p[2, 2]) <= c.partial_ar_max_float_sigma_m
    pair_sat = (pairs[:, 0] - c.n_kin) // n_f
    return resolve(x, p, active, pos_in, pairs, pair_el, pair_sat, c.ratio_threshold, partial, c.partial_ar_max_drop,
                   c.min_ambiguities_to_fix, c.min_success_rate)


@njit(cache=True)
def hold(c, x, p, pairs, integers, el):
    """Fix-and-hold: the fixed DD ambiguities become observations of the float filter with variance
    c.hold_variance_cyc2 (RTKLIB 2.4.3: 0.001 cycles^2, which pins the float values to the integers; demo5:
    0.1, which lets them follow the data, so that a signal whose phase misfits the held ones by a few
    centimetres shows it in its own float value and ratio instead of being pulled onto an integer)."""
    n_f = (p.shape[0] - c.n_kin) // el.shape[0]
    keep = np.zeros(pairs.shape[0], np.bool_)
    for k in range(pairs.shape[0]):
        s = (pairs[k, 0] - c.n_kin) // n_f
        keep[k] = el[s] >= c.hold_elevation_mask_rad
    rows = np.nonzero(keep)[0]
    m = rows.shape[0]
    if m == 0:
        return
    active, pos_in = active_states(p)
    na = active.shape[0]
    hp = np.empty((m, na))
    v = np.empty(m)
    for q in range(m):
        i, j = pairs[rows[q], 0], pairs[rows[q], 1]
        v[q] = integers[rows[q]] - (x[i] - x[j])
        for u in range(na):
            hp[q, u] = p[i, active[u]] - p[j, active[u]]
    s_mat = np.zeros((m, m))
    for q in range(m):
        for w in range(m):
            s_mat[q, w] = hp[q, pos_in[pairs[rows[w], 0]]] - hp[q, pos_in[pairs[rows[w], 1]]]
        s_mat[q, q] += c.hold_variance_cyc2
    kt = np.linalg.solve(s_mat, hp)
    dx = kt.T @ v
    kh = kt.T @ hp
    for u in range(na):
        x[active[u]] += dx[u]
    for u in range(na):
        for w in range(na):
            p[active[u], active[w]] -= kh[u, w]
    for u in range(na):
        for w in range(u + 1, na):
            a, b = active[u], active[w]
            sym = 0.5 * (p[a, b] + p[b, a])
            p[a, b] = sym
            p[b, a] = sym


# ---------------------------------------------------------------------------------------------- the pass
@njit(cache=True)
def filter_pass(d, c, backward, known, use_known):
    """Run the filter over all epochs (backward: last to first), starting from `known` (3,) ECEF when
    use_known. Returns (status, position (E, 3), covariance (E, 3, 3), n_sats, ratio, residuals (E, S, F),
    n_fixed_amb, float position (E, 3), float covariance (E, 3, 3))."""
    n_e = d.time_s.shape[0]
    n_s, n_f = d.lam.shape
    n_kin = c.n_kin
    nx = n_kin + n_s * n_f
    out_status = np.zeros(n_e, np.int8)
    out_pos = np.full((n_e, 3), np.nan)
    out_cov = np.full((n_e, 3, 3), np.nan)
    out_n_sats = np.zeros(n_e, np.int16)
    out_ratio = np.zeros(n_e)
    out_res = np.full((n_e, n_s, n_f), np.nan)
    out_n_fix = np.zeros(n_e, np.int16)
    out_float_pos = np.full((n_e, 3), np.nan)     # the float solution at every epoch (fixed ones included)
    out_float_cov = np.full((n_e, 3, 3), np.nan)
    x = np.zeros(nx)
    p = np.zeros((nx, nx))
    last_obs = np.full((n_s, n_f), -1, np.int64)          # data index of the last epoch the signal was used
    last_step = np.full((n_s, n_f), -10**9, np.int64)     # processing step of that epoch
    lock = np.zeros((n_s, n_f), np.int64)
    los = np.empty((n_s, 3))
    pos_initialised = False
    fix_count = 0
    prev_fixed = False
    prev_ratio = 0.0
    prev_fix_set = np.zeros((n_s, n_f), np.bool_)
    have_prev = False
    prev_t = 0.0
    known_done = False
    for step in range(n_e):
        e = n_e - 1 - step if backward else step
        t = d.time_s[e]
        dt = abs(t - prev_t) if have_prev else 0.0
        have_base = np.isfinite(d.age_s[e]) and d.age_s[e] <= c.max_age_s
        if d.spp_valid[e]:
            out_status[e] = STATUS_SINGLE
            out_pos[e] = d.spp_pos[e]
            out_cov[e] = d.spp_cov[e]
            out_float_pos[e] = d.spp_pos[e]
            out_float_cov[e] = d.spp_cov[e]
        if not have_base or c.mode == MODE_SINGLE:
            continue
        # ---------------- time update: position
        if not pos_initialised:
            if not use_known and not d.spp_valid[e]:
                continue
            x[:3] = known if use_known else d.spp_pos[e]
            p[:, :3] = 0.0
            p[:3, :] = 0.0
            var0 = c.known_start_var_m2 if use_known else VAR_POS_INIT_M2
            for k in range(3):
                p[k, k] = var0
            if n_kin == 6:
                x[3:6] = 0.0
                for k in range(3, 6):
                    p[k, k] = 100.0
            pos_initialised = True
        elif c.mode == MODE_STATIC:
            pass
        elif c.dynamics == DYNAMICS_OFF:
            if d.spp_valid[e]:
                x[:3] = d.spp_pos[e]
            p[:3, :] = 0.0
            p[:, :3] = 0.0
            for k in range(3):
                p[k, k] = VAR_POS_INIT_M2
        elif c.dynamics == DYNAMICS_RANDOM_WALK:
            for k in range(3):
                p[k, k] += c.position_rw_q * dt
        else:  # constant velocity, white-noise acceleration (ECEF, isotropic with the horizontal value)
            sdt = (-1.0 if backward else 1.0) * dt
            for k in range(3):
                x[k] += sdt * x[k + 3]
            for k in range(3):
                p[k, :] += sdt * p[k + 3, :]
            for k in range(3):
                p[:, k] += sdt * p[:, k + 3]
            q = c.accel_q
            sgn = -1.0 if backward else 1.0
            for k in range(3):
                p[k, k] += q * dt**3 / 3
                p[k, k + 3] += sgn * q * dt**2 / 2
                p[k + 3, k] += sgn * q * dt**2 / 2
                p[k + 3, k + 3] += q * dt
        # ---------------- rover model at the predicted position
        obs_ok = d.obs_ok[e]
        code_ok = d.code_ok[e]
        geo = rover_model_m(d, e, x[:3], los)
        sd_phase, sd_code = single_differences(d, e, geo)
        # ---------------- ambiguity time update, slips, outages, initialisation
        if c.ar_mode == AR_INSTANTANEOUS:
            for i in range(n_kin, nx):
                if p[i, i] > 0:
                    reset_state(x, p, i)
        slip_cum = d.slip_cum
        for s in range(n_s):
            for b in range(n_f):
                i = n_kin + s * n_f + b
                if obs_ok[s, b] and p[i, i] > 0:
                    lo, hi = min(e, last_obs[s, b]), max(e, last_obs[s, b])
                    slipped = slip_cum[hi + 1, s, b] - slip_cum[lo + 1, s, b] > 0
                    if slipped or step - last_step[s, b] > c.outage_reset_epochs:
                        reset_state(x, p, i)
                        lock[s, b] = 0
        for s in range(n_s):
            for b in range(n_f):
                i = n_kin + s * n_f + b
                if p[i, i] > 0 and not obs_ok[s, b] and step - last_step[s, b] > c.outage_reset_epochs:
                    reset_state(x, p, i)
                    lock[s, b] = 0
        q_bias = c.bias_process_noise_cyc**2 * dt
        for i in range(n_kin, nx):
            if p[i, i] > 0:
                p[i, i] += q_bias
        new = np.zeros((n_s, n_f), np.bool_)
        any_new = False
        for s in range(n_s):
            for b in range(n_f):
                i = n_kin + s * n_f + b
                if obs_ok[s, b] and p[i, i] <= 0:
                    new[s, b] = True
                    any_new = True
        if any_new:
            init_biases(x, p, new, sd_phase, sd_code, d.lam, obs_ok, n_kin, c.initial_bias_var_cyc2)
        if use_known and not known_done and obs_ok.sum() >= 5:
            known_start_ambiguities(d, c, x, p, obs_ok, sd_phase, e)
            known_done = True
        # ---------------- measurement update
        ok, x_upd, p_upd, used = measurement_update(d, c, e, x, p, obs_ok, code_ok, sd_phase, sd_code, los)
        if not ok:
            continue
        x, p = x_upd, p_upd
        n_sat = 0
        for s in range(n_s):
            seen = False
            for b in range(n_f):
                if used[s, b]:
                    last_obs[s, b] = e
                    last_step[s, b] = step
                    lock[s, b] += 1
                    seen = True
                else:
                    lock[s, b] = 0
            n_sat += seen
        prev_t = t
        have_prev = True
        status = STATUS_FLOAT
        pos = x[:3].copy()
        cov = p[:3, :3].copy()
        out_float_pos[e] = pos
        out_float_cov[e] = cov
        ratio = 0.0
        n_fix = 0
        x_res = x
        # ---------------- ambiguity resolution
        if c.ar_mode != AR_OFF:
            excluded = np.zeros((n_s, n_f), np.bool_)
            accepted = False
            entrants_checked = not (c.ar_filter and prev_fixed)
            attempt = 0
            while attempt < FIX_ATTEMPTS:
                fixed, fix_ratio, x_fixed, cov_fixed, pairs, integers = resolve_epoch(
                    d, c, e, x, p, used & ~excluded, obs_ok, lock)
                ratio = fix_ratio if attempt == 0 else max(ratio, fix_ratio)
                if not entrants_checked:
                    # signals the last epoch's fix did not hold (risen, re-acquired, after a slip) that
                    # bring a sound fix down to a marginal one are left float for now (demo5's arfilter;
                    # only on success: leaving them out of a failed search gave wrong fixes on the walk)
                    entrants_checked = True
                    if fixed and fix_ratio < ENTRANT_RATIO_FACTOR * c.ratio_threshold and fix_ratio < 0.5 * prev_ratio:
                        entrants = used & ~excluded & ~prev_fix_set
                        if entrants.any():
                            excluded |= entrants
                            continue
                attempt += 1
                if not fixed:
                    break
                s_w, b_w = validate_fix(d, c, e, x_fixed, used & ~excluded)
                if s_w < 0:
                    accepted = True
                    break
                excluded[s_w, b_w] = True
            prev_fix_set[:, :] = False
            prev_fixed = accepted
            prev_ratio = fix_ratio if accepted else 0.0
            if accepted:
                status = STATUS_FIX
                pos = x_fixed[:3].copy()
                cov = cov_fixed
                n_fix = pairs.shape[0]
                x_res = x_fixed
                fix_count += 1
                for k in range(pairs.shape[0]):
                    for i in (pairs[k, 0], pairs[k, 1]):
                        prev_fix_set[(i - n_kin) // n_f, (i - n_kin) % n_f] = True
                if c.ar_mode == AR_FIX_AND_HOLD and fix_count >= c.ar_min_fix_to_hold:
                    hold(c, x, p, pairs, integers, d.el[e])
            else:
                fix_count = 0
        out_status[e] = status
        out_pos[e] = pos
        out_cov[e] = cov
        out_n_sats[e] = n_sat
        out_ratio[e] = ratio
        out_n_fix[e] = n_fix
        out_res[e] = phase_residuals(d, c, e, pos, x_res, used & obs_ok)[0]
    return out_status, out_pos, out_cov, out_n_sats, out_ratio, out_res, out_n_fix, out_float_pos, out_float_cov
