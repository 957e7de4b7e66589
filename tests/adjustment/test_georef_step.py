"""`georef georef` on a small simulated survey (12 images, 640 x 480, dual-frequency GNSS, five targets):
the command's outputs, control/check switching without re-matching, blunder naming and input errors.
The accuracy figures at realistic sizes are in bench/sim_end_to_end.py (docs/georeferencing.md)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from georef_core.cli.main import main

from ..once_per_session import once_per_session

pytest.importorskip("pycolmap")


@pytest.fixture(scope="module")
def survey(tmp_path_factory) -> Path:
    def make(folder):
        out = folder / "site"
        assert main(["simulate", str(out), "--seed", "11", "--small", "--quiet"]) == 0
        return out

    return once_per_session(tmp_path_factory, "georef_step_survey_seed11", make)


@pytest.fixture(scope="module")
def first_run(survey, tmp_path_factory):
    def make(out):
        rc = main(["georef", str(survey), "--out", str(out), "--control", "T01,T03,T05", "--no-leave-one-out"])
        assert rc == 0
        return out

    return once_per_session(tmp_path_factory, "georef_step_first_run", make)


def _linked_copy(survey: Path, dest: Path, without: str) -> Path:
    """The survey folder with symlinks to everything but ``without`` (to be replaced by the test)."""
    dest.mkdir()
    for item in survey.iterdir():
        if item.name != without:
            (dest / item.name).symlink_to(item)
    return dest


def _reusing(run: Path, dest: Path) -> Path:
    """A new output folder holding ``run``'s PPK and SfM, so that a re-run only adjusts."""
    dest.mkdir()
    for sub in ("ppk", "sfm"):
        shutil.copytree(run / sub, dest / sub)
    return dest


def _truth_lever_delay(survey: Path):
    t = json.loads((survey / "truth" / "lever_arm_delay.json").read_text())
    return np.array(t["lever_arm_cam_m"]), t["delay_s"]


def test_outputs_and_check_point_table(survey, first_run):
    out = first_run
    summary = json.loads((out / "georef_summary.json").read_text())
    assert summary["images"]["registered"] == summary["images"]["total"] == 12
    assert summary["images"]["with_gnss"] == 12
    assert summary["adjustment"]["converged"]
    res = json.loads((out / "residuals.json").read_text())
    names = {r["name"] for r in res["points"]}
    assert names and names <= {"T02", "T04"}                 # the check points only
    assert all(r["role"] == "check" for r in res["points"])
    d = np.array([[r["dx_m"], r["dy_m"], r["dz_m"]] for r in res["points"]])
    assert np.all(np.abs(d[:, :2]) < 0.03) and np.all(np.abs(d[:, 2]) < 0.05), d
    st = res["statistics"]
    assert st["n"] == len(names) and st["3d"]["rmse_m"] == pytest.approx(np.sqrt(np.mean(np.sum(d ** 2, 1))))
    csv_lines = (out / "residuals.csv").read_text().splitlines()
    assert csv_lines[0].startswith("point,role,dx_m,dy_m,dz_m,d3_m")
    lad = json.loads((out / "lever_arm_delay.json").read_text())
    lever, delay = _truth_lever_delay(survey)
    est, sig = np.array(lad["lever_arm_cam_m"]), np.array(lad["lever_arm_sigma_m"])
    assert np.all(np.abs(est - lever) < np.maximum(4 * sig, 0.01)), (est, sig, lever)
    assert abs(lad["delay_s"] - delay) < max(4 * lad["delay_sigma_s"], 0.003)
    assert "lever_z" in lad["correlations"]["names"] and "f" in lad["correlations"]["names"]
    oriented = json.loads((out / "oriented_images.json").read_text())
    assert len(oriented["images"]) == 12
    for name in ("plots/check_residuals.png", "plots/gnss_residuals.png", "sparse_points.ply", "gnss_residuals.json"):
        assert (out / name).is_file(), name
    # paths in the summary are relative to the run folder (a moved run folder stays valid)
    assert not any(Path(v).is_absolute() for v in summary["outputs"].values())
    # the base position of the PPK (the simulated base's RINEX header) is named as what the survey rests on
    basis = {b["kind"]: b for b in summary["absolute_accuracy"]["basis"]}
    assert basis["base position"] == {"kind": "base position", "source": "rinex-header", "sigma_enu_m": None}
    assert "taken as surveyed" in summary["absolute_accuracy"]["text"]


def test_an_unsurveyed_base_position_is_stated_as_the_surveys_absolute_uncertainty():
    """PPK relative to a base whose position is an averaged single-point solution: the absolute-accuracy
    statement gives the base position's sigma and says that the whole survey shifts with it (the per-photo
    PPK sigmas, centimetres, describe the shape only); with control points, that they tie it."""
    from types import SimpleNamespace

    from georef_core.adjustment.control_points import ControlData, GroundPoint
    from georef_core.steps.georef import ImageGnss, _absolute_accuracy

    n = 4
    gnss = ImageGnss(names=[f"i{k}" for k in range(n)], trigger_gps_time_s=np.arange(n, dtype=float),
                     position_ecef_m=np.zeros((n, 3)), velocity_ecef_m_s=np.zeros((n, 3)),
                     sd_ecef_m=np.full((n, 3), 0.01), status=np.ones(n, int), source="PPK (test)")
    gnss_enu = {f"i{k}": (None, None, np.diag([1e-4, 1e-4, 2.25e-4])) for k in range(n)}
    adj = SimpleNamespace(gnss_rows=[{"image": f"i{k}"} for k in range(n)], stats={"control_points_used": []})
    base = {"source": "averaged-single-point", "sigma_enu_m": [0.6, 0.8, 2.1],
            "text": "an averaged single-point position of the base log base.ubx (not surveyed)"}
    acc = _absolute_accuracy(gnss, adj, ControlData(), gnss_enu, base)
    assert {b["kind"] for b in acc["basis"]} == {"PPK camera positions", "base position"}
    assert "uncertain by 1.0 m horizontally and 2.1 m vertically" in acc["text"]
    assert "shifted by the base position's error" in acc["text"] and "base.ubx" in acc["text"]
    control = ControlData()
    control.points["A"] = GroundPoint("A", np.zeros(3), "EPSG:32633", "control")
    adj.stats["control_points_used"] = ["A"]
    assert "the control points tie it" in _absolute_accuracy(gnss, adj, control, gnss_enu, base)["text"]
    # a surveyed base (no sigma stated): named, no metre-level claim
    surveyed = {"source": "given", "sigma_enu_m": None, "text": "the base position given in the settings"}
    text = _absolute_accuracy(gnss, SimpleNamespace(gnss_rows=adj.gnss_rows, stats={}), ControlData(), gnss_enu,
                              surveyed)["text"]
    assert "given in the settings" in text and "uncertain by" not in text


def test_switching_control_and_check_reuses_matching(survey, first_run, tmp_path):
    out = tmp_path / "switch"
    shutil.copytree(first_run, out)
    ppk_made = (out / "ppk" / "summary.json").stat().st_mtime_ns
    rc = main(["georef", str(survey), "--out", str(out), "--control", "T02,T04", "--no-leave-one-out"])
    assert rc == 0
    summary = json.loads((out / "georef_summary.json").read_text())
    assert summary["timings_s"]["sfm_s"] < 2.0             # the SfM model was reused, not recomputed
    assert (out / "ppk" / "summary.json").stat().st_mtime_ns == ppk_made    # the PPK too (same trigger times)
    names = {r["name"] for r in json.loads((out / "residuals.json").read_text())["points"]}
    assert names and names <= {"T01", "T03", "T05"}


def test_a_wrong_click_is_named(survey, first_run, tmp_path):
    bad = _linked_copy(survey, tmp_path / "bad_survey", "gcp")
    (bad / "gcp").mkdir()
    lines = (survey / "gcp" / "gcp_list.txt").read_text().splitlines()
    counts: dict[str, int] = {}
    for ln in lines[1:]:
        tok = ln.split()
        counts[tok[6]] = counts.get(tok[6], 0) + 1
    victim = max(counts, key=counts.get)
    assert counts[victim] >= 3
    for k, ln in enumerate(lines):
        tok = ln.split()
        if k > 0 and tok[6] == victim:
            tok[3] = f"{float(tok[3]) + 40.0:.2f}"         # clicked 40 px beside the target
            lines[k] = " ".join(tok)
            wrong_image = tok[5]
            break
    (bad / "gcp" / "gcp_list.txt").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    shutil.copytree(first_run, out)                          # reuse PPK and SfM
    assert main(["georef", str(bad), "--out", str(out), "--control", "all", "--no-leave-one-out"]) == 0
    summary = json.loads((out / "georef_summary.json").read_text())
    named = [(b["point"], b["image"]) for b in summary["blunders"]]
    assert (victim, wrong_image) in named
    assert len(named) == 1


def test_bad_inputs_are_named(survey, first_run, tmp_path, capsys):
    bad = _linked_copy(survey, tmp_path / "crs_survey", "gcp")
    (bad / "gcp").mkdir()
    lines = (survey / "gcp" / "gcp_list.txt").read_text().splitlines()
    (bad / "gcp" / "gcp_list.txt").write_text("\n".join(["EPSG:1234567"] + lines[1:]) + "\n")
    out = tmp_path / "out"
    shutil.copytree(first_run, out)
    assert main(["georef", str(bad), "--out", str(out)]) != 0
    err = capsys.readouterr().err
    assert "gcp_list.txt" in err and "unknown coordinate reference system" in err
    assert "Traceback" not in err

    # an image without a trigger: named, and the rest of the survey is still processed
    ev = _linked_copy(survey, tmp_path / "events_survey", "events.csv")
    ev_lines = (survey / "events.csv").read_text().splitlines()
    dropped = ev_lines[-1].split(",")[0]
    (ev / "events.csv").write_text("\n".join(ev_lines[:-1]) + "\n")
    out2 = _reusing(first_run, tmp_path / "out2")    # SfM reused; the PPK, made for other trigger times, runs again
    ppk_made = (out2 / "ppk" / "summary.json").stat().st_mtime_ns
    assert main(["georef", str(ev), "--out", str(out2), "--no-leave-one-out"]) == 0
    from georef_core.steps.gnss_solve import trigger_table_key

    assert (out2 / "ppk" / "summary.json").stat().st_mtime_ns != ppk_made
    assert json.loads((out2 / "ppk" / "summary.json").read_text())["triggers_sha256"] == trigger_table_key(ev / "events.csv")
    summary = json.loads((out2 / "georef_summary.json").read_text())
    assert summary["images"]["with_gnss"] == 11 and summary["images"]["registered"] == 12
    assert any(dropped in w for w in summary["warnings"])

    # images that are not images
    noimg = tmp_path / "noimg"
    noimg.mkdir()
    (noimg / "images").mkdir()
    assert main(["georef", str(noimg), "--out", str(tmp_path / "out3")]) != 0
    assert "no JPEG/TIFF images" in capsys.readouterr().err


def test_images_to_dense_to_volumes_end_to_end(survey, first_run, tmp_path):
    """The whole chain on the small scene: oriented images -> dense DSM -> stockpile volumes (base: the
    outline's best-fit plane) against the simulator's analytic volumes. 640 x 480 images give a coarse
    DSM (3 cm cells), so the band here is 3 % and the stated uncertainty must cover the error at 3 sigma;
    the 1 % figure at realistic image sizes is measured by bench/sim_end_to_end.py (docs/volumes.md)."""
    from georef_core.steps.dense import run_dense
    from georef_core.steps.volumes import run_volumes

    out = tmp_path / "run"
    shutil.copytree(first_run, out)
    dense = run_dense(out)
    assert (out / "dense" / "dsm.tif").is_file() and (out / "dense" / "ortho.tif").is_file()
    assert dense["dsm_vertical_rmse_m"] is not None and dense["dsm_vertical_rmse_m"] < 0.05
    piles = json.loads((survey / "truth" / "stockpiles.geojson").read_text())["features"]
    vol = run_volumes(out / "dense" / "dsm.tif", survey / "truth" / "stockpiles.geojson", base="plane")
    assert len(vol["results"]) == len(piles) >= 2
    for res, feat in zip(vol["results"], piles):
        true_v = feat["properties"]["volume_m3"]
        err = res["net_m3"] - true_v
        sigma = res["uncertainty"]["sigma_m3"]
        assert abs(err) < 0.03 * true_v, (feat["properties"]["name"], res["net_m3"], true_v)
        assert abs(err) < 3 * sigma, (feat["properties"]["name"], err, sigma)
        assert res["fill_m3"] < 0.02 * true_v                 # a pile on flat ground: (almost) no fill


def test_trigger_times_from_exif_with_a_clock_offset(survey, first_run, tmp_path):
    """No camera events used: trigger = EXIF time (the simulator stamps the exposure, to the ms) + offset.
    With the offset = -delay the trigger times come back to within the EXIF's millisecond, and the images
    get the same antenna positions as from the events."""
    import csv

    _, delay = _truth_lever_delay(survey)
    out = tmp_path / "exif"
    out.mkdir()
    shutil.copytree(first_run / "sfm", out / "sfm")
    rc = main(["georef", str(survey), "--out", str(out), "--control", "T01,T03,T05", "--no-leave-one-out",
               "--exif-time-offset", f"{-delay:.4f}"])
    assert rc == 0
    s = json.loads((out / "georef_summary.json").read_text())
    assert s["images"]["with_gnss"] == 12 and "EXIF" in s["gnss_source"]
    truth = {r["image"]: float(r["trigger_gps_time_s"]) for r in csv.DictReader((survey / "events.csv").open())}
    exif = {r["image"]: float(r["gps_time_s"]) for r in csv.DictReader((out / "ppk" / "exif_triggers.csv").open())}
    assert set(exif) == set(truth)
    assert max(abs(exif[k] - truth[k]) for k in truth) < 0.0011
    assert s["rolling_shutter"]["rolling_shutter"] is None        # SimCam-GS is not in the shutter table
    # the same triggers again: the PPK is reused; then the camera events: the PPK is redone for them
    ppk_summary = out / "ppk" / "summary.json"
    made = ppk_summary.stat().st_mtime_ns
    assert main(["georef", str(survey), "--out", str(out), "--control", "T01,T03,T05", "--no-leave-one-out",
                 "--exif-time-offset", f"{-delay:.4f}"]) == 0
    assert ppk_summary.stat().st_mtime_ns == made
    assert main(["georef", str(survey), "--out", str(out), "--control", "T01,T03,T05", "--no-leave-one-out"]) == 0
    assert ppk_summary.stat().st_mtime_ns != made
    s2 = json.loads((out / "georef_summary.json").read_text())
    assert s2["images"]["with_gnss"] == 12 and "events.csv" in s2["gnss_source"]
    d = np.array([[r["dx_m"], r["dy_m"], r["dz_m"]] for r in json.loads((out / "residuals.json").read_text())["points"]])
    assert np.all(np.abs(d[:, :2]) < 0.03) and np.all(np.abs(d[:, 2]) < 0.05), d


def test_rolling_shutter_cameras_are_flagged():
    from georef_core.photo.camera_shutter import rolling_shutter_of

    assert rolling_shutter_of("FC330")[0] is True            # Phantom 4
    assert rolling_shutter_of("FC6310")[0] is False          # Phantom 4 Pro, mechanical shutter
    assert rolling_shutter_of("SimCam-GS")[0] is None
    assert rolling_shutter_of(None)[0] is None


def test_without_events_csv_the_rover_event_records_are_matched_in_exif_time_order(survey, first_run, tmp_path):
    bare = _linked_copy(survey, tmp_path / "bare", "events.csv")
    out = tmp_path / "out"
    out.mkdir()
    shutil.copytree(first_run / "sfm", out / "sfm")
    assert main(["georef", str(bare), "--out", str(out), "--control", "T01,T03,T05", "--no-leave-one-out"]) == 0
    s = json.loads((out / "georef_summary.json").read_text())
    assert s["images"]["with_gnss"] == 12
    assert "EXIF times" in s["gnss_source"] and not any("file-name order" in w for w in s["warnings"])
    d = np.array([[r["dx_m"], r["dy_m"], r["dz_m"]] for r in json.loads((out / "residuals.json").read_text())["points"]])
    assert np.all(np.abs(d[:, :2]) < 0.03) and np.all(np.abs(d[:, 2]) < 0.05), d


def test_production_flight_with_a_calibration(survey, first_run, tmp_path, capsys):
    """--calibration CAL_OUT_DIR: the calibration run's camera is held, its lever arm is a prior, no control."""
    out = _reusing(first_run, tmp_path / "prod")
    assert main(["georef", str(survey), "--out", str(out), "--control", "none", "--calibration", str(first_run),
                 "--no-leave-one-out"]) == 0
    cal = json.loads((first_run / "georef_summary.json").read_text())
    s = json.loads((out / "georef_summary.json").read_text())
    np.testing.assert_allclose(s["intrinsics"]["values"], cal["intrinsics"]["values"], atol=1e-9)
    assert s["intrinsics"]["sigma"] == {}                       # held, not estimated
    assert s["options"]["lever_arm_cam_m"] == pytest.approx(cal["lever_arm_delay"]["lever_arm_cam_m"])
    res = json.loads((out / "residuals.json").read_text())
    assert {r["name"] for r in res["points"]} == {"T01", "T02", "T03", "T04", "T05"}
    assert res["statistics"]["3d"]["rmse_m"] < 0.05
    # a folder that is not a georeferencing run is named
    assert main(["georef", str(survey), "--out", str(out), "--calibration", str(tmp_path)]) != 0
    assert "georef_summary.json" in capsys.readouterr().err


def test_options_from_the_platform_settings():
    from georef_core.errors import ProcessingError
    from georef_core.steps.georef import georef_options_from_dict

    o = georef_options_from_dict({"mode": "a", "control": "T01,T02,T03", "lever_arm_cam_m": [0.01, -0.1, 0.2]})
    assert o.mode == "gcp" and o.lever_arm_cam_m == (0.01, -0.1, 0.2)
    with pytest.raises(ProcessingError, match="unknown georeferencing settings: levr"):
        georef_options_from_dict({"levr": 1})
    with pytest.raises(ProcessingError, match="mode"):
        georef_options_from_dict({"mode": "fast"})


def test_unknown_gnss_settings_are_refused(survey, tmp_path):
    from georef_core.errors import ProcessingError
    from georef_core.steps.gnss_solve import run_survey_gnss

    with pytest.raises(ProcessingError, match="gnss settings: elmsk: unknown option"):
        run_survey_gnss(survey, tmp_path, {"elmsk": 10})
    with pytest.raises(ProcessingError, match="freq: 'l2' is not one of"):
        run_survey_gnss(survey, tmp_path, {"freq": "l2"})


def test_gnss_settings_reach_the_engine(survey, tmp_path):
    """The platform's GNSS settings (tdcp_slips, hold_variance, ...) are applied and recorded in the summary;
    a value the engine cannot take is refused with the setting named."""
    from georef_core.errors import ProcessingError
    from georef_core.steps.gnss_solve import run_survey_gnss

    summary = run_survey_gnss(survey, tmp_path / "a", {"tdcp_slips": 0.08, "hold_variance": 0.01, "ratio": 2.5,
                                                       "ar": "fix-and-hold"})
    o = summary["options"]
    assert o["tdcp_slips_m"] == 0.08 and o["hold_variance_cyc2"] == 0.01 and o["ratio"] == 2.5
    assert o["ar"] == "fix-and-hold"
    # refused by the step's declared option ranges (specs.GNSS) before anything is read
    with pytest.raises(ProcessingError, match="gnss settings: hold_variance: 0 is below the minimum"):
        run_survey_gnss(survey, tmp_path / "b", {"hold_variance": 0})
    with pytest.raises(ProcessingError, match="gnss settings: tdcp_slips: 2 is above the maximum 1 m"):
        run_survey_gnss(survey, tmp_path / "c", {"tdcp_slips": 2})
    with pytest.raises(ProcessingError, match="gnss settings: ratio: 'three' is not a number"):
        run_survey_gnss(survey, tmp_path / "d", {"ratio": "three"})


@pytest.fixture(scope="module")
def rolling_survey(tmp_path_factory) -> Path:
    """A rolling-shutter camera (40 ms readout at 5 m/s: the camera moves 20 cm while the rows are read):
    27 images of 1600 x 1200 in four lines, enough to estimate the readout (a 12-image, two-line block is
    not: docs/georeferencing.md)."""
    out = tmp_path_factory.mktemp("georef_rs") / "site"
    assert main(["simulate", str(out), "--seed", "5", "--images", "30", "--readout-ms", "40", "--quiet"]) == 0
    return out


def test_rolling_shutter_readout_is_estimated_and_modelled(rolling_survey, tmp_path):
    """The readout is estimated within 3 sigma and 3 ms of the truth, the lever arm and delay come back
    (within 2 cm and 5 ms), and the check points within a centimetre; adjusted as a global shutter, the same
    survey's check points are off by centimetres and the lever arm by decimetres."""
    out = tmp_path / "modelled"
    assert main(["georef", str(rolling_survey), "--out", str(out), "--no-leave-one-out"]) == 0
    s = json.loads((out / "georef_summary.json").read_text())
    rs = s["rolling_shutter"]
    assert rs["rolling_shutter"] is True and rs["modelled"] is True and rs["readout_source"] == "estimated"
    assert not any("rolling shutter" in w or "readout" in w for w in s["warnings"]), s["warnings"]
    assert rs["readout_strongest_correlation"]["abs_rho"] < 0.4   # measured 0.24 (delay)
    true_lever, true_delay = _truth_lever_delay(rolling_survey)
    err = abs(rs["readout_s"] - 0.040)
    assert err < 3 * rs["readout_sigma_s"] and err < 0.003, rs
    lad = s["lever_arm_delay"]
    assert np.all(np.abs(np.array(lad["lever_arm_cam_m"]) - true_lever) < 0.02), lad
    assert abs(lad["delay_s"] - true_delay) < 0.005, lad
    assert lad["readout_s"] == pytest.approx(rs["readout_s"]) and lad["estimated"]["readout"] is True
    oriented = json.loads((out / "oriented_images.json").read_text())  # handed on to the dense step
    assert oriented["cameras"]["1"]["readout_s"] == pytest.approx(rs["readout_s"], abs=1e-6)
    assert all(len(im["velocity_enu_m_s"]) == 3 for im in oriented["images"])
    rmse = s["check_points"]["statistics"]["3d"]["rmse_m"]
    assert rmse < 0.01, s["check_points"]["statistics"]

    ignored = _reusing(out, tmp_path / "ignored")
    assert main(["georef", str(rolling_survey), "--out", str(ignored), "--global-shutter", "--no-leave-one-out"]) == 0
    g = json.loads((ignored / "georef_summary.json").read_text())
    assert g["rolling_shutter"]["modelled"] is False
    assert g["check_points"]["statistics"]["3d"]["rmse_m"] > 2 * max(rmse, 0.01), g["check_points"]["statistics"]
    assert np.max(np.abs(np.array(g["lever_arm_delay"]["lever_arm_cam_m"]) - true_lever)) > 0.1

    # a calibration flight hands its readout on: held fixed in the production run
    prod = _reusing(out, tmp_path / "prod")
    assert main(["georef", str(rolling_survey), "--out", str(prod), "--control", "none", "--calibration", str(out),
                 "--no-leave-one-out"]) == 0
    p = json.loads((prod / "georef_summary.json").read_text())["rolling_shutter"]
    assert p["modelled"] and p["readout_source"] == "given" and p["readout_s"] == pytest.approx(rs["readout_s"], abs=1e-6)


def test_rolling_shutter_options_are_checked(survey, tmp_path, capsys):
    from georef_core.errors import ProcessingError
    from georef_core.steps.georef import georef_options_from_dict

    assert georef_options_from_dict({"readout_s": 0.03}).readout_s == 0.03
    with pytest.raises(ProcessingError, match="readout time 500 ms"):
        georef_options_from_dict({"readout_s": 0.5})
    with pytest.raises(ProcessingError, match="global-shutter"):
        georef_options_from_dict({"readout_s": 0.03, "rolling_shutter": False})
    assert main(["georef", str(survey), "--out", str(tmp_path / "o"), "--readout-ms", "-5"]) != 0
    assert "readout time -5 ms" in capsys.readouterr().err
    assert main(["simulate", str(tmp_path / "s"), "--small", "--readout-ms", "0"]) != 0
    assert "--readout-ms 0" in capsys.readouterr().err


def test_rolling_shutter_simulation_renders_what_it_projects(tmp_path):
    """The simulator's rolling-shutter images and its target measurements agree (the rows seen from where
    the camera was at their exposure), and differ from a global-shutter projection by the camera's motion."""
    from georef_core.adjustment.control_points import load_control
    from georef_core.adjustment.target_refinement import refine_measurements

    site = tmp_path / "rs"
    assert main(["simulate", str(site), "--seed", "3", "--small", "--readout-ms", "60", "--no-gnss", "--quiet"]) == 0
    control = load_control(None, site / "gcp" / "gcp_list.txt", None)
    clicked = {(m.image, m.point): np.array(m.uv_px) for m in control.measurements}
    refine_measurements(site / "images", control.measurements)
    d = np.array([np.array(m.uv_px) - clicked[(m.image, m.point)] for m in control.measurements])
    assert len(d) >= 20
    assert np.all(np.abs(d.mean(axis=0)) < 0.2) and np.all(np.sqrt(np.mean(d ** 2, axis=0)) < 0.6), d
    # the same targets projected as from a global shutter lie off by the motion during the readout
    from georef_core.sim.camera import CameraModel

    intr = json.loads((site / "truth" / "intrinsics.json").read_text())
    cam = CameraModel(**{k: intr[k] for k in CameraModel.__dataclass_fields__ if k in intr})
    assert cam.readout_s == pytest.approx(0.060) and cam.model == "SimCam-RS"
    point, centre, nadir = np.array([[0.0, 10.0, 0.0]]), np.array([0.0, 0.0, 40.0]), np.diag([1.0, -1.0, -1.0])
    uv = cam.project_world(point, centre, nadir)  # 10 m north of the nadir point: in the upper rows
    moving = cam.project_world_moving(point, centre, nadir, np.array([0.0, 5.0, 0.0]))
    shift_px = np.linalg.norm(moving - uv)
    # 5 m/s x 60 ms x (row offset from the middle) seen from 40 m
    expected = cam.fx * 5.0 * cam.row_time_s(moving[0, 1]) / 40.0
    assert abs(expected) > 1.0
    assert shift_px == pytest.approx(abs(expected), rel=0.05, abs=0.01)


def test_rolling_shutter_on_a_small_block_warns_that_the_readout_is_weak(tmp_path):
    """On the 12-image, two-line scene the readout trades against the across-track lever arm (docs): the
    run says so, and with the readout given the lever arm and check points come back."""
    site = tmp_path / "rs"
    assert main(["simulate", str(site), "--seed", "2", "--small", "--readout-ms", "40", "--quiet"]) == 0
    out = tmp_path / "free"
    assert main(["georef", str(site), "--out", str(out), "--no-leave-one-out"]) == 0
    s = json.loads((out / "georef_summary.json").read_text())
    corr = s["rolling_shutter"]["readout_strongest_correlation"]
    assert corr["abs_rho"] > 0.4
    assert any("readout" in w and "--readout-ms" in w for w in s["warnings"]), s["warnings"]
    given = _reusing(out, tmp_path / "given")
    assert main(["georef", str(site), "--out", str(given), "--readout-ms", "40", "--no-leave-one-out"]) == 0
    g = json.loads((given / "georef_summary.json").read_text())
    assert g["rolling_shutter"]["readout_source"] == "given" and not any("readout" in w for w in g["warnings"])
    true_lever, true_delay = _truth_lever_delay(site)
    assert np.all(np.abs(np.array(g["lever_arm_delay"]["lever_arm_cam_m"]) - true_lever) < 0.07), g["lever_arm_delay"]
    assert g["check_points"]["statistics"]["3d"]["rmse_m"] < 0.015, g["check_points"]["statistics"]


def test_a_single_odd_photo_is_left_out_and_named(survey, first_run, tmp_path):
    """One photo of another size (a resized copy) among the survey's: with one camera per (make/model, size,
    focal length) it makes a camera group of one photo, too small to calibrate: it is left out, named with
    why, and the rest georeferences as before (the shared camera used to make COLMAP refuse every image)."""
    from PIL import Image

    odd = _linked_copy(survey, tmp_path / "odd_survey", "images")
    (odd / "images").mkdir()
    for f in sorted((survey / "images").iterdir()):
        if f.name == "IMG_0005.JPG":
            with Image.open(f) as im:
                im.resize((480, 360), Image.LANCZOS).save(odd / "images" / f.name, exif=im.info["exif"], quality=92)
        else:
            (odd / "images" / f.name).symlink_to(f)
    out = tmp_path / "odd_out"
    out.mkdir()
    shutil.copytree(first_run / "ppk", out / "ppk")
    assert main(["georef", str(odd), "--out", str(out), "--control", "T01,T03,T05", "--no-leave-one-out"]) == 0
    s = json.loads((out / "georef_summary.json").read_text())
    assert s["images"]["total"] == 12 and s["images"]["registered"] == 11
    assert [lo["image"] for lo in s["images"]["left_out"]] == ["IMG_0005.JPG"]
    named = [w for w in s["warnings"] if w.startswith("IMG_0005.JPG: left out")]
    assert len(named) == 1 and "480 x 360 px" in named[0] and "640 x 480" in named[0], s["warnings"]
    assert not any("not registered" in w for w in s["warnings"])
    assert len(s["cameras"]) == 1
    d = np.array([[r["dx_m"], r["dy_m"], r["dz_m"]] for r in json.loads((out / "residuals.json").read_text())["points"]])
    assert len(d) and np.all(np.abs(d[:, :2]) < 0.03) and np.all(np.abs(d[:, 2]) < 0.05), d


def _true_ground_doming(survey: Path, out: Path) -> dict:
    """The quadratic bowl of the adjusted tie points' heights against the simulator's true DSM, over the
    cameras' extent (the same fit and definition as the reported figure)."""
    import rasterio

    from georef_core.adjustment.doming import fit_doming
    from georef_core.project_frame import ProjectFrame

    oi = json.loads((out / "oriented_images.json").read_text())
    pf = ProjectFrame.from_dict(oi["project_frame"])
    C = np.array([im["centre_enu_m"] for im in oi["images"]])
    xyz = np.load(out / "oriented_images_sparse.npz")["xyz_enu_m"]
    inside = np.all((xyz[:, :2] >= C[:, :2].min(0)) & (xyz[:, :2] <= C[:, :2].max(0)), axis=1)
    g = pf.enu_to_grid(xyz[inside])
    with rasterio.open(survey / "truth" / "dsm.tif") as ds:
        h = np.array([v[0] for v in ds.sample(g[:, :2])], float)
    ok = h > 1.0                                    # inside the true DSM (0 outside)
    dz = g[ok, 2] - h[ok]
    keep = np.abs(dz - np.median(dz)) < 0.5         # a few tie points on steep pile flanks
    return fit_doming(xyz[inside][ok][keep, :2], dz[keep], None, "true ground")


def test_doming_of_a_wrong_held_distortion_is_reported(survey, first_run, tmp_path):
    """The camera held at a calibration whose k1 is 0.01 off (the lever arm held at its true value, zero
    control): the block bends, and the georef summary reports a significant doming of the right sign and
    size (the bowl of the tie points against the true DSM under the cameras); held at the true calibration
    the figure is not significant. Measured (seed 11): k1 + 0.01: +87.9 mm (sigma 1.7 mm) reported, true
    ground +113 mm; k1 - 0.01: -93.5 mm (2.0), true -111 mm; true k1: -0.2 mm (1.1), true +1.3 mm."""
    from georef_core.steps.georef import GeorefOptions, run_georef

    t = json.loads((survey / "truth" / "intrinsics.json").read_text())
    lever, _ = _truth_lever_delay(survey)
    found = {}
    for dk1 in (0.0, 0.01, -0.01):
        intr = (t["fx"], t["cx"], t["cy"], t["k1"] + dk1, t["k2"], t["k3"], t["p1"], t["p2"])
        out = _reusing(first_run, tmp_path / f"k1_{dk1:+.2f}")
        s = run_georef(survey, out, GeorefOptions(control="none", leave_one_out=False, fixed_intrinsics=intr,
                                                  lever_arm_cam_m=tuple(lever), estimate_lever_arm=False))
        found[dk1] = (s["doming"]["camera_positions"], _true_ground_doming(survey, out), s)
        d, truth, _ = found[dk1]
        print(f"k1 {dk1:+.2f}: reported {1000 * d['doming_m']:+.1f} mm (sigma {1000 * d['sigma_m']:.1f}, "
              f"p {d['p_value']:.2g}), true ground {1000 * truth['doming_m']:+.1f} mm")
    d, truth, s = found[0.0]
    assert not d["significant"] and abs(d["doming_m"]) < 0.02, d
    assert not any(w.startswith("doming") for w in s["warnings"])
    assert s["doming"]["text"].startswith("doming: ") and "not significant" in s["doming"]["text"]
    for dk1, sign in ((0.01, 1.0), (-0.01, -1.0)):
        d, truth, s = found[dk1]
        assert d["significant"] and np.sign(d["doming_m"]) == sign == np.sign(truth["doming_m"]), (d, truth)
        assert 0.5 < d["doming_m"] / truth["doming_m"] < 1.5, (d, truth)
        assert any(w.startswith("doming: ") and "significant" in w for w in s["warnings"]), s["warnings"]


def test_exif_triggers_are_a_gnss_setting_and_georef_reads_the_gnss_steps_ppk(survey, first_run, tmp_path):
    """The platform's order (issue 24): the gnss step makes ppk/ from the photos' EXIF times
    (exif_time_offset_s) with the run's GNSS options; the georef step ties the photos to those triggers
    without re-running PPK (before, it re-ran PPK into ppk/ with its own, default GNSS options)."""
    from georef_core.steps.gnss_solve import run_survey_gnss

    _, delay = _truth_lever_delay(survey)
    out = tmp_path / "platform"
    out.mkdir()
    shutil.copytree(first_run / "sfm", out / "sfm")
    g = run_survey_gnss(survey, out, {"exif_time_offset_s": -delay, "elmask": 20.0})
    assert g["exif_time_offset_s"] == pytest.approx(-delay) and g["options"]["elmask_deg"] == 20.0
    assert (out / "ppk" / "exif_triggers.csv").is_file()
    made = (out / "ppk" / "summary.json").stat().st_mtime_ns
    from georef_core.steps.contract import Workspace
    from georef_core.steps.georef import step_entry

    s = step_entry(Workspace(survey, out), {"control": "T01,T03,T05", "leave_one_out": False}, None, {})
    assert (out / "ppk" / "summary.json").stat().st_mtime_ns == made            # the gnss step's PPK, read
    assert json.loads((out / "ppk" / "summary.json").read_text())["options"]["elmask_deg"] == 20.0
    assert s["images"]["with_gnss"] == 12 and "EXIF" in s["gnss_source"]
    from georef_core.errors import ProcessingError
    from georef_core.steps.contract import get_spec

    with pytest.raises(ProcessingError, match="georef settings: exif_time_offset_s: unknown option"):
        get_spec("georef").validate({"exif_time_offset_s": 0.1})


def test_ppk_reuse_key_is_the_trigger_times(survey, first_run, tmp_path):
    """The command reuses a PPK only under the same trigger-times key (ppk/summary.json triggers_sha256, issue 24;
    the runs that reuse or redo it: test_switching_control_and_check_reuses_matching, test_bad_inputs_are_named).
    The key is the survey's trigger times: one moved by 2 ms changes it; the rows reordered do not."""
    import csv

    from georef_core.steps.gnss_solve import trigger_table_key

    key = json.loads((first_run / "ppk" / "summary.json").read_text())["triggers_sha256"]
    assert key == trigger_table_key(survey / "events.csv")
    rows = list(csv.DictReader((survey / "events.csv").open()))

    def table(name, rows_out):
        path = tmp_path / name
        with path.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows_out)
        return path

    moved = [dict(r) for r in rows]
    moved[5]["trigger_gps_time_s"] = f"{float(moved[5]['trigger_gps_time_s']) + 0.002:.6f}"
    assert trigger_table_key(table("moved.csv", moved)) != key
    assert trigger_table_key(table("reordered.csv", rows[::-1])) == key
    assert trigger_table_key(tmp_path / "none.csv") is None      # no table: the rover log's own event records


def test_ppk_reuse_key_is_the_gnss_inputs_and_options(survey, first_run, tmp_path):
    """Besides the trigger times, the command reuses a PPK only under the same inputs key (ppk/summary.json
    inputs_sha256): every GNSS file's content and the validated GNSS options. A base file with one byte
    changed, an added navigation file or another elevation mask change it; the defaults written out do not."""
    from georef_core.steps.gnss_solve import gnss_inputs_key
    from georef_core.steps.survey_inputs import survey_inputs

    key = json.loads((first_run / "ppk" / "summary.json").read_text())["inputs_sha256"]
    assert gnss_inputs_key(survey_inputs(survey, tmp_path / "o0"), {}) == key
    assert gnss_inputs_key(survey_inputs(survey, tmp_path / "o1"), {"elmask": 15.0}) == key     # the default
    assert gnss_inputs_key(survey_inputs(survey, tmp_path / "o2"), {"elmask": 20.0}) != key
    edited = tmp_path / "edited"
    shutil.copytree(survey, edited, symlinks=True)
    base = sorted((edited / "base").iterdir())[0]
    data = bytearray(base.read_bytes())
    data[-2] = ord("9") if data[-2] != ord("9") else ord("8")
    base.write_bytes(bytes(data))
    assert gnss_inputs_key(survey_inputs(edited, tmp_path / "o3"), {}) != key
