"""`georef simulate --crs`: the site in any projected CRS; geographic or unknown codes are refused."""

from __future__ import annotations

import csv
import json

import numpy as np
from pyproj import Transformer

from georef_core.cli.main import main


def test_site_in_another_projected_crs(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["simulate", str(out), "--small", "--no-images", "--quiet", "--crs", "6676"]) == 0
    frame = json.loads((out / "truth" / "site.json").read_text())["frame"]
    assert frame["epsg"] == 6676
    # target coordinates are in EPSG:6676: converting them to ECEF lands next to the site origin
    with open(out / "truth" / "targets.csv") as f:
        rows = list(csv.DictReader(f))
    tr = Transformer.from_crs("EPSG:6676", "EPSG:4326", always_xy=True)
    for r in rows:
        lon, lat = tr.transform(float(r["easting_m"]), float(r["northing_m"]))
        # the projected coordinates and the geodetic ones written beside them describe the same point (< 1 mm)
        assert abs(lat - float(r["lat_deg"])) < 1e-8 and abs(lon - float(r["lon_deg"])) < 1e-8
    assert np.all(np.abs([float(r["lat_deg"]) - frame["origin_lat_deg"] for r in rows]) < 0.01)


def test_geographic_or_unknown_crs_refused(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "a"), "--small", "--no-images", "--crs", "4326"]) == 2
    assert "not a projected CRS" in capsys.readouterr().err
    assert main(["simulate", str(tmp_path / "b"), "--small", "--no-images", "--crs", "999999"]) == 2
    assert "not an EPSG code" in capsys.readouterr().err
