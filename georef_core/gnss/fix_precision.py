"""Fixed epochs whose fixed position is too imprecise to carry the "fixed" flag, output as float.

A fix means the integers are resolved; it does not by itself mean a centimetre position. Where the
geometry collapses (on GEONET's last L1 epochs five satellites remain, four double differences for three
coordinates) the position computed with the right integers still has a formal 3-D standard deviation of
15-19 cm, and lies 10-14 cm from the truth, as its covariance says. Software that reads a .pos file (ours
downstream, and third-party photogrammetry packages that weight "Q=1" camera positions as centimetre
ones) takes the flag as the precision class, so the flag must not promise more than the covariance.

Rule: a fixed epoch whose fixed position has sqrt(trace(covariance)) > RtkOptions.fix_max_sigma_m (default
FIX_MAX_SIGMA_M = 5 cm, the tolerance that defines a wrong fix in docs/gnss.md; 0 turns the rule off) is
output with status float. Its position and covariance stay those of the fixed solution (the better
estimate; its covariance is honest), so nothing downstream loses precision, only the flag changes.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .rtk_filter import STATUS_FIX, STATUS_FLOAT, FilterOutput

FIX_MAX_SIGMA_M = 0.05


def sigma_3d_m(covariance_ecef_m2: np.ndarray) -> np.ndarray:
    """(E,) formal 3-D standard deviation sqrt(trace) of each epoch's position covariance."""
    return np.sqrt(np.abs(np.trace(covariance_ecef_m2, axis1=1, axis2=2)))


def refuse_imprecise_fixes(out: FilterOutput, max_sigma_m: float) -> tuple[FilterOutput, int]:
    """``out`` with the fixed epochs whose 3-D sigma exceeds ``max_sigma_m`` set to float, and their count."""
    if max_sigma_m <= 0:
        return out, 0
    weak = (out.status == STATUS_FIX) & (sigma_3d_m(out.covariance_ecef_m2) > max_sigma_m)
    n = int(weak.sum())
    if n == 0:
        return out, 0
    status = out.status.copy()
    status[weak] = STATUS_FLOAT
    return dataclasses.replace(out, status=status), n
