"""Broadcast navigation message containers (one record per satellite and issue of data).

All times are gps_time_s (see gnss_time.py): readers convert BDT, GLONASS UTC(SU) and week/TOW
fields before filling these records, so the orbit code never deals with time scales.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class KeplerEphemeris:
    """GPS / Galileo / QZSS / BeiDou broadcast ephemeris (IS-GPS-200 style Keplerian elements)."""

    sat_id: str
    toe_gps_s: float          # time of ephemeris, gps_time_s
    toc_gps_s: float          # time of clock, gps_time_s
    af0_s: float
    af1_s_s: float
    af2_s_s2: float
    sqrt_a: float             # sqrt(m)
    e: float
    i0_rad: float
    omega0_rad: float         # longitude of ascending node at weekly epoch
    omega_rad: float          # argument of perigee
    m0_rad: float
    delta_n_rad_s: float
    idot_rad_s: float
    omega_dot_rad_s: float
    cuc_rad: float
    cus_rad: float
    crc_m: float
    crs_m: float
    cic_rad: float
    cis_rad: float
    toe_sow_s: float          # time of ephemeris as seconds of (system) week, as broadcast
    week: int                 # week number in the system's own count (GPS week for G/J/E in RINEX)
    iode: int = 0
    iodc: int = 0
    tgd_s: tuple[float, ...] = (0.0, 0.0)   # GPS/QZS: (TGD, 0); GAL: (BGD E1-E5a, BGD E1-E5b); BDS: (TGD1, TGD2)
    accuracy_m: float = 2.0   # URA / SISA in metres
    health: int = 0           # 0 = healthy (Galileo: SV health bits)
    fit_interval_h: float = 4.0
    transmit_gps_s: float = float("nan")
    data_source: int = 0      # Galileo: I/NAV (bit 0/9) vs F/NAV (bit 1/8)


@dataclass
class GlonassEphemeris:
    """GLONASS broadcast ephemeris: state vector in PZ-90 (treated as ITRF), integrated with RK4."""

    sat_id: str
    toe_gps_s: float                 # reference time tb converted to gps_time_s
    frame_time_gps_s: float          # message frame time
    position_ecef_m: np.ndarray      # (3,)
    velocity_ecef_m_s: np.ndarray    # (3,)
    acceleration_ecef_m_s2: np.ndarray  # (3,) luni-solar
    tau_n_s: float                   # clock bias (sign as broadcast: t_sv correction = -tau_n + gamma_n * dt)
    gamma_n: float                   # relative frequency bias
    fcn: int                         # frequency channel number, -7..+6
    health: int = 0
    age_days: int = 0
    accuracy_m: float = 5.0


@dataclass
class NavigationData:
    """Everything read from navigation files (RINEX NAV or UBX SFRBX) for one processing job."""

    kepler: dict[str, list[KeplerEphemeris]] = field(default_factory=dict)     # sorted by toe
    glonass: dict[str, list[GlonassEphemeris]] = field(default_factory=dict)   # sorted by toe
    iono_gps_alpha: np.ndarray | None = None   # Klobuchar alpha0..3
    iono_gps_beta: np.ndarray | None = None    # Klobuchar beta0..3
    iono_gal: np.ndarray | None = None         # NeQuick ai0..ai2
    iono_bds_alpha: np.ndarray | None = None
    iono_bds_beta: np.ndarray | None = None
    leap_seconds: int | None = None
    source_paths: list[str] = field(default_factory=list)
    records_outside_window: int = 0            # records skipped by a reader's time window
    record_span_gps_s: tuple[float, float] | None = None   # epochs of all records read or skipped (RINEX)

    def glonass_fcn(self) -> dict[str, int]:
        return {sat: recs[-1].fcn for sat, recs in self.glonass.items() if recs}

    def merge(self, other: "NavigationData") -> "NavigationData":
        """Union of two navigation data sets (duplicates by toe and sat dropped)."""
        out = NavigationData(source_paths=self.source_paths + other.source_paths,
                             records_outside_window=self.records_outside_window + other.records_outside_window)
        spans = [sp for sp in (self.record_span_gps_s, other.record_span_gps_s) if sp is not None]
        if spans:
            out.record_span_gps_s = (min(sp[0] for sp in spans), max(sp[1] for sp in spans))
        for attr in ("kepler", "glonass"):
            merged: dict = {}
            for src in (getattr(self, attr), getattr(other, attr)):
                for sat, recs in src.items():
                    merged.setdefault(sat, []).extend(recs)
            for sat, recs in merged.items():
                seen, uniq = set(), []
                for r in sorted(recs, key=lambda r: r.toe_gps_s):
                    key = (round(r.toe_gps_s, 3), getattr(r, "iode", 0), getattr(r, "data_source", 0))
                    if key not in seen:
                        seen.add(key)
                        uniq.append(r)
                merged[sat] = uniq
            setattr(out, attr, merged)
        for attr in ("iono_gps_alpha", "iono_gps_beta", "iono_gal", "iono_bds_alpha", "iono_bds_beta", "leap_seconds"):
            a = getattr(self, attr)
            setattr(out, attr, a if a is not None else getattr(other, attr))
        return out

    @property
    def n_records(self) -> int:
        return sum(len(v) for v in self.kepler.values()) + sum(len(v) for v in self.glonass.values())
