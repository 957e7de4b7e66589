"""`georef gnss solve` end to end on the committed GEONET sample, and its answers to bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from georef_core.cli.main import main
from georef_core.gnss.solution_io import read_pos

DATA = Path(__file__).resolve().parents[1] / "data" / "gnss" / "gsi_0759_3040"
ROVER, BASE = DATA / "07590920.05o", DATA / "30400920.05o"
NAV = DATA / "07590920.05n"
BASE_XYZ = "-3978241.958,3382840.234,3649900.853"


def run(args, capsys):
    rc = main(args)
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_solve_writes_pos_parquet_events_and_summary(tmp_path, capsys):
    events = tmp_path / "triggers.csv"
    events.write_text("gps_time_s\n" + "\n".join(f"{t:.3f}" for t in (796867215.0, 796867500.5, 796869000.25)))
    out = tmp_path / "sol.pos"
    rc, stdout, err = run(["gnss", "solve", str(ROVER), str(BASE), str(NAV), str(DATA / "30400920.05n"), "--out", str(out),
                           "--mode", "static", "--freq", "l1+l2", "--filter", "combined", f"--base-pos={BASE_XYZ}",
                           "--events", str(events), "--crs", "32654", "--json"], capsys)
    assert rc == 0, err
    summary = json.loads(stdout)
    assert summary["epochs"] == 120 and summary["fix_rate"] > 0.95
    pos = read_pos(out)
    assert np.sum(pos.status == 1) == summary["fix"]
    table = pq.read_table(out.with_suffix(".parquet")).to_pandas()
    for col in ("gps_time_s", "x_ecef_m", "lat_deg", "cov_xx_ecef_m2", "sd_up_m", "v_east_m_s", "x_epsg32654", "ratio"):
        assert col in table.columns
    fixed = table[table.status == 1]
    # static GEONET pillar: the fixed positions agree to a few millimetres
    assert fixed.x_ecef_m.std() < 0.005 and fixed.z_ecef_m.std() < 0.005
    res = pq.read_table(tmp_path / "sol_residuals.parquet").to_pandas()
    assert len(res) > 100 and res.residual_m.abs().median() < 0.01
    ev = (tmp_path / "sol_events.csv").read_text().splitlines()
    assert len(ev) == 4 and ev[0].startswith("event,gps_time_s,status")
    assert summary["events"]["count"] == 3


def test_rtklib_conf_is_applied_and_unsupported_options_reported(tmp_path, capsys):
    conf = tmp_path / "my.conf"
    conf.write_text("pos1-posmode =static\npos1-frequency =l1\npos1-elmask =20\npos1-tidecorr =on\n"
                    "pos2-armode =continuous\nweird-key =1\n")
    rc, stdout, err = run(["gnss", "solve", str(ROVER), str(BASE), str(NAV), "--out", str(tmp_path / "s.pos"),
                           "--rtklib-conf", str(conf), "--filter", "forward"], capsys)
    assert rc == 0
    assert "pos1-tidecorr not applied" in err and "unknown option 'weird-key'" in err
    head = (tmp_path / "s.pos").read_text()
    assert "% pos mode  : static" in head and "% elev mask : 20.0 deg" in head and "% freqs     : L1\n" in head


@pytest.mark.parametrize("make_bad, expect", [
    (lambda d: NAV, "navigation file"),
    (lambda d: d / "missing.obs", "file not found"),
    (lambda d: (d / "junk.obs").write_bytes(bytes(range(256)) * 20) and d / "junk.obs", "not a RINEX observation"),
    (lambda d: (d / "bad.05o").write_text(ROVER.read_text().replace(
        ROVER.read_text().splitlines()[40][:20], "ABCDEFGHIJKLMNOPQRST", 1)) and d / "bad.05o", "line 41"),
])
def test_bad_rover_file_gives_clear_error(tmp_path, capsys, make_bad, expect):
    bad = make_bad(tmp_path)
    rc, _, err = run(["gnss", "solve", str(bad), str(BASE), str(NAV), "--out", str(tmp_path / "x.pos")], capsys)
    assert rc == 2
    assert str(bad) in err and expect in err
    assert "Traceback" not in err and not (tmp_path / "x.pos").exists()


def test_truncated_rover_keeps_complete_epochs_and_warns(tmp_path, capsys):
    cut = tmp_path / "cut.05o"
    cut.write_bytes(ROVER.read_bytes()[:30000])
    rc, stdout, err = run(["gnss", "solve", str(cut), str(BASE), str(NAV), "--out", str(tmp_path / "c.pos")], capsys)
    assert rc == 0
    assert "truncated" in err and str(cut) in err
    assert 40 < len(read_pos(tmp_path / "c.pos").time_s) < 120


def test_inconsistent_inputs_are_refused(tmp_path, capsys):
    out = str(tmp_path / "x.pos")
    rc, _, err = run(["gnss", "solve", str(ROVER), str(BASE), str(NAV), "--out", out, "--base-pos", "45,10,100"], capsys)
    assert rc == 2 and "km from the rover" in err
    rc, _, err = run(["gnss", "solve", str(ROVER), str(BASE), str(NAV), "--out", out, "--navsys", "R"], capsys)
    assert rc == 2 and "share no satellite" in err
    rc, _, err = run(["gnss", "solve", str(ROVER), str(BASE), str(NAV), "--out", out, "--navsys", "G,X"], capsys)
    assert rc == 2 and "unknown system" in err
    other_day = tmp_path / "other.05o"
    text = BASE.read_text().replace(" 05  4  2", " 05  4  9")
    other_day.write_text(text)
    rc, _, err = run(["gnss", "solve", str(ROVER), str(other_day), str(NAV), "--out", out], capsys)
    assert rc == 2 and "do not overlap in time" in err


def test_navigation_for_another_day_is_refused(tmp_path, capsys):
    nav = tmp_path / "old.05n"
    shutil.copy(NAV, nav)
    text = nav.read_text().replace(" 05  4  2", " 05  3  2")
    nav.write_text(text)
    rc, _, err = run(["gnss", "solve", str(ROVER), str(BASE), str(nav), "--out", str(tmp_path / "x.pos")], capsys)
    assert rc == 2 and "navigation data" in err and str(ROVER) in err


def test_known_start_requires_position(tmp_path, capsys):
    rc, _, err = run(["gnss", "solve", str(ROVER), str(BASE), str(NAV), "--out", str(tmp_path / "x.pos"),
                      "--mode", "known-start"], capsys)
    assert rc == 2 and "known-start" in err


@pytest.mark.parametrize("flag,field,values,bad,message", [
    ("--tdcp-slips", "slip_tdcp_threshold_m", ("0", "0.08"), "-1", "slip threshold"),   # 0 turns the check off
    ("--hold-variance", "hold_variance_cyc2", ("0.001",), "0", "hold variance"),        # 0: a hold never met
    ("--fix-max-sigma", "fix_max_sigma_m", ("0", "0.1"), "-0.1", "fix precision limit"),  # 0 turns it off
])
def test_engine_option_flags(tmp_path, capsys, monkeypatch, flag, field, values, bad, message):
    """The flag reaches the engine's options (seen by a spy on the CLI's option builder, the solve then
    running with them); an out-of-range value is refused with a message that names it."""
    from georef_core.cli import gnss_commands

    seen = []
    real = gnss_commands.options_from_args

    def spy(args):
        opts, notes = real(args)
        seen.append(getattr(opts, field))
        return opts, notes

    monkeypatch.setattr(gnss_commands, "options_from_args", spy)
    for value in values:
        rc, _, err = run(["gnss", "solve", str(ROVER), str(BASE), str(NAV), "--out", str(tmp_path / f"t{value}.pos"),
                          "--freq", "l1", "--filter", "forward", f"--base-pos={BASE_XYZ}", flag, value], capsys)
        assert rc == 0, err
    assert seen == [float(v) for v in values]
    rc, _, err = run(["gnss", "solve", str(ROVER), str(BASE), str(NAV), "--out", str(tmp_path / "bad.pos"),
                      flag, bad], capsys)
    assert rc == 2 and message in err


def test_navigation_far_from_the_observations_names_both_spans(tmp_path, capsys):
    """Every record months away from the observations: none is read, and the error names the rover,
    the observation span and the records' span."""
    nav = tmp_path / "january.05n"
    shutil.copy(NAV, nav)
    nav.write_text(nav.read_text().replace(" 05  4  ", " 05  1  "))
    rc, _, err = run(["gnss", "solve", str(ROVER), str(BASE), str(nav), "--out", str(tmp_path / "x.pos")], capsys)
    assert rc == 2 and "no navigation data for the epochs of" in err and str(ROVER) in err
    assert "2005-04-02" in err and "2005-01-0" in err and str(nav) in err
