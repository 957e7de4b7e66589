"""DXF drawings (ezdxf, AutoCAD 2013 format) of polylines, points and texts on named layers: contours,
outlines, surveyed points, design-difference polylines (any caller: ``write_dxf``).

DXF has no coordinate reference system: coordinates are written as they are (CRS easting, northing and
height, metres: $INSUNITS = 6) and a companion ``<name>.prj`` (ESRI WKT of the horizontal CRS) is written
beside the drawing, which QGIS and Global Mapper read (AutoCAD Map / Civil 3D: assign the CRS by its EPSG
code). The CRS and the vertical datum are also stated in the drawing's custom header properties
``GEOREF_CRS`` and ``GEOREF_VERTICAL_DATUM`` (AutoCAD: DWGPROPS, Custom)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ProcessingError

# AutoCAD colour index of the layers this package draws (others get white/black, 7)
LAYER_COLOURS = {"CONTOUR_MINOR": 8, "CONTOUR_INDEX": 7, "CONTOUR_LABEL": 7, "STOCKPILE_OUTLINE": 1,
                 "CHECK_POINTS": 3, "CONTROL_POINTS": 5, "POINT_LABELS": 2}


@dataclass
class DxfPolyline:
    """A polyline on ``layer``. ``xy_m`` (n, 2) with ``elevation_m``: a 2-D polyline at that height
    (LWPOLYLINE, its elevation set: how contours are drawn); ``xy_m`` (n, 3): a 3-D polyline (POLYLINE)."""

    layer: str
    xy_m: np.ndarray
    closed: bool = False
    elevation_m: float | None = None


@dataclass
class DxfPoint:
    layer: str
    xyz_m: tuple[float, float, float]
    label: str | None = None          # written as TEXT beside the point on POINT_LABELS
    label_layer: str = "POINT_LABELS"


@dataclass
class DxfText:
    layer: str
    text: str
    xyz_m: tuple[float, float, float]
    height_m: float
    rotation_deg: float = 0.0
    centred: bool = True              # the insertion point is the text's middle


def prj_text(crs) -> str:
    """ESRI WKT (.prj) of a pyproj CRS's horizontal part."""
    from pyproj.enums import WktVersion

    horiz = crs.sub_crs_list[0] if crs.is_compound else crs
    return horiz.to_wkt(WktVersion.WKT1_ESRI)


def write_dxf(path, polylines=(), points=(), texts=(), crs=None, vertical_datum: str | None = None,
              layer_colours: dict[str, int] | None = None, point_size_m: float | None = None) -> list[Path]:
    """Writes a DXF of the given entities (layers made as named; colours from LAYER_COLOURS or
    ``layer_colours``) and, with ``crs`` (pyproj), its companion .prj. Returns the files written."""
    import ezdxf

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = ezdxf.new("R2013", setup=True)
    doc.header["$INSUNITS"] = 6        # metres
    doc.header["$MEASUREMENT"] = 1     # metric
    doc.header["$PDMODE"] = 3          # points drawn as crosses
    if point_size_m:
        doc.header["$PDSIZE"] = float(point_size_m)
    if crs is not None:
        doc.header.custom_vars.append("GEOREF_CRS", crs_label(crs))
    if vertical_datum:
        doc.header.custom_vars.append("GEOREF_VERTICAL_DATUM", vertical_datum)
    colours = {**LAYER_COLOURS, **(layer_colours or {})}
    msp = doc.modelspace()

    def layer(name: str) -> str:
        if name not in doc.layers:
            doc.layers.add(name, color=colours.get(name, 7))
        return name

    for pl in polylines:
        xy = np.asarray(pl.xy_m, float)
        if xy.ndim != 2 or len(xy) < 2 or xy.shape[1] not in (2, 3):
            raise ProcessingError(f"DXF polyline on {pl.layer}: needs at least 2 vertices of 2 or 3 coordinates")
        closed = pl.closed
        if closed and np.abs(xy[0] - xy[-1]).max() < 1e-9:
            xy = xy[:-1]
        if xy.shape[1] == 2:
            e = msp.add_lwpolyline(xy.tolist(), format="xy", close=closed, dxfattribs={"layer": layer(pl.layer)})
            if pl.elevation_m is not None:
                e.dxf.elevation = float(pl.elevation_m)
        else:
            msp.add_polyline3d(xy.tolist(), close=closed, dxfattribs={"layer": layer(pl.layer)})
    for pt in points:
        x, y, z = (float(v) for v in pt.xyz_m)
        msp.add_point((x, y, z), dxfattribs={"layer": layer(pt.layer)})
        if pt.label:
            h = point_size_m or 0.5
            t = msp.add_text(pt.label, height=h, dxfattribs={"layer": layer(pt.label_layer)})
            t.set_placement((x + h, y + h, z))
    for tx in texts:
        x, y, z = (float(v) for v in tx.xyz_m)
        t = msp.add_text(tx.text, height=float(tx.height_m), rotation=float(tx.rotation_deg),
                         dxfattribs={"layer": layer(tx.layer)})
        if tx.centred:
            from ezdxf.enums import TextEntityAlignment

            t.set_placement((x, y, z), align=TextEntityAlignment.MIDDLE_CENTER)
        else:
            t.set_placement((x, y, z))
    doc.saveas(path)
    written = [path]
    if crs is not None:
        prj = path.with_suffix(".prj")
        prj.write_text(prj_text(crs))
        written.append(prj)
    return written


def crs_label(crs) -> str:
    e = crs.to_epsg()
    if e:
        return f"EPSG:{e}"
    if crs.is_compound:
        parts = [c.to_epsg() for c in crs.sub_crs_list]
        if all(parts):
            return "EPSG:" + "+".join(str(p) for p in parts)
    h = crs.sub_crs_list[0] if crs.is_compound else crs
    he = h.to_2d().to_epsg() if hasattr(h, "to_2d") else h.to_epsg()
    return f"EPSG:{he} (3-D: ellipsoidal heights)" if he else crs.name
