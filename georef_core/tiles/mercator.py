"""The Web Mercator (EPSG:3857) XYZ tile grid ("GoogleMapsCompatible": 256 px tiles, tile (0, 0) at the
top left, zoom z has 2^z x 2^z tiles)."""

from __future__ import annotations

import math

ORIGIN_M = 20037508.342789244           # half the Mercator world width, metres
TILE_PX = 256
MAX_ZOOM = 24                           # 2.4 mm pixels at the equator: finer than any drone product
WGS84_A_M = 6378137.0


def tile_size_m(z: int) -> float:
    return 2 * ORIGIN_M / (1 << z)


def tile_bounds_m(z: int, x: int, y: int) -> tuple[float, float, float, float]:
    """(left, bottom, right, top) of tile z/x/y in EPSG:3857 metres."""
    s = tile_size_m(z)
    left = -ORIGIN_M + x * s
    top = ORIGIN_M - y * s
    return left, top - s, left + s, top


def check_tile(z: int, x: int, y: int, max_zoom: int = MAX_ZOOM) -> str | None:
    """None when z/x/y is a tile of the grid, else what is wrong (for a 400)."""
    if not 0 <= z <= max_zoom:
        return f"zoom {z} outside 0-{max_zoom}"
    n = 1 << z
    if not (0 <= x < n and 0 <= y < n):
        return f"tile {x}/{y} outside the {n} x {n} tiles of zoom {z}"
    return None


def ground_pixel_m(z: int, lat_deg: float) -> float:
    """Ground size of a tile pixel at latitude `lat_deg` (Mercator stretches by 1/cos(lat))."""
    return tile_size_m(z) / TILE_PX * math.cos(math.radians(lat_deg))


def zoom_for_pixel(pixel_m: float, lat_deg: float, max_zoom: int = MAX_ZOOM) -> int:
    """The smallest zoom whose tile pixels are at least as fine as `pixel_m` on the ground at `lat_deg`
    (the zoom a raster of that cell size is fully resolved at)."""
    world_px = 2 * ORIGIN_M / TILE_PX * math.cos(math.radians(lat_deg))
    z = math.ceil(math.log2(world_px / max(pixel_m, 1e-6)) - 1e-9)
    return max(0, min(max_zoom, z))


def lonlat_to_tile(lon_deg: float, lat_deg: float, z: int) -> tuple[float, float]:
    """Fractional tile coordinates (x, y) of a point at zoom z."""
    n = 1 << z
    x = (lon_deg + 180.0) / 360.0 * n
    lat = math.radians(lat_deg)
    y = (1.0 - math.asinh(math.tan(lat)) / math.pi) / 2.0 * n
    return x, y
