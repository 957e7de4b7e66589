"""One Web Mercator tile (PNG, RGBA, 256 x 256) of a georeferenced raster, read from the overview level
nearest the tile's pixel: the work per tile is bounded (181 to 362 source cells across per band with
power-of-two overviews, a few more where the raster's grid is rotated against Mercator), whatever the zoom.

Styles (the `tile` of a step's declared output, georef_core.steps.contract.Output):

* ``rgb``: an orthophoto, bands 1-3 as red, green, blue; transparent where the raster's mask (alpha band,
  internal mask or nodata) says no data.
* ``heights``: a surface model (m): a colour ramp between the 2nd and 98th percentiles of the raster's
  heights, shaded by a hillshade (sun from the north-west, 45 degrees up) computed on the tile's ground
  spacing; :func:`legend` gives the colours against heights.
* ``difference``: a signed difference (m, e.g. surveyed minus design): a diverging ramp symmetric about
  zero (blue below, white at zero, red above) to +-the larger of |2nd| and |98th| percentile (at least
  5 cm).

The ramp limits come from the raster itself (:func:`raster_info`, read on its coarsest overview), so
every tile of a raster uses the same colours.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import InputFileError
from .mercator import MAX_ZOOM, TILE_PX, tile_bounds_m, zoom_for_pixel

STYLES = ("rgb", "heights", "difference")
STYLE_VERSION = 1          # in the tile cache's key and the ETag: bump when a style's look changes
MERCATOR = "EPSG:3857"

# colour ramps: (position 0..1, (r, g, b))
HEIGHT_RAMP = ((0.0, (43, 131, 186)), (0.25, (128, 191, 172)), (0.5, (199, 233, 173)), (0.75, (253, 174, 97)),
               (1.0, (215, 25, 28)))
DIFF_RAMP = ((0.0, (33, 102, 172)), (0.25, (103, 169, 207)), (0.5, (247, 247, 247)), (0.75, (239, 138, 98)),
             (1.0, (178, 24, 43)))


@dataclass
class RasterInfo:
    """What the tiles of a raster need once: its grid, overviews, extent and, for ramped styles, limits."""

    style: str
    crs: str
    width: int
    height: int
    cell_m: float
    count: int
    overviews: list[int]
    bounds: tuple[float, float, float, float]            # raster CRS
    lonlat_bounds: tuple[float, float, float, float]     # WGS 84 (west, south, east, north)
    mercator_bounds: tuple[float, float, float, float]   # EPSG:3857
    max_zoom: int
    low: float | None = None
    high: float | None = None
    units: str = ""

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class Tile:
    png: bytes | None                     # None: the tile does not touch the raster
    read_shape: tuple[int, int] = (0, 0)  # source cells read (rows, columns), per band
    overview_factor: int = 1              # 1: full resolution
    extra: dict = field(default_factory=dict)


def _open(path):
    import rasterio

    try:
        return rasterio.open(path)
    except rasterio.errors.RasterioIOError as exc:
        raise InputFileError(path, f"not a readable raster ({exc})") from None


def raster_info(path, style: str) -> RasterInfo:
    """The raster's grid and extent, and the ramp limits of `style` from its coarsest overview."""
    from rasterio.warp import transform_bounds

    if style not in STYLES:
        raise ValueError(f"style {style!r}: one of {', '.join(STYLES)}")
    with _open(path) as ds:
        if ds.crs is None:
            raise InputFileError(path, "the raster has no coordinate reference system")
        crs = ds.crs.to_string()
        ovr = list(ds.overviews(1))
        lonlat = transform_bounds(ds.crs, "EPSG:4326", *ds.bounds, densify_pts=21)
        merc = transform_bounds(ds.crs, MERCATOR, *ds.bounds, densify_pts=21)
        cell = abs(ds.res[0])
        if ds.crs.is_geographic:
            cell *= 111320.0 * math.cos(math.radians((lonlat[1] + lonlat[3]) / 2))
        elif ds.crs.linear_units_factor is not None:
            cell *= ds.crs.linear_units_factor[1]
        lat = (lonlat[1] + lonlat[3]) / 2
        info = RasterInfo(style, crs, ds.width, ds.height, cell, ds.count, ovr, tuple(ds.bounds), tuple(lonlat),
                          tuple(merc), zoom_for_pixel(cell, lat, MAX_ZOOM))
        if style in ("heights", "difference"):
            level = len(ovr) - 1
            data = _read_coarsest(path, level)
            vals = data[np.isfinite(data)]
            info.units = "m"
            if vals.size:
                p2, p98 = (float(v) for v in np.percentile(vals, [2, 98]))
                if style == "heights":
                    info.low, info.high = p2, max(p98, p2 + 0.01)
                else:
                    lim = max(abs(p2), abs(p98), 0.05)
                    info.low, info.high = -lim, lim
    return info


def _read_coarsest(path, level: int) -> np.ndarray:
    """Band 1 of the overview `level` (-1: full resolution) as float with NaN for no data, at most about
    1024 x 1024 cells (decimated on read when the raster has too few overviews)."""
    import rasterio

    kw = {"overview_level": level} if level >= 0 else {}
    with rasterio.open(path, **kw) as ds:
        f = max(1.0, max(ds.width, ds.height) / 1024)
        shape = (max(1, int(ds.height / f)), max(1, int(ds.width / f)))
        a = ds.read(1, out_shape=shape, masked=True).astype("float64")
    return a.filled(np.nan)


def legend(info: RasterInfo, n: int = 6) -> dict:
    """The colours of a ramped style against values: stops from low to high."""
    if info.style == "rgb" or info.low is None:
        return {"style": info.style, "units": info.units, "stops": []}
    ramp = HEIGHT_RAMP if info.style == "heights" else DIFF_RAMP
    stops = []
    for i in range(n):
        t = i / (n - 1)
        rgb = _ramp(np.array([t]), ramp)[0]
        stops.append({"value": round(info.low + t * (info.high - info.low), 3),
                      "color": "#%02x%02x%02x" % tuple(int(c) for c in rgb)})
    what = {"heights": "surface height (the raster's vertical datum), 2nd to 98th percentile, hillshaded",
            "difference": "signed difference, blue below zero, red above"}[info.style]
    return {"style": info.style, "units": info.units, "low": info.low, "high": info.high, "description": what,
            "stops": stops}


def _ramp(t: np.ndarray, ramp) -> np.ndarray:
    pos = np.array([p for p, _ in ramp])
    cols = np.array([c for _, c in ramp], dtype="float64")
    out = np.empty(t.shape + (3,), dtype="float64")
    tc = np.clip(t, 0.0, 1.0)
    for k in range(3):
        out[..., k] = np.interp(tc, pos, cols[:, k])
    return out


@lru_cache(maxsize=1)
def empty_png() -> bytes:
    return _png(np.zeros((TILE_PX, TILE_PX, 4), dtype="uint8"))


def _png(rgba: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(buf, "PNG", compress_level=6)
    return buf.getvalue()


def _pick_level(overviews, decimation: float) -> int:
    """Index of the overview to read (-1: full resolution) among the overview factors ``overviews`` (a
    dataset's ``overviews(1)``): the one nearest (in log scale) to the decimation the tile needs, so that a
    tile reads 181-362 cells across (power-of-two overviews), never more than 1.41 source cells per tile
    pixel from an overview."""
    level = -1
    for i, f in enumerate(overviews):
        if f <= decimation * math.sqrt(2.0):
            level = i
    return level


def _read_plan(ds, source_bounds, n: int, overviews) -> tuple | None:
    """For a tile of n pixels whose extent in the raster's CRS is ``source_bounds``: (the part of it inside the
    raster ``ds``, the decimation the tile needs, the overview level to read (_pick_level), its factor), or None
    when the tile misses the raster."""
    rb = ds.bounds
    sb = source_bounds
    ib = (max(sb[0], rb.left), max(sb[1], rb.bottom), min(sb[2], rb.right), min(sb[3], rb.top))
    if ib[0] >= ib[2] or ib[1] >= ib[3]:
        return None
    # cells the whole tile spans at full resolution, against the tile's pixels
    span = max((sb[2] - sb[0]) / abs(ds.res[0]), (sb[3] - sb[1]) / abs(ds.res[1]))
    decimation = max(1.0, span / n)
    level = _pick_level(overviews, decimation)
    return ib, decimation, level, (overviews[level] if level >= 0 else 1)


def _source_window(ds, bounds, decimation: float, factor: float):
    """(window, (out_h, out_w), transform of the read array) of the cells of ``ds`` (an overview level of
    ``factor``) under ``bounds`` plus a one-cell margin; a raster with too few overviews (not a COG) is
    decimated on read, so the output stays bounded."""
    from affine import Affine
    from rasterio.windows import Window, from_bounds as window_from_bounds

    win = window_from_bounds(*bounds, transform=ds.transform).round_offsets(op="floor").round_lengths(op="ceil")
    col0, row0 = max(0, int(win.col_off) - 1), max(0, int(win.row_off) - 1)
    col1 = min(ds.width, int(win.col_off + win.width) + 1)
    row1 = min(ds.height, int(win.row_off + win.height) + 1)
    win = Window(col0, row0, col1 - col0, row1 - row0)
    rest = decimation / factor
    out_h, out_w = int(win.height), int(win.width)
    if rest > 1.5:
        out_h, out_w = max(1, math.ceil(win.height / rest)), max(1, math.ceil(win.width / rest))
    return win, (out_h, out_w), ds.window_transform(win) @ Affine.scale(win.width / out_w, win.height / out_h)


def render_tile(path, info: RasterInfo, z: int, x: int, y: int) -> Tile:
    """Tile z/x/y of the raster at `path` in the style of `info` (from :func:`raster_info`)."""
    rgba, shape, factor = render_tile_rgba(path, info, z, x, y)
    if rgba is None:
        return Tile(None)
    return Tile(_png(rgba), shape, factor)


def render_tile_rgba(path, info: RasterInfo, z: int, x: int, y: int) -> tuple[np.ndarray | None, tuple, int]:
    """:func:`render_tile` before PNG encoding: (RGBA uint8 array TILE_PX x TILE_PX x 4, or None when the tile
    does not touch the raster; source cells read per band; overview factor). For writers that encode the
    tile themselves (the KMZ super-overlay: JPEG where it has no transparent pixel)."""
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.transform import from_bounds
    from rasterio.warp import reproject, transform_bounds

    left, bottom, right, top = tile_bounds_m(z, x, y)
    mb = info.mercator_bounds
    if right <= mb[0] or left >= mb[2] or top <= mb[1] or bottom >= mb[3]:
        return None, (0, 0), 1
    pad = 1 if info.style in ("heights", "difference") else 0   # one pixel around the tile for the hillshade
    n = TILE_PX + 2 * pad
    px = (right - left) / TILE_PX
    dst_transform = from_bounds(left - pad * px, bottom - pad * px, right + pad * px, top + pad * px, n, n)
    with _open(path) as ds0:
        sb = transform_bounds(MERCATOR, ds0.crs, left - pad * px, bottom - pad * px, right + pad * px,
                              top + pad * px, densify_pts=21)
        plan = _read_plan(ds0, sb, n, ds0.overviews(1))
        if plan is None:
            return None, (0, 0), 1
        ib, decimation, level, factor = plan
    kw = {"overview_level": level} if level >= 0 else {}
    with rasterio.open(path, **kw) as ds:
        win, shape, src_transform = _source_window(ds, ib, decimation, factor)
        out_h, out_w = shape
        if info.style == "rgb":
            bands = [1, 2, 3] if ds.count >= 3 else [1, 1, 1]
            rgb = ds.read(bands, window=win, out_shape=(3,) + shape, resampling=Resampling.average)
            mask = ds.read_masks(1, window=win, out_shape=shape, resampling=Resampling.nearest)
            valid = (mask > 0).astype("float32")[None]
            # premultiplied by the mask: no-data cells lend no colour to their neighbours when resampled
            src = np.concatenate([rgb.astype("float32") * valid, valid * 255.0])
            dst = np.zeros((4, n, n), dtype="float32")
            reproject(src, dst, src_transform=src_transform, src_crs=ds.crs, dst_transform=dst_transform,
                      dst_crs=MERCATOR, resampling=Resampling.bilinear, src_nodata=None, dst_nodata=0.0)
            alpha = dst[3]
            ok = alpha >= 127.5
            colour = np.where(alpha > 0, dst[:3] * 255.0 / np.maximum(alpha, 1e-6), 0.0)
            rgba = np.zeros((n, n, 4), dtype="uint8")
            rgba[..., :3] = np.clip(np.rint(np.moveaxis(colour, 0, -1)), 0, 255)
            rgba[..., 3] = np.where(ok, 255, 0)
        else:
            a = ds.read(1, window=win, out_shape=shape, masked=True, resampling=Resampling.average)
            src = a.astype("float32").filled(np.nan)
            dst = np.full((n, n), np.nan, dtype="float32")
            reproject(src, dst, src_transform=src_transform, src_crs=ds.crs, dst_transform=dst_transform,
                      dst_crs=MERCATOR, resampling=Resampling.bilinear, src_nodata=np.nan, dst_nodata=np.nan)
            rgba = _style_values(dst, info, px, (top + bottom) / 2)
        rgba = rgba[pad:pad + TILE_PX, pad:pad + TILE_PX]
    return np.ascontiguousarray(rgba), shape, factor


def _style_values(h: np.ndarray, info: RasterInfo, px_merc_m: float, y_merc_m: float) -> np.ndarray:
    ok = np.isfinite(h)
    lo = info.low if info.low is not None else 0.0
    hi = info.high if info.high is not None else 1.0
    t = (np.where(ok, h, lo) - lo) / max(hi - lo, 1e-9)
    rgb = _ramp(t, HEIGHT_RAMP if info.style == "heights" else DIFF_RAMP)
    if info.style == "heights":
        lat = math.degrees(2 * math.atan(math.exp(y_merc_m / 6378137.0)) - math.pi / 2)
        g = px_merc_m * math.cos(math.radians(lat))          # ground size of a tile pixel, m
        rgb *= _hillshade(np.where(ok, h, np.nanmean(h) if ok.any() else 0.0), g)[..., None]
    out = np.zeros(h.shape + (4,), dtype="uint8")
    out[..., :3] = np.clip(np.rint(rgb), 0, 255)
    out[..., 3] = np.where(ok, 255, 0)
    return out


def _hillshade(h: np.ndarray, spacing_m: float, azimuth_deg: float = 315.0, altitude_deg: float = 45.0) -> np.ndarray:
    """Lambertian shade in 0.35..1 (rows run south, columns east)."""
    dzdy, dzdx = np.gradient(h, spacing_m)
    slope = np.arctan(np.hypot(dzdx, dzdy))
    aspect = np.arctan2(-dzdx, dzdy)      # downslope direction, radians clockwise from north
    az, alt = math.radians(azimuth_deg), math.radians(altitude_deg)
    shade = math.sin(alt) * np.cos(slope) + math.cos(alt) * np.sin(slope) * np.cos(az - aspect)
    return 0.35 + 0.65 * np.clip(shade, 0.0, 1.0)


def tile_png(path: Path, style: str, z: int, x: int, y: int) -> bytes:
    """A tile's PNG (the transparent tile outside the raster): for scripts; the API caches `raster_info`."""
    t = render_tile(path, raster_info(path, style), z, x, y)
    return t.png if t.png is not None else empty_png()


# --------------------------------------------------------------------------------- many tiles of one orthophoto

AFFINE_MAX_RESIDUAL_PX = 0.01   # the tile's Mercator -> raster mapping taken as affine when it errs less (source px)
FOUR_SAMPLE_MIN_SCALE = 1.0     # GDAL's warper uses its 4-sample bilinear from 0.95 (tile px per source px); margin


class RgbTileDrawer:
    """:func:`render_tile_rgba` of the ``rgb`` style for many tiles of one raster (the KMZ super-overlay), faster:
    the raster and its overviews are opened once and kept open, the Mercator -> raster transformation (pyproj) is
    made once, and each tile's warp is done here instead of by GDAL: the tile's pixel centres mapped to the source
    window by an affine fitted on a 5 x 5 grid of exactly transformed points (its residual checked: under
    AFFINE_MAX_RESIDUAL_PX), then GDAL's own 4-sample bilinear formula (weights from the centre offsets, taps outside
    the window dropped and the weights renormalised, pixel centres outside the window left empty) on the same
    premultiplied bands. A tile where GDAL would not use that formula (fewer than FOUR_SAMPLE_MIN_SCALE tile pixels
    per source pixel: GDAL's warper widens its kernel then) or where the affine errs more is drawn by
    render_tile_rgba itself. The result is render_tile_rgba's within rounding (bench/kmz_super_overlay.py measures
    the largest difference)."""

    def __init__(self, path, info: RasterInfo):
        from pyproj import Transformer

        if info.style != "rgb":
            raise ValueError(f"RgbTileDrawer draws the rgb style, not {info.style!r}")
        self.path, self.info = Path(path), info
        self._base = _open(path)
        self._datasets: dict[int, object] = {}
        self._overviews = list(self._base.overviews(1))
        self._to_src = Transformer.from_crs(MERCATOR, self._base.crs.to_wkt(), always_xy=True)
        self.drawn_here = 0       # tiles drawn by the fast path; the others by render_tile_rgba
        self.drawn_by_gdal = 0

    def close(self) -> None:
        for ds in self._datasets.values():
            ds.close()
        self._datasets.clear()
        self._base.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _dataset(self, level: int):
        import rasterio

        if level < 0:
            return self._base
        if level not in self._datasets:
            self._datasets[level] = rasterio.open(self.path, overview_level=level)
        return self._datasets[level]

    def rgba(self, z: int, x: int, y: int) -> np.ndarray | None:
        """The tile as render_tile_rgba's first value (TILE_PX x TILE_PX x 4 uint8, or None off the raster)."""
        from rasterio.enums import Resampling

        left, bottom, right, top = tile_bounds_m(z, x, y)
        mb = self.info.mercator_bounds
        if right <= mb[0] or left >= mb[2] or top <= mb[1] or bottom >= mb[3]:
            return None
        n = TILE_PX
        ds0 = self._base
        sb = self._to_src.transform_bounds(left, bottom, right, top, densify_pts=21)   # transform_bounds's
        plan = _read_plan(ds0, sb, n, self._overviews)
        if plan is None:
            return None
        ib, decimation, level, factor = plan
        ds = self._dataset(level)
        win, (out_h, out_w), src_transform = _source_window(ds, ib, decimation, factor)
        # tile pixel (column, row) -> source pixel (column, row) of the window read: an affine fitted on 5 x 5 points
        g = np.linspace(0.0, n, 5)
        cols, rows = (a.ravel() for a in np.meshgrid(g, g))
        px = (right - left) / n
        e, nn = self._to_src.transform(left + cols * px, top - rows * px)
        inv = ~src_transform
        sc = inv.a * np.asarray(e) + inv.b * np.asarray(nn) + inv.c
        sr = inv.d * np.asarray(e) + inv.e * np.asarray(nn) + inv.f
        m = np.column_stack([cols, rows, np.ones_like(cols)])
        fit_c, *_ = np.linalg.lstsq(m, sc, rcond=None)
        fit_r, *_ = np.linalg.lstsq(m, sr, rcond=None)
        residual = float(np.max(np.hypot(m @ fit_c - sc, m @ fit_r - sr)))
        # tile pixels per source pixel along each axis of the window (GDAL's dfXScale, dfYScale)
        scale_x = 1.0 / max(math.hypot(fit_c[0], fit_r[0]), 1e-12)
        scale_y = 1.0 / max(math.hypot(fit_c[1], fit_r[1]), 1e-12)
        if residual > AFFINE_MAX_RESIDUAL_PX or min(scale_x, scale_y) < FOUR_SAMPLE_MIN_SCALE:
            self.drawn_by_gdal += 1
            return render_tile_rgba(self.path, self.info, z, x, y)[0]
        self.drawn_here += 1
        shape = (out_h, out_w)
        bands = [1, 2, 3] if ds.count >= 3 else [1, 1, 1]
        rgb = ds.read(bands, window=win, out_shape=(3,) + shape, resampling=Resampling.average)
        mask = ds.read_masks(1, window=win, out_shape=shape, resampling=Resampling.nearest)
        valid = (mask > 0).astype("float32")[None]
        src = np.concatenate([rgb.astype("float32") * valid, valid * 255.0])     # premultiplied, as render_tile_rgba
        from .warp_kernel import bilinear_4_sample, premultiplied_to_rgba

        dst = np.zeros((4, n, n), dtype="float32")
        bilinear_4_sample(np.ascontiguousarray(src), *(float(v) for v in fit_c), *(float(v) for v in fit_r), dst)
        out = np.empty((n, n, 4), dtype="uint8")
        premultiplied_to_rgba(dst, out)
        return out
