"""The GNSS part of a simulated survey: rover and base RINEX files, the navigation file and the GNSS truth.

:func:`simulate_survey_gnss` turns the simulator's true antenna trajectory, camera events and base-station
point into the files a user uploads::

    rover/rover.obs   (RINEX 3.04; rover.<yy>o with RINEX 2.11) drone receiver, 5 Hz (option 10 Hz), camera
                      trigger time marks as event records (epoch flag 5) at CameraEvent.trigger_gps_time_s
    base/base.obs     static base at Site.base_station_ecef(), 1 Hz, optional logging gaps
    nav/base.nav      the shipped multi-GNSS broadcast navigation file (georef_core/sim/data/base.nav)
    truth/gnss_truth.npz, truth/gnss_truth.json   what was injected (see :func:`write_gnss_truth`)

The observations come from :mod:`georef_core.sim.gnss_observations` (satellite geometry of the real broadcast
file, receiver clocks, atmosphere, multipath, noise, ambiguities, slips). Receiver types:

* ``'l1l2'``: geodetic multi-GNSS dual-frequency receiver (GPS L1C/L2W, GLONASS L1C/L2P, Galileo E1C/E5bQ,
  QZSS L1C/L2L, BeiDou B1I/B2I), rover and base alike;
* ``'l1'``: u-blox M8T-like GPS + GLONASS L1 C/A receiver (noisier code and phase, 1 ms clock jumps), with a
  couple of cycle slips on the rover (LLI flagged); the base is the same receiver type on a tripod.

The shipped navigation file holds only the satellites tracked by the receiver that recorded it (near Nagoya,
2024-06-24 around 08:20 GPST), so the simulated site must be near there and the survey within its validity
(see :func:`navigation_coverage`); :func:`simulate_survey_gnss` checks it.
"""

from __future__ import annotations

import io
import math
import zipfile
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..gnss.ephemeris import ephemeris_states, is_healthy, select_ephemeris
from ..gnss.frames import azimuth_elevation_rad, ecef_to_geodetic
from ..gnss.gnss_time import gps_time_s_to_datetime
from ..gnss.navigation import NavigationData
from .flight import gps_time_to_utc

DATA_DIR = Path(__file__).resolve().parent / "data"
SHIPPED_NAV = DATA_DIR / "base.nav"
RECEIVER_TYPES = ("l1", "l1l2")
ROVER_SYSTEMS = {"l1": ("G", "R"), "l1l2": ("G", "R", "E", "J", "C")}


@dataclass
class GnssOptions:
    """GNSS part of a simulated survey (``SimulationOptions.gnss``; None there: no GNSS files).

    Noise levels (``code_noise_m``, ``phase_noise_m``) are the rover's undifferenced zenith sigmas; None keeps
    the receiver type's (l1l2: 0.2 m / 1.6 mm, l1: 0.5 m / 3 mm, growing as 1 / sin(elevation) for half of
    it). ``base_gaps``: ``base_gap_count`` logging gaps of the base (lengths uniform in ``base_gap_s``) during
    the flight."""

    receiver: str = "l1l2"                      # 'l1l2' | 'l1' (rover; the base too unless base_receiver)
    base_receiver: str | None = None            # None: same type as the rover
    rover_rate_hz: float = 5.0
    base_rate_hz: float = 1.0
    rinex_version: int = 3                      # 3 (3.04) | 2 (2.11: GPS, GLONASS, Galileo only)
    base_gaps: bool = False
    base_gap_count: int = 3
    base_gap_s: tuple[float, float] = (2.0, 15.0)
    code_noise_m: float | None = None
    phase_noise_m: float | None = None
    cycle_slips: int | None = None              # rover slips; None: 2 for 'l1', 0 for 'l1l2'
    base_antenna_height_m: float = 1.8          # above the ground at Site.base_station_site_xy()
    base_lead_s: float = 60.0                   # base logging starts this long before the rover
    base_trail_s: float = 60.0                  # and ends this long after it
    nav_path: str | None = None                 # None: the shipped file (SHIPPED_NAV)
    check_navigation: bool = True               # refuse surveys outside the navigation file's coverage

    def validate(self) -> None:
        for name in ("receiver", "base_receiver"):
            v = getattr(self, name)
            if v is not None and v not in RECEIVER_TYPES:
                raise ValueError(f"GnssOptions.{name}={v!r}: expected one of {', '.join(RECEIVER_TYPES)}")
        if self.rinex_version not in (2, 3):
            raise ValueError(f"GnssOptions.rinex_version={self.rinex_version!r}: expected 2 or 3")
        if not (self.rover_rate_hz > 0 and self.base_rate_hz > 0):
            raise ValueError("GNSS rates must be positive")
        for name in ("code_noise_m", "phase_noise_m"):
            v = getattr(self, name)
            if v is not None and v < 0:
                raise ValueError(f"GnssOptions.{name} must be >= 0")


@dataclass
class SurveyGnssResult:
    rover_path: Path
    base_path: Path
    nav_paths: list[Path]
    truth_npz: Path
    truth_json: Path
    takeoff_antenna_ecef_m: np.ndarray
    base_position_ecef_m: np.ndarray
    survey: object                  # gnss_observations.SimulatedSurvey
    summary: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------------------------------------
# navigation coverage
# ----------------------------------------------------------------------------------------------------------


def _nearest_healthy_record(nav: NavigationData, sat: str, t: float):
    recs = [r for r in (nav.glonass.get(sat) if sat[0] == "R" else nav.kepler.get(sat)) or [] if is_healthy(r)]
    if not recs:
        return None
    return min(recs, key=lambda r: abs(r.toe_gps_s - t))


def navigation_coverage(nav: NavigationData, position_ecef_m, t0_gps_s: float, t1_gps_s: float,
                        systems=("G", "R", "E", "J", "C"), step_s: float = 60.0) -> dict:
    """Whether the navigation data cover a survey at ``position_ecef_m`` over [t0, t1] (GPS s).

    A satellite *lacks* an ephemeris at t when it is above the horizon there (position from its nearest healthy
    record, whatever its age) but the engine's :func:`select_ephemeris` finds no record recent enough
    (satellites never healthy in the file are left out, as the engine does). Returns
    ``{system: {"min_visible": n, "max_visible": n, "missing": [(sat, t), ...]}}``, visible = above 10 deg
    elevation with a usable record, over a grid of ``step_s`` (and both ends)."""
    pos = np.asarray(position_ecef_m, float).reshape(3)
    times = np.unique(np.append(np.arange(t0_gps_s, t1_gps_s, step_s), t1_gps_s))
    out = {}
    for sysc in systems:
        sats = sorted(s for s in (set(nav.kepler) | set(nav.glonass)) if s[0] == sysc)
        counts, missing = [], []
        for t in times:
            n = 0
            for sat in sats:
                rec = select_ephemeris(nav, sat, float(t))
                if rec is None:
                    near = _nearest_healthy_record(nav, sat, float(t))
                    if near is None:   # never healthy: the engine leaves it out anyway
                        continue
                    st = ephemeris_states([near], np.array([t]))
                    if not st.valid[0]:
                        continue
                    _, el = azimuth_elevation_rad(pos, st.position_ecef_m[0])
                    # unhealthy right now: the engine leaves it out, not a gap of the file
                    if el > 0 and select_ephemeris(nav, sat, float(t), require_healthy=False) is None:
                        missing.append((sat, float(t)))
                    continue
                st = ephemeris_states([rec], np.array([t]))
                _, el = azimuth_elevation_rad(pos, st.position_ecef_m[0])
                n += int(el > math.radians(10.0))
            counts.append(n)
        out[sysc] = {"min_visible": int(min(counts)), "max_visible": int(max(counts)), "missing": missing}
    return out


# Satellites above 10 deg a full constellation gives anywhere, at any time (about half the usual count; QZSS is
# regional). A file recorded elsewhere holds only the satellites visible there: far from it, few are left.
MIN_VISIBLE = {"G": 5, "R": 4, "E": 3, "J": 0, "C": 5}


def check_navigation_coverage(nav: NavigationData, position_ecef_m, t0_gps_s: float, t1_gps_s: float,
                              systems, min_visible: dict | None = None) -> None:
    """Raise ValueError if a satellite above the horizon lacks an ephemeris at some time of [t0, t1], or if a
    system has fewer satellites above 10 deg with one than ``min_visible[system]`` (default MIN_VISIBLE)."""
    cov = navigation_coverage(nav, position_ecef_m, t0_gps_s, t1_gps_s, systems)
    need = {**MIN_VISIBLE, **(min_visible or {})}
    problems = []
    for sysc, c in cov.items():
        if c["missing"]:
            sats = sorted({s for s, _ in c["missing"]})
            problems.append(f"{sysc}: no usable ephemeris for {', '.join(sats)} while above the horizon")
        if c["min_visible"] < need.get(sysc, 1):
            problems.append(f"{sysc}: only {c['min_visible']} satellites above 10 deg with an ephemeris")
    if problems:
        a, b = (gps_time_s_to_datetime(float(x)).isoformat(sep=" ") for x in (t0_gps_s, t1_gps_s))
        raise ValueError(
            f"the navigation file does not cover the survey ({a} - {b} GPST): {'; '.join(problems)}. With the "
            "shipped file the site must be near Nagoya (SiteOptions.lat_deg/lon_deg) and the survey within "
            "2024-06-24 08:00-09:15 GPST (FlightOptions.start_utc); or give GnssOptions.nav_path")


# ----------------------------------------------------------------------------------------------------------
# receivers
# ----------------------------------------------------------------------------------------------------------


def _scale_noise(kw: dict, a_key: str, b_key: str, zenith: float | None, defaults) -> None:
    if zenith is None:
        return
    a, b = kw.get(a_key, getattr(defaults, a_key)), kw.get(b_key, getattr(defaults, b_key))
    tot = a + b
    fa = a / tot if tot > 0 else 0.5
    kw[a_key], kw[b_key] = zenith * fa, zenith * (1.0 - fa)


def receiver_options(kind: str, role: str, *, code_noise_m: float | None = None, phase_noise_m: float | None = None,
                     slips=(), gaps=()):
    """ReceiverOptions of a receiver type ('l1' | 'l1l2') as 'rover' (on the drone) or 'base' (on a tripod)."""
    from .gnss_observations import ReceiverOptions

    marker = "ROVR" if role == "rover" else "BASE"
    if kind == "l1":
        kw: dict = {"marker_name": marker}
        if role == "base":   # the same receiver on a tripod in the open: less multipath than on the airframe
            kw.update(code_multipath_m=0.3, phase_multipath_m=0.002, multipath_period_s=(60.0, 600.0))
        else:
            kw.update(code_multipath_m=0.6, phase_multipath_m=0.004)
        _scale_noise(kw, "code_sigma_a_m", "code_sigma_b_m", code_noise_m, ReceiverOptions.ublox_l1())
        _scale_noise(kw, "phase_sigma_a_m", "phase_sigma_b_m", phase_noise_m, ReceiverOptions.ublox_l1())
        return ReceiverOptions.ublox_l1(slips=tuple(slips), gaps=tuple(gaps), **kw)
    if kind == "l1l2":
        kw = {"marker_name": marker, "receiver_type": "GEODETIC SIM", "antenna_type": "GEODETIC_ANT    NONE"}
        if role == "rover":
            kw.update(multipath_period_s=(5.0, 60.0), code_multipath_m=0.2, phase_multipath_m=0.002)
        _scale_noise(kw, "code_sigma_a_m", "code_sigma_b_m", code_noise_m, ReceiverOptions())
        _scale_noise(kw, "phase_sigma_a_m", "phase_sigma_b_m", phase_noise_m, ReceiverOptions())
        return ReceiverOptions.geodetic(slips=tuple(slips), gaps=tuple(gaps), **kw)
    raise ValueError(f"receiver type {kind!r}: expected one of {', '.join(RECEIVER_TYPES)}")


def _pick_slips(nav, base_ecef, systems, t_air0: float, t_air1: float, n: int, rng: np.random.Generator):
    """``n`` CycleSlip on satellites well above the horizon during the airborne part of the flight."""
    from .gnss_observations import CycleSlip

    if n <= 0 or t_air1 <= t_air0:
        return []
    probe = np.linspace(t_air0, t_air1, 5)
    good = []
    for sat in sorted(s for s in (set(nav.kepler) | set(nav.glonass)) if s[0] in systems):
        if sat[0] == "R" and sat not in nav.glonass_fcn():
            continue
        els = []
        for t in probe:
            rec = select_ephemeris(nav, sat, float(t))
            if rec is None:
                break
            st = ephemeris_states([rec], np.array([t]))
            els.append(float(azimuth_elevation_rad(base_ecef, st.position_ecef_m[0])[1]))
        if len(els) == len(probe) and min(els) > math.radians(30.0):
            good.append(sat)
    if not good:
        return []
    sats = rng.choice(good, size=min(n, len(good)), replace=False)
    span = t_air1 - t_air0
    times = np.sort(t_air0 + span * (0.15 + 0.7 * rng.random(len(sats))))
    out = []
    for sat, t in zip(sats, times):
        cyc = int(rng.integers(1, 25)) * int(rng.choice([-1, 1]))
        out.append(CycleSlip(time_gps_s=float(t), sat_id=str(sat), cycles=cyc, band=None, flagged=True))
    return out


def _base_gaps(o: GnssOptions, t0: float, t1: float, rng: np.random.Generator) -> list[tuple[float, float]]:
    if not o.base_gaps or o.base_gap_count <= 0 or t1 - t0 < 60.0:
        return []
    n = int(o.base_gap_count)
    edges = np.linspace(t0 + 20.0, t1 - 20.0, n + 1)   # one gap per sub-interval: no overlaps
    gaps = []
    for k in range(n):
        length = float(rng.uniform(*o.base_gap_s))
        start = float(rng.uniform(edges[k], max(edges[k], edges[k + 1] - length)))
        gaps.append((round(start, 3), round(start + length, 3)))
    return gaps


# ----------------------------------------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------------------------------------


def _fix_rinex_date(path: Path, stamp: str) -> None:
    """Replace the creation date of 'PGM / RUN BY / DATE' (the writer puts the wall-clock time there) with a
    fixed one, so that the same seed gives the same bytes."""
    data = path.read_bytes()
    end = data.find(b"END OF HEADER")
    i = data.find(b"PGM / RUN BY / DATE", 0, end)
    if i < 0:
        return
    line_start = data.rfind(b"\n", 0, i) + 1
    field40 = stamp.encode("ascii")[:20].ljust(20)
    data = data[:line_start + 40] + field40 + data[line_start + 60:]
    path.write_bytes(data)


def _write_npz(path: Path, arrays: dict) -> None:
    """np.savez_compressed with fixed member timestamps (byte-identical for identical arrays)."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, arr in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asanyarray(arr), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue())


NPZ_ARRAYS = {
    "rover_receiver_time_s": "(E,) rover RINEX epoch time tags (receiver time, GPS s)",
    "rover_true_time_s": "(E,) GPS time of the rover measurements (tag - receiver clock bias)",
    "rover_position_ecef_m": "(E, 3) true antenna phase centre at rover_true_time_s",
    "rover_velocity_ecef_m_s": "(E, 3) true antenna velocity",
    "rover_clock_bias_s": "(E,) rover receiver clock bias (tag - true time; 1 ms jumps included for 'l1')",
    "rover_clock_drift_s_s": "(E,)",
    "base_receiver_time_s": "(B,) base epoch tags", "base_true_time_s": "(B,)", "base_clock_bias_s": "(B,)",
    "base_position_ecef_m": "(3,) true base antenna phase centre (also the base RINEX header position)",
    "sat_ids": "(S,) rover satellites", "signals": "(S, 3) RINEX 3 signal per band ('' none)",
    "wavelength_m": "(S, 3)",
    "sd_ambiguity_cyc": "(E, S, 3) true single-difference integer ambiguities N_rover - N_base on the rover "
                        "epochs (base at its latest epoch <= the rover tag; NaN where not both tracked)",
    "slips": "(K, 5) rover cycle slips: epoch index, receiver time, band, cycles, flagged", "slip_sats": "(K,)",
    "event_gps_time_s": "(N,) camera trigger time marks (true GPS time; = events.csv, = RINEX flag-5 epochs)",
    "event_position_ecef_m": "(N, 3) true antenna phase centre at the trigger times",
    "event_velocity_ecef_m_s": "(N, 3)",
    "takeoff_antenna_ecef_m": "(3,) antenna phase centre on the ground before take-off (for --known-start)",
}


def write_gnss_truth(truth_dir: Path, survey, takeoff_ecef: np.ndarray, summary: dict) -> tuple[Path, Path]:
    """truth/gnss_truth.npz (arrays, see NPZ_ARRAYS) and truth/gnss_truth.json (summary)."""
    truth_dir.mkdir(parents=True, exist_ok=True)
    r, b = survey.rover_truth, survey.base_truth
    arrays = {
        "rover_receiver_time_s": r.receiver_time_s, "rover_true_time_s": r.true_time_s,
        "rover_position_ecef_m": r.position_ecef_m, "rover_velocity_ecef_m_s": r.velocity_ecef_m_s,
        "rover_clock_bias_s": r.clock_bias_s, "rover_clock_drift_s_s": r.clock_drift_s_s,
        "base_receiver_time_s": b.receiver_time_s, "base_true_time_s": b.true_time_s,
        "base_clock_bias_s": b.clock_bias_s, "base_position_ecef_m": np.asarray(survey.base_position_ecef_m),
        "sat_ids": np.array(r.sat_ids, dtype="<U3"), "signals": np.asarray(r.signals, dtype="<U2"),
        "wavelength_m": r.wavelength_m, "sd_ambiguity_cyc": survey.sd_ambiguity_cyc,
        "slips": np.array([(s.epoch, s.receiver_time_s, s.band, s.cycles, s.flagged) for s in r.slips],
                          dtype=float).reshape(-1, 5),
        "slip_sats": np.array([s.sat_id for s in r.slips], dtype="<U3"),
        "event_gps_time_s": r.event_gps_time_s, "event_position_ecef_m": r.event_position_ecef_m,
        "event_velocity_ecef_m_s": r.event_velocity_ecef_m_s,
        "takeoff_antenna_ecef_m": np.asarray(takeoff_ecef, float),
    }
    npz = truth_dir / "gnss_truth.npz"
    _write_npz(npz, arrays)
    js = truth_dir / "gnss_truth.json"
    from .truth import write_json

    write_json(js, {**summary, "npz_arrays": NPZ_ARRAYS})
    return npz, js


# ----------------------------------------------------------------------------------------------------------
# the survey
# ----------------------------------------------------------------------------------------------------------


def _llh_deg(ecef) -> list[float]:
    llh = ecef_to_geodetic(np.asarray(ecef, float))
    return [math.degrees(float(llh[0])), math.degrees(float(llh[1])), float(llh[2])]


def simulate_survey_gnss(out_dir, site, trajectory, events, options: GnssOptions | None = None,
                         seed: int = 0) -> SurveyGnssResult:
    """Write rover/, base/, nav/ and truth/gnss_truth.* of a simulated survey into ``out_dir``.

    The rover logs from the first to the last trajectory sample (static periods included) at
    ``rover_rate_hz``, with the camera trigger times as RINEX event records; the base logs at ``base_rate_hz``
    from ``base_lead_s`` before to ``base_trail_s`` after, at ``site.base_station_ecef()``. Deterministic for a
    seed (the GNSS draws from ``SeedSequence([seed, 808])``, independent of the site and flight streams)."""
    from ..gnss.rinex_nav import read_rinex_nav
    from .gnss_observations import Environment, epoch_grid, simulate_survey, write_survey_gnss

    o = options or GnssOptions()
    o.validate()
    out = Path(out_dir)
    nav_path = Path(o.nav_path) if o.nav_path else SHIPPED_NAV
    nav = read_rinex_nav(nav_path)
    base_kind = o.base_receiver or o.receiver
    ss = np.random.SeedSequence([int(seed), 808])
    g_seed, g_slip, g_gap = ss.spawn(3)
    gnss_seed = int(np.random.default_rng(g_seed).integers(0, 2**31 - 1))

    t0, t1 = trajectory.t_start, trajectory.t_end
    base_ecef = np.asarray(site.base_station_ecef(o.base_antenna_height_m), float).reshape(3)
    b0, b1 = t0 - o.base_lead_s, t1 + o.base_trail_s
    systems = sorted(set(ROVER_SYSTEMS[o.receiver]) | set(ROVER_SYSTEMS[base_kind]), key="GREJC".index)
    if o.check_navigation:
        check_navigation_coverage(nav, base_ecef, b0, b1, systems)

    t_air0 = trajectory.info.get("takeoff_gps_time_s") or t0
    t_air1 = trajectory.info.get("landing_gps_time_s") or t1
    n_slips = o.cycle_slips if o.cycle_slips is not None else (2 if o.receiver == "l1" else 0)
    slips = _pick_slips(nav, base_ecef, ROVER_SYSTEMS[o.receiver], t_air0, t_air1, n_slips,
                        np.random.default_rng(g_slip))
    gaps = _base_gaps(o, t0, t1, np.random.default_rng(g_gap))
    rover_o = receiver_options(o.receiver, "rover", code_noise_m=o.code_noise_m, phase_noise_m=o.phase_noise_m,
                               slips=slips)
    base_o = receiver_options(base_kind, "base", gaps=gaps)

    def pos(t):   # receiver clock offsets put the first/last true times up to ~1 ms outside the spline
        return trajectory.position_ecef(np.clip(np.atleast_1d(np.asarray(t, float)), t0, t1))

    def vel(t):
        return trajectory.velocity_ecef(np.clip(np.atleast_1d(np.asarray(t, float)), t0, t1))

    eps = 0.002
    rover_epochs = epoch_grid(t0 + eps, t1 - t0 - 2 * eps, o.rover_rate_hz)
    base_epochs = epoch_grid(b0, b1 - b0, o.base_rate_hz)
    triggers = np.array([e.trigger_gps_time_s for e in events], dtype=float)
    survey = simulate_survey(nav, pos, vel, rover_epochs, base_ecef, base_epochs, rover_options=rover_o,
                             base_options=base_o, environment=Environment(seed=gnss_seed), seed=gnss_seed,
                             events_gps_s=triggers)
    written = write_survey_gnss(out, survey.rover, survey.base, [nav_path], rinex_version=o.rinex_version,
                                program="georef-sim")
    # deterministic header date: the end of the base logging (as if converted right after the survey)
    stamp = gps_time_to_utc(float(survey.base.gps_time_s[-1])).strftime("%Y%m%d %H%M%S UTC")
    for p in written["rover"] + written["base"]:
        _fix_rinex_date(p, stamp)

    takeoff = trajectory.position_ecef(t0)
    rt, bt = survey.rover_truth, survey.base_truth
    rover_path, base_path = written["rover"][0], written["base"][0]
    rel = {k: [str(p.relative_to(out)) for p in v] for k, v in written.items() if v}
    freq = "l1" if "l1" in (o.receiver, base_kind) else "l1+l2"
    x, y, z = (f"{v:.4f}" for v in takeoff)
    cmd = (f"georef gnss solve {rel['rover'][0]} {rel['base'][0]} {' '.join(rel['nav'])} --out ppk/trajectory.pos "
           f"--freq {freq} --mode known-start --known-start={x},{y},{z}")
    n_sys: dict[str, int] = {}
    for s in rt.sat_ids:
        n_sys[s[0]] = n_sys.get(s[0], 0) + 1
    summary = {
        "seed": int(seed), "gnss_seed": gnss_seed,
        "receiver": {"rover": o.receiver, "base": base_kind},
        "rinex_version": "3.04" if o.rinex_version == 3 else "2.11",
        "files": rel,
        "navigation": {"file": nav_path.name, "systems_used": systems},
        "rover": {
            "rate_hz": o.rover_rate_hz, "n_epochs": int(rt.n_epochs),
            "first_epoch_gps_s": float(rt.receiver_time_s[0]), "last_epoch_gps_s": float(rt.receiver_time_s[-1]),
            "first_epoch_utc": None, "satellites_per_system": n_sys,
            "clock_bias_s_range": [float(np.min(rt.clock_bias_s)), float(np.max(rt.clock_bias_s))],
            "n_events": int(len(triggers)),
            "noise": {"code_sigma_a_m": rover_o.code_sigma_a_m, "code_sigma_b_m": rover_o.code_sigma_b_m,
                      "phase_sigma_a_m": rover_o.phase_sigma_a_m, "phase_sigma_b_m": rover_o.phase_sigma_b_m,
                      "code_multipath_m": rover_o.code_multipath_m, "phase_multipath_m": rover_o.phase_multipath_m,
                      "model": "sigma = a + b / sin(elevation), times a per-signal factor, + multipath"},
            "signals": {k: list(v) for k, v in rover_o.active_signals().items()},
        },
        "base": {
            "rate_hz": o.base_rate_hz, "n_epochs": int(bt.n_epochs), "position_ecef_m": base_ecef,
            "position_llh_deg_m": _llh_deg(base_ecef), "antenna_height_above_ground_m": o.base_antenna_height_m,
            "first_epoch_gps_s": float(bt.receiver_time_s[0]), "last_epoch_gps_s": float(bt.receiver_time_s[-1]),
            "gaps_receiver_time_s": [list(g) for g in gaps], "dropped_epochs": int(len(bt.dropped_epochs_s)),
            "header_position": "APPROX POSITION XYZ is the true antenna phase centre",
            "signals": {k: list(v) for k, v in base_o.active_signals().items()},
        },
        "takeoff_antenna_ecef_m": takeoff, "takeoff_antenna_llh_deg_m": _llh_deg(takeoff),
        "slips": [{"sat": s.sat_id, "band": s.band, "signal": str(rt.signals[rt.sat_ids.index(s.sat_id), s.band]),
                   "epoch": s.epoch, "receiver_time_s": s.receiver_time_s, "cycles": s.cycles, "flagged": s.flagged}
                  for s in rt.slips],
        "options": asdict(o),
        "solve_command": cmd,
        "conventions": "times are gps_time_s (GPS seconds since 1980-01-06); RINEX epoch tags are receiver time "
                       "(true time + receiver clock bias), event records are true GPS times of the trigger time "
                       "marks; positions are the antenna phase centre (no antenna offsets or PCV modelled)",
    }
    summary["rover"]["first_epoch_utc"] = gps_time_to_utc(float(rt.receiver_time_s[0])).isoformat() + "Z"
    npz, js = write_gnss_truth(out / "truth", survey, takeoff, summary)
    return SurveyGnssResult(rover_path=rover_path, base_path=base_path, nav_paths=written["nav"], truth_npz=npz,
                            truth_json=js, takeoff_antenna_ecef_m=takeoff, base_position_ecef_m=base_ecef,
                            survey=survey, summary=summary)
