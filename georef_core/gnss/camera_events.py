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
    """Camera trigger times from a CSV (parse_event_table) or from a DJI Timestamp.MRK (its exposure times),
    recognised by content. Times must be finite."""
    from .dji_mrk import looks_like_mrk, read_mrk

    p = Path(path)
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(p, f"cannot read as text ({exc})") from None
    if looks_like_mrk(text[:4096].encode("utf-8", "replace")):
        return read_mrk(p).gps_time_s.copy()
    return np.array([t for t, _ in parse_event_table(text, p)])


EVENT_TIME_COLUMNS = ("gps_time_s", "trigger_gps_time_s")


def parse_event_table(text: str, source) -> list[tuple[float, str | None]]:
    """The rows of a camera-trigger CSV as (gps_time_s, image name or None): the time column is gps_time_s
    (or trigger_gps_time_s), else the first column; an optional `image` column names
    the photo. The one reading of events.csv, for the gnss step and the upload check alike. Raises
    InputFileError(source, problem, line)."""
    numbered = [(n, line) for n, line in enumerate(text.splitlines(), start=1)
                if line.strip() and not line.startswith("#")]
    rows = [(n, r) for (n, _), r in zip(numbered, csv.reader(line for _, line in numbered))]
    if not rows:
        raise InputFileError(source, "no event times")
    col, img, start = 0, None, 0
    if any(not _is_float(v) for v in rows[0][1]):
        header = [h.strip().lower() for h in rows[0][1]]
        col = next((header.index(c) for c in EVENT_TIME_COLUMNS if c in header), 0)
        img = header.index("image") if "image" in header else None
        start = 1
    out = []
    for n, r in rows[start:]:
        if col >= len(r) or not _is_float(r[col]):
            raise InputFileError(source, f"event time {r[col] if col < len(r) else ''!r} is not a number", n)
        if not np.isfinite(float(r[col])):
            raise InputFileError(source, f"event time {r[col].strip()!r} is not a finite number", n)
        out.append((float(r[col]), r[img].strip() if img is not None and img < len(r) and r[img].strip() else None))
    if not out:
        raise InputFileError(source, "a header and no event")
    return out


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
