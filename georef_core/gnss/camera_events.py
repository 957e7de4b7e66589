"""Antenna position, velocity and uncertainty at camera events (trigger time marks), interpolated between
the solution epochs that bracket each event with a cubic Hermite curve (positions and velocities at both
ends). The uncertainty is the interpolated covariance, widened by the velocity uncertainty over the
interval and by the interpolation model error (estimated from the Hermite-linear difference)."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputFileError


@dataclass
class EventPositions:
    event_time_s: np.ndarray          # (N,) gps_time_s of the time marks
    position_ecef_m: np.ndarray       # (N, 3) antenna phase centre
    velocity_ecef_m_s: np.ndarray     # (N, 3)
    covariance_ecef_m2: np.ndarray    # (N, 3, 3)
    status: np.ndarray                # (N,) worst quality of the two bracketing epochs; 0 = none
    gap_s: np.ndarray                 # (N,) length of the bracketing interval


def interpolate_at_events(sol, event_time_s, max_gap_s: float | None = None) -> EventPositions:
    t = sol.time_s
    ok = sol.status > 0
    tv, pv, vv = t[ok], sol.position_ecef_m[ok], sol.velocity_ecef_m_s[ok]
    cv, vcv, sv = sol.covariance_ecef_m2[ok], sol.velocity_covariance_m2_s2[ok], sol.status[ok]
    ev = np.asarray(event_time_s, dtype=float)
    n = len(ev)
    pos = np.full((n, 3), np.nan)
    vel = np.full((n, 3), np.nan)
    cov = np.full((n, 3, 3), np.nan)
    status = np.zeros(n, dtype=np.int8)
    gap = np.full(n, np.nan)
    if len(tv) < 2:
        return EventPositions(ev, pos, vel, cov, status, gap)
    if max_gap_s is None:
        max_gap_s = 2.5 * float(np.median(np.diff(tv)))
    k = np.searchsorted(tv, ev, side="right") - 1
    for i in range(n):
        j = k[i]
        if j < 0 or j >= len(tv) - 1:
            continue
        h = tv[j + 1] - tv[j]
        gap[i] = h
        if h > max_gap_s:
            continue
        s = (ev[i] - tv[j]) / h
        v0, v1 = np.nan_to_num(vv[j]), np.nan_to_num(vv[j + 1])
        h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
        p = h00 * pv[j] + h10 * h * v0 + h01 * pv[j + 1] + h11 * h * v1
        dp = (6 * s**2 - 6 * s) / h * pv[j] + (3 * s**2 - 4 * s + 1) * v0 + (-6 * s**2 + 6 * s) / h * pv[j + 1] \
            + (3 * s**2 - 2 * s) * v1
        lin = (1 - s) * pv[j] + s * pv[j + 1]
        model = 0.5 * (p - lin)
        # neighbouring epochs share their ambiguities: their errors are close to fully correlated, so the
        # covariance is interpolated (an upper bound of the uncorrelated h00^2 C0 + h01^2 C1)
        c = h00 * cv[j] + h01 * cv[j + 1]
        c = c + (h10 * h) ** 2 * np.nan_to_num(vcv[j]) + (h11 * h) ** 2 * np.nan_to_num(vcv[j + 1]) + np.diag(model**2)
        pos[i], vel[i], cov[i] = p, dp, c
        a, b = int(sv[j]), int(sv[j + 1])
        status[i] = max(a, b)
    return EventPositions(ev, pos, vel, cov, status, gap)


def read_event_csv(path) -> np.ndarray:
    """Camera trigger times from a CSV (a column named gps_time_s, or the first numeric column) or from a
    DJI Timestamp.MRK (its exposure times), recognised by content. Times must be finite."""
    from .dji_mrk import looks_like_mrk, read_mrk

    p = Path(path)
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(p, f"cannot read as text ({exc})") from None
    if looks_like_mrk(text[:4096].encode("utf-8", "replace")):
        return read_mrk(p).gps_time_s.copy()
    rows = list(csv.reader(line for line in text.splitlines() if line.strip() and not line.startswith("#")))
    if not rows:
        raise InputFileError(p, "no event times")
    col = 0
    start = 0
    if any(not _is_float(v) for v in rows[0]):
        header = [h.strip().lower() for h in rows[0]]
        col = header.index("gps_time_s") if "gps_time_s" in header else 0
        start = 1
    out = []
    for n, r in enumerate(rows[start:], start + 1):
        if col >= len(r) or not _is_float(r[col]):
            raise InputFileError(p, f"event time {r[col] if col < len(r) else ''!r} is not a number", n)
        if not np.isfinite(float(r[col])):
            raise InputFileError(p, f"event time {r[col].strip()!r} is not a finite number", n)
        out.append(float(r[col]))
    return np.array(out)


def _is_float(v: str) -> bool:
    try:
        float(v)
        return True
    except ValueError:
        return False


def write_event_csv(path, events: EventPositions, epsg: int | None = None) -> None:
    from .frames import ecef_to_crs, ecef_to_geodetic

    llh = ecef_to_geodetic(np.nan_to_num(events.position_ecef_m))
    proj = ecef_to_crs(np.nan_to_num(events.position_ecef_m), epsg) if epsg else None
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        head = ["event", "gps_time_s", "status", "x_ecef_m", "y_ecef_m", "z_ecef_m", "lat_deg", "lon_deg", "height_ellipsoid_m",
                "vx_ecef_m_s", "vy_ecef_m_s", "vz_ecef_m_s", "sd_x_m", "sd_y_m", "sd_z_m", "gap_s"]
        if epsg:
            head += [f"x_epsg{epsg}", f"y_epsg{epsg}", f"z_epsg{epsg}"]
        w.writerow(head)
        for i in range(len(events.event_time_s)):
            sd = np.sqrt(np.abs(np.diag(events.covariance_ecef_m2[i])))
            row = [i + 1, f"{events.event_time_s[i]:.6f}", int(events.status[i]),
                   *(f"{v:.4f}" for v in events.position_ecef_m[i]), f"{np.degrees(llh[i, 0]):.9f}",
                   f"{np.degrees(llh[i, 1]):.9f}", f"{llh[i, 2]:.4f}", *(f"{v:.4f}" for v in events.velocity_ecef_m_s[i]),
                   *(f"{v:.4f}" for v in sd), f"{events.gap_s[i]:.3f}"]
            if epsg:
                row += [f"{v:.4f}" for v in proj[i]]
            w.writerow(row)
