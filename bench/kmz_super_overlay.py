"""Benchmark: the orthophoto KMZ of a large orthophoto, as one reduced image, as the earlier super-overlay
capped at 1024 finest tiles, and as the regionated pyramid down to the zoom that resolves it (no cap)
(georef_core/deliverables/kmz_writer.py). A synthetic orthophoto (textured ground with roads and piles,
a no-data margin, 3 cm pixels, EPSG:32633) is written as a cloud-optimised GeoTIFF with overviews, as the
dense step writes its orthophoto; prints, for each form, the time, the KMZ size, the overlay's finest ground
pixel, the tile counts per level and the Python heap's peak while writing (tracemalloc: numpy arrays and the
encoded tiles; the earlier writer also held every encoded tile until the end, printed as "held"), and the
ratios of the pyramid to the capped overlay.

    python bench/kmz_super_overlay.py                 # 8000 x 8000 px (240 m at 3 cm)
    python bench/kmz_super_overlay.py --size 20000 --no-one-image
    python bench/kmz_super_overlay.py --size 20000 --plan  # the tile counts per level only
    python bench/kmz_super_overlay.py --size 4000 --max-tiles 256
    python bench/kmz_super_overlay.py --size 4000 --no-one-image --drawing   # the tile drawer against the reference

``--drawing`` also draws every tile of the pyramid twice, by the reference (tiles.render.render_tile_rgba: GDAL's
warper, the raster opened per tile) and by the KMZ writer's drawer (tiles.render.RgbTileDrawer), in this process,
and prints the time of each, their ratio and the largest colour difference (grey levels, where both are opaque)
with the count of pixels that differ; then writes the pyramid KMZ with the reference drawing (write_super_overlay
fast_tiles=False) and prints the ratio of the whole write, reference / drawer.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from georef_core.deliverables.kmz_writer import write_kmz  # noqa: E402

E0, N0, EPSG, CELL_M = 512_000.0, 5_123_000.0, 32633, 0.03


def write_ortho(path: Path, size: int) -> None:
    import rasterio
    from rasterio.transform import from_origin

    rng = np.random.default_rng(5)
    rows = 512
    profile = dict(driver="GTiff", width=size, height=size, count=3, dtype="uint8", crs=f"EPSG:{EPSG}",
                   transform=from_origin(E0, N0, CELL_M, CELL_M), nodata=0, tiled=True, blockxsize=512,
                   blockysize=512, compress="deflate")
    with rasterio.open(path, "w", **profile) as ds:
        x = np.arange(size) * CELL_M
        for r0 in range(0, size, rows):
            n = min(rows, size - r0)
            y = (r0 + np.arange(n))[:, None] * CELL_M
            g = 120 + 35 * np.sin(x[None, :] / 7.0) * np.cos(y / 11.0) + rng.normal(0, 10, (n, size))
            road = np.abs(x[None, :] - 0.5 * y - 40.0) < 3.0
            pile = np.hypot(x[None, :] - 0.6 * size * CELL_M, y - 0.4 * size * CELL_M) < 25.0
            rgb = np.stack([g * 0.9, g, g * 0.7])
            rgb[:, road] = 205
            rgb[:, pile] = np.array([160, 125, 95])[:, None]
            rgb = np.clip(rgb, 1, 255).astype(np.uint8)
            margin = (x[None, :] + 0 * y) < 0.05 * size * CELL_M          # a no-data strip on the west
            rgb[:, margin] = 0
            ds.write(rgb, window=rasterio.windows.Window(0, r0, size, n))
        ds.build_overviews([2, 4, 8, 16, 32, 64], rasterio.enums.Resampling.average)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=8000, help="orthophoto width and height, px")
    ap.add_argument("--max-tiles", type=int, default=1024, help="the earlier cap: tiles at the finest level")
    ap.add_argument("--no-one-image", action="store_true", help="skip the one-image KMZ (slow on large rasters)")
    ap.add_argument("--drawing", action="store_true", help="compare the tile drawer with the reference (time, "
                    "largest difference) and write the pyramid with the reference drawing too")
    ap.add_argument("--plan", action="store_true", help="only count the tiles per level of both forms (nothing "
                    "drawn): the pyramid's tile count and levels for a size too slow to run here")
    a = ap.parse_args()
    if a.plan:
        from pyproj import Transformer

        from georef_core.deliverables.kmz_writer import overlay_levels, tile_range
        from georef_core.tiles.mercator import ground_pixel_m, zoom_for_pixel

        side = a.size * CELL_M
        lon, lat = Transformer.from_crs(EPSG, 4326, always_xy=True).transform([E0, E0 + side], [N0 - side, N0])
        box = (lon[0], lat[0], lon[1], lat[1])
        zf = zoom_for_pixel(CELL_M, (lat[0] + lat[1]) / 2)

        def count(z):
            x0, y0, x1, y1 = tile_range(box, z)
            return (x1 - x0 + 1) * (y1 - y0 + 1)

        for label, cap in (("capped", a.max_tiles), ("pyramid", None)):
            lv = overlay_levels(box, zf, cap)
            per = {z: count(z) for z in lv}
            print(f"{label:8s}: zoom levels {lv[0]}-{lv[-1]}, at most {sum(per.values())} tiles {per}, finest pixel "
                  f"{ground_pixel_m(lv[-1], lat[0]) * 100:.1f} cm")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        ortho = tmp / "ortho.tif"
        t = time.perf_counter()
        write_ortho(ortho, a.size)
        print(f"orthophoto {a.size} x {a.size} px, {CELL_M * 100:.0f} cm pixels ({a.size * CELL_M:.0f} m): written in "
              f"{time.perf_counter() - t:.1f} s")

        def timed(out, **kw):
            tracemalloc.start()
            t = time.perf_counter()
            try:
                r = write_kmz(ortho, out, **kw)
                _, peak = tracemalloc.get_traced_memory()
            finally:
                tracemalloc.stop()
            return r, time.perf_counter() - t, peak / 1e6, out.stat().st_size / 1e6

        if not a.no_one_image:
            one, t_one, _, mb = timed(tmp / "one.kmz", tile_threshold_px=10 ** 9)
            print(f"one image  : {t_one:6.1f} s, {mb:7.1f} MB, {one['width_px']} x {one['height_px']} px, "
                  f"{one['pixel_m'] * 100:.1f} cm pixels")
        res = {}
        for label, cap in (("capped", a.max_tiles), ("pyramid", None)):
            r, dt, peak, mb = timed(tmp / f"{label}.kmz", max_tiles=cap, tile_threshold_px=1024)
            with zipfile.ZipFile(tmp / f"{label}.kmz") as z:
                held = sum(i.file_size for i in z.infolist() if i.filename.endswith((".jpg", ".png"))) / 1e6
            res[label] = (r, dt, mb)
            print(f"{label:8s} super-overlay: {dt:6.1f} s, {mb:7.1f} MB, {r['tiles']} tiles over zoom levels "
                  f"{r['levels'][0]}-{r['levels'][-1]} ({r['tiles_per_level']}), finest pixel {r['pixel_m'] * 100:.1f} cm "
                  f"({r['tiles'] / dt:.0f} tiles/s); heap peak {peak:.0f} MB (encoded tiles: {held:.0f} MB, what the "
                  f"earlier writer held)")
        (rc, tc, mc), (rp, tp, mp) = res["capped"], res["pyramid"]
        print(f"ratios pyramid / capped: time {tp / tc:.2f}, size {mp / mc:.2f}, tiles {rp['tiles'] / rc['tiles']:.2f}, "
              f"finest pixel {rp['pixel_m'] / rc['pixel_m']:.2f}")
        if not a.no_one_image:
            print(f"ratio of the finest ground pixels, one image / pyramid: {one['pixel_m'] / rp['pixel_m']:.2f}")
        if a.drawing:
            compare_drawing(ortho, tmp, tp)
    return 0


def compare_drawing(ortho: Path, tmp: Path, t_pyramid_s: float) -> None:
    """Every tile of the pyramid drawn by the reference and by the drawer (time, largest difference); the pyramid
    KMZ written with the reference drawing (time against ``t_pyramid_s``, the drawer's)."""
    from georef_core.deliverables.kmz_writer import _level_keys, overlay_levels, write_super_overlay
    from georef_core.tiles.render import RgbTileDrawer, raster_info, render_tile_rgba

    info = raster_info(ortho, "rgb")
    keys = [k for z in overlay_levels(info.lonlat_bounds, info.max_zoom) for k in _level_keys(info.lonlat_bounds, z)]
    worst, n_diff, flips, opaque, t_ref, t_new = 0, 0, 0, 0, 0.0, 0.0
    with RgbTileDrawer(ortho, info) as drawer:
        drawer.rgba(*keys[-1])     # numba's kernels loaded (compiled once, then from its cache) outside the timing
        drawer.drawn_here = drawer.drawn_by_gdal = 0
        for k in keys:
            t = time.perf_counter()
            ref = render_tile_rgba(ortho, info, *k)[0]
            t_ref += time.perf_counter() - t
            t = time.perf_counter()
            new = drawer.rgba(*k)
            t_new += time.perf_counter() - t
            if (ref is None) != (new is None):
                raise SystemExit(f"tile {k}: drawn by one and not the other")
            if ref is None:
                continue
            both = (ref[..., 3] == 255) & (new[..., 3] == 255)
            d = np.abs(ref[..., :3].astype(int) - new[..., :3].astype(int))[both]
            worst, n_diff = max(worst, int(d.max(initial=0))), n_diff + int(np.count_nonzero(d))
            flips += int(np.count_nonzero(ref[..., 3] != new[..., 3]))
            opaque += int(both.sum())
        here, by_gdal = drawer.drawn_here, drawer.drawn_by_gdal
    print(f"tile drawing, the pyramid's {len(keys)} tiles ({here} by the drawer's kernel, {by_gdal} handed to the "
          f"reference): reference {t_ref:.1f} s, drawer {t_new:.1f} s, ratio reference / drawer {t_ref / t_new:.2f}; "
          f"largest colour difference {worst} grey level(s) ({n_diff} of {3 * opaque} opaque pixel values differ), "
          f"{flips} pixel(s) opaque in one and transparent in the other")
    t = time.perf_counter()
    write_super_overlay(ortho, tmp / "reference.kmz", fast_tiles=False)
    t_ref_kmz = time.perf_counter() - t
    print(f"pyramid KMZ with the reference drawing {t_ref_kmz:.1f} s against {t_pyramid_s:.1f} s with the drawer: "
          f"ratio {t_ref_kmz / t_pyramid_s:.2f}")


if __name__ == "__main__":
    raise SystemExit(main())
