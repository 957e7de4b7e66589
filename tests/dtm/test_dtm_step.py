"""Bare-earth DTM on a simulated site with machines (tests/dtm/scene.py: DSM = truth surface + 3 cm noise, points
sampled from it): the judged figures (DTM vs truth ground RMSE on open ground <= 2 x the DSM's, >= 95 % of the
machine cells non-ground), stockpiles kept (their volumes on the DTM equal those on the DSM), point classes, the
CLI, the volumes on the DTM and bad input."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import rasterio
from scipy import ndimage

from georef_core.cli.main import main
from georef_core.sim.truth import stockpiles_geojson

from .scene import NOISE_M, make_scene


@pytest.fixture(scope="module")
def done(tmp_path_factory):
    run = tmp_path_factory.mktemp("dtm_run")
    sc = make_scene(run)
    assert len(sc.site.machines) >= 3
    assert main(["dtm", str(run), "--quiet"]) == 0
    with rasterio.open(run / "dtm" / "dtm.tif") as ds:
        dtm = ds.read(1).astype(float)
        assert ds.transform == sc.transform and ds.crs.to_epsg() == sc.epsg
    with rasterio.open(run / "dtm" / "dtm_interpolated_mask.tif") as ds:
        mask = ds.read(1)
    summary = json.loads((run / "dtm" / "dtm_summary.json").read_text())
    return sc, dtm, mask, summary


def _rmse(d):
    return float(np.sqrt(np.mean(d * d)))


def test_dtm_against_truth_ground_and_machines_removed(done):
    sc, dtm, mask, summary = done
    near_machine = ndimage.binary_dilation(sc.machine, iterations=20)  # 2 m around the footprints
    open_ground = ~near_machine & (sc.pile < 0)
    dsm_rmse = _rmse((sc.dsm - sc.truth_surface)[open_ground])
    assert dsm_rmse == pytest.approx(NOISE_M, rel=0.05)
    # judged: DTM vs truth ground on open ground <= 2 x the DSM's RMSE there
    assert _rmse((dtm - sc.truth_bare)[open_ground]) <= 2.0 * dsm_rmse
    # everywhere, the ground under the machines (interpolated) and the piles included: still within 2 x
    assert _rmse(dtm - sc.truth_bare) <= 2.0 * dsm_rmse
    # under the machines alone, the interpolation stays within 10 cm RMS (3 cm noise, 2 % slopes, 3-6 m objects)
    assert _rmse((dtm - sc.truth_bare)[sc.machine]) < 0.10
    # judged: >= 95 % of the machine cells non-ground (removed and interpolated)
    assert np.mean(mask[sc.machine] == 1) >= 0.95
    # stockpiles are ground: (almost) none of their cells removed; nothing removed on open ground
    assert np.mean(mask[sc.pile >= 0] == 1) < 0.001
    assert np.mean(mask[open_ground] == 1) < 0.001
    # one object per machine (spikes aside), each 2.5-4 m high
    objs = summary["removed_objects"]
    assert objs["count"] == len(sc.site.machines)
    assert all(2.3 <= it["max_height_m"] <= 4.3 for it in objs["items"])
    true_area = float(sc.machine.sum()) * 0.01
    assert objs["area_m2"] == pytest.approx(true_area, rel=0.10)
    # the self-check hides ground patches and refills them: an error of a few noise sigmas
    chk = summary["interpolation_check"]
    assert chk["patches"] >= 5 and chk["rmse_m"] < 4 * NOISE_M
    assert summary["dsm_vertical_rmse_m"] == NOISE_M   # the DSM's error model carried for the volume tools


def test_point_classes(done):
    sc, _dtm, _mask, summary = done
    from georef_core.dense.point_cloud_io import read_point_cloud

    xyz, _rgb, crs, las = read_point_cloud(sc.run / "dtm" / "points_classified.laz")
    assert crs.to_2d().to_epsg() == sc.epsg
    cls = np.asarray(las.classification)
    f = sc.site.frame
    x, y = xyz[:, 0] - f.origin_e, xyz[:, 1] - f.origin_n
    on_machine = sc.site.machine_index(x, y) >= 0
    on_pile = sc.site.pile_index(x, y) >= 0
    assert on_machine.sum() > 100
    assert np.mean(cls[on_machine] == 1) >= 0.95
    assert np.mean(cls[on_pile] == 2) >= 0.99
    inner = (np.abs(x) < sc.site.half_w - 1) & (np.abs(y) < sc.site.half_h - 1)
    near_machine = np.zeros(len(x), bool)
    for m in sc.site.machines:
        near_machine |= m.footprint_sdf(x, y) < 1.0
    far = inner & ~on_pile & ~near_machine
    assert np.mean(cls[far] == 2) >= 0.999
    p = summary["points"]
    assert p["total"] == len(cls) and p["ground"] == int(np.sum(cls == 2))


def test_stockpile_volumes_on_the_dtm_equal_those_on_the_dsm(done, tmp_path):
    sc, _dtm, _mask, _summary = done
    from georef_core.steps.volumes import run_volumes

    poly = tmp_path / "piles.geojson"
    poly.write_text(json.dumps(stockpiles_geojson(sc.site)))
    on_dsm = run_volumes(sc.run / "dense" / "dsm.tif", poly, base="plane")
    out = tmp_path / "vol.json"
    assert main(["volume", "--run", str(sc.run), "--surface", "dtm", "--polygon", str(poly), "--base", "plane",
                 "--out", str(out), "--json"]) == 0
    on_dtm = json.loads(out.read_text())
    assert on_dtm["dsm"].endswith("dtm/dtm.tif")
    assert on_dtm["noise_model"]["sources"]["sigma_z_m"].startswith("dtm_summary.json")
    for a, b, pile in zip(on_dsm["results"], on_dtm["results"], sc.site.piles):
        # stockpiles kept: the DTM's volume within 0.2 % (+ 0.05 m3) of the DSM's, and both within 3 % of the truth
        assert abs(b["net_m3"] - a["net_m3"]) <= 0.002 * a["net_m3"] + 0.05, pile.name
        assert b["net_m3"] == pytest.approx(pile.volume, rel=0.03), pile.name


def test_volumes_step_on_the_dtm(done, tmp_path):
    sc, *_ = done
    from georef_core.steps.contract import Workspace
    from georef_core.steps.volumes import step_entry

    fc = stockpiles_geojson(sc.site)
    piles = [{"id": i, "name": ft["properties"]["name"], "base": "plane", "outline": ft["geometry"]}
             for i, ft in enumerate(fc["features"])]
    ws = Workspace(tmp_path, sc.run)
    s = step_entry(ws, {"surface": "dtm"}, None, {"crs": f"EPSG:{sc.epsg}", "stockpiles": piles})
    assert s == {"stockpiles": len(piles), "surface": "dtm"}
    doc = json.loads((sc.run / "volumes" / "volumes.json").read_text())
    assert doc["surface"] == "dtm"
    for rec, pile in zip(doc["stockpiles"], sc.site.piles):
        assert rec["volume_m3"] == pytest.approx(pile.volume, rel=0.03)


def test_missing_dense_outputs_are_named(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    assert main(["dtm", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(run / "dense" / "dsm.tif") in err and "georef dense" in err
    make_scene(run, options=dataclasses.replace(__import__("tests.dtm.scene", fromlist=["SITE"]).SITE,
                                                size_m=(30.0, 20.0), stockpiles=("cone",), stockpile_scale=0.4,
                                                machines=1, n_roads=0))
    (run / "dense" / "points.laz").unlink()
    assert main(["dtm", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(run / "dense" / "points.laz") in err
    assert main(["dtm", str(run), "--slope", "-1", "--quiet"]) == 2
    assert "slope must be a positive number" in capsys.readouterr().err
    assert not (run / "dtm" / "dtm.tif").exists()


def test_spec_options_are_the_filter_options():
    from georef_core.dtm.ground_filter import GroundFilterOptions
    from georef_core.steps.contract import get_spec

    spec = {o.name: o.default for o in get_spec("dtm").options}
    assert spec == {f.name: f.default for f in dataclasses.fields(GroundFilterOptions)}
    assert get_spec("dtm").output("dtm").path == "dtm/dtm.tif"
