"""Cycle slips the receivers did not flag, found in time-differenced carrier phase (compiled with numba).

Between two consecutive rover epochs the between-receiver single difference of carrier phase changes by
the rover's displacement projected on each line of sight plus the change of the receiver clocks (one per
system), and by nothing else: the ambiguity cancels as long as the signal keeps lock. Fitting those four
or five unknowns to all signals of the epoch by least squares leaves millimetre residuals; a signal that
slipped by a cycle (19 cm on L1) or a half cycle stands out by decimetres. The worst one beyond the
threshold is flagged and the fit repeated, until every residual is within it.

This needs no position better than a single-point solution (a 5 m error changes the residuals by
~0.2 mm over one second of satellite motion), no second frequency and no Doppler, so it catches the
slips that low-cost single-frequency receivers leave unflagged: on the u-blox M8P walk of shared/data it
finds 26 slips in 1180 epochs beside the 932 that the receivers flag (docs/gnss.md).
"""

from __future__ import annotations

import numpy as np
from .kernel_loader import njit


DEFAULT_THRESHOLD_M = 0.05   # residual beyond which a signal is called slipped (a quarter cycle on L1)
MIN_SIGNALS = 6              # signals an epoch pair needs for the fit to be checked at all
MAX_GAP_S = 30.0             # epoch pairs further apart are not checked (satellite motion, atmosphere)


def time_differenced_slips(time_s: np.ndarray, sd_phase_m: np.ndarray, los: np.ndarray, sys_code: np.ndarray,
                           flagged: np.ndarray, threshold_m: float = DEFAULT_THRESHOLD_M,
                           min_signals: int = MIN_SIGNALS, max_gap_s: float = MAX_GAP_S) -> np.ndarray:
    """(E, S, F) bool: the signal slipped between epoch e - 1 and e.

    sd_phase_m (E, S, F): rover-minus-base carrier phase (m) minus the modelled range (NaN where either
    receiver has no phase); los (E, S, 3) unit vectors to the satellites; sys_code (S,) system index per
    satellite; flagged (E, S, F) slips already known (such signals are left out of the fit)."""
    if threshold_m <= 0 or len(time_s) < 2:
        return np.zeros(sd_phase_m.shape, dtype=bool)
    return _slips(np.ascontiguousarray(time_s, dtype=float), np.ascontiguousarray(sd_phase_m, dtype=float),
                  np.ascontiguousarray(los, dtype=float), np.ascontiguousarray(sys_code, dtype=np.int64),
                  np.ascontiguousarray(flagged, dtype=np.bool_), float(threshold_m), int(min_signals),
                  float(max_gap_s))


@njit(cache=True)
def _slips(time_s, sd, los, sys_code, flagged, threshold, min_signals, max_gap):
    n_e, n_s, n_f = sd.shape
    n_sys = 0
    for s in range(n_s):
        n_sys = max(n_sys, sys_code[s] + 1)
    out = np.zeros((n_e, n_s, n_f), np.bool_)
    n_max = n_s * n_f
    y = np.empty(n_max)
    a = np.zeros((n_max, 3 + n_sys))
    where_s = np.empty(n_max, np.int64)
    where_b = np.empty(n_max, np.int64)
    for e in range(1, n_e):
        if time_s[e] - time_s[e - 1] > max_gap:
            continue
        m = 0
        for s in range(n_s):
            for b in range(n_f):
                if flagged[e, s, b] or np.isnan(sd[e, s, b]) or np.isnan(sd[e - 1, s, b]):
                    continue
                y[m] = sd[e, s, b] - sd[e - 1, s, b]
                for k in range(3):
                    a[m, k] = -los[e, s, k]
                for k in range(n_sys):
                    a[m, 3 + k] = 0.0
                a[m, 3 + sys_code[s]] = 1.0
                where_s[m] = s
                where_b[m] = b
                m += 1
        if m < min_signals:
            continue
        keep = np.ones(m, np.bool_)
        while True:
            # the unknowns: displacement (3) and one clock change per system that has a kept signal
            cols = np.zeros(3 + n_sys, np.bool_)
            cols[:3] = True
            n_keep = 0
            for i in range(m):
                if keep[i]:
                    n_keep += 1
                    for k in range(n_sys):
                        if a[i, 3 + k] != 0.0:
                            cols[3 + k] = True
            idx = np.nonzero(cols)[0]
            n_u = idx.shape[0]
            if n_keep < n_u + 2:      # too few left to tell a slip from the fit
                break
            ata = np.zeros((n_u, n_u))
            aty = np.zeros(n_u)
            for i in range(m):
                if not keep[i]:
                    continue
                for p in range(n_u):
                    aty[p] += a[i, idx[p]] * y[i]
                    for q in range(n_u):
                        ata[p, q] += a[i, idx[p]] * a[i, idx[q]]
            sol = np.linalg.solve(ata, aty)
            worst = -1
            worst_r = threshold
            for i in range(m):
                if not keep[i]:
                    continue
                r = y[i]
                for p in range(n_u):
                    r -= a[i, idx[p]] * sol[p]
                if abs(r) > worst_r:
                    worst_r = abs(r)
                    worst = i
            if worst < 0:
                break
            keep[worst] = False
            out[e, where_s[worst], where_b[worst]] = True
    return out
