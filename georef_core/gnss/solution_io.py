"""Writing and reading PPK solutions: RTKLIB-compatible .pos text (so existing tools read it), and a
columnar Parquet file for the rest of the pipeline (positions in ECEF, geodetic and an optional EPSG CRS,
full covariance, velocity, quality), plus the DD residuals in long form."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputFileError
from .frames import ecef_to_crs, ecef_to_geodetic
from .gnss_time import calendar_to_gps_time_s, gps_time_s_to_datetime

STATUS_NAMES = {0: "none", 1: "fix", 2: "float", 5: "single"}


def _signed_sqrt(v):
    return np.sign(v) * np.sqrt(np.abs(v))


def _enu_rotations(lat_rad: np.ndarray, lon_rad: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations ECEF -> local east/north/up (frames.ecef_to_enu_rotation for many points)."""
    sl, cl, so, co = np.sin(lat_rad), np.cos(lat_rad), np.sin(lon_rad), np.cos(lon_rad)
    zero = np.zeros_like(sl)
    return np.stack([np.stack([-so, co, zero], -1), np.stack([-sl * co, -sl * so, cl], -1),
                     np.stack([cl * co, cl * so, sl], -1)], -2)


def write_pos(path, sol, program: str = "georef") -> None:
    """RTKLIB .pos, latitude/longitude/height (ellipsoidal), GPST calendar time, ENU standard deviations."""
    o = sol.options
    lines = [f"% program   : {program}"]
    for role in ("rover", "base", "nav"):
        for p in sol.input_paths.get(role, []):
            # the file's name only: the folder it was read from is the processing machine's business
            lines.append(f"% inp file  : {str(p).replace(chr(92), '/').rsplit('/', 1)[-1]}")
    valid = np.nonzero(sol.status > 0)[0]
    if len(valid):
        t0, t1 = gps_time_s_to_datetime(sol.time_s[valid[0]]), gps_time_s_to_datetime(sol.time_s[valid[-1]])
        lines.append(f"% obs start : {t0:%Y/%m/%d %H:%M:%S}.{t0.microsecond // 100000:d} GPST")
        lines.append(f"% obs end   : {t1:%Y/%m/%d %H:%M:%S}.{t1.microsecond // 100000:d} GPST")
    lines += [f"% pos mode  : {o.mode}", f"% freqs     : {['L1', 'L1+L2', 'L1+L2+L5'][o.n_bands - 1]}",
              f"% solution  : {o.filter_direction}", f"% elev mask : {o.elevation_mask_deg:.1f} deg",
              f"% amb res   : {o.ar_mode}", f"% val thres : {o.ratio_threshold:.1f}"]
    bl = ecef_to_geodetic(sol.base_position_ecef_m)
    lines.append(f"% ref pos   : {np.degrees(bl[0]):13.9f} {np.degrees(bl[1]):14.9f} {bl[2]:10.4f}")
    lines.append("%")
    lines.append("% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)")
    lines.append("%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)"
                 "  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio")
    llh = ecef_to_geodetic(np.nan_to_num(sol.position_ecef_m))
    rot = _enu_rotations(llh[valid, 0], llh[valid, 1])
    q_enu = rot @ sol.covariance_ecef_m2[valid] @ rot.transpose(0, 2, 1)
    sd = np.sqrt(np.abs(np.diagonal(q_enu, axis1=1, axis2=2)))  # e, n, u
    sdne, sdeu, sdun = _signed_sqrt(q_enu[:, 1, 0]), _signed_sqrt(q_enu[:, 0, 2]), _signed_sqrt(q_enu[:, 2, 1])
    lat, lon, h = np.degrees(llh[valid, 0]), np.degrees(llh[valid, 1]), llh[valid, 2]
    age = np.where(np.isfinite(sol.age_s[valid]), sol.age_s[valid], 0.0)
    # Python floats and ints (formatting numpy scalars costs ~1 us per field)
    cols = [lat, lon, h, sol.status[valid].astype(int), sol.n_sats[valid].astype(int), sd[:, 1], sd[:, 0], sd[:, 2],
            sdne, sdeu, sdun, age, sol.ratio[valid]]
    times_ms = np.round(sol.time_s[valid] * 1000.0).astype(np.int64).tolist()
    fmt = "%s %02d:%02d:%02d.%03d %14.9f %14.9f %10.4f %3d %3d %8.4f %8.4f %8.4f %8.4f %8.4f %8.4f %6.2f %6.1f"
    dates: dict[int, str] = {}   # calendar date text per GPS day, formatted once
    for t_ms, row in zip(times_ms, zip(*(c.tolist() for c in cols))):
        day, ms_of_day = divmod(t_ms, 86_400_000)
        date = dates.get(day)
        if date is None:
            date = dates[day] = f"{gps_time_s_to_datetime(day * 86400.0):%Y/%m/%d}"
        sec, ms = divmod(ms_of_day, 1000)
        lines.append(fmt % (date, sec // 3600, sec // 60 % 60, sec % 60, ms, *row))
    Path(path).write_text("\n".join(lines) + "\n")


@dataclass
class PosFile:
    time_s: np.ndarray     # gps_time_s
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height_m: np.ndarray
    status: np.ndarray
    n_sats: np.ndarray
    sd_enu_m: np.ndarray   # (E, 3)
    ratio: np.ndarray


def read_pos(path) -> PosFile:
    """Read an RTKLIB .pos file written with llh and GPST calendar time (ours or rnx2rtkp's)."""
    rows = []
    p = Path(path)
    for lineno, line in enumerate(p.read_text().splitlines(), 1):
        if not line.strip() or line.startswith("%"):
            continue
        f = line.split()
        if len(f) < 15:
            raise InputFileError(p, f"expected 15 columns of an llh .pos record, got {len(f)}", lineno)
        y, mo, d = (int(v) for v in f[0].split("/"))
        hh, mm, ss = f[1].split(":")
        rows.append((y, mo, d, int(hh), int(mm), float(ss), *(float(v) for v in f[2:15])))
    if not rows:
        raise InputFileError(p, "no solution records")
    a = np.array(rows, dtype=float)
    t = calendar_to_gps_time_s(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5])
    return PosFile(np.asarray(t), a[:, 6], a[:, 7], a[:, 8], a[:, 9].astype(int), a[:, 10].astype(int),
                   a[:, [12, 11, 13]], a[:, 18])


def _arrow_table(cols: dict):
    """pyarrow.Table of numpy columns (numbers, booleans) and lists of str, built from the arrays' buffers:
    ``pa.table``/``pa.array`` import pandas to check for pandas objects (~0.2 s of every ``georef gnss
    solve``); the columns are the same (NaN stays NaN, not null)."""
    import pyarrow as pa

    arrays = []
    for v in cols.values():
        if isinstance(v, list):
            data = [s.encode() for s in v]
            offsets = np.zeros(len(data) + 1, dtype=np.int32)
            np.cumsum([len(b) for b in data], out=offsets[1:])
            arrays.append(pa.Array.from_buffers(pa.string(), len(data),
                                                [None, pa.py_buffer(offsets), pa.py_buffer(b"".join(data))]))
            continue
        a = np.ascontiguousarray(v)
        if a.dtype == bool:
            arrays.append(pa.Array.from_buffers(pa.bool_(), len(a),
                                                [None, pa.py_buffer(np.packbits(a, bitorder="little"))]))
        else:
            arrays.append(pa.Array.from_buffers(pa.from_numpy_dtype(a.dtype), len(a), [None, pa.py_buffer(a)]))
    return pa.Table.from_arrays(arrays, names=list(cols))


def solution_table(sol, epsg: int | None = None):
    """Columnar table (pyarrow.Table) of the solution, units in column names."""
    llh = ecef_to_geodetic(np.nan_to_num(sol.position_ecef_m))
    cols = {
        "gps_time_s": sol.time_s, "receiver_time_s": sol.receiver_time_s,
        "status": sol.status.astype(np.int8), "quality": [STATUS_NAMES.get(int(s), "none") for s in sol.status],
        "x_ecef_m": sol.position_ecef_m[:, 0], "y_ecef_m": sol.position_ecef_m[:, 1], "z_ecef_m": sol.position_ecef_m[:, 2],
        "lat_deg": np.degrees(llh[:, 0]), "lon_deg": np.degrees(llh[:, 1]), "height_ellipsoid_m": llh[:, 2],
    }
    for i, a in enumerate("xyz"):
        for j, b in enumerate("xyz"):
            if j >= i:
                cols[f"cov_{a}{b}_ecef_m2"] = sol.covariance_ecef_m2[:, i, j]
    enu_sd = np.full((len(sol.time_s), 3), np.nan)
    vel_enu = np.full((len(sol.time_s), 3), np.nan)
    ok = np.nonzero(sol.status > 0)[0]
    r = _enu_rotations(llh[ok, 0], llh[ok, 1])                      # (n, 3, 3), as ecef_to_enu_rotation
    enu_sd[ok] = np.sqrt(np.abs(np.einsum("nij,njk,nik->ni", r, sol.covariance_ecef_m2[ok], r)))
    vel_enu[ok] = np.einsum("nij,nj->ni", r, sol.velocity_ecef_m_s[ok])
    cols.update({"sd_east_m": enu_sd[:, 0], "sd_north_m": enu_sd[:, 1], "sd_up_m": enu_sd[:, 2]})
    cols.update({"vx_ecef_m_s": sol.velocity_ecef_m_s[:, 0], "vy_ecef_m_s": sol.velocity_ecef_m_s[:, 1],
                 "vz_ecef_m_s": sol.velocity_ecef_m_s[:, 2], "v_east_m_s": vel_enu[:, 0], "v_north_m_s": vel_enu[:, 1],
                 "v_up_m_s": vel_enu[:, 2],
                 "sd_vel_m_s": np.sqrt(np.abs(np.trace(sol.velocity_covariance_m2_s2, axis1=1, axis2=2)))})
    cols.update({"n_sats": sol.n_sats, "ratio": sol.ratio, "age_s": sol.age_s})
    if epsg:
        proj = ecef_to_crs(np.nan_to_num(sol.position_ecef_m), epsg)
        cols.update({f"x_epsg{epsg}": proj[:, 0], f"y_epsg{epsg}": proj[:, 1], f"z_epsg{epsg}": proj[:, 2]})
    return _arrow_table(cols)


def residual_table(sol):
    """Long-form DD phase residuals: gps_time_s, sat, band, residual_m."""
    e_i, s_i, b_i = np.nonzero(np.isfinite(sol.residuals_m))
    return _arrow_table({"gps_time_s": sol.time_s[e_i], "sat": [sol.sat_ids[s] for s in s_i],
                         "band": b_i.astype(np.int8), "residual_m": sol.residuals_m[e_i, s_i, b_i]})


def write_parquet(path, sol, epsg: int | None = None) -> None:
    import pyarrow.parquet as pq

    pq.write_table(solution_table(sol, epsg), path)
    pq.write_table(residual_table(sol), str(Path(path).with_suffix("")) + "_residuals.parquet")
