"""An elevation GeoTIFF (DSM or DTM) read whole for the deliverables: heights as float64 with NaN for
no-data, the cell centres, the horizontal CRS and the CRS that states the heights too.

Heights: the dense step writes ellipsoidal heights (WGS 84 ellipsoid) under a 2-D projected CRS. A raster
whose CRS is compound (projected + a vertical datum, e.g. EPSG:32632+3855 EGM2008) has its heights in that
vertical datum. ``Surface.crs_3d`` is what every vector file gets: the compound CRS as it is, else the
projected CRS made 3-D with ellipsoidal height (a WKT2 PROJCRS with a third, ellipsoidal-height axis; a
Shapefile's .prj carries it as a VERTCS on the WGS 84 ellipsoid)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputFileError
from ..volumes.raster_io import RasterInfo, open_elevation_raster, read_window

# a surface read whole is held in memory as float64: beyond this many cells the caller decimates (read_surface
# reads with GDAL's averaging overview/decimation instead of the full grid)
MAX_CELLS = 16_000_000


@dataclass
class Surface:
    path: Path
    z_m: np.ndarray            # (rows, cols) heights, NaN = no-data
    x0: float                  # left edge
    y0: float                  # top edge
    dx: float                  # cell width (> 0)
    dy: float                  # cell height (< 0: north-up)
    crs: object                # pyproj CRS, horizontal (2-D projected)
    crs_3d: object             # pyproj CRS stating the heights too (compound, or projected 3-D ellipsoidal)
    vertical_datum: str        # e.g. "ellipsoidal height (WGS 84)" or "EGM2008 height"
    native_cell_m: float       # the file's cell size (before any decimation)

    @property
    def cell_m(self) -> float:
        return math.sqrt(abs(self.dx * self.dy))

    @property
    def x_m(self) -> np.ndarray:
        """x of the column centres."""
        return self.x0 + (np.arange(self.z_m.shape[1]) + 0.5) * self.dx

    @property
    def y_m(self) -> np.ndarray:
        """y of the row centres."""
        return self.y0 + (np.arange(self.z_m.shape[0]) + 0.5) * self.dy

    def epsg(self) -> int | None:
        return self.crs.to_epsg()

    def crs_label(self) -> str:
        e = self.epsg()
        return f"EPSG:{e}" if e else self.crs.name

    def height_at(self, x, y) -> np.ndarray:
        """Bilinear height at CRS points (NaN outside or next to no-data)."""
        c = (np.asarray(x, float) - self.x0) / self.dx - 0.5
        r = (np.asarray(y, float) - self.y0) / self.dy - 0.5
        return bilinear(self.z_m, r, c)


def bilinear(z: np.ndarray, r: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of grid ``z`` at fractional (row, col) indices of cell centres."""
    r0 = np.floor(r).astype(int)
    c0 = np.floor(c).astype(int)
    ok = (r0 >= 0) & (c0 >= 0) & (r0 < z.shape[0] - 1) & (c0 < z.shape[1] - 1)
    out = np.full(np.shape(r), np.nan)
    r0, c0, fr, fc = r0[ok], c0[ok], (r - np.floor(r))[ok], (c - np.floor(c))[ok]
    out[ok] = (z[r0, c0] * (1 - fr) * (1 - fc) + z[r0, c0 + 1] * (1 - fr) * fc
               + z[r0 + 1, c0] * fr * (1 - fc) + z[r0 + 1, c0 + 1] * fr * fc)
    return out


def vertical_of(crs) -> tuple[object, object, str]:
    """(horizontal CRS, CRS stating the heights, vertical datum label) of a raster's pyproj CRS."""
    if crs.is_compound:
        horiz, vert = crs.sub_crs_list[0], crs.sub_crs_list[1]
        return horiz, crs, vert.name
    ell = crs.geodetic_crs.ellipsoid.name if crs.geodetic_crs is not None else "WGS 84"
    return crs, crs.to_3d(), f"ellipsoidal height ({ell})"


def _block_mean(z: np.ndarray, k: int) -> np.ndarray:
    """Mean of k x k blocks ignoring NaN; a block with less than half its cells valid is NaN."""
    rows, cols = (z.shape[0] // k) * k, (z.shape[1] // k) * k
    b = z[:rows, :cols].reshape(rows // k, k, cols // k, k)
    valid = np.isfinite(b)
    n = valid.sum(axis=(1, 3))
    s = np.where(valid, b, 0.0).sum(axis=(1, 3))
    out = np.full(n.shape, np.nan)
    ok = n >= (k * k) / 2.0
    out[ok] = s[ok] / n[ok]
    return out


def read_surface(path, what: str = "surface", max_cells: int = MAX_CELLS) -> Surface:
    """Reads an elevation GeoTIFF (projected CRS in metres, north-up). A grid of more than ``max_cells``
    cells is reduced by k x k block means (k the smallest that fits). Raises InputFileError naming the file
    when it is missing, not a raster, geographic, rotated, or holds no valid height."""
    info: RasterInfo = open_elevation_raster(path, what)
    if info.dy >= 0:
        raise InputFileError(info.path, f"the {what} grid is not north-up (positive row step {info.dy:g})")
    z = read_window(info, info.full_window).astype(np.float64)
    if not np.isfinite(z).any():
        raise InputFileError(info.path, f"the {what} holds no valid height: every cell is no-data")
    k = 1
    while (z.shape[0] // k) * (z.shape[1] // k) > max_cells:
        k += 1
    if k > 1:
        z = _block_mean(z, k)
    horiz, crs3, label = vertical_of(info.crs)
    return Surface(info.path, z, info.x0, info.y0, info.dx * k, info.dy * k, horiz, crs3, label, info.cell_size_m)
