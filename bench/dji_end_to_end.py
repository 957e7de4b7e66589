"""DJI RTK flights at realistic size on the simulator, against truth (docs/georeferencing.md, DJI RTK
flights): `georef simulate --aircraft dji-rtk` (default size: about 96 photos of 1600 px at 60 m), then
`georef georef` with zero control points (every target a check point) three ways:

* raw PPK (the aircraft's RTCM 3 log + the base) with the MRK's per-exposure offsets;
* RTK-tagged photos alone (no raw log, no base), weighted by their RtkStd sigmas;
* the MRK offsets zeroed (the camera taken at the antenna): the figure that shows the offsets matter.

Prints the check points' 3D RMSE and the camera centres' ANEES against the truth for each, and the
time of each step. Usage: python bench/dji_end_to_end.py [--seed 41] [--small] [--images N] [--keep DIR]
[--flight-offsets MODE[,MODE...]] [--flight-offset-sigma H,V] [--cases ppk,rtk,zeroed]

``--flight-offsets auto,on`` runs each case once per mode (forwarded to `georef georef --flight-offsets`; the
SfM is reused), e.g. to compare the per-flight GNSS offsets modelled or not on the same survey; ``--cases ppk``
runs the raw PPK case alone. The check points' ANEES (their stated sigmas against their errors) is printed too.
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
            "centre_mean_error_enu_mm": (1000 * d.mean(axis=0)).round(1).tolist(),
            "check_anees": _check_anees(res)}


def _check_anees(res: dict) -> float:
    """The check points' ANEES: mean over points of |error / stated sigma|^2 / 3 (nan where no sigma)."""
    rows = [r for r in res.get("rows", res.get("points", [])) if r.get("sigma_m")]
    if not rows:
        return float("nan")
    e = np.array([[r["dx_m"], r["dy_m"], r["dz_m"]] for r in rows])
    return float(np.mean(np.sum((e / np.array([r["sigma_m"] for r in rows])) ** 2, axis=1) / 3.0))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=41)
    ap.add_argument("--small", action="store_true")
    ap.add_argument("--images", type=int)
    ap.add_argument("--keep", help="work folder to keep (default: a temporary one)")
    ap.add_argument("--flight-offsets", default="",
                    help="comma-separated modes (auto, on, off) forwarded to georef --flight-offsets; each case runs "
                         "once per mode (default: the step's default, not forwarded)")
    ap.add_argument("--flight-offset-sigma", help="H,V (m): forwarded to georef --flight-offset-sigma (the per-flight "
                    "offsets' prior; default the step's 1 cm / 1.5 cm)")
    ap.add_argument("--cases", default="ppk,rtk,zeroed", help="which cases to run: ppk, rtk, zeroed (comma-separated)")
    ap.add_argument("--control", default="none",
                    help="forwarded to georef --control: 'none' (default, every target a check point) or the names of "
                         "the control points (e.g. one target: what a focal length left at its prior needs)")
    a = ap.parse_args()
    modes = [m.strip() for m in a.flight_offsets.split(",") if m.strip()] or [None]
    wanted = {c.strip() for c in a.cases.split(",") if c.strip()}
    if bad := [m for m in modes if m is not None and m not in ("auto", "on", "off")] + sorted(wanted - {"ppk", "rtk", "zeroed"}):
        ap.error(f"unknown --flight-offsets mode or --cases name: {', '.join(map(str, bad))}")
    work = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="dji_bench_"))
    survey = work / "site"
    args = ["simulate", str(survey), "--seed", str(a.seed), "--quiet", "--aircraft", "dji-rtk"]
    args += ["--small"] if a.small else []
    args += ["--images", str(a.images)] if a.images else []
    t0 = time.perf_counter()
    assert georef(args) == 0
    print(f"simulated in {time.perf_counter() - t0:.0f} s -> {survey}")
    cases = {
        "raw PPK + MRK offsets": (survey, "ppk"),
        "RTK-tagged photos alone": (None if "rtk" not in wanted else _copy(
            survey, work / "rtk_only", lambda p: p.name.endswith("_PPKRAW.bin") or p.parent.name == "base"), "rtk"),
        "MRK offsets zeroed": (None if "zeroed" not in wanted else _copy(
            survey, work / "zeroed", lambda p: False,
            lambda t: re.sub(r"-?\d+,N\t\s*-?\d+,E\t\s*-?\d+,V", "0,N\t0,E\t0,V", t)), "zeroed"),
    }
    runs = [(f"{name} [{m}]" if m else name, site, m) for name, (site, key) in cases.items() if key in wanted
            for m in modes]
    first_out = None
    for name, site, mode in runs:
        out = work / ("out_" + re.sub(r"\W+", "_", name))
        if first_out is not None:           # the same photos: reuse the first run's SfM
            out.mkdir(parents=True, exist_ok=True)
            shutil.copytree(first_out / "sfm", out / "sfm", dirs_exist_ok=True)
        t0 = time.perf_counter()
        rc = georef(["georef", str(site), "--out", str(out), "--control", a.control, "--no-leave-one-out"]
                    + (["--flight-offsets", mode] if mode else [])
                    + (["--flight-offset-sigma", a.flight_offset_sigma] if a.flight_offset_sigma else []))
        dt = time.perf_counter() - t0
        if rc != 0:
            print(f"{name}: georef failed ({rc})")
            continue
        first_out = first_out or out
        f = _figures(survey, out)
        print(f"{name:26s} check points {f['check_points']}: 3D RMSE {f['rmse_3d_mm']:6.1f} mm; camera centres ANEES "
              f"{f['centre_anees']:6.2f}, mean error E/N/U {f['centre_mean_error_enu_mm']} mm; check-point ANEES "
              f"{f['check_anees']:.2f}; {dt:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
