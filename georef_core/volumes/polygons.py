"""Volume polygons from GeoJSON: reading, CRS handling, validation and reprojection.

A file may hold a FeatureCollection, a Feature or a bare Polygon/MultiPolygon geometry. Each polygon
feature becomes one :class:`AreaPolygon`, named by its ``name`` property (else ``Name``, ``id``, or
``polygon N``). The CRS comes from, in order: the caller (``--polygon-crs``), the legacy GeoJSON
``crs`` member (``{"type": "name", "properties": {"name": "EPSG:32633"}}`` or an OGC URN), else
RFC 7946's WGS84 longitude/latitude (EPSG:4326), which is checked to be plausible."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError


@dataclass
class AreaPolygon:
    """One named polygon (shapely Polygon or MultiPolygon, 2-D) with its CRS (pyproj.CRS)."""

    name: str
    geometry: object
    crs: object
    source: str = ""
    properties: dict = field(default_factory=dict)

    @property
    def area_m2(self) -> float:
        """Planimetric area in CRS units (m^2 for a projected metric CRS)."""
        return float(self.geometry.area)

    def to_crs(self, dst_crs) -> "AreaPolygon":
        """This polygon in ``dst_crs`` (vertices transformed, edges kept straight in the new CRS)."""
        if self.crs == dst_crs:
            return self
        import shapely
        from pyproj import Transformer

        tr = Transformer.from_crs(self.crs, dst_crs, always_xy=True)

        def fwd(xy):
            x, y = tr.transform(xy[:, 0], xy[:, 1])
            return np.column_stack([x, y])

        geom = shapely.transform(self.geometry, fwd)
        if not shapely.is_valid(geom) or not all(math.isfinite(v) for v in geom.bounds):
            raise InputFileError(self.source or "polygon", f"{self.name!r}: cannot be transformed from "
                                 f"{crs_label(self.crs)} to {crs_label(dst_crs)} (outside the target CRS's area?)")
        return AreaPolygon(self.name, geom, dst_crs, self.source, self.properties)

    def outer_rings(self) -> list:
        """Exterior rings (shapely LinearRing) of every part."""
        parts = getattr(self.geometry, "geoms", [self.geometry])
        return [p.exterior for p in parts]

    def to_geojson_geometry(self, ndigits: int = 4) -> dict:
        import shapely.geometry

        g = shapely.geometry.mapping(self.geometry)

        def rnd(c):
            return [rnd(v) for v in c] if isinstance(c[0], (list, tuple)) else [round(float(v), ndigits) for v in c]

        return {"type": g["type"], "coordinates": rnd(g["coordinates"])}


def crs_label(crs) -> str:
    epsg = crs.to_epsg() if crs is not None else None
    return f"EPSG:{epsg}" if epsg else (crs.name if crs is not None else "no CRS")


def parse_crs(text, path=None):
    """A pyproj CRS from 'EPSG:32633', '32633', an OGC URN or WKT; InputFileError (naming ``path``) if not."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        return CRS.from_user_input(int(text) if str(text).strip().isdigit() else str(text).strip())
    except (CRSError, ValueError, TypeError) as exc:
        raise InputFileError(path or "CRS", f"CRS {text!r} is not understood ({exc})") from None


def _geojson_crs(doc: dict, path: Path):
    crs = doc.get("crs")
    if crs is None:
        return None
    props = crs.get("properties", {}) if isinstance(crs, dict) else {}
    name = props.get("name") or props.get("code")
    if not name:
        raise InputFileError(path, f"the GeoJSON 'crs' member {crs!r} has no name; write "
                                   '{"type": "name", "properties": {"name": "EPSG:XXXX"}}')
    return parse_crs(name, path)


def _features(doc, path: Path) -> list[tuple[dict, dict]]:
    """(geometry, properties) pairs of a GeoJSON document."""
    t = doc.get("type") if isinstance(doc, dict) else None
    if t == "FeatureCollection":
        feats = doc.get("features")
        if not isinstance(feats, list):
            raise InputFileError(path, "FeatureCollection without a 'features' list")
        return [(f.get("geometry"), f.get("properties") or {}) for f in feats if isinstance(f, dict)]
    if t == "Feature":
        return [(doc.get("geometry"), doc.get("properties") or {})]
    if t in ("Polygon", "MultiPolygon", "GeometryCollection", "Point", "LineString", "MultiLineString", "MultiPoint"):
        return [(doc, {})]
    raise InputFileError(path, f"not GeoJSON (top-level type {t!r}; expected FeatureCollection, Feature or Polygon)")


def _feature_name(props: dict, index: int, taken: set) -> str:
    for key in ("name", "Name", "NAME", "id", "label"):
        v = props.get(key)
        if v not in (None, ""):
            name = str(v)
            break
    else:
        name = f"polygon {index + 1}"
    base, k = name, 2
    while name in taken:
        name = f"{base} ({k})"
        k += 1
    taken.add(name)
    return name


def validate_polygon(geom, name: str, path) -> None:
    """InputFileError naming the file and the feature if ``geom`` is empty, degenerate or invalid
    (self-intersecting, ...), with shapely's explanation of where."""
    import shapely
    from shapely.validation import explain_validity

    if geom.is_empty:
        raise InputFileError(path, f"feature {name!r}: empty polygon")
    if not shapely.is_valid(geom):
        why = explain_validity(geom)
        hint = ("the outline crosses itself, so it has no defined inside; redraw it without crossing"
                if "Self-intersection" in why or "Ring Self-intersection" in why else "fix the geometry")
        raise InputFileError(path, f"feature {name!r}: invalid polygon ({why}): {hint}")
    if geom.area <= 0:
        raise InputFileError(path, f"feature {name!r}: polygon has zero area")


def read_polygons(path, crs=None) -> list[AreaPolygon]:
    """Polygons of a GeoJSON file (see the module docstring for the CRS rules); every problem raises
    InputFileError naming ``path`` and the feature."""
    import shapely.geometry
    from pyproj import CRS

    p = Path(path)
    if not p.exists():
        raise InputFileError(p, "file not found")
    try:
        doc = json.loads(p.read_text(encoding="utf-8-sig"))
    except UnicodeDecodeError:
        raise InputFileError(p, "not a text file (GeoJSON expected)") from None
    except json.JSONDecodeError as exc:
        raise InputFileError(p, f"not valid JSON ({exc.msg})", line=exc.lineno) from None
    if crs is not None:
        src_crs = crs if isinstance(crs, CRS) else parse_crs(crs, p)
        declared = True
    else:
        src_crs = _geojson_crs(doc, p)
        declared = src_crs is not None
        if src_crs is None:
            src_crs = CRS.from_epsg(4326)
    out: list[AreaPolygon] = []
    taken: set = set()
    for i, (g, props) in enumerate(_features(doc, p)):
        if g is None:
            continue
        gtype = g.get("type") if isinstance(g, dict) else None
        if gtype not in ("Polygon", "MultiPolygon"):
            raise InputFileError(p, f"feature {i + 1} is a {gtype}, not a Polygon or MultiPolygon")
        name = _feature_name(props, i, taken)
        try:
            geom = shapely.geometry.shape(g)
        except Exception as exc:
            raise InputFileError(p, f"feature {name!r}: malformed coordinates ({exc})") from None
        geom = shapely.force_2d(geom)
        validate_polygon(geom, name, p)
        out.append(AreaPolygon(name, geom, src_crs, str(p), dict(props)))
    if not out:
        raise InputFileError(p, "no polygon in the file")
    if not declared:
        for a in out:
            x0, y0, x1, y1 = a.geometry.bounds
            if not (-180.0 <= x0 and x1 <= 360.0 and -90.0 <= y0 and y1 <= 90.0):
                raise InputFileError(p, f"no CRS given and the coordinates of {a.name!r} (e.g. {x0:.1f}, {y0:.1f}) are "
                                        "not longitude/latitude, which GeoJSON (RFC 7946) assumes; add a 'crs' member "
                                        "or give the polygon CRS (--polygon-crs EPSG:XXXX)")
    elif src_crs.is_geographic:
        for a in out:
            x0, y0, x1, y1 = a.geometry.bounds
            if not (-180.0 <= x0 and x1 <= 360.0 and -90.0 <= y0 and y1 <= 90.0):
                raise InputFileError(p, f"the file declares {crs_label(src_crs)} but the coordinates of {a.name!r} are "
                                        "not degrees; wrong CRS?")
    return out
