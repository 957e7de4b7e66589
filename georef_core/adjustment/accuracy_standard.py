"""The formal accuracy statement of a survey after the ASPRS Positional Accuracy Standards for Digital
Geospatial Data, Edition 2 (2023), computed from the check-point residual table (residual_table) and the
check points' own survey accuracy. Pure: numbers in, numbers and sentences out (docs/deliverables.md,
"The survey report", says what is implemented and what is not).

What Edition 2 asks and what is done here:

* accuracy is an RMSE (the 95 % figures of Edition 1 are gone): horizontal RMSE_H = sqrt(RMSE_x^2 + RMSE_y^2)
  (dx easting, dy northing), vertical RMSE_V from dz (non-vegetated terrain: the check points are targets
  on open ground);
* the check points' own survey error is part of the product's error:
  RMSE_H(product) = sqrt(RMSE_H(measured)^2 + RMSE_H(survey)^2), the same for V. The survey's RMSE_H is
  sqrt(sigma_E^2 + sigma_N^2) of the points' per-axis survey sigma (sqrt(2) x sigma for equal axes), taken
  as the RMS over the points;
* the accuracy class: the smallest class of a list of class values (or the user's target class) that the
  product RMSE meets, and whose half the check points' survey RMSE meets (Edition 2: the check points at
  least two times more accurate than the class tested);
* a statement of compliance ("tested to meet ... for a __ (cm) RMSE_H Horizontal Positional Accuracy Class",
  "... for a __ (cm) RMSE_V Vertical Accuracy Class. NVA accuracy was found to be ...") needs at least 30 check
  points (the minimum Edition 2 calls for); with fewer, the tested RMSE is stated with the number of check
  points and explicitly without a claim of compliance.

Only points whose role is "check" count (control points, left out one by one or not, are not independent
check points)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

STANDARD = "ASPRS Positional Accuracy Standards for Digital Geospatial Data, Edition 2 (2023)"
MIN_CHECK_POINTS = 30
# class values (cm) a drone survey is stated against: Edition 2 allows any X-cm class; these are the usual steps
HORIZONTAL_CLASSES_CM = (1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 7.5, 10.0, 12.5, 15.0, 20.0, 25.0, 30.0, 50.0, 100.0)
VERTICAL_CLASSES_CM = (1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 7.5, 10.0, 15.0, 20.0, 33.3, 66.7, 100.0)
SURVEY_RATIO = 2.0          # the check points' survey at least this many times more accurate than the class
_EPS_CM = 1e-9


@dataclass
class AxisAccuracy:
    """One component (horizontal or vertical) of the assessment; lengths in cm as the statement writes them."""
    component: str                     # "horizontal" | "vertical"
    measured_rmse_cm: float | None     # from the residuals alone
    survey_rmse_cm: float              # the check points' own survey RMSE
    product_rmse_cm: float | None      # both combined: what is stated
    class_cm: float | None             # the class met (smallest of the list, or the target), None: none met
    target_cm: float | None            # the user's target class, if given
    meets_target: bool | None          # None without a target
    survey_limits_class: bool          # the class the residuals alone would meet is refused by the survey RMSE
    statement: str


@dataclass
class AccuracyAssessment:
    standard: str
    n_check_points: int
    min_check_points: int
    compliant: bool                    # a statement of compliance is made (enough check points, classes met)
    rmse_x_cm: float | None
    rmse_y_cm: float | None
    horizontal: AxisAccuracy
    vertical: AxisAccuracy
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)


def _fmt_cm(v: float) -> str:
    return f"{v:.1f}"


def _fmt_class(c: float) -> str:
    return f"{c:g}"


def _check_rows(residuals) -> tuple[np.ndarray, list[str]]:
    """(n, 3) dx, dy, dz (m) of the check points and their names, from a ResidualTable, its dict (residuals.json)
    or an array."""
    rows = None
    if hasattr(residuals, "rows"):
        rows = [{"name": r.name, "role": r.role, "dx_m": r.dx_m, "dy_m": r.dy_m, "dz_m": r.dz_m} for r in residuals.rows]
    elif isinstance(residuals, dict):
        rows = residuals.get("points") or []
    if rows is None:
        d = np.asarray(residuals, dtype=float).reshape(-1, 3)
        return d, [f"#{i + 1}" for i in range(len(d))]
    keep = [r for r in rows if isinstance(r, dict) and str(r.get("role") or "check").strip().lower() == "check"
            and all(isinstance(r.get(k), (int, float)) and math.isfinite(r[k]) for k in ("dx_m", "dy_m", "dz_m"))]
    d = np.array([[r["dx_m"], r["dy_m"], r["dz_m"]] for r in keep], dtype=float).reshape(-1, 3)
    return d, [str(r.get("name", "")) for r in keep]


def _survey_rmse_cm(check_sigma_m, n: int) -> tuple[float, float]:
    """(RMSE_H, RMSE_V) of the check points' survey, cm. ``check_sigma_m``: (sigma per horizontal axis,
    sigma vertical) for every point, or one such pair per point."""
    s = np.asarray(check_sigma_m if check_sigma_m is not None else (0.0, 0.0), dtype=float)
    if s.ndim == 1:
        s = np.broadcast_to(s.reshape(1, 2), (max(n, 1), 2))
    if s.shape[-1] != 2 or (n and len(s) != n) or not np.all(np.isfinite(s)) or np.any(s < 0):
        raise ValueError(f"check point survey sigmas: (horizontal per axis, vertical) >= 0 per point; got {s.shape}")
    h = math.sqrt(2.0 * float(np.mean(s[:, 0] ** 2)))
    v = math.sqrt(float(np.mean(s[:, 1] ** 2)))
    return 100.0 * h, 100.0 * v


def _classify(product_cm: float | None, measured_cm: float | None, survey_cm: float, classes, target_cm):
    """The class met (or None) and whether the survey's accuracy refused a class the residuals met."""
    if product_cm is None:
        return None, None, False
    cands = (float(target_cm),) if target_cm is not None else tuple(sorted(float(c) for c in classes))
    met = [c for c in cands if product_cm <= c + _EPS_CM and survey_cm <= c / SURVEY_RATIO + _EPS_CM]
    by_residuals = [c for c in cands if product_cm <= c + _EPS_CM]
    cls = met[0] if met else None
    limited = bool(by_residuals) and (cls is None or cls > by_residuals[0])
    meets = None if target_cm is None else cls is not None
    return cls, meets, limited


def _statement(component: str, n: int, min_n: int, product_cm, cls, target_cm, survey_cm) -> str:
    """The sentence of the report. With at least ``min_n`` check points and a class met, Edition 2's statement:
    "... for a X (cm) RMSE_H Horizontal Positional Accuracy Class. The tested horizontal positional accuracy was
    found to be RMSE_H = x (cm)." / "... for a X (cm) RMSE_V Vertical Accuracy Class. NVA accuracy was found to be
    RMSE_V = x (cm)." (the vertical one for non-vegetated terrain, NVA); otherwise our own sentence, which makes no
    claim of compliance (docs/deliverables.md, "The accuracy statement", for the sources)."""
    sym = "RMSE_H" if component == "horizontal" else "RMSE_V"
    what = "horizontal positional accuracy" if component == "horizontal" else "vertical accuracy"
    class_name = ("Horizontal Positional Accuracy Class" if component == "horizontal" else "Vertical Accuracy Class")
    if product_cm is None or n == 0:
        return f"The {what} was not tested: no check point."
    found = (f"The tested horizontal positional accuracy was found to be {sym} = {_fmt_cm(product_cm)} (cm)."
             if component == "horizontal" else f"NVA accuracy was found to be {sym} = {_fmt_cm(product_cm)} (cm).")
    if n < min_n:
        within = (f" It lies within the {_fmt_class(cls)} (cm) {sym} {class_name}; no statement of compliance is made."
                  if cls is not None else
                  f" No {sym} class {'of ' + _fmt_class(target_cm) + ' (cm) ' if target_cm is not None else ''}"
                  "is met.")
        return (f"This data set was tested against the {STANDARD} using {n} check point{'s' if n != 1 else ''}, "
                f"fewer than the minimum of thirty (30) the standard calls for. {found}{within}")
    if cls is None:
        aim = (f"the {_fmt_class(target_cm)} (cm) {sym} {class_name}" if target_cm is not None else
               f"any {sym} {class_name} up to {_fmt_class(max(HORIZONTAL_CLASSES_CM if component == 'horizontal' else VERTICAL_CLASSES_CM))} (cm)")
        why = ""
        if product_cm is not None and target_cm is not None and product_cm <= target_cm + _EPS_CM:
            why = (f" (the check points' own survey, {sym} = {_fmt_cm(survey_cm)} (cm), is not two times more "
                   "accurate than the class)")
        return (f"This data set was tested against the {STANDARD} using {n} check points and does not meet "
                f"{aim}{why}. {found}")
    return f"This data set was tested to meet {STANDARD} for a {_fmt_class(cls)} (cm) {sym} {class_name}. {found}"


def assess_accuracy(residuals, check_sigma_m=(0.01, 0.02), target_class_cm: tuple | None = None,
                    horizontal_classes_cm=HORIZONTAL_CLASSES_CM, vertical_classes_cm=VERTICAL_CLASSES_CM,
                    min_check_points: int = MIN_CHECK_POINTS) -> AccuracyAssessment:
    """The ASPRS Edition 2 assessment of a residual table.

    ``residuals``: a ResidualTable, its dict (residuals.json: "points" with role, dx_m, dy_m, dz_m) or an
    (n, 3) array of dx, dy, dz in metres (all check points). ``check_sigma_m``: the check points' survey
    sigma (horizontal per axis, vertical) in metres, one pair for all or one per check point.
    ``target_class_cm``: (horizontal, vertical) class to test against (either may be None: the smallest
    class of the list met)."""
    d, _names = _check_rows(residuals)
    n = len(d)
    survey_h, survey_v = _survey_rmse_cm(check_sigma_m, n)
    tgt_h, tgt_v = (tuple(target_class_cm) + (None, None))[:2] if target_class_cm is not None else (None, None)
    if n:
        rx, ry, rz = (100.0 * math.sqrt(float(np.mean(d[:, k] ** 2))) for k in range(3))
        meas_h, meas_v = math.hypot(rx, ry), rz
        prod_h, prod_v = math.hypot(meas_h, survey_h), math.hypot(meas_v, survey_v)
    else:
        rx = ry = meas_h = meas_v = prod_h = prod_v = None
    axes = []
    for comp, meas, survey, prod, classes, tgt in (("horizontal", meas_h, survey_h, prod_h, horizontal_classes_cm, tgt_h),
                                                   ("vertical", meas_v, survey_v, prod_v, vertical_classes_cm, tgt_v)):
        cls, meets, limited = _classify(prod, meas, survey, classes, tgt)
        axes.append(AxisAccuracy(comp, meas, survey, prod, cls, None if tgt is None else float(tgt), meets, limited,
                                 _statement(comp, n, min_check_points, prod, cls, tgt, survey)))
    notes = []
    if n < min_check_points:
        notes.append(f"{n} check point{'s' if n != 1 else ''}: the standard asks for at least {min_check_points} "
                     "for a statement of compliance; the figures are stated without it.")
    for a in axes:
        if a.survey_limits_class:
            notes.append(f"{a.component}: the check points' own survey RMSE ({_fmt_cm(a.survey_rmse_cm)} cm) is not "
                         f"two times more accurate than the class the residuals alone would meet: a more accurate "
                         "check-point survey is needed for that class.")
    compliant = n >= min_check_points and all(a.class_cm is not None for a in axes)
    return AccuracyAssessment(STANDARD, n, min_check_points, compliant, rx, ry, axes[0], axes[1], notes)
