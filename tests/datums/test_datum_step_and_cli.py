"""The datum step on a small run folder (DSM, point cloud, surveyed points, residuals) and `georef datum`."""

from __future__ import annotations

import csv
import json

import numpy as np
import pyproj
import pytest
import rasterio
from rasterio.transform import from_origin

from georef_core.cli.main import main
from georef_core.datums import vertical_datum as vd
from georef_core.datums.grids import configure_pyproj
from georef_core.dense.cog_writer import HEIGHT_TAGS, write_cog
from georef_core.dense.point_cloud_io import write_point_cloud
from georef_core.steps.contract import Workspace, get_spec

E0, N0 = 448_000.0, 5_412_000.0


def _undulation(e, n):
    configure_pyproj()
    lon, lat = pyproj.Transformer.from_crs("EPSG:32631", "EPSG:4326", always_xy=True).transform(e, n)
    return vd.geoid_undulation_m("egm96", lat, lon)


def _run_folder(tmp_path):
    survey, out = tmp_path / "survey", tmp_path / "run"
    (survey / "gcp").mkdir(parents=True)
    (survey / "survey.json").write_text(json.dumps({"points_crs": "EPSG:32631"}))
    (survey / "gcp" / "points.csv").write_text("name,easting_m,northing_m,ellipsoidal_height_m,role\n"
                                               f"G1,{E0 + 10},{N0 + 20},150.000,control\n"
                                               f"C1,{E0 + 80},{N0 + 60},151.250,check\n")
    ws = Workspace(survey, out)
    ws.path("georef", "residuals_json").parent.mkdir(parents=True, exist_ok=True)
    ws.path("georef", "residuals_json").write_text(json.dumps({"crs": "EPSG:32631", "points": [
        {"name": "C1", "role": "check", "dx_m": 0.004, "dy_m": -0.002, "dz_m": 0.011, "d3_m": 0.0119}]}))
    z = np.full((50, 50), 150.0, np.float32)
    write_cog(ws.path("dense", "dsm"), z, from_origin(E0, N0 + 100, 2.0, 2.0), 32631, nodata=-9999.0,
              tags=HEIGHT_TAGS)
    xyz = np.column_stack([E0 + np.arange(100.0), N0 + np.arange(100.0), np.full(100, 150.0)])
    write_point_cloud(ws.path("dense", "point_cloud"), xyz, np.zeros((100, 3), np.uint8), 32631)
    return ws


def test_datum_step_writes_orthometric_copies_naming_the_datum(tmp_path):
    ws = _run_folder(tmp_path)
    fn = get_spec("datum").resolve()
    summary = fn(ws, {}, None, {"crs": "EPSG:32631", "vertical_datum": "EPSG:5773"})
    assert summary["vertical_datum"] == "EPSG:5773" and set(summary["files"]) == {"dsm", "point_cloud",
                                                                                  "ground_points"}
    with rasterio.open(ws.path("datum", "dsm")) as src:
        assert vd.datum_of_crs(pyproj.CRS.from_wkt(src.crs.to_wkt())) is vd.EGM96
        got = src.read(1)[25, 25]
    e, n = E0 + 51.0, N0 + 100 - 51.0
    assert abs(got - (150.0 - _undulation(e, n))) <= 1e-3
    rows = list(csv.DictReader(open(ws.path("datum", "points_csv"))))
    assert [r["name"] for r in rows] == ["G1", "C1"]
    assert all(r["vertical_datum"] == "EPSG:5773" and r["horizontal_crs"] == "EPSG:32631" for r in rows)
    h_want = 151.25 - _undulation(E0 + 80, N0 + 60)
    assert abs(float(rows[1]["height_m"]) - h_want) <= 1e-3 and float(rows[1]["dz_m"]) == 0.011
    assert rows[0]["dz_m"] == ""
    gj = json.loads(ws.path("datum", "points_geojson").read_text())
    assert gj["vertical_datum"] == "EPSG:5773" and abs(gj["features"][1]["geometry"]["coordinates"][2] - h_want) < 1e-3
    # a site in ellipsoidal heights: nothing to do
    assert fn(ws, {}, None, {"crs": "EPSG:32631", "vertical_datum": None})["skipped"] is True


def test_datum_step_missing_grid_fails_naming_it(tmp_path):
    ws = _run_folder(tmp_path)
    if vd.is_available("EPSG:5701"):
        pytest.skip("the OSGM15 grid is installed here")
    with pytest.raises(vd.GridMissingError, match="uk_os_OSGM15_GB"):
        get_spec("datum").resolve()(ws, {"vertical_datum": "EPSG:5701"}, None, {"crs": "EPSG:32631"})
    assert not ws.path("datum", "dsm").exists()


def test_cli_convert_calibrate_apply(tmp_path, capsys):
    write_cog(tmp_path / "dsm.tif", np.full((20, 20), 120.0, np.float32), from_origin(E0, N0 + 40, 2.0, 2.0), 32631,
              tags=HEIGHT_TAGS)
    assert main(["datum", "convert", "--in", str(tmp_path / "dsm.tif"), "--to", "egm96",
                 "--out", str(tmp_path / "dsm_egm96.tif")]) == 0
    assert "EGM96 height (EPSG:5773)" in capsys.readouterr().out
    with rasterio.open(tmp_path / "dsm_egm96.tif") as src:
        assert abs(src.read(1)[10, 10] - (120.0 - _undulation(E0 + 21.0, N0 + 19.0))) <= 1e-3
    assert main(["datum", "convert", "--in", str(tmp_path / "dsm.tif"), "--to", "EPSG:4326",
                 "--out", str(tmp_path / "x.tif")]) == 2
    assert "not a vertical CRS" in capsys.readouterr().err

    pairs = tmp_path / "pairs.csv"
    pairs.write_text("name,easting_m,northing_m,height_m,local_e_m,local_n_m,local_h_m\n"
                     f"A,{E0},{N0},100.0,1000.000,2000.000,52.000\n"
                     f"B,{E0 + 300},{N0},101.0,1300.004,2000.003,53.010\n"
                     f"C,{E0 + 300},{N0 + 300},102.0,1299.998,2300.002,54.000\n"
                     f"D,{E0},{N0 + 300},103.0,999.997,2299.996,54.985\n")
    cal = tmp_path / "calibration.json"
    assert main(["datum", "calibrate", "--points", str(pairs), "--out", str(cal), "--crs", "EPSG:32631",
                 "--height-datum", "egm96"]) == 0
    text = capsys.readouterr().out
    assert "inclined plane" in text and "RMS" in text
    doc = json.loads(cal.read_text())
    assert doc["height_datum"] == "EPSG:5773" and len(doc["points"]) == 4
    assert max(abs(p["residual_m"]["dE_m"]) for p in doc["points"]) < 0.01
    pts = tmp_path / "pts.csv"
    pts.write_text(f"name,easting_m,northing_m,height_m\nA,{E0},{N0},100.0\nM,{E0 + 150},{N0 + 150},101.5\n")
    assert main(["datum", "apply", "--calibration", str(cal), "--in", str(pts), "--out", str(tmp_path / "l.csv")]) == 0
    rows = list(csv.DictReader(open(tmp_path / "l.csv")))
    assert abs(float(rows[0]["local_e_m"]) - 1000.0) < 0.01 and abs(float(rows[0]["local_h_m"]) - 52.0) < 0.01
    assert main(["datum", "apply", "--calibration", str(pairs), "--in", str(pts), "--out", str(tmp_path / "x.csv")]) == 2
    assert "pairs.csv" in capsys.readouterr().err
