"""Contours of an analytic surface (tests/deliverables/conftest.py: a 2 % plane plus a 6 m Gaussian hill,
0.25 m cells, 2 cm noise, an 8 m no-data square) against the truth surface's contours.

What is measured: the truth surface's height at every vertex of a traced contour minus the contour's level
(a vertex exactly on the truth contour scores 0; the horizontal distance to the truth contour is that
difference over the truth slope). The judged band is half the interval."""

from __future__ import annotations

import json

import numpy as np
import pytest

from georef_core.deliverables.contours import trace_contours
from georef_core.deliverables.exports import label_height_m, run_contours, write_contours
from georef_core.deliverables.surface import read_surface
from georef_core.errors import InputFileError

from . import conftest as C

INTERVAL_M = 0.5


def _vertices(cs):
    xy = np.concatenate([c.xy_m for c in cs.lines])
    lv = np.concatenate([np.full(len(c.xy_m), c.level_m) for c in cs.lines])
    return xy, lv


@pytest.fixture(scope="module")
def noisy(tmp_path_factory):
    return C.write_surface(tmp_path_factory.mktemp("c") / "dsm.tif")


def test_contours_within_half_an_interval_of_the_truth(noisy):
    cs = trace_contours(read_surface(noisy), INTERVAL_M)
    xy, lv = _vertices(cs)
    dz = np.abs(C.truth_height(xy[:, 0], xy[:, 1]) - lv)
    assert dz.max() <= INTERVAL_M / 2                       # the judged band
    assert np.percentile(dz, 95) <= 0.03                     # 1.5 x the 2 cm DSM noise: smoothing works
    gx, gy = C.truth_gradient(xy[:, 0], xy[:, 1])
    slope = np.hypot(gx, gy)
    dh = dz / slope
    # horizontally: on the hill's flanks (slope >= 10 %) the 95th percentile is within one 0.25 m cell
    assert np.percentile(dh[slope >= 0.10], 95) <= 0.25
    # every level of the surface's range is there, and index contours are the multiples of 2.5 m
    zmin, zmax = 100.0, 100.0 + 0.02 * 60.0 + 6.0
    want = {round(k * INTERVAL_M, 6) for k in range(int(np.ceil(zmin / INTERVAL_M)), int(zmax / INTERVAL_M) + 1)
            if zmin + 0.05 < k * INTERVAL_M < C.HILL["h"] + 100.6 - 0.05}
    got = {round(c.level_m, 6) for c in cs.lines}
    assert want <= got
    for c in cs.lines:
        assert c.index == (abs(c.level_m / 2.5 - round(c.level_m / 2.5)) < 1e-9)
    assert any(c.index for c in cs.lines) and not all(c.index for c in cs.lines)


def test_smoothing_displacement_is_bounded(tmp_path):
    """On the noise-free surface the only error is the smoothing's (sigma 1.5 cells = 0.375 m): at the
    hilltop it lowers heights by sigma^2/2 x |laplacian| = 0.375^2/2 x 2 x 6/8^2 = 13 mm; nowhere more than
    2 cm (the blend back to the cell's own height next to no-data keeps the one-sided kernel's bias off)."""
    cs = trace_contours(read_surface(C.write_surface(tmp_path / "clean.tif", noise_m=0.0)), INTERVAL_M)
    xy, lv = _vertices(cs)
    dz = C.truth_height(xy[:, 0], xy[:, 1]) - lv
    assert np.abs(dz).max() <= 0.02
    # with no smoothing the same surface's contours are exact to the linear interpolation (a few mm)
    cs0 = trace_contours(read_surface(tmp_path / "clean.tif"), INTERVAL_M, smoothing_m=0.0)
    xy0, lv0 = _vertices(cs0)
    assert np.abs(C.truth_height(xy0[:, 0], xy0[:, 1]) - lv0).max() <= 0.01


def test_contours_stop_at_no_data(noisy):
    cs = trace_contours(read_surface(noisy), INTERVAL_M)
    xy, _ = _vertices(cs)
    assert not C.in_hole(xy[:, 0], xy[:, 1], margin=0.13).any()
    # the levels crossing the hole are cut there: open lines ending within a cell of its edge
    x0, y0, x1, y1 = C.HOLE
    ends = np.array([p for c in cs.lines if not c.closed for p in (c.xy_m[0], c.xy_m[-1])])
    near = (ends[:, 0] > x0 - 0.5) & (ends[:, 0] < x1 + 0.5) & (ends[:, 1] > y0 - 0.5) & (ends[:, 1] < y1 + 0.5)
    assert near.sum() >= 4


def test_bad_surfaces_name_the_file(tmp_path):
    p = C.write_surface(tmp_path / "empty.tif", all_nodata=True)
    with pytest.raises(InputFileError, match="empty.tif.*no valid height"):
        read_surface(p)
    g = C.write_surface(tmp_path / "geo.tif", crs="EPSG:4326")
    with pytest.raises(InputFileError, match="geo.tif.*geographic"):
        read_surface(g)
    with pytest.raises(InputFileError, match="missing.tif.*not found"):
        read_surface(tmp_path / "missing.tif")
    (tmp_path / "junk.tif").write_bytes(b"not a tiff")
    with pytest.raises(InputFileError, match="junk.tif.*cannot be read"):
        read_surface(tmp_path / "junk.tif")
    ok = C.write_surface(tmp_path / "ok.tif")
    with pytest.raises(InputFileError, match=r"out.kml.*\.geojson, \.gpkg, \.dxf"):
        run_contours(ok, tmp_path / "out.kml", 1.0)


def test_contour_files_open_in_independent_readers(noisy, tmp_path):
    import ezdxf
    import pyogrio
    from pyogrio.raw import read
    from pyproj import CRS, Transformer

    cs = trace_contours(read_surface(noisy), INTERVAL_M)
    n, n_index = len(cs.lines), sum(c.index for c in cs.lines)
    levels = sorted({c.level_m for c in cs.lines})

    # DXF: minor/index layers, LWPOLYLINEs at their level, a label per index contour on CONTOUR_LABEL, a .prj
    write_contours(cs, tmp_path / "c.dxf")
    doc = ezdxf.readfile(tmp_path / "c.dxf")
    msp = doc.modelspace()
    minor = msp.query('LWPOLYLINE[layer=="CONTOUR_MINOR"]')
    index = msp.query('LWPOLYLINE[layer=="CONTOUR_INDEX"]')
    assert len(minor) == n - n_index and len(index) == n_index
    assert {round(e.dxf.elevation, 6) for e in index} == {c.level_m for c in cs.lines if c.index}
    labels = msp.query('TEXT[layer=="CONTOUR_LABEL"]')
    h = label_height_m(cs.surface)              # 60 m / 150 = 0.4 m; lines shorter than 8 heights get none
    long_index = [c for c in cs.lines if c.index and c.length_m >= 8 * h]
    assert len(labels) >= len(long_index) >= 2
    assert {t.dxf.text for t in labels} == {f"{c.level_m:.1f}" for c in long_index}
    assert doc.header["$INSUNITS"] == 6
    assert CRS.from_wkt((tmp_path / "c.prj").read_text()).to_epsg() == 32632

    # GeoPackage: the CRS with its vertical (ellipsoidal-height) axis, attributes elevation_m and index
    write_contours(cs, tmp_path / "c.gpkg")
    info = pyogrio.read_info(tmp_path / "c.gpkg")
    crs = CRS.from_user_input(info["crs"])
    assert len(crs.axis_info) == 3 and crs.to_2d().to_epsg() == 32632
    assert "ellipsoidal height" in crs.axis_info[2].name.lower()
    assert info["features"] == n and info["geometry_type"] == "LineString Z"
    _, _, geoms, fields = read(tmp_path / "c.gpkg")
    el = dict(zip(info["fields"], fields))["elevation_m"]
    assert sorted(set(el.round(6))) == levels

    # Shapefile: the .prj carries the vertical CRS too
    write_contours(cs, tmp_path / "c.shp")
    sinfo = pyogrio.read_info(tmp_path / "c.shp")
    assert sinfo["features"] == n and "elev_m" in list(sinfo["fields"]) and "VERTCS" in (tmp_path / "c.prj").read_text()

    # GeoJSON (RFC 7946): lon/lat back to UTM lie on the truth surface within the band, heights = levels
    write_contours(cs, tmp_path / "c.geojson")
    fc = json.loads((tmp_path / "c.geojson").read_text())
    assert len(fc["features"]) == n and "ellipsoidal" in fc["georef"]["heights"]
    tr = Transformer.from_crs(4326, 32632, always_xy=True)
    for f in fc["features"][:5]:
        c = np.array(f["geometry"]["coordinates"])
        e, nn = tr.transform(c[:, 0], c[:, 1])
        assert np.allclose(c[:, 2], f["properties"]["elevation_m"])
        assert np.abs(C.truth_height(e, nn) - f["properties"]["elevation_m"]).max() <= INTERVAL_M / 2
