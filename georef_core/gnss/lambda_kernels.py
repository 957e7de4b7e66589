"""Compiled (numba) kernels of the integer least-squares search used by lambda_search.mlambda_search:
decorrelation by integer Gauss transformations and adjacent permutations of Q = L^T D L, then the
depth-first shrinking-ellipsoid search for the m best integer vectors. Arrays are float64; Z is the
accumulated unimodular transformation (z = Z^T a)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _gauss(lmat, zmat, i, j):
    n = lmat.shape[0]
    mu = np.floor(lmat[i, j] + 0.5)
    if mu != 0.0:
        for k in range(i, n):
            lmat[k, j] -= mu * lmat[k, i]
        for k in range(n):
            zmat[k, j] -= mu * zmat[k, i]


@njit(cache=True)
def _permute(lmat, d, j, delta, zmat):
    n = lmat.shape[0]
    eta = d[j] / delta
    lam = d[j + 1] * lmat[j + 1, j] / delta
    d[j] = eta * d[j + 1]
    d[j + 1] = delta
    for k in range(j):
        a0 = lmat[j, k]
        a1 = lmat[j + 1, k]
        lmat[j, k] = -lmat[j + 1, j] * a0 + a1
        lmat[j + 1, k] = eta * a0 + lam * a1
    lmat[j + 1, j] = lam
    for k in range(j + 2, n):
        t = lmat[k, j]
        lmat[k, j] = lmat[k, j + 1]
        lmat[k, j + 1] = t
    for k in range(n):
        t = zmat[k, j]
        zmat[k, j] = zmat[k, j + 1]
        zmat[k, j + 1] = t


@njit(cache=True)
def reduce_ltdl(lmat, d, zmat):
    """In place: decorrelate L, D and accumulate Z (starts as identity)."""
    n = d.shape[0]
    j = n - 2
    k = n - 2
    while j >= 0:
        if j <= k:
            for i in range(j + 1, n):
                _gauss(lmat, zmat, i, j)
        delta = d[j] + lmat[j + 1, j] * lmat[j + 1, j] * d[j + 1]
        if delta + 1e-6 < d[j + 1]:
            _permute(lmat, d, j, delta, zmat)
            k = j
            j = n - 2
        else:
            j -= 1


@njit(cache=True)
def search_best(lmat, d, zs, m, max_nodes):
    """m best integer vectors (columns of the returned (n, m) array) and their squared norms.
    Returns n_found < m when the tree had fewer leaves; raises nothing (node limit -> n_found = -1)."""
    n = d.shape[0]
    s_mat = np.zeros((n, n))
    dist = np.zeros(n)
    zb = np.zeros(n)
    z = np.zeros(n)
    step = np.zeros(n)
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
                order = np.argsort(s[:nn])
                return zn[:, order], s[order], nn
            k += 1
            z[k] += step[k]
            y = zb[k] - z[k]
            step[k] = -step[k] - (1.0 if step[k] > 0 else -1.0)
    return zn, s, -1
