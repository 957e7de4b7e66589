"""Survey flight of a multirotor: plan, true trajectory, attitude and camera events.

The true trajectory is that of the **GNSS antenna phase centre** (APC). It is *defined* as a quintic
interpolating B-spline through position knots sampled every ``1 / knot_rate_hz`` seconds (local ENU
frame of the site, see :mod:`georef_core.sim.geo`); velocities and accelerations are the spline's
exact derivatives. The camera attitude is a :class:`scipy.spatial.transform.RotationSpline` through
attitude knots at the same instants. ``truth/trajectory.csv`` holds the knots, and
:meth:`Trajectory.from_csv` rebuilds the same interpolators from it.

Time is ``gps_time_s`` (GPS seconds since 1980-01-06, float64) everywhere.

Lever arm and delay convention
------------------------------
``lever_arm_cam_m`` is the vector from the antenna phase centre to the camera's projection centre,
expressed in the camera frame (x right, y down in the image, z along the optical axis). A camera
event has a trigger time ``t_trig`` (the GNSS receiver's time mark) and an exposure time
``t_exp = t_trig + delay_s``. The truth camera centre of an image is exactly::

    C = apc(t_exp) + R_cam_to_world(t_exp) @ lever_arm_cam_m

The georeferencing step models it to first order from the antenna state at the time mark::

    C ~= apc(t_trig) + R_cam_to_world @ lever_arm_cam_m + v_apc(t_trig) * delay_s

(the two differ by ~ a * delay^2 / 2 and the rotation during the delay; both are sub-millimetre on the
straight lines, and are reported by :meth:`CameraEvent` consumers if needed).

Attitude model
--------------
With ``camera_mount="gimbal"`` the camera stays level with the heading (a stabilised gimbal, as on
DJI RTK aircraft) and only the body tilts; the antenna -> camera vector then depends on the attitude
(``antenna_to_camera_enu``). Otherwise the camera is rigidly mounted on the body, pointing at nadir, image top towards the nose:
``R_cam_to_body = [[0,-1,0],[1,0,0],[0,0,1]]`` with the body frame FRD (x forward, y right, z down).
The body's up axis follows the thrust a multirotor needs: ``a + g e_up + drag (v - wind)``, so it
pitches into its acceleration and air speed and rolls against a cross wind; its heading follows the
direction of travel of each leg, turned smoothly at the stops between legs; smooth random roll, pitch
and yaw (sums of sinusoids) are added in flight. On the ground the body is level.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import make_interp_spline
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation, RotationSpline

from ..gnss.gnss_time import gps_time_s_to_datetime, leap_seconds_at, utc_datetime_to_gps_time_s
from .camera import CameraModel
from .geo import SiteFrame

G_M_S2 = 9.80665
R_CAM_TO_BODY = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
# body FRD expressed in ENU for a level body heading north is [[0,1,0],[1,0,0],[0,0,-1]] (columns F, R, D)


@dataclass
class FlightOptions:
    height_m: float = 60.0  # flight height above the take-off ground
    # a calibration flight: every other pair of lines flown at this second height (None: one height).
    # Two heights separate the lever arm from the focal length and principal point (docs/georeferencing.md)
    second_height_m: float | None = None
    # ... and at this second ground speed (separates the along-track lever arm from the trigger delay)
    second_speed_m_s: float | None = None
    speed_m_s: float = 5.0  # ground speed on the lines
    forward_overlap: float = 0.75
    side_overlap: float = 0.65
    line_bearing_deg: float | None = None  # grid bearing of the lines; None: along the longer side
    extra_triggers: int = 1  # triggers added beyond each end of the work area on every line
    takeoff_xy: tuple[float, float] | None = None  # site coordinates; None: near the first line's start
    climb_speed_m_s: float = 3.0
    descent_speed_m_s: float = 2.0
    horizontal_accel_m_s2: float = 1.5
    vertical_accel_m_s2: float = 1.0
    transit_speed_m_s: float = 7.0
    hover_s: float = 3.0  # hover after the climb and before the descent
    static_before_s: float = 30.0  # on the ground, motors off, before take-off (PPK initialisation)
    static_after_s: float = 20.0
    antenna_height_m: float = 0.35  # antenna phase centre above the ground when landed
    wind_speed_m_s: float = 3.0
    wind_from_deg: float = 250.0  # meteorological: direction the wind blows from (true azimuth)
    gust_m_s: float = 0.8
    drag_per_s: float = 0.15  # air-speed drag coefficient / mass (tilt per air speed)
    attitude_noise_deg: float = 0.5  # RMS of the smooth random roll / pitch
    yaw_noise_deg: float = 0.6
    position_noise_m: float = 0.15  # RMS of the smooth random deviation from the plan (per horizontal axis)
    lever_arm_cam_m: tuple[float, float, float] = (0.0123, -0.1047, 0.2156)
    # "fixed": the camera is bolted to the body (lever_arm_cam_m applies); "gimbal": a stabilised camera
    # (DJI RTK aircraft) that stays at nadir with the heading whatever the body's roll and pitch: the
    # antenna -> camera vector is then R_body @ antenna_to_gimbal_body_m + R_cam @ gimbal_to_camera_cam_m,
    # and changes with the attitude (what a DJI Timestamp.MRK logs per exposure)
    camera_mount: str = "fixed"
    antenna_to_gimbal_body_m: tuple[float, float, float] = (0.07, 0.0, 0.16)   # body FRD
    gimbal_to_camera_cam_m: tuple[float, float, float] = (0.0, 0.0, 0.03)      # camera frame
    gimbal_jitter_deg: float = 0.05                                            # RMS stabilisation error
    trigger_delay_s: float = 0.038  # exposure time = trigger (GNSS time mark) + delay
    # UTC at the first trajectory sample; the shipped navigation file covers 08:00-09:15 GPST on 2024-06-24
    start_utc: str = "2024-06-24T08:10:00"
    knot_rate_hz: float = 10.0  # rate of the trajectory knots (and of truth/trajectory.csv)


@dataclass
class CameraEvent:
    index: int
    name: str
    trigger_gps_time_s: float  # GNSS time mark
    exposure_gps_time_s: float  # trigger + delay
    line: int  # flight line index


@dataclass
class FlightPlan:
    line_bearing_deg: float
    line_spacing_m: float
    trigger_spacing_m: float
    footprint_m: tuple[float, float]  # (across, along) at the nominal height
    lines: list = field(default_factory=list)  # per line: dict(start_xy, end_xy, triggers_s (along-line), direction_xy)
    takeoff_xy: tuple[float, float] = (0.0, 0.0)
    takeoff_ground_h: float = 0.0
    flight_h: float = 0.0  # ellipsoidal height of the antenna on the lines

    def trigger_positions_xy(self) -> np.ndarray:
        """Planned image centres (site coordinates) of every line, (N, 2)."""
        pts = []
        for ln in self.lines:
            o = np.asarray(ln["origin_xy"])
            d = np.asarray(ln["direction_xy"])
            pts.extend(o + d * s for s in ln["triggers_s"])
        return np.array(pts)

    def coverage_bounds(self, margin_m: float = 0.0) -> tuple[float, float, float, float]:
        """Site-coordinate box (xmin, ymin, xmax, ymax) covering every planned image footprint + a margin."""
        pts = self.trigger_positions_xy()
        b = math.radians(self.line_bearing_deg)
        dx, dy = abs(math.sin(b)), abs(math.cos(b))
        across, along = self.footprint_m
        ex = dx * along / 2 + dy * across / 2 + margin_m
        ey = dy * along / 2 + dx * across / 2 + margin_m
        return (float(pts[:, 0].min() - ex), float(pts[:, 1].min() - ey), float(pts[:, 0].max() + ex),
                float(pts[:, 1].max() + ey))


def plan_flight(site, camera: CameraModel, o: FlightOptions) -> FlightPlan:
    """Lawn-mower lines over the work area with spacings from the footprint and the overlaps."""
    across, along = camera.footprint_m(o.height_m)  # image width across track, height along track
    base = (1.0 - o.forward_overlap) * along
    spacing = (1.0 - o.side_overlap) * across
    hw, hh = site.half_w, site.half_h
    bearing = o.line_bearing_deg
    if bearing is None:
        bearing = 90.0 if hw >= hh else 0.0
    b = math.radians(bearing)
    d = np.array([math.sin(b), math.cos(b)])  # along the lines (grid)
    p = np.array([d[1], -d[0]])  # to the right of d
    corners = np.array([[-hw, -hh], [hw, -hh], [hw, hh], [-hw, hh]])
    a_rng = corners @ d
    c_rng = corners @ p
    a0, a1 = a_rng.min(), a_rng.max()
    c0, c1 = c_rng.min(), c_rng.max()
    n_lines = int(math.ceil((c1 - c0) / spacing - 1e-9)) + 1
    sp = (c1 - c0) / (n_lines - 1) if n_lines > 1 else 0.0
    n_int = max(1, int(math.ceil((a1 - a0) / base - 1e-9)))
    bt = (a1 - a0) / n_int
    trig = a0 + bt * np.arange(-o.extra_triggers, n_int + o.extra_triggers + 1)
    v_max = max(o.speed_m_s, o.second_speed_m_s or 0.0)
    runin = v_max**2 / (2 * o.horizontal_accel_m_s2) + 1.5 * v_max
    lines = []
    for k in range(n_lines):
        off = c0 + k * sp if n_lines > 1 else 0.5 * (c0 + c1)
        fwd = k % 2 == 0
        dd = d if fwd else -d
        s_first, s_last = (trig[0], trig[-1]) if fwd else (-trig[-1], -trig[0])
        origin = off * p
        lines.append({
            "index": k, "offset_m": float(off), "direction_xy": dd.tolist(), "origin_xy": origin.tolist(),
            "height_m": float(o.second_height_m if (o.second_height_m is not None and (k // 2) % 2 == 1) else o.height_m),
            "speed_m_s": float(o.second_speed_m_s if (o.second_speed_m_s is not None and (k // 2) % 2 == 1) else o.speed_m_s),
            "triggers_s": (np.sort(trig * (1 if fwd else -1))).tolist(),
            "start_xy": (origin + dd * (s_first - runin)).tolist(),
            "end_xy": (origin + dd * (s_last + runin)).tolist(),
        })
    if o.takeoff_xy is not None:
        to = np.array(o.takeoff_xy, dtype=float)
    else:
        st = np.array(lines[0]["start_xy"])
        to = np.clip(st, [-hw + 4.0, -hh + 4.0], [hw - 4.0, hh - 4.0])
        for _ in range(200):  # off the stockpiles, the pit and the targets
            ok = all(pl.footprint_sdf(*to) > 4.0 for pl in site.piles)
            ok = ok and (site.pit is None or site.pit_sdf(*to) > 3.0)
            ok = ok and all(math.hypot(t.x - to[0], t.y - to[1]) > 4.0 for t in site.targets)
            ok = ok and all(float(m.footprint_sdf(*to)) > 4.0 for m in getattr(site, "machines", ()))
            if ok:
                break
            to = to * 0.97
    ground = float(site.surface(to[0], to[1]))
    return FlightPlan(line_bearing_deg=float(bearing), line_spacing_m=float(sp), trigger_spacing_m=float(bt),
                      footprint_m=(float(across), float(along)), lines=lines, takeoff_xy=(float(to[0]), float(to[1])),
                      takeoff_ground_h=ground, flight_h=ground + o.antenna_height_m + o.height_m)


# --------------------------------------------------------------------------------------------------
def _trapezoid(dist: float, vmax: float, acc: float, dt: float) -> np.ndarray:
    """Travelled distance at t = 0, dt, 2dt, ... for a rest-to-rest move (trapezoidal speed)."""
    if dist <= 1e-9:
        return np.zeros(1)
    t_acc = vmax / acc
    d_acc = 0.5 * acc * t_acc**2
    if 2 * d_acc > dist:
        t_acc = math.sqrt(dist / acc)
        vmax = acc * t_acc
        t_flat = 0.0
    else:
        t_flat = (dist - 2 * d_acc) / vmax
    T = 2 * t_acc + t_flat
    t = np.arange(0.0, T + dt, dt)
    s = np.where(t < t_acc, 0.5 * acc * t**2,
                 np.where(t < t_acc + t_flat, 0.5 * acc * t_acc**2 + vmax * (t - t_acc),
                          dist - 0.5 * acc * np.maximum(T - t, 0.0) ** 2))
    return np.minimum(s, dist)


def _smooth_transition(x):
    """C-infinity step: 0 for x <= 0, 1 for x >= 1."""
    x = np.asarray(x, dtype=float)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        a = np.where(x > 0, np.exp(-1.0 / np.where(x > 0, x, 1.0)), 0.0)
        b = np.where(x < 1, np.exp(-1.0 / np.where(x < 1, 1.0 - x, 1.0)), 0.0)
    return a / (a + b)


def _sinusoids(rng, n: int, fmin: float, fmax: float, rms: float):
    """Parameters of a sum of n sinusoids with total RMS ``rms``: (freq_hz, phase, amplitude) arrays."""
    f = np.exp(rng.uniform(math.log(fmin), math.log(fmax), n))
    ph = rng.uniform(0, 2 * np.pi, n)
    a = rng.uniform(0.5, 1.0, n)
    a = a * rms * math.sqrt(2.0) / math.sqrt(np.sum(a * a))
    return f, ph, a


def _eval_sin(params, t):
    f, ph, a = params
    return np.sum(a[:, None] * np.sin(2 * np.pi * f[:, None] * np.asarray(t)[None, :] + ph[:, None]), axis=0)


def _body_from_up_yaw(up: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """R_body_to_enu (N,3,3) for FRD body axes from the up axis (N,3, ENU) and heading (rad from north)."""
    fh = np.stack([np.sin(yaw), np.cos(yaw), np.zeros_like(yaw)], -1)
    x = fh - up * np.sum(fh * up, -1, keepdims=True)
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    z = -up
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


class Trajectory:
    """True antenna-phase-centre trajectory and camera attitude, continuous in ``gps_time_s``."""

    def __init__(self, frame: SiteFrame, knot_times_gps_s, positions_enu, R_cam_to_enu, info: dict | None = None,
                 R_body_to_enu=None):
        self.frame = frame
        self.knot_times = np.asarray(knot_times_gps_s, dtype=float)
        self.t0 = float(self.knot_times[0])
        self.knot_positions_enu = np.asarray(positions_enu, dtype=float)
        self.knot_R_cam_to_enu = np.asarray(R_cam_to_enu, dtype=float)
        tr = self.knot_times - self.t0
        self._pos = make_interp_spline(tr, self.knot_positions_enu, k=5)
        self._vel = self._pos.derivative(1)
        self._acc = self._pos.derivative(2)
        self._rot = RotationSpline(tr, Rotation.from_matrix(self.knot_R_cam_to_enu))
        # a gimbal camera: the body has its own attitude (None: the camera is fixed to the body)
        self.knot_R_body_to_enu = None if R_body_to_enu is None else np.asarray(R_body_to_enu, dtype=float)
        self._body_rot = None if R_body_to_enu is None else RotationSpline(tr, Rotation.from_matrix(R_body_to_enu))
        self.info = dict(info or {})

    # ---- time span ---------------------------------------------------------------------------------
    @property
    def t_start(self) -> float:
        return float(self.knot_times[0])

    @property
    def t_end(self) -> float:
        return float(self.knot_times[-1])

    def _rel(self, t):
        t = np.asarray(t, dtype=float)
        if np.any(t < self.t_start - 1e-6) or np.any(t > self.t_end + 1e-6):
            raise ValueError("time outside the trajectory span")
        return t - self.t0

    # ---- antenna phase centre ------------------------------------------------------------------------
    def position_enu(self, t):
        return self._pos(self._rel(t))

    def velocity_enu(self, t):
        return self._vel(self._rel(t))

    def acceleration_enu(self, t):
        return self._acc(self._rel(t))

    def position_ecef(self, t):
        """Antenna phase centre, ECEF (m): (3,) for a scalar time, (N, 3) for an array."""
        return self.frame.enu_to_ecef(self.position_enu(t))

    def velocity_ecef(self, t):
        return self.frame.enu_vec_to_ecef(self.velocity_enu(t))

    def antenna_state_ecef(self, t) -> tuple[np.ndarray, np.ndarray]:
        """(position, velocity) of the antenna phase centre in ECEF at gps_time_s ``t``."""
        return self.position_ecef(t), self.velocity_ecef(t)

    # ---- attitude ------------------------------------------------------------------------------------
    def R_cam_to_enu(self, t) -> np.ndarray:
        return self._rot(self._rel(t)).as_matrix()

    def R_cam_to_ecef(self, t) -> np.ndarray:
        return self.frame.R_enu_to_ecef @ self.R_cam_to_enu(t)

    def R_body_to_enu(self, t) -> np.ndarray:
        if self._body_rot is not None:
            return self._body_rot(self._rel(t)).as_matrix()
        return self.R_cam_to_enu(t) @ R_CAM_TO_BODY.T

    def angular_rate_enu(self, t) -> np.ndarray:
        """Angular velocity of the camera (rad/s), in ENU axes."""
        return self._rot(self._rel(t), 1)

    def yaw_pitch_roll_deg(self, t) -> np.ndarray:
        """Body heading (true azimuth), pitch (nose up +) and roll (right wing down +), degrees (ZYX, NED)."""
        rb = self.R_body_to_enu(t)
        enu_to_ned = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
        r_ned = enu_to_ned @ rb
        ypr = Rotation.from_matrix(r_ned).as_euler("ZYX", degrees=True)
        ypr[..., 0] = np.mod(ypr[..., 0], 360.0)
        return ypr

    # ---- camera --------------------------------------------------------------------------------------
    def camera_centre_enu(self, t, lever_arm_cam_m) -> np.ndarray:
        R = self.R_cam_to_enu(t)
        return self.position_enu(t) + R @ np.asarray(lever_arm_cam_m, dtype=float)

    def camera_centre_ecef(self, t, lever_arm_cam_m) -> np.ndarray:
        return self.frame.enu_to_ecef(self.camera_centre_enu(t, lever_arm_cam_m))

    # ---- I/O -------------------------------------------------------------------------------------------
    def sample_table(self, times=None) -> dict:
        """Columns of ``truth/trajectory.csv`` at ``times`` (default: the knots)."""
        t = self.knot_times if times is None else np.asarray(times, dtype=float)
        p = self.position_enu(t)
        v = self.velocity_enu(t)
        pe = self.frame.enu_to_ecef(p)
        ve = self.frame.enu_vec_to_ecef(v)
        g = self.frame.enu_to_grid(p)
        R = self.R_cam_to_enu(t)
        ypr = self.yaw_pitch_roll_deg(t)
        cols = {"gps_time_s": t,
                "x_ecef_m": pe[:, 0], "y_ecef_m": pe[:, 1], "z_ecef_m": pe[:, 2],
                "vx_ecef_m_s": ve[:, 0], "vy_ecef_m_s": ve[:, 1], "vz_ecef_m_s": ve[:, 2],
                "e_enu_m": p[:, 0], "n_enu_m": p[:, 1], "u_enu_m": p[:, 2],
                "ve_enu_m_s": v[:, 0], "vn_enu_m_s": v[:, 1], "vu_enu_m_s": v[:, 2],
                "E_crs_m": g[:, 0], "N_crs_m": g[:, 1], "h_ell_m": g[:, 2],
                "yaw_deg": ypr[:, 0], "pitch_deg": ypr[:, 1], "roll_deg": ypr[:, 2]}
        for i in range(3):
            for j in range(3):
                cols[f"r{i}{j}"] = R[:, i, j]
        return cols

    def to_csv(self, path) -> None:
        cols = self.sample_table()
        names = list(cols)
        fmt = []
        for n in names:
            if n == "gps_time_s":
                fmt.append("%.6f")
            elif n.startswith(("x_", "y_", "z_", "e_", "n_", "u_", "E_", "N_", "h_")):
                fmt.append("%.6f")
            elif n.startswith("r") and len(n) == 3:
                fmt.append("%.12f")
            else:
                fmt.append("%.9f")
        data = np.stack([cols[n] for n in names], axis=-1)
        header = ",".join(names)
        np.savetxt(path, data, delimiter=",", header=header, comments="", fmt=fmt)

    @classmethod
    def from_csv(cls, path, frame: SiteFrame) -> "Trajectory":
        """Rebuild the interpolators from the knots written by :meth:`to_csv` (ENU columns + rotations)."""
        data = np.genfromtxt(path, delimiter=",", names=True)
        t = data["gps_time_s"]
        p = np.stack([data["e_enu_m"], data["n_enu_m"], data["u_enu_m"]], -1)
        R = np.stack([np.stack([data[f"r{i}{j}"] for j in range(3)], -1) for i in range(3)], -2)
        return cls(frame, t, p, R)


# --------------------------------------------------------------------------------------------------
def simulate_flight(site, camera: CameraModel, o: FlightOptions, seed: int,
                    plan: FlightPlan | None = None) -> tuple[Trajectory, list[CameraEvent], FlightPlan]:
    """Fly the plan: nominal stop-and-go path, smoothing, perturbations, attitude, camera events."""
    frame: SiteFrame = site.frame
    plan = plan or plan_flight(site, camera, o)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 202]))
    dt = 0.01

    def enu(xy, h):
        return frame.site_to_enu(xy[0], xy[1], h)

    h_ground = plan.takeoff_ground_h + o.antenna_height_m
    home_g = enu(plan.takeoff_xy, h_ground)
    home_a = enu(plan.takeoff_xy, plan.flight_h)
    segs: list[tuple[np.ndarray, float]] = []  # (positions (n,3), yaw target)

    def heading(a, b, default):
        d = b - a
        return math.atan2(d[0], d[1]) if math.hypot(d[0], d[1]) > 0.5 else default

    def move(a, b, v, acc, yaw):
        dist = float(np.linalg.norm(b - a))
        s = _trapezoid(dist, v, acc, dt)
        u = (b - a) / dist if dist > 0 else np.zeros(3)
        segs.append((a[None, :] + s[:, None] * u[None, :], yaw))

    def hold(p, seconds, yaw):
        n = max(1, int(round(seconds / dt)))
        segs.append((np.repeat(p[None, :], n, axis=0), yaw))

    first = enu(plan.lines[0]["start_xy"], plan.flight_h + plan.lines[0].get("height_m", o.height_m) - o.height_m)
    yaw0 = heading(home_a, first, math.atan2(plan.lines[0]["direction_xy"][0], plan.lines[0]["direction_xy"][1]))
    hold(home_g, o.static_before_s, yaw0)
    move(home_g, home_a, o.climb_speed_m_s, o.vertical_accel_m_s2, yaw0)
    hold(home_a, o.hover_s, yaw0)
    move(home_a, first, o.transit_speed_m_s, o.horizontal_accel_m_s2, yaw0)
    line_enu = []
    prev = first
    def line_h(ln):  # antenna height of a line (lines of a two-height calibration flight differ)
        return plan.flight_h + ln.get("height_m", o.height_m) - o.height_m

    for k, ln in enumerate(plan.lines):
        a = enu(ln["start_xy"], line_h(ln))
        b = enu(ln["end_xy"], line_h(ln))
        if k > 0:
            move(prev, a, min(o.transit_speed_m_s, o.speed_m_s), o.horizontal_accel_m_s2, heading(prev, a, 0.0))
        hold(a, 0.5, heading(a, b, 0.0))
        move(a, b, ln.get("speed_m_s", o.speed_m_s), o.horizontal_accel_m_s2, heading(a, b, 0.0))
        hold(b, 0.5, heading(a, b, 0.0))
        line_enu.append((a, b))
        prev = b
    yaw_back = heading(prev, home_a, 0.0)
    move(prev, home_a, o.transit_speed_m_s, o.horizontal_accel_m_s2, yaw_back)
    hold(home_a, o.hover_s, yaw_back)
    move(home_a, home_g, o.descent_speed_m_s, o.vertical_accel_m_s2, yaw_back)
    hold(home_g, o.static_after_s, yaw_back)

    pos = np.concatenate([s[0] for s in segs])
    yaw_t = np.concatenate([np.full(len(s[0]), s[1]) for s in segs])
    yaw_t = np.unwrap(yaw_t)
    # smooth: C-infinity positions and heading changes spread over a few seconds
    pos = gaussian_filter1d(pos, sigma=0.35 / dt, axis=0, mode="nearest")
    yaw_t = gaussian_filter1d(yaw_t, sigma=0.9 / dt, mode="nearest")
    # airborne envelope: 0 on the ground, 1 from ~1 m up
    agl = pos[:, 2] - home_g[2]
    env = _smooth_transition((agl - 0.02) / 2.0)

    n_fine = len(pos)
    t_fine = np.arange(n_fine) * dt
    step = int(round(1.0 / (o.knot_rate_hz * dt)))
    idx = np.arange(0, n_fine, step)
    tk = t_fine[idx]
    pk = pos[idx].copy()
    envk = env[idx]
    yawk = yaw_t[idx]

    # smooth random deviation from the plan (horizontal mostly)
    pert = np.stack([_eval_sin(_sinusoids(rng, 6, 0.01, 0.15, o.position_noise_m), tk),
                     _eval_sin(_sinusoids(rng, 6, 0.01, 0.15, o.position_noise_m), tk),
                     _eval_sin(_sinusoids(rng, 6, 0.01, 0.15, 0.4 * o.position_noise_m), tk)], -1)
    pk = pk + pert * envk[:, None]

    start = _dt.datetime.fromisoformat(o.start_utc.replace("Z", "")).replace(tzinfo=None)
    t0 = utc_datetime_to_gps_time_s(start)
    t_gps = t0 + tk
    spline = make_interp_spline(tk, pk, k=5)
    vel = spline.derivative(1)(tk)
    acc = spline.derivative(2)(tk)

    # wind (air moves towards wind_from + 180 deg) with gusts, drag tilt, smooth attitude noise
    wto = math.radians(o.wind_from_deg + 180.0)
    wind = np.array([math.sin(wto), math.cos(wto), 0.0]) * o.wind_speed_m_s
    gust = np.stack([_eval_sin(_sinusoids(rng, 5, 0.05, 0.5, o.gust_m_s), tk),
                     _eval_sin(_sinusoids(rng, 5, 0.05, 0.5, o.gust_m_s), tk), np.zeros_like(tk)], -1)
    air = vel - (wind[None, :] + gust)
    thrust = acc + np.array([0.0, 0.0, G_M_S2]) + o.drag_per_s * air
    up_air = thrust / np.linalg.norm(thrust, axis=-1, keepdims=True)
    ez = np.array([0.0, 0.0, 1.0])
    up = ez + envk[:, None] * (up_air - ez)
    up /= np.linalg.norm(up, axis=-1, keepdims=True)
    dyaw = np.radians(_eval_sin(_sinusoids(rng, 5, 0.03, 0.4, o.yaw_noise_deg), tk)) * envk
    rb = _body_from_up_yaw(up, yawk + dyaw)
    droll = np.radians(_eval_sin(_sinusoids(rng, 6, 0.05, 0.8, o.attitude_noise_deg), tk)) * envk
    dpitch = np.radians(_eval_sin(_sinusoids(rng, 6, 0.05, 0.8, o.attitude_noise_deg), tk)) * envk
    pert_r = Rotation.from_euler("xy", np.stack([droll, dpitch], -1)).as_matrix()  # about body x then y
    rb = rb @ pert_r
    if o.camera_mount == "gimbal":
        # stabilised: level with the heading, the gimbal's small residual error only
        level = _body_from_up_yaw(np.broadcast_to(ez, up.shape), yawk + dyaw)
        jit = np.radians(_eval_sin(_sinusoids(rng, 4, 0.1, 1.0, o.gimbal_jitter_deg), tk))
        jit2 = np.radians(_eval_sin(_sinusoids(rng, 4, 0.1, 1.0, o.gimbal_jitter_deg), tk))
        rc = level @ R_CAM_TO_BODY @ Rotation.from_euler("xy", np.stack([jit, jit2], -1)).as_matrix()
    elif o.camera_mount == "fixed":
        rc = rb @ R_CAM_TO_BODY
    else:
        raise ValueError(f"camera_mount must be 'fixed' or 'gimbal', not {o.camera_mount!r}")

    info = {"takeoff_gps_time_s": None, "landing_gps_time_s": None}
    air_idx = np.nonzero(envk > 0)[0]
    if len(air_idx):
        info["takeoff_gps_time_s"] = float(t_gps[max(air_idx[0] - 1, 0)])
        info["landing_gps_time_s"] = float(t_gps[min(air_idx[-1] + 1, len(t_gps) - 1)])
    traj = Trajectory(frame, t_gps, pk, rc, info, R_body_to_enu=rb if o.camera_mount == "gimbal" else None)

    # ---- camera events: distance-triggered along each line ------------------------------------------
    events: list[CameraEvent] = []
    tt = t0 + np.arange(0.0, tk[-1], 0.05)
    ptt = traj.position_enu(tt)
    k_img = 0
    for k, (ln, (a, b)) in enumerate(zip(plan.lines, line_enu)):
        dirv = (b - a) / np.linalg.norm(b - a)
        o_line = enu(ln["origin_xy"], line_h(ln))
        s_all = (ptt - o_line) @ dirv
        # the part of the flight on this line: between its start and end stops
        sel = (tt >= _closest_time(tt, ptt, a)) & (tt <= _closest_time(tt, ptt, b))
        ts, ss = tt[sel], s_all[sel]
        for s_target in np.asarray(ln["triggers_s"], dtype=float):  # along the line's own direction
            s_signed = s_target
            j = int(np.searchsorted(ss, s_signed))
            j = min(max(j, 1), len(ss) - 1)
            tj = ts[j - 1] + (s_signed - ss[j - 1]) / (ss[j] - ss[j - 1]) * (ts[j] - ts[j - 1])
            for _ in range(4):  # Newton on s(t) = s_target
                sj = float((traj.position_enu(tj) - o_line) @ dirv)
                vj = float(traj.velocity_enu(tj) @ dirv)
                tj = tj - (sj - s_signed) / vj
            events.append(CameraEvent(index=k_img, name="", trigger_gps_time_s=float(tj),
                                      exposure_gps_time_s=float(tj) + o.trigger_delay_s, line=k))
            k_img += 1
    events.sort(key=lambda e: e.trigger_gps_time_s)
    for i, e in enumerate(events):
        e.index = i
        e.name = f"IMG_{i + 1:04d}.JPG"
    return traj, events, plan


def antenna_to_camera_enu(traj: Trajectory, t, o: FlightOptions) -> np.ndarray:
    """The vector from the antenna phase centre to the camera centre at ``t`` (ENU, m): R_cam @ lever arm
    for a fixed camera; for a gimbal camera the body part of the mount turns with the body and the
    gimbal part with the camera (``FlightOptions.camera_mount``)."""
    if o.camera_mount == "gimbal":
        return (traj.R_body_to_enu(t) @ np.asarray(o.antenna_to_gimbal_body_m, dtype=float)
                + traj.R_cam_to_enu(t) @ np.asarray(o.gimbal_to_camera_cam_m, dtype=float))
    return traj.R_cam_to_enu(t) @ np.asarray(o.lever_arm_cam_m, dtype=float)


def _closest_time(tt, ptt, p):
    return float(tt[int(np.argmin(np.sum((ptt - p) ** 2, axis=-1)))])


def gps_time_to_utc(t_gps: float) -> _dt.datetime:
    """UTC (naive datetime) of a gps_time_s."""
    t = gps_time_s_to_datetime(t_gps)
    return t - _dt.timedelta(seconds=leap_seconds_at(t))

