"""Fixed epochs whose fixed position the geometry leaves decimetre-level are output as float
(georef_core/gnss/fix_precision.py), on real data: the GEONET 3.3 km static sample processed kinematic L1
forward, whose last epochs keep five satellites (positions 10-14 cm from the truth with the right integers)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from georef_core.gnss.fix_precision import refuse_imprecise_fixes, sigma_3d_m
from georef_core.gnss.ppk import solve_files
from georef_core.gnss.rtk_filter import STATUS_FIX, STATUS_FLOAT, FilterOutput
from georef_core.gnss.rtk_options import RtkOptions

DATA = Path(__file__).resolve().parents[1] / "data" / "gnss" / "gsi_0759_3040"
ROVER, BASE, NAV = DATA / "07590920.05o", DATA / "30400920.05o", DATA / "07590920.05n"


def _output(status, sigma_axis_m):
    n = len(status)
    cov = np.stack([np.eye(3) * s**2 for s in sigma_axis_m])
    return FilterOutput(status=np.asarray(status), position_ecef_m=np.zeros((n, 3)), covariance_ecef_m2=cov,
                        n_sats=np.full(n, 6), ratio=np.full(n, 5.0), residuals_m=np.zeros((n, 1, 1)),
                        n_fixed_amb=np.zeros(n, int))


def test_rule_flags_only_imprecise_fixes():
    # per-axis sigmas 1, 2.8, 3 cm -> 3-D 1.7, 4.85, 5.2 cm; the float epoch stays as it is
    out = _output([STATUS_FIX, STATUS_FIX, STATUS_FIX, STATUS_FLOAT], [0.01, 0.028, 0.03, 0.5])
    new, n = refuse_imprecise_fixes(out, 0.05)
    assert n == 1
    assert new.status.tolist() == [STATUS_FIX, STATUS_FIX, STATUS_FLOAT, STATUS_FLOAT]
    assert out.status[2] == STATUS_FIX                 # the input is not changed in place
    np.testing.assert_array_equal(new.covariance_ecef_m2, out.covariance_ecef_m2)
    assert refuse_imprecise_fixes(out, 0.0)[1] == 0    # 0 turns it off


def test_geonet_weak_geometry_fixes_are_not_output_as_fixed():
    opts = RtkOptions(n_bands=1, filter_direction="forward", ar_mode="continuous")
    on = solve_files(ROVER, BASE, [NAV], opts)
    off = solve_files(ROVER, BASE, [NAV], opts.replace(fix_max_sigma_m=0.0))
    # the rover is static: the median of the precise fixes is its position to a few mm
    sig_on = sigma_3d_m(on.covariance_ecef_m2)
    precise = (on.status == STATUS_FIX)
    truth = np.median(on.position_ecef_m[precise], axis=0)
    err_on = np.linalg.norm(on.position_ecef_m - truth, axis=1)
    err_off = np.linalg.norm(off.position_ecef_m - truth, axis=1)
    # without the rule: fixed epochs more than 5 cm from the truth, every one with a 3-D sigma over 5 cm
    wrong_off = (off.status == STATUS_FIX) & (err_off > 0.05)
    assert wrong_off.sum() >= 1
    assert np.all(sigma_3d_m(off.covariance_ecef_m2)[wrong_off] > 0.05)
    # with it: no fixed epoch beyond 5 cm, none with a sigma over 5 cm, and the changed epochs are exactly
    # those fixes, their positions kept
    assert not np.any((on.status == STATUS_FIX) & (err_on > 0.05))
    assert np.all(sig_on[on.status == STATUS_FIX] <= 0.05)
    changed = on.status != off.status
    assert np.array_equal(changed, (off.status == STATUS_FIX) & (sigma_3d_m(off.covariance_ecef_m2) > 0.05))
    assert np.all(on.status[changed] == STATUS_FLOAT)
    np.testing.assert_allclose(on.position_ecef_m, off.position_ecef_m)
    assert any("output as float" in w for w in on.warnings)
    assert not any("output as float" in w for w in off.warnings)
