"""Benchmark: the orthophoto KMZ of a large orthophoto, as one reduced image and as a super-overlay
(georef_core/deliverables/kmz_writer.py). A synthetic orthophoto (textured ground with roads and piles,
a no-data margin, 3 cm pixels, EPSG:32633) is written as a cloud-optimised GeoTIFF with overviews, as the
dense step writes its orthophoto; prints, for each form, the time, the KMZ size, the overlay's finest ground
pixel and the tile counts per level, and the ratio of the finest pixels (one image / super-overlay).

    python bench/kmz_super_overlay.py                 # 8000 x 8000 px (240 m at 3 cm)
    python bench/kmz_super_overlay.py --size 4000 --max-tiles 256
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
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
    ap.add_argument("--max-tiles", type=int, default=1024, help="tiles at the finest level, at most")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        ortho = tmp / "ortho.tif"
        t = time.perf_counter()
        write_ortho(ortho, a.size)
        print(f"orthophoto {a.size} x {a.size} px, {CELL_M * 100:.0f} cm pixels ({a.size * CELL_M:.0f} m): written in "
              f"{time.perf_counter() - t:.1f} s")
        t = time.perf_counter()
        one = write_kmz(ortho, tmp / "one.kmz", tile_threshold_px=10 ** 9)
        t_one = time.perf_counter() - t
        print(f"one image  : {t_one:6.1f} s, {(tmp / 'one.kmz').stat().st_size / 1e6:7.1f} MB, "
              f"{one['width_px']} x {one['height_px']} px, {one['pixel_m'] * 100:.1f} cm pixels")
        t = time.perf_counter()
        sup = write_kmz(ortho, tmp / "tiled.kmz", max_tiles=a.max_tiles)
        t_sup = time.perf_counter() - t
        print(f"super-overlay: {t_sup:6.1f} s, {(tmp / 'tiled.kmz').stat().st_size / 1e6:7.1f} MB, {sup['tiles']} tiles "
              f"over zoom levels {sup['levels'][0]}-{sup['levels'][-1]} ({sup['tiles_per_level']}), finest pixel "
              f"{sup['pixel_m'] * 100:.1f} cm ({sup['tiles'] / t_sup:.0f} tiles/s)")
        print(f"ratio of the finest ground pixels, one image / super-overlay: {one['pixel_m'] / sup['pixel_m']:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
