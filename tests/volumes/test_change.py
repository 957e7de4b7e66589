"""Change between two surveys: the difference map, cut (removed) / fill (placed) over the common area and
per polygon against closed forms, the stable-ground check (passes; a vertically shifted survey is flagged
with its numbers; --align removes the shift), and a "before" DSM in another CRS and grid."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio

from georef_core.cli.main import main
from georef_core.steps.volumes import run_change

from .synthetic import E0, N0, circle, cone_height, cone_volume, write_dsm, write_geojson

SIZE = 40.0
A = (E0 + 12.0, N0 + 14.0)  # pile that grows
B = (E0 + 29.0, N0 + 26.0)  # new pile
P = (E0 + 28.0, N0 + 10.0)  # pit dug


def before_fn(E, N):
    return 100 + 0.01 * (E - E0) + cone_height(*A, 7.0, 3.0)(E, N)


def after_fn(E, N, shift=0.0):
    return (100 + shift + 0.01 * (E - E0) + cone_height(*A, 7.0, 4.0)(E, N) + cone_height(*B, 4.0, 2.5)(E, N)
            - cone_height(*P, 3.0, 1.5)(E, N))


@pytest.fixture(scope="module")
def surveys(tmp_path_factory):
    d = tmp_path_factory.mktemp("change")
    bef = write_dsm(d / "before.tif", before_fn, (SIZE, SIZE), 0.1)
    aft = write_dsm(d / "after.tif", after_fn, (SIZE, SIZE), 0.1)
    shifted = write_dsm(d / "after_shifted.tif", lambda E, N: after_fn(E, N, 0.08), (SIZE, SIZE), 0.1)
    polys = write_geojson(d / "piles.geojson", {"A": circle(*A, 7.5), "B": circle(*B, 4.5), "pit": circle(*P, 3.5)})
    stable = write_geojson(d / "stable.geojson", {"road": [[E0 + 2, N0 + 30], [E0 + 18, N0 + 30], [E0 + 18, N0 + 36],
                                                          [E0 + 2, N0 + 36]]})
    return d, bef, aft, shifted, polys, stable


def test_change_volumes_and_map(surveys):
    d, bef, aft, _, polys, stable = surveys
    out = d / "run1"
    doc = run_change(bef, aft, out, polys, stable, dsm_sigma_m=0.03, height_bias_m=0.02, correlation_length_m=0.5)
    va, vb, vp = cone_volume(7.0, 1.0), cone_volume(4.0, 2.5), cone_volume(3.0, 1.5)
    c = doc["common"]
    assert c["fill_m3"] == pytest.approx(va + vb, rel=1e-3) and c["cut_m3"] == pytest.approx(vp, rel=1e-3)
    assert c["net_m3"] == pytest.approx(va + vb - vp, rel=1e-3)
    assert c["valid_area_m2"] == pytest.approx(SIZE * SIZE, rel=1e-9) and c["nodata_area_m2"] == 0
    assert c["uncertainty"]["sigma_m3"] > 0 and c["lod95_m"] == pytest.approx(1.96 * np.hypot(0.03, 0.03), rel=1e-3)
    per = {p["name"]: p for p in doc["polygons"]}
    assert per["A"]["fill_m3"] == pytest.approx(va, rel=1e-3) and per["A"]["cut_m3"] < 1e-3
    assert per["B"]["net_m3"] == pytest.approx(vb, rel=1e-3)
    assert per["pit"]["cut_m3"] == pytest.approx(vp, rel=1e-3) and per["pit"]["net_m3"] == pytest.approx(-vp, rel=1e-3)
    assert doc["stable_ok"] is True and doc["flags"] == []
    assert abs(doc["stable"][0]["median_dz_m"]) < 1e-4
    with rasterio.open(out / "dz.tif") as ds:
        dz = ds.read(1)
        assert ds.crs.to_epsg() == 32633 and dz.shape == (400, 400)
        assert dz[ds.index(*A)] == pytest.approx(1.0, abs=0.03)  # apex of A: 4 m high, was 3 m
    assert dz.max() == pytest.approx(2.5, abs=0.05) and dz.min() == pytest.approx(-1.5, abs=0.05)
    saved = json.loads((out / "change.json").read_text())
    assert saved["common"]["net_m3"] == c["net_m3"]


def test_shifted_survey_is_flagged_and_can_be_aligned(surveys):
    d, bef, _, shifted, polys, stable = surveys
    doc = run_change(bef, shifted, None, polys, stable, dsm_sigma_m=0.03, height_bias_m=0.02)
    assert doc["stable_ok"] is False
    s = doc["stable"][0]
    assert s["median_dz_m"] == pytest.approx(0.08, abs=1e-4) and not s["ok"]
    assert "road" in doc["flags"][0] and "0.080" in doc["flags"][0]
    # the shift inflates the fill by 0.08 m x area: visible and covered by the relative-bias term
    per = {p["name"]: p for p in doc["polygons"]}
    extra = per["A"]["fill_m3"] - cone_volume(7.0, 1.0)
    assert extra == pytest.approx(0.08 * per["A"]["area_m2"], rel=0.01)
    assert per["A"]["uncertainty"]["components_m3"]["height_bias_m3"] == pytest.approx(0.08 * per["A"]["area_m2"], rel=0.01)
    # a 10 cm tolerance accepts it, and aligning on the road removes the shift
    doc = run_change(bef, shifted, None, polys, stable, tolerance_m=0.1, align=True, dsm_sigma_m=0.03)
    assert doc["stable_ok"] is True and doc["vertical_offset_m"] == pytest.approx(0.08, abs=1e-4)
    per = {p["name"]: p for p in doc["polygons"]}
    assert per["A"]["fill_m3"] == pytest.approx(cone_volume(7.0, 1.0), rel=1e-3)
    assert doc["common"]["net_m3"] == pytest.approx(cone_volume(7.0, 1.0) + cone_volume(4.0, 2.5) - cone_volume(3.0, 1.5),
                                                    rel=1e-3)


def test_before_in_another_crs_and_grid(surveys, tmp_path):
    """The before DSM warped to UTM 32N at 0.15 m: resampled back onto the after grid, same volumes within
    the resampling error."""
    from rasterio.warp import calculate_default_transform, reproject, Resampling

    d, bef, aft, _, polys, _ = surveys
    with rasterio.open(bef) as src:
        tr, w, h = calculate_default_transform(src.crs, "EPSG:32632", src.width, src.height, *src.bounds, resolution=0.15)
        prof = src.profile | {"crs": "EPSG:32632", "transform": tr, "width": w, "height": h, "nodata": float("nan")}
        with rasterio.open(tmp_path / "before32.tif", "w", **prof) as dst:
            reproject(rasterio.band(src, 1), rasterio.band(dst, 1), resampling=Resampling.cubic, dst_nodata=float("nan"))
    doc = run_change(tmp_path / "before32.tif", aft, None, polys, None, dsm_sigma_m=0.03)
    per = {p["name"]: p for p in doc["polygons"]}
    assert per["B"]["net_m3"] == pytest.approx(cone_volume(4.0, 2.5), rel=0.01)
    assert per["A"]["net_m3"] == pytest.approx(cone_volume(7.0, 1.0), rel=0.02)
    assert doc["stable_ok"] is None and "not checked" in doc["noise"]["relative_bias_source"]


def test_change_cli(surveys, capsys):
    d, bef, aft, shifted, polys, stable = surveys
    rc = main(["change", "--before", str(bef), "--after", str(shifted), "--polygon", str(polys), "--stable", str(stable),
               "--out", str(d / "cli")])
    out = capsys.readouterr().out
    assert rc == 0 and "FLAGGED" in out and "FLAG: stable area 'road' moved" in out
    assert (d / "cli" / "dz.tif").exists() and (d / "cli" / "change.json").exists()
