"""Every export of `georef export` read back by an implementation other than the one that wrote it (issue 25's
"contractors' CAD/GIS software opens them", which cannot run here):

* DXF (written by ezdxf): GDAL/OGR's DXF driver (through pyogrio) for layers, entity kinds, coordinates and
  contour elevations; a reader of DXF group codes written here for the header ($INSUNITS, $EXTMIN/$EXTMAX, the
  custom CRS properties, the opening view); ezdxf's recover + audit (AutoCAD refuses files that fail such checks);
* GeoPackage (written by GDAL): SQLite itself (the tables the GeoPackage standard defines, the geometry blobs
  decoded by hand, the CRS in both its WKT1 and WKT2 columns);
* Shapefile (written by GDAL): pyshp, a pure-Python reader;
* KMZ (written by Georef's own KML): GDAL's LIBKML driver (the GroundOverlay as a feature) and its
  KMLSUPEROVERLAY raster driver (the picture where it belongs);
* LandXML (written as text): lxml, against what LandXML 1.2 asks of a TIN surface;
* XLSX (written by openpyxl) and CSV (Python's csv): GDAL's XLSX and CSV drivers.

One seeded synthetic run (tests/deliverables/conftest.py), exported once for the module."""

from __future__ import annotations

import io
import sqlite3
import struct
import zipfile

import numpy as np
import pytest

from georef_core.deliverables.contours import trace_contours
from georef_core.deliverables.exports import export_run
from georef_core.deliverables.surface import read_surface

from . import conftest as C

NS = {"lx": "http://www.landxml.org/schema/LandXML-1.2"}
SURVEYED = {n: (x, y, round(float(C.truth_height(x, y)), 3), role) for n, role, x, y in C.POINTS}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    run, survey = C.make_run_folder(tmp_path_factory.mktemp("independent"))
    m = export_run(run, survey_dir=survey, interval_m=0.5, tin_spacing_m=1.0)
    cs = trace_contours(read_surface(run / "dense" / "dsm.tif", "DSM"), 0.5, 5, None)
    return run / "exports", m, cs


def _ogr(path, layer=None):
    """(field name -> values, shapely geometries) as GDAL/OGR reads the file."""
    import pyogrio
    import shapely

    meta, _, wkb, values = pyogrio.raw.read(path, layer=layer, return_fids=True)
    geoms = shapely.from_wkb(wkb) if wkb is not None else None
    return dict(zip(meta["fields"], values)), geoms


def _dxf_pairs(path):
    """(group code, value) pairs of a DXF file: the format's own structure, read without any DXF library."""
    lines = path.read_text(encoding="utf-8").splitlines()
    return [(int(lines[i].strip()), lines[i + 1].strip()) for i in range(0, len(lines) - 1, 2)]


def _dxf_header(pairs):
    head, var = {}, None
    for code, value in pairs[pairs.index((2, "HEADER")) + 1:]:
        if code == 0 and value == "ENDSEC":
            break
        if code == 9:
            var = value
            if var == "$CUSTOMPROPERTY":
                head.setdefault("custom", []).append(None)
            continue
        if var == "$CUSTOMPROPERTYTAG":
            head.setdefault("tags", []).append(value)
        elif var == "$CUSTOMPROPERTY":
            head["custom"][-1] = value
        else:
            head.setdefault(var, {})[code] = value
    head["custom"] = dict(zip(head.pop("tags", []), head.get("custom", [])))
    return head


def _active_vport(pairs):
    """The *Active VPORT's centre (12, 22) and view height (40)."""
    for k, (code, value) in enumerate(pairs):
        if (code, value) == (2, "*Active"):
            out = {}
            for c, v in pairs[k + 1:]:
                if c == 0:
                    break
                out.setdefault(c, float(v) if c in (12, 22, 40) else v)
            return out
    return None


def test_dxf_as_gdal_reads_it(exported):
    import rasterio.crs

    out, m, cs = exported
    f, g = _ogr(out / "site.dxf")
    layers = np.asarray(f["Layer"])
    kinds = {(lay, geom.geom_type, sub) for lay, geom, sub in zip(layers, g, f["SubClasses"])}
    assert kinds == {("CONTOUR_MINOR", "LineString", "AcDbEntity:AcDbPolyline"),
                     ("CONTOUR_INDEX", "LineString", "AcDbEntity:AcDbPolyline"),
                     ("CONTOUR_LABEL", "Point", "AcDbEntity:AcDbText:AcDbText"),
                     ("STOCKPILE_OUTLINE", "LineString", "AcDbEntity:AcDb3dPolyline"),
                     ("CHECK_POINTS", "Point", "AcDbEntity:AcDbPoint"),
                     ("CONTROL_POINTS", "Point", "AcDbEntity:AcDbPoint"),
                     ("POINT_LABELS", "Point", "AcDbEntity:AcDbText:AcDbText")}

    # contours: one LWPOLYLINE per traced line, in order, at its level (OGR puts the elevation in z), to the mm
    contours = [geom for lay, geom in zip(layers, g) if lay.startswith("CONTOUR_") and lay != "CONTOUR_LABEL"]
    assert len(contours) == len(cs.lines) == m["contours"]["lines"]
    assert sum(lay == "CONTOUR_INDEX" for lay in layers) == m["contours"]["index_lines"] > 0
    for geom, line in zip(contours, cs.lines):
        xyz = np.asarray(geom.coords)
        ref = line.xy_m
        if line.closed and np.abs(ref[0] - ref[-1]).max() > 1e-9:
            ref = np.vstack([ref, ref[:1]])
        assert xyz.shape == (len(ref), 3) and np.abs(xyz[:, :2] - ref).max() < 1e-3
        assert np.all(xyz[:, 2] == line.level_m) and (line.level_m / 0.5) % 1 == 0
    # index labels: the level of an index contour, placed at that level
    labels = [(t, geom) for lay, t, geom in zip(layers, f["Text"], g) if lay == "CONTOUR_LABEL"]
    index_levels = {c.level_m for c in cs.lines if c.index}
    assert labels and all(float(t) in index_levels and geom.z == float(t) for t, geom in labels)

    # stockpile outlines: closed 3-D polylines draped on the surface (ground truth within 10 cm: DSM noise)
    outlines = [geom for lay, geom in zip(layers, g) if lay == "STOCKPILE_OUTLINE"]
    assert len(outlines) == 2
    for geom in outlines:
        xyz = np.asarray(geom.coords)
        assert geom.is_closed and len(xyz) == 5
        assert np.abs(xyz[:, 2] - C.truth_height(xyz[:, 0], xyz[:, 1])).max() < 0.1
    assert {tuple(np.round(np.asarray(o.coords)[:4, :2].min(axis=0), 3)) for o in outlines} == \
        {tuple(min(p) for p in zip(*ring)) for ring in C.PILES.values()}

    # surveyed points to the mm with their heights, labelled by name
    for lay, role in (("CHECK_POINTS", "check"), ("CONTROL_POINTS", "control")):
        got = sorted(tuple(np.round(geom.coords[0], 3)) for ly, geom in zip(layers, g) if ly == lay)
        assert got == sorted((x, y, h) for x, y, h, r in SURVEYED.values() if r == role)
    assert sorted(t for lay, t in zip(layers, f["Text"]) if lay == "POINT_LABELS") == sorted(SURVEYED)

    # the CRS: GDAL's DXF driver reads none, the .prj beside it (GDAL's own WKT parser) names EPSG:32632
    assert rasterio.crs.CRS.from_wkt((out / "site.prj").read_text()).to_epsg() == 32632


def test_dxf_header_extents_view_and_audit(exported):
    import ezdxf
    from ezdxf import recover

    out, _, _ = exported
    path = out / "site.dxf"
    pairs = _dxf_pairs(path)
    head = _dxf_header(pairs)
    assert head["$ACADVER"][1] == "AC1027" and head["$INSUNITS"][70] == "6" and head["$MEASUREMENT"][70] == "1"
    assert head["custom"]["GEOREF_CRS"] == "EPSG:32632" and "ellipsoidal" in head["custom"]["GEOREF_VERTICAL_DATUM"]
    # the extents enclose every entity GDAL reads (before: left at +-1e20, so a CAD program opened the drawing
    # looking at 0,0, 5000 km from the site)
    _, g = _ogr(path)
    b = np.array([geom.bounds for geom in g])
    lo = np.array([float(head["$EXTMIN"][c]) for c in (10, 20)])
    hi = np.array([float(head["$EXTMAX"][c]) for c in (10, 20)])
    assert np.all(lo <= b[:, :2].min(axis=0) + 1e-6) and np.all(hi >= b[:, 2:].max(axis=0) - 1e-6)
    assert np.all(hi - lo < 61.0) and lo[0] > 499_999 and lo[1] > 4_999_999
    vp = _active_vport(pairs)
    assert vp is not None and lo[0] <= vp[12] <= hi[0] and lo[1] <= vp[22] <= hi[1]
    assert (hi - lo).max() <= vp[40] <= 2 * (hi - lo).max()

    doc, auditor = recover.readfile(path)
    assert not auditor.has_errors and not auditor.fixes
    audit = ezdxf.readfile(path).audit()
    assert not audit.has_errors and not audit.has_fixes


def _gpkg_geometry(blob: bytes):
    """A GeoPackage geometry blob (GeoPackage 1.2 section 2.1.3): 'GP', version, flags, srs_id, envelope, WKB."""
    import shapely

    assert blob[:2] == b"GP" and blob[2] == 0
    flags = blob[3]
    order = "<" if flags & 1 else ">"
    srs_id = struct.unpack(order + "i", blob[4:8])[0]
    envelope = {0: 0, 1: 32, 2: 48, 3: 48, 4: 64}[(flags >> 1) & 7]
    return srs_id, shapely.from_wkb(blob[8 + envelope:])


def test_geopackage_as_sqlite_reads_it(exported):
    from pyproj import CRS

    out, m, cs = exported
    con = sqlite3.connect(out / "site.gpkg")
    try:
        assert con.execute("PRAGMA application_id").fetchone()[0] == 0x47504B47          # "GPKG"
        assert con.execute("PRAGMA user_version").fetchone()[0] >= 10200
        contents = {r[0]: r[1] for r in con.execute("SELECT table_name, data_type FROM gpkg_contents")}
        assert contents == {"contours": "features", "stockpiles": "features", "points": "features"}
        cols = {r[0]: r[1:] for r in con.execute(
            "SELECT table_name, column_name, geometry_type_name, srs_id, z FROM gpkg_geometry_columns")}
        assert {t: (c[1], c[3]) for t, c in cols.items()} == \
            {"contours": ("LINESTRING", 1), "stockpiles": ("POLYGON", 1), "points": ("POINT", 1)}
        srs_ids = {c[2] for c in cols.values()}
        assert len(srs_ids) == 1
        srs_id = srs_ids.pop()
        wkt1, wkt2 = con.execute("SELECT definition, definition_12_063 FROM gpkg_spatial_ref_sys WHERE srs_id = ?",
                                 (srs_id,)).fetchone()
        # WKT2 (the crs_wkt extension): the 3-D CRS, UTM 32N with its ellipsoidal height axis
        crs3 = CRS.from_wkt(wkt2)
        assert len(crs3.axis_info) == 3 and crs3.to_2d().to_epsg() == 32632
        # WKT1 (core GeoPackage, all a reader without the extension sees): was "undefined", now the horizontal CRS
        assert wkt1 != "undefined" and CRS.from_wkt(wkt1).to_epsg() == 32632

        types = {t: {r[1]: r[2] for r in con.execute(f'PRAGMA table_info("{t}")')} for t in contents}
        assert types["contours"]["elevation_m"] == "REAL" and types["stockpiles"]["volume_m3"] == "REAL"
        assert types["points"]["name"] == "TEXT" and types["points"]["dz_m"] == "REAL"

        rows = con.execute('SELECT geom, elevation_m, "index" FROM contours ORDER BY fid').fetchall()
        assert len(rows) == len(cs.lines)
        for (blob, level, index), line in zip(rows, cs.lines):
            sid, geom = _gpkg_geometry(blob)
            xyz = np.asarray(geom.coords)
            assert sid == srs_id and level == line.level_m and bool(index) == line.index
            assert np.all(xyz[:, 2] == level) and np.abs(xyz[:, :2] - line.xy_m).max() < 1e-6
        pts = {name: (_gpkg_geometry(blob)[1], role, dz) for blob, name, role, dz in
               con.execute("SELECT geom, name, role, dz_m FROM points")}
        assert set(pts) == set(SURVEYED)
        for name, (geom, role, dz) in pts.items():
            x, y, h, r = SURVEYED[name]
            assert role == r and np.allclose(geom.coords[0], (x, y, h), atol=1e-3)
        assert pts["CK1"][2] == pytest.approx(0.03) and pts["CP1"][2] is None
        vols = dict(con.execute("SELECT name, volume_m3 FROM stockpiles").fetchall())
        assert vols == {"north pile": 10.0, "south pile": 11.0}
    finally:
        con.close()


def test_shapefiles_as_pyshp_reads_them(exported):
    import shapefile
    from pyproj import CRS

    out, _, cs = exported
    with zipfile.ZipFile(out / "shapefiles.zip") as z:
        files = {n: z.read(n) for n in z.namelist()}

    def reader(stem):
        return shapefile.Reader(shp=io.BytesIO(files[f"{stem}.shp"]), shx=io.BytesIO(files[f"{stem}.shx"]),
                                dbf=io.BytesIO(files[f"{stem}.dbf"]), encoding=files[f"{stem}.cpg"].decode())

    for stem in ("contours", "stockpiles", "points"):
        prj = files[f"{stem}.prj"].decode()            # ESRI WKT: PROJCS + VERTCS (ellipsoidal heights: WGS_1984)
        crs = CRS.from_wkt(prj)
        assert 'VERTCS["WGS_1984"' in prj and len(crs.axis_info) == 3 and crs.to_2d().to_epsg() == 32632
    r = reader("contours")
    assert r.shapeType == shapefile.POLYLINEZ and len(r) == len(cs.lines)
    assert [(f.name, f.field_type) for f in r.fields[1:]][:2] == [("elev_m", "N"), ("index", "N")]
    for sr, line in zip(r.iterShapeRecords(), cs.lines):
        assert sr.record["elev_m"] == line.level_m and sr.record["index"] == int(line.index)
        assert np.all(np.asarray(sr.shape.z) == line.level_m)
        assert np.abs(np.asarray(sr.shape.points) - line.xy_m).max() < 1e-6
    r = reader("stockpiles")
    assert r.shapeType == shapefile.POLYGONZ and len(r) == 2
    for sr in r.iterShapeRecords():
        ring = np.asarray(sr.shape.points)
        area2 = np.sum(ring[:-1, 0] * ring[1:, 1] - ring[1:, 0] * ring[:-1, 1])
        assert area2 < 0                                 # outer rings clockwise (the Shapefile rule)
        assert sr.record["area_m2"] in (100.0, 150.0) and sr.record["vdatum"].startswith("ellipsoidal")
        assert np.abs(np.asarray(sr.shape.z) - C.truth_height(ring[:, 0], ring[:, 1])).max() < 0.1
    r = reader("points")
    assert r.shapeType == shapefile.POINTZ
    got = {sr.record["name"]: (*sr.shape.points[0], sr.shape.z[0]) for sr in r.iterShapeRecords()}
    assert {n: tuple(round(v, 3) for v in p) for n, p in got.items()} == \
        {n: (x, y, h) for n, (x, y, h, _) in SURVEYED.items()}


def test_kmz_as_gdal_reads_it(exported):
    import rasterio
    from pyproj import Transformer

    out, m, _ = exported
    f, g = _ogr(out / "ortho.kmz")
    assert list(f["icon"]) == ["files/ortho.png"] and len(g) == 1
    west, south, east, north = g[0].bounds
    tr = Transformer.from_crs(f"EPSG:{C.EPSG}", "EPSG:4326", always_xy=True)
    lon, lat = tr.transform([C.X0, C.X0 + 60, C.X0, C.X0 + 60], [C.Y0, C.Y0, C.Y0 - 60, C.Y0 - 60])
    px = (east - west) / m["kmz"]["width_px"]
    assert abs(west - min(lon)) <= px and abs(east - max(lon)) <= px
    assert abs(south - min(lat)) <= px and abs(north - max(lat)) <= px
    # the picture where it belongs: GDAL's KML super-overlay reader, sampled at orthophoto pixels
    x = C.X0 + np.array([10.1, 30.1, 50.1, 30.1])
    y = C.Y0 - np.array([30.1, 10.1, 50.1, 1.0])                 # the last in the no-data strip (north 4 m)
    lon, lat = tr.transform(x, y)
    with rasterio.open(out / "ortho.kmz") as ds:
        assert ds.crs.to_epsg() == 4326 and ds.count == 4
        px = np.array(list(ds.sample(list(zip(lon, lat)))))
    col, row = ((x - C.X0) / 0.2).astype(int), ((C.Y0 - y) / 0.2).astype(int)
    want_r, want_g = np.linspace(0, 255, 300)[col], np.linspace(0, 255, 300)[row]
    assert np.all(px[:3, 3] == 255) and px[3, 3] == 0
    assert np.abs(px[:3, 0] - want_r[:3]).max() <= 10 and np.abs(px[:3, 1] - want_g[:3]).max() <= 10


def test_landxml_tin_as_lxml_reads_it(exported):
    import datetime

    from lxml import etree

    out, m, _ = exported
    root = etree.parse(str(out / "surface.xml")).getroot()
    assert root.tag == f"{{{NS['lx']}}}LandXML" and root.get("version") == "1.2"
    datetime.date.fromisoformat(root.get("date"))
    datetime.time.fromisoformat(root.get("time"))
    assert root.find("lx:Units/lx:Metric", NS).get("linearUnit") == "meter"
    assert root.find("lx:CoordinateSystem", NS).get("epsgCode") == "32632"
    surfaces = root.findall("lx:Surfaces/lx:Surface", NS)
    assert len(surfaces) == 1 and surfaces[0].get("name")
    d = surfaces[0].find("lx:Definition", NS)
    assert d.get("surfType") == "TIN"
    pts = d.findall("lx:Pnts/lx:P", NS)
    ids = [int(p.get("id")) for p in pts]
    assert len(set(ids)) == len(ids) == m["tin"]["points"]
    nez = np.array([[float(v) for v in p.text.split()] for p in pts])
    # LandXML's order is northing easting elevation: the heights sit on the truth surface at (easting, northing)
    dz = nez[:, 2] - C.truth_height(nez[:, 1], nez[:, 0])
    assert np.sqrt(np.mean(dz ** 2)) < 0.01
    assert float(d.get("elevMin")) == pytest.approx(nez[:, 2].min(), abs=1e-3)
    assert float(d.get("elevMax")) == pytest.approx(nez[:, 2].max(), abs=1e-3)
    faces = np.array([[int(v) for v in f.text.split()] for f in d.findall("lx:Faces/lx:F", NS)])
    assert faces.shape == (m["tin"]["faces"], 3)
    assert set(np.unique(faces)) <= set(ids)                     # every face names points that exist
    pos = {i: k for k, i in enumerate(ids)}
    e, n = nez[:, 1], nez[:, 0]
    k = np.vectorize(pos.get)(faces)
    cross = (e[k[:, 1]] - e[k[:, 0]]) * (n[k[:, 2]] - n[k[:, 0]]) - (e[k[:, 2]] - e[k[:, 0]]) * (n[k[:, 1]] - n[k[:, 0]])
    assert np.all(cross > 0)                                     # no degenerate face, all counter-clockwise
    assert float(d.get("area2DSurf")) == pytest.approx(0.5 * cross.sum(), abs=0.01)


def test_tables_as_gdal_reads_them(exported):
    out, _, _ = exported
    f, _ = _ogr(out / "site.xlsx", layer="Points")
    got = {n: (e, no, h, r) for n, e, no, h, r in zip(f["name"], f["easting_m"], f["northing_m"], f["height_m"],
                                                       f["role"])}
    assert {n: (float(e), float(no), round(float(h), 3), r) for n, (e, no, h, r) in got.items()} == \
        {n: (x, y, h, r) for n, (x, y, h, r) in SURVEYED.items()}
    assert np.isnan(f["dz_m"][list(f["name"]).index("CP1")]) and 0.03 in list(f["dz_m"])
    f, _ = _ogr(out / "site.xlsx", layer="Volumes")
    assert dict(zip(f["name"], map(float, f["volume_m3"]))) == {"north pile": 10.0, "south pile": 11.0}
    f, _ = _ogr(out / "site.xlsx", layer="About")
    about = dict(zip(*f.values()))
    assert about["crs"] == "EPSG:32632" and "ellipsoidal" in about["heights"]
    # no server folder in a deliverable (it held the run folder's absolute path): its name only
    assert about["run"] == "run" and not any("/" in str(v) for v in about.values())
    f, _ = _ogr(out / "points.csv")
    assert {n: (float(e), float(no), float(h)) for n, e, no, h in
            zip(f["name"], f["easting_m"], f["northing_m"], f["height_m"])} == \
        {n: (x, y, h) for n, (x, y, h, _) in SURVEYED.items()}
    f, _ = _ogr(out / "volumes.csv")
    assert [float(v) for v in f["sigma_m3"]] == [0.2, 0.2]


def test_dxf_names_outside_ascii(tmp_path):
    """Point names and layers in any script (a Japanese site's 基準点): the R2013 DXF is UTF-8, as AutoCAD reads it
    from R2007 on. GDAL's DXF driver decodes by $DWGCODEPAGE (ANSI_1252) whatever the version, so GDAL and QGIS need
    DXF_ENCODING=UTF-8 (docs/deliverables.md); with it they read the names as written."""
    import ezdxf
    import pyogrio
    from pyproj import CRS

    from georef_core.deliverables.dxf_writer import DxfPoint, DxfPolyline, write_dxf

    path = tmp_path / "names.dxf"
    write_dxf(path, [DxfPolyline("切土_CUT", np.array([[0.0, 0.0, 1.0], [10.0, 0.0, 2.0], [10.0, 10.0, 3.0]]), True)],
              [DxfPoint("CHECK_POINTS", (1.0, 2.0, 3.0), "基準点1 Böschung")], crs=CRS.from_epsg(6677),
              vertical_datum="JGD2011 (vertical) height (EPSG:6695)")
    assert path.read_bytes().decode("utf-8")                   # valid UTF-8 throughout
    pyogrio.set_gdal_config_options({"DXF_ENCODING": "UTF-8"})
    try:
        f, g = _ogr(path)
    finally:
        pyogrio.set_gdal_config_options({"DXF_ENCODING": None})
    assert set(f["Layer"]) == {"切土_CUT", "CHECK_POINTS", "POINT_LABELS"}
    assert [t for t in f["Text"] if t] == ["基準点1 Böschung"]
    assert ezdxf.readfile(path).modelspace().query("TEXT")[0].dxf.text == "基準点1 Böschung"
