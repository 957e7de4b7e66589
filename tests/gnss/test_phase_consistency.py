"""phase_consistency.reference_free_change_rms: the misfit the judge of fixes (judged_comparison) uses,
checked against the double differences' quadratic form with their full covariance."""

from __future__ import annotations

import numpy as np

from georef_core.gnss.fix_continuity import dd_change_rms
from georef_core.gnss.phase_consistency import reference_free_change_rms


def _dd_residuals(sd: np.ndarray, sys_code: np.ndarray, refs: dict) -> np.ndarray:
    """DD residuals (S, 1) against the reference satellite of each system, NaN at the reference (as
    rtk_kernels.phase_residuals gives them)."""
    out = np.full((len(sd), 1), np.nan)
    for sys, ref in refs.items():
        members = sys_code == sys
        out[members, 0] = sd[members] - sd[ref]
        out[ref, 0] = np.nan
    return out


def test_equals_the_full_covariance_quadratic_form_whatever_the_reference():
    rng = np.random.default_rng(7)
    sys_code = np.array([0] * 7 + [1] * 5)
    sd0, sd1 = rng.normal(0, 0.01, 12), rng.normal(0, 0.01, 12)
    # chi^2 of the DD changes with covariance s^2 (I + 1 1^T) per system, times s^2
    chi2, dof = 0.0, 0
    for sys in (0, 1):
        x = (sd1 - sd0)[sys_code == sys]
        v = x[1:] - x[0]
        q = np.eye(len(v)) + 1.0
        chi2 += float(v @ np.linalg.solve(q, v))
        dof += len(v)
    expected = np.sqrt(chi2 / dof)
    ok = np.ones((12, 1), dtype=bool)
    for refs0, refs1 in (({0: 0, 1: 7}, {0: 0, 1: 7}), ({0: 3, 1: 9}, {0: 6, 1: 11}), ({0: 6, 1: 8}, {0: 1, 1: 7})):
        got = reference_free_change_rms(_dd_residuals(sd0, sys_code, refs0), _dd_residuals(sd1, sys_code, refs1),
                                        ok, sys_code)
        assert abs(got - expected) < 1e-12, (refs0, refs1, got, expected)


def test_one_bad_reference_does_not_spread_into_every_term():
    """Against a first-satellite reference one satellite 4 cm off its neighbours enters every double
    difference when it is the reference (the u-blox walk's epoch 771); the reference-free RMS counts it
    once, whichever satellite is first."""
    rng = np.random.default_rng(3)
    sys_code = np.zeros(8, dtype=np.int64)
    sd0 = np.zeros(8)
    sd1 = rng.normal(0, 0.003, 8)
    sd1_bad_first = sd1.copy()
    sd1_bad_first[0] += 0.04
    sd1_bad_last = sd1.copy()
    sd1_bad_last[7] += 0.04
    refs = {0: 7}   # the epoch's reference (NaN); dd_change_rms re-references to the first present, 0
    ok = np.ones((8, 1), dtype=bool)
    first = [dd_change_rms(_dd_residuals(sd0, sys_code, refs), _dd_residuals(s, sys_code, refs), sys_code, 1)
             for s in (sd1_bad_first, sd1_bad_last)]
    free = [reference_free_change_rms(_dd_residuals(sd0, sys_code, refs), _dd_residuals(s, sys_code, refs), ok,
                                      sys_code) for s in (sd1_bad_first, sd1_bad_last)]
    assert first[0] > 0.035 and first[1] < 0.02          # 4 cm in every term, or left out with the reference
    assert abs(free[0] - free[1]) < 0.004                 # the same whichever satellite is off
    assert 0.012 < free[0] < 0.02                         # one 4 cm outlier among 8: about 4 / sqrt(8) cm


def test_needs_two_signals_of_one_system_and_band():
    sys_code = np.array([0, 1, 2])
    r = np.array([[0.0], [0.01], [0.02]])
    assert np.isnan(reference_free_change_rms(r, r + 0.01, np.ones((3, 1), dtype=bool), sys_code))
    r2 = np.array([[0.0, np.nan], [0.01, np.nan], [np.nan, np.nan]])
    assert np.isnan(reference_free_change_rms(r2, r2, np.isfinite(r2), np.array([0, 1, 0])))
