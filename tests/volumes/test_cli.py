"""`georef volume`: one result per feature named by its 'name', the table and the JSON agree, --out writes
the same JSON, uncertainty defaults come from dense_summary.json next to the DSM when present; the step
function run_volumes writes its JSON."""

from __future__ import annotations

import json

import pytest

from georef_core.cli.main import main
from georef_core.steps.volumes import run_volumes

from .synthetic import E0, N0, circle, cone_height, cone_volume, write_dsm, write_geojson

A, B = (E0 + 10.0, N0 + 10.0), (E0 + 25.0, N0 + 22.0)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    dsm = write_dsm(d / "dsm.tif", lambda E, N: 80 + cone_height(*A, 6.0, 3.0)(E, N) + cone_height(*B, 5.0, 2.0)(E, N),
                    (35, 32), 0.1)
    polys = write_geojson(d / "piles.geojson", {"sand": circle(*A, 6.4), "gravel": circle(*B, 5.4)})
    return d, dsm, polys


def test_volume_json_and_table(files, capsys):
    d, dsm, polys = files
    out = d / "v.json"
    assert main(["volume", "--dsm", str(dsm), "--polygon", str(polys), "--base", "mean", "--json", "--out", str(out)]) == 0
    doc = json.loads(capsys.readouterr().out)
    names = [r["name"] for r in doc["results"]]
    assert names == ["sand", "gravel"]
    vols = {r["name"]: r["net_m3"] for r in doc["results"]}
    assert vols["sand"] == pytest.approx(cone_volume(6, 3), rel=1e-3) and vols["gravel"] == pytest.approx(cone_volume(5, 2), rel=1e-3)
    assert doc["totals"]["net_m3"] == pytest.approx(sum(vols.values()), abs=0.01)
    assert doc["noise_model"]["sources"]["sigma_z_m"].startswith("default")
    assert json.loads(out.read_text())["results"] == doc["results"]
    r = doc["results"][0]
    assert {"cut_m3", "fill_m3", "net_m3", "area_m2", "uncertainty", "base"} <= set(r)
    assert r["base"]["method"] == "mean"
    assert main(["volume", "--dsm", str(dsm), "--polygon", str(polys), "--base", "mean"]) == 0
    table = capsys.readouterr().out
    assert "sand" in table and "gravel" in table and "total" in table and "cut = material above the base" in table
    assert f"{vols['sand']:,.2f}" in table


def test_dense_summary_defaults_and_step(files, tmp_path):
    d, dsm, polys = files
    (d / "dense_summary.json").write_text(json.dumps({"dsm_vertical_rmse_m": 0.021, "dsm_height_bias_m": 0.004}))
    try:
        doc = run_volumes(dsm, polys, tmp_path / "vol.json", base="elevation:80")
    finally:
        (d / "dense_summary.json").unlink()
    m = doc["noise_model"]
    assert m["sigma_z_m"] == 0.021 and m["height_bias_m"] == 0.004
    assert m["sources"]["sigma_z_m"] == "dense_summary.json: dsm_vertical_rmse_m"
    saved = json.loads((tmp_path / "vol.json").read_text())
    assert saved["base"] == "elevation:80" and len(saved["results"]) == 2
    r = saved["results"][0]
    assert r["uncertainty"]["components_m3"]["height_bias_m3"] == pytest.approx(0.004 * r["area_m2"], rel=1e-3)
