"""Integer ambiguity resolution on the filter's single-difference ambiguity states (compiled with numba):
double differences per system and band against the best-determined member, MLAMBDA with the ratio test,
partial fixing, and the float solution conditioned on the integers.

Arrays: x (nx,) state, p (nx, nx) covariance, `active` the states with a positive variance (the others
have zero rows and columns), `pos_in[i]` the position of state i in `active` (-1 if inactive), `pairs`
(n, 2) state indices (ambiguity, reference ambiguity) of each double difference."""

from __future__ import annotations

import math

import numpy as np
from .kernel_loader import njit

from .lambda_kernels import integer_least_squares

MAX_SEARCH_NODES = 500_000      # lambda_search.DEFAULT_MAX_NODES
SINGULAR_RTOL = 1e-13           # lambda_search._SINGULAR_RTOL
UNCERTAIN_VARIANCE_FACTOR = 4.0  # partial fixing drops first the DDs whose variance exceeds 4x the median
MAX_UNDECIDED = 3               # ... then the DDs (at most 3) on which the two best candidates differ

FIX_OK, FIX_REJECTED, FIX_FAILED = 0, 1, 2


@njit(cache=True)
def dd_pairs(states, variance_key, elevation, group):
    """Double-difference pairs (state, reference state) per group; groups in order of first appearance,
    members in the given order. The reference is the member with the largest (variance_key, elevation),
    the first one on ties. Returns (pairs (n, 2), elevation of each pair's non-reference member)."""
    n = states.shape[0]
    pairs = np.empty((n, 2), np.int64)
    pair_el = np.empty(n)
    done = np.zeros(n, np.bool_)
    k = 0
    for g0 in range(n):
        if done[g0]:
            continue
        g = group[g0]
        ref = -1
        count = 0
        for i in range(g0, n):
            if group[i] == g:
                done[i] = True
                count += 1
                if ref < 0 or variance_key[i] > variance_key[ref] or (
                        variance_key[i] == variance_key[ref] and elevation[i] > elevation[ref]):
                    ref = i
        if count < 2:
            continue
        for i in range(g0, n):
            if group[i] == g and i != ref:
                pairs[k, 0] = states[i]
                pairs[k, 1] = states[ref]
                pair_el[k] = elevation[i]
                k += 1
    return pairs[:k], pair_el[:k]


@njit(cache=True)
def _success_rate(conditional_variances):
    """Bootstrapped success rate prod(2 Phi(1 / (2 sigma)) - 1) (lambda_search.bootstrap_success_rate)."""
    out = 1.0
    for v in conditional_variances:
        out *= math.erf(1.0 / (2.0 * math.sqrt(2.0) * math.sqrt(v)))
    return out


@njit(cache=True)
def try_fix(x, p, active, pos_in, pairs, threshold, min_success_rate):
    """MLAMBDA on the DDs `pairs`. Returns (outcome, ratio, x_fixed (nx,), position covariance (3, 3),
    integers (n,), undecided (n,) bool): outcome FIX_OK, FIX_REJECTED (ratio test or success rate; the
    undecided DDs are those where the two best candidates differ) or FIX_FAILED (the search failed).
    x_fixed, the covariance and the integers are meaningful only with FIX_OK (x itself is returned
    otherwise)."""
    n = pairs.shape[0]
    na = active.shape[0]
    if n == 0:
        return FIX_FAILED, 0.0, x, np.zeros((3, 3)), np.zeros(0, np.int64), np.zeros(0, np.bool_)
    a_float = np.empty(n)
    q_xa = np.empty((na, n))   # cov(states, DDs) = P_aa D^T
    for r in range(n):
        i, j = pairs[r, 0], pairs[r, 1]
        a_float[r] = x[i] - x[j]
        for u in range(na):
            q_xa[u, r] = p[active[u], i] - p[active[u], j]
    q_a = np.empty((n, n))
    for r in range(n):
        ir, jr = pos_in[pairs[r, 0]], pos_in[pairs[r, 1]]
        for k in range(n):
            q_a[r, k] = q_xa[ir, k] - q_xa[jr, k]
    for r in range(n):
        for k in range(r + 1):
            sym = 0.5 * (q_a[r, k] + q_a[k, r])
            q_a[r, k] = sym
            q_a[k, r] = sym
    undecided = np.zeros(n, np.bool_)
    no_cov = np.zeros((3, 3))
    ints, norms, found, dred = integer_least_squares(a_float, q_a, 2, MAX_SEARCH_NODES, SINGULAR_RTOL)
    if found < 0:
        return FIX_FAILED, 0.0, x, no_cov, np.zeros(n, np.int64), undecided
    ratio = norms[1] / norms[0] if found >= 2 and norms[0] > 0.0 else np.inf
    if not np.isfinite(ratio) and found < 2:
        ratio = 0.0
    passed = ratio >= threshold
    if passed and min_success_rate > 0.0:
        passed = _success_rate(dred) >= min_success_rate
    if not passed:
        if found >= 2:
            for k in range(n):
                undecided[k] = ints[0, k] != ints[1, k]
        return FIX_REJECTED, ratio, x, no_cov, ints[0], undecided
    # condition the float solution on the integers: x - Q_xa Q_a^-1 (a - a_fix); only the position
    # block of the conditioned covariance is needed
    rhs = np.empty((n, 4))
    for r in range(n):
        rhs[r, 0] = a_float[r] - ints[0, r]
        for c in range(3):
            rhs[r, 1 + c] = q_xa[pos_in[c], r]
    gain = np.linalg.solve(q_a, rhs)
    x_fixed = x.copy()
    cov_pos = np.empty((3, 3))
    for u in range(na):
        acc = 0.0
        for r in range(n):
            acc += q_xa[u, r] * gain[r, 0]
        x_fixed[active[u]] = x[active[u]] - acc
    for a in range(3):
        for b in range(3):
            acc = 0.0
            for r in range(n):
                acc += q_xa[pos_in[a], r] * gain[r, 1 + b]
            cov_pos[a, b] = p[a, b] - acc
    return FIX_OK, ratio, x_fixed, cov_pos, ints[0], undecided


@njit(cache=True)
def resolve(x, p, active, pos_in, pairs, pair_el, pair_sat, threshold, partial, max_drop, min_ambiguities,
            min_success_rate):
    """MLAMBDA on the DD ambiguities `pairs`. When the full set fails: drop at once those far less certain
    than the rest (float variance above 4x the median: newly tracked or recently slipped signals), then the
    lowest satellites one at a time (multipath, residual atmosphere), up to max_drop; after a failed search
    whose two best candidates differ in at most 3 DDs, the satellites of those undecided DDs (every band
    of them: ``pair_sat`` names each DD's satellite) are dropped next. A fix needs the
    ratio test and, when min_success_rate > 0, a bootstrapped success rate at least that high.
    Returns (fixed, ratio, x_fixed, position covariance, fixed pairs, their integers)."""
    n = pairs.shape[0]
    if n == 0:
        return False, 0.0, x, np.zeros((3, 3)), np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    var = np.empty(n)
    for k in range(n):
        i, j = pairs[k, 0], pairs[k, 1]
        var[k] = p[i, i] + p[j, j] - 2 * p[i, j]
    uncertain = var > UNCERTAIN_VARIANCE_FACTOR * np.median(var)
    order = np.argsort(pair_el, kind="mergesort")   # stable: ties (bands of one satellite) keep their order
    # the subsets to search, in order (rows of a membership mask)
    subsets = np.ones((2 + max_drop, n), np.bool_)
    n_sub = 1
    if partial:
        kept = ~uncertain
        if kept.sum() < n:
            subsets[n_sub] = kept
            n_sub += 1
        dropped = 0
        for k in order:
            if dropped >= max_drop:
                break
            if uncertain[k]:
                continue
            kept = kept.copy()
            kept[k] = False
            subsets[n_sub] = kept
            n_sub += 1
            dropped += 1
    best_ratio = 0.0
    n_try = 0
    next_sub = 0
    pending = np.zeros(n, np.bool_)
    have_pending = False
    while True:
        if have_pending:
            kept = pending
            have_pending = False
        elif next_sub < n_sub:
            kept = subsets[next_sub]
            next_sub += 1
        else:
            break
        if kept.sum() < min_ambiguities:
            break
        sub = pairs[kept]
        outcome, ratio, x_fixed, cov_pos, ints, undecided = try_fix(x, p, active, pos_in, sub, threshold,
                                                                     min_success_rate)
        if outcome == FIX_FAILED:
            break
        if n_try == 0:
            best_ratio = ratio
        n_try += 1
        if outcome == FIX_OK:
            return True, ratio, x_fixed, cov_pos, sub, ints
        n_undecided = undecided.sum()
        if partial and 0 < n_undecided <= MAX_UNDECIDED and n_try <= max_drop + 2:
            pending = kept.copy()
            for k in np.nonzero(kept)[0][undecided]:
                for m in range(n):
                    if pair_sat[m] == pair_sat[k]:
                        pending[m] = False
            have_pending = True
    return False, best_ratio, x, np.zeros((3, 3)), np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
