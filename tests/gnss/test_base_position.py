"""Base position from the RINEX header: the marker plus ANTENNA: DELTA H/E/N."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from georef_core.gnss.frames import ecef_to_enu_rotation, ecef_to_geodetic
from georef_core.gnss.ppk import solve
from georef_core.gnss.rinex_nav import read_rinex_nav
from georef_core.gnss.rinex_obs import read_rinex_obs
from georef_core.gnss.rtk_options import RtkOptions

DATA = Path(__file__).resolve().parents[1] / "data" / "gnss" / "gsi_0759_3040"


def test_header_antenna_delta_moves_the_solution_with_the_base():
    rover = read_rinex_obs(DATA / "07590920.05o")
    nav = read_rinex_nav(DATA / "07590920.05n")
    opts = RtkOptions(mode="static", filter_direction="forward", systems=("G",))
    base = read_rinex_obs(DATA / "30400920.05o")
    ref = solve(rover, base, nav, opts)
    base.header.antenna_delta_hen_m = np.array([1.5, 0.2, -0.1])
    moved = solve(rover, base, nav, opts)
    assert any("antenna delta" in w for w in moved.warnings)
    fixed = (ref.status == 1) & (moved.status == 1)
    assert fixed.sum() > 100
    lat, lon, _ = ecef_to_geodetic(ref.position_ecef_m[fixed][-1])
    shift = (moved.position_ecef_m[fixed] - ref.position_ecef_m[fixed]) @ ecef_to_enu_rotation(lat, lon).T
    # the rover follows the base antenna by the same ENU offset; the 1.5 m higher base also sees ~0.5 mm
    # less hydrostatic delay at zenith (more at 15 degrees), which moves the solution by ~1.5 mm vertically
    assert np.allclose(shift, [0.2, -0.1, 1.5], atol=0.002)
