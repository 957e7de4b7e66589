"""The ASPRS Edition 2 (2023) assessment (georef_core.adjustment.accuracy_standard) against hand computations:
the check points' survey error added in quadrature, the class met, the 30-point minimum, the survey accuracy
at least two times the class, only check points counted."""

from __future__ import annotations

import math

import numpy as np
import pytest

from georef_core.adjustment.accuracy_standard import assess_accuracy
from georef_core.adjustment.residual_table import ResidualRow, ResidualTable


def _alternating(n: int, a_m: tuple[float, float, float]) -> np.ndarray:
    """n residuals of +-a per axis (signs alternating): the RMSE of each axis is exactly a."""
    s = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)[:, None]
    return s * np.asarray(a_m)[None, :]


def test_thirty_check_points_hand_computation():
    # by hand: RMSE_x 1.2 cm, RMSE_y 0.9 cm -> RMSE_H(measured) = 1.5 cm; survey 0.5 cm per axis ->
    # RMSE_H(survey) = sqrt(0.25 + 0.25) = 0.7071 cm; product sqrt(2.25 + 0.5) = 1.6583 cm -> the 2 cm class
    # (survey 0.71 <= 2 / 2). Vertical: 3.0 cm measured, survey 1.5 cm -> sqrt(9 + 2.25) = 3.3541 cm -> 4 cm class.
    a = assess_accuracy(_alternating(30, (0.012, 0.009, 0.030)), check_sigma_m=(0.005, 0.015))
    assert a.n_check_points == 30 and a.compliant
    assert a.rmse_x_cm == pytest.approx(1.2, abs=1e-9) and a.rmse_y_cm == pytest.approx(0.9, abs=1e-9)
    h, v = a.horizontal, a.vertical
    assert h.measured_rmse_cm == pytest.approx(1.5, abs=1e-9)
    assert h.survey_rmse_cm == pytest.approx(math.sqrt(0.5), abs=1e-9)
    assert h.product_rmse_cm == pytest.approx(math.sqrt(2.75), abs=1e-9) and h.class_cm == 2.0
    assert v.product_rmse_cm == pytest.approx(math.sqrt(11.25), abs=1e-9) and v.class_cm == 4.0
    assert h.statement == ("This data set was tested to meet ASPRS Positional Accuracy Standards for Digital "
                           "Geospatial Data, Edition 2 (2023) for a 2 (cm) RMSE_H Horizontal Positional Accuracy "
                           "Class. The tested horizontal positional accuracy was found to be RMSE_H = 1.7 (cm).")
    assert v.statement == ("This data set was tested to meet ASPRS Positional Accuracy Standards for Digital "
                           "Geospatial Data, Edition 2 (2023) for a 4 (cm) RMSE_V Vertical Accuracy Class. NVA "
                           "accuracy was found to be RMSE_V = 3.4 (cm).")
    assert not a.notes


def test_the_survey_error_is_counted_and_can_refuse_a_class():
    # residuals alone 1.5 cm H would meet 1.5 cm; a 1.2 cm per-axis survey (RMSE_H 1.70 cm) makes the product
    # sqrt(2.25 + 2.88) = 2.265 cm, and the class must also be >= 2 x 1.70 = 3.39 cm: the 4 cm class
    a = assess_accuracy(_alternating(40, (0.012, 0.009, 0.010)), check_sigma_m=(0.012, 0.005))
    h = a.horizontal
    assert h.product_rmse_cm == pytest.approx(math.sqrt(2.25 + 2 * 1.44), abs=1e-9)
    assert h.class_cm == 4.0 and h.survey_limits_class
    assert any("two times more accurate" in n for n in a.notes)
    # a target class is tested as given: 3 cm is met by the residuals but refused by the survey
    t = assess_accuracy(_alternating(40, (0.012, 0.009, 0.010)), check_sigma_m=(0.012, 0.005),
                        target_class_cm=(3.0, 5.0))
    assert t.horizontal.class_cm is None and t.horizontal.meets_target is False and not t.compliant
    assert "does not meet the 3 (cm) RMSE_H" in t.horizontal.statement
    assert t.vertical.meets_target and t.vertical.class_cm == 5.0


def test_fewer_than_thirty_check_points_make_no_compliance_claim():
    # 5 points of a ResidualTable (two control rows ignored): dx 1, -1, 2, -2, 0 cm -> RMSE_x = sqrt(10/5) = 1.414 cm
    rows = [ResidualRow(f"C{i}", "check", dx, 0.0, dz, 0.0, 4) for i, (dx, dz) in
            enumerate([(0.01, 0.02), (-0.01, -0.02), (0.02, 0.02), (-0.02, -0.02), (0.0, 0.02)])]
    rows += [ResidualRow("G1", "control (left out)", 0.5, 0.5, 0.5, 0.9, 4), ResidualRow("G2", "control", 1, 1, 1, 1.7, 4)]
    table = ResidualTable("check points", "EPSG:32631", rows)
    a = assess_accuracy(table, check_sigma_m=(0.0, 0.0))
    assert a.n_check_points == 5 and not a.compliant
    assert a.horizontal.product_rmse_cm == pytest.approx(math.sqrt(2.0), abs=1e-9)
    assert a.vertical.product_rmse_cm == pytest.approx(2.0, abs=1e-9)
    s = a.horizontal.statement
    assert "using 5 check points, fewer than the minimum of thirty (30) the standard calls for" in s
    assert "RMSE_H = 1.4 (cm)" in s and "tested to meet" not in s
    assert s.endswith("within the 1.5 (cm) RMSE_H Horizontal Positional Accuracy Class; no statement of compliance is "
                      "made.")
    # the same from the table's JSON (residuals.json) and per-point survey sigmas
    b = assess_accuracy(table.to_dict(), check_sigma_m=[(0.003, 0.004)] * 5)
    assert b.horizontal.survey_rmse_cm == pytest.approx(100 * math.sqrt(2) * 0.003, abs=1e-9)
    assert b.vertical.product_rmse_cm == pytest.approx(math.hypot(2.0, 0.4), abs=1e-9)


def test_no_check_point_and_bad_sigmas():
    a = assess_accuracy(np.zeros((0, 3)))
    assert a.n_check_points == 0 and not a.compliant and a.horizontal.product_rmse_cm is None
    assert "not tested" in a.horizontal.statement
    with pytest.raises(ValueError):
        assess_accuracy(np.zeros((3, 3)), check_sigma_m=[(0.01, 0.02)] * 2)
