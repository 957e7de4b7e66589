"""Epoch-to-epoch consistency of a solution with time-differenced double-differenced carrier phase.

Between two consecutive epochs without a cycle slip the integer ambiguities cancel: the change of the
DD phase residual computed at two positions depends on the positions only. For a correct pair of
positions it is millimetres (phase noise and the change of multipath in one epoch); a wrong fix that
begins or ends between the two epochs shows as centimetres. This needs no truth and no integers, so it
judges any engine's fixed solution on the same data (RTKLIB's as well as ours) where no reference
trajectory exists: the u-blox walk of shared/data/gnss (docs/gnss.md).

The same holds over any span of epochs in which a set of signals is tracked throughout without a slip:
`anchored_rms_m` compares every fixed epoch of a solution with "anchor" epochs (fixed epochs that two
engines agree on) across such spans. Where two engines' fixes part, at most one of them can share the
anchors' integers, and the carrier phase tells which, with no truth needed.
"""

from __future__ import annotations

import numpy as np

from .fix_continuity import consecutive_jump_rms
from .rtk_filter import PreparedData, RtkFilter
from .rtk_kernels import phase_residuals
from .rtk_options import RtkOptions

JUMP_THRESHOLD_M = 0.02    # RMS change beyond which a pair of epochs is called inconsistent
MIN_SPAN_SIGNALS = 6       # signals tracked without a gap or slip over a whole span to an anchor
MAX_ANCHORS = 5            # anchors per epoch (the nearest in time with enough signals)


def epoch_pair_rms_m(data: PreparedData, opts: RtkOptions, position_ecef_m: np.ndarray,
                     valid: np.ndarray) -> np.ndarray:
    """(E,) RMS (m) over the double differences of the change of DD phase residual between epoch e - 1 at
    position_ecef_m[e - 1] and epoch e at position_ecef_m[e]; NaN where either epoch is not `valid` or
    fewer than fix_continuity.MIN_SIGNALS signals are tracked without a slip over both (the compiled check the engine
    itself uses to refuse fixes, fix_continuity.consecutive_jump_rms)."""
    flt = RtkFilter(data, opts)
    pos = np.ascontiguousarray(np.nan_to_num(np.asarray(position_ecef_m, dtype=float)))
    return consecutive_jump_rms(flt.arrays(), flt.config(), np.asarray(valid, dtype=bool), pos)


def inconsistent_fixed_epochs(data: PreparedData, opts: RtkOptions, position_ecef_m: np.ndarray,
                              fixed: np.ndarray, threshold_m: float = JUMP_THRESHOLD_M) -> np.ndarray:
    """Indices e of consecutive fixed epochs (e - 1, e) whose position change disagrees with the
    time-differenced carrier phase by more than threshold_m (RMS)."""
    rms = epoch_pair_rms_m(data, opts, position_ecef_m, fixed)
    return np.nonzero(rms > threshold_m)[0]


def reference_free_change_rms(r0: np.ndarray, r1: np.ndarray, ok: np.ndarray, sys_code: np.ndarray) -> float:
    """RMS (m) of the change of the DD residuals (S, F) from r0 to r1 over the signals `ok` (S, F), the
    residuals as rtk_kernels.phase_residuals gives them (NaN at each system's reference satellite, which is
    counted with its own residual, zero; the two epochs' references may differ, their offsets cancel), free
    of the choice of reference satellite: per system and band the changes minus their mean, pooled over
    (number of signals - 1) degrees of freedom. The sum of squares equals the double differences' quadratic
    form with their full covariance (equal single-difference variances), so no satellite enters twice;
    double differences against one reference satellite (fix_continuity.dd_change_rms) put that satellite's
    own error into every term (on the u-blox walk a GLONASS reference 2-5 cm off its neighbours made both
    engines' fixes of epoch 771 look alike: docs/gnss.md). For independent errors of standard deviation s
    in the change of each single difference this estimates s (the reference-based RMS about s * sqrt(2)).
    NaN when no system and band has two signals."""
    change = np.where(ok, np.nan_to_num(r1) - np.nan_to_num(r0), np.nan)
    systems = np.unique(sys_code)
    acc, dof = 0.0, 0
    for b in range(change.shape[1]):
        for sys in systems:
            x = change[(sys_code == sys) & ok[:, b], b]
            if len(x) >= 2:
                acc += float(np.sum((x - x.mean()) ** 2))
                dof += len(x) - 1
    return float(np.sqrt(acc / dof)) if dof else np.nan


def _span_signals(d, lo, hi, unbroken: np.ndarray) -> np.ndarray:
    """(S, F) signals observed at every epoch lo..hi with no slip flagged at lo + 1..hi; (N, S, F) for arrays
    lo, hi of N spans."""
    lo, hi = np.asarray(lo), np.asarray(hi)
    n_epochs = (hi + 1 - lo).reshape(lo.shape + (1, 1))
    return (unbroken[hi + 1] - unbroken[lo] == n_epochs) & (d.slip_cum[hi + 1] == d.slip_cum[lo + 1])


class PhaseSpans:
    """The filter's observation arrays and the running count of unbroken tracking, built once per solve and
    shared by every anchored_rms_m call on it (the arbiter compares two candidates on the same arrays)."""

    def __init__(self, data: PreparedData, opts: RtkOptions):
        flt = RtkFilter(data, opts)
        self.d, self.cfg = flt.arrays(), flt.config()
        d = self.d
        self.zero_amb = np.zeros(self.cfg.n_kin + d.obs_ok.shape[1] * d.obs_ok.shape[2])
        self.unbroken = np.concatenate([np.zeros((1,) + d.obs_ok.shape[1:], np.int64),
                                        np.cumsum(d.obs_ok, axis=0, dtype=np.int64)])
        # DD phase residuals at an anchor epoch over the signals of its span to an epoch e, by (anchor, e, anchor
        # position bytes): the arbiter's two candidates share them
        self.anchor_residuals: dict = {}


ANCHOR_BLOCK = 8   # anchors whose spans are counted together at first (nearest first), the blocks doubling after


def _qualifying_anchors(d, e: int, ordered: np.ndarray, unbroken: np.ndarray, min_signals: int):
    """The anchors of `ordered` (nearest first, e itself left out) whose span to e keeps at least min_signals
    signals (_span_signals), in order: the same test, counted for a block of anchors at once (ANCHOR_BLOCK, then
    twice as many each time: most epochs need the first block only, some look far)."""
    k, size = 0, ANCHOR_BLOCK
    while k < len(ordered):
        block = ordered[k:k + size]
        k, size = k + size, 2 * size
        ok = _span_signals(d, np.minimum(block, e), np.maximum(block, e), unbroken)
        n_ok = ok.reshape(len(block), -1).sum(axis=1)
        yield from block[n_ok >= min_signals]


def anchored_rms_m(data: PreparedData, opts: RtkOptions, position_ecef_m: np.ndarray, fixed: np.ndarray,
                   anchor_ecef_m: np.ndarray, anchors: np.ndarray, max_anchors: int = MAX_ANCHORS,
                   min_signals: int = MIN_SPAN_SIGNALS, spans: PhaseSpans | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """For every `fixed` epoch e: the RMS (m) of the change of DD phase residual (reference-free:
    reference_free_change_rms) between anchor epoch a (at anchor_ecef_m[a]) and e (at
    position_ecef_m[e]), over the signals tracked without a gap or slip from a to e, the median over the
    (at most max_anchors) nearest anchors with at least min_signals such signals. A position consistent
    with the anchors' carrier phase gives the phase noise plus the change of multipath over the span (a
    centimetre or two over minutes on a u-blox walk); a fix that differs from the anchors' in its integers
    gives decimetres.
    `spans`: the arrays of (data, opts) when the caller already built them (PhaseSpans).
    Returns (rms (E,), NaN where not fixed or no anchor qualifies; number of anchors used (E,))."""
    spans = spans or PhaseSpans(data, opts)
    d, cfg, zero_amb, unbroken = spans.d, spans.cfg, spans.zero_amb, spans.unbroken
    n_e = len(d.time_s)
    anchors = np.asarray(anchors, dtype=np.int64)
    out = np.full(n_e, np.nan)
    used = np.zeros(n_e, dtype=np.int64)
    cache = spans.anchor_residuals
    for e in np.nonzero(fixed)[0]:
        rms = []
        ordered = anchors[np.argsort(np.abs(anchors - e), kind="stable")]
        for a in _qualifying_anchors(d, e, ordered[ordered != e], unbroken, min_signals):
            lo, hi = min(a, e), max(a, e)
            ok = _span_signals(d, lo, hi, unbroken)
            pos_a = np.asarray(anchor_ecef_m[a], float)
            key = (int(a), int(e), pos_a.tobytes())
            r_a = cache.get(key)
            if r_a is None:
                r_a = cache[key] = phase_residuals(d, cfg, a, pos_a, zero_amb, ok)[0]
            r_e = phase_residuals(d, cfg, e, np.asarray(position_ecef_m[e], float), zero_amb, ok)[0]
            change = reference_free_change_rms(r_a, r_e, ok, d.sys_code)
            if np.isfinite(change):
                rms.append(float(change))
            if len(rms) == max_anchors:
                break
        if rms:
            out[e] = float(np.median(rms))
            used[e] = len(rms)
    return out, used
