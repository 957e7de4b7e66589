"""Camera positions written into the photos themselves, for surveys without the drone's raw GNSS.

* RTK-tagged photos (DJI RTK aircraft, XMP ``drone-dji:``): the camera centre (DJI has already applied
  the antenna-to-camera offset and the exposure time) at ``GpsLatitude`` / ``GpsLongtitude`` /
  ``AbsoluteAltitude``, weighted by the aircraft's own standard deviations ``RtkStdLat`` / ``RtkStdLon``
  / ``RtkStdHgt`` (floored at 5 mm), the fix state from ``RtkFlag`` (50 fixed, 34 float, 16 single).
  ``AbsoluteAltitude`` is read as the WGS84 ellipsoidal height, which is what RTK aircraft record when
  their RTK service gives ellipsoidal heights; some firmware writes a geoid height there: survey.json's
  ``photo_heights: "egm96"`` (or any vertical datum georef_core.datums knows: ``egm2008``, ``EPSG:code``)
  says so, and each height is converted to the ellipsoidal one (h = H + N, the geoid undulation N through
  PROJ with the installed grid) before use; without the grid the survey is refused, never placed 30-50 m off.
* Plain EXIF GPS (any other drone): the navigation-grade receiver's position, weighted honestly at
  3 m horizontally and 5 m vertically (a consumer receiver and barometric height); such a result's
  absolute position rests on its control points where it has some, else on these metre-level positions,
  and the summary (``absolute_accuracy``) says which.

Nothing else is estimated from these positions: no lever arm (the position already is the camera's)
and no trigger delay (they carry no velocity).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError

RTK_SIGMA_FLOOR_M = 0.005
EXIF_GPS_SIGMA_M = (3.0, 5.0)        # horizontal, vertical (1 sigma) of a navigation-grade drone GNSS
STATUS_OF_RTK_FLAG = {50: 1, 34: 2, 16: 5}


@dataclass
class PhotoPositions:
    """Camera centres read from the photos (ECEF) with their covariances."""

    names: list[str]
    position_ecef_m: np.ndarray          # (N, 3)
    cov_ecef_m2: np.ndarray              # (N, 3, 3)
    status: np.ndarray                   # (N,) 1 RTK fixed, 2 float, 5 single / navigation grade
    time_gps_s: np.ndarray               # (N,) from the EXIF time where there is one, else NaN
    kind: str                            # "rtk" (XMP RtkFlag) or "exif-gps"
    warnings: list[str] = field(default_factory=list)
    # (N, 2) the recorded gimbal pitch and yaw (DJI XMP GimbalPitchDegree / GimbalYawDegree, degrees: pitch -90
    # looking straight down, yaw from true north clockwise), NaN where a photo has none (photo/exif_heights.py)
    gimbal_deg: np.ndarray | None = None
    # every photo also carries DJI XMP RelativeAltitude: the heights come from a barometer zeroed at take-off
    heights_from_takeoff: bool = False

    @property
    def source(self) -> str:
        if self.kind == "rtk":
            return "RTK camera positions in the photos' XMP (drone-dji), weighted by their RtkStd sigmas"
        return (f"navigation-grade EXIF GPS of the photos, weighted {EXIF_GPS_SIGMA_M[0]:g} m horizontally and "
                f"{EXIF_GPS_SIGMA_M[1]:g} m vertically")


def _enu_cov_to_ecef(lat: float, lon: float, sig_neu: tuple[float, float, float]) -> np.ndarray:
    from ..gnss.frames import ecef_to_enu_rotation

    R = ecef_to_enu_rotation(lat, lon)
    d = np.diag([sig_neu[1] ** 2, sig_neu[0] ** 2, sig_neu[2] ** 2])    # E, N, U
    return R.T @ d @ R


def read_photo_positions(image_dir: Path, names: list[str], height_datum: str = "ellipsoidal") -> PhotoPositions | None:
    """Camera positions of the photos that carry one (RTK XMP first; EXIF GPS when no photo has RTK
    tags); None when no photo has a position. Photos without one are named in the warnings."""
    from ..gnss.frames import geodetic_to_ecef_m
    from ..gnss.gnss_time import utc_datetime_to_gps_time_s
    from .dji_xmp import read_dji_xmp
    from .images import read_image_info

    from ..datums.vertical_datum import resolve as resolve_datum

    image_dir = Path(image_dir)
    try:
        datum = resolve_datum(height_datum)
    except ValueError as exc:
        raise InputFileError(image_dir, f"photo height datum (survey.json photo_heights): {exc}") from None
    rtk, exif = {}, {}
    times, gimbal, relative = {}, {}, set()
    for name in names:
        p = image_dir / name
        x = read_dji_xmp(p)
        if x is not None and x.gimbal_pitch_deg is not None and x.gimbal_yaw_deg is not None:
            gimbal[name] = (float(x.gimbal_pitch_deg), float(x.gimbal_yaw_deg))
        if x is not None and x.relative_altitude_m is not None:
            relative.add(name)
        info = read_image_info(p, warn=False)
        if info.time_original is not None:
            t = info.time_original
            import datetime as dt

            utc = t.astimezone(dt.timezone.utc).replace(tzinfo=None) if t.tzinfo else t
            times[name] = utc_datetime_to_gps_time_s(utc)
        if x is not None and x.rtk_flag is not None and x.gps_latitude_deg is not None \
                and x.gps_longitude_deg is not None and x.absolute_altitude_m is not None:
            rtk[name] = x
        elif info.has_gps and info.gps_alt_m is not None:
            exif[name] = info
    if not rtk and not exif:
        return None
    warnings: list[str] = []
    out_names, pos, cov, status = [], [], [], []
    if rtk:
        if not datum.is_ellipsoidal:
            _to_ellipsoidal(rtk, datum, "gps_latitude_deg", "gps_longitude_deg", "absolute_altitude_m")
        missing = [n for n in names if n not in rtk]
        if missing:
            warnings.append(f"{len(missing)} photo(s) without RTK tags used without a position "
                            f"({', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''})")
        not_fixed = {}
        for name in names:
            x = rtk.get(name)
            if x is None:
                continue
            lat, lon = math.radians(x.gps_latitude_deg), math.radians(x.gps_longitude_deg)
            sig = tuple(max(RTK_SIGMA_FLOOR_M, float(v)) if v is not None and math.isfinite(v) else 0.05
                        for v in (x.rtk_std_lat_m, x.rtk_std_lon_m, x.rtk_std_hgt_m))
            out_names.append(name)
            pos.append(geodetic_to_ecef_m(lat, lon, x.absolute_altitude_m))
            cov.append(_enu_cov_to_ecef(lat, lon, sig))
            status.append(STATUS_OF_RTK_FLAG.get(int(x.rtk_flag), 5))
            if int(x.rtk_flag) != 50:
                not_fixed[name] = int(x.rtk_flag)
        if not_fixed:
            flags = sorted(set(not_fixed.values()))
            warnings.append(f"{len(not_fixed)} of {len(out_names)} photos were taken without an RTK fix (RtkFlag "
                            f"{', '.join(map(str, flags))}: 50 is fixed): they carry their larger sigmas "
                            f"({', '.join(list(not_fixed)[:5])}{' ...' if len(not_fixed) > 5 else ''})")
        kind = "rtk"
    else:
        if not datum.is_ellipsoidal:
            _to_ellipsoidal(exif, datum, "gps_lat_deg", "gps_lon_deg", "gps_alt_m")
        for name in names:
            info = exif.get(name)
            if info is None:
                continue
            lat, lon = math.radians(info.gps_lat_deg), math.radians(info.gps_lon_deg)
            out_names.append(name)
            pos.append(geodetic_to_ecef_m(lat, lon, info.gps_alt_m))
            cov.append(_enu_cov_to_ecef(lat, lon, (EXIF_GPS_SIGMA_M[0], EXIF_GPS_SIGMA_M[0], EXIF_GPS_SIGMA_M[1])))
            status.append(5)
        kind = "exif-gps"
    t = np.array([times.get(n, np.nan) for n in out_names], dtype=float)
    gim = np.array([gimbal.get(n, (np.nan, np.nan)) for n in out_names], dtype=float).reshape(-1, 2)
    return PhotoPositions(out_names, np.asarray(pos, dtype=float).reshape(-1, 3), np.asarray(cov).reshape(-1, 3, 3),
                          np.asarray(status, dtype=int), t, kind, warnings, gimbal_deg=gim,
                          heights_from_takeoff=bool(out_names) and all(n in relative for n in out_names))


def _to_ellipsoidal(records: dict, datum, lat_attr: str, lon_attr: str, height_attr: str) -> None:
    """The photos' heights in ``datum`` replaced, in place (copies of the records), by ellipsoidal heights."""
    import dataclasses

    from ..datums.vertical_datum import orthometric_to_ellipsoidal

    names = list(records)
    lat = np.array([getattr(records[n], lat_attr) for n in names], float)
    lon = np.array([getattr(records[n], lon_attr) for n in names], float)
    hgt = np.array([getattr(records[n], height_attr) for n in names], float)
    h = orthometric_to_ellipsoidal(datum, lat, lon, hgt)
    for n, v in zip(names, h):
        records[n] = dataclasses.replace(records[n], **{height_attr: float(v)})
