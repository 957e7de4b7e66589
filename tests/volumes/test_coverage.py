"""Exact edge-cell coverage: every cell's fraction equals shapely's intersection area of the cell and the
polygon (to 1e-12), on random polygons, holes, multipolygons, rectangular cells and window edges."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from shapely.geometry import MultiPolygon, Polygon

from georef_core.volumes.coverage import coverage_grid, polygon_coverage
from georef_core.volumes.raster_io import GridWindow


def _reference(poly, win: GridWindow) -> np.ndarray:
    ii, jj = np.mgrid[0:win.nrows, 0:win.ncols]
    boxes = shapely.box(win.x0 + jj * win.dx, win.y0 + (ii + 1) * win.dy, win.x0 + (jj + 1) * win.dx, win.y0 + ii * win.dy)
    return shapely.area(shapely.intersection(boxes, poly)) / win.cell_area_m2


def _random_star(rng, cx, cy, rmin, rmax, n):
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = rng.uniform(rmin, rmax, n)
    return Polygon(np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)]))


@pytest.mark.parametrize("seed,dx,dy", [(0, 0.37, -0.37), (1, 0.5, -0.41), (2, 0.25, -0.25), (3, 1.0, -0.6)])
def test_cell_fractions_equal_exact_intersections(seed, dx, dy):
    rng = np.random.default_rng(seed)
    poly = _random_star(rng, 50.0, 30.0, 3.0, 10.0, 40)
    if seed == 2:  # a hole
        poly = poly.difference(shapely.Point(50.0, 30.0).buffer(1.7, 64))
    if seed == 3:  # two parts, one crossing the window's right and bottom edges
        poly = MultiPolygon([poly, shapely.box(62.0, 10.0, 80.0, 25.0)])
    assert poly.is_valid
    win = GridWindow(0, 0, int(30 / abs(dy)), int(30 / dx), 36.3, 46.1, dx, dy)
    cov = coverage_grid(poly, win, np.float64)
    ref = _reference(poly, win)
    assert np.abs(cov - ref).max() < 1e-12
    inside = poly.intersection(shapely.box(win.x0, win.y0 + win.nrows * dy, win.x0 + win.ncols * dx, win.y0)).area
    assert cov.sum() * win.cell_area_m2 == pytest.approx(inside, rel=1e-12)


def test_polygon_larger_than_window_and_degenerate_edges():
    """A polygon covering the whole window (all edges outside) gives 1 everywhere; horizontal and vertical
    edges exactly on cell lines are exact too."""
    win = GridWindow(0, 0, 20, 30, 100.0, 200.0, 0.5, -0.5)
    big = shapely.box(0.0, 0.0, 1000.0, 1000.0)
    assert np.all(coverage_grid(big, win, np.float64) == 1.0)
    on_lines = shapely.box(101.0, 195.0, 104.5, 198.5)
    cov = coverage_grid(on_lines, win, np.float64)
    assert np.abs(cov - _reference(on_lines, win)).max() < 1e-12
    assert set(np.unique(cov)) <= {0.0, 1.0}


def test_row_view_matches_dense():
    rng = np.random.default_rng(9)
    poly = _random_star(rng, 10.0, 10.0, 4.0, 8.0, 30)
    win = GridWindow(0, 0, 80, 80, 0.0, 20.0, 0.25, -0.25)
    c = polygon_coverage(poly, win)
    full = c.dense(np.float64)
    np.testing.assert_array_equal(c.rows(17, 23).dense(np.float64), full[17:40])
