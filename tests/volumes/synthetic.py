"""Synthetic DSM GeoTIFFs with analytic shapes (UTM 33N), for the volume tests and the benchmark."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

EPSG = 32633
E0, N0 = 512_000.0, 5_123_000.0  # site origin (a multiple of every test resolution)


def write_dsm(path, height_fn, size_m: tuple[float, float], res: float, epsg: int = EPSG, origin=(E0, N0),
              nodata: float | None = None, block_rows: int = 512, tile: int = 256) -> Path:
    """float32 GeoTIFF of ``height_fn(E, N)`` at cell centres over [E0, E0 + w] x [N0, N0 + h]."""
    import rasterio
    from affine import Affine

    w, h = size_m
    ncols, nrows = int(round(w / res)), int(round(h / res))
    e0, n_top = origin[0], origin[1] + nrows * res
    profile = {"driver": "GTiff", "width": ncols, "height": nrows, "count": 1, "dtype": "float32",
               "crs": f"EPSG:{epsg}", "transform": Affine(res, 0, e0, 0, -res, n_top), "tiled": True,
               "blockxsize": tile, "blockysize": tile}
    if nodata is not None:
        profile["nodata"] = nodata
    from rasterio.windows import Window

    with rasterio.open(path, "w", **profile) as ds:
        e = e0 + (np.arange(ncols) + 0.5) * res
        for r0 in range(0, nrows, block_rows):
            rows = np.arange(r0, min(r0 + block_rows, nrows))
            n = n_top - (rows + 0.5) * res
            E, N = np.meshgrid(e, n)
            z = np.asarray(height_fn(E, N), dtype=np.float32)
            ds.write(z, 1, window=Window(0, r0, ncols, len(rows)))
    return Path(path)


def circle(cx, cy, r, n=256):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)])


def write_geojson(path, rings: dict, epsg: int | None = EPSG, to_lonlat: bool = False, properties=None) -> Path:
    """FeatureCollection of named polygons (rings in UTM); with ``to_lonlat`` written in EPSG:4326
    (RFC 7946, no crs member)."""
    feats = []
    for name, ring in rings.items():
        xy = np.asarray(ring, float)
        if to_lonlat:
            from pyproj import Transformer

            tr = Transformer.from_crs(epsg, 4326, always_xy=True)
            lon, lat = tr.transform(xy[:, 0], xy[:, 1])
            xy = np.column_stack([lon, lat])
        coords = xy.tolist() + [xy[0].tolist()]
        props = {"name": name, **((properties or {}).get(name, {}))}
        feats.append({"type": "Feature", "properties": props, "geometry": {"type": "Polygon", "coordinates": [coords]}})
    doc = {"type": "FeatureCollection", "features": feats}
    if epsg is not None and not to_lonlat:
        doc["crs"] = {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{epsg}"}}
    Path(path).write_text(json.dumps(doc))
    return Path(path)


def cone_height(cx, cy, radius, h):
    return lambda E, N: h * np.maximum(0.0, 1.0 - np.hypot(E - cx, N - cy) / radius)


def cone_volume(radius, h):
    return math.pi * radius ** 2 * h / 3.0
