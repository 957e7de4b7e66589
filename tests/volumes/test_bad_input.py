"""Bad input gives a clear error naming the file and the problem, never NaN or 0: polygon outside the DSM,
self-intersecting polygon, missing or wrong CRS, DSM without CRS or in degrees, unreadable files, no data
inside the polygon, too much missing; small holes are filled and reported."""

from __future__ import annotations

import json

import numpy as np
import pytest

from georef_core.cli.main import main
from georef_core.errors import GeorefError, InputFileError
from georef_core.volumes import NoiseModel, compute_volume, read_polygons

from .synthetic import E0, N0, circle, cone_height, cone_volume, write_dsm, write_geojson

CX, CY = E0 + 12.0, N0 + 12.0
MODEL = NoiseModel(0.03, 0.02, 0.5)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad")
    dsm = write_dsm(d / "dsm.tif", lambda E, N: 50 + cone_height(CX, CY, 6.0, 3.0)(E, N), (24, 24), 0.1)
    return d, dsm


def _error(capsys, args) -> str:
    rc = main(args)
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("georef: error: "), err
    return err


def test_polygon_outside_the_dsm(scene, capsys):
    d, dsm = scene
    far = write_geojson(d / "far.geojson", {"far": circle(CX + 500, CY, 5)})
    err = _error(capsys, ["volume", "--dsm", str(dsm), "--polygon", str(far)])
    assert "far.geojson" in err and "outside the DSM dsm.tif" in err
    part = write_geojson(d / "part.geojson", {"edge": circle(E0 + 1.0, CY, 3)})
    with pytest.raises(InputFileError, match=r"part.geojson.*extends .* beyond the DSM"):
        compute_volume(dsm, read_polygons(part)[0], "plane", noise=MODEL)


def test_self_intersecting_polygon(scene, capsys):
    d, dsm = scene
    bow = [[CX - 3, CY - 3], [CX + 3, CY + 3], [CX + 3, CY - 3], [CX - 3, CY + 3]]
    f = write_geojson(d / "bow.geojson", {"bowtie": bow})
    err = _error(capsys, ["volume", "--dsm", str(dsm), "--polygon", str(f)])
    assert "bow.geojson" in err and "'bowtie'" in err and "Self-intersection" in err


def test_missing_and_wrong_crs(scene, capsys):
    d, dsm = scene
    f = write_geojson(d / "nocrs.geojson", {"p": circle(CX, CY, 6.5)}, epsg=None)  # UTM numbers, no crs member
    err = _error(capsys, ["volume", "--dsm", str(dsm), "--polygon", str(f)])
    assert "nocrs.geojson" in err and "not longitude/latitude" in err
    assert main(["volume", "--dsm", str(dsm), "--polygon", str(f), "--polygon-crs", "EPSG:32633", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["results"][0]["net_m3"] == pytest.approx(cone_volume(6.0, 3.0), rel=1e-3)
    wrong = write_geojson(d / "wrong.geojson", {"p": circle(CX, CY, 6.5)}, epsg=32632)  # a zone away: far off
    err = _error(capsys, ["volume", "--dsm", str(dsm), "--polygon", str(wrong)])
    assert "wrong.geojson" in err and "outside the DSM" in err
    bad = d / "badcrs.geojson"
    doc = json.loads(f.read_text())
    doc["crs"] = {"type": "name", "properties": {"name": "EPSG:999999"}}
    bad.write_text(json.dumps(doc))
    assert "badcrs.geojson" in _error(capsys, ["volume", "--dsm", str(dsm), "--polygon", str(bad)])


def test_bad_dsm_files(scene, tmp_path, capsys):
    import rasterio

    d, dsm = scene
    poly = write_geojson(tmp_path / "p.geojson", {"p": circle(CX, CY, 6.5)})
    junk = tmp_path / "junk.tif"
    junk.write_text("not a raster")
    assert "junk.tif" in _error(capsys, ["volume", "--dsm", str(junk), "--polygon", str(poly)])
    assert "missing.tif: file not found" in _error(capsys, ["volume", "--dsm", str(tmp_path / "missing.tif"),
                                                            "--polygon", str(poly)])
    with rasterio.open(dsm) as src:
        z, prof = src.read(1), src.profile
    prof.update(crs=None)
    with rasterio.open(tmp_path / "nocrs.tif", "w", **prof) as dst:
        dst.write(z, 1)
    err = _error(capsys, ["volume", "--dsm", str(tmp_path / "nocrs.tif"), "--polygon", str(poly)])
    assert "nocrs.tif" in err and "no coordinate reference system" in err
    prof.update(crs="EPSG:4326")
    with rasterio.open(tmp_path / "geo.tif", "w", **prof) as dst:
        dst.write(z, 1)
    err = _error(capsys, ["volume", "--dsm", str(tmp_path / "geo.tif"), "--polygon", str(poly)])
    assert "geo.tif" in err and "geographic CRS" in err
    (tmp_path / "bad.geojson").write_text("{not json")
    assert "bad.geojson, line 1" in _error(capsys, ["volume", "--dsm", str(dsm), "--polygon", str(tmp_path / "bad.geojson")])
    assert "unknown base" in _error(capsys, ["volume", "--dsm", str(dsm), "--polygon", str(poly), "--base", "lowst"])


def _with_hole(path, r_hole: float, nodata=-9999.0):
    def f(E, N):
        z = 50 + cone_height(CX, CY, 6.0, 3.0)(E, N)
        return np.where(np.hypot(E - CX - 2.0, N - CY) < r_hole, nodata, z)

    return write_dsm(path, f, (24, 24), 0.1, nodata=nodata)


def test_nodata_inside_polygon(tmp_path):
    poly = read_polygons(write_geojson(tmp_path / "p.geojson", {"p": circle(CX, CY, 6.5)}))[0]
    small = _with_hole(tmp_path / "small.tif", 0.5)
    r = compute_volume(small, poly, "plane", noise=MODEL)
    hole = np.pi * 0.5 ** 2
    assert r.filled_nodata_m2 == pytest.approx(hole, rel=0.1)
    assert any("filled by interpolation" in w for w in r.warnings)
    # the hole sits on the cone's straight flank: harmonic filling is close (curvature is small there)
    assert r.net_m3 == pytest.approx(cone_volume(6.0, 3.0), rel=2e-3)
    # the filled hole is interpolated: by default outside the stated uncertainty, with its own bound;
    # accepted, area x sigma_z is in it
    assert r.uncertainty["components_m3"]["nodata_fill_m3"] == 0.0 and r.interpolated["bound_m3"] > 0
    from georef_core.volumes.volume import VolumeOptions

    ra = compute_volume(small, poly, "plane", noise=MODEL, options=VolumeOptions(accept_interpolated=True))
    assert ra.uncertainty["components_m3"]["nodata_fill_m3"] == pytest.approx(ra.filled_nodata_m2 * 0.03, rel=1e-6)
    big = _with_hole(tmp_path / "big.tif", 2.5)
    with pytest.raises(InputFileError, match=r"big.tif: .* has no DSM data; at most 5 % is filled"):
        compute_volume(big, poly, "plane", noise=MODEL)
    empty = write_dsm(tmp_path / "empty.tif", lambda E, N: np.full(E.shape, -9999.0), (24, 24), 0.1, nodata=-9999.0)
    with pytest.raises(InputFileError, match="empty.tif"):
        compute_volume(empty, poly, "elevation:50", noise=MODEL)
    with pytest.raises(InputFileError, match="empty.tif: the DSM has no data along the outline"):
        compute_volume(empty, poly, "plane", noise=MODEL)


def test_every_error_is_a_georef_error(scene, tmp_path):
    d, dsm = scene
    with pytest.raises(GeorefError):
        compute_volume(dsm, read_polygons(write_geojson(tmp_path / "q.geojson", {"q": circle(CX, CY, 5)}))[0],
                       f"surface:{tmp_path / 'nope.tif'}")


def test_dense_interpolated_cells_are_reported(tmp_path):
    """dsm_filled_mask.tif (the dense step's: 1 = interpolated) next to the DSM: the interpolated area inside
    the polygon is reported and warned about; by default it is outside the stated uncertainty, with its own
    bound (area x the height range around it) and its share of the net; accepted, it is counted as measured
    (area x sigma_z in the uncertainty)."""
    import rasterio

    dsm = write_dsm(tmp_path / "dsm.tif", lambda E, N: 50 + cone_height(CX, CY, 6.0, 3.0)(E, N), (24, 24), 0.1)
    poly = read_polygons(write_geojson(tmp_path / "p.geojson", {"p": circle(CX, CY, 6.5)}))[0]
    with rasterio.open(dsm) as src:
        prof = src.profile | {"dtype": "uint8", "nodata": 255}
        mask = np.zeros((src.height, src.width), np.uint8)
        r0, c = src.index(CX, CY)
    mask[r0 - 10:r0 + 10, c - 15:c + 15] = 1  # 20 x 30 cells = 6 m^2, well inside the polygon
    mask[:5, :5] = 1  # outside the polygon: not counted
    with rasterio.open(tmp_path / "dsm_filled_mask.tif", "w", **prof) as dst:
        dst.write(mask, 1)
    r = compute_volume(dsm, poly, "plane", noise=MODEL)
    assert r.dsm_interpolated_m2 == pytest.approx(6.0, rel=1e-9)
    assert any("interpolated by the dense step" in w for w in r.warnings)
    it = r.interpolated
    assert it["area_m2"] == pytest.approx(6.0, rel=1e-9) and not it["accepted"]
    assert it["fraction"] == pytest.approx(6.0 / poly.area_m2, abs=1e-4)
    # the net on those cells: the cone above the plane base over the 2 x 3 m box at the apex
    with rasterio.open(dsm) as src:
        z = src.read(1)
    assert it["net_m3"] > 0 and it["net_m3"] < r.net_m3
    # bound: the box's area x the height range of the measured cells around it (the cone's flanks)
    rim = np.concatenate([z[r0 - 11, c - 16:c + 16], z[r0 + 10, c - 16:c + 16], z[r0 - 11:r0 + 11, c - 16],
                          z[r0 - 11:r0 + 11, c + 15]])
    assert it["bound_m3"] == pytest.approx(6.0 * (rim.max() - rim.min()), rel=0.05)
    assert r.uncertainty["components_m3"]["nodata_fill_m3"] == 0.0
    assert r.uncertainty["ci95_with_interpolated_bound_m3"] == pytest.approx(r.uncertainty["ci95_m3"] + it["bound_m3"],
                                                                           abs=2e-3)
    assert any("not in the stated uncertainty" in w for w in r.warnings)
    from georef_core.volumes.volume import VolumeOptions

    ra = compute_volume(dsm, poly, "plane", noise=MODEL, options=VolumeOptions(accept_interpolated=True))
    assert ra.interpolated["accepted"] and ra.net_m3 == pytest.approx(r.net_m3, rel=1e-12)
    assert ra.uncertainty["components_m3"]["nodata_fill_m3"] == pytest.approx(6.0 * 0.03, rel=1e-3)
    assert ra.uncertainty["sigma_m3"] > r.uncertainty["sigma_m3"]
    assert "ci95_with_interpolated_bound_m3" not in ra.uncertainty


def test_surface_base_with_a_small_hole(tmp_path):
    """An imported base surface with a nodata hole under the polygon: filled (planar ground: exactly) and
    reported; a surface missing under most of the polygon is an error naming the surface file."""
    dsm = write_dsm(tmp_path / "dsm.tif", lambda E, N: 50 + 0.02 * (E - E0) + cone_height(CX, CY, 6.0, 3.0)(E, N),
                    (24, 24), 0.1)
    poly = read_polygons(write_geojson(tmp_path / "p.geojson", {"p": circle(CX, CY, 6.5)}))[0]

    def ground(E, N, r):
        return np.where(np.hypot(E - CX + 1, N - CY) < r, -9999.0, 50 + 0.02 * (E - E0))

    holed = write_dsm(tmp_path / "ground.tif", lambda E, N: ground(E, N, 0.6), (24, 24), 0.2, nodata=-9999.0)
    r = compute_volume(dsm, poly, f"surface:{holed}", noise=MODEL)
    assert r.net_m3 == pytest.approx(cone_volume(6.0, 3.0), rel=1e-3)
    assert any("base surface" in w and "interpolated" in w for w in r.warnings)
    bad = write_dsm(tmp_path / "ground_bad.tif", lambda E, N: ground(E, N, 4.0), (24, 24), 0.2, nodata=-9999.0)
    with pytest.raises(InputFileError, match="ground_bad.tif: the base surface has no data under"):
        compute_volume(dsm, poly, f"surface:{bad}", noise=MODEL)
