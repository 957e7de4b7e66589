"""`georef export` / the exports step on a small run folder (tests/deliverables/conftest.py): every file opened
by an independent reader (ezdxf, pyogrio, lxml against a LandXML 1.2 schema subset, zipfile + KML,
openpyxl) and its content checked against the scene (counts, heights, CRS with its vertical part)."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from georef_core.cli.main import main
from georef_core.deliverables.exports import export_run

from . import conftest as C

XSD = Path(__file__).resolve().parents[1] / "data" / "landxml" / "LandXML-1.2-subset.xsd"
NS = {"lx": "http://www.landxml.org/schema/LandXML-1.2", "kml": "http://www.opengis.net/kml/2.2"}


@pytest.fixture()
def exported(run_folder):
    run, survey = run_folder
    m = export_run(run, survey_dir=survey, interval_m=0.5, tin_spacing_m=1.0)
    return run / "exports", m


def test_every_export_opens_in_an_independent_reader(exported):
    import ezdxf
    import openpyxl
    import pyogrio
    from lxml import etree
    from pyproj import CRS, Transformer

    out, m = exported
    assert set(m["written"]) == {"geojson", "dxf", "gpkg", "shp", "landxml", "kmz", "xlsx", "csv"}
    assert m["skipped"] == {} and m["crs"] == "EPSG:32632" and "ellipsoidal" in m["vertical_datum"]
    n_contours = m["contours"]["lines"]

    # DXF: contours, the two stockpile outlines (closed 3-D polylines draped on the surface), the points
    doc = ezdxf.readfile(out / "site.dxf")
    msp = doc.modelspace()
    assert len(msp.query("LWPOLYLINE")) == n_contours
    outlines = msp.query('POLYLINE[layer=="STOCKPILE_OUTLINE"]')
    assert len(outlines) == 2 and all(o.is_closed for o in outlines)
    for o in outlines:
        v = np.array([p.dxf.location for p in o.vertices])
        assert np.abs(v[:, 2] - C.truth_height(v[:, 0], v[:, 1])).max() < 0.1
    checks = msp.query('POINT[layer=="CHECK_POINTS"]')
    assert len(checks) == 2 and len(msp.query('POINT[layer=="CONTROL_POINTS"]')) == 1
    assert {t.dxf.text for t in msp.query('TEXT[layer=="POINT_LABELS"]')} == {"CP1", "CK1", "CK2"}
    assert CRS.from_wkt((out / "site.prj").read_text()).to_epsg() == 32632

    # GeoPackage: three layers, each in the 3-D CRS (ellipsoidal heights)
    layers = dict(pyogrio.list_layers(out / "site.gpkg"))
    assert set(layers) == {"contours", "stockpiles", "points"}
    for name in layers:
        info = pyogrio.read_info(out / "site.gpkg", layer=name)
        crs = CRS.from_user_input(info["crs"])
        assert crs.to_2d().to_epsg() == 32632 and len(crs.axis_info) == 3
    _, _, _, f = pyogrio.raw.read(out / "site.gpkg", layer="stockpiles")
    info = pyogrio.read_info(out / "site.gpkg", layer="stockpiles")
    vols = dict(zip(info["fields"], f))
    assert sorted(vols["volume_m3"]) == [10.0, 11.0]

    # Shapefiles (zipped) with .prj carrying the vertical datum
    with zipfile.ZipFile(out / "shapefiles.zip") as z:
        names = set(z.namelist())
    assert {"contours.shp", "contours.prj", "points.dbf", "stockpiles.shx"} <= names
    sinfo = pyogrio.read_info(f"/vsizip/{out / 'shapefiles.zip'}/points.shp")
    assert sinfo["features"] == 3 and CRS.from_user_input(sinfo["crs"]).to_2d().to_epsg() == 32632

    # LandXML: valid against the schema subset, metric, EPSG code, TIN heights on the truth surface
    schema = etree.XMLSchema(etree.parse(str(XSD)))
    tree = etree.parse(str(out / "surface.xml"))
    assert schema.validate(tree), schema.error_log
    assert tree.find("lx:Units/lx:Metric", NS).get("linearUnit") == "meter"
    cs = tree.find("lx:CoordinateSystem", NS)
    assert cs.get("epsgCode") == "32632" and "ellipsoidal" in cs.get("verticalDatum")
    pnts = tree.findall(".//lx:Pnts/lx:P", NS)
    nez = np.array([[float(v) for v in p.text.split()] for p in pnts])
    assert len(pnts) == m["tin"]["points"]
    assert np.sqrt(np.mean((nez[:, 2] - C.truth_height(nez[:, 1], nez[:, 0])) ** 2)) < 0.02   # N E Z order
    assert not C.in_hole(nez[:, 1], nez[:, 0]).any()
    faces = np.array([[int(v) for v in f.text.split()] for f in tree.findall(".//lx:Faces/lx:F", NS)])
    assert faces.min() == 1 and faces.max() <= len(pnts) and len(faces) == m["tin"]["faces"]
    assert m["tin"]["deviation_from_surface"]["rms_m"] < 0.04    # TIN vs the 2 cm-noise DSM it stands for

    # KMZ: doc.kml first, a GroundOverlay whose LatLonBox covers the orthophoto's corners
    with zipfile.ZipFile(out / "ortho.kmz") as z:
        assert z.namelist()[0] == "doc.kml"
        kml = etree.fromstring(z.read("doc.kml"))
        png = z.read("files/ortho.png")
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    box = {k: float(kml.find(f".//kml:LatLonBox/kml:{k}", NS).text) for k in ("north", "south", "east", "west")}
    tr = Transformer.from_crs(32632, 4326, always_xy=True)
    lon, lat = tr.transform([C.X0, C.X0 + 60, C.X0, C.X0 + 60], [C.Y0, C.Y0, C.Y0 - 60, C.Y0 - 60])
    px = (box["east"] - box["west"]) / m["kmz"]["width_px"]           # one overlay pixel (0.2 m), in degrees
    assert abs(box["west"] - min(lon)) <= px and abs(box["east"] - max(lon)) <= px
    assert abs(box["south"] - min(lat)) <= px and abs(box["north"] - max(lat)) <= px

    # XLSX: the points with their residuals, the volumes, the CRS stated
    wb = openpyxl.load_workbook(out / "site.xlsx")
    about = {r[0]: r[1] for r in wb["About"].iter_rows(min_row=2, values_only=True)}
    assert about["crs"] == "EPSG:32632" and "ellipsoidal" in about["heights"]
    rows = list(wb["Points"].iter_rows(values_only=True))
    head = rows[0]
    pts = {r[0]: dict(zip(head, r)) for r in rows[1:]}
    assert set(pts) == {"CP1", "CK1", "CK2"} and pts["CK1"]["dz_m"] == pytest.approx(0.03)
    assert pts["CK1"]["easting_m"] == pytest.approx(C.X0 + 30.0)
    assert len(list(wb["Volumes"].iter_rows(min_row=2))) == 2

    # GeoJSON points: RFC 7946 lon/lat, heights of the surveyed points
    fc = json.loads((out / "points.geojson").read_text())
    c = np.array([f["geometry"]["coordinates"] for f in fc["features"]])
    assert np.all((c[:, 0] > 8.9) & (c[:, 0] < 9.1) & (c[:, 1] > 45) & (c[:, 1] < 45.2))
    manifest = json.loads((out / "exports.json").read_text())
    assert manifest["written"] == m["written"]


def test_export_says_what_it_skipped(tmp_path):
    run = tmp_path / "run"
    C.write_surface(run / "dense" / "dsm.tif", hole=False)
    m = export_run(run, formats=["kmz", "xlsx", "dxf", "landxml"], interval_m=1.0, surface="dtm")
    assert set(m["written"]) == {"dxf", "landxml"}
    assert "no orthophoto" in m["skipped"]["kmz"] and "no points and no volumes" in m["skipped"]["xlsx"]
    assert "DSM instead" in m["skipped"]["dtm"] and "points" in m["skipped"]
    # with a DTM (here the DSM 0.5 m lower) and surface=dtm, the contours are the DTM's
    C.write_surface(run / "dtm" / "dtm.tif", hole=False)
    import rasterio

    with rasterio.open(run / "dtm" / "dtm.tif", "r+") as ds:
        ds.write(ds.read(1) - 0.5, 1)
    m2 = export_run(run, formats=["gpkg"], interval_m=1.0, surface="dtm")
    assert m2["surface"] == "DTM" and m2["surface_file"] == "dtm/dtm.tif"
    # no server path in the manifest a client downloads
    manifest_text = (run / "exports" / "exports.json").read_text()
    assert str(run.resolve()) not in manifest_text and str(run) not in manifest_text, manifest_text
    with pytest.raises(Exception, match="unknown export format"):
        export_run(run, formats=["pdf"])


def test_cli_contours_and_export(run_folder, tmp_path, capsys):
    import ezdxf

    run, survey = run_folder
    dsm = run / "dense" / "dsm.tif"
    assert main(["contours", "--dsm", str(dsm), "--interval", "1", "--out", str(tmp_path / "c.dxf")]) == 0
    assert "index" in capsys.readouterr().out
    assert len(ezdxf.readfile(tmp_path / "c.dxf").modelspace().query('LWPOLYLINE[layer=="CONTOUR_INDEX"]')) >= 2
    assert main(["export", str(run), "--format", "dxf,csv", "--format", "kmz", "--survey", str(survey),
                 "--interval", "1", "--to", str(tmp_path / "x")]) == 0
    out = capsys.readouterr().out
    assert "site.dxf" in out and "points.csv" in out and "ortho.kmz" in out
    assert sorted(p.name for p in (tmp_path / "x").iterdir()) == ["exports.json", "ortho.kmz", "points.csv",
                                                                  "site.dxf", "site.prj", "volumes.csv"]
    # bad input: the file is named
    assert main(["contours", "--dsm", str(tmp_path / "nope.tif"), "--out", str(tmp_path / "c.gpkg")]) == 2
    assert "nope.tif: file not found" in capsys.readouterr().err
    assert main(["export", str(tmp_path / "no_run")]) == 2
    assert "no_run: not a folder" in capsys.readouterr().err


def test_step_writes_its_declared_outputs(run_folder):
    from georef_core.steps.contract import Workspace, get_spec
    from georef_core.steps.exports import step_entry

    run, survey = run_folder
    ws = Workspace(survey, run)
    s = step_entry(ws, {"interval_m": 1.0, "formats": "dxf,gpkg,landxml,xlsx,csv,geojson,shp,kmz"}, None,
                   {"crs": "EPSG:32632"})
    assert s["skipped"] == {} and s["contours"]["interval_m"] == 1.0
    spec = get_spec("exports")
    for o in spec.outputs:
        assert ws.path("exports", o.key).is_file(), o.path
    for p in spec.products:
        assert (run / p.endpoint.removeprefix("files/")).is_file()
    with pytest.raises(Exception, match="formats: pdf"):
        step_entry(ws, {"formats": "dxf,pdf"}, None, {})
