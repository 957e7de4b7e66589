"""A real image set through the user's path: `georef georef` (photos alone) then the dense step, evaluated.

Given the output folder of `georef georef SURVEY --out OUT` (OUT/oriented_images.json), runs the dense step at
its defaults (unless OUT/dense/dsm.tif exists and --reuse) and prints, as bench/dense_real.py does for its own
levelled SfM: completeness over the block footprint (cells whose centre projects into >= 2 images), the support
raster's causes (band 2 of dsm_support.tif, over the footprint and over the grid), where the holes are (near the
footprint's edge / low texture / vegetation), the DSM noise on flat areas, the dense step's stage times and peak
memory, and the orthophoto's seam figure (`ortho_check.seam_contrast` without a reference: seam steps / steps
inside the views' regions, 1 = invisible), for the step's orthophoto and, as the reference run in the same
script, the same DSM mosaicked the earlier way (no radiometric compensation, feathering), both against the
latter's view labels (the nadir-most visible view: Voronoi-like seams). Writes small PNGs (orthophoto, DSM
hillshade, support causes) when --png-prefix is given.

    .venv/bin/python bench/dense_real_georef.py OUT [--reuse] [--workers 2] [--png-prefix docs/images/NAME]
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

CAUSE_COLOURS = {0: None, 1: (60, 110, 220), 2: (240, 150, 30), 3: (220, 40, 40), 4: (150, 150, 150),
                 5: (235, 235, 235)}


def support_causes_png(dense_dir: Path, png: Path, max_size: int) -> Path:
    """Band 2 of dsm_support.tif as colours: measured green (darker: more views), coarse blue, interpolated and
    seen orange, interpolated unseen red, no data seen grey, no data unseen light grey, outside white."""
    import rasterio
    from PIL import Image

    with rasterio.open(dense_dir / "dsm_support.tif") as ss:
        views, causes = ss.read(1).astype(np.float32), ss.read(2)
    img = np.full(causes.shape + (3,), 255, np.uint8)
    g = np.clip(views / 8.0, 0.25, 1.0)
    m = causes == 0
    img[m] = np.stack([40 * (1 - g[m]), 90 + 130 * g[m], 40 * (1 - g[m])], -1).astype(np.uint8)
    for code, rgb in CAUSE_COLOURS.items():
        if rgb is not None:
            img[causes == code] = rgb
    im = Image.fromarray(img)
    im.thumbnail((max_size, max_size), Image.NEAREST)
    png.parent.mkdir(parents=True, exist_ok=True)
    im.save(png, optimize=True)
    return png


def fit_png(png: Path, max_bytes: int) -> None:
    """Keep a PNG under ``max_bytes`` (docs pictures): a 256-colour palette, then smaller, as needed."""
    from PIL import Image

    if png.stat().st_size <= max_bytes:
        return
    im = Image.open(png).convert("RGB")
    while True:
        im.quantize(256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(png, optimize=True)
        if png.stat().st_size <= max_bytes or max(im.size) < 200:
            return
        im = im.resize((int(im.width * 0.85), int(im.height * 0.85)), Image.LANCZOS)


def seam_figures(out: Path) -> dict:
    """The seam figure of the step's orthophoto and of the same DSM mosaicked by feathering (reference)."""
    import rasterio

    from georef_core.dense.ortho_check import ortho_inputs, seam_contrast
    from georef_core.dense.orthophoto import OrthoOptions, build_orthophoto

    inp = ortho_inputs(out)
    g = inp["ortho_grid"]
    with rasterio.open(out / "dense" / "ortho.tif") as os_:
        step = os_.read()
    if step.shape[1:] != (g.height, g.width):
        return {"error": f"ortho.tif is {step.shape[1:]}, the rebuilt grid {(g.height, g.width)}"}
    labels = np.full((g.height, g.width), -1, np.int32)
    t0, c0 = time.perf_counter(), time.process_time()
    feather = build_orthophoto(**inp, options=OrthoOptions(compensate=False, blend=False), labels_out=labels)
    t_feather, cpu_feather = time.perf_counter() - t0, time.process_time() - c0
    a = seam_contrast(step, labels)
    b = seam_contrast(feather, labels)
    keys = ("seam_step_percent", "interior_step_percent", "seam_p90_percent", "ratio")
    return {"step_orthophoto": {k: round(float(a[k]), 3) for k in keys},
            "feathering_reference": {k: round(float(b[k]), 3) for k in keys},
            "seam_step_after_over_before": round(float(a["seam_step_percent"] / b["seam_step_percent"]), 3),
            "feathering_rebuild_s": round(t_feather, 1), "feathering_rebuild_cpu_s": round(cpu_feather, 1),
            "ortho_cells": [g.height, g.width], "ortho_resolution_m": g.resolution_m}


def level_orientations(src: Path, dst: Path) -> dict:
    """SRC/oriented_images.json rotated about the camera centres' centroid so that their best-fit plane is
    level (bench/dense_caliterra.py's levelling), written to DST/oriented_images.json; returns the tilt removed."""
    from dense_caliterra import level_rotation
    from georef_core.photo.oriented_images import OrientedImages, read_oriented_images

    oi = read_oriented_images(src / "oriented_images.json")
    C = np.array([im.centre_enu_m for im in oi.images])
    dirs = np.array([im.R_cam_to_enu[:, 2] for im in oi.images])
    P = oi.sparse_xyz_enu_m if oi.sparse_xyz_enu_m is not None and len(oi.sparse_xyz_enu_m) else C - [0, 0, 50]
    R, how = level_rotation(C, dirs, P)
    c = C.mean(axis=0)
    images = [replace(im, R_cam_to_enu=R @ im.R_cam_to_enu, centre_enu_m=R @ (im.centre_enu_m - c) + c,
                      velocity_enu_m_s=None if im.velocity_enu_m_s is None else R @ im.velocity_enu_m_s)
              for im in oi.images]
    sparse = (np.asarray(oi.sparse_xyz_enu_m) - c) @ R.T + c if oi.sparse_xyz_enu_m is not None else None
    dst.mkdir(parents=True, exist_ok=True)
    OrientedImages(oi.frame, oi.image_dir, oi.cameras, images, sparse, oi.sparse_rgb,
                   extra={"source": f"bench/dense_real_georef.py: {src} levelled ({how})"}).write(
        dst / "oriented_images.json")
    tilt = float(np.degrees(np.arccos(np.clip(R[2, 2], -1, 1))))
    return {"from": str(src), "by": how, "tilt_removed_deg": round(tilt, 2)}


def evaluate(out: Path) -> dict:
    import rasterio

    from dense_real import hole_causes
    from georef_core.dense.camera_views import views_from_oriented
    from georef_core.dense.dsm_quality import completeness, flat_area_noise, footprint_counts
    from georef_core.dense.dsm_raster import MASK_COARSE, MASK_MEASURED, RasterGrid
    from georef_core.dense.dsm_support import cause_counts
    from georef_core.photo.oriented_images import read_oriented_images

    d = out / "dense"
    oi = read_oriented_images(out / "oriented_images.json")
    with rasterio.open(d / "dsm.tif") as ds:
        dsm = ds.read(1, masked=True).filled(np.nan)
        T = ds.transform
    mask = rasterio.open(d / "dsm_filled_mask.tif").read(1)
    causes = rasterio.open(d / "dsm_support.tif").read(2)
    grid = RasterGrid(T.c, T.f, T.a, dsm.shape[1], dsm.shape[0])
    fp = footprint_counts(views_from_oriented(oi, 400), oi.frame, grid, dsm) >= 2
    n_fp = int(fp.sum())
    by_fp = {k: round(v / max(n_fp, 1), 4) for k, v in cause_counts(np.where(fp, causes, 255)).items()}
    res = {"dsm_cell_m": float(T.a), "dsm_cells": [int(dsm.shape[0]), int(dsm.shape[1])],
           "footprint_area_m2": round(n_fp * T.a * T.a, 0),
           "completeness": completeness(mask, fp),
           "causes_share_of_footprint": by_fp, "causes_cells_whole_grid": cause_counts(causes),
           "noise_flat_full": flat_area_noise(dsm, mask == MASK_MEASURED, T.a),
           "noise_flat_coarse_included": flat_area_noise(dsm, (mask == MASK_MEASURED) | (mask == MASK_COARSE), T.a)}
    if (d / "ortho.tif").exists():
        res["holes"] = hole_causes(out, mask, fp, T.a)
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="a `georef georef` output folder")
    ap.add_argument("--reuse", action="store_true", help="evaluate OUT/dense as it is")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-seams", action="store_true")
    ap.add_argument("--png-prefix", type=Path, help="write PREFIX_ortho.png, PREFIX_dsm.png, PREFIX_support.png")
    ap.add_argument("--png-size", type=int, default=640)
    ap.add_argument("--level", type=Path, metavar="DIR",
                    help="level OUT's orientations on the plane of the camera centres into DIR and run there (a "
                         "photos-alone block whose EXIF altitudes drift comes out tilted)")
    args = ap.parse_args(argv)
    from georef_core.steps.dense import run_dense

    out = args.out
    report: dict = {}
    georef = out / "georef_summary.json"
    if args.level:
        report["levelled"] = level_orientations(out, args.level)
        out = args.level
    if georef.is_file():
        g = json.loads(georef.read_text())
        report["georef"] = {k: g.get(k) for k in ("images", "registered", "sfm", "absolute_accuracy", "timings_s")
                            if k in g}
    if not (args.reuse and (out / "dense" / "dsm.tif").is_file()):
        t0 = time.perf_counter()
        run_dense(out, {"workers": args.workers})
        report["dense_wall_s"] = round(time.perf_counter() - t0, 1)
    summary = json.loads((out / "dense" / "dense_summary.json").read_text())
    report["dense_timings_s"] = summary.get("timings_s")
    report["dense_peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 0)
    report["dense_gsd_m"] = summary.get("gsd_m")
    report["dsm_vertical_rmse_m"] = summary.get("dsm_vertical_rmse_m")
    report["ortho_radiometry"] = (summary.get("ortho") or {}).get("radiometry")
    report["evaluation"] = evaluate(out)
    if not args.no_seams and (out / "dense" / "ortho.tif").is_file():
        report["seams"] = seam_figures(out)
    if args.png_prefix:
        from georef_core.dense.preview import dsm_preview_png, ortho_preview_png

        p = args.png_prefix
        pngs = [ortho_preview_png(out / "dense" / "ortho.tif", Path(f"{p}_ortho.png"), max_size=args.png_size),
                dsm_preview_png(out / "dense" / "dsm.tif", Path(f"{p}_dsm.png"), max_size=args.png_size),
                support_causes_png(out / "dense", Path(f"{p}_support.png"), max_size=args.png_size)]
        for x in pngs:
            fit_png(x, 300 * 1024)
        report["pngs_kb"] = {str(x): round(x.stat().st_size / 1024, 1) for x in pngs}
    text = json.dumps(report, indent=1, default=str)
    (out / "dense_real_georef.json").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
