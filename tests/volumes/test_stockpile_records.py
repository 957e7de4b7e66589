"""Stockpile records across surveys: the base is locked on the first survey and reused, so a pile whose
toe later spreads over its outline is still measured against the original ground (a re-estimated base
would sit on the spilled material); JSON round trip; idempotent re-measurement; the CLI."""

from __future__ import annotations

import json
import math

import pytest

from georef_core.cli.main import main
from georef_core.errors import GeorefError
from georef_core.volumes import NoiseModel, StockpileRecord, StockpileRegistry, compute_volume, read_polygons

from .synthetic import E0, N0, circle, cone_height, cone_volume, write_dsm, write_geojson

C = (E0 + 15.0, N0 + 15.0)
RP = 8.5  # outline radius
MODEL = NoiseModel(0.03, 0.02, 0.5)


def ground(E, N):
    return 100 + 0.03 * (E - E0) - 0.02 * (N - N0)


def cone_inside(R, H, rp):
    """Volume of a cone (radius R, height H) inside a concentric disc of radius rp."""
    r = min(R, rp)
    return 2 * math.pi * H * (r * r / 2 - r ** 3 / (3 * R))


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    d = tmp_path_factory.mktemp("site")
    s1 = write_dsm(d / "s1.tif", lambda E, N: ground(E, N) + cone_height(*C, 8.0, 4.0)(E, N), (30, 30), 0.1)
    s2 = write_dsm(d / "s2.tif", lambda E, N: ground(E, N) + cone_height(*C, 10.0, 5.0)(E, N), (30, 30), 0.1)
    poly = write_geojson(d / "pile.geojson", {"north pile": circle(*C, RP)})
    return d, s1, s2, poly


def test_locked_base_series(site, tmp_path):
    d, s1, s2, poly = site
    reg = StockpileRegistry.load(tmp_path)
    assert reg.records == {}
    reg.add(read_polygons(poly)[0], material="gravel", base_method="plane")
    m1 = reg.measure("north pile", s1, "2024-05-01", "2024-05-01", noise=MODEL)
    assert m1.net_m3 == pytest.approx(cone_volume(8.0, 4.0), rel=1e-3)
    lb = reg.get("north pile").locked_base
    assert lb.method == "plane" and lb.survey_id == "2024-05-01" and lb.crs == "EPSG:32633"
    assert lb.parameters["dz_dx"] == pytest.approx(0.03, abs=1e-6)
    m2 = reg.measure("north pile", s2, "2024-06-01", "2024-06-01", noise=MODEL)
    truth2 = cone_inside(10.0, 5.0, RP)
    assert m2.net_m3 == pytest.approx(truth2, rel=1e-3)
    # against a base re-estimated on survey 2 the toe of the spread pile lifts the base: clearly less
    fresh = compute_volume(s2, read_polygons(poly)[0], "plane", noise=MODEL)
    assert fresh.net_m3 < 0.9 * truth2
    # the locked base is independent of the new survey: its bias and its own error count
    assert m2.sigma_m3 > m1.sigma_m3
    reg.save()

    again = StockpileRegistry.load(tmp_path)
    rec = again.get("north pile")
    assert [s["survey_id"] for s in rec.series()] == ["2024-05-01", "2024-06-01"]
    assert rec.series()[1]["net_m3"] == pytest.approx(m2.net_m3)
    assert StockpileRecord.from_dict(json.loads(json.dumps(rec.to_dict()))).to_dict() == rec.to_dict()
    again.measure("north pile", s2, "2024-06-01", "2024-06-01", noise=MODEL)  # re-run: replaced, not added
    assert len(again.get("north pile").measurements) == 2
    with pytest.raises(GeorefError, match="already exists"):
        again.add(read_polygons(poly)[0])
    with pytest.raises(GeorefError, match="no stockpile named 'south'"):
        again.get("south")


def test_locked_tin_and_lowest_bases(site, tmp_path):
    d, s1, s2, poly = site
    reg = StockpileRegistry(tmp_path)
    p = read_polygons(poly)[0]
    reg.add(p, base_method="tin")
    reg.measure("north pile", s1, "a", noise=MODEL)
    pts = reg.get("north pile").locked_base.parameters["points_xyz_m"]
    assert len(pts) > 100 and len(pts[0]) == 3
    assert reg.measure("north pile", s2, "b", noise=MODEL).net_m3 == pytest.approx(cone_inside(10.0, 5.0, RP), rel=1e-3)
    reg.add(p, base_method="lowest", replace=True)
    reg.lock_base("north pile", s1, "a")
    z = reg.get("north pile").locked_base.parameters["elevation_m"]
    m = reg.measure("north pile", s2, "b", noise=MODEL)
    assert m.net_m3 == pytest.approx(compute_volume(s2, p, f"elevation:{z}", noise=MODEL).net_m3, abs=2e-3)


def test_stockpile_cli(site, tmp_path, capsys):
    d, s1, s2, poly = site
    sd = str(tmp_path / "site")
    assert main(["stockpile", sd, "add", "--polygon", str(poly), "--material", "sand"]) == 0
    assert main(["stockpile", sd, "measure", "--dsm", str(s1), "--survey", "S1", "--date", "2024-05-01",
                 "--dsm-sigma", "0.03"]) == 0
    assert main(["stockpile", sd, "measure", "--dsm", str(s2), "--survey", "S2", "--date", "2024-06-01",
                 "--dsm-sigma", "0.03"]) == 0
    capsys.readouterr()
    assert main(["stockpile", sd, "series", "north pile", "--json"]) == 0
    ser = json.loads(capsys.readouterr().out)["series"]
    assert [s["survey_id"] for s in ser] == ["S1", "S2"]
    assert ser[1]["net_m3"] - ser[0]["net_m3"] == pytest.approx(cone_inside(10, 5, RP) - cone_volume(8, 4), rel=2e-3)
    assert main(["stockpile", sd, "list"]) == 0
    assert "north pile: sand; base locked plane (survey S1" in capsys.readouterr().out
