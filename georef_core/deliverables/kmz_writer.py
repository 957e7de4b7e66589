"""The orthophoto as a KMZ overlay (Google Earth, Avenza Maps, phones).

* Up to ``tile_threshold_px`` (2048) pixels on its longer side: one image. The orthophoto reduced to at most
  ``max_px`` pixels on its longer side, warped to WGS 84 longitude/latitude (a north-up lat/lon grid, so the
  KML GroundOverlay's LatLonBox places it without rotation), PNG with no-data transparent; doc.kml plus
  files/ortho.png zipped.
* Larger: a super-overlay (KML Regions with levels of detail), which Google Earth loads tile by tile as the
  view comes closer, where one large image would be cut down to the viewer's texture limit. The tiles are
  the web map's (georef_core.tiles: Web Mercator 256 px tiles, each read from the orthophoto's nearest
  overview), over a regionated pyramid of zoom levels: from the finest that resolves the orthophoto (no cap
  on its tile count; ``max_tiles`` may set one, making it coarser) up to the first level where one tile
  covers it (a single root, as GDAL's KML super-overlay reader expects; a site astride a tile edge of every
  level down to z has a few one- or two-tile levels more, cheap to draw). Every tile is
  ``tiles/{z}_{x}_{y}.kml`` (a Region with its Lod, a GroundOverlay of ``tiles/{z}_{x}_{y}.jpg`` or ``.png``
  and a NetworkLink with its Region to each of its 4 children that holds data or leads to some), so a viewer
  loads only the tiles in view at the detail the view needs; doc.kml links the root tile. Memory does not grow
  with the orthophoto: each tile is read by a window of the nearest overview, encoded and written to the zip
  at once (only the tile keys are kept). The tiles are drawn by tiles.render.RgbTileDrawer (the raster open
  once, each tile's warp a kernel over an affine fitted to the exact transformation; render_tile_rgba's result
  within one grey level).
  Tiles without no-data are JPEG (quality 90), tiles with some PNG (no-data transparent), tiles all no-data
  are left out. A Mercator tile placed by a LatLonBox (linear in latitude) is off by at most
  R x dphi^2 x tan(lat) / 8 inside it (dphi its latitude span): under 3 cm for a 1.2 km tile at 45 deg, a
  hundredth of its pixel.

The overlay is for viewing on site, not measuring: the KML states the ground pixel size."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

from ..errors import InputFileError

KML_NS = "http://www.opengis.net/kml/2.2"


def write_kmz(ortho_path, out_path, max_px: int = 4096, name: str = "Orthophoto", tile_threshold_px: int = 2048,
              max_tiles: int | None = None) -> dict:
    """Writes ``out_path`` (.kmz) from the orthophoto GeoTIFF: one overlay image, or a super-overlay when the
    orthophoto is larger than ``tile_threshold_px`` on its longer side (module description). Returns
    {"tiled", "west", "south", "east", "north", "pixel_m"} and "width_px", "height_px" (one image) or
    "levels", "tiles", "tiles_per_level" (super-overlay)."""
    import rasterio
    from PIL import Image
    from rasterio.crs import CRS as RioCRS
    from rasterio.enums import Resampling
    from rasterio.errors import RasterioIOError
    from rasterio.warp import calculate_default_transform, reproject

    src_path = Path(ortho_path)
    if not src_path.exists():
        raise InputFileError(src_path, "file not found")
    try:
        ds = rasterio.open(src_path)
    except RasterioIOError as exc:
        raise InputFileError(src_path, f"cannot be read as a raster ({exc})") from None
    with ds:
        if ds.crs is None:
            raise InputFileError(src_path, "the orthophoto has no CRS")
        if ds.count < 3:
            raise InputFileError(src_path, f"the orthophoto has {ds.count} band(s), RGB (3 or 4) expected")
        tiled = max(ds.width, ds.height) > tile_threshold_px
    if tiled:
        return write_super_overlay(src_path, out_path, name, max_tiles)
    with rasterio.open(src_path) as ds:
        scale = max(1.0, max(ds.width, ds.height) / max_px)
        w, h = max(1, int(round(ds.width / scale))), max(1, int(round(ds.height / scale)))
        rgb = ds.read((1, 2, 3), out_shape=(3, h, w), resampling=Resampling.average)
        alpha = ds.read_masks(1, out_shape=(h, w), resampling=Resampling.nearest)
        if ds.count >= 4 and ds.colorinterp[3].name == "alpha":
            alpha = np.minimum(alpha, ds.read(4, out_shape=(h, w), resampling=Resampling.nearest))
        src_t = ds.transform @ ds.transform.scale(ds.width / w, ds.height / h)
        src_crs = ds.crs
        pixel_m = abs(src_t.a)
    dst_crs = RioCRS.from_epsg(4326)
    bounds = rasterio.transform.array_bounds(h, w, src_t)
    dst_t, dw, dh = calculate_default_transform(src_crs, dst_crs, w, h, *bounds)
    out = np.zeros((4, dh, dw), np.uint8)
    src = np.concatenate([rgb.astype(np.uint8), alpha[None].astype(np.uint8)])
    for b in range(4):
        reproject(src[b], out[b], src_transform=src_t, src_crs=src_crs, dst_transform=dst_t, dst_crs=dst_crs,
                  resampling=Resampling.nearest if b == 3 else Resampling.bilinear, src_nodata=None, dst_nodata=0)
    png = io.BytesIO()
    Image.fromarray(np.moveaxis(out, 0, -1), "RGBA").save(png, "PNG", optimize=True)
    west, north = dst_t.c, dst_t.f
    east, south = west + dw * dst_t.a, north + dh * dst_t.e
    kml = f"""<?xml version="1.0" encoding="UTF-8"?>
<kml xmlns="{KML_NS}">
 <Document>
  <name>{escape(name)}</name>
  <GroundOverlay>
   <name>{escape(name)}</name>
   <description>{escape(f"Georef orthophoto, {pixel_m:.3f} m pixels in this overlay (reduced for viewing); "
                        f"source {src_path.name}")}</description>
   <Icon><href>files/ortho.png</href></Icon>
   <LatLonBox>
    <north>{north:.9f}</north>
    <south>{south:.9f}</south>
    <east>{east:.9f}</east>
    <west>{west:.9f}</west>
    <rotation>0</rotation>
   </LatLonBox>
  </GroundOverlay>
 </Document>
</kml>
"""
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(out_path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("doc.kml", kml)               # first entry: what KMZ readers open
        z.writestr("files/ortho.png", png.getvalue())
    return {"tiled": False, "west": west, "south": south, "east": east, "north": north, "width_px": dw,
            "height_px": dh, "pixel_m": round(pixel_m, 4)}


# ---------------------------------------------------------------------------------------------- super-overlay
TOP_LEVEL_MAX_TILES = 1          # the coarsest level: the first (from the finest) one tile covers (one root)
MIN_LOD_PIXELS = 128             # a tile shows once its Region spans this many screen pixels
JPEG_QUALITY = 90


def tile_lonlat_box(z: int, x: int, y: int) -> tuple[float, float, float, float]:
    """(west, south, east, north) of Web Mercator tile z/x/y in degrees."""
    import math

    from ..tiles.mercator import WGS84_A_M, tile_bounds_m

    left, bottom, right, top = tile_bounds_m(z, x, y)
    lat = lambda ym: math.degrees(math.atan(math.sinh(ym / WGS84_A_M)))  # noqa: E731
    return (math.degrees(left / WGS84_A_M), lat(bottom), math.degrees(right / WGS84_A_M), lat(top))


def tile_range(lonlat_bounds, z: int) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1), inclusive, of the tiles of zoom z that the lon/lat box touches."""
    import math

    from ..tiles.mercator import lonlat_to_tile

    w, s, e, n = lonlat_bounds
    fx0, fy0 = lonlat_to_tile(w, n, z)
    fx1, fy1 = lonlat_to_tile(e, s, z)
    top = (1 << z) - 1
    x0, y0 = max(0, math.floor(fx0)), max(0, math.floor(fy0))
    x1, y1 = min(top, max(x0, math.ceil(fx1) - 1)), min(top, max(y0, math.ceil(fy1) - 1))
    return x0, y0, x1, y1


def _level_keys(lonlat_bounds, z: int) -> list[tuple[int, int, int]]:
    """The tiles (z, x, y) of zoom z that the lon/lat box touches, row by row."""
    x0, y0, x1, y1 = tile_range(lonlat_bounds, z)
    return [(z, x, y) for y in range(y0, y1 + 1) for x in range(x0, x1 + 1)]


def overlay_levels(lonlat_bounds, finest_zoom: int, max_tiles: int | None = None) -> list[int]:
    """The zoom levels of the super-overlay, coarsest first (module description); ``max_tiles`` None: no cap
    on the finest level's tile count."""
    def count(z):
        x0, y0, x1, y1 = tile_range(lonlat_bounds, z)
        return (x1 - x0 + 1) * (y1 - y0 + 1)

    zf = finest_zoom
    while max_tiles is not None and zf > 0 and count(zf) > max(1, max_tiles):
        zf -= 1
    zc = zf
    while zc > 0 and count(zc) > TOP_LEVEL_MAX_TILES:
        zc -= 1
    return list(range(zc, zf + 1))


def _box(tag: str, box) -> str:
    w, s, e, n = box
    return (f"<{tag}><north>{n:.9f}</north><south>{s:.9f}</south><east>{e:.9f}</east><west>{w:.9f}</west>"
            f"</{tag}>")


def _region(box, min_lod: int) -> str:
    return (f"<Region>{_box('LatLonAltBox', box)}<Lod><minLodPixels>{min_lod}</minLodPixels>"
            "<maxLodPixels>-1</maxLodPixels></Lod></Region>")


def _link(key, min_lod: int, prefix: str = "") -> str:
    z, x, y = key
    return (f"<NetworkLink><name>{z}/{x}/{y}</name>{_region(tile_lonlat_box(z, x, y), min_lod)}"
            f"<Link><href>{prefix}{z}_{x}_{y}.kml</href><viewRefreshMode>onRegion</viewRefreshMode></Link>"
            "</NetworkLink>")


def _encode_tile(rgba: np.ndarray) -> tuple[bytes, str] | None:
    """The tile (RGBA array) as JPEG (no transparent pixel) or PNG (some), None when every pixel is no-data."""
    from PIL import Image

    alpha = rgba[..., 3]
    if not alpha.any():
        return None
    buf = io.BytesIO()
    if alpha.min() == 255:
        Image.fromarray(rgba[..., :3], "RGB").save(buf, "JPEG", quality=JPEG_QUALITY)
        return buf.getvalue(), "jpg"
    Image.fromarray(rgba, "RGBA").save(buf, "PNG", compress_level=3)
    return buf.getvalue(), "png"


def write_super_overlay(ortho_path, out_path, name: str = "Orthophoto", max_tiles: int | None = None,
                        fast_tiles: bool = True) -> dict:
    """The orthophoto as a KMZ super-overlay (module description); returns {"tiled": True, "west", "south",
    "east", "north" (the orthophoto's WGS 84 box), "levels", "tiles", "tiles_per_level", "pixel_m" (ground
    pixel of the finest level at the centre)}. ``max_tiles``: None (default) for the zoom that resolves the
    orthophoto whatever its size; a number makes the finest level coarser until it holds at most that many.

    Memory is bounded whatever the orthophoto's size: each tile is read from the orthophoto by a window
    (``tiles.render.render_tile_rgba``), encoded and written into the zip at once; only the tile keys and their
    image type are kept (a few dozen bytes a tile) to write the KML tree at the end.

    ``fast_tiles`` (default): the tiles are drawn by ``tiles.render.RgbTileDrawer`` (the raster kept open, the warp
    done by a kernel from an affine per tile: about 3.5 times faster, within one grey level of render_tile_rgba);
    False: by render_tile_rgba, tile by tile (the reference, bench/kmz_super_overlay.py)."""
    import contextlib

    from ..tiles.mercator import ground_pixel_m
    from ..tiles.render import RgbTileDrawer, raster_info, render_tile_rgba

    src_path = Path(ortho_path)
    info = raster_info(src_path, "rgb")
    levels = overlay_levels(info.lonlat_bounds, info.max_zoom, max_tiles)
    west, south, east, north = info.lonlat_bounds
    lat = (south + north) / 2
    pixel_m = ground_pixel_m(levels[-1], lat)
    finest = levels[-1]
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    part = out_path.with_name(out_path.name + ".part")
    images: dict[tuple[int, int, int], str] = {}      # tile -> image extension: what the KML tree needs
    try:
        with zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as zf, \
                (RgbTileDrawer(src_path, info) if fast_tiles else contextlib.nullcontext()) as drawer:
            # doc.kml first (what KMZ readers open): it links the root, the one tile of the coarsest level
            top_keys = _level_keys(info.lonlat_bounds, levels[0])
            desc_head = f"Georef orthophoto over zoom levels {levels[0]}-{finest}, {pixel_m:.3f} m pixels at the finest"
            doc = (f'<?xml version="1.0" encoding="UTF-8"?>\n<kml xmlns="{KML_NS}">\n <Document>\n'
                   f"  <name>{escape(name)}</name>\n"
                   f"  <description>{escape(desc_head + '; source ' + src_path.name)}</description>\n"
                   + "".join("  " + _link(k, 0, "tiles/") + "\n" for k in top_keys)
                   + " </Document>\n</kml>\n")
            zf.writestr("doc.kml", doc)
            for z in levels:
                for key in _level_keys(info.lonlat_bounds, z):
                    rgba = drawer.rgba(*key) if drawer is not None else render_tile_rgba(src_path, info, *key)[0]
                    enc = _encode_tile(rgba) if rgba is not None else None
                    if enc is None:
                        continue
                    data, ext = enc
                    images[key] = ext
                    # JPEG and PNG are compressed already
                    zf.writestr(zipfile.ZipInfo(f"tiles/{key[0]}_{key[1]}_{key[2]}.{ext}",
                                                date_time=(1980, 1, 1, 0, 0, 0)), data,
                                compress_type=zipfile.ZIP_STORED)
            if not images:
                raise InputFileError(src_path, "the orthophoto holds no valid pixel (all no-data)")
            # every tile with an image and every tile above one (a coarse tile all no-data may still lead to
            # finer tiles with data at the orthophoto's edge: it is kept, without an overlay); the roots always
            nodes = set(images) | set(top_keys)
            for z in range(finest, levels[0], -1):
                nodes |= {(z - 1, x // 2, y // 2) for (zz, x, y) in list(nodes) if zz == z}
            for z, x, y in sorted(nodes):
                box = tile_lonlat_box(z, x, y)
                kids = [(z + 1, 2 * x + i, 2 * y + j) for j in (0, 1) for i in (0, 1)]
                links = "".join(_link(k, MIN_LOD_PIXELS) for k in kids if k in nodes)
                overlay = ""
                if (z, x, y) in images:
                    overlay = (f"<GroundOverlay><drawOrder>{z}</drawOrder>"
                               f"<Icon><href>{z}_{x}_{y}.{images[(z, x, y)]}</href></Icon>"
                               f"{_box('LatLonBox', box)}</GroundOverlay>")
                kml = (f'<?xml version="1.0" encoding="UTF-8"?>\n<kml xmlns="{KML_NS}"><Document>'
                       f"<name>{z}/{x}/{y}</name>{_region(box, 0 if z == levels[0] else MIN_LOD_PIXELS)}"
                       f"{overlay}{links}</Document></kml>\n")
                zf.writestr(f"tiles/{z}_{x}_{y}.kml", kml)
        part.replace(out_path)
    finally:
        part.unlink(missing_ok=True)
    per_level = {str(z): sum(1 for k in images if k[0] == z) for z in levels}
    return {"tiled": True, "west": west, "south": south, "east": east, "north": north, "levels": levels,
            "tiles": len(images), "tiles_per_level": per_level, "pixel_m": round(pixel_m, 4)}
