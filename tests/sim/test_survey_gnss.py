"""The GNSS part of a simulated survey (georef_core.sim.survey_gnss) and `georef simulate`.

A small site (12 camera events) is simulated without images for each receiver type; its rover/base/nav files must
load in our reader and in georinex, carry the camera trigger times as event records, and give, through
`georef gnss solve`, a fixed trajectory within a few centimetres of the truth. About 30 s on 2 cores (the two
PPK runs take most of it).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from georef_core.cli.main import main as georef_main
from georef_core.gnss.rinex_nav import read_rinex_nav
from georef_core.gnss.rinex_obs import read_rinex_obs
from georef_core.sim import SimulationOptions, build_site, simulate_flight, simulate_site
from georef_core.sim.camera import CameraModel
from georef_core.sim.site import SiteOptions
from georef_core.sim.survey_gnss import SHIPPED_NAV, GnssOptions, check_navigation_coverage, navigation_coverage

SEED = 7


def _simulate(tmp_path_factory, name: str, **gnss) -> object:
    o = SimulationOptions.small()
    o.write_images = False
    o.gnss = GnssOptions(**gnss)
    return simulate_site(tmp_path_factory.mktemp(name), seed=SEED, options=o, verbose=False)


@pytest.fixture(scope="module")
def sim_l1l2(tmp_path_factory):
    return _simulate(tmp_path_factory, "gnss_l1l2", receiver="l1l2")


@pytest.fixture(scope="module")
def sim_l1(tmp_path_factory):
    return _simulate(tmp_path_factory, "gnss_l1", receiver="l1")


def _run_georef(*args) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = georef_main([str(a) for a in args])
    return rc, out.getvalue() + err.getvalue()


def _solve(res, *extra) -> dict:
    """`georef gnss solve` (known-start with the true take-off antenna position) on a simulated survey."""
    out = res.out_dir / "ppk" / "trajectory.pos"
    x, y, z = res.gnss.takeoff_antenna_ecef_m
    rc, text = _run_georef("gnss", "solve", res.gnss.rover_path, res.gnss.base_path, *res.gnss.nav_paths,
                           "--out", out, "--mode", "known-start", f"--known-start={x:.4f},{y:.4f},{z:.4f}", *extra)
    assert rc == 0, text
    import pyarrow.parquet as pq

    tab = pq.read_table(out.with_suffix(".parquet")).to_pydict()
    t = np.asarray(tab["gps_time_s"])
    pos = np.stack([tab["x_ecef_m"], tab["y_ecef_m"], tab["z_ecef_m"]], -1)
    tr = res.trajectory
    err = np.linalg.norm(pos - tr.position_ecef(np.clip(t, tr.t_start, tr.t_end)), axis=1)
    with open(out.with_name("trajectory_events.csv")) as fh:
        rows = list(csv.DictReader(fh))
    ev_t = np.array([float(r["gps_time_s"]) for r in rows])
    ev_p = np.array([[float(r[k]) for k in ("x_ecef_m", "y_ecef_m", "z_ecef_m")] for r in rows])
    trig = np.array([e.trigger_gps_time_s for e in res.events])
    return {"status": np.asarray(tab["status"]), "err": err, "event_t": ev_t, "trig": trig,
            "event_status": np.array([int(r["status"]) for r in rows]),
            "event_err": np.linalg.norm(ev_p - tr.position_ecef(trig), axis=1)}


@pytest.fixture(scope="module")
def ppk_l1l2(sim_l1l2):
    return _solve(sim_l1l2)


@pytest.fixture(scope="module")
def ppk_l1(sim_l1):
    return _solve(sim_l1, "--freq", "l1")


# ------------------------------------------------------------------------------------------------------------
# navigation file and coverage
# ------------------------------------------------------------------------------------------------------------

def test_shipped_navigation_file_and_provenance():
    assert SHIPPED_NAV.is_file()
    prov = (SHIPPED_NAV.parent / "PROVENANCE.txt").read_text()
    for s in ("taroz/MatRTKLIB", "69bcbd3faebc39815adb03e4b329033a4a7deb4a", "MIT", "Taro Suzuki"):
        assert s in prov
    nav = read_rinex_nav(SHIPPED_NAV)
    assert {s[0] for s in nav.kepler} | {s[0] for s in nav.glonass} == set("GREJC")


def test_default_survey_lies_inside_the_navigation_coverage():
    """The default flight (static periods included) and the base logging around it are covered, for every
    system; the old default site (Paris) is not: the file holds only the satellites tracked near Nagoya."""
    o = SimulationOptions()
    site = build_site(o.site, 0)
    traj, _, _ = simulate_flight(site, CameraModel.from_options(o.camera), o.flight, 0)
    g = o.gnss
    t0, t1 = traj.t_start - g.base_lead_s, traj.t_end + g.base_trail_s
    nav = read_rinex_nav(SHIPPED_NAV)
    check_navigation_coverage(nav, site.base_station_ecef(), t0, t1, "GREJC")
    cov = navigation_coverage(nav, site.base_station_ecef(), t0, t1, "GREJC")
    assert cov["G"]["min_visible"] >= 6 and cov["R"]["min_visible"] >= 5 and cov["E"]["min_visible"] >= 4
    paris = build_site(SiteOptions(lat_deg=48.85, lon_deg=2.35), 0)
    with pytest.raises(ValueError, match="does not cover"):
        check_navigation_coverage(nav, paris.base_station_ecef(), t0, t1, "GR")
    # the span: 08:00 (GPS records) to 09:15 GPST (GLONASS records)
    from georef_core.gnss.gnss_time import calendar_to_gps_time_s

    check_navigation_coverage(nav, site.base_station_ecef(), calendar_to_gps_time_s(2024, 6, 24, 8, 0, 30),
                              calendar_to_gps_time_s(2024, 6, 24, 9, 14, 30), "GREJC")
    for h, m in ((7, 58), (9, 17)):
        with pytest.raises(ValueError):
            t = calendar_to_gps_time_s(2024, 6, 24, h, m, 0)
            check_navigation_coverage(nav, site.base_station_ecef(), t, t + 60.0, "GREJC")


# ------------------------------------------------------------------------------------------------------------
# folder and files
# ------------------------------------------------------------------------------------------------------------

def test_survey_folder_layout(sim_l1l2):
    out = sim_l1l2.out_dir
    assert sorted(p.name for p in (out / "rover").iterdir()) == ["rover.obs"]
    assert sorted(p.name for p in (out / "base").iterdir()) == ["base.obs"]
    assert sorted(p.name for p in (out / "nav").iterdir()) == ["base.nav"]
    assert (out / "nav" / "base.nav").read_bytes() == SHIPPED_NAV.read_bytes()
    assert (out / "gcp" / "points.csv").is_file() and (out / "events.csv").is_file()
    assert not (out / "images").exists()      # --no-images
    for name in ("gnss_truth.npz", "gnss_truth.json", "trajectory.csv", "camera_poses.json"):
        assert (out / "truth" / name).is_file()
    s = json.loads((out / "truth" / "gnss_truth.json").read_text())
    assert s["files"] == {"rover": ["rover/rover.obs"], "base": ["base/base.obs"], "nav": ["nav/base.nav"]}
    assert s["receiver"] == {"rover": "l1l2", "base": "l1l2"} and s["rover"]["rate_hz"] == 5.0
    assert set(s["rover"]["satellites_per_system"]) == set("GREJC")
    assert "georef gnss solve rover/rover.obs base/base.obs nav/base.nav" in s["solve_command"]
    t = np.load(out / "truth" / "gnss_truth.npz")
    raw = read_rinex_obs(out / "rover" / "rover.obs")
    n_e, n_s = len(raw.gps_time_s), len(raw.sat_ids)
    np.testing.assert_allclose(t["rover_receiver_time_s"], raw.gps_time_s, atol=1e-6)
    assert t["rover_position_ecef_m"].shape == (n_e, 3) and t["sd_ambiguity_cyc"].shape == (n_e, n_s, 3)
    sd = t["sd_ambiguity_cyc"]
    assert np.isfinite(sd).mean() > 0.3 and np.all(sd[np.isfinite(sd)] == np.round(sd[np.isfinite(sd)]))
    tr = sim_l1l2.trajectory
    np.testing.assert_allclose(t["rover_position_ecef_m"],
                               tr.position_ecef(np.clip(t["rover_true_time_s"], tr.t_start, tr.t_end)), atol=1e-6)
    np.testing.assert_allclose(t["base_position_ecef_m"], sim_l1l2.site.base_station_ecef(), atol=1e-6)
    np.testing.assert_allclose(t["takeoff_antenna_ecef_m"], tr.position_ecef(tr.t_start), atol=1e-6)
    # the rover logs over the whole flight, static periods included; the base around it
    assert raw.gps_time_s[0] - tr.t_start < 0.25 and tr.t_end - raw.gps_time_s[-1] < 0.25
    assert np.median(np.diff(raw.gps_time_s)) == pytest.approx(0.2)
    base = read_rinex_obs(out / "base" / "base.obs")
    assert base.gps_time_s[0] < tr.t_start - 50 and base.gps_time_s[-1] > tr.t_end + 50
    assert np.median(np.diff(base.gps_time_s)) == pytest.approx(1.0)
    np.testing.assert_allclose(base.header.approx_position_ecef_m, sim_l1l2.site.base_station_ecef(), atol=1e-3)


def _georinex_load(path, use=None):
    gr = pytest.importorskip("georinex")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return gr.load(path, use=use)


def _gps_seconds(ds) -> np.ndarray:
    return (ds.time.values.astype("datetime64[ns]") - np.datetime64("1980-01-06T00:00:00", "ns")).astype(np.int64) / 1e9


@pytest.mark.parametrize("folder,system", [("rover", "G"), ("base", "E")])
def test_rover_and_base_load_in_our_reader_and_georinex(sim_l1l2, folder, system):
    """Our reader and georinex read the same epochs and values (georinex's RINEX 3 parser is slow: one system)."""
    path = sim_l1l2.out_dir / folder / f"{folder}.obs"
    raw = read_rinex_obs(path)
    assert {s[0] for s in raw.sat_ids} == set("GREJC")
    ds = _georinex_load(path, use=system)
    np.testing.assert_allclose(_gps_seconds(ds), raw.gps_time_s, rtol=0, atol=1e-3)
    assert sorted(str(s) for s in ds.sv.values) == [s for s in raw.sat_ids if s[0] == system]
    n = 0
    for code in ds.data_vars:
        g = ds[code].values.astype(float)
        for i, sv in enumerate(str(s) for s in ds.sv.values):
            ours = raw.values[:, raw.sat_ids.index(sv), raw.obs_codes.index(code)]
            np.testing.assert_array_equal(np.isfinite(g[:, i]), np.isfinite(ours), err_msg=f"{sv} {code}")
            ok = np.isfinite(ours)
            np.testing.assert_allclose(g[ok, i], ours[ok], rtol=0, atol=5e-4, err_msg=f"{sv} {code}")
            n += int(ok.sum())
    assert n > 5000


def test_event_records_are_the_trigger_times(sim_l1l2):
    raw = read_rinex_obs(sim_l1l2.gnss.rover_path)
    trig = np.array([e.trigger_gps_time_s for e in sim_l1l2.events])
    assert len(trig) == 12
    np.testing.assert_allclose(raw.event_gps_time_s, trig, rtol=0, atol=3e-7)   # F11.7 + float64 at 1.4e9 s
    with open(sim_l1l2.out_dir / "events.csv") as fh:
        csv_t = np.array([float(r["trigger_gps_time_s"]) for r in csv.DictReader(fh)])
    np.testing.assert_allclose(raw.event_gps_time_s, csv_t, rtol=0, atol=3e-7)
    t = np.load(sim_l1l2.gnss.truth_npz)
    np.testing.assert_allclose(t["event_position_ecef_m"], sim_l1l2.trajectory.position_ecef(trig), atol=1e-6)


def test_l1_receiver_signals_slips_and_clock(sim_l1):
    raw = read_rinex_obs(sim_l1.gnss.rover_path)
    assert {s[0] for s in raw.sat_ids} == {"G", "R"}
    assert sorted(raw.obs_codes) == ["C1C", "D1C", "L1C", "S1C"]
    s = sim_l1.gnss.summary
    assert len(s["slips"]) == 2
    k = raw.obs_codes.index("L1C")
    for sl in s["slips"]:
        i = raw.sat_ids.index(sl["sat"])
        assert sl["flagged"] and raw.lli[sl["epoch"], i, k] & 1
    t = np.load(sim_l1.gnss.truth_npz)
    assert t["slips"].shape == (2, 5) and list(t["slip_sats"]) == [sl["sat"] for sl in s["slips"]]
    assert np.all(np.abs(t["rover_clock_bias_s"]) <= 0.5e-3 + 1e-9)   # u-blox style 1 ms clock jumps


# ------------------------------------------------------------------------------------------------------------
# PPK on the simulated survey
# ------------------------------------------------------------------------------------------------------------

def test_ppk_l1l2_fixed_within_2cm_of_the_truth(ppk_l1l2):
    st, err = ppk_l1l2["status"], ppk_l1l2["err"]
    assert np.mean(st == 1) > 0.95
    assert err.max() < 0.02, f"max 3D error {err.max():.4f} m"
    assert np.sqrt(np.mean(err**2)) < 0.01


def test_ppk_l1_fixed_within_3cm_of_the_truth(ppk_l1):
    st, err = ppk_l1["status"], ppk_l1["err"]
    assert np.mean(st == 1) > 0.9
    assert err.max() < 0.03, f"max 3D error {err.max():.4f} m"
    assert np.sqrt(np.mean(err**2)) < 0.015


@pytest.mark.parametrize("which", ["ppk_l1l2", "ppk_l1"])
def test_antenna_positions_at_camera_events_within_2cm(which, request):
    ppk = request.getfixturevalue(which)
    np.testing.assert_allclose(ppk["event_t"], ppk["trig"], rtol=0, atol=1e-6)
    assert np.all(ppk["event_status"] == 1)
    assert ppk["event_err"].max() < 0.02, f"max 3D error at events {ppk['event_err'].max():.4f} m"


# ------------------------------------------------------------------------------------------------------------
# determinism and the command
# ------------------------------------------------------------------------------------------------------------

def _gnss_bytes(out: Path) -> dict:
    return {str(p.relative_to(out)): p.read_bytes()
            for p in sorted(out.rglob("*")) if p.is_file() and p.parent.name in ("rover", "base", "nav")
            or p.name.startswith("gnss_truth")}


def test_same_seed_same_bytes(sim_l1l2, tmp_path_factory):
    again = _simulate(tmp_path_factory, "gnss_again", receiver="l1l2")
    a, b = _gnss_bytes(sim_l1l2.out_dir), _gnss_bytes(again.out_dir)
    assert sorted(a) == sorted(b) and len(a) == 5
    for k in a:
        assert a[k] == b[k], k
    o = SimulationOptions.small()
    o.write_images = False
    other = simulate_site(tmp_path_factory.mktemp("gnss_other"), seed=SEED + 1, options=o, verbose=False)
    assert (other.out_dir / "rover" / "rover.obs").read_bytes() != a["rover/rover.obs"]


def test_georef_simulate_command_options(tmp_path):
    out = tmp_path / "survey"
    rc, text = _run_georef("simulate", out, "--seed", "3", "--small", "--no-images", "--receiver", "l1",
                           "--rover-rate", "10", "--base-gaps", "--rinex-version", "2",
                           "--lever-arm", "0.01,-0.02,0.03", "--delay", "0.05", "--code-noise", "0.8",
                           "--phase-noise", "0.004", "--quiet")
    assert rc == 0, text
    assert "simulated 12 camera events" in text and " s (" in text
    assert sorted(p.name for p in (out / "rover").iterdir()) == ["rover.24o"]
    assert sorted(p.name for p in (out / "base").iterdir()) == ["base.24o"]
    s = json.loads((out / "truth" / "gnss_truth.json").read_text())
    assert s["rinex_version"] == "2.11" and s["rover"]["rate_hz"] == 10.0 and s["receiver"]["rover"] == "l1"
    assert len(s["base"]["gaps_receiver_time_s"]) == 3 and s["base"]["dropped_epochs"] > 3
    n = s["rover"]["noise"]
    assert n["code_sigma_a_m"] + n["code_sigma_b_m"] == pytest.approx(0.8)
    assert n["phase_sigma_a_m"] + n["phase_sigma_b_m"] == pytest.approx(0.004)
    lev = json.loads((out / "truth" / "lever_arm_delay.json").read_text())
    assert lev["lever_arm_cam_m"] == [0.01, -0.02, 0.03] and lev["delay_s"] == 0.05
    rover = read_rinex_obs(out / "rover" / "rover.24o")
    assert np.median(np.diff(rover.gps_time_s)) == pytest.approx(0.1)
    with open(out / "events.csv") as fh:
        trig = np.array([float(r["trigger_gps_time_s"]) for r in csv.DictReader(fh)])
    np.testing.assert_allclose(rover.event_gps_time_s, trig, rtol=0, atol=3e-7)
    base = read_rinex_obs(out / "base" / "base.24o")
    gaps = np.diff(base.gps_time_s)
    assert np.sum(gaps > 1.5) == 3
    ds = _georinex_load(out / "base" / "base.24o")
    np.testing.assert_allclose(_gps_seconds(ds), base.gps_time_s, rtol=0, atol=1e-3)


def test_images_option_scales_the_work_area(tmp_path):
    from georef_core.cli.simulate_command import planned_image_count, scale_for_image_count

    o = SimulationOptions()
    assert planned_image_count(o, o.site.size_m) == 96
    for n in (40, 100, 250):
        o2, planned = scale_for_image_count(o, n)
        assert abs(planned - n) <= 0.1 * n
        assert o2.site.size_m[0] / o2.site.size_m[1] == pytest.approx(1.6, rel=0.01)
        assert planned_image_count(o2, o2.site.size_m) == planned
    # a small count: the work area shrinks and what does not fit on it is left out
    rc, text = _run_georef("simulate", tmp_path / "s", "--images", "20", "--no-images", "--no-gnss", "--quiet")
    assert rc == 0, text
    assert "work area 51.4 x 32.1 m, 21 images planned" in text and "left out" in text and "the pit" in text
    assert "simulated 21 camera events" in text


def test_python_m_georef_core_sim_is_the_same_command(capsys):
    from georef_core.sim.__main__ import main

    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    help_text = capsys.readouterr().out
    for opt in ("--receiver", "--rover-rate", "--images", "--base-gaps", "--rinex-version", "--lever-arm"):
        assert opt in help_text


def test_rendered_survey_has_the_upload_layout(small_sim):
    """The session's small rendered survey (tests/sim/conftest.py): images next to the GNSS files."""
    out = small_sim.out_dir
    assert len(list((out / "images").glob("IMG_*.JPG"))) == small_sim.n_images == 12
    assert (out / "rover" / "rover.obs").is_file() and (out / "base" / "base.obs").is_file()
    assert (out / "nav" / "base.nav").is_file() and (out / "gcp" / "points.csv").is_file()
    assert not list((out / "rover").glob("README*"))
    assert "georef gnss solve" in (out / "README.md").read_text()
