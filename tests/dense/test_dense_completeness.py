"""Complete surfaces: the tiers of the DSM (full resolution, two-view edge points, coarse pass), the mask and
support rasters, the flat-area noise figure, and a simulated survey with weakly textured patches (a soil
pad with texture only 1-3 m across, a uniform pond)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from georef_core.dense.dsm_raster import MASK_COARSE, MASK_FILLED, MASK_MEASURED, RasterGrid
from georef_core.dense.dsm_support import SUPPORT_NONE, tiered_dsm


def _plane(e, n):
    return 100.0 + 0.03 * e - 0.02 * n


def test_tiers_fill_only_what_better_tiers_left_empty():
    rng = np.random.default_rng(5)
    res = 0.1
    grid = RasterGrid(0.0, 10.0, res, 100, 100)
    E, N = grid.centres()
    e, n = E.ravel(), N.ravel()
    hole = (np.abs(e - 5) < 2.0) & (np.abs(n - 5) < 2.0)  # 40 x 40 cells without full-resolution points
    gap = (np.abs(e - 1.05) < 0.05) & (np.abs(n - 1.05) < 0.05)  # one isolated empty cell
    two_view = hole & (e < 3.5)  # a strip of the hole seen by two views only
    strong = ~hole & ~gap
    z_fine = _plane(e, n) + rng.normal(0, 0.01, e.size)
    pts = np.column_stack([e, n, z_fine])
    nv = np.where(strong, 5, np.where(two_view, 2, 0)).astype(np.uint8)
    keep = strong | two_view
    # the coarse pass: one point per 2 x 2 cells everywhere, 3 cm noise, 5 cm high (to tell it apart)
    ce, cn = np.meshgrid(np.arange(0.1, 10, 0.2), np.arange(0.1, 10, 0.2))
    ce, cn = ce.ravel(), cn.ravel()
    cpts = np.column_stack([ce, cn, _plane(ce, cn) + 0.05 + rng.normal(0, 0.03, ce.size)])
    t = tiered_dsm(grid, pts[keep], nv[keep], 3, cpts, np.full(ce.size, 4, np.uint8), 0.2, 30.0)
    m = t.mask.ravel()
    truth = _plane(e, n)
    # full-resolution cells: exactly the fine points (one per cell), untouched by the other tiers
    assert np.all(m[strong] == MASK_MEASURED)
    assert np.allclose(t.dsm.ravel()[strong], z_fine[strong], atol=1e-5)
    # the two-view strip: measured, support 2
    assert np.all(m[two_view] == MASK_MEASURED) and np.all(t.support.ravel()[two_view] == 2)
    # the rest of the hole: the coarse pass, within its noise of the truth; support = its views
    inner = hole & ~two_view
    far = inner & (e > 3.8) & (e < 6.8) & (np.abs(n - 5) < 1.8)
    assert np.all(m[far] == MASK_COARSE)
    assert np.all(t.support.ravel()[far] == 4)
    assert abs(np.median(t.dsm.ravel()[far] - truth[far]) - 0.05) < 0.01
    # the isolated one-cell gap: interpolated from its neighbours (not the coarse pass), support 0
    assert np.all(m[gap] == MASK_FILLED) and np.all(t.support.ravel()[gap] == SUPPORT_NONE)
    assert np.abs(t.dsm.ravel()[gap] - truth[gap]).max() < 0.02
    # the coarse pass checks itself against the fine cells where both measured
    assert abs(t.stats["coarse_minus_fine_m"]["median"] - 0.05) < 0.01


def test_flat_area_noise_recovers_the_noise_of_a_plane():
    from georef_core.dense.dsm_quality import flat_area_noise

    rng = np.random.default_rng(3)
    res = 0.1
    yy, xx = np.mgrid[0:300, 0:300] * res
    z = 50 + 0.05 * xx + 0.02 * yy + rng.normal(0, 0.02, xx.shape)
    z[:, 150:] += 0.5 * np.sin(xx[:, 150:] * 3.0)  # rough half: not a plane, not noise
    r = flat_area_noise(z, np.ones(z.shape, bool), res)
    assert r["windows"] == 100
    assert 0.017 < r["nmad_m"] < 0.023, r  # 2 cm of noise, from the planar half only
    assert r["all_windows_median_nmad_m"] > 0.05


PATCHES = ((-2.0, 4.5, 3.0, "soil"), (11.0, -4.0, 2.5, "water"))


@pytest.fixture(scope="module")
def patched_run(tmp_path_factory):
    """The small simulated survey with a soil pad (texture only 1-3 m across) and a pond (uniform), dense
    with the texture threshold on (stereo.min_texture_std 2.5 grey levels)."""
    from tests.dense.conftest import rendering_available

    if not rendering_available():
        pytest.skip("open3d / Pillow / piexif / rasterio / opencv / laspy missing")
    from georef_core.photo.oriented_images import oriented_images_from_simulator_truth
    from georef_core.sim import SimulationOptions, simulate_site
    from georef_core.steps.dense import run_dense

    o = SimulationOptions.small()
    o.gnss = None
    o.texture.weak_patches = PATCHES
    sim = simulate_site(tmp_path_factory.mktemp("weak_sim"), seed=1, options=o, verbose=False)
    out = tmp_path_factory.mktemp("weak_run")
    oriented_images_from_simulator_truth(sim.out_dir).write(out / "oriented_images.json")
    summary = run_dense(out, {"workers": 2, "ortho": False, "stereo": {"min_texture_std": 2.5}})
    return sim, out, summary


def _patch_cells(sim, out):
    import rasterio
    from rasterio.warp import Resampling, reproject

    d = out / "dense"
    with rasterio.open(d / "dsm.tif") as ds:
        z = ds.read(1, masked=True).filled(np.nan)
        T, crs = ds.transform, ds.crs
    with rasterio.open(d / "dsm_filled_mask.tif") as ms:
        mask = ms.read(1)
    with rasterio.open(d / "dsm_support.tif") as ss:
        support = ss.read(1)
        assert ss.nodata == 255 and ss.dtypes[0] == "uint8" and ss.transform == T
        assert ss.count == 2    # band 2: why a cell has or lacks a measurement (dsm_support.CAUSE_*)
    with rasterio.open(sim.out_dir / "truth" / "dsm.tif") as rs:
        ref = np.full(z.shape, np.nan)
        reproject(rs.read(1).astype(float), ref, src_transform=rs.transform, src_crs=rs.crs, dst_transform=T,
                  dst_crs=crs, resampling=Resampling.average)
    f = json.loads((sim.out_dir / "truth" / "site.json").read_text())["frame"]
    r, c = np.indices(z.shape)
    x = T.c + (c + 0.5) * T.a - f["origin_E_m"]
    y = T.f + (r + 0.5) * T.e - f["origin_N_m"]
    cells = {kind: np.hypot(x - px, y - py) < pr - 0.3 for px, py, pr, kind in PATCHES}
    return z - ref, mask, support, cells


def test_weak_texture_soil_is_measured_by_the_coarse_pass(patched_run):
    sim, out, summary = patched_run
    dz, mask, support, cells = _patch_cells(sim, out)
    soil = cells["soil"]
    measured = soil & ((mask == MASK_MEASURED) | (mask == MASK_COARSE))
    assert measured.sum() > 0.7 * soil.sum()  # measured 0.82 (0.13 full resolution, 0.69 coarse)
    coarse = soil & (mask == MASK_COARSE)
    assert coarse.sum() > 0.5 * soil.sum()
    d = dz[coarse]
    assert np.sqrt(np.mean(d * d)) < 0.20  # measured 13.7 cm: 4x coarser images (160 x 120 px)
    assert np.all(support[coarse] >= 2)
    assert summary["dsm"]["coarse_cells"] == int(np.count_nonzero(mask == MASK_COARSE))
    assert summary["coarse_pass"]["points"] > 1000


def test_uniform_pond_is_marked_unsupported(patched_run):
    sim, out, _ = patched_run
    dz, mask, support, cells = _patch_cells(sim, out)
    pond = cells["water"]
    interp = pond & (mask == MASK_FILLED)
    assert interp.sum() > 0.3 * pond.sum()  # measured 0.51: nothing to match in its middle at any scale
    assert np.all(support[interp] == SUPPORT_NONE)
    assert np.all(support[pond & (mask != MASK_FILLED)] >= 2)
    # and flagged for why: the images see the pond (it is in the middle of the block) but agree on no depth there
    from georef_core.dense.dsm_support import CAUSE_FILLED_SEEN, cause_counts

    import rasterio

    with rasterio.open(out / "dense" / "dsm_support.tif") as ss:
        causes = ss.read(2)
    assert np.all(causes[interp] == CAUSE_FILLED_SEEN)
    assert cause_counts(causes) == patched_run[2]["dsm"]["cells_by_cause"]
    # its surface is flat: the interpolation across it is close (not a claim of measurement)
    assert np.sqrt(np.nanmean(dz[interp] ** 2)) < 0.10  # measured 2.9 cm
