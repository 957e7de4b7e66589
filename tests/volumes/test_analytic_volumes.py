"""Volumes on synthetic DSMs (GeoTIFF, UTM 33N) of analytic piles against their closed-form volumes, at
5, 10 and 25 cm cells, with every base method; cut and fill where the base crosses the surface; a polygon
in EPSG:4326 gives the DSM-CRS polygon's volume."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from georef_core.sim.stockpiles import Cone, Frustum, HipPile, Windrow
from georef_core.volumes import AreaPolygon, base_from_dict, compute_volume, read_polygons
from georef_core.volumes.uncertainty import NoiseModel

from .synthetic import E0, EPSG, N0, write_dsm, write_geojson

SIZE = 34.0  # DSM side (m)
C = 17.03  # pile centre (site coordinates, m): not on a cell corner
TOL = 1e-3  # 0.1 %
MODEL = NoiseModel(0.03, 0.02, 0.5)


def _pile(kind: str, gx: float, gy: float):
    common = dict(name=kind, cx=C, cy=C - 0.04, z0=100.0, gx=gx, gy=gy)
    if kind in ("cone", "pit"):
        return Cone(radius=8.0, h=5.0, **common)
    if kind == "frustum":
        return Frustum(radius=9.0, top_radius=3.0, h=4.0, **common)
    if kind == "windrow":
        return Windrow(length=18.0, radius=5.0, top_radius=1.0, h=3.4, theta=0.6, **common)
    return HipPile(half_length=12.0, half_width=6.5, slope=0.7, h=3.0, theta=-0.4, **common)


def _scene(tmp_path, kind: str, res: float, inclined: bool):
    gx, gy = (0.04, -0.025) if inclined else (0.0, 0.0)
    p = _pile(kind, gx, gy)
    sign = -1.0 if kind == "pit" else 1.0

    def height(E, N):
        x, y = E - E0, N - N0
        return p.base_height(x, y) + sign * p.height(x, y)

    dsm = write_dsm(tmp_path / f"{kind}_{res}_{int(inclined)}.tif", height, (SIZE, SIZE), res)
    toe = shapely.Polygon(p.footprint_polygon(512) + [E0, N0]).buffer(0.4, 64)
    poly = AreaPolygon(kind, toe, _crs(), "test")
    return dsm, poly, p


def _crs():
    from pyproj import CRS

    return CRS.from_epsg(EPSG)


SHAPES = ["cone", "frustum", "windrow", "hip", "pit"]


@pytest.mark.parametrize("res", [0.05, 0.1, 0.25])
@pytest.mark.parametrize("kind", SHAPES)
def test_inclined_ground_plane_and_tin(tmp_path, kind, res):
    dsm, poly, p = _scene(tmp_path, kind, res, inclined=True)
    for base in ("plane", "tin"):
        r = compute_volume(dsm, poly, base, noise=MODEL)
        if kind == "pit":
            assert r.fill_m3 == pytest.approx(p.volume, rel=TOL)
            assert r.cut_m3 < 1e-4 * p.volume
            assert r.net_m3 == pytest.approx(-p.volume, rel=TOL)
        else:
            assert r.cut_m3 == pytest.approx(p.volume, rel=TOL), (base, r.cut_m3, p.volume)
            assert r.fill_m3 < 1e-4 * p.volume
        assert r.area_m2 == pytest.approx(poly.area_m2, rel=1e-9)
        if base == "plane":
            assert r.base["dz_dx"] == pytest.approx(0.04, abs=1e-6) and r.base["dz_dy"] == pytest.approx(-0.025, abs=1e-6)
            assert r.base["fit"]["rms_m"] < 1e-4
        assert r.uncertainty["sigma_m3"] > 0 and r.uncertainty["ci95_m3"] == pytest.approx(1.96 * r.uncertainty["sigma_m3"],
                                                                                           rel=1e-3)


@pytest.mark.parametrize("res", [0.05, 0.1, 0.25])
@pytest.mark.parametrize("kind", SHAPES)
def test_flat_ground_lowest_highest_mean_elevation(tmp_path, kind, res):
    dsm, poly, p = _scene(tmp_path, kind, res, inclined=False)
    for base in ("lowest", "highest", "mean", "elevation:100"):
        r = compute_volume(dsm, poly, base, noise=MODEL)
        assert r.net_m3 == pytest.approx(-p.volume if kind == "pit" else p.volume, rel=TOL), (base, r.net_m3)
        assert r.base["elevation_m"] == pytest.approx(100.0, abs=1e-5)
    r = compute_volume(dsm, poly, "lowest", noise=MODEL)
    assert r.base["percentile"] == 2.0


def test_lowest_and_highest_on_a_slope_bracket_the_plane(tmp_path):
    """On inclined ground the horizontal lowest/highest bases lie below/above the ground under the pile:
    more/less volume than the plane base, by the expected amounts (percentiles of the outline)."""
    dsm, poly, p = _scene(tmp_path, "cone", 0.1, inclined=True)
    v = {b: compute_volume(dsm, poly, b, noise=MODEL) for b in ("lowest", "highest", "plane", "mean")}
    assert v["lowest"].net_m3 > v["plane"].net_m3 + 10 and v["highest"].net_m3 < v["plane"].net_m3 - 10
    assert v["mean"].net_m3 == pytest.approx(p.volume, rel=TOL)  # mean of a circle's outline = plane at its centre
    assert v["mean"].fill_m3 > 1.0  # horizontal base through inclined ground: void under its low side
    # the 2nd percentile of the outline of a circle of radius R' on a plane of gradient g: z0 - g R' cos(pi p')
    g, rp = math.hypot(0.04, 0.025), 8.4 + 0.15
    expect = 100.0 - g * rp * math.cos(math.pi * 0.02)
    assert v["lowest"].base["elevation_m"] == pytest.approx(expect, abs=0.01)
    assert set(v["plane"].base_nets_m3) == {"mean", "plane", "tin"}


def _ring_integral(alpha, beta, a, c):
    """int_a^c max(alpha - beta r, 0) r dr, elementwise (alpha, beta arrays; a, c scalars)."""
    alpha, beta = np.broadcast_arrays(np.asarray(alpha, float), np.asarray(beta, float))
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = np.clip(np.where(beta != 0, alpha / beta, 0.0), a, c)
    lo = np.where(beta > 0, a, np.where(beta < 0, rs, a))
    hi = np.where(beta > 0, rs, np.where(beta < 0, c, np.where(alpha > 0, c, a)))

    def F(r):
        return alpha * r * r / 2 - beta * r ** 3 / 3

    return F(hi) - F(lo)


def _cut_fill_inclined_base(R, H, Rp, b0, g, n=8192):
    """Cone (radius R, height H on flat ground 0) under a base b0 + g x, over a disc of radius Rp: the
    material above the base and the void below it, by a closed form along each ray and the trapezoid
    rule over the angle (periodic, smooth pieces)."""
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    gc = g * np.cos(th)
    cut = _ring_integral(H - b0, H / R + gc, 0.0, R) + _ring_integral(-b0, gc, R, Rp)
    fill = _ring_integral(-(H - b0), -(H / R + gc), 0.0, R) + _ring_integral(b0, -gc, R, Rp)
    return float(cut.mean() * 2 * np.pi), float(fill.mean() * 2 * np.pi)


@pytest.mark.parametrize("res", [0.05, 0.1, 0.25])
def test_base_crossing_the_surface(tmp_path, res):
    """Horizontal base half-way up a cone (closed form) and an inclined plane through the mound (closed form
    along rays): cut and fill both right, net = cut - fill; the same plane as an imported surface GeoTIFF
    (another grid) gives the same."""
    R, H, Rp = 8.0, 5.0, 9.0
    cx, cy = E0 + C, N0 + C

    def cone(E, N):
        return 100.0 + H * np.maximum(0.0, 1.0 - np.hypot(E - cx, N - cy) / R)

    dsm = write_dsm(tmp_path / "cone.tif", cone, (SIZE, SIZE), res)
    ring = np.column_stack([cx + Rp * np.cos(np.linspace(0, 2 * np.pi, 1024, endpoint=False)),
                            cy + Rp * np.sin(np.linspace(0, 2 * np.pi, 1024, endpoint=False))])
    poly = read_polygons(write_geojson(tmp_path / "p.geojson", {"mound": ring}))[0]

    b = 2.0  # horizontal base 2 m above the ground
    r = compute_volume(dsm, poly, f"elevation:{100 + b}", noise=MODEL)
    rt = R * (1 - b / H)
    cut = math.pi * rt ** 2 * (H - b) / 3
    fill = b * poly.area_m2 - (math.pi * R ** 2 * H / 3 - cut)
    assert r.cut_m3 == pytest.approx(cut, rel=TOL) and r.fill_m3 == pytest.approx(fill, rel=TOL)
    assert r.net_m3 == pytest.approx(cut - fill, rel=TOL)
    assert r.uncertainty["components_m3"]["height_bias_m3"] == pytest.approx(0.02 * r.area_m2, rel=1e-3)

    b0, g = 1.2, 0.3  # inclined plane through the mound: 1.2 m at the centre, rising 0.3 m/m eastwards
    cut, fill = _cut_fill_inclined_base(R, H, Rp, b0, g)
    assert cut > 20 and fill > 20
    plane = base_from_dict({"method": "plane", "x_ref": cx, "y_ref": cy, "z_ref_m": 100 + b0, "dz_dx": g, "dz_dy": 0.0})
    r = compute_volume(dsm, poly, plane, noise=MODEL)
    assert r.cut_m3 == pytest.approx(cut, rel=TOL) and r.fill_m3 == pytest.approx(fill, rel=TOL)
    surf = write_dsm(tmp_path / "plane.tif", lambda E, N: 100 + b0 + g * (E - cx) + 0 * N, (SIZE + 2, SIZE + 2), 0.2,
                     origin=(E0 - 1.0, N0 - 1.0))
    r2 = compute_volume(dsm, poly, f"surface:{surf}", noise=MODEL)
    assert r2.cut_m3 == pytest.approx(cut, rel=TOL) and r2.fill_m3 == pytest.approx(fill, rel=TOL)
    assert r2.base["method"] == "surface" and not r2.base["depends_on_dsm"]


def test_polygon_in_wgs84_gives_the_same_volume(tmp_path):
    p = _pile("windrow", 0.02, 0.01)
    dsm = write_dsm(tmp_path / "w.tif", lambda E, N: p.surface(E - E0, N - N0), (SIZE, SIZE), 0.1)
    ring = np.asarray(shapely.Polygon(p.footprint_polygon(256) + [E0, N0]).buffer(0.5, 16).exterior.coords)[:-1]
    utm = read_polygons(write_geojson(tmp_path / "utm.geojson", {"w": ring}))[0]
    ll = read_polygons(write_geojson(tmp_path / "ll.geojson", {"w": ring}, to_lonlat=True))[0]
    assert ll.crs.to_epsg() == 4326 and utm.crs.to_epsg() == EPSG
    for base in ("plane", "tin", "lowest"):
        a = compute_volume(dsm, utm, base, noise=MODEL)
        b = compute_volume(dsm, ll, base, noise=MODEL)
        assert b.net_m3 == pytest.approx(a.net_m3, rel=1e-6) and b.area_m2 == pytest.approx(a.area_m2, rel=1e-7)
        if base != "lowest":  # lowest: a horizontal base below the inclined ground, more than the pile
            assert a.net_m3 == pytest.approx(p.volume, rel=TOL)
