"""The check points' height errors of a kept `bench/dji_end_to_end.py --keep DIR` run against the focal length
(docs/dji.md, "The check-point height errors are the focal length's"): the simulator's true focal length, the
DewarpData prior the simulated unit wrote, the adjusted focal length and its sigma; the check points' mean dz
against -(df/f) x the flying height (+ the camera centres' mean height error against the truth); the intrinsics'
part of each check point's dz (triangulated with the adjusted and with the true intrinsics, both on the adjusted
cameras), the rest and the cameras' part of it (adjusted against true cameras, both with the true intrinsics); the check points' stated sigmas and ANEES.

Usage: python bench/dji_focal_check.py DIR [OUT_DIR ...]   (default: every DIR/out_* folder)
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from dji_end_to_end import centre_errors_enu_m  # noqa: E402
from georef_core.adjustment.control_points import read_gcp_list  # noqa: E402
from georef_core.adjustment.triangulation import triangulate  # noqa: E402
from georef_core.photo.dji_xmp import read_dji_xmp  # noqa: E402
from georef_core.project_frame import ProjectFrame  # noqa: E402


def dz_parts_m(site: Path, out: Path, names: list[str], true_intr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per check point, from its gcp_list measurements (the same in each triangulation, so their noise cancels):
    the intrinsics' part of dz (adjusted minus true intrinsics, both on the adjusted cameras) and the cameras' part
    (adjusted minus true cameras, both with the true intrinsics), m."""
    est = np.array(json.loads((out / "georef_summary.json").read_text())["intrinsics"]["values"])
    oi = json.loads((out / "oriented_images.json").read_text())
    pf = ProjectFrame.from_dict(oi["project_frame"])
    idx = {im["name"]: i for i, im in enumerate(oi["images"])}
    R = np.array([im["R_cam_to_enu"] for im in oi["images"]])
    C = np.array([im["centre_enu_m"] for im in oi["images"]])
    Rt, Ct = R.copy(), C.copy()
    dji = json.loads((site / "truth" / "dji_names.json").read_text())["names"]
    for p in json.loads((site / "truth" / "camera_poses.json").read_text())["images"]:
        i = idx.get(dji[p["name"]])
        if i is not None:
            Ct[i] = pf.ecef_to_enu(np.array(p["camera_centre_ecef_m"]))
            Rt[i] = pf.R_ecef_to_enu @ np.array(p["R_cam_to_ecef"])
    _, _, ms = read_gcp_list(site / "gcp" / "gcp_list.txt")
    intr_part, cam_part = [], []
    for name in names:
        m = [x for x in ms if x.point == name and x.image in idx]
        uv, cams = np.array([x.uv_px for x in m]), np.array([idx[x.image] for x in m])
        z_true = triangulate(uv, cams, R, C, true_intr).xyz_enu_m[2]
        intr_part.append(triangulate(uv, cams, R, C, est).xyz_enu_m[2] - z_true)
        cam_part.append(z_true - triangulate(uv, cams, Rt, Ct, true_intr).xyz_enu_m[2])
    return np.array(intr_part), np.array(cam_part)


def report(work: Path, out: Path) -> dict:
    site = work / "site"
    t = json.loads((site / "truth" / "intrinsics.json").read_text())
    true_intr = np.array([t["fx"], t["cx"], t["cy"], t["k1"], t["k2"], t["k3"], t["p1"], t["p2"]])
    f_true = float(t["fx"])
    x = read_dji_xmp(sorted(site.glob("DJI_*/*.JPG"))[0])
    f_prior = 0.5 * (x.dewarp.fx_px + x.dewarp.fy_px)
    s = json.loads((out / "georef_summary.json").read_text())
    f_est, f_sig = s["intrinsics"]["values"][0], s["intrinsics"]["sigma"]["f"]
    f_prior_sig = s["adjustment"]["factory_calibration"]["sigma"]["f"]
    rows = json.loads((out / "residuals.json").read_text())["points"]
    e = np.array([[r["dx_m"], r["dy_m"], r["dz_m"]] for r in rows])
    sg = np.array([r["sigma_m"] for r in rows])
    oi = json.loads((out / "oriented_images.json").read_text())
    pf = ProjectFrame.from_dict(oi["project_frame"])
    cam_h = np.mean([pf.enu_to_grid(np.array(im["centre_enu_m"]))[2] for im in oi["images"]])
    tg = {r["name"]: float(r["ellipsoidal_height_m"]) for r in csv.DictReader(open(site / "truth" / "targets.csv"))}
    H = np.array([cam_h - tg[r["name"]] for r in rows])
    dc, _ = centre_errors_enu_m(site, out)
    df_rel = (f_est - f_true) / f_true
    dz = e[:, 2]
    sem = dz.std(ddof=1) / np.sqrt(len(dz))
    part, cam_part = dz_parts_m(site, out, [r["name"] for r in rows], true_intr)
    pred = float(np.mean(-df_rel * H) + dc[:, 2].mean())
    print(f"== {out}")
    print(f"focal length: true {f_true:.3f} px; DewarpData prior {f_prior:.3f} ({1e2 * (f_prior - f_true) / f_true:+.4f} %, "
          f"{(f_prior - f_true) / f_prior_sig:+.2f} x its sigma {f_prior_sig:.3f}); adjusted {f_est:.3f} +- {f_sig:.3f} "
          f"({1e2 * df_rel:+.4f} %)")
    print(f"check points {len(rows)}: mean dz {1e3 * dz.mean():+.1f} mm (sem {1e3 * sem:.1f}); -(df/f) H "
          f"{1e3 * np.mean(-df_rel * H):+.1f} mm (H {H.mean():.1f} m) + cameras' mean dU {1e3 * dc[:, 2].mean():+.1f} mm "
          f"= {1e3 * pred:+.1f} mm; intrinsics' part {1e3 * part.mean():+.1f} mm, rest {1e3 * (dz - part).mean():+.1f} mm "
          f"(std {1e3 * (dz - part).std(ddof=1):.1f}), of it the cameras' {1e3 * cam_part.mean():+.1f} mm (per point "
          f"{np.round(1e3 * cam_part, 1).tolist()}); f sigma x H {1e3 * f_sig / f_true * H.mean():.1f} mm")
    print(f"stated sigma median E/N/U {np.round(1e3 * np.median(sg, 0), 1).tolist()} mm; check ANEES "
          f"{np.mean(np.sum((e / sg) ** 2, 1) / 3):.3f}; vertical NEES {np.mean((dz / sg[:, 2]) ** 2):.3f}; "
          f"3D RMSE {1e3 * np.sqrt(np.mean(np.sum(e ** 2, 1))):.1f} mm")
    return {"f_prior_z": (f_prior - f_true) / f_prior_sig, "mean_dz_m": float(dz.mean()), "predicted_dz_m": pred,
            "intrinsics_part_m": float(part.mean())}


def main() -> int:
    if len(sys.argv) < 2:
        print(__doc__)
        return 2
    work = Path(sys.argv[1])
    outs = [Path(p) for p in sys.argv[2:]] or sorted(work.glob("out_*"))
    for out in outs:
        report(work, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
