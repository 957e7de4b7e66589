"""Analytic stockpile volumes against the truth DSM integrated numerically; site geometry invariants."""

from __future__ import annotations

import math

import numpy as np
import pytest

from georef_core.sim import SiteOptions, build_site
from georef_core.sim.stockpiles import Cone, Frustum, HipPile, Windrow

from .conftest import _have


@pytest.fixture(scope="module")
def site():
    return build_site(SiteOptions(), seed=3)


def _numeric_volume(pile, step=0.01):
    """Midpoint rule on a fine grid of the analytic thickness (independent of the DSM writer)."""
    r = pile.bounding_radius + 0.5
    xs = pile.cx - r + (np.arange(int(2 * r / step)) + 0.5) * step
    total = 0.0
    for i0 in range(0, len(xs), 512):
        X, Y = np.meshgrid(xs, xs[i0:i0 + 512] - pile.cx + pile.cy)
        total += float(pile.height(X, Y).sum())
    return total * step * step


@pytest.mark.parametrize("pile", [
    Cone(name="c", cx=1.0, cy=2.0, radius=7.3, h=5.1),
    Frustum(name="f", cx=0.0, cy=0.0, radius=9.0, top_radius=2.5, h=4.2, gx=0.1, gy=-0.05),
    Windrow(name="w", cx=0.0, cy=0.0, theta=0.7, length=18.0, radius=5.0, top_radius=1.0, h=3.4),
    Windrow(name="w0", cx=0.0, cy=0.0, theta=0.2, length=10.0, radius=4.0, top_radius=0.0, h=2.8),
    HipPile(name="h", cx=0.0, cy=0.0, theta=-0.4, half_length=12.0, half_width=6.0, slope=0.7, h=3.0),
])
def test_volume_formulas(pile):
    assert _numeric_volume(pile, 0.01) == pytest.approx(pile.volume, rel=2e-4)


def test_site_has_all_shapes_and_targets(site):
    kinds = [p.kind for p in site.piles]
    assert sorted(set(kinds)) == ["cone", "frustum", "hip", "windrow"]
    slope = [p for p in site.piles if p.name.endswith("slope_cone")][0]
    assert math.hypot(slope.gx, slope.gy) > 0.05  # stands on the hillside
    assert 5 <= len(site.targets) <= 15
    assert sum(t.role == "control" for t in site.targets) == site.options.n_control
    for t in site.targets:
        assert abs(t.x) <= site.half_w and abs(t.y) <= site.half_h
        assert t.z == pytest.approx(float(site.surface(t.x, t.y)))
        assert all(p.footprint_sdf(t.x, t.y) > 0 for p in site.piles)


def test_pads_are_exact_base_planes(site):
    for p in site.piles:
        r = p.bounding_radius + site.options.pad_margin_m
        X, Y = np.meshgrid(np.linspace(p.cx - r, p.cx + r, 120), np.linspace(p.cy - r, p.cy + r, 120))
        inside = p.footprint_sdf(X, Y) < site.options.pad_margin_m
        np.testing.assert_allclose(site.surface(X, Y)[inside], p.surface(X, Y)[inside], atol=1e-9)


@pytest.mark.skipif(not _have("rasterio"), reason="rasterio missing")
def test_analytic_volumes_match_dsm_integral(site, tmp_path):
    """Fine truth DSM (GeoTIFF written by the truth writer, 4 cm) around each pile, integrated above the
    base plane over the exact-pad region: agrees with the analytic volume to 0.1 %."""
    import rasterio

    from georef_core.sim.truth import write_dsm

    f = site.frame
    res = 0.04
    for p in site.piles:
        r = p.bounding_radius + 0.5
        path = tmp_path / f"{p.name}.tif"
        write_dsm(path, site, res, (p.cx - r, p.cy - r, p.cx + r, p.cy + r))
        with rasterio.open(path) as ds:
            z = ds.read(1).astype(np.float64)
            tr = ds.transform
            assert ds.crs.to_epsg() == f.epsg
        rows, cols = np.mgrid[0:z.shape[0], 0:z.shape[1]]
        e = tr.c + (cols + 0.5) * tr.a
        n = tr.f + (rows + 0.5) * tr.e
        x, y = e - f.origin_e, n - f.origin_n
        m = p.footprint_sdf(x, y) < site.options.pad_margin_m
        vol = float(np.sum((z - p.base_height(x, y))[m])) * res * res
        assert vol == pytest.approx(p.volume, rel=1e-3), p.name


def test_geojson_and_ground_volume(site):
    from georef_core.sim.truth import stockpiles_geojson

    gj = stockpiles_geojson(site)
    assert len(gj["features"]) == len(site.piles)
    for feat, p in zip(gj["features"], site.piles):
        props = feat["properties"]
        assert props["volume_m3"] == pytest.approx(p.volume)
        assert 0.9990 < props["scale_factor"] < 1.0010
        assert props["volume_ground_m3"] == pytest.approx(p.volume / props["scale_factor"] ** 2)
        ring = np.array(feat["geometry"]["coordinates"][0])
        assert np.allclose(ring[0], ring[-1])
