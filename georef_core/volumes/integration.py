"""The volume kernel: one pass over the cells a polygon covers, weighted by their exact coverage.

For every cell with coverage w > 0 and a height z (cell centre) above/below the base b:
cut += w (z - b)^+ and fill += w (b - z)^+ (cell units; times the cell area gives m^3), plus the
coverage moments (area, centroid) and sum w (z - z_ref) used for the other bases' nets and the
uncertainty, and the coverage summed over coarse blocks (the weight field of the noise model).
Cells without data are counted (``missing``) and skipped; the caller fills them and runs again.

Rows are processed in parallel (numba prange), each row writing its own partial sums and coarse
row: no shared accumulator, deterministic results, and a window can be processed in row strips of any
height (:class:`Integrator`). Inside a row the coverage is the
running sum of the row's deposits (:mod:`.coverage`), so fully inside runs are plain loops.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from .coverage import CellCoverage

N_STATS = 9  # area, cut, fill, sum w (z - zref), sum w u, sum w v, missing, missing_base, sum w^2


# reassociation lets LLVM vectorise the sums; no "nnan"/"ninf": the NaN tests must stay
_FAST = {"reassoc", "contract", "nsz", "arcp"}


@njit(cache=True, nogil=True, fastmath=_FAST)
def _run_plane(zrow, j0, j1, w, b0, qu, zref, acc):
    """Cells j0..j1-1 of one row, coverage w, plane base b0 + qu * (j + 0.5). acc: area, cut, fill, sz, su,
    miss, sw2 (added to)."""
    area = 0.0
    cut = 0.0
    fill = 0.0
    sz = 0.0
    su = 0.0
    nz = 0.0
    for jj in range(j0, j1):
        zz = zrow[jj]
        ok = zz == zz
        dz = (zz - (b0 + qu * (jj + 0.5))) if ok else 0.0
        wv = w if ok else 0.0
        area += wv
        sz += (zz - zref) if ok else 0.0
        su += wv * (jj + 0.5)
        cut += max(dz, 0.0)
        fill += max(-dz, 0.0)
        nz += 0.0 if ok else 1.0
    acc[0] += area
    acc[1] += w * cut
    acc[2] += w * fill
    acc[3] += w * sz
    acc[4] += su
    acc[5] += w * nz
    acc[6] += w * area


@njit(cache=True, nogil=True, fastmath=_FAST)
def _run_grid(zrow, brow, j0, j1, w, zref, acc):
    """As _run_plane with a per-cell base row (NaN: no base); acc[7] counts cells without base."""
    area = 0.0
    cut = 0.0
    fill = 0.0
    sz = 0.0
    su = 0.0
    nz = 0.0
    nb = 0.0
    for jj in range(j0, j1):
        zz = zrow[jj]
        bb = brow[jj]
        okz = zz == zz
        okb = bb == bb
        ok = okz and okb
        dz = (zz - bb) if ok else 0.0
        wv = w if ok else 0.0
        area += wv
        sz += (zz - zref) if ok else 0.0
        su += wv * (jj + 0.5)
        cut += max(dz, 0.0)
        fill += max(-dz, 0.0)
        nz += 0.0 if okz else 1.0
        nb += 1.0 if (okz and not okb) else 0.0
    acc[0] += area
    acc[1] += w * cut
    acc[2] += w * fill
    acc[3] += w * sz
    acc[4] += su
    acc[5] += w * nz
    acc[6] += w * area
    acc[7] += w * nb


@njit(parallel=True, cache=True, nogil=True)
def _integrate_rows(z, row_ptr, dcols, dvals, use_grid, q0, qu, qv, base_grid, zref, block, coarse_rows, stats):
    nrows, ncols = z.shape
    for i in prange(nrows):
        acc = np.zeros(8)
        cov = 0.0
        j = 0
        kend = row_ptr[i + 1]
        vc = i + 0.5
        b0 = q0 + qv * vc
        for k in range(row_ptr[i], kend + 1):
            jn = dcols[k] if k < kend else ncols
            if cov > 1e-12 and jn > j:
                w = cov if cov < 1.0 else 1.0
                b_first = j // block
                b_last = (jn - 1) // block
                if b_first == b_last:
                    coarse_rows[i, b_first] += w * (jn - j)
                else:
                    coarse_rows[i, b_first] += w * ((b_first + 1) * block - j)
                    for bb in range(b_first + 1, b_last):
                        coarse_rows[i, bb] += w * block
                    coarse_rows[i, b_last] += w * (jn - b_last * block)
                if use_grid:
                    _run_grid(z[i], base_grid[i], j, jn, w, zref, acc)
                else:
                    _run_plane(z[i], j, jn, w, b0, qu, zref, acc)
            if k < kend:
                cov += dvals[k]
            j = jn
        stats[i, 0] = acc[0]
        stats[i, 1] = acc[1]
        stats[i, 2] = acc[2]
        stats[i, 3] = acc[3]
        stats[i, 4] = acc[4]
        stats[i, 5] = acc[0] * vc
        stats[i, 6] = acc[5]
        stats[i, 7] = acc[7]
        stats[i, 8] = acc[6]


@dataclass
class CellSums:
    """Sums of the kernel in cell units (multiply areas by the cell area, volumes by it too); u, v are
    pixel coordinates of the whole window."""

    area: float  # sum of w over cells with data (and base)
    cut: float  # sum w (z - b)^+
    fill: float  # sum w (b - z)^+
    sum_dz_ref: float  # sum w (z - z_ref)
    sum_u: float  # sum w u (pixel column of the cell centre)
    sum_v: float
    missing: float  # sum w over cells without DSM data
    missing_base: float  # sum w over cells without base (grid bases)
    sum_w2: float
    coarse: np.ndarray  # coverage summed over blocks of block x block cells (all covered cells)
    block: int


class Integrator:
    """Accumulates the kernel over the row strips of a window (any strip heights, any order)."""

    def __init__(self, cov: CellCoverage, block: int, z_ref: float):
        self.cov = cov
        self.block = int(block)
        self.z_ref = float(z_ref)
        self.coarse = np.zeros((-(-cov.nrows // block), -(-cov.ncols // block)))
        self.totals = np.zeros(N_STATS)

    def add(self, z: np.ndarray, row_start: int, plane=None, base_grid: np.ndarray | None = None) -> None:
        """Rows [row_start, row_start + len(z)) of the window: heights ``z`` (float32, NaN = no data) with a
        plane base ``(q0, qu, qv)`` in the strip's pixel coordinates, or a per-cell ``base_grid``."""
        n, ncols = z.shape
        rp = self.cov.row_ptr[row_start:row_start + n + 1]
        if rp[-1] == rp[0]:
            return  # the polygon does not reach these rows
        coarse_rows = np.zeros((n, self.coarse.shape[1]))
        stats = np.zeros((n, N_STATS))
        if base_grid is not None:
            grid, use_grid, (q0, qu, qv) = base_grid, True, (0.0, 0.0, 0.0)
        else:
            grid, use_grid, (q0, qu, qv) = np.zeros((1, 1), np.float32), False, plane
        z = z if z.dtype == np.float32 else z.astype(np.float32)
        grid = grid if grid.dtype == np.float32 else grid.astype(np.float32)
        _integrate_rows(z, rp, self.cov.cols, self.cov.vals, use_grid, float(q0), float(qu), float(qv), grid,
                        self.z_ref, self.block, coarse_rows, stats)
        s = stats.sum(axis=0)
        s[5] += row_start * s[0]  # v of the strip -> v of the window
        self.totals += s
        brow = (row_start + np.arange(n)) // self.block
        starts = np.flatnonzero(np.r_[True, brow[1:] != brow[:-1]])
        self.coarse[brow[starts]] += np.add.reduceat(coarse_rows, starts, axis=0)

    def result(self) -> CellSums:
        return CellSums(*[float(v) for v in self.totals], coarse=self.coarse, block=self.block)


def integrate(z: np.ndarray, cov: CellCoverage, plane=None, base_grid: np.ndarray | None = None, z_ref: float = 0.0,
              block: int = 1) -> CellSums:
    """The kernel over a whole window held in memory."""
    acc = Integrator(cov, block, z_ref)
    acc.add(z, 0, plane, base_grid)
    return acc.result()
