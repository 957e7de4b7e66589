"""A height raster (DSM, DTM) converted to another vertical datum, the datum written into the GeoTIFF.

The output is a cloud-optimised GeoTIFF whose CRS is the compound CRS horizontal + vertical (GeoTIFF's
VerticalCSTypeGeoKey: QGIS, GDAL and rasterio read it back as e.g. "WGS 84 / UTM zone 31N + EGM96 height";
ellipsoidal heights: the 2-D CRS, GeoTIFF having no code for them, and the HEIGHTS tag saying so),
with the tags HEIGHTS (the datum's label), VERTICAL_DATUM (its EPSG code) and GEOID_OPERATION (PROJ's
operation). The height change is height_shift.HeightShift: PROJ at nodes 10 m apart, bilinear in between.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputFileError
from .height_shift import DEFAULT_STEP_M, HeightShift
from .vertical_datum import compound_crs, datum_of_crs, horizontal_crs, resolve, transformation

ROWS_PER_BLOCK = 512


def raster_datum(path, crs, tags: dict, given=None):
    """The vertical datum of a raster's heights: ``given`` when the caller states it, else its CRS's vertical
    component, else its HEIGHTS tag saying ellipsoidal (what the dense step writes); InputFileError when
    nothing says (the heights' datum is never guessed)."""
    if given is not None:
        return resolve(given)
    d = datum_of_crs(crs.to_wkt()) if crs is not None else None
    if d is not None:
        return d
    if "ellipsoidal" in str(tags.get("HEIGHTS", "")).lower():
        return resolve("ellipsoidal")
    raise InputFileError(path, "the datum of its heights is not stated (no vertical CRS, no HEIGHTS tag): give "
                               "it (--from ellipsoidal | egm96 | EPSG:code)")


def convert_raster_heights(src_path, dst_path, to_datum, from_datum=None, step_m: float = DEFAULT_STEP_M) -> dict:
    """Writes ``dst_path``: the raster of ``src_path`` with its heights in ``to_datum``; returns a summary
    (datums, the height change's range over the raster, the operation)."""
    import rasterio

    from ..dense.cog_writer import write_cog

    src_path = Path(src_path)
    if not src_path.is_file():
        raise InputFileError(src_path, "raster not found")
    try:
        with rasterio.open(src_path) as src:
            z = src.read(1)
            transform, crs, nodata, tags = src.transform, src.crs, src.nodata, src.tags()
            units = src.units[0] if src.units else None
    except rasterio.errors.RasterioIOError as exc:
        raise InputFileError(src_path, f"not a readable GeoTIFF ({exc})") from None
    if crs is None:
        raise InputFileError(src_path, "the raster has no CRS")
    hcrs = horizontal_crs(crs.to_wkt())
    if not hcrs.is_projected:
        raise InputFileError(src_path, f"the raster's CRS ({hcrs.name}) is not projected (easting/northing in metres)")
    a = raster_datum(src_path, crs, tags, from_datum)
    b = resolve(to_datum)
    h, w = z.shape
    valid = np.isfinite(z) if nodata is None else (np.isfinite(z) & (z != nodata))
    corners = np.array([pixel_to_map(transform, c, r) for c in (0, w) for r in (0, h)])
    shift = HeightShift.over(hcrs, corners[:, 0].min(), corners[:, 0].max(), corners[:, 1].min(),
                             corners[:, 1].max(), a, b, step_m)
    out = z.astype(np.float32 if z.dtype != np.float64 else np.float64, copy=True)
    cols = np.arange(w) + 0.5
    lo, hi = np.inf, -np.inf
    for r0 in range(0, h, ROWS_PER_BLOCK):
        rows = np.arange(r0, min(h, r0 + ROWS_PER_BLOCK)) + 0.5
        cc, rr = np.meshgrid(cols, rows)
        e, n = pixel_to_map(transform, cc, rr)
        dz = shift.at(e, n)
        m = valid[r0:r0 + len(rows)]
        block = out[r0:r0 + len(rows)]
        block[m] = (block[m].astype(np.float64) + dz[m]).astype(out.dtype)
        if m.any():
            lo, hi = min(lo, float(dz[m].min())), max(hi, float(dz[m].max()))
    op = transformation(b if not b.is_ellipsoidal else a)
    new_tags = {k: v for k, v in tags.items() if k not in ("AREA_OR_POINT",)}
    new_tags.update(HEIGHTS=f"{b.label}, metres", VERTICAL_DATUM=b.code,
                    HEIGHTS_CONVERTED_FROM=a.label, GEOID_OPERATION=op["operation"])
    # GeoTIFF has no code for a 3-D projected CRS: ellipsoidal heights are the 2-D CRS + the HEIGHTS tag
    out_crs = hcrs if b.is_ellipsoidal else compound_crs(hcrs, b)
    write_cog(dst_path, out, transform, 0, nodata=nodata, tags=new_tags, units=units or "metre", crs=out_crs.to_wkt())
    return {"from": a.label, "to": b.label, "crs": out_crs.name, "path": str(dst_path),
            "dz_m": {"min": None if lo == np.inf else round(lo, 4), "max": None if hi == -np.inf else round(hi, 4)},
            "operation": op["operation"], "grid": op["grid"], "node_step_m": step_m}


def pixel_to_map(t, col, row):
    """Pixel (col, row) -> (E, N) through the affine geotransform ``t`` (arrays)."""
    return t.a * col + t.b * row + t.c, t.d * col + t.e * row + t.f
