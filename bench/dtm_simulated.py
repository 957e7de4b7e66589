"""Bare-earth DTM on a simulated survey with machines, end to end: `georef simulate --machines N` -> `georef
georef` -> `georef dense` -> `georef dtm`, against the simulator's truth (truth/dsm.tif: the surface with the
machines, truth/dtm.tif: the bare earth, truth/machines.geojson, truth/stockpiles.geojson).

Prints the two judged figures:
* the DTM's RMSE against the truth bare earth on open ground (2 m or more from a machine, outside the piles),
  as a ratio to the DSM's RMSE against the truth surface there (the reference run is the DSM of the same
  survey; judged: <= 2);
* the share of the machines' cells the DTM classified non-ground (removed and interpolated; judged: >= 95 %);
and the DTM under the machines, the stockpile cells removed (should be none) and the piles' volumes on the
DSM and the DTM.

    .venv/bin/python bench/dtm_simulated.py [--seed 11] [--images 40] [--image-size 1024 768] [--machines 6]
                                            [--work work_out/bench_dtm]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def on_grid(path: Path, like) -> np.ndarray:
    import rasterio
    from rasterio.warp import Resampling, reproject

    out = np.full((like.height, like.width), np.nan)
    with rasterio.open(path) as t:
        reproject(rasterio.band(t, 1), out, dst_transform=like.transform, dst_crs=like.crs,
                  resampling=Resampling.bilinear, dst_nodata=np.nan)
    return out


def polygons_mask(geojson: Path, like) -> np.ndarray:
    from rasterio.features import rasterize

    feats = json.loads(geojson.read_text())["features"]
    shapes = [(f["geometry"], 1) for f in feats]
    if not shapes:
        return np.zeros((like.height, like.width), bool)
    return rasterize(shapes, out_shape=(like.height, like.width), transform=like.transform, fill=0,
                     dtype="uint8").astype(bool)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--images", type=int, default=40)
    ap.add_argument("--image-size", type=int, nargs=2, default=(1024, 768))
    ap.add_argument("--machines", type=int, default=6)
    ap.add_argument("--work", default="work_out/bench_dtm")
    args = ap.parse_args()

    import rasterio
    from scipy import ndimage

    from georef_core.cli.main import main as georef
    from georef_core.steps.volumes import run_volumes

    work = Path(args.work)
    sim = work / f"sim_{args.seed}_{args.images}_{args.machines}"
    out = work / f"out_{args.seed}_{args.images}_{args.machines}"
    seconds = {}
    t = time.perf_counter()
    if not (sim / "truth" / "site.json").is_file():
        if georef(["simulate", str(sim), "--seed", str(args.seed), "--images", str(args.images), "--image-size",
                   str(args.image_size[0]), str(args.image_size[1]), "--machines", str(args.machines), "--quiet"]):
            raise SystemExit("simulation failed")
    seconds["simulate"] = time.perf_counter() - t
    site = json.loads((sim / "truth" / "site.json").read_text())
    print(f"site {site['work_area_site_xy_m']}, machines placed {len(site.get('machines', []))} of "
          f"{site.get('machines_requested', 0)}", flush=True)
    for name, argv in (("georef", ["georef", str(sim), "--out", str(out)]),
                       ("dense", ["dense", str(out), "--quiet"]), ("dtm", ["dtm", str(out), "--quiet"])):
        done = {"georef": out / "oriented_images.json", "dense": out / "dense" / "dsm.tif"}.get(name)
        t = time.perf_counter()
        if done is None or not done.is_file():
            if georef(argv):
                raise SystemExit(f"georef {name} failed")
        seconds[name] = time.perf_counter() - t

    with rasterio.open(out / "dense" / "dsm.tif") as ds:
        like = ds
        dsm = ds.read(1, masked=True).astype(float).filled(np.nan)
        truth_surface = on_grid(sim / "truth" / "dsm.tif", ds)
        truth_bare = on_grid(sim / "truth" / "dtm.tif", ds)
        machines = polygons_mask(sim / "truth" / "machines.geojson", ds)
        piles = polygons_mask(sim / "truth" / "stockpiles.geojson", ds)
        res = ds.res[0]
        (w0, s0), (w1, s1) = site["work_area_site_xy_m"]
        f = site["frame"]
        cols, rows = np.meshgrid(np.arange(ds.width), np.arange(ds.height))
        e, n = ds.transform * (cols + 0.5, rows + 0.5)
        inside = ((e - f["origin_E_m"] > w0) & (e - f["origin_E_m"] < w1) & (n - f["origin_N_m"] > s0)
                  & (n - f["origin_N_m"] < s1))
        del like
    with rasterio.open(out / "dtm" / "dtm.tif") as ds:
        dtm = ds.read(1, masked=True).astype(float).filled(np.nan)
    with rasterio.open(out / "dtm" / "dtm_interpolated_mask.tif") as ds:
        mask = ds.read(1)
    near = ndimage.distance_transform_edt(~machines) * res < 2.0
    pile_zone = ndimage.distance_transform_edt(~piles) * res < 2.0
    open_ground = inside & ~near & ~pile_zone & np.isfinite(dsm) & np.isfinite(truth_surface)

    def rmse(d):
        d = d[np.isfinite(d)]
        return float(np.sqrt(np.mean(d * d))), int(d.size)

    dsm_rmse, n_open = rmse((dsm - truth_surface)[open_ground])
    dtm_rmse, _ = rmse((dtm - truth_bare)[open_ground])
    under, n_m = rmse((dtm - truth_bare)[machines & np.isfinite(dtm)])
    dsm_on_machines, _ = rmse((dsm - truth_bare)[machines & np.isfinite(dsm)])
    removed_share = float(np.mean(mask[machines & (mask != 255)] == 1)) if n_m else float("nan")
    pile_removed = float(np.mean(mask[piles & (mask != 255)] == 1)) if piles.any() else 0.0
    summary = json.loads((out / "dtm" / "dtm_summary.json").read_text())
    vols = []
    poly = sim / "truth" / "stockpiles.geojson"
    if json.loads(poly.read_text())["features"]:
        a = run_volumes(out / "dense" / "dsm.tif", poly, base="plane")
        b = run_volumes(out / "dtm" / "dtm.tif", poly, base="plane")
        for ra, rb, ft in zip(a["results"], b["results"], json.loads(poly.read_text())["features"]):
            vols.append({"name": ft["properties"]["name"], "true_m3": round(ft["properties"]["volume_m3"], 2),
                         "dsm_m3": round(ra["net_m3"], 2), "dtm_m3": round(rb["net_m3"], 2)})
    row = {"seed": args.seed, "images": args.images, "machines": len(site.get("machines", [])),
           "dsm_cell_m": res, "open_ground_cells": n_open, "machine_cells": n_m,
           "dsm_rmse_vs_truth_surface_open_m": round(dsm_rmse, 4),
           "dtm_rmse_vs_truth_ground_open_m": round(dtm_rmse, 4),
           "ratio_dtm_to_dsm_open": round(dtm_rmse / dsm_rmse, 3),
           "machine_cells_non_ground_pct": round(100 * removed_share, 2),
           "dtm_rmse_under_machines_m": round(under, 4), "dsm_rmse_under_machines_vs_ground_m": round(dsm_on_machines, 3),
           "pile_cells_removed_pct": round(100 * pile_removed, 3),
           "removed_objects": summary["removed_objects"]["count"], "interpolation_check": summary["interpolation_check"],
           "volumes": vols, "seconds": {k: round(v, 1) for k, v in seconds.items()}}
    print(json.dumps(row, indent=1))
    print(f"judged: DTM RMSE on open ground {dtm_rmse * 100:.2f} cm = {dtm_rmse / dsm_rmse:.2f} x the DSM's "
          f"{dsm_rmse * 100:.2f} cm (<= 2); machine cells non-ground {100 * removed_share:.1f} % (>= 95 %)")
    (work / "summary.json").write_text(json.dumps(row, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
