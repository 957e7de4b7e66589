"""The PPK step: rover + base observations + navigation -> per-epoch trajectory with quality,
covariance and velocity. Loads, prepares (vectorised precomputation), runs the filter forward,
backward or both, and combines."""

from __future__ import annotations

import os
from pathlib import Path

import time as _time
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputFileError, ProcessingError
from .base_alignment import align_base_to_rover, base_zero_difference, ephemeris_records
from .constants import CLIGHT_M_S, N_BANDS, wavelength_table_m
from .corrections import ionosphere_delay_m, troposphere_delay_m
from .cycle_slips import doppler_slips, geometry_free_slips, lli_slips
from .fix_continuity import refuse_jumping_fixes
from .fix_precision import refuse_imprecise_fixes
from . import concurrent_pass
from .fix_witness import PhaseArbiter, refuse_contradicted_fixes
from .frames import ecef_to_enu_rotation, ecef_to_geodetic
from .gnss_time import gps_time_s_to_datetime
from .input_files import load_navigation, load_observations
from .navigation import NavigationData
from .observations import ObservationSet, RawObservations, select_bands
from .rtk_filter import STATUS_FIX, STATUS_NONE, PreparedData, RtkFilter
from .rtk_options import RtkOptions
from .satellite_geometry import compute_observed_satellites, geometric_range_m
from .smoothing import combine
from .spp import CLOCK_COLUMN, AveragedPosition, SppResult, average_spp_positions, solve_spp
from .tdcp_slips import time_differenced_slips


@dataclass
class PpkSolution:
    """Per-epoch PPK solution. time_s is GPS time of the position (receiver time tag minus the
    receiver clock bias, as RTKLIB reports it)."""

    time_s: np.ndarray
    receiver_time_s: np.ndarray
    status: np.ndarray                 # 1 fix, 2 float, 5 single, 0 none
    position_ecef_m: np.ndarray        # (E, 3)
    covariance_ecef_m2: np.ndarray     # (E, 3, 3)
    velocity_ecef_m_s: np.ndarray      # (E, 3)
    velocity_covariance_m2_s2: np.ndarray
    n_sats: np.ndarray
    ratio: np.ndarray
    age_s: np.ndarray
    residuals_m: np.ndarray            # (E, S, F) DD phase post-fit residuals
    sat_ids: list[str]
    base_position_ecef_m: np.ndarray
    options: RtkOptions
    event_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    fix_conflicts: np.ndarray | None = None
    # where the base position came from and its uncertainty (base_position_basis): every PPK position shares
    # the base position's error
    base_position_basis: dict = field(default_factory=dict)
    input_paths: dict[str, list[str]] = field(default_factory=dict)
    # rover and base receiver/antenna models as their files state them (receiver_equipment.py)
    equipment: dict[str, dict] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def fix_rate(self) -> float:
        valid = self.status != STATUS_NONE
        return float(np.mean(self.status[valid] == STATUS_FIX)) if valid.any() else 0.0


def reindex_satellites(obs: ObservationSet, sat_ids: list[str]) -> ObservationSet:
    """Observation arrays on another satellite list (missing satellites are NaN)."""
    pos = {s: i for i, s in enumerate(obs.sat_ids)}
    src = np.array([pos.get(s, -1) for s in sat_ids])
    have = src >= 0

    def take(a, fill):
        out = np.full((a.shape[0], len(sat_ids)) + a.shape[2:], fill, dtype=a.dtype)
        out[:, have] = a[:, src[have]]
        return out

    return ObservationSet(obs.source_path, obs.gps_time_s, list(sat_ids), take(obs.code_m, np.nan),
                          take(obs.phase_cyc, np.nan), take(obs.doppler_hz, np.nan), take(obs.snr_dbhz, np.nan),
                          take(obs.lli, 0), take(obs.signal_codes, 0), obs.signal_names, obs.header, obs.event_gps_time_s)


def _header_position_source(header) -> str:
    """Where a receiver header's approximate position came from: approx_position_source, or for a header
    that does not say (readers older than the field) 'rinex-header' when it was read from RINEX."""
    if header.approx_position_source:
        return header.approx_position_source
    return "rinex-header" if header.rinex_version is not None else ""


def _header_position_is_surveyed(header) -> bool:
    """A header position that stands for the base's station coordinates (RINEX APPROX POSITION XYZ, an RTCM
    station record, or a header of unstated origin, as before), not the receiver's own metre-level fixes."""
    return header.approx_position_ecef_m is not None and _header_position_source(header) != "receiver-fixes"


def _averaged_spp_note(path: str, avg: AveragedPosition, receiver_fix: np.ndarray | None) -> str:
    def enu(v):
        return "/".join(f"{x:.2f}" for x in v)

    text = (f"{path}: no base position given (--base-pos) nor in a RINEX header; using the averaged single-point "
            f"position of the base log: the weighted mean of {avg.n_used} of {avg.n_epochs} epochs"
            f"{f' ({avg.n_rejected} beyond the chi-square bound dropped)' if avg.n_rejected else ''} over "
            f"{avg.span_s / 60:.0f} min. Scatter of single epochs E/N/U {enu(avg.scatter_enu_m)} m; sigma of the "
            f"mean E/N/U {enu(avg.sigma_mean_enu_m)} m (the scatter over the square root of {avg.n_independent} "
            f"independent {avg.block_s:.0f} s blocks: epochs are time-correlated, so the formal "
            f"{enu(avg.formal_sigma_mean_enu_m)} m is optimistic; errors of the broadcast ionosphere and "
            "troposphere models common to all epochs are not in it). A single-point position is metre-level: the "
            "whole trajectory shifts by its error. Give --base-pos with a surveyed position.")
    if receiver_fix is not None:
        text += (f" (The receiver's own fixes in the log, not used, lie "
                 f"{np.linalg.norm(receiver_fix - avg.position_ecef_m):.1f} m from it.)")
    return text


# The uncertainty of a base position that is not surveyed, beyond what its own data show. An averaged
# single-point position carries the broadcast ionosphere, troposphere, orbit and clock errors common to all
# its epochs, which averaging does not reduce: taken as 1 m horizontally and 2 m vertically (an assumption of
# order of magnitude for single-frequency broadcast models, added in quadrature to the sigma of the mean; on
# the shared u-blox walk the averaged base was 2.8 m from its surveyed position). A receiver's own navigation
# fixes: 2.5 m horizontally, 5 m vertically (a standalone receiver's usual specification, 2.5 m CEP).
SPP_COMMON_SIGMA_ENU_M = (1.0, 1.0, 2.0)
RECEIVER_FIX_SIGMA_ENU_M = (2.5, 2.5, 5.0)


def base_position_basis(source: str, sigma_enu_m=None, text: str = "") -> dict:
    """What the summary says of the base position: its source ('given', 'rinex-header', 'rtcm-station',
    'averaged-single-point', 'receiver-fixes'), its 1-sigma E/N/U uncertainty when Georef can state one (None
    for a surveyed or given position: its accuracy is the survey's) and a sentence."""
    return {"source": source, "sigma_enu_m": None if sigma_enu_m is None else [round(float(v), 3) for v in sigma_enu_m],
            "text": text}


def _base_position(base: ObservationSet, opts: RtkOptions, base_spp: SppResult | None
                   ) -> tuple[np.ndarray, list[str], dict]:
    """The base antenna position, from the best source available: --base-pos > the header's position (RINEX
    APPROX POSITION XYZ plus ANTENNA: DELTA H/E/N, or an RTCM station record) > the averaged single-point
    solution of the base log (average_spp_positions) > the receiver's own fixes recorded in the log (UBX).
    The note names the source and the file; the basis (base_position_basis) says how uncertain it is."""
    notes = []
    header = base.header
    source = _header_position_source(header)
    receiver_fix = (np.array(header.approx_position_ecef_m, dtype=float)
                    if header.approx_position_ecef_m is not None and source == "receiver-fixes" else None)
    avg = None
    if opts.base_position_ecef_m is None and not _header_position_is_surveyed(header) and base_spp is not None:
        avg = average_spp_positions(base.gps_time_s, base_spp.position_ecef_m, base_spp.covariance_ecef_m2,
                                    base_spp.valid)
    if opts.base_position_ecef_m is not None:
        pos = np.array(opts.base_position_ecef_m, dtype=float)
        basis = base_position_basis("given", None, "the base position given in the settings (--base-pos)")
    elif _header_position_is_surveyed(header):
        pos = np.array(header.approx_position_ecef_m, dtype=float)
        # the header position is the marker; the antenna reference point is ANTENNA: DELTA H/E/N above it
        h, east, north = (float(v) for v in header.antenna_delta_hen_m)
        if h or east or north:
            lat, lon, _ = ecef_to_geodetic(pos)
            pos = pos + ecef_to_enu_rotation(lat, lon).T @ np.array([east, north, h])
        where = {"rinex-header": "the RINEX header",
                 "rtcm-station": "the reference station record (RTCM 3 1005/1006)"}.get(source, "the header")
        notes.append(f"base position taken from {where} of {base.source_path}"
                     + (f" (plus its antenna delta H/E/N {h:.4f}/{east:.4f}/{north:.4f} m)" if h or east or north else ""))
        basis = base_position_basis(source or "rinex-header", None,
                                    f"the base position in {where} of {Path(base.source_path).name}, taken as "
                                    "surveyed (its accuracy is the survey's)")
    elif avg is not None:
        pos = avg.position_ecef_m.copy()
        notes.append(_averaged_spp_note(base.source_path, avg, receiver_fix))
        sigma = np.hypot(avg.sigma_mean_enu_m, SPP_COMMON_SIGMA_ENU_M)
        basis = base_position_basis("averaged-single-point", sigma,
                                    f"an averaged single-point position of the base log {Path(base.source_path).name}"
                                    " (not surveyed)")
    elif receiver_fix is not None:
        pos = receiver_fix
        basis = base_position_basis("receiver-fixes", RECEIVER_FIX_SIGMA_ENU_M,
                                    f"the base receiver's own navigation fixes in {Path(base.source_path).name} "
                                    "(not surveyed)")
        notes.append(f"{base.source_path}: no base position given (--base-pos) nor in a RINEX header, and no "
                     "single-point solution of the base log; using the median of the receiver's own navigation fixes "
                     "recorded in the log (metre-level, not a surveyed position: the whole trajectory shifts by its "
                     "error). Give --base-pos.")
    else:
        raise ProcessingError(f"{base.source_path}: the base position is unknown (not given, not in the header, "
                              "and no single-point solution); give --base-pos")
    if any(opts.base_antenna_delta_enu_m):
        lat, lon, _ = ecef_to_geodetic(pos)
        pos = pos + ecef_to_enu_rotation(lat, lon).T @ np.asarray(opts.base_antenna_delta_enu_m)
    return pos, notes, basis


def _unflagged_slips(rover, rsat, position_ecef_m, trop_m, iono_m, lam, base_phase_res_m, flagged, sat_ids,
                     threshold_m):
    """Slips neither receiver flagged, from the time-differenced single-difference phase (tdcp_slips)."""
    rng, los = geometric_range_m(np.nan_to_num(rsat.position_ecef_m), position_ecef_m[:, None, :])
    model = rng - CLIGHT_M_S * np.nan_to_num(rsat.clock_bias_s) + trop_m
    sd = rover.phase_cyc * lam[None] - (model[..., None] - iono_m) - base_phase_res_m
    sd[~rsat.valid] = np.nan
    systems = sorted({s[0] for s in sat_ids})
    sys_code = np.array([systems.index(s[0]) for s in sat_ids], dtype=np.int64)
    return time_differenced_slips(rover.gps_time_s, sd, los, sys_code, flagged, threshold_m)


def prepare(rover_raw: RawObservations, base_raw: RawObservations, nav: NavigationData, opts: RtkOptions):
    """Vectorised precomputation shared by the forward and backward passes."""
    timings = {}
    t0 = _time.perf_counter()
    rover = select_bands(rover_raw)
    base = select_bands(base_raw)
    if len(rover.gps_time_s) == 0:
        raise ProcessingError(f"{rover.source_path}: no observation epochs")
    if len(base.gps_time_s) == 0:
        raise ProcessingError(f"{base.source_path}: no observation epochs")
    overlap = min(rover.gps_time_s[-1], base.gps_time_s[-1]) - max(rover.gps_time_s[0], base.gps_time_s[0])
    if overlap < -opts.max_age_s:
        gap = -overlap
        gap_text = f"{gap / 86400:.1f} days" if gap > 86400 else f"{gap:.0f} s"
        raise ProcessingError(f"rover {rover.source_path} and base {base.source_path} do not overlap in time "
                              f"(gap {gap_text})")
    sat_ids = sorted(set(rover.sat_ids) | set(base.sat_ids))
    sat_ids = [s for s in sat_ids if s[0] in opts.systems and s not in opts.excluded_sats]
    common = set(rover.sat_ids) & set(base.sat_ids) & set(sat_ids)
    if not common:
        raise ProcessingError(f"rover {rover.source_path} and base {base.source_path} share no satellite of the "
                              f"selected systems ({','.join(opts.systems)})")
    rover = reindex_satellites(rover, sat_ids)
    base = reindex_satellites(base, sat_ids)
    fcn = {**base.header.glonass_fcn, **rover.header.glonass_fcn, **nav.glonass_fcn()}
    lam = wavelength_table_m(sat_ids, fcn)
    timings["select"] = _time.perf_counter() - t0

    t0 = _time.perf_counter()
    rsat = compute_observed_satellites(rover, nav)
    bsat = compute_observed_satellites(base, nav)
    if not rsat.valid.any():
        raise ProcessingError(f"no navigation data for the epochs of {rover.source_path} "
                              f"({', '.join(nav.source_paths) or 'no navigation file'}): no satellite position could be computed")
    timings["orbits"] = _time.perf_counter() - t0

    t0 = _time.perf_counter()
    spp = solve_spp(rover, rsat, nav, opts, rover.header.approx_position_ecef_m)
    if not spp.valid.any():
        raise ProcessingError(f"{rover.source_path}: no epoch has a single-point solution (too few satellites "
                              "with navigation data above the elevation mask)")
    base_spp = None
    if opts.base_position_ecef_m is None and not _header_position_is_surveyed(base.header):
        # start from the receiver's own fixes, else the rover (within max_baseline_km): the SPP kernel needs
        # a start away from the Earth's centre
        start = base.header.approx_position_ecef_m
        if start is None:
            start = np.median(spp.position_ecef_m[spp.valid], axis=0)
        base_spp = solve_spp(base, bsat, nav, opts, start)
    base_pos, notes, base_basis = _base_position(base, opts, base_spp)
    baseline_m = float(np.median(np.linalg.norm(spp.position_ecef_m[spp.valid] - base_pos, axis=1)))
    if baseline_m > opts.max_baseline_km * 1e3:
        raise ProcessingError(f"base {base.source_path} is {baseline_m / 1e3:.0f} km from the rover (limit "
                              f"{opts.max_baseline_km:.0f} km): wrong base file or wrong base position?")
    timings["spp"] = _time.perf_counter() - t0

    t0 = _time.perf_counter()
    dd_iono = opts.ionosphere if opts.dd_ionosphere else "off"
    b_phase, b_code, b_el = base_zero_difference(base, bsat, nav, base_pos, lam, opts.troposphere, dd_iono,
                                                 opts.dd_troposphere_humidity)
    # a base residual computed with another broadcast record than the rover epoch's carries the records'
    # discontinuity (a record change inside a base gap): left out there (base_alignment.py)
    records = (ephemeris_records(nav, sat_ids, base.gps_time_s), ephemeris_records(nav, sat_ids, rover.gps_time_s))
    aligned = align_base_to_rover(rover.gps_time_s, base, b_phase, b_code, b_el, opts.max_age_s, opts.base_interpolation,
                                  records=records)
    timings["base"] = _time.perf_counter() - t0

    t0 = _time.perf_counter()
    # rover atmosphere at the single-point position (the troposphere is corrected to the filter's height below)
    spp_pos = spp.position_ecef_m.copy()
    fill = np.median(spp_pos[spp.valid], axis=0)   # (np.nanmedian with an axis: 0.25 ms)
    spp_pos[~spp.valid] = fill
    llh = ecef_to_geodetic(spp_pos)
    el = np.where(spp.valid[:, None], spp.elevation_rad, aligned.elevation_rad)
    el = np.nan_to_num(el, nan=-1.0)
    az = spp.azimuth_rad
    trop, _ = troposphere_delay_m(opts.troposphere, llh[:, 0:1], llh[:, 2:3], np.maximum(el, 0.01),
                                  opts.dd_troposphere_humidity)
    # the single-point height is metres off; the filter corrects the delay to its own height with this
    # derivative (hydrostatic delay changes ~0.3 mm/m at zenith, ~1.2 mm/m at 15 degrees)
    trop_up, _ = troposphere_delay_m(opts.troposphere, llh[:, 0:1], llh[:, 2:3] + 1.0, np.maximum(el, 0.01),
                                     opts.dd_troposphere_humidity)
    trop_dh = trop_up - trop
    up = np.stack([np.cos(llh[:, 0]) * np.cos(llh[:, 1]), np.cos(llh[:, 0]) * np.sin(llh[:, 1]), np.sin(llh[:, 0])], axis=1)
    iono = np.zeros(rover.code_m.shape)
    for b in range(N_BANDS):
        iono[..., b], _ = ionosphere_delay_m(dd_iono, nav, rover.gps_time_s[:, None], llh[:, 0:1], llh[:, 1:2], az,
                                             np.maximum(el, 0.01), lam[None, :, b])
    usable = rsat.valid & (el >= np.radians(opts.elevation_mask_deg))
    if opts.snr_mask_dbhz > 0:
        usable &= ~(rover.snr_dbhz[..., 0] < opts.snr_mask_dbhz)
    slips = lli_slips(rover.lli, rover.phase_cyc) | aligned.slip_into
    slips |= geometry_free_slips(rover.phase_cyc, lam, opts.slip_gf_threshold_m)
    slips |= doppler_slips(rover.phase_cyc, rover.doppler_hz, rover.gps_time_s, opts.slip_doppler_threshold_cyc)
    if opts.slip_tdcp_threshold_m > 0:
        slips |= _unflagged_slips(rover, rsat, spp_pos, trop, iono, lam, aligned.phase_res_m, slips, sat_ids,
                                  opts.slip_tdcp_threshold_m)
    slip_cum = np.zeros((len(rover.gps_time_s) + 1,) + slips.shape[1:], dtype=np.int32)
    np.cumsum(slips, axis=0, out=slip_cum[1:])
    half = (rover.lli & 2).astype(bool) | aligned.half_cycle
    data = PreparedData(
        time_s=rover.gps_time_s, sat_ids=sat_ids, wavelength_m=lam,
        rover_phase_m=rover.phase_cyc * lam[None], rover_code_m=rover.code_m,
        rover_sat_pos_ecef_m=rsat.position_ecef_m, rover_sat_clock_m=CLIGHT_M_S * np.nan_to_num(rsat.clock_bias_s),
        rover_trop_m=trop, rover_trop_dh_m_per_m=trop_dh, rover_trop_ref_ecef_m=spp_pos, rover_up_unit=up,
        rover_iono_m=iono, rover_elevation_rad=el, rover_usable=usable,
        base_phase_res_m=aligned.phase_res_m, base_code_res_m=aligned.code_res_m, age_s=aligned.age_s,
        slip_cum=slip_cum, half_cycle=half, spp_position_ecef_m=spp.position_ecef_m,
        spp_covariance_m2=spp.covariance_ecef_m2, spp_valid=spp.valid, baseline_m=baseline_m,
        base_position_basis=base_basis)
    timings["prepare"] = _time.perf_counter() - t0
    return data, spp, base_pos, notes, timings, rover


def _velocities(time_s, pos, cov, status, spp: SppResult):
    """Central differences of fixed positions (mm/s) where both neighbours are fixed and close in time;
    Doppler velocities elsewhere."""
    vel = spp.velocity_ecef_m_s.copy()
    vcov = spp.velocity_covariance_m2_s2.copy()
    n = len(time_s)
    if n >= 3:
        dt_nominal = float(np.median(np.diff(time_s)))
        a, b = np.arange(0, n - 2), np.arange(2, n)
        dt = time_s[b] - time_s[a]
        ok = (status[a] == STATUS_FIX) & (status[b] == STATUS_FIX) & (dt <= 2.5 * dt_nominal) & (dt > 0)
        mid = a[ok] + 1
        vel[mid] = (pos[b[ok]] - pos[a[ok]]) / dt[ok, None]
        vcov[mid] = (cov[b[ok]] + cov[a[ok]]) / (dt[ok, None, None] ** 2)
    return vel, vcov


def solve(rover_raw: RawObservations, base_raw: RawObservations, nav: NavigationData, opts: RtkOptions,
          progress=None) -> PpkSolution:
    """Single-threaded BLAS: the filter's matrices are small (~100-300), and a threaded BLAS on a busy
    machine makes each solve an order of magnitude slower (measured 17x on 2 cores). ``progress(stage, done,
    total)``: before each stage (of 4, reading the files being the first: solve_files)."""
    with _blas_controller().limit(limits=1, user_api="blas"):
        return _solve(rover_raw, base_raw, nav, opts, progress)


_BLAS_CONTROLLER = None


def _blas_controller():
    """threadpoolctl's view of the loaded BLAS libraries (numpy's, and scipy's that the compiled kernels
    call), built once: scanning the process's libraries costs ~1 ms per solve."""
    global _BLAS_CONTROLLER
    if _BLAS_CONTROLLER is None:
        # load scipy's BLAS before the scan; the submodules by their full names, so that tables the CLI loaded
        # alone (cli/numba_start.py) are used as they are, without scipy.linalg's package __init__
        import scipy.linalg.cython_blas  # noqa: F401
        import scipy.linalg.cython_lapack  # noqa: F401
        from threadpoolctl import ThreadpoolController

        _BLAS_CONTROLLER = ThreadpoolController()
    return _BLAS_CONTROLLER


def _solve(rover_raw: RawObservations, base_raw: RawObservations, nav: NavigationData, opts: RtkOptions,
           progress=None) -> PpkSolution:
    opts.validate()
    if progress:
        progress("orbits, single point positions, slips", 1, 4)
    data, spp, base_pos, notes, timings, rover = prepare(rover_raw, base_raw, nav, opts)
    flt = RtkFilter(data, opts)
    known = np.asarray(opts.known_start_position_ecef_m, dtype=float) if opts.mode == "known-start" else None
    t0 = _time.perf_counter()
    conflicts = None
    arrays, config = flt.arrays(), flt.config()

    def filtered(backward: bool, start):
        # fixes the carrier phase contradicts (a jump against the neighbouring fixes) get their float back
        return refuse_jumping_fixes(arrays, config, flt.run(backward=backward, known_start_ecef_m=start))[0]

    def run_pass(backward: bool, start, stage: int = 2, role: str = ""):
        if progress:
            progress(f"Kalman filter, {'backward' if backward else 'forward'} pass{role}", stage, 4)
        return filtered(backward, start)

    def backward_start(fwd):
        """known-start: the backward pass starts from the forward pass's last fixed position."""
        if known is None:
            return None
        fixed = np.nonzero(fwd.status == STATUS_FIX)[0]
        return fwd.position_ecef_m[fixed[-1]] if len(fixed) else None

    def two_passes(first_backward: bool, role: str):
        """The first pass and the second (the other direction), the second in a forked child on another
        core while this process runs the first when the two are independent and the solve is big enough
        (concurrent_pass.py: the same arrays either way)."""
        second_start = known if first_backward else None
        independent = first_backward or known is None
        second = None
        if independent and concurrent_pass.worth_forking(int(data.rover_usable.size) * opts.n_bands):
            second = concurrent_pass.ForkedPass(lambda: filtered(not first_backward, second_start))
        try:
            first = run_pass(first_backward, None if first_backward else known)
            if second is None:
                return first, run_pass(not first_backward, second_start if first_backward else backward_start(first),
                                       3, role)
            if progress:
                progress(f"Kalman filter, {'forward' if first_backward else 'backward'} pass{role}", 3, 4)
            return first, second.result()
        finally:
            if second is not None:
                second.cancel()

    arbiter = PhaseArbiter(data, opts)
    if opts.filter_direction == "combined":
        fwd, bwd = two_passes(False, "")
        out, conflicts = combine(fwd, bwd, arbiter)
        # the two passes' fixes side by side can jump where the combination changes pass
        out = refuse_jumping_fixes(arrays, config, out)[0]
    elif opts.filter_direction == "forward":
        if opts.reverse_witness:
            # the fixes the backward pass contradicts are not output as fixed (fix_witness.py)
            out, witness = two_passes(False, " (witness)")
            out, conflicts = refuse_contradicted_fixes(out, witness, arbiter)
        else:
            out = run_pass(False, known)
    else:
        if opts.reverse_witness:
            out, witness = two_passes(True, " (witness)")
            out, conflicts = refuse_contradicted_fixes(out, witness, arbiter)
        else:
            out = run_pass(True, None)
    # a fix whose position the geometry leaves decimetre-level is not output as fixed (fix_precision.py)
    out, n_imprecise = refuse_imprecise_fixes(out, opts.fix_max_sigma_m)
    if n_imprecise:
        notes.append(f"{n_imprecise} fixed epoch(s) output as float: their fixed position's formal 3-D sigma "
                     f"exceeds {opts.fix_max_sigma_m:g} m (too few satellites for a centimetre position)")
    timings["filter"] = _time.perf_counter() - t0
    clock_g = spp.clock_bias_m[:, CLOCK_COLUMN["G"]] if spp.clock_bias_m.size else np.zeros(len(data.time_s))
    clock_g = np.where(spp.valid, clock_g, np.nan)
    if np.isfinite(clock_g).any():
        idx = np.arange(len(clock_g))
        good = np.isfinite(clock_g)
        clock_g = np.interp(idx, idx[good], clock_g[good])
    else:
        clock_g = np.zeros(len(data.time_s))
    true_time = data.time_s - clock_g / CLIGHT_M_S
    vel, vcov = _velocities(true_time, out.position_ecef_m, out.covariance_ecef_m2, out.status, spp)
    sol = PpkSolution(
        time_s=true_time, receiver_time_s=data.time_s, status=out.status, position_ecef_m=out.position_ecef_m,
        covariance_ecef_m2=out.covariance_ecef_m2, velocity_ecef_m_s=vel, velocity_covariance_m2_s2=vcov,
        n_sats=out.n_sats, ratio=out.ratio, age_s=data.age_s, residuals_m=out.residuals_m, sat_ids=data.sat_ids,
        base_position_ecef_m=base_pos, options=opts, event_time_s=np.asarray(rover.event_gps_time_s, dtype=float),
        fix_conflicts=conflicts, base_position_basis=data.base_position_basis, input_paths={"rover": [rover_raw.source_path], "base": [base_raw.source_path],
                                              "nav": list(nav.source_paths)},
        warnings=notes, timings_s=timings)
    return sol


def _observation_window_gps_s(*observations: RawObservations) -> tuple[float, float] | None:
    """First and last epoch over the receivers' observations (None when none has an epoch)."""
    times = [o.gps_time_s for o in observations if len(o.gps_time_s)]
    if not times:
        return None
    return float(min(t.min() for t in times)), float(max(t.max() for t in times))


def _utc_text(gps_time_s: float) -> str:
    return f"{gps_time_s_to_datetime(gps_time_s):%Y-%m-%d %H:%M}"


def _as_paths(p) -> list:
    return [p] if isinstance(p, (str, bytes, os.PathLike)) else list(p)


def load_receiver(paths, role: str, approx_gps_time_s: float | None = None, event_edge: str = "falling"):
    """One receiver's observations from one or several files (flights, hourly files), joined in time
    order, with the navigation data the files carry and notes on gaps. ``role`` names it in messages."""
    from .input_files import LoadedObservations
    from .observations import join_observations

    paths = _as_paths(paths)
    if not paths:
        raise ProcessingError(f"no {role} observation file")
    import warnings

    # what the readers warn about (a file cut inside an epoch record, ...) reaches the solution's warnings,
    # and through them the step summary and the UI, not only the console
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        loaded = [load_observations(p, approx_gps_time_s, event_edge) for p in paths]
    read_notes = list(dict.fromkeys(f"{role}: {w.message}" for w in caught if issubclass(w.category, UserWarning)))
    for w in caught:
        if not issubclass(w.category, UserWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if len(loaded) == 1:
        return loaded[0], read_notes
    raw, notes = join_observations([x.observations for x in loaded])
    if role == "base" and any("header positions differ" in n for n in notes):
        raise InputFileError(paths[0], f"the base files {', '.join(Path(p).name for p in paths)} are not from one "
                                       f"station: {next(n for n in notes if 'header positions' in n)}")
    nav = None
    for x in loaded:
        if x.navigation is not None:
            nav = x.navigation if nav is None else nav.merge(x.navigation)
    notes = read_notes + [f"{role}: {len(paths)} files joined" + (f" ({'; '.join(notes)})" if notes else "")]
    return LoadedObservations(raw, nav, "joined"), notes


def solve_files(rover_path, base_path, nav_paths, opts: RtkOptions,
                approx_gps_time_s: float | None = None, progress=None) -> PpkSolution:
    """Load the files (RINEX 2/3 in any packing, UBX or RTCM 3; a rover or base of several files is joined
    in time order) and solve. ``approx_gps_time_s`` dates a rover RTCM 3 stream without ephemerides (e.g.
    the first exposure of a DJI MRK)."""
    t0 = _time.perf_counter()
    if progress:
        progress("reading the files", 0, 4)
    rover, rover_notes = load_receiver(rover_path, "rover", approx_gps_time_s, opts.ubx_event_edge)
    first = float(rover.observations.gps_time_s[0]) if rover.observations.n_epochs else None
    base, base_notes = load_receiver(base_path, "base", first)
    window = _observation_window_gps_s(rover.observations, base.observations)
    nav = load_navigation(list(nav_paths), window) if nav_paths else NavigationData()
    for extra in (rover.navigation, base.navigation):
        if extra is not None:
            nav = nav.merge(extra)
    if nav.n_records == 0 and nav.records_outside_window and window is not None:
        a, b = nav.record_span_gps_s
        raise ProcessingError(f"no navigation data for the epochs of {rover_path} ({_utc_text(window[0])} to "
                              f"{_utc_text(window[1])} GPST): the records of {', '.join(map(str, nav_paths))} span "
                              f"{_utc_text(a)} to {_utc_text(b)}")
    if nav.n_records == 0:
        named = ", ".join(Path(p).name for p in _as_paths(rover_path) + _as_paths(base_path))
        raise InputFileError(nav_paths[0] if nav_paths else _as_paths(rover_path)[0],
                             f"no navigation data: the observation files ({named}) carry no ephemerides"
                             + (" and the navigation files hold none" if nav_paths else
                                " and no navigation file was given (add the RINEX navigation file of the day, "
                                "e.g. the base's .nav or a CORS BRDC file)"))
    load_s = _time.perf_counter() - t0
    sol = solve(rover.observations, base.observations, nav, opts, progress)
    sol.warnings[:0] = rover_notes + base_notes
    from .receiver_equipment import equipment_of_loaded

    sol.equipment = {"rover": equipment_of_loaded(rover, _as_paths(rover_path)),
                     "base": equipment_of_loaded(base, _as_paths(base_path))}
    sol.timings_s["load"] = load_s
    return sol
