"""Point tables (control and check points) in a vertical datum, the datum named in every file.

CSV: columns name, role, easting_m, northing_m, height_m, then the residuals when known, then horizontal_crs
and vertical_datum on every row (e.g. EPSG:32631, EPSG:5773), so that a row copied alone still says what its
height is. GeoJSON (RFC 7946): Point geometries in longitude, latitude and the height in the datum, the
projected coordinates as properties, and the foreign members horizontal_crs, vertical_datum and
height_datum naming them.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from .vertical_datum import convert_heights, datum_of_crs, horizontal_crs, resolve

RESIDUAL_KEYS = ("dx_m", "dy_m", "dz_m")


def points_in_datum(points, site_crs, datum) -> list[dict]:
    """Ground points (adjustment.control_points.GroundPoint: coordinates in their own CRS, heights ellipsoidal
    unless that CRS is compound with a vertical datum) as rows in ``site_crs`` with heights in ``datum``:
    [{name, role, easting_m, northing_m, height_m, lat_deg, lon_deg}]."""
    from pyproj import CRS, Transformer

    datum = resolve(datum)
    site_h = horizontal_crs(site_crs)
    rows = []
    for p in points:
        crs = CRS.from_user_input(p.crs)
        src_datum = datum_of_crs(crs) if crs.is_compound else None
        hcrs = horizontal_crs(crs)
        lon, lat = Transformer.from_crs(hcrs, "EPSG:4326", always_xy=True).transform(p.xyz_crs[0], p.xyz_crs[1])
        e, n = Transformer.from_crs("EPSG:4326", site_h, always_xy=True).transform(lon, lat)
        z = convert_heights(lat, lon, float(p.xyz_crs[2]), src_datum or "ellipsoidal", datum)
        rows.append({"name": p.name, "role": p.role, "easting_m": float(e), "northing_m": float(n),
                     "height_m": float(z), "lat_deg": float(lat), "lon_deg": float(lon)})
    return rows


def _crs_code(crs) -> str:
    from pyproj import CRS

    c = horizontal_crs(CRS.from_user_input(crs))
    auth = c.to_authority()
    return f"{auth[0]}:{auth[1]}" if auth else c.name


def write_points_csv(path, rows: list[dict], site_crs, datum) -> Path:
    datum = resolve(datum)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with_res = any(k in r for r in rows for k in RESIDUAL_KEYS)
    code = _crs_code(site_crs)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["name", "role", "easting_m", "northing_m", "height_m", *(RESIDUAL_KEYS if with_res else ()),
                    "horizontal_crs", "vertical_datum"])
        for r in rows:
            res = [("" if r.get(k) is None else f"{r[k]:.4f}") for k in RESIDUAL_KEYS] if with_res else []
            w.writerow([r["name"], r.get("role", ""), f"{r['easting_m']:.4f}", f"{r['northing_m']:.4f}",
                        f"{r['height_m']:.4f}", *res, code, datum.code])
    return path


def write_points_geojson(path, rows: list[dict], site_crs, datum) -> Path:
    datum = resolve(datum)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    feats = []
    for r in rows:
        props = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()
                 if k not in ("lat_deg", "lon_deg")}
        feats.append({"type": "Feature", "properties": props,
                      "geometry": {"type": "Point", "coordinates": [round(r["lon_deg"], 9), round(r["lat_deg"], 9),
                                                                    round(r["height_m"], 4)]}})
    doc = {"type": "FeatureCollection", "horizontal_crs": _crs_code(site_crs), "vertical_datum": datum.code,
           "height_datum": datum.label, "features": feats}
    path.write_text(json.dumps(doc, indent=1))
    return path


def attach_residuals(rows: list[dict], residuals_json) -> list[dict]:
    """The georef step's residuals (residuals.json: d = estimated - surveyed) added to the rows by name. The
    residuals are differences at one place: the datum changes them by the geoid's slope times the residual
    (under 1e-4 x a few cm: below a micrometre), so they hold in any datum."""
    path = Path(residuals_json)
    if not path.is_file():
        return rows
    doc = json.loads(path.read_text())
    by_name = {p["name"]: p for p in doc.get("points", [])}
    out = []
    for r in rows:
        p = by_name.get(r["name"])
        out.append({**r, **({k: float(p[k]) for k in RESIDUAL_KEYS if p.get(k) is not None and np.isfinite(p[k])}
                            if p else {})})
    return out
