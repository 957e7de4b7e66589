"""Ground control / check points: surveyed coordinates (CSV in any CRS) and their image measurements
(OpenDroneMap ``gcp_list.txt``).

``points.csv``: a header row with a name column and three coordinate columns (``easting_m``/``x``/``lon``...,
``northing_m``/``y``/``lat``..., ``ellipsoidal_height_m``/``height``/``z``...) and optionally ``role``
(``control`` or ``check``). The CRS is given by the caller (option, survey.json ``points_crs``).

``gcp_list.txt`` (OpenDroneMap): first line the CRS (``EPSG:32611``, a PROJ string such as
``+proj=utm +zone=11 ...``, or ``WGS84 UTM 11N``), then one measurement per line:
``geo_x geo_y geo_z pixel_x pixel_y image_name [point_name]``; pixel (0, 0) is the centre of the top-left
pixel. Without point names, points are told apart by their coordinates.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError

_X = ("easting_m", "easting", "e", "x", "x_m", "lon", "lon_deg", "longitude")
_Y = ("northing_m", "northing", "n", "y", "y_m", "lat", "lat_deg", "latitude")
_Z = ("ellipsoidal_height_m", "height_m", "height", "h", "z", "z_m", "elevation", "alt", "altitude")


@dataclass
class GroundPoint:
    name: str
    xyz_crs: np.ndarray          # in ``crs`` (x=easting/lon, y=northing/lat, z=height)
    crs: str
    role: str = "control"        # control | check
    sigma_m: tuple[float, float] = (0.01, 0.02)  # horizontal, vertical (survey accuracy)


@dataclass
class ImageMeasurement:
    point: str
    image: str
    uv_px: np.ndarray            # OpenCV pixel convention
    source: str = ""             # file:line


@dataclass
class ControlData:
    points: dict[str, GroundPoint] = field(default_factory=dict)
    measurements: list[ImageMeasurement] = field(default_factory=list)

    def measurements_of(self, name: str) -> list[ImageMeasurement]:
        return [m for m in self.measurements if m.point == name]


def parse_crs(text: str, path=None) -> str:
    """A CRS string from a gcp_list header or an option, validated by pyproj; returns a pyproj-readable form."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    t = text.strip()
    m = re.match(r"^WGS84\s+UTM\s+(\d{1,2})\s*([NS])$", t, re.IGNORECASE)
    if m:
        zone, hemi = int(m.group(1)), m.group(2).upper()
        t = f"EPSG:{(32600 if hemi == 'N' else 32700) + zone}"
    try:
        if not t or t[0] in "0123456789+-." and not t.startswith("+proj"):
            raise CRSError("a number, not a CRS")   # a measurement line where the CRS line should be: no lookup
        CRS.from_user_input(t)
    except CRSError:
        raise InputFileError(path or "<crs>", f"unknown coordinate reference system {text.strip()!r} "
                                              f"(give e.g. EPSG:32633, a PROJ string, or 'WGS84 UTM 33N')") from None
    return t


POINT_FIELDS = ("easting_m", "northing_m", "ellipsoidal_height_m")
# no coordinate of a point on Earth exceeds this in any CRS (projected: < 4e7 m; geocentric: < 7e6 m)
MAX_ABS_COORDINATE = 1e8


def parse_points_table(text: str, default_role: str = "check", source=None) -> list[dict]:
    """The rows of a surveyed-points table (CSV: a name column and easting/x, northing/y, height/z columns
    under any of their usual names, an optional role/type/use column: control or check, 'gcp' meaning
    control) as {name, easting_m, northing_m, ellipsoidal_height_m, role}: the one reading of points.csv,
    for the georef step and the upload check alike. Raises InputFileError(source, problem, line)."""
    rows = list(csv.reader(line for line in text.splitlines() if line.strip() and not line.startswith("#")))
    if not rows:
        raise InputFileError(source, "the point file is empty")
    head = [h.strip().lower() for h in rows[0]]

    def col(cands):
        for c in cands:
            if c in head:
                return head.index(c)
        return None

    ix, iy, iz = col(_X), col(_Y), col(_Z)
    iname = col(("name", "id", "point", "label"))
    irole = col(("role", "type", "use"))
    if None in (ix, iy, iz, iname):
        raise InputFileError(source, f"needs columns name, easting/x, northing/y and height/z; found {rows[0]}")
    out, seen = [], set()
    for k, r in enumerate(rows[1:], start=2):
        if len(r) < len(head):
            raise InputFileError(source, f"{len(r)} fields, {len(head)} expected", line=k)
        xyz = []
        for i in (ix, iy, iz):
            try:
                v = float(r[i])
            except ValueError:
                raise InputFileError(source, f"{head[i]} {r[i]!r} is not a number", line=k) from None
            if not math.isfinite(v):
                raise InputFileError(source, f"{head[i]} {r[i]!r} is not finite", line=k)
            if abs(v) > MAX_ABS_COORDINATE:   # 1e308 ran to a "succeeded" run with an empty residual table
                raise InputFileError(source, f"{head[i]} {r[i]!r} is not a place on Earth (over "
                                             f"{MAX_ABS_COORDINATE:g} in absolute value in any CRS)", line=k)
            xyz.append(v)
        name = r[iname].strip() if iname < len(r) else ""
        if not name:
            raise InputFileError(source, "empty point name", line=k)
        role = (r[irole].strip().lower() if irole is not None and irole < len(r) else default_role) or default_role
        if role in ("gcp", "control point"):
            role = "control"
        if role not in ("control", "check"):
            raise InputFileError(source, f"role {role!r} of {name} is neither control nor check", line=k)
        if name in seen:
            raise InputFileError(source, f"point {name} appears twice", line=k)
        seen.add(name)
        out.append({"name": name, **dict(zip(POINT_FIELDS, xyz)), "role": role})
    if not out:
        raise InputFileError(source, "header only, no point")
    return out


def read_points_csv(path, crs: str, default_role: str = "check") -> dict[str, GroundPoint]:
    path = Path(path)
    crs = parse_crs(crs, path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"cannot read the point file ({exc})") from None
    return {r["name"]: GroundPoint(r["name"], np.array([r[c] for c in POINT_FIELDS]), crs, r["role"])
            for r in parse_points_table(text, default_role, path)}


def read_gcp_list(path) -> tuple[str, dict[str, GroundPoint], list[ImageMeasurement]]:
    """OpenDroneMap gcp_list.txt -> (crs, points with role 'control', measurements)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"cannot read the GCP file ({exc})") from None
    return parse_gcp_list(text, path)


def parse_gcp_list(text: str, source) -> tuple[str, dict[str, GroundPoint], list[ImageMeasurement]]:
    """The text of an OpenDroneMap gcp_list.txt (a CRS line, then 'x y z px py image [name]' per
    measurement) -> (crs, points with role 'control', measurements): the one reading of the format, for the
    georef step and the upload check alike. Raises InputFileError(source, problem, line)."""
    name_of = Path(str(source)).name
    lines = [(k, ln) for k, ln in enumerate(text.splitlines(), start=1)
             if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise InputFileError(source, "the GCP file is empty")
    crs = parse_crs(lines[0][1], source)
    if len(lines) < 2:
        raise InputFileError(source, "a CRS line and no measurement")
    points: dict[str, GroundPoint] = {}
    meas = []
    by_coords: dict[tuple, str] = {}
    for k, ln in lines[1:]:
        tok = ln.split()
        if len(tok) < 6:
            raise InputFileError(source, f"expected 'x y z px py image [name]', got {ln.strip()[:80]!r}", line=k)
        try:
            xyz = np.array([float(tok[0]), float(tok[1]), float(tok[2])])
            uv = np.array([float(tok[3]), float(tok[4])])
        except ValueError:
            raise InputFileError(source, "a coordinate is not a number", line=k) from None
        if not (np.all(np.isfinite(xyz)) and np.all(np.isfinite(uv))):
            raise InputFileError(source, "a coordinate is not a finite number", line=k)
        key = tuple(np.round(xyz, 3))
        name = tok[6] if len(tok) >= 7 else by_coords.get(key, f"gcp{len(by_coords) + 1:02d}")
        by_coords.setdefault(key, name)
        if name in points and np.max(np.abs(points[name].xyz_crs - xyz)) > 1e-3:
            raise InputFileError(source, f"point {name} is given with two different coordinates", line=k)
        points.setdefault(name, GroundPoint(name, xyz, crs, "control"))
        meas.append(ImageMeasurement(name, tok[5], uv, f"{name_of}:{k}"))
    return crs, points, meas


def load_control(points_csv=None, gcp_list=None, points_crs: str | None = None) -> ControlData:
    """Points from points.csv (coordinates and roles win) and/or gcp_list.txt (measurements)."""
    data = ControlData()
    if gcp_list is not None and Path(gcp_list).is_file():
        crs, pts, meas = read_gcp_list(gcp_list)
        data.points.update(pts)
        data.measurements = meas
        points_crs = points_crs or crs
    if points_csv is not None and Path(points_csv).is_file():
        if not points_crs:
            raise InputFileError(points_csv, "the CRS of the point file is unknown: give --points-crs (e.g. EPSG:32633) "
                                             "or points_crs in survey.json")
        data.points.update(read_points_csv(points_csv, points_crs))
    unknown = sorted({m.point for m in data.measurements} - set(data.points))
    if unknown:
        raise InputFileError(gcp_list, f"measurements of points missing from the point file: {', '.join(unknown)}")
    return data


def point_sigma_enu_cov(points: list[GroundPoint]) -> np.ndarray:
    return np.stack([np.diag([p.sigma_m[0] ** 2, p.sigma_m[0] ** 2, p.sigma_m[1] ** 2]) for p in points]) \
        if points else np.zeros((0, 3, 3))


def points_to_enu(points: list[GroundPoint], frame) -> np.ndarray:
    """Coordinates of the points in the project frame's local ENU (any CRS through pyproj; a point
    file in a 2-D CRS is taken with ellipsoidal heights, one in a compound CRS with that CRS's vertical
    datum's heights)."""
    from pyproj import CRS, Transformer

    from ..gnss.frames import geodetic_to_ecef_m

    out = np.zeros((len(points), 3))
    for k, p in enumerate(points):
        crs = CRS.from_user_input(p.crs)
        # a compound CRS (e.g. EPSG:32631+5773) gives orthometric heights: made ellipsoidal through the geoid
        # grid (georef_core.datums; an error when the grid is missing, never taken as ellipsoidal)
        tr = Transformer.from_crs(crs.sub_crs_list[0] if crs.is_compound else crs, "EPSG:4326", always_xy=True)
        lon, lat = tr.transform(p.xyz_crs[0], p.xyz_crs[1])
        h = p.xyz_crs[2]
        if crs.is_compound:
            from ..datums.vertical_datum import datum_of_crs, orthometric_to_ellipsoidal

            h = float(orthometric_to_ellipsoidal(datum_of_crs(crs), lat, lon, h))
        ecef = geodetic_to_ecef_m(np.radians(lat), np.radians(lon), h).reshape(3)
        out[k] = frame.ecef_to_enu(ecef)
    return out
