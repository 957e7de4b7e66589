"""Benchmark: volume of a large polygon on a 100-million-cell DSM (10000 x 10000 float32, 5 cm cells,
500 x 500 m) with georef_core.volumes, against a naive reference that computes the same exact-coverage
volume with rasterio + shapely + numpy (rasterised interior mask, shapely box intersections for the
boundary cells, whole-array numpy arithmetic). Prints the time of each stage, the ratio naive / ours
(> 1: ours is faster) and the agreement of the two volumes.

    python bench/volume_speed.py                   # 10000 x 10000 cells, uncompressed tiled GeoTIFF
    python bench/volume_speed.py --size 4000 --compress deflate --no-naive
"""

from __future__ import annotations

import argparse
import math
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from georef_core.volumes.polygons import AreaPolygon  # noqa: E402
from georef_core.volumes.volume import compute_volume  # noqa: E402

E0, N0, EPSG = 512_000.0, 5_123_000.0, 32633


def terrain(E, N, size_m):
    """Inclined, gently undulating ground with a few large piles and a pit (heights ~100 m)."""
    x, y = E - E0, N - N0
    z = 100.0 + 0.01 * x - 0.004 * y + 0.3 * np.sin(x / 37.0) * np.cos(y / 23.0)
    s = size_m / 500.0
    for cx, cy, r, h in ((0.3, 0.35, 60, 18), (0.62, 0.55, 80, 22), (0.45, 0.72, 45, 12)):
        z = z + h * np.maximum(0.0, 1.0 - np.hypot(x - cx * size_m, y - cy * size_m) / (r * s))
    z = z - 8.0 * np.maximum(0.0, 1.0 - np.hypot(x - 0.7 * size_m, y - 0.25 * size_m) / (40 * s))
    return z


def write_bench_dsm(path: Path, n: int, res: float, compress: str | None) -> None:
    import rasterio
    from affine import Affine
    from rasterio.windows import Window

    size_m = n * res
    prof = {"driver": "GTiff", "width": n, "height": n, "count": 1, "dtype": "float32", "crs": f"EPSG:{EPSG}",
            "transform": Affine(res, 0, E0, 0, -res, N0 + size_m), "tiled": True, "blockxsize": 512,
            "blockysize": 512, "BIGTIFF": "IF_SAFER"}
    if compress:
        prof.update(compress=compress, predictor=3)
    e = E0 + (np.arange(n) + 0.5) * res
    with rasterio.open(path, "w", **prof) as ds:
        for r0 in range(0, n, 512):
            rows = np.arange(r0, min(r0 + 512, n))
            E, N = np.meshgrid(e, N0 + size_m - (rows + 0.5) * res)
            ds.write(terrain(E, N, size_m).astype(np.float32), 1, window=Window(0, r0, n, len(rows)))


def bench_polygon(size_m: float, n_vertices: int = 3000):
    """An irregular star-shaped outline covering about 60 % of the DSM."""
    import shapely

    rng = np.random.default_rng(5)
    a = np.linspace(0, 2 * np.pi, n_vertices, endpoint=False)
    r = 0.44 * size_m * (1.0 + 0.08 * np.sin(5 * a) + 0.04 * np.sin(17 * a + 1.0)) + rng.normal(0, 0.002 * size_m, a.size)
    xy = np.column_stack([E0 + 0.5 * size_m + r * np.cos(a), N0 + 0.5 * size_m + r * np.sin(a)])
    return shapely.Polygon(xy)


def naive_volume(dsm: Path, poly, base_z: float) -> dict:
    """Same quantity, straightforward: whole array in memory, rasterised centre mask, shapely areas of the
    boundary cells, numpy arithmetic on full arrays."""
    import rasterio
    import shapely
    from rasterio.features import rasterize

    t = {}
    t0 = time.perf_counter()
    with rasterio.open(dsm) as ds:
        z = ds.read(1).astype(np.float64)
        tr = ds.transform
    t["read_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    inside = rasterize([(poly, 1)], out_shape=z.shape, transform=tr, all_touched=False, dtype="uint8")
    edge = rasterize([(poly.exterior, 1)], out_shape=z.shape, transform=tr, all_touched=True, dtype="uint8")
    w = inside.astype(np.float64)
    ii, jj = np.nonzero(edge)
    boxes = shapely.box(tr.c + jj * tr.a, tr.f + (ii + 1) * tr.e, tr.c + (jj + 1) * tr.a, tr.f + ii * tr.e)
    w[ii, jj] = shapely.area(shapely.intersection(boxes, poly)) / abs(tr.a * tr.e)
    t["coverage_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    dz = z - base_z
    cell = abs(tr.a * tr.e)
    cut = float(np.sum(w * np.maximum(dz, 0.0))) * cell
    fill = float(np.sum(w * np.maximum(-dz, 0.0))) * cell
    area = float(np.sum(w)) * cell
    t["sums_s"] = time.perf_counter() - t0
    t["total_s"] = sum(t.values())
    return {"cut_m3": cut, "fill_m3": fill, "area_m2": area, "timings_s": t, "boundary_cells": int(len(ii))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=10000, help="DSM cells a side (default 10000: 1e8 cells)")
    ap.add_argument("--res", type=float, default=0.05, help="cell size (m)")
    ap.add_argument("--compress", choices=["none", "deflate", "lzw", "zstd"], default="none")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of ours (best and median printed)")
    ap.add_argument("--no-naive", action="store_true", help="skip the naive reference")
    ap.add_argument("--keep", metavar="DIR", help="write the DSM here (kept) instead of a temporary folder")
    args = ap.parse_args()
    from pyproj import CRS

    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="volbench_"))
    work.mkdir(parents=True, exist_ok=True)
    dsm = work / f"bench_dsm_{args.size}_{args.compress}.tif"
    size_m = args.size * args.res
    if not dsm.exists():
        t0 = time.perf_counter()
        write_bench_dsm(dsm, args.size, args.res, None if args.compress == "none" else args.compress)
        print(f"wrote {dsm} ({args.size} x {args.size} = {args.size ** 2 / 1e6:.0f} M cells, "
              f"{dsm.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - t0:.1f} s")
    poly = AreaPolygon("bench", bench_polygon(size_m), CRS.from_epsg(EPSG), "bench")
    print(f"polygon: {len(poly.geometry.exterior.coords) - 1} vertices, {poly.area_m2:.0f} m^2 = "
          f"{poly.area_m2 / args.res ** 2 / 1e6:.1f} M cells ({100 * poly.area_m2 / size_m ** 2:.0f} % of the DSM)")

    # warm-up: numba kernels loaded from their cache (or compiled once) on a small polygon
    t0 = time.perf_counter()
    small = AreaPolygon("warm", poly.geometry.centroid.buffer(5.0), poly.crs, "warm")
    compute_volume(dsm, small, "plane")
    compute_volume(dsm, small, "lowest")
    print(f"warm-up (imports, numba kernels from cache or compiled): {time.perf_counter() - t0:.2f} s")

    results = {}
    for base in ("lowest", "plane"):
        runs = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            r = compute_volume(dsm, poly, base)
            runs.append((time.perf_counter() - t0, r))
        runs.sort(key=lambda x: x[0])
        best, r = runs[0]
        med = runs[len(runs) // 2][0]
        results[base] = r
        tm = r.timings_s
        print(f"ours, base {base:6s}: best {best:.3f} s, median {med:.3f} s  (read {tm['read_s']:.3f}, base "
              f"{tm['base_s']:.3f}, integrate {tm['integrate_s']:.3f}, uncertainty {tm['uncertainty_s']:.3f}) -> "
              f"cut {r.cut_m3:,.2f} m^3, fill {r.fill_m3:,.2f} m^3, net {r.net_m3:,.2f} ± {r.uncertainty['sigma_m3']:.2f} m^3 "
              f"(1 sigma), area {r.area_m2:,.3f} m^2")
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak resident memory so far: {rss:.0f} MB")
    if not args.no_naive:
        r = results["lowest"]
        zb = r.base["elevation_m"]
        nv = naive_volume(dsm, poly.geometry, zb)
        t = nv["timings_s"]
        print(f"naive reference (same base {zb:.4f} m): {t['total_s']:.3f} s (read {t['read_s']:.3f}, coverage "
              f"{t['coverage_s']:.3f} for {nv['boundary_cells']} boundary cells, sums {t['sums_s']:.3f}) -> cut "
              f"{nv['cut_m3']:,.2f}, fill {nv['fill_m3']:,.2f}, area {nv['area_m2']:,.3f}")
        ours_t = r.timings_s["read_s"] + r.timings_s["integrate_s"]
        print(f"ratio naive / ours (read + coverage + sums vs read + integrate): {t['total_s'] / ours_t:.1f} x; "
              f"whole volume call incl. base fit and uncertainty: {t['total_s'] / r.timings_s['total_s']:.1f} x")
        print(f"agreement: cut {abs(nv['cut_m3'] - r.cut_m3) / r.cut_m3:.2e}, area "
              f"{abs(nv['area_m2'] - r.area_m2) / r.area_m2:.2e} (relative)")
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"peak resident memory: {rss:.0f} MB (naive holds float64 copies of the whole grid)")
    print(f"polygon exact area {poly.area_m2:,.3f} m^2; coverage-weighted area {results['plane'].area_m2:,.3f} m^2 "
          f"(difference {abs(poly.area_m2 - results['plane'].area_m2):.2e} m^2)")
    if not math.isfinite(results["plane"].net_m3):
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
