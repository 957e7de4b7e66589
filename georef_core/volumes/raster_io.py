"""Reading DSM GeoTIFFs for volume work: validation (CRS, metric units, north-up grid), windowed reads
with nodata as NaN, resampling another raster onto a DSM window, and writing float GeoTIFFs.

Every failure on a user file raises :class:`georef_core.errors.InputFileError` naming the file."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputFileError


@dataclass(frozen=True)
class GridWindow:
    """A rectangular block of a raster grid: ``nrows x ncols`` cells from (``row0``, ``col0``), with the
    affine coefficients of its top-left corner. Cell (i, j) covers x in [x0 + j*dx, x0 + (j+1)*dx] and
    y in [y0 + (i+1)*dy, y0 + i*dy] (``dy`` < 0 for north-up rasters)."""

    row0: int
    col0: int
    nrows: int
    ncols: int
    x0: float  # x of the window's left edge (CRS units)
    y0: float  # y of the window's top edge
    dx: float  # cell width (> 0)
    dy: float  # cell height (< 0 for north-up)

    @property
    def cell_area_m2(self) -> float:
        return abs(self.dx * self.dy)

    @property
    def transform(self):
        from affine import Affine

        return Affine(self.dx, 0.0, self.x0, 0.0, self.dy, self.y0)

    def to_pixel(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """CRS coordinates -> continuous (column, row) of this window (cell (0, 0) spans [0, 1] x [0, 1])."""
        return (np.asarray(x, dtype=float) - self.x0) / self.dx, (np.asarray(y, dtype=float) - self.y0) / self.dy

    def cell_centres(self, rows, cols) -> tuple[np.ndarray, np.ndarray]:
        return self.x0 + (np.asarray(cols) + 0.5) * self.dx, self.y0 + (np.asarray(rows) + 0.5) * self.dy

    def sub(self, row_start: int, nrows: int, col_start: int = 0, ncols: int | None = None) -> "GridWindow":
        """Rows [row_start, row_start + nrows) (and columns from ``col_start``) of this window."""
        nc = self.ncols - col_start if ncols is None else ncols
        return GridWindow(self.row0 + row_start, self.col0 + col_start, nrows, nc, self.x0 + col_start * self.dx,
                          self.y0 + row_start * self.dy, self.dx, self.dy)


@dataclass
class RasterInfo:
    """What volume code needs to know about a single-band elevation raster."""

    path: Path
    crs: object  # pyproj.CRS
    width: int
    height: int
    x0: float
    y0: float
    dx: float
    dy: float
    nodata: float | None
    has_mask: bool  # an internal/external GDAL mask band flags invalid cells
    block_rows: int = 256  # rows of the file's blocks (tiles or strips)

    @property
    def cell_size_m(self) -> float:
        return math.sqrt(abs(self.dx * self.dy))

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        xs = (self.x0, self.x0 + self.width * self.dx)
        ys = (self.y0, self.y0 + self.height * self.dy)
        return min(xs), min(ys), max(xs), max(ys)

    @property
    def full_window(self) -> GridWindow:
        return GridWindow(0, 0, self.height, self.width, self.x0, self.y0, self.dx, self.dy)

    def crs_label(self) -> str:
        epsg = self.crs.to_epsg()
        return f"EPSG:{epsg}" if epsg else self.crs.name

    def window_for_bounds(self, xmin: float, ymin: float, xmax: float, ymax: float, margin_cells: int = 2) -> GridWindow | None:
        """Smallest window covering the box plus ``margin_cells`` cells, clipped to the raster; None if the
        box does not overlap the raster."""
        c0 = math.floor((xmin - self.x0) / self.dx) - margin_cells
        c1 = math.ceil((xmax - self.x0) / self.dx) + margin_cells
        ra, rb = (ymax - self.y0) / self.dy, (ymin - self.y0) / self.dy
        r0 = math.floor(min(ra, rb)) - margin_cells
        r1 = math.ceil(max(ra, rb)) + margin_cells
        c0, r0 = max(c0, 0), max(r0, 0)
        c1, r1 = min(c1, self.width), min(r1, self.height)
        if c1 <= c0 or r1 <= r0:
            return None
        return GridWindow(r0, c0, r1 - r0, c1 - c0, self.x0 + c0 * self.dx, self.y0 + r0 * self.dy, self.dx, self.dy)


def _open(path):
    import rasterio
    from rasterio.errors import RasterioIOError

    p = Path(path)
    if not p.exists():
        raise InputFileError(p, "file not found")
    try:
        return rasterio.open(p)
    except RasterioIOError as exc:
        raise InputFileError(p, f"cannot be read as a raster ({exc})") from None


def open_elevation_raster(path, what: str = "DSM") -> RasterInfo:
    """Open and validate an elevation raster: one band used (the first), a projected CRS in metres, no
    rotation. Raises InputFileError naming the file otherwise."""
    from pyproj import CRS
    from rasterio.enums import MaskFlags

    p = Path(path)
    with _open(p) as ds:
        if ds.count < 1:
            raise InputFileError(p, f"the {what} has no band")
        if ds.crs is None:
            raise InputFileError(p, f"the {what} has no coordinate reference system (CRS); volumes need a "
                                    "projected CRS in metres (write one with gdal_edit.py -a_srs EPSG:XXXX)")
        try:
            crs = CRS.from_user_input(ds.crs.to_wkt())
        except Exception as exc:  # pyproj cannot parse what GDAL wrote
            raise InputFileError(p, f"the {what}'s CRS is not understood ({exc})") from None
        if not crs.is_projected:
            raise InputFileError(p, f"the {what} is in a geographic CRS ({crs.name}): cell areas are not in square "
                                    "metres; reproject it to a projected CRS (e.g. its UTM zone)")
        units = {a.unit_name for a in crs.axis_info[:2]}
        if not units <= {"metre", "meter", "m"}:
            raise InputFileError(p, f"the {what}'s CRS ({crs.name}) has axis units {sorted(units)}, not metres")
        t = ds.transform
        if abs(t.b) > 1e-12 * abs(t.a) or abs(t.d) > 1e-12 * abs(t.e):
            raise InputFileError(p, f"the {what} grid is rotated (geotransform {tuple(t)[:6]}); warp it north-up first")
        if t.a <= 0 or t.e == 0:
            raise InputFileError(p, f"the {what} geotransform is degenerate ({tuple(t)[:6]})")
        if ds.dtypes[0] not in ("float32", "float64", "int16", "int32", "uint16", "uint32", "int8", "uint8"):
            raise InputFileError(p, f"the {what} band type {ds.dtypes[0]} is not an elevation type")
        flags = ds.mask_flag_enums[0]
        has_mask = MaskFlags.per_dataset in flags and MaskFlags.nodata not in flags and MaskFlags.all_valid not in flags
        nodata = ds.nodata
        return RasterInfo(p, crs, ds.width, ds.height, t.c, t.f, t.a, t.e,
                          None if nodata is None else float(nodata), has_mask, int(ds.block_shapes[0][0]))


GDAL_CACHE_MB = 64  # GDAL block cache while reading: small, so block memory is recycled, not faulted in anew


class WindowReader:
    """Reads windows of one raster (kept open) as float32 with NaN for invalid cells; use as a context
    manager. GDAL's block cache is capped while it is open (big reads through a big cache cost more in
    fresh-page faults than the disk read itself)."""

    def __init__(self, info: RasterInfo):
        self.info = info
        self._env = None
        self._ds = None

    def __enter__(self):
        import rasterio

        self._env = rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_MB)
        self._env.__enter__()
        self._ds = _open(self.info.path)
        return self

    def __exit__(self, *exc):
        try:
            if self._ds is not None:
                self._ds.close()
        finally:
            self._env.__exit__(*exc)
        return False

    def read(self, window: GridWindow, out: np.ndarray | None = None) -> np.ndarray:
        from rasterio.windows import Window

        w = Window(window.col0, window.row0, window.ncols, window.nrows)
        if out is None:
            out = np.empty((window.nrows, window.ncols), np.float32)
        info = self.info
        try:
            self._ds.read(1, window=w, out=out)
            mask = self._ds.read_masks(1, window=w) if info.has_mask else None
        except Exception as exc:
            raise InputFileError(info.path, f"cannot read the raster data ({exc})") from None
        if info.nodata is not None and not math.isnan(info.nodata):
            out[out == np.float32(info.nodata)] = np.nan
        if mask is not None:
            out[mask == 0] = np.nan
        np.copyto(out, np.float32(np.nan), where=np.isinf(out))
        return out


def read_window(info: RasterInfo, window: GridWindow) -> np.ndarray:
    """The window's heights as float32, invalid cells (nodata, masked, non-finite) as NaN."""
    with WindowReader(info) as r:
        return r.read(window)


class WindowResampler:
    """Resamples one raster onto many windows of a destination grid (row blocks of a change map) with
    bilinear interpolation, reading only the source rows each window needs."""

    def __init__(self, path, dst_crs, what: str = "DSM"):
        from pyproj import Transformer

        self.info = open_elevation_raster(path, what)
        self.dst_crs = dst_crs
        self.same_crs = self.info.crs == dst_crs
        self._to_src = None if self.same_crs else Transformer.from_crs(dst_crs, self.info.crs, always_xy=True)

    def __call__(self, window: GridWindow) -> np.ndarray:
        from rasterio.crs import CRS as RioCRS
        from rasterio.enums import Resampling
        from rasterio.warp import reproject

        # the source area this window needs (its corners and edge midpoints, in the source CRS), plus a margin
        xs = window.x0 + np.array([0, 0.5, 1, 0, 1, 0, 0.5, 1]) * window.ncols * window.dx
        ys = window.y0 + np.array([0, 0, 0, 0.5, 0.5, 1, 1, 1]) * window.nrows * window.dy
        if self._to_src is not None:
            xs, ys = self._to_src.transform(xs, ys)
        src_win = self.info.window_for_bounds(xs.min(), ys.min(), xs.max(), ys.max(), margin_cells=3)
        out = np.full((window.nrows, window.ncols), np.nan, dtype=np.float32)
        if src_win is None:
            return out
        src = read_window(self.info, src_win)
        try:
            reproject(
                source=src, destination=out, src_transform=src_win.transform,
                src_crs=RioCRS.from_wkt(self.info.crs.to_wkt()), src_nodata=np.nan,
                dst_transform=window.transform, dst_crs=RioCRS.from_wkt(self.dst_crs.to_wkt()), dst_nodata=np.nan,
                resampling=Resampling.bilinear)
        except Exception as exc:
            raise InputFileError(self.info.path, f"cannot be resampled onto the grid of the other DSM ({exc})") from None
        return out


def open_float_geotiff_writer(path, window: GridWindow, crs, description: str, tags: dict | None = None):
    """A tiled, deflate-compressed float32 GeoTIFF for ``window``'s grid, NaN as nodata (caller closes)."""
    import rasterio
    from rasterio.crs import CRS as RioCRS

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    tiled = window.ncols >= 256 and window.nrows >= 256
    profile = {"driver": "GTiff", "width": window.ncols, "height": window.nrows, "count": 1, "dtype": "float32",
               "crs": RioCRS.from_wkt(crs.to_wkt()), "transform": window.transform, "nodata": float("nan"),
               "compress": "deflate", "predictor": 3}
    if tiled:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    ds = rasterio.open(path, "w", **profile)
    ds.set_band_description(1, description)
    if tags:
        ds.update_tags(**{k: str(v) for k, v in tags.items()})
    return ds
