"""Dense reconstruction of real images: the Caliterra subset (30 images, 1600 x 1200, EXIF GPS).

SfM (georef_core.photo.sfm.run_sfm) -> the model levelled and aligned to the EXIF GPS positions -> an
oriented-images file -> the dense step (georef_core.steps.dense.run_dense) -> hillshaded DSM and orthophoto
thumbnails in docs/images/. This is the "looks right" evidence on real images; there is no ground truth.

The EXIF GPS of this camera is poor (PROVENANCE.txt: altitude drifts ~110 m during the flight, horizontal
errors ~16-21 m), so a 7-parameter fit to the EXIF positions would tilt the model. The model is levelled
instead (the plane of the camera centres, which the drone flies at a constant height, or the mean viewing
direction when the centres are nearly collinear), then a horizontal similarity (scale, rotation about the
vertical, shift) is fitted to the EXIF latitude/longitude in the UTM zone's local ENU frame; the height
datum is the EXIF altitude of the first images minus the flying height (approximate, metres-level).

    .venv/bin/python bench/dense_caliterra.py [--work DIR] [--workers 2] [--images DIR] [--no-png] [--reuse-sfm]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from georef_core.photo.align import fit_similarity  # noqa: E402
from georef_core.photo.oriented_images import OrientedCamera, OrientedImage, OrientedImages  # noqa: E402
from georef_core.project_frame import ProjectFrame, utm_epsg_for  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def default_images() -> Path:
    env = os.environ.get("GEOREF_SHARED_DATA")
    base = Path(env) if env else REPO.parent / "shared"
    for cand in (base / "data" / "images" / "caliterra_subset30", base / "images" / "caliterra_subset30"):
        if cand.is_dir():
            return cand
    return base / "data" / "images" / "caliterra_subset30"


def level_rotation(centres: np.ndarray, view_dirs: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, str]:
    """Rotation taking the model's "up" to +z: the normal of the camera-centre plane when the centres span
    an area, else minus the mean viewing direction."""
    c = centres - centres.mean(axis=0)
    _, sv, vt = np.linalg.svd(c, full_matrices=False)
    if sv[1] > 0.2 * sv[0]:
        up, how = vt[2], "plane of the camera centres"
    else:
        up, how = -view_dirs.mean(axis=0), "mean viewing direction (centres nearly collinear)"
    up = up / np.linalg.norm(up)
    if np.median((centres - points.mean(axis=0)) @ up) < 0:  # cameras above the ground
        up = -up
    z = up
    x = np.cross([0.0, 1.0, 0.0], z)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z]), how


def oriented_from_sfm(result, image_dir: Path) -> tuple[OrientedImages, dict]:
    rec = result.reconstruction
    infos = {i.name: i for i in result.images}
    ims = sorted(rec.images.values(), key=lambda im: im.name)
    names = [im.name for im in ims if infos[im.name].has_gps]
    if len(names) < 3:
        raise SystemExit("fewer than 3 registered images with EXIF GPS")
    lat = np.array([infos[n].gps_lat_deg for n in names])
    lon = np.array([infos[n].gps_lon_deg for n in names])
    alt = np.array([infos[n].gps_alt_m or 0.0 for n in names])
    epsg = utm_epsg_for(float(lat.mean()), float(lon.mean()))
    tmp = ProjectFrame(epsg, 0.0, 0.0, 0.0)
    e, n = tmp.latlon_rad_to_grid(np.radians(lat), np.radians(lon))
    by_name = {im.name: im for im in ims}
    C_model = np.array([by_name[k].centre for k in names])
    dirs = np.array([by_name[k].R_cam_from_world[2] for k in names])
    R_level, how = level_rotation(C_model, dirs, rec.points_xyz)
    C_lev = C_model @ R_level.T
    P_lev = rec.points_xyz @ R_level.T
    # horizontal similarity: levelled model x, y -> ENU east, north of the EXIF positions
    frame0 = ProjectFrame(epsg, float(np.round(e.mean())), float(np.round(n.mean())), 0.0)
    gps_enu = frame0.grid_to_enu(e, n, np.zeros_like(e))
    src = np.column_stack([C_lev[:, :2], np.zeros(len(names))])
    dst = np.column_stack([gps_enu[:, :2], np.zeros(len(names))])
    sim, resid = fit_similarity(src, dst)
    s, R2, t2 = sim.scale, sim.R, sim.t
    ground_lev = float(np.median(P_lev[:, 2]))
    flying_height = s * float(np.median(C_lev[:, 2]) - ground_lev)
    first = np.argsort([infos[k].time_original or 0 for k in names])[:5] if all(
        infos[k].time_original for k in names) else np.arange(min(5, len(names)))
    h_ground = float(np.median(alt[first]) - flying_height)
    frame = ProjectFrame(epsg, frame0.origin_e, frame0.origin_n, h_ground)
    # full transform: X_enu = s R2 R_level X_model + t, with the ground median at ENU up = 0
    R = R2 @ R_level
    t = np.array([t2[0], t2[1], -s * ground_lev])

    def to_enu(x):
        return s * np.asarray(x) @ R.T + t

    cams = {cid: OrientedCamera(c.model, c.width, c.height, list(c.params)) for cid, c in rec.cameras.items()}
    images = [OrientedImage(im.name, im.camera_id, R @ im.R_cam_from_world.T, to_enu(im.centre)) for im in ims]
    oi = OrientedImages(frame, image_dir.resolve(), cams, images, to_enu(rec.points_xyz), rec.points_rgb,
                        extra={"source": "bench/dense_caliterra.py: SfM levelled and aligned to EXIF GPS (horizontal)"})
    info = {"epsg": epsg, "levelled_by": how, "scale": s, "flying_height_m": round(flying_height, 2),
            "gps_horizontal_residual_rms_m": round(float(np.sqrt(np.mean(np.sum(resid[:, :2] ** 2, axis=1)))), 2),
            "ground_height_datum_m": round(h_ground, 2)}
    return oi, info


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=Path, default=default_images())
    ap.add_argument("--work", type=Path, default=Path("/tmp/georef_dense_caliterra"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-png", action="store_true", help="do not write docs/images/dense_caliterra_*.png")
    ap.add_argument("--reuse-sfm", action="store_true", help="reuse WORK/oriented_images.json of an earlier run")
    args = ap.parse_args(argv)
    if not args.images.is_dir():
        print(f"images not found: {args.images}", file=sys.stderr)
        return 1
    from georef_core.dense.preview import dsm_preview_png, ortho_preview_png
    from georef_core.photo.sfm import SfmOptions, run_sfm
    from georef_core.steps.dense import DenseOptions, run_dense

    from georef_core.photo.oriented_images import read_oriented_images

    if args.reuse_sfm and (args.work / "oriented_images.json").is_file():
        oi = read_oriented_images(args.work / "oriented_images.json")
        print(f"reusing {args.work / 'oriented_images.json'}")
    else:
        t0 = time.perf_counter()
        sfm = run_sfm(args.images, args.work / "sfm", SfmOptions(num_threads=args.workers))
        t_sfm = time.perf_counter() - t0
        print(f"SfM: {sfm.n_registered}/{sfm.n_images} images, {sfm.mean_reprojection_error_px:.3f} px, {t_sfm:.1f} s")
        oi, info = oriented_from_sfm(sfm, args.images)
        oi.write(args.work / "oriented_images.json")
        (args.work / "caliterra_alignment.json").write_text(json.dumps(info, indent=1))
        print("alignment:", json.dumps(info))
    s = run_dense(args.work, DenseOptions(workers=args.workers))
    t = s["timings_s"]
    print(f"dense: {s['n_images']} images, {s['pairs']['count']} pairs, {s['points']['written']} points, GSD "
          f"{100 * s['gsd_m']:.1f} cm, DSM {s['dsm']['width']} x {s['dsm']['height']} @ {s['dsm_resolution_m']} m, "
          f"filled {100 * s['dsm']['hole_fraction']:.1f} %, estimated DSM precision "
          f"{100 * s['dsm_vertical_rmse_m']:.1f} cm")
    print(f"dense time {t['total']:.1f} s = {s['time_per_image_s']:.2f} s per image: "
          + ", ".join(f"{k} {v:.1f}" for k, v in t.items() if k != "total"))
    # consistency with the independent SfM points: DSM height at each sparse point minus its height
    import rasterio

    from georef_core.dense.orthophoto import DsmSampler
    from georef_core.dense.dsm_raster import RasterGrid

    with rasterio.open(args.work / "dense" / "dsm.tif") as ds:
        dsm = ds.read(1, masked=True).filled(np.nan)
        T = ds.transform
    grid = RasterGrid(T.c, T.f, T.a, dsm.shape[1], dsm.shape[0])
    sp = oi.frame.enu_to_grid(oi.sparse_xyz_enu_m)
    h = DsmSampler(dsm, grid, oi.frame).heights(sp[:, 0], sp[:, 1])
    dz = (h - sp[:, 2])[np.isfinite(h)]
    med = float(np.median(dz))
    print(f"DSM - SfM sparse points ({len(dz)}): median {100 * med:.1f} cm, NMAD "
          f"{100 * 1.4826 * np.median(np.abs(dz - med)):.1f} cm, |dz| < 10 cm for {100 * np.mean(np.abs(dz) < 0.1):.1f} %")
    if not args.no_png:
        out = REPO / "docs" / "images"
        a = dsm_preview_png(args.work / "dense" / "dsm.tif", out / "dense_caliterra_dsm.png", max_size=900)
        b = ortho_preview_png(args.work / "dense" / "ortho.tif", out / "dense_caliterra_ortho.png", max_size=900)
        for p in (a, b):
            print(f"{p.relative_to(REPO)}: {p.stat().st_size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
