"""Antenna position at camera events: Hermite interpolation between solution epochs."""

from __future__ import annotations

import numpy as np
import pytest

from georef_core.gnss.camera_events import interpolate_at_events, read_event_csv
from georef_core.gnss.ppk import PpkSolution
from georef_core.gnss.rtk_options import RtkOptions


def _circle_solution(rate_hz=5.0, speed=6.0, radius=40.0, sigma=0.01, n=200):
    t = 1.3e9 + np.arange(n) / rate_hz
    w = speed / radius
    centre = np.array([4.0e6, 3.0e5, 4.9e6])
    pos = centre + radius * np.stack([np.cos(w * t), np.sin(w * t), 0.02 * t - 0.02 * t[0]], axis=1)
    vel = radius * np.stack([-w * np.sin(w * t), w * np.cos(w * t), np.full(n, 0.02)], axis=1)
    cov = np.tile(np.eye(3) * sigma**2, (n, 1, 1))
    vcov = np.tile(np.eye(3) * 0.005**2, (n, 1, 1))
    sol = PpkSolution(t, t, np.ones(n, np.int8), pos, cov, vel, vcov, np.full(n, 12), np.full(n, 10.0), np.zeros(n),
                      np.full((n, 1, 1), np.nan), ["G01"], centre, RtkOptions())
    return sol, centre, radius, w


def test_hermite_interpolation_on_a_turn():
    sol, centre, radius, w = _circle_solution()
    ev = sol.time_s[10] + np.random.default_rng(3).uniform(0, 30, 50)
    res = interpolate_at_events(sol, ev)
    truth = centre + radius * np.stack([np.cos(w * ev), np.sin(w * ev), 0.02 * ev - 0.02 * sol.time_s[0]], axis=1)
    err = np.linalg.norm(res.position_ecef_m - truth, axis=1)
    assert np.all(res.status == 1)
    assert err.max() < 0.001  # 6 m/s on a 40 m radius, 5 Hz: Hermite error well under a millimetre
    vtruth = radius * w * np.stack([-np.sin(w * ev), np.cos(w * ev)], axis=1)
    assert np.abs(res.velocity_ecef_m_s[:, :2] - vtruth).max() < 0.01
    sd = np.sqrt(res.covariance_ecef_m2[:, 0, 0])
    assert np.all(sd >= 0.0099)  # never below the epochs' own uncertainty


def test_gaps_and_outside_span_have_no_solution():
    sol, *_ = _circle_solution()
    sol.status[50:60] = 0
    ev = np.array([sol.time_s[0] - 1.0, sol.time_s[55], sol.time_s[-1] + 1.0, sol.time_s[20] + 0.1])
    res = interpolate_at_events(sol, ev)
    assert list(res.status) == [0, 0, 0, 1]
    assert np.isnan(res.position_ecef_m[0]).all()


def test_event_csv(tmp_path):
    p = tmp_path / "ev.csv"
    p.write_text("# camera triggers\nimage,gps_time_s\nIMG_1.JPG,1300000000.25\nIMG_2.JPG,1300000001.5\n")
    assert np.allclose(read_event_csv(p), [1300000000.25, 1300000001.5])
    p.write_text("gps_time_s\n12.5\nnot-a-time\n")
    try:
        read_event_csv(p)
    except Exception as exc:
        assert "ev.csv" in str(exc) and "line 3" in str(exc)
    else:
        raise AssertionError("bad event time accepted")


def test_event_times_must_be_finite_and_mrk_is_read(tmp_path):
    """nan/inf trigger times are refused naming the file and line; a DJI MRK gives its exposure times."""
    from georef_core.errors import InputFileError
    from georef_core.gnss.camera_events import read_event_csv

    p = tmp_path / "events.csv"
    p.write_text("image,gps_time_s\na.jpg,1400000000.5\nb.jpg,nan\n")
    with pytest.raises(InputFileError, match=r"events.csv, line 3: event time 'nan' is not a finite number"):
        read_event_csv(p)
    p.write_text("gps_time_s\ninf\n")
    with pytest.raises(InputFileError, match="line 2"):
        read_event_csv(p)
    mrk = tmp_path / "x.MRK"
    mrk.write_text("1\t275295.301059\t[2024]\t   -26,N\t    19,E\t   191,V\t-36.41144502,Lat\t174.63075195,Lon\t"
                   "170.415,Ellh\t1.492559, 1.368525, 3.180128\t16,Q\n")
    assert read_event_csv(mrk).tolist() == [2024 * 604800 + 275295.301059]
