"""Relative (PPK) extended Kalman filter.

States: rover position (ECEF, m) [+ velocity for the constant-velocity model] and one single-difference
(rover - base) carrier-phase ambiguity per satellite and band (cycles). Single-difference states avoid
the reference-satellite hand-over problem (Takasu & Yasuda 2009; Eling et al. 2014). Observations:
double-differenced carrier phase and code (m), per system and band, reference = highest satellite.
Noise at single-difference level: sigma_phase^2 = 2 (a^2 + (b / sin el)^2), sigma_code = f * sigma_phase,
plus a baseline-length term and the base clock term c * clock_stability * age.

The filter walks the epochs in either direction; cycle slips are given as 'slip between two
observations' flags so that the backward pass uses them correctly. This module prepares the arrays and
options; each pass runs in compiled code (rtk_kernels.py: time and measurement updates, slips, residual
tests, fix validation, fix-and-hold; ambiguity_kernels.py and lambda_kernels.py: ambiguity resolution).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .rtk_kernels import (
    AR_CONTINUOUS,
    AR_FIX_AND_HOLD,
    AR_INSTANTANEOUS,
    AR_OFF,
    DYNAMICS_CONSTANT_VELOCITY,
    DYNAMICS_OFF,
    DYNAMICS_RANDOM_WALK,
    MODE_KINEMATIC,
    MODE_KNOWN_START,
    MODE_SINGLE,
    MODE_STATIC,
    STATUS_FIX,
    STATUS_FLOAT,
    STATUS_NONE,
    STATUS_SINGLE,
    FilterArrays,
    FilterConfig,
    filter_pass,
)
from .rtk_options import RtkOptions

__all__ = ["STATUS_FIX", "STATUS_FLOAT", "STATUS_NONE", "STATUS_SINGLE", "FilterOutput", "PreparedData", "RtkFilter"]

_MODES = {"kinematic": MODE_KINEMATIC, "static": MODE_STATIC, "known-start": MODE_KNOWN_START, "single": MODE_SINGLE}
_DYNAMICS = {"off": DYNAMICS_OFF, "random-walk": DYNAMICS_RANDOM_WALK, "constant-velocity": DYNAMICS_CONSTANT_VELOCITY}
_AR_MODES = {"off": AR_OFF, "continuous": AR_CONTINUOUS, "instantaneous": AR_INSTANTANEOUS, "fix-and-hold": AR_FIX_AND_HOLD}

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
    # where the base position came from and its uncertainty (ppk.base_position_basis): not used by the filter,
    # carried to the solution's summary
    base_position_basis: dict = field(default_factory=dict)


@dataclass
class FilterOutput:
    status: np.ndarray              # (E,) 1 fix, 2 float, 5 single, 0 none
    position_ecef_m: np.ndarray     # (E, 3)
    covariance_ecef_m2: np.ndarray  # (E, 3, 3)
    n_sats: np.ndarray              # (E,)
    ratio: np.ndarray               # (E,)
    residuals_m: np.ndarray         # (E, S, F) post-fit DD phase residuals (NaN = unused/reference)
    n_fixed_amb: np.ndarray         # (E,)
    float_position_ecef_m: np.ndarray | None = None      # (E, 3) the float solution, fixed epochs included
    float_covariance_ecef_m2: np.ndarray | None = None   # (E, 3, 3)


class RtkFilter:
    """The filter on prepared data. Each pass runs in compiled code (rtk_kernels.filter_pass): per epoch the
    time update, slip and outage handling, ambiguity initialisation, the DD measurement update with post-fit
    residual tests, ambiguity resolution with fixed-solution validation, and fix-and-hold."""

    def __init__(self, data: PreparedData, opts: RtkOptions):
        self.d = data
        self.o = opts
        self.n_s = len(data.sat_ids)
        self.n_f = opts.n_bands
        self.n_kin = 6 if opts.dynamics == "constant-velocity" else 3
        self.nx = self.n_kin + self.n_s * self.n_f
        self.sys = np.array([s[0] for s in data.sat_ids])
        self.systems = list(np.unique(self.sys))
        self.ar_allowed = np.array([(s[0] != "R" or opts.glonass_ar) and (s[0] != "C" or opts.bds_ar) for s in data.sat_ids],
                                   dtype=bool)
        self._arrays: FilterArrays | None = None

    def arrays(self) -> FilterArrays:
        """The prepared data as the compiled pass takes them (bands limited to n_bands, contiguous, fixed dtypes:
        one compiled signature)."""
        if self._arrays is None:
            d, n_f = self.d, self.n_f
            usable = d.rover_usable[:, :, None]

            def band_slice(a):
                return np.ascontiguousarray(a[:, :, :n_f], dtype=float)

            rover_phase, rover_code = band_slice(d.rover_phase_m), band_slice(d.rover_code_m)
            base_phase, base_code = band_slice(d.base_phase_res_m), band_slice(d.base_code_res_m)
            code_ok = usable & ~np.isnan(rover_code) & ~np.isnan(base_code)
            obs_ok = code_ok & ~np.isnan(rover_phase) & ~np.isnan(base_phase)
            sys_index = {s: k for k, s in enumerate(self.systems)}
            self._arrays = FilterArrays(
                time_s=np.ascontiguousarray(d.time_s, dtype=float),
                lam=np.ascontiguousarray(d.wavelength_m[:, :n_f], dtype=float),
                rover_phase_m=rover_phase, rover_code_m=rover_code, rover_iono_m=band_slice(d.rover_iono_m),
                sat_pos=np.ascontiguousarray(np.nan_to_num(d.rover_sat_pos_ecef_m), dtype=float),
                sat_clock_m=np.ascontiguousarray(d.rover_sat_clock_m, dtype=float),
                trop_m=np.ascontiguousarray(d.rover_trop_m, dtype=float),
                trop_dh=np.ascontiguousarray(d.rover_trop_dh_m_per_m, dtype=float),
                trop_ref=np.ascontiguousarray(d.rover_trop_ref_ecef_m, dtype=float),
                up=np.ascontiguousarray(d.rover_up_unit, dtype=float),
                el=np.ascontiguousarray(d.rover_elevation_rad, dtype=float),
                base_phase_res_m=base_phase, base_code_res_m=base_code,
                age_s=np.ascontiguousarray(d.age_s, dtype=float),
                slip_cum=np.ascontiguousarray(d.slip_cum[:, :, :n_f], dtype=np.int64),
                half_cycle=np.ascontiguousarray(d.half_cycle[:, :, :n_f], dtype=bool),
                obs_ok=np.ascontiguousarray(obs_ok), code_ok=np.ascontiguousarray(code_ok),
                spp_pos=np.ascontiguousarray(d.spp_position_ecef_m, dtype=float),
                spp_cov=np.ascontiguousarray(d.spp_covariance_m2, dtype=float),
                spp_valid=np.ascontiguousarray(d.spp_valid, dtype=bool),
                sys_code=np.array([sys_index[s] for s in self.sys], dtype=np.int64),
                is_glonass=np.ascontiguousarray(self.sys == "R"), ar_allowed=np.ascontiguousarray(self.ar_allowed))
        return self._arrays

    def config(self) -> FilterConfig:
        o = self.o
        return FilterConfig(
            n_systems=len(self.systems), n_kin=self.n_kin, mode=_MODES[o.mode], dynamics=_DYNAMICS[o.dynamics],
            ar_mode=_AR_MODES[o.ar_mode], max_age_s=float(o.max_age_s), outage_reset_epochs=int(o.outage_reset_epochs),
            bias_process_noise_cyc=float(o.bias_process_noise_cyc),
            initial_bias_var_cyc2=float(o.initial_bias_sigma_cyc) ** 2,
            known_start_var_m2=float(o.known_start_sigma_m) ** 2,
            position_rw_q=float(o.position_random_walk_m_sqrt_s) ** 2, accel_q=float(o.accel_noise_h_m_s2) ** 2,
            reject_innovation_m=float(o.reject_innovation_m), ratio_threshold=float(o.ratio_threshold),
            min_success_rate=float(o.min_success_rate), ar_min_lock_epochs=int(o.ar_min_lock_epochs),
            ar_elevation_mask_rad=float(np.radians(o.ar_elevation_mask_deg)),
            ar_min_fix_to_hold=int(o.ar_min_fix_to_hold),
            hold_elevation_mask_rad=float(np.radians(o.hold_elevation_mask_deg)),
            hold_variance_cyc2=float(o.hold_variance_cyc2), ar_filter=bool(o.ar_filter),
            partial_ar=bool(o.partial_ar), partial_ar_max_drop=int(o.partial_ar_max_drop),
            partial_ar_max_float_sigma_m=float(o.partial_ar_max_float_sigma_m),
            min_ambiguities_to_fix=int(o.min_ambiguities_to_fix), phase_error_a_m=float(o.phase_error_a_m),
            phase_error_b_m=float(o.phase_error_b_m),
            code_phase_ratio=np.asarray(o.code_phase_ratio, dtype=float),
            baseline_term_m=float(o.phase_error_baseline_m_per_10km * self.d.baseline_m / 1e4),
            clock_stability=float(o.clock_stability), glonass_error_factor=float(o.glonass_error_factor))

    def run(self, backward: bool = False, known_start_ecef_m: np.ndarray | None = None) -> FilterOutput:
        use_known = known_start_ecef_m is not None
        known = np.asarray(known_start_ecef_m, dtype=float) if use_known else np.zeros(3)
        res = filter_pass(self.arrays(), self.config(), bool(backward), known, use_known)
        return FilterOutput(*res)

    def _rover_trop(self, e, pos):
        """Slant troposphere (m) per satellite at the rover position `pos` (first order in height)."""
        d = self.d
        dh = float((pos - d.rover_trop_ref_ecef_m[e]) @ d.rover_up_unit[e])
        return d.rover_trop_m[e] + d.rover_trop_dh_m_per_m[e] * dh
