"""Per-flight GNSS offsets end to end on the simulator (docs/georeferencing.md, "Several flights").

`georef simulate --aircraft dji-rtk --small --images 30 --flights 2` (30 photos of 640 x 480, two flight
folders, raw PPK + MRK), each flight's PPK camera positions then shifted by a common offset (flight 1 +3 cm,
flight 2 -4 cm on each of E, N, U: added in memory to the positions the georef step reads, as a base or
ambiguity error would), processed with the offsets not modelled (`--flight-offsets off`) and modelled
(default), with no control point and with one. Prints the camera centres' ANEES against the simulator's
truth, the check points' 3D RMSE and the offsets estimated with their sigma.

    python bench/flight_offsets_sim.py [--seed 23] [--keep DIR] [--modes joint,similarity,gcp]

`--modes similarity` runs the 7-parameter + delay mode (no control point: the lever arm is the MRK's, held),
`--modes gcp` the lever-arm/delay mode on three control points (the other two targets check points); both with
the offsets not modelled and modelled, printing also the delay with its sigma (the simulator's is 0).
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import georef_core.steps.georef as step  # noqa: E402
from georef_core.cli.main import main as georef  # noqa: E402
from georef_core.gnss.frames import ecef_to_enu_rotation, ecef_to_geodetic  # noqa: E402
from georef_core.steps.survey_inputs import read_camera_flights  # noqa: E402

OFFSETS_ENU_M = np.array([[0.03, 0.03, 0.03], [-0.04, -0.04, -0.04]])
_match = step.match_images_to_events


def _shifted_match(image_dir, image_names, ppk_events_csv, times=None, times_source="", ev_csv=None):
    """match_images_to_events, then each flight's positions shifted by its offset (flights from the DJI
    layout's camera_offsets.csv beside events.csv)."""
    g = _match(image_dir, image_names, ppk_events_csv, times, times_source, ev_csv)
    flight = read_camera_flights(Path(ev_csv).parent / "camera_offsets.csv")
    lat, lon, _ = ecef_to_geodetic(g.position_ecef_m.mean(axis=0))
    R = ecef_to_enu_rotation(lat, lon)
    for k, n in enumerate(g.names):
        g.position_ecef_m[k] = g.position_ecef_m[k] + R.T @ OFFSETS_ENU_M[flight[n]]
    return g


def _figures(survey: Path, out: Path) -> dict:
    from dji_end_to_end import centre_errors_enu_m      # bench/: the same comparison with the truth

    res = json.loads((out / "residuals.json").read_text())
    d, sd = centre_errors_enu_m(survey, out)
    rows = res["rows"] if "rows" in res else res.get("points", [])
    cp = [(np.array([r["dx_m"], r["dy_m"], r["dz_m"]]), np.array(r["sigma_m"])) for r in rows if r.get("sigma_m")]
    summary = json.loads((out / "georef_summary.json").read_text())
    fo = summary["adjustment"].get("flight_offsets")
    return {"n_check": res["statistics"]["n"], "rmse_3d_mm": 1000 * res["statistics"]["3d"]["rmse_m"],
            "centre_anees": float(np.mean(np.sum((d / sd) ** 2, axis=1) / 3.0)),
            "centre_mean_error_mm": (1000 * d.mean(axis=0)).round(1).tolist(),
            "centre_median_sigma_mm": (1000 * np.median(sd, axis=0)).round(1).tolist(),
            "check_anees": float(np.mean([np.sum((e / s) ** 2) / 3.0 for e, s in cp])) if cp else float("nan"),
            "offsets": None if not fo else [(np.round(100 * np.array(r["offset_enu_m"]), 2).tolist(),
                                             np.round(100 * np.array(r["sigma_enu_m"]), 2).tolist())
                                            for r in fo["flights"]]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=23)
    ap.add_argument("--images", type=int, default=30)
    ap.add_argument("--keep", help="work folder to keep (default: a temporary one)")
    ap.add_argument("--modes", default="joint", help="adjustment modes, comma-separated (joint, similarity, gcp)")
    a = ap.parse_args()
    work = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="flight_offsets_"))
    survey = work / "site"
    t0 = time.perf_counter()
    if not (survey / "truth").is_dir():
        assert georef(["simulate", str(survey), "--seed", str(a.seed), "--quiet", "--aircraft", "dji-rtk", "--small",
                       "--images", str(a.images), "--flights", "2"]) == 0
    print(f"simulated in {time.perf_counter() - t0:.0f} s -> {survey}")
    with open(survey / "gcp" / "points.csv") as f:
        points = [r[0] for r in csv.reader(f) if r and not r[0].startswith("#")][1:]
    step.match_images_to_events = _shifted_match
    first = None
    cases = []
    for adj_mode in a.modes.split(","):
        if adj_mode == "joint":
            cases += [("joint", n, m) for n in (0, 1) for m in ("off", "auto")]
        else:
            cases += [(adj_mode, 0 if adj_mode == "similarity" else 3, m) for m in ("off", "auto")]
    for adj_mode, n_control, mode in cases:
        out = work / (f"out_{n_control}_{mode}" if adj_mode == "joint" else f"out_{adj_mode}_{mode}")
        if first is not None:
            for sub in ("ppk", "sfm", "inputs"):
                shutil.copytree(first / sub, out / sub, dirs_exist_ok=True)
        control = ("none" if not n_control else points[len(points) // 2] if n_control == 1
                   else ",".join(points[:n_control]))
        t1 = time.perf_counter()
        rc = georef(["georef", str(survey), "--out", str(out), "--control", control, "--no-leave-one-out",
                     "--flight-offsets", mode, "--mode", adj_mode])
        if rc != 0:
            print(f"georef failed ({rc})")
            continue
        first = first or out
        f = _figures(survey, out)
        lad = json.loads((out / "lever_arm_delay.json").read_text())
        if adj_mode != "joint":
            print(f"mode {adj_mode}: delay {1000 * lad['delay_s']:.2f} +- "
                  f"{1000 * (lad['delay_sigma_s'] or float('nan')):.2f} ms")
        print(f"{adj_mode}, {n_control} GCP ({control}), offsets {'modelled' if mode == 'auto' else 'not modelled'}: camera "
              f"centres ANEES {f['centre_anees']:.2f} (mean error {f['centre_mean_error_mm']} mm, median sigma "
              f"{f['centre_median_sigma_mm']} mm); {f['n_check']} check points 3D RMSE {f['rmse_3d_mm']:.1f} mm, "
              f"ANEES {f['check_anees']:.2f}; offsets (cm, +- sigma) {f['offsets']}; {time.perf_counter() - t1:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
