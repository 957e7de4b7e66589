"""Earth frames: ECEF <-> geodetic (WGS84), local ENU rotations, and any EPSG CRS through pyproj."""

from __future__ import annotations

import numpy as np

from .constants import WGS84_A_M, WGS84_E2


def geodetic_to_ecef_m(lat_rad, lon_rad, h_m) -> np.ndarray:
    """Geodetic latitude/longitude (radians) and ellipsoidal height (m) to ECEF (m); vectorised, last axis xyz."""
    lat_rad, lon_rad, h_m = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (lat_rad, lon_rad, h_m)))
    sin_lat = np.sin(lat_rad)
    n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    x = (n + h_m) * np.cos(lat_rad) * np.cos(lon_rad)
    y = (n + h_m) * np.cos(lat_rad) * np.sin(lon_rad)
    z = (n * (1.0 - WGS84_E2) + h_m) * sin_lat
    return np.stack([x, y, z], axis=-1)


def ecef_to_geodetic(ecef_m) -> np.ndarray:
    """ECEF (m), last axis xyz, to [lat_rad, lon_rad, h_m] (iterative, converges to < 1e-4 mm)."""
    p = np.asarray(ecef_m, dtype=float)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    r2 = x * x + y * y
    zk = z.copy() if np.ndim(z) else float(z)
    v = WGS84_A_M
    for _ in range(10):
        sinp = zk / np.sqrt(r2 + zk * zk)
        v = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sinp * sinp)
        zk = z + v * WGS84_E2 * sinp
    lat = np.where(r2 > 1e-12, np.arctan(zk / np.sqrt(np.maximum(r2, 1e-300))), np.where(z > 0, np.pi / 2, -np.pi / 2))
    lon = np.where(r2 > 1e-12, np.arctan2(y, x), 0.0)
    h = np.sqrt(r2 + zk * zk) - v
    return np.stack([lat, lon, h], axis=-1)


def ecef_to_enu_rotation(lat_rad: float, lon_rad: float) -> np.ndarray:
    """3x3 matrix R with enu = R @ d_ecef."""
    sl, cl = np.sin(lat_rad), np.cos(lat_rad)
    so, co = np.sin(lon_rad), np.cos(lon_rad)
    return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])


def ecef_delta_to_enu_m(delta_ecef_m, origin_ecef_m) -> np.ndarray:
    lat, lon, _ = ecef_to_geodetic(np.asarray(origin_ecef_m, dtype=float))
    return np.asarray(delta_ecef_m, dtype=float) @ ecef_to_enu_rotation(lat, lon).T


def azimuth_elevation_rad(receiver_ecef_m, sat_ecef_m) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (radians) of satellites (N,3) seen from one receiver position (3,)."""
    rcv = np.asarray(receiver_ecef_m, dtype=float)
    lat, lon, _ = ecef_to_geodetic(rcv)
    d = np.asarray(sat_ecef_m, dtype=float) - rcv
    enu = d @ ecef_to_enu_rotation(lat, lon).T
    horiz = np.hypot(enu[..., 0], enu[..., 1])
    el = np.arctan2(enu[..., 2], horiz)
    az = np.arctan2(enu[..., 0], enu[..., 1]) % (2 * np.pi)
    return az, el


def azimuth_elevation_batch(rcv_ecef_m: np.ndarray, los: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Azimuth and elevation (rad) of unit line-of-sight vectors ``los`` (E, S, 3) seen from receivers
    ``rcv_ecef_m`` (E, 3), one receiver per row; also returns the receivers' geodetic [lat, lon, h] (E, 3)."""
    llh = ecef_to_geodetic(rcv_ecef_m)
    lat, lon = llh[:, 0:1], llh[:, 1:2]
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    x, y, z = los[..., 0], los[..., 1], los[..., 2]
    east = -so * x + co * y
    north = -sl * co * x - sl * so * y + cl * z
    up = cl * co * x + cl * so * y + sl * z
    return np.arctan2(east, north) % (2 * np.pi), np.arcsin(np.clip(up, -1.0, 1.0)), llh


def ecef_to_crs(ecef_m, epsg: int) -> np.ndarray:
    """ECEF (WGS84, m) to coordinates of any EPSG CRS (e.g. 32633 UTM 33N -> E, N, ellipsoidal h)."""
    from pyproj import Transformer

    tr = Transformer.from_crs("EPSG:4978", f"EPSG:{int(epsg)}", always_xy=True)
    p = np.atleast_2d(np.asarray(ecef_m, dtype=float))
    a, b, c = tr.transform(p[:, 0], p[:, 1], p[:, 2])
    out = np.stack([a, b, c], axis=-1)
    return out if np.ndim(ecef_m) > 1 else out[0]
