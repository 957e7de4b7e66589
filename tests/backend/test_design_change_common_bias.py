"""The vertical bias common to two surveys of a design (backend/services/design_changes: base_of, shared_base,
common_bias) when they share no control-point files but were both processed by PPK against the same base position:
that position's error is in every PPK position of both, so its vertical sigma is the common part. Unit level: the
gnss and georef steps' summaries as the steps write them (georef_core.gnss.ppk.base_position_basis; the georef
step's absolute_accuracy basis); the platform path (pair_inputs reading the steps' summaries) is in
test_design_change_jobs."""

from __future__ import annotations

import math

import pytest

from backend.services import design_changes as dc
from georef_core.gnss.ppk import SPP_COMMON_SIGMA_ENU_M, base_position_basis

BASE_ECEF_M = [-2694892.461, -4297416.218, 3854435.497]


def gnss_summary(position=BASE_ECEF_M, source="averaged-single-point", sigma_enu_m=(1.02, 1.03, 2.05)) -> dict:
    return {"epochs": 1200, "base_position_ecef_m": [round(v, 4) for v in position],
            "base_position": base_position_basis(source, sigma_enu_m, f"base position from {source}")}


def georef_summary(base_sigma=(1.02, 1.03, 2.05), control_points: int = 0) -> dict:
    basis = []
    if control_points:
        basis.append({"kind": "control points", "n": control_points, "sigma_m": [0.02, 0.02]})
    basis.append({"kind": "PPK camera positions", "source": "ppk", "n": 80,
                  "median_sigma_m": {"horizontal": 0.012, "vertical": 0.02}})
    basis.append({"kind": "base position", "source": "averaged-single-point", "sigma_enu_m": base_sigma})
    return {"absolute_accuracy": {"basis": basis, "text": "..."}}


def test_an_averaged_single_point_base_shared_by_two_ppk_surveys_gives_its_vertical_sigma():
    a = dc.base_of(gnss_summary(), georef_summary())
    b = dc.base_of(gnss_summary([v + 0.0004 for v in BASE_ECEF_M]), georef_summary())   # 0.7 mm away
    shared = dc.shared_base(a, b)
    assert shared is not None and shared["sigma_v_m"] == pytest.approx(2.05)
    sigma, source = dc.common_bias(None, None, None, shared)
    assert sigma == pytest.approx(2.05)
    assert "same base position (averaged-single-point" in source and "2.050 m" in source
    # the figure the step states for such a base: sigma of the mean and the broadcast models' common error
    s = math.hypot(0.3, SPP_COMMON_SIGMA_ENU_M[2])
    shared = dc.shared_base(dc.base_of(gnss_summary(sigma_enu_m=(1.0, 1.0, s)), georef_summary()),
                            dc.base_of(gnss_summary(sigma_enu_m=(1.0, 1.0, s)), georef_summary()))
    assert dc.common_bias(None, None, None, shared)[0] == pytest.approx(round(s, 3))


def test_a_given_surveyed_base_counts_the_surveyed_point_accuracy():
    a = dc.base_of(gnss_summary(source="given", sigma_enu_m=None), georef_summary(base_sigma=None))
    b = dc.base_of(gnss_summary(source="given", sigma_enu_m=None), georef_summary(base_sigma=None))
    assert a["sigma_v_m"] is None
    sigma, source = dc.common_bias(None, None, None, dc.shared_base(a, b))
    assert sigma == dc.SURVEYED_BASE_SIGMA_V_M == dc.CONTROL_POINT_SIGMA_V_M
    assert "taken as surveyed" in source and "given" in source


def test_no_common_part_unless_the_same_position_from_the_same_source_and_no_control():
    a = dc.base_of(gnss_summary(), georef_summary())
    # 2 mm apart (another day's averaged base at the same mark): independent
    assert dc.shared_base(a, dc.base_of(gnss_summary([v + 0.0012 for v in BASE_ECEF_M]), georef_summary())) is None
    # the same coordinates from another source (header vs given)
    assert dc.shared_base(dc.base_of(gnss_summary(source="rinex-header", sigma_enu_m=None), georef_summary(None)),
                          dc.base_of(gnss_summary(source="given", sigma_enu_m=None), georef_summary(None))) is None
    # a survey tied to control points: its vertical offset is the control's, not the base's
    assert dc.base_of(gnss_summary(), georef_summary(control_points=4)) is None
    # photos alone (gnss skipped) or a run without the summaries
    assert dc.base_of({"skipped": True, "reason": "no raw GNSS log"}, georef_summary()) is None
    assert dc.base_of(gnss_summary(), None) is None and dc.base_of(None, georef_summary()) is None
    assert dc.base_of(gnss_summary(), {"absolute_accuracy": {"basis": []}}) is None
    assert dc.shared_base(a, None) is None
    sigma, source = dc.common_bias(None, None, None, None)
    assert sigma == 0.0 and "independent" in source
