"""Simulated raw GNSS observations (code, carrier phase, Doppler, C/N0) of a rover on a known trajectory
and of a static base, from the satellite geometry of a real broadcast navigation file.

The result is a :class:`~georef_core.gnss.observations.RawObservations` per receiver, exactly what the RINEX
readers return, plus a :class:`SimulatedTruth` holding every injected quantity (true times, positions,
receiver clocks, ambiguities, slips, delays, errors), so that the PPK engine can be tested in physical units.

Entry points
------------
* :func:`simulate_receiver` one receiver: ``(RawObservations, SimulatedTruth)``;
* :func:`simulate_survey` a rover and a static base sharing one :class:`Environment` (atmosphere and
  broadcast-orbit errors), with the single-difference ambiguity truth;
* :func:`write_survey_gnss` RINEX 3.04 or 2.11 files in ``rover/``, ``base/`` and the navigation file(s) in ``nav/``;
* :func:`lawnmower_trajectory`, :func:`static_trajectory` antenna trajectories (position and velocity functions);
* :func:`epoch_grid`, :func:`single_difference_ambiguities`.

Observation model (per receiver r, satellite s, band b; true reception time t)
-----------------------------------------------------------------------------
::

    P  = rho + c (dtr - dts) + c TGD_b + T + I_b + B_r(sys, b) + MP_P + e_P              (m)
    L  = [rho + c (dtr - dts) + T - I_b + MP_L + e_L] / lambda_b + N_rsb                  (cycles)
    D  = -[drho/dt + c (ddtr - ddts) + dT/dt - dI_b/dt + dMP_L/dt] / lambda_b + e_D      (Hz)

* ``rho`` is georef_core's geometric range (:func:`~georef_core.gnss.satellite_geometry.geometric_range_m`):
  the satellite at the transmission time ``t - tau`` in the ECEF frame of that instant, ``|x_s - x_r|`` plus the
  Earth-rotation term ``omega_e (x_s y_r - y_s x_r) / c``; ``tau = rho / c`` is solved by fixed-point iteration
  (the atmospheric delays change the transmission time by < 50 ns: < 0.05 mm of range, neglected).
* The satellite truth is the broadcast ephemeris the engine selects (select_ephemeris at the transmission time),
  blended smoothly (quintic step over ``Environment.ephemeris_blend_s``) across record changes so that the true
  satellite never jumps, plus a smooth broadcast error (orbit and clock, constant + drift per satellite). The
  truth is evaluated on a 2 s grid and interpolated (cubic Hermite, position and velocity): < 1e-6 m from a direct
  evaluation, with the transmission time carried relative to the first epoch (no 2.4e-7 s float64 rounding).
* ``dts``: broadcast clock (relativistic term included) + clock error; ``TGD_b``: the broadcast group delay of
  the band (ephemeris.group_delay_s, record valid at the middle of the span; 0 for GLONASS).
* Receiver clock ``dtr``: free-running TCXO (offset up to ``max_offset_s``, frequency offset up to
  ``max_drift_s_s``, white and random-walk frequency noise, optional 1 ms jumps as u-blox receivers do) or
  steered (tens of ns). RINEX time tags are receiver time: the requested epochs are the tags and the true
  reception time is ``t = tag - dtr(t)``.
* ``T``: Saastamoinen (standard atmosphere, ``Environment.humidity``) at the receiver's true height with a
  1/sin(el) mapping, plus a zenith wet delay error field (common offset, horizontal gradient, drift).
* ``I_b``: Klobuchar from the navigation file's coefficients plus a spatially correlated residual field (a sum of
  random plane waves over the ionospheric pierce point, scaled by Klobuchar's obliquity), scaled by
  ``(f_L1 / f_b)^2``; code delayed, phase advanced.
* ``B_r``: receiver code bias per system and band (GPS and QZSS share one, as the SPP clock does).
* ``N``: a random integer in +-5e7 per receiver, satellite, band and lock arc; user cycle slips add integers from
  their epoch to the end of the arc (LLI bit 0 set unless ``flagged=False``); after an outage (random short
  blockage) or a rise above the tracking mask a new arc starts with a new integer and LLI bit 0 (unless the file's
  first epoch). Half-cycle flags (LLI bit 1) are never set.
* ``MP``: multipath, a slowly varying unit-RMS sum of sinusoids per receiver, satellite, band and observable,
  amplitude ``A * exp(-el / el_scale)``; ``e``: white noise of sigma ``a + b / sin(el)`` (times a per-signal factor).
* C/N0 rises with elevation (``cn0_zenith``..``cn0_horizon``), per-signal offset, 1 dB noise, quantised.

Not modelled: antenna phase-centre offsets/variations, phase wind-up, tides, higher-order ionosphere, receiver
fractional phase biases and GLONASS inter-frequency / inter-channel biases (all receivers are alike), signal
blockage by terrain or the airframe (only random outages and the mask), clock jumps of the phase alone.

Times: RawObservations.gps_time_s are receiver time tags (as in RINEX); SimulatedTruth.true_time_s are GPS times
of the measurements; event times (camera trigger marks) are true GPS times, as receivers report time marks.
The navigation file is used (and copied) as it is: the simulated epochs must lie within its records' validity
(e.g. the MatRTKLIB multi-GNSS file: 2024-06-24 about 07:45-09:15 GPST with GLONASS; the GSI file: 2005-04-02).

Signals: GPS C1C/L1C + C2W/L2W, GLONASS C1C/L1C + C2P/L2P (frequency channel from the navigation file),
Galileo C1C/L1C + C7Q/L7Q, QZSS C1C/L1C + C2L/L2L, BeiDou C2I/L2I + C7I/L7I (B2I from BDS-2 satellites only),
each with its D (Doppler) and S (C/N0) observation; or L1 C/A only (u-blox-like, GPS + GLONASS).
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..gnss.atmosphere import klobuchar_delay_m, saastamoinen_zenith_and_slant
from ..gnss.constants import CLIGHT_M_S, FREQ_HZ, N_BANDS, OMEGA_EARTH_RAD_S, RINEX_DIGIT_TO_BAND, wavelength_table_m
from ..gnss.ephemeris import ephemeris_states, group_delay_s, select_ephemeris
from ..gnss.frames import azimuth_elevation_batch, ecef_to_enu_rotation, ecef_to_geodetic
from ..gnss.navigation import NavigationData
from ..gnss.observations import RawObservations, ReceiverHeader
from ..gnss.rinex_obs import write_rinex2_obs, write_rinex3_obs
from ..gnss.satellite_geometry import geometric_range_m

__all__ = [
    "GEODETIC_SIGNALS", "UBLOX_L1_SIGNALS", "ClockOptions", "CycleSlip", "Environment", "KinematicTrajectory",
    "ReceiverOptions", "SimulatedSurvey", "SimulatedTruth", "SlipRecord", "epoch_grid", "lawnmower_trajectory",
    "simulate_receiver", "simulate_survey", "single_difference_ambiguities", "static_trajectory", "write_survey_gnss",
]

PositionFn = Callable[[np.ndarray], np.ndarray]
L1_HZ = FREQ_HZ["G"][0]
SYSTEM_ORDER = "GREJC"
_AMBIGUITY_RANGE = 50_000_000
_ORBIT_GRID_S = 2.0
_SELECT_STEP_S = 10.0

# Tracked signals (RINEX 3 frequency digit + attribute) per system.
GEODETIC_SIGNALS: dict[str, tuple[str, ...]] = {
    "G": ("1C", "2W"), "R": ("1C", "2P"), "E": ("1C", "7Q"), "J": ("1C", "2L"), "C": ("2I", "7I"),
}
UBLOX_L1_SIGNALS: dict[str, tuple[str, ...]] = {"G": ("1C",), "R": ("1C",)}

# (code noise factor, phase noise factor, C/N0 offset dB) per (system, signal); default (1, 1, 0).
_SIGNAL_QUALITY: dict[tuple[str, str], tuple[float, float, float]] = {
    ("G", "2W"): (1.6, 1.3, -7.0), ("G", "2L"): (1.1, 1.0, -3.0), ("G", "5Q"): (0.7, 1.0, 2.0),
    ("R", "1C"): (1.8, 1.0, -1.0), ("R", "2C"): (1.8, 1.0, -3.0), ("R", "2P"): (1.5, 1.1, -5.0),
    ("E", "7Q"): (0.7, 1.0, 1.0), ("E", "5Q"): (0.7, 1.0, 2.0), ("J", "2L"): (1.1, 1.0, -3.0),
    ("C", "2I"): (1.2, 1.0, -2.0), ("C", "7I"): (1.2, 1.0, -3.0),
}


def _signal_available(sat_id: str, sig: str) -> bool:
    """BeiDou B2I (7I) is broadcast by BDS-2 satellites only (C01-C18)."""
    if sat_id[0] == "C" and sig == "7I":
        return int(sat_id[1:]) <= 18
    return True


# ----------------------------------------------------------------------------------------------------------
# options
# ----------------------------------------------------------------------------------------------------------


@dataclass
class ClockOptions:
    """Receiver clock. 'free': TCXO with an initial offset uniform in +-max_offset_s and a frequency offset
    uniform in +-max_drift_s_s, white frequency noise (Allan deviation at 1 s) and random-walk frequency noise;
    'steered': offset ~ N(0, steered_sigma_s), no frequency offset. millisecond_jumps keeps |dtr| <= 0.5 ms by
    1 ms steps (code, phase and time tags jump together, as u-blox receivers)."""

    mode: str = "free"
    max_offset_s: float = 5e-4
    max_drift_s_s: float = 2e-7
    white_frequency_noise: float = 1e-10
    frequency_random_walk_s_s_per_sqrt_s: float = 2e-12
    steered_sigma_s: float = 2e-8
    millisecond_jumps: bool = False


@dataclass
class CycleSlip:
    """A cycle slip from the first epoch whose receiver time tag is >= time_gps_s (to the end of the lock arc).
    band None: every tracked band (each slips by ``cycles``). flagged=False leaves LLI at 0 (an undetected slip).
    A slip at an epoch where the satellite is not tracked is ignored (it is not in SimulatedTruth.slips)."""

    time_gps_s: float
    sat_id: str
    cycles: int = 7
    band: int | None = None
    flagged: bool = True


@dataclass
class SlipRecord:
    epoch: int            # index in the receiver's epochs (RawObservations / SimulatedTruth)
    receiver_time_s: float
    sat_id: str
    band: int
    cycles: int
    flagged: bool


@dataclass
class ReceiverOptions:
    """Receiver, antenna environment and tracking. Noise sigmas are ``a + b / sin(el)`` (undifferenced, m or Hz),
    multiplied by per-signal factors (_SIGNAL_QUALITY); multipath amplitudes (RMS) are at the horizon and decay
    as exp(-el / multipath_elevation_scale_deg)."""

    marker_name: str = "SIM"
    receiver_type: str = "GEOREF SIMULATOR"
    antenna_type: str = "SIM_ANTENNA     NONE"
    signals: dict[str, tuple[str, ...]] = field(default_factory=lambda: dict(GEODETIC_SIGNALS))
    systems: tuple[str, ...] | None = None          # subset of the signals' systems; None: all
    tracking_mask_deg: float = 5.0
    clock: ClockOptions = field(default_factory=ClockOptions)
    code_sigma_a_m: float = 0.10
    code_sigma_b_m: float = 0.10
    phase_sigma_a_m: float = 0.0008
    phase_sigma_b_m: float = 0.0008
    doppler_sigma_a_hz: float = 0.01
    doppler_sigma_b_hz: float = 0.01
    code_multipath_m: float = 0.4
    phase_multipath_m: float = 0.003
    multipath_elevation_scale_deg: float = 15.0
    multipath_period_s: tuple[float, float] = (60.0, 600.0)
    system_code_bias_m: float = 2.0                 # sigma of the receiver code bias of each system (not GPS/QZSS)
    band_code_bias_m: float = 0.5                   # sigma of the receiver code bias of each band (not band 0)
    cn0_zenith_dbhz: float = 50.0
    cn0_horizon_dbhz: float = 35.0
    cn0_noise_db: float = 1.0
    snr_resolution_dbhz: float = 0.25
    outage_rate_per_hour: float = 0.0               # random blockages per satellite and hour
    outage_duration_s: tuple[float, float] = (0.5, 5.0)
    lli_on_reacquisition: bool = True
    slips: tuple[CycleSlip, ...] = ()
    gaps: tuple[tuple[float, float], ...] = ()      # [t0, t1) of receiver time with no epoch written (radio/log loss)
    random_gap_rate_per_hour: float = 0.0
    random_gap_duration_s: tuple[float, float] = (1.0, 10.0)
    header_position: bool = True                    # APPROX POSITION XYZ = mean true position

    @classmethod
    def geodetic(cls, **kw) -> "ReceiverOptions":
        """Survey-grade multi-frequency receiver on a good site (GPS L1C/L2W, GLONASS L1C/L2P, Galileo E1C/E5bQ,
        QZSS L1C/L2L, BeiDou B1I/B2I)."""
        return cls(**kw)

    @classmethod
    def ublox_l1(cls, **kw) -> "ReceiverOptions":
        """u-blox M8T-like single-frequency receiver (GPS + GLONASS C1C/L1C/D1C/S1C, integer dB-Hz) with a
        patch antenna on a drone: noisier code and phase, faster, weaker multipath."""
        base = dict(marker_name="ROVR", receiver_type="U-BLOX SIM", antenna_type="PATCH           NONE",
                    signals=dict(UBLOX_L1_SIGNALS), code_sigma_a_m=0.25, code_sigma_b_m=0.25,
                    phase_sigma_a_m=0.001, phase_sigma_b_m=0.001, doppler_sigma_a_hz=0.05,
                    doppler_sigma_b_hz=0.05, code_multipath_m=0.5, phase_multipath_m=0.003,
                    multipath_period_s=(5.0, 60.0), cn0_zenith_dbhz=47.0, cn0_horizon_dbhz=30.0,
                    snr_resolution_dbhz=1.0, clock=ClockOptions(millisecond_jumps=True))
        base.update(kw)
        return cls(**base)

    def active_signals(self) -> dict[str, tuple[str, ...]]:
        keep = set(self.systems) if self.systems is not None else set(self.signals)
        return {s: sig for s, sig in self.signals.items() if s in keep and sig}


# ----------------------------------------------------------------------------------------------------------
# environment: atmosphere and broadcast errors shared by the receivers of a survey
# ----------------------------------------------------------------------------------------------------------


def _sat_seed(seed: int, tag: int, sat_id: str, extra: int = 0) -> np.random.Generator:
    code = SYSTEM_ORDER.index(sat_id[0]) if sat_id[0] in SYSTEM_ORDER else 9
    return np.random.default_rng(np.random.SeedSequence([abs(int(seed)), tag, code, int(sat_id[1:]), extra]))


@dataclass(eq=False)
class Environment:
    """The atmosphere and the broadcast-orbit errors of a survey, deterministic for a seed. Receivers simulated
    with the same Environment see the same (spatially correlated) delays; do not give a rover and its base
    different environments. The zenith wet error field is referenced to ``reference_ecef_m`` (default: the first
    receiver position simulated) and ``reference_time_s`` (default: its first epoch)."""

    seed: int = 0
    humidity: float = 0.6                     # relative humidity of the standard atmosphere (truth)
    zwd_error_m: float = 0.02                 # sigma of the zenith wet delay error (common part)
    zwd_gradient_m_per_km: float = 0.0005     # sigma of each horizontal gradient component
    zwd_drift_m_per_h: float = 0.005          # sigma of the temporal drift
    iono_residual_m: float = 0.2              # RMS of the L1 vertical delay residual to Klobuchar
    iono_wavelength_km: float = 1000.0        # typical horizontal wavelength of the residual
    iono_period_s: float = 3600.0             # typical period of the residual
    iono_components: int = 8
    orbit_error_m: float = 0.3                # sigma per axis of the broadcast orbit error (constant part)
    clock_error_m: float = 0.3                # sigma of the broadcast clock error (constant part)
    broadcast_error_drift_per_h: float = 0.3  # drift per hour, as a fraction of the constant part
    ephemeris_blend_s: float = 120.0
    reference_ecef_m: np.ndarray | None = None
    reference_time_s: float | None = None

    def __post_init__(self):
        rng = np.random.default_rng(np.random.SeedSequence([abs(int(self.seed)), 101]))
        self._zwd = rng.normal(0.0, 1.0, 4) * np.array([self.zwd_error_m, self.zwd_gradient_m_per_km,
                                                        self.zwd_gradient_m_per_km, self.zwd_drift_m_per_h])
        k = max(int(self.iono_components), 1)
        d = rng.normal(size=(k, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        wl = self.iono_wavelength_km * 1e3 * rng.uniform(0.5, 2.0, k)
        self._iono_k = d * (2 * np.pi / wl)[:, None]                    # rad per metre
        self._iono_w = 2 * np.pi / (self.iono_period_s * rng.uniform(0.5, 2.0, k)) * rng.choice([-1.0, 1.0], k)
        self._iono_phi = rng.uniform(0, 2 * np.pi, k)
        self._iono_amp = self.iono_residual_m * math.sqrt(2.0 / k)

    def bind(self, position_ecef_m, time_s: float) -> None:
        """Set the reference point and time of the zenith wet delay field if not set yet."""
        if self.reference_ecef_m is None:
            self.reference_ecef_m = np.asarray(position_ecef_m, dtype=float).reshape(3).copy()
        if self.reference_time_s is None:
            self.reference_time_s = float(time_s)

    # --- troposphere
    def zenith_wet_error_m(self, t_abs, pos_ecef) -> np.ndarray:
        ref = self.reference_ecef_m
        lat, lon, _ = ecef_to_geodetic(ref)
        enu = (np.asarray(pos_ecef, float) - ref) @ ecef_to_enu_rotation(lat, lon).T
        z = self._zwd
        return (z[0] + (z[1] * enu[..., 0] + z[2] * enu[..., 1]) / 1e3
                + z[3] * (np.asarray(t_abs, float) - self.reference_time_s) / 3600.0)

    def troposphere_m(self, t_abs, pos_ecef, llh, el) -> np.ndarray:
        """Slant delay (m): Saastamoinen at the true height + zenith wet error / sin(el). Shapes (E,S)."""
        slant = saastamoinen_zenith_and_slant(llh[:, 0:1], llh[:, 2:3], el, humidity=self.humidity)
        zwd = self.zenith_wet_error_m(t_abs, pos_ecef)[:, None]
        return np.where(el > 0, slant + zwd / np.sin(np.maximum(el, 1e-3)), 0.0)

    # --- ionosphere
    def ionosphere_l1_m(self, nav: NavigationData, t_abs, llh, az, el) -> np.ndarray:
        """L1 group delay (m): Klobuchar + residual field at the pierce point (obliquity-scaled), >= 0."""
        t = np.asarray(t_abs, float)[:, None]
        lat, lon = llh[:, 0:1], llh[:, 1:2]
        klob = klobuchar_delay_m(t, lat, lon, az, el, nav.iono_gps_alpha, nav.iono_gps_beta, L1_HZ)
        el_sc = np.maximum(el, 0.0) / np.pi
        psi = 0.0137 / (el_sc + 0.11) - 0.022
        phi = np.clip(lat / np.pi + psi * np.cos(az), -0.49, 0.49) * np.pi
        lam = lon + psi * np.pi * np.sin(az) / np.cos(phi)
        u = np.stack([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)], axis=-1) * 6.721e6
        arg = u @ self._iono_k.T + t[..., None] * self._iono_w + self._iono_phi       # (E,S,K)
        res = self._iono_amp * np.cos(arg).sum(axis=-1)
        obliq = 1.0 + 16.0 * (0.53 - el_sc) ** 3
        return np.where(el > 0, np.maximum(klob + obliq * res, 0.0), 0.0)

    # --- broadcast errors
    def broadcast_error(self, sat_id: str) -> tuple[np.ndarray, np.ndarray]:
        """(orbit coefficients (2,3) m and m/h, clock coefficients (2,) m and m/h) of a satellite."""
        rng = _sat_seed(self.seed, 7, sat_id)
        d = self.broadcast_error_drift_per_h
        orbit = rng.normal(size=(2, 3)) * self.orbit_error_m * np.array([[1.0], [d]])
        clock = rng.normal(size=2) * self.clock_error_m * np.array([1.0, d])
        return orbit, clock


# ----------------------------------------------------------------------------------------------------------
# trajectories
# ----------------------------------------------------------------------------------------------------------


@dataclass
class KinematicTrajectory:
    """Antenna phase-centre trajectory: a quintic spline in the local ENU frame of ``origin_ecef_m`` (positions
    and exact derivative velocities), as functions of GPS time."""

    origin_ecef_m: np.ndarray
    start_gps_s: float
    spline: object                 # scipy BSpline of local time -> ENU
    duration_s: float
    description: str = ""

    @property
    def end_gps_s(self) -> float:
        return self.start_gps_s + self.duration_s

    def _rot(self) -> np.ndarray:
        lat, lon, _ = ecef_to_geodetic(self.origin_ecef_m)
        return ecef_to_enu_rotation(lat, lon)

    def position_enu(self, t_gps_s) -> np.ndarray:
        tl = np.clip(np.atleast_1d(np.asarray(t_gps_s, float)) - self.start_gps_s, 0.0, self.duration_s)
        return np.asarray(self.spline(tl))

    def velocity_enu(self, t_gps_s) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t_gps_s, float)) - self.start_gps_s
        v = np.asarray(self.spline.derivative()(np.clip(t, 0.0, self.duration_s)))
        v[(t < 0) | (t > self.duration_s)] = 0.0
        return v

    def position_ecef(self, t_gps_s) -> np.ndarray:
        return self.origin_ecef_m + self.position_enu(t_gps_s) @ self._rot()

    def velocity_ecef(self, t_gps_s) -> np.ndarray:
        return self.velocity_enu(t_gps_s) @ self._rot()


def static_trajectory(position_ecef_m) -> tuple[PositionFn, PositionFn]:
    """(position_fn, velocity_fn) of a static antenna."""
    p = np.asarray(position_ecef_m, dtype=float).reshape(3)

    def pos(t):
        return np.broadcast_to(p, (np.size(t), 3)).copy()

    def vel(t):
        return np.zeros((np.size(t), 3))

    return pos, vel


def _min_jerk(p0, p1, duration, n):
    tau = np.linspace(0.0, 1.0, n)[:, None]
    s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    return p0 + (p1 - p0) * s


def lawnmower_trajectory(origin_ecef_m, start_gps_s: float, *, speed_m_s: float = 5.0, n_lines: int = 4,
                         line_length_m: float = 100.0, line_spacing_m: float = 20.0, height_m: float = 40.0,
                         heading_deg: float = 0.0, pattern_offset_enu_m=(15.0, 10.0), static_before_s: float = 20.0,
                         static_after_s: float = 10.0, climb_speed_m_s: float = 2.5, transit_speed_m_s: float = 5.0,
                         accel_m_s2: float = 1.5, smooth_s: float = 0.5,
                         sample_hz: float = 20.0) -> KinematicTrajectory:
    """A drone survey flight: static on the ground at ``origin`` (the take-off point, antenna phase centre),
    climb, transit to the first line, ``n_lines`` parallel lines at ``speed_m_s`` joined by half-circle turns of
    diameter ``line_spacing_m`` (speed kept through the turns; accelerations ``accel_m_s2`` at both ends),
    transit back, descend and stay static. Minimum-jerk climbs, transits and descents; the whole path is then
    smoothed with a Gaussian of ``smooth_s`` (continuous accelerations, corners of the turns slightly cut)."""
    from scipy.interpolate import make_interp_spline
    from scipy.ndimage import gaussian_filter1d

    dt = 1.0 / sample_hz
    h = math.radians(heading_deg)
    along = np.array([math.sin(h), math.cos(h), 0.0])
    across = np.array([math.cos(h), -math.sin(h), 0.0])
    start = np.array([pattern_offset_enu_m[0], pattern_offset_enu_m[1], height_m])
    chunks: list[np.ndarray] = []

    def add(points: np.ndarray) -> None:
        chunks.append(points if not chunks else points[1:])

    def hold(p, duration):
        n = max(int(round(duration / dt)), 1) + 1
        add(np.repeat(np.asarray(p, float)[None], n, axis=0))

    def move(p0, p1, speed):
        dist = float(np.linalg.norm(np.asarray(p1) - np.asarray(p0)))
        if dist < 1e-9:
            return
        duration = 1.875 * dist / speed
        n = max(int(round(duration / dt)), 2) + 1
        add(_min_jerk(np.asarray(p0, float), np.asarray(p1, float), duration, n))

    ground = np.zeros(3)
    hold(ground, static_before_s)
    top = np.array([0.0, 0.0, height_m])
    move(ground, top, climb_speed_m_s)
    move(top, start, transit_speed_m_s)
    # the line pattern by arc length
    r = line_spacing_m / 2.0
    seg_len = [line_length_m] + [math.pi * r, line_length_m] * (n_lines - 1)
    total = float(sum(seg_len))

    def point_at(s_arc: np.ndarray) -> np.ndarray:
        out = np.zeros((len(s_arc), 3))
        pos = start.copy()
        direction = along.copy()
        acc = 0.0
        for k, length in enumerate(seg_len):
            sel = (s_arc >= acc) & (s_arc <= acc + length + 1e-9)
            u = (s_arc[sel] - acc)[:, None]
            if k % 2 == 0:   # straight line
                out[sel] = pos + direction * u
                end = pos + direction * length
            else:            # half circle towards +across
                centre = pos + across * r
                ang = u[:, 0] / r
                out[sel] = centre - across * r * np.cos(ang)[:, None] + direction * r * np.sin(ang)[:, None]
                end = pos + across * 2 * r
                direction = -direction
            pos = end
            acc += length
        return out

    v, a = speed_m_s, accel_m_s2
    s_ramp = v * v / (2 * a)
    if 2 * s_ramp > total:
        v = math.sqrt(a * total)
        s_ramp = total / 2
    t_ramp = v / a
    t_const = (total - 2 * s_ramp) / v
    t_total = 2 * t_ramp + t_const
    tl = np.arange(0.0, t_total + dt / 2, dt)
    tl[-1] = t_total
    s_arc = np.where(tl < t_ramp, 0.5 * a * tl**2,
                     np.where(tl < t_ramp + t_const, s_ramp + v * (tl - t_ramp),
                              total - 0.5 * a * np.maximum(t_total - tl, 0.0) ** 2))
    line_pts = point_at(np.clip(s_arc, 0.0, total))
    add(line_pts)
    move(line_pts[-1], top, transit_speed_m_s)
    move(top, ground, climb_speed_m_s * 0.8)
    hold(ground, static_after_s)
    enu = np.concatenate(chunks)
    # a multirotor does not jerk: smooth the accelerations of the piecewise path over ~0.5 s
    enu = gaussian_filter1d(enu, smooth_s * sample_hz, axis=0, mode="nearest") if smooth_s > 0 else enu
    t = np.arange(len(enu)) * dt
    spline = make_interp_spline(t, enu, k=5)
    return KinematicTrajectory(np.asarray(origin_ecef_m, float).reshape(3).copy(), float(start_gps_s), spline,
                               float(t[-1]), f"lawn-mower {n_lines} lines x {line_length_m:g} m at {speed_m_s:g} m/s, "
                               f"{height_m:g} m above take-off")


def epoch_grid(start_gps_s: float, duration_s: float, rate_hz: float) -> np.ndarray:
    """Nominal receiver time tags, multiples of 1 / rate_hz, within [start, start + duration]."""
    k0 = math.ceil(round(start_gps_s * rate_hz, 6))
    k1 = math.floor(round((start_gps_s + duration_s) * rate_hz, 6))
    return np.arange(k0, k1 + 1) / rate_hz


# ----------------------------------------------------------------------------------------------------------
# receiver clock
# ----------------------------------------------------------------------------------------------------------


class _Clock:
    """Receiver clock on a 0.1 s grid of time relative to T0: bias (s, continuous) and frequency."""

    def __init__(self, o: ClockOptions, t_lo: float, t_hi: float, rng: np.random.Generator, step: float = 0.1):
        n = int(math.ceil((t_hi - t_lo) / step)) + 3
        self.t0, self.step, self.o = t_lo - step, step, o
        if o.mode == "free":
            b0 = rng.uniform(-o.max_offset_s, o.max_offset_s)
            f0 = rng.uniform(-o.max_drift_s_s, o.max_drift_s_s)
        elif o.mode == "steered":
            b0 = rng.normal(0.0, o.steered_sigma_s)
            f0 = 0.0
        else:
            raise ValueError(f"clock mode {o.mode!r}: expected 'free' or 'steered'")
        freq = f0 + np.concatenate([[0.0], np.cumsum(rng.normal(0.0, o.frequency_random_walk_s_s_per_sqrt_s
                                                                * math.sqrt(step), n - 1))])
        white = rng.normal(0.0, o.white_frequency_noise * math.sqrt(step), n - 1)
        self.bias = b0 + np.concatenate([[0.0], np.cumsum(0.5 * (freq[1:] + freq[:-1]) * step + white)])

    def continuous(self, t_rel) -> np.ndarray:
        x = (np.asarray(t_rel, float) - self.t0) / self.step
        return np.interp(x, np.arange(len(self.bias)), self.bias)

    def bias_s(self, t_rel) -> np.ndarray:
        b = self.continuous(t_rel)
        if self.o.millisecond_jumps:
            b = b - 1e-3 * np.round(b / 1e-3)
        return b

    def drift_s_s(self, t_rel) -> np.ndarray:
        h = self.step / 2
        return (self.continuous(np.asarray(t_rel) + h) - self.continuous(np.asarray(t_rel) - h)) / (2 * h)


# ----------------------------------------------------------------------------------------------------------
# satellite truth
# ----------------------------------------------------------------------------------------------------------


def _hermite(tq, t0, h, p0, v0, p1, v1):
    s = ((tq - t0) / h)[..., None]
    s2, s3 = s * s, s * s * s
    pos = (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * v0 + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * h * v1
    vel = ((6 * s2 - 6 * s) * p0 + (3 * s2 - 4 * s + 1) * h * v0 + (-6 * s2 + 6 * s) * p1
           + (3 * s2 - 2 * s) * h * v1) / h
    return pos, vel


class _OrbitTruth:
    """True satellite states of each satellite on a grid (relative time), interpolated (cubic Hermite).

    Truth = the broadcast record the engine selects at that time, blended smoothly over `blend_s` across record
    changes, plus the Environment's broadcast error. Also the record selected at each time (for the group delay)."""

    def __init__(self, nav: NavigationData, sat_ids: list[str], T0: float, t_lo: float, t_hi: float, env: Environment):
        self.sat_ids = sat_ids
        self.T0 = T0
        h = _ORBIT_GRID_S
        self.h = h
        self.g0 = math.floor(t_lo / h) * h - h
        n = int(math.ceil((t_hi - self.g0) / h)) + 2
        self.nodes = self.g0 + h * np.arange(n)
        n_s = len(sat_ids)
        self.pos = np.full((n_s, n, 3), np.nan)
        self.vel = np.full((n_s, n, 3), np.nan)
        self.clk = np.full((n_s, n), np.nan)      # m (c * dts)
        self.drift = np.full((n_s, n), np.nan)    # m/s
        self.mid_record: list = []
        t_mid_abs = T0 + 0.5 * (t_lo + t_hi)
        w = env.ephemeris_blend_s
        for i, sat in enumerate(sat_ids):
            self.mid_record.append(select_ephemeris(nav, sat, t_mid_abs))
            # record per grid node, with the switching times between selected records
            probe = np.arange(self.nodes[0] - w, self.nodes[-1] + w + _SELECT_STEP_S, _SELECT_STEP_S)
            recs = [select_ephemeris(nav, sat, T0 + float(t)) for t in probe]
            switches = []   # (time, rec_before, rec_after)
            for k in range(len(probe) - 1):
                if recs[k] is not recs[k + 1]:
                    a, b = float(probe[k]), float(probe[k + 1])
                    for _ in range(40):
                        m = 0.5 * (a + b)
                        if select_ephemeris(nav, sat, T0 + m) is recs[k]:
                            a = m
                        else:
                            b = m
                    switches.append((0.5 * (a + b), recs[k], recs[k + 1]))
            node_rec = [select_ephemeris(nav, sat, T0 + float(t)) for t in self.nodes]
            if all(r is None for r in node_rec):
                continue
            p, v, c, d, ok = self._states(node_rec, self.nodes)
            for ts, ra, rb in switches:
                if ra is None or rb is None:
                    continue
                sel = np.abs(self.nodes - ts) < w / 2
                if not sel.any():
                    continue
                tn = self.nodes[sel]
                pa, va, ca, da, oka = self._states([ra] * len(tn), tn)
                pb, vb, cb, db, okb = self._states([rb] * len(tn), tn)
                u = (tn - (ts - w / 2)) / w
                s = (10 * u**3 - 15 * u**4 + 6 * u**5)[:, None]
                sd = (30 * u**2 * (1 - u) ** 2 / w)[:, None]
                p[sel] = (1 - s) * pa + s * pb
                v[sel] = (1 - s) * va + s * vb + sd * (pb - pa)
                c[sel] = (1 - s[:, 0]) * ca + s[:, 0] * cb
                d[sel] = (1 - s[:, 0]) * da + s[:, 0] * db + sd[:, 0] * (cb - ca)
                ok[sel] = oka & okb
            orbit, clock = env.broadcast_error(sat)
            dt_h = (self.nodes - 0.5 * (t_lo + t_hi)) / 3600.0
            p = p + orbit[0] + dt_h[:, None] * orbit[1]
            v = v + orbit[1] / 3600.0
            c = c + clock[0] + dt_h * clock[1]
            d = d + clock[1] / 3600.0
            p[~ok], v[~ok], c[~ok], d[~ok] = np.nan, np.nan, np.nan, np.nan
            self.pos[i], self.vel[i], self.clk[i], self.drift[i] = p, v, c, d

    def _states(self, records, t_rel):
        st = ephemeris_states(records, self.T0 + np.asarray(t_rel, float))
        return (st.position_ecef_m.copy(), st.velocity_ecef_m_s.copy(), CLIGHT_M_S * st.clock_bias_s,
                CLIGHT_M_S * st.clock_drift_s_s, st.valid.copy())

    def states(self, t_rel: np.ndarray):
        """t_rel (E, S) -> pos (E,S,3), vel (E,S,3), clock (E,S) m, drift (E,S) m/s; NaN where unavailable."""
        k = np.floor((t_rel - self.g0) / self.h).astype(np.int64)
        k = np.clip(k, 0, len(self.nodes) - 2)
        s_idx = np.broadcast_to(np.arange(len(self.sat_ids))[None, :], t_rel.shape)
        t0 = self.nodes[k]
        pos, vel = _hermite(t_rel, t0, self.h, self.pos[s_idx, k], self.vel[s_idx, k], self.pos[s_idx, k + 1],
                            self.vel[s_idx, k + 1])
        c = np.stack([self.clk[s_idx, k], self.drift[s_idx, k]], -1)
        c1 = np.stack([self.clk[s_idx, k + 1], self.drift[s_idx, k + 1]], -1)
        clk, drift = _hermite(t_rel, t0, self.h, c[..., :1], c[..., 1:], c1[..., :1], c1[..., 1:])
        return pos, vel, clk[..., 0], drift[..., 0]


# ----------------------------------------------------------------------------------------------------------
# truth container
# ----------------------------------------------------------------------------------------------------------


@dataclass
class SimulatedTruth:
    """Everything injected into one receiver's observations, on its epochs (aligned with RawObservations)."""

    receiver_time_s: np.ndarray       # (E,) time tags as written (receiver time)
    true_time_s: np.ndarray           # (E,) GPS time of the measurements
    position_ecef_m: np.ndarray       # (E, 3) antenna phase centre at true_time_s
    velocity_ecef_m_s: np.ndarray     # (E, 3)
    clock_bias_s: np.ndarray          # (E,) receiver clock: tag - true time (1 ms jumps included)
    clock_drift_s_s: np.ndarray       # (E,)
    sat_ids: list[str]                # (S,) as RawObservations.sat_ids
    signals: np.ndarray               # (S, N_BANDS) tracked signal per band ('1C', '2W', ... or '')
    wavelength_m: np.ndarray          # (S, N_BANDS)
    ambiguity_cyc: np.ndarray         # (E, S, N_BANDS) integer carrier ambiguity N (NaN where not tracked)
    slips: list[SlipRecord]
    outages: list[tuple[str, float, float]]   # (sat, start, end) receiver time
    elevation_rad: np.ndarray         # (E, S) NaN where not tracked
    azimuth_rad: np.ndarray
    range_m: np.ndarray               # (E, S) geometric range with the Earth-rotation term (true orbit)
    satellite_clock_m: np.ndarray     # (E, S) c * true satellite clock (broadcast + error)
    troposphere_m: np.ndarray         # (E, S)
    ionosphere_m: np.ndarray          # (E, S, N_BANDS) code delay (phase advance) per band
    group_delay_m: np.ndarray         # (S, N_BANDS) c * TGD_b added to code
    receiver_code_bias_m: np.ndarray  # (S, N_BANDS) receiver code bias of each satellite's system and band
    code_error_m: np.ndarray          # (E, S, N_BANDS) multipath + noise on code
    phase_error_m: np.ndarray         # (E, S, N_BANDS) multipath + noise on phase (m)
    event_gps_time_s: np.ndarray      # (N,) true GPS times of the camera events
    event_position_ecef_m: np.ndarray  # (N, 3)
    event_velocity_ecef_m_s: np.ndarray
    dropped_epochs_s: np.ndarray      # receiver time tags requested but not written (gaps)

    @property
    def n_epochs(self) -> int:
        return len(self.receiver_time_s)

    def save_npz(self, path) -> None:
        arrays = {k: v for k, v in self.__dict__.items() if isinstance(v, np.ndarray)}
        arrays["sat_ids"] = np.array(self.sat_ids)
        arrays["slips"] = np.array([(s.epoch, s.receiver_time_s, s.band, s.cycles, s.flagged) for s in self.slips],
                                   dtype=float).reshape(-1, 5)
        arrays["slip_sats"] = np.array([s.sat_id for s in self.slips], dtype="<U3")
        np.savez_compressed(path, **arrays)


def single_difference_ambiguities(rover: SimulatedTruth, base: SimulatedTruth, max_age_s: float = 30.0) -> np.ndarray:
    """(E_rover, S_rover, N_BANDS) true single-difference ambiguities N_rover - N_base on the rover's epochs, the
    base taken at its latest epoch at or before the rover's time tag (NaN where either is missing)."""
    out = np.full(rover.ambiguity_cyc.shape, np.nan)
    tb = base.receiver_time_s
    j = np.searchsorted(tb, rover.receiver_time_s + 1e-3, side="right") - 1
    ok = (j >= 0) & (rover.receiver_time_s - tb[np.clip(j, 0, None)] <= max_age_s)
    col = {s: i for i, s in enumerate(base.sat_ids)}
    for s, sat in enumerate(rover.sat_ids):
        if sat not in col:
            continue
        nb = base.ambiguity_cyc[np.clip(j, 0, None), col[sat]]
        out[ok, s] = rover.ambiguity_cyc[ok, s] - nb[ok]
    return out


# ----------------------------------------------------------------------------------------------------------
# the simulator
# ----------------------------------------------------------------------------------------------------------


def _candidate_satellites(nav: NavigationData, systems: Sequence[str]) -> list[str]:
    sats = set(nav.kepler) | set(nav.glonass)
    return sorted((s for s in sats if s[0] in systems), key=lambda s: (SYSTEM_ORDER.index(s[0]), int(s[1:])))


def _unit_process(rng: np.random.Generator, periods: tuple[float, float], k: int = 4):
    """Parameters of a unit-RMS sum of k sinusoids with log-uniform periods (see _unit_eval)."""
    p = np.exp(rng.uniform(math.log(periods[0]), math.log(periods[1]), k))
    ph = rng.uniform(0, 2 * np.pi, k)
    a = rng.normal(size=k)
    a *= math.sqrt(2.0) / np.linalg.norm(a)
    return p, ph, a


def _unit_eval(params, t_rel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Value and time derivative of a _unit_process at t_rel (1-D)."""
    p, ph, a = params
    arg = 2 * np.pi * np.asarray(t_rel)[:, None] / p + ph
    return np.cos(arg) @ a, -(np.sin(arg) * (2 * np.pi / p)) @ a


def _in_intervals(t: np.ndarray, intervals) -> np.ndarray:
    out = np.zeros(len(t), bool)
    for a, b in intervals:
        out |= (t >= a) & (t < b)
    return out


def simulate_receiver(nav: NavigationData, position_fn: PositionFn, velocity_fn: PositionFn, epochs_gps_s,
                      options: ReceiverOptions | None = None, rng: np.random.Generator | None = None, *,
                      environment: Environment | None = None, events_gps_s=None,
                      source_path: str = "simulated") -> tuple[RawObservations, SimulatedTruth]:
    """Raw observations of one receiver.

    position_fn(t) / velocity_fn(t): (N,) true GPS times -> (N, 3) ECEF antenna phase centre (m, m/s).
    epochs_gps_s: receiver time tags (see :func:`epoch_grid`); epochs in ``options.gaps`` / random gaps are not
    written (tracking goes on). events_gps_s: camera trigger marks (true GPS time), stored as
    ``RawObservations.event_gps_time_s``. environment: share one between the receivers of a survey (default: a
    new ``Environment()`` bound to this receiver). Returns ``(RawObservations, SimulatedTruth)``."""
    o = options or ReceiverOptions()
    rng = rng if rng is not None else np.random.default_rng(0)
    env = environment if environment is not None else Environment()
    sig_map = o.active_signals()
    seeds = rng.integers(0, 2**62, size=8)
    g_clock, g_noise, g_events, g_misc = (np.random.default_rng(int(s)) for s in seeds[:4])
    mp_seed = int(seeds[4])

    tags = np.unique(np.asarray(epochs_gps_s, dtype=float))
    if len(tags) == 0:
        raise ValueError("no epochs to simulate")
    T0 = float(math.floor(tags[0]))
    rel_tags_all = tags - T0
    span = float(rel_tags_all[-1])
    # --- epochs written (gaps: radio or logging losses)
    gaps = list(o.gaps)
    if o.random_gap_rate_per_hour > 0:
        n_gap = g_events.poisson(o.random_gap_rate_per_hour * max(span, 1.0) / 3600.0)
        for _ in range(n_gap):
            a = tags[0] + g_events.uniform(0, span)
            gaps.append((a, a + g_events.uniform(*o.random_gap_duration_s)))
    keep = ~_in_intervals(tags, gaps)
    dropped = tags[~keep]
    tags, rel_tags = tags[keep], rel_tags_all[keep]
    if len(tags) == 0:
        raise ValueError("every epoch falls in a gap")
    n_e = len(tags)

    # --- receiver clock and true times
    clock = _Clock(o.clock, -1.0, span + 1.0, g_clock)
    t_rel = rel_tags.copy()
    for _ in range(4):
        t_rel = rel_tags - clock.bias_s(t_rel)
    dtr = clock.bias_s(t_rel)
    ddtr = clock.drift_s_s(t_rel)
    t_abs = T0 + t_rel
    rpos = np.asarray(position_fn(t_abs), dtype=float).reshape(n_e, 3)
    rvel = np.asarray(velocity_fn(t_abs), dtype=float).reshape(n_e, 3)
    env.bind(rpos[0], float(t_abs[0]))

    # --- satellites, signals, wavelengths
    sats = _candidate_satellites(nav, list(sig_map))
    fcn = nav.glonass_fcn()
    sats = [s for s in sats if s[0] != "R" or s in fcn]
    n_s = len(sats)
    sig_names = np.full((n_s, N_BANDS), "", dtype="<U2")
    for i, sat in enumerate(sats):
        for sig in sig_map[sat[0]]:
            band = RINEX_DIGIT_TO_BAND.get(sat[0], {}).get(sig[0])
            if band is not None and _signal_available(sat, sig):
                sig_names[i, band] = sig
    lam = wavelength_table_m(sats, fcn)
    has_sig = (sig_names != "") & np.isfinite(lam)
    lam_safe = np.where(np.isfinite(lam), lam, 1.0)

    # --- geometry: transmission time, ranges
    orbit = _OrbitTruth(nav, sats, T0, float(t_rel.min()) - 0.5, float(t_rel.max()) + 0.5, env)
    tau = np.full((n_e, n_s), 0.075)
    rcv = rpos[:, None, :]
    for _ in range(3):
        spos, svel, sclk, sdrift = orbit.states(t_rel[:, None] - tau)
        rho, _ = geometric_range_m(np.nan_to_num(spos), rcv)
        tau = rho / CLIGHT_M_S
    spos, svel, sclk, sdrift = orbit.states(t_rel[:, None] - tau)
    valid = np.isfinite(spos).all(axis=-1) & np.isfinite(sclk)
    spos0 = np.nan_to_num(spos)
    svel0 = np.nan_to_num(svel)
    rho, los = geometric_range_m(spos0, rcv)
    w = OMEGA_EARTH_RAD_S / CLIGHT_M_S      # d/dt of geometric_range_m's Earth-rotation term, and 1 - dtau/dt
    a_term = np.einsum("esk,esk->es", los, svel0) + w * (svel0[..., 0] * rcv[..., 1] - svel0[..., 1] * rcv[..., 0])
    b_term = -np.einsum("esk,ek->es", los, rvel) \
        + w * (spos0[..., 0] * rvel[:, None, 1] - spos0[..., 1] * rvel[:, None, 0])
    rho_dot = (a_term + b_term) / (1.0 + a_term / CLIGHT_M_S)
    az, el, llh = azimuth_elevation_batch(rpos, los)

    # --- tracking: mask, outages, arcs
    mask = np.radians(o.tracking_mask_deg)
    visible = valid & (el >= mask)
    outages: list[tuple[str, float, float]] = []
    outage_between = np.zeros((n_e, n_s), bool)
    if o.outage_rate_per_hour > 0:
        for i, sat in enumerate(sats):
            n_out = g_events.poisson(o.outage_rate_per_hour * max(span, 1.0) / 3600.0)
            for _ in range(n_out):
                a = T0 + g_events.uniform(0, span)
                b = a + g_events.uniform(*o.outage_duration_s)
                outages.append((sat, a, b))
                inside = (tags >= a) & (tags < b)
                visible[inside, i] = False
                # an outage between two written epochs also breaks the lock
                k = np.searchsorted(tags, b)
                if k < n_e:
                    outage_between[k, i] = True
    prev_vis = np.zeros_like(visible)
    prev_vis[1:] = visible[:-1]
    arc_start = visible & (~prev_vis | outage_between)
    arc_id = np.cumsum(arc_start, axis=0)

    # --- atmosphere
    def delays(dt):
        p = rpos + rvel * dt
        sp = spos0 + svel0 * dt
        d = sp - p[:, None, :]
        los_ = d / np.linalg.norm(d, axis=-1, keepdims=True)
        az_, el_, llh_ = azimuth_elevation_batch(p, los_)
        ta = t_abs + dt
        trop = env.troposphere_m(ta, p, llh_, el_)
        iono1 = env.ionosphere_l1_m(nav, ta, llh_, az_, el_)
        return trop, iono1, el_

    trop, iono1, _ = delays(0.0)
    hstep = 0.5
    trop_p, iono_p, _ = delays(hstep)
    trop_m, iono_m, _ = delays(-hstep)
    trop_rate = (trop_p - trop_m) / (2 * hstep)
    iono_rate1 = (iono_p - iono_m) / (2 * hstep)
    f_ratio2 = (L1_HZ / (CLIGHT_M_S / lam_safe)) ** 2                 # (S, B)
    iono = iono1[..., None] * f_ratio2[None]
    iono_rate = iono_rate1[..., None] * f_ratio2[None]

    # --- biases
    code_bias = np.zeros((n_s, N_BANDS))
    sys_bias = {sysc: (0.0 if sysc in "GJ" else g_misc.normal(0.0, o.system_code_bias_m)) for sysc in SYSTEM_ORDER}
    band_bias = {(sysc, b): (0.0 if b == 0 else g_misc.normal(0.0, o.band_code_bias_m))
                 for sysc in SYSTEM_ORDER for b in range(N_BANDS)}
    for b in range(N_BANDS):    # QZSS shares GPS's band biases (same signals, one SPP clock)
        band_bias[("J", b)] = band_bias[("G", b)]
    tgd = np.zeros((n_s, N_BANDS))
    for i, sat in enumerate(sats):
        for b in range(N_BANDS):
            code_bias[i, b] = sys_bias[sat[0]] + band_bias[(sat[0], b)]
            rec = orbit.mid_record[i]
            if rec is not None:
                tgd[i, b] = CLIGHT_M_S * group_delay_s(rec, b)

    # --- per-signal quality, noise, multipath, C/N0
    sin_el = np.sin(np.maximum(el, np.radians(1.0)))
    el_deg = np.degrees(np.maximum(el, 0.0))
    mp_shape = np.exp(-el_deg / o.multipath_elevation_scale_deg)
    code_err = np.zeros((n_e, n_s, N_BANDS))
    phase_err = np.zeros((n_e, n_s, N_BANDS))
    mp_phase_rate = np.zeros((n_e, n_s, N_BANDS))
    snr = np.full((n_e, n_s, N_BANDS), np.nan)
    dop_noise = np.zeros((n_e, n_s, N_BANDS))
    cn0_base = o.cn0_horizon_dbhz + (o.cn0_zenith_dbhz - o.cn0_horizon_dbhz) * np.sqrt(np.maximum(np.sin(el), 0.0))
    for i, sat in enumerate(sats):
        for b in range(N_BANDS):
            if not has_sig[i, b]:
                continue
            qc, qp, qs = _SIGNAL_QUALITY.get((sat[0], sig_names[i, b]), (1.0, 1.0, 0.0))
            g = _sat_seed(mp_seed, 3, sat, b)
            mp_c, _ = _unit_eval(_unit_process(g, o.multipath_period_s), t_rel)
            mp_p, mp_p_dot = _unit_eval(_unit_process(g, o.multipath_period_s), t_rel)
            sig_code = o.code_sigma_a_m + o.code_sigma_b_m / sin_el[:, i]
            sig_phase = o.phase_sigma_a_m + o.phase_sigma_b_m / sin_el[:, i]
            code_err[:, i, b] = qc * (o.code_multipath_m * mp_shape[:, i] * mp_c + sig_code * g_noise.normal(size=n_e))
            phase_err[:, i, b] = qp * (o.phase_multipath_m * mp_shape[:, i] * mp_p
                                       + sig_phase * g_noise.normal(size=n_e))
            # the Doppler sees the slowly varying phase multipath too (its elevation-shape change is neglected)
            mp_phase_rate[:, i, b] = qp * o.phase_multipath_m * mp_shape[:, i] * mp_p_dot
            dop_noise[:, i, b] = (o.doppler_sigma_a_hz + o.doppler_sigma_b_hz / sin_el[:, i]) * g_noise.normal(size=n_e)
            s = cn0_base[:, i] + qs + o.cn0_noise_db * g_noise.normal(size=n_e) - 3.0 * mp_shape[:, i] * np.abs(mp_c)
            if o.snr_resolution_dbhz > 0:
                s = np.round(s / o.snr_resolution_dbhz) * o.snr_resolution_dbhz
            snr[:, i, b] = np.clip(s, 10.0, 60.0)

    # --- ambiguities per arc and band, cycle slips
    tracked = visible[..., None] & has_sig[None]
    amb = np.full((n_e, n_s, N_BANDS), np.nan)
    lli = np.zeros((n_e, n_s, N_BANDS), np.uint8)
    for i in range(n_s):
        for b in range(N_BANDS):
            if not has_sig[i, b]:
                continue
            ids = arc_id[:, i]
            n_arcs = int(ids.max()) if n_e else 0
            values = g_misc.integers(-_AMBIGUITY_RANGE, _AMBIGUITY_RANGE, size=n_arcs + 1).astype(float)
            amb[:, i, b] = np.where(tracked[:, i, b], values[ids], np.nan)
            if o.lli_on_reacquisition:
                starts = arc_start[:, i].copy()
                starts[0] = False
                lli[starts & tracked[:, i, b], i, b] |= 1
    slip_records: list[SlipRecord] = []
    sat_index = {s: i for i, s in enumerate(sats)}
    for sl in o.slips:
        i = sat_index.get(sl.sat_id)
        if i is None:
            continue
        e0 = int(np.searchsorted(tags, sl.time_gps_s - 1e-6))
        if e0 >= n_e or not visible[e0, i]:
            continue
        bands = [sl.band] if sl.band is not None else [b for b in range(N_BANDS) if has_sig[i, b]]
        same_arc = arc_id[:, i] == arc_id[e0, i]
        same_arc[:e0] = False
        for b in bands:
            if not has_sig[i, b]:
                continue
            amb[same_arc, i, b] += sl.cycles
            if sl.flagged:
                lli[e0, i, b] |= 1
            slip_records.append(SlipRecord(e0, float(tags[e0]), sl.sat_id, b, int(sl.cycles), bool(sl.flagged)))

    # --- observables
    clk_m = CLIGHT_M_S * dtr[:, None]
    common = rho + clk_m - sclk + trop                                   # (E,S)
    code = common[..., None] + tgd[None] + iono + code_bias[None] + code_err
    phase = (common[..., None] - iono + phase_err) / lam_safe[None] + amb
    rate = rho_dot + CLIGHT_M_S * ddtr[:, None] - np.nan_to_num(sdrift) + trop_rate
    doppler = -(rate[..., None] - iono_rate + mp_phase_rate) / lam_safe[None] + dop_noise
    for arr in (code, phase, doppler, snr):
        arr[~tracked] = np.nan

    # --- assemble RawObservations (only satellites observed at least once)
    seen = tracked.any(axis=(0, 2))
    keep_s = np.nonzero(seen)[0]
    out_sats = [sats[i] for i in keep_s]
    systems_present = [s for s in SYSTEM_ORDER if any(x[0] == s for x in out_sats)]
    obs_codes: list[str] = []
    for sysc in systems_present:
        for sig in sig_map[sysc]:
            for t in "CLDS":
                if t + sig not in obs_codes:
                    obs_codes.append(t + sig)
    n_k = len(obs_codes)
    values = np.full((n_e, len(keep_s), n_k), np.nan)
    lli_out = np.zeros((n_e, len(keep_s), n_k), np.uint8)
    ssi_out = np.zeros((n_e, len(keep_s), n_k), np.uint8)
    ssi_digit = np.where(np.isfinite(snr), np.clip(np.floor(np.nan_to_num(snr) / 6.0), 1, 9), 0).astype(np.uint8)
    for j, i in enumerate(keep_s):
        for b in range(N_BANDS):
            sig = sig_names[i, b]
            if not has_sig[i, b]:
                continue
            for t, arr in zip("CLDS", (code, phase, doppler, snr)):
                k = obs_codes.index(t + sig)
                values[:, j, k] = arr[:, i, b]
                if t != "S":
                    ssi_out[:, j, k] = ssi_digit[:, i, b]
                if t == "L":
                    lli_out[:, j, k] = lli[:, i, b]
    has_epoch = np.isfinite(values).any(axis=(1, 2))
    ev = np.sort(np.asarray(events_gps_s if events_gps_s is not None else [], dtype=float))
    header = ReceiverHeader(
        marker_name=o.marker_name, receiver_type=o.receiver_type, antenna_type=o.antenna_type,
        approx_position_ecef_m=rpos.mean(axis=0) if o.header_position else None,
        interval_s=float(np.median(np.diff(tags))) if n_e > 1 else None,
        glonass_fcn={s: int(fcn[s]) for s in out_sats if s[0] == "R"})
    e_sel = np.nonzero(has_epoch)[0]
    raw = RawObservations(source_path=source_path, gps_time_s=tags[e_sel], sat_ids=out_sats, obs_codes=obs_codes,
                          values=values[e_sel], lli=lli_out[e_sel], ssi=ssi_out[e_sel], header=header,
                          event_gps_time_s=ev, epoch_flags=np.zeros(len(e_sel), np.uint8))
    remap = {int(e): n for n, e in enumerate(e_sel)}
    sl_out = [replace(s, epoch=remap[s.epoch]) for s in slip_records if s.epoch in remap]
    ix = np.ix_(e_sel, keep_s)

    def nan_untracked2(a):
        a = a.copy()
        a[~visible] = np.nan
        return a[ix]

    ev_pos = np.asarray(position_fn(ev), float).reshape(len(ev), 3) if len(ev) else np.zeros((0, 3))
    ev_vel = np.asarray(velocity_fn(ev), float).reshape(len(ev), 3) if len(ev) else np.zeros((0, 3))
    truth = SimulatedTruth(
        receiver_time_s=tags[e_sel], true_time_s=t_abs[e_sel], position_ecef_m=rpos[e_sel],
        velocity_ecef_m_s=rvel[e_sel], clock_bias_s=dtr[e_sel], clock_drift_s_s=ddtr[e_sel], sat_ids=out_sats,
        signals=sig_names[keep_s], wavelength_m=lam[keep_s], ambiguity_cyc=amb[ix],
        slips=sl_out, outages=[x for x in outages if x[0] in out_sats],
        elevation_rad=nan_untracked2(el), azimuth_rad=nan_untracked2(az), range_m=nan_untracked2(rho),
        satellite_clock_m=nan_untracked2(sclk), troposphere_m=nan_untracked2(trop),
        ionosphere_m=np.where(tracked, iono, np.nan)[ix], group_delay_m=tgd[keep_s],
        receiver_code_bias_m=code_bias[keep_s], code_error_m=np.where(tracked, code_err, np.nan)[ix],
        phase_error_m=np.where(tracked, phase_err, np.nan)[ix], event_gps_time_s=ev,
        event_position_ecef_m=ev_pos, event_velocity_ecef_m_s=ev_vel,
        dropped_epochs_s=np.concatenate([dropped, tags[~has_epoch]]))
    return raw, truth


# ----------------------------------------------------------------------------------------------------------
# a survey: rover + base
# ----------------------------------------------------------------------------------------------------------


@dataclass
class SimulatedSurvey:
    rover: RawObservations
    base: RawObservations
    rover_truth: SimulatedTruth
    base_truth: SimulatedTruth
    base_position_ecef_m: np.ndarray
    environment: Environment
    nav: NavigationData

    @property
    def sd_ambiguity_cyc(self) -> np.ndarray:
        """(E_rover, S_rover, N_BANDS) N_rover - N_base on the rover's epochs."""
        return single_difference_ambiguities(self.rover_truth, self.base_truth)


def simulate_survey(nav: NavigationData, rover_position_fn: PositionFn, rover_velocity_fn: PositionFn,
                    rover_epochs_gps_s, base_position_ecef_m, base_epochs_gps_s, *,
                    rover_options: ReceiverOptions | None = None, base_options: ReceiverOptions | None = None,
                    environment: Environment | None = None, seed: int = 0, events_gps_s=None) -> SimulatedSurvey:
    """A rover on a trajectory and a static base, in one shared environment (bound to the base position and the
    base's first epoch), deterministic for ``seed``. Defaults: geodetic receivers; the rover's antenna multipath is
    that of a drone (weaker, periods 5-60 s), the base's that of a static site (periods 1-10 min).
    Use ``SimulatedSurvey.sd_ambiguity_cyc`` for the single-difference ambiguity truth."""
    env = environment if environment is not None else Environment(seed=seed)
    base_pos = np.asarray(base_position_ecef_m, float).reshape(3)
    env.bind(base_pos, float(np.min(base_epochs_gps_s)))
    ss = np.random.SeedSequence([abs(int(seed)), 2024])
    g_rover, g_base = (np.random.default_rng(s) for s in ss.spawn(2))
    bo = base_options or ReceiverOptions(marker_name="BASE")
    ro = rover_options or ReceiverOptions(marker_name="ROVR", multipath_period_s=(5.0, 60.0), code_multipath_m=0.2,
                                          phase_multipath_m=0.002)
    bpos, bvel = static_trajectory(base_pos)
    base, base_truth = simulate_receiver(nav, bpos, bvel, base_epochs_gps_s, bo, g_base, environment=env,
                                         source_path="simulated_base")
    rover, rover_truth = simulate_receiver(nav, rover_position_fn, rover_velocity_fn, rover_epochs_gps_s, ro, g_rover,
                                           environment=env, events_gps_s=events_gps_s, source_path="simulated_rover")
    return SimulatedSurvey(rover, base, rover_truth, base_truth, base_pos, env, nav)


# ----------------------------------------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------------------------------------


def _rinex2_subset(raw: RawObservations) -> RawObservations:
    keep = [i for i, s in enumerate(raw.sat_ids) if s[0] in "GRES"]
    return RawObservations(raw.source_path, raw.gps_time_s, [raw.sat_ids[i] for i in keep], raw.obs_codes,
                           raw.values[:, keep], raw.lli[:, keep], raw.ssi[:, keep], raw.header, raw.event_gps_time_s,
                           raw.epoch_flags)


def write_survey_gnss(out_dir, rover: RawObservations, base: RawObservations, nav_paths=(), *, rinex_version: int = 3,
                      rover_name: str = "rover", base_name: str = "base", truth: SimulatedSurvey | None = None,
                      program: str = "georef-sim") -> dict[str, list[Path]]:
    """Write ``out_dir/rover/``, ``out_dir/base/`` (RINEX 3.04 '<name>.obs' or RINEX 2.11 '<name>.<yy>o') and copy
    the navigation file(s) into ``out_dir/nav/``. RINEX 2.11 holds GPS, GLONASS, Galileo and SBAS only: QZSS and
    BeiDou satellites are left out of those files. With ``truth``, the two SimulatedTruth are saved as
    ``out_dir/truth/gnss_{rover,base}_truth.npz``. Returns the written paths by folder."""
    from ..gnss.gnss_time import gps_time_s_to_datetime

    out = Path(out_dir)
    written: dict[str, list[Path]] = {"rover": [], "base": [], "nav": [], "truth": []}
    for folder, raw, name in (("rover", rover, rover_name), ("base", base, base_name)):
        d = out / folder
        d.mkdir(parents=True, exist_ok=True)
        if rinex_version == 3:
            path = d / f"{name}.obs"
            write_rinex3_obs(path, raw, program=program)
        elif rinex_version == 2:
            yy = gps_time_s_to_datetime(float(raw.gps_time_s[0])).year % 100
            path = d / f"{name}.{yy:02d}o"
            write_rinex2_obs(path, _rinex2_subset(raw), program=program)
        else:
            raise ValueError(f"rinex_version {rinex_version}: expected 2 or 3")
        written[folder].append(path)
    if isinstance(nav_paths, (str, Path)):
        nav_paths = [nav_paths]
    nd = out / "nav"
    nd.mkdir(parents=True, exist_ok=True)
    for p in nav_paths:
        dst = nd / Path(p).name
        shutil.copyfile(p, dst)
        written["nav"].append(dst)
    if truth is not None:
        td = out / "truth"
        td.mkdir(parents=True, exist_ok=True)
        for name, tr in (("rover", truth.rover_truth), ("base", truth.base_truth)):
            path = td / f"gnss_{name}_truth.npz"
            tr.save_npz(path)
            written["truth"].append(path)
    return written
