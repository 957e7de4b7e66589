"""Base-station observations brought to the rover's epochs.

The base position is known, so its zero-difference residuals (observation minus geometric range,
satellite clock and atmosphere, all computed at the base's own epoch) change only slowly: the base
receiver clock (common to all satellites, it cancels in double differences), the atmosphere and the
broadcast clock error. Following the "simulated master observations" of Eling et al. (2014), the
residuals are interpolated linearly between the base epochs that bracket a rover epoch (base at 1 Hz,
rover at 5-10 Hz, base gaps), or taken from the latest older base epoch when a cycle slip lies between
the two. Without interpolation each rover epoch takes the nearest base epoch, older or newer (RTKLIB
demo5's pairing). The age of corrections is the distance to the nearest base epoch used.

Receivers time-tag their epochs on their own clocks: a u-blox rover at x.987 s and its base at x.990 s
observe "the same" epoch. A base epoch up to SYNC_TOLERANCE_S after a rover epoch is therefore used as
that epoch's own (RTKLIB's DTTOL, 25 ms); before, a 1 ms tolerance sent such a rover epoch to the base
epoch before, seconds older.

Broadcast ephemeris records change at fixed times (GLONASS every 30 min, GPS every 2 h): the base residual of
a satellite carries the orbit and clock of the record selected at the base epoch, the rover's those of the
record at the rover epoch. Where the two differ (a base gap across the change, or a rover epoch between two
base epochs that straddle it) the single difference carries the records' discontinuity, 0.03-0.53 m on the
GLONASS satellites of the simulated cases at 08:30:18 GPST (bench/gnss_stale_base.py). With ``records``
(ephemeris_records of the base and of the rover epochs) align_base_to_rover leaves such a satellite without
base data at those rover epochs (no data rather than a biased one).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .constants import CLIGHT_M_S
from .corrections import ionosphere_delay_m, troposphere_delay_m
from .cycle_slips import lli_slips
from .ephemeris import _select_many
from .frames import azimuth_elevation_batch
from .navigation import NavigationData
from .observations import ObservationSet
from .satellite_geometry import ObservedSatellites, geometric_range_m


SYNC_TOLERANCE_S = 0.025
# nominal signal travel time: the engine selects a satellite's record at the transmission time (satellite_geometry),
# about 67-90 ms before the reception time for GPS and GLONASS; only epochs within ~15 ms of a record change
# can be assigned to the other record by this approximation
NOMINAL_TRANSIT_S = 0.075


@dataclass
class BaseResiduals:
    """Base zero-difference residuals (m) on the rover's epochs and satellite list."""

    phase_res_m: np.ndarray     # (E, S, F) NaN where unusable
    code_res_m: np.ndarray      # (E, S, F)
    elevation_rad: np.ndarray   # (E, S)
    slip_into: np.ndarray       # (E, S, F) bool: a base cycle slip occurred before this rover epoch
    half_cycle: np.ndarray      # (E, S, F) bool: base half-cycle ambiguity unresolved
    snr_dbhz: np.ndarray        # (E, S, F)
    age_s: np.ndarray           # (E,) age of corrections; NaN where no base data within max age


def base_zero_difference(base: ObservationSet, sats: ObservedSatellites, nav: NavigationData,
                         base_ecef_m: np.ndarray, lam: np.ndarray, troposphere: str, ionosphere: str,
                         humidity: float = 0.0):
    """Residuals phase (m) and code (m) of the base at its own epochs, plus elevation."""
    n_e = len(base.gps_time_s)
    rcv = np.broadcast_to(base_ecef_m, (n_e, 3))
    rng, los = geometric_range_m(np.nan_to_num(sats.position_ecef_m), rcv[:, None, :])
    az, el, llh = azimuth_elevation_batch(rcv, los)
    trop, _ = troposphere_delay_m(troposphere, llh[:, 0:1], llh[:, 2:3], el, humidity)
    geo = rng - CLIGHT_M_S * sats.clock_bias_s + trop
    phase = np.full(base.phase_cyc.shape, np.nan)
    code = np.full(base.code_m.shape, np.nan)
    for b in range(base.phase_cyc.shape[2]):
        iono, _ = ionosphere_delay_m(ionosphere, nav, base.gps_time_s[:, None], llh[:, 0:1], llh[:, 1:2], az, el, lam[None, :, b])
        phase[..., b] = base.phase_cyc[..., b] * lam[None, :, b] - (geo - iono)
        code[..., b] = base.code_m[..., b] - (geo + iono)
    invalid = ~sats.valid
    phase[invalid] = np.nan
    code[invalid] = np.nan
    return phase, code, el


def ephemeris_records(nav: NavigationData, sat_ids: list[str], t_rx_s: np.ndarray) -> np.ndarray:
    """(E, S) index of the broadcast record selected for each satellite at each reception time (at the nominal
    transmission time t - NOMINAL_TRANSIT_S; -1 where none): what align_base_to_rover compares."""
    t = np.ascontiguousarray(np.asarray(t_rx_s, dtype=float) - NOMINAL_TRANSIT_S)
    out = np.full((len(t), len(sat_ids)), -1, dtype=np.int64)
    for s, sat in enumerate(sat_ids):
        out[:, s] = _select_many(nav, sat, t, True)[1]
    return out


def align_base_to_rover(rover_time_s: np.ndarray, base: ObservationSet, phase_res: np.ndarray,
                        code_res: np.ndarray, el: np.ndarray, max_age_s: float, interpolate: bool,
                        records: tuple[np.ndarray, np.ndarray] | None = None) -> BaseResiduals:
    """Residuals of the base (on the base's epochs) mapped to each rover epoch; see module doc. ``records``:
    (base (Eb, S), rover (E, S)) ephemeris record indices (ephemeris_records); a satellite whose base epoch(s)
    used for a rover epoch have another record than the rover epoch gets no base residual there."""
    tb = base.gps_time_s
    n_r = len(rover_time_s)
    shape = (n_r,) + phase_res.shape[1:]
    out_phase = np.full(shape, np.nan)
    out_code = np.full(shape, np.nan)
    out_el = np.full(shape[:2], np.nan)
    slip_into = np.zeros(shape, dtype=bool)
    half = np.zeros(shape, dtype=bool)
    snr = np.full(shape, np.nan)
    age = np.full(n_r, np.nan)
    if len(tb) == 0:
        return BaseResiduals(out_phase, out_code, out_el, slip_into, half, snr, age)
    used0 = np.full(n_r, -1, dtype=np.int64)     # base epochs used by each rover epoch (-1: none)
    used1 = np.full(n_r, -1, dtype=np.int64)
    tol = SYNC_TOLERANCE_S
    # index of the latest base epoch at or before each rover epoch (or within tol after it), and the next one
    i0 = np.searchsorted(tb, rover_time_s + tol, side="right") - 1
    i1 = i0 + 1
    have0 = i0 >= 0
    have1 = i1 < len(tb)
    i0c, i1c = np.clip(i0, 0, len(tb) - 1), np.clip(i1, 0, len(tb) - 1)
    dt0 = np.where(have0, rover_time_s - tb[i0c], np.inf)
    dt1 = np.where(have1, tb[i1c] - rover_time_s, np.inf)
    exact = have0 & (np.abs(dt0) <= tol)
    lli_slip = lli_slips(base.lli, base.phase_cyc)   # lost lock, or a half-cycle flag change
    base_half = (base.lli & 2).astype(bool)
    if not interpolate:
        e_idx, j = _nearest_epochs(tb, rover_time_s, phase_res, code_res, el, base, lli_slip, base_half, i0c, i1c,
                                   dt0, dt1, have0 & (dt0 <= max_age_s), have1 & (dt1 <= max_age_s),
                                   out_phase, out_code, out_el, slip_into, half, snr, age)
        used0[e_idx] = j
        _drop_record_mismatches(records, used0, used1, out_phase, out_code)
        return BaseResiduals(out_phase, out_code, out_el, slip_into, half, snr, age)
    for e in range(n_r):
        if not have0[e] or dt0[e] > max_age_s:
            # no older epoch: allow a slightly newer base epoch (e.g. rover starts first)
            if have1[e] and dt1[e] <= min(max_age_s, 1.0):
                j = i1c[e]
                out_phase[e], out_code[e], out_el[e] = phase_res[j], code_res[j], el[j]
                half[e], snr[e] = base_half[j], base.snr_dbhz[j]
                age[e] = dt1[e]
                used0[e] = j
            continue
        j0 = i0c[e]
        used0[e] = j0
        p, c = phase_res[j0].copy(), code_res[j0].copy()
        a = dt0[e]
        if not exact[e] and have1[e] and (dt0[e] + dt1[e]) <= max_age_s:
            j1 = i1c[e]
            w = dt0[e] / (dt0[e] + dt1[e])
            p1, c1 = phase_res[j1], code_res[j1]
            ok_p = ~np.isnan(p) & ~np.isnan(p1) & ~lli_slip[j1]
            ok_c = ~np.isnan(c) & ~np.isnan(c1)
            p[ok_p] = (1 - w) * p[ok_p] + w * p1[ok_p]
            c[ok_c] = (1 - w) * c[ok_c] + w * c1[ok_c]
            a = min(dt0[e], dt1[e])
            if w > 0:
                used1[e] = j1
        out_phase[e], out_code[e], out_el[e] = p, c, el[j0]
        half[e], snr[e] = base_half[j0], base.snr_dbhz[j0]
        age[e] = abs(a)
    # base slips: a slip flagged at base epoch j applies from the first rover epoch that uses epoch j
    first_use = np.searchsorted(rover_time_s, tb - tol, side="left")
    for j in np.nonzero(lli_slip.any(axis=(1, 2)))[0]:
        if first_use[j] < n_r:
            slip_into[first_use[j]] |= lli_slip[j]
    _drop_record_mismatches(records, used0, used1, out_phase, out_code)
    return BaseResiduals(out_phase, out_code, out_el, slip_into, half, snr, age)


def _drop_record_mismatches(records, used0, used1, out_phase, out_code) -> None:
    """Base residuals of satellites whose used base epoch(s) have another ephemeris record than the rover
    epoch: set to NaN (module doc)."""
    if records is None:
        return
    rec_base, rec_rover = (np.asarray(r) for r in records)
    if rec_base.ndim != 2 or rec_rover.shape != out_phase.shape[:2] or rec_base.shape[1] != out_phase.shape[1]:
        raise ValueError(f"ephemeris record indices of shapes {rec_base.shape} (base) and {rec_rover.shape} "
                         f"(rover) do not fit residuals of shape {out_phase.shape}")
    bad = np.zeros(out_phase.shape[:2], dtype=bool)
    for used in (used0, used1):
        e = np.nonzero(used >= 0)[0]
        bad[e] |= rec_base[used[e]] != rec_rover[e]
    out_phase[bad] = np.nan
    out_code[bad] = np.nan


def _nearest_epochs(tb, rover_time_s, phase_res, code_res, el, base, lli_slip, base_half, i0c, i1c, dt0, dt1, ok0, ok1,
                    out_phase, out_code, out_el, slip_into, half, snr, age):
    """(rover epochs served, their base epochs). Without interpolation each rover epoch takes the nearest base
    epoch, older or newer, within the maximum age (as RTKLIB demo5 pairs them); a base slip applies from the
    first rover epoch whose base epoch is at or after it."""
    use0 = ok0 & (~ok1 | (dt0 <= dt1))
    e_idx = np.nonzero(use0 | ok1)[0]
    if len(e_idx) == 0:
        return e_idx, e_idx
    j = np.where(use0, i0c, i1c)[e_idx]            # non-decreasing: the nearest epoch moves forward in time
    out_phase[e_idx], out_code[e_idx], out_el[e_idx] = phase_res[j], code_res[j], el[j]
    half[e_idx], snr[e_idx] = base_half[j], base.snr_dbhz[j]
    age[e_idx] = np.abs(np.where(use0, dt0, dt1)[e_idx])
    # slips flagged at base epochs prev+1 .. j, where prev is the base epoch of the previous rover epoch served
    cum = np.zeros((len(tb) + 1,) + lli_slip.shape[1:], dtype=np.int64)
    np.cumsum(lli_slip, axis=0, out=cum[1:])
    prev = np.concatenate(([j[0] - 1], j[:-1]))
    new = j > prev
    slip_into[e_idx[new]] |= (cum[j[new] + 1] - cum[prev[new] + 1]) > 0
    return e_idx, j
