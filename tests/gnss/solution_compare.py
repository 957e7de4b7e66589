"""Comparison of two solutions (ours and a reference such as an RTKLIB .pos) epoch by epoch: fix rates,
and on epochs fixed in both, horizontal/vertical differences in the local ENU frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from georef_core.gnss.frames import ecef_to_enu_rotation, geodetic_to_ecef_m
from georef_core.gnss.solution_io import PosFile


@dataclass
class Comparison:
    n_common: int
    fix_rate: float              # ours, over the common epochs
    fix_rate_ref: float
    n_both_fixed: int
    median_horizontal_m: float
    median_vertical_m: float
    max_3d_m: float
    n_beyond_5cm: int
    beyond_5cm_time_s: tuple = ()  # the reference's times of those epochs

    def as_dict(self) -> dict:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


def pos_ecef_m(p: PosFile) -> np.ndarray:
    return geodetic_to_ecef_m(np.radians(p.lat_deg), np.radians(p.lon_deg), p.height_m)


def nearest_epochs(time_s: np.ndarray, query_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each query time: the index of the nearest of the sorted times `time_s` and the distance (s)."""
    idx = np.clip(np.searchsorted(time_s, query_s), 0, max(len(time_s) - 1, 0))
    cand = np.stack([np.clip(idx - 1, 0, None), idx])
    dt = np.abs(time_s[cand] - query_s[None, :])
    pick = np.argmin(dt, axis=0)
    cols = np.arange(len(query_s))
    return cand[pick, cols], dt[pick, cols]


def compare_pos(ours: PosFile, ref: PosFile, time_tolerance_s: float = 0.02) -> Comparison:
    """Epochs are matched by time; fix rates are computed over the reference's epochs (an epoch we do not
    output counts as not fixed)."""
    best, dt = nearest_epochs(ours.time_s, ref.time_s)
    matched = dt <= time_tolerance_s
    n_ref = len(ref.time_s)
    ours_fix = np.zeros(n_ref, dtype=bool)
    ours_fix[matched] = ours.status[best[matched]] == 1
    ref_fix = ref.status == 1
    both = ours_fix & ref_fix
    med_h = med_v = max3 = float("nan")
    n_bad = 0
    bad_t: tuple = ()
    if both.any():
        a = pos_ecef_m(ours)[best[both]]
        b = pos_ecef_m(ref)[both]
        lat0, lon0 = np.radians(ref.lat_deg[both][0]), np.radians(ref.lon_deg[both][0])
        enu = (a - b) @ ecef_to_enu_rotation(lat0, lon0).T
        h = np.hypot(enu[:, 0], enu[:, 1])
        d3 = np.linalg.norm(enu, axis=1)
        med_h, med_v, max3 = float(np.median(h)), float(np.median(np.abs(enu[:, 2]))), float(d3.max())
        n_bad = int(np.sum(d3 > 0.05))
        bad_t = tuple(float(t) for t in ref.time_s[both][d3 > 0.05])
    return Comparison(int(matched.sum()), float(ours_fix.mean()) if n_ref else 0.0,
                      float(ref_fix.mean()) if n_ref else 0.0, int(both.sum()), med_h, med_v, max3, n_bad, bad_t)


def fixed_position_at(sol: PosFile, time_s: float, time_tolerance_s: float = 0.02) -> np.ndarray | None:
    """ECEF position of a fixed epoch of ``sol`` at ``time_s`` (None when absent or not fixed)."""
    i = int(np.argmin(np.abs(sol.time_s - time_s))) if len(sol.time_s) else -1
    if i < 0 or abs(sol.time_s[i] - time_s) > time_tolerance_s or sol.status[i] != 1:
        return None
    return geodetic_to_ecef_m(np.radians(sol.lat_deg[i]), np.radians(sol.lon_deg[i]), sol.height_m[i])
