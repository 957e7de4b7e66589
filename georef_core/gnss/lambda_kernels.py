"""Compiled (numba) kernels of the integer least-squares search used by lambda_search.mlambda_search and
by the filter's ambiguity resolution: LTDL factorisation, MLAMBDA reduction (integer Gauss transformations
and adjacent permutations of Q = L^T D L, applied lazily as in lambda_search._reduce and logged rather than
accumulated in a matrix), the depth-first shrinking-ellipsoid search for the m best integer vectors, and
the back-transformation of the candidates by replaying the log. Arrays are float64."""

from __future__ import annotations

import numpy as np
from .kernel_loader import njit

# The lazy reduction leaves most entries of L unreduced; beyond these sizes all Gauss transformations are
# applied (lambda_search._GROWTH_LIMIT and _GROWTH_LIMIT_LOOP).
GROWTH_LIMIT = 1e6
GROWTH_LIMIT_LOOP = 1e9


@njit(cache=True)
def _grown(ops):
    """The log (rows (j, i, mu)) with twice the room."""
    bigger = np.empty((2 * ops.shape[0], 3))
    bigger[:ops.shape[0]] = ops
    return bigger


@njit(cache=True)
def _size_reduce(lmat, zhat, ops, n_ops):
    """All integer Gauss transformations, |L[i, j]| <= 1/2 below the diagonal (in place, logged). Not needed by
    the search; applied only when the lazily unreduced entries of L have grown large enough to cost precision."""
    n = lmat.shape[0]
    for j in range(n - 2, -1, -1):
        for i in range(j + 1, n):
            mu = np.rint(lmat[i, j])
            if mu != 0.0:
                for r in range(i, n):
                    lmat[r, j] -= mu * lmat[r, i]
                zhat[j] -= mu * zhat[i]
                if n_ops == ops.shape[0]:
                    ops = _grown(ops)
                ops[n_ops, 0], ops[n_ops, 1], ops[n_ops, 2] = j, i, mu
                n_ops += 1
    return ops, n_ops


@njit(cache=True)
def reduce_lazy(lmat, d, zhat, growth_limit, growth_limit_loop):
    """MLAMBDA reduction in place on L (unit lower triangular), D and the transformed floats zhat, the kernel
    form of lambda_search._reduce: the Gauss transformation of L[k+1, k] is applied only when the pair
    (k, k+1) is swapped, and after a swap the sweep resumes at the pair above. Returns the log (n_ops, 3):
    rows (j, i, mu), an integer Gauss transformation (column j of Z minus mu times column i) when mu != 0, the
    swap of j and i = j + 1 when mu == 0."""
    n = d.shape[0]
    ops = np.empty((8 * n * n + 8, 3))
    n_ops = 0
    k = n - 2
    while k >= 0:
        k1 = k + 1
        ell = lmat[k1, k]
        mu = np.rint(ell)
        lf = ell - mu  # L[k+1, k] after the integer Gauss transformation
        dk = d[k]
        dk1 = d[k1]
        delta = dk + lf * lf * dk1  # D[k+1] after a swap
        if delta < dk1:
            if mu != 0.0:
                # Gauss transformation of column k, done together with the column swap in the rows below k+1
                zhat[k] -= mu * zhat[k1]
                if n_ops == ops.shape[0]:
                    ops = _grown(ops)
                ops[n_ops, 0], ops[n_ops, 1], ops[n_ops, 2] = k, k1, mu
                n_ops += 1
                for r in range(k + 2, n):
                    a0 = lmat[r, k]
                    b0 = lmat[r, k1]
                    lmat[r, k] = b0
                    lmat[r, k1] = a0 - mu * b0
            else:
                for r in range(k + 2, n):
                    a0 = lmat[r, k]
                    lmat[r, k] = lmat[r, k1]
                    lmat[r, k1] = a0
            eta = dk / delta
            lam = dk1 * lf / delta
            d[k] = eta * dk1
            d[k1] = delta
            # rows k and k+1 of L after the symmetric swap
            big = 0.0
            for c in range(k):
                a = lmat[k, c]
                b = lmat[k1, c]
                lmat[k, c] = b - lf * a
                lmat[k1, c] = eta * a + lam * b
                big = max(big, abs(lmat[k1, c]))
            lmat[k1, k] = lam
            big = max(big, abs(lam))
            t = zhat[k]
            zhat[k] = zhat[k1]
            zhat[k1] = t
            if n_ops == ops.shape[0]:
                ops = _grown(ops)
            ops[n_ops, 0], ops[n_ops, 1], ops[n_ops, 2] = k, k1, 0.0
            n_ops += 1
            if (lam > 1.0 or lam < -1.0) and k and big > growth_limit_loop:
                ops, n_ops = _size_reduce(lmat, zhat, ops, n_ops)  # rare: keep the unreduced entries bounded
            if k < n - 2:
                k = k1
        else:
            k -= 1
    big = 0.0
    for r in range(n):
        for c in range(r):
            big = max(big, abs(lmat[r, c]))
    if big > growth_limit:
        ops, n_ops = _size_reduce(lmat, zhat, ops, n_ops)
    return ops[:n_ops]


@njit(cache=True)
def back_transform(v, ops):
    """In place: v <- Z^-T v for one integer vector (back to the order before the reduction), replaying the
    log backwards."""
    for q in range(ops.shape[0] - 1, -1, -1):
        j, i, mu = int(ops[q, 0]), int(ops[q, 1]), ops[q, 2]
        if mu != 0.0:
            v[j] += mu * v[i]
        else:
            t = v[j]
            v[j] = v[i]
            v[i] = t


@njit(cache=True)
def search_best(lmat, d, zs, m, max_nodes):
    """m best integer vectors (columns of the returned (n, m) array) and their squared norms, best first.
    Returns n_found < m when the tree had fewer leaves; raises nothing (node limit -> n_found = -1)."""
    n = d.shape[0]
    s_mat = np.zeros((n, n))
    work = np.zeros((4, n))
    dist, zb, z, step = work[0], work[1], work[2], work[3]
    zn = np.zeros((n, m))
    s = np.zeros(m)
    nn = 0
    imax = 0
    maxdist = 1e99
    k = n - 1
    zb[k] = zs[k]
    z[k] = np.floor(zb[k] + 0.5)
    y = zb[k] - z[k]
    step[k] = 1.0 if y > 0 else -1.0
    for _ in range(max_nodes):
        newdist = dist[k] + y * y / d[k]
        if newdist < maxdist:
            if k != 0:
                k -= 1
                dist[k] = newdist
                for i in range(k + 1):
                    s_mat[k, i] = s_mat[k + 1, i] + (z[k + 1] - zb[k + 1]) * lmat[k + 1, i]
                zb[k] = zs[k] + s_mat[k, k]
                z[k] = np.floor(zb[k] + 0.5)
                y = zb[k] - z[k]
                step[k] = 1.0 if y > 0 else -1.0
            else:
                if nn < m:
                    if nn == 0 or newdist > s[imax]:
                        imax = nn
                    zn[:, nn] = z
                    s[nn] = newdist
                    nn += 1
                    if nn == m:
                        maxdist = s[imax]
                else:
                    if newdist < s[imax]:
                        zn[:, imax] = z
                        s[imax] = newdist
                        imax = 0
                        for i in range(m):
                            if s[imax] < s[i]:
                                imax = i
                    maxdist = s[imax]
                z[0] += step[0]
                y = zb[0] - z[0]
                step[0] = -step[0] - (1.0 if step[0] > 0 else -1.0)
        else:
            if k == n - 1:
                # best first (insertion sort of the few candidates, in place)
                for a in range(1, nn):
                    b = a
                    while b > 0 and s[b] < s[b - 1]:
                        s[b], s[b - 1] = s[b - 1], s[b]
                        for i in range(n):
                            zn[i, b], zn[i, b - 1] = zn[i, b - 1], zn[i, b]
                        b -= 1
                return zn, s, nn
            k += 1
            z[k] += step[k]
            y = zb[k] - z[k]
            step[k] = -step[k] - (1.0 if step[k] > 0 else -1.0)
    return zn, s, -1


@njit(cache=True)
def ltdl_from_last(q):
    """Q = L^T diag(D) L with L unit lower triangular, eliminating from the last index down (the
    factorisation MLAMBDA works on). Returns (L, D, ok); ok is False when Q is not positive definite."""
    n = q.shape[0]
    a = q.copy()
    lmat = np.zeros((n, n))
    d = np.zeros(n)
    for i in range(n - 1, -1, -1):
        di = a[i, i]
        if not di > 0.0:
            return lmat, d, False
        d[i] = di
        for j in range(i):
            lmat[i, j] = a[i, j] / di
        lmat[i, i] = 1.0
        for j in range(i):
            lij = lmat[i, j]
            for k in range(j + 1):
                a[j, k] -= lij * a[i, k]
    return lmat, d, True


@njit(cache=True)
def search_from_ltdl(a, lmat, d, m, max_nodes, growth_limit, growth_limit_loop, perm):
    """Reduction and search on an already factorised problem (a, L, D in the factorisation's order;
    L and D are overwritten); index j of the factorisation is perm[j] of the caller. Returns (integers
    (found, n) int64 in the caller's order, squared norms, found, reduced D); found = -1: node limit,
    -2: non-positive conditional variance after reduction."""
    n = a.shape[0]
    a_int = np.floor(a + 0.5)   # integer part, kept out of the search (precision of large ambiguities)
    zhat = a - a_int
    ops = reduce_lazy(lmat, d, zhat, growth_limit, growth_limit_loop)
    for i in range(n):
        if not d[i] > 0.0:
            return np.zeros((0, n), np.int64), np.zeros(0), -2, d
    zn, norms, found = search_best(lmat, d, zhat, m, max_nodes)
    if found < 0:
        return np.zeros((0, n), np.int64), np.zeros(0), -1, d
    ints = np.zeros((found, n), np.int64)
    for k in range(found):
        v = zn[:, k]
        back_transform(v, ops)
        for j in range(n):
            ints[k, perm[j]] = np.int64(v[j] + a_int[j])
    return ints, norms[:found], found, d


@njit(cache=True)
def integer_least_squares(a, q, m, max_nodes, singular_rtol):
    """The m best integer vectors for float ambiguities a with covariance q (MLAMBDA with the indices
    ordered by decreasing variance, a stable order). Returns (integers (found, n) int64, squared norms
    ascending, found, reduced conditional variances); found = -1: node limit, -2: q not positive definite,
    -3: non-finite input."""
    n = a.shape[0]
    for i in range(n):
        if not np.isfinite(a[i]):
            return np.zeros((0, n), np.int64), np.zeros(0), -3, np.zeros(n)
        for j in range(n):
            if not np.isfinite(q[i, j]):
                return np.zeros((0, n), np.int64), np.zeros(0), -3, np.zeros(n)
    # indices by decreasing variance, ties in their order (stable insertion sort)
    perm = np.arange(n)
    for i in range(1, n):
        j = i
        while j > 0 and q[perm[j], perm[j]] > q[perm[j - 1], perm[j - 1]]:
            perm[j], perm[j - 1] = perm[j - 1], perm[j]
            j -= 1
    qp = np.empty((n, n))
    ap = np.empty(n)
    for i in range(n):
        ap[i] = a[perm[i]]
        for j in range(n):
            qp[i, j] = q[perm[i], perm[j]]
    lmat, d, ok = ltdl_from_last(qp)
    qmax = 0.0
    for i in range(n):
        qmax = max(qmax, q[i, i])
    if not ok or not d.min() > singular_rtol * qmax:
        return np.zeros((0, n), np.int64), np.zeros(0), -2, d
    return search_from_ltdl(ap, lmat, d, m, max_nodes, GROWTH_LIMIT, GROWTH_LIMIT_LOOP, perm)
