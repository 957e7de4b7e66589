"""Cut/fill to design on analytic scenes (tests/design/scenes.py): a valley-shaped design (two planes) and a
surveyed surface = design + a cone (cut, 37.70 m3) + a conical pit (fill, 20.94 m3), 10 cm cells, an
irregular hexagonal area; the design as a GeoTIFF grid, a LandXML TIN and DXF 3DFACEs / polyface."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from georef_core.steps.design import run_design
from tests.design import scenes as S

EXACT = {"dsm_sigma_m": 0.01, "vertical_rmse_m": 0.01, "correlation_length_m": 0.0}


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("design_scene")
    sc = S.write_scene(d)
    sc["tif"] = S.write_design_geotiff(d / "design.tif")
    sc["xml"] = S.write_design_landxml(d / "design.xml")
    sc["dxf_quads"] = S.write_design_dxf(d / "design_quads.dxf")
    sc["dxf_triangles"] = S.write_design_dxf(d / "design_tri.dxf", quads=False)
    sc["dxf_polyface"] = S.write_design_dxf(d / "design_pf.dxf", polyface=True)
    sc["dir"] = d
    return sc


@pytest.mark.parametrize("fmt", ["tif", "xml", "dxf_quads", "dxf_triangles", "dxf_polyface"])
def test_cut_fill_within_1_percent_of_analytic_for_each_design_format(scene, fmt, tmp_path):
    doc = run_design(scene["dsm"], scene[fmt], scene["polygon"], tmp_path, dict(EXACT, tolerance_m=0.05))
    assert doc["cut_m3"] == pytest.approx(S.cut_volume(), rel=0.01)
    assert doc["fill_m3"] == pytest.approx(S.fill_volume(), rel=0.01)
    assert doc["net_m3"] == pytest.approx(S.cut_volume() - S.fill_volume(), rel=0.01)
    assert doc["area_m2"] == pytest.approx(S.area_m2(), rel=1e-6)  # exact polygon coverage
    # on grade: everywhere but where a cone is more than 5 cm off (r < R (1 - t/H)); cells of 10 cm
    want = 1.0 - S.off_grade_area(0.05) / S.area_m2()
    assert doc["on_grade"]["share"] == pytest.approx(want, abs=0.002)
    assert doc["classes_m2"]["cut"] == pytest.approx(math.pi * (6.0 * 0.95) ** 2, rel=0.01)
    assert doc["classes_m2"]["fill"] == pytest.approx(math.pi * (5.0 * (1 - 0.05 / 0.8)) ** 2, rel=0.01)
    assert doc["classes_m2"]["not_significant"] == 0.0  # 1.96 x 1.4 cm < 5 cm tolerance
    assert not doc["warnings"]
    # outputs: the difference raster holds the cone's apex height, the classes raster its colour table
    import rasterio

    with rasterio.open(tmp_path / "difference.tif") as ds:
        dz = ds.read(1)
        assert np.nanmax(dz) == pytest.approx(1.0, abs=0.02) and np.nanmin(dz) == pytest.approx(-0.8, abs=0.02)
    with rasterio.open(tmp_path / "classes.tif") as ds:
        cls = ds.read(1)
        assert ds.colormap(1)[1][:3] == (214, 39, 40) and ds.nodata == 0
        assert set(np.unique(cls)) == {0, 1, 2, 3}
    gj = json.loads((tmp_path / "contours.geojson").read_text())
    # the +-5 cm band edges: one circle around each cone (R (1 - t/H) from its centre)
    assert sorted(f["properties"]["level_m"] for f in gj["features"]) == [-0.05, 0.05]
    ring = np.array(next(f for f in gj["features"] if f["properties"]["level_m"] == 0.05)["geometry"]["coordinates"])
    r = np.hypot(ring[:, 0] - S.BUMP["cx"], ring[:, 1] - S.BUMP["cy"])
    assert np.all(np.abs(r - 6.0 * 0.95) < 0.1)


def test_landxml_points_are_north_east_elevation(scene):
    from georef_core.design import read_design

    tin = read_design(scene["xml"])
    pts, _ = S.tin_vertices()
    # LandXML writes "N E Z": the reader must give easting first
    assert np.allclose(np.sort(tin.points_xyz[:, 0]), np.sort(pts[:, 0]))
    assert tin.points_xyz[:, 0].max() < 1e6 and tin.points_xyz[:, 1].min() > 5e6
    # and the file read as "E N Z" would put the design 4.9e6 m away: nothing to compare
    assert tin.kind == "tin" and len(tin.faces) == 4


def test_landxml_namespaces_feet_and_surface_choice(scene, tmp_path):
    from georef_core.design import read_design
    from georef_core.errors import InputFileError

    area = S.area_m2()
    for ns in ("http://www.landxml.org/schema/LandXML-1.0", "http://www.landxml.org/schema/LandXML-1.1", ""):
        p = S.write_design_landxml(tmp_path / f"d{len(ns)}.xml", namespace=ns)
        doc = run_design(scene["dsm"], p, scene["polygon"], None, EXACT)
        assert doc["cut_m3"] == pytest.approx(S.cut_volume(), rel=0.01)
    # international feet with an EPSG code: converted to metres, and said so
    p = S.write_design_landxml(tmp_path / "feet.xml", feet=True, epsg=S.EPSG)
    tin = read_design(p)
    assert any("converted to metres" in n for n in tin.notes)
    doc = run_design(scene["dsm"], p, scene["polygon"], None, EXACT)
    assert doc["fill_m3"] == pytest.approx(S.fill_volume(), rel=0.01)
    # two surfaces: a name is needed; the existing ground 3 m lower gives 3 m x area more net
    p = S.write_design_landxml(tmp_path / "two.xml", extra_surface=True)
    with pytest.raises(InputFileError, match=r"2 surfaces in the file \('EG', 'FG design'\)"):
        read_design(p)
    with pytest.raises(InputFileError, match="no surface named 'XX'"):
        read_design(p, "XX")
    fg = run_design(scene["dsm"], p, scene["polygon"], None, EXACT, surface_name="FG design")
    eg = run_design(scene["dsm"], p, scene["polygon"], None, EXACT, surface_name="EG")
    assert fg["net_m3"] == pytest.approx(S.cut_volume() - S.fill_volume(), rel=0.01)
    assert eg["net_m3"] - fg["net_m3"] == pytest.approx(3.0 * area, rel=1e-4)
    p = tmp_path / "bad_ns.xml"
    p.write_text(S.write_design_landxml(tmp_path / "x.xml").read_text().replace("LandXML-1.2", "LandXML-9.9"))
    with pytest.raises(InputFileError, match="unknown LandXML namespace"):
        read_design(p)


def test_significance_band_from_the_survey_accuracy(tmp_path):
    # a low mound (4 cm) below 1.96 sigma_cell (1.96 x sqrt(3^2 + 2^2) cm = 7.1 cm), a deep pit above it
    bump = dict(S.BUMP, h=0.04)
    sc = S.write_scene(tmp_path, bump=bump)
    design = S.write_design_landxml(tmp_path / "design.xml")
    t = 0.02
    doc = run_design(sc["dsm"], design, sc["polygon"], tmp_path / "out",
                     {"tolerance_m": t, "dsm_sigma_m": 0.03, "vertical_rmse_m": 0.02, "correlation_length_m": 0.0})
    sig = doc["significance"]
    assert sig["sigma_cell_m"] == pytest.approx(math.hypot(0.03, 0.02), abs=1e-5)
    thr = 1.96 * math.hypot(0.03, 0.02)
    R, H = bump["radius"], bump["h"]
    # the whole mound beyond tolerance is 'not significant', none of it 'cut'
    assert doc["classes_m2"]["cut"] == 0.0
    assert doc["classes_m2"]["not_significant"] == pytest.approx(
        math.pi * (R * (1 - t / H)) ** 2 + math.pi * S.PIT["radius"] ** 2 * ((1 - t / 0.8) ** 2 - (1 - thr / 0.8) ** 2),
        rel=0.02)
    # the pit's core is still a significant fill, and the volume is there all the same
    assert doc["classes_m2"]["fill"] == pytest.approx(math.pi * (S.PIT["radius"] * (1 - thr / 0.8)) ** 2, rel=0.01)
    assert doc["cut_m3"] == pytest.approx(math.pi * R * R * H / 3, rel=0.01)
    assert doc["on_grade"]["surely_share"] < doc["on_grade"]["share"] < doc["on_grade"]["possibly_share"]
    import rasterio

    with rasterio.open(tmp_path / "out" / "classes.tif") as ds:
        assert 4 in np.unique(ds.read(1)) and 1 not in np.unique(ds.read(1))


def test_noisy_survey_volumes_inflation_and_uncertainty(tmp_path):
    """White noise of 2 cm on every cell (seeded): the net stays within its stated noise sigma band, and the
    gross cut and fill grow by about the predicted noise inflation (sigma / sqrt(2 pi) per on-grade m2)."""
    sigma = 0.02
    sc = S.write_scene(tmp_path, noise_sigma=sigma, seed=7)
    design = S.write_design_dxf(tmp_path / "design.dxf")
    doc = run_design(sc["dsm"], design, sc["polygon"], tmp_path / "out",
                     {"tolerance_m": 0.05, "dsm_sigma_m": sigma, "vertical_rmse_m": 0.0, "correlation_length_m": 0.0})
    s_net = doc["uncertainty"]["net_m3"]["sigma_m3"]
    assert s_net == pytest.approx(sigma * math.sqrt(S.area_m2() * 0.01), rel=0.02)  # sigma sqrt(sum w^2)
    assert abs(doc["net_m3"] - (S.cut_volume() - S.fill_volume())) < 3 * s_net
    flat = S.area_m2() - math.pi * (S.BUMP["radius"] ** 2 + S.PIT["radius"] ** 2)
    infl = doc["noise_inflation_m3"]
    assert infl == pytest.approx(sigma / math.sqrt(2 * math.pi) * flat, rel=0.1)
    assert doc["cut_m3"] - S.cut_volume() == pytest.approx(infl, rel=0.1)
    assert doc["fill_m3"] - S.fill_volume() == pytest.approx(infl, rel=0.1)
    # on the truly on-design ground a cell reads as cut/fill only when |noise| > 5 cm (2.5 sigma): 1.2 %
    import rasterio

    with rasterio.open(tmp_path / "out" / "classes.tif") as ds:
        cls = ds.read(1)
        rows, cols = np.indices(cls.shape)
        x, y = ds.xy(rows.ravel(), cols.ravel())
    x, y, cls = np.asarray(x), np.asarray(y), cls.ravel()
    away = (np.hypot(x - S.BUMP["cx"], y - S.BUMP["cy"]) > S.BUMP["radius"] + 0.2) & \
        (np.hypot(x - S.PIT["cx"], y - S.PIT["cy"]) > S.PIT["radius"] + 0.2) & (cls != 0)
    share = np.mean(np.isin(cls[away], (1, 2)))
    assert 0.006 < share < 0.02


def test_check_point_rmse_read_from_the_run_folder(scene, tmp_path):
    import shutil

    run = tmp_path / "run"
    (run / "dense").mkdir(parents=True)
    shutil.copy(scene["dsm"], run / "dense" / "dsm.tif")
    (run / "dense" / "dense_summary.json").write_text(json.dumps({"dsm_vertical_rmse_m": 0.012,
                                                                  "dsm_error_correlation_length_m": 0.5}))
    (run / "residuals.json").write_text(json.dumps({"statistics": {"n": 3, "dz": {"rmse_m": 0.021, "mean_m": 0.004}}}))
    doc = run_design(run / "dense" / "dsm.tif", scene["xml"], scene["polygon"], None, {"tolerance_m": 0.05})
    sig = doc["significance"]
    assert sig["dsm_sigma_m"] == 0.012 and sig["vertical_rmse_m"] == 0.021 and sig["correlation_length_m"] == 0.5
    assert "residuals.json" in sig["sources"]["vertical_rmse_m"]
    # the bias of the survey moves every cell together: net sigma carries 2.1 cm x area
    assert doc["uncertainty"]["net_m3"]["components_m3"]["vertical_bias_m3"] == pytest.approx(0.021 * S.area_m2(), rel=1e-3)
    # cut: the secant of the cut over +-b, i.e. about b x (area above design)
    # cut: the secant over +-b: b per m2 above design, b/2 per m2 on it (a bias either adds cut there or not)
    flat = S.area_m2() - math.pi * (36.0 + 25.0)
    assert doc["uncertainty"]["cut_m3"]["components_m3"]["vertical_bias_m3"] == pytest.approx(
        0.021 * (math.pi * 36.0 + 0.5 * flat), rel=0.01)
