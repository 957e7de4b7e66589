"""Cloud-Optimized GeoTIFF writing: the raster is built in memory as a tiled GeoTIFF and copied with GDAL's
COG driver (internal 512 x 512 tiles, overviews, compression), the layout web viewers and GIS read by
HTTP range requests."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import rasterio
from rasterio.enums import ColorInterp
from rasterio.shutil import copy as rio_copy
from rasterio.transform import Affine

HEIGHT_TAGS = {"HEIGHTS": "ellipsoidal (WGS84), metres", "PRODUCER": "georef dense step"}


def write_cog(path, bands: np.ndarray, transform: Affine, epsg: int, *, nodata=None, compress: str = "DEFLATE",
              overview_resampling: str = "AVERAGE", colorinterp: list | None = None,
              descriptions: list[str] | None = None, tags: dict | None = None, units: str | None = None,
              jpeg_quality: int = 90, crs=None) -> Path:
    """Write ``bands`` (count, rows, cols) as a COG. float rasters get the floating-point predictor. ``crs``
    (WKT or any rasterio CRS input, e.g. a compound CRS with the heights' vertical datum) replaces EPSG:epsg."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    bands = np.asarray(bands)
    if bands.ndim == 2:
        bands = bands[None]
    count, h, w = bands.shape
    profile = {"driver": "GTiff", "width": w, "height": h, "count": count, "dtype": bands.dtype.name,
               "crs": crs if crs is not None else f"EPSG:{int(epsg)}", "transform": transform, "tiled": True,
               "blockxsize": 512, "blockysize": 512, "compress": "NONE", "BIGTIFF": "IF_SAFER"}
    if nodata is not None:
        profile["nodata"] = nodata
    fd, tmp_name = tempfile.mkstemp(suffix=".tif", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        with rasterio.open(tmp, "w", **profile) as dst:
            dst.write(bands)
            if colorinterp:
                dst.colorinterp = colorinterp
            if descriptions:
                for k, d in enumerate(descriptions, start=1):
                    dst.set_band_description(k, d)
            if units:
                dst.units = [units] * count
            dst.update_tags(**(tags or {}))
        options = {"COMPRESS": compress, "BLOCKSIZE": "512", "OVERVIEW_RESAMPLING": overview_resampling,
                   "BIGTIFF": "IF_SAFER", "NUM_THREADS": "1"}
        if compress.upper() in ("DEFLATE", "LZW", "ZSTD"):
            options["PREDICTOR"] = "FLOATING_POINT" if np.issubdtype(bands.dtype, np.floating) else "YES"
        if compress.upper() == "JPEG":
            options["QUALITY"] = str(jpeg_quality)
        out_tmp = path.with_name(path.name + ".part")
        rio_copy(tmp, out_tmp, driver="COG", **options)
        os.replace(out_tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


RGBA = [ColorInterp.red, ColorInterp.green, ColorInterp.blue, ColorInterp.alpha]


def geotiff_to_cog(src, dst, *, compress: str = "DEFLATE", overview_resampling: str = "AVERAGE") -> Path:
    """Copy an existing (tiled, strip-written) GeoTIFF into a COG at ``dst`` through GDAL's COG driver: the
    raster is streamed, never held whole in memory; band descriptions, tags, nodata and a colour table are
    kept. ``overview_resampling``: AVERAGE for continuous values, NEAREST for classes (an average of two
    class codes is a third class). Written under ``dst``.part and renamed."""
    src, dst = Path(src), Path(dst)
    with rasterio.open(src) as ds:
        floating = np.issubdtype(np.dtype(ds.dtypes[0]), np.floating)
    options = {"COMPRESS": compress, "BLOCKSIZE": "512", "OVERVIEW_RESAMPLING": overview_resampling,
               "BIGTIFF": "IF_SAFER", "NUM_THREADS": "1"}
    if compress.upper() in ("DEFLATE", "LZW", "ZSTD"):
        options["PREDICTOR"] = "FLOATING_POINT" if floating else "YES"
    part = dst.with_name(dst.name + ".part")
    rio_copy(src, part, driver="COG", **options)
    os.replace(part, dst)
    return dst
