"""Comparison of two fixed solutions of the same data in which a wrong fix counts as a failure, not a fix.

`solution_compare.compare_pos` takes the reference (RTKLIB demo5) as it is: where demo5 fixes wrongly, our
correct fix shows as a disagreement. Where two fixes of the same epoch lie more than `APART_M` apart, at
most one of them can carry the right integers. Without truth the carrier phase tells which
(`phase_consistency.anchored_rms_m`, a misfit free of the choice of reference satellite): both positions
are compared, over signals tracked without a gap or a slip, with the "anchors", the epochs both solutions
fix within `ANCHOR_AGREEMENT_M` of each other. The fix that misfits the anchors' carrier phase at least
`DECISIVE_RATIO` times more than the other is refuted, and demoted to float before the two solutions are
compared again. A fix that cannot be judged (no anchor reachable without a slip) loses against one that
can. Where the carrier phase is not decisive and the two solutions are passes of one direction (forward,
or backward), each engine's pass in the other direction is a witness: when three of the four passes (two
engines, two directions) fix the epoch within `ANCHOR_AGREEMENT_M` of each other, the fourth (the
contested fix, more than `APART_M` from the other engine's) is refuted (its own engine, run the other way
through the same data, contradicts it; what the two directions do not share is the filter's history, a
wrong or partial fix carried from earlier epochs). A refutation carries along the same solution's chain of
consecutive contested fixes whose position changes the time-differenced carrier phase confirms
(`phase_consistency.epoch_pair_rms_m` within `phase_consistency.JUMP_THRESHOLD_M`): such a neighbour
carries the same integers, so the same error (where a wrong stretch begins or ends, the anchors' check
alone can be short of decisive). Where neither the check nor the witnesses decide, neither fix is refuted
and the disagreement stays in the figures.

The ratio is calibrated where a truth exists: on the 5.3 km car baseline with L1 only (the hardest case
for the check: the residual ionosphere drifts over the spans to the anchors), demo5's dual-frequency
solution taken as truth, the check gave the larger misfit to the fix nearer the truth at 3 of 188
epochs, all with ratios below 1.72; at each of the 119 with a ratio of 2 or more it picked the right one
(2026-11-25; docs/gnss.md). The reverse-pass witnesses on the same baseline (applied to every contested
epoch of the two forward L1 runs): 55 + 71 of demo5's fixes refuted, none of ours, the only picks against
the truth at one epoch (197, in both runs; both fixes within 3.1 cm of the truth, which leaves its own
trend there).

The rule is symmetric: a refuted fix of ours counts against us exactly as one of demo5's counts against
demo5 (tests/gnss/test_ppk_vs_rtklib.py asserts that ours are never refuted; docs/gnss.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from georef_core.gnss.frames import geodetic_to_ecef_m
from georef_core.gnss.phase_consistency import JUMP_THRESHOLD_M, anchored_rms_m, epoch_pair_rms_m
from georef_core.gnss.rtk_filter import PreparedData
from georef_core.gnss.rtk_options import RtkOptions
from tests.gnss.solution_compare import Comparison, compare_pos, nearest_epochs
from georef_core.gnss.solution_io import PosFile

APART_M = 0.05              # two fixes farther apart than this cannot both be right
ANCHOR_AGREEMENT_M = 0.01   # epochs both fix within this of each other anchor the carrier-phase check
DECISIVE_RATIO = 2.0        # a fix is refuted when it misfits the anchors this many times more than the other
EPOCH_TOLERANCE_S = 0.05    # a .pos record belongs to the data epoch this close to it


@dataclass
class JudgedComparison:
    raw: Comparison              # compare_pos of the two solutions as they are
    judged: Comparison           # compare_pos after demoting the refuted fixes of both to float
    n_anchors: int
    n_apart: int                 # epochs both fix more than APART_M apart
    n_refuted_ours: int
    n_refuted_ref: int
    n_unjudged: int              # of n_apart: neither fix refuted (not judgeable, or not decisive)
    n_refuted_by_reverse: int = 0  # of the refuted: decided by the reverse passes (before chains), both sides
    refuted_ours_time_s: tuple = ()
    refuted_ref_time_s: tuple = ()

    def as_dict(self) -> dict:
        out = {k: v for k, v in self.__dict__.items() if not isinstance(v, Comparison)}
        out["raw"], out["judged"] = self.raw.as_dict(), self.judged.as_dict()
        return out


def positions_on_epochs(pos_file: PosFile, time_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF positions (E, 3) and fixed flags (E,) of a .pos file on the data epochs `time_s` (NaN / False
    where it has no record), and for each record the epoch index it belongs to (-1: none)."""
    best, dt = nearest_epochs(time_s, pos_file.time_s)
    ok = dt < EPOCH_TOLERANCE_S
    pos = np.full((len(time_s), 3), np.nan)
    fixed = np.zeros(len(time_s), dtype=bool)
    pos[best[ok]] = geodetic_to_ecef_m(np.radians(pos_file.lat_deg[ok]), np.radians(pos_file.lon_deg[ok]),
                                       pos_file.height_m[ok])
    fixed[best[ok]] = pos_file.status[ok] == 1
    return pos, fixed, np.where(ok, best, -1)


def _fixed_positions(pos_file: PosFile, time_s: np.ndarray) -> np.ndarray:
    """ECEF positions (E, 3) of a .pos file's fixed records on the data epochs; NaN elsewhere."""
    pos, fixed, _ = positions_on_epochs(pos_file, time_s)
    return np.where(fixed[:, None], pos, np.nan)


def _demoted(pos_file: PosFile, record_epoch: np.ndarray, refuted: np.ndarray) -> PosFile:
    status = pos_file.status.copy()
    hit = (record_epoch >= 0) & refuted[np.clip(record_epoch, 0, None)] & (status == 1)
    status[hit] = 2
    return replace(pos_file, status=status)


def _along_chains(refuted: np.ndarray, contested: np.ndarray, pair_rms_m: np.ndarray, barred: np.ndarray,
                  chain_m: float) -> np.ndarray:
    """`refuted` extended to the contested epochs joined to a refuted one by consecutive epoch pairs whose
    carrier-phase change confirms the solution's position change (pair_rms_m[e]: epochs e - 1 and e), never
    onto `barred` epochs (where the other solution's fix is refuted)."""
    out = refuted.copy()
    linked = np.zeros(len(out), dtype=bool)
    linked[1:] = contested[1:] & contested[:-1] & (pair_rms_m[1:] < chain_m)      # (e - 1, e) one chain
    for e in range(1, len(out)):                                                     # forward
        if linked[e] and out[e - 1] and not barred[e]:
            out[e] = True
    for e in range(len(out) - 2, -1, -1):                                            # backward
        if linked[e + 1] and out[e + 1] and not barred[e]:
            out[e] = True
    return out


def _refuted_by_reverse(a: np.ndarray, b: np.ndarray, a_rev: np.ndarray, b_rev: np.ndarray, undecided: np.ndarray,
                        agree_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(refuted a, refuted b) among the `undecided` epochs: a is refuted where b, b's own reverse pass and a's
    reverse pass agree pairwise within agree_m (NaN positions: not fixed, no agreement), and vice versa."""
    def close(x, y):
        with np.errstate(invalid="ignore"):
            return np.linalg.norm(x - y, axis=1) < agree_m

    b_side = close(b, b_rev) & close(b, a_rev) & close(b_rev, a_rev)
    a_side = close(a, a_rev) & close(a, b_rev) & close(a_rev, b_rev)
    return undecided & b_side & ~a_side, undecided & a_side & ~b_side


def judge_fixes(data: PreparedData, opts: RtkOptions, ours: PosFile, ref: PosFile,
                apart_m: float = APART_M, anchor_m: float = ANCHOR_AGREEMENT_M,
                decisive_ratio: float = DECISIVE_RATIO, chain_m: float = JUMP_THRESHOLD_M,
                ours_reverse: PosFile | None = None, ref_reverse: PosFile | None = None) -> JudgedComparison:
    """Compare `ours` with `ref` (both solutions of `data`, e.g. read from .pos files) as they are and
    after demoting the fixes the carrier phase refutes where the two part by more than `apart_m`.
    `ours_reverse`, `ref_reverse`: the same engines' solutions of the same data in the other direction
    (given only when `ours` and `ref` are forward or backward passes): witnesses where the carrier phase is
    not decisive (module docstring)."""
    a, a_fixed, a_rec = positions_on_epochs(ours, data.time_s)
    b, b_fixed, b_rec = positions_on_epochs(ref, data.time_s)
    both = a_fixed & b_fixed
    apart = np.full(len(data.time_s), np.nan)
    apart[both] = np.linalg.norm(a[both] - b[both], axis=1)
    anchors = np.nonzero(both & (apart < anchor_m))[0]
    far = both & (apart > apart_m)
    anchor_pos = np.where(both[:, None], 0.5 * (a + b), np.nan)
    refuted_a = np.zeros(len(data.time_s), dtype=bool)
    refuted_b = np.zeros(len(data.time_s), dtype=bool)
    n_by_reverse = 0
    if far.any() and len(anchors):
        rms_a, _ = anchored_rms_m(data, opts, a, far, anchor_pos, anchors)
        rms_b, _ = anchored_rms_m(data, opts, b, far, anchor_pos, anchors)
        fa, fb = np.isfinite(rms_a), np.isfinite(rms_b)
        refuted_a = far & fb & (~fa | (rms_a > decisive_ratio * rms_b))
        refuted_b = far & fa & (~fb | (rms_b > decisive_ratio * rms_a))
    if far.any() and ours_reverse is not None and ref_reverse is not None:
        rev_a, rev_b = _refuted_by_reverse(
            np.where(a_fixed[:, None], a, np.nan), np.where(b_fixed[:, None], b, np.nan),
            _fixed_positions(ours_reverse, data.time_s), _fixed_positions(ref_reverse, data.time_s),
            far & ~refuted_a & ~refuted_b, anchor_m)
        refuted_a |= rev_a
        refuted_b |= rev_b
        n_by_reverse = int(rev_a.sum() + rev_b.sum())
    if refuted_a.any():
        refuted_a = _along_chains(refuted_a, far, epoch_pair_rms_m(data, opts, a, a_fixed), refuted_b, chain_m)
    if refuted_b.any():
        refuted_b = _along_chains(refuted_b, far, epoch_pair_rms_m(data, opts, b, b_fixed), refuted_a, chain_m)
    n_unjudged = int(np.sum(far & ~refuted_a & ~refuted_b))
    t = data.time_s
    return JudgedComparison(
        raw=compare_pos(ours, ref),
        judged=compare_pos(_demoted(ours, a_rec, refuted_a), _demoted(ref, b_rec, refuted_b)),
        n_anchors=len(anchors), n_apart=int(far.sum()), n_refuted_ours=int(refuted_a.sum()),
        n_refuted_ref=int(refuted_b.sum()), n_unjudged=n_unjudged, n_refuted_by_reverse=n_by_reverse,
        refuted_ours_time_s=tuple(float(x) for x in t[refuted_a]),
        refuted_ref_time_s=tuple(float(x) for x in t[refuted_b]))
