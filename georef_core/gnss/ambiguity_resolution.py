"""Integer ambiguity resolution on the filter's single-difference ambiguity states: double differences
per system and band (reference = highest eligible satellite), MLAMBDA search with ratio-test
validation, partial fixing (dropping the lowest satellites) and the fixed-solution update."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .lambda_search import mlambda_search


@dataclass
class FixResult:
    fixed: bool
    ratio: float
    x_fixed: np.ndarray | None       # full state, ambiguities at their fixed (float-conditioned) values
    p_fixed: np.ndarray | None       # covariance of the conditioned state (ambiguities ~0)
    dd_rows: list[tuple[int, int]]   # (state index of satellite, state index of reference) per fixed DD
    dd_integers: np.ndarray | None
    n_dropped: int = 0


def dd_pairs(amb_states: list[int], preference: list, group: list[tuple]) -> list[tuple[int, int]]:
    """Pairs (state, reference state) per group, the reference being the member with the largest
    `preference` (for AR: the best-determined ambiguity, then the highest satellite)."""
    pairs: list[tuple[int, int]] = []
    by_group: dict[tuple, list[int]] = {}
    for k, g in enumerate(group):
        by_group.setdefault(g, []).append(k)
    for members in by_group.values():
        if len(members) < 2:
            continue
        ref = max(members, key=lambda k: preference[k])
        for k in members:
            if k != ref:
                pairs.append((amb_states[k], amb_states[ref]))
    return pairs


def _try_fix(x: np.ndarray, p: np.ndarray, active: np.ndarray, pairs: list[tuple[int, int]], threshold: float,
             min_success_rate: float = 0.0):
    n = len(pairs)
    pos_in = {s: i for i, s in enumerate(active)}
    d = np.zeros((n, len(active)))
    for r, (i, j) in enumerate(pairs):
        d[r, pos_in[i]] = 1.0
        d[r, pos_in[j]] = -1.0
    xa = x[active]
    pa = p[np.ix_(active, active)]
    a_float = d @ xa
    q_xa = pa @ d.T
    q_a = d @ q_xa
    q_a = 0.5 * (q_a + q_a.T)
    try:
        res = mlambda_search(a_float, q_a, 2)
    except (ValueError, np.linalg.LinAlgError):
        return None
    ratio = float(res.ratio)
    if not np.isfinite(ratio) and len(res.squared_norms) < 2:
        ratio = 0.0
    if ratio < threshold or not res.success_rate >= min_success_rate:
        undecided = []
        if len(res.candidates) >= 2:
            undecided = [int(k) for k in np.nonzero(res.candidates[0] != res.candidates[1])[0]]
        return ratio, None, undecided
    a_fix = np.asarray(res.candidates[0], dtype=float)
    try:
        gain = np.linalg.solve(q_a, np.column_stack([a_float - a_fix, q_xa.T]))
    except np.linalg.LinAlgError:
        return None
    x_fix = xa - q_xa @ gain[:, 0]
    p_fix = pa - q_xa @ gain[:, 1:]
    return ratio, (x_fix, p_fix, a_fix), []


def resolve(x: np.ndarray, p: np.ndarray, active: np.ndarray, pairs: list[tuple[int, int]], pair_elev: list[float],
            threshold: float, partial: bool, max_drop: int, min_ambiguities: int,
            min_success_rate: float = 0.0) -> FixResult:
    """MLAMBDA on the DD ambiguities `pairs`. When the full set fails: drop at once those far less certain
    than the rest (float variance above 4x the median: newly tracked or recently slipped signals), then
    the lowest satellites one at a time (multipath, residual atmosphere), up to max_drop. A fix needs the
    ratio test and, when min_success_rate > 0, a bootstrapped success rate at least that high."""
    var = np.array([p[i, i] + p[j, j] - 2 * p[i, j] for i, j in pairs])
    elev = np.asarray(pair_elev)
    uncertain = var > 4.0 * np.median(var)
    by_elevation = [int(k) for k in np.argsort(elev) if not uncertain[k]]
    subsets = [list(range(len(pairs)))]
    if partial:
        kept = [k for k in range(len(pairs)) if not uncertain[k]]
        if len(kept) < len(pairs):
            subsets.append(kept)
        for k in by_elevation[:max_drop]:
            kept = [j for j in kept if j != k]
            subsets.append(kept)
    best_ratio = 0.0
    n_try = 0
    while subsets:
        kept = subsets.pop(0)
        if len(kept) < min_ambiguities:
            break
        sub = [pairs[k] for k in kept]
        out = _try_fix(x, p, active, sub, threshold, min_success_rate)
        if out is None:
            break
        ratio, fixed, undecided = out
        if n_try == 0:
            best_ratio = ratio
        n_try += 1
        if fixed is not None:
            x_fix, p_fix, a_fix = fixed
            xf = x.copy()
            xf[active] = x_fix
            pf = p.copy()
            pf[np.ix_(active, active)] = p_fix
            return FixResult(True, ratio, xf, pf, sub, a_fix, len(pairs) - len(kept))
        if partial and undecided and len(undecided) <= 3 and n_try <= max_drop + 2:
            # the ambiguities on which the two best candidates differ are those the data leave undecided
            subsets.insert(0, [k for i, k in enumerate(kept) if i not in set(undecided)])
    return FixResult(False, best_ratio, None, None, [], None)
