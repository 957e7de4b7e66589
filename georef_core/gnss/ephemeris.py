"""Broadcast ephemeris selection and evaluation: satellite position, velocity, clock and variance.

Algorithms follow RTKLIB demo5 (ephemeris.c), so that results can be compared with it:

* Kepler orbits (GPS, Galileo, QZSS, BeiDou) per IS-GPS-200 / Galileo OS-SIS-ICD / BDS-SIS-ICD, with
  the system's own gravitational constant and Earth rotation rate (QZSS uses the GPS values).
  Kepler's equation is solved by Newton iteration to 1e-13 rad (at most 30 iterations). BeiDou GEO
  satellites (C01-C05, C59-C63) are computed in their inertial-like frame, rotated by -5 degrees about
  X and by the Earth rotation since toe about Z.
* GLONASS: PZ-90 equations of motion (central term, J2, Earth rotation) plus the broadcast luni-solar
  acceleration, integrated with classical RK4 from toe to t in 60 s steps with a shorter last step,
  exactly RTKLIB's step pattern. Compiled (ephemeris_kernels.py): per call, the 60 s grid of each record
  is integrated once, so an evaluation costs one (short) RK4 step. PZ-90 is used as ITRF (no
  transformation), as in RTKLIB.
* Selection and evaluation run per satellite for all requested times at once (satellite_states).
* Velocities are analytic: the time derivative of the Kepler/GEO formulas (harmonic corrections,
  inclination rate and node rate included) and the integrated velocity for GLONASS. RTKLIB uses a
  1 ms forward difference instead (error up to ~3e-4 m/s from the orbit curvature).
* Clock bias = af0 + af1*dt + af2*dt^2 + relativistic correction -2*sqrt(mu*a)*e*sin(E)/c^2
  (GLONASS: -tau_n + gamma_n*(t - toe)); no group delay (see group_delay_s). Clock drift is the
  analytic derivative (relativistic rate included).
* Variance: RTKLIB's URA mapping (URA metres -> URA index -> upper bound of the index band, squared;
  Galileo SISA quantised per the Galileo ICD, NAPA -> (500 m)^2; GLONASS accuracy_m^2 = (5 m)^2).

Positions are ECEF at the transmission time given, in the frame of that instant: the caller applies
the Earth rotation over the signal travel time (Sagnac).

Time precision note: gps_time_s float64 values near 1.4e9 s have a resolution of 2.4e-7 s, which is up
to ~0.5 mm of along-track satellite motion; results are exact for the time value passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence, Union

import numpy as np

from .constants import (
    CLIGHT_M_S,
    FREQ_HZ,
    GM_BDS_M3_S2,
    GM_GAL_M3_S2,
    GM_GPS_M3_S2,
    OMEGA_EARTH_BDS_RAD_S,
    OMEGA_EARTH_RAD_S,
)
from .ephemeris_kernels import K_IODE, K_VAR, glonass_states, kepler_states, select_records
from .gnss_time import gps_time_s_to_datetime, leap_seconds_at
from .navigation import GlonassEphemeris, KeplerEphemeris, NavigationData

Ephemeris = Union[KeplerEphemeris, GlonassEphemeris]

# Maximum |t - toe| for an ephemeris to be used, seconds. RTKLIB demo5 seleph()/selgeph():
# MAXDTOE(+1 s) for GPS/QZSS, MAXDTOE_GAL for Galileo, MAXDTOE_CMP(+1 s) for BeiDou, MAXDTOE_GLO
# for GLONASS (7200, 7200, 14400, 21600 and 1800 s in rtklib.h; Galileo was 10800 s before 2.4.3).
MAX_EPHEMERIS_AGE_S: dict[str, float] = {"G": 7201.0, "J": 7201.0, "E": 14400.0, "C": 21601.0, "R": 1800.0}

KEPLER_TOLERANCE_RAD = 1e-13
KEPLER_MAX_ITERATIONS = 30

_SIN_M5 = math.sin(math.radians(-5.0))
_COS_M5 = math.cos(math.radians(-5.0))
_URA_BOUNDS_M = (2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0)
_GAL_NAPA_STD_M = 500.0
_GAL_FNAV_BITS = 0x102     # data source bits 1 (F/NAV E5a-I) and 8 (clock for E5a,E1)
_GAL_INAV_BITS = 0x205     # data source bits 0, 2 (I/NAV E1-B, E5b-I) and 9 (clock for E5b,E1)


@dataclass
class SatelliteStates:
    """Satellite states for N requests (row i answers sat_ids[i] at t[i]).

    position_ecef_m    (N,3) m, ECEF at transmission time (no Earth-rotation correction applied)
    velocity_ecef_m_s  (N,3) m/s, ECEF (rotating frame)
    clock_bias_s       (N,)  s, broadcast clock incl. relativistic correction, no group delay
    clock_drift_s_s    (N,)  s/s
    variance_m2        (N,)  m^2, orbit+clock variance from URA/SISA
    valid              (N,)  bool; False: no usable ephemeris (rows hold zeros)
    iode               (N,)  int: IODE / IODnav / AODE; GLONASS: tb index (15-min slot of the day)
    """

    position_ecef_m: np.ndarray
    velocity_ecef_m_s: np.ndarray
    clock_bias_s: np.ndarray
    clock_drift_s_s: np.ndarray
    variance_m2: np.ndarray
    valid: np.ndarray
    iode: np.ndarray

    @classmethod
    def empty(cls, n: int) -> "SatelliteStates":
        return cls(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n), np.zeros(n), np.zeros(n),
                   np.zeros(n, dtype=bool), np.zeros(n, dtype=np.int64))


# --------------------------------------------------------------------------------------------------
# record properties


def is_galileo_fnav(eph: KeplerEphemeris) -> bool:
    """True for a Galileo F/NAV record (data source bits 1/8 without I/NAV bits 0/2/9)."""
    ds = eph.data_source
    return bool(ds & _GAL_FNAV_BITS) and not ds & _GAL_INAV_BITS


def is_healthy(eph: Ephemeris) -> bool:
    """Broadcast health as RTKLIB demo5 satexclude(): any non-zero health word excludes the satellite,
    except QZSS where bit 0 is ignored (health & 0xFE). GLONASS: Bn (RINEX health) must be 0."""
    if isinstance(eph, GlonassEphemeris):
        return eph.health == 0
    if eph.sat_id[0] == "J":
        return (eph.health & 0xFE) == 0
    return eph.health == 0


def _gal_sisa_std_m(sisa_m: float) -> float:
    """Galileo SISA (m, as in RINEX) quantised to the ICD index grid; NAPA/unknown -> 500 m."""
    if sisa_m < 0.0 or sisa_m > 6.0:
        return _GAL_NAPA_STD_M
    if sisa_m <= 0.49:
        return round(sisa_m / 0.01) * 0.01
    if sisa_m <= 0.98:
        return 0.5 + round((sisa_m - 0.5) / 0.02) * 0.02
    if sisa_m <= 1.96:
        return 1.0 + round((sisa_m - 1.0) / 0.04) * 0.04
    index = round((sisa_m - 2.0) / 0.16)
    return 2.0 + index * 0.16 if index <= 25 else _GAL_NAPA_STD_M


def ephemeris_variance_m2(eph: Ephemeris) -> float:
    """Orbit + clock variance (m^2) of a broadcast record, RTKLIB's mapping.

    GPS/QZSS/BeiDou: the URA (m) is mapped to the smallest URA index band containing it and the
    band's upper bound (2.4, 3.4, 4.85, ... 6144 m) is squared. Galileo: SISA quantised, NAPA 500 m.
    GLONASS: accuracy_m^2 (5 m by default, RTKLIB's ERREPH_GLO)."""
    if isinstance(eph, GlonassEphemeris):
        return eph.accuracy_m ** 2
    if eph.sat_id[0] == "E":
        return _gal_sisa_std_m(eph.accuracy_m) ** 2
    for bound in _URA_BOUNDS_M:
        if bound >= eph.accuracy_m:
            return bound ** 2
    return _URA_BOUNDS_M[-1] ** 2


def group_delay_s(eph: Ephemeris, band: int) -> float:
    """Broadcast group delay (s) of the signal on `band` (constants.py band convention).

    Sign convention (IS-GPS-200 20.3.3.3.3.2): the satellite clock seen on the band is
        dts_band = clock_bias_s - group_delay_s(eph, band)
    so a single point positioner either models P = rho + c*(dtr - dts_band) + ..., or equivalently
    corrects the measured pseudorange  P_corr = P - c*group_delay_s(eph, band)  and then uses
    clock_bias_s (RTKLIB pntpos prange(): P1 - c*TGD).

    GPS/QZSS: TGD * (f_L1/f_band)^2 (L5 approximated with TGD, the CNAV ISCs are not in RINEX 3 LNAV).
    Galileo: BGD from the record's clock reference: I/NAV clock (E1,E5b): E1 BGD_b, E5b (f1/f7)^2*BGD_b,
      E5a BGD_b + ((f1/f5)^2 - 1)*BGD_a; F/NAV clock (E1,E5a): E1 BGD_a, E5a (f1/f5)^2*BGD_a,
      E5b BGD_a + ((f1/f7)^2 - 1)*BGD_b  (BGD_a = BGD(E1,E5a) = tgd_s[0], BGD_b = tgd_s[1]).
    BeiDou (clock referenced to B3I): B1I TGD1, B2I TGD2, B3I 0.
    GLONASS: 0 (the RINEX 3.05 L1/L2 delta tau is not stored).
    """
    if isinstance(eph, GlonassEphemeris):
        return 0.0
    sys = eph.sat_id[0]
    tgd = eph.tgd_s
    if sys in ("G", "J"):
        f = FREQ_HZ[sys]
        return (f[0] / f[band]) ** 2 * tgd[0]
    if sys == "E":
        f = FREQ_HZ["E"]
        gamma_b = (f[0] / f[1]) ** 2
        gamma_a = (f[0] / f[2]) ** 2
        bgd_a, bgd_b = tgd[0], tgd[1]
        if is_galileo_fnav(eph):
            return (bgd_a, bgd_a + (gamma_b - 1.0) * bgd_b, gamma_a * bgd_a)[band]
        return (bgd_b, gamma_b * bgd_b, bgd_b + (gamma_a - 1.0) * bgd_a)[band]
    if sys == "C":
        return (tgd[0], tgd[1], 0.0)[band]
    return 0.0


def clock_polynomial_s(eph: Ephemeris, t_sv_gps_s: float) -> float:
    """Broadcast clock polynomial (s) without relativistic correction, evaluated from a time read on
    the satellite clock (RTKLIB eph2clk/geph2clk): solves t = t_sv - dts(t) by two fixed-point steps.
    Use it to turn t_sv = t_rx - P/c into GPS time before calling satellite_states."""
    if isinstance(eph, GlonassEphemeris):
        ts = t_sv_gps_s - eph.toe_gps_s
        t = ts
        for _ in range(2):
            t = ts - (-eph.tau_n_s + eph.gamma_n * t)
        return -eph.tau_n_s + eph.gamma_n * t
    ts = t_sv_gps_s - eph.toc_gps_s
    t = ts
    for _ in range(2):
        t = ts - (eph.af0_s + eph.af1_s_s * t + eph.af2_s_s2 * t * t)
    return eph.af0_s + eph.af1_s_s * t + eph.af2_s_s2 * t * t


# --------------------------------------------------------------------------------------------------
# selection


class _SortedRecords:
    """Records of one satellite sorted by toe, with their toes, I/NAV flags and health for selection."""

    __slots__ = ("source", "length", "records", "toes", "inav", "healthy")

    def __init__(self, source: list):
        self.source = source
        self.length = len(source)
        self.records = sorted(source, key=lambda r: r.toe_gps_s)
        self.toes = np.array([r.toe_gps_s for r in self.records], dtype=float)
        self.inav = np.array([isinstance(r, KeplerEphemeris) and not is_galileo_fnav(r) for r in self.records],
                             dtype=bool)
        self.healthy = np.array([is_healthy(r) for r in self.records], dtype=bool)


_SORTED_CACHE: dict[int, _SortedRecords] = {}
_CACHE_LIMIT = 8192


def _sorted_records(records: list) -> _SortedRecords:
    entry = _SORTED_CACHE.get(id(records))
    if entry is None or entry.source is not records or entry.length != len(records):
        if len(_SORTED_CACHE) >= _CACHE_LIMIT:
            _SORTED_CACHE.clear()
        entry = _SortedRecords(records)
        _SORTED_CACHE[id(records)] = entry
    return entry


def _select_many(nav: NavigationData, sat_id: str, t_gps_s: np.ndarray,
                 require_healthy: bool) -> tuple[list, np.ndarray]:
    """(records of sat_id sorted by toe, index of the record to use at each time or -1); see select_ephemeris."""
    sys = sat_id[:1]
    tmax = MAX_EPHEMERIS_AGE_S.get(sys)
    records = (nav.glonass.get(sat_id) if sys == "R" else nav.kepler.get(sat_id)) if tmax is not None else None
    if not records:
        return [], np.full(len(t_gps_s), -1, dtype=np.int64)
    index = _sorted_records(records)
    chosen = select_records(index.toes, index.inav, sys == "E", np.ascontiguousarray(t_gps_s, dtype=float), tmax)
    if require_healthy:
        unhealthy = chosen >= 0
        unhealthy[unhealthy] = ~index.healthy[chosen[unhealthy]]
        chosen[unhealthy] = -1
    return index.records, chosen


def select_ephemeris(nav: NavigationData, sat_id: str, t_gps_s: float, *,
                     require_healthy: bool = True) -> Ephemeris | None:
    """The broadcast record to use for `sat_id` at `t_gps_s`, or None.

    RTKLIB demo5 rule: the record whose toe is nearest to t with |t - toe| <= MAX_EPHEMERIS_AGE_S
    (ties: the later record). Galileo: I/NAV records are preferred whenever one is within the limit
    (their clock refers to E1/E5b, the pair RTKLIB uses); F/NAV only otherwise. As in RTKLIB, a Galileo
    record with toe >= t (age of data <= 0) is only used when no earlier one is within the limit.
    Health is tested on the chosen record (RTKLIB satexclude()): an unhealthy nearest record gives
    None rather than falling back to an older healthy one, which would predate a manoeuvre or
    anomaly. require_healthy=False returns the nearest record whatever its health.
    """
    records, chosen = _select_many(nav, sat_id, np.array([t_gps_s], dtype=float), require_healthy)
    return records[chosen[0]] if chosen[0] >= 0 else None


# --------------------------------------------------------------------------------------------------
# evaluation


def _kepler_row(eph: KeplerEphemeris) -> tuple:
    """The record's parameters in the column order of ephemeris_kernels (K_TOE ... K_IODE)."""
    sys = eph.sat_id[0]
    prn = int(eph.sat_id[1:])
    if sys == "E":
        mu, we = GM_GAL_M3_S2, OMEGA_EARTH_RAD_S
    elif sys == "C":
        mu, we = GM_BDS_M3_S2, OMEGA_EARTH_BDS_RAD_S
    else:
        mu, we = GM_GPS_M3_S2, OMEGA_EARTH_RAD_S
    geo = sys == "C" and (prn <= 5 or prn >= 59)
    return (eph.toe_gps_s, eph.toc_gps_s, eph.af0_s, eph.af1_s_s, eph.af2_s_s2, eph.sqrt_a * eph.sqrt_a,
            eph.e, eph.i0_rad, eph.omega0_rad, eph.omega_rad, eph.m0_rad, eph.delta_n_rad_s, eph.idot_rad_s,
            eph.omega_dot_rad_s, eph.cuc_rad, eph.cus_rad, eph.crc_m, eph.crs_m, eph.cic_rad, eph.cis_rad,
            eph.toe_sow_s, mu, we, 1.0 if geo else 0.0, ephemeris_variance_m2(eph), float(eph.iode))


# Per-record precomputations keyed by id(record); the record itself is kept in the entry so that the id
# cannot be reused while cached. Records are treated as immutable once evaluated.
_ROW_CACHE: dict[int, tuple[object, object]] = {}


def _cached(eph: Ephemeris) -> tuple:
    """Per-record precomputation (Kepler parameter row, or GLONASS state at toe and acceleration), cached by
    identity."""
    entry = _ROW_CACHE.get(id(eph))
    if entry is not None and entry[0] is eph:
        return entry[1]  # type: ignore[return-value]
    if len(_ROW_CACHE) >= _CACHE_LIMIT:
        _ROW_CACHE.clear()
    if isinstance(eph, KeplerEphemeris):
        payload: tuple = _kepler_row(eph)
    else:
        payload = (tuple(float(v) for v in eph.position_ecef_m) + tuple(float(v) for v in eph.velocity_ecef_m_s),
                   tuple(float(v) for v in eph.acceleration_ecef_m_s2))
    _ROW_CACHE[id(eph)] = (eph, payload)
    return payload


def _glonass_tb_index(eph: GlonassEphemeris, leap_s: int | None) -> int:
    if leap_s is None:
        leap_s = leap_seconds_at(gps_time_s_to_datetime(eph.toe_gps_s))
    return int(((eph.toe_gps_s - leap_s + 10800.0) % 86400.0) / 900.0 + 0.5)


def _kepler_states(rows: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, ...]:
    """Kepler evaluation of many rows at once (ephemeris_kernels.kepler_states). rows: (N, 26) parameter
    rows, t: (N,) gps_time_s."""
    return kepler_states(np.ascontiguousarray(rows, dtype=float), np.ascontiguousarray(t, dtype=float),
                         KEPLER_TOLERANCE_RAD, KEPLER_MAX_ITERATIONS, CLIGHT_M_S, _COS_M5, _SIN_M5)


def _evaluate(records: list, rec_id: np.ndarray, t: np.ndarray, leap_seconds: int | None) -> SatelliteStates:
    """States of records[rec_id[i]] at t[i] (rec_id -1: invalid row)."""
    n = len(rec_id)
    out = SatelliteStates.empty(n)
    if n == 0 or not records:
        return out
    # per record: 1 usable Kepler orbit, 2 usable GLONASS state (RTKLIB rejects |tau_n| > 1 s), 0 neither
    kind = np.array([(1 if r.sqrt_a > 0.0 else 0) if isinstance(r, KeplerEphemeris) else (2 if abs(r.tau_n_s) <= 1.0 else 0)
                     for r in records], dtype=np.int64)
    req_kind = np.where((rec_id >= 0) & np.isfinite(t), kind[np.maximum(rec_id, 0)], 0)
    glo = np.nonzero(req_kind == 2)[0]
    if len(glo):
        used = np.unique(rec_id[glo])
        recs = [records[i] for i in used]
        params = [_cached(r) for r in recs]
        x0 = np.array([p[0] for p in params], dtype=float).reshape(-1, 6)
        acc = np.array([p[1] for p in params], dtype=float).reshape(-1, 3)
        toe = np.array([r.toe_gps_s for r in recs], dtype=float)
        local = np.searchsorted(used, rec_id[glo])
        x = glonass_states(x0, acc, toe, local, np.ascontiguousarray(t[glo]))
        tau = np.array([r.tau_n_s for r in recs], dtype=float)[local]
        gamma = np.array([r.gamma_n for r in recs], dtype=float)[local]
        out.position_ecef_m[glo] = x[:, :3]
        out.velocity_ecef_m_s[glo] = x[:, 3:]
        out.clock_bias_s[glo] = -tau + gamma * (t[glo] - toe[local])
        out.clock_drift_s_s[glo] = gamma
        out.variance_m2[glo] = np.array([ephemeris_variance_m2(r) for r in recs], dtype=float)[local]
        out.iode[glo] = np.array([_glonass_tb_index(r, leap_seconds) for r in recs], dtype=np.int64)[local]
        out.valid[glo] = np.isfinite(x[:, 0]) & ((x[:, 0] * x[:, 0] + x[:, 1] * x[:, 1] + x[:, 2] * x[:, 2]) > 0.0)
    kep = np.nonzero(req_kind == 1)[0]
    if len(kep):
        used = np.unique(rec_id[kep])
        rows = np.asarray([_cached(records[i]) for i in used], dtype=float)[np.searchsorted(used, rec_id[kep])]
        pos, vel, clk, drift = _kepler_states(rows, t[kep])
        out.position_ecef_m[kep] = pos
        out.velocity_ecef_m_s[kep] = vel
        out.clock_bias_s[kep] = clk
        out.clock_drift_s_s[kep] = drift
        out.variance_m2[kep] = rows[:, K_VAR]
        out.iode[kep] = rows[:, K_IODE].astype(np.int64)
        out.valid[kep] = np.isfinite(pos).all(axis=1) & np.isfinite(clk)
    bad = ~out.valid
    if bad.any():
        out.position_ecef_m[bad] = 0.0
        out.velocity_ecef_m_s[bad] = 0.0
        out.clock_bias_s[bad] = 0.0
        out.clock_drift_s_s[bad] = 0.0
    return out


def ephemeris_states(records: Sequence[Ephemeris | None], t_gps_s: np.ndarray | float,
                     *, leap_seconds: int | None = None) -> SatelliteStates:
    """States of explicitly given records (no selection, no health test) at times t (gps_time_s).

    records[i] may be None (row invalid). t is a scalar or an (N,) array. leap_seconds (GPS-UTC) is
    only used for the GLONASS tb index reported in `iode` (default: gnss_time table)."""
    n = len(records)
    t = np.broadcast_to(np.asarray(t_gps_s, dtype=float), (n,))
    unique: list = []
    where: dict[int, int] = {}
    rec_id = np.full(n, -1, dtype=np.int64)
    for i, rec in enumerate(records):
        if rec is not None:
            k = where.get(id(rec))
            if k is None:
                k = where[id(rec)] = len(unique)
                unique.append(rec)
            rec_id[i] = k
    return _evaluate(unique, rec_id, t, leap_seconds)


def satellite_states(nav: NavigationData, sat_ids: Sequence[str], t_transmit_gps_s: np.ndarray | float,
                     *, t_select_gps_s: float | np.ndarray | None = None,
                     require_healthy: bool = True) -> SatelliteStates:
    """Positions, velocities, clocks and variances of satellites at their transmission times.

    sat_ids: N satellite ids ('G05', 'R12', 'E11', 'J02', 'C23'); t_transmit_gps_s: (N,) or scalar
    gps_time_s at which each signal left the satellite (GPS time, i.e. already corrected for the
    satellite clock). The ephemeris is chosen by select_ephemeris at t_select_gps_s (default: the
    transmission time; RTKLIB uses the observation epoch, pass it to reproduce RTKLIB exactly at
    ephemeris changes). Rows without a usable (healthy, unless require_healthy=False) ephemeris have
    valid=False and zeros elsewhere. The selection runs once per satellite for all its rows.
    """
    names, inverse = np.unique(np.asarray(sat_ids, dtype=str), return_inverse=True)
    return satellite_states_indexed(nav, [str(x) for x in names], inverse.reshape(-1), t_transmit_gps_s,
                                    t_select_gps_s=t_select_gps_s, require_healthy=require_healthy)


def satellite_states_indexed(nav: NavigationData, names: Sequence[str], sat_index: np.ndarray,
                             t_transmit_gps_s: np.ndarray | float, *, t_select_gps_s: float | np.ndarray | None = None,
                             require_healthy: bool = True) -> SatelliteStates:
    """satellite_states with the satellites given as indices into `names` (row i is names[sat_index[i]]):
    the form observation arrays already have, without building and sorting a string per row."""
    sat_index = np.asarray(sat_index, dtype=np.int64)
    n = len(sat_index)
    t = np.broadcast_to(np.asarray(t_transmit_gps_s, dtype=float), (n,))
    ts = t if t_select_gps_s is None else np.broadcast_to(np.asarray(t_select_gps_s, dtype=float), (n,))
    rec_id = np.full(n, -1, dtype=np.int64)
    records: list = []
    if n:
        order = np.argsort(sat_index, kind="stable")
        bounds = np.searchsorted(sat_index[order], np.arange(len(names) + 1))
        for k, sat in enumerate(names):
            rows = order[bounds[k]:bounds[k + 1]]
            if len(rows) == 0:
                continue
            recs, chosen = _select_many(nav, sat, ts[rows], require_healthy)
            ok = chosen >= 0
            rec_id[rows[ok]] = chosen[ok] + len(records)
            records.extend(recs)
    return _evaluate(records, rec_id, t, nav.leap_seconds)


__all__ = [
    "MAX_EPHEMERIS_AGE_S",
    "SatelliteStates",
    "clock_polynomial_s",
    "ephemeris_states",
    "ephemeris_variance_m2",
    "group_delay_s",
    "is_galileo_fnav",
    "is_healthy",
    "satellite_states",
    "satellite_states_indexed",
    "select_ephemeris",
]

