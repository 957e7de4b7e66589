"""DJI RTK flights at realistic size on the simulator, against truth (docs/georeferencing.md, DJI RTK
flights): `georef simulate --aircraft dji-rtk` (default size: about 96 photos of 1600 px at 60 m), then
`georef georef` with zero control points (every target a check point) three ways:

* raw PPK (the aircraft's RTCM 3 log + the base) with the MRK's per-exposure offsets;
* RTK-tagged photos alone (no raw log, no base), weighted by their RtkStd sigmas;
* the MRK offsets zeroed (the camera taken at the antenna): the figure that shows the offsets matter.

Prints the check points' 3D RMSE and the camera centres' ANEES against the truth for each, and the
time of each step. Usage: python bench/dji_end_to_end.py [--seed 41] [--small] [--images N] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from georef_core.cli.main import main as georef  # noqa: E402
from georef_core.project_frame import ProjectFrame  # noqa: E402


def _copy(src: Path, dst: Path, drop, edit_mrk=None) -> Path:
    for p in src.rglob("*"):
        if p.is_dir() or drop(p):
            continue
        q = dst / p.relative_to(src)
        q.parent.mkdir(parents=True, exist_ok=True)
        if p.suffix.upper() == ".JPG":
            q.symlink_to(p)
        elif edit_mrk and p.name.endswith("_Timestamp.MRK"):
            q.write_text(edit_mrk(p.read_text()))
        else:
            shutil.copy2(p, q)
    return dst


def centre_errors_enu_m(survey: Path, out: Path) -> tuple[np.ndarray, np.ndarray]:
    """(errors, sigmas), (N, 3) each: the adjusted camera centres of a georef output folder against the
    simulated DJI survey's true centres, in the project frame's ENU (m)."""
    truth = json.loads((survey / "truth" / "camera_poses.json").read_text())
    names = json.loads((survey / "truth" / "dji_names.json").read_text())["names"]
    true_ecef = {names[p["name"]]: np.array(p["camera_centre_ecef_m"]) for p in truth["images"]}
    oi = json.loads((out / "oriented_images.json").read_text())
    pf = ProjectFrame.from_dict(oi["project_frame"])
    d = np.array([np.array(im["centre_enu_m"]) - pf.ecef_to_enu(true_ecef[im["name"]]) for im in oi["images"]])
    return d, np.array([im["centre_sigma_enu_m"] for im in oi["images"]])


def _figures(survey: Path, out: Path) -> dict:
    res = json.loads((out / "residuals.json").read_text())
    d, sd = centre_errors_enu_m(survey, out)
    return {"check_points": res["statistics"]["n"], "rmse_3d_mm": 1000 * res["statistics"]["3d"]["rmse_m"],
            "rmse_v_mm": 1000 * res["statistics"]["dz"]["rmse_m"],
            "centre_anees": float(np.mean(np.sum((d / sd) ** 2, axis=1) / 3.0)),
            "centre_mean_error_enu_mm": (1000 * d.mean(axis=0)).round(1).tolist()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=41)
    ap.add_argument("--small", action="store_true")
    ap.add_argument("--images", type=int)
    ap.add_argument("--keep", help="work folder to keep (default: a temporary one)")
    a = ap.parse_args()
    work = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="dji_bench_"))
    survey = work / "site"
    args = ["simulate", str(survey), "--seed", str(a.seed), "--quiet", "--aircraft", "dji-rtk"]
    args += ["--small"] if a.small else []
    args += ["--images", str(a.images)] if a.images else []
    t0 = time.perf_counter()
    assert georef(args) == 0
    print(f"simulated in {time.perf_counter() - t0:.0f} s -> {survey}")
    cases = {
        "raw PPK + MRK offsets": (survey, None),
        "RTK-tagged photos alone": (_copy(survey, work / "rtk_only", lambda p: p.name.endswith("_PPKRAW.bin")
                                         or p.parent.name == "base"), None),
        "MRK offsets zeroed": (_copy(survey, work / "zeroed", lambda p: False,
                                     lambda t: re.sub(r"-?\d+,N\t\s*-?\d+,E\t\s*-?\d+,V", "0,N\t0,E\t0,V", t)), None),
    }
    first_out = None
    for name, (site, _) in cases.items():
        out = work / ("out_" + re.sub(r"\W+", "_", name))
        if first_out is not None:           # the same photos: reuse the first run's SfM
            out.mkdir(parents=True, exist_ok=True)
            shutil.copytree(first_out / "sfm", out / "sfm", dirs_exist_ok=True)
        t0 = time.perf_counter()
        rc = georef(["georef", str(site), "--out", str(out), "--control", "none", "--no-leave-one-out"])
        dt = time.perf_counter() - t0
        if rc != 0:
            print(f"{name}: georef failed ({rc})")
            continue
        first_out = first_out or out
        f = _figures(survey, out)
        print(f"{name:26s} check points {f['check_points']}: 3D RMSE {f['rmse_3d_mm']:6.1f} mm; camera centres ANEES "
              f"{f['centre_anees']:6.2f}, mean error E/N/U {f['centre_mean_error_enu_mm']} mm; {dt:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
