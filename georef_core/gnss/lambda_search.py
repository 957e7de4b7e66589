"""Integer least-squares ambiguity resolution: MLAMBDA reduction and search, ratio test, partial fixing.

Problem: given float ambiguities ``a`` (cycles) with covariance ``Q`` (cycles^2), find the integer
vectors ``z`` with the smallest squared norms ``(a - z)^T Q^-1 (a - z)``; the best ``m`` are returned.

Method (Chang, Yang & Zhou 2005, "MLAMBDA: a modified LAMBDA method for integer least-squares
estimation", J. Geodesy 79; building on Teunissen 1995, "The least-squares ambiguity decorrelation
adjustment: a method for fast GPS integer ambiguity estimation", J. Geodesy 70):

1. ``L^T D L`` factorisation of the (symmetrically permuted) covariance, ``L`` unit lower triangular.
   MLAMBDA's symmetric minimum pivoting (the index eliminated at each step, from the last down, is
   the one with the smallest remaining conditional variance) is available as
   ``ordering="min-pivot"``. The default ``"sorted"`` orders the indices by decreasing variance and
   factorises with one LAPACK Cholesky call: the pivoted factorisation needs n Python-level steps
   (about 0.5 ms at n = 20, against 10 us for LAPACK), more than the permutations it saves in step
   2 cost (measured on simulated DD float solutions: 205 against 235 permutations at n = 20). All
   orderings give the same search result.
2. Reduction (decorrelation) by a unimodular ``Z`` (integer Gauss transformations and symmetric
   permutations of adjacent pairs, ``Z^T Q Z = L^T D L``) until no swap of a pair ``(k, k+1)`` can
   lower ``D[k+1]``. As in MLAMBDA the Gauss transformation of ``L[k+1, k]`` is applied only when the
   swap test says the pair is permuted, and the other Gauss transformations are not applied: they
   change neither ``D`` nor the set of nodes the search visits (for fixed levels above, they shift
   the integers of a level by an integer), only the values in ``L``. They are applied all at once
   only if the unreduced entries grow past 1e6 (rare), to keep the search precise. After a swap the
   sweep resumes at the pair above (k + 1) instead of restarting from the end.
3. Depth-first search with a shrinking ellipsoid in Schnorr-Euchner (zig-zag) order: the first leaf
   is the bootstrapped solution; once ``m`` candidates are held the radius is the largest of their
   norms and shrinks whenever a better one replaces it. The conditional estimates are updated
   lazily (only the partial sums that changed since the level was last visited are recomputed, after
   Ghasemmehdi & Agrell 2011, "Faster recursions in sphere decoding"), so a node costs O(1) typically.

The norms are invariant under ``Z``. The transformation is not stored as a matrix: the integer
Gauss transformations and swaps are logged and replayed backwards on the few candidates.
The float vector is first split into its nearest integer and a fraction in [-0.5, 0.5] so that
large ambiguities (1e6 cycles and more) lose no precision. All arithmetic in steps 2 and 3 is scalar
Python: at the problem sizes of GNSS (n <= ~40) a numpy call costs more than a short Python loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.linalg.lapack import dpotrf

__all__ = [
    "LambdaResult",
    "PartialFixResult",
    "SearchLimitError",
    "ltdl_decompose",
    "mlambda_search",
    "partial_fix_subset",
    "ratio_test_passes",
]

# A conditional variance at or below this fraction of the largest variance is treated as singular.
_SINGULAR_RTOL = 1e-13
# The lazy reduction leaves most entries of L unreduced; they can grow (seen: 5e7 for n = 40). If
# any exceeds _GROWTH_LIMIT at the end (or _GROWTH_LIMIT_LOOP during the reduction) all Gauss
# transformations are applied, to protect the precision of the conditional estimates.
_GROWTH_LIMIT = 1e6
_GROWTH_LIMIT_LOOP = 1e9
# Default bound on the number of search-tree nodes (descents) before giving up.
DEFAULT_MAX_NODES = 500_000

Ordering = Literal["sorted", "min-pivot", "none"]


class SearchLimitError(ValueError):
    """The search visited more nodes than allowed (a very weak float solution); treat as not fixed."""


@dataclass(frozen=True)
class LambdaResult:
    """Outcome of an integer least-squares search.

    candidates: (m, n) int64 integer vectors in the caller's order, best first (cycles).
    squared_norms: (m,) squared distances ``(a - z)^T Q^-1 (a - z)`` (dimensionless), ascending.
    ratio: ``squared_norms[1] / squared_norms[0]`` (RTKLIB's ratio); ``inf`` when the best norm is
        exactly 0 or fewer than two candidates were asked for.
    """

    candidates: np.ndarray
    squared_norms: np.ndarray
    ratio: float
    success_rate: float = float("nan")   # bootstrapped success rate of the decorrelated problem

    @property
    def best(self) -> np.ndarray:
        """The integer least-squares solution, (n,) int64."""
        return self.candidates[0]


@dataclass(frozen=True)
class PartialFixResult:
    """Outcome of partial ambiguity resolution (see partial_fix_subset).

    kept: indices into the input vector of the subset searched last, ascending.
    dropped: indices removed, in the order they were removed.
    result: the search result on ``kept`` (``None`` when no search succeeded).
    fixed: True when the ratio test passed on ``kept``.
    """

    kept: np.ndarray
    dropped: np.ndarray
    result: LambdaResult | None
    fixed: bool

    def fixed_ambiguities(self) -> np.ndarray:
        """Best integers for ``kept`` (int64, cycles); empty when not fixed."""
        if not self.fixed or self.result is None:
            return np.zeros(0, dtype=np.int64)
        return self.result.best


def _validate(float_amb, cov) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(float_amb, dtype=float)
    q = np.asarray(cov, dtype=float)
    if a.ndim != 1 or a.size == 0:
        raise ValueError(f"float ambiguities must be a non-empty 1-D array, got shape {a.shape}")
    n = a.size
    if q.shape != (n, n):
        raise ValueError(f"ambiguity covariance must have shape ({n}, {n}), got {q.shape}")
    if not math.isfinite(float(a.sum()) + float(q.sum())):
        raise ValueError("float ambiguities or their covariance contain NaN or infinity")
    if n > 1 and float(np.abs(q - q.T).max()) > 1e-9 * float(np.abs(q).max()):
        raise ValueError("ambiguity covariance is not symmetric")
    return a, q


def _not_pd(detail: str) -> ValueError:
    return ValueError(f"ambiguity covariance is not positive definite ({detail})")


def ltdl_decompose(cov: np.ndarray, pivot: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``Q[perm][:, perm] = L^T diag(D) L`` factorisation (L unit lower triangular).

    Args:
        cov: (n, n) symmetric positive-definite matrix (cycles^2).
        pivot: MLAMBDA symmetric minimum pivoting: eliminating from the last index down, each step
            takes the remaining index with the smallest conditional variance. Without it ``perm``
            is the identity and the factorisation is one LAPACK Cholesky call.

    Returns:
        (L (n, n), D (n,) conditional variances, perm (n,) int).

    Raises:
        ValueError: the matrix is not (numerically) positive definite.
    """
    q = np.asarray(cov, dtype=float)
    n = q.shape[0]
    tol = _SINGULAR_RTOL * max(float(np.max(np.abs(np.diagonal(q)))), 1e-300)
    if not pivot:
        lmat, d = _ltdl_lapack(q)
        if not np.all(d > tol):
            raise _not_pd(f"smallest conditional variance {float(np.min(d)):.3e}")
        return lmat, d, np.arange(n)
    a = q.copy()  # working copy, overwritten by Schur complements
    perm = np.arange(n)
    lmat = np.zeros((n, n))
    d = np.empty(n)
    diag = np.einsum("ii->i", a)  # writable view of the diagonal
    for k in range(n - 1, -1, -1):
        if k > 0:
            p = int(np.argmin(diag[: k + 1]))
            if p != k:
                a[[p, k], : k + 1] = a[[k, p], : k + 1]
                a[: k + 1, [p, k]] = a[: k + 1, [k, p]]
                lmat[k + 1 :, [p, k]] = lmat[k + 1 :, [k, p]]
                perm[[p, k]] = perm[[k, p]]
        dk = a[k, k]
        if not dk > tol:
            raise _not_pd(f"conditional variance {dk:.3e} at elimination step {n - k}")
        d[k] = dk
        row = a[k, :k]
        lrow = row / dk
        lmat[k, :k] = lrow
        lmat[k, k] = 1.0
        if k:
            a[:k, :k] -= np.multiply.outer(lrow, row)
    return lmat, d, perm


def _ltdl_lapack(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unpivoted ``Q = L^T D L`` through the Cholesky factor of the index-reversed matrix."""
    c, info = dpotrf(q[::-1, ::-1], lower=1)  # R Q R = C C^T, R the reversal
    if info != 0:
        raise _not_pd("Cholesky factorisation failed")
    u = c[::-1, ::-1]  # Q = U U^T, U upper triangular
    ud = np.diagonal(u).copy()
    return (u / ud).T, ud * ud


def _reduce(rows: list[list[float]], d: list[float], zhat: list[float], ops: list[tuple[int, int, int]]) -> None:
    """MLAMBDA reduction, in place on the strictly-lower rows of L, D and the transformed floats.

    ``rows[i]`` holds ``L[i, :i]``. Every transformation is appended to ``ops`` as ``(j, i, mu)``:
    an integer Gauss transformation (column j of Z minus mu times column i) when mu != 0, the swap
    of j and i = j + 1 when mu == 0.
    """
    n = len(d)
    log = ops.append
    k = n - 2
    while k >= 0:
        rk1 = rows[k + 1]
        ell = rk1[k]
        mu = round(ell)
        lf = ell - mu  # L[k+1, k] after the integer Gauss transformation
        dk = d[k]
        dk1 = d[k + 1]
        delta = dk + lf * lf * dk1  # D[k+1] after a swap
        if delta < dk1:
            k1 = k + 1
            if mu:
                # Gauss transformation: column k of Z (and of L) minus mu times column k+1; in the
                # rows below k+1 it is done together with the column swap
                zhat[k] -= mu * zhat[k1]
                log((k, k1, mu))
                for row in rows[k + 2 :]:
                    a0 = row[k]
                    b0 = row[k1]
                    row[k] = b0
                    row[k1] = a0 - mu * b0
            else:
                for row in rows[k + 2 :]:
                    row[k], row[k1] = row[k1], row[k]
            eta = dk / delta
            lam = dk1 * lf / delta
            d[k] = eta * dk1
            d[k1] = delta
            rk = rows[k]
            # rows k and k+1 of L after the symmetric swap
            rows[k] = [b - lf * a for a, b in zip(rk, rk1)]
            new_k1 = [eta * a + lam * b for a, b in zip(rk, rk1)]
            new_k1.append(lam)
            rows[k1] = new_k1
            zhat[k], zhat[k1] = zhat[k1], zhat[k]
            log((k, k1, 0))
            if (lam > 1.0 or lam < -1.0) and k and max(map(abs, new_k1)) > _GROWTH_LIMIT_LOOP:
                _size_reduce(rows, zhat, ops)  # rare: keep the unreduced entries of L bounded
            if k < n - 2:
                k = k1
        else:
            k -= 1
    if max((abs(x) for row in rows for x in row), default=0.0) > _GROWTH_LIMIT:
        _size_reduce(rows, zhat, ops)


def _size_reduce(rows: list[list[float]], zhat: list[float], ops: list[tuple[int, int, int]]) -> None:
    """All integer Gauss transformations, |L[i, j]| <= 1/2 below the diagonal (in place, logged).

    Not needed by the search (it visits the same nodes either way); used only when the lazily
    unreduced entries of L have grown large enough to cost precision.
    """
    n = len(rows)
    log = ops.append
    for j in range(n - 2, -1, -1):
        for i in range(j + 1, n):
            mu = round(rows[i][j])
            if mu:
                rows[i][j] -= mu
                for row in rows[i + 1 :]:
                    row[j] -= mu * row[i]
                zhat[j] -= mu * zhat[i]
                log((j, i, mu))


def _search(
    rows: list[list[float]], d: list[float], zhat: list[float], m: int, max_nodes: int
) -> list[tuple[float, list[float]]]:
    """Shrinking-ellipsoid depth-first search for the m best integer vectors, sorted by norm.

    Minimises sum_k (z_k - zb_k)^2 / d_k with the conditional estimates
    zb_k = zhat_k + sum_{i>k} L[i, k] (z_i - zb_i), starting at the last level. ``part[j][i]``
    caches sum_{i' >= i} L[i', j] (z_i' - zb_i') and ``stale[j]`` is the highest level changed since
    ``part[j]`` was last brought up to date.
    """
    n = len(d)
    dinv = [1.0 / v for v in d]
    part = [[0.0] * (n + 1) for _ in range(n)]
    stale = [n - 1] * n
    zb = [0.0] * n
    z = [0.0] * n
    y = [0.0] * n
    step = [0.0] * n
    dist = [0.0] * n
    cands: list[tuple[float, list[float]]] = []
    maxdist = float("inf")
    nodes = 0
    rint = round
    top = n - 1

    k = top
    zb[k] = zbk = zhat[k]
    z[k] = zk = float(rint(zbk))
    dz = zbk - zk
    step[k] = -1.0 if dz <= 0.0 else 1.0
    while True:
        newdist = dist[k] + dz * dz * dinv[k]
        if newdist < maxdist:
            if k:
                # descend to level j = k - 1: bring part[j] up to date from the highest changed level
                nodes += 1
                if nodes > max_nodes:
                    raise SearchLimitError(f"integer search exceeded {max_nodes} nodes (n = {n})")
                yk = y[k] = zk - zbk
                j = k - 1
                pj = part[j]
                hi = stale[j]
                if hi <= k:
                    hi = k
                    acc = pj[k] = pj[k + 1] + rows[k][j] * yk
                else:
                    acc = pj[hi + 1]
                    for i in range(hi, j, -1):
                        acc += rows[i][j] * y[i]
                        pj[i] = acc
                if j and stale[j - 1] < hi:
                    stale[j - 1] = hi
                stale[j] = j
                k = j
                dist[k] = newdist
                zb[k] = zbk = zhat[k] + acc
                z[k] = zk = float(rint(zbk))
                dz = zbk - zk
                step[k] = -1.0 if dz <= 0.0 else 1.0
                continue
            # a leaf: new candidate
            if len(cands) < m:
                cands.append((newdist, z[:]))
                if len(cands) == m:
                    cands.sort(key=_norm_key)
                    maxdist = cands[-1][0]
            else:
                cands[-1] = (newdist, z[:])
                cands.sort(key=_norm_key)
                maxdist = cands[-1][0]
            # next integer at level 0 in zig-zag order
            s = step[0]
            z[0] = zk = zk + s
            dz = zbk - zk
            step[0] = -s - 1.0 if s > 0.0 else 1.0 - s
        else:
            if k == top:
                break
            k += 1
            s = step[k]
            zbk = zb[k]
            z[k] = zk = z[k] + s
            dz = zbk - zk
            step[k] = -s - 1.0 if s > 0.0 else 1.0 - s
    cands.sort(key=_norm_key)
    return cands


def _norm_key(c: tuple[float, list[float]]) -> float:
    return c[0]


def _back_transform(zvec: list[float], ops: list[tuple[int, int, int]]) -> list[int]:
    """Z^-T z for one integer vector (before the initial permutation), replaying the log backwards."""
    v = [int(x) for x in zvec]
    for j, i, mu in reversed(ops):
        if mu:
            v[j] += mu * v[i]
        else:
            v[j], v[i] = v[i], v[j]
    return v


def mlambda_search(
    float_amb: np.ndarray,
    cov: np.ndarray,
    n_candidates: int = 2,
    ordering: Ordering = "sorted",
    max_nodes: int = DEFAULT_MAX_NODES,
    engine: Literal["compiled", "python"] = "compiled",
) -> LambdaResult:
    """Integer least-squares estimate of the ambiguities with the MLAMBDA method.

    Args:
        float_amb: (n,) float ambiguities (cycles).
        cov: (n, n) their covariance (cycles^2), symmetric positive definite.
        n_candidates: number m >= 1 of best integer vectors to return.
        ordering: initial symmetric permutation before the reduction: "sorted" (decreasing
            variance, LAPACK factorisation; default, fastest), "min-pivot" (MLAMBDA minimum
            pivoting) or "none". The result does not depend on it.
        max_nodes: bound on the search-tree size; beyond it SearchLimitError is raised.
        engine: "compiled" (numba kernels of lambda_kernels.py: the same lazy MLAMBDA reduction,
            RTKLIB-style search; ~50x faster at n = 60) or "python" (the lazy MLAMBDA reduction and
            Schnorr-Euchner search of this module, kept as the reference implementation).

    Returns:
        LambdaResult with candidates (m, n) int64 best first, their squared norms and the
        ratio ``norm[1] / norm[0]``.

    Raises:
        ValueError: bad shapes, non-finite values, an asymmetric or non-positive-definite
            covariance; SearchLimitError (a ValueError) when the search is too large.
    """
    a, q = _validate(float_amb, cov)
    m = int(n_candidates)
    if m < 1:
        raise ValueError(f"n_candidates must be >= 1, got {n_candidates}")
    n = a.size
    if ordering == "min-pivot":
        lmat, d, perm = ltdl_decompose(q, pivot=True)
    elif ordering == "sorted" or ordering == "none":
        perm = np.argsort(-np.diagonal(q), kind="stable") if ordering == "sorted" else np.arange(n)
        lmat, d = _ltdl_lapack(q.take(perm, 0).take(perm, 1))
    else:
        raise ValueError(f"unknown ordering {ordering!r}")
    dl = d.tolist()
    if not min(dl) > _SINGULAR_RTOL * max(q.diagonal().tolist()):
        raise _not_pd(f"smallest conditional variance {min(dl):.3e}")
    if engine == "compiled":
        return _search_compiled(a, lmat, d, perm, m, max_nodes)
    rows = [r[:i] for i, r in enumerate(lmat.tolist())]
    a_perm = a.take(perm).tolist()
    a_int = [math.floor(v + 0.5) for v in a_perm]  # integer part, kept out of the search
    zhat = [v - i for v, i in zip(a_perm, a_int)]
    ops: list[tuple[int, int, int]] = []
    _reduce(rows, dl, zhat, ops)
    if min(dl) <= 0.0:
        raise _not_pd("non-positive conditional variance after reduction")
    cands = _search(rows, dl, zhat, m, max_nodes)
    perm_l = perm.tolist()
    out = []
    for _, zv in cands:
        v = _back_transform(zv, ops)
        row = [0] * n
        for j, p in enumerate(perm_l):
            row[p] = v[j] + a_int[j]
        out.append(row)
    ints = np.array(out, dtype=np.int64)
    norms = np.array([c[0] for c in cands])
    ratio = float(norms[1] / norms[0]) if m >= 2 and norms[0] > 0.0 else float("inf")
    return LambdaResult(candidates=ints, squared_norms=norms, ratio=ratio, success_rate=bootstrap_success_rate(dl))


def _search_compiled(a, lmat, d, perm, m, max_nodes) -> LambdaResult:
    from .lambda_kernels import search_from_ltdl

    lc = np.ascontiguousarray(lmat, dtype=float)
    dc = np.ascontiguousarray(d, dtype=float)
    ints, norms, found, dred = search_from_ltdl(np.ascontiguousarray(a.take(perm)), lc, dc, m, max_nodes,
                                                _GROWTH_LIMIT, _GROWTH_LIMIT_LOOP, np.asarray(perm, dtype=np.int64))
    if found == -2:
        raise _not_pd("non-positive conditional variance after reduction")
    if found < 0:
        raise SearchLimitError(f"search exceeded {max_nodes} nodes (weak float solution)")
    ratio = float(norms[1] / norms[0]) if found >= 2 and norms[0] > 0.0 else float("inf")
    return LambdaResult(candidates=ints, squared_norms=norms, ratio=ratio, success_rate=bootstrap_success_rate(dred))


def bootstrap_success_rate(conditional_variances) -> float:
    """Probability that integer bootstrapping of the decorrelated problem picks the right integers:
    prod_i (2 Phi(1 / (2 sigma_i)) - 1), sigma_i^2 the conditional variances (Teunissen 1998). It is a
    lower bound of the integer least-squares success rate, so a threshold on it is conservative."""
    from scipy.special import erf

    sig = np.sqrt(np.asarray(conditional_variances, dtype=float))
    return float(np.prod(erf(1.0 / (2.0 * np.sqrt(2.0) * sig))))


def ratio_test_passes(result: LambdaResult, threshold: float) -> bool:
    """RTKLIB-style ratio test: second-best over best squared norm >= threshold (e.g. 3.0).

    A best norm of exactly 0 passes (ratio inf), as in RTKLIB. Needs a search with >= 2 candidates.
    """
    if result.squared_norms.size < 2:
        raise ValueError("the ratio test needs a search with n_candidates >= 2")
    return bool(result.ratio >= threshold)


def partial_fix_subset(
    float_amb: np.ndarray,
    cov: np.ndarray,
    order_by: np.ndarray,
    threshold: float,
    min_ambiguities: int,
) -> PartialFixResult:
    """Partial ambiguity resolution by removing the weakest ambiguities one at a time.

    Strategy: search the full set; while the ratio test fails (or the search gives up) and more
    than ``min_ambiguities`` remain, drop the remaining ambiguity with the smallest ``order_by``
    value and search again on the marginal distribution of the rest (sub-vector and sub-matrix of
    ``cov``: the dropped ambiguities simply stay float). ``order_by`` is a quality score, lowest
    dropped first: pass the elevation (radians) to drop low satellites first, or ``-np.diag(cov)``
    to drop the most uncertain first; ties go to the lower index. Stops at the first subset that
    passes, or when the next drop would leave fewer than ``min_ambiguities``.

    Args:
        float_amb: (n,) float ambiguities (cycles).
        cov: (n, n) covariance (cycles^2).
        order_by: (n,) score per ambiguity, lowest = worst.
        threshold: ratio-test threshold (e.g. 3.0).
        min_ambiguities: smallest subset size that is still searched (>= 1).

    Returns:
        PartialFixResult; ``fixed`` tells whether the last subset searched passed.
    """
    a, q = _validate(float_amb, cov)
    score = np.asarray(order_by, dtype=float)
    if score.shape != a.shape:
        raise ValueError(f"order_by must have shape {a.shape}, got {score.shape}")
    min_n = max(1, int(min_ambiguities))
    drop_order = [int(i) for i in np.lexsort((np.arange(a.size), score))]  # worst first
    kept = np.arange(a.size)
    dropped: list[int] = []
    last: LambdaResult | None = None
    while kept.size >= min_n:
        try:
            last = mlambda_search(a[kept], q[np.ix_(kept, kept)], 2)
        except SearchLimitError:
            last = None
        if last is not None and ratio_test_passes(last, threshold):
            return PartialFixResult(kept, np.asarray(dropped, dtype=np.int64), last, True)
        if kept.size - 1 < min_n:
            break
        worst = drop_order.pop(0)
        dropped.append(worst)
        kept = kept[kept != worst]
    return PartialFixResult(kept, np.asarray(dropped, dtype=np.int64), last, False)
