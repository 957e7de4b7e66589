"""The KMZ super-overlay's tile drawer (georef_core.tiles.render.RgbTileDrawer: the raster kept open, each tile's
warp a numba kernel over an affine fitted to the exact transformation, GDAL's 4-sample bilinear formula) against
the reference, render_tile_rgba (GDAL's warper), tile by tile over every level of the pyramid: a synthetic noisy
orthophoto (UTM, overviews) with a no-data strip and a no-data triangle. Colours within one grey level where both
are opaque, transparency the same but for pixels whose coverage is within a hair of one half; grids rotated
against Mercator (far from the zone's central meridian); a pixel size for which GDAL would widen its kernel
falls back to the reference itself (identical tiles). Speed: bench/kmz_super_overlay.py."""

from __future__ import annotations

import numpy as np
import pytest

EPSG, SIZE_PX = 32633, 500


def _ortho(path, e0: float, n0: float, cell_m: float):
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.transform import from_origin

    rng = np.random.default_rng(3)
    x = np.arange(SIZE_PX)
    g = 110 + 40 * np.sin(x[None, :] / 9.0) * np.cos(x[:, None] / 13.0) + rng.normal(0, 20, (SIZE_PX, SIZE_PX))
    rgb = np.clip(np.stack([g * 0.9, g, g * 0.7]), 1, 255).astype(np.uint8)
    rgb[:, :, :30] = 0                                            # a no-data strip on the west
    rgb[:, x[:, None] + x[None, :] > 1.6 * SIZE_PX] = 0          # and a triangle in the south-east corner
    profile = dict(driver="GTiff", width=SIZE_PX, height=SIZE_PX, count=3, dtype="uint8", crs=f"EPSG:{EPSG}",
                   transform=from_origin(e0, n0, cell_m, cell_m), nodata=0, tiled=True, blockxsize=256,
                   blockysize=256)
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(rgb)
        ds.build_overviews([2, 4, 8], Resampling.average)
    return path


def _compare(path):
    from georef_core.deliverables.kmz_writer import _level_keys, overlay_levels
    from georef_core.tiles.render import RgbTileDrawer, raster_info, render_tile_rgba

    info = raster_info(path, "rgb")
    keys = [k for z in overlay_levels(info.lonlat_bounds, info.max_zoom) for k in _level_keys(info.lonlat_bounds, z)]
    worst, alpha_flips, opaque = 0, 0, 0
    with RgbTileDrawer(path, info) as drawer:
        for k in keys:
            before = drawer.drawn_by_gdal
            ref, new = render_tile_rgba(path, info, *k)[0], drawer.rgba(*k)
            assert (ref is None) == (new is None), k
            if ref is None:
                continue
            if drawer.drawn_by_gdal > before:     # the fallback is the reference itself
                assert np.array_equal(ref, new), k
            both = (ref[..., 3] == 255) & (new[..., 3] == 255)
            opaque += int(both.sum())
            worst = max(worst, int(np.abs(ref[..., :3].astype(int) - new[..., :3].astype(int))[both].max(initial=0)))
            alpha_flips += int((ref[..., 3] != new[..., 3]).sum())
        return len(keys), drawer.drawn_here, drawer.drawn_by_gdal, worst, alpha_flips, opaque


@pytest.mark.parametrize("e0", [512_003.0, 760_011.0])   # near the central meridian, and 260 km east of it
def test_drawn_tiles_match_gdals_within_one_grey_level(tmp_path, e0):
    n, here, by_gdal, worst, alpha_flips, opaque = _compare(_ortho(tmp_path / "o.tif", e0, 5_123_007.0, 0.03))
    assert here == n and by_gdal == 0      # 3 cm at 46 deg N: 1.16 tile pixels a source pixel, the fast path
    assert opaque > 200_000
    assert worst <= 1, worst
    assert alpha_flips <= 1e-5 * opaque + 2, alpha_flips


def test_a_pixel_gdal_would_widen_its_kernel_for_is_drawn_by_gdal(tmp_path):
    # 2.4 cm at 46 deg N: 0.93 tile pixels a source pixel at the finest level, under the 4-sample formula's bound
    # (those tiles are the reference's own); coarser levels read an overview at another ratio
    n, here, by_gdal, worst, alpha_flips, opaque = _compare(_ortho(tmp_path / "o.tif", 512_003.0, 5_123_007.0, 0.024))
    assert by_gdal > 0 and here + by_gdal == n
    assert worst <= 1 and alpha_flips <= 1e-5 * opaque + 2
