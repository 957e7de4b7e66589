"""Japan's geoid (GSIGEO2011, JGD2011 (vertical) height EPSG:6695) from the PyPI package japan-geoid, decoded and
written once as the PROJ grid jp_gsi_gsigeo2011.tif (georef_core/datums/grids.py), used through PROJ's own
transformation.

Reference values: the test program of MapIV's llh_converter (test/src/gsigeo_test.cpp in MapIV/llh_converter,
which reads GSI's own gsigeo2011_ver2_1.asc with GSI's interpolation): 40.1954 m at 36.104394 N 140.085365 E
(Tsukuba) and 36.6453 m at 35.160410 N 139.615526 E (Miura), given to 0.1 mm."""

from __future__ import annotations

import numpy as np
import pytest

from georef_core.datums import grids
from georef_core.datums import vertical_datum as vd
from georef_core.errors import ProcessingError

LLH_CONVERTER = np.array([(36.104394, 140.085365, 40.1954), (35.160410, 139.615526, 36.6453)])


@pytest.fixture(scope="module")
def gsigeo(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv(grids.GRID_CACHE_ENV, str(tmp_path_factory.mktemp("grid_cache")))
    path = grids.ensure_packaged_gsigeo2011()
    yield path
    mp.undo()


def test_jgd2011_heights_through_proj_match_published_values(gsigeo):
    assert gsigeo is not None and gsigeo.name == grids.GSIGEO2011_TIF and gsigeo.is_file()
    assert vd.resolve("jgd2011") is vd.resolve("EPSG:6695") and vd.is_available("jgd2011")
    op = vd.transformation("jgd2011")
    assert op["grid"] == str(gsigeo) and "vgridshift" in op["definition"]
    lat, lon, want = LLH_CONVERTER.T
    N = vd.geoid_undulation_m("jgd2011", lat, lon)
    assert np.abs(N - want).max() <= 0.0002, N              # published to 0.1 mm (ver. 2.1; the package has 2.2)
    H = vd.ellipsoidal_to_orthometric("jgd2011", lat, lon, np.array([100.0, 250.0]))
    assert np.allclose(H, [100.0, 250.0] - N, atol=1e-6)
    with pytest.raises(ProcessingError):                     # at sea off Japan: GSIGEO2011 has no value there
        vd.geoid_undulation_m("jgd2011", np.array([30.0]), np.array([145.0]))


def test_the_grid_holds_the_package_values(gsigeo):
    """The decoded grid against the package's own interpolation at its nodes, and PROJ's bilinear interpolation
    against the package's between them."""
    import japan_geoid
    import rasterio

    geoid = japan_geoid.load_embedded_gsigeo2011()
    h, lon0, lat0, dlon, dlat, version = grids.decode_gsi_binary(geoid.to_binary())
    assert h.shape == (1801, 1201) and (lon0, lat0) == (120.0, 20.0) and version == "ver2.2"
    rng = np.random.default_rng(5)
    i, j = rng.integers(0, 1800, 20000), rng.integers(0, 1200, 20000)
    ref = geoid.get_heights(lon0 + j * dlon, lat0 + i * dlat)
    ok = np.isfinite(ref)
    assert ok.sum() > 1000 and np.abs(h[i, j][ok] - ref[ok]).max() < 1e-9
    with rasterio.open(gsigeo) as ds:                        # rows north to south, nodes at pixel centres
        assert ds.crs.to_epsg() == 6668 and ds.tags()["AREA_OR_POINT"] == "Point"
        grid = ds.read(1, masked=True)[::-1]
    assert np.abs(grid[i, j][ok] - ref[ok]).max() < 1e-5     # float32 storage
    lat, lon = rng.uniform(31, 44, 4000), rng.uniform(130, 145, 4000)
    ref = geoid.get_heights(lon, lat)
    ok = np.isfinite(ref)
    N = vd.geoid_undulation_m("jgd2011", lat[ok], lon[ok])
    assert ok.sum() > 300 and np.abs(N - ref[ok]).max() < 1e-5
