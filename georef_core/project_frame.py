"""The project frame of a site: project CRS (E, N, ellipsoidal h) <-> ECEF <-> local ENU.

* **project CRS** (``epsg``, usually a UTM zone): easting ``E``, northing ``N`` (m, grid units) and
  ellipsoidal height ``h`` (m, WGS84). Surveyed points, rasters and volumes are reported here.
  "Site coordinates" are grid offsets ``x = E - E0``, ``y = N - N0`` from the site origin, heights
  stay absolute ellipsoidal heights.
* **ECEF** (WGS84, EPSG:4978): the GNSS frame.
* **local ENU** (``enu``): the Euclidean east/north/up tangent frame at the site origin
  (``E0, N0, h_ref``), where photogrammetry is done. It is an exact, rigid (rotation + translation)
  image of ECEF: ``ecef = origin_ecef + R_enu_to_ecef @ enu``.

A grid point ``(E, N, h)`` is mapped to ECEF rigorously (projection inverse + geodetic to ECEF).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .gnss.frames import ecef_to_enu_rotation, ecef_to_geodetic, geodetic_to_ecef_m


def utm_epsg_for(lat_deg: float, lon_deg: float) -> int:
    """EPSG code of the WGS84 UTM zone containing a point (no Norway/Svalbard exceptions)."""
    zone = int(math.floor((lon_deg + 180.0) / 6.0)) + 1
    zone = min(max(zone, 1), 60)
    return (32600 if lat_deg >= 0 else 32700) + zone


@dataclass
class ProjectFrame:
    """Project CRS <-> ECEF <-> local ENU conversions for one site."""

    epsg: int
    origin_e: float
    origin_n: float
    h_ref: float
    _fwd: object = field(default=None, repr=False, compare=False)
    _inv: object = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        from pyproj import Transformer

        self._fwd = Transformer.from_crs("EPSG:4326", f"EPSG:{int(self.epsg)}", always_xy=True)
        self._inv = Transformer.from_crs(f"EPSG:{int(self.epsg)}", "EPSG:4326", always_xy=True)
        lat, lon = self.grid_to_latlon_rad(self.origin_e, self.origin_n)
        self.origin_lat_rad = float(lat)
        self.origin_lon_rad = float(lon)
        self.origin_ecef = geodetic_to_ecef_m(lat, lon, self.h_ref).reshape(3)
        self.R_ecef_to_enu = ecef_to_enu_rotation(self.origin_lat_rad, self.origin_lon_rad)
        self.R_enu_to_ecef = self.R_ecef_to_enu.T.copy()

    # --- project CRS <-> geodetic -------------------------------------------------------------
    def grid_to_latlon_rad(self, e, n) -> tuple[np.ndarray, np.ndarray]:
        lon, lat = self._inv.transform(np.asarray(e, dtype=float), np.asarray(n, dtype=float))
        return np.radians(lat), np.radians(lon)

    def latlon_rad_to_grid(self, lat_rad, lon_rad) -> tuple[np.ndarray, np.ndarray]:
        e, n = self._fwd.transform(np.degrees(lon_rad), np.degrees(lat_rad))
        return np.asarray(e, dtype=float), np.asarray(n, dtype=float)

    # --- project CRS <-> ECEF -----------------------------------------------------------------
    def grid_to_ecef(self, e, n, h) -> np.ndarray:
        lat, lon = self.grid_to_latlon_rad(e, n)
        return geodetic_to_ecef_m(lat, lon, h)

    def ecef_to_grid(self, ecef) -> np.ndarray:
        """ECEF (..., 3) to (..., 3) of E, N, ellipsoidal h (same result as gnss.frames.ecef_to_crs)."""
        llh = ecef_to_geodetic(np.asarray(ecef, dtype=float))
        e, n = self.latlon_rad_to_grid(llh[..., 0], llh[..., 1])
        return np.stack([e, n, llh[..., 2]], axis=-1)

    # --- ECEF <-> ENU -------------------------------------------------------------------------
    def ecef_to_enu(self, ecef) -> np.ndarray:
        return (np.asarray(ecef, dtype=float) - self.origin_ecef) @ self.R_ecef_to_enu.T

    def enu_to_ecef(self, enu) -> np.ndarray:
        return np.asarray(enu, dtype=float) @ self.R_enu_to_ecef.T + self.origin_ecef

    def enu_vec_to_ecef(self, v) -> np.ndarray:
        """A free vector (velocity, offset) from ENU to ECEF axes."""
        return np.asarray(v, dtype=float) @ self.R_enu_to_ecef.T

    # --- site coordinates (grid offsets) <-> ENU ------------------------------------------------
    def site_to_enu(self, x, y, h) -> np.ndarray:
        return self.ecef_to_enu(self.grid_to_ecef(np.asarray(x) + self.origin_e, np.asarray(y) + self.origin_n, h))

    def enu_to_site(self, enu) -> np.ndarray:
        g = self.ecef_to_grid(self.enu_to_ecef(enu))
        g[..., 0] -= self.origin_e
        g[..., 1] -= self.origin_n
        return g

    def grid_to_enu(self, e, n, h) -> np.ndarray:
        return self.ecef_to_enu(self.grid_to_ecef(e, n, h))

    def enu_to_grid(self, enu) -> np.ndarray:
        return self.ecef_to_grid(self.enu_to_ecef(enu))

    # --- projection properties -----------------------------------------------------------------
    def grid_factors(self, e, n) -> tuple[np.ndarray, np.ndarray]:
        """(meridian convergence in radians, point scale factor) at grid points.

        Convergence gamma is the angle from true north to grid north, positive clockwise (PROJ's
        convention): a grid bearing is a true azimuth minus gamma."""
        from pyproj import Proj

        p = Proj(f"EPSG:{int(self.epsg)}")
        lat, lon = self.grid_to_latlon_rad(e, n)
        f = p.get_factors(np.degrees(lon), np.degrees(lat))
        return np.radians(np.asarray(f.meridian_convergence)), np.asarray(f.meridional_scale)

    def R_enu_to_grid_axes(self, e, n, h) -> np.ndarray:
        """Rotation turning origin-ENU vectors into (grid east, grid north, up) axes at a grid point.

        Built numerically from the directions of grid east and grid north at the point (so it holds
        the meridian convergence and the tilt of the local vertical relative to the origin's); the
        projection's scale factor is not a rotation and is left out."""
        p0 = self.grid_to_enu(e, n, h)
        de = self.grid_to_enu(e + 1.0, n, h) - p0
        dn = self.grid_to_enu(e, n + 1.0, h) - p0
        up = np.cross(de, dn)
        up /= np.linalg.norm(up)
        ge = de - up * (de @ up)
        ge /= np.linalg.norm(ge)
        gn = np.cross(up, ge)
        return np.stack([ge, gn, up])

    def to_dict(self) -> dict:
        return {
            "epsg": int(self.epsg),
            "origin_E_m": self.origin_e,
            "origin_N_m": self.origin_n,
            "h_ref_m": self.h_ref,
            "origin_ecef_m": [float(v) for v in self.origin_ecef],
            "origin_lat_deg": math.degrees(self.origin_lat_rad),
            "origin_lon_deg": math.degrees(self.origin_lon_rad),
            "R_ecef_to_enu": self.R_ecef_to_enu.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "ProjectFrame":
        """Rebuild from :meth:`to_dict` (derived fields are recomputed)."""
        return cls(epsg=int(d["epsg"]), origin_e=float(d["origin_E_m"]), origin_n=float(d["origin_N_m"]),
                   h_ref=float(d["h_ref_m"]))
