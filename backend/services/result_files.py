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


def _pick(d: dict, *names):
    for n in names:
        if n in d and d[n] is not None:
            return d[n]
    return None


def normalise_residuals(json_text: str | None, csv_text: str | None) -> dict:
    """{"points": [{name, role, dx_m, dy_m, dz_m, d_m, ...}], "stats": {...}} from residuals.json/.csv."""
    raw = json.loads(json_text) if json_text else None
    rows = None
    stats: dict = {}
    if isinstance(raw, dict):
        for key in ("points", "check_points", "residuals", "rows", "table"):
            if isinstance(raw.get(key), list):
                rows = raw[key]
                break
        for key in ("stats", "summary", "statistics"):
            if isinstance(raw.get(key), dict):
                stats = raw[key]
                break
    elif isinstance(raw, list):
        rows = raw
    if rows is None and csv_text:
        rows = parse_csv(csv_text)
    points = []
    for r in rows or []:
        if not isinstance(r, dict):
            continue
        dx, dy, dz = _pick(r, "dx_m", "dx", "de_m", "dE_m"), _pick(r, "dy_m", "dy", "dn_m", "dN_m"), \
            _pick(r, "dz_m", "dz", "dh_m", "du_m")
        d = _pick(r, "d_m", "d3_m", "d3d_m", "norm_m", "abs_m", "|d|_m", "d")
        if d is None and None not in (dx, dy, dz):
            d = math.sqrt(dx * dx + dy * dy + dz * dz)
        points.append({**r, "name": _pick(r, "name", "point", "id"), "dx_m": dx, "dy_m": dy, "dz_m": dz, "d_m": d})
    if not stats and points:
        stats = residual_stats(points)
    return {"points": points, "stats": stats, "raw": raw}


def residual_stats(points: list[dict]) -> dict:
    out = {"n": len(points)}
    for c in ("dx_m", "dy_m", "dz_m", "d_m"):
        v = [p[c] for p in points if p.get(c) is not None]
        if v:
            n = len(v)
            mean = sum(v) / n
            out[c] = {"mean": mean, "std": math.sqrt(sum((x - mean) ** 2 for x in v) / n),
                      "rmse": math.sqrt(sum(x * x for x in v) / n), "max_abs": max(abs(x) for x in v)}
    return out


def rmse_of(residuals: dict, component: str = "d_m") -> float | None:
    st = residuals.get("stats") or {}
    c = st.get(component)
    if isinstance(c, dict):
        return _f(c.get("rmse"))
    for key in (f"rmse_{component}", f"{component}_rmse", "rmse_3d_m", "rmse_m"):
        if key in st:
            return _f(st[key])
    return None
