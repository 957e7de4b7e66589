"""Single point positioning (code, L1) and Doppler velocity for every epoch of a receiver: weighted
Gauss-Newton with one receiver clock per system, elevation-dependent weights, broadcast ionosphere and a
troposphere model, and iterative rejection of outlying pseudoranges. Each epoch is solved on its own, in
compiled code (spp_kernels.py); this module prepares the arrays. ``average_spp_positions`` turns the epochs
of a static receiver (a base without a surveyed position) into one robust weighted mean with an honest sigma."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .atmosphere import klobuchar_parameters
from .atmosphere_kernels import TROPO_MODELS
from .constants import CLIGHT_M_S, wavelength_table_m
from .ephemeris import group_delay_s, select_ephemeris
from .frames import ecef_to_enu_rotation, ecef_to_geodetic
from .navigation import NavigationData
from .observations import ObservationSet
from .rtk_options import RtkOptions
from .satellite_geometry import ObservedSatellites
from .spp_kernels import N_CLOCKS, doppler_velocity, spp_all

CLOCK_COLUMN = {"G": 0, "J": 0, "R": 1, "E": 2, "C": 3}
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
    lam = wavelength_table_m(obs.sat_ids, {**obs.header.glonass_fcn, **nav.glonass_fcn()})
    tgd_m = code_group_delays_m(obs, nav)
    code = obs.code_m[..., 0] - tgd_m[None, :]
    sys_ok = np.array([s[0] in opts.systems and s not in opts.excluded_sats for s in obs.sat_ids])
    usable = sats.valid & ~np.isnan(code) & sys_ok[None, :] & ~np.isnan(lam[None, :, 0])
    if opts.snr_mask_dbhz > 0:
        usable &= ~(obs.snr_dbhz[..., 0] < opts.snr_mask_dbhz)
    sys_col = np.array([CLOCK_COLUMN.get(s[0], 0) for s in obs.sat_ids], dtype=np.int64)
    sys_fact = np.array([SPP_SYSTEM_FACTOR.get(s[0], 1.0) for s in obs.sat_ids])
    x0 = np.zeros(3 + N_CLOCKS)
    if initial_ecef_m is not None and np.all(np.isfinite(initial_ecef_m)) and np.linalg.norm(initial_ecef_m) > 1e6:
        x0[:3] = initial_ecef_m
    sat_pos = np.where(usable[..., None], sats.position_ecef_m, 0.0)
    f_a, f_b = opts.code_phase_ratio[0] * opts.phase_error_a_m, opts.code_phase_ratio[0] * opts.phase_error_b_m
    alpha, beta = klobuchar_parameters(nav.iono_gps_alpha, nav.iono_gps_beta)
    x, cov, converged_once, used, az, el = spp_all(
        np.ascontiguousarray(obs.gps_time_s, dtype=float), np.ascontiguousarray(code, dtype=float),
        np.ascontiguousarray(usable, dtype=bool), np.ascontiguousarray(sat_pos, dtype=float),
        np.ascontiguousarray(CLIGHT_M_S * np.nan_to_num(sats.clock_bias_s), dtype=float),
        np.ascontiguousarray(np.nan_to_num(sats.variance_m2), dtype=float),
        sys_col, np.ascontiguousarray(sys_fact**2, dtype=float),
        np.ascontiguousarray(np.nan_to_num(lam[:, 0], nan=1.0), dtype=float), x0,
        float(np.radians(opts.elevation_mask_deg)), float(f_a), float(f_b), TROPO_MODELS[opts.troposphere],
        opts.ionosphere != "off", np.ascontiguousarray(alpha, dtype=float), np.ascontiguousarray(beta, dtype=float),
        int(max_rejections))
    n_used = used.sum(axis=1)
    pos = x[:, :3].copy()
    gdop = np.sqrt(np.abs(np.trace(cov, axis1=1, axis2=2)))
    valid = converged_once & (n_used >= 4) & (np.linalg.norm(pos, axis=1) > 6.0e6) & (np.linalg.norm(pos, axis=1) < 6.6e6)
    pos[~valid] = np.nan
    vel, vel_cov, drift = _doppler_velocity(obs, sats, pos, used, lam, el)
    return SppResult(pos, cov[:, :3, :3], x[:, 3:], vel, vel_cov, drift, valid, n_used, used, az, el, gdop)


def _doppler_velocity(obs: ObservationSet, sats: ObservedSatellites, pos: np.ndarray, used: np.ndarray,
                      lam: np.ndarray, el: np.ndarray):
    """Receiver velocity and clock drift from band-0 Doppler, by weighted least squares (three passes,
    each dropping residuals beyond 4 sigma); spp_kernels.doppler_velocity."""
    dop = obs.doppler_hz[..., 0]
    ok = used & ~np.isnan(dop) & np.isfinite(pos[:, :1]) & sats.valid
    rate_obs = np.nan_to_num(-lam[None, :, 0] * dop)
    sigma = 0.05 + 0.1 / np.maximum(np.sin(el), 0.1)   # m/s
    def f64(a):
        return np.ascontiguousarray(a, dtype=float)

    return doppler_velocity(f64(rate_obs), np.ascontiguousarray(ok, dtype=bool), f64(np.nan_to_num(sats.position_ecef_m)),
                            f64(np.nan_to_num(sats.velocity_ecef_m_s)), f64(CLIGHT_M_S * np.nan_to_num(sats.clock_drift_s_s)),
                            f64(np.nan_to_num(pos)), f64(sigma))


# chi-square distribution with 3 degrees of freedom: median and the 99.9 % quantile
CHI2_3DOF_MEDIAN = 2.3659738843753377
CHI2_3DOF_P999 = 16.266236196238129


@dataclass
class AveragedPosition:
    """A static receiver's position from its per-epoch single-point solutions (average_spp_positions).

    The sigmas are in the local east/north/up frame at the position. ``sigma_mean_enu_m`` is the one to
    quote: the scatter of single epochs divided by the square root of the number of independent blocks
    (``n_independent``, epochs ``block_s`` apart and more are taken as independent), never below the
    formal one. ``formal_sigma_mean_enu_m`` treats every epoch as independent with its own covariance:
    optimistic, since pseudorange errors (multipath, atmosphere, orbits) are correlated over minutes."""

    position_ecef_m: np.ndarray            # (3,)
    covariance_ecef_m2: np.ndarray         # (3, 3) of the mean, matching sigma_mean_enu_m
    sigma_mean_enu_m: np.ndarray           # (3,) decorrelation-aware standard deviation of the mean
    scatter_enu_m: np.ndarray              # (3,) standard deviation of single epochs about the mean
    formal_sigma_mean_enu_m: np.ndarray    # (3,) from the epoch covariances as if independent
    n_epochs: int                          # epochs with a usable solution (finite, positive-definite covariance)
    n_used: int                            # kept after the outlier test
    n_independent: int                     # independent blocks among the kept epochs (n_eff)
    block_s: float
    span_s: float                          # first to last kept epoch
    variance_factor: float                 # robust scale of the epoch covariances (median chi-square / 2.366)
    used: np.ndarray                       # (E,) bool over the input epochs: the ones in the mean

    @property
    def n_rejected(self) -> int:
        return self.n_epochs - self.n_used


def average_spp_positions(time_s, position_ecef_m, covariance_ecef_m2, valid=None, *, block_s: float = 300.0,
                          reject_chi2: float = CHI2_3DOF_P999, max_iterations: int = 20) -> AveragedPosition | None:
    """Weighted mean of per-epoch positions (E, 3) with their covariances (E, 3, 3), robust to outliers.

    Weights are the inverse covariances. Outliers: starting from the component-wise median, an epoch whose
    squared Mahalanobis distance from the current mean exceeds ``reject_chi2`` (chi-square, 3 degrees of
    freedom, 99.9 %) times the variance factor is dropped, the factor being the median distance over all
    epochs divided by the chi-square median (the SPP covariances are formal: their scale is not trusted);
    mean and test are iterated until the kept set no longer changes. None when no epoch is usable."""
    t = np.asarray(time_s, dtype=float).reshape(-1)
    p = np.asarray(position_ecef_m, dtype=float).reshape(-1, 3)
    c = np.asarray(covariance_ecef_m2, dtype=float).reshape(-1, 3, 3)
    ok = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(c.reshape(len(c), 9)), axis=1) & np.isfinite(t)
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool).reshape(-1)
    c_sym = 0.5 * (c + np.swapaxes(c, 1, 2))
    ok[ok] &= np.linalg.eigvalsh(c_sym[ok]).min(axis=1) > 0.0
    if not ok.any():
        return None
    ok_index = np.flatnonzero(ok)
    t, p, c = t[ok], p[ok], c_sym[ok]
    n = len(p)
    w = np.linalg.inv(c)
    center = np.median(p, axis=0)
    keep = np.ones(n, dtype=bool)

    def weighted_mean(sel):
        normal = w[sel].sum(axis=0)
        return np.linalg.solve(normal, np.einsum("eij,ej->i", w[sel], p[sel])), normal

    scale = 1.0
    normal = w.sum(axis=0)
    for _ in range(max_iterations):
        d = p - center
        q = np.einsum("ei,eij,ej->e", d, w, d)
        scale = max(float(np.median(q)) / CHI2_3DOF_MEDIAN, 1e-12)
        new = q <= reject_chi2 * scale
        if not new.any():
            new = q <= np.min(q)
        new_center, normal = weighted_mean(new)
        done = np.array_equal(new, keep) and np.linalg.norm(new_center - center) < 1e-6
        keep, center = new, new_center
        if done:
            break
    lat, lon, _ = ecef_to_geodetic(center)
    rot = ecef_to_enu_rotation(lat, lon)
    enu = (p[keep] - center) @ rot.T
    n_used = int(keep.sum())
    formal = np.sqrt(np.diag(rot @ np.linalg.inv(normal) @ rot.T))
    if n_used >= 2:
        sample_cov = enu.T @ enu / (n_used - 1)
    else:
        sample_cov = rot @ c[keep][0] @ rot.T
    scatter = np.sqrt(np.diag(sample_cov))
    t_kept = t[keep]
    blocks = np.unique(np.floor((t_kept - t_kept.min()) / block_s))
    n_eff = max(1, min(n_used, len(blocks)))
    mean_cov_enu = sample_cov / n_eff
    sigma_mean = np.sqrt(np.diag(mean_cov_enu))
    used = np.zeros(len(ok), dtype=bool)
    used[ok_index[keep]] = True
    boost = np.maximum(formal / np.maximum(sigma_mean, 1e-12), 1.0)   # never below the formal sigma
    mean_cov_enu = mean_cov_enu * np.outer(boost, boost)
    return AveragedPosition(
        position_ecef_m=center, covariance_ecef_m2=rot.T @ mean_cov_enu @ rot,
        sigma_mean_enu_m=np.sqrt(np.diag(mean_cov_enu)), scatter_enu_m=scatter, formal_sigma_mean_enu_m=formal,
        n_epochs=n, n_used=n_used, n_independent=n_eff, block_s=float(block_s),
        span_s=float(t_kept.max() - t_kept.min()), variance_factor=scale, used=used)
