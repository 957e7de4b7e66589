"""When a survey was flown, read from its data (for a survey whose date nobody typed in).

In order of trust:

1. the GNSS step's solution (``ppk/summary.json``, ``time_span``): the span of the camera triggers, else
   of the solution's epochs; GPS time turned into UTC with the leap seconds of the day;
2. the exposures of DJI ``*_Timestamp.MRK`` files (GPS time);
3. the photos' EXIF ``DateTimeOriginal`` (the camera's clock: read as UTC unless ``OffsetTimeOriginal``
   gives its zone; the result says so).

``survey_flight_time(survey_dir, out_dir)`` answers ``{"start", "end", "source", "detail"}`` (times as
ISO 8601 UTC, ``source`` one of ``gnss``, ``dji-mrk``, ``exif``) or None when the data holds no time."""

from __future__ import annotations

import datetime as _dt
import json
from pathlib import Path

SOURCES = ("gnss", "dji-mrk", "exif")
MAX_PHOTOS_READ = 24      # photos whose EXIF is read (evenly spread over the sorted names, first and last)
_IMAGE_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff", ".dng")


def iso_utc(t: _dt.datetime) -> str:
    """'2024-06-24T08:10:00Z' (a naive time is UTC; whole seconds)."""
    if t.tzinfo is None:
        t = t.replace(tzinfo=_dt.timezone.utc)
    return t.astimezone(_dt.timezone.utc).replace(microsecond=0).strftime("%Y-%m-%dT%H:%M:%SZ")


def gps_seconds_to_utc(gps_time_s: float) -> _dt.datetime:
    """Continuous GPS seconds (since 1980-01-06) -> UTC datetime (aware)."""
    from ..gnss.gnss_time import gps_time_s_to_datetime, leap_seconds_at

    gps = gps_time_s_to_datetime(float(gps_time_s))
    return (gps - _dt.timedelta(seconds=leap_seconds_at(gps))).replace(tzinfo=_dt.timezone.utc)


def gnss_time_span(solution_times_s, event_times_s=None) -> dict | None:
    """The ``time_span`` of a GNSS summary: GPS seconds of the first and last camera trigger when there
    are triggers, else of the first and last solution epoch."""
    import numpy as np

    ev = np.asarray(event_times_s if event_times_s is not None else [], dtype=float)
    ev = ev[np.isfinite(ev)]
    t = np.asarray(solution_times_s, dtype=float)
    t = t[np.isfinite(t)]
    if len(ev):
        return {"first_gps_time_s": float(ev.min()), "last_gps_time_s": float(ev.max()), "of": "camera triggers"}
    if len(t):
        return {"first_gps_time_s": float(t.min()), "last_gps_time_s": float(t.max()), "of": "solution epochs"}
    return None


def _span(first: _dt.datetime, last: _dt.datetime, source: str, detail: str) -> dict:
    return {"start": iso_utc(first), "end": iso_utc(last), "source": source, "detail": detail}


def from_gnss_summary(out_dir) -> dict | None:
    p = Path(out_dir) / "ppk" / "summary.json"
    try:
        doc = json.loads(p.read_text())
    except (OSError, ValueError):
        return None
    span = doc.get("time_span") if isinstance(doc, dict) else None
    if not isinstance(span, dict):
        return None
    try:
        first, last = float(span["first_gps_time_s"]), float(span["last_gps_time_s"])
    except (KeyError, TypeError, ValueError):
        return None
    return _span(gps_seconds_to_utc(first), gps_seconds_to_utc(last), "gnss",
                 f"GNSS solution ({span.get('of', 'epochs')})")


def from_mrk(survey_dir) -> dict | None:
    from ..errors import GeorefError
    from ..gnss.dji_mrk import read_mrk

    times = []
    for p in sorted(Path(survey_dir).rglob("*")):
        if not p.is_file() or not p.name.lower().endswith("timestamp.mrk"):
            continue
        try:
            m = read_mrk(p)
        except (GeorefError, OSError, ValueError):
            continue
        if m.n_exposures:
            times += [float(m.gps_time_s.min()), float(m.gps_time_s.max())]
    if not times:
        return None
    return _span(gps_seconds_to_utc(min(times)), gps_seconds_to_utc(max(times)), "dji-mrk",
                 "DJI Timestamp.MRK exposures")


def from_exif(survey_dir) -> dict | None:
    from ..errors import GeorefError
    from ..photo.images import read_image_info

    survey_dir = Path(survey_dir)
    photos = sorted(p for d in ("images", "flights") if (survey_dir / d).is_dir()
                    for p in (survey_dir / d).rglob("*") if p.is_file() and p.suffix.lower() in _IMAGE_SUFFIXES)
    if not photos:
        return None
    if len(photos) > MAX_PHOTOS_READ:
        step = (len(photos) - 1) / (MAX_PHOTOS_READ - 1)
        photos = [photos[round(k * step)] for k in range(MAX_PHOTOS_READ)]
    times, zoned = [], True
    for p in photos:
        try:
            t = read_image_info(p, warn=False).time_original
        except (GeorefError, OSError, ValueError):
            continue
        if t is None:
            continue
        zoned = zoned and t.tzinfo is not None
        times.append(t if t.tzinfo is not None else t.replace(tzinfo=_dt.timezone.utc))
    if not times:
        return None
    detail = "photos' EXIF DateTimeOriginal" + ("" if zoned else " (camera clock, read as UTC)")
    return _span(min(times), max(times), "exif", detail)


def survey_flight_time(survey_dir, out_dir=None) -> dict | None:
    """The flight's time span from the best source the run folder has (see the module's text), or None."""
    readers = ([lambda: from_gnss_summary(out_dir)] if out_dir is not None else []) + [
        lambda: from_mrk(survey_dir), lambda: from_exif(survey_dir)]
    for read in readers:     # the first that finds a time; the later (slower) ones are not read
        found = read()
        if found is not None:
            return found
    return None


def add_flight_time(summary, survey_dir, out_dir) -> None:
    """Put ``flight_time`` into a step's summary (the platform stores it on a survey whose date nobody gave);
    the date is a convenience: a file it cannot read never fails the step."""
    from ..errors import GeorefError

    if not isinstance(summary, dict) or summary.get("flight_time"):
        return
    try:
        found = survey_flight_time(survey_dir, out_dir)
    except (GeorefError, OSError, ValueError):
        found = None
    if found:
        summary["flight_time"] = found
