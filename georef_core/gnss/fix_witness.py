"""Fixes the other filter direction contradicts, refused (the reverse pass as a witness).

A forward and a backward pass over the same data are two filters with different histories: a wrong
integer set that one of them fixed (an over-confident float, a held fix carried across a slip that
nobody flagged) is not what the other one fixes at the same epoch, except by rare coincidence. Where
both passes are fixed and their positions lie more than FIX_CONFLICT_M apart, at most one of them holds
the right integers. The carrier phase decides where it can: both candidates are compared with the
anchors (epochs both passes fix within FIX_CONFLICT_M of each other) over the signals tracked without a
slip, at least fix_continuity.MIN_SIGNALS of them (phase_consistency.anchored_rms_m); the candidate whose misfit is at most ARBITER_MAX_RMS_M and at
most 1/ARBITER_FACTOR of the other's is kept (the factor 2 calibrated in the judged comparison on the car's
L1 data against its dual-frequency quasi-truth, docs/gnss.md); when both fit the anchors within
ARBITER_MAX_RMS_M and neither misfits twice the other, both carry the anchors' integers and differ by the
geometry alone (on GEONET's last epochs, 5 satellites, a 5-epoch static start 9-11 cm from the long one,
misfits 2.4-2.6 vs 3.8-5.3 mm): both are kept. Otherwise (no anchor spans the epoch, or one misfit beyond
ARBITER_MAX_RMS_M without the other being half of it) nothing tells which is wrong and neither is output
as fixed, unless one of the two fixed runs that meet there (consecutive fixed epochs of one pass) holds
anchors and the other none: the other pass confirmed that run's integers elsewhere, and the carrier phase
carried them through the run (fix_continuity refuses or splits runs whose phase jumps). The fixed run of a refused fix is refused
whole when it is at most MAX_REFUSED_RUN epochs long: its other epochs carry the same integers, so the same
error. A fix alone in its pass (not fixed at the epochs before and after in that pass) where the other
pass is not fixed is refused as well (on the u-blox walk such fixes were the combined solution's only ones the carrier
phase contradicted, 1.1-1.7 m off).

Used for every direction (ppk._solve): a forward (or backward) solution runs the other pass as its
witness unless RtkOptions.reverse_witness is off; the combined solution applies the same rule where it
joins the passes (smoothing.combine). Refused epochs get their pass's float solution back (status float).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .fix_continuity import MIN_SIGNALS
from .phase_consistency import PhaseSpans, anchored_rms_m
from .rtk_filter import STATUS_FIX, STATUS_FLOAT, FilterOutput, PreparedData
from .rtk_options import RtkOptions

FIX_CONFLICT_M = 0.05   # two fixed solutions of one epoch further apart than this disagree on an integer
MAX_REFUSED_RUN = 10    # a refused fix's run this short (epochs) is refused whole
ARBITER_FACTOR = 2.0    # the kept candidate's carrier-phase misfit against the anchors: at most 1/2 of the other's
ARBITER_MAX_RMS_M = 0.04   # ... and at most this (fix_continuity's jump threshold)

__all__ = ["FIX_CONFLICT_M", "MAX_REFUSED_RUN", "PhaseArbiter", "contradicted_fixes", "fixed_runs", "float_back",
           "refuse_contradicted_fixes"]


def fixed_runs(status: np.ndarray) -> np.ndarray:
    """(E,) index of the run of consecutive fixed epochs each epoch belongs to (-1 where not fixed)."""
    fixed = np.asarray(status) == STATUS_FIX
    starts = fixed & ~np.concatenate([[False], fixed[:-1]])
    run = np.cumsum(starts) - 1
    return np.where(fixed, run, -1)


class PhaseArbiter:
    """Decides conflicting fixes by the carrier phase against the anchors (module docstring)."""

    def __init__(self, data: PreparedData, opts: RtkOptions):
        self.data, self.opts = data, opts
        self._spans: PhaseSpans | None = None   # built at the first conflict, shared by every later one

    def __call__(self, epochs: np.ndarray, pos_a: np.ndarray, pos_b: np.ndarray, anchors: np.ndarray,
                 anchor_ecef_m: np.ndarray) -> np.ndarray:
        """(len(epochs),) 1 where a's fix is kept, 2 where b's, 3 where both are (both fit the anchors' integers:
        the positions differ by the geometry, not by an integer), 0 where undecided."""
        out = np.zeros(len(epochs), dtype=np.int8)
        if len(anchors) == 0:
            return out
        fixed = np.zeros(len(pos_a), dtype=bool)
        fixed[epochs] = True
        if self._spans is None:
            self._spans = PhaseSpans(self.data, self.opts)
        rms_a, _ = anchored_rms_m(self.data, self.opts, pos_a, fixed, anchor_ecef_m, anchors, min_signals=MIN_SIGNALS,
                                  spans=self._spans)
        rms_b, _ = anchored_rms_m(self.data, self.opts, pos_b, fixed, anchor_ecef_m, anchors, min_signals=MIN_SIGNALS,
                                  spans=self._spans)
        ra, rb = rms_a[epochs], rms_b[epochs]
        out[(ra <= ARBITER_MAX_RMS_M) & (rb >= ARBITER_FACTOR * ra)] = 1
        out[(rb <= ARBITER_MAX_RMS_M) & (ra >= ARBITER_FACTOR * rb)] = 2
        out[(ra <= ARBITER_MAX_RMS_M) & (rb <= ARBITER_MAX_RMS_M) & (ra < ARBITER_FACTOR * rb)
            & (rb < ARBITER_FACTOR * ra)] = 3
        return out


def _lone_fix(status: np.ndarray) -> np.ndarray:
    """Fixed epochs whose neighbours in the pass (both, where they exist) are not fixed."""
    fixed = np.asarray(status) == STATUS_FIX
    before = np.concatenate([[False], fixed[:-1]])
    after = np.concatenate([fixed[1:], [False]])
    return fixed & ~before & ~after


def contradicted_fixes(a: FilterOutput, b: FilterOutput, arbiter: PhaseArbiter | None = None,
                       conflict_m: float = FIX_CONFLICT_M,
                       max_refused_run: int = MAX_REFUSED_RUN) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The epochs of `a` and of `b` (two passes over the same epochs) whose fixes the other pass
    contradicts: (refuse_a (E,), refuse_b (E,), conflict (E,)), conflict being the epochs where both are fixed
    more than conflict_m apart. See the module docstring for the rule; without an arbiter no conflict is
    decided."""
    fa, fb = a.status == STATUS_FIX, b.status == STATUS_FIX
    dist = np.linalg.norm(a.position_ecef_m - b.position_ecef_m, axis=1)
    conflict = fa & fb & ~(dist <= conflict_m)      # NaN positions count as a conflict
    refuse_a, refuse_b = conflict.copy(), conflict.copy()
    run_a, run_b = fixed_runs(a.status), fixed_runs(b.status)
    if conflict.any():
        anchors = np.nonzero(fa & fb & (dist <= conflict_m))[0]
        epochs = np.nonzero(conflict)[0]
        winner = np.zeros(len(epochs), dtype=np.int8)
        if arbiter is not None:
            winner = arbiter(epochs, a.position_ecef_m, b.position_ecef_m, anchors,
                             0.5 * (a.position_ecef_m + b.position_ecef_m))
        # where the carrier phase cannot tell: a run that the other pass confirms somewhere (it holds anchors)
        # against one it confirms nowhere
        confirmed_a = np.isin(run_a[epochs], run_a[anchors])
        confirmed_b = np.isin(run_b[epochs], run_b[anchors])
        winner = np.where((winner == 0) & confirmed_a & ~confirmed_b, 1, winner)
        winner = np.where((winner == 0) & confirmed_b & ~confirmed_a, 2, winner)
        refuse_a[epochs[(winner == 1) | (winner == 3)]] = False
        refuse_b[epochs[(winner == 2) | (winner == 3)]] = False
    refuse_a |= _lone_fix(a.status) & ~fb
    refuse_b |= _lone_fix(b.status) & ~fa
    for run, refuse in ((run_a, refuse_a), (run_b, refuse_b)):
        if not refuse.any():
            continue
        length = np.bincount(run[run >= 0])
        for r in np.unique(run[refuse & (run >= 0)]):
            if length[r] <= max_refused_run:
                refuse |= run == r
    return refuse_a, refuse_b, conflict


def float_back(out: FilterOutput, refuse: np.ndarray) -> FilterOutput:
    """`out` with the epochs `refuse` given their float solution (status float)."""
    if not refuse.any():
        return out
    status = out.status.copy()
    pos, cov = out.position_ecef_m.copy(), out.covariance_ecef_m2.copy()
    n_fix = out.n_fixed_amb.copy()
    status[refuse] = STATUS_FLOAT
    n_fix[refuse] = 0
    if out.float_position_ecef_m is not None:
        has = refuse & np.isfinite(out.float_position_ecef_m).all(axis=1)
        pos[has] = out.float_position_ecef_m[has]
        cov[has] = out.float_covariance_ecef_m2[has]
    return dataclasses.replace(out, status=status, position_ecef_m=pos, covariance_ecef_m2=cov, n_fixed_amb=n_fix)


def refuse_contradicted_fixes(out: FilterOutput, witness: FilterOutput,
                              arbiter: PhaseArbiter | None = None) -> tuple[FilterOutput, np.ndarray]:
    """`out` with the fixes its witness (the other direction's pass) contradicts given back their float
    solution; returns (output, conflict (E,) bool: both fixed, more than FIX_CONFLICT_M apart)."""
    refuse, _, conflict = contradicted_fixes(out, witness, arbiter)
    return float_back(out, refuse), conflict
