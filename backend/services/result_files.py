"""Readers of the files the steps write (pure functions on text/bytes, shared by the API and the report).

They are tolerant of the optional columns and keys a step may add, and strict about what they need."""

from __future__ import annotations

import csv
import io
import json
import math
from datetime import datetime

GPS_EPOCH = datetime(1980, 1, 6)


def _f(v):
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def parse_pos(text: str) -> list[dict]:
    """RTKLIB .pos (lat/lon/height form, GPST as calendar or week/TOW)."""
    rows = []
    for line in text.splitlines():
        if not line.strip() or line.startswith("%"):
            continue
        f = line.split()
        try:
            if "/" in f[0]:
                t = datetime.strptime(f[0] + " " + f[1], "%Y/%m/%d %H:%M:%S.%f")
                gps_s = (t - GPS_EPOCH).total_seconds()
                rest = f[2:]
            else:
                gps_s = int(f[0]) * 604800 + float(f[1])
                rest = f[2:]
            rows.append({"gps_time_s": round(gps_s, 3), "lat_deg": float(rest[0]), "lon_deg": float(rest[1]),
                         "height_m": float(rest[2]), "q": int(rest[3]), "ns": int(rest[4]),
                         "sdn_m": _f(rest[5]) if len(rest) > 5 else None, "sde_m": _f(rest[6]) if len(rest) > 6 else None,
                         "sdu_m": _f(rest[7]) if len(rest) > 7 else None,
                         "ratio": _f(rest[12]) if len(rest) > 12 else None})
        except (ValueError, IndexError):
            continue
    return rows


def parse_csv(text: str) -> list[dict]:
    out = []
    for r in csv.DictReader(io.StringIO(text)):
        row = {}
        for k, v in r.items():
            if k is None:
                continue
            x = _f(v)
            row[k.strip()] = x if x is not None and v not in ("",) and not k.strip().lower().endswith(("name", "image"))\
                else (v.strip() if isinstance(v, str) else v)
        out.append(row)
    return out


def normalise_residuals(json_text: str | None, csv_text: str | None) -> dict:
    """{"points": [{name, role, dx_m, dy_m, dz_m, d_m, ...}], "stats": {...}, "raw": ...} from the georef step's
    residuals.json (its declared shape: ResidualTable.to_dict, "points" and "statistics"), else its
    residuals.csv. The statistics are the core's (residual_table.residual_statistics), read from the file or,
    for a table that has only its CSV, computed by that same function: one definition for the API, the PDF,
    run comparison and the browser."""
    from georef_core.adjustment.residual_table import residual_statistics

    raw = json.loads(json_text) if json_text else None
    rows = raw.get("points") if isinstance(raw, dict) else None
    stats = raw.get("statistics") if isinstance(raw, dict) else None
    if rows is None and csv_text:
        # the core's CSV ends with its statistics rows (mean, std, rmse: no role): the points are the others
        rows = [r for r in parse_csv(csv_text)
                if r.get("role") or str(r.get("point", r.get("name", ""))) not in ("mean", "std", "rmse")]
    points = []
    for r in rows or []:
        if not isinstance(r, dict):
            continue
        dx, dy, dz = _f(r.get("dx_m")), _f(r.get("dy_m")), _f(r.get("dz_m"))
        d = _f(r.get("d3_m"))
        if d is None and None not in (dx, dy, dz):
            d = math.sqrt(dx * dx + dy * dy + dz * dz)
        points.append({**r, "name": r.get("name", r.get("point")), "dx_m": dx, "dy_m": dy, "dz_m": dz, "d_m": d})
    if not isinstance(stats, dict):
        stats = residual_statistics([(p["dx_m"], p["dy_m"], p["dz_m"]) for p in points
                                     if None not in (p["dx_m"], p["dy_m"], p["dz_m"])])
    return {"points": points, "stats": stats, "raw": raw}


def rmse_3d_m(residuals: dict) -> float | None:
    """The 3D RMSE of a normalised residual table's statistics (None without points)."""
    return _f(((residuals.get("stats") or {}).get("3d") or {}).get("rmse_m"))


