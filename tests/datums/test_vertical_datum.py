"""Vertical datums: geoid heights against PROJ's own transformation with the same grid, DSM and point-cloud
conversion (the interpolation between PROJ nodes measured at every cell / point), the compound CRS read back
by rasterio and laspy, a missing grid, and photos whose heights are EGM96 heights."""

from __future__ import annotations

import math

import laspy
import numpy as np
import pyproj
import pytest
import rasterio
from rasterio.transform import from_origin

from georef_core.datums import vertical_datum as vd
from georef_core.datums.grids import configure_pyproj, find_grid
from georef_core.datums.point_cloud_heights import convert_point_cloud_heights
from georef_core.datums.raster_heights import convert_raster_heights
from georef_core.dense.cog_writer import HEIGHT_TAGS, write_cog
from georef_core.dense.point_cloud_io import write_point_cloud
from georef_core.errors import InputFileError

# the EGM96 grid node where the geoid's slope changes most (measured over the whole 15' grid: 2.2e-4 at
# 28.25 N, 16.75 W, Canary Islands): the worst place for interpolating between PROJ's nodes
KINK_LAT, KINK_LON, KINK_EPSG = 28.25, -16.75, 32628


def _egm96_grid():
    configure_pyproj()           # the reference transformations below use the same installed grid
    g = find_grid(*vd.EGM96.grids)
    assert g is not None, "the EGM96 grid is not installed: make install installs Debian's proj-data"
    return g


def _proj_reference(crs_from, crs_to, probe_xy):
    """PROJ's own best transformation. pyproj's only_best falls back to a 'ballpark' no-op (a mere warning)
    when the grid is missing, which would make these comparisons meaningless: the probe point (where |N| is
    tens of metres) must move."""
    t = pyproj.Transformer.from_crs(crs_from, crs_to, always_xy=True, only_best=True)
    assert abs(t.transform(*probe_xy, 0.0)[2]) > 5.0, "PROJ did not apply the geoid grid (ballpark operation)"
    return t


def _proj_pipeline_undulation(grid, lat, lon):
    """N from PROJ with the grid file named explicitly (no database, no choice of operation)."""
    t = pyproj.Transformer.from_pipeline(
        f"+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
        f"+step +proj=vgridshift +grids={grid} +multiplier=1 +step +proj=unitconvert +xy_in=rad +xy_out=deg")
    _, _, z = t.transform(np.asarray(lon, float), np.asarray(lat, float), np.zeros(np.size(lat)))
    return np.asarray(z)


def test_geoid_heights_agree_with_proj_at_scattered_points():
    grid = _egm96_grid()
    rng = np.random.default_rng(25)
    lat = rng.uniform(-85, 85, 300)
    lon = rng.uniform(-180, 180, 300)
    h = rng.uniform(-50, 3000, 300)
    H = vd.ellipsoidal_to_orthometric("egm96", lat, lon, h)
    # PROJ's own best transformation WGS84 3-D -> WGS84 + EGM96 height
    t = _proj_reference("EPSG:4979", "EPSG:4326+5773", (0.0, 0.0))
    _, _, H_proj = t.transform(lon, lat, h)
    assert np.max(np.abs(H - H_proj)) <= 1e-3
    # the same grid through an explicit vgridshift pipeline
    N = _proj_pipeline_undulation(grid, lat, lon)
    assert np.max(np.abs((h - H) - N)) <= 1e-3
    assert np.ptp(N) > 50.0                       # the grid was applied: EGM96 spans about -105 .. +85 m
    # back to ellipsoidal, and between datums through the ellipsoid
    assert np.max(np.abs(vd.orthometric_to_ellipsoidal("egm96", lat, lon, H) - h)) <= 1e-9
    assert np.max(np.abs(vd.convert_heights(lat, lon, H, "EPSG:5773", "ellipsoidal") - h)) <= 1e-9


def test_datum_names_and_crs():
    assert vd.resolve(None).is_ellipsoidal and vd.resolve("egm96") is vd.resolve("EPSG:5773") is vd.EGM96
    assert vd.resolve("3855") is vd.EGM2008
    assert vd.resolve("EPSG:5701").name == "ODN height"
    for bad in ("EPSG:32631", "geoid", "EPSG:1"):
        with pytest.raises(ValueError):
            vd.resolve(bad)
    crs = vd.compound_crs("EPSG:32631", "egm96")
    assert crs.is_compound and vd.datum_of_crs(crs) is vd.EGM96
    assert vd.datum_of_crs(vd.compound_crs("EPSG:32631", "ellipsoidal")) is vd.ELLIPSOIDAL
    assert vd.datum_of_crs("EPSG:32631") is None          # a 2-D CRS says nothing about heights


def _dsm_across_kink(path, cell_m=4.0, size=300):
    tr = pyproj.Transformer.from_crs("EPSG:4326", f"EPSG:{KINK_EPSG}", always_xy=True)
    e0, n0 = tr.transform(KINK_LON, KINK_LAT)
    half = cell_m * size / 2
    transform = from_origin(e0 - half + 0.37, n0 + half - 0.61, cell_m, cell_m)
    rng = np.random.default_rng(7)
    z = (250.0 + rng.normal(0.0, 3.0, (size, size))).astype(np.float32)
    z[:5, :7] = -9999.0
    write_cog(path, z, transform, KINK_EPSG, nodata=-9999.0, tags=HEIGHT_TAGS)
    return z, transform


def test_dsm_conversion_matches_proj_at_every_cell_and_states_its_datum(tmp_path):
    _egm96_grid()
    z, tr = _dsm_across_kink(tmp_path / "dsm.tif")
    out = convert_raster_heights(tmp_path / "dsm.tif", tmp_path / "dsm_egm96.tif", "egm96")
    rows, cols = np.mgrid[0:z.shape[0], 0:z.shape[1]]
    e, n = tr.c + tr.a * (cols + 0.5), tr.f + tr.e * (rows + 0.5)
    t = _proj_reference(pyproj.CRS.from_epsg(KINK_EPSG).to_3d(), f"EPSG:{KINK_EPSG}+5773", (e[0, 0], n[0, 0]))
    _, _, H = t.transform(e.ravel(), n.ravel(), z.astype(float).ravel())
    H = H.reshape(z.shape)
    with rasterio.open(tmp_path / "dsm_egm96.tif") as src:
        got = src.read(1)
        crs = pyproj.CRS.from_wkt(src.crs.to_wkt())
        tags = src.tags()
        assert src.nodata == -9999.0
    valid = z != -9999.0
    err = np.abs(got[valid].astype(float) - H[valid])
    # float32 storage of ~200 m heights: 15 um; interpolation between nodes 10 m apart: < 0.55 mm (docs)
    assert err.max() <= 1e-3, err.max()
    assert np.all(got[~valid] == -9999.0)
    assert crs.is_compound and vd.datum_of_crs(crs) is vd.EGM96
    assert crs.sub_crs_list[0].to_epsg() == KINK_EPSG
    assert tags["VERTICAL_DATUM"] == "EPSG:5773" and "EGM96" in tags["HEIGHTS"]
    assert out["to"] == vd.EGM96.label and out["dz_m"]["max"] - out["dz_m"]["min"] > 0.01
    # and back: the converted file states its datum, so no --from is needed
    convert_raster_heights(tmp_path / "dsm_egm96.tif", tmp_path / "back.tif", "ellipsoidal")
    with rasterio.open(tmp_path / "back.tif") as src:
        back = src.read(1)
        assert src.crs.to_epsg() == KINK_EPSG and "ellipsoidal" in src.tags()["HEIGHTS"]
    assert np.max(np.abs(back[valid] - z[valid])) <= 1e-4


def test_raster_without_stated_datum_is_refused(tmp_path):
    write_cog(tmp_path / "plain.tif", np.ones((4, 4), np.float32), from_origin(448000, 5412000, 1, 1), 32631)
    with pytest.raises(InputFileError, match="not stated"):
        convert_raster_heights(tmp_path / "plain.tif", tmp_path / "o.tif", "egm96")
    convert_raster_heights(tmp_path / "plain.tif", tmp_path / "o.tif", "egm96", from_datum="ellipsoidal")


def test_point_cloud_conversion_and_compound_wkt(tmp_path):
    _egm96_grid()
    rng = np.random.default_rng(3)
    tr = pyproj.Transformer.from_crs("EPSG:4326", f"EPSG:{KINK_EPSG}", always_xy=True)
    e0, n0 = tr.transform(KINK_LON, KINK_LAT)
    xyz = np.column_stack([e0 + rng.uniform(-600, 600, 20000), n0 + rng.uniform(-600, 600, 20000),
                           rng.uniform(100, 300, 20000)])
    write_point_cloud(tmp_path / "p.laz", xyz, rng.integers(0, 255, (20000, 3)), KINK_EPSG)
    src = laspy.read(tmp_path / "p.laz")
    x, y, z = np.asarray(src.x), np.asarray(src.y), np.asarray(src.z)     # as stored (1 mm)
    out = convert_point_cloud_heights(tmp_path / "p.laz", tmp_path / "p_egm96.laz", "egm96")
    las = laspy.read(tmp_path / "p_egm96.laz")
    crs = las.header.parse_crs()
    assert crs.is_compound and vd.datum_of_crs(crs) is vd.EGM96 and out["points"] == 20000
    t = _proj_reference(pyproj.CRS.from_epsg(KINK_EPSG).to_3d(), f"EPSG:{KINK_EPSG}+5773", (x[0], y[0]))
    _, _, H = t.transform(x, y, z)
    # 1 mm storage rounding (0.5 mm) + interpolation (< 0.55 mm)
    assert np.max(np.abs(np.asarray(las.z) - H)) <= 1.1e-3
    assert np.array_equal(np.asarray(las.red), np.asarray(src.red)) and np.allclose(las.x, x)


def test_missing_grid_is_a_clear_error_and_writes_nothing(tmp_path):
    datum = vd.resolve("EPSG:5701")            # ODN height: OSGM15, no Debian package carries it
    if find_grid(*datum.grids):
        pytest.skip("the OSGM15 grid is installed here")
    assert not vd.is_available(datum)
    with pytest.raises(vd.GridMissingError, match=r"ODN height \(EPSG:5701\).*uk_os_OSGM15_GB\.tif.*not installed"):
        vd.geoid_undulation_m(datum, 52.0, -1.0)
    _dsm_across_kink(tmp_path / "dsm.tif", size=20)
    with pytest.raises(vd.GridMissingError, match="uk_os_OSGM15_GB"):
        convert_raster_heights(tmp_path / "dsm.tif", tmp_path / "odn.tif", datum)
    assert not (tmp_path / "odn.tif").exists()


def _insert_xmp(jpeg, tags: dict) -> None:
    """A drone-dji XMP packet (attribute form, as DJI writes it) spliced in after the JPEG's SOI."""
    attrs = " ".join(f'drone-dji:{k}="{v}"' for k, v in tags.items())
    xmp = ('<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
           f'<rdf:Description rdf:about="" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" {attrs}/>'
           '</rdf:RDF></x:xmpmeta>')
    body = b"http://ns.adobe.com/xap/1.0/\x00" + xmp.encode()
    data = jpeg.read_bytes()
    jpeg.write_bytes(data[:2] + b"\xff\xe1" + (len(body) + 2).to_bytes(2, "big") + body + data[2:])


def test_photos_with_egm96_heights_become_ellipsoidal(tmp_path):
    """survey.json "photo_heights": "egm96": each AbsoluteAltitude is H + N (PROJ, the same grid)."""
    from PIL import Image

    from georef_core.gnss.frames import ecef_to_geodetic
    from georef_core.photo.photo_positions import read_photo_positions

    _egm96_grid()
    pts = [(43.36511377, 141.81345593, 116.56), (43.36611377, 141.81445593, 118.02)]
    names = []
    for k, (lat, lon, H) in enumerate(pts):
        p = tmp_path / f"DJI_{k:04d}.JPG"
        Image.new("RGB", (32, 24), (100, 120, 140)).save(p, format="JPEG")
        _insert_xmp(p, {"GpsLatitude": f"{lat:.8f}", "GpsLongtitude": f"{lon:.8f}", "AbsoluteAltitude": f"{H:+.3f}",
                        "RtkFlag": "50", "RtkStdLon": "0.01", "RtkStdLat": "0.01", "RtkStdHgt": "0.02"})
        names.append(p.name)
    ell = read_photo_positions(tmp_path, names, "ellipsoidal")
    geo = read_photo_positions(tmp_path, names, "egm96")
    t = _proj_reference("EPSG:4979", "EPSG:4326+5773", (pts[0][1], pts[0][0]))
    for k, (lat, lon, H) in enumerate(pts):
        _, _, h0 = ecef_to_geodetic(ell.position_ecef_m[k])
        la, lo, h1 = ecef_to_geodetic(geo.position_ecef_m[k])
        _, _, H_of_h1 = t.transform(lon, lat, h1)             # PROJ takes the converted height back to EGM96
        assert abs(h0 - H) < 1e-6 and abs(H_of_h1 - H) <= 1e-3
        assert abs(h1 - h0) > 10.0                           # the geoid is ~ +30 m there: not silently ignored
        assert abs(math.degrees(la) - lat) < 1e-9 and abs(math.degrees(lo) - lon) < 1e-9
    with pytest.raises(InputFileError, match="photo_heights"):
        read_photo_positions(tmp_path, names, "msl")


def test_control_points_in_a_compound_crs_get_ellipsoidal_heights(tmp_path):
    """gcp/points.csv with points_crs EPSG:32631+5773 (orthometric heights): the adjustment's ENU is the same
    as for the ellipsoidal heights H + N in EPSG:32631."""
    from georef_core.adjustment.control_points import read_points_csv, points_to_enu
    from georef_core.project_frame import ProjectFrame

    _egm96_grid()
    csv = tmp_path / "points.csv"
    csv.write_text("name,easting_m,northing_m,height_m\nA,448100.0,5412200.0,61.250\nB,448900.0,5411400.0,58.1\n")
    frame = ProjectFrame(32631, 448500.0, 5411800.0, 100.0)
    ortho = read_points_csv(csv, "EPSG:32631+5773")
    enu_o = points_to_enu(list(ortho.values()), frame)
    plain = read_points_csv(csv, "EPSG:32631")
    lat, lon = vd.lat_lon_of("EPSG:32631", [448100.0, 448900.0], [5412200.0, 5411400.0])
    N = vd.geoid_undulation_m("egm96", lat, lon)
    for p, n in zip(plain.values(), N):
        p.xyz_crs = p.xyz_crs + np.array([0.0, 0.0, n])
    enu_e = points_to_enu(list(plain.values()), frame)
    assert np.max(np.abs(enu_o - enu_e)) <= 1e-6 and np.min(N) > 40.0
