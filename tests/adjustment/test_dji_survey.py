"""DJI RTK flights end to end, on the simulator's DJI layout (`georef simulate --aircraft dji-rtk`:
flight folders with a Timestamp.MRK of per-exposure antenna-to-camera offsets, an RTCM 3 raw log and
RTK-tagged photos from a gimbal camera, plus base/ and gcp/), against the simulator's truth:
raw PPK + MRK with no control point, RTK-tagged photos alone, the gimbal offsets ignored (which must
fail visibly), and two flights with a split base equal to the same data joined by hand."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from georef_core.cli.main import main

from ..once_per_session import once_per_session

pytest.importorskip("pycolmap")


def _simulate(out: Path, flights: int, seed: int = 21, images: int | None = None) -> Path:
    args = ["simulate", str(out), "--seed", str(seed), "--small", "--quiet", "--aircraft", "dji-rtk",
            "--flights", str(flights)]
    assert main(args + (["--images", str(images)] if images else [])) == 0
    return out


@pytest.fixture(scope="module")
def dji_survey(tmp_path_factory) -> Path:
    """30 photos of 640 x 480 in four lines over a 69 x 31 m site, five targets (all check points)."""
    return once_per_session(tmp_path_factory, "dji_survey_seed23",
                            lambda folder: _simulate(folder / "site", 1, seed=23, images=30))


@pytest.fixture(scope="module")
def ppk_run(dji_survey, tmp_path_factory) -> Path:
    def make(out):
        assert main(["georef", str(dji_survey), "--out", str(out), "--control", "none", "--no-leave-one-out"]) == 0
        return out

    return once_per_session(tmp_path_factory, "dji_survey_seed23_ppk_run", make)


def _check_rmse_3d(out: Path) -> tuple[float, int]:
    res = json.loads((out / "residuals.json").read_text())
    return res["statistics"]["3d"]["rmse_m"], res["statistics"]["n"]


def _copy_without(survey: Path, dest: Path, drop) -> Path:
    """A copy of the survey (photos linked) without the files for which ``drop(path)`` is true."""
    for src in survey.rglob("*"):
        rel = src.relative_to(survey)
        if src.is_dir() or drop(src):
            continue
        dst = dest / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.suffix.upper() == ".JPG":
            dst.symlink_to(src)
        else:
            shutil.copy2(src, dst)
    return dest


def test_layout_is_what_the_aircraft_writes(dji_survey):
    flights = sorted(p for p in dji_survey.iterdir() if p.is_dir() and p.name.startswith("DJI_"))
    assert len(flights) == 1
    files = {p.name for p in flights[0].iterdir()}
    assert any(n.endswith("_Timestamp.MRK") for n in files) and any(n.endswith("_PPKRAW.bin") for n in files)
    assert not (dji_survey / "rover").exists() and not (dji_survey / "events.csv").exists()
    assert not (dji_survey / "nav").exists()           # the raw log carries the ephemerides


def test_raw_ppk_and_mrk_without_control(dji_survey, ppk_run):
    """Zero control points, every target a check point: 3D RMSE <= 2 cm from raw PPK + MRK offsets."""
    summary = json.loads((ppk_run / "georef_summary.json").read_text())
    assert summary["inputs"]["layout"] == "dji"
    assert summary["images"]["with_gnss"] == summary["images"]["total"] == 30
    assert summary["adjustment"]["factory_calibration"]["used_as"] == "prior"
    cross = summary["inputs"]["rtk_cross_check"]           # the MRK's RTK quality against the photos' XMP
    assert (cross["checked"], cross["disagree"]) == (30, 0), cross
    assert "MRK" in summary["gnss_source"]
    lad = json.loads((ppk_run / "lever_arm_delay.json").read_text())
    assert lad["lever_arm_cam_m"] == [0.0, 0.0, 0.0]         # held: the offsets place the camera
    rmse, n = _check_rmse_3d(ppk_run)
    assert n >= 4
    assert rmse <= 0.02, rmse
    gnss = json.loads((ppk_run / "ppk" / "summary.json").read_text())
    assert gnss["inputs"]["layout"] == "dji" and gnss["fix_rate"] > 0.9


def test_gimbal_offsets_ignored_fail_visibly(dji_survey, ppk_run, tmp_path):
    """The same flight with the MRK offsets zeroed (the camera taken at the antenna): the check points
    move by the ~20 cm antenna-to-camera offset."""
    def zero_offsets(text: str) -> str:
        return re.sub(r"-?\d+,N\t\s*-?\d+,E\t\s*-?\d+,V", "0,N\t0,E\t0,V", text)

    survey = _copy_without(dji_survey, tmp_path / "site", lambda p: False)
    for mrk in survey.rglob("*_Timestamp.MRK"):
        mrk.write_text(zero_offsets(mrk.read_text()))
    out = tmp_path / "out"
    out.mkdir()
    shutil.copytree(ppk_run / "ppk", out / "ppk")
    shutil.copytree(ppk_run / "sfm", out / "sfm")
    assert main(["georef", str(survey), "--out", str(out), "--control", "none", "--no-leave-one-out"]) == 0
    assert json.loads((out / "georef_summary.json").read_text())["sfm"]["reused"]
    rmse_ignored, _ = _check_rmse_3d(out)
    rmse_used, _ = _check_rmse_3d(ppk_run)
    print(f"check points 3D RMSE: MRK offsets used {1000 * rmse_used:.1f} mm, ignored {1000 * rmse_ignored:.1f} mm")
    assert rmse_ignored > 0.10 and rmse_ignored > 5 * rmse_used


def test_rtk_photos_alone(dji_survey, ppk_run, tmp_path):
    """No raw log, no base: the photos' RTK positions with their sigmas: check points <= 3 cm, and the
    adjusted camera centres' errors consistent with their stated sigmas (ANEES within [0.5, 2])."""
    survey = _copy_without(dji_survey, tmp_path / "site",
                           lambda p: p.name.endswith("_PPKRAW.bin") or p.parent.name == "base")
    out = tmp_path / "out"
    out.mkdir()
    # the same photos, so the same SfM (its key does not hold the positions of an exhaustive block)
    shutil.copytree(ppk_run / "sfm", out / "sfm")
    assert main(["georef", str(survey), "--out", str(out), "--control", "none", "--no-leave-one-out"]) == 0
    summary = json.loads((out / "georef_summary.json").read_text())
    assert summary["sfm"]["reused"]          # other positions, the same photos: the model is not made again
    assert "RTK camera positions in the photos' XMP" in summary["gnss_source"]
    # one fixed RTK-photo flight: auto models its RTK session's error (the simulator draws one per flight)
    assert [r["quality"] for r in summary["adjustment"]["flight_offsets"]["flights"]] == ["fixed"]
    rmse, n = _check_rmse_3d(out)
    assert n >= 4 and rmse <= 0.03, rmse
    truth = json.loads((dji_survey / "truth" / "camera_poses.json").read_text())
    names = json.loads((dji_survey / "truth" / "dji_names.json").read_text())["names"]
    true_ecef = {names[p["name"]]: np.array(p["camera_centre_ecef_m"]) for p in truth["images"]}
    oriented = json.loads((out / "oriented_images.json").read_text())
    from georef_core.project_frame import ProjectFrame

    pf = ProjectFrame.from_dict(oriented["project_frame"])
    nees = []
    for im in oriented["images"]:
        d = np.array(im["centre_enu_m"]) - pf.ecef_to_enu(true_ecef[im["name"]])
        sd = np.array(im["centre_sigma_enu_m"])
        nees.append(float(np.sum((d / sd) ** 2) / 3.0))
    anees = float(np.mean(nees))
    print(f"RTK photos alone: check points 3D RMSE {1000 * rmse:.1f} mm, camera centres ANEES {anees:.2f}")
    assert 0.5 <= anees <= 2.0, anees


def test_two_flights_and_split_base_equal_one_joined_flight(tmp_path):
    """Two flight folders and a base in two files process in one run; the antenna positions at every
    exposure equal those of the same data joined by hand into one flight (one MRK, one RTCM 3 log, one
    base file) within 1 mm."""
    from georef_core.gnss.rinex_obs import read_rinex_obs, write_rinex3_obs
    from georef_core.gnss.observations import join_observations
    from georef_core.steps.gnss_solve import run_survey_gnss

    two = _simulate(tmp_path / "two", 2, seed=22)
    flights = sorted(p for p in two.iterdir() if p.is_dir() and p.name.startswith("DJI_"))
    assert len(flights) == 2 and len(list((two / "base").glob("*.obs"))) == 2
    s_two = run_survey_gnss(two, tmp_path / "out_two")
    assert len(s_two["inputs"]["flights"]) == 2 and len(s_two["inputs"]["base"]) == 2
    assert any("between flights" in w for w in s_two["warnings"])
    # the same data joined by hand: one folder, one MRK (exposures renumbered), one log, one base file
    one = tmp_path / "one"
    folder = one / "DJI_joined_001_Georef"
    folder.mkdir(parents=True)
    mrk_lines, stream, k = [], b"", 0
    for fl in flights:
        for line in next(fl.glob("*_Timestamp.MRK")).read_text().splitlines():
            k += 1
            old, rest = line.split("\t", 1)
            mrk_lines.append(f"{k}\t{rest}")
            photo = next(fl.glob(f"*_{int(old):04d}_V.JPG"))
            (folder / f"DJI_{k:04d}.JPG").symlink_to(photo)
        stream += next(fl.glob("*_PPKRAW.bin")).read_bytes()
    (folder / "DJI_joined_Timestamp.MRK").write_text("\n".join(mrk_lines) + "\n")
    (folder / "DJI_joined_PPKRAW.bin").write_bytes(stream)
    (one / "base").mkdir()
    base, _ = join_observations([read_rinex_obs(p) for p in sorted((two / "base").glob("*.obs"))])
    write_rinex3_obs(one / "base" / "base.obs", base)
    shutil.copytree(two / "gcp", one / "gcp")
    s_one = run_survey_gnss(one, tmp_path / "out_one")
    assert len(s_one["inputs"]["flights"]) == 1
    ev_two = np.genfromtxt(tmp_path / "out_two" / "ppk" / "events.csv", delimiter=",", names=True)
    ev_one = np.genfromtxt(tmp_path / "out_one" / "ppk" / "events.csv", delimiter=",", names=True)
    assert len(ev_two) == len(ev_one) == 12
    d = np.stack([ev_two[c] - ev_one[c] for c in ("x_ecef_m", "y_ecef_m", "z_ecef_m")], axis=1)
    print(f"two flights vs joined: max antenna difference {1000 * np.abs(d).max():.3f} mm")
    assert np.abs(d).max() <= 1e-3
