"""Raster and file pieces of the dense step on synthetic data: median binning, hole filling and flags, the
surface outlier filter, COG writing, LAS/LAZ round trip with the CRS, the DSM comparison."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio

from georef_core.dense.cog_writer import RGBA, write_cog
from georef_core.dense.dsm_compare import compare_dsm
from georef_core.dense.dsm_raster import (MASK_FILLED, MASK_MEASURED, MASK_NODATA, RasterGrid, bin_median,
                                          fill_holes, grid_covering)
from georef_core.dense.point_cloud_filter import surface_outliers
from georef_core.dense.point_cloud_io import read_point_cloud, write_point_cloud
from georef_core.errors import InputFileError
from georef_core.dense.rectified_stereo import median_depth_map


def test_bin_median_matches_brute_force():
    rng = np.random.default_rng(0)
    e = rng.uniform(500000.0, 500003.0, 4000)
    n = rng.uniform(4000000.0, 4000002.0, 4000)
    h = rng.normal(100.0, 1.0, 4000)
    grid = grid_covering(e, n, 0.25)
    assert grid.west == 500000.0 and grid.width == 12 and grid.height == 8
    dsm, cnt = bin_median(grid, e, n, h)
    row, col = grid.cell_index(e, n)
    for r in range(grid.height):
        for c in range(grid.width):
            sel = (row == r) & (col == c)
            assert cnt[r, c] == sel.sum()
            if sel.any():
                assert dsm[r, c] == pytest.approx(np.median(h[sel]), abs=1e-4)  # float32 raster
            else:
                assert np.isnan(dsm[r, c])
    dsm3, _ = bin_median(grid, e, n, h, min_points=cnt.max())
    assert np.isfinite(dsm3).sum() == (cnt == cnt.max()).sum()


def test_holes_filled_inside_flagged_and_not_outside():
    y, x = np.mgrid[0:100, 0:120].astype(float)
    truth = 50.0 + 0.01 * x + 0.02 * y
    dsm = np.full(truth.shape, np.nan)
    cover = (x - 60) ** 2 + (y - 50) ** 2 < 40 ** 2
    dsm[cover] = truth[cover]
    dsm[45:55, 55:65] = np.nan  # an enclosed hole (10 x 10 cells)
    dsm[48:52, 20:22] = np.nan  # a narrow gap at the border side
    out, mask = fill_holes(dsm, max_gap_cells=3)
    assert np.all(mask[45:55, 55:65] == MASK_FILLED)
    assert np.allclose(out[45:55, 55:65], truth[45:55, 55:65], atol=1e-4)  # harmonic fill reproduces a plane
    assert np.all(mask[cover & np.isfinite(dsm)] == MASK_MEASURED)
    assert np.array_equal(out[mask == MASK_MEASURED], dsm[mask == MASK_MEASURED].astype(np.float32))
    far = (x - 60) ** 2 + (y - 50) ** 2 > 44 ** 2
    assert np.all(mask[far] == MASK_NODATA) and np.all(np.isnan(out[far]))


def test_surface_outliers():
    rng = np.random.default_rng(2)
    e = rng.uniform(0, 20, 40000)
    n = rng.uniform(0, 20, 40000)
    h = 10 + 0.3 * np.sin(e / 3) + rng.normal(0, 0.01, e.size)
    h[:200] += rng.choice([-1, 1], 200) * rng.uniform(0.3, 3.0, 200)
    bad = surface_outliers(e, n, h, 0.2)
    assert bad[:200].mean() > 0.95
    assert bad[200:].mean() < 0.002


def testmedian_depth_map():
    a = np.array([[1.0, np.nan, np.nan, 4.0]], np.float32)
    b = np.array([[3.0, 2.0, np.nan, 6.0]], np.float32)
    c = np.array([[2.0, np.nan, np.nan, 100.0]], np.float32)
    m = median_depth_map([a, b, c])
    assert m[0, 0] == 2.0 and m[0, 1] == 2.0 and np.isnan(m[0, 2]) and m[0, 3] == 6.0
    assert median_depth_map([a, b])[0, 0] == 2.0


def test_cog_writer_and_compare(tmp_path):
    grid = RasterGrid(500000.0, 4000100.0, 0.1, 700, 600)
    y, x = np.mgrid[0:600, 0:700]
    z = (80 + 0.01 * x).astype(np.float32)
    write_cog(tmp_path / "ref.tif", z, grid.transform, 32633, nodata=-9999.0)
    z2 = z + np.float32(0.05)
    z2[:50] = -9999.0
    write_cog(tmp_path / "dsm.tif", z2, grid.transform, 32633, nodata=-9999.0, tags={"HEIGHTS": "ellipsoidal"})
    with rasterio.open(tmp_path / "dsm.tif") as ds:
        assert ds.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG" and ds.overviews(1) == [2]
        assert ds.crs.to_epsg() == 32633 and ds.tags()["HEIGHTS"] == "ellipsoidal"
        assert np.array_equal(ds.read(1), z2)
    c = compare_dsm(tmp_path / "dsm.tif", tmp_path / "ref.tif")
    assert c["measured"]["rmse_m"] == pytest.approx(0.05, abs=1e-5)
    assert c["completeness"] == pytest.approx(550 / 600, abs=0.01)
    rgba = np.zeros((4, 600, 700), np.uint8)
    rgba[:, 100:200] = 200
    write_cog(tmp_path / "o.tif", rgba, grid.transform, 32633, colorinterp=RGBA)
    with rasterio.open(tmp_path / "o.tif") as ds:
        assert ds.count == 4 and ds.colorinterp[3] == rasterio.enums.ColorInterp.alpha
        assert np.array_equal(ds.read(), rgba)


def test_las_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    xyz = np.column_stack([rng.uniform(679400, 679600, 5000), rng.uniform(3889100, 3889300, 5000),
                           rng.uniform(70, 90, 5000)])
    rgb = rng.integers(0, 256, (5000, 3)).astype(np.uint8)
    views = rng.integers(3, 12, 5000)
    write_point_cloud(tmp_path / "p.laz", xyz, rgb, 32653, n_views=views)
    assert not (tmp_path / "p.laz.part.laz").exists()
    back, rgb2, crs, las = read_point_cloud(tmp_path / "p.laz")
    assert las.header.are_points_compressed
    assert np.max(np.abs(back - xyz)) <= 0.0005 + 1e-9  # 1 mm integer grid
    assert np.array_equal(rgb2, rgb) and np.array_equal(las.user_data, views)
    assert crs.to_2d().to_epsg() == 32653 and len(crs.axis_info) == 3
    with pytest.raises(InputFileError, match="not found"):
        read_point_cloud(tmp_path / "missing.laz")
    (tmp_path / "bad.laz").write_bytes(b"not a las file")
    with pytest.raises(InputFileError, match="bad.laz"):
        read_point_cloud(tmp_path / "bad.laz")
