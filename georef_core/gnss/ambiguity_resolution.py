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


def dd_pairs(amb_states: list[int], elevation: list[float], group: list[tuple]) -> list[tuple[int, int]]:
    """Pairs (state, reference state) per group, the reference being the highest satellite of the group."""
    pairs: list[tuple[int, int]] = []
    by_group: dict[tuple, list[int]] = {}
    for k, g in enumerate(group):
        by_group.setdefault(g, []).append(k)
    for members in by_group.values():
        if len(members) < 2:
            continue
        ref = max(members, key=lambda k: elevation[k])
        for k in members:
            if k != ref:
                pairs.append((amb_states[k], amb_states[ref]))
    return pairs


def _try_fix(x: np.ndarray, p: np.ndarray, active: np.ndarray, pairs: list[tuple[int, int]], threshold: float):
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
    if ratio < threshold:
        return ratio, None
    a_fix = np.asarray(res.candidates[0], dtype=float)
    try:
        gain = np.linalg.solve(q_a, np.column_stack([a_float - a_fix, q_xa.T]))
    except np.linalg.LinAlgError:
        return None
    x_fix = xa - q_xa @ gain[:, 0]
    p_fix = pa - q_xa @ gain[:, 1:]
    return ratio, (x_fix, p_fix, a_fix)


def resolve(x: np.ndarray, p: np.ndarray, active: np.ndarray, pairs: list[tuple[int, int]], pair_elev: list[float],
            threshold: float, partial: bool, max_drop: int, min_ambiguities: int) -> FixResult:
    """MLAMBDA on the DD ambiguities `pairs`; on failure, drop DD ambiguities one at a time: first those
    far less certain than the rest (float variance above 4x the median: newly tracked or recently slipped
    signals, largest first), then the lowest satellites (multipath, residual atmosphere)."""
    var = np.array([p[i, i] + p[j, j] - 2 * p[i, j] for i, j in pairs])
    elev = np.asarray(pair_elev)
    uncertain = var > 4.0 * np.median(var)
    order = [int(k) for k in np.argsort(-var) if uncertain[k]] + [int(k) for k in np.argsort(elev) if not uncertain[k]]
    kept = list(range(len(pairs)))
    best_ratio = 0.0
    for n_drop in range(0, (max_drop if partial else 0) + 1):
        if len(kept) < min_ambiguities:
            break
        sub = [pairs[k] for k in kept]
        out = _try_fix(x, p, active, sub, threshold)
        if out is None:
            break
        ratio, fixed = out
        best_ratio = max(best_ratio, ratio) if n_drop == 0 else best_ratio
        if fixed is not None:
            x_fix, p_fix, a_fix = fixed
            xf = x.copy()
            xf[active] = x_fix
            pf = p.copy()
            pf[np.ix_(active, active)] = p_fix
            return FixResult(True, ratio, xf, pf, sub, a_fix, n_drop)
        if n_drop == 0:
            best_ratio = ratio
        # drop the lowest remaining
        lowest = next(k for k in order if k in kept)
        kept.remove(lowest)
    return FixResult(False, best_ratio, None, None, [], None)
