"""The orthophoto as a KMZ overlay (Google Earth, Avenza Maps, phones): the orthophoto reduced to at most
``max_px`` pixels on its longer side, warped to WGS 84 longitude/latitude (a north-up lat/lon grid, so the
KML GroundOverlay's LatLonBox places it without rotation), PNG with no-data transparent; doc.kml plus
files/ortho.png zipped. The reduction is for viewing on site, not measuring: the KML states the ground
pixel size."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

from ..errors import InputFileError

KML_NS = "http://www.opengis.net/kml/2.2"


def write_kmz(ortho_path, out_path, max_px: int = 4096, name: str = "Orthophoto") -> dict:
    """Writes ``out_path`` (.kmz) from the orthophoto GeoTIFF; returns {"west", "south", "east", "north",
    "width_px", "height_px", "pixel_m"}."""
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
    return {"west": west, "south": south, "east": east, "north": north, "width_px": dw, "height_px": dh,
            "pixel_m": round(pixel_m, 4)}
