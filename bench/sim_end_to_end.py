"""End to end on simulated flights with truth: images + GNSS -> PPK -> SfM -> GNSS-aided adjustment ->
dense DSM -> stockpile volumes, and every figure compared with the simulator's truth.

The operational sequence a contractor follows, on two flights of the same drone (same lever arm and
trigger delay, different seeds = different site, noise and flight):

1. calibration flight (seed A; by default every other pair of lines at a second height and speed, as
   docs/georeferencing.md recommends): all targets are control; the joint adjustment (mode c) estimates
   the lever arm and the delay  ->  errors against the true lever arm / delay;
2. production flight (seed B): zero control points, the calibrated lever arm as a prior with its
   sigma and the calibrated camera held fixed (`georef georef --calibration CAL_OUT_DIR`), every target a
   check point  ->  check-point residual table (3D RMSE);
3. dense DSM of flight B  ->  vertical RMSE against the truth DSM;
4. volumes of the simulated stockpiles on that DSM (base: best-fit plane of the outline)  ->  error
   against the analytic volume, and whether the stated uncertainty covers it.

With ``--readout-ms MS`` both flights carry a rolling-shutter camera: the calibration flight estimates
the readout time with the lever arm and delay, and the production flight holds it (as
``--calibration`` does)  ->  readout error against the truth.

    .venv/bin/python bench/sim_end_to_end.py [--pairs 3:4 5:6] [--images 30] [--cal-images 60] [--image-size 1024 768]
                                            [--receiver l1l2|l1] [--lens perspective|fisheye] [--readout-ms 40] [--work DIR]

The last line printed summarises the volumes: RMS of error / stated sigma and how many piles the 95 %
interval covers (a calibrated uncertainty has an RMS near 1 and about 95 % covered).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def simulate(folder: Path, seed: int, images: int, size: tuple[int, int], receiver: str,
             second_height: float | None = None, second_speed: float | None = None, lens: str = "perspective",
             readout_ms: float | None = None) -> None:
    from georef_core.cli.main import main

    if (folder / "truth" / "lever_arm_delay.json").is_file():
        return
    extra = ["--second-height", str(second_height)] if second_height else []
    extra += ["--second-speed", str(second_speed)] if second_speed else []
    extra += ["--lens", lens]
    extra += ["--readout-ms", str(readout_ms)] if readout_ms else []
    rc = main(["simulate", str(folder), "--seed", str(seed), "--images", str(images), "--image-size",
               str(size[0]), str(size[1]), "--receiver", receiver, "--quiet"] + extra)
    if rc != 0:
        raise SystemExit(f"simulation of seed {seed} failed")


def dsm_rmse_against_truth(dsm_path: Path, truth_path: Path) -> dict:
    """Vertical differences of our DSM against the truth DSM on our grid (cells with data in both)."""
    import rasterio
    from rasterio.warp import Resampling, reproject

    with rasterio.open(dsm_path) as a:
        ours = a.read(1, masked=True).astype(float).filled(np.nan)
        truth = np.full(ours.shape, np.nan)
        with rasterio.open(truth_path) as t:
            reproject(rasterio.band(t, 1), truth, dst_transform=a.transform, dst_crs=a.crs,
                      resampling=Resampling.bilinear, dst_nodata=np.nan)
    d = ours - truth
    d = d[np.isfinite(d)]
    return {"cells": int(d.size), "mean_m": float(d.mean()), "rmse_m": float(np.sqrt(np.mean(d ** 2))),
            "p95_abs_m": float(np.percentile(np.abs(d), 95))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", nargs="+", default=["3:4"], help="CAL_SEED:PRODUCTION_SEED pairs")
    ap.add_argument("--images", type=int, default=30)
    ap.add_argument("--cal-images", type=int, help="images of the calibration flight (default: --images)")
    ap.add_argument("--image-size", type=int, nargs=2, default=(1024, 768))
    ap.add_argument("--receiver", choices=("l1l2", "l1"), default="l1l2")
    ap.add_argument("--lens", choices=("perspective", "fisheye"), default="perspective",
                    help="simulated lens; fisheye flights are adjusted with --camera-model fisheye")
    ap.add_argument("--max-tie-points", type=int, default=8000)
    ap.add_argument("--readout-ms", type=float, help="a rolling-shutter camera with this readout time (ms)")
    ap.add_argument("--work", default="work_out/bench_sim_e2e")
    ap.add_argument("--skip-dense", action="store_true")
    ap.add_argument("--self-calibrate", action="store_true",
                    help="production flight: self-calibrate the camera instead of holding the calibration flight's")
    ap.add_argument("--cal-second-height", type=float, default=90.0,
                    help="second line height of the calibration flight (m; 0: one height like production)")
    ap.add_argument("--cal-second-speed", type=float, default=8.0,
                    help="ground speed of the calibration flight's second-height lines (m/s; 0: one speed)")
    args = ap.parse_args()

    from georef_core.steps.dense import run_dense
    from georef_core.steps.georef import GeorefOptions, run_georef
    from georef_core.steps.volumes import run_volumes

    work = Path(args.work)
    rows = []
    for pair in args.pairs:
        seed_a, seed_b = (int(s) for s in pair.split(":"))
        tag = f"{args.receiver}_{args.images}_{args.image_size[0]}" + ("_fisheye" if args.lens == "fisheye" else "") \
            + (f"_rs{args.readout_ms:g}" if args.readout_ms else "")
        cal_images = args.cal_images or args.images
        cal_tag = tag.replace(f"_{args.images}_", f"_{cal_images}_", 1)
        cal_tag = (f"{cal_tag}_h{args.cal_second_height:g}" if args.cal_second_height else cal_tag) + \
            (f"_v{args.cal_second_speed:g}" if args.cal_second_speed else "")
        sim_a, sim_b = work / f"sim_{seed_a}_{cal_tag}", work / f"sim_{seed_b}_{tag}"
        t0 = time.perf_counter()
        simulate(sim_a, seed_a, cal_images, tuple(args.image_size), args.receiver, args.cal_second_height or None,
                 args.cal_second_speed or None, args.lens, args.readout_ms)
        simulate(sim_b, seed_b, args.images, tuple(args.image_size), args.receiver, lens=args.lens,
                 readout_ms=args.readout_ms)
        t_sim = time.perf_counter() - t0
        truth = json.loads((sim_a / "truth" / "lever_arm_delay.json").read_text())
        true_lever, true_delay = np.array(truth["lever_arm_cam_m"]), truth["delay_s"]

        # 1. calibration flight: all targets control, lever arm and delay estimated jointly
        out_a = work / f"out_{seed_a}_{cal_tag}_cal"
        t0 = time.perf_counter()
        camera_model = "fisheye" if args.lens == "fisheye" else "brown"
        sa = run_georef(sim_a, out_a, GeorefOptions(mode="joint", control="all", leave_one_out=False,
                                                    max_tie_points=args.max_tie_points, camera_model=camera_model))
        t_cal = time.perf_counter() - t0
        lad = sa["lever_arm_delay"]
        lever = np.array(lad["lever_arm_cam_m"])
        lever_sig = np.array(lad["lever_arm_sigma_m"])

        # 2. production flight: zero control, calibrated lever arm (prior with its sigma), delay estimated
        out_b = work / f"out_{seed_b}_{tag}_direct"
        t0 = time.perf_counter()
        sb = run_georef(sim_b, out_b, GeorefOptions(
            mode="joint", control="none", lever_arm_cam_m=tuple(lever), lever_arm_sigma_m=float(max(lever_sig.max(), 0.002)),
            delay_s=float(lad["delay_s"]), leave_one_out=False, max_tie_points=args.max_tie_points,
            camera_model=camera_model, readout_s=sa["rolling_shutter"].get("readout_s") if args.readout_ms else None,
            fixed_intrinsics=None if args.self_calibrate else tuple(sa["intrinsics"]["values"])))
        t_direct = time.perf_counter() - t0
        chk = sb["check_points"]["statistics"]

        row = {"pair": pair, "receiver": args.receiver, "lens": args.lens, "images": sb["images"]["registered"],
               "calibration_images": sa["images"]["registered"],
               "calibration_second_height_m": args.cal_second_height or None,
               "calibration_second_speed_m_s": args.cal_second_speed or None,
               "lever_error_mm": ((lever - true_lever) * 1000).round(1).tolist(),
               "lever_sigma_mm": (lever_sig * 1000).round(1).tolist(),
               "delay_error_ms": round((lad["delay_s"] - true_delay) * 1000, 2),
               "delay_sigma_ms": round(lad["delay_sigma_s"] * 1000, 2),
               **({"readout_error_ms": round(1000 * sa["rolling_shutter"]["readout_s"] - args.readout_ms, 2),
                   "readout_sigma_ms": round(1000 * sa["rolling_shutter"]["readout_sigma_s"], 2),
                   "production_readout_source": sb["rolling_shutter"].get("readout_source")}
                  if args.readout_ms else {}),
               "check_n": chk.get("n"), "check_rmse_3d_mm": round(chk["3d"]["rmse_m"] * 1000, 1),
               "check_rmse_h_mm": round(chk["horizontal"]["rmse_m"] * 1000, 1),
               "check_rmse_z_mm": round(chk["dz"]["rmse_m"] * 1000, 1),
               "check_mean_dz_mm": round(chk["dz"]["mean_m"] * 1000, 1),
               "seconds": {"simulate": round(t_sim, 1), "calibration_flight": round(t_cal, 1),
                           "production_flight": round(t_direct, 1)}}

        if not args.skip_dense:
            t0 = time.perf_counter()
            ds = run_dense(out_b)
            row["seconds"]["dense"] = round(time.perf_counter() - t0, 1)
            dsm = out_b / "dense" / "dsm.tif"
            row["dsm_vs_truth"] = {k: (round(v, 4) if isinstance(v, float) else v)
                                   for k, v in dsm_rmse_against_truth(dsm, sim_b / "truth" / "dsm.tif").items()}
            row["dsm_vertical_rmse_stated_m"] = ds.get("dsm_vertical_rmse_m")
            piles = json.loads((sim_b / "truth" / "stockpiles.geojson").read_text())
            vol = run_volumes(dsm, sim_b / "truth" / "stockpiles.geojson", base="plane",
                              height_bias_m=abs(chk["dz"]["mean_m"]) if chk.get("n") else None)
            vrows = []
            for res, feat in zip(vol["results"], piles["features"]):
                true_v = feat["properties"]["volume_m3"]
                err = res["net_m3"] - true_v
                sig = res["uncertainty"]["sigma_m3"]
                vrows.append({"name": feat["properties"]["name"], "true_m3": round(true_v, 2),
                              "net_m3": round(res["net_m3"], 2), "error_pct": round(100 * err / true_v, 2),
                              "sigma_m3": sig, "error_sigma": round(err / sig, 2) if sig else None,
                              "covered_95": bool(abs(err) <= res["uncertainty"]["ci95_m3"])})
            row["volumes"] = vrows
        rows.append(row)
        print(json.dumps(row, indent=1), flush=True)
    z = np.array([v["error_sigma"] for r in rows for v in r.get("volumes", []) if v["error_sigma"] is not None])
    if z.size:
        # a calibrated uncertainty has RMS(error / sigma) near 1 and about 95 % of the piles inside ci95
        print(f"volumes: {z.size} piles, RMS(error/sigma) {np.sqrt(np.mean(z ** 2)):.2f}, mean {z.mean():+.2f}, "
              f"inside ci95 {int(np.sum(np.abs(z) <= 1.959964))}/{z.size}, largest |error/sigma| {np.abs(z).max():.2f}")
    (work / "summary.json").write_text(json.dumps(rows, indent=1))
    print(f"written {work / 'summary.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
