"""Fixes that the carrier phase contradicts, refused after a filter pass (compiled with numba).

Between two fixed epochs the change of every double-differenced phase residual of a signal tracked
without a slip depends on the two positions only (the integers cancel): millimetres for two correct fixes,
centimetres to decimetres where one of them holds a wrong integer (phase_consistency.py explains the
check and shows it on simulated and real data). The check runs between consecutive fixed epochs and
across the float epochs between two fixed runs up to MAX_BRIDGED_GAP_S apart: a short float gap (a ratio
test that failed for a few epochs) breaks no signal's integer, so the two runs must agree. Where a pass's
fixed positions jump like that, the shorter of the two fixed runs that meet there is the suspect one: a
fresh fix that disagrees with a long consistent run, or a brief run between floats. Runs up to
MAX_REFUSED_RUN epochs are given back their float solution (status float; in the combined solution the
covariance-weighted mean of both passes' floats, smoothing.combine); a jump between two longer runs is
left alone (nothing tells which one is wrong). The pass is checked again until no jump remains that can
be resolved.

On the u-blox walk of shared/data this removes the three wrong fixes of our continuous-mode solutions
that no anchor reaches (56-145 mm jumps), and, across float gaps, short runs that contradict a longer run
a few seconds away (e.g. 2 epochs 49 mm RMS from a run 3 s earlier on 10 signals; docs/gnss.md).
"""

from __future__ import annotations

import numpy as np
from .kernel_loader import njit

from .rtk_filter import STATUS_FIX, STATUS_FLOAT, FilterOutput
from .rtk_kernels import phase_residuals

JUMP_THRESHOLD_M = 0.04    # RMS change of the DD phase residuals between two fixed epochs (consecutive or bridged)
MAX_REFUSED_RUN = 10       # fixed runs up to this many epochs may be refused
MIN_SIGNALS = 5            # signals tracked without a slip over both epochs, references included
MAX_BRIDGED_GAP_S = 10.0   # two fixed runs this close (float epochs between them) are checked against each other


@njit(cache=True)
def bridged_jump_rms(d, c, fixed, pos, max_gap_s):
    """(E,) RMS (m) of the change of the DD phase residuals between each fixed epoch e and the previous fixed
    epoch p = prev[e], at their positions: consecutive epochs, or across the float epochs between two fixed
    runs where they span at most max_gap_s seconds; with at least MIN_SIGNALS signals observed at every
    epoch p..e without a slip (their integers are the same at p and e whatever the filter did in between);
    NaN elsewhere. Returns (rms, prev) with prev[e] = -1 where there is no such p."""
    n_e = fixed.shape[0]
    n_s, n_f = d.lam.shape
    out = np.full(n_e, np.nan)
    prev = np.full(n_e, -1, dtype=np.int64)
    zero = np.zeros(c.n_kin + n_s * n_f)
    last = -1
    for e in range(n_e):
        if not fixed[e]:
            continue
        p = last
        last = e
        if p < 0 or (e - p > 1 and d.time_s[e] - d.time_s[p] > max_gap_s):
            continue
        prev[e] = p
        ok = d.obs_ok[p].copy()
        for k in range(p + 1, e + 1):
            ok &= d.obs_ok[k]
        n_ok = 0
        for s in range(n_s):
            for b in range(n_f):
                if d.slip_cum[e + 1, s, b] != d.slip_cum[p + 1, s, b]:
                    ok[s, b] = False
                if ok[s, b]:
                    n_ok += 1
        if n_ok < MIN_SIGNALS:
            continue
        r0 = phase_residuals(d, c, p, pos[p], zero, ok)[0]
        r1 = phase_residuals(d, c, e, pos[e], zero, ok)[0]
        out[e] = dd_change_rms(r0, r1, d.sys_code, c.n_systems)
    return out, prev


@njit(cache=True)
def consecutive_jump_rms(d, c, fixed, pos):
    """(E,) RMS (m) of the change of the DD phase residuals between epoch e - 1 and e, both fixed, at their
    positions; NaN where not both fixed or fewer than MIN_SIGNALS signals are tracked without a slip."""
    return bridged_jump_rms(d, c, fixed, pos, 0.0)[0]


@njit(cache=True)
def dd_change_rms(r0, r1, sys_code, n_systems):
    """RMS (m) of the change of the DD residuals (S, F) from r0 to r1, both re-referenced, per system and
    band, to the first satellite present in both (the two epochs may have chosen different reference
    satellites); NaN when no double difference is left."""
    n_s, n_f = r0.shape
    acc = 0.0
    n = 0
    for b in range(n_f):
        for sys in range(n_systems):
            ref = -1
            for s in range(n_s):
                if sys_code[s] != sys or np.isnan(r0[s, b]) or np.isnan(r1[s, b]):
                    continue
                if ref < 0:
                    ref = s
                    continue
                dv = (r1[s, b] - r1[ref, b]) - (r0[s, b] - r0[ref, b])
                acc += dv * dv
                n += 1
    return np.sqrt(acc / n) if n > 0 else np.nan


def _fixed_runs(fixed: np.ndarray, jump: np.ndarray) -> np.ndarray:
    """Run id per epoch: consecutive fixed epochs without a jump between them share one (-1 elsewhere)."""
    run = np.full(len(fixed), -1, dtype=np.int64)
    current = -1
    for e in range(len(fixed)):
        if not fixed[e]:
            continue
        if e == 0 or not fixed[e - 1] or jump[e]:
            current += 1
        run[e] = current
    return run


def refuse_jumping_fixes(d, c, out: FilterOutput, threshold_m: float = JUMP_THRESHOLD_M, max_run: int = MAX_REFUSED_RUN,
                         max_gap_s: float = MAX_BRIDGED_GAP_S) -> tuple[FilterOutput, int]:
    """`out` with the fixed runs the carrier phase contradicts given back their float solution (in place),
    and the number of epochs refused. d, c: the pass's FilterArrays and FilterConfig."""
    if out.float_position_ecef_m is None:
        return out, 0
    refused = 0
    for _ in range(50):
        fixed = out.status == STATUS_FIX
        if not fixed.any():
            break
        rms, prev = bridged_jump_rms(d, c, fixed, np.ascontiguousarray(out.position_ecef_m), max_gap_s)
        jump = np.nan_to_num(rms, nan=0.0) > threshold_m
        if not jump.any():
            break
        run = _fixed_runs(fixed, jump)
        length = np.bincount(run[run >= 0])
        drop = set()
        for e in np.nonzero(jump)[0]:
            a, b = run[prev[e]], run[e]
            shorter = a if length[a] <= length[b] else b
            if length[shorter] <= max_run:
                drop.add(int(shorter))
        if not drop:
            break
        epochs = np.nonzero(np.isin(run, list(drop)))[0]
        out.status[epochs] = STATUS_FLOAT
        out.position_ecef_m[epochs] = out.float_position_ecef_m[epochs]
        out.covariance_ecef_m2[epochs] = out.float_covariance_ecef_m2[epochs]
        out.n_fixed_amb[epochs] = 0
        refused += len(epochs)
    return out, refused
