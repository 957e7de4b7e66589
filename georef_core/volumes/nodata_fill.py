"""Filling small nodata holes of a DSM window by harmonic (Laplace) interpolation.

Each missing cell that a polygon needs, with the whole 4-connected group of missing cells it belongs to
(inside the window), is given the value that makes it the mean of its four neighbours: the smoothest
surface matching the valid cells around the hole (exact on planes; on curved ground it sags toward the
hole's rim). One sparse linear system for all holes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ProcessingError


@dataclass
class FillReport:
    n_cells: int  # cells given a value
    n_holes: int  # connected groups of missing cells filled
    largest_hole_cells: int


def fill_holes(z: np.ndarray, needed: np.ndarray) -> FillReport:
    """Fill, in place, the NaN cells of ``z`` connected to the cells flagged in ``needed``."""
    from scipy import ndimage
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    missing = ~np.isfinite(z)
    labels, _ = ndimage.label(missing)
    wanted = np.unique(labels[needed & missing])
    wanted = wanted[wanted > 0]
    if not len(wanted):
        return FillReport(0, 0, 0)
    unknown = np.isin(labels, wanted)
    ii, jj = np.nonzero(unknown)
    n = len(ii)
    index = np.full(z.shape, -1, np.int64)
    index[ii, jj] = np.arange(n)
    diag = np.zeros(n)
    rhs = np.zeros(n)
    r_list, c_list = [], []
    for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        ni, nj = ii + di, jj + dj
        inside = (ni >= 0) & (ni < z.shape[0]) & (nj >= 0) & (nj < z.shape[1])
        k = np.flatnonzero(inside)
        nb = index[ni[k], nj[k]]
        is_unknown = nb >= 0
        diag[k] += 1.0
        ku = k[is_unknown]
        r_list.append(ku)
        c_list.append(nb[is_unknown])
        kk = k[~is_unknown]
        rhs[kk] += z[ni[kk], nj[kk]]
    # every group needs at least one valid neighbour
    has_known = np.zeros(n, bool)
    for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        ni, nj = np.clip(ii + di, 0, z.shape[0] - 1), np.clip(jj + dj, 0, z.shape[1] - 1)
        has_known |= np.isfinite(z[ni, nj])
    groups = labels[ii, jj]
    anchored = np.unique(groups[has_known])
    if len(anchored) < len(wanted):
        raise ProcessingError("a nodata area has no valid cell around it to interpolate from")
    rows = np.concatenate([np.arange(n)] + r_list)
    cols = np.concatenate([np.arange(n)] + c_list)
    vals = np.concatenate([diag] + [-np.ones(len(r)) for r in r_list])
    A = coo_matrix((vals, (rows, cols)), shape=(n, n)).tocsc()
    sol = spsolve(A, rhs)
    z[ii, jj] = sol.astype(z.dtype)
    sizes = np.bincount(groups)
    return FillReport(n, len(wanted), int(sizes[wanted].max()))
