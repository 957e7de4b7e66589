"""A tiled dense run's orthophoto radiometry: the block's one model (solved once from the depth parts'
observations, dense/block_radiometry.py) against each tile estimating its own and the merge harmonising their
gauges (the earlier way), on a simulated survey with injected per-image gains and vignetting (known truth).

Simulates one survey twice from the same seed (bench/ortho_seams.py's ``simulate``): with per-image exposure
gains (1 +- 15 %) and a cos^4-like vignetting 30 % darker at the corners, and radiometrically perfect. The dense
step runs in tiles (``contract.run_split``, this process) three times: the first survey the earlier way
(``dense_tiles.BLOCK_RADIOMETRY = False``) and the new way, and the perfect survey (the reference orthophoto).
Prints, for both ways, in this same run:

* the gains against the truth (each image's log gain minus the truth's, the block's mean removed: RMS and
  max in %; the earlier way: every tile's estimate after the merge's tile offset) and how far the tiles'
  estimates of one image scatter (weighted RMS, %);
* the seam step across the tile cuts and across the images' footprints (``ortho_check.seam_contrast`` against
  the reference orthophoto, labels = the tile's core / the nearest image centre point), median and p90 in %;
* the radiometry's cost (seconds summed over the parts) and the whole run's wall time.

    .venv/bin/python bench/ortho_tiles_radiometry.py [--small] [--images 40] [--seed 3] [--tiles 4]
        [--max-image-size 800] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def _run(survey: Path, run: Path, options: dict, block: bool) -> tuple[dict, float]:
    from georef_core.photo.oriented_images import oriented_images_from_simulator_truth
    from georef_core.steps import dense_tiles
    from georef_core.steps.contract import Workspace, get_spec, run_split

    shutil.rmtree(run, ignore_errors=True)
    oriented_images_from_simulator_truth(survey).write(run / "oriented_images.json")
    dense_tiles.BLOCK_RADIOMETRY = block
    t0 = time.perf_counter()
    try:
        summary = run_split(get_spec("dense"), Workspace(run, run), options, None, {})
    finally:
        dense_tiles.BLOCK_RADIOMETRY = True
    return summary, time.perf_counter() - t0


def _read(path: Path):
    import rasterio

    with rasterio.open(path) as ds:
        return ds.read(), ds.transform


def _common(a, ta, b, tb):
    """The two rasters (bands, rows, cols) cut to their common window (same cell, aligned grids)."""
    res = ta.a
    dc, dr = int(round((tb.c - ta.c) / res)), int(round((ta.f - tb.f) / res))   # b's origin in a's cells
    r0, c0 = max(0, dr), max(0, dc)
    r1, c1 = min(a.shape[1], dr + b.shape[1]), min(a.shape[2], dc + b.shape[2])
    return a[:, r0:r1, c0:c1], b[:, r0 - dr:r1 - dr, c0 - dc:c1 - dc], (ta.c + c0 * res, ta.f - r0 * res, res)


def _labels(shape, origin, summary, run: Path):
    """(tile label, nearest image centre point label) per orthophoto cell."""
    from scipy.spatial import cKDTree

    from georef_core.dense.orthophoto import view_footprints
    from georef_core.photo.oriented_images import read_oriented_images

    west, north, res = origin
    cols = west + (np.arange(shape[1]) + 0.5) * res
    rows = north - (np.arange(shape[0]) + 0.5) * res
    E, N = np.meshgrid(cols, rows)
    tiles = np.full(shape, -1, np.int32)
    for t, pt in enumerate(summary["tiles"]["per_tile"]):
        w, s, e, n = pt["core"]
        tiles[(E >= w) & (E < e) & (N >= s) & (N < n)] = t
    from georef_core.dense.camera_views import views_from_oriented

    oriented = read_oriented_images(run / "oriented_images.json")
    views = views_from_oriented(oriented, 400)
    dsm, t = _read(run / "dense" / "dsm.tif")
    h = float(np.median(dsm[0][dsm[0] > -9000]))
    z = float(oriented.frame.grid_to_enu(np.array([t.c]), np.array([t.f]), np.array([h]))[0, 2])
    _, centres = view_footprints(views, oriented.frame, z - 5, z + 5)
    ok = np.all(np.isfinite(centres), axis=1)
    _, idx = cKDTree(centres[ok]).query(np.column_stack([E.ravel(), N.ravel()]))
    return tiles, np.flatnonzero(ok)[idx].reshape(shape).astype(np.int32)


def _gain_errors(run: Path, summary: dict, truth: dict, block: bool) -> dict:
    """Gains against the truth (log, the block's mean removed) and the tiles' scatter of one image."""
    parts = sorted((run / "dense" / "parts").iterdir())
    true = {n: np.log(g) for n, g in truth["gains"].items()}
    est: dict[str, list] = {}
    if block:
        f = next(p / "radiometry.json" for p in parts if (p / "radiometry.json").is_file())
        for n, g in json.loads(f.read_text())["images"].items():
            est.setdefault(n, []).append((float(np.mean(g[:3])), float(g[3])))
    else:
        offs = summary["ortho"]["tile_harmonisation"].get("tile_offsets_percent") or []
        tiles = [json.loads((p / "core_summary.json").read_text()) for p in parts if (p / "core_summary.json").is_file()]
        for t, r in enumerate(tiles):
            c = np.mean(offs[t]) / 100 if t < len(offs) and offs[t] is not None else 0.0
            for n, g in (((r.get("summary") or {}).get("ortho") or {}).get("log_gains") or {}).items():
                # the merge multiplies the tile's colours by exp(c): the image's effective log gain is a - c
                est.setdefault(n, []).append((float(np.mean(g[:3])) - c, float(g[3])))
    names = sorted(n for n in est if n in true)
    d = np.array([v - true[n] for n in names for v, _ in est[n]])
    w = np.array([wt for n in names for _, wt in est[n]])
    d -= np.average(d, weights=w)
    spread = [(v - np.average([x for x, _ in est[n]], weights=[y for _, y in est[n]])) for n in names
              for v, _ in est[n] if len(est[n]) > 1]
    wsp = [wt for n in names for _, wt in est[n] if len(est[n]) > 1]
    return {"images": len(names), "estimates": len(d), "rms_percent": 100 * float(np.sqrt(np.average(d ** 2, weights=w))),
            "max_percent": 100 * float(np.abs(d).max()),
            "tile_scatter_percent": (100 * float(np.sqrt(np.average(np.square(spread), weights=wsp)))
                                     if spread else 0.0)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=40)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--small", action="store_true", help="the small 12-image scene (640 x 480), 2 tiles")
    ap.add_argument("--tiles", type=int, default=4)
    ap.add_argument("--tile-margin", type=float, default=0.25)
    ap.add_argument("--max-image-size", type=int, default=800)
    ap.add_argument("--work", type=Path, default=Path("/tmp/georef_ortho_tiles"))
    args = ap.parse_args(argv)

    from ortho_seams import simulate

    from georef_core.dense.ortho_check import seam_contrast

    tag = "small" if args.small else f"{args.images}_seed{args.seed}"
    survey = simulate(args.work / f"radiometric_{tag}", args, perfect=False)
    perfect = simulate(args.work / f"perfect_{tag}", args, perfect=True)
    truth = json.loads((survey / "truth" / "radiometry.json").read_text())
    options = {"tiles": 2 if args.small else args.tiles, "tile_margin": 0.0 if args.small else args.tile_margin,
               "workers": 2, "max_image_size": args.max_image_size, "keep_depth_maps": True}
    ref_sum, t_ref = _run(perfect, args.work / f"run_perfect_{tag}", options, True)
    ref, t_r = _read(args.work / f"run_perfect_{tag}" / "dense" / "ortho.tif")
    print(f"reference (perfect images) run: {t_ref:.1f} s; {ref_sum['n_images']} images, tiles "
          f"{ref_sum['tiles']['shape']}")
    rows = []
    for name, block in (("per tile + harmonised offsets (before)", False), ("block-wide, solved once (after)", True)):
        run = args.work / f"run_{'block' if block else 'tiles'}_{tag}"
        summary, wall = _run(survey, run, options, block)
        img, t = _read(run / "dense" / "ortho.tif")
        a, b, origin = _common(img, t, ref, t_r)
        tiles, voronoi = _labels(a.shape[1:], origin, summary, run)
        cut = seam_contrast(a, tiles, reference=b)
        foot = seam_contrast(a, voronoi, reference=b)
        gains = _gain_errors(run, summary, truth, block)
        tm = summary["timings_s"]
        rad_s = (tm.get("radiometry_samples", 0.0) + tm.get("radiometry_solve", 0.0)) if block else None
        if not block:
            rad_s = sum(((json.loads((p / "core_summary.json").read_text()).get("summary") or {}).get("ortho") or {})
                        .get("radiometry_s", 0.0) for p in (run / "dense" / "parts").iterdir()
                        if (p / "core_summary.json").is_file())
        rows.append((name, cut, foot, gains, rad_s, wall, summary))
    print(f"\n{'way':<42}{'tile-cut step %':>17}{'p90':>7}{'footprint step %':>18}{'p90':>7}"
          f"{'gain err RMS/max %':>20}{'tile scatter %':>16}{'radiometry s':>14}{'wall s':>9}")
    for name, cut, foot, gains, rad_s, wall, _ in rows:
        print(f"{name:<42}{cut['seam_step_percent']:17.3f}{cut['seam_p90_percent']:7.3f}"
              f"{foot['seam_step_percent']:18.3f}{foot['seam_p90_percent']:7.3f}"
              f"{gains['rms_percent']:11.3f} / {gains['max_percent']:.3f}{gains['tile_scatter_percent']:13.3f}"
              f"{rad_s:14.2f}{wall:9.1f}")
    (b_cut, b_foot), (a_cut, a_foot) = [(r[1], r[2]) for r in rows]
    print(f"\nafter / before: tile-cut step {a_cut['seam_step_percent'] / max(b_cut['seam_step_percent'], 1e-9):.2f}, "
          f"footprint step {a_foot['seam_step_percent'] / max(b_foot['seam_step_percent'], 1e-9):.2f} "
          f"(cells at the cuts: {a_cut['n_seam']}, at footprints: {a_foot['n_seam']}); truth: gains "
          f"{min(truth['gains'].values()):.3f}-{max(truth['gains'].values()):.3f}, corner loss "
          f"{truth['vignetting']['corner_loss_cos4']}")
    block_sum = rows[1][6]["ortho"].get("block_radiometry") or {}
    print("block model:", json.dumps(block_sum.get("summary")), f"observations {block_sum.get('observations')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
