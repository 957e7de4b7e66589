"""What the survey report reads from a run folder: each step's summary and declared outputs (the step
contract: georef_core/steps/specs.py), parsed defensively (a missing or unreadable file is a section that
says so, never a failed report)."""

from __future__ import annotations

import json
import math
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from .. import result_files


def read_json(path: Path):
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def gnss_summary(run_dir: Path) -> dict | None:
    return read_json(run_dir / "ppk" / "summary.json") or read_json(run_dir / "ppk" / "trajectory_summary.json")


def pos_epochs(path: Path, max_lines: int = 2_000_000) -> dict | None:
    """The epochs of an RTKLIB .pos file: gps time (s, from the file's GPST date and time), the quality flag
    Q and the 3D sigma (m, from the sdn/sde/sdu or sdx/sdy/sdz columns); None without epochs."""
    try:
        fh = open(path, encoding="latin-1")
    except OSError:
        return None
    t, q, s = [], [], []
    gpst = True
    with fh:
        for k, line in enumerate(fh):
            if k > max_lines:
                break
            if line.startswith("%"):
                if "UTC" in line and "GPST" not in line and "latitude" in line:
                    gpst = False
                continue
            f = line.split()
            if len(f) < 10:
                continue
            try:
                dt = datetime.strptime(f"{f[0]} {f[1][:15]}", "%Y/%m/%d %H:%M:%S.%f").replace(tzinfo=timezone.utc)
                t.append(dt.timestamp())
                q.append(int(f[5]))
                s.append(math.sqrt(float(f[7]) ** 2 + float(f[8]) ** 2 + float(f[9]) ** 2))
            except (ValueError, IndexError):
                continue
    if not t:
        return None
    return {"unix_s": np.array(t), "status": np.array(q), "sigma3d_m": np.array(s), "time_scale": "GPST" if gpst else "UTC"}


def trigger_rows(run_dir: Path) -> list[dict]:
    p = run_dir / "ppk" / "events.csv"
    if not p.exists():
        p = run_dir / "ppk" / "trajectory_events.csv"
    try:
        return result_files.parse_csv(p.read_text()) if p.exists() else []
    except (OSError, ValueError):
        return []


GPS_EPOCH_UNIX_S = 315964800.0


def residuals(run_dir: Path) -> dict | None:
    rj, rc = run_dir / "residuals.json", run_dir / "residuals.csv"
    if not (rj.exists() or rc.exists()):
        return None
    try:
        return result_files.normalise_residuals(rj.read_text() if rj.exists() else None,
                                                rc.read_text() if rc.exists() else None)
    except (OSError, ValueError):
        return None


def surveyed_points(survey_dir: Path | None, crs: str | None) -> list[dict]:
    """The surveyed points of the survey's gcp/points.csv in the project CRS: [{name, role, e, n, h}] (the
    survey's survey.json names the points' CRS when it differs); [] when absent or unreadable."""
    if survey_dir is None:
        return []
    p = Path(survey_dir) / "gcp" / "points.csv"
    if not p.exists():
        return []
    try:
        from georef_core.adjustment.control_points import parse_points_table

        rows = parse_points_table(p.read_text(), source=p.name)
    except Exception:           # noqa: BLE001 - a points file the georef step refused: no map markers
        return []
    info = read_json(Path(survey_dir) / "survey.json") or {}
    pts_crs = info.get("points_crs") or crs
    e = np.array([r["easting_m"] for r in rows], float)
    n = np.array([r["northing_m"] for r in rows], float)
    if pts_crs and crs and pts_crs != crs:
        try:
            from pyproj import Transformer

            e, n = Transformer.from_crs(pts_crs, crs, always_xy=True).transform(e, n)
        except Exception:       # noqa: BLE001
            return []
    return [{"name": r["name"], "role": r.get("role", "check"), "e": float(a), "n": float(b),
             "h": r["ellipsoidal_height_m"]} for r, a, b in zip(rows, e, n)]


def outline_rings(stockpiles: list[dict] | None) -> list[dict]:
    """The stockpile outlines' outer rings (GeoJSON Polygon or MultiPolygon in the site CRS)."""
    out = []
    for p in stockpiles or []:
        g = p.get("outline") or {}
        if g.get("type") == "Feature":
            g = g.get("geometry") or {}
        polys = [g.get("coordinates")] if g.get("type") == "Polygon" else (g.get("coordinates") or []) \
            if g.get("type") == "MultiPolygon" else []
        for poly in polys:
            if poly and isinstance(poly[0], list) and len(poly[0]) >= 3:
                out.append({"name": p.get("name", ""), "ring": [(float(q[0]), float(q[1])) for q in poly[0]]})
    return out


def volumes_from_file(run_dir: Path) -> list[dict]:
    """The volumes step's records (volumes/volumes.json) shaped as the report's volume rows."""
    doc = read_json(run_dir / "volumes" / "volumes.json") or {}
    rows = []
    for r in doc.get("stockpiles") or []:
        if isinstance(r, dict):
            rows.append({"name": r.get("stockpile_name", ""), "base": r.get("base", ""), "volume_m3": r.get("volume_m3"),
                         "sigma_m3": (r.get("details") or {}).get("sigma_m3"), "area_m2": r.get("area_m2")})
    return rows


