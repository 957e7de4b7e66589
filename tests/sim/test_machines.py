"""Machines on a simulated site (SiteOptions.machines): a default site is unchanged, machines stand on open
ground with vertical sides, surface = bare earth + machines, and their truth files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from georef_core.sim.site import SiteOptions, build_site


def test_default_site_has_no_machines_and_machines_leave_the_rest_unchanged():
    plain = build_site(SiteOptions(), seed=42)
    busy = build_site(SiteOptions(machines=6), seed=42)
    assert plain.machines == [] and "machines" not in plain.to_dict()
    assert len(busy.machines) == 6
    assert [(p.cx, p.cy, p.z0) for p in plain.piles] == [(p.cx, p.cy, p.z0) for p in busy.piles]
    assert [(t.x, t.y, t.z) for t in plain.targets] == [(t.x, t.y, t.z) for t in busy.targets]
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-80, 80, 20000), rng.uniform(-50, 50, 20000)
    off = busy.machine_index(x, y) < 0
    np.testing.assert_array_equal(plain.surface(x, y), busy.bare_earth(x, y))
    np.testing.assert_array_equal(plain.surface(x[off], y[off]), busy.surface(x[off], y[off]))


def test_machines_are_steep_sided_blocks_on_open_ground():
    site = build_site(SiteOptions(machines=6), seed=7)
    o = site.options
    for m in site.machines:
        assert 2.5 <= m.height_m <= 4.0 and m.kind in ("truck", "excavator", "box")
        pts = m.outline_points(0.25)
        ext = np.ptp(np.stack(m.to_local(pts[:, 0], pts[:, 1]), -1), axis=0)
        assert 3.0 <= ext.max() <= 10.0 and ext.min() >= 2.4
        # clear of the piles' pads, the pit and the targets
        assert min(float(np.min(p.footprint_sdf(pts[:, 0], pts[:, 1]))) for p in site.piles) >= \
            o.pad_margin_m + o.pad_blend_m + 3.0
        assert site.pit is None or float(np.min(site.pit_sdf(pts[:, 0], pts[:, 1]))) >= 3.0
        assert all(float(m.footprint_sdf(t.x, t.y)) >= 3.0 for t in site.targets)
        # vertical sides: 5 cm inside the outline the surface is the machine's top, 5 cm outside the bare earth
        c = np.array([m.cx, m.cy])
        v = c - pts
        nv = np.linalg.norm(v, axis=1, keepdims=True)
        inside = (pts + 0.05 * v / np.maximum(nv, 1e-9))[nv[:, 0] > 0.1]
        inside = inside[m.footprint_sdf(inside[:, 0], inside[:, 1]) < -0.04]
        assert np.all(site.surface(inside[:, 0], inside[:, 1]) - site.bare_earth(inside[:, 0], inside[:, 1]) >= 1.0)
        top = m.base_z + m.height_m
        xs, ys = m.to_site(np.linspace(-3, 3, 50), np.zeros(50))
        assert np.max(site.surface(xs, ys)) <= top + 1e-9
        assert np.all(m.top(xs, ys)[m.footprint_sdf(xs, ys) <= 0] >= site.bare_earth(xs, ys)[m.footprint_sdf(xs, ys) <= 0])


def test_truth_files_of_the_machines(tmp_path):
    import rasterio

    from georef_core.sim.machines import machines_geojson
    from georef_core.sim.truth import write_dsm

    site = build_site(SiteOptions(size_m=(60.0, 40.0), stockpiles=("cone",), stockpile_scale=0.6, pit=False,
                                  hillside=False, n_roads=1, machines=2), seed=5)
    assert len(site.machines) == 2
    gj = machines_geojson(site)
    assert [f["properties"]["name"] for f in gj["features"]] == ["M01", "M02"]
    area = sum(f["properties"]["footprint_area_m2"] for f in gj["features"])
    bounds = (-site.half_w, -site.half_h, site.half_w, site.half_h)
    write_dsm(tmp_path / "dsm.tif", site, 0.1, bounds)
    write_dsm(tmp_path / "dtm.tif", site, 0.1, bounds, bare_earth=True)
    with rasterio.open(tmp_path / "dsm.tif") as a, rasterio.open(tmp_path / "dtm.tif") as b:
        d = a.read(1).astype(float) - b.read(1).astype(float)
        assert "bare earth" in b.tags()["SOURCE"]
    assert np.all(d >= -1e-4)
    assert float(np.sum(d > 0.5)) * 0.01 == pytest.approx(area, rel=0.03)
    json.dumps(site.to_dict())  # the site description (truth/site.json) holds the machines
    assert len(site.to_dict()["machines"]) == 2
