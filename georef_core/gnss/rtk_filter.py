"""Relative (PPK) extended Kalman filter.

States: rover position (ECEF, m) [+ velocity for the constant-velocity model] and one single-difference
(rover - base) carrier-phase ambiguity per satellite and band (cycles). Single-difference states avoid
the reference-satellite hand-over problem (Takasu & Yasuda 2009; Eling et al. 2014). Observations:
double-differenced carrier phase and code (m), per system and band, reference = highest satellite.
Noise at single-difference level: sigma_phase^2 = 2 (a^2 + (b / sin el)^2), sigma_code = f * sigma_phase,
plus a baseline-length term and the base clock term c * clock_stability * age.

The filter walks the epochs in either direction; cycle slips are given as 'slip between two
observations' flags so that the backward pass uses them correctly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .ambiguity_resolution import FixResult, dd_pairs, resolve
from .constants import CLIGHT_M_S
from .rtk_options import RtkOptions
from .satellite_geometry import geometric_range_m

STATUS_NONE, STATUS_FIX, STATUS_FLOAT, STATUS_SINGLE = 0, 1, 2, 5
VAR_POS_INIT_M2 = 30.0**2
VAR_HOLD_AMB_CYC2 = 0.001
VAR_KNOWN_AMB_CYC2 = 1e-6


@dataclass
class PreparedData:
    """Everything the filter needs, on the rover's epochs and a common satellite list."""

    time_s: np.ndarray              # (E,) gps_time_s of rover epochs
    sat_ids: list[str]              # (S,)
    wavelength_m: np.ndarray        # (S, F)
    rover_phase_m: np.ndarray       # (E, S, F) carrier phase times wavelength
    rover_code_m: np.ndarray        # (E, S, F)
    rover_sat_pos_ecef_m: np.ndarray   # (E, S, 3)
    rover_sat_clock_m: np.ndarray      # (E, S) c * dts
    rover_trop_m: np.ndarray        # (E, S) slant troposphere at rover_trop_ref_ecef_m
    rover_trop_dh_m_per_m: np.ndarray  # (E, S) its change per metre of height
    rover_trop_ref_ecef_m: np.ndarray  # (E, 3) where it was evaluated (single-point position)
    rover_up_unit: np.ndarray       # (E, 3) local vertical there
    rover_iono_m: np.ndarray        # (E, S, F) code ionospheric delay at the rover
    rover_elevation_rad: np.ndarray # (E, S)
    rover_usable: np.ndarray        # (E, S) satellite valid, selected system, above the mask
    base_phase_res_m: np.ndarray    # (E, S, F)
    base_code_res_m: np.ndarray     # (E, S, F)
    age_s: np.ndarray               # (E,)
    slip_cum: np.ndarray            # (E + 1, S, F) cumulative count of slips into each epoch
    half_cycle: np.ndarray          # (E, S, F) bool
    spp_position_ecef_m: np.ndarray # (E, 3)
    spp_covariance_m2: np.ndarray   # (E, 3, 3)
    spp_valid: np.ndarray           # (E,)
    baseline_m: float


@dataclass
class FilterOutput:
    status: np.ndarray              # (E,) 1 fix, 2 float, 5 single, 0 none
    position_ecef_m: np.ndarray     # (E, 3)
    covariance_ecef_m2: np.ndarray  # (E, 3, 3)
    n_sats: np.ndarray              # (E,)
    ratio: np.ndarray               # (E,)
    residuals_m: np.ndarray         # (E, S, F) post-fit DD phase residuals (NaN = unused/reference)
    n_fixed_amb: np.ndarray         # (E,)


def _sd_sigma2(opts: RtkOptions, sys: np.ndarray, el: np.ndarray, band: int, is_code: bool, baseline_m: float,
               age_s: float) -> np.ndarray:
    fact = opts.code_phase_ratio[min(band, len(opts.code_phase_ratio) - 1)] if is_code else 1.0
    fact = fact * np.where(sys == "R", opts.glonass_error_factor, 1.0)
    a = fact * opts.phase_error_a_m
    b = fact * opts.phase_error_b_m
    c = opts.phase_error_baseline_m_per_10km * baseline_m / 1e4
    d = CLIGHT_M_S * opts.clock_stability * age_s
    sinel = np.maximum(np.sin(el), 0.05)
    return 2.0 * (a**2 + (b / sinel) ** 2 + c**2) + d**2


class RtkFilter:
    def __init__(self, data: PreparedData, opts: RtkOptions):
        self.d = data
        self.o = opts
        self.n_s = len(data.sat_ids)
        self.n_f = opts.n_bands
        self.n_kin = 6 if opts.dynamics == "constant-velocity" else 3
        self.nx = self.n_kin + self.n_s * self.n_f
        self.sys = np.array([s[0] for s in data.sat_ids])
        self.systems = list(np.unique(self.sys))
        self.ar_allowed = np.array([(s[0] != "R" or opts.glonass_ar) and (s[0] != "C" or opts.bds_ar) for s in data.sat_ids])

    def amb_index(self, s, b):
        return self.n_kin + s * self.n_f + b

    # ------------------------------------------------------------------ main loop
    def run(self, backward: bool = False, known_start_ecef_m: np.ndarray | None = None) -> FilterOutput:
        d, o = self.d, self.o
        n_e, n_s, n_f = len(d.time_s), self.n_s, self.n_f
        out = FilterOutput(np.zeros(n_e, np.int8), np.full((n_e, 3), np.nan), np.full((n_e, 3, 3), np.nan),
                           np.zeros(n_e, np.int16), np.zeros(n_e), np.full((n_e, n_s, n_f), np.nan), np.zeros(n_e, np.int16))
        x = np.zeros(self.nx)
        p = np.zeros((self.nx, self.nx))
        last_obs = np.full((n_s, n_f), -1)       # data index of the last epoch the signal was used
        last_step = np.full((n_s, n_f), -10**9)  # processing step of that epoch
        lock = np.zeros((n_s, n_f), dtype=int)
        pos_initialised = False
        fix_count = 0
        prev_t = None
        known = known_start_ecef_m
        known_done = False
        order = range(n_e - 1, -1, -1) if backward else range(n_e)
        for step, e in enumerate(order):
            t = d.time_s[e]
            dt = 0.0 if prev_t is None else abs(t - prev_t)
            have_base = np.isfinite(d.age_s[e]) and d.age_s[e] <= o.max_age_s
            if d.spp_valid[e]:
                out.status[e] = STATUS_SINGLE
                out.position_ecef_m[e] = d.spp_position_ecef_m[e]
                out.covariance_ecef_m2[e] = d.spp_covariance_m2[e]
            if not have_base or o.mode == "single":
                continue
            # ---------------- time update: position
            if not pos_initialised:
                start = known if known is not None else (d.spp_position_ecef_m[e] if d.spp_valid[e] else None)
                if start is None:
                    continue
                x[:3] = start
                p[:, :3] = 0.0
                p[:3, :] = 0.0
                var0 = o.known_start_sigma_m**2 if known is not None else VAR_POS_INIT_M2
                p[:3, :3] = np.eye(3) * var0
                if self.n_kin == 6:
                    x[3:6] = 0.0
                    p[3:6, 3:6] = np.eye(3) * 100.0
                pos_initialised = True
            elif o.mode == "static":
                pass
            elif o.dynamics == "off":
                if d.spp_valid[e]:
                    x[:3] = d.spp_position_ecef_m[e]
                p[:3, :] = 0.0
                p[:, :3] = 0.0
                p[:3, :3] = np.eye(3) * VAR_POS_INIT_M2
            elif o.dynamics == "random-walk":
                p[:3, :3] += np.eye(3) * o.position_random_walk_m_sqrt_s**2 * dt
            else:  # constant velocity, white-noise acceleration (ECEF, isotropic with the horizontal value)
                sgn = -1.0 if backward else 1.0
                f = np.eye(self.nx)
                f[:3, 3:6] = np.eye(3) * sgn * dt
                x = f @ x
                p = f @ p @ f.T
                q = o.accel_noise_h_m_s2**2
                p[:3, :3] += np.eye(3) * q * dt**3 / 3
                p[:3, 3:6] += np.eye(3) * sgn * q * dt**2 / 2
                p[3:6, :3] += np.eye(3) * sgn * q * dt**2 / 2
                p[3:6, 3:6] += np.eye(3) * q * dt
            # ---------------- which signals are observed (both receivers, phase and code)
            usable = d.rover_usable[e][:, None] & np.ones((1, n_f), bool)
            obs_ok = usable & ~np.isnan(d.rover_phase_m[e, :, :n_f]) & ~np.isnan(d.base_phase_res_m[e, :, :n_f]) \
                & ~np.isnan(d.rover_code_m[e, :, :n_f]) & ~np.isnan(d.base_code_res_m[e, :, :n_f])
            code_ok = usable & ~np.isnan(d.rover_code_m[e, :, :n_f]) & ~np.isnan(d.base_code_res_m[e, :, :n_f])
            # ---------------- rover residuals at the predicted position
            rng, los = geometric_range_m(np.nan_to_num(d.rover_sat_pos_ecef_m[e]), x[:3][None, :])
            geo = rng - d.rover_sat_clock_m[e] + self._rover_trop(e, x[:3])
            sd_phase = d.rover_phase_m[e, :, :n_f] - (geo[:, None] - d.rover_iono_m[e, :, :n_f]) - d.base_phase_res_m[e, :, :n_f]
            sd_code = d.rover_code_m[e, :, :n_f] - (geo[:, None] + d.rover_iono_m[e, :, :n_f]) - d.base_code_res_m[e, :, :n_f]
            lam = d.wavelength_m[:, :n_f]
            # ---------------- ambiguity time update, slips, outages, initialisation
            if o.ar_mode == "instantaneous":
                for s, b in zip(*np.nonzero(p.diagonal()[self.n_kin:].reshape(n_s, n_f) > 0)):
                    self._reset(x, p, self.amb_index(s, b))
            for s, b in zip(*np.nonzero(obs_ok)):
                i = self.amb_index(s, b)
                if p[i, i] > 0:
                    lo, hi = sorted((e, last_obs[s, b]))
                    slipped = d.slip_cum[hi + 1, s, b] - d.slip_cum[lo + 1, s, b] > 0
                    if slipped or step - last_step[s, b] > o.outage_reset_epochs:
                        self._reset(x, p, i)
                        lock[s, b] = 0
            amb_diag = p.diagonal()[self.n_kin:].reshape(n_s, n_f)
            stale = (amb_diag > 0) & ~obs_ok & (step - last_step > o.outage_reset_epochs)
            for s, b in zip(*np.nonzero(stale)):
                self._reset(x, p, self.amb_index(s, b))
                lock[s, b] = 0
            act = self.n_kin + np.nonzero(p.diagonal()[self.n_kin:] > 0)[0]
            p[act, act] += o.bias_process_noise_cyc**2 * dt
            new = obs_ok & (p.diagonal()[self.n_kin:].reshape(n_s, n_f) <= 0)
            if new.any():
                self._init_biases(x, p, new, sd_phase, sd_code, lam, obs_ok)
            if known is not None and not known_done and obs_ok.sum() >= 5:
                self._known_start_ambiguities(x, p, obs_ok, sd_phase, lam, d.rover_elevation_rad[e])
                known_done = True
            # ---------------- measurement update
            upd = self._measurement_update(e, x, p, obs_ok, code_ok, sd_phase, sd_code, los, lam)
            if upd is None:
                continue
            x, p, phase_rows = upd
            used = np.zeros((n_s, n_f), bool)
            for (s, b, ref) in (pr for pr in phase_rows if pr is not None):
                used[s, b] = used[ref, b] = True
            last_obs[used] = e
            last_step[used] = step
            lock[used] += 1
            lock[~used] = 0
            prev_t = t
            n_sat = int(used.any(axis=1).sum())
            status = STATUS_FLOAT
            pos, cov = x[:3].copy(), p[:3, :3].copy()
            ratio = 0.0
            n_fix = 0
            # ---------------- ambiguity resolution
            if o.ar_mode != "off":
                excluded = np.zeros((n_s, n_f), bool)
                accepted = False
                for _attempt in range(3):
                    fix = self._resolve(e, x, p, used & ~excluded, obs_ok, lock)
                    ratio = fix.ratio if _attempt == 0 else max(ratio, fix.ratio)
                    if not fix.fixed:
                        break
                    worst = self._validate_fix(e, fix.x_fixed, used & ~excluded, lam)
                    if worst is None:
                        accepted = True
                        break
                    excluded[worst] = True
                if accepted:
                    status = STATUS_FIX
                    pos, cov = fix.x_fixed[:3].copy(), fix.p_fixed[:3, :3].copy()
                    n_fix = len(fix.dd_rows)
                    fix_count += 1
                    if o.ar_mode == "fix-and-hold" and fix_count >= o.ar_min_fix_to_hold:
                        self._hold(x, p, fix, d.rover_elevation_rad[e])
                else:
                    fix_count = 0
            out.status[e] = status
            out.position_ecef_m[e] = pos
            out.covariance_ecef_m2[e] = cov
            out.n_sats[e] = n_sat
            out.ratio[e] = ratio
            out.n_fixed_amb[e] = n_fix
            out.residuals_m[e] = self._phase_residuals(e, pos, x if status != STATUS_FIX else fix.x_fixed, used, lam, obs_ok)
        return out

    # ------------------------------------------------------------------ helpers
    def _rover_trop(self, e, pos):
        """Slant troposphere (m) per satellite at the rover position `pos` (first order in height)."""
        d = self.d
        dh = float((pos - d.rover_trop_ref_ecef_m[e]) @ d.rover_up_unit[e])
        return d.rover_trop_m[e] + d.rover_trop_dh_m_per_m[e] * dh

    def _reset(self, x, p, i):
        x[i] = 0.0
        p[i, :] = 0.0
        p[:, i] = 0.0

    def _init_biases(self, x, p, new, sd_phase, sd_code, lam, obs_ok):
        """New ambiguity = (SD phase - SD code) / wavelength, shifted by the mean offset that continuing
        ambiguities of the same band show between their state and that estimate (a common receiver
        phase-clock term), so new and old states agree in their arbitrary common part."""
        n_s, n_f = new.shape
        est = (sd_phase - sd_code) / lam
        amb_diag = p.diagonal()[self.n_kin:].reshape(n_s, n_f)
        for b in range(n_f):
            cont = obs_ok[:, b] & (amb_diag[:, b] > 0) & ~new[:, b]
            offset = 0.0
            if cont.any():
                idx = self.n_kin + np.nonzero(cont)[0] * n_f + b
                offsets = (x[idx] - est[cont, b]) * lam[cont, b]  # m, common to all satellites
                offset_m = float(np.median(offsets))
                offset = offset_m
            for s in np.nonzero(new[:, b])[0]:
                i = self.amb_index(s, b)
                x[i] = est[s, b] + offset / lam[s, b]
                p[i, :] = 0.0
                p[:, i] = 0.0
                p[i, i] = self.o.initial_bias_sigma_cyc**2

    def _known_start_ambiguities(self, x, p, obs_ok, sd_phase, lam, el):
        """Daakir et al.: with the antenna at a surveyed point, DD ambiguities follow by rounding.
        Same-wavelength groups only (GLONASS FDMA stays float); fractions beyond 0.2 cycle stay float."""
        n_s, n_f = obs_ok.shape
        for b in range(n_f):
            for sys in np.unique(self.sys):
                if sys == "R":
                    continue
                members = np.nonzero(obs_ok[:, b] & (self.sys == sys))[0]
                if len(members) < 2:
                    continue
                ref = members[np.argmax(el[members])]
                i_ref = self.amb_index(ref, b)
                n_ref = np.round(x[i_ref])
                x[i_ref] = n_ref
                p[i_ref, :] = 0.0
                p[:, i_ref] = 0.0
                p[i_ref, i_ref] = VAR_KNOWN_AMB_CYC2
                for s in members:
                    if s == ref:
                        continue
                    dd = (sd_phase[s, b] - sd_phase[ref, b]) / lam[s, b]
                    if abs(dd - np.round(dd)) > 0.2:
                        continue
                    i = self.amb_index(s, b)
                    x[i] = n_ref + np.round(dd)
                    p[i, :] = 0.0
                    p[:, i] = 0.0
                    p[i, i] = VAR_KNOWN_AMB_CYC2

    def _dd_rows(self, e, obs_ok, code_ok, sd_phase, sd_code, x, los, lam):
        """Double-difference innovations v, design matrix H and covariance R for phase and code, one block
        per (band, system, phase|code), reference = highest satellite of the block. row_info describes each
        row: (kind, satellite, band, reference, (system, band))."""
        d, o = self.d, self.o
        el = d.rover_elevation_rad[e]
        age = float(d.age_s[e])
        v_parts, h_parts, sig_parts, blocks, row_info = [], [], [], [], []
        n_rows = 0
        for b in range(self.n_f):
            for sys in self.systems:
                in_sys = self.sys == sys
                for is_code in (False, True):
                    members = np.nonzero((code_ok if is_code else obs_ok)[:, b] & in_sys)[0]
                    if len(members) < 2:
                        continue
                    ref = members[np.argmax(el[members])]
                    others = members[members != ref]
                    sig2 = _sd_sigma2(o, self.sys[members], el[members], b, is_code, d.baseline_m, age)
                    sref = sig2[members == ref][0]
                    h = np.zeros((len(others), self.nx))
                    h[:, :3] = -(los[others] - los[ref])
                    if is_code:
                        v = sd_code[others, b] - sd_code[ref, b]
                        kind = "code"
                    else:
                        i_o = self.n_kin + others * self.n_f + b
                        i_r = self.n_kin + ref * self.n_f + b
                        v = (sd_phase[others, b] - sd_phase[ref, b]) - (lam[others, b] * x[i_o] - lam[ref, b] * x[i_r])
                        h[np.arange(len(others)), i_o] = lam[others, b]
                        h[:, i_r] = -lam[ref, b]
                        kind = "phase"
                    v_parts.append(v)
                    h_parts.append(h)
                    sig_parts.append(sig2[members != ref])
                    row_info.extend((kind, int(s_), b, int(ref), (sys, b)) for s_ in others)
                    blocks.append((n_rows, n_rows + len(others), sref))
                    n_rows += len(others)
        if n_rows < 4:
            return None
        r = np.diag(np.concatenate(sig_parts))
        for start, stop, sref in blocks:
            r[start:stop, start:stop] += sref
        return np.concatenate(v_parts), np.vstack(h_parts), r, row_info

    def _measurement_update(self, e, x, p, obs_ok, code_ok, sd_phase, sd_code, los, lam, max_resets: int = 3):
        """EKF update with DD phase and code. Post-fit phase residuals beyond 5 sigma point at a cycle slip
        or a wrong ambiguity: the culprit (the group's reference when the whole group is offset, else the
        worst satellite) has its ambiguity re-initialised and the update is redone from the prior."""
        o = self.o
        x0, p0 = x, p
        obs_ok = obs_ok.copy()
        reset_done: set = set()
        for attempt in range(max_resets + 1):
            rows = self._dd_rows(e, obs_ok, code_ok, sd_phase, sd_code, x0, los, lam)
            if rows is None:
                return None
            v, h, r, row_info = rows
            keep = np.abs(v) <= o.reject_innovation_m
            if keep.sum() < 4:
                return None
            v, h, r = v[keep], h[keep], r[np.ix_(keep, keep)]
            row_info = [ri for ri, k in zip(row_info, keep) if k]
            ix = np.nonzero(p0.diagonal() > 0)[0]
            hs = h[:, ix]
            ps = p0[np.ix_(ix, ix)]
            s_mat = hs @ ps @ hs.T + r
            try:
                k_gain = np.linalg.solve(s_mat, hs @ ps).T
            except np.linalg.LinAlgError:
                return None
            dx = k_gain @ v
            x = x0.copy()
            x[ix] += dx
            ps = ps - k_gain @ hs @ ps
            p = p0.copy()
            p[np.ix_(ix, ix)] = 0.5 * (ps + ps.T)
            if attempt == max_resets:
                break
            post = v - hs @ dx
            z = np.abs(post) / np.sqrt(np.diag(r))
            culprit = self._culprit(row_info, post, z)
            if culprit is None:
                break
            s_c, b_c = culprit
            x0, p0 = x0.copy(), p0.copy()
            again = np.zeros_like(obs_ok)
            if culprit in reset_done:
                # the reference was re-initialised already and most of its group is still offset: the group's
                # (held) integers cannot be trusted -> re-initialise the whole group (system and band)
                again[:, b_c] = obs_ok[:, b_c] & (self.sys == self.sys[s_c])
            else:
                again[s_c, b_c] = True
            reset_done.add(culprit)
            for s_r, b_r in zip(*np.nonzero(again)):
                self._reset(x0, p0, self.amb_index(s_r, b_r))
            self._init_biases(x0, p0, again, sd_phase, sd_code, lam, obs_ok)
        phase_rows = [(ri[1], ri[2], ri[3]) if ri[0] == "phase" else None for ri in row_info]
        return x, p, phase_rows

    @staticmethod
    def _culprit(row_info, post, z, threshold: float = 5.0):
        """The signal to blame for post-fit phase residuals beyond `threshold` sigma: the group's reference
        when most of the group is offset, else the worst satellite. (Moving on to other satellites once the
        reference was reset made the real u-blox data worse: 78 instead of 43 epochs beyond 5 cm of demo5.)"""
        phase = [k for k, ri in enumerate(row_info) if ri[0] == "phase"]
        if not phase or max(z[k] for k in phase) <= threshold:
            return None
        groups: dict = {}
        for k in phase:
            groups.setdefault(row_info[k][4], []).append(k)
        worst_k = max(phase, key=lambda k: z[k])
        members = groups[row_info[worst_k][4]]
        bad = [k for k in members if z[k] > threshold]
        _, s, b, ref, _ = row_info[worst_k]
        if len(members) >= 3 and len(bad) > len(members) / 2:
            return ref, b
        return s, b

    def _eligible(self, e, used, obs_ok):
        d, o = self.d, self.o
        el = d.rover_elevation_rad[e]
        elig = used & obs_ok & self.ar_allowed[:, None] & (el[:, None] >= np.radians(o.ar_elevation_mask_deg)) \
            & ~d.half_cycle[e, :, : self.n_f]
        return elig

    def _resolve(self, e, x, p, used, obs_ok, lock):
        o = self.o
        el = self.d.rover_elevation_rad[e]
        elig = self._eligible(e, used, obs_ok) & (lock > o.ar_min_lock_epochs)
        states, elevs, groups = [], [], []
        for s, b in zip(*np.nonzero(elig)):
            states.append(self.amb_index(s, b))
            elevs.append(el[s])
            groups.append((self.sys[s], b))
        # reference of each group: the best-determined ambiguity (a freshly initialised one as reference
        # would contaminate every DD of its group), then the highest satellite
        pref = [(-round(float(np.log10(max(p[i, i], 1e-12))), 1), el_s) for i, el_s in zip(states, elevs)]
        pairs = dd_pairs(states, pref, groups)
        if len(pairs) < o.min_ambiguities_to_fix:
            return FixResult(False, 0.0, None, None, [], None)
        el_of_state = dict(zip(states, elevs))
        pair_el = [el_of_state[i] for i, _ in pairs]
        active = np.nonzero(p.diagonal() > 0)[0]
        # searching subsets of an unconverged float solution finds wrong integers that pass the ratio test
        # (simulated L1 starts: float sigma ~1 m, 7 of 8 ambiguities, ratio 4.7, 2.2 m off)
        partial = o.partial_ar and float(np.sqrt(np.trace(p[:3, :3]))) <= o.partial_ar_max_float_sigma_m
        return resolve(x, p, active, pairs, pair_el, o.ratio_threshold, partial, o.partial_ar_max_drop,
                       o.min_ambiguities_to_fix, o.min_success_rate)

    def _validate_fix(self, e, x_fix, used, lam):
        """Fixed DD phase residuals must stay within 4 sigma. Returns None when they do, else the
        (satellite, band) of the worst residual (to be excluded from the next attempt)."""
        res = self._phase_residuals(e, x_fix[:3], x_fix, used, lam, used, with_sigma=True)
        if res is None:
            return None
        v, sig, where = res
        z = np.abs(v) / sig
        k = int(np.argmax(z))
        return None if z[k] <= 4.0 else where[k]

    def _phase_residuals(self, e, pos, xs, used, lam, obs_ok, with_sigma=False):
        """DD phase residuals (m) at position `pos` with the ambiguities of state `xs`, per satellite and band
        (NaN for references and unused signals); with_sigma: (residuals, DD sigmas, [(sat, band)])."""
        d, o = self.d, self.o
        n_f = self.n_f
        rng, _ = geometric_range_m(np.nan_to_num(d.rover_sat_pos_ecef_m[e]), pos[None, :])
        geo = rng - d.rover_sat_clock_m[e] + self._rover_trop(e, pos)
        sd_phase = d.rover_phase_m[e, :, :n_f] - (geo[:, None] - d.rover_iono_m[e, :, :n_f]) - d.base_phase_res_m[e, :, :n_f]
        corr = sd_phase - lam * xs[self.n_kin:].reshape(self.n_s, n_f)
        out = np.full((self.n_s, n_f), np.nan)
        el = d.rover_elevation_rad[e]
        vs, sigs, where = [], [], []
        ok_all = used & obs_ok
        for b in range(n_f):
            for sys in self.systems:
                members = np.nonzero(ok_all[:, b] & (self.sys == sys))[0]
                if len(members) < 2:
                    continue
                ref = members[np.argmax(el[members])]
                others = members[members != ref]
                out[others, b] = corr[others, b] - corr[ref, b]
                if with_sigma:
                    sig2 = _sd_sigma2(o, self.sys[members], el[members], b, False, d.baseline_m, float(d.age_s[e]))
                    sref = sig2[members == ref][0]
                    vs.append(out[others, b])
                    sigs.append(np.sqrt(sig2[members != ref] + sref))
                    where.extend((int(s_), b) for s_ in others)
        if with_sigma:
            return (np.concatenate(vs), np.concatenate(sigs), where) if vs else None
        return out

    def _hold(self, x, p, fix, el):
        """Fix-and-hold: the fixed DD ambiguities become observations of the float filter (variance 0.001 cyc^2)."""
        o = self.o
        rows = []
        for (i, j), a in zip(fix.dd_rows, fix.dd_integers):
            s = (i - self.n_kin) // self.n_f
            if el[s] >= np.radians(o.hold_elevation_mask_deg):
                rows.append((i, j, a))
        if not rows:
            return
        ix = np.nonzero(p.diagonal() > 0)[0]
        pos_in = {s: k for k, s in enumerate(ix)}
        h = np.zeros((len(rows), len(ix)))
        v = np.zeros(len(rows))
        for r, (i, j, a) in enumerate(rows):
            h[r, pos_in[i]] = 1.0
            h[r, pos_in[j]] = -1.0
            v[r] = a - (x[i] - x[j])
        ps = p[np.ix_(ix, ix)]
        s_mat = h @ ps @ h.T + np.eye(len(rows)) * VAR_HOLD_AMB_CYC2
        k_gain = np.linalg.solve(s_mat, h @ ps).T
        x[ix] += k_gain @ v
        ps = ps - k_gain @ h @ ps
        p[np.ix_(ix, ix)] = 0.5 * (ps + ps.T)
