"""Volumes on the simulator's truth DSM against the analytic stockpile volumes it writes
(truth/stockpiles.geojson, volume_m3: the volume above each pile's base plane, in grid m^2 x m). The
truth's base is a plane (the levelled pad, exact within 2 m of the toe), so `plane` and `tin` must match;
the full site has a cone, a frustum, a windrow, a hip pile and a cone on the hillside (inclined base)."""

from __future__ import annotations

import json

import pytest

from georef_core.cli.main import main


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "site"
    assert main(["simulate", str(out), "--no-images", "--no-gnss", "--seed", "3", "--quiet"]) == 0
    return out


@pytest.mark.parametrize("base", ["plane", "tin"])
def test_truth_volumes(site, base, capsys):
    truth = json.loads((site / "truth" / "stockpiles.geojson").read_text())
    expect = {f["properties"]["name"]: f["properties"] for f in truth["features"]}
    assert {p["shape"] for p in expect.values()} == {"cone", "frustum", "windrow", "hip"}
    assert any(abs(p["base_plane"]["dz_dx"]) + abs(p["base_plane"]["dz_dy"]) > 0.005 for p in expect.values())
    capsys.readouterr()
    rc = main(["volume", "--dsm", str(site / "truth" / "dsm.tif"), "--polygon", str(site / "truth" / "stockpiles.geojson"),
               "--base", base, "--json"])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert len(doc["results"]) == len(expect)
    for r in doc["results"]:
        v = expect[r["name"]]["volume_m3"]
        assert r["net_m3"] == pytest.approx(v, rel=1e-3), (r["name"], r["net_m3"], v)
        assert r["fill_m3"] < 1e-3 * v
        assert r["uncertainty"]["sigma_m3"] > 0
