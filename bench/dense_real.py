"""Dense completeness and noise on the shared real image sets (no ground truth).

Per set: SfM (registered images, mean reprojection error, time) -> a levelled, metric frame -> the dense
step, run twice on the same orientations: the reference configuration (no coarse pass, no edge sweep:
the step as it was before issue 26) and the current defaults. Printed per run: completeness over the
block footprint (cells seen by >= 2 images; georef_core/dense/dsm_quality.py) per class (full resolution,
coarse pass, interpolated, no data), where the holes are (near the footprint edge / low texture /
vegetation, from the orthophoto), the DSM noise on flat areas (median NMAD of plane-fit residuals in the
best 10 % of 3 x 3 m windows), timings, and the ratios current / reference.

* caliterra_75: 75 photos of a construction site, EXIF GPS: levelled on the camera-centre plane and aligned
  horizontally to the EXIF positions (bench/dense_caliterra.py).
* copr_subset40: 40 kite photos of dunes, no GPS: levelled on the best-fit plane of the sparse points
  (the beach), scaled and aligned horizontally to the 10 surveyed targets (gcp_list_1600px.txt; the
  labelling blunder of gcp04 in IMG_0031 left out). Target heights were not surveyed.

    .venv/bin/python bench/dense_real.py [--sets caliterra_75 copr_subset40] [--work DIR] [--reuse-sfm]
        [--only current|reference] [--no-png] [--no-ortho]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from dense_caliterra import oriented_from_sfm  # noqa: E402

from georef_core.photo.align import fit_similarity  # noqa: E402
from georef_core.photo.oriented_images import OrientedCamera, OrientedImage, OrientedImages  # noqa: E402
from georef_core.project_frame import ProjectFrame  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
REFERENCE = {"coarse": {"factor": 1.0}, "fusion": {"edge_min_b_over_d": 0.0}}


def shared_images() -> Path:
    import os

    env = os.environ.get("GEOREF_SHARED_DATA")
    base = Path(env) if env else REPO.parent / "shared"
    return base / "data" / "images"


def oriented_from_gcps(result, image_dir: Path) -> tuple[OrientedImages, dict]:
    """COPR: level on the sparse points' plane, then a horizontal similarity to the surveyed targets."""
    from georef_core.dense.camera_views import views_from_oriented

    rec = result.reconstruction
    ims = sorted(rec.images.values(), key=lambda im: im.name)
    cams = {cid: OrientedCamera(c.model, c.width, c.height, list(c.params)) for cid, c in rec.cameras.items()}
    model = OrientedImages(ProjectFrame(32611, 0.0, 0.0, 0.0), image_dir.resolve(), cams,
                           [OrientedImage(im.name, im.camera_id, im.R_cam_from_world.T, im.centre) for im in ims],
                           rec.points_xyz, rec.points_rgb)
    views = {v.name: v for v in views_from_oriented(model, None)}
    obs: dict[str, list] = {}
    gcp_e = {}
    for line in (image_dir / "gcp_list_1600px.txt").read_text().splitlines()[1:]:
        f = line.split()
        if len(f) < 7 or (f[6] == "gcp04" and f[5] == "IMG_0031.jpg"):  # the labelling blunder (PROVENANCE.txt)
            continue
        gcp_e[f[6]] = (float(f[0]), float(f[1]))
        if f[5] in views:
            obs.setdefault(f[6], []).append((views[f[5]], float(f[3]), float(f[4])))
    names, X = [], []
    for g, lst in obs.items():
        if len(lst) < 2:
            continue
        A, b = np.zeros((3, 3)), np.zeros(3)
        for v, u, w in lst:  # least-squares intersection of the rays
            xy = v.undistort_points(np.array([[u, w]]))[0]
            d = v.R_world_to_cam.T @ np.array([xy[0], xy[1], 1.0])
            d /= np.linalg.norm(d)
            P = np.eye(3) - np.outer(d, d)
            A += P
            b += P @ v.centre_enu_m
        names.append(g)
        X.append(np.linalg.solve(A, b))
    X = np.array(X)
    P = rec.points_xyz
    c = P - P.mean(axis=0)
    up = np.linalg.svd(c, full_matrices=False)[2][2]
    C = np.array([im.centre for im in ims])
    if np.median((C - P.mean(axis=0)) @ up) < 0:
        up = -up
    x = np.cross([0.0, 1.0, 0.0], up)
    x /= np.linalg.norm(x)
    R_level = np.stack([x, np.cross(up, x), up])
    E = np.array([gcp_e[g] for g in names])
    frame0 = ProjectFrame(32611, float(np.round(E[:, 0].mean())), float(np.round(E[:, 1].mean())), 0.0)
    enu = frame0.grid_to_enu(E[:, 0], E[:, 1], np.zeros(len(E)))
    Xl = X @ R_level.T
    sim, resid = fit_similarity(np.column_stack([Xl[:, :2], np.zeros(len(X))]),
                                np.column_stack([enu[:, :2], np.zeros(len(X))]))
    s, R2, t2 = sim.scale, sim.R, sim.t
    ground = float(np.median((P @ R_level.T)[:, 2]))
    R = R2 @ R_level
    t = np.array([t2[0], t2[1], -s * ground])

    def to_enu(p):
        return s * np.asarray(p) @ R.T + t

    images = [OrientedImage(im.name, im.camera_id, R @ im.R_cam_from_world.T, to_enu(im.centre)) for im in ims]
    oi = OrientedImages(frame0, image_dir.resolve(), cams, images, to_enu(P), rec.points_rgb,
                        extra={"source": "bench/dense_real.py: SfM levelled on the sparse points, aligned to the targets"})
    info = {"targets_used": len(names), "scale": s,
            "target_horizontal_residual_rms_m": round(float(np.sqrt(np.mean(np.sum(resid[:, :2] ** 2, axis=1)))), 3)}
    return oi, info


def hole_causes(work: Path, mask: np.ndarray, footprint: np.ndarray, res: float) -> dict:
    """Share of the footprint's unmeasured cells near its edge (< 5 m), on low texture (ortho grey std over
    ~1 m below its 20th percentile over the footprint) and on vegetation (excess green 2g - r - b > 0.05)."""
    import cv2
    import rasterio
    from rasterio.warp import Resampling, reproject
    from scipy import ndimage

    from georef_core.dense.dsm_raster import MASK_COARSE, MASK_MEASURED

    holes = footprint & (mask != MASK_MEASURED) & (mask != MASK_COARSE)
    n = int(holes.sum())
    if n == 0:
        return {"hole_cells": 0}
    edge = ndimage.distance_transform_edt(footprint) * res < 5.0
    with rasterio.open(work / "dense" / "ortho.tif") as os_:
        rgb = os_.read([1, 2, 3]).astype(np.float32)
        alpha = os_.read(4) if os_.count >= 4 else np.full(rgb.shape[1:], 255, np.uint8)
        ot, crs = os_.transform, os_.crs
    with rasterio.open(work / "dense" / "dsm.tif") as ds:
        dt = ds.transform
    grey = rgb.mean(axis=0)
    k = max(3, int(round(1.0 / ot.a)))
    m = cv2.blur(grey, (k, k))
    std = np.sqrt(np.maximum(cv2.blur(grey * grey, (k, k)) - m * m, 0))
    # cells the orthophoto does not cover (and their ~1 m rim) have no texture figure: without this, their zero
    # std set the 20th percentile to 0 on a block with holes and no hole was "low texture"
    std[cv2.erode((alpha > 0).astype(np.uint8), np.ones((k, k), np.uint8)) == 0] = np.nan
    s = rgb.sum(axis=0) + 1e-3
    exg = (2 * rgb[1] - rgb[0] - rgb[2]) / s
    out = {}
    for name, a in (("std", std), ("exg", exg)):
        dst = np.full(mask.shape, np.nan, np.float32)
        reproject(a, dst, src_transform=ot, src_crs=crs, dst_transform=dt, dst_crs=crs, resampling=Resampling.average,
                  src_nodata=np.nan, dst_nodata=np.nan)
        out[name] = dst
    low_tex = out["std"] < np.nanpercentile(out["std"][footprint], 20)
    veg = out["exg"] > 0.05
    return {"hole_cells": n, "near_edge_5m": round(float(np.mean(edge[holes])), 3),
            "low_texture": round(float(np.mean(low_tex[holes])), 3), "vegetation": round(float(np.mean(veg[holes])), 3),
            "footprint_low_texture": 0.2, "footprint_vegetation": round(float(np.mean(veg[footprint])), 3),
            "low_texture_cells_measured": round(float(1 - np.mean(holes[low_tex & footprint])), 3)}


def evaluate(work: Path, oi, summary: dict) -> dict:
    import rasterio

    from georef_core.dense.camera_views import views_from_oriented
    from georef_core.dense.dsm_quality import completeness, flat_area_noise, footprint_counts
    from georef_core.dense.dsm_raster import MASK_COARSE, MASK_MEASURED, RasterGrid

    d = work / "dense"
    with rasterio.open(d / "dsm.tif") as ds:
        dsm = ds.read(1, masked=True).filled(np.nan)
        T = ds.transform
    mask = rasterio.open(d / "dsm_filled_mask.tif").read(1)
    grid = RasterGrid(T.c, T.f, T.a, dsm.shape[1], dsm.shape[0])
    views = views_from_oriented(oi, 400)  # projection only: the size does not matter
    fp = footprint_counts(views, oi.frame, grid, dsm) >= 2
    res = {"completeness": completeness(mask, fp),
           "noise_flat_full": flat_area_noise(dsm, mask == MASK_MEASURED, T.a),
           "noise_flat_coarse_included": flat_area_noise(dsm, (mask == MASK_MEASURED) | (mask == MASK_COARSE), T.a)}
    if (d / "ortho.tif").exists():
        res["holes"] = hole_causes(work, mask, fp, T.a)
    res["dense_s"] = summary["timings_s"]["total"]
    res["coarse_minus_fine_m"] = summary["dsm"].get("coarse_minus_fine_m")
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", nargs="+", default=["caliterra_75", "copr_subset40"])
    ap.add_argument("--work", type=Path, default=Path("/tmp/georef_dense_real"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--reuse-sfm", action="store_true")
    ap.add_argument("--only", choices=("current", "reference"))
    ap.add_argument("--no-png", action="store_true")
    ap.add_argument("--no-ortho", action="store_true", help="no orthophoto (then no hole causes)")
    args = ap.parse_args(argv)
    from georef_core.dense.preview import dsm_preview_png
    from georef_core.photo.oriented_images import read_oriented_images
    from georef_core.photo.sfm import SfmOptions, run_sfm
    from georef_core.steps.dense import run_dense

    report = {}
    for name in args.sets:
        images = shared_images() / name
        if not images.is_dir():
            print(f"{name}: {images} not found, skipped")
            continue
        root = args.work / name
        root.mkdir(parents=True, exist_ok=True)
        oi_path = root / "oriented_images.json"
        info = {}
        if args.reuse_sfm and oi_path.is_file():
            oi = read_oriented_images(oi_path)
            if (root / "sfm_info.json").exists():
                info = json.loads((root / "sfm_info.json").read_text())
        else:
            t0 = time.perf_counter()
            sfm = run_sfm(images, root / "sfm", SfmOptions(num_threads=args.workers))
            info = {"registered": sfm.n_registered, "images": sfm.n_images, "matcher": sfm.matcher,
                    "reprojection_error_px": round(sfm.mean_reprojection_error_px, 3),
                    "sfm_s": round(time.perf_counter() - t0, 1)}
            oi, align = oriented_from_gcps(sfm, images) if name.startswith("copr") else oriented_from_sfm(sfm, images)
            info["alignment"] = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in align.items()}
            oi.write(oi_path)
            (root / "sfm_info.json").write_text(json.dumps(info, indent=1))
        print(f"{name}: SfM {info.get('registered')}/{info.get('images')} images registered, "
              f"{info.get('reprojection_error_px')} px, {info.get('sfm_s')} s ({info.get('matcher')})")
        report[name] = {"sfm": info}
        for run in ("reference", "current"):
            if args.only and run != args.only:
                continue
            work = root / run
            work.mkdir(exist_ok=True)
            oi.write(work / "oriented_images.json")
            opts = dict(REFERENCE) if run == "reference" else {}
            opts["workers"] = args.workers
            if args.no_ortho:
                opts["ortho"] = False
                (work / "dense" / "ortho.tif").unlink(missing_ok=True)
            s = run_dense(work, opts)
            r = evaluate(work, oi, s)
            report[name][run] = r
            c, nz = r["completeness"], r["noise_flat_full"]
            print(f"  {run}: completeness {100 * c['completeness']:.1f} % of the footprint ({c['footprint_cells']} "
                  f"cells: full {100 * c['measured_full_resolution']:.1f} %, coarse {100 * c['measured_coarse']:.1f} %, "
                  f"interpolated {100 * c['interpolated']:.1f} %, no data {100 * c['no_data']:.1f} %); flat-area "
                  f"noise {100 * nz.get('nmad_m', float('nan')):.1f} cm; dense {r['dense_s']:.0f} s")
            print(f"    holes: {json.dumps(r.get('holes'))}; coarse - fine {json.dumps(r['coarse_minus_fine_m'])}")
            if run == "current" and not args.no_png:
                out = REPO / "docs" / "images"
                dsm_preview_png(work / "dense" / "dsm.tif", out / f"dense_real_{name}_dsm.png", max_size=560)
                support_png(work / "dense", out / f"dense_real_{name}_support.png")
        if "reference" in report[name] and "current" in report[name]:
            a, b = report[name]["reference"], report[name]["current"]
            print(f"  current / reference: completeness {b['completeness']['completeness'] / max(a['completeness']['completeness'], 1e-9):.3f}, "
                  f"dense time {b['dense_s'] / a['dense_s']:.2f}")
    (args.work / "dense_real_report.json").write_text(json.dumps(report, indent=1))
    return 0


def support_png(dense_dir: Path, png: Path, max_size: int = 700) -> Path:
    """The measurement classes as colours: full resolution shaded by views (green), coarse (blue),
    interpolated (red), none (white)."""
    import rasterio
    from PIL import Image

    mask = rasterio.open(dense_dir / "dsm_filled_mask.tif").read(1)
    sup = rasterio.open(dense_dir / "dsm_support.tif").read(1).astype(np.float32)
    img = np.full(mask.shape + (3,), 255, np.uint8)
    g = np.clip(sup / 8.0, 0.25, 1.0)
    full = mask == 0
    img[full] = np.stack([40 * (1 - g[full]), 90 + 130 * g[full], 40 * (1 - g[full])], -1).astype(np.uint8)
    img[mask == 2] = (60, 110, 220)
    img[mask == 1] = (220, 50, 40)
    im = Image.fromarray(img)
    im.thumbnail((max_size, max_size), Image.NEAREST)
    png.parent.mkdir(parents=True, exist_ok=True)
    im.save(png, optimize=True)
    return png


if __name__ == "__main__":
    sys.exit(main())
