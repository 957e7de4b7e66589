"""Time scales. Internally every epoch is ``gps_time_s``: seconds of GPS time since 1980-01-06 00:00:00,
a float64 with no week roll-over. BeiDou time is GPST - 14 s; GLONASS time is UTC(SU) + 3 h; UTC is
GPST - leap seconds."""

from __future__ import annotations

import datetime as _dt
import math

import numpy as np

GPS_EPOCH = _dt.datetime(1980, 1, 6)
SECONDS_PER_WEEK = 604800.0
BDS_MINUS_GPS_S = -14.0

# (UTC date from which it applies, GPS-UTC seconds)
_LEAP_TABLE = [
    (_dt.datetime(1981, 7, 1), 1), (_dt.datetime(1982, 7, 1), 2), (_dt.datetime(1983, 7, 1), 3),
    (_dt.datetime(1985, 7, 1), 4), (_dt.datetime(1988, 1, 1), 5), (_dt.datetime(1990, 1, 1), 6),
    (_dt.datetime(1991, 1, 1), 7), (_dt.datetime(1992, 7, 1), 8), (_dt.datetime(1993, 7, 1), 9),
    (_dt.datetime(1994, 7, 1), 10), (_dt.datetime(1996, 1, 1), 11), (_dt.datetime(1997, 7, 1), 12),
    (_dt.datetime(1999, 1, 1), 13), (_dt.datetime(2006, 1, 1), 14), (_dt.datetime(2009, 1, 1), 15),
    (_dt.datetime(2012, 7, 1), 16), (_dt.datetime(2015, 7, 1), 17), (_dt.datetime(2017, 1, 1), 18),
]


def leap_seconds_at(utc: _dt.datetime) -> int:
    """GPS - UTC in seconds at a UTC instant."""
    n = 0
    for start, value in _LEAP_TABLE:
        if utc >= start:
            n = value
    return n


def datetime_to_gps_time_s(t: _dt.datetime) -> float:
    """A naive datetime read as GPS time (as RINEX epochs in GPS time are) to gps_time_s."""
    delta = t - GPS_EPOCH
    return delta.days * 86400.0 + delta.seconds + delta.microseconds * 1e-6


def calendar_to_gps_time_s(year, month, day, hour, minute, second) -> np.ndarray | float:
    """Vectorised calendar (GPS time scale) to gps_time_s; arguments may be numpy arrays."""
    year = np.asarray(year, dtype=np.int64)
    month = np.asarray(month, dtype=np.int64)
    day = np.asarray(day, dtype=np.int64)
    # days from civil (proleptic Gregorian), Howard Hinnant's algorithm
    y = year - (month <= 2)
    era = np.floor_divide(y, 400)
    yoe = y - era * 400
    mp = (month + 9) % 12
    doy = (153 * mp + 2) // 5 + day - 1
    doe = yoe * 365 + yoe // 4 - yoe // 100 + doy
    days_since_1970 = era * 146097 + doe - 719468
    days_since_gps = days_since_1970 - 3657  # 1980-01-06 is day 3657 after 1970-01-01
    out = days_since_gps * 86400.0 + np.asarray(hour) * 3600.0 + np.asarray(minute) * 60.0 + np.asarray(second, dtype=float)
    return out if np.ndim(out) else float(out)


def gps_time_s_to_datetime(t_s: float) -> _dt.datetime:
    return GPS_EPOCH + _dt.timedelta(seconds=float(t_s))


def gps_time_s_to_week_tow(t_s: float) -> tuple[int, float]:
    week = int(np.floor(t_s / SECONDS_PER_WEEK))
    return week, t_s - week * SECONDS_PER_WEEK


def utc_datetime_to_gps_time_s(utc: _dt.datetime) -> float:
    return datetime_to_gps_time_s(utc) + leap_seconds_at(utc)


def resolve_tow_near(tow_s: float, week_ref_time_s: float) -> float:
    """A time-of-week (GPS scale) turned into gps_time_s, choosing the week closest to a reference time.
    Scalars only (math.floor: np.floor on a Python float was most of its cost, two calls per navigation
    record)."""
    t = math.floor(week_ref_time_s / SECONDS_PER_WEEK) * SECONDS_PER_WEEK + tow_s
    if t - week_ref_time_s > SECONDS_PER_WEEK / 2:
        t -= SECONDS_PER_WEEK
    elif t - week_ref_time_s < -SECONDS_PER_WEEK / 2:
        t += SECONDS_PER_WEEK
    return t
