"""Vector layers (contours, outlines, points) as GeoJSON, GeoPackage and Shapefile.

CRS in each file:

* GeoPackage and Shapefile (pyogrio, GDAL): the surface's CRS stating the heights (surface.Surface.crs_3d:
  the compound CRS of a raster that has one, else the projected CRS with an ellipsoidal-height axis); the
  Shapefile gets it as its .prj (ESRI WKT: PROJCS + VERTCS).
* GeoJSON: RFC 7946 (WGS 84 longitude/latitude in degrees, 9 decimals = 0.1 mm; heights as the third
  coordinate in the surface's vertical datum, ellipsoidal unless a geoid was applied), as every GeoJSON
  Georef serves; ``geojson_crs="site"`` writes the site's projected coordinates with the (pre-RFC 7946)
  "crs" member instead, which QGIS reads. Both state the vertical datum in a "georef" member.

Every feature also carries ``vertical_datum`` so a reader that drops the CRS still knows the heights'
reference."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ProcessingError


@dataclass
class VectorLayer:
    name: str
    geometry_type: str                     # "LineString Z", "Polygon Z", "Point Z", ...
    geometries: list                       # shapely geometries in the layer CRS (with z)
    fields: dict[str, list] = field(default_factory=dict)
    shp_names: dict[str, str] = field(default_factory=dict)   # field -> Shapefile name (10 characters at most)


def _field_arrays(layer: VectorLayer, names: dict[str, str] | None = None) -> tuple[list[str], list[np.ndarray]]:
    cols, arrays = [], []
    for k, v in layer.fields.items():
        a = np.asarray(v)
        if a.dtype.kind in "OU":
            a = np.asarray(["" if x is None else str(x) for x in v], dtype=object)
        elif a.dtype.kind == "b":
            a = a.astype(np.int32)
        name = (names or {}).get(k, k)
        cols.append(name)
        arrays.append(a)
    return cols, arrays


def write_gpkg(path, layers: list[VectorLayer], crs, metadata: dict | None = None) -> Path:
    """One GeoPackage holding every (non-empty) layer, in ``crs`` (pyproj)."""
    import shapely
    from pyogrio.raw import write

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists():
        path.unlink()
    wkt = crs.to_wkt()
    n = 0
    for layer in layers:
        if not layer.geometries:
            continue
        cols, arrays = _field_arrays(layer)
        write(path, shapely.to_wkb(np.array(layer.geometries, dtype=object)), arrays, fields=cols, crs=wkt,
              geometry_type=layer.geometry_type, driver="GPKG", layer=layer.name, append=n > 0,
              layer_metadata={k: str(v) for k, v in (metadata or {}).items()} or None)
        n += 1
    if n == 0:
        raise ProcessingError(f"{path}: nothing to write (every layer is empty)")
    _wkt1_fallback(path, crs)
    return path


def _wkt1_fallback(path: Path, crs) -> None:
    """A 3-D projected CRS (ellipsoidal heights) has no WKT1 form: GDAL writes it into the GeoPackage's
    ``definition_12_063`` column (WKT2, the crs_wkt extension) and leaves ``definition`` as "undefined", so a reader
    that knows only WKT1 (the core GeoPackage) saw no CRS at all. ``definition`` then gets the WKT1 of the
    horizontal CRS; readers of the extension still take the 3-D CRS from ``definition_12_063``, which wins."""
    import sqlite3

    from pyproj.enums import WktVersion

    horiz = crs.sub_crs_list[0] if crs.is_compound else crs
    try:
        wkt1 = (horiz.to_2d() if len(horiz.axis_info) == 3 else horiz).to_wkt(WktVersion.WKT1_GDAL)
    except Exception:  # noqa: BLE001 (no WKT1 form even in 2-D: leave what GDAL wrote)
        return
    if not wkt1:
        return
    con = sqlite3.connect(path)
    try:
        cols = {r[1] for r in con.execute("PRAGMA table_info(gpkg_spatial_ref_sys)")}
        if "definition_12_063" in cols:
            with con:
                con.execute("UPDATE gpkg_spatial_ref_sys SET definition = ? WHERE definition = 'undefined' AND "
                            "definition_12_063 NOT IN ('', 'undefined') AND srs_id IN "
                            "(SELECT srs_id FROM gpkg_geometry_columns)", (wkt1,))
    finally:
        con.close()


def write_shapefiles(folder, layers: list[VectorLayer], crs) -> list[Path]:
    """One Shapefile per non-empty layer (``folder/<layer>.shp`` with .shx, .dbf, .prj, .cpg)."""
    import shapely
    from pyogrio.raw import write

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for layer in layers:
        if not layer.geometries:
            continue
        cols, arrays = _field_arrays(layer, layer.shp_names)
        bad = [c for c in cols if len(c) > 10]
        if bad:
            raise ProcessingError(f"Shapefile layer {layer.name}: field names over 10 characters: {bad}")
        p = folder / f"{layer.name}.shp"
        write(p, shapely.to_wkb(np.array(layer.geometries, dtype=object)), arrays, fields=cols, crs=crs.to_wkt(),
              geometry_type=layer.geometry_type, driver="ESRI Shapefile", encoding="UTF-8")
        out.append(p)
    return out


def _rounded(coords, decimals: int):
    if isinstance(coords, (list, tuple)) and coords and isinstance(coords[0], (int, float)):
        return [round(float(c), decimals if i < 2 else 4) for i, c in enumerate(coords)]
    return [_rounded(c, decimals) for c in coords]


def write_geojson(path, layer: VectorLayer, crs, vertical_datum: str, geojson_crs: str = "wgs84",
                  extra: dict | None = None) -> Path:
    """A GeoJSON FeatureCollection of one layer (``geojson_crs``: "wgs84" RFC 7946, or "site": the layer's
    projected CRS named in a "crs" member)."""
    import shapely
    from pyproj import CRS, Transformer

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    horiz = crs.sub_crs_list[0] if crs.is_compound else crs
    if geojson_crs == "wgs84":
        tr = Transformer.from_crs(horiz, CRS.from_epsg(4326), always_xy=True)

        def fwd(xy):
            lon, lat = tr.transform(xy[:, 0], xy[:, 1])
            return np.column_stack([lon, lat, *xy[:, 2:].T])

        decimals = 9
    elif geojson_crs == "site":
        fwd, decimals = None, 4
    else:
        raise ProcessingError(f"GeoJSON CRS {geojson_crs!r}: wgs84 or site")
    features = []
    for k, g in enumerate(layer.geometries):
        if fwd is not None:
            g = shapely.transform(g, fwd, include_z=shapely.has_z(g))
        props = {name: _json_value(vals[k]) for name, vals in layer.fields.items()}
        props.setdefault("vertical_datum", vertical_datum)
        features.append({"type": "Feature", "properties": props,
                         "geometry": {**(geom := shapely.geometry.mapping(g)),
                                      "coordinates": _rounded(_listify(geom["coordinates"]), decimals)}})
    doc = {"type": "FeatureCollection", "name": layer.name}
    if geojson_crs == "site":
        e = horiz.to_epsg()
        doc["crs"] = {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{e}" if e else horiz.to_wkt()}}
    doc["georef"] = {"coordinates": "WGS 84 longitude, latitude (degrees; RFC 7946)" if geojson_crs == "wgs84"
                     else f"{horiz.name} easting, northing (metres)", "heights": vertical_datum,
                     "source_crs": horiz.to_wkt() if not horiz.to_epsg() else f"EPSG:{horiz.to_epsg()}",
                     **(extra or {})}
    doc["features"] = features
    path.write_text(json.dumps(doc, separators=(",", ":")))
    return path


def _listify(c):
    if isinstance(c, (list, tuple)):
        return [_listify(x) for x in c]
    return c


def _json_value(v):
    if isinstance(v, (np.bool_, bool)):
        return bool(v)
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.floating):
        return None if not np.isfinite(v) else float(v)
    return v
