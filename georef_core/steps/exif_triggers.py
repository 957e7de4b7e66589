"""Trigger times from the photos' EXIF time plus a camera-clock offset: a GNSS-step setting
(exif_time_offset_s), for cameras whose exposures the receiver did not record; the georef step reads the
same times to tie each photo to its trigger."""

from __future__ import annotations

import csv
from pathlib import Path

from ..errors import InputFileError


def exif_trigger_times(image_dir: Path, image_names: list[str], offset_s: float) -> tuple[dict[str, float], list[str]]:
    """image name -> trigger GPS time from its EXIF time plus a clock offset (s)."""
    import datetime as dt

    from ..gnss.gnss_time import utc_datetime_to_gps_time_s
    from ..photo.images import read_image_info

    times, warnings = {}, []
    for name in image_names:
        t = read_image_info(image_dir / name, warn=False).time_original
        if t is None:
            warnings.append(f"{name}: no EXIF DateTimeOriginal; the image is used without GNSS")
            continue
        utc = t.astimezone(dt.timezone.utc).replace(tzinfo=None) if t.tzinfo else t
        times[name] = utc_datetime_to_gps_time_s(utc + dt.timedelta(seconds=float(offset_s)))
    if not times:
        raise InputFileError(image_dir, "no image has an EXIF time: trigger times cannot come from EXIF")
    return times, warnings


def trigger_csv_text(times: dict[str, float]) -> str:
    """The trigger table (image, gps_time_s) in time order, as written to ppk/exif_triggers.csv."""
    import io

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["image", "gps_time_s"])
    for name, t in sorted(times.items(), key=lambda kv: kv[1]):
        w.writerow([name, f"{t:.6f}"])
    return buf.getvalue()


def write_trigger_csv(path: Path, times: dict[str, float]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(trigger_csv_text(times))
