"""DXF drawings (ezdxf, AutoCAD 2013 format) of polylines, points and texts on named layers: contours,
outlines, surveyed points, design-difference polylines (any caller: ``write_dxf``).

Coordinates are written as they are (CRS easting, northing and height, metres: $INSUNITS = 6). The CRS
travels three ways: the model space's GEODATA object (AutoCAD's geographic location, DXF R2010+: a local
grid whose design point and reference point coincide, so drawing coordinates *are* CRS coordinates, units
metres, north up, with the coordinate-system definition as the XML dictionary AutoCAD stores, carrying the
EPSG code, the projection and its parameters, the datum and the ellipsoid: :func:`geodata_xml`); a
companion ``<name>.prj`` (ESRI WKT of the horizontal CRS) beside the drawing, which QGIS and Global Mapper
read; and the drawing's custom header properties ``GEOREF_CRS`` and ``GEOREF_VERTICAL_DATUM`` (AutoCAD:
DWGPROPS, Custom)."""

from __future__ import annotations

import re
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
    from ezdxf import bbox

    ext = bbox.extents(msp, fast=True)
    if ext.has_data:
        # the drawing's extents and its opening view: without them ($EXTMIN/$EXTMAX left at ezdxf's +-1e20 and
        # the view at 0,0) a CAD program opens a drawing at UTM coordinates looking at empty space
        lo, hi = tuple(ext.extmin), tuple(ext.extmax)
        doc.header["$EXTMIN"], doc.header["$EXTMAX"] = lo, hi
        msp.reset_extents(lo, hi)
        size = max(hi[0] - lo[0], hi[1] - lo[1], 1.0)
        doc.set_modelspace_vport(1.1 * size, ((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2))
    if crs is not None:
        add_geodata(doc, crs, _centre(polylines, points, texts))
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


def _centre(polylines, points, texts) -> tuple[float, float]:
    """The middle of the drawn entities' extent (x, y): the GEODATA design point."""
    xy = [np.asarray(pl.xy_m, float)[:, :2] for pl in polylines]
    xy += [np.array([[float(p.xyz_m[0]), float(p.xyz_m[1])]]) for p in points]
    xy += [np.array([[float(t.xyz_m[0]), float(t.xyz_m[1])]]) for t in texts]
    if not xy:
        return 0.0, 0.0
    a = np.concatenate(xy)
    lo, hi = a.min(axis=0), a.max(axis=0)
    return float((lo[0] + hi[0]) / 2), float((lo[1] + hi[1]) / 2)


def add_geodata(doc, crs, design_point_xy=(0.0, 0.0)):
    """Adds the model space's GEODATA object for a projected ``crs`` (pyproj; its horizontal part) in metres:
    a local grid where the drawing's coordinates are the CRS's (design point = reference point, north up,
    unit scale 1, no sea-level correction). Returns the GeoData, or None for a CRS that is not projected
    in metres (nothing to say in AutoCAD's terms; the .prj still states it)."""
    horiz = crs.sub_crs_list[0] if crs.is_compound else crs
    if not horiz.is_projected or any((a.unit_name or "").lower() not in ("metre", "meter")
                                     for a in horiz.axis_info[:2]):
        return None
    msp = doc.modelspace()
    geo = msp.new_geodata({"block_record_handle": msp.block_record_handle})   # its host: the model space
    x, y = (float(v) for v in design_point_xy)
    geo.setup_local_grid(design_point=(x, y, 0.0), reference_point=(x, y, 0.0), north_direction=(0, 1),
                         crs=geodata_xml(crs))
    return geo


def _x(text) -> str:
    from xml.sax.saxutils import escape

    return escape(str(text), {'"': "&quot;"})


def geodata_xml(crs) -> str:
    """The coordinate-system definition of a GEODATA object: the XML dictionary (namespace
    http://www.osgeo.org/mapguide/coordinatesystem) that AutoCAD writes there, built from the pyproj CRS's
    horizontal part: the projected system (name, EPSG code as an "EPSG Code" alias, easting/northing axes in
    metres, the projection method and parameters), its geodetic datum and ellipsoid (each with its EPSG
    alias where it has one). Georef's own writing of that format; readers that know the EPSG code (ezdxf's
    GeoData.get_crs, AutoCAD) need nothing else."""
    horiz = crs.sub_crs_list[0] if crs.is_compound else crs
    h2 = horiz.to_2d() if hasattr(horiz, "to_2d") else horiz
    epsg = h2.to_epsg()
    if epsg:
        from pyproj import CRS

        h2 = CRS.from_epsg(epsg)         # to_2d() drops the datum's and ellipsoid's EPSG identifiers
    name = (f"EPSG-{epsg}" if epsg else re.sub(r"[^A-Za-z0-9]+", "-", h2.name).strip("-")) or "SITE-CRS"
    datum, ell = h2.datum, h2.ellipsoid
    datum_id = re.sub(r"[^A-Za-z0-9]+", "-", datum.name).strip("-") or "DATUM"
    ell_id = re.sub(r"[^A-Za-z0-9]+", "-", ell.name).strip("-") or "ELLIPSOID"

    def code(obj):
        ident = (obj.to_json_dict() or {}).get("id") or {}
        return ident.get("code") if ident.get("authority") == "EPSG" else None

    lines = ['<?xml version="1.0" encoding="UTF-16" standalone="no" ?>',
             '<Dictionary version="1.0" xmlns="http://www.osgeo.org/mapguide/coordinatesystem">',
             f'<ProjectedCoordinateSystem id="{_x(name)}">', f"<Name>{_x(name)}</Name>",
             f"<Description>{_x(h2.name)}</Description>", "<Authority>EPSG</Authority>" if epsg else ""]
    aou = h2.area_of_use
    if aou is not None:
        lines += ["<DomainOfValidity><Extent><GeographicElement><GeographicBoundingBox>",
                  f"<WestBoundLongitude>{aou.west:g}</WestBoundLongitude>",
                  f"<EastBoundLongitude>{aou.east:g}</EastBoundLongitude>",
                  f"<SouthBoundLatitude>{aou.south:g}</SouthBoundLatitude>",
                  f"<NorthBoundLatitude>{aou.north:g}</NorthBoundLatitude>",
                  "</GeographicBoundingBox></GeographicElement></Extent></DomainOfValidity>"]
    lines += [f"<DatumId>{_x(datum_id)}</DatumId>", '<Axis uom="Meter">']
    for k, (nm, ab, d) in enumerate((("Easting", "E", "East"), ("Northing", "N", "North")), start=1):
        lines.append(f"<CoordinateSystemAxis><AxisOrder>{k}</AxisOrder><AxisName>{nm}</AxisName>"
                     f"<AxisAbbreviation>{ab}</AxisAbbreviation><AxisDirection>{d}</AxisDirection>"
                     "</CoordinateSystemAxis>")
    lines.append("</Axis>")
    op = h2.coordinate_operation
    if op is not None:
        lines += ["<Conversion><Projection>", f"<OperationMethodId>{_x(op.method_name)}</OperationMethodId>"]
        for p in op.params:
            uom = {"degree": "degree", "metre": "Meter", "unity": "unity"}.get(p.unit_name, p.unit_name)
            lines.append(f"<ParameterValue><OperationParameterId>{_x(p.name)}</OperationParameterId>"
                         f'<Value uom="{_x(uom)}">{p.value!r}</Value></ParameterValue>')
        lines.append("</Projection></Conversion>")
    lines.append("</ProjectedCoordinateSystem>")
    if epsg:
        lines += [f'<Alias id="{epsg}" type="CoordinateSystem">', f"<ObjectId>{_x(name)}</ObjectId>",
                  "<Namespace>EPSG Code</Namespace>", "</Alias>"]
    lines += [f'<GeodeticDatum id="{_x(datum_id)}">', f"<Name>{_x(datum.name)}</Name>",
              "<PrimeMeridianId>Greenwich</PrimeMeridianId>", f"<EllipsoidId>{_x(ell_id)}</EllipsoidId>",
              "</GeodeticDatum>"]
    if code(datum):
        lines += [f'<Alias id="{code(datum)}" type="Datum">', f"<ObjectId>{_x(datum_id)}</ObjectId>",
                  "<Namespace>EPSG Code</Namespace>", "</Alias>"]
    lines += [f'<Ellipsoid id="{_x(ell_id)}">', f"<Name>{_x(ell.name)}</Name>",
              f'<SemiMajorAxis uom="meter">{ell.semi_major_metre!r}</SemiMajorAxis>',
              f'<SecondDefiningParameter><SemiMinorAxis uom="meter">{ell.semi_minor_metre!r}</SemiMinorAxis>'
              "</SecondDefiningParameter>", "</Ellipsoid>"]
    if code(ell):
        lines += [f'<Alias id="{code(ell)}" type="Ellipsoid">', f"<ObjectId>{_x(ell_id)}</ObjectId>",
                  "<Namespace>EPSG Code</Namespace>", "</Alias>"]
    lines.append("</Dictionary>")
    return "\n".join(x for x in lines if x)
